//! The shooting loop: progressive refinement (DESIGN.md section 2) over the
//! ranks of a [`Collectives`]. Before every shot one all-gather of each
//! rank's [`Vote`] decides the stop rule, the shooter, the ambient term, the
//! cache and whether to save or stop; so every rank makes the same decision
//! at the same shot.

use super::ahead::{Ahead, RUNNERS_UP};
use super::options::{RenderError, RenderOptions};
use super::source::{GpuFormFactors, GroupPart, Started};
use crate::lit_mesh::LitMesh;
use crate::parallel::{Collectives, Deal};
use crate::solver::{
    Candidate, FormFactorSource, NetUnshot, Shot, ShotRegion, Solver, StopRule, Transfer,
    UNSHOT_ONE,
};
use std::time::{Duration, Instant};

/// What the shooting loop asks of its caller between shots.
pub trait LoopHooks<'m> {
    /// After every shot, on every rank, with the unshot fraction before it.
    fn after_shot(&mut self, _solver: &Solver<'m>, _unshot_fraction: f64) {}
    /// This rank's say for the next shot (see [`Flags`]).
    fn flags(&self) -> Flags {
        Flags::default()
    }
    /// Saves the state; every rank calls it at the same point.
    fn checkpoint(&mut self, _solver: &Solver<'m>) -> Result<(), RenderError> {
        Ok(())
    }
}

/// A rank's say before a shot.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Flags {
    /// Stop now (this rank was interrupted); the state is saved first.
    pub stop: bool,
    /// Save the state (only rank 0's counts, so ranks agree).
    pub save: bool,
}

impl Flags {
    fn bits(self) -> u32 {
        self.stop as u32 | (self.save as u32) << 1
    }

    fn from_bits(bits: u32) -> Self {
        Self {
            stop: bits & 1 != 0,
            save: bits & 2 != 0,
        }
    }
}

/// Hooks from a closure run after every shot (no checkpoints).
pub struct AfterShot<F>(pub F);

impl<'m, F: FnMut(&Solver<'m>, f64)> LoopHooks<'m> for AfterShot<F> {
    fn after_shot(&mut self, solver: &Solver<'m>, unshot_fraction: f64) {
        (self.0)(solver, unshot_fraction)
    }
}

/// What a shooting loop measured, besides the solver's state.
#[derive(Default)]
pub struct LoopStats {
    /// It stopped because a rank was interrupted.
    pub interrupted: bool,
    /// Time choosing shooters (the per-shot collective included).
    pub select: Duration,
    /// Time updating radiosities.
    pub update: Duration,
    /// Each shot's time.
    pub shot_times: Vec<Duration>,
    /// Power each patch shot, summed (sum over RGB; the same on every rank).
    pub patch_power: Vec<f64>,
    /// The rows of batched shots this rank drew, in order (the first
    /// [`MAX_ROW_RECORDS`] shots' only): what the performance model needs
    /// to replay a batch's assignment on any number of ranks.
    pub rows: Vec<RowRecord>,
    /// Process CPU seconds drawing the batched rows this rank drew (all of
    /// them; the divided work of a batched solve).
    pub rows_cpu_seconds: f64,
}

/// A batched step's buffers: per row this rank's own transfers, per rank
/// the words sent to it, and the words received from every rank.
#[derive(Default)]
struct BatchBuffers {
    rows: Vec<Vec<Transfer>>,
    outgoing: Vec<Vec<u32>>,
    incoming: Vec<u32>,
}

/// What a batch's rounds fill: per rank the row pieces to send, per row
/// this rank's own transfers, and per row its sums.
type BatchOut<'a> = (&'a mut [Vec<u32>], &'a mut [Vec<Transfer>], &'a mut [f64]);

/// Batched shots whose rows are recorded ([`LoopStats::rows`]).
pub const MAX_ROW_RECORDS: u64 = 10_000;

/// One row of a batched shot, as its drawing rank saw it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RowRecord {
    /// The solve's shot count when its batch began.
    pub batch_start: u64,
    /// Its place in the batch (round 1: in the batch's list of groups).
    pub index: u32,
    /// 0: a row (its first hemisphere, and, for a split shot, its
    /// assembly); 1: a group of a split shot, dealt in a second round.
    pub round: u32,
    /// The cost the assignment weighed it at (`GpuFormFactors::row_cost`,
    /// `GpuFormFactors::group_cost`).
    pub cost: f64,
    /// Process CPU seconds drawing it and packing it for its owners.
    pub cpu_seconds: f64,
}

/// What one rank tells the others before a shot.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Vote {
    /// Its unshot power over the emitted power, [`UNSHOT_ONE`] fixed point.
    unshot: u64,
    /// Its best patch.
    candidate: Option<Candidate>,
    /// What the last shot landed on its elements, fixed point.
    landed: u64,
    /// The bytes of its pending cache row.
    pending_bytes: u64,
    flags: Flags,
    /// Its signed unshot power per channel.
    net: NetUnshot,
    /// The power the last shot delivered to its elements, over the emitted
    /// power, signed fixed point.
    delivered: i64,
}

impl Vote {
    /// f64 slots a vote takes in the all-gather. Every integer is below
    /// 2^53, so it travels exactly.
    const LEN: usize = 18;

    fn pack(&self) -> [f64; Self::LEN] {
        let mut v = [0.0; Self::LEN];
        v[0] = self.unshot as f64;
        v[1] = -1.0;
        if let Some(c) = self.candidate {
            v[1..1 + CANDIDATE_LEN].copy_from_slice(&pack_candidate(&c));
        }
        v[11] = self.landed as f64;
        v[12] = self.pending_bytes as f64;
        v[13] = self.flags.bits() as f64;
        v[14..17].copy_from_slice(&self.net.map(|x| x as f64));
        v[17] = self.delivered as f64;
        v
    }

    fn unpack(v: &[f64]) -> Self {
        Self {
            unshot: v[0] as u64,
            // f32 -> f64 -> f32 is exact, so every rank gets the owner's point.
            candidate: unpack_candidate(&v[1..1 + CANDIDATE_LEN]),
            landed: v[11] as u64,
            pending_bytes: v[12] as u64,
            flags: Flags::from_bits(v[13] as u32),
            net: [v[14] as i64, v[15] as i64, v[16] as i64],
            delivered: v[17] as i64,
        }
    }
}

/// Why a loop stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stopped {
    /// The stop rule is met.
    Done,
    /// The strongest shooter left is below the loop's floor, or none has power.
    Floor,
    /// A rank was interrupted (the state was saved).
    Interrupted,
}

/// What one step of the loop did.
#[derive(Clone, Copy, Debug)]
pub enum Step {
    /// One shot.
    Shot(Shot),
    /// No shot: the loop is over.
    Stopped(Stopped),
}

/// The shooting loop, one shot at a time (the renderer runs it to the end;
/// the viewer steps it between its commands).
pub struct ShotLoop<'m> {
    mesh: &'m LitMesh,
    comm: &'m dyn Collectives,
    stop: StopRule,
    floor: f64,
    /// What the last shot landed on this rank's elements, fixed point.
    landed: u64,
    /// What the last shot delivered to this rank's elements, fixed point.
    delivered: i64,
    /// The power the last shot shot, until its landing is summed.
    last_power: Option<f64>,
    ff: Vec<Transfer>,
    /// Shots a step (see [`ShotLoop::batched`]); 1 is progressive
    /// refinement's one shooter at a time.
    batch: usize,
    /// Whether a batch's rows and groups are pooled ([`Deal`]).
    pooled: bool,
    /// A batch's buffers, kept from batch to batch: fresh ones cost the
    /// kernel's zeroing of their pages every batch (a fortieth of a
    /// one-core shot in cubes-b1).
    kept: BatchBuffers,
    /// What the loop measured so far.
    pub stats: LoopStats,
}

impl<'m> ShotLoop<'m> {
    /// A loop that shoots until `stop` says done, or until the strongest
    /// shooter left has less than `floor` power.
    pub fn new(mesh: &'m LitMesh, comm: &'m dyn Collectives, stop: StopRule, floor: f64) -> Self {
        Self {
            mesh,
            comm,
            stop,
            floor,
            landed: 0,
            delivered: 0,
            last_power: None,
            ff: Vec::new(),
            batch: 1,
            pooled: true,
            kept: BatchBuffers::default(),
            stats: LoopStats {
                patch_power: vec![0.0; mesh.patches.len()],
                ..LoopStats::default()
            },
        }
    }

    /// The loop shooting `batch` shooters a step (at least 1): the
    /// strongest `batch` patches are chosen at once, the ranks compute
    /// their rows (each a whole hemisphere with a source of one process; a
    /// cached row on its cache's rank, one dear row a rank, the rest taken
    /// by whichever rank comes free first: [`crate::parallel::Deal`]), and
    /// every rank lands every row on its own elements, shot by shot in the
    /// batch's order. The numbers depend on `batch`, never on the rank
    /// count or on who drew what.
    pub fn batched(mut self, batch: usize) -> Self {
        self.batch = batch.max(1);
        self
    }

    /// The loop dealing a batch's rows as `deal` says (pooled by default).
    pub fn dealing_rows(mut self, deal: crate::settings::DealRows) -> Self {
        self.pooled = deal == crate::settings::DealRows::Pool;
        self
    }

    /// Decides, with every rank, whether to go on and who shoots; then
    /// shoots. `hooks` run after the shot and say when to save or stop.
    /// In a batched loop `source` is a source of one process on every rank
    /// (whole rows), and a step shoots a batch.
    pub fn step<'s>(
        &mut self,
        source: &mut GpuFormFactors,
        solver: &mut Solver<'s>,
        hooks: &mut dyn LoopHooks<'s>,
    ) -> Result<Step, RenderError> {
        self.step_drawing(source, solver, hooks, None)
    }

    /// As [`ShotLoop::step`], with rows drawn ahead on `ahead`'s helper
    /// where given (one shot a step; see `render::ahead`).
    fn step_drawing<'s>(
        &mut self,
        source: &mut GpuFormFactors,
        solver: &mut Solver<'s>,
        hooks: &mut dyn LoopHooks<'s>,
        ahead: Option<&Ahead>,
    ) -> Result<Step, RenderError> {
        let shot_start = Instant::now();
        let votes = self.vote(source, solver, hooks);
        if let Some(power) = self.last_power.take() {
            // What the last shot landed, over every rank's elements (fixed
            // point, so the sum is exact and the same on every rank).
            let landed = votes.iter().map(|v| v.landed).sum::<u64>() as f64 / UNSHOT_ONE;
            solver.note_retention(power, landed);
            let delivered = votes.iter().map(|v| v.delivered).sum::<i64>() as f64 / UNSHOT_ONE;
            // The source's back-face share is the same on every rank.
            let back = power * source.last_blocked();
            solver.note_energy(power, delivered * solver.emitted_power(), back);
        }
        let unshot_fraction = votes.iter().map(|v| v.unshot).sum::<u64>() as f64 / UNSHOT_ONE;
        // Between shots the state decides everything that follows: the
        // place to save it, or to stop when any rank was interrupted.
        let interrupted = votes.iter().any(|v| v.flags.stop);
        if interrupted || votes[0].flags.save {
            hooks.checkpoint(solver)?;
        }
        if interrupted {
            self.stats.interrupted = true;
            return Ok(Step::Stopped(Stopped::Interrupted));
        }
        if solver.done_at(&self.stop, unshot_fraction) {
            return Ok(Step::Stopped(Stopped::Done));
        }
        // The whole solution's signed unshot power, summed exactly: every
        // rank gets the same ambient term, whatever their number.
        let mut net: NetUnshot = [0; 3];
        for v in &votes {
            for (n, x) in net.iter_mut().zip(v.net) {
                *n += x;
            }
        }
        let ambient = solver.ambient_from(net);
        if self.batch > 1 {
            return self.step_batch(
                source,
                solver,
                hooks,
                (shot_start, unshot_fraction, ambient),
            );
        }
        let best = Candidate::best(votes.iter().filter_map(|v| v.candidate));
        self.stats.select += shot_start.elapsed();
        let Some(best) = best.filter(|b| b.power >= self.floor) else {
            return Ok(Step::Stopped(Stopped::Floor));
        };
        let mut region = self.region(solver, &best, ambient);
        if source.by_transport(best.power) && !solver.overshoot() {
            self.join_group(solver, &best, &mut region);
        }
        let shot = self.shoot(source, solver, (&best, &region), ahead)?;
        self.stats.shot_times.push(shot_start.elapsed());
        hooks.after_shot(solver, unshot_fraction);
        Ok(Step::Shot(shot))
    }

    /// One step of a batched loop, after the vote: the batch's shooters,
    /// their rows (each from the rank whose turn it is), and their landing.
    fn step_batch<'s>(
        &mut self,
        source: &mut GpuFormFactors,
        solver: &mut Solver<'s>,
        hooks: &mut dyn LoopHooks<'s>,
        (shot_start, unshot_fraction, ambient): (Instant, f64, [f64; 3]),
    ) -> Result<Step, RenderError> {
        let (rank, ranks) = (self.comm.rank(), self.comm.size());
        let room = self.stop.max_shots.saturating_sub(solver.shots()) as usize;
        let batch = self.batch.min(room.max(1));
        let chosen = self.choose(source, solver, batch);
        self.stats.select += shot_start.elapsed();
        if chosen.is_empty() {
            return Ok(Step::Stopped(Stopped::Floor));
        }
        // A weak shooter along the transport shoots for its group (which
        // empties other patches' stores): it goes alone, as in a loop of
        // one shot a step, every rank making its own elements' part of the
        // (cheap) row (the source's transport ranks are the run's), its
        // landing summed at the next vote.
        if chosen.len() == 1 && source.by_transport(chosen[0].power) && !solver.overshoot() {
            let best = chosen[0];
            let mut region = self.region(solver, &best, ambient);
            self.join_group(solver, &best, &mut region);
            let shot = self.shoot(source, solver, (&best, &region), None)?;
            self.stats.shot_times.push(shot_start.elapsed());
            hooks.after_shot(solver, unshot_fraction);
            return Ok(Step::Shot(shot));
        }
        let regions: Vec<ShotRegion> = chosen
            .iter()
            .map(|c| self.region(solver, c, ambient))
            .collect();
        // Which rank draws each row: a cached row its cache's rank, one of
        // the dearest rows each rank, the rest whichever rank comes free
        // first (a pool). Only time depends on it.
        let costs: Vec<f64> = chosen
            .iter()
            .zip(&regions)
            .map(|(c, r)| source.row_cost(c.patch, r))
            .collect();
        let costs = if ranks > 1 {
            self.comm.all_gather_f64(&costs)
        } else {
            costs
        };
        let deal = Deal::new(&costs, ranks, self.pooled);
        // This rank's rows, each sent in pieces to the owners of its elements.
        let BatchBuffers {
            mut rows,
            mut outgoing,
            mut incoming,
        } = std::mem::take(&mut self.kept);
        rows.resize_with(chosen.len(), Vec::new);
        outgoing.resize_with(ranks, Vec::new);
        rows.iter_mut().for_each(Vec::clear);
        outgoing.iter_mut().for_each(Vec::clear);
        let mut sums = vec![0.0; chosen.len() * ROW_SUMS];
        let batch_start = solver.shots();
        let recorded = batch_start < MAX_ROW_RECORDS;
        // Per row: its record's place in `stats.rows`, its split shot's
        // groups, and whether this rank drew it.
        let mut record_of = vec![usize::MAX; chosen.len()];
        let mut groups = vec![0u32; chosen.len()];
        let mut drew = vec![false; chosen.len()];
        for k in deal.taken(self.comm) {
            let (c, region) = (&chosen[k], &regions[k]);
            drew[k] = true;
            let cpu = crate::parallel::process_cpu_seconds();
            match source.start_row(c.patch, region, &mut self.ff)? {
                Started::Row => {
                    let out = (&mut outgoing[..], &mut rows[..], &mut sums[..]);
                    self.send_row(solver, source, (c.patch, k, region.shoot), out);
                }
                Started::Split(n) => groups[k] = n as u32,
            }
            let cpu_seconds = crate::parallel::process_cpu_seconds() - cpu;
            self.stats.rows_cpu_seconds += cpu_seconds;
            if recorded {
                record_of[k] = self.stats.rows.len();
                self.stats.rows.push(RowRecord {
                    batch_start,
                    index: k as u32,
                    round: 0,
                    cost: costs.get(rank * chosen.len() + k).copied().unwrap_or(1.0),
                    cpu_seconds,
                });
            }
        }
        // A shooter's penumbra is its last row's, which another rank may
        // have drawn: the passes sum every rank's (see `refined_mesh`).
        for (c, _) in chosen.iter().zip(&drew).filter(|(_, &d)| !d) {
            source.forget_penumbra(c.patch);
        }
        self.split_round(
            (source, solver),
            (&chosen, &regions, &drew),
            (groups, &record_of),
            (&mut outgoing, &mut rows, &mut sums),
        )?;
        let t = Instant::now();
        let cpu = crate::parallel::CpuSpan::start(self.comm);
        let starts = self.comm.all_to_all_u32_into(&outgoing, &mut incoming);
        // Each shot's sums come from one rank; the others add exact zeros.
        let all_sums = self.comm.all_gather_f64(&sums);
        source.timings.exchange += t.elapsed();
        let parts = starts.windows(2).filter_map(|w| incoming.get(w[0]..w[1]));
        unpack_rows(parts, &mut rows, &regions);
        let landing_start = Instant::now();
        let mut totals = vec![0.0; sums.len()];
        for part in all_sums.chunks_exact(sums.len().max(1)) {
            for (t, x) in totals.iter_mut().zip(part) {
                *t += x;
            }
        }
        // Every shooter gives up its store before any shot lands, so light
        // one of them lands on another stays for a later batch.
        let shares: Vec<[f64; 3]> = chosen
            .iter()
            .zip(&regions)
            .map(|(c, r)| solver.take_shooter(c, r))
            .collect();
        let mut last = None;
        for (k, (c, region)) in chosen.iter().zip(&regions).enumerate() {
            let mut shot = solver.land(c, region, &rows[k], shares[k]);
            let s = &totals[k * ROW_SUMS..(k + 1) * ROW_SUMS];
            shot.form_factor_sum = s[3];
            self.after_landing(solver, c, shot, [s[0], s[1], s[2], s[3]]);
            last = Some(shot);
        }
        self.stats.update += landing_start.elapsed();
        if let Some(b) = source.busy_cpu.last_mut() {
            *b += cpu.own(self.comm);
        }
        let per_shot = shot_start.elapsed() / chosen.len() as u32;
        self.stats
            .shot_times
            .extend(std::iter::repeat_n(per_shot, chosen.len()));
        hooks.after_shot(solver, unshot_fraction);
        self.kept = BatchBuffers {
            rows,
            outgoing,
            incoming,
        };
        Ok(last.map_or(Step::Stopped(Stopped::Floor), Step::Shot))
    }

    /// Row `k` of a batch (shooter `patch`, shooting `shoot` as a whole),
    /// just made in `self.ff`: its sums noted and its transfers packed for
    /// their owners.
    fn send_row(
        &self,
        solver: &Solver,
        source: &GpuFormFactors,
        (patch, k, shoot): (u32, usize, [f64; 3]),
        (outgoing, rows, sums): BatchOut<'_>,
    ) {
        let s = row_sums(solver, patch, &self.ff, source.last_blocked());
        sums[k * ROW_SUMS..(k + 1) * ROW_SUMS].copy_from_slice(&s);
        pack_row(
            solver,
            (k, self.comm.rank(), shoot),
            &self.ff,
            outgoing,
            &mut rows[k],
        );
    }

    /// A batch's second round: the groups of its split shots (`groups[k]`
    /// of row k, started by its drawer, the rank with `drew[k]`), dealt
    /// over every rank as work of their own, sent to the rows' drawers, who
    /// assemble the rows (in group order: the bits of a shot drawn whole)
    /// and pack them as the first round's.
    fn split_round<'s>(
        &mut self,
        (source, solver): (&mut GpuFormFactors, &mut Solver<'s>),
        (chosen, regions, drew): (&[Candidate], &[ShotRegion], &[bool]),
        (groups, record_of): (Vec<u32>, &[usize]),
        (outgoing, rows, sums): BatchOut<'_>,
    ) -> Result<(), RenderError> {
        let (rank, ranks) = (self.comm.rank(), self.comm.size());
        let (groups, drawer) = if ranks > 1 {
            // A row's drawer tells its groups plus one, the others 0: which
            // rank drew a pooled row is learnt here.
            let marks: Vec<u32> = groups
                .iter()
                .zip(drew)
                .map(|(&g, &d)| if d { g + 1 } else { 0 })
                .collect();
            let lengths = vec![marks.len(); ranks];
            let mut all = vec![0u32; marks.len()];
            let mut drawer = vec![0usize; marks.len()];
            for (r, part) in self
                .comm
                .all_gather_u32(&marks, Some(&lengths))
                .into_iter()
                .enumerate()
            {
                for (k, m) in part.into_iter().enumerate() {
                    if m > 0 {
                        all[k] = m - 1;
                        drawer[k] = r;
                    }
                }
            }
            (all, drawer)
        } else {
            let n = groups.len();
            (groups, vec![0; n])
        };
        let units: Vec<(usize, usize)> = groups
            .iter()
            .enumerate()
            .flat_map(|(k, &n)| (0..n as usize).map(move |g| (k, g)))
            .collect();
        if units.is_empty() {
            return Ok(());
        }
        let batch_start = solver.shots();
        // Every rank weighs a group alike.
        let weights: Vec<f64> = units
            .iter()
            .map(|&(k, _)| source.group_cost(chosen[k].patch, &regions[k]))
            .collect();
        let all_weights: Vec<f64> = (0..ranks).flat_map(|_| weights.iter().copied()).collect();
        let deal = Deal::new(&all_weights, ranks, self.pooled);
        let mut parts_out = vec![Vec::new(); ranks];
        for u in deal.taken(self.comm) {
            let (k, g) = units[u];
            let cpu = crate::parallel::process_cpu_seconds();
            let part = source.group_part(chosen[k].patch, &regions[k], g)?;
            part.pack(k, g, &mut parts_out[drawer[k]]);
            let cpu_seconds = crate::parallel::process_cpu_seconds() - cpu;
            self.stats.rows_cpu_seconds += cpu_seconds;
            if batch_start < MAX_ROW_RECORDS {
                self.stats.rows.push(RowRecord {
                    batch_start,
                    index: u as u32,
                    round: 1,
                    cost: weights[u],
                    cpu_seconds,
                });
            }
        }
        let t = Instant::now();
        let incoming = if ranks > 1 {
            self.comm.all_to_all_u32(&parts_out)
        } else {
            parts_out
        };
        source.timings.exchange += t.elapsed();
        let columns = |k: usize| {
            chosen
                .get(k)
                .map_or(0, |c| self.mesh.patches[c.patch as usize].elements.len())
        };
        let mut parts: Vec<Vec<(usize, GroupPart)>> = vec![Vec::new(); chosen.len()];
        for words in &incoming {
            let unpacked = GroupPart::unpack(words, columns).ok_or_else(|| {
                RenderError::SplitShot(u32::MAX, "a part cut short in transit".into())
            })?;
            for (k, g, part) in unpacked {
                if let Some(p) = parts.get_mut(k) {
                    p.push((g, part));
                }
            }
        }
        for (k, mut mine) in parts.into_iter().enumerate() {
            if groups[k] == 0 || drawer[k] != rank {
                continue;
            }
            let cpu = crate::parallel::process_cpu_seconds();
            let (c, region) = (&chosen[k], &regions[k]);
            mine.sort_by_key(|p| p.0);
            let in_order: Vec<&GroupPart> = mine.iter().map(|p| &p.1).collect();
            source.finish_row(c.patch, region, &in_order, &mut self.ff)?;
            self.send_row(
                solver,
                source,
                (c.patch, k, region.shoot),
                (&mut *outgoing, &mut *rows, &mut *sums),
            );
            let cpu_seconds = crate::parallel::process_cpu_seconds() - cpu;
            self.stats.rows_cpu_seconds += cpu_seconds;
            if let Some(r) = record_of.get(k).and_then(|&i| self.stats.rows.get_mut(i)) {
                r.cpu_seconds += cpu_seconds;
            }
        }
        Ok(())
    }

    /// The batch's shooters: every rank's strongest `batch` patches
    /// gathered, the strongest `batch` of them (the lowest patch on ties),
    /// above the floor, and up to the first that shoots along the transport
    /// (which goes alone).
    fn choose(&self, source: &GpuFormFactors, solver: &Solver, batch: usize) -> Vec<Candidate> {
        let mut mine = vec![-1.0; batch * CANDIDATE_LEN];
        for (slot, c) in mine
            .chunks_exact_mut(CANDIDATE_LEN)
            .zip(solver.local_top(batch))
        {
            slot.copy_from_slice(&pack_candidate(&c));
        }
        let all = self.comm.all_gather_f64(&mine);
        let mut chosen: Vec<Candidate> = all
            .chunks_exact(CANDIDATE_LEN)
            .filter_map(unpack_candidate)
            .collect();
        chosen.sort_by(|a, b| b.power.total_cmp(&a.power).then(a.patch.cmp(&b.patch)));
        chosen.truncate(batch);
        chosen.retain(|c| c.power >= self.floor);
        if !solver.overshoot() {
            if let Some(at) = chosen.iter().position(|c| source.by_transport(c.power)) {
                chosen.truncate(at.max(1));
            }
        }
        chosen
    }

    /// A batched shot's bookkeeping once landed: its energy (from the
    /// whole row's sums) and the loop's statistics.
    fn after_landing(
        &mut self,
        solver: &mut Solver,
        best: &Candidate,
        shot: Shot,
        [landed, delivered, blocked, _]: [f64; ROW_SUMS],
    ) {
        solver.note_retention(shot.shot_power, landed / UNSHOT_ONE);
        let emitted = solver.emitted_power();
        solver.note_energy(
            shot.shot_power,
            delivered / UNSHOT_ONE * emitted,
            shot.shot_power * blocked,
        );
        self.stats.patch_power[best.patch as usize] += shot.power;
    }

    /// Every rank's vote, in rank order (one collective), after which the
    /// last shot's cache row is settled.
    fn vote<'s>(
        &self,
        source: &mut GpuFormFactors,
        solver: &Solver<'s>,
        hooks: &dyn LoopHooks<'s>,
    ) -> Vec<Vote> {
        let (unshot, candidate) = solver.local_vote();
        let mine = Vote {
            unshot,
            candidate,
            landed: self.landed,
            delivered: self.delivered,
            pending_bytes: source.pending_bytes(),
            flags: hooks.flags(),
            // Only overshooting needs the ambient term during the loop.
            net: if solver.overshoot() {
                solver.local_net_unshot()
            } else {
                [0; 3]
            },
        };
        let all = self.comm.all_gather_f64(&mine.pack());
        let votes: Vec<Vote> = all.chunks_exact(Vote::LEN).map(Vote::unpack).collect();
        if self.comm.size() > 1 {
            source.settle_cache(votes.iter().map(|v| v.pending_bytes).sum());
        }
        votes
    }

    /// How `best` shoots. Only the owner of a weighted shooter knows what
    /// each of its elements shoots: it tells the others (all know how many
    /// there are).
    fn region(&self, solver: &Solver, best: &Candidate, ambient: [f64; 3]) -> ShotRegion {
        if !best.weighted {
            return solver.candidate_region(best, ambient);
        }
        let rank = self.comm.rank();
        let owner = solver.patch_rank(best.patch);
        let m = self.mesh.patches[best.patch as usize].elements.len();
        let mut mine = vec![0.0; 3 * m + 3];
        if rank == owner {
            let r = solver.shooting_region(best.patch, ambient);
            mine[..3].copy_from_slice(&r.shoot);
            for n in 0..m {
                mine[3 + 3 * n..6 + 3 * n].copy_from_slice(r.elements.get(n).unwrap_or(&r.shoot));
            }
        }
        let all = self.comm.all_gather_f64(&mine);
        let theirs = &all[owner * (3 * m + 3)..(owner + 1) * (3 * m + 3)];
        let elements = theirs[3..]
            .chunks_exact(3)
            .map(|x| [x[0], x[1], x[2]])
            .collect();
        ShotRegion::new(
            best.centre,
            best.power,
            [theirs[0], theirs[1], theirs[2]],
            elements,
        )
    }

    /// A weak shooter along the transport shoots for its whole group (its
    /// cluster of patches, in a mesh of more than `ambient::PATCH_GROUPS`
    /// patches): the other members' unshot power, summed exactly over the
    /// ranks (fixed point), joins `region` as if `best` held it, and the
    /// members' stores are emptied before the shot lands (light landing
    /// back on them stays). Members whose emission is unshot wait for their
    /// own shot (its first shot is the solution's direct part). So weak
    /// shots scale with the clusters, not the patches.
    fn join_group(&self, solver: &mut Solver, best: &Candidate, region: &mut ShotRegion) {
        let transport = self.mesh.ambient_transport();
        let members: Vec<u32> = transport
            .patches_of(transport.group_of(best.patch))
            .iter()
            .copied()
            .filter(|&p| p != best.patch && !solver.emission_unshot(p))
            .collect();
        if members.is_empty() {
            return;
        }
        let mine = solver.net_unshot_of(&members).map(|x| x as f64);
        let all = self.comm.all_gather_f64(&mine);
        let mut net = [0i64; 3];
        for rank in all.chunks_exact(3) {
            for (n, x) in net.iter_mut().zip(rank) {
                *n += *x as i64;
            }
        }
        let area = self.mesh.patches[best.patch as usize].area;
        let emitted = solver.emitted_power();
        for (s, n) in region.shoot.iter_mut().zip(net) {
            *s += n as f64 / UNSHOT_ONE * emitted / area;
        }
        // `region.power` stays the shooter's: it chose the transport, and
        // the source asks it again. The transport shoots the mean only.
        region.elements.clear();
        solver.clear_unshot(&members);
    }

    /// Gets the form factors of `best`'s shot and distributes it.
    fn shoot(
        &mut self,
        source: &mut GpuFormFactors,
        solver: &mut Solver,
        (best, region): (&Candidate, &ShotRegion),
        ahead: Option<&Ahead>,
    ) -> Result<Shot, RenderError> {
        match ahead {
            Some(ahead) => {
                // Asked only of a shot that draws, while drawing ahead.
                let next = |source: &GpuFormFactors| runners_up(source, solver, best.patch);
                ahead.form_factors(source, (best.patch, region), next, &mut self.ff)?;
            }
            None => source.form_factors(best.patch, region, &mut self.ff)?,
        }
        let t = Instant::now();
        let cpu = crate::parallel::CpuSpan::start(self.comm);
        let cores = ahead.map_or_else(crate::parallel::cores, Ahead::cores_now);
        let shot =
            crate::parallel::with_cores(cores, || solver.shoot_candidate(best, region, &self.ff));
        let dt = t.elapsed();
        if let Some(b) = source.busy_cpu.last_mut() {
            *b += cpu.own(self.comm);
        }
        (self.landed, self.delivered) = shot.landed;
        self.last_power = Some(shot.shot_power);
        self.stats.update += dt;
        self.stats.patch_power[best.patch as usize] += shot.power;
        if let Some(b) = source.busy.last_mut() {
            *b += dt.as_secs_f64();
        }
        Ok(shot)
    }
}

/// What the transfers `ff` of `shooter`'s shot land and deliver, over the
/// emitted power, in [`UNSHOT_ONE`] fixed point: each element's share
/// rounded on its own, so that sums over any split of the elements agree.
fn landing<'t>(
    solver: &Solver,
    shooter: u32,
    ff: impl Iterator<Item = &'t Transfer>,
) -> (u64, i64) {
    let emitted = solver.emitted_power();
    let area = solver.mesh().patches[shooter as usize].area;
    let (mut landed, mut delivered) = (0u64, 0i64);
    for t in ff {
        let (l, d) = crate::solver::landing_share(t, area, emitted);
        landed += l;
        delivered += d;
    }
    (landed, delivered)
}

/// f64 slots of a candidate in a batch's gather.
const CANDIDATE_LEN: usize = 10;

/// A candidate as f64 slots (every field travels exactly).
fn pack_candidate(c: &Candidate) -> [f64; CANDIDATE_LEN] {
    [
        c.patch as f64,
        c.power,
        c.unshot[0],
        c.unshot[1],
        c.unshot[2],
        c.centre.x as f64,
        c.centre.y as f64,
        c.centre.z as f64,
        c.weighted as u8 as f64,
        c.lit,
    ]
}

/// A slot's candidate, `None` for an empty slot.
fn unpack_candidate(v: &[f64]) -> Option<Candidate> {
    (v[0] >= 0.0).then(|| Candidate {
        patch: v[0] as u32,
        power: v[1],
        unshot: [v[2], v[3], v[4]],
        centre: glam::Vec3::new(v[5] as f32, v[6] as f32, v[7] as f32),
        weighted: v[8] != 0.0,
        lit: v[9],
    })
}

/// A whole row's sums a batched shot's energy needs: what it landed and
/// delivered ([`landing`]), the share that met back faces, and the sum of
/// its form factors.
const ROW_SUMS: usize = 4;

fn row_sums(solver: &Solver, shooter: u32, ff: &[Transfer], blocked: f64) -> [f64; ROW_SUMS] {
    let (landed, delivered) = landing(solver, shooter, ff.iter());
    let sum = ff.iter().map(|t| t.form_factor).sum();
    [landed as f64, delivered as f64, blocked, sum]
}

/// Words a transfer takes in a batch's exchange: its element, then the
/// form factor's and each channel's radiosity's f64 bits, two words each.
const TRANSFER_WORDS: usize = 9;

/// Words a transfer of a uniform shot takes: its element and the form
/// factor's bits. Its radiosities are F times what the patch shoots, which
/// every rank knows (the batch's regions), so the owner makes them again,
/// to the same bits.
const UNIFORM_WORDS: usize = 3;

/// A row's header bit saying its transfers travel as [`UNIFORM_WORDS`].
const UNIFORM_ROW: u32 = 1 << 31;

/// Appends `x`'s bits as two words, low first.
fn push_bits(out: &mut Vec<u32>, x: f64) {
    let b = x.to_bits();
    out.push(b as u32);
    out.push((b >> 32) as u32);
}

/// The f64 whose bits [`push_bits`] wrote at `w[0..2]`.
fn from_words(w: &[u32]) -> f64 {
    f64::from_bits(u64::from(w[0]) | u64::from(w[1]) << 32)
}

/// What a uniform shot of `shoot` sends a receiver of form factor `f`.
fn uniform(f: f64, shoot: [f64; 3]) -> [f64; 3] {
    shoot.map(|s| f * s)
}

/// Splits shot `k`'s row, computed on rank `rank`, between its elements'
/// owners: this rank's transfers to `own`, the others' appended to their
/// words as the shot's index and its transfer count, then
/// [`TRANSFER_WORDS`] words a transfer (36 bytes: the element once, not
/// once per value), or [`UNIFORM_WORDS`] (12 bytes, marked by
/// [`UNIFORM_ROW`]) when every transfer's radiosities are, bit for bit,
/// its form factor times `shoot` (a patch shooting uniformly).
fn pack_row(
    solver: &Solver,
    (k, rank, shoot): (usize, usize, [f64; 3]),
    ff: &[Transfer],
    outgoing: &mut [Vec<u32>],
    own: &mut Vec<Transfer>,
) {
    let bits = |r: [f64; 3]| r.map(f64::to_bits);
    let compact = ff
        .iter()
        .all(|t| bits(t.radiosity) == bits(uniform(t.form_factor, shoot)));
    let (mark, words) = if compact {
        (UNIFORM_ROW, UNIFORM_WORDS)
    } else {
        (0, TRANSFER_WORDS)
    };
    let starts: Vec<usize> = outgoing.iter().map(Vec::len).collect();
    for (r, out) in outgoing.iter_mut().enumerate() {
        if r != rank {
            out.extend([k as u32 | mark, 0]);
        }
    }
    for t in ff {
        let r = solver.element_rank(t.element);
        if r == rank {
            own.push(*t);
            continue;
        }
        let out = &mut outgoing[r];
        out.push(t.element);
        push_bits(out, t.form_factor);
        if !compact {
            for c in t.radiosity {
                push_bits(out, c);
            }
        }
    }
    for (r, (out, start)) in outgoing.iter_mut().zip(starts).enumerate() {
        if r != rank {
            out[start + 1] = ((out.len() - start - 2) / words) as u32;
        }
    }
}

/// Adds the rows [`pack_row`] sent this rank to `rows`, by shot (each in
/// its row's order), from every rank's words; `regions[k]` is how shot k
/// shoots.
fn unpack_rows<'w>(
    incoming: impl Iterator<Item = &'w [u32]>,
    rows: &mut [Vec<Transfer>],
    regions: &[ShotRegion],
) {
    for words in incoming {
        let mut at = 0;
        while let [head, count, ..] = words[at..] {
            let (k, count) = ((head & !UNIFORM_ROW) as usize, count as usize);
            let compact = head & UNIFORM_ROW != 0;
            let size = if compact {
                UNIFORM_WORDS
            } else {
                TRANSFER_WORDS
            };
            at += 2;
            let Some(body) = words.get(at..at + size * count) else {
                break;
            };
            let (Some(row), Some(region)) = (rows.get_mut(k), regions.get(k)) else {
                break;
            };
            row.extend(body.chunks_exact(size).map(|t| {
                let form_factor = from_words(&t[1..3]);
                Transfer {
                    element: t[0],
                    form_factor,
                    radiosity: if compact {
                        uniform(form_factor, region.shoot)
                    } else {
                        [3, 5, 7].map(|c| from_words(&t[c..c + 2]))
                    },
                }
            }));
            at += size * count;
        }
    }
}

/// Shoots until the loop stops (see [`ShotLoop`]), as `opts` says: its
/// stop rule, its batch and how a batch's rows are dealt. The final solve
/// and the refinement passes both shoot here (with `source` from
/// [`GpuFormFactors::for_solve`]), shooting no shooter below `floor`; `ahead`: whether rows may be drawn
/// ahead where [`Ahead::applies`] (the final solve; a pass measures the
/// penumbrae of the rows its source draws, so it draws each in its shot).
pub fn shoot_until<'m>(
    mesh: &'m LitMesh,
    opts: &RenderOptions,
    (floor, ahead): (f64, bool),
    comm: &dyn Collectives,
    source: &mut GpuFormFactors,
    solver: &mut Solver<'m>,
    hooks: &mut dyn LoopHooks<'m>,
) -> Result<LoopStats, RenderError> {
    let mut shots = ShotLoop::new(mesh, comm, opts.stop, floor)
        .batched(opts.batch)
        .dealing_rows(opts.deal_rows);
    if ahead && Ahead::applies(opts, comm.size()) {
        Ahead::run(opts, source, |ahead, source| {
            while let Step::Shot(_) = shots.step_drawing(source, solver, hooks, Some(ahead))? {}
            Ok(())
        })?;
    } else {
        while let Step::Shot(_) = shots.step(source, solver, hooks)? {}
    }
    Ok(shots.stats)
}

/// The rows wanted after `shooter`'s: those of the vote's runners-up that
/// would draw (most likely first), keyed as their shots would key them.
fn runners_up(
    source: &GpuFormFactors,
    solver: &Solver,
    shooter: u32,
) -> Vec<(crate::render::cache::RowKey, glam::Vec3)> {
    solver
        .local_top(RUNNERS_UP + 1)
        .into_iter()
        .filter(|c| c.patch != shooter)
        .take(RUNNERS_UP)
        .filter_map(|c| {
            source
                .drawn_key(c.patch, c.centre, c.power)
                .map(|key| (key, c.centre))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vote_travels_exactly() {
        let c = Candidate {
            patch: 4_000_000,
            power: 0.1234567890123,
            unshot: [1.0, -2.5, 1e-300],
            centre: glam::Vec3::new(0.1, -7.3, 1e6),
            weighted: true,
            lit: 0.75,
        };
        for vote in [
            Vote {
                unshot: (1 << 52) + 7,
                candidate: Some(c),
                landed: (1 << 50) + 3,
                pending_bytes: 1 << 40,
                flags: Flags {
                    stop: true,
                    save: false,
                },
                net: [-(1 << 45), 3, 0],
                delivered: -(1 << 51) + 9,
            },
            Vote {
                flags: Flags {
                    stop: false,
                    save: true,
                },
                ..Vote::default()
            },
        ] {
            assert_eq!(Vote::unpack(&vote.pack()), vote);
        }
    }

    #[test]
    fn rows_travel_exactly_and_uniform_ones_in_a_third() {
        let mesh = LitMesh::unlit(crate::mesh::unit_square(64, 2));
        let solver = Solver::partitioned(&mesh, 0, 2);
        let shoot = [0.3, 0.7, 1e-9];
        let uniform_row: Vec<Transfer> = (0..mesh.elements.len() as u32)
            .map(|j| {
                let f = 1.0 / (1.0 + f64::from(j));
                Transfer {
                    element: j,
                    form_factor: f,
                    radiosity: uniform(f, shoot),
                }
            })
            .collect();
        // One transfer not F times the patch's (a shooter weighted by
        // element), and one whose zero's sign differs: both rows go whole.
        let mut weighted = uniform_row.clone();
        weighted[4000].radiosity[1] *= 1.5;
        let mut signed = uniform_row.clone();
        signed[4001].radiosity = [-0.0, 0.0, 0.0];
        signed[4001].form_factor = 0.0;
        let rows_in = [uniform_row, weighted, signed];
        let (mut outgoing, mut own) = (vec![Vec::new(); 2], vec![Vec::new(); 3]);
        for (k, row) in rows_in.iter().enumerate() {
            pack_row(&solver, (k, 0, shoot), row, &mut outgoing, &mut own[k]);
        }
        assert!(outgoing[0].is_empty(), "nothing to itself");
        let theirs = |row: &[Transfer]| -> Vec<Transfer> {
            row.iter()
                .filter(|t| solver.element_rank(t.element) == 1)
                .copied()
                .collect()
        };
        let n = theirs(&rows_in[0]).len();
        assert!(
            n > 1000 && n < mesh.elements.len() - 1000,
            "both ranks own some"
        );
        assert_eq!(
            outgoing[1].len(),
            3 * 2 + n * (UNIFORM_WORDS + 2 * TRANSFER_WORDS),
            "the uniform row in 12 bytes a transfer, the others in 36"
        );
        let regions = vec![
            ShotRegion {
                shoot,
                ..ShotRegion::default()
            };
            3
        ];
        let mut rows = vec![Vec::new(); 3];
        let sent: [&[u32]; 2] = [&[], &outgoing[1]];
        unpack_rows(sent.into_iter(), &mut rows, &regions);
        let bits = |row: &[Transfer]| -> Vec<(u32, u64, [u64; 3])> {
            row.iter()
                .map(|t| {
                    let r = t.radiosity.map(f64::to_bits);
                    (t.element, t.form_factor.to_bits(), r)
                })
                .collect()
        };
        for k in 0..3 {
            assert_eq!(bits(&rows[k]), bits(&theirs(&rows_in[k])), "row {k}");
            let mine: Vec<Transfer> = rows_in[k]
                .iter()
                .filter(|t| solver.element_rank(t.element) == 0)
                .copied()
                .collect();
            assert_eq!(bits(&own[k]), bits(&mine), "row {k}, kept");
        }
    }
}
