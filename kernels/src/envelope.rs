//! Envelope (profile, "skyline") Cholesky `A = L Lᵀ` of a symmetric
//! positive definite matrix of 3x3 blocks, and its triangular solves.
//!
//! Layout: scalar row `i` of `L` is stored densely in
//! `factor[start[i]..start[i + 1]]`, from column `first[i]` to the
//! diagonal, which is its last value. The three rows of a block share
//! their first column, a multiple of 3. Row by row,
//!
//! ```text
//! L_ij = (A_ij - Σ_{k = max(f_i, f_j)}^{j-1} L_ik L_jk) / L_jj    f_i ≤ j < i
//! L_ii = sqrt(A_ii - Σ_{k = f_i}^{i-1} L_ik²)
//! ```
//!
//! taken a block row at a time: the nine sums of a 3x3 block share their
//! loads, and every inner loop runs over contiguous slices (no index
//! lists, no symbolic work). Every sum runs in a fixed order (four
//! interleaved partial sums, then a fixed tree, then the tail) and the
//! code runs under runtime dispatch only so that the compiler may use wide
//! registers for those independent partial sums: the results are the same
//! bits on every instruction set.

use pulp::Simd;

use crate::lanes::ordered_dot as dot;

/// Lane count of the fixed-order sums.
const LANES: usize = 4;

/// Where the factorisation stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NotPositive {
    /// The scalar row (in the factor's order) whose pivot was not positive.
    pub row: usize,
}

/// The envelope of `L` and where its rows lie.
pub struct Envelope<'a> {
    /// First stored column of every scalar row (a multiple of 3, equal for
    /// the three rows of a block).
    pub first: &'a [u32],
    /// Start of every row in `factor`, plus the end.
    pub start: &'a [u32],
}

impl Envelope<'_> {
    fn check(&self, factor: &[f64], inverse_diagonal: &[f64]) {
        let n = self.first.len();
        assert!(n % 3 == 0 && self.start.len() == n + 1, "3x3 blocks and one start per row plus the end");
        assert_eq!(self.start[n] as usize, factor.len(), "the rows fill the factor");
        assert_eq!(inverse_diagonal.len(), n, "one inverse diagonal per row");
        for i in 0..n {
            let (f, len) = (self.first[i] as usize, (self.start[i + 1] - self.start[i]) as usize);
            assert!(f % 3 == 0 && f == self.first[i - i % 3] as usize && len == i - f + 1, "row {i}");
        }
    }
}

struct Factor<'a> {
    envelope: &'a Envelope<'a>,
    factor: &'a mut [f64],
    inverse_diagonal: &'a mut [f64],
}

impl pulp::WithSimd for Factor<'_> {
    type Output = Result<(), NotPositive>;
    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) -> Self::Output {
        let Factor { envelope: Envelope { first, start }, factor, inverse_diagonal } = self;
        for i in (0..first.len()).step_by(3) {
            let fi = first[i] as usize;
            // the rows above are final: split them off the block row being
            // written (its three rows are consecutive)
            let (done, rest) = factor.split_at_mut(start[i] as usize);
            let (r0, rest) = rest.split_at_mut(i - fi + 1);
            let (r1, rest) = rest.split_at_mut(i - fi + 2);
            let mut rows = [r0, r1, &mut rest[..i - fi + 3]];
            for j in (fi..i).step_by(3) {
                let fj = first[j] as usize;
                let f = fi.max(fj);
                let (s0, s1, s2) = (start[j] as usize, start[j + 1] as usize, start[j + 2] as usize);
                let (o, len) = (f - fj, j - f);
                let other = [&done[s0 + o..s0 + o + len], &done[s1 + o..s1 + o + len], &done[s2 + o..s2 + o + len]];
                let (m, end) = (f - fi, j - fi);
                let s = dot3x3([&rows[0][m..end], &rows[1][m..end], &rows[2][m..end]], other);
                // L_IJ L_JJᵀ = A_IJ - S, by forward substitution over the
                // columns of the lower triangular L_JJ
                let d = j - fj;
                let (l10, l20, l21) = (done[s1 + d], done[s2 + d], done[s2 + d + 1]);
                let inv = &inverse_diagonal[j..j + 3];
                for (row, s) in rows.iter_mut().zip(&s) {
                    let x = &mut row[j - fi..j - fi + 3];
                    x[0] = (x[0] - s[0]) * inv[0];
                    x[1] = (x[1] - s[1] - x[0] * l10) * inv[1];
                    x[2] = (x[2] - s[2] - x[0] * l20 - x[1] * l21) * inv[2];
                }
            }
            // the diagonal block: A_II - L_I L_Iᵀ, then its own Cholesky
            let d = i - fi;
            let mine = [&rows[0][..d], &rows[1][..d], &rows[2][..d]];
            let s = dot3x3(mine, mine);
            for r in 0..3 {
                for c in 0..r {
                    let mut v = rows[r][d + c] - s[r][c];
                    for k in 0..c {
                        v -= rows[r][d + k] * rows[c][d + k];
                    }
                    rows[r][d + c] = v * inverse_diagonal[i + c];
                }
                let mut v = rows[r][d + r] - s[r][r];
                for k in 0..r {
                    v -= rows[r][d + k] * rows[r][d + k];
                }
                if v.is_nan() || v <= 0.0 {
                    return Err(NotPositive { row: i + r });
                }
                let l = v.sqrt();
                rows[r][d + r] = l;
                inverse_diagonal[i + r] = 1.0 / l;
            }
        }
        Ok(())
    }
}

/// Factorises in place: `factor` holds the lower triangle of `A` in the
/// envelope layout on entry (zeros where `A` has none), `L` on exit, and
/// `inverse_diagonal` receives `1 / L_ii`. Fails at the first row whose
/// pivot is not positive (or not finite).
pub fn factor(envelope: &Envelope<'_>, factor: &mut [f64], inverse_diagonal: &mut [f64]) -> Result<(), NotPositive> {
    envelope.check(factor, inverse_diagonal);
    crate::lanes::dispatch(Factor { envelope, factor, inverse_diagonal })
}

struct Solve<'a> {
    envelope: &'a Envelope<'a>,
    factor: &'a [f64],
    inverse_diagonal: &'a [f64],
    x: &'a mut [f64],
}

impl pulp::WithSimd for Solve<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        let Solve { envelope: Envelope { first, start }, factor, inverse_diagonal, x } = self;
        // L y = b, row by row
        for i in 0..x.len() {
            let (f, s) = (first[i] as usize, start[i] as usize);
            x[i] = (x[i] - dot(&factor[s..s + (i - f)], &x[f..i])) * inverse_diagonal[i];
        }
        // Lᵀ x = y, rows last to first, each subtracted from the rows above
        for i in (0..x.len()).rev() {
            let (f, s) = (first[i] as usize, start[i] as usize);
            let xi = x[i] * inverse_diagonal[i];
            x[i] = xi;
            for (xk, l) in x[f..i].iter_mut().zip(&factor[s..s + (i - f)]) {
                *xk -= xi * l;
            }
        }
    }
}

/// Overwrites `x` with `(L Lᵀ)⁻¹ x` for a factor from [`factor`].
pub fn solve(envelope: &Envelope<'_>, factor: &[f64], inverse_diagonal: &[f64], x: &mut [f64]) {
    envelope.check(factor, inverse_diagonal);
    assert_eq!(x.len(), inverse_diagonal.len(), "one value per row");
    crate::lanes::dispatch(Solve { envelope, factor, inverse_diagonal, x });
}

/// The nine sums `S_rc = Σ_k a_r[k] b_c[k]` of three rows against three
/// rows of equal length, each in the order of [`dot`]; every loaded value
/// feeds three products.
#[inline(always)]
fn dot3x3(a: [&[f64]; 3], b: [&[f64]; 3]) -> [[f64; 3]; 3] {
    let len = a[0].len();
    let whole = len - len % LANES;
    for v in a.iter().chain(&b) {
        assert_eq!(v.len(), len, "rows of equal length");
    }
    let mut s = [[[0.0f64; LANES]; 3]; 3];
    for k in (0..whole).step_by(LANES) {
        let av = [chunk(a[0], k), chunk(a[1], k), chunk(a[2], k)];
        let bv = [chunk(b[0], k), chunk(b[1], k), chunk(b[2], k)];
        for r in 0..3 {
            for c in 0..3 {
                for l in 0..LANES {
                    s[r][c][l] += av[r][l] * bv[c][l];
                }
            }
        }
    }
    let mut out = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            let p = &s[r][c];
            let mut sum = (p[0] + p[2]) + (p[1] + p[3]);
            for k in whole..len {
                sum += a[r][k] * b[c][k];
            }
            out[r][c] = sum;
        }
    }
    out
}

/// `LANES` values of `v` from `k` (within bounds: the caller's loop ends
/// at a whole number of chunks), as one load. Gathered value by value
/// (`[v[k], v[k + 1], ..]`), the AVX2 build of [`dot3x3`] in the `cleave`
/// program shuffled them across its accumulators and spilled those to the
/// stack: its factorisation took twice the scalar reference's time
/// (`cleave bench --only simd`, 200 factors of 450 unknowns: 78 against
/// 41 ms, AMD EPYC Zen 4), now 35 against 39 ms (AVX-512 33 → 32 ms).
#[inline(always)]
fn chunk(v: &[f64], k: usize) -> [f64; LANES] {
    v[k..k + LANES].try_into().expect("a whole chunk")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lanes::levels;

    /// A symmetric positive definite matrix of `blocks` 3x3 blocks whose
    /// block row `I` reaches back to block `first_block(I)`, in the
    /// envelope layout, with its dense copy.
    fn banded(blocks: usize, first_block: impl Fn(usize) -> usize) -> (Vec<u32>, Vec<u32>, Vec<f64>, Vec<f64>) {
        let n = 3 * blocks;
        let first: Vec<u32> = (0..n).map(|i| 3 * first_block(i / 3) as u32).collect();
        let mut start = vec![0u32];
        for i in 0..n {
            start.push(start[i] + (i - first[i] as usize + 1) as u32);
        }
        let mut dense = vec![0.0; n * n];
        for i in 0..n {
            for j in first[i] as usize..=i {
                let v = if i == j { 6.0 + (i % 3) as f64 } else { -0.3 + 0.05 * ((i * 5 + j * 3) % 7) as f64 / 7.0 };
                dense[i * n + j] = v;
                dense[j * n + i] = v;
            }
        }
        let lower: Vec<f64> =
            (0..n).flat_map(|i| (first[i] as usize..=i).map(|j| dense[i * n + j]).collect::<Vec<_>>()).collect();
        (first, start, lower, dense)
    }

    #[test]
    fn factor_reproduces_the_matrix_and_solves_on_every_level_to_the_bit() {
        let blocks = 13;
        let (first, start, lower, dense) = banded(blocks, |b| b.saturating_sub(1 + b % 3));
        let n = 3 * blocks;
        let envelope = Envelope { first: &first, start: &start };
        let b: Vec<f64> = (0..n).map(|i| (0.3 * i as f64).cos()).collect();
        let mut results = Vec::new();
        for level in levels::available("envelope") {
            let (mut l, mut inv) = (lower.clone(), vec![0.0; n]);
            levels::run(level, Factor { envelope: &envelope, factor: &mut l, inverse_diagonal: &mut inv }).unwrap();
            let mut x = b.clone();
            levels::run(level, Solve { envelope: &envelope, factor: &l, inverse_diagonal: &inv, x: &mut x });
            results.push((l, x));
        }
        let (l, x) = &results[0];
        assert!(results.iter().all(|r| r == &results[0]), "every level gives the same bits");
        // L Lᵀ = A inside the envelope and A x = b
        let at = |i: usize, j: usize| {
            let f = first[i] as usize;
            if j < f || j > i {
                0.0
            } else {
                l[start[i] as usize + j - f]
            }
        };
        for i in 0..n {
            for j in 0..=i {
                let llt: f64 = (0..=j).map(|k| at(i, k) * at(j, k)).sum();
                assert!((llt - dense[i * n + j]).abs() < 1e-14, "(L Lᵀ)_{i}{j} = {llt}, A = {}", dense[i * n + j]);
            }
            let ax: f64 = (0..n).map(|j| dense[i * n + j] * x[j]).sum();
            assert!((ax - b[i]).abs() < 1e-13, "(A x)_{i} = {ax}, b = {}", b[i]);
        }
    }

    #[test]
    fn a_matrix_that_is_not_positive_definite_names_its_row() {
        let (first, start, mut lower, _) = banded(4, |_| 0);
        let envelope = Envelope { first: &first, start: &start };
        // a zero diagonal in block 2
        lower[start[7] as usize + 7] = 0.0;
        let mut inv = vec![0.0; 12];
        assert_eq!(factor(&envelope, &mut lower, &mut inv), Err(NotPositive { row: 7 }));
    }
}
