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
use std::collections::HashMap;

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
    let grid = EdgeGrid::new(&polygons, extent);
    // Each polygon's pieces depend on the polygons alone: found on every
    // core (a dense scene spends seconds looking for cut lines), then
    // joined in order.
    let mut pieces: Vec<Option<Vec<Vec<Vec3>>>> = vec![None; polygons.len()];
    crate::sampling::in_parallel(&mut pieces, |i, out| {
        *out = pieces_of(&grid, &polygons, i, eps, hover);
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
fn pieces_of(
    grid: &EdgeGrid,
    polygons: &[Polygon],
    i: usize,
    eps: f32,
    hover: f32,
) -> Option<Vec<Vec<Vec3>>> {
    let cuts = grid.cuts(polygons, i, eps, hover);
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

/// Every polygon edge, bucketed by the grid cells its bounding box touches.
struct EdgeGrid {
    cell: f32,
    edges: Vec<(Vec3, Vec3, u32)>,
    /// Per polygon, the diagonal of its bounding box.
    sizes: Vec<f32>,
    cells: HashMap<[i32; 3], Vec<u32>>,
}

impl EdgeGrid {
    fn new(polygons: &[Polygon], extent: f32) -> Self {
        let cell = (extent / 64.0).max(1e-6);
        let mut edges = Vec::new();
        for (i, p) in polygons.iter().enumerate() {
            let n = p.vertices.len();
            for k in 0..n {
                edges.push((p.vertices[k], p.vertices[(k + 1) % n], i as u32));
            }
        }
        let mut cells: HashMap<[i32; 3], Vec<u32>> = HashMap::new();
        for (e, (a, b, _)) in edges.iter().enumerate() {
            let (lo, hi) = (Self::key(a.min(*b), cell), Self::key(a.max(*b), cell));
            // Long edges would touch many cells: such an edge is a cut
            // candidate for polygons near any part of it, so keep them all
            // (bounded, as a room's edges are few).
            for x in lo[0]..=hi[0] {
                for y in lo[1]..=hi[1] {
                    for z in lo[2]..=hi[2] {
                        cells.entry([x, y, z]).or_default().push(e as u32);
                    }
                }
            }
        }
        let sizes = polygons
            .iter()
            .map(|p| {
                let (lo, hi) = p.bounds();
                (hi - lo).length()
            })
            .collect();
        EdgeGrid {
            cell,
            edges,
            sizes,
            cells,
        }
    }

    fn key(p: Vec3, cell: f32) -> [i32; 3] {
        (p / cell).floor().as_ivec3().to_array()
    }

    /// The cut lines (in-plane normal m, offset c) of polygon `i`: edges of
    /// other, non-coplanar polygons that lie in its plane and cross it, and
    /// edges of parallel polygons in front of it by at most `hover`,
    /// dropped onto its plane.
    fn cuts(
        &self,
        polygons: &[Polygon],
        i: usize,
        eps: f32,
        hover: f32,
    ) -> Vec<(Vec3, f32, Vec3, Vec3)> {
        let p = &polygons[i];
        let n = p.normal;
        let (lo, hi) = p.bounds();
        // The box reaches `hover` in front of the plane.
        let (lo, hi) = (lo.min(lo + n * hover), hi.max(hi + n * hover));
        let (klo, khi) = (
            Self::key(lo - eps, self.cell),
            Self::key(hi + eps, self.cell),
        );
        let plane = n.dot(p.vertices[0]);
        // Only edges in this polygon's plane can cut it: test that first
        // (two dot products), then sort the few left (a dense scene puts
        // thousands of edges in a cell).
        let mut seen = Vec::new();
        for x in klo[0]..=khi[0] {
            for y in klo[1]..=khi[1] {
                for z in klo[2]..=khi[2] {
                    let Some(list) = self.cells.get(&[x, y, z]) else {
                        continue;
                    };
                    seen.extend(list.iter().copied().filter(|&e| {
                        let (a, b, q) = self.edges[e as usize];
                        let (da, db) = (n.dot(a) - plane, n.dot(b) - plane);
                        let in_plane = da.abs() <= eps && db.abs() <= eps;
                        let hover = hover.min(HOVER_OWN * self.sizes[q as usize]);
                        let hovering = (eps..=hover).contains(&da) && (eps..=hover).contains(&db);
                        q as usize != i && (in_plane || hovering)
                    }));
                }
            }
        }
        seen.sort_unstable();
        seen.dedup();
        let mut out: Vec<(Vec3, f32, Vec3, Vec3)> = Vec::new();
        for e in seen {
            let (a, b, q) = self.edges[e as usize];
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
    fn coplanar_neighbours_and_far_polygons_do_not_split() {
        let a = Polygon::square(Vec3::ZERO, 1.0, Vec3::X, -Vec3::Z, [0.5; 3], [0.0; 3]);
        let b = Polygon::square(Vec3::X * 2.0, 1.0, Vec3::X, -Vec3::Z, [0.5; 3], [0.0; 3]);
        let (out, split) = split_at_contacts(vec![a, b], 4.0);
        assert_eq!((out.len(), split), (2, 0));
    }
}
