//! `radiosity-lab accuracy --reports`: error against solve time charted from
//! render reports that were made elsewhere (a scene too big to run every
//! curve of `radiosity-lab accuracy` in one go), scored per node against an
//! independent reference, leaving out the nodes the reference itself did
//! not resolve to the stated standard error.

use crate::accuracy::{chart, time_to, Curve, Point};
use anyhow::{bail, Context, Result};
use radiosity::report::Surface;
use std::path::{Path, PathBuf};

/// `radiosity-lab accuracy --reports ...`: charts the reports' traces against
/// `--reference-file` into `--out` (default `docs/bench/reports`).
pub fn from_args(args: &crate::accuracy::AccuracyArgs) -> Result<()> {
    let reference = args
        .reference_file
        .as_deref()
        .context("--reports needs --reference-file")?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| std::path::PathBuf::from("docs/bench/reports"));
    run(&args.reports, reference, args.reference_error, &out)
}

/// Charts `reports` against the reference at `reference` (nodes whose
/// relative standard error exceeds `max_error` left out) into `out`.
pub fn run(reports: &[PathBuf], reference: &Path, max_error: f64, out: &Path) -> Result<()> {
    let read = |p: &Path| -> Result<serde_json::Value> {
        let text = std::fs::read_to_string(p).with_context(|| format!("{}", p.display()))?;
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", p.display()))
    };
    let doc = read(reference)?;
    let kept: Vec<Surface> = doc["surfaces"]
        .as_array()
        .with_context(|| format!("{}: no surfaces", reference.display()))?
        .iter()
        .filter(|s| {
            s["relative_standard_error"]
                .as_f64()
                .is_some_and(|e| e <= max_error)
        })
        .map(|s| serde_json::from_value(s.clone()))
        .collect::<Result<Vec<Surface>, _>>()
        .with_context(|| format!("{}: surfaces", reference.display()))?
        .into_iter()
        // An unlit node has no relative error to score.
        .filter(|s| s.radiosity.iter().any(|&x| x > 0.0))
        .collect();
    if kept.is_empty() {
        bail!(
            "{}: no node within {max_error} relative standard error",
            reference.display()
        );
    }
    let names: std::collections::HashSet<&str> = kept.iter().map(|s| s.node.as_str()).collect();
    let mut curves = Vec::new();
    // Per report, its last unshot fraction.
    let mut unshot = Vec::new();
    // The nodes both a report and the reference have (what is scored).
    let mut scored_nodes = 0;
    let mut csv = String::from("report,shots,seconds,mean_error,max_error\n");
    let mut scene = String::new();
    for path in reports {
        let r = read(path)?;
        scene = r["scene"].as_str().unwrap_or("scene").to_string();
        let trace: Vec<radiosity::report::TracePoint> =
            serde_json::from_value(r["convergence"].clone())
                .with_context(|| format!("{}: no convergence trace", path.display()))?;
        unshot.push(trace.last().map_or(f64::NAN, |p| p.unshot_fraction));
        if let Some(p) = trace.last() {
            scored_nodes = p
                .surfaces
                .iter()
                .filter(|s| names.contains(s.node.as_str()))
                .count();
        }
        // Points the report kept without per-node values (a big scene's
        // thinned trace, `report::thin_trace`) cannot be scored.
        let points = trace
            .iter()
            .filter(|p| !p.surfaces.is_empty())
            .map(|p| {
                let scored: Vec<Surface> = p
                    .surfaces
                    .iter()
                    .filter(|s| names.contains(s.node.as_str()))
                    .cloned()
                    .collect();
                let (mean, max) = radiosity::report::relative_error(&scored, &kept);
                Point {
                    seconds: p.seconds,
                    mean,
                    max,
                    shots: p.shots,
                }
            })
            .collect::<Vec<Point>>();
        for p in &points {
            csv += &format!(
                "{},{},{:.4},{:.6e},{:.6e}\n",
                path.display(),
                p.shots,
                p.seconds,
                p.mean,
                p.max
            );
        }
        let settings = &r["settings"];
        let label = match settings["transport_below"].as_f64() {
            Some(t) if t > 0.0 => format!("weak shooters along the transport below {t:e}"),
            _ => "default".to_string(),
        };
        curves.push(Curve {
            label: format!(
                "{label} ({})",
                path.file_stem().unwrap_or_default().to_string_lossy()
            ),
            key: true,
            method: settings["form_factor"]
                .as_str()
                .unwrap_or("hybrid")
                .to_string(),
            resolution: settings["resolution"].as_str().unwrap_or("").to_string(),
            patches: r["counts"]["patches"].as_u64().unwrap_or(0) as usize,
            elements: r["counts"]["elements"].as_u64().unwrap_or(0) as usize,
            points,
        });
    }
    std::fs::create_dir_all(out)?;
    let name = radiosity::render::write::output_stem(&scene).to_lowercase();
    let mut summary = format!(
        "Scored against {} (area-weighted mean relative error per node, channels averaged) over the {} nodes the reports share with it whose reference is within {} relative standard error.\n\n| curve | seconds to 1 % (mean) | final mean error | final unshot | final seconds |\n|---|---|---|---|---|\n",
        reference.display(),
        scored_nodes,
        max_error
    );
    for (c, u) in curves.iter().zip(&unshot) {
        let last = c.points.last().copied();
        summary += &format!(
            "| {} | {} | {} | {u:.4} | {} |\n",
            c.label,
            time_to(&c.points, 0.01, |p| p.mean)
                .map_or("not reached".into(), |t| format!("{t:.1}")),
            last.map_or("-".into(), |p| format!("{:.2} %", 100.0 * p.mean)),
            last.map_or("-".into(), |p| format!("{:.1}", p.seconds)),
        );
    }
    radiosity::output::write_atomic(&out.join("summary.md"), summary.as_bytes())?;
    radiosity::output::write_atomic(&out.join("points.csv"), csv.as_bytes())?;
    chart(out, &name, &curves)?;
    println!("{summary}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A node the reference did not resolve is left out of the score.
    #[test]
    fn reports_are_scored_without_the_unresolved_nodes() {
        let dir = tempfile::tempdir().expect("temp dir");
        let node = |name: &str, b: f64, se: f64| {
            serde_json::json!({"node": name, "area": 1.0, "radiosity": [b, b, b],
                "relative_standard_error": se})
        };
        let reference = dir.path().join("reference.json");
        let doc = serde_json::json!({"surfaces": [node("a", 1.0, 0.001), node("b", 1.0, 0.5)]});
        std::fs::write(&reference, doc.to_string()).expect("write");
        let point = serde_json::json!({"shots": 3, "seconds": 2.0, "unshot_fraction": 0.5,
            "surfaces": [node("a", 1.1, 0.0), node("b", 5.0, 0.0)]});
        let report = dir.path().join("run.json");
        let doc = serde_json::json!({"scene": "box", "settings": {}, "counts": {},
            "convergence": [point]});
        std::fs::write(&report, doc.to_string()).expect("write");
        let out = dir.path().join("out");
        run(&[report], &reference, 0.01, &out).expect("charted");
        let csv = std::fs::read_to_string(out.join("points.csv")).expect("csv");
        let mean: f64 = csv
            .lines()
            .nth(1)
            .expect("a point")
            .split(',')
            .nth(3)
            .expect("mean")
            .parse()
            .expect("number");
        assert!((mean - 0.1).abs() < 1e-9, "{csv}");
        assert!(out.join("error-box.svg").exists());
        let summary = std::fs::read_to_string(out.join("summary.md")).expect("summary");
        assert!(summary.contains("over the 1 nodes"), "{summary}");
    }
}
