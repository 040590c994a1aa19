//! A parallel progressive radiosity renderer whose form factors come from an
//! equal-angle hemisphere rasterised with wgpu (Uejima & Yamazaki 1999).
//!
//! Layers, bottom up (see ARCHITECTURE.md):
//! - [`hemisphere`]: cells, delta form factors, tiles (pure maths);
//! - [`scene`], [`mesh`]: glTF in, polygons -> patches -> elements;
//! - [`solver`]: progressive refinement, knows nothing of GPUs;
//! - [`gpu`]: wgpu plumbing (device, hemisphere rasteriser, camera view);
//! - [`render`]: one render from scene to image and report;
//! - [`output`], [`report`]: files out.

pub mod gpu;
pub mod hemisphere;
pub mod mesh;
pub mod output;
pub mod render;
pub mod report;
pub mod scene;
pub mod solver;
