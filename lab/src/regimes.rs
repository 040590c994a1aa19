//! `radiosity-lab accuracy --regimes`: the failure-regime study's single-polygon
//! cases (docs/accuracy.md, the same scenes as the test
//! `traps::failure_regimes_for_both_projections`), each polygon's summed
//! delta form factors from a point shooter against Lambert's contour
//! integral, for both projections at 128 x 512 and 512 x 2048, charted.

use anyhow::Result;
use glam::{DVec3, Vec3};
use radiosity::gpu::{Gpu, HemisphereRasterizer};
use radiosity::hemisphere::{Resolution, TileLayout};
use radiosity::mesh::{Mesh, MeshSettings, ShooterFrame};
use radiosity::scene::{axis_rect as rect, polygon_normal, Polygon, Scene, Subdivision};
use std::path::Path;

/// The regimes: name and polygon, seen from the origin facing +z.
pub fn cases() -> Vec<(&'static str, Vec<Vec3>)> {
    vec![
        ("seam", rect(0, 1.0, [-0.3, 0.2], [0.3, 0.8], false)),
        ("pole", rect(2, 1.0, [-0.4, -0.3], [0.5, 0.6], false)),
        ("horizon", rect(1, 1.0, [-0.5, -0.3], [0.5, 0.4], false)),
        ("small far", rect(2, 3.0, [0.05, -0.2], [0.45, 0.2], false)),
        (
            "tiny near the pole",
            rect(2, 1.0, [0.002, 0.001], [0.012, 0.011], false),
        ),
        ("grazing", rect(2, 0.05, [1.0, -1.0], [5.0, 1.0], false)),
    ]
}

/// Summed delta form factors of the cells that show `poly`.
fn measured(gpu: &Gpu, poly: &[Vec3], res: Resolution, tessellated: bool) -> Result<f64> {
    let scene = Scene {
        name: "regime".into(),
        nodes: vec!["n".into()],
        polygons: vec![Polygon {
            vertices: poly.to_vec(),
            normal: polygon_normal(poly),
            reflectance: [0.5; 3],
            emission: [1.0; 3],
            node: 0,
            subdivision: Some(Subdivision {
                patches: [1, 1],
                elements: [4, 4],
            }),
            back_side: false,
            parent: None,
            texture: None,
            emissive: None,
        }],
        ..Default::default()
    };
    let mesh = Mesh::build(&scene, &MeshSettings::default());
    let mut raster = HemisphereRasterizer::new(&gpu.device, &mesh, res, 1, 10.0)?;
    if tessellated {
        raster.use_tessellation(
            &gpu.device,
            radiosity::render::DEFAULT_TESSELLATION_TOLERANCE,
        )?;
    }
    let frame = ShooterFrame::new(Vec3::ZERO, Vec3::Z, Vec3::X, u32::MAX);
    let mut items = Vec::new();
    raster.render(
        &gpu.device,
        &gpu.queue,
        &frame,
        &TileLayout::whole(res),
        (0, 0),
        &mut items,
        None,
    )?;
    let dff = res.delta_form_factors();
    Ok(items
        .iter()
        .enumerate()
        .filter(|(_, &id)| (id as usize) < mesh.elements.len())
        .map(|(i, _)| dff[i / res.cols as usize])
        .sum())
}

/// Runs the cases and writes `regimes.csv` and `regimes.{svg,png}` to `out`.
pub fn run(gpu: &Gpu, out: &Path) -> Result<()> {
    let resolutions = [128u32, 512].map(|rows| Resolution {
        rows,
        cols: 4 * rows,
    });
    let mut csv = String::from("regime,projection,resolution,form_factor,lambert,relative_error\n");
    // (series label, per case |error| in %)
    let mut series: Vec<(String, Vec<f64>)> = Vec::new();
    for tessellated in [false, true] {
        for res in resolutions {
            let label = format!(
                "{} {res}",
                if tessellated { "tessellated" } else { "exact" }
            );
            let mut errors = Vec::new();
            for (name, poly) in cases() {
                let expected = radiosity::formfactor::point_to_polygon(
                    DVec3::ZERO,
                    DVec3::Z,
                    &poly.iter().map(|p| p.as_dvec3()).collect::<Vec<_>>(),
                );
                let f = measured(gpu, &poly, res, tessellated)?;
                let err = f / expected - 1.0;
                eprintln!("regimes: {name} {label}: {:+.3} %", 100.0 * err);
                csv += &format!("{name},{label},{res},{f:.9e},{expected:.9e},{err:.6e}\n");
                errors.push(100.0 * err.abs());
            }
            series.push((label, errors));
        }
    }
    radiosity::output::write_atomic(&out.join("regimes.csv"), csv.as_bytes())?;
    let names: Vec<&str> = cases().iter().map(|c| c.0).collect();
    svg_and_png!(out, "regimes", (1000, 560), |root| draw(
        root, &names, &series
    ));
    println!(
        "wrote {}, .png and regimes.csv",
        out.join("regimes.svg").display()
    );
    Ok(())
}

fn draw<DB: plotters::prelude::DrawingBackend>(
    root: plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    names: &[&str],
    series: &[(String, Vec<f64>)],
) -> Result<(), String> {
    use plotters::prelude::*;
    let e = |x: &dyn std::fmt::Display| x.to_string();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let top = series
        .iter()
        .flat_map(|s| s.1.iter().copied())
        .fold(1.0f64, f64::max);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "failure regimes: |error| of one polygon's hemisphere form factor",
            ("sans-serif", 22),
        )
        .margin(12)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(
            -0.5f64..names.len() as f64 - 0.5,
            (0.001f64..top * 2.0).log_scale(),
        )
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_labels(names.len())
        .x_label_formatter(&|x| {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 {
                names
                    .get(i as usize)
                    .map_or(String::new(), |s| s.to_string())
            } else {
                String::new()
            }
        })
        .y_desc("|relative error| % (log)")
        .draw()
        .map_err(|x| e(&x))?;
    chart
        .draw_series(LineSeries::new(
            [(-0.5, 1.0), (names.len() as f64 - 0.5, 1.0)],
            BLACK.mix(0.5),
        ))
        .map_err(|x| e(&x))?
        .label("1 %")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.5)));
    let w = 0.8 / series.len() as f64;
    for (k, (label, errors)) in series.iter().enumerate() {
        let color = Palette99::pick(k).to_rgba();
        chart
            .draw_series(errors.iter().enumerate().map(|(i, &v)| {
                let x = i as f64 - 0.4 + w * k as f64;
                Rectangle::new([(x, 0.001), (x + w * 0.9, v.max(0.001))], color.filled())
            }))
            .map_err(|x| e(&x))?
            .label(label.as_str())
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], color.filled()));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))
}
