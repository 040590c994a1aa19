//! Base-colour textures (issue 18 item 3): the images, how a polygon maps
//! onto one, and the mean reflectance over a region.
//!
//! A textured polygon carries an affine map from its plane to texture
//! coordinates ([`TexMap`]): exact for a triangle, and kept for a quad only
//! where both of its triangles share it (the loader merges no others), so a
//! piece cut from a polygon (a contact split, an element) needs no
//! coordinates of its own. `KHR_texture_transform` is folded into the map.
//! Texels are sRGB (glTF's base colour is); sampling decodes them to
//! linear. Means over a region sample a mip level whose texels are about
//! the size of one sample's share of it, so a large element's mean is not
//! the noise of a few texels.

use glam::{Vec2, Vec3};
use std::sync::Arc;

/// How coordinates outside [0, 1] wrap (glTF sampler `wrapS`/`wrapT`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wrap {
    /// Repeat (glTF's default).
    Repeat,
    /// Repeat, mirrored every other time.
    Mirror,
    /// Clamp to the edge.
    Clamp,
}

impl Wrap {
    /// From glTF's numeric wrap mode.
    pub fn from_gltf(mode: gltf::texture::WrappingMode) -> Self {
        match mode {
            gltf::texture::WrappingMode::ClampToEdge => Wrap::Clamp,
            gltf::texture::WrappingMode::MirroredRepeat => Wrap::Mirror,
            gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
        }
    }

    /// Texel index for integer coordinate `i` of a `n`-texel axis.
    fn index(self, i: i64, n: usize) -> usize {
        let n = n as i64;
        let k = match self {
            Wrap::Repeat => i.rem_euclid(n),
            Wrap::Clamp => i.clamp(0, n - 1),
            Wrap::Mirror => {
                let m = i.rem_euclid(2 * n);
                if m < n {
                    m
                } else {
                    2 * n - 1 - m
                }
            }
        };
        k as usize
    }
}

/// One mip level's texels, row by row: the image as decoded (8-bit sRGB,
/// a quarter of the memory: Sponza's twenty 1024 x 1024 textures take 60 MB
/// so) or linear (the mip levels, and textures made from linear texels).
#[derive(Clone, Debug)]
enum Texels {
    Srgb8(Vec<[u8; 3]>),
    Linear(Vec<[f32; 3]>),
}

/// sRGB 8-bit to linear, tabulated once.
fn srgb8_table() -> &'static [f32; 256] {
    static TABLE: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|i| srgb_to_linear(i as f32 / 255.0)))
}

/// One mip level.
#[derive(Clone, Debug)]
struct Level {
    width: usize,
    height: usize,
    texels: Texels,
}

impl Level {
    /// Texel `i`, linear.
    fn get(&self, i: usize) -> [f32; 3] {
        match &self.texels {
            Texels::Srgb8(t) => {
                let lut = srgb8_table();
                t[i].map(|c| lut[c as usize])
            }
            Texels::Linear(t) => t[i],
        }
    }
}

/// A decoded base-colour image and its mip levels.
#[derive(Clone, Debug)]
pub struct Texture {
    /// The image's name or URI (for messages).
    pub name: String,
    /// Wrap along u and v.
    pub wrap: [Wrap; 2],
    /// Level 0 (the image) down to 1 x 1, each half the last.
    levels: Vec<Level>,
    /// The image's alpha (linear, level 0), where some texel is not opaque
    /// (what `alphaMode: MASK` cuts by).
    alpha: Option<Vec<u8>>,
    /// A hash of the image's texels ([`Texture::digest`]), made when asked.
    digest: std::sync::OnceLock<u64>,
}

/// sRGB to linear (the IEC 61966-2-1 curve).
pub fn srgb_to_linear(x: f32) -> f32 {
    if x <= 0.04045 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    }
}

impl Texture {
    /// A texture from 8-bit sRGB RGB(A) texels (`width * height`, row by row).
    pub fn from_srgb8(
        name: &str,
        width: usize,
        height: usize,
        rgba: &[[u8; 4]],
        wrap: [Wrap; 2],
    ) -> Self {
        let texels = rgba.iter().map(|t| [t[0], t[1], t[2]]).collect();
        let mut t = Self::from_level(name, [width, height], Texels::Srgb8(texels), wrap);
        if rgba.iter().any(|t| t[3] < 255) {
            t.alpha = Some(rgba.iter().map(|t| t[3]).collect());
        }
        t
    }

    /// The image's alpha at `uv` (bilinear, level 0; 1 where it has none).
    pub fn alpha(&self, uv: Vec2) -> f32 {
        let Some(alpha) = &self.alpha else {
            return 1.0;
        };
        let l = &self.levels[0];
        let (corners, [fx, fy]) = self.bilinear([l.width, l.height], uv);
        let [a, b, c, d] = corners.map(|i| f32::from(alpha[i]) / 255.0);
        let top = a + (b - a) * fx;
        let bottom = c + (d - c) * fx;
        top + (bottom - top) * fy
    }

    /// Bilinear filtering at `uv` over a `size` level: its four texels'
    /// indices (top-left, top-right, bottom-left, bottom-right, wrapped)
    /// and the weights along x and y.
    fn bilinear(&self, [width, height]: [usize; 2], uv: Vec2) -> ([usize; 4], [f32; 2]) {
        let (x, y) = (uv.x * width as f32 - 0.5, uv.y * height as f32 - 0.5);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let at =
            |i: i64, j: i64| self.wrap[1].index(j, height) * width + self.wrap[0].index(i, width);
        let corners = [
            at(x0, y0),
            at(x0 + 1, y0),
            at(x0, y0 + 1),
            at(x0 + 1, y0 + 1),
        ];
        (corners, [fx, fy])
    }

    /// A texture from linear RGB texels (`width * height`, row by row).
    pub fn from_linear(
        name: &str,
        width: usize,
        height: usize,
        texels: Vec<[f32; 3]>,
        wrap: [Wrap; 2],
    ) -> Self {
        Self::from_level(name, [width, height], Texels::Linear(texels), wrap)
    }

    fn from_level(
        name: &str,
        [width, height]: [usize; 2],
        texels: Texels,
        wrap: [Wrap; 2],
    ) -> Self {
        let mut levels = vec![Level {
            width: width.max(1),
            height: height.max(1),
            texels,
        }];
        while let Some(last) = levels.last().filter(|l| l.width > 1 || l.height > 1) {
            let (w, h) = (last.width.div_ceil(2), last.height.div_ceil(2));
            let mut next = Vec::with_capacity(w * h);
            for y in 0..h {
                for x in 0..w {
                    let mut sum = [0.0f32; 3];
                    let mut n = 0.0;
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (sx, sy) = (2 * x + dx, 2 * y + dy);
                        if sx < last.width && sy < last.height {
                            let t = last.get(sy * last.width + sx);
                            for c in 0..3 {
                                sum[c] += t[c];
                            }
                            n += 1.0;
                        }
                    }
                    next.push(sum.map(|s| s / n));
                }
            }
            levels.push(Level {
                width: w,
                height: h,
                texels: Texels::Linear(next),
            });
        }
        Texture {
            name: name.to_string(),
            wrap,
            levels,
            alpha: None,
            digest: Default::default(),
        }
    }

    /// A hash (FNV-1a) of the image's size and texels, for the checkpoint's
    /// fingerprint: another image under the same name changes it.
    pub fn digest(&self) -> u64 {
        *self.digest.get_or_init(|| {
            let l = &self.levels[0];
            let mut h = 0xcbf2_9ce4_8422_2325u64;
            let mut eat = |x: u64| h = (h ^ x).wrapping_mul(0x100_0000_01b3);
            eat(l.width as u64);
            eat(l.height as u64);
            for i in 0..l.width * l.height {
                l.get(i).iter().for_each(|c| eat(u64::from(c.to_bits())));
            }
            h
        })
    }

    /// Width and height of the image, texels.
    pub fn size(&self) -> [usize; 2] {
        [self.levels[0].width, self.levels[0].height]
    }

    /// The mean linear colour of the whole image.
    pub fn mean(&self) -> [f32; 3] {
        self.levels.last().map_or([0.0; 3], |l| l.get(0))
    }

    /// Bilinear sample at `uv` of the level whose texels are about
    /// `footprint` (in uv units, along each axis) wide: glTF's coordinates,
    /// (0, 0) the image's top-left corner.
    pub fn sample(&self, uv: Vec2, footprint: f32) -> [f32; 3] {
        let texels = footprint.max(0.0) * self.levels[0].width.max(self.levels[0].height) as f32;
        let level = if texels > 1.0 {
            (texels.log2().floor() as usize).min(self.levels.len() - 1)
        } else {
            0
        };
        let l = &self.levels[level];
        let ([a, b, c, d], [fx, fy]) = self.bilinear([l.width, l.height], uv);
        let (a, b, c, d) = (l.get(a), l.get(b), l.get(c), l.get(d));
        [0, 1, 2].map(|k| {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bottom = c[k] + (d[k] - c[k]) * fx;
            top + (bottom - top) * fy
        })
    }
}

/// How a polygon maps onto a texture: uv(p) = `uv0` + (`du`·(p - `origin`),
/// `dv`·(p - `origin`)) for p in the polygon's plane (the
/// `KHR_texture_transform` included), and what the texture is multiplied by.
#[derive(Clone, Debug, PartialEq)]
pub struct TexMap {
    /// The texture, shared by every polygon that uses it.
    pub texture: Arc<TextureRef>,
    /// A point of the plane.
    pub origin: Vec3,
    /// The coordinates at `origin`.
    pub uv0: Vec2,
    /// Gradient of u over the plane, per metre.
    pub du: Vec3,
    /// Gradient of v over the plane, per metre.
    pub dv: Vec3,
    /// The material's factor: baseColorFactor times (1 - metallic).
    pub factor: [f32; 3],
}

/// A texture as polygons refer to it (compared by index, not by texels).
#[derive(Debug)]
pub struct TextureRef {
    /// Index of the texture in its scene.
    pub index: usize,
    /// The texture.
    pub texture: Texture,
    /// The image as the file had it (PNG or JPEG bytes) and its MIME type,
    /// for a bake to carry (empty when made from texels).
    pub encoded: (Vec<u8>, String),
}

impl PartialEq for TextureRef {
    fn eq(&self, other: &Self) -> bool {
        self.index == other.index
    }
}

/// The highest reflectance a texel may give (as for factors: see
/// `gltf_load::CLAMPED`): a white texel reflecting everything never converges.
pub const MAX_REFLECTANCE: f32 = 0.95;

/// The midpoints of a `side`-square grid over the (u, v) of the polygon
/// with `corners` (3 or 4; see [`crate::sampling::point_in`]), each
/// standing for about an equal share of it.
pub fn grid_points(corners: &[Vec3], side: u32) -> Vec<Vec3> {
    (0..side * side)
        .map(|q| {
            let u = ((q % side) as f32 + 0.5) / side as f32;
            let v = ((q / side) as f32 + 0.5) / side as f32;
            crate::sampling::point_in(corners, u, v).0
        })
        .collect()
}

/// Points along each side of a polygon for its emissive texture's mean
/// ([`TexMap::mean_over`]).
const POLYGON_POINTS: u32 = 16;

impl TexMap {
    /// The factor times the texture's mean over the polygon with
    /// `vertices` (3 or 4).
    pub fn mean_over(&self, vertices: &[Vec3]) -> [f32; 3] {
        let area = match vertices.len() {
            3 => {
                0.5 * (vertices[1] - vertices[0])
                    .cross(vertices[2] - vertices[0])
                    .length()
            }
            _ => {
                0.5 * (vertices[2] - vertices[0])
                    .cross(vertices[3] - vertices[1])
                    .length()
            }
        };
        self.mean(&grid_points(vertices, POLYGON_POINTS), area)
    }

    /// The affine map of a triangle with corners `p` and coordinates `t`;
    /// `None` when the triangle or its coordinates are degenerate.
    pub fn of_triangle(
        p: [Vec3; 3],
        t: [Vec2; 3],
        texture: Arc<TextureRef>,
        factor: [f32; 3],
    ) -> Option<Self> {
        let (e1, e2) = ((p[1] - p[0]).as_dvec3(), (p[2] - p[0]).as_dvec3());
        let (a, b, c) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let det = a * c - b * b;
        if det.abs() <= 1e-24 * a * c || det.is_nan() {
            return None;
        }
        let (d1, d2) = ((t[1] - t[0]).as_dvec2(), (t[2] - t[0]).as_dvec2());
        // g = x e1 + y e2 with g·e1 = d1, g·e2 = d2, per coordinate.
        let grad = |r1: f64, r2: f64| {
            let x = (c * r1 - b * r2) / det;
            let y = (a * r2 - b * r1) / det;
            (e1 * x + e2 * y).as_vec3()
        };
        let map = TexMap {
            texture,
            origin: p[0],
            uv0: t[0],
            du: grad(d1.x, d2.x),
            dv: grad(d1.y, d2.y),
            factor,
        };
        (map.du.is_finite() && map.dv.is_finite()).then_some(map)
    }

    /// The coordinates at `p`.
    pub fn uv(&self, p: Vec3) -> Vec2 {
        let d = p - self.origin;
        self.uv0 + Vec2::new(self.du.dot(d), self.dv.dot(d))
    }

    /// Whether `other` maps the plane the same way (within a thousandth of
    /// a texel-free unit at `points`): two triangles that may share a quad.
    pub fn agrees(&self, other: &TexMap, points: &[Vec3]) -> bool {
        self.texture == other.texture
            && self.factor == other.factor
            && points
                .iter()
                .all(|&p| (self.uv(p) - other.uv(p)).abs().max_element() < 1e-4)
    }

    /// The factor times the texel colour at `p` (bilinear, finest level).
    pub fn value(&self, p: Vec3) -> [f32; 3] {
        let t = self.texture.texture.sample(self.uv(p), 0.0);
        [0, 1, 2].map(|c| self.factor[c] * t[c])
    }

    /// The reflectance at `p`: [`TexMap::value`], at most [`MAX_REFLECTANCE`].
    pub fn reflectance(&self, p: Vec3) -> [f32; 3] {
        self.value(p).map(|x| x.min(MAX_REFLECTANCE))
    }

    /// The mean reflectance over a region: [`TexMap::mean`], at most
    /// [`MAX_REFLECTANCE`].
    pub fn mean_reflectance(&self, points: &[Vec3], area: f32) -> [f32; 3] {
        self.mean(points, area).map(|x| x.min(MAX_REFLECTANCE))
    }

    /// The factor times the texture's mean over a region, from `points`
    /// inside it that each stand for an equal share of it (`area` m^2 in all).
    pub fn mean(&self, points: &[Vec3], area: f32) -> [f32; 3] {
        // One point's share of the region, as a length in uv units.
        let scale = (self.du.length() * self.dv.length()).sqrt();
        let footprint = scale * (area / points.len().max(1) as f32).sqrt();
        let mut sum = [0.0f32; 3];
        for &p in points {
            let t = self.texture.texture.sample(self.uv(p), footprint);
            for c in 0..3 {
                sum[c] += t[c];
            }
        }
        let n = points.len().max(1) as f32;
        [0, 1, 2].map(|c| self.factor[c] * sum[c] / n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn halves() -> Arc<TextureRef> {
        // Left half red, right half blue (linear), 8 x 2.
        let texels = (0..16)
            .map(|i| {
                if i % 8 < 4 {
                    [1.0, 0.0, 0.0]
                } else {
                    [0.0, 0.0, 1.0]
                }
            })
            .collect();
        Arc::new(TextureRef {
            index: 0,
            texture: Texture::from_linear("halves", 8, 2, texels, [Wrap::Repeat; 2]),
            encoded: Default::default(),
        })
    }

    #[test]
    fn a_triangle_map_reproduces_its_corners_and_means_follow_the_texture() {
        let p = [Vec3::ZERO, Vec3::X * 2.0, Vec3::Z * 2.0];
        let t = [Vec2::ZERO, Vec2::X, Vec2::Y];
        let m = TexMap::of_triangle(p, t, halves(), [1.0; 3]).expect("map");
        for k in 0..3 {
            assert!((m.uv(p[k]) - t[k]).length() < 1e-6);
        }
        // Points over x in [0, 1] (u in [0, 0.5]): red; the whole width: half and half.
        let grid = |x1: f32| -> Vec<Vec3> {
            (0..64)
                .map(|i| {
                    Vec3::new(
                        x1 * (i % 8) as f32 / 8.0 + x1 / 16.0,
                        0.0,
                        0.1 + 0.1 * (i / 8) as f32,
                    )
                })
                .collect()
        };
        // (Repeat wrapping blends the left edge with the blue right one.)
        let left = m.mean_reflectance(&grid(1.0), 0.1);
        assert!(left[0] > 0.9 && left[2] < 0.1, "{left:?}");
        let whole = m.mean_reflectance(&grid(2.0), 0.2);
        assert!(
            (whole[0] - 0.5).abs() < 0.05 && (whole[2] - 0.5).abs() < 0.05,
            "{whole:?}"
        );
    }

    #[test]
    fn mip_levels_keep_the_mean_and_wrap_modes_fold_coordinates() {
        let t = &halves().texture;
        assert_eq!(t.mean(), [0.5, 0.0, 0.5]);
        assert_eq!(Wrap::Repeat.index(-1, 4), 3);
        assert_eq!(Wrap::Mirror.index(4, 4), 3);
        assert_eq!(Wrap::Mirror.index(-1, 4), 0);
        assert_eq!(Wrap::Clamp.index(9, 4), 3);
        // A footprint of the whole image samples the last level: the mean.
        let s = t.sample(Vec2::new(0.3, 0.7), 1.0);
        assert!((s[0] - 0.5).abs() < 1e-6, "{s:?}");
    }
}
