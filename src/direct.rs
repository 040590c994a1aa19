//! Direct light with exact visibility, for the camera image: at a point, each
//! emitter's unoccluded form factor (Lambert's contour integral, exact) times
//! the share of the emitter the point sees, estimated by shadow rays to
//! stratified points on the emitter (a ratio estimator pooled over a pixel's
//! samples or an element's points, see [`Pool`]: exact where they see all or
//! none of the emitter, noisy only in penumbrae); and each point,
//! spot or directional light's irradiance with its one shadow ray
//! (`lights::irradiance`).
//!
//! The image is then the solution's indirect part, interpolated, plus this
//! direct part per pixel: contact shadows and shadow edges as sharp as the
//! geometry makes them, however coarse the mesh. No GPU, no radiosity
//! updates: the solver's numbers are untouched.

use crate::formfactor::point_to_polygon;
use crate::gather::{Gather, GatherPixel};
use crate::mesh::Mesh;
use crate::raytrace::Bvh;
use crate::rng::Rng;
use crate::sampling::{in_parallel, point_in, unit, RayStart, Strata};
use crate::scene::{Camera, Scene};
use glam::{DVec3, Vec3};

/// An emitting polygon, as direct light sees it.
#[derive(Clone, Debug)]
struct Emitter<'a> {
    polygon: u32,
    corners: Vec<Vec3>,
    exact: Vec<DVec3>,
    normal: Vec3,
    centre: Vec3,
    /// Exitance pi * L_e per channel, W/m^2 (with an emissive texture,
    /// its mean over the polygon).
    exitance: [f64; 3],
    /// The emissive texture, if it has one: the shadow rays weigh its
    /// points by their exitance over `exitance`.
    texture: Option<&'a crate::scene::TexMap>,
}

/// Direct irradiance from a scene's emitters at any surface point.
#[derive(Clone, Debug)]
pub struct DirectLight<'a> {
    bvh: &'a Bvh,
    emitters: Vec<Emitter<'a>>,
    /// Point, spot and directional lights (one shadow ray each).
    lights: Vec<crate::scene::Light>,
    normals: Vec<Vec3>,
    reflectance: Vec<[f32; 3]>,
    /// Each polygon's texture map, if it has one (`reflectance` is then its mean).
    textures: Vec<Option<&'a crate::scene::TexMap>>,
    /// Each polygon's emissive texture map, if it has one (the image shows
    /// its emission per sample: see [`Image::emitted`]).
    emissive: Vec<Option<&'a crate::scene::TexMap>>,
    /// Shadow rays per emitter per point (per image sample): `strata` x `strata`.
    strata: u32,
    /// Offset of ray ends off their surfaces, m.
    eps: f32,
    /// What camera rays that leave the scene see.
    sky: crate::scene::Background<'a>,
}

pub use crate::sampling::ELEMENT_POINTS;

/// Shadow rays per emitter per element point, along each axis.
pub const ELEMENT_RAYS: u32 = 2;

/// The most element and emitter pairs whose direct light is traced
/// ([`DirectLight::emitter_field`]): each pair costs [`EMITTER_SAMPLES`]'
/// 64 contour integrals and 64 shadow rays (cubes-b1's coarse mesh, 1.2
/// million pairs: 2.45 s on two cores).
pub const MAX_TRACED_PAIRS: usize = 4_000_000;

/// Points along each side of an element, and shadow rays along each side
/// from each point, of [`DirectLight::emitter_field`]: 8 x 8 points of one
/// ray kept its sum within 0.11 % of the emitted power on cubes-b1's
/// coarse mesh, where 4 x 4 of 2 x 2 missed by 0.25 %
/// (docs/notebook/visibility.md).
pub const EMITTER_SAMPLES: (u32, u32) = (8, 1);

/// What the emitting polygons deliver to each element, traced: their first
/// shot, with visibility integrated over the whole emitter (shadow rays to
/// stratified points of it from stratified points of each element) where a
/// hemisphere would sample it from one point of each patch and alias
/// against regular geometry. The emitters' emission is then shot.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EmitterField {
    /// Mean irradiance per element, W/m^2 per channel.
    pub irradiance: Vec<[f64; 3]>,
    /// The emitters' power, W (sum over RGB).
    pub power: f64,
    /// The power delivered to the elements, W (sum over RGB).
    pub delivered: f64,
}

/// What a set of points (an image pixel's samples, an element's points)
/// gathers of the direct light, weighted per point. Each emitter's visible
/// share is one ratio over all the points' shadow rays (their
/// cos cos / r^2 seen over all of it): exact where the points see all of
/// the emitter or none, and over many rays spread across the emitter
/// (each point's strata are a block of one stratification) right in
/// penumbrae too. A ratio per point, from the one ray an image sample
/// casts, counted the emitter's visible *area*: under a large emitter seen
/// through an opening its near part weighs more, and the penumbra was
/// 25-40 % too bright.
struct Pool {
    /// Point, spot and directional lights' weighted irradiance.
    lights: [f64; 3],
    /// Per emitter, the points' weighted unoccluded irradiance.
    unoccluded: Vec<[f64; 3]>,
    /// Per emitter, its shadow rays' weights: the seen ones' per channel
    /// (times the emitter's exitance there over its mean, on an emissive
    /// texture), and all of them.
    rays: Vec<([f64; 3], f64)>,
    /// Per light, then per emitter, the leaf that stopped the last shadow
    /// ray toward it (a pixel's or an element's points are near each other
    /// and mostly shadowed alike; see `Bvh::occluded_hinted`, which gives
    /// the same answer whatever the hint).
    hints: Vec<crate::raytrace::Hints>,
}

impl Pool {
    fn new(emitters: usize, lights: usize) -> Self {
        Pool {
            lights: [0.0; 3],
            unoccluded: vec![[0.0; 3]; emitters],
            rays: vec![([0.0; 3], 0.0); emitters],
            // One more for a sky map's sun, last.
            hints: vec![[None; crate::raytrace::RECENT_HINTS]; lights + emitters + 1],
        }
    }

    /// The weighted sum of the points' direct irradiance.
    fn total(&self) -> [f64; 3] {
        let mut out = self.lights;
        for (u, (seen, all)) in self.unoccluded.iter().zip(&self.rays) {
            for c in 0..3 {
                let share = if *all > 0.0 { seen[c] / all } else { 1.0 };
                out[c] += u[c] * share;
            }
        }
        out
    }
}

/// What [`DirectLight::image`] gives: per pixel the direct radiance and the
/// texture multiplier, and which polygons the pixels saw.
#[derive(Clone, Debug)]
pub struct Image {
    /// Reflected direct radiance per pixel.
    pub direct: Vec<[f32; 3]>,
    /// Per polygon, whether some sample saw it.
    pub seen: Vec<bool>,
    /// Per pixel, the mean texture reflectance over its samples (1 where
    /// they meet no textured polygon).
    pub texture: Vec<[f32; 3]>,
    /// Per pixel, the sky's radiance along its samples' camera rays that
    /// left the scene, over all its samples (what the sky adds there).
    pub sky: Vec<[f32; 3]>,
    /// Per pixel, the emitted radiance of the emissive textures its
    /// samples met (front sides), over all its samples; the image shows
    /// it in place of those elements' mean emission.
    pub emitted: Vec<[f32; 3]>,
    /// Per pixel, with a final gather ([`Gather`]), what its samples
    /// gathered (else empty).
    pub gathered: Vec<GatherPixel>,
}

impl Image {
    /// The image of `pixels` over a scene of `polygons`, with what they
    /// gathered if `gathered`.
    fn of(pixels: &[PixelSums], polygons: usize, gathered: bool) -> Self {
        let mut seen = vec![false; polygons];
        for p in pixels {
            if p.polygon > 0 {
                seen[p.polygon as usize - 1] = true;
            }
        }
        Image {
            direct: pixels.iter().map(|p| p.direct).collect(),
            seen,
            texture: pixels.iter().map(|p| p.texture).collect(),
            sky: pixels.iter().map(|p| p.sky).collect(),
            emitted: pixels.iter().map(|p| p.emitted).collect(),
            gathered: match gathered {
                true => pixels.iter().map(|p| p.gathered).collect(),
                false => Vec::new(),
            },
        }
    }
}

/// One pixel of [`DirectLight::image`] as its samples build it.
#[derive(Clone, Copy)]
struct PixelSums {
    direct: [f32; 3],
    /// 1 + the last polygon a sample saw (0: none).
    polygon: u32,
    texture: [f32; 3],
    sky: [f32; 3],
    emitted: [f32; 3],
    gathered: GatherPixel,
}

impl PixelSums {
    /// Adds one of `per_pixel` samples whose camera ray left the scene and
    /// saw the sky's `radiance`.
    fn add_sky(&mut self, radiance: [f32; 3], per_pixel: f64) {
        (0..3).for_each(|c| self.sky[c] += radiance[c] / per_pixel as f32);
    }

    /// Adds one of `per_pixel` samples' emission where it met `x` on a
    /// polygon whose emissive texture is `map`, if any.
    fn add_emitted(&mut self, map: Option<&crate::scene::TexMap>, x: Vec3, per_pixel: f64) {
        if let Some(l) = map.map(|m| m.value(x)) {
            (0..3).for_each(|c| self.emitted[c] += l[c] / per_pixel as f32);
        }
    }
}

impl<'a> DirectLight<'a> {
    /// Gathers `scene`'s emitters; `bvh` holds the scene's polygons (the
    /// mesh's [`Mesh::occluders`], built once); `strata` squared shadow rays
    /// go to each emitter from each point.
    pub fn new(scene: &'a Scene, bvh: &'a Bvh, strata: u32) -> Self {
        let emitters = scene
            .polygons
            .iter()
            .enumerate()
            .filter(|(_, p)| p.is_emitter())
            .map(|(i, p)| Emitter {
                polygon: i as u32,
                corners: p.vertices.clone(),
                exact: p.vertices.iter().map(|v| v.as_dvec3()).collect(),
                normal: p.normal,
                centre: p.centre(),
                exitance: p.emission.map(|e| std::f64::consts::PI * e as f64),
                texture: p.emissive.as_ref(),
            })
            .collect();
        DirectLight {
            bvh,
            emitters,
            lights: scene.lights.clone(),
            normals: scene.polygons.iter().map(|p| p.normal).collect(),
            reflectance: scene.polygons.iter().map(|p| p.reflectance).collect(),
            textures: scene.polygons.iter().map(|p| p.texture.as_ref()).collect(),
            emissive: scene.polygons.iter().map(|p| p.emissive.as_ref()).collect(),
            strata: strata.max(1),
            eps: 1e-5 * scene.extent().max(1e-6),
            sky: scene.background(),
        }
    }

    /// Direct irradiance (W/m^2 per channel) at `x` on polygon `polygon`
    /// (its front side), from every emitter but `polygon` itself, with
    /// `strata` x `strata` shadow rays per emitter.
    pub fn irradiance(&self, x: Vec3, polygon: u32, rng: &mut Rng) -> [f64; 3] {
        self.irradiance_in(x, polygon, rng, Strata::whole(self.strata))
    }

    /// [`DirectLight::irradiance`] with shadow rays to the cells `strata`
    /// says of each emitter's (u, v) square.
    fn irradiance_in(&self, x: Vec3, polygon: u32, rng: &mut Rng, strata: Strata) -> [f64; 3] {
        let mut pool = Pool::new(self.emitters.len(), self.lights.len());
        self.gather(&mut pool, x, polygon, [1.0; 3], rng, strata);
        pool.total()
    }

    /// Adds point `x` on polygon `polygon` to `pool`, its irradiance
    /// weighted by `weight` per channel: the lights' at once, and per
    /// emitter its unoccluded part and its shadow rays (to the cells
    /// `strata` says of the emitter's (u, v) square).
    fn gather(
        &self,
        pool: &mut Pool,
        x: Vec3,
        polygon: u32,
        weight: [f64; 3],
        rng: &mut Rng,
        strata: Strata,
    ) {
        let n = self.normals[polygon as usize];
        let origin = x + n * self.eps;
        let (light_hints, emitter_hints) = pool.hints.split_at_mut(self.lights.len());
        let (map_hint, emitter_hints) = emitter_hints.split_last_mut().expect("the map's hint");
        if let Some(map) = self.sky.map.filter(|m| m.has_sun()) {
            let from = RayStart {
                origin,
                normal: n,
                polygon,
            };
            let e = map_sun(map, self.bvh, from, rng, strata, map_hint);
            (0..3).for_each(|c| pool.lights[c] += weight[c] * e[c]);
        }
        for (light, hint) in self.lights.iter().zip(light_hints) {
            let d = crate::lights::irradiance(light, self.bvh, x, n, polygon, self.eps, hint);
            for c in 0..3 {
                pool.lights[c] += weight[c] * d[c];
            }
        }
        for (k, e) in self.emitters.iter().enumerate() {
            if e.polygon == polygon || (x - e.centre).dot(e.normal) <= 0.0 {
                continue;
            }
            let f = point_to_polygon(x.as_dvec3(), n.as_dvec3(), &e.exact);
            if f <= 0.0 {
                continue;
            }
            let hint = &mut emitter_hints[k];
            let from = RayStart {
                origin,
                normal: n,
                polygon,
            };
            let (seen, all) = self.shadow_rays(e, from, rng, strata, hint);
            for ((u, w), x) in pool.unoccluded[k].iter_mut().zip(weight).zip(e.exitance) {
                *u += w * x * f;
            }
            let rays = &mut pool.rays[k];
            (0..3).for_each(|c| rays.0[c] += seen[c]);
            rays.1 += all;
        }
    }

    /// Emitter `e`'s shadow rays from `origin`: the visible ones' (per
    /// channel, each times the exitance there over the emitter's mean on
    /// an emissive texture) and all of them's cos cos / r^2 over the
    /// sampling density (their ratio is the share of the unoccluded form
    /// factor `origin` sees, weighted by the texture).
    fn shadow_rays(
        &self,
        e: &Emitter,
        from: RayStart,
        rng: &mut Rng,
        strata: Strata,
        hints: &mut crate::raytrace::Hints,
    ) -> ([f64; 3], f64) {
        let RayStart {
            origin,
            normal: n,
            polygon,
        } = from;
        let (mut all, mut seen) = (0.0f64, [0.0f64; 3]);
        let g = strata.grid as f32;
        for i in 0..strata.side * strata.side {
            let cx = strata.first[0] + i % strata.side;
            let cy = strata.first[1] + i / strata.side;
            let u = (cx as f32 + unit(rng)) / g;
            let v = (cy as f32 + unit(rng)) / g;
            let (y, jac) = point_in(&e.corners, u, v);
            let d = y + e.normal * self.eps - origin;
            let r2 = d.length_squared();
            let w = (n.dot(d).max(0.0) * (-e.normal.dot(d)).max(0.0)) as f64 / (r2 * r2) as f64
                * jac as f64;
            if w <= 0.0 || !w.is_finite() {
                continue;
            }
            all += w;
            if !self
                .bvh
                .occluded_recent(origin, d, 0.0, 1.0, [polygon, e.polygon], hints)
            {
                match e.texture {
                    None => seen.iter_mut().for_each(|s| *s += w),
                    Some(map) => {
                        let l = map.value(y);
                        for c in 0..3 {
                            let mean = e.exitance[c] / std::f64::consts::PI;
                            if mean > 0.0 {
                                seen[c] += w * f64::from(l[c]) / mean;
                            }
                        }
                    }
                }
            }
        }
        (seen, all)
    }

    /// The scene's emitting polygons as the first shot of the solve
    /// ([`EmitterField`]), or `None` where there are none or where
    /// tracing them would cost more than [`MAX_TRACED_PAIRS`] element and
    /// emitter pairs (they then shoot by hemisphere, as other patches).
    pub fn emitter_field(scene: &Scene, mesh: &Mesh) -> Option<EmitterField> {
        // The emitters alone: the lights and a map's sun are `lights`'.
        let light = DirectLight {
            lights: Vec::new(),
            sky: crate::scene::Background::default(),
            ..DirectLight::new(scene, &mesh.occluders, ELEMENT_RAYS)
        };
        let pairs = light.emitters.len().saturating_mul(mesh.elements.len());
        if light.emitters.is_empty() || pairs > MAX_TRACED_PAIRS {
            return None;
        }
        let started = std::time::Instant::now();
        let wanted = vec![true; mesh.polygons.len()];
        let irradiance = light.element_irradiance_at(mesh, &wanted, EMITTER_SAMPLES);
        let delivered = mesh
            .elements
            .iter()
            .zip(&irradiance)
            .map(|(e, d)| d.iter().sum::<f64>() * e.area)
            .sum();
        log::debug!(
            "emitters traced: {} emitters to {} elements, delivered {:.5} of their power, {:.2} s",
            light.emitters.len(),
            mesh.elements.len(),
            delivered / mesh.emitted_power(),
            started.elapsed().as_secs_f64()
        );
        Some(EmitterField {
            irradiance,
            power: mesh.emitted_power(),
            delivered,
        })
    }

    /// Each element's mean direct irradiance over its area (jittered
    /// points on an [`ELEMENT_POINTS`]-square grid, [`ELEMENT_RAYS`] squared
    /// shadow rays from each), for the elements whose polygon `wanted`
    /// says; others get 0.
    pub fn element_irradiance(&self, mesh: &Mesh, wanted: &[bool]) -> Vec<[f64; 3]> {
        self.element_irradiance_at(mesh, wanted, (ELEMENT_POINTS, ELEMENT_RAYS))
    }

    /// [`DirectLight::element_irradiance`] at `side` x `side` points an
    /// element, `rays` x `rays` shadow rays from each.
    fn element_irradiance_at(
        &self,
        mesh: &Mesh,
        wanted: &[bool],
        (side, rays): (u32, u32),
    ) -> Vec<[f64; 3]> {
        let work = |j: usize, out: &mut [f64; 3]| {
            let e = &mesh.elements[j];
            if !wanted.get(e.polygon as usize).copied().unwrap_or(false) {
                return;
            }
            let corners: &[Vec3] = if e.corners[3] == e.corners[2] {
                &e.corners[..3]
            } else {
                &e.corners
            };
            let mut rng = Rng(0x5eed_0000_0000 ^ j as u64);
            let mut pool = Pool::new(self.emitters.len(), self.lights.len());
            let mut weight = 0.0;
            for q in 0..side * side {
                let u = ((q % side) as f32 + unit(&mut rng)) / side as f32;
                let v = ((q / side) as f32 + unit(&mut rng)) / side as f32;
                let (x, jac) = point_in(corners, u, v);
                // The points share one stratification of each emitter.
                let strata = Strata {
                    grid: side * rays,
                    first: [q % side * rays, q / side * rays],
                    side: rays,
                };
                let jac = f64::from(jac);
                self.gather(&mut pool, x, e.polygon, [jac; 3], &mut rng, strata);
                weight += jac;
            }
            *out = pool
                .total()
                .map(|s| if weight > 0.0 { s / weight } else { 0.0 });
        };
        let mut out = vec![[0.0; 3]; mesh.elements.len()];
        in_parallel(&mut out, work);
        out
    }

    /// The camera image's direct part: `width * height` pixels (top row
    /// first) of reflected direct radiance rho E / pi, box-filtered over
    /// `ss` x `ss` samples per pixel at the centres the rasteriser uses
    /// (rho the texture's at each sample on a textured polygon); which
    /// polygons some sample saw; and per pixel the mean over its samples
    /// of the texture's reflectance where they meet a textured polygon, 1
    /// elsewhere (what the interpolated irradiance of textured elements is
    /// multiplied by: see `render::image`); with `gather`, each pixel's
    /// emission and indirect light gathered from the solution.
    pub fn image(
        &self,
        camera: &Camera,
        size: [u32; 2],
        ss: u32,
        depth: [f32; 2],
        gather: Option<&Gather>,
    ) -> Image {
        let [width, height] = size;
        let ss = ss.max(1);
        let (w, h) = ((width * ss) as f32, (height * ss) as f32);
        let tan = (0.5 * camera.yfov).tan();
        let aspect = width as f32 / height as f32;
        let per_pixel = (ss * ss) as f64;
        let work = |p: usize, out: &mut PixelSums| {
            let (px, py) = ((p as u32 % width) * ss, (p as u32 / width) * ss);
            let mut rng = Rng(0xd1ec_7000_0000 ^ p as u64);
            // The pixel's samples share one (ss * strata)^2 stratification of
            // each emitter, each sample a block of it in shuffled order, so a
            // pixel's shadow rays cover the emitter evenly.
            let mut order: Vec<u32> = (0..ss * ss).collect();
            for k in (1..order.len()).rev() {
                order.swap(k, rng.below(k + 1));
            }
            let mut pool = Pool::new(self.emitters.len(), self.lights.len());
            let mut texture = [0.0f64; 3];
            for k in 0..ss * ss {
                let (sx, sy) = ((px + k % ss) as f32 + 0.5, (py + k / ss) as f32 + 0.5);
                let dir = camera.rotation
                    * Vec3::new(
                        (2.0 * sx / w - 1.0) * tan * aspect,
                        (1.0 - 2.0 * sy / h) * tan,
                        -1.0,
                    );
                // Coinciding faces: the one facing the camera shows (as in
                // the rasterised view), and a back face is black.
                let Some(hit) =
                    self.bvh
                        .nearest_facing(camera.position, dir, depth[0], depth[1], 1e-5)
                else {
                    texture.iter_mut().for_each(|t| *t += 1.0);
                    out.add_sky(self.sky.radiance(dir.normalize()), per_pixel);
                    continue;
                };
                out.polygon = hit.polygon + 1;
                let x = camera.position + dir * hit.t;
                let textured = self.textures[hit.polygon as usize].map(|m| m.reflectance(x));
                for (t, r) in texture.iter_mut().zip(textured.unwrap_or([1.0; 3])) {
                    *t += f64::from(r);
                }
                if dir.dot(self.normals[hit.polygon as usize]) >= 0.0 {
                    continue;
                }
                out.add_emitted(self.emissive[hit.polygon as usize], x, per_pixel);
                let block = order[k as usize];
                let strata = Strata {
                    grid: ss * self.strata,
                    first: [block % ss * self.strata, block / ss * self.strata],
                    side: self.strata,
                };
                let rho = textured.unwrap_or(self.reflectance[hit.polygon as usize]);
                let weight = rho.map(|r| f64::from(r) / std::f64::consts::PI);
                self.gather(&mut pool, x, hit.polygon, weight, &mut rng, strata);
                if let Some(g) = gather {
                    let sample = g.sample(x, hit.polygon, rho, &mut rng, [ss, block]);
                    out.gathered.add(&sample, 1.0 / per_pixel);
                }
            }
            out.direct = pool.total().map(|s| (s / per_pixel) as f32);
            out.texture = texture.map(|t| (t / per_pixel) as f32);
        };
        let blank = PixelSums {
            direct: [0.0; 3],
            polygon: 0,
            texture: [1.0; 3],
            sky: [0.0; 3],
            emitted: [0.0; 3],
            gathered: GatherPixel::default(),
        };
        let mut pixels = vec![blank; (width * height) as usize];
        in_parallel(&mut pixels, work);
        Image::of(&pixels, self.normals.len(), gather.is_some())
    }
}

/// The irradiance from `map`'s sun at `from`: one direction drawn from the
/// sun's brightness in each cell `strata` says of a stratification of the
/// unit square, kept where its shadow ray leaves the scene.
fn map_sun(
    map: &crate::scene::SkyMap,
    bvh: &Bvh,
    from: RayStart,
    rng: &mut Rng,
    strata: Strata,
    hints: &mut crate::raytrace::Hints,
) -> [f64; 3] {
    let g = f64::from(strata.grid);
    let mut sum = [0.0; 3];
    let skip = [from.polygon, from.polygon];
    for i in 0..strata.side * strata.side {
        let u1 = (f64::from(strata.first[0] + i % strata.side) + rng.unit()) / g;
        let u2 = (f64::from(strata.first[1] + i / strata.side) + rng.unit()) / g;
        let Some(m) = map.sample_sun(u1, u2) else {
            continue;
        };
        let cos = f64::from(m.direction.dot(from.normal));
        if cos > 0.0
            && !bvh.occluded_recent(from.origin, m.direction, 0.0, f32::INFINITY, skip, hints)
        {
            (0..3).for_each(|c| sum[c] += m.weight[c] * cos);
        }
    }
    let n = f64::from((strata.side * strata.side).max(1));
    sum.map(|s| s / n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Polygon;

    fn square(centre: Vec3, half: f32, up: bool, emission: f32) -> Polygon {
        let (a, b) = if up {
            (Vec3::X, -Vec3::Z)
        } else {
            (-Vec3::Z, Vec3::X)
        };
        Polygon::square(centre, half, a, b, [0.5; 3], [emission; 3])
    }

    fn scene(polygons: Vec<Polygon>) -> Scene {
        Scene {
            name: "test".into(),
            nodes: vec!["n".into()],
            node_transforms: vec![[0.0; 16]],
            polygons,
            ..Default::default()
        }
    }

    #[test]
    fn unoccluded_point_gets_the_exact_form_factor() {
        // A unit emitter 1 m above a point: E = pi L F, F from the closed form
        // for a square of side 2a at height h centred over the point.
        let s = scene(vec![
            square(Vec3::ZERO, 2.0, true, 0.0),
            square(Vec3::Y, 0.5, false, 1.0),
        ]);
        let bvh = Bvh::new(&s.polygons);
        let d = DirectLight::new(&s, &bvh, 4);
        let e = d.irradiance(Vec3::ZERO, 0, &mut Rng(1));
        let (a, h) = (0.5f64, 1.0f64);
        let x = a / (a * a + h * h).sqrt();
        let f = 2.0 / std::f64::consts::PI * (2.0 * x * (x).atan());
        let want = std::f64::consts::PI * f;
        assert!((e[0] - want).abs() < 1e-4 * want, "{} vs {want}", e[0]);
    }

    #[test]
    fn image_pixels_weigh_a_large_emitters_parts_by_their_form_factor() {
        // A 2 x 2 m emitter 3 m above the floor, half hidden by a screen at
        // 1.5 m whose edge runs over x = 0: the floor at x sees the emitter
        // where its x > -x. Seen from the floor under the lit side, the near
        // part of the emitter (above the point) weighs most; one shadow ray
        // per image sample, each sample's ray ratio on its own, counted the
        // visible area instead.
        let s = scene(vec![
            square(Vec3::ZERO, 4.0, true, 0.0),
            square(Vec3::Y * 3.0, 1.0, false, 1.0),
            square(Vec3::new(-3.0, 1.5, 0.0), 3.0, false, 0.0),
        ]);
        let bvh = Bvh::new(&s.polygons);
        let d = DirectLight::new(&s, &bvh, 1);
        let camera = Camera {
            position: Vec3::Y,
            rotation: glam::Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2),
            yfov: 2.0 * 0.6f32.atan(),
            aspect: None,
            znear: 0.01,
        };
        let (size, ss) = (16u32, 4u32);
        let image = d.image(&camera, [size, size], ss, [0.01, 10.0], None);
        // The same samples' light from 24 x 24 rays each, per side of x = 0.
        let fine = DirectLight::new(&s, &bvh, 24);
        let mut rng = Rng(7);
        let (mut got, mut want) = ([0.0f64; 2], [0.0f64; 2]);
        for p in 0..size * size {
            let (px, py) = (p % size, p / size);
            let mut sum = 0.0;
            for k in 0..ss * ss {
                let w = (size * ss) as f32;
                let sx = (px * ss + k % ss) as f32 + 0.5;
                let sy = (py * ss + k / ss) as f32 + 0.5;
                let dir = camera.rotation
                    * Vec3::new((2.0 * sx / w - 1.0) * 0.6, (1.0 - 2.0 * sy / w) * 0.6, -1.0);
                let x = camera.position + dir * (1.0 / -dir.y);
                sum += fine.irradiance(x, 0, &mut rng)[0] * 0.5 / std::f64::consts::PI;
            }
            let side = usize::from(px >= size / 2);
            want[side] += sum / (ss * ss) as f64;
            got[side] += f64::from(image.direct[p as usize][0]);
        }
        for side in 0..2 {
            let err = got[side] / want[side] - 1.0;
            // Pooled: +2.2 % (dark side) and +0.6 %; per sample: +11.8 % and -4.0 %.
            assert!(err.abs() < 0.04, "side {side}: {:.2} %", 100.0 * err);
        }
    }

    #[test]
    fn a_blocker_halfway_casts_a_shadow_and_a_penumbra() {
        // A small occluder right under the emitter's centre hides all of it
        // from the point below; points far out to the side see all of it.
        let s = scene(vec![
            square(Vec3::ZERO, 4.0, true, 0.0),
            square(Vec3::Y * 2.0, 0.1, false, 1.0),
            square(Vec3::Y * 1.0, 0.3, false, 0.0),
        ]);
        let bvh = Bvh::new(&s.polygons);
        let d = DirectLight::new(&s, &bvh, 8);
        let mut rng = Rng(3);
        assert_eq!(d.irradiance(Vec3::ZERO, 0, &mut rng), [0.0; 3]);
        let far = Vec3::new(1.5, 0.0, 0.0);
        let lit = d.irradiance(far, 0, &mut rng)[0];
        let f = point_to_polygon(far.as_dvec3(), DVec3::Y, &d.emitters[0].exact);
        assert!((lit - std::f64::consts::PI * f).abs() < 1e-9);
        // In the penumbra, something strictly between.
        let half = d.irradiance(Vec3::new(0.6, 0.0, 0.0), 0, &mut rng)[0];
        let full = std::f64::consts::PI
            * point_to_polygon(DVec3::new(0.6, 0.0, 0.0), DVec3::Y, &d.emitters[0].exact);
        assert!(half > 0.0 && half < full, "{half} of {full}");
    }
}
