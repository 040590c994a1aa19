//! The final gather: the camera image's indirect light per pixel, from the
//! solution by rays with exact visibility.
//!
//! The solution holds one radiosity per element. Interpolating it shows
//! every error of its last bounce where the eye sees it: a large element's
//! visibility sampled from a few points, the transport's ray-sampled shares
//! landing light on whole patches (the walls' splotches in a furnished room).
//! A final gather moves that bounce into the picture: at each image sample
//! rays leave in cosine-distributed directions and each brings back the
//! radiance of what it meets, the solution's element there (less its
//! emission, which the direct light traces), or the sky where it leaves the
//! scene. The sample's reflected indirect radiance is rho times their mean.
//! The solution's errors then reach the picture only after one more bounce,
//! and its splotches are averaged over the whole hemisphere.
//!
//! Pure maths: rays through the mesh's [`crate::raytrace::Bvh`], no GPU, no ranks.

use crate::locate::{element_at, nearest_other};
use crate::mesh::Mesh;
use crate::rng::Rng;
use crate::sampling::{cosine_direction, unit, Strata};
use crate::scene::Background;
use glam::Vec3;

/// Gather rays per pixel by default (rounded to a square per image
/// sample): docs/notebook/gather.md.
pub const DEFAULT_GATHER_RAYS: u32 = 256;

/// What the gather rays see: each element's radiance and the sky's.
#[derive(Clone, Debug)]
pub struct Gather<'a> {
    mesh: &'a Mesh,
    /// Per element, the radiance it sends on: its display radiance less
    /// its own emission (W sr^-1 m^-2).
    reflected: Vec<[f32; 3]>,
    /// Per polygon, its emitted radiance (0 where an emissive texture
    /// gives it, which the image traces per sample).
    emitted: Vec<[f32; 3]>,
    /// What a ray that leaves the scene sees.
    sky: Background<'a>,
    /// Gather rays per image sample: `side` x `side`.
    side: u32,
}

impl<'a> Gather<'a> {
    /// A gather over `mesh` whose elements show `radiance` (display
    /// radiance, emission included) under the sky `sky`, with
    /// `side` x `side` rays per image sample.
    pub fn new(mesh: &'a Mesh, radiance: &[[f32; 3]], sky: Background<'a>, side: u32) -> Self {
        let emitted: Vec<[f32; 3]> = mesh
            .polygons
            .iter()
            .map(|p| match p.emission_texels {
                Some(_) => [0.0; 3],
                None => p.exitance.map(|m| (m / std::f64::consts::PI) as f32),
            })
            .collect();
        let reflected: Vec<[f32; 3]> = radiance
            .iter()
            .enumerate()
            .map(|(j, r)| {
                let le = mesh.element_exitance(j);
                [0, 1, 2].map(|c| (r[c] - (le[c] / std::f64::consts::PI) as f32).max(0.0))
            })
            .collect();
        Gather {
            mesh,
            reflected,
            emitted,
            sky,
            side: side.max(1),
        }
    }

    /// Gather rays per image sample along each axis.
    pub fn side(&self) -> u32 {
        self.side
    }

    /// What polygon `polygon` emits (W sr^-1 m^-2).
    pub fn emitted(&self, polygon: u32) -> [f32; 3] {
        self.emitted[polygon as usize]
    }

    /// What image sample `at[1]` of a pixel of `at[0]` x `at[0]` samples
    /// gathers at `x` on `polygon` of reflectance `rho`: its block of the
    /// pixel's stratification of the hemisphere (`at[0] * side` cells along
    /// each axis).
    pub fn sample(
        &self,
        x: Vec3,
        polygon: u32,
        rho: [f32; 3],
        rng: &mut Rng,
        at: [u32; 2],
    ) -> GatherSample {
        let ([ss, block], side) = (at, self.side);
        let cells = Strata {
            grid: ss * side,
            first: [block % ss * side, block / ss * side],
            side,
        };
        let sum = self.incoming(x, polygon, rng, cells);
        GatherSample {
            incoming: sum.map(|s| s / f64::from(side * side)),
            rho,
            emitted: self.emitted(polygon),
        }
    }

    /// The sum of the radiance the gather rays from `x` on `polygon` (its
    /// front side) bring back, one ray in each cell `strata` says of a
    /// stratification of the cosine-weighted hemisphere; their mean times
    /// rho is the reflected indirect radiance.
    pub fn incoming(&self, x: Vec3, polygon: u32, rng: &mut Rng, strata: Strata) -> [f64; 3] {
        let mesh = self.mesh;
        let poly = &mesh.polygons[polygon as usize];
        let origin = x + poly.normal * mesh.ray_offset;
        let g = strata.grid as f32;
        let mut sum = [0.0f64; 3];
        for k in 0..strata.side * strata.side {
            let u1 = ((strata.first[0] + k % strata.side) as f32 + unit(rng)) / g;
            let u2 = ((strata.first[1] + k / strata.side) as f32 + unit(rng)) / g;
            let dir = cosine_direction(poly.normal, poly.tangent, u1, u2);
            let radiance = match nearest_other(mesh, origin, dir, polygon) {
                // A map's sun is traced as direct light.
                None => self.sky.radiance_without_sun(dir.normalize()),
                // One-sided surfaces are black behind.
                Some(hit) if mesh.polygons[hit.polygon as usize].normal.dot(dir) >= 0.0 => continue,
                Some(hit) => {
                    let at = element_at(mesh, hit.polygon, origin + dir * hit.t);
                    self.reflected[at as usize]
                }
            };
            for c in 0..3 {
                sum[c] += f64::from(radiance[c]);
            }
        }
        sum
    }
}

/// What one image sample gathered.
#[derive(Clone, Copy, Debug)]
pub struct GatherSample {
    /// The mean radiance its gather rays brought back.
    pub incoming: [f64; 3],
    /// Its reflectance (the texture's there on a textured polygon).
    pub rho: [f32; 3],
    /// What its surface emits.
    pub emitted: [f32; 3],
}

/// A pixel's gathered samples, summed: each weighs `1 / samples a pixel`.
#[derive(Clone, Copy, Debug, Default)]
pub struct GatherPixel {
    /// Weighted sums of their reflected radiance and emission.
    reflected: [f32; 3],
    emitted: [f32; 3],
    /// The samples' count, their weight, and the sum and sum of squares of
    /// their reflected radiance's [`luminance`] (for the gather's variance).
    samples: u32,
    weight: f32,
    sum: f32,
    squares: f32,
}

impl GatherPixel {
    /// Adds `s`, weighing `w`.
    pub fn add(&mut self, s: &GatherSample, w: f64) {
        let w = w as f32;
        let reflected = [0, 1, 2].map(|c| s.rho[c] * s.incoming[c] as f32);
        for ((r, e), (x, le)) in self
            .reflected
            .iter_mut()
            .zip(&mut self.emitted)
            .zip(reflected.iter().zip(s.emitted))
        {
            *r += w * x;
            *e += w * le;
        }
        let y = luminance(reflected);
        self.samples += 1;
        self.weight = w;
        self.sum += y;
        self.squares += y * y;
    }

    /// The variance of the pixel's gathered light: its samples' spread
    /// about their mean, over their count, times their weight squared each.
    fn variance(&self) -> f32 {
        let n = self.samples as f32;
        if self.samples < 2 {
            return 0.0;
        }
        let mean = self.sum / n;
        let spread = (self.squares - n * mean * mean).max(0.0) / (n - 1.0);
        // The pixel's value is weight x sum of n samples.
        self.weight * self.weight * n * spread
    }
}

/// Moves each of `pixels` (the interpolated solution's emission and
/// indirect light) toward what the pixel gathered, by how far the two
/// differ beyond the gather's own noise: with d the difference and s^2 the
/// gather's variance (from its samples' spread), the weight is
/// max(0, 1 - s^2 / d^2), positive-part James-Stein shrinkage. Where the
/// solution is wrong (near-field visibility, a coarse element, transport
/// splotches) the difference stands well above the noise and the gather
/// wins; where a few rays met a small bright region far away (a far field
/// lit through an opening) the difference is the gather's noise and the
/// smooth solution stays.
pub fn blend(pixels: &mut [[f32; 3]], gathered: &[GatherPixel], width: usize) {
    let ours: Vec<[f32; 3]> = gathered
        .iter()
        .map(|g| [0, 1, 2].map(|c| g.emitted[c] + g.reflected[c]))
        .collect();
    let diff: Vec<f32> = ours
        .iter()
        .zip(pixels.iter())
        .map(|(g, p)| luminance(*g) - luminance(*p))
        .collect();
    let variance: Vec<f32> = gathered.iter().map(GatherPixel::variance).collect();
    let height = pixels.len() / width.max(1);
    let r = BLEND_RADIUS;
    for (i, p) in pixels.iter_mut().enumerate() {
        let (x, y) = (i % width, i / width);
        let (mut d, mut v, mut n) = (0.0f32, 0.0f32, 0.0f32);
        for yy in y.saturating_sub(r)..(y + r + 1).min(height) {
            for xx in x.saturating_sub(r)..(x + r + 1).min(width) {
                let j = yy * width + xx;
                d += diff[j];
                v += variance[j];
                n += 1.0;
            }
        }
        // The neighbourhood's mean difference, and that mean's variance.
        let (d, v) = (d / n, v / (n * n));
        let w = if d * d > v { 1.0 - v / (d * d) } else { 0.0 };
        for c in 0..3 {
            p[c] += w * (ours[i][c] - p[c]);
        }
    }
}

/// Pixels on each side of a pixel whose differences [`blend`] pools.
const BLEND_RADIUS: usize = 2;

/// The mean of the three channels (the shrinkage's one number per pixel).
fn luminance(c: [f32; 3]) -> f32 {
    (c[0] + c[1] + c[2]) / 3.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::MeshSettings;
    use crate::scene::{Polygon, Scene};

    fn mesh_of(polygons: Vec<Polygon>) -> Mesh {
        let scene = Scene {
            nodes: vec!["n".into()],
            polygons,
            ..Default::default()
        };
        Mesh::build(&scene, &MeshSettings::default())
    }

    /// Every ray from a closed room's floor meets a wall or the ceiling and
    /// brings back the element's radiance there, less its emission.
    #[test]
    fn rays_in_a_closed_box_bring_back_the_elements_radiance_less_emission() {
        let mut polygons = crate::scene::inward_unit_cube(0.5);
        polygons[3].emission = [2.0; 3];
        let mesh = mesh_of(polygons);
        // Each element shows 0.25 reflected, the ceiling its emission too.
        let radiance: Vec<[f32; 3]> = mesh
            .elements
            .iter()
            .map(|e| [0.25 + if e.polygon == 3 { 2.0 } else { 0.0 }; 3])
            .collect();
        let g = Gather::new(
            &mesh,
            &radiance,
            Background {
                uniform: [9.0; 3],
                map: None,
            },
            4,
        );
        let sum = g.incoming(Vec3::new(0.3, 0.0, 0.6), 2, &mut Rng(7), Strata::whole(4));
        for c in sum {
            assert!((c / 16.0 - 0.25).abs() < 1e-6, "{sum:?}");
        }
        assert_eq!(g.emitted(3), [2.0; 3]);
    }

    /// An open floor sees only the sky.
    #[test]
    fn rays_from_an_open_floor_bring_back_the_sky() {
        let floor = Polygon::square(Vec3::ZERO, 1.0, Vec3::Z, Vec3::X, [0.5; 3], [0.0; 3]);
        let mesh = mesh_of(vec![floor]);
        let radiance = vec![[1.0; 3]; mesh.elements.len()];
        let g = Gather::new(
            &mesh,
            &radiance,
            Background {
                uniform: [3.0, 2.0, 1.0],
                map: None,
            },
            2,
        );
        let sum = g.incoming(Vec3::ZERO, 0, &mut Rng(1), Strata::whole(2));
        assert_eq!(sum, [12.0, 8.0, 4.0]);
    }

    fn pixel(samples: &[f64]) -> GatherPixel {
        let mut p = GatherPixel::default();
        for &x in samples {
            let s = GatherSample {
                incoming: [x; 3],
                rho: [1.0; 3],
                emitted: [0.0; 3],
            };
            p.add(&s, 1.0 / samples.len() as f64);
        }
        p
    }

    /// Where the gather's samples agree with each other and not with the
    /// interpolated value the gather wins; where they spread wider than
    /// the difference the interpolated value stays.
    #[test]
    fn the_blend_takes_the_gather_only_where_it_differs_beyond_its_noise() {
        let sure = vec![pixel(&[2.0; 4]); 9];
        let mut pixels = vec![[1.0f32; 3]; 9];
        blend(&mut pixels, &sure, 3);
        assert!(pixels.iter().all(|p| *p == [2.0; 3]), "{pixels:?}");
        let noisy = vec![pixel(&[0.0, 0.0, 0.0, 4.4]); 9];
        let mut pixels = vec![[1.0f32; 3]; 9];
        blend(&mut pixels, &noisy, 3);
        assert!(pixels.iter().all(|p| *p == [1.0; 3]), "{pixels:?}");
    }
}
