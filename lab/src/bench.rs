//! `radiosity-lab bench`: shot timings on built-in scenes, printed as a Markdown
//! table (the notebook's shot measurements, docs/notebook/, are this output).

use anyhow::Result;
use clap::Args;
use radiosity::cli::SolveArgs;
use radiosity::gpu::Gpu;
use radiosity::render::render_ranks;
use radiosity::report::Report;
use radiosity::{output, scene};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Options of `radiosity-lab bench`.
#[derive(Args)]
pub struct BenchArgs {
    /// Scenes to time (files or built-in names), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "cornell,cubes-8")]
    scenes: Vec<String>,
    /// Shots to time per scene (every one drawing its hemisphere unless
    /// --transport-below is given).
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
        "| {name} | {} | {} | {} | {} | {:.2} | {:.2} | {:.0} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
        r.counts.polygons,
        r.counts.patches,
        r.counts.elements,
        r.shots,
        t.median_shot_ms,
        t.mean_shot_ms,
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
    // The timings are written last: a bad place fails now, not after them.
    if let Some(path) = &args.json {
        output::check_writable(path)?;
    }
    let gpu = Gpu::new()?;
    // Ranks of this process and batches change what a shot's time means
    // (a batch's time over its rows; the phase columns are rank 0's).
    let ranks = args.solve.ranks as usize;
    let mode = match (args.solve.ranks, args.solve.batch) {
        (1, 1) => String::new(),
        (1, b) => format!(", batches of {b}"),
        (r, b) => format!(", {r} ranks in this process, batches of {b} (phase columns: rank 0's)"),
    };
    println!(
        "device: {}, hemisphere {}{mode}\n",
        gpu.describe(),
        args.solve.resolution
    );
    println!("| scene | polygons | patches | elements | shots | median shot ms | mean shot ms | shots/s | bounds ms | raster ms | readback ms | sum F ms | update ms |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut reports = Vec::new();
    for name in &args.scenes {
        let t = Instant::now();
        let scene = scene::open(name)?;
        let mut opts = args.solve.options();
        opts.width = 0;
        opts.stop.threshold = 0.0;
        opts.stop.max_shots = args.shots;
        // It times shots that draw: weak shooters along the transport (by
        // default in big meshes) only when asked for.
        opts.transport_below.get_or_insert(0.0);
        let r = render_ranks(&gpu, &scene, &opts, ranks, t.elapsed(), &mut |_| {})?;
        println!("{}", row(name, &r.report));
        reports.push(r.report);
    }
    if args.converge > 0.0 {
        let scene = scene::open("cornell")?;
        let mut opts = args.solve.options();
        opts.width = 0;
        opts.stop.threshold = args.converge;
        let r = render_ranks(&gpu, &scene, &opts, ranks, Duration::ZERO, &mut |_| {})?;
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

/// Options of `radiosity-lab bench-report`.
#[derive(Args)]
pub struct ReportArgs {
    /// Report JSON files from `radiosity render` runs (see scripts/bench-mpi.sh).
    #[arg(required = true)]
    reports: Vec<PathBuf>,
    /// Directory for results.csv and the charts.
    #[arg(long, default_value = "docs/bench")]
    out: PathBuf,
}

/// One run, flattened for the CSV and the charts.
struct Run {
    /// File stem: runs named `sweep-*` are the resolution and tile sweeps.
    tag: String,
    scene: String,
    ranks: f64,
    exchange: String,
    tile: String,
    resolution: String,
    shots: f64,
    ms_per_shot: f64,
    bytes_per_shot: f64,
    formula_bytes: Option<f64>,
    eps: [f64; 3],
}

fn run_of(path: &std::path::Path) -> Result<Run> {
    use anyhow::Context;
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a report", path.display()))?;
    let p = &v["parallel"];
    let num = |x: &serde_json::Value| {
        x.as_f64()
            .with_context(|| format!("{}: missing number", path.display()))
    };
    let shots = num(&v["shots"])?;
    let res = &v["settings"]["resolution"];
    Ok(Run {
        tag: path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        scene: v["scene"].as_str().unwrap_or("?").to_string(),
        ranks: num(&p["ranks"])?,
        exchange: p["exchange"].as_str().unwrap_or("?").to_string(),
        tile: format!("{}x{}", p["tile"][0], p["tile"][1]),
        resolution: format!("{}x{}", res["rows"], res["cols"]),
        shots,
        ms_per_shot: num(&v["timings"]["solve"])? / shots.max(1.0) * 1e3,
        bytes_per_shot: num(&p["measured_bytes_per_shot"])?,
        formula_bytes: p["formula_bytes_per_shot"].as_f64(),
        eps: [
            num(&p["load_balance"]["mean"])?,
            num(&p["load_balance"]["max"])?,
            num(&p["load_balance"]["min"])?,
        ],
    })
}

/// Named curves of (x, y) points.
pub(crate) type Series = Vec<(String, Vec<(f64, f64)>)>;

pub(crate) fn draw_chart<DB: plotters::prelude::DrawingBackend>(
    root: plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    axes: (&str, &str),
    series: &Series,
    log_y: bool,
    legend: plotters::chart::SeriesLabelPosition,
) -> Result<(), String> {
    use plotters::prelude::*;
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let pts = series.iter().flat_map(|s| s.1.iter());
    let x1 = pts.clone().map(|p| p.0).fold(1.0f64, f64::max);
    let (y0, y1) = pts
        .map(|p| p.1)
        .fold((f64::MAX, 0.0f64), |(a, b), y| (a.min(y), b.max(y)));
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut builder = ChartBuilder::on(&root);
    builder
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70);
    let x_range = 0.0..x1 * 1.05;
    macro_rules! body {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(axes.0)
                .y_desc(axes.1)
                .draw()
                .map_err(|x| e(&x))?;
            for (i, (name, points)) in series.iter().enumerate() {
                let color = Palette99::pick(i).mix(0.95);
                chart
                    .draw_series(LineSeries::new(points.clone(), color.stroke_width(2)))
                    .map_err(|x| e(&x))?
                    .label(name.as_str())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                    });
                chart
                    .draw_series(points.iter().map(|&p| Circle::new(p, 3, color.filled())))
                    .map_err(|x| e(&x))?;
            }
            chart
                .configure_series_labels()
                .position(legend.clone())
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .draw()
                .map_err(|x| e(&x))?;
        }};
    }
    if log_y && y0 > 0.0 {
        body!(builder
            .build_cartesian_2d(x_range, (y0 * 0.8..y1 * 1.25).log_scale())
            .map_err(|x| e(&x))?);
    } else {
        body!(builder
            .build_cartesian_2d(x_range, 0.0..y1.max(1e-9) * 1.1)
            .map_err(|x| e(&x))?);
    }
    root.present().map_err(|x| e(&x))
}

/// Writes `<stem>.svg` and `<stem>.png`.
pub(crate) fn chart(
    out: &std::path::Path,
    stem: &str,
    title: &str,
    axes: (&str, &str),
    series: &Series,
    log_y: bool,
) -> Result<()> {
    chart_at(
        out,
        stem,
        title,
        axes,
        series,
        log_y,
        plotters::chart::SeriesLabelPosition::UpperRight,
    )
}

/// [`chart`] with the legend at `legend` (where the curves leave room).
pub(crate) fn chart_at(
    out: &std::path::Path,
    stem: &str,
    title: &str,
    axes: (&str, &str),
    series: &Series,
    log_y: bool,
    legend: plotters::chart::SeriesLabelPosition,
) -> Result<()> {
    if series.iter().all(|s| s.1.is_empty()) {
        return Ok(());
    }
    svg_and_png!(out, stem, (900, 540), |root| draw_chart(
        root,
        title,
        axes,
        series,
        log_y,
        legend.clone()
    ));
    Ok(())
}

/// Turns render reports into docs/bench/results.csv and charts (the paper's
/// figures 8-12 for this machine).
pub fn report(args: ReportArgs) -> Result<()> {
    let mut runs = args
        .reports
        .iter()
        .map(|p| run_of(p))
        .collect::<Result<Vec<_>>>()?;
    runs.sort_by(|a, b| {
        (
            &a.scene,
            &a.exchange,
            a.ranks as u64,
            &a.resolution,
            &a.tile,
        )
            .cmp(&(
                &b.scene,
                &b.exchange,
                b.ranks as u64,
                &b.resolution,
                &b.tile,
            ))
    });
    std::fs::create_dir_all(&args.out)?;
    let csv = results_csv(&runs);
    output::write_atomic(&args.out.join("results.csv"), csv.as_bytes())?;
    for scene in scene_names(&runs) {
        scene_charts(&args.out, &runs, scene)?;
    }
    sweep_charts(&args.out, &runs)?;
    eprintln!(
        "wrote {} runs to {}",
        runs.len(),
        args.out.join("results.csv").display()
    );
    Ok(())
}

/// `docs/bench/results.csv`'s text: one line per run.
fn results_csv(runs: &[Run]) -> String {
    let mut csv = String::from("scene,ranks,exchange,tile,resolution,shots,ms_per_shot,bytes_per_shot,formula_bytes_per_shot,eps_mean,eps_max,eps_min\n");
    for r in runs {
        csv += &format!(
            "{},{},{},{},{},{},{:.3},{:.0},{},{:.4},{:.4},{:.4}\n",
            r.scene,
            r.ranks,
            r.exchange,
            r.tile,
            r.resolution,
            r.shots,
            r.ms_per_shot,
            r.bytes_per_shot,
            r.formula_bytes.map_or(String::new(), |f| format!("{f:.0}")),
            r.eps[0],
            r.eps[1],
            r.eps[2]
        );
    }
    csv
}

/// The scenes of `runs`, in order, once each.
fn scene_names(runs: &[Run]) -> Vec<&str> {
    let mut scenes: Vec<&str> = runs.iter().map(|r| r.scene.as_str()).collect();
    scenes.dedup();
    scenes
}

/// One scene's charts: time and bytes per shot against ranks per exchange,
/// and the load balance.
fn scene_charts(out: &std::path::Path, runs: &[Run], scene: &str) -> Result<()> {
    let default = |r: &&Run| {
        !r.tag.starts_with("sweep-")
            && r.resolution == "128x512"
            && (r.tile == "1x1" || r.ranks == 1.0)
    };
    let of_scene: Vec<&Run> = runs
        .iter()
        .filter(|r| r.scene == scene)
        .filter(default)
        .collect();
    let by_exchange = |value: &dyn Fn(&Run) -> f64, multi_only: bool| -> Series {
        ["hemispheres", "form-factors", "sparse"]
            .iter()
            .map(|ex| {
                // One rank runs no exchange: its point belongs to every series.
                let mut pts: Vec<(f64, f64)> = of_scene
                    .iter()
                    .filter(|r| r.exchange == *ex || (r.ranks == 1.0 && !multi_only))
                    .map(|r| (r.ranks, value(r)))
                    .collect();
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                (ex.to_string(), pts)
            })
            .collect()
    };
    let name = scene.replace(['/', '.'], "_");
    chart(
        out,
        &format!("time-{name}"),
        &format!("{scene}: time per shot"),
        ("ranks", "ms per shot"),
        &by_exchange(&|r| r.ms_per_shot, false),
        false,
    )?;
    chart(
        out,
        &format!("bytes-{name}"),
        &format!("{scene}: bytes received per rank per shot"),
        ("ranks", "bytes"),
        &by_exchange(&|r| r.bytes_per_shot, true),
        true,
    )?;
    let hemis: Vec<&&Run> = of_scene
        .iter()
        .filter(|r| r.exchange == "hemispheres")
        .collect();
    let eps: Series = ["mean", "max", "min"]
        .iter()
        .enumerate()
        .map(|(k, n)| {
            (
                format!("epsilon {n}"),
                hemis.iter().map(|r| (r.ranks, r.eps[k])).collect(),
            )
        })
        .collect();
    chart(
        out,
        &format!("balance-{name}"),
        &format!("{scene}: load balance (hemispheres)"),
        ("ranks", "T_min / T_max"),
        &eps,
        false,
    )?;
    Ok(())
}

/// The sweeps: load balance against resolution (R_phi) and tile size (cells).
fn sweep_charts(out: &std::path::Path, runs: &[Run]) -> Result<()> {
    let sweep = |prefix: &str, x: &dyn Fn(&Run) -> f64| -> Series {
        let mut pts: Vec<&Run> = runs.iter().filter(|r| r.tag.starts_with(prefix)).collect();
        pts.sort_by(|a, b| x(a).total_cmp(&x(b)));
        ["mean", "max", "min"]
            .iter()
            .enumerate()
            .map(|(k, n)| {
                (
                    format!("epsilon {n}"),
                    pts.iter().map(|r| (x(r), r.eps[k])).collect(),
                )
            })
            .collect()
    };
    let dims = |s: &str| -> (f64, f64) {
        let mut it = s.split('x').map(|v| v.parse::<f64>().unwrap_or(0.0));
        (it.next().unwrap_or(0.0), it.next().unwrap_or(0.0))
    };
    chart(
        out,
        "balance-resolution",
        "load balance against hemisphere resolution",
        ("R_phi (R_theta = 4 R_phi)", "T_min / T_max"),
        &sweep("sweep-res-", &|r| dims(&r.resolution).0),
        false,
    )?;
    let tile_cells = |r: &Run| {
        let (w, h) = dims(&r.tile);
        w * h
    };
    chart(
        out,
        "balance-tile",
        "load balance against tile size",
        ("cells per tile", "T_min / T_max"),
        &sweep("sweep-tile-", &tile_cells),
        false,
    )?;
    Ok(())
}
