//! Discretisation: polygons -> patches (shooters) -> elements (receivers), on
//! uniform grids (bilinear for quads, barycentric lattices for triangles).
//!
//! # The automatic subdivision rule
//! A shooter is treated as a point at its centre, which overestimates the form
//! factor to receivers that are near compared with the shooter's size (two unit
//! squares 1 apart: about 20 % high with one patch, 0.6 % with 5 x 5). The error
//! falls roughly as (s / h)^2 for patch size s and distance h. For every pair of
//! polygons P, Q that face each other (each centre in front of the other), at
//! centre distance h, P's patches may be at most `near_field_ratio * h`, relaxed
//! by sqrt(0.2 / F) (up to h) when the disk estimate F = A_Q cos cos / (pi h^2 + A_Q)
//! of the form factor P -> Q is below 0.2: a pair that exchanges little light
//! matters little to the solution. P takes the smallest size over all Q;
//! polygons that nothing faces stay one patch. Each patch gets 2 x 2 elements.
//! Both counts are capped per edge.
//! A node's `extras.radiosity` overrides it, and `--patch-size` / `--element-size`
//! (given for one run) override both.

use crate::scene::{Polygon, Scene};
use glam::Vec3;
use std::ops::Range;

/// How polygons are subdivided.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct MeshSettings {
    /// Fixed patch edge length in metres (automatic when `None`).
    pub patch_size: Option<f32>,
    /// Fixed element edge length in metres (2 x 2 elements per patch when `None`).
    pub element_size: Option<f32>,
    /// Automatic rule: patch size as a fraction of the distance to the nearest facing polygon.
    pub near_field_ratio: f32,
    /// Cap on patches along one polygon edge.
    pub max_patches_per_edge: u32,
    /// Cap on elements along one patch edge.
    pub max_elements_per_edge: u32,
    /// Refinement passes by need (`refine`): the automatic rule starts
    /// `2^refine` times coarser (patches up to `near_field_ratio * 2^refine`
    /// of the distance, at most the distance), and each pass doubles the
    /// patch grid of the polygons whose shots ask for it.
    pub refine: u32,
    /// Refinement by need also doubles the patch grid of a polygon one of
    /// whose patches holds its light so unevenly that a uniform patch would
    /// misplace more than this fraction of the emitted power
    /// (`refine`); 0: receivers never ask.
    pub receiver_tol: f64,
    /// Refinement by need also doubles the patch grid of a polygon one of
    /// whose patches the camera image would shade with a relative error
    /// above this (`refine::shading_error`); 0: never.
    pub shading_tol: f64,
}

/// The default of [`MeshSettings::receiver_tol`]: chosen on the Cornell box
/// and seed 1 of the scene family against their path-traced images (0.002
/// refined too few receivers; 0.0002 cost 1.5-3x the solve time for little
/// more), judged on seed 2 (docs/guide/meshing.md, "Refinement by need").
pub const DEFAULT_RECEIVER_TOL: f64 = 5e-4;

/// The default of [`MeshSettings::shading_tol`].
pub const DEFAULT_SHADING_TOL: f64 = 0.08;

impl Default for MeshSettings {
    fn default() -> Self {
        Self {
            patch_size: None,
            element_size: None,
            near_field_ratio: 0.2,
            max_patches_per_edge: 32,
            max_elements_per_edge: 16,
            refine: 1,
            receiver_tol: DEFAULT_RECEIVER_TOL,
            shading_tol: DEFAULT_SHADING_TOL,
        }
    }
}

/// Above this many polygons the O(N^2) nearest-facing-polygon search is
/// skipped and patches default to 1/32 of the scene's extent.
const AUTO_SEARCH_LIMIT: usize = 20_000;

/// Per-polygon data the solver and renderers share.
#[derive(Clone, Debug)]
pub struct MeshPolygon {
    /// Index of the glTF node (see [`Scene::nodes`]).
    pub node: usize,
    /// Front normal.
    pub normal: Vec3,
    /// Unit tangent along the first edge (the shooter frame's x axis).
    pub tangent: Vec3,
    /// Reflectance per channel.
    pub reflectance: [f64; 3],
    /// Emitted radiosity (exitance) E = pi * L_e per channel, W/m^2.
    pub exitance: [f64; 3],
    /// The back side of a double-sided surface (see [`crate::scene::Polygon::back_side`]).
    pub back_side: bool,
    /// Whether a texture gives its elements their reflectances.
    pub textured: bool,
    /// Where an emissive texture gives its elements their own exitances
    /// (`exitance` is then the texture's mean over the polygon): the index
    /// of its first element's in [`Mesh::textured_exitance`].
    pub emission_texels: Option<u32>,
    /// Patches of this polygon.
    pub patches: Range<u32>,
    /// Elements of this polygon.
    pub elements: Range<u32>,
    /// Patch grid (triangles: [n, n]).
    pub patch_grid: [u32; 2],
    /// Elements per patch (triangles: [m, m]).
    pub element_grid: [u32; 2],
}

impl MeshPolygon {
    /// Whether the polygon emits light.
    pub fn emits(&self) -> bool {
        self.exitance.iter().any(|&x| x > 0.0)
    }
}

/// A shooting patch.
#[derive(Clone, Debug)]
pub struct Patch {
    /// Owning polygon.
    pub polygon: u32,
    /// Area-weighted centre: where the hemisphere is placed.
    pub centre: Vec3,
    /// Area in m^2.
    pub area: f64,
    /// Its elements (contiguous).
    pub elements: Range<u32>,
    /// Its outline, counter-clockwise (a triangle repeats its last corner):
    /// what receiver-side analytic form factors integrate over.
    pub corners: [Vec3; 4],
}

/// A receiving element: a small planar quad or triangle.
#[derive(Clone, Debug)]
pub struct Element {
    /// Owning patch.
    pub patch: u32,
    /// Owning polygon.
    pub polygon: u32,
    /// Corners counter-clockwise; a triangle repeats its last corner.
    pub corners: [Vec3; 4],
    /// Area in m^2.
    pub area: f64,
    /// Shading-vertex indices of the corners (shared within a polygon).
    pub vertices: [u32; 4],
    /// Reflectance per channel: its polygon's, or, on a textured polygon,
    /// the texture's mean over the element times the factor.
    pub reflectance: [f64; 3],
    /// Centroid (see [`element_centre`]), kept: every shot evaluates its
    /// receivers' form factors there.
    pub centre: Vec3,
}

/// The discretised scene.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// One per scene polygon, same order.
    pub polygons: Vec<MeshPolygon>,
    /// All patches, polygon by polygon.
    pub patches: Vec<Patch>,
    /// All elements, patch by patch.
    pub elements: Vec<Element>,
    /// Positions of the shading vertices (element corners, shared within a polygon).
    pub vertices: Vec<Vec3>,
    /// The closed solids among the scene's nodes (see [`Solid`]).
    pub solids: Vec<Solid>,
    /// Per polygon, the solid it bounds, if any (an index into `solids`).
    pub solid_of: Vec<Option<u32>>,
    /// The scene's polygons for exact ray queries ([`Mesh::enclosed`]).
    pub occluders: crate::raytrace::Bvh,
    /// How far a ray starts off its surface, m (1e-5 of the scene's size).
    pub ray_offset: f32,
    /// The exitances of the elements of polygons with an emissive texture
    /// (each the texture's mean over the element), polygon by polygon (see
    /// [`MeshPolygon::emission_texels`]); empty when no polygon has one.
    pub textured_exitance: Vec<[f64; 3]>,
}

/// A glTF node whose polygons close a volume with their fronts facing out (a
/// box, say): every edge is shared by exactly two of its polygons, wound
/// oppositely. Seen from outside its bounding box, a ray meets one of its
/// front faces before any of its back faces, so a shot from there need not
/// draw its back faces (they can hide nothing the front ones do not).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Solid {
    /// Bounding box, grown by a margin: inside it, draw everything.
    pub lo: Vec3,
    /// See `lo`.
    pub hi: Vec3,
}

impl Solid {
    /// Whether `p` is in the (grown) bounding box.
    pub fn holds(&self, p: Vec3) -> bool {
        p.cmpge(self.lo).all() && p.cmple(self.hi).all()
    }
}

/// Finds the closed, outward-facing solids among `polygons` (see [`Solid`]):
/// each node's polygons are split into pieces connected by shared edges (a
/// node of 64 separate cubes gives 64 solids), and each piece is a solid when
/// it is closed and faces out. Vertices match when they agree to a millionth
/// of the node's size; T-junctions, holes, doubled faces or inward-facing
/// pieces (a room seen from inside) are not solids. Returns the solids and,
/// per polygon, the solid it bounds.
pub fn find_solids(polygons: &[crate::scene::Polygon]) -> (Vec<Solid>, Vec<Option<u32>>) {
    let mut by_node: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for (i, p) in polygons.iter().enumerate() {
        by_node.entry(p.node).or_default().push(i);
    }
    let mut solids = Vec::new();
    let mut solid_of = vec![None; polygons.len()];
    for members in by_node.values() {
        if members.len() < 4 {
            continue;
        }
        for piece in closed_pieces(polygons, members) {
            let Some(solid) = outward_solid(polygons, members, &piece) else {
                continue;
            };
            let index = solids.len() as u32;
            solids.push(solid);
            for &m in &piece {
                solid_of[members[m]] = Some(index);
            }
        }
    }
    (solids, solid_of)
}

/// The closed pieces of one node's polygons (`members`, indices into
/// `polygons`): polygons joined by shared edges, each edge matched exactly
/// once the other way round. Pieces hold indices into `members`.
fn closed_pieces(polygons: &[crate::scene::Polygon], members: &[usize]) -> Vec<Vec<usize>> {
    type Key = [i64; 3];
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for &i in members {
        for &v in &polygons[i].vertices {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    let size = (hi - lo).length() as f64;
    if !(size > 0.0 && size.is_finite()) {
        return Vec::new();
    }
    let eps = 1e-6 * size;
    let key = |v: Vec3| -> Key {
        let q = |x: f32| (x as f64 / eps).round() as i64;
        [q(v.x), q(v.y), q(v.z)]
    };
    // Directed edges (counter-clockwise about each normal) and their owners.
    let mut edges: std::collections::HashMap<(Key, Key), (u32, usize)> = Default::default();
    for (m, &i) in members.iter().enumerate() {
        let v = &polygons[i].vertices;
        for k in 0..v.len() {
            let (a, b) = (key(v[k]), key(v[(k + 1) % v.len()]));
            if a != b {
                edges.entry((a, b)).or_insert((0, m)).0 += 1;
            }
        }
    }
    // Connected pieces: polygons joined by a shared edge (union-find).
    let mut parent: Vec<usize> = (0..members.len()).collect();
    fn root(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    // A piece is open if any of its edges is not matched exactly once,
    // the other way round.
    let mut open = vec![false; members.len()];
    for (&(a, b), &(count, m)) in &edges {
        match edges.get(&(b, a)) {
            Some(&(back, n)) if count == 1 && back == 1 => {
                let (ra, rb) = (root(&mut parent, m), root(&mut parent, n));
                parent[ra] = rb;
            }
            _ => open[m] = true,
        }
    }
    let mut pieces: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for m in 0..members.len() {
        let r = root(&mut parent, m);
        pieces.entry(r).or_default().push(m);
    }
    pieces
        .into_values()
        .filter(|piece| piece.len() >= 4 && !piece.iter().any(|&m| open[m]))
        .collect()
}

/// The solid a closed piece bounds, if its normals face out (the volume
/// the divergence theorem gives is positive), with a grown bounding box.
fn outward_solid(
    polygons: &[crate::scene::Polygon],
    members: &[usize],
    piece: &[usize],
) -> Option<Solid> {
    let (mut plo, mut phi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for &m in piece {
        for &v in &polygons[members[m]].vertices {
            plo = plo.min(v);
            phi = phi.max(v);
        }
    }
    let centre = (0.5 * (plo + phi)).as_dvec3();
    let volume: f64 = piece
        .iter()
        .map(|&m| {
            let p = &polygons[members[m]];
            let c = p.vertices.iter().map(|v| v.as_dvec3()).sum::<glam::DVec3>()
                / p.vertices.len() as f64;
            p.area() as f64 * (c - centre).dot(p.normal.as_dvec3()) / 3.0
        })
        .sum();
    let psize = (phi - plo).length() as f64;
    if volume <= 1e-9 * psize * psize * psize {
        return None;
    }
    let margin = Vec3::splat((1e-4 * psize) as f32);
    Some(Solid {
        lo: plo - margin,
        hi: phi + margin,
    })
}

/// Points per element along each axis for its texture mean.
const TEXTURE_POINTS: u32 = 4;

impl Mesh {
    /// Gives the elements from `first` on (all of `poly`'s) their
    /// textures' means: reflectance (or the polygon's), and, with an
    /// emissive texture, exitance in [`Mesh::textured_exitance`], whose
    /// index of the first it returns.
    fn texture_elements(&mut self, poly: &Polygon, first: usize) -> Option<u32> {
        let refl = poly.reflectance.map(f64::from);
        for e in &mut self.elements[first..] {
            e.reflectance = match &poly.texture {
                Some(map) => texture_mean(map, e)
                    .map(|x| f64::from(x.min(crate::scene::texture::MAX_REFLECTANCE))),
                None => refl,
            };
        }
        let map = poly.emissive.as_ref()?;
        let start = self.textured_exitance.len() as u32;
        for e in &self.elements[first..] {
            let le = texture_mean(map, e);
            let exitance = le.map(|l| std::f64::consts::PI * f64::from(l));
            self.textured_exitance.push(exitance);
        }
        Some(start)
    }
}

/// The factor times `map`'s texture's mean over element `e`, from the
/// midpoints of a [`TEXTURE_POINTS`]-square grid over it.
fn texture_mean(map: &crate::scene::TexMap, e: &Element) -> [f32; 3] {
    let corners: &[Vec3] = if e.corners[3] == e.corners[2] {
        &e.corners[..3]
    } else {
        &e.corners
    };
    map.mean(
        &crate::scene::texture::grid_points(corners, TEXTURE_POINTS),
        e.area as f32,
    )
}

impl Mesh {
    /// Subdivides every polygon of `scene`.
    pub fn build(scene: &Scene, settings: &MeshSettings) -> Mesh {
        Self::build_refined(scene, settings, &[])
    }

    /// Subdivides every polygon of `scene`, multiplying polygon i's patch grid
    /// by `factors[i]` along each edge (within the cap; each patch keeps its
    /// element grid); missing factors are 1.
    pub fn build_refined(scene: &Scene, settings: &MeshSettings, factors: &[u32]) -> Mesh {
        let sizes = patch_sizes(scene, settings);
        let mut mesh = Mesh::default();
        for (pi, (poly, &size)) in scene.polygons.iter().zip(&sizes).enumerate() {
            let f = factors.get(pi).copied().unwrap_or(1);
            mesh.add_polygon(pi as u32, poly, size, settings, f);
        }
        (mesh.solids, mesh.solid_of) = find_solids(&scene.polygons);
        mesh.occluders = crate::raytrace::Bvh::new(&scene.polygons);
        mesh.ray_offset = 1e-5 * scene.extent().max(1e-6);
        mesh
    }

    /// Where a hemisphere for `elements` of polygon `polygon` can stand:
    /// their area centroid if it lies outside every closed solid, else the
    /// area-weighted centroid of their points (centres and corners, drawn a
    /// tenth of the way in) that lie outside, or, if that too is inside one,
    /// the nearest of those points. `None` when every point is inside.
    pub fn open_centre<'a>(
        &self,
        polygon: u32,
        elements: impl Iterator<Item = &'a Element> + Clone,
    ) -> Option<Vec3> {
        let centre = area_centroid(elements.clone())?;
        if !self.enclosed(centre, polygon) {
            return Some(centre);
        }
        let mut open = Vec::new();
        let (mut sum, mut weight) = (glam::DVec3::ZERO, 0.0);
        for e in elements {
            let points = [
                e.centre,
                e.corners[0],
                e.corners[1],
                e.corners[2],
                e.corners[3],
            ];
            for q in points.map(|c| c + (e.centre - c) * 0.1) {
                if !self.enclosed(q, polygon) {
                    open.push(q);
                    sum += q.as_dvec3() * e.area;
                    weight += e.area;
                }
            }
        }
        if open.is_empty() {
            return None;
        }
        let centre = (sum / weight).as_vec3();
        if !self.enclosed(centre, polygon) {
            return Some(centre);
        }
        open.into_iter().min_by(|a, b| {
            a.distance_squared(centre)
                .total_cmp(&b.distance_squared(centre))
        })
    }

    /// Whether the point `p` of polygon `polygon` lies inside a closed
    /// solid (under a box resting on the floor, say, or inside a box that
    /// touches this one), so that a hemisphere there would see only back
    /// faces: a ray from it along the polygon's normal meets a back face
    /// first. Where a back face coincides with a front face (the top of a
    /// box under the bottom of the box stacked on it) the back face counts
    /// first. Faces are oriented as their surfaces are: the back-side copy
    /// of a double-sided surface counts as the original seen from behind, so
    /// a double-sided box is a solid too. (The inside of a room whose walls
    /// are two one-sided faces back to back counts as inside a solid too:
    /// one ray cannot tell it from stacked boxes; five rays and a vote were
    /// tried and lost light on stacked boxes, see docs/accuracy.md.)
    pub fn enclosed(&self, p: Vec3, polygon: u32) -> bool {
        let n = self.polygons[polygon as usize].normal;
        let origin = p + n * self.ray_offset;
        self.occluders
            .nearest_facing(origin, n, 0.0, f32::INFINITY, -1e-5)
            .is_some_and(|hit| {
                let q = &self.polygons[hit.polygon as usize];
                let facing = if q.back_side { -q.normal } else { q.normal };
                facing.dot(n) > 0.0
            })
    }

    /// Total emitted power (exitance times area, summed over patches and RGB), W.
    pub fn emitted_power(&self) -> f64 {
        (0..self.patches.len())
            .map(|i| {
                let e = self.patch_exitance(i);
                (e[0] + e[1] + e[2]) * self.patches[i].area
            })
            .sum()
    }

    /// Element `j`'s exitance: its polygon's, or its own where an emissive
    /// texture gives it one.
    pub fn element_exitance(&self, j: usize) -> [f64; 3] {
        let p = &self.polygons[self.elements[j].polygon as usize];
        match p.emission_texels {
            Some(first) => self.textured_exitance[first as usize + j - p.elements.start as usize],
            None => p.exitance,
        }
    }

    /// Patch `i`'s exitance: its polygon's, or, where an emissive texture
    /// gives its elements their own, their mean weighted by area.
    pub fn patch_exitance(&self, i: usize) -> [f64; 3] {
        let p = &self.patches[i];
        let polygon = &self.polygons[p.polygon as usize];
        if polygon.emission_texels.is_none() {
            return polygon.exitance;
        }
        let mut sum = [0.0; 3];
        for j in p.elements.clone() {
            let (e, a) = (
                self.element_exitance(j as usize),
                self.elements[j as usize].area,
            );
            (0..3).for_each(|c| sum[c] += e[c] * a);
        }
        sum.map(|s| s / p.area.max(1e-300))
    }

    /// Total area of all elements.
    pub fn total_area(&self) -> f64 {
        self.elements.iter().map(|e| e.area).sum()
    }

    fn add_polygon(
        &mut self,
        index: u32,
        poly: &Polygon,
        patch_size: f32,
        s: &MeshSettings,
        factor: u32,
    ) {
        let v = &poly.vertices;
        let tri = v.len() == 3;
        let cap_p = |len: f32| ((len / patch_size).ceil() as u32).clamp(1, s.max_patches_per_edge);
        // Precedence: a flag given for this run, then the node's extras, then the automatic rule.
        let (lu, lv) = if tri && poly.parent.is_some() {
            // A sliver cut off at a contact (`scene::contact`): sized by its
            // area, or its n x n grid on the longest edge would make n^2
            // tiny patches.
            let m = (2.0 * poly.area()).sqrt();
            (m, m)
        } else if tri {
            let m = (v[1] - v[0])
                .length()
                .max((v[2] - v[1]).length())
                .max((v[0] - v[2]).length());
            (m, m)
        } else {
            (
                (v[1] - v[0]).length().max((v[2] - v[3]).length()),
                (v[3] - v[0]).length().max((v[2] - v[1]).length()),
            )
        };
        let patch_grid = match (s.patch_size, poly.subdivision) {
            (None, Some(sub)) => sub.patches,
            _ if tri => [cap_p(lu); 2],
            _ => [cap_p(lu), cap_p(lv)],
        };
        let per = |len: f32, n: u32, e: f32| {
            ((len / n as f32 / e).ceil() as u32).clamp(1, s.max_elements_per_edge)
        };
        let element_grid = match (s.element_size, poly.subdivision) {
            (Some(e), _) if tri => [per(lu, patch_grid[0], e); 2],
            (Some(e), _) => [per(lu, patch_grid[0], e), per(lv, patch_grid[1], e)],
            (None, Some(sub)) => sub.elements,
            (None, None) => [2, 2],
        };
        let patch_grid = patch_grid.map(|n| (n * factor).min(s.max_patches_per_edge).max(n));
        let refl = poly.reflectance.map(f64::from);
        let exitance = poly.emission.map(|l| std::f64::consts::PI * l as f64);
        let first_patch = self.patches.len() as u32;
        let first_element = self.elements.len() as u32;
        if tri {
            self.triangle(index, v, patch_grid[0], element_grid[0]);
        } else {
            self.quad(index, v, patch_grid, element_grid);
        }
        let emission_texels = self.texture_elements(poly, first_element as usize);
        let tangent = (v[1] - v[0]).normalize();
        self.polygons.push(MeshPolygon {
            node: poly.node,
            normal: poly.normal,
            tangent,
            reflectance: refl,
            exitance,
            back_side: poly.back_side,
            textured: poly.texture.is_some(),
            emission_texels,
            patches: first_patch..self.patches.len() as u32,
            elements: first_element..self.elements.len() as u32,
            patch_grid: if tri { [patch_grid[0]; 2] } else { patch_grid },
            element_grid: if tri {
                [element_grid[0]; 2]
            } else {
                element_grid
            },
        });
    }

    fn push_patch(&mut self, polygon: u32, first_element: u32, corners: [Vec3; 4]) {
        let els = &self.elements[first_element as usize..];
        let area: f64 = els.iter().map(|e| e.area).sum();
        let centre = area_centroid(els).unwrap_or(Vec3::ZERO);
        let patch = self.patches.len() as u32;
        self.patches.push(Patch {
            polygon,
            centre,
            area,
            elements: first_element..self.elements.len() as u32,
            corners,
        });
        for e in &mut self.elements[first_element as usize..] {
            e.patch = patch;
        }
    }

    fn push_element(&mut self, polygon: u32, corners: [Vec3; 4], vertices: [u32; 4]) {
        let area = 0.5
            * (corners[2] - corners[0])
                .cross(corners[3] - corners[1])
                .length() as f64;
        self.elements.push(Element {
            patch: 0,
            polygon,
            corners,
            area,
            vertices,
            centre: centroid(&corners),
            reflectance: [0.0; 3],
        });
    }

    fn quad(&mut self, polygon: u32, v: &[Vec3], pg: [u32; 2], eg: [u32; 2]) {
        let (nu, nv) = (pg[0] * eg[0], pg[1] * eg[1]);
        let base = self.vertices.len() as u32;
        for j in 0..=nv {
            for i in 0..=nu {
                let (u, w) = (i as f32 / nu as f32, j as f32 / nv as f32);
                self.vertices
                    .push(bilinear(&[v[0], v[1], v[2], v[3]], u, w));
            }
        }
        let id = |i: u32, j: u32| base + j * (nu + 1) + i;
        for pj in 0..pg[1] {
            for pi in 0..pg[0] {
                let first = self.elements.len() as u32;
                for ej in 0..eg[1] {
                    for ei in 0..eg[0] {
                        let (i, j) = (pi * eg[0] + ei, pj * eg[1] + ej);
                        let ids = [id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)];
                        let corners = ids.map(|k| self.vertices[k as usize]);
                        self.push_element(polygon, corners, ids);
                    }
                }
                let (i0, j0) = (pi * eg[0], pj * eg[1]);
                let (i1, j1) = (i0 + eg[0], j0 + eg[1]);
                let outline = [id(i0, j0), id(i1, j0), id(i1, j1), id(i0, j1)]
                    .map(|k| self.vertices[k as usize]);
                self.push_patch(polygon, first, outline);
            }
        }
    }

    fn triangle(&mut self, polygon: u32, v: &[Vec3], np: u32, ne: u32) {
        let n = np * ne;
        let base = self.vertices.len() as u32;
        // Lattice point (i, j), i + j <= n: v0 + i/n (v1 - v0) + j/n (v2 - v0).
        let mut starts = Vec::with_capacity(n as usize + 1);
        let mut acc = 0u32;
        for j in 0..=n {
            starts.push(acc);
            acc += n + 1 - j;
        }
        for j in 0..=n {
            for i in 0..=(n - j) {
                let p = v[0]
                    + (v[1] - v[0]) * (i as f32 / n as f32)
                    + (v[2] - v[0]) * (j as f32 / n as f32);
                self.vertices.push(p);
            }
        }
        let id = |i: u32, j: u32| base + starts[j as usize] + i;
        // Each patch triangle is an up (sign +1) or down (sign -1) triangle of the
        // patch lattice; its elements are the fine-lattice triangles inside it.
        let mut patch_tris = Vec::new();
        for pj in 0..np {
            for pi in 0..(np - pj) {
                patch_tris.push(((pi * ne) as i64, (pj * ne) as i64, 1i64));
                if pi + pj + 1 < np {
                    patch_tris.push((((pi + 1) * ne) as i64, ((pj + 1) * ne) as i64, -1i64));
                }
            }
        }
        let ne = ne as i64;
        for (a, b, s) in patch_tris {
            let first = self.elements.len() as u32;
            let pt = |k: i64, l: i64| id((a + s * k) as u32, (b + s * l) as u32);
            for l in 0..ne {
                for k in 0..(ne - l) {
                    let ids = [pt(k, l), pt(k + 1, l), pt(k, l + 1)];
                    self.push_tri_element(polygon, ids);
                    if k + l + 1 < ne {
                        let ids = [pt(k + 1, l), pt(k + 1, l + 1), pt(k, l + 1)];
                        self.push_tri_element(polygon, ids);
                    }
                }
            }
            let outline = [pt(0, 0), pt(ne, 0), pt(0, ne)].map(|k| self.vertices[k as usize]);
            self.push_patch(
                polygon,
                first,
                [outline[0], outline[1], outline[2], outline[2]],
            );
        }
    }

    fn push_tri_element(&mut self, polygon: u32, ids: [u32; 3]) {
        let c = ids.map(|k| self.vertices[k as usize]);
        self.push_element(
            polygon,
            [c[0], c[1], c[2], c[2]],
            [ids[0], ids[1], ids[2], ids[2]],
        );
    }
}

/// The point (u, v) of the bilinear quad with corners `c` (counter-clockwise
/// from (0, 0)): how quads are subdivided, and how pieces of them are cut.
pub fn bilinear(c: &[Vec3; 4], u: f32, v: f32) -> Vec3 {
    c[0] * (1.0 - u) * (1.0 - v) + c[1] * u * (1.0 - v) + c[2] * u * v + c[3] * (1.0 - u) * v
}

/// The area-weighted centre of some elements (`None` when they have no area).
pub fn area_centroid<'a>(elements: impl IntoIterator<Item = &'a Element>) -> Option<Vec3> {
    let (mut sum, mut area) = (Vec3::ZERO, 0.0f64);
    for e in elements {
        sum += element_centre(e) * e.area as f32;
        area += e.area;
    }
    (area > 0.0).then(|| sum / area as f32)
}

/// Centroid (centre of area) of an element: for a quad, the area-weighted
/// centroids of its two triangles (the vertex average is off for a kite or a
/// trapezoid, and the receiver-side form factor is evaluated here).
pub fn element_centre(e: &Element) -> Vec3 {
    e.centre
}

/// The centroid of a quad (a triangle repeats its last corner).
fn centroid(c: &[Vec3; 4]) -> Vec3 {
    let tri = (c[0] + c[1] + c[2]) / 3.0;
    if c[3] == c[2] {
        return tri;
    }
    let a1 = (c[1] - c[0]).cross(c[2] - c[0]).length();
    let a2 = (c[2] - c[0]).cross(c[3] - c[0]).length();
    if a1 + a2 <= 0.0 {
        return (c[0] + c[1] + c[2] + c[3]) / 4.0;
    }
    (tri * a1 + (c[0] + c[2] + c[3]) / 3.0 * a2) / (a1 + a2)
}

/// One unit square in z = 0 facing +z, with `patches` x `patches` patches
/// of `elements` x `elements` elements: a fixture for unit tests.
#[cfg(test)]
pub(crate) fn unit_square(patches: u32, elements: u32) -> Mesh {
    let mut poly = crate::scene::Polygon::square(
        Vec3::new(0.5, 0.5, 0.0),
        0.5,
        Vec3::X,
        Vec3::Y,
        [0.5; 3],
        [0.0; 3],
    );
    poly.subdivision = Some(crate::scene::Subdivision {
        patches: [patches; 2],
        elements: [elements; 2],
    });
    let scene = Scene {
        polygons: vec![poly],
        nodes: vec!["n".into()],
        ..Default::default()
    };
    Mesh::build(&scene, &MeshSettings::default())
}

/// Patch edge length for every polygon under the automatic rule (or the fixed size).
pub fn patch_sizes(scene: &Scene, s: &MeshSettings) -> Vec<f32> {
    let n = scene.polygons.len();
    if let Some(size) = s.patch_size {
        return vec![size; n];
    }
    if n > AUTO_SEARCH_LIMIT {
        return vec![scene.extent() / 32.0; n];
    }
    // Refinement by need starts coarser and halves where the solution asks.
    let ratio = if s.refine > 0 {
        (s.near_field_ratio * (1u32 << s.refine.min(8)) as f32).min(1.0)
    } else {
        s.near_field_ratio
    };
    let eps = 1e-5 * scene.extent();
    // Pieces of a polygon split at a contact (`scene::contact`) are sized
    // as their whole: one entry per whole, with its centroid and area.
    let mut whole_of = vec![0usize; n];
    let mut wholes: Vec<(Vec3, f32, Vec3)> = Vec::new();
    let mut index: std::collections::HashMap<u32, usize> = Default::default();
    for (i, p) in scene.polygons.iter().enumerate() {
        let a = p.area();
        let k = match p.parent {
            Some(parent) => *index.entry(parent).or_insert_with(|| {
                wholes.push((Vec3::ZERO, 0.0, p.normal));
                wholes.len() - 1
            }),
            None => {
                wholes.push((Vec3::ZERO, 0.0, p.normal));
                wholes.len() - 1
            }
        };
        wholes[k].0 += p.centre() * a;
        wholes[k].1 += a;
        whole_of[i] = k;
    }
    let centres: Vec<Vec3> = wholes.iter().map(|w| w.0 / w.1.max(1e-30)).collect();
    let areas: Vec<f32> = wholes.iter().map(|w| w.1).collect();
    let normals: Vec<Vec3> = wholes.iter().map(|w| w.2).collect();
    let n = wholes.len();
    let mut size = vec![f32::INFINITY; n];
    for i in 0..n {
        let (ci, ni) = (centres[i], normals[i]);
        for j in (i + 1)..n {
            let (cj, nj) = (centres[j], normals[j]);
            let d = cj - ci;
            let h = d.length();
            // Each must lie in front of the other: they exchange light.
            let (cos_i, cos_j) = (ni.dot(d), nj.dot(-d));
            if cos_i <= eps || cos_j <= eps {
                continue;
            }
            let (cos_i, cos_j) = (cos_i / h, cos_j / h);
            let pi_h2 = std::f32::consts::PI * h * h;
            // Disk estimate of F in each direction; a pair that exchanges
            // little light tolerates a larger relative error (up to h / ratio).
            let allow = |f: f32| ratio * h * (0.2 / f.max(1e-6)).sqrt().clamp(1.0, 1.0 / ratio);
            size[i] = size[i].min(allow(areas[j] * cos_i * cos_j / (pi_h2 + areas[j])));
            size[j] = size[j].min(allow(areas[i] * cos_i * cos_j / (pi_h2 + areas[i])));
        }
    }
    // A whole's patch grid was capped at `max_patches_per_edge`: its pieces
    // keep the capped size, or together they would hold many more patches.
    let mut span = vec![(Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)); n];
    for (p, &k) in scene.polygons.iter().zip(&whole_of) {
        for v in &p.vertices {
            span[k] = (span[k].0.min(*v), span[k].1.max(*v));
        }
    }
    let cap = s.max_patches_per_edge.max(1) as f32;
    scene
        .polygons
        .iter()
        .zip(&whole_of)
        .map(|(p, &k)| match p.parent {
            Some(_) => size[k].max((span[k].1 - span[k].0).max_element() / cap),
            None => size[k],
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The six faces of the unit box at `at`, facing out (or in).
    fn cube(at: Vec3, out: bool, node: usize) -> Vec<crate::scene::Polygon> {
        let mut faces = Vec::new();
        for axis in 0..3 {
            for (side, positive) in [(0.0, false), (1.0, true)] {
                let v: Vec<Vec3> =
                    crate::scene::axis_rect(axis, side, [0.0; 2], [1.0; 2], positive == out)
                        .into_iter()
                        .map(|p| p + at)
                        .collect();
                faces.push(crate::scene::Polygon {
                    normal: crate::scene::polygon_normal(&v),
                    vertices: v,
                    reflectance: [0.5; 3],
                    emission: [0.0; 3],
                    node,
                    subdivision: None,
                    back_side: false,
                    parent: None,
                    texture: None,
                    emissive: None,
                });
            }
        }
        faces
    }

    #[test]
    fn closed_outward_boxes_are_solids_and_nothing_else_is() {
        let mut polys = cube(Vec3::ZERO, true, 0);
        polys.extend(cube(Vec3::new(3.0, 0.0, 0.0), true, 1));
        // A room seen from inside, an open box, a box with a face doubled.
        polys.extend(cube(Vec3::new(0.0, 5.0, 0.0), false, 2));
        let mut open = cube(Vec3::new(3.0, 5.0, 0.0), true, 3);
        open.pop();
        polys.extend(open);
        let mut doubled = cube(Vec3::new(6.0, 5.0, 0.0), true, 4);
        doubled.push(doubled[0].clone());
        polys.extend(doubled);
        // One node holding two separate boxes: two solids.
        let n = polys.len();
        polys.extend(cube(Vec3::new(0.0, 9.0, 0.0), true, 5));
        polys.extend(cube(Vec3::new(3.0, 9.0, 0.0), true, 5));
        let (solids, of) = find_solids(&polys);
        assert_eq!(solids.len(), 4, "{solids:?}");
        assert!(of[..6].iter().all(|s| *s == Some(0)));
        assert!(of[6..12].iter().all(|s| *s == Some(1)));
        assert!(of[12..n].iter().all(Option::is_none));
        assert!(of[n..n + 6].iter().all(|s| *s == Some(2)));
        assert!(of[n + 6..].iter().all(|s| *s == Some(3)));
        // The box holds its own faces' points (with a margin), not a point beside it.
        assert!(solids[0].holds(Vec3::new(0.5, 0.0, 0.5)));
        assert!(solids[0].holds(Vec3::new(0.5, 1.0, 0.5)));
        assert!(!solids[0].holds(Vec3::new(0.5, 1.01, 0.5)));
    }
    use crate::scene::Subdivision;

    fn poly(vertices: Vec<Vec3>, sub: Option<Subdivision>) -> Polygon {
        let normal = crate::scene::polygon_normal(&vertices);
        Polygon {
            vertices,
            normal,
            reflectance: [0.5; 3],
            emission: [0.0; 3],
            node: 0,
            subdivision: sub,
            back_side: false,
            parent: None,
            texture: None,
            emissive: None,
        }
    }

    #[test]
    fn element_areas_sum_to_polygon_area() {
        let quad = vec![
            Vec3::ZERO,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(1.5, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let tri = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
        let sub = Subdivision {
            patches: [3, 2],
            elements: [2, 3],
        };
        let scene = Scene {
            polygons: vec![poly(quad, Some(sub)), poly(tri, Some(sub))],
            nodes: vec!["n".into()],
            ..Default::default()
        };
        let m = Mesh::build(&scene, &MeshSettings::default());
        assert_eq!(m.patches.len(), 6 + 9);
        assert_eq!(m.elements.len(), 36 + 9 * 4);
        let qa: f64 = m.elements[..36].iter().map(|e| e.area).sum();
        let ta: f64 = m.elements[36..].iter().map(|e| e.area).sum();
        assert!((qa - 1.75).abs() < 1e-5, "{qa}");
        assert!((ta - 0.5).abs() < 1e-6, "{ta}");
        for p in &m.patches {
            let a: f64 = m.elements[p.elements.start as usize..p.elements.end as usize]
                .iter()
                .map(|e| e.area)
                .sum();
            assert!((a - p.area).abs() < 1e-9);
        }
        // Every element faces the same way as its polygon.
        for e in &m.elements {
            let n = (e.corners[1] - e.corners[0]).cross(e.corners[2] - e.corners[0]);
            assert!(n.z > 0.0);
        }
    }
}

/// Where and how a patch shoots: its centre and an orthonormal frame with z
/// along the normal (theta = 0 along `tangent`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShooterFrame {
    /// Hemisphere centre.
    pub centre: Vec3,
    /// x axis (theta = 0).
    pub tangent: Vec3,
    /// y axis (theta = pi / 2).
    pub bitangent: Vec3,
    /// z axis (phi = 0).
    pub normal: Vec3,
    /// The shooter's polygon, which must not see itself.
    pub polygon: u32,
    /// Only polygons within this distance of the centre are drawn (infinite
    /// but for a split shot's groups, which look only at near receivers).
    pub reach: f32,
    /// Polygons within this distance of the centre are drawn even when
    /// hidden (occlusion culling leaves them): the hidden cells of near
    /// receivers decide whether a shot splits.
    pub near: f32,
}

impl ShooterFrame {
    /// A frame at `centre` with z along `normal` and x along `tangent`
    /// (made orthogonal to the normal).
    pub fn new(centre: Vec3, normal: Vec3, tangent: Vec3, polygon: u32) -> Self {
        let normal = normal.normalize();
        let mut t = tangent - normal * normal.dot(tangent);
        if t.length_squared() < 1e-12 {
            t = normal.any_orthonormal_vector();
        }
        let tangent = t.normalize();
        Self {
            centre,
            tangent,
            bitangent: normal.cross(tangent),
            normal,
            polygon,
            reach: f32::INFINITY,
            near: 0.0,
        }
    }

    /// This frame drawing only polygons within `reach` of its centre.
    pub fn within(self, reach: f32) -> Self {
        Self { reach, ..self }
    }

    /// This frame drawing every polygon within `near` of its centre, hidden or not.
    pub fn keeping_near(self, near: f32) -> Self {
        Self { near, ..self }
    }
}

impl ShooterFrame {
    /// A world-space vector in this frame's coordinates (x: tangent, z: normal).
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(
            v.dot(self.tangent),
            v.dot(self.bitangent),
            v.dot(self.normal),
        )
    }
}

impl Mesh {
    /// The hemisphere frame of patch `patch`.
    pub fn shooter_frame(&self, patch: u32) -> ShooterFrame {
        self.shooter_frame_at(patch, self.patches[patch as usize].centre)
    }

    /// The hemisphere frame of patch `patch` placed at `centre` (a point of its plane).
    pub fn shooter_frame_at(&self, patch: u32, centre: Vec3) -> ShooterFrame {
        let p = &self.patches[patch as usize];
        let poly = &self.polygons[p.polygon as usize];
        ShooterFrame::new(centre, poly.normal, poly.tangent, p.polygon)
    }
}
