//! Emissive textures (issue 64 item 4): emission = emissiveFactor x
//! emissiveTexture x strength, each element emitting the texture's mean over
//! it, the shadow rays weighing the emitter's points by the texture, and
//! the picture showing the texture. The scene is
//! `tests/fixtures/emissive/panel-room.gltf` (`scripts/make-emissive-scene.py`):
//! a closed grey room lit only by a ceiling panel whose texture is white on
//! its -x half and black on its +x half, at strength 10.

use crate::common::*;
use radiosity::mesh::{Mesh, MeshSettings};
use radiosity::render::{render, RenderOptions};
use std::time::Duration;

/// The fixture's path.
pub(crate) const PANEL_ROOM: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/fixtures/emissive/panel-room.gltf"
);

fn panel_room() -> radiosity::scene::Scene {
    radiosity::scene::open(PANEL_ROOM).expect("the fixture loads")
}

#[test]
fn an_emissive_texture_emits_its_mean_over_each_element() {
    let scene = panel_room();
    let panel = scene
        .nodes
        .iter()
        .position(|n| n == "panel")
        .expect("panel");
    let mesh = Mesh::build(&scene, &MeshSettings::default());
    // 8 x 8 elements, one texel wide each: texels 0-3 white, 4-7 black.
    // Bilinear filtering blurs the middle two columns (4 points an element
    // at texel offsets 1/8, 3/8, 5/8, 7/8: 0.875 and 0.125 of white).
    let x0 = mesh
        .elements
        .iter()
        .filter(|e| mesh.polygons[e.polygon as usize].node == panel)
        .map(|e| e.centre.x)
        .fold(f32::INFINITY, f32::min);
    let mut columns = [(0.0, 0.0); 8];
    for (j, e) in mesh.elements.iter().enumerate() {
        if mesh.polygons[e.polygon as usize].node != panel {
            continue;
        }
        let k = ((e.centre.x - x0) / 0.125).round() as usize;
        columns[k].0 += mesh.element_exitance(j)[0] * e.area;
        columns[k].1 += e.area;
    }
    let white = std::f64::consts::PI * 10.0;
    let want = [1.0, 1.0, 1.0, 0.875, 0.125, 0.0, 0.0, 0.0];
    for (k, ((sum, area), w)) in columns.iter().zip(want).enumerate() {
        let got = sum / area / white;
        assert!(
            (got - w).abs() < 1e-4,
            "column {k}: {got} of white, want {w}"
        );
    }
    // The polygon emits the texture's mean over it; the power is its sum.
    let p = scene
        .polygons
        .iter()
        .find(|p| p.node == panel)
        .expect("the panel's polygon");
    assert!((p.emission[0] - 5.0).abs() < 1e-4, "{:?}", p.emission);
    let power = mesh.emitted_power();
    assert!(rel(power, 3.0 * white * 0.5) < 1e-4, "power {power}");
}

/// The room converges to the path tracer's radiosities (Mitsuba 3, the
/// panel's area emitter taking the same texture, per node at 0.1 %
/// standard error: docs/references/emissive-panel-room.json), and the wall
/// under the lit half is brighter than the other, as the texture makes it.
#[test]
fn a_room_lit_only_by_an_emissive_texture_converges_to_the_path_tracer() {
    let scene = panel_room();
    let opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    let r = render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("render");
    assert!(r.report.converged, "the solve reached its stop rule");
    let left = node(&r, "wall_left").radiosity[0];
    let right = node(&r, "wall_right").radiosity[0];
    assert!(left > 1.2 * right, "left wall {left}, right wall {right}");
    crate::reference::check_scene("emissive-panel-room", &scene);
}

/// The picture shows the texture: the lit half at its radiance, the dark
/// half black, and the whole within 2.5 % SMAPE of the path-traced image
/// (docs/references/images/emissive-panel-room.exr).
#[test]
fn the_picture_shows_the_emissive_texture() {
    let dir = format!("{}/docs/references/images", env!("CARGO_MANIFEST_DIR"));
    let path = std::path::PathBuf::from(format!("{dir}/emissive-panel-room.exr"));
    let (w, h, reference) = radiosity::output::read_exr(&path).expect("reference EXR");
    let opts = RenderOptions {
        width: w,
        height: Some(h),
        ..RenderOptions::default()
    };
    let r = render(gpu(), &panel_room(), &opts, Duration::ZERO, &mut |_| {}).expect("render");
    let (_, _, pixels) = r.image.as_ref().expect("an image");
    // The panel fills the middle two thirds; its halves' middles are at a
    // sixth of the width either side of the centre.
    let at = |x: u32| {
        let rows = 2 * h / 5..3 * h / 5;
        let n = rows.len() as f32;
        rows.map(|y| pixels[(y * w + x) as usize][0]).sum::<f32>() / n
    };
    let (lit, dark) = (at(w / 2 - w / 6), at(w / 2 + w / 6));
    eprintln!("picture: lit half {lit}, dark half {dark}");
    assert!((lit - 10.0).abs() < 0.05, "lit half {lit}, want 10");
    assert!(dark < 0.05, "dark half {dark}, want 0");
    let smape = radiosity::compare::smape(pixels, &reference, w as usize, h as usize);
    eprintln!("emissive-panel-room: image {:.2} % SMAPE", 100.0 * smape);
    assert!(smape <= 0.025, "image {:.2} % off", 100.0 * smape);
}
