//! Checkpoints: a solve's whole state between two shots, so it can stop
//! (SIGINT, SIGTERM, `--checkpoint-every`, a failed rank) and resume to the
//! bitwise same result, on any number of ranks.
//!
//! # Format
//! `RADCKPT1`, the header's length (u64 LE), the header (JSON: what the
//! state is for, the refinement, the trace so far), then the state's f64
//! arrays as little-endian bits: radiosity and unshot radiosity per element
//! (3 each), unshot radiosity per patch (3), the solution's own direct part
//! per element (3), the retention pair, and one byte per patch (1: its
//! emission is still unshot). A file without the direct part and the bytes
//! (written before they were kept) still resumes. Bits, not
//! decimal text, so a resumed solve continues from exactly the same numbers.
//! Written atomically (a temporary file renamed), so a crash while writing
//! leaves the previous checkpoint.

use crate::report::{Refinement, TracePoint};
use crate::solver::SolverState;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

const MAGIC: &[u8; 8] = b"RADCKPT1";

/// What a checkpoint says besides the arrays.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// The scene (path or built-in name) it was made from.
    pub scene: String,
    /// A hash of the scene's geometry and materials and of every setting
    /// that changes the numbers: resuming with anything else is an error.
    pub fingerprint: String,
    /// Patches and elements of the mesh.
    pub counts: [usize; 2],
    /// Per polygon, the patch-grid factor refinement chose (so a resume
    /// skips the passes).
    pub factors: Vec<u32>,
    /// What refinement did.
    pub refinement: Refinement,
    /// Solve seconds so far.
    pub seconds: f64,
    /// The convergence trace so far.
    pub trace: Vec<TracePoint>,
    /// Power shot, delivered and absorbed by back faces so far
    /// (`Solver::energy_record`).
    #[serde(default)]
    pub energy: [f64; 3],
}

/// A saved solve.
#[derive(Clone, Debug, PartialEq)]
pub struct Checkpoint {
    /// Everything but the arrays.
    pub header: Header,
    /// The solver's state.
    pub state: SolverState,
}

/// Why a checkpoint cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// Reading failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not a checkpoint, or is cut short.
    #[error("{path}: not a radiosity checkpoint ({reason})")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

fn flat(v: &[[f64; 3]], out: &mut Vec<u8>) {
    for x in v.iter().flatten() {
        out.extend_from_slice(&x.to_bits().to_le_bytes());
    }
}

impl Checkpoint {
    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let header = serde_json::to_vec(&self.header).unwrap_or_default();
        let s = &self.state;
        let mut out = Vec::with_capacity(
            16 + header.len() + 8 * (6 * s.radiosity.len() + 3 * s.unshot.len() + 3),
        );
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(header.len() as u64).to_le_bytes());
        out.extend_from_slice(&header);
        out.extend_from_slice(&s.shots.to_le_bytes());
        flat(&s.radiosity, &mut out);
        flat(&s.element_unshot, &mut out);
        flat(&s.unshot, &mut out);
        if !s.direct.is_empty() {
            flat(&s.direct, &mut out);
        }
        for x in s.retention {
            out.extend_from_slice(&x.to_bits().to_le_bytes());
        }
        if !s.direct.is_empty() {
            out.extend(s.emission_unshot.iter().map(|&b| b as u8));
        }
        out
    }

    /// Parses a checkpoint file's bytes (`path` names it in errors).
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Self, CheckpointError> {
        let bad = |reason: &str| CheckpointError::Invalid {
            path: path.to_path_buf(),
            reason: reason.to_string(),
        };
        let mut at = 0usize;
        let mut take = |n: usize| -> Result<&[u8], CheckpointError> {
            let end = at.checked_add(n).filter(|&e| e <= bytes.len());
            let end = end.ok_or_else(|| bad("cut short"))?;
            let s = &bytes[at..end];
            at = end;
            Ok(s)
        };
        if take(8)? != MAGIC {
            return Err(bad("wrong magic number"));
        }
        let u64_at = |b: &[u8]| u64::from_le_bytes(b.try_into().unwrap_or([0; 8]));
        let len = usize::try_from(u64_at(take(8)?)).map_err(|_| bad("header too long"))?;
        let header: Header =
            serde_json::from_slice(take(len)?).map_err(|e| bad(&format!("header: {e}")))?;
        let shots = u64_at(take(8)?);
        let [patches, elements] = header.counts;
        // Without the direct part and the emission bytes (an older file):
        let old_size = (16 + 8 + 16)
            + len
            + elements
                .checked_mul(48)
                .and_then(|x| x.checked_add(patches.checked_mul(24)?))
                .ok_or_else(|| bad("counts too large"))?;
        let has_direct = bytes.len() > old_size;
        let mut triples = |n: usize| -> Result<Vec<[f64; 3]>, CheckpointError> {
            let raw = take(n.checked_mul(24).ok_or_else(|| bad("counts too large"))?)?;
            Ok(raw
                .chunks_exact(24)
                .map(|c| [0, 8, 16].map(|o| f64::from_bits(u64_at(&c[o..o + 8]))))
                .collect())
        };
        let radiosity = triples(elements)?;
        let element_unshot = triples(elements)?;
        let unshot = triples(patches)?;
        let direct = if has_direct {
            triples(elements)?
        } else {
            Vec::new()
        };
        let r = take(16)?;
        let retention = [
            f64::from_bits(u64_at(&r[..8])),
            f64::from_bits(u64_at(&r[8..])),
        ];
        let emission_unshot = if has_direct {
            take(patches)?.iter().map(|&b| b != 0).collect()
        } else {
            Vec::new()
        };
        if at != bytes.len() {
            return Err(bad("trailing bytes"));
        }
        Ok(Self {
            header,
            state: SolverState {
                radiosity,
                unshot,
                element_unshot,
                shots,
                retention,
                direct,
                emission_unshot,
            },
        })
    }

    /// Reads a checkpoint file.
    pub fn read(path: &Path) -> Result<Self, CheckpointError> {
        let bytes = std::fs::read(path).map_err(|source| CheckpointError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(path, &bytes)
    }
}

/// FNV-1a, 64 bits: a stable hash (std's is not promised to stay the same
/// between releases, and checkpoints outlive builds).
pub fn fingerprint(parts: &[&[u8]]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for part in parts {
        for &b in part.iter().chain(&(part.len() as u64).to_le_bytes()) {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    format!("{h:016x}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Checkpoint {
        Checkpoint {
            header: Header {
                scene: "s".into(),
                fingerprint: fingerprint(&[b"x"]),
                counts: [1, 2],
                factors: vec![1, 2],
                refinement: Refinement::default(),
                seconds: 1.5,
                trace: Vec::new(),
                energy: [3.0, 2.5, 1.0 / 7.0],
            },
            state: SolverState {
                radiosity: vec![[0.1, f64::MIN_POSITIVE, 3.0], [1.0 / 3.0, 2.0, -0.0]],
                element_unshot: vec![[0.0; 3], [1e-300, 5.0, 6.0]],
                unshot: vec![[7.0, 8.0, 9.0]],
                shots: 42,
                retention: [0.7, 0.6],
                direct: vec![[0.5, 0.25, 0.0], [1e-3, 2.0, 3.0]],
                emission_unshot: vec![true],
            },
        }
    }

    #[test]
    fn a_checkpoint_round_trips_bit_for_bit() {
        let c = sample();
        let back = Checkpoint::from_bytes(Path::new("c"), &c.to_bytes()).expect("parses");
        assert_eq!(back, c);
        let bits = |s: &SolverState| -> Vec<u64> {
            s.radiosity.iter().flatten().map(|x| x.to_bits()).collect()
        };
        assert_eq!(bits(&back.state), bits(&c.state));
        // One written before the direct part was kept still reads.
        let mut old = c.clone();
        old.state.direct.clear();
        old.state.emission_unshot.clear();
        let back = Checkpoint::from_bytes(Path::new("c"), &old.to_bytes()).expect("parses");
        assert_eq!(back, old);
    }

    #[test]
    fn damaged_files_are_clear_errors() {
        let bytes = sample().to_bytes();
        for (cut, what) in [
            (&bytes[..bytes.len() - 1], "cut short"),
            (&bytes[..4], "cut short"),
        ] {
            let e = Checkpoint::from_bytes(Path::new("c.ckpt"), cut).expect_err("damaged");
            assert!(e.to_string().contains(what), "{e}");
            assert!(e.to_string().starts_with("c.ckpt: "), "{e}");
        }
        let mut wrong = bytes.clone();
        wrong[0] = b'X';
        let e = Checkpoint::from_bytes(Path::new("c"), &wrong).expect_err("magic");
        assert!(e.to_string().contains("magic"), "{e}");
    }
}
