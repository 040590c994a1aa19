//! `radiosity bench`: shot timings on built-in scenes, printed as a Markdown
//! table (the README's "Performance" section is this output).

use crate::SolveArgs;
use anyhow::Result;
use clap::Args;
use radiosity::gpu::Gpu;
use radiosity::render::render;
use radiosity::report::Report;
use radiosity::{output, scene};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Options of `radiosity bench`.
#[derive(Args)]
pub struct BenchArgs {
    /// Scenes to time (files or built-in names), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "cornell,cubes-8")]
    scenes: Vec<String>,
    /// Shots to time per scene.
    #[arg(long, default_value_t = 200)]
    shots: u64,
    /// Also time the Cornell box's whole solve to this unshot fraction (0: skip).
    #[arg(long, default_value_t = 1e-3)]
    converge: f64,
    /// Write the raw reports here as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    #[command(flatten)]
    solve: SolveArgs,
}

fn row(name: &str, r: &Report) -> String {
    let t = &r.timings;
    let per = |s: f64| s / r.shots.max(1) as f64 * 1e3;
    format!(
        "| {name} | {} | {} | {} | {} | {:.2} | {:.0} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
        r.counts.polygons,
        r.counts.patches,
        r.counts.elements,
        r.shots,
        t.median_shot_ms,
        r.shots as f64 / t.solve.max(1e-9),
        per(t.bounds),
        per(t.rasterise),
        per(t.read_back),
        per(t.sum_form_factors),
        per(t.update + t.select_shooter),
    )
}

/// Runs the benchmark.
pub fn run(args: BenchArgs) -> Result<()> {
    let gpu = Gpu::new()?;
    println!(
        "device: {}, hemisphere {}\n",
        gpu.describe(),
        args.solve.resolution
    );
    println!("| scene | polygons | patches | elements | shots | median shot ms | shots/s | bounds ms | raster ms | readback ms | sum F ms | update ms |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut reports = Vec::new();
    for name in &args.scenes {
        let t = Instant::now();
        let scene = scene::open(name)?;
        let mut opts = args.solve.options();
        opts.width = 0;
        opts.stop.threshold = 0.0;
        opts.stop.max_shots = args.shots;
        let r = render(&gpu, &scene, &opts, t.elapsed(), &mut |_| {})?;
        println!("{}", row(name, &r.report));
        reports.push(r.report);
    }
    if args.converge > 0.0 {
        let scene = scene::open("cornell")?;
        let mut opts = args.solve.options();
        opts.width = 0;
        opts.stop.threshold = args.converge;
        let r = render(&gpu, &scene, &opts, Duration::ZERO, &mut |_| {})?;
        println!(
            "\ncornell to unshot fraction {:.0e}: {} shots, {:.2} s solve ({:.2} s with setup)",
            args.converge,
            r.report.shots,
            r.report.timings.solve,
            r.report.timings.solve + r.report.timings.setup + r.report.timings.mesh
        );
        reports.push(r.report);
    }
    if let Some(path) = &args.json {
        output::write_json(path, &reports)?;
    }
    Ok(())
}
