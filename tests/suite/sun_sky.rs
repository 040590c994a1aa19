//! `--sun-sky` (issue 64 item 2): the sky and sun of the Hosek-Wilkie model
//! as Mitsuba's `sunsky` gives them. An open floor gets the model's
//! cosine-weighted integral (by quadrature of the model, not of the map)
//! plus the sun's irradiance times the sine of its elevation; the sun's
//! shadow falls where the azimuth says; a furnished room is scored per node
//! and per pixel against Mitsuba's own `sunsky`.

use crate::common::*;
use crate::lights::{floor, scene_with, solve};
use crate::sky_maps::{box_on_quarters, QUARTERS};
use radiosity::scene::light::LightArgs;
use radiosity::scene::sunsky::SunSky;
use std::f64::consts::{PI, TAU};

fn lit(scene: &mut radiosity::scene::Scene, sun_sky: &str) {
    let lights = LightArgs {
        sun_sky: Some(sun_sky.parse().expect("a sun-sky")),
        ..Default::default()
    };
    lights.apply(scene).expect("the sun-sky");
}

#[test]
fn an_open_floor_gets_the_models_sky_and_sun() {
    let value = "35,200,2.5";
    let model: SunSky = value.parse().expect("parses");
    let mut scene = scene_with(&[floor("floor", [-1.0, -1.0], [1.0, 1.0])], &[]);
    lit(&mut scene, value);
    let got = node(&solve(&scene), "floor").radiosity;
    // The model's irradiance on a horizontal surface: midpoint quadrature
    // in cos(theta) and phi.
    let (n, mut sky) = (400, [0.0; 3]);
    for i in 0..n {
        let c = (i as f64 + 0.5) / n as f64;
        let s = (1.0 - c * c).sqrt();
        for j in 0..2 * n {
            let phi = (j as f64 + 0.5) / (2 * n) as f64 * TAU;
            let l = model.sky_radiance([s * phi.sin(), c, -s * phi.cos()]);
            (0..3).for_each(|k| sky[k] += l[k] * c / n as f64 * PI / n as f64);
        }
    }
    let sun = model.sun_irradiance();
    let sine = model.elevation.to_radians().sin();
    for k in 0..3 {
        let want = sky[k] + sun[k] * sine;
        let e = got[k] / 0.5;
        eprintln!(
            "channel {k}: {e:.4} W/m^2 against {want:.4} (sky {:.4}, sun {:.4}): {:+.3} %",
            sky[k],
            sun[k] * sine,
            100.0 * (e / want - 1.0)
        );
        assert!(rel(e, want) < 0.01, "channel {k}: {e} vs {want}");
    }
}

#[test]
fn the_suns_shadow_falls_away_from_its_azimuth() {
    // Azimuth 90 is east (+x): the box's shadow lies on the -x quarters;
    // azimuth 0 is north (-z): on the +z quarters.
    for (azimuth, dark) in [(90.0, ["-x-z", "-x+z"]), (0.0, ["-x+z", "+x+z"])] {
        let mut scene = box_on_quarters();
        lit(&mut scene, &format!("30,{azimuth}"));
        let r = solve(&scene);
        let e = |q: &str| node(&r, q).radiosity[1];
        let shaded: f64 = dark.iter().map(|q| e(q)).sum();
        let sunny: f64 = QUARTERS
            .iter()
            .filter(|q| !dark.contains(q))
            .map(|q| e(q))
            .sum();
        eprintln!("azimuth {azimuth}: shaded {shaded:.3}, sunny {sunny:.3}");
        assert!(
            shaded < 0.97 * sunny,
            "azimuth {azimuth}: {shaded} vs {sunny}"
        );
    }
}

/// The sun-sky the furnished room is lit by: its window's sun direction
/// (toward -1, 0.9, 0.3: 40.8 degrees up, azimuth 253.3).
const WINDOW_SUN_SKY: &str = "40.8,253.3,3";

/// A furnished room under the sun-sky against Mitsuba's `sunsky`
/// (`docs/references/family-furnished-1-sun-sky.json`), per node.
#[test]
fn a_furnished_room_under_the_sun_sky_is_within_one_percent_mean_of_mitsubas_sunsky() {
    let mut s = radiosity::scene::open("family-furnished-1").expect("scene");
    lit(&mut s, WINDOW_SUN_SKY);
    assert!(
        s.sky.is_none() && s.lights.len() == 1,
        "the sun-sky replaces the room's"
    );
    crate::reference::check_scene("family-furnished-1-sun-sky", &s);
}

/// The same room's picture against Mitsuba's image of it
/// (`docs/references/images/family-furnished-1-sun-sky.*`).
#[test]
fn a_furnished_room_under_the_sun_sky_pictures_within_two_and_a_half_percent_of_mitsubas() {
    let mut s = radiosity::scene::open("family-furnished-1").expect("scene");
    lit(&mut s, WINDOW_SUN_SKY);
    let error = crate::image::score_scene("family-furnished-1-sun-sky", &s, |_| {});
    assert!(error <= 0.025, "SMAPE {:.2} % > 2.5 %", 100.0 * error);
}
