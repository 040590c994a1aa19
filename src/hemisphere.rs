//! The equal-angle hemisphere: its cells, their exact delta form factors, and
//! the tiles the cells are grouped into for parallel rasterisation.
//!
//! Pure maths: nothing here knows about GPUs or ranks.

use std::f64::consts::{FRAC_PI_2, PI};
use std::fmt;
use std::str::FromStr;

/// Item-buffer value of a cell that sees nothing (the scene is open there).
pub const EMPTY: u32 = u32::MAX;
/// Item-buffer value of a cell that sees the back of a one-sided surface:
/// light is blocked there but no element receives it.
pub const BLOCKED: u32 = u32::MAX - 1;

/// Fixed-point scale of delta form factors: 2^62 represents a form factor of 1.
///
/// Sums of fixed-point values are exact and therefore independent of the order
/// in which cells are visited, which keeps results identical however the
/// hemisphere is split into tiles or ranks.
pub const FIXED_ONE: f64 = (1u64 << 62) as f64;

/// Hemisphere resolution: `rows` polar rows (R_phi) by `cols` azimuth columns (R_theta).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Resolution {
    /// R_phi: rows over the polar angle phi in [0, pi/2].
    pub rows: u32,
    /// R_theta: columns over the azimuth theta in [0, 2 pi).
    pub cols: u32,
}

impl Default for Resolution {
    fn default() -> Self {
        Self {
            rows: 128,
            cols: 512,
        }
    }
}

impl fmt::Display for Resolution {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}x{}", self.rows, self.cols)
    }
}

impl FromStr for Resolution {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (r, c) = s
            .split_once(['x', 'X'])
            .ok_or_else(|| format!("expected R_PHIxR_THETA such as 128x512, got '{s}'"))?;
        let rows: u32 = r
            .trim()
            .parse()
            .map_err(|_| format!("bad row count '{r}'"))?;
        let cols: u32 = c
            .trim()
            .parse()
            .map_err(|_| format!("bad column count '{c}'"))?;
        let res = Resolution { rows, cols };
        res.validate()?;
        Ok(res)
    }
}

impl Resolution {
    /// Checks the resolution is usable (both counts in 4..=8192).
    pub fn validate(&self) -> Result<(), String> {
        if !(4..=8192).contains(&self.rows) || !(4..=8192).contains(&self.cols) {
            return Err(format!(
                "hemisphere resolution {self} out of range: each count must be 4..=8192"
            ));
        }
        Ok(())
    }

    /// Number of cells, N_M = R_phi * R_theta.
    pub fn cells(&self) -> usize {
        self.rows as usize * self.cols as usize
    }

    /// Polar angle of the boundary between row `p - 1` and row `p` (phi_p).
    pub fn phi_edge(&self, p: u32) -> f64 {
        p as f64 * FRAC_PI_2 / self.rows as f64
    }

    /// Delta form factor of any cell in row `p`: (sin^2 phi_(p+1) - sin^2 phi_p) / R_theta.
    ///
    /// Written as a product of sines, which is exact to rounding even near the
    /// pole where the difference of squares would cancel.
    pub fn delta_form_factor(&self, p: u32) -> f64 {
        let (a, b) = (self.phi_edge(p), self.phi_edge(p + 1));
        // sin^2 b - sin^2 a = sin(b - a) sin(b + a)
        (b - a).sin() * (b + a).sin() / self.cols as f64
    }

    /// Delta form factors of every row, as f64.
    pub fn delta_form_factors(&self) -> Vec<f64> {
        (0..self.rows).map(|p| self.delta_form_factor(p)).collect()
    }

    /// Delta form factors of every row in fixed point (see [`FIXED_ONE`]).
    pub fn delta_form_factors_fixed(&self) -> Vec<u64> {
        (0..self.rows)
            .map(|p| (self.delta_form_factor(p) * FIXED_ONE).round() as u64)
            .collect()
    }

    /// Direction (in the shooter's frame, z = normal) through the centre of cell (p, t).
    pub fn cell_direction(&self, p: u32, t: u32) -> [f64; 3] {
        let phi = (p as f64 + 0.5) * FRAC_PI_2 / self.rows as f64;
        let theta = (t as f64 + 0.5) * 2.0 * PI / self.cols as f64;
        [phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos()]
    }
}

/// How the hemisphere's cells are grouped into tiles and dealt to a
/// `px` x `py` grid of ranks: tile (p, t) goes to rank (t mod px, p mod py).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct TileLayout {
    /// Tile width in cells (along theta).
    pub tile_w: u32,
    /// Tile height in cells (along phi).
    pub tile_h: u32,
    /// Ranks along theta.
    pub px: u32,
    /// Ranks along phi.
    pub py: u32,
}

impl TileLayout {
    /// One tile covering the whole hemisphere, drawn by one rank.
    pub fn whole(res: Resolution) -> Self {
        Self {
            tile_w: res.cols,
            tile_h: res.rows,
            px: 1,
            py: 1,
        }
    }

    /// Rank-grid coordinates owning cell (p, t).
    pub fn owner(&self, p: u32, t: u32) -> (u32, u32) {
        ((t / self.tile_w) % self.px, (p / self.tile_h) % self.py)
    }

    /// Number of ranks in the grid.
    pub fn ranks(&self) -> u32 {
        self.px * self.py
    }

    /// Tiles along theta and phi for a resolution (the last ones may be partial).
    pub fn tile_counts(&self, res: Resolution) -> (u32, u32) {
        (
            res.cols.div_ceil(self.tile_w),
            res.rows.div_ceil(self.tile_h),
        )
    }
}

/// Sparse per-element form factors of one shot, accumulated in fixed point.
///
/// `add_cells` may be called for several partial item buffers in any order;
/// the result is the same because integer addition is associative.
#[derive(Debug, Default)]
pub struct FormFactorAccumulator {
    fixed: Vec<u64>,
    touched: Vec<u32>,
}

impl FormFactorAccumulator {
    /// An accumulator for `elements` elements.
    pub fn new(elements: usize) -> Self {
        Self {
            fixed: vec![0; elements],
            touched: Vec::new(),
        }
    }

    /// Adds the delta form factor of every cell of `items` (row-major, `cols`
    /// values per row, rows starting at `first_row`) to the element it names.
    pub fn add_cells(&mut self, items: &[u32], cols: usize, first_row: usize, dff_fixed: &[u64]) {
        for (r, row) in items.chunks_exact(cols).enumerate() {
            let w = dff_fixed[first_row + r];
            for &id in row {
                if let Some(slot) = self.fixed.get_mut(id as usize) {
                    if *slot == 0 {
                        self.touched.push(id);
                    }
                    *slot += w;
                }
            }
        }
    }

    /// Drains the accumulated form factors as (element, F) pairs sorted by element.
    pub fn drain_sorted(&mut self, out: &mut Vec<(u32, f64)>) {
        out.clear();
        self.touched.sort_unstable();
        for &id in &self.touched {
            let slot = &mut self.fixed[id as usize];
            out.push((id, *slot as f64 / FIXED_ONE));
            *slot = 0;
        }
        self.touched.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delta_form_factors_sum_to_one() {
        for (rows, cols) in [(8, 32), (128, 512), (160, 640), (192, 768), (1000, 7)] {
            let res = Resolution { rows, cols };
            let sum: f64 = res.delta_form_factors().iter().sum::<f64>() * cols as f64;
            assert!((sum - 1.0).abs() < 1e-12, "{res}: sum {sum}");
        }
    }

    #[test]
    fn owner_is_two_d_interleave() {
        let l = TileLayout {
            tile_w: 1,
            tile_h: 1,
            px: 4,
            py: 2,
        };
        assert_eq!(l.owner(0, 0), (0, 0));
        assert_eq!(l.owner(1, 5), (1, 1));
        assert_eq!(l.owner(2, 7), (3, 0));
    }

    #[test]
    fn parse_resolution() {
        assert_eq!(
            "160x640".parse::<Resolution>(),
            Ok(Resolution {
                rows: 160,
                cols: 640
            })
        );
        assert!("160".parse::<Resolution>().is_err());
        assert!("1x640".parse::<Resolution>().is_err());
    }
}
