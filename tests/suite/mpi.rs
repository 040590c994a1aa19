//! The same solve on 1 to 4 MPI ranks (oversubscribed), with every exchange
//! and several tile sizes: bitwise identical reports and images, and the
//! paper's traffic formulas.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

fn mpirun(ranks: usize, dir: &Path, tag: &str, extra: &[&str]) -> serde_json::Value {
    mpirun_scene(ranks, dir, tag, "cornell", extra)
}

/// [`mpirun`] on another scene.
fn mpirun_scene(
    ranks: usize,
    dir: &Path,
    tag: &str,
    scene: &str,
    extra: &[&str],
) -> serde_json::Value {
    let report = dir.join(format!("{tag}.json"));
    let image = dir.join(format!("{tag}.exr"));
    let mut cmd = Command::new("mpirun");
    cmd.args(["--oversubscribe", "-n", &ranks.to_string()])
        .arg(env!("CARGO_BIN_EXE_radiosity"))
        .args(["render", scene, "--width", "48"])
        .args(if extra.contains(&"--max-shots") {
            &[][..]
        } else {
            &["--max-shots", "25"][..]
        })
        .arg("--report")
        .arg(&report)
        .arg("--image")
        .arg(&image)
        .args(extra)
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_btl", "self,vader,tcp");
    let out = cmd.output().unwrap_or_else(|e| {
        panic!("cannot run mpirun ({e}): install openmpi-bin (scripts/setup.sh does)")
    });
    assert!(
        out.status.success(),
        "mpirun -n {ranks} {extra:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(&std::fs::read_to_string(&report).expect("report written")).expect("json")
}

fn same_result(a: &serde_json::Value, b: &serde_json::Value, what: &str) {
    for key in ["surfaces", "shots", "unshot_fraction"] {
        assert_eq!(a[key], b[key], "{what}: '{key}' differs");
    }
    // The convergence trace too, point by point (its seconds are timings).
    let (ta, tb) = (
        a["convergence"].as_array().expect("trace"),
        b["convergence"].as_array().expect("trace"),
    );
    assert_eq!(ta.len(), tb.len(), "{what}: trace lengths differ");
    for (p, q) in ta.iter().zip(tb) {
        for key in ["shots", "unshot_fraction", "surfaces"] {
            assert_eq!(p[key], q[key], "{what}: trace '{key}' differs");
        }
    }
}

#[test]
fn every_rank_count_exchange_and_tile_gives_identical_results() {
    let dir = tempfile::tempdir().expect("temp dir");
    let base = mpirun(1, dir.path(), "base", &[]);
    let base_image = std::fs::read(dir.path().join("base.exr")).expect("image");
    // The same report and the same EXR image as one rank.
    let same_as_one = |ranks: usize, tag: &str, args: &[&str]| -> serde_json::Value {
        let r = mpirun(ranks, dir.path(), tag, args);
        same_result(&base, &r, tag);
        let image = std::fs::read(dir.path().join(format!("{tag}.exr"))).expect("image");
        assert!(image == base_image, "{tag}: image differs");
        r
    };
    for ranks in [2, 3, 4] {
        for exchange in ["hemispheres", "form-factors", "sparse"] {
            let tag = format!("n{ranks}-{exchange}");
            let r = same_as_one(ranks, &tag, &["--exchange", exchange]);
            assert_eq!(r["parallel"]["ranks"], ranks);
        }
    }
    for tile in ["8x4", "3x5", "512x128"] {
        let tag = format!("tile-{tile}");
        let r = mpirun(4, dir.path(), &tag, &["--tile", tile]);
        same_result(&base, &r, &tag);
    }
    // The bounds dealt between the ranks or not (by default where the scene
    // has 1024 polygons: not this box).
    for (ranks, deal) in [(2, "on"), (3, "on"), (4, "off")] {
        let tag = format!("n{ranks}-deal-{deal}");
        let r = same_as_one(ranks, &tag, &["--deal-bounds", deal]);
        assert_eq!(r["settings"]["deal_bounds"], deal);
    }
    // On lavapipe the runs above draw on the CPU (`--rasteriser auto`); the
    // device's drawing gives the same bits on any rank count too, the
    // packed lattice of 1 x 1 tiles included.
    let device = ["--rasteriser", "device"];
    let one = mpirun(1, dir.path(), "device-n1", &device);
    assert_eq!(one["settings"]["rasteriser"], "device");
    for (ranks, tile) in [(2, "64x32"), (3, "1x1")] {
        let tag = format!("device-n{ranks}-{tile}");
        let r = mpirun(
            ranks,
            dir.path(),
            &tag,
            &[&device[..], &["--tile", tile]].concat(),
        );
        same_result(&one, &r, &tag);
    }
}

#[test]
fn split_shots_agree_across_ranks() {
    // Long enough that some shooters have a near receiver partly hidden and
    // split their shot: the decision is gathered, so every rank splits alike.
    let dir = tempfile::tempdir().expect("temp dir");
    let one = mpirun(1, dir.path(), "one", &["--max-shots", "600"]);
    assert!(
        one["timings"]["split_shots"].as_u64().expect("split count") > 0,
        "no split shot in 600"
    );
    for exchange in ["hemispheres", "sparse"] {
        let tag = format!("three-{exchange}");
        let r = mpirun(
            3,
            dir.path(),
            &tag,
            &["--max-shots", "600", "--exchange", exchange],
        );
        same_result(&one, &r, &tag);
        assert_eq!(r["timings"]["split_shots"], one["timings"]["split_shots"]);
    }
}

#[test]
fn bytes_exchanged_match_the_formulas() {
    let dir = tempfile::tempdir().expect("temp dir");
    // 4 ranks on a 2 x 2 grid with the automatic 64 x 16 tiles split
    // 128 x 512 evenly.
    // The formulas are for the pure hemisphere method; hybrid form factors
    // also send per-element coverage counts to their owners (checked below).
    let pure = ["--form-factor", "hemisphere"];
    let h = mpirun(
        4,
        dir.path(),
        "h",
        &["--exchange", "hemispheres", pure[0], pure[1]],
    );
    let cells = 128.0 * 512.0;
    assert_eq!(
        h["parallel"]["formula_bytes_per_shot"].as_f64(),
        Some(4.0 * cells * 3.0 / 4.0)
    );
    assert_eq!(
        h["parallel"]["measured_bytes_per_shot"].as_f64(),
        Some(4.0 * cells * 3.0 / 4.0)
    );
    // Form factors: every rank receives the whole dense array, 8 bytes per element.
    let f = mpirun(
        4,
        dir.path(),
        "f",
        &["--exchange", "form-factors", pure[0], pure[1]],
    );
    let elements = f["counts"]["elements"].as_f64().expect("count");
    assert_eq!(
        f["parallel"]["measured_bytes_per_shot"].as_f64(),
        Some(8.0 * elements)
    );
    // Sparse sends no more than the dense array would.
    let s = mpirun(
        4,
        dir.path(),
        "s",
        &["--exchange", "sparse", pure[0], pure[1]],
    );
    let sparse = s["parallel"]["measured_bytes_per_shot"]
        .as_f64()
        .expect("bytes");
    assert!(sparse > 0.0 && sparse < 12.0 * elements, "sparse {sparse}");
    // Hybrid: the same dense array for form factors; hemispheres add at most
    // one (element, count) pair of 12 bytes per element.
    // (Hybrid refines the mesh by need, so each run has its own count.)
    let hf = mpirun(4, dir.path(), "hf", &["--exchange", "form-factors"]);
    let hf_elements = hf["counts"]["elements"].as_f64().expect("count");
    assert_eq!(
        hf["parallel"]["measured_bytes_per_shot"].as_f64(),
        Some(8.0 * hf_elements)
    );
    let hh = mpirun(4, dir.path(), "hh", &["--exchange", "hemispheres"]);
    let elements = hh["counts"]["elements"].as_f64().expect("count");
    let hb = hh["parallel"]["measured_bytes_per_shot"]
        .as_f64()
        .expect("bytes");
    assert!(
        hb > 4.0 * cells * 3.0 / 4.0 && hb <= 4.0 * cells * 3.0 / 4.0 + 12.0 * elements + 16.0,
        "hybrid hemispheres {hb}"
    );
    for r in [&h, &f, &s] {
        let lb = &r["parallel"]["load_balance"];
        let (min, mean, max) = (
            lb["min"].as_f64().expect("min"),
            lb["mean"].as_f64().expect("mean"),
            lb["max"].as_f64().expect("max"),
        );
        assert!(
            0.0 < min && min <= mean && mean <= max && max <= 1.0,
            "load balance {lb}"
        );
    }
}

#[test]
fn ranks_in_threads_under_mpirun_are_refused_with_a_reason() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = Command::new("mpirun")
        .args(["--oversubscribe", "-n", "2"])
        .arg(env!("CARGO_BIN_EXE_radiosity"))
        .args([
            "render",
            "cornell",
            "--width",
            "0",
            "--max-shots",
            "5",
            "--ranks",
            "2",
        ])
        .arg("--out-dir")
        .arg(dir.path())
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_btl", "self,vader,tcp")
        .output()
        .expect("mpirun (install openmpi-bin)");
    assert!(!out.status.success(), "--ranks 2 on 2 MPI ranks ran");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--ranks 2 under mpirun (2 ranks)"),
        "no reason given:\n{err}"
    );
}

#[test]
fn a_failure_on_one_rank_ends_every_rank_with_a_message_from_rank_zero() {
    let dir = tempfile::tempdir().expect("temp dir");
    let bin = env!("CARGO_BIN_EXE_radiosity");
    let out_dir = dir.path().to_str().expect("utf-8");
    // MPMD launch: rank 1 gets no Vulkan driver.
    let mut child = Command::new("mpirun")
        .args([
            "--oversubscribe",
            "-n",
            "1",
            bin,
            "render",
            "cornell",
            "--out-dir",
            out_dir,
            ":",
            "-n",
            "1",
        ])
        .args([
            "-x",
            "VK_ICD_FILENAMES=/nonexistent/icd.json",
            "-x",
            "VK_DRIVER_FILES=/nonexistent/icd.json",
        ])
        .args([bin, "render", "cornell", "--out-dir", out_dir])
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("mpirun (install openmpi-bin)");
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s;
        }
        if start.elapsed() > std::time::Duration::from_secs(120) {
            let _ = child.kill();
            panic!("ranks still running after 120 s: a failure on one rank must end them all");
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().expect("stderr"), &mut stderr)
        .expect("read");
    assert!(!status.success(), "should fail: {stderr}");
    assert!(
        stderr.contains("error: rank 1:") && stderr.contains("mesa-vulkan-drivers"),
        "rank 0 should name rank 1 and the package: {stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        !dir.path().join("cornell.json").exists(),
        "no report on failure"
    );
}

/// `radiosity render cornell` with the test settings of the fault tests:
/// slow enough (no row cache) to be stopped mid-solve, short enough to finish.
fn fault_run(ranks: usize, extra: &[&str]) -> Command {
    let bin = env!("CARGO_BIN_EXE_radiosity");
    let mut cmd = if ranks > 1 {
        let mut c = Command::new("mpirun");
        c.args(["--oversubscribe", "-n", &ranks.to_string(), bin]);
        c
    } else {
        Command::new(bin)
    };
    // No refinement pass: a signal or a fault that lands in the pass keeps
    // the pass's solution and refines from it (checkpoint.rs tests that),
    // so the same bits as a straight run need the stop in the final solve,
    // wherever a loaded machine's timing puts it.
    cmd.args([
        "render",
        "cornell",
        "--width",
        "0",
        "--no-cache",
        "--refine",
        "0",
    ])
    .args(["--threshold", "1e-6", "--max-shots", "2500"])
    .args(extra)
    .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
    .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
    .env("OMPI_MCA_btl", "self,vader,tcp")
    .stdout(std::process::Stdio::null())
    .stderr(std::process::Stdio::piped());
    cmd
}

fn report_at(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("report written")).expect("json")
}

/// Waits (bounded) for the child to end; returns its status, stderr and how long it took.
fn finish(
    child: std::process::Child,
    within: Duration,
) -> (std::process::ExitStatus, String, Duration) {
    let start = Instant::now();
    let mut child = child;
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            let mut err = String::new();
            if let Some(mut e) = child.stderr.take() {
                use std::io::Read;
                let _ = e.read_to_string(&mut err);
            }
            return (status, err, start.elapsed());
        }
        if start.elapsed() > within {
            let _ = child.kill();
            panic!("the job did not end within {within:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Resumes the fault tests' solve from `ck` on `ranks` ranks; its report.
fn resume(ranks: usize, ck: &Path, report: &Path) -> serde_json::Value {
    let (status, err, _) = finish(
        fault_run(
            ranks,
            &[
                "--resume",
                ck.to_str().expect("utf-8"),
                "--report",
                report.to_str().expect("utf-8"),
            ],
        )
        .spawn()
        .expect("run"),
        Duration::from_secs(120),
    );
    assert!(status.success(), "{err}");
    report_at(report)
}

#[test]
fn sigint_saves_and_a_resume_on_two_ranks_gives_the_same_bits() {
    let dir = tempfile::tempdir().expect("temp dir");
    let p = |n: &str| dir.path().join(n);
    let s = p("straight.json");
    let status = fault_run(1, &["--report", s.to_str().expect("utf-8")])
        .status()
        .expect("run");
    assert!(status.success());
    let ck = p("c.ckpt");
    let stopped = p("stopped.json");
    let child = fault_run(
        1,
        &[
            "--checkpoint",
            ck.to_str().expect("utf-8"),
            "--report",
            stopped.to_str().expect("utf-8"),
        ],
    )
    .spawn()
    .expect("run");
    std::thread::sleep(Duration::from_millis(1500));
    let _ = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status();
    let (status, err, _) = finish(child, Duration::from_secs(60));
    assert_eq!(status.code(), Some(130), "{err}");
    assert!(err.contains("--resume"), "{err}");
    let partial = report_at(&stopped);
    assert_eq!(partial["converged"], false);
    let resumed = resume(2, &ck, &p("resumed.json"));
    same_result(&resumed, &report_at(&s), "resumed on 2 ranks");
}

#[test]
fn a_killed_rank_ends_the_job_naming_it_and_the_job_resumes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let p = |n: &str| dir.path().join(n);
    let s = p("straight.json");
    assert!(fault_run(1, &["--report", s.to_str().expect("utf-8")])
        .status()
        .expect("run")
        .success());
    let ck = p("c.ckpt");
    let child = fault_run(
        2,
        &[
            "--checkpoint",
            ck.to_str().expect("utf-8"),
            "--checkpoint-every",
            "0.2",
            "--report",
            p("never.json").to_str().expect("utf-8"),
        ],
    )
    .spawn()
    .expect("mpirun");
    // Wait for a checkpoint, then kill one rank (a child of mpirun).
    let start = Instant::now();
    while !ck.exists() {
        assert!(start.elapsed() < Duration::from_secs(60), "no checkpoint");
        std::thread::sleep(Duration::from_millis(20));
    }
    let ranks = Command::new("pgrep")
        .args(["-P", &child.id().to_string()])
        .output()
        .expect("pgrep (procps)");
    let pid = String::from_utf8_lossy(&ranks.stdout)
        .lines()
        .last()
        .expect("a rank process")
        .trim()
        .to_string();
    let _ = Command::new("kill").args(["-KILL", &pid]).status();
    let (status, err, took) = finish(child, Duration::from_secs(30));
    assert!(!status.success());
    assert!(took < Duration::from_secs(10), "took {took:?}");
    assert!(
        err.contains("rank") && err.contains("signal 9"),
        "the message should name the rank: {err}"
    );
    // The last checkpoint resumes, here on one rank.
    let resumed = resume(1, &ck, &p("resumed.json"));
    same_result(&resumed, &report_at(&s), "resumed after a killed rank");
}

#[test]
fn under_mpirun_rank_0_bakes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("baked.glb");
    let r = mpirun(
        2,
        dir.path(),
        "bake",
        &["--bake", path.to_str().expect("utf-8")],
    );
    assert_eq!(r["bake"]["path"].as_str(), path.to_str());
    let scene = radiosity::scene::load(&path).expect("the bake loads");
    assert_eq!(scene.nodes.len(), 8);
}

#[test]
fn the_tessellated_projection_is_the_same_on_every_rank_count() {
    // Both projections are bitwise invariant across rank counts, tiles and
    // exchanges; the tessellated one always draws the full hemisphere and
    // discards other ranks' cells (a packed lattice would move its
    // vertices against the rasteriser's sub-pixel grid).
    let dir = tempfile::tempdir().expect("temp dir");
    let t = ["--projection", "tessellated"];
    let base = mpirun(1, dir.path(), "t1", &t);
    for (ranks, extra) in [
        (3, ["--exchange", "hemispheres"]),
        (4, ["--exchange", "sparse"]),
        (2, ["--tile", "8x4"]),
    ] {
        let tag = format!("t{ranks}-{}", extra[1]);
        let r = mpirun(ranks, dir.path(), &tag, &[t[0], t[1], extra[0], extra[1]]);
        same_result(&base, &r, &tag);
    }
    // And it is not the exact projection's result bit for bit (it is a
    // different approximation), so the flag really switches.
    let exact = mpirun(1, dir.path(), "e1", &[]);
    assert_ne!(exact["surfaces"], base["surfaces"]);
}

#[test]
fn weak_shooters_along_the_transport_agree_across_ranks() {
    // A weak shooter's row along the ambient term's transport is made by
    // each rank for its own elements only: the same bits as one rank, which
    // makes the whole row.
    let dir = tempfile::tempdir().expect("temp dir");
    let args = ["--max-shots", "200", "--transport-below", "0.05"];
    let one = mpirun(1, dir.path(), "one", &args);
    let transported = one["timings"]["transport_shots"]
        .as_u64()
        .expect("transport count");
    assert!(
        transported > 100,
        "{transported} of 200 shots along the transport"
    );
    for ranks in [2, 3] {
        let r = mpirun(ranks, dir.path(), &format!("n{ranks}"), &args);
        same_result(&one, &r, &format!("{ranks} ranks"));
        assert_eq!(
            r["timings"]["transport_shots"],
            one["timings"]["transport_shots"]
        );
    }
}

#[test]
fn batched_shots_agree_across_ranks_and_stay_close_to_one_at_a_time() {
    // Each rank draws whole hemispheres for its turns of a batch and sends
    // each row to its elements' owners: the same bits on any rank count.
    // A batch shoots from one state, so it converges a
    // little slower a shot than one shooter at a time, not much.
    let dir = tempfile::tempdir().expect("temp dir");
    let args = ["--max-shots", "60", "--batch", "4"];
    let one = mpirun(1, dir.path(), "one", &args);
    for ranks in [2, 3] {
        let r = mpirun(ranks, dir.path(), &format!("n{ranks}"), &args);
        same_result(&one, &r, &format!("{ranks} ranks, batches of 4"));
        assert_eq!(r["energy"], one["energy"]);
    }
    // Split shots' groups are dealt over the ranks in a second round of
    // their batch and travel back to their rows' drawers over MPI (the
    // Cornell box's 60 shots split none; this room's do).
    let split = ["--max-shots", "60", "--batch", "5"];
    let a = mpirun_scene(1, dir.path(), "split1", "family-stacked-2", &split);
    let b = mpirun_scene(2, dir.path(), "split2", "family-stacked-2", &split);
    same_result(&a, &b, "split shots in batches of 5");
    let c = mpirun_scene(3, dir.path(), "split3", "family-stacked-2", &split);
    same_result(&a, &c, "split shots in batches of 5, 3 ranks");
    let takers: std::collections::BTreeSet<_> = b["parallel"]["rows"]
        .as_array()
        .expect("rows")
        .iter()
        .filter(|x| x["round"] == 1)
        .map(|x| x["rank"].as_u64())
        .collect();
    assert_eq!(takers.len(), 2, "split groups drawn by {takers:?}");
    let single = mpirun(1, dir.path(), "single", &["--max-shots", "60"]);
    let (u1, u4) = (
        single["unshot_fraction"].as_f64().expect("unshot"),
        one["unshot_fraction"].as_f64().expect("unshot"),
    );
    assert!(
        u4 >= u1 * 0.98 && u4 <= u1 * 1.3,
        "unshot after 60 shots: {u4} batched, {u1} not"
    );
    assert_ne!(
        single["surfaces"], one["surfaces"],
        "a batch is not one shot at a time"
    );
}

#[test]
fn coarse_shots_agree_across_ranks() {
    // A weak shooter's coarse hemisphere is chosen from the gathered
    // power: the same whatever the rank count.
    let dir = tempfile::tempdir().expect("temp dir");
    let args = ["--max-shots", "400"];
    let one = mpirun(1, dir.path(), "one", &args);
    assert!(
        one["timings"]["coarse_shots"]
            .as_u64()
            .expect("coarse count")
            > 0,
        "no coarse shot in 400"
    );
    let two = mpirun(2, dir.path(), "two", &args);
    same_result(&one, &two, "two ranks");
    assert_eq!(
        two["timings"]["coarse_shots"],
        one["timings"]["coarse_shots"]
    );
}

#[test]
fn a_sun_and_a_sky_give_the_same_bits_on_every_rank_count() {
    let dir = tempfile::tempdir().expect("temp dir");
    let args = ["--sun", "0.3,0.5,1,20", "--sky", "0.2,0.25,0.4"];
    let one = mpirun(1, dir.path(), "one", &args);
    let emitted = one["energy"]["emitted"].as_f64().expect("emitted");
    assert!(emitted > 0.0);
    for ranks in [2, 3] {
        let r = mpirun(ranks, dir.path(), &format!("n{ranks}"), &args);
        same_result(&one, &r, &format!("{ranks} ranks with a sun and a sky"));
        assert_eq!(r["energy"], one["energy"]);
    }
}

#[test]
fn ranks_divide_the_bounds_of_scenes_of_many_small_polygons() {
    // Bounds (issue 19, item 1), counts, not times; the results stay the
    // same bits (the other tests here). Not dealt, a rank computes the
    // cell rectangles only of polygons whose bounding spheres may show in
    // its tiles: in a room of 512 cubes most faces are small and fall in
    // one rank's tiles, but the walls and the floor span every rank's.
    // Dealt (`--deal-bounds`, by default on scenes of 1024 polygons and
    // more), each polygon is bounded by one rank: the counts sum to one
    // rank's exactly.
    let dir = tempfile::tempdir().expect("temp dir");
    let args = ["--max-shots", "6", "--refine", "0"];
    let bounded = |r: &serde_json::Value| -> Vec<u64> {
        r["parallel"]["per_rank"]
            .as_array()
            .expect("per rank")
            .iter()
            .map(|s| s["bounded"].as_u64().expect("bounded"))
            .collect()
    };
    // The reference bounds what is in view: one rank culling on one core
    // skips what nearer polygons hide before bounding it (nearest first),
    // which the ranks' deal does not.
    let reference = [&args[..], &["--no-occlusion-cull"]].concat();
    let one_report = mpirun_scene(1, dir.path(), "one", "cubes-8", &reference);
    let one = bounded(&one_report)[0];
    assert!(one > 0, "one rank bounded nothing");
    for (ranks, deal, most) in [(2, "off", 0.75), (4, "off", 0.62)] {
        let tag = format!("n{ranks}-{deal}");
        let extra = [&args[..], &["--deal-bounds", deal]].concat();
        let r = mpirun_scene(ranks, dir.path(), &tag, "cubes-8", &extra);
        let per = bounded(&r);
        // Each polygon that shows in some rank's tiles is bounded by at
        // least that rank; none by a rank whose tiles it misses.
        assert!(
            per.iter().sum::<u64>() >= one && per.iter().all(|&k| k as f64 <= most * one as f64),
            "{tag}: proxies bounded {per:?} of {one} (at most {most} each)"
        );
        eprintln!("{tag}: proxies bounded {per:?} of {one}");
    }
    // Polygons dealt in turn: within a third of an even share.
    for (ranks, deal) in [(2, "on"), (3, "on"), (4, "auto")] {
        let tag = format!("n{ranks}-{deal}");
        let extra = [&args[..], &["--deal-bounds", deal]].concat();
        let r = mpirun_scene(ranks, dir.path(), &tag, "cubes-8", &extra);
        same_result(&one_report, &r, &tag);
        let per = bounded(&r);
        let most = 1.33 / ranks as f64;
        assert!(
            per.iter().sum::<u64>() == one && per.iter().all(|&k| k as f64 <= most * one as f64),
            "{tag}: proxies bounded {per:?} of {one} (exactly, at most {most} each)"
        );
        let received: u64 = r["parallel"]["per_rank"]
            .as_array()
            .expect("per rank")
            .iter()
            .map(|s| s["rect_bytes_received"].as_u64().expect("rect bytes"))
            .sum();
        assert!(received > 0, "{tag}: no rectangles travelled");
        eprintln!("{tag}: proxies bounded {per:?} of {one}, {received} bytes of rectangles");
    }
}

#[test]
fn ranks_divide_the_hemisphere_cells_and_say_what_they_repeat() {
    // Work counted, not timed (issue 19): the cells each rank draws sum to
    // the one-rank count and are split evenly; what each rank repeats
    // (rectangles bounded, receivers summed) is in the report beside it.
    let dir = tempfile::tempdir().expect("temp dir");
    let one = mpirun(1, dir.path(), "one", &[]);
    let count = |r: &serde_json::Value, key: &str| -> Vec<u64> {
        r["parallel"]["per_rank"]
            .as_array()
            .expect("per rank")
            .iter()
            .map(|s| s[key].as_u64().unwrap_or_else(|| panic!("{key}")))
            .collect()
    };
    let cells = count(&one, "cells")[0];
    assert!(cells > 0, "one rank drew no cells");
    assert!(
        count(&one, "peak_resident_bytes")[0] > 0,
        "peak memory missing"
    );
    for ranks in [2, 3, 4] {
        let r = mpirun(ranks, dir.path(), &format!("n{ranks}"), &[]);
        let per = count(&r, "cells");
        assert_eq!(per.iter().sum::<u64>(), cells, "{ranks} ranks: {per:?}");
        // Tiles dealt by 2-D interleave, as many to each rank: within the
        // narrower last row or column of tiles of an even split.
        let fair = cells as f64 / ranks as f64;
        let slack = 0.05;
        assert!(
            per.iter().all(|&c| (c as f64) <= fair * (1.0 + slack)),
            "{ranks} ranks: {per:?} (even: {fair})"
        );
        // Each rank sums the form factors of its own receivers only
        // (owner computes): the one-rank count, split by patch ownership.
        let receivers = count(&r, "receivers");
        let all = count(&one, "receivers")[0];
        assert_eq!(
            receivers.iter().sum::<u64>(),
            all,
            "{ranks} ranks: {receivers:?}"
        );
        let fair = all as f64 / ranks as f64;
        assert!(
            receivers.iter().all(|&c| (c as f64) <= fair * 1.1),
            "{ranks} ranks: receivers {receivers:?} (even: {fair})"
        );
        // Rectangles: each rank draws those that hold some of its cells
        // (with 1 x 1 tiles, nearly all of them; see docs/notebook/ranks.md "Ranks"), or,
        // dealing the bounds (`auto`: scenes of 1024 polygons and more,
        // not this box), finds those of its polygons.
        // Either way at most 3/4 of them from 2 ranks on.
        let rects = count(&r, "rects");
        let one_rects = count(&one, "rects")[0];
        assert!(
            rects.iter().all(|&k| k as f64 <= 0.75 * one_rects as f64),
            "{ranks} ranks: rectangles {rects:?} of {one_rects}"
        );
        eprintln!(
            "{ranks} ranks: cells {per:?}, rects {rects:?}, receivers {:?} (one rank: {cells} cells, {one_rects} rects, {:?} receivers)",
            count(&r, "receivers"),
            count(&one, "receivers")
        );
    }
}

#[test]
fn a_cluttered_scene_gives_the_same_bits_culled_on_one_rank_and_on_five() {
    // The 4096-cube room: one rank culls the hidden polygons
    // (`crate::occlusion`) and scans its 69 000 patches for far receivers
    // on every core; five ranks cull what is hidden in every rank's tiles
    // (agreed by a gather) and scan their 14 000 patches each on one
    // thread. The same bits.
    let dir = tempfile::tempdir().expect("temp dir");
    let args = ["--max-shots", "12", "--refine", "0"];
    let one = mpirun_scene(1, dir.path(), "one", "cubes-16", &args);
    // Left out after bounding, or (one rank on one core, nearest first)
    // before.
    let left_out = |r: &serde_json::Value| {
        r["timings"]["occluded_per_shot"]
            .as_f64()
            .expect("occluded")
            + r["timings"]["skipped_per_shot"].as_f64().expect("skipped")
    };
    assert!(
        left_out(&one) > 1000.0,
        "little was culled: {}",
        left_out(&one)
    );
    let five = mpirun_scene(5, dir.path(), "five", "cubes-16", &args);
    same_result(&one, &five, "five ranks");
    // Five ranks agree to leave out what is hidden in all their tiles.
    let culled = five["timings"]["occluded_per_shot"]
        .as_f64()
        .expect("occluded");
    assert!(culled > 100.0, "five ranks culled {culled} a shot");
    // With 1 x 1 tiles (the packed lattice) no rank culls; the same bits.
    let lattice = mpirun_scene(
        2,
        dir.path(),
        "lattice",
        "cubes-16",
        &[&args[..], &["--tile", "1x1"]].concat(),
    );
    same_result(&one, &lattice, "lattice");
    assert_eq!(lattice["timings"]["occluded_per_shot"].as_f64(), Some(0.0));
}

/// Renders `scene` with `args` on one rank and on two (in `dir`): the
/// same report numbers and the same image bytes. Returns the one rank's
/// report.
fn one_and_two_ranks_agree(
    dir: &Path,
    scene: &str,
    args: &[&str],
    what: &str,
) -> serde_json::Value {
    let one = mpirun_scene(1, dir, "one", scene, args);
    let two = mpirun_scene(2, dir, "two", scene, args);
    same_result(&one, &two, &format!("2 ranks {what}"));
    let image = |tag: &str| std::fs::read(dir.join(format!("{tag}.exr"))).expect("image");
    assert!(image("one") == image("two"), "the images differ {what}");
    one
}

#[test]
fn a_sky_map_gives_the_same_bits_on_every_rank_count() {
    // The map's rays are drawn per element from its own seed, as the
    // uniform sky's are: every rank computes the same field.
    let dir = tempfile::tempdir().expect("temp dir");
    let map = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/docs/references/maps/window-sun.exr"
    );
    let args = [
        "--sky-map",
        map,
        "--sky-rotation",
        "10",
        "--max-shots",
        "60",
    ];
    let one = one_and_two_ranks_agree(dir.path(), "family-furnished-1", &args, "under a sky map");
    assert!(one["sky_map"]
        .as_str()
        .is_some_and(|m| m.contains("window-sun.exr")));
}

#[test]
fn a_sun_sky_gives_the_same_bits_on_every_rank_count() {
    let dir = tempfile::tempdir().expect("temp dir");
    let args = ["--sun-sky", "35,240,4", "--max-shots", "60"];
    let one = one_and_two_ranks_agree(dir.path(), "family-furnished-1", &args, "under a sun-sky");
    assert!(one["sky_map"]
        .as_str()
        .is_some_and(|m| m.contains("sun-sky 35.0,240.0,4.0")));
}

#[test]
fn an_emissive_texture_gives_the_same_bits_on_every_rank_count() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = crate::emissive::PANEL_ROOM;
    let what = "lit by an emissive texture";
    one_and_two_ranks_agree(dir.path(), scene, &["--max-shots", "60"], what);
}

#[test]
fn an_alpha_mask_gives_the_same_bits_on_every_rank_count() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("masked.gltf");
    let doc = crate::masks::masked_doc(Some("MASK"));
    std::fs::write(&path, serde_json::to_vec(&doc).expect("JSON")).expect("write");
    let scene = path.to_str().expect("utf-8");
    one_and_two_ranks_agree(dir.path(), scene, &[], "with a masked surface");
}
