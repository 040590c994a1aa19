//! `radiosity-lab scaling`: fits the performance model (`crate::scaling`)
//! to the runs of `scripts/calibrate-scaling.sh`, checks it against them,
//! and redraws the paper's figures 8-12 for up to 1024 ranks over two
//! networks (docs/scaling.md).

use crate::scaling::{self, Calibration, Model, Network, AP1000, CLUSTER, PHASES};
use anyhow::Result;
use clap::Args;
use plotters::chart::SeriesLabelPosition;
use radiosity::output;
use std::fmt::Write as _;
use std::path::PathBuf;

/// Options of `radiosity-lab scaling`.
#[derive(Args)]
pub struct ScalingArgs {
    /// Directory of calibration reports (scripts/calibrate-scaling.sh).
    #[arg(long, default_value = "docs/scaling/runs")]
    runs: PathBuf,
    /// Directory for the CSV files and the charts.
    #[arg(long, default_value = "docs/scaling")]
    out: PathBuf,
    /// Fit only to runs of at most this many ranks (the others are then a
    /// held-out check); default all.
    #[arg(long)]
    fit_up_to: Option<usize>,
}

/// Ranks the figures are drawn for.
const RANKS: [f64; 11] = [
    1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0, 256.0, 512.0, 1024.0,
];

/// The paper's 64-processor speedups (its text; figures 8, 9), per scene:
/// (partial form factors, partial hemispheres) where it gives them per
/// scene, else its ranges.
const PAPER_64: [(&str, &str, &str); 6] = [
    ("cubes-b1", "9.5-11.1", "20.4-21.8"),
    ("cubes-b2", "9.5-11.1", "20.4-21.8"),
    ("cubes-b3", "9.5-11.1", "20.4-21.8 (20.27 in fig. 12)"),
    ("classroom-c1", "28.2-37.0", "35.1-40.2"),
    ("classroom-c2", "28.2-37.0", "35.1-40.2"),
    ("classroom-c3", "28.2-37.0", "35.1-40.2"),
];

/// Fits, validates, writes docs/scaling/*.csv and the charts, and prints
/// the tables docs/scaling.md quotes.
pub fn run(args: ScalingArgs) -> Result<()> {
    let runs = scaling::read_runs(&args.runs)?;
    let cal = Calibration::fit_up_to(runs, args.fit_up_to.unwrap_or(usize::MAX))?;
    std::fs::create_dir_all(&args.out)?;
    let checks = cal.validation();
    let mut csv = String::from(
        "scene,resolution,exchange,ranks,quantity,measured,predicted,relative_error\n",
    );
    for c in &checks {
        writeln!(
            csv,
            "{},{}x{},{},{},{},{:.6e},{:.6e},{:.4}",
            c.scene,
            c.resolution[0],
            c.resolution[1],
            c.exchange,
            c.ranks,
            c.quantity,
            c.measured,
            c.predicted,
            c.relative_error()
        )?;
    }
    output::write_atomic(&args.out.join("validation.csv"), csv.as_bytes())?;
    output::write_atomic(&args.out.join("fits.csv"), fits_csv(&cal)?.as_bytes())?;
    output::write_atomic(&args.out.join("model.csv"), model_csv(&cal)?.as_bytes())?;
    charts(&args.out, &cal)?;
    print!("{}", summary(&cal, &checks)?);
    Ok(())
}

fn res_name(r: [u32; 2]) -> String {
    format!("{}x{}", r[0], r[1])
}

fn fits_csv(cal: &Calibration) -> Result<String> {
    let mut s = String::from("scene,resolution,exchange,serial_s,replicated_s,divided_s");
    for p in PHASES {
        write!(s, ",{p}_replicated,{p}_divided")?;
    }
    s += ",calls,hemispheres,bytes_law,imbalance2,gamma\n";
    for m in &cal.models {
        write!(
            s,
            "{},{},{},{:.6e},{:.6e},{:.6e}",
            m.scene,
            res_name(m.resolution),
            m.exchange,
            m.serial,
            m.replicated,
            m.divided
        )?;
        for p in &m.phases {
            write!(s, ",{:.6e},{:.6e}", p.replicated, p.divided)?;
        }
        writeln!(
            s,
            ",{:.2},{:.3},\"{:?}\",{:.4},{:.3}",
            m.calls, m.hemispheres, m.bytes, m.imbalance2, m.gamma
        )?;
    }
    writeln!(
        s,
        "# local network: latency {:.3e} s per stage, bandwidth {:.3e} B/s",
        cal.local.latency, cal.local.bandwidth
    )?;
    Ok(s)
}

fn networks(cal: &Calibration) -> [Network; 3] {
    [cal.local, AP1000, CLUSTER]
}

fn model_csv(cal: &Calibration) -> Result<String> {
    let mut s = String::from(
        "scene,resolution,exchange,network,ranks,seconds_per_shot,speedup,epsilon,bytes_per_shot\n",
    );
    for m in &cal.models {
        for net in networks(cal) {
            for n in RANKS {
                writeln!(
                    s,
                    "{},{},{},\"{}\",{},{:.6e},{:.3},{:.4},{:.0}",
                    m.scene,
                    res_name(m.resolution),
                    m.exchange,
                    net.name,
                    n,
                    m.seconds_per_shot(n, &net),
                    m.speedup(n, &net),
                    m.epsilon(n),
                    m.bytes.received(n)
                )?;
            }
        }
    }
    Ok(s)
}

const STD: [u32; 2] = [128, 512];

/// Speedup against log2 ranks of `scenes` for both of the paper's methods.
fn speedup_series(cal: &Calibration, scenes: &[&str], net: &Network) -> crate::bench::Series {
    let mut series = Vec::new();
    for ex in ["hemispheres", "form-factors"] {
        for scene in scenes {
            if let Some(m) = cal.model(scene, STD, ex) {
                let label = match ex {
                    "hemispheres" => "partial hemispheres",
                    _ => "partial form factors",
                };
                series.push((
                    format!("{scene}, {label}"),
                    RANKS
                        .iter()
                        .map(|&n| (n.log2(), m.speedup(n, net)))
                        .collect(),
                ));
            }
        }
    }
    // Batched shots (not the paper's method: whole hemispheres a rank).
    for m in cal.models.iter().filter(|m| {
        m.resolution == STD
            && m.exchange.starts_with("batches")
            && scenes.contains(&m.scene.as_str())
    }) {
        series.push((
            format!("{}, {}", m.scene, m.exchange.replace('-', " of ")),
            RANKS
                .iter()
                .map(|&n| (n.log2(), m.speedup(n, net)))
                .collect(),
        ));
    }
    series
}

fn charts(out: &std::path::Path, cal: &Calibration) -> Result<()> {
    let benchmark = ["cubes-b1", "cubes-b2", "cubes-b3"];
    let classroom = ["classroom-c1", "classroom-c2", "classroom-c3"];
    for (tag, net) in [("ap1000", AP1000), ("cluster", CLUSTER)] {
        for (fig, scenes, what) in [
            ("fig8", &benchmark, "benchmark scenes"),
            ("fig9", &classroom, "classrooms"),
        ] {
            crate::bench::chart_at(
                out,
                &format!("{fig}-{tag}"),
                &format!("Speedup, {what}, model over {}", net.name),
                ("log2 ranks", "speedup (100 shots)"),
                &speedup_series(cal, scenes, &net),
                false,
                SeriesLabelPosition::UpperLeft,
            )?;
        }
    }
    // Figure 10: load balance against ranks (C2), model and CPU measurements.
    let mut eps = Vec::new();
    for scene in classroom {
        if let Some(m) = cal.model(scene, STD, "hemispheres") {
            eps.push((
                format!("{scene} model"),
                RANKS.iter().map(|&n| (n.log2(), m.epsilon(n))).collect(),
            ));
            let measured: Vec<(f64, f64)> = cal
                .runs
                .iter()
                .filter(|r| r.scene == scene && r.ranks > 1 && r.exchange == "hemispheres")
                .map(|r| ((r.ranks as f64).log2(), r.epsilon_cpu))
                .collect();
            eps.push((format!("{scene} measured (CPU)"), measured));
        }
    }
    crate::bench::chart_at(
        out,
        "fig10",
        "Mean load balance epsilon against ranks",
        ("log2 ranks", "epsilon = T_min / T_max"),
        &eps,
        false,
        SeriesLabelPosition::LowerRight,
    )?;
    // Figure 12: B3's seconds a shot at two resolutions, cluster network.
    let mut res = Vec::new();
    for r in [[128, 512], [192, 768]] {
        if let Some(m) = cal.model("cubes-b3", r, "hemispheres") {
            res.push((
                format!("cubes-b3 {}", res_name(r)),
                RANKS
                    .iter()
                    .map(|&n| (n.log2(), m.seconds_per_shot(n, &CLUSTER)))
                    .collect(),
            ));
        }
    }
    crate::bench::chart(
        out,
        "fig12",
        "cubes-b3 seconds a shot against ranks, two resolutions (cluster)",
        ("log2 ranks", "seconds a shot"),
        &res,
        true,
    )?;
    Ok(())
}

fn summary(cal: &Calibration, checks: &[scaling::Check]) -> Result<String> {
    let mut s = String::new();
    writeln!(
        s,
        "this machine's exchange: {:.1} us a stage, {:.2} GB/s\n",
        cal.local.latency * 1e6,
        cal.local.bandwidth / 1e9
    )?;
    if cal.fitted_up_to < usize::MAX {
        writeln!(s, "fitted to runs of at most {} ranks\n", cal.fitted_up_to)?;
    }
    writeln!(
        s,
        "## Fits (compute seconds a shot; phases from the 1- and 2-rank wall times)\n"
    )?;
    writeln!(
        s,
        "| scene | res | exchange | 1 rank | replicated | divided | limit | bounds R/D | rasterise R/D | sum R/D | calls | u(2) | gamma |"
    )?;
    writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|---|---|")?;
    for m in &cal.models {
        let rd = |k: usize| {
            format!(
                "{:.1}/{:.1} ms",
                m.phases[k].replicated * 1e3,
                m.phases[k].divided * 1e3
            )
        };
        let (u2, gamma) = if m.replay.is_some() {
            ("replay".to_string(), "replay".to_string())
        } else {
            (format!("{:.3}", m.imbalance2), format!("{:.2}", m.gamma))
        };
        writeln!(
            s,
            "| {} | {} | {} | {:.1} ms | {:.1} ms | {:.1} ms | {:.1} | {} | {} | {} | {:.1} | {} | {} |",
            m.scene,
            res_name(m.resolution),
            m.exchange,
            m.serial * 1e3,
            m.replicated * 1e3,
            m.divided * 1e3,
            m.amdahl_limit(),
            rd(1),
            rd(2),
            rd(4),
            m.calls,
            u2,
            gamma
        )?;
    }
    writeln!(
        s,
        "\n## Batched shots replayed (rows as one rank drew them, dealt again on N ranks)\n"
    )?;
    writeln!(
        s,
        "| scene | exchange | steps | rows | rest a + s b / N | contention s(2), power | slowest rank's rows at 16 / 64 ranks | 64 ranks (cluster): compute + exchange, latencies | speedup 64 (cluster) |"
    )?;
    writeln!(s, "|---|---|---|---|---|---|---|---|---|")?;
    for m in &cal.models {
        let Some(r) = &m.replay else { continue };
        writeln!(
            s,
            "| {} | {} | {} | {:.1} ms | {:.2} + s {:.2} / N ms | {:.3}, {:.2} | {:.2} / {:.2} ms | {:.3} + {:.3} ms, {:.1} | {:.1} |",
            m.scene,
            m.exchange,
            r.batches.len(),
            r.rows() * 1e3,
            r.rest_a * 1e3,
            r.rest_b * 1e3,
            r.contention2,
            r.contention_power,
            r.loads(16, false).0 * 1e3,
            r.loads(64, false).0 * 1e3,
            m.compute_max(64.0) * 1e3,
            m.exchange(64.0, &CLUSTER) * 1e3,
            m.stages(64.0, CLUSTER.paper_schedule),
            m.speedup(64.0, &CLUSTER)
        )?;
    }
    writeln!(s, "\n## Validation\n")?;
    writeln!(
        s,
        "| scene | res | exchange | ranks | quantity | measured | predicted | error |"
    )?;
    writeln!(s, "|---|---|---|---|---|---|---|---|")?;
    for c in checks {
        writeln!(s, "{}", c.row())?;
    }
    let worst = checks
        .iter()
        .filter(|c| c.is_cost())
        .map(|c| c.relative_error().abs())
        .fold(0.0, f64::max);
    writeln!(s, "\nworst time/bytes error: {:.1} %", worst * 100.0)?;
    writeln!(
        s,
        "\n## Speedup (100 shots) and load balance at 64, 256, 1024 ranks\n"
    )?;
    writeln!(
        s,
        "| scene | exchange | network | S(2) | S(64) | S(256) | S(1024) | eps(64) | paper S(64) |"
    )?;
    writeln!(s, "|---|---|---|---|---|---|---|---|---|")?;
    for m in cal.models.iter().filter(|m| m.resolution == STD) {
        for net in networks(cal) {
            let paper = PAPER_64
                .iter()
                .find(|p| p.0 == m.scene)
                .map(|p| match m.exchange.as_str() {
                    "hemispheres" => p.2,
                    "form-factors" => p.1,
                    _ => "-",
                })
                .unwrap_or("-");
            writeln!(
                s,
                "| {} | {} | {} | {:.2} | {:.1} | {:.1} | {:.1} | {:.3} | {} |",
                m.scene,
                m.exchange,
                net.name,
                m.speedup(2.0, &net),
                m.speedup(64.0, &net),
                m.speedup(256.0, &net),
                m.speedup(1024.0, &net),
                m.epsilon(64.0),
                paper
            )?;
        }
    }
    writeln!(
        s,
        "\n## Where each exchange wins (fastest seconds a shot)\n"
    )?;
    writeln!(s, "| scene | network | 2 | 8 | 64 | 256 | 1024 |")?;
    writeln!(s, "|---|---|---|---|---|---|---|")?;
    let mut scenes: Vec<&str> = cal.models.iter().map(|m| m.scene.as_str()).collect();
    scenes.dedup();
    for scene in scenes {
        for net in networks(cal) {
            write!(s, "| {scene} | {} |", net.name)?;
            for n in [2.0, 8.0, 64.0, 256.0, 1024.0] {
                let best = ["hemispheres", "form-factors", "sparse"]
                    .iter()
                    .filter_map(|ex| cal.model(scene, STD, ex))
                    .min_by(|a: &&Model, b: &&Model| {
                        a.seconds_per_shot(n, &net)
                            .total_cmp(&b.seconds_per_shot(n, &net))
                    });
                write!(s, " {} |", best.map_or("-", |m| m.exchange.as_str()))?;
            }
            writeln!(s)?;
        }
    }
    if let (Some(a), Some(b)) = (
        cal.model("cubes-b3", [128, 512], "hemispheres"),
        cal.model("cubes-b3", [192, 768], "hemispheres"),
    ) {
        writeln!(s, "\n## cubes-b3 at 192x768 against 128x512 (paper: 1.65x on 1, 1.40x on 64; speedup 20.27 and 23.91)\n")?;
        for net in [AP1000, CLUSTER] {
            writeln!(
                s,
                "- {}: time ratio {:.2}x on 1 rank, {:.2}x on 64; speedup at 64 {:.2} and {:.2}",
                net.name,
                b.seconds_per_shot(1.0, &net) / a.seconds_per_shot(1.0, &net),
                b.seconds_per_shot(64.0, &net) / a.seconds_per_shot(64.0, &net),
                a.speedup(64.0, &net),
                b.speedup(64.0, &net)
            )?;
        }
    }
    Ok(s)
}
