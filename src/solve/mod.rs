//! Linear solvers for the symmetric positive definite systems of a step.
//!
//! A solver is told the pattern once per topology ([`LinearSolver::analyze`]),
//! the values whenever they change ([`LinearSolver::factor`]), and then solves
//! for any number of right-hand sides.

mod cholesky;

pub use cholesky::{solve_checked, Cholesky};

use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use thiserror::Error;

/// A failed solve.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum SolveError {
    /// The matrix is not (numerically) positive definite.
    #[error("the system matrix is not positive definite (pivot {pivot} of {n}): is the body unconstrained with zero mass, or a parameter NaN?")]
    NotPositiveDefinite { pivot: usize, n: usize },
    /// The symbolic analysis failed.
    #[error("symbolic analysis failed: {0}")]
    Analysis(String),
    /// An iterative solver stopped before reaching its tolerance.
    #[error("the iterative solver did not converge: residual {residual:.3e} after {iterations} iterations (tolerance {tolerance:.1e})")]
    NotConverged { iterations: usize, residual: f64, tolerance: f64 },
    /// The right-hand side or the solution holds NaN or infinity.
    #[error("the system has a non-finite right-hand side or solution")]
    NonFinite,
    /// `factor` or `solve` was called before `analyze`.
    #[error("the solver was used before analyze/factor")]
    NotReady,
}

/// What a solve did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SolveStats {
    /// Iterations (1 for a direct solve).
    pub iterations: usize,
    /// Relative residual `|b - A x| / |b|` reached.
    pub residual: f64,
}

/// A solver of `A x = b` for symmetric positive definite `A`.
pub trait LinearSolver: Send {
    /// Prepares for matrices with the structure `pattern` (both triangles).
    fn analyze(&mut self, pattern: SymbolicSparseColMatRef<'_, usize>) -> Result<(), SolveError>;
    /// Takes the current values of the matrix.
    fn factor(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError>;
    /// Solves `A x = b`; `x` holds a starting guess on entry (used by
    /// iterative solvers) and the solution on exit.
    fn solve(&mut self, b: &[f64], x: &mut [f64]) -> Result<SolveStats, SolveError>;
}

/// Relative residual `|b - A x| / |b|` (0 when `b` is zero and `A x` too).
pub fn relative_residual(a: SparseColMatRef<'_, usize, f64>, b: &[f64], x: &[f64]) -> f64 {
    let mut r = b.to_vec();
    let (sym, val) = a.parts();
    let (cp, ri) = (sym.col_ptr(), sym.row_idx());
    for j in 0..x.len() {
        for p in cp[j]..cp[j + 1] {
            r[ri[p]] -= val[p] * x[j];
        }
    }
    let nb = b.iter().map(|v| v * v).sum::<f64>().sqrt();
    let nr = r.iter().map(|v| v * v).sum::<f64>().sqrt();
    if nb > 0.0 {
        nr / nb
    } else {
        nr
    }
}
