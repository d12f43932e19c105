//! The inverse `M = L⁻¹` of a dense Cholesky factor (`A = L Lᵀ`), stored
//! packed and rounded to `f32`, and its application `A⁻¹ v = Mᵀ (M v)`.
//!
//! Packed: the lower triangle of `M` by columns, each from its diagonal
//! down, `n (n + 1) / 2` values. A preconditioner made of such blocks
//! stays symmetric positive definite whatever the rounding (`M̃ᵀ M̃` is,
//! for any rounded `M̃` with a nonzero diagonal), and its application
//! reads half the bytes of `f64` values, with `f64` arithmetic throughout.
//!
//! Triangular solves with `L` itself are chains: each unknown waits for
//! the division and the sums of the one before it, and on a 106 x 106
//! block they ran at 5 GFlop/s (Intel Xeon, AVX-512). With the inverse,
//! `w = M v` adds column `j` times `v_j` into `w` (independent updates),
//! and `(Mᵀ w)_j` is the dot product of column `j` with `w` from `j` down
//! (independent of the other columns'), in eight running sums added in
//! a fixed tree, then the tail: the same bits on every instruction set,
//! under runtime dispatch so that those sums fill wide registers.

use crate::lanes::{dispatched_level, SimdLevel};

/// Running sums of the dot products.
const LANES: usize = 8;

/// Values of the packed inverse of order `n`.
pub fn packed_len(n: usize) -> usize {
    n * (n + 1) / 2
}

/// Packs the lower triangle of the column-major `n x n` matrix `dense`
/// into `packed` (at least [`packed_len`]`(n)` long), rounded to `f32`.
pub fn pack(dense: &[f64], n: usize, packed: &mut [f32]) {
    let lower = (0..n).flat_map(|j| &dense[j * n + j..(j + 1) * n]);
    packed[..packed_len(n)].iter_mut().zip(lower).for_each(|(p, &l)| *p = l as f32);
}

/// `v = Mᵀ (M v)` for the packed inverse factor `m` of order `v.len()`;
/// `w` (as long as `v`) is scratch.
pub fn apply(m: &[f32], v: &mut [f64], w: &mut [f64]) {
    assert_eq!(m.len(), packed_len(v.len()), "a packed inverse factor of the vector's order");
    assert_eq!(w.len(), v.len(), "scratch of the vector's length");
    apply_at(dispatched_level(SimdLevel::Avx2), Apply { m, v, w })
}

/// [`apply`] at the instruction set `level`: the generic kernel for
/// scalar, [`avx2::apply`] at AVX2 and above (the compiler's vectorisation
/// of the generic dot products went through shuffles of two lanes at a
/// time: 6 GFlop/s on 106 x 106 blocks).
fn apply_at(level: SimdLevel, operands: Apply<'_>) {
    #[cfg(target_arch = "x86_64")]
    if level != SimdLevel::Scalar {
        let Apply { m, v, w } = operands;
        return avx2::apply(m, v, w);
    }
    level.run(operands)
}

struct Apply<'a> {
    m: &'a [f32],
    v: &'a mut [f64],
    w: &'a mut [f64],
}

impl pulp::WithSimd for Apply<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let Apply { m, v, w } = self;
        let n = v.len();
        // w = M v, column by column
        w.fill(0.0);
        let mut at = 0;
        for (j, &vj) in v.iter().enumerate() {
            let column = &m[at..at + n - j];
            at += n - j;
            for (w, &m) in w[j..].iter_mut().zip(column) {
                *w += f64::from(m) * vj;
            }
        }
        // v = Mᵀ w, a dot product per column
        at = 0;
        for (j, vj) in v.iter_mut().enumerate() {
            let (column, below) = (&m[at..at + n - j], &w[j..]);
            at += n - j;
            let (mc, bc) = (column.chunks_exact(LANES), below.chunks_exact(LANES));
            let mut tail = 0.0;
            for (&m, b) in mc.remainder().iter().zip(bc.remainder()) {
                tail += f64::from(m) * b;
            }
            let mut sums = [0.0f64; LANES];
            for (m, b) in mc.zip(bc) {
                for q in 0..LANES {
                    sums[q] += f64::from(m[q]) * b[q];
                }
            }
            *vj = (((sums[0] + sums[1]) + (sums[2] + sums[3])) + ((sums[4] + sums[5]) + (sums[6] + sums[7]))) + tail;
        }
    }
}

/// [`Apply`] written with AVX2's instructions, in its order: the same bits.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{packed_len, LANES};
    use crate::spmv::avx2::{lane_sum, Lanes};
    use core::arch::x86_64::*;

    /// `v = Mᵀ (M v)`; panics without AVX2.
    pub(super) fn apply(m: &[f32], v: &mut [f64], w: &mut [f64]) {
        assert!(is_x86_feature_detected!("avx2"), "the AVX2 kernel runs where AVX2 is");
        assert!(m.len() >= packed_len(v.len()) && w.len() >= v.len());
        // SAFETY: AVX2 is available, and every read and write below lies
        // within the columns of `m` (checked above) and within `v` and `w`.
        unsafe { apply_avx2(m, v, w) }
    }

    #[target_feature(enable = "avx2")]
    unsafe fn apply_avx2(m: &[f32], v: &mut [f64], w: &mut [f64]) {
        let n = v.len();
        let (mp, wp) = (m.as_ptr(), w.as_mut_ptr());
        w[..n].fill(0.0);
        let mut at = 0;
        for j in 0..n {
            let (len, vj) = (n - j, v[j]);
            let (column, wj) = (mp.add(at), wp.add(j));
            let scale = _mm256_set1_pd(vj);
            let full = len - len % 4;
            for i in (0..full).step_by(4) {
                let product = _mm256_mul_pd(_mm256_cvtps_pd(_mm_loadu_ps(column.add(i))), scale);
                _mm256_storeu_pd(wj.add(i), _mm256_add_pd(_mm256_loadu_pd(wj.add(i)), product));
            }
            for i in full..len {
                *wj.add(i) += f64::from(*column.add(i)) * vj;
            }
            at += len;
        }
        at = 0;
        for (j, vj) in v.iter_mut().enumerate() {
            let len = n - j;
            let (column, wj) = (mp.add(at), wp.add(j));
            let full = len - len % LANES;
            let mut tail = 0.0;
            for i in full..len {
                tail += f64::from(*column.add(i)) * *wj.add(i);
            }
            let (mut low, mut high) = (_mm256_setzero_pd(), _mm256_setzero_pd());
            for i in (0..full).step_by(LANES) {
                let (a, b) = f32::load(column.add(i));
                low = _mm256_add_pd(low, _mm256_mul_pd(a, _mm256_loadu_pd(wj.add(i))));
                high = _mm256_add_pd(high, _mm256_mul_pd(b, _mm256_loadu_pd(wj.add(i + 4))));
            }
            *vj = lane_sum(low, high) + tail;
            at += len;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against the matrix it inverts: for `A` symmetric positive definite
    /// (orders with and without a tail of the running sums), `M` the
    /// inverse of its Cholesky factor, `A (Mᵀ M v)` gives `v` back to the
    /// rounding of `M` to `f32`, with the same bits on every instruction
    /// set.
    #[test]
    fn the_packed_inverse_factor_inverts_the_matrix_on_every_level() {
        for n in [1, 7, 8, 30, 53] {
            // A = B Bᵀ + n I
            let b = |i: usize, j: usize| ((i * 7 + j * 3) % 5) as f64 - 2.0;
            let a = |i: usize, j: usize| {
                (0..n).map(|k| b(i, k) * b(j, k)).sum::<f64>() + if i == j { n as f64 } else { 0.0 }
            };
            // its lower Cholesky factor L, then M = L⁻¹, column-major
            let mut l = vec![0.0; n * n];
            for j in 0..n {
                for i in j..n {
                    let s = a(i, j) - (0..j).map(|k| l[k * n + i] * l[k * n + j]).sum::<f64>();
                    l[j * n + i] = if i == j { s.sqrt() } else { s / l[j * n + j] };
                }
            }
            let mut inverse = vec![0.0; n * n];
            for j in 0..n {
                inverse[j * n + j] = 1.0 / l[j * n + j];
                for i in j + 1..n {
                    let s: f64 = (j..i).map(|k| l[k * n + i] * inverse[j * n + k]).sum();
                    inverse[j * n + i] = -s / l[i * n + i];
                }
            }
            let mut packed = vec![0.0f32; packed_len(n)];
            pack(&inverse, n, &mut packed);
            let rhs: Vec<f64> = (0..n).map(|i| (i as f64 * 0.61).cos()).collect();
            let mut bits = None;
            for level in crate::lanes::levels::available("inverse_factor") {
                let (mut v, mut w) = (rhs.clone(), vec![0.0; n]);
                // (AVX2 and above run the explicit kernel, scalar the generic
                // one: the bits compared below are the two kernels')
                apply_at(level, Apply { m: &packed, v: &mut v, w: &mut w });
                let scale: f64 = rhs.iter().map(|x| x.abs()).fold(0.0, f64::max);
                for i in 0..n {
                    let back: f64 = (0..n).map(|k| a(i, k) * v[k]).sum();
                    assert!(
                        (back - rhs[i]).abs() < 1e-5 * scale,
                        "n {n}, {level:?}: row {i} gives {back} back for {}",
                        rhs[i]
                    );
                }
                let these: Vec<u64> = v.iter().map(|x| x.to_bits()).collect();
                assert_eq!(*bits.get_or_insert(these.clone()), these, "{level:?} differs from the first level");
            }
        }
    }
}
