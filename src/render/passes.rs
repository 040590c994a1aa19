//! Refinement by need (`crate::refine`): coarse solves, each followed by a
//! decision that doubles some polygons' patch grids. The passes run the
//! same shooting loop as the final solve, and their time counts as solve time.

use super::hooks::Progress;
use super::options::{RenderError, RenderOptions};
use super::shoot::{shoot_until, Flags, LoopHooks, Until};
use super::source::GpuFormFactors;
use super::trace::{gather_whole_consuming, Extra, Trace};
use crate::ambient::{GroupRays, Transport, PASS_RAY_BUDGET};
use crate::gpu::Gpu;
use crate::lit_mesh::LitMesh;
use crate::mesh::Mesh;
use crate::parallel::{Collectives, Single};
use crate::refine::{self, PatchStats};
use crate::report::{Refinement, TracePoint};
use crate::scene::Scene;
use crate::settings::AmbientTerm;
use crate::solver::{Solver, SolverState};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Shading errors are summed over ranks in fixed point up to this.
const SHADING_CAP: f64 = 16.0;

/// What refinement by need leaves the final solve.
pub struct Refined {
    /// The mesh to solve.
    pub mesh: LitMesh,
    /// What the passes did.
    pub refinement: Refinement,
    /// Per polygon, its patch-grid factor.
    pub factors: Vec<u32>,
    /// The passes' convergence trace (rank 0's; each point says its pass):
    /// every pass's solution is shown from its first shot, as the final
    /// solve's is, and the trace's times run on through the passes.
    pub trace: Vec<TracePoint>,
    /// Seconds the passes' trace bookkeeping took: neither solve time (as
    /// the final solve's is not) nor mesh time.
    pub bookkeeping: f64,
    /// When a pass was interrupted: its solver's state, on `mesh` (that
    /// pass's, refined no further), for the final solve to continue from.
    pub interrupted: Option<Handoff>,
}

/// The mesh a render solves: refinement by need (`crate::refine`), i.e.
/// coarse solves, each followed by a decision that doubles some polygons'
/// patch grids, until nothing asks for more or [`RenderOptions::mesh_settings`]' `refine`
/// passes have run. Every rank calls this with the same arguments.
pub fn refined_mesh(
    gpu: &Gpu,
    scene: &Scene,
    opts: &RenderOptions,
    comm: &dyn Collectives,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Refined, RenderError> {
    refined_mesh_shown(gpu, scene, opts, comm, progress, &mut |_, _| {})
}

/// Who is shown a pass's solution: called with the pass and its solver.
pub type ShowPass<'a> = &'a mut dyn FnMut(u32, &Solver);

/// What the passes decided so far: each polygon's patch-grid factor, why
/// polygons were refined, and the summary the report gives.
struct Tally {
    factors: Vec<u32>,
    summary: Refinement,
    trace: Vec<TracePoint>,
    bookkeeping: f64,
    shooters: Vec<bool>,
    receivers: Vec<bool>,
    shading: Vec<bool>,
}

impl Tally {
    fn new(polygons: usize) -> Self {
        Self {
            factors: vec![1; polygons],
            summary: Refinement::default(),
            trace: Vec::new(),
            bookkeeping: 0.0,
            shooters: vec![false; polygons],
            receivers: vec![false; polygons],
            shading: vec![false; polygons],
        }
    }

    /// Counts a pass's shots, time and trace.
    fn add_pass(&mut self, measured: &mut Measured) {
        self.summary.passes += 1;
        self.summary.shots += measured.shots;
        self.summary.seconds += measured.seconds;
        self.trace.append(&mut measured.trace);
        self.bookkeeping += measured.bookkeeping;
    }

    /// Doubles the patch grids a pass decided on; returns how many.
    fn apply(&mut self, decided: &[refine::Decision]) -> usize {
        let mut changed = 0;
        for (i, d) in decided.iter().enumerate() {
            if d.refine() {
                self.factors[i] *= 2;
                changed += 1;
            }
            self.shading[i] |= d.shading;
            self.summary.shading_refinements += d.shading as u32;
            self.shooters[i] |= d.shooter;
            self.receivers[i] |= d.receiver;
            self.summary.shooter_refinements += d.shooter as u32;
            self.summary.receiver_refinements += d.receiver as u32;
        }
        changed
    }

    /// What the passes leave the final solve, on `mesh`.
    fn finish(mut self, mesh: LitMesh, interrupted: Option<Handoff>) -> Refined {
        // An interrupted pass's summary keeps no polygon counts, as before.
        if interrupted.is_none() {
            let count = |v: &[bool]| v.iter().filter(|&&x| x).count() as u32;
            self.summary.shooter_polygons = count(&self.shooters);
            self.summary.receiver_polygons = count(&self.receivers);
            self.summary.shading_polygons = count(&self.shading);
        }
        self.summary.end = [mesh.patches.len(), mesh.elements.len()];
        self.summary.interrupted = interrupted.is_some();
        Refined {
            mesh,
            refinement: self.summary,
            factors: self.factors,
            trace: self.trace,
            bookkeeping: self.bookkeeping,
            interrupted,
        }
    }
}

/// Logs what pass `pass` (from 0) decided, on rank 0.
fn log_pass(pass: u32, mesh: &LitMesh, shots: u64, decided: &[refine::Decision]) {
    let count = |f: fn(&refine::Decision) -> bool| decided.iter().filter(|d| f(d)).count();
    let changed = count(|d| d.refine());
    let (s, r, sh) = (
        count(|d| d.shooter),
        count(|d| d.receiver),
        count(|d| d.shading),
    );
    log::info!(
        "refinement pass {}: {} patches, {shots} shots; {changed} polygons refined ({s} for their shooters, {r} for uneven receivers, {sh} for their shading)",
        pass + 1,
        mesh.patches.len(),
    );
}

/// [`refined_mesh`], calling `show` on rank 0 with the pass number and its
/// solver (rank 0's share; one process's is whole) after every pass shot:
/// how the viewer shows a pass's solution as it comes.
pub fn refined_mesh_shown(
    gpu: &Gpu,
    scene: &Scene,
    opts: &RenderOptions,
    comm: &dyn Collectives,
    progress: &mut dyn FnMut(&Progress),
    show: ShowPass<'_>,
) -> Result<Refined, RenderError> {
    let run = PassRun {
        gpu,
        scene,
        opts,
        comm,
    };
    let settings = opts.mesh_settings();
    let mut tally = Tally::new(scene.polygons.len());
    // The last pass's light field: the next mesh casts rays only for the
    // polygons refined since.
    let mut kept = None;
    for pass in 0..settings.refine {
        let mut mesh = crate::parallel::built_once(comm, || {
            LitMesh::build_refined_from(scene, &settings, &tally.factors, kept.as_ref())
        });
        if pass == 0 {
            tally.summary.start = [mesh.patches.len(), mesh.elements.len()];
        }
        crate::report::log_memory("a pass's mesh");
        // Every pass shows its solution from its first shot, so the
        // transport comes first (solve time, as the final solve's does).
        let t = Instant::now();
        if wants_transport(opts, &mesh) {
            shared_transport(&mesh, PASS_RAY_BUDGET, comm);
        }
        let transport = t.elapsed().as_secs_f64();
        tally.summary.seconds += transport;
        tally.summary.transport_seconds += transport;
        let at = PassAt {
            pass,
            before: tally.summary.seconds,
        };
        let mut measured = one_pass(&run, &mesh, at, &mut *progress, &mut *show)?;
        crate::report::log_memory("a pass's solve");
        tally.add_pass(&mut measured);
        if let Some(handoff) = measured.interrupted {
            if comm.rank() == 0 {
                log::warn!(
                    "interrupted during refinement pass {} (after {} shots): its solution on its mesh is kept, refined no further",
                    pass + 1,
                    measured.shots
                );
            }
            return Ok(tally.finish(mesh, Some(handoff)));
        }
        if comm.rank() == 0 {
            log_pass(pass, &mesh, measured.shots, &measured.decided);
        }
        if tally.apply(&measured.decided) == 0 {
            // The last pass's mesh is the final one (building it again
            // would cost its light field); the final solve estimates its
            // own transport, with the full budget.
            mesh.ambient.take();
            return Ok(tally.finish(mesh, None));
        }
        kept = Some(mesh.take_field());
    }
    let mesh = crate::parallel::built_once(comm, || {
        LitMesh::build_refined_from(scene, &settings, &tally.factors, kept.as_ref())
    });
    Ok(tally.finish(mesh, None))
}

/// Whether a solve of `mesh` with `opts` needs the ambient transport: the
/// carried ambient term shows it, and the transport tier shoots along it.
pub fn wants_transport(opts: &RenderOptions, mesh: &Mesh) -> bool {
    opts.ambient == AmbientTerm::Carried || opts.transport_below_for(mesh.patches.len()) > 0.0
}

/// Runs of groups per rank that a transport's rays are cut into
/// ([`crate::ambient::Plan::pieces`]): enough that the last one taken is
/// short, few enough that a ticket a run costs nothing.
const TRANSPORT_RUNS_PER_RANK: usize = 32;

/// Gives `mesh` its ambient transport (once), of `budget` rays
/// ([`Transport::built_within`]), every rank of `comm` casting runs of
/// groups taken from a pool as it comes free
/// ([`crate::ambient::Plan::pieces`]) and all gathering the counts: the
/// same bits as one rank casting them all, whoever cast what.
pub(super) fn shared_transport(mesh: &LitMesh, budget: usize, comm: &dyn Collectives) {
    mesh.ambient.get_or_init(|| {
        Transport::built_within(mesh, budget, |plan| {
            let ranks = comm.size();
            if ranks == 1 {
                return plan.cast_all();
            }
            let runs = plan.pieces(ranks * TRANSPORT_RUNS_PER_RANK);
            let mut words = Vec::new();
            for k in crate::parallel::pool(comm, runs.len()) {
                for row in plan.cast_these(&runs[k].clone().collect::<Vec<_>>()) {
                    row.pack(&mut words);
                }
            }
            let mut rows: Vec<GroupRays> = comm
                .all_gather_u32(&words, None)
                .iter()
                .flat_map(|w| GroupRays::unpack_all(w).unwrap_or_default())
                .collect();
            rows.sort_by_key(|r| r.group);
            // Every rank runs the same binary on the same mesh, so this
            // cannot fail; if it ever did, cast them all here.
            if rows.len() != plan.groups() {
                return plan.cast_all();
            }
            rows
        })
    });
}

/// What one coarse solve measured.
struct Measured {
    /// Which polygons' patch grids to double, and why.
    decided: Vec<refine::Decision>,
    /// Shots taken.
    shots: u64,
    /// Solve seconds (set-up and the trace's own time left out).
    seconds: f64,
    /// Its convergence trace.
    trace: Vec<TracePoint>,
    /// Seconds the trace's bookkeeping took (left out of `seconds`).
    bookkeeping: f64,
    /// Its solver's state when it was interrupted (then nothing was decided).
    interrupted: Option<Handoff>,
}

/// The hooks of a pass's shooting loop: its trace (the pass's solution is
/// what a stop now would keep, shown as the final solve's is, its own time
/// left out), progress, and interrupts (a pass stops at once, and the
/// render keeps its solution: [`Refined::interrupted`]).
struct PassHooks<'a, 'm> {
    comm: &'a dyn Collectives,
    nodes: &'a [String],
    ambient: AmbientTerm,
    interrupt: Option<&'a AtomicBool>,
    trace: Trace<'m>,
    /// When the solve would have started had the passes before this one
    /// run back to back (the trace's times run on through the passes).
    solve_start: Instant,
    /// When this pass started.
    started: Instant,
    progress: &'a mut dyn FnMut(&Progress),
    /// The pass, and who is shown its solution after each shot (rank 0).
    show: (u32, ShowPass<'a>),
}

impl<'a> PassHooks<'a, '_> {
    /// The hooks of pass `at`, started at `started`.
    fn new(
        run: &PassRun<'a>,
        at: PassAt,
        started: Instant,
        progress: &'a mut dyn FnMut(&Progress),
        show: ShowPass<'a>,
    ) -> Self {
        Self {
            comm: run.comm,
            nodes: &run.scene.nodes,
            ambient: run.opts.ambient,
            interrupt: run.opts.interrupt.as_deref(),
            trace: Trace::default(),
            solve_start: started
                .checked_sub(Duration::from_secs_f64(at.before))
                .unwrap_or(started),
            started,
            progress,
            show: (at.pass, show),
        }
    }
}

impl<'m> LoopHooks<'m> for PassHooks<'_, 'm> {
    fn after_shot(&mut self, s: &Solver<'m>, u: f64) {
        if self.trace.due(s.shots()) {
            self.trace
                .record(self.comm, s, self.nodes, self.ambient, self.solve_start);
        }
        if self.comm.rank() == 0 {
            (self.progress)(&Progress {
                shots: s.shots(),
                unshot_fraction: u,
                elapsed: self.started.elapsed(),
            });
            (self.show.1)(self.show.0, s);
        }
    }

    fn flags(&self) -> Flags {
        Flags {
            stop: self.interrupt.is_some_and(|i| i.load(Ordering::Relaxed)),
            save: false,
        }
    }
}

/// A pass's solver state, handed to the final solve when the pass was
/// interrupted: the render then writes (and checkpoints) that solution.
pub struct Handoff {
    /// The pass's solver state (this rank's patches hold theirs).
    pub state: SolverState,
    /// Its energy record.
    pub energy: [f64; 3],
}

/// What every pass is solved with: the device, the scene, the options and
/// the ranks.
struct PassRun<'a> {
    gpu: &'a Gpu,
    scene: &'a Scene,
    opts: &'a RenderOptions,
    comm: &'a dyn Collectives,
}

/// Where a pass stands: its number and the solve seconds before it.
#[derive(Clone, Copy)]
struct PassAt {
    pass: u32,
    before: f64,
}

/// One coarse solve of `mesh`, pass `at.pass`, after `at.before` seconds of
/// solve: which polygons' patch grids to double (and why), its shots,
/// seconds and trace.
fn one_pass(
    run: &PassRun<'_>,
    mesh: &LitMesh,
    at: PassAt,
    progress: &mut dyn FnMut(&Progress),
    show: ShowPass<'_>,
) -> Result<Measured, RenderError> {
    let PassRun {
        gpu,
        scene,
        opts,
        comm,
    } = *run;
    // A batched solve's passes are batched too, each rank drawing whole
    // hemispheres for its rows (as the final solve's: see
    // `ShotLoop::batched`), so the ranks divide the passes as they divide
    // the solve; the mesh then depends on the batch, never on the ranks.
    let one = Single::default();
    let mut source = GpuFormFactors::for_solve(gpu, mesh, opts, (comm, &one), scene.extent())?;
    // Coarse, unsplit hemispheres measure what the pass decides by as
    // well, in 2-6x less pass time (docs/guide/meshing.md "Refinement by need"); the
    // emitters draw fine, as a coarse light over-refined the 64 cubes
    // (8100 -> 12 900 elements).
    source.measuring();
    let started = Instant::now();
    // No overshooting here: the passes only measure the shooters, and
    // the mesh they choose is then the same with or without it.
    let mut solver = Solver::partitioned(mesh, comm.rank(), comm.size());
    // Shots after the last one strong enough to be refined change nothing.
    let floor = refine::SHOOTER_TOL * solver.emitted_power();
    let mut hooks = PassHooks::new(run, at, started, progress, show);
    let until = Until {
        floor,
        draw_ahead: false,
    };
    let stats = shoot_until(opts, comm, until, &mut source, &mut solver, &mut hooks)?;
    let seconds = started
        .elapsed()
        .saturating_sub(hooks.trace.spent)
        .as_secs_f64();
    let bookkeeping = hooks.trace.spent.as_secs_f64();
    let mut trace = hooks.trace.points;
    for p in &mut trace {
        p.pass = Some(at.pass);
    }
    let mut measured = Measured {
        decided: Vec::new(),
        shots: solver.shots(),
        seconds,
        trace,
        bookkeeping,
        interrupted: None,
    };
    if stats.interrupted {
        // Every rank stopped at the same shot (the vote): its solution
        // is what the render keeps, on this pass's mesh, refined no further.
        measured.interrupted = Some(Handoff {
            state: solver.state(),
            energy: solver.energy_record(),
        });
        return Ok(measured);
    }
    // The rasteriser and the solver go before the whole solution is
    // gathered (see `patch_stats`): the three at once were double-sided
    // Sponza's peak memory.
    let penumbra = std::mem::take(&mut source.penumbra);
    drop(source);
    let emitted = solver.emitted_power();
    let patches = patch_stats(run, mesh, solver, &penumbra, &stats.patch_power);
    let settings = opts.mesh_settings();
    measured.decided = refine::decide(
        mesh,
        &patches,
        emitted,
        settings.receiver_tol,
        settings.shading_tol,
    );
    Ok(measured)
}

/// What a pass measured of each patch, summed over the ranks: its power,
/// the penumbrae it cast (`penumbra`, per patch of this rank's rows), how
/// unevenly it holds its light and how badly a uniform patch would shade.
/// Every rank saw its own receivers' penumbrae and holds its own patches'
/// light, so the sums are exact (fixed point, the others' shares 0).
fn patch_stats(
    run: &PassRun<'_>,
    mesh: &LitMesh,
    solver: Solver,
    penumbra: &[[u64; 2]],
    patch_power: &[f64],
) -> Vec<PatchStats> {
    let emitted = solver.emitted_power();
    let one = crate::formfactor::SHARE_ONE;
    let mut sums: Vec<u64> = penumbra.iter().flatten().copied().collect();
    sums.extend(solver.patch_unevenness().iter().map(|&w| {
        let share = if emitted > 0.0 { w / emitted } else { 0.0 };
        crate::numeric::round_u64(share.clamp(0.0, 1.0) * one)
    }));
    sums.extend(shading_errors(run, mesh, solver, emitted));
    run.comm.reduce_broadcast_sum(&mut sums);
    let n = mesh.patches.len();
    let (penumbra, rest) = sums.split_at(2 * n);
    let (uneven, shading) = rest.split_at(n);
    patch_power
        .iter()
        .zip(penumbra.chunks_exact(2))
        .zip(uneven.iter().zip(shading))
        .map(|((&power, p), (&u, &s))| PatchStats {
            power,
            penumbra: [p[0], p[1]],
            uneven: u as f64 / one * emitted,
            shading: s as f64 / one,
        })
        .collect()
}

/// Per patch, how badly the image would shade it (fixed point). The
/// shading error needs neighbours' values across patches (and ranks):
/// rank 0 judges the whole solution; the others add zeros.
fn shading_errors(run: &PassRun<'_>, mesh: &LitMesh, solver: Solver, emitted: f64) -> Vec<u64> {
    let mut shading = vec![0u64; mesh.patches.len()];
    if run.opts.mesh_settings().shading_tol <= 0.0 {
        return shading;
    }
    let extra = Extra {
        direct: true,
        ..Extra::default()
    };
    let whole = gather_whole_consuming(run.comm, solver, extra);
    // (A pass's solver always knows its direct part.)
    if let Some((whole, direct)) = whole.as_ref().and_then(|w| Some((w, w.direct()?))) {
        let radiosity = whole.display_radiosity(crate::settings::AmbientTerm::Off);
        let errors = refine::shading_error(mesh, &radiosity, direct, &whole.unlit(), emitted);
        let one = crate::formfactor::SHARE_ONE;
        for (s, e) in shading.iter_mut().zip(errors) {
            *s = crate::numeric::round_u64(e.clamp(0.0, SHADING_CAP) * one);
        }
    }
    shading
}
