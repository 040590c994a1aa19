//! The renderer's command-line settings, shared by the `radiosity` binary
//! and the lab's tools (`radiosity-lab bench`, `accuracy`, the flag fuzzer),
//! so every tool that renders is told the same way: [`SolveArgs`] (how to
//! solve) inside [`RenderArgs`] (what to render and where to write it).

use crate::gpu::Shading;
use crate::hemisphere::Resolution;
use crate::mesh::MeshSettings;
use crate::parallel::Exchange;
use crate::render::{FormFactorMethod, RenderOptions};
use crate::solver::StopRule;
use clap::Args;
use std::path::PathBuf;

/// Settings shared by `render` and `bench`.
#[derive(Args, Clone)]
pub struct SolveArgs {
    /// Hemisphere resolution R_phi x R_theta (polar rows x azimuth columns).
    #[arg(long, default_value = "128x512")]
    pub resolution: Resolution,
    /// How form factors are evaluated: hybrid (receiver-side: Lambert's
    /// contour integral from each element to the shooter patch, scaled by the
    /// visible fraction of its hemisphere cells; Baum et al. 1989) or
    /// hemisphere (the sum of the delta form factors of the cells that show
    /// each element, a point shooter at the patch centre).
    #[arg(long, value_enum, default_value = "hybrid")]
    pub form_factor: FormFactorMethod,
    /// Stop when the unshot power is at most this fraction of the emitted power.
    #[arg(long, default_value_t = 1e-3, value_parser = fraction)]
    threshold: f64,
    /// Stop after this many shots even if the threshold is not reached.
    #[arg(long, default_value_t = 100_000)]
    max_shots: u64,
    /// Patch edge length in metres, for every polygon (default: the node's
    /// extras.radiosity, else automatic: see --near-field-ratio).
    #[arg(long, value_parser = positive)]
    patch_size: Option<f32>,
    /// Element edge length in metres, for every polygon (default: the node's
    /// extras.radiosity, else 2 x 2 elements per patch).
    #[arg(long, value_parser = positive)]
    element_size: Option<f32>,
    /// Automatic subdivision: patch size as a fraction of the distance to the
    /// nearest polygon that faces it (smaller: more accurate, slower).
    #[arg(long, default_value_t = 0.2, value_parser = positive)]
    near_field_ratio: f32,
    /// How each piece's hemisphere cells are found: exact (a conservative
    /// cell rectangle and an exact per-cell ray test) or tessellated (pieces
    /// cut until each edge's curved image is within --tessellation-tolerance
    /// cells of its chords, projected in the vertex shader). docs/method/projections.md
    /// compares them.
    #[arg(long, value_enum, default_value = "exact")]
    projection: crate::render::Projection,
    /// The tessellated projection's tolerance, in cells.
    #[arg(long, default_value_t = crate::render::DEFAULT_TESSELLATION_TOLERANCE, value_parser = positive)]
    tessellation_tolerance: f32,
    /// Where the exact projection's hemisphere cells are drawn: device (by
    /// the wgpu device), cpu (by the renderer on the CPU, the same per-cell
    /// test) or auto (cpu where the adapter is a CPU rasteriser such as
    /// lavapipe, whose per-rectangle overheads make a shot's drawing
    /// several times dearer; device otherwise). Results agree to a few
    /// cells in 100 000 (the same bits on lavapipe in cluttered rooms;
    /// docs/scaling.md "Drawn on the CPU").
    #[arg(long, value_enum, default_value = "auto")]
    rasteriser: crate::render::Rasteriser,
    /// Refinement passes by need: the mesh starts 2^N times coarser than the
    /// automatic rule's (or at the scene's own subdivision), each pass solves
    /// it roughly and doubles the patch grid of polygons whose shooters cast
    /// penumbrae onto a noticeable share of the light, or whose receivers
    /// hold their light unevenly or would be shaded badly (see
    /// --refine-receivers and --refine-shading; docs/guide/meshing.md). 0: the mesh as given. Hybrid form factors only;
    /// `--patch-size` fixes the mesh.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(0..=6))]
    refine: u32,
    /// Refinement by need doubles the patch grid of a polygon one of whose
    /// patches holds its light so unevenly (sum over its elements of area x
    /// |B - the patch's mean|) that a uniform patch would misplace more than
    /// this fraction of the emitted power; 0: only shooters ask.
    #[arg(long, default_value_t = crate::mesh::DEFAULT_RECEIVER_TOL, value_parser = fraction)]
    refine_receivers: f64,
    /// Refinement by need also doubles the patch grid of a polygon where the
    /// image's smooth shading of the indirect light would stray from the
    /// solution by more than this fraction of the light there (its curvature
    /// over the element size); 0: never.
    #[arg(long, default_value_t = crate::mesh::DEFAULT_SHADING_TOL, value_parser = fraction)]
    refine_shading: f64,
    /// Cap on patches along one polygon edge (automatic subdivision).
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u32).range(1..=4096))]
    max_patches_per_edge: u32,
    /// What the hemisphere rasteriser draws: every quad polygon as at most
    /// N x N pieces (never more than its elements), the fragment shader
    /// finding the element at each hit point; 0 draws every element on its own
    /// (the old way). Triangles are drawn per element. The per-cell test is
    /// exact at any N, so results do not depend on it; larger N gives tighter
    /// rectangles (less fill) for more of them.
    #[arg(long, default_value_t = crate::render::DEFAULT_RASTER_PIECES, value_parser = clap::value_parser!(u32).range(0..=64))]
    raster_pieces: u32,
    /// Do not keep the form-factor rows of patches that have shot (by default
    /// a patch that shoots again reuses its row instead of rasterising; the
    /// results are identical, only the time changes).
    #[arg(long)]
    no_cache: bool,
    /// Draw every polygon in view, even those nearer ones certainly hide
    /// (by default those hidden in every rank's tiles are left undrawn: in
    /// cluttered scenes most of what a hemisphere holds is hidden). The
    /// results are identical, only the time changes.
    #[arg(long)]
    no_occlusion_cull: bool,
    /// Draw every row in the shot that takes it. By default a solve of one
    /// process on two cores or more draws, one row on each core, the rows
    /// of the shooters likely to shoot next (the runners-up of the vote)
    /// while the shot is under way, and a shot whose row is ready takes it.
    /// The results are identical, only the time changes.
    #[arg(long)]
    no_look_ahead: bool,
    /// Whether the ranks of an MPI run deal the polygons' bounds between
    /// them: each bounds every N-th block of polygons for the whole
    /// hemisphere and sends each piece to its tile's owner, instead of every
    /// rank testing every polygon for its own tiles. auto: on every run of
    /// ranks whose scene has 1024 polygons or more (measured: docs/notebook/ranks.md). The results are identical, only the time changes.
    #[arg(long, value_enum, default_value = "auto")]
    deal_bounds: crate::render::DealBounds,
    /// The memory each rank aims to stay within, GB: the form-factor row
    /// cache takes only what the scene, the mesh and the drawing leave of it
    /// (at most 1 GiB a rank; ranks of `--ranks` each count their share of
    /// the process). It changes no number, only the time.
    #[arg(long, default_value_t = crate::settings::DEFAULT_MEMORY_BUDGET as f32 / 1e9, value_parser = positive)]
    memory: f32,
    /// Do not split hybrid shots: by default, when a receiver near the
    /// shooter is partly hidden from its centre, each group of the shooter's
    /// elements takes visibility from a hemisphere of its own.
    #[arg(long)]
    no_split: bool,
    /// Hemisphere resolution of weak shooters (see --coarse-below): they
    /// matter little, and a coarse hemisphere costs a fraction of the time.
    /// Default: half --resolution along each axis, but no coarser than
    /// 64x256 (so 64x256 for 128x512, none for 64x256).
    #[arg(long)]
    coarse_resolution: Option<Resolution>,
    /// Shooters whose unshot power is below this fraction of the emitted
    /// power draw their hemisphere at --coarse-resolution (0: every shot at
    /// --resolution).
    #[arg(long, default_value_t = crate::render::DEFAULT_COARSE_BELOW, value_parser = parse_fraction)]
    coarse_below: f64,
    /// Shooters whose unshot power is below this fraction of the emitted
    /// power shoot along the ambient term's ray-sampled transport instead of
    /// drawing a hemisphere: their light lands on whole patches (clusters of
    /// patches in meshes of over 8192), for microseconds a shot. 0: never.
    /// Default: 1e-4 in meshes of over 8192 patches (where the transport
    /// clusters them), else 0. See docs/bench/transport-below.md "Weak shooters along the transport".
    #[arg(long, value_parser = parse_fraction)]
    transport_below: Option<f64>,
    /// Shooters a step of the final solve. 1 (the default): one at a time,
    /// each shot's hemisphere split over the ranks (the paper's method).
    /// Above 1: the strongest BATCH patches shoot from the same state, each
    /// rank drawing whole hemispheres for its turns of the batch, and the
    /// rows go to their elements' owners; the numbers depend on BATCH, never
    /// on the rank count. See docs/notebook/ranks.md "Ranks".
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub batch: u32,
    /// Ranks to run as threads of this one process, each with its share of
    /// the cores: what `mpirun -n RANKS` does, without MPI, and the same
    /// numbers (with --batch, the same as one rank's). With --batch 16 or
    /// more, two ranks on two cores shoot about 1.3-1.5x faster in big
    /// scenes than one rank using both (docs/bench/ranks-in-one-process.md "Ranks in one process");
    /// without --batch they split each hemisphere, which is slower. Under
    /// mpirun each process is one rank: leave this at 1 there.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=256))]
    pub ranks: u32,
}

impl SolveArgs {
    /// The render options these flags describe.
    pub fn options(&self) -> RenderOptions {
        RenderOptions {
            resolution: self.resolution,
            form_factor: self.form_factor,
            stop: StopRule {
                threshold: self.threshold,
                max_shots: self.max_shots,
            },
            mesh: MeshSettings {
                patch_size: self.patch_size,
                element_size: self.element_size,
                near_field_ratio: self.near_field_ratio,
                max_patches_per_edge: self.max_patches_per_edge,
                refine: self.refine,
                receiver_tol: self.refine_receivers,
                shading_tol: self.refine_shading,
                ..MeshSettings::default()
            },
            raster_pieces: self.raster_pieces,
            occlusion_cull: !self.no_occlusion_cull,
            look_ahead: !self.no_look_ahead,
            deal_bounds: self.deal_bounds,
            projection: self.projection,
            tessellation_tolerance: self.tessellation_tolerance,
            rasteriser: self.rasteriser,
            cache_rows: !self.no_cache,
            memory_budget: (f64::from(self.memory) * 1e9) as u64,
            split_shots: !self.no_split,
            coarse: self.coarse_resolution,
            coarse_below: self.coarse_below,
            transport_below: self.transport_below,
            batch: self.batch as usize,
            ..RenderOptions::default()
        }
    }
}

#[derive(Args)]
pub struct RenderArgs {
    /// A .gltf/.glb file, or a built-in scene: cornell, cubes-N (N^3 cubes in a
    /// lit room), cubes-b1, cubes-b2, cubes-b3, classroom-c1, classroom-c2,
    /// classroom-c3 (the paper's benchmark scenes).
    pub scene: String,
    /// Output EXR path (linear radiance); the PNG preview goes beside it.
    /// Default: OUT_DIR/<scene>.exr.
    #[arg(long)]
    pub image: Option<PathBuf>,
    /// Output JSON report path. Default: OUT_DIR/<scene>.json.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Directory for outputs whose paths are not given.
    #[arg(long, default_value = "out")]
    pub out_dir: PathBuf,
    /// Image width in pixels; 0 writes no image (only the report).
    #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(0..=16384))]
    pub width: u32,
    /// Image height in pixels (default: from the camera's aspect ratio).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub height: Option<u32>,
    /// Shading of the image: smooth (interpolated) or flat (one value per element).
    #[arg(long, value_enum, default_value = "smooth")]
    pub shading: Shading,
    /// Shadow rays per emitter per image sample for the image's direct
    /// light, traced with exact visibility (contact shadows, sharp shadow
    /// edges); 0 interpolates the direct light from the solution like the rest.
    #[arg(long, default_value_t = crate::render::image::DEFAULT_SHADOW_RAYS, value_parser = clap::value_parser!(u32).range(0..=4096))]
    pub shadow_rays: u32,
    /// Keep black the pixels where camera rays leave the scene (by default
    /// they show the sky, `--sky`, at its radiance).
    #[arg(long)]
    pub no_background: bool,
    /// Final gather rays per pixel for the image's indirect light: rays from
    /// each image sample bring back the solution's radiance where they land
    /// (smooth indirect light with exact visibility); 0 interpolates the
    /// indirect light from the solution. Needs --shadow-rays > 0.
    #[arg(long, default_value_t = crate::gather::DEFAULT_GATHER_RAYS, value_parser = clap::value_parser!(u32).range(0..=65536))]
    pub gather: u32,
    /// The glTF camera to render from, by name (the camera's, else its
    /// node's); default: the file's first perspective camera.
    #[arg(long)]
    pub camera: Option<String>,
    /// Draw the element edges over the image.
    #[arg(long)]
    pub wireframe: bool,
    /// The ambient term: the estimate of the light not yet shot that the
    /// image, the trace and the report's radiosities add. `carried`: the
    /// unshot power carried along the scene's geometry (rays between
    /// patches, estimated once per solve); `even`: spread evenly over the
    /// scene (Cohen et al. 1988); `off`: none.
    #[arg(long, value_enum, default_value_t)]
    pub ambient: crate::settings::AmbientTerm,
    /// Same as `--ambient off`.
    #[arg(long)]
    pub no_ambient: bool,
    /// Tile size WxH in hemisphere cells when running on several MPI ranks
    /// (tiles are dealt to the rank grid by 2-D interleave; 1x1 is the paper's
    /// per-cell interleave). Default: automatic, 4 x 4 tiles per rank (64x32
    /// on two ranks at 128x512), so each rank skips the rectangles outside
    /// its tiles. Results are the same bits for any tiles.
    #[arg(long, value_parser = parse_tile)]
    pub tile: Option<(u32, u32)>,
    /// How ranks exchange form factors each shot.
    #[arg(long, value_enum, default_value = "hemispheres")]
    pub exchange: Exchange,
    /// PNG preview exposure adjustment in stops, on top of automatic exposure.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub exposure: f32,
    /// Where to save the solve's state (replaced atomically each time), to
    /// resume it with --resume. SIGINT or SIGTERM always save it (here, or
    /// OUT_DIR/<scene>.ckpt) and write the outputs so far. Default: OUT_DIR/<scene>.ckpt.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Also save the state every this many seconds of solving.
    #[arg(long, value_parser = positive)]
    pub checkpoint_every: Option<f32>,
    /// Also write the solved scene as glTF (.glb or .gltf): every mesh node
    /// with its name and transform, re-meshed on its elements, the radiosity
    /// as linear vertex colours and unlit materials (docs/guide/bake.md "Baking").
    #[arg(long)]
    pub bake: Option<PathBuf>,
    /// Continue a solve from a checkpoint (same scene and settings that
    /// change the numbers; any number of ranks, tiles or exchange). The
    /// result is bit for bit the one an uninterrupted solve gives.
    #[arg(long)]
    pub resume: Option<PathBuf>,
    #[command(flatten)]
    pub lights: crate::scene::light::LightArgs,
    #[command(flatten)]
    pub solve: SolveArgs,
}

/// A finite number above 0 (sizes and ratios: 0 would mean infinitely many patches).
pub fn positive(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        Ok(_) => Err(format!("'{s}' must be a finite number above 0")),
        Err(_) => Err(format!("'{s}' is not a number")),
    }
}

/// A finite fraction in [0, 1].
pub fn fraction(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if (0.0..=1.0).contains(&x) => Ok(x),
        Ok(_) => Err(format!("'{s}' must be between 0 and 1")),
        Err(_) => Err(format!("'{s}' is not a number")),
    }
}

pub fn parse_fraction(s: &str) -> Result<f64, String> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|x| (0.0..=1.0).contains(x))
        .ok_or_else(|| format!("expected a fraction in [0, 1], got '{s}'"))
}

/// A tile size `WxH`, each side 1..=8192.
pub fn parse_tile(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WxH such as 8x4, got '{s}'"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|&n| (1..=8192).contains(&n))
            .ok_or_else(|| format!("bad tile size '{s}': each side must be 1..=8192"))
    };
    Ok((parse(w)?, parse(h)?))
}
