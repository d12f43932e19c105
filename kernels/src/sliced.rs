//! The product `y = A x` of a symmetric matrix of 3x3 blocks stored
//! sliced: block columns side by side in groups of [`LANES`], so that one
//! SIMD lane runs down each column of a group (sliced ELLPACK, "SELL-C-σ"
//! of Kreutzer et al. 2014, with C = 8 and σ = [`WINDOW`]).
//!
//! The layout of [`crate::spmv`] keeps each block column's values
//! contiguous; its product takes three short dot products per column,
//! whose gathers, lane sums and tails cost more than the bytes it reads
//! (on bunny_100k, 255k blocks in `f32`, 2 cores, Intel Xeon with a
//! 260 MB L3: 18 GB/s, where the cache serves 55). Here a group's `s`-th
//! slot holds the `s`-th block of each of its columns: the 9 values of
//! lane `l` at `values[(9 s + 3 c + r) LANES + l]` (the entry
//! `A[3 i + r][3 j + c]` of block row `i`, column `j`), and `3 i` at
//! `rows[s LANES + l]`. One slot takes three vectors of `x` (rows `3 i`,
//! `3 i + 1`, `3 i + 2` of each lane, pairs of loads interleaved) and
//! nine products of whole vectors, no sums across lanes:
//!
//! ```text
//! y[3 j + c] = Σ_slots Σ_r A[3 i + r][3 j + c] x[3 i + r]
//! ```
//!
//! A group is as long as its longest column; the shorter ones are padded
//! with zero blocks on their own row. To keep that padding small, the
//! columns of each window of [`WINDOW`] columns are dealt to the lanes
//! longest first (on bunny_100k in the solver's numbering: 7.7% padding,
//! against 23% in the given order). The order within a window is the
//! layout's alone: the product writes each lane's sums to its own column.
//!
//! Every lane sums its column's terms in one fixed order, the even slots
//! and the odd slots in two running sums (the dependent additions of one
//! would bound the loop), added at the end; each slot's three terms in
//! row order, products and sums unfused: the same bits at every
//! instruction set, for any split of the groups across threads. A padded
//! term is `0 · x`, which adds nothing to a finite sum.
//!
//! The product runs its AVX2 code on machines with AVX-512 too. On an AMD
//! EPYC (Zen 4, AVX-512), the product of a 22³ grid's 244k blocks (8.8 MB
//! of values, one thread, medians of 200 products, two runs) took 0.27 ms
//! at AVX2, 0.30–0.31 ms with the same loads into 512-bit vectors and
//! 0.49 ms with 512-bit hardware gathers of `x` (three per slot), which
//! the bunny's steps used until then: at 1e-8 the clamped body's solve
//! took 28.8–30.8 ms per step at AVX2 against 33.2–44.1 ms with the
//! gathers (`cleave bench --only steps`, renumbered, three runs
//! alternated with the gathering binary). Three gathers of a slot's four
//! lanes issue twelve loads, where the pairs take eight.

use core::ops::Range;

use crate::lanes::{dispatched_level, SimdLevel};
use crate::spmv::BlockColumns;

/// Block columns per group: the lanes of two AVX2 vectors of `f64`.
pub const LANES: usize = 8;

/// Block columns whose lengths are sorted before they are dealt to the
/// lanes of their groups (a multiple of [`LANES`]).
pub const WINDOW: usize = 32;

/// Groups per window.
const GROUPS_PER_WINDOW: usize = WINDOW / LANES;

/// No column: a lane a window's last group leaves empty, or a padded slot.
const NONE: u32 = u32::MAX;

/// Where each block of a block column structure lies in the sliced layout
/// (see the module docs), and where its values come from in the column
/// layout of [`BlockColumns`].
#[derive(Clone, Debug, Default)]
pub struct SlicedLayout {
    /// Block columns (and block rows).
    blocks: usize,
    /// Group `g`'s slots are `group_start[g]..group_start[g + 1]`.
    group_start: Vec<u32>,
    /// `3 i` for the block row `i` of each slot's lane (a padded slot: its
    /// own column's, or 0 in an empty lane).
    rows: Vec<u32>,
    /// The block column of each group's lane ([`NONE`] if empty).
    lane_column: Vec<u32>,
    /// For each group's lane, where its column's values start in the
    /// column layout (scalar column `c` of `n` block rows at `3 n c` after
    /// it), and its block rows `n`.
    source: Vec<(usize, u32)>,
}

impl SlicedLayout {
    /// The layout of the `blocks` block columns of `columns`, each of whose
    /// block rows is below `blocks`. Panics otherwise, or when an index
    /// does not fit 32 bits.
    pub fn new(columns: BlockColumns<'_>, blocks: usize) -> Self {
        let mut layout = SlicedLayout::default();
        layout.renew(columns, blocks);
        layout
    }

    /// [`SlicedLayout::new`] in place, reusing the arrays' room.
    pub fn renew(&mut self, columns: BlockColumns<'_>, blocks: usize) {
        assert!(columns.ptr.len() == blocks + 1, "{} block columns, {blocks} blocks", columns.ptr.len() - 1);
        assert!(3 * blocks < NONE as usize, "{blocks} blocks: beyond 32-bit indices");
        let length = |j: usize| (columns.ptr[j + 1] - columns.ptr[j]) as usize;
        let windows = blocks.div_ceil(WINDOW);
        let groups = windows * GROUPS_PER_WINDOW;
        // each window's columns, longest first (ties by number)
        self.lane_column.clear();
        self.lane_column.resize(groups * LANES, NONE);
        for w in 0..windows {
            let lanes = &mut self.lane_column[w * WINDOW..(w + 1) * WINDOW];
            let these = w * WINDOW..((w + 1) * WINDOW).min(blocks);
            lanes.iter_mut().zip(these.clone()).for_each(|(lane, j)| *lane = j as u32);
            lanes[..these.len()].sort_by_key(|&j| (core::cmp::Reverse(length(j as usize)), j));
        }
        self.group_start.clear();
        self.group_start.push(0);
        let mut slots = 0usize;
        for g in 0..groups {
            let lanes = &self.lane_column[g * LANES..(g + 1) * LANES];
            slots += lanes.iter().filter(|&&j| j != NONE).map(|&j| length(j as usize)).max().unwrap_or(0);
            self.group_start.push(u32::try_from(slots).expect("slots fit 32 bits"));
        }
        assert!(9 * slots * LANES < NONE as usize, "{slots} slots: beyond 32-bit indices");
        self.rows.clear();
        self.rows.resize(slots * LANES, 0);
        self.source.clear();
        self.source.resize(groups * LANES, (0, 0));
        for g in 0..groups {
            let padded = self.group_start[g] as usize..self.group_start[g + 1] as usize;
            for l in 0..LANES {
                let j = self.lane_column[g * LANES + l];
                if j == NONE {
                    continue;
                }
                let j = j as usize;
                let rows = &columns.rows[columns.ptr[j] as usize..columns.ptr[j + 1] as usize];
                self.source[g * LANES + l] = (columns.start[j], rows.len() as u32);
                let lane = self.rows[padded.start * LANES + l..padded.end * LANES].iter_mut().step_by(LANES);
                let own = core::iter::repeat(j as u32);
                for (at, i) in lane.zip(rows.iter().copied().chain(own)) {
                    assert!((i as usize) < blocks, "block row {i} of column {j}: {blocks} blocks");
                    *at = 3 * i;
                }
            }
        }
        self.blocks = blocks;
    }

    /// Block columns.
    pub fn blocks(&self) -> usize {
        self.blocks
    }

    /// Values of the sliced layout, padding included.
    pub fn values_len(&self) -> usize {
        9 * self.rows.len()
    }

    /// Groups.
    pub fn groups(&self) -> usize {
        self.lane_column.len() / LANES
    }

    /// The stretch of the sliced values that holds `groups`.
    pub fn values_of(&self, groups: Range<usize>) -> Range<usize> {
        9 * LANES * self.group_start[groups.start] as usize..9 * LANES * self.group_start[groups.end] as usize
    }

    /// The groups of the block columns `columns`, which start and end at
    /// windows or at the last block column.
    pub fn groups_of(&self, columns: Range<usize>) -> Range<usize> {
        let group_at = |j: usize| {
            assert!(
                j % WINDOW == 0 || j == self.blocks,
                "columns {columns:?} do not start and end at windows of {WINDOW}"
            );
            match j == self.blocks {
                true => self.groups(),
                false => j / LANES,
            }
        };
        group_at(columns.start)..group_at(columns.end)
    }

    /// The values of `groups`: `out` (their stretch of the sliced values,
    /// [`SlicedLayout::values_of`]) takes the values of the column layout
    /// (for the structure of [`SlicedLayout::new`]) whose stretch from
    /// index `offset` on is `values`, zeros where padded.
    pub fn fill<T: Copy + Default>(&self, values: &[T], offset: usize, groups: Range<usize>, out: &mut [T]) {
        let first = self.group_start[groups.start] as usize;
        assert_eq!(out.len(), self.values_of(groups.clone()).len(), "the stretch of the groups {groups:?}");
        let zero = [T::default(); 3];
        for g in groups {
            let slots = self.group_start[g] as usize - first..self.group_start[g + 1] as usize - first;
            let group = &mut out[9 * LANES * slots.start..9 * LANES * slots.end];
            // each lane's three scalar columns, block row `s`'s entries at `3 s..`
            let columns: [[&[T]; 3]; LANES] = core::array::from_fn(|l| {
                let (start, n) = self.source[g * LANES + l];
                // (an empty lane reads nothing)
                let (start, n) = (if n == 0 { 0 } else { start - offset }, n as usize);
                core::array::from_fn(|c| &values[start + 3 * n * c..start + 3 * n * (c + 1)])
            });
            for (s, slot) in group.chunks_exact_mut(9 * LANES).enumerate() {
                for (l, lane) in columns.iter().enumerate() {
                    for (c, column) in lane.iter().enumerate() {
                        let terms = column.get(3 * s..3 * s + 3).unwrap_or(&zero);
                        (0..3).for_each(|r| slot[(3 * c + r) * LANES + l] = terms[r]);
                    }
                }
            }
        }
    }

    /// `y_j = (A x)_j` for the block columns `first..first + y.len() / 3`,
    /// which start and end at windows or at the last block column
    /// ([`SlicedLayout::groups_of`]), with the sliced `values` of all
    /// groups; returns `Σ_j x_j · y_j` over those columns, summed in order.
    pub fn products(&self, values: &[f32], x: &[f64], first: usize, y: &mut [f64]) -> f64 {
        self.products_at(dispatched_level(SimdLevel::Avx2), values, x, first, y)
    }

    /// [`SlicedLayout::products`] at the instruction set `level` (AVX2's
    /// code at AVX-512: see the module docs).
    fn products_at(&self, level: SimdLevel, values: &[f32], x: &[f64], first: usize, y: &mut [f64]) -> f64 {
        assert_eq!(x.len(), 3 * self.blocks, "x of {} entries for {} blocks", x.len(), self.blocks);
        assert_eq!(values.len(), self.values_len(), "the layout's values");
        let groups = self.groups_of(first..first + y.len() / 3);
        let product = Product { values, x, groups, first, y: &mut *y };
        #[cfg(target_arch = "x86_64")]
        match level {
            // SAFETY: the level is available; every group's slots lie in
            // `rows` and `values` (the layout's, checked above), and every
            // row `3 i` was checked below `3 blocks = x.len()` as the layout
            // was made.
            SimdLevel::Avx512 | SimdLevel::Avx2 => unsafe { x86::sums_avx2(self, product) },
            SimdLevel::Scalar => self.scalar_sums(product),
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.scalar_sums(product);
        let mut dot = 0.0;
        for (q, yj) in y.chunks_exact(3).enumerate() {
            let j = 3 * (first + q);
            dot += x[j] * yj[0] + x[j + 1] * yj[1] + x[j + 2] * yj[2];
        }
        dot
    }
}

/// A product's operands: the sliced `values` (of the whole layout) times
/// `x` into `y`, for the groups `groups`, whose columns start at `first`.
struct Product<'a> {
    values: &'a [f32],
    x: &'a [f64],
    groups: Range<usize>,
    first: usize,
    y: &'a mut [f64],
}

impl SlicedLayout {
    /// The sums of `product` by [`scalar_sums`].
    fn scalar_sums(&self, product: Product<'_>) {
        let Product { values, x, groups, first, y } = product;
        self.write_sums(groups, first, y, |slots, sums| scalar_sums(&self.rows, values, x, slots, sums));
    }

    /// Writes the sums `group_sums(slots, sums)` makes of each group of
    /// `groups` to its lanes' columns of `y` (which starts at block column
    /// `first`).
    #[inline(always)]
    fn write_sums(
        &self,
        groups: Range<usize>,
        first: usize,
        y: &mut [f64],
        mut group_sums: impl FnMut(Range<usize>, &mut [[f64; LANES]; 3]),
    ) {
        let mut sums = [[0.0f64; LANES]; 3];
        for g in groups {
            group_sums(self.group_start[g] as usize..self.group_start[g + 1] as usize, &mut sums);
            for (l, &j) in self.lane_column[g * LANES..(g + 1) * LANES].iter().enumerate() {
                if j != NONE {
                    let at = 3 * (j as usize - first);
                    (0..3).for_each(|c| y[at + c] = sums[c][l]);
                }
            }
        }
    }
}

/// The sums of one group (`slots`, on rows `rows` and `values` of the
/// whole layout): `sums[c][l]` is lane `l`'s output `c`. The reference the
/// SIMD kernels follow operation for operation.
#[inline(always)]
fn scalar_sums(rows: &[u32], values: &[f32], x: &[f64], slots: Range<usize>, sums: &mut [[f64; LANES]; 3]) {
    let mut acc = [[[0.0f64; LANES]; 3]; 2];
    for (s, slot) in slots.enumerate() {
        let acc = &mut acc[s % 2];
        for l in 0..LANES {
            let i = rows[slot * LANES + l] as usize;
            for (c, acc) in acc.iter_mut().enumerate() {
                for r in 0..3 {
                    let v = values[(9 * slot + 3 * c + r) * LANES + l] as f64;
                    acc[l] += v * x[i + r];
                }
            }
        }
    }
    for c in 0..3 {
        for l in 0..LANES {
            sums[c][l] = acc[0][c][l] + acc[1][c][l];
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{Product, SlicedLayout, LANES};
    use core::arch::x86_64::*;
    use core::ops::Range;

    /// [`SlicedLayout::write_sums`] with [`group_sums_avx2`].
    ///
    /// # Safety
    /// AVX2 is available; the groups' slots lie within the layout's rows
    /// and `values`, and every row `3 i` of them has `x[3 i + 2]`.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn sums_avx2(layout: &SlicedLayout, product: Product<'_>) {
        let Product { values, x, groups, first, y } = product;
        layout.write_sums(groups, first, y, |slots, sums| group_sums_avx2(&layout.rows, values, x, slots, sums));
    }

    /// `[x[3 i_l + r] for l in 0..4]` for `r = 0, 1, 2`, the rows `3 i_l`
    /// at `rows`: pairs of entries loaded into the halves of one vector
    /// and interleaved, `[x0 x1 | x0' x1']` of lanes 0 and 2 with those of
    /// lanes 1 and 3 giving rows 0 and 1, the pairs from `3 i + 1` giving
    /// row 2. On AMD Zen 3, where `vgatherdpd` is microcoded, the product
    /// of a 22³ grid's 244k blocks (8.8 MB of values, one thread) took
    /// 0.64–0.73 ms instead of 1.11–1.21 with three hardware gathers
    /// (medians of six rounds). It reads `x[3 i..3 i + 3]` only.
    ///
    /// # Safety
    /// AVX2 is available, `rows` has 4 entries, and `x` has each
    /// `3 i + 2` among them.
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn x_of_lanes(x: *const f64, rows: *const u32) -> [__m256d; 3] {
        let at = |l: usize| x.add(*rows.add(l) as usize);
        let pairs = |l: usize, shift: usize| _mm256_loadu2_m128d(at(l + 2).add(shift), at(l).add(shift));
        let (even, odd) = (pairs(0, 0), pairs(1, 0));
        let (even_next, odd_next) = (pairs(0, 1), pairs(1, 1));
        [_mm256_unpacklo_pd(even, odd), _mm256_unpackhi_pd(even, odd), _mm256_unpackhi_pd(even_next, odd_next)]
    }

    /// [`super::scalar_sums`] with AVX2: each output in two vectors of
    /// four lanes, the entries of `x` by [`x_of_lanes`].
    ///
    /// # Safety
    /// As [`sums_avx2`], for the slots `slots`.
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn group_sums_avx2(
        rows: &[u32],
        values: &[f32],
        x: &[f64],
        slots: Range<usize>,
        sums: &mut [[f64; LANES]; 3],
    ) {
        let mut acc = [[[_mm256_setzero_pd(); 2]; 3]; 2];
        let xp = x.as_ptr();
        for (s, slot) in slots.enumerate() {
            let acc = &mut acc[s % 2];
            for half in 0..2 {
                let xs = x_of_lanes(xp, rows.as_ptr().add(slot * LANES + 4 * half));
                let v = values.as_ptr().add(9 * slot * LANES + 4 * half);
                for (c, acc) in acc.iter_mut().enumerate() {
                    for (r, xr) in xs.iter().enumerate() {
                        let a = _mm256_cvtps_pd(_mm_loadu_ps(v.add((3 * c + r) * LANES)));
                        acc[half] = _mm256_add_pd(acc[half], _mm256_mul_pd(a, *xr));
                    }
                }
            }
        }
        for (c, out) in sums.iter_mut().enumerate() {
            for half in 0..2 {
                _mm256_storeu_pd(out.as_mut_ptr().add(4 * half), _mm256_add_pd(acc[0][c][half], acc[1][c][half]));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spmv::tests::{ring, Ring};

    /// Against the dense product, with the columns split as the solver
    /// splits them (a first window, then the rest), on every instruction
    /// set the machine has, with the same bits on each; the matrices have
    /// columns of 3, 13 and 131 block rows, block counts that leave the
    /// last window short and its last group empty.
    #[test]
    fn products_match_the_dense_matrix_on_every_level() {
        for (n, reach) in [(7, 1), (45, 6), (140, 65)] {
            let Ring { ptr, rows, start, values, dense } = ring(n, reach);
            let layout = SlicedLayout::new(BlockColumns { ptr: &ptr, rows: &rows, start: &start }, n);
            let values32: Vec<f32> = values.iter().map(|&v| v as f32).collect();
            let mut sliced = vec![f32::NAN; layout.values_len()];
            layout.fill(&values32, 0, layout.groups_of(0..n), &mut sliced);
            let x: Vec<f64> = (0..3 * n).map(|i| (i as f64 * 0.7).sin()).collect();
            // the rounded values' exact product, and the scale of its rounding
            let rounded = |i: usize, j: usize| f64::from(dense[i][j] as f32);
            let want: Vec<f64> = (0..3 * n).map(|i| (0..3 * n).map(|j| rounded(i, j) * x[j]).sum()).collect();
            let scale: Vec<f64> = (0..3 * n).map(|i| (0..3 * n).map(|j| (rounded(i, j) * x[j]).abs()).sum()).collect();
            let split = WINDOW.min(n);
            let mut bits = None;
            for level in crate::lanes::levels::available("sliced") {
                let mut y = vec![0.0; 3 * n];
                let (head, tail) = y.split_at_mut(3 * split);
                let dot = layout.products_at(level, &sliced, &x, 0, head)
                    + layout.products_at(level, &sliced, &x, split, tail);
                for (i, &got) in y.iter().enumerate() {
                    assert!((got - want[i]).abs() <= 1e-14 * scale[i], "{level:?}: y[{i}] = {got}, dense {}", want[i]);
                }
                let want_dot: f64 = x.iter().zip(&want).map(|(a, b)| a * b).sum();
                assert!((dot - want_dot).abs() <= 1e-12 * (1.0 + want_dot.abs()), "{level:?}: x·Ax {dot}, {want_dot}");
                let these: Vec<u64> = y.iter().map(|v| v.to_bits()).collect();
                assert_eq!(*bits.get_or_insert(these.clone()), these, "{level:?} differs from the first level");
            }
        }
    }

    /// Every value of the column layout lands once, at its block's slot
    /// and lane, and every other entry is a padded zero.
    #[test]
    fn the_layout_holds_each_value_once_and_pads_with_zeros() {
        let (n, reach) = (45, 6);
        let Ring { ptr, rows, start, .. } = ring(n, reach);
        let columns = BlockColumns { ptr: &ptr, rows: &rows, start: &start };
        let layout = SlicedLayout::new(columns, n);
        // each value its own number plus one
        let count = 9 * rows.len();
        let numbered: Vec<f64> = (0..count).map(|v| (v + 1) as f64).collect();
        let mut sliced = vec![-1.0; layout.values_len()];
        layout.fill(&numbered, 0, layout.groups_of(0..n), &mut sliced);
        let mut seen = vec![false; count];
        for &v in sliced.iter().filter(|&&v| v != 0.0) {
            assert!(!std::mem::replace(&mut seen[v as usize - 1], true), "value {v} twice");
        }
        assert!(seen.iter().all(|&s| s), "a value is missing");
        let padding = layout.values_len() as f64 / count as f64 - 1.0;
        assert!(padding < 0.5, "padding {padding}");
    }

    /// A range of columns that starts within a window has no groups of
    /// its own: refused.
    #[test]
    #[should_panic(expected = "do not start and end at windows")]
    fn columns_not_at_windows_are_refused() {
        let Ring { ptr, rows, start, .. } = ring(45, 2);
        SlicedLayout::new(BlockColumns { ptr: &ptr, rows: &rows, start: &start }, 45).groups_of(3..45);
    }
}
