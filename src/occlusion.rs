//! Occlusion culling for one hemisphere: per cell, the nearest distance at
//! which some piece drawn in this shot certainly covers the cell's centre.
//! A polygon that is farther than that in every cell its pieces could
//! cover draws nothing that survives the depth test, and is left undrawn.
//!
//! In a cluttered scene most of what a hemisphere's rectangles hold is
//! hidden (cubes-b3: 188 000 elements covered, 21 500 visible; ten
//! fragments a cell), and a software rasteriser's time is its fragments.
//!
//! Everything here is conservative, with margins far above f32 rounding:
//! a piece counts as covering a cell only when the cell's centre direction
//! is inside every edge plane by [`INSIDE`] (the shader draws a fragment
//! from -1e-6); a polygon counts as present in a cell wherever its pieces'
//! edge tests pass within [`INSIDE`] outside, and is hidden there only when
//! the cover is nearer by a relative [`DEPTH_MARGIN`]. Pure maths: no GPU.

use crate::hemisphere::Resolution;

/// How far inside every edge plane (the sine of the angle) a cell's centre
/// direction must be for a piece to count as covering it, and how far
/// outside a piece may be and still count as present.
const INSIDE: f32 = 1e-4;

/// Relative margin between a cover's distance and a hidden piece's.
const DEPTH_MARGIN: f32 = 1e-4;

/// Below this cosine between a cell's direction and a piece's plane, the
/// distance along the ray is not trusted (the piece's nearest possible
/// distance stands in).
const GRAZING: f32 = 1e-6;

/// A piece as the map sees it: its conservative cell rectangle
/// ([x0, x1, y0, y1]; x may run past either end of the columns), the inward
/// unit normals of its edge planes (zero for a degenerate edge) and its
/// plane (unit normal, offset: the distance along a direction d is
/// offset / (normal . d)), all in the shooter's frame.
#[derive(Clone, Copy, Debug)]
pub struct Piece<'a> {
    /// Cell rectangle.
    pub rect: [f32; 4],
    /// Inward edge-plane normals.
    pub edges: &'a [[f32; 3]; 4],
    /// Plane normal and offset.
    pub plane: [f32; 4],
}

/// The cells of one hemisphere and how near each is certainly covered.
#[derive(Clone, Debug)]
pub struct OcclusionMap {
    res: Resolution,
    /// Per cell (row-major): the distance within which something covers its
    /// centre (infinite: nothing known).
    depth: Vec<f32>,
    /// Per row, per run of [`TILE`] columns: the farthest of its cells'
    /// depths (a sphere or piece wholly behind it needs no look at them).
    coarse: Vec<f32>,
    /// Per row: sin and cos of its centre's polar angle; per column: cos
    /// and sin of its centre's azimuth (`hemisphere::direction_table`, the
    /// shader's directions).
    rows: Vec<[f32; 2]>,
    cols_cos: Vec<f32>,
    cols_sin: Vec<f32>,
}

/// A piece's plane and its edges' planes seen along one row of cells: each
/// as (a, b, c) with n . d = a cos(theta) + b sin(theta) + c (a degenerate
/// edge as one no direction fails, so the tests below have no branches).
struct RowPlanes {
    edges: [[f32; 3]; 4],
    plane: [f32; 3],
}

/// A piece's edge planes with the degenerate ones marked, found once a
/// piece rather than once a row (see [`RowPlanes::along`]).
struct PiecePlanes {
    edges: [Option<[f32; 3]>; 4],
    plane: [f32; 3],
}

impl PiecePlanes {
    fn new(piece: &Piece) -> Self {
        Self {
            edges: piece
                .edges
                .map(|e| (e[0] * e[0] + e[1] * e[1] + e[2] * e[2] >= 0.25).then_some(e)),
            plane: [piece.plane[0], piece.plane[1], piece.plane[2]],
        }
    }
}

impl RowPlanes {
    /// The planes of `piece` along the row whose centre has polar sine
    /// and cosine `sp`, `cp`.
    #[inline(always)]
    fn along(piece: &PiecePlanes, [sp, cp]: [f32; 2]) -> Self {
        let along = |n: &[f32; 3]| [sp * n[0], sp * n[1], cp * n[2]];
        Self {
            edges: piece
                .edges
                .map(|e| e.map_or([0.0, 0.0, 1.0], |e| along(&e))),
            plane: along(&piece.plane),
        }
    }

    /// The least edge test of the direction (cos, sin) of a column.
    #[inline(always)]
    fn least(&self, ct: f32, st: f32) -> f32 {
        let [a, b, c, d] = self.edges.map(|e| e[0] * ct + e[1] * st + e[2]);
        a.min(b).min(c.min(d))
    }

    /// The cosine between the direction and the piece's plane normal.
    #[inline(always)]
    fn cosine(&self, ct: f32, st: f32) -> f32 {
        self.plane[0] * ct + self.plane[1] * st + self.plane[2]
    }
}

impl OcclusionMap {
    /// An empty map for hemispheres of `res`.
    pub fn new(res: Resolution) -> Self {
        let table = crate::hemisphere::direction_table(res);
        let (rows, cols) = table.split_at(res.rows as usize);
        Self {
            res,
            depth: vec![f32::INFINITY; res.cells()],
            coarse: vec![f32::INFINITY; res.rows as usize * tiles(res.cols as usize)],
            rows: rows.to_vec(),
            cols_cos: cols.iter().map(|c| c[0]).collect(),
            cols_sin: cols.iter().map(|c| c[1]).collect(),
        }
    }

    /// Forgets every cell's cover (a new shot).
    pub fn clear(&mut self) {
        self.depth.iter_mut().for_each(|d| *d = f32::INFINITY);
        self.coarse.iter_mut().for_each(|d| *d = f32::INFINITY);
    }

    /// Takes in a piece that is drawn: every cell whose centre direction is
    /// inside all its edge planes is covered at its distance there.
    /// Returns the cells the piece's rectangle holds.
    pub fn add(&mut self, piece: &Piece) -> usize {
        self.whole_band().add(piece)
    }

    /// Every row of the map, as one thread fills them.
    fn whole_band(&mut self) -> Band<'_> {
        Band {
            map: &self.rows,
            cos: &self.cols_cos,
            sin: &self.cols_sin,
            depth: &mut self.depth,
            coarse: &mut self.coarse,
            rows: 0..self.res.rows as usize,
        }
    }

    /// [`OcclusionMap::add`] for every item's piece, the rows divided
    /// between `threads` threads (the same map as one thread makes).
    /// Returns the cells the rectangles hold, in all.
    pub fn add_all<T: Sync>(
        &mut self,
        items: &[T],
        piece: fn(&T) -> Piece<'_>,
        threads: usize,
    ) -> usize {
        if threads <= 1 {
            return items.iter().map(|item| self.add(&piece(item))).sum();
        }
        let cols = self.res.cols as usize;
        let band = (self.res.rows as usize).div_ceil(threads).max(1);
        let (rows, cos, sin) = (&self.rows, &self.cols_cos, &self.cols_sin);
        let add = |k: usize, (depth, coarse): (&mut [f32], &mut [f32])| {
            let range = k * band..k * band + depth.len() / cols;
            let mut part = Band {
                map: rows,
                cos,
                sin,
                depth,
                coarse,
                rows: range,
            };
            items
                .iter()
                .map(|item| part.add(&piece(item)))
                .sum::<usize>()
        };
        let parts = self
            .depth
            .chunks_mut(band * cols)
            .zip(self.coarse.chunks_mut(band * tiles(cols)));
        crate::parallel::each(parts, add).iter().sum()
    }

    /// How many cell centres `rect` holds (what drawing it costs).
    pub fn cells_held(&self, rect: [f32; 4]) -> usize {
        let (p0, p1) = row_span(self.res, rect, 0..self.res.rows as usize);
        (p1 - p0) * column_runs(self.res, rect).map(|r| r.len()).sum::<usize>()
    }

    /// Whether every cell whose centre `rect` holds is covered nearer than
    /// `nearest` (a block of polygons, none nearer than that, is hidden
    /// whole).
    pub fn hides_rect(&mut self, rect: [f32; 4], nearest: f32) -> bool {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, just tested.
            return unsafe { self.hides_rect_avx2(rect, nearest) };
        }
        self.hides_rect_lanes(rect, nearest)
    }

    /// [`OcclusionMap::hides_rect_lanes`] compiled for AVX2 (see [`Band::add`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn hides_rect_avx2(&mut self, rect: [f32; 4], nearest: f32) -> bool {
        self.hides_rect_lanes(rect, nearest)
    }

    #[inline(always)]
    fn hides_rect_lanes(&mut self, rect: [f32; 4], nearest: f32) -> bool {
        let cols = self.res.cols as usize;
        let (p0, p1) = row_span(self.res, rect, 0..self.res.rows as usize);
        let farthest = |a: f32, d: &f32| a.max(*d);
        // The farthest cover of each run of cells (branch-free reductions:
        // a hidden block has every cell read anyway), whole tiles read
        // from their farthest.
        let runs = Runs::of(self.res, rect);
        (p0..p1).all(|p| {
            let depth = &self.depth[p * cols..(p + 1) * cols];
            let coarse = &mut self.coarse[p * tiles(cols)..(p + 1) * tiles(cols)];
            runs.iter().all(|run| {
                let (first, end) = (run.start.div_ceil(TILE), run.end / TILE);
                let far = if first < end {
                    refresh(&mut coarse[first..end], depth, first);
                    let head = depth[run.start..first * TILE].iter().fold(0.0, farthest);
                    let middle = coarse[first..end].iter().fold(head, farthest);
                    depth[end * TILE..run.end].iter().fold(middle, farthest)
                } else {
                    depth[run].iter().fold(0.0, farthest)
                };
                far * (1.0 + DEPTH_MARGIN) < nearest
            })
        })
    }

    /// Finds every stale tile's farthest depth (before [`OcclusionMap::hides`],
    /// which reads a stale tile's cells instead).
    pub fn refresh(&mut self) {
        let cols = self.res.cols as usize;
        for (coarse, depth) in self
            .coarse
            .chunks_mut(tiles(cols))
            .zip(self.depth.chunks(cols))
        {
            refresh(coarse, depth, 0);
        }
    }

    /// Whether every cell the piece could draw is covered nearer than the
    /// piece is there; `nearest` bounds its distance from below (used where
    /// its plane is seen edge-on).
    pub fn hides(&self, piece: &Piece, nearest: f32) -> bool {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, just tested.
            return unsafe { self.hides_avx2(piece, nearest) };
        }
        self.hides_lanes(piece, nearest, cells_hidden)
    }

    /// [`OcclusionMap::hides_lanes`] compiled for AVX2, a tile's cells
    /// eight at a time (see [`wide`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn hides_avx2(&self, piece: &Piece, nearest: f32) -> bool {
        if self.cols_cos.len() < wide::LANES {
            return self.hides_lanes(piece, nearest, cells_hidden);
        }
        self.hides_lanes(piece, nearest, |cells, planes, run| {
            // SAFETY: the CPU has AVX2 (this function's contract), and the
            // row has a window of lanes.
            unsafe { wide::cells_hidden(cells, planes, run) }
        })
    }

    /// Whether every cell `piece` could draw is covered nearer, each run
    /// of a tile's cells left to `run_hidden`.
    #[inline(always)]
    fn hides_lanes(
        &self,
        piece: &Piece,
        nearest: f32,
        run_hidden: impl Fn(&RowCells, &RowPlanes, std::ops::Range<usize>) -> bool,
    ) -> bool {
        let cols = self.res.cols as usize;
        let (p0, p1) = row_span(self.res, piece.rect, 0..self.res.rows as usize);
        let (prepared, runs) = (PiecePlanes::new(piece), Runs::of(self.res, piece.rect));
        (p0..p1).all(|p| {
            let planes = RowPlanes::along(&prepared, self.rows[p]);
            let depth = &self.depth[p * cols..(p + 1) * cols];
            let coarse = &self.coarse[p * tiles(cols)..(p + 1) * tiles(cols)];
            // A whole tile covered nearer than the piece can be is hidden
            // without a look at its cells (`at` below is never nearer).
            let hidden_tile = |t: usize| {
                let far = coarse[t / TILE];
                far != STALE && far * (1.0 + DEPTH_MARGIN) < nearest
            };
            let cells = RowCells {
                cos: &self.cols_cos,
                sin: &self.cols_sin,
                depth,
                offset: piece.plane[3],
                nearest,
            };
            runs.iter().all(|run| {
                // Tile by tile, each run of its cells.
                let mut t = run.start;
                while t < run.end {
                    let next = ((t / TILE + 1) * TILE).min(run.end);
                    let whole = next - t == TILE && hidden_tile(t);
                    if !whole && !run_hidden(&cells, &planes, t..next) {
                        return false;
                    }
                    t = next;
                }
                true
            })
        })
    }
}

/// One row of a map as [`OcclusionMap::hides`] reads it, with the piece's
/// plane offset and nearest possible distance.
struct RowCells<'a> {
    cos: &'a [f32],
    sin: &'a [f32],
    depth: &'a [f32],
    offset: f32,
    nearest: f32,
}

/// Whether every cell of `run` is hidden from the piece whose planes along
/// the row are `planes`: outside it, behind the hemisphere, or covered
/// nearer than the piece can be there.
fn cells_hidden(cells: &RowCells, planes: &RowPlanes, run: std::ops::Range<usize>) -> bool {
    run.into_iter().all(|t| {
        let (ct, st) = (cells.cos[t], cells.sin[t]);
        if planes.least(ct, st) < -INSIDE {
            return true;
        }
        let cos = planes.cosine(ct, st);
        let t_hit = cells.offset / cos;
        let at = if cos.abs() >= GRAZING && t_hit.is_finite() {
            if t_hit <= 0.0 {
                // Behind the hemisphere: no fragment.
                return true;
            }
            t_hit.max(cells.nearest)
        } else {
            cells.nearest
        };
        cells.depth[t] * (1.0 + DEPTH_MARGIN) < at
    })
}

/// The cell tests of [`Band::add`] and [`OcclusionMap::hides`] on eight
/// columns an instruction, whatever a run's length: the runs of a small
/// piece are a few cells long, and the compiler's vector loop left them
/// to its one-cell remainder. A run is taken in windows of eight columns
/// (the last moved back to end at the row's end), the lanes outside the
/// run masked; each lane does the scalar test's operations in its order,
/// so the same map and verdicts (tested).
#[cfg(target_arch = "x86_64")]
mod wide {
    use super::{RowCells, RowPlanes, DEPTH_MARGIN, GRAZING, INSIDE};
    use std::arch::x86_64::*;

    /// Columns a window holds.
    pub(super) const LANES: usize = 8;

    /// The least edge test and the plane's cosine of the window's columns.
    #[target_feature(enable = "avx2")]
    fn terms(planes: &RowPlanes, ct: __m256, st: __m256) -> (__m256, __m256) {
        let term = |e: &[f32; 3]| {
            let along = _mm256_add_ps(
                _mm256_mul_ps(_mm256_set1_ps(e[0]), ct),
                _mm256_mul_ps(_mm256_set1_ps(e[1]), st),
            );
            _mm256_add_ps(along, _mm256_set1_ps(e[2]))
        };
        let [a, b, c, d] = [0, 1, 2, 3].map(|k| term(&planes.edges[k]));
        let least = _mm256_min_ps(_mm256_min_ps(a, b), _mm256_min_ps(c, d));
        (least, term(&planes.plane))
    }

    /// All ones in the lanes of the window from `start` whose columns lie
    /// in `run`.
    #[target_feature(enable = "avx2")]
    fn in_run(start: usize, run: &std::ops::Range<usize>) -> __m256 {
        let column = _mm256_add_epi32(
            _mm256_set1_epi32(start as i32),
            _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
        );
        let from = _mm256_cmpgt_epi32(_mm256_set1_epi32(run.start as i32), column);
        let before = _mm256_cmpgt_epi32(_mm256_set1_epi32(run.end as i32), column);
        _mm256_castsi256_ps(_mm256_andnot_si256(from, before))
    }

    /// The windows over `run` in a row of `cols` columns (at least
    /// [`LANES`]): each window's first column.
    fn windows(run: std::ops::Range<usize>, cols: usize) -> impl Iterator<Item = usize> {
        let last = cols - LANES;
        (run.start..run.end)
            .step_by(LANES)
            .map(move |s| s.min(last))
    }

    /// [`super::cells_hidden`] a window at a time.
    ///
    /// # Safety
    /// The CPU must have AVX2, and the row at least [`LANES`] columns.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn cells_hidden(
        cells: &RowCells,
        planes: &RowPlanes,
        run: std::ops::Range<usize>,
    ) -> bool {
        let cols = cells.cos.len();
        let (sign, zero) = (_mm256_set1_ps(-0.0), _mm256_setzero_ps());
        let nearest = _mm256_set1_ps(cells.nearest);
        for w in windows(run.clone(), cols) {
            let load = |v: &[f32]| _mm256_loadu_ps(v[w..w + LANES].as_ptr());
            let (least, cos) = terms(planes, load(cells.cos), load(cells.sin));
            let outside = _mm256_cmp_ps::<_CMP_LT_OQ>(least, _mm256_set1_ps(-INSIDE));
            let t_hit = _mm256_div_ps(_mm256_set1_ps(cells.offset), cos);
            let finite = _mm256_cmp_ps::<_CMP_LT_OQ>(
                _mm256_andnot_ps(sign, t_hit),
                _mm256_set1_ps(f32::INFINITY),
            );
            let steep =
                _mm256_cmp_ps::<_CMP_GE_OQ>(_mm256_andnot_ps(sign, cos), _mm256_set1_ps(GRAZING));
            let trusted = _mm256_and_ps(steep, finite);
            let behind = _mm256_and_ps(trusted, _mm256_cmp_ps::<_CMP_LE_OQ>(t_hit, zero));
            let at = _mm256_blendv_ps(nearest, _mm256_max_ps(t_hit, nearest), trusted);
            let cover = _mm256_mul_ps(load(cells.depth), _mm256_set1_ps(1.0 + DEPTH_MARGIN));
            let covered = _mm256_cmp_ps::<_CMP_LT_OQ>(cover, at);
            let hidden = _mm256_or_ps(outside, _mm256_or_ps(behind, covered));
            let shown = _mm256_andnot_ps(hidden, in_run(w, &run));
            if _mm256_movemask_ps(shown) != 0 {
                return false;
            }
        }
        true
    }

    /// [`super::Band::add`]'s cell loop over `run` of `row` a window at
    /// a time.
    ///
    /// # Safety
    /// The CPU must have AVX2, and the row at least [`LANES`] columns.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn cover_run(
        row: &mut [f32],
        (cos, sin): (&[f32], &[f32]),
        planes: &RowPlanes,
        offset: f32,
        run: std::ops::Range<usize>,
    ) {
        let sign = _mm256_set1_ps(-0.0);
        for w in windows(run.clone(), cos.len()) {
            let load = |v: &[f32]| _mm256_loadu_ps(v[w..w + LANES].as_ptr());
            let (least, c) = terms(planes, load(cos), load(sin));
            let t_hit = _mm256_div_ps(_mm256_set1_ps(offset), c);
            let inside = _mm256_cmp_ps::<_CMP_GE_OQ>(least, _mm256_set1_ps(INSIDE));
            let steep =
                _mm256_cmp_ps::<_CMP_GE_OQ>(_mm256_andnot_ps(sign, c), _mm256_set1_ps(GRAZING));
            let ahead = _mm256_cmp_ps::<_CMP_GT_OQ>(t_hit, _mm256_setzero_ps());
            let covers = _mm256_and_ps(
                _mm256_and_ps(inside, steep),
                _mm256_and_ps(ahead, in_run(w, &run)),
            );
            let depth = &mut row[w..w + LANES];
            let old = _mm256_loadu_ps(depth.as_ptr());
            let new = _mm256_blendv_ps(old, _mm256_min_ps(old, t_hit), covers);
            _mm256_storeu_ps(depth.as_mut_ptr(), new);
        }
    }
}

/// Finds the farthest depth of every stale tile of `coarse` (tiles
/// `first..` of a row whose cells are `depth`).
fn refresh(coarse: &mut [f32], depth: &[f32], first: usize) {
    for (k, c) in coarse.iter_mut().enumerate() {
        if *c == STALE {
            let t = (first + k) * TILE;
            *c = depth[t..(t + TILE).min(depth.len())]
                .iter()
                .fold(0.0f32, |m, &d| m.max(d));
        }
    }
}

/// Some rows of a map, for one thread to fill.
struct Band<'a> {
    map: &'a [[f32; 2]],
    cos: &'a [f32],
    sin: &'a [f32],
    /// The rows `rows` of the map's depths, and of its tiles' farthest.
    depth: &'a mut [f32],
    coarse: &'a mut [f32],
    rows: std::ops::Range<usize>,
}

/// Columns a tile of [`OcclusionMap::coarse`] spans.
const TILE: usize = 16;

/// [`OcclusionMap::coarse`] of a tile whose cells changed since it was
/// last found (no depth is negative).
const STALE: f32 = -1.0;

/// Tiles of a row of `cols` columns.
fn tiles(cols: usize) -> usize {
    cols.div_ceil(TILE)
}

impl Band<'_> {
    /// Takes in a piece (see [`OcclusionMap::add`]). Where the CPU has
    /// AVX2 the same code runs compiled for it (eight cells an
    /// instruction instead of four): the same operations, so the same map.
    fn add(&mut self, piece: &Piece) -> usize {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, just tested.
            return unsafe { self.add_avx2(piece) };
        }
        self.add_lanes(piece, cover_run)
    }

    /// [`Band::add_lanes`] compiled for AVX2, a run's cells eight at a
    /// time (see [`wide`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn add_avx2(&mut self, piece: &Piece) -> usize {
        if self.cos.len() < wide::LANES {
            return self.add_lanes(piece, cover_run);
        }
        self.add_lanes(piece, |row, columns, planes, offset, run| {
            // SAFETY: the CPU has AVX2 (this function's contract), and the
            // row has a window of lanes.
            unsafe { wide::cover_run(row, columns, planes, offset, run) }
        })
    }

    /// Takes in a piece, each run of a row's cells left to `cover`.
    #[inline(always)]
    fn add_lanes(
        &mut self,
        piece: &Piece,
        cover: impl Fn(&mut [f32], (&[f32], &[f32]), &RowPlanes, f32, std::ops::Range<usize>),
    ) -> usize {
        let cols = self.cos.len();
        let res = Resolution {
            rows: self.map.len() as u32,
            cols: cols as u32,
        };
        let (p0, p1) = row_span(res, piece.rect, self.rows.clone());
        let mut held = 0;
        let (prepared, runs) = (PiecePlanes::new(piece), Runs::of(res, piece.rect));
        for p in p0..p1 {
            let planes = RowPlanes::along(&prepared, self.map[p]);
            let row = &mut self.depth[(p - self.rows.start) * cols..][..cols];
            for run in runs.iter() {
                held += run.len();
                cover(
                    row,
                    (self.cos, self.sin),
                    &planes,
                    piece.plane[3],
                    run.clone(),
                );
                // The tiles the run touched: their farthest, when asked.
                let coarse = &mut self.coarse[(p - self.rows.start) * tiles(cols)..][..tiles(cols)];
                coarse[run.start / TILE..=(run.end - 1) / TILE].fill(STALE);
            }
        }
        held
    }
}

/// Covers the cells of `run` of `row` that the piece whose planes along the
/// row are `planes` (plane offset `offset`) certainly covers, at its
/// distance there where nearer than their cover so far.
fn cover_run(
    row: &mut [f32],
    (cos, sin): (&[f32], &[f32]),
    planes: &RowPlanes,
    offset: f32,
    run: std::ops::Range<usize>,
) {
    let (cos, sin) = (&cos[run.clone()], &sin[run.clone()]);
    // Branch-free, so the loop vectorises.
    for ((d, &ct), &st) in row[run].iter_mut().zip(cos).zip(sin) {
        let c = planes.cosine(ct, st);
        let t_hit = offset / c;
        let covers = planes.least(ct, st) >= INSIDE && c.abs() >= GRAZING && t_hit > 0.0;
        *d = if covers { d.min(t_hit) } else { *d };
    }
}

/// The rows (a half-open range within `within`) whose centres `rect` holds.
fn row_span(res: Resolution, rect: [f32; 4], within: std::ops::Range<usize>) -> (usize, usize) {
    let lo = ((rect[2] - 0.5).ceil().max(0.0) as usize).max(within.start);
    let hi = (((rect[3] - 0.5).floor() + 1.0).clamp(0.0, res.rows as f32) as usize).min(within.end);
    (lo, hi.max(lo))
}

/// [`column_runs`] found once for a rectangle's rows (the same for each).
struct Runs {
    runs: [std::ops::Range<usize>; 2],
}

impl Runs {
    fn of(res: Resolution, rect: [f32; 4]) -> Self {
        let mut runs = [0..0, 0..0];
        for (slot, run) in runs.iter_mut().zip(column_runs(res, rect)) {
            *slot = run;
        }
        Self { runs }
    }

    /// The runs, in [`column_runs`]' order.
    fn iter(&self) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        self.runs.iter().filter(|r| !r.is_empty()).cloned()
    }
}

/// The columns whose centres `rect` holds, as at most two runs of column
/// indices (a rectangle past either end of the columns wraps around).
fn column_runs(res: Resolution, rect: [f32; 4]) -> impl Iterator<Item = std::ops::Range<usize>> {
    let cols = res.cols as i64;
    let lo = (rect[0] - 0.5).ceil() as i64;
    let hi = ((rect[1] - 0.5).floor() as i64).min(lo + cols - 1);
    // Unwrapped [lo, hi] shifted into [0, 2 cols), then cut at cols.
    let shift = lo.div_euclid(cols) * cols;
    let (a, b) = (lo - shift, hi - shift);
    let first = (a.min(cols) as usize)..((b + 1).clamp(0, cols) as usize);
    let second = 0..((b + 1 - cols).clamp(0, cols) as usize);
    [first, second].into_iter().filter(|r| !r.is_empty())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn res() -> Resolution {
        Resolution {
            rows: 32,
            cols: 128,
        }
    }

    /// A quad seen from the origin as `raster::proxies` draws a front face:
    /// inward edge normals and the plane.
    fn quad(d: [[f32; 3]; 4]) -> ([[f32; 3]; 4], [f32; 4]) {
        let v = d.map(glam::Vec3::from);
        let edges = std::array::from_fn(|k| (-v[k].cross(v[(k + 1) % 4]).normalize()).to_array());
        let n = (v[1] - v[0]).cross(v[2] - v[1]).normalize();
        (edges, [n.x, n.y, n.z, n.dot(v[0])])
    }

    /// A square of half-size `h` at height `z` overhead, facing down.
    fn overhead(h: f32, z: f32) -> ([[f32; 3]; 4], [f32; 4]) {
        quad([[-h, -h, z], [-h, h, z], [h, h, z], [h, -h, z]])
    }

    fn whole(r: Resolution) -> [f32; 4] {
        [0.0, r.cols as f32, 0.0, r.rows as f32]
    }

    #[test]
    fn a_cover_holds_only_cells_inside_the_piece_at_its_distance() {
        let r = res();
        let (edges, plane) = overhead(0.5, 1.0);
        let mut map = OcclusionMap::new(r);
        map.add(&Piece {
            rect: whole(r),
            edges: &edges,
            plane,
        });
        let mut covered = 0;
        for (k, &depth) in map.depth.iter().enumerate() {
            let (p, t) = (k / r.cols as usize, k % r.cols as usize);
            let theta = (t as f64 + 0.5) * std::f64::consts::TAU / r.cols as f64;
            let phi = (p as f64 + 0.5) * std::f64::consts::FRAC_PI_2 / r.rows as f64;
            let d = glam::DVec3::new(phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos());
            if depth.is_finite() {
                covered += 1;
                // Inside the square, at the distance to the plane z = 1.
                let hit = d / d.z;
                assert!(hit.x.abs() < 0.5 && hit.y.abs() < 0.5, "cell {t}, {p}");
                assert!((depth as f64 - 1.0 / d.z).abs() < 1e-5);
            }
        }
        assert!(covered > 200, "{covered} cells covered");
    }

    #[test]
    fn hidden_needs_every_cell_covered_nearer() {
        let r = res();
        let mut map = OcclusionMap::new(r);
        let (edges, plane) = overhead(5.0, 1.0);
        map.add(&Piece {
            rect: whole(r),
            edges: &edges,
            plane,
        });
        // A smaller square behind it: hidden; in front of it: not.
        let (e2, p2) = overhead(1.0, 2.0);
        let behind = Piece {
            rect: whole(r),
            edges: &e2,
            plane: p2,
        };
        assert!(map.hides(&behind, 2.0));
        let (e3, p3) = overhead(0.4, 0.9);
        let before = Piece {
            rect: whole(r),
            edges: &e3,
            plane: p3,
        };
        assert!(!map.hides(&before, 0.9));
        // A wide square behind reaches past the cover near the horizon.
        let (e4, p4) = overhead(50.0, 2.0);
        let wide = Piece {
            rect: whole(r),
            edges: &e4,
            plane: p4,
        };
        assert!(!map.hides(&wide, 2.0));
        // A rectangle between cell centres draws nothing: hidden.
        let between = Piece {
            rect: [10.6, 11.4, 20.0, 22.0],
            edges: &e4,
            plane: p4,
        };
        assert!(map.hides(&between, 2.0));
    }

    #[test]
    fn the_tiles_change_no_verdict() {
        // The tiles' farthest depths only let whole tiles be passed over:
        // every verdict is the one the cells alone give.
        let r = Resolution { rows: 24, cols: 96 };
        let mut rng = crate::rng::Rng(0x2545_f491_4f6c_dd1d);
        let mut uniform = move || rng.unit() as f32;
        let mut map = OcclusionMap::new(r);
        let mut pieces = Vec::new();
        for _ in 0..40 {
            let (x, y, h, z) = (
                uniform() - 0.5,
                uniform() - 0.5,
                0.05 + uniform(),
                0.2 + uniform(),
            );
            let c = [
                [x - h, y - h, z],
                [x - h, y + h, z],
                [x + h, y + h, z],
                [x + h, y - h, z],
            ];
            let rect = [
                uniform() * r.cols as f32 - 20.0,
                uniform() * r.cols as f32 + 40.0,
                uniform() * 8.0,
                8.0 + uniform() * 16.0,
            ];
            pieces.push((quad(c), rect, z));
        }
        let mut hidden = [0, 0];
        for (k, ((edges, plane), rect, z)) in pieces.iter().enumerate() {
            let piece = Piece {
                rect: *rect,
                edges,
                plane: *plane,
            };
            // Before and after adding, against the cells read one by one.
            for d in [0.3, *z, 1.5 * z] {
                let mut cells_only = map.clone();
                cells_only.coarse.fill(STALE);
                let want = cells_only.hides(&piece, d);
                map.refresh();
                assert_eq!(map.hides(&piece, d), want, "piece {k} at {d}");
                let (p0, p1) = row_span(r, *rect, 0..r.rows as usize);
                let far = (p0..p1)
                    .flat_map(|p| {
                        column_runs(r, *rect).flat_map(move |run| run.map(move |t| (p, t)))
                    })
                    .map(|(p, t)| map.depth[p * r.cols as usize + t])
                    .fold(0.0f32, f32::max);
                let want_rect = p0 >= p1 || far * (1.0 + DEPTH_MARGIN) < d;
                assert_eq!(map.hides_rect(*rect, d), want_rect, "rectangle {k} at {d}");
                hidden[usize::from(want)] += 1;
            }
            map.add(&piece);
        }
        assert!(
            hidden[0] > 10 && hidden[1] > 10,
            "{hidden:?}: both verdicts"
        );
    }

    /// The windows of eight give the scalar loops' map and verdicts bit for
    /// bit: random tilted pieces (grazing, behind the centre, across the
    /// seam) over rectangles that cut runs of every length.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn windows_of_eight_give_the_scalar_map_and_verdicts() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let mut rng = crate::rng::Rng(0x9e37_79b9_7f4a_7c15);
        let mut uniform = move || rng.unit() as f32;
        let mut verdicts = [0, 0];
        for r in [
            Resolution { rows: 24, cols: 96 },
            Resolution {
                rows: 128,
                cols: 512,
            },
        ] {
            let (mut scalar, mut wide) = (OcclusionMap::new(r), OcclusionMap::new(r));
            for k in 0..300 {
                let centre = [
                    uniform() * 2.0 - 1.0,
                    uniform() * 2.0 - 1.0,
                    uniform() * 1.5 - 0.3,
                ];
                let (a, b) = (uniform() * 0.6, uniform() * 0.6);
                let tilt = uniform() - 0.5;
                let c = [
                    [centre[0] - a, centre[1] - b, centre[2] - tilt * a],
                    [centre[0] - a, centre[1] + b, centre[2] - tilt * a],
                    [centre[0] + a, centre[1] + b, centre[2] + tilt * a],
                    [centre[0] + a, centre[1] - b, centre[2] + tilt * a],
                ];
                let (edges, plane) = quad(c);
                let x0 = uniform() * r.cols as f32 * 1.2 - 0.2 * r.cols as f32;
                let y0 = uniform() * r.rows as f32;
                let rect = [x0, x0 + uniform() * 40.0, y0, y0 + uniform() * 12.0];
                let piece = Piece {
                    rect,
                    edges: &edges,
                    plane,
                };
                for nearest in [0.2, 0.8, 2.0] {
                    let want = scalar.hides_lanes(&piece, nearest, cells_hidden);
                    // SAFETY: the CPU has AVX2, just tested.
                    let got = unsafe { wide.hides_avx2(&piece, nearest) };
                    assert_eq!(got, want, "piece {k} at {nearest} in {r}");
                    verdicts[usize::from(want)] += 1;
                }
                scalar.whole_band().add_lanes(&piece, cover_run);
                // SAFETY: the CPU has AVX2, just tested.
                unsafe { wide.whole_band().add_avx2(&piece) };
                let bits =
                    |m: &OcclusionMap| m.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>();
                assert!(
                    bits(&scalar) == bits(&wide),
                    "piece {k} in {r}: the maps differ"
                );
                assert!(
                    scalar.coarse == wide.coarse,
                    "piece {k} in {r}: the tiles differ"
                );
            }
            let covered = scalar.depth.iter().filter(|d| d.is_finite()).count();
            assert!(covered > 500, "{covered} cells of {r} covered");
        }
        assert!(
            verdicts[0] > 50 && verdicts[1] > 50,
            "{verdicts:?}: both verdicts"
        );
    }

    #[test]
    fn rectangles_across_the_seam_wrap() {
        let r = res();
        let mut map = OcclusionMap::new(r);
        let (edges, plane) = overhead(5.0, 1.0);
        // The copy shifted a turn down covers the same cells.
        map.add(&Piece {
            rect: [-(r.cols as f32), 0.0, 0.0, r.rows as f32],
            edges: &edges,
            plane,
        });
        let (e2, p2) = overhead(1.0, 2.0);
        let behind = Piece {
            rect: [-3.0, 2.0, 0.0, 6.0],
            edges: &e2,
            plane: p2,
        };
        assert!(map.hides(&behind, 2.0));
    }
}
