//! What a render checks of its settings before it starts: that every rank
//! draws hemispheres the same way, and what rank 0 should warn of.

use super::options::{RenderError, RenderOptions};
use crate::gpu::Gpu;
use crate::parallel::Collectives;
use crate::settings::Rasteriser;

/// Before a run starts: every rank must draw the same way (a collective),
/// and rank 0 says what the settings should be told of.
pub(super) fn check_settings(
    gpu: &Gpu,
    opts: &RenderOptions,
    comm: &dyn Collectives,
) -> Result<(), RenderError> {
    let mine = opts.rasteriser_for(gpu.is_cpu());
    if comm.size() > 1 {
        let code = u32::from(mine == Rasteriser::Device);
        let lengths = vec![1; comm.size()];
        let all: Vec<u32> = comm.all_gather_u32(&[code], Some(&lengths)).concat();
        one_rasteriser(&all).map_err(|e| {
            RenderError::Settings(format!("{e} (this rank's adapter: {})", gpu.describe()))
        })?;
    }
    warn_of_settings(gpu, opts, comm);
    Ok(())
}

/// Whether every rank draws the same way, by each rank's code (1: the
/// device, 0: the CPU): a driver may fuse a multiply-add the CPU drawing
/// does not, so ranks drawing differently could break "the same bits on
/// any rank count" (`--rasteriser auto` resolves on each rank's adapter).
fn one_rasteriser(codes: &[u32]) -> Result<(), String> {
    if codes.iter().all(|&c| c == codes[0]) {
        return Ok(());
    }
    let on = |what: u32| {
        let ranks: Vec<String> = (0..codes.len())
            .filter(|&r| codes[r] == what)
            .map(|r| r.to_string())
            .collect();
        ranks.join(", ")
    };
    Err(format!(
        "the ranks would draw hemispheres differently: ranks {} on the device, ranks {} on the CPU (their adapters differ: give --rasteriser device or cpu)",
        on(1),
        on(0)
    ))
}

/// What a run's settings should be told of before it starts (rank 0).
fn warn_of_settings(gpu: &Gpu, opts: &RenderOptions, comm: &dyn Collectives) {
    if comm.rank() != 0 {
        return;
    }
    if let Some(w) = device_on_a_cpu(gpu, opts) {
        log::warn!("{w}");
    }
    if opts.batch > 1 && comm.size() > opts.batch {
        // Not an error: the split shots' groups, the transport's rays and
        // the landing still go to every rank (docs/scaling.md).
        log::warn!(
            "--batch {} on {} ranks: a batch's rows keep at most {} ranks drawing; a batch of at least the rank count uses them all (the numbers depend on --batch, not on the ranks)",
            opts.batch,
            comm.size(),
            opts.batch
        );
    }
}

/// The warning for a run that asked for the device's drawing
/// (`--rasteriser device`) on an adapter that is itself a CPU rasteriser:
/// its "device" figures are a CPU's (wgpu falls back to lavapipe where no
/// Vulkan driver for the GPU is installed).
pub(super) fn device_on_a_cpu(gpu: &Gpu, opts: &RenderOptions) -> Option<String> {
    (opts.rasteriser == crate::settings::Rasteriser::Device && gpu.is_cpu()).then(|| {
        format!(
            "--rasteriser device asked for a GPU, but the adapter is a CPU rasteriser: {} (no Vulkan driver for a GPU?): its device drawing runs on the CPU",
            gpu.describe()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::one_rasteriser;

    #[test]
    fn ranks_that_would_draw_differently_are_an_error_naming_them() {
        assert!(one_rasteriser(&[1, 1, 1]).is_ok());
        assert!(one_rasteriser(&[0]).is_ok());
        let e = one_rasteriser(&[1, 0, 1, 0]).expect_err("they differ");
        assert!(
            e.contains("ranks 0, 2 on the device") && e.contains("ranks 1, 3 on the CPU"),
            "{e}"
        );
    }
}
