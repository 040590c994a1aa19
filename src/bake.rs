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
//!
//! # Textures
//! A textured surface keeps its texture (the image as the scene file had
//! it, in the bake's buffer) and its coordinates, and its `COLOR_0` is the
//! irradiance, `B / (pi rho) * scale` with rho the element's mean
//! reflectance, so a viewer that multiplies the texture by the vertex
//! colour (glTF's unlit materials do) shows the lit texture. The scale then
//! covers the brightest of both.

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
        .flat_map(|(b, e)| baked_value(mesh, e, b))
        .filter(|x| x.is_finite())
        .fold(0.0f64, f64::max)
        / std::f64::consts::PI;
    if peak > 0.0 {
        1.0 / peak
    } else {
        1.0
    }
}

/// Appends `bytes` to the buffer (4-byte aligned) as a new buffer view.
fn push_view(
    bin: &mut Vec<u8>,
    views: &mut Vec<Value>,
    bytes: &[u8],
    target: Option<u32>,
) -> usize {
    let offset = bin.len();
    bin.extend_from_slice(bytes);
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let mut v = json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()});
    if let Some(t) = target {
        v["target"] = json!(t);
    }
    views.push(v);
    views.len() - 1
}

/// What element `e` of radiosity `b` bakes (before 1 / pi and the scale):
/// B, or B / rho on a textured polygon (see the module docs).
fn baked_value(mesh: &Mesh, e: &crate::mesh::Element, b: &[f64; 3]) -> [f64; 3] {
    if mesh.polygons[e.polygon as usize].textured {
        [0, 1, 2].map(|c| {
            if e.reflectance[c] > 1e-6 {
                b[c] / e.reflectance[c]
            } else {
                0.0
            }
        })
    } else {
        *b
    }
}

/// The solved scene as a glTF document (buffer embedded as a data URI; see
/// [`crate::scene::to_glb`] for GLB). `radiosity` is per element of `mesh`.
pub fn bake(scene: &Scene, mesh: &Mesh, radiosity: &[[f64; 3]], scale: f64) -> (Value, usize) {
    let (mut doc, bin, triangles) = bake_parts(scene, mesh, radiosity, scale);
    doc["buffers"][0]["uri"] = json!(format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    ));
    (doc, triangles)
}

/// The bake's glTF arrays and its one buffer, filled node by node.
#[derive(Default)]
struct GltfParts {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
    materials: Vec<Value>,
    images: Vec<Value>,
    textures: Vec<Value>,
    /// Texture index in the scene -> its index in the bake and its sampler.
    texture_of: std::collections::HashMap<usize, (usize, Value)>,
    triangles: usize,
}

impl GltfParts {
    /// A buffer view of `bytes` (`target`: a vertex or index buffer).
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        push_view(&mut self.bin, &mut self.views, bytes, target)
    }

    /// One primitive of node `name`: its positions, colours and indices,
    /// its material and, textured, its coordinates and texture.
    fn primitive(&mut self, name: &str, g: &NodeGeometry) -> Value {
        self.triangles += g.triangles;
        let count = g.pos.len() / 3;
        let p = self.view(bytemuck::cast_slice(&g.pos), Some(34962));
        let c = self.view(bytemuck::cast_slice(&g.col), Some(34962));
        let i = self.view(bytemuck::cast_slice(&g.idx), Some(34963));
        let a = self.accessors.len();
        self.accessors.push(
            json!({"bufferView": p, "componentType": 5126, "count": count, "type": "VEC3",
            "min": g.lo.to_array().map(|x| x as f32), "max": g.hi.to_array().map(|x| x as f32)}),
        );
        self.accessors
            .push(json!({"bufferView": c, "componentType": 5126, "count": count, "type": "VEC3"}));
        self.accessors.push(
            json!({"bufferView": i, "componentType": 5125, "count": g.idx.len(), "type": "SCALAR"}),
        );
        let mut attributes = json!({"POSITION": a, "COLOR_0": a + 1});
        let mut material = baked_material(name, g.reflectance, g.exitance);
        if let Some(t) = &g.texture {
            let uv = self.view(bytemuck::cast_slice(&g.uv), Some(34962));
            attributes["TEXCOORD_0"] = json!(self.accessors.len());
            self.accessors.push(
                json!({"bufferView": uv, "componentType": 5126, "count": count, "type": "VEC2"}),
            );
            let index = self.texture(t);
            material["pbrMetallicRoughness"]["baseColorTexture"] = json!({"index": index});
        }
        let m = self.materials.len();
        self.materials.push(material);
        json!({"attributes": attributes, "indices": a + 2, "material": m, "mode": 4})
    }

    /// The bake's index of texture `t`, its image written once.
    fn texture(&mut self, t: &crate::scene::texture::TextureRef) -> usize {
        if let Some((k, _)) = self.texture_of.get(&t.index) {
            return *k;
        }
        let v = self.view(&t.encoded.0, None);
        self.images
            .push(json!({"bufferView": v, "mimeType": t.encoded.1, "name": t.texture.name}));
        let [s, tw] = t.texture.wrap.map(|w| match w {
            crate::scene::texture::Wrap::Repeat => 10497,
            crate::scene::texture::Wrap::Mirror => 33648,
            crate::scene::texture::Wrap::Clamp => 33071,
        });
        let k = self.textures.len();
        self.textures
            .push(json!({"source": self.images.len() - 1, "sampler": k}));
        self.texture_of
            .insert(t.index, (k, json!({"wrapS": s, "wrapT": tw})));
        k
    }
}

/// [`bake`]'s document without its buffer's URI, the buffer's bytes, and
/// the triangle count: a GLB is written from them directly (Sponza's bake
/// is 178 MB; a data URI would hold a third more, twice over).
fn bake_parts(
    scene: &Scene,
    mesh: &Mesh,
    radiosity: &[[f64; 3]],
    scale: f64,
) -> (Value, Vec<u8>, usize) {
    let origin = DVec3::from(scene.origin);
    let mut baked = GltfParts::default();
    let (mut nodes, mut meshes) = (vec![], vec![]);
    for (n, name) in scene.nodes.iter().enumerate() {
        // Vertices in the node's own frame, so its transform stays its own.
        let world = scene
            .node_transforms
            .get(n)
            .map(DMat4::from_cols_array)
            .filter(|m| m.determinant().is_finite() && m.determinant() != 0.0)
            .unwrap_or(DMat4::IDENTITY);
        let groups = node_geometry(scene, mesh, radiosity, n, world.inverse(), origin, scale);
        if groups.is_empty() {
            continue;
        }
        let primitives: Vec<Value> = groups.iter().map(|g| baked.primitive(name, g)).collect();
        meshes.push(json!({"name": name, "primitives": primitives}));
        let mut node = json!({"name": name, "mesh": meshes.len() - 1});
        if world != DMat4::IDENTITY {
            node["matrix"] = json!(world.to_cols_array().map(|x| x as f32));
        }
        nodes.push(node);
    }
    let GltfParts {
        bin,
        views,
        accessors,
        materials,
        images,
        textures,
        texture_of,
        triangles,
    } = baked;
    let mut samplers: Vec<(usize, Value)> = texture_of.into_values().collect();
    samplers.sort_by_key(|(i, _)| *i);
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": "radiosity (baked solution)"},
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0,
        "scenes": [{"nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes, "meshes": meshes, "materials": materials,
        "accessors": accessors, "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    if !images.is_empty() {
        doc["images"] = json!(images);
        doc["textures"] = json!(textures);
        doc["samplers"] = json!(samplers.into_iter().map(|s| s.1).collect::<Vec<_>>());
    }
    if let Some(cam) = &scene.camera {
        add_camera(&mut doc, cam, origin);
    }
    (doc, bin, triangles)
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

/// One node's elements of one texture (or none) as triangles in its own
/// frame, with their colours, coordinates, bounds and material.
struct NodeGeometry {
    texture: Option<std::sync::Arc<crate::scene::texture::TextureRef>>,
    pos: Vec<f32>,
    col: Vec<f32>,
    uv: Vec<f32>,
    idx: Vec<u32>,
    lo: DVec3,
    hi: DVec3,
    /// The group's first polygon's reflectance and exitance.
    reflectance: [f64; 3],
    exitance: [f64; 3],
    triangles: usize,
}

/// Node `n`'s elements, grouped by texture (untextured first), in the
/// node's frame (`to_local`).
fn node_geometry(
    scene: &Scene,
    mesh: &Mesh,
    radiosity: &[[f64; 3]],
    n: usize,
    to_local: DMat4,
    origin: DVec3,
    scale: f64,
) -> Vec<NodeGeometry> {
    let mut groups: Vec<NodeGeometry> = Vec::new();
    for (e, b) in mesh.elements.iter().zip(radiosity) {
        let poly = &mesh.polygons[e.polygon as usize];
        if poly.node != n {
            continue;
        }
        let map = scene
            .polygons
            .get(e.polygon as usize)
            .and_then(|p| p.texture.as_ref());
        let key = map.map(|m| m.texture.index);
        let g = match groups
            .iter()
            .position(|g| g.texture.as_ref().map(|t| t.index) == key)
        {
            Some(k) => &mut groups[k],
            None => {
                groups.push(NodeGeometry {
                    texture: map.map(|m| m.texture.clone()),
                    pos: Vec::new(),
                    col: Vec::new(),
                    uv: Vec::new(),
                    idx: Vec::new(),
                    lo: DVec3::splat(f64::INFINITY),
                    hi: DVec3::splat(f64::NEG_INFINITY),
                    reflectance: poly.reflectance,
                    exitance: poly.exitance,
                    triangles: 0,
                });
                groups.last_mut().expect("just pushed")
            }
        };
        let colour = baked_value(mesh, e, b)
            .map(|x| ((x / std::f64::consts::PI * scale).clamp(0.0, 1.0)) as f32);
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
            if let Some(m) = map {
                g.uv.extend(m.uv(*c).to_array());
            }
        }
        for k in 1..corners.len() as u32 - 1 {
            g.idx.extend_from_slice(&[base, base + k, base + k + 1]);
            g.triangles += 1;
        }
    }
    groups.sort_by_key(|g| g.texture.as_ref().map(|t| t.index));
    groups
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
    let glb = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("glb"));
    let (doc, bytes, triangles) = if glb {
        let (doc, bin, triangles) = bake_parts(scene, mesh, radiosity, scale);
        let bytes = crate::scene::glb_from(&doc, bin).unwrap_or_default();
        (doc, bytes, triangles)
    } else {
        let (doc, triangles) = bake(scene, mesh, radiosity, scale);
        let bytes = serde_json::to_vec_pretty(&doc).unwrap_or_default();
        (doc, bytes, triangles)
    };
    crate::output::write_atomic(path, &bytes)?;
    Ok(Baked {
        path: path.display().to_string(),
        scale,
        nodes: doc["nodes"].as_array().map_or(0, Vec::len) - usize::from(scene.camera.is_some()),
        triangles,
    })
}
