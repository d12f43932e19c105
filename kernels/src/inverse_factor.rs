//! The inverse `M = L⁻¹` of a dense Cholesky factor (`A = L Lᵀ`), stored
//! in tiles and rounded to `f32` (or kept in `f64`), and its application
//! `A⁻¹ v = Mᵀ (M v)`.
//!
//! A preconditioner made of such blocks stays symmetric positive definite
//! whatever the rounding (`M̃ᵀ M̃` is, for any rounded `M̃` with a nonzero
//! diagonal), and its application reads half the bytes of `f64` values,
//! with `f64` arithmetic throughout.
//!
//! Triangular solves with `L` itself are chains: each unknown waits for
//! the division and the sums of the one before it, and on a 106 x 106
//! block they ran at 5 GFlop/s (Intel Xeon, AVX-512). With the inverse,
//! both halves are products whose sums are independent of each other.
//!
//! Tiled: the lower triangle of `M` in 4 x 4 tiles, by tile columns, each
//! from its diagonal tile down, every tile column-major; the entries above
//! the diagonal and past the order `n` are zeros (`n` rounded up to a
//! multiple of four, [`padded`]). Then `w = M v` adds, per tile column,
//! its four columns times their four entries of `v` into each tile row of
//! `w` (one load and store of `w` per four columns), and `v = Mᵀ w` takes
//! four dot products per tile column at once, each in four running sums
//! (one per row of a tile) added in a fixed tree: whole registers, no
//! tails, and the same bits on every instruction set. Stored as packed
//! columns instead (each from its diagonal down, `n (n + 1) / 2` values),
//! the 98 blocks of order 54 of the clamped bunny_100k's coarse level took
//! 103.7 µs at AVX2 against 46.2 µs tiled (`f32`, one thread, best of 5,
//! Intel Xeon model 207): the columns' short stretches and per-column
//! tails cost more than the products.

use crate::lanes::{dispatched_level, SimdLevel};
use crate::spmv::Value;

/// The order of a tile.
const TILE: usize = 4;

/// The types a tiled inverse factor is stored in: `f32` (half the bytes,
/// for a preconditioner's blocks) or `f64` (for a solve that must be exact
/// to rounding).
pub trait Stored: Value {
    /// `x` rounded to the type.
    fn from_f64(x: f64) -> Self;
}

impl Stored for f32 {
    #[inline(always)]
    fn from_f64(x: f64) -> Self {
        x as f32
    }
}

impl Stored for f64 {
    #[inline(always)]
    fn from_f64(x: f64) -> Self {
        x
    }
}

/// `n` rounded up to whole tiles: the length of the vectors [`apply`]
/// works on.
pub fn padded(n: usize) -> usize {
    n.div_ceil(TILE) * TILE
}

/// Values of the tiled inverse of order `n`.
pub fn tiled_len(n: usize) -> usize {
    let tiles = n.div_ceil(TILE);
    TILE * TILE * tiles * (tiles + 1) / 2
}

/// Stores the lower triangle of the column-major `n x n` matrix `dense`
/// in `tiled` (at least [`tiled_len`]`(n)` long, see module docs), rounded
/// to `T`.
pub fn tile<T: Stored>(dense: &[f64], n: usize, tiled: &mut [T]) {
    let tiles = n.div_ceil(TILE);
    let mut at = 0;
    for c in 0..tiles {
        for r in c..tiles {
            for q in 0..TILE {
                for l in 0..TILE {
                    let (i, j) = (TILE * r + l, TILE * c + q);
                    let value = if i < n && j < n && i >= j { dense[j * n + i] } else { 0.0 };
                    tiled[at] = T::from_f64(value);
                    at += 1;
                }
            }
        }
    }
}

/// `v = Mᵀ (M v)` for the tiled inverse factor `m` of order `v.len()`;
/// `scratch` (at least `2 `[`padded`]`(v.len())` long) is overwritten.
pub fn apply<T: Stored>(m: &[T], v: &mut [f64], scratch: &mut [f64]) {
    let n = v.len();
    assert_eq!(m.len(), tiled_len(n), "a tiled inverse factor of the vector's order");
    assert!(scratch.len() >= 2 * padded(n), "scratch of twice the padded order");
    let (x, w) = scratch[..2 * padded(n)].split_at_mut(padded(n));
    x[..n].copy_from_slice(v);
    x[n..].fill(0.0);
    apply_at(dispatched_level(SimdLevel::Avx2), Apply { m, x, w });
    v.copy_from_slice(&x[..n]);
}

/// [`apply`] on the padded vector `x` at the instruction set `level`: the
/// generic kernel for scalar, [`avx2::apply`] at AVX2 and above.
fn apply_at<T: Stored>(level: SimdLevel, operands: Apply<'_, T>) {
    #[cfg(target_arch = "x86_64")]
    if level != SimdLevel::Scalar {
        let Apply { m, x, w } = operands;
        if let Some(m) = T::as_f32(m) {
            return avx2::apply(m, x, w);
        }
        if let Some(m) = T::as_f64(m) {
            return avx2::apply(m, x, w);
        }
        return level.run(Apply { m, x, w });
    }
    level.run(operands)
}

/// `x = Mᵀ (M x)` for the padded vector `x`, `w` its scratch.
struct Apply<'a, T> {
    m: &'a [T],
    x: &'a mut [f64],
    w: &'a mut [f64],
}

impl<T: Stored> pulp::WithSimd for Apply<'_, T> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let Apply { m, x, w } = self;
        let tiles = x.len() / TILE;
        let tile = |at: usize, q: usize, l: usize| m[at + TILE * q + l].to_f64();
        // w = M x: per tile column, its four columns in order into every
        // tile row
        w.fill(0.0);
        let mut at = 0;
        for c in 0..tiles {
            for r in c..tiles {
                for l in 0..TILE {
                    let mut s = w[TILE * r + l];
                    for q in 0..TILE {
                        s += tile(at, q, l) * x[TILE * c + q];
                    }
                    w[TILE * r + l] = s;
                }
                at += TILE * TILE;
            }
        }
        // x = Mᵀ w: per tile column, four dot products in four running sums
        at = 0;
        for c in 0..tiles {
            let mut sums = [[0.0f64; TILE]; TILE];
            for r in c..tiles {
                for (q, sum) in sums.iter_mut().enumerate() {
                    for l in 0..TILE {
                        sum[l] += tile(at, q, l) * w[TILE * r + l];
                    }
                }
                at += TILE * TILE;
            }
            for (q, sum) in sums.iter().enumerate() {
                x[TILE * c + q] = (sum[0] + sum[1]) + (sum[2] + sum[3]);
            }
        }
    }
}

/// [`Apply`] written with AVX2's instructions, in its order: the same bits.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::TILE;
    use crate::spmv::avx2::Lanes;
    use core::arch::x86_64::*;

    /// `x = Mᵀ (M x)` for the padded `x`; panics without AVX2.
    pub(super) fn apply<T: Lanes>(m: &[T], x: &mut [f64], w: &mut [f64]) {
        assert!(is_x86_feature_detected!("avx2"), "the AVX2 kernel runs where AVX2 is");
        let tiles = x.len() / TILE;
        assert!(x.len() % TILE == 0 && w.len() == x.len() && m.len() >= super::tiled_len(x.len()));
        // SAFETY: AVX2 is available, and every read and write below lies
        // within the tiles of `m` (checked above) and within `x` and `w`.
        unsafe { apply_avx2(m, x, w, tiles) }
    }

    #[target_feature(enable = "avx2")]
    unsafe fn apply_avx2<T: Lanes>(m: &[T], x: &mut [f64], w: &mut [f64], tiles: usize) {
        let (mp, xp, wp) = (m.as_ptr(), x.as_mut_ptr(), w.as_mut_ptr());
        w.fill(0.0);
        let mut at = 0;
        for c in 0..tiles {
            let scale: [__m256d; TILE] = core::array::from_fn(|q| _mm256_set1_pd(*xp.add(TILE * c + q)));
            for r in c..tiles {
                let mut s = _mm256_loadu_pd(wp.add(TILE * r));
                for (q, scale) in scale.iter().enumerate() {
                    s = _mm256_add_pd(s, _mm256_mul_pd(T::load4(mp.add(at + TILE * q)), *scale));
                }
                _mm256_storeu_pd(wp.add(TILE * r), s);
                at += TILE * TILE;
            }
        }
        at = 0;
        for c in 0..tiles {
            let mut sums = [_mm256_setzero_pd(); TILE];
            for r in c..tiles {
                let wr = _mm256_loadu_pd(wp.add(TILE * r));
                for (q, sum) in sums.iter_mut().enumerate() {
                    *sum = _mm256_add_pd(*sum, _mm256_mul_pd(T::load4(mp.add(at + TILE * q)), wr));
                }
                at += TILE * TILE;
            }
            // lane q: (sums[q]₀ + sums[q]₁) + (sums[q]₂ + sums[q]₃)
            let (low, high) = (_mm256_hadd_pd(sums[0], sums[1]), _mm256_hadd_pd(sums[2], sums[3]));
            let pairs = (_mm256_permute2f128_pd(low, high, 0x20), _mm256_permute2f128_pd(low, high, 0x31));
            _mm256_storeu_pd(xp.add(TILE * c), _mm256_add_pd(pairs.0, pairs.1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against the matrix it inverts: for `A` symmetric positive definite
    /// (orders filling their last tile, and not), `M` the inverse of its
    /// Cholesky factor, `A (Mᵀ M v)` gives `v` back to the rounding of `M`
    /// to `f32`, and to that of `f64` for `M` stored as `f64`, with the
    /// same bits on every instruction set.
    #[test]
    fn the_tiled_inverse_factor_inverts_the_matrix_on_every_level() {
        inverts_on_every_level::<f32>(1e-5);
        inverts_on_every_level::<f64>(1e-12);
    }

    fn inverts_on_every_level<T: Stored + Default>(tolerance: f64) {
        for n in [1, 3, 4, 5, 7, 8, 11, 30, 53, 54, 108] {
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
            let mut tiled = vec![T::default(); tiled_len(n)];
            tile(&inverse, n, &mut tiled);
            let rhs: Vec<f64> = (0..n).map(|i| (i as f64 * 0.61).cos()).collect();
            let mut bits = None;
            for level in crate::lanes::levels::available("inverse_factor") {
                let (mut x, mut w) = (rhs.clone(), vec![f64::NAN; padded(n)]);
                x.resize(padded(n), 0.0);
                // (AVX2 and above run the explicit kernel, scalar the generic
                // one: the bits compared below are the two kernels')
                apply_at(level, Apply { m: &tiled, x: &mut x, w: &mut w });
                let v = &x[..n];
                assert!(x[n..].iter().all(|&p| p == 0.0), "n {n}, {level:?}: the padding stays zero");
                let scale: f64 = rhs.iter().map(|x| x.abs()).fold(0.0, f64::max);
                for i in 0..n {
                    let back: f64 = (0..n).map(|k| a(i, k) * v[k]).sum();
                    assert!(
                        (back - rhs[i]).abs() < tolerance * scale,
                        "n {n}, {level:?}: row {i} gives {back} back for {}",
                        rhs[i]
                    );
                }
                let these: Vec<u64> = v.iter().map(|x| x.to_bits()).collect();
                // (the public entry point pads and copies back the same bits)
                let mut through = rhs.clone();
                apply(&tiled, &mut through, &mut vec![0.0; 2 * padded(n)]);
                assert!(level != crate::lanes::dispatched_level(SimdLevel::Avx2) || through == v, "n {n}: apply");
                assert_eq!(*bits.get_or_insert(these.clone()), these, "{level:?} differs from the first level");
            }
        }
    }
}
