//! `radiosity`: the command-line renderer.

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use radiosity::gpu::{Gpu, Shading};
use radiosity::hemisphere::Resolution;
use radiosity::mesh::MeshSettings;
use radiosity::render::{render, Progress, RenderOptions};
use radiosity::solver::StopRule;
use radiosity::{output, scene};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

mod bench;

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
        out: PathBuf,
    },
    /// Time shots on the built-in scenes and print a table (see README "Performance").
    Bench(bench::BenchArgs),
}

/// Settings shared by `render` and `bench`.
#[derive(Args, Clone)]
pub struct SolveArgs {
    /// Hemisphere resolution R_phi x R_theta (polar rows x azimuth columns).
    #[arg(long, default_value = "128x512")]
    pub resolution: Resolution,
    /// Stop when the unshot power is at most this fraction of the emitted power.
    #[arg(long, default_value_t = 1e-3)]
    threshold: f64,
    /// Stop after this many shots even if the threshold is not reached.
    #[arg(long, default_value_t = 100_000)]
    max_shots: u64,
    /// Patch edge length in metres, for every polygon (default: the node's
    /// extras.radiosity, else automatic: see --near-field-ratio).
    #[arg(long)]
    patch_size: Option<f32>,
    /// Element edge length in metres, for every polygon (default: the node's
    /// extras.radiosity, else 2 x 2 elements per patch).
    #[arg(long)]
    element_size: Option<f32>,
    /// Automatic subdivision: patch size as a fraction of the distance to the
    /// nearest polygon that faces it (smaller: more accurate, slower).
    #[arg(long, default_value_t = 0.2)]
    near_field_ratio: f32,
    /// Cap on patches along one polygon edge (automatic subdivision).
    #[arg(long, default_value_t = 32)]
    max_patches_per_edge: u32,
    /// Tessellation control: cut each element into N x N pieces for
    /// rasterisation. The per-cell test is exact at any N; larger N gives near,
    /// large elements tighter bounds (less fill) at the cost of more vertices.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=16))]
    raster_split: u32,
}

impl SolveArgs {
    /// The render options these flags describe.
    pub fn options(&self) -> RenderOptions {
        RenderOptions {
            resolution: self.resolution,
            stop: StopRule {
                threshold: self.threshold,
                max_shots: self.max_shots,
            },
            mesh: MeshSettings {
                patch_size: self.patch_size,
                element_size: self.element_size,
                near_field_ratio: self.near_field_ratio,
                max_patches_per_edge: self.max_patches_per_edge,
                ..MeshSettings::default()
            },
            raster_split: self.raster_split,
            ..RenderOptions::default()
        }
    }
}

#[derive(Args)]
struct RenderArgs {
    /// A .gltf/.glb file, or a built-in scene: cornell, cubes-N (N^3 cubes in a
    /// lit room), cubes-b1, cubes-b2, cubes-b3 (the paper's benchmark scenes).
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
    /// Image width in pixels.
    #[arg(long, default_value_t = 512)]
    width: u32,
    /// Image height in pixels (default: from the camera's aspect ratio).
    #[arg(long)]
    height: Option<u32>,
    /// Shading of the image: smooth (interpolated) or flat (one value per element).
    #[arg(long, value_enum, default_value = "smooth")]
    shading: Shading,
    /// Leave the ambient term out of the image (it never enters the report).
    #[arg(long)]
    no_ambient: bool,
    /// PNG preview exposure adjustment in stops, on top of automatic exposure.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    exposure: f32,
    #[command(flatten)]
    solve: SolveArgs,
}

fn main() {
    env_logger::Builder::from_env(
        env_logger::Env::default().default_filter_or("warn,radiosity=info"),
    )
    .format_timestamp(None)
    .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => run_render(args),
        Command::Scene { name, out } => write_scene(&name, &out),
        Command::Bench(args) => bench::run(args),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn write_scene(name: &str, out: &Path) -> Result<()> {
    let text = scene::builtin_gltf(name).with_context(|| {
        format!(
            "no built-in scene '{name}' (built-ins: {})",
            scene::builtin_names().join(", ")
        )
    })?;
    output::write_atomic(out, text.as_bytes())?;
    eprintln!("wrote {}", out.display());
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

fn stem(scene: &str) -> String {
    Path::new(scene)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "render".into())
}

fn run_render(args: RenderArgs) -> Result<()> {
    let t = Instant::now();
    let scene = scene::open(&args.scene)?;
    let load_time = t.elapsed();
    let image_path = args
        .image
        .clone()
        .unwrap_or_else(|| args.out_dir.join(format!("{}.exr", stem(&args.scene))));
    let report_path = args
        .report
        .clone()
        .unwrap_or_else(|| args.out_dir.join(format!("{}.json", stem(&args.scene))));
    let gpu = Gpu::new()?;
    log::info!("device: {}", gpu.describe());
    let mut opts = args.solve.options();
    opts.width = args.width;
    opts.height = args.height;
    opts.shading = args.shading;
    opts.ambient = !args.no_ambient;
    let mut reporter = Reporter::new(opts.stop.max_shots, opts.stop.threshold);
    let rendered = render(&gpu, &scene, &opts, load_time, &mut |p| reporter.update(p));
    reporter.finish();
    let rendered = rendered?;
    let r = &rendered.report;
    log::info!(
        "{} shots, unshot fraction {:.3e}, solve {:.2} s (median shot {:.2} ms)",
        r.shots,
        r.unshot_fraction,
        r.timings.solve,
        r.timings.median_shot_ms
    );
    if let Some((w, h, pixels)) = &rendered.image {
        let png = output::write_image(&image_path, *w, *h, pixels, args.exposure)?;
        eprintln!("wrote {} and {}", image_path.display(), png.display());
    }
    output::write_json(&report_path, &rendered.report)?;
    eprintln!("wrote {}", report_path.display());
    Ok(())
}
