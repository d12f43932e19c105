//! Sparse Cholesky `A = L L^T` through faer's low-level API: the symbolic
//! factorisation (ordering, elimination tree, supernodes) once per pattern,
//! the numeric one into kept buffers whenever values change.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

use super::{relative_residual, LinearSolver, SolveError, SolveStats};

/// Direct sparse Cholesky solver.
#[derive(Default)]
pub struct Cholesky {
    symbolic: Option<SymbolicCholesky<usize>>,
    l_values: Vec<f64>,
    scratch: Option<MemBuffer>,
    factored: bool,
    par: Option<Par>,
}

impl Cholesky {
    /// A solver that runs faer's kernels with `par` (default: the rayon pool).
    pub fn new(par: Par) -> Self {
        Cholesky { par: Some(par), ..Default::default() }
    }

    fn par(&self) -> Par {
        self.par.unwrap_or(Par::rayon(0))
    }

    /// Number of stored entries of `L` (fill), once analysed.
    pub fn factor_nnz(&self) -> usize {
        self.symbolic.as_ref().map_or(0, |s| s.len_val())
    }
}

impl LinearSolver for Cholesky {
    fn analyze(&mut self, pattern: SymbolicSparseColMatRef<'_, usize>) -> Result<(), SolveError> {
        let sym = factorize_symbolic_cholesky(
            pattern,
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams::default(),
        )
        .map_err(|e| SolveError::Analysis(format!("{e:?}")))?;
        let par = self.par();
        let req = sym
            .factorize_numeric_llt_scratch::<f64>(par, Default::default())
            .or(sym.solve_in_place_scratch::<f64>(1, par));
        self.scratch = Some(MemBuffer::new(req));
        self.l_values = vec![0.0; sym.len_val()];
        self.symbolic = Some(sym);
        self.factored = false;
        Ok(())
    }

    fn factor(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError> {
        let par = self.par();
        let (Some(sym), Some(buf)) = (self.symbolic.as_ref(), self.scratch.as_mut()) else {
            return Err(SolveError::NotReady);
        };
        if matrix.parts().1.iter().any(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite);
        }
        self.factored = false;
        sym.factorize_numeric_llt(
            &mut self.l_values,
            matrix,
            Side::Lower,
            LltRegularization::default(),
            par,
            MemStack::new(buf),
            Default::default(),
        )
        .map_err(|e| match e {
            faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index } => {
                SolveError::NotPositiveDefinite { pivot: index, n: matrix.nrows() }
            }
        })?;
        self.factored = true;
        Ok(())
    }

    fn solve(
        &mut self,
        _matrix: SparseColMatRef<'_, usize, f64>,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, SolveError> {
        let par = self.par();
        let (Some(sym), Some(buf), true) = (self.symbolic.as_ref(), self.scratch.as_mut(), self.factored) else {
            return Err(SolveError::NotReady);
        };
        if b.iter().any(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite);
        }
        x.copy_from_slice(b);
        let llt = LltRef::<'_, usize, f64>::new(sym, &self.l_values);
        let n = x.len();
        llt.solve_in_place_with_conj(Conj::No, MatMut::from_column_major_slice_mut(x, n, 1), par, MemStack::new(buf));
        if x.iter().any(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite);
        }
        Ok(SolveStats { iterations: 1, residual: f64::NAN })
    }
}

/// Solves and reports the true relative residual.
pub fn solve_checked(
    solver: &mut dyn LinearSolver,
    a: SparseColMatRef<'_, usize, f64>,
    b: &[f64],
    x: &mut [f64],
) -> Result<SolveStats, SolveError> {
    let mut stats = solver.solve(a, b, x)?;
    stats.residual = relative_residual(a, b, x);
    Ok(stats)
}
