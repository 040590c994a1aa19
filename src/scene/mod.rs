//! The scene as the solver sees it: planar polygons (triangles and quads) with
//! diffuse reflectance and emitted radiance, grouped by the glTF node they came
//! from, plus an optional camera.
//!
//! Loading ([`load`]) follows the glTF conventions of DESIGN.md section 6.

mod builtin;
pub mod contact;
pub mod family;
mod gltf_load;
mod gltf_write;
pub mod light;
pub mod mask;
pub mod sky;
pub mod sunsky;
pub mod texture;
pub mod tolerate;

pub use builtin::{builtin_gltf, builtin_names};
pub use gltf_load::{load, load_slice, polygon_normal};
pub use gltf_write::{axis_rect, glb_from, to_glb, write_gltf, GltfSurface};
pub use light::{parse_sky, parse_sun, Light, LightKind, LUMENS_PER_WATT};
pub use sky::{Background, SkyMap, SkyMapError};
pub use texture::{TexMap, Texture};

use glam::{Quat, Vec3};

/// A planar polygon: a triangle or a convex quad, counter-clockwise seen from its front.
#[derive(Clone, Debug)]
pub struct Polygon {
    /// 3 or 4 vertices, counter-clockwise around `normal`.
    pub vertices: Vec<Vec3>,
    /// Unit normal of the front side.
    pub normal: Vec3,
    /// Diffuse reflectance rho per RGB channel.
    pub reflectance: [f32; 3],
    /// Emitted radiance L_e per RGB channel (W sr^-1 m^-2); exitance is pi * L_e.
    pub emission: [f32; 3],
    /// Index into [`Scene::nodes`] of the glTF node this polygon belongs to.
    pub node: usize,
    /// Subdivision fixed by the node's `extras.radiosity`, if any.
    pub subdivision: Option<Subdivision>,
    /// Whether this is the back side of a double-sided surface (the
    /// reversed copy the loader adds): reported apart from the front.
    pub back_side: bool,
    /// The polygon this one was split from where others stand on it (see
    /// [`contact`]), as an index into the list before the split; `None`
    /// when it was not split. Subdivision sizes come from the whole.
    pub parent: Option<u32>,
    /// How a base-colour texture maps onto it, if its material has one
    /// (then `reflectance` is the texture's mean times the factor, and
    /// each element gets its own mean: see [`texture`]).
    pub texture: Option<TexMap>,
    /// How an emissive texture maps onto it, if its material has one (its
    /// factor is emissiveFactor times the emissive strength; `emission` is
    /// then the texture's mean over the polygon, and each element emits
    /// its own mean: see `Mesh::element_exitance`).
    pub emissive: Option<TexMap>,
}

impl Polygon {
    /// Area of the polygon.
    pub fn area(&self) -> f32 {
        let v = &self.vertices;
        match v.len() {
            3 => 0.5 * (v[1] - v[0]).cross(v[2] - v[0]).length(),
            _ => 0.5 * (v[2] - v[0]).cross(v[3] - v[1]).length(),
        }
    }

    /// Axis-aligned bounds (min, max) of its vertices.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let lo = self.vertices.iter().fold(Vec3::INFINITY, |m, v| m.min(*v));
        let hi = self
            .vertices
            .iter()
            .fold(Vec3::NEG_INFINITY, |m, v| m.max(*v));
        (lo, hi)
    }

    /// Vertex average (equal to the centroid for parallelograms and triangles).
    pub fn centre(&self) -> Vec3 {
        self.vertices.iter().copied().sum::<Vec3>() / self.vertices.len() as f32
    }

    /// A square of half-side `half` about `centre` spanned by the unit
    /// vectors `a` and `b`, facing `a x b` (for tests and generated scenes).
    pub fn square(
        centre: Vec3,
        half: f32,
        a: Vec3,
        b: Vec3,
        reflectance: [f32; 3],
        emission: [f32; 3],
    ) -> Self {
        let (a, b) = (a * half, b * half);
        Polygon {
            vertices: vec![
                centre - a - b,
                centre + a - b,
                centre + a + b,
                centre - a + b,
            ],
            normal: a.cross(b).normalize(),
            reflectance,
            emission,
            node: 0,
            subdivision: None,
            back_side: false,
            parent: None,
            texture: None,
            emissive: None,
        }
    }

    /// Whether the polygon emits light.
    pub fn is_emitter(&self) -> bool {
        self.emission.iter().any(|&e| e > 0.0)
    }
}

/// A closed unit cube from the origin as six inward-facing squares of
/// reflectance `rho` (for tests).
#[cfg(test)]
pub(crate) fn inward_unit_cube(rho: f32) -> Vec<Polygon> {
    let s = |c: Vec3, u: Vec3, v: Vec3| Polygon::square(c, 0.5, u, v, [rho; 3], [0.0; 3]);
    vec![
        s(Vec3::new(0.5, 0.5, 0.0), Vec3::X, Vec3::Y),
        s(Vec3::new(0.5, 0.5, 1.0), Vec3::Y, Vec3::X),
        s(Vec3::new(0.5, 0.0, 0.5), Vec3::Z, Vec3::X),
        s(Vec3::new(0.5, 1.0, 0.5), Vec3::X, Vec3::Z),
        s(Vec3::new(0.0, 0.5, 0.5), Vec3::Y, Vec3::Z),
        s(Vec3::new(1.0, 0.5, 0.5), Vec3::Z, Vec3::Y),
    ]
}

/// A fixed subdivision: patches per polygon and elements per patch, along the
/// polygon's first and second edge directions (triangles use the first count).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Subdivision {
    /// Patches along u and v.
    pub patches: [u32; 2],
    /// Elements per patch along u and v.
    pub elements: [u32; 2],
}

/// A perspective camera (glTF conventions: looks down its local -Z, +Y up).
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    /// Eye position in world space.
    pub position: Vec3,
    /// Camera-to-world rotation.
    pub rotation: Quat,
    /// Vertical field of view in radians.
    pub yfov: f32,
    /// Width / height, if the file fixes it.
    pub aspect: Option<f32>,
    /// Near plane distance.
    pub znear: f32,
}

/// A loaded scene.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// Where it came from (a path or a built-in name).
    pub name: String,
    /// Names of the glTF nodes that hold surfaces, indexed by [`Polygon::node`].
    pub nodes: Vec<String>,
    /// Each of those nodes' world transform (column-major, f64, absolute
    /// world coordinates: `origin` is not subtracted), for writing them back.
    pub node_transforms: Vec<[f64; 16]>,
    /// Every polygon, both sides of double-sided surfaces included.
    pub polygons: Vec<Polygon>,
    /// The camera the image is made from: the first perspective camera, if
    /// any (or the one [`Scene::use_camera`] picked).
    pub camera: Option<Camera>,
    /// Every perspective camera, with its name (the camera's, else its node's).
    pub cameras: Vec<(String, Camera)>,
    /// Non-fatal problems met while loading (e.g. degenerate triangles skipped).
    pub warnings: Vec<String>,
    /// World position (metres, f64) of the point all positions here are
    /// relative to: the loader works in f64 and keeps f32 coordinates near
    /// zero, so a scene far from the world origin loses no precision.
    pub origin: [f64; 3],
    /// Lights that are not surfaces: the file's `KHR_lights_punctual` and a
    /// `--sun` (see [`light`]).
    pub lights: Vec<Light>,
    /// A uniform sky's radiance (W sr^-1 m^-2 per channel) seen by every
    /// direction that leaves the scene (`--sky`).
    pub sky: Option<[f64; 3]>,
    /// An environment map seen along every direction that leaves the scene
    /// (`--sky-map`), added to the uniform sky.
    pub sky_map: Option<std::sync::Arc<SkyMap>>,
    /// The sun and sky `sky_map` and the light named
    /// [`sunsky::SUN_NAME`] were made from (`--sun-sky`), if so.
    pub sun_sky: Option<sunsky::SunSky>,
}

impl Scene {
    /// What a ray that leaves the scene sees: the uniform sky and the map.
    pub fn background(&self) -> Background<'_> {
        Background {
            uniform: self.sky.unwrap_or([0.0; 3]),
            map: self.sky_map.as_deref(),
        }
    }

    /// Axis-aligned bounds (min, max) of all vertices.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.polygons
            .iter()
            .map(Polygon::bounds)
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), (a, b)| {
                (lo.min(a), hi.max(b))
            })
    }

    /// Length of the bounding-box diagonal.
    pub fn extent(&self) -> f32 {
        let (lo, hi) = self.bounds();
        (hi - lo).length()
    }

    /// Whether anything lights the scene: an emitting surface, a light or
    /// a sky brighter than 0. The error says how to light it.
    pub fn check_lit(&self) -> Result<(), SceneError> {
        let lights = self
            .lights
            .iter()
            .any(|l| l.intensity.iter().any(|&i| i > 0.0));
        let sky = !self.background().is_dark();
        if lights || sky || self.polygons.iter().any(Polygon::is_emitter) {
            Ok(())
        } else {
            Err(SceneError::NoEmitter {
                path: self.name.clone(),
            })
        }
    }

    /// Reads the file's light units as photometric (`--photometric`): a
    /// point or spot light's intensity as candela, a directional light's as
    /// lux, emission as nits, each divided by [`LUMENS_PER_WATT`] into the
    /// radiometric units the solver uses. Lights added by `--sun` and
    /// `--sky` are radiometric: add them after this.
    pub fn read_photometric(&mut self) {
        let k = 1.0 / LUMENS_PER_WATT;
        for l in &mut self.lights {
            l.intensity = l.intensity.map(|i| i * k);
        }
        for p in &mut self.polygons {
            p.emission = p.emission.map(|e| (f64::from(e) * k) as f32);
        }
    }

    /// Makes the camera named `name` the view; the error lists the names.
    pub fn use_camera(&mut self, name: &str) -> Result<(), SceneError> {
        match self.cameras.iter().find(|(n, _)| n == name) {
            Some((_, c)) => {
                self.camera = Some(*c);
                Ok(())
            }
            None => Err(SceneError::NoCamera {
                path: self.name.clone(),
                camera: name.to_string(),
                names: self
                    .cameras
                    .iter()
                    .map(|(n, _)| format!("'{n}'"))
                    .collect::<Vec<_>>()
                    .join(", "),
            }),
        }
    }

    /// A camera that frames the whole scene from +Z, for scenes without one.
    pub fn default_camera(&self) -> Camera {
        let (lo, hi) = self.bounds();
        let centre = 0.5 * (lo + hi);
        let radius = 0.5 * (hi - lo).length().max(1e-3);
        let yfov = 0.8f32;
        let distance = radius / (0.5 * yfov).sin();
        Camera {
            position: centre + Vec3::Z * distance,
            rotation: Quat::IDENTITY,
            yfov,
            aspect: None,
            znear: (distance - radius).max(distance * 1e-3),
        }
    }
}

/// Why a scene could not be loaded. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The sky map (`--sky-map`) could not be used.
    #[error(transparent)]
    SkyMap(#[from] SkyMapError),
    /// The file could not be read.
    #[error("cannot read scene '{path}': {source}")]
    Read {
        /// The scene path.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not valid glTF (or a buffer it references is missing or short).
    #[error("scene '{path}' is not valid glTF: {message}")]
    Parse {
        /// The scene path.
        path: String,
        /// What the parser said.
        message: String,
    },
    /// No usable triangle in the whole scene.
    #[error("scene '{path}' has no triangles to render")]
    NoTriangles {
        /// The scene path.
        path: String,
    },
    /// Nothing emits light, so the solution would be black.
    #[error("scene '{path}' has no emitter: give some material an emissiveFactor, add a KHR_lights_punctual light, or light it with --sun / --sky")]
    NoEmitter {
        /// The scene path.
        path: String,
    },
    /// A vertex (after the node transforms) is NaN or infinite.
    #[error("scene '{path}', node '{node}': non-finite vertex coordinates")]
    NonFinite {
        /// The scene path.
        path: String,
        /// The node holding the vertex.
        node: String,
    },
    /// A node's `extras.radiosity` could not be understood.
    #[error("scene '{path}', node '{node}': bad extras.radiosity: {message}")]
    BadExtras {
        /// The scene path.
        path: String,
        /// The node.
        node: String,
        /// What is wrong.
        message: String,
    },
    /// A material value outside the glTF specification's range.
    #[error("scene '{path}', node '{node}': {message}")]
    BadMaterial {
        /// The scene path.
        path: String,
        /// The node.
        node: String,
        /// What is wrong.
        message: String,
    },
    /// `--camera NAME` names no camera of the file.
    #[error("scene '{path}' has no perspective camera '{camera}' (its cameras: {names})")]
    NoCamera {
        /// The scene path.
        path: String,
        /// The name asked for.
        camera: String,
        /// The cameras it has.
        names: String,
    },
    /// A scene name that is neither a file nor a built-in scene.
    #[error("no scene file '{0}' and no built-in scene of that name (built-ins: {1})")]
    Unknown(String, String),
}

/// Loads a scene from a glTF/GLB path or a built-in scene name.
///
/// Polygons that others stand on are split along the contacts
/// ([`contact::split_at_contacts`]); [`open_as_authored`] leaves them whole.
pub fn open(name_or_path: &str) -> Result<Scene, SceneError> {
    let mut scene = open_as_authored(name_or_path)?;
    let extent = scene.extent();
    let started = std::time::Instant::now();
    let (polygons, split) = contact::split_at_contacts(std::mem::take(&mut scene.polygons), extent);
    scene.polygons = polygons;
    if split > 0 {
        log::info!(
            "{}: {split} polygons split where others stand on them",
            scene.name
        );
    }
    log::debug!("contact split: {:.2} s", started.elapsed().as_secs_f64());
    Ok(scene)
}

/// [`open`] without the contact split: the polygons as the file gives them
/// (the paper's scene counts are of these).
pub fn open_as_authored(name_or_path: &str) -> Result<Scene, SceneError> {
    let path = std::path::Path::new(name_or_path);
    if path.exists() {
        return load(path);
    }
    if let Some(doc) = builtin_gltf(name_or_path) {
        let mut scene = load_slice(doc.as_bytes(), name_or_path)?;
        // A generated room lit through a window carries its sun and sky.
        if let Some((sun, sky)) = family::family_lights(name_or_path) {
            scene.lights.push(sun);
            scene.sky = Some(sky);
        }
        return Ok(scene);
    }
    let looks_like_file = path.extension().is_some() || name_or_path.contains('/');
    if looks_like_file {
        return load(path);
    }
    Err(SceneError::Unknown(
        name_or_path.to_string(),
        builtin_names().join(", "),
    ))
}
