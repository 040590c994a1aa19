//! The exact projection's fragments drawn on the CPU: what
//! `shaders/hemisphere.wgsl`'s `fs` does for each cell of each rectangle,
//! with the depth test after it, in the order the rectangles come.
//!
//! Where the adapter is itself a CPU rasteriser (lavapipe), a shot's
//! rectangles are small (a cluttered room draws about 2 000 of them and
//! 200 000 fragments a shot), and lavapipe's pipeline (binning, 4 x 4
//! blocks of lanes mostly idle, the fragment depth written from the
//! shader so no early test, one atomic per lane, the submission, clears
//! and copies) costs several times the arithmetic. Here a fragment is a
//! few dozen instructions, rows are dealt between threads, and the
//! coverage counts need no atomics: each thread counts its own cells.
//!
//! Drawn here or on the device, a cell gets the same test in f32; the
//! driver may round a few products or the division differently, so a
//! ray grazing an edge or a tie in depth can go the other way (a
//! handful of cells in a million, tested). Every rank of a run draws
//! the same way, so results stay the same on any rank count.

use super::proxies::Instance;
use crate::hemisphere::{Resolution, TileLayout, BLOCKED, EMPTY};
use std::ops::Range;

/// The shader's angular tolerance of the edge tests (`EDGE_TOL`).
const EDGE_TOL: f32 = 1.0e-6;

/// The CPU's drawing state, kept from shot to shot.
pub(crate) struct Software {
    res: Resolution,
    /// Per row (sin phi, cos phi), then per column (cos theta, sin theta):
    /// the shader's table (`hemisphere::direction_table`).
    rows: Vec<[f32; 2]>,
    cols: Vec<[f32; 2]>,
    depth: Vec<f32>,
    /// Per thread, its cells' coverage counts, and where asked its visible
    /// cells' counts (see [`Software::draw`]).
    counts: Vec<Counts>,
    visible: Vec<Counts>,
    /// The drawn rectangles' element ranges (first, count).
    ranges: Vec<(u32, u32)>,
    /// The rank's cells, kept while its place in the layout stays.
    owned: Option<Owned>,
    /// Each rectangle's test and owned cells (reused from shot to shot).
    rects: Rects,
    elements: usize,
}

/// One thread's coverage counts, per element (zero between shots).
type Counts = Vec<u32>;

/// Which cells a rank draws: per axis, its cells in order.
struct Owned {
    /// The layout and the rank's place in it.
    place: (TileLayout, (u32, u32)),
    cols: Vec<u32>,
    rows: Vec<u32>,
}

impl Owned {
    fn new(res: Resolution, layout: &TileLayout, own: (u32, u32)) -> Self {
        let (tw, th) = (layout.tile_w.max(1), layout.tile_h.max(1));
        let (px, py) = (layout.px.max(1), layout.py.max(1));
        Self {
            place: (*layout, own),
            cols: (0..res.cols).filter(|t| (t / tw) % px == own.0).collect(),
            rows: (0..res.rows).filter(|p| (p / th) % py == own.1).collect(),
        }
    }

    /// The positions in `cells` of the cells whose centres `[lo, hi)`
    /// holds (the rasteriser's rule: a centre on the near edge is in,
    /// one on the far edge out).
    fn span(cells: &[u32], lo: f32, hi: f32) -> Range<usize> {
        let first = Self::before(cells, lo);
        let end = Self::before(cells, hi);
        first..end.max(first)
    }

    /// How many of `cells` have their centre before `x`: where every cell
    /// is there (one rank's whole hemisphere), a guess from `x` moved to
    /// the exact count, else a binary search (the same count either way).
    fn before(cells: &[u32], x: f32) -> usize {
        let n = cells.len();
        let whole = cells.last().is_none_or(|&c| c as usize + 1 == n);
        if !whole {
            return cells.partition_point(|&c| (c as f32 + 0.5) < x);
        }
        let centre_before = |c: usize| (c as f32 + 0.5) < x;
        // A saturating cast (NaN: 0) within one of the count; no libm call.
        // Moved by at most one each way without branches (which way is a
        // coin toss for the predictor, four times a rectangle).
        let mut k = ((x - 0.5) as i64).clamp(0, n as i64) as usize;
        k -= usize::from((k > 0) & !centre_before(k.saturating_sub(1)));
        k += usize::from((k < n) & centre_before(k));
        k
    }
}

/// A rectangle's fragment test, prepared once.
struct Prepared {
    edges: [[f32; 3]; 4],
    plane: [f32; 4],
    back: bool,
    first: u32,
    lookup: Option<GridLookup>,
}

/// The shader's `grid_element_of`, with its per-rectangle parts made once.
struct GridLookup {
    origin: [f32; 3],
    x: [f32; 3],
    y: [f32; 3],
    ex: f32,
    f: [f32; 2],
    g: [f32; 2],
    n: [u32; 2],
    per: [u32; 2],
    /// 1 / per per axis, rounded (see [`div_by`]).
    per_inv: [f32; 2],
    patches_u: u32,
}

/// Elements along an axis below which [`div_by`] is exact.
const DIV_BY_EXACT: u32 = 1 << 20;

/// Whether an element grid (elements along u and v, ...) is short enough
/// to be drawn here (see [`div_by`]); a mesh with a longer one is drawn
/// by the device.
pub(crate) fn fits(grid: [u32; 4]) -> bool {
    grid[0] < DIV_BY_EXACT && grid[1] < DIV_BY_EXACT
}

/// a / d for a below [`DIV_BY_EXACT`], given r = 1 / d rounded: the
/// shader's `div_by` (its note says why the floor is the quotient), which
/// compilers can run lane by lane, unlike an integer divide.
#[inline(always)]
fn div_by(a: i32, r: f32) -> i32 {
    let q = (a as f32 + 0.5) * r;
    // SAFETY: a is an element index in [0, 2^20) and r in (0, 1], so q is
    // finite and in i32's range. (Positive, so the truncation is the
    // floor. `as` would test for NaN and range lane by lane, and the lanes
    // would no longer run side by side.)
    unsafe { q.to_int_unchecked() }
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn cross2(a: [f32; 2], b: [f32; 2]) -> f32 {
    a[0] * b[1] - a[1] * b[0]
}

impl GridLookup {
    fn new(inst: &Instance) -> Option<Self> {
        if inst.grid[0] == 0 {
            return None;
        }
        let normal = [inst.plane[0], inst.plane[1], inst.plane[2]];
        let x = [inst.axis[0], inst.axis[1], inst.axis[2]];
        let per = [inst.grid[2].max(1), inst.grid[3].max(1)];
        Some(Self {
            origin: [inst.origin[0], inst.origin[1], inst.origin[2]],
            x,
            y: cross(normal, x),
            ex: inst.bilinear[0],
            f: [inst.bilinear[1], inst.bilinear[2]],
            g: [inst.bilinear[3], inst.origin[3]],
            n: [inst.grid[0], inst.grid[1]],
            per,
            per_inv: per.map(|d| 1.0 / d as f32),
            patches_u: inst.grid[0] / per[0],
        })
    }
}

impl Prepared {
    fn new(inst: &Instance) -> Self {
        Self {
            edges: inst.edges,
            plane: inst.plane,
            back: inst.item[1] != 0,
            first: inst.item[0],
            lookup: GridLookup::new(inst),
        }
    }

    /// The shader's `fs` for the cells of one row whose centre rays are
    /// (x[l], y[l], z), lane by lane without branches so the compiler
    /// tests them side by side: per lane the item, the depth and whether
    /// the shader keeps the fragment.
    #[inline(always)]
    fn lanes(
        &self,
        x: &[f32; LANES],
        y: &[f32; LANES],
        z: f32,
        inv_far: f32,
    ) -> ([u32; LANES], [f32; LANES], [bool; LANES]) {
        let mut hit = [true; LANES];
        for e in &self.edges {
            for l in 0..LANES {
                // (Never NaN: the directions and normals are finite.)
                hit[l] &= x[l] * e[0] + y[l] * e[1] + z * e[2] >= -EDGE_TOL;
            }
        }
        // A run of cells wholly outside the outline (a quarter of the runs
        // in a cluttered room: rectangles bound slanted outlines loosely)
        // draws nothing: its depths and items are not needed.
        if hit == [false; LANES] {
            return ([self.first; LANES], [1.0; LANES], hit);
        }
        let [nx, ny, nz, w] = self.plane;
        let mut t = [0.0; LANES];
        for l in 0..LANES {
            let cosine = x[l] * nx + y[l] * ny + z * nz;
            t[l] = w / cosine;
            // `&`, not `&&`: no branch, so the lanes stay side by side. (A
            // NaN cosine makes t NaN, which fails the first test.)
            hit[l] &= (t[l] > 0.0) & (cosine.abs() >= 1.0e-12);
        }
        let mut depth = [0.0; LANES];
        let mut ids = [self.first; LANES];
        if self.back {
            for l in 0..LANES {
                depth[l] = (t[l] * inv_far * (1.0 + 1.0e-5)).min(1.0);
            }
            ids = [BLOCKED; LANES];
        } else {
            for l in 0..LANES {
                depth[l] = (t[l] * inv_far).min(1.0);
            }
            if let Some(g) = &self.lookup {
                ids = g.elements(self.first, x, y, z, &t);
            }
        }
        (ids, depth, hit)
    }
}

impl GridLookup {
    /// The shader's `inverse_bilinear` and `grid_element_of`: the element
    /// of the grid at each hit point (x, y, z) t, lane by lane. (A lane
    /// that missed still gets an element of the grid: u and v are clamped.)
    #[inline(always)]
    fn elements(
        &self,
        first: u32,
        x: &[f32; LANES],
        y: &[f32; LANES],
        z: f32,
        t: &[f32; LANES],
    ) -> [u32; LANES] {
        let (e, f, g) = ([self.ex, 0.0], self.f, self.g);
        let k2 = cross2(g, f);
        let ef = cross2(e, f);
        let mut h0 = [0.0f32; LANES];
        let (mut k0, mut k1) = ([0.0f32; LANES], [0.0f32; LANES]);
        let mut linear = [false; LANES];
        for l in 0..LANES {
            let q = [
                x[l] * t[l] - self.origin[0],
                y[l] * t[l] - self.origin[1],
                z * t[l] - self.origin[2],
            ];
            let h = [dot(q, self.x), dot(q, self.y)];
            h0[l] = h[0];
            k1[l] = ef + cross2(h, g);
            k0[l] = cross2(h, e);
            linear[l] = k2.abs() <= 1.0e-6 * k1[l].abs();
        }
        let mut v = [0.0f32; LANES];
        for l in 0..LANES {
            v[l] = -k0[l] / k1[l];
        }
        // A parallelogram's grid (most quads: k2 is then 0 but for
        // rounding) takes the linear root in every lane; only then is the
        // quadratic's square root and two divisions skipped, so every lane
        // still gets the shader's choice.
        if !linear.iter().all(|&b| b) {
            for l in 0..LANES {
                let w = (k1[l] * k1[l] - 4.0 * k0[l] * k2).max(0.0).sqrt();
                let near = (-k1[l] - w) / (2.0 * k2);
                let other = (-k1[l] + w) / (2.0 * k2);
                // As the shader tests it: a NaN root stays.
                #[allow(clippy::manual_range_contains)]
                let root = if (near < -0.01) | (near > 1.01) {
                    other
                } else {
                    near
                };
                v[l] = if linear[l] { v[l] } else { root };
            }
        }
        let mut u = [0.0f32; LANES];
        for l in 0..LANES {
            u[l] = (h0[l] - f[0] * v[l]) / (self.ex + g[0] * v[l]);
        }
        // Element counts fit in i32 (they index memory), so the
        // arithmetic can be signed, which x86-64 converts lane-wise.
        let [pu, pv] = self.per.map(|p| p as i32);
        let patches_u = self.patches_u as i32;
        let mut ids = [0; LANES];
        for l in 0..LANES {
            let iu = cell_index(u[l], self.n[0]);
            let iv = cell_index(v[l], self.n[1]);
            let (qu, qv) = (div_by(iu, self.per_inv[0]), div_by(iv, self.per_inv[1]));
            let patch = qv * patches_u + qu;
            ids[l] = first + (patch * pu * pv + (iv - qv * pv) * pu + (iu - qu * pu)) as u32;
        }
        ids
    }
}

/// The shader's min(u32(max(u, 0) n), n - 1): the clamp taken in f32
/// first (the same, for whole n - 1), so the conversion is in range.
#[inline(always)]
fn cell_index(u: f32, n: u32) -> i32 {
    // (`max` takes a NaN to 0, `min` an infinity to n - 1.)
    let x = (u.max(0.0) * n as f32).min((n - 1) as f32);
    // SAFETY: x is finite, in [0, n - 1] with n < 2^20 (see `fits`).
    unsafe { x.to_int_unchecked() }
}

/// Cells of a row tested side by side ([`Prepared::lanes`]).
const LANES: usize = 8;

/// One thread's rows: (row, its items, its depths).
type Band<'a> = Vec<(u32, &'a mut [u32], &'a mut [f32])>;

impl Software {
    /// The drawing state for hemispheres of `res` over `elements` elements.
    pub(crate) fn new(res: Resolution, elements: usize) -> Self {
        let table = crate::hemisphere::direction_table(res);
        let (rows, cols) = table.split_at(res.rows as usize);
        Self {
            res,
            rows: rows.to_vec(),
            cols: cols.to_vec(),
            depth: Vec::new(),
            counts: Vec::new(),
            visible: Vec::new(),
            ranges: Vec::new(),
            owned: None,
            rects: Rects::default(),
            elements,
        }
    }

    /// Draws the shot's instances in order into `items` (row-major, rows x
    /// cols; cells other ranks own stay [`EMPTY`]) as the device would, for
    /// the shot's rank of its layout, on up to `threads` threads; with `coverage`,
    /// fills it with every element's count of covered cells, hidden or
    /// not, in element order; with `visible` too, where this rank draws
    /// every cell, each count packed with the element's visible cells
    /// (visible << 32 | covered, as `formfactor::unpack` reads it: what
    /// the hybrid weights summed over `items` and added to the coverage
    /// give). Returns whether it packed them.
    pub(crate) fn draw_shot(
        &mut self,
        shot: &super::CellShot<'_>,
        threads: usize,
        items: &mut Vec<u32>,
        coverage: Option<&mut Vec<(u32, u64)>>,
        visible: bool,
    ) -> bool {
        let super::CellShot {
            instances,
            far,
            layout,
            own,
            ..
        } = *shot;
        let (rows, cols) = (self.res.rows as usize, self.res.cols as usize);
        items.clear();
        items.resize(rows * cols, EMPTY);
        self.depth.clear();
        self.depth.resize(rows * cols, 1.0);
        if self
            .owned
            .as_ref()
            .is_some_and(|o| o.place != (*layout, own))
        {
            self.owned = None;
        }
        let res = self.res;
        let owned = &*self
            .owned
            .get_or_insert_with(|| Owned::new(res, layout, own));
        let threads = threads.clamp(1, owned.rows.len().max(1));
        let counting = coverage.is_some();
        if counting {
            zeroed(&mut self.counts, threads, self.elements);
        }
        // Visible cells are counted only where every cell is the rank's.
        let packing = counting && visible && owned.cols.len() == cols && owned.rows.len() == rows;
        if packing {
            zeroed(&mut self.visible, threads, self.elements);
        }
        let bands = deal_rows(items, &mut self.depth, &owned.rows, (cols, threads));
        let inv_far = 1.0 / far;
        self.rects.prepare(instances, owned, threads);
        let shot = Shot {
            owned_cols: &owned.cols,
            prepared: &self.rects.prepared,
            spans: &self.rects.spans,
            rows: &self.rows,
            cols: &self.cols,
            inv_far,
            every_col: owned.cols.len() == cols
                && owned.cols.iter().enumerate().all(|(i, &t)| i == t as usize),
        };
        let run =
            |k: usize, band: &mut Band, counts: Option<&mut Counts>, seen: Option<&mut Counts>| {
                draw_band((k, threads), band, &shot, counts);
                if let Some(seen) = seen {
                    count_seen(band, seen);
                }
            };
        let mut counts = self.counts.iter_mut().filter(|_| counting);
        let mut seen = self.visible.iter_mut().filter(|_| packing);
        let mut work: Vec<(Band, Option<&mut Counts>, Option<&mut Counts>)> = bands
            .into_iter()
            .map(|b| (b, counts.next(), seen.next()))
            .collect();
        crate::parallel::each(work.iter_mut(), |k, (band, counts, seen)| {
            run(k, band, counts.as_deref_mut(), seen.as_deref_mut())
        });
        drop(work);
        if let Some(out) = coverage {
            self.gather(instances, (threads, packing), out);
        }
        packing
    }

    /// The threads' counts, summed into `out` in element order, and reset.
    /// Only the elements of the drawn rectangles can have counts: their
    /// ranges, in order without repeats (a polygon's pieces, seam copies
    /// and tile cuts share one), are read, so no thread keeps a list of
    /// what it touched (a branch a fragment).
    fn gather(
        &mut self,
        instances: &[Instance],
        (threads, packing): (usize, bool),
        out: &mut Vec<(u32, u64)>,
    ) {
        out.clear();
        self.ranges.clear();
        self.ranges.extend(
            instances
                .iter()
                .filter(|i| i.item[1] == 0)
                .map(|i| (i.item[0], (i.grid[0] * i.grid[1]).max(1))),
        );
        self.ranges.sort_unstable();
        self.ranges.dedup();
        let (ranges, counts) = (&self.ranges, &mut self.counts[..threads]);
        let visible = &mut self.visible[..if packing { threads } else { 0 }];
        // Two halves of the elements (ranges are disjoint, in order), the
        // second on another thread where there are many.
        let total: usize = ranges.iter().map(|r| r.1 as usize).sum();
        let cut = if threads > 1 && total >= PARALLEL_GATHER {
            let mut seen = 0;
            ranges
                .iter()
                .position(|r| {
                    seen += r.1 as usize;
                    2 * seen > total
                })
                .map_or(ranges.len(), |k| k + 1)
        } else {
            ranges.len()
        };
        let Some(&(split, _)) = ranges.get(cut) else {
            let all = (whole(counts), whole(visible));
            sum_counts(&ranges[..], all, 0, out);
            return;
        };
        let split_all = |list| halves(list, split as usize);
        let ((low, high), (low_seen, high_seen)) = (split_all(counts), split_all(visible));
        let mut rest = Vec::new();
        crate::parallel::scope(|s| {
            let later = &ranges[cut..];
            let rest = &mut rest;
            s.spawn(move |_| sum_counts(later, (high, high_seen), split as usize, rest));
            sum_counts(&ranges[..cut], (low, low_seen), 0, out);
        });
        out.extend_from_slice(&rest);
    }
}

/// Every thread's counts, whole.
fn whole(list: &mut [Counts]) -> Vec<&mut [u32]> {
    list.iter_mut().map(|c| &mut c[..]).collect()
}

/// Every thread's counts cut at element `split`.
fn halves(list: &mut [Counts], split: usize) -> (Vec<&mut [u32]>, Vec<&mut [u32]>) {
    list.iter_mut().map(|c| c.split_at_mut(split)).unzip()
}

/// Each element's visible cells in the band's rows, added to `seen`.
fn count_seen(band: &Band, seen: &mut Counts) {
    for (_, row, _) in band.iter() {
        for &id in row.iter() {
            if let Some(c) = seen.get_mut(id as usize) {
                *c += 1;
            }
        }
    }
}

/// `threads` per-thread counts of `elements` elements each.
fn zeroed(counts: &mut Vec<Counts>, threads: usize, elements: usize) {
    counts.resize_with(threads, Counts::default);
    for c in &mut counts[..threads] {
        c.resize(elements, 0);
    }
}

/// This rank's rows of `items` and `depth` (rows of `cols` cells), dealt in
/// turn over `threads` bands, so every thread gets cells near the pole and
/// the horizon alike.
fn deal_rows<'r>(
    items: &'r mut [u32],
    depth: &'r mut [f32],
    rows: &[u32],
    (cols, threads): (usize, usize),
) -> Vec<Band<'r>> {
    let mut bands: Vec<Band> = (0..threads).map(|_| Vec::new()).collect();
    let mut row_cells: Vec<Option<(&mut [u32], &mut [f32])>> = items
        .chunks_mut(cols)
        .zip(depth.chunks_mut(cols))
        .map(Some)
        .collect();
    for (k, &p) in rows.iter().enumerate() {
        if let Some((i, d)) = row_cells[p as usize].take() {
            bands[k % threads].push((p, i, d));
        }
    }
    bands
}

/// Each rectangle's test and owned cells, and the same for the second half
/// of a shot's rectangles, prepared on another thread where there are many
/// (all kept from shot to shot).
#[derive(Default)]
struct Rects {
    prepared: Vec<Prepared>,
    spans: Vec<Spans>,
    second: (Vec<Prepared>, Vec<Spans>),
}

impl Rects {
    /// Prepares `instances` for the cells `owned`, on up to two of `threads`.
    fn prepare(&mut self, instances: &[Instance], owned: &Owned, threads: usize) {
        let prepare = |list: &[Instance], prepared: &mut Vec<Prepared>, spans: &mut Vec<Spans>| {
            prepared.clear();
            prepared.extend(list.iter().map(Prepared::new));
            spans.clear();
            spans.extend(list.iter().map(|inst| {
                let [x0, x1, y0, y1] = inst.rect;
                (
                    Owned::span(&owned.cols, x0, x1),
                    Owned::span(&owned.rows, y0, y1),
                )
            }));
        };
        let Self {
            prepared,
            spans,
            second: (later, later_spans),
        } = self;
        if threads > 1 && instances.len() >= PARALLEL_PREPARE {
            let (first, rest) = instances.split_at(instances.len() / 2);
            crate::parallel::scope(|s| {
                s.spawn(|_| prepare(rest, later, later_spans));
                prepare(first, prepared, spans);
            });
            prepared.append(later);
            spans.append(later_spans);
        } else {
            prepare(instances, prepared, spans);
        }
    }
}

/// Rectangles below which they are prepared on one thread.
const PARALLEL_PREPARE: usize = 1024;

/// A rectangle's owned columns and rows (positions in the owned lists).
type Spans = (Range<usize>, Range<usize>);

/// Elements below which the counts are gathered on one thread.
const PARALLEL_GATHER: usize = 1 << 15;

/// The threads' coverage counts and, where kept, visible counts (each of
/// elements `from..`) over element `ranges`, summed into `out` in element
/// order where not zero (visible << 32 | covered: `formfactor::unpack`'s
/// packing), and reset.
fn sum_counts(
    ranges: &[(u32, u32)],
    (mut counts, mut visible): (Vec<&mut [u32]>, Vec<&mut [u32]>),
    from: usize,
    out: &mut Vec<(u32, u64)>,
) {
    let total = |list: &mut Vec<&mut [u32]>, id: usize| -> u64 {
        list.iter_mut()
            .map(|c| u64::from(std::mem::take(&mut c[id - from])))
            .sum()
    };
    for &(first, n) in ranges {
        for id in first as usize..(first + n) as usize {
            let sum = (total(&mut visible, id) << 32) | total(&mut counts, id);
            if sum > 0 {
                out.push((id as u32, sum));
            }
        }
    }
}

/// What every band of a shot reads.
struct Shot<'a> {
    /// The rank's columns, in order.
    owned_cols: &'a [u32],
    /// The rectangles, in drawing order, and the owned columns and rows
    /// (positions in the owned lists) their cells' centres lie in.
    prepared: &'a [Prepared],
    spans: &'a [Spans],
    /// The direction tables (see [`Software`]).
    rows: &'a [[f32; 2]],
    cols: &'a [[f32; 2]],
    inv_far: f32,
    /// Whether the rank owns every column (one process drawing the whole
    /// hemisphere): a span's positions are then its columns, and whole
    /// runs of eight cells are read and written side by side.
    every_col: bool,
}

/// Band `k` of `threads`' share of a shot: every rectangle, in order, in
/// its rows (owned rows k, k + threads, ...). Where the CPU has AVX2 the
/// same code is compiled for it too, and runs eight lanes an instruction
/// instead of four: the same operations, so the same bits.
fn draw_band(at: (usize, usize), band: &mut Band, shot: &Shot, counts: Option<&mut Counts>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, just tested.
        unsafe { draw_band_avx2(at, band, shot, counts) };
        return;
    }
    draw_band_lanes(at, band, shot, counts)
}

/// [`draw_band_lanes`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn draw_band_avx2(
    at: (usize, usize),
    band: &mut Band,
    shot: &Shot,
    counts: Option<&mut Counts>,
) {
    draw_band_lanes(at, band, shot, counts)
}

/// [`draw_band`], for whichever instructions it is compiled for.
#[inline(always)]
fn draw_band_lanes(
    (k, threads): (usize, usize),
    band: &mut Band,
    shot: &Shot,
    mut counts: Option<&mut Counts>,
) {
    let Shot {
        owned_cols,
        prepared,
        spans,
        rows,
        cols,
        inv_far,
        every_col,
    } = *shot;
    // The band's j-th row is owned row k + j threads: the first at or
    // after owned row i is its ceil((i - k) / threads)-th.
    let at = |i: usize| i.saturating_sub(k).div_ceil(threads);
    for (prep, (xs, ys)) in prepared.iter().zip(spans) {
        let (from, to) = (at(ys.start), at(ys.end).min(band.len()));
        if from >= to {
            continue;
        }
        for (p, row_items, row_depth) in &mut band[from..to] {
            let [s, c] = rows[*p as usize];
            // Whole runs of eight columns, where the columns are the
            // positions: the same operations a lane, without the gathers
            // and scatters through `owned_cols` (a fifth of the drawing).
            let mut start = xs.start;
            if every_col {
                while start + LANES <= xs.end {
                    let run = start..start + LANES;
                    start += LANES;
                    let (Ok(dirs), Ok(depth), Ok(items)) = (
                        <&[[f32; 2]; LANES]>::try_from(&cols[run.clone()]),
                        <&mut [f32; LANES]>::try_from(&mut row_depth[run.clone()]),
                        <&mut [u32; LANES]>::try_from(&mut row_items[run.clone()]),
                    ) else {
                        start -= LANES;
                        break;
                    };
                    let x: [f32; LANES] = std::array::from_fn(|l| s * dirs[l][0]);
                    let y: [f32; LANES] = std::array::from_fn(|l| s * dirs[l][1]);
                    let (ids, depths, hit) = prep.lanes(&x, &y, c, inv_far);
                    if let (Some(counts), false) = (counts.as_deref_mut(), prep.back) {
                        for l in 0..LANES {
                            counts[ids[l] as usize] += u32::from(hit[l]);
                        }
                    }
                    for l in 0..LANES {
                        let wins = hit[l] & (depths[l] < depth[l]);
                        depth[l] = if wins { depths[l] } else { depth[l] };
                        items[l] = if wins { ids[l] } else { items[l] };
                    }
                }
            }
            for ts in owned_cols[start..xs.end].chunks(LANES) {
                let (mut x, mut y) = ([0.0; LANES], [0.0; LANES]);
                for (l, &t) in ts.iter().enumerate() {
                    let [ct, st] = cols[t as usize];
                    x[l] = s * ct;
                    y[l] = s * st;
                }
                let (ids, depths, hit) = prep.lanes(&x, &y, c, inv_far);
                // Without branches on the lanes' outcomes (they are
                // unpredictable): a lane that missed adds 0 and keeps the cell.
                if let (Some(counts), false) = (counts.as_deref_mut(), prep.back) {
                    for l in 0..ts.len() {
                        counts[ids[l] as usize] += u32::from(hit[l]);
                    }
                }
                for (l, &t) in ts.iter().enumerate() {
                    let cell = t as usize;
                    let (depth, item) = (row_depth[cell], row_items[cell]);
                    let wins = hit[l] & (depths[l] < depth);
                    row_depth[cell] = if wins { depths[l] } else { depth };
                    row_items[cell] = if wins { ids[l] } else { item };
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn division_by_a_rounded_reciprocal_is_exact_below_the_bound() {
        // Every quotient of an element index by a grid's elements per
        // patch: all numerators below 2^16, then a stride up to the bound.
        for d in 1..=64u32 {
            let r = 1.0 / d as f32;
            let big = (1 << 16..DIV_BY_EXACT)
                .step_by(997)
                .chain([DIV_BY_EXACT - 1]);
            for a in (0..1 << 16).chain(big) {
                assert_eq!(div_by(a as i32, r) as u32, a / d, "{a} / {d}");
            }
        }
    }

    #[test]
    fn a_span_holds_the_cells_whose_centres_the_rectangle_holds() {
        // The rasteriser's rule, near edge in and far edge out, over a
        // rank's columns of a tiled grid, for rectangles anywhere (the
        // seam copies start below 0).
        let res = Resolution { rows: 16, cols: 64 };
        let layout = TileLayout {
            tile_w: 3,
            tile_h: 2,
            px: 2,
            py: 3,
        };
        let owned = Owned::new(res, &layout, (1, 2));
        assert!(owned.cols.iter().all(|t| (t / 3) % 2 == 1));
        assert!(owned.rows.iter().all(|p| (p / 2) % 3 == 2));
        // And over one rank's whole hemisphere (found without a search).
        let whole = Owned::new(res, &TileLayout::whole(res), (0, 0));
        let below = |x: f32| f32::from_bits(x.to_bits() - 1);
        let above = |x: f32| f32::from_bits(x.to_bits() + 1);
        let mut edges = vec![
            -70.0, -3.5, -0.5, 0.0, 1e-30, 0.5, 0.7, 3.0, 3.5, 17.25, 63.5, 64.0, 70.0,
        ];
        edges.extend(
            [0.5f32, 3.5, 17.5, 63.5]
                .iter()
                .flat_map(|&x| [below(x), above(x)]),
        );
        for cells in [&owned.cols, &whole.cols] {
            for &lo in &edges {
                for &hi in &edges {
                    let span = Owned::span(cells, lo, hi);
                    let expected: Vec<u32> = cells
                        .iter()
                        .copied()
                        .filter(|&c| lo <= c as f32 + 0.5 && (c as f32 + 0.5) < hi)
                        .collect();
                    assert_eq!(&cells[span], &expected[..], "[{lo}, {hi})");
                }
            }
        }
    }
}
