//! The CPU side of drawing a hemisphere, apart from any device: every
//! polygon's rasterisation proxies and the conservative cell rectangles a
//! shot draws ([`proxies`]: bounds, the walks over the polygons, the ranks'
//! deal of the bounds, the occlusion cull over them), and the exact
//! projection drawn on the CPU ([`software`]: the shader's per-cell test,
//! eight cells side by side). `gpu::HemisphereRasterizer` hands the same
//! rectangles either to the device or to [`software`]. No wgpu here.

pub mod proxies;
pub mod software;

pub use proxies::{Agree, ProxyShapes, Scatter};
