//! Bad input gets a one-line error naming the cause, a non-zero exit and no panic.

use crate::common::*;
use glam::Vec3;
use std::process::Command;

fn run(args: &[&str], envs: &[(&str, &str)]) -> (i32, String) {
    let out_dir = tempfile::tempdir().expect("temp dir");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_radiosity"));
    cmd.args(args)
        .arg("--out-dir")
        .arg(out_dir.path())
        .arg("--max-shots")
        .arg("3")
        .arg("--width")
        .arg("16");
    for (k, v) in envs {
        cmd.env(k, v);
    }
    let out = cmd.output().expect("run radiosity");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    (out.status.code().unwrap_or(-1), stderr)
}

fn expect_error(args: &[&str], needle: &str) {
    let (code, stderr) = run(args, &[]);
    assert_ne!(code, 0, "should fail: {stderr}");
    let line = stderr
        .lines()
        .find(|l| l.starts_with("error:"))
        .unwrap_or_else(|| panic!("no error line in: {stderr}"));
    assert!(
        line.contains(needle),
        "error line '{line}' should mention '{needle}'"
    );
}

fn render_args(path: &std::path::Path) -> Vec<String> {
    vec!["render".into(), path.to_string_lossy().into_owned()]
}

#[test]
fn missing_file() {
    expect_error(
        &["render", "/nonexistent/scene.gltf"],
        "/nonexistent/scene.gltf",
    );
}

#[test]
fn unknown_name() {
    expect_error(&["render", "no-such-scene"], "no-such-scene");
}

#[test]
fn truncated_gltf() {
    let (dir, path) = write_scene(
        "good",
        &[surface(
            "light",
            vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
            0.5,
            1.0,
        )],
    );
    let text = std::fs::read(&path).expect("read");
    let cut = dir.path().join("cut.gltf");
    std::fs::write(&cut, &text[..text.len() / 2]).expect("write");
    let args = render_args(&cut);
    expect_error(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        "cut.gltf",
    );
    // A .glb that is not binary glTF at all.
    let glb = dir.path().join("junk.glb");
    std::fs::write(&glb, b"glTF\x02\x00\x00\x00junk").expect("write");
    let args = render_args(&glb);
    expect_error(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        "junk.glb",
    );
}

#[test]
fn no_triangles() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("empty.gltf");
    std::fs::write(
        &path,
        r#"{"asset":{"version":"2.0"},"scenes":[{"nodes":[0]}],"nodes":[{"name":"nothing"}]}"#,
    )
    .expect("write");
    let args = render_args(&path);
    expect_error(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        "no triangles",
    );
}

#[test]
fn no_emitter() {
    let (_dir, path) = write_scene(
        "dark",
        &[surface(
            "wall",
            vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
            0.5,
            0.0,
        )],
    );
    let args = render_args(&path);
    expect_error(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        "no emitter",
    );
}

#[test]
fn non_finite_coordinates() {
    // A node scale that overflows f32 turns finite vertices into infinities.
    let (_dir, path) = write_scene(
        "huge",
        &[surface(
            "light",
            vec![rect(2, 1e10, [0.0, 0.0], [1e10, 1e10], true)],
            0.5,
            1.0,
        )],
    );
    let text = std::fs::read_to_string(&path).expect("read");
    let text = text.replacen(
        "\"mesh\": 0,",
        "\"mesh\": 0, \"scale\": [1e30, 1e30, 1e30],",
        1,
    );
    std::fs::write(&path, text).expect("write");
    let args = render_args(&path);
    expect_error(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        "node 'light': non-finite",
    );
}

#[test]
fn degenerate_triangles_are_skipped_with_a_warning() {
    let light = rect(2, 1.0, [0.0, 0.0], [1.0, 1.0], false);
    let floor = rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true);
    let sliver = vec![Vec3::ZERO, Vec3::X, Vec3::new(2.0, 0.0, 0.0)];
    let (_dir, path) = write_scene(
        "sliver",
        &[
            surface("light", vec![light], 0.0, 1.0),
            surface("floor", vec![floor, sliver], 0.5, 0.0),
        ],
    );
    let report = path.with_extension("json");
    let (code, stderr) = run(
        &[
            "render",
            path.to_str().expect("utf-8"),
            "--report",
            report.to_str().expect("utf-8"),
        ],
        &[],
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.contains("degenerate"), "warning expected: {stderr}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert!(json["warnings"][0]
        .as_str()
        .expect("warning")
        .contains("degenerate"));
    assert!(
        json["surfaces"][1]["radiosity"][0]
            .as_f64()
            .expect("number")
            > 0.0
    );
}

#[test]
fn no_vulkan_adapter() {
    let (code, stderr) = run(
        &["render", "cornell"],
        &[
            ("VK_ICD_FILENAMES", "/nonexistent/icd.json"),
            ("VK_DRIVER_FILES", "/nonexistent/icd.json"),
        ],
    );
    assert_ne!(code, 0, "should fail without a driver: {stderr}");
    assert!(
        stderr.contains("mesa-vulkan-drivers"),
        "should name the package: {stderr}"
    );
}

/// A one-node scene whose material JSON gets `edit` applied.
fn scene_with_material(
    name: &str,
    edit: impl Fn(String) -> String,
) -> (tempfile::TempDir, Vec<String>) {
    let (dir, path) = write_scene(
        name,
        &[surface(
            "lamp",
            vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
            0.5,
            1.0,
        )],
    );
    let text = std::fs::read_to_string(&path).expect("read");
    std::fs::write(&path, edit(text)).expect("write");
    (dir, render_args(&path))
}

#[test]
fn reflectance_above_one_is_an_error() {
    // It would create energy: the issue's room came out 7x too bright.
    let (_dir, args) = scene_with_material("bright", |t| {
        let mut json: serde_json::Value = serde_json::from_str(&t).expect("json");
        json["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] =
            serde_json::json!([1.5, 0.5, 0.5, 1.0]);
        json.to_string()
    });
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    expect_error(&args, "node 'lamp'");
    expect_error(&args, "baseColorFactor");
}

#[test]
fn negative_emissive_strength_is_an_error() {
    let (_dir, args) = scene_with_material("negative", |t| {
        let mut json: serde_json::Value = serde_json::from_str(&t).expect("json");
        json["materials"][0]["extensions"] = serde_json::json!({
            "KHR_materials_emissive_strength": { "emissiveStrength": -3.0 }
        });
        json["extensionsUsed"] = serde_json::json!(["KHR_materials_emissive_strength"]);
        json.to_string()
    });
    expect_error(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        "KHR_materials_emissive_strength",
    );
}

#[test]
fn flags_are_checked_when_parsed() {
    for (flag, value) in [
        ("--patch-size", "0"),
        ("--patch-size", "-1"),
        ("--element-size", "nan"),
        ("--near-field-ratio", "0"),
        ("--threshold", "2"),
        ("--height", "0"),
        ("--max-patches-per-edge", "0"),
    ] {
        let arg = format!("{flag}={value}");
        let (code, stderr) = run(&["render", "cornell", &arg], &[]);
        assert_ne!(code, 0, "{flag} {value} should fail: {stderr}");
        assert!(
            stderr.contains(flag) && stderr.contains("error"),
            "{flag} {value}: {stderr}"
        );
    }
}

#[test]
fn a_report_with_a_non_finite_number_is_caught() {
    let scene = radiosity::scene::open("cornell").expect("scene");
    let mut opts = tight(1e-3);
    opts.stop.max_shots = 5;
    let mut r =
        radiosity::render::render(gpu(), &scene, &opts, std::time::Duration::ZERO, &mut |_| {})
            .expect("render");
    assert_eq!(r.report.non_finite(), None);
    r.report.convergence[2].surfaces[1].radiosity[0] = f64::NAN;
    let what = r.report.non_finite().expect("caught");
    assert!(
        what.contains("ceiling") && what.contains("3 shots"),
        "{what}"
    );
    r.report.surfaces[0].radiosity[2] = f64::INFINITY;
    assert_eq!(r.report.non_finite().as_deref(), Some("surface 'floor'"));
}

#[test]
fn an_accessor_past_its_buffer_is_an_error() {
    // The issue's case: a count of 1e9 skipped the floor and rendered without it.
    let (_dir, args) = scene_with_material("count", |t| {
        let mut json: serde_json::Value = serde_json::from_str(&t).expect("json");
        let acc = json["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
            .as_u64()
            .expect("position accessor") as usize;
        json["accessors"][acc]["count"] = serde_json::json!(1_000_000_000u64);
        json.to_string()
    });
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    expect_error(&args, "node 'lamp'");
}

#[test]
fn a_world_of_one_under_a_launcher_of_several_is_an_error() {
    // N independent solves would all write the same files.
    let (code, stderr) = run(&["render", "cornell"], &[("OMPI_COMM_WORLD_SIZE", "3")]);
    assert_ne!(code, 0, "should fail: {stderr}");
    assert!(
        stderr.contains("started 3 processes") && stderr.contains("world of 1"),
        "{stderr}"
    );
}

#[test]
fn an_output_that_cannot_be_written_fails_before_the_solve() {
    // A file where a directory should be, and a directory where a file
    // should be: the error names them at once (before, the solve ran and
    // its results were lost at the end, with "File exists" for a reason).
    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("not-a-dir");
    std::fs::write(&file, b"x").expect("write");
    let under = |name: &str| file.join(name).to_string_lossy().into_owned();
    let named = format!("'{}' is a file, not a directory", file.display());
    for flag in ["--report", "--image", "--checkpoint", "--bake"] {
        expect_error(&["render", "cornell", flag, &under("out")], &named);
    }
    let here = dir.path().to_string_lossy().into_owned();
    expect_error(
        &["render", "cornell", "--report", &here],
        "it is a directory",
    );
    // Nothing was written where the outputs could go.
    assert_eq!(std::fs::read_dir(dir.path()).expect("list").count(), 1);
    // No image (--width 0) needs no place for one.
    let out = Command::new(env!("CARGO_BIN_EXE_radiosity"))
        .args(["render", "cornell", "--width", "0", "--max-shots", "2"])
        .arg("--image")
        .arg(under("x.exr"))
        .arg("--out-dir")
        .arg(dir.path().join("out"))
        .output()
        .expect("run radiosity");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(dir.path().join("out").join("cornell.json").is_file());
}
