//! Linear solvers for the symmetric positive definite systems of a step.
//!
//! A solver is told the pattern once per topology ([`LinearSolver::analyze`]),
//! the values whenever they change ([`LinearSolver::factor`]), and then solves
//! for any number of right-hand sides.

mod aggregate_cycle;
mod cg;
mod cholesky;
mod coarse;
mod envelope;
mod history;
mod lagged;
mod ordering;
mod tree_solve;

pub use cg::{dot, symmetric_matvec, BlockStructure, ConjugateGradient};
pub use cholesky::{Cholesky, PARALLEL_CHOLESKY_MIN_UNKNOWNS};
pub use envelope::EnvelopeCholesky;
pub use lagged::{LaggedCholesky, ENERGY_TOLERANCE, MAX_BACKOFF, MAX_LAGGED_ITERATIONS, REFACTOR_AFTER};
pub(crate) use ordering::{component_roots, reverse_cuthill_mckee};

use std::sync::OnceLock;

use faer::sparse::{SparseColMatRef, SymbolicSparseColMat, SymbolicSparseColMatRef};
use thiserror::Error;

/// Order of the dense factor [`prepare_thread`] computes: past faer's
/// recursion threshold (64), so that its Cholesky factor and triangular
/// inverse go through the packed matrix product.
const PREPARED_ORDER: usize = 128;

/// Makes this thread's buffers of the dense kernels, which are otherwise
/// made by the thread's first dense factor large enough to go through a
/// packed matrix product (faer's product keeps its packing room per
/// thread, for the thread's lifetime). The coarse level of the conjugate
/// gradients factors its blocks in parallel, on whichever thread picks
/// each up, so that a thread's first such block can fall at any later
/// refresh: a host that needs every step after a topology's first to
/// allocate nothing (a real-time loop) calls this once on every thread
/// that may step, e.g. in its rayon pool's `start_handler`. It factors
/// and inverts one identity matrix of order 128, and
/// changes no result.
pub fn prepare_thread() {
    use faer::linalg::cholesky::llt;
    let n = PREPARED_ORDER;
    let mut a = faer::Mat::<f64>::identity(n, n);
    let mut stack = faer::dyn_stack::MemBuffer::new(llt::factor::cholesky_in_place_scratch::<f64>(
        n,
        faer::Par::Seq,
        Default::default(),
    ));
    llt::factor::cholesky_in_place(
        a.as_mut(),
        Default::default(),
        faer::Par::Seq,
        faer::dyn_stack::MemStack::new(&mut stack),
        Default::default(),
    )
    .expect("the identity is positive definite");
    let mut inverse = faer::Mat::<f64>::zeros(n, n);
    faer::linalg::triangular_inverse::invert_lower_triangular(inverse.as_mut(), a.as_ref(), faer::Par::Seq);
    // (run as a pool's start handler, it would leave every thread of the
    // pool with the registers faer's products leave in use)
    cleave_kernels::lanes::clear_upper_registers();
}

/// A failed solve.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum SolveError {
    /// The matrix is not (numerically) positive definite.
    #[error("the system matrix is not positive definite (pivot {pivot} of {n}): is the body unconstrained with zero mass, or a parameter NaN?")]
    NotPositiveDefinite {
        /// The failing pivot.
        pivot: usize,
        /// The system's size.
        n: usize,
    },
    /// Conjugate gradients met a search direction `p` with `pᵀ A p <= 0`
    /// (or not a number): the matrix is not positive definite.
    #[error("the system matrix is not positive definite: conjugate gradients met a direction of curvature pᵀAp = {curvature:.3e} at iteration {iteration}: is the body unconstrained with zero mass, or a parameter NaN?")]
    NonPositiveCurvature {
        /// The iteration (from 0) whose direction it was.
        iteration: usize,
        /// `pᵀ A p` of that direction.
        curvature: f64,
    },
    /// The symbolic analysis failed.
    #[error("symbolic analysis failed: {0}")]
    Analysis(String),
    /// An iterative solver stopped before reaching its tolerance.
    #[error("the iterative solver did not converge: residual {residual:.3e} after {iterations} iterations (tolerance {tolerance:.1e})")]
    NotConverged {
        /// Iterations run.
        iterations: usize,
        /// The relative residual reached.
        residual: f64,
        /// The tolerance asked for.
        tolerance: f64,
    },
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

/// The structure of a system matrix in 3x3 blocks as a simulation hands
/// it to a solver: its [`BlockStructure`], and the scalar compressed
/// columns made from it on the first request. A solver that works on
/// blocks never asks, so a body solved by conjugate gradients never holds
/// them (on bunny_100k, 18 MB of row indices that every cut had to move).
#[derive(Clone, Copy, Debug)]
pub struct SystemPattern<'a> {
    blocks: &'a BlockStructure,
    scalar: &'a OnceLock<SymbolicSparseColMat<usize>>,
}

impl<'a> SystemPattern<'a> {
    /// The pattern of `blocks`, whose scalar structure is kept in `scalar`
    /// once made (it must be empty or hold that of `blocks`).
    pub fn new(blocks: &'a BlockStructure, scalar: &'a OnceLock<SymbolicSparseColMat<usize>>) -> Self {
        SystemPattern { blocks, scalar }
    }

    /// The 3x3 block structure.
    pub fn blocks(&self) -> &'a BlockStructure {
        self.blocks
    }

    /// The scalar compressed columns (both triangles), made now if they
    /// were not yet.
    pub fn scalar(&self) -> SymbolicSparseColMatRef<'a, usize> {
        self.scalar.get_or_init(|| self.blocks.scalar()).as_ref()
    }
}

/// A solver of `A x = b` for symmetric positive definite `A`.
pub trait LinearSolver: Send + Sync {
    /// Prepares for matrices with the structure `pattern` (both triangles).
    fn analyze(&mut self, pattern: SymbolicSparseColMatRef<'_, usize>) -> Result<(), SolveError>;
    /// [`LinearSolver::analyze`] for a pattern in 3x3 block columns whose
    /// [`BlockStructure`] the caller already has (`blocks` must be that of
    /// `pattern`): a solver that works on blocks takes it instead of
    /// reading it off the scalar rows. By default, `analyze`.
    fn analyze_blocks(
        &mut self,
        pattern: SymbolicSparseColMatRef<'_, usize>,
        blocks: &BlockStructure,
    ) -> Result<(), SolveError> {
        let _ = blocks;
        self.analyze(pattern)
    }
    /// Takes the current values of the matrix.
    fn factor(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError>;
    /// Solves `A x = b` for the matrix last given to `factor`; `x` holds a
    /// starting guess on entry (used by iterative solvers) and the solution
    /// on exit. The stats report the relative residual reached.
    fn solve(
        &mut self,
        matrix: SparseColMatRef<'_, usize, f64>,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, SolveError>;
    /// [`LinearSolver::analyze_blocks`] for a [`SystemPattern`]: by
    /// default on its scalar structure (made if it was not yet).
    fn analyze_pattern(&mut self, pattern: SystemPattern<'_>) -> Result<(), SolveError> {
        self.analyze_blocks(pattern.scalar(), pattern.blocks())
    }
    /// [`LinearSolver::factor`] for the `values` of a matrix on `pattern`.
    fn factor_values(&mut self, pattern: SystemPattern<'_>, values: &[f64]) -> Result<(), SolveError> {
        self.factor(SparseColMatRef::new(pattern.scalar(), values))
    }
    /// [`LinearSolver::solve`] for the `values` of a matrix on `pattern`.
    fn solve_values(
        &mut self,
        pattern: SystemPattern<'_>,
        values: &[f64],
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, SolveError> {
        self.solve(SparseColMatRef::new(pattern.scalar(), values), b, x)
    }
    /// Takes a reference matrix on the same pattern that a preconditioner
    /// may factor once per topology (the rest-state system); ignored by
    /// default.
    fn set_reference(&mut self, _matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError> {
        Ok(())
    }
    /// Whether this solver wants [`LinearSolver::set_reference`] and
    /// [`LinearSolver::set_frames`].
    fn wants_frames(&self) -> bool {
        false
    }
    /// Takes the rotation (row-major) of every 3x3 block for the coming
    /// solves; ignored by default.
    fn set_frames(&mut self, _frames: &[[f64; 9]]) {}
    /// Takes the position (m) of every 3x3 block, where blocks are nodes,
    /// for the coming factor and solves (a preconditioner may build rigid
    /// motions from them); ignored by default.
    fn set_positions(&mut self, _positions: &[[f64; 3]]) {}
}

/// The solvers a simulation can use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum SolverKind {
    /// The envelope Cholesky up to [`ENVELOPE_MAX_UNKNOWNS`] unknowns, CG
    /// above, until CG proves slow: a dynamic simulation hands its steps
    /// to [`SolverKind::Cholesky`] for good when CG's running mean of
    /// iterations per step passes [`auto_cg_budget`], or when a step's CG
    /// does not converge (that step is solved again, by Cholesky); static
    /// solves take Cholesky. Measured per step (2 cores, AMD EPYC Zen 4),
    /// a refactorising Cholesky against CG: 15.5 against 2.8-3.8 ms on
    /// bunny_5k (6.4k unknowns) for E = 1e5 to 1e9 Pa and soft contacts,
    /// 22 against 5-7 ms on a box of 14x10x8 hexahedra, 24 against 8.9 ms
    /// over the first 60 steps of `dg_bunny_from_cube`; over `bunny_cut`
    /// Cholesky alone and CG alone tied (its stiff contacts took CG 110
    /// iterations a step), and Auto, CG while the bunny falls and Cholesky
    /// after, took 14.1-14.9 ms a step against Cholesky's 16.8-18.2
    /// (alternated runs). CG took 1.5 times as long at ν = 0.49, and did
    /// not converge on a beam of 40x2x2 hexahedra at E = 1e10 Pa. On the
    /// 100k-tet bunny (60k unknowns) a CG step takes ~0.035 s and a
    /// refactorising Cholesky step ~0.55 s.
    #[default]
    Auto,
    /// Direct Cholesky, refactorised whenever the matrix changes: the
    /// envelope factorisation ([`EnvelopeCholesky`]) up to
    /// [`ENVELOPE_MAX_UNKNOWNS`] unknowns, the sparse supernodal one
    /// ([`Cholesky`]) above.
    Cholesky,
    /// The sparse supernodal Cholesky at every size (the large-system path
    /// of [`SolverKind::Cholesky`], to compare against).
    SparseCholesky,
    /// The sparse supernodal Cholesky whose factor is kept across steps as
    /// the preconditioner of conjugate gradients, and renewed only when
    /// the matrix has drifted from it ([`LaggedCholesky`]); the envelope
    /// factorisation, refactorised every step, up to
    /// [`ENVELOPE_MAX_UNKNOWNS`] unknowns.
    LaggedCholesky,
    /// Conjugate gradients preconditioned by block Jacobi plus a coarse
    /// correction (the rigid motions of aggregates of nodes),
    /// warm-started.
    Cg,
    /// Conjugate gradients preconditioned by the Cholesky factor of the
    /// rest-state system, applied in per-node rotated frames
    /// (`z = R A₀⁻¹ Rᵀ r`); factored once per topology.
    CgRest,
}

/// The iterations per step, on average, that [`SolverKind::Auto`]'s CG
/// may take on a system of `unknowns` unknowns before the steps go to
/// Cholesky: `unknowns / 100`, at least 40. About where a CG step costs
/// as much as a refactorising Cholesky one (measured: ~35 iterations at
/// 1.4k unknowns, 70-95 at 6.4k, ~110 at 14k; ~1,100 at 60k, 0.55 s
/// against 0.5 ms an iteration), so that the conditioning CG is slow on
/// costs at most about one Cholesky step more than it would. The mean starts from 0 and weighs the newest step a
/// sixteenth (about the last sixteen steps), so that a few steps that
/// take more (the first ones, a contact coming on) do not end CG: a body
/// of 10x6x5 hexahedra (1.4k unknowns) landing at h = 0.02 s took 25
/// iterations a step, 42 and 43 on two. Counts, not times: the choice is
/// the same on every machine and thread count.
pub fn auto_cg_budget(unknowns: usize) -> usize {
    (unknowns / 100).max(40)
}

/// Largest system that [`SolverKind::Cholesky`] factorises in its envelope.
/// Measured (factor and solve of a step's matrix, AMD EPYC with AVX-512,
/// one thread): the envelope takes half the time of the sparse path up to
/// ~300 unknowns (random_cube_drop's 165: 48 against 92 µs; 90 hexahedral
/// nodes, 270: 93 against 241 µs), about the same from 375 to 750 on
/// compact boxes (4x4x4 hexahedra: 197 against 178 µs), and 1.4 times
/// as long at 630 on a 6x5x4 box, growing from there.
pub const ENVELOPE_MAX_UNKNOWNS: usize = 450;

/// The solver [`make_solver`] makes: a [`SolverKind`] resolved for a
/// number of unknowns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SolverChoice {
    /// [`EnvelopeCholesky`].
    Envelope,
    /// [`Cholesky`].
    Sparse,
    /// [`LaggedCholesky`].
    Lagged,
    /// [`ConjugateGradient`] with block Jacobi and the coarse level.
    Cg,
    /// [`ConjugateGradient`] with the rotated rest-state factor.
    CgRest,
}

impl SolverChoice {
    /// The solver for `unknowns` scalar unknowns of `kind`.
    pub fn of(kind: SolverKind, unknowns: usize) -> Self {
        match kind {
            SolverKind::Auto | SolverKind::Cholesky | SolverKind::LaggedCholesky
                if unknowns <= ENVELOPE_MAX_UNKNOWNS =>
            {
                SolverChoice::Envelope
            }
            SolverKind::Cholesky | SolverKind::SparseCholesky => SolverChoice::Sparse,
            SolverKind::LaggedCholesky => SolverChoice::Lagged,
            SolverKind::Auto | SolverKind::Cg => SolverChoice::Cg,
            SolverKind::CgRest => SolverChoice::CgRest,
        }
    }
}

/// A boxed solver of `kind` for `unknowns` scalar unknowns (`tolerance` and
/// `max_iterations` apply to CG).
pub fn make_solver(kind: SolverKind, unknowns: usize, tolerance: f64, max_iterations: usize) -> Box<dyn LinearSolver> {
    match SolverChoice::of(kind, unknowns) {
        SolverChoice::Envelope => Box::new(EnvelopeCholesky::default()),
        SolverChoice::Sparse => Box::new(Cholesky::default()),
        SolverChoice::Lagged => Box::new(LaggedCholesky::default()),
        SolverChoice::Cg => Box::new(ConjugateGradient::new(tolerance, max_iterations)),
        SolverChoice::CgRest => Box::new(ConjugateGradient::new(tolerance, max_iterations).with_rest_preconditioner()),
    }
}

/// The solve of a direct solver: `x = A⁻¹ b` by `solve_in_place` (which
/// overwrites its argument with the solution), the right-hand side and the
/// solution checked finite, and the relative residual reported (`r` is
/// scratch, sized here to `b.len()`).
fn direct_solve(
    matrix: SparseColMatRef<'_, usize, f64>,
    b: &[f64],
    x: &mut [f64],
    r: &mut Vec<f64>,
    solve_in_place: impl FnOnce(&mut [f64]) -> Result<(), SolveError>,
) -> Result<SolveStats, SolveError> {
    if b.iter().any(|v| !v.is_finite()) {
        return Err(SolveError::NonFinite);
    }
    x.copy_from_slice(b);
    solve_in_place(x)?;
    if x.iter().any(|v| !v.is_finite()) {
        return Err(SolveError::NonFinite);
    }
    r.resize(b.len(), 0.0);
    Ok(SolveStats { iterations: 1, residual: relative_residual(matrix, b, x, r) })
}

/// Relative residual `|b - A x| / |b|` (`|A x|` when `b` is zero) for
/// symmetric `A` stored in both triangles; `r` is scratch of `b.len()`
/// values.
pub fn relative_residual(a: SparseColMatRef<'_, usize, f64>, b: &[f64], x: &[f64], r: &mut [f64]) -> f64 {
    symmetric_matvec(a, x, r);
    r.iter_mut().zip(b).for_each(|(r, b)| *r = b - *r);
    let (nb, nr) = (dot(b, b).sqrt(), dot(r, r).sqrt());
    if nb > 0.0 {
        nr / nb
    } else {
        nr
    }
}
