//! The projection's traps (DESIGN.md section 2), each against the analytic
//! form factor from a differential area (Lambert's contour integral).
//!
//! A shooter frame sits at the origin with z up and theta = 0 along +x; the
//! test polygons go through the loader-free path: scene -> mesh -> rasteriser,
//! and F is the sum of delta form factors over the cells naming each polygon.

use crate::common::*;
use glam::Vec3;
use radiosity::gpu::HemisphereRasterizer;
use radiosity::hemisphere::{Resolution, TileLayout, BLOCKED, EMPTY};
use radiosity::mesh::{Mesh, MeshSettings, ShooterFrame};
use radiosity::scene::{polygon_normal, Polygon, Scene, Subdivision};

struct Hemi {
    /// Form factor seen per polygon (by index), and of BLOCKED cells.
    per_polygon: Vec<f64>,
    blocked: f64,
    /// The item buffer assembled from every rank's tiles.
    assembled: Vec<u32>,
}

fn look(
    polys: &[Vec<Vec3>],
    res: Resolution,
    frame: ShooterFrame,
    elements: u32,
    layout: TileLayout,
) -> Hemi {
    look_with(polys, res, frame, elements, layout, None)
}

/// [`look`] with the tessellated projection at `tessellation` cells, if given.
fn look_with(
    polys: &[Vec<Vec3>],
    res: Resolution,
    frame: ShooterFrame,
    elements: u32,
    layout: TileLayout,
    tessellation: Option<f32>,
) -> Hemi {
    let polygons = polys
        .iter()
        .map(|v| Polygon {
            vertices: v.clone(),
            normal: polygon_normal(v),
            reflectance: [0.5; 3],
            emission: [1.0; 3],
            node: 0,
            subdivision: Some(Subdivision {
                patches: [1, 1],
                elements: [elements, elements],
            }),
            back_side: false,
            parent: None,
            texture: None,
            emissive: None,
        })
        .collect();
    let scene = Scene {
        name: "trap".into(),
        nodes: vec!["n".into()],
        polygons,
        ..Default::default()
    };
    let mesh = Mesh::build(&scene, &MeshSettings::default());
    let g = gpu();
    let mut raster = HemisphereRasterizer::new(&g.device, &mesh, res, 1, 10.0).expect("rasteriser");
    if let Some(tol) = tessellation {
        raster
            .use_tessellation(&g.device, tol)
            .expect("tessellation");
    }
    let dff = res.delta_form_factors();
    let mut per_polygon = vec![0.0; polys.len()];
    let mut blocked = 0.0;
    let mut items = Vec::new();
    let mut assembled = vec![EMPTY; res.cells()];
    for ry in 0..layout.py {
        for rx in 0..layout.px {
            raster
                .render(
                    &g.device,
                    &g.queue,
                    &frame,
                    &layout,
                    (rx, ry),
                    &mut items,
                    None,
                )
                .expect("render");
            for (i, &id) in items.iter().enumerate() {
                let (p, t) = (
                    (i / res.cols as usize) as u32,
                    (i % res.cols as usize) as u32,
                );
                if layout.owner(p, t) == (rx, ry) {
                    assembled[i] = id;
                } else {
                    assert_eq!(
                        id, EMPTY,
                        "rank ({rx},{ry}) drew cell ({p},{t}) it does not own"
                    );
                }
                let w = dff[i / res.cols as usize];
                if id == BLOCKED {
                    blocked += w;
                } else if (id as usize) < mesh.elements.len() {
                    per_polygon[mesh.elements[id as usize].polygon as usize] += w;
                }
            }
        }
    }
    Hemi {
        per_polygon,
        blocked,
        assembled,
    }
}

fn origin_frame() -> ShooterFrame {
    ShooterFrame::new(Vec3::ZERO, Vec3::Z, Vec3::X, u32::MAX)
}

fn as_f64(p: &[Vec3]) -> Vec<[f64; 3]> {
    p.iter()
        .map(|v| [v.x as f64, v.y as f64, v.z as f64])
        .collect()
}

// Fine enough that the cell-centre sampling error of these polygons is well
// under 1 % (at 256 x 1024 the seam test polygon is 1.1 % high; the same at
// any azimuth, so the seam itself adds nothing).
const RES: Resolution = Resolution {
    rows: 512,
    cols: 2048,
};

fn check_single(name: &str, poly: Vec<Vec3>) {
    let expected = lambert(&as_f64(&poly));
    let h = look(&[poly], RES, origin_frame(), 4, TileLayout::whole(RES));
    let f = h.per_polygon[0];
    eprintln!("{name}: F = {f:.6}, Lambert {expected:.6}");
    assert!(
        rel(f, expected) < 0.01,
        "{name}: F = {f}, expected {expected}"
    );
}

#[test]
fn polygon_straddling_the_seam() {
    // In the plane x = 1, facing the shooter (-x), across theta = 0.
    check_single("seam", rect(0, 1.0, [-0.3, 0.2], [0.3, 0.8], false));
}

#[test]
fn polygon_containing_the_pole() {
    // Above the shooter, facing down, off-centre around the normal direction.
    check_single("pole", rect(2, 1.0, [-0.4, -0.3], [0.5, 0.6], false));
}

#[test]
fn polygon_crossing_the_horizon() {
    // In the plane y = 1 facing -y, half below the tangent plane.
    check_single("horizon", rect(1, 1.0, [-0.5, -0.3], [0.5, 0.4], false));
}

#[test]
fn small_far_polygon_near_the_pole_is_still_found() {
    check_single("far", rect(2, 3.0, [0.05, -0.2], [0.45, 0.2], false));
}

#[test]
fn a_frame_with_a_reach_draws_only_the_polygons_within_it() {
    // A split shot's groups look again only at the near receivers, and
    // draw only what lies within reach of them: a polygon wholly beyond the
    // reach is not drawn; one within it, or reaching into it, is drawn whole.
    let near = rect(2, 0.5, [-0.2, -0.2], [0.2, 0.2], false);
    // Off to the side, where neither of the others hides it.
    let far = rect(2, 3.0, [-4.0, -1.0], [-2.0, 1.0], false);
    let long = rect(0, 0.8, [-0.3, 0.1], [0.3, 3.0], false);
    let polys = [near.clone(), far, long];
    let whole = TileLayout::whole(RES);
    let all = look(&polys, RES, origin_frame(), 4, whole);
    let cut = look(&polys, RES, origin_frame().within(1.0), 4, whole);
    assert!(rel(cut.per_polygon[0], lambert(&as_f64(&near))) < 0.01);
    assert!(all.per_polygon[1] > 0.01, "the far polygon shows unlimited");
    assert_eq!(cut.per_polygon[1], 0.0, "the far polygon is beyond reach");
    assert!(all.per_polygon[2] > 0.01, "the long polygon shows");
    for k in [0, 2] {
        assert_eq!(cut.per_polygon[k], all.per_polygon[k], "polygon {k}");
    }
}

#[test]
fn back_face_blocks_but_receives_nothing() {
    // A receiver behind a blocker whose back faces the shooter.
    let receiver = rect(2, 1.0, [-0.3, -0.3], [0.3, 0.3], false);
    let blocker = rect(2, 0.5, [-1.0, -1.0], [1.0, 1.0], true);
    let blocker_f = lambert(&as_f64(&blocker));
    let h = look(
        &[receiver.clone(), blocker],
        RES,
        origin_frame(),
        4,
        TileLayout::whole(RES),
    );
    assert_eq!(h.per_polygon[0], 0.0, "the receiver is fully shadowed");
    assert_eq!(h.per_polygon[1], 0.0, "a back face receives nothing");
    assert!(
        rel(h.blocked, blocker_f) < 0.01,
        "blocked {} vs {blocker_f}",
        h.blocked
    );

    // Without the blocker the receiver sees its analytic share.
    let alone = look(
        std::slice::from_ref(&receiver),
        RES,
        origin_frame(),
        4,
        TileLayout::whole(RES),
    );
    assert!(rel(alone.per_polygon[0], lambert(&as_f64(&receiver))) < 0.01);

    // A receiver seen from its back gets nothing but blocks.
    let backwards = rect(2, 1.0, [-0.3, -0.3], [0.3, 0.3], true);
    let h = look(&[backwards], RES, origin_frame(), 4, TileLayout::whole(RES));
    assert_eq!(h.per_polygon[0], 0.0);
    assert!(rel(h.blocked, lambert(&as_f64(&receiver))) < 0.01);
}

#[test]
fn own_polygon_and_coplanar_neighbours_are_invisible() {
    let own = rect(2, 0.0, [-1.0, -1.0], [1.0, 1.0], true);
    let neighbour = rect(2, 0.0, [1.0, -1.0], [2.0, 1.0], true);
    let frame = ShooterFrame::new(Vec3::ZERO, Vec3::Z, Vec3::X, 0);
    let h = look(&[own, neighbour], RES, frame, 4, TileLayout::whole(RES));
    assert_eq!(h.per_polygon, vec![0.0, 0.0]);
    assert_eq!(h.blocked, 0.0);
}

#[test]
fn item_buffer_does_not_depend_on_tiling() {
    let polys = vec![
        rect(0, 1.0, [-0.3, 0.2], [0.3, 0.8], false),
        rect(2, 1.0, [-0.4, -0.3], [0.5, 0.6], false),
        rect(1, 1.0, [-0.5, -0.3], [0.5, 0.4], false),
        rect(2, 0.5, [-1.0, -1.0], [-0.2, 1.0], true),
    ];
    let res = Resolution {
        rows: 64,
        cols: 256,
    };
    let whole = look(&polys, res, origin_frame(), 3, TileLayout::whole(res));
    for layout in [
        TileLayout {
            tile_w: 1,
            tile_h: 1,
            px: 4,
            py: 2,
        },
        TileLayout {
            tile_w: 16,
            tile_h: 8,
            px: 3,
            py: 2,
        },
        TileLayout {
            tile_w: 7,
            tile_h: 5,
            px: 1,
            py: 3,
        },
    ] {
        let tiled = look(&polys, res, origin_frame(), 3, layout);
        assert!(
            tiled.assembled == whole.assembled,
            "{layout:?}: assembled item buffer differs"
        );
    }
}

/// The failure regimes (docs/accuracy.md) for both projections: each trap
/// polygon's summed delta form factors against Lambert's integral, at
/// 128 x 512 and 512 x 2048. Asserted within 1 % at 512 x 2048 (cell
/// sampling is the only error left there); 128 x 512 is printed for the
/// study.
#[test]
fn failure_regimes_for_both_projections() {
    let cases: Vec<(&str, Vec<Vec3>)> = vec![
        ("seam", rect(0, 1.0, [-0.3, 0.2], [0.3, 0.8], false)),
        ("pole", rect(2, 1.0, [-0.4, -0.3], [0.5, 0.6], false)),
        ("horizon", rect(1, 1.0, [-0.5, -0.3], [0.5, 0.4], false)),
        ("small far", rect(2, 3.0, [0.05, -0.2], [0.45, 0.2], false)),
        (
            "tiny near the pole",
            rect(2, 1.0, [0.002, 0.001], [0.012, 0.011], false),
        ),
        ("grazing", rect(2, 0.05, [1.0, -1.0], [5.0, 1.0], false)),
    ];
    let mut bad = Vec::new();
    for (name, poly) in &cases {
        let expected = lambert(&as_f64(poly));
        for rows in [128u32, 512] {
            let res = Resolution {
                rows,
                cols: 4 * rows,
            };
            for tess in [None, Some(0.1f32)] {
                let h = look_with(
                    std::slice::from_ref(poly),
                    res,
                    origin_frame(),
                    4,
                    TileLayout::whole(res),
                    tess,
                );
                let f = h.per_polygon[0];
                let what = if tess.is_some() {
                    "tessellated"
                } else {
                    "exact"
                };
                eprintln!(
                    "regime {name} {what} {res}: F = {f:.6e}, Lambert {expected:.6e}, {:+.3} %",
                    100.0 * (f / expected - 1.0)
                );
                if rows == 512 && rel(f, expected) >= 0.01 {
                    bad.push(format!("{name} {what} {res}: {f} vs {expected}"));
                }
            }
        }
    }
    // Coincident surfaces: the one drawn first wins every tie, in both
    // projections, and the cells are not counted twice.
    let a = rect(2, 1.0, [-0.3, -0.3], [0.3, 0.3], false);
    let expected = lambert(&as_f64(&a));
    for tess in [None, Some(0.1f32)] {
        let h = look_with(
            &[a.clone(), a.clone()],
            RES,
            origin_frame(),
            2,
            TileLayout::whole(RES),
            tess,
        );
        eprintln!(
            "regime coincident {tess:?}: {:?}, Lambert {expected:.6}",
            h.per_polygon
        );
        if rel(h.per_polygon[0] + h.per_polygon[1], expected) >= 0.01 || h.per_polygon[1] > 0.0 {
            bad.push(format!("coincident {tess:?}: {:?}", h.per_polygon));
        }
    }
    assert!(bad.is_empty(), "{bad:#?}");
}
