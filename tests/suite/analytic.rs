//! Form factors through the whole pipeline (glTF file -> render -> report)
//! against closed-form values (DESIGN.md section 5), automatic subdivision:
//! the default (hybrid) method within 0.5 %, the pure hemisphere within 1 %.
//!
//! The emitter (L_e = 1, exitance pi, black) lights a white receiver (rho = 1)
//! in empty space; nothing comes back, so the receiver's mean radiosity is
//! pi * F_er * A_e / A_r and the form factor follows from the report.

use crate::common::*;
use radiosity::render::FormFactorMethod;
use radiosity::report::Surface;

/// The receivers' reflectance: white, as the file writes it (an explicit
/// factor of 1 is used as written), so B = pi F A_e / A_r.
pub const RECEIVER_RHO: f32 = 1.0;

fn form_factor(emitter: &Surface, receiver: &Surface) -> f64 {
    receiver.radiosity[0] * receiver.area
        / (std::f64::consts::PI * emitter.area * RECEIVER_RHO as f64)
}

fn check(name: &str, emitter: Vec<Vec<glam::Vec3>>, receiver: Vec<Vec<glam::Vec3>>, expected: f64) {
    let (_dir, path) = write_scene(
        name,
        &[
            surface("emitter", emitter, 0.0, 1.0),
            surface("receiver", receiver, RECEIVER_RHO, 0.0),
        ],
    );
    for (method, tolerance) in [
        (FormFactorMethod::Hybrid, 0.005),
        (FormFactorMethod::Hemisphere, 0.01),
    ] {
        let mut opts = tight(1e-9);
        opts.form_factor = method;
        let r = solve_file(&path, &opts);
        let f = form_factor(node(&r, "emitter"), node(&r, "receiver"));
        eprintln!(
            "{name} ({method:?}): F = {f:.5} (expected {expected:.5}, {} patches, {:+.3} %)",
            r.report.counts.patches,
            100.0 * (f / expected - 1.0)
        );
        assert!(
            rel(f, expected) < tolerance,
            "{name} ({method:?}): F = {f}, expected {expected} within {tolerance}"
        );
    }
}

/// Form factor from the emitter (in z = 0, facing +z) to a polygon, by
/// Lambert's formula at 32 x 32 midpoints of the emitter, averaged.
fn emitter_to_polygon(emitter: [[f32; 2]; 2], poly: &[glam::Vec3]) -> f64 {
    let n = 32;
    let mut sum = 0.0;
    for i in 0..n {
        for j in 0..n {
            let x = emitter[0][0] as f64
                + (emitter[1][0] - emitter[0][0]) as f64 * (i as f64 + 0.5) / n as f64;
            let y = emitter[0][1] as f64
                + (emitter[1][1] - emitter[0][1]) as f64 * (j as f64 + 0.5) / n as f64;
            let rel_poly: Vec<[f64; 3]> = poly
                .iter()
                .map(|p| [p.x as f64 - x, p.y as f64 - y, p.z as f64])
                .collect();
            sum += lambert(&rel_poly);
        }
    }
    sum / (n * n) as f64
}

#[test]
fn small_far_receiver() {
    // A 0.1 m square 2.2 m from a 0.1 m emitter, off the axis: a few cells per
    // element at 128 x 512, where the pure hemisphere aliases.
    let receiver = rect(2, 1.8, [1.2, 0.3], [1.3, 0.4], false);
    let expected = emitter_to_polygon([[0.0, 0.0], [0.1, 0.1]], &receiver);
    let (_dir, path) = write_scene(
        "far",
        &[
            surface(
                "emitter",
                vec![rect(2, 0.0, [0.0, 0.0], [0.1, 0.1], true)],
                0.0,
                1.0,
            ),
            surface("receiver", vec![receiver], RECEIVER_RHO, 0.0),
        ],
    );
    let r = solve_file(&path, &tight(1e-9));
    let f = form_factor(node(&r, "emitter"), node(&r, "receiver"));
    eprintln!("far: F = {f:.6e} (expected {expected:.6e})");
    assert!(rel(f, expected) < 0.01, "far: F = {f}, expected {expected}");
}

#[test]
fn trace_ends_at_the_report_and_its_error_falls() {
    // Two facing unit squares, both reflecting 0.5: light bounces between
    // them, so the solution converges over many shots.
    let (_dir, path) = write_scene(
        "bounce",
        &[
            surface(
                "a",
                vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
                0.5,
                1.0,
            ),
            surface(
                "b",
                vec![rect(2, 0.5, [0.0, 0.0], [1.0, 1.0], false)],
                0.5,
                0.0,
            ),
        ],
    );
    let mut opts = tight(1e-7);
    opts.ambient = radiosity::settings::AmbientTerm::Off;
    let r = solve_file(&path, &opts);
    let whole = &r.report.convergence;
    assert!(whole.windows(2).all(|w| w[0].seconds <= w[1].seconds));
    // The refinement pass's points come first, each saying its pass; the
    // final solve starts again from B = E.
    let passes = whole.iter().take_while(|p| p.pass.is_some()).count();
    assert_eq!(r.report.refinement.passes, 1);
    assert!(passes >= 1, "the pass shows its solution");
    let trace = &whole[passes..];
    assert!(trace.iter().all(|p| p.pass.is_none()));
    let last = trace.last().expect("a trace");
    assert_eq!(last.shots, r.report.shots);
    assert_eq!(last.surfaces, r.report.surfaces);
    assert_eq!(last.unshot_fraction, r.report.unshot_fraction);
    assert!(trace.len() >= 20, "{} points", trace.len());
    // Every doubling of the shot count has a point.
    let mut s = 1;
    while s <= r.report.shots {
        assert!(trace.iter().any(|p| p.shots == s), "no point at {s} shots");
        s *= 2;
    }
    // Error against the final answer falls from first to last point
    // (without the ambient term, radiosity only grows towards it).
    let err = |p: &radiosity::report::TracePoint| {
        p.surfaces
            .iter()
            .zip(&r.report.surfaces)
            .map(|(a, b)| rel(a.radiosity[0], b.radiosity[0]))
            .fold(0.0, f64::max)
    };
    let errors: Vec<f64> = trace.iter().map(err).collect();
    for w in errors.windows(2) {
        assert!(w[1] <= w[0] + 1e-12, "error rose: {errors:?}");
    }
    assert!(errors[0] > 0.01 && errors[errors.len() - 1] == 0.0);
}

#[test]
fn parallel_unit_squares_one_apart() {
    check(
        "parallel",
        vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
        vec![rect(2, 1.0, [0.0, 0.0], [1.0, 1.0], false)],
        0.19982,
    );
}

#[test]
fn perpendicular_unit_squares_sharing_an_edge() {
    // Emitter in z = 0 facing +z; receiver in y = 0 facing +y; common edge along x.
    check(
        "perpendicular",
        vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
        vec![rect(1, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
        0.20004,
    );
}

#[test]
fn parallel_rectangles_half_apart() {
    check(
        "rectangles",
        vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.5], true)],
        vec![rect(2, 0.5, [0.0, 0.0], [1.0, 1.5], false)],
        0.47558,
    );
}

#[test]
fn coaxial_disks() {
    // Polygonal disks of 96 sides (area within 0.07 % of the circles').
    let (r1, r2, a) = (0.1f64, 0.2f64, 0.5f64);
    let (big_r1, big_r2) = (r1 / a, r2 / a);
    let s = 1.0 + (1.0 + big_r2 * big_r2) / (big_r1 * big_r1);
    let expected = 0.5 * (s - (s * s - 4.0 * (r2 / r1).powi(2)).sqrt());
    assert!((expected - 0.13393).abs() < 5e-5);
    check(
        "disks",
        disk(0.1, 0.0, 96, true),
        disk(0.2, 0.5, 96, false),
        expected,
    );
}

/// Packs a self-contained .gltf (one data-URI buffer) into a .glb container.
fn to_glb(gltf_text: &str) -> Vec<u8> {
    use base64::Engine;
    let mut json: serde_json::Value = serde_json::from_str(gltf_text).expect("json");
    let uri = json["buffers"][0]["uri"].as_str().expect("uri").to_string();
    let mut bin = base64::engine::general_purpose::STANDARD
        .decode(uri.split(',').nth(1).expect("data uri"))
        .expect("base64");
    json["buffers"][0]
        .as_object_mut()
        .expect("buffer")
        .remove("uri");
    let mut text = serde_json::to_vec(&json).expect("json");
    while text.len() % 4 != 0 {
        text.push(b' ');
    }
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// A black emitter (L_e = 1) and a white receiver: unit squares 1 apart, facing.
fn unit_squares_one_apart() -> [radiosity::scene::GltfSurface; 2] {
    [
        surface(
            "emitter",
            vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
            0.0,
            1.0,
        ),
        surface(
            "receiver",
            vec![rect(2, 1.0, [0.0, 0.0], [1.0, 1.0], false)],
            RECEIVER_RHO,
            0.0,
        ),
    ]
}

#[test]
fn glb_gives_the_same_answer_as_gltf() {
    let surfaces = unit_squares_one_apart();
    let (dir, path) = write_scene("pair", &surfaces);
    let glb = dir.path().join("pair.glb");
    std::fs::write(&glb, to_glb(&std::fs::read_to_string(&path).expect("read"))).expect("write");
    let mut opts = tight(1e-6);
    opts.stop.max_shots = 30;
    let a = solve_file(&path, &opts);
    let b = solve_file(&glb, &opts);
    assert_eq!(a.report.surfaces, b.report.surfaces);
    assert!(node(&b, "receiver").radiosity[0] > 0.25);
}

#[test]
fn a_scene_far_from_the_origin_gives_the_same_answer() {
    // 1e6 m away, f32 world coordinates would keep only 6 cm steps; the
    // loader works in f64 relative to the scene, so nothing changes.
    let surfaces = unit_squares_one_apart();
    let (_near_dir, near) = write_scene("near", &surfaces);
    let (_far_dir, far) = write_scene("far-away", &surfaces);
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&far).expect("read")).expect("json");
    for node in json["nodes"].as_array_mut().expect("nodes") {
        node["translation"] = serde_json::json!([1.0e6, -2.0e6, 3.0e6]);
    }
    std::fs::write(&far, json.to_string()).expect("write");
    let opts = tight(1e-6);
    let (a, b) = (solve_file(&near, &opts), solve_file(&far, &opts));
    for (x, y) in a.report.surfaces.iter().zip(&b.report.surfaces) {
        assert!(
            rel(y.radiosity[0], x.radiosity[0]) < 1e-3,
            "{}: {:?} far vs {:?} near",
            x.node,
            y.radiosity,
            x.radiosity
        );
    }
    assert!(
        rel(
            b.report.surfaces[1].radiosity[0],
            std::f64::consts::PI * 0.19982 * RECEIVER_RHO as f64
        ) < 0.005
    );
}
