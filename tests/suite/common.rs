//! Shared helpers: one GPU for the whole suite, scene building, Lambert's formula.

use glam::Vec3;
use radiosity::gpu::Gpu;
use radiosity::render::{render, RenderOptions, Rendered};
use radiosity::scene::{self, GltfSurface};
use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::Duration;

/// The suite's one device.
pub fn gpu() -> &'static Gpu {
    static GPU: OnceLock<Gpu> = OnceLock::new();
    GPU.get_or_init(|| match Gpu::new() {
        Ok(g) => g,
        Err(e) => panic!("{e}"),
    })
}

/// A one-sided surface.
pub fn surface(
    name: &str,
    polygons: Vec<Vec<Vec3>>,
    reflectance: f32,
    emission: f32,
) -> GltfSurface {
    GltfSurface {
        name: name.into(),
        polygons,
        reflectance: [reflectance; 3],
        emission: [emission; 3],
        double_sided: false,
        subdivision: None,
    }
}

/// Axis-aligned rectangle in the plane `axis = at`, facing `+axis` when `positive`
/// (the library's [`radiosity::scene::axis_rect`]).
pub fn rect(axis: usize, at: f32, lo: [f32; 2], hi: [f32; 2], positive: bool) -> Vec<Vec3> {
    radiosity::scene::axis_rect(axis, at, lo, hi, positive)
}

/// A regular polygon approximating a disk of radius `r` in the plane z = `z`.
pub fn disk(r: f32, z: f32, segments: usize, facing_up: bool) -> Vec<Vec<Vec3>> {
    (0..segments)
        .map(|i| {
            let a0 = i as f32 / segments as f32 * std::f32::consts::TAU;
            let a1 = (i + 1) as f32 / segments as f32 * std::f32::consts::TAU;
            let mut t = vec![
                Vec3::new(0.0, 0.0, z),
                Vec3::new(r * a0.cos(), r * a0.sin(), z),
                Vec3::new(r * a1.cos(), r * a1.sin(), z),
            ];
            if !facing_up {
                t.reverse();
            }
            t
        })
        .collect()
}

/// Writes surfaces as a glTF file in a fresh temporary directory.
pub fn write_scene(name: &str, surfaces: &[GltfSurface]) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join(format!("{name}.gltf"));
    std::fs::write(&path, scene::write_gltf(surfaces, None)).expect("write scene");
    (dir, path)
}

/// Loads a glTF file through the public loader and renders it (no image unless `width` > 0).
pub fn solve_file(path: &std::path::Path, opts: &RenderOptions) -> Rendered {
    let scene = scene::open(path.to_str().expect("utf-8 path")).expect("scene loads");
    render(gpu(), &scene, opts, Duration::ZERO, &mut |_| {}).expect("render")
}

/// Options for accuracy tests: converge tightly, no image.
pub fn tight(threshold: f64) -> RenderOptions {
    let mut o = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    o.stop.threshold = threshold;
    o
}

/// The report surface named `node`.
pub fn node<'a>(r: &'a Rendered, node: &str) -> &'a radiosity::report::Surface {
    r.report
        .surfaces
        .iter()
        .find(|s| s.node == node)
        .unwrap_or_else(|| panic!("no surface {node}"))
}

/// Form factor from a differential area at the origin with normal +z to a
/// planar polygon, by Lambert's contour integral, after clipping the polygon
/// to z >= 0. Independent of the renderer.
pub fn lambert(poly: &[[f64; 3]]) -> f64 {
    let clipped = clip_z(poly);
    let mut sum = 0.0;
    for i in 0..clipped.len() {
        let a = clipped[i];
        let b = clipped[(i + 1) % clipped.len()];
        let c = [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ];
        let lc = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        if lc < 1e-15 {
            continue;
        }
        let la = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        let lb = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
        let cos = ((a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (la * lb)).clamp(-1.0, 1.0);
        sum += cos.acos() * c[2] / lc;
    }
    sum.abs() / (2.0 * std::f64::consts::PI)
}

fn clip_z(poly: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut out = Vec::new();
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        if a[2] >= 0.0 {
            out.push(a);
        }
        if (a[2] >= 0.0) != (b[2] >= 0.0) {
            let t = a[2] / (a[2] - b[2]);
            out.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), 0.0]);
        }
    }
    out
}

/// Relative difference.
pub fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

/// Gives mesh `mesh` of a glTF document its texture coordinates `uv` (one
/// pair a vertex, as a data-URI buffer) and its material a base-colour
/// texture of the image at `image_uri`, sampled clamped.
pub fn add_base_texture(doc: &mut serde_json::Value, mesh: usize, uv: &[f32], image_uri: &str) {
    use base64::Engine;
    use serde_json::json;
    let bytes: Vec<u8> = uv.iter().flat_map(|f| f.to_le_bytes()).collect();
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bytes)
    );
    let push = |doc: &mut serde_json::Value, key: &str, item: serde_json::Value| {
        let list = doc[key].as_array_mut().expect("a glTF array");
        list.push(item);
        list.len() - 1
    };
    let buffer = push(
        doc,
        "buffers",
        json!({"uri": uri, "byteLength": bytes.len()}),
    );
    let view = push(
        doc,
        "bufferViews",
        json!({"buffer": buffer, "byteLength": bytes.len()}),
    );
    let accessor = push(
        doc,
        "accessors",
        json!({"bufferView": view, "componentType": 5126, "count": uv.len() / 2, "type": "VEC2"}),
    );
    doc["meshes"][mesh]["primitives"][0]["attributes"]["TEXCOORD_0"] = json!(accessor);
    doc["images"] = json!([{ "uri": image_uri }]);
    doc["samplers"] = json!([{"wrapS": 33071, "wrapT": 33071}]);
    doc["textures"] = json!([{"source": 0, "sampler": 0}]);
}
