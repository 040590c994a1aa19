//! The equal-angle hemisphere: its cells, their exact delta form factors, and
//! the tiles the cells are grouped into for parallel rasterisation.
//!
//! Pure maths: nothing here knows about GPUs or ranks.

use glam::Vec3;
use std::f64::consts::{FRAC_PI_2, PI};
use std::fmt;
use std::str::FromStr;

mod bounds;
pub use bounds::{cell_bounds, CellRect};
#[cfg(test)]
use bounds::{cell_bounds_scalar, lanes};

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

/// The most rows, and the most columns, a hemisphere may have: the
/// rasteriser's table of cell directions is one 64 KiB uniform binding
/// (16 bytes a row and column), the size every device offers.
pub const MAX_COUNT: u32 = 4096;

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

/// Why a hemisphere resolution is unusable.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ResolutionError {
    /// Not of the form RxC.
    #[error("expected R_PHIxR_THETA such as 128x512, got '{0}'")]
    Syntax(String),
    /// The row count is not a number.
    #[error("bad row count '{0}'")]
    Rows(String),
    /// The column count is not a number.
    #[error("bad column count '{0}'")]
    Cols(String),
    /// A count is out of range.
    #[error("hemisphere resolution {0} out of range: each count must be 4..={MAX_COUNT}")]
    Range(Resolution),
}

impl FromStr for Resolution {
    type Err = ResolutionError;
    fn from_str(s: &str) -> Result<Self, ResolutionError> {
        let (r, c) = s
            .split_once(['x', 'X'])
            .ok_or_else(|| ResolutionError::Syntax(s.into()))?;
        let rows: u32 = r
            .trim()
            .parse()
            .map_err(|_| ResolutionError::Rows(r.into()))?;
        let cols: u32 = c
            .trim()
            .parse()
            .map_err(|_| ResolutionError::Cols(c.into()))?;
        let res = Resolution { rows, cols };
        res.validate()?;
        Ok(res)
    }
}

impl Resolution {
    /// Checks the resolution is usable (both counts in 4..=[`MAX_COUNT`]).
    pub fn validate(&self) -> Result<(), ResolutionError> {
        let range = 4..=MAX_COUNT;
        if !range.contains(&self.rows) || !range.contains(&self.cols) {
            return Err(ResolutionError::Range(*self));
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
            .map(|p| crate::numeric::round_u64(self.delta_form_factor(p) * FIXED_ONE))
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
}

/// Sparse per-element form factors of one shot, accumulated in fixed point.
///
/// `add_cells` may be called for several partial item buffers in any order;
/// the result is the same because integer addition is associative.
#[derive(Debug, Default)]
pub struct FormFactorAccumulator {
    fixed: Vec<u64>,
    touched: Vec<u32>,
    /// Room for sorting `touched` (see [`radix_sort`]).
    scratch: Vec<u32>,
    /// Whether a sum overflowed (it is then left saturated, never wrapped).
    overflow: bool,
}

impl FormFactorAccumulator {
    /// An accumulator for `elements` elements.
    pub fn new(elements: usize) -> Self {
        Self {
            fixed: vec![0; elements],
            touched: Vec::new(),
            scratch: Vec::new(),
            overflow: false,
        }
    }

    /// Adds the delta form factor of every cell of `items` (row-major, `cols`
    /// values per row, from the top row) to the element it names,
    /// skipping elements for which `keep` (indexed by element) is false.
    pub fn add_cells(
        &mut self,
        items: &[u32],
        cols: usize,
        dff_fixed: &[u64],
        keep: Option<&[bool]>,
    ) {
        for (r, row) in items.chunks_exact(cols).enumerate() {
            let w = dff_fixed[r];
            for &id in row {
                if keep.is_some_and(|k| !k.get(id as usize).copied().unwrap_or(false)) {
                    continue;
                }
                self.add(id, w);
            }
        }
    }

    /// Adds `value` (fixed point) to element `id`; ids past the end (EMPTY, BLOCKED) are ignored.
    /// A sum that would pass `u64::MAX` saturates and is reported by
    /// [`FormFactorAccumulator::take_overflow`].
    pub fn add(&mut self, id: u32, value: u64) {
        if let Some(slot) = self.fixed.get_mut(id as usize) {
            if *slot == 0 {
                self.touched.push(id);
            }
            match slot.checked_add(value) {
                Some(v) => *slot = v,
                None => {
                    *slot = u64::MAX;
                    self.overflow = true;
                }
            }
        }
    }

    /// Whether a sum overflowed since the last call (and forget it).
    pub fn take_overflow(&mut self) -> bool {
        std::mem::take(&mut self.overflow)
    }

    /// Drains the accumulated fixed-point sums as (element, sum) pairs sorted by element.
    pub fn drain_fixed(&mut self, out: &mut Vec<(u32, u64)>) {
        out.clear();
        radix_sort(&mut self.touched, &mut self.scratch, self.fixed.len());
        for &id in &self.touched {
            out.push((id, std::mem::take(&mut self.fixed[id as usize])));
        }
        self.touched.clear();
    }

    /// The dense fixed-point sums (one per element), for exchanges that move
    /// them whole. After changing them call [`FormFactorAccumulator::retouch`].
    pub fn dense_mut(&mut self) -> &mut [u64] {
        &mut self.fixed
    }

    /// Rebuilds the list of nonzero elements after [`FormFactorAccumulator::dense_mut`],
    /// keeping only elements for which `keep` is true (the others are zeroed).
    pub fn retouch(&mut self, keep: &[bool]) {
        self.touched.clear();
        for (id, slot) in self.fixed.iter_mut().enumerate() {
            if *slot != 0 {
                if keep.get(id).copied().unwrap_or(false) {
                    self.touched.push(id as u32);
                } else {
                    *slot = 0;
                }
            }
        }
    }
}

/// Sorts `keys`, all below `bound`, by their digits of 11 bits, lowest
/// first (`scratch` is room for a copy): integers, so the order is the one
/// `sort_unstable` gives, in a few passes over the keys instead of a
/// comparison sort's log n (a cluttered room's shot touches 50 000
/// elements of 276 000; the sort was a third of draining them).
fn radix_sort(keys: &mut Vec<u32>, scratch: &mut Vec<u32>, bound: usize) {
    const BITS: u32 = 11;
    if keys.len() < 256 {
        keys.sort_unstable();
        return;
    }
    let width = usize::BITS - bound.max(1).leading_zeros();
    scratch.clear();
    scratch.resize(keys.len(), 0);
    let mut shift = 0;
    while shift < width {
        let mut start = [0usize; 1 << BITS];
        for &k in keys.iter() {
            start[((k >> shift) & ((1 << BITS) - 1)) as usize] += 1;
        }
        let mut sum = 0;
        for s in start.iter_mut() {
            let n = *s;
            *s = sum;
            sum += n;
        }
        for &k in keys.iter() {
            let digit = ((k >> shift) & ((1 << BITS) - 1)) as usize;
            scratch[start[digit]] = k;
            start[digit] += 1;
        }
        std::mem::swap(keys, scratch);
        shift += BITS;
    }
}

/// The cell-centre directions the hemisphere shader uses, computed once in
/// f64 and rounded to f32: per row (sin phi, cos phi), then per column
/// (cos theta, sin theta). The shader multiplies them (correctly rounded in
/// every driver), so every driver sees the same directions; its own f32
/// sin/cos would not (their precision is unspecified).
pub fn direction_table(res: Resolution) -> Vec<[f32; 2]> {
    let rows = (0..res.rows).map(|p| {
        let phi = (p as f64 + 0.5) * FRAC_PI_2 / res.rows as f64;
        [phi.sin() as f32, phi.cos() as f32]
    });
    let cols = (0..res.cols).map(|t| {
        let theta = (t as f64 + 0.5) * 2.0 * PI / res.cols as f64;
        [theta.cos() as f32, theta.sin() as f32]
    });
    rows.chain(cols).collect()
}

/// A vertex the tessellated projection draws: a point in the shooter's
/// frame, with its column given outright (`x_override >= 0`: a vertex at the
/// pole, whose azimuth is that of its neighbour) and an offset added to its
/// column (unwrapping across the theta = 0 seam, or a copy one turn over).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TessPoint {
    /// Shooter frame, relative to the hemisphere centre.
    pub p: Vec3,
    /// The column coordinate to use instead of the azimuth (negative: none).
    pub x_override: f32,
    /// Added to the column coordinate.
    pub x_offset: f32,
}

/// Most cuts along a piece's edge in the tessellated projection.
pub const MAX_TESSELLATION: u32 = 64;

/// (column, row) in cell units of the direction `p` (column in [0, cols)).
pub fn cell_coords(p: Vec3, res: Resolution) -> (f32, f32) {
    use std::f32::consts::{FRAC_PI_2 as HALF_PI, TAU};
    let mut theta = p.y.atan2(p.x);
    if theta < 0.0 {
        theta += TAU;
    }
    let rho = p.x.hypot(p.y);
    (
        theta / TAU * res.cols as f32,
        rho.atan2(p.z) / HALF_PI * res.rows as f32,
    )
}

/// The index (row-major, as an item buffer) of the cell holding the
/// direction `p`: [`cell_coords`] with [`crate::numeric::atan2_f32`]
/// (within 5e-7 rad, no library calls), so a cell on a boundary may be
/// either neighbour. For lookups that only need a nearby cell.
pub fn cell_holding(p: Vec3, res: Resolution) -> usize {
    use crate::numeric::atan2_f32;
    use std::f32::consts::{FRAC_PI_2, TAU};
    let theta = atan2_f32(p.y, p.x);
    let theta = if theta < 0.0 { theta + TAU } else { theta };
    let phi = atan2_f32((p.x * p.x + p.y * p.y).sqrt(), p.z);
    // Truncation saturates (a NaN gives 0): always a cell.
    let col = ((theta / TAU * res.cols as f32) as usize).min(res.cols as usize - 1);
    let row = ((phi / FRAC_PI_2 * res.rows as f32) as usize).min(res.rows as usize - 1);
    row * res.cols as usize + col
}

/// The column `x` moved by a whole turn of `cols` to within half a turn of `to`.
fn within_half_turn(x: f32, to: f32, cols: f32) -> f32 {
    if x - to > 0.5 * cols {
        x - cols
    } else if to - x > 0.5 * cols {
        x + cols
    } else {
        x
    }
}

/// How far the image of the segment a-b bends away from the chord of its
/// end points' images at its middle, in row heights (a column's share
/// weighted by its width on the sphere); 0 below the horizon.
fn bend(a: Vec3, b: Vec3, res: Resolution) -> f32 {
    let m = 0.5 * (a + b);
    if a.z <= 0.0 || b.z <= 0.0 || m.z <= 0.0 {
        return 0.0;
    }
    let cols = res.cols as f32;
    let near = |x: f32, to: f32| within_half_turn(x, to, cols);
    let (ax, ay) = cell_coords(a, res);
    let (bx, by) = cell_coords(b, res);
    let (mx, my) = cell_coords(m, res);
    let (bx, mx) = (near(bx, ax), near(mx, ax));
    // Columns are narrower than rows by sin(phi) on the sphere: measure the
    // column error at its true angular size, in row heights (near the pole
    // a column's width in angle goes to 0, and so does its error).
    let column =
        (0.5 * std::f32::consts::PI * my / res.rows as f32).sin() * (4.0 * res.rows as f32 / cols);
    ((mx - 0.5 * (ax + bx)) * column).hypot(my - 0.5 * (ay + by))
}

/// Cuts the planar piece `d` (corners in the shooter's frame; a triangle
/// repeats its last corner) into triangles whose edges' equal-angle images
/// are within `tolerance` cells of their chords (row heights; see `bend`) (a uniform grid of 1 to
/// [`MAX_TESSELLATION`] cuts per edge, the same for every edge of the piece,
/// so it has no cracks inside), clipped at the horizon (z >= 0), with
/// triangles across the theta = 0 seam drawn twice (unwrapped, and one turn
/// over) and a triangle holding the pole drawn as a fan of quads from row 0.
/// `emit` gets three vertices per triangle.
pub fn tessellate(d: &[Vec3; 4], res: Resolution, tolerance: f32, mut emit: impl FnMut(TessPoint)) {
    let tri = d[3] == d[2];
    let corners: &[Vec3] = if tri { &d[..3] } else { &d[..] };
    if let Some(pole) = pole_point(corners) {
        pole_fan(corners, pole, res, tolerance, &mut emit);
        return;
    }
    let at = |u: f32, v: f32| -> Vec3 {
        if tri {
            d[0] + (d[1] - d[0]) * u + (d[2] - d[0]) * v
        } else {
            crate::mesh::bilinear(d, u, v)
        }
    };
    // Lines whose bend decides the cut count: the edges and two middle lines.
    let quad_lines;
    let lines: &[(Vec3, Vec3)] = if tri {
        quad_lines = [
            (d[0], d[1]),
            (d[1], d[2]),
            (d[2], d[0]),
            (0.5 * (d[0] + d[1]), d[2]),
            (d[0], d[0]),
            (d[0], d[0]),
        ];
        &quad_lines[..4]
    } else {
        quad_lines = [
            (d[0], d[1]),
            (d[3], d[2]),
            (d[0], d[3]),
            (d[1], d[2]),
            (at(0.0, 0.5), at(1.0, 0.5)),
            (at(0.5, 0.0), at(0.5, 1.0)),
        ];
        &quad_lines
    };
    let mut n = 1u32;
    while n < MAX_TESSELLATION {
        let fine = lines.iter().all(|&(a, b)| {
            (0..n).all(|k| {
                let (s, t) = (k as f32 / n as f32, (k + 1) as f32 / n as f32);
                bend(a + (b - a) * s, a + (b - a) * t, res) <= tolerance
            })
        });
        if fine {
            break;
        }
        n *= 2;
    }
    emit_grid(tri, n, at, res, &mut emit);
}

/// A piece holding the pole: a fan of quads from row 0, one per cut of its
/// outline. Their sides are meridians, straight in cell space, so only the
/// outline needs cutting.
fn pole_fan(
    corners: &[Vec3],
    pole: Vec3,
    res: Resolution,
    tolerance: f32,
    emit: &mut impl FnMut(TessPoint),
) {
    let m = corners.len();
    for k in 0..m {
        let (a, b) = (corners[k], corners[(k + 1) % m]);
        let mut n = 1u32;
        while n < MAX_TESSELLATION
            && (0..n).any(|i| {
                let (s, t) = (i as f32 / n as f32, (i + 1) as f32 / n as f32);
                bend(a + (b - a) * s, a + (b - a) * t, res) > tolerance
            })
        {
            n *= 2;
        }
        for i in 0..n {
            let (s, t) = (i as f32 / n as f32, (i + 1) as f32 / n as f32);
            pole_quad(pole, a + (b - a) * s, a + (b - a) * t, res, emit);
        }
    }
}

/// Emits the triangles of an `n` x `n` grid over a piece (`at` maps (u, v)
/// to its point), or of the lattice over a triangle, clipped at the horizon.
fn emit_grid(
    tri: bool,
    n: u32,
    at: impl Fn(f32, f32) -> Vec3,
    res: Resolution,
    emit: &mut impl FnMut(TessPoint),
) {
    let f = n as f32;
    let mut out = |a: Vec3, b: Vec3, c: Vec3| clip_and_emit([a, b, c], res, emit);
    if tri {
        for j in 0..n {
            for i in 0..(n - j) {
                let p = |i: u32, j: u32| at(i as f32 / f, j as f32 / f);
                out(p(i, j), p(i + 1, j), p(i, j + 1));
                if i + j + 1 < n {
                    out(p(i + 1, j), p(i + 1, j + 1), p(i, j + 1));
                }
            }
        }
    } else {
        for j in 0..n {
            for i in 0..n {
                let p = |i: u32, j: u32| at(i as f32 / f, j as f32 / f);
                let (p00, p10, p11, p01) = (p(i, j), p(i + 1, j), p(i + 1, j + 1), p(i, j + 1));
                out(p00, p10, p11);
                out(p00, p11, p01);
            }
        }
    }
}

/// Clips a triangle to z >= 0 and emits what is left (see [`tessellate`]).
fn clip_and_emit(t: [Vec3; 3], res: Resolution, emit: &mut impl FnMut(TessPoint)) {
    if t.iter().all(|p| p.z <= 0.0) {
        return;
    }
    // At most four corners survive one plane; no allocation per triangle.
    let (mut poly, mut n) = ([Vec3::ZERO; 6], 0usize);
    let mut push = |p: Vec3| {
        if n == 0 || poly[n - 1] != p {
            poly[n] = p;
            n += 1;
        }
    };
    for k in 0..3 {
        let (a, b) = (t[k], t[(k + 1) % 3]);
        if a.z >= 0.0 {
            push(a);
        }
        if (a.z > 0.0) != (b.z > 0.0) && a.z != b.z {
            let s = a.z / (a.z - b.z);
            let mut x = a + (b - a) * s;
            x.z = 0.0;
            push(x);
        }
    }
    for k in 1..n.saturating_sub(1) {
        project_triangle([poly[0], poly[k], poly[k + 1]], res, emit);
    }
}

/// Emits one triangle above the horizon: unwrapped across the seam, or as
/// a fan of quads when it holds the pole.
fn project_triangle(t: [Vec3; 3], res: Resolution, emit: &mut impl FnMut(TessPoint)) {
    let cols = res.cols as f32;
    if let Some(pole) = pole_point(&t) {
        for k in 0..3 {
            pole_quad(pole, t[k], t[(k + 1) % 3], res, emit);
        }
        return;
    }
    let x = t.map(|p| cell_coords(p, res).0);
    // A vertex on the pole axis has no azimuth: it takes its neighbours'.
    let on_axis = t.map(|p| p.x.hypot(p.y) <= 1e-7 * p.length());
    // Unwrap around the triangle: each vertex's column taken within half a
    // turn of the previous one (a triangle that does not hold the pole spans
    // less than half a turn, so this finds its true extent).
    let near = |x: f32, to: f32| within_half_turn(x, to, cols);
    let mut pts = [TessPoint {
        p: Vec3::ZERO,
        x_override: -1.0,
        x_offset: 0.0,
    }; 3];
    let mut last: Option<f32> = None;
    let mut unwrapped = [0.0f32; 3];
    for k in 0..3 {
        if on_axis[k] {
            continue;
        }
        let u = last.map_or(x[k], |l| near(x[k], l));
        unwrapped[k] = u;
        pts[k] = TessPoint {
            p: t[k],
            x_override: -1.0,
            x_offset: u - x[k],
        };
        last = Some(u);
    }
    let placed = || (0..3).filter(|&k| !on_axis[k]).map(|k| unwrapped[k]);
    let count = placed().count();
    if count == 0 {
        return;
    }
    let mean = placed().sum::<f32>() / count as f32;
    for k in 0..3 {
        if on_axis[k] {
            pts[k] = TessPoint {
                p: t[k],
                x_override: mean.rem_euclid(cols),
                x_offset: mean - mean.rem_euclid(cols),
            };
        }
    }
    let (lo, hi) = placed().fold((f32::MAX, f32::MIN), |(l, h), x| (l.min(x), h.max(x)));
    for turn in [0.0, -cols, cols] {
        // Copies one turn over only where the triangle leaves [0, cols).
        if (turn < 0.0 && hi <= cols) || (turn > 0.0 && lo >= 0.0) {
            continue;
        }
        for q in pts {
            emit(TessPoint {
                x_offset: q.x_offset + turn,
                ..q
            });
        }
    }
}

/// Where the pole axis (+z) meets the convex planar polygon `c` (shooter
/// frame), if it passes strictly inside and above the horizon.
fn pole_point(c: &[Vec3]) -> Option<Vec3> {
    let z_of = |a: Vec3, b: Vec3| a.x * b.y - a.y * b.x;
    let m = c.len();
    let s = || (0..m).map(|k| z_of(c[k], c[(k + 1) % m]));
    let inside = s().all(|x| x > 0.0) || s().all(|x| x < 0.0);
    let n = (c[1] - c[0]).cross(c[2] - c[0]);
    if !inside || n.z == 0.0 {
        return None;
    }
    let t = n.dot(c[0]) / n.z;
    (t > 0.0).then(|| Vec3::new(0.0, 0.0, t))
}

/// The quad P|u, u, v, P|v between the pole `pole` and the segment u-v,
/// from row 0 (P takes the column of its neighbour), with a copy one turn
/// over where it leaves [0, cols).
fn pole_quad(pole: Vec3, u: Vec3, v: Vec3, res: Resolution, emit: &mut impl FnMut(TessPoint)) {
    let cols = res.cols as f32;
    let (xu, _) = cell_coords(u, res);
    let (xv, _) = cell_coords(v, res);
    let shift = within_half_turn(xv, xu, cols) - xv;
    let lo = xu.min(xv + shift);
    let hi = xu.max(xv + shift);
    for turn in [0.0, -cols, cols] {
        if (turn < 0.0 && hi <= cols) || (turn > 0.0 && lo >= 0.0) {
            continue;
        }
        let pu = TessPoint {
            p: pole,
            x_override: xu,
            x_offset: turn,
        };
        let pv = TessPoint {
            p: pole,
            x_override: xv,
            x_offset: shift + turn,
        };
        let uu = TessPoint {
            p: u,
            x_override: -1.0,
            x_offset: turn,
        };
        let vv = TessPoint {
            p: v,
            x_override: -1.0,
            x_offset: shift + turn,
        };
        for q in [pu, uu, vv, pu, vv, pv] {
            emit(q);
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_radix_sort_is_the_comparison_sort() {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut scratch = Vec::new();
        for (n, bound) in [
            (0, 1),
            (100, 7),
            (300, 1),
            (5000, 3000),
            (60_000, 276_300),
            (70_000, 1 << 31),
        ] {
            let mut keys: Vec<u32> = (0..n)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    (s % bound as u64) as u32
                })
                .collect();
            let mut expected = keys.clone();
            expected.sort_unstable();
            super::radix_sort(&mut keys, &mut scratch, bound);
            assert_eq!(keys, expected, "{n} keys below {bound}");
        }
    }

    #[test]
    fn the_cell_holding_a_direction_is_its_cell_coordinates_cell() {
        let res = super::Resolution {
            rows: 128,
            cols: 512,
        };
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        };
        let mut checked = 0;
        for _ in 0..20_000 {
            let p = glam::Vec3::new(next(), next(), next().abs());
            let (x, y) = super::cell_coords(p, res);
            // Away from cell boundaries the two atan2s agree on the cell.
            let edge = |v: f32| (v - v.round()).abs() < 1e-3;
            if p.length() < 0.1 || edge(x) || edge(y) {
                continue;
            }
            let want = (y as usize).min(127) * 512 + (x as usize).min(511);
            assert_eq!(super::cell_holding(p, res), want, "{p:?}");
            checked += 1;
        }
        assert!(checked > 15_000, "{checked} directions checked");
    }

    #[test]
    fn an_overflowing_sum_is_reported_not_wrapped() {
        let mut acc = super::FormFactorAccumulator::new(2);
        acc.add(1, u64::MAX - 1);
        assert!(!acc.take_overflow());
        acc.add(1, 5);
        assert!(acc.take_overflow());
        let mut out = Vec::new();
        acc.drain_fixed(&mut out);
        assert_eq!(out, vec![(1, u64::MAX)]);
        assert!(!acc.take_overflow());
    }

    use super::*;

    /// Every cell whose centre ray (in f64) passes inside the quad `d`.
    fn cells_inside(d: &[Vec3; 4], res: Resolution, rows: std::ops::Range<u32>) -> Vec<(u32, u32)> {
        let c: Vec<glam::DVec3> = d.iter().map(|v| v.as_dvec3()).collect();
        let centre = (c[0] + c[1] + c[2] + c[3]) / 4.0;
        let planes: Vec<glam::DVec3> = (0..4).map(|k| c[k].cross(c[(k + 1) % 4])).collect();
        let sides: Vec<f64> = planes.iter().map(|p| p.dot(centre).signum()).collect();
        let mut out = Vec::new();
        for p in rows {
            let phi = (p as f64 + 0.5) * FRAC_PI_2 / res.rows as f64;
            for t in 0..res.cols {
                let theta = (t as f64 + 0.5) * 2.0 * PI / res.cols as f64;
                let r =
                    glam::DVec3::new(phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos());
                // Well inside every edge plane (a cell on an edge may go either way).
                if planes
                    .iter()
                    .zip(&sides)
                    .all(|(pl, s)| pl.dot(r) * s > 1e-9 * pl.length())
                {
                    out.push((p, t));
                }
            }
        }
        out
    }

    fn in_rect(r: &CellRect, res: Resolution, (p, t): (u32, u32)) -> bool {
        let (y, x) = (p as f32 + 0.5, t as f32 + 0.5);
        let cols = res.cols as f32;
        r.y0 <= y
            && y <= r.y1
            && ((r.x0 <= x && x <= r.x1) || (r.x0 <= x + cols && x + cols <= r.x1))
    }

    #[test]
    fn rectangles_hold_every_cell_near_the_pole() {
        // Small quads a few rows from the pole, far away, at 512 x 2048 and
        // 2048 x 8192: the polar bound must hold the outline and every cell
        // the exact per-cell test accepts.
        for rows in [512, 2048] {
            pole_case(Resolution {
                rows,
                cols: 4 * rows,
            });
        }
    }

    fn pole_case(res: Resolution) {
        let row = FRAC_PI_2 / res.rows as f64;
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = move || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut missed = Vec::new();
        let mut worst = f64::MIN;
        for _ in 0..400 {
            let (phi, theta) = (rnd() * 3.0 * row, rnd() * 2.0 * PI);
            let dist = 1.0 + 999.0 * rnd();
            let half = (0.3 + 2.0 * rnd()) * row * dist;
            let centre =
                glam::DVec3::new(phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos())
                    * dist;
            let a = rnd() * PI;
            let (ex, ey) = (
                glam::DVec3::new(a.cos(), a.sin(), 0.0) * half,
                glam::DVec3::new(-a.sin(), a.cos(), 0.0) * half,
            );
            let d = [
                centre - ex - ey,
                centre + ex - ey,
                centre + ex + ey,
                centre - ex + ey,
            ]
            .map(|v| v.as_vec3());
            let rect = cell_bounds(&d, res, 2000.0);
            // The polar range of the outline, sampled in f64 (inside the true range).
            let (mut lo, mut hi) = (f64::MAX, 0.0f64);
            for k in 0..4 {
                let (a, b) = (d[k].as_dvec3(), d[(k + 1) % 4].as_dvec3());
                for i in 0..=64 {
                    let q = a + (b - a) * (i as f64 / 64.0);
                    let ph = q.x.hypot(q.y).atan2(q.z) / row;
                    lo = lo.min(ph);
                    hi = hi.max(ph);
                }
            }
            if let Some(r) = rect {
                worst = worst.max(r.y0 as f64 - lo).max(hi - r.y1 as f64);
            }
            for cell in cells_inside(&d, res, 0..8) {
                if !rect.is_some_and(|r| in_rect(&r, res, cell)) {
                    missed.push((cell, rect));
                }
            }
        }
        assert!(
            missed.is_empty(),
            "{res}: {} cells dropped, e.g. {:?}",
            missed.len(),
            missed.first()
        );
        assert!(
            worst <= 0.0,
            "{res}: the rectangle misses the outline by {worst} rows"
        );
    }

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

    /// The lanes give the scalar rectangle bit for bit: random convex quads
    /// and triangles anywhere around the centre (across the seam, over the
    /// pole, through the horizon, a corner nearly at the centre, edges
    /// seen end-on), and pieces built to tie (a corner repeated, corners at
    /// one polar angle, a symmetric piece over the pole).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn cell_bounds_in_lanes_are_the_scalar_ones_bit_for_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let mut seed = 0x5851_f42d_4c95_7f2du64;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let bits = |r: Option<CellRect>| r.map(|r| [r.x0, r.x1, r.y0, r.y1].map(f32::to_bits));
        let mut quads: Vec<[Vec3; 4]> = vec![
            [
                Vec3::new(1.0, 0.0, 1.0),
                Vec3::new(0.0, 1.0, 1.0),
                Vec3::new(-1.0, 0.0, 1.0),
                Vec3::new(0.0, -1.0, 1.0),
            ],
            [
                Vec3::new(1.0, 1.0, 1.0),
                Vec3::new(-1.0, 1.0, 1.0),
                Vec3::new(-1.0, -1.0, 1.0),
                Vec3::new(1.0, -1.0, 1.0),
            ],
            [
                Vec3::new(1.0, 0.0, 0.5),
                Vec3::new(0.0, 1.0, 0.5),
                Vec3::new(0.0, 1.0, 0.5),
                Vec3::new(1.0, 0.0, 0.5),
            ],
            [
                Vec3::new(1.0, -0.1, 0.0),
                Vec3::new(1.0, 0.1, 0.0),
                Vec3::new(1.0, 0.1, 0.2),
                Vec3::new(1.0, -0.1, 0.2),
            ],
            [
                Vec3::new(1e-9, 0.0, 1e-9),
                Vec3::new(1.0, 0.0, 1.0),
                Vec3::new(1.0, 1.0, 1.0),
                Vec3::new(0.0, 1.0, 1.0),
            ],
            [
                Vec3::new(0.0, 0.0, 1.0),
                Vec3::new(1.0, 0.0, 1.0),
                Vec3::new(1.0, 1.0, 1.0),
                Vec3::new(0.0, 1.0, 1.0),
            ],
        ];
        for _ in 0..200_000 {
            let centre = Vec3::new(rnd() * 4.0 - 2.0, rnd() * 4.0 - 2.0, rnd() * 3.0 - 0.5);
            let size = 10f32.powf(rnd() * 4.0 - 3.5);
            let (a, b) = (rnd() * std::f32::consts::TAU, rnd() * std::f32::consts::PI);
            let e1 = Vec3::new(a.cos() * b.sin(), a.sin() * b.sin(), b.cos()) * size;
            let e2 = e1.any_orthonormal_vector() * size * (0.2 + rnd());
            let mut q = [
                centre - e1 - e2,
                centre + e1 - e2,
                centre + e1 + e2,
                centre - e1 + e2,
            ];
            if rnd() < 0.25 {
                q[3] = q[2];
            }
            quads.push(q);
        }
        for res in [
            Resolution {
                rows: 128,
                cols: 512,
            },
            Resolution {
                rows: 512,
                cols: 2048,
            },
        ] {
            for q in &quads {
                for far in [10.0, 2000.0] {
                    // SAFETY: the CPU has AVX2, just tested.
                    let lanes = unsafe { lanes::cell_bounds(q, res, far) };
                    assert_eq!(
                        bits(lanes),
                        bits(cell_bounds_scalar(q, res, far)),
                        "{q:?} at {res}"
                    );
                }
            }
        }
    }

    /// Brute force: every cell whose centre ray hits the quad lies in its rectangle.
    #[test]
    fn cell_bounds_are_conservative() {
        let res = Resolution {
            rows: 32,
            cols: 128,
        };
        let quads: Vec<[Vec3; 4]> = vec![
            // across the seam
            [
                Vec3::new(1.0, -0.3, 0.2),
                Vec3::new(1.0, 0.3, 0.2),
                Vec3::new(1.0, 0.3, 0.8),
                Vec3::new(1.0, -0.3, 0.8),
            ],
            // around the pole
            [
                Vec3::new(-0.5, -0.5, 1.0),
                Vec3::new(0.5, -0.5, 1.0),
                Vec3::new(0.5, 0.5, 1.0),
                Vec3::new(-0.5, 0.5, 1.0),
            ],
            // just beside the pole
            [
                Vec3::new(0.05, -0.5, 1.0),
                Vec3::new(0.6, -0.5, 1.0),
                Vec3::new(0.6, 0.5, 1.0),
                Vec3::new(0.05, 0.5, 1.0),
            ],
            // through the horizon
            [
                Vec3::new(-0.2, 1.0, -0.5),
                Vec3::new(0.4, 1.0, -0.5),
                Vec3::new(0.4, 1.0, 0.5),
                Vec3::new(-0.2, 1.0, 0.5),
            ],
            // a triangle, tilted
            [
                Vec3::new(-1.0, -0.2, 0.1),
                Vec3::new(-0.3, -0.9, 0.4),
                Vec3::new(-0.6, 0.4, 0.9),
                Vec3::new(-0.6, 0.4, 0.9),
            ],
        ];
        for q in &quads {
            let r = cell_bounds(q, res, 10.0).expect("visible");
            let n = (q[2] - q[0]).cross(q[3] - q[1]).normalize();
            for p in 0..res.rows {
                for t in 0..res.cols {
                    let d = res.cell_direction(p, t);
                    let d = Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32);
                    let tt = n.dot(q[0]) / n.dot(d);
                    if tt.is_nan() || tt <= 0.0 {
                        continue;
                    }
                    let hit = d * tt;
                    let inside =
                        (0..4).all(|k| (q[(k + 1) % 4] - q[k]).cross(hit - q[k]).dot(n) >= -1e-6);
                    if inside {
                        let (x, y) = (t as f32 + 0.5, p as f32 + 0.5);
                        let in_x =
                            (r.x0 <= x && x <= r.x1) || (r.x0 <= x + 128.0 && x + 128.0 <= r.x1);
                        assert!(
                            in_x && r.y0 <= y && y <= r.y1,
                            "cell ({p},{t}) outside {r:?} for {q:?}"
                        );
                    }
                }
            }
        }
        // Entirely below the tangent plane: culled.
        let below = [
            Vec3::new(0.0, 0.0, -1.0),
            Vec3::new(1.0, 0.0, -1.0),
            Vec3::new(1.0, 1.0, -1.0),
            Vec3::new(0.0, 1.0, -1.0),
        ];
        assert!(cell_bounds(&below, res, 10.0).is_none());
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
        // The shader's direction table bounds both counts.
        assert!("1024x4096".parse::<Resolution>().is_ok());
        assert!("1024x4097".parse::<Resolution>().is_err());
    }
}
