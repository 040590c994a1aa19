//! Environment maps (`--sky-map`, issue 64 items 1 and 3) against closed
//! forms: a uniform map is the uniform sky bit for bit; an open floor gets
//! the cosine-weighted integral of the map's upper half; a small bright
//! spot lights as the sun of its irradiance, shadow included, and turning
//! the map by 90 degrees turns the shadow; the picture shows the map where
//! camera rays leave; `.hdr` and `.exr` files read alike.

use crate::common::*;
use crate::lights::{check, floor, irradiance, scene_with, solve};
use glam::Vec3;
use radiosity::render::{render, RenderOptions};
use radiosity::scene::{Light, Scene, SkyMap};
use std::f64::consts::{PI, TAU};
use std::sync::Arc;
use std::time::Duration;

/// A `w` x `h` grey map whose texel (x, y) is `f(x, y)`, turned `turn` degrees.
fn map(size: [u32; 2], turn: f64, f: impl Fn(u32, u32) -> f32) -> SkyMap {
    let t = (0..size[0] * size[1])
        .map(|k| [f(k % size[0], k / size[0]); 3])
        .collect();
    SkyMap::from_texels("test", size, t, [turn, 1.0]).expect("a map")
}

/// The direction of texel (x, y)'s centre in the map's own axes.
fn texel_direction(x: u32, y: u32, size: [u32; 2]) -> Vec3 {
    let phi = (f64::from(x) + 0.5) / f64::from(size[0]) * TAU;
    let theta = (f64::from(y) + 0.5) / f64::from(size[1]) * PI;
    Vec3::new(
        (phi.sin() * theta.sin()) as f32,
        theta.cos() as f32,
        (-phi.cos() * theta.sin()) as f32,
    )
}

/// A black map with a Gaussian spot 1 degree wide toward `toward` (map
/// axes) of irradiance `e` on a surface facing it, summed over the texels.
fn spot(toward: Vec3, e: f64, turn: f64) -> SkyMap {
    let size = [1024, 512];
    let s = toward.normalize();
    let g = |x: u32, y: u32| {
        let d = texel_direction(x, y, size);
        let a = f64::from(d.dot(s).clamp(-1.0, 1.0)).acos();
        (-0.5 * (a / 1f64.to_radians()).powi(2)).exp()
    };
    let mut sum = 0.0;
    for y in 0..size[1] {
        let h = f64::from(size[1]);
        let solid = ((f64::from(y) / h * PI).cos() - (f64::from(y + 1) / h * PI).cos()) * TAU
            / f64::from(size[0]);
        for x in 0..size[0] {
            let cos = f64::from(texel_direction(x, y, size).dot(s)).max(0.0);
            sum += g(x, y) * cos * solid;
        }
    }
    map(size, turn, |x, y| (g(x, y) * e / sum) as f32)
}

/// The floor's quarters, by the signs of x and z.
pub(crate) const QUARTERS: [&str; 4] = ["-x-z", "-x+z", "+x-z", "+x+z"];

/// A floor of four 3 m quarters around a unit box standing at the origin
/// (the box's shadow edges fall inside them, not on their borders).
pub(crate) fn box_on_quarters() -> Scene {
    let mut surfaces: Vec<_> = QUARTERS
        .iter()
        .map(|name| {
            let (x, z) = (&name[..2] == "+x", &name[2..] == "+z");
            let lo = [if x { 0.0 } else { -3.0 }, if z { 0.0 } else { -3.0 }];
            floor(name, lo, [lo[0] + 3.0, lo[1] + 3.0])
        })
        .collect();
    let mut faces = Vec::new();
    // The sides' corners in their planes' (y, z) and (x, y).
    for (axis, lo, hi) in [(0, [0.0, -0.5], [1.0, 0.5]), (2, [-0.5, 0.0], [0.5, 1.0])] {
        for (at, positive) in [(-0.5, false), (0.5, true)] {
            faces.push(rect(axis, at, lo, hi, positive));
        }
    }
    faces.push(rect(1, 1.0, [-0.5, -0.5], [0.5, 0.5], true));
    surfaces.push(surface("box", faces, 0.5, 0.0));
    scene_with(&surfaces, &[])
}

#[test]
fn a_uniform_map_is_the_uniform_sky_bit_for_bit() {
    let mut sky = box_on_quarters();
    sky.sky = Some([0.75; 3]);
    let mut mapped = box_on_quarters();
    mapped.sky_map = Some(Arc::new(map([64, 32], 40.0, |_, _| 0.75)));
    let (a, b) = (solve(&sky), solve(&mapped));
    assert_eq!(a.radiosity, b.radiosity);
}

#[test]
fn an_open_floor_gets_the_cosine_weighted_integral_of_the_maps_upper_half() {
    let size = [64, 32];
    // Brighter toward the zenith, and on one side.
    let f = |x: u32, y: u32| 0.2 + 0.1 * (32 - y) as f32 + if x < 20 { 2.0 } else { 0.0 };
    let mut scene = scene_with(&[floor("floor", [-1.0, -1.0], [1.0, 1.0])], &[]);
    scene.sky_map = Some(Arc::new(map(size, 25.0, f)));
    let mut want = 0.0;
    for y in 0..size[1] / 2 {
        // The integral of cos over a texel of rows from theta0 to theta1.
        let (t0, t1) = (f64::from(y) / 32.0 * PI, f64::from(y + 1) / 32.0 * PI);
        let cos = (t1.sin().powi(2) - t0.sin().powi(2)) / 2.0 * TAU / 64.0;
        want += (0..size[0]).map(|x| f64::from(f(x, y)) * cos).sum::<f64>();
    }
    check(
        "map over an open floor",
        irradiance(&solve(&scene), "floor"),
        want,
        0.005,
    );
}

#[test]
fn a_small_bright_spot_lights_as_the_sun_of_its_irradiance_and_turns_with_the_map() {
    let toward = Vec3::new(1.0, 1.2, 0.0);
    for turn in [0.0, 90.0] {
        let mut mapped = box_on_quarters();
        mapped.sky_map = Some(Arc::new(spot(toward, 40.0, turn)));
        let mut sunlit = box_on_quarters();
        // The map's +Z turns toward +X: its spot with it.
        let turned = glam::Quat::from_rotation_y((turn as f32).to_radians()) * toward;
        sunlit.lights.push(Light::sun(turned, [40.0; 3]));
        let (m, s) = (solve(&mapped), solve(&sunlit));
        for node in QUARTERS.iter().chain(&["box"]) {
            let what = format!("{node}, map turned {turn}");
            check(&what, irradiance(&m, node), irradiance(&s, node), 0.01);
        }
        // The box shades the half away from the spot: -x, then +z.
        let half = |r, keep: &dyn Fn(&str) -> bool| -> f64 {
            QUARTERS
                .iter()
                .filter(|q| keep(q))
                .map(|q| irradiance(r, q))
                .sum()
        };
        let (shaded, lit) = if turn == 0.0 {
            (
                half(&m, &|q| q.starts_with("-x")),
                half(&m, &|q| q.starts_with("+x")),
            )
        } else {
            (
                half(&m, &|q| q.ends_with("+z")),
                half(&m, &|q| q.ends_with("-z")),
            )
        };
        assert!(
            shaded < 0.97 * lit,
            "turned {turn}: shaded half {shaded} vs {lit}"
        );
    }
}

#[test]
fn the_picture_shows_the_map_where_camera_rays_leave() {
    let (_dir, path) = write_scene(
        "open",
        &[surface(
            "floor",
            vec![rect(1, 0.0, [-50.0, -50.0], [50.0, 50.0], true)],
            0.5,
            0.0,
        )],
    );
    let mut s = radiosity::scene::open(path.to_str().expect("utf-8")).expect("scene");
    // 1 all round, 4 in the quarter of the map around +X (turned 90: -Z).
    let size = [64, 32];
    s.sky_map = Some(Arc::new(map(size, 90.0, |x, _| {
        if (8..24).contains(&x) {
            4.0
        } else {
            1.0
        }
    })));
    // Looking along -Z sees 4, along +Z (turned round) 1.
    let round = glam::Quat::from_rotation_y(PI as f32);
    for (rotation, want) in [(glam::Quat::IDENTITY, 4.0), (round, 1.0)] {
        s.camera = Some(radiosity::scene::Camera {
            position: Vec3::new(0.0, 1.0, 0.0) - glam::DVec3::from(s.origin).as_vec3(),
            rotation,
            yfov: 0.5,
            aspect: Some(1.0),
            znear: 0.01,
        });
        let mut opts = RenderOptions {
            width: 16,
            height: Some(16),
            ..RenderOptions::default()
        };
        opts.stop.max_shots = 20;
        let r = render(gpu(), &s, &opts, Duration::ZERO, &mut |_| {}).expect("render");
        let (w, _, pixels) = r.image.expect("an image");
        for p in &pixels[..w as usize] {
            assert!(
                p.iter().all(|&c| (c - want).abs() < 1e-5),
                "top row {p:?}, want {want}"
            );
        }
    }
}

#[test]
fn hdr_and_exr_maps_read_alike_and_a_bad_file_is_named() {
    let (w, h) = (8u32, 4u32);
    let texels: Vec<image::Rgb<f32>> = (0..w * h)
        .map(|k| image::Rgb([0.25 * (k % w) as f32, 1.0, 0.5 * (k / w) as f32]))
        .collect();
    let dir = tempfile::tempdir().expect("temp dir");
    let hdr = dir.path().join("sky.hdr");
    let file = std::fs::File::create(&hdr).expect("create");
    image::codecs::hdr::HdrEncoder::new(file)
        .encode(&texels, w as usize, h as usize)
        .expect("hdr");
    let exr = dir.path().join("sky.exr");
    let buffer = image::Rgb32FImage::from_fn(w, h, |x, y| texels[(x + y * w) as usize]);
    buffer.save(&exr).expect("exr");
    // Other writers (Mitsuba) sign Radiance files "#?RGBE".
    let rgbe = dir.path().join("rgbe.hdr");
    let mut bytes = std::fs::read(&hdr).expect("read");
    let end = bytes
        .iter()
        .position(|&b| b == b'\n')
        .expect("a first line");
    bytes.splice(..end, b"#?RGBE".iter().copied());
    std::fs::write(&rgbe, bytes).expect("write");
    let maps: Vec<SkyMap> = [&hdr, &exr, &rgbe]
        .iter()
        .map(|p| SkyMap::load(p, 0.0, 2.0).expect("loads"))
        .collect();
    for y in 0..h {
        for x in 0..w {
            let d = texel_direction(x, y, [w, h]);
            let want = texels[(x + y * w) as usize].0.map(|c| 2.0 * c);
            let most = want.iter().fold(0.0f32, |a, &b| a.max(b));
            for m in &maps {
                let got = m.radiance(d);
                // Radiance files keep 8 bits of mantissa per texel.
                let close = (0..3).all(|c| (got[c] - want[c]).abs() <= 0.01 * most);
                assert!(close, "{got:?} vs {want:?}");
            }
        }
    }
    std::fs::write(dir.path().join("bad.hdr"), b"not a map").expect("write");
    let err = SkyMap::load(&dir.path().join("bad.hdr"), 0.0, 1.0).expect_err("bad");
    assert!(err.to_string().contains("bad.hdr"), "{err}");
}

/// A furnished room under `docs/references/maps/window-sun.exr` (the sun and
/// sky it carries, as a map, made by `scripts/make-sky-map.py`) against
/// Mitsuba's `envmap` of the same file, per node: 0.13 % mean, 1.36 % worst
/// on 2026-12-07 (the map's sky and sun drawn apart). Turned 90 degrees it is 83 % off: the orientation is
/// Mitsuba's.
#[test]
fn a_furnished_room_under_a_map_is_within_one_percent_mean_of_mitsubas_envmap() {
    let mut s = radiosity::scene::open("family-furnished-1").expect("scene");
    let lights = radiosity::scene::light::LightArgs {
        sky_map: Some(
            format!(
                "{}/docs/references/maps/window-sun.exr",
                env!("CARGO_MANIFEST_DIR")
            )
            .into(),
        ),
        ..Default::default()
    };
    lights.apply(&mut s).expect("the map reads");
    assert!(
        s.lights.is_empty() && s.sky.is_none(),
        "the map replaces the room's sun and sky"
    );
    crate::reference::check_scene("family-furnished-1-window-map", &s);
}

#[test]
fn the_picture_traces_a_maps_sun_as_it_does_the_sun() {
    // The box's shadow in the picture is as sharp as the pixels: the map's
    // sun is traced per sample, not interpolated per element.
    let toward = Vec3::new(1.0, 1.2, 0.4);
    let picture = |scene: &mut Scene| {
        scene.camera = Some(radiosity::scene::Camera {
            position: Vec3::new(-2.5, 2.5, 3.5) - glam::DVec3::from(scene.origin).as_vec3(),
            rotation: glam::Quat::from_rotation_y(-0.6) * glam::Quat::from_rotation_x(-0.55),
            yfov: 0.9,
            aspect: Some(1.0),
            znear: 0.01,
        });
        let opts = RenderOptions {
            width: 64,
            height: Some(64),
            gather: 0,
            ..RenderOptions::default()
        };
        let r = render(gpu(), scene, &opts, Duration::ZERO, &mut |_| {}).expect("render");
        r.image.expect("an image").2
    };
    let mut mapped = box_on_quarters();
    mapped.sky_map = Some(Arc::new(spot(toward, 40.0, 0.0)));
    let mut sunlit = box_on_quarters();
    sunlit.lights.push(Light::sun(toward, [40.0; 3]));
    let (m, s) = (picture(&mut mapped), picture(&mut sunlit));
    let error = radiosity::compare::smape(&m, &s, 64, 64);
    eprintln!("map's sun against the sun: {:.2} % SMAPE", 100.0 * error);
    assert!(error < 0.02, "{:.2} %", 100.0 * error);
}

/// The same room's picture against Mitsuba's image of it under the map
/// (`docs/references/images/family-furnished-1-window-map.*`, 16 384 spp,
/// block noise 0.92 %): 1.82 % SMAPE on 2026-12-07 (2.60 % with the map's
/// sun interpolated per element instead of traced per sample).
#[test]
fn a_furnished_room_under_a_map_pictures_within_two_and_a_half_percent_of_mitsubas() {
    let mut s = radiosity::scene::open("family-furnished-1").expect("scene");
    let map = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/docs/references/maps/window-sun.exr"
    );
    let lights = radiosity::scene::light::LightArgs {
        sky_map: Some(map.into()),
        ..Default::default()
    };
    lights.apply(&mut s).expect("the map reads");
    let error = crate::image::score_scene("family-furnished-1-window-map", &s, |_| {});
    assert!(error <= 0.025, "SMAPE {:.2} % > 2.5 %", 100.0 * error);
}
