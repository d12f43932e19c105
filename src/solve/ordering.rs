//! Orderings of a matrix's blocks for locality: reverse Cuthill–McKee (and
//! the connected components of a graph), and
//! a 3x3 block structure renumbered into such an order, with the maps that
//! carry its values and vectors there and back.
//!
//! A product `A x` over block columns reads, per column, the entries of `x`
//! at the column's block rows. Meshes arrive numbered as their files number
//! them (in bunny_100k, 64 % of the coupled block pairs lie more than 2,000
//! blocks apart), and those reads then miss the caches: on one AMD EPYC
//! core, the `f32` product of bunny_100k's matrix took 1.41 ms in the file's
//! order and 0.55 ms for a box of as many values numbered row by row. In a
//! reverse Cuthill–McKee order a column's rows lie within the order's
//! bandwidth of it, so the reads of consecutive columns overlap.

use std::ops::Range;

use cleave_kernels::sliced::{SlicedLayout, WINDOW};
use cleave_kernels::spmv::BlockColumns;
use rayon::prelude::*;

use super::BlockStructure;

/// The connected components of the `n` vertices joined by `edges`: every
/// vertex's root, the first (lowest-numbered) vertex of its component.
pub(crate) fn component_roots(n: usize, edges: impl Iterator<Item = (u32, u32)>) -> Vec<u32> {
    let mut root: Vec<u32> = (0..n as u32).collect();
    let find = |root: &mut [u32], mut v: u32| {
        while root[v as usize] != v {
            let up = root[root[v as usize] as usize];
            root[v as usize] = up;
            v = up;
        }
        v
    };
    for (v, w) in edges {
        let (x, y) = (find(&mut root, v), find(&mut root, w));
        root[x.max(y) as usize] = x.min(y);
    }
    for v in 0..n as u32 {
        root[v as usize] = find(&mut root, v);
    }
    root
}

/// Reverse Cuthill–McKee order of a graph of `n` vertices: per connected
/// component, a breadth-first search from a pseudo-peripheral vertex
/// (George–Liu), visiting neighbours by increasing degree (ties by index),
/// then the whole order reversed. Vertices may repeat in `neighbours`.
pub(crate) fn reverse_cuthill_mckee<I: Iterator<Item = usize>>(n: usize, neighbours: impl Fn(usize) -> I) -> Vec<u32> {
    let degree: Vec<usize> = (0..n).map(|v| neighbours(v).count()).collect();
    let mut order: Vec<u32> = Vec::with_capacity(n);
    let mut placed = vec![false; n];
    let mut seen = vec![usize::MAX; n];
    let mut stamp = 0;
    // breadth-first levels from `root` over unplaced vertices: the last
    // level's vertices and the number of levels
    let mut levels = |root: usize, placed: &[bool], out: &mut Vec<usize>| -> (usize, usize) {
        stamp += 1;
        out.clear();
        out.push(root);
        seen[root] = stamp;
        let (mut begin, mut depth) = (0, 0);
        loop {
            let end = out.len();
            for idx in begin..end {
                for u in neighbours(out[idx]) {
                    if !placed[u] && seen[u] != stamp {
                        seen[u] = stamp;
                        out.push(u);
                    }
                }
            }
            if out.len() == end {
                return (begin, depth);
            }
            begin = end;
            depth += 1;
        }
    };
    let mut queue = Vec::with_capacity(n);
    let mut next: Vec<usize> = Vec::new();
    for seed in 0..n {
        if placed[seed] {
            continue;
        }
        // pseudo-peripheral root: move to a least-degree vertex of the last
        // level while that makes the search deeper
        let mut root = seed;
        let (mut last, mut depth) = levels(root, &placed, &mut queue);
        loop {
            let candidate = *queue[last..].iter().min_by_key(|&&u| (degree[u], u)).unwrap_or(&root);
            let (l, d) = levels(candidate, &placed, &mut queue);
            if d <= depth {
                break;
            }
            (root, last, depth) = (candidate, l, d);
        }
        // Cuthill–McKee from the root
        let begin = order.len();
        order.push(root as u32);
        placed[root] = true;
        let mut head = begin;
        while head < order.len() {
            let v = order[head] as usize;
            head += 1;
            next.clear();
            next.extend(neighbours(v).filter(|&u| !placed[u]));
            next.sort_unstable_by_key(|&u| (degree[u], u));
            next.dedup();
            for &u in &next {
                if !placed[u] {
                    placed[u] = true;
                    order.push(u as u32);
                }
            }
        }
    }
    order.reverse();
    order
}

/// Block columns per parallel task of the renumbering's passes.
const TASK_COLUMNS: usize = 256;

// (a range split in halves at windows leaves both halves some columns)
const _: () = assert!(TASK_COLUMNS >= 2 * WINDOW);

/// How much larger than its reverse Cuthill–McKee order's envelope a
/// structure's own may be for [`Renumbering::renew`] to keep it. (The
/// order is not idempotent: bunny_100k's matrix has an envelope of 96.3M
/// blocks in the file's order, 10.28M in its reverse Cuthill–McKee order
/// (the order `PolyMesh::renumber_for_locality` gives the mesh), and 9.17M
/// in that order's own.)
const KEPT_ENVELOPE: f64 = 1.25;

/// How many times the blocks of the last whole analysis a structure may
/// hold for [`Renumbering::renew`] to append its new blocks to that
/// analysis's order instead of ordering it again. Twelve blade cuts across
/// bunny_100k append 12.6k nodes to its 17.6k (72 %); the clamped steps
/// after them took 1.82 ms per iteration with the blocks appended against
/// 1.83 ms with each placed after its first old neighbour (Intel Xeon
/// model 207): the appended columns' reads of the vector are scattered,
/// but a vector of 30k blocks (720 kB) stays in the caches.
const KEPT_GROWTH: usize = 2;

/// The blocks of `blocks` in the order of the first `analysed` (an order
/// for locality), each later block (appended since) right after the
/// earliest of them it reaches through later blocks, its anchor (the
/// earliest anchor of its neighbours before it, itself if there is none);
/// blocks of the same anchor follow it in their own order. A greedy
/// aggregation visiting the blocks so founds its aggregates as it would
/// in an order for locality of all blocks: on twelve blade cuts across
/// bunny_100k, the appended blocks visited last made the clamped steps
/// after them take 1127 iterations for 1007.
pub(super) fn anchored_order(blocks: &BlockStructure, analysed: usize) -> Vec<u32> {
    let n = blocks.len();
    let analysed = analysed.min(n);
    let mut anchor: Vec<u32> = (0..analysed as u32).collect();
    let mut later: Vec<(u32, u32)> = Vec::with_capacity(n - analysed);
    for b in analysed..n {
        let reached = blocks.column_rows(b).iter().filter(|&&r| (r as usize) < b).map(|&r| anchor[r as usize]).min();
        let a = reached.unwrap_or(b as u32);
        anchor.push(a);
        later.push((a, b as u32));
    }
    later.sort_unstable();
    let mut order = Vec::with_capacity(n);
    let mut next = later.iter().peekable();
    for b in 0..n as u32 {
        if (b as usize) < analysed {
            order.push(b);
        }
        while let Some(&&(_, c)) = next.peek().filter(|(a, _)| *a == b) {
            order.push(c);
            next.next();
        }
    }
    order
}

/// The envelope of a symmetric structure under a numbering: `Σ_j (j -
/// min_i i)` over every column `j` and its rows `i` (`rows(j)` in the
/// numbering, `at(j)` the column's own number there), the entries a
/// profile factor would store, and how far a column's reads of a vector
/// reach back.
fn envelope<I: Iterator<Item = usize>>(n: usize, rows: impl Fn(usize) -> I, at: impl Fn(usize) -> usize) -> usize {
    (0..n).map(|j| at(j).saturating_sub(rows(j).min().unwrap_or(usize::MAX))).sum()
}

/// A block structure (in the layout of [`BlockStructure`]) renumbered in
/// the reverse Cuthill–McKee order of its block graph: new block `b` is old
/// block `order[b]`, every column's rows sorted in the new numbering.
#[derive(Clone, Debug, Default)]
pub(super) struct Renumbering {
    /// The old block of every new block.
    order: Vec<u32>,
    /// The new block of every old block.
    rank: Vec<u32>,
    /// Per new block column, the first value of its old column.
    old_start: Vec<usize>,
    /// Per block of the new structure, in its order: the place of the same
    /// block among the rows of its old column (empty for the identity,
    /// where every block keeps its place).
    source: Vec<u32>,
    /// Per new block column, its old column's rows in their old order,
    /// numbered in the new numbering: with `old_start`, the old values read
    /// as the new columns (see [`Renumbering::old_columns`]; empty for the
    /// identity, where they are the renumbered structure's rows).
    unsorted: Vec<u32>,
    /// The renumbered structure.
    blocks: BlockStructure,
    /// Per new block column, the place of its diagonal block among its
    /// rows (`u32::MAX`: none).
    diagonal: Vec<u32>,
    /// The number of blocks of the last whole analysis, to which later
    /// renewals append their new blocks up to [`KEPT_GROWTH`] times as many.
    analysed: usize,
    /// Whether `order` is the identity (the whole analysis kept the
    /// structure's own order, and blocks were appended since): the
    /// renumbered structure is then the structure itself, copied, and the
    /// values keep their layout.
    identity: bool,
    /// The renumbering before the last [`Renumbering::renew`], whose sorted
    /// columns an appended order reuses (and whose arrays the next renewal
    /// writes into).
    last: SortedColumns,
}

/// The order and sorted columns of a renumbering, kept for the next one.
#[derive(Clone, Debug, Default)]
struct SortedColumns {
    order: Vec<u32>,
    rank: Vec<u32>,
    ptr: Vec<u32>,
    rows: Vec<u32>,
    source: Vec<u32>,
}

impl Renumbering {
    /// Renumbers `old` (reusing this renumbering's arrays). A structure
    /// that extends the last one renumbered (its blocks first, new ones
    /// after them, as a cut appends its nodes) keeps the last order with
    /// the new blocks appended, in their own order, while it holds at most
    /// [`KEPT_GROWTH`] times the blocks of the last whole analysis: the old
    /// blocks keep their numbers, and the cut costs no search over the
    /// whole graph. Otherwise the whole analysis: the reverse Cuthill–McKee
    /// order, or the structure's own when its envelope is at most
    /// [`KEPT_ENVELOPE`] times that one's (a mesh renumbered for locality:
    /// carrying values and vectors is then streaming them).
    ///
    /// In the structure's own order (the identity), the renumbered columns
    /// are copies of its columns, and no permutation of them is kept (on
    /// renumbered bunny_100k, a cut then writes a third of the arrays it
    /// wrote). Otherwise a column whose rows did not
    /// change keeps its sorted permutation, and only the columns a cut
    /// changed are sorted again (on bunny_100k, sorting every column took
    /// 5.5-6 ms of a cut on 2 threads).
    pub fn renew(&mut self, old: &BlockStructure) {
        let n = old.len();
        let before = self.order.len();
        // (the last renumbering moves aside, its arrays reused below)
        let last = &mut self.last;
        std::mem::swap(&mut self.order, &mut last.order);
        std::mem::swap(&mut self.rank, &mut last.rank);
        std::mem::swap(&mut self.blocks.ptr, &mut last.ptr);
        std::mem::swap(&mut self.blocks.rows, &mut last.rows);
        std::mem::swap(&mut self.source, &mut last.source);
        let kept = 0 < before && before <= n && n <= KEPT_GROWTH * self.analysed;
        if kept {
            self.order.clear();
            self.order.extend_from_slice(&self.last.order);
            self.order.extend(before as u32..n as u32);
            self.rank.clear();
            self.rank.extend_from_slice(&self.last.rank);
            self.rank.extend(before as u32..n as u32);
        } else {
            let order = reverse_cuthill_mckee(n, |v| old.column_rows(v).iter().map(|&r| r as usize));
            self.rank_by(&order);
            let reordered = self.envelope_of(old);
            let own = envelope(n, |j| old.column_rows(j).iter().map(|&r| r as usize), |j| j);
            self.identity = own as f64 <= KEPT_ENVELOPE * reordered as f64;
            self.order = order;
            if self.identity {
                self.order.clear();
                self.order.extend(0..n as u32);
                self.rank.clone_from(&self.order);
            }
            self.analysed = n;
        }
        self.old_start.clear();
        crate::reserve_room(&mut self.old_start, n);
        self.old_start.extend(self.order.iter().map(|&o| old.start[o as usize]));
        let blocks = &mut self.blocks;
        blocks.ptr.clear();
        crate::reserve_room(&mut blocks.ptr, n + 1);
        blocks.ptr.push(0);
        for &o in &self.order {
            let end = blocks.ptr[blocks.ptr.len() - 1] + old.column_rows(o as usize).len() as u32;
            blocks.ptr.push(end);
        }
        blocks.start.clear();
        crate::reserve_room(&mut blocks.start, n);
        blocks.start.extend(blocks.ptr[..n].iter().map(|&p| 9 * p as usize));
        let total = old.rows_len();
        crate::resize_with_room(&mut blocks.rows, total, 0);
        let permuted = if self.identity { 0 } else { total };
        crate::resize_with_room(&mut self.source, permuted, 0);
        crate::resize_with_room(&mut self.unsorted, permuted, 0);
        // each task copies its columns' rows (in the structure's own order),
        // or sorts them into their new numbers, reusing the last sorted
        // permutation of a column that did not change
        let (order, rank, identity) = (&self.order, &self.rank, self.identity);
        let last = kept.then_some(&self.last);
        let sort = |columns: Range<usize>, (rows, (source, unsorted)): (Along<u32>, (Along<u32>, Along<u32>))| {
            let (rows, source, unsorted) = (rows.0, source.0, unsorted.0);
            if identity {
                rows.copy_from_slice(&old.rows[old.ptr[columns.start] as usize..old.ptr[columns.end] as usize]);
                return;
            }
            let mut at = 0;
            for j in columns {
                let o = order[j] as usize;
                let column = old.column_rows(o);
                let renumbered = &mut unsorted[at..at + column.len()];
                renumbered.iter_mut().zip(column).for_each(|(u, &r)| *u = rank[r as usize]);
                if let Some(permutation) = last.filter(|_| o < before).and_then(|last| last.unchanged(o, column)) {
                    for (k, &q) in permutation.iter().enumerate() {
                        (rows[at + k], source[at + k]) = (renumbered[q as usize], q);
                    }
                    at += column.len();
                    continue;
                }
                // (a column's rows are distinct: an unstable sort is exact;
                // a row and its place packed into one integer, row first,
                // sort as the pairs would, with one comparison each)
                let mut pairs: smallvec::SmallVec<[u64; 64]> =
                    renumbered.iter().enumerate().map(|(q, &r)| (u64::from(r) << 32) | q as u64).collect();
                pairs.sort_unstable();
                for (k, pair) in pairs.into_iter().enumerate() {
                    (rows[at + k], source[at + k]) = ((pair >> 32) as u32, pair as u32);
                }
                at += column.len();
            }
        };
        let parts =
            (Along::blocks(&mut blocks.rows), (Along::blocks(&mut self.source), Along::blocks(&mut self.unsorted)));
        in_column_tasks(&blocks.ptr, 0..n, parts, &sort, &|(), ()| ());
        // the place of every new column's diagonal block among its rows
        let (rows, ptr) = (&blocks.rows, &blocks.ptr);
        self.diagonal.clear();
        crate::reserve_room(&mut self.diagonal, n);
        self.diagonal.par_extend((0..n).into_par_iter().map(|j| {
            let column = &rows[ptr[j] as usize..ptr[j + 1] as usize];
            column.binary_search(&(j as u32)).map_or(u32::MAX, |p| p as u32)
        }));
    }

    /// Sets `rank` to the inverse of `order`.
    fn rank_by(&mut self, order: &[u32]) {
        crate::resize_with_room(&mut self.rank, order.len(), 0);
        for (new, &o) in order.iter().enumerate() {
            self.rank[o as usize] = new as u32;
        }
    }

    /// The envelope of `old` in the numbering `rank`.
    fn envelope_of(&self, old: &BlockStructure) -> usize {
        let rank = &self.rank;
        envelope(old.len(), |j| old.column_rows(j).iter().map(|&r| rank[r as usize] as usize), |j| rank[j] as usize)
    }

    /// The number of blocks of the last whole analysis: the renumbered
    /// structure's blocks from there on were appended since.
    pub fn analysed(&self) -> usize {
        self.analysed
    }

    /// The renumbered structure.
    pub fn blocks(&self) -> &BlockStructure {
        &self.blocks
    }

    /// The old block of every new block.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// The new block of every old block.
    pub fn rank(&self) -> &[u32] {
        &self.rank
    }

    /// The values laid out on the old structure read as the new block
    /// columns: new column `j` is old column `order[j]`, its rows in their
    /// old order but numbered in the new numbering (so a product with it
    /// takes and gives vectors in the new numbering, summed as on the old
    /// structure).
    pub fn old_columns(&self) -> BlockColumns<'_> {
        let rows = if self.identity { &self.blocks.rows } else { &self.unsorted };
        BlockColumns { ptr: &self.blocks.ptr, rows, start: &self.old_start }
    }

    /// The place among the rows of new column `j`'s old column of the
    /// block at place `p` of the new column.
    fn source(&self, j: usize, p: usize) -> usize {
        if self.identity {
            p
        } else {
            self.source[self.blocks.ptr[j] as usize + p] as usize
        }
    }

    /// Writes the values `old` (laid out on the old structure) in the new
    /// layout rounded to `f32` into `rounded`, and `diagonal(block)` of
    /// every diagonal block (row-major, from the `f64` values) into
    /// `diagonals`, in the new numbering. Each parallel task of columns
    /// then calls `task_done(columns, rounded, parts)` with its stretch of
    /// the rounded values and of the arrays `parts` while its columns'
    /// values are still in the cache (to take products with them on
    /// [`Renumbering::old_columns`]); their
    /// results are combined in column order. Returns whether every value
    /// is finite, whether every rounded one is (a finite value beyond
    /// `f32`'s range rounds to infinity), and the tasks' combined result.
    /// Every block column must hold its diagonal block
    /// ([`Renumbering::missing_diagonal`]).
    #[allow(clippy::too_many_arguments)]
    pub fn round_values<D: Send, P: AlongColumns, R: Send>(
        &self,
        old: &[f64],
        rounded: &mut [f32],
        diagonals: &mut [D],
        diagonal: impl Fn([f64; 9]) -> D + Sync,
        parts: P,
        task_done: impl Fn(Range<usize>, &[f32], &mut P) -> R + Sync,
        combine: impl Fn(R, R) -> R + Sync,
    ) -> (bool, bool, R) {
        let column_done = |j: usize, q: usize, column: &[f64], out: &[f32], (diagonals, _): &mut (Along<D>, P)| {
            let (stride, at) = (column.len() / 3, 3 * self.source(j, self.diagonal[j] as usize));
            let block = std::array::from_fn(|e| column[(e % 3) * stride + at + e / 3]);
            diagonals.0[q] = diagonal(block);
            out.iter().all(|v| v.is_finite())
        };
        let parts = (Along::columns(diagonals, 1), parts);
        let (in_range, result) = self.carry(
            old,
            rounded,
            |v| v as f32,
            parts,
            column_done,
            |columns, rounded, (_, parts)| task_done(columns, rounded, parts),
            combine,
        );
        // (every rounded value finite: then so is every value; else the
        // values themselves are looked at)
        (in_range || old.par_iter().all(|v| v.is_finite()), in_range, result)
    }

    /// Writes the values `old` (laid out on the old structure) in the new
    /// layout into `out`.
    pub fn carry_exact(&self, old: &[f64], out: &mut [f64]) {
        self.carry(old, out, |v| v, (), |_, _, _, _, _| true, |_, _, _| (), |(), ()| ());
    }

    /// The old number of the first block whose column has no diagonal
    /// block, if any.
    pub fn missing_diagonal(&self) -> Option<u32> {
        let missing = self.diagonal.iter().position(|&p| p == u32::MAX)?;
        Some(self.order[missing])
    }

    /// Writes `convert(v)` for every value `v` of `old` (laid out on the
    /// old structure) into `out` in the new layout, and calls
    /// `column_done(j, q, old column j, its new values, parts)` for every
    /// new block column `j` once it is written, the `q`-th column of its
    /// task, with the task's stretch of the arrays `parts`, and
    /// `task_done(columns, out, parts)` once a task's columns are (`out`
    /// their values); returns
    /// whether the check `column_done` returns held for every column, and
    /// the results of `task_done` combined in column order.
    #[allow(clippy::too_many_arguments)]
    fn carry<T: Copy + Send, P: AlongColumns, R: Send>(
        &self,
        old: &[f64],
        out: &mut [T],
        convert: impl Fn(f64) -> T + Sync,
        parts: P,
        column_done: impl Fn(usize, usize, &[f64], &[T], &mut P) -> bool + Sync,
        task_done: impl Fn(Range<usize>, &[T], &mut P) -> R + Sync,
        combine: impl Fn(R, R) -> R + Sync,
    ) -> (bool, R) {
        let blocks = &self.blocks;
        let n = blocks.len();
        let old_column = |j: usize| {
            let stride = 3 * (blocks.ptr[j + 1] - blocks.ptr[j]) as usize;
            &old[self.old_start[j]..self.old_start[j] + 3 * stride]
        };
        let carry = |columns: Range<usize>, (out, mut parts): (Along<T>, P)| {
            let (out, mut at, mut checked, first) = (out.0, 0, true, columns.start);
            for j in columns.clone() {
                // (the old columns lie all over the values: the next one's
                // lines are asked for while this one is carried)
                if j + 1 < columns.end {
                    old_column(j + 1).iter().step_by(8).for_each(crate::assembly::prefetch);
                }
                let stride = 3 * (blocks.ptr[j + 1] - blocks.ptr[j]) as usize;
                let column = old_column(j);
                let out = &mut out[at..at + 3 * stride];
                if self.identity {
                    out.iter_mut().zip(column).for_each(|(to, &from)| *to = convert(from));
                } else {
                    let source = &self.source[blocks.ptr[j] as usize..blocks.ptr[j + 1] as usize];
                    for (column, out) in column.chunks_exact(stride).zip(out.chunks_exact_mut(stride)) {
                        for (to, &q) in out.chunks_exact_mut(3).zip(source) {
                            let q = 3 * q as usize;
                            let from = &column[q..q + 3];
                            (to[0], to[1], to[2]) = (convert(from[0]), convert(from[1]), convert(from[2]));
                        }
                    }
                }
                checked &= column_done(j, j - first, column, out, &mut parts);
                at += 3 * stride;
            }
            (checked, task_done(columns, out, &mut parts))
        };
        let combine = |(a, x): (bool, R), (b, y): (bool, R)| (a && b, combine(x, y));
        in_column_tasks(&blocks.ptr, 0..n, (Along::values(out), parts), &carry, &combine)
    }

    /// `new[b] = old[order[b]]`: a vector of the old numbering in the new.
    pub fn to_new<T: Copy + Send + Sync>(&self, old: &[T], new: &mut [T]) {
        new.par_iter_mut().zip(&self.order).for_each(|(n, &o)| *n = old[o as usize]);
    }

    /// `old[b] = new[rank[b]]`: a vector of the new numbering in the old.
    pub fn to_old<T: Copy + Send + Sync>(&self, new: &[T], old: &mut [T]) {
        old.par_iter_mut().zip(&self.rank).for_each(|(o, &r)| *o = new[r as usize]);
    }
}

impl SortedColumns {
    /// The sorted permutation of old block `o`'s column (`source`) when
    /// its rows `column` are the ones it had in this renumbering (the same
    /// old blocks at the same places): then, the old blocks keeping their
    /// relative order, they sort the same way again.
    fn unchanged(&self, o: usize, column: &[u32]) -> Option<&[u32]> {
        let p = *self.rank.get(o)? as usize;
        let span = self.ptr[p] as usize..self.ptr[p + 1] as usize;
        let (rows, source) = (&self.rows[span.clone()], &self.source[span]);
        let same = rows.len() == column.len()
            && rows.iter().zip(source).all(|(&r, &q)| column[q as usize] == self.order[r as usize]);
        same.then_some(source)
    }
}

/// Arrays laid out along the block columns, which [`in_column_tasks`]
/// splits between its tasks.
pub(super) trait AlongColumns: Send + Sized {
    /// The stretch of the first `blocks` blocks and `columns` columns, and
    /// the rest.
    fn split(self, blocks: usize, columns: usize) -> (Self, Self);
}

/// An array of `per_block` items for each block of the columns and
/// `per_column` for each column (an empty array: none).
pub(super) struct Along<'a, T>(pub &'a mut [T], usize, usize);

impl<'a, T> Along<'a, T> {
    /// One item per block, or none when `items` is empty.
    fn blocks(items: &'a mut [T]) -> Self {
        let per_block = usize::from(!items.is_empty());
        Along(items, per_block, 0)
    }

    /// The nine values of each block.
    fn values(items: &'a mut [T]) -> Self {
        Along(items, 9, 0)
    }

    /// `per_column` items per column, or none when `items` is empty.
    pub fn columns(items: &'a mut [T], per_column: usize) -> Self {
        let per_column = if items.is_empty() { 0 } else { per_column };
        Along(items, 0, per_column)
    }
}

impl<T: Send> AlongColumns for Along<'_, T> {
    fn split(self, blocks: usize, columns: usize) -> (Self, Self) {
        let Along(items, per_block, per_column) = self;
        let (first, rest) = items.split_at_mut(per_block * blocks + per_column * columns);
        (Along(first, per_block, per_column), Along(rest, per_block, per_column))
    }
}

impl<A: AlongColumns, B: AlongColumns> AlongColumns for (A, B) {
    fn split(self, blocks: usize, columns: usize) -> (Self, Self) {
        let ((a0, a1), (b0, b1)) = (self.0.split(blocks, columns), self.1.split(blocks, columns));
        ((a0, b0), (a1, b1))
    }
}

/// The sliced values of the columns from `first` on (the stretch of their
/// groups, [`SlicedLayout::values_of`]): split at windows.
pub(super) struct AlongGroups<'a> {
    pub values: &'a mut [f32],
    pub layout: &'a SlicedLayout,
    pub first: usize,
}

impl AlongColumns for AlongGroups<'_> {
    fn split(self, _: usize, columns: usize) -> (Self, Self) {
        let AlongGroups { values, layout, first } = self;
        let mid = first + columns;
        let (head, tail) = values.split_at_mut(layout.values_of(layout.groups_of(first..mid)).len());
        (AlongGroups { values: head, layout, first }, AlongGroups { values: tail, layout, first: mid })
    }
}

impl AlongColumns for () {
    fn split(self, _: usize, _: usize) -> (Self, Self) {
        ((), ())
    }
}

/// Runs `task` on ranges of at most [`TASK_COLUMNS`] block columns of
/// `columns` in parallel, each with its stretch of `parts` (the columns'
/// block offsets `ptr`), halving the range at a window of the sliced
/// layout (without allocating); combines the tasks' results in column
/// order. Ranges from a window on split into ranges from windows on.
fn in_column_tasks<P: AlongColumns, R: Send>(
    ptr: &[u32],
    columns: Range<usize>,
    parts: P,
    task: &(impl Fn(Range<usize>, P) -> R + Sync),
    combine: &(impl Fn(R, R) -> R + Sync),
) -> R {
    if columns.len() <= TASK_COLUMNS {
        return task(columns, parts);
    }
    // (at a window of the sliced layout, which a task's columns then fill)
    let mid = (columns.start + columns.len() / 2) / WINDOW * WINDOW;
    let (first, rest) = parts.split((ptr[mid] - ptr[columns.start]) as usize, mid - columns.start);
    let (left, right) = rayon::join(
        || in_column_tasks(ptr, columns.start..mid, first, task, combine),
        || in_column_tasks(ptr, mid..columns.end, rest, task, combine),
    );
    combine(left, right)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blocks of an `m x m x m` grid coupled to their six neighbours
    /// (and themselves), numbered in a shuffled order, as a block structure.
    fn shuffled_grid(m: usize) -> BlockStructure {
        structure(shuffled_grid_columns(m))
    }

    /// The block rows of every column of [`shuffled_grid`].
    fn shuffled_grid_columns(m: usize) -> Vec<Vec<u32>> {
        let n = m * m * m;
        // a permutation of 0..n by a multiplier coprime to n
        let shuffle = |v: usize| (v * 7919) % n;
        let mut columns = vec![Vec::new(); n];
        for v in 0..n {
            let (x, y, z) = (v % m, (v / m) % m, v / (m * m));
            let mut add = |u: usize| columns[shuffle(v)].push(shuffle(u) as u32);
            add(v);
            for (c, step) in [(x, 1), (y, m), (z, m * m)] {
                if c > 0 {
                    add(v - step);
                }
                if c + 1 < m {
                    add(v + step);
                }
            }
        }
        columns
    }

    /// The block structure of the columns' block rows (any order).
    fn structure(columns: Vec<Vec<u32>>) -> BlockStructure {
        let (mut ptr, mut rows, mut start) = (vec![0u32], Vec::new(), Vec::new());
        for mut column in columns {
            column.sort_unstable();
            start.push(9 * rows.len());
            rows.extend(column);
            ptr.push(rows.len() as u32);
        }
        let nnz = 9 * rows.len();
        BlockStructure::from_columns(ptr, rows, start, nnz).unwrap()
    }

    /// The largest distance between a block column and one of its rows.
    fn bandwidth(blocks: &BlockStructure) -> usize {
        (0..blocks.len())
            .flat_map(|j| blocks.column_rows(j).iter().map(move |&r| (r as usize).abs_diff(j)))
            .max()
            .unwrap()
    }

    /// In a Cuthill–McKee order every coupling joins a breadth-first level
    /// to itself or the next, so the bandwidth is below twice the widest
    /// level: from a corner of the grid, the points with `x + y + z = k`.
    #[test]
    fn the_order_gathers_a_shuffled_grid_into_a_band() {
        let m = 10;
        let old = shuffled_grid(m);
        let widest = (0..3 * m)
            .map(|k| (0..m * m * m).filter(|v| v % m + (v / m) % m + v / (m * m) == k).count())
            .max()
            .unwrap();
        let mut renumbering = Renumbering::default();
        renumbering.renew(&old);
        let (before, after) = (bandwidth(&old), bandwidth(renumbering.blocks()));
        assert!(before > 900, "the shuffled grid's bandwidth is {before}");
        assert!(after < 2 * widest, "bandwidth {after} after renumbering, widest level {widest}");
    }

    /// A structure already in a reverse Cuthill–McKee order (as a mesh
    /// renumbered for locality gives it) keeps its own order, and its
    /// values are carried as they are, also after a block is appended and
    /// a column changed; a shuffled one does not.
    #[test]
    fn an_order_as_local_as_its_own_is_kept() {
        // the renumbering is the identity, its structure `blocks`, and
        // values are carried as they are
        let kept_as_is = |renumbering: &Renumbering, blocks: &BlockStructure| {
            assert!(renumbering.order().iter().enumerate().all(|(b, &o)| o as usize == b), "not the identity");
            assert_eq!(renumbering.blocks(), blocks);
            let values: Vec<f64> = (0..9 * blocks.rows_len()).map(|v| v as f64).collect();
            let mut out = vec![0.0; values.len()];
            renumbering.carry_exact(&values, &mut out);
            assert_eq!(out, values);
        };
        let mut first = Renumbering::default();
        first.renew(&shuffled_grid(8));
        assert!(first.order().iter().enumerate().any(|(b, &o)| o as usize != b), "a shuffled grid is renumbered");
        let banded = first.blocks().clone();
        let mut again = Renumbering::default();
        again.renew(&banded);
        kept_as_is(&again, &banded);
        // a block appended and a column changed: still the structure itself
        let mut columns: Vec<Vec<u32>> = (0..banded.len()).map(|j| banded.column_rows(j).to_vec()).collect();
        let added = columns.len();
        columns.push(vec![added as u32, 3]);
        columns[3].push(added as u32);
        let grown = structure(columns);
        again.renew(&grown);
        kept_as_is(&again, &grown);
    }

    /// Blocks appended to a renumbered structure (as a cut appends nodes)
    /// go last, in their own order, and the old blocks keep theirs, until
    /// the structure holds more than [`KEPT_GROWTH`] times the blocks of the
    /// last whole analysis: then the whole analysis runs again.
    #[test]
    fn appended_blocks_go_last_until_the_structure_outgrows_the_analysis() {
        let mut columns = shuffled_grid_columns(6);
        let n = columns.len();
        let mut renumbering = Renumbering::default();
        renumbering.renew(&structure(columns.clone()));
        let first = renumbering.order().to_vec();
        let couple = |columns: &mut Vec<Vec<u32>>, a: usize, b: usize| {
            columns[a].push(b as u32);
            columns[b].push(a as u32);
        };
        // a: between two grid neighbours; b: to a and one old block; c: alone
        let (u, v, w) = (first[40] as usize, first[41] as usize, first[100] as usize);
        columns.extend([vec![n as u32], vec![n as u32 + 1], vec![n as u32 + 2]]);
        let (a, b, c) = (n, n + 1, n + 2);
        couple(&mut columns, a, u);
        couple(&mut columns, a, v);
        couple(&mut columns, b, a);
        couple(&mut columns, b, w);
        renumbering.renew(&structure(columns.clone()));
        let mut want = first.clone();
        want.extend([a, b, c].map(|x| x as u32));
        assert_eq!(renumbering.order(), &want[..]);
        // blocks coupled to the last ones, up to twice the analysed blocks
        while columns.len() < KEPT_GROWTH * n {
            columns.push(vec![columns.len() as u32]);
            let added = columns.len() - 1;
            couple(&mut columns, added, added - 1);
        }
        renumbering.renew(&structure(columns.clone()));
        assert_eq!(&renumbering.order()[..n], &first[..], "the old blocks keep their order");
        assert!(renumbering.order()[n..].iter().zip(n as u32..).all(|(&o, b)| o == b), "appended in order");
        // one more: the whole analysis reorders every block
        columns.push(vec![columns.len() as u32]);
        let added = columns.len() - 1;
        couple(&mut columns, added, first[0] as usize);
        renumbering.renew(&structure(columns));
        assert_ne!(&renumbering.order()[..n], &first[..], "the whole analysis reorders the old blocks");
    }

    /// The anchored order visits every block once: the analysed ones in
    /// their order, each appended one right after the earliest analysed
    /// block it reaches through appended ones (block 11, reaching 2 directly
    /// and 7 through block 10, after 2), one reaching none last.
    #[test]
    fn appended_blocks_are_visited_after_their_anchors() {
        // a path 0 - 1 - ... - 9, then 10 - 7, 11 - 10 and 11 - 2, 12 alone
        let mut columns: Vec<Vec<u32>> = (0..10u32)
            .map(|v| [v.checked_sub(1), Some(v), (v < 9).then_some(v + 1)].into_iter().flatten().collect())
            .collect();
        columns.extend([vec![10, 7, 11], vec![11, 10, 2], vec![12]]);
        columns[7].push(10);
        columns[2].push(11);
        let order = anchored_order(&structure(columns), 10);
        assert_eq!(order, [0, 1, 2, 11, 3, 4, 5, 6, 7, 10, 8, 9, 12]);
    }

    /// Blocks appended over two renewals, each coupled to two old blocks,
    /// and an old block's neighbour handed over to one of them: the old
    /// blocks keep their order, and every column (sorted again
    /// where it changed, its last permutation reused where it did not)
    /// holds its old rows in the new numbering, ascending, each one's place
    /// in the old column in `source`.
    #[test]
    fn an_extended_renumbering_sorts_the_changed_columns_again() {
        let mut columns = shuffled_grid_columns(6);
        let mut renumbering = Renumbering::default();
        renumbering.renew(&structure(columns.clone()));
        for round in 0..2 {
            let last = renumbering.order().to_vec();
            for k in 0..5 {
                let added = columns.len();
                columns.push(vec![added as u32]);
                for u in [last[10 + 30 * k + round], last[12 + 30 * k + round]] {
                    columns[added].push(u);
                    columns[u as usize].push(added as u32);
                }
            }
            // a column that changes at the same length: one of its
            // neighbours handed over to the last appended block (as a cut
            // renames a node)
            let (w, added) = (last[200 + round] as usize, columns.len() - 1);
            let x = *columns[w].iter().find(|&&x| x as usize != w).unwrap();
            columns[w].iter_mut().filter(|r| **r == x).for_each(|r| *r = added as u32);
            columns[x as usize].retain(|&r| r as usize != w);
            columns[added].push(w as u32);
            let old = structure(columns.clone());
            renumbering.renew(&old);
            let (order, rank, new) = (renumbering.order(), renumbering.rank(), renumbering.blocks());
            let kept: Vec<u32> = order.iter().copied().filter(|&o| (o as usize) < last.len()).collect();
            assert_eq!(kept, last, "round {round}: the old blocks keep their order");
            for j in 0..new.len() {
                let (rows, column) = (new.column_rows(j), old.column_rows(order[j] as usize));
                let mut want: Vec<u32> = column.iter().map(|&r| rank[r as usize]).collect();
                want.sort_unstable();
                assert_eq!(rows, &want[..], "round {round}: column {j}");
                let source = &renumbering.source[new.ptr[j] as usize..new.ptr[j + 1] as usize];
                for (&r, &q) in rows.iter().zip(source) {
                    assert_eq!(rank[column[q as usize] as usize], r, "round {round}: column {j}'s source");
                }
            }
        }
    }

    /// [`Renumbering::round_values`] with no products: whether every value
    /// is finite, and every rounded one.
    fn round(
        renumbering: &Renumbering,
        values: &[f64],
        rounded: &mut [f32],
        diagonals: &mut [[f64; 9]],
    ) -> (bool, bool) {
        let (finite, in_range, ()) =
            renumbering.round_values(values, rounded, diagonals, |b| b, (), |_, _, _| (), |(), ()| ());
        (finite, in_range)
    }

    /// [`shuffled_grid`]`(m)`, or (`banded`) its renumbered structure,
    /// whose own order is kept (the renumbering is the identity).
    fn grid(m: usize, banded: bool) -> BlockStructure {
        let shuffled = shuffled_grid(m);
        if !banded {
            return shuffled;
        }
        let mut renumbering = Renumbering::default();
        renumbering.renew(&shuffled);
        renumbering.blocks().clone()
    }

    /// [`grid`]`(m, banded)`, values for it, and its renumbering.
    fn renumbered_grid(m: usize, banded: bool) -> (BlockStructure, Vec<f64>, Renumbering) {
        let old = grid(m, banded);
        let values: Vec<f64> = (0..9 * old.rows_len()).map(|i| ((i * 37 % 101) as f64 - 50.0) * 0.01).collect();
        let mut renumbering = Renumbering::default();
        renumbering.renew(&old);
        assert_eq!(renumbering.identity, banded);
        (old, values, renumbering)
    }

    /// The tasks of a rounding pass each slice their own columns' values
    /// (split at windows of the sliced layout): together, the values of
    /// the whole rounded matrix sliced in one go.
    #[test]
    fn the_tasks_slice_the_rounded_values_as_a_whole_fill_does() {
        let (old, values, renumbering) = renumbered_grid(9, false);
        let (blocks, n) = (renumbering.blocks(), old.len());
        assert!(n > 2 * TASK_COLUMNS, "{n} blocks: more than one task");
        let layout = SlicedLayout::new(blocks.columns(), n);
        let (mut rounded, mut diagonals) = (vec![0.0f32; values.len()], vec![[0.0; 9]; n]);
        let mut by_tasks = vec![f32::NAN; layout.values_len()];
        let parts = AlongGroups { values: &mut by_tasks, layout: &layout, first: 0 };
        let task = |columns: Range<usize>, task_values: &[f32], sliced: &mut AlongGroups<'_>| {
            let groups = layout.groups_of(columns.clone());
            layout.fill(task_values, blocks.start[columns.start], groups, sliced.values);
        };
        renumbering.round_values(&values, &mut rounded, &mut diagonals, |b| b, parts, task, |(), ()| ());
        let mut whole = vec![f32::NAN; layout.values_len()];
        layout.fill(&rounded, 0, 0..layout.groups(), &mut whole);
        assert!(whole.iter().zip(&by_tasks).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    /// The old values read as the new columns ([`Renumbering::old_columns`])
    /// multiply a vector in the new numbering as the old structure
    /// multiplies it in the old one, bit for bit (the same sums in the
    /// same order), within the tasks of a pass that carries them; the
    /// tasks' results combine over every column once. So too where the
    /// renumbering is the identity.
    #[test]
    fn products_on_the_old_values_in_the_new_numbering_are_the_old_products() {
        for banded in [false, true] {
            products_in_the_new_numbering(banded);
        }
    }

    fn products_in_the_new_numbering(banded: bool) {
        let (old, values, renumbering) = renumbered_grid(6, banded);
        let n = old.len();
        let x_old: Vec<f64> = (0..3 * n).map(|i| (i as f64 * 0.37).sin()).collect();
        let mut x_new = vec![[0.0; 3]; n];
        let as_blocks = |v: &[f64]| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
        renumbering.to_new(&as_blocks(&x_old), &mut x_new);
        let x_new: Vec<f64> = x_new.concat();
        let mut y_old = vec![0.0; 3 * n];
        cleave_kernels::spmv::block_products(old.columns(), &values, &x_old, 0, &mut y_old);
        let (mut rounded, mut diagonals, mut y_new) = (vec![0.0f32; values.len()], vec![[0.0; 9]; n], vec![0.0; 3 * n]);
        let view = renumbering.old_columns();
        let task = |columns: Range<usize>, _: &[f32], y: &mut Along<f64>| {
            cleave_kernels::spmv::block_products(view, &values, &x_new, columns.start, y.0);
            columns.len()
        };
        let parts = Along::columns(&mut y_new, 3);
        let (finite, _, columns) =
            renumbering.round_values(&values, &mut rounded, &mut diagonals, |b| b, parts, task, |a, b| a + b);
        assert!(finite);
        assert_eq!(columns, n);
        for (new, &o) in renumbering.order().iter().enumerate() {
            let o = o as usize;
            assert_eq!(y_new[3 * new..3 * new + 3], y_old[3 * o..3 * o + 3], "block {o}, new {new}");
        }
    }

    /// The carried values are the renumbered matrix `Q A Qᵀ`, entry by
    /// entry, and their `f32` roundings; every column's rows ascend; the
    /// vector maps are each other's inverse; a value that is not finite,
    /// or not finite in `f32`, is reported. So too where the renumbering
    /// is the identity.
    #[test]
    fn carried_values_are_the_renumbered_matrix() {
        for banded in [false, true] {
            carried_values(&grid(5, banded));
        }
    }

    fn carried_values(old: &BlockStructure) {
        let entry = |i: usize, j: usize, e: usize| (i * 31 + j * 7 + e) as f64 * 1.000_000_1;
        let mut values = vec![0.0; 9 * old.rows_len()];
        for j in 0..old.len() {
            let rows = old.column_rows(j);
            let stride = 3 * rows.len();
            for (q, &i) in rows.iter().enumerate() {
                for e in 0..9 {
                    values[old.start[j] + (e / 3) * stride + 3 * q + e % 3] = entry(i as usize, j, e);
                }
            }
        }
        let mut renumbering = Renumbering::default();
        renumbering.renew(old);
        let (mut out, mut rounded) = (vec![0.0; values.len()], vec![0.0f32; values.len()]);
        let mut diagonals = vec![[0.0; 9]; old.len()];
        assert_eq!(round(&renumbering, &values, &mut rounded, &mut diagonals), (true, true));
        renumbering.carry_exact(&values, &mut out);
        let (new, order) = (renumbering.blocks(), renumbering.order());
        for j in 0..new.len() {
            let rows = new.column_rows(j);
            assert!(rows.windows(2).all(|w| w[0] < w[1]), "column {j}'s rows do not ascend");
            let stride = 3 * rows.len();
            for (q, &i) in rows.iter().enumerate() {
                for e in 0..9 {
                    let at = new.start[j] + (e / 3) * stride + 3 * q + e % 3;
                    assert_eq!(out[at], entry(order[i as usize] as usize, order[j] as usize, e));
                    assert_eq!(rounded[at], out[at] as f32);
                }
            }
            // the diagonal block row by row: entry (r, c) is e = 3c + r above
            let o = order[j] as usize;
            let want: [f64; 9] = std::array::from_fn(|rc| entry(o, o, 3 * (rc % 3) + rc / 3));
            assert_eq!(diagonals[j], want, "diagonal block of new column {j}");
        }
        let v: Vec<[f64; 3]> = (0..old.len()).map(|i| [i as f64, 0.5, -(i as f64)]).collect();
        let (mut there, mut back) = (vec![[0.0; 3]; v.len()], vec![[0.0; 3]; v.len()]);
        renumbering.to_new(&v, &mut there);
        renumbering.to_old(&there, &mut back);
        assert_eq!(back, v);
        assert_eq!(there[0], v[order[0] as usize]);
        values[17] = 1e39;
        assert_eq!(round(&renumbering, &values, &mut rounded, &mut diagonals), (true, false));
        values[17] = f64::NAN;
        assert!(!round(&renumbering, &values, &mut rounded, &mut diagonals).0);
    }

    #[test]
    fn reverse_cuthill_mckee_orders_every_vertex_once_per_component() {
        // two paths, 0-2-4 and 1-3, and an isolated vertex 5
        let edges = [vec![2], vec![3], vec![0, 4], vec![1], vec![2], vec![]];
        let order = reverse_cuthill_mckee(6, |v| edges[v].iter().copied());
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, vec![0, 1, 2, 3, 4, 5]);
        // a path keeps its vertices consecutive, in path order
        let pos = |v: u32| order.iter().position(|&u| u == v).unwrap();
        assert_eq!(pos(2).abs_diff(pos(0)), 1);
        assert_eq!(pos(2).abs_diff(pos(4)), 1);
        assert_eq!(pos(1).abs_diff(pos(3)), 1);
    }
}
