//! The ambient term carried by the scene's geometry.
//!
//! Progressive refinement shows, at every point of a solve, the radiosity
//! so far plus an estimate of the light still to come from the unshot
//! radiosity (the ambient term). Cohen et al.'s estimate spreads all the
//! unshot power evenly over the scene; it is right in a uniform enclosure
//! and wrong wherever the unshot light sits: the floor under a light holds
//! most of it early on and, being flat, can send none of it to itself, yet
//! the even spread gives it back its own share (the Cornell box's floor was
//! +6 % after 338 shots, its blocks -5 %).
//!
//! [`Transport`] carries the unshot power along the scene's own geometry
//! instead: for groups of surfaces (each polygon, or each glTF node's side
//! in big scenes) it estimates once, by rays from stratified points in
//! cosine-distributed directions, which share of a group's diffuse light
//! lands on the front of each other group (the rest meets back faces or
//! leaves the scene). The display's ambient term is then the unshot power
//! of each group carried bounce after bounce through those shares, each
//! group reflecting its mean reflectance. It changes nothing the solver
//! shoots: it is an estimate for display, and it tends to 0 with the
//! unshot power, as Cohen's does.
//!
//! Pure maths: rays through [`crate::raytrace::Bvh`], no GPU, no ranks.
//! Deterministic: every group's rays come from a generator seeded by its
//! index, whatever the thread count.

use crate::fuzz::Rng;
use crate::mesh::Mesh;
use crate::sampling::{in_parallel, point_in, unit};
use glam::Vec3;

/// Up to this many polygons each polygon is a group; above it, each glTF
/// node's front sides are one group and its back sides (double-sided
/// surfaces' copies) another.
pub const POLYGON_GROUPS: usize = 4096;

/// Up to this many patches each patch is a group.
pub const PATCH_GROUPS: usize = 8192;

/// Rays cast in all, shared evenly by the groups (within [`MIN_RAYS`] and
/// [`MAX_RAYS`] a group).
const RAY_BUDGET: usize = 1 << 18;
/// The fewest rays a group casts.
const MIN_RAYS: usize = 64;
/// The most rays a group casts (a share's standard error is then at most
/// 0.8 % of the group's light).
const MAX_RAYS: usize = 4096;
/// Bounces carried at most; the light left after them is dropped (below
/// [`CARRY_TOLERANCE`] of what started, in every scene whose mean
/// reflectance is under 0.93).
const MAX_BOUNCES: usize = 256;
/// Carrying stops once the light in flight is this share of the unshot power.
const CARRY_TOLERANCE: f64 = 1e-6;

/// Where each group's diffuse light lands (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct Transport {
    /// Per patch, its group.
    group_of: Vec<u32>,
    /// Per group, its area, m^2.
    area: Vec<f64>,
    /// Per group, its area-weighted mean reflectance per channel.
    reflectance: Vec<[f64; 3]>,
    /// Group q's landings are `landings[offsets[q]..offsets[q + 1]]`.
    offsets: Vec<usize>,
    /// (group landed on, share of the light that left group q), by group.
    landings: Vec<(u32, f64)>,
}

impl Transport {
    /// Estimates the shares for `mesh` (see the module docs).
    pub fn new(mesh: &Mesh) -> Self {
        let group_of = groups(mesh);
        let count = group_of.iter().map(|&g| g as usize + 1).max().unwrap_or(0);
        let mut area = vec![0.0; count];
        let mut reflectance = vec![[0.0; 3]; count];
        // Per group, its elements and their cumulative areas (to pick
        // points in proportion to area).
        let mut members: Vec<Vec<(u32, f64)>> = vec![Vec::new(); count];
        for (j, e) in mesh.elements.iter().enumerate() {
            let g = group_of[e.patch as usize] as usize;
            area[g] += e.area;
            for c in 0..3 {
                reflectance[g][c] += e.reflectance[c] * e.area;
            }
            members[g].push((j as u32, area[g]));
        }
        for (r, &a) in reflectance.iter_mut().zip(&area) {
            if a > 0.0 {
                *r = r.map(|x| x / a);
            }
        }
        let rays = (RAY_BUDGET / count.max(1)).clamp(MIN_RAYS, MAX_RAYS);
        let mut rows: Vec<Vec<(u32, f64)>> = vec![Vec::new(); count];
        in_parallel(&mut rows, |g, row| {
            *row = landings_of(mesh, &group_of, &members[g], g as u64, rays);
        });
        let mut offsets = Vec::with_capacity(count + 1);
        offsets.push(0);
        let mut landings = Vec::new();
        for row in rows {
            landings.extend(row);
            offsets.push(landings.len());
        }
        if std::env::var_os("AMBIENT_DEBUG").is_some() {
            for q in 0..count {
                let row = &landings[offsets[q]..offsets[q + 1]];
                let sum: f64 = row.iter().map(|(_, s)| s).sum();
                eprintln!("group {q} area {:.4} rho {:?} sum {sum:.4} {:?}", area[q], reflectance[q], row);
            }
        }
        Self {
            group_of,
            area,
            reflectance,
            offsets,
            landings,
        }
    }

    /// The number of groups.
    pub fn groups(&self) -> usize {
        self.area.len()
    }

    /// Patch `patch`'s group.
    pub fn group_of(&self, patch: u32) -> usize {
        self.group_of[patch as usize] as usize
    }

    /// The share of group `from`'s diffuse light that lands on the front of
    /// group `to` (0 where none of its rays did).
    pub fn share(&self, from: usize, to: usize) -> f64 {
        self.row(from)
            .iter()
            .find(|(g, _)| *g as usize == to)
            .map_or(0.0, |(_, s)| *s)
    }

    fn row(&self, g: usize) -> &[(u32, f64)] {
        &self.landings[self.offsets[g]..self.offsets[g + 1]]
    }

    /// The irradiance, W/m^2 per channel and group, that the unshot power
    /// `unshot` (W per channel and group, signed) will deliver: carried
    /// through the shares bounce after bounce, each group reflecting its
    /// mean reflectance of what lands on it.
    pub fn irradiance(&self, unshot: &[[f64; 3]]) -> Vec<[f64; 3]> {
        let n = self.groups();
        let start: f64 = unshot.iter().flatten().map(|x| x.abs()).sum();
        let mut total = vec![[0.0; 3]; n];
        let mut leaving: Vec<[f64; 3]> = unshot.to_vec();
        leaving.resize(n, [0.0; 3]);
        let mut landing = vec![[0.0; 3]; n];
        for _ in 0..MAX_BOUNCES {
            landing.iter_mut().for_each(|l| *l = [0.0; 3]);
            for (q, out) in leaving.iter().enumerate() {
                if *out == [0.0; 3] {
                    continue;
                }
                for &(p, s) in self.row(q) {
                    let l = &mut landing[p as usize];
                    for c in 0..3 {
                        l[c] += s * out[c];
                    }
                }
            }
            let mut flight = 0.0;
            for p in 0..n {
                for c in 0..3 {
                    total[p][c] += landing[p][c];
                    leaving[p][c] = self.reflectance[p][c] * landing[p][c];
                    flight += leaving[p][c].abs();
                }
            }
            if flight <= CARRY_TOLERANCE * start {
                break;
            }
        }
        total
            .iter()
            .zip(&self.area)
            .map(|(t, &a)| if a > 0.0 { t.map(|x| x / a) } else { [0.0; 3] })
            .collect()
    }
}

/// Per patch, its group: the patch itself in meshes of up to
/// [`PATCH_GROUPS`] patches, else its polygon in scenes of up to
/// [`POLYGON_GROUPS`] polygons, else its node's side (numbered in order of
/// first appearance).
fn groups(mesh: &Mesh) -> Vec<u32> {
    if mesh.patches.len() <= PATCH_GROUPS {
        return (0..mesh.patches.len() as u32).collect();
    }
    if mesh.polygons.len() <= POLYGON_GROUPS {
        return mesh.patches.iter().map(|p| p.polygon).collect();
    }
    let mut ids = std::collections::HashMap::new();
    let of_polygon: Vec<u32> = mesh
        .polygons
        .iter()
        .map(|p| {
            let next = ids.len() as u32;
            *ids.entry((p.node, p.back_side)).or_insert(next)
        })
        .collect();
    mesh.patches
        .iter()
        .map(|p| of_polygon[p.polygon as usize])
        .collect()
}

/// Where `rays` rays from group `seed`'s elements `members` (with their
/// cumulative areas) land: (group, share), by group.
fn landings_of(
    mesh: &Mesh,
    group_of: &[u32],
    members: &[(u32, f64)],
    seed: u64,
    rays: usize,
) -> Vec<(u32, f64)> {
    let Some(&(_, total)) = members.last() else {
        return Vec::new();
    };
    if total <= 0.0 {
        return Vec::new();
    }
    let mut rng = Rng(seed.wrapping_mul(0x2545_f491_4f6c_dd1d) ^ 0x5eed_a3b1);
    let mut hits: Vec<u32> = Vec::with_capacity(rays);
    for r in 0..rays {
        // Stratified in area: ray r picks its point in the r-th slice.
        let at = (r as f64 + unit(&mut rng) as f64) / rays as f64 * total;
        let k = members.partition_point(|&(_, c)| c < at).min(members.len() - 1);
        let e = &mesh.elements[members[k].0 as usize];
        let corners: &[Vec3] = if e.corners[3] == e.corners[2] {
            &e.corners[..3]
        } else {
            &e.corners
        };
        let (p, _) = point_in(corners, unit(&mut rng), unit(&mut rng));
        let poly = &mesh.polygons[e.polygon as usize];
        let dir = cosine_direction(poly.normal, poly.tangent, unit(&mut rng), unit(&mut rng));
        let origin = p + poly.normal * mesh.ray_offset;
        let Some(hit) = nearest_other(mesh, origin, dir, e.polygon)
        else {
            continue; // leaves the scene
        };
        // Light meeting a back face is absorbed there (one-sided surfaces
        // are black behind).
        if mesh.polygons[hit.polygon as usize].normal.dot(dir) < 0.0 {
            hits.push(group_at(mesh, group_of, hit.polygon, origin + dir * hit.t));
        }
    }
    hits.sort_unstable();
    let mut out: Vec<(u32, f64)> = Vec::new();
    for g in hits {
        match out.last_mut() {
            Some((last, s)) if *last == g => *s += 1.0,
            _ => out.push((g, 1.0)),
        }
    }
    for (_, s) in &mut out {
        *s /= rays as f64;
    }
    out
}

/// The group of the point `x` of polygon `polygon`: its patch's where
/// patches are groups (the patch whose centre is nearest, among the
/// polygon's), else the polygon's.
fn group_at(mesh: &Mesh, group_of: &[u32], polygon: u32, x: Vec3) -> u32 {
    let patches = mesh.polygons[polygon as usize].patches.clone();
    let first = group_of[patches.start as usize];
    if patches.len() == 1 || group_of[patches.start as usize + 1] == first {
        return first;
    }
    let nearest = patches
        .min_by(|&a, &b| {
            let da = mesh.patches[a as usize].centre.distance_squared(x);
            let db = mesh.patches[b as usize].centre.distance_squared(x);
            da.total_cmp(&db)
        })
        .unwrap_or(0);
    group_of[nearest as usize]
}

/// The nearest hit along the ray, skipping polygon `own` (a quad that is
/// not quite planar, as the measured Cornell box's left wall, meets a ray
/// leaving one of its triangles in its other one, a hair away).
fn nearest_other(mesh: &Mesh, origin: Vec3, dir: Vec3, own: u32) -> Option<crate::raytrace::Hit> {
    let mut t_min = 0.0;
    for _ in 0..4 {
        let hit = mesh
            .occluders
            .nearest_facing(origin, dir, t_min, f32::INFINITY, 1e-5)?;
        if hit.polygon != own {
            return Some(hit);
        }
        t_min = hit.t * (1.0 + 1e-5) + mesh.ray_offset;
    }
    None
}

/// A cosine-distributed direction about `normal` (unit) from two uniform
/// numbers; `tangent` is any unit vector across the normal.
fn cosine_direction(normal: Vec3, tangent: Vec3, u1: f32, u2: f32) -> Vec3 {
    let bitangent = normal.cross(tangent);
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let z = (1.0 - u1).max(0.0).sqrt();
    (tangent * (r * phi.cos()) + bitangent * (r * phi.sin()) + normal * z).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::MeshSettings;
    use crate::scene::{Polygon, Scene};

    /// A closed unit cube of six inward-facing squares (reflectance `rho`).
    fn cube(rho: f32) -> Mesh {
        let s = |c: Vec3, u: Vec3, v: Vec3| Polygon::square(c, 0.5, u, v, [rho; 3], [0.0; 3]);
        let polygons = vec![
            s(Vec3::new(0.5, 0.5, 0.0), Vec3::X, Vec3::Y),
            s(Vec3::new(0.5, 0.5, 1.0), Vec3::Y, Vec3::X),
            s(Vec3::new(0.5, 0.0, 0.5), Vec3::Z, Vec3::X),
            s(Vec3::new(0.5, 1.0, 0.5), Vec3::X, Vec3::Z),
            s(Vec3::new(0.0, 0.5, 0.5), Vec3::Y, Vec3::Z),
            s(Vec3::new(1.0, 0.5, 0.5), Vec3::Z, Vec3::Y),
        ];
        let scene = Scene {
            nodes: vec!["box".into(); 1],
            polygons,
            ..Default::default()
        };
        Mesh::build(&scene, &MeshSettings::default())
    }

    #[test]
    fn a_closed_cube_sends_every_ray_to_the_other_faces() {
        let mesh = cube(0.5);
        let t = Transport::new(&mesh);
        assert_eq!(t.groups(), 6);
        for q in 0..6 {
            let sum: f64 = t.row(q).iter().map(|(_, s)| s).sum();
            assert!((sum - 1.0).abs() < 1e-12, "face {q}: {sum}");
            assert_eq!(t.share(q, q), 0.0, "a flat face cannot light itself");
            // Unit cube: the opposite face takes 0.19982, each adjacent one 0.20004.
            for p in (0..6).filter(|&p| p != q) {
                let s = t.share(q, p);
                assert!((s - 0.2).abs() < 0.03, "{q} -> {p}: {s}");
            }
        }
    }

    #[test]
    fn in_a_closed_uniform_box_the_carried_light_is_cohens() {
        // Uniform unshot radiosity u on every face of a closed box of
        // reflectance rho: every face receives u / (1 - rho) in all.
        let rho = 0.6;
        let mesh = cube(rho as f32);
        let t = Transport::new(&mesh);
        let unshot = vec![[1.0, 0.5, 0.0]; 6];
        let e = t.irradiance(&unshot);
        for (g, h) in e.iter().enumerate() {
            for c in 0..3 {
                let want = unshot[0][c] / (1.0 - rho);
                assert!((h[c] - want).abs() <= 0.03 * want + 1e-12, "{g}/{c}: {} vs {want}", h[c]);
            }
        }
        // The whole power is carried exactly: rows sum to 1.
        let total: f64 = e.iter().map(|h| h[0]).sum::<f64>();
        assert!((total - 6.0 / (1.0 - rho)).abs() < 1e-6, "{total}");
    }

    #[test]
    fn the_same_shares_on_every_run() {
        let mesh = cube(0.5);
        let (a, b) = (Transport::new(&mesh), Transport::new(&mesh));
        assert_eq!(a.landings, b.landings);
    }
}
