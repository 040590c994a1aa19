//! The camera image against path-traced images: Mitsuba 3's path
//! integrator (next-event estimation at every vertex), box-filtered like the
//! renderer's supersampling, cached in `docs/references/images/` with each
//! 4x4 block's standard error and the command that made it
//! (`scripts/reference.py --image`). Default settings; the score is the SMAPE
//! over interior 4x4 blocks (`radiosity::compare::smape`).

use crate::common::gpu;
use radiosity::render::{render, RenderOptions};
use std::time::Duration;

/// The SMAPE of `scene`'s default image at the reference's size, with
/// `shadow_rays` per sample (0: the direct light interpolated).
fn score(scene: &str, shadow_rays: u32) -> f64 {
    score_with(scene, |o| o.shadow_rays = shadow_rays)
}

/// The SMAPE of `scene`'s image at the reference's size, with the default
/// settings as `change` leaves them.
fn score_with(scene: &str, change: impl Fn(&mut RenderOptions)) -> f64 {
    let s = radiosity::scene::open(scene).expect("scene");
    score_scene(scene, &s, change)
}

/// [`score_with`] of the scene `s` against the reference named `scene`.
pub(crate) fn score_scene(
    scene: &str,
    s: &radiosity::scene::Scene,
    change: impl Fn(&mut RenderOptions),
) -> f64 {
    let dir = format!("{}/docs/references/images", env!("CARGO_MANIFEST_DIR"));
    let meta: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(format!("{dir}/{scene}.json")).expect("reference metadata"),
    )
    .expect("reference JSON");
    assert!(
        meta["command"].as_str().is_some(),
        "{scene}: says how it was made"
    );
    let (w, h, reference) =
        radiosity::output::read_exr(std::path::Path::new(&format!("{dir}/{scene}.exr")))
            .expect("reference EXR");
    let mut opts = RenderOptions {
        width: w,
        height: Some(h),
        ..RenderOptions::default()
    };
    change(&mut opts);
    let r = render(gpu(), s, &opts, Duration::ZERO, &mut |_| {}).expect("render");
    let (iw, ih, pixels) = r.image.expect("an image");
    assert_eq!((iw, ih), (w, h));
    radiosity::compare::smape(&pixels, &reference, w as usize, h as usize)
}

#[test]
fn default_images_are_within_two_and_a_half_percent_of_path_traced_images() {
    for scene in [
        "cornell",
        "family-boxes-1",
        "family-slab-1",
        "family-corridor-1",
        // Above 2.5 % until the image interpolated only the solution's
        // indirect part, without hidden elements, extrapolated at edges.
        "family-floor-1",
        "family-l-room-1",
        // 3.17 % before receivers were refined by need.
        "family-stacked-1",
    ] {
        let s = score(scene, radiosity::render::image::DEFAULT_SHADOW_RAYS);
        assert!(s <= 0.025, "{scene}: SMAPE {:.2} % > 2.5 %", s * 100.0);
    }
}

/// Seed 2 of the family: images nobody chose a default on.
#[test]
fn held_out_images_are_within_two_and_a_half_percent() {
    // family-opening-2: 3.74 % before the pooled shadow rays and the
    // shading criterion (both chosen on seed 1).
    for scene in ["family-floor-2", "family-stacked-2", "family-opening-2"] {
        let s = score(scene, radiosity::render::image::DEFAULT_SHADOW_RAYS);
        assert!(s <= 0.025, "{scene}: SMAPE {:.2} % > 2.5 %", s * 100.0);
    }
}

/// family-boxes-2's camera looks at one box face 20 cm away, lit only by
/// the wall 25 cm behind it: the picture is that face's near-field
/// indirect light. The goal (2.5 %) is not met since the emitters are
/// traced: 2.51 % (1.07 % before). Per face against the path tracer that
/// face went from +0.3 % to +1.8 % while the scene's other box faces got
/// better (the worst -13.5 % -> +6.2 %); finer patches make it worse
/// (3.21 % at --near-field-ratio 0.15), more emitter samples do not move
/// it (2.48-2.49 %): docs/notebook/visibility.md. This bounds what is
/// measured so a change for the worse fails.
#[test]
fn a_box_face_in_front_of_the_camera_stays_within_its_measured_error() {
    let s = score(
        "family-boxes-2",
        radiosity::render::image::DEFAULT_SHADOW_RAYS,
    );
    assert!(
        s <= 0.027,
        "family-boxes-2: SMAPE {:.2} % > 2.7 %",
        s * 100.0
    );
}

/// Furnished rooms lit by a sun and a sky through a window: 1.26 % and
/// 1.15 % on 2026-12-07 (1.49 % and 1.34 % before each element's sky-ray
/// blocks were shuffled; references with 0.6-0.7 % block noise).
#[test]
fn furnished_rooms_are_within_two_and_a_half_percent_of_path_traced_images() {
    for scene in ["family-furnished-1", "family-furnished-2"] {
        let s = score(scene, radiosity::render::image::DEFAULT_SHADOW_RAYS);
        assert!(s <= 0.025, "{scene}: SMAPE {:.2} % > 2.5 %", s * 100.0);
    }
}

/// The final gather (`radiosity::gather`) is what takes the solution's
/// last-bounce errors out of the picture: on held-out seeds the default
/// image beats the same solution's indirect light interpolated
/// (2026-12-07: family-floor-2 0.67 % against 0.85 %, family-stacked-2
/// 0.66 % against 0.86 %; docs/notebook/gather.md).
#[test]
fn the_final_gather_beats_interpolating_the_indirect_light() {
    for scene in ["family-floor-2", "family-stacked-2"] {
        let gathered = score(scene, radiosity::render::image::DEFAULT_SHADOW_RAYS);
        let interpolated = score_with(scene, |o| o.gather = 0);
        assert!(
            gathered <= 0.9 * interpolated,
            "{scene}: gathered {:.2} % against interpolated {:.2} %",
            gathered * 100.0,
            interpolated * 100.0
        );
    }
}

/// Traced direct light is what gives the contact shadows and the sharp
/// shadow edges: without it the same solution scores much worse.
#[test]
fn traced_direct_light_beats_interpolating_it() {
    let traced = score("cornell", radiosity::render::image::DEFAULT_SHADOW_RAYS);
    let interpolated = score("cornell", 0);
    assert!(
        traced < 0.8 * interpolated,
        "traced {:.2} % vs interpolated {:.2} %",
        traced * 100.0,
        interpolated * 100.0
    );
}

/// Receivers refined by need (patches whose elements hold their light
/// unevenly) give a better picture than refining shooters alone: boxes on a
/// floor were 1.98 % with shooters only.
#[test]
fn refining_uneven_receivers_beats_refining_shooters_only() {
    let on = score_with("family-floor-1", |_| {});
    let off = score_with("family-floor-1", |o| {
        o.mesh.receiver_tol = 0.0;
        o.mesh.shading_tol = 0.0;
    });
    assert!(
        on < 0.75 * off,
        "receivers refined {:.2} % vs shooters only {:.2} %",
        on * 100.0,
        off * 100.0
    );
}

/// The room lit through a small opening needs the shading criterion (a
/// finer mesh where the image would shade its indirect light badly, however
/// little of the emitted power that light is): 2.93 % without it, over the
/// 2.5 % bound, 1.90 % with it.
#[test]
fn the_shading_criterion_brings_the_room_lit_through_an_opening_within_bounds() {
    let on = score_with("family-opening-1", |_| {});
    let off = score_with("family-opening-1", |o| o.mesh.shading_tol = 0.0);
    assert!(on <= 0.025, "SMAPE {:.2} % > 2.5 %", on * 100.0);
    assert!(
        on < 0.8 * off,
        "with the shading criterion {:.2} % vs without {:.2} %",
        on * 100.0,
        off * 100.0
    );
}

#[test]
fn a_point_light_a_sun_and_a_sky_give_the_path_traced_picture_within_two_and_a_half_percent() {
    // The lights' direct light is traced per sample like the panel's.
    // The textured floor's picture multiplies the interpolated irradiance
    // by the texture per sample.
    for scene in ["cornell-lit", "cornell-textured"] {
        let s = score_scene(scene, &crate::reference::lit_cornell_file(scene), |_| {});
        eprintln!("{scene}: {:.2} %", 100.0 * s);
        assert!(s < 0.025, "{scene}: SMAPE {:.2} %", 100.0 * s);
    }
}

/// Where camera rays leave the scene the sky shows at its radiance: an open
/// floor under `--sky L` seen from 1 m above, looking at the horizon, shows
/// L in every pixel above it and the lit floor below.
#[test]
fn the_sky_is_drawn_where_camera_rays_leave_the_scene() {
    use crate::common::{rect, surface, write_scene};
    let floor = vec![rect(1, 0.0, [-50.0, -50.0], [50.0, 50.0], true)];
    let (_dir, path) = write_scene("open", &[surface("floor", floor, 0.5, 0.0)]);
    let mut s = radiosity::scene::open(path.to_str().expect("utf-8")).expect("scene");
    let sky = 0.7;
    s.sky = Some([sky; 3]);
    s.camera = Some(radiosity::scene::Camera {
        // Positions are stored relative to the scene's origin.
        position: glam::Vec3::new(0.0, 1.0, 0.0) - glam::DVec3::from(s.origin).as_vec3(),
        rotation: glam::Quat::IDENTITY,
        yfov: 1.0,
        aspect: Some(1.0),
        znear: 0.01,
    });
    let mut opts = RenderOptions {
        width: 32,
        height: Some(32),
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 50;
    let r = render(gpu(), &s, &opts, Duration::ZERO, &mut |_| {}).expect("render");
    let (w, h, pixels) = r.image.expect("an image");
    let row = |y: u32| &pixels[(y * w) as usize..((y + 1) * w) as usize];
    for p in row(0).iter().chain(row(h / 2 - 2)) {
        for c in p {
            assert!(
                (f64::from(*c) / sky - 1.0).abs() < 1e-4,
                "above the horizon: {p:?}"
            );
        }
    }
    // The floor reflects rho E / pi = 0.5 L of the sky it sees (an open
    // floor: nothing blocks its sky, so all of it).
    for p in row(h - 1) {
        assert!(
            (f64::from(p[0]) / (0.5 * sky) - 1.0).abs() < 0.05,
            "the floor: {p:?}"
        );
    }
    // `--no-background` keeps it black; the floor is the same.
    opts.background = false;
    let r = render(gpu(), &s, &opts, Duration::ZERO, &mut |_| {}).expect("render");
    let (_, _, black) = r.image.expect("an image");
    assert!(black[..w as usize].iter().all(|p| *p == [0.0; 3]));
    let last = ((h - 1) * w) as usize;
    assert_eq!(black[last..], pixels[last..]);
}
