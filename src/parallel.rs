//! The collectives a distributed solve needs, as a trait, so the render loop
//! can run on one process or on MPI ranks without knowing which. The MPI
//! implementation lives in [`crate::comm`], the only module that calls MPI.

use std::cell::Cell;

/// Bytes this rank sent and received in exchanges, summed over calls.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Traffic {
    /// Bytes sent.
    pub sent: u64,
    /// Bytes received.
    pub received: u64,
}

/// Collective operations over the ranks of one solve. Every rank must make
/// the same calls in the same order.
pub trait Collectives {
    /// This rank, 0-based.
    fn rank(&self) -> usize;
    /// Number of ranks.
    fn size(&self) -> usize;
    /// Every rank's `local` (the same length on every rank), concatenated in rank order.
    fn all_gather_f64(&self, local: &[f64]) -> Vec<f64>;
    /// Every rank's `local` (any length), in rank order. `lengths` gives every
    /// rank's length when all ranks already know them, which saves a collective.
    fn all_gather_u32(&self, local: &[u32], lengths: Option<&[usize]>) -> Vec<Vec<u32>>;
    /// Element-wise sum of `data` over ranks, reduced to rank 0 and broadcast back.
    fn reduce_broadcast_sum(&self, data: &mut [u64]);
    /// Sends `outgoing[r]` to rank r; returns everything sent to this rank, in rank order.
    fn all_to_all_pairs(&self, outgoing: &[Vec<(u32, u64)>]) -> Vec<(u32, u64)>;
    /// Rank 0 gets every rank's `local`, in rank order; the others get `None`.
    fn gather_f64(&self, local: &[f64]) -> Option<Vec<Vec<f64>>>;
    /// Whether every rank passed `ok`; when not, rank 0 gets the failing
    /// ranks' messages (`(rank, message)`), the others an empty list.
    fn all_ok(&self, ok: Result<(), String>) -> Result<(), Vec<(usize, String)>>;
    /// Bytes exchanged so far by the form-factor exchanges.
    fn traffic(&self) -> Traffic;
    /// Ends every rank now (after an error that only this rank saw).
    fn abort(&self, code: i32) -> !;
}

/// One process: every collective is the identity.
#[derive(Default)]
pub struct Single {
    traffic: Cell<Traffic>,
}

impl Collectives for Single {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn all_gather_f64(&self, local: &[f64]) -> Vec<f64> {
        local.to_vec()
    }
    fn all_gather_u32(&self, local: &[u32], _lengths: Option<&[usize]>) -> Vec<Vec<u32>> {
        vec![local.to_vec()]
    }
    fn reduce_broadcast_sum(&self, _data: &mut [u64]) {}
    fn all_to_all_pairs(&self, outgoing: &[Vec<(u32, u64)>]) -> Vec<(u32, u64)> {
        outgoing.first().cloned().unwrap_or_default()
    }
    fn gather_f64(&self, local: &[f64]) -> Option<Vec<Vec<f64>>> {
        Some(vec![local.to_vec()])
    }
    fn all_ok(&self, ok: Result<(), String>) -> Result<(), Vec<(usize, String)>> {
        ok.map_err(|m| vec![(0, m)])
    }
    fn traffic(&self) -> Traffic {
        self.traffic.get()
    }
    fn abort(&self, code: i32) -> ! {
        std::process::exit(code)
    }
}

/// How the ranks exchange form factors each shot (DESIGN.md section 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Exchange {
    /// All-gather the partial item buffers; every rank sums F itself (the paper's new method).
    #[default]
    Hemispheres,
    /// Dense partial form factors over all elements, reduced and broadcast (the paper's earlier method).
    FormFactors,
    /// Nonzero (element, F) pairs sent straight to the owning ranks.
    Sparse,
}

/// The Px x Py rank grid for `n` ranks: Py is the largest divisor of n not
/// above sqrt(n), so the grid is as square as n allows (a prime n gives n x 1).
pub fn rank_grid(n: usize) -> (u32, u32) {
    let n = n.max(1);
    let py = (1..=n)
        .take_while(|d| d * d <= n)
        .filter(|d| n % d == 0)
        .max()
        .unwrap_or(1);
    ((n / py) as u32, py as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rank_grids() {
        assert_eq!(rank_grid(1), (1, 1));
        assert_eq!(rank_grid(4), (2, 2));
        assert_eq!(rank_grid(6), (3, 2));
        assert_eq!(rank_grid(7), (7, 1));
        assert_eq!(rank_grid(64), (8, 8));
        assert_eq!(rank_grid(8), (4, 2));
    }
}
