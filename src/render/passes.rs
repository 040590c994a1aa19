//! Refinement by need (`crate::refine`): coarse solves, each followed by a
//! decision that doubles some polygons' patch grids. The passes run the
//! same shooting loop as the final solve, and their time counts as solve time.

use super::hooks::Progress;
use super::options::{RenderError, RenderOptions};
use super::shoot::{shoot_until, AfterShot};
use super::source::GpuFormFactors;
use crate::gpu::Gpu;
use crate::mesh::Mesh;
use crate::parallel::Collectives;
use crate::refine::{self, PatchStats};
use crate::report::Refinement;
use crate::scene::Scene;
use crate::solver::Solver;
use std::time::Instant;

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
    for pass in 0..levels {
        let mesh = Mesh::build_refined(scene, &settings, &factors);
        if pass == 0 {
            summary.start = [mesh.patches.len(), mesh.elements.len()];
        }
        let (decided, shots, seconds) = one_pass(gpu, scene, &mesh, opts, comm, progress)?;
        summary.passes += 1;
        summary.shots += shots;
        summary.seconds += seconds;
        let mut changed = 0;
        for ((f, refined), &d) in factors.iter_mut().zip(&mut shooters).zip(&decided) {
            if d {
                *f *= 2;
                *refined = true;
                changed += 1;
            }
        }
        summary.shooter_refinements += changed;
        if comm.rank() == 0 {
            log::info!(
                "refinement pass {}: {} patches, {} shots; {changed} polygons get finer shooters",
                pass + 1,
                mesh.patches.len(),
                shots,
            );
        }
        if changed == 0 {
            break;
        }
    }
    summary.shooter_polygons = shooters.iter().filter(|&&x| x).count() as u32;
    Ok((
        Mesh::build_refined(scene, &settings, &factors),
        summary,
        factors,
    ))
}

/// One coarse solve of `mesh`: which polygons' patch grids to double, the
/// shots it took and its solve seconds (set-up left out).
fn one_pass(
    gpu: &Gpu,
    scene: &Scene,
    mesh: &Mesh,
    opts: &RenderOptions,
    comm: &dyn Collectives,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Vec<bool>, u64, f64), RenderError> {
    let mut source = GpuFormFactors::new(gpu, mesh, opts, comm, scene.extent())?;
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
    // Every rank saw its own receivers' penumbrae: sum them (exactly).
    let mut penumbra: Vec<u64> = source.penumbra.iter().flatten().copied().collect();
    comm.reduce_broadcast_sum(&mut penumbra);
    let patches: Vec<PatchStats> = stats
        .patch_power
        .iter()
        .zip(penumbra.chunks_exact(2))
        .map(|(&power, p)| PatchStats {
            power,
            penumbra: [p[0], p[1]],
        })
        .collect();
    let decided = refine::decide(mesh, &patches, solver.emitted_power());
    Ok((decided, solver.shots(), started.elapsed().as_secs_f64()))
}
