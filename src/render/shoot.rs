//! The shooting loop: progressive refinement (DESIGN.md section 2) over the
//! ranks of a [`Collectives`]. Before every shot one all-gather of each
//! rank's [`Vote`] decides the stop rule, the shooter, the ambient term, the
//! cache and whether to save or stop; so every rank makes the same decision
//! at the same shot.

use super::ahead::{Ahead, RUNNERS_UP};
use super::options::{RenderError, RenderOptions};
use super::source::{GpuFormFactors, GroupPart, Started};
use crate::lit_mesh::LitMesh;
use crate::parallel::Collectives;
use crate::solver::{
    Candidate, FormFactorSource, Shot, ShotRegion, Solver, StopRule, Transfer, UNSHOT_ONE,
};
use std::time::{Duration, Instant};

mod batch;
use batch::{BatchBuffers, ROW_SUMS};

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
    /// It stopped because the scene loses almost no light, so it cannot
    /// converge ([`LOSSLESS_SHOTS`]).
    pub lossless: bool,
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
    /// The power the last shot delivered to its elements, over the emitted
    /// power, signed fixed point.
    delivered: i64,
}

impl Vote {
    /// f64 slots a vote takes in the all-gather. Every integer is below
    /// 2^53, so it travels exactly.
    const LEN: usize = 14;

    fn pack(&self) -> [f64; Self::LEN] {
        let mut v = [0.0; Self::LEN];
        v[0] = self.unshot as f64;
        v[1] = -1.0;
        if let Some(c) = self.candidate {
            v[1..1 + CANDIDATE_LEN].copy_from_slice(&pack_candidate(&c));
        }
        v[10] = self.landed as f64;
        v[11] = self.pending_bytes as f64;
        v[12] = self.flags.bits() as f64;
        v[13] = self.delivered as f64;
        v
    }

    fn unpack(v: &[f64]) -> Self {
        Self {
            unshot: v[0] as u64,
            // f32 -> f64 -> f32 is exact, so every rank gets the owner's point.
            candidate: unpack_candidate(&v[1..1 + CANDIDATE_LEN]),
            landed: v[10] as u64,
            pending_bytes: v[11] as u64,
            flags: Flags::from_bits(v[12] as u32),
            delivered: v[13] as i64,
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
    /// The scene keeps almost all its light ([`LOSSLESS_SHOTS`]).
    Lossless,
}

/// After this many shots, a solve that still holds at least
/// [`LOSSLESS_UNSHOT`] of the emitted power unshot stops: its surfaces
/// reflect (nearly) everything in a closed scene, and it would run to the
/// shot cap. Real rooms have lost far more by then (every surface under
/// 0.95 loses 5 % of every shot). A function of the state, so the same on
/// any rank count and on resuming.
pub const LOSSLESS_SHOTS: u64 = 2000;

/// See [`LOSSLESS_SHOTS`].
pub const LOSSLESS_UNSHOT: f64 = 0.9;

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
            kept: BatchBuffers::default(),
            stats: LoopStats {
                patch_power: vec![0.0; mesh.patches.len()],
                ..LoopStats::default()
            },
        }
    }

    /// The loop shooting `batch` shooters a step (at least 1): the
    /// strongest `batch` patches are chosen at once, the ranks compute
    /// their rows (each a whole hemisphere with a source of one process,
    /// dealt by [`crate::parallel::assign_rows`]: a cached row on its
    /// cache's rank, the rest to even the ranks' costs), and
    /// every rank lands every row on its own elements, shot by shot in the
    /// batch's order. The numbers depend on `batch`, never on the rank
    /// count or on who drew what.
    pub fn batched(mut self, batch: usize) -> Self {
        self.batch = batch.max(1);
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
        if solver.shots() >= LOSSLESS_SHOTS && unshot_fraction >= LOSSLESS_UNSHOT {
            self.stats.lossless = true;
            return Ok(Step::Stopped(Stopped::Lossless));
        }
        if self.batch > 1 {
            return self.step_batch(source, solver, hooks, (shot_start, unshot_fraction));
        }
        let best = Candidate::best(votes.iter().filter_map(|v| v.candidate));
        self.stats.select += shot_start.elapsed();
        let Some(best) = best.filter(|b| b.power >= self.floor) else {
            return Ok(Step::Stopped(Stopped::Floor));
        };
        let mut region = self.region(solver, &best);
        if source.by_transport(best.power) {
            self.join_group(solver, &best, &mut region);
        }
        let shot = self.shoot(source, solver, (&best, &region), ahead)?;
        self.stats.shot_times.push(shot_start.elapsed());
        hooks.after_shot(solver, unshot_fraction);
        Ok(Step::Shot(shot))
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
        if let Some(at) = chosen.iter().position(|c| source.by_transport(c.power)) {
            chosen.truncate(at.max(1));
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
    fn region(&self, solver: &Solver, best: &Candidate) -> ShotRegion {
        if !best.weighted {
            return solver.candidate_region(best);
        }
        let rank = self.comm.rank();
        let owner = solver.patch_rank(best.patch);
        let m = self.mesh.patches[best.patch as usize].elements.len();
        let mut mine = vec![0.0; 3 * m + 3];
        if rank == owner {
            let r = solver.shooting_region(best.patch);
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
const CANDIDATE_LEN: usize = 9;

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
    })
}

/// Shoots until the loop stops (see [`ShotLoop`]), as `opts` says: its
/// stop rule, its batch and how a batch's rows are dealt. The final solve
/// and the refinement passes both shoot here (with `source` from
/// [`GpuFormFactors::for_solve`]), shooting no shooter below `floor`; `ahead`: whether rows may be drawn
/// ahead where [`Ahead::applies`] (the final solve; a pass measures the
/// penumbrae of the rows its source draws, so it draws each in its shot).
pub fn shoot_until<'m>(
    opts: &RenderOptions,
    comm: &dyn Collectives,
    until: Until,
    source: &mut GpuFormFactors,
    solver: &mut Solver<'m>,
    hooks: &mut dyn LoopHooks<'m>,
) -> Result<LoopStats, RenderError> {
    let mut shots = ShotLoop::new(solver.mesh(), comm, opts.stop, until.floor).batched(opts.batch);
    if until.draw_ahead && Ahead::applies(opts, comm.size()) {
        Ahead::run(opts, source, |ahead, source| {
            while let Step::Shot(_) = shots.step_drawing(source, solver, hooks, Some(ahead))? {}
            Ok(())
        })?;
    } else {
        while let Step::Shot(_) = shots.step(source, solver, hooks)? {}
    }
    Ok(shots.stats)
}

/// Where [`shoot_until`] stops besides its stop rule, and how it draws.
#[derive(Clone, Copy, Debug)]
pub struct Until {
    /// No shooter weaker than this shoots (W; 0: any).
    pub floor: f64,
    /// Whether rows of the likely next shooters may be drawn beside the
    /// shot ([`Ahead`]: only the final solve; a refinement pass reads the
    /// penumbrae its own source measured).
    pub draw_ahead: bool,
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
    use super::batch::{pack_row, uniform, unpack_rows, TRANSFER_WORDS, UNIFORM_WORDS};
    use super::*;

    #[test]
    fn a_vote_travels_exactly() {
        let c = Candidate {
            patch: 4_000_000,
            power: 0.1234567890123,
            unshot: [1.0, -2.5, 1e-300],
            centre: glam::Vec3::new(0.1, -7.3, 1e6),
            weighted: true,
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
