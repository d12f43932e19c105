//! The block sparsity pattern, element slot maps and element colouring.

use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use rayon::prelude::*;

use crate::store::ElementStore;

/// Sparsity of the global matrix for one topology, with everything needed
/// to write element matrices into its values without searching.
#[derive(Clone, Debug)]
pub struct SparsePattern {
    /// Number of blocks (3 scalar unknowns each).
    pub num_blocks: usize,
    /// The scalar compressed-column structure (`3 * num_blocks` square).
    pub symbolic: SymbolicSparseColMat<usize>,
    /// Scalar offset between consecutive columns of block column `j`
    /// (`3 *` its number of block rows).
    col_stride: Vec<usize>,
    /// Per batch, per element, per local pair `(a, b)` (row-major `k x k`):
    /// the value index of scalar entry `(3 node_a, 3 node_b)`.
    slots: Vec<Vec<usize>>,
    /// Per batch: element indices grouped by colour.
    colours: Vec<Vec<Vec<u32>>>,
    /// Value index of every scalar diagonal entry.
    diagonal: Vec<usize>,
}

/// A raw pointer to the values that colour classes write concurrently.
#[derive(Clone, Copy)]
struct SharedValues(*mut f64);
// SAFETY: threads write through it only to disjoint slots (one element per
// colour touches any entry), see `SparsePattern::assemble`.
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
        // block rows of every block column: union of element node sets
        let mut touching: Vec<Vec<u32>> = vec![Vec::new(); num_blocks];
        for b in &store.batches {
            for i in 0..b.len() {
                let nodes = b.element_nodes(i);
                for &j in nodes {
                    touching[j as usize].extend_from_slice(nodes);
                }
            }
        }
        touching.par_iter_mut().for_each(|rows| {
            rows.sort_unstable();
            rows.dedup();
        });
        // lone blocks (nodes of no element) still get their diagonal
        for (j, rows) in touching.iter_mut().enumerate() {
            if rows.is_empty() {
                rows.push(j as u32);
            }
        }
        let n = 3 * num_blocks;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        let mut col_start = Vec::with_capacity(num_blocks);
        let mut col_stride = Vec::with_capacity(num_blocks);
        col_ptr.push(0usize);
        for rows in &touching {
            col_start.push(row_idx.len());
            col_stride.push(3 * rows.len());
            for _c in 0..3 {
                for &i in rows {
                    row_idx.extend_from_slice(&[3 * i as usize, 3 * i as usize + 1, 3 * i as usize + 2]);
                }
                col_ptr.push(row_idx.len());
            }
        }
        let position = |i: u32, j: u32| -> usize {
            let rows = &touching[j as usize];
            col_start[j as usize] + 3 * rows.binary_search(&i).expect("pattern holds every element pair")
        };
        let slots: Vec<Vec<usize>> = store
            .batches
            .iter()
            .map(|b| {
                let k = b.k;
                (0..b.len())
                    .into_par_iter()
                    .flat_map_iter(|e| {
                        let nodes = b.element_nodes(e);
                        (0..k * k).map(move |ab| position(nodes[ab / k], nodes[ab % k]))
                    })
                    .collect()
            })
            .collect();
        let diagonal = (0..n)
            .map(|d| {
                let (j, c) = (d / 3, d % 3);
                position(j as u32, j as u32) + c * col_stride[j] + c
            })
            .collect();
        let colours = store.batches.iter().map(|b| colour(b.k, &b.nodes, num_blocks)).collect();
        // SAFETY-free check of the structure happens inside faer.
        let symbolic = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
        SparsePattern { num_blocks, symbolic, col_stride, slots, colours, diagonal }
    }

    /// Number of stored scalar entries.
    pub fn nnz(&self) -> usize {
        self.symbolic.row_idx().len()
    }

    /// Value index of the diagonal entry of scalar unknown `d`.
    pub fn diagonal_slot(&self, d: usize) -> usize {
        self.diagonal[d]
    }

    /// A matrix view of `values` on this pattern.
    pub fn matrix<'a>(&'a self, values: &'a [f64]) -> SparseColMatRef<'a, usize, f64> {
        SparseColMatRef::new(self.symbolic.as_ref(), values)
    }

    /// Adds every element matrix to `values` (which the caller zeroes).
    ///
    /// `element_matrix(batch, i, out)` writes the dense row-major `3k x 3k`
    /// matrix of entry `i` of `batch` into `out`. Deterministic: see the
    /// module docs of [`crate::assembly`].
    pub fn assemble<F>(&self, store: &ElementStore, values: &mut [f64], element_matrix: F)
    where
        F: Fn(usize, usize, &mut [f64]) + Sync,
    {
        assert_eq!(values.len(), self.nnz());
        let shared = SharedValues(values.as_mut_ptr());
        for (bi, b) in store.batches.iter().enumerate() {
            let k = b.k;
            let slots = &self.slots[bi];
            for class in &self.colours[bi] {
                class.par_chunks(64).for_each_init(
                    || vec![0.0; 9 * k * k],
                    |ke, chunk| {
                        for &e in chunk {
                            let e = e as usize;
                            element_matrix(bi, e, ke);
                            let nodes = b.element_nodes(e);
                            for a in 0..k {
                                for bb in 0..k {
                                    let base = slots[e * k * k + a * k + bb];
                                    let stride = self.col_stride[nodes[bb] as usize];
                                    for c in 0..3 {
                                        for r in 0..3 {
                                            let v = ke[(3 * a + r) * 3 * k + 3 * bb + c];
                                            // SAFETY: `base + c * stride + r` is a valid value
                                            // index (built above), and no other element of this
                                            // colour shares node pair (a, bb), so no other thread
                                            // touches this entry while this colour runs.
                                            unsafe { shared.add(base + c * stride + r, v) };
                                        }
                                    }
                                }
                            }
                        }
                    },
                );
            }
        }
    }
}

/// Greedy colouring of the elements of one batch (`k` nodes each) so that
/// no two elements of one colour share a node; returns the colour classes.
fn colour(k: usize, nodes: &[u32], num_blocks: usize) -> Vec<Vec<u32>> {
    let n = nodes.len() / k.max(1);
    // node -> elements of this batch
    let mut start = vec![0u32; num_blocks + 1];
    for &v in nodes {
        start[v as usize + 1] += 1;
    }
    for i in 0..num_blocks {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut incident = vec![0u32; nodes.len()];
    for (p, &v) in nodes.iter().enumerate() {
        incident[fill[v as usize] as usize] = (p / k) as u32;
        fill[v as usize] += 1;
    }
    let mut colour_of = vec![u32::MAX; n];
    let mut classes: Vec<Vec<u32>> = Vec::new();
    let mut taken: Vec<bool> = Vec::new();
    for e in 0..n {
        taken.iter_mut().for_each(|t| *t = false);
        for &v in &nodes[e * k..(e + 1) * k] {
            for &other in &incident[start[v as usize] as usize..start[v as usize + 1] as usize] {
                let c = colour_of[other as usize];
                if c != u32::MAX {
                    taken[c as usize] = true;
                }
            }
        }
        let c = taken.iter().position(|t| !t).unwrap_or(taken.len());
        if c == taken.len() {
            taken.push(false);
            classes.push(Vec::new());
        }
        colour_of[e] = c as u32;
        classes[c].push(e as u32);
    }
    classes
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::Material;
    use crate::meshing::box_tet;

    #[test]
    fn colouring_separates_elements_sharing_nodes() {
        let mesh = box_tet([0.0; 3], [1.0; 3], [3, 2, 2]).unwrap();
        let store = ElementStore::build(&mesh, &Material::new(1.0, 0.3, 1.0).unwrap(), &Default::default()).unwrap();
        let b = &store.batches[0];
        let classes = colour(b.k, &b.nodes, mesh.nodes.len());
        assert_eq!(classes.iter().map(Vec::len).sum::<usize>(), b.len());
        for class in &classes {
            let mut seen = std::collections::HashSet::new();
            for &e in class {
                for &v in b.element_nodes(e as usize) {
                    assert!(seen.insert(v), "node {v} twice in one colour");
                }
            }
        }
    }
}
