//! The block sparsity pattern and the per-node gather lists that assemble
//! into it.

use std::sync::OnceLock;

use faer::sparse::{SparseColMatRef, SymbolicSparseColMat, SymbolicSparseColMatRef};
use rayon::prelude::*;

use crate::solve::{BlockStructure, SystemPattern};

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
    /// Start of the element's `k` slots among the node's in
    /// [`SparsePattern::slots`].
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
///
/// Every array holds the nodes' columns one after another, in node order,
/// with nothing between them: the step's passes over the values stream
/// them (gaps left between the columns for cuts to grow into cost a
/// bunny_100k step 7 %, 3.5 ms, in assembly and in the solve). A topology
/// change rewrites the columns of the nodes it touched where they now
/// start, and moves the others between them as a whole (see
/// [`SparsePattern::update`]).
#[derive(Clone, Debug)]
pub struct SparsePattern {
    /// Number of blocks (3 scalar unknowns each).
    pub num_blocks: usize,
    /// The structure in 3x3 blocks (what assembly and block solvers read):
    /// block column `j`'s block rows, and where its values start.
    blocks: BlockStructure,
    /// The scalar compressed-column structure (`3 * num_blocks` square),
    /// made from the blocks when first asked for
    /// ([`SparsePattern::symbolic`]): a body solved by conjugate gradients
    /// never needs it.
    scalar: OnceLock<SymbolicSparseColMat<usize>>,
    /// Scalar offset between consecutive columns of block column `j` (three
    /// times its number of block rows).
    col_stride: Vec<usize>,
    /// CSR offsets into `incidences` and into `slots`, one row per node.
    offsets: Vec<u32>,
    slot_offsets: Vec<u32>,
    /// Elements touching each node, in a fixed order.
    incidences: Vec<Incidence>,
    /// For each incidence and each local row node `a` of its element: the
    /// offset of scalar entry `(3 node_a, 3 j)` from the start of column
    /// `3 j` (so a column that moves keeps its slots).
    slots: Vec<u32>,
    /// Offset of the diagonal block's first entry from the start of column
    /// `3 j`, per node.
    diagonal: Vec<u32>,
}

/// A pattern as a checkpoint stores it: the arrays, the compressed
/// columns as plain vectors (faer's structure has no serde support).
#[derive(serde::Serialize, serde::Deserialize)]
struct Stored<Columns, Incidences, Numbers> {
    num_blocks: usize,
    col_ptr: Columns,
    row_idx: Columns,
    col_stride: Columns,
    offsets: Numbers,
    slot_offsets: Numbers,
    incidences: Incidences,
    slots: Numbers,
    diagonal: Numbers,
}

impl serde::Serialize for SparsePattern {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        // (made for the checkpoint alone where no solver asked for it: a
        // body solved by CG keeps not holding it)
        let made;
        let symbolic = match self.scalar.get() {
            Some(scalar) => scalar.as_ref(),
            None => {
                made = self.blocks.scalar();
                made.as_ref()
            }
        };
        Stored {
            num_blocks: self.num_blocks,
            col_ptr: symbolic.col_ptr(),
            row_idx: symbolic.row_idx(),
            col_stride: &self.col_stride[..],
            offsets: &self.offsets[..],
            slot_offsets: &self.slot_offsets[..],
            incidences: &self.incidences[..],
            slots: &self.slots[..],
            diagonal: &self.diagonal[..],
        }
        .serialize(serializer)
    }
}

impl<'de> serde::Deserialize<'de> for SparsePattern {
    /// Checks the compressed columns (sorted rows in range, one block
    /// column's three scalar columns alike) and every node's incidences and
    /// slots (within its column) before building faer's structure, which
    /// would panic on bad columns, and before assembly writes through the
    /// slots.
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let s: Stored<Vec<usize>, Vec<Incidence>, Vec<u32>> = serde::Deserialize::deserialize(deserializer)?;
        let (nb, n) = (s.num_blocks, 3 * s.num_blocks);
        let lengths_ok = s.col_ptr.len() == n + 1
            && s.col_ptr.first() == Some(&0)
            && s.col_ptr.last() == Some(&s.row_idx.len())
            && s.col_stride.len() == nb
            && s.diagonal.len() == nb
            && [&s.offsets, &s.slot_offsets].iter().all(|o| o.len() == nb + 1 && o.first() == Some(&0))
            && s.offsets.last().map(|&o| o as usize) == Some(s.incidences.len())
            && s.slot_offsets.last().map(|&o| o as usize) == Some(s.slots.len());
        let column_ok = |j: usize| {
            let (start, stride) = (s.col_ptr[3 * j], s.col_stride[j]);
            let shape_ok = stride % 3 == 0
                && (0..=3).all(|c| s.col_ptr[3 * j + c] == start + c * stride)
                && s.offsets[j] <= s.offsets[j + 1]
                && s.slot_offsets[j] <= s.slot_offsets[j + 1];
            if !shape_ok {
                return false;
            }
            let rows = &s.row_idx[start..start + 3 * stride];
            let first = &rows[..stride];
            let rows_ok = first.windows(2).all(|p| p[0] < p[1])
                && first.last().is_none_or(|&r| r < n)
                && first.chunks(3).all(|r| r[0] % 3 == 0 && r[1] == r[0] + 1 && r[2] == r[0] + 2)
                && (1..3).all(|c| rows[c * stride..(c + 1) * stride] == *first)
                && first.get(s.diagonal[j] as usize) == Some(&(3 * j));
            let slots = &s.slots[s.slot_offsets[j] as usize..s.slot_offsets[j + 1] as usize];
            let incidences = &s.incidences[s.offsets[j] as usize..s.offsets[j + 1] as usize];
            rows_ok
                && slots.iter().all(|&slot| slot % 3 == 0 && (slot as usize) < stride)
                && incidences.iter().all(|inc| {
                    (inc.size as usize) <= MAX_ENTRY_BLOCKS && inc.slots as usize + inc.size as usize <= slots.len()
                })
        };
        if !(lengths_ok && (0..nb).all(column_ok)) {
            return Err(serde::de::Error::custom("the sparse pattern's arrays are inconsistent"));
        }
        let symbolic = SymbolicSparseColMat::new_checked(n, n, s.col_ptr, None, s.row_idx);
        let blocks = BlockStructure::new(symbolic.as_ref()).map_err(serde::de::Error::custom)?;
        Ok(SparsePattern {
            num_blocks: nb,
            blocks,
            scalar: OnceLock::from(symbolic),
            col_stride: s.col_stride,
            offsets: s.offsets,
            slot_offsets: s.slot_offsets,
            incidences: s.incidences,
            slots: s.slots,
            diagonal: s.diagonal,
        })
    }
}

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

/// An incidence not yet written.
const UNSET: Incidence = Incidence { batch: 0, element: 0, id: 0, local: 0, size: 0, slots: 0 };

/// The group and index of an incidence whose entry [`SparsePattern::locate`]
/// has not placed yet.
const UNLOCATED: u32 = u32::MAX;

/// What an [`SparsePattern::update`] leaves for [`SparsePattern::locate`]:
/// the recomputed columns (ascending), whose incidences are not located,
/// and the places the changed entries left, into which the couplings may
/// have moved other entries.
#[derive(Debug)]
pub struct Unlocated {
    columns: Vec<usize>,
    vacated: Vec<(u32, u32)>,
}

/// The blocks of the entry with a stable id, read where `couplings`
/// locate it.
fn located_blocks<'a, C: Couplings>(couplings: &'a C) -> impl Fn(u32) -> &'a [u32] + Sync + 'a {
    |id| {
        let (group, entry) = couplings.locate(id);
        couplings.blocks(group as usize, entry as usize)
    }
}

/// Columns per parallel task of [`SparsePattern::lay_out`].
const LAY_OUT_RUN: usize = 256;

/// A node's column computed from its elements.
struct NewColumn {
    /// The elements touching the node, in the pattern's order.
    incidences: Vec<Incidence>,
    /// Its block rows: the union of their nodes and itself, ascending.
    rows: Vec<u32>,
    /// For each incidence in turn and each of its element's blocks: the
    /// block's scalar offset in the column (three times its place among
    /// `rows`).
    slots: Vec<u32>,
    /// The diagonal block's scalar offset in the column.
    diagonal: u32,
}

/// Columns made per parallel task: each task clears a place table as long
/// as the pattern once.
const COLUMN_TASK: usize = 128;

/// A place table for [`NewColumn::of`]: one entry per block, all
/// [`NOWHERE`] between columns.
fn place_table(num_blocks: usize) -> Vec<u32> {
    vec![NOWHERE; num_blocks]
}

/// A block not among the rows of the column being made.
const NOWHERE: u32 = u32::MAX;

impl NewColumn {
    /// The column of node `j` touched by `incidences`, whose entries couple
    /// the blocks `blocks_of(id)`. `places` ([`place_table`]) marks the
    /// blocks met, then holds their places while the slots are read, and
    /// is left as it came: the rows are found without sorting the blocks
    /// of every element (a node of a tetrahedral mesh meets each of its
    /// neighbours about five times), and each slot is one look-up.
    fn of<'a>(j: usize, incidences: Vec<Incidence>, blocks_of: &impl Fn(u32) -> &'a [u32], places: &mut [u32]) -> Self {
        let blocks = || incidences.iter().flat_map(|inc| blocks_of(inc.id).iter().copied());
        // (sized once: a cut makes thousands of columns)
        let size = incidences.iter().map(|inc| inc.size as usize).sum::<usize>();
        let (mut rows, mut slots) = (Vec::with_capacity(size + 1), Vec::with_capacity(size));
        rows.push(j as u32); // (a lone node keeps its diagonal)
        places[j] = 0;
        for a in blocks() {
            if places[a as usize] == NOWHERE {
                places[a as usize] = 0;
                rows.push(a);
            }
        }
        rows.sort_unstable();
        let offset = |p: usize| u32::try_from(3 * p).expect("fewer than 2^32 entries per column");
        rows.iter().enumerate().for_each(|(p, &r)| places[r as usize] = offset(p));
        slots.extend(blocks().map(|a| places[a as usize]));
        let diagonal = places[j];
        rows.iter().for_each(|&r| places[r as usize] = NOWHERE);
        NewColumn { incidences, rows, slots, diagonal }
    }

    /// Writes the column into its stretches of the arrays: the block rows,
    /// the incidences (their slots counted from the node's first) and the
    /// slots.
    fn write(&self, block_out: &mut [u32], inc_out: &mut [Incidence], slot_out: &mut [u32]) {
        block_out.copy_from_slice(&self.rows);
        slot_out.copy_from_slice(&self.slots);
        let mut written = 0;
        for (out, inc) in inc_out.iter_mut().zip(&self.incidences) {
            *out = Incidence { slots: written, ..*inc };
            written += inc.size;
        }
    }
}

/// Where every column starts after a change, given where each started
/// (`old`, the end of the last column after them) and the length of each
/// recomputed one (`fresh(j)`, for every column past the old ones too):
/// the columns lie one after another, in order.
fn new_starts(old: &[usize], fresh: impl Fn(usize) -> Option<usize>, n: usize) -> Vec<usize> {
    let mut starts = Vec::with_capacity(n + 1);
    let mut end = 0;
    for j in 0..n {
        starts.push(end);
        end += fresh(j).unwrap_or_else(|| old[j + 1] - old[j]);
    }
    starts.push(end);
    starts
}

/// Moves the columns that were not `recomputed` from their `old` starts to
/// their `new` ones. Columns between two
/// recomputed ones move together, by one `copy_within`; the stretches
/// moving up go first, the last first, then those moving down, the first
/// first: the columns keep their order, so none is overwritten before it
/// moves (a recomputed column's old items are not needed).
fn move_columns<T: Copy>(array: &mut [T], recomputed: &[bool], old: &[usize], new: &[usize]) {
    let kept = old.len() - 1;
    let mut stretches: Vec<(usize, usize)> = Vec::new();
    let mut j = 0;
    while j < kept {
        if recomputed[j] {
            j += 1;
            continue;
        }
        let first = j;
        while j < kept && !recomputed[j] {
            j += 1;
        }
        stretches.push((first, j));
    }
    for &(a, b) in stretches.iter().rev().filter(|&&(a, _)| new[a] > old[a]) {
        array.copy_within(old[a]..old[b], new[a]);
    }
    for &(a, b) in stretches.iter().filter(|&&(a, _)| new[a] < old[a]) {
        array.copy_within(old[a]..old[b], new[a]);
    }
}

/// `array`'s columns moved from their `old` starts to their `new` ones
/// ([`move_columns`], the recomputed ones left to be written), its length
/// set to the new end (new items `fill`).
fn relocate<T: Copy>(array: &mut Vec<T>, recomputed: &[bool], old: &[usize], new: &[usize], fill: T) {
    let end = new[new.len() - 1];
    crate::resize_with_room(array, end.max(array.len()), fill);
    move_columns(array, recomputed, old, new);
    array.truncate(end);
}

/// The stretches of `array` that the columns `listed` (ascending) take,
/// column `listed[k]` from `starts[listed[k]]` on, `len(k)` items long.
fn columns_of<'a, T>(
    array: &'a mut [T],
    listed: &[usize],
    starts: &[usize],
    len: impl Fn(usize) -> usize,
) -> Vec<&'a mut [T]> {
    let mut lengths = Vec::with_capacity(2 * listed.len());
    let mut at = 0;
    for (k, &j) in listed.iter().enumerate() {
        lengths.extend([starts[j] - at, len(k)]);
        at = starts[j] + len(k);
    }
    crate::stretches(array, lengths).into_iter().skip(1).step_by(2).collect()
}

/// Offsets into the incidences or the slots, as the pattern keeps them.
fn narrow(offsets: impl Iterator<Item = usize>) -> Vec<u32> {
    offsets.map(|o| u32::try_from(o).expect("fewer than 2^32 incidences and slots")).collect()
}

/// The block structure of block columns that start at the block rows
/// `starts` (the last entry their end) in `rows`, their values laid out one
/// after another: `checked` once, when the pattern is first laid out, and
/// in order by construction after an update (see
/// [`BlockStructure::from_ordered_columns`]).
fn block_structure(starts: &[usize], rows: Vec<u32>, checked: bool) -> BlockStructure {
    let ptr = starts.iter().map(|&p| u32::try_from(p).expect("fewer than 2^32 block rows")).collect();
    let values: Vec<usize> = starts[..starts.len() - 1].iter().map(|&p| 9 * p).collect();
    let nnz = 9 * starts[starts.len() - 1];
    if checked {
        BlockStructure::from_columns(ptr, rows, values, nnz).expect("the layout writes ordered block columns")
    } else {
        BlockStructure::from_ordered_columns(ptr, rows, values, nnz)
    }
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
        let blocks_of = located_blocks(store);
        let columns = (columns.into_par_iter().enumerate().with_min_len(COLUMN_TASK))
            .map_init(|| place_table(num_blocks), |places, (j, inc)| NewColumn::of(j, inc, &blocks_of, places));
        Self::lay_out(columns.collect())
    }

    /// The pattern of no blocks.
    pub fn empty() -> Self {
        SparsePattern {
            num_blocks: 0,
            blocks: BlockStructure::default(),
            scalar: OnceLock::new(),
            col_stride: Vec::new(),
            offsets: vec![0],
            slot_offsets: vec![0],
            incidences: Vec::new(),
            slots: Vec::new(),
            diagonal: Vec::new(),
        }
    }

    /// Updates the pattern's structure after the entries `changed` (stable
    /// ids, sorted) changed the blocks they couple: `blocks_of(id)` are an
    /// entry's blocks now, in its local order (none for an entry that is
    /// gone), `old_nodes` the blocks the changed entries coupled before.
    /// Only the columns of their blocks, old and new, are recomputed, and
    /// written where they now start; the others move as a whole, in place
    /// (`move_columns`), instead of being copied into new arrays: a blade
    /// cut across bunny_100k (3,000 nodes touched) took 14-15 ms in this
    /// phase with copies, 8 ms in place, and faults in no new pages until
    /// the arrays outgrow their capacity (`grow`). Blocks from `num_blocks`
    /// on are dropped (a failed cut's, when its update is undone).
    ///
    /// The structure needs no element data, so it is updated while the
    /// store rebuilds the changed elements (for an element store, `blocks_of`
    /// reads the mesh's element nodes, which the store keeps in the same
    /// order). Where the entries sit in their groups is filled in by
    /// [`SparsePattern::locate`] once the couplings hold them: until then
    /// the pattern's structure ([`SparsePattern::blocks`]) is
    /// the new one, but it must not assemble.
    #[must_use = "the pattern assembles only once its entries are located"]
    pub fn update<'a>(
        &mut self,
        num_blocks: usize,
        blocks_of: &(impl Fn(u32) -> &'a [u32] + Sync),
        changed: &[u32],
        old_nodes: &[u32],
    ) -> Unlocated {
        // (the counting sort below lists each block's new incidences in the
        // order of `changed`, which must be the pattern's: by id)
        debug_assert!(changed.windows(2).all(|w| w[0] < w[1]), "changed entries sorted");
        let kept = self.num_blocks;
        // (every column at or past the new end is "recomputed": it does not move)
        let mut dirty = vec![false; num_blocks.max(kept)];
        old_nodes.iter().filter(|&&v| (v as usize) < num_blocks).for_each(|&v| dirty[v as usize] = true);
        dirty[kept.min(num_blocks)..].fill(true);
        // the changed entries' incidences by block (a counting sort: each
        // block's in the order of `changed`, by id)
        let mut added_at = vec![0u32; num_blocks.max(kept) + 1];
        for &e in changed {
            for &v in blocks_of(e) {
                dirty[v as usize] = true;
                added_at[v as usize + 1] += 1;
            }
        }
        (1..added_at.len()).for_each(|j| added_at[j] += added_at[j - 1]);
        let mut added = vec![UNSET; added_at[added_at.len() - 1] as usize];
        let mut fill = added_at.clone();
        for &e in changed {
            let blocks = blocks_of(e);
            for (a, &v) in blocks.iter().enumerate() {
                let size = blocks.len() as u32;
                let inc = Incidence { batch: UNLOCATED, element: UNLOCATED, id: e, local: a as u32, size, slots: 0 };
                added[fill[v as usize] as usize] = inc;
                fill[v as usize] += 1;
            }
        }
        let last = changed.iter().max().map_or(0, |&e| e as usize + 1);
        let mut is_changed = vec![false; last];
        changed.iter().for_each(|&e| is_changed[e as usize] = true);
        let was_changed = |e: u32| is_changed.get(e as usize).copied().unwrap_or(false);
        let dirty_list: Vec<usize> = (0..num_blocks).filter(|&j| dirty[j]).collect();
        // where the changed entries sat: the couplings move others into
        // these places (a swap-remove), whose incidences `locate` refreshes
        // (each entry read once, where it holds its first block: all its
        // old blocks are among `old_nodes`)
        let mut vacated: Vec<(u32, u32)> = (0..kept)
            .filter(|&j| dirty[j])
            .flat_map(|j| self.column_incidences(j))
            .filter(|inc| inc.local == 0 && was_changed(inc.id) && inc.batch != UNLOCATED)
            .map(|inc| (inc.batch, inc.element))
            .collect();
        vacated.sort_unstable();
        vacated.dedup();
        // (the columns are independent: made in parallel, in order)
        let this = &*self;
        let new: Vec<NewColumn> = (dirty_list.par_iter().with_min_len(COLUMN_TASK))
            .map_init(
                || place_table(num_blocks),
                |places, &j| {
                    let staying = this.column_incidences(j).iter().filter(|inc| !was_changed(inc.id)).copied();
                    let fresh = &added[added_at[j] as usize..added_at[j + 1] as usize];
                    NewColumn::of(j, staying.chain(fresh.iter().copied()).collect(), blocks_of, places)
                },
            )
            .collect();
        let mut which = vec![u32::MAX; num_blocks];
        dirty_list.iter().enumerate().for_each(|(k, &j)| which[j] = k as u32);
        let fresh = |j: usize| new.get(which[j] as usize);
        // where the columns start now: block rows (values in nines),
        // incidences, slots
        let ptr = self.blocks.columns().ptr;
        let old_rows: Vec<usize> = (0..=kept).map(|j| ptr.get(j).map_or(0, |&p| p as usize)).collect();
        let old_incidences: Vec<usize> = self.offsets.iter().map(|&o| o as usize).collect();
        let old_slots: Vec<usize> = self.slot_offsets.iter().map(|&o| o as usize).collect();
        let rows = new_starts(&old_rows, |j| fresh(j).map(|c| c.rows.len()), num_blocks);
        let incidences = new_starts(&old_incidences, |j| fresh(j).map(|c| c.incidences.len()), num_blocks);
        let slots = new_starts(&old_slots, |j| fresh(j).map(|c| c.slots.len()), num_blocks);
        // the columns that stay the same move, then the new ones are written
        // (the scalar structure, if it was made, is made again when asked for)
        self.scalar = OnceLock::new();
        let mut block_rows = std::mem::take(&mut self.blocks).into_rows();
        let (incidence_array, slot_array) = (&mut self.incidences, &mut self.slots);
        rayon::join(
            || relocate(&mut block_rows, &dirty, &old_rows, &rows, 0),
            || {
                relocate(incidence_array, &dirty, &old_incidences, &incidences, UNSET);
                relocate(slot_array, &dirty, &old_slots, &slots, 0);
            },
        );
        crate::resize_with_room(&mut self.col_stride, num_blocks, 0);
        crate::resize_with_room(&mut self.diagonal, num_blocks, 0);
        // the new columns written in parallel, each into its own stretches
        let sizes: Vec<[usize; 3]> = new.iter().map(|c| [c.rows.len(), c.incidences.len(), c.slots.len()]).collect();
        let block_parts = columns_of(&mut block_rows, &dirty_list, &rows, |k| sizes[k][0]);
        let inc_parts = columns_of(&mut self.incidences, &dirty_list, &incidences, |k| sizes[k][1]);
        let slot_parts = columns_of(&mut self.slots, &dirty_list, &slots, |k| sizes[k][2]);
        (new.par_iter().zip(block_parts).zip(inc_parts.into_par_iter().zip(slot_parts)))
            .for_each(|((column, block_out), (inc_out, slot_out))| column.write(block_out, inc_out, slot_out));
        for (&j, column) in dirty_list.iter().zip(&new) {
            (self.diagonal[j], self.col_stride[j]) = (column.diagonal, 3 * column.rows.len());
        }
        (self.offsets, self.slot_offsets) = (narrow(incidences.iter().copied()), narrow(slots.iter().copied()));
        self.num_blocks = num_blocks;
        self.blocks = block_structure(&rows, block_rows, false);
        Unlocated { columns: dirty_list, vacated }
    }

    /// Locates the entries an [`SparsePattern::update`] left unlocated in
    /// `couplings` (which now hold the changed entries): every incidence of
    /// a recomputed column, and those of the entries the couplings moved
    /// into the changed entries' old places.
    pub fn locate(&mut self, couplings: &impl Couplings, unlocated: Unlocated) {
        let Unlocated { columns, vacated } = unlocated;
        let starts: Vec<usize> = self.offsets.iter().map(|&o| o as usize).collect();
        let parts =
            columns_of(&mut self.incidences, &columns, &starts, |k| starts[columns[k] + 1] - starts[columns[k]]);
        parts.into_par_iter().with_min_len(64).for_each(|column| {
            for inc in column {
                (inc.batch, inc.element) = couplings.locate(inc.id);
            }
        });
        for (b, i) in vacated {
            if (i as usize) >= couplings.entries(b as usize) {
                continue;
            }
            let id = couplings.id(b as usize, i as usize);
            for &v in couplings.blocks(b as usize, i as usize) {
                let column = self.offsets[v as usize] as usize..self.offsets[v as usize + 1] as usize;
                for inc in self.incidences[column].iter_mut().filter(|inc| inc.id == id) {
                    (inc.batch, inc.element) = (b, i);
                }
            }
        }
    }

    /// The ids of the entries (elements) coupling block `j`, in the
    /// pattern's fixed order (none for a block past the pattern).
    pub fn elements_at(&self, j: usize) -> impl Iterator<Item = u32> + '_ {
        self.column_incidences(j).iter().map(|inc| inc.id)
    }

    /// Where the entries coupling block `j` hold it, in the pattern's fixed
    /// order: `(group, entry, local)`, block `j` being the entry's
    /// `local`-th (none for a block past the pattern).
    pub fn held_at(&self, j: usize) -> impl Iterator<Item = (usize, usize, usize)> + '_ {
        self.column_incidences(j).iter().map(|inc| (inc.batch as usize, inc.element as usize, inc.local as usize))
    }

    /// The incidences of node `j` (none for a node past the pattern).
    fn column_incidences(&self, j: usize) -> &[Incidence] {
        match (self.offsets.get(j), self.offsets.get(j + 1)) {
            (Some(&a), Some(&b)) => &self.incidences[a as usize..b as usize],
            _ => &[],
        }
    }

    /// Lays out `columns` one after another: the sizes first, then every
    /// column written into its own stretch of the arrays, in parallel over
    /// runs of [`LAY_OUT_RUN`] columns (the arrays are the same whatever
    /// the thread count).
    fn lay_out(columns: Vec<NewColumn>) -> Self {
        let num_blocks = columns.len();
        // per column: block rows, incidences, slots
        let sizes = |c: &NewColumn| [c.rows.len(), c.incidences.len(), c.slots.len()];
        let mut starts: Vec<[usize; 3]> = Vec::with_capacity(num_blocks + 1);
        let mut at = [0usize; 3];
        for column in &columns {
            starts.push(at);
            let size = sizes(column);
            (0..3).for_each(|k| at[k] += size[k]);
        }
        starts.push(at);
        let (mut block_rows, mut incidences, mut slots) = (Vec::new(), Vec::new(), Vec::new());
        crate::resize_with_room(&mut block_rows, at[0], 0);
        crate::resize_with_room(&mut incidences, at[1], UNSET);
        crate::resize_with_room(&mut slots, at[2], 0);
        // the arrays cut into the stretches of runs of columns
        let ranges: Vec<std::ops::Range<usize>> =
            (0..num_blocks).step_by(LAY_OUT_RUN).map(|first| first..(first + LAY_OUT_RUN).min(num_blocks)).collect();
        let lengths = |k: usize, unit: usize| -> Vec<usize> {
            ranges.iter().map(|r| unit * (starts[r.end][k] - starts[r.start][k])).collect()
        };
        let block_parts = crate::stretches(&mut block_rows, lengths(0, 1));
        let (inc_parts, slot_parts) =
            (crate::stretches(&mut incidences, lengths(1, 1)), crate::stretches(&mut slots, lengths(2, 1)));
        let runs: Vec<_> = (ranges.iter().cloned().zip(block_parts).zip(inc_parts).zip(slot_parts))
            .map(|(((range, b), i), s)| (range, b, i, s))
            .collect();
        runs.into_par_iter().for_each(|(range, block_out, inc_out, slot_out)| {
            let base = starts[range.start];
            for j in range {
                let [b, i, s] = std::array::from_fn(|k| starts[j][k] - base[k]);
                let [bs, is, ss] = sizes(&columns[j]);
                let block_out = &mut block_out[b..b + bs];
                let (inc_out, slot_out) = (&mut inc_out[i..i + is], &mut slot_out[s..s + ss]);
                columns[j].write(block_out, inc_out, slot_out);
            }
        });
        let diagonal: Vec<u32> = columns.iter().map(|c| c.diagonal).collect();
        let col_stride: Vec<usize> = columns.iter().map(|c| 3 * c.rows.len()).collect();
        let row_starts: Vec<usize> = starts.iter().map(|s| s[0]).collect();
        let blocks = block_structure(&row_starts, block_rows, true);
        SparsePattern {
            num_blocks,
            blocks,
            scalar: OnceLock::new(),
            col_stride,
            offsets: narrow(starts.iter().map(|s| s[1])),
            slot_offsets: narrow(starts.iter().map(|s| s[2])),
            incidences,
            slots,
            diagonal,
        }
    }

    /// The 3x3 block structure of the pattern.
    pub fn blocks(&self) -> &BlockStructure {
        &self.blocks
    }

    /// The scalar compressed-column structure (`3 num_blocks` square, both
    /// triangles), made from the blocks on the first call after a change.
    pub fn symbolic(&self) -> SymbolicSparseColMatRef<'_, usize> {
        self.system().scalar()
    }

    /// Whether the scalar structure is made (since the last change): a
    /// solver that works on blocks never asks for it.
    pub fn holds_scalar(&self) -> bool {
        self.scalar.get().is_some()
    }

    /// The pattern as a solver takes it (the scalar structure made only if
    /// the solver asks for it).
    pub fn system(&self) -> SystemPattern<'_> {
        SystemPattern::new(&self.blocks, &self.scalar)
    }

    /// Number of stored scalar entries.
    pub fn nnz(&self) -> usize {
        self.blocks.values_len()
    }

    /// Value index of the diagonal entry of scalar unknown `d`.
    pub fn diagonal_slot(&self, d: usize) -> usize {
        self.block_slot(d / 3, d % 3, d % 3)
    }

    /// Value index of scalar entry `(3 j + r, 3 j + c)` of the diagonal block
    /// of node `j`.
    pub fn block_slot(&self, j: usize, r: usize, c: usize) -> usize {
        self.blocks.start(j) + self.diagonal[j] as usize + c * self.col_stride[j] + r
    }

    /// Value index of entry `(3 i, 3 j)` of block `(i, j)`, if the pattern
    /// holds that block: entry `(3 i + r, 3 j + c)` is at `base + c stride
    /// + r` with [`SparsePattern::column_stride`]`(j)`.
    pub fn block_offset(&self, i: usize, j: usize) -> Option<usize> {
        let rows = self.blocks.column_rows(j);
        rows.binary_search(&(i as u32)).ok().map(|p| self.blocks.start(j) + 3 * p)
    }

    /// The offset between consecutive scalar columns of block column `j`.
    pub fn column_stride(&self, j: usize) -> usize {
        self.col_stride[j]
    }

    /// A matrix view of `values` on this pattern.
    pub fn matrix<'a>(&'a self, values: &'a [f64]) -> SparseColMatRef<'a, usize, f64> {
        SparseColMatRef::new(self.symbolic(), values)
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
        self.assemble_prefetched(values, blocks, |_, _| {}, |_| [0.0; 3]);
    }

    /// [`SparsePattern::assemble`], calling `prefetch(batch, element)` a few
    /// incidences before `blocks` reads that element, so that its data is
    /// on its way to the cache (a hint: results do not depend on it), and
    /// adding `diagonal(j)` to the three diagonal entries of node `j` once
    /// its column is summed (a mass term: added while the column is in the
    /// cache, where a pass over the diagonals after the assembly took 0.9
    /// ms of a bunny_100k step on one thread, missing the cache at every
    /// node).
    ///
    /// The sums go straight into `values`, value by value. Measured on
    /// bunny_100k (2 threads, Intel Xeon with AVX-512), these variants were
    /// slower than that code's 4.8 ms:
    /// - summing the column in a stack buffer of four-lane block rows,
    ///   under AVX2, and writing it once (5.3-5.5 ms);
    /// - the same with the column written by non-temporal stores
    ///   (9.4-10 ms);
    /// - the whole crate built for the machine (`-C target-cpu=native`:
    ///   AVX-512 code for the blocks' arithmetic, with the same bits), on
    ///   another Intel Xeon with AVX-512 (model 207, 2 vCPUs) where this
    ///   code took 8.6-10.9 ms per clamped bunny_100k step: 11.9-12.3 ms,
    ///   over four alternated runs of 20 steps. The arithmetic is not what
    ///   limits the assembly.
    ///
    /// With constant blocks, the same code takes 2.5 ms. Writing the values
    /// (18 MB) costs about half of the assembly.
    pub fn assemble_prefetched<F, P, D>(&self, values: &mut [f64], blocks: F, prefetch: P, diagonal: D)
    where
        F: Fn(usize, usize, usize, &mut [[f64; 9]]) + Sync,
        P: Fn(usize, usize) + Sync,
        D: Fn(usize) -> [f64; 3] + Sync,
    {
        assert_eq!(values.len(), self.nnz());
        let shared = SharedValues(values.as_mut_ptr());
        // one column of blocks per task, on the stack (no allocation)
        let column = || [[0.0f64; 9]; MAX_ENTRY_BLOCKS];
        (0..self.num_blocks).into_par_iter().with_min_len(64).for_each_init(column, |scratch, j| {
            let values = shared.get();
            let (stride, base) = (self.col_stride[j], self.blocks.start(j));
            // SAFETY (every write below): entries of columns 3j..3j+3
            // belong to this node task only, and lie in `values`
            for p in base..base + 3 * stride {
                unsafe { *values.add(p) = 0.0 };
            }
            let (first, end) = (self.offsets[j] as usize, self.offsets[j + 1] as usize);
            let first_slot = self.slot_offsets[j] as usize;
            for t in first..end {
                if let Some(ahead) = self.incidences.get(t + PREFETCH_AHEAD) {
                    prefetch(ahead.batch as usize, ahead.element as usize);
                }
                let inc = &self.incidences[t];
                let at = first_slot + inc.slots as usize;
                let slots = &self.slots[at..at + inc.size as usize];
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
            let (add, at) = (diagonal(j), base + self.diagonal[j] as usize);
            for (c, add) in add.into_iter().enumerate() {
                unsafe { *values.add(at + c * stride + c) += add };
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
            for inc in self.column_incidences(j) {
                let v = element_vector(inc.batch as usize, inc.element as usize, inc.local as usize);
                s = [s[0] + v[0], s[1] + v[1], s[2] + v[2]];
            }
            *o = s;
        });
    }
}
