//! Closed rooms: the furnace (B = pi L_e / (1 - rho) everywhere) and energy
//! conservation (sum A B = sum A E / (1 - rho) for uniform rho).

use crate::common::*;

/// The six inward-facing faces of the box [0, 2] x [0, 1.5] x [0, 1].
fn room(emission: [f32; 6], rho: f32) -> Vec<radiosity::scene::GltfSurface> {
    let (x, y, z) = (2.0, 1.5, 1.0);
    let faces = [
        ("x0", rect(0, 0.0, [0.0, 0.0], [y, z], true)),
        ("x1", rect(0, x, [0.0, 0.0], [y, z], false)),
        ("y0", rect(1, 0.0, [0.0, 0.0], [z, x], true)),
        ("y1", rect(1, y, [0.0, 0.0], [z, x], false)),
        ("z0", rect(2, 0.0, [0.0, 0.0], [x, y], true)),
        ("z1", rect(2, z, [0.0, 0.0], [x, y], false)),
    ];
    faces
        .into_iter()
        .zip(emission)
        .map(|((n, f), e)| surface(n, vec![f], rho, e))
        .collect()
}

#[test]
fn furnace_gives_two_pi_everywhere() {
    let (_dir, path) = write_scene("furnace", &room([1.0; 6], 0.5));
    let r = solve_file(&path, &tight(1e-5));
    let expected = 2.0 * std::f64::consts::PI;
    for s in &r.report.surfaces {
        eprintln!("{}: {:?}", s.node, s.radiosity);
        assert!(
            rel(s.radiosity[0], expected) < 0.005,
            "{}: B = {} vs 2 pi",
            s.node,
            s.radiosity[0]
        );
    }
    // Every element, not just the means. With receiver-side analytic form
    // factors every element point sees exactly the whole room (the form
    // factors to all shooters sum to 1), so even corner elements, lit by
    // shooters as near as they are large, come out right; a point-centred
    // shooter alone breaks reciprocity there by up to about 10 %.
    let worst = r
        .radiosity
        .iter()
        .map(|b| rel(b[0], expected))
        .fold(0.0, f64::max);
    eprintln!("worst element off by {worst}");
    assert!(worst < 0.02, "worst element off by {worst}");
}

#[test]
fn closed_room_conserves_energy() {
    // Only the ceiling emits.
    let rho = 0.6;
    let (_dir, path) = write_scene("room", &room([0.0, 0.0, 0.0, 0.0, 0.0, 2.0], rho as f32));
    let r = solve_file(&path, &tight(1e-6));
    let out: f64 = r
        .report
        .surfaces
        .iter()
        .map(|s| s.area * s.radiosity[0])
        .sum();
    let emitted: f64 = 2.0 * 1.5 * std::f64::consts::PI * 2.0;
    let expected = emitted / (1.0 - rho);
    assert!(
        rel(out, expected) < 0.002,
        "sum A B = {out}, expected {expected}"
    );
}
