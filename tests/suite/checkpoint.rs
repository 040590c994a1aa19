//! Checkpoint and resume: a solve stopped between two shots and resumed (in
//! another tile layout) ends bit for bit where an uninterrupted one does.

use crate::common::*;
use radiosity::checkpoint::Checkpoint;
use radiosity::hemisphere::TileLayout;
use radiosity::render::{render, CheckpointPlan, RenderOptions, Rendered};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

fn cornell(opts: &RenderOptions, stop_at: Option<u64>) -> Rendered {
    let scene = radiosity::scene::open("cornell").expect("built-in scene");
    solve_scene(&scene, opts, stop_at)
}

/// The Cornell box with a point light, a sun, a sky and a sky map besides
/// its panel.
fn lit_cornell() -> radiosity::scene::Scene {
    use radiosity::scene::{Light, LightKind};
    let mut scene = radiosity::scene::open("cornell").expect("built-in scene");
    let (lo, hi) = scene.bounds();
    scene.lights.push(Light {
        name: "bulb".into(),
        kind: LightKind::Point,
        position: lo + (hi - lo) * glam::Vec3::new(0.3, 0.7, 0.6),
        direction: -glam::Vec3::Z,
        intensity: [0.05, 0.04, 0.03],
    });
    scene
        .lights
        .push(Light::sun(glam::Vec3::new(0.2, 0.4, 1.0), [2.0; 3]));
    scene.sky = Some([0.1, 0.12, 0.2]);
    scene.sky_map = Some(Arc::new(sky_map(0.0)));
    scene
}

/// An 8 x 4 sky map brighter toward the zenith and on one side, turned
/// `turn` degrees.
fn sky_map(turn: f64) -> radiosity::scene::SkyMap {
    let texels = (0..32u32)
        .map(|k| [0.05 * (4 - k / 8) as f32 + if k % 8 < 2 { 0.3 } else { 0.0 }; 3])
        .collect();
    radiosity::scene::SkyMap::from_texels("test", [8, 4], texels, [turn, 1.0]).expect("a map")
}

/// Solves `scene` with a checkpoint at `path`, stopped by a signal after
/// shot `stop_at`, then resumes it from the checkpoint (`opts` is left
/// resuming).
fn stop_and_resume(
    scene: &radiosity::scene::Scene,
    opts: &mut RenderOptions,
    path: &std::path::Path,
    stop_at: u64,
) -> Rendered {
    opts.checkpoint = Some(CheckpointPlan {
        path: path.to_path_buf(),
        every: None,
    });
    opts.interrupt = Some(Arc::new(AtomicBool::new(false)));
    assert!(solve_scene(scene, opts, Some(stop_at)).interrupted);
    opts.interrupt = None;
    opts.checkpoint = None;
    opts.resume = Some(Arc::new(Checkpoint::read(path).expect("checkpoint")));
    solve_scene(scene, opts, None)
}

fn solve_scene(
    scene: &radiosity::scene::Scene,
    opts: &RenderOptions,
    stop_at: Option<u64>,
) -> Rendered {
    let flag = opts.interrupt.clone();
    render(gpu(), scene, opts, Duration::ZERO, &mut |p| {
        // A signal arriving after shot `stop_at` (or the batch holding it).
        if let (Some(f), Some(n)) = (&flag, stop_at) {
            if p.shots >= n {
                f.store(true, Ordering::Relaxed);
            }
        }
    })
    .expect("render")
}

/// Asserts that resuming `opts`'s checkpoint with `scene` is refused as
/// another scene or settings.
fn refused(scene: &radiosity::scene::Scene, opts: &RenderOptions) {
    let err = render(gpu(), scene, opts, Duration::ZERO, &mut |_| {})
        .err()
        .expect("refused");
    assert!(
        err.to_string().contains("other geometry or settings"),
        "{err}"
    );
}

fn same_solution(a: &Rendered, b: &Rendered) {
    assert!(a.radiosity == b.radiosity, "element radiosities differ");
    assert_eq!(a.report.surfaces, b.report.surfaces);
    assert_eq!(a.report.shots, b.report.shots);
    assert_eq!(
        a.report.unshot_fraction.to_bits(),
        b.report.unshot_fraction.to_bits()
    );
    let points = |r: &Rendered| -> Vec<_> {
        r.report
            .convergence
            .iter()
            .map(|p| (p.shots, p.surfaces.clone(), p.unshot_fraction.to_bits()))
            .collect()
    };
    assert_eq!(points(a), points(b), "the convergence traces differ");
}

/// Renders the Cornell box with `opts` (which resume a checkpoint made with
/// other settings) and checks that the resume is refused as such.
fn refused_as_other_settings(opts: &RenderOptions) {
    let scene = radiosity::scene::open("cornell").expect("built-in scene");
    refused(&scene, opts);
}

/// The Cornell box to unshot 2e-3, saving to `path` when interrupted
/// (with the flag `interrupt`, or never without it).
fn interruptible(path: &std::path::Path, interrupt: bool) -> RenderOptions {
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.threshold = 2e-3;
    opts.checkpoint = Some(CheckpointPlan {
        path: path.to_path_buf(),
        every: None,
    });
    opts.interrupt = interrupt.then(|| Arc::new(AtomicBool::new(false)));
    opts
}

#[test]
fn an_interrupted_solve_resumes_to_the_same_bits() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("cornell.ckpt");
    let straight = cornell(&interruptible(&path, false), None);

    let mut opts = interruptible(&path, true);
    let stopped = cornell(&opts, Some(150));
    assert!(stopped.interrupted);
    assert_eq!(stopped.report.shots, 150);
    assert!(!stopped.report.converged);
    assert!(
        stopped
            .report
            .warnings
            .iter()
            .any(|w| w.contains("--resume")),
        "{:?}",
        stopped.report.warnings
    );
    let saved = Checkpoint::read(&path).expect("checkpoint written");
    assert_eq!(saved.state.shots, 150);

    // Resume in another layout (four ranks' tiles drawn in turn), as a
    // different number of ranks would.
    opts.interrupt = None;
    opts.resume = Some(Arc::new(saved));
    opts.layout = Some(TileLayout {
        tile_w: 4,
        tile_h: 2,
        px: 2,
        py: 2,
    });
    let resumed = cornell(&opts, None);
    assert!(!resumed.interrupted);
    same_solution(&resumed, &straight);
}

/// Batched shots stop between two batches: the checkpoint holds whole
/// batches, and the resumed solve takes the batches the straight one took.
#[test]
fn an_interrupted_batched_solve_resumes_to_the_same_bits() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("batched.ckpt");
    let batched = |interrupt| {
        let mut opts = interruptible(&path, interrupt);
        opts.batch = 8;
        opts
    };
    let straight = cornell(&batched(false), None);
    assert_eq!(straight.report.parallel.batch, 8);

    let mut opts = batched(true);
    // Asked for mid-batch (150 is not a multiple of 8): the batch ends first.
    let stopped = cornell(&opts, Some(150));
    assert!(stopped.interrupted);
    let shots = stopped.report.shots;
    assert!((150..150 + 8).contains(&shots), "stopped after {shots}");
    let saved = Checkpoint::read(&path).expect("checkpoint written");
    assert_eq!(saved.state.shots, shots);

    opts.interrupt = None;
    opts.resume = Some(Arc::new(saved.clone()));
    let resumed = cornell(&opts, None);
    assert!(!resumed.interrupted);
    same_solution(&resumed, &straight);

    // The batch is part of the settings a checkpoint must match.
    opts.batch = 4;
    refused_as_other_settings(&opts);
}

#[test]
fn a_checkpoint_from_other_settings_is_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("c.ckpt");
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 20;
    opts.checkpoint = Some(CheckpointPlan {
        path: path.clone(),
        every: Some(Duration::ZERO),
    });
    cornell(&opts, None);
    let saved = Checkpoint::read(&path).expect("saved every shot");
    assert_eq!(saved.state.shots, 20);
    opts.checkpoint = None;
    opts.resolution = radiosity::hemisphere::Resolution {
        rows: 64,
        cols: 256,
    };
    opts.resume = Some(Arc::new(saved));
    refused_as_other_settings(&opts);
}

#[test]
fn a_solve_with_lights_sun_sky_and_a_map_resumes_to_the_same_bits_and_other_lights_are_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("lit.ckpt");
    let scene = lit_cornell();
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.threshold = 2e-3;
    let straight = solve_scene(&scene, &opts, None);
    opts.checkpoint = Some(CheckpointPlan {
        path: path.clone(),
        every: None,
    });
    opts.interrupt = Some(Arc::new(AtomicBool::new(false)));
    let stopped = solve_scene(&scene, &opts, Some(60));
    assert!(stopped.interrupted);
    let saved = Arc::new(Checkpoint::read(&path).expect("checkpoint written"));
    opts.interrupt = None;
    opts.checkpoint = None;
    opts.resume = Some(saved.clone());
    opts.layout = Some(TileLayout {
        tile_w: 4,
        tile_h: 2,
        px: 2,
        py: 2,
    });
    same_solution(&solve_scene(&scene, &opts, None), &straight);
    let mut brighter = scene.clone();
    brighter.sky = Some([0.2, 0.12, 0.2]);
    let mut turned = scene.clone();
    turned.sky_map = Some(Arc::new(sky_map(90.0)));
    for other in [brighter, turned] {
        refused(&other, &opts);
    }
}

/// A signal during the refinement pass stops the pass at once (it used to
/// run the pass to its end, minutes on Sponza, and then keep the final
/// mesh's empty start), and the render keeps the pass's solution: the mesh
/// is the pass's, refined no further, the report is the pass's last
/// trace point bit for bit, and the checkpoint goes on from it.
#[test]
fn an_interrupt_during_the_refinement_pass_keeps_the_pass_solution() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("cornell.ckpt");
    let mut opts = interruptible(&path, true);
    // The pass takes over 40 shots; the signal comes after its fifth.
    let stopped = cornell(&opts, Some(5));
    assert!(stopped.interrupted);
    let r = &stopped.report;
    assert!(r.refinement.interrupted);
    assert_eq!((r.refinement.passes, r.refinement.shots), (1, 5));
    assert_eq!(r.shots, 5);
    assert_eq!(
        [r.counts.patches, r.counts.elements],
        r.refinement.start,
        "the pass's mesh"
    );
    let trace = &r.convergence;
    let (last, passes) = trace.split_last().expect("a trace");
    assert!(passes.iter().all(|p| p.pass == Some(0)));
    assert_eq!(passes.len(), 5, "a point per pass shot");
    assert_eq!(last.surfaces, r.surfaces);
    assert_eq!(
        passes[4].surfaces, r.surfaces,
        "the report is the pass's solution"
    );
    let saved = Checkpoint::read(&path).expect("checkpoint written");
    assert_eq!(saved.state.shots, 5);

    // Resumed, it goes on to converge on the pass's mesh.
    opts.interrupt = None;
    opts.resume = Some(Arc::new(saved));
    let resumed = cornell(&opts, None);
    let q = &resumed.report;
    assert!(!resumed.interrupted && q.converged);
    assert!(q.refinement.interrupted);
    assert_eq!([q.counts.patches, q.counts.elements], r.refinement.start);
    assert!(q.shots > 5);
    // As a solve of that mesh from the start does (the box is open at the
    // front: a third of the light leaves), its energy record carried over.
    opts.resume = None;
    opts.mesh.refine = 0;
    let plain = cornell(&opts, None);
    let p = &plain.report;
    assert_eq!([p.counts.patches, p.counts.elements], r.refinement.start);
    let (a, b) = (q.energy.balance, p.energy.balance);
    assert!((a - b).abs() < 2e-3, "energy balance {a} against {b}");
    for (x, y) in q.surfaces.iter().zip(&p.surfaces) {
        let (x, y): (f64, f64) = (x.radiosity.iter().sum(), y.radiosity.iter().sum());
        assert!((x / y - 1.0).abs() < 0.01, "{x} against {y}");
    }
}

/// A signal right after the refinement pass's last shot, before the final
/// mesh's first: what the render keeps must not be worse than what the pass
/// had (the final mesh's start is only the emitters' light).
#[test]
fn an_interrupt_at_the_end_of_the_refinement_pass_loses_no_light() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("cornell.ckpt");
    let measured = cornell(&interruptible(&path, false), None);
    let pass = measured.report.refinement.shots;
    assert!(pass > 0, "the pass shot");
    let opts = interruptible(&path, true);
    let stopped = cornell(&opts, Some(pass));
    assert!(stopped.interrupted);
    let r = &stopped.report;
    let trace = &r.convergence;
    let last_pass = trace
        .iter()
        .rfind(|p| p.pass.is_some())
        .expect("the pass's points");
    assert!(
        r.unshot_fraction <= last_pass.unshot_fraction * (1.0 + 1e-9),
        "the report's unshot {} against the pass's {}",
        r.unshot_fraction,
        last_pass.unshot_fraction
    );
    // It is the pass's solution after its last shot, as an interrupt
    // during the pass keeps (not the final mesh's start).
    assert!(r.refinement.interrupted);
    assert_eq!((r.shots, r.refinement.shots), (pass, pass));
    assert_eq!(
        [r.counts.patches, r.counts.elements],
        r.refinement.start,
        "the pass's mesh"
    );
    let saved = Checkpoint::read(&path).expect("checkpoint written");
    assert_eq!(saved.state.shots, r.shots);
}

/// The same signal during the refinement pass on two ranks (threads that
/// share the flag, as a signal reaches every rank): the ranks stop at the
/// same shot and keep the same pass solution as one rank does, bit for bit.
#[test]
fn an_interrupt_during_the_refinement_pass_on_two_ranks_keeps_the_same_solution() {
    use radiosity::parallel::{Collectives, ThreadComm};
    let dir = tempfile::tempdir().expect("temp dir");
    let one_path = dir.path().join("one.ckpt");
    let one = cornell(&interruptible(&one_path, true), Some(5));
    let path = dir.path().join("two.ckpt");
    let opts = interruptible(&path, true);
    let scene = radiosity::scene::open("cornell").expect("built-in scene");
    let flag = opts.interrupt.clone().expect("a flag");
    let two = ThreadComm::run(2, |comm| {
        let rank = comm.rank();
        radiosity::render::render_on(gpu(), &scene, &opts, comm, Duration::ZERO, &mut |p| {
            // The signal after rank 0's fifth shot.
            if rank == 0 && p.shots == 5 {
                flag.store(true, Ordering::Relaxed);
            }
        })
        .expect("render")
    })
    .into_iter()
    .flatten()
    .next()
    .expect("rank 0's result");
    assert!(one.interrupted && two.interrupted);
    let (a, b) = (&one.report, &two.report);
    assert_eq!(b.counts.ranks, 2);
    assert!(b.refinement.interrupted);
    assert_eq!((b.shots, b.refinement.shots), (a.shots, a.refinement.shots));
    assert_eq!(
        [b.counts.patches, b.counts.elements],
        [a.counts.patches, a.counts.elements]
    );
    assert_eq!(
        a.surfaces, b.surfaces,
        "1 and 2 ranks keep the same solution"
    );
    let saved = Checkpoint::read(&path).expect("checkpoint written");
    assert_eq!(saved.state.shots, b.shots);
}

/// A room lit by an emissive texture resumes to the same bits, and the
/// same room with the texture's halves swapped (the same mean emission)
/// is refused: the fingerprint holds the texture.
#[test]
fn an_emissive_texture_resumes_to_the_same_bits_and_another_is_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("panel.ckpt");
    let scene = radiosity::scene::open(crate::emissive::PANEL_ROOM).expect("fixture");
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    let straight = solve_scene(&scene, &opts, None);
    same_solution(&stop_and_resume(&scene, &mut opts, &path, 200), &straight);
    let mut swapped = scene.clone();
    for p in &mut swapped.polygons {
        if let Some(m) = p.emissive.as_mut() {
            // u -> 1 - u: the lit half moves to +x.
            m.uv0.x = 1.0 - m.uv0.x;
            m.du = -m.du;
        }
    }
    refused(&swapped, &opts);
}

/// A furnished room under `--sun-sky` (a map and a sun, both in the
/// fingerprint) resumes to the same bits; the same sun an hour later is
/// refused.
#[test]
fn a_sun_sky_resumes_to_the_same_bits_and_another_hour_is_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("sun-sky.ckpt");
    let lit = |value: &str| {
        let mut s = radiosity::scene::open("family-furnished-1").expect("scene");
        let lights = radiosity::scene::light::LightArgs {
            sun_sky: Some(value.parse().expect("a sun-sky")),
            ..Default::default()
        };
        lights.apply(&mut s).expect("the sun-sky");
        s
    };
    let scene = lit("40,250");
    let mut opts = RenderOptions {
        width: 0,
        stop: radiosity::solver::StopRule {
            max_shots: 400,
            ..Default::default()
        },
        ..RenderOptions::default()
    };
    let straight = solve_scene(&scene, &opts, None);
    same_solution(&stop_and_resume(&scene, &mut opts, &path, 150), &straight);
    refused(&lit("45,265"), &opts);
}

/// A room with an alpha-masked square between its light and its floor
/// resumes to the same bits; the same square opaque (other geometry, as the
/// cut makes pieces) is refused.
#[test]
fn an_alpha_mask_resumes_to_the_same_bits_and_the_square_opaque_is_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("masked.ckpt");
    let scene = crate::masks::masked_room(Some("MASK"));
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    let straight = solve_scene(&scene, &opts, None);
    // Stopped in the final solve (the refinement pass takes 36 shots).
    same_solution(&stop_and_resume(&scene, &mut opts, &path, 300), &straight);
    let opaque = crate::masks::masked_room(Some("OPAQUE"));
    refused(&opaque, &opts);
}
