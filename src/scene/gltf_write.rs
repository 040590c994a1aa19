//! Writes simple scenes as self-contained glTF 2.0 (buffers embedded as data URIs),
//! so built-in scenes can be opened in Blender and go through the same loader.

use super::Subdivision;
use base64::Engine;
use glam::{Quat, Vec3};
use serde_json::{json, Value};

/// One glTF node: planar polygons (3 or 4 vertices each, counter-clockwise seen
/// from the front) sharing one material.
#[derive(Clone, Debug)]
pub struct GltfSurface {
    /// Node name (the report's `surfaces[].node`).
    pub name: String,
    /// Polygons as vertex lists.
    pub polygons: Vec<Vec<Vec3>>,
    /// Reflectance (baseColorFactor.rgb).
    pub reflectance: [f32; 3],
    /// Emitted radiance (emissiveFactor x KHR_materials_emissive_strength).
    pub emission: [f32; 3],
    /// Whether both sides are surfaces.
    pub double_sided: bool,
    /// Optional fixed subdivision, written to the node's `extras.radiosity`.
    pub subdivision: Option<Subdivision>,
}

/// Serialises surfaces and an optional perspective camera (position, rotation,
/// vertical fov, aspect) to glTF JSON text.
pub fn write_gltf(surfaces: &[GltfSurface], camera: Option<(Vec3, Quat, f32, f32)>) -> String {
    let mut bin: Vec<u8> = Vec::new();
    let (mut nodes, mut meshes, mut materials, mut accessors, mut views) =
        (vec![], vec![], vec![], vec![], vec![]);
    for (i, s) in surfaces.iter().enumerate() {
        let mut pos: Vec<f32> = Vec::new();
        let mut idx: Vec<u32> = Vec::new();
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for poly in &s.polygons {
            let base = (pos.len() / 3) as u32;
            for v in poly {
                pos.extend_from_slice(&v.to_array());
                lo = lo.min(*v);
                hi = hi.max(*v);
            }
            // Fan triangulation keeps quads as consecutive triangle pairs sharing an edge.
            for k in 1..poly.len() as u32 - 1 {
                idx.extend_from_slice(&[base, base + k, base + k + 1]);
            }
        }
        let pos_off = bin.len();
        bin.extend_from_slice(bytemuck::cast_slice(&pos));
        let idx_off = bin.len();
        bin.extend_from_slice(bytemuck::cast_slice(&idx));
        views.push(json!({"buffer": 0, "byteOffset": pos_off, "byteLength": pos.len() * 4, "target": 34962}));
        views.push(json!({"buffer": 0, "byteOffset": idx_off, "byteLength": idx.len() * 4, "target": 34963}));
        accessors.push(json!({"bufferView": 2 * i, "componentType": 5126, "count": pos.len() / 3, "type": "VEC3",
            "min": lo.to_array(), "max": hi.to_array()}));
        accessors.push(json!({"bufferView": 2 * i + 1, "componentType": 5125, "count": idx.len(), "type": "SCALAR"}));
        let peak = s.emission.iter().cloned().fold(0.0f32, f32::max);
        let mut material = json!({
            "name": s.name,
            "pbrMetallicRoughness": {"baseColorFactor": [s.reflectance[0], s.reflectance[1], s.reflectance[2], 1.0],
                                      "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "doubleSided": s.double_sided,
        });
        if peak > 0.0 {
            let scale = peak.max(1.0);
            material["emissiveFactor"] = json!(s.emission.map(|e| e / scale));
            if scale > 1.0 {
                material["extensions"] =
                    json!({"KHR_materials_emissive_strength": {"emissiveStrength": scale}});
            }
        }
        materials.push(material);
        meshes.push(json!({"name": s.name, "primitives": [{"attributes": {"POSITION": 2 * i}, "indices": 2 * i + 1, "material": i, "mode": 4}]}));
        let mut node = json!({"name": s.name, "mesh": i});
        if let Some(sub) = s.subdivision {
            node["extras"] =
                json!({"radiosity": {"patches": sub.patches, "elements": sub.elements}});
        }
        nodes.push(node);
    }
    let mut cameras: Vec<Value> = vec![];
    if let Some((p, r, yfov, aspect)) = camera {
        cameras.push(json!({"type": "perspective", "perspective": {"yfov": yfov, "aspectRatio": aspect, "znear": 0.01}}));
        nodes.push(json!({"name": "camera", "camera": 0, "translation": p.to_array(), "rotation": r.to_array()}));
    }
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": "radiosity"},
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "scene": 0,
        "scenes": [{"nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes, "meshes": meshes, "materials": materials,
        "accessors": accessors, "bufferViews": views,
        "buffers": [{"byteLength": bin.len(), "uri": uri}],
    });
    if !cameras.is_empty() {
        doc["cameras"] = Value::Array(cameras);
    }
    // serde_json's pretty printer is deterministic (maps are sorted), so the
    // shipped scenes can be checked against the generator byte for byte.
    serde_json::to_string_pretty(&doc).unwrap_or_default()
}

/// The same document as GLB (glTF's binary container): the first buffer's
/// data URI moved to the BIN chunk. `None` when it has no such buffer.
pub fn to_glb(doc: &Value) -> Option<Vec<u8>> {
    let mut doc = doc.clone();
    let uri = doc.pointer("/buffers/0/uri")?.as_str()?.to_string();
    let data = base64::engine::general_purpose::STANDARD
        .decode(uri.split_once(',')?.1)
        .ok()?;
    doc.pointer_mut("/buffers/0")?
        .as_object_mut()?
        .remove("uri");
    glb_from(&doc, data)
}

/// A GLB of `doc` (whose buffer 0 has no URI) and `bin`, that buffer's bytes.
pub fn glb_from(doc: &Value, bin: Vec<u8>) -> Option<Vec<u8>> {
    let data = bin;
    let mut json = serde_json::to_vec(doc).ok()?;
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let mut bin = data;
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    Some(out)
}

/// An axis-aligned rectangle in the plane `axis = at`, facing `+axis` when
/// `positive`; `lo`/`hi` bound the other two axes (in cyclic order after
/// `axis`). For test and study scenes.
pub fn axis_rect(axis: usize, at: f32, lo: [f32; 2], hi: [f32; 2], positive: bool) -> Vec<Vec3> {
    let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
    let p = |u: f32, v: f32| {
        let mut c = [0.0; 3];
        c[axis] = at;
        c[a] = u;
        c[b] = v;
        Vec3::from(c)
    };
    // (a, b, axis) is right-handed, so counter-clockwise in (a, b) faces +axis.
    let mut q = vec![
        p(lo[0], lo[1]),
        p(hi[0], lo[1]),
        p(hi[0], hi[1]),
        p(lo[0], hi[1]),
    ];
    if !positive {
        q.reverse();
    }
    q
}

/// Six faces of an axis-aligned box, each facing outwards (or inwards).
pub(super) fn box_faces(lo: Vec3, hi: Vec3, outward: bool) -> Vec<Vec<Vec3>> {
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    let (a, b) = (lo, hi);
    // Counter-clockwise seen from outside.
    let mut faces = vec![
        vec![
            c(a.x, a.y, a.z),
            c(a.x, a.y, b.z),
            c(a.x, b.y, b.z),
            c(a.x, b.y, a.z),
        ], // -x
        vec![
            c(b.x, a.y, a.z),
            c(b.x, b.y, a.z),
            c(b.x, b.y, b.z),
            c(b.x, a.y, b.z),
        ], // +x
        vec![
            c(a.x, a.y, a.z),
            c(b.x, a.y, a.z),
            c(b.x, a.y, b.z),
            c(a.x, a.y, b.z),
        ], // -y
        vec![
            c(a.x, b.y, a.z),
            c(a.x, b.y, b.z),
            c(b.x, b.y, b.z),
            c(b.x, b.y, a.z),
        ], // +y
        vec![
            c(a.x, a.y, a.z),
            c(a.x, b.y, a.z),
            c(b.x, b.y, a.z),
            c(b.x, a.y, a.z),
        ], // -z
        vec![
            c(a.x, a.y, b.z),
            c(b.x, a.y, b.z),
            c(b.x, b.y, b.z),
            c(a.x, b.y, b.z),
        ], // +z
    ];
    if !outward {
        faces.iter_mut().for_each(|f| f.reverse());
    }
    faces
}
