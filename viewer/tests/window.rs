//! The viewer in a real window under Xvfb with lavapipe: it solves, draws and
//! saves a screenshot; bad input is a clear error.

use std::process::Command;

fn viewer() -> Command {
    let mut cmd = Command::new("xvfb-run");
    cmd.args([
        "-a",
        "-s",
        "-screen 0 1400x900x24",
        env!("CARGO_BIN_EXE_radiosity-viewer"),
    ]);
    cmd
}

#[test]
fn screenshot_shows_the_cornell_box_the_right_way_round() {
    let dir = tempfile::tempdir().expect("temp dir");
    let shot = dir.path().join("viewer.png");
    let stats = dir.path().join("frames.json");
    let out = viewer()
        .args(["cornell", "--shots", "40", "--screenshot"])
        .arg(&shot)
        .arg("--frame-stats")
        .arg(&stats)
        .output()
        .unwrap_or_else(|e| {
            panic!("cannot run xvfb-run ({e}): install xvfb (scripts/setup.sh does)")
        });
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "viewer failed: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    // Frame times are measured (a benchmark, not a pass condition).
    let f: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&stats).expect("frame stats written"))
            .expect("json");
    assert!(f["frames"].as_u64().is_some_and(|n| n >= 2), "{f}");
    assert!(f["ui_ms_median"].as_f64().is_some_and(|x| x > 0.0), "{f}");
    eprintln!("frame times: {f}");
    let img = image::open(&shot).expect("a PNG screenshot").to_rgb8();
    // Not blank: many distinct colours.
    let mut colours: Vec<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    colours.sort_unstable();
    colours.dedup();
    assert!(
        colours.len() > 500,
        "screenshot looks blank ({} colours)",
        colours.len()
    );
    // The red wall left of the green wall: centroids of strongly red and green pixels.
    let (mut red, mut green) = ((0u64, 0u64), (0u64, 0u64));
    for (x, _, p) in img.enumerate_pixels() {
        let [r, g, b] = p.0.map(u32::from);
        if r > 120 && r > 2 * g && r > 2 * b {
            red = (red.0 + x as u64, red.1 + 1);
        }
        if g > 100 && g > r + r / 4 && g > 2 * b {
            green = (green.0 + x as u64, green.1 + 1);
        }
    }
    assert!(
        red.1 > 5000 && green.1 > 5000,
        "walls not found: {} red, {} green pixels",
        red.1,
        green.1
    );
    assert!(
        red.0 / red.1 < green.0 / green.1,
        "the red wall must be on the left of the green one"
    );
}

/// Runs the viewer with `args`: it must fail with one clear error line that
/// names `what`, and no panic.
fn fails_clearly(args: &[&str], what: &str) {
    let out = viewer()
        .args(args)
        .output()
        .expect("xvfb-run (install xvfb)");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("error:") && stderr.contains(what),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn bad_scene_is_a_clear_error() {
    fails_clearly(&["/nonexistent/scene.gltf"], "/nonexistent/scene.gltf");
}

#[test]
fn an_unknown_camera_is_a_clear_error() {
    fails_clearly(&["cornell", "--camera", "no-such-camera"], "no-such-camera");
}

#[test]
fn a_sun_and_a_sky_light_the_view_and_a_bad_sun_is_a_clear_error() {
    let dir = tempfile::tempdir().expect("temp dir");
    let shot = dir.path().join("sun.png");
    let out = viewer()
        .args([
            "cornell",
            "--shots",
            "10",
            "--sun",
            "0.3,0.5,1,50",
            "--sky",
            "0.2",
        ])
        .arg("--screenshot")
        .arg(&shot)
        .output()
        .expect("xvfb-run (install xvfb)");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "viewer failed: {stderr}");
    let img = image::open(&shot).expect("a PNG screenshot").to_rgb8();
    let mut colours: Vec<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    colours.sort_unstable();
    colours.dedup();
    assert!(colours.len() > 500, "screenshot looks blank");
    fails_clearly(&["cornell", "--sun", "0,0,0,5"], "--sun");
}
