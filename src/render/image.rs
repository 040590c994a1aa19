//! The camera image of a solution: the solution's radiance interpolated over
//! the mesh, with its direct part (by default) replaced per pixel by direct
//! light traced with exact visibility ([`crate::direct`]). Each element's
//! mean direct irradiance, traced the same way, is taken out of its
//! radiance before interpolation, so what is interpolated is the rest
//! (emission, interreflection, the ambient term) and an element's pixels
//! still average to the solution's value.

use crate::direct::DirectLight;
use crate::gather::Gather;
use crate::gpu::{view_depth_range, Gpu, GpuError, Shading, Shown, ViewRenderer, ViewSettings};
use crate::mesh::Mesh;
use crate::render::options::RenderOptions;
use crate::scene::{Camera, Scene};
use crate::solver::Solver;

pub use crate::settings::DEFAULT_SHADOW_RAYS;

/// Image samples per pixel along each axis (box-filtered), where the
/// device allows the supersampled target.
pub const SUPERSAMPLE: u32 = 4;

/// [`SUPERSAMPLE`], or less where a `width` x `height` image that many
/// times over would exceed the device's `max_dim` texture size.
pub fn supersample_for(width: u32, height: u32, max_dim: u32) -> u32 {
    let biggest = width.max(height).max(1);
    (max_dim / biggest).clamp(1, SUPERSAMPLE)
}

/// The image settings a render uses for a `size` image: its shading and
/// wireframe, [`SUPERSAMPLE`] where the device allows.
pub fn view_for(gpu: &Gpu, size: [u32; 2], shading: Shading, wireframe: bool) -> ViewSettings {
    ViewSettings {
        width: size[0],
        height: size[1],
        shading,
        supersample: supersample_for(
            size[0],
            size[1],
            gpu.device.limits().max_texture_dimension_2d,
        ),
        wireframe,
    }
}

/// The camera image of `solver`'s solution (its display radiance, with the
/// ambient term if `opts` says so, and `opts.shadow_rays`): see [`camera_image`].
pub fn solution_image(
    gpu: &Gpu,
    scene: &Scene,
    solver: &Solver,
    opts: &RenderOptions,
    camera: &Camera,
    view: &ViewSettings,
) -> Result<Vec<[f32; 3]>, GpuError> {
    let radiance = solver.display_radiance(opts.ambient);
    let parts = Parts {
        radiance: &radiance,
        direct: solver.direct(),
        unlit: Some(solver.unlit()),
    };
    let rays = ImageRays {
        shadow_rays: opts.shadow_rays,
        background: opts.background,
        gather: opts.gather,
    };
    camera_image(gpu, scene, solver.mesh(), &parts, camera, view, rays)
}

/// A solution as the image needs it: per element its radiance, and what
/// the solver knows beyond it for a better picture.
pub struct Parts<'a> {
    /// Display radiance per element (W sr^-1 m^-2).
    pub radiance: &'a [[f32; 3]],
    /// Its own direct part per element ([`Solver::direct`]): replaced by
    /// the traced direct light, so only the indirect rest is interpolated.
    /// `None` when unknown (then each element's traced mean is taken out).
    pub direct: Option<&'a [[f64; 3]]>,
    /// The elements no light reached ([`Solver::unlit`]): left out of
    /// their vertices' smooth values (`None`: every element votes).
    pub unlit: Option<Vec<bool>>,
}

/// What the camera image traces per sample.
#[derive(Clone, Copy, Debug)]
pub struct ImageRays {
    /// About this many shadow rays per emitter (rounded to a square); 0:
    /// the direct light is interpolated like the rest and nothing is traced.
    pub shadow_rays: u32,
    /// Whether the scene's sky shows where camera rays leave the scene.
    pub background: bool,
    /// Final gather rays per pixel (rounded to a square per sample) for
    /// the indirect light ([`crate::gather`]); 0 interpolates it from the
    /// solution. Only with `shadow_rays` > 0.
    pub gather: u32,
}

/// Renders `mesh` with the solution `parts` from `camera`; with
/// `rays.shadow_rays` > 0 the direct light is traced per sample, and the
/// scene's sky drawn where camera rays leave the scene (unless
/// `rays.background` is off); otherwise the direct light is interpolated
/// like the rest and what no polygon covers stays black.
pub fn camera_image(
    gpu: &Gpu,
    scene: &Scene,
    mesh: &Mesh,
    parts: &Parts,
    camera: &Camera,
    view: &ViewSettings,
    rays: ImageRays,
) -> Result<Vec<[f32; 3]>, GpuError> {
    let shadow_rays = rays.shadow_rays;
    let (device, queue) = (&gpu.device, &gpu.queue);
    let mut renderer = ViewRenderer::new(device);
    let unlit = parts.unlit.as_deref();
    let radiance = parts.radiance;
    if shadow_rays == 0 {
        let shown = Shown {
            mesh,
            radiance,
            hidden: unlit,
        };
        return renderer.render_masked(device, queue, shown, camera, view);
    }
    let strata = (shadow_rays as f64).sqrt().ceil() as u32;
    // The mesh's hierarchy holds the same polygons (built once per mesh).
    let light = DirectLight::new(scene, &mesh.occluders, strata);
    let (near, far) = view_depth_range(mesh, camera);
    let size = [view.width, view.height];
    let ss = view.supersample.max(1);
    let gather = (rays.gather > 0).then(|| {
        let side = (f64::from(rays.gather) / f64::from(ss * ss)).sqrt().ceil() as u32;
        Gather::new(mesh, radiance, scene.background(), side)
    });
    let traced = light.image(camera, size, ss, [near, far], gather.as_ref());
    let rest = indirect_part(mesh, parts, &light, &traced.seen);
    let shown = Shown {
        mesh,
        radiance: &rest,
        hidden: unlit,
    };
    let mut pixels = renderer.render_masked(device, queue, shown, camera, view)?;
    for (p, t) in pixels.iter_mut().zip(&traced.texture) {
        (0..3).for_each(|c| p[c] *= t[c]);
    }
    if gather.is_some() {
        crate::gather::blend(&mut pixels, &traced.gathered, size[0] as usize);
    }
    // Where a sample's ray leaves the scene the sky shows, at its radiance.
    let shown_sky = if rays.background { 1.0 } else { 0.0 };
    let traced_parts = traced.direct.iter().zip(&traced.sky).zip(&traced.emitted);
    for (p, ((d, sky), le)) in pixels.iter_mut().zip(traced_parts) {
        for c in 0..3 {
            // The rest of an element whose direct light the solution
            // underestimated can dip below 0 where the traced light is small.
            p[c] = (p[c] + d[c]).max(0.0) + shown_sky * sky[c] + le[c];
        }
    }
    Ok(pixels)
}

/// What the image interpolates of `parts`: each element's radiance less its
/// direct part (the solution's own, else `light`'s traced mean over the
/// elements of the polygons `seen`), over its reflectance on textured
/// polygons (each pixel multiplies its texture back).
fn indirect_part(mesh: &Mesh, parts: &Parts, light: &DirectLight, seen: &[bool]) -> Vec<[f32; 3]> {
    let radiance = parts.radiance;
    let mut rest: Vec<[f32; 3]> = match parts.direct {
        Some(direct) => radiance
            .iter()
            .zip(direct)
            .map(|(r, d)| [0, 1, 2].map(|c| r[c] - (d[c] / std::f64::consts::PI) as f32))
            .collect(),
        None => {
            let element_direct = light.element_irradiance(mesh, seen);
            mesh.elements
                .iter()
                .zip(radiance)
                .zip(&element_direct)
                .map(|((e, r), d)| {
                    let rho = e.reflectance;
                    [0, 1, 2].map(|c| r[c] - (rho[c] * d[c] / std::f64::consts::PI) as f32)
                })
                .collect()
        }
    };
    // An emissive texture's emission is traced per sample (`Image::emitted`).
    for (j, (r, e)) in rest.iter_mut().zip(&mesh.elements).enumerate() {
        if mesh.polygons[e.polygon as usize].emission_texels.is_some() {
            let le = mesh.element_exitance(j);
            (0..3).for_each(|c| r[c] -= (le[c] / std::f64::consts::PI) as f32);
        }
    }
    // Textured elements interpolate their irradiance (the rest over their
    // reflectance); each pixel multiplies it by its texture.
    for (r, e) in rest.iter_mut().zip(&mesh.elements) {
        if mesh.polygons[e.polygon as usize].textured {
            for (x, rho) in r.iter_mut().zip(e.reflectance) {
                *x = if rho > 1e-6 {
                    (f64::from(*x) / rho) as f32
                } else {
                    0.0
                };
            }
        }
    }
    rest
}
