//! The test suite, one binary so every test shares one wgpu device (lavapipe
//! in CI). A missing adapter fails the tests with the package to install.

mod analytic;
mod bad_input;
mod bake;
mod big_scenes;
mod checkpoint;
mod common;
mod determinism;
mod double_sided;
mod emissive;
mod energy;
mod furnace;
mod image;
mod layout;
mod lights;
mod masks;
mod mpi;
mod projections;
mod quiet;
mod rasterisers;
mod real_files;
mod reference;
mod refine;
mod shaders;
mod sky_maps;
mod sun_sky;
mod textures;
mod traps;
