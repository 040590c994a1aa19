//! `radiosity-lab accuracy`: error against solve time, for every method option and
//! hemisphere resolution, beside a path tracer (Mitsuba 3) on the same axes.
//!
//! Error is scored per glTF node against a reference: the area-weighted mean
//! over nodes of the relative error of the node's mean radiosity (mean over
//! RGB channels), and the worst node's. References are closed forms for the
//! analytic case and, for the other scenes, the independent path-traced
//! references in `docs/references/<scene>.json` (next-event estimation,
//! `scripts/reference.py`, with their standard errors and commands). Only
//! with `--self-reference` is a scene without one scored against a long fine
//! run of this renderer (hybrid, 256 x 1024, patches of 1/40 of the scene's
//! extent, unshot 1e-5), which cannot show the method's own bias.

use anyhow::{bail, Context, Result};
use clap::Args;
use radiosity::cli::SolveArgs;
use radiosity::gpu::Gpu;
use radiosity::hemisphere::Resolution;
use radiosity::output;
use radiosity::render::{render, render_ranks, FormFactorMethod, Projection, RenderOptions};
use radiosity::report::Surface;
use radiosity::scene::{self, GltfSurface, Scene};
use radiosity::settings::AmbientTerm;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Options of `radiosity-lab accuracy`.
#[derive(Args)]
pub struct AccuracyArgs {
    /// Scenes (built-in names or files; `squares` is the analytic pair of
    /// parallel unit squares 1 apart), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "squares,cornell,cubes-4")]
    scenes: Vec<String>,
    /// Hemisphere resolutions to chart, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "64x256,128x512,256x1024")]
    resolutions: Vec<Resolution>,
    /// Patch sizes to chart beside each scene's own subdivision (both methods
    /// at 128 x 512), as fractions 1/N of the scene's extent, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "16,8")]
    patch_fractions: Vec<f32>,
    /// Where the CSV and the charts go (default docs/bench/accuracy, or
    /// docs/bench/projections with --projections).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Where the cached references are (computed there when missing).
    #[arg(long, default_value = "docs/bench/accuracy")]
    references: PathBuf,
    /// Recompute the references even when cached (`--self-reference` ones).
    #[arg(long)]
    recompute_reference: bool,
    /// The independent, path-traced references (`scripts/reference.py`).
    #[arg(long, default_value = "docs/references")]
    independent: PathBuf,
    /// Score scenes without an independent reference against a long run of
    /// this renderer (cached beside the charts) instead of refusing them.
    #[arg(long)]
    self_reference: bool,
    /// Each charted run stops at this unshot fraction (overrides --threshold).
    #[arg(long, default_value_t = 1e-4)]
    run_threshold: f64,
    /// ... or after this many shots (overrides --max-shots).
    #[arg(long, default_value_t = 20_000)]
    run_max_shots: u64,
    /// The path tracer script (Mitsuba 3); empty to skip it. The default is
    /// the strong one (next-event estimation at points on each node, the
    /// references' own method, run with --trace); `scripts/pathtrace.py` is
    /// the old irradiance meter per node, without emitter sampling.
    #[arg(long, default_value = "scripts/reference.py")]
    pathtracer: String,
    /// Python interpreter for the path tracer.
    #[arg(long, default_value = "python3")]
    python: String,
    /// Mitsuba variant: auto (llvm_ad_rgb when Debian's libllvm19 is
    /// installed, else scalar_rgb, which runs anywhere) or a variant name.
    #[arg(long, default_value = "auto")]
    variant: String,
    /// Chart the two projections instead (`exact`, `tessellated`): each over
    /// the hemisphere resolutions 64x256 to 512x2048, and the tessellated
    /// one over its tolerance at 128x512, with the pure hemisphere method on
    /// `squares` (its form factors are the cells a projection finds) and the
    /// default method on the others. Writes to docs/bench/projections unless
    /// --out is given; no path tracer.
    #[arg(long)]
    projections: bool,
    /// Chart the failure regimes instead (docs/accuracy.md): single
    /// polygons at the seam, the pole, the horizon, grazing, tiny near the
    /// pole and small and far, for both projections at 128x512 and 512x2048,
    /// to docs/bench/regimes.{svg,png,csv} (or --out).
    #[arg(long)]
    regimes: bool,
    /// Chart refinement by need against uniform meshes instead (the camera
    /// image's SMAPE against its path-traced reference, and the node errors,
    /// against elements and solve time): the default, without the shading
    /// criterion, shooters only and six uniform patch sizes, on the scenes given
    /// with --scenes (default: the family scenes with image references), to
    /// docs/bench/receivers (or --out).
    #[arg(long)]
    receivers: bool,
    /// Largest samples per sensor for the path tracer (it also stops once a
    /// level takes more than a minute).
    #[arg(long, default_value_t = 1 << 24)]
    max_spp: u32,
    /// Chart these render reports' convergence traces instead of running
    /// anything (comma-separated JSON reports of one scene), against the
    /// independent reference `--reference-file`: for scenes too big to run
    /// every curve here (Sponza). Writes `error-NAME` and `summary.md` to
    /// --out (default docs/bench/reports).
    #[arg(long, value_delimiter = ',')]
    pub reports: Vec<PathBuf>,
    /// The independent reference the reports are scored against.
    #[arg(long)]
    pub reference_file: Option<PathBuf>,
    /// With --reports: leave out the nodes whose reference has a relative
    /// standard error above this (Sponza's reached 1 % on 113 of 148).
    #[arg(long, default_value_t = 0.01)]
    pub reference_error: f64,
}

impl AccuracyArgs {
    /// `--scenes`' default.
    fn default_scenes() -> Vec<String> {
        ["squares", "cornell", "cubes-4"].map(String::from).to_vec()
    }

    fn out_dir(&self) -> PathBuf {
        self.out.clone().unwrap_or_else(|| {
            PathBuf::from(if self.projections {
                "docs/bench/projections"
            } else {
                "docs/bench/accuracy"
            })
        })
    }
}

/// A file-name-safe name for a scene (a file's stem; built-in names as they are).
fn stem(name: &str) -> String {
    radiosity::render::write::output_stem(name)
}

/// A cached reference solution.
#[derive(Serialize, Deserialize)]
struct Reference {
    scene: String,
    how: String,
    seconds: f64,
    surfaces: Vec<Surface>,
}

/// One point of an error curve.
#[derive(Clone, Copy)]
pub(crate) struct Point {
    pub(crate) seconds: f64,
    pub(crate) mean: f64,
    pub(crate) max: f64,
    pub(crate) shots: u64,
}

/// One curve: a configuration's error against time.
pub(crate) struct Curve {
    pub(crate) label: String,
    /// Whether the chart shows it (the default, its alternatives and the
    /// path tracer; every curve is in the CSV and the summary).
    pub(crate) key: bool,
    pub(crate) method: String,
    pub(crate) resolution: String,
    pub(crate) patches: usize,
    pub(crate) elements: usize,
    pub(crate) points: Vec<Point>,
}

fn error(s: &[Surface], reference: &[Surface]) -> (f64, f64) {
    radiosity::report::relative_error(s, reference)
}

/// Seconds after which the curve's error stays at or below `level`.
pub(crate) fn time_to(points: &[Point], level: f64, pick: fn(&Point) -> f64) -> Option<f64> {
    let last_above = points.iter().rposition(|p| pick(p) > level);
    match last_above {
        None => points.first().map(|p| p.seconds),
        Some(i) => points.get(i + 1).map(|p| p.seconds),
    }
}

/// The analytic scene: parallel unit squares 1 apart, a black emitter of
/// L_e = 1 and a grey receiver (reflectance 0.5: a reflectance of 1 is
/// clamped on loading); the receiver's radiosity is 0.5 pi F.
fn squares(dir: &Path) -> Result<(Scene, Vec<Surface>)> {
    use glam::Vec3;
    let sq = |z: f32, up: bool| {
        let mut v = vec![
            Vec3::new(0.0, 0.0, z),
            Vec3::new(1.0, 0.0, z),
            Vec3::new(1.0, 1.0, z),
            Vec3::new(0.0, 1.0, z),
        ];
        if !up {
            v.reverse();
        }
        v
    };
    let surfaces = [
        GltfSurface {
            name: "emitter".into(),
            polygons: vec![sq(0.0, true)],
            reflectance: [0.0; 3],
            emission: [1.0; 3],
            double_sided: false,
            subdivision: None,
        },
        GltfSurface {
            name: "receiver".into(),
            polygons: vec![sq(1.0, false)],
            reflectance: [0.5; 3],
            emission: [0.0; 3],
            double_sided: false,
            subdivision: None,
        },
    ];
    let path = dir.join("squares.gltf");
    std::fs::write(&path, scene::write_gltf(&surfaces, None))?;
    let mut s = scene::open(path.to_str().context("utf-8 path")?)?;
    s.name = "squares".into();
    let pi = std::f64::consts::PI;
    let reference = vec![
        Surface {
            node: "emitter".into(),
            area: 1.0,
            radiosity: [pi; 3],
            back: None,
        },
        Surface {
            node: "receiver".into(),
            area: 1.0,
            radiosity: [0.5 * pi * 0.19982; 3],
            back: None,
        },
    ];
    Ok((s, reference))
}

fn options(solve: &SolveArgs, args: &AccuracyArgs) -> RenderOptions {
    let mut o = solve.options();
    o.width = 0;
    o.stop.threshold = args.run_threshold;
    o.stop.max_shots = args.run_max_shots;
    o
}

fn reference(
    gpu: &Gpu,
    scene: &Scene,
    base: &RenderOptions,
    args: &AccuracyArgs,
) -> Result<Vec<Surface>> {
    let independent = args.independent.join(format!("{}.json", stem(&scene.name)));
    if let Ok(text) = std::fs::read_to_string(&independent) {
        let r: Reference = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a reference", independent.display()))?;
        eprintln!(
            "accuracy: {} against {} ({})",
            scene.name,
            independent.display(),
            r.how
        );
        return Ok(r.surfaces);
    }
    if !args.self_reference {
        bail!(
            "no independent reference for {} in {}: make one with `radiosity scene {} --nodes nodes.json && python3 scripts/reference.py nodes.json --target 1e-3 > {}` (docs/method/yardstick.md), or pass --self-reference to score against a long run of this renderer",
            scene.name,
            args.independent.display(),
            scene.name,
            independent.display()
        );
    }
    let path = args
        .references
        .join(format!("reference-{}.json", stem(&scene.name)));
    if !args.recompute_reference {
        if let Ok(text) = std::fs::read_to_string(&path) {
            let r: Reference = serde_json::from_str(&text)
                .with_context(|| format!("{}: not a reference", path.display()))?;
            return Ok(r.surfaces);
        }
    }
    let patch = scene.extent() / 40.0;
    let mut o = base.clone();
    o.form_factor = FormFactorMethod::Hybrid;
    o.resolution = Resolution {
        rows: 256,
        cols: 1024,
    };
    o.mesh.patch_size = Some(patch);
    o.mesh.element_size = Some(patch / 2.0);
    o.stop.threshold = 1e-5;
    o.stop.max_shots = 1_000_000;
    eprintln!(
        "accuracy: computing the reference for {} (patches of {patch:.3} m)...",
        scene.name
    );
    let r = render(gpu, scene, &o, Duration::ZERO, &mut |_| {})?;
    let reference = Reference {
        scene: scene.name.clone(),
        how: format!(
            "radiosity render --form-factor hybrid --resolution 256x1024 --patch-size {patch} --element-size {} --threshold 1e-5: {} patches, {} elements, {} shots",
            patch / 2.0,
            r.report.counts.patches,
            r.report.counts.elements,
            r.report.shots
        ),
        seconds: r.report.timings.solve,
        surfaces: r.report.surfaces.clone(),
    };
    output::write_json(&path, &reference)?;
    Ok(reference.surfaces)
}

fn run_curve(
    gpu: &Gpu,
    scene: &Scene,
    o: &RenderOptions,
    label: String,
    reference: &[Surface],
) -> Result<Curve> {
    run_curve_on(gpu, scene, (o, 1), label, reference)
}

/// [`run_curve`] on `ranks` ranks that are threads of this process.
fn run_curve_on(
    gpu: &Gpu,
    scene: &Scene,
    (o, ranks): (&RenderOptions, usize),
    label: String,
    reference: &[Surface],
) -> Result<Curve> {
    let r = render_ranks(gpu, scene, o, ranks, Duration::ZERO, &mut |_| {})?;
    let points = r
        .report
        .convergence
        .iter()
        .filter(|p| !p.surfaces.is_empty())
        .map(|p| {
            let (mean, max) = error(&p.surfaces, reference);
            Point {
                seconds: p.seconds,
                mean,
                max,
                shots: p.shots,
            }
        })
        .collect();
    Ok(Curve {
        key: false,
        label,
        method: format!("{:?}", o.form_factor).to_lowercase(),
        resolution: o.resolution.to_string(),
        patches: r.report.counts.patches,
        elements: r.report.counts.elements,
        points,
    })
}

/// Debian's libLLVM 19, which Mitsuba's `llvm_ad_rgb` variant wants.
const LIBLLVM: &str = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so";

/// Whether `args.pathtracer` is the strong path tracer (`reference.py`).
fn strong(args: &AccuracyArgs) -> bool {
    args.pathtracer.ends_with("reference.py")
}

/// Runs the path tracer on the exported scene `json`; returns what it
/// printed (one JSON line per level or round).
fn run_path_tracer(args: &AccuracyArgs, json: &Path) -> Result<String> {
    let mut cmd = std::process::Command::new(&args.python);
    cmd.arg(&args.pathtracer).arg(json);
    if strong(args) {
        let variant = match args.variant.as_str() {
            "auto" if Path::new(LIBLLVM).exists() => "llvm_ad_rgb",
            "auto" => "scalar_rgb",
            v => v,
        };
        if std::env::var_os("DRJIT_LIBLLVM_PATH").is_none() && Path::new(LIBLLVM).exists() {
            cmd.env("DRJIT_LIBLLVM_PATH", LIBLLVM);
        }
        // Rounds of 16 384 points per node, until a minute has passed.
        cmd.args(["--trace", "--target", "1e-9", "--batch", "16384"])
            .args(["--variant", variant]);
    } else {
        cmd.args(["--variant", &args.variant])
            .args(["--max-spp", &args.max_spp.to_string()]);
    }
    let out = cmd
        .args(["--max-seconds", "60"])
        .output()
        .with_context(|| format!("cannot run {} {}", args.python, args.pathtracer))?;
    if !out.status.success() {
        bail!(
            "{} failed: {}",
            args.pathtracer,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

fn path_tracer(
    scene: &Scene,
    args: &AccuracyArgs,
    reference: &[Surface],
    dir: &Path,
) -> Result<Curve> {
    #[derive(Deserialize)]
    struct Level {
        #[serde(alias = "points")]
        spp: u64,
        seconds: f64,
        surfaces: Vec<Surface>,
    }
    let json = dir.join(format!("{}-pt.json", stem(&scene.name)));
    radiosity::export::write_nodes(scene, &json)?;
    eprintln!(
        "accuracy: path tracing {} with Mitsuba 3 ({})...",
        scene.name, args.variant
    );
    let stdout = run_path_tracer(args, &json)?;
    let mut points = Vec::new();
    let mut variant = args.variant.clone();
    let mut last: Option<Level> = None;
    for line in stdout.lines() {
        if let Ok(v) = serde_json::from_str::<serde_json::Value>(line) {
            if let Some(name) = v.get("variant").and_then(|n| n.as_str()) {
                variant = name.to_string();
                continue;
            }
        }
        let l: Level =
            serde_json::from_str(line).with_context(|| format!("path tracer said '{line}'"))?;
        let (mean, max) = error(&l.surfaces, reference);
        points.push(Point {
            seconds: l.seconds,
            mean,
            max,
            shots: l.spp,
        });
        last = Some(l);
    }
    // The path tracer's most converged estimate, kept as an independent check
    // of the reference.
    if let Some(l) = last {
        let how = if strong(args) {
            format!(
                "Mitsuba 3 {variant}, next-event estimation at {} points per node (scripts/reference.py --trace)",
                l.spp
            )
        } else {
            format!(
                "Mitsuba 3 {variant}, path integrator, {} spp per node (scripts/pathtrace.py)",
                l.spp
            )
        };
        let path = args
            .references
            .join(format!("pathtracer-{}.json", stem(&scene.name)));
        let r = Reference {
            scene: scene.name.clone(),
            how,
            seconds: l.seconds,
            surfaces: l.surfaces,
        };
        output::write_json(&path, &r)?;
    }
    let label = if strong(args) {
        format!("path tracer, next-event estimation (Mitsuba 3 {variant})")
    } else {
        format!("path tracer, no emitter sampling (Mitsuba 3 {variant}, spp doubling)")
    };
    Ok(Curve {
        label,
        key: true,
        method: "pathtracer".into(),
        resolution: String::new(),
        patches: 0,
        elements: 0,
        points,
    })
}

/// Labels, CSV rows, summary rows and the chart of one scene's curves.
fn finish_scene(
    args: &AccuracyArgs,
    scene: &Scene,
    mut curves: Vec<Curve>,
    csv: &mut String,
    summary: &mut String,
) -> Result<()> {
    for c in &mut curves {
        if c.method != "pathtracer" {
            c.label = format!(
                "{} ({} patches, {} elements)",
                c.label, c.patches, c.elements
            );
        }
    }
    for c in &curves {
        for p in &c.points {
            *csv += &format!(
                "{},\"{}\",{},{},{},{},{},{:.6},{:.6e},{:.6e}\n",
                scene.name,
                c.label,
                c.method,
                c.resolution,
                c.patches,
                c.elements,
                p.shots,
                p.seconds,
                p.mean,
                p.max
            );
        }
        let fmt = |t: Option<f64>| t.map_or("not reached".to_string(), |t| format!("{t:.3}"));
        let last = c.points.last().copied().unwrap_or(Point {
            seconds: 0.0,
            mean: f64::NAN,
            max: f64::NAN,
            shots: 0,
        });
        *summary += &format!(
            "| {} | {} | {} | {} | {} | {} | {:.2} % | {:.3} |\n",
            scene.name,
            c.label,
            c.patches,
            c.elements,
            fmt(time_to(&c.points, 0.01, |p| p.mean)),
            fmt(time_to(&c.points, 0.01, |p| p.max)),
            100.0 * last.mean,
            last.seconds
        );
    }
    chart(&args.out_dir(), &stem(&scene.name), &curves)?;
    Ok(())
}

/// One scene's error chart (see [`chart`]).
fn draw<DB: plotters::prelude::DrawingBackend>(
    root: plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    scene: &str,
    curves: &[Curve],
) -> Result<(), String> {
    use plotters::prelude::*;
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let curves: Vec<&Curve> = curves.iter().filter(|c| c.key).collect();
    let ((x0, x1), (y0, y1)) = extent(&curves);
    if x1 <= 0.0 || y1 <= 0.0 {
        return Ok(());
    }
    root.fill(&WHITE).map_err(|x| e(&x))?;
    // The legend goes beside the plot, never over the data.
    let (plot, legend) = root.split_horizontally(640);
    let mut chart = ChartBuilder::on(&plot)
        .caption(
            format!("{scene}: area-weighted mean error per surface vs solve time"),
            ("sans-serif", 22),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(
            (x0 * 0.8..x1 * 1.25).log_scale(),
            (y0.min(0.005) * 0.8..y1 * 1.25).log_scale(),
        )
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("seconds (log)")
        .y_desc("relative error (log)")
        .draw()
        .map_err(|x| e(&x))?;
    chart
        .draw_series(LineSeries::new(
            [(x0 * 0.8, 0.01), (x1 * 1.25, 0.01)],
            BLACK.mix(0.5),
        ))
        .map_err(|x| e(&x))?;
    let mut entries = vec![("1 %".to_string(), BLACK.mix(0.5))];
    for (i, c) in curves.iter().enumerate() {
        let color = if c.method == "pathtracer" {
            BLACK.to_rgba()
        } else {
            Palette99::pick(i).to_rgba()
        };
        let points: Vec<(f64, f64)> = c
            .points
            .iter()
            .filter(|p| p.seconds > 0.0 && p.mean > 0.0)
            .map(|p| (p.seconds, p.mean))
            .collect();
        chart
            .draw_series(LineSeries::new(points.clone(), color.stroke_width(2)))
            .map_err(|x| e(&x))?;
        chart
            .draw_series(points.iter().map(|&p| Circle::new(p, 2, color.filled())))
            .map_err(|x| e(&x))?;
        entries.push((c.label.clone(), color));
    }
    for (k, (label, color)) in entries.iter().enumerate() {
        let y = 60 + 44 * k as i32;
        legend
            .draw(&PathElement::new(
                vec![(4, y), (28, y)],
                color.stroke_width(3),
            ))
            .map_err(|x| e(&x))?;
        // Long labels take two lines.
        let (a, b) = match label.find(" (") {
            Some(i) if label.len() > 44 => (&label[..i], &label[i + 1..]),
            _ => (label.as_str(), ""),
        };
        for (line, text) in [a, b].iter().enumerate() {
            legend
                .draw(&Text::new(
                    text.to_string(),
                    (34, y - 7 + 16 * line as i32),
                    ("sans-serif", 13),
                ))
                .map_err(|x| e(&x))?;
        }
    }
    root.present().map_err(|x| e(&x))
}

/// The range of the curves' positive seconds and mean errors.
fn extent(curves: &[&Curve]) -> ((f64, f64), (f64, f64)) {
    let pts = || {
        curves
            .iter()
            .flat_map(|c| c.points.iter())
            .filter(|p| p.seconds > 0.0 && p.mean > 0.0)
    };
    let x = pts().fold((f64::MAX, 0.0f64), |(a, b), p| {
        (a.min(p.seconds), b.max(p.seconds))
    });
    let y = pts().fold((f64::MAX, 0.0f64), |(a, b), p| {
        (a.min(p.mean), b.max(p.mean))
    });
    (x, y)
}

pub(crate) fn chart(out: &Path, scene: &str, curves: &[Curve]) -> Result<()> {
    svg_and_png!(out, format!("error-{scene}"), (1000, 620), |root| draw(
        root, scene, curves
    ));
    Ok(())
}

/// The projections study: both projections at four resolutions, and the
/// tessellated one at three tolerances.
fn projection_curves(
    gpu: &Gpu,
    scene: &Scene,
    base: &RenderOptions,
    reference: &[Surface],
) -> Result<Vec<Curve>> {
    let mut curves = Vec::new();
    let method = if scene.name == "squares" {
        FormFactorMethod::Hemisphere
    } else {
        FormFactorMethod::Hybrid
    };
    let m = format!("{method:?}").to_lowercase();
    for projection in [Projection::Exact, Projection::Tessellated] {
        for rows in [64u32, 128, 256, 512] {
            let mut o = base.clone();
            o.form_factor = method;
            o.projection = projection;
            o.resolution = Resolution {
                rows,
                cols: 4 * rows,
            };
            eprintln!(
                "projections: {} {projection:?} {}",
                scene.name, o.resolution
            );
            let label = format!("{m} {projection:?} {}", o.resolution).to_lowercase();
            curves.push(Curve {
                key: true,
                ..run_curve(gpu, scene, &o, label, reference)?
            });
        }
    }
    for tol in [0.05f32, 0.5, 2.0] {
        let mut o = base.clone();
        o.form_factor = method;
        o.projection = Projection::Tessellated;
        o.tessellation_tolerance = tol;
        eprintln!("projections: {} tessellated, tolerance {tol}", scene.name);
        let label = format!("{m} tessellated 128x512, tolerance {tol} cells");
        curves.push(Curve {
            key: true,
            ..run_curve(gpu, scene, &o, label, reference)?
        });
    }
    Ok(curves)
}

/// The solver's curves: both methods at every resolution, and the default
/// against each of its levers turned the other way.
fn solver_curves(
    gpu: &Gpu,
    scene: &Scene,
    base: &RenderOptions,
    args: &AccuracyArgs,
    reference: &[Surface],
) -> Result<Vec<Curve>> {
    let mut curves = Vec::new();
    for method in [FormFactorMethod::Hybrid, FormFactorMethod::Hemisphere] {
        for &res in &args.resolutions {
            let mut o = base.clone();
            o.form_factor = method;
            o.resolution = res;
            eprintln!("accuracy: {} {method:?} {res}", scene.name);
            let coarse = o
                .coarse_tier()
                .map(|c| format!(", weak shooters {c}"))
                .unwrap_or_default();
            let label = format!("{} {res}{coarse}", format!("{method:?}").to_lowercase());
            let mut curve = run_curve(gpu, scene, &o, label, reference)?;
            // The default and the other method at the default resolution.
            curve.key = res == base.resolution;
            curves.push(curve);
        }
    }
    if base.mesh.refine > 0 && base.mesh.receiver_tol > 0.0 {
        // Refinement by need with and without the receivers' criterion.
        let mut o = base.clone();
        o.mesh.receiver_tol = 0.0;
        o.mesh.shading_tol = 0.0;
        eprintln!("accuracy: {} hybrid, shooters refined only", scene.name);
        let label =
            "hybrid 128x512, shooters refined only (--refine-receivers 0 --refine-shading 0)"
                .to_string();
        let mut curve = run_curve(gpu, scene, &o, label, reference)?;
        curve.key = true;
        curves.push(curve);
    }
    if base.mesh.refine > 0 {
        // Refinement by need against the mesh it starts from, unrefined.
        let mut o = base.clone();
        o.mesh.refine = 0;
        eprintln!("accuracy: {} hybrid, no refinement", scene.name);
        let label = "hybrid 128x512, no refinement (--refine 0)".to_string();
        let mut curve = run_curve(gpu, scene, &o, label, reference)?;
        curve.key = true;
        curves.push(curve);
    }
    if base.ambient == AmbientTerm::Carried {
        // The ambient term carried along the geometry against Cohen's even
        // spread: the same solve, another display of its unshot light.
        let mut o = base.clone();
        o.ambient = AmbientTerm::Even;
        eprintln!("accuracy: {} hybrid, even ambient", scene.name);
        let label = "hybrid 128x512, Cohen's even ambient term (--ambient even)".to_string();
        let mut curve = run_curve(gpu, scene, &o, label, reference)?;
        curve.key = true;
        curves.push(curve);
    }
    if base.coarse_below > 0.0 {
        // Coarse hemispheres for weak shooters against every shot at 128 x 512.
        let mut o = base.clone();
        o.coarse_below = 0.0;
        eprintln!("accuracy: {} hybrid, every shot fine", scene.name);
        let label = "hybrid 128x512, every shot at 128x512 (--coarse-below 0)".to_string();
        curves.push(run_curve(gpu, scene, &o, label, reference)?);
    }
    {
        // Batches of shooters from one state, on two ranks of this process
        // (`--batch 64 --ranks 2`): what the time bought is charted against
        // what the batches cost in accuracy a shot.
        let mut o = base.clone();
        o.batch = 64;
        eprintln!("accuracy: {} hybrid, batches of 64 on 2 ranks", scene.name);
        let label =
            "hybrid 128x512, batches of 64 on 2 ranks in one process (--batch 64 --ranks 2)";
        curves.push(run_curve_on(
            gpu,
            scene,
            (&o, 2),
            label.to_string(),
            reference,
        )?);
    }
    for &n in &args.patch_fractions {
        let p = scene.extent() / n.max(1.0);
        for method in [FormFactorMethod::Hybrid, FormFactorMethod::Hemisphere] {
            let mut o = base.clone();
            o.form_factor = method;
            o.mesh.patch_size = Some(p);
            eprintln!("accuracy: {} {method:?} patches {p} m", scene.name);
            let label = format!(
                "{} 128x512, {p:.3} m patches",
                format!("{method:?}").to_lowercase()
            );
            curves.push(run_curve(gpu, scene, &o, label, reference)?);
        }
    }
    Ok(curves)
}

/// Runs the accuracy benchmark.
pub fn run(args: AccuracyArgs, solve: SolveArgs) -> Result<()> {
    let gpu = Gpu::new()?;
    let out_or = |default: &str| args.out.clone().unwrap_or_else(|| PathBuf::from(default));
    if args.regimes {
        let out = out_or("docs/bench");
        std::fs::create_dir_all(&out)?;
        return crate::regimes::run(&gpu, &out);
    }
    if args.receivers {
        let out = out_or("docs/bench/receivers");
        let default = AccuracyArgs::default_scenes();
        let scenes: Vec<String> = if args.scenes == default {
            crate::receivers::SCENES.map(String::from).to_vec()
        } else {
            args.scenes.clone()
        };
        return crate::receivers::run(&gpu, &scenes, &solve.options(), &out);
    }
    let out = args.out_dir();
    std::fs::create_dir_all(&out)?;
    let tmp = tempfile::tempdir()?;
    let base = options(&solve, &args);
    let mut csv = String::from(
        "scene,curve,method,resolution,patches,elements,shots_or_spp,seconds,mean_error,max_error\n",
    );
    let mut summary = String::from(
        "| scene | curve | patches | elements | seconds to 1 % (mean) | seconds to 1 % (every surface) | final mean error | final seconds |\n|---|---|---|---|---|---|---|---|\n",
    );
    for name in &args.scenes {
        let (scene, closed_form) = if name == "squares" {
            let (s, r) = squares(tmp.path())?;
            (s, Some(r))
        } else {
            (scene::open(name)?, None)
        };
        let reference = match closed_form {
            Some(r) => r,
            None => reference(&gpu, &scene, &base, &args)?,
        };
        let mut curves = Vec::new();
        if args.projections {
            let curves = projection_curves(&gpu, &scene, &base, &reference)?;
            finish_scene(&args, &scene, curves, &mut csv, &mut summary)?;
            continue;
        }
        curves.extend(solver_curves(&gpu, &scene, &base, &args, &reference)?);
        if !args.pathtracer.is_empty() {
            match path_tracer(&scene, &args, &reference, tmp.path()) {
                Ok(c) => curves.push(c),
                Err(e) => eprintln!("accuracy: no path-tracer curve for {}: {e:#}", scene.name),
            }
        }
        finish_scene(&args, &scene, curves, &mut csv, &mut summary)?;
    }
    output::write_atomic(&out.join("accuracy.csv"), csv.as_bytes())?;
    output::write_atomic(&out.join("summary.md"), summary.as_bytes())?;
    println!("device: {}\n\n{summary}", gpu.describe());
    Ok(())
}
