//! Baking (`--bake`): the glTF holds every node with the solution as vertex
//! colours proportional to the report's radiosity, and loads back with the
//! same geometry.

use crate::common::*;
use radiosity::render::{render, RenderOptions};
use std::collections::HashMap;
use std::time::Duration;

#[test]
fn a_baked_cornell_box_carries_the_report_and_the_geometry() {
    let scene = radiosity::scene::open("cornell").expect("built-in");
    let mut opts = RenderOptions {
        width: 0,
        ..RenderOptions::default()
    };
    opts.stop.max_shots = 300;
    let r = render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("render");
    let dir = tempfile::tempdir().expect("temp dir");
    for ext in ["glb", "gltf"] {
        let path = dir.path().join(format!("baked.{ext}"));
        let baked =
            radiosity::bake::write(&path, &scene, &r.mesh, &r.radiosity).expect("bake written");
        assert_eq!(baked.nodes, scene.nodes.len());

        // Per node, the area-weighted mean vertex colour is B / pi x scale
        // (every element is flat: its three vertices share a colour).
        let (doc, buffers, _) = gltf::import(&path).expect("the bake is valid glTF");
        assert!(doc.extensions_used().any(|e| e == "KHR_materials_unlit"));
        let mut area_of = HashMap::new();
        for node in doc.nodes() {
            let Some(mesh) = node.mesh() else { continue };
            let name = node.name().expect("named").to_string();
            let (mut sum, mut area) = ([0.0f64; 3], 0.0f64);
            for prim in mesh.primitives() {
                assert!(prim.material().unlit(), "{name}: not unlit");
                let reader = prim.reader(|b| Some(&buffers[b.index()]));
                let p: Vec<[f32; 3]> = reader.read_positions().expect("positions").collect();
                let c: Vec<[f32; 4]> = reader
                    .read_colors(0)
                    .expect("COLOR_0")
                    .into_rgba_f32()
                    .collect();
                let idx: Vec<u32> = reader.read_indices().expect("indices").into_u32().collect();
                for t in idx.chunks_exact(3) {
                    let v = [t[0], t[1], t[2]].map(|i| glam::Vec3::from(p[i as usize]).as_dvec3());
                    let a = 0.5 * (v[1] - v[0]).cross(v[2] - v[0]).length();
                    area += a;
                    for k in 0..3 {
                        sum[k] += a * c[t[0] as usize][k] as f64;
                    }
                }
            }
            area_of.insert(name.clone(), area);
            let surface = node_named(&r, &name);
            if name == "light" {
                // The emitter clips at 1.
                assert!(sum.iter().all(|s| rel(s / area, 1.0) < 1e-6), "{name}");
                continue;
            }
            for (k, s) in sum.iter().enumerate() {
                let want = surface.radiosity[k] / std::f64::consts::PI * baked.scale;
                assert!(
                    rel(s / area, want) < 1e-4,
                    "{name}[{k}]: mean colour {} against {want}",
                    s / area
                );
            }
        }
        // The geometry round-trips through the renderer's own loader.
        let back = radiosity::scene::load(&path).expect("loads back");
        let mut names = back.nodes.clone();
        names.sort();
        let mut want = scene.nodes.clone();
        want.sort();
        assert_eq!(names, want);
        for s in &r.report.surfaces {
            let loaded: f64 = back
                .polygons
                .iter()
                .filter(|p| back.nodes[p.node] == s.node)
                .map(|p| p.area() as f64)
                .sum();
            assert!(
                rel(loaded, s.area) < 1e-4,
                "{}: area {loaded} against {}",
                s.node,
                s.area
            );
            assert!(rel(area_of[&s.node], s.area) < 1e-4);
        }
        let (lo, hi) = back.bounds();
        let (a, b) = scene.bounds();
        let moved = (glam::Vec3::from(back.origin.map(|x| x as f32)) + lo)
            .distance(glam::Vec3::from(scene.origin.map(|x| x as f32)) + a)
            + (glam::Vec3::from(back.origin.map(|x| x as f32)) + hi)
                .distance(glam::Vec3::from(scene.origin.map(|x| x as f32)) + b);
        assert!(moved < 1e-4, "bounds moved by {moved}");
    }
}

fn node_named<'a>(
    r: &'a radiosity::render::Rendered,
    name: &str,
) -> &'a radiosity::report::Surface {
    r.report
        .surfaces
        .iter()
        .find(|s| s.node == name)
        .unwrap_or_else(|| panic!("no surface {name}"))
}
