//! Polygons split where another polygon stands on them (a box on a floor, a
//! box on a box, a wall on a floor that runs under it): along the line of
//! each edge of a non-coplanar polygon that lies in a polygon's plane and
//! crosses its inside, and along the outline of a parallel polygon hovering
//! just in front of it (a light panel hung 1 cm under a ceiling: its
//! edges dropped onto the ceiling, within [`HOVER`] of the scene's size and
//! [`HOVER_OWN`] of the panel's).
//! Without the split, an element straddling the line
//! averages the light of both sides (the floor under a box is lit by the
//! floor beside it, a room's floor by the hall outside its walls), and a
//! hemisphere standing on it may stand inside the box. The split keeps
//! every piece's node, material and side, so per-node results and the
//! geometry are unchanged. Pure geometry.

use super::Polygon;
use glam::Vec3;

/// At most this many cut lines per polygon (a floor under many objects
/// keeps the first ones).
const MAX_CUTS: usize = 24;

/// At most this many pieces per polygon; a polygon that would give more
/// stays whole.
const MAX_PIECES: usize = 256;

/// A polygon parallel to another and in front of it by at most this
/// fraction of the scene's size, and of its own size (a light panel hung
/// under a ceiling), cuts it along its outline dropped onto it (see the
/// module docs).
pub const HOVER: f32 = 1e-2;

/// The hovering polygon's own bound: at most this fraction of its size
/// (the diagonal of its bounding box) in front.
pub const HOVER_OWN: f32 = 0.05;

/// Splits `polygons` at their contact lines (see the module docs); returns
/// the new list and how many polygons were split. `extent` is the scene's
/// size (tolerances are a hundred-thousandth of it).
pub fn split_at_contacts(polygons: Vec<Polygon>, extent: f32) -> (Vec<Polygon>, usize) {
    let eps = 1e-5 * extent.max(1e-6);
    let hover = HOVER * extent.max(1e-6);
    let grid = Edges::new(&polygons, hover);
    // Each polygon's pieces depend on the polygons alone: found on every
    // core (a dense scene spends seconds looking for cut lines), then
    // joined in order.
    let mut pieces: Vec<Option<Vec<Vec<Vec3>>>> = vec![None; polygons.len()];
    crate::sampling::in_parallel(&mut pieces, |i, out| {
        *out = pieces_of(&grid, &polygons, i, eps);
    });
    let mut out = Vec::with_capacity(polygons.len());
    let mut split = 0;
    for ((i, p), pieces) in polygons.iter().enumerate().zip(pieces) {
        let Some(pieces) = pieces else {
            out.push(p.clone());
            continue;
        };
        let whole = pieces.len() == 1;
        split += usize::from(!whole);
        for piece in pieces {
            push_convex(&mut out, p, piece, (!whole).then_some(i as u32));
        }
    }
    (out, split)
}

/// Polygon `i` cut along its contact lines (one piece where the lines it
/// has miss it), or `None` where it stays as it is (it has no cut lines, or
/// would fall into more than [`MAX_PIECES`]).
fn pieces_of(grid: &Edges, polygons: &[Polygon], i: usize, eps: f32) -> Option<Vec<Vec<Vec3>>> {
    let cuts = grid.cuts(polygons, i, eps);
    if cuts.is_empty() {
        return None;
    }
    // Each line cuts only the pieces its contact segment crosses, so a box
    // on a big floor cuts out its footprint's neighbourhood, not strips
    // across the whole floor.
    let mut pieces = vec![polygons[i].vertices.clone()];
    for (m, c, a, b) in cuts {
        pieces = pieces
            .into_iter()
            .flat_map(|piece| {
                if overlaps(&piece, a, b, eps) {
                    cut(&piece, m, c, eps)
                } else {
                    vec![piece]
                }
            })
            .collect();
    }
    // A floor under many objects would become hundreds of strips, each with
    // its own patches (the many-objects scene: 5x the patches and 10x the
    // time): such a polygon stays whole.
    (pieces.len() <= MAX_PIECES).then_some(pieces)
}

/// A convex piece of `p` as polygons of 3 or 4 vertices (a fan beyond).
fn push_convex(out: &mut Vec<Polygon>, p: &Polygon, piece: Vec<Vec3>, parent: Option<u32>) {
    let whole = p.area().max(1e-30);
    let with = |vertices: Vec<Vec3>| {
        let mut q = Polygon {
            vertices,
            parent,
            ..p.clone()
        };
        // A fixed subdivision is the whole's: a piece gets its share of the
        // patches (by the square root of its share of the area).
        let k = (q.area() / whole).sqrt();
        if let Some(sub) = q.subdivision.as_mut() {
            sub.patches = sub.patches.map(|n| ((n as f32 * k).ceil() as u32).max(1));
        }
        q
    };
    if piece.len() <= 4 {
        out.push(with(piece));
        return;
    }
    // A fan of quads where they fit, then a triangle.
    let mut k = 1;
    while k + 1 < piece.len() {
        if k + 2 < piece.len() {
            out.push(with(vec![piece[0], piece[k], piece[k + 1], piece[k + 2]]));
            k += 2;
        } else {
            out.push(with(vec![piece[0], piece[k], piece[k + 1]]));
            k += 1;
        }
    }
}

/// `piece` cut by the line m . x = c in its plane: one or two convex pieces
/// (none cut off that is thinner than `eps`).
fn cut(piece: &[Vec3], m: Vec3, c: f32, eps: f32) -> Vec<Vec<Vec3>> {
    let d: Vec<f32> = piece.iter().map(|v| m.dot(*v) - c).collect();
    let above = d.iter().any(|&x| x > eps);
    let below = d.iter().any(|&x| x < -eps);
    if !(above && below) {
        return vec![piece.to_vec()];
    }
    let mut parts = [Vec::new(), Vec::new()];
    let n = piece.len();
    for k in 0..n {
        let (a, b) = (piece[k], piece[(k + 1) % n]);
        let (da, db) = (d[k], d[(k + 1) % n]);
        if da >= 0.0 {
            parts[0].push(a);
        }
        if da <= 0.0 {
            parts[1].push(a);
        }
        if (da > 0.0 && db < 0.0) || (da < 0.0 && db > 0.0) {
            let x = a + (b - a) * (da / (da - db));
            parts[0].push(x);
            parts[1].push(x);
        }
    }
    parts.into_iter().filter(|p| p.len() >= 3).collect()
}

/// Every polygon edge, in a hierarchy of boxes (median splits): a polygon
/// looks only at the edges whose boxes meet its own (a uniform grid made
/// every small polygon of a dense mesh scan the thousands of edges sharing
/// its cell: Sponza's split took 5.8 s).
struct Edges {
    /// In the hierarchy's order, so that a leaf's edges lie side by side.
    order: Vec<Edge>,
    /// Depth first: a node's first child follows it.
    nodes: Vec<EdgeNode>,
}

/// A node of [`Edges`]' hierarchy: the box of `order[start..end]`, a leaf
/// when `second` is 0, else its children at its own index + 1 and `second`.
struct EdgeNode {
    lo: Vec3,
    hi: Vec3,
    start: u32,
    end: u32,
    second: u32,
}

/// A polygon's edge, as [`Edges`] keeps it.
#[derive(Clone, Copy)]
struct Edge {
    a: Vec3,
    b: Vec3,
    /// The polygon.
    polygon: u32,
    /// The edge's index in polygon order (cuts are taken in that order).
    index: u32,
    /// How far in front of a polygon the edge may hover and still cut it:
    /// [`HOVER`] of the scene's size, or [`HOVER_OWN`] of its polygon's if
    /// less. Its box is grown by this much, so that a polygon's own box
    /// finds the edges hovering over it.
    reach: f32,
}

impl Edge {
    fn bounds(&self) -> (Vec3, Vec3) {
        (
            self.a.min(self.b) - self.reach,
            self.a.max(self.b) + self.reach,
        )
    }
}

/// Edges per leaf of [`Edges`]' hierarchy, at most.
const EDGE_LEAF: usize = 4;

/// The empty box (every point extends it).
const NO_BOX: (Vec3, Vec3) = (Vec3::INFINITY, Vec3::NEG_INFINITY);

impl Edges {
    fn new(polygons: &[Polygon], hover: f32) -> Self {
        let mut order = Vec::new();
        for (i, p) in polygons.iter().enumerate() {
            let (lo, hi) = p.bounds();
            let reach = hover.min(HOVER_OWN * (hi - lo).length());
            let n = p.vertices.len();
            for k in 0..n {
                order.push(Edge {
                    a: p.vertices[k],
                    b: p.vertices[(k + 1) % n],
                    polygon: i as u32,
                    index: order.len() as u32,
                    reach,
                });
            }
        }
        let mut nodes = Vec::with_capacity(order.len() / EDGE_LEAF * 2 + 1);
        if !order.is_empty() {
            Self::build(&mut order, 0, &mut nodes);
        }
        Edges { order, nodes }
    }

    /// Appends the subtree over `edges` (which start at `offset` in the
    /// order) to `nodes`; returns its root's index.
    fn build(edges: &mut [Edge], offset: usize, nodes: &mut Vec<EdgeNode>) -> u32 {
        let (lo, hi) = edges.iter().fold(NO_BOX, |(lo, hi), e| {
            let (a, b) = e.bounds();
            (lo.min(a), hi.max(b))
        });
        let at = nodes.len();
        nodes.push(EdgeNode {
            lo,
            hi,
            start: offset as u32,
            end: (offset + edges.len()) as u32,
            second: 0,
        });
        if edges.len() > EDGE_LEAF {
            // Halved at the median of the widest spread of midpoints.
            let (clo, chi) = edges.iter().fold(NO_BOX, |(lo, hi), e| {
                let c = e.a + e.b;
                (lo.min(c), hi.max(c))
            });
            let axis = (chi - clo).max_position();
            let mid = edges.len() / 2;
            edges.select_nth_unstable_by(mid, |x, y| {
                (x.a + x.b)[axis].total_cmp(&(y.a + y.b)[axis])
            });
            let (left, right) = edges.split_at_mut(mid);
            Self::build(left, offset, nodes);
            nodes[at].second = Self::build(right, offset + mid, nodes);
        }
        at as u32
    }

    /// Calls `f` with every edge whose box (grown by its reach) meets the
    /// box `lo`-`hi`.
    fn meeting(&self, lo: Vec3, hi: Vec3, mut f: impl FnMut(&Edge)) {
        let meets = |(a, b): (Vec3, Vec3)| a.cmple(hi).all() && b.cmpge(lo).all();
        let mut stack: Vec<u32> = Vec::with_capacity(64);
        if !self.nodes.is_empty() {
            stack.push(0);
        }
        while let Some(at) = stack.pop() {
            let node = &self.nodes[at as usize];
            if !meets((node.lo, node.hi)) {
                continue;
            }
            if node.second != 0 {
                stack.push(node.second);
                stack.push(at + 1);
                continue;
            }
            for edge in &self.order[node.start as usize..node.end as usize] {
                if meets(edge.bounds()) {
                    f(edge);
                }
            }
        }
    }

    /// The cut lines (in-plane normal m, offset c) of polygon `i`: edges of
    /// other, non-coplanar polygons that lie in its plane and cross it, and
    /// edges of parallel polygons in front of it by at most their reach,
    /// dropped onto its plane.
    fn cuts(&self, polygons: &[Polygon], i: usize, eps: f32) -> Vec<(Vec3, f32, Vec3, Vec3)> {
        self.cuts_among(polygons, i, eps, false)
    }

    /// [`Edges::cuts`], from every edge when `scan` (the tests' reference)
    /// or from those the hierarchy finds.
    fn cuts_among(
        &self,
        polygons: &[Polygon],
        i: usize,
        eps: f32,
        scan: bool,
    ) -> Vec<(Vec3, f32, Vec3, Vec3)> {
        let p = &polygons[i];
        let n = p.normal;
        // An edge that cuts has a piece inside the polygon, within `eps`
        // behind it or its reach in front, so its grown box meets this one
        // (grown by `eps` twice over, for rounding).
        let (lo, hi) = p.bounds();
        let (lo, hi) = (lo - 2.0 * eps, hi + 2.0 * eps);
        let plane = n.dot(p.vertices[0]);
        // Only edges in this polygon's plane can cut it: test that first
        // (two dot products), then sort the few left.
        let mut seen = Vec::new();
        let consider = |e: &Edge| {
            let (da, db) = (n.dot(e.a) - plane, n.dot(e.b) - plane);
            let in_plane = da.abs() <= eps && db.abs() <= eps;
            let hovering = (eps..=e.reach).contains(&da) && (eps..=e.reach).contains(&db);
            if e.polygon as usize != i && (in_plane || hovering) {
                seen.push((e.index, e.a, e.b, e.polygon));
            }
        };
        if scan {
            self.order.iter().for_each(consider);
        } else {
            self.meeting(lo, hi, consider);
        }
        // In polygon order, as the cuts are capped at MAX_CUTS.
        seen.sort_unstable_by_key(|&(e, ..)| e);
        let mut out: Vec<(Vec3, f32, Vec3, Vec3)> = Vec::new();
        for (_, a, b, q) in seen {
            let parallel = polygons[q as usize].normal.dot(n).abs() > 0.99;
            let in_plane = (n.dot(a) - plane).abs() <= eps;
            // A coplanar neighbour does not cut; a parallel polygon hovering
            // in front cuts along its edges' shadow, a slanted one never.
            if parallel == in_plane {
                continue;
            }
            let (a, b) = (a - n * (n.dot(a) - plane), b - n * (n.dot(b) - plane));
            let u = b - a;
            if u.length() <= 10.0 * eps {
                continue;
            }
            let m = n.cross(u).normalize();
            let c = m.dot(a);
            // The segment must overlap the polygon, and the line cross it.
            if !overlaps(&p.vertices, a, b, eps) {
                continue;
            }
            let d = p.vertices.iter().map(|v| m.dot(*v) - c);
            let (above, below) = d.fold((false, false), |(x, y), t| (x || t > eps, y || t < -eps));
            if above && below && out.len() < MAX_CUTS {
                out.push((m, c, a, b));
            }
        }
        out
    }
}

/// Whether the segment a-b (in the convex polygon's plane) has a part of
/// positive length inside the polygon.
fn overlaps(poly: &[Vec3], a: Vec3, b: Vec3, eps: f32) -> bool {
    // Clip the segment by each edge's inward half-plane.
    let n = (poly[1] - poly[0])
        .cross(poly[2] - poly[0])
        .normalize_or_zero();
    let (mut t0, mut t1) = (0.0f32, 1.0f32);
    let k = poly.len();
    for i in 0..k {
        let (p, q) = (poly[i], poly[(i + 1) % k]);
        let inward = n.cross(q - p).normalize_or_zero();
        let (da, db) = (inward.dot(a - p), inward.dot(b - p));
        if da < -eps && db < -eps {
            return false;
        }
        if (da < 0.0) != (db < 0.0) {
            let t = da / (da - db);
            if da < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    (t1 - t0) * (b - a).length() > 10.0 * eps
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_box_side_on_a_floor_splits_the_floor_along_its_line() {
        let floor = Polygon::square(Vec3::ZERO, 2.0, Vec3::X, -Vec3::Z, [0.5; 3], [0.0; 3]);
        // One side of a box standing on the floor: its bottom edge lies in
        // the floor's plane, x in [-0.5, 0.5] at z = 0.5.
        let side = Polygon {
            vertices: vec![
                Vec3::new(-0.5, 0.0, 0.5),
                Vec3::new(0.5, 0.0, 0.5),
                Vec3::new(0.5, 1.0, 0.5),
                Vec3::new(-0.5, 1.0, 0.5),
            ],
            normal: Vec3::Z,
            ..floor.clone()
        };
        let (out, split) = split_at_contacts(vec![floor.clone(), side], 4.0);
        assert_eq!(split, 1);
        // The full line z = 0.5 across the floor: two pieces, areas summing to 16.
        let pieces: Vec<_> = out.iter().filter(|p| p.normal == Vec3::Y).collect();
        assert_eq!(pieces.len(), 2);
        let area: f32 = pieces.iter().map(|p| p.area()).sum();
        assert!((area - floor.area()).abs() < 1e-4, "{area}");
    }

    #[test]
    fn a_panel_hung_under_a_ceiling_splits_it_along_its_outline() {
        // A 4 x 4 m ceiling facing down, a 1 x 1 m panel 1 cm under it
        // (facing down too): the ceiling is cut along the panel's four
        // edges, and one piece lies exactly over the panel.
        let ceiling = Polygon::square(Vec3::Y * 3.0, 2.0, Vec3::X, Vec3::Z, [0.5; 3], [0.0; 3]);
        assert!(ceiling.normal.y < 0.0);
        let panel_at = |y: f32| {
            let c = Vec3::new(0.5, y, 0.25);
            Polygon::square(c, 0.5, Vec3::X, Vec3::Z, [0.8; 3], [1.0; 3])
        };
        let (out, split) = split_at_contacts(vec![ceiling.clone(), panel_at(2.99)], 6.0);
        assert_eq!(split, 1);
        let pieces: Vec<_> = out.iter().filter(|p| p.vertices[0].y == 3.0).collect();
        let area: f32 = pieces.iter().map(|p| p.area()).sum();
        assert!((area - ceiling.area()).abs() < 1e-3, "{area}");
        let over = pieces.iter().filter(|p| {
            let c = p.centre();
            (c.x - 0.5).abs() < 0.5 && (c.z - 0.25).abs() < 0.5
        });
        let over: f32 = over.map(|p| p.area()).sum();
        assert!((over - 1.0).abs() < 1e-3, "{over}");
        // Nothing hovers in front of the panel: it stays whole. Farther
        // than the hover distance (6 cm here), the ceiling stays whole too.
        assert_eq!(out.iter().filter(|p| p.emission[0] > 0.0).count(), 1);
        assert_eq!(split_at_contacts(vec![ceiling, panel_at(2.9)], 6.0).1, 0);
    }

    #[test]
    fn the_edge_hierarchy_finds_the_cuts_a_scan_of_every_edge_finds() {
        // Boxes on floors and on boxes, panels under ceilings, slabs and
        // openings, and a random scatter of small tilted squares, some
        // hovering just over the floor and over each other.
        let names = ["cornell", "classroom-c1", "cubes-3"].map(String::from);
        let families =
            ["boxes", "stacked", "slab", "opening", "many"].map(|k| format!("family-{k}-3"));
        let mut scenes: Vec<Vec<Polygon>> = names
            .iter()
            .chain(&families)
            .map(|name| crate::scene::open_as_authored(name).unwrap().polygons)
            .collect();
        let mut rng = crate::rng::Rng(7);
        let mut unit = || crate::sampling::unit(&mut rng);
        let floor = Polygon::square(Vec3::ZERO, 2.0, Vec3::X, -Vec3::Z, [0.5; 3], [0.0; 3]);
        let mut scatter = vec![floor];
        for _ in 0..400 {
            let c = Vec3::new(unit() * 4.0 - 2.0, unit() * 0.02, unit() * 4.0 - 2.0);
            let u = Vec3::new(1.0, unit() * 0.3 * f32::from(unit() < 0.5), 0.0).normalize();
            let v = if unit() < 0.5 { -Vec3::Z } else { Vec3::Y };
            scatter.push(Polygon::square(
                c,
                0.01 + unit() * 0.3,
                u,
                v,
                [0.5; 3],
                [0.0; 3],
            ));
        }
        scenes.push(scatter);
        let mut cut = 0;
        for polygons in &scenes {
            let extent = {
                let (lo, hi) = polygons
                    .iter()
                    .map(Polygon::bounds)
                    .fold(NO_BOX, |(l, h), (a, b)| (l.min(a), h.max(b)));
                (hi - lo).length()
            };
            let (eps, hover) = (1e-5 * extent, HOVER * extent);
            let edges = Edges::new(polygons, hover);
            for i in 0..polygons.len() {
                let found = edges.cuts_among(polygons, i, eps, false);
                let scanned = edges.cuts_among(polygons, i, eps, true);
                let key = |c: &[(Vec3, f32, Vec3, Vec3)]| format!("{c:?}");
                assert_eq!(key(&found), key(&scanned), "polygon {i}");
                cut += usize::from(!found.is_empty());
            }
        }
        // Enough polygons have cuts for the comparison to mean something.
        assert!(cut > 100, "{cut}");
    }

    #[test]
    fn coplanar_neighbours_and_far_polygons_do_not_split() {
        let a = Polygon::square(Vec3::ZERO, 1.0, Vec3::X, -Vec3::Z, [0.5; 3], [0.0; 3]);
        let b = Polygon::square(Vec3::X * 2.0, 1.0, Vec3::X, -Vec3::Z, [0.5; 3], [0.0; 3]);
        let (out, split) = split_at_contacts(vec![a, b], 4.0);
        assert_eq!((out.len(), split), (2, 0));
    }
}
