//! The viewer's solve logic without a window: pause at a shot count, step,
//! resume, restart with new settings, quit.

use radiosity::gpu::Gpu;
use radiosity::gpu::Shading;
use radiosity::hemisphere::Resolution;
use radiosity::render::RenderOptions;
use radiosity_viewer::solve::{self, Command, SaveRequest, Settings, Snapshot};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Waits (bounded) until `cond` holds for the shared snapshot.
fn wait_for(shared: &Mutex<Snapshot>, what: &str, cond: impl Fn(&Snapshot) -> bool) -> Snapshot {
    let start = Instant::now();
    loop {
        let s = shared.lock().expect("lock").clone();
        if cond(&s) {
            return s;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "timed out waiting for {what}: {} shots, paused {}",
            s.shots,
            s.paused
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A device, the Cornell box and options for quick solves of it.
fn cornell_at_32x128() -> (Gpu, radiosity::scene::Scene, RenderOptions) {
    let gpu = Gpu::new().unwrap_or_else(|e| panic!("{e}"));
    let scene = radiosity::scene::open("cornell").expect("built-in scene");
    let options = RenderOptions {
        resolution: Resolution {
            rows: 32,
            cols: 128,
        },
        ..RenderOptions::default()
    };
    (gpu, scene, options)
}

#[test]
fn pause_step_resume_restart_quit() {
    let (gpu, scene, mut options) = cornell_at_32x128();
    options.stop.threshold = 0.02;
    let shared = Arc::new(Mutex::new(Snapshot::default()));
    let (tx, rx) = std::sync::mpsc::channel();
    let thread_shared = shared.clone();
    let handle = std::thread::spawn(move || {
        solve::run(
            gpu,
            scene,
            Settings {
                options,
                pause_at: Some(5),
            },
            rx,
            thread_shared,
            || {},
        )
    });

    // Pauses by itself after 5 shots, with the mesh, radiance and item buffer published.
    let s = wait_for(&shared, "the automatic pause", |s| s.shots == 5 && s.paused);
    assert_eq!(s.items.len(), 32 * 128);
    assert_eq!(
        s.radiance.len(),
        s.mesh.as_ref().expect("mesh").elements.len()
    );
    assert_eq!(s.history.len(), 5);
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(shared.lock().expect("lock").shots, 5, "a pause holds");

    // Step: exactly one more shot.
    solve::send(&tx, Command::Step);
    wait_for(&shared, "one step", |s| s.shots == 6 && s.paused);
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(shared.lock().expect("lock").shots, 6, "a step is one shot");

    // Resume: runs (not shown paused: the automatic pause is behind it) to the stop rule.
    solve::send(&tx, Command::Resume);
    wait_for(&shared, "running past the pause", |s| {
        s.shots > 6 && !s.paused && !s.converged
    });
    let s = wait_for(&shared, "convergence", |s| s.converged);
    assert!(s.unshot_fraction <= 0.02 && s.shots > 6);

    // Save writes what `radiosity render` writes: EXR, PNG and a JSON report.
    let dir = tempfile::tempdir().expect("temp dir");
    let stem = dir.path().join("saved");
    let camera = radiosity::scene::open("cornell")
        .expect("scene")
        .camera
        .expect("camera");
    solve::send(
        &tx,
        Command::Save(SaveRequest {
            camera,
            shading: Shading::Flat,
            wireframe: true,
            ev: 0.0,
            stem: stem.clone(),
            bake: true,
        }),
    );
    let s = wait_for(&shared, "the save", |s| s.saved.is_some());
    assert!(
        s.saved.as_deref().is_some_and(|m| m.starts_with("wrote")),
        "{:?}",
        s.saved
    );
    for ext in ["exr", "png", "json", "glb"] {
        assert!(stem.with_extension(ext).exists(), "{ext} missing");
    }
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(stem.with_extension("json")).expect("report"),
    )
    .expect("json");
    assert_eq!(report["shots"].as_u64(), Some(s.shots));
    assert_eq!(report["surfaces"].as_array().map(Vec::len), Some(8));
    // The bake of the current state, as `radiosity render --bake` writes it.
    assert!(report["bake"]["scale"].as_f64().is_some_and(|x| x > 0.0));
    let baked = radiosity::scene::load(&stem.with_extension("glb")).expect("the bake loads");
    assert_eq!(baked.nodes.len(), 8);
    // The snapshot carries the trace the plot draws.
    assert!(s.trace.len() >= 2, "{} trace points", s.trace.len());
    // The convergence trace, as `radiosity render` writes it: ends at the report.
    let trace = report["convergence"].as_array().expect("trace");
    let last = trace.last().expect("a point");
    assert_eq!(last["shots"], report["shots"]);
    assert_eq!(last["surfaces"], report["surfaces"]);
    assert!(trace.len() >= 2, "{} points", trace.len());

    // Restart with another resolution: starts again from no shots.
    let mut options = RenderOptions {
        resolution: Resolution { rows: 16, cols: 64 },
        ..RenderOptions::default()
    };
    // Above what the emitters' traced first shot leaves unshot (0.44).
    options.stop.threshold = 0.3;
    solve::send(
        &tx,
        Command::Restart(Settings {
            options,
            pause_at: Some(2),
        }),
    );
    let s = wait_for(&shared, "the restart", |s| {
        s.resolution == (16, 64) && s.shots == 2 && s.paused
    });
    assert_eq!(s.items.len(), 16 * 64);

    solve::send(&tx, Command::Quit);
    handle.join().expect("the solve thread ends cleanly");
}

/// The viewer drives the renderer's own shooting loop: the same settings
/// give the same shots, unshot fraction and radiance, bit for bit, and the
/// same convergence trace.
#[test]
fn the_viewer_and_the_renderer_give_the_same_numbers() {
    let (gpu, scene, mut options) = cornell_at_32x128();
    options.width = 0;
    // The ambient term is where the two drivers once differed: on.
    options.stop.threshold = 0.01;
    let rendered = radiosity::render::render(&gpu, &scene, &options, Duration::ZERO, &mut |_| {})
        .expect("render");

    let shared = Arc::new(Mutex::new(Snapshot::default()));
    let (tx, rx) = std::sync::mpsc::channel();
    let thread_shared = shared.clone();
    let viewer_scene = scene.clone();
    let viewer_options = options.clone();
    let handle = std::thread::spawn(move || {
        solve::run(
            gpu,
            viewer_scene,
            Settings {
                options: viewer_options,
                pause_at: None,
            },
            rx,
            thread_shared,
            || {},
        )
    });
    let s = wait_for(&shared, "convergence", |s| s.converged);
    solve::send(&tx, Command::Quit);
    handle.join().expect("solve thread");

    assert_eq!(s.shots, rendered.report.shots, "shots");
    assert_eq!(s.unshot_fraction, rendered.report.unshot_fraction);
    let radiance: Vec<[f32; 3]> = rendered
        .radiosity
        .iter()
        .map(|b| b.map(|x| (x / std::f64::consts::PI) as f32))
        .collect();
    assert_eq!(*s.radiance, radiance, "per-element radiance");
    // The trace at the same shot counts of the same pass or final solve
    // (the report's last point is the final result, which the viewer's
    // trace need not have reached).
    let report_trace = &rendered.report.convergence;
    let mut compared = 0;
    assert!(
        s.trace.iter().any(|p| p.pass.is_some()),
        "the pass's points"
    );
    for p in s.trace.iter() {
        if let Some(q) = report_trace
            .iter()
            .find(|q| (q.pass, q.shots) == (p.pass, p.shots))
        {
            assert_eq!(p.surfaces, q.surfaces, "trace at {} shots", p.shots);
            assert_eq!(p.unshot_fraction, q.unshot_fraction);
            compared += 1;
        }
    }
    assert!(compared >= 10, "{compared} trace points compared");
}
