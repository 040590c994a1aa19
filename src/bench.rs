//! `radiosity bench`: shot timings on built-in scenes.

use anyhow::Result;
use clap::Args;

/// Options of `radiosity bench`.
#[derive(Args)]
pub struct BenchArgs {
    /// Shots to time per scene.
    #[arg(long, default_value_t = 200)]
    shots: u64,
}

/// Runs the benchmark.
pub fn run(_args: BenchArgs) -> Result<()> {
    anyhow::bail!("not yet")
}
