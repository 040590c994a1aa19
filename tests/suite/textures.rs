//! Base-colour textures (issue 18 item 3): each element reflects the
//! texture's mean over it times the factor, `KHR_texture_transform` moves
//! it, the solution uses it, and the camera image shows the texture.

use crate::common::*;
use base64::Engine;
use radiosity::mesh::{Mesh, MeshSettings};
use radiosity::render::{render, RenderOptions};
use radiosity::scene::{self, Light, Scene, Subdivision};
use serde_json::json;
use std::time::Duration;

/// sRGB 188 is linear 0.50289 (the IEC 61966-2-1 curve).
const GREY: u8 = 188;
const GREY_LINEAR: f32 = 0.502_886;

/// A PNG, `width` x 1, whose texel x is `texel(x)` (grey levels, sRGB).
fn png(width: u32, texel: impl Fn(u32) -> u8) -> String {
    let img = image::RgbImage::from_fn(width, 1, |x, _| {
        let g = texel(x);
        image::Rgb([g, g, g])
    });
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .expect("encode");
    format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

/// A 2 m x 2 m floor (facing +y, x and z in [-1, 1]), 4 x 4 elements,
/// textured along x by `image` (u = 0 at x = -1, 1 at x = 1), clamped at
/// its edges; `transform` is its `KHR_texture_transform`, if any.
fn textured_floor(image: &str, transform: Option<serde_json::Value>, camera: bool) -> Scene {
    let mut floor = surface(
        "floor",
        vec![rect(1, 0.0, [-1.0, -1.0], [1.0, 1.0], true)],
        1.0,
        0.0,
    );
    floor.subdivision = Some(Subdivision {
        patches: [2, 2],
        elements: [2, 2],
    });
    let camera = camera.then(|| {
        let s = std::f32::consts::FRAC_1_SQRT_2;
        (
            glam::Vec3::new(0.0, 2.0, 0.0),
            glam::Quat::from_xyzw(-s, 0.0, 0.0, s),
            1.2,
            1.0,
        )
    });
    let text = scene::write_gltf(&[floor], camera);
    let mut doc: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    // The quad's corners as written: (z, x) = (lo, lo), (hi, lo), (hi, hi), (lo, hi).
    let xs = [-1.0f32, -1.0, 1.0, 1.0];
    let uv: Vec<f32> = xs.iter().flat_map(|x| [(x + 1.0) / 2.0, 0.5]).collect();
    add_base_texture(&mut doc, 0, &uv, image);
    let pbr = &mut doc["materials"][0]["pbrMetallicRoughness"];
    pbr.as_object_mut().expect("pbr").remove("baseColorFactor");
    pbr["baseColorTexture"] = json!({"index": 0});
    if let Some(t) = transform {
        pbr["baseColorTexture"]["extensions"] = json!({"KHR_texture_transform": t});
        doc["extensionsUsed"] = json!(["KHR_texture_transform"]);
    }
    scene::load_slice(&serde_json::to_vec(&doc).expect("JSON"), "textured").expect("loads")
}

/// The elements' reflectance (red) by column of x, left to right.
fn columns(scene: &Scene) -> Vec<f64> {
    let mesh = Mesh::build(scene, &MeshSettings::default());
    let mut cols = [(0.0, 0.0); 4];
    // Positions are kept relative to the first vertex (x = -1).
    let x0 = scene.bounds().0.x;
    for e in &mesh.elements {
        let k = (((e.centre.x - x0) * 2.0).floor() as usize).min(3);
        cols[k].0 += e.reflectance[0] * e.area;
        cols[k].1 += e.area;
    }
    cols.iter().map(|(r, a)| r / a).collect()
}

#[test]
fn elements_reflect_the_texture_mean_over_them_and_a_transform_moves_it() {
    // Left half grey, right half black: 8 texels.
    let image = png(8, |x| if x < 4 { GREY } else { 0 });
    let scene = textured_floor(&image, None, false);
    assert!(
        !scene.warnings.iter().any(|w| w.contains("clamped")),
        "a textured material's factor of 1 is not a reflectance of 1: {:?}",
        scene.warnings
    );
    let c = columns(&scene);
    eprintln!("columns: {c:?}");
    let g = f64::from(GREY_LINEAR);
    assert!(rel(c[0], g) < 1e-3, "{c:?}");
    assert!(c[3] < 1e-6, "{c:?}");
    // Bilinear filtering blurs the edge between columns 1 and 2, but keeps the mean.
    let mean = c.iter().sum::<f64>() / 4.0;
    assert!(rel(mean, g / 2.0) < 1e-3, "{c:?}");
    // Moved by a quarter of the image (a column): each column takes what
    // the one left of it had (the first stays grey: the image is clamped).
    let moved = textured_floor(&image, Some(json!({"offset": [-0.25, 0.0]})), false);
    let m = columns(&moved);
    eprintln!("moved: {m:?}");
    for k in 1..4 {
        assert!((m[k] - c[k - 1]).abs() < 1e-4, "{m:?} vs {c:?}");
    }
    // Scaled by a half, the grey half of the image covers the floor (the
    // last column's edge blurs into the black).
    let scaled = textured_floor(&image, Some(json!({"scale": [0.5, 1.0]})), false);
    let s = columns(&scaled);
    eprintln!("scaled: {s:?}");
    assert!(s[..3].iter().all(|&r| rel(r, g) < 1e-3), "{s:?}");
    assert!(s[3] < g && s[3] > 0.8 * g, "{s:?}");
}

#[test]
fn the_solution_uses_the_texture_and_the_picture_shows_it() {
    // Left half grey, right half a quarter as bright in linear terms.
    let quarter = (((GREY_LINEAR / 4.0).powf(1.0 / 2.4) * 1.055 - 0.055) * 255.0).round() as u8;
    let image = png(8, |x| if x < 4 { GREY } else { quarter });
    let mut scene = textured_floor(&image, None, true);
    let e = 100.0;
    scene.lights.push(Light::sun(glam::Vec3::Y, [e; 3]));
    let opts = RenderOptions {
        width: 64,
        height: Some(64),
        ..tight(1e-6)
    };
    let r = render(gpu(), &scene, &opts, Duration::ZERO, &mut |_| {}).expect("render");
    let mesh = Mesh::build(&scene, &MeshSettings::default());
    let area: f64 = mesh.elements.iter().map(|e| e.area).sum();
    let mean_rho: f64 = mesh
        .elements
        .iter()
        .map(|e| e.reflectance[0] * e.area)
        .sum::<f64>()
        / area;
    let b = node(&r, "floor").radiosity[0];
    assert!(
        rel(b, mean_rho * e) < 1e-3,
        "floor radiosity {b} vs {}",
        mean_rho * e
    );
    // The picture: columns well inside each half, against rho E / pi.
    let (w, h, pixels) = r.image.as_ref().expect("an image");
    let at = |x: u32| {
        let sum: f32 = (h / 4..3 * h / 4)
            .map(|y| pixels[(y * w + x) as usize][0])
            .sum();
        f64::from(sum) / f64::from(h / 2)
    };
    let want = |rho: f64| rho * e / std::f64::consts::PI;
    let dark = f64::from(scene::texture::srgb_to_linear(f32::from(quarter) / 255.0));
    let (left, right) = (at(w / 6), at(w - 1 - w / 6));
    eprintln!(
        "picture: left {left:.4} (want {:.4}), right {right:.4} (want {:.4})",
        want(f64::from(GREY_LINEAR)),
        want(dark)
    );
    // The camera looks down -y with +y up... the image's left is -x.
    let (lo, hi) = if left > right {
        (right, left)
    } else {
        (left, right)
    };
    assert!(
        rel(hi, want(f64::from(GREY_LINEAR))) < 0.01,
        "bright half {hi}"
    );
    assert!(rel(lo, want(dark)) < 0.01, "dark half {lo}");
}

#[test]
fn a_missing_texture_falls_back_to_the_factor_with_a_warning_naming_it() {
    let scene = textured_floor("missing_diffuse.png", None, false);
    let warned: Vec<_> = scene
        .warnings
        .iter()
        .filter(|w| w.contains("missing_diffuse.png"))
        .collect();
    assert_eq!(warned.len(), 1, "{:?}", scene.warnings);
    // No factor given: glTF's 1, clamped (with its own warning).
    assert!(scene
        .polygons
        .iter()
        .all(|p| p.texture.is_none() && p.reflectance == [0.95; 3]));
}

#[test]
fn a_textured_bake_keeps_the_texture_and_bakes_irradiance() {
    let image = png(8, |x| if x < 4 { GREY } else { 40 });
    let mut scene = textured_floor(&image, None, false);
    let e = 100.0;
    scene.lights.push(Light::sun(glam::Vec3::Y, [e; 3]));
    let r = render(gpu(), &scene, &tight(1e-6), Duration::ZERO, &mut |_| {}).expect("render");
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("baked.glb");
    let baked = radiosity::bake::write(&path, &scene, &r.mesh, &r.radiosity).expect("bake");
    let (doc, buffers, images) = gltf::import(&path).expect("the bake is valid glTF");
    assert_eq!(images.len(), 1, "the texture travels with the bake");
    assert_eq!((images[0].width, images[0].height), (8, 1));
    let prim = doc
        .meshes()
        .next()
        .expect("a mesh")
        .primitives()
        .next()
        .expect("a primitive");
    let info = prim
        .material()
        .pbr_metallic_roughness()
        .base_color_texture()
        .expect("textured");
    assert_eq!(info.tex_coord(), 0);
    let reader = prim.reader(|b| Some(&buffers[b.index()]));
    let uv: Vec<[f32; 2]> = reader
        .read_tex_coords(0)
        .expect("TEXCOORD_0")
        .into_f32()
        .collect();
    assert!(
        uv.iter().all(|t| (-1e-6..=1.0 + 1e-6).contains(&t[0])),
        "{uv:?}"
    );
    // A sun straight overhead: the same irradiance everywhere, whatever
    // the texture, so every vertex has the brightest colour.
    let colours: Vec<[f32; 4]> = reader
        .read_colors(0)
        .expect("COLOR_0")
        .into_rgba_f32()
        .collect();
    assert!(
        colours.iter().all(|c| (c[0] - 1.0).abs() < 1e-4),
        "{colours:?}"
    );
    assert!(
        rel(baked.scale, std::f64::consts::PI / e) < 1e-3,
        "scale {}",
        baked.scale
    );
}
