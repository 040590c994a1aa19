//! A parallel progressive radiosity renderer whose form factors come from an
//! equal-angle hemisphere rasterised with wgpu (Uejima & Yamazaki 1999).
//!
//! Layers, bottom up (see ARCHITECTURE.md):
//! - [`settings`], [`shot`], [`rng`], [`numeric`]: plain data, the
//!   solver's interface to a form-factor source, the seeded generator,
//!   atan2 and rounding without libm calls;
//! - [`hemisphere`], [`formfactor`], [`occlusion`]: cells and delta form
//!   factors, Lambert's contour integral, the occlusion map (pure maths);
//! - [`scene`], [`mesh`], [`lit_mesh`]: glTF in, polygons -> patches ->
//!   elements, and the lighting state beside the geometry;
//! - [`raytrace`], [`sampling`], [`lights`], [`direct`], [`ambient`]: exact
//!   visibility on the CPU and what it estimates;
//! - [`solver`], [`refine`], [`interpolate`]: progressive refinement,
//!   refinement by need, smooth shading's vertex values;
//! - [`raster`]: the CPU side of drawing a hemisphere (no wgpu); [`gpu`]:
//!   wgpu plumbing (device, hemisphere rasteriser, camera view);
//! - [`parallel`]: the collectives a distributed solve needs; [`comm`]: their
//!   MPI implementation (the only module that calls MPI); [`launch`]: the
//!   ranks a launcher started;
//! - [`render`]: one render from scene to image and report, on one or many ranks;
//! - [`report`], [`output`], [`checkpoint`], [`bake`], [`export`],
//!   [`compare`]: what goes out;
//! - [`cli`]: the render flags, shared by the binaries.

pub mod ambient;
pub mod bake;
pub mod checkpoint;
pub mod cli;
pub mod comm;
pub mod compare;
pub mod direct;
pub mod export;
pub mod formfactor;
pub mod gather;
pub mod gpu;
pub mod hemisphere;
pub mod interpolate;
pub mod launch;
pub mod lights;
pub mod lit_mesh;
pub mod locate;
pub mod mesh;
pub mod numeric;
pub mod occlusion;
pub mod output;
pub mod parallel;
pub mod raster;
pub mod raytrace;
pub mod refine;
pub mod render;
pub mod report;
pub mod rng;
pub mod sampling;
pub mod scene;
pub mod settings;
pub mod shot;
pub mod solver;
