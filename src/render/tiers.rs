//! Resolution tiers: a shot is drawn at the fine resolution, or at the
//! coarse one when its shooter is weak, and each tier knows, without a GPU,
//! how its hemisphere is tiled over the ranks and what each cell weighs.

use super::options::{FormFactorMethod, RenderError, RenderOptions};
use crate::hemisphere::{Resolution, TileLayout, EMPTY};
use crate::parallel::rank_grid;

/// Which tier a shot draws in: the coarse one (tier 1, when there is one)
/// for shooters with less unshot power than a share of the emitted power.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TierChoice {
    /// How many tiers there are (1 or 2).
    pub tiers: usize,
    /// Shooters with less unshot power than this (W, sum over RGB) draw coarse.
    pub coarse_below: f64,
    /// Shooters with less unshot power than this (W, sum over RGB) shoot
    /// along the ambient term's transport, drawing nothing.
    pub transport_below: f64,
    /// Every shooter but the emitters' patches draws coarse (the refinement
    /// passes, which only measure: see `passes::one_pass`).
    pub measuring: bool,
}

impl TierChoice {
    /// The choice `opts` describes for a mesh of `patches` patches emitting
    /// `emitted_power`.
    pub fn new(opts: &RenderOptions, emitted_power: f64, patches: usize) -> Self {
        Self {
            tiers: 1 + opts.coarse_tier().is_some() as usize,
            coarse_below: opts.coarse_below * emitted_power,
            transport_below: opts.transport_below_for(patches) * emitted_power,
            measuring: false,
        }
    }

    /// Whether a shooter of unshot power `power` shoots along the transport.
    pub fn by_transport(&self, power: f64) -> bool {
        power < self.transport_below
    }

    /// The tier a shooter of unshot power `power` draws in (`emitter`:
    /// whether its polygon emits).
    pub fn tier_for(&self, power: f64, emitter: bool) -> usize {
        if self.tiers > 1 && (power < self.coarse_below || (self.measuring && !emitter)) {
            1
        } else {
            0
        }
    }

    /// The resolution of each tier `opts` asks for, fine first.
    pub fn resolutions(opts: &RenderOptions) -> Vec<Resolution> {
        std::iter::once(opts.resolution)
            .chain(opts.coarse_tier())
            .collect()
    }
}

/// Tiles per rank along each axis of the automatic tile size: each rank
/// draws 4 x 4 tiles spread over the hemisphere by the interleave.
pub const AUTO_TILES_PER_RANK_AXIS: u32 = 4;

/// The automatic tile size for a hemisphere of `res` over a `px` x `py`
/// rank grid: [`AUTO_TILES_PER_RANK_AXIS`] tiles per rank along each axis.
/// Measured on two ranks of one core each (docs/notebook/ranks.md "Ranks"): 1 x 1 tiles
/// (the paper's per-cell interleave) make every rank bound and draw nearly
/// every rectangle, since nearly every rectangle holds cells of every rank
/// (cubes-b1 1.32x, classroom-c3 1.29x); tiles this size let each rank skip
/// the rectangles outside its tiles while the interleave still spreads its
/// tiles over the whole hemisphere (1.62x, 1.40x). Results are the same
/// bits for any tiles.
pub fn auto_tile(res: Resolution, px: u32, py: u32) -> (u32, u32) {
    let k = AUTO_TILES_PER_RANK_AXIS;
    // Rounded up, so the tile count along each axis is a multiple of the
    // grid's: every rank gets as many tiles (the last row or column of
    // tiles may be narrower).
    (
        res.cols.div_ceil(px.max(1) * k).max(1),
        res.rows.div_ceil(py.max(1) * k).max(1),
    )
}

/// The tile layout of a hemisphere of `res` over `ranks` ranks: the rank
/// grid with `opts.tile` tiles (else [`auto_tile`]) on several ranks, else
/// `opts.layout` (one process drawing every rank's tiles in turn) or one
/// whole tile.
pub fn layout_for(
    opts: &RenderOptions,
    res: Resolution,
    ranks: usize,
) -> Result<TileLayout, RenderError> {
    let layout = if ranks > 1 {
        let (px, py) = rank_grid(ranks);
        let (tile_w, tile_h) = opts.tile.unwrap_or_else(|| auto_tile(res, px, py));
        TileLayout {
            tile_w,
            tile_h,
            px,
            py,
        }
    } else {
        opts.layout.unwrap_or_else(|| TileLayout::whole(res))
    };
    if layout.tile_w == 0 || layout.tile_h == 0 || layout.px == 0 || layout.py == 0 {
        return Err(RenderError::Settings(format!(
            "tile layout {layout:?} has a zero size"
        )));
    }
    Ok(layout)
}

/// Everything of one tier's hemisphere that needs no GPU: its layout, what a
/// cell adds to the element it shows, and which cells each rank owns.
#[derive(Clone, Debug)]
pub struct TierCells {
    /// The hemisphere resolution.
    pub resolution: Resolution,
    /// How its cells are tiled over the ranks.
    pub layout: TileLayout,
    /// What one cell adds to the element it shows, per row: its delta form
    /// factor in fixed point (hemisphere) or one visible cell (hybrid).
    pub weights: Vec<u64>,
    /// Each row's delta form factor in [`crate::formfactor::SHARE_ONE`]
    /// fixed point, per cell: what a cell adds to the share of the
    /// hemisphere that sees something (exact to sum over any split of the
    /// cells between ranks).
    pub shares: Vec<u64>,
    /// Each rank's tiles as runs of consecutive cells, one per tile row
    /// (row-major cell indices, end excluded), in row-major order
    /// (hemisphere exchange; empty in one process).
    pub runs_of: Vec<Vec<std::ops::Range<u32>>>,
    /// How many cells each rank owns (known to all, so never exchanged).
    pub cell_counts: Vec<usize>,
    /// The whole hemisphere's cells, assembled from every rank's.
    pub full: Vec<u32>,
    /// How many cells each grid position of `layout` owns (row-major over
    /// the grid), for the work accounting.
    position_cells: Vec<usize>,
}

impl TierCells {
    /// The cells of a hemisphere of `res` laid out by `layout` over `ranks`
    /// ranks, weighted for `method`.
    pub fn new(
        res: Resolution,
        layout: TileLayout,
        ranks: usize,
        method: FormFactorMethod,
    ) -> Self {
        let weights = match method {
            FormFactorMethod::Hybrid => vec![crate::formfactor::VISIBLE_ONE; res.rows as usize],
            FormFactorMethod::Hemisphere => res.delta_form_factors_fixed(),
        };
        let mut runs_of: Vec<Vec<std::ops::Range<u32>>> = vec![Vec::new(); ranks];
        if ranks > 1 && layout.ranks() as usize == ranks {
            for p in 0..res.rows {
                for t in 0..res.cols {
                    let (x, y) = layout.owner(p, t);
                    let c = p * res.cols + t;
                    let runs = &mut runs_of[(y * layout.px + x) as usize];
                    match runs.last_mut() {
                        Some(run) if run.end == c && t % layout.tile_w != 0 => run.end += 1,
                        _ => runs.push(c..c + 1),
                    }
                }
            }
        }
        let mut position_cells = vec![0usize; layout.ranks() as usize];
        for p in 0..res.rows {
            for t in 0..res.cols {
                let (x, y) = layout.owner(p, t);
                position_cells[(y * layout.px + x) as usize] += 1;
            }
        }
        let shares = res
            .delta_form_factors()
            .iter()
            .map(|f| crate::numeric::round_u64(f * crate::formfactor::SHARE_ONE))
            .collect();
        Self {
            resolution: res,
            layout,
            weights,
            shares,
            cell_counts: runs_of
                .iter()
                .map(|runs| runs.iter().map(|r| r.len()).sum())
                .collect(),
            runs_of,
            full: vec![EMPTY; res.cells()],
            position_cells,
        }
    }

    /// How many cells the tiles of grid position `own` hold.
    pub fn cells_at(&self, own: (u32, u32)) -> usize {
        let k = (own.1 * self.layout.px + own.0) as usize;
        self.position_cells.get(k).copied().unwrap_or(0)
    }

    /// What a drawing of the tiles of grid position `own` shows (`items`:
    /// the whole hemisphere, other positions' cells EMPTY): the shares of
    /// the hemisphere that show an element and a back face (SHARE_ONE fixed
    /// point), and how many of `own`'s cells show nothing (light leaving
    /// the scene). Summed over the positions, the whole hemisphere's.
    pub fn view_shares(&self, items: &[u32], own: (u32, u32)) -> [u64; 3] {
        let cols = self.resolution.cols as usize;
        let whole = self.layout.ranks() == 1;
        let mut out = [0u64; 3];
        // A cell showing `id` with weight `w`; `counted` when an empty one
        // is this position's.
        let mut tally = |id: u32, w: u64, counted: bool| match id {
            crate::hemisphere::EMPTY => out[2] += u64::from(counted),
            crate::hemisphere::BLOCKED => out[1] += w,
            _ => out[0] += w,
        };
        let k = (own.1 * self.layout.px + own.0) as usize;
        if let Some(runs) = self.runs_of.get(k).filter(|r| !r.is_empty()) {
            // A rank of a run reads its own cells only: the others' are
            // EMPTY here, and asking each one's owner cost more than the rest.
            for run in runs {
                let w = self.shares[run.start as usize / cols];
                for &id in &items[run.start as usize..run.end as usize] {
                    tally(id, w, true);
                }
            }
        } else {
            for (row, cells) in items.chunks_exact(cols).enumerate() {
                let w = self.shares[row];
                for (t, &id) in cells.iter().enumerate() {
                    let counted = id != crate::hemisphere::EMPTY
                        || whole
                        || self.layout.owner(row as u32, t as u32) == own;
                    tally(id, w, counted);
                }
            }
        }
        out
    }

    /// Where a whole hemisphere's `items` show nothing, as runs of cells
    /// (start and end, end excluded, flattened; none across a row of cells).
    pub fn empty_runs(&self, items: &[u32]) -> Vec<u32> {
        let cols = self.resolution.cols as usize;
        let mut runs = Vec::new();
        for (row, cells) in items.chunks_exact(cols).enumerate() {
            let base = (row * cols) as u32;
            let mut open = None;
            for (t, &id) in cells.iter().enumerate() {
                match (id == crate::hemisphere::EMPTY, open) {
                    (true, None) => open = Some(base + t as u32),
                    (false, Some(start)) => {
                        runs.extend([start, base + t as u32]);
                        open = None;
                    }
                    _ => {}
                }
            }
            if let Some(start) = open {
                runs.extend([start, base + cols as u32]);
            }
        }
        runs
    }

    /// [`Self::view_shares`] of a whole hemisphere's `items`, over the
    /// cells of `runs` (as [`Self::empty_runs`] gives them) only.
    pub fn view_shares_within(&self, items: &[u32], runs: &[u32]) -> [u64; 3] {
        let cols = self.resolution.cols as usize;
        let mut out = [0u64; 3];
        for run in runs.chunks_exact(2) {
            let (start, end) = (run[0] as usize, run[1] as usize);
            let w = self.shares[start / cols];
            for &id in items.get(start..end).unwrap_or(&[]) {
                match id {
                    crate::hemisphere::EMPTY => out[2] += 1,
                    crate::hemisphere::BLOCKED => out[1] += w,
                    _ => out[0] += w,
                }
            }
        }
        out
    }

    /// The rank-grid position (x, y) of rank `rank`.
    pub fn grid_position(&self, rank: usize) -> (u32, u32) {
        let rank = rank as u32;
        (rank % self.layout.px, rank / self.layout.px)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_group_view_splits_into_its_drawn_cells_and_the_first_hemisphere_beyond() {
        use crate::hemisphere::{BLOCKED, EMPTY};
        let res = Resolution { rows: 6, cols: 10 };
        let cells = TierCells::new(res, TileLayout::whole(res), 1, FormFactorMethod::Hemisphere);
        // A whole hemisphere and a reach-limited one: every kind of cell,
        // empty runs that start, end and fill rows.
        let pick = |k: usize, salt: usize| match (k * 7 + salt) % 5 {
            0 | 1 => EMPTY,
            2 => BLOCKED,
            _ => k as u32,
        };
        let whole: Vec<u32> = (0..res.cells()).map(|k| pick(k, 1)).collect();
        let mut group: Vec<u32> = (0..res.cells()).map(|k| pick(k, 3)).collect();
        group[10..20].fill(EMPTY);
        group[0] = EMPTY;
        let composite: Vec<u32> = group
            .iter()
            .zip(&whole)
            .map(|(&g, &w)| if g == EMPTY { w } else { g })
            .collect();
        let want = cells.view_shares(&composite, (0, 0));
        let runs = cells.empty_runs(&group);
        assert!(runs
            .chunks_exact(2)
            .all(|r| r[0] < r[1] && r[0] / res.cols == (r[1] - 1) / res.cols));
        let drawn = cells.view_shares(&group, (0, 0));
        let beyond = cells.view_shares_within(&whole, &runs);
        assert_eq!(beyond[2], want[2]);
        assert_eq!(
            [drawn[0] + beyond[0], drawn[1] + beyond[1]],
            [want[0], want[1]]
        );
        let empty: usize = runs.chunks_exact(2).map(|r| (r[1] - r[0]) as usize).sum();
        assert_eq!(empty as u64, drawn[2]);
    }

    #[test]
    fn every_cell_belongs_to_exactly_one_rank() {
        let res = Resolution { rows: 12, cols: 40 };
        let opts = RenderOptions {
            tile: Some((3, 2)),
            ..RenderOptions::default()
        };
        for ranks in [2, 3, 4, 6] {
            let layout = layout_for(&opts, res, ranks).expect("layout");
            let cells = TierCells::new(res, layout, ranks, FormFactorMethod::Hybrid);
            let mut seen = vec![0u8; res.cells()];
            for (r, runs) in cells.runs_of.iter().enumerate() {
                let own: Vec<u32> = runs.iter().flat_map(|r| r.clone()).collect();
                assert_eq!(cells.cell_counts[r], own.len());
                assert!(!own.is_empty(), "{ranks} ranks: rank {r} owns no cell");
                assert!(own.windows(2).all(|w| w[0] < w[1]), "runs in order");
                assert!(
                    runs.iter()
                        .all(|r| r.start / res.cols == (r.end - 1) / res.cols),
                    "a run within one row"
                );
                for &c in &own {
                    seen[c as usize] += 1;
                    let (p, t) = (c / res.cols, c % res.cols);
                    let (x, y) = layout.owner(p, t);
                    assert_eq!(cells.grid_position(r), (x, y));
                }
            }
            assert!(seen.iter().all(|&n| n == 1), "{ranks} ranks");
        }
    }

    #[test]
    fn weights_follow_the_method() {
        let res = Resolution { rows: 8, cols: 32 };
        let one = TileLayout::whole(res);
        let h = TierCells::new(res, one, 1, FormFactorMethod::Hemisphere);
        let sum: f64 = h.weights.iter().map(|&w| w as f64).sum::<f64>() * res.cols as f64;
        assert!(
            (sum / crate::hemisphere::FIXED_ONE - 1.0).abs() < 1e-9,
            "{sum}"
        );
        let y = TierCells::new(res, one, 1, FormFactorMethod::Hybrid);
        assert!(y
            .weights
            .iter()
            .all(|&w| w == crate::formfactor::VISIBLE_ONE));
        assert!(h.runs_of[0].is_empty(), "one process needs no cell lists");
    }

    #[test]
    fn weak_shooters_draw_coarse_only_when_there_is_a_coarse_tier() {
        let opts = RenderOptions::default();
        let c = TierChoice::new(&opts, 100.0, 10);
        assert_eq!(c.tiers, 2);
        assert_eq!(c.tier_for(0.29, false), 1);
        assert_eq!(c.tier_for(0.3, false), 0);
        let none = TierChoice::new(
            &RenderOptions {
                coarse_below: 0.0,
                transport_below: Some(0.0),
                ..opts.clone()
            },
            100.0,
            10,
        );
        assert_eq!(none.tier_for(0.0, false), 0);
        // The transport tier: by default only in meshes whose transport
        // clusters patches; a given threshold holds in any mesh.
        let big = crate::ambient::PATCH_GROUPS + 1;
        assert!(!c.by_transport(0.001));
        let auto = TierChoice::new(&opts, 100.0, big);
        assert!(auto.by_transport(0.0099) && !auto.by_transport(0.01));
        assert!(!none.by_transport(0.0));
        let off = RenderOptions {
            transport_below: Some(0.0),
            ..opts.clone()
        };
        assert!(!TierChoice::new(&off, 100.0, big).by_transport(0.0));
        let given = RenderOptions {
            transport_below: Some(1e-3),
            ..opts.clone()
        };
        assert!(TierChoice::new(&given, 100.0, 10).by_transport(0.099));
        assert_eq!(TierChoice::resolutions(&opts).len(), 2);
        // Measuring (the refinement passes): strong shooters draw coarse
        // too, the emitters' patches fine, and without a coarse tier nothing changes.
        let measuring = TierChoice {
            measuring: true,
            ..c
        };
        assert_eq!(measuring.tier_for(50.0, false), 1);
        assert_eq!(measuring.tier_for(50.0, true), 0);
        assert_eq!(measuring.tier_for(0.1, true), 1);
        let measuring_none = TierChoice {
            measuring: true,
            ..none
        };
        assert_eq!(measuring_none.tier_for(50.0, false), 0);
    }

    #[test]
    fn a_zero_tile_is_an_error() {
        let opts = RenderOptions {
            tile: Some((0, 4)),
            ..RenderOptions::default()
        };
        assert!(layout_for(&opts, Resolution::default(), 2).is_err());
        assert!(layout_for(&opts, Resolution::default(), 1).is_ok());
    }
}
