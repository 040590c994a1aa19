//! `radiosity`: the command-line renderer. Its flags are the library's
//! `cli` module; the lab's tools (benchmarks, charts, the performance model,
//! the fuzzer) are the `radiosity-lab` binary.

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use radiosity::checkpoint::Checkpoint;
use radiosity::cli::RenderArgs;
use radiosity::comm::MpiComm;
use radiosity::gpu::Gpu;
use radiosity::parallel::{Collectives, Single};
use radiosity::render::write::{output_stem, write_outputs, OutputPaths, WriteError};
use radiosity::render::{
    render_on, render_ranks, CheckpointPlan, Progress, RenderOptions, Rendered,
};
use radiosity::{launch, output, scene};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Progressive radiosity with equal-angle hemisphere form factors rasterised by wgpu.
#[derive(Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

// Parsed once per run: the size of its largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
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
    /// over interior 4x4 blocks (docs/method/yardstick.md).
    Compare {
        /// The image to score.
        image: PathBuf,
        /// The reference (e.g. `scripts/reference.py --image`).
        reference: PathBuf,
    },
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
    // Headless: no window system to ask which GPU drives a display.
    radiosity::gpu::leave_out_device_select_layer();
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
        lights.apply(&mut scene)?;
        radiosity::export::write_nodes(&scene, path)?;
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
    opts.background = !args.no_background;
    opts.gather = args.gather;
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
    let (scene, gpu, load_time) = open_everywhere(&args, comm)?;
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

/// Every rank loads the scene and opens a device; any failure ends all of
/// them, with rank 0 reporting which rank failed and why (before any work,
/// rank 0 also checks that every output can be written). Returns them and
/// this rank's load time.
fn open_everywhere(
    args: &RenderArgs,
    comm: &dyn Collectives,
) -> Result<(scene::Scene, Gpu, Duration)> {
    let (rank, ranks) = (comm.rank(), comm.size());
    let t = Instant::now();
    let setup = scene::open(&args.scene)
        .and_then(|mut s| {
            if let Some(name) = &args.camera {
                s.use_camera(name)?;
            }
            args.lights.apply(&mut s)?;
            s.check_lit()?;
            Ok(s)
        })
        .map_err(anyhow::Error::from)
        .and_then(|s| {
            if rank == 0 {
                check_outputs(args)?;
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
    Ok((scene, gpu, load_time))
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
