//! `radiosity`: the command-line renderer.

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use radiosity::checkpoint::Checkpoint;
use radiosity::comm::MpiComm;
use radiosity::gpu::{Gpu, Shading};
use radiosity::hemisphere::Resolution;
use radiosity::mesh::MeshSettings;
use radiosity::parallel::{Collectives, Exchange, Single};
use radiosity::render::write::{output_stem, write_outputs, OutputPaths, WriteError};
use radiosity::render::{
    render_on, render_ranks, CheckpointPlan, FormFactorMethod, Progress, RenderOptions, Rendered,
};
use radiosity::solver::StopRule;
use radiosity::{launch, output, scene};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Draws one chart twice, as `STEM.svg` and `STEM.png` in `out`, at `size`:
/// `|root| body` is expanded once per backend (the drawing functions are
/// generic over it), and an error names the file.
macro_rules! svg_and_png {
    ($out:expr, $stem:expr, $size:expr, |$root:ident| $body:expr) => {{
        use plotters::prelude::IntoDrawingArea;
        let svg = $out.join(format!("{}.svg", $stem));
        {
            let $root = plotters::prelude::SVGBackend::new(&svg, $size).into_drawing_area();
            $body.map_err(|e| anyhow::anyhow!("{}: {e}", svg.display()))?;
        }
        let png = $out.join(format!("{}.png", $stem));
        {
            let $root = plotters::prelude::BitMapBackend::new(&png, $size).into_drawing_area();
            $body.map_err(|e| anyhow::anyhow!("{}: {e}", png.display()))?;
        }
    }};
}

mod accuracy;
mod bench;
mod charted;
mod receivers;
mod regimes;
mod scaling_report;

/// Progressive radiosity with equal-angle hemisphere form factors rasterised by wgpu.
#[derive(Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Solve a scene and write an EXR image, a PNG preview and a JSON report.
    Render(RenderArgs),
    /// Write a built-in scene as a glTF file (to open in Blender, or to edit).
    Scene {
        /// Built-in scene name (see `radiosity render --help`).
        name: String,
        /// Output .gltf path.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Also write the scene (a built-in or a glTF file, as the renderer
        /// loads it) as per-node triangles, reflectance, emission and area:
        /// the JSON `scripts/reference.py` reads.
        #[arg(long)]
        nodes: Option<PathBuf>,
        /// Lights for --nodes (a sun, a sky, photometric units), as `render` takes them.
        #[command(flatten)]
        lights: radiosity::scene::light::LightArgs,
    },
    /// Score an EXR image against a reference EXR of the same size: the SMAPE
    /// over interior 4x4 blocks (README "An independent yardstick").
    Compare {
        /// The image to score.
        image: PathBuf,
        /// The reference (e.g. `scripts/reference.py --image`).
        reference: PathBuf,
    },
    /// Time shots on the built-in scenes and print a table (see README "Performance").
    Bench(bench::BenchArgs),
    /// Turn render reports (e.g. from scripts/bench-mpi.sh) into a CSV and charts.
    BenchReport(bench::ReportArgs),
    /// Fit the performance model to calibration runs (scripts/calibrate-scaling.sh),
    /// check it against them and redraw the paper's figures 8-12 for up to
    /// 1024 ranks (docs/scaling.md).
    Scaling(scaling_report::ScalingArgs),
    /// Chart error against solve time for every method option and resolution,
    /// beside a path tracer (Mitsuba 3), to docs/bench/accuracy.
    Accuracy {
        #[command(flatten)]
        args: accuracy::AccuracyArgs,
        #[command(flatten)]
        solve: SolveArgs,
    },
    /// Robustness run: broken glTF/GLB files made from the Cornell box, each
    /// loaded and rendered small, and random `render` flag lists parsed; exits
    /// non-zero on any panic, hang or non-finite report (README "Reliability").
    Fuzz {
        /// Scene cases to run.
        #[arg(long, default_value_t = 10_000)]
        cases: u64,
        /// First case's seed (cases are seed, seed + 1, ...).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Random flag lists to parse.
        #[arg(long, default_value_t = 10_000)]
        flag_cases: u64,
    },
}

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
    /// cells of its chords, projected in the vertex shader). README
    /// "Projections" compares them.
    #[arg(long, value_enum, default_value = "exact")]
    projection: radiosity::render::Projection,
    /// The tessellated projection's tolerance, in cells.
    #[arg(long, default_value_t = radiosity::render::DEFAULT_TESSELLATION_TOLERANCE, value_parser = positive)]
    tessellation_tolerance: f32,
    /// Where the exact projection's hemisphere cells are drawn: device (by
    /// the wgpu device), cpu (by the renderer on the CPU, the same per-cell
    /// test) or auto (cpu where the adapter is a CPU rasteriser such as
    /// lavapipe, whose per-rectangle overheads make a shot's drawing
    /// several times dearer; device otherwise). Results agree to a few
    /// cells in 100 000 (the same bits on lavapipe in cluttered rooms;
    /// README "Drawn on the CPU").
    #[arg(long, value_enum, default_value = "auto")]
    rasteriser: radiosity::render::Rasteriser,
    /// Refinement passes by need: the mesh starts 2^N times coarser than the
    /// automatic rule's (or at the scene's own subdivision), each pass solves
    /// it roughly and doubles the patch grid of polygons whose shooters cast
    /// penumbrae onto a noticeable share of the light, or whose receivers
    /// hold their light unevenly or would be shaded badly (see
    /// --refine-receivers and --refine-shading; README "Refinement by
    /// need"). 0: the mesh as given. Hybrid form factors only;
    /// `--patch-size` fixes the mesh.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(0..=6))]
    refine: u32,
    /// Refinement by need doubles the patch grid of a polygon one of whose
    /// patches holds its light so unevenly (sum over its elements of area x
    /// |B - the patch's mean|) that a uniform patch would misplace more than
    /// this fraction of the emitted power; 0: only shooters ask.
    #[arg(long, default_value_t = radiosity::mesh::DEFAULT_RECEIVER_TOL, value_parser = fraction)]
    refine_receivers: f64,
    /// Refinement by need also doubles the patch grid of a polygon where the
    /// image's smooth shading of the indirect light would stray from the
    /// solution by more than this fraction of the light there (its curvature
    /// over the element size); 0: never.
    #[arg(long, default_value_t = radiosity::mesh::DEFAULT_SHADING_TOL, value_parser = fraction)]
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
    #[arg(long, default_value_t = radiosity::render::DEFAULT_RASTER_PIECES, value_parser = clap::value_parser!(u32).range(0..=64))]
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
    /// ranks whose scene has 1024 polygons or more (measured: README
    /// "Ranks"). The results are identical, only the time changes.
    #[arg(long, value_enum, default_value = "auto")]
    deal_bounds: radiosity::render::DealBounds,
    /// How the ranks of a batched solve (`--batch`) deal a batch's rows:
    /// pool (each rank starts on one of the dearest, then takes the rest
    /// as it comes free) or fixed (every row dealt before any is drawn).
    /// The results are identical, only the time changes.
    #[arg(long, value_enum, default_value = "pool")]
    deal_rows: radiosity::settings::DealRows,
    /// The memory each rank aims to stay within, GB: the form-factor row
    /// cache takes only what the scene, the mesh and the drawing leave of it
    /// (at most 1 GiB a rank; ranks of `--ranks` each count their share of
    /// the process). It changes no number, only the time.
    #[arg(long, default_value_t = radiosity::settings::DEFAULT_MEMORY_BUDGET as f32 / 1e9, value_parser = positive)]
    memory: f32,
    /// Do not split hybrid shots: by default, when a receiver near the
    /// shooter is partly hidden from its centre, each group of the shooter's
    /// elements takes visibility from a hemisphere of its own.
    #[arg(long)]
    no_split: bool,
    /// Overshoot: each shooter shoots its unshot radiosity plus its
    /// reflectance times the ambient term (the light it can still expect),
    /// taking back later what it shot ahead (Feda & Purgathofer 1992). About
    /// half the shots to the same error, but not less time on lavapipe (most
    /// of a solve's time is each patch's first, rasterised shot): README
    /// "Overshooting".
    #[arg(long)]
    overshoot: bool,
    /// Hemisphere resolution of weak shooters (see --coarse-below): they
    /// matter little, and a coarse hemisphere costs a fraction of the time.
    /// Default: half --resolution along each axis, but no coarser than
    /// 64x256 (so 64x256 for 128x512, none for 64x256).
    #[arg(long)]
    coarse_resolution: Option<Resolution>,
    /// Shooters whose unshot power is below this fraction of the emitted
    /// power draw their hemisphere at --coarse-resolution (0: every shot at
    /// --resolution).
    #[arg(long, default_value_t = radiosity::render::DEFAULT_COARSE_BELOW, value_parser = parse_fraction)]
    coarse_below: f64,
    /// Shooters whose unshot power is below this fraction of the emitted
    /// power shoot along the ambient term's ray-sampled transport instead of
    /// drawing a hemisphere: their light lands on whole patches (clusters of
    /// patches in meshes of over 8192), for microseconds a shot. 0: never.
    /// Default: 1e-4 in meshes of over 8192 patches (where the transport
    /// clusters them), else 0. See README "Weak shooters along the transport".
    #[arg(long, value_parser = parse_fraction)]
    transport_below: Option<f64>,
    /// Shooters a step of the final solve. 1 (the default): one at a time,
    /// each shot's hemisphere split over the ranks (the paper's method).
    /// Above 1: the strongest BATCH patches shoot from the same state, each
    /// rank drawing whole hemispheres for its turns of the batch, and the
    /// rows go to their elements' owners; the numbers depend on BATCH, never
    /// on the rank count. See README "Ranks".
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub batch: u32,
    /// Ranks to run as threads of this one process, each with its share of
    /// the cores: what `mpirun -n RANKS` does, without MPI, and the same
    /// numbers (with --batch, the same as one rank's). With --batch 16 or
    /// more, two ranks on two cores shoot about 1.3-1.5x faster in big
    /// scenes than one rank using both (README "Ranks in one process");
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
            deal_rows: self.deal_rows,
            projection: self.projection,
            tessellation_tolerance: self.tessellation_tolerance,
            rasteriser: self.rasteriser,
            cache_rows: !self.no_cache,
            memory_budget: (f64::from(self.memory) * 1e9) as u64,
            split_shots: !self.no_split,
            overshoot: self.overshoot,
            coarse: self.coarse_resolution,
            coarse_below: self.coarse_below,
            transport_below: self.transport_below,
            batch: self.batch as usize,
            ..RenderOptions::default()
        }
    }
}

#[derive(Args)]
struct RenderArgs {
    /// A .gltf/.glb file, or a built-in scene: cornell, cubes-N (N^3 cubes in a
    /// lit room), cubes-b1, cubes-b2, cubes-b3, classroom-c1, classroom-c2,
    /// classroom-c3 (the paper's benchmark scenes).
    scene: String,
    /// Output EXR path (linear radiance); the PNG preview goes beside it.
    /// Default: OUT_DIR/<scene>.exr.
    #[arg(long)]
    image: Option<PathBuf>,
    /// Output JSON report path. Default: OUT_DIR/<scene>.json.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Directory for outputs whose paths are not given.
    #[arg(long, default_value = "out")]
    out_dir: PathBuf,
    /// Image width in pixels; 0 writes no image (only the report).
    #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(0..=16384))]
    width: u32,
    /// Image height in pixels (default: from the camera's aspect ratio).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=16384))]
    height: Option<u32>,
    /// Shading of the image: smooth (interpolated) or flat (one value per element).
    #[arg(long, value_enum, default_value = "smooth")]
    shading: Shading,
    /// Shadow rays per emitter per image sample for the image's direct
    /// light, traced with exact visibility (contact shadows, sharp shadow
    /// edges); 0 interpolates the direct light from the solution like the rest.
    #[arg(long, default_value_t = radiosity::render::image::DEFAULT_SHADOW_RAYS, value_parser = clap::value_parser!(u32).range(0..=4096))]
    shadow_rays: u32,
    /// The glTF camera to render from, by name (the camera's, else its
    /// node's); default: the file's first perspective camera.
    #[arg(long)]
    camera: Option<String>,
    /// Draw the element edges over the image.
    #[arg(long)]
    wireframe: bool,
    /// The ambient term: the estimate of the light not yet shot that the
    /// image, the trace and the report's radiosities add. `carried`: the
    /// unshot power carried along the scene's geometry (rays between
    /// patches, estimated once per solve); `even`: spread evenly over the
    /// scene (Cohen et al. 1988); `off`: none.
    #[arg(long, value_enum, default_value_t)]
    ambient: radiosity::settings::AmbientTerm,
    /// Same as `--ambient off`.
    #[arg(long)]
    no_ambient: bool,
    /// Tile size WxH in hemisphere cells when running on several MPI ranks
    /// (tiles are dealt to the rank grid by 2-D interleave; 1x1 is the paper's
    /// per-cell interleave). Default: automatic, 4 x 4 tiles per rank (64x32
    /// on two ranks at 128x512), so each rank skips the rectangles outside
    /// its tiles. Results are the same bits for any tiles.
    #[arg(long, value_parser = parse_tile)]
    tile: Option<(u32, u32)>,
    /// How ranks exchange form factors each shot.
    #[arg(long, value_enum, default_value = "hemispheres")]
    exchange: Exchange,
    /// PNG preview exposure adjustment in stops, on top of automatic exposure.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    exposure: f32,
    /// Where to save the solve's state (replaced atomically each time), to
    /// resume it with --resume. SIGINT or SIGTERM always save it (here, or
    /// OUT_DIR/<scene>.ckpt) and write the outputs so far. Default: OUT_DIR/<scene>.ckpt.
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Also save the state every this many seconds of solving.
    #[arg(long, value_parser = positive)]
    checkpoint_every: Option<f32>,
    /// Also write the solved scene as glTF (.glb or .gltf): every mesh node
    /// with its name and transform, re-meshed on its elements, the radiosity
    /// as linear vertex colours and unlit materials (README "Baking").
    #[arg(long)]
    bake: Option<PathBuf>,
    /// Continue a solve from a checkpoint (same scene and settings that
    /// change the numbers; any number of ranks, tiles or exchange). The
    /// result is bit for bit the one an uninterrupted solve gives.
    #[arg(long)]
    resume: Option<PathBuf>,
    #[command(flatten)]
    lights: radiosity::scene::light::LightArgs,
    #[command(flatten)]
    solve: SolveArgs,
}

/// A finite number above 0 (sizes and ratios: 0 would mean infinitely many patches).
fn positive(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        Ok(_) => Err(format!("'{s}' must be a finite number above 0")),
        Err(_) => Err(format!("'{s}' is not a number")),
    }
}

/// A finite fraction in [0, 1].
fn fraction(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if (0.0..=1.0).contains(&x) => Ok(x),
        Ok(_) => Err(format!("'{s}' must be between 0 and 1")),
        Err(_) => Err(format!("'{s}' is not a number")),
    }
}

fn parse_fraction(s: &str) -> Result<f64, String> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|x| (0.0..=1.0).contains(x))
        .ok_or_else(|| format!("expected a fraction in [0, 1], got '{s}'"))
}

fn parse_tile(s: &str) -> Result<(u32, u32), String> {
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

/// An error already reported by rank 0: other ranks exit quietly.
#[derive(Debug)]
struct ReportedByRankZero;

/// The solve was interrupted: the outputs so far and a checkpoint are
/// written; the process exits with 130 (the shell's code for SIGINT).
#[derive(Debug)]
struct Interrupted(String);

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Interrupted {}

impl std::fmt::Display for ReportedByRankZero {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("failed (reported by rank 0)")
    }
}

impl std::error::Error for ReportedByRankZero {}

/// Writes one line to stderr in a single write, so that under mpirun other
/// processes' output cannot land in the middle of it.
fn print_error(line: &str) {
    use std::io::Write;
    let _ = std::io::stderr().write_all(format!("{line}\n").as_bytes());
}

/// The log, less what ranks other than 0 of this process (`--ranks`)
/// say below a warning: under mpirun those ranks' levels are set so.
struct RankLogger(env_logger::Logger);

impl log::Log for RankLogger {
    fn enabled(&self, metadata: &log::Metadata) -> bool {
        self.0.enabled(metadata)
            && (metadata.level() <= log::Level::Warn || !radiosity::parallel::quiet_rank())
    }

    fn log(&self, record: &log::Record) {
        if self.enabled(record.metadata()) {
            self.0.log(record);
        }
    }

    fn flush(&self) {
        self.0.flush();
    }
}

fn main() {
    let logger = env_logger::Builder::from_env(
        env_logger::Env::default().default_filter_or("warn,radiosity=info"),
    )
    .format_timestamp(None)
    .build();
    log::set_max_level(logger.filter());
    // Only fails if a logger was set before: none is.
    let _ = log::set_boxed_logger(Box::new(RankLogger(logger)));
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => run_render(args),
        Command::Scene {
            name,
            out,
            nodes,
            lights,
        } => write_scene(&name, out.as_deref(), nodes.as_deref(), &lights),
        Command::Compare { image, reference } => compare_images(&image, &reference),
        Command::Bench(args) => bench::run(args),
        Command::BenchReport(args) => bench::report(args),
        Command::Scaling(args) => scaling_report::run(args),
        Command::Accuracy { args, solve } => accuracy::run(args, solve),
        Command::Fuzz {
            cases,
            seed,
            flag_cases,
        } => fuzz(cases, seed, flag_cases),
    };
    if let Err(e) = result {
        if let Some(Interrupted(message)) = e.downcast_ref::<Interrupted>() {
            print_error(message);
            std::process::exit(130);
        }
        if e.downcast_ref::<ReportedByRankZero>().is_none() {
            print_error(&format!("error: {e:#}"));
        }
        std::process::exit(1);
    }
}

/// `radiosity fuzz`: see [`radiosity::fuzz`].
fn fuzz(cases: u64, seed: u64, flag_cases: u64) -> Result<()> {
    use radiosity::fuzz::{case, check, Outcome};
    // Thousands of renders: their progress lines would drown the findings.
    log::set_max_level(log::LevelFilter::Warn);
    let gpu: &'static Gpu = Box::leak(Box::new(Gpu::new()?));
    let base: serde_json::Value = serde_json::from_str(
        &scene::builtin_gltf("cornell").context("the Cornell box is built in")?,
    )?;
    let dir = tempfile::tempdir()?;
    let (mut rejected, mut rendered, mut failed, mut bugs) = (0u64, 0u64, 0u64, Vec::new());
    let start = Instant::now();
    for s in seed..seed + cases {
        let c = case(&base, s);
        match check(gpu, &c, dir.path(), std::time::Duration::from_secs(60)) {
            Outcome::Rejected(_) => rejected += 1,
            Outcome::Rendered => rendered += 1,
            Outcome::Failed(_) => failed += 1,
            bug => {
                eprintln!("BUG {}: {bug:?}", c.name);
                bugs.push(c.name);
            }
        }
        if (s - seed + 1) % 500 == 0 {
            eprintln!(
                "{} cases in {:.0} s: {rejected} rejected, {rendered} rendered, {failed} failed, {} bugs",
                s - seed + 1,
                start.elapsed().as_secs_f64(),
                bugs.len()
            );
        }
    }
    let (accepted, refused) = fuzz_flags(seed, flag_cases, &mut bugs);
    println!(
        "{cases} scene cases (seeds {seed}..{}): {rejected} rejected with an error, {rendered} rendered with finite reports, {failed} failed with an error; {flag_cases} flag lists: {accepted} accepted, {refused} refused; {} bugs ({:.0} s)",
        seed + cases,
        bugs.len(),
        start.elapsed().as_secs_f64()
    );
    if !bugs.is_empty() {
        anyhow::bail!(
            "{} cases panicked, hung or gave non-finite numbers",
            bugs.len()
        );
    }
    Ok(())
}

/// Flags the fuzzer passes, with odd values.
const FUZZ_FLAGS: [&str; 24] = [
    "--resolution",
    "--threshold",
    "--max-shots",
    "--patch-size",
    "--element-size",
    "--near-field-ratio",
    "--refine",
    "--raster-pieces",
    "--width",
    "--height",
    "--tile",
    "--exchange",
    "--form-factor",
    "--shading",
    "--shadow-rays",
    "--camera",
    "--exposure",
    "--checkpoint-every",
    "--max-patches-per-edge",
    "--coarse-resolution",
    "--coarse-below",
    "--overshoot",
    "--batch",
    "--ranks",
];
/// The values it gives them.
const FUZZ_VALUES: [&str; 19] = [
    "0",
    "-1",
    "1",
    "1e9",
    "NaN",
    "inf",
    "-inf",
    "0x0",
    "128x512",
    "1x1",
    "x",
    "",
    "1e-300",
    "4294967296",
    "hybrid",
    "sparse",
    "flat",
    "0.5",
    "65536x65536",
];

/// Random lists of real flags with odd values: parsing either accepts or
/// says why, and never panics. Returns (accepted, refused); a panic is a bug.
fn fuzz_flags(seed: u64, flag_cases: u64, bugs: &mut Vec<String>) -> (u64, u64) {
    let (mut accepted, mut refused) = (0u64, 0u64);
    let mut rng = radiosity::fuzz::Rng(seed ^ 0x00f1_a6f1_a65e_ed00);
    let mut next = move |n: usize| rng.below(n);
    for _ in 0..flag_cases {
        let mut argv = vec!["radiosity".to_string(), "render".into(), "cornell".into()];
        for _ in 0..1 + next(4) {
            argv.push(FUZZ_FLAGS[next(FUZZ_FLAGS.len())].into());
            argv.push(FUZZ_VALUES[next(FUZZ_VALUES.len())].into());
        }
        let outcome = std::panic::catch_unwind(|| Cli::try_parse_from(&argv).is_ok());
        match outcome {
            Ok(true) => accepted += 1,
            Ok(false) => refused += 1,
            Err(_) => {
                eprintln!("BUG: flags {argv:?} panicked");
                bugs.push(argv.join(" "));
            }
        }
    }
    (accepted, refused)
}

fn compare_images(image: &Path, reference: &Path) -> Result<()> {
    let read = |p: &Path| output::read_exr(p).with_context(|| format!("reading {}", p.display()));
    let (a, b) = (read(image)?, read(reference)?);
    if (a.0, a.1) != (b.0, b.1) {
        anyhow::bail!(
            "{} is {}x{} but {} is {}x{}",
            image.display(),
            a.0,
            a.1,
            reference.display(),
            b.0,
            b.1
        );
    }
    let s = radiosity::compare::smape(&a.2, &b.2, a.0 as usize, a.1 as usize);
    println!("SMAPE {:.2} % (interior 4x4 blocks)", s * 100.0);
    Ok(())
}

fn write_scene(
    name: &str,
    out: Option<&Path>,
    nodes: Option<&Path>,
    lights: &radiosity::scene::light::LightArgs,
) -> Result<()> {
    if let Some(out) = out {
        let text = scene::builtin_gltf(name).with_context(|| {
            format!(
                "no built-in scene '{name}' (built-ins: {})",
                scene::builtin_names().join(", ")
            )
        })?;
        output::write_atomic(out, text.as_bytes())?;
        eprintln!("wrote {}", out.display());
    }
    if let Some(path) = nodes {
        let mut scene = scene::open(name)?;
        lights.apply(&mut scene);
        accuracy::export_for_pathtracer(&scene, path)?;
        eprintln!("wrote {}", path.display());
    }
    if out.is_none() && nodes.is_none() {
        anyhow::bail!("nothing to write: give --out and/or --nodes");
    }
    Ok(())
}

/// A progress display: a bar on a terminal, a log line every few seconds otherwise.
pub struct Reporter {
    bar: Option<ProgressBar>,
    last_log: Instant,
    threshold: f64,
}

impl Reporter {
    /// A reporter for a solve that stops at `threshold`.
    pub fn new(max_shots: u64, threshold: f64) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = ProgressBar::new(max_shots);
            let style = ProgressStyle::with_template(
                "{spinner} shots {pos} | unshot {msg} | {elapsed_precise}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_spinner());
            bar.set_style(style);
            bar.enable_steady_tick(Duration::from_millis(200));
            bar
        });
        Self {
            bar,
            last_log: Instant::now(),
            threshold,
        }
    }

    /// Shows progress.
    pub fn update(&mut self, p: &Progress) {
        match &self.bar {
            Some(bar) => {
                bar.set_position(p.shots);
                bar.set_message(format!(
                    "{:.2e} (stop at {:.0e})",
                    p.unshot_fraction, self.threshold
                ));
            }
            None if self.last_log.elapsed() >= Duration::from_secs(5) => {
                self.last_log = Instant::now();
                log::info!(
                    "shot {}: unshot fraction {:.3e}, {:.1} s",
                    p.shots,
                    p.unshot_fraction,
                    p.elapsed.as_secs_f64()
                );
            }
            None => {}
        }
    }

    /// Removes the bar.
    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// Where the outputs of `args` go.
fn output_paths(args: &RenderArgs) -> OutputPaths {
    let stem = output_stem(&args.scene);
    OutputPaths {
        image: Some(
            args.image
                .clone()
                .unwrap_or_else(|| args.out_dir.join(format!("{stem}.exr"))),
        ),
        exposure: args.exposure,
        bake: args.bake.clone(),
        report: args
            .report
            .clone()
            .unwrap_or_else(|| args.out_dir.join(format!("{stem}.json"))),
    }
}

/// Where `args`' solve saves its state.
fn checkpoint_path(args: &RenderArgs) -> PathBuf {
    args.checkpoint.clone().unwrap_or_else(|| {
        args.out_dir
            .join(format!("{}.ckpt", output_stem(&args.scene)))
    })
}

/// Rank 0's check, before the solve, that every output of `args` and its
/// saved state can be written: a bad place is found in a second, not after
/// hours of solving whose results it would lose.
fn check_outputs(args: &RenderArgs) -> Result<()> {
    output_paths(args).check(args.width != 0)?;
    radiosity::output::check_writable(&checkpoint_path(args))?;
    Ok(())
}

/// The render options of `args`, with `interrupt` to stop the solve.
fn render_options(
    args: &RenderArgs,
    interrupt: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> Result<RenderOptions> {
    let mut opts = args.solve.options();
    opts.width = args.width;
    opts.height = args.height;
    opts.shading = args.shading;
    opts.shadow_rays = args.shadow_rays;
    opts.ambient = if args.no_ambient {
        radiosity::settings::AmbientTerm::Off
    } else {
        args.ambient
    };
    opts.wireframe = args.wireframe;
    opts.tile = args.tile;
    opts.exchange = args.exchange;
    opts.checkpoint = Some(CheckpointPlan {
        path: checkpoint_path(args),
        every: args
            .checkpoint_every
            .map(std::time::Duration::from_secs_f32),
    });
    if let Some(path) = &args.resume {
        opts.resume = Some(std::sync::Arc::new(Checkpoint::read(path)?));
    }
    opts.interrupt = Some(interrupt);
    Ok(opts)
}

/// SIGINT and SIGTERM (mpirun forwards them to every rank) end the solve
/// after the current shot, saving its state and writing what it has.
fn handle_signals() -> Result<std::sync::Arc<std::sync::atomic::AtomicBool>> {
    let interrupt = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, interrupt.clone())
            .with_context(|| format!("cannot handle signal {signal}"))?;
    }
    Ok(interrupt)
}

fn run_render(args: RenderArgs) -> Result<()> {
    // Registered first, so no signal finds the default handler.
    let interrupt = handle_signals()?;
    launch::share_cores_between_ranks();
    let mpi = MpiComm::init();
    let single = Single::default();
    let comm: &dyn Collectives = match &mpi {
        Some(c) => c,
        None => &single,
    };
    let (rank, ranks) = (comm.rank(), comm.size());
    launch::check_world(ranks)?;
    if ranks > 1 && args.solve.ranks > 1 {
        anyhow::bail!(
            "--ranks {} under mpirun ({ranks} ranks): each process is one rank there; leave --ranks at 1",
            args.solve.ranks
        );
    }
    if rank > 0 {
        log::set_max_level(log::LevelFilter::Warn);
    }
    // Every rank loads the scene and opens a device; any failure ends all of
    // them, with rank 0 reporting which rank failed and why.
    let t = Instant::now();
    let setup = scene::open(&args.scene)
        .and_then(|mut s| {
            if let Some(name) = &args.camera {
                s.use_camera(name)?;
            }
            args.lights.apply(&mut s);
            s.check_lit()?;
            Ok(s)
        })
        .map_err(anyhow::Error::from)
        .and_then(|s| {
            if rank == 0 {
                check_outputs(&args)?;
            }
            Ok(s)
        })
        .and_then(|s| Ok((s, Gpu::new()?)))
        .map_err(|e| format!("{e:#}"));
    let load_time = t.elapsed();
    let (scene, gpu) = match launch::start_together(comm, setup) {
        Ok(x) => x,
        Err(e) => {
            if rank == 0 {
                print_error(&format!("error: {e}"));
            }
            return Err(ReportedByRankZero.into());
        }
    };
    if rank == 0 {
        let ranks_note = if ranks > 1 {
            format!(", {ranks} ranks")
        } else {
            String::new()
        };
        log::info!("device: {}{ranks_note}", gpu.describe());
    }
    let opts = render_options(&args, interrupt)?;
    let mut reporter = (rank == 0).then(|| Reporter::new(opts.stop.max_shots, opts.stop.threshold));
    let mut show = |p: &Progress| {
        if let Some(r) = reporter.as_mut() {
            r.update(p)
        }
    };
    let in_process = args.solve.ranks as usize;
    let rendered = if in_process > 1 {
        render_ranks(&gpu, &scene, &opts, in_process, load_time, &mut show).map(Some)
    } else {
        render_on(&gpu, &scene, &opts, comm, load_time, &mut show)
    };
    if let Some(r) = &reporter {
        r.finish();
    }
    let rendered = match rendered {
        Ok(r) => r,
        // A failure mid-solve is seen by one rank only: end every rank now.
        Err(e) if ranks > 1 => {
            print_error(&format!("error: rank {rank}: {e:#}"));
            comm.abort(1)
        }
        Err(e) => return Err(e.into()),
    };
    match rendered {
        Some(rendered) => write_rendered(&args, &scene, rendered),
        None => Ok(()),
    }
}

/// Rank 0's outputs: the image, the bake and the report.
fn write_rendered(args: &RenderArgs, scene: &scene::Scene, mut rendered: Rendered) -> Result<()> {
    let r = &rendered.report;
    log::info!(
        "{} shots, unshot fraction {:.3e}, solve {:.2} s (median shot {:.2} ms)",
        r.shots,
        r.unshot_fraction,
        r.timings.solve,
        r.timings.median_shot_ms
    );
    if rendered.image.is_none() {
        eprintln!("no image (--width 0)");
    }
    let image = rendered
        .image
        .as_ref()
        .map(|(w, h, pixels)| (*w, *h, &pixels[..]));
    let written = write_outputs(
        &output_paths(args),
        scene,
        &rendered.mesh,
        &rendered.radiosity,
        image,
        &mut rendered.report,
    )
    .map_err(|e| match e {
        // The binary names the scene as it was given.
        WriteError::NonFinite { what, .. } => anyhow::anyhow!(
            "{}: the solution has a non-finite number in {what}; no report written",
            args.scene
        ),
        e => e.into(),
    })?;
    for line in written.lines() {
        eprintln!("{line}");
    }
    if rendered.interrupted {
        let why = rendered.report.warnings.last().cloned().unwrap_or_default();
        return Err(Interrupted(format!("{}: {why}", args.scene)).into());
    }
    Ok(())
}
