//! A parallel progressive radiosity renderer whose form factors come from an
//! equal-angle hemisphere rasterised with wgpu (Uejima & Yamazaki 1999).
//!
//! Layers, bottom up (see ARCHITECTURE.md):
//! - [`hemisphere`]: cells, delta form factors, tiles (pure maths);
//! - [`formfactor`]: analytic point-to-polygon form factors (pure maths);
//! - [`numeric`]: atan2 and rounding without libm calls (pure maths);
//! - [`scene`], [`mesh`]: glTF in, polygons -> patches -> elements;
//! - [`settings`]: the enums a render is told and the report records;
//! - [`raytrace`], [`direct`], [`lights`], [`sampling`]: exact visibility
//!   on the CPU, the camera image's direct light, what lights, suns and
//!   skies deliver (pure maths);
//! - [`interpolate`]: per-element values to vertex values for smooth shading;
//! - [`solver`]: progressive refinement, knows nothing of GPUs;
//! - [`refine`]: which polygons a coarse solution says to subdivide (pure maths);
//! - [`gpu`]: wgpu plumbing (device, hemisphere rasteriser, camera view);
//! - [`parallel`]: the collectives a distributed solve needs; [`comm`]: their
//!   MPI implementation (the only module that calls MPI); [`launch`]: starting
//!   the ranks a launcher started;
//! - [`render`]: one render from scene to image and report, on one or many
//!   ranks: options, the row cache, tiers and exchanges (no GPU), the GPU
//!   form-factor source, the shooting loop, trace, passes, driver and the one
//!   write path;
//! - [`compare`]: image error against a reference (SMAPE over blocks);
//! - [`output`], [`report`], [`checkpoint`]: files out (and a solve's state, to resume);
//! - [`bake`]: the solution as glTF with vertex colours.

pub mod ambient;
pub mod bake;
pub mod checkpoint;
pub mod cli;
pub mod comm;
pub mod compare;
pub mod direct;
pub mod export;
pub mod formfactor;
pub mod gpu;
pub mod hemisphere;
pub mod interpolate;
pub mod launch;
pub mod lights;
pub mod lit_mesh;
pub mod mesh;
pub mod numeric;
pub mod occlusion;
pub mod output;
pub mod parallel;
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
