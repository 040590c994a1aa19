//! Exact visibility on the CPU: a bounding volume hierarchy over the scene's
//! polygons (fanned into triangles), answering nearest-hit and any-hit
//! (shadow) queries. The camera image's direct light uses it
//! (`direct`); nothing here knows about radiosity. Pure maths.

use crate::scene::Polygon;
use glam::{BVec4A, Vec3, Vec4};

/// A triangle, stored for the Moller-Trumbore test.
#[derive(Clone, Copy, Debug)]
struct Tri {
    v0: Vec3,
    e1: Vec3,
    e2: Vec3,
    polygon: u32,
}

/// A node of the hierarchy: a leaf holds `count` triangles from `first`; an
/// inner node (count 0) has its children at `first` and `first + 1`.
#[derive(Clone, Copy, Debug)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    first: u32,
    count: u32,
}

/// The nearest surface along a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit or not) direction, in its units.
    pub t: f32,
    /// Index of the scene polygon hit.
    pub polygon: u32,
}

/// Four nodes of the binary hierarchy side by side, one SIMD lane each (a
/// node of the 4-wide hierarchy that rays walk): their boxes by axis, and
/// what each is: a leaf (`LEAF_BIT` | its index in `Bvh::packed`),
/// another wide node (its index), or nothing (`NO_CHILD`).
#[derive(Clone, Copy, Debug)]
struct Wide {
    lo: [Vec4; 3],
    hi: [Vec4; 3],
    child: [u32; 4],
}

/// A binary leaf's (up to four) triangles side by side, one SIMD lane
/// each: the same numbers as their [`Tri`]s.
#[derive(Clone, Copy, Debug)]
struct Packed {
    v0: [Vec4; 3],
    e1: [Vec4; 3],
    e2: [Vec4; 3],
    polygon: [u32; 4],
    /// The binary leaf's box, which a hinted ray tests first (a copy: the
    /// leaf's node was a second cache miss on every guessed leaf).
    lo: Vec3,
    hi: Vec3,
    count: u32,
}

/// How many wide levels above a hinted ray's leaf its second try starts
/// (chosen on cubes-b1's far receivers, where it walks a third fewer wide
/// nodes; a fifth fewer on classroom-c3, a third on the 4096-cube room).
const HINT_LEVELS: usize = 4;

/// How many recent occluders a run of shadow rays keeps as hints (see
/// [`Bvh::occluded_recent`]): rays from one element's points, or to
/// neighbouring patches, meet a handful of occluders.
pub const RECENT_HINTS: usize = 4;

/// The recent occluders' leaves, the latest first ([`Bvh::occluded_recent`]).
pub type Hints = [Option<u32>; RECENT_HINTS];

/// Marks a wide node's child that is a leaf of the binary hierarchy.
const LEAF_BIT: u32 = 1 << 31;

/// An unused lane of a wide node.
const NO_CHILD: u32 = u32::MAX;

/// A bounding volume hierarchy over a scene's polygons.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// The triangles in leaf order while building (then packed; kept only
    /// in unit tests, for the binary reference walk).
    tris: Vec<Tri>,
    /// The same hierarchy collapsed to four children a node, which every
    /// ray walks (empty when the root is a leaf). Its leaves are the binary
    /// ones, so a ray tests the same triangles either way.
    wide: Vec<Wide>,
    /// The binary leaves' triangles packed by four (the wide hierarchy's
    /// leaves: `LEAF_BIT` | an index here).
    packed: Vec<Packed>,
    /// The wide node holding each packed leaf, and each wide node's parent
    /// (`NO_CHILD` for the root): where a hinted walk looks after the hint.
    leaf_up: Vec<u32>,
    wide_up: Vec<u32>,
    /// Where the walks start: wide node 0, or the packed root when the
    /// root is a leaf (`NO_CHILD` when there are no triangles).
    root: u32,
    /// The first packed leaf holding each polygon's triangles (`NO_CHILD`
    /// for a polygon without any): where a guessed occluder is tried
    /// ([`Bvh::occluded_guided`]).
    polygon_leaf: Vec<u32>,
    /// The most entries a walk's stack can hold: three pending siblings a
    /// wide level and the deepest node's four children.
    stack_bound: usize,
}

/// Triangles per leaf, at most.
const LEAF: usize = 4;

/// A walk's stack where [`Bvh::stack_bound`] allows (every scene here; a
/// fresh stack is filled at each walk, and filling 256 entries cost a few
/// per cent of Sponza's light field), and where it does not.
const SHORT_STACK: usize = 64;
const LONG_STACK: usize = 256;

/// Bins per axis of the surface area heuristic's split search.
const SAH_BINS: usize = 16;

/// The empty box (every point extends it).
const NO_BOX: (Vec3, Vec3) = (Vec3::INFINITY, Vec3::NEG_INFINITY);

impl Tri {
    fn centre(&self) -> Vec3 {
        self.v0 + (self.e1 + self.e2) / 3.0
    }
}

impl Bvh {
    /// Builds the hierarchy over `polygons`: binned surface-area-heuristic
    /// splits of the centroids (median splits where they do not spread).
    /// Deterministic.
    pub fn new(polygons: &[Polygon]) -> Self {
        let mut tris = Vec::new();
        for (i, p) in polygons.iter().enumerate() {
            for k in 1..p.vertices.len().saturating_sub(1) {
                let (a, b, c) = (p.vertices[0], p.vertices[k], p.vertices[k + 1]);
                tris.push(Tri {
                    v0: a,
                    e1: b - a,
                    e2: c - a,
                    polygon: i as u32,
                });
            }
        }
        let mut bvh = Bvh {
            nodes: Vec::with_capacity(2 * tris.len() / LEAF + 1),
            tris,
            wide: Vec::new(),
            packed: Vec::new(),
            leaf_up: Vec::new(),
            wide_up: Vec::new(),
            root: NO_CHILD,
            polygon_leaf: Vec::new(),
            stack_bound: 1,
        };
        if !bvh.tris.is_empty() {
            bvh.nodes.push(Node {
                lo: Vec3::ZERO,
                hi: Vec3::ZERO,
                first: 0,
                count: 0,
            });
            bvh.split(0, 0, bvh.tris.len());
            bvh.root = if bvh.nodes[0].count == 0 {
                bvh.widen(0)
            } else {
                bvh.pack(0, NO_CHILD)
            };
            // A wide node comes after its parent.
            let mut levels = vec![0usize; bvh.wide.len()];
            for w in 0..bvh.wide.len() {
                let up = bvh.wide_up[w];
                levels[w] = if up == NO_CHILD {
                    1
                } else {
                    levels[up as usize] + 1
                };
            }
            bvh.stack_bound = 3 * levels.iter().max().copied().unwrap_or(0) + 1;
            bvh.polygon_leaf = vec![NO_CHILD; polygons.len()];
            for (k, leaf) in bvh.packed.iter().enumerate() {
                for &polygon in &leaf.polygon[..leaf.count as usize] {
                    if let Some(first) = bvh.polygon_leaf.get_mut(polygon as usize) {
                        *first = (*first).min(k as u32);
                    }
                }
            }
            // Every walk reads the packed copies; only the tests' binary
            // reference walk reads these (Sponza: 22 MB).
            if !cfg!(test) {
                bvh.tris = Vec::new();
            }
        }
        bvh
    }

    /// Appends the wide node for the binary inner node `at` and, below it,
    /// those of its descendants; returns its index. Its lanes are the
    /// (up to four) descendants left after opening the largest inner one
    /// until there are four: a shadow ray tests their boxes at once.
    fn widen(&mut self, at: usize) -> u32 {
        let node = self.nodes[at];
        let mut kids = vec![node.first as usize, node.first as usize + 1];
        while kids.len() < 4 {
            let area = |k: &usize| {
                let d = (self.nodes[*k].hi - self.nodes[*k].lo).max(Vec3::ZERO);
                d.x * d.y + d.y * d.z + d.z * d.x
            };
            let open = kids
                .iter()
                .enumerate()
                .filter(|(_, &k)| self.nodes[k].count == 0)
                .max_by(|a, b| area(a.1).total_cmp(&area(b.1)))
                .map(|(i, _)| i);
            let Some(i) = open else { break };
            let first = self.nodes[kids[i]].first as usize;
            kids[i] = first;
            kids.insert(i + 1, first + 1);
        }
        let w = self.wide.len();
        self.wide.push(Wide {
            lo: [Vec4::ZERO; 3],
            hi: [Vec4::ZERO; 3],
            child: [NO_CHILD; 4],
        });
        self.wide_up.push(NO_CHILD);
        let mut wide = self.wide[w];
        for (lane, &k) in kids.iter().enumerate() {
            let n = self.nodes[k];
            for axis in 0..3 {
                wide.lo[axis][lane] = n.lo[axis];
                wide.hi[axis][lane] = n.hi[axis];
            }
            wide.child[lane] = if n.count > 0 {
                self.pack(k, w as u32)
            } else {
                let below = self.widen(k);
                self.wide_up[below as usize] = w as u32;
                below
            };
        }
        self.wide[w] = wide;
        w as u32
    }

    /// Packs the binary leaf `at`'s triangles; returns the wide child
    /// naming them.
    fn pack(&mut self, at: usize, up: u32) -> u32 {
        let node = self.nodes[at];
        let mut p = Packed {
            v0: [Vec4::ZERO; 3],
            e1: [Vec4::ZERO; 3],
            e2: [Vec4::ZERO; 3],
            polygon: [u32::MAX; 4],
            lo: node.lo,
            hi: node.hi,
            count: node.count,
        };
        let tris = &self.tris[node.first as usize..(node.first + node.count) as usize];
        for (lane, t) in tris.iter().enumerate() {
            for axis in 0..3 {
                p.v0[axis][lane] = t.v0[axis];
                p.e1[axis][lane] = t.e1[axis];
                p.e2[axis][lane] = t.e2[axis];
            }
            p.polygon[lane] = t.polygon;
        }
        self.packed.push(p);
        self.leaf_up.push(up);
        LEAF_BIT | (self.packed.len() - 1) as u32
    }

    fn bounds(tris: &[Tri]) -> (Vec3, Vec3) {
        tris.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), t| {
                let (b, c) = (t.v0 + t.e1, t.v0 + t.e2);
                (lo.min(t.v0).min(b).min(c), hi.max(t.v0).max(b).max(c))
            },
        )
    }

    /// Makes node `at` cover triangles `start..end`, splitting as needed.
    fn split(&mut self, at: usize, start: usize, end: usize) {
        let (lo, hi) = Self::bounds(&self.tris[start..end]);
        self.nodes[at].lo = lo;
        self.nodes[at].hi = hi;
        if end - start <= LEAF {
            self.nodes[at].first = start as u32;
            self.nodes[at].count = (end - start) as u32;
            return;
        }
        let mid = match self.sah_split(start, end) {
            Some(mid) => mid,
            None => self.median_split(start, end),
        };
        let first = self.nodes.len();
        let blank = Node {
            lo,
            hi,
            first: 0,
            count: 0,
        };
        self.nodes.extend([blank, blank]);
        self.nodes[at].first = first as u32;
        self.nodes[at].count = 0;
        self.split(first, start, mid);
        self.split(first + 1, mid, end);
    }

    /// Sorts `start..end` so that the split with the least surface area
    /// heuristic cost (over [`SAH_BINS`] bins of the centroids along each
    /// axis) puts the left child first; returns where the right one starts,
    /// or `None` when the centroids do not spread (all in one bin).
    /// Deterministic: ties keep the lower axis and bin.
    fn sah_split(&mut self, start: usize, end: usize) -> Option<usize> {
        let tris = &self.tris[start..end];
        let (clo, chi) = tris.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(l, h), t| (l.min(t.centre()), h.max(t.centre())),
        );
        let ext = chi - clo;
        let bin_of = |t: &Tri, axis: usize| {
            let b = (t.centre()[axis] - clo[axis]) / ext[axis] * SAH_BINS as f32;
            (b.max(0.0) as usize).min(SAH_BINS - 1)
        };
        let area = |lo: Vec3, hi: Vec3| {
            let d = (hi - lo).max(Vec3::ZERO);
            d.x * d.y + d.y * d.z + d.z * d.x
        };
        let mut best: Option<(f32, usize, usize)> = None;
        for axis in 0..3 {
            if ext[axis] <= 0.0 || !ext[axis].is_finite() {
                continue;
            }
            let mut boxes = [NO_BOX; SAH_BINS];
            let mut counts = [0usize; SAH_BINS];
            for t in tris {
                let b = bin_of(t, axis);
                let (lo, hi) = Self::bounds(std::slice::from_ref(t));
                boxes[b] = (boxes[b].0.min(lo), boxes[b].1.max(hi));
                counts[b] += 1;
            }
            // Right-hand sweeps: the cost of bins k.. on the right.
            let mut right = [0.0f32; SAH_BINS];
            let ((mut lo, mut hi), mut n) = (NO_BOX, 0);
            for k in (1..SAH_BINS).rev() {
                (lo, hi, n) = (lo.min(boxes[k].0), hi.max(boxes[k].1), n + counts[k]);
                right[k] = if n > 0 { area(lo, hi) * n as f32 } else { 0.0 };
            }
            let ((mut lo, mut hi), mut n) = (NO_BOX, 0);
            for k in 1..SAH_BINS {
                (lo, hi, n) = (
                    lo.min(boxes[k - 1].0),
                    hi.max(boxes[k - 1].1),
                    n + counts[k - 1],
                );
                if n == 0 || n == tris.len() {
                    continue;
                }
                let cost = area(lo, hi) * n as f32 + right[k];
                if best.is_none_or(|(c, _, _)| cost < c) {
                    best = Some((cost, axis, k));
                }
            }
        }
        let (_, axis, k) = best?;
        // Partition in place: bins below k first.
        let tris = &mut self.tris[start..end];
        let (mut a, mut b) = (0, tris.len());
        while a < b {
            if bin_of(&tris[a], axis) < k {
                a += 1;
            } else {
                b -= 1;
                tris.swap(a, b);
            }
        }
        Some(start + a)
    }

    /// Sorts `start..end` about the median centroid along the axis they
    /// spread most on; returns the middle.
    fn median_split(&mut self, start: usize, end: usize) -> usize {
        let (clo, chi) = self.tris[start..end].iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(l, h), t| (l.min(t.centre()), h.max(t.centre())),
        );
        let ext = chi - clo;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        let mid = (start + end) / 2;
        self.tris[start..end].select_nth_unstable_by(mid - start, |a, b| {
            a.centre()[axis].total_cmp(&b.centre()[axis])
        });
        mid
    }

    /// Number of triangles held.
    pub fn triangles(&self) -> usize {
        self.packed.iter().map(|p| p.count as usize).sum()
    }

    /// The nearest hit along `origin + t dir` with `t` in (`t_min`, `t_max`).
    pub fn nearest(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Option<Hit> {
        self.nearest_facing(origin, dir, t_min, t_max, 0.0)
    }

    /// [`Bvh::nearest`], where a back face (the ray meets the side its
    /// polygon's normal points away from) counts as `1 + behind` times
    /// farther than it is: with `behind` > 0 a front face coinciding with a
    /// back face (a wall given as two one-sided faces) wins whatever the
    /// rounding; with `behind` < 0 the back face does.
    ///
    /// The wide walk: children nearest first, four boxes and then a
    /// leaf's four triangles a test, each lane the scalar test's
    /// arithmetic, the reach shrinking as the binary walk's does (triangle
    /// by triangle within a leaf).
    pub fn nearest_facing(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        t_max: f32,
        behind: f32,
    ) -> Option<Hit> {
        slab(self.nodes.first()?, origin, dir.recip(), t_min, t_max)?;
        let mut ray = WideRay::new(origin, dir, t_min, t_max);
        let mut best: Option<(f32, Hit)> = None;
        let mut reach = t_max;
        // Each entry keeps the distance at which the ray enters its box: a
        // box entered beyond the reach now would fail its test again.
        let (mut short, mut long);
        let stack: &mut [(u32, f32)] = if self.stack_bound <= SHORT_STACK {
            short = [(self.root, f32::NEG_INFINITY); SHORT_STACK];
            &mut short
        } else {
            long = [(self.root, f32::NEG_INFINITY); LONG_STACK];
            &mut long
        };
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (at, entry) = stack[top];
            if entry > reach {
                continue;
            }
            ray.t_max = Vec4::splat(reach);
            if at & LEAF_BIT != 0 {
                let leaf = &self.packed[(at & !LEAF_BIT) as usize];
                let (t, mask, back) = ray.hits(leaf);
                for lane in 0..leaf.count as usize {
                    if mask & (1 << lane) == 0 || t[lane] >= reach {
                        continue;
                    }
                    let t = t[lane];
                    let key = if back & (1 << lane) != 0 {
                        t * (1.0 + behind)
                    } else {
                        t
                    };
                    let hit = Hit {
                        t,
                        polygon: leaf.polygon[lane],
                    };
                    if beats((key, hit), best) {
                        best = Some((key, hit));
                        reach = bound(best, key, behind, t_max);
                    }
                }
                continue;
            }
            let wide = &self.wide[at as usize];
            let (passed, near) = ray.entries(wide);
            let mut kids: [(u32, f32); 4] = [(NO_CHILD, 0.0); 4];
            let mut n = 0;
            for (lane, &child) in wide.child.iter().enumerate() {
                if passed & (1 << lane) != 0 && child != NO_CHILD {
                    kids[n] = (child, near[lane]);
                    n += 1;
                }
            }
            // The farthest first on the stack, so the nearest comes off first.
            kids[..n].sort_unstable_by(|a, b| b.1.total_cmp(&a.1));
            for &kid in &kids[..n] {
                if top < stack.len() {
                    stack[top] = kid;
                    top += 1;
                }
            }
        }
        best.map(|(_, h)| h)
    }

    /// Whether anything but the polygons in `skip` lies on the segment
    /// `origin + t dir`, `t` in (`t_min`, `t_max`).
    pub fn occluded(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        t_max: f32,
        skip: [u32; 2],
    ) -> bool {
        self.occluded_hinted(origin, dir, t_min, t_max, skip, &mut None)
    }

    /// [`Bvh::occluded`], trying first the leaf `hint` (the one that
    /// occluded an earlier ray: rays to neighbouring points are mostly
    /// stopped by the same occluder), then the subtree [`HINT_LEVELS`] wide
    /// levels above it (the occluder's neighbours), then the rest, and
    /// leaving in `hint` the leaf that occluded this ray. The answer is
    /// `occluded`'s whatever the hint: a leaf whose box the segment passes
    /// lies inside every ancestor's box, which the segment then passes too
    /// (the box test rounds monotonically), so the full walk would reach
    /// the same triangle; and a subtree found clear is clear in the full
    /// walk too, which skips it.
    pub fn occluded_hinted(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        t_max: f32,
        skip: [u32; 2],
        hint: &mut Option<u32>,
    ) -> bool {
        self.occluded_recent(origin, dir, t_min, t_max, skip, std::slice::from_mut(hint))
    }

    /// [`Bvh::occluded_hinted`] with several hints, the latest first:
    /// every hint's leaf is tried before the subtree above the first, and
    /// the leaf that occluded this ray moves to the front (the others
    /// shifting back, the last dropped). The answer is `occluded`'s
    /// whatever the hints.
    pub fn occluded_recent(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        t_max: f32,
        skip: [u32; 2],
        recent: &mut [Option<u32>],
    ) -> bool {
        self.occluded_guided(origin, dir, t_min, t_max, skip, recent, || None)
    }

    /// The packed leaf a guess at polygon `polygon` names for
    /// [`Bvh::occluded_guided`] (the first holding its triangles), if any.
    pub fn polygon_leaf(&self, polygon: u32) -> Option<u32> {
        self.polygon_leaf
            .get(polygon as usize)
            .copied()
            .filter(|&leaf| leaf != NO_CHILD)
    }

    /// [`Bvh::occluded_recent`], trying next, where the recent occluders
    /// do not block the ray, the leaf `guess` names ([`Bvh::polygon_leaf`]
    /// of a polygon; found only then: the polygon a hemisphere cell beside
    /// the ray saw, which costs a cell lookup), which becomes the latest hint if it blocks
    /// and otherwise anchors the subtree tried before the rest. The answer
    /// is `occluded`'s whatever the guess, as for any hint.
    // The ray, its range and skips, the hints and the guess: all needed.
    #[allow(clippy::too_many_arguments)]
    pub fn occluded_guided(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        t_max: f32,
        skip: [u32; 2],
        recent: &mut [Option<u32>],
        guess: impl FnOnce() -> Option<u32>,
    ) -> bool {
        let inv = dir.recip();
        let ray = WideRay::new(origin, dir, t_min, t_max);
        // A hint names a packed leaf; its box is its binary leaf's.
        for i in 0..recent.len() {
            let Some(leaf) = recent[i].and_then(|h| self.packed.get(h as usize)) else {
                break;
            };
            if slab_box(leaf.lo, leaf.hi, origin, inv, t_min, t_max).is_some()
                && ray.blocked_by(leaf, skip)
            {
                recent[..=i].rotate_right(1);
                return true;
            }
        }
        let Some(root) = self.nodes.first() else {
            return false;
        };
        if slab(root, origin, inv, t_min, t_max).is_none() {
            return false;
        }
        // The guessed leaf, unless a recent hint just failed there.
        let guessed = guess()
            .filter(|&leaf| (leaf as usize) < self.packed.len() && !recent.contains(&Some(leaf)));
        if let Some(k) = guessed {
            let leaf = &self.packed[k as usize];
            if slab_box(leaf.lo, leaf.hi, origin, inv, t_min, t_max).is_some()
                && ray.blocked_by(leaf, skip)
            {
                if !recent.is_empty() {
                    recent.rotate_right(1);
                    recent[0] = Some(k);
                }
                return true;
            }
        }
        let first = guessed.or(recent.first().copied().flatten());
        let mut hint = first;
        let mut clear = NO_CHILD;
        // The first hint's leaf and the wide node holding it (none: the root is that leaf).
        let held = first
            .and_then(|h| Some((h, *self.leaf_up.get(h as usize)?)))
            .filter(|&(_, up)| up != NO_CHILD);
        let mut blocked = false;
        if let Some((leaf, up)) = held {
            let mut at = up;
            for _ in 1..HINT_LEVELS {
                match self.wide_up.get(at as usize) {
                    Some(&parent) if parent != NO_CHILD => at = parent,
                    _ => break,
                }
            }
            // The hint's own leaf was just tested.
            blocked = self.any_hit(&ray, at, LEAF_BIT | leaf, skip, &mut hint);
            clear = at;
        }
        blocked = blocked || self.any_hit(&ray, self.root, clear, skip, &mut hint);
        if blocked && !recent.is_empty() {
            recent.rotate_right(1);
            recent[0] = hint;
        }
        blocked
    }

    /// Whether a triangle below `start` (a wide node, or a packed leaf
    /// with `LEAF_BIT`), outside `clear` (a wide node or a packed leaf,
    /// known clear), blocks the ray: the
    /// wide walk, nearest box first (a shadow ray is mostly stopped near
    /// its start). Each lane's test is `slab`'s, bit for bit, on the same
    /// boxes, so it reaches exactly the leaves the binary walk does. A
    /// blocking leaf becomes the hint.
    fn any_hit(
        &self,
        ray: &WideRay,
        start: u32,
        clear: u32,
        skip: [u32; 2],
        hint: &mut Option<u32>,
    ) -> bool {
        let (mut short, mut long);
        let stack: &mut [u32] = if self.stack_bound <= SHORT_STACK {
            short = [start; SHORT_STACK];
            &mut short
        } else {
            long = [start; LONG_STACK];
            &mut long
        };
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let at = stack[top];
            if at == clear {
                continue;
            }
            if at & LEAF_BIT != 0 {
                let k = at & !LEAF_BIT;
                if ray.blocked_by(&self.packed[k as usize], skip) {
                    *hint = Some(k);
                    return true;
                }
                continue;
            }
            let wide = &self.wide[at as usize];
            let (passed, near) = ray.entries(wide);
            let mut kids = [(NO_CHILD, 0.0f32); 4];
            let mut n = 0;
            for (lane, &child) in wide.child.iter().enumerate() {
                if passed & (1 << lane) != 0 && child != NO_CHILD {
                    kids[n] = (child, near[lane]);
                    n += 1;
                }
            }
            // Pushed farthest first, so the nearest is walked first (at
            // most four: sorted in place, no call).
            for i in 1..n {
                let mut j = i;
                while j > 0 && kids[j - 1].1.total_cmp(&kids[j].1).is_lt() {
                    kids.swap(j - 1, j);
                    j -= 1;
                }
            }
            for &(child, _) in &kids[..n] {
                if top < stack.len() {
                    stack[top] = child;
                    top += 1;
                }
            }
        }
        false
    }

    /// Visits the triangles of every leaf the ray's box test passes, nearest
    /// child first; `visit` returns (stop, the current far limit). (The
    /// binary walk, the tests' reference for the wide one.)
    #[cfg(test)]
    fn walk(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        t_max: f32,
        mut visit: impl FnMut(&Tri, f32) -> (bool, f32),
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let inv = dir.recip();
        let mut far = t_max;
        // Each entry keeps the entry distance its slab test gave when it was
        // pushed (NaN for the root, which had none): if that is still within
        // `far` the test would pass again (its box's exit lay beyond it
        // then), so only an entry `far` has since overtaken, or a NaN, is
        // tested again. That halves the slab tests of a shadow ray, whose
        // `far` never shrinks, and changes no verdict.
        let mut stack = [(0u32, f32::NAN); 64];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (at, entry) = stack[top];
            let node = &self.nodes[at as usize];
            let still_in = entry <= far;
            if !still_in && slab(node, origin, inv, t_min, far).is_none() {
                continue;
            }
            if node.count > 0 {
                let (a, b) = (node.first as usize, (node.first + node.count) as usize);
                for tri in &self.tris[a..b] {
                    let (stop, f) = visit(tri, t_min);
                    far = f;
                    if stop {
                        return;
                    }
                }
                continue;
            }
            let (l, r) = (node.first, node.first + 1);
            let dl = slab(&self.nodes[l as usize], origin, inv, t_min, far);
            let dr = slab(&self.nodes[r as usize], origin, inv, t_min, far);
            // Push the farther child first so the nearer is visited first.
            let order = match (dl, dr) {
                (Some(a), Some(b)) if a <= b => [Some((r, b)), Some((l, a))],
                (Some(a), Some(b)) => [Some((l, a)), Some((r, b))],
                (Some(a), None) => [None, Some((l, a))],
                (None, Some(b)) => [None, Some((r, b))],
                (None, None) => [None, None],
            };
            for child in order.into_iter().flatten() {
                if top < stack.len() {
                    stack[top] = child;
                    top += 1;
                }
            }
        }
    }
}

/// A ray's origin, direction, reciprocal direction and range, one copy a lane.
struct WideRay {
    origin: [Vec4; 3],
    dir: [Vec4; 3],
    inv: [Vec4; 3],
    t_min: Vec4,
    t_max: Vec4,
    /// Whether every component of the direction is non-zero (no axis can
    /// give 0 x inf, so the NaN masks can be left out).
    finite: bool,
}

impl WideRay {
    fn new(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Self {
        let inv = dir.recip();
        Self {
            origin: [0, 1, 2].map(|a| Vec4::splat(origin[a])),
            dir: [0, 1, 2].map(|a| Vec4::splat(dir[a])),
            inv: [0, 1, 2].map(|a| Vec4::splat(inv[a])),
            t_min: Vec4::splat(t_min),
            t_max: Vec4::splat(t_max),
            finite: inv.is_finite(),
        }
    }

    /// Which of `wide`'s four boxes [`slab`] lets the ray through (a bit
    /// mask: the same arithmetic a lane; an axis with a NaN bounds nothing,
    /// the rest are exact minima and maxima, whatever their order), with
    /// the entry distance a lane.
    #[inline(always)]
    fn entries(&self, wide: &Wide) -> (u32, Vec4) {
        let (passed, near) = self.boxes(wide);
        (passed.bitmask(), near)
    }

    /// Which boxes pass, and where the ray enters each.
    #[inline(always)]
    fn boxes(&self, wide: &Wide) -> (BVec4A, Vec4) {
        let (mut near, mut far) = (self.t_min, self.t_max);
        for axis in 0..3 {
            let a = (wide.lo[axis] - self.origin[axis]) * self.inv[axis];
            let b = (wide.hi[axis] - self.origin[axis]) * self.inv[axis];
            let (mut lo, mut hi) = (
                Vec4::select(a.cmplt(b), a, b),
                Vec4::select(a.cmpgt(b), a, b),
            );
            if !self.finite {
                let free = a.is_nan_mask() | b.is_nan_mask();
                lo = Vec4::select(free, Vec4::NEG_INFINITY, lo);
                hi = Vec4::select(free, Vec4::INFINITY, hi);
            }
            near = Vec4::select(lo.cmpgt(near), lo, near);
            far = Vec4::select(hi.cmplt(far), hi, far);
        }
        (near.cmple(far), near)
    }

    /// Whether a triangle of `leaf` not in `skip` lies on the ray within
    /// its range: `intersect` a lane, the same operations in the same
    /// order (glam's `cross` and `dot`), so the same verdicts.
    fn blocked_by(&self, leaf: &Packed, skip: [u32; 2]) -> bool {
        let mut mask = self.hits(leaf).1;
        for (lane, &polygon) in leaf.polygon.iter().enumerate() {
            if lane as u32 >= leaf.count || skip.contains(&polygon) {
                mask &= !(1 << lane);
            }
        }
        mask != 0
    }

    /// `intersect` a lane: the distances, which lanes hit (unused lanes
    /// included: the caller counts them out) and which of those meet a
    /// back face (`dir . (e1 x e2) > 0`, as [`Bvh::nearest_facing`] asks).
    fn hits(&self, leaf: &Packed) -> (Vec4, u32, u32) {
        const WIDE: f32 = 1e-6;
        let cross = |a: [Vec4; 3], b: [Vec4; 3]| {
            [
                a[1] * b[2] - b[1] * a[2],
                a[2] * b[0] - b[2] * a[0],
                a[0] * b[1] - b[0] * a[1],
            ]
        };
        let dot = |a: [Vec4; 3], b: [Vec4; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let p = cross(self.dir, leaf.e2);
        let det = dot(leaf.e1, p);
        let inv = Vec4::ONE / det;
        let s = [0, 1, 2].map(|a| self.origin[a] - leaf.v0[a]);
        let u = dot(s, p) * inv;
        let q = cross(s, leaf.e1);
        let v = dot(self.dir, q) * inv;
        let t = dot(leaf.e2, q) * inv;
        let (low, high) = (Vec4::splat(-WIDE), Vec4::splat(1.0 + WIDE));
        // Each rejection of `intersect` as a mask (NaNs compare false alike).
        let hit = !det.abs().cmplt(Vec4::splat(1e-20))
            & u.cmpge(low)
            & u.cmple(high)
            & !v.cmplt(low)
            & !(u + v).cmpgt(high)
            & t.cmpgt(self.t_min)
            & t.cmplt(self.t_max);
        let back = dot(self.dir, cross(leaf.e1, leaf.e2)).cmpgt(Vec4::ZERO);
        (t, hit.bitmask(), back.bitmask())
    }
}

/// How far a nearest-hit walk still looks once its best key is `far`: past
/// every distance at which a face's key could still tie it (a back face's
/// key is `1 + behind` times its distance, so with `behind` < 0 that is
/// `far / (1 + behind)`, which `1 + 2 |behind|` covers with room for the
/// keys' rounding), and a hair beyond (`intersect` and the box tests take
/// their limit exclusively), so a tie is found whichever face comes first;
/// never beyond `t_max`.
fn bound(best: Option<(f32, Hit)>, far: f32, behind: f32, t_max: f32) -> f32 {
    if best.is_none() {
        return t_max;
    }
    let reach = far * (1.0 + 2.0 * behind.abs());
    // The next float up (f32::next_up needs Rust 1.86).
    let above = if reach.is_finite() && reach > 0.0 {
        f32::from_bits(reach.to_bits() + 1)
    } else {
        reach
    };
    above.min(t_max)
}

/// Whether `hit` (with its key) beats `best`: the nearer key, then, on an
/// exact tie (faces given twice, a ray through a shared edge), the lower
/// polygon and the nearer distance, so the answer does not depend on the
/// order the walk meets them in.
fn beats((key, hit): (f32, Hit), best: Option<(f32, Hit)>) -> bool {
    best.is_none_or(|(k, b)| {
        key < k
            || (key == k && (hit.polygon < b.polygon || (hit.polygon == b.polygon && hit.t < b.t)))
    })
}

/// The entry distance of a ray into a node's box, if it meets it in (t_min, t_max).
fn slab(node: &Node, origin: Vec3, inv: Vec3, t_min: f32, t_max: f32) -> Option<f32> {
    slab_box(node.lo, node.hi, origin, inv, t_min, t_max)
}

/// [`slab`] for the box `lo`..`hi`.
#[inline(always)]
fn slab_box(lo: Vec3, hi: Vec3, origin: Vec3, inv: Vec3, t_min: f32, t_max: f32) -> Option<f32> {
    let a = (lo - origin) * inv;
    let b = (hi - origin) * inv;
    let (mut near, mut far) = (t_min, t_max);
    for axis in 0..3 {
        let (x, y) = (a[axis], b[axis]);
        // 0 x inf: a ray parallel to this axis in a box face's plane, on
        // the box's boundary. The axis bounds nothing, so the test stays
        // conservative and a box passes whenever a box inside it does.
        // (glam's min/max are compare-and-select: a NaN there fell either
        // way by its place and could reject a box a child of which passes.)
        if x.is_nan() || y.is_nan() {
            continue;
        }
        near = near.max(x.min(y));
        far = far.min(x.max(y));
    }
    (near <= far).then_some(near)
}

/// Moller-Trumbore, with the edges widened by a hair so a ray through a
/// shared edge of two triangles of one polygon cannot slip between them.
/// (The scalar test each lane of `WideRay::hits` repeats; the tests'
/// reference walks call it.)
#[cfg(test)]
fn intersect(tri: &Tri, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Option<f32> {
    const WIDE: f32 = 1e-6;
    let p = dir.cross(tri.e2);
    let det = tri.e1.dot(p);
    if det.abs() < 1e-20 {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - tri.v0;
    let u = s.dot(p) * inv;
    if !(-WIDE..=1.0 + WIDE).contains(&u) {
        return None;
    }
    let q = s.cross(tri.e1);
    let v = dir.dot(q) * inv;
    if v < -WIDE || u + v > 1.0 + WIDE {
        return None;
    }
    let t = tri.e2.dot(q) * inv;
    (t > t_min && t < t_max).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad(centre: Vec3, half: f32, normal_z: bool) -> Polygon {
        let (a, b) = if normal_z {
            (Vec3::X, Vec3::Y)
        } else {
            (Vec3::Y, Vec3::X)
        };
        Polygon::square(centre, half, a, b, [0.5; 3], [0.0; 3])
    }

    /// A number in [0, 1).
    fn unit(rng: &mut crate::rng::Rng) -> f32 {
        (rng.next_u64() >> 11) as f32 / (1u64 << 53) as f32
    }

    /// `n` squares: centres with x and y within `box_[0]` / 2 of 0 and z
    /// from `box_[1]` to `box_[1] + box_[2]`, half-sizes from `size[0]` to
    /// `size[0] + size[1]`, the share `facing_z` of them facing +z (the rest
    /// +x).
    fn scattered(
        rng: &mut crate::rng::Rng,
        n: usize,
        box_: [f32; 3],
        size: [f32; 2],
        facing_z: f32,
    ) -> Vec<Polygon> {
        (0..n)
            .map(|_| {
                let [w, z0, dz] = box_;
                let c = Vec3::new(
                    unit(rng) * w - w / 2.0,
                    unit(rng) * w - w / 2.0,
                    z0 + unit(rng) * dz,
                );
                quad(c, size[0] + unit(rng) * size[1], unit(rng) < facing_z)
            })
            .collect()
    }

    #[test]
    fn nearest_hit_matches_a_brute_force_scan() {
        // A stack of squares at random heights and offsets: the hierarchy's
        // nearest hit is the one a scan of every polygon finds.
        let mut rng = crate::rng::Rng(7);
        let polys = scattered(&mut rng, 200, [4.0, 0.0, 10.0], [0.2, 0.5], 0.5);
        let mut unit = || unit(&mut rng);
        let bvh = Bvh::new(&polys);
        assert_eq!(bvh.triangles(), 400);
        for _ in 0..2000 {
            let o = Vec3::new(unit() * 4.0 - 2.0, unit() * 4.0 - 2.0, -1.0);
            let d = Vec3::new(unit() - 0.5, unit() - 0.5, 2.0);
            let got = bvh.nearest(o, d, 0.0, f32::INFINITY);
            let single = |i: usize| Bvh::new(std::slice::from_ref(&polys[i]));
            let want = (0..polys.len())
                .filter_map(|i| {
                    single(i)
                        .nearest(o, d, 0.0, f32::INFINITY)
                        .map(|h| (h.t, i))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            assert_eq!(got.map(|h| h.polygon as usize), want.map(|w| w.1));
            let far = want.map_or(1e3, |w| w.0 * 0.999);
            assert!(!bvh.occluded(o, d, 0.0, far, [u32::MAX; 2]));
            if let Some((t, _)) = want {
                assert!(bvh.occluded(o, d, 0.0, t * 1.001, [u32::MAX; 2]));
            }
        }
    }

    /// Squares scattered over a slab (seeded by `seed`) and 4000 segments
    /// (origin, end, polygons skipped) from near the origin to
    /// neighbouring points of a grid above, in order: a hint or a guess
    /// is often right and sometimes stale.
    fn neighbouring_segments(seed: u64) -> (Bvh, Vec<(Vec3, Vec3, [u32; 2])>) {
        let mut rng = crate::rng::Rng(seed);
        let polys = scattered(&mut rng, 300, [8.0, 1.0, 4.0], [0.1, 0.4], 0.7);
        let mut unit = || unit(&mut rng);
        let segments = (0..4000)
            .map(|i| {
                let o = Vec3::new(unit() * 0.2, unit() * 0.2, 0.0);
                let to = Vec3::new(
                    (i % 64) as f32 * 0.12 - 3.8 + unit() * 0.05,
                    (i / 64) as f32 * 0.12 - 3.8,
                    6.0,
                );
                (o, to, [(i % 300) as u32, u32::MAX])
            })
            .collect();
        (Bvh::new(&polys), segments)
    }

    #[test]
    fn a_hinted_shadow_ray_answers_as_the_full_walk_does() {
        // Squares scattered over a slab; segments to neighbouring points, in
        // order, so the hint (its leaf, then the subtree above it) is often
        // right and sometimes stale: the verdict is the plain walk's and
        // the binary walk's every time, and the hint does the work.
        let (bvh, segments) = neighbouring_segments(11);
        let mut hint = None;
        let mut recent = [None; RECENT_HINTS];
        let (mut hidden, mut hinted, mut by_recent) = (0, 0, 0);
        for (i, &(o, to, skip)) in segments.iter().enumerate() {
            let want = bvh.occluded(o, to - o, 0.0, 1.0, skip);
            // The binary walk, the wide walks' reference.
            assert_eq!(
                occluded_binary(&bvh, o, to - o, 1.0, skip),
                want,
                "segment {i}"
            );
            let before = hint;
            let got = bvh.occluded_hinted(o, to - o, 0.0, 1.0, skip, &mut hint);
            assert_eq!(got, want, "segment {i}");
            hidden += want as u32;
            hinted += (want && hint == before && before.is_some()) as u32;
            // Several recent leaves: the same verdict, the occluder first.
            let was = recent;
            let got = bvh.occluded_recent(o, to - o, 0.0, 1.0, skip, &mut recent);
            assert_eq!(got, want, "segment {i}, recent hints");
            if want {
                let leaf = recent[0].expect("an occluder's leaf");
                assert!(bvh.packed[leaf as usize]
                    .polygon
                    .iter()
                    .any(|&p| !skip.contains(&p)));
                by_recent += was.contains(&Some(leaf)) as u32;
                // The others are the earlier hints in order, less the one moved up.
                let rest: Vec<_> = was.iter().filter(|&&h| h != Some(leaf)).collect();
                assert!(
                    recent[1..].iter().zip(rest).all(|(a, b)| a == b),
                    "segment {i}"
                );
            } else {
                assert_eq!(recent, was, "segment {i}: a clear ray keeps the hints");
            }
        }
        assert!(hidden > 1000, "the scene hides {hidden} of 4000 segments");
        assert!(
            hinted > hidden / 4,
            "the hint answered {hinted} of {hidden}"
        );
        assert!(
            by_recent > hinted,
            "the recent leaves answered {by_recent} of {hidden}, the last alone {hinted}"
        );
    }

    #[test]
    fn a_guessed_occluder_changes_no_verdict_and_answers_when_right() {
        // The segments of the hinted test, each with a guess: none, a
        // polygon picked at random (often wrong, sometimes no polygon at
        // all), or the nearest polygon the segment meets (right unless
        // skipped). The verdict is the plain walk's every time; a right
        // guess answers where the hint could not.
        let (bvh, segments) = neighbouring_segments(12);
        let mut hint = None;
        let (mut hidden, mut by_guess) = (0, 0);
        for (i, &(o, to, skip)) in segments.iter().enumerate() {
            let want = bvh.occluded(o, to - o, 0.0, 1.0, skip);
            let nearest = bvh.nearest(o, to - o, 0.0, 1.0).map(|h| h.polygon);
            let guess = match i % 3 {
                0 => None,
                1 => Some((i * 7919 % 400) as u32),
                _ => nearest,
            };
            let before = hint;
            let mut asked = false;
            let got = bvh.occluded_guided(
                o,
                to - o,
                0.0,
                1.0,
                skip,
                std::slice::from_mut(&mut hint),
                || {
                    asked = true;
                    guess.and_then(|polygon| bvh.polygon_leaf(polygon))
                },
            );
            assert_eq!(got, want, "segment {i}, guess {guess:?}");
            hidden += want as u32;
            if want && asked && hint != before && guess == nearest && guess.is_some() {
                // The guess's leaf became the hint.
                let leaf = hint.expect("the occluder's leaf");
                by_guess += bvh.packed[leaf as usize]
                    .polygon
                    .contains(&guess.unwrap_or(u32::MAX)) as u32;
            }
        }
        assert!(hidden > 1000, "the scene hides {hidden} of 4000 segments");
        assert!(by_guess > 100, "right guesses answered {by_guess} segments");
    }

    /// [`Bvh::nearest_facing`] by the binary walk (what nearest-hit rays
    /// took before the wide one), from 0.
    fn nearest_binary(bvh: &Bvh, o: Vec3, d: Vec3, t_max: f32, behind: f32) -> Option<Hit> {
        let mut best: Option<(f32, Hit)> = None;
        let mut far = t_max;
        bvh.walk(o, d, 0.0, t_max, |tri, t_min| {
            let reach = bound(best, far, behind, t_max);
            if let Some(t) = intersect(tri, o, d, t_min, reach) {
                let back = d.dot(tri.e1.cross(tri.e2)) > 0.0;
                let key = if back { t * (1.0 + behind) } else { t };
                let hit = Hit {
                    t,
                    polygon: tri.polygon,
                };
                if beats((key, hit), best) {
                    best = Some((key, hit));
                    far = key;
                }
            }
            (false, bound(best, far, behind, t_max))
        });
        best.map(|(_, h)| h)
    }

    /// The binary walk's verdict (what shadow rays took before the wide one).
    fn occluded_binary(bvh: &Bvh, o: Vec3, d: Vec3, t_max: f32, skip: [u32; 2]) -> bool {
        let mut hit = false;
        bvh.walk(o, d, 0.0, t_max, |tri, _| {
            hit |= !skip.contains(&tri.polygon) && intersect(tri, o, d, 0.0, t_max).is_some();
            (hit, t_max)
        });
        hit
    }

    /// Unit squares on an `n` x `n` grid at heights i j mod `heights`,
    /// facing z, x and y in turn (edges on the planes [`grid_ray`]'s rays
    /// start in), each given twice and every third once more facing the
    /// other way (exact ties, facing keys), then scattered ones.
    fn grid_scene(rng: &mut crate::rng::Rng, n: usize, heights: usize) -> Vec<Polygon> {
        let mut polys = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let c = Vec3::new(i as f32, j as f32, (i * j % heights) as f32);
                let (a, b) =
                    [(Vec3::X, Vec3::Y), (Vec3::Y, Vec3::Z), (Vec3::Z, Vec3::X)][(i + j) % 3];
                polys.push(Polygon::square(c, 0.5, a, b, [0.5; 3], [0.0; 3]));
                polys.push(Polygon::square(c, 0.5, a, b, [0.5; 3], [0.0; 3]));
                if (i * 7 + j) % 3 == 0 {
                    polys.push(Polygon::square(c, 0.5, b, a, [0.5; 3], [0.0; 3]));
                }
            }
        }
        let w = n as f32;
        polys.extend(scattered(
            rng,
            250,
            [w, 0.0, heights as f32],
            [0.1, 0.4],
            0.5,
        ));
        polys
    }

    /// Ray `k` over a [`grid_scene`]: every other one from a grid point or
    /// a half-way point (in box faces' planes) along an axis or a grid
    /// diagonal (zero components: the box test's NaN cases), the rest from
    /// anywhere in any direction.
    fn grid_ray(
        k: usize,
        n: usize,
        heights: usize,
        unit: &mut impl FnMut() -> f32,
    ) -> (Vec3, Vec3) {
        let w = n as f32;
        if k % 2 == 0 {
            let offset = [0.0, 0.5, -0.5, 0.25][k % 4];
            let mut grid = || (unit() * w).floor() + offset;
            let (x, y) = (grid(), grid());
            let z = (unit() * heights as f32).floor() + [0.0, 0.5, -0.5][k % 3];
            let axes = [
                Vec3::X,
                Vec3::Y,
                Vec3::Z,
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(0.0, -1.0, 1.0),
            ];
            let sign = if unit() < 0.5 { -1.0 } else { 1.0 };
            let d = axes[k / 2 % axes.len()] * sign * (1.0 + unit() * 10.0);
            (Vec3::new(x, y, z), d)
        } else {
            let o = Vec3::new(
                unit() * (w + 2.0) - 1.0,
                unit() * (w + 2.0) - 1.0,
                unit() * (heights as f32 + 2.0) - 0.5,
            );
            (
                o,
                Vec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5) * 20.0,
            )
        }
    }

    /// Over a [`grid_scene`] of `n` x `n` squares, 20 000 [`grid_ray`]s:
    /// the wide walk's shadow verdict and nearest hit (every `behind`) are
    /// the binary walk's. Returns how many were hidden and how many hit.
    fn compare_walks(seed: u64, n: usize, heights: usize) -> (u32, u32) {
        let mut rng = crate::rng::Rng(seed);
        let polys = grid_scene(&mut rng, n, heights);
        let bvh = Bvh::new(&polys);
        assert!(!bvh.wide.is_empty());
        let mut unit = || unit(&mut rng);
        let (mut hidden, mut hits) = (0, 0);
        for k in 0..20_000 {
            let (o, d) = grid_ray(k, n, heights, &mut unit);
            let t_max = if k % 3 == 0 {
                f32::INFINITY
            } else {
                unit() * 2.0
            };
            let skip = [(k % polys.len()) as u32, u32::MAX];
            let want = occluded_binary(&bvh, o, d, t_max, skip);
            let got = bvh.occluded(o, d, 0.0, t_max, skip);
            assert_eq!(got, want, "shadow ray {k}: {o} {d}");
            hidden += want as u32;
            let behind = [0.0, 1e-5, -1e-5][k % 3];
            let reach = if k % 5 == 0 { 2.0 } else { f32::INFINITY };
            let want = nearest_binary(&bvh, o, d, reach, behind);
            let got = bvh.nearest_facing(o, d, 0.0, reach, behind);
            assert_eq!(got, want, "nearest, ray {k}: {o} {d}");
            hits += want.is_some() as u32;
        }
        (hidden, hits)
    }

    #[test]
    fn the_reach_holds_every_face_that_ties_the_best_key() {
        // A face at distance t ties a best key k when its own key (t, or
        // t (1 + behind) for a back face), rounded, equals k: the walks must
        // still test it, so t must lie inside the reach after k.
        let mut rng = crate::rng::Rng(21);
        let none = Hit { t: 0.0, polygon: 0 };
        for k in 0..200_000 {
            let t = 1e-3 + unit(&mut rng) * 100.0;
            let behind = [0.0, 1e-5, -1e-5, 1e-3, -1e-3][k % 5];
            for key in [t, t * (1.0 + behind)] {
                let reach = bound(Some((key, none)), key, behind, f32::INFINITY);
                let back = key != t;
                assert!(
                    t < reach && (back || key < reach),
                    "t {t:e} key {key:e} behind {behind}: reach {reach:e}"
                );
            }
        }
    }

    #[test]
    fn the_wide_walk_gives_the_binary_walks_answers() {
        for (seed, n, heights) in [(5, 12, 5), (9, 10, 4)] {
            let (hidden, hits) = compare_walks(seed, n, heights);
            assert!(
                (2000..18_000).contains(&hidden) && hits > 5000,
                "{hidden} hidden and {hits} hit of 20 000"
            );
        }
    }

    #[test]
    fn coinciding_polygons_build_and_answer() {
        // Centroids that do not spread give the surface area heuristic
        // nothing to split: the build falls back to the median.
        let polys: Vec<Polygon> = (0..50).map(|_| quad(Vec3::ZERO, 1.0, true)).collect();
        let bvh = Bvh::new(&polys);
        assert_eq!(bvh.triangles(), 100);
        let hit = bvh.nearest(Vec3::new(0.2, 0.3, 1.0), -Vec3::Z, 0.0, 10.0);
        assert!(hit.is_some_and(|h| (h.t - 1.0).abs() < 1e-6));
        assert!(!bvh.occluded(Vec3::new(2.0, 0.0, 1.0), -Vec3::Z, 0.0, 10.0, [u32::MAX; 2]));
    }

    #[test]
    fn a_ray_along_a_shared_edge_does_not_slip_through() {
        let polys = vec![quad(Vec3::ZERO, 1.0, true)];
        let bvh = Bvh::new(&polys);
        // Through the diagonal shared by the quad's two triangles.
        for k in 0..100 {
            let s = -0.99 + 1.98 * k as f32 / 99.0;
            let hit = bvh.nearest(Vec3::new(s, s, 1.0), -Vec3::Z, 0.0, 10.0);
            assert_eq!(hit.map(|h| h.polygon), Some(0), "at {s}");
        }
    }
}
