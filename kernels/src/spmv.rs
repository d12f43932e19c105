//! The product `y = A x` of a symmetric matrix stored as compressed
//! columns in 3x3 blocks (each block column's three scalar columns share
//! one list of block rows) with a vector: the kernel of every conjugate
//! gradient iteration, bound by the matrix's memory traffic and, once that
//! is halved by `f32` values, by arithmetic.
//!
//! Block row `i` of block column `j` holds, in scalar column `3 j + c`, the
//! three entries `A[3 i + r][3 j + c]` one after the other; by symmetry
//! `y[3 j + c] = Σ_i Σ_r A[3 i + r][3 j + c] x[3 i + r]`. The kernel keeps
//! one running sum per entry of the block, `acc[c][r]`, as four lanes (the
//! fourth multiplies the next stored value by a zero of `x`), so that the
//! three lanes of a column are one vector operation at AVX2 width, and adds
//! the lanes of each `c` in order at the end: the same arithmetic in the
//! same order at every instruction set, so the same bits.

use crate::lanes::dispatch;

/// A stored matrix value: `f64`, or `f32` for half the memory traffic (the
/// sums are `f64` either way).
pub trait Value: Copy + Sync {
    /// The value as `f64` (exact).
    fn to_f64(self) -> f64;
}

impl Value for f64 {
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
}

impl Value for f32 {
    #[inline(always)]
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
}

/// The block structure of a matrix: block rows of block column `j` at
/// `rows[ptr[j]..ptr[j + 1]]` (sorted), its first value at `start[j]`.
#[derive(Clone, Copy, Debug)]
pub struct BlockColumns<'a> {
    /// Offsets into `rows`, one per block column plus one.
    pub ptr: &'a [u32],
    /// Block row indices.
    pub rows: &'a [u32],
    /// Index of each block column's first value.
    pub start: &'a [usize],
}

/// `y_j = (A x)_j` for the block columns `first..first + y.len() / 3` of
/// `values` on `structure`; returns `Σ_j x_j · y_j` over those columns,
/// summed in order. Every value must be finite (the padding lane multiplies
/// a stored value by zero).
pub fn block_products<T: Value>(
    structure: BlockColumns<'_>,
    values: &[T],
    x: &[f64],
    first: usize,
    y: &mut [f64],
) -> f64 {
    dispatch(Products { structure, values, x, first, y })
}

struct Products<'a, T> {
    structure: BlockColumns<'a>,
    values: &'a [T],
    x: &'a [f64],
    first: usize,
    y: &'a mut [f64],
}

impl<T: Value> pulp::WithSimd for Products<'_, T> {
    type Output = f64;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> f64 {
        let Products { structure, values, x, first, y } = self;
        let mut dot = 0.0;
        for (q, yj) in y.chunks_exact_mut(3).enumerate() {
            let j = first + q;
            let rows = &structure.rows[structure.ptr[j] as usize..structure.ptr[j + 1] as usize];
            let stride = 3 * rows.len();
            let column = &values[structure.start[j]..structure.start[j] + 3 * stride];
            let mut acc = [[0.0f64; 4]; 3];
            let lane = |v: &[T], xi: &[f64; 4], a: &mut [f64; 4]| {
                for r in 0..4 {
                    a[r] += v[r].to_f64() * xi[r];
                }
            };
            let xi = |i: u32| {
                let i = 3 * i as usize;
                [x[i], x[i + 1], x[i + 2], 0.0]
            };
            let Some((&last, most)) = rows.split_last() else { continue };
            // every block row but the last reads four values per column
            // (the fourth is the next block row's first)
            for (p, &i) in most.iter().enumerate() {
                let xi = xi(i);
                for (c, a) in acc.iter_mut().enumerate() {
                    lane(&column[c * stride + 3 * p..c * stride + 3 * p + 4], &xi, a);
                }
            }
            // the last one, whose fourth value may lie past the column
            let (xl, p) = (xi(last), rows.len() - 1);
            for (c, a) in acc.iter_mut().enumerate() {
                for r in 0..3 {
                    a[r] += column[c * stride + 3 * p + r].to_f64() * xl[r];
                }
            }
            for (out, a) in yj.iter_mut().zip(acc) {
                *out = a[0] + a[1] + a[2];
            }
            dot += x[3 * j] * yj[0] + x[3 * j + 1] * yj[1] + x[3 * j + 2] * yj[2];
        }
        dot
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A matrix as block columns (see [`BlockColumns`]) and dense.
    struct Ring {
        ptr: Vec<u32>,
        rows: Vec<u32>,
        start: Vec<usize>,
        values: Vec<f64>,
        dense: Vec<Vec<f64>>,
    }

    /// A symmetric matrix of 3x3 blocks on a ring of `n` blocks (each
    /// coupled to itself and its two neighbours).
    fn ring(n: usize) -> Ring {
        let mut dense = vec![vec![0.0; 3 * n]; 3 * n];
        let entry = |i: usize, j: usize| ((i * 7 + j * 13) % 11) as f64 - 5.0 + 0.25 * (i + j) as f64;
        for bj in 0..n {
            for bi in [bj, (bj + 1) % n, (bj + n - 1) % n] {
                for r in 0..3 {
                    for c in 0..3 {
                        let (i, j) = (3 * bi + r, 3 * bj + c);
                        let v = entry(i.min(j), i.max(j));
                        dense[i][j] = v;
                        dense[j][i] = v;
                    }
                }
            }
        }
        let (mut ptr, mut rows, mut start, mut values) = (vec![0u32], Vec::new(), Vec::new(), Vec::new());
        for bj in 0..n {
            let mut r: Vec<u32> = vec![bj as u32, ((bj + 1) % n) as u32, ((bj + n - 1) % n) as u32];
            r.sort_unstable();
            r.dedup();
            start.push(values.len());
            for c in 0..3 {
                for &bi in &r {
                    values.extend((0..3).map(|q| dense[3 * bi as usize + q][3 * bj + c]));
                }
            }
            rows.extend(&r);
            ptr.push(rows.len() as u32);
        }
        Ring { ptr, rows, start, values, dense }
    }

    /// Against the dense product, for `f64` and `f32` values, on every
    /// instruction set the machine has (the same bits on each), over
    /// ranges of block columns as the solver splits them.
    #[test]
    fn products_match_the_dense_matrix_on_every_level() {
        let n = 7;
        let Ring { ptr, rows, start, values, dense } = ring(n);
        let structure = BlockColumns { ptr: &ptr, rows: &rows, start: &start };
        let x: Vec<f64> = (0..3 * n).map(|i| (i as f64 * 0.7).sin()).collect();
        let want: Vec<f64> = dense.iter().map(|row| row.iter().zip(&x).map(|(a, b)| a * b).sum()).collect();
        let values32: Vec<f32> = values.iter().map(|&v| v as f32).collect();
        let mut bits = None;
        for level in crate::lanes::levels::available("spmv") {
            let (mut y, mut y32) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            let (head, tail) = y.split_at_mut(9);
            let dot =
                crate::lanes::levels::run(level, Products { structure, values: &values, x: &x, first: 0, y: head })
                    + crate::lanes::levels::run(
                        level,
                        Products { structure, values: &values, x: &x, first: 3, y: tail },
                    );
            crate::lanes::levels::run(level, Products { structure, values: &values32, x: &x, first: 0, y: &mut y32 });
            for (i, (&got, &w)) in y.iter().zip(&want).enumerate() {
                assert!((got - w).abs() <= 1e-12 * (1.0 + w.abs()), "{level:?}: y[{i}] = {got}, dense {w}");
                assert!((y32[i] - w).abs() <= 1e-5 * (1.0 + w.abs()), "{level:?}: f32 y[{i}] = {}, dense {w}", y32[i]);
            }
            let want_dot: f64 = x.iter().zip(&want).map(|(a, b)| a * b).sum();
            assert!(
                (dot - want_dot).abs() <= 1e-10 * (1.0 + want_dot.abs()),
                "{level:?}: x·Ax {dot} against {want_dot}"
            );
            let these: Vec<u64> = y.iter().chain(&y32).map(|v| v.to_bits()).collect();
            assert_eq!(*bits.get_or_insert(these.clone()), these, "{level:?} differs from the first level");
        }
    }
}
