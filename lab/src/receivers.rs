//! `radiosity-lab accuracy --receivers`: refinement by need against uniform
//! meshes, on scenes with path-traced references (the camera image and the
//! nodes, `docs/references/`). Per scene: the default (shooters, uneven
//! receivers and badly shaded polygons refined), without the shading
//! criterion (`--refine-shading 0`), shooters only, and uniform meshes (`--refine 0 --patch-size P` for
//! P = extent / 6 .. extent / 32), each with its element count, solve time,
//! image SMAPE and node errors; charted as image error against elements
//! and against solve seconds.

use anyhow::{Context, Result};
use radiosity::gpu::Gpu;
use radiosity::render::{render, RenderOptions};
use radiosity::report::Surface;
use std::path::Path;
use std::time::Duration;

/// One render of the study.
struct Run {
    label: String,
    uniform: bool,
    elements: usize,
    seconds: f64,
    smape: f64,
    mean: f64,
    worst: f64,
}

/// Scenes studied by default: those with both references.
pub const SCENES: [&str; 5] = [
    "family-opening-1",
    "family-stacked-1",
    "family-floor-1",
    "family-boxes-1",
    "cornell",
];

/// Runs the study on `scenes`, writing `receivers.csv`, `summary.md` and
/// `receivers-SCENE.{svg,png}` to `out`.
pub fn run(gpu: &Gpu, scenes: &[String], base: &RenderOptions, out: &Path) -> Result<()> {
    std::fs::create_dir_all(out)?;
    let mut csv = String::from("scene,run,uniform,elements,seconds,smape,mean_error,max_error\n");
    let mut md = String::from(
        "| scene | run | elements | solve s | image SMAPE | node mean | node worst |\n|---|---|---|---|---|---|---|\n",
    );
    for name in scenes {
        let runs = study(gpu, name, base)?;
        for r in &runs {
            csv += &format!(
                "{name},{},{},{},{:.3},{:.5},{:.5},{:.5}\n",
                r.label, r.uniform, r.elements, r.seconds, r.smape, r.mean, r.worst
            );
            md += &format!(
                "| {name} | {} | {} | {:.2} | {:.2} % | {:.2} % | {:.2} % |\n",
                r.label,
                r.elements,
                r.seconds,
                100.0 * r.smape,
                100.0 * r.mean,
                100.0 * r.worst
            );
        }
        chart(out, name, &runs)?;
    }
    radiosity::output::write_atomic(&out.join("receivers.csv"), csv.as_bytes())?;
    radiosity::output::write_atomic(&out.join("summary.md"), md.as_bytes())?;
    println!("{md}");
    Ok(())
}

/// Every run of one scene.
fn study(gpu: &Gpu, name: &str, base: &RenderOptions) -> Result<Vec<Run>> {
    let scene = radiosity::scene::open(name)?;
    let dir = Path::new("docs/references");
    let image = dir.join("images").join(format!("{name}.exr"));
    let (w, h, reference) = radiosity::output::read_exr(&image)
        .with_context(|| format!("{}: no reference image", image.display()))?;
    let nodes = dir.join(format!("{name}.json"));
    let text = std::fs::read_to_string(&nodes).with_context(|| format!("{}", nodes.display()))?;
    #[derive(serde::Deserialize)]
    struct Nodes {
        surfaces: Vec<Surface>,
    }
    let nodes: Nodes = serde_json::from_str(&text)?;
    let mut configs: Vec<(String, bool, RenderOptions)> = Vec::new();
    let mut o = base.clone();
    o.width = w;
    o.height = Some(h);
    configs.push(("by need (default)".into(), false, o.clone()));
    let mut unshaded = o.clone();
    unshaded.mesh.shading_tol = 0.0;
    configs.push((
        "by need, no shading criterion (--refine-shading 0)".into(),
        false,
        unshaded,
    ));
    let mut shooters = o.clone();
    shooters.mesh.receiver_tol = 0.0;
    shooters.mesh.shading_tol = 0.0;
    configs.push((
        "shooters only (--refine-receivers 0 --refine-shading 0)".into(),
        false,
        shooters,
    ));
    for k in [6.0f32, 8.0, 12.0, 16.0, 24.0, 32.0] {
        let mut u = o.clone();
        u.mesh.refine = 0;
        u.mesh.patch_size = Some(scene.extent() / k);
        configs.push((format!("uniform, extent/{k}"), true, u));
    }
    let mut runs = Vec::new();
    for (label, uniform, opts) in configs {
        let r = render(gpu, &scene, &opts, Duration::ZERO, &mut |_| {})?;
        let (_, _, pixels) = r.image.context("no image")?;
        let smape = radiosity::compare::smape(&pixels, &reference, w as usize, h as usize);
        let (mean, worst) = radiosity::report::relative_error(&r.report.surfaces, &nodes.surfaces);
        eprintln!(
            "receivers: {name} {label}: {} elements, {:.2} s, image {:.2} %, nodes {:.2} / {:.2} %",
            r.report.counts.elements,
            r.report.timings.solve,
            100.0 * smape,
            100.0 * mean,
            100.0 * worst
        );
        runs.push(Run {
            label,
            uniform,
            elements: r.report.counts.elements,
            seconds: r.report.timings.solve,
            smape,
            mean,
            worst,
        });
    }
    Ok(runs)
}

/// The two panels (image error against elements, and against solve time),
/// as SVG and PNG.
fn chart(out: &Path, scene: &str, runs: &[Run]) -> Result<()> {
    svg_and_png!(out, format!("receivers-{scene}"), (1100, 460), |root| draw(
        root, scene, runs
    ));
    Ok(())
}

/// What a panel puts along its x axis.
type Axis = fn(&Run) -> f64;

fn draw<DB: plotters::prelude::DrawingBackend>(
    root: plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    scene: &str,
    runs: &[Run],
) -> Result<(), String> {
    use plotters::prelude::*;
    let e = |x: &dyn std::fmt::Display| x.to_string();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let root = root
        .titled(
            &format!("{scene}: camera image error (SMAPE against the path tracer)"),
            ("sans-serif", 20),
        )
        .map_err(|x| e(&x))?;
    let (left, right) = root.split_horizontally(550);
    let panels: [(_, &str, Axis); 2] = [
        (left, "elements (log)", |r| r.elements as f64),
        (right, "solve seconds (log)", |r| r.seconds),
    ];
    let y1 = runs.iter().map(|r| r.smape).fold(0.0f64, f64::max) * 1.7; // room for the legend above the data
    for (area, desc, x) in panels {
        let xs = runs.iter().map(x);
        let (x0, x1) = xs.fold((f64::MAX, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
        let mut chart = ChartBuilder::on(&area)
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((x0 * 0.8..x1 * 1.25).log_scale(), 0.0..y1.max(1e-3))
            .map_err(|x| e(&x))?;
        chart
            .configure_mesh()
            .x_desc(desc)
            .x_labels(6)
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_desc("image SMAPE")
            .y_label_formatter(&|v| format!("{:.1} %", v * 100.0))
            .draw()
            .map_err(|x| e(&x))?;
        let uniform: Vec<(f64, f64)> = runs
            .iter()
            .filter(|r| r.uniform)
            .map(|r| (x(r), r.smape))
            .collect();
        chart
            .draw_series(LineSeries::new(uniform.clone(), BLUE.stroke_width(2)))
            .map_err(|x| e(&x))?
            .label("uniform meshes (--refine 0 --patch-size)")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        chart
            .draw_series(uniform.iter().map(|&p| Circle::new(p, 3, BLUE.filled())))
            .map_err(|x| e(&x))?;
        for (r, color) in runs
            .iter()
            .filter(|r| !r.uniform)
            .zip([RED, MAGENTA, BLACK])
        {
            chart
                .draw_series([TriangleMarker::new((x(r), r.smape), 7, color.filled())])
                .map_err(|x| e(&x))?
                .label(r.label.as_str())
                .legend(move |(x, y)| TriangleMarker::new((x + 10, y), 6, color.filled()));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 12))
            .draw()
            .map_err(|x| e(&x))?;
    }
    root.present().map_err(|x| e(&x))
}
