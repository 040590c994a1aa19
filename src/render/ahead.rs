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
        source.form_factors_by(shooter, region, out, |source, key, centre| {
            let next = next(source);
            {
                let mut board = self.lock();
                board.wanted.clear();
                board.wanted.push((key, centre));
                board
                    .wanted
                    .extend(next.iter().filter(|(k, _)| *k != key).copied());
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
