//! Bakes a solution into glTF: every mesh node of the scene, with its name
//! and world transform, re-meshed on its elements with the radiosity as
//! linear vertex colours (`COLOR_0`) and unlit materials
//! (`KHR_materials_unlit`), so Blender, three.js or a game engine show the lit
//! scene without lights. Pure data: no GPU, no MPI.
//!
//! # Colour scale
//! `COLOR_0 = min(1, B / pi * scale)`: radiance times `scale`, where `scale`
//! is 1 over the brightest radiance of any element that does not emit (so
//! lit surfaces span [0, 1] and only emitters clip). The report's `bake`
//! section says the scale; B includes the ambient term when the report's
//! radiosities do.

use crate::mesh::Mesh;
use crate::scene::Scene;
use base64::Engine;
use glam::{DMat4, DVec3};
use serde_json::{json, Value};

/// What a bake wrote, for the report.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Baked {
    /// The file.
    pub path: String,
    /// COLOR_0 = min(1, radiance x scale), radiance = B / pi in W sr^-1 m^-2.
    pub scale: f64,
    /// Nodes written.
    pub nodes: usize,
    /// Triangles written.
    pub triangles: usize,
}

/// The colour scale (see the module docs).
pub fn colour_scale(mesh: &Mesh, radiosity: &[[f64; 3]]) -> f64 {
    let peak = radiosity
        .iter()
        .zip(&mesh.elements)
        .filter(|(_, e)| mesh.polygons[e.polygon as usize].exitance == [0.0; 3])
        .flat_map(|(b, _)| b.iter().copied())
        .filter(|x| x.is_finite())
        .fold(0.0f64, f64::max)
        / std::f64::consts::PI;
    if peak > 0.0 {
        1.0 / peak
    } else {
        1.0
    }
}

/// The solved scene as a glTF document (buffer embedded as a data URI; see
/// [`crate::scene::to_glb`] for GLB). `radiosity` is per element of `mesh`.
pub fn bake(scene: &Scene, mesh: &Mesh, radiosity: &[[f64; 3]], scale: f64) -> (Value, usize) {
    let origin = DVec3::from(scene.origin);
    let mut bin: Vec<u8> = Vec::new();
    let (mut nodes, mut meshes, mut materials, mut accessors, mut views) =
        (vec![], vec![], vec![], vec![], vec![]);
    let mut triangles = 0usize;
    let mut view = |bin: &mut Vec<u8>, bytes: &[u8], target: u32| -> usize {
        let offset = bin.len();
        bin.extend_from_slice(bytes);
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        views.push(
            json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len(), "target": target}),
        );
        views.len() - 1
    };
    for (n, name) in scene.nodes.iter().enumerate() {
        // Vertices in the node's own frame, so its transform stays its own.
        let world = scene
            .node_transforms
            .get(n)
            .map(DMat4::from_cols_array)
            .filter(|m| m.determinant().is_finite() && m.determinant() != 0.0)
            .unwrap_or(DMat4::IDENTITY);
        let g = node_geometry(mesh, radiosity, n, world.inverse(), origin, scale);
        let Some((reflectance, exitance)) = g.material else {
            continue;
        };
        triangles += g.triangles;
        let (pos, col, idx, lo, hi) = (g.pos, g.col, g.idx, g.lo, g.hi);
        let count = pos.len() / 3;
        let p = view(&mut bin, bytemuck::cast_slice(&pos), 34962);
        let c = view(&mut bin, bytemuck::cast_slice(&col), 34962);
        let i = view(&mut bin, bytemuck::cast_slice(&idx), 34963);
        let a = accessors.len();
        accessors.push(
            json!({"bufferView": p, "componentType": 5126, "count": count, "type": "VEC3",
            "min": lo.to_array().map(|x| x as f32), "max": hi.to_array().map(|x| x as f32)}),
        );
        accessors
            .push(json!({"bufferView": c, "componentType": 5126, "count": count, "type": "VEC3"}));
        accessors.push(
            json!({"bufferView": i, "componentType": 5125, "count": idx.len(), "type": "SCALAR"}),
        );
        let m = materials.len();
        materials.push(baked_material(name, reflectance, exitance));
        meshes.push(json!({"name": name, "primitives": [{"attributes": {"POSITION": a, "COLOR_0": a + 1}, "indices": a + 2, "material": m, "mode": 4}]}));
        let mut node = json!({"name": name, "mesh": meshes.len() - 1});
        if world != DMat4::IDENTITY {
            node["matrix"] = json!(world.to_cols_array().map(|x| x as f32));
        }
        nodes.push(node);
    }
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": "radiosity (baked solution)"},
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0,
        "scenes": [{"nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes, "meshes": meshes, "materials": materials,
        "accessors": accessors, "bufferViews": views,
        "buffers": [{"byteLength": bin.len(), "uri": format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&bin)
        )}],
    });
    if let Some(cam) = &scene.camera {
        add_camera(&mut doc, cam, origin);
    }
    (doc, triangles)
}

/// Adds `cam` (in the scene's frame, offset by `origin`) as a camera node.
fn add_camera(doc: &mut Value, cam: &crate::scene::Camera, origin: DVec3) {
    let n = doc["nodes"].as_array().map_or(0, Vec::len);
    let position = (cam.position.as_dvec3() + origin)
        .to_array()
        .map(|x| x as f32);
    doc["cameras"] = json!([{"type": "perspective", "perspective": {
            "yfov": cam.yfov, "znear": cam.znear, "aspectRatio": cam.aspect.unwrap_or(1.0)}}]);
    if let Some(nodes) = doc["nodes"].as_array_mut() {
        nodes.push(json!({"name": "camera", "camera": 0, "translation": position, "rotation": cam.rotation.to_array()}));
    }
    if let Some(list) = doc["scenes"][0]["nodes"].as_array_mut() {
        list.push(json!(n));
    }
}

/// One node's elements as triangles in its own frame (`to_local`), with
/// their colours, bounds and material.
struct NodeGeometry {
    pos: Vec<f32>,
    col: Vec<f32>,
    idx: Vec<u32>,
    lo: DVec3,
    hi: DVec3,
    /// The node's reflectance and exitance; `None`: the node has no elements.
    material: Option<([f64; 3], [f64; 3])>,
    triangles: usize,
}

fn node_geometry(
    mesh: &Mesh,
    radiosity: &[[f64; 3]],
    n: usize,
    to_local: DMat4,
    origin: DVec3,
    scale: f64,
) -> NodeGeometry {
    let mut g = NodeGeometry {
        pos: Vec::new(),
        col: Vec::new(),
        idx: Vec::new(),
        lo: DVec3::splat(f64::INFINITY),
        hi: DVec3::splat(f64::NEG_INFINITY),
        material: None,
        triangles: 0,
    };
    for (e, b) in mesh.elements.iter().zip(radiosity) {
        let poly = &mesh.polygons[e.polygon as usize];
        if poly.node != n {
            continue;
        }
        g.material.get_or_insert((poly.reflectance, poly.exitance));
        let colour = b.map(|x| ((x / std::f64::consts::PI * scale).clamp(0.0, 1.0)) as f32);
        let corners: &[glam::Vec3] = if e.corners[3] == e.corners[2] {
            &e.corners[..3]
        } else {
            &e.corners
        };
        let base = (g.pos.len() / 3) as u32;
        for c in corners {
            let p = to_local.transform_point3(c.as_dvec3() + origin);
            g.lo = g.lo.min(p);
            g.hi = g.hi.max(p);
            g.pos.extend(p.to_array().map(|x| x as f32));
            g.col.extend_from_slice(&colour);
        }
        for k in 1..corners.len() as u32 - 1 {
            g.idx.extend_from_slice(&[base, base + k, base + k + 1]);
            g.triangles += 1;
        }
    }
    g
}

/// An unlit material that shows the vertex colours; emitters stay emitters
/// (so the file loads back here as a scene), normalised:
/// KHR_materials_emissive_strength beside unlit draws a validator warning,
/// and the radiance itself is in the extras.
fn baked_material(name: &str, reflectance: [f64; 3], exitance: [f64; 3]) -> Value {
    let radiance = exitance.map(|x| x / std::f64::consts::PI);
    let mut material = json!({
        "name": name,
        "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
        "extensions": {"KHR_materials_unlit": {}},
        "extras": {"reflectance": reflectance, "emitted_radiance": radiance},
    });
    let peak = radiance.iter().copied().fold(0.0f64, f64::max);
    if peak > 0.0 {
        material["emissiveFactor"] = json!(radiance.map(|x| x / peak.max(1.0)));
    }
    material
}

/// Writes the bake to `path` (`.glb` binary, anything else glTF JSON), atomically.
pub fn write(
    path: &std::path::Path,
    scene: &Scene,
    mesh: &Mesh,
    radiosity: &[[f64; 3]],
) -> Result<Baked, crate::output::OutputError> {
    let scale = colour_scale(mesh, radiosity);
    let (doc, triangles) = bake(scene, mesh, radiosity, scale);
    let glb = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("glb"));
    let bytes = if glb {
        crate::scene::to_glb(&doc).unwrap_or_default()
    } else {
        serde_json::to_vec_pretty(&doc).unwrap_or_default()
    };
    crate::output::write_atomic(path, &bytes)?;
    Ok(Baked {
        path: path.display().to_string(),
        scale,
        nodes: doc["nodes"].as_array().map_or(0, Vec::len) - usize::from(scene.camera.is_some()),
        triangles,
    })
}
