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
    /// Cell-centre directions (`hemisphere::direction_table`, the shader's).
    trig: Vec<[f32; 2]>,
}

impl OcclusionMap {
    /// An empty map for hemispheres of `res`.
    pub fn new(res: Resolution) -> Self {
        Self {
            res,
            depth: vec![f32::INFINITY; res.cells()],
            trig: crate::hemisphere::direction_table(res),
        }
    }

    /// Forgets every cell's cover (a new shot).
    pub fn clear(&mut self) {
        self.depth.iter_mut().for_each(|d| *d = f32::INFINITY);
    }

    /// Takes in a piece that is drawn: every cell whose centre direction is
    /// inside all its edge planes is covered at its distance there.
    pub fn add(&mut self, piece: &Piece) {
        let rows = 0..self.res.rows as usize;
        add_to_rows(self.res, &self.trig, &mut self.depth, rows, piece);
    }

    /// [`OcclusionMap::add`] for every item's piece, the rows divided
    /// between `threads` threads (the same map as one thread makes).
    pub fn add_all<T: Sync>(&mut self, items: &[T], piece: fn(&T) -> Piece<'_>, threads: usize) {
        if threads <= 1 {
            items.iter().for_each(|item| self.add(&piece(item)));
            return;
        }
        let (res, trig) = (self.res, &self.trig);
        let cols = res.cols as usize;
        let band = (res.rows as usize).div_ceil(threads.max(1)).max(1);
        std::thread::scope(|scope| {
            for (k, depth) in self.depth.chunks_mut(band * cols).enumerate() {
                let rows = k * band..k * band + depth.len() / cols;
                scope.spawn(move || {
                    for item in items {
                        add_to_rows(res, trig, depth, rows.clone(), &piece(item));
                    }
                });
            }
        });
    }

    /// Whether every cell the piece could draw is covered nearer than the
    /// piece is there; `nearest` bounds its distance from below (used where
    /// its plane is seen edge-on).
    pub fn hides(&self, piece: &Piece, nearest: f32) -> bool {
        let cols = self.res.cols as usize;
        cells(self.res, &self.trig, piece.rect).all(|(cell, d)| {
            if piece.edges.iter().any(|e| dot(e, d) < -INSIDE) {
                return true;
            }
            let cos = dot(&piece.plane, d);
            let t = piece.plane[3] / cos;
            let t = if cos.abs() >= GRAZING && t.is_finite() {
                if t <= 0.0 {
                    // Behind the hemisphere: no fragment.
                    return true;
                }
                t.max(nearest)
            } else {
                nearest
            };
            self.depth[cell[1] * cols + cell[0]] * (1.0 + DEPTH_MARGIN) < t
        })
    }
}

/// The cells (column wrapped, row) of `res` whose centres `rect` holds, with
/// their centre directions from `trig` (`hemisphere::direction_table`).
fn cells(
    res: Resolution,
    trig: &[[f32; 2]],
    rect: [f32; 4],
) -> impl Iterator<Item = ([usize; 2], [f32; 3])> + '_ {
    let lo = |x: f32| (x - 0.5).ceil() as i64;
    let hi = |x: f32| (x - 0.5).floor() as i64;
    let (rows, cols) = (res.rows as i64, res.cols as i64);
    let (t0, t1) = (lo(rect[0]), hi(rect[1]).min(lo(rect[0]) + cols - 1));
    let (p0, p1) = (lo(rect[2]).max(0), hi(rect[3]).min(rows - 1));
    (p0..=p1).flat_map(move |p| {
        let [sp, cp] = trig[p as usize];
        (t0..=t1).map(move |t| {
            let t = t.rem_euclid(cols) as usize;
            let [ct, st] = trig[rows as usize + t];
            ([t, p as usize], [sp * ct, sp * st, cp])
        })
    })
}

/// Adds a piece's cover to `depth`, the map's rows `rows` (row-major).
fn add_to_rows(
    res: Resolution,
    trig: &[[f32; 2]],
    depth: &mut [f32],
    rows: std::ops::Range<usize>,
    piece: &Piece,
) {
    let cols = res.cols as usize;
    let mut rect = piece.rect;
    rect[2] = rect[2].max(rows.start as f32);
    rect[3] = rect[3].min(rows.end as f32);
    for (cell, d) in cells(res, trig, rect) {
        if piece.edges.iter().all(|e| dot(e, d) >= INSIDE) {
            let cos = dot(&piece.plane, d);
            let t = piece.plane[3] / cos;
            if cos.abs() >= GRAZING && t > 0.0 {
                let k = (cell[1] - rows.start) * cols + cell[0];
                depth[k] = depth[k].min(t);
            }
        }
    }
}

fn dot(e: &[f32], d: [f32; 3]) -> f32 {
    e[0] * d[0] + e[1] * d[1] + e[2] * d[2]
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

    /// A quad seen from the origin as `gpu::proxies` draws a front face:
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
