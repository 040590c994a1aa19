//! The three form-factor exchanges of DESIGN.md section 3, apart from the
//! GPU: each rank has drawn its tiles of one hemisphere into an item buffer
//! (and, for hybrid form factors, counted every element's covered cells);
//! afterwards each rank's accumulator holds the fixed-point sums of the
//! elements it owns, whichever exchange moved them.

use super::tiers::TierCells;
use crate::hemisphere::FormFactorAccumulator;
use crate::parallel::{Collectives, Exchange, Owners};
use crate::settings::FormFactorMethod;
use std::time::{Duration, Instant};

/// One rank's side of the exchanges: who owns each element, and buffers
/// reused from shot to shot.
pub struct Exchanger<'c> {
    comm: &'c dyn Collectives,
    kind: Exchange,
    method: FormFactorMethod,
    /// Whether this rank owns each element.
    owned: Vec<bool>,
    /// Rank owning each element.
    element_rank: Vec<u32>,
    /// This rank's cell values, packed for the all-gather.
    packed: Vec<u32>,
    pairs: Vec<(u32, u64)>,
}

impl<'c> Exchanger<'c> {
    /// The exchanger of this rank of `comm`, for elements of the patches
    /// `element_patches` (one entry per element) of `owners`' patches.
    pub fn new(
        comm: &'c dyn Collectives,
        (kind, method): (Exchange, FormFactorMethod),
        owners: Owners,
        element_patches: impl Iterator<Item = u32>,
    ) -> Self {
        let element_rank: Vec<u32> = element_patches.map(|p| owners.of(p) as u32).collect();
        let owned = element_rank
            .iter()
            .map(|&r| r as usize == comm.rank())
            .collect();
        Self {
            comm,
            kind,
            method,
            owned,
            element_rank,
            packed: Vec::new(),
            pairs: Vec::new(),
        }
    }

    /// Adds a drawing's cells straight to `acc` (one process, or this rank's
    /// own cells before a reduction): each cell's weight to the element it
    /// shows and every element's covered cells.
    pub fn add_own(
        acc: &mut FormFactorAccumulator,
        cells: &TierCells,
        items: &[u32],
        coverage: impl Iterator<Item = (u32, u64)>,
    ) {
        let cols = cells.resolution.cols as usize;
        acc.add_cells(items, cols, &cells.weights, None);
        for (id, c) in coverage {
            acc.add(id, c);
        }
    }

    /// Exchanges this rank's drawing (`items`, its tiles' cells; `coverage`,
    /// its covered-cell counts) with the other ranks, leaving in `acc` the
    /// sums for the elements this rank owns. Returns the time spent in
    /// collectives.
    pub fn exchange(
        &mut self,
        acc: &mut FormFactorAccumulator,
        cells: &mut TierCells,
        items: &[u32],
        coverage: impl Iterator<Item = (u32, u64)>,
    ) -> Duration {
        match self.kind {
            Exchange::Hemispheres => self.hemispheres(acc, cells, items, coverage),
            Exchange::FormFactors => {
                Self::add_own(acc, cells, items, coverage);
                let t = Instant::now();
                self.comm.reduce_broadcast_sum(acc.dense_mut());
                let spent = t.elapsed();
                acc.retouch(&self.owned);
                spent
            }
            Exchange::Sparse => {
                Self::add_own(acc, cells, items, coverage);
                acc.drain_fixed(&mut self.pairs);
                let pairs = std::mem::take(&mut self.pairs);
                let spent = self.send_to_owners(acc, pairs.iter().copied());
                self.pairs = pairs;
                spent
            }
        }
    }

    /// The paper's method: all-gather the partial item buffers, and every
    /// rank sums the cells of its own elements over the whole hemisphere.
    fn hemispheres(
        &mut self,
        acc: &mut FormFactorAccumulator,
        cells: &mut TierCells,
        items: &[u32],
        coverage: impl Iterator<Item = (u32, u64)>,
    ) -> Duration {
        let comm = self.comm;
        self.packed.clear();
        for run in &cells.runs_of[comm.rank()] {
            self.packed
                .extend_from_slice(&items[run.start as usize..run.end as usize]);
        }
        let t = Instant::now();
        let all = comm.all_gather_u32(&self.packed, Some(&cells.cell_counts));
        let mut spent = t.elapsed();
        for (runs, values) in cells.runs_of.iter().zip(&all) {
            let mut at = 0;
            for run in runs {
                let n = run.len();
                cells.full[run.start as usize..run.end as usize]
                    .copy_from_slice(&values[at..at + n]);
                at += n;
            }
        }
        let cols = cells.resolution.cols as usize;
        acc.add_cells(&cells.full, cols, &cells.weights, Some(&self.owned));
        if self.method == FormFactorMethod::Hybrid {
            // Coverage counts are per rank: send them to the owners.
            spent += self.send_to_owners(acc, coverage);
        }
        spent
    }

    /// Sends (element, fixed-point value) pairs to the ranks that own the
    /// elements and adds what arrives to `acc`. Returns the time in the collective.
    fn send_to_owners(
        &self,
        acc: &mut FormFactorAccumulator,
        pairs: impl Iterator<Item = (u32, u64)>,
    ) -> Duration {
        let mut outgoing = vec![Vec::new(); self.comm.size()];
        for (id, v) in pairs {
            outgoing[self.element_rank[id as usize] as usize].push((id, v));
        }
        let t = Instant::now();
        let incoming = self.comm.all_to_all_pairs(&outgoing);
        let spent = t.elapsed();
        for (id, v) in incoming {
            acc.add(id, v);
        }
        spent
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hemisphere::{Resolution, EMPTY};
    use crate::parallel::ThreadComm;
    use crate::render::tiers::layout_for;
    use crate::render::RenderOptions;

    const ELEMENTS: u32 = 23;

    /// A made-up whole item buffer (some cells empty) and covered-cell
    /// counts, the same on every call.
    fn drawing(res: Resolution) -> (Vec<u32>, Vec<(u32, u64)>) {
        let mut rng = crate::rng::Rng(12345);
        let mut next = || rng.next_u64() as u32;
        let items = (0..res.cells())
            .map(|_| match next() % 10 {
                0 => EMPTY,
                _ => next() % ELEMENTS,
            })
            .collect();
        let coverage = (0..ELEMENTS)
            .map(|e| (e, u64::from(next() % 7 + 1)))
            .collect();
        (items, coverage)
    }

    /// Each rank's sums for its own elements, every exchange on `ranks`
    /// thread ranks, with elements of patch e / 2 (so ownership is mixed).
    fn exchanged(kind: Exchange, method: FormFactorMethod, ranks: usize) -> Vec<(u32, u64)> {
        let res = Resolution { rows: 8, cols: 32 };
        let opts = RenderOptions {
            tile: Some((3, 2)),
            ..RenderOptions::default()
        };
        let (whole, coverage) = drawing(res);
        let per_rank = ThreadComm::run(ranks, |comm| {
            let layout = layout_for(&opts, res, ranks).expect("layout");
            let mut cells = TierCells::new(res, layout, ranks, method);
            // This rank draws only its own tiles; it counts coverage for
            // the elements its share of the cells covers (here: a share of
            // the counts, split by rank so they must be summed).
            let own = cells.grid_position(comm.rank());
            let items: Vec<u32> = whole
                .iter()
                .enumerate()
                .map(|(i, &v)| {
                    let (p, t) = (i as u32 / res.cols, i as u32 % res.cols);
                    if layout.owner(p, t) == own {
                        v
                    } else {
                        EMPTY
                    }
                })
                .collect();
            let share: Vec<(u32, u64)> = coverage
                .iter()
                .filter(|(e, _)| (*e as usize + comm.rank()) % 2 == 0)
                .copied()
                .collect();
            let share = if method == FormFactorMethod::Hybrid {
                share
            } else {
                Vec::new()
            };
            let owners = Owners::new(ELEMENTS.div_ceil(2) as usize, ranks);
            let mut ex = Exchanger::new(comm, (kind, method), owners, (0..ELEMENTS).map(|e| e / 2));
            let mut acc = FormFactorAccumulator::new(ELEMENTS as usize);
            ex.exchange(&mut acc, &mut cells, &items, share.into_iter());
            let mut out = Vec::new();
            acc.drain_fixed(&mut out);
            assert!(
                out.iter().all(|&(e, _)| owners.of(e / 2) == comm.rank()),
                "{kind:?}: a rank kept sums of elements it does not own"
            );
            out
        });
        let mut all: Vec<(u32, u64)> = per_rank.concat();
        all.sort_unstable();
        all
    }

    /// What one process computes from the whole drawing, every rank's
    /// coverage share included.
    fn single(method: FormFactorMethod, ranks: usize) -> Vec<(u32, u64)> {
        let res = Resolution { rows: 8, cols: 32 };
        let (whole, coverage) = drawing(res);
        let cells = TierCells::new(res, crate::hemisphere::TileLayout::whole(res), 1, method);
        let mut acc = FormFactorAccumulator::new(ELEMENTS as usize);
        let counts = (0..ranks).flat_map(|r| {
            coverage
                .iter()
                .filter(move |(e, _)| (*e as usize + r) % 2 == 0)
                .copied()
        });
        let counts: Vec<(u32, u64)> = match method {
            FormFactorMethod::Hybrid => counts.collect(),
            FormFactorMethod::Hemisphere => Vec::new(),
        };
        Exchanger::add_own(&mut acc, &cells, &whole, counts.into_iter());
        let mut out = Vec::new();
        acc.drain_fixed(&mut out);
        out
    }

    #[test]
    fn the_three_exchanges_agree_with_one_process() {
        for method in [FormFactorMethod::Hybrid, FormFactorMethod::Hemisphere] {
            for ranks in [2, 3, 4] {
                let one = single(method, ranks);
                assert!(!one.is_empty());
                for kind in [
                    Exchange::Hemispheres,
                    Exchange::FormFactors,
                    Exchange::Sparse,
                ] {
                    assert_eq!(
                        exchanged(kind, method, ranks),
                        one,
                        "{kind:?}, {method:?}, {ranks} ranks"
                    );
                }
            }
        }
    }
}
