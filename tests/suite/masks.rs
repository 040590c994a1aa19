//! Alpha cut-outs (issue 64 item 5): `alphaMode: MASK` cuts a surface out
//! where its base colour's alpha is under the cutoff, for light and for the
//! picture alike (`radiosity::scene::mask`).

use crate::common::*;
use base64::Engine;
use radiosity::render::{render, RenderOptions};
use radiosity::scene;
use serde_json::json;
use std::time::Duration;

/// A PNG data URI: a `k` x `k` checkerboard, grey, its even squares opaque
/// and its odd ones clear.
fn checker_png(k: u32) -> String {
    let img = image::RgbaImage::from_fn(k, k, |x, y| {
        image::Rgba([160, 160, 160, if (x + y) % 2 == 0 { 255 } else { 0 }])
    });
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .expect("encode");
    format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

/// A 1 m light 1 m up, facing down, over a 6 m floor; with `mask`
/// (`Some("MASK")` or `Some("OPAQUE")`), a 2 m square half way between,
/// facing up, textured by an 8 x 8 checkerboard whose odd squares are
/// clear. Nothing but the floor reflects toward the floor, so its
/// radiosity is rho times the light that reaches it.
pub(crate) fn masked_room(mask: Option<&str>) -> scene::Scene {
    scene::load_slice(
        &serde_json::to_vec(&masked_doc(mask)).expect("JSON"),
        "masked",
    )
    .expect("loads")
}

/// [`masked_room`] as glTF JSON.
pub(crate) fn masked_doc(mask: Option<&str>) -> serde_json::Value {
    let light = surface(
        "light",
        vec![rect(1, 1.0, [-0.5, -0.5], [0.5, 0.5], false)],
        0.0,
        1.0,
    );
    let floor = surface(
        "floor",
        vec![rect(1, 0.0, [-3.0, -3.0], [3.0, 3.0], true)],
        0.5,
        0.0,
    );
    let mut surfaces = vec![light, floor];
    if mask.is_some() {
        surfaces.push(surface(
            "mask",
            vec![rect(1, 0.5, [-1.0, -1.0], [1.0, 1.0], true)],
            0.5,
            0.0,
        ));
    }
    let text = scene::write_gltf(&surfaces, None);
    let mut doc: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    if let Some(mode) = mask {
        // The quad's corners as written: (z, x) = (lo, lo), (hi, lo), (hi, hi), (lo, hi).
        let uv: [f32; 8] = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0];
        add_base_texture(&mut doc, 2, &uv, &checker_png(8));
        let material = &mut doc["materials"][2];
        material["pbrMetallicRoughness"]["baseColorTexture"] = json!({"index": 0});
        material["alphaMode"] = json!(mode);
        material["alphaCutoff"] = json!(0.5);
    }
    doc
}

/// The floor's light under a checkerboard mask is half way between its
/// light with no square and under an opaque one: the clear half passes
/// (the even and odd squares see the light alike, by the scene's mirror
/// symmetry), within 1 %. The mask's warning is gone.
#[test]
fn a_checkerboard_mask_over_a_light_passes_half_its_light() {
    let opts = RenderOptions {
        width: 0,
        ..tight(1e-4)
    };
    let floor = |s: &scene::Scene| {
        let r = render(gpu(), s, &opts, Duration::ZERO, &mut |_| {}).expect("render");
        node(&r, "floor").radiosity[0]
    };
    let masked = masked_room(Some("MASK"));
    assert!(
        !masked.warnings.iter().any(|w| w.contains("MASK")),
        "{:?}",
        masked.warnings
    );
    let (none, opaque, half) = (
        floor(&masked_room(None)),
        floor(&masked_room(Some("OPAQUE"))),
        floor(&masked),
    );
    let want = 0.5 * (none + opaque);
    eprintln!("floor: no square {none}, opaque {opaque}, masked {half} (want {want})");
    assert!(opaque < 0.8 * none, "the square must shade the floor");
    assert!(rel(half, want) < 0.01, "masked {half}, want {want}");
}
