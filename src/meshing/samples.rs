//! Sample meshes for benchmarks and tests: single convex elements with a
//! given vertex count, and many disjoint copies of one element.

use super::clipped_box;
use crate::mesh::{Cell, MeshError, PolyMesh};

/// A single convex element with exactly `k` vertices (a clipped box; the
/// first seed that gives `k`), or `None`.
pub fn element_with_vertices(k: usize) -> Option<PolyMesh> {
    (0..30)
        .flat_map(|planes| (0..40).map(move |seed| (planes, seed)))
        .find_map(|(planes, seed)| clipped_box([0.0; 3], [1.0; 3], planes, seed).ok().filter(|m| m.nodes.len() == k))
}

/// `n` disjoint copies of the single-element `mesh`, side by side.
pub fn replicate(mesh: &PolyMesh, n: usize) -> Result<PolyMesh, MeshError> {
    let k = mesh.nodes.len();
    let loops: Vec<Vec<u32>> = mesh.elements[0]
        .faces
        .iter()
        .map(|r| {
            let v = &mesh.faces[r.face as usize].vertices;
            if r.outward {
                v.to_vec()
            } else {
                v.iter().rev().copied().collect()
            }
        })
        .collect();
    let mut nodes = Vec::with_capacity(n * k);
    let mut cells = Vec::with_capacity(n);
    for c in 0..n {
        let shift = [2.0 * (c % 100) as f64, 2.0 * (c / 100) as f64, 0.0];
        nodes.extend(mesh.nodes.iter().map(|p| [p[0] + shift[0], p[1] + shift[1], p[2]]));
        let base = (c * k) as u32;
        cells.push(Cell::Polyhedron(loops.iter().map(|l| l.iter().map(|&v| v + base).collect()).collect()));
    }
    PolyMesh::from_cells(nodes, &cells)
}
