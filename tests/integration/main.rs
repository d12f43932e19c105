//! The integration tests, as one test binary: every file here is a module
//! of it, so that they link once (each binary links the whole engine) and
//! the test threads share all of them out, instead of one binary at a time
//! leaving a core idle behind its longest test. Run one file's tests with
//! `cargo test --release --test integration cutting::`.
//!
//! The counting allocators of `tests/allocations.rs`, `tests/fuzz.rs` and
//! `tests/soak.rs` are global to their binaries, which stay apart (the
//! soak's heap comparison counts every thread's allocations: beside other
//! tests it counted theirs too).

mod common;

mod api;
mod bodies;
mod checkpoint;
mod convergence;
mod cut_health;
mod cutting;
mod dg;
mod dg_convergence;
mod dg_integration;
mod dynamics;
mod embedding;
mod guards;
mod harmonic_basis;
mod harmonic_elements;
mod incremental;
mod io_formats;
mod mean_value_basis;
mod mean_value_elements;
mod mesh_validation;
mod meshing;
mod patch_test;
mod refine;
mod render;
mod scenes;
mod slivers;
mod spectra;
mod split;
mod vtu_meshio;
