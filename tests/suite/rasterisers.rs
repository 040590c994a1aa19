//! The exact projection drawn by the device (wgpu) and on the CPU
//! (`--rasteriser`): the same cells, the same coverage counts and the same
//! solution, on any tiling.

use crate::common::*;
use radiosity::hemisphere::{Resolution, TileLayout, EMPTY};
use radiosity::render::{render, Rasteriser, RenderOptions};
use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

#[test]
fn the_cpu_draws_the_cells_and_counts_the_device_draws() {
    // 27 cubes in a room (depth complexity, seams, back faces) at the
    // default resolution, and the Cornell box (walls of many elements)
    // at the coarse tier's, from 40 shooters all over each, on one rank's
    // whole hemisphere, one rank's tiles of a 3 x 2 grid and one rank's
    // cells of a 1 x 1 lattice. Both compute the same f32 test, but a
    // driver may fuse a multiply-add or divide by a reciprocal: a hit
    // point on the line between two elements of a grid may then land in
    // the other (at most 1 cell in 10 000; hidden or not, at most 1
    // fragment in 10 000 counted for a neighbour, two counts off each),
    // and a ray grazing an edge or a depth tie may see another polygon (at
    // most 1 cell in 100 000). On lavapipe the 27 cubes agree to the bit,
    // and the Cornell box in 41 of 704 512 cells, none showing another
    // polygon.
    let coarse = Resolution {
        rows: 64,
        cols: 256,
    };
    for (name, res) in [("cubes-3", Resolution::default()), ("cornell", coarse)] {
        let scene = radiosity::scene::open(name).expect("built-in");
        let mesh = radiosity::mesh::Mesh::build(&scene, &Default::default());
        agree(&scene, &mesh, res);
    }
}

/// Draws 40 shooters' hemispheres of `mesh` at `res` by the device and on
/// the CPU, on three tilings, and compares cells and coverage counts.
fn agree(scene: &radiosity::scene::Scene, mesh: &radiosity::mesh::Mesh, res: Resolution) {
    let g = gpu();
    let new = |cpu: bool| {
        let mut r =
            radiosity::gpu::HemisphereRasterizer::new(&g.device, mesh, res, 1, scene.extent())
                .expect("rasteriser");
        r.set_count_coverage(true);
        r.set_software(cpu);
        assert_eq!(r.software(), cpu);
        r
    };
    let (mut device, mut cpu, mut packing) = (new(false), new(true), new(true));
    packing.set_pack_visible(true);
    let layouts = [
        (TileLayout::whole(res), (0, 0)),
        (
            TileLayout {
                tile_w: 8,
                tile_h: 4,
                px: 3,
                py: 2,
            },
            (1, 1),
        ),
        (
            TileLayout {
                tile_w: 1,
                tile_h: 1,
                px: 3,
                py: 1,
            },
            (2, 0),
        ),
    ];
    // What a cell shows: a polygon, a back face or nothing.
    let polygon = |item: u32| mesh.elements.get(item as usize).map(|e| e.polygon);
    let (mut a, mut b, mut c) = (Vec::new(), Vec::new(), Vec::new());
    for (layout, own) in layouts {
        let (mut cells, mut drawn, mut elements, mut polygons) = (0, 0, 0, 0);
        let (mut counted, mut count_diff) = (0u64, 0u64);
        for patch in (0..mesh.patches.len()).step_by(mesh.patches.len() / 40) {
            let frame = mesh.shooter_frame(patch as u32);
            device
                .render(&g.device, &g.queue, &frame, &layout, own, &mut a, None)
                .expect("device");
            cpu.render(&g.device, &g.queue, &frame, &layout, own, &mut b, None)
                .expect("cpu");
            // Counting visible cells into the coverage pairs (one rank's
            // whole hemisphere only) changes no cell, and each pair is the
            // element's visible cells << 32 | its covered cells.
            packing
                .render(&g.device, &g.queue, &frame, &layout, own, &mut c, None)
                .expect("cpu, packing");
            assert!(
                b == c,
                "{layout:?}: counting visible cells changed the cells"
            );
            let whole = layout.ranks() == 1;
            assert_eq!(packing.coverage_packs_visible(), whole, "{layout:?}");
            let mut want: BTreeMap<u32, u64> = cpu.coverage_pairs().collect();
            if whole {
                for &item in &b {
                    if let Some(count) = want.get_mut(&item) {
                        *count += 1 << 32;
                    }
                }
            }
            let got: BTreeMap<u32, u64> = packing.coverage_pairs().collect();
            assert!(got == want, "{layout:?}: other packed counts");
            assert_eq!(a.len(), b.len());
            cells += a.len();
            drawn += b.iter().filter(|&&c| c != EMPTY).count();
            for (&x, &y) in a.iter().zip(&b) {
                if x != y {
                    elements += 1;
                    let (p, q) = (polygon(x), polygon(y));
                    polygons += usize::from(p != q || (p.is_none() && x != y));
                }
            }
            let on_device: BTreeMap<u32, u64> = device.coverage_pairs().collect();
            let on_cpu: BTreeMap<u32, u64> = cpu.coverage_pairs().collect();
            counted += on_device.values().sum::<u64>();
            let keys: BTreeSet<&u32> = on_device.keys().chain(on_cpu.keys()).collect();
            count_diff += keys
                .into_iter()
                .map(|k| {
                    let (x, y) = (on_device.get(k), on_cpu.get(k));
                    x.copied().unwrap_or(0).abs_diff(y.copied().unwrap_or(0))
                })
                .sum::<u64>();
        }
        eprintln!(
            "{} at {res}, {layout:?} rank {own:?}: {elements} of {cells} cells differ \
             ({polygons} in what they show; {drawn} drawn); coverage by {count_diff} of \
             {counted}",
            scene.name
        );
        assert!(drawn > cells / 20, "{layout:?}: only {drawn} cells drawn");
        assert!(
            polygons * 100_000 <= cells,
            "{layout:?}: {polygons} of {cells} cells show another polygon"
        );
        assert!(
            elements * 10_000 <= cells,
            "{layout:?}: {elements} of {cells} cells differ"
        );
        assert!(
            count_diff * 5_000 <= counted,
            "{layout:?}: coverage differs by {count_diff} of {counted}"
        );
    }
}

#[test]
fn a_solve_drawn_on_the_cpu_is_the_devices_and_tiles_alike() {
    // The Cornell box, 60 shots, drawn by the device and on the CPU: every
    // node within 1e-4 (the few cells above), the report saying which drew;
    // and on the CPU the same bits on any tiling, as on the device
    // (determinism.rs checks the default, `auto`).
    let scene = radiosity::scene::open("cornell").expect("built-in scene");
    let solve = |rasteriser: Rasteriser, layout: Option<TileLayout>| {
        let mut opts = RenderOptions {
            width: 0,
            rasteriser,
            layout,
            ..RenderOptions::default()
        };
        opts.stop.max_shots = 60;
        render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("render")
    };
    let device = solve(Rasteriser::Device, None);
    let cpu = solve(Rasteriser::Cpu, None);
    assert_eq!(device.report.settings.rasteriser, Rasteriser::Device);
    assert_eq!(cpu.report.settings.rasteriser, Rasteriser::Cpu);
    for (d, c) in device.report.surfaces.iter().zip(&cpu.report.surfaces) {
        for k in 0..3 {
            let (x, y) = (d.radiosity[k], c.radiosity[k]);
            assert!(
                (x - y).abs() <= 1e-4 * x.abs().max(1e-3),
                "{}: {x} on the device, {y} on the CPU",
                d.node
            );
        }
    }
    for rasteriser in [Rasteriser::Device, Rasteriser::Cpu] {
        let whole = if rasteriser == Rasteriser::Device {
            &device
        } else {
            &cpu
        };
        for (tile_w, tile_h, px, py) in [(8, 4, 3, 2), (1, 1, 7, 1)] {
            let layout = TileLayout {
                tile_w,
                tile_h,
                px,
                py,
            };
            let tiled = solve(rasteriser, Some(layout));
            assert!(
                whole.radiosity == tiled.radiosity,
                "{rasteriser:?}: radiosities differ on {layout:?}"
            );
        }
    }
    // `auto` draws on the CPU on a CPU adapter (lavapipe), else on the device.
    let auto = solve(Rasteriser::Auto, None);
    let expected = if gpu().is_cpu() {
        Rasteriser::Cpu
    } else {
        Rasteriser::Device
    };
    assert_eq!(auto.report.settings.rasteriser, expected);
    // The tessellated projection needs fixed-function rasterisation: the
    // device draws it whatever is asked, and the report says so.
    let tessellated = RenderOptions {
        projection: radiosity::render::Projection::Tessellated,
        rasteriser: Rasteriser::Cpu,
        ..RenderOptions::default()
    };
    assert_eq!(tessellated.rasteriser_for(true), Rasteriser::Device);
    assert_eq!(
        RenderOptions::default().rasteriser_for(true),
        Rasteriser::Cpu
    );
    assert_eq!(
        RenderOptions::default().rasteriser_for(false),
        Rasteriser::Device
    );
}

/// Asking for the device's drawing on an adapter that is itself a CPU
/// rasteriser (lavapipe, as in CI) says so loudly, in the log and the
/// report; `auto` (which draws on the CPU there) says nothing of it.
#[test]
fn the_device_asked_for_on_a_cpu_adapter_is_a_warning_in_the_report() {
    let scene = radiosity::scene::open("cornell").expect("scene");
    let warned = |rasteriser: Rasteriser| {
        let mut opts = RenderOptions {
            width: 0,
            rasteriser,
            ..RenderOptions::default()
        };
        opts.stop.max_shots = 10;
        let r = render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("render");
        r.report
            .warnings
            .iter()
            .any(|w| w.contains("the adapter is a CPU rasteriser"))
    };
    assert_eq!(warned(Rasteriser::Device), gpu().is_cpu());
    assert!(!warned(Rasteriser::Auto));
}
