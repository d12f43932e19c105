//! # cleave
//!
//! Elastic solids simulated with finite elements on arbitrary polyhedral
//! elements, so that cutting, fracture and adaptive refinement never need
//! tetrahedral remeshing.
//!
//! The library is the product; the `cleave` program is a thin layer over it.
//! Data flows as follows (see `DESIGN.md`):
//!
//! 1. [`mesh::PolyMesh`]: nodes, global faces with one triangulation each,
//!    elements as closed polyhedra; read by [`io`] or made by [`meshing`].
//! 2. [`store::ElementStore`]: elements batched by vertex count, with their
//!    stiffness matrices and lumped masses.
//! 3. [`assembly::SparsePattern`]: the global sparse structure, built once
//!    per topology, and deterministic parallel assembly.
//! 4. [`solve`]: sparse Cholesky (and iterative solvers).
//! 5. [`sim::Simulation`]: state, constraints and the solve of a step.
//! 6. [`scene`]: TOML scene files that drive all of the above, and
//!    [`output`] for frames and reports.
//!
//! Units are SI throughout: metres, pascals, kilograms, seconds.

// `!(x > 0.0)` is how this crate rejects NaN together with out-of-range
// values; `partial_cmp` would hide that intent.
#![warn(missing_docs)]
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Index loops mirror the formulas (rows, columns, components).
#![allow(clippy::needless_range_loop)]

pub mod assembly;
pub mod dg;
pub mod io;
pub mod material;
pub mod mesh;
pub mod meshing;
pub mod output;
pub mod param;
pub mod render;
pub mod scene;
pub mod sim;
pub mod solve;
pub mod store;
pub mod surface;
pub mod topology;

use thiserror::Error;

/// Any failure of cleave, by layer. Every variant names the place.
#[derive(Debug, Error)]
pub enum Error {
    /// A mesh is structurally or geometrically invalid.
    #[error("invalid mesh: {0}")]
    Mesh(#[from] mesh::MeshError),
    /// A file could not be read or written.
    #[error(transparent)]
    Io(#[from] io::IoError),
    /// A parameter is out of its allowed range.
    #[error("invalid parameter {0}")]
    Parameter(#[from] param::ParamError),
    /// A basis could not be built on an element.
    #[error(transparent)]
    Basis(#[from] store::BasisError),
    /// A plane split failed.
    #[error(transparent)]
    Split(#[from] topology::SplitError),
    /// A surface does not bound a solid.
    #[error("invalid surface: {0}")]
    Surface(#[from] surface::SurfaceError),
    /// A linear solve failed.
    #[error("solve failed: {0}")]
    Solve(#[from] solve::SolveError),
    /// A time step failed.
    #[error("step {step}: {source}")]
    Step {
        /// The step that failed (0 for the first).
        step: usize,
        /// Why its solve failed.
        source: solve::SolveError,
    },
    /// An invariant of cleave itself does not hold: a bug, to be reported.
    #[error("internal error (please report): {0}")]
    Internal(String),
}
