//! glTF 2.0 loading (DESIGN.md section 6).

use super::texture::{TexMap, Texture, TextureRef, Wrap};
use super::{Camera, Light, LightKind, Polygon, Scene, SceneError, Subdivision};
use glam::{DMat4, DVec3, Vec2, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod materials;
use materials::{Material, MaterialTexture};

/// Cosine of the largest fold (0.8 degrees) between two triangles merged into
/// a quad: the Cornell box's measured red wall is folded by 0.4 degrees.
const COPLANAR_COS: f32 = 0.9999;

/// What glTF's implicit reflectance of 1 (a material with no
/// baseColorFactor and no texture) is clamped to, with a warning.
pub const CLAMPED: f32 = 0.95;

/// Loads a `.gltf` or `.glb` file.
pub fn load(path: &Path) -> Result<Scene, SceneError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| SceneError::Read {
        path: name.clone(),
        source,
    })?;
    load_with_base(&bytes, &name, path.parent())
}

/// Loads glTF from memory; `name` is used in messages. External buffer files
/// cannot be resolved (embedded data URIs and GLB blobs can).
pub fn load_slice(bytes: &[u8], name: &str) -> Result<Scene, SceneError> {
    load_with_base(bytes, name, None)
}

/// gltf-json 1.4's validator indexes `accessors` with a primitive's POSITION
/// index before checking it, and panics on a file where it is out of range
/// (found by `radiosity-lab fuzz`): check every primitive's accessor indices first.
fn check_primitive_indices(bytes: &[u8], name: &str) -> Result<(), SceneError> {
    // Not a readable GLB: the full parse below says why.
    let Some(json) = json_chunk(bytes) else {
        return Ok(());
    };
    let Ok(root) = gltf::json::Root::from_slice(&json) else {
        return Ok(());
    };
    let n = root.accessors.len();
    for (mi, mesh) in root.meshes.iter().enumerate() {
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            let attributes = prim
                .attributes
                .iter()
                .map(|(s, i)| (format!("attributes {s:?}"), i));
            for (what, index) in
                attributes.chain(prim.indices.iter().map(|i| ("indices".into(), i)))
            {
                if index.value() >= n {
                    return Err(SceneError::Parse {
                        path: name.to_string(),
                        message: format!(
                            "invalid glTF: meshes[{mi}].primitives[{pi}] {what}: accessor {} does not exist ({n} accessors)",
                            index.value()
                        ),
                    });
                }
            }
        }
    }
    Ok(())
}

/// The JSON of glTF (or GLB) `bytes`; `None` for a GLB that does not read.
fn json_chunk(bytes: &[u8]) -> Option<std::borrow::Cow<'_, [u8]>> {
    if bytes.starts_with(b"glTF") {
        gltf::Glb::from_slice(bytes).ok().map(|glb| glb.json)
    } else {
        Some(std::borrow::Cow::Borrowed(bytes))
    }
}

fn load_with_base(bytes: &[u8], name: &str, base: Option<&Path>) -> Result<Scene, SceneError> {
    let parse_err = |e: gltf::Error| SceneError::Parse {
        path: name.to_string(),
        message: e.to_string(),
    };
    let mut tolerated = Vec::new();
    let rewritten = super::tolerate::tolerate(bytes, &mut tolerated);
    let bytes = rewritten.as_deref().unwrap_or(bytes);
    check_primitive_indices(bytes, name)?;
    let explicit_base = materials::explicit_base_colours(bytes);
    let gltf = gltf::Gltf::from_slice(bytes).map_err(parse_err)?;
    let base = base.map(|b| {
        if b.as_os_str().is_empty() {
            Path::new(".")
        } else {
            b
        }
    });
    let buffers =
        gltf::import_buffers(&gltf.document, base, gltf.blob.clone()).map_err(parse_err)?;

    let mut loader = Loader {
        path: name.to_string(),
        base: base.map(Path::to_path_buf),
        textures: HashMap::new(),
        buffers: &buffers,
        scene: Scene::default(),
        origin: None,
        camera_at: Vec::new(),
        light_at: Vec::new(),
        explicit_base,
        mask_cuts: crate::scene::mask::cuts_for(masked_triangles(&gltf.document)),
    };
    loader.scene.name = name.to_string();
    loader.scene.warnings = tolerated;
    let doc = &gltf.document;
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().collect(),
        // No scene: treat every node that is nobody's child as a root.
        None => {
            let mut is_child = vec![false; doc.nodes().len()];
            for n in doc.nodes() {
                for c in n.children() {
                    is_child[c.index()] = true;
                }
            }
            doc.nodes().filter(|n| !is_child[n.index()]).collect()
        }
    };
    for node in roots {
        loader.visit(&node, DMat4::IDENTITY, 0)?;
    }
    let origin = loader.origin.unwrap_or(DVec3::ZERO);
    for ((_, cam), at) in loader.scene.cameras.iter_mut().zip(&loader.camera_at) {
        cam.position = (*at - origin).as_vec3();
    }
    for (light, at) in loader.scene.lights.iter_mut().zip(&loader.light_at) {
        light.position = (*at - origin).as_vec3();
    }
    loader.scene.camera = loader.scene.cameras.first().map(|c| c.1);
    let mut scene = loader.scene;
    scene.origin = origin.to_array();
    if scene.polygons.is_empty() {
        return Err(SceneError::NoTriangles {
            path: name.to_string(),
        });
    }
    for w in &scene.warnings {
        log::warn!("{name}: {w}");
    }
    scene.warnings.shrink_to_fit();
    Ok(scene)
}

struct Loader<'a> {
    path: String,
    /// Where relative URIs point (the file's folder).
    base: Option<PathBuf>,
    /// Base-colour textures by glTF texture index (`None`: it did not load).
    textures: HashMap<usize, Option<Arc<TextureRef>>>,
    buffers: &'a [gltf::buffer::Data],
    scene: Scene,
    /// The first vertex's world position: every position is stored relative
    /// to it (computed in f64, then f32).
    origin: Option<DVec3>,
    /// The cameras' world positions (made relative at the end).
    camera_at: Vec<DVec3>,
    /// The lights' world positions (made relative at the end).
    light_at: Vec<DVec3>,
    /// Per material, whether the file writes its baseColorFactor (one it
    /// leaves out reads as glTF's default, 1).
    explicit_base: Vec<bool>,
    /// Pieces along each edge of a masked triangle at most
    /// ([`crate::scene::mask::cuts_for`]).
    mask_cuts: u32,
}

/// About how many triangles the document's masked materials cover (each
/// mesh counted once, however many nodes use it).
fn masked_triangles(doc: &gltf::Document) -> usize {
    doc.meshes()
        .flat_map(|m| m.primitives())
        .filter(|p| p.material().alpha_mode() == gltf::material::AlphaMode::Mask)
        .map(|p| {
            let count = p.indices().or_else(|| p.get(&gltf::Semantic::Positions));
            count.map_or(0, |a| a.count() / 3)
        })
        .sum()
}

/// A triangle's corners and their vertex indices.
type Indexed = ([Vec3; 3], [u32; 3]);

impl Loader<'_> {
    fn visit(&mut self, node: &gltf::Node, parent: DMat4, depth: usize) -> Result<(), SceneError> {
        let name = node
            .name()
            .map(str::to_string)
            .unwrap_or_else(|| format!("node{}", node.index()));
        if depth > 256 {
            return Err(SceneError::Parse {
                path: self.path.clone(),
                message: format!("node '{name}' nests too deeply (a cycle?)"),
            });
        }
        let local = node.transform().matrix().map(|c| c.map(f64::from));
        let world = parent * DMat4::from_cols_array_2d(&local);
        if let Some(cam) = node.camera() {
            if let gltf::camera::Projection::Perspective(p) = cam.projection() {
                let (_, rotation, position) = world.to_scale_rotation_translation();
                self.camera_at.push(position);
                let camera = Camera {
                    position: position.as_vec3(),
                    rotation: rotation.normalize().as_quat(),
                    yfov: p.yfov(),
                    aspect: p.aspect_ratio(),
                    znear: p.znear(),
                };
                let label = cam.name().map_or_else(|| name.clone(), str::to_string);
                self.scene.cameras.push((label, camera));
            }
        }
        if let Some(light) = node.light() {
            self.light(&light, world, &name)?;
        }
        if let Some(mesh) = node.mesh() {
            let subdivision = self.extras(node, &name)?;
            let node_id = self.scene.nodes.len();
            self.scene.nodes.push(name.clone());
            self.scene.node_transforms.push(world.to_cols_array());
            let before = self.scene.polygons.len();
            for prim in mesh.primitives() {
                self.primitive(&prim, world, node_id, &name, subdivision)?;
            }
            if self.scene.polygons.len() == before {
                self.scene.nodes.pop();
                self.scene.node_transforms.pop();
            }
        }
        for child in node.children() {
            self.visit(&child, world, depth + 1)?;
        }
        Ok(())
    }

    /// A `KHR_lights_punctual` light at the node's world transform,
    /// shining along the node's -Z; its intensity times its colour, in
    /// radiometric units (see [`super::light`]).
    fn light(
        &mut self,
        light: &gltf::khr_lights_punctual::Light,
        world: DMat4,
        node: &str,
    ) -> Result<(), SceneError> {
        use gltf::khr_lights_punctual::Kind;
        let name = light
            .name()
            .map_or_else(|| node.to_string(), str::to_string);
        let bad = |message: String| SceneError::BadMaterial {
            path: self.path.clone(),
            node: node.to_string(),
            message: format!("light '{name}': {message}"),
        };
        let (color, intensity) = (light.color(), light.intensity());
        if !(intensity.is_finite() && intensity >= 0.0) {
            return Err(bad(format!(
                "intensity {intensity} must be finite and >= 0"
            )));
        }
        if !color.iter().all(|c| c.is_finite() && *c >= 0.0) {
            return Err(bad(format!("color {color:?} must be finite and >= 0")));
        }
        let kind = match light.kind() {
            Kind::Point => LightKind::Point,
            Kind::Directional => LightKind::Directional,
            Kind::Spot {
                inner_cone_angle,
                outer_cone_angle,
            } => {
                let ok = (0.0..=std::f32::consts::FRAC_PI_2).contains(&outer_cone_angle)
                    && (0.0..outer_cone_angle.max(f32::MIN_POSITIVE)).contains(&inner_cone_angle);
                if !ok {
                    return Err(bad(format!(
                        "spot cone angles inner {inner_cone_angle}, outer {outer_cone_angle}: glTF needs 0 <= inner < outer <= pi/2"
                    )));
                }
                LightKind::Spot {
                    inner: inner_cone_angle,
                    outer: outer_cone_angle,
                }
            }
        };
        let direction = world.transform_vector3(DVec3::NEG_Z);
        if !(direction.is_finite() && direction.length() > 0.0) {
            return Err(bad("its node's transform is degenerate".into()));
        }
        let position = world.transform_point3(DVec3::ZERO);
        if !position.is_finite() {
            return Err(bad("its node's position is not finite".into()));
        }
        self.light_at.push(position);
        self.scene.lights.push(Light {
            name,
            kind,
            position: Vec3::ZERO,
            direction: direction.normalize().as_vec3(),
            intensity: color.map(|c| f64::from(c) * f64::from(intensity)),
        });
        Ok(())
    }

    fn extras(&self, node: &gltf::Node, name: &str) -> Result<Option<Subdivision>, SceneError> {
        let Some(raw) = node.extras() else {
            return Ok(None);
        };
        let bad = |message: String| SceneError::BadExtras {
            path: self.path.clone(),
            node: name.to_string(),
            message,
        };
        let value: serde_json::Value =
            serde_json::from_str(raw.get()).map_err(|e| bad(e.to_string()))?;
        let Some(r) = value.get("radiosity") else {
            return Ok(None);
        };
        let pair = |key: &str, default: [u32; 2]| -> Result<[u32; 2], SceneError> {
            match r.get(key) {
                None => Ok(default),
                Some(v) => {
                    let p: [u32; 2] = serde_json::from_value(v.clone())
                        .map_err(|_| bad(format!("'{key}' must be two positive integers")))?;
                    if p[0] == 0 || p[1] == 0 || p[0] > 4096 || p[1] > 4096 {
                        return Err(bad(format!("'{key}' counts must be 1..=4096")));
                    }
                    Ok(p)
                }
            }
        };
        Ok(Some(Subdivision {
            patches: pair("patches", [1, 1])?,
            elements: pair("elements", [1, 1])?,
        }))
    }

    /// The gltf crate's readers assume the spec's accessor types (and hit
    /// `unreachable!` otherwise): checks them first.
    fn check_accessors(&self, prim: &gltf::Primitive, name: &str) -> Result<(), SceneError> {
        use gltf::accessor::{DataType, Dimensions};
        let bad_type = |what: &str, acc: &gltf::Accessor, want: &str| SceneError::Parse {
            path: self.path.clone(),
            message: format!(
                "node '{name}': {what} accessor {} is {:?} {:?}; the glTF spec requires {want}",
                acc.index(),
                acc.dimensions(),
                acc.data_type()
            ),
        };
        if let Some(acc) = prim.get(&gltf::Semantic::Positions) {
            if acc.data_type() != DataType::F32 || acc.dimensions() != Dimensions::Vec3 {
                return Err(bad_type("POSITION", &acc, "VEC3 of FLOAT"));
            }
        }
        if let Some(acc) = prim.indices() {
            let unsigned = matches!(
                acc.data_type(),
                DataType::U8 | DataType::U16 | DataType::U32
            );
            if !unsigned || acc.dimensions() != Dimensions::Scalar {
                return Err(bad_type("index", &acc, "SCALAR of unsigned integers"));
            }
        }
        Ok(())
    }

    /// The primitive's triangles (wound for the node's transform), degenerate
    /// ones skipped with a warning.
    fn triangles(
        &mut self,
        positions: &[Vec3],
        indices: &[u32],
        flip: bool,
        name: &str,
    ) -> Result<Vec<Indexed>, SceneError> {
        let mut tris = Vec::with_capacity(indices.len() / 3);
        let mut degenerate = 0usize;
        for (k, t) in indices.chunks_exact(3).enumerate() {
            let get = |i: u32| positions.get(i as usize).copied();
            let (Some(a), Some(b), Some(c)) = (get(t[0]), get(t[1]), get(t[2])) else {
                return Err(SceneError::Parse {
                    path: self.path.clone(),
                    message: format!(
                        "node '{name}': triangle {k} indexes past the end of its positions"
                    ),
                });
            };
            let (tri, idx) = if flip {
                ([a, c, b], [t[0], t[2], t[1]])
            } else {
                ([a, b, c], [t[0], t[1], t[2]])
            };
            let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
            let scale = (tri[1] - tri[0])
                .length_squared()
                .max((tri[2] - tri[0]).length_squared());
            if n.length() <= 1e-7 * scale || scale == 0.0 {
                degenerate += 1;
                continue;
            }
            tris.push((tri, idx));
        }
        if degenerate > 0 {
            self.scene.warnings.push(format!(
                "node '{name}': {degenerate} degenerate triangle(s) skipped"
            ));
        }
        Ok(tris)
    }

    /// Adds the polygons of `tris` (pairs merged into quads where they make
    /// one), both sides of a double-sided material. A polygon with an
    /// emissive texture emits the texture's mean over it.
    fn add_polygons(
        &mut self,
        tris: &[[Vec3; 3]],
        maps: &[Maps],
        mat: &Material,
        node: usize,
        subdivision: Option<Subdivision>,
    ) {
        let pieces = match mat.mask {
            Some(mask) => cut_out(tris, maps, mask, self.mask_cuts),
            None => merge_quads(tris, maps),
        };
        for (verts, (texture, emissive)) in pieces {
            let normal = polygon_normal(&verts);
            let emission = emissive
                .as_ref()
                .map_or(mat.emission, |m| m.mean_over(&verts));
            let poly = Polygon {
                vertices: verts,
                normal,
                reflectance: mat.reflectance,
                emission,
                node,
                subdivision,
                back_side: false,
                parent: None,
                texture,
                emissive,
            };
            if mat.double_sided {
                let mut back = poly.clone();
                back.vertices.reverse();
                back.normal = -normal;
                back.back_side = true;
                self.scene.polygons.push(poly);
                self.scene.polygons.push(back);
            } else {
                self.scene.polygons.push(poly);
            }
        }
    }

    /// Each triangle's map onto `texture` (`None` for all without one; a
    /// primitive without the coordinates its texture needs falls back to
    /// the material's mean, with a warning).
    fn texture_maps(
        &mut self,
        uvs: &[[f32; 2]],
        tris: &[Indexed],
        texture: Option<&MaterialTexture>,
        name: &str,
    ) -> Vec<Option<TexMap>> {
        let Some(t) = texture else {
            return vec![None; tris.len()];
        };
        let mut missing = 0usize;
        let maps = tris
            .iter()
            .map(|(p, idx)| {
                let uv = idx.map(|i| uvs.get(i as usize).copied());
                let [Some(a), Some(b), Some(c)] = uv else {
                    missing += 1;
                    return None;
                };
                TexMap::of_triangle(
                    *p,
                    [t.apply(a), t.apply(b), t.apply(c)],
                    t.texture.clone(),
                    t.factor,
                )
            })
            .collect();
        if missing > 0 {
            self.scene.warnings.push(format!(
                "node '{name}': {missing} triangle(s) lack TEXCOORD_{} for their texture: their material's mean stands in",
                t.set
            ));
        }
        maps
    }

    fn primitive(
        &mut self,
        prim: &gltf::Primitive,
        world: DMat4,
        node: usize,
        name: &str,
        subdivision: Option<Subdivision>,
    ) -> Result<(), SceneError> {
        if prim.mode() != gltf::mesh::Mode::Triangles {
            self.scene.warnings.push(format!(
                "node '{name}': primitive mode {:?} skipped (only triangles are rendered)",
                prim.mode()
            ));
            return Ok(());
        }
        self.check_accessors(prim, name)?;
        let reader = prim.reader(|b| self.buffers.get(b.index()).map(|d| d.0.as_slice()));
        let Some(positions) = reader.read_positions() else {
            if let Some(acc) = prim.get(&gltf::Semantic::Positions) {
                // It has positions the buffers cannot hold (e.g. a count past
                // the buffer's end): rendering without it would be wrong.
                return Err(SceneError::Parse {
                    path: self.path.clone(),
                    message: format!(
                        "node '{name}': POSITION accessor {} ({} elements) does not fit its buffer",
                        acc.index(),
                        acc.count()
                    ),
                });
            }
            self.scene.warnings.push(format!(
                "node '{name}': primitive without positions skipped"
            ));
            return Ok(());
        };
        let positions: Vec<Vec3> = positions
            .map(|p| {
                let w = world.transform_point3(Vec3::from(p).as_dvec3());
                (w - *self.origin.get_or_insert(w)).as_vec3()
            })
            .collect();
        if positions.iter().any(|p| !p.is_finite()) {
            return Err(SceneError::NonFinite {
                path: self.path.clone(),
                node: name.to_string(),
            });
        }
        let indices: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..positions.len() as u32).collect(),
        };
        // A mirroring transform flips the winding (glTF spec, 3.7.4).
        let flip = world.determinant() < 0.0;
        let mut clamped = Vec::new();
        let mat = self.material(prim, name, &mut clamped)?;
        for w in clamped {
            if !self.scene.warnings.contains(&w) {
                self.scene.warnings.push(w);
            }
        }
        let tris = self.triangles(&positions, &indices, flip, name)?;
        let uvs = |t: Option<&MaterialTexture>| -> Vec<[f32; 2]> {
            t.and_then(|t| reader.read_tex_coords(t.set))
                .map(|c| c.into_f32().collect())
                .unwrap_or_default()
        };
        let (base_uvs, emissive_uvs) = (uvs(mat.texture.as_ref()), uvs(mat.emissive.as_ref()));
        let base = self.texture_maps(&base_uvs, &tris, mat.texture.as_ref(), name);
        let emissive = self.texture_maps(&emissive_uvs, &tris, mat.emissive.as_ref(), name);
        let maps: Vec<Maps> = base.into_iter().zip(emissive).collect();
        let tris: Vec<[Vec3; 3]> = tris.into_iter().map(|t| t.0).collect();
        self.add_polygons(&tris, &maps, &mat, node, subdivision);
        Ok(())
    }
}

/// Unit normal of a counter-clockwise triangle or planar quad.
pub fn polygon_normal(v: &[Vec3]) -> Vec3 {
    match v.len() {
        3 => (v[1] - v[0]).cross(v[2] - v[0]).normalize(),
        _ => (v[2] - v[0]).cross(v[3] - v[1]).normalize(),
    }
}

/// The pieces of `tris` that a material's `mask` keeps (see
/// [`crate::scene::mask`]), each with its triangle's maps.
fn cut_out(
    tris: &[[Vec3; 3]],
    maps: &[Maps],
    mask: crate::scene::mask::Mask,
    most: u32,
) -> Vec<(Vec<Vec3>, Maps)> {
    let mut out = Vec::with_capacity(tris.len());
    for (i, t) in tris.iter().enumerate() {
        let map = maps.get(i).cloned().unwrap_or_default();
        for piece in crate::scene::mask::cut(*t, map.0.as_ref(), mask, most) {
            out.push((piece, map.clone()));
        }
    }
    out
}

/// A triangle's maps onto its base-colour and emissive textures.
type Maps = (Option<TexMap>, Option<TexMap>);

/// Merges consecutive triangles that share an edge, are coplanar and together
/// form a convex quad; everything else stays a triangle.
/// A textured pair merges only where both triangles map onto their
/// textures alike (so the quad's one affine map is exact on both).
fn merge_quads(tris: &[[Vec3; 3]], maps: &[Maps]) -> Vec<(Vec<Vec3>, Maps)> {
    let mut out = Vec::with_capacity(tris.len());
    let mut i = 0;
    let map = |i: usize| maps.get(i).cloned().unwrap_or_default();
    let agree = |a: &Option<TexMap>, b: &Option<TexMap>, q: &[Vec3]| match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => a.agrees(b, q),
        _ => false,
    };
    while i < tris.len() {
        if i + 1 < tris.len() {
            if let Some(q) = try_merge(&tris[i], &tris[i + 1]) {
                let (a, b) = (map(i), map(i + 1));
                if agree(&a.0, &b.0, &q) && agree(&a.1, &b.1, &q) {
                    out.push((q.to_vec(), a));
                    i += 2;
                    continue;
                }
            }
        }
        out.push((tris[i].to_vec(), map(i)));
        i += 1;
    }
    out
}

/// `uri` with its %XX escapes decoded (glTF URIs are percent-encoded).
fn percent_decode(uri: &str) -> String {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            if let Ok(b) = u8::from_str_radix(&uri[i + 1..i + 3], 16) {
                out.push(b);
                i += 3;
                continue;
            }
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn try_merge(a: &[Vec3; 3], b: &[Vec3; 3]) -> Option<[Vec3; 4]> {
    let na = polygon_normal(a);
    let nb = polygon_normal(b);
    if na.dot(nb) < COPLANAR_COS {
        return None;
    }
    // Find the edge (a[i], a[i+1]) that b contains reversed, and b's third vertex.
    for i in 0..3 {
        let (p, q) = (a[i], a[(i + 1) % 3]);
        for j in 0..3 {
            if b[j] == q && b[(j + 1) % 3] == p {
                let x = b[(j + 2) % 3];
                let r = a[(i + 2) % 3];
                // Quad in counter-clockwise order: r, p, x, q.
                let quad = [r, p, x, q];
                let convex = (0..4).all(|k| {
                    let e0 = quad[(k + 1) % 4] - quad[k];
                    let e1 = quad[(k + 2) % 4] - quad[(k + 1) % 4];
                    e0.cross(e1).dot(na) > 0.0
                });
                return convex.then_some(quad);
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_triangles_of_a_square_merge() {
        let (a, b, c, d) = (Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y);
        let q = try_merge(&[a, b, c], &[a, c, d]).expect("merges");
        assert!(polygon_normal(&q).dot(Vec3::Z) > 0.999);
        let area = 0.5 * (q[2] - q[0]).cross(q[3] - q[1]).length();
        assert!((area - 1.0).abs() < 1e-6);
    }

    #[test]
    fn concave_or_bent_pairs_stay_triangles() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        // Folded: second triangle out of plane.
        assert!(try_merge(&[a, b, c], &[c, b, Vec3::new(1.0, 1.0, 1.0)]).is_none());
        // Concave (dart) shape.
        assert!(try_merge(&[a, b, c], &[c, b, Vec3::new(0.2, 0.2, 0.0)]).is_none());
    }
}
