//! Same scene and settings, same numbers: across runs, and however the
//! hemisphere is split into tiles and rank grids.

use crate::common::*;
use radiosity::hemisphere::TileLayout;
use radiosity::render::{render, RenderOptions};
use std::time::Duration;

fn cornell(opts: &RenderOptions) -> radiosity::render::Rendered {
    let scene = radiosity::scene::open("cornell").expect("built-in scene");
    render(gpu(), &scene, opts, Duration::ZERO, &mut |_| {}).expect("render")
}

#[test]
fn identical_runs_are_bitwise_identical() {
    let mut opts = RenderOptions {
        width: 96,
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 120;
    let a = cornell(&opts);
    let b = cornell(&opts);
    assert_eq!(a.report.surfaces, b.report.surfaces);
    assert!(a.radiosity == b.radiosity, "element radiosities differ");
    let (ia, ib) = (a.image.expect("image"), b.image.expect("image"));
    assert!(
        ia.2.iter()
            .zip(&ib.2)
            .all(|(p, q)| p.map(f32::to_bits) == q.map(f32::to_bits)),
        "image pixels differ"
    );
    assert!(ia.2.iter().any(|p| p[0] > 0.0), "image is black");
}

#[test]
fn tiling_does_not_change_the_solution() {
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 40;
    let whole = cornell(&opts);
    opts.layout = Some(TileLayout {
        tile_w: 8,
        tile_h: 4,
        px: 3,
        py: 2,
    });
    let tiled = cornell(&opts);
    assert!(
        whole.radiosity == tiled.radiosity,
        "radiosities differ between tilings"
    );
}

#[test]
fn lattice_grids_of_many_columns_leave_no_cracks() {
    // 1 x 1 tiles pack each rank's cells into a lattice image, which shrinks
    // the rectangles' margins by the grid size: with 6 or more columns they
    // fell below the rasteriser's sub-pixel snap. Every rank grid must give
    // the whole hemisphere's solution bit for bit.
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 30;
    let whole = cornell(&opts);
    for (px, py) in [(6, 1), (7, 1), (8, 4), (13, 1), (32, 2)] {
        opts.layout = Some(TileLayout {
            tile_w: 1,
            tile_h: 1,
            px,
            py,
        });
        let tiled = cornell(&opts);
        assert!(
            whole.radiosity == tiled.radiosity,
            "radiosities differ on a {px} x {py} lattice"
        );
    }
}

#[test]
fn cornell_box_looks_right() {
    // Red wall on the left of the camera view, green on the right, light brightest at the top.
    let mut opts = RenderOptions {
        width: 64,
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 200;
    let r = cornell(&opts);
    let (w, h, px) = r.image.as_ref().expect("image");
    let (w, h) = (*w, *h);
    let at = |x: u32, y: u32| px[(y * w + x) as usize];
    let left = at(w / 16, h / 2);
    let right = at(w - 1 - w / 16, h / 2);
    assert!(left[0] > 2.0 * left[1], "left wall should be red: {left:?}");
    assert!(
        right[1] > 2.0 * right[0],
        "right wall should be green: {right:?}"
    );
    // Energy in the report: the light's mean radiosity is its exitance pi * L_e.
    let light = node(&r, "light");
    assert!(
        rel(light.radiosity[0], std::f64::consts::PI * 17.0) < 0.01,
        "light {:?}",
        light.radiosity
    );
}

#[test]
fn benchmark_scene_counts_match_the_paper() {
    // DESIGN.md section 4, Table 1 (B1): polygons, patches, elements.
    let scene = radiosity::scene::open_as_authored("cubes-b1").expect("built-in");
    let mesh = radiosity::mesh::Mesh::build(&scene, &Default::default());
    assert_eq!(
        (
            scene.polygons.len(),
            mesh.patches.len(),
            mesh.elements.len()
        ),
        (24_588, 49_776, 199_032)
    );
}

#[test]
fn threaded_rectangle_pass_is_deterministic() {
    // cubes-5 has at least 8424 elements, enough for the multi-threaded rectangle pass.
    let scene = radiosity::scene::open("cubes-5").expect("built-in");
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 12;
    let a = render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("render");
    let b = render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("render");
    assert!(a.mesh.elements.len() >= 8424);
    assert!(
        a.radiosity == b.radiosity,
        "radiosities differ between runs"
    );
}

#[test]
fn shipped_cornell_file_matches_the_built_in_scene() {
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell.gltf");
    let text = std::fs::read_to_string(&shipped).expect("scenes/cornell.gltf is shipped");
    let built_in = radiosity::scene::builtin_gltf("cornell").expect("built-in");
    assert!(text == built_in, "scenes/cornell.gltf is stale: regenerate with `radiosity scene cornell --out scenes/cornell.gltf`");
    let scene = radiosity::scene::open(shipped.to_str().expect("utf-8")).expect("loads");
    assert_eq!(scene.nodes.len(), 8);
    assert!(scene.camera.is_some());
}

#[test]
fn classroom_counts_are_near_the_paper() {
    // DESIGN.md section 4, Table 2: (polygons, patches, elements) within 10 %.
    for (name, expected) in [
        ("classroom-c1", [3159.0, 6344.0, 17402.0]),
        ("classroom-c2", [4629.0, 9236.0, 24342.0]),
        ("classroom-c3", [7592.0, 14941.0, 37127.0]),
    ] {
        // The paper's counts are of the scenes as authored (before the
        // contact split adds pieces under the desks and chairs).
        let scene = radiosity::scene::open_as_authored(name).expect("built-in");
        let mesh = radiosity::mesh::Mesh::build(&scene, &Default::default());
        let got = [
            scene.polygons.len() as f64,
            mesh.patches.len() as f64,
            mesh.elements.len() as f64,
        ];
        eprintln!("{name}: {got:?} vs {expected:?}");
        for (g, e) in got.iter().zip(expected) {
            assert!(rel(*g, e) < 0.10, "{name}: {got:?} vs {expected:?}");
        }
    }
}

#[test]
fn row_cache_changes_no_number() {
    // Enough shots that most patches shoot again and hit the cache.
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 1500;
    let cached = cornell(&opts);
    assert!(
        cached.report.timings.cached_shots > 300,
        "{} cached shots",
        cached.report.timings.cached_shots
    );
    opts.cache_rows = false;
    let fresh = cornell(&opts);
    assert_eq!(fresh.report.timings.cached_shots, 0);
    assert!(
        cached.radiosity == fresh.radiosity,
        "the cache changed the solution"
    );
    assert_eq!(cached.report.surfaces, fresh.report.surfaces);
}

#[test]
fn drawing_polygons_or_elements_gives_the_same_form_factors() {
    // Polygons drawn whole, in 3 x 3 pieces, or element by element: the
    // element at each cell is the same but for cells on element boundaries,
    // which may go to either neighbour.
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.threshold = 1e-3;
    let results: Vec<_> = [1, 3, 0]
        .into_iter()
        .map(|pieces| {
            opts.raster_pieces = pieces;
            cornell(&opts).report.surfaces
        })
        .collect();
    for other in &results[1..] {
        for (a, b) in results[0].iter().zip(other) {
            for c in 0..3 {
                assert!(
                    rel(a.radiosity[c], b.radiosity[c]) < 2e-3,
                    "{}: {:?} vs {:?}",
                    a.node,
                    a.radiosity,
                    b.radiosity
                );
            }
        }
    }
}

#[test]
fn the_ambient_term_is_in_the_report_unless_asked_not_to_be() {
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 20;
    let with = cornell(&opts);
    opts.ambient = radiosity::settings::AmbientTerm::Off;
    let without = cornell(&opts);
    assert!(with.report.unshot_fraction > 0.1);
    // After 20 shots much light is unshot: every reflecting surface is
    // brighter with the estimate of it, and the emitter-only light is not.
    for (a, b) in with.report.surfaces.iter().zip(&without.report.surfaces) {
        if a.node != "light" {
            assert!(
                a.radiosity[1] > b.radiosity[1],
                "{}: {a:?} vs {b:?}",
                a.node
            );
        }
    }
    assert!(with.report.settings.ambient && !without.report.settings.ambient);
}

#[test]
fn skipping_the_back_faces_of_solids_changes_no_cell() {
    // 27 closed cubes in a room: from any shooter outside a cube, the cube's
    // front faces hide its back faces, so not drawing those leaves the item
    // buffer as it was (but for rays grazing a silhouette edge).
    let scene = radiosity::scene::open("cubes-3").expect("built-in");
    let mesh = radiosity::mesh::Mesh::build(&scene, &Default::default());
    assert_eq!(
        mesh.solids.len(),
        28,
        "every cube and the light are solids, the room is not"
    );
    let g = gpu();
    let res = radiosity::hemisphere::Resolution::default();
    let layout = radiosity::hemisphere::TileLayout::whole(res);
    let new = |cull: bool| {
        let mut r =
            radiosity::gpu::HemisphereRasterizer::new(&g.device, &mesh, res, 1, scene.extent())
                .expect("rasteriser");
        r.set_cull_solids(cull);
        r
    };
    let (mut culled, mut full) = (new(true), new(false));
    let (mut a, mut b) = (Vec::new(), Vec::new());
    let (mut differing, mut cells, mut rects) = (0usize, 0usize, [0u32; 2]);
    // Shooters all over: room walls, cube faces, the light.
    for patch in (0..mesh.patches.len()).step_by(mesh.patches.len() / 40) {
        let frame = mesh.shooter_frame(patch as u32);
        let s = culled
            .render(&g.device, &g.queue, &frame, &layout, (0, 0), &mut a, None)
            .expect("render");
        let t = full
            .render(&g.device, &g.queue, &frame, &layout, (0, 0), &mut b, None)
            .expect("render");
        rects[0] += s.rects;
        rects[1] += t.rects;
        differing += a.iter().zip(&b).filter(|(x, y)| x != y).count();
        cells += a.len();
    }
    eprintln!(
        "{differing} of {cells} cells differ; {} rectangles drawn instead of {}",
        rects[0], rects[1]
    );
    assert!(
        10 * rects[0] < 8 * rects[1],
        "few back faces skipped: {rects:?}"
    );
    assert!(
        differing * 100_000 <= cells,
        "{differing} of {cells} cells differ"
    );
}

#[test]
fn the_occlusion_cull_changes_no_number() {
    // Polygons hidden behind nearer ones in every cell they could cover are
    // left undrawn on one rank; their elements are all hidden, so no form
    // factor may change, with either method, split shots, coarse shots and
    // near receivers (which stay drawn) included. Cluttered scenes, where
    // the cull leaves out most of what is in view.
    for (name, method) in [
        ("cubes-4", radiosity::settings::FormFactorMethod::Hybrid),
        (
            "family-floor-1",
            radiosity::settings::FormFactorMethod::Hybrid,
        ),
        (
            "family-many-2",
            radiosity::settings::FormFactorMethod::Hybrid,
        ),
        ("cubes-4", radiosity::settings::FormFactorMethod::Hemisphere),
    ] {
        let scene = radiosity::scene::open(name).expect("built-in scene");
        let mut opts = RenderOptions {
            width: 0,
            form_factor: method,
            ..RenderOptions::default()
        };
        opts.stop.max_shots = 150;
        let run = |opts: &RenderOptions| {
            render(gpu(), &scene, opts, Duration::ZERO, &mut |_| {}).expect("render")
        };
        let culled = run(&opts);
        opts.occlusion_cull = false;
        let drawn = run(&opts);
        let t = &culled.report.timings;
        assert!(
            t.occluded_per_shot + t.skipped_per_shot > 0.0,
            "{name}: nothing culled"
        );
        assert_eq!(drawn.report.timings.occluded_per_shot, 0.0);
        assert!(
            culled.radiosity == drawn.radiosity,
            "{name} {method:?}: radiosities differ with the occlusion cull"
        );
        assert_eq!(culled.report.energy, drawn.report.energy, "{name}");
    }
}

#[test]
fn rows_drawn_ahead_change_no_number() {
    // On two cores or more, the final solve draws the rows of the vote's
    // runners-up beside the shot, and a shot whose row is ready takes it: a
    // row depends only on its shooter, centre and tier, so every number is
    // the one drawing each row in its shot gives. Default settings (the row
    // cache, the coarse tier, split shots), cluttered and plain scenes.
    for name in ["cubes-4", "family-many-2", "family-stacked-5"] {
        let scene = radiosity::scene::open(name).expect("built-in scene");
        let mut opts = RenderOptions {
            width: 0,
            ..RenderOptions::default()
        };
        opts.stop.max_shots = 200;
        let run = |opts: &RenderOptions| {
            render(gpu(), &scene, opts, Duration::ZERO, &mut |_| {}).expect("render")
        };
        let ahead = run(&opts);
        opts.look_ahead = false;
        let own = run(&opts);
        if radiosity::parallel::cores() >= 2 {
            assert!(
                ahead.report.timings.drawn_ahead_shots > 20,
                "{name}: {} shots took a row drawn ahead",
                ahead.report.timings.drawn_ahead_shots
            );
        }
        assert_eq!(own.report.timings.drawn_ahead_shots, 0);
        assert!(
            ahead.radiosity == own.radiosity,
            "{name}: radiosities differ with rows drawn ahead"
        );
        assert_eq!(ahead.report.surfaces, own.report.surfaces, "{name}");
        assert_eq!(ahead.report.energy, own.report.energy, "{name}");
        assert_eq!(ahead.report.shots, own.report.shots, "{name}");
    }
}

#[test]
fn the_contact_split_is_the_same_on_one_core_and_on_every_core() {
    // Each polygon's pieces are found on every core and joined in order:
    // the scene as loaded (the classroom's desks and chairs stand on its
    // floor) is the same, bit for bit, pinned to one core.
    let dir = tempfile::tempdir().expect("temp dir");
    let export = |name: &str, one_core: bool| {
        let out = dir.path().join(name);
        let status = radiosity_on(one_core)
            .args(["scene", "classroom-c1", "--nodes"])
            .arg(&out)
            .stdout(std::process::Stdio::null())
            .status()
            .expect("runs (taskset is util-linux's)");
        assert!(status.success());
        std::fs::read(&out).expect("nodes written")
    };
    let (one, all) = (export("one.json", true), export("all.json", false));
    let scene: serde_json::Value = serde_json::from_slice(&all).expect("json");
    let triangles: usize = scene["nodes"]
        .as_array()
        .expect("nodes")
        .iter()
        .map(|n| n["triangles"].as_array().map_or(0, Vec::len))
        .sum();
    assert!(triangles > 5000, "{triangles} triangles");
    assert!(one == all, "the scene differs with the core count");
}

#[test]
fn far_receivers_scanned_beside_the_bounds_give_the_same_bits() {
    // With a second core, a big mesh's far receivers may be scanned on a
    // thread of their own while the bounds keep to one core (the way each
    // hemisphere takes is chosen by measured time, so both are taken in a
    // solve); pinned to one core, never. Both ways must give the same
    // solution, bit for bit.
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    assert!(cores >= 2, "this test needs two cores, found {cores}");
    let dir = tempfile::tempdir().expect("temp dir");
    let render = |name: &str, one_core: bool| -> serde_json::Value {
        let report = dir.path().join(name);
        // cubes-16: 50 088 patches, far above the scan's 16 384.
        let status = radiosity_on(one_core)
            .args([
                "render",
                "cubes-16",
                "--max-shots",
                "40",
                "--threshold",
                "0",
            ])
            .args(["--width", "0", "--refine-shading", "0", "--out-dir"])
            .arg(dir.path())
            .arg("--report")
            .arg(&report)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .status()
            .expect("runs (taskset is util-linux's)");
        assert!(status.success(), "{name}: the render failed");
        serde_json::from_slice(&std::fs::read(&report).expect("report written")).expect("json")
    };
    let (one, all) = (render("one.json", true), render("all.json", false));
    let ahead = all["timings"]["far_receivers_ahead"]
        .as_f64()
        .expect("timing");
    assert!(ahead > 0.0, "no hemisphere scanned its far receivers ahead");
    assert_eq!(one["timings"]["far_receivers_ahead"].as_f64(), Some(0.0));
    for key in ["surfaces", "energy", "unshot_fraction", "counts"] {
        assert!(
            one[key] == all[key],
            "{key} differs with the far receivers scanned ahead"
        );
    }
}

/// The `radiosity` binary, pinned to core 0 (`taskset`, util-linux's)
/// when `one_core`, else free to use every core.
fn radiosity_on(one_core: bool) -> std::process::Command {
    let bin = env!("CARGO_BIN_EXE_radiosity");
    if one_core {
        let mut c = std::process::Command::new("taskset");
        c.args(["-c", "0", bin]);
        c
    } else {
        std::process::Command::new(bin)
    }
}

/// Ranks that are threads of this process (`--ranks`): the numbers one
/// rank gives, batched and unbatched (the hemisphere split over the ranks),
/// image included, drawn on the CPU and by the device (which the ranks
/// share).
#[test]
fn ranks_in_one_process_give_one_ranks_numbers() {
    use radiosity::settings::Rasteriser;
    let scene = radiosity::scene::open("cornell").expect("built-in scene");
    for (batch, rasteriser) in [
        (1, Rasteriser::Auto),
        (6, Rasteriser::Auto),
        (6, Rasteriser::Device),
    ] {
        let mut opts = RenderOptions {
            width: 48,
            batch,
            rasteriser,
            ..RenderOptions::default()
        };
        opts.stop.max_shots = 30;
        let one = render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("render");
        for ranks in [2, 3] {
            let many = radiosity::render::render_ranks(
                gpu(),
                &scene,
                &opts,
                ranks,
                Duration::ZERO,
                &mut |_| {},
            )
            .expect("render on ranks");
            let what = format!("batch {batch}, {rasteriser:?}, {ranks} ranks");
            assert_eq!(many.report.counts.ranks, ranks, "{what}");
            assert_eq!(one.report.shots, many.report.shots, "{what}");
            assert_eq!(one.report.surfaces, many.report.surfaces, "{what}");
            assert!(
                one.radiosity == many.radiosity,
                "{what}: radiosities differ"
            );
            let (a, b) = (
                one.image.as_ref().expect("image"),
                many.image.expect("image"),
            );
            assert!(
                a.2.iter()
                    .zip(&b.2)
                    .all(|(p, q)| p.map(f32::to_bits) == q.map(f32::to_bits)),
                "{what}: image pixels differ"
            );
        }
    }
}
