//! `radiosity-lab`: the project's measuring tools (see the crate's
//! documentation). Users render with `radiosity`; this binary is for the
//! benchmarks, charts and checks that back the README's figures.

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use radiosity::cli::{RenderArgs, SolveArgs};
use radiosity::gpu::Gpu;
use radiosity::scene;
use radiosity_lab::{accuracy, bench, charted, scaling_report};
use std::time::Instant;

/// The radiosity renderer's lab: benchmarks, accuracy charts, the
/// performance model and the fuzzer.
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
    /// Time shots on the built-in scenes and print a table (see docs/notebook/shot-speed.md "Performance").
    Bench(radiosity_lab::bench::BenchArgs),
    /// Turn render reports (e.g. from scripts/bench-mpi.sh) into a CSV and charts.
    BenchReport(radiosity_lab::bench::ReportArgs),
    /// Fit the performance model to calibration runs (scripts/calibrate-scaling.sh),
    /// check it against them and redraw the paper's figures 8-12 for up to
    /// 1024 ranks (docs/scaling.md).
    Scaling(radiosity_lab::scaling_report::ScalingArgs),
    /// Chart error against solve time for every method option and resolution,
    /// beside a path tracer (Mitsuba 3), to docs/bench/accuracy.
    Accuracy {
        #[command(flatten)]
        args: radiosity_lab::accuracy::AccuracyArgs,
        #[command(flatten)]
        solve: SolveArgs,
    },
    /// Chart image error against wall time, this renderer beside the path
    /// tracer, from scripts/image-time.sh's rows (docs/bench/image-time).
    ImageTime(radiosity_lab::image_time::ImageTimeArgs),
    /// Robustness run: broken glTF/GLB files made from the Cornell box, each
    /// loaded and rendered small, and random `render` flag lists parsed; exits
    /// non-zero on any panic, hang or non-finite report (docs/tests.md "Reliability").
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

/// `radiosity render`'s flags alone, for the flag fuzzer.
#[derive(Parser)]
struct RenderCli {
    #[command(flatten)]
    args: RenderArgs,
}

fn main() -> Result<()> {
    radiosity::gpu::leave_out_device_select_layer();
    env_logger::Builder::from_env(
        env_logger::Env::default().default_filter_or("warn,radiosity=info"),
    )
    .format_timestamp(None)
    .init();
    match Cli::parse().command {
        Command::Bench(args) => bench::run(args),
        Command::ImageTime(args) => radiosity_lab::image_time::run(&args),
        Command::BenchReport(args) => bench::report(args),
        Command::Scaling(args) => scaling_report::run(args),
        Command::Accuracy { args, .. } if !args.reports.is_empty() => charted::from_args(&args),
        Command::Accuracy { args, solve } => accuracy::run(args, solve),
        Command::Fuzz {
            cases,
            seed,
            flag_cases,
        } => fuzz(cases, seed, flag_cases),
    }
}

/// `radiosity-lab fuzz`: see [`radiosity_lab::fuzz`].
fn fuzz(cases: u64, seed: u64, flag_cases: u64) -> Result<()> {
    use radiosity_lab::fuzz::{case, check, Outcome};
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
const FUZZ_FLAGS: [&str; 23] = [
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
    let mut rng = radiosity::rng::Rng(seed ^ 0x00f1_a6f1_a65e_ed00);
    let mut next = move |n: usize| rng.below(n);
    for _ in 0..flag_cases {
        let mut argv = vec!["radiosity-render".to_string(), "cornell".into()];
        for _ in 0..1 + next(4) {
            argv.push(FUZZ_FLAGS[next(FUZZ_FLAGS.len())].into());
            argv.push(FUZZ_VALUES[next(FUZZ_VALUES.len())].into());
        }
        let outcome = std::panic::catch_unwind(|| RenderCli::try_parse_from(&argv).is_ok());
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
