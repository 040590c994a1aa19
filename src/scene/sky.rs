//! An environment map (`--sky-map`): an equirectangular (latitude-longitude)
//! image of the radiance (W sr^-1 m^-2, linear) that arrives along every
//! direction leaving the scene, in Radiance `.hdr` or OpenEXR.
//!
//! Orientation: Mitsuba 3's `envmap` with no `to_world`. +Y is up; the
//! image's top row is the zenith, its bottom row the nadir; along a row the
//! left edge looks toward -Z, a quarter across +X, the middle +Z, three
//! quarters -X. `--sky-rotation D` turns the map about +Y by D degrees,
//! right-handed (90 takes the middle from +Z to +X), as Mitsuba's
//! `to_world` rotation about [0, 1, 0] does. Blender's world texture puts
//! the middle at +X of a glTF scene (Blender's +X): `--sky-rotation 90`.
//!
//! Sampling: the map is split into its floor (per channel, its darkest
//! texel), which lights like a uniform sky and is estimated as one (so a
//! uniform map is exactly the uniform sky); its sun, what is above
//! [`SUN_CAP`] times the map's mean radiance (per channel); and its sky,
//! the rest between them. The sky and the sun are each sampled in
//! proportion to their brightness times each texel's solid angle, so a
//! small bright sun costs no more rays than a dull sky and leaves the sky
//! its rays. The sun is direct light, which the camera image traces again
//! per sample, as it does a `--sun`.

use glam::Vec3;
use std::f64::consts::PI;
use std::path::Path;

/// Why a sky map could not be used.
#[derive(Debug, thiserror::Error)]
pub enum SkyMapError {
    /// The file could not be read or decoded.
    #[error("sky map '{path}': {reason}")]
    Read {
        /// The file.
        path: String,
        /// What the decoder said.
        reason: String,
    },
    /// It decoded, but is not a usable map.
    #[error("sky map '{path}': {reason}")]
    Invalid {
        /// The file.
        path: String,
        /// What is wrong with it.
        reason: String,
    },
}

/// Radiance above this many times the map's mean (over the sphere, per
/// channel) is the map's sun, traced per image sample: a clear sky's sun is
/// thousands of times its mean, an overcast sky's brightest texels a few
/// times (docs/notebook/sky-maps.md).
pub const SUN_CAP: f64 = 8.0;

/// A distribution over a map's texels in proportion to a weight times
/// each texel's solid angle: cumulative shares of the rows, and of each
/// row's texels.
#[derive(Clone, Default)]
struct Table {
    /// Per row, the cumulative share up to and including it (the last 1).
    rows: Vec<f64>,
    /// Per texel, the cumulative share of its row.
    columns: Vec<f64>,
    /// The weight's integral over the sphere.
    total: f64,
}

impl Table {
    /// The table of `weight` (per texel, top row first) over a map of `size`.
    fn build(size: [u32; 2], weight: impl Fn(usize) -> f64) -> Self {
        let [w, h] = size.map(|s| s as usize);
        let (mut columns, mut rows) = (vec![0.0; w * h], vec![0.0; h]);
        let mut total = 0.0;
        for y in 0..h {
            let solid = row_solid_angle(y, size);
            let mut acc = 0.0;
            for x in 0..w {
                acc += weight(x + y * w) * solid;
                columns[x + y * w] = acc;
            }
            if acc > 0.0 {
                columns[y * w..(y + 1) * w]
                    .iter_mut()
                    .for_each(|c| *c /= acc);
            }
            total += acc;
            rows[y] = total;
        }
        if total > 0.0 {
            rows.iter_mut().for_each(|r| *r /= total);
        }
        Table {
            rows,
            columns,
            total,
        }
    }

    /// The texel (u2 picks the row, u1 the texel in it; a stratified
    /// square stays stratified) and where in it (x, y from 0 to 1).
    fn pick(&self, size: [u32; 2], u1: f64, u2: f64) -> Option<(usize, f64, f64)> {
        if self.total <= 0.0 {
            return None;
        }
        let w = size[0] as usize;
        let (y, fy) = pick(&self.rows, u2);
        let (x, fx) = pick(&self.columns[y * w..(y + 1) * w], u1);
        Some((x + y * w, fx, fy))
    }
}

/// A direction drawn from a part of a map (its sky or its sun), in world
/// axes, and per channel that part's radiance over the density it was
/// drawn with.
#[derive(Clone, Copy, Debug)]
pub struct MapSample {
    /// The unit direction.
    pub direction: Vec3,
    /// The part's radiance over the density.
    pub weight: [f64; 3],
}

/// A loaded environment map, turned and scaled as the flags say, with what
/// sampling it in proportion to its brightness needs.
#[derive(Clone)]
pub struct SkyMap {
    /// The file it came from.
    pub path: String,
    /// Texels along a row and rows.
    pub size: [u32; 2],
    /// Degrees about +Y (see the module docs).
    pub rotation: f64,
    /// What every texel is multiplied by.
    pub strength: f64,
    /// Radiance per texel, top row first, strength applied.
    texels: Vec<[f32; 3]>,
    /// Per channel, the darkest texel's radiance: lights like a uniform sky.
    floor: [f64; 3],
    /// Per channel, the radiance above which a texel's light is the sun's.
    cap: [f64; 3],
    /// The brightness above the floor less the sun's.
    rest: Table,
    /// The sun's brightness.
    sun: Table,
    /// The turn as cos and sin.
    turn: [f32; 2],
    /// A hash of the texels, for the checkpoint's fingerprint.
    digest: u64,
}

impl std::fmt::Debug for SkyMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.describe())
    }
}

/// A texel's brightness, for sampling: the mean of its channels.
fn brightness(c: [f64; 3]) -> f64 {
    (c[0] + c[1] + c[2]) / 3.0
}

impl SkyMap {
    /// Reads `path` (`.hdr` or `.exr`) and prepares it, turned by
    /// `rotation` degrees about +Y and scaled by `strength`.
    pub fn load(path: &Path, rotation: f64, strength: f64) -> Result<Self, SkyMapError> {
        let name = path.display().to_string();
        let read = |reason: String| SkyMapError::Read {
            path: name.clone(),
            reason,
        };
        let mut bytes = std::fs::read(path).map_err(|e| read(e.to_string()))?;
        // Radiance files begin "#?RADIANCE"; many writers (Mitsuba among
        // them) put the equally valid "#?RGBE", which the decoder refuses.
        if bytes.starts_with(b"#?RGBE\n") {
            bytes.splice(..7, b"#?RADIANCE\n".iter().copied());
        }
        let image = image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| read(e.to_string()))?
            .decode()
            .map_err(|e| read(e.to_string()))?
            .into_rgb32f();
        let size = [image.width(), image.height()];
        let texels = image.pixels().map(|p| p.0).collect();
        Self::from_texels(&name, size, texels, [rotation, strength])
    }

    /// A map of `size` texels (top row first) named `name`, turned by
    /// `turn[0]` degrees and scaled by `turn[1]`.
    pub fn from_texels(
        name: &str,
        size: [u32; 2],
        mut texels: Vec<[f32; 3]>,
        turn: [f64; 2],
    ) -> Result<Self, SkyMapError> {
        let [rotation, strength] = turn;
        let invalid = |reason: String| SkyMapError::Invalid {
            path: name.to_string(),
            reason,
        };
        if size[0] < 2 || size[1] < 1 || texels.len() != (size[0] * size[1]) as usize {
            return Err(invalid(format!(
                "{} x {} texels is not a map",
                size[0], size[1]
            )));
        }
        if !(strength.is_finite() && strength >= 0.0 && rotation.is_finite()) {
            return Err(invalid(format!(
                "strength {strength} and rotation {rotation} must be finite, strength >= 0"
            )));
        }
        if let Some(k) = texels
            .iter()
            .position(|t| t.iter().any(|c| !(c.is_finite() && *c >= 0.0)))
        {
            let (x, y) = (k as u32 % size[0], k as u32 / size[0]);
            return Err(invalid(format!(
                "texel ({x}, {y}) is {:?}: radiance must be finite and >= 0",
                texels[k]
            )));
        }
        let mut digest = 0xcbf2_9ce4_8422_2325u64;
        for t in &mut texels {
            for c in t.iter_mut() {
                digest = (digest ^ u64::from(c.to_bits())).wrapping_mul(0x100_0000_01b3);
                *c = (f64::from(*c) * strength) as f32;
            }
        }
        let mut floor = [f64::INFINITY; 3];
        for t in &texels {
            (0..3).for_each(|c| floor[c] = floor[c].min(f64::from(t[c])));
        }
        let theta = f64::from(rotation as f32).to_radians() as f32;
        let mut map = SkyMap {
            path: name.to_string(),
            size,
            rotation,
            strength,
            texels,
            floor,
            cap: [f64::INFINITY; 3],
            rest: Table::default(),
            sun: Table::default(),
            turn: [theta.cos(), theta.sin()],
            digest,
        };
        map.build_sampling();
        Ok(map)
    }

    /// The sun's cap and the sampling tables of the rest and the sun.
    fn build_sampling(&mut self) {
        // The mean radiance over the sphere, per channel.
        let mut mean = [0.0; 3];
        let w = self.size[0] as usize;
        for (k, t) in self.texels.iter().enumerate() {
            let solid = row_solid_angle(k / w, self.size) / (4.0 * PI);
            (0..3).for_each(|c| mean[c] += f64::from(t[c]) * solid);
        }
        self.cap = [0, 1, 2].map(|c| (SUN_CAP * mean[c]).max(self.floor[c]));
        self.rest = Table::build(self.size, |k| brightness(self.sky_of(k)));
        self.sun = Table::build(self.size, |k| brightness(self.sun_of(k)));
    }

    /// Texel `k`'s radiance above the floor up to the cap: not the sun's.
    fn sky_of(&self, k: usize) -> [f64; 3] {
        let t = self.texels[k];
        [0, 1, 2].map(|c| (f64::from(t[c]).min(self.cap[c]) - self.floor[c]).max(0.0))
    }

    /// Texel `k`'s radiance above the cap: the sun's.
    fn sun_of(&self, k: usize) -> [f64; 3] {
        let t = self.texels[k];
        [0, 1, 2].map(|c| (f64::from(t[c]) - self.cap[c]).max(0.0))
    }

    /// Per channel, the radiance every direction has at least (the darkest
    /// texel's): it lights as a uniform sky does.
    pub fn floor(&self) -> [f64; 3] {
        self.floor
    }

    /// Whether anything is left above the floor (else the map is uniform).
    pub fn has_rest(&self) -> bool {
        self.rest.total > 0.0 || self.sun.total > 0.0
    }

    /// Whether some of it is above the cap: a sun the image traces.
    pub fn has_sun(&self) -> bool {
        self.sun.total > 0.0
    }

    /// The radiance along the unit direction `d` (world axes): the texel
    /// it falls in.
    pub fn radiance(&self, d: Vec3) -> [f32; 3] {
        self.texels[self.texel_of(d)]
    }

    /// [`SkyMap::radiance`] less the sun's part (what the image does not
    /// trace as direct light).
    pub fn radiance_without_sun(&self, d: Vec3) -> [f32; 3] {
        let t = self.texels[self.texel_of(d)];
        [0, 1, 2].map(|c| (f64::from(t[c]).min(self.cap[c])) as f32)
    }

    /// The texel the world direction `d` falls in.
    fn texel_of(&self, d: Vec3) -> usize {
        let [c, s] = self.turn;
        // Into the map's own axes: the turn undone.
        let m = Vec3::new(c * d.x - s * d.z, d.y, s * d.x + c * d.z);
        let phi = f64::from(m.x)
            .atan2(f64::from(-m.z))
            .rem_euclid(std::f64::consts::TAU);
        let theta = f64::from(m.y.clamp(-1.0, 1.0)).acos();
        let [w, h] = self.size;
        let x = ((phi / std::f64::consts::TAU * f64::from(w)) as u32).min(w - 1);
        let y = ((theta / PI * f64::from(h)) as u32).min(h - 1);
        (x + y * w) as usize
    }

    /// A direction drawn from (u1, u2) in the unit square in proportion to
    /// the map's sky (the brightness above the floor less the sun's), with
    /// that radiance over its density there: the mean over many of
    /// `weight * cos * visible` estimates the sky's irradiance. Drawn apart
    /// from the sun, so a bright sun leaves the sky its rays. `None` when
    /// the map has nothing there.
    pub fn sample(&self, u1: f64, u2: f64) -> Option<MapSample> {
        self.draw(&self.rest, Self::sky_of, [u1, u2])
    }

    /// [`SkyMap::sample`] of the map's sun. `None` when it has none.
    pub fn sample_sun(&self, u1: f64, u2: f64) -> Option<MapSample> {
        self.draw(&self.sun, Self::sun_of, [u1, u2])
    }

    /// A direction drawn from `table` at `u`, weighted by the texel's
    /// `part` over its density.
    fn draw(
        &self,
        table: &Table,
        part: fn(&Self, usize) -> [f64; 3],
        u: [f64; 2],
    ) -> Option<MapSample> {
        let (k, fx, fy) = table.pick(self.size, u[0], u[1])?;
        let radiance = part(self, k);
        let b = brightness(radiance);
        (b > 0.0).then(|| MapSample {
            direction: self.direction_in(k, fx, fy),
            weight: radiance.map(|s| s * table.total / b),
        })
    }

    /// The world direction at (fx, fy) within texel `k`, uniform in solid
    /// angle (phi linear, cos theta linear).
    fn direction_in(&self, k: usize, fx: f64, fy: f64) -> Vec3 {
        let [w, h] = self.size.map(|s| s as usize);
        let (x, y) = (k % w, k / w);
        let phi = (x as f64 + fx) / w as f64 * std::f64::consts::TAU;
        let (c0, c1) = (
            (y as f64 / h as f64 * PI).cos(),
            ((y + 1) as f64 / h as f64 * PI).cos(),
        );
        let cos_t = c0 + (c1 - c0) * fy;
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let m = Vec3::new(
            (phi.sin() * sin_t) as f32,
            cos_t as f32,
            (-phi.cos() * sin_t) as f32,
        );
        let [c, s] = self.turn;
        Vec3::new(c * m.x + s * m.z, m.y, -s * m.x + c * m.z)
    }

    /// One line for the report, the log and the checkpoint's fingerprint.
    pub fn describe(&self) -> String {
        format!(
            "sky map '{}' ({} x {}, texels {:016x}) turned {:?} degrees, strength {:?}",
            self.path, self.size[0], self.size[1], self.digest, self.rotation, self.strength
        )
    }
}

/// The solid angle of one texel of row `y` of a map of `size` texels.
fn row_solid_angle(y: usize, size: [u32; 2]) -> f64 {
    let h = f64::from(size[1]);
    let (t0, t1) = (y as f64 / h * PI, (y + 1) as f64 / h * PI);
    (t0.cos() - t1.cos()) * std::f64::consts::TAU / f64::from(size[0])
}

/// The bin of cumulative shares `cdf` (ascending, last 1) that `u` falls
/// in, and where in it (0 to 1). Bins of no share are never picked.
fn pick(cdf: &[f64], u: f64) -> (usize, f64) {
    let i = cdf.partition_point(|&c| c <= u).min(cdf.len() - 1);
    let lo = if i == 0 { 0.0 } else { cdf[i - 1] };
    let span = cdf[i] - lo;
    let f = if span > 0.0 {
        ((u - lo) / span).clamp(0.0, 1.0)
    } else {
        0.5
    };
    (i, f)
}

/// What a ray that leaves the scene sees: a uniform sky and an environment
/// map, added.
#[derive(Clone, Copy, Debug, Default)]
pub struct Background<'a> {
    /// The uniform sky's radiance (`--sky`), W sr^-1 m^-2 per channel.
    pub uniform: [f64; 3],
    /// The environment map (`--sky-map`), if any.
    pub map: Option<&'a SkyMap>,
}

impl Background<'_> {
    /// The radiance along the unit direction `d`.
    pub fn radiance(&self, d: Vec3) -> [f32; 3] {
        let m = self.map.map_or([0.0; 3], |m| m.radiance(d));
        [0, 1, 2].map(|c| self.uniform[c] as f32 + m[c])
    }

    /// Per channel, the radiance every direction has at least: the uniform
    /// sky plus the map's floor.
    pub fn floor(&self) -> [f64; 3] {
        let m = self.map.map_or([0.0; 3], SkyMap::floor);
        [0, 1, 2].map(|c| self.uniform[c] + m[c])
    }

    /// [`Background::radiance`] less a map's sun (which the image traces).
    pub fn radiance_without_sun(&self, d: Vec3) -> [f32; 3] {
        let m = self.map.map_or([0.0; 3], |m| m.radiance_without_sun(d));
        [0, 1, 2].map(|c| self.uniform[c] as f32 + m[c])
    }

    /// Whether it is black in every direction.
    pub fn is_dark(&self) -> bool {
        self.floor().iter().all(|&l| l <= 0.0) && !self.map.is_some_and(SkyMap::has_rest)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w` x `h` map whose texel (x, y) is `f(x, y)`.
    fn map(size: [u32; 2], turn: f64, f: impl Fn(u32, u32) -> f32) -> SkyMap {
        let t = (0..size[0] * size[1])
            .map(|k| [f(k % size[0], k / size[0]); 3])
            .collect();
        SkyMap::from_texels("test", size, t, [turn, 1.0]).expect("a map")
    }

    #[test]
    fn the_orientation_is_mitsubas_and_the_turn_is_right_handed_about_y() {
        // One bright texel per quarter of the middle row.
        let m = map(
            [4, 3],
            0.0,
            |x, y| if y == 1 { 1.0 + x as f32 } else { 0.0 },
        );
        assert_eq!(m.radiance(-Vec3::Z)[0], 1.0, "left edge: -Z");
        assert_eq!(m.radiance(Vec3::X)[0], 2.0, "a quarter: +X");
        assert_eq!(m.radiance(Vec3::Z)[0], 3.0, "the middle: +Z");
        assert_eq!(m.radiance(-Vec3::X)[0], 4.0, "three quarters: -X");
        assert_eq!(m.radiance(Vec3::Y)[0], 0.0, "top row: +Y");
        let turned = map(
            [4, 3],
            90.0,
            |x, y| if y == 1 { 1.0 + x as f32 } else { 0.0 },
        );
        assert_eq!(
            turned.radiance(Vec3::X)[0],
            3.0,
            "90 degrees takes the middle to +X"
        );
    }

    #[test]
    fn samples_follow_the_brightness_and_weigh_to_its_integral() {
        // A sky brighter toward the zenith and on one side: the mean weight
        // of stratified samples is the integral of the rest over the sphere.
        let m = map([16, 8], 30.0, |x, y| {
            0.5 + (8 - y) as f32 + if x < 4 { 3.0 } else { 0.0 }
        });
        let n = 256;
        let mut sum = 0.0;
        for k in 0..n * n {
            let (u1, u2) = (
                ((k % n) as f64 + 0.5) / n as f64,
                ((k / n) as f64 + 0.5) / n as f64,
            );
            let m = m.sample(u1, u2).expect("a sample");
            assert!((m.direction.length() - 1.0).abs() < 1e-5);
            sum += m.weight[0];
        }
        let mut want = 0.0;
        for y in 0..8 {
            for x in 0..16 {
                let l = 0.5 + (8 - y) as f64 + if x < 4 { 3.0 } else { 0.0 } - m.floor()[0];
                want += l * row_solid_angle(y as usize, [16, 8]);
            }
        }
        let got = sum / (n * n) as f64;
        assert!((got - want).abs() < 1e-6 * want, "{got} vs {want}");
        assert_eq!(m.floor(), [1.5; 3]);
    }

    #[test]
    fn a_uniform_map_has_no_rest_and_bad_maps_say_why() {
        let m = map([8, 4], 0.0, |_, _| 0.25);
        assert!(!m.has_rest() && m.sample(0.3, 0.6).is_none());
        assert_eq!(m.floor(), [0.25; 3]);
        let bad = SkyMap::from_texels(
            "x.hdr",
            [2, 1],
            vec![[1.0; 3], [f32::NAN, 0.0, 0.0]],
            [0.0, 1.0],
        );
        let err = bad.expect_err("a NaN texel").to_string();
        assert!(err.contains("x.hdr") && err.contains("(1, 0)"), "{err}");
        let missing = SkyMap::load(Path::new("/nonexistent/sky.hdr"), 0.0, 1.0);
        assert!(missing
            .expect_err("no file")
            .to_string()
            .contains("/nonexistent/sky.hdr"));
    }
}
