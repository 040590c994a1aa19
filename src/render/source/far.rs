//! The far receivers of a hybrid shot: patches too small for the
//! hemisphere's cells, which get their visibility by ray, and which
//! patches the cells saw. Part of [`GpuFormFactors`] (its fields are this
//! module's parent's).

use super::GpuFormFactors;
use crate::formfactor;
use crate::mesh::Mesh;
use crate::parallel;
use std::time::Instant;

/// Patches that subtend less than this many of the largest hemisphere cells
/// and that no cell saw get their visibility by ray (see
/// `GpuFormFactors::add_far_receivers`).
pub const FAR_CELLS: f32 = 4.0;

/// Far receivers' scans of at least this many patches use every core, in
/// runs of [`FAR_RUN`] patches (see `on_every_core`).
const PARALLEL_FAR: usize = 16_384;
const FAR_RUN: usize = 4096;

/// Clear far receivers of at least this many patches get their element
/// rays on every core, in runs of [`CLEAR_RUN`] (see `on_every_core`).
const PARALLEL_CLEAR: usize = 1024;
const CLEAR_RUN: usize = 256;

/// One of this rank's patches as the far receivers' scan reads it: every
/// shot tests every patch, and reading these from the patches, polygons
/// and elements was a cache miss apiece (most of the scan's time in big
/// scenes).
#[derive(Clone, Copy)]
pub(super) struct FarPatch {
    centre: glam::Vec3,
    area: f32,
    normal: glam::Vec3,
    patch: u32,
    /// Its polygon and its elements (`first..end`): a candidate's ray
    /// read them from its patch, a cache miss that was a third of the
    /// scan's time on one core.
    polygon: u32,
    elements: [u32; 2],
}

impl FarPatch {
    /// Rank `rank`'s patches of `ranks`, in increasing order.
    pub(super) fn owned(mesh: &Mesh, rank: usize, ranks: usize) -> Vec<Self> {
        parallel::Owners::new(mesh.patches.len(), ranks)
            .patches(rank, mesh.patches.len())
            .map(|k| {
                let p = &mesh.patches[k];
                Self {
                    centre: p.centre,
                    area: p.area as f32,
                    normal: mesh.polygons[p.polygon as usize].normal,
                    patch: k as u32,
                    polygon: p.polygon,
                    elements: [p.elements.start, p.elements.end],
                }
            })
            .collect()
    }
}

/// What a far receivers' scan needs of the shot: where it stands, which
/// patches it looks at and the largest cell.
#[derive(Clone, Copy)]
struct FarShot {
    shooter: u32,
    centre: glam::Vec3,
    /// The shooter's normal.
    normal: glam::Vec3,
    /// Where rays start: the centre moved off the shooter's plane.
    origin: glam::Vec3,
    /// Only patches whose centres lie within this of `centre` are looked at.
    within: f32,
    /// The solid angle of the largest hemisphere cell (at the horizon).
    cell: f32,
}

impl FarShot {
    /// The scan of the shot of `shooter` from `centre` with cells of `res`.
    fn new(
        mesh: &Mesh,
        shooter: u32,
        centre: glam::Vec3,
        res: crate::hemisphere::Resolution,
        within: f32,
    ) -> Self {
        // The largest cells are at the horizon: dtheta times dphi.
        let cell = (2.0 * std::f32::consts::PI / res.cols as f32)
            * (std::f32::consts::FRAC_PI_2 / res.rows as f32);
        let sp = &mesh.patches[shooter as usize];
        let normal = mesh.polygons[sp.polygon as usize].normal;
        Self {
            shooter,
            centre,
            normal,
            origin: centre + normal * mesh.ray_offset,
            within,
            cell,
        }
    }
}

/// What the hemisphere just drawn saw, by cell (one process drawing the
/// whole hemisphere): a far receiver's ray that the recent occluders do
/// not stop tries next the polygon the cell around it saw. Most such rays
/// are stopped by it: a hidden patch that small lies behind what its cell
/// shows. Only time is at stake (see [`Bvh::occluded_guided`]).
///
/// [`Bvh::occluded_guided`]: crate::raytrace::Bvh::occluded_guided
struct Guide<'a> {
    items: &'a [u32],
    res: crate::hemisphere::Resolution,
    /// The hemisphere's frame (its x, y and z axes).
    axes: [glam::Vec3; 3],
    /// Per element, its polygon's leaf ([`guide_leaves`]).
    leaves: &'a [u32],
}

impl Guide<'_> {
    /// The occluders' leaf holding the polygon the cell holding direction
    /// `d` (from the hemisphere's centre) saw, if any.
    fn leaf(&self, d: glam::Vec3) -> Option<u32> {
        let local = glam::Vec3::from_array(self.axes.map(|a| d.dot(a)));
        let item = *self
            .items
            .get(crate::hemisphere::cell_holding(local, self.res))?;
        self.leaves
            .get(item as usize)
            .copied()
            .filter(|&l| l != u32::MAX)
    }
}

/// Per element of `mesh`, the leaf of its occluders' hierarchy holding the
/// element's polygon (`u32::MAX`: none): a guess at a far receiver's
/// occluder reads one table from the cell's item instead of two (the
/// element's polygon, the polygon's leaf), each a cache miss.
pub(super) fn guide_leaves(mesh: &Mesh) -> Vec<u32> {
    mesh.elements
        .iter()
        .map(|e| mesh.occluders.polygon_leaf(e.polygon).unwrap_or(u32::MAX))
        .collect()
}

/// A far receiver whose centre the shooter's ray reached.
#[derive(Clone, Copy)]
pub(super) struct Clear {
    /// The patch as the scan read it (its elements' rays need its normal,
    /// polygon and elements: a cache miss apiece from the mesh).
    patch: FarPatch,
    /// Whether it subtends at most one cell (its elements then take its
    /// centre's verdict; larger ones cast a ray to each element).
    one_cell: bool,
}

/// The far receivers of `part` whose centre rays are clear, in order:
/// patches in front of the shooter, facing it, that subtend less than
/// [`FAR_CELLS`] of the largest cells, hold an element `keep` accepts and
/// that `seen` (where given) does not mark.
fn centre_rays(
    mesh: &Mesh,
    part: &[FarPatch],
    shot: &FarShot,
    (seen, guide): (Option<&[bool]>, Option<&Guide<'_>>),
    keep: &(impl Fn(u32) -> bool + Sync),
) -> Vec<Clear> {
    let sp = &mesh.patches[shot.shooter as usize];
    let n = shot.normal;
    let mut clear = Vec::new();
    // Most candidates in a cluttered scene are hidden, by the same
    // occluder as the patch before them (see `Bvh::occluded_hinted`).
    let mut hint = [None; 2];
    for fp in part {
        let k = fp.patch as usize;
        if k == shot.shooter as usize || seen.is_some_and(|s| s[k]) {
            continue;
        }
        let d = fp.centre - shot.centre;
        let dist2 = d.length_squared();
        if dist2 > shot.within * shot.within {
            continue;
        }
        let rn = fp.normal;
        let cos_r = -rn.dot(d);
        if n.dot(d) <= 0.0 || cos_r <= 0.0 {
            continue;
        }
        let solid_angle = fp.area * cos_r / (dist2 * dist2.sqrt());
        if solid_angle > FAR_CELLS * shot.cell || !(fp.elements[0]..fp.elements[1]).any(keep) {
            continue;
        }
        // One ray to the patch's centre first: most such patches are
        // hidden, and a patch this small hidden at its centre is taken
        // as hidden whole.
        let to = fp.centre + rn * mesh.ray_offset - shot.origin;
        if !mesh.occluders.occluded_guided(
            shot.origin,
            to,
            0.0,
            1.0,
            [sp.polygon, fp.polygon],
            &mut hint,
            || guide.and_then(|g| g.leaf(d)),
        ) {
            clear.push(Clear {
                patch: *fp,
                one_cell: solid_angle <= shot.cell,
            });
        }
    }
    clear
}

/// `items.partition_point(pred)` found by doubling steps from the start,
/// then halving: the merge of the rays' pairs into the cells' walks both
/// lists forward, and its next cut is mostly a few pairs on (a search
/// over the whole rest was a sixth of the shot's own bookkeeping).
fn gallop<T>(items: &[T], pred: impl Fn(&T) -> bool) -> usize {
    let mut step = 1;
    let mut lo = 0;
    // Invariant: every item before `lo` satisfies `pred`.
    while lo + step <= items.len() && pred(&items[lo + step - 1]) {
        lo += step;
        step *= 2;
    }
    let hi = (lo + step).min(items.len());
    lo + items[lo..hi].partition_point(pred)
}

/// `scan` over `items` on every core, in runs of `run` items joined in
/// order (a ray's hint only saves time, so the verdicts are the same
/// however it is split), or on this thread alone below `parallel` items
/// or on one core (a pinned rank: no thread to start, one hint throughout).
fn on_every_core<T: Sync, U: Clone + Send>(
    items: &[T],
    (parallel, run): (usize, usize),
    scan: impl Fn(&[T]) -> Vec<U> + Sync,
) -> Vec<U> {
    if items.len() < parallel || crate::parallel::cores() <= 1 {
        return scan(items);
    }
    let runs: Vec<&[T]> = items.chunks(run).collect();
    let mut parts = vec![Vec::new(); runs.len()];
    crate::sampling::in_parallel(&mut parts, |k, part| *part = scan(runs[k]));
    parts.concat()
}

/// Whether a whole hemisphere's far receivers can be scanned on a thread
/// of their own while the hemisphere is drawn (see
/// [`GpuFormFactors::far_ahead`]): over [`PARALLEL_FAR`] patches, with a
/// second core to run on.
fn can_scan_ahead(far: &[FarPatch]) -> bool {
    far.len() >= PARALLEL_FAR && parallel::cores() >= 2
}

/// Which way a tier's whole hemispheres find their far receivers: after
/// drawing, on every core, or beside the bounds, which then keep to one
/// core ([`GpuFormFactors::far_ahead`]). Neither wins everywhere: in a
/// room of 4096 cubes the bounds on one core (nearest first, skipping
/// what they already hide) are as fast as on two, and the scan beside
/// them is free; in a classroom they are 1.6 times slower on one, more
/// than the scan saves. So each way's time is measured as the solve goes
/// (the bounds and the far receivers, against the rasteriser's time for
/// the same hemispheres, which neither way changes: shooters differ a
/// hundredfold in what they see), as running means, and the cheaper way
/// taken, the other tried again every [`TRY_OTHER`]-th hemisphere. Only
/// time is at stake: both ways give the same rectangles and verdicts.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct FarWay {
    /// Running means of seconds per hemisphere, inline and ahead: the
    /// bounds and far receivers, and the rasteriser (0: not yet tried).
    mean: [[f64; 2]; 2],
    hemispheres: u64,
}

/// Hemispheres between tries of the way not taken (see [`FarWay`]).
const TRY_OTHER: u64 = 16;

/// The running means' weight of the newest hemisphere (see [`FarWay`]).
const NEWEST: f64 = 0.125;

impl FarWay {
    /// Whether the next hemisphere scans ahead.
    fn ahead(&mut self) -> bool {
        self.hemispheres += 1;
        let [[inline, inline_raster], [ahead, ahead_raster]] = self.mean;
        let better = if ahead_raster == 0.0 {
            true
        } else if inline_raster == 0.0 {
            false
        } else {
            ahead * inline_raster < inline * ahead_raster
        };
        better != (self.hemispheres % TRY_OTHER == 0)
    }

    /// Takes a hemisphere drawn `ahead` or not: `spent` seconds in the
    /// bounds and far receivers, `raster` in the rasteriser.
    fn took(&mut self, ahead: bool, spent: f64, raster: f64) {
        let mean = &mut self.mean[usize::from(ahead)];
        if mean[1] == 0.0 {
            *mean = [spent, raster.max(f64::MIN_POSITIVE)];
        } else {
            mean[0] += NEWEST * (spent - mean[0]);
            mean[1] += NEWEST * (raster - mean[1]);
        }
    }
}

impl GpuFormFactors<'_> {
    /// The whole hemisphere of `shooter` at `centre` drawn (see
    /// [`Self::hemisphere`]), and its far receivers found
    /// ([`Self::add_far_receivers`]). Where the tier's [`FarWay`] says,
    /// another thread casts the far receivers' centre rays while the
    /// bounds are found on one core (whether the cells see a patch is not
    /// known yet, so the patches they will see get rays too: a tenth more
    /// in a cluttered room). Returns the exchange's time.
    pub(super) fn whole_with_far(
        &mut self,
        shooter: u32,
        centre: glam::Vec3,
        tier: usize,
    ) -> Result<std::time::Duration, crate::render::RenderError> {
        let before = (
            self.timings.bounds + self.timings.far,
            self.timings.rasterise,
        );
        let scan = can_scan_ahead(&self.far_patches);
        let ahead = scan && self.tiers[tier].far_way.ahead();
        let (exchange, clear) = if ahead {
            self.far_ahead(shooter, centre, tier)?
        } else {
            (self.hemisphere(shooter, centre, tier, f32::INFINITY)?, None)
        };
        let everything = |_| true;
        self.add_far_receivers((shooter, centre), tier, (f32::INFINITY, everything), clear);
        if scan {
            let spent = self.timings.bounds + self.timings.far - before.0;
            let raster = self.timings.rasterise - before.1;
            let way = &mut self.tiers[tier].far_way;
            way.took(ahead, spent.as_secs_f64(), raster.as_secs_f64());
        }
        Ok(exchange)
    }

    /// The far receivers' scan of the shot of `shooter` from `centre` in
    /// tier `tier`, patches within `within` of it.
    fn far_shot(&self, shooter: u32, centre: glam::Vec3, tier: usize, within: f32) -> FarShot {
        let res = self.tiers[tier].cells.resolution;
        FarShot::new(self.mesh, shooter, centre, res, within)
    }

    /// The whole hemisphere drawn with its bounds on one core while
    /// another casts the far receivers' centre rays; the exchange's time
    /// and the clear patches.
    fn far_ahead(
        &mut self,
        shooter: u32,
        centre: glam::Vec3,
        tier: usize,
    ) -> Result<(std::time::Duration, Option<Vec<Clear>>), crate::render::RenderError> {
        let mesh = self.mesh;
        let shot = self.far_shot(shooter, centre, tier, f32::INFINITY);
        let far = std::mem::take(&mut self.far_patches);
        let patches = &far;
        self.tiers[tier].raster.set_bounds_threads(1);
        let mut scanned = None;
        let (drawn, waiting) = crate::parallel::scope(|s| {
            let (scanned, shot) = (&mut scanned, &shot);
            s.spawn(move |_| {
                let start = Instant::now();
                let clear = centre_rays(mesh, patches, shot, (None, None), &|_| true);
                *scanned = Some((clear, start.elapsed()));
            });
            let drawn = self.hemisphere(shooter, centre, tier, f32::INFINITY);
            // The scope ends when the scan has (a panic in it resumes here).
            (drawn, Instant::now())
        });
        let waited = waiting.elapsed();
        let (clear, spent) = scanned.unwrap_or_default();
        // Waiting for the scan counts as the far receivers' time.
        self.timings.far += waited;
        self.tiers[tier].raster.set_bounds_threads(usize::MAX);
        self.far_patches = far;
        self.timings.far_ahead += spent;
        Ok((drawn?, Some(clear)))
    }

    /// Receivers too small to cover a hemisphere cell from the shooter (the
    /// far end of a corridor): cell centres miss most of them, and a hybrid
    /// row, which takes visibility from the cells, gave them nothing (the
    /// corridor's far end was 30 % too dark). Each of this rank's patches
    /// that no cell covered, in front of the shooter at `centre`, facing it
    /// and subtending less than [`FAR_CELLS`] of the largest cells, gets its
    /// elements' visibility from rays from `centre` (visible: one visible of
    /// one covered cell): one to its centre, and, when that one is clear and
    /// the patch subtends more than one cell, one to each element (a patch
    /// under a cell takes its centre's answer). Only elements `keep` accepts
    /// of patches whose centres lie `within` of `centre` (a split group's
    /// near receivers) are looked at. `ahead`: the centre rays already cast
    /// for this shot, cells unseen or not ([`Self::far_ahead`]; with
    /// `within` infinite and `keep` taking all). Deterministic and per
    /// rank, so the row is the same on any rank count.
    pub(super) fn add_far_receivers(
        &mut self,
        (shooter, centre): (u32, glam::Vec3),
        tier: usize,
        (within, keep): (f32, impl Fn(u32) -> bool + Sync),
        ahead: Option<Vec<Clear>>,
    ) {
        let start = Instant::now();
        let mesh = self.mesh;
        let shot = self.far_shot(shooter, centre, tier, within);
        self.mark_seen();
        let seen = &self.seen;
        // The cells' items cover the whole hemisphere on one process
        // drawing it in one tile.
        let layout = self.tiers[tier].cells.layout;
        let res = self.tiers[tier].cells.resolution;
        let whole = self.comm.size() == 1 && layout.ranks() == 1 && self.items.len() == res.cells();
        let frame = mesh.shooter_frame_at(shooter, centre);
        let guide = whole.then(|| Guide {
            items: &self.items,
            res,
            axes: [frame.tangent, frame.bitangent, frame.normal],
            leaves: &self.guide_leaves,
        });
        let clear = match ahead {
            Some(clear) => clear,
            None => on_every_core(&self.far_patches, (PARALLEL_FAR, FAR_RUN), |part| {
                centre_rays(mesh, part, &shot, (Some(seen), guide.as_ref()), &keep)
            }),
        };
        // The elements the rays see, in patch order: a patch under a cell
        // takes its centre's verdict, a larger one a ray to each element.
        let sp = &mesh.patches[shooter as usize];
        let receivers = &self.receivers;
        let elements = |run: &[Clear]| -> Vec<u32> {
            let mut found = Vec::new();
            for c in run.iter().filter(|c| !seen[c.patch.patch as usize]) {
                let p = &c.patch;
                let skip = [sp.polygon, p.polygon];
                found.extend((p.elements[0]..p.elements[1]).filter(|&j| {
                    let to = receivers.centre(j) + p.normal * mesh.ray_offset - shot.origin;
                    keep(j)
                        && shot.normal.dot(to) > 0.0
                        && (c.one_cell || !mesh.occluders.occluded(shot.origin, to, 0.0, 1.0, skip))
                }));
            }
            found
        };
        let found = on_every_core(&clear, (PARALLEL_CLEAR, CLEAR_RUN), elements);
        if !found.is_empty() {
            // A patch the rays saw takes their verdict alone: the cells
            // it covered (all hidden, or it would have been seen) go, so
            // its elements' visibilities do not depend on whether a
            // hidden polygon was drawn (the occlusion cull) or not. Both
            // lists are sorted by element (the rays' in patch order, a
            // patch's elements a run of their own), so one merge takes
            // the rays' pairs in and their patches' cells' pairs out.
            let old = std::mem::take(&mut self.pairs);
            let mut merged = Vec::with_capacity(old.len() + found.len());
            let (mut at, mut i) = (0, 0);
            while let Some(&first) = found.get(i) {
                let [lo, hi] = self.receivers.elements_of(self.receivers.patch(first));
                let below = at + gallop(&old[at..], |p| p.0 < lo);
                merged.extend_from_slice(&old[at..below]);
                at = below + gallop(&old[below..], |p| p.0 < hi);
                while let Some(&j) = found.get(i).filter(|&&j| j < hi) {
                    merged.push((j, formfactor::VISIBLE_ONE + 1));
                    i += 1;
                }
            }
            merged.extend_from_slice(&old[at..]);
            debug_assert!(merged.windows(2).all(|w| w[0].0 < w[1].0));
            self.pairs = merged;
        }
        self.timings.far += start.elapsed();
    }

    /// The receivers of the last hemisphere with a visible cell (or a far
    /// receiver's ray): the work a hybrid row does per receiver, counted
    /// alike whether hidden polygons were drawn or culled.
    pub(super) fn visible_receivers(&self) -> u64 {
        self.pairs
            .iter()
            .filter(|p| formfactor::unpack(p.1).0 > 0)
            .count() as u64
    }

    /// Marks in `self.seen` the patches the last hemisphere's cells saw (a
    /// visible cell, not only covered ones: whether a hidden patch was drawn
    /// at all depends on the occlusion cull, and must not change its rays).
    fn mark_seen(&mut self) {
        self.seen.iter_mut().for_each(|s| *s = false);
        for &(j, x) in &self.pairs {
            if formfactor::unpack(x).0 > 0 {
                self.seen[self.receivers.patch(j) as usize] = true;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{gallop, FarWay, TRY_OTHER};

    #[test]
    fn the_gallop_finds_the_partition_point() {
        for n in 0..70usize {
            let items: Vec<usize> = (0..n).map(|k| 3 * k).collect();
            for x in 0..3 * n + 3 {
                let want = items.partition_point(|&v| v < x);
                assert_eq!(gallop(&items, |&v| v < x), want, "{x} in {n}");
            }
        }
    }

    #[test]
    fn the_cheaper_way_for_its_drawing_is_taken_and_the_other_tried_again() {
        let mut way = FarWay::default();
        // Both ways are tried first.
        assert!(way.ahead());
        way.took(true, 2.0, 10.0);
        assert!(!way.ahead());
        way.took(false, 3.0, 30.0);
        // Inline cost 0.1 of its drawing, ahead 0.2: inline, but for every
        // TRY_OTHER-th hemisphere. Times are weighed against the drawing,
        // not taken raw (ahead's 2 s is less than inline's 3 s).
        let mut tried = 0;
        for _ in 0..4 * TRY_OTHER {
            if way.ahead() {
                tried += 1;
            }
        }
        assert_eq!(tried, 4);
        // Ahead grows cheaper: it is taken from then on.
        for _ in 0..40 {
            way.took(true, 0.5, 10.0);
        }
        let taken = (0..TRY_OTHER).filter(|_| way.ahead()).count() as u64;
        assert_eq!(taken, TRY_OTHER - 1);
    }
}
