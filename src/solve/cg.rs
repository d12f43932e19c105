//! Preconditioned conjugate gradients with a 3x3 block-Jacobi
//! preconditioner, warm-started from the caller's guess.
//!
//! The matrix stores both triangles and is symmetric, so `y = A x` is
//! computed row by row as `y_i = (column i) · x`, in parallel without
//! write conflicts, reading the pattern's 3x3 block structure (one 32-bit
//! block row index per 9 values instead of a 64-bit index per value, which
//! halves the traffic of this memory-bound kernel). Dot products sum fixed-size chunks in parallel and the
//! chunk sums in order, so the iterates are bitwise independent of the
//! thread count.

use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use rayon::prelude::*;

use super::{Cholesky, LinearSolver, SolveError, SolveStats};

/// Chunk length of the deterministic reductions.
const CHUNK: usize = 4096;

/// PCG solver (see module docs).
pub struct ConjugateGradient {
    /// Relative residual `|b - A x| / |b|` to reach.
    pub tolerance: f64,
    /// Iteration cap; reaching it is an error.
    pub max_iterations: usize,
    /// Value index of entry `(3j + r, 3j + c)` at `[j][3r + c]`.
    diagonal_blocks: Vec<[usize; 9]>,
    /// Inverted diagonal blocks of the current matrix.
    inverse_blocks: Vec<[f64; 9]>,
    /// Block structure: block rows of block column `j` at
    /// `block_rows[block_ptr[j]..block_ptr[j + 1]]`, its first value at
    /// `value_start[j]`.
    block_ptr: Vec<u32>,
    block_rows: Vec<u32>,
    value_start: Vec<usize>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    ap: Vec<f64>,
    /// `Rᵀ r` and `A₀⁻¹ Rᵀ r` of the rotated preconditioner.
    rotated: Vec<f64>,
    /// The rotated rest-state preconditioner, when chosen.
    rest: Option<RestPreconditioner>,
}

/// `z = R A₀⁻¹ Rᵀ r`: the Cholesky factor of the rest-state matrix `A₀`
/// applied in per-block rotated frames `R`.
struct RestPreconditioner {
    cholesky: Cholesky,
    frames: Vec<[f64; 9]>,
    ready: bool,
}

impl ConjugateGradient {
    /// A solver with the given tolerance and iteration cap.
    pub fn new(tolerance: f64, max_iterations: usize) -> Self {
        ConjugateGradient {
            tolerance,
            max_iterations,
            diagonal_blocks: Vec::new(),
            inverse_blocks: Vec::new(),
            block_ptr: Vec::new(),
            block_rows: Vec::new(),
            value_start: Vec::new(),
            r: Vec::new(),
            z: Vec::new(),
            p: Vec::new(),
            ap: Vec::new(),
            rotated: Vec::new(),
            rest: None,
        }
    }

    /// Preconditions with the rotated rest-state Cholesky factor (see
    /// [`super::SolverKind::CgRest`]) once a reference matrix is given.
    pub fn with_rest_preconditioner(mut self) -> Self {
        self.rest = Some(RestPreconditioner { cholesky: Cholesky::default(), frames: Vec::new(), ready: false });
        self
    }

    /// `y = A x` through the block structure (see module docs).
    fn matvec(&self, a: SparseColMatRef<'_, usize, f64>, x: &[f64], y: &mut [f64]) {
        let val = a.parts().1;
        y.par_chunks_mut(3).with_min_len(128).enumerate().for_each(|(j, yj)| {
            let rows = &self.block_rows[self.block_ptr[j] as usize..self.block_ptr[j + 1] as usize];
            let stride = 3 * rows.len();
            let start = self.value_start[j];
            for (c, out) in yj.iter_mut().enumerate() {
                let col = &val[start + c * stride..start + (c + 1) * stride];
                let mut s = 0.0;
                for (blk, &i) in col.chunks_exact(3).zip(rows) {
                    let xi = &x[3 * i as usize..3 * i as usize + 3];
                    s += blk[0] * xi[0] + blk[1] * xi[1] + blk[2] * xi[2];
                }
                *out = s;
            }
        });
    }

    fn precondition(&mut self, r: &[f64], z: &mut [f64]) -> Result<(), SolveError> {
        if let Some(rest) = self.rest.as_mut().filter(|p| p.ready) {
            let rotate = |frames: &[[f64; 9]], v: &[f64], out: &mut [f64], transpose: bool| {
                out.par_chunks_mut(3).zip(v.par_chunks(3)).zip(frames).for_each(|((o, v), m)| {
                    for i in 0..3 {
                        o[i] = if transpose {
                            m[i] * v[0] + m[3 + i] * v[1] + m[6 + i] * v[2]
                        } else {
                            m[3 * i] * v[0] + m[3 * i + 1] * v[1] + m[3 * i + 2] * v[2]
                        };
                    }
                });
            };
            let t = &mut self.rotated;
            t.resize(r.len(), 0.0);
            rotate(&rest.frames, r, t, true);
            rest.cholesky.solve_in_place(t)?;
            rotate(&rest.frames, t, z, false);
            return Ok(());
        }
        z.par_chunks_mut(3).zip(r.par_chunks(3)).zip(&self.inverse_blocks).for_each(|((z, r), m)| {
            for i in 0..3 {
                z[i] = m[3 * i] * r[0] + m[3 * i + 1] * r[1] + m[3 * i + 2] * r[2];
            }
        });
        Ok(())
    }
}

/// `y = A x` for symmetric `A` stored in both triangles.
pub fn symmetric_matvec(a: SparseColMatRef<'_, usize, f64>, x: &[f64], y: &mut [f64]) {
    let (sym, val) = a.parts();
    let (cp, ri) = (sym.col_ptr(), sym.row_idx());
    y.par_iter_mut().with_min_len(512).enumerate().for_each(|(i, yi)| {
        let mut s = 0.0;
        for p in cp[i]..cp[i + 1] {
            s += val[p] * x[ri[p]];
        }
        *yi = s;
    });
}

/// Chunk sums [`dot`] keeps on the stack (vectors up to `4096 · 1024`
/// values); longer vectors keep theirs on the heap.
const STACK_CHUNKS: usize = 1024;

/// `Σ a_i b_i`, summed in fixed chunks in parallel and the chunk sums in
/// order (deterministic: the same bits on any number of threads).
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    let chunks = a.len().div_ceil(CHUNK);
    let sum_into = |partial: &mut [f64]| -> f64 {
        partial
            .par_iter_mut()
            .zip(a.par_chunks(CHUNK).zip(b.par_chunks(CHUNK)))
            .for_each(|(s, (x, y))| *s = x.iter().zip(y).map(|(p, q)| p * q).sum());
        partial.iter().sum()
    };
    if chunks <= STACK_CHUNKS {
        sum_into(&mut [0.0; STACK_CHUNKS][..chunks])
    } else {
        sum_into(&mut vec![0.0; chunks])
    }
}

/// Inverse of a 3x3 matrix (row-major); the identity where it is singular.
fn invert3(m: [f64; 9]) -> [f64; 9] {
    let c = [
        m[4] * m[8] - m[5] * m[7],
        m[2] * m[7] - m[1] * m[8],
        m[1] * m[5] - m[2] * m[4],
        m[5] * m[6] - m[3] * m[8],
        m[0] * m[8] - m[2] * m[6],
        m[2] * m[3] - m[0] * m[5],
        m[3] * m[7] - m[4] * m[6],
        m[1] * m[6] - m[0] * m[7],
        m[0] * m[4] - m[1] * m[3],
    ];
    let det = m[0] * c[0] + m[1] * c[3] + m[2] * c[6];
    if det.abs() > 0.0 && det.is_finite() {
        c.map(|x| x / det)
    } else {
        [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    }
}

impl LinearSolver for ConjugateGradient {
    fn analyze(&mut self, pattern: SymbolicSparseColMatRef<'_, usize>) -> Result<(), SolveError> {
        let n = pattern.nrows();
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        self.diagonal_blocks = (0..n / 3)
            .map(|j| {
                let mut slots = [0usize; 9];
                for c in 0..3 {
                    let col = 3 * j + c;
                    let rows = &ri[cp[col]..cp[col + 1]];
                    for r in 0..3 {
                        let p = rows
                            .binary_search(&(3 * j + r))
                            .map_err(|_| SolveError::Analysis(format!("block {j} has no diagonal")))?;
                        slots[3 * r + c] = cp[col] + p;
                    }
                }
                Ok(slots)
            })
            .collect::<Result<_, SolveError>>()?;
        self.inverse_blocks = vec![[0.0; 9]; n / 3];
        // block structure: every block column repeats its block rows in its
        // three scalar columns (the layout of `assembly::SparsePattern`)
        self.block_ptr = vec![0];
        self.block_rows.clear();
        self.value_start.clear();
        for j in 0..n / 3 {
            let rows = &ri[cp[3 * j]..cp[3 * j + 1]];
            let regular = rows.len() % 3 == 0
                && rows.chunks(3).all(|r| r[0] % 3 == 0 && r[1] == r[0] + 1 && r[2] == r[0] + 2)
                && (1..3).all(|c| ri[cp[3 * j + c]..cp[3 * j + c + 1]] == *rows);
            if !regular {
                return Err(SolveError::Analysis(format!("block column {j} is not a repeated 3x3 block column")));
            }
            self.value_start.push(cp[3 * j]);
            self.block_rows.extend(rows.chunks(3).map(|r| (r[0] / 3) as u32));
            self.block_ptr.push(self.block_rows.len() as u32);
        }
        for v in [&mut self.r, &mut self.z, &mut self.p, &mut self.ap] {
            *v = vec![0.0; n];
        }
        Ok(())
    }

    fn factor(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError> {
        let val = matrix.parts().1;
        if val.iter().any(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite);
        }
        self.inverse_blocks.par_iter_mut().zip(&self.diagonal_blocks).for_each(|(inv, slots)| {
            *inv = invert3(slots.map(|s| val[s]));
        });
        Ok(())
    }

    fn solve(
        &mut self,
        matrix: SparseColMatRef<'_, usize, f64>,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, SolveError> {
        if b.iter().chain(x.iter()).any(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite);
        }
        let norm_b = dot(b, b).sqrt();
        if norm_b == 0.0 {
            x.fill(0.0);
            return Ok(SolveStats { iterations: 0, residual: 0.0 });
        }
        let mut ap = std::mem::take(&mut self.ap);
        self.matvec(matrix, x, &mut ap);
        self.ap = ap;
        self.r.par_iter_mut().zip(b).zip(&self.ap).for_each(|((r, b), ax)| *r = b - ax);
        let (r, mut z) = (std::mem::take(&mut self.r), std::mem::take(&mut self.z));
        self.precondition(&r, &mut z)?;
        (self.r, self.z) = (r, z);
        self.p.copy_from_slice(&self.z);
        let mut rz = dot(&self.r, &self.z);
        let mut residual = dot(&self.r, &self.r).sqrt() / norm_b;
        for it in 0..self.max_iterations {
            if residual <= self.tolerance {
                return Ok(SolveStats { iterations: it, residual });
            }
            let mut ap = std::mem::take(&mut self.ap);
            self.matvec(matrix, &self.p, &mut ap);
            self.ap = ap;
            let pap = dot(&self.p, &self.ap);
            if !(pap > 0.0) {
                return Err(SolveError::NotPositiveDefinite { pivot: it, n: b.len() });
            }
            let alpha = rz / pap;
            x.par_iter_mut().zip(&self.p).for_each(|(x, p)| *x += alpha * p);
            self.r.par_iter_mut().zip(&self.ap).for_each(|(r, ap)| *r -= alpha * ap);
            let (r, mut z) = (std::mem::take(&mut self.r), std::mem::take(&mut self.z));
            self.precondition(&r, &mut z)?;
            (self.r, self.z) = (r, z);
            let rz_new = dot(&self.r, &self.z);
            let beta = rz_new / rz;
            rz = rz_new;
            self.p.par_iter_mut().zip(&self.z).for_each(|(p, z)| *p = z + beta * *p);
            residual = dot(&self.r, &self.r).sqrt() / norm_b;
            if !residual.is_finite() {
                return Err(SolveError::NonFinite);
            }
        }
        if residual <= self.tolerance {
            return Ok(SolveStats { iterations: self.max_iterations, residual });
        }
        Err(SolveError::NotConverged { iterations: self.max_iterations, residual, tolerance: self.tolerance })
    }

    fn set_reference(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError> {
        if let Some(rest) = self.rest.as_mut() {
            rest.cholesky.analyze(matrix.symbolic())?;
            rest.cholesky.factor(matrix)?;
            rest.ready = true;
        }
        Ok(())
    }

    fn wants_frames(&self) -> bool {
        self.rest.is_some()
    }

    fn set_frames(&mut self, frames: &[[f64; 9]]) {
        if let Some(rest) = self.rest.as_mut() {
            rest.frames.clear();
            rest.frames.extend_from_slice(frames);
        }
    }
}
