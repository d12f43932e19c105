//! Elements equal up to a translation share one fit. A grid of one cell
//! shape (the L-prisms of `box_l_prisms`, every cell of a structured
//! non-hexahedral mesh) holds thousands of copies of one element, and the
//! least-squares fit of the method of fundamental solutions is most of an
//! element's cost: it is made once per shape, and each copy takes the
//! fitted functions and quadrature rule moved by its offset.
//!
//! Two elements have the same shape when their vertices, in element-local
//! order and relative to the first, agree to [`QUANTUM`] of the binade of
//! their diameter (a translation's rounding, `1e-16` of the coordinates,
//! is far below it; a copy scaled by even `1 + 1e-9` is another shape),
//! and their faces are the same loops of local vertices with the
//! same orientation. A copy's functions then differ from a fit of its own
//! by about that quantum, far below the fit's own error (`1e-3` and up at
//! the collocation points); its gradients are still shifted to its own
//! shared face moments, so the discrete divergence theorem holds exactly.

use std::collections::HashMap;

use cleave_kernels::vec3::sub;

use crate::mesh::PolyMesh;

/// Resolution of a shape key, relative to the power of two at or below
/// the element's diameter (`2^-40`, about `9e-13`).
pub const QUANTUM: f64 = 1.0 / (1u64 << 40) as f64;

/// The elements of a batch grouped by shape: `template[i]` is the index
/// (into the batch's elements) of the first element with the shape of
/// element `i`, the one whose fit the others take.
pub(super) fn templates(mesh: &PolyMesh, elements: &[u32]) -> Vec<usize> {
    let mut first: HashMap<Vec<i64>, usize> = HashMap::with_capacity(elements.len());
    elements.iter().enumerate().map(|(i, &e)| *first.entry(shape_key(mesh, e as usize)).or_insert(i)).collect()
}

/// The offset (m) that moves element `from` onto the congruent `to`: the
/// difference of their first vertices.
pub(super) fn offset(mesh: &PolyMesh, from: u32, to: u32) -> [f64; 3] {
    let first = |e: u32| mesh.nodes[mesh.elements[e as usize].nodes[0] as usize];
    sub(first(to), first(from))
}

/// The shape of element `e` up to translation: the binary exponent `p`
/// of its diameter, its vertices relative to the first in units of
/// [`QUANTUM`] times `2^p` (a length, not a fraction of the diameter: a
/// scaled copy has another shape), then its faces as outward loops of
/// local vertex indices (each closed by `-1`).
fn shape_key(mesh: &PolyMesh, e: usize) -> Vec<i64> {
    let el = &mesh.elements[e];
    let p = mesh.element_diameter(e).log2().floor();
    let unit = QUANTUM * p.exp2();
    let x0 = mesh.nodes[el.nodes[0] as usize];
    let mut key: Vec<i64> = vec![p as i64];
    key.extend(el.nodes.iter().flat_map(|&v| {
        let d = sub(mesh.nodes[v as usize], x0);
        d.map(|c| (c / unit).round() as i64)
    }));
    for r in &el.faces {
        let vertices = &mesh.faces[r.face as usize].vertices;
        let local = |v: &u32| el.nodes.binary_search(v).map_or(-2, |i| i as i64);
        if r.outward {
            key.extend(vertices.iter().map(local));
        } else {
            key.extend(vertices.iter().rev().map(local));
        }
        key.push(-1);
    }
    key
}
