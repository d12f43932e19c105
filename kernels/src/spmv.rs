//! The product `y = A x` of a symmetric matrix stored as compressed
//! columns in 3x3 blocks (each block column's three scalar columns share
//! one list of block rows) with a vector: the kernel of every conjugate
//! gradient iteration, bound by the matrix's memory traffic and, once that
//! is halved by `f32` values, by arithmetic.
//!
//! Block row `i` of block column `j` holds, in scalar column `3 j + c`, the
//! three entries `A[3 i + r][3 j + c]` one after the other; by symmetry
//! `y[3 j + c] = Σ_i Σ_r A[3 i + r][3 j + c] x[3 i + r]`: each scalar
//! column, a contiguous run of values, dotted with the same gathered
//! entries of `x`. The kernel gathers them once per block column (in
//! segments of at most `SEGMENT` block rows), then takes the three dot
//! products `LANES` values at a time, one running sum per lane, and adds
//! the lanes in a fixed order at the end: the same arithmetic in the same
//! order at every instruction set, so the same bits.
//!
//! The generic kernel (`Products`) is the reference and the scalar path.
//! With AVX2 the product runs `avx2::block_products` instead (and the
//! product with eight vectors `avx2::block_products_of_vectors`), the same
//! arithmetic written with the instructions themselves: the compiler's
//! vectorisation of the generic kernel took each column's tail one value
//! at a time and its horizontal sums through the stack, and the product
//! is bound by those instructions, not by the bytes it reads, once the
//! `f32` values fit in the last-level cache (on bunny_100k, 2.3M values,
//! 2 cores, Intel Xeon: 0.42 ms against 0.33 ms).

use crate::lanes::{dispatched_level, SimdLevel};

/// A stored matrix value: `f64`, or `f32` for half the memory traffic (the
/// sums are `f64` either way).
pub trait Value: Copy + Sync {
    /// The value as `f64` (exact).
    fn to_f64(self) -> f64;

    /// The values, when they are `f32`.
    fn as_f32(values: &[Self]) -> Option<&[f32]> {
        let _ = values;
        None
    }

    /// The values, when they are `f64`.
    fn as_f64(values: &[Self]) -> Option<&[f64]> {
        let _ = values;
        None
    }
}

impl Value for f64 {
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }

    fn as_f64(values: &[Self]) -> Option<&[f64]> {
        Some(values)
    }
}

impl Value for f32 {
    #[inline(always)]
    fn to_f64(self) -> f64 {
        f64::from(self)
    }

    fn as_f32(values: &[Self]) -> Option<&[f32]> {
        Some(values)
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
/// summed in order.
pub fn block_products<T: Value>(
    structure: BlockColumns<'_>,
    values: &[T],
    x: &[f64],
    first: usize,
    y: &mut [f64],
) -> f64 {
    products_at(dispatched_level(SimdLevel::Avx2), Operands { structure, values, x, first, y })
}

/// [`block_products`] at the instruction set `level`: the generic kernel
/// for scalar, [`avx2::block_products`] at AVX2 and above (its code is
/// AVX2's: wider registers did not speed the product up).
fn products_at<T: Value>(level: SimdLevel, operands: Operands<'_, T>) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if level != SimdLevel::Scalar {
        let Operands { structure, values, x, first, y } = operands;
        if let Some(values) = T::as_f32(values) {
            return avx2::block_products(structure, values, x, first, y);
        }
        if let Some(values) = T::as_f64(values) {
            return avx2::block_products(structure, values, x, first, y);
        }
        return level.run(Products(Operands { structure, values, x, first, y }));
    }
    level.run(Products(operands))
}

/// Lanes of the running sums of a column's dot product (the width of an
/// AVX-512 vector of `f64`, two of AVX2).
const LANES: usize = 8;

/// Block rows gathered at a time (a column's `x` entries on the stack).
const SEGMENT: usize = 64;

/// A product's operands: `y` takes the block columns `first..` of
/// `values` on `structure` times `x`.
struct Operands<'a, T> {
    structure: BlockColumns<'a>,
    values: &'a [T],
    x: &'a [f64],
    first: usize,
    y: &'a mut [f64],
}

impl<'a> BlockColumns<'a> {
    /// Block column `j`'s block rows and values (scalar column `c` at
    /// `[c * 3 rows..(c + 1) * 3 rows]`).
    #[inline(always)]
    fn column<'v, T>(&self, j: usize, values: &'v [T]) -> (&'a [u32], &'v [T]) {
        let rows = &self.rows[self.ptr[j] as usize..self.ptr[j + 1] as usize];
        (rows, &values[self.start[j]..self.start[j] + 9 * rows.len()])
    }
}

/// The product with one vector.
struct Products<'a, T>(Operands<'a, T>);

impl<T: Value> pulp::WithSimd for Products<'_, T> {
    type Output = f64;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> f64 {
        let Operands { structure, values, x, first, y } = self.0;
        let mut dot = 0.0;
        let mut gathered = [0.0f64; 3 * SEGMENT];
        for (q, yj) in y.chunks_exact_mut(3).enumerate() {
            let j = first + q;
            let (rows, column) = structure.column(j, values);
            let stride = 3 * rows.len();
            let mut acc = [[0.0f64; LANES]; 3];
            for (s, segment) in rows.chunks(SEGMENT).enumerate() {
                let n = 3 * segment.len();
                for (g, &i) in gathered.chunks_exact_mut(3).zip(segment) {
                    let i = 3 * i as usize;
                    g.copy_from_slice(&x[i..i + 3]);
                }
                let offset = 3 * SEGMENT * s;
                for (c, acc) in acc.iter_mut().enumerate() {
                    let v = &column[c * stride + offset..c * stride + offset + n];
                    let (v_lanes, v_tail) = v.split_at(n - n % LANES);
                    let (g_lanes, g_tail) = gathered[..n].split_at(n - n % LANES);
                    for (v, g) in v_lanes.chunks_exact(LANES).zip(g_lanes.chunks_exact(LANES)) {
                        for l in 0..LANES {
                            acc[l] += v[l].to_f64() * g[l];
                        }
                    }
                    for ((a, v), g) in acc.iter_mut().zip(v_tail).zip(g_tail) {
                        *a += v.to_f64() * g;
                    }
                }
            }
            for (out, a) in yj.iter_mut().zip(acc) {
                *out = ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
            }
            dot += x[3 * j] * yj[0] + x[3 * j + 1] * yj[1] + x[3 * j + 2] * yj[2];
        }
        dot
    }
}

/// Vectors a multi-vector product takes at once (the width of an AVX-512
/// vector of `f64`).
pub const VECTORS: usize = 8;

/// `Y = A X` for [`VECTORS`] vectors at once, stored interleaved (entry
/// `i` of vector `k` at `x[VECTORS * i + k]`, and so `y`), for the block
/// columns `first..first + y.len() / (3 VECTORS)` of `values` on
/// `structure`: one read of the matrix for all of them, each value
/// multiplying the vectors' entries side by side. Each output's sum runs
/// over the column's values in order; the same bits on every instruction
/// set.
pub fn block_products_of_vectors<T: Value>(
    structure: BlockColumns<'_>,
    values: &[T],
    x: &[f64],
    first: usize,
    y: &mut [f64],
) {
    vector_products_at(dispatched_level(SimdLevel::Avx2), Operands { structure, values, x, first, y })
}

/// [`block_products_of_vectors`] at the instruction set `level`: the
/// generic kernel for scalar, [`avx2::block_products_of_vectors`] at AVX2
/// and above (AVX-512's registers, one per row of the eight vectors, made
/// it no faster: 0.78 against 0.81 ms on bunny_100k, Intel Xeon).
fn vector_products_at<T: Value>(level: SimdLevel, operands: Operands<'_, T>) {
    #[cfg(target_arch = "x86_64")]
    if level != SimdLevel::Scalar {
        let Operands { structure, values, x, first, y } = operands;
        if let Some(values) = T::as_f32(values) {
            return avx2::block_products_of_vectors(structure, values, x, first, y);
        }
        if let Some(values) = T::as_f64(values) {
            return avx2::block_products_of_vectors(structure, values, x, first, y);
        }
        return level.run(VectorProducts(Operands { structure, values, x, first, y }));
    }
    level.run(VectorProducts(operands))
}

/// The product with [`VECTORS`] interleaved vectors.
struct VectorProducts<'a, T>(Operands<'a, T>);

impl<T: Value> pulp::WithSimd for VectorProducts<'_, T> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let Operands { structure, values, x, first, y } = self.0;
        for (q, yj) in y.chunks_exact_mut(3 * VECTORS).enumerate() {
            let (rows, column) = structure.column(first + q, values);
            let stride = 3 * rows.len();
            // acc[c]: scalar column c's sums (three independent chains of
            // additions, which AVX2's sixteen registers hold too)
            let mut acc = [[0.0f64; VECTORS]; 3];
            for (t, &i) in rows.iter().enumerate() {
                let i = 3 * VECTORS * i as usize;
                let xi: &[f64; 3 * VECTORS] = x[i..i + 3 * VECTORS].try_into().expect("three rows of vectors");
                for r in 0..3 {
                    let xr: &[f64; VECTORS] = xi[r * VECTORS..(r + 1) * VECTORS].try_into().expect("one row");
                    for (c, acc) in acc.iter_mut().enumerate() {
                        let a = column[c * stride + 3 * t + r].to_f64();
                        for k in 0..VECTORS {
                            acc[k] += a * xr[k];
                        }
                    }
                }
            }
            for (out, acc) in yj.chunks_exact_mut(VECTORS).zip(acc) {
                out.copy_from_slice(&acc);
            }
        }
    }
}

/// The block product written with AVX2's instructions: [`Products`]'s
/// arithmetic in its order (lane `l` of the eight sums takes a segment's
/// values `l, l + 8, …` by a multiplication and an addition, never fused;
/// the lanes are added as `((s₀ + s₁) + (s₂ + s₃)) + ((s₄ + s₅) + (s₆ +
/// s₇))`), so the same bits. Each column's last values are read by a masked
/// load and multiplied by gathered entries padded with zeros: a lane adds
/// `+0` there, which leaves every sum as it was (a sum that starts at `+0`
/// is never `-0`).
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2 {
    use super::{BlockColumns, LANES, SEGMENT, VECTORS};
    use core::arch::x86_64::*;

    /// Values that load as two vectors of four `f64`.
    pub(crate) trait Lanes: super::Value {
        /// Values `p[0..8]` as `f64`.
        ///
        /// # Safety
        /// AVX2 is available and `p[0..8]` is readable.
        unsafe fn load(p: *const Self) -> (__m256d, __m256d);

        /// Values `p[0..count]` as `f64`, zeros after, reading only those.
        ///
        /// # Safety
        /// AVX2 is available, `p[0..count]` is readable and `count < 8`.
        unsafe fn load_first(p: *const Self, count: usize) -> (__m256d, __m256d);

        /// Values `p[0..4]` as `f64`.
        ///
        /// # Safety
        /// AVX2 is available and `p[0..4]` is readable.
        unsafe fn load4(p: *const Self) -> __m256d;
    }

    /// Lane masks: the last `8 - count` entries of `MASK[8 - count..]`
    /// select the first `count` lanes.
    const MASK: [i32; 16] = [-1, -1, -1, -1, -1, -1, -1, -1, 0, 0, 0, 0, 0, 0, 0, 0];
    const MASK64: [i64; 16] = [-1, -1, -1, -1, -1, -1, -1, -1, 0, 0, 0, 0, 0, 0, 0, 0];

    impl Lanes for f32 {
        #[inline(always)]
        unsafe fn load(p: *const f32) -> (__m256d, __m256d) {
            let v = _mm256_loadu_ps(p);
            (_mm256_cvtps_pd(_mm256_castps256_ps128(v)), _mm256_cvtps_pd(_mm256_extractf128_ps(v, 1)))
        }

        #[inline(always)]
        unsafe fn load_first(p: *const f32, count: usize) -> (__m256d, __m256d) {
            let mask = _mm256_loadu_si256(MASK.as_ptr().add(8 - count).cast());
            let v = _mm256_maskload_ps(p, mask);
            (_mm256_cvtps_pd(_mm256_castps256_ps128(v)), _mm256_cvtps_pd(_mm256_extractf128_ps(v, 1)))
        }

        #[inline(always)]
        unsafe fn load4(p: *const f32) -> __m256d {
            _mm256_cvtps_pd(_mm_loadu_ps(p))
        }
    }

    impl Lanes for f64 {
        #[inline(always)]
        unsafe fn load(p: *const f64) -> (__m256d, __m256d) {
            (_mm256_loadu_pd(p), _mm256_loadu_pd(p.add(4)))
        }

        #[inline(always)]
        unsafe fn load_first(p: *const f64, count: usize) -> (__m256d, __m256d) {
            let low = _mm256_loadu_si256(MASK64.as_ptr().add(8 - count).cast());
            let high = _mm256_loadu_si256(MASK64.as_ptr().add(12 - count).cast());
            (_mm256_maskload_pd(p, low), _mm256_maskload_pd(p.add(4), high))
        }

        #[inline(always)]
        unsafe fn load4(p: *const f64) -> __m256d {
            _mm256_loadu_pd(p)
        }
    }

    /// `y_j = (A x)_j` and `Σ_j x_j · y_j` as [`super::block_products`]
    /// computes them; panics without AVX2.
    pub(crate) fn block_products<T: Lanes>(
        structure: BlockColumns<'_>,
        values: &[T],
        x: &[f64],
        first: usize,
        y: &mut [f64],
    ) -> f64 {
        assert!(is_x86_feature_detected!("avx2"), "the AVX2 product runs where AVX2 is");
        // SAFETY: AVX2 is available; every column's values are a checked
        // slice and every gathered row of `x` is checked before it is read.
        unsafe { products(structure, values, x, first, y) }
    }

    /// The sum of the eight lanes `low`, `high` in [`Products`]'s order,
    /// `((s₀ + s₁) + (s₂ + s₃)) + ((s₄ + s₅) + (s₆ + s₇))`.
    ///
    /// # Safety
    /// AVX2 is available.
    ///
    /// [`Products`]: super::Products
    #[inline(always)]
    pub(crate) unsafe fn lane_sum(low: __m256d, high: __m256d) -> f64 {
        // [s0 + s1, s4 + s5, s2 + s3, s6 + s7]
        let pairs = _mm256_hadd_pd(low, high);
        // [(s0 + s1) + (s2 + s3), (s4 + s5) + (s6 + s7)]
        let halves = _mm_add_pd(_mm256_castpd256_pd128(pairs), _mm256_extractf128_pd(pairs, 1));
        _mm_cvtsd_f64(_mm_add_sd(halves, _mm_unpackhi_pd(halves, halves)))
    }

    #[target_feature(enable = "avx2")]
    unsafe fn products<T: Lanes>(
        structure: BlockColumns<'_>,
        values: &[T],
        x: &[f64],
        first: usize,
        y: &mut [f64],
    ) -> f64 {
        let mut dot = 0.0;
        // a segment's gathered entries and a lane group of zeros after them
        let mut gathered = [0.0f64; 3 * SEGMENT + LANES + 1];
        let g = gathered.as_mut_ptr();
        let xp = x.as_ptr();
        for (q, yj) in y.chunks_exact_mut(3).enumerate() {
            let j = first + q;
            let (rows, column) = structure.column(j, values);
            let stride = 3 * rows.len();
            let mut sums = [[_mm256_setzero_pd(); 2]; 3];
            for (s, segment) in rows.chunks(SEGMENT).enumerate() {
                let n = 3 * segment.len();
                for (t, &i) in segment.iter().enumerate() {
                    let i = 3 * i as usize;
                    // (four entries where the vector has a fourth; the next
                    // row overwrites it)
                    if i + 4 <= x.len() {
                        _mm256_storeu_pd(g.add(3 * t), _mm256_loadu_pd(xp.add(i)));
                    } else {
                        g.add(3 * t).copy_from_nonoverlapping(x[i..i + 3].as_ptr(), 3);
                    }
                }
                _mm256_storeu_pd(g.add(n), _mm256_setzero_pd());
                _mm256_storeu_pd(g.add(n + 4), _mm256_setzero_pd());
                let values = column.as_ptr().add(3 * SEGMENT * s);
                let full = n - n % LANES;
                let mut add = |e: usize, loaded: [(__m256d, __m256d); 3]| {
                    let (low, high) = (_mm256_loadu_pd(g.add(e)), _mm256_loadu_pd(g.add(e + 4)));
                    for (sum, (a, b)) in sums.iter_mut().zip(loaded) {
                        sum[0] = _mm256_add_pd(sum[0], _mm256_mul_pd(a, low));
                        sum[1] = _mm256_add_pd(sum[1], _mm256_mul_pd(b, high));
                    }
                };
                for e in (0..full).step_by(LANES) {
                    add(e, [0, 1, 2].map(|c| T::load(values.add(c * stride + e))));
                }
                if full < n {
                    add(full, [0, 1, 2].map(|c| T::load_first(values.add(c * stride + full), n - full)));
                }
            }
            for (out, [low, high]) in yj.iter_mut().zip(sums) {
                *out = lane_sum(low, high);
            }
            dot += x[3 * j] * yj[0] + x[3 * j + 1] * yj[1] + x[3 * j + 2] * yj[2];
        }
        dot
    }

    /// `Y = A X` as [`super::block_products_of_vectors`] computes it;
    /// panics without AVX2.
    pub(crate) fn block_products_of_vectors<T: Lanes>(
        structure: BlockColumns<'_>,
        values: &[T],
        x: &[f64],
        first: usize,
        y: &mut [f64],
    ) {
        assert!(is_x86_feature_detected!("avx2"), "the AVX2 product runs where AVX2 is");
        // SAFETY: AVX2 is available; every column's values are a checked
        // slice and every row of `x` is checked before it is read.
        unsafe { vector_products(structure, values, x, first, y) }
    }

    /// [`super::VectorProducts`]'s arithmetic in its order. A segment's
    /// values are first converted to `f64` on the stack, eight at a time,
    /// so that each is then broadcast by a load alone: converting and
    /// broadcasting each value from a register took two shuffle-port
    /// instructions per value, the product's bottleneck (0.82-0.92 against
    /// 0.97-0.99 ms on bunny_100k, 2 threads, Intel Xeon; 1.36 against 1.66
    /// ms on one thread, `cleave bench --only simd`).
    #[target_feature(enable = "avx2")]
    unsafe fn vector_products<T: Lanes>(
        structure: BlockColumns<'_>,
        values: &[T],
        x: &[f64],
        first: usize,
        y: &mut [f64],
    ) {
        // each scalar column's values of a segment, as f64 (whole lane
        // groups: the last one's zeros fit, as a segment's length is a
        // multiple of LANES)
        const { assert!(3 * SEGMENT % LANES == 0) };
        let mut converted = [[0.0f64; 3 * SEGMENT]; 3];
        for (q, yj) in y.chunks_exact_mut(3 * VECTORS).enumerate() {
            let (rows, column) = structure.column(first + q, values);
            let stride = 3 * rows.len();
            let mut sums = [[_mm256_setzero_pd(); 2]; 3];
            for (s, segment) in rows.chunks(SEGMENT).enumerate() {
                let n = 3 * segment.len();
                for (c, converted) in converted.iter_mut().enumerate() {
                    let (from, to) = (column.as_ptr().add(c * stride + 3 * SEGMENT * s), converted.as_mut_ptr());
                    for e in (0..n).step_by(LANES) {
                        let (low, high) = match n - e {
                            left if left < LANES => T::load_first(from.add(e), left),
                            _ => T::load(from.add(e)),
                        };
                        _mm256_storeu_pd(to.add(e), low);
                        _mm256_storeu_pd(to.add(e + 4), high);
                    }
                }
                for (t, &i) in segment.iter().enumerate() {
                    let xi = &x[3 * VECTORS * i as usize..3 * VECTORS * (i as usize + 1)];
                    for r in 0..3 {
                        let low = _mm256_loadu_pd(xi.as_ptr().add(r * VECTORS));
                        let high = _mm256_loadu_pd(xi.as_ptr().add(r * VECTORS + 4));
                        for (sum, converted) in sums.iter_mut().zip(&converted) {
                            let a = _mm256_broadcast_sd(&converted[3 * t + r]);
                            sum[0] = _mm256_add_pd(sum[0], _mm256_mul_pd(a, low));
                            sum[1] = _mm256_add_pd(sum[1], _mm256_mul_pd(a, high));
                        }
                    }
                }
            }
            for (out, [low, high]) in yj.chunks_exact_mut(VECTORS).zip(sums) {
                _mm256_storeu_pd(out.as_mut_ptr(), low);
                _mm256_storeu_pd(out.as_mut_ptr().add(4), high);
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A matrix as block columns (see [`BlockColumns`]) and dense.
    pub(crate) struct Ring {
        pub ptr: Vec<u32>,
        pub rows: Vec<u32>,
        pub start: Vec<usize>,
        pub values: Vec<f64>,
        pub dense: Vec<Vec<f64>>,
    }

    /// A symmetric matrix of 3x3 blocks on a ring of `n` blocks, each
    /// coupled to itself and its `reach` neighbours on either side.
    pub(crate) fn ring(n: usize, reach: usize) -> Ring {
        let mut dense = vec![vec![0.0; 3 * n]; 3 * n];
        let entry = |i: usize, j: usize| ((i * 7 + j * 13) % 11) as f64 - 5.0 + 0.25 * (i + j) as f64;
        for bj in 0..n {
            for bi in (0..=reach).flat_map(|d| [(bj + d) % n, (bj + n - d) % n]) {
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
            let mut r: Vec<u32> =
                (0..=reach).flat_map(|d| [((bj + d) % n) as u32, ((bj + n - d) % n) as u32]).collect();
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
    /// ranges of block columns as the solver splits them: block columns of
    /// 3 block rows (9 values, one lane group and a tail), 13 and 131 (more
    /// than two segments).
    #[test]
    fn products_match_the_dense_matrix_on_every_level() {
        for (n, reach) in [(7, 1), (20, 6), (140, 65)] {
            products_match_the_dense_matrix(n, reach);
        }
    }

    /// The vectors' products against the dense one of each vector, for
    /// `f64` and `f32` values, with the same bits on every level.
    #[test]
    fn products_of_vectors_match_the_dense_matrix_on_every_level() {
        for (n, reach) in [(7, 1), (20, 6), (140, 65)] {
            let Ring { ptr, rows, start, values, dense } = ring(n, reach);
            let structure = BlockColumns { ptr: &ptr, rows: &rows, start: &start };
            let x: Vec<f64> = (0..3 * n * VECTORS).map(|i| (i as f64 * 0.37).sin()).collect();
            let values32: Vec<f32> = values.iter().map(|&v| v as f32).collect();
            let mut bits = None;
            for level in crate::lanes::levels::available("spmv") {
                let (mut y, mut y32) = (vec![0.0; 3 * n * VECTORS], vec![0.0; 3 * n * VECTORS]);
                // (in two ranges of block columns, as the solver splits them)
                let (head, tail) = y.split_at_mut(9 * VECTORS);
                // (AVX2 and above run the explicit kernel, scalar the
                // generic one)
                vector_products_at(level, Operands { structure, values: &values, x: &x, first: 0, y: head });
                vector_products_at(level, Operands { structure, values: &values, x: &x, first: 3, y: tail });
                vector_products_at(level, Operands { structure, values: &values32, x: &x, first: 0, y: &mut y32 });
                for (i, row) in dense.iter().enumerate() {
                    for k in 0..VECTORS {
                        let terms = row.iter().enumerate().map(|(j, a)| a * x[VECTORS * j + k]);
                        let (want, scale) = terms.fold((0.0, 0.0), |(s, m), t| (s + t, m + f64::abs(t)));
                        let (got, got32) = (y[VECTORS * i + k], y32[VECTORS * i + k]);
                        assert!((got - want).abs() <= 1e-14 * scale, "{level:?}: y[{i}][{k}] = {got}, dense {want}");
                        assert!((got32 - want).abs() <= 1e-7 * scale, "{level:?}: f32 {got32}, dense {want}");
                    }
                }
                let these: Vec<u64> = y.iter().chain(&y32).map(|v| v.to_bits()).collect();
                assert_eq!(*bits.get_or_insert(these.clone()), these, "{level:?} differs from the first level");
            }
        }
    }

    fn products_match_the_dense_matrix(n: usize, reach: usize) {
        let Ring { ptr, rows, start, values, dense } = ring(n, reach);
        let structure = BlockColumns { ptr: &ptr, rows: &rows, start: &start };
        let x: Vec<f64> = (0..3 * n).map(|i| (i as f64 * 0.7).sin()).collect();
        let want: Vec<f64> = dense.iter().map(|row| row.iter().zip(&x).map(|(a, b)| a * b).sum()).collect();
        // the rounding scale of each row's sum: Σ |a_ij x_j|
        let scale: Vec<f64> = dense.iter().map(|row| row.iter().zip(&x).map(|(a, b)| (a * b).abs()).sum()).collect();
        let values32: Vec<f32> = values.iter().map(|&v| v as f32).collect();
        let mut bits = None;
        for level in crate::lanes::levels::available("spmv") {
            let (mut y, mut y32) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
            let (head, tail) = y.split_at_mut(9);
            // (AVX2 and above run the explicit kernel, scalar the generic
            // one: the bits compared below are the two kernels')
            let dot = products_at(level, Operands { structure, values: &values, x: &x, first: 0, y: head })
                + products_at(level, Operands { structure, values: &values, x: &x, first: 3, y: tail });
            products_at(level, Operands { structure, values: &values32, x: &x, first: 0, y: &mut y32 });
            for (i, ((&got, &w), &scale)) in y.iter().zip(&want).zip(&scale).enumerate() {
                assert!((got - w).abs() <= 1e-14 * scale, "{level:?}: y[{i}] = {got}, dense {w}");
                // (each value rounded to f32 by at most 2⁻²⁴ of itself)
                assert!((y32[i] - w).abs() <= 1e-7 * scale, "{level:?}: f32 y[{i}] = {}, dense {w}", y32[i]);
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
