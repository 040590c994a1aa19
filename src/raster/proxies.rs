//! The CPU side of a shot: every polygon's rasterisation proxies (built
//! once), the cull of polygons the shooter cannot see, and each visible
//! proxy's conservative cell rectangle with its edge planes, as the
//! rectangles the GPU draws.

use crate::hemisphere::{cell_bounds, CellRect, Resolution};
use crate::mesh::{Mesh, ShooterFrame};
use crate::occlusion::{OcclusionMap, Piece};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use std::ops::{Deref, Range};
use std::sync::Arc;

/// One rectangle to draw, with what the fragment test needs (see the shader's `Rect`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub struct Instance {
    pub(crate) rect: [f32; 4],
    pub(crate) edges: [[f32; 3]; 4],
    pub(crate) plane: [f32; 4],
    pub(crate) item: [u32; 2],
    pub(crate) origin: [f32; 4],
    pub(crate) axis: [f32; 4],
    pub(crate) bilinear: [f32; 4],
    pub(crate) grid: [u32; 4],
}

/// A dealt rectangle on the wire: the proxy and its cell rectangle (or a
/// piece of it); the receiver rebuilds the rest of its [`Instance`] from
/// the proxy, as the sender would have (20 bytes instead of 152).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Bound {
    proxy: u32,
    rect: [f32; 4],
}

/// A polygon's pieces and what culling needs.
pub(crate) struct PolygonProxies {
    pub(crate) proxies: Range<u32>,
    pub(crate) normal: Vec3,
    pub(crate) centre: Vec3,
    pub(crate) radius: f32,
    /// Its bilinear element grid, when it is drawn in pieces (an index into `quads`).
    pub(crate) quad: Option<u32>,
    /// The solid it bounds, if any (an index into `Mesh::solids`).
    pub(crate) solid: Option<u32>,
    /// Its first proxy's first corner, a point of its plane (kept here: the
    /// back-face test reads it for every solid's polygon in view, and the
    /// proxies' corners are elsewhere in memory).
    pub(crate) corner: Vec3,
}

/// A quad polygon drawn in pieces: its corners (world space) and element
/// grid (elements along u and v, elements per patch along u and v), from
/// which the fragment shader finds the element at a hit point.
pub(crate) struct QuadGrid {
    pub(crate) corners: [Vec3; 4],
    pub(crate) grid: [u32; 4],
}

/// The outline of a quad polygon (its patches' outer corners), or `None` for
/// a triangle.
fn polygon_outline(mesh: &Mesh, poly: &crate::mesh::MeshPolygon) -> Option<[Vec3; 4]> {
    let patches = &mesh.patches[poly.patches.start as usize..poly.patches.end as usize];
    let first = patches.first()?;
    if first.corners[3] == first.corners[2] {
        return None;
    }
    let [pu, pv] = poly.patch_grid;
    let at = |i: u32, j: u32| &patches[(j * pu + i) as usize];
    Some([
        at(0, 0).corners[0],
        at(pu - 1, 0).corners[1],
        at(pu - 1, pv - 1).corners[2],
        at(0, pv - 1).corners[3],
    ])
}

/// What the fragment shader needs to find the element of a piece of a quad
/// polygon at a hit point, in the shooter's frame: the polygon's bilinear map
/// p = o + u e1 + v e2 + u v g written in a 2-D basis of its plane (x along e1).
#[derive(Clone, Copy, Default)]
pub(crate) struct Lookup {
    /// o (shooter frame), and g's y coordinate.
    pub(crate) origin: [f32; 4],
    /// The plane's x axis (shooter frame).
    pub(crate) axis: [f32; 4],
    /// |e1|, e2.x, e2.y, g.x.
    pub(crate) bilinear: [f32; 4],
    /// Elements along u, along v, per patch along u, per patch along v (all 0: a single element).
    pub(crate) grid: [u32; 4],
}

impl Lookup {
    pub(crate) fn new(q: &QuadGrid, shooter: &ShooterFrame, n: Vec3) -> Self {
        let c = q.corners.map(|p| shooter.to_local(p - shooter.centre));
        let (e1, e2, g) = (c[1] - c[0], c[3] - c[0], c[0] - c[1] + c[2] - c[3]);
        let x = e1.normalize_or_zero();
        let y = n.cross(x);
        Self {
            origin: [c[0].x, c[0].y, c[0].z, g.dot(y)],
            axis: [x.x, x.y, x.z, 0.0],
            bilinear: [e1.length(), e2.dot(x), e2.dot(y), g.dot(x)],
            grid: q.grid,
        }
    }
}

/// Every polygon's rasterisation proxies: quad polygons as at most
/// `pieces` x `pieces` pieces (the fragment shader finds the element), or
/// every element on its own (0, and triangles). Read-only once built, so
/// the tiers of a source and a sibling source drawing rows ahead share one
/// (`Arc`): Sponza's are 1.2 M proxies, built in about a second each.
pub struct ProxyShapes {
    /// Corners of every proxy (world space).
    pub(crate) corners: Vec<[Vec3; 4]>,
    /// Element each proxy belongs to (the polygon's first element for a piece of a quad grid).
    pub(crate) element: Vec<u32>,
    /// Quad polygons drawn in pieces.
    pub(crate) quads: Vec<QuadGrid>,
    pub(crate) polygons: Vec<PolygonProxies>,
    /// A bounding sphere of each run of [`BLOCK`] consecutive polygons
    /// (centre, radius): a shot skips a run wholly out of view, or wholly
    /// outside a rank's tiles, without looking at its polygons.
    pub(crate) blocks: Vec<(Vec3, f32)>,
    /// A bounding sphere of each of the mesh's solids.
    solid_spheres: Vec<(Vec3, f32)>,
}

/// A rasteriser's proxies: the shared shapes, and how its shots walk them.
pub(crate) struct Proxies {
    shapes: Arc<ProxyShapes>,
    /// Whether a whole hemisphere culled on one process walks the blocks
    /// nearest first ([`Proxies::visit_near_first`]); `None`: on one
    /// thread only. Tests set it to compare both walks.
    pub(crate) near_first: Option<bool>,
    /// The most threads a shot's bounds use (see
    /// `gpu::HemisphereRasterizer::set_bounds_threads`).
    pub(crate) max_threads: usize,
    /// The nearest-first walk's buffer of rectangles in walk order, kept
    /// from shot to shot: grown afresh each shot, its reallocations and
    /// page faults were a tenth of the walk's copying.
    scratch: std::sync::Mutex<Drawn>,
}

/// Polygons per block of [`Proxies::blocks`]. Consecutive polygons are
/// mostly near each other (one glTF mesh, one box), so a block's sphere is
/// small; 32 keeps the block test a small share of the polygons' tests.
const BLOCK: usize = 32;

/// The bounding spheres of each [`BLOCK`] consecutive polygons.
fn block_spheres(polygons: &[PolygonProxies]) -> Vec<(Vec3, f32)> {
    polygons
        .chunks(BLOCK)
        .map(|run| {
            let (lo, hi) = run.iter().fold((Vec3::MAX, Vec3::MIN), |(lo, hi), p| {
                (lo.min(p.centre - p.radius), hi.max(p.centre + p.radius))
            });
            let centre = 0.5 * (lo + hi);
            let radius = run
                .iter()
                .map(|p| p.centre.distance(centre) + p.radius)
                .fold(0.0f32, f32::max);
            grown(centre, radius)
        })
        .collect()
}

/// A bounding sphere grown a little: f32 rounding must not put what it
/// bounds outside it.
fn grown(centre: Vec3, radius: f32) -> (Vec3, f32) {
    (
        centre,
        radius * (1.0 + 1e-5) + 1e-6 * centre.abs().max_element(),
    )
}

impl Deref for Proxies {
    type Target = ProxyShapes;

    fn deref(&self) -> &ProxyShapes {
        &self.shapes
    }
}

impl Proxies {
    /// The proxies of `mesh` (see `gpu::HemisphereRasterizer::new`).
    #[cfg(test)]
    pub(crate) fn build(mesh: &Mesh, pieces: u32) -> Self {
        Self::sharing(Arc::new(ProxyShapes::build(mesh, pieces)))
    }

    /// A rasteriser's walk over `shapes`.
    pub(crate) fn sharing(shapes: Arc<ProxyShapes>) -> Self {
        Self {
            shapes,
            near_first: None,
            max_threads: usize::MAX,
            scratch: std::sync::Mutex::default(),
        }
    }
}

impl ProxyShapes {
    /// The proxies of `mesh` (see `gpu::HemisphereRasterizer::new`).
    pub fn build(mesh: &Mesh, pieces: u32) -> Self {
        let mut corners = Vec::new();
        let mut element = Vec::new();
        let mut quads = Vec::new();
        let mut polygons = Vec::with_capacity(mesh.polygons.len());
        for (k, poly) in mesh.polygons.iter().enumerate() {
            let first = corners.len() as u32;
            let (mut lo, mut hi) = (Vec3::MAX, Vec3::MIN);
            for id in poly.elements.clone() {
                for p in mesh.elements[id as usize].corners {
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
            let outline = polygon_outline(mesh, poly);
            let quad = match outline {
                Some(c) if pieces > 0 => {
                    let (nu, nv) = (
                        poly.patch_grid[0] * poly.element_grid[0],
                        poly.patch_grid[1] * poly.element_grid[1],
                    );
                    let (su, sv) = (pieces.min(nu), pieces.min(nv));
                    let at = |u: f32, v: f32| crate::mesh::bilinear(&c, u, v);
                    for j in 0..sv {
                        for i in 0..su {
                            let (u0, u1) = (i as f32 / su as f32, (i + 1) as f32 / su as f32);
                            let (v0, v1) = (j as f32 / sv as f32, (j + 1) as f32 / sv as f32);
                            corners.push([at(u0, v0), at(u1, v0), at(u1, v1), at(u0, v1)]);
                            element.push(poly.elements.start);
                        }
                    }
                    quads.push(QuadGrid {
                        corners: c,
                        grid: [nu, nv, poly.element_grid[0], poly.element_grid[1]],
                    });
                    Some(quads.len() as u32 - 1)
                }
                _ => {
                    for id in poly.elements.clone() {
                        corners.push(mesh.elements[id as usize].corners);
                        element.push(id);
                    }
                    None
                }
            };
            polygons.push(PolygonProxies {
                proxies: first..corners.len() as u32,
                normal: poly.normal,
                centre: 0.5 * (lo + hi),
                radius: 0.5 * (hi - lo).length(),
                quad,
                solid: mesh.solid_of.get(k).copied().flatten(),
                corner: corners
                    .get(first as usize)
                    .map_or(Vec3::ZERO, |c: &[Vec3; 4]| c[0]),
            });
        }
        let blocks = block_spheres(&polygons);
        let solid_spheres = mesh
            .solids
            .iter()
            .map(|s| grown(0.5 * (s.lo + s.hi), 0.5 * (s.hi - s.lo).length()))
            .collect();
        Self {
            solid_spheres,
            corners,
            element,
            quads,
            polygons,
            blocks,
        }
    }
}

impl Proxies {
    /// Whether no polygon of block `b` can be drawn by this shot on this
    /// rank: the block's sphere is wholly behind the shooter's plane, wholly
    /// beyond its reach, or (over several ranks) shows in none of this
    /// rank's tiles. Each polygon's sphere lies inside the block's, so
    /// [`in_view`]'s plane and reach tests and [`Ownership::may_see`] would
    /// reject every one of them: skipping the block changes nothing drawn.
    fn block_out(
        &self,
        b: usize,
        shooter: &ShooterFrame,
        res: Resolution,
        ownership: Option<&Ownership>,
    ) -> bool {
        let (centre, radius) = self.blocks[b];
        let d = centre - shooter.centre;
        let dist = d.length();
        let slack = 1e-5 * (dist + radius);
        d.dot(shooter.normal) + radius < -slack
            || dist - radius > shooter.reach + slack
            || ownership.is_some_and(|o| !o.may_see(shooter.to_local(d), radius + slack, res))
    }

    /// Fills `self.instances` with a rectangle for every proxy the shooter can
    /// see, in proxy order (so the draw order, and with it every depth tie, is
    /// the same on every run), seam copies right after their originals. Large
    /// scenes split the polygons between threads and join the lists in order.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn collect_rects(
        &self,
        shooter: &ShooterFrame,
        outside: &[bool],
        res: Resolution,
        far: f32,
        ownership: Option<&Ownership>,
        occlusion: Option<(&mut OcclusionMap, Agree<'_>)>,
        scatter: Option<Scatter<'_>>,
        instances: &mut Vec<Instance>,
    ) -> Collected {
        instances.clear();
        // What the occlusion cull needs: per polygon drawn its rectangles'
        // range and nearest possible distance. Over several ranks each
        // draws its tiles' pieces only (not the packed lattice of 1 x 1
        // tiles, whose rectangles are not cut to the rank's cells).
        let culling = occlusion.is_some() && ownership.is_none_or(|o| o.place.clip);
        let threads = if self.corners.len() < PARALLEL_PROXIES {
            1
        } else {
            crate::parallel::cores().min(8).min(self.max_threads).max(1)
        };
        // Polygon `at`, in view: its rectangles into `out`, counted in `done`.
        let draw = |at: usize, poly: &PolygonProxies, out: &mut Drawn, done: &mut Collected| {
            // Over several ranks, a polygon whose bounding sphere holds
            // none of this rank's cells is left to the others before any
            // per-proxy work: the ranks divide the bounds.
            if let Some(o) = ownership {
                let c = shooter.to_local(poly.centre - shooter.centre);
                if !o.may_see(c, poly.radius, res) {
                    return;
                }
            }
            done.bounded += poly.proxies.len();
            let start = out.instances.len();
            done.rects += self.push_polygon(poly, shooter, res, far, ownership, &mut out.instances);
            if culling {
                let end = out.instances.len();
                out.polygons
                    .push((start, end, nearest(poly, shooter), at as u32));
            }
        };
        // Returns the rectangles drawn (each cut to a rank's tiles counts
        // once) and the proxies bounded.
        let visit = |polys: &[PolygonProxies], first: usize, out: &mut Drawn| {
            let mut done = Collected::default();
            let mut k = 0;
            while k < polys.len() {
                let at = first + k;
                // At each block's start (or the run's), skip it whole if it can.
                if (at % BLOCK == 0 || k == 0)
                    && self.block_out(at / BLOCK, shooter, res, ownership)
                {
                    k = ((at / BLOCK + 1) * BLOCK - first).min(polys.len());
                    continue;
                }
                let poly = &polys[k];
                k += 1;
                if in_view(at, poly, outside, shooter) {
                    draw(at, poly, out, &mut done);
                }
            }
            done
        };
        let mut drawn = Drawn {
            instances: std::mem::take(instances),
            ..Drawn::default()
        };
        // Ranks of a run, each its tiles cut out: the polygons are dealt.
        let dealt = ownership
            .filter(|o| o.place.clip)
            .zip(scatter)
            .map(|(o, scatter)| {
                let deal = Deal {
                    shooter,
                    outside,
                    res,
                    far,
                    place: o.place,
                };
                self.deal(&deal, threads, culling, scatter, &mut drawn)
            });
        let mut occlusion = occlusion;
        // One process drawing the whole hemisphere on one core fills the
        // map block by block, nearest first, and skips what it already
        // hides (on more cores the parallel walk below was as fast).
        let mut filled = None;
        let mut done = match (dealt, occlusion.as_mut()) {
            (Some(done), _) => done,
            (None, Some((map, _)))
                if culling && ownership.is_none() && self.near_first.unwrap_or(true) =>
            {
                let (done, held) =
                    self.visit_near_first(&draw, (shooter, outside), res, map, &mut drawn);
                filled = Some(held);
                done
            }
            (None, _) if threads <= 1 => visit(&self.polygons, 0, &mut drawn),
            (None, _) => self.visit_in_parallel(threads, &visit, &mut drawn),
        };
        if let (Some((map, agree)), true) = (occlusion, culling) {
            // The verdicts take every core, even where the walk kept to
            // one (beside the far receivers' scan, which has mostly ended
            // by now; the work is shared out as the threads come free).
            let verdict_threads = if self.corners.len() < PARALLEL_PROXIES {
                1
            } else {
                crate::parallel::cores().min(8)
            };
            let cull = drawn.cull_hidden(map, verdict_threads, agree, self.polygons.len(), filled);
            done.culled = Some(cull);
        }
        *instances = drawn.instances;
        done
    }

    /// How many proxies polygons `range` (cut to the polygons) hold.
    fn proxies_of(&self, range: std::ops::Range<usize>) -> usize {
        let polys = &self.polygons
            [range.start.min(self.polygons.len())..range.end.min(self.polygons.len())];
        polys.iter().map(|p| p.proxies.len()).sum()
    }

    /// `draw` block by block ([`BLOCK`] polygons in a bounding sphere),
    /// the nearest blocks first, each polygon's pieces added to `map` once
    /// drawn. A block whose sphere's cells are all covered nearer than the
    /// sphere's nearest point is skipped before any per-polygon work, and
    /// so is, in a block drawn, each solid whose sphere the map hides and
    /// each other polygon in view whose own sphere it hides (in a
    /// cluttered room most of them lie behind nearer cubes). The cull
    /// would have left every one of them out ([`nearest`] is never nearer
    /// than a sphere's nearest point): the same polygons
    /// survive it, in polygon order in `drawn`, and `map` holds what
    /// [`OcclusionMap::add_all`] of those drawn would. Returns the work and
    /// [`Filled`].
    fn visit_near_first<F>(
        &self,
        draw: &F,
        (shooter, outside): (&ShooterFrame, &[bool]),
        res: Resolution,
        map: &mut OcclusionMap,
        drawn: &mut Drawn,
    ) -> (Collected, Filled)
    where
        F: Fn(usize, &PolygonProxies, &mut Drawn, &mut Collected),
    {
        let mut order: Vec<(f32, usize)> = (0..self.blocks.len())
            .filter(|&b| !self.block_out(b, shooter, res, None))
            .map(|b| {
                let (c, r) = self.blocks[b];
                ((c - shooter.centre).length() - r, b)
            })
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        map.clear();
        let mut filled = Filled::default();
        let mut done = Collected::default();
        // (Poisoned only by a panic in an earlier walk: its contents are
        // cleared here anyway.)
        let mut scratch = self
            .scratch
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let part = &mut *scratch;
        part.instances.clear();
        part.polygons.clear();
        // Per block drawn: its index and its ranges in `part`.
        let mut ranges = Vec::new();
        for (nearest, b) in order {
            let (c, r) = self.blocks[b];
            // Near receivers are never culled (see [`nearest`]).
            if nearest > shooter.near {
                let local = shooter.to_local(c - shooter.centre);
                if let Some(rect) = sphere_cells(local, r, res, [true, true]) {
                    if map.hides_rect(rect, nearest) {
                        filled.skipped_cells += map.cells_held(rect);
                        done.skipped += self.proxies_of(b * BLOCK..(b + 1) * BLOCK);
                        continue;
                    }
                }
            }
            let lo = b * BLOCK;
            let hi = (lo + BLOCK).min(self.polygons.len());
            let (start, first) = (part.instances.len(), part.polygons.len());
            // The last solid looked at, and whether its sphere is hidden.
            let mut solid = (u32::MAX, false);
            for k in lo..hi {
                // The same test for each polygon's own sphere, against
                // what the nearer blocks and this one's polygons so far hold.
                let poly = &self.polygons[k];
                // Out of view costs less to find than hidden (back faces).
                if !in_view(k, poly, outside, shooter) {
                    continue;
                }
                // A solid's faces (consecutive polygons) are skipped at
                // once where its sphere is hidden; where it is not, most of
                // its faces in view show, so they go without their own test
                // (the cull finds the rest): a fifth off the walk in the
                // rooms of cubes, a seventh in a classroom.
                if let Some(s) = poly.solid {
                    if s != solid.0 {
                        let (c, r) = self.solid_spheres[s as usize];
                        let nearest = (c - shooter.centre).length() - r;
                        let hidden = nearest > shooter.near
                            && sphere_cells(
                                shooter.to_local(c - shooter.centre),
                                r,
                                res,
                                [true, true],
                            )
                            .is_some_and(|rect| map.hides_rect(rect, nearest));
                        solid = (s, hidden);
                    }
                    if solid.1 {
                        done.skipped += poly.proxies.len();
                        continue;
                    }
                }
                let sphere = (poly.centre - shooter.centre).length() - poly.radius;
                if sphere > shooter.near && poly.solid.is_none() {
                    let local = shooter.to_local(poly.centre - shooter.centre);
                    if let Some(rect) = sphere_cells(local, poly.radius, res, [true, true]) {
                        if map.hides_rect(rect, sphere) {
                            filled.skipped_cells += map.cells_held(rect);
                            done.skipped += poly.proxies.len();
                            continue;
                        }
                    }
                }
                let at = part.instances.len();
                draw(k, poly, part, &mut done);
                for inst in &part.instances[at..] {
                    filled.held += map.add(&piece(inst));
                }
            }
            ranges.push((b, start..part.instances.len(), first..part.polygons.len()));
        }
        ranges.sort_by_key(|r| r.0);
        drawn.instances.reserve(part.instances.len());
        drawn.polygons.reserve(part.polygons.len());
        for (_, rects, polygons) in ranges {
            let offset = drawn.instances.len() as isize - rects.start as isize;
            drawn.instances.extend_from_slice(&part.instances[rects]);
            drawn
                .polygons
                .extend(part.polygons[polygons].iter().map(|&(a, b, d, k)| {
                    let shift = |x: usize| (x as isize + offset) as usize;
                    (shift(a), shift(b), d, k)
                }));
        }
        (done, filled)
    }

    /// `visit` over contiguous runs of polygons with about equal proxy
    /// counts on `threads` threads, the parts joined in order into `drawn`.
    fn visit_in_parallel<F>(&self, threads: usize, visit: &F, drawn: &mut Drawn) -> Collected
    where
        F: Fn(&[PolygonProxies], usize, &mut Drawn) -> Collected + Sync,
    {
        let parts = self.on_runs(threads, |lo, hi| {
            let mut out = Drawn::default();
            let done = visit(&self.polygons[lo..hi], lo, &mut out);
            (out, done)
        });
        let mut done = Collected::default();
        for (part, n) in parts {
            let offset = drawn.instances.len();
            drawn.instances.extend_from_slice(&part.instances);
            drawn.polygons.extend(
                part.polygons
                    .iter()
                    .map(|&(a, b, d, k)| (a + offset, b + offset, d, k)),
            );
            done.rects += n.rects;
            done.bounded += n.bounded;
        }
        done
    }
}

impl Proxies {
    /// `run(lo, hi)` over contiguous runs of polygons with about equal
    /// proxy counts, one a thread (all of them at once on one), the results
    /// in polygon order.
    fn on_runs<T: Send>(&self, threads: usize, run: impl Fn(usize, usize) -> T + Sync) -> Vec<T> {
        if threads <= 1 {
            return vec![run(0, self.polygons.len())];
        }
        let per = self.corners.len().div_ceil(threads) as u32;
        let mut bounds = vec![0usize];
        for (k, poly) in self.polygons.iter().enumerate() {
            if poly.proxies.end >= per * bounds.len() as u32 && bounds.len() < threads {
                bounds.push(k + 1);
            }
        }
        bounds.push(self.polygons.len());
        bounds.dedup();
        crate::parallel::each(bounds.windows(2), |_, w| run(w[0], w[1]))
    }

    /// Pushes the rectangles of `poly`'s proxies (see [`push_piece`]);
    /// returns how many it drew uncut.
    fn push_polygon(
        &self,
        poly: &PolygonProxies,
        shooter: &ShooterFrame,
        res: Resolution,
        far: f32,
        ownership: Option<&Ownership>,
        out: &mut Vec<Instance>,
    ) -> usize {
        let (n, lookup) = self.polygon_frame(poly, shooter);
        poly.proxies
            .clone()
            .map(|i| {
                let d = self.local_corners(i, shooter);
                let element = self.element[i as usize];
                push_piece(out, &d, n, element, &lookup, res, far, ownership)
            })
            .sum()
    }

    /// `poly`'s normal in the shooter's frame and its element lookup.
    fn polygon_frame(&self, poly: &PolygonProxies, shooter: &ShooterFrame) -> (Vec3, Lookup) {
        let n = shooter.to_local(poly.normal);
        let lookup = poly.quad.map_or_else(Lookup::default, |q| {
            Lookup::new(&self.quads[q as usize], shooter, n)
        });
        (n, lookup)
    }

    /// Proxy `i`'s corners in the shooter's frame.
    fn local_corners(&self, i: u32, shooter: &ShooterFrame) -> [Vec3; 4] {
        self.corners[i as usize].map(|c| shooter.to_local(c - shooter.centre))
    }

    /// The cell rectangles of `poly`'s proxies, uncut, in the order
    /// [`Proxies::push_polygon`] draws them (each proxy's own, then its seam
    /// copy): what a dealing rank sends, the rest of each [`Instance`] left
    /// to the rank that draws it. Returns how many.
    fn bound_polygon(
        &self,
        poly: &PolygonProxies,
        shooter: &ShooterFrame,
        res: Resolution,
        far: f32,
        out: &mut Vec<Bound>,
    ) -> usize {
        let before = out.len();
        for i in poly.proxies.clone() {
            let d = self.local_corners(i, shooter);
            let Some(r) = cell_bounds(&d, res, far) else {
                continue;
            };
            let (own, copy) = seam_rects(&r, res);
            out.extend(
                std::iter::once(own)
                    .chain(copy)
                    .map(|rect| Bound { proxy: i, rect }),
            );
        }
        out.len() - before
    }

    /// The rectangles of a run of ranks, each drawing its tiles: this rank
    /// bounds its deal of the polygons (runs of them in turn), cuts their rectangles at every tile edge, and sends each
    /// piece to the rank whose tile holds it; from what it gets back it
    /// lays out its own tiles' pieces in polygon order. The view test and
    /// the cell rectangles are then computed once a polygon over the run
    /// (not once per rank whose tiles its sphere may touch), and every
    /// rank draws the very list [`Ownership::pieces`] would have given it.
    /// Returns this rank's counts (the run's sum to one process's).
    fn deal(
        &self,
        deal: &Deal<'_>,
        threads: usize,
        culling: bool,
        scatter: Scatter<'_>,
        drawn: &mut Drawn,
    ) -> Collected {
        let place = deal.place;
        let ranks = (place.grid[0] * place.grid[1]).max(1) as usize;
        let rank = (place.own[1] * place.grid[0] + place.own[0]) as usize;
        // Dealt in turn by runs of `unit` consecutive polygons: whole blocks
        // where the scene has eight or more a rank (a rank then skips the
        // others' blocks at once, and its polygons lie together: 8 % a shot
        // faster than single polygons at 8 ranks on cubes-b1), shorter runs
        // in small scenes, so that no rank is left without polygons.
        let unit = (self.polygons.len() / (8 * ranks)).clamp(1, BLOCK);
        let run = |lo: usize, hi: usize| -> (Vec<Vec<u32>>, Collected) {
            let mut out = vec![Vec::new(); ranks];
            let mut done = Collected::default();
            let (mut whole, mut heads) = (Vec::new(), Vec::new());
            let mut k = lo;
            while k < hi {
                let b = k / BLOCK;
                if (k % BLOCK == 0 || k == lo)
                    && ((unit == BLOCK && b % ranks != rank)
                        || self.block_out(b, deal.shooter, deal.res, None))
                {
                    k = ((b + 1) * BLOCK).min(hi);
                    continue;
                }
                let (at, poly) = (k, &self.polygons[k]);
                k += 1;
                if (at / unit) % ranks != rank || !in_view(at, poly, deal.outside, deal.shooter) {
                    continue;
                }
                done.bounded += poly.proxies.len();
                whole.clear();
                done.rects +=
                    self.bound_polygon(poly, deal.shooter, deal.res, deal.far, &mut whole);
                deal_pieces(&place, at as u32, &whole, &mut heads, &mut out);
            }
            (out, done)
        };
        // Runs in polygon order, so each rank's stream stays in order.
        let (mut out, mut done) = (vec![Vec::new(); ranks], Collected::default());
        for (part, n) in self.on_runs(threads, run) {
            for (o, p) in out.iter_mut().zip(part) {
                o.extend(p);
            }
            done.rects += n.rects;
            done.bounded += n.bounded;
        }
        let incoming = scatter(&out);
        // Each polygon came from one rank: its runs, sorted, are the order
        // one process would have drawn them in.
        let mut runs: Vec<(u32, usize, usize, usize)> = Vec::new();
        for (from, words) in incoming.iter().enumerate() {
            let mut at = 0;
            while let Some(&[polygon, count]) = words.get(at..at + 2) {
                let len = count as usize * BOUND_WORDS;
                if words.len() < at + 2 + len {
                    break;
                }
                runs.push((polygon, from, at + 2, len));
                at += 2 + len;
            }
        }
        runs.sort_unstable_by_key(|r| r.0);
        for (polygon, from, start, len) in runs {
            // Every rank numbers polygons and proxies alike.
            let Some(poly) = self.polygons.get(polygon as usize) else {
                continue;
            };
            let first = drawn.instances.len();
            let (n, lookup) = self.polygon_frame(poly, deal.shooter);
            let words = &incoming[from][start..start + len];
            for b in bytemuck::cast_slice::<u32, Bound>(words) {
                if poly.proxies.contains(&b.proxy) {
                    let d = self.local_corners(b.proxy, deal.shooter);
                    let element = self.element[b.proxy as usize];
                    drawn
                        .instances
                        .push(instance(&d, n, element, &lookup, b.rect));
                }
            }
            if culling {
                let nearest = nearest(poly, deal.shooter);
                drawn
                    .polygons
                    .push((first, drawn.instances.len(), nearest, polygon));
            }
        }
        done
    }
}

/// What a dealt bounds pass looks from and at (see [`Proxies::deal`]).
struct Deal<'a> {
    shooter: &'a ShooterFrame,
    outside: &'a [bool],
    res: Resolution,
    far: f32,
    /// This rank's place in the run's grid of tiles.
    place: TilePlace,
}

/// Words of one [`Bound`] on the wire.
const BOUND_WORDS: usize = std::mem::size_of::<Bound>() / 4;

/// How the rectangles travel between ranks (see [`Proxies::deal`]): each
/// rank's words for each rank, and back what each rank sent this one.
pub type Scatter<'a> = &'a mut dyn FnMut(&[Vec<u32>]) -> Vec<Vec<u32>>;

/// Appends polygon `polygon`'s rectangles `whole` (in order, uncut) to
/// `out[r]`, cut at every tile edge, each piece to the rank `r` whose
/// tile holds it, after a (polygon, count) head where the polygon has any.
/// A rank's pieces come in the order [`Ownership::pieces`] gives them.
/// `head` is scratch (where each rank's count is), kept between polygons.
fn deal_pieces(
    place: &TilePlace,
    polygon: u32,
    whole: &[Bound],
    head: &mut Vec<usize>,
    out: &mut [Vec<u32>],
) {
    head.clear();
    head.resize(out.len(), usize::MAX);
    for bound in whole {
        let r = bound.rect;
        for (x, ox) in tile_spans(place, r[0], r[1], 0) {
            for (y, oy) in tile_spans(place, r[2], r[3], 1) {
                let to = (oy * place.grid[0] + ox) as usize;
                let Some(words) = out.get_mut(to) else {
                    continue;
                };
                if head[to] == usize::MAX {
                    head[to] = words.len() + 1;
                    words.extend([polygon, 0]);
                }
                words[head[to]] += 1;
                let piece = Bound {
                    rect: [x[0], x[1], y[0], y[1]],
                    ..*bound
                };
                words.extend_from_slice(bytemuck::cast_slice(std::slice::from_ref(&piece)));
            }
        }
    }
}

/// The spans of `[lo, hi]` along `axis` in each tile that holds one of its
/// cell centres, with the tile's owner along the axis: what
/// [`Ownership::spans`] gives the owner, for every owner at once.
fn tile_spans(
    place: &TilePlace,
    lo: f32,
    hi: f32,
    axis: usize,
) -> impl Iterator<Item = ([f32; 2], u32)> {
    let (tile, grid) = (place.tile[axis].max(1), place.grid[axis].max(1));
    let cells = place.cells[axis] as i64;
    let (c0, c1) = (ceil_i(lo - 0.5).max(0), floor_i(hi - 0.5).min(cells - 1));
    // No tile where no cell centre lies in the span.
    let tiles = if c0 > c1 {
        0..0
    } else {
        (c0 as u32 / tile)..(c1 as u32 / tile + 1)
    };
    tiles.map(move |t| {
        let (start, end) = (t * tile, (t + 1) * tile);
        ([lo.max(start as f32), hi.min(end as f32)], t % grid)
    })
}

/// A shot's rectangles as they are collected, and what the occlusion cull
/// needs of them (filled only when culling).
/// A drawn rectangle as the occlusion map sees it.
fn piece(i: &Instance) -> Piece<'_> {
    Piece {
        rect: i.rect,
        edges: &i.edges,
        plane: i.plane,
    }
}

/// What [`Proxies::visit_near_first`] left in the map: the cells the drawn
/// rectangles hold (as [`OcclusionMap::add_all`] counts them), and the
/// cells of the spheres it skipped.
#[derive(Clone, Copy, Debug, Default)]
struct Filled {
    held: usize,
    skipped_cells: usize,
}

#[derive(Default)]
struct Drawn {
    instances: Vec<Instance>,
    /// Per polygon drawn: its rectangles (start, end), the least distance
    /// any point of it can be from the shooter (`None`: never culled, see
    /// [`nearest`]) and its index.
    polygons: Vec<(usize, usize, Option<f32>, u32)>,
}

impl Drawn {
    /// Leaves out every polygon whose rectangles the map (filled here from
    /// the rectangles themselves) says are covered nearer; returns how many
    /// rectangles went. A whole polygon or nothing: its elements are then
    /// all hidden, so their covered cells (the hybrid visibility's
    /// denominator, and a patch's visibility for its elements no cell
    /// centre hit) change no receiver's form factor. The order of the rest
    /// is kept. Returns what went.
    fn cull_hidden(
        &mut self,
        map: &mut OcclusionMap,
        threads: usize,
        agree: Agree<'_>,
        polygons: usize,
        filled: Option<Filled>,
    ) -> Culled {
        // Skipped blocks count as hidden cells (what the cull saved).
        let (held, skipped) = match filled {
            Some(f) => (f.held + f.skipped_cells, f.skipped_cells),
            None => {
                map.clear();
                (map.add_all(&self.instances, piece, threads), 0)
            }
        };
        // Each polygon's verdict in this rank's cells (read-only, so in
        // parallel where the scene is big).
        let (instances, records) = (&self.instances, &self.polygons);
        map.refresh();
        let map = &*map;
        let verdict = |k: usize, hide: &mut bool| {
            let (start, end, nearest, _) = records[k];
            *hide = nearest.is_some_and(|nearest| {
                instances[start..end]
                    .iter()
                    .all(|i| map.hides(&piece(i), nearest))
            });
        };
        let mut hidden = vec![false; records.len()];
        if threads <= 1 {
            hidden
                .iter_mut()
                .enumerate()
                .for_each(|(k, h)| verdict(k, h));
        } else {
            crate::sampling::in_parallel(&mut hidden, verdict);
        }
        // What every rank saw: a polygon is left out only where it is
        // hidden in every rank's cells (a rank that does not draw it has
        // none of its cells), so its elements are hidden in all.
        let hidden_cells: usize = skipped
            + records
                .iter()
                .zip(&hidden)
                .filter(|(_, &h)| h)
                .flat_map(|(r, _)| &instances[r.0..r.1])
                .map(|i| map.cells_held(i.rect))
                .sum::<usize>();
        let mut message = split_u64(held as u64).to_vec();
        message.extend(split_u64(hidden_cells as u64));
        message.extend(
            self.polygons
                .iter()
                .zip(&hidden)
                .filter(|(_, &h)| !h)
                .map(|(r, _)| r.3),
        );
        let all = agree(&message);
        let mut seen = vec![0u64; polygons.div_ceil(64)];
        let (mut all_held, mut all_hidden) = (0u64, 0u64);
        for part in &all {
            let Some((head, ids)) = part.split_first_chunk::<4>() else {
                continue;
            };
            all_held += join_u64(head[0], head[1]);
            all_hidden += join_u64(head[2], head[3]);
            for &k in ids {
                if let Some(w) = seen.get_mut(k as usize / 64) {
                    *w |= 1 << (k % 64);
                }
            }
        }
        let shown = |k: u32| seen[k as usize / 64] & (1 << (k % 64)) != 0;
        let mut culled = Culled {
            rects: 0,
            share: all_hidden as f64 / all_held.max(1) as f64,
        };
        // The survivors moved down, in order.
        let mut kept = 0;
        for (r, hide) in self.polygons.iter().zip(hidden) {
            if hide && !shown(r.3) {
                culled.rects += r.1 - r.0;
            } else {
                self.instances.copy_within(r.0..r.1, kept);
                kept += r.1 - r.0;
            }
        }
        self.instances.truncate(kept);
        culled
    }
}

/// How the ranks agree on what to leave out: every rank's message, in rank
/// order (one rank: its own).
pub type Agree<'a> = &'a mut dyn FnMut(&[u32]) -> Vec<Vec<u32>>;

fn split_u64(x: u64) -> [u32; 2] {
    [x as u32, (x >> 32) as u32]
}

fn join_u64(lo: u32, hi: u32) -> u64 {
    lo as u64 | (hi as u64) << 32
}

/// The least distance from the shooter's centre that any point of `poly`
/// can have: the larger of its plane's distance and its bounding sphere's;
/// `None` (never culled) for a polygon that may hold near receivers,
/// within `shooter.near`, whose hidden cells the split decision counts.
fn nearest(poly: &PolygonProxies, shooter: &ShooterFrame) -> Option<f32> {
    let sphere = (poly.centre - shooter.centre).length() - poly.radius;
    if sphere <= shooter.near {
        return None;
    }
    let plane = poly.normal.dot(poly.corner - shooter.centre).abs();
    Some(sphere.max(plane))
}

/// What [`Proxies::collect_rects`] did: work counted, not timed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Collected {
    /// Rectangles drawn (each cut to a rank's tiles counts once).
    pub(crate) rects: usize,
    /// Proxies whose cell rectangle was computed (the bounds pass's work).
    pub(crate) bounded: usize,
    /// Proxies the occlusion cull left out before bounding them (polygons
    /// in view, and every polygon of a block, that nearer ones hide: see
    /// [`Proxies::visit_near_first`]).
    pub(crate) skipped: usize,
    /// What the occlusion cull did, when it ran.
    pub(crate) culled: Option<Culled>,
}

/// What one occlusion cull left out, against what it looked at.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Culled {
    /// Rectangles left out (of [`Collected::rects`]).
    pub(crate) rects: usize,
    /// Over every rank: the share of the cells the rectangles held that
    /// lay in polygons hidden in the rank's cells (what the cull can save).
    pub(crate) share: f64,
}

/// asin of `x` in [0, 0.9] as atan2(x, sqrt(1 - x^2)), within 5e-7 rad
/// (f32 `asin` is a libm call, and the sphere test runs for every polygon
/// in view on every rank).
fn asin(x: f32) -> f32 {
    crate::numeric::atan2_f32(x, (1.0 - x * x).sqrt())
}

/// Conservative bounds, in cells ([x0, x1, y0, y1]; x may run below 0 or
/// past the last column, to be wrapped), of the directions from the
/// shooter to a sphere with centre `c` (in the shooter's frame) and radius
/// `r`, or `None` when the sphere comes so near the shooter that it could
/// fill any cell. The cone of half-angle asin(r / |c|) about `c` spans the
/// polar angles within that of `c`; seen from above, the sphere is a disc
/// of radius r at distance rho = |c.xy| from the axis, so unless it covers
/// the axis its azimuths lie within asin(r / rho) of `c`'s. A margin of
/// [`SPHERE_MARGIN`] cells covers the f32 arithmetic here and the
/// rectangles' own margin. Only the axes `split` says the ranks' tiles
/// divide are bounded (the other spans every cell): over 2 ranks the
/// tiles are columns of the hemisphere, and the polar bound would cost a
/// third of the test for nothing.
fn sphere_cells(c: Vec3, r: f32, res: Resolution, split: [bool; 2]) -> Option<[f32; 4]> {
    use std::f32::consts::FRAC_PI_2;
    let d = c.length();
    // Near or around the shooter the cone is wide; asin is steep there
    // (and a NaN, from a degenerate polygon, says nothing either).
    if r.is_nan() || r >= 0.9 * d {
        return None;
    }
    let (rows, cols) = (res.rows as f32, res.cols as f32);
    let rho = (c.x * c.x + c.y * c.y).sqrt();
    let (y0, y1) = if split[1] {
        let alpha = asin(r / d);
        let polar = crate::numeric::atan2_f32(rho, c.z);
        (
            (polar - alpha) / FRAC_PI_2 * rows - SPHERE_MARGIN,
            (polar + alpha) / FRAC_PI_2 * rows + SPHERE_MARGIN,
        )
    } else {
        (0.0, rows)
    };
    if !split[0] || r >= 0.9 * rho {
        return Some([0.0, cols, y0, y1]);
    }
    let beta = asin(r / rho);
    let azimuth = crate::numeric::atan2_f32(c.y, c.x);
    Some(azimuth_cells((azimuth, beta), cols, [y0, y1]))
}

/// A sphere's rectangle from its centre's azimuth (atan2's, in (-pi, pi])
/// and its half-width `beta` in azimuth, over rows `y`.
fn azimuth_cells((azimuth, beta): (f32, f32), cols: f32, [y0, y1]: [f32; 2]) -> [f32; 4] {
    use std::f32::consts::TAU;
    let azimuth = if azimuth < 0.0 {
        azimuth + TAU
    } else {
        azimuth
    };
    [
        (azimuth - beta) / TAU * cols - SPHERE_MARGIN,
        (azimuth + beta) / TAU * cols + SPHERE_MARGIN,
        y0,
        y1,
    ]
}

/// Cells of margin around a sphere's bounds (see [`sphere_cells`]): far more
/// than f32's error in the angles (1e-6 rad against 7.7e-4 rad cells even
/// at 2048 x 8192) and the cell rectangles' own 0.01-cell margin.
const SPHERE_MARGIN: f32 = 0.05;

/// Whether polygon `k` (`poly`) can show in the shooter's hemisphere: the
/// shooter never sees its own polygon, polygons wholly below its plane,
/// polygons whose plane passes through the shooter (edge-on: no solid
/// angle), the hidden back faces of solids it is outside of, or polygons
/// wholly beyond the frame's reach. The one cull both projections use.
pub(crate) fn in_view(
    k: usize,
    poly: &PolygonProxies,
    outside: &[bool],
    shooter: &ShooterFrame,
) -> bool {
    k as u32 != shooter.polygon
        && (poly.centre - shooter.centre).dot(shooter.normal) + poly.radius > 0.0
        && (poly.centre - shooter.centre).length() - poly.radius <= shooter.reach
        && !edge_on(poly, shooter)
        && !hidden_back_face(poly, outside, shooter)
}

/// Whether `poly`'s plane passes through the shooter's centre (to a
/// millionth of their distance and size): the polygon is seen edge-on and
/// covers no solid angle, but a cell ray from a point in its plane can meet
/// it at t = 0. Without this, the bottom face of a box resting on the
/// shooter's face (coplanar with it) covered the shooter's hemisphere, and
/// the light went to the box's back faces.
fn edge_on(poly: &PolygonProxies, shooter: &ShooterFrame) -> bool {
    let offset = (shooter.centre - poly.centre).dot(poly.normal).abs();
    offset <= 1e-6 * ((shooter.centre - poly.centre).length() + poly.radius)
}

/// Whether `poly` is a back face of a solid that the shooter is outside of
/// (`outside`, per solid): then a front face of the same solid is nearer in
/// every direction it covers, and it need not be drawn.
fn hidden_back_face(poly: &PolygonProxies, outside: &[bool], shooter: &ShooterFrame) -> bool {
    poly.solid
        .is_some_and(|s| outside.get(s as usize).copied().unwrap_or(false))
        && !poly.proxies.is_empty()
        && (shooter.centre - poly.corner).dot(poly.normal) < 0.0
}

/// The largest integer at most `x` (saturating; `x` is finite here).
fn floor_i(x: f32) -> i64 {
    let t = x as i64;
    if (t as f32) > x {
        t - 1
    } else {
        t
    }
}

/// The smallest integer at least `x` (saturating; `x` is finite here).
fn ceil_i(x: f32) -> i64 {
    let t = x as i64;
    if (t as f32) < x {
        t + 1
    } else {
        t
    }
}

/// Scenes with at least this many proxies find their rectangles on several threads.
const PARALLEL_PROXIES: usize = 8192;

/// One rank's place in a grid of tiles, per axis (columns, rows): tile
/// (p, t) of `tile` cells is the rank's when t mod grid[0] = own[0] and p
/// mod grid[1] = own[1], over a hemisphere of `cells`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct TilePlace {
    pub(crate) tile: [u32; 2],
    pub(crate) grid: [u32; 2],
    pub(crate) own: [u32; 2],
    pub(crate) cells: [u32; 2],
    /// Whether to clip each rectangle to the rank's tiles (one instance per
    /// tile it meets), so the rasteriser makes fragments only for this
    /// rank's cells instead of discarding the others' (off in lattice mode,
    /// whose 1 x 1 tiles are packed instead).
    pub(crate) clip: bool,
}

/// The tiles one rank of a grid owns ([`TilePlace`]), with the tables the
/// bounds read them through.
#[derive(Clone)]
pub(crate) struct Ownership {
    /// What the tables were made for.
    pub(crate) place: TilePlace,
    /// Per axis, where the rank's tiles lie (see [`OwnedCells`]).
    axes: [OwnedCells; 2],
}

/// Along one axis, per cell, where this rank's next tile starts and ends:
/// every rectangle on every rank asks which of its cells are the rank's,
/// and tables answer without the integer divisions (four an axis) that
/// made the question cost a third of a rank's bounds.
#[derive(Clone)]
struct OwnedCells {
    /// `next[c]`: the first cell at or after c in one of the rank's tiles
    /// (`cells` if none), for c in 0..=cells.
    next: Vec<u32>,
    /// `tile[c]` for a cell of the rank's: its tile's first cell and the
    /// one after its last (the tile's own edges, not clamped to the grid).
    tile: Vec<[u32; 2]>,
}

impl OwnedCells {
    fn new(tile: u32, grid: u32, own: u32, cells: u32) -> Self {
        let tile = tile.max(1);
        let grid = grid.max(1);
        let mut next = vec![cells; cells as usize + 1];
        let mut edges = vec![[0, 0]; cells as usize];
        for c in (0..cells).rev() {
            let t = c / tile;
            if t % grid == own {
                next[c as usize] = c;
                edges[c as usize] = [t * tile, (t + 1) * tile];
            } else {
                next[c as usize] = next[c as usize + 1];
            }
        }
        Self { next, tile: edges }
    }

    /// The first cell of the rank's whose centre is at or after `c0` and
    /// at most `c1`, if any (`c0`, `c1` already clamped to the grid).
    fn first(&self, c0: i64, c1: i64) -> Option<usize> {
        if c0 > c1 {
            return None;
        }
        let c = self.next[c0 as usize] as i64;
        (c <= c1).then_some(c as usize)
    }
}

impl Ownership {
    /// The tables of `place`.
    pub(crate) fn new(place: TilePlace) -> Self {
        let TilePlace {
            tile,
            grid,
            own,
            cells,
            ..
        } = place;
        Self {
            place,
            axes: [0, 1].map(|a| OwnedCells::new(tile[a], grid[a], own[a], cells[a])),
        }
    }

    /// The cells whose centres `[lo, hi]` holds along `axis`, clamped to
    /// the grid (empty when `c0 > c1`). (Whole cells in integers: f32 floor
    /// and ceil are library calls on the baseline x86-64 target, and this
    /// runs for every rectangle on every rank.)
    fn cell_range(&self, lo: f32, hi: f32, axis: usize) -> (i64, i64) {
        let cells = self.axes[axis].tile.len() as i64;
        (ceil_i(lo - 0.5).max(0), floor_i(hi - 0.5).min(cells - 1))
    }

    /// The spans of `[lo, hi]` along `axis` that lie in this rank's tiles.
    fn spans(&self, lo: f32, hi: f32, axis: usize) -> impl Iterator<Item = [f32; 2]> + '_ {
        let (c0, c1) = self.cell_range(lo, hi, axis);
        let owned = &self.axes[axis];
        let mut at = owned.first(c0, c1);
        std::iter::from_fn(move || {
            let c = at?;
            let [start, end] = owned.tile[c];
            at = owned.first((end as i64).min(owned.next.len() as i64 - 1), c1);
            Some([lo.max(start as f32), hi.min(end as f32)])
        })
    }

    /// Whether `[lo, hi]` holds the centre of a cell of this rank's along `axis`.
    fn holds_along(&self, lo: f32, hi: f32, axis: usize) -> bool {
        let (c0, c1) = self.cell_range(lo, hi, axis);
        self.axes[axis].first(c0, c1).is_some()
    }

    /// `rect` ([x0, x1, y0, y1] in cells) cut to each of this rank's tiles
    /// it meets. Tile edges fall on whole cells and cell centres on halves,
    /// so the pieces hold exactly the rank's cells of the rectangle.
    fn pieces(&self, rect: [f32; 4]) -> impl Iterator<Item = [f32; 4]> + '_ {
        self.spans(rect[0], rect[1], 0).flat_map(move |x| {
            self.spans(rect[2], rect[3], 1)
                .map(move |y| [x[0], x[1], y[0], y[1]])
        })
    }

    /// Whether the cell rectangle holds the centre of a cell of one of this rank's tiles.
    fn holds_own(&self, x0: f32, x1: f32, y0: f32, y1: f32) -> bool {
        self.holds_along(x0, x1, 0) && self.holds_along(y0, y1, 1)
    }

    /// Whether a sphere with centre `c` (in the shooter's frame) and radius
    /// `r` may show in a cell of this rank's tiles ([`sphere_cells`], on
    /// the axes the rank grid divides), its columns wrapped around the
    /// azimuth.
    pub(crate) fn may_see(&self, c: Vec3, r: f32, res: Resolution) -> bool {
        let split = self.place.grid.map(|g| g > 1);
        let Some([x0, x1, y0, y1]) = sphere_cells(c, r, res, split) else {
            return true;
        };
        let cols = self.place.cells[0] as f32;
        self.holds_own(x0, x1, y0, y1)
            || (x1 > cols && self.holds_own(x0 - cols, x1 - cols, y0, y1))
            || (x0 < 0.0 && self.holds_own(x0 + cols, x1 + cols, y0, y1))
    }
}

/// Adds the rectangle(s) of one planar quad `d` (corners in the shooter's frame)
/// of element `element` on a plane with normal `n`; with an `ownership`, only
/// rectangles that hold a cell of one of this rank's tiles, cut to them.
/// Returns how many rectangles (uncut) it drew: 0, 1 or 2 (the seam copy).
#[allow(clippy::too_many_arguments)]
fn push_piece(
    out: &mut Vec<Instance>,
    d: &[Vec3; 4],
    n: Vec3,
    element: u32,
    lookup: &Lookup,
    res: Resolution,
    far: f32,
    ownership: Option<&Ownership>,
) -> usize {
    let Some(r) = cell_bounds(d, res, far) else {
        return 0;
    };
    let mine =
        |rect: &[f32; 4]| ownership.is_none_or(|o| o.holds_own(rect[0], rect[1], r.y0, r.y1));
    let (own, copy) = seam_rects(&r, res);
    let (primary, wrapped) = (mine(&own), copy.filter(mine));
    if !primary && wrapped.is_none() {
        return 0;
    }
    let inst = instance(d, n, element, lookup, own);
    // Pieces of one rectangle go out together, in order, so every cell
    // sees the same fragments in the same order as if it were drawn whole.
    let mut push = |rect: [f32; 4]| match ownership {
        Some(o) if o.place.clip => out.extend(o.pieces(rect).map(|rect| Instance { rect, ..inst })),
        _ => out.push(Instance { rect, ..inst }),
    };
    if primary {
        push(inst.rect);
    }
    if let Some(rect) = wrapped {
        push(rect);
    }
    primary as usize + wrapped.is_some() as usize
}

/// A proxy's cell rectangle and, where it runs past the last column, its
/// copy one turn of azimuth back (the seam): the rectangles it is drawn in.
fn seam_rects(r: &CellRect, res: Resolution) -> ([f32; 4], Option<[f32; 4]>) {
    let cols = res.cols as f32;
    let copy = (r.x1 > cols).then_some([r.x0 - cols, r.x1 - cols, r.y0, r.y1]);
    ([r.x0, r.x1, r.y0, r.y1], copy)
}

/// What the fragment test needs of one planar quad `d` (corners in the
/// shooter's frame) of element `element` on a plane with normal `n`, drawn
/// over the cell rectangle `rect`.
fn instance(d: &[Vec3; 4], n: Vec3, element: u32, lookup: &Lookup, rect: [f32; 4]) -> Instance {
    // The shooter is in front when it is on the side n points to.
    let offset = n.dot(d[0]);
    let back = offset >= 0.0;
    // Inside <=> the direction is on the inner side of every edge plane; which
    // side is inner depends on the side the shooter sees.
    let sign = if back { 1.0 } else { -1.0 };
    let edges =
        std::array::from_fn(|k| (d[k].cross(d[(k + 1) % 4]).normalize_or_zero() * sign).to_array());
    Instance {
        rect,
        edges,
        plane: [n.x, n.y, n.z, offset],
        item: [element, back as u32],
        origin: lookup.origin,
        axis: lookup.axis,
        bilinear: lookup.bilinear,
        grid: lookup.grid,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seeded xorshift generator of numbers in [0, 1).
    fn uniform(mut seed: u64) -> impl FnMut() -> f32 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    /// Random quads around a shooter at the origin (z up), small and
    /// large, near and far, some reaching below the horizon.
    fn quads(count: usize) -> Vec<[Vec3; 4]> {
        let mut rnd = uniform(0x2545_f491_4f6c_dd1d);
        (0..count)
            .map(|_| {
                let dist = 0.2 + 20.0 * rnd() * rnd();
                let (phi, theta) = (1.7 * rnd(), std::f32::consts::TAU * rnd());
                let centre =
                    Vec3::new(phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos()) * dist;
                let size = dist * (0.002 + 0.5 * rnd() * rnd());
                let a = Vec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5).normalize() * size;
                let b = a.cross(centre).normalize() * size * (0.3 + rnd());
                [
                    centre - a - b,
                    centre + a - b,
                    centre + a + b,
                    centre - a + b,
                ]
            })
            .collect()
    }

    /// Every rank layout of a few rank counts at 128 x 512 (tiles as the
    /// renderer picks them, and the paper's 1 x 1 cells).
    fn layouts() -> Vec<Ownership> {
        let mut out = Vec::new();
        for (tile, grid) in [
            ([64, 32], [2, 1]),
            ([64, 32], [2, 2]),
            ([32, 16], [4, 2]),
            ([1, 1], [2, 1]),
            ([512, 16], [1, 3]),
            ([48, 20], [3, 2]),
        ] {
            for ox in 0..grid[0] {
                for oy in 0..grid[1] {
                    out.push(Ownership::new(TilePlace {
                        tile,
                        grid,
                        own: [ox, oy],
                        cells: [512, 128],
                        clip: tile != [1, 1],
                    }));
                }
            }
        }
        out
    }

    #[test]
    fn a_polygon_left_to_other_ranks_draws_nothing_in_this_ranks_tiles() {
        let res = Resolution {
            rows: 128,
            cols: 512,
        };
        let (mut kept, mut culled) = (0, 0);
        for d in quads(4000) {
            let (lo, hi) = d.iter().fold((Vec3::MAX, Vec3::MIN), |(lo, hi), &p| {
                (lo.min(p), hi.max(p))
            });
            let (centre, radius) = (0.5 * (lo + hi), 0.5 * (hi - lo).length());
            let n = (d[1] - d[0]).cross(d[3] - d[0]).normalize();
            for o in layouts() {
                let mut out = Vec::new();
                let drawn =
                    push_piece(&mut out, &d, n, 0, &Lookup::default(), res, 100.0, Some(&o));
                let may = o.may_see(centre, radius, res);
                assert!(
                    may || drawn == 0,
                    "a quad at {centre} (radius {radius}) draws {drawn} rectangles in tiles {:?} its sphere misses",
                    o.place.own
                );
                if may {
                    kept += 1;
                } else {
                    culled += 1;
                }
            }
        }
        // The cull has to pay: a quarter of these (a third when measured)
        // are left to other ranks before their rectangles are computed.
        assert!(
            4 * culled > culled + kept,
            "only {culled} of {} culled",
            culled + kept
        );
    }

    #[test]
    fn skipping_blocks_of_polygons_draws_the_same_rectangles() {
        // A room of 512 boxes: shots from patches all over it, whole
        // hemispheres and split groups' short reaches, one rank and several.
        let scene = crate::scene::open("cubes-8").expect("built-in scene");
        let mesh = Mesh::build(&scene, &crate::mesh::MeshSettings::default());
        let proxies = Proxies::build(&mesh, 4);
        let mut shapes = ProxyShapes::build(&mesh, 4);
        shapes.blocks.iter_mut().for_each(|b| b.1 = f32::INFINITY);
        let never = Proxies::sharing(Arc::new(shapes));
        let res = Resolution {
            rows: 128,
            cols: 512,
        };
        let outside = vec![true; mesh.solids.len()];
        let (mut skipped, mut all) = (0, 0);
        let owners: Vec<Option<Ownership>> = std::iter::once(None)
            .chain(layouts().into_iter().map(Some))
            .collect();
        for (k, patch) in mesh.patches.iter().enumerate().step_by(97) {
            let poly = &mesh.polygons[patch.polygon as usize];
            let frame = ShooterFrame::new(patch.centre, poly.normal, poly.tangent, patch.polygon);
            for shooter in [frame, frame.within(1.5)] {
                for o in owners.iter().skip(k % 3).step_by(3).map(Option::as_ref) {
                    let (mut a, mut b) = (Vec::new(), Vec::new());
                    let got =
                        proxies.collect_rects(&shooter, &outside, res, 1e3, o, None, None, &mut a);
                    let want =
                        never.collect_rects(&shooter, &outside, res, 1e3, o, None, None, &mut b);
                    assert_eq!(got, want, "patch {k}");
                    assert!(
                        bytemuck::cast_slice::<Instance, u8>(&a)
                            == bytemuck::cast_slice::<Instance, u8>(&b),
                        "patch {k}: other rectangles"
                    );
                    skipped += (0..proxies.blocks.len())
                        .filter(|&b| proxies.block_out(b, &shooter, res, o))
                        .count();
                    all += proxies.blocks.len();
                }
            }
        }
        // The blocks have to pay: half the room is behind a box's face, and
        // a split group's reach holds a few boxes (31 % skipped when written).
        assert!(4 * skipped > all, "{skipped} of {all} blocks skipped");
    }

    /// `p`'s rectangles for `shooter`, culled on one process.
    fn culled_walk(
        p: &Proxies,
        shooter: &ShooterFrame,
        outside: &[bool],
        res: Resolution,
        map: &mut OcclusionMap,
        out: &mut Vec<Instance>,
    ) -> Collected {
        let mut agree = |m: &[u32]| vec![m.to_vec()];
        p.collect_rects(
            shooter,
            outside,
            res,
            1e3,
            None,
            Some((map, &mut agree)),
            None,
            out,
        )
    }

    #[test]
    fn walking_blocks_nearest_first_leaves_the_same_rectangles_drawn() {
        // The cull's verdicts on what the nearest-first walk draws leave the
        // rectangles the plain walk leaves: what it skips (blocks and
        // polygons hidden behind nearer ones) the cull would have left out.
        let scene = crate::scene::open("cubes-8").expect("built-in scene");
        let mesh = Mesh::build(&scene, &crate::mesh::MeshSettings::default());
        let mut near = Proxies::build(&mesh, 1);
        near.near_first = Some(true);
        let mut plain = Proxies::build(&mesh, 1);
        plain.near_first = Some(false);
        let res = Resolution {
            rows: 128,
            cols: 512,
        };
        let outside = vec![true; mesh.solids.len()];
        let mut map = OcclusionMap::new(res);
        let (mut bounded, mut plain_bounded, mut culled) = (0, 0, 0);
        for (k, patch) in mesh.patches.iter().enumerate().step_by(53) {
            let poly = &mesh.polygons[patch.polygon as usize];
            let frame = ShooterFrame::new(patch.centre, poly.normal, poly.tangent, patch.polygon);
            for shooter in [frame, frame.within(1.5)] {
                let (mut a, mut b) = (Vec::new(), Vec::new());
                let got = culled_walk(&near, &shooter, &outside, res, &mut map, &mut a);
                let want = culled_walk(&plain, &shooter, &outside, res, &mut map, &mut b);
                assert!(
                    bytemuck::cast_slice::<Instance, u8>(&a)
                        == bytemuck::cast_slice::<Instance, u8>(&b),
                    "patch {k}: other rectangles drawn"
                );
                bounded += got.bounded;
                plain_bounded += want.bounded;
                culled += want.culled.map_or(0, |c| c.rects);
            }
        }
        assert!(culled > 0, "nothing hidden in the room");
        // It has to pay: 31 % fewer proxies bounded when written (the
        // 4096-cube room: 67 %).
        assert!(
            4 * bounded < 3 * plain_bounded,
            "nearest first bounded {bounded} proxies, the plain walk {plain_bounded}"
        );
    }

    /// The spans as they were computed before the tables: tile numbers by
    /// integer division, the reference the tables must match bit for bit.
    fn spans_by_division(o: &Ownership, lo: f32, hi: f32, axis: usize) -> Vec<[f32; 2]> {
        let p = o.place;
        let [tile, grid, own, cells] = [p.tile, p.grid, p.own, p.cells].map(|v| v[axis] as i64);
        let c0 = ceil_i(lo - 0.5).max(0);
        let c1 = floor_i(hi - 0.5).min(cells - 1);
        let (t0, t1) = (c0.div_euclid(tile), c1.div_euclid(tile));
        let first = t0 + (own - t0).rem_euclid(grid);
        let count = if c0 <= c1 && first <= t1 {
            ((t1 - first) / grid) as usize + 1
        } else {
            0
        };
        let tile = tile as f32;
        (0..count)
            .map(|k| {
                let t = (first + k as i64 * grid) as f32;
                [lo.max(t * tile), hi.min((t + 1.0) * tile)]
            })
            .collect()
    }

    #[test]
    fn the_tiles_tables_give_the_divisions_spans_bit_for_bit() {
        let mut rnd = uniform(0x5851_f42d_4c95_7f2d);
        let mut spans = 0;
        for o in layouts() {
            for _ in 0..4000 {
                for axis in 0..2 {
                    let n = o.place.cells[axis] as f32;
                    // Wide and narrow, inside, across and beyond the grid,
                    // some on whole and half cells exactly.
                    let mut lo = rnd() * (n + 40.0) - 20.0;
                    let mut hi = lo + rnd() * rnd() * n;
                    if rnd() < 0.2 {
                        (lo, hi) = ((lo * 2.0).round() / 2.0, (hi * 2.0).round() / 2.0);
                    }
                    let want = spans_by_division(&o, lo, hi, axis);
                    let got: Vec<[f32; 2]> = o.spans(lo, hi, axis).collect();
                    // Bit for bit, but for the sign of a zero: f32::max
                    // of -0 and +0 may give either, as inlining falls.
                    let bits = |v: &[[f32; 2]]| {
                        v.iter()
                            .map(|s| s.map(|x| (x + 0.0).to_bits()))
                            .collect::<Vec<_>>()
                    };
                    assert_eq!(
                        bits(&got),
                        bits(&want),
                        "[{lo}, {hi}] on axis {axis} of tiles {:?} {:?}",
                        o.place.own,
                        o.place.tile
                    );
                    assert_eq!(o.holds_along(lo, hi, axis), !want.is_empty());
                    spans += want.len();
                }
            }
        }
        assert!(spans > 10_000, "only {spans} spans met");
    }

    #[test]
    fn a_rectangles_pieces_hold_exactly_the_ranks_cells_it_holds() {
        let mut rnd = uniform(0x9e37_79b9_7f4a_7c15);
        let centre_in = |r: &[f32; 4], x: u32, y: u32| {
            let (cx, cy) = (x as f32 + 0.5, y as f32 + 0.5);
            r[0] <= cx && cx <= r[1] && r[2] <= cy && cy <= r[3]
        };
        for o in layouts() {
            let own = |x: u32, y: u32| {
                let p = o.place;
                let (tx, ty) = (x / p.tile[0], y / p.tile[1]);
                tx % p.grid[0] == p.own[0] && ty % p.grid[1] == p.own[1]
            };
            for _ in 0..40 {
                let (x0, y0) = (rnd() * 560.0 - 20.0, rnd() * 140.0 - 6.0);
                let rect = [x0, x0 + rnd() * 200.0, y0, y0 + rnd() * 60.0];
                let pieces: Vec<[f32; 4]> = o.pieces(rect).collect();
                let mut holds = false;
                for y in 0..128 {
                    for x in 0..512 {
                        let want = own(x, y) && centre_in(&rect, x, y);
                        let got = pieces.iter().filter(|p| centre_in(p, x, y)).count();
                        assert_eq!(
                            got, want as usize,
                            "cell ({x}, {y}) of {rect:?} in tiles {:?}",
                            o.place.own
                        );
                        holds |= want;
                    }
                }
                assert_eq!(
                    o.holds_own(rect[0], rect[1], rect[2], rect[3]),
                    holds,
                    "{rect:?}"
                );
            }
        }
    }

    #[test]
    fn a_dealt_rectangle_gives_each_rank_the_pieces_its_tiles_would_cut() {
        let mut rnd = uniform(0x2545_f491_4f6c_dd1d);
        for o in layouts().into_iter().filter(|o| o.place.clip) {
            let p = o.place;
            let ranks = (p.grid[0] * p.grid[1]) as usize;
            let rank = (p.own[1] * p.grid[0] + p.own[0]) as usize;
            for k in 0..200u32 {
                // Three rectangles of one polygon, some across the seam or
                // off the grid, some on whole and half cells.
                let whole: Vec<Bound> = (0..3)
                    .map(|_| {
                        let v: [f32; 8] = std::array::from_fn(|_| rnd());
                        let snap = |x: f32, u: f32| {
                            if u < 0.3 {
                                (x * 2.0).round() / 2.0
                            } else {
                                x
                            }
                        };
                        let (x0, y0) = (
                            snap(v[0] * 600.0 - 40.0, v[4]),
                            snap(v[1] * 150.0 - 10.0, v[5]),
                        );
                        Bound {
                            proxy: k,
                            rect: [
                                x0,
                                snap(x0 + v[2] * 150.0, v[6]),
                                y0,
                                snap(y0 + v[3] * 50.0, v[7]),
                            ],
                        }
                    })
                    .collect();
                let mut out = vec![Vec::new(); ranks];
                deal_pieces(&p, k, &whole, &mut Vec::new(), &mut out);
                let want: Vec<[f32; 4]> = whole.iter().flat_map(|i| o.pieces(i.rect)).collect();
                let got: Vec<[f32; 4]> = match out[rank].split_first_chunk::<2>() {
                    None => Vec::new(),
                    Some(([polygon, count], words)) => {
                        assert_eq!(*polygon, k);
                        assert_eq!(words.len(), *count as usize * BOUND_WORDS);
                        bytemuck::cast_slice::<u32, Bound>(words)
                            .iter()
                            .map(|b| {
                                assert_eq!(b.proxy, k);
                                b.rect
                            })
                            .collect()
                    }
                };
                // Bit for bit, in the same order.
                let bits = |v: &[[f32; 4]]| -> Vec<[u32; 4]> {
                    v.iter().map(|r| r.map(f32::to_bits)).collect()
                };
                assert_eq!(bits(&got), bits(&want), "{:?} rank {rank}", p);
            }
        }
    }

    #[test]
    fn dealt_bounds_give_every_rank_the_rectangles_it_would_find_itself() {
        // A room of 512 boxes, shots from patches all over it, on thread
        // ranks of several grids: each rank's dealt list is its own list,
        // bit for bit, and the ranks bound each proxy once between them.
        let scene = crate::scene::open("cubes-8").expect("built-in scene");
        let mesh = Mesh::build(&scene, &crate::mesh::MeshSettings::default());
        let proxies = Proxies::build(&mesh, 1);
        let res = Resolution {
            rows: 128,
            cols: 512,
        };
        let outside = vec![true; mesh.solids.len()];
        for (tile, grid) in [([64, 32], [2, 1]), ([32, 16], [2, 2]), ([48, 20], [3, 1])] {
            let ranks = (grid[0] * grid[1]) as usize;
            let place = |rank: usize| TilePlace {
                tile,
                grid,
                own: [rank as u32 % grid[0], rank as u32 / grid[0]],
                cells: [512, 128],
                clip: true,
            };
            for (k, patch) in mesh.patches.iter().enumerate().step_by(131) {
                let poly = &mesh.polygons[patch.polygon as usize];
                let shooter =
                    ShooterFrame::new(patch.centre, poly.normal, poly.tangent, patch.polygon);
                let (proxies, outside) = (&proxies, &outside);
                let dealt = crate::parallel::ThreadComm::run(ranks, |comm| {
                    use crate::parallel::Collectives;
                    let o = Ownership::new(place(comm.rank()));
                    let mut scatter = |out: &[Vec<u32>]| comm.all_to_all_u32(out);
                    let collect = |scatter: Option<Scatter<'_>>, out: &mut Vec<Instance>| {
                        let o = Some(&o);
                        proxies.collect_rects(&shooter, outside, res, 1e3, o, None, scatter, out)
                    };
                    let (mut mine, mut theirs) = (Vec::new(), Vec::new());
                    let done = collect(Some(&mut scatter), &mut mine);
                    collect(None, &mut theirs);
                    let same = bytemuck::cast_slice::<Instance, u8>(&mine)
                        == bytemuck::cast_slice::<Instance, u8>(&theirs);
                    (same, done.bounded)
                });
                let mut whole = Vec::new();
                let one = proxies
                    .collect_rects(&shooter, outside, res, 1e3, None, None, None, &mut whole);
                for (rank, (same, _)) in dealt.iter().enumerate() {
                    assert!(
                        same,
                        "patch {k}, grid {grid:?}: rank {rank} drew other rectangles"
                    );
                }
                let bounded: usize = dealt.iter().map(|d| d.1).sum();
                assert_eq!(bounded, one.bounded, "patch {k}, grid {grid:?}");
            }
        }
    }
}
