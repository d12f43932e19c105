//! The block sparsity pattern and the per-node gather lists that assemble
//! into it.

use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use rayon::prelude::*;

use crate::solve::BlockStructure;

use super::{Couplings, MAX_ENTRY_BLOCKS};

/// One element touching a node: where the node sits in it, and where the
/// element's blocks land in the node's column.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
struct Incidence {
    /// The element's batch and index in it (refreshed after every update).
    batch: u32,
    element: u32,
    /// The element's mesh id.
    id: u32,
    /// The node's local index in the element.
    local: u32,
    /// The element's node count `k`.
    size: u32,
    /// Start of the element's `k` slots in [`SparsePattern::slots`].
    slots: u32,
}

/// Sparsity of the global matrix for one topology, and everything needed to
/// write element blocks into its values without searching.
///
/// Assembly is gathered per node: node `j` owns its three scalar columns
/// and sums, in a fixed order, the blocks of every element that touches it.
/// Columns are disjoint, so nodes run in parallel without locks and every
/// entry receives its contributions in the same order whatever the thread
/// count (bitwise reproducible).
#[derive(Clone, Debug)]
pub struct SparsePattern {
    /// Number of blocks (3 scalar unknowns each).
    pub num_blocks: usize,
    /// The scalar compressed-column structure (`3 * num_blocks` square).
    pub symbolic: SymbolicSparseColMat<usize>,
    /// The same structure in 3x3 blocks (what block solvers read).
    blocks: BlockStructure,
    /// Scalar offset between consecutive columns of block column `j`.
    col_stride: Vec<usize>,
    /// CSR offsets into `incidences`, one row per node.
    offsets: Vec<u32>,
    /// Elements touching each node, in a fixed order.
    incidences: Vec<Incidence>,
    /// For each incidence and each local row node `a` of its element: the
    /// offset of scalar entry `(3 node_a, 3 j)` from the start of column
    /// `3 j` (so a column that does not change keeps its slots).
    slots: Vec<u32>,
    /// Offset of the diagonal block's first entry from the start of column
    /// `3 j`, per node.
    diagonal: Vec<u32>,
    /// The previous topology's arrays, emptied: the next update writes into
    /// them instead of fresh memory (a cut costs no page faults for the
    /// large arrays, at the price of keeping them twice).
    spare: Buffers,
}

/// A pattern as a checkpoint stores it: the arrays, the compressed
/// columns as plain vectors (faer's structure has no serde support), and
/// no spare buffers (they hold capacity, not data).
#[derive(serde::Serialize, serde::Deserialize)]
struct Stored<Columns, Incidences, Numbers> {
    num_blocks: usize,
    col_ptr: Columns,
    row_idx: Columns,
    col_stride: Columns,
    offsets: Numbers,
    incidences: Incidences,
    slots: Numbers,
    diagonal: Numbers,
}

impl serde::Serialize for SparsePattern {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        Stored {
            num_blocks: self.num_blocks,
            col_ptr: self.symbolic.col_ptr(),
            row_idx: self.symbolic.row_idx(),
            col_stride: &self.col_stride[..],
            offsets: &self.offsets[..],
            incidences: &self.incidences[..],
            slots: &self.slots[..],
            diagonal: &self.diagonal[..],
        }
        .serialize(serializer)
    }
}

impl<'de> serde::Deserialize<'de> for SparsePattern {
    /// Checks the compressed columns (sorted rows in range, monotone
    /// offsets) and the per-node arrays' lengths before building faer's
    /// structure, which would panic on them.
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let s: Stored<Vec<usize>, Vec<Incidence>, Vec<u32>> = serde::Deserialize::deserialize(deserializer)?;
        let n = 3 * s.num_blocks;
        let columns_ok = s.col_ptr.len() == n + 1
            && s.col_ptr.first() == Some(&0)
            && s.col_ptr.last() == Some(&s.row_idx.len())
            && s.col_ptr.windows(2).all(|w| w[0] <= w[1])
            && s.col_ptr.windows(2).all(|w| {
                let rows = &s.row_idx[w[0]..w[1]];
                rows.iter().all(|&r| r < n) && rows.windows(2).all(|p| p[0] < p[1])
            });
        let nodes_ok = s.col_stride.len() == s.num_blocks
            && s.diagonal.len() == s.num_blocks
            && s.offsets.len() == s.num_blocks + 1
            && s.offsets.last().map(|&o| o as usize) == Some(s.incidences.len());
        if !(columns_ok && nodes_ok) {
            return Err(serde::de::Error::custom("the sparse pattern's arrays are inconsistent"));
        }
        let symbolic = SymbolicSparseColMat::new_checked(n, n, s.col_ptr, None, s.row_idx);
        let blocks = BlockStructure::new(symbolic.as_ref()).map_err(serde::de::Error::custom)?;
        Ok(SparsePattern {
            num_blocks: s.num_blocks,
            symbolic,
            blocks,
            col_stride: s.col_stride,
            offsets: s.offsets,
            incidences: s.incidences,
            slots: s.slots,
            diagonal: s.diagonal,
            spare: Buffers::default(),
        })
    }
}

/// The large arrays of a pattern, reused between updates.
#[derive(Clone, Debug, Default)]
struct Buffers {
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    block_rows: Vec<u32>,
    incidences: Vec<Incidence>,
    slots: Vec<u32>,
}

/// The `n x n` compressed columns `col_ptr`, `row_idx`, checked as faer's
/// `new_checked` checks them (offsets ascending from 0 to the number of
/// rows, each column's rows strictly ascending below `n`) but with the
/// columns in parallel: a cut's new pattern holds millions of rows.
fn checked_columns(n: usize, col_ptr: Vec<usize>, row_idx: Vec<usize>) -> SymbolicSparseColMat<usize> {
    let offsets_ok = col_ptr.len() == n + 1
        && col_ptr.first() == Some(&0)
        && col_ptr.last() == Some(&row_idx.len())
        && col_ptr.par_windows(2).all(|w| w[0] <= w[1]);
    let rows_ok = offsets_ok
        && col_ptr.par_windows(2).all(|w| {
            let rows = &row_idx[w[0]..w[1]];
            rows.windows(2).all(|p| p[0] < p[1]) && rows.last().is_none_or(|&r| r < n)
        });
    assert!(rows_ok, "the sparse pattern's layout wrote unordered columns");
    // SAFETY: the invariants faer's constructor would check were checked
    // just above
    unsafe { SymbolicSparseColMat::new_unchecked(n, n, col_ptr, None, row_idx) }
}

/// Sets the length of a reused `array` to `len` for
/// [`SparsePattern::lay_out`], which overwrites every value: its old
/// contents stay, so only what it grows by is written here. An array too
/// small is emptied first (growing then copies nothing) and given room for
/// four more changes like this one, from `previous` values to `len` (the
/// spare arrays are two topologies old when reused; a blade cut across
/// bunny_100k adds about 5 % to its entries), and at least a quarter: a
/// new array's pages are faulted in as they are first written, which cost
/// a blade cut on bunny_100k about 2,600 page faults when the arrays had a
/// sixteenth to spare.
fn fit<T: Copy>(array: &mut Vec<T>, len: usize, previous: usize, fill: T) {
    if array.capacity() < len {
        array.clear();
        array.reserve(len + (4 * len.saturating_sub(previous)).max(len / 4));
    }
    array.resize(len, fill);
}

/// Columns per parallel task of [`SparsePattern::lay_out`].
const LAY_OUT_RUN: usize = 256;

/// A raw pointer to the values, shared by the node tasks of one assembly.
#[derive(Clone, Copy)]
struct SharedValues(*mut f64);
// SAFETY: node `j` writes only inside its own three columns, which no other
// node touches (see `SparsePattern::assemble`).
unsafe impl Send for SharedValues {}
unsafe impl Sync for SharedValues {}

impl SharedValues {
    /// The pointer (read through a method so that a closure captures the
    /// whole `Sync` wrapper, and keeps the pointer in a register).
    #[inline(always)]
    fn get(&self) -> *mut f64 {
        self.0
    }
}

/// How many incidences ahead [`SparsePattern::assemble_prefetched`] asks
/// for an element's data: mesh node ids need not be spatially coherent, so
/// the elements around consecutive nodes lie anywhere in memory, and each
/// read would otherwise wait on memory (bunny_100k, one thread, the
/// assembly phase of a step: 53 ms without the hint, 16-20 ms with it).
const PREFETCH_AHEAD: usize = 4;

/// The incidences of one node being laid out.
enum Column<'a> {
    /// The same elements as in this pattern (rows and slots are copied;
    /// only where the elements sit in the store is refreshed).
    Kept(&'a SparsePattern),
    /// Recomputed from these incidences.
    New(Vec<Incidence>),
}

impl SparsePattern {
    /// Builds the pattern of `store`'s couplings over `num_blocks` blocks.
    pub fn build(num_blocks: usize, store: &impl Couplings) -> Self {
        let mut columns: Vec<Vec<Incidence>> = vec![Vec::new(); num_blocks];
        for bi in 0..store.groups() {
            for e in 0..store.entries(bi) {
                let blocks = store.blocks(bi, e);
                for (a, &v) in blocks.iter().enumerate() {
                    columns[v as usize].push(Incidence {
                        batch: bi as u32,
                        element: e as u32,
                        id: store.id(bi, e),
                        local: a as u32,
                        size: blocks.len() as u32,
                        slots: 0,
                    });
                }
            }
        }
        let incidences: usize = columns.iter().map(Vec::len).sum();
        let slots = columns.iter().flatten().map(|inc| inc.size as usize).sum();
        let buffers = Buffers {
            incidences: Vec::with_capacity(incidences),
            slots: Vec::with_capacity(slots),
            ..Default::default()
        };
        Self::lay_out(store, columns.into_iter().map(Column::New).collect(), buffers, None)
    }

    /// The pattern of no blocks.
    pub fn empty() -> Self {
        SparsePattern {
            num_blocks: 0,
            symbolic: SymbolicSparseColMat::new_checked(0, 0, vec![0], None, Vec::new()),
            blocks: BlockStructure::default(),
            col_stride: Vec::new(),
            offsets: vec![0],
            incidences: Vec::new(),
            slots: Vec::new(),
            diagonal: Vec::new(),
            spare: Buffers::default(),
        }
    }

    /// Updates the pattern after the entries `changed` (stable ids, sorted)
    /// were rebuilt in `store` (for an element store, see
    /// [`crate::store::ElementStore::update`]); `old_nodes` are the blocks
    /// those entries coupled before. Only the columns of their blocks, old
    /// and new, are recomputed; the others are copied.
    pub fn update(&mut self, num_blocks: usize, store: &impl Couplings, changed: &[u32], old_nodes: &[u32]) {
        let spare = std::mem::take(&mut self.spare);
        let mut dirty = vec![false; num_blocks];
        old_nodes.iter().for_each(|&v| dirty[v as usize] = true);
        let mut added: Vec<(u32, Incidence)> = Vec::new();
        for &e in changed {
            let (bi, i) = store.locate(e);
            let blocks = store.blocks(bi as usize, i as usize);
            for (a, &v) in blocks.iter().enumerate() {
                dirty[v as usize] = true;
                let size = blocks.len() as u32;
                let inc = Incidence { batch: bi, element: i, id: e, local: a as u32, size, slots: 0 };
                added.push((v, inc));
            }
        }
        added.sort_by_key(|&(v, inc)| (v, inc.id));
        let last = changed.iter().max().map_or(0, |&e| e as usize + 1);
        let mut is_changed = vec![false; last];
        changed.iter().for_each(|&e| is_changed[e as usize] = true);
        let was_changed = |e: u32| is_changed.get(e as usize).copied().unwrap_or(false);
        // (the columns are independent: made in parallel, in order)
        let this = &*self;
        let columns: Vec<Column> = (0..num_blocks)
            .into_par_iter()
            .map(|j| {
                if !dirty[j] && j < this.num_blocks {
                    return Column::Kept(this);
                }
                let (lo, hi) =
                    (added.partition_point(|a| (a.0 as usize) < j), added.partition_point(|a| a.0 as usize <= j));
                let kept = this.column_incidences(j).iter().filter(|inc| !was_changed(inc.id)).copied();
                let mut incidences: Vec<Incidence> = kept.chain(added[lo..hi].iter().map(|a| a.1)).collect();
                // entries of other elements may have moved in their batch
                for inc in &mut incidences {
                    (inc.batch, inc.element) = store.locate(inc.id);
                }
                Column::New(incidences)
            })
            .collect();
        let previous = [self.nnz(), self.incidences.len(), self.slots.len(), self.blocks.rows_len()];
        let new = Self::lay_out(store, columns, spare, Some(previous));
        let old = std::mem::replace(self, new);
        let (_, _, col_ptr, _, row_idx) = old.symbolic.into_parts();
        let block_rows = old.blocks.into_rows();
        self.spare = Buffers { col_ptr, row_idx, block_rows, incidences: old.incidences, slots: old.slots };
    }

    /// The ids of the entries (elements) coupling block `j`, in the
    /// pattern's fixed order (none for a block past the pattern).
    pub fn elements_at(&self, j: usize) -> impl Iterator<Item = u32> + '_ {
        self.column_incidences(j).iter().map(|inc| inc.id)
    }

    /// The incidences of node `j` (none for a node past the pattern).
    fn column_incidences(&self, j: usize) -> &[Incidence] {
        match (self.offsets.get(j), self.offsets.get(j + 1)) {
            (Some(&a), Some(&b)) => &self.incidences[a as usize..b as usize],
            _ => &[],
        }
    }

    /// Lays out the compressed columns of `columns` into `buffers`, copying
    /// the rows and slots of kept columns: the sizes first, then every
    /// column written into its own stretch of the arrays, in parallel over
    /// runs of [`LAY_OUT_RUN`] columns (the arrays are the same whatever
    /// the thread count). `previous` are the sizes of the pattern this one
    /// replaces (entries, incidences, slots, block rows), if any.
    fn lay_out(store: &impl Couplings, columns: Vec<Column>, buffers: Buffers, previous: Option<[usize; 4]>) -> Self {
        let num_blocks = columns.len();
        // block rows of every recomputed column: union of its elements' nodes
        let rows: Vec<Vec<u32>> = columns
            .par_iter()
            .enumerate()
            .map(|(j, col)| {
                let Column::New(incidences) = col else {
                    return Vec::new();
                };
                let mut r: Vec<u32> = incidences
                    .iter()
                    .flat_map(|inc| store.blocks(inc.batch as usize, inc.element as usize).iter().copied())
                    .collect();
                r.push(j as u32); // lone nodes keep their diagonal
                r.sort_unstable();
                r.dedup();
                r
            })
            .collect();
        // per column: scalar stride, incidences and slots, and where each
        // starts in its array
        let (mut col_stride, mut diagonal) = (Vec::with_capacity(num_blocks), Vec::with_capacity(num_blocks));
        let mut starts = Vec::with_capacity(num_blocks + 1);
        // (entries, incidences, slots, block rows)
        let mut at = [0usize; 4];
        for (j, col) in columns.iter().enumerate() {
            starts.push(at);
            let (stride, incidences, slots) = match col {
                Column::Kept(old) => {
                    diagonal.push(old.diagonal[j]);
                    // (a column's slots lie together, in incidence order)
                    let incidences = old.column_incidences(j);
                    let slots = incidences.last().map_or(0, |l| (l.slots + l.size - incidences[0].slots) as usize);
                    (old.col_stride[j], incidences.len(), slots)
                }
                Column::New(incidences) => {
                    let p = rows[j].binary_search(&(j as u32)).expect("every column holds its diagonal");
                    diagonal.push(u32::try_from(3 * p).expect("fewer than 2^32 entries per column"));
                    let slots = incidences.iter().map(|inc| inc.size as usize).sum();
                    (3 * rows[j].len(), incidences.len(), slots)
                }
            };
            col_stride.push(stride);
            at[0] += 3 * stride;
            at[1] += incidences;
            at[2] += slots;
            at[3] += stride / 3;
        }
        starts.push(at);
        let n = 3 * num_blocks;
        let Buffers { mut col_ptr, mut row_idx, mut block_rows, mut incidences, mut slots } = buffers;
        col_ptr.clear();
        col_ptr.extend((0..n).map(|c| starts[c / 3][0] + (c % 3) * col_stride[c / 3]));
        col_ptr.push(at[0]);
        let offsets: Vec<u32> =
            starts.iter().map(|s| u32::try_from(s[1]).expect("fewer than 2^32 incidences")).collect();
        let unset = Incidence { batch: 0, element: 0, id: 0, local: 0, size: 0, slots: 0 };
        let previous = previous.unwrap_or(at);
        fit(&mut row_idx, at[0], previous[0], 0);
        fit(&mut block_rows, at[3], previous[3], 0);
        fit(&mut incidences, at[1], previous[1], unset);
        fit(&mut slots, at[2], previous[2], 0);
        // the arrays cut into the stretches of runs of columns
        let ranges: Vec<std::ops::Range<usize>> =
            (0..num_blocks).step_by(LAY_OUT_RUN).map(|first| first..(first + LAY_OUT_RUN).min(num_blocks)).collect();
        let lengths =
            |k: usize| -> Vec<usize> { ranges.iter().map(|r| starts[r.end][k] - starts[r.start][k]).collect() };
        let (row_parts, inc_parts) =
            (crate::stretches(&mut row_idx, lengths(0)), crate::stretches(&mut incidences, lengths(1)));
        let (slot_parts, block_parts) =
            (crate::stretches(&mut slots, lengths(2)), crate::stretches(&mut block_rows, lengths(3)));
        let runs: Vec<_> = (ranges.iter().cloned().zip(row_parts).zip(inc_parts).zip(slot_parts).zip(block_parts))
            .map(|((((range, r), i), s), b)| (range, r, i, s, b))
            .collect();
        runs.into_par_iter().for_each(|(range, row_out, inc_out, slot_out, block_out)| {
            let base = starts[range.start];
            for j in range {
                let [e0, i0, s0, b0] = std::array::from_fn(|k| starts[j][k] - base[k]);
                let [e1, i1, s1, b1] = std::array::from_fn(|k| starts[j + 1][k] - base[k]);
                let (row_out, inc_out, slot_out) = (&mut row_out[e0..e1], &mut inc_out[i0..i1], &mut slot_out[s0..s1]);
                let block_out = &mut block_out[b0..b1];
                let mut slot = starts[j][2];
                match &columns[j] {
                    Column::Kept(old) => {
                        let old_col = old.symbolic.col_ptr();
                        row_out.copy_from_slice(&old.symbolic.row_idx()[old_col[3 * j]..old_col[3 * j + 3]]);
                        block_out.copy_from_slice(old.blocks.column_rows(j));
                        let mut written = 0;
                        for (out, inc) in inc_out.iter_mut().zip(old.column_incidences(j)) {
                            let (from, size) = (inc.slots as usize, inc.size as usize);
                            let (batch, element) = store.locate(inc.id);
                            *out = Incidence { batch, element, slots: slot as u32, ..*inc };
                            slot_out[written..written + size].copy_from_slice(&old.slots[from..from + size]);
                            (written, slot) = (written + size, slot + size);
                        }
                    }
                    Column::New(new_incidences) => {
                        let r = &rows[j];
                        block_out.copy_from_slice(r);
                        let third = 3 * r.len();
                        for (out, &i) in row_out[..third].chunks_exact_mut(3).zip(r) {
                            out.copy_from_slice(&[3 * i as usize, 3 * i as usize + 1, 3 * i as usize + 2]);
                        }
                        row_out.copy_within(..third, third);
                        row_out.copy_within(..third, 2 * third);
                        let position = |i: u32| -> u32 {
                            let p = r.binary_search(&i).expect("pattern holds every element pair");
                            u32::try_from(3 * p).expect("fewer than 2^32 entries per column")
                        };
                        let mut written = 0;
                        for (out, inc) in inc_out.iter_mut().zip(new_incidences) {
                            *out = Incidence { slots: slot as u32, ..*inc };
                            let nodes = store.blocks(inc.batch as usize, inc.element as usize);
                            for (s, &a) in slot_out[written..written + nodes.len()].iter_mut().zip(nodes) {
                                *s = position(a);
                            }
                            (written, slot) = (written + nodes.len(), slot + nodes.len());
                        }
                    }
                }
            }
        });
        let symbolic = checked_columns(n, col_ptr, row_idx);
        let block_ptr = starts.iter().map(|s| u32::try_from(s[3]).expect("fewer than 2^32 blocks")).collect();
        let block_start = starts[..num_blocks].iter().map(|s| s[0]).collect();
        let blocks = BlockStructure::from_columns(block_ptr, block_rows, block_start, at[0])
            .expect("the layout writes ordered block columns");
        SparsePattern {
            num_blocks,
            symbolic,
            blocks,
            col_stride,
            offsets,
            incidences,
            slots,
            diagonal,
            spare: Buffers::default(),
        }
    }

    /// The 3x3 block structure of the pattern.
    pub fn blocks(&self) -> &BlockStructure {
        &self.blocks
    }

    /// Number of stored scalar entries.
    pub fn nnz(&self) -> usize {
        self.symbolic.row_idx().len()
    }

    /// Value index of the diagonal entry of scalar unknown `d`.
    pub fn diagonal_slot(&self, d: usize) -> usize {
        self.block_slot(d / 3, d % 3, d % 3)
    }

    /// Value index of scalar entry `(3 j + r, 3 j + c)` of the diagonal block
    /// of node `j`.
    pub fn block_slot(&self, j: usize, r: usize, c: usize) -> usize {
        self.symbolic.col_ptr()[3 * j] + self.diagonal[j] as usize + c * self.col_stride[j] + r
    }

    /// Value index of entry `(3 i, 3 j)` of block `(i, j)`, if the pattern
    /// holds that block: entry `(3 i + r, 3 j + c)` is at `base + c stride
    /// + r` with [`SparsePattern::column_stride`]`(j)`.
    pub fn block_offset(&self, i: usize, j: usize) -> Option<usize> {
        let cp = self.symbolic.col_ptr();
        let rows = &self.symbolic.row_idx()[cp[3 * j]..cp[3 * j + 1]];
        rows.binary_search(&(3 * i)).ok().map(|p| cp[3 * j] + p)
    }

    /// The offset between consecutive scalar columns of block column `j`.
    pub fn column_stride(&self, j: usize) -> usize {
        self.col_stride[j]
    }

    /// A matrix view of `values` on this pattern.
    pub fn matrix<'a>(&'a self, values: &'a [f64]) -> SparseColMatRef<'a, usize, f64> {
        SparseColMatRef::new(self.symbolic.as_ref(), values)
    }

    /// Writes the global matrix into `values` (every entry is overwritten).
    ///
    /// `blocks(batch, element, b, out)` fills `out[a]` with the row-major
    /// 3x3 block `K_ab` of that element for every local node `a` (rows) and
    /// the given local node `b` (columns). Node `j` zeroes its own columns,
    /// then adds, for every element touching it as local `b`, the column of
    /// blocks `K_·b` into them.
    pub fn assemble<F>(&self, values: &mut [f64], blocks: F)
    where
        F: Fn(usize, usize, usize, &mut [[f64; 9]]) + Sync,
    {
        self.assemble_prefetched(values, blocks, |_, _| {});
    }

    /// [`SparsePattern::assemble`], calling `prefetch(batch, element)` a few
    /// incidences before `blocks` reads that element, so that its data is
    /// on its way to the cache (a hint: results do not depend on it).
    pub fn assemble_prefetched<F, P>(&self, values: &mut [f64], blocks: F, prefetch: P)
    where
        F: Fn(usize, usize, usize, &mut [[f64; 9]]) + Sync,
        P: Fn(usize, usize) + Sync,
    {
        assert_eq!(values.len(), self.nnz());
        let shared = SharedValues(values.as_mut_ptr());
        let col_ptr = self.symbolic.col_ptr();
        // one column of blocks per task, on the stack (no allocation)
        let column = || [[0.0f64; 9]; MAX_ENTRY_BLOCKS];
        (0..self.num_blocks).into_par_iter().with_min_len(64).for_each_init(column, |scratch, j| {
            let values = shared.get();
            let (stride, base) = (self.col_stride[j], col_ptr[3 * j]);
            // SAFETY (every write below): entries of columns 3j..3j+3
            // belong to this node task only, and lie in `values`
            for p in col_ptr[3 * j]..col_ptr[3 * j + 3] {
                unsafe { *values.add(p) = 0.0 };
            }
            let (first, end) = (self.offsets[j] as usize, self.offsets[j + 1] as usize);
            for t in first..end {
                if let Some(ahead) = self.incidences.get(t + PREFETCH_AHEAD) {
                    prefetch(ahead.batch as usize, ahead.element as usize);
                }
                let inc = &self.incidences[t];
                let slots = &self.slots[inc.slots as usize..(inc.slots + inc.size) as usize];
                let scratch = &mut scratch[..slots.len()];
                blocks(inc.batch as usize, inc.element as usize, inc.local as usize, scratch);
                for (kab, &slot) in scratch.iter().zip(slots) {
                    for c in 0..3 {
                        // column 3j + c of block (a, j): three consecutive rows
                        let col = unsafe { values.add(base + slot as usize + c * stride) };
                        unsafe {
                            *col += kab[c];
                            *col.add(1) += kab[3 + c];
                            *col.add(2) += kab[6 + c];
                        }
                    }
                }
            }
        });
    }

    /// Sums per-element nodal vectors into per-node vectors, in a fixed
    /// order: `out[j] = Σ_{elements e ∋ j} element_vector(batch, e, local)`.
    pub fn gather<F>(&self, out: &mut [[f64; 3]], element_vector: F)
    where
        F: Fn(usize, usize, usize) -> [f64; 3] + Sync,
    {
        out.par_iter_mut().with_min_len(256).enumerate().for_each(|(j, o)| {
            let mut s = [0.0; 3];
            for inc in &self.incidences[self.offsets[j] as usize..self.offsets[j + 1] as usize] {
                let v = element_vector(inc.batch as usize, inc.element as usize, inc.local as usize);
                s = [s[0] + v[0], s[1] + v[1], s[2] + v[2]];
            }
            *o = s;
        });
    }
}
