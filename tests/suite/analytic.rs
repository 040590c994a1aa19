//! Form factors through the whole pipeline (glTF file -> render -> report)
//! against closed-form values (DESIGN.md section 5), automatic subdivision.
//!
//! The emitter (L_e = 1, exitance pi, black) lights a white receiver (rho = 1)
//! in empty space; nothing comes back, so the receiver's mean radiosity is
//! pi * F_er * A_e / A_r and the form factor follows from the report.

use crate::common::*;
use radiosity::report::Surface;

fn form_factor(emitter: &Surface, receiver: &Surface) -> f64 {
    receiver.radiosity[0] * receiver.area / (std::f64::consts::PI * emitter.area)
}

fn check(name: &str, emitter: Vec<Vec<glam::Vec3>>, receiver: Vec<Vec<glam::Vec3>>, expected: f64) {
    let (_dir, path) = write_scene(
        name,
        &[
            surface("emitter", emitter, 0.0, 1.0),
            surface("receiver", receiver, 1.0, 0.0),
        ],
    );
    let r = solve_file(&path, &tight(1e-9));
    let f = form_factor(node(&r, "emitter"), node(&r, "receiver"));
    eprintln!(
        "{name}: F = {f:.5} (expected {expected}, {} patches)",
        r.report.counts.patches
    );
    assert!(
        rel(f, expected) < 0.01,
        "{name}: F = {f}, expected {expected} within 1%"
    );
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

#[test]
fn glb_gives_the_same_answer_as_gltf() {
    let surfaces = [
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
    ];
    let (dir, path) = write_scene("pair", &surfaces);
    let glb = dir.path().join("pair.glb");
    std::fs::write(&glb, to_glb(&std::fs::read_to_string(&path).expect("read"))).expect("write");
    let mut opts = tight(1e-6);
    opts.stop.max_shots = 30;
    let a = solve_file(&path, &opts);
    let b = solve_file(&glb, &opts);
    assert_eq!(a.report.surfaces, b.report.surfaces);
    assert!(node(&b, "receiver").radiosity[0] > 0.5);
}
