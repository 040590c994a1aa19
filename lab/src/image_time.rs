//! `radiosity-lab image-time`: image error against wall time, this renderer
//! beside the path tracer, charted from the rows `scripts/image-time.sh`
//! measured in one sitting (issue 63 item 5).

use crate::bench::{draw_chart, Series};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// The chart's flags.
#[derive(clap::Args, Debug)]
pub struct ImageTimeArgs {
    /// CSV files of `scene,renderer,setting,seconds,smape_percent` rows.
    #[arg(required = true)]
    pub csv: Vec<PathBuf>,
    /// Where the charts go (one SVG and PNG a scene).
    #[arg(long, default_value = "docs/bench/image-time")]
    pub out: PathBuf,
}

/// One measured image: who made it, how, in what wall time, how far off.
struct Row {
    scene: String,
    renderer: String,
    setting: String,
    seconds: f64,
    smape: f64,
}

fn read(path: &Path) -> Result<Vec<Row>> {
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    let mut rows = Vec::new();
    for (n, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 5 {
            bail!(
                "{}:{}: want 5 fields, found {}",
                path.display(),
                n + 1,
                f.len()
            );
        }
        let num = |s: &str| -> Result<f64> {
            s.trim()
                .parse()
                .with_context(|| format!("{}:{}: '{s}' is not a number", path.display(), n + 1))
        };
        rows.push(Row {
            scene: f[0].into(),
            renderer: f[1].into(),
            setting: f[2].into(),
            seconds: num(f[3])?,
            smape: num(f[4])?,
        });
    }
    Ok(rows)
}

/// Charts every scene of the CSV files into `args.out`.
pub fn run(args: &ImageTimeArgs) -> Result<()> {
    let mut rows = Vec::new();
    for p in &args.csv {
        rows.extend(read(p)?);
    }
    std::fs::create_dir_all(&args.out)?;
    let mut scenes: Vec<&str> = rows.iter().map(|r| r.scene.as_str()).collect();
    scenes.dedup();
    for scene in scenes {
        let curve = |label: &str, keep: &dyn Fn(&Row) -> bool| {
            let mut points: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| r.scene == scene && keep(r))
                .map(|r| (r.seconds, r.smape))
                .collect();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            (label.to_string(), points)
        };
        let series: Series = vec![
            curve("radiosity, gathered", &|r| {
                r.renderer == "radiosity" && !r.setting.ends_with("gather 0")
            }),
            curve("radiosity, interpolated", &|r| {
                r.renderer == "radiosity" && r.setting.ends_with("gather 0")
            }),
            curve("path tracer (Mitsuba 3, NEE)", &|r| r.renderer == "mitsuba"),
        ];
        let title = format!("{scene}: image error against wall time, two cores");
        let axes = ("wall seconds", "SMAPE, 4x4 blocks (%)");
        let legend = plotters::chart::SeriesLabelPosition::UpperRight;
        svg_and_png!(args.out, scene, (900, 560), |root| draw_chart(
            root,
            &title,
            axes,
            &series,
            true,
            legend.clone()
        ));
        println!(
            "{}: {} points",
            scene,
            series.iter().map(|s| s.1.len()).sum::<usize>()
        );
    }
    Ok(())
}
