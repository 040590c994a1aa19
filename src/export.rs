//! The scene as the independent path tracer (`scripts/reference.py`) reads
//! it: per glTF node its world-space triangles, reflectance, emission and
//! area (a textured node also its image, factor and wrap modes), the camera,
//! the lights and the sky (`radiosity scene NAME --nodes FILE`).

use crate::output::{self, OutputError};
use crate::scene::Scene;
use std::path::Path;

/// Why the scene could not be written for the path tracer.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The path tracer takes one material per node.
    #[error(
        "node '{node}' mixes textured and other materials: the path tracer takes one per node"
    )]
    MixedMaterials {
        /// The node's name.
        node: String,
    },
    /// A file could not be written.
    #[error(transparent)]
    Write(#[from] OutputError),
}

/// Writes the scene as JSON for the path tracer: per node, world-space
/// triangles, reflectance, emitted radiance, area; a textured node also its
/// texture (the image written beside `path`, its factor and wrap modes) and
/// each triangle's texture coordinates.
pub fn write_nodes(scene: &Scene, path: &Path) -> Result<(), ExportError> {
    let mut nodes: Vec<serde_json::Value> = Vec::new();
    let mut written = std::collections::HashMap::new();
    for (i, name) in scene.nodes.iter().enumerate() {
        let polys: Vec<_> = scene.polygons.iter().filter(|p| p.node == i).collect();
        let map = one_map(&polys, |p| p.texture.as_ref(), name)?;
        let emissive = one_map(&polys, |p| p.emissive.as_ref(), name)?;
        let (mut tris, mut uvs, mut emissive_uvs) = (Vec::new(), Vec::new(), Vec::new());
        for p in &polys {
            for k in 1..p.vertices.len() - 1 {
                let t = [p.vertices[0], p.vertices[k], p.vertices[k + 1]];
                tris.push(t.map(|v| v.to_array()));
                if let Some(m) = &p.texture {
                    uvs.push(t.map(|v| m.uv(v).to_array()));
                }
                if let Some(m) = &p.emissive {
                    emissive_uvs.push(t.map(|v| m.uv(v).to_array()));
                }
            }
        }
        let (refl, mut emit) = polys
            .first()
            .map_or(([0.0; 3], [0.0; 3]), |p| (p.reflectance, p.emission));
        if emissive.is_some() {
            // The node's mean emission (its polygons' differ).
            let area: f32 = polys.iter().map(|p| p.area()).sum();
            emit = [0, 1, 2].map(|c| {
                polys.iter().map(|p| p.emission[c] * p.area()).sum::<f32>() / area.max(1e-30)
            });
        }
        let mut node = serde_json::json!({
            "name": name,
            "triangles": tris,
            "reflectance": refl,
            "emission": emit,
            "area": polys.iter().map(|p| p.area() as f64).sum::<f64>(),
        });
        if let Some(m) = map {
            node["texture"] = texture_json(m, path, &mut written)?;
            node["uvs"] = serde_json::json!(uvs);
        }
        if let Some(m) = emissive {
            node["emissive_texture"] = texture_json(m, path, &mut written)?;
            node["emissive_uvs"] = serde_json::json!(emissive_uvs);
        }
        nodes.push(node);
    }
    // The camera the render uses (the file's first, or the default), for
    // path-traced images.
    let cam = scene.camera.unwrap_or_else(|| scene.default_camera());
    let camera = serde_json::json!({
        "position": cam.position.to_array(),
        "forward": (cam.rotation * -glam::Vec3::Z).to_array(),
        "up": (cam.rotation * glam::Vec3::Y).to_array(),
        "yfov_degrees": cam.yfov.to_degrees(),
        "aspect": cam.aspect,
    });
    // Lights as the report gives them (reference.py hands them to Mitsuba).
    // A sun-sky's sun is Mitsuba's sunsky's own (below).
    let lights: Vec<crate::report::LightSummary> = scene
        .lights
        .iter()
        .filter(|l| scene.sun_sky.is_none() || l.name != crate::scene::sunsky::SUN_NAME)
        .map(crate::report::LightSummary::of)
        .collect();
    let sky_map = sky_map_json(scene);
    output::write_json(
        path,
        &serde_json::json!({ "nodes": nodes, "camera": camera, "lights": lights, "sky": scene.sky, "sky_map": sky_map }),
    )?;
    Ok(())
}

/// The map as Mitsuba's envmap takes it (file, turn about +Y, scale), or
/// the sun-sky as its sunsky does (direction, turbidity, albedo, scale).
fn sky_map_json(scene: &Scene) -> Option<serde_json::Value> {
    scene.sky_map.as_ref().map(|m| match scene.sun_sky {
        Some(s) => serde_json::json!({ "sun_sky": {
            "toward": s.toward(), "turbidity": s.turbidity,
            "albedo": crate::scene::sunsky::ALBEDO,
            "scale": crate::scene::sunsky::MITSUBA_UNIT * m.strength } }),
        None => {
            let path = std::fs::canonicalize(&m.path).unwrap_or_else(|_| m.path.clone().into());
            serde_json::json!({ "path": path, "rotation_degrees": m.rotation, "strength": m.strength })
        }
    })
}

/// The one texture map (`map` of each polygon) the polygons of node `name`
/// share: `None` where none has one; an error where they differ in texture
/// or factor, or only some have one (the path tracer takes one material a
/// node).
fn one_map<'a>(
    polys: &[&'a crate::scene::Polygon],
    map: impl Fn(&'a crate::scene::Polygon) -> Option<&'a crate::scene::texture::TexMap>,
    name: &str,
) -> Result<Option<&'a crate::scene::texture::TexMap>, ExportError> {
    let Some(m) = polys.iter().find_map(|p| map(p)) else {
        return Ok(None);
    };
    let alike = polys
        .iter()
        .all(|p| map(p).is_some_and(|t| t.texture == m.texture && t.factor == m.factor));
    match alike {
        true => Ok(Some(m)),
        false => Err(ExportError::MixedMaterials {
            node: name.to_string(),
        }),
    }
}

/// A textured node's texture as the path tracer reads it: its image (written
/// beside `path` once, whoever uses it), factor and wrap modes.
fn texture_json(
    m: &crate::scene::texture::TexMap,
    path: &Path,
    written: &mut std::collections::HashMap<usize, String>,
) -> Result<serde_json::Value, ExportError> {
    let t = &m.texture;
    let file = match written.get(&t.index) {
        Some(f) => f.clone(),
        None => {
            let ext = if t.encoded.1 == "image/jpeg" {
                "jpg"
            } else {
                "png"
            };
            let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("nodes");
            let file = format!("{stem}.texture{}.{ext}", t.index);
            let dir = path.parent().unwrap_or(Path::new("."));
            output::write_atomic(&dir.join(&file), &t.encoded.0)?;
            written.insert(t.index, file.clone());
            file
        }
    };
    let wrap = t.texture.wrap.map(|w| match w {
        crate::scene::texture::Wrap::Repeat => "repeat",
        crate::scene::texture::Wrap::Mirror => "mirror",
        crate::scene::texture::Wrap::Clamp => "clamp",
    });
    Ok(serde_json::json!({"image": file, "factor": m.factor, "wrap": wrap}))
}
