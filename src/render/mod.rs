//! One render from start to finish: scene -> mesh -> form factors on the GPU
//! -> progressive refinement -> image and report, on one or many ranks. Used
//! by the `radiosity` binary, the tests and the viewer; it joins the modules
//! but adds no maths of its own.
//!
//! The parts, bottom up (nothing here imports upward):
//! - [`options`]: what a render can be told, its defaults, the fingerprint;
//! - [`cache`], [`tiers`], [`exchange`]: the row cache, the resolution
//!   tiers and the three form-factor exchanges (no GPU; unit-tested);
//! - [`source`]: the GPU form-factor source that joins them per shot;
//! - [`shoot`]: the shooting loop and the one collective before each shot;
//! - [`ahead`]: rows of the likely next shooters drawn beside the shot;
//! - [`trace`], [`hooks`]: the convergence trace, progress and checkpoints;
//! - [`passes`]: refinement by need (coarse solves that choose the mesh);
//! - [`image`]: the camera image (interpolated solution, traced direct light);
//! - [`driver`]: the render itself, the gather to rank 0 and the report.

pub mod ahead;
pub mod cache;
mod checks;
pub mod driver;
pub mod exchange;
pub mod hooks;
pub mod image;
pub mod options;
pub mod passes;
pub mod shoot;
pub mod source;
pub mod tiers;
pub mod trace;
pub mod write;

pub use driver::{
    build_report, render, render_on, render_ranks, single_process, Rendered, RunRecord,
};
pub use hooks::Progress;
pub use options::{
    CheckpointPlan, DealBounds, FormFactorMethod, Projection, Rasteriser, RenderError,
    RenderOptions, AUTO_TRANSPORT_BELOW, DEFAULT_COARSE_BELOW, DEFAULT_RASTER_PIECES,
    DEFAULT_TESSELLATION_TOLERANCE,
};
pub use passes::{refined_mesh, refined_mesh_shown};
pub use shoot::{
    shoot_until, AfterShot, Flags, LoopHooks, LoopStats, ShotLoop, Step, Stopped, Until,
};
pub use source::{GpuFormFactors, PhaseTimes};
pub use trace::{gather_whole, Extra, Trace};
