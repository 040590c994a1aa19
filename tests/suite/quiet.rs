//! A headless run prints nothing that looks like an error when nothing is
//! wrong (issue 61): Mesa's device-selection layer used to print
//! "error: XDG_RUNTIME_DIR is invalid or not set" twice on every run
//! without a window system.

use std::process::Command;

#[test]
fn a_headless_render_prints_nothing_that_looks_like_an_error() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = Command::new(env!("CARGO_BIN_EXE_radiosity"))
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("NODEVICE_SELECT")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("DISPLAY")
        .args(["render", "cornell", "--max-shots", "5", "--width", "32"])
        .args(["--refine", "0", "--out-dir"])
        .arg(dir.path())
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        !stderr.to_lowercase().contains("error"),
        "a clean run said: {stderr}"
    );
}
