//! One render from start to finish: the mesh (refined, or a checkpoint's),
//! the final solve, the gather to rank 0, the camera image and the report.

use super::hooks::{Progress, SolveHooks};
use super::options::{fingerprint, RenderError, RenderOptions};
use super::passes::{refined_mesh, shared_transport, wants_transport, Handoff, Refined};
use super::shoot::{shoot_until, LoopStats, Until};
use super::source::{GpuFormFactors, PhaseTimes};
use super::trace::{gather_whole_consuming, Extra, Trace};
use crate::checkpoint::Header;
use crate::gpu::Gpu;
use crate::hemisphere::{Resolution, TileLayout};
use crate::lit_mesh::LitMesh;
use crate::mesh::Mesh;
use crate::parallel::{Collectives, Exchange, Single, ThreadComm, Traffic};
use crate::render::image::{solution_image, view_for};
use crate::report::{
    self, Counts, Decomposition, LoadBalance, Parallel, RankStats, Refinement, Report, Settings,
    Timings, TracePoint,
};
use crate::scene::Scene;
use crate::settings::Projection;
use crate::solver::Solver;
use std::time::{Duration, Instant};

/// The result of [`render`].
pub struct Rendered {
    /// The discretised scene.
    pub mesh: LitMesh,
    /// Radiosity per element (the ambient term added when the options say so).
    pub radiosity: Vec<[f64; 3]>,
    /// Image size and linear radiance pixels (top row first), if an image was asked for.
    pub image: Option<Image>,
    /// The report.
    pub report: Report,
    /// The solve stopped early because it was interrupted.
    pub interrupted: bool,
}

/// What every step of a render is given: the device, the scene, the
/// options and the ranks (every rank holds the same).
#[derive(Clone, Copy)]
struct Job<'a> {
    gpu: &'a Gpu,
    scene: &'a Scene,
    opts: &'a RenderOptions,
    comm: &'a dyn Collectives,
}

/// Where the final solve starts: the passes' summary and trace, and an
/// interrupted pass's state to go on from.
struct Start<'r> {
    refinement: &'r Refinement,
    passes: Vec<TracePoint>,
    handoff: Option<Handoff>,
}

/// Solves `scene` in this process and renders its camera view. `load_time` is
/// reported as the load phase.
pub fn render(
    gpu: &Gpu,
    scene: &Scene,
    opts: &RenderOptions,
    load_time: Duration,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Rendered, RenderError> {
    let single = Single::default();
    // With one rank this process is rank 0, which always gets the result.
    render_on(gpu, scene, opts, &single, load_time, progress)?
        .ok_or_else(|| RenderError::Settings("no result on rank 0".into()))
}

/// [`render`] on `ranks` ranks that are threads of this process
/// ([`ThreadComm::ranks`]), each with its share of the cores: the same
/// numbers as `mpirun -n ranks` gives (and, with `--batch`, as one rank),
/// without MPI. Only rank 0 reports `progress`.
pub fn render_ranks(
    gpu: &Gpu,
    scene: &Scene,
    opts: &RenderOptions,
    ranks: usize,
    load_time: Duration,
    progress: &mut (dyn FnMut(&Progress) + Send),
) -> Result<Rendered, RenderError> {
    if ranks <= 1 {
        return render(gpu, scene, opts, load_time, progress);
    }
    if opts.batch <= 1 {
        // Not an error (the same numbers as one rank), but rarely wanted.
        log::warn!(
            "{ranks} ranks with --batch 1 split each shot's hemisphere between them, which on one machine is slower than one rank; --batch 16 or more gives each rank whole shots (docs/guide/mpi.md)"
        );
    }
    let progress = std::sync::Mutex::new(progress);
    let rendered = ThreadComm::ranks(ranks, |comm| {
        if comm.rank() > 0 {
            return render_on(gpu, scene, opts, comm, load_time, &mut |_| {});
        }
        let mut shown = progress.lock().unwrap_or_else(|p| p.into_inner());
        render_on(gpu, scene, opts, comm, load_time, &mut |p| shown(p))
    })?;
    rendered.ok_or_else(|| RenderError::Settings("no result on rank 0".into()))
}

/// The mesh to solve: a checkpoint's (whose fingerprint must match), or
/// the refinement passes' (see [`refined_mesh`]).
fn solve_mesh(
    job: Job<'_>,
    fingerprint: &str,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Refined, RenderError> {
    let Job {
        gpu,
        scene,
        opts,
        comm,
    } = job;
    let Some(c) = &opts.resume else {
        return refined_mesh(gpu, scene, opts, comm, progress);
    };
    if c.header.fingerprint != fingerprint {
        return Err(RenderError::Checkpoint(format!(
            "it was saved from {} with other geometry or settings (resolution, form factors, subdivision and split shots must match)",
            c.header.scene
        )));
    }
    Ok(Refined {
        mesh: LitMesh::build_refined(scene, &opts.mesh_settings(), &c.header.factors),
        refinement: c.header.refinement.clone(),
        factors: c.header.factors.clone(),
        // The checkpoint's trace holds the passes' points.
        trace: Vec::new(),
        bookkeeping: 0.0,
        interrupted: None,
    })
}

/// A solver at the start of the final solve (or where a checkpoint left
/// it), its trace so far, and the solve seconds already spent.
fn start_solver<'m>(
    job: Job<'_>,
    mesh: &'m LitMesh,
    start: Start<'_>,
) -> Result<(Solver<'m>, SoFar<'m>), RenderError> {
    let Job { opts, comm, .. } = job;
    let Start {
        refinement,
        passes,
        handoff,
    } = start;
    let mut solver = Solver::partitioned(mesh, comm.rank(), comm.size());
    // An interrupted pass's solution is where the solve goes on from (and
    // the trace's schedule from its shots).
    let mut shots = 0;
    if let Some(h) = handoff {
        solver
            .restore(&h.state)
            .map_err(|e| RenderError::Settings(format!("an interrupted pass's state: {e}")))?;
        solver.set_energy_record(h.energy);
        shots = h.state.shots;
    }
    let mut trace = Trace::default();
    trace.resume(passes, shots);
    // The refinement passes (and, resuming, the solve before the checkpoint)
    // count as solve time (set-up excluded), so the trace's times are the
    // honest time to each accuracy.
    let mut so_far = refinement.seconds;
    if let Some(c) = &opts.resume {
        solver
            .restore(&c.state)
            .map_err(|e| RenderError::Checkpoint(e.to_string()))?;
        solver.set_energy_record(c.header.energy);
        trace.resume(c.header.trace.clone(), c.state.shots);
        so_far = c.header.seconds;
        if comm.rank() == 0 {
            log::info!(
                "resuming after {} shots ({so_far:.2} s of solve)",
                c.state.shots
            );
        }
    }
    Ok((solver, SoFar { trace, so_far }))
}

/// Where the final solve starts from: its trace so far and the solve
/// seconds already spent (the passes', or a checkpoint's).
struct SoFar<'m> {
    trace: Trace<'m>,
    so_far: f64,
}

/// What the final solve left: its loop statistics, trace and solve time.
struct Solved<'m> {
    stats: LoopStats,
    trace: Trace<'m>,
    solve: f64,
    /// Of `solve`: the ambient term's transport.
    ambient: f64,
    /// The transport's gather (not a form-factor exchange).
    ambient_traffic: Traffic,
}

/// Runs the final solve with the trace, progress and checkpoint hooks,
/// from where `start` says.
fn final_solve<'m>(
    job: Job<'_>,
    source: &mut GpuFormFactors,
    solver: &mut Solver<'m>,
    start: SoFar<'m>,
    header: Header,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Solved<'m>, RenderError> {
    let Job {
        scene, opts, comm, ..
    } = job;
    let SoFar { trace, so_far } = start;
    let mesh = solver.mesh();
    let solve_start = Instant::now()
        .checked_sub(Duration::from_secs_f64(so_far))
        .unwrap_or_else(Instant::now);
    let mut hooks = SolveHooks {
        comm,
        nodes: &scene.nodes,
        ambient: opts.ambient,
        solve_start,
        trace,
        progress,
        plan: opts.checkpoint.as_ref(),
        interrupt: opts.interrupt.as_deref(),
        last_save: Instant::now(),
        header,
    };
    // The display's ambient term (and the transport tier) needs the
    // transport: estimated here, so its cost counts as solve time (the
    // trace's own time does not), every rank casting its share of the rays.
    let t = Instant::now();
    let before = comm.traffic();
    if wants_transport(opts, mesh) {
        shared_transport(mesh, crate::ambient::RAY_BUDGET, comm);
    }
    let ambient = t.elapsed().as_secs_f64();
    // Its gather is not a form-factor exchange: the report's bytes leave it out.
    let ambient_traffic = comm.traffic().since(before);
    let until = Until {
        floor: 0.0,
        draw_ahead: true,
    };
    let stats = shoot_until(opts, comm, until, source, solver, &mut hooks)?;
    let trace = hooks.trace;
    let solve = (solve_start.elapsed() - trace.spent).as_secs_f64();
    // Left out of the solve's time, so say it where it can be seen.
    log::debug!(
        "convergence trace: {} points, {:.2} s",
        trace.points.len(),
        trace.spent.as_secs_f64()
    );
    Ok(Solved {
        stats,
        trace,
        solve,
        ambient,
        ambient_traffic,
    })
}

/// Solves `scene` over the ranks of `comm` (every rank calls this with the
/// same arguments) and, on rank 0, renders the camera view and the report.
/// Other ranks get `Ok(None)`.
pub fn render_on(
    gpu: &Gpu,
    scene: &Scene,
    opts: &RenderOptions,
    comm: &dyn Collectives,
    load_time: Duration,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Option<Rendered>, RenderError> {
    opts.validate()?;
    scene.check_lit()?;
    let job = Job {
        gpu,
        scene,
        opts,
        comm,
    };
    super::checks::check_settings(gpu, opts, comm)?;
    let mut timings = Timings {
        load: load_time.as_secs_f64(),
        ..Default::default()
    };
    let fingerprint = fingerprint(scene, opts, opts.rasteriser_for(gpu.is_cpu()));
    let Refined {
        mesh,
        refinement,
        factors,
        trace: passes,
        interrupted,
        ..
    } = mesh_phase(job, &fingerprint, &mut timings, progress)?;
    let t = Instant::now();
    let one = Single::default();
    let mut source = GpuFormFactors::for_solve(gpu, &mesh, opts, (comm, &one), scene.extent())?;
    timings.setup = t.elapsed().as_secs_f64();
    crate::report::log_memory("the rasteriser's set-up");
    let start = Start {
        refinement: &refinement,
        passes,
        handoff: interrupted,
    };
    let (mut solver, so_far) = start_solver(job, &mesh, start)?;
    crate::report::log_memory("the solver's set-up");
    let header = Header {
        scene: scene.name.clone(),
        fingerprint,
        counts: [mesh.patches.len(), mesh.elements.len()],
        factors,
        refinement: refinement.clone(),
        ..Header::default()
    };
    // The passes' and the set-up's exchanges are not the final solve's.
    let before = comm.traffic();
    let cpu_start = crate::parallel::process_cpu_seconds();
    let solved = final_solve(job, &mut source, &mut solver, so_far, header, progress)?;
    timings.solve = solved.solve;
    // The transport is estimated before the first pass, or here.
    timings.ambient = refinement.transport_seconds + solved.ambient;
    source.release_cache();
    let excluded = not_exchanges(&solved, &source, before);
    // The trace's summaries are left out of the solve's CPU as of its time.
    let cpu = crate::parallel::process_cpu_seconds() - cpu_start - solved.trace.spent_cpu;
    let layout = source.layout();
    let Some(gathered) = gather_to_root(comm, solver, &solved.stats, source, (excluded, cpu))
    else {
        return Ok(None);
    };
    crate::report::log_memory("the solve");
    let shots = gathered.whole.shots();
    phase_timings(&mut timings, &gathered.phases, &solved.stats, shots);
    let (solver, parallel) = gathered.parallel(layout, opts, &mesh);
    let interrupted = solved.stats.interrupted;
    let (image, mut report) = finish(job, &solver, timings, parallel, solved)?;
    report.refinement = refinement;
    let radiosity = solver.display_radiosity(opts.ambient);
    drop(solver);
    Ok(Some(Rendered {
        mesh,
        radiosity,
        image,
        report,
        interrupted,
    }))
}

/// The mesh to solve ([`solve_mesh`]), its time in `timings` (the
/// passes' solves count as solve time, their traces' bookkeeping nowhere).
fn mesh_phase(
    job: Job<'_>,
    fingerprint: &str,
    timings: &mut Timings,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Refined, RenderError> {
    let t = Instant::now();
    let refined = solve_mesh(job, fingerprint, progress)?;
    let passes = refined.refinement.seconds + refined.bookkeeping;
    timings.mesh = (t.elapsed().as_secs_f64() - passes).max(0.0);
    if job.comm.rank() == 0 {
        log_mesh(job.scene, &refined.mesh);
    }
    crate::report::log_memory("the mesh");
    Ok(refined)
}

/// The traffic that is not the final solve's form-factor exchanges: what
/// came `before` it, the trace's gathers, the transport's, and the
/// occlusion cull's agreements and the rectangles' deal (counted apart, per
/// rank).
fn not_exchanges(solved: &Solved, source: &GpuFormFactors, before: Traffic) -> Traffic {
    solved
        .trace
        .traffic
        .plus(before)
        .plus(solved.ambient_traffic)
        .plus(source.timings.cull_traffic)
        .plus(source.timings.rect_traffic)
}

/// Says, on rank 0, when a batch is smaller than the rank count.
/// A camera image: width, height and linear radiance pixels, top row first.
type Image = (u32, u32, Vec<[f32; 3]>);

fn log_mesh(scene: &Scene, mesh: &Mesh) {
    log::info!(
        "{}: {} polygons, {} patches, {} elements",
        scene.name,
        scene.polygons.len(),
        mesh.patches.len(),
        mesh.elements.len()
    );
}

/// What rank 0 holds after the gather.
struct Gathered<'m> {
    /// The whole solution.
    whole: Solver<'m>,
    /// Rank 0's phase times.
    phases: PhaseTimes,
    /// Every rank's statistics.
    per_rank: Vec<RankStats>,
    /// Every rank's busy time per shot.
    busy: Vec<Vec<f64>>,
    /// ... and its busy CPU seconds per shot.
    busy_cpu: Vec<Vec<f64>>,
    /// Batched shots' rows, in shot order.
    rows: Vec<crate::report::BatchRow>,
}

impl<'m> Gathered<'m> {
    /// The whole solution, and the report's `parallel` section from what
    /// was gathered.
    fn parallel(
        self,
        layout: TileLayout,
        opts: &RenderOptions,
        mesh: &Mesh,
    ) -> (Solver<'m>, Parallel) {
        let d = Decomposition {
            ranks: self.per_rank.len(),
            layout,
            exchange: opts.exchange,
            resolution: opts.resolution,
        };
        let mut parallel = Parallel::new(
            d,
            mesh.elements.len(),
            self.whole.shots(),
            self.per_rank,
            LoadBalance::from_busy(&self.busy),
        );
        parallel.load_balance_cpu = LoadBalance::from_busy(&self.busy_cpu);
        if opts.batch > 1 {
            // Batched rows travel as pairs to their owners: no closed form.
            parallel.batch = opts.batch;
            parallel.rows = self.rows;
            if parallel.ranks > 1 {
                parallel.formula_bytes_per_shot = None;
            }
        }
        (self.whole, parallel)
    }
}

/// Gathers the solution and every rank's statistics to rank 0; `None` on
/// the other ranks. The rasteriser and the rank's solver are dropped before
/// the whole solution is built: the three at once were double-sided
/// Sponza's peak memory.
fn gather_to_root<'m>(
    comm: &dyn Collectives,
    solver: Solver<'m>,
    stats: &LoopStats,
    mut source: GpuFormFactors,
    (excluded, cpu): (Traffic, f64),
) -> Option<Gathered<'m>> {
    let extra = Extra {
        direct: true,
        ..Extra::default()
    };
    let (timings, busy, busy_cpu) = (
        source.timings,
        std::mem::take(&mut source.busy),
        std::mem::take(&mut source.busy_cpu),
    );
    drop(source);
    let whole = gather_whole_consuming(comm, solver, extra);
    let traffic = comm.traffic().since(excluded);
    let mine = pack_rank_stats(&timings, stats, traffic, cpu);
    let all_stats = comm.gather_f64(&mine);
    let busy = comm.gather_f64(&busy);
    let busy_cpu = comm.gather_f64(&busy_cpu);
    let rows: Vec<f64> = stats
        .rows
        .iter()
        .flat_map(|r| {
            [
                r.batch_start as f64,
                f64::from(r.index),
                f64::from(r.round),
                r.cost,
                r.cpu_seconds,
            ]
        })
        .collect();
    let rows = comm.gather_f64(&rows);
    let (whole, all_stats, busy, busy_cpu, rows) = (whole?, all_stats?, busy?, busy_cpu?, rows?);
    let mut rows: Vec<crate::report::BatchRow> = rows
        .iter()
        .enumerate()
        .flat_map(|(rank, v)| {
            v.chunks_exact(5).map(move |r| crate::report::BatchRow {
                batch_start: r[0] as u64,
                index: r[1] as u32,
                round: r[2] as u32,
                rank,
                cost: r[3],
                cpu_seconds: r[4],
            })
        })
        .collect();
    rows.sort_by_key(|r| (r.batch_start, r.round, r.index));
    Some(Gathered {
        whole,
        phases: timings,
        per_rank: all_stats
            .iter()
            .enumerate()
            .map(|(r, v)| unpack_rank_stats(r, v))
            .collect(),
        busy,
        busy_cpu,
        rows,
    })
}

/// One rank's phase seconds and bytes, for the gather: `traffic` is the
/// final solve's exchanges (not the trace's gathers or the refinement
/// passes'), `cpu` the process CPU seconds the final solve took.
fn pack_rank_stats(t: &PhaseTimes, stats: &LoopStats, traffic: Traffic, cpu: f64) -> Vec<f64> {
    vec![
        stats.select.as_secs_f64(),
        t.bounds.as_secs_f64(),
        t.rasterise.as_secs_f64(),
        t.read_back.as_secs_f64(),
        t.exchange.as_secs_f64(),
        t.sum.as_secs_f64(),
        stats.update.as_secs_f64(),
        traffic.sent as f64,
        traffic.received as f64,
        t.rects as f64,
        t.cells as f64,
        t.receivers as f64,
        crate::report::peak_resident_bytes() as f64,
        cpu,
        // Every collective of the final solve: the model counts the rank's
        // own work as its CPU outside all of them, and their calls' latency.
        traffic.cpu_seconds + t.cull_traffic.cpu_seconds + t.rect_traffic.cpu_seconds,
        (traffic.calls + t.cull_traffic.calls + t.rect_traffic.calls) as f64,
        t.bounded as f64,
        t.cull_traffic.received as f64,
        t.rect_traffic.received as f64,
        stats.rows_cpu_seconds,
    ]
}

/// [`pack_rank_stats`] read back, for rank `rank`.
fn unpack_rank_stats(rank: usize, v: &[f64]) -> RankStats {
    RankStats {
        rank,
        select_shooter: v[0],
        bounds: v[1],
        rasterise: v[2],
        read_back: v[3],
        exchange: v[4],
        sum_form_factors: v[5],
        update: v[6],
        bytes_sent: v[7] as u64,
        bytes_received: v[8] as u64,
        rects: v[9] as u64,
        cells: v[10] as u64,
        receivers: v[11] as u64,
        peak_resident_bytes: v[12] as u64,
        cpu_seconds: v[13],
        mpi_cpu_seconds: v[14],
        mpi_calls: v[15] as u64,
        bounded: v[16] as u64,
        occlusion_bytes_received: v[17] as u64,
        rect_bytes_received: v[18] as u64,
        rows_cpu_seconds: v[19],
    }
}

/// Fills the report's per-phase timings from rank 0's measurements.
fn phase_timings(timings: &mut Timings, t: &PhaseTimes, stats: &LoopStats, shots: u64) {
    timings.select_shooter = stats.select.as_secs_f64();
    timings.update = stats.update.as_secs_f64();
    timings.bounds = t.bounds.as_secs_f64();
    timings.rects_per_shot = t.rects as f64 / shots.max(1) as f64;
    timings.occluded_per_shot = t.occluded as f64 / shots.max(1) as f64;
    timings.skipped_per_shot = t.skipped as f64 / shots.max(1) as f64;
    timings.cached_shots = t.cached;
    timings.row_cache_bytes = t.cache_budget;
    timings.split_shots = t.split;
    timings.coarse_shots = t.coarse;
    timings.transport_shots = t.transported;
    timings.drawn_ahead_shots = t.drawn_ahead;
    timings.rasterise = t.rasterise.as_secs_f64();
    timings.read_back = t.read_back.as_secs_f64();
    timings.exchange = t.exchange.as_secs_f64();
    timings.sum_form_factors = t.sum.as_secs_f64();
    timings.far_receivers = t.far.as_secs_f64();
    timings.far_receivers_ahead = t.far_ahead.as_secs_f64();
    let total: Duration = stats.shot_times.iter().sum();
    timings.mean_shot_ms = total.as_secs_f64() * 1e3 / stats.shot_times.len().max(1) as f64;
    let mut shot_times = stats.shot_times.clone();
    shot_times.sort();
    timings.median_shot_ms = shot_times
        .get(shot_times.len() / 2)
        .map_or(0.0, |d| d.as_secs_f64() * 1e3);
}

/// Rank 0's end of a render: the image, and the report with its trace.
fn finish(
    job: Job<'_>,
    solver: &Solver,
    mut timings: Timings,
    parallel: Parallel,
    solved: Solved,
) -> Result<(Option<Image>, Report), RenderError> {
    let Job {
        gpu, scene, opts, ..
    } = job;
    let mesh = solver.mesh();
    let t = Instant::now();
    let camera = scene.camera.unwrap_or_else(|| scene.default_camera());
    let height = opts.image_height(camera.aspect);
    let image = if opts.width > 0 {
        let view = view_for(gpu, [opts.width, height], opts.shading, opts.wireframe);
        let pixels = solution_image(gpu, scene, solver, opts, &camera, &view)?;
        Some((opts.width, height, pixels))
    } else {
        None
    };
    timings.image = t.elapsed().as_secs_f64();
    let shots = solver.shots();
    let run = RunRecord {
        image_size: [opts.width, height],
        timings,
        parallel,
    };
    let mut report = build_report(scene, mesh, opts, solver, gpu, run);
    report.convergence = solved.trace.finish(&report, solved.solve);
    report
        .warnings
        .extend(super::checks::device_on_a_cpu(gpu, opts));
    if solved.stats.lossless {
        let w = format!(
            "stopped after {shots} shots: the scene keeps {:.1} % of its light unshot, so it cannot converge (a closed scene whose surfaces reflect all light: check reflectances of 1)",
            100.0 * report.unshot_fraction
        );
        log::warn!("{w}");
        report.warnings.push(w);
    }
    if solved.stats.interrupted {
        report.warnings.push(match &opts.checkpoint {
            Some(plan) => format!(
                "interrupted after {shots} shots; the state is saved in {}: resume with --resume {}",
                plan.path.display(),
                plan.path.display()
            ),
            None => format!("interrupted after {shots} shots (no checkpoint to resume from)"),
        });
    }
    Ok((image, report))
}

/// What a run measured beside its solution: the image's size, the phases'
/// timings and the ranks' section.
pub struct RunRecord {
    /// The camera image's width and height (0 wide: none).
    pub image_size: [u32; 2],
    /// The phases' seconds.
    pub timings: Timings,
    /// The ranks, their statistics and the exchange.
    pub parallel: Parallel,
}

/// The report of a (gathered) solution: settings, counts, progress and surfaces.
pub fn build_report(
    scene: &Scene,
    mesh: &Mesh,
    opts: &RenderOptions,
    solver: &Solver,
    gpu: &Gpu,
    run: RunRecord,
) -> Report {
    let RunRecord {
        image_size,
        timings,
        parallel,
    } = run;
    let unshot_fraction = solver.unshot_fraction();
    Report {
        scene: scene.name.clone(),
        settings: Settings {
            resolution: opts.resolution,
            form_factor: opts.form_factor,
            threshold: opts.stop.threshold,
            max_shots: opts.stop.max_shots,
            mesh: opts.mesh_settings(),
            raster_pieces: opts.raster_pieces,
            occlusion_cull: opts.occlusion_cull,
            deal_bounds: opts.deal_bounds,
            projection: opts.projection,
            tessellation_tolerance: (opts.projection == Projection::Tessellated)
                .then_some(opts.tessellation_tolerance),
            rasteriser: opts.rasteriser_for(gpu.is_cpu()),
            image_size,
            shading: opts.shading,
            shadow_rays: opts.shadow_rays,
            background: opts.background,
            gather: opts.gather,
            ambient: opts.ambient.is_on(),
            ambient_term: opts.ambient,
            coarse: opts
                .coarse_tier()
                .map(|c| (c.to_string(), opts.coarse_below)),
            transport_below: opts.transport_below_for(mesh.patches.len()),
        },
        device: gpu.describe(),
        lights: scene
            .lights
            .iter()
            .map(crate::report::LightSummary::of)
            .collect(),
        sky: scene.sky,
        sky_map: scene.sky_map.as_ref().map(|m| m.describe()),
        refinement: Refinement::default(),
        bake: None,
        counts: Counts {
            polygons: scene.polygons.len(),
            patches: mesh.patches.len(),
            elements: mesh.elements.len(),
            cells: opts.resolution.cells(),
            ranks: parallel.ranks,
        },
        shots: solver.shots(),
        unshot_fraction,
        converged: unshot_fraction <= opts.stop.threshold,
        emitted_power: solver.emitted_power(),
        energy: solver.energy(),
        timings,
        parallel,
        surfaces: report::surfaces(mesh, &scene.nodes, solver.display_radiosities(opts.ambient)),
        convergence: Vec::new(),
        warnings: scene.warnings.clone(),
    }
}

/// The `parallel` section of a one-process solve.
pub fn single_process(res: Resolution, elements: usize, shots: u64) -> Parallel {
    let d = Decomposition {
        ranks: 1,
        layout: TileLayout::whole(res),
        exchange: Exchange::Hemispheres,
        resolution: res,
    };
    Parallel::new(d, elements, shots, Vec::new(), LoadBalance::default())
}
