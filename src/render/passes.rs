//! Refinement by need (`crate::refine`): coarse solves, each followed by a
//! decision that doubles some polygons' patch grids. The passes run the
//! same shooting loop as the final solve, and their time counts as solve time.

use super::hooks::Progress;
use super::options::{RenderError, RenderOptions};
use super::shoot::{shoot_until, AfterShot};
use super::source::GpuFormFactors;
use super::trace::{gather_whole, Extra};
use crate::gpu::Gpu;
use crate::lights::KeptField;
use crate::mesh::Mesh;
use crate::parallel::Collectives;
use crate::refine::{self, PatchStats};
use crate::report::Refinement;
use crate::scene::Scene;
use crate::solver::Solver;
use std::time::Instant;

/// Shading errors are summed over ranks in fixed point up to this.
const SHADING_CAP: f64 = 16.0;

/// The mesh a render solves: refinement by need (`crate::refine`), i.e.
/// coarse solves, each followed by a decision that doubles some polygons'
/// patch grids, until nothing asks for more or [`RenderOptions::mesh_settings`]' `refine`
/// passes have run. Returns the mesh, what the passes did and the
/// per-polygon patch-grid factors. Every rank calls this with the same arguments.
pub fn refined_mesh(
    gpu: &Gpu,
    scene: &Scene,
    opts: &RenderOptions,
    comm: &dyn Collectives,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Mesh, Refinement, Vec<u32>), RenderError> {
    let settings = opts.mesh_settings();
    let n = scene.polygons.len();
    let mut factors = vec![1u32; n];
    let mut summary = Refinement::default();
    let levels = settings.refine;
    let mut shooters = vec![false; n];
    let mut receivers = vec![false; n];
    let mut shading = vec![false; n];
    // The last pass's mesh, when it asked for nothing more (the final
    // mesh would be built the same: building it again costs its light field).
    let mut last = None;
    // The last pass's light field: the next mesh casts rays only for the
    // polygons refined since.
    let mut kept = None;
    for pass in 0..levels {
        let mut mesh = Mesh::build_refined_from(scene, &settings, &factors, kept.as_ref());
        if pass == 0 {
            summary.start = [mesh.patches.len(), mesh.elements.len()];
        }
        crate::report::log_memory("a pass's mesh");
        let (decided, shots, seconds) = one_pass(gpu, scene, &mesh, opts, comm, progress)?;
        crate::report::log_memory("a pass's solve");
        summary.passes += 1;
        summary.shots += shots;
        summary.seconds += seconds;
        let mut changed = 0;
        for (i, d) in decided.iter().enumerate() {
            if d.refine() {
                factors[i] *= 2;
                changed += 1;
            }
            shading[i] |= d.shading;
            summary.shading_refinements += d.shading as u32;
            shooters[i] |= d.shooter;
            receivers[i] |= d.receiver;
            summary.shooter_refinements += d.shooter as u32;
            summary.receiver_refinements += d.receiver as u32;
        }
        if comm.rank() == 0 {
            let (s, r, sh) = (
                decided.iter().filter(|d| d.shooter).count(),
                decided.iter().filter(|d| d.receiver).count(),
                decided.iter().filter(|d| d.shading).count(),
            );
            log::info!(
                "refinement pass {}: {} patches, {} shots; {changed} polygons refined ({s} for their shooters, {r} for uneven receivers, {sh} for their shading)",
                pass + 1,
                mesh.patches.len(),
                shots,
            );
        }
        if changed == 0 {
            last = Some(mesh);
            break;
        }
        kept = Some(KeptField::take(&mut mesh));
    }
    summary.shooter_polygons = shooters.iter().filter(|&&x| x).count() as u32;
    summary.receiver_polygons = receivers.iter().filter(|&&x| x).count() as u32;
    summary.shading_polygons = shading.iter().filter(|&&x| x).count() as u32;
    let mesh =
        last.unwrap_or_else(|| Mesh::build_refined_from(scene, &settings, &factors, kept.as_ref()));
    summary.end = [mesh.patches.len(), mesh.elements.len()];
    Ok((mesh, summary, factors))
}

/// One coarse solve of `mesh`: which polygons' patch grids to double (and
/// why), the shots it took and its solve seconds (set-up left out).
fn one_pass(
    gpu: &Gpu,
    scene: &Scene,
    mesh: &Mesh,
    opts: &RenderOptions,
    comm: &dyn Collectives,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Vec<refine::Decision>, u64, f64), RenderError> {
    let mut source = GpuFormFactors::new(gpu, mesh, opts, comm, scene.extent())?;
    // Coarse, unsplit hemispheres measure what the pass decides by as
    // well, in 2-6x less pass time (README "Refinement by need"); the
    // emitters draw fine, as a coarse light over-refined the 64 cubes
    // (8100 -> 12 900 elements).
    source.measuring();
    let started = Instant::now();
    // No overshooting here: the passes only measure the shooters, and
    // the mesh they choose is then the same with or without it.
    let mut solver = Solver::partitioned(mesh, comm.rank(), comm.size());
    // Shots after the last one strong enough to be refined change nothing.
    let floor = refine::SHOOTER_TOL * solver.emitted_power();
    let stats = shoot_until(
        mesh,
        &opts.stop,
        floor,
        comm,
        &mut source,
        &mut solver,
        &mut AfterShot(|s: &Solver, u: f64| {
            if comm.rank() == 0 {
                progress(&Progress {
                    shots: s.shots(),
                    unshot_fraction: u,
                    elapsed: started.elapsed(),
                });
            }
        }),
    )?;
    // Every rank saw its own receivers' penumbrae and holds its own
    // patches' light: sum them (exactly: fixed point, the rest are 0).
    let emitted = solver.emitted_power();
    let one = crate::formfactor::SHARE_ONE;
    let mut sums: Vec<u64> = source.penumbra.iter().flatten().copied().collect();
    sums.extend(solver.patch_unevenness().iter().map(|&w| {
        let share = if emitted > 0.0 { w / emitted } else { 0.0 };
        crate::numeric::round_u64(share.clamp(0.0, 1.0) * one)
    }));
    let settings = opts.mesh_settings();
    // The shading error needs neighbours' values across patches (and
    // ranks): rank 0 judges the whole solution; the others add zeros.
    let mut shading = vec![0u64; mesh.patches.len()];
    if settings.shading_tol > 0.0 {
        let whole = gather_whole(
            comm,
            &solver,
            Extra {
                direct: true,
                ..Extra::default()
            },
        );
        // (A pass's solver always knows its direct part.)
        if let Some((whole, direct)) = whole.as_ref().and_then(|w| Some((w, w.direct()?))) {
            let radiosity = whole.display_radiosity(crate::settings::AmbientTerm::Off);
            let errors = refine::shading_error(mesh, &radiosity, direct, &whole.unlit(), emitted);
            for (s, e) in shading.iter_mut().zip(errors) {
                *s = crate::numeric::round_u64(e.clamp(0.0, SHADING_CAP) * one);
            }
        }
    }
    sums.extend(shading);
    comm.reduce_broadcast_sum(&mut sums);
    let n = mesh.patches.len();
    let (penumbra, rest) = sums.split_at(2 * n);
    let (uneven, shading) = rest.split_at(n);
    let patches: Vec<PatchStats> = stats
        .patch_power
        .iter()
        .zip(penumbra.chunks_exact(2))
        .zip(uneven.iter().zip(shading))
        .map(|((&power, p), (&u, &s))| PatchStats {
            power,
            penumbra: [p[0], p[1]],
            uneven: u as f64 / one * emitted,
            shading: s as f64 / one,
        })
        .collect();
    let decided = refine::decide(
        mesh,
        &patches,
        emitted,
        settings.receiver_tol,
        settings.shading_tol,
    );
    Ok((decided, solver.shots(), started.elapsed().as_secs_f64()))
}
