//! The solve, on a background thread: the library's solver and GPU form
//! factors, driven by commands from the window and publishing snapshots.

use radiosity::gpu::Gpu;
use radiosity::lit_mesh::LitMesh;
use radiosity::mesh::Mesh;
use radiosity::parallel::Single;
use radiosity::render::write::{write_outputs, OutputPaths};
use radiosity::render::{
    build_report, refined_mesh_shown, single_process, AfterShot, GpuFormFactors, RenderOptions,
    ShotLoop, Step, Trace,
};
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
    pub mesh: Option<Arc<LitMesh>>,
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

/// Where the user has put the solve: running, paused, stepping, or stopped
/// at the automatic pause; and whether the loop has stopped by itself.
#[derive(Default)]
struct Control {
    paused: bool,
    steps_left: Option<u64>,
    /// The automatic pause applies once: a step or resume goes past it.
    pause_at: Option<u64>,
    /// The shooting loop said it is over (the stop rule is met).
    done: bool,
}

impl Control {
    /// Whether to shoot now, after `shots` shots.
    fn shooting(&self, shots: u64) -> bool {
        !(self.paused
            || self.done
            || self.pause_at.is_some_and(|n| shots >= n)
            || self.steps_left == Some(0))
    }

    /// Applies a pause, resume or step.
    fn apply(&mut self, cmd: &Command) {
        match cmd {
            Command::Pause => self.paused = true,
            Command::Resume => {
                self.paused = false;
                self.steps_left = None;
                self.pause_at = None;
            }
            Command::Step => {
                self.paused = false;
                self.steps_left = Some(1);
                self.pause_at = None;
            }
            _ => {}
        }
    }
}

/// One solve: the library's own mesh, form-factor source, solver and
/// shooting loop (exactly what `radiosity render` runs on one rank), stepped
/// a shot at a time between the window's commands. Returns the settings of a
/// requested restart, or `None` on quit.
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
    let refined = refined_mesh_shown(gpu, scene, opts, &single, &mut |_| {}, &mut {
        let mut shower = PassShower::new(shared, opts.ambient, wake);
        move |pass, solver: &Solver| shower.show(pass, solver)
    })
    .map_err(|e| e.to_string())?;
    let mesh = Arc::new(refined.mesh);
    // The passes' points and time come first, as in a render's report.
    let passes = (refined.trace, refined.refinement.seconds);
    let mut source = GpuFormFactors::new(gpu, &mesh, opts, &single, scene.extent())
        .map_err(|e| e.to_string())?;
    let mut solver = Solver::partitioned(&mesh, 0, 1);
    let mut shots = ShotLoop::new(&mesh, &single, opts.stop, 0.0);
    let mut pub_ = Publisher::start(shared, &mesh, &solver, opts, wake, passes)?;
    let mut control = Control {
        pause_at: settings.pause_at,
        ..Control::default()
    };
    loop {
        let idle = !control.shooting(solver.shots());
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
            Some(Command::Restart(next)) => return Ok(Some(next)),
            Some(Command::Quit) => return Ok(None),
            Some(Command::Save(req)) => {
                let outcome = save(gpu, scene, &mesh, opts, &solver, &pub_, &req);
                if let Ok(mut s) = shared.lock() {
                    s.saved = Some(outcome.unwrap_or_else(|e| format!("save failed: {e}")));
                }
                wake();
            }
            Some(c) => control.apply(&c),
            None => {}
        }
        let shooting = control.shooting(solver.shots());
        if shooting {
            let t = Instant::now();
            let step = shots
                .step(&mut source, &mut solver, &mut AfterShot(|_: &Solver, _| {}))
                .map_err(|e| e.to_string())?;
            pub_.solve_time += t.elapsed();
            match step {
                Step::Shot(shot) => {
                    if let Some(n) = control.steps_left.as_mut() {
                        *n = n.saturating_sub(1);
                    }
                    pub_.after_shot(&solver, &source, shot.shooter, &scene.nodes, &single)?;
                }
                Step::Stopped(_) => control.done = true,
            }
        }
        let now_idle = !control.shooting(solver.shots());
        pub_.idle(&solver, &source, now_idle, control.done);
    }
}

/// Publishes a refinement pass's solution as it comes (at most every
/// [`PUBLISH_PERIOD`]), on a copy of the pass's mesh geometry (the view
/// needs no more; the copy is made once a pass), so the window shows the
/// pass, as the report's trace does, instead of waiting for the final solve.
struct PassShower<'s, W: Fn()> {
    shared: &'s Mutex<Snapshot>,
    ambient: radiosity::settings::AmbientTerm,
    wake: &'s W,
    /// The pass whose mesh was copied, and the copy.
    mesh: Option<(u32, Arc<LitMesh>)>,
    last_publish: Option<Instant>,
}

impl<'s, W: Fn()> PassShower<'s, W> {
    fn new(
        shared: &'s Mutex<Snapshot>,
        ambient: radiosity::settings::AmbientTerm,
        wake: &'s W,
    ) -> Self {
        Self {
            shared,
            ambient,
            wake,
            mesh: None,
            last_publish: None,
        }
    }

    fn show(&mut self, pass: u32, solver: &Solver) {
        if self
            .last_publish
            .is_some_and(|t| t.elapsed() < PUBLISH_PERIOD)
        {
            return;
        }
        self.last_publish = Some(Instant::now());
        let mesh = match &self.mesh {
            Some((p, m)) if *p == pass => m.clone(),
            _ => {
                let m = solver.mesh();
                let copy = Arc::new(LitMesh::unlit(Mesh {
                    polygons: m.polygons.clone(),
                    patches: m.patches.clone(),
                    elements: m.elements.clone(),
                    vertices: m.vertices.clone(),
                    ..Mesh::default()
                }));
                self.mesh = Some((pass, copy.clone()));
                copy
            }
        };
        let radiance = Arc::new(solver.display_radiance(self.ambient));
        if let Ok(mut s) = self.shared.lock() {
            s.mesh = Some(mesh);
            s.radiance = radiance;
            s.shots = solver.shots();
            s.unshot_fraction = solver.unshot_fraction();
            s.version += 1;
        }
        (self.wake)();
    }
}

/// What the solve thread publishes to the window, and how often.
struct Publisher<'s, 'm, W: Fn()> {
    shared: &'s Mutex<Snapshot>,
    wake: &'s W,
    ambient: radiosity::settings::AmbientTerm,
    last_publish: Instant,
    /// Solve time so far (pauses left out).
    solve_time: Duration,
    /// The report's convergence trace, as `radiosity render` keeps it.
    trace: Trace<'m>,
}

impl<'s, 'm, W: Fn()> Publisher<'s, 'm, W> {
    /// Publishes the start of a solve (B = E) and returns the publisher,
    /// whose trace starts with the refinement passes' points and whose
    /// time with theirs (`passes`).
    fn start(
        shared: &'s Mutex<Snapshot>,
        mesh: &Arc<LitMesh>,
        solver: &Solver,
        opts: &RenderOptions,
        wake: &'s W,
        passes: (Vec<radiosity::report::TracePoint>, f64),
    ) -> Result<Self, String> {
        let mut trace = Trace::default();
        trace.points = passes.0;
        let res = opts.resolution;
        {
            let mut s = shared.lock().map_err(|_| "state lock poisoned")?;
            *s = Snapshot {
                mesh: Some(mesh.clone()),
                version: s.version + 1,
                resolution: (res.rows, res.cols),
                ..Snapshot::default()
            };
            s.radiance = Arc::new(solver.display_radiance(opts.ambient));
            s.trace = Arc::new(trace.points.clone());
        }
        wake();
        Ok(Self {
            shared,
            wake,
            ambient: opts.ambient,
            last_publish: Instant::now(),
            solve_time: Duration::from_secs_f64(passes.1.max(0.0)),
            trace,
        })
    }

    /// Records the trace when due and publishes the shot.
    fn after_shot(
        &mut self,
        solver: &Solver<'m>,
        source: &GpuFormFactors,
        shooter: u32,
        nodes: &[String],
        single: &Single,
    ) -> Result<(), String> {
        if self.trace.due(solver.shots()) {
            let seconds = self.solve_time.as_secs_f64();
            self.trace
                .record_at(single, solver, nodes, self.ambient, seconds);
            if let Ok(mut s) = self.shared.lock() {
                s.trace = Arc::new(self.trace.points.clone());
            }
        }
        let mut s = self.shared.lock().map_err(|_| "state lock poisoned")?;
        s.shots = solver.shots();
        s.unshot_fraction = solver.unshot_fraction();
        s.elapsed = self.solve_time;
        let point = (s.shots, self.solve_time.as_secs_f64(), s.unshot_fraction);
        Arc::make_mut(&mut s.history).push(point);
        s.shooter = Some(shooter);
        // The window redraws what is published: at most about 10 times a
        // second, so drawing never takes the cores the solve needs.
        if self.last_publish.elapsed() > PUBLISH_PERIOD {
            self.publish(&mut s, solver, source);
            drop(s);
            (self.wake)();
        }
        Ok(())
    }

    /// Publishes the final state of a run of shots once it goes idle.
    fn idle(&mut self, solver: &Solver, source: &GpuFormFactors, idle: bool, converged: bool) {
        let Ok(mut s) = self.shared.lock() else {
            return;
        };
        if idle && (s.paused != idle || s.converged != converged) {
            self.publish(&mut s, solver, source);
            (self.wake)();
        }
        s.paused = idle;
        s.converged = converged;
    }

    fn publish(&mut self, s: &mut Snapshot, solver: &Solver, source: &GpuFormFactors) {
        s.radiance = Arc::new(solver.display_radiance(self.ambient));
        let (items, res) = source.last_items();
        s.items = Arc::new(items.to_vec());
        s.resolution = (res.rows, res.cols);
        s.version += 1;
        self.last_publish = Instant::now();
    }
}

/// How often a running solve publishes its state.
const PUBLISH_PERIOD: Duration = Duration::from_millis(250);

/// Writes the image, the report (and with `req.bake` the bake) of the
/// current state, through the renderer's own write path.
fn save<W: Fn()>(
    gpu: &Gpu,
    scene: &Scene,
    mesh: &Mesh,
    opts: &RenderOptions,
    solver: &Solver,
    pub_: &Publisher<'_, '_, W>,
    req: &SaveRequest,
) -> Result<String, String> {
    let (w, h) = (800, 600);
    let mut camera = req.camera;
    camera.aspect = Some(w as f32 / h as f32);
    let view = radiosity::render::image::view_for(gpu, [w, h], req.shading, req.wireframe);
    // The renderer's own image path: traced direct light, the rest interpolated.
    let pixels = radiosity::render::image::solution_image(gpu, scene, solver, opts, &camera, &view)
        .map_err(|e| e.to_string())?;
    let seconds = pub_.solve_time.as_secs_f64();
    let timings = radiosity::report::Timings {
        solve: seconds,
        ..Default::default()
    };
    let parallel = single_process(opts.resolution, mesh.elements.len(), solver.shots());
    let run = radiosity::render::RunRecord {
        image_size: [w, h],
        timings,
        parallel,
    };
    let mut report = build_report(scene, mesh, opts, solver, gpu, run);
    report.convergence = pub_.trace.ending_with(&report, seconds);
    let paths = OutputPaths {
        image: Some(req.stem.with_extension("exr")),
        exposure: req.ev,
        bake: req.bake.then(|| req.stem.with_extension("glb")),
        report: req.stem.with_extension("json"),
    };
    let radiosity = solver.display_radiosity(opts.ambient);
    let written = write_outputs(
        &paths,
        scene,
        mesh,
        &radiosity,
        Some((w, h, &pixels)),
        &mut report,
    )
    .map_err(|e| e.to_string())?;
    Ok(written.lines().join("; "))
}

/// Sends a command, ignoring a solve thread that has already ended.
pub fn send(tx: &Sender<Command>, cmd: Command) {
    let _ = tx.send(cmd);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pass's solution reaches the window on a copy of its mesh's
    /// geometry, made once a pass, and at most every publish period.
    #[test]
    fn a_pass_is_shown_on_its_own_mesh() {
        let scene = radiosity::scene::open("cornell").expect("scene");
        let opts = RenderOptions::default();
        let mesh = LitMesh::build_refined(&scene, &opts.mesh_settings(), &[]);
        let solver = Solver::new(&mesh);
        let shared = Mutex::new(Snapshot::default());
        let woken = std::cell::Cell::new(0);
        let wake = || woken.set(woken.get() + 1);
        let mut shower = PassShower::new(&shared, opts.ambient, &wake);
        shower.show(0, &solver);
        let first = shared.lock().expect("lock").clone();
        let shown = first.mesh.clone().expect("the pass's mesh");
        assert_eq!(shown.elements.len(), mesh.elements.len());
        assert_eq!(*first.radiance, solver.display_radiance(opts.ambient));
        assert_eq!(woken.get(), 1);
        // Within the publish period nothing more is published.
        shower.show(0, &solver);
        assert_eq!(woken.get(), 1);
        // The next publish of the same pass reuses its copy.
        shower.last_publish = None;
        shower.show(0, &solver);
        let again = shared.lock().expect("lock").mesh.clone().expect("mesh");
        assert!(Arc::ptr_eq(&shown, &again));
        assert!(shared.lock().expect("lock").version > first.version);
    }
}
