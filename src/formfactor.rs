//! Analytic form factors: a differential area to a planar polygon by
//! Lambert's contour integral, the value behind the receiver-side ("hybrid")
//! form factors of Baum, Rushmeier & Winget (1989).
//!
//! The hemisphere tells which receivers see the shooter and how much of it
//! (a visibility fraction); this module gives what an unoccluded receiver
//! point gets, exactly. Pure maths: nothing here knows about GPUs or ranks.

use crate::mesh::{element_centre, Mesh};
use crate::shot::{ShotRegion, Transfer};
use glam::DVec3;

mod contour;
pub use contour::*;

/// How one visible cell counts in a hybrid shot's per-element sums: visible
/// cells in the high 32 bits, covered cells (hidden or not) in the low 32, so
/// that plain u64 addition, whatever the order or the rank, sums both at once.
pub const VISIBLE_ONE: u64 = 1 << 32;

/// Splits a packed count into (visible cells, covered cells).
pub fn unpack(v: u64) -> (u64, u64) {
    (v >> 32, v & 0xffff_ffff)
}

/// Shooter patches with at most this many elements keep one form factor per
/// element (so each element can shoot its own share); larger ones shoot as a whole.
pub const MAX_SHOOTER_COLUMNS: usize = 16;

/// The groups of a shooter's `columns` elements that get a hemisphere each
/// when its shot is split: up to four runs of consecutive elements (for a
/// quad patch, rows of its element grid), with the area-weighted centre of
/// each (moved out of any closed solid it lies in).
pub fn split_groups(
    mesh: &Mesh,
    shooter: u32,
    columns: usize,
) -> Vec<(std::ops::Range<usize>, glam::Vec3)> {
    let sp = &mesh.patches[shooter as usize];
    let per = columns.div_ceil(4).max(1);
    (0..columns)
        .step_by(per)
        .map(|start| {
            let range = start..(start + per).min(columns);
            let first = sp.elements.start as usize;
            // Outside every solid (see `Mesh::open_centre`).
            let elements = &mesh.elements[first + range.start..first + range.end];
            let centre = mesh
                .open_centre(sp.polygon, elements.iter())
                .or_else(|| crate::mesh::area_centroid(elements))
                .unwrap_or(sp.centre);
            (range, centre)
        })
        .collect()
}

/// What a hybrid row reads of every receiver element, packed: a big
/// scene's row visits about 100 000 of them in element order, and reading
/// the element, patch and polygon records (120, 80 and 120 bytes) was a
/// cache miss each, most of a row's time outside the integrals.
pub struct ReceiverTable {
    elements: Vec<ReceiverElement>,
    /// Per polygon, its normal.
    normals: Vec<glam::Vec3>,
    /// Per patch, its elements' first and one-past-last index.
    patch_elements: Vec<[u32; 2]>,
    /// Per element, its patch and polygon, apart: a shot asks them of the
    /// elements its cells saw, in no order (a miss a 40-byte record).
    owners: Vec<[u32; 2]>,
}

/// One element in a [`ReceiverTable`].
#[derive(Clone, Copy)]
struct ReceiverElement {
    centre: glam::Vec3,
    polygon: u32,
    area: f64,
    /// The largest distance from its centre to a corner.
    radius: f64,
}

impl ReceiverTable {
    /// The table of `mesh` (32 bytes an element, and 8 in `owners`).
    pub fn new(mesh: &Mesh) -> Self {
        Self {
            elements: mesh
                .elements
                .iter()
                .map(|e| {
                    let centre = element_centre(e);
                    ReceiverElement {
                        centre,
                        polygon: e.polygon,
                        area: e.area,
                        radius: element_radius(e, centre.as_dvec3()),
                    }
                })
                .collect(),
            normals: mesh.polygons.iter().map(|p| p.normal).collect(),
            patch_elements: mesh
                .patches
                .iter()
                .map(|p| [p.elements.start, p.elements.end])
                .collect(),
            owners: mesh.elements.iter().map(|e| [e.patch, e.polygon]).collect(),
        }
    }

    /// The patch of element `j`.
    pub fn patch(&self, j: u32) -> u32 {
        self.owners[j as usize][0]
    }

    /// The centre of element `j` (the element record's).
    pub fn centre(&self, j: u32) -> glam::Vec3 {
        self.elements[j as usize].centre
    }

    /// The first and one-past-last elements of patch `k`.
    pub fn elements_of(&self, k: u32) -> [u32; 2] {
        self.patch_elements[k as usize]
    }

    /// The polygon of element `j`, if there is such an element.
    pub fn polygon(&self, j: u32) -> Option<u32> {
        self.owners.get(j as usize).map(|o| o[1])
    }

    /// The area of element `j` (the element record's).
    pub fn area(&self, j: u32) -> f64 {
        self.elements[j as usize].area
    }
}

/// Receivers farther than this many shooter radii from the shooter's centre
/// take one integral over the whole patch instead of one per shooter element.
pub const NEAR_FIELD: f64 = 4.0;

/// Rows with at least this many integrals are evaluated on every core.
const PARALLEL_INTEGRALS: usize = 4096;

/// One shooter's form factors to the receivers it reaches: for each receiver,
/// one value per shooter element (`columns` of them; 1 when the patch shoots
/// as a whole). The form factor for a given spread of the shooter's unshot
/// radiosity over its elements is the weighted sum (see [`Row::combine`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Row {
    /// Values per receiver.
    pub columns: usize,
    /// Receiving elements, sorted.
    pub ids: Vec<u32>,
    /// `columns` values per receiver, receiver-major.
    pub values: Vec<f64>,
    /// The form factor hidden from the shooter's centre among receivers
    /// within [`NEAR_FIELD`] shooter radii, and the row's total (visible)
    /// form factor, both in [`SHARE_ONE`] fixed point (see [`hybrid_row`]).
    pub near_hidden: u64,
    /// See `near_hidden`.
    pub total: u64,
    /// The visible form factor of receivers that the shooter's centre sees
    /// only partly (some of their cells hidden): where a shadow edge crosses
    /// them, at any distance. Its share of `total` says how much of the
    /// shooter's light lands where its size would blur the shadow (a
    /// penumbra), which one point at its centre cannot see: the shooter
    /// refinement criterion (`refine`). [`SHARE_ONE`] fixed point.
    pub partial: u64,
    /// Per column, the share of that shooter element's light (delta form
    /// factors of its hemisphere's cells, over every rank) that meets the
    /// back of a one-sided surface: light the black back face absorbs.
    pub blocked: Vec<f64>,
}

impl Row {
    /// What the shot `region` sends each receiver: F_ij (the columns summed)
    /// and sum_k F_ij,k * S_k per channel, with each column's own shot
    /// radiosity where the region gives one per element (and this row has a
    /// column per element), else the patch's.
    pub fn combine(&self, region: &ShotRegion, out: &mut Vec<Transfer>) {
        out.clear();
        let m = self.columns.max(1);
        let per_element = region.elements.len() == m && m > 1;
        for (&id, v) in self.ids.iter().zip(self.values.chunks_exact(m)) {
            let f: f64 = v.iter().sum();
            if f <= 0.0 {
                continue;
            }
            let radiosity = if per_element {
                let mut r = [0.0; 3];
                for (a, s) in v.iter().zip(&region.elements) {
                    for c in 0..3 {
                        r[c] += a * s[c];
                    }
                }
                r
            } else {
                region.shoot.map(|s| f * s)
            };
            out.push(Transfer {
                element: id,
                form_factor: f,
                radiosity,
            });
        }
    }

    /// Adds `other` (the same shooter, other columns) receiver by receiver.
    pub fn merge(&mut self, other: &Row) {
        let m = self.columns.max(1);
        let (mut ids, mut values) = (Vec::new(), Vec::new());
        let (mut a, mut b) = (0, 0);
        while a < self.ids.len() || b < other.ids.len() {
            let ia = self.ids.get(a).copied().unwrap_or(u32::MAX);
            let ib = other.ids.get(b).copied().unwrap_or(u32::MAX);
            let id = ia.min(ib);
            let start = values.len();
            values.resize(start + m, 0.0);
            if ia == id {
                for (v, x) in values[start..]
                    .iter_mut()
                    .zip(&self.values[a * m..(a + 1) * m])
                {
                    *v += x;
                }
                a += 1;
            }
            if ib == id {
                for (v, x) in values[start..]
                    .iter_mut()
                    .zip(&other.values[b * m..(b + 1) * m])
                {
                    *v += x;
                }
                b += 1;
            }
            ids.push(id);
        }
        self.ids = ids;
        self.values = values;
        self.near_hidden += other.near_hidden;
        self.partial += other.partial;
        self.total += other.total;
    }

    /// Keeps only the receivers `keep` accepts (the decision statistics stay).
    pub fn retain(&mut self, keep: impl Fn(u32) -> bool) {
        let m = self.columns.max(1);
        let mut n = 0;
        for k in 0..self.ids.len() {
            if keep(self.ids[k]) {
                self.ids[n] = self.ids[k];
                self.values.copy_within(k * m..(k + 1) * m, n * m);
                n += 1;
            }
        }
        self.ids.truncate(n);
        self.values.truncate(n * m);
    }

    /// Each column's sum over this row's receivers, every value rounded to
    /// [`SHARE_ONE`] fixed point on its own (so sums over ranks are exact).
    pub fn column_totals(&self) -> Vec<u64> {
        let m = self.columns.max(1);
        let mut out = vec![0u64; m];
        for v in self.values.chunks_exact(m) {
            for (o, x) in out.iter_mut().zip(v) {
                *o += to_share(*x);
            }
        }
        out
    }

    /// Scales column k's values by `scales[k]` (the row normalised to what
    /// its hemisphere saw; the decision statistics stay as measured).
    pub fn scale_columns(&mut self, scales: &[f64]) {
        let m = self.columns.max(1);
        for v in self.values.chunks_exact_mut(m) {
            for (x, s) in v.iter_mut().zip(scales) {
                *x *= s;
            }
        }
    }

    /// Bytes this row holds (its allocations, not only what it uses).
    pub fn bytes(&self) -> usize {
        std::mem::size_of::<Self>()
            + 4 * self.ids.capacity()
            + 8 * (self.values.capacity() + self.blocked.capacity())
    }

    /// Gives back what the row's vectors hold beyond their lengths.
    pub fn shrink_to_fit(&mut self) {
        self.ids.shrink_to_fit();
        self.values.shrink_to_fit();
        self.blocked.shrink_to_fit();
    }
}

/// Receiver-side form factors of one shot (Baum, Rushmeier & Winget 1989):
/// for each element j of a patch that the hemisphere saw and each element k
/// of the shooter patch i,
///
/// F_ij,k = V_j * F(dA_j -> A_k) * A_j / A_i,
///
/// where F(dA_j -> A_k) is Lambert's contour integral from j's centre to k's
/// outline (exact when nothing is in between; the whole patch's outline when
/// it has more than [`MAX_SHOOTER_COLUMNS`] elements) and the visibility
/// V_j = visible cells / covered cells comes from the same hemisphere, so
/// cell-sampling error (aliasing) cancels. An element that no cell centre hit
/// takes its patch's visibility, so small receivers are not lost between cell
/// centres. `counts` holds (element, packed count) pairs sorted by element
/// (see [`VISIBLE_ONE`]).
///
/// Only the columns in `columns` are filled (the others are 0): a shot split
/// into sub-hemispheres fills each group of shooter elements from its own.
/// The row's `near_hidden` is the form factor that receivers nearer than
/// [`NEAR_FIELD`] shooter radii lose to occlusion seen from the shooter's
/// centre; where that is a noticeable share of the row ([`needs_split`]),
/// visibility from one point is not to be trusted (see [`split_groups`]).
pub fn hybrid_row(
    mesh: &Mesh,
    table: &ReceiverTable,
    shooter: u32,
    counts: &[(u32, u64)],
    columns: std::ops::Range<usize>,
) -> Row {
    let geo = ShooterGeometry::new(mesh, shooter);
    let mut row = Row {
        columns: geo.outlines.len(),
        ..Row::default()
    };
    let shares = column_shares(mesh, &geo, &columns);
    // Per run of whole patches: first the receivers and their visibilities
    // (cheap), then the integrals. Every receiver's values are its own, so
    // the runs, joined in order, make the row one run makes.
    let run = |counts: &[(u32, u64)]| {
        let mut near_hidden = 0;
        let (jobs, partly) = receivers(mesh, table, &geo, counts, &mut near_hidden);
        let values = integrals(mesh, table, &geo, &shares, &columns, &jobs);
        (jobs, partly, near_hidden, values)
    };
    let m = geo.outlines.len();
    for (jobs, partly, near_hidden, values) in on_patch_runs(table, counts, m, run) {
        row.near_hidden += near_hidden;
        for ((&(j, _), v), &part) in jobs.iter().zip(values.chunks_exact(m)).zip(&partly) {
            if v.iter().any(|&f| f > 0.0) {
                row.ids.push(j);
                row.values.extend_from_slice(v);
                let share = to_share(v.iter().sum());
                row.total += share;
                if part {
                    row.partial += share;
                }
            }
        }
    }
    row
}

/// `run` over `counts` (sorted by element, so each patch's are together)
/// cut into runs of whole patches, one a core where the row is big (about
/// [`PARALLEL_INTEGRALS`] integrals of `columns` columns), the results in
/// order.
fn on_patch_runs<T: Send>(
    table: &ReceiverTable,
    counts: &[(u32, u64)],
    columns: usize,
    run: impl Fn(&[(u32, u64)]) -> T + Sync,
) -> Vec<T> {
    let threads = if counts.len() * columns >= PARALLEL_INTEGRALS {
        crate::parallel::cores().min(8)
    } else {
        1
    };
    if threads <= 1 {
        return vec![run(counts)];
    }
    // Cut near equal shares, each moved on to its patch's end.
    let mut cuts = vec![0];
    for k in 1..threads {
        let mut at = (counts.len() * k / threads).max(*cuts.last().unwrap_or(&0));
        while at > 0
            && at < counts.len()
            && table.patch(counts[at].0) == table.patch(counts[at - 1].0)
        {
            at += 1;
        }
        cuts.push(at);
    }
    cuts.push(counts.len());
    crate::parallel::each(cuts.windows(2), |_, w| run(&counts[w[0]..w[1]]))
}

/// What a hybrid row needs of its shooter patch.
struct ShooterGeometry<'m> {
    patch: &'m crate::mesh::Patch,
    /// One outline per column: each element's, or the whole patch's.
    outlines: Vec<([DVec3; 4], usize)>,
    normal: DVec3,
    origin: DVec3,
    /// The patch's own outline and its corner count.
    outline: ([DVec3; 4], usize),
    /// The farthest corner from the centre.
    radius: f64,
    /// The patch's [`GaussQuad`] where it is a quad (triangles take the
    /// contour integral at every distance).
    gauss: Option<GaussQuad>,
}

impl<'m> ShooterGeometry<'m> {
    fn new(mesh: &'m Mesh, shooter: u32) -> Self {
        let sp = &mesh.patches[shooter as usize];
        let spoly = &mesh.polygons[sp.polygon as usize];
        let own = sp.elements.clone();
        let outlines: Vec<([DVec3; 4], usize)> = if own.len() <= MAX_SHOOTER_COLUMNS {
            own.map(|k| outline(&mesh.elements[k as usize].corners))
                .collect()
        } else {
            vec![outline(&sp.corners)]
        };
        let origin = sp.centre.as_dvec3();
        let (patch_outline, patch_n) = outline(&sp.corners);
        let radius = patch_outline[..patch_n]
            .iter()
            .map(|c| c.distance(origin))
            .fold(0.0f64, f64::max);
        let normal = spoly.normal.as_dvec3();
        Self {
            patch: sp,
            outlines,
            normal,
            origin,
            outline: (patch_outline, patch_n),
            radius,
            gauss: (patch_n == 4).then(|| GaussQuad::new(&patch_outline, normal)),
        }
    }

    /// The patch's own outline.
    fn patch_outline(&self) -> &[DVec3] {
        &self.outline.0[..self.outline.1]
    }
}

/// The receivers a shot reaches, with their visibilities (`(element, V)`),
/// and whether each is partly hidden; adds to `near_hidden` what near
/// receivers lose to occlusion seen from the shooter's centre.
fn receivers(
    mesh: &Mesh,
    table: &ReceiverTable,
    geo: &ShooterGeometry,
    counts: &[(u32, u64)],
    near_hidden: &mut u64,
) -> (Vec<(u32, f64)>, Vec<bool>) {
    let mut jobs: Vec<(u32, f64)> = Vec::with_capacity(counts.len());
    let mut partly = Vec::with_capacity(counts.len());
    let mut k = 0;
    while k < counts.len() {
        // The records of patches a few runs on: the cells' receivers are
        // scattered over the mesh, and each first read was a cache miss
        // (a fifth of this loop's time in the 4096-cube room).
        if let Some(&(ahead, _)) = counts.get(k + PREFETCH_AHEAD) {
            crate::numeric::prefetch(&table.elements[ahead as usize]);
        }
        let patch = table.patch(counts[k].0);
        // A patch's elements are contiguous: compare ids with its range.
        let [first, last] = table.patch_elements[patch as usize];
        let end = k + counts[k..]
            .iter()
            .take_while(|(id, _)| (first..last).contains(id))
            .count();
        let group = &counts[k..end];
        k = end;
        let (pv, pc) = group.iter().fold((0u64, 0u64), |(v, c), &(_, x)| {
            let (a, b) = unpack(x);
            (v + a, c + b)
        });
        if pc == 0 {
            continue;
        }
        let patch_visibility = pv as f64 / pc as f64;
        let mut g = group.iter().peekable();
        for j in first..last {
            let (vis, cov) = match g.peek() {
                Some(&&(id, x)) if id == j => {
                    g.next();
                    unpack(x)
                }
                _ => (0, 0),
            };
            let v = if cov > 0 {
                vis as f64 / cov as f64
            } else {
                patch_visibility
            };
            // The shooter emits from its front only.
            let x = table.elements[j as usize].centre.as_dvec3();
            if geo.normal.dot(x - geo.origin) <= 0.0 {
                continue;
            }
            if cov > vis && x.distance(geo.origin) < NEAR_FIELD * geo.radius {
                let e = &mesh.elements[j as usize];
                let n = mesh.polygons[e.polygon as usize].normal.as_dvec3();
                let f = point_to_polygon(x, n, geo.patch_outline()) * e.area / geo.patch.area;
                *near_hidden += to_share(f * (cov - vis) as f64 / cov as f64);
            }
            if v > 0.0 {
                jobs.push((j, v));
                partly.push(cov > vis && vis > 0);
            }
        }
    }
    (jobs, partly)
}

/// How many receivers ahead the form-factor loops ask for the records they
/// will read (see [`receivers`]).
const PREFETCH_AHEAD: usize = 8;

/// Each column's share of a far receiver's one integral over the whole
/// patch: by element area (which any spread then sums back to, since the
/// weights average to 1 over the area), 0 outside `columns`.
fn column_shares(mesh: &Mesh, geo: &ShooterGeometry, columns: &std::ops::Range<usize>) -> Vec<f64> {
    let sp = geo.patch;
    if geo.outlines.len() > 1 {
        sp.elements
            .clone()
            .enumerate()
            .map(|(k, e)| {
                if columns.contains(&k) {
                    mesh.elements[e as usize].area / sp.area
                } else {
                    0.0
                }
            })
            .collect()
    } else {
        vec![if columns.contains(&0) { 1.0 } else { 0.0 }]
    }
}

/// The form factors of `jobs` (receiver, visibility), one per column, in
/// order. Where the spread over the shooter's elements matters (receivers
/// nearer than NEAR_FIELD shooter radii) one integral per column; farther
/// ones one integral over the whole patch, shared out by `shares`.
fn integrals(
    mesh: &Mesh,
    table: &ReceiverTable,
    geo: &ShooterGeometry,
    shares: &[f64],
    columns: &std::ops::Range<usize>,
    jobs: &[(u32, f64)],
) -> Vec<f64> {
    let outlines = &geo.outlines;
    let mut values = Vec::with_capacity(jobs.len() * outlines.len());
    let mut column = vec![0.0; outlines.len()];
    for (i, &(j, v)) in jobs.iter().enumerate() {
        if let Some(&(ahead, _)) = jobs.get(i + PREFETCH_AHEAD) {
            crate::numeric::prefetch(&table.elements[ahead as usize]);
        }
        let r = &table.elements[j as usize];
        let x = r.centre.as_dvec3();
        let normal = table.normals[r.polygon as usize].as_dvec3();
        let scale = v * r.area / geo.patch.area;
        let reach = geo.radius.max(r.radius);
        let distance = x.distance(geo.origin);
        if distance > NEAR_FIELD * reach {
            // Far: one integral over the whole patch, at the element's
            // centre; farther still, the Gauss rule's (a fifth of the
            // contour integral's cost, within 1e-4 of A / (pi d^2)).
            let gauss = geo
                .gauss
                .as_ref()
                .filter(|_| distance > GAUSS_FAR * geo.radius)
                .and_then(|g| g.form_factor(x, normal));
            let f =
                scale * gauss.unwrap_or_else(|| point_to_polygon(x, normal, geo.patch_outline()));
            values.extend(shares.iter().map(|a| f * a));
        } else {
            // Near: per shooter element, averaged over four points of the
            // receiver (the midpoint rule alone is off where the
            // integrand bends within the element).
            column.iter_mut().for_each(|c| *c = 0.0);
            for y in sub_points(&mesh.elements[j as usize]) {
                for (k, (c, (o, n))) in column.iter_mut().zip(outlines).enumerate() {
                    if columns.contains(&k) {
                        *c += point_to_polygon(y, normal, &o[..*n]);
                    }
                }
            }
            values.extend(column.iter().map(|c| scale * c / 4.0));
        }
    }
    values
}

/// Fixed-point scale of the form factors a split decision sums: per
/// receiver rounded, so sums are exact and ranks agree bit for bit.
pub const SHARE_ONE: f64 = (1u64 << 40) as f64;

fn to_share(f: f64) -> u64 {
    // `numeric::round_u64` of the clamped value, without its range tests:
    // in [0, 2^40] (NaN: 0, as there) a signed conversion is exact and one
    // instruction, and no branch is left for the per-column sums.
    let x = f.clamp(0.0, 1.0) * SHARE_ONE;
    let t = x as i64;
    (t + i64::from(x - t as f64 >= 0.5)) as u64
}

/// A shot is split when the near receivers lose more than this share of the
/// shooter's light to occlusion seen from its centre.
pub const SPLIT_SHARE: f64 = 0.02;

/// Whether a shot whose rows (over all ranks) sum to `near_hidden` and
/// `total` needs one hemisphere per group of shooter elements.
pub fn needs_split(near_hidden: u64, total: u64) -> bool {
    near_hidden as f64 > SPLIT_SHARE * (near_hidden + total) as f64
}

/// Whether element `j` is a near receiver of shooter patch `shooter`: its
/// centre within [`NEAR_FIELD`] times the distance from the patch's centre
/// to its farthest corner (the receivers [`Row::near_hidden`] counts).
/// Returns the test and that distance.
pub fn near_receivers(mesh: &Mesh, shooter: u32) -> (impl Fn(u32) -> bool + '_, f64) {
    let geo = ShooterGeometry::new(mesh, shooter);
    let (origin, near) = (geo.origin, NEAR_FIELD * geo.radius);
    let test = move |j: u32| {
        element_centre(&mesh.elements[j as usize])
            .as_dvec3()
            .distance(origin)
            < near
    };
    (test, near)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauss_rule_is_within_its_bound_of_the_contour() {
        // Random planar quads (not parallelograms), receivers at
        // GAUSS_FAR to 3 GAUSS_FAR radii in any direction in front, facing
        // any way that keeps the quad in front: the rule within 1e-4 of
        // A / (pi d^2) of the exact contour integral.
        let mut rng = crate::rng::Rng(0x2545_f491_4f6c_dd1d);
        let mut uniform = move || rng.unit();
        let (mut cases, mut worst) = (0, 0.0f64);
        while cases < 20_000 {
            let (a, b) = (0.3 + 0.7 * uniform(), 0.3 + 0.7 * uniform());
            let quad = [(-a, -b), (a, -b), (a, b), (-a, b)].map(|(x, y)| {
                let (jx, jy) = (0.4 * (uniform() - 0.5), 0.4 * (uniform() - 0.5));
                DVec3::new(x + jx, y + jy, 0.0)
            });
            let n = DVec3::Z;
            let radius = quad.iter().map(|p| p.length()).fold(0.0, f64::max);
            let v = |u: &mut dyn FnMut() -> f64| DVec3::new(u() - 0.5, u() - 0.5, u() - 0.5);
            let dir = (v(&mut uniform) + DVec3::new(0.0, 0.0, 0.55)).normalize();
            let x = dir * GAUSS_FAR * radius * (1.0 + 2.0 * uniform()) + DVec3::new(0.0, 0.0, 1e-3);
            if x.z <= 0.0 {
                continue;
            }
            let mut m = v(&mut uniform).normalize();
            if m.dot(-x) < 0.0 {
                m = -m;
            }
            let Some(f) = GaussQuad::new(&quad, n).form_factor(x, m) else {
                continue;
            };
            let exact = point_to_polygon(x, m, &quad);
            let area = 0.5 * (quad[2] - quad[0]).cross(quad[3] - quad[1]).length();
            let bound = area / (std::f64::consts::PI * x.length_squared());
            worst = worst.max((f - exact).abs() / bound);
            cases += 1;
        }
        assert!(worst < 1e-4, "worst error {worst} of A / (pi d^2)");
    }

    #[test]
    fn the_edges_side_by_side_are_the_edges_one_by_one() {
        // The AVX2 edge terms against the scalar ones, bit for bit: quads
        // near and far, seen from points on their corners and edges too.
        let mut rng = crate::rng::Rng(0x853c_49e6_748f_ea9b);
        let mut uniform = move || rng.unit();
        let mut cases = 0;
        for k in 0..20_000usize {
            let scale = 10f64.powi(k as i32 % 7 - 3);
            let mut v = || DVec3::new(uniform() - 0.5, uniform() - 0.5, uniform() + 0.1) * scale;
            let mut r = [v(), v(), v(), v()];
            if k % 5 == 0 {
                r[k % 4] = DVec3::ZERO;
            }
            if k % 7 == 0 {
                r[(k + 1) % 4] = r[k % 4];
            }
            let n = DVec3::new(uniform() - 0.5, uniform() - 0.5, 1.0).normalize();
            let want = [0, 1, 2, 3].map(|e| edge_term(r[e], r[(e + 1) % 4], n));
            let got = quad_edge_terms(&r, n);
            for e in 0..4 {
                assert!(
                    got[e].to_bits() == want[e].to_bits() || (got[e].is_nan() && want[e].is_nan()),
                    "case {k} edge {e}: {} against {}",
                    got[e],
                    want[e]
                );
            }
            cases += 1;
        }
        assert_eq!(cases, 20_000);
    }

    #[test]
    fn clipped_polygons_sum_their_edges_side_by_side_as_one_by_one() {
        // Triangles and quads with corners behind the receiver (some a
        // rounding behind, as where a face meets the floor): the form
        // factor's bits are the scalar edge sum's over the clipped outline.
        let mut rng = crate::rng::Rng(0x9e37_79b9_7f4a_7c15);
        let mut uniform = move || rng.unit();
        for k in 0..20_000usize {
            let count = 3 + k % 2;
            let mut poly = [DVec3::ZERO; 6];
            for p in &mut poly[..count] {
                *p = DVec3::new(uniform() - 0.5, uniform() - 0.5, uniform() - 0.3);
            }
            if k % 3 == 0 {
                poly[k % count].z = -1e-17;
            }
            let (x, n) = (DVec3::ZERO, DVec3::Z);
            let mut clipped = Vec::new();
            for e in 0..count {
                let (a, b) = (poly[e] - x, poly[(e + 1) % count] - x);
                let (da, db) = (n.dot(a), n.dot(b));
                if da >= 0.0 {
                    clipped.push(a);
                }
                if (da >= 0.0) != (db >= 0.0) {
                    clipped.push(a + (b - a) * (da / (da - db)));
                }
            }
            let mut sum = 0.0;
            for e in 0..clipped.len() {
                sum += edge_term(clipped[e], clipped[(e + 1) % clipped.len()], n);
            }
            let want = (sum / (2.0 * std::f64::consts::PI)).abs();
            let got = point_to_polygon(x, n, &poly[..count]);
            assert_eq!(
                got.to_bits(),
                want.to_bits(),
                "case {k}: {got} against {want}"
            );
        }
    }

    #[test]
    fn shares_round_as_the_general_rounding_does() {
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut values = vec![
            0.0,
            -0.0,
            1.0,
            -1.0,
            2.0,
            f64::NAN,
            f64::INFINITY,
            0.5 / SHARE_ONE,
        ];
        values.extend((0..100_000).map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 1.2 - 0.1
        }));
        // Values whose fraction is a half exactly, at several magnitudes.
        values.extend((0..40).map(|k| (2f64.powi(k) + 0.5) / SHARE_ONE));
        for f in values {
            let general = crate::numeric::round_u64(f.clamp(0.0, 1.0) * SHARE_ONE);
            assert_eq!(to_share(f), general, "{f}");
        }
    }

    fn square(z: f64, half: f64) -> Vec<DVec3> {
        vec![
            DVec3::new(-half, -half, z),
            DVec3::new(half, -half, z),
            DVec3::new(half, half, z),
            DVec3::new(-half, half, z),
        ]
    }

    #[test]
    fn each_shooter_element_shoots_its_own_colour() {
        // Two shooter elements, one red and one blue: a receiver that sees
        // only the first gets red only, whatever the patch's mean colour.
        let row = Row {
            columns: 2,
            ids: vec![4, 9],
            values: vec![0.3, 0.0, 0.1, 0.2],
            ..Row::default()
        };
        let region = ShotRegion {
            shoot: [0.5, 0.0, 0.5],
            elements: vec![[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            ..ShotRegion::default()
        };
        let mut out = Vec::new();
        row.combine(&region, &mut out);
        assert_eq!(out.len(), 2);
        assert_eq!((out[0].element, out[0].form_factor), (4, 0.3));
        assert_eq!(out[0].radiosity, [0.3, 0.0, 0.0]);
        assert_eq!(out[1].radiosity, [0.1, 0.0, 0.2]);
        // Uniform: F times the patch's shot radiosity.
        let uniform = ShotRegion {
            shoot: [2.0, 1.0, 0.0],
            ..ShotRegion::default()
        };
        row.combine(&uniform, &mut out);
        assert!((out[1].radiosity[0] - 0.6).abs() < 1e-12);
        assert!((out[1].radiosity[1] - 0.3).abs() < 1e-12);
        assert_eq!(out[1].radiosity[2], 0.0);
    }

    #[test]
    fn a_row_keeps_the_receivers_asked_for_with_their_columns() {
        let mut row = Row {
            columns: 2,
            ids: vec![1, 4, 9],
            values: vec![0.1, 0.2, 0.3, 0.4, 0.5, 0.6],
            total: 7,
            ..Row::default()
        };
        row.retain(|j| j != 4);
        assert_eq!(row.ids, vec![1, 9]);
        assert_eq!(row.values, vec![0.1, 0.2, 0.5, 0.6]);
        assert_eq!(row.total, 7, "the decision statistics stay");
    }

    #[test]
    fn centred_square_matches_the_closed_form() {
        // DESIGN.md section 5: a 2 x 2 square at height 1, F = 0.554126.
        let f = point_to_polygon(DVec3::ZERO, DVec3::Z, &square(1.0, 1.0));
        assert!((f - 0.554126).abs() < 1e-6, "{f}");
        // Winding does not matter.
        let mut rev = square(1.0, 1.0);
        rev.reverse();
        let g = point_to_polygon(DVec3::ZERO, DVec3::Z, &rev);
        assert!((f - g).abs() < 1e-15);
    }

    #[test]
    fn behind_the_receiver_is_clipped() {
        assert_eq!(
            point_to_polygon(DVec3::ZERO, DVec3::Z, &square(-1.0, 1.0)),
            0.0
        );
        // Half of a vertical square straddling the tangent plane: the upper half only.
        let wall = vec![
            DVec3::new(1.0, -0.5, -0.5),
            DVec3::new(1.0, 0.5, -0.5),
            DVec3::new(1.0, 0.5, 0.5),
            DVec3::new(1.0, -0.5, 0.5),
        ];
        let upper = vec![
            DVec3::new(1.0, -0.5, 0.0),
            DVec3::new(1.0, 0.5, 0.0),
            DVec3::new(1.0, 0.5, 0.5),
            DVec3::new(1.0, -0.5, 0.5),
        ];
        let (a, b) = (
            point_to_polygon(DVec3::ZERO, DVec3::Z, &wall),
            point_to_polygon(DVec3::ZERO, DVec3::Z, &upper),
        );
        assert!((a - b).abs() < 1e-12 && a > 0.0, "{a} {b}");
    }

    #[test]
    fn an_infinite_plane_tends_to_one() {
        let f = point_to_polygon(DVec3::ZERO, DVec3::Z, &square(1.0, 1e5));
        assert!((f - 1.0).abs() < 1e-4, "{f}");
    }
}
