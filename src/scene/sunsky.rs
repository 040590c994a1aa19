//! `--sun-sky ELEVATION,AZIMUTH[,TURBIDITY]`: a clear sky and its sun from
//! where the sun stands, so a room is lit by the hour of the day.
//!
//! The sky is the Hosek-Wilkie model (2012) in its RGB form, evaluated as
//! Mitsuba 3's `sunsky` does (its tables, the same interpolation over the
//! sun's elevation, the turbidity and a ground albedo of [`ALBEDO`]); the
//! sun is Mitsuba's (Hosek-Wilkie's solar radiance, a 0.5358-degree disc,
//! limb darkened) integrated over its disc into a directional light. The
//! tables are `sunsky/hosek-wilkie-rgb.bin`, written by
//! `scripts/make-sunsky-data.py` from the datasets Mitsuba ships (3-clause
//! BSD, Lukas Hosek and Alexander Wilkie: `sunsky/LICENSE-hosek-wilkie.txt`).
//!
//! Units: the datasets' own, luminance-equivalent radiance in W sr^-1 m^-2
//! (times 683 lm/W it is cd/m^2, as `--photometric` reads a file's lamps): a
//! clear zenith is about 10 (7 kcd/m^2), the sun at 45 degrees about
//! 130 W/m^2 (90 klx). Mitsuba's `sunsky` is these over [`MITSUBA_UNIT`].
//!
//! Directions: +Y is up; the azimuth is measured from -Z (north) toward +X
//! (east), clockwise seen from above. The sky is turned into an
//! environment map ([`SunSky::texels`], [`MAP_SIZE`]) that lights and is
//! drawn as `--sky-map` is; below the horizon it is black.

use glam::Vec3;
use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::sync::OnceLock;

/// The tables, little-endian f64: the sky's parameters, its radiance
/// scales, the sun's irradiance (see `scripts/make-sunsky-data.py`).
const DATA: &[u8] = include_bytes!("sunsky/hosek-wilkie-rgb.bin");
/// Values in the sky's parameter table: turbidity 1..10, albedo 0 and 1,
/// six control points over elevation, three channels, nine parameters.
const PARAMS: usize = 10 * 2 * 6 * 3 * 9;
/// Values in the sky's radiance-scale table.
const SCALES: usize = 10 * 2 * 6 * 3;
/// Rows of the sun's table per turbidity: elevation 0 to 90 by half degrees.
const SUN_ROWS: usize = 181;

/// The ground's albedo the sky is evaluated for (Mitsuba's default).
pub const ALBEDO: f64 = 0.3;
/// The turbidity when none is given: a clear day.
pub const DEFAULT_TURBIDITY: f64 = 3.0;
/// Mitsuba's `sunsky` radiance is this model's over this (measured to 1e-5
/// by `scripts/make-sunsky-data.py`'s comparison; `scripts/reference.py`
/// scales Mitsuba's by it).
pub const MITSUBA_UNIT: f64 = 106.7505;
/// The name of the sun's directional light.
pub const SUN_NAME: &str = "sun-sky sun";
/// The environment map the sky is drawn into: texels along a row, rows.
pub const MAP_SIZE: [u32; 2] = [1024, 512];

/// The tables, decoded once.
fn tables() -> &'static [f64] {
    static TABLES: OnceLock<Vec<f64>> = OnceLock::new();
    TABLES.get_or_init(|| {
        let v: Vec<f64> = DATA
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().expect("eight bytes")))
            .collect();
        assert_eq!(
            v.len(),
            PARAMS + SCALES + 10 * SUN_ROWS * 3,
            "sun-sky tables"
        );
        v
    })
}

/// A sun and sky: where the sun stands and how hazy the air is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunSky {
    /// The sun's height above the horizon, degrees (0 to 90).
    pub elevation: f64,
    /// The sun's compass direction, degrees from -Z toward +X.
    pub azimuth: f64,
    /// The atmosphere's turbidity, 1 (very clear) to 10 (hazy).
    pub turbidity: f64,
}

/// Why a `--sun-sky` value could not be read.
#[derive(Debug, thiserror::Error)]
#[error("--sun-sky '{value}': {reason}")]
pub struct SunSkyError {
    /// What was given.
    pub value: String,
    /// What is wrong with it.
    pub reason: String,
}

impl std::str::FromStr for SunSky {
    type Err = SunSkyError;

    /// Reads `ELEVATION,AZIMUTH[,TURBIDITY]` (degrees, degrees, 1 to 10).
    fn from_str(s: &str) -> Result<Self, SunSkyError> {
        let err = |reason: &str| SunSkyError {
            value: s.to_string(),
            reason: reason.to_string(),
        };
        let v: Vec<f64> = s
            .split(',')
            .map(|x| x.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<_>>()
            .ok_or_else(|| err("give ELEVATION,AZIMUTH[,TURBIDITY] as finite numbers"))?;
        let sky = match v[..] {
            [elevation, azimuth] => SunSky {
                elevation,
                azimuth,
                turbidity: DEFAULT_TURBIDITY,
            },
            [elevation, azimuth, turbidity] => SunSky {
                elevation,
                azimuth,
                turbidity,
            },
            _ => return Err(err("give ELEVATION,AZIMUTH[,TURBIDITY]")),
        };
        if !(0.0..=90.0).contains(&sky.elevation) {
            return Err(err(
                "the elevation must be 0 to 90 degrees (the model has no night)",
            ));
        }
        if !(1.0..=10.0).contains(&sky.turbidity) {
            return Err(err("the turbidity must be 1 to 10"));
        }
        Ok(sky)
    }
}

impl SunSky {
    /// The unit direction toward the sun (world axes, +Y up).
    pub fn toward(&self) -> [f64; 3] {
        let (e, a) = (self.elevation.to_radians(), self.azimuth.to_radians());
        [a.sin() * e.cos(), e.sin(), -a.cos() * e.cos()]
    }

    /// One line for the report, the log and the map's name.
    pub fn describe(&self) -> String {
        format!(
            "sun-sky {:?},{:?},{:?}",
            self.elevation, self.azimuth, self.turbidity
        )
    }

    /// Per channel, the model's nine parameters and its radiance scale at
    /// this elevation and turbidity.
    fn config(&self) -> [([f64; 9], f64); 3] {
        let t = tables();
        let x = (self.elevation.to_radians() / FRAC_PI_2).cbrt();
        [0, 1, 2].map(|c| {
            let params = std::array::from_fn(|k| {
                self.blend(x, |ti, a, i| t[(((ti * 2 + a) * 6 + i) * 3 + c) * 9 + k])
            });
            let scale = self.blend(x, |ti, a, i| t[PARAMS + ((ti * 2 + a) * 6 + i) * 3 + c]);
            (params, scale)
        })
    }

    /// A table entry `at(turbidity index, albedo index, control point)`
    /// as the model interpolates it: a quintic Bezier over `x` (the cube
    /// root of the elevation over 90 degrees), linear between the integer
    /// turbidities and between the albedos 0 and 1.
    fn blend(&self, x: f64, at: impl Fn(usize, usize, usize) -> f64) -> f64 {
        const BINOMIAL: [f64; 6] = [1.0, 5.0, 10.0, 10.0, 5.0, 1.0];
        let bezier = |ti: usize, a: usize| -> f64 {
            (0..6)
                .map(|i| {
                    BINOMIAL[i] * (1.0 - x).powi(5 - i as i32) * x.powi(i as i32) * at(ti, a, i)
                })
                .sum()
        };
        let (t0, ft) = Self::cell(self.turbidity);
        let t1 = (t0 + 1).min(9);
        let albedo = |a: usize| bezier(t0, a) * (1.0 - ft) + bezier(t1, a) * ft;
        albedo(0) * (1.0 - ALBEDO) + albedo(1) * ALBEDO
    }

    /// The turbidity's table index (0 for 1) and the fraction toward the
    /// next.
    fn cell(turbidity: f64) -> (usize, f64) {
        let t = turbidity.clamp(1.0, 10.0);
        let t0 = (t.floor() as usize).min(10);
        (t0 - 1, t - t0 as f64)
    }

    /// The sky's radiance along the unit direction `d` (world axes), per
    /// channel; black below the horizon.
    pub fn sky_radiance(&self, d: [f64; 3]) -> [f64; 3] {
        Self::radiance(&self.config(), self.toward(), d)
    }

    /// The model at `d` for the configuration `config` and the sun along
    /// `sun`: Hosek and Wilkie's extended Perez formula.
    fn radiance(config: &[([f64; 9], f64); 3], sun: [f64; 3], d: [f64; 3]) -> [f64; 3] {
        let cos_t = d[1];
        if cos_t <= 0.0 {
            return [0.0; 3];
        }
        let cos_g = (sun[0] * d[0] + sun[1] * d[1] + sun[2] * d[2]).clamp(-1.0, 1.0);
        let gamma = cos_g.acos();
        config.map(|(p, scale)| {
            let [a, b, c, d, e, f, g, i, h] = p;
            let mie = (1.0 + cos_g * cos_g) / (1.0 + h * h - 2.0 * h * cos_g).powf(1.5);
            let glow = c + d * (e * gamma).exp() + f * cos_g * cos_g + g * mie + i * cos_t.sqrt();
            ((1.0 + a * (b / (cos_t + 0.01)).exp()) * glow * scale).max(0.0)
        })
    }

    /// The sun's irradiance (W/m^2 per channel) on a surface facing it:
    /// the table, linear in elevation and turbidity.
    pub fn sun_irradiance(&self) -> [f64; 3] {
        let sun = &tables()[PARAMS + SCALES..];
        let (t0, ft) = Self::cell(self.turbidity);
        let t1 = (t0 + 1).min(9);
        let e = self.elevation * 2.0;
        let k = (e.floor() as usize).min(SUN_ROWS - 2);
        let fe = e - k as f64;
        let at = |t: usize, row: usize, c: usize| sun[(t * SUN_ROWS + row) * 3 + c];
        [0, 1, 2].map(|c| {
            let row = |t| at(t, k, c) * (1.0 - fe) + at(t, k + 1, c) * fe;
            row(t0) * (1.0 - ft) + row(t1) * ft
        })
    }

    /// The sky as an equirectangular map of [`MAP_SIZE`] texels, top row
    /// first, each its centre's radiance, oriented as `--sky-map` (turned
    /// 0 degrees).
    pub fn texels(&self) -> Vec<[f32; 3]> {
        let config = self.config();
        let sun = self.toward();
        let [w, h] = MAP_SIZE;
        let mut texels = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            let theta = (f64::from(y) + 0.5) / f64::from(h) * PI;
            for x in 0..w {
                let phi = (f64::from(x) + 0.5) / f64::from(w) * TAU;
                let d = [
                    phi.sin() * theta.sin(),
                    theta.cos(),
                    -phi.cos() * theta.sin(),
                ];
                texels.push(Self::radiance(&config, sun, d).map(|v| v as f32));
            }
        }
        texels
    }

    /// The direction the sun's light travels (a directional light's).
    pub fn sun_travel(&self) -> Vec3 {
        let [x, y, z] = self.toward();
        -Vec3::new(x as f32, y as f32, z as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sky(elevation: f64, azimuth: f64, turbidity: f64) -> SunSky {
        SunSky {
            elevation,
            azimuth,
            turbidity,
        }
    }

    #[test]
    fn the_flag_reads_and_bad_values_say_why() {
        let s: SunSky = "30,90".parse().expect("two numbers");
        assert_eq!(s, sky(30.0, 90.0, DEFAULT_TURBIDITY));
        let t = s.toward();
        assert!((t[0] - 30f64.to_radians().cos()).abs() < 1e-12 && t[2].abs() < 1e-12);
        assert!("45,0,2.5".parse::<SunSky>().is_ok());
        for bad in [
            "-5,0", "95,0", "30,0,0.5", "30,0,11", "30", "30,x", "1,2,3,4",
        ] {
            let e = bad.parse::<SunSky>().expect_err(bad);
            assert!(e.to_string().contains(bad), "{e}");
        }
    }

    /// Mitsuba 3.9.1's `sunsky` (scalar_rgb, albedo 0.3, Z up there, so
    /// its (x, y, z) is this module's (x, z, y) up to the azimuth) at a
    /// few directions, times [`MITSUBA_UNIT`]; the printing script is in
    /// docs/notebook/light-sources.md.
    #[test]
    fn the_sky_is_mitsubas_sunsky() {
        // (elevation, turbidity, direction in the sun's vertical plane at
        // (elevation above the horizon, degrees from the sun's azimuth),
        // Mitsuba's RGB).
        let cases: [(f64, f64, [f64; 2], [f64; 3]); 4] = [
            (45.0, 3.0, [30.0, 0.0], [0.1603198, 0.1986030, 0.2509902]),
            (45.0, 3.0, [10.0, 180.0], [0.0960440, 0.1527042, 0.2300688]),
            (20.0, 7.3, [60.0, 90.0], [0.0278491, 0.0394642, 0.0585782]),
            (5.0, 2.0, [2.0, 45.0], [0.1071410, 0.0925204, 0.0472304]),
        ];
        for (elevation, turbidity, [up, around], want) in cases {
            let s = sky(elevation, 0.0, turbidity);
            let (e, a) = (up.to_radians(), around.to_radians());
            let d = [a.sin() * e.cos(), e.sin(), -a.cos() * e.cos()];
            let got = s.sky_radiance(d);
            for c in 0..3 {
                let w = want[c] * MITSUBA_UNIT;
                assert!(
                    (got[c] - w).abs() < 1e-4 * w,
                    "{elevation} {up},{around}: {got:?} vs {w}"
                );
            }
        }
        assert_eq!(sky(45.0, 0.0, 3.0).sky_radiance([0.0, -1.0, 0.0]), [0.0; 3]);
    }

    #[test]
    fn the_sun_dims_toward_the_horizon_and_with_haze() {
        let noon = sky(60.0, 0.0, 3.0).sun_irradiance();
        let low = sky(5.0, 0.0, 3.0).sun_irradiance();
        let hazy = sky(60.0, 0.0, 8.0).sun_irradiance();
        assert!(noon[1] > 100.0 && noon[1] < 200.0, "{noon:?}");
        assert!(
            low[1] < 0.5 * noon[1] && hazy[1] < noon[1],
            "{low:?} {hazy:?}"
        );
        // A low sun is red: blue is scattered out first.
        assert!(low[2] < low[0], "{low:?}");
    }
}
