//! The shooting loop: progressive refinement (DESIGN.md section 2) over the
//! ranks of a [`Collectives`]. Before every shot one all-gather of each
//! rank's [`Vote`] decides the stop rule, the shooter, the ambient term, the
//! cache and whether to save or stop; so every rank makes the same decision
//! at the same shot.

use super::options::RenderError;
use super::source::GpuFormFactors;
use crate::mesh::Mesh;
use crate::parallel::{patch_owner, Collectives};
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
            v[1..10].copy_from_slice(&[
                c.patch as f64,
                c.power,
                c.unshot[0],
                c.unshot[1],
                c.unshot[2],
                c.centre.x as f64,
                c.centre.y as f64,
                c.centre.z as f64,
                c.weighted as u8 as f64,
            ]);
            v[13] = c.lit;
        }
        v[10] = self.landed as f64;
        v[11] = self.pending_bytes as f64;
        v[12] = self.flags.bits() as f64;
        v[14..17].copy_from_slice(&self.net.map(|x| x as f64));
        v[17] = self.delivered as f64;
        v
    }

    fn unpack(v: &[f64]) -> Self {
        Self {
            unshot: v[0] as u64,
            candidate: (v[1] >= 0.0).then(|| Candidate {
                patch: v[1] as u32,
                power: v[2],
                unshot: [v[3], v[4], v[5]],
                // f32 -> f64 -> f32 is exact, so every rank gets the owner's point.
                centre: glam::Vec3::new(v[6] as f32, v[7] as f32, v[8] as f32),
                weighted: v[9] != 0.0,
                lit: v[13],
            }),
            landed: v[10] as u64,
            pending_bytes: v[11] as u64,
            flags: Flags::from_bits(v[12] as u32),
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
    mesh: &'m Mesh,
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
    /// What the loop measured so far.
    pub stats: LoopStats,
}

impl<'m> ShotLoop<'m> {
    /// A loop that shoots until `stop` says done, or until the strongest
    /// shooter left has less than `floor` power.
    pub fn new(mesh: &'m Mesh, comm: &'m dyn Collectives, stop: StopRule, floor: f64) -> Self {
        Self {
            mesh,
            comm,
            stop,
            floor,
            landed: 0,
            delivered: 0,
            last_power: None,
            ff: Vec::new(),
            stats: LoopStats {
                patch_power: vec![0.0; mesh.patches.len()],
                ..LoopStats::default()
            },
        }
    }

    /// Decides, with every rank, whether to go on and who shoots; then
    /// shoots. `hooks` run after the shot and say when to save or stop.
    pub fn step<'s>(
        &mut self,
        source: &mut GpuFormFactors,
        solver: &mut Solver<'s>,
        hooks: &mut dyn LoopHooks<'s>,
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
        let best = Candidate::best(votes.iter().filter_map(|v| v.candidate));
        self.stats.select += shot_start.elapsed();
        let Some(best) = best.filter(|b| b.power >= self.floor) else {
            return Ok(Step::Stopped(Stopped::Floor));
        };
        // The whole solution's signed unshot power, summed exactly: every
        // rank gets the same ambient term, whatever their number.
        let mut net: NetUnshot = [0; 3];
        for v in &votes {
            for (n, x) in net.iter_mut().zip(v.net) {
                *n += x;
            }
        }
        let mut region = self.region(solver, &best, solver.ambient_from(net));
        if source.by_transport(best.power) && !solver.overshoot() {
            self.join_group(solver, &best, &mut region);
        }
        let shot = self.shoot(source, solver, &best, &region)?;
        self.stats.shot_times.push(shot_start.elapsed());
        hooks.after_shot(solver, unshot_fraction);
        Ok(Step::Shot(shot))
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
        let (rank, ranks) = (self.comm.rank(), self.comm.size());
        let owner = patch_owner(best.patch, ranks);
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
        best: &Candidate,
        region: &ShotRegion,
    ) -> Result<Shot, RenderError> {
        source.form_factors(best.patch, region, &mut self.ff)?;
        let t = Instant::now();
        let cpu = crate::parallel::CpuSpan::start(self.comm);
        let shot = solver.shoot_candidate(best, region, &self.ff);
        let dt = t.elapsed();
        if let Some(b) = source.busy_cpu.last_mut() {
            *b += cpu.own(self.comm);
        }
        (self.landed, self.delivered) = self.landed_here(solver, best);
        self.last_power = Some(shot.shot_power);
        self.stats.update += dt;
        self.stats.patch_power[best.patch as usize] += shot.power;
        if let Some(b) = source.busy.last_mut() {
            *b += dt.as_secs_f64();
        }
        Ok(shot)
    }

    /// What the last shot landed on this rank's elements (the sum of their
    /// form factors) and the power it delivered to them over the emitted
    /// power, both in [`UNSHOT_ONE`] fixed point, told at the next
    /// collective. Each element's share is rounded on its own, so the sums
    /// over ranks do not depend on how elements are split between them.
    fn landed_here(&self, solver: &Solver, best: &Candidate) -> (u64, i64) {
        let emitted = solver.emitted_power();
        let area = self.mesh.patches[best.patch as usize].area;
        let (mut landed, mut delivered) = (0u64, 0i64);
        for t in &self.ff {
            if !solver.owns_element(t.element) {
                continue;
            }
            landed += crate::numeric::round_u64(t.form_factor.clamp(0.0, 1.0) * UNSHOT_ONE);
            if emitted > 0.0 {
                let w = (t.radiosity[0] + t.radiosity[1] + t.radiosity[2]) * area;
                delivered += crate::numeric::round_i64(w / emitted * UNSHOT_ONE);
            }
        }
        (landed, delivered)
    }
}

/// Shoots until the loop stops (see [`ShotLoop`]).
pub fn shoot_until<'m>(
    mesh: &'m Mesh,
    stop: &StopRule,
    floor: f64,
    comm: &dyn Collectives,
    source: &mut GpuFormFactors,
    solver: &mut Solver<'m>,
    hooks: &mut dyn LoopHooks<'m>,
) -> Result<LoopStats, RenderError> {
    let mut shots = ShotLoop::new(mesh, comm, *stop, floor);
    while let Step::Shot(_) = shots.step(source, solver, hooks)? {}
    Ok(shots.stats)
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
}
