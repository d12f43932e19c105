//! The aggregates' part of the coarse level: `A₁ e = g` for the rigid
//! motions of the node aggregates, approximately by a two-level additive
//! correction, or exactly when there are few aggregates.
//!
//! `A₁ = Pᵀ A P` couples each aggregate's `k` modes (three translations,
//! and three rotations when the nodes have positions) with those of its
//! neighbours: a sparse matrix of `k x k` blocks on the graph of the
//! aggregates ([`AggregateMatrix`]). On bunny_100k one aggregation round
//! gives 687 aggregates, 4,122 modes; its sparse Cholesky factor held 0.8M
//! values and took 29 ms to compute and 0.9 ms to apply (2 cores, AMD
//! EPYC), as much as the fine product it would accompany in every
//! iteration. The cycle instead applies
//!
//! ```text
//! e = T A₂⁻¹ Tᵀ g + Σ_G R_Gᵀ A_G⁻¹ R_G g
//! ```
//!
//! `T` the map from the rigid motions of each aggregate of aggregates (a
//! group) to those of its aggregates, `A₂ = Tᵀ A₁ T` (a dense matrix of a
//! few hundred modes), `R_G` the restriction to the modes of group `G`'s
//! aggregates and `A_G = R_G A₁ R_Gᵀ` its block of `A₁` (about a hundred
//! modes): a two-level additive Schwarz method on `A₁` with the groups as
//! subdomains, symmetric positive definite, as conjugate gradients need of
//! their preconditioner. Each `A_G` is applied by the inverse of its
//! Cholesky factor rounded to `f32` (`kernels/src/inverse_factor.rs`),
//! which keeps it positive definite. Its predecessor, the `k x k` diagonal
//! blocks of `A₁` in place of the groups' blocks, took 65.9 iterations
//! per step on bunny_100k clamped at 1e-8 (43.2 at 1e-6), the groups'
//! blocks 55.8 (36.8), for 0.1 ms more per iteration: the solve 53.4 ->
//! 50.9 ms (2 cores, Intel Xeon; a group of more than
//! [`MAX_BLOCK_AGGREGATES`] aggregates is split into runs of them, 56.05
//! iterations at 1e-8; the exact solve of `A₁` takes 55 at
//! 1e-8 over the first 10 steps, against 77 and 65 for the two). Blocks
//! of 7 groups of 770 modes instead of 51 of about 100 gained almost
//! nothing more (63.8 against 65.2 iterations over those 10 steps).
//! Multiplicative forms (a Chebyshev smoothing of degree 1 or 2 around
//! the groups' correction, with the diagonal blocks) took 20 to 25% fewer
//! iterations of the conjugate gradients on the clamped bunny's steps,
//! but their two or three products with `A₁` per iteration cost more than
//! those iterations (bunny_100k clamped at 1e-8, 2 cores, AMD EPYC: 79
//! iterations per step and 88 ms of solve additive, 64 and 91 ms with
//! degree 2, 107 and 101 ms with the 32 aggregates of one dense level
//! alone). Smaller aggregates (2,987 instead of 898 on the clamped
//! bunny) take fewer iterations solved exactly (43 over 10 steps) but
//! more by this cycle (105 with the diagonal blocks).
//!
//! Every sum runs in a fixed order: the same bits on any number of threads.

use cleave_kernels::inverse_factor::{self, padded, tiled_len};
use cleave_kernels::vec3::cross;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::linalg::triangular_inverse::invert_lower_triangular;
use faer::{MatMut, MatRef, Par};
use rayon::prelude::*;

/// The regularisation of a rotation's diagonal, relative to the largest
/// diagonal entry: an aggregate too small or too flat to rotate (one node,
/// nodes on a line) has rotations of no stiffness, whose rows of `P` are
/// zero; with it every factor exists and such a mode corrects nothing.
pub(super) const ROTATION_FLOOR: f64 = 1e-12;

/// Groups of a component from which its block of `A₂` is assembled with
/// its columns in parallel.
const PARALLEL_GROUPS: usize = 16;

/// `A₁`: symmetric, both triangles stored, `k x k` blocks. Block column
/// `b` holds the blocks of rows `rows[ptr[b]..ptr[b + 1]]` (ascending),
/// block `p` at `values[k² p..k² (p + 1)]` with entry `(r, c)` at `c k + r`.
#[derive(Clone, Debug, Default)]
pub(super) struct AggregateMatrix {
    /// Modes per aggregate, 3 or 6.
    pub k: usize,
    pub ptr: Vec<u32>,
    pub rows: Vec<u32>,
    pub values: Vec<f64>,
}

impl AggregateMatrix {
    /// Number of aggregates.
    pub fn aggregates(&self) -> usize {
        self.ptr.len().saturating_sub(1)
    }

    /// The block of column `b` in row `a`, if the graph couples them.
    pub fn slot(&self, a: u32, b: usize) -> Option<usize> {
        let rows = &self.rows[self.ptr[b] as usize..self.ptr[b + 1] as usize];
        rows.binary_search(&a).ok().map(|p| self.ptr[b] as usize + p)
    }
}

/// Why a factor of the aggregates' system failed: the aggregate (of `A₁`)
/// whose mode was not positive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct NotPositive {
    pub aggregate: usize,
}

/// The most aggregates of one block of the local solves: a group of more
/// is split into runs of its aggregates (in their order, which follows the
/// solver's numbering of the nodes) of at most this many. The factor of a
/// block of `n` modes costs `n³` flops at every refresh and its solve `n²`
/// per iteration: on a 1M-tetrahedron box falling (`cleave bench --only
/// steps`, 2 cores, Intel Xeon) the groups held about 50 aggregates each,
/// and whole-group blocks took its step's solve from 0.50 s (with the
/// aggregates' diagonal blocks) to 2.3 s, blocks of at most 24 aggregates
/// to 0.61 s and of 12 to 0.56 s; the clamped bunny_100k (groups of 17.6
/// on average) took 55.75 iterations per step at 1e-8 with whole groups,
/// 56.05 with runs of 12.
const MAX_BLOCK_AGGREGATES: usize = 12;

/// A block of `A₁` of the local solves, factored, and its workspace.
#[derive(Default)]
struct LocalBlock {
    dense: Vec<f64>,
    inverse: Vec<f64>,
    factor: Vec<f32>,
    stack: Option<MemBuffer>,
    side: Vec<f64>,
    scratch: Vec<f64>,
}

impl LocalBlock {
    /// Room for a block of order `n`, keeping what it has (a cut's new
    /// blocks reuse their predecessors' memory).
    fn fit(&mut self, n: usize) {
        let grow = |v: &mut Vec<f64>, len: usize| {
            if v.len() < len {
                v.resize(len, 0.0);
            }
        };
        grow(&mut self.dense, n * n);
        grow(&mut self.inverse, n * n);
        grow(&mut self.side, n);
        grow(&mut self.scratch, 2 * padded(n));
        if self.factor.len() < tiled_len(n) {
            self.factor.resize(tiled_len(n), 0.0);
        }
        let needed = cholesky_scratch(n);
        if self.stack.as_ref().is_none_or(|s| s.len() < needed.size_bytes()) {
            self.stack = Some(MemBuffer::new(needed));
        }
    }
}

impl std::fmt::Debug for LocalBlock {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LocalBlock").field("order", &self.side.len()).finish()
    }
}

/// The approximate (or exact) solve of `A₁` and its workspace.
#[derive(Default)]
pub(super) struct AggregateCycle {
    /// Aggregate of aggregates of every aggregate, and their number.
    of: Vec<u32>,
    groups: usize,
    /// Aggregates of group `g` at `members[ptr[g]..ptr[g + 1]]`.
    ptr: Vec<u32>,
    members: Vec<u32>,
    /// Every aggregate's centroid from its group's (m), with rotations.
    offsets: Vec<[f64; 3]>,
    /// The groups of connected component `c` (of the groups' graph, which
    /// couples two groups where `A₁` couples aggregates of theirs) at
    /// `component_ptr[c]..component_ptr[c + 1]`: the groups are numbered
    /// component by component, so that `A₂` is block diagonal, one dense
    /// block per component. A body cut into pieces has a component per
    /// piece, and no piece's modes meet another's in the factor.
    component_ptr: Vec<u32>,
    /// Whether every aggregate is its own group: the cycle is then the
    /// exact solve of `A₁`.
    exact: bool,
    /// The blocks of the local solves: block `b` holds the aggregates
    /// `members[block_ptr[b]..block_ptr[b + 1]]`, all of one group (a
    /// group of at most [`MAX_BLOCK_AGGREGATES`], or a run of one).
    block_ptr: Vec<u32>,
    /// Per block, the inverse of the Cholesky factor of its block of `A₁`
    /// (`n = k m` modes for its `m` aggregates, in the order of `members`),
    /// its scratch and room for a right-hand side: sized for six modes
    /// when the groups are made, so that a factor or a solve allocates
    /// nothing.
    local: Vec<LocalBlock>,
    /// A diagonal block of `A₂ = Tᵀ A₁ T` (one per component, dense,
    /// column-major), overwritten by its lower Cholesky factor, whose
    /// inverse below serves the solves: room for the largest component,
    /// reused component by component.
    factor: Vec<f64>,
    /// The inverse of each component's factor, tiled (in `f64`: the
    /// groups' solve stays exact to rounding), laid end to end; the dense
    /// inverse of one component and twice the padded order of the largest
    /// (scratch). The solve on the 192 modes of the clamped bunny_100k's
    /// 32 groups took 42-47 µs per iteration as faer's two triangular
    /// solves (chains of dependent sums), and takes 30-31 µs as two
    /// products with the inverse: 5.4 µs alone, the rest the 150 kB of the
    /// inverse coming back into the cache after each iteration's product
    /// (Intel Xeon model 207).
    inverse: Vec<f64>,
    dense_inverse: Vec<f64>,
    scratch: Vec<f64>,
    stack: Option<MemBuffer>,
    /// Work vector of the modes of `A₂`.
    coarse: Vec<f64>,
}

impl AggregateCycle {
    /// The cycle for `aggregates` aggregates grouped by `of` (`groups`
    /// groups; `None`: each its own, the exact solve), neighbours in
    /// `graph` (offsets, neighbours: the pattern of `A₁`), in the memory of
    /// `old`. The groups are numbered again, component by component.
    pub fn renew(aggregates: usize, grouping: Option<(Vec<u32>, usize)>, graph: (&[u32], &[u32]), old: Self) -> Self {
        let exact = grouping.is_none();
        let (mut of, groups) = grouping.unwrap_or_else(|| ((0..aggregates as u32).collect(), aggregates));
        let component_ptr = number_by_component(graph, &mut of, groups);
        let (ptr, members) = super::coarse::group(&of, groups);
        let mut block_ptr = vec![0u32];
        if !exact {
            for g in 0..groups {
                let (start, len) = (ptr[g] as usize, (ptr[g + 1] - ptr[g]) as usize);
                let runs = len.div_ceil(MAX_BLOCK_AGGREGATES).max(1);
                block_ptr.extend((1..=runs).map(|r| (start + r * len / runs) as u32));
            }
        }
        let mut local = old.local;
        local.resize_with(block_ptr.len() - 1, LocalBlock::default);
        for (block, run) in local.iter_mut().zip(block_ptr.windows(2)) {
            block.fit(6 * (run[1] - run[0]) as usize);
        }
        AggregateCycle {
            of,
            groups,
            ptr,
            members,
            component_ptr,
            exact,
            block_ptr,
            local,
            factor: old.factor,
            inverse: old.inverse,
            dense_inverse: old.dense_inverse,
            scratch: old.scratch,
            stack: old.stack,
            ..Default::default()
        }
    }

    /// The groups of every component, in order.
    fn components(&self) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        self.component_ptr.windows(2).map(|w| w[0] as usize..w[1] as usize)
    }

    /// Number of aggregates of aggregates.
    #[cfg(test)]
    pub fn groups(&self) -> usize {
        self.groups
    }

    /// Number of groups of every component, in order.
    #[cfg(test)]
    pub fn component_groups(&self) -> Vec<usize> {
        self.components().map(|c| c.len()).collect()
    }

    /// Whether the cycle is the exact solve of `A₁`.
    #[cfg(test)]
    pub fn is_exact(&self) -> bool {
        self.exact
    }

    /// Takes the aggregates' centroids (m) and their member offsets
    /// (aggregate `a` has `member_ptr[a + 1] - member_ptr[a]` nodes): each
    /// group's rotations turn about the centroid of all its nodes.
    pub fn set_centroids(&mut self, centroids: &[[f64; 3]], member_ptr: &[u32]) {
        self.offsets.clear();
        self.offsets.resize(centroids.len(), [0.0; 3]);
        for g in 0..self.groups {
            let members = &self.members[self.ptr[g] as usize..self.ptr[g + 1] as usize];
            let (mut sum, mut weight) = ([0.0; 3], 0.0);
            for &a in members {
                let w = f64::from(member_ptr[a as usize + 1] - member_ptr[a as usize]);
                (0..3).for_each(|d| sum[d] += w * centroids[a as usize][d]);
                weight += w;
            }
            for &a in members {
                let c = centroids[a as usize];
                self.offsets[a as usize] = std::array::from_fn(|d| c[d] - sum[d] / weight.max(1.0));
            }
        }
    }

    /// Readies the cycle for `a1`: factors its blocks on the groups,
    /// assembles and factors `A₂`.
    pub fn factor(&mut self, a1: &AggregateMatrix) -> Result<(), NotPositive> {
        let (k, m) = (a1.k, a1.aggregates());
        let rotations = k == 6 && self.offsets.len() == m;
        self.coarse.resize(k * self.groups, 0.0);
        if !self.exact {
            self.factor_local(a1)?;
        }
        self.factor_groups(a1, rotations)
    }

    /// The blocks of `A₁` of the local solves, assembled and factored in
    /// parallel.
    fn factor_local(&mut self, a1: &AggregateMatrix) -> Result<(), NotPositive> {
        let (k, kk) = (a1.k, a1.k * a1.k);
        let (block_ptr, members) = (&self.block_ptr, &self.members);
        let failed = (self.local.par_iter_mut().zip(block_ptr.par_windows(2)))
            .map(|(block, run)| {
                let members = &members[run[0] as usize..run[1] as usize];
                let n = k * members.len();
                let dense = &mut block.dense[..n * n];
                dense.fill(0.0);
                for (column, &b) in members.iter().enumerate() {
                    for p in a1.ptr[b as usize] as usize..a1.ptr[b as usize + 1] as usize {
                        // (the block's aggregates ascend)
                        let Ok(row) = members.binary_search(&a1.rows[p]) else { continue };
                        let values = &a1.values[kk * p..kk * (p + 1)];
                        for c in 0..k {
                            let at = (k * column + c) * n + k * row;
                            dense[at..at + k].copy_from_slice(&values[c * k..(c + 1) * k]);
                        }
                    }
                }
                let factored = llt::factor::cholesky_in_place(
                    MatMut::from_column_major_slice_mut(dense, n, n),
                    Default::default(),
                    Par::Seq,
                    MemStack::new(block.stack.as_mut().expect("sized when the blocks are made")),
                    Default::default(),
                );
                if let Err(llt::factor::LltError::NonPositivePivot { index }) = factored {
                    return Some(members[index / k] as usize);
                }
                tile_inverse(dense, n, &mut block.inverse, &mut block.factor);
                None
            })
            .min();
        match failed.flatten() {
            Some(aggregate) => Err(NotPositive { aggregate }),
            None => Ok(()),
        }
    }

    /// `A₂ = Tᵀ A₁ T`, a dense block per component (the group columns of a
    /// large one in parallel), the Cholesky factor of each block and its
    /// tiled inverse.
    fn factor_groups(&mut self, a1: &AggregateMatrix, rotations: bool) -> Result<(), NotPositive> {
        let k = a1.k;
        let order = |groups: &std::ops::Range<usize>| k * groups.len();
        let largest = self.components().map(|c| order(&c)).max().unwrap_or(0);
        let mut dense = std::mem::take(&mut self.factor);
        dense.resize(largest * largest, 0.0);
        let mut stack = self.stack.take().unwrap_or_else(|| MemBuffer::new(cholesky_scratch(largest)));
        if stack.len() < cholesky_scratch(largest).size_bytes() {
            stack = MemBuffer::new(cholesky_scratch(largest));
        }
        let tiled: usize = self.components().map(|c| tiled_len(order(&c))).sum();
        let (mut inverse, mut dense_inverse) =
            (std::mem::take(&mut self.inverse), std::mem::take(&mut self.dense_inverse));
        inverse.resize(tiled, 0.0);
        dense_inverse.resize(largest * largest, 0.0);
        self.scratch.resize(2 * padded(largest), 0.0);
        let mut result = Ok(());
        let mut tiled_rest = &mut inverse[..];
        for groups in self.components() {
            let n = order(&groups);
            let block = &mut dense[..n * n];
            let (tiles, after) = tiled_rest.split_at_mut(tiled_len(n));
            tiled_rest = after;
            let column = |(g, cols): (usize, &mut [f64])| self.assemble_group(a1, rotations, &groups, g, cols);
            if groups.len() >= PARALLEL_GROUPS {
                block.par_chunks_mut(k * n).enumerate().for_each(column);
            } else {
                block.chunks_mut(k * n).enumerate().for_each(column);
            }
            let factored = llt::factor::cholesky_in_place(
                MatMut::from_column_major_slice_mut(block, n, n),
                Default::default(),
                Par::Seq,
                MemStack::new(&mut stack),
                Default::default(),
            );
            if let Err(llt::factor::LltError::NonPositivePivot { index }) = factored {
                let group = groups.start + index / k;
                result = Err(NotPositive { aggregate: self.members[self.ptr[group] as usize] as usize });
                break;
            }
            tile_inverse(block, n, &mut dense_inverse, tiles);
        }
        (self.inverse, self.dense_inverse) = (inverse, dense_inverse);
        self.factor = dense;
        self.stack = Some(stack);
        result
    }

    /// Columns `cols` (`k` columns of the block of the component of
    /// `groups`, column-major) of `A₂` for its `g`-th group.
    fn assemble_group(
        &self,
        a1: &AggregateMatrix,
        rotations: bool,
        groups: &std::ops::Range<usize>,
        g: usize,
        cols: &mut [f64],
    ) {
        let (k, kk) = (a1.k, a1.k * a1.k);
        let n = k * groups.len();
        cols.fill(0.0);
        let g = groups.start + g;
        for &b in &self.members[self.ptr[g] as usize..self.ptr[g + 1] as usize] {
            let b = b as usize;
            for p in a1.ptr[b] as usize..a1.ptr[b + 1] as usize {
                let a = a1.rows[p] as usize;
                let block = &a1.values[kk * p..kk * (p + 1)];
                let row = k * (self.of[a] as usize - groups.start);
                add_transferred(block, self.offset(a, rotations), self.offset(b, rotations), k, |r, c, v| {
                    cols[c * n + row + r] += v;
                });
            }
        }
    }

    /// Aggregate `a`'s centroid from its group's, with rotations.
    fn offset(&self, a: usize, rotations: bool) -> Option<[f64; 3]> {
        rotations.then(|| self.offsets[a])
    }

    /// `e ≈ A₁⁻¹ g` by the cycle (see the module docs), or exactly. The
    /// groups' correction and the solves of their blocks run side by
    /// side (each is a few dozen microseconds on bunny_100k: one after the
    /// other, the second thread idled through the first).
    pub fn apply(&mut self, k: usize, g: &[f64], e: &mut [f64]) {
        if self.exact {
            self.apply_groups(k, g, e);
            return;
        }
        let (mut coarse, mut local) = (std::mem::take(&mut self.coarse), std::mem::take(&mut self.local));
        let mut scratch = std::mem::take(&mut self.scratch);
        let this = &*self;
        rayon::join(
            || this.groups_correction(&mut coarse, &mut scratch, k, g, e),
            || {
                local.par_iter_mut().zip(this.block_ptr.par_windows(2)).for_each(|(block, run)| {
                    let members = &this.members[run[0] as usize..run[1] as usize];
                    let n = k * members.len();
                    for (side, &a) in block.side.chunks_exact_mut(k).zip(members) {
                        side.copy_from_slice(&g[k * a as usize..k * (a as usize + 1)]);
                    }
                    let (factor, side) = (&block.factor[..tiled_len(n)], &mut block.side[..n]);
                    inverse_factor::apply(factor, side, &mut block.scratch);
                });
            },
        );
        (self.coarse, self.local, self.scratch) = (coarse, local, scratch);
        for (block, run) in self.local.iter().zip(self.block_ptr.windows(2)) {
            let members = &self.members[run[0] as usize..run[1] as usize];
            for (side, &a) in block.side.chunks_exact(k).zip(members) {
                e[k * a as usize..k * (a as usize + 1)].iter_mut().zip(side).for_each(|(e, s)| *e += s);
            }
        }
    }

    /// `e = T A₂⁻¹ Tᵀ g`: the exact correction of the aggregates of
    /// aggregates alone (all of the cycle when it is exact).
    pub fn apply_groups(&mut self, k: usize, g: &[f64], e: &mut [f64]) {
        let (mut coarse, mut scratch) = (std::mem::take(&mut self.coarse), std::mem::take(&mut self.scratch));
        self.groups_correction(&mut coarse, &mut scratch, k, g, e);
        (self.coarse, self.scratch) = (coarse, scratch);
    }

    /// [`AggregateCycle::apply_groups`] with the groups' modes in `coarse`
    /// and `scratch` (both sized by [`AggregateCycle::factor`]).
    fn groups_correction(&self, coarse: &mut [f64], scratch: &mut [f64], k: usize, g: &[f64], e: &mut [f64]) {
        self.restrict(g, k, coarse);
        self.solve_groups(k, coarse, scratch);
        e.fill(0.0);
        self.prolong(coarse, e, k);
    }

    /// `coarse = Tᵀ r`, summed over each group's aggregates in order.
    fn restrict(&self, r: &[f64], k: usize, coarse: &mut [f64]) {
        coarse.fill(0.0);
        for (a, ra) in r.chunks_exact(k).enumerate() {
            let g = k * self.of[a] as usize;
            (0..3).for_each(|s| coarse[g + s] += ra[s]);
            if k == 6 {
                let d = self.offsets.get(a).copied().unwrap_or([0.0; 3]);
                let w = cross(d, [ra[0], ra[1], ra[2]]);
                (0..3).for_each(|s| coarse[g + 3 + s] += ra[3 + s] + w[s]);
            }
        }
    }

    /// `x += T e`.
    fn prolong(&self, e: &[f64], x: &mut [f64], k: usize) {
        for (a, xa) in x.chunks_exact_mut(k).enumerate() {
            let g = k * self.of[a] as usize;
            (0..k).for_each(|s| xa[s] += e[g + s]);
            if k == 6 {
                let d = self.offsets.get(a).copied().unwrap_or([0.0; 3]);
                let w = cross([e[g + 3], e[g + 4], e[g + 5]], d);
                (0..3).for_each(|s| xa[s] += w[s]);
            }
        }
    }

    /// `v = A₂⁻¹ v` by the dense factor.
    fn solve_groups(&self, k: usize, v: &mut [f64], scratch: &mut [f64]) {
        let mut offset = 0;
        for groups in self.components() {
            let n = k * groups.len();
            let tiles = &self.inverse[offset..offset + tiled_len(n)];
            inverse_factor::apply(tiles, &mut v[k * groups.start..k * groups.end], scratch);
            offset += tiled_len(n);
        }
    }
}

/// `add(r, c, (T_aᵀ M T_b)[r][c])` for the `k x k` block `M` (column-major)
/// and the maps `T_a`, `T_b` from a group's modes to its aggregates' (see
/// [`AggregateCycle`]): with rotations (offsets `d_a`, `d_b` of the
/// aggregates' centroids from their groups') `T = [I  X; 0  I]`, `X =
/// -[d]×` (a rigid motion `(t, ω)` of the group moves the aggregate by `t
/// + ω × d` and turns it by `ω`), so that `M T_b` is `M` with `M₀ X_b`
/// added to its last three columns (`M₀` its first three), and `T_aᵀ N` is
/// `N` with `X_aᵀ N₀ = d_a × N₀` added to its last three rows (`N₀` its
/// first three); without rotations `T = I`.
fn add_transferred(
    m: &[f64],
    d_a: Option<[f64; 3]>,
    d_b: Option<[f64; 3]>,
    k: usize,
    mut add: impl FnMut(usize, usize, f64),
) {
    let (Some(d_a), Some(d_b)) = (d_a, d_b) else {
        (0..k * k).for_each(|e| add(e % k, e / k, m[e]));
        return;
    };
    // n = M T_b, column-major 6 x 6; column 3 + c gains M₀ (e_c × d_b)
    let mut n = [0.0; 36];
    n.copy_from_slice(&m[..36]);
    for c in 0..3 {
        let w = cross(unit(c), d_b);
        for r in 0..6 {
            n[(3 + c) * 6 + r] += (0..3).map(|q| m[q * 6 + r] * w[q]).sum::<f64>();
        }
    }
    // rows 3..6 of every column gain d_a × (rows 0..3 of it)
    for c in 0..6 {
        let top = [n[c * 6], n[c * 6 + 1], n[c * 6 + 2]];
        let w = cross(d_a, top);
        (0..3).for_each(|r| add(r, c, top[r]));
        (0..3).for_each(|r| add(3 + r, c, n[c * 6 + 3 + r] + w[r]));
    }
}

/// Renumbers the `groups` groups of `of` (aggregate to group) so that each
/// connected component of the groups' graph (two groups neighbour where an
/// aggregate of one neighbours an aggregate of the other in `graph`:
/// offsets, neighbours) is a range of numbers, components in the order of
/// their first group and groups in their order within; returns the ranges'
/// bounds.
fn number_by_component(graph: (&[u32], &[u32]), of: &mut [u32], groups: usize) -> Vec<u32> {
    let (ptr, adj) = graph;
    let of_ref = &*of;
    let edges = (0..ptr.len().saturating_sub(1))
        .flat_map(|a| adj[ptr[a] as usize..ptr[a + 1] as usize].iter().map(move |&b| (of_ref[a], of_ref[b as usize])));
    let root = super::ordering::component_roots(groups, edges);
    // a stable counting sort of the groups by their root
    let mut start = vec![0u32; groups + 1];
    root.iter().for_each(|&r| start[r as usize + 1] += 1);
    (0..groups).for_each(|r| start[r + 1] += start[r]);
    let mut fill = start.clone();
    let number: Vec<u32> = root
        .iter()
        .map(|&r| {
            fill[r as usize] += 1;
            fill[r as usize] - 1
        })
        .collect();
    of.iter_mut().for_each(|g| *g = number[*g as usize]);
    let firsts = (0..groups).filter(|&g| root[g] == g as u32).map(|g| start[g]);
    firsts.chain(std::iter::once(groups as u32)).collect()
}

/// The inverse of the lower Cholesky factor `factor` (column-major, order
/// `n`) into `tiled` ([`inverse_factor::tile`]), made in `square` (at least
/// `n²` long).
fn tile_inverse<T: inverse_factor::Stored>(factor: &[f64], n: usize, square: &mut [f64], tiled: &mut [T]) {
    let square = &mut square[..n * n];
    invert_lower_triangular(
        MatMut::from_column_major_slice_mut(square, n, n),
        MatRef::from_column_major_slice(&factor[..n * n], n, n),
        Par::Seq,
    );
    cleave_kernels::lanes::clear_upper_registers();
    inverse_factor::tile(square, n, tiled);
}

/// Scratch of the dense Cholesky factor of order `n`.
fn cholesky_scratch(n: usize) -> faer::dyn_stack::StackReq {
    llt::factor::cholesky_in_place_scratch::<f64>(n, Par::Seq, Default::default())
}

/// The unit vector along axis `c`.
fn unit(c: usize) -> [f64; 3] {
    std::array::from_fn(|d| if d == c { 1.0 } else { 0.0 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::prelude::Solve;

    /// `T_aᵀ M T_b` by the structure of `T` against the product of the
    /// matrices written out: `T = [I  -[d]×; 0  I]`.
    #[test]
    fn a_block_carried_to_the_groups_is_the_triple_product() {
        let m: Vec<f64> = (0..36).map(|e| ((e * 7 + 3) % 11) as f64 - 4.5).collect();
        let (d_a, d_b) = ([0.3, -1.2, 0.7], [-0.4, 0.25, 1.5]);
        let t = |d: [f64; 3]| -> [[f64; 6]; 6] {
            let mut t = [[0.0; 6]; 6];
            (0..6).for_each(|i| t[i][i] = 1.0);
            for c in 0..3 {
                let w = cross(unit(c), d);
                (0..3).for_each(|r| t[r][3 + c] = w[r]);
            }
            t
        };
        let (ta, tb) = (t(d_a), t(d_b));
        let entry = |r: usize, c: usize| m[c * 6 + r];
        let mut got = [[0.0; 6]; 6];
        add_transferred(&m, Some(d_a), Some(d_b), 6, |r, c, v| got[r][c] += v);
        for r in 0..6 {
            for c in 0..6 {
                let want: f64 = (0..6)
                    .flat_map(|s| (0..6).map(move |u| (s, u)))
                    .map(|(s, u)| ta[s][r] * entry(s, u) * tb[u][c])
                    .sum();
                assert!((got[r][c] - want).abs() < 1e-12, "({r}, {c}): {} against {want}", got[r][c]);
            }
        }
    }

    /// The cycle against its formula written out densely: `e = T A₂⁻¹ Tᵀ
    /// g + Σ_G R_Gᵀ (R_G A₁ R_Gᵀ)⁻¹ R_G g` with `A₂ = Tᵀ A₁ T`, for five aggregates on a chain in two
    /// groups, with rotations (`T` per aggregate `[I  -[d]×; 0  I]`, `d` its
    /// centroid from its group's, weighted by the member counts) and
    /// without (`T` per aggregate `I`); and for the chain cut in two pieces
    /// (aggregates 0-1 and 2-4), with groups numbered across the pieces
    /// (the cycle numbers them again, piece by piece, and factors a block
    /// per piece).
    #[test]
    fn the_cycle_is_its_formula() {
        let m = 5usize;
        let centroids = [[0.0, 0.1, 0.2], [1.0, -0.3, 0.4], [2.1, 0.5, -0.2], [2.9, 0.0, 0.3], [4.2, -0.1, 0.1]];
        let (counts, member_ptr) = ([3u32, 5, 2, 4, 1], [0u32, 3, 8, 10, 14, 15]);
        let cases = [
            (false, vec![0u32, 0, 1, 1, 1], 2, 1),
            (true, vec![1, 1, 0, 0, 0], 2, 2),
            (true, vec![1, 1, 0, 2, 2], 3, 2),
        ];
        for ((cut, of, groups, pieces), k) in cases.into_iter().flat_map(|case| [3usize, 6].map(|k| (case.clone(), k)))
        {
            // A₁ on the chain: symmetric, diagonally dominant
            let entry = |a: usize, b: usize, r: usize, c: usize| -> f64 {
                let (i, j) = (k * a + r, k * b + c);
                let off = 0.3 * ((i * 7 + j * 7 + i * j) % 5) as f64 / 5.0 - 0.15;
                if i == j {
                    4.0 + r as f64
                } else {
                    off
                }
            };
            // neighbours on the chain, unless the cut parts them
            let coupled = |a: usize, b: usize| a.abs_diff(b) <= 1 && !(cut && a.min(b) == 1 && a.max(b) == 2);
            let (mut ptr, mut rows, mut values) = (vec![0u32], vec![], vec![]);
            for b in 0..m {
                for a in (b.saturating_sub(1)..(b + 2).min(m)).filter(|&a| coupled(a, b)) {
                    rows.push(a as u32);
                    (0..k * k).for_each(|e| values.push(entry(a, b, e % k, e / k)));
                }
                ptr.push(rows.len() as u32);
            }
            let a1 = AggregateMatrix { k, ptr, rows, values };
            let mut cycle =
                AggregateCycle::renew(m, Some((of.clone(), groups)), (&a1.ptr, &a1.rows), AggregateCycle::default());
            assert_eq!(cycle.component_ptr.len() - 1, pieces, "{of:?}");
            if k == 6 {
                cycle.set_centroids(&centroids, &member_ptr);
            }
            cycle.factor(&a1).unwrap();
            let dense_a1 = faer::Mat::<f64>::from_fn(k * m, k * m, |i, j| {
                let (a, b) = (i / k, j / k);
                if coupled(a, b) {
                    entry(a, b, i % k, j % k)
                } else {
                    0.0
                }
            });
            let t = faer::Mat::<f64>::from_fn(k * m, groups * k, |i, j| {
                let (a, r, c) = (i / k, i % k, j % k);
                if of[a] as usize != j / k {
                    return 0.0;
                }
                match (r < 3, c < 3) {
                    (_, _) if r == c => 1.0,
                    (true, false) => {
                        // the group's weighted centroid, then -[d]× column c - 3
                        let members: Vec<usize> = (0..m).filter(|&b| of[b] == of[a]).collect();
                        let weight: f64 = members.iter().map(|&b| f64::from(counts[b])).sum();
                        let d: [f64; 3] = std::array::from_fn(|x| {
                            let mean: f64 = members.iter().map(|&b| f64::from(counts[b]) * centroids[b][x]).sum();
                            centroids[a][x] - mean / weight
                        });
                        cross(unit(c - 3), d)[r]
                    }
                    _ => 0.0,
                }
            });
            let a2 = t.transpose() * &dense_a1 * &t;
            let g = faer::Mat::<f64>::from_fn(k * m, 1, |i, _| (i as f64 * 0.9).sin() + 0.2);
            let mut want = &t * a2.llt(faer::Side::Lower).unwrap().solve(t.transpose() * &g);
            for group in 0..groups as u32 {
                // the block of A₁ on the group's aggregates, solved
                let members: Vec<usize> = (0..m).filter(|&a| of[a] == group).collect();
                let at = |i: usize| k * members[i / k] + i % k;
                let n = k * members.len();
                let block = faer::Mat::<f64>::from_fn(n, n, |i, j| dense_a1[(at(i), at(j))]);
                let side = faer::Mat::<f64>::from_fn(n, 1, |i, _| g[(at(i), 0)]);
                let local = block.llt(faer::Side::Lower).unwrap().solve(&side);
                (0..n).for_each(|i| want[(at(i), 0)] += local[(i, 0)]);
            }
            let g: Vec<f64> = (0..k * m).map(|i| g[(i, 0)]).collect();
            let mut got = vec![0.0; k * m];
            cycle.apply(k, &g, &mut got);
            // (the groups' blocks are applied by their inverse factors
            // rounded to f32, 2⁻²⁴ relative, times the small condition
            // numbers of these diagonally dominant blocks)
            for i in 0..k * m {
                let w = want[(i, 0)];
                assert!((got[i] - w).abs() <= 1e-6 * (1.0 + w.abs()), "{of:?}, k = {k}, entry {i}: {} vs {w}", got[i]);
            }
        }
    }
}
