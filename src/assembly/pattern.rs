//! The block sparsity pattern and the per-node gather lists that assemble
//! into it.

use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use rayon::prelude::*;

use crate::store::ElementStore;

/// One element touching a node: where the node sits in it, and where the
/// element's blocks land in the node's column.
#[derive(Clone, Copy, Debug)]
struct Incidence {
    batch: u32,
    element: u32,
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
    /// Scalar offset between consecutive columns of block column `j`.
    col_stride: Vec<usize>,
    /// CSR offsets into `incidences`, one row per node.
    offsets: Vec<u32>,
    /// Elements touching each node, in increasing (batch, element) order.
    incidences: Vec<Incidence>,
    /// For each incidence and each local row node `a` of its element: the
    /// value index of scalar entry `(3 node_a, 3 j)` in column block `j`.
    slots: Vec<u32>,
    /// Value index of every scalar diagonal entry.
    diagonal: Vec<usize>,
}

/// A raw pointer to the values, shared by the node tasks of one assembly.
#[derive(Clone, Copy)]
struct SharedValues(*mut f64);
// SAFETY: node `j` writes only inside its own three columns, which no other
// node touches (see `SparsePattern::assemble`).
unsafe impl Send for SharedValues {}
unsafe impl Sync for SharedValues {}

impl SharedValues {
    /// Adds `v` to entry `i`.
    ///
    /// # Safety
    /// `i` must be in bounds and no other thread may access entry `i` now.
    #[inline(always)]
    unsafe fn add(&self, i: usize, v: f64) {
        unsafe { *self.0.add(i) += v };
    }
}

impl SparsePattern {
    /// Builds the pattern of `store` over `num_blocks` blocks (nodes).
    pub fn build(num_blocks: usize, store: &ElementStore) -> Self {
        // elements touching each node
        let mut counts = vec![0u32; num_blocks + 1];
        for b in &store.batches {
            for &v in &b.nodes {
                counts[v as usize + 1] += 1;
            }
        }
        for i in 0..num_blocks {
            counts[i + 1] += counts[i];
        }
        let offsets = counts.clone();
        let mut fill = counts;
        let mut incidences =
            vec![Incidence { batch: 0, element: 0, local: 0, size: 0, slots: 0 }; offsets[num_blocks] as usize];
        for (bi, b) in store.batches.iter().enumerate() {
            for e in 0..b.len() {
                for (a, &v) in b.element_nodes(e).iter().enumerate() {
                    let p = &mut fill[v as usize];
                    incidences[*p as usize] =
                        Incidence { batch: bi as u32, element: e as u32, local: a as u32, size: b.k as u32, slots: 0 };
                    *p += 1;
                }
            }
        }
        // block rows of every block column: union of the element node sets
        let rows: Vec<Vec<u32>> = (0..num_blocks)
            .into_par_iter()
            .map(|j| {
                let mut r: Vec<u32> = incidences[offsets[j] as usize..offsets[j + 1] as usize]
                    .iter()
                    .flat_map(|inc| {
                        store.batches[inc.batch as usize].element_nodes(inc.element as usize).iter().copied()
                    })
                    .collect();
                r.push(j as u32); // lone nodes keep their diagonal
                r.sort_unstable();
                r.dedup();
                r
            })
            .collect();
        let n = 3 * num_blocks;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        let mut col_start = Vec::with_capacity(num_blocks);
        let mut col_stride = Vec::with_capacity(num_blocks);
        col_ptr.push(0usize);
        for r in &rows {
            col_start.push(row_idx.len());
            col_stride.push(3 * r.len());
            for _c in 0..3 {
                for &i in r {
                    row_idx.extend_from_slice(&[3 * i as usize, 3 * i as usize + 1, 3 * i as usize + 2]);
                }
                col_ptr.push(row_idx.len());
            }
        }
        let position = |i: u32, j: usize| -> u32 {
            let p = rows[j].binary_search(&i).expect("pattern holds every element pair");
            u32::try_from(col_start[j] + 3 * p).expect("fewer than 2^32 stored entries")
        };
        let mut slots = Vec::new();
        for j in 0..num_blocks {
            for inc in &mut incidences[offsets[j] as usize..offsets[j + 1] as usize] {
                inc.slots = u32::try_from(slots.len()).expect("fewer than 2^32 slots");
                let nodes = store.batches[inc.batch as usize].element_nodes(inc.element as usize);
                slots.extend(nodes.iter().map(|&a| position(a, j)));
            }
        }
        let diagonal = (0..n)
            .map(|d| {
                let (j, c) = (d / 3, d % 3);
                position(j as u32, j) as usize + c * col_stride[j] + c
            })
            .collect();
        let symbolic = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
        SparsePattern { num_blocks, symbolic, col_stride, offsets, incidences, slots, diagonal }
    }

    /// Number of stored scalar entries.
    pub fn nnz(&self) -> usize {
        self.symbolic.row_idx().len()
    }

    /// Value index of the diagonal entry of scalar unknown `d`.
    pub fn diagonal_slot(&self, d: usize) -> usize {
        self.diagonal[d]
    }

    /// Value index of scalar entry `(3 j + r, 3 j + c)` of the diagonal block
    /// of node `j`.
    pub fn block_slot(&self, j: usize, r: usize, c: usize) -> usize {
        self.diagonal[3 * j] + c * self.col_stride[j] + r
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
        assert_eq!(values.len(), self.nnz());
        let shared = SharedValues(values.as_mut_ptr());
        let col_ptr = self.symbolic.col_ptr();
        (0..self.num_blocks).into_par_iter().with_min_len(64).for_each_init(Vec::new, |scratch, j| {
            let stride = self.col_stride[j];
            for p in col_ptr[3 * j]..col_ptr[3 * j + 3] {
                // SAFETY: entries of columns 3j..3j+3 belong to this node task only.
                unsafe { *shared.0.add(p) = 0.0 };
            }
            for inc in &self.incidences[self.offsets[j] as usize..self.offsets[j + 1] as usize] {
                let slots = &self.slots[inc.slots as usize..(inc.slots + inc.size) as usize];
                scratch.resize(slots.len(), [0.0; 9]);
                blocks(inc.batch as usize, inc.element as usize, inc.local as usize, scratch);
                for (kab, &slot) in scratch.iter().zip(slots) {
                    for c in 0..3 {
                        for r in 0..3 {
                            // SAFETY: `slot + c * stride + r` lies in column 3j + c
                            // (built above), which only this node task writes.
                            unsafe { shared.add(slot as usize + c * stride + r, kab[3 * r + c]) };
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
