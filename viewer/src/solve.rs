//! The solve, on a background thread: the library's solver and GPU form
//! factors, driven by commands from the window and publishing snapshots.

use radiosity::gpu::Gpu;
use radiosity::mesh::Mesh;
use radiosity::parallel::Single;
use radiosity::render::{GpuFormFactors, RenderOptions};
use radiosity::scene::Scene;
use radiosity::solver::Solver;
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// What the window can ask of the solve.
#[derive(Clone, Debug)]
pub enum Command {
    /// Stop shooting until resumed.
    Pause,
    /// Shoot until the stop rule is met.
    Resume,
    /// One shot, then pause.
    Step,
    /// Start again from B = E with new settings.
    Restart(Settings),
    /// Write the current image (EXR + PNG) and report, as `radiosity render` does.
    Save(SaveRequest),
    /// End the thread.
    Quit,
}

/// What to save and how to draw it.
#[derive(Clone, Debug)]
pub struct SaveRequest {
    /// The view to render.
    pub camera: radiosity::scene::Camera,
    /// Smooth or flat.
    pub shading: radiosity::gpu::Shading,
    /// Element edges on top.
    pub wireframe: bool,
    /// PNG exposure adjustment in stops.
    pub ev: f32,
    /// Also bake the solution to glTF (`STEM.glb`, as `radiosity render --bake`).
    pub bake: bool,
    /// Output paths without extension (".exr", ".png", ".json" are added).
    pub stem: std::path::PathBuf,
}

/// Settings a restart may change.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Hemisphere resolution, subdivision and stop rule.
    pub options: RenderOptions,
    /// Pause after this many shots (for screenshots).
    pub pause_at: Option<u64>,
}

/// The state the window shows.
#[derive(Clone, Default)]
pub struct Snapshot {
    /// Bumped whenever the radiosities change.
    pub version: u64,
    /// The mesh being solved (replaced on restart).
    pub mesh: Option<Arc<Mesh>>,
    /// Display radiance per element (B plus ambient, over pi). Shared, so
    /// the UI's copy of a snapshot each frame copies no arrays.
    pub radiance: Arc<Vec<[f32; 3]>>,
    /// Shots so far.
    pub shots: u64,
    /// Unshot power fraction.
    pub unshot_fraction: f64,
    /// Solve time so far.
    pub elapsed: Duration,
    /// (shots, seconds, unshot fraction) after every shot.
    pub history: Arc<Vec<(u64, f64, f64)>>,
    /// The convergence trace so far (as in the report: per-node radiosities
    /// at log-spaced shot counts).
    pub trace: Arc<Vec<radiosity::report::TracePoint>>,
    /// The last shot's item buffer and resolution (rows, cols), and its shooter patch.
    pub items: Arc<Vec<u32>>,
    /// Hemisphere rows and columns.
    pub resolution: (u32, u32),
    /// The last shooter patch.
    pub shooter: Option<u32>,
    /// Paused (by the user, a step, or the stop rule).
    pub paused: bool,
    /// Whether the stop rule is met.
    pub converged: bool,
    /// A failure, shown in the window.
    pub error: Option<String>,
    /// The outcome of the last save.
    pub saved: Option<String>,
}

/// Runs solves until told to quit. Publishes into `shared` and calls `wake` after each update.
pub fn run(
    gpu: Gpu,
    scene: Scene,
    mut settings: Settings,
    commands: Receiver<Command>,
    shared: Arc<Mutex<Snapshot>>,
    wake: impl Fn(),
) {
    loop {
        match solve(&gpu, &scene, &settings, &commands, &shared, &wake) {
            Ok(Some(next)) => settings = next,
            Ok(None) => return,
            Err(e) => {
                if let Ok(mut s) = shared.lock() {
                    s.error = Some(e);
                    s.paused = true;
                }
                wake();
                // Wait for a restart or quit.
                loop {
                    match commands.recv() {
                        Ok(Command::Restart(next)) => {
                            settings = next;
                            break;
                        }
                        Ok(Command::Quit) | Err(_) => return,
                        Ok(_) => {}
                    }
                }
            }
        }
    }
}

/// One solve; returns the settings of a requested restart, or `None` on quit.
fn solve(
    gpu: &Gpu,
    scene: &Scene,
    settings: &Settings,
    commands: &Receiver<Command>,
    shared: &Mutex<Snapshot>,
    wake: &impl Fn(),
) -> Result<Option<Settings>, String> {
    let opts = &settings.options;
    let single = Single::default();
    // The same mesh `radiosity render` solves (refinement passes included).
    let (mesh, _, _) = radiosity::render::refined_mesh(gpu, scene, opts, &single, &mut |_| {})
        .map_err(|e| e.to_string())?;
    let mesh = Arc::new(mesh);
    let mut source = GpuFormFactors::new(gpu, &mesh, opts, &single, scene.extent())
        .map_err(|e| e.to_string())?;
    let mut solver = Solver::new(&mesh);
    solver.set_overshoot(opts.overshoot);
    let res = opts.resolution;
    {
        let mut s = shared.lock().map_err(|_| "state lock poisoned")?;
        *s = Snapshot {
            mesh: Some(mesh.clone()),
            version: s.version + 1,
            resolution: (res.rows, res.cols),
            ..Snapshot::default()
        };
        s.radiance = Arc::new(display(&solver));
    }
    wake();
    let mut paused = false;
    let mut steps_left: Option<u64> = None;
    // The automatic pause applies once: a step or resume goes past it.
    let mut pause_at = settings.pause_at;
    let mut solve_time = Duration::ZERO;
    // The report's convergence trace, as `radiosity render` keeps it.
    let mut trace = radiosity::render::Trace::default();
    let mut last_publish = Instant::now();
    loop {
        let done = solver.done(&opts.stop);
        let at_pause = pause_at.is_some_and(|n| solver.shots() >= n);
        let idle = paused || done || at_pause || steps_left == Some(0);
        let cmd = if idle {
            match commands.recv_timeout(Duration::from_millis(100)) {
                Ok(c) => Some(c),
                Err(RecvTimeoutError::Timeout) => None,
                Err(RecvTimeoutError::Disconnected) => return Ok(None),
            }
        } else {
            commands.try_recv().ok()
        };
        match cmd {
            Some(Command::Pause) => paused = true,
            Some(Command::Resume) => {
                paused = false;
                steps_left = None;
                pause_at = None;
            }
            Some(Command::Step) => {
                paused = false;
                steps_left = Some(1);
                pause_at = None;
            }
            Some(Command::Restart(next)) => return Ok(Some(next)),
            Some(Command::Save(req)) => {
                let outcome = save(gpu, scene, &mesh, opts, &solver, solve_time, &trace, &req);
                if let Ok(mut s) = shared.lock() {
                    s.saved = Some(outcome.unwrap_or_else(|e| format!("save failed: {e}")));
                }
                wake();
            }
            Some(Command::Quit) => return Ok(None),
            None => {}
        }
        let shooting = !(paused
            || done
            || pause_at.is_some_and(|n| solver.shots() >= n)
            || steps_left == Some(0));
        if shooting {
            let t = Instant::now();
            let Some(shot) = solver.step(&mut source).map_err(|e| e.to_string())? else {
                paused = true;
                continue;
            };
            let shooter = shot.shooter;
            solve_time += t.elapsed();
            if trace.due(solver.shots()) {
                let seconds = solve_time.as_secs_f64();
                trace.record_at(&single, &solver, &scene.nodes, opts.ambient, seconds);
                if let Ok(mut s) = shared.lock() {
                    s.trace = Arc::new(trace.points.clone());
                }
            }
            if let Some(n) = steps_left.as_mut() {
                *n = n.saturating_sub(1);
            }
            let mut s = shared.lock().map_err(|_| "state lock poisoned")?;
            s.shots = solver.shots();
            s.unshot_fraction = solver.unshot_fraction();
            s.elapsed = solve_time;
            let point = (s.shots, solve_time.as_secs_f64(), s.unshot_fraction);
            Arc::make_mut(&mut s.history).push(point);
            s.shooter = Some(shooter);
            // Small scenes publish every shot; large ones at about 10 Hz.
            if mesh.elements.len() < 20_000 || last_publish.elapsed() > Duration::from_millis(100) {
                s.radiance = Arc::new(display(&solver));
                let (items, res) = source.last_items();
                s.items = Arc::new(items.to_vec());
                s.resolution = (res.rows, res.cols);
                s.version += 1;
                last_publish = Instant::now();
            }
            drop(s);
            wake();
        }
        let now_idle = !shooting
            || solver.done(&opts.stop)
            || pause_at.is_some_and(|n| solver.shots() >= n)
            || steps_left == Some(0);
        if let Ok(mut s) = shared.lock() {
            let converged = solver.done(&opts.stop);
            if now_idle && (s.paused != now_idle || s.converged != converged) {
                // Publish the final state of a run of shots.
                s.radiance = Arc::new(display(&solver));
                let (items, res) = source.last_items();
                s.items = Arc::new(items.to_vec());
                s.resolution = (res.rows, res.cols);
                s.version += 1;
                wake();
            }
            s.paused = now_idle;
            s.converged = converged;
        }
    }
}

/// Writes the image and the report of the current state.
#[allow(clippy::too_many_arguments)]
fn save(
    gpu: &Gpu,
    scene: &Scene,
    mesh: &Mesh,
    opts: &RenderOptions,
    solver: &Solver,
    solve_time: Duration,
    trace: &radiosity::render::Trace,
    req: &SaveRequest,
) -> Result<String, String> {
    let (w, h) = (800, 600);
    let mut camera = req.camera;
    camera.aspect = Some(w as f32 / h as f32);
    let view = radiosity::gpu::ViewSettings {
        width: w,
        height: h,
        shading: req.shading,
        supersample: 2,
        wireframe: req.wireframe,
    };
    let pixels = radiosity::gpu::render_view(
        &gpu.device,
        &gpu.queue,
        mesh,
        &display(solver),
        &camera,
        &view,
    )
    .map_err(|e| e.to_string())?;
    let exr = req.stem.with_extension("exr");
    radiosity::output::write_image(&exr, w, h, &pixels, req.ev).map_err(|e| e.to_string())?;
    let timings = radiosity::report::Timings {
        solve: solve_time.as_secs_f64(),
        ..Default::default()
    };
    let parallel =
        radiosity::render::single_process(opts.resolution, mesh.elements.len(), solver.shots());
    let mut report =
        radiosity::render::build_report(scene, mesh, opts, solver, gpu, [w, h], timings, parallel);
    report.convergence = trace.ending_with(&report, solve_time.as_secs_f64());
    let mut wrote = format!("wrote {}, .png and .json", exr.display());
    if req.bake {
        let glb = req.stem.with_extension("glb");
        let radiosity = solver.display_radiosity(opts.ambient);
        let baked =
            radiosity::bake::write(&glb, scene, mesh, &radiosity).map_err(|e| e.to_string())?;
        wrote += &format!(" and {}", glb.display());
        report.bake = Some(baked);
    }
    let json = req.stem.with_extension("json");
    radiosity::output::write_json(&json, &report).map_err(|e| e.to_string())?;
    Ok(wrote)
}

fn display(solver: &Solver) -> Vec<[f32; 3]> {
    solver
        .display_radiosity(true)
        .iter()
        .map(|b| b.map(|x| (x / std::f64::consts::PI) as f32))
        .collect()
}

/// Sends a command, ignoring a solve thread that has already ended.
pub fn send(tx: &Sender<Command>, cmd: Command) {
    let _ = tx.send(cmd);
}
