//! Per node against independent references: path-traced radiosities with
//! next-event estimation (`scripts/reference.py`, Mitsuba 3), cached in
//! `docs/references/` with their standard errors (at most 0.1 % per node)
//! and the command that made them. The suite never runs the path tracer.
//! Default settings, on scenes of the generated family no default was
//! chosen on, and the Cornell box.

use crate::common::gpu;
use radiosity::render::{render, RenderOptions};
use std::time::Duration;

/// A cached reference's nodes: (name, radiosity summed over RGB, relative
/// standard error).
fn reference(scene: &str) -> Vec<(String, f64, f64)> {
    let path = format!(
        "{}/docs/references/{scene}.json",
        env!("CARGO_MANIFEST_DIR")
    );
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let doc: serde_json::Value = serde_json::from_str(&text).expect("reference JSON");
    assert!(
        doc["command"].as_str().is_some(),
        "{path} says how it was made"
    );
    doc["surfaces"]
        .as_array()
        .expect("surfaces")
        .iter()
        .map(|s| {
            let b: f64 = s["radiosity"]
                .as_array()
                .expect("rgb")
                .iter()
                .filter_map(|x| x.as_f64())
                .sum();
            let se = s["relative_standard_error"]
                .as_f64()
                .expect("standard error");
            (s["node"].as_str().expect("node").to_string(), b, se)
        })
        .collect()
}

#[test]
fn default_renders_are_within_one_percent_mean_and_three_worst_of_path_traced_references() {
    check([
        "cornell",
        "family-l-room-1",
        "family-slab-1",
        "family-boxes-1",
        "family-corridor-1",
        "family-floor-1",
        // Touching and stacked boxes, and a room whose floor runs under its
        // walls: above 3 % worst before the contact split.
        "family-stacked-1",
        "family-opening-1",
    ]);
}

/// Seed 2 of the family: scenes that no default and no fix was chosen
/// on (their references were made after the defaults were fixed).
#[test]
fn held_out_scenes_are_within_one_percent_mean_and_three_worst() {
    check([
        "family-boxes-2",
        "family-l-room-2",
        "family-corridor-2",
        "family-opening-2",
        "family-floor-2",
    ]);
}

/// Lattices (3-D grids of boxes whose gaps are narrower than the boxes)
/// and thin things against walls (a picture 1-2 cm off a wall, a skirting
/// board, a shelf board, small objects on a table): made after the
/// defaults were fixed. Before the emitters were traced over their whole
/// area, family-lattice-1 was 2.8 % mean, 13.4 % worst (its second layer).
#[test]
fn lattices_and_thin_things_are_within_one_percent_mean_and_three_worst() {
    check([
        "family-lattice-1",
        "family-lattice-2",
        "family-thin-1",
        "family-thin-2",
    ]);
}

/// Bookcases under a grid of ceiling panels: the goal (1 % mean, 3 %
/// worst) is not met. The bottom shelf is 3.0 % (seed 1) and 5.75 %
/// (seed 2) too bright, from the large floor and wall patches beside it
/// (uniform 0.25 m patches give 2.4 %); this bounds what is measured so a
/// change for the worse fails (docs/notebook/visibility.md).
#[test]
fn bookcases_under_a_grid_of_panels_stay_within_their_measured_error() {
    for scene in ["family-shelves-1", "family-shelves-2"] {
        let s = radiosity::scene::open(scene).expect("scene");
        let opts = RenderOptions {
            width: 0,
            ..RenderOptions::default()
        };
        check_with(scene, &s, &opts, 0.01, 0.065);
    }
}

/// Furnished rooms lit by a sun and a sky through a window (no lamp), at
/// default settings: 0.15 % mean, 0.86 % worst (seed 1) and 0.26 %, 1.27 %
/// (seed 2) on 2026-12-07, with each element's sky-ray blocks shuffled. With
/// 64 sky directions an element, as before the sky's rays grew with the
/// budget, seed 1's picture was 9.5 % too dark.
#[test]
fn furnished_rooms_lit_through_a_window_are_within_one_percent_mean_and_three_worst() {
    check(["family-furnished-1", "family-furnished-2"]);
}

/// The Cornell box with a point light besides its panel
/// (`scenes/cornell-lit.gltf`), a sun and a sky through its open front
/// (issue 18's benchmark: lights against the strong path tracer).
#[test]
fn a_point_light_a_sun_and_a_sky_are_within_one_percent_mean_of_a_path_traced_reference() {
    check_scene("cornell-lit", &lit_cornell());
}

/// The same with a striped texture on the floor (`scenes/cornell-textured.gltf`):
/// the path tracer samples the texture at each point, the renderer takes
/// its mean per element.
#[test]
fn a_textured_floor_under_lights_is_within_one_percent_mean_of_a_path_traced_reference() {
    let s = lit_cornell_file("cornell-textured");
    assert!(
        s.polygons.iter().any(|p| p.texture.is_some()),
        "the floor is textured"
    );
    check_scene("cornell-textured", &s);
}

/// `scenes/cornell-lit.gltf` with the sun and sky its references were made with.
pub fn lit_cornell() -> radiosity::scene::Scene {
    lit_cornell_file("cornell-lit")
}

/// `scenes/NAME.gltf` with the sun and sky the lit references were made with.
pub fn lit_cornell_file(name: &str) -> radiosity::scene::Scene {
    let path = format!("{}/scenes/{name}.gltf", env!("CARGO_MANIFEST_DIR"));
    let mut s = radiosity::scene::open(&path).expect("scene");
    assert_eq!(s.lights.len(), 1, "the file's point light");
    s.lights
        .push(radiosity::scene::parse_sun(LIT_SUN).expect("sun"));
    s.sky = Some(radiosity::scene::parse_sky(LIT_SKY).expect("sky"));
    s
}

/// The sun and sky the lit Cornell box's reference was made with.
const LIT_SUN: &str = "0.3,0.5,1,3";
const LIT_SKY: &str = "0.3";

/// Default renders of `scenes` against their references: area-weighted
/// mean node error <= 1 %, worst node <= 3 % (emitters left out).
fn check<const N: usize>(scenes: [&str; N]) {
    for scene in scenes {
        let s = radiosity::scene::open(scene).expect("scene");
        check_scene(scene, &s);
    }
}

/// [`check`] of one scene `s` against the reference named `scene`.
pub(crate) fn check_scene(scene: &str, s: &radiosity::scene::Scene) {
    let opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    check_with(scene, s, &opts, 0.01, 0.03);
}

/// A solve stopped after 64 shots, with most of the light still unshot
/// (19-37 %), shows that light by the ambient term carried along the
/// geometry (`radiosity::ambient`): within 1 % mean per node of the
/// references. Cohen's even spread, which it replaced, was 2.2-7.9 % off
/// at this point on the same scenes (docs/accuracy.md, "The ambient term").
#[test]
fn a_solve_stopped_early_shows_the_unshot_light_within_one_percent_mean() {
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 64;
    for (scene, worst) in [
        ("cornell", 0.02),
        ("cubes-4", 0.02),
        ("family-l-room-2", 0.02),
        // One box of the pile is far from settled after 64 shots (5 %).
        ("family-stacked-2", 0.08),
    ] {
        let s = radiosity::scene::open(scene).expect("scene");
        check_with(scene, &s, &opts, 0.01, worst);
    }
}

/// Renders `s` with `opts` and checks it against the reference named
/// `scene`: area-weighted mean node error at most `mean_bound`, worst
/// node at most `worst_bound` (emitters left out).
fn check_with(
    scene: &str,
    s: &radiosity::scene::Scene,
    opts: &RenderOptions,
    mean_bound: f64,
    worst_bound: f64,
) {
    let r = render(gpu(), s, opts, Duration::ZERO, &mut |_| {}).expect("render");
    within(scene, &r.report.surfaces, mean_bound, worst_bound);
}

/// Checks `surfaces` against the reference named `scene`: area-weighted
/// mean node error at most `mean_bound`, worst node at most `worst_bound`
/// (emitters left out).
fn within(scene: &str, surfaces: &[radiosity::report::Surface], mean_bound: f64, worst_bound: f64) {
    let reference = reference(scene);
    let (mut weighted, mut area, mut worst) = (0.0, 0.0, (0.0f64, String::new()));
    for surface in surfaces {
        // The emitters' radiosity is their emission: nothing to score.
        if surface.node == "light" || surface.node == "panels" {
            continue;
        }
        let (_, b_ref, se) = reference
            .iter()
            .find(|(n, ..)| *n == surface.node)
            .unwrap_or_else(|| panic!("{scene}: no reference for {}", surface.node));
        assert!(*se <= 1.5e-3, "{scene} {}: reference SE {se}", surface.node);
        let b: f64 = surface.radiosity.iter().sum();
        let e = (b / b_ref - 1.0).abs();
        weighted += e * surface.area;
        area += surface.area;
        if e > worst.0 {
            worst = (e, surface.node.clone());
        }
    }
    let mean = weighted / area;
    eprintln!(
        "{scene}: mean {:.2} %, worst {:.2} % ({})",
        100.0 * mean,
        100.0 * worst.0,
        worst.1
    );
    assert!(
        mean <= mean_bound,
        "{scene}: mean node error {:.2} %",
        100.0 * mean
    );
    assert!(
        worst.0 <= worst_bound,
        "{scene}: node {} is {:.2} % off",
        worst.1,
        100.0 * worst.0
    );
}

/// A refinement pass shows its coarse solution from its first shot, with
/// its own ambient transport, as the final solve shows its own: the
/// report's trace starts with the pass's points (each saying its pass),
/// its times run on into the final solve's, and the pass's first point
/// is already within 1 % mean of the reference. Before, nothing was shown
/// until the pass and the final transport were done (the Cornell box's
/// first point came at 0.15-0.17 s of solve; the strong path tracer is at
/// 1 % mean in 0.13 s).
#[test]
fn a_refinement_pass_shows_its_solution_from_its_first_shot() {
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    // (The passes stop at the shot limit too.)
    opts.stop.max_shots = 6;
    for scene in ["cornell", "family-l-room-2"] {
        let s = radiosity::scene::open(scene).expect("scene");
        let r = render(gpu(), &s, &opts, Duration::ZERO, &mut |_| {}).expect("render");
        let trace = &r.report.convergence;
        let passes = trace.iter().take_while(|p| p.pass == Some(0)).count();
        assert_eq!(r.report.refinement.shots, 6, "{scene}");
        assert_eq!(passes, 6, "{scene}: a point per pass shot");
        assert!(trace[passes..].iter().all(|p| p.pass.is_none()), "{scene}");
        assert_eq!(trace[0].shots, 1);
        assert!(
            trace.windows(2).all(|w| w[0].seconds <= w[1].seconds),
            "{scene}: the trace's times run on"
        );
        let last_pass = trace[passes - 1].seconds;
        assert!(last_pass <= r.report.refinement.seconds, "{scene}");
        assert!(trace[passes].seconds >= r.report.refinement.seconds);
        within(scene, &trace[0].surfaces, 0.01, 0.03);
    }
}

/// Weak shooters along the transport (`--transport-below 1e-4`) against the
/// references: their light lands on whole patches, from ray-sampled
/// shares, so the result is coarser than the default's, but it must stay
/// within the bounds (1 % mean, 3 % worst) on a built-in scene and
/// two held-out ones. (At 1e-3, held-out stacked boxes end 6.7 % off on one
/// box, and family-boxes-2 3.1 %: docs/bench/transport-below.md "Weak shooters along the transport".)
#[test]
fn weak_shooters_along_the_transport_stay_within_one_percent_mean() {
    let opts = RenderOptions {
        width: 0,
        transport_below: Some(1e-4),
        ..RenderOptions::default()
    };
    for scene in ["cornell", "family-l-room-2", "family-boxes-2"] {
        let s = radiosity::scene::open(scene).expect("scene");
        check_with(scene, &s, &opts, 0.01, 0.03);
    }
}
