//! Mutated scenes for robustness checks: a deterministic generator of
//! broken glTF and GLB files from a good one, and the check every case must
//! pass (a clear error, or a render whose report has only finite numbers;
//! never a panic, never a hang). `radiosity-lab fuzz` runs thousands of cases;
//! the test suite runs a fixed corpus of a few hundred.

pub use radiosity::rng::Rng;
use serde_json::Value;

/// One generated input file.
#[derive(Clone, Debug)]
pub struct Case {
    /// Which case: its seed and what was done to it.
    pub name: String,
    /// `gltf` or `glb`.
    pub ext: &'static str,
    /// The file's bytes.
    pub bytes: Vec<u8>,
}

/// Values that break things: out of range, wrong type, extreme.
fn nasty(rng: &mut Rng) -> Value {
    let pick = [
        serde_json::json!(0),
        serde_json::json!(-1),
        serde_json::json!(1.5),
        serde_json::json!(1e9),
        serde_json::json!(-1e9),
        serde_json::json!(4_294_967_296u64),
        serde_json::json!(3.5e38),
        serde_json::json!(1e300),
        serde_json::json!(1e-45),
        serde_json::json!(null),
        serde_json::json!("NaN"),
        serde_json::json!([]),
        serde_json::json!({}),
        serde_json::json!(true),
    ];
    pick[rng.below(pick.len())].clone()
}

/// Every path (object keys and array indices) in `v`, depth first.
fn paths(v: &Value, at: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
    out.push(at.clone());
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                at.push(k.clone());
                paths(x, at, out);
                at.pop();
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                at.push(i.to_string());
                paths(x, at, out);
                at.pop();
            }
        }
        _ => {}
    }
}

fn get_mut<'a>(v: &'a mut Value, path: &[String]) -> Option<&'a mut Value> {
    let mut v = v;
    for k in path {
        v = match v {
            Value::Object(m) => m.get_mut(k)?,
            Value::Array(a) => a.get_mut(k.parse::<usize>().ok()?)?,
            _ => return None,
        };
    }
    Some(v)
}

/// One mutation of a glTF document; returns what it did.
fn mutate_json(doc: &mut Value, rng: &mut Rng) -> String {
    let mut all = Vec::new();
    paths(doc, &mut Vec::new(), &mut all);
    // The buffer's data URI is huge and uninteresting as a path: keep it
    // for the byte-level mutations.
    all.retain(|p| p.last().is_none_or(|k| k != "uri"));
    // Mostly perturb numbers (loads, then renders something odd), else
    // break the structure (types, missing keys, extra items).
    let kind = [0, 1, 2, 3, 3, 3, 3, 3][rng.below(8)];
    if kind == 3 {
        let numbers: Vec<&Vec<String>> = all
            .iter()
            .filter(|p| get_mut(&mut doc.clone(), p).is_some_and(|v| v.is_number()))
            .collect();
        if let Some(path) = numbers.get(rng.below(numbers.len())).map(|p| (*p).clone()) {
            let name = path.join("/");
            if let Some(Value::Number(n)) = get_mut(doc, &path) {
                let x = n.as_f64().unwrap_or(0.0);
                let integer = n.is_u64() || n.is_i64();
                let y = match rng.below(6) {
                    0 => x * 1e6,
                    1 => -x,
                    2 => x * 1e-6,
                    3 => x + 1.0,
                    4 => x * 1e30,
                    _ => x * (1.0 + 1e-7),
                };
                let v = if integer && y.fract() == 0.0 && y.abs() < 1e18 {
                    Some(serde_json::Number::from(y as i64))
                } else {
                    serde_json::Number::from_f64(y)
                };
                if let Some(v) = v {
                    *n = v;
                }
                return format!("{name}: {x} -> {y}");
            }
        }
    }
    let path = all[rng.below(all.len())].clone();
    let name = path.join("/");
    let Some(target) = get_mut(doc, &path) else {
        return format!("nothing at {name}");
    };
    match (kind, target) {
        (1, Value::Object(m)) if !m.is_empty() => {
            let keys: Vec<String> = m.keys().cloned().collect();
            let k = keys[rng.below(keys.len())].clone();
            m.remove(&k);
            format!("removed {name}/{k}")
        }
        (2, Value::Array(a)) if !a.is_empty() => {
            let i = rng.below(a.len());
            let x = a[i].clone();
            a.push(x);
            format!("duplicated {name}/{i}")
        }
        (_, t) => {
            let v = nasty(rng);
            let what = format!("{name} = {v}");
            *t = v;
            what
        }
    }
}

/// Flips, zeroes or cuts bytes.
fn mutate_bytes(bytes: &mut Vec<u8>, rng: &mut Rng, from: usize) -> String {
    if bytes.len() <= from {
        return "nothing to mutate".into();
    }
    match rng.below(4) {
        0 => {
            let at = from + rng.below(bytes.len() - from);
            bytes.truncate(at);
            format!("cut at {at}")
        }
        1 => {
            let mut hit = Vec::new();
            for _ in 0..1 + rng.below(8) {
                let at = from + rng.below(bytes.len() - from);
                bytes[at] ^= 1 << rng.below(8);
                hit.push(at);
            }
            format!("flipped bits at {hit:?}")
        }
        2 => {
            let at = from + rng.below(bytes.len() - from);
            let n = (bytes.len() - at).min(1 + rng.below(64));
            bytes[at..at + n].fill(0xff);
            format!("0xff x {n} at {at}")
        }
        _ => {
            let at = from + rng.below(bytes.len() - from);
            let v = [0u8, 0x7f, 0x80, 0xff][rng.below(4)];
            bytes[at] = v;
            format!("byte {at} = {v:#x}")
        }
    }
}

/// Case `seed` made from the glTF document `base` (JSON with an embedded
/// buffer): one to three mutations of its JSON, of its buffer's bytes, or of
/// the GLB made from it.
pub fn case(base: &Value, seed: u64) -> Case {
    let mut rng = Rng(seed.wrapping_mul(0x2545_f491_4f6c_dd1d) ^ 0x5151);
    let glb = rng.below(3) == 0;
    let mut doc = base.clone();
    let mut done = Vec::new();
    let n = 1 + rng.below(3);
    let bytes_only = rng.below(4) == 0;
    if !bytes_only {
        for _ in 0..n {
            done.push(mutate_json(&mut doc, &mut rng));
        }
    }
    let (ext, mut bytes) = if glb {
        ("glb", radiosity::scene::to_glb(&doc).unwrap_or_default())
    } else {
        ("gltf", serde_json::to_vec(&doc).unwrap_or_default())
    };
    if bytes_only || rng.below(4) == 0 {
        // Bytes, mostly of the geometry: GLB's BIN chunk (raw floats and
        // indices) or the glTF's base64 data; now and then anywhere.
        let data = if glb {
            bytes
                .get(12..16)
                .map(|l| 12 + 8 + u32::from_le_bytes([l[0], l[1], l[2], l[3]]) as usize + 8)
        } else {
            bytes
                .windows(7)
                .position(|w| w == b"base64,")
                .map(|i| i + 7)
        };
        let from = match data {
            Some(d) if rng.below(4) != 0 => d,
            _ => 4,
        };
        done.push(mutate_bytes(&mut bytes, &mut rng, from));
    }
    Case {
        name: format!("case {seed} ({ext}): {}", done.join("; ")),
        ext,
        bytes,
    }
}

/// What a case came to.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    /// The loader refused it, saying why (fine).
    Rejected(String),
    /// It rendered, every number in the report finite (fine).
    Rendered,
    /// It loaded but the render stopped with an error, saying why (fine).
    Failed(String),
    /// The report would have held a non-finite number (a bug).
    NonFinite(String),
    /// Something panicked (a bug).
    Panicked(String),
    /// It took longer than the limit (a bug).
    Hung,
}

impl Outcome {
    /// Whether this outcome is a bug.
    pub fn is_bug(&self) -> bool {
        matches!(
            self,
            Outcome::NonFinite(_) | Outcome::Panicked(_) | Outcome::Hung
        )
    }
}

/// Loads `case` from a file in `dir` and renders it small (16 x 64 cells,
/// 30 shots, a 16-pixel image) on a thread, giving up after `limit`.
pub fn check(
    gpu: &'static radiosity::gpu::Gpu,
    case: &Case,
    dir: &std::path::Path,
    limit: std::time::Duration,
) -> Outcome {
    let path = dir.join(format!("case.{}", case.ext));
    if let Err(e) = std::fs::write(&path, &case.bytes) {
        return Outcome::Failed(format!("cannot write the case: {e}"));
    }
    let (tx, rx) = std::sync::mpsc::channel();
    let spawned = std::thread::Builder::new()
        .name("fuzz case".into())
        .spawn(move || {
            // A panic is the finding: nothing shared is used after it.
            let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                let scene = match radiosity::scene::load(&path) {
                    Ok(s) => s,
                    Err(e) => return Outcome::Rejected(e.to_string()),
                };
                let mut opts = radiosity::render::RenderOptions {
                    resolution: radiosity::hemisphere::Resolution { rows: 16, cols: 64 },
                    width: 16,
                    ..Default::default()
                };
                opts.stop.max_shots = 30;
                match radiosity::render::render(
                    gpu,
                    &scene,
                    &opts,
                    std::time::Duration::ZERO,
                    &mut |_| {},
                ) {
                    Err(e) => Outcome::Failed(e.to_string()),
                    Ok(r) => match r.report.non_finite() {
                        Some(what) => Outcome::NonFinite(what),
                        None => Outcome::Rendered,
                    },
                }
            }));
            let outcome = run.unwrap_or_else(|p| {
                Outcome::Panicked(
                    p.downcast_ref::<String>()
                        .cloned()
                        .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                        .unwrap_or_default(),
                )
            });
            let _ = tx.send(outcome);
        });
    if let Err(e) = spawned {
        return Outcome::Failed(format!("cannot start a thread: {e}"));
    }
    match rx.recv_timeout(limit) {
        Ok(o) => o,
        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => Outcome::Hung,
        Err(_) => Outcome::Panicked("the case's thread died".into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cases_are_deterministic_and_varied() {
        let base: Value =
            serde_json::from_str(&radiosity::scene::builtin_gltf("cornell").expect("cornell"))
                .expect("json");
        let a: Vec<Vec<u8>> = (0..50).map(|s| case(&base, s).bytes).collect();
        let b: Vec<Vec<u8>> = (0..50).map(|s| case(&base, s).bytes).collect();
        assert_eq!(a, b);
        let distinct: std::collections::HashSet<&Vec<u8>> = a.iter().collect();
        assert!(distinct.len() >= 45, "{} distinct", distinct.len());
        assert!((0..50).any(|s| case(&base, s).ext == "glb"));
        // The unmutated GLB is a good scene.
        let glb = radiosity::scene::to_glb(&base).expect("glb");
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("c.glb");
        std::fs::write(&path, glb).expect("write");
        let scene = radiosity::scene::load(&path).expect("the GLB loads");
        assert_eq!(scene.polygons.len(), 16);
    }
}
