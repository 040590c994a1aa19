//! Refinement by need: what the passes refine, and that they refine nothing
//! where nothing casts a shadow.

use crate::common::*;
use radiosity::render::{render, RenderOptions};
use std::time::Duration;

fn patches_per_polygon(mesh: &radiosity::mesh::Mesh) -> Vec<usize> {
    mesh.polygons.iter().map(|p| p.patches.len()).collect()
}

/// The Cornell box's light is traced over its whole area
/// (`direct::EmitterField`), so it never shoots by hemisphere and needs no
/// finer patches; the walls' shooters are dim and the blocks' shadows are
/// not theirs: no shooter is refined. (Before the light was traced, it
/// alone was refined, 4 x its patches.)
#[test]
fn the_cornell_box_refines_no_shooter() {
    let scene = radiosity::scene::open("cornell").expect("built-in");
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.threshold = 0.05;
    // The shooters' criterion alone (the shading criterion refines the
    // blocks' and walls' polygons where the image needs it).
    opts.mesh.shading_tol = 0.0;
    let refined = render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("render");
    opts.mesh.refine = 0;
    let plain = render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("render");
    let (a, b) = (
        patches_per_polygon(&refined.mesh),
        patches_per_polygon(&plain.mesh),
    );
    let changed: Vec<usize> = (0..a.len()).filter(|&i| a[i] != b[i]).collect();
    let r = &refined.report.refinement;
    assert!(r.passes >= 1, "{r:?}");
    assert_eq!(changed.len() as u32, r.shooter_polygons, "{r:?}");
    assert_eq!(r.receiver_polygons, 0, "{r:?}");
    assert_eq!(
        r.end,
        [refined.mesh.patches.len(), refined.mesh.elements.len()]
    );
    assert_eq!(
        r.start,
        [plain.mesh.patches.len(), plain.mesh.elements.len()]
    );
    assert_eq!(refined.report.counts.patches, refined.mesh.patches.len());
    assert!(changed.is_empty(), "refined polygons {changed:?}");
    assert_eq!(plain.report.refinement.passes, 0);
}

#[test]
fn two_facing_squares_refine_no_shooter() {
    // No occluder: no receiver is ever partly visible, so no penumbra.
    let (_dir, path) = write_scene(
        "squares",
        &[
            surface(
                "emitter",
                vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
                0.0,
                1.0,
            ),
            surface(
                "receiver",
                vec![rect(2, 1.0, [0.0, 0.0], [1.0, 1.0], false)],
                1.0,
                0.0,
            ),
        ],
    );
    let r = solve_file(&path, &tight(1e-6));
    assert!(r.report.refinement.passes >= 1);
    let refinement = &r.report.refinement;
    assert_eq!(refinement.shooter_polygons, 0);
    // Whatever the receivers asked for is what the final mesh grew by.
    let receivers = refinement.receiver_polygons as usize;
    assert_eq!(
        refinement.start[0] == r.mesh.patches.len(),
        receivers == 0,
        "{refinement:?}"
    );
}
