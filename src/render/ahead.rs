//! Rows drawn ahead: a solve of one process on two cores or more draws, one
//! row on each core, the row of the shot under way and those of the
//! shooters likely to shoot next (the vote's runners-up), so that both
//! cores draw whole rows instead of splitting each row between them.
//!
//! Why: one shot at a time, the two cores split every row, and a shot's
//! serial parts (landing, the vote, the forks' joins) leave one core idle
//! a fifth of the time. A row depends only on its shooter, its centre and
//! its tier ([`RowKey`]), never on the state, so a row drawn before its shot
//! is the row the shot would draw: the numbers are the same bits with or
//! without drawing ahead (tested), and a runner-up that does not shoot next
//! costs only time (two shots in three take the runner-up in the 4096-cube
//! room, nine in ten one of the first four).
//!
//! The shot loop's thread draws too: it draws its own row when nobody has
//! started it, and while the helper thread draws it, the next wanted row.
//! Whether drawing ahead pays is measured as the solve goes ([`Probe`]):
//! in a big scene it did not.

use super::cache::RowKey;
use super::options::{RenderError, RenderOptions};
use super::source::GpuFormFactors;
use super::PhaseTimes;
use crate::formfactor::Row;
use crate::parallel::{self, Single};
use crate::solver::{ShotRegion, Transfer};
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::Duration;

/// Runners-up whose rows are wanted after the shot's own. In the
/// 4096-cube room, 640 shots: with 1, 2, 3, 5, 8 and 16 runners-up,
/// 45, 58, 66, 70, 73 and 74 % of the shots found their row drawn; the
/// rows drawn and never taken stay near 10 % from 5 on.
pub const RUNNERS_UP: usize = 8;

/// Rows drawn and not yet taken that are kept (beyond those still wanted).
const KEPT: usize = 8;

/// The longest wait for the helper's row: a row's every wait on the device
/// is bounded far below this, so a longer one is a bug, said loudly.
const WAIT_LIMIT: Duration = Duration::from_secs(600);

/// A row someone wants drawn: its key and its hemisphere's centre.
type Want = (RowKey, glam::Vec3);

/// Shots a window lasts.
const WINDOW: u32 = 32;

/// Whether each probe window draws ahead, after one window of warm-up:
/// ABBA BAAB, which cancels a steady drift of the shots' cost and a
/// curving one.
const PROBE: [bool; 8] = [true, false, false, true, false, true, true, false];

/// When the probe may decide early: after its first pair of windows (AB)
/// where one way took at most 0.7 of the other's time, or after its first
/// two pairs (AB, BA) where in each the same way took at most 0.8 of the
/// other's. In the 4096-cube room drawing ahead takes 0.46-0.65 of the
/// other way's time, and the probe's in-shot windows cost 9 % of its
/// 640-shot bench; a closer call, or pairs that disagree, take all eight
/// windows (Sponza's first probe does).
const EARLY: [(usize, f64); 2] = [(1, 0.7), (2, 0.8)];

/// Windows the measured choice holds before it measures again; doubled
/// each time the probe agrees with the choice it held, up to [`MOST_HOLD`]
/// (a probe spends half its shots the slower way).
const HOLD: u32 = 16;
const MOST_HOLD: u32 = 256;

/// Whether drawing ahead pays, measured as the solve goes: rows drawn
/// ahead for a runner-up that does not shoot next are lost, and in a big
/// scene two rows drawn at once slow each other, so the loss can outweigh
/// the gain (Sponza's first 128 shots, each way throughout: 4.07 s drawing
/// ahead against 3.07 s; the 4096-cube room 9.8-10.1 ms a shot ahead
/// against 12.8-14.8 ms). A cycle is one window of warm-up in the way
/// held so far (a switch of ways, or the solve's start, costs the window
/// after it: its shots are the solve's first, or rows drawn ahead are
/// still being taken), then the [`PROBE`] windows, whose times are summed
/// each way; the faster way holds for [`HOLD`] windows or more. A window's
/// cost varies with its shooters by half or more: one window a way, the
/// first counted, chose each row in its shot in the 4096-cube room, 30 %
/// slower. Still fooled by a sudden drop: Sponza's shots cost a tenth
/// after its first 130, so its probe measures ahead as faster, and its
/// solve pays 0.3-0.8 s (docs/notebook/shot-speed.md "Rows drawn ahead"). Windows of 16 shots,
/// ABBA four times, measured the switches more than the ways. Only time
/// depends on it: the rows are the same either way.
#[derive(Debug)]
struct Probe {
    /// Windows done in this cycle (0: warm-up; then probing until decided).
    window: u32,
    /// Shots into the current window and when it began.
    shots: u32,
    began: Option<std::time::Instant>,
    /// The probe's time drawing ahead and drawing in the shot.
    spent: [Duration; 2],
    /// Each probe window's time, in [`PROBE`]'s order.
    windows: [Duration; PROBE.len()],
    /// The way chosen by the last probe.
    chosen: bool,
    /// Once this cycle's probe has chosen: the window its hold ends at.
    until: Option<u32>,
    /// How long the last choice held; 0 before the first.
    hold: u32,
}

impl Default for Probe {
    fn default() -> Self {
        Self {
            window: 0,
            shots: 0,
            began: None,
            spent: [Duration::ZERO; 2],
            windows: [Duration::ZERO; PROBE.len()],
            chosen: true,
            until: None,
            hold: 0,
        }
    }
}

impl Probe {
    /// Notes a shot starting; returns whether it draws ahead.
    fn shot(&mut self) -> bool {
        self.shot_at(std::time::Instant::now())
    }

    /// [`Probe::shot`], the shot starting at `now`.
    fn shot_at(&mut self, now: std::time::Instant) -> bool {
        let began = *self.began.get_or_insert(now);
        if self.shots == WINDOW {
            let ahead = self.ahead();
            let took = now - began;
            log::trace!("window {}: {took:?} {}", self.window, way(ahead));
            if self.probing() {
                self.spent[usize::from(!ahead)] += took;
                self.windows[self.window as usize - 1] = took;
            }
            self.window += 1;
            let probed = self.window as usize - 1;
            if self.until.is_none() && (probed == PROBE.len() || self.decisive(probed)) {
                self.decide();
            }
            if self.until == Some(self.window) {
                self.window = 0;
                self.spent = [Duration::ZERO; 2];
                self.windows = [Duration::ZERO; PROBE.len()];
                self.until = None;
            }
            self.shots = 0;
            self.began = Some(now);
        }
        self.shots += 1;
        self.ahead()
    }

    /// Ends this cycle's probe: the faster way holds, longer when it is the
    /// way held before.
    fn decide(&mut self) {
        let faster = self.spent[0] <= self.spent[1];
        self.hold = if self.hold > 0 && faster == self.chosen {
            (2 * self.hold).min(MOST_HOLD)
        } else {
            HOLD
        };
        self.chosen = faster;
        self.until = Some(self.window + self.hold);
        log::debug!(
            "drawing ahead: {:?} against {:?} drawing each row in its shot; {} for {} windows",
            self.spent[0],
            self.spent[1],
            way(self.chosen),
            self.hold
        );
    }

    /// Whether the first `probed` probe windows are the pairs of an
    /// [`EARLY`] decision, each pair finding the same way faster by its
    /// margin or more.
    fn decisive(&self, probed: usize) -> bool {
        let Some(&(pairs, margin)) = EARLY.iter().find(|e| 2 * e.0 == probed) else {
            return false;
        };
        let faster = |pair: usize| {
            let (mut t, k) = ([0.0; 2], 2 * pair);
            for (w, &ahead) in PROBE[k..k + 2].iter().enumerate() {
                t[usize::from(!ahead)] = self.windows[k + w].as_secs_f64();
            }
            if t[0] <= margin * t[1] {
                Some(true)
            } else if t[1] <= margin * t[0] {
                Some(false)
            } else {
                None
            }
        };
        let first = faster(0);
        first.is_some() && (1..pairs).all(|p| faster(p) == first)
    }

    /// Whether the current window is one of the probe's.
    fn probing(&self) -> bool {
        self.until.is_none() && self.window >= 1
    }

    /// Whether the current window draws ahead.
    fn ahead(&self) -> bool {
        if self.probing() {
            PROBE[self.window as usize - 1]
        } else {
            self.chosen
        }
    }
}

/// A way of drawing, in words.
fn way(ahead: bool) -> &'static str {
    if ahead {
        "ahead"
    } else {
        "in the shot"
    }
}

/// What the shot loop and the helper share.
#[derive(Default)]
struct Board {
    /// Rows wanted and not yet started, the most wanted first.
    wanted: Vec<Want>,
    /// Rows being drawn.
    busy: Vec<RowKey>,
    /// Rows drawn and not yet taken, oldest first.
    done: Vec<(RowKey, Result<Row, RenderError>)>,
    /// The loop is over: the helper leaves.
    stop: bool,
    /// The helper could not start, or has failed: the loop draws alone.
    helper_gone: bool,
    /// What became of the shots' rows and of the rows drawn ahead.
    counts: Counts,
}

/// What became of the rows (logged at debug level when the solve ends).
#[derive(Clone, Copy, Debug, Default)]
struct Counts {
    /// Shots whose row was drawn and waiting.
    ready: u64,
    /// Shots whose row the helper was drawing: waited for.
    waited: u64,
    /// Shots that drew their own row.
    own: u64,
    /// Rows drawn ahead, by the helper and by the loop's thread.
    ahead: u64,
    /// Rows drawn ahead and dropped untaken.
    dropped: u64,
}

impl Board {
    /// Takes the first wanted row nobody draws, marking it busy.
    fn claim(&mut self) -> Option<Want> {
        let at = self
            .wanted
            .iter()
            .position(|(k, _)| !self.busy.contains(k) && !self.done.iter().any(|(d, _)| d == k))?;
        let want = self.wanted.remove(at);
        self.busy.push(want.0);
        Some(want)
    }

    /// Puts a drawn row down.
    fn finish(&mut self, key: RowKey, row: Result<Row, RenderError>) {
        self.busy.retain(|k| *k != key);
        self.counts.ahead += 1;
        self.done.push((key, row));
    }

    /// Drops the oldest drawn rows nobody wants now, beyond [`KEPT`].
    fn prune(&mut self) {
        let before = self.done.len();
        let mut extra = before.saturating_sub(KEPT);
        let wanted = &self.wanted;
        self.done.retain(|(k, _)| {
            let drop = extra > 0 && !wanted.iter().any(|(w, _)| w == k);
            extra -= usize::from(drop);
            !drop
        });
        self.counts.dropped += (before - self.done.len()) as u64;
    }
}

/// The board of a solve that draws ahead (see the module's comment).
#[derive(Default)]
pub struct Ahead {
    board: Mutex<Board>,
    turn: Condvar,
    probe: Mutex<Probe>,
}

impl Ahead {
    /// Whether a solve with `opts` over `ranks` ranks draws ahead: on
    /// request (by default), one rank alone in its process, one shot a
    /// step, and two cores or more.
    pub fn applies(opts: &RenderOptions, ranks: usize) -> bool {
        opts.look_ahead
            && ranks == 1
            && opts.batch <= 1
            && parallel::ranks_in_this_process() == 1
            && parallel::cores() >= 2
    }

    /// Runs `solve` (the shot loop, on this thread) beside
    /// a helper thread that draws wanted rows with a source of its own (one
    /// process, one core, built like `source`); returns what `solve` does,
    /// the helper's phase times added to `source`'s.
    pub fn run<T>(
        opts: &RenderOptions,
        source: &mut GpuFormFactors,
        solve: impl FnOnce(&Ahead, &mut GpuFormFactors) -> Result<T, RenderError>,
    ) -> Result<T, RenderError> {
        let ahead = Ahead::default();
        let parts = source.parts();
        let (out, helper, ready) = std::thread::scope(|s| {
            let helper = s.spawn(|| ahead.helper(opts, parts));
            let out = solve(&ahead, source);
            let counts = {
                let mut board = ahead.lock();
                board.stop = true;
                board.counts
            };
            ahead.turn.notify_all();
            log::debug!(
                "rows drawn ahead: {} shots took theirs ready, {} waited for it, {} drew their own; {} rows drawn ahead, {} dropped untaken",
                counts.ready,
                counts.waited,
                counts.own,
                counts.ahead,
                counts.dropped
            );
            (out, helper.join(), counts.ready + counts.waited)
        });
        match helper {
            Ok(times) => source.absorb(&times),
            Err(panic) => std::panic::resume_unwind(panic),
        }
        source.timings.drawn_ahead += ready;
        out
    }

    /// The cores the shot loop's thread may fork onto now: one while the
    /// helper draws, else every core (a weak shot along the transport and
    /// its landing, while nothing is drawn ahead, keep both cores).
    pub fn cores_now(&self) -> usize {
        if self.lock().busy.is_empty() {
            parallel::cores()
        } else {
            1
        }
    }

    fn lock(&self) -> MutexGuard<'_, Board> {
        self.board.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The helper: draws wanted rows until the loop is over.
    fn helper(&self, opts: &RenderOptions, parts: super::source::Parts<'_>) -> PhaseTimes {
        // Marks the helper gone however it leaves, so the loop never waits
        // on a row nobody draws.
        struct Gone<'b>(&'b Ahead);
        impl Drop for Gone<'_> {
            fn drop(&mut self) {
                let mut board = self.0.lock();
                board.helper_gone = true;
                board.busy.clear();
                self.0.turn.notify_all();
            }
        }
        let _gone = Gone(self);
        parallel::with_cores(1, || {
            let one = Single::default();
            let built = std::time::Instant::now();
            let mut source = match GpuFormFactors::sibling(parts, opts, &one) {
                Ok(source) => {
                    log::debug!(
                        "drawing ahead: the helper's source built in {:?}",
                        built.elapsed()
                    );
                    source
                }
                Err(e) => {
                    log::warn!("drawing rows ahead: {e}; drawing each row in its shot");
                    return PhaseTimes::default();
                }
            };
            loop {
                let mut board = self.lock();
                let (key, centre) = loop {
                    if board.stop {
                        return source.timings;
                    }
                    if let Some(want) = board.claim() {
                        break want;
                    }
                    board = self.turn.wait(board).unwrap_or_else(|e| e.into_inner());
                };
                drop(board);
                let row = source.draw_row(key, centre);
                self.lock().finish(key, row);
                self.turn.notify_all();
            }
        })
    }

    /// The form factors of `shooter` shooting `region` into `out`, as
    /// [`crate::solver::FormFactorSource::form_factors`] gives them: a row
    /// to draw is taken drawn when it is, drawn here when nobody has
    /// started it, or waited for while this thread draws the next wanted
    /// row. `next` gives the rows wanted after it (the runners-up's, most
    /// likely first).
    pub fn form_factors(
        &self,
        source: &mut GpuFormFactors,
        (shooter, region): (u32, &ShotRegion),
        next: impl FnOnce(&GpuFormFactors) -> Vec<Want>,
        out: &mut Vec<Transfer>,
    ) -> Result<(), RenderError> {
        let ahead = self.probe.lock().unwrap_or_else(|e| e.into_inner()).shot();
        source.form_factors_by(shooter, region, out, |source, key, centre| {
            let next = ahead.then(|| next(source));
            {
                let mut board = self.lock();
                board.wanted.clear();
                if let Some(next) = next {
                    board.wanted.push((key, centre));
                    board
                        .wanted
                        .extend(next.iter().filter(|(k, _)| *k != key).copied());
                }
                board.prune();
            }
            self.turn.notify_all();
            self.take(source, (key, centre))
        })
    }

    /// Row `key`: taken drawn, drawn here when nobody draws it, or, while
    /// the helper draws it, waited for with the next wanted rows drawn
    /// here meanwhile. Returns it with the time in exchanges (none: one
    /// process) and the time spent on other rows (not this shot's summing).
    fn take(
        &self,
        source: &mut GpuFormFactors,
        (key, centre): Want,
    ) -> Result<(Row, Duration, Duration), RenderError> {
        let mut aside = Duration::ZERO;
        let mut waited = false;
        let mut board = self.lock();
        loop {
            if let Some(at) = board.done.iter().position(|(k, _)| *k == key) {
                let (_, row) = board.done.remove(at);
                if waited {
                    board.counts.waited += 1;
                } else {
                    board.counts.ready += 1;
                }
                return row.map(|r| (r, Duration::ZERO, aside));
            }
            if board.helper_gone || !board.busy.contains(&key) {
                board.wanted.retain(|(k, _)| *k != key);
                board.counts.own += 1;
                drop(board);
                // One core each while the helper draws beside it.
                let cores = self.cores_now();
                let (row, exchange) = parallel::with_cores(cores, || source.own_row(key, centre))?;
                return Ok((row, exchange, aside));
            }
            if let Some((k, c)) = board.claim() {
                drop(board);
                let start = std::time::Instant::now();
                let row = parallel::with_cores(1, || source.draw_row(k, c));
                aside += start.elapsed();
                board = self.lock();
                board.finish(k, row);
                self.turn.notify_all();
                continue;
            }
            waited = true;
            let (b, wait) = self
                .turn
                .wait_timeout(board, WAIT_LIMIT)
                .unwrap_or_else(|e| e.into_inner());
            board = b;
            if wait.timed_out() {
                return Err(RenderError::DrawnAhead(
                    key.patch,
                    format!("waited {} s", WAIT_LIMIT.as_secs()),
                ));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    /// Runs `windows` windows of shots through a new probe, each shot
    /// costing what `cost` says of its way and its window; returns each
    /// window's way, checking that every shot of a window takes it.
    fn run(windows: u32, cost: impl Fn(bool, u32) -> Duration) -> Vec<bool> {
        let mut probe = Probe::default();
        let mut at = Instant::now();
        (0..windows)
            .map(|w| {
                let ways: Vec<bool> = (0..WINDOW)
                    .map(|_| {
                        let ahead = probe.shot_at(at);
                        at += cost(ahead, w);
                        ahead
                    })
                    .collect();
                assert!(
                    ways.iter().all(|&a| a == ways[0]),
                    "window {w} changed ways"
                );
                ways[0]
            })
            .collect()
    }

    /// A shot's time: `base` microseconds, `slow` times more the slower way.
    fn shot(ahead: bool, ahead_faster: bool, base: f64, slow: f64) -> Duration {
        let factor = if ahead == ahead_faster { 1.0 } else { slow };
        Duration::from_micros((base * factor) as u64)
    }

    const P: usize = PROBE.len();

    #[test]
    fn the_probe_chooses_the_faster_way_whatever_the_first_window_costs() {
        for ahead_faster in [true, false] {
            // The solve's first window costs 20x (drawn ahead), and the
            // shots' cost drifts up as the solve goes; the faster way is
            // 10 % faster.
            let ways = run(P as u32 + 6, |ahead, w| {
                let base = if w == 0 {
                    20_000.0
                } else {
                    1_000.0 + 10.0 * w as f64
                };
                shot(ahead, ahead_faster, base, 1.1)
            });
            assert!(ways[0], "the warm-up draws ahead");
            assert_eq!(ways[1..=P], PROBE, "the probe's windows");
            assert!(
                ways[P + 1..].iter().all(|&a| a == ahead_faster),
                "held: the faster way (ahead faster: {ahead_faster})"
            );
        }
    }

    #[test]
    fn the_probe_decides_early_only_where_its_pairs_agree_by_far() {
        // The in-shot way's cost against ahead's in the first pair and the
        // second: 2x in the first decides after it; 1.33x (0.75) in both
        // after two pairs; 1.33x then a coin toss, or 1.18x (0.85), takes
        // all eight windows.
        for (first, second, probed) in [
            (2.0, 1.0, 2),
            (1.33, 1.33, 4),
            (1.33, 1.0, P),
            (1.18, 1.18, P),
        ] {
            let ways = run(P as u32 + 3, |ahead, w| {
                let factor = if (3..5).contains(&w) { second } else { first };
                shot(ahead, true, 1_000.0, factor)
            });
            let early = probed < P;
            assert_eq!(ways[1..=probed], PROBE[..probed], "the probe's windows");
            assert!(
                ways[probed + 1..].iter().all(|&a| a),
                "held ahead (early: {early})"
            );
        }
    }

    #[test]
    fn the_probe_measures_again_after_holding_and_holds_longer_when_it_agrees() {
        let hold = HOLD as usize;
        // One way twice as fast: decided after the first pair.
        let cycle = |warm: bool, hold: usize, held: bool| {
            let mut c = vec![warm];
            c.extend(&PROBE[..2]);
            c.extend(vec![held; hold]);
            c
        };
        // Ahead holds, the probe agrees and it holds twice as long; then
        // drawing ahead turns twice as slow: the next probe switches, and
        // the one after agrees.
        let mut want = cycle(true, hold, true);
        want.extend(cycle(true, 2 * hold, true));
        let switch = want.len() as u32;
        want.extend(cycle(true, hold, false));
        want.extend(cycle(false, 2 * hold, false));
        let ways = run(want.len() as u32, |ahead, w| {
            shot(ahead, w < switch, 1_000.0, 2.0)
        });
        assert_eq!(ways, want);
    }
}
