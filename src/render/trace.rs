//! The convergence trace the report carries (per-node radiosities at
//! log-spaced shot counts), and the gather of a distributed solution to
//! rank 0 that the trace and the checkpoints share.

use crate::parallel::{Collectives, Traffic};
use crate::report::{self, Report, TracePoint};
use crate::settings::AmbientTerm;
use crate::solver::Solver;
use std::time::{Duration, Instant};

/// What [`gather_whole`] gathers besides radiosities and unshot radiosities.
#[derive(Clone, Copy, Debug, Default)]
pub struct Extra {
    /// The elements' unshot radiosities (a checkpoint needs them).
    pub element_unshot: bool,
    /// The solution's own direct part (the image and checkpoints need it;
    /// without it the whole solution's is unknown).
    pub direct: bool,
}

/// Gathers every rank's share of `solver` to rank 0 and assembles the whole
/// solution there (`None` on the other ranks): radiosities, unshot
/// radiosities, shots, retention, and what `extra` asks for.
/// Every rank must call it.
pub fn gather_whole<'m>(
    comm: &dyn Collectives,
    solver: &Solver<'m>,
    extra: Extra,
) -> Option<Solver<'m>> {
    let mut whole = None;
    gather_whole_into(comm, solver, extra, &mut whole);
    whole
}

/// [`gather_whole`] into `whole`, reused when it already holds a solver of
/// the same mesh (a solver for a big scene is hundreds of megabytes, and a
/// fresh one per trace point spent most of a point's time on page faults).
/// Returns `Some` on rank 0. Every field the whole solution reads is
/// overwritten: every patch is some rank's, so the gathered radiosities and
/// unshot radiosities cover all of them.
pub fn gather_whole_into<'w, 'm>(
    comm: &dyn Collectives,
    solver: &Solver<'m>,
    extra: Extra,
    whole: &'w mut Option<Solver<'m>>,
) -> Option<&'w Solver<'m>> {
    let parts = Parts::gather(comm, solver, extra)?;
    if whole
        .as_ref()
        .is_none_or(|w| !std::ptr::eq(w.mesh(), solver.mesh()))
    {
        *whole = Some(Solver::new(solver.mesh()));
    }
    let whole = whole.as_mut()?;
    parts.install(whole, solver.shots(), solver.retained());
    Some(whole)
}

/// [`gather_whole`] of a solver no longer needed: it is dropped once its
/// share is gathered, before the whole is built, so that the two are never
/// held at once (a big scene's solver is hundreds of megabytes: double-sided
/// Sponza's is 340 MB). The same bits as [`gather_whole`].
pub fn gather_whole_consuming<'m>(
    comm: &dyn Collectives,
    solver: Solver<'m>,
    extra: Extra,
) -> Option<Solver<'m>> {
    let parts = Parts::gather(comm, &solver, extra);
    let (mesh, shots, retained) = (solver.mesh(), solver.shots(), solver.retained());
    drop(solver);
    let parts = parts?;
    let mut whole = Solver::new(mesh);
    parts.install(&mut whole, shots, retained);
    Some(whole)
}

/// Every rank's share of a solution, gathered on rank 0.
struct Parts {
    radiosity: Vec<Vec<f64>>,
    unshot: Vec<Vec<f64>>,
    element_unshot: Option<Vec<Vec<f64>>>,
    direct: Option<Vec<Vec<f64>>>,
}

impl Parts {
    /// Gathers `solver`'s share (every rank calls it); `Some` on rank 0.
    fn gather(comm: &dyn Collectives, solver: &Solver, extra: Extra) -> Option<Self> {
        let (b, u) = solver.local_state();
        let (gb, gu) = (comm.gather_f64(&b), comm.gather_f64(&u));
        let ge = (extra.element_unshot)
            .then(|| comm.gather_f64(&solver.local_element_unshot()))
            .flatten();
        let gd = (extra.direct)
            .then(|| comm.gather_f64(&solver.local_direct()))
            .flatten();
        Some(Parts {
            radiosity: gb?,
            unshot: gu?,
            element_unshot: ge,
            direct: gd,
        })
    }

    /// Overwrites every field the whole solution reads: every patch is
    /// some rank's, so the gathered radiosities and unshot radiosities
    /// cover all of them.
    fn install(self, whole: &mut Solver, shots: u64, retained: crate::solver::Retained) {
        whole.assemble(&self.radiosity, &self.unshot);
        if let Some(e) = &self.element_unshot {
            whole.assemble_element_unshot(e);
        }
        whole.set_shots(shots);
        whole.restore_retained(retained);
        match &self.direct {
            Some(d) => whole.assemble_direct(d),
            None => whole.forget_direct(),
        }
    }
}

/// The report's convergence trace as the solve goes: when to record, and the
/// points so far (rank 0's; other ranks only take part in the gathers).
#[derive(Default)]
pub struct Trace<'m> {
    /// Recorded points.
    pub points: Vec<TracePoint>,
    /// The next shot count to record after the first 32.
    next: u64,
    /// Time spent gathering and summarising (left out of the solve time).
    pub spent: Duration,
    /// The same in process CPU seconds.
    pub spent_cpu: f64,
    /// Bytes the trace's gathers moved (left out of the exchange's traffic).
    pub traffic: Traffic,
    /// Rank 0's whole solution, reused from point to point (several ranks).
    whole: Option<Solver<'m>>,
}

impl<'m> Trace<'m> {
    /// Whether a point is due after `shots` shots: every shot up to 32, then
    /// at every power of two and at counts growing by 2^(1/4). The
    /// same on every rank, since it depends on the shot count alone.
    pub fn due(&mut self, shots: u64) -> bool {
        if shots <= 32 || shots.is_power_of_two() {
            return true;
        }
        if shots >= self.next.max(33) {
            self.next = ((shots as f64) * 2f64.powf(0.25)).ceil() as u64;
            return true;
        }
        false
    }

    /// Records the solution now. Every rank must call this at the same shot;
    /// with several ranks the owners' radiosities are gathered to rank 0.
    pub fn record(
        &mut self,
        comm: &dyn Collectives,
        solver: &Solver<'m>,
        nodes: &[String],
        ambient: AmbientTerm,
        solve_start: Instant,
    ) {
        let seconds = solve_start
            .elapsed()
            .saturating_sub(self.spent)
            .as_secs_f64();
        self.record_at(comm, solver, nodes, ambient, seconds);
    }

    /// [`Trace::record`] with the solve time given (e.g. a viewer's, which
    /// leaves its pauses out).
    pub fn record_at(
        &mut self,
        comm: &dyn Collectives,
        solver: &Solver<'m>,
        nodes: &[String],
        ambient: AmbientTerm,
        seconds: f64,
    ) {
        let t = Instant::now();
        let cpu = crate::parallel::process_cpu_seconds();
        let before = comm.traffic();
        let summary = if comm.size() == 1 {
            Some((
                report::surfaces(solver.mesh(), nodes, solver.display_radiosities(ambient)),
                solver.unshot_fraction(),
            ))
        } else {
            let extra = Extra::default();
            gather_whole_into(comm, solver, extra, &mut self.whole).map(|whole| {
                (
                    report::surfaces(solver.mesh(), nodes, whole.display_radiosities(ambient)),
                    whole.unshot_fraction(),
                )
            })
        };
        if let Some((surfaces, unshot_fraction)) = summary {
            self.points.push(TracePoint {
                shots: solver.shots(),
                seconds,
                unshot_fraction,
                surfaces,
                pass: None,
            });
        }
        self.spent += t.elapsed();
        self.spent_cpu += crate::parallel::process_cpu_seconds() - cpu;
        let after = comm.traffic();
        self.traffic = self.traffic.plus(after.since(before));
    }

    /// The trace with its last point made equal to the final result.
    pub fn finish(self, report: &Report, seconds: f64) -> Vec<TracePoint> {
        self.ending_with(report, seconds)
    }

    /// Continues a trace saved after `shots` shots (its points, and the
    /// schedule of the points to come, as if it had run here).
    pub fn resume(&mut self, points: Vec<TracePoint>, shots: u64) {
        self.points = points;
        for s in 1..=shots {
            self.due(s);
        }
    }

    /// The points so far, the last made equal to `report` (which the trace
    /// keeps going after), thinned for the report ([`report::thin_trace`]).
    pub fn ending_with(&self, report: &Report, seconds: f64) -> Vec<TracePoint> {
        let mut points = self.points.clone();
        if points
            .last()
            .is_some_and(|p| p.pass.is_none() && p.shots == report.shots)
        {
            points.pop();
        }
        points.push(TracePoint {
            shots: report.shots,
            seconds,
            unshot_fraction: report.unshot_fraction,
            surfaces: report.surfaces.clone(),
            pass: None,
        });
        report::thin_trace(&mut points);
        points
    }
}
