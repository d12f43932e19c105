//! Sparse Cholesky with a lagged factor: the factor of an earlier step's
//! matrix `A₀` preconditions conjugate gradients on the current `A`, and
//! the matrix is factored again only when that stops paying.
//!
//! From one step to the next the corotated system changes little (the
//! rotations turn by a few degrees), so the spectrum of `A₀⁻¹ A` clusters
//! about 1 and a few iterations reach a direct solve's accuracy: one a step
//! while `bunny_slices` falls (residual 1e-13), 3-9 a step on bunny_100k
//! swinging from a clamped base. An iteration costs one pair of triangular
//! solves with the factor plus a product with `A`; a factorisation of a 3-D
//! mesh's system costs some 30-50 such pairs (bunny_100k: 850 ms against
//! 17-27 ms, 2 cores). Penalty contacts that come and go change `A` by
//! stiff terms of high rank, which the old factor does not see: on a body
//! resting or bouncing on a collider lagged solves mostly fail, and the
//! solver backs off to factoring every step. The factor is renewed
//!
//! - at the first solve of a pattern (after [`LinearSolver::analyze`]),
//! - when the last lagged solve needed more than [`REFACTOR_AFTER`]
//!   iterations (the matrix has drifted: the next solve would too),
//! - when a lagged solve does not converge within [`MAX_LAGGED_ITERATIONS`]
//!   (it then solves directly with the new factor); the next 1, 2, 4, ...
//!   (at most [`MAX_BACKOFF`]) factorisations after consecutive failures
//!   then do not try the old factor.
//!
//! The iteration stops when the preconditioned residual `rᵀ A₀⁻¹ r`, which
//! estimates the squared energy norm of the error `‖x - x*‖²_A`, falls to
//! [`ENERGY_TOLERANCE`]² of `xᵀ b` (the squared energy norm of the solution,
//! `x*ᵀ A x* = x*ᵀ b`): a relative error of 1e-10 in the norm that the step's
//! energy is measured in, where a direct solve reaches about 1e-13.
//!
//! Every decision depends on iteration counts only, never on timings, and
//! every reduction is summed in a fixed order: the same bits on any number
//! of threads.

use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use rayon::prelude::*;

use super::{dot, relative_residual, symmetric_matvec, Cholesky, LinearSolver, SolveError, SolveStats};

/// Most iterations of a solve on a lagged factor before it gives up,
/// factors the current matrix and solves directly (at bunny_100k's ratio
/// of factorisation to iteration, about a third of a factorisation's cost).
pub const MAX_LAGGED_ITERATIONS: usize = 12;

/// Iterations of a lagged solve beyond which the next step factors afresh
/// instead of trying the old factor again.
pub const REFACTOR_AFTER: usize = 8;

/// Most factorisations in a row that do not try the lagged factor, after
/// lagged solves that failed one after another (see the module docs).
pub const MAX_BACKOFF: usize = 32;

/// Relative energy-norm error at which a lagged solve stops (see the
/// module docs).
pub const ENERGY_TOLERANCE: f64 = 1e-10;

/// Direct sparse Cholesky whose factor is reused across steps as the
/// preconditioner of conjugate gradients (see the module docs).
#[derive(Default)]
pub struct LaggedCholesky {
    cholesky: Cholesky,
    /// The factor is of an earlier matrix than the one given last.
    stale: bool,
    /// Iterations of the last solve on a stale factor; 0 after a direct one.
    last_lagged: usize,
    /// Coming factorisations that skip the lagged factor, after a failed
    /// lagged solve, and the number of them the last failure set.
    skip: usize,
    backoff: usize,
    /// CG's residual, preconditioned residual, direction and `A p`.
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
}

impl LaggedCholesky {
    /// Factors `matrix` now.
    fn refactor(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError> {
        self.stale = false;
        self.last_lagged = 0;
        self.cholesky.factor(matrix)
    }

    /// Books a lagged solve that did not converge: the next `backoff`
    /// factorisations go straight to a new factor, twice as many as after
    /// the last failure when no lagged solve has converged since (up to
    /// [`MAX_BACKOFF`]).
    fn failed(&mut self) {
        self.backoff = (2 * self.backoff).clamp(1, MAX_BACKOFF);
        self.skip = self.backoff;
    }

    /// Conjugate gradients on `A x = b` from the guess in `x`, preconditioned
    /// by the (stale) factor: `Some(iterations)` once the energy-norm error
    /// estimate meets [`ENERGY_TOLERANCE`], `None` when it does not within
    /// [`MAX_LAGGED_ITERATIONS`] or meets a direction of non-positive
    /// curvature (a refactorisation then decides).
    fn iterate(
        &mut self,
        matrix: SparseColMatRef<'_, usize, f64>,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<Option<usize>, SolveError> {
        let n = b.len();
        for v in [&mut self.r, &mut self.z, &mut self.p, &mut self.q] {
            v.resize(n, 0.0);
        }
        let (r, z, p, q) = (&mut self.r, &mut self.z, &mut self.p, &mut self.q);
        symmetric_matvec(matrix, x, q);
        r.par_iter_mut().zip(b.par_iter().zip(q.par_iter())).for_each(|(r, (b, q))| *r = b - q);
        z.copy_from_slice(r);
        self.cholesky.solve_in_place(z)?;
        p.copy_from_slice(z);
        let mut rz = dot(r, z);
        let converged = |rz: f64, x: &[f64]| rz <= ENERGY_TOLERANCE * ENERGY_TOLERANCE * dot(x, b) || rz == 0.0;
        if converged(rz, x) {
            return Ok(Some(0));
        }
        for iteration in 1..=MAX_LAGGED_ITERATIONS {
            symmetric_matvec(matrix, p, q);
            let curvature = dot(p, q);
            if !(curvature > 0.0) || !rz.is_finite() {
                return Ok(None);
            }
            let alpha = rz / curvature;
            x.par_iter_mut().zip(p.par_iter()).for_each(|(x, p)| *x += alpha * p);
            r.par_iter_mut().zip(q.par_iter()).for_each(|(r, q)| *r -= alpha * q);
            z.copy_from_slice(r);
            self.cholesky.solve_in_place(z)?;
            let rz_next = dot(r, z);
            if converged(rz_next, x) {
                return Ok(Some(iteration));
            }
            let beta = rz_next / rz;
            p.par_iter_mut().zip(z.par_iter()).for_each(|(p, z)| *p = z + beta * *p);
            rz = rz_next;
        }
        Ok(None)
    }
}

impl LinearSolver for LaggedCholesky {
    fn analyze(&mut self, pattern: SymbolicSparseColMatRef<'_, usize>) -> Result<(), SolveError> {
        self.stale = false;
        self.last_lagged = 0;
        self.cholesky.analyze(pattern)
    }

    fn factor(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError> {
        if self.skip > 0 {
            self.skip -= 1;
            return self.refactor(matrix);
        }
        if !self.cholesky.is_factored() || self.last_lagged > REFACTOR_AFTER {
            return self.refactor(matrix);
        }
        if matrix.parts().1.iter().any(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite);
        }
        self.stale = true;
        Ok(())
    }

    fn solve(
        &mut self,
        matrix: SparseColMatRef<'_, usize, f64>,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, SolveError> {
        if !self.stale {
            return self.cholesky.solve(matrix, b, x);
        }
        if b.iter().chain(x.iter()).any(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite);
        }
        match self.iterate(matrix, b, x)? {
            Some(iterations) => {
                self.last_lagged = iterations;
                self.backoff = 0;
                let residual = relative_residual(matrix, b, x, &mut self.q);
                Ok(SolveStats { iterations, residual })
            }
            None => {
                self.failed();
                self.refactor(matrix)?;
                let stats = self.cholesky.solve(matrix, b, x)?;
                Ok(SolveStats { iterations: MAX_LAGGED_ITERATIONS + 1, ..stats })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::cholesky::tests::box_system;

    /// `A x = b` solved by a fresh factor of `values`.
    fn direct(pattern: &crate::assembly::SparsePattern, values: &[f64], b: &[f64]) -> Vec<f64> {
        let mut chol = Cholesky::default();
        chol.analyze(pattern.symbolic()).unwrap();
        chol.factor(pattern.matrix(values)).unwrap();
        let mut x = vec![0.0; b.len()];
        chol.solve(pattern.matrix(values), b, &mut x).unwrap();
        x
    }

    /// `‖x - y‖_A / ‖y‖_A`.
    fn energy_error(pattern: &crate::assembly::SparsePattern, values: &[f64], x: &[f64], y: &[f64]) -> f64 {
        let e: Vec<f64> = x.iter().zip(y).map(|(x, y)| x - y).collect();
        let mut ae = vec![0.0; e.len()];
        let mut ay = vec![0.0; e.len()];
        symmetric_matvec(pattern.matrix(values), &e, &mut ae);
        symmetric_matvec(pattern.matrix(values), y, &mut ay);
        (dot(&e, &ae) / dot(y, &ay)).sqrt()
    }

    /// The box's stiffness `K + 10³ I` and the same stiffness 3 % stiffer
    /// in one direction (a drift like a step's change of rotations).
    fn drifted(cells: usize) -> (crate::assembly::SparsePattern, Vec<f64>, Vec<f64>, Vec<f64>) {
        let (pattern, values, b) = box_system(cells);
        let mut next = values.clone();
        let (sym, _) = pattern.matrix(&values).parts();
        for j in 0..sym.ncols() {
            for p in sym.col_ptr()[j]..sym.col_ptr()[j + 1] {
                if j % 3 == 0 && sym.row_idx()[p] % 3 == 0 {
                    next[p] *= 1.03;
                }
            }
        }
        (pattern, values, next, b)
    }

    /// The first solve of a pattern is direct; the next, on a matrix that
    /// drifted from the factored one, iterates on the old factor to the
    /// energy tolerance, without a new factorisation, and lands within it
    /// of the direct solution.
    #[test]
    fn a_drifted_matrix_is_solved_on_the_old_factor() {
        let (pattern, first, next, b) = drifted(8);
        let mut solver = LaggedCholesky::default();
        solver.analyze(pattern.symbolic()).unwrap();
        let mut x = vec![0.0; b.len()];
        solver.factor(pattern.matrix(&first)).unwrap();
        let stats = solver.solve(pattern.matrix(&first), &b, &mut x).unwrap();
        assert_eq!(stats.iterations, 1, "the first solve is direct");
        assert!(stats.residual < 1e-12, "{stats:?}");
        solver.factor(pattern.matrix(&next)).unwrap();
        let stats = solver.solve(pattern.matrix(&next), &b, &mut x).unwrap();
        assert!(solver.stale, "the factor was renewed");
        assert!((1..=REFACTOR_AFTER).contains(&stats.iterations), "{stats:?}");
        let error = energy_error(&pattern, &next, &x, &direct(&pattern, &next, &b));
        assert!(error <= ENERGY_TOLERANCE, "energy-norm error {error:e}");
        assert!(stats.residual < 1e-8, "{stats:?}");
    }

    /// A matrix far from the factored one (stiff penalties on a third of
    /// the unknowns, like contacts that came) makes the lagged solve give
    /// up, factor the matrix and solve directly; the next factorisation
    /// then skips the lag (it backs off) and solves directly.
    #[test]
    fn a_matrix_far_from_the_factor_is_factored_again() {
        let (pattern, first, _, b) = drifted(8);
        let penalised = |scale: f64| {
            let mut values = first.clone();
            (0..b.len()).step_by(3).for_each(|d| values[pattern.diagonal_slot(d)] += scale);
            values
        };
        let mut solver = LaggedCholesky::default();
        solver.analyze(pattern.symbolic()).unwrap();
        let mut x = vec![0.0; b.len()];
        solver.factor(pattern.matrix(&first)).unwrap();
        solver.solve(pattern.matrix(&first), &b, &mut x).unwrap();
        for (scale, iterations) in [(1e9, MAX_LAGGED_ITERATIONS + 1), (2e9, 1)] {
            let values = penalised(scale);
            solver.factor(pattern.matrix(&values)).unwrap();
            let stats = solver.solve(pattern.matrix(&values), &b, &mut x).unwrap();
            assert_eq!(stats.iterations, iterations, "penalty {scale:e}");
            assert!(stats.residual < 1e-12, "penalty {scale:e}: {stats:?}");
        }
    }

    /// Direct and lagged solves give the same bits on pools of 1, 2 and 4
    /// threads.
    #[test]
    fn lagged_solves_have_the_same_bits_on_any_pool() {
        let (pattern, first, next, b) = drifted(10);
        let solve = || {
            let mut solver = LaggedCholesky::default();
            solver.analyze(pattern.symbolic()).unwrap();
            let mut x = vec![0.0; b.len()];
            let mut bits = Vec::new();
            for values in [&first, &next] {
                solver.factor(pattern.matrix(values)).unwrap();
                solver.solve(pattern.matrix(values), &b, &mut x).unwrap();
                bits.extend(x.iter().map(|v| v.to_bits()));
            }
            bits
        };
        let runs: Vec<Vec<u64>> = [1, 2, 4]
            .iter()
            .map(|&threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(solve))
            .collect();
        assert!(runs.iter().all(|r| *r == runs[0]), "the bits depend on the threads");
    }
}
