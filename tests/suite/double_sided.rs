//! Double-sided materials (what Blender and most tools export): the Cornell
//! box with every material but the light's double-sided must give the
//! single-sided box's picture and front radiosities, each pixel showing the
//! side that faces the camera, and the report must give the backs apart.

use crate::common::gpu;
use radiosity::render::{render, RenderOptions, Rendered};
use radiosity::scene::Scene;
use std::time::Duration;

fn cornell(double_sided: bool) -> Scene {
    let text = radiosity::scene::builtin_gltf("cornell").expect("built-in");
    let mut doc: serde_json::Value = serde_json::from_str(&text).expect("glTF JSON");
    for m in doc["materials"].as_array_mut().expect("materials") {
        let emits = m["emissiveFactor"]
            .as_array()
            .is_some_and(|e| e.iter().any(|x| x.as_f64().unwrap_or(0.0) > 0.0));
        if !emits {
            m["doubleSided"] = serde_json::json!(double_sided);
        }
    }
    let bytes = serde_json::to_vec(&doc).expect("JSON");
    radiosity::scene::load_slice(&bytes, "cornell").expect("loads")
}

fn solve(scene: &Scene) -> Rendered {
    let opts = RenderOptions {
        width: 128,
        ..RenderOptions::default()
    };
    render(gpu(), scene, &opts, Duration::ZERO, &mut |_| {}).expect("render")
}

#[test]
fn a_double_sided_cornell_box_gives_the_single_sided_picture_and_fronts() {
    let (one, two) = (solve(&cornell(false)), solve(&cornell(true)));
    let (w, h, a) = one.image.as_ref().expect("image");
    let (_, _, b) = two.image.as_ref().expect("image");
    let s = radiosity::compare::smape(a, b, *w as usize, *h as usize);
    assert!(s <= 0.005, "image SMAPE {:.2} % > 0.5 %", s * 100.0);
    for x in &one.report.surfaces {
        let y = two
            .report
            .surfaces
            .iter()
            .find(|y| y.node == x.node)
            .expect("same nodes");
        let (p, q): (f64, f64) = (x.radiosity.iter().sum(), y.radiosity.iter().sum());
        assert!(
            (q / p - 1.0).abs() <= 0.005,
            "{}: front {q} vs single-sided {p}",
            x.node
        );
        assert!(
            (x.area - y.area).abs() < 1e-9 * x.area,
            "{}: front area",
            x.node
        );
        assert!(x.back.is_none(), "{}: one-sided has no back", x.node);
        if x.node == "light" {
            assert!(y.back.is_none(), "the light stays one-sided");
        } else {
            let back = y.back.expect("a double-sided node reports its back");
            assert!((back.area - y.area).abs() < 1e-6 * y.area);
            // The outside of the box sees no light; its inside neither.
            let b: f64 = back.radiosity.iter().sum();
            assert!(b < 0.02 * q, "{}: back {b} vs front {q}", x.node);
        }
    }
}
