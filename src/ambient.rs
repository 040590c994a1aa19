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
//! instead: for groups of surfaces (each patch; in meshes of more than
//! [`PATCH_GROUPS`] patches, clusters of nearby patches facing the same
//! way) it estimates once, by rays from stratified points in
//! cosine-distributed directions, which share of a group's diffuse light
//! lands on the front of each other group (the rest meets back faces or
//! leaves the scene). The display's ambient term is then the unshot power
//! of each group carried bounce after bounce through those shares, each
//! group reflecting its mean reflectance: a coarse Monte Carlo radiosity
//! solution of the light still unshot, which the progressive solution
//! replaces as it shoots. It changes nothing the solver shoots (it is for
//! display: the trace, the report, the image, the viewer), and it tends
//! to 0 with the unshot power, as Cohen's does.
//!
//! Pure maths: rays through [`crate::raytrace::Bvh`], no GPU, no ranks.
//! Deterministic: every group's rays come from a generator seeded by its
//! index, whatever the thread count.

use crate::locate::{nearest_other, patch_at};
use crate::mesh::Mesh;
use crate::rng::Rng;
use crate::sampling::{cosine_direction, in_parallel, point_in, unit};
use glam::Vec3;

/// Up to this many patches each patch is a group; bigger meshes group
/// their patches into at most this many clusters (see [`groups`]).
pub const PATCH_GROUPS: usize = 8192;

/// Rays cast in all, shared evenly by the groups (within [`MIN_RAYS`] and
/// [`MAX_RAYS`] a group); as many again at most go to the emitters' groups
/// (see [`Plan::rays_of`]).
pub const RAY_BUDGET: usize = 1 << 18;
/// The budget of a refinement pass's transport ([`Transport::built_within`]):
/// a pass's solution is shown only until the final solve's first shot, and
/// its hemispheres are drawn coarse too.
pub const PASS_RAY_BUDGET: usize = RAY_BUDGET / 2;
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
    /// Per group, the share of its light that met back faces.
    back: Vec<f64>,
    /// The groups' patches.
    members: Members,
    /// The landings by the group landed on: group p's are
    /// `into[into_offsets[p]..into_offsets[p + 1]]` as (group it left,
    /// share), in the order [`Transport::irradiance`] adds them.
    into_offsets: Vec<usize>,
    into: Vec<(u32, f64)>,
}

/// Each group's patches: group g's are `patches[offsets[g]..offsets[g + 1]]`,
/// in increasing order.
#[derive(Clone, Debug, Default)]
struct Members {
    offsets: Vec<usize>,
    patches: Vec<u32>,
}

impl Members {
    /// From each patch's group (`count` groups), by a counting sort.
    fn of(group_of: &[u32], count: usize) -> Self {
        let mut offsets = vec![0; count + 1];
        for &g in group_of {
            offsets[g as usize + 1] += 1;
        }
        for g in 0..count {
            offsets[g + 1] += offsets[g];
        }
        let mut next = offsets.clone();
        let mut patches = vec![0; group_of.len()];
        for (p, &g) in group_of.iter().enumerate() {
            patches[next[g as usize]] = p as u32;
            next[g as usize] += 1;
        }
        Self { offsets, patches }
    }

    /// Group `g`'s patches, in increasing order.
    fn of_group(&self, g: usize) -> &[u32] {
        &self.patches[self.offsets[g]..self.offsets[g + 1]]
    }
}

/// What one group's rays found: how many it cast, how many landed on the
/// front of each group (by group) and how many met back faces. Plain
/// counts, so ranks can cast different groups' rays and gather them
/// ([`GroupRays::pack`]) into the same bits one rank would make.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GroupRays {
    /// The group.
    pub group: u32,
    /// Rays cast.
    pub rays: u32,
    /// (group landed on, rays), by group.
    pub hits: Vec<(u32, u32)>,
    /// Rays that met back faces.
    pub back: u32,
    /// The group's area, m^2, and its elements' reflectances times their
    /// areas, summed per channel (in element order, where it was cast).
    pub area: f64,
    /// See `area`.
    pub reflected: [f64; 3],
}

impl GroupRays {
    /// Appends this group's counts to `out` as words.
    pub fn pack(&self, out: &mut Vec<u32>) {
        out.extend([self.group, self.rays, self.back, self.hits.len() as u32]);
        for x in [
            self.area,
            self.reflected[0],
            self.reflected[1],
            self.reflected[2],
        ] {
            let bits = x.to_bits();
            out.extend([bits as u32, (bits >> 32) as u32]);
        }
        for &(g, n) in &self.hits {
            out.extend([g, n]);
        }
    }

    /// Every group's counts in `words` (as [`GroupRays::pack`] wrote them;
    /// None if they are cut short).
    pub fn unpack_all(mut words: &[u32]) -> Option<Vec<GroupRays>> {
        let mut out = Vec::new();
        while let [group, rays, back, n, rest @ ..] = words {
            let n = *n as usize;
            let sums = rest.get(..8)?;
            let pairs = rest.get(8..8 + 2 * n)?;
            let f = |k: usize| {
                f64::from_bits(u64::from(sums[2 * k]) | u64::from(sums[2 * k + 1]) << 32)
            };
            out.push(GroupRays {
                group: *group,
                rays: *rays,
                back: *back,
                hits: pairs.chunks_exact(2).map(|p| (p[0], p[1])).collect(),
                area: f(0),
                reflected: [f(1), f(2), f(3)],
            });
            words = &rest[8 + 2 * n..];
        }
        words.is_empty().then_some(out)
    }
}

/// How a transport's rays are cast: the groups, their members and rays.
/// [`Plan::cast`] casts one group's rays, the same wherever it runs.
pub struct Plan<'m> {
    mesh: &'m Mesh,
    group_of: Vec<u32>,
    members: Members,
    /// Per group, the rays it casts.
    rays: Vec<u32>,
}

impl Plan<'_> {
    /// Per group, its rays: the budget shared evenly, and the emitters'
    /// groups up to [`MAX_RAYS`] each from a second budget as big. Early in
    /// a solve nearly all the unshot light is the emitters' own: their
    /// shares carry most of the display then, and few rays leave them noisy
    /// (the Cornell box's 16 light patches at 209 rays each put its mean
    /// error at 1.5-2.6 % until they had shot). Taking those rays from the
    /// other groups made the later displays worse (docs/accuracy.md).
    fn rays_of(mesh: &Mesh, group_of: &[u32], count: usize, budget: usize) -> Vec<u32> {
        let even = (budget / count.max(1)).clamp(MIN_RAYS, MAX_RAYS);
        let mut emits = vec![false; count];
        for (p, &g) in mesh.patches.iter().zip(group_of) {
            emits[g as usize] |= mesh.polygons[p.polygon as usize].emits();
        }
        let emitters = emits.iter().filter(|&&e| e).count();
        let more = (budget / emitters.max(1)).clamp(even, MAX_RAYS);
        emits
            .iter()
            .map(|&e| if e { more } else { even } as u32)
            .collect()
    }

    /// The number of groups.
    pub fn groups(&self) -> usize {
        self.rays.len()
    }

    /// Group `g`'s rays, area and reflectance. Only the rank that casts a
    /// group reads its elements: on N ranks each reads 1/N of the mesh's.
    pub fn cast(&self, g: usize) -> GroupRays {
        // Its elements in increasing order, each with the group's area up to
        // and including it (to pick points in proportion to area).
        let mut ids: Vec<u32> = self
            .members
            .of_group(g)
            .iter()
            .flat_map(|&p| self.mesh.patches[p as usize].elements.clone())
            .collect();
        ids.sort_unstable();
        let (mut area, mut reflected) = (0.0, [0.0; 3]);
        let members: Vec<(u32, f64)> = ids
            .into_iter()
            .map(|j| {
                let e = &self.mesh.elements[j as usize];
                area += e.area;
                for (r, rho) in reflected.iter_mut().zip(e.reflectance) {
                    *r += rho * e.area;
                }
                (j, area)
            })
            .collect();
        let mut out = landings_of(
            self.mesh,
            &self.group_of,
            &members,
            g as u64,
            self.rays[g] as usize,
        );
        (out.area, out.reflected) = (area, reflected);
        out
    }

    /// The groups cut into about `pieces` runs of consecutive groups, each
    /// of about an equal share of the rays (a group dearer than a share is
    /// a run of its own), the dearest run first (the earlier on ties):
    /// what ranks take from a [`crate::parallel::pool`] as they come free,
    /// so a rank whose core runs slower casts fewer, and what is left at
    /// the end is small. Consecutive groups are near one another, so a
    /// rank's rays keep to one part of the scene (a deal of single groups
    /// by cost cast 13 % more CPU over two ranks than one rank did).
    pub fn pieces(&self, pieces: usize) -> Vec<std::ops::Range<usize>> {
        let total: u64 = self.rays.iter().map(|&r| u64::from(r)).sum();
        let share = total.div_ceil(pieces.max(1) as u64).max(1);
        let mut runs = Vec::new();
        let (mut start, mut rays) = (0, 0u64);
        for (g, &r) in self.rays.iter().enumerate() {
            let r = u64::from(r);
            if g > start && rays + r > share {
                runs.push((rays, start..g));
                (start, rays) = (g, 0);
            }
            rays += r;
        }
        if start < self.rays.len() {
            runs.push((rays, start..self.rays.len()));
        }
        runs.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.start.cmp(&b.1.start)));
        runs.into_iter().map(|(_, run)| run).collect()
    }

    /// The rays of each of `groups`, on every core, in that order.
    pub fn cast_these(&self, groups: &[usize]) -> Vec<GroupRays> {
        let mut out = vec![GroupRays::default(); groups.len()];
        in_parallel(&mut out, |k, row| *row = self.cast(groups[k]));
        out
    }

    /// Every group's rays, in group order.
    pub fn cast_all(&self) -> Vec<GroupRays> {
        self.cast_these(&(0..self.groups()).collect::<Vec<_>>())
    }
}

impl Transport {
    /// Estimates the shares for `mesh` (see the module docs), casting every
    /// group's rays here.
    pub fn new(mesh: &Mesh) -> Self {
        Self::built(mesh, |plan| plan.cast_all())
    }

    /// [`Transport::new`], with the rays cast by `cast`, which must return
    /// [`Plan::cast`] of every group in group order (it may split the
    /// groups between ranks and gather their counts: the same bits).
    pub fn built(mesh: &Mesh, cast: impl FnOnce(&Plan) -> Vec<GroupRays>) -> Self {
        Self::built_within(mesh, RAY_BUDGET, cast)
    }

    /// [`Transport::built`] with `budget` rays shared evenly by the groups
    /// (and as many again at most for the emitters'; see [`Plan::rays_of`]).
    pub fn built_within(
        mesh: &Mesh,
        budget: usize,
        cast: impl FnOnce(&Plan) -> Vec<GroupRays>,
    ) -> Self {
        let start = std::time::Instant::now();
        let group_of = groups(mesh);
        let count = group_of.iter().map(|&g| g as usize + 1).max().unwrap_or(0);
        let members = Members::of(&group_of, count);
        let rays = Plan::rays_of(mesh, &group_of, count, budget);
        let plan = Plan {
            mesh,
            group_of,
            members,
            rays,
        };
        let rows = cast(&plan);
        let Plan {
            group_of,
            members,
            rays,
            ..
        } = plan;
        let mut offsets = Vec::with_capacity(count + 1);
        offsets.push(0);
        // Sized once: grown row by row it was copied a dozen times.
        let mut landings = Vec::with_capacity(rows.iter().map(|r| r.hits.len()).sum());
        let mut back = Vec::with_capacity(count);
        let mut area = Vec::with_capacity(count);
        let mut reflectance = Vec::with_capacity(count);
        for row in rows {
            let n = f64::from(row.rays.max(1));
            landings.extend(row.hits.iter().map(|&(g, k)| (g, f64::from(k) / n)));
            offsets.push(landings.len());
            back.push(f64::from(row.back) / n);
            let a = row.area;
            area.push(a);
            reflectance.push(if a > 0.0 {
                row.reflected.map(|x| x / a)
            } else {
                row.reflected
            });
        }
        log::info!(
            "ambient term: {count} groups, {} rays, {} landings, {:.3} s",
            rays.iter().map(|&r| u64::from(r)).sum::<u64>(),
            landings.len(),
            start.elapsed().as_secs_f64()
        );
        let (into_offsets, into) = transposed(&offsets, &landings, count);
        Self {
            group_of,
            area,
            reflectance,
            offsets,
            landings,
            back,
            members,
            into_offsets,
            into,
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

    /// Where group `g`'s diffuse light lands: (group, share), by group.
    pub fn row(&self, g: usize) -> &[(u32, f64)] {
        &self.landings[self.offsets[g]..self.offsets[g + 1]]
    }

    /// The share of group `g`'s diffuse light that meets back faces.
    pub fn back_share(&self, g: usize) -> f64 {
        self.back[g]
    }

    /// Group `g`'s patches, in increasing order.
    pub fn patches_of(&self, g: usize) -> &[u32] {
        self.members.of_group(g)
    }

    /// Group `g`'s area, m^2.
    pub fn area_of(&self, g: usize) -> f64 {
        self.area[g]
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
        // Each group's landing gathered from the groups it is reached from,
        // in the order a pass over the leaving groups would add them (so
        // the same sums), the groups shared out between the cores where
        // the landings are many.
        let threads = if self.into.len() >= PARALLEL_CARRY {
            crate::parallel::cores().min(8)
        } else {
            1
        };
        let chunk = n.div_ceil(threads.max(1)).max(1);
        for _ in 0..MAX_BOUNCES {
            let gather = |first: usize, part: &mut [[f64; 3]]| {
                for (k, l) in part.iter_mut().enumerate() {
                    let p = first + k;
                    *l = [0.0; 3];
                    for &(q, s) in &self.into[self.into_offsets[p]..self.into_offsets[p + 1]] {
                        let out = leaving[q as usize];
                        if out == [0.0; 3] {
                            continue;
                        }
                        for c in 0..3 {
                            l[c] += s * out[c];
                        }
                    }
                }
            };
            if threads <= 1 {
                gather(0, &mut landing);
            } else {
                crate::parallel::each(landing.chunks_mut(chunk), |k, part| gather(k * chunk, part));
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

/// Landings below which a bounce of [`Transport::irradiance`] runs on one
/// thread.
const PARALLEL_CARRY: usize = 1 << 16;

/// The landings by group left (`offsets`, `landings`) as the landings by
/// group landed on, each group's in order of the group left (a stable
/// counting sort): (offsets, (group left, share)).
fn transposed(
    offsets: &[usize],
    landings: &[(u32, f64)],
    count: usize,
) -> (Vec<usize>, Vec<(u32, f64)>) {
    let mut into_offsets = vec![0usize; count + 1];
    for &(p, _) in landings {
        if let Some(o) = into_offsets.get_mut(p as usize + 1) {
            *o += 1;
        }
    }
    for k in 0..count {
        into_offsets[k + 1] += into_offsets[k];
    }
    let mut next = into_offsets.clone();
    let mut into = vec![(0u32, 0.0f64); into_offsets[count]];
    for q in 0..offsets.len().saturating_sub(1) {
        for &(p, s) in &landings[offsets[q]..offsets[q + 1]] {
            if let Some(at) = next.get_mut(p as usize) {
                into[*at] = (q as u32, s);
                *at += 1;
            }
        }
    }
    (into_offsets, into)
}

/// Per patch, its group: the patch itself in meshes of up to
/// [`PATCH_GROUPS`] patches; in bigger ones, the patches whose centres share
/// a cell of the finest uniform grid over the scene that makes at most that
/// many groups, and whose polygons face the same way (the same dominant
/// axis and sign of the normal, the same side of a double-sided surface).
/// Numbered in order of first appearance.
fn groups(mesh: &Mesh) -> Vec<u32> {
    let n = mesh.patches.len();
    if n <= PATCH_GROUPS {
        return (0..n as u32).collect();
    }
    let (lo, hi) = mesh
        .patches
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.centre), hi.max(p.centre))
        });
    let size = (hi - lo).max(Vec3::splat(1e-6));
    // Per polygon once: every grid tried reads every patch's.
    let facing: Vec<u8> = mesh
        .polygons
        .iter()
        .map(|poly| {
            let a = poly.normal.abs();
            let axis = if a.x >= a.y && a.x >= a.z {
                0
            } else if a.y >= a.z {
                1
            } else {
                2
            };
            let sign = (poly.normal[axis] < 0.0) as usize;
            (axis * 2 + sign) as u8 + if poly.back_side { 6 } else { 0 }
        })
        .collect();
    // A patch's (cell, facing) as one index into a dense table: cells^3 x 12.
    let slot = |p: &crate::mesh::Patch, cells: u32| -> usize {
        let c = ((p.centre - lo) / size * cells as f32)
            .as_uvec3()
            .min(glam::UVec3::splat(cells - 1));
        let cell = (c.z as usize * cells as usize + c.y as usize) * cells as usize + c.x as usize;
        cell * 12 + facing[p.polygon as usize] as usize
    };
    let mut cells = 64u32;
    loop {
        let slots = (cells as usize).pow(3) * 12;
        // Too many groups shows early: count the distinct slots until the
        // count passes the limit (every rank repeats this; a hash map of
        // every patch at every grid took 0.1 s of cubes-b3's solve).
        if cells > 1 {
            let mut seen = vec![0u64; slots.div_ceil(64)];
            let mut distinct = 0;
            let too_many = mesh.patches.iter().any(|p| {
                let s = slot(p, cells);
                let (word, bit) = (s / 64, 1u64 << (s % 64));
                if seen[word] & bit == 0 {
                    seen[word] |= bit;
                    distinct += 1;
                }
                distinct > PATCH_GROUPS
            });
            if too_many {
                cells = (cells * 3 / 4).max(1);
                continue;
            }
        }
        // Numbered in order of first appearance.
        let mut ids = vec![u32::MAX; slots];
        let mut next = 0;
        return mesh
            .patches
            .iter()
            .map(|p| {
                let id = &mut ids[slot(p, cells)];
                if *id == u32::MAX {
                    *id = next;
                    next += 1;
                }
                *id
            })
            .collect();
    }
}

/// Where `rays` rays from group `seed`'s elements `members` (with their
/// cumulative areas) land.
fn landings_of(
    mesh: &Mesh,
    group_of: &[u32],
    members: &[(u32, f64)],
    seed: u64,
    rays: usize,
) -> GroupRays {
    let mut out = GroupRays {
        group: seed as u32,
        rays: rays as u32,
        ..GroupRays::default()
    };
    let Some(&(_, total)) = members.last() else {
        return out;
    };
    if total <= 0.0 {
        return out;
    }
    let mut rng = Rng(seed.wrapping_mul(0x2545_f491_4f6c_dd1d) ^ 0x5eed_a3b1);
    let mut hits: Vec<u32> = Vec::with_capacity(rays);
    // Directions: a Hammersley set of `rays` points, shifted by a random
    // offset (a Cranley-Patterson rotation: each point still uniform), dealt
    // to the area's slices in a random order, so both the points and the
    // directions are stratified and neither is tied to the other. At the
    // same rays a node's carried light scatters about 2.5x less between
    // seeds than with independent directions (docs/accuracy.md).
    let shift = [unit(&mut rng), unit(&mut rng)];
    let mut order: Vec<u32> = (0..rays as u32).collect();
    for k in (1..order.len()).rev() {
        order.swap(k, rng.below(k + 1));
    }
    let inv = 1.0 / rays as f32;
    for (r, &i) in order.iter().enumerate() {
        let d1 = ((i as f32 + 0.5) * inv + shift[0]).fract();
        let d2 = (i.reverse_bits() as f32 * (1.0 / 4_294_967_296.0) + shift[1]).fract();
        // Stratified in area: ray r picks its point in the r-th slice.
        let at = (r as f64 + unit(&mut rng) as f64) / rays as f64 * total;
        let k = members
            .partition_point(|&(_, c)| c < at)
            .min(members.len() - 1);
        let e = &mesh.elements[members[k].0 as usize];
        let corners: &[Vec3] = if e.corners[3] == e.corners[2] {
            &e.corners[..3]
        } else {
            &e.corners
        };
        let (p, _) = point_in(corners, unit(&mut rng), unit(&mut rng));
        let poly = &mesh.polygons[e.polygon as usize];
        let dir = cosine_direction(poly.normal, poly.tangent, d1, d2);
        let origin = p + poly.normal * mesh.ray_offset;
        let Some(hit) = nearest_other(mesh, origin, dir, e.polygon) else {
            continue; // leaves the scene
        };
        // Light meeting a back face is absorbed there (one-sided surfaces
        // are black behind).
        if mesh.polygons[hit.polygon as usize].normal.dot(dir) < 0.0 {
            hits.push(group_of[patch_at(mesh, hit.polygon, origin + dir * hit.t) as usize]);
        } else {
            out.back += 1;
        }
    }
    hits.sort_unstable();
    for g in hits {
        match out.hits.last_mut() {
            Some((last, n)) if *last == g => *n += 1,
            _ => out.hits.push((g, 1)),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::MeshSettings;
    use crate::scene::{Scene, Subdivision};

    /// A closed unit cube of six inward-facing squares (reflectance `rho`),
    /// each of `patches` x `patches` patches.
    fn cube(rho: f32, patches: u32) -> Mesh {
        let mut polygons = crate::scene::inward_unit_cube(rho);
        for p in &mut polygons {
            p.subdivision = Some(Subdivision {
                patches: [patches; 2],
                elements: [1; 2],
            });
        }
        let scene = Scene {
            nodes: vec!["box".into(); 1],
            polygons,
            ..Default::default()
        };
        Mesh::build(&scene, &MeshSettings::default())
    }

    #[test]
    fn a_closed_cube_sends_every_ray_to_the_other_faces() {
        let mesh = cube(0.5, 2);
        let t = Transport::new(&mesh);
        assert_eq!(t.groups(), 24, "one group a patch");
        let face = |g: usize| mesh.patches[g].polygon as usize;
        let mut faces = [[0.0; 6]; 6];
        for q in 0..t.groups() {
            let sum: f64 = t.row(q).iter().map(|(_, s)| s).sum();
            assert!((sum - 1.0).abs() < 1e-12, "group {q}: {sum}");
            for &(p, s) in t.row(q) {
                assert_ne!(face(p as usize), face(q), "a flat face cannot light itself");
                faces[face(q)][face(p as usize)] += s / 4.0;
            }
        }
        // Unit cube: the opposite face takes 0.19982, each adjacent one 0.20004.
        for (q, row) in faces.iter().enumerate() {
            for (p, s) in row.iter().enumerate().filter(|&(p, _)| p != q) {
                assert!((s - 0.2).abs() < 0.01, "{q} -> {p}: {s}");
            }
        }
    }

    #[test]
    fn in_a_closed_uniform_box_the_carried_light_is_cohens() {
        // Uniform unshot radiosity u on every face of a closed box of
        // reflectance rho: every face receives u / (1 - rho) in all.
        let rho = 0.6;
        let mesh = cube(rho as f32, 2);
        let t = Transport::new(&mesh);
        let u = [1.0, 0.5, 0.0];
        let unshot: Vec<[f64; 3]> = (0..t.groups())
            .map(|g| u.map(|x| x * mesh.patches[g].area))
            .collect();
        let e = t.irradiance(&unshot);
        for (g, h) in e.iter().enumerate() {
            for c in 0..3 {
                let want = u[c] / (1.0 - rho);
                assert!(
                    (h[c] - want).abs() <= 0.05 * want,
                    "{g}/{c}: {} vs {want}",
                    h[c]
                );
            }
        }
        // The whole power is carried: the rows sum to 1.
        let total: f64 = e
            .iter()
            .zip(&mesh.patches)
            .map(|(h, p)| h[0] * p.area)
            .sum();
        assert!((total - 6.0 / (1.0 - rho)).abs() < 1e-4, "{total}");
    }

    #[test]
    fn the_emitters_groups_cast_more_rays_from_a_budget_of_their_own() {
        let mut mesh = cube(0.5, 16);
        mesh.polygons[0].exitance = [1.0; 3];
        let group_of = groups(&mesh);
        let rays = Plan::rays_of(&mesh, &group_of, 6 * 256, RAY_BUDGET);
        let even = (RAY_BUDGET / (6 * 256)) as u32;
        for (p, (&g, &r)) in mesh.patches.iter().zip(group_of.iter().zip(&rays)) {
            let want = if p.polygon == 0 { 1024 } else { even };
            assert_eq!(r, want, "group {g}");
        }
        let extra: u32 = rays.iter().map(|&r| r - even).sum();
        assert!(extra as usize <= RAY_BUDGET);
        // No emitter: every group casts the even share.
        mesh.polygons[0].exitance = [0.0; 3];
        assert!(Plan::rays_of(&mesh, &group_of, 6 * 256, RAY_BUDGET)
            .iter()
            .all(|&r| r == even));
    }

    #[test]
    fn the_groups_are_cut_into_runs_each_once_the_dearest_first() {
        let mut mesh = cube(0.5, 16);
        mesh.polygons[0].exitance = [1.0; 3];
        let group_of = groups(&mesh);
        let count = group_of.len();
        let plan = Plan {
            mesh: &mesh,
            members: Members::of(&group_of, count),
            rays: Plan::rays_of(&mesh, &group_of, count, RAY_BUDGET),
            group_of,
        };
        let dearest = plan.rays.iter().copied().max().unwrap_or(0);
        let total: u32 = plan.rays.iter().sum();
        for pieces in [1, 2, 5, 64, 10_000] {
            let runs = plan.pieces(pieces);
            let mut seen = vec![0; count];
            for run in &runs {
                assert!(!run.is_empty(), "{pieces} pieces: an empty run");
                for g in run.clone() {
                    seen[g] += 1;
                }
            }
            assert!(
                seen.iter().all(|&n| n == 1),
                "{pieces} pieces: each group once"
            );
            let rays = |r: &std::ops::Range<usize>| plan.rays[r.clone()].iter().sum::<u32>();
            assert!(
                runs.windows(2).all(|w| rays(&w[0]) >= rays(&w[1])),
                "{pieces} pieces: the dearest first"
            );
            // A run holds at most a share, or a single dearer group.
            let share = total.div_ceil(pieces as u32);
            for run in &runs {
                assert!(
                    rays(run) <= share.max(dearest) || run.len() == 1,
                    "{pieces} pieces: a run of {} rays against a share of {share}",
                    rays(run)
                );
            }
            // Runs are cut only where the next group would overfill one:
            // no two neighbours together fit a share.
            let mut in_order = runs.clone();
            in_order.sort_by_key(|r| r.start);
            for w in in_order.windows(2) {
                assert!(rays(&w[0]) + plan.rays[w[1].start] > share);
            }
        }
    }

    #[test]
    fn the_same_shares_on_every_run() {
        let mesh = cube(0.5, 2);
        let (a, b) = (Transport::new(&mesh), Transport::new(&mesh));
        assert_eq!(a.landings, b.landings);
        assert_eq!(a.offsets, b.offsets);
    }

    #[test]
    fn rays_cast_by_several_ranks_and_gathered_give_the_same_transport() {
        let mesh = cube(0.5, 2);
        let whole = Transport::new(&mesh);
        for ranks in [2, 3, 7] {
            let split = Transport::built(&mesh, |plan| {
                let mut gathered = Vec::new();
                // Runs taken by ranks in turn, backwards, as a pool might.
                let runs = plan.pieces(4 * ranks);
                for rank in 0..ranks {
                    let mut words = Vec::new();
                    for run in runs.iter().rev().skip(rank).step_by(ranks) {
                        for row in plan.cast_these(&run.clone().collect::<Vec<_>>()) {
                            row.pack(&mut words);
                        }
                    }
                    gathered.extend(GroupRays::unpack_all(&words).expect("whole words"));
                }
                gathered.sort_by_key(|r| r.group);
                gathered
            });
            assert_eq!(split.landings, whole.landings, "{ranks} ranks");
            assert_eq!(split.back, whole.back);
        }
        // Words cut short are refused, not misread.
        let mut words = Vec::new();
        let group_of = groups(&mesh);
        Plan {
            mesh: &mesh,
            members: Members::of(&group_of, group_of.len()),
            group_of,
            rays: vec![4; 24],
        }
        .cast(0)
        .pack(&mut words);
        let row = GroupRays {
            group: 3,
            rays: 8,
            hits: vec![(1, 2), (5, 6)],
            back: 0,
            area: 0.25,
            reflected: [0.125, -1.5e-300, f64::MAX],
        };
        row.pack(&mut words);
        let got = GroupRays::unpack_all(&words).expect("whole words");
        assert_eq!(got.len(), 2);
        assert_eq!(got[1], row, "every bit travels");
        assert_eq!(GroupRays::unpack_all(&words[..words.len() - 1]), None);
    }

    #[test]
    fn gathered_landings_carry_the_light_as_scattered_ones_do() {
        // Each group's landing gathered from where it came, on every core,
        // against a pass over the leaving groups (the way it was carried
        // first): the same bits, for signed unshot light with zero groups.
        let scene = crate::scene::open("cornell").expect("built-in scene");
        let mesh = Mesh::build(&scene, &MeshSettings::default());
        let t = Transport::new(&mesh);
        assert!(
            t.into.len() >= PARALLEL_CARRY,
            "{} landings: one thread",
            t.into.len()
        );
        let mut rng = crate::rng::Rng(7);
        let n = t.groups();
        let unshot: Vec<[f64; 3]> = (0..n)
            .map(|_| {
                if rng.below(4) == 0 {
                    [0.0; 3]
                } else {
                    [(); 3].map(|_| rng.unit() - 0.3)
                }
            })
            .collect();
        // The scattering pass, as it was.
        let start: f64 = unshot.iter().flatten().map(|x| x.abs()).sum();
        let (mut total, mut leaving) = (vec![[0.0; 3]; n], unshot.clone());
        let mut landing = vec![[0.0f64; 3]; n];
        for _ in 0..MAX_BOUNCES {
            landing.iter_mut().for_each(|l| *l = [0.0; 3]);
            for (q, out) in leaving.iter().enumerate() {
                if *out == [0.0; 3] {
                    continue;
                }
                for &(p, s) in t.row(q) {
                    for c in 0..3 {
                        landing[p as usize][c] += s * out[c];
                    }
                }
            }
            let mut flight = 0.0;
            for p in 0..n {
                for c in 0..3 {
                    total[p][c] += landing[p][c];
                    leaving[p][c] = t.reflectance[p][c] * landing[p][c];
                    flight += leaving[p][c].abs();
                }
            }
            if flight <= CARRY_TOLERANCE * start {
                break;
            }
        }
        let want: Vec<[f64; 3]> = total
            .iter()
            .zip(&t.area)
            .map(|(x, &a)| if a > 0.0 { x.map(|x| x / a) } else { [0.0; 3] })
            .collect();
        let got = t.irradiance(&unshot);
        let bits = |v: &[[f64; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert!(bits(&got) == bits(&want), "other irradiances");
    }

    #[test]
    fn big_meshes_group_patches_facing_the_same_way() {
        let mesh = cube(0.5, 40);
        assert!(mesh.patches.len() > PATCH_GROUPS);
        let of = groups(&mesh);
        let count = of.iter().max().map_or(0, |&g| g as usize + 1);
        assert!(
            (PATCH_GROUPS / 8..=PATCH_GROUPS).contains(&count),
            "{count} groups"
        );
        let mut face = vec![None; count];
        for (p, &g) in mesh.patches.iter().zip(&of) {
            let f = face[g as usize].get_or_insert(p.polygon);
            assert_eq!(*f, p.polygon, "group {g} mixes faces");
        }
    }
}
