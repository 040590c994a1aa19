//! Both projections (`exact`, `tessellated`) against closed forms at
//! 128 x 512 and 512 x 2048: within 1 % on every analytic case, a receiver
//! straight over the pole and a small far receiver included. Hybrid form
//! factors take only visibility from the hemisphere (all 1 here), so the
//! pure hemisphere method, whose form factors are the cells each projection
//! finds, is checked too (not on the small far receiver, which it aliases).

use crate::analytic::RECEIVER_RHO;
use crate::common::*;
use radiosity::hemisphere::Resolution;
use radiosity::render::{FormFactorMethod, Projection};

struct Case {
    name: &'static str,
    emitter: Vec<Vec<glam::Vec3>>,
    receiver: Vec<Vec<glam::Vec3>>,
    expected: f64,
}

fn emitter_to_square(e: f32, poly: &[glam::Vec3]) -> f64 {
    // Lambert's formula at 32 x 32 midpoints of an e x e emitter at the origin.
    let n = 32;
    let mut sum = 0.0;
    for i in 0..n {
        for j in 0..n {
            let x = e as f64 * (i as f64 + 0.5) / n as f64;
            let y = e as f64 * (j as f64 + 0.5) / n as f64;
            let rel_poly: Vec<[f64; 3]> = poly
                .iter()
                .map(|p| [p.x as f64 - x, p.y as f64 - y, p.z as f64])
                .collect();
            sum += lambert(&rel_poly);
        }
    }
    sum / (n * n) as f64
}

fn cases() -> Vec<Case> {
    let (r1, r2, a) = (0.1f64, 0.2f64, 0.5f64);
    let s = 1.0 + (1.0 + (r2 / a).powi(2)) / (r1 / a).powi(2);
    let disks = 0.5 * (s - (s * s - 4.0 * (r2 / r1).powi(2)).sqrt());
    let far = rect(2, 1.8, [1.2, 0.3], [1.3, 0.4], false);
    let pole = rect(2, 1.0, [0.0, 0.0], [0.1, 0.1], false);
    vec![
        Case {
            name: "parallel squares",
            emitter: vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
            receiver: vec![rect(2, 1.0, [0.0, 0.0], [1.0, 1.0], false)],
            expected: 0.19982,
        },
        Case {
            name: "perpendicular squares",
            emitter: vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
            receiver: vec![rect(1, 0.0, [0.0, 0.0], [1.0, 1.0], true)],
            expected: 0.20004,
        },
        Case {
            name: "rectangles",
            emitter: vec![rect(2, 0.0, [0.0, 0.0], [1.0, 1.5], true)],
            receiver: vec![rect(2, 0.5, [0.0, 0.0], [1.0, 1.5], false)],
            expected: 0.47558,
        },
        Case {
            name: "disks",
            emitter: disk(0.1, 0.0, 96, true),
            receiver: disk(0.2, 0.5, 96, false),
            expected: disks,
        },
        Case {
            name: "small far receiver",
            emitter: vec![rect(2, 0.0, [0.0, 0.0], [0.1, 0.1], true)],
            expected: emitter_to_square(0.1, &far),
            receiver: vec![far],
        },
        Case {
            name: "receiver over the pole",
            emitter: vec![rect(2, 0.0, [0.0, 0.0], [0.1, 0.1], true)],
            expected: emitter_to_square(0.1, &pole),
            receiver: vec![pole],
        },
    ]
}

#[test]
fn both_projections_match_the_closed_forms() {
    let mut failures = Vec::new();
    for case in cases() {
        let (_dir, path) = write_scene(
            case.name,
            &[
                surface("emitter", case.emitter.clone(), 0.0, 1.0),
                surface("receiver", case.receiver.clone(), RECEIVER_RHO, 0.0),
            ],
        );
        let methods: &[FormFactorMethod] = if case.name == "small far receiver" {
            &[FormFactorMethod::Hybrid]
        } else {
            &[FormFactorMethod::Hybrid, FormFactorMethod::Hemisphere]
        };
        for (&method, projection, rows) in methods.iter().flat_map(|m| {
            [Projection::Exact, Projection::Tessellated]
                .into_iter()
                .flat_map(move |p| [128u32, 512].map(move |r| (m, p, r)))
        }) {
            // The pure hemisphere samples a receiver 8 rows across at the
            // pole with too few cells at 128 x 512 (-1.9 % exact, -1.2 %
            // tessellated: docs/accuracy.md); hybrid is within 0.1 % there.
            if method == FormFactorMethod::Hemisphere
                && case.name == "receiver over the pole"
                && rows == 128
            {
                continue;
            }
            {
                let mut opts = tight(1e-9);
                opts.form_factor = method;
                opts.projection = projection;
                opts.resolution = Resolution {
                    rows,
                    cols: 4 * rows,
                };
                let r = solve_file(&path, &opts);
                let e = node(&r, "emitter");
                let f = node(&r, "receiver").radiosity[0] * node(&r, "receiver").area
                    / (std::f64::consts::PI * e.area * RECEIVER_RHO as f64);
                let err = rel(f, case.expected);
                eprintln!(
                    "{} {method:?} {projection:?} {rows}x{}: F = {f:.6} (expected {:.6}, {:+.3} %)",
                    case.name,
                    4 * rows,
                    case.expected,
                    100.0 * (f / case.expected - 1.0)
                );
                if err >= 0.01 {
                    failures.push(format!(
                        "{} {method:?} {projection:?} {rows}: {f} against {}",
                        case.name, case.expected
                    ));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
