//! The coarse level of the preconditioner: the rigid motions of
//! aggregates of blocks.
//!
//! Blocks (nodes) are grouped into aggregates by one round of greedy
//! aggregation of the matrix graph (on bunny_100k: 17.6k blocks into 687
//! aggregates). The prolongation `P` maps the rigid motions of each
//! aggregate to its blocks: `P_ia = [I  S_i]` for block `i` of aggregate
//! `a`, `S_i = -[d_i]×` the infinitesimal rotations about the aggregate's
//! centroid (`d_i` the block's position from it, so that `S_i ω = ω ×
//! d_i`), or `P_ia = I` (translations alone) when the blocks have no
//! positions. The correction added to the smoother's `z` is `P B Pᵀ r`,
//! `B ≈ A₁⁻¹` the cycle of `aggregate_cycle.rs` on `A₁ = Pᵀ A P` (exactly
//! `A₁⁻¹` when there are few aggregates): the exact solve on the rigid
//! motions of aggregates of aggregates plus the exact solves on the
//! blocks of `A₁` of each aggregate of aggregates' own aggregates. It
//! removes the error that block Jacobi reduces slowly: motions of whole
//! regions, which only the mass resists while block
//! Jacobi divides by the much larger stiffness diagonal. (The coarse level
//! was first the aggregates of aggregates alone, 32 on bunny_100k, with a
//! dense factor: the clamped bunny's steps took 107 iterations at 1e-8
//! with it, 79 with the aggregates' block Jacobi added; see
//! `aggregate_cycle.rs` for the groups' blocks that replaced it.)
//!
//! Aggregates follow the matrix graph, so no aggregate spans two pieces of
//! a cut body. Every sum runs in a fixed order, so the correction has the
//! same bits on any number of threads.

use cleave_kernels::spmv::Value;
use cleave_kernels::vec3::cross;
use rayon::prelude::*;

use super::aggregate_cycle::{AggregateCycle, AggregateMatrix, ROTATION_FLOOR};
use super::{BlockStructure, SolveError};

/// The most aggregates whose system the coarse level solves exactly, and
/// the most aggregates of aggregates the cycle solves exactly otherwise
/// (for a body in pieces, the budget `Σ m_c² ≤ m²` over the pieces' dense
/// blocks), for a matrix storing `stored` values: `m = ∛stored / 2`. Its
/// dense factor of six modes per aggregate then costs `(6m)³ / 3 = 9 · stored`
/// flops once per step (a few passes over the matrix) and its triangular
/// solves `36 m²` flops per iteration, a small fraction of the product's
/// `2 · stored`. (On bunny_100k, 2.3M values, the second aggregation round
/// gives 32 aggregates of aggregates.)
pub(super) fn aggregate_limit(stored: usize) -> usize {
    ((stored as f64).cbrt() / 2.0) as usize
}

/// Marks a vertex without aggregate.
const FREE: u32 = u32::MAX;

/// Block columns below which the run sums are formed without splitting.
const RUN_TASK_COLUMNS: usize = 512;

/// Block columns of `A₁` below which they are assembled without splitting.
const AGGREGATE_TASK_COLUMNS: usize = 16;

/// Aggregates of the blocks and the solve of their system.
#[derive(Default)]
pub(super) struct CoarseSpace {
    /// Aggregate of every block.
    of: Vec<u32>,
    /// Every block's position from its aggregate's centroid (m), when the
    /// blocks have positions (then each aggregate has six modes, else
    /// three).
    offsets: Vec<[f64; 3]>,
    /// Blocks of aggregate `a` at `members[ptr[a]..ptr[a + 1]]`, ascending.
    ptr: Vec<u32>,
    members: Vec<u32>,
    /// The runs of every block column: its block rows of one aggregate
    /// each, column `j`'s at `run_ptr[j]..run_ptr[j + 1]`, run `k` those in
    /// aggregate `run_aggregate[k]`, in the order the rows first meet them,
    /// and the block of `A₁` it adds to, `run_slot[k]`.
    run_ptr: Vec<u32>,
    run_aggregate: Vec<u32>,
    run_slot: Vec<u32>,
    /// The sums of the blocks `A_ij` of every run, `Σ A_ij` and, with
    /// positions, `Σ S_iᵀ A_ij` (`[3 c + r]` and `[9 + 3 c + r]` for entry
    /// `(r, c)`).
    run_sums: Vec<[f64; 18]>,
    /// `A₁ = Pᵀ A P` on the graph of the aggregates.
    system: AggregateMatrix,
    /// Its solve.
    cycle: AggregateCycle,
    /// Every aggregate's centroid (m).
    centroids: Vec<[f64; 3]>,
    /// Blocks per chunk of a restriction, the first aggregate of each
    /// chunk's blocks, and the most aggregates a chunk's blocks reach from
    /// it: a chunk restricts into a window of aggregates, not all of them
    /// (they are founded in block order, blocks a cut appended beside
    /// their anchors, so a chunk's aggregates mostly lie close
    /// together: on bunny_100k 1024 blocks reach windows of at most about
    /// 150 of 898 aggregates).
    chunk_blocks: usize,
    window_first: Vec<u32>,
    window: usize,
    /// `Pᵀ r` per chunk of blocks of [`CoarseSpace::correct`], then summed
    /// in order.
    partial: Vec<f64>,
    /// `Pᵀ r` and `B Pᵀ r`.
    restricted: Vec<f64>,
    correction: Vec<f64>,
}

impl CoarseSpace {
    /// Aggregates of the blocks of `blocks` (founded visiting them in
    /// order), their system solved exactly up to `max_aggregates`
    /// aggregates, else by a cycle whose aggregates of aggregates are
    /// coarsened to at most that many (or until a round merges nothing).
    #[cfg(test)]
    pub fn new(blocks: &BlockStructure, max_aggregates: usize, chunk_blocks: usize) -> Self {
        let visit: Vec<u32> = (0..blocks.len() as u32).collect();
        Self::renew(blocks, &visit, max_aggregates, chunk_blocks, Self::default())
    }

    /// [`CoarseSpace::new`] with the blocks visited in the order `visit`
    /// (each once; see [`super::ordering::anchored_order`]), restricting
    /// in chunks of `chunk_blocks` blocks, in the arrays of `old` (the
    /// space of the pattern before a topology change, or an empty one): a
    /// space per cut reuses its predecessor's memory instead of faulting
    /// in fresh pages for its runs.
    ///
    /// After a blade cut of bunny_100k, a renewal took 6.7 ms of CPU
    /// (sampled by `perf` over 24 cuts, Intel Xeon model 207): 0.7 ms
    /// for the greedy aggregation, 1.5 ms for the aggregates' graph and
    /// 2.7 ms for the columns' runs. Keeping the aggregates that a cut did
    /// not touch, with their part of the graph and their columns' runs,
    /// and aggregating again only the touched ones and the new blocks, took
    /// a renewal from 8.8 to 4.5 ms of CPU (commit 4993b54, reverted): the
    /// clamped steps after 6 and 12 blade cuts then took 0.3-8.5 % more
    /// iterations than with the whole renewal's aggregates (about 1 % per
    /// cut followed), which costs the steps more than it saves the cuts.
    /// The aggregates' graph is read from the columns' runs (a few per
    /// column) instead of from every block row again: 10 % fewer
    /// instructions over the first analysis and six blade cuts (callgrind,
    /// 173.5M against 156.2M), the same graph. The runs and the graph's
    /// neighbour lists are written without a branch on whether an
    /// aggregate is new, and the slots are found aggregate by aggregate:
    /// perf over 24 blade cuts, three alternated runs (AMD EPYC Zen 4),
    /// 4.2 against 3.3 thread-ms per renewal.
    pub fn renew(
        blocks: &BlockStructure,
        visit: &[u32],
        max_aggregates: usize,
        chunk_blocks: usize,
        old: Self,
    ) -> Self {
        let n = blocks.ptr.len() - 1;
        let limit = max_aggregates.max(1);
        // one round (none for a system the limit solves whole)
        let visit = visit.iter().map(|&v| v as usize);
        let round = (n > limit)
            .then(|| aggregate(&blocks.ptr, &blocks.rows, visit, |_| true))
            .filter(|&(_, merged)| merged < n);
        let merged = round.is_some();
        let (of, count) = round.unwrap_or_else(|| ((0..n as u32).collect(), n));
        let (ptr, members) = group(&of, count);
        let column_rows = |j: usize| &blocks.rows[blocks.ptr[j] as usize..blocks.ptr[j + 1] as usize];
        // every task of columns lists its columns' runs (in parallel, in
        // order), then the lists are laid end to end: a column's runs are
        // the aggregates of its rows, each once, as the rows meet them
        // (marked with the column). Every row's aggregate is written at the
        // list's end, which moves on only past a new one: no branch to
        // mispredict where rows of one aggregate and of its neighbours mix
        let tasks: Vec<std::ops::Range<usize>> =
            (0..n).step_by(RUN_TASK_COLUMNS).map(|first| first..(first + RUN_TASK_COLUMNS).min(n)).collect();
        let listed: Vec<(Vec<u32>, Vec<u32>)> = tasks
            .par_iter()
            .map(|columns| {
                let rows = (blocks.ptr[columns.end] - blocks.ptr[columns.start]) as usize;
                let (mut counts, mut aggregates, mut marked) = (Vec::new(), vec![0; rows], vec![FREE; count]);
                let mut listed = 0;
                for j in columns.clone() {
                    let before = listed;
                    for &r in column_rows(j) {
                        let a = of[r as usize];
                        let new = marked[a as usize] != j as u32;
                        marked[a as usize] = j as u32;
                        aggregates[listed] = a;
                        listed += usize::from(new);
                    }
                    counts.push((listed - before) as u32);
                }
                aggregates.truncate(listed);
                (counts, aggregates)
            })
            .collect();
        let mut run_ptr = Vec::with_capacity(n + 1);
        run_ptr.push(0u32);
        for count in listed.iter().flat_map(|(counts, _)| counts) {
            run_ptr.push(run_ptr[run_ptr.len() - 1] + count);
        }
        let (mut run_aggregate, mut run_slot, mut run_sums) = (old.run_aggregate, old.run_slot, old.run_sums);
        let runs = run_ptr[n] as usize;
        run_aggregate.clear();
        crate::reserve_room(&mut run_aggregate, runs);
        listed.iter().for_each(|(_, aggregates)| run_aggregate.extend_from_slice(aggregates));
        // the aggregates' graph: an aggregate's neighbours are the
        // aggregates of its members' runs (read from the runs, a few per
        // column, rather than from every block row again)
        let graph = if merged {
            quotient(&run_ptr, &run_aggregate, (&ptr, &members), |a| a)
        } else {
            (blocks.ptr.clone(), blocks.rows.clone())
        };
        let grouping = coarsen(&graph, count, limit);
        let (graph_ptr, graph_rows) = graph;
        // each run's slot among the neighbours of its column's own
        // aggregate, looked up in a table of that aggregate's neighbours:
        // every task visits its columns by aggregate (sorted), filling the
        // table once per aggregate and writing each column's slots in place
        run_slot.clear();
        crate::resize_with_room(&mut run_slot, runs, 0);
        let task_runs = tasks.iter().map(|c| (run_ptr[c.end] - run_ptr[c.start]) as usize);
        let stretches = crate::stretches(&mut run_slot, task_runs);
        tasks.into_par_iter().zip(stretches).for_each_init(
            || (vec![0u32; count], Vec::new()),
            |(slot_in, by_aggregate), (columns, slots)| {
                let first = run_ptr[columns.start] as usize;
                by_aggregate.clear();
                by_aggregate.extend(columns.map(|j| (u64::from(of[j]) << 32) | j as u64));
                by_aggregate.sort_unstable();
                let mut table_of = FREE;
                for &key in by_aggregate.iter() {
                    let (b, j) = ((key >> 32) as u32, key as u32 as usize);
                    let neighbours = graph_ptr[b as usize]..graph_ptr[b as usize + 1];
                    if table_of != b {
                        neighbours.clone().for_each(|p| slot_in[graph_rows[p as usize] as usize] = p);
                        table_of = b;
                    }
                    let runs = run_ptr[j] as usize..run_ptr[j + 1] as usize;
                    for (slot, &a) in slots[runs.start - first..runs.end - first].iter_mut().zip(&run_aggregate[runs]) {
                        *slot = slot_in[a as usize];
                        // (the graph is made of the runs: see the test
                        // `the_aggregates_graph_and_the_runs_follow_the_block_rows`)
                        debug_assert!(
                            neighbours.contains(slot) && graph_rows[*slot as usize] == a,
                            "aggregates of neighbouring blocks are neighbours"
                        );
                    }
                }
            },
        );
        crate::resize_with_room(&mut run_sums, runs, [0.0; 18]);
        let mut system = old.system;
        (system.ptr, system.rows) = (graph_ptr, graph_rows);
        let cycle = AggregateCycle::renew(count, grouping, (&system.ptr, &system.rows), old.cycle);
        let chunk_blocks = chunk_blocks.max(1);
        let spans: Vec<(u32, u32)> = of
            .chunks(chunk_blocks)
            .map(|c| c.iter().fold((u32::MAX, 0), |(lo, hi), &a| (lo.min(a), hi.max(a))))
            .collect();
        let window = spans.iter().map(|&(lo, hi)| (hi - lo) as usize + 1).max().unwrap_or(0);
        CoarseSpace {
            chunk_blocks,
            window_first: spans.iter().map(|&(lo, _)| lo).collect(),
            window,
            of,
            ptr,
            members,
            run_ptr,
            run_aggregate,
            run_slot,
            run_sums,
            system,
            cycle,
            partial: old.partial,
            restricted: old.restricted,
            correction: old.correction,
            ..Default::default()
        }
    }

    /// Number of aggregates.
    pub fn aggregates(&self) -> usize {
        self.ptr.len() - 1
    }

    /// Modes per aggregate: 6 with positions, else 3.
    fn modes(&self) -> usize {
        if self.offsets.is_empty() {
            3
        } else {
            6
        }
    }

    /// Takes the blocks' positions (m), one per block: from now on each
    /// aggregate has its rotations too. Positions of another length are
    /// refused (the coarse level keeps translations alone).
    pub fn set_positions(&mut self, positions: &[[f64; 3]]) {
        if positions.len() != self.of.len() {
            self.offsets.clear();
            return;
        }
        self.offsets.resize(positions.len(), [0.0; 3]);
        self.centroids.resize(self.aggregates(), [0.0; 3]);
        let (ptr, members) = (&self.ptr, &self.members);
        for a in 0..ptr.len() - 1 {
            let blocks = &members[ptr[a] as usize..ptr[a + 1] as usize];
            let mut c = [0.0; 3];
            for &i in blocks {
                (0..3).for_each(|d| c[d] += positions[i as usize][d]);
            }
            let n = blocks.len() as f64;
            c = c.map(|c| c / n);
            for &i in blocks {
                let x = positions[i as usize];
                self.offsets[i as usize] = std::array::from_fn(|d| x[d] - c[d]);
            }
            self.centroids[a] = c;
        }
        self.cycle.set_centroids(&self.centroids, &self.ptr);
    }

    /// Assembles `A₁ = Pᵀ A P` from the values on `blocks` (`f64`, or the
    /// `f32` copy the iteration reads) and readies its solve.
    /// The run sums stream through the values in their order; each block
    /// column `b` of `A₁` then adds, for each member `j` and each run of
    /// aggregate `a` in its column, `[T  T S_j; U  U S_j]` to its block in
    /// row `a` (`T = Σ A_ij`, `U = Σ S_iᵀ A_ij`). Rotations of an aggregate
    /// too small or too flat to rotate (a single node, nodes on a line)
    /// have no stiffness: every rotation's diagonal gets [`ROTATION_FLOOR`]
    /// of the largest diagonal entry, so the factors exist and such a
    /// mode, whose `P` column is zero, corrects nothing.
    pub fn factor<T: Value>(&mut self, blocks: &BlockStructure, values: &[T]) -> Result<(), SolveError> {
        let k = self.modes();
        let kk = k * k;
        let mut sums = std::mem::take(&mut self.run_sums);
        self.sum_runs(blocks, values, 0..blocks.ptr.len() - 1, &mut sums);
        self.run_sums = sums;
        let mut system = std::mem::take(&mut self.system);
        system.k = k;
        system.values.resize(kk * system.rows.len(), 0.0);
        self.add_runs(&system.ptr, k, 0..self.aggregates(), &mut system.values);
        if k == 6 {
            let diagonal = |b: usize| system.slot(b as u32, b).expect("every aggregate couples to itself");
            let largest = (0..self.aggregates())
                .flat_map(|b| (0..6).map(move |r| (b, r)))
                .map(|(b, r)| system.values[kk * diagonal(b) + 7 * r])
                .fold(0.0f64, f64::max);
            for b in 0..self.aggregates() {
                let p = kk * system.slot(b as u32, b).expect("every aggregate couples to itself");
                (3..6).for_each(|r| system.values[p + 7 * r] += ROTATION_FLOOR * largest);
            }
        }
        let result = self.cycle.factor(&system);
        self.system = system;
        // (named by a degree of freedom of the system: the first of the
        // aggregate whose mode failed)
        result.map_err(|failed| {
            let first = self.members[self.ptr[failed.aggregate] as usize] as usize;
            SolveError::NotPositiveDefinite { pivot: 3 * first, n: 3 * self.of.len() }
        })
    }

    /// The block columns `columns` of `A₁` (`out` their values, `ptr` its
    /// block column offsets) from the run sums of their members, halving
    /// the range across threads down to a few columns.
    fn add_runs(&self, ptr: &[u32], k: usize, columns: std::ops::Range<usize>, out: &mut [f64]) {
        let kk = k * k;
        if columns.len() > AGGREGATE_TASK_COLUMNS {
            let mid = columns.start + columns.len() / 2;
            let (left, right) = out.split_at_mut(kk * (ptr[mid] - ptr[columns.start]) as usize);
            rayon::join(
                || self.add_runs(ptr, k, columns.start..mid, left),
                || self.add_runs(ptr, k, mid..columns.end, right),
            );
            return;
        }
        let rotations = k == 6;
        out.fill(0.0);
        let first_block = ptr[columns.start] as usize;
        for b in columns {
            for &j in &self.members[self.ptr[b] as usize..self.ptr[b + 1] as usize] {
                let runs = self.run_ptr[j as usize] as usize..self.run_ptr[j as usize + 1] as usize;
                let dj = if rotations { self.offsets[j as usize] } else { [0.0; 3] };
                for (sum, &slot) in self.run_sums[runs.clone()].iter().zip(&self.run_slot[runs]) {
                    let block = &mut out[kk * (slot as usize - first_block)..kk * (slot as usize - first_block + 1)];
                    // entry (r, c) at c k + r
                    for c in 0..3 {
                        (0..3).for_each(|r| block[c * k + r] += sum[3 * c + r]);
                        if rotations {
                            (0..3).for_each(|r| block[c * k + 3 + r] += sum[9 + 3 * c + r]);
                        }
                    }
                    if rotations {
                        // column c of M S_j is M (e_c × d_j)
                        for c in 0..3 {
                            let e = cross(unit(c), dj);
                            for r in 0..3 {
                                block[(3 + c) * k + r] += (0..3).map(|q| sum[3 * q + r] * e[q]).sum::<f64>();
                                block[(3 + c) * k + 3 + r] += (0..3).map(|q| sum[9 + 3 * q + r] * e[q]).sum::<f64>();
                            }
                        }
                    }
                }
            }
        }
    }

    /// The run sums of the block columns `columns` into `out` (theirs
    /// alone), halving the range across threads down to
    /// [`RUN_TASK_COLUMNS`] columns.
    fn sum_runs<T: Value>(
        &self,
        blocks: &BlockStructure,
        values: &[T],
        columns: std::ops::Range<usize>,
        out: &mut [[f64; 18]],
    ) {
        if columns.len() > RUN_TASK_COLUMNS {
            let mid = columns.start + columns.len() / 2;
            let split = (self.run_ptr[mid] - self.run_ptr[columns.start]) as usize;
            let (left, right) = out.split_at_mut(split);
            rayon::join(
                || self.sum_runs(blocks, values, columns.start..mid, left),
                || self.sum_runs(blocks, values, mid..columns.end, right),
            );
            return;
        }
        let first_run = self.run_ptr[columns.start] as usize;
        for j in columns {
            let rows = &blocks.rows[blocks.ptr[j] as usize..blocks.ptr[j + 1] as usize];
            let stride = 3 * rows.len();
            let column = &values[blocks.start[j]..blocks.start[j] + 3 * stride];
            let runs = self.run_ptr[j] as usize..self.run_ptr[j + 1] as usize;
            let aggregates = &self.run_aggregate[runs.clone()];
            let sums = &mut out[runs.start - first_run..runs.end - first_run];
            sums.fill([0.0; 18]);
            for (q, &row) in rows.iter().enumerate() {
                let a = self.of[row as usize];
                let k = aggregates.iter().position(|&b| b == a).expect("every row's aggregate has its run");
                let sum = &mut sums[k];
                let block: [f64; 9] = std::array::from_fn(|e| column[(e / 3) * stride + 3 * q + e % 3].to_f64());
                (0..9).for_each(|e| sum[e] += block[e]);
                if let Some(d) = self.offsets.get(row as usize) {
                    // S_iᵀ = [d_i]×: column c of S_iᵀ A_ij is d_i × (column c of A_ij)
                    for c in 0..3 {
                        let v = cross(*d, [block[3 * c], block[3 * c + 1], block[3 * c + 2]]);
                        (0..3).for_each(|r| sum[9 + 3 * c + r] += v[r]);
                    }
                }
            }
        }
    }

    /// Length of a restricted vector `Pᵀ r`: modes times aggregates.
    pub fn restricted_len(&self) -> usize {
        self.modes() * self.aggregates()
    }

    /// Length of the part of `Pᵀ r` that one chunk of blocks restricts
    /// into: the modes of [`CoarseSpace::window`] aggregates.
    pub fn window_len(&self) -> usize {
        self.modes() * self.window
    }

    /// `partial = Pᵀ r` of the blocks of chunk `chunk` (`r` their entries),
    /// over the window of aggregates from the chunk's first one (see
    /// [`CoarseSpace::window`]), summed in block order; a run of blocks in
    /// one aggregate is summed in registers.
    pub fn restrict(&self, chunk: usize, r: &[f64], partial: &mut [f64]) {
        let (k, first) = (self.modes(), chunk * self.chunk_blocks);
        let base = self.window_first.get(chunk).map_or(0, |&a| a as usize);
        partial.fill(0.0);
        let mut add = |a: usize, sum: &[f64; 6]| {
            let a = a - base;
            partial[k * a..k * a + k].iter_mut().zip(sum).for_each(|(p, s)| *p += s);
        };
        let Some(&start) = self.of.get(first) else { return };
        let (mut current, mut sum) = (start as usize, [0.0; 6]);
        for (q, r) in r.chunks_exact(3).enumerate() {
            let i = first + q;
            let a = self.of[i] as usize;
            if a != current {
                add(current, &sum);
                (current, sum) = (a, [0.0; 6]);
            }
            (0..3).for_each(|d| sum[d] += r[d]);
            if let Some(&d) = self.offsets.get(i) {
                let w = cross(d, [r[0], r[1], r[2]]);
                (0..3).for_each(|e| sum[3 + e] += w[e]);
            }
        }
        add(current, &sum);
    }

    /// Sums the partial restrictions (`partials`, one [`window_len`] run
    /// per chunk of blocks, in order) to `Pᵀ r` and solves `A₁ e = Pᵀ r`
    /// (by the cycle, [`AggregateCycle::apply`]) for the correction `e`
    /// that [`prolonged`] reads; returns `r · P e`, the correction's share
    /// of `r · z`.
    ///
    /// [`window_len`]: CoarseSpace::window_len
    /// [`prolonged`]: CoarseSpace::prolonged
    pub fn solve(&mut self, partials: &[f64]) -> f64 {
        self.sum_partials(partials);
        self.cycle.apply(self.system.k, &self.restricted, &mut self.correction);
        self.restricted.iter().zip(&self.correction).map(|(r, e)| r * e).sum()
    }

    /// `self.restricted = Pᵀ r` from the chunks' windows, in chunk order.
    fn sum_partials(&mut self, partials: &[f64]) {
        let (m, k, w) = (self.restricted_len(), self.modes(), self.window_len());
        self.restricted.clear();
        self.restricted.resize(m, 0.0);
        for (partial, &first) in partials.chunks_exact(w).zip(&self.window_first) {
            let at = k * first as usize;
            // (a window reaching past the last aggregate holds zeros there)
            let end = (at + w).min(m);
            self.restricted[at..end].iter_mut().zip(partial).for_each(|(s, p)| *s += p);
        }
        self.correction.resize(m, 0.0);
    }

    /// `(P e)_i`, the correction of the last [`CoarseSpace::solve`] at
    /// block `i`: its aggregate's translation plus, with positions, its
    /// rotation `ω × d_i`.
    #[inline(always)]
    pub fn prolonged(&self, i: usize) -> [f64; 3] {
        let a = self.modes() * self.of[i] as usize;
        let e = &self.correction;
        let mut add = [e[a], e[a + 1], e[a + 2]];
        if let Some(&d) = self.offsets.get(i) {
            let w = cross([e[a + 3], e[a + 4], e[a + 5]], d);
            (0..3).for_each(|c| add[c] += w[c]);
        }
        add
    }

    /// `z += P B Pᵀ r` (or, for [`Correction::Groups`], the exact
    /// correction of the aggregates of aggregates alone, `P T A₂⁻¹ Tᵀ Pᵀ
    /// r`), restricting per chunk of blocks in parallel; returns `r · z`'s
    /// share of the correction.
    pub fn correct(&mut self, r: &[f64], z: &mut [f64], correction: Correction) -> f64 {
        let (w, chunk_blocks) = (self.window_len(), self.chunk_blocks);
        let mut partials = std::mem::take(&mut self.partial);
        partials.resize(r.len().div_ceil(3 * chunk_blocks) * w, 0.0);
        partials.par_chunks_mut(w).zip(r.par_chunks(3 * chunk_blocks)).enumerate().for_each(|(t, (partial, r))| {
            self.restrict(t, r, partial);
        });
        let share = match correction {
            Correction::Whole => self.solve(&partials),
            Correction::Groups => {
                self.sum_partials(&partials);
                self.cycle.apply_groups(self.system.k, &self.restricted, &mut self.correction);
                self.restricted.iter().zip(&self.correction).map(|(r, e)| r * e).sum()
            }
        };
        self.partial = partials;
        z.par_chunks_mut(3 * chunk_blocks).enumerate().for_each(|(t, z)| {
            for (q, z) in z.chunks_exact_mut(3).enumerate() {
                let add = self.prolonged(t * chunk_blocks + q);
                (0..3).for_each(|e| z[e] += add[e]);
            }
        });
        share
    }
}

/// Which correction [`CoarseSpace::correct`] adds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Correction {
    /// `P B Pᵀ r`, the coarse level's.
    Whole,
    /// The aggregates of aggregates' alone, solved exactly.
    Groups,
}

/// The unit vector along axis `c`.
fn unit(c: usize) -> [f64; 3] {
    std::array::from_fn(|d| if d == c { 1.0 } else { 0.0 })
}

/// Aggregates of the `count` vertices of `graph` (offsets, neighbours),
/// coarsened by rounds of [`aggregate`] until the dense blocks of the
/// cycle, one per connected component ([`AggregateCycle`]: a body a cut
/// set in pieces has a block per piece), hold at most as many values as
/// one of `limit` aggregates would, `Σ count_c² ≤ limit²`; and their
/// number. A round merges in every component of more than one; a piece
/// that is one aggregate costs the cycle a `k x k` block. `None` when no
/// round is needed or the first merges nothing.
fn coarsen(graph: &(Vec<u32>, Vec<u32>), count: usize, limit: usize) -> Option<(Vec<u32>, usize)> {
    let mut of: Vec<u32> = (0..count as u32).collect();
    let (mut groups, mut quotient_graph) = (count, None::<(Vec<u32>, Vec<u32>)>);
    loop {
        let (ptr, adj) = quotient_graph.as_ref().unwrap_or(graph);
        let size = component_sizes(ptr, adj);
        // Σ over components of count_c² is Σ over vertices of count_c
        if size.iter().sum::<usize>() <= limit * limit {
            break;
        }
        let (round, merged) = aggregate(ptr, adj, 0..ptr.len() - 1, |v| size[v] > 1);
        if merged == groups {
            break;
        }
        of.iter_mut().for_each(|a| *a = round[*a as usize]);
        let (group_ptr, vertices) = group(&round, merged);
        quotient_graph = Some(quotient(ptr, adj, (&group_ptr, &vertices), |u| round[u as usize]));
        groups = merged;
    }
    (groups < count).then_some((of, groups))
}

/// The number of vertices of every vertex's connected component in the
/// graph (offsets, neighbours).
fn component_sizes(ptr: &[u32], adj: &[u32]) -> Vec<usize> {
    let n = ptr.len() - 1;
    let edges = (0..n).flat_map(|v| adj[ptr[v] as usize..ptr[v + 1] as usize].iter().map(move |&w| (v as u32, w)));
    let root = super::ordering::component_roots(n, edges);
    let mut size = vec![0usize; n];
    root.iter().for_each(|&r| size[r as usize] += 1);
    root.iter().map(|&r| size[r as usize]).collect()
}

/// One round of greedy aggregation of the graph whose vertex `v` has the
/// neighbours `adj[ptr[v]..ptr[v + 1]]` (itself among them or not), among
/// the vertices that `merges`, visited in the order `visit` (every vertex
/// once): a vertex whose neighbours are all free founds an aggregate of
/// itself and them; every vertex left then joins the aggregate of its
/// first neighbour that has one (after the first pass, every free vertex
/// has such a neighbour: else it would have founded one). A vertex that
/// does not merge (nor may any of its neighbours) is an aggregate of its
/// own. Returns the aggregate of every vertex (numbered as they were
/// founded) and their number.
fn aggregate(
    ptr: &[u32],
    adj: &[u32],
    visit: impl Iterator<Item = usize> + Clone,
    merges: impl Fn(usize) -> bool,
) -> (Vec<u32>, usize) {
    let n = ptr.len() - 1;
    let neighbours = |v: usize| if merges(v) { &adj[ptr[v] as usize..ptr[v + 1] as usize] } else { &[] };
    let mut of = vec![FREE; n];
    let mut count = 0u32;
    for v in visit.clone() {
        if of[v] == FREE && neighbours(v).iter().all(|&u| of[u as usize] == FREE) {
            of[v] = count;
            neighbours(v).iter().for_each(|&u| of[u as usize] = count);
            count += 1;
        }
    }
    let founded = of.clone();
    for v in visit {
        if of[v] == FREE {
            of[v] = neighbours(v).iter().map(|&u| founded[u as usize]).find(|&a| a != FREE).expect("see above");
        }
    }
    (of, count as usize)
}

/// The graph of groups of vertices (group `a`'s vertices at
/// `vertices[group_ptr[a]..group_ptr[a + 1]]`) of the graph whose vertex
/// `v` has the neighbours `adj[ptr[v]..ptr[v + 1]]`, each read as the group
/// `image(u)`: two groups are neighbours when any of their vertices are.
/// (The groups' neighbour lists are made in parallel, each in its own
/// order, then sorted: the graph does not depend on the thread count.
/// Every neighbour met is written at the list's end, which moves on only
/// past a new one, as the coarse space's runs are listed.)
fn quotient(
    ptr: &[u32],
    adj: &[u32],
    (group_ptr, vertices): (&[u32], &[u32]),
    image: impl Fn(u32) -> u32 + Sync,
) -> (Vec<u32>, Vec<u32>) {
    let count = group_ptr.len() - 1;
    let lists: Vec<Vec<u32>> = (0..count)
        .into_par_iter()
        .map_init(
            || (vec![FREE; count], Vec::new()),
            |(seen, met), a| {
                let group = &vertices[group_ptr[a] as usize..group_ptr[a + 1] as usize];
                let neighbours = |v: u32| &adj[ptr[v as usize] as usize..ptr[v as usize + 1] as usize];
                met.resize(group.iter().map(|&v| neighbours(v).len()).sum(), 0);
                let mut listed = 0;
                for &u in group.iter().flat_map(|&v| neighbours(v)) {
                    let b = image(u);
                    let new = seen[b as usize] != a as u32;
                    seen[b as usize] = a as u32;
                    met[listed] = b;
                    listed += usize::from(new);
                }
                let mut list = met[..listed].to_vec();
                list.sort_unstable();
                list
            },
        )
        .collect();
    let mut out_ptr = Vec::with_capacity(count + 1);
    out_ptr.push(0u32);
    for list in &lists {
        out_ptr.push(out_ptr[out_ptr.len() - 1] + list.len() as u32);
    }
    (out_ptr, lists.concat())
}

/// The vertices of each group of `of` (`count` groups), ascending: group
/// `a`'s at `members[ptr[a]..ptr[a + 1]]`.
pub(super) fn group(of: &[u32], count: usize) -> (Vec<u32>, Vec<u32>) {
    let mut ptr = vec![0u32; count + 1];
    of.iter().for_each(|&a| ptr[a as usize + 1] += 1);
    (0..count).for_each(|a| ptr[a + 1] += ptr[a]);
    let mut fill = ptr.clone();
    let mut members = vec![0u32; of.len()];
    for (i, &a) in of.iter().enumerate() {
        members[fill[a as usize] as usize] = i as u32;
        fill[a as usize] += 1;
    }
    (ptr, members)
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::linalg::solvers::Solve;
    use faer::sparse::SymbolicSparseColMat;

    /// The blocks of an `nx x ny x nz` grid, each coupled to its 6
    /// neighbours, as a pattern in the block layout, and symmetric positive
    /// definite values (symmetric and strictly diagonally dominant): about
    /// `-I` off the diagonal, about `7 I` on it, every entry perturbed.
    fn grid(nx: usize, ny: usize, nz: usize) -> (SymbolicSparseColMat<usize>, Vec<f64>) {
        let n = nx * ny * nz;
        let id = |x: usize, y: usize, z: usize| x + nx * (y + ny * z);
        let neighbours = |j: usize| {
            let (x, y, z) = (j % nx, (j / nx) % ny, j / (nx * ny));
            let mut out = vec![j];
            if x > 0 {
                out.push(id(x - 1, y, z));
            }
            if x + 1 < nx {
                out.push(id(x + 1, y, z));
            }
            if y > 0 {
                out.push(id(x, y - 1, z));
            }
            if y + 1 < ny {
                out.push(id(x, y + 1, z));
            }
            if z > 0 {
                out.push(id(x, y, z - 1));
            }
            if z + 1 < nz {
                out.push(id(x, y, z + 1));
            }
            out.sort_unstable();
            out
        };
        // entry (r, c) of block (i, j), symmetric as a scalar matrix
        let entry = |i: usize, j: usize, r: usize, c: usize| -> f64 {
            let (a, b) = ((3 * i + r).min(3 * j + c), (3 * i + r).max(3 * j + c));
            if i == j {
                return if r == c { 7.0 + 0.01 * i as f64 } else { 0.1 * ((a * 7 + b * 3) % 5) as f64 / 5.0 };
            }
            let jitter = ((a * 31 + b * 17) % 11) as f64 / 11.0;
            if r == c {
                -1.0 + 0.05 * jitter
            } else {
                0.02 * jitter
            }
        };
        let (mut col_ptr, mut row_idx, mut values) = (vec![0usize], Vec::new(), Vec::new());
        for j in 0..n {
            let rows = neighbours(j);
            for c in 0..3 {
                for &i in &rows {
                    for r in 0..3 {
                        row_idx.push(3 * i + r);
                        values.push(entry(i, j, r, c));
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        (SymbolicSparseColMat::new_checked(3 * n, 3 * n, col_ptr, None, row_idx), values)
    }

    /// Every block has an aggregate, every aggregate is connected in the
    /// matrix graph, one round makes the aggregates (none when the limit
    /// takes every block), and the aggregates of aggregates are coarsened
    /// to the limit.
    #[test]
    fn aggregates_cover_every_block_and_are_connected() {
        let (pattern, _) = grid(9, 7, 5);
        let blocks = BlockStructure::new(pattern.as_ref()).unwrap();
        let one_round = aggregate(&blocks.ptr, &blocks.rows, 0..blocks.len(), |_| true).1;
        for limit in [1000, 40, 5] {
            let coarse = CoarseSpace::new(&blocks, limit, 1024);
            let m = coarse.aggregates();
            let want = if limit >= 315 { 315 } else { one_round };
            assert_eq!(m, want, "limit {limit}: {m} aggregates");
            assert!(coarse.cycle.groups() <= limit, "limit {limit}: {} groups", coarse.cycle.groups());
            assert!(coarse.of.iter().all(|&a| (a as usize) < m));
            for a in 0..m {
                let members = &coarse.members[coarse.ptr[a] as usize..coarse.ptr[a + 1] as usize];
                assert!(!members.is_empty(), "aggregate {a} is empty");
                // breadth-first search inside the aggregate reaches all of it
                let mut reached = vec![members[0]];
                let mut next = 0;
                while next < reached.len() {
                    let v = reached[next] as usize;
                    next += 1;
                    for &u in &blocks.rows[blocks.ptr[v] as usize..blocks.ptr[v + 1] as usize] {
                        if coarse.of[u as usize] == a as u32 && !reached.contains(&u) {
                            reached.push(u);
                        }
                    }
                }
                assert_eq!(reached.len(), members.len(), "limit {limit}: aggregate {a} is not connected");
            }
        }
    }

    /// The aggregates' graph (read from the runs) is its definition: two
    /// aggregates are neighbours exactly when blocks of theirs are, each
    /// list ascending; every column's runs are the aggregates of its rows,
    /// each once, in the order the rows meet them, and each run's slot is
    /// that aggregate's place among its column aggregate's neighbours.
    #[test]
    fn the_aggregates_graph_and_the_runs_follow_the_block_rows() {
        let (pattern, _) = grid(9, 7, 5);
        let blocks = BlockStructure::new(pattern.as_ref()).unwrap();
        for limit in [40, 5] {
            let coarse = CoarseSpace::new(&blocks, limit, 1024);
            let (m, of) = (coarse.aggregates(), &coarse.of);
            let mut want = vec![std::collections::BTreeSet::new(); m];
            for j in 0..blocks.len() {
                let rows = blocks.column_rows(j);
                rows.iter().for_each(|&r| _ = want[of[j] as usize].insert(of[r as usize]));
                let mut met: Vec<u32> = Vec::new();
                rows.iter().map(|&r| of[r as usize]).for_each(|a| {
                    if !met.contains(&a) {
                        met.push(a)
                    }
                });
                let runs = coarse.run_ptr[j] as usize..coarse.run_ptr[j + 1] as usize;
                assert_eq!(coarse.run_aggregate[runs.clone()], met[..], "limit {limit}: runs of column {j}");
                for k in runs {
                    let slot = coarse.run_slot[k] as usize;
                    let own =
                        coarse.system.ptr[of[j] as usize] as usize..coarse.system.ptr[of[j] as usize + 1] as usize;
                    assert!(own.contains(&slot) && coarse.system.rows[slot] == coarse.run_aggregate[k]);
                }
            }
            for (a, want) in want.iter().enumerate() {
                let got = &coarse.system.rows[coarse.system.ptr[a] as usize..coarse.system.ptr[a + 1] as usize];
                assert_eq!(got, want.iter().copied().collect::<Vec<u32>>(), "limit {limit}: neighbours of {a}");
            }
        }
    }

    /// A body cut in pieces (a grid of 9 x 7 x 5 blocks, one of 3 x 2 x 1,
    /// 30 lone blocks): the cycle has a block per piece, the blocks within
    /// the budget of `limit` groups (`Σ g_c² ≤ limit²`), and the large
    /// piece keeps more than one group (coarsening stops at the budget, not
    /// when every piece is one group).
    #[test]
    fn a_body_in_pieces_has_a_block_per_piece_within_the_budget() {
        let parts: Vec<(usize, usize, usize)> =
            [(9, 7, 5), (3, 2, 1)].into_iter().chain(std::iter::repeat_n((1, 1, 1), 30)).collect();
        let (mut col_ptr, mut row_idx, mut first) = (vec![0usize], Vec::new(), 0);
        for &(nx, ny, nz) in &parts {
            let (pattern, _) = grid(nx, ny, nz);
            for c in 0..pattern.ncols() {
                row_idx.extend(pattern.row_idx_of_col(c).map(|r| r + first));
                col_ptr.push(row_idx.len());
            }
            first += pattern.nrows();
        }
        let pattern = SymbolicSparseColMat::new_checked(first, first, col_ptr, None, row_idx);
        let blocks = BlockStructure::new(pattern.as_ref()).unwrap();
        let limit = 8;
        let coarse = CoarseSpace::new(&blocks, limit, 1024);
        let sizes = coarse.cycle.component_groups();
        assert_eq!(sizes.len(), parts.len(), "{sizes:?}");
        assert!(sizes.iter().map(|g| g * g).sum::<usize>() <= limit * limit, "{sizes:?}");
        assert!(sizes[0] > 1, "{sizes:?}");
    }

    /// Positions of the blocks of [`grid`]: on a unit lattice, jittered.
    fn lattice(nx: usize, ny: usize, nz: usize) -> Vec<[f64; 3]> {
        (0..nx * ny * nz)
            .map(|j| {
                let (x, y, z) = (j % nx, (j / nx) % ny, j / (nx * ny));
                let jitter = 0.1 * (j as f64 * 1.3).sin();
                [x as f64 + jitter, y as f64 - jitter, z as f64 + 0.5 * jitter]
            })
            .collect()
    }

    /// `A_c = Pᵀ A P` and the correction `P A_c⁻¹ Pᵀ r` against the same
    /// products formed densely from `P` written out (`[I  -[d_i]×]` per
    /// block with positions, with the same `1e-12` on the rotations'
    /// diagonal; `I` without), and the returned `r · z`.
    #[test]
    fn the_correction_is_the_dense_coarse_solve() {
        let (nx, ny, nz) = (6, 5, 4);
        let (pattern, values) = grid(nx, ny, nz);
        let n = pattern.nrows();
        let blocks = BlockStructure::new(pattern.as_ref()).unwrap();
        // (a limit the aggregates of one round stay under: A₁ is solved exactly)
        let limit = aggregate(&blocks.ptr, &blocks.rows, 0..blocks.len(), |_| true).1;
        for (rotations, chunk_blocks) in [(false, 1024), (true, 1024), (false, 5), (true, 5)] {
            // restricted in one chunk, and in chunks of 5 blocks (runs of an
            // aggregate cut by chunk ends)
            let mut coarse = CoarseSpace::new(&blocks, limit, chunk_blocks);
            if rotations {
                // positions may come after a first factor of translations
                coarse.factor(&blocks, &values).unwrap();
                coarse.set_positions(&lattice(nx, ny, nz));
            }
            let k = if rotations { 6 } else { 3 };
            let m = k * coarse.aggregates();
            assert!(m > k, "a coarse level of more than one aggregate");
            coarse.factor(&blocks, &values).unwrap();
            let a = faer::sparse::SparseColMatRef::new(pattern.as_ref(), &values).to_dense();
            let p = faer::Mat::<f64>::from_fn(n, m, |i, col| {
                let (block, r) = (i / 3, i % 3);
                if coarse.of[block] as usize != col / k {
                    return 0.0;
                }
                match col % k {
                    c if c < 3 => f64::from(u8::from(c == r)),
                    c => {
                        // column c - 3 of -[d]×: e_c × d
                        let d = coarse.offsets[block];
                        cross(unit(c - 3), d)[r]
                    }
                }
            });
            let mut ac = p.transpose() * &a * &p;
            if rotations {
                let largest = (0..m).map(|i| ac[(i, i)]).fold(0.0f64, f64::max);
                (0..m).filter(|i| i % 6 >= 3).for_each(|i| ac[(i, i)] += 1e-12 * largest);
            }
            let r = faer::Mat::<f64>::from_fn(n, 1, |i, _| (i as f64 * 0.7).sin());
            let expected = &p * ac.llt(faer::Side::Lower).unwrap().solve(p.transpose() * &r);
            let base: Vec<f64> = (0..n).map(|i| 0.25 * (i as f64).cos()).collect();
            let r_slice: Vec<f64> = (0..n).map(|i| r[(i, 0)]).collect();
            let mut z = base.clone();
            let rz = coarse.correct(&r_slice, &mut z, Correction::Whole);
            for i in 0..n {
                let got = z[i] - base[i];
                let want = expected[(i, 0)];
                assert!(
                    (got - want).abs() <= 1e-12 * (1.0 + want.abs()),
                    "rotations {rotations}, chunks of {chunk_blocks}, entry {i}"
                );
            }
            let dense_rz: f64 = (0..n).map(|i| r[(i, 0)] * expected[(i, 0)]).sum();
            assert!((rz - dense_rz).abs() <= 1e-12 * dense_rz.abs(), "rotations {rotations}");
        }
    }

    /// With more aggregates than the limit, `B` is the cycle: the
    /// correction `z = P B Pᵀ r` must still be a symmetric positive
    /// definite operator, as conjugate gradients need (the cycle's formula
    /// is tested in `aggregate_cycle`, what it saves in `cg`).
    #[test]
    fn the_cycle_is_symmetric_and_positive() {
        // the stiffness of a box of 8 x 8 x 8 cells of tetrahedra plus a
        // mass-like diagonal, as a step's matrix is
        use crate::store::{BasisOptions, ElementStore};
        let mesh = crate::meshing::box_tet([0.0; 3], [1.0; 3], [8; 3]).unwrap();
        let material = crate::material::Material::new(1e5, 0.3, 1000.0).unwrap();
        let store = ElementStore::build(&mesh, &material, &BasisOptions::default()).unwrap();
        let system = crate::assembly::SparsePattern::build(mesh.nodes.len(), &store);
        let mut values = vec![0.0; system.nnz()];
        system.assemble(&mut values, |b, i, c, out| store.batches[b].block_column(i, c, out));
        (0..3 * mesh.nodes.len()).for_each(|d| values[system.diagonal_slot(d)] += 1e2);
        let (n, blocks) = (3 * mesh.nodes.len(), system.blocks());
        for rotations in [false, true] {
            let mut coarse = CoarseSpace::new(blocks, 8, 64);
            if rotations {
                coarse.set_positions(&mesh.nodes);
            }
            coarse.factor(blocks, &values).unwrap();
            assert!(!coarse.cycle.is_exact() && coarse.cycle.groups() <= 8, "{} groups", coarse.cycle.groups());
            let vector = |seed: f64| -> Vec<f64> { (0..n).map(|i| (i as f64 * seed).sin() + 0.3).collect() };
            let mut apply = |r: &[f64]| -> Vec<f64> {
                let mut z = vec![0.0; n];
                coarse.correct(r, &mut z, Correction::Whole);
                z
            };
            let (u, v) = (vector(0.37), vector(1.91));
            let (bu, bv) = (apply(&u), apply(&v));
            let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
            let (ubv, vbu) = (dot(&u, &bv), dot(&v, &bu));
            assert!(
                (ubv - vbu).abs() <= 1e-10 * ubv.abs().max(vbu.abs()),
                "rotations {rotations}: {ubv} against {vbu}"
            );
            assert!(dot(&u, &bu) > 0.0 && dot(&v, &bv) > 0.0, "rotations {rotations}");
        }
    }

    /// A coarse matrix that is not positive definite is reported at a
    /// degree of freedom of the system: the first of the aggregate whose
    /// mode failed, out of the system's size (not the coarse matrix's).
    #[test]
    fn a_failing_coarse_factor_names_a_degree_of_freedom_of_the_system() {
        let (pattern, mut values) = grid(8, 1, 1);
        let blocks = BlockStructure::new(pattern.as_ref()).unwrap();
        let mut coarse = CoarseSpace::new(&blocks, 4, 1024);
        let a = coarse.aggregates() - 1;
        assert!(a >= 1, "{} aggregates", a + 1);
        // the last aggregate's own couplings negated: its coarse block is
        // negative definite, the others' stay positive
        let last = |b: usize| coarse.of[b] as usize == a;
        let (col_ptr, row_idx) = (pattern.col_ptr(), pattern.row_idx());
        for c in 0..pattern.ncols() {
            for at in col_ptr[c]..col_ptr[c + 1] {
                if last(c / 3) && last(row_idx[at] / 3) {
                    values[at] = -values[at];
                }
            }
        }
        let first = coarse.members[coarse.ptr[a] as usize] as usize;
        assert_eq!(coarse.factor(&blocks, &values), Err(SolveError::NotPositiveDefinite { pivot: 3 * first, n: 24 }));
    }

    /// An aggregate that cannot rotate (a lone block, blocks on a line)
    /// still factors, and its rotations add nothing to `z`.
    #[test]
    fn aggregates_that_cannot_rotate_still_factor() {
        for (nx, ny, nz) in [(1, 1, 1), (5, 1, 1)] {
            let (pattern, values) = grid(nx, ny, nz);
            let blocks = BlockStructure::new(pattern.as_ref()).unwrap();
            let mut coarse = CoarseSpace::new(&blocks, 1, 1024);
            let line: Vec<[f64; 3]> = (0..nx).map(|x| [x as f64, 0.0, 0.0]).collect();
            coarse.set_positions(&line);
            coarse.factor(&blocks, &values).unwrap();
            let r: Vec<f64> = (0..3 * nx).map(|i| 1.0 + i as f64).collect();
            let mut z = vec![0.0; 3 * nx];
            coarse.correct(&r, &mut z, Correction::Whole);
            assert!(z.iter().all(|v| v.is_finite()), "{nx} blocks on a line: {z:?}");
            if nx == 1 {
                // a lone block's correction is its translations' alone
                let mut translations = CoarseSpace::new(&blocks, 1, 1024);
                translations.factor(&blocks, &values).unwrap();
                let mut expected = vec![0.0; 3];
                translations.correct(&r, &mut expected, Correction::Whole);
                for (a, b) in z.iter().zip(&expected) {
                    assert!((a - b).abs() <= 1e-12 * b.abs(), "a lone block: {z:?} vs {expected:?}");
                }
            }
        }
    }
}
