//! Everything a render can be told, its defaults, and what each setting
//! implies (the coarse tier, the mesh settings, the checkpoint fingerprint).

use crate::checkpoint::Checkpoint;
use crate::gpu::{GpuError, Shading};
use crate::hemisphere::{Resolution, TileLayout};
use crate::mesh::MeshSettings;
use crate::parallel::Exchange;
use crate::scene::{Scene, Subdivision};
pub use crate::settings::{
    DealBounds, FormFactorMethod, Projection, Rasteriser, AUTO_TRANSPORT_BELOW,
    DEFAULT_COARSE_BELOW, DEFAULT_MEMORY_BUDGET, DEFAULT_RASTER_PIECES, DEFAULT_SHADOW_RAYS,
    DEFAULT_TESSELLATION_TOLERANCE,
};
use crate::solver::StopRule;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

/// Everything a render can be told.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    /// Hemisphere resolution.
    pub resolution: Resolution,
    /// How form factors are evaluated.
    pub form_factor: FormFactorMethod,
    /// When to stop.
    pub stop: StopRule,
    /// How to subdivide.
    pub mesh: MeshSettings,
    /// How cells are found: exact per-cell test, or tessellation.
    pub projection: Projection,
    /// The tessellated projection's tolerance (cells between an edge's
    /// curved image and its chords).
    pub tessellation_tolerance: f32,
    /// Where the exact projection's cells are drawn: by the device or on
    /// the CPU.
    pub rasteriser: Rasteriser,
    /// What the hemisphere rasteriser draws: quad polygons as at most N x N
    /// pieces (the element is found per fragment), or every element (0).
    pub raster_pieces: u32,
    /// Whether shots leave undrawn the polygons that nearer ones certainly
    /// hide in every rank's tiles (`crate::occlusion`; the same bits
    /// either way).
    pub occlusion_cull: bool,
    /// Whether a solve of one process on two cores or more draws the rows
    /// of the shooters likely next beside the shot (`render::ahead`; the
    /// same bits either way).
    pub look_ahead: bool,
    /// Whether the ranks of a run deal the polygons' bounds between them
    /// (`raster::Scatter`; the same bits either way).
    pub deal_bounds: DealBounds,
    /// How the hemisphere is tiled and over which rank grid. Under MPI the
    /// grid comes from the rank count and only the tile size is used; in one
    /// process every rank's tiles are drawn in turn (one tile by default).
    pub layout: Option<TileLayout>,
    /// Tile size in cells (width along theta, height along phi) when running on
    /// several ranks; 1 x 1 is the paper's per-cell interleave; `None`:
    /// automatic (`render::tiers::auto_tile`: 4 x 4 tiles per rank).
    pub tile: Option<(u32, u32)>,
    /// How ranks exchange form factors.
    pub exchange: Exchange,
    /// Image width in pixels (0: no image).
    pub width: u32,
    /// Image height (from the camera's aspect ratio when `None`).
    pub height: Option<u32>,
    /// Smooth or flat shading.
    pub shading: Shading,
    /// Shadow rays per emitter per image sample for the image's traced
    /// direct light (0: the direct light interpolated from the solution).
    pub shadow_rays: u32,
    /// Draw the scene's sky where camera rays leave the scene (with traced
    /// direct light); `false` keeps those pixels black (`--no-background`).
    pub background: bool,
    /// Final gather rays per pixel for the image's indirect light (0: the
    /// indirect light interpolated from the solution); with traced direct light.
    pub gather: u32,
    /// Add the ambient term to the image and the reported radiosities.
    pub ambient: crate::settings::AmbientTerm,
    /// Keep form-factor rows of patches that have shot, so a patch that
    /// shoots again costs no rasterisation (results are identical either way).
    pub cache_rows: bool,
    /// The memory each rank aims to stay within, bytes: the row cache takes
    /// only what the scene, the mesh and the drawing leave of it (at most
    /// 1 GiB). It changes no number, only the time.
    pub memory_budget: u64,
    /// Split a hybrid shot into one hemisphere per group of shooter elements
    /// where a near receiver is partly hidden from the shooter's centre.
    pub split_shots: bool,
    /// The hemisphere resolution of weak shooters (see `coarse_below`);
    /// `None`: half `resolution` along each axis (a quarter of the cells).
    pub coarse: Option<Resolution>,
    /// Shooters whose unshot power is below this fraction of the emitted
    /// power draw their hemisphere at `coarse` (0: every shot at `resolution`).
    pub coarse_below: f64,
    /// Shooters whose unshot power is below this fraction of the emitted
    /// power shoot along the ambient term's ray-sampled transport
    /// (`crate::ambient::Transport`) instead of drawing a hemisphere: their
    /// light lands on whole patches (clusters in big meshes), for
    /// microseconds a shot. 0: never. `None`, the default: automatic
    /// ([`RenderOptions::transport_below_for`]).
    pub transport_below: Option<f64>,
    /// Shooters a step of the final solve (1: one at a time, the paper's
    /// decomposition of each shot over the ranks). Above 1 the strongest
    /// `batch` patches shoot from the same state, each rank drawing whole
    /// hemispheres for its turns of the batch: the numbers depend on
    /// `batch`, not on the rank count.
    pub batch: usize,
    /// Draw element edges over the image.
    pub wireframe: bool,
    /// Where and how often to save the solve's state (`None`: never).
    pub checkpoint: Option<CheckpointPlan>,
    /// Set (by a signal handler, say) to stop after the current shot: the
    /// state goes to the checkpoint and the result so far is returned.
    pub interrupt: Option<Arc<AtomicBool>>,
    /// Continue from this saved state instead of starting afresh.
    pub resume: Option<Arc<Checkpoint>>,
}

/// Where a solve saves its state.
#[derive(Clone, Debug)]
pub struct CheckpointPlan {
    /// The checkpoint file (replaced atomically each time).
    pub path: std::path::PathBuf,
    /// Save every this often (`None`: only when interrupted).
    pub every: Option<Duration>,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            resolution: Resolution::default(),
            form_factor: FormFactorMethod::default(),
            stop: StopRule::default(),
            mesh: MeshSettings::default(),
            raster_pieces: DEFAULT_RASTER_PIECES,
            occlusion_cull: true,
            look_ahead: true,
            deal_bounds: DealBounds::Auto,
            projection: Projection::Exact,
            tessellation_tolerance: DEFAULT_TESSELLATION_TOLERANCE,
            rasteriser: Rasteriser::Auto,
            layout: None,
            tile: None,
            exchange: Exchange::Hemispheres,
            width: 512,
            height: None,
            shading: Shading::Smooth,
            shadow_rays: DEFAULT_SHADOW_RAYS,
            background: true,
            gather: crate::gather::DEFAULT_GATHER_RAYS,
            ambient: crate::settings::AmbientTerm::default(),
            cache_rows: true,
            memory_budget: DEFAULT_MEMORY_BUDGET,
            split_shots: true,
            coarse: None,
            coarse_below: DEFAULT_COARSE_BELOW,
            transport_below: None,
            batch: 1,
            wireframe: false,
            checkpoint: None,
            interrupt: None,
            resume: None,
        }
    }
}

impl RenderOptions {
    /// The hemisphere resolution weak shooters draw at, if there is a coarse
    /// tier: `coarse`, or half `resolution` along each axis but no coarser
    /// than 64 x 256 (weak shooters at 48 x 192 or 32 x 128 leave the 64
    /// cubes above 1 %: docs/method/form-factors.md "Coarse hemispheres for weak shooters"), when
    /// `coarse_below` is above 0 and it has fewer cells than `resolution`.
    pub fn coarse_tier(&self) -> Option<Resolution> {
        let res = self.resolution;
        let coarse = self.coarse.unwrap_or(Resolution {
            rows: (res.rows / 2).max(64),
            cols: (res.cols / 2).max(256),
        });
        (self.coarse_below > 0.0 && coarse.cells() < res.cells()).then_some(coarse)
    }

    /// The mesh settings a render uses: refinement by need only with hybrid
    /// form factors (hemisphere sums do not measure penumbrae) and without a
    /// fixed `--patch-size`.
    pub fn mesh_settings(&self) -> MeshSettings {
        let mut m = self.mesh;
        if self.form_factor != FormFactorMethod::Hybrid || m.patch_size.is_some() {
            m.refine = 0;
        }
        m
    }

    /// The transport tier's threshold (a fraction of the emitted power) for
    /// a mesh of `patches` patches: the one given, or, by default,
    /// [`AUTO_TRANSPORT_BELOW`] in meshes of more than
    /// [`crate::ambient::PATCH_GROUPS`] patches, where the transport
    /// clusters patches and a weak cluster shoots as one (so the shots a
    /// solve needs stop growing with the polygon count: Sponza reaches
    /// unshot 1e-2 in 9 s instead of hours), and 0 (off) in smaller ones,
    /// where each group is a patch and drawing its hemisphere is cheap.
    pub fn transport_below_for(&self, patches: usize) -> f64 {
        self.transport_below
            .unwrap_or(if patches > crate::ambient::PATCH_GROUPS {
                AUTO_TRANSPORT_BELOW
            } else {
                0.0
            })
    }

    /// Who draws the hemispheres on an adapter that is
    /// (`adapter_is_cpu`) or is not a CPU rasteriser: `Device` or `Cpu`
    /// (`--rasteriser` resolved; the tessellated projection always draws
    /// on the device).
    pub fn rasteriser_for(&self, adapter_is_cpu: bool) -> Rasteriser {
        match self.projection {
            Projection::Tessellated => Rasteriser::Device,
            Projection::Exact => self.rasteriser.resolve(adapter_is_cpu),
        }
    }

    /// Fails on settings no solve can use.
    pub fn validate(&self) -> Result<(), RenderError> {
        self.resolution
            .validate()
            .map_err(|e| RenderError::Settings(e.to_string()))?;
        if let Some(t) = self.transport_below.filter(|t| !(0.0..1.0).contains(t)) {
            return Err(RenderError::Settings(format!(
                "transport-below {t} must be in [0, 1)"
            )));
        }
        if self.stop.threshold.is_nan() || self.stop.threshold < 0.0 {
            return Err(RenderError::Settings(format!(
                "threshold {} must be >= 0",
                self.stop.threshold
            )));
        }
        Ok(())
    }

    /// The image height: `height`, or `width` over the camera's aspect ratio.
    pub fn image_height(&self, aspect: Option<f32>) -> u32 {
        self.height
            .unwrap_or_else(|| (self.width as f32 / aspect.unwrap_or(1.0)).round().max(1.0) as u32)
    }
}

/// Why a render failed.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// The GPU failed.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// A setting is unusable.
    #[error("invalid setting: {0}")]
    Settings(String),
    /// A checkpoint could not be written or does not fit this render.
    #[error("checkpoint: {0}")]
    Checkpoint(String),
    /// A shot's fixed-point form-factor sums overflowed (no GPU fault: the
    /// scene or resolution is beyond what the sums can hold).
    #[error("the fixed-point form-factor sums of shooter {0} overflowed 64 bits")]
    Overflow(u32),
    /// Ranks of a batched solve disagreed on a split shot (a part sent
    /// to the wrong rank, or one missing): a bug, reported, not a hang.
    #[error("split shot of shooter {0}: {1}")]
    SplitShot(u32, String),
    /// A row drawn ahead (`render::ahead`) never came: a bug, reported,
    /// not a hang.
    #[error("the row of shooter {0} drawn ahead: {1}")]
    DrawnAhead(u32, String),
    /// The scene cannot be rendered as it is (nothing lights it).
    #[error(transparent)]
    Scene(#[from] crate::scene::SceneError),
}

/// What a checkpoint must match to be resumed here: the scene's geometry,
/// materials and subdivision, and every setting that changes the numbers
/// (not the rank count, tiles or exchange, which do not). Spelled out field
/// by field (never through `Debug`, whose output Rust does not promise to
/// keep), in the text checkpoints have always hashed. `rasteriser` is where
/// the run draws (`RenderOptions::rasteriser_for`): a driver may fuse a
/// multiply-add the CPU drawing does not, so a resume drawn elsewhere could
/// differ in a cell in ten thousand.
pub fn fingerprint(scene: &Scene, opts: &RenderOptions, rasteriser: Rasteriser) -> String {
    let mut geometry = Vec::new();
    for p in &scene.polygons {
        let floats = p.vertices.iter().flat_map(|v| v.to_array());
        for x in floats.chain(p.reflectance).chain(p.emission) {
            geometry.extend_from_slice(&x.to_bits().to_le_bytes());
        }
        let subdivision = option_text(p.subdivision.as_ref().map(subdivision_text));
        geometry.extend_from_slice(format!("{} {subdivision};", p.node).as_bytes());
        // Only with an emissive texture, so older checkpoints still resume.
        if let Some(m) = &p.emissive {
            let (uv, du, dv) = (m.uv0, m.du, m.dv);
            let floats = [uv.x, uv.y, du.x, du.y, du.z, dv.x, dv.y, dv.z].into_iter();
            let map: Vec<String> = floats
                .chain(m.factor)
                .map(|x| x.to_bits().to_string())
                .collect();
            let texture = m.texture.texture.digest();
            geometry
                .extend_from_slice(format!("emissive {texture:x} {};", map.join(" ")).as_bytes());
        }
    }
    // Lights change the numbers; scenes without them keep the text older
    // checkpoints were written with.
    for l in &scene.lights {
        geometry.extend_from_slice(format!("light {};", l.describe()).as_bytes());
    }
    if let Some(sky) = scene.sky {
        geometry.extend_from_slice(format!("sky {sky:?};").as_bytes());
    }
    if let Some(map) = &scene.sky_map {
        geometry.extend_from_slice(format!("{};", map.describe()).as_bytes());
    }
    let settings = format!(
        "{} {} {} {} {} {} {} {} {}",
        opts.resolution,
        opts.form_factor.name(),
        mesh_text(&opts.mesh_settings()),
        opts.split_shots,
        // Where overshooting (removed) was: older checkpoints still resume.
        false,
        opts.projection.name(),
        opts.tessellation_tolerance,
        option_text(opts.coarse_tier().map(|r| format!("\"{r}\""))),
        opts.coarse_below
    );
    // Only when set, so checkpoints written before the option resume.
    // (The automatic choice follows from the geometry and the subdivision,
    // which the fingerprint holds.)
    let settings = match opts.transport_below {
        Some(t) if t > 0.0 => format!("{settings} transport {t}"),
        _ => settings,
    };
    let settings = match opts.batch {
        b if b > 1 => format!("{settings} batch {b}"),
        _ => settings,
    };
    // The device's drawing only, so checkpoints drawn on the CPU (every one
    // before the rasteriser was held here) still resume.
    let settings = match rasteriser {
        Rasteriser::Device => format!("{settings} rasteriser device"),
        _ => settings,
    };
    crate::checkpoint::fingerprint(&[
        &geometry,
        settings.as_bytes(),
        scene.nodes.join("\n").as_bytes(),
    ])
}

fn option_text(x: Option<String>) -> String {
    x.map_or_else(|| "None".into(), |s| format!("Some({s})"))
}

fn subdivision_text(s: &Subdivision) -> String {
    format!(
        "Subdivision {{ patches: [{}, {}], elements: [{}, {}] }}",
        s.patches[0], s.patches[1], s.elements[0], s.elements[1]
    )
}

fn mesh_text(m: &MeshSettings) -> String {
    // Checkpoints from before receivers were refined resume with it off.
    let mut receivers = if m.receiver_tol > 0.0 {
        format!(", receivers: {:?}", m.receiver_tol)
    } else {
        String::new()
    };
    // Likewise the shading criterion.
    if m.shading_tol > 0.0 {
        receivers += &format!(", shading: {:?}", m.shading_tol);
    }
    format!(
        "MeshSettings {{ patch_size: {}, element_size: {}, near_field_ratio: {:?}, max_patches_per_edge: {}, max_elements_per_edge: {}, refine: {}{receivers} }}",
        option_text(m.patch_size.map(|x| format!("{x:?}"))),
        option_text(m.element_size.map(|x| format!("{x:?}"))),
        m.near_field_ratio,
        m.max_patches_per_edge,
        m.max_elements_per_edge,
        m.refine
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fingerprint's text is the one checkpoints were written with
    /// (then through `Debug`): old checkpoints still resume.
    #[test]
    fn fingerprint_text_is_the_one_checkpoints_were_written_with() {
        let s = Subdivision {
            patches: [3, 4],
            elements: [2, 1],
        };
        assert_eq!(subdivision_text(&s), format!("{s:?}"));
        for m in [
            MeshSettings::default(),
            MeshSettings {
                patch_size: Some(0.25),
                element_size: Some(1e-7),
                near_field_ratio: 0.125,
                refine: 3,
                ..MeshSettings::default()
            },
        ] {
            // Checkpoints were written before receivers were refined: with
            // the receivers' criterion off, the text is theirs.
            let off = MeshSettings {
                receiver_tol: 0.0,
                shading_tol: 0.0,
                ..m
            };
            let old = format!("{off:?}").replace(", receiver_tol: 0.0, shading_tol: 0.0", "");
            assert_eq!(mesh_text(&off), old);
            assert!(
                mesh_text(&m).ends_with(", receivers: 0.0005, shading: 0.08 }"),
                "{}",
                mesh_text(&m)
            );
        }
        for m in [FormFactorMethod::Hybrid, FormFactorMethod::Hemisphere] {
            assert_eq!(m.name(), format!("{m:?}"));
        }
        // Drawn by the device, a checkpoint says so; drawn on the CPU, its
        // text is the one before the rasteriser was held.
        let scene = Scene::default();
        let opts = RenderOptions::default();
        let cpu = fingerprint(&scene, &opts, Rasteriser::Cpu);
        assert_ne!(fingerprint(&scene, &opts, Rasteriser::Device), cpu);
        assert_eq!(fingerprint(&scene, &opts, Rasteriser::Auto), cpu);
        for p in [Projection::Exact, Projection::Tessellated] {
            assert_eq!(p.name(), format!("{p:?}"));
        }
        let coarse = Some(
            Resolution {
                rows: 64,
                cols: 256,
            }
            .to_string(),
        );
        assert_eq!(
            option_text(coarse.as_ref().map(|r| format!("\"{r}\""))),
            format!("{coarse:?}")
        );
        assert_eq!(option_text(None), format!("{:?}", None::<String>));
    }

    #[test]
    fn coarse_tier_follows_the_resolution() {
        let mut o = RenderOptions::default();
        assert_eq!(
            o.coarse_tier(),
            Some(Resolution {
                rows: 64,
                cols: 256
            })
        );
        o.resolution = Resolution {
            rows: 256,
            cols: 1024,
        };
        assert_eq!(
            o.coarse_tier(),
            Some(Resolution {
                rows: 128,
                cols: 512
            })
        );
        o.resolution = Resolution {
            rows: 64,
            cols: 256,
        };
        assert_eq!(o.coarse_tier(), None, "no coarser than 64x256");
        o.resolution = Resolution::default();
        o.coarse_below = 0.0;
        assert_eq!(o.coarse_tier(), None);
    }
}
