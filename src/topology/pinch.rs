//! Opening pinched nodes: a node whose elements fall into groups that no
//! chain of faces through the node connects (pieces touching at a vertex
//! or along an edge) becomes one node per group.
//!
//! Nodal families share a node's value among all its elements, so such a
//! node is a hinge and holds the pieces together. The discontinuous
//! Galerkin family glues elements through shared faces only: there the
//! pieces move apart, and a node they share would average positions of
//! different pieces in the stitched field (and in every frame written from
//! it). Cuts make such nodes where successive cut planes, snapped nodes and
//! elements kept whole meet along a line.

use crate::mesh::{Adjacency, PolyMesh};

/// The groups of elements around node `v`: elements holding `v`, joined
/// when they share a face through `v`; the group of the lowest element id
/// first, every group in increasing element order.
fn groups_around(mesh: &PolyMesh, adjacency: &Adjacency, v: u32) -> Vec<Vec<u32>> {
    let around = adjacency.node_elements(v as usize);
    let mut label: Vec<usize> = (0..around.len()).collect();
    fn root(label: &mut [usize], mut i: usize) -> usize {
        while label[i] != i {
            label[i] = label[label[i]];
            i = label[i];
        }
        i
    }
    for (i, &e) in around.iter().enumerate() {
        for r in &mesh.elements[e as usize].faces {
            if !mesh.faces[r.face as usize].vertices.contains(&v) {
                continue;
            }
            for other in adjacency.face_elements[r.face as usize] {
                // every element on a face through v holds v (the padding
                // of a boundary face is found nowhere)
                let Ok(j) = around.binary_search(&other) else { continue };
                let (a, b) = (root(&mut label, i), root(&mut label, j));
                label[a.max(b)] = a.min(b);
            }
        }
    }
    let mut groups: Vec<Vec<u32>> = Vec::new();
    let mut group_of_root = vec![usize::MAX; around.len()];
    for (i, &e) in around.iter().enumerate() {
        let r = root(&mut label, i);
        if group_of_root[r] == usize::MAX {
            group_of_root[r] = groups.len();
            groups.push(Vec::new());
        }
        groups[group_of_root[r]].push(e);
    }
    groups
}

/// The pinched nodes among `candidates` (see the module docs), in
/// increasing order.
pub fn pinched_nodes(mesh: &PolyMesh, candidates: impl IntoIterator<Item = u32>) -> Vec<u32> {
    let adjacency = Adjacency::without_edges(mesh);
    let mut pinched: Vec<u32> =
        candidates.into_iter().filter(|&v| groups_around(mesh, &adjacency, v).len() > 1).collect();
    pinched.sort_unstable();
    pinched.dedup();
    pinched
}

/// Opens every node of `nodes` that is pinched: the group of elements
/// holding its lowest-numbered element keeps it, every other group gets a
/// new node at the same position (appended) and its faces through the node
/// renamed. Returns the `(original, copy)` pairs and the elements whose
/// nodes changed (sorted). Geometry, faces and elements keep their ids.
pub fn open_pinched_nodes(mesh: &mut PolyMesh, nodes: &[u32]) -> (Vec<(u32, u32)>, Vec<u32>) {
    let adjacency = Adjacency::without_edges(mesh);
    let mut duplicated = Vec::new();
    let mut changed = Vec::new();
    for &v in nodes {
        let groups = groups_around(mesh, &adjacency, v);
        for group in groups.iter().skip(1) {
            let copy = mesh.nodes.len() as u32;
            mesh.nodes.push(mesh.nodes[v as usize]);
            duplicated.push((v, copy));
            for &e in group {
                for k in 0..mesh.elements[e as usize].faces.len() {
                    // faces through v are used by this group only, so each
                    // is renamed once
                    let face = &mut mesh.faces[mesh.elements[e as usize].faces[k].face as usize];
                    let rename = |w: &mut u32| {
                        if *w == v {
                            *w = copy;
                        }
                    };
                    face.vertices.iter_mut().for_each(rename);
                    face.triangles.iter_mut().for_each(|t| t.iter_mut().for_each(rename));
                }
                mesh.refresh_element_nodes(e as usize);
                changed.push(e);
            }
        }
    }
    changed.sort_unstable();
    changed.dedup();
    (duplicated, changed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Cell;
    use crate::meshing::box_hex;

    /// Two unit cubes touching along the edge x = 1, y = 1 only.
    fn edge_touching_cubes() -> PolyMesh {
        let corners = |o: [f64; 3]| -> Vec<[f64; 3]> {
            let mut v = Vec::new();
            for z in [0.0, 1.0] {
                for (x, y) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
                    v.push([o[0] + x, o[1] + y, o[2] + z]);
                }
            }
            v
        };
        let mut nodes = corners([0.0; 3]);
        // the second cube's corner (0, 0) is the first cube's corner (1, 1)
        let second = corners([1.0, 1.0, 0.0]);
        let mut ids = [0u32; 8];
        for (i, p) in second.iter().enumerate() {
            ids[i] = nodes.iter().position(|q| q == p).unwrap_or_else(|| {
                nodes.push(*p);
                nodes.len() - 1
            }) as u32;
        }
        PolyMesh::from_cells(nodes, &[Cell::Hex([0, 1, 2, 3, 4, 5, 6, 7]), Cell::Hex(ids)]).unwrap()
    }

    #[test]
    fn cubes_touching_along_an_edge_get_their_own_nodes() {
        let mut mesh = edge_touching_cubes();
        assert_eq!(mesh.nodes.len(), 14);
        let all = 0..mesh.nodes.len() as u32;
        let pinched = pinched_nodes(&mesh, all.clone());
        assert_eq!(pinched, vec![2, 6], "the two nodes of the shared edge");
        let (duplicated, changed) = open_pinched_nodes(&mut mesh, &pinched);
        assert_eq!(duplicated, vec![(2, 14), (6, 15)]);
        assert_eq!(changed, vec![1]);
        assert!(mesh.elements[0].nodes.iter().all(|v| !mesh.elements[1].nodes.contains(v)));
        assert!(pinched_nodes(&mesh, 0..mesh.nodes.len() as u32).is_empty());
        // (coincident copies are by design, as after a cut: check the elements)
        mesh.check_elements(&[0, 1], &crate::mesh::ValidationOptions::default()).unwrap();
        let x = |v: u32| mesh.nodes[v as usize];
        assert_eq!(x(14), x(2));
        assert_eq!(x(15), x(6));
    }

    #[test]
    fn a_conforming_mesh_has_no_pinched_node() {
        let mesh = box_hex([0.0; 3], [2.0, 1.0, 1.0], [3, 2, 2]).unwrap();
        assert!(pinched_nodes(&mesh, 0..mesh.nodes.len() as u32).is_empty());
    }
}
