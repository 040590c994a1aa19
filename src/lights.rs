//! What lights that are not surfaces deliver ([`crate::scene::light`]):
//! point and spot lights, directional lights (a sun) and a uniform sky.
//!
//! They shoot once, before the first patch does, and never receive. A
//! point light is exact by ray casting: each element's mean irradiance is
//! I cos / r^2 (times the spot falloff) at stratified points on it, each
//! with one shadow ray to the light, so its shadows are as sharp as the
//! elements (and, in the camera image, which traces the same rays per
//! pixel, as sharp as the geometry). A directional light is the same with
//! parallel rays: one ray per point is the parallel projection over the
//! scene the issue asks for, with exact visibility. The sky is radiance L
//! from every direction that leaves the scene: at each point, shadow rays
//! along a stratified cosine-weighted pattern of directions count the share
//! that escapes, and E = pi L times that share (exact over an open floor).
//!
//! Every element's value depends only on its index (a seeded generator per
//! element), so every rank computes the same field bit for bit. Pure maths:
//! no GPU, no radiosity updates.

use crate::mesh::Mesh;
use crate::raytrace::{Bvh, Hints, RECENT_HINTS};
use crate::rng::Rng;
use crate::sampling::{in_parallel, point_in, unit, RayStart};
use crate::scene::sky::MapSample;
use crate::scene::{Background, Light, LightKind};
use glam::Vec3;

pub use crate::sampling::ELEMENT_POINTS;

/// Points an element: [`ELEMENT_POINTS`] squared.
const POINTS: usize = (ELEMENT_POINTS * ELEMENT_POINTS) as usize;

/// The fewest sky directions per element point along each axis: each
/// element's points share one `(ELEMENT_POINTS * side)^2` stratification
/// of the cosine-weighted hemisphere (64 directions an element).
pub const SKY_RAYS: u32 = 2;

/// The most: 8 x 8 x 16 = 1024 directions an element. Through a window,
/// 64 directions put about three rays through it, and the walls' sky
/// light was splotched by +-60 % from element to element.
pub const MAX_SKY_RAYS: u32 = 8;

/// Sky directions per element, times the scene's polygons: an element
/// takes `SKY_BUDGET / polygons` directions (within 64 and 1024), so a
/// 290-polygon furnished room takes 1024 and Sponza's 288 718 polygons
/// stay at 64 (docs/notebook/gather.md).
pub const SKY_BUDGET: u64 = 1 << 25;

/// Sky directions per point along each axis for `mesh`'s elements: from
/// the scene's polygon count, which refinement leaves alone (a refined
/// mesh's field reuses the unrefined one's, bit for bit).
fn sky_rays(mesh: &Mesh) -> u32 {
    let per_element = SKY_BUDGET / (mesh.polygons.len() as u64).max(1);
    let points = u64::from(ELEMENT_POINTS * ELEMENT_POINTS);
    let side = ((per_element / points) as f64).sqrt() as u32;
    side.clamp(SKY_RAYS, MAX_SKY_RAYS)
}

/// What the lights and the sky deliver to each element of a mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LightField {
    /// Mean irradiance from the point, spot and directional lights per
    /// element, W/m^2 per channel (what the camera image traces again per
    /// pixel: the solution's direct part).
    pub direct: Vec<[f64; 3]>,
    /// Mean irradiance from the sky per element, W/m^2 per channel (left
    /// in the interpolated rest of the image).
    pub sky: Vec<[f64; 3]>,
    /// The power the lights and sky emit, W (sum over RGB): a point or
    /// spot light's whole power, plus what directional lights and the sky
    /// deliver to the elements (their power depends on what they fall on).
    pub emitted: f64,
    /// The power delivered to the elements, W (sum over RGB).
    pub delivered: f64,
    /// Of `direct`, the directional lights' part per element (sum over RGB).
    pub directional: Vec<f64>,
}

/// A light field kept from a mesh to be reused by another mesh of the same
/// scene (a refinement pass's next mesh, see [`element_field_reusing`]):
/// the field and where each polygon's elements were.
#[derive(Clone, Debug, Default)]
pub struct KeptField {
    field: LightField,
    /// Per polygon: its elements, patch grid and element grid.
    polygons: Vec<(std::ops::Range<u32>, [u32; 2], [u32; 2])>,
}

impl KeptField {
    /// Keeps `field`, the light field of `mesh`, to reuse.
    pub fn new(field: LightField, mesh: &Mesh) -> Self {
        Self {
            field,
            polygons: mesh
                .polygons
                .iter()
                .map(|p| (p.elements.clone(), p.patch_grid, p.element_grid))
                .collect(),
        }
    }

    /// Where element `j` of `mesh` (of polygon `polygon`) was, if its
    /// polygon was subdivided alike.
    fn find(&self, mesh: &Mesh, j: usize) -> Option<usize> {
        let polygon = mesh.elements[j].polygon as usize;
        let p = &mesh.polygons[polygon];
        let (was, patches, elements) = self.polygons.get(polygon)?;
        let alike = *patches == p.patch_grid
            && *elements == p.element_grid
            && was.len() == p.elements.len()
            && !self.field.direct.is_empty();
        alike.then(|| was.start as usize + (j - p.elements.start as usize))
    }
}

impl LightField {
    /// Whether there is nothing (no lights and no sky).
    pub fn is_empty(&self) -> bool {
        self.direct.is_empty()
    }
}

/// Irradiance (W/m^2 per channel) from `light` at `x` on polygon `polygon`
/// (normal `n`), with one shadow ray from `x + n eps` (0 where anything but
/// `polygon` blocks it). The ray tries first the leaves `hints` that stopped
/// recent ones (see [`Bvh::occluded_recent`]: the same answer, sooner
/// where neighbouring points are shadowed by the same occluder).
pub fn irradiance(
    light: &Light,
    bvh: &Bvh,
    x: Vec3,
    n: Vec3,
    polygon: u32,
    eps: f32,
    hints: &mut Hints,
) -> [f64; 3] {
    let origin = x + n * eps;
    let skip = [polygon, polygon];
    let scale = match light.kind {
        LightKind::Directional => {
            let toward = -light.direction;
            let cos = n.dot(toward);
            if cos <= 0.0 || bvh.occluded_recent(origin, toward, 0.0, f32::INFINITY, skip, hints) {
                return [0.0; 3];
            }
            f64::from(cos)
        }
        LightKind::Point | LightKind::Spot { .. } => {
            let d = light.position - origin;
            let r2 = f64::from(d.length_squared());
            let cos = n.dot(d);
            if cos <= 0.0 || r2 <= 0.0 {
                return [0.0; 3];
            }
            let unit_d = d.normalize();
            let falloff = light.falloff(-unit_d);
            if falloff <= 0.0 || bvh.occluded_recent(origin, d, 0.0, 1.0, skip, hints) {
                return [0.0; 3];
            }
            falloff * f64::from(cos) / (r2 * r2.sqrt())
        }
    };
    light.intensity.map(|i| i * scale)
}

/// The share of the cosine-weighted hemisphere over `n` at `x` that leaves
/// the scene, from shadow rays along the cells `first..first+side` (each
/// axis) of a `grid` x `grid` stratification (one jittered direction a
/// cell), each trying first the leaves that stopped recent ones (`hints`).
fn sky_share(bvh: &Bvh, from: RayStart, cells: Cells, rng: &mut Rng, hints: &mut Hints) -> f64 {
    let RayStart {
        origin,
        normal: n,
        polygon,
    } = from;
    let (t, b) = frame(n);
    let g = cells.grid as f32;
    let (mut open, mut all) = (0u32, 0u32);
    for i in 0..cells.side * cells.side {
        let u1 = ((cells.first[0] + i % cells.side) as f32 + unit(rng)) / g;
        let u2 = ((cells.first[1] + i / cells.side) as f32 + unit(rng)) / g;
        let (r, phi) = (u1.sqrt(), std::f32::consts::TAU * u2);
        let d = t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt();
        all += 1;
        if !bvh.occluded_recent(origin, d, 0.0, f32::INFINITY, [polygon, polygon], hints) {
            open += 1;
        }
    }
    if all == 0 {
        0.0
    } else {
        f64::from(open) / f64::from(all)
    }
}

/// Which cells of a stratification a point's sky rays take.
#[derive(Clone, Copy)]
struct Cells {
    grid: u32,
    first: [u32; 2],
    side: u32,
}

/// Two unit tangents completing `n` to a right-handed frame.
fn frame(n: Vec3) -> (Vec3, Vec3) {
    let helper = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let t = n.cross(helper).normalize();
    (t, n.cross(t))
}

/// What `lights` and the sky `sky` deliver to every element of
/// `mesh` (its [`Mesh::occluders`] give visibility): the mean over
/// [`ELEMENT_POINTS`]^2 jittered points of each element. Empty when there
/// are no lights and no sky.
pub fn element_field(mesh: &Mesh, lights: &[Light], sky: Background) -> LightField {
    element_field_reusing(mesh, lights, sky, None)
}

/// [`element_field`], copying from `kept` (the field of another mesh of the
/// same scene) the values of every polygon subdivided alike in both. An
/// element's values depend only on the scene, its polygon and its place in
/// it (its random numbers too), so the field is the one [`element_field`]
/// gives, bit for bit, and a refinement pass's next mesh casts rays only
/// for the polygons it refined.
pub fn element_field_reusing(
    mesh: &Mesh,
    lights: &[Light],
    sky: Background,
    kept: Option<&KeptField>,
) -> LightField {
    let sky = (!sky.is_dark()).then_some(sky);
    if lights.is_empty() && sky.is_none() {
        return LightField::default();
    }
    // Per element: the lights' irradiance, the sky's, and the part of the
    // first from directional lights (sum over RGB).
    let sky_rays = sky_rays(mesh);
    let work = |j: usize, out: &mut ([f64; 3], [f64; 3], f64)| {
        if let Some((k, f)) = kept.and_then(|f| Some((f.find(mesh, j)?, &f.field))) {
            *out = (f.direct[k], f.sky[k], f.directional[k]);
            return;
        }
        *out = element_light(mesh, lights, sky.map(|s| (s, sky_rays)), j);
    };
    let started = std::time::Instant::now();
    let mut values = vec![([0.0; 3], [0.0; 3], 0.0); mesh.elements.len()];
    in_parallel(&mut values, work);
    if sky_rays < MAX_SKY_RAYS {
        pool_sky_by_patch(mesh, &mut values, |j| {
            kept.and_then(|f| f.find(mesh, j)).is_some()
        });
    }
    // The field is most of a big sunlit scene's mesh time: say what it cost.
    log::debug!(
        "light field: {} elements, {} lights{}, {:.2} s",
        mesh.elements.len(),
        lights.len(),
        if sky.is_some() { " and the sky" } else { "" },
        started.elapsed().as_secs_f64()
    );
    // Point and spot lights emit their whole power whatever they meet;
    // directional lights and the sky emit what they deliver (their power
    // depends on what they fall on).
    let (mut emitted, mut delivered) = (lights.iter().filter_map(Light::power).sum::<f64>(), 0.0);
    for (e, (d, s, p)) in mesh.elements.iter().zip(&values) {
        let sky_power = s.iter().sum::<f64>();
        delivered += (d.iter().sum::<f64>() + sky_power) * e.area;
        emitted += (p + sky_power) * e.area;
    }
    LightField {
        direct: values.iter().map(|v| v.0).collect(),
        sky: values.iter().map(|v| v.1).collect(),
        emitted,
        delivered,
        directional: values.iter().map(|v| v.2).collect(),
    }
}

/// Gives each patch's elements their area-weighted mean sky light (the
/// `.1` of `values`): where an element's few sky rays find the sky seen
/// through an opening, their noise is tens of per cent from element to
/// element, and a patch's elements share their rays' worth. Patches whose
/// values were `copied` (already pooled) stay as they are.
fn pool_sky_by_patch(
    mesh: &Mesh,
    values: &mut [([f64; 3], [f64; 3], f64)],
    copied: impl Fn(usize) -> bool,
) {
    for p in &mesh.patches {
        let range = p.elements.start as usize..p.elements.end as usize;
        if range.len() < 2 || copied(range.start) {
            continue;
        }
        let (mut sum, mut area) = ([0.0f64; 3], 0.0f64);
        for j in range.clone() {
            let a = mesh.elements[j].area;
            (0..3).for_each(|c| sum[c] += values[j].1[c] * a);
            area += a;
        }
        if area > 0.0 {
            for j in range {
                values[j].1 = sum.map(|x| x / area);
            }
        }
    }
}

/// Element `j`'s mean irradiance from the lights, from the sky `sky.0`,
/// and the lights' part that is directional (sum over RGB), over jittered
/// points on it, each with shadow rays (`sky.1` x `sky.1` sky directions a
/// point for the sky's floor, as many again for a map's rest).
fn element_light(
    mesh: &Mesh,
    lights: &[Light],
    sky: Option<(Background, u32)>,
    j: usize,
) -> ([f64; 3], [f64; 3], f64) {
    let (eps, bvh) = (mesh.ray_offset, &mesh.occluders);
    let e = &mesh.elements[j];
    let n = mesh.polygons[e.polygon as usize].normal;
    let corners: &[Vec3] = if e.corners[3] == e.corners[2] {
        &e.corners[..3]
    } else {
        &e.corners
    };
    // Seeded by the element's polygon and place in it, not its index in
    // the mesh, so that another mesh's field can be reused.
    let local = j as u64 - u64::from(mesh.polygons[e.polygon as usize].elements.start);
    let mut rng = Rng(0x119b_7000_0000 ^ (u64::from(e.polygon) << 32) ^ local);
    let side = ELEMENT_POINTS;
    let (mut direct, mut parallel, mut weight) = ([0.0; 3], 0.0, 0.0);
    // The leaves that stopped each light's recent rays, and the sky's:
    // an element's points are mostly shadowed by the same few occluders.
    let mut hints = vec![[None; RECENT_HINTS]; lights.len()];
    let mut sky_hints = [None; RECENT_HINTS];
    let mut points = Vec::with_capacity((side * side) as usize);
    for q in 0..side * side {
        let u = ((q % side) as f32 + unit(&mut rng)) / side as f32;
        let v = ((q / side) as f32 + unit(&mut rng)) / side as f32;
        let (x, jac) = point_in(corners, u, v);
        points.push((x, jac));
        let jac = f64::from(jac);
        for (light, hint) in lights.iter().zip(&mut hints) {
            let d = irradiance(light, bvh, x, n, e.polygon, eps, hint);
            for c in 0..3 {
                direct[c] += d[c] * jac;
            }
            if light.kind == LightKind::Directional {
                parallel += d.iter().sum::<f64>() * jac;
            }
        }
        weight += jac;
    }
    if weight <= 0.0 {
        return ([0.0; 3], [0.0; 3], 0.0);
    }
    let Some((background, rays)) = sky else {
        return (direct.map(|d| d / weight), [0.0; 3], parallel / weight);
    };
    let mut blocks: [u32; POINTS] = std::array::from_fn(|k| k as u32);
    for k in (1..blocks.len()).rev() {
        blocks.swap(k, rng.below(k + 1));
    }
    let at = SkyPoints {
        points: &points,
        blocks,
        normal: n,
        polygon: e.polygon,
        eps,
    };
    let (sky, sun) = at.light(bvh, background, rays, &mut rng, &mut sky_hints);
    // A map's sun is direct light (the image traces it again); like a
    // directional light's, its power is what it delivers.
    let direct = [0, 1, 2].map(|c| direct[c] / weight + sun[c]);
    let parallel = parallel / weight + sun.iter().sum::<f64>();
    (direct, sky, parallel)
}

/// An element's points (and their area weights) as its sky rays leave them.
struct SkyPoints<'a> {
    points: &'a [(Vec3, f32)],
    /// Per point, which block of the directions' stratification it takes:
    /// shuffled per element, so that no part of the element always looks
    /// the same way (a fixed pairing biases an element that sees the sky
    /// through an opening from some of its points only).
    blocks: [u32; POINTS],
    normal: Vec3,
    polygon: u32,
    eps: f32,
}

impl SkyPoints<'_> {
    /// The points' weighted irradiance from `background` (`rays` x `rays`
    /// directions a point), as the sky's part and a map's sun. The floor
    /// lights as a uniform sky: pi L times the open share of the
    /// cosine-weighted hemisphere (exact over an open floor). A map's sky
    /// and its sun by directions drawn from each one's brightness, apart,
    /// the sun with a quarter of them (its visibility is nearly all or
    /// nothing).
    fn light(
        &self,
        bvh: &Bvh,
        background: Background,
        rays: u32,
        rng: &mut Rng,
        hints: &mut Hints,
    ) -> ([f64; 3], [f64; 3]) {
        let floor = background.floor();
        let mut sky = [0.0; 3];
        if floor.iter().any(|&l| l > 0.0) {
            let open = self.share(bvh, rays, rng, hints);
            sky = floor.map(|l| std::f64::consts::PI * l * open);
        }
        let Some(map) = background.map.filter(|m| m.has_rest()) else {
            return (sky, [0.0; 3]);
        };
        let rest = self.map_irradiance(bvh, |u1, u2| map.sample(u1, u2), rays, rng, hints);
        (0..3).for_each(|c| sky[c] += rest[c]);
        if !map.has_sun() {
            return (sky, [0.0; 3]);
        }
        let draw = |u1, u2| map.sample_sun(u1, u2);
        let sun = self.map_irradiance(bvh, draw, (rays / 2).max(1), rng, hints);
        (sky, sun)
    }

    /// The points' weighted sky share, with `rays` x `rays` directions a
    /// point, all of them one stratification of the hemisphere.
    fn share(&self, bvh: &Bvh, rays: u32, rng: &mut Rng, hints: &mut Hints) -> f64 {
        let side = ELEMENT_POINTS;
        let (mut open, mut weight) = (0.0, 0.0);
        for (&b, &(x, jac)) in self.blocks.iter().zip(self.points) {
            let cells = Cells {
                grid: side * rays,
                first: [b % side * rays, b / side * rays],
                side: rays,
            };
            let from = RayStart {
                origin: x + self.normal * self.eps,
                normal: self.normal,
                polygon: self.polygon,
            };
            open += sky_share(bvh, from, cells, rng, hints) * f64::from(jac);
            weight += f64::from(jac);
        }
        if weight > 0.0 {
            open / weight
        } else {
            0.0
        }
    }

    /// The points' weighted irradiance from a map's directions `draw`
    /// gives, `rays` x `rays` a point, all of them one stratification of
    /// the unit square `draw` maps.
    fn map_irradiance(
        &self,
        bvh: &Bvh,
        draw: impl Fn(f64, f64) -> Option<MapSample>,
        rays: u32,
        rng: &mut Rng,
        hints: &mut Hints,
    ) -> [f64; 3] {
        let side = ELEMENT_POINTS;
        let grid = f64::from(side * rays);
        let (mut sum, mut weight) = ([0.0; 3], 0.0);
        for (&b, &(x, jac)) in self.blocks.iter().zip(self.points) {
            let origin = x + self.normal * self.eps;
            let mut e = [0.0; 3];
            for i in 0..rays * rays {
                let u1 = (f64::from(b % side * rays + i % rays) + rng.unit()) / grid;
                let u2 = (f64::from(b / side * rays + i / rays) + rng.unit()) / grid;
                let Some(m) = draw(u1, u2) else {
                    continue;
                };
                let (d, skip) = (m.direction, [self.polygon, self.polygon]);
                let cos = f64::from(d.dot(self.normal));
                if cos <= 0.0 || bvh.occluded_recent(origin, d, 0.0, f32::INFINITY, skip, hints) {
                    continue;
                }
                (0..3).for_each(|c| e[c] += m.weight[c] * cos);
            }
            let share = f64::from(jac) / f64::from(rays * rays);
            (0..3).for_each(|c| sum[c] += e[c] * share);
            weight += f64::from(jac);
        }
        if weight > 0.0 {
            sum.map(|s| s / weight)
        } else {
            [0.0; 3]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::MeshSettings;

    #[test]
    fn pooled_sky_light_is_each_patchs_area_mean_and_keeps_the_power() {
        let mesh = Mesh::build(
            &crate::scene::open("cornell").expect("built-in"),
            &MeshSettings::default(),
        );
        let mut values: Vec<_> = (0..mesh.elements.len())
            .map(|j| ([0.0; 3], [(j % 7) as f64; 3], 0.0))
            .collect();
        let power = |v: &[([f64; 3], [f64; 3], f64)]| -> f64 {
            mesh.elements
                .iter()
                .zip(v)
                .map(|(e, v)| e.area * v.1[0])
                .sum()
        };
        let before = power(&values);
        // The first patch's polygon counts as copied: it stays.
        let first = mesh.patches[0].elements.clone();
        let kept: Vec<_> = values[first.start as usize..first.end as usize].to_vec();
        pool_sky_by_patch(&mesh, &mut values, |j| first.contains(&(j as u32)));
        assert_eq!(kept, values[first.start as usize..first.end as usize]);
        assert!((power(&values) - before).abs() <= 1e-9 * before);
        for p in &mesh.patches[1..] {
            let v = &values[p.elements.start as usize..p.elements.end as usize];
            assert!(v.iter().all(|x| (x.1[0] - v[0].1[0]).abs() < 1e-12));
        }
    }

    #[test]
    fn a_refined_mesh_reuses_the_field_of_its_unrefined_polygons_bit_for_bit() {
        // The Cornell box under a sun and a sky: refine every other polygon.
        let mut scene = crate::scene::open("cornell").expect("built-in");
        scene.lights.push(Light {
            name: "sun".into(),
            kind: LightKind::Directional,
            position: Vec3::ZERO,
            direction: Vec3::new(0.3, -1.0, 0.2).normalize(),
            intensity: [500.0; 3],
        });
        scene.sky = Some([3.0; 3]);
        let settings = MeshSettings::default();
        use crate::lit_mesh::LitMesh;
        let mut coarse = LitMesh::build(&scene, &settings);
        let factors: Vec<u32> = (0..scene.polygons.len())
            .map(|i| 1 + i as u32 % 2)
            .collect();
        let fresh = LitMesh::build_refined(&scene, &settings, &factors);
        let kept = coarse.take_field();
        let reused = LitMesh::build_refined_from(&scene, &settings, &factors, Some(&kept));
        assert!(fresh.light_field.sky.iter().any(|s| s[0] > 0.0));
        assert!(fresh.light_field.direct.iter().any(|d| d[0] > 0.0));
        assert_eq!(reused.light_field, fresh.light_field);
        // Every element of an unrefined polygon was copied, none of a refined one.
        for (j, e) in reused.elements.iter().enumerate() {
            let refined = factors[e.polygon as usize] > 1;
            assert_eq!(kept.find(&reused, j).is_some(), !refined, "element {j}");
        }
    }
}
