//! Light that does not come from a surface: glTF's `KHR_lights_punctual`
//! (point, spot, directional), a sun (`--sun`) and a uniform sky (`--sky`).
//! Plain data and the units' conversion; what a light delivers is
//! `lights`.
//!
//! Units are radiometric, as emission is (W sr^-1 m^-2): a point or spot
//! light's intensity is W/sr, a directional light's W/m^2 on a surface
//! facing it, a sky's radiance W sr^-1 m^-2. `--photometric` reads a file's
//! lights as the glTF specification's candela and lux and its emission as
//! nits, at 683 lm/W ([`LUMENS_PER_WATT`]).

use glam::Vec3;

/// The luminous efficacy the photometric units are read at (lm/W): the
/// definition of the candela, as the glTF specification and Blender use it.
pub const LUMENS_PER_WATT: f64 = 683.0;

/// What kind of light, and its cone.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightKind {
    /// Shines equally in every direction from a point.
    Point,
    /// A point that shines into a cone: full intensity inside `inner`
    /// (radians from the axis), nothing outside `outer`, and between them
    /// glTF's recommended smooth falloff (the square of a linear ramp in
    /// the cosine).
    Spot {
        /// Inner cone half-angle, radians.
        inner: f32,
        /// Outer cone half-angle, radians.
        outer: f32,
    },
    /// Parallel light from infinitely far (a sun).
    Directional,
}

/// One light.
#[derive(Clone, Debug, PartialEq)]
pub struct Light {
    /// The glTF light's name, else its node's (or `sun`).
    pub name: String,
    /// Point, spot or directional.
    pub kind: LightKind,
    /// Where it is (relative to [`super::Scene::origin`]); unused for a
    /// directional light.
    pub position: Vec3,
    /// Unit vector along which it shines (glTF: the node's -Z): a spot's
    /// axis, the direction a directional light travels.
    pub direction: Vec3,
    /// W/sr (point, spot) or W/m^2 (directional), per channel: glTF's
    /// `intensity` times `color`.
    pub intensity: [f64; 3],
}

impl LightKind {
    /// Its name in reports: `point`, `spot` or `directional`.
    pub fn name(self) -> &'static str {
        match self {
            LightKind::Point => "point",
            LightKind::Spot { .. } => "spot",
            LightKind::Directional => "directional",
        }
    }
}

impl Light {
    /// The spot falloff (1 for a point light) toward the unit direction `d`
    /// from the light: glTF's recommended
    /// `clamp((cos - cos_outer) / (cos_inner - cos_outer), 0, 1)^2`.
    pub fn falloff(&self, d: Vec3) -> f64 {
        match self.kind {
            LightKind::Spot { inner, outer } => {
                let (ci, co) = (f64::from(inner.cos()), f64::from(outer.cos()));
                let c = f64::from(self.direction.dot(d));
                if c >= ci {
                    1.0
                } else if c <= co {
                    0.0
                } else {
                    let t = ((c - co) / (ci - co).max(1e-9)).clamp(0.0, 1.0);
                    t * t
                }
            }
            _ => 1.0,
        }
    }

    /// The power it emits (W, sum over RGB): 4 pi I for a point light; for
    /// a spot, 2 pi I ((1 - cos inner) + (cos inner - cos outer) / 3), the
    /// falloff integrated; `None` for a directional light (its power
    /// depends on the area it falls on).
    pub fn power(&self) -> Option<f64> {
        let i: f64 = self.intensity.iter().sum();
        let tau = std::f64::consts::TAU;
        match self.kind {
            LightKind::Point => Some(2.0 * tau * i),
            LightKind::Spot { inner, outer } => {
                let (ci, co) = (f64::from(inner.cos()), f64::from(outer.cos()));
                Some(tau * i * ((1.0 - ci) + (ci - co).max(0.0) / 3.0))
            }
            LightKind::Directional => None,
        }
    }

    /// A sun: light travelling against `toward` (the direction to the sun,
    /// need not be unit) with irradiance `irradiance` (W/m^2 per channel)
    /// on a surface facing it.
    pub fn sun(toward: Vec3, irradiance: [f64; 3]) -> Self {
        Light {
            name: "sun".into(),
            kind: LightKind::Directional,
            position: Vec3::ZERO,
            direction: -toward.normalize(),
            intensity: irradiance,
        }
    }

    /// Shifts the light by `offset` (scenes keep coordinates relative to
    /// their origin).
    pub fn shifted(mut self, offset: Vec3) -> Self {
        self.position -= offset;
        self
    }

    /// One line for the checkpoint fingerprint and the log: every number
    /// that changes the solution.
    pub fn describe(&self) -> String {
        let kind = match self.kind {
            LightKind::Spot { inner, outer } => format!("spot {inner:?}..{outer:?}"),
            k => k.name().to_string(),
        };
        format!(
            "{kind} '{}' at {:?} along {:?}, {:?}",
            self.name,
            self.position.to_array(),
            self.direction.to_array(),
            self.intensity
        )
    }
}

/// The command-line flags that light a scene (the renderer's and the
/// viewer's): `--sun`, `--sky` and `--photometric`.
#[derive(Clone, Debug, clap::Args)]
pub struct LightArgs {
    /// A sun: X,Y,Z,E (the direction toward it, Y up, and its irradiance in
    /// W/m^2 on a surface facing it; X,Y,Z,R,G,B for a colour). Shoots once,
    /// with a shadow ray per point (sharp shadows).
    #[arg(long, value_parser = parse_sun, allow_hyphen_values = true)]
    pub sun: Option<Light>,
    /// A uniform sky: its radiance R,G,B (or one grey number), W sr^-1 m^-2,
    /// seen along every direction that leaves the scene.
    #[arg(long, value_parser = parse_sky)]
    pub sky: Option<[f64; 3]>,
    /// An environment map: an equirectangular image (.hdr or .exr) of
    /// linear radiance, W sr^-1 m^-2, +Y up, oriented as Mitsuba's envmap
    /// (the middle of the image toward +Z). It replaces the sun and sky a
    /// generated room carries; added to --sky.
    #[arg(long, value_name = "FILE", conflicts_with = "sun_sky")]
    pub sky_map: Option<std::path::PathBuf>,
    /// A clear sky and its sun (Hosek-Wilkie, as Mitsuba's sunsky): the
    /// sun's ELEVATION above the horizon and AZIMUTH from -Z (north)
    /// toward +X (east), degrees, and the TURBIDITY (1 clear to 10 hazy,
    /// default 3). Luminance-equivalent units (x 683 = cd/m^2); lights
    /// and is drawn as a sky map is, and replaces a generated room's sun
    /// and sky.
    #[arg(
        long,
        value_name = "ELEVATION,AZIMUTH[,TURBIDITY]",
        allow_hyphen_values = true
    )]
    pub sun_sky: Option<super::sunsky::SunSky>,
    /// Turns the sky map about +Y by DEGREES (right-handed: 90 takes the
    /// middle of the image from +Z to +X; 90 matches Blender's world).
    #[arg(
        long,
        value_name = "DEGREES",
        default_value_t = 0.0,
        allow_hyphen_values = true
    )]
    pub sky_rotation: f64,
    /// Multiplies the sky map's radiance (the sun-sky's sky and sun).
    #[arg(long, value_name = "S", default_value_t = 1.0)]
    pub sky_strength: f64,
    /// Read the file's light units as photometric: point and spot
    /// intensities as candela, directional ones as lux, emission as nits
    /// (683 lm/W). --sun and --sky stay radiometric.
    #[arg(long)]
    pub photometric: bool,
}

impl Default for LightArgs {
    /// No lights, as the flags' defaults are (a map's strength 1).
    fn default() -> Self {
        LightArgs {
            sun: None,
            sky: None,
            sky_map: None,
            sun_sky: None,
            sky_rotation: 0.0,
            sky_strength: 1.0,
            photometric: false,
        }
    }
}

impl LightArgs {
    /// Lights `scene` as the flags say (after loading it); reads the sky
    /// map.
    pub fn apply(&self, scene: &mut super::Scene) -> Result<(), super::SkyMapError> {
        if self.photometric {
            scene.read_photometric();
        }
        if let Some(path) = &self.sky_map {
            let map = super::SkyMap::load(path, self.sky_rotation, self.sky_strength)?;
            install_map(scene, map);
        }
        if let Some(sun_sky) = self.sun_sky {
            let map = super::SkyMap::from_texels(
                &sun_sky.describe(),
                super::sunsky::MAP_SIZE,
                sun_sky.texels(),
                [0.0, self.sky_strength],
            )?;
            install_map(scene, map);
            let mut sun = Light::sun(
                -sun_sky.sun_travel(),
                sun_sky.sun_irradiance().map(|e| e * self.sky_strength),
            );
            sun.name = super::sunsky::SUN_NAME.into();
            scene.lights.push(sun);
            scene.sun_sky = Some(sun_sky);
        }
        if let Some(sun) = &self.sun {
            scene.lights.push(sun.clone());
        }
        if self.sky.is_some() {
            scene.sky = self.sky;
        }
        Ok(())
    }
}

/// Makes `map` the scene's environment: it is the whole of it, its sun
/// included, so a generated room's own sun and sky go.
fn install_map(scene: &mut super::Scene, map: super::SkyMap) {
    scene
        .lights
        .retain(|l| l.name != super::family::CARRIED_SUN);
    if super::family::family_lights(&scene.name).is_some() {
        scene.sky = None;
    }
    scene.sky_map = Some(std::sync::Arc::new(map));
}

/// Why a `--sun` or `--sky` value could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct LightSpecError(String);

/// Parses `--sun X,Y,Z,E`: the direction toward the sun (Y up; any length
/// but zero) and its irradiance in W/m^2 on a surface facing it (one grey
/// number, or `X,Y,Z,R,G,B`).
pub fn parse_sun(s: &str) -> Result<Light, LightSpecError> {
    let v = numbers(s, "--sun")?;
    let irradiance = match v.len() {
        4 => [v[3]; 3],
        6 => [v[3], v[4], v[5]],
        _ => {
            return Err(LightSpecError(format!(
            "--sun '{s}': give X,Y,Z,E (the direction toward the sun and its irradiance in W/m^2)"
        )))
        }
    };
    let toward = Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32);
    if toward.length() < 1e-6 {
        return Err(LightSpecError(format!(
            "--sun '{s}': the direction toward the sun must not be zero"
        )));
    }
    if irradiance.iter().any(|&e| e < 0.0) {
        return Err(LightSpecError(format!(
            "--sun '{s}': the irradiance must be >= 0"
        )));
    }
    Ok(Light::sun(toward, irradiance))
}

/// Parses `--sky R,G,B` (or one grey number): the uniform sky's radiance,
/// W sr^-1 m^-2, each >= 0.
pub fn parse_sky(s: &str) -> Result<[f64; 3], LightSpecError> {
    let v = numbers(s, "--sky")?;
    let radiance = match v.len() {
        1 => [v[0]; 3],
        3 => [v[0], v[1], v[2]],
        _ => {
            return Err(LightSpecError(format!(
                "--sky '{s}': give R,G,B or one grey radiance (W sr^-1 m^-2)"
            )))
        }
    };
    if radiance.iter().any(|&l| l < 0.0) {
        return Err(LightSpecError(format!(
            "--sky '{s}': the radiance must be >= 0"
        )));
    }
    Ok(radiance)
}

fn numbers(s: &str, flag: &str) -> Result<Vec<f64>, LightSpecError> {
    s.split(',')
        .map(|x| {
            x.trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    LightSpecError(format!("{flag} '{s}': '{x}' is not a finite number"))
                })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spot_falls_off_smoothly_between_its_cones_and_its_power_integrates_that() {
        let spot = Light {
            name: "s".into(),
            kind: LightKind::Spot {
                inner: 0.3,
                outer: 0.6,
            },
            position: Vec3::ZERO,
            direction: -Vec3::Y,
            intensity: [1.0, 0.0, 0.0],
        };
        assert_eq!(spot.falloff(-Vec3::Y), 1.0);
        let at = |a: f32| Vec3::new(a.sin(), -a.cos(), 0.0);
        assert_eq!(spot.falloff(at(0.7)), 0.0);
        let mid = spot.falloff(at(0.45));
        assert!(mid > 0.0 && mid < 1.0);
        // Power: integrate the falloff over the sphere numerically.
        let n = 200_000;
        let mut sum = 0.0;
        for k in 0..n {
            let c = -1.0 + 2.0 * (k as f64 + 0.5) / n as f64;
            let s = (1.0 - c * c).sqrt() as f32;
            sum += spot.falloff(Vec3::new(s, -(c as f32), 0.0)) * 2.0 / n as f64;
        }
        let want = std::f64::consts::TAU * sum;
        let got = spot.power().expect("a spot has a power");
        assert!((got - want).abs() < 1e-3 * want, "{got} vs {want}");
    }

    #[test]
    fn sun_and_sky_flags_parse_and_bad_ones_say_why() {
        let sun = parse_sun("0,2,0,100").expect("parses");
        assert_eq!(sun.direction, -Vec3::Y);
        assert_eq!(sun.intensity, [100.0; 3]);
        assert!(parse_sun("0,0,0,1").is_err());
        assert!(parse_sun("0,1,0").is_err());
        assert!(parse_sun("0,1,0,-1").is_err());
        assert_eq!(parse_sky("0.5").expect("grey"), [0.5; 3]);
        assert_eq!(parse_sky("1,2,3").expect("rgb"), [1.0, 2.0, 3.0]);
        let err = parse_sky("1,x,3").expect_err("not a number");
        assert!(err.to_string().contains("'x'"), "{err}");
    }
}
