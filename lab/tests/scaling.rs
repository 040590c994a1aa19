//! The performance model (docs/scaling.md) against the committed runs it was
//! calibrated on (docs/scaling/runs, made by scripts/calibrate-scaling.sh
//! with the hemispheres drawn by lavapipe, and docs/scaling/cpu/runs, drawn
//! on the CPU):
//! its predictions of the measured seconds, CPU seconds and bytes a shot
//! at 1 to 16 ranks within 15 %. The runs are measurements, not outputs of
//! this build: the test checks the model, not the renderer's speed.

use radiosity_lab::scaling::{read_runs, Calibration, AP1000, CALLS, CLUSTER, SLOWEST_ROWS};
use std::path::Path;

/// The two committed calibrations: the device's drawing, then the CPU's.
const CALIBRATIONS: [&str; 2] = ["docs/scaling/runs", "docs/scaling/cpu/runs"];

fn calibration(runs: &str) -> Calibration {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(runs);
    let runs = read_runs(&dir).expect("the committed calibration runs");
    assert!(runs.len() >= 20, "{} runs in {}", runs.len(), dir.display());
    Calibration::fit(runs).expect("every scene has its 1- and 2-rank runs")
}

#[test]
fn the_model_reproduces_its_calibration_within_15_percent() {
    for runs in CALIBRATIONS {
        reproduces(runs);
    }
}

/// The model fitted to `runs` predicts every one of them within 15 %.
fn reproduces(runs: &str) {
    let cal = calibration(runs);
    let checks = cal.validation();
    let timed: Vec<_> = checks.iter().filter(|c| c.is_cost()).collect();
    // 1- and 2-rank wall times, 4-16-rank CPU seconds, bytes.
    assert!(timed
        .iter()
        .any(|c| c.ranks == 2 && c.quantity == "seconds a shot"));
    assert!(timed
        .iter()
        .any(|c| c.ranks == 16 && c.quantity.contains("CPU")));
    // Batched runs: the replay's deal of the rows against the runs' own.
    assert!(timed
        .iter()
        .any(|c| c.ranks == 16 && c.quantity == SLOWEST_ROWS));
    // ... and their calls: the collectives the 2-rank run made beside its
    // pool's tickets, against the runs beyond 2 ranks, which deal theirs.
    assert!(timed.iter().any(|c| c.ranks == 16 && c.quantity == CALLS));
    let bad: Vec<String> = timed
        .iter()
        .filter(|c| c.relative_error().abs() > 0.15)
        .map(|c| c.row())
        .collect();
    assert!(
        bad.is_empty(),
        "{runs}: off by more than 15 %:\n{}",
        bad.join("\n")
    );
}

#[test]
fn the_model_keeps_the_papers_orderings() {
    for runs in CALIBRATIONS {
        keeps_orderings(runs);
    }
}

/// The model fitted to `runs` keeps the paper's orderings.
fn keeps_orderings(runs: &str) {
    let cal = calibration(runs);
    for scene in ["cubes-b1", "cubes-b3"] {
        let hem = cal.model(scene, [128, 512], "hemispheres").expect(scene);
        let ff = cal.model(scene, [128, 512], "form-factors").expect(scene);
        // Partial form factors move the scene's size each stage: over the
        // paper's network they lose at 64 ranks (its figure 8).
        assert!(
            hem.speedup(64.0, &AP1000) > ff.speedup(64.0, &AP1000),
            "{scene}"
        );
        // A faster network never slows a shot.
        for n in [2.0, 64.0, 1024.0] {
            assert!(hem.seconds_per_shot(n, &CLUSTER) <= hem.seconds_per_shot(n, &AP1000));
        }
        // Amdahl: the speedup never passes (R + D) / R.
        assert!(hem.speedup(1024.0, &CLUSTER) <= hem.amdahl_limit() * (1.0 + 1e-9));
    }
}

/// A batched run's calls a shot are counts, so the model gets them within
/// 1 %: the calibration's oversubscribed runs, whose rows are dealt (the
/// collectives alone), and pooled runs beyond 2 ranks
/// (`docs/scaling/cpu/pooled`: 4 and 8 ranks on this machine's 2 cores,
/// made for this check and not fitted), whose ranks also take the pool's
/// tickets, fewer each as the ranks grow.
#[test]
fn the_model_counts_a_batched_runs_calls() {
    for runs in CALIBRATIONS {
        let calls: Vec<_> = calibration(runs)
            .validation()
            .into_iter()
            .filter(|c| c.quantity == CALLS)
            .collect();
        assert!(calls.iter().any(|c| c.ranks == 16), "{runs}");
        for c in calls {
            assert!(c.relative_error().abs() < 0.01, "{runs}: {}", c.row());
        }
    }
    let cal = calibration(CALIBRATIONS[1]);
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/scaling/cpu/pooled");
    let runs = read_runs(&dir).expect("the committed pooled runs");
    assert_eq!(runs.len(), 4);
    for r in &runs {
        assert!(r.pooled && r.ranks > 2, "{}", r.path.display());
        let m = cal
            .model(&r.scene, r.resolution, &r.exchange)
            .expect("a batched model of the run's scene");
        let replay = m.replay.as_ref().expect("batched runs are replayed");
        let predicted = m.calls + replay.tickets(r.ranks as f64, r.pooled);
        let measured = r.calls.iter().sum::<f64>() / r.calls.len() as f64;
        assert!(
            (predicted / measured - 1.0).abs() < 0.01,
            "{}: {measured} calls a shot, the model {predicted}",
            r.path.display()
        );
    }
}
