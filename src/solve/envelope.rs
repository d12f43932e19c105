//! Envelope (profile, "skyline") Cholesky for small systems.
//!
//! After a reverse Cuthill–McKee ordering of the block graph, row `i` of
//! `L` is stored densely from its first nonzero column to the diagonal;
//! fill never leaves that envelope. The factorisation and the solves are
//! [`cleave_kernels::envelope`]: contiguous dot products, with no index
//! lists and no symbolic work per factorisation. The pattern's values reach
//! the envelope through a map built once per pattern, and nothing is
//! allocated after [`LinearSolver::analyze`]. On a small body this beats a
//! general sparse factorisation, whose per-call symbolic steps (the
//! elimination reach of every row, permuting the matrix) cost more than
//! the arithmetic; on larger meshes the envelope grows faster than the
//! nested-dissection fill, so [`super::make_solver`] switches by size (see
//! [`super::ENVELOPE_MAX_UNKNOWNS`]).

use cleave_kernels::envelope::{self, Envelope};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};

use super::ordering::reverse_cuthill_mckee;
use super::{LinearSolver, SolveError, SolveStats};

/// A value slot of the pattern that is not copied (the upper triangle).
const UPPER: u32 = u32::MAX;

/// Envelope Cholesky solver (see module docs) for matrices of 3x3 blocks.
#[derive(Clone, Debug, Default)]
pub struct EnvelopeCholesky {
    /// Scalar unknown of each position in the elimination order.
    order: Vec<u32>,
    /// First stored column of each row (in the elimination order).
    first: Vec<u32>,
    /// Start of each row's values in `factor`, plus the end.
    start: Vec<u32>,
    /// Where each value of the pattern (compressed columns, both
    /// triangles) lands in `factor`, [`UPPER`] for the upper triangle.
    target: Vec<u32>,
    /// The envelope of `L`, row by row.
    factor: Vec<f64>,
    /// `1 / L_ii`.
    inverse_diagonal: Vec<f64>,
    /// A right-hand side in the elimination order.
    permuted: Vec<f64>,
    /// `b - A x`, for the residual a solve reports.
    residual: Vec<f64>,
    factored: bool,
}

impl EnvelopeCholesky {
    /// Stored values of `L` (the envelope), once analysed.
    pub fn envelope_len(&self) -> usize {
        self.factor.len()
    }

    fn envelope(&self) -> Envelope<'_> {
        Envelope { first: &self.first, start: &self.start }
    }

    /// Overwrites `x` with `A⁻¹ x` for the last factored `A`.
    pub fn solve_in_place(&mut self, x: &mut [f64]) -> Result<(), SolveError> {
        if !self.factored || x.len() != self.order.len() {
            return Err(SolveError::NotReady);
        }
        let mut y = std::mem::take(&mut self.permuted);
        for (yi, &o) in y.iter_mut().zip(&self.order) {
            *yi = x[o as usize];
        }
        envelope::solve(&self.envelope(), &self.factor, &self.inverse_diagonal, &mut y);
        for (yi, &o) in y.iter().zip(&self.order) {
            x[o as usize] = *yi;
        }
        self.permuted = y;
        Ok(())
    }
}

impl LinearSolver for EnvelopeCholesky {
    fn analyze(&mut self, pattern: SymbolicSparseColMatRef<'_, usize>) -> Result<(), SolveError> {
        let n = pattern.nrows();
        if n % 3 != 0 || u32::try_from(n).is_err() {
            return Err(SolveError::Analysis(format!("the envelope solver takes 3x3 blocks, not {n} unknowns")));
        }
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        let m = n / 3;
        // blocks adjacent to block `v`: the rows of its first column
        let blocks = reverse_cuthill_mckee(m, |v| ri[cp[3 * v]..cp[3 * v + 1]].iter().map(|&r| r / 3));
        let mut position = vec![0u32; m];
        for (p, &v) in blocks.iter().enumerate() {
            position[v as usize] = p as u32;
        }
        self.order = blocks.iter().flat_map(|&v| (0..3).map(move |c| 3 * v + c)).collect();
        // first block column of every block row, then per scalar row
        let mut first_block: Vec<u32> = (0..m as u32).collect();
        for j in 0..n {
            for &r in &ri[cp[j]..cp[j + 1]] {
                let (pr, pc) = (position[r / 3], position[j / 3]);
                let row = pr.max(pc) as usize;
                first_block[row] = first_block[row].min(pr.min(pc));
            }
        }
        self.first = (0..n).map(|i| 3 * first_block[i / 3]).collect();
        self.start = Vec::with_capacity(n + 1);
        let mut len = 0usize;
        for i in 0..n {
            self.start.push(u32::try_from(len).map_err(|_| too_large(len))?);
            len += i - self.first[i] as usize + 1;
        }
        self.start.push(u32::try_from(len).map_err(|_| too_large(len))?);
        self.target = Vec::with_capacity(ri.len());
        for j in 0..n {
            for &r in &ri[cp[j]..cp[j + 1]] {
                let pr = 3 * position[r / 3] as usize + r % 3;
                let pc = 3 * position[j / 3] as usize + j % 3;
                self.target.push(if pr >= pc { self.start[pr] + (pc - self.first[pr] as usize) as u32 } else { UPPER });
            }
        }
        self.factor = vec![0.0; len];
        self.inverse_diagonal = vec![0.0; n];
        self.permuted = vec![0.0; n];
        self.residual = vec![0.0; n];
        self.factored = false;
        Ok(())
    }

    fn factor(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError> {
        let values = matrix.parts().1;
        if values.len() != self.target.len() {
            return Err(SolveError::NotReady);
        }
        self.factored = false;
        self.factor.fill(0.0);
        for (&t, &v) in self.target.iter().zip(values) {
            if !v.is_finite() {
                return Err(SolveError::NonFinite);
            }
            if t != UPPER {
                self.factor[t as usize] = v;
            }
        }
        let mut factor = std::mem::take(&mut self.factor);
        let mut inverse_diagonal = std::mem::take(&mut self.inverse_diagonal);
        let done = envelope::factor(&self.envelope(), &mut factor, &mut inverse_diagonal);
        (self.factor, self.inverse_diagonal) = (factor, inverse_diagonal);
        if let Err(envelope::NotPositive { row }) = done {
            return Err(SolveError::NotPositiveDefinite { pivot: self.order[row] as usize, n: self.order.len() });
        }
        self.factored = true;
        Ok(())
    }

    fn solve(
        &mut self,
        matrix: SparseColMatRef<'_, usize, f64>,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, SolveError> {
        let mut residual = std::mem::take(&mut self.residual);
        let stats = super::direct_solve(matrix, b, x, &mut residual, |x| self.solve_in_place(x));
        self.residual = residual;
        stats
    }
}

fn too_large(len: usize) -> SolveError {
    SolveError::Analysis(format!("an envelope of {len} values is too large"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::sparse::{SparseColMat, Triplet};

    /// A symmetric positive definite matrix on the graph of a path of
    /// `blocks` 3x3 blocks, with some longer couplings, shuffled.
    fn matrix(blocks: usize) -> SparseColMat<usize, f64> {
        let n = 3 * blocks;
        let mut t = Vec::new();
        let couple = |i: usize, j: usize, t: &mut Vec<Triplet<usize, usize, f64>>| {
            for r in 0..3 {
                for c in 0..3 {
                    let v = -0.1 - 0.01 * ((i * 7 + j * 3 + r + 2 * c) % 5) as f64;
                    t.push(Triplet::new(3 * i + r, 3 * j + c, v));
                    t.push(Triplet::new(3 * j + c, 3 * i + r, v));
                }
            }
        };
        let shuffle = |i: usize| (i * 7) % blocks;
        for i in 0..blocks {
            if i + 1 < blocks {
                couple(shuffle(i), shuffle(i + 1), &mut t);
            }
            if i + 4 < blocks {
                couple(shuffle(i), shuffle(i + 4), &mut t);
            }
        }
        for i in 0..n {
            t.push(Triplet::new(i, i, 8.0 + (i % 3) as f64));
        }
        SparseColMat::try_new_from_triplets(n, n, &t).unwrap()
    }

    #[test]
    fn solves_to_rounding_and_matches_the_sparse_cholesky() {
        let a = matrix(25);
        let n = a.nrows();
        let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let mut env = EnvelopeCholesky::default();
        env.analyze(a.symbolic()).unwrap();
        env.factor(a.as_ref()).unwrap();
        let mut x = vec![0.0; n];
        let stats = env.solve(a.as_ref(), &b, &mut x).unwrap();
        assert!(stats.residual < 1e-14, "residual {}", stats.residual);
        let mut sparse = super::super::Cholesky::default();
        sparse.analyze(a.symbolic()).unwrap();
        sparse.factor(a.as_ref()).unwrap();
        let mut y = vec![0.0; n];
        sparse.solve(a.as_ref(), &b, &mut y).unwrap();
        let diff = x.iter().zip(&y).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
        assert!(diff < 1e-14, "envelope and sparse Cholesky differ by {diff}");
        // the ordering narrows the shuffled path's envelope below the dense
        // triangle's n(n+1)/2
        assert!(env.envelope_len() < n * (n + 1) / 4, "envelope {} of {}", env.envelope_len(), n * (n + 1) / 2);
    }

    #[test]
    fn refuses_an_indefinite_or_unblocked_matrix_and_use_before_analysis() {
        let mut env = EnvelopeCholesky::default();
        let a = matrix(3);
        assert_eq!(env.factor(a.as_ref()), Err(SolveError::NotReady));
        env.analyze(a.symbolic()).unwrap();
        let mut x = [0.0; 9];
        assert_eq!(env.solve_in_place(&mut x), Err(SolveError::NotReady));
        // unknown 4 made negative: the error names it in the caller's numbering
        let (sym, mut values) = (a.symbolic(), a.val().to_vec());
        let (cp, ri) = (sym.col_ptr(), sym.row_idx());
        let slot = (cp[4]..cp[5]).find(|&p| ri[p] == 4).unwrap();
        values[slot] = -1.0;
        let indefinite = SparseColMatRef::new(sym, &values);
        assert_eq!(env.factor(indefinite), Err(SolveError::NotPositiveDefinite { pivot: 4, n: 9 }));
        let t = [Triplet::new(0, 0, 1.0), Triplet::new(1, 1, 2.0)];
        let unblocked = SparseColMat::<usize, f64>::try_new_from_triplets(2, 2, &t).unwrap();
        assert!(matches!(env.analyze(unblocked.symbolic()), Err(SolveError::Analysis(_))));
    }
}
