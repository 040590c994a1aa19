//! Lights that are not surfaces (issue 18 item 1 and 2), through the whole
//! pipeline (glTF with `KHR_lights_punctual` -> render -> report) against
//! closed forms: a point light over a rectangle gives I Omega / A; a spot
//! lights a tile inside its inner cone as a point light would and one
//! outside its outer cone not at all; a sun at 60 degrees from the zenith
//! gives E cos 60; a uniform sky over an open floor gives pi L. Each within
//! 1 %. The receivers reflect half: their radiosity is rho E.

use crate::common::*;
use radiosity::render::{render, RenderOptions, Rendered};
use radiosity::scene::{self, Light, Scene};
use serde_json::json;
use std::time::Duration;

const RHO: f64 = 0.5;

/// Surfaces plus `lights` (glTF light objects, each with the node
/// transform fields to put it at), loaded through the public loader.
pub(crate) fn scene_with(
    surfaces: &[scene::GltfSurface],
    lights: &[(serde_json::Value, serde_json::Value)],
) -> Scene {
    let text = scene::write_gltf(surfaces, None);
    let mut doc: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    if !lights.is_empty() {
        doc["extensionsUsed"] = json!(["KHR_lights_punctual"]);
        doc["extensions"] = json!({"KHR_lights_punctual": {"lights": lights.iter().map(|l| l.0.clone()).collect::<Vec<_>>()}});
        for (i, (_, node)) in lights.iter().enumerate() {
            let mut node = node.clone();
            node["extensions"] = json!({"KHR_lights_punctual": {"light": i}});
            let nodes = doc["nodes"].as_array_mut().expect("nodes");
            nodes.push(node);
            let index = nodes.len() - 1;
            doc["scenes"][0]["nodes"]
                .as_array_mut()
                .expect("scene nodes")
                .push(json!(index));
        }
    }
    scene::load_slice(&serde_json::to_vec(&doc).expect("JSON"), "lights").expect("loads")
}

pub(crate) fn solve(scene: &Scene) -> Rendered {
    render(gpu(), scene, &tight(1e-6), Duration::ZERO, &mut |_| {}).expect("render")
}

/// A floor rectangle facing +y at y = 0.
pub(crate) fn floor(name: &str, lo: [f32; 2], hi: [f32; 2]) -> scene::GltfSurface {
    surface(
        name,
        vec![rect(1, 0.0, [lo[1], lo[0]], [hi[1], hi[0]], true)],
        RHO as f32,
        0.0,
    )
}

/// Solid angle of the rectangle [-a, a] x [-b, b] from height h over its centre.
fn solid_angle(a: f64, b: f64, h: f64) -> f64 {
    4.0 * (a * b / ((a * a + h * h) * (b * b + h * h)).sqrt()).asin()
}

pub(crate) fn irradiance(r: &Rendered, node: &str) -> f64 {
    let s = crate::common::node(r, node);
    s.radiosity[0] / RHO
}

pub(crate) fn check(what: &str, got: f64, want: f64, tolerance: f64) {
    eprintln!(
        "{what}: {got:.5} (closed form {want:.5}, {:+.3} %)",
        100.0 * (got / want - 1.0)
    );
    assert!(rel(got, want) < tolerance, "{what}: {got} vs {want}");
}

#[test]
fn a_point_light_over_a_rectangle_gives_intensity_times_solid_angle_over_area() {
    let (a, b, h, i) = (1.0, 0.5, 0.8, 10.0);
    let scene = scene_with(
        &[floor("floor", [-a as f32, -b as f32], [a as f32, b as f32])],
        &[(
            json!({"type": "point", "intensity": i, "color": [1.0, 1.0, 1.0]}),
            json!({"name": "bulb", "translation": [0.0, h, 0.0]}),
        )],
    );
    assert_eq!(scene.lights.len(), 1);
    let r = solve(&scene);
    let want = i * solid_angle(a, b, h) / (4.0 * a * b);
    check("point light", irradiance(&r, "floor"), want, 0.01);
}

#[test]
fn a_spot_lights_inside_its_inner_cone_and_nothing_outside_its_outer_cone() {
    let (h, i, half) = (1.0, 5.0, 0.2);
    // -Z turned to -Y: a rotation of -90 degrees about X.
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let scene = scene_with(
        &[
            floor("inside", [-half, -half], [half, half]),
            floor("outside", [1.8, -half], [2.2, half]),
        ],
        &[(
            json!({"type": "spot", "intensity": i, "spot": {"innerConeAngle": 0.35, "outerConeAngle": 0.5}}),
            json!({"name": "spot", "translation": [0.0, h, 0.0], "rotation": [-s, 0.0, 0.0, s]}),
        )],
    );
    let light = &scene.lights[0];
    assert!(
        light.direction.dot(-glam::Vec3::Y) > 0.9999,
        "{:?}",
        light.direction
    );
    let r = solve(&scene);
    let half = f64::from(half);
    let want = i * solid_angle(half, half, h) / (4.0 * half * half);
    check("spot, inner cone", irradiance(&r, "inside"), want, 0.01);
    assert_eq!(irradiance(&r, "outside"), 0.0, "outside the outer cone");
}

#[test]
fn a_sun_sixty_degrees_from_the_zenith_gives_e_cos_60() {
    let mut scene = scene_with(&[floor("floor", [-1.0, -1.0], [1.0, 1.0])], &[]);
    let e = 300.0;
    let toward = glam::Vec3::new(60f32.to_radians().sin(), 60f32.to_radians().cos(), 0.0);
    scene.lights.push(Light::sun(toward, [e; 3]));
    let r = solve(&scene);
    check("sun at 60 degrees", irradiance(&r, "floor"), e * 0.5, 0.01);
}

#[test]
fn a_uniform_sky_over_an_open_floor_gives_pi_l() {
    let mut scene = scene_with(&[floor("floor", [-1.0, -1.0], [1.0, 1.0])], &[]);
    let l = 2.0;
    scene.sky = Some([l; 3]);
    let r = solve(&scene);
    check(
        "sky",
        irradiance(&r, "floor"),
        std::f64::consts::PI * l,
        0.01,
    );
}

#[test]
fn a_point_light_in_a_closed_room_balances_its_power() {
    // Six inward walls around a point light: everything it emits lands.
    let walls: Vec<_> = (0..3)
        .flat_map(|axis| {
            [(0.0, true), (1.0, false)].map(|(at, positive)| {
                surface(
                    &format!("wall{axis}{at}"),
                    vec![rect(axis, at, [0.0, 0.0], [1.0, 1.0], positive)],
                    RHO as f32,
                    0.0,
                )
            })
        })
        .collect();
    let scene = scene_with(
        &walls,
        &[(
            json!({"type": "point", "intensity": 1.0}),
            json!({"name": "bulb", "translation": [0.4, 0.6, 0.5]}),
        )],
    );
    let r = solve(&scene);
    let e = r.report.energy;
    let power = 4.0 * std::f64::consts::PI * 3.0;
    check("emitted", e.emitted, power, 1e-9);
    // The report says which lights the solve used.
    let lights = &r.report.lights;
    assert_eq!(lights.len(), 1);
    assert_eq!((lights[0].name.as_str(), lights[0].kind), ("bulb", "point"));
    assert!(rel(lights[0].power.expect("a point light's power"), power) < 1e-12);
    check("balance", e.balance, 1.0, 0.01);
    // Weak shots are weak against all the light, a light's too: measured
    // against the surfaces' emission alone (none here) no shot was weak,
    // and a room lit by lights never drew the coarse hemisphere.
    let t = &r.report.timings;
    assert!(
        t.coarse_shots > 0 && t.coarse_shots < r.report.shots,
        "{} of {} shots coarse",
        t.coarse_shots,
        r.report.shots
    );
}

#[test]
fn photometric_units_read_candela_as_683_lumens_per_watt() {
    let mut scene = scene_with(
        &[floor("floor", [-1.0, -1.0], [1.0, 1.0])],
        &[(
            json!({"type": "point", "intensity": 683.0}),
            json!({"translation": [0.0, 1.0, 0.0]}),
        )],
    );
    let args = scene::light::LightArgs {
        photometric: true,
        ..Default::default()
    };
    args.apply(&mut scene).expect("lit");
    assert!((scene.lights[0].intensity[0] - 1.0).abs() < 1e-12);
}

#[test]
fn a_scene_lit_only_by_a_sky_renders_and_an_unlit_one_says_how_to_light_it() {
    let mut scene = scene_with(&[floor("floor", [-1.0, -1.0], [1.0, 1.0])], &[]);
    let opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    let err = render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {})
        .err()
        .expect("unlit");
    assert!(err.to_string().contains("--sun"), "{err}");
    scene.sky = Some([1.0; 3]);
    render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("lit by the sky");
}

#[test]
fn a_spot_with_bad_cones_is_a_clear_error() {
    let text = scene::write_gltf(&[floor("floor", [-1.0, -1.0], [1.0, 1.0])], None);
    let mut doc: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    doc["extensionsUsed"] = json!(["KHR_lights_punctual"]);
    doc["extensions"] = json!({"KHR_lights_punctual": {"lights": [
        {"name": "bad", "type": "spot", "intensity": 1.0, "spot": {"innerConeAngle": 0.6, "outerConeAngle": 0.5}}
    ]}});
    doc["nodes"]
        .as_array_mut()
        .expect("nodes")
        .push(json!({"name": "n", "extensions": {"KHR_lights_punctual": {"light": 0}}}));
    doc["scenes"][0]["nodes"]
        .as_array_mut()
        .expect("nodes")
        .push(json!(1));
    let err = scene::load_slice(&serde_json::to_vec(&doc).expect("JSON"), "bad spot")
        .expect_err("bad cones");
    assert!(err.to_string().contains("light 'bad'"), "{err}");
}
