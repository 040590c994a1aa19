//! A fixed corpus of broken scenes (`radiosity_lab::fuzz`): every case is a clear
//! error or a render whose report has only finite numbers; none panics or
//! hangs. (`radiosity-lab fuzz --cases 10000` runs the long version.)

use radiosity::gpu::Gpu;
use radiosity_lab::fuzz::{case, check, Outcome};
use std::sync::OnceLock;
use std::time::Duration;

/// One device for the file's tests (a missing adapter fails them, naming the package).
fn gpu() -> &'static Gpu {
    static GPU: OnceLock<Gpu> = OnceLock::new();
    GPU.get_or_init(|| Gpu::new().unwrap_or_else(|e| panic!("{e}")))
}

#[test]
fn three_hundred_broken_scenes_end_in_clear_errors_or_finite_renders() {
    let base: serde_json::Value =
        serde_json::from_str(&radiosity::scene::builtin_gltf("cornell").expect("cornell"))
            .expect("json");
    let dir = tempfile::tempdir().expect("temp dir");
    let (mut rejected, mut rendered, mut failed) = (0, 0, 0);
    let mut bugs = Vec::new();
    let gpu = gpu();
    for seed in 0..300 {
        let c = case(&base, seed);
        match check(gpu, &c, dir.path(), Duration::from_secs(60)) {
            Outcome::Rejected(why) => {
                if std::env::var_os("FUZZ_VERBOSE").is_some() {
                    eprintln!("{} -> {why}", c.name);
                }
                rejected += 1;
                assert!(!why.trim().is_empty(), "{}: an empty error", c.name);
            }
            Outcome::Rendered => rendered += 1,
            Outcome::Failed(_) => failed += 1,
            bug => bugs.push(format!("{}: {bug:?}", c.name)),
        }
    }
    eprintln!("{rejected} rejected, {rendered} rendered, {failed} failed with an error");
    assert!(bugs.is_empty(), "{} bugs:\n{}", bugs.len(), bugs.join("\n"));
    // The corpus exercises both paths.
    assert!(
        rejected >= 100 && rendered >= 20,
        "{rejected} rejected, {rendered} rendered"
    );
}

#[test]
fn what_the_long_fuzz_run_found_stays_fixed() {
    let base: serde_json::Value =
        serde_json::from_str(&radiosity::scene::builtin_gltf("cornell").expect("cornell"))
            .expect("json");
    let dir = tempfile::tempdir().expect("temp dir");
    let gpu = gpu();
    // Case 1080: float indices reached an `unreachable!` in the gltf crate.
    let c = case(&base, 1080);
    match check(gpu, &c, dir.path(), Duration::from_secs(60)) {
        Outcome::Rejected(why) => assert!(
            why.contains("index accessor") && why.contains("the glTF spec requires"),
            "{why}"
        ),
        other => panic!("{}: {other:?}", c.name),
    }
    // Case 4590: a POSITION accessor index out of range panicked inside
    // gltf-json's own validator.
    let c = case(&base, 4590);
    match check(gpu, &c, dir.path(), Duration::from_secs(60)) {
        Outcome::Rejected(why) => assert!(why.contains("accessor 8000000 does not exist"), "{why}"),
        other => panic!("{}: {other:?}", c.name),
    }
}
