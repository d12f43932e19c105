//! A mesh renumbered for locality: nodes in the reverse Cuthill–McKee order
//! of the node graph (two nodes adjacent when an element holds both), then
//! elements by their first node in that order.
//!
//! The engine's passes gather per node over the elements that touch it and
//! per element over its nodes. In the order a mesh file gives (bunny_100k's
//! nodes: a coupled pair lies 8,800 nodes apart on average, the bandwidth
//! is 17,537 of 17,608) those reads land all over memory; after the
//! renumbering neighbours sit within the order's bandwidth (981 for
//! bunny_100k) and an element's nodes close to each other and to the
//! elements before it. Nothing else changes: positions, faces, shapes and
//! orientations are the same, so is every result up to the rounding of
//! sums taken in another order.

use super::{Adjacency, PolyMesh};

/// Where the nodes and elements of a renumbered mesh went.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Renumbered {
    /// The new id of every old node.
    pub node: Vec<u32>,
    /// The new index of every old element.
    pub element: Vec<u32>,
}

impl PolyMesh {
    /// Renumbers the nodes and elements for locality (see the module docs)
    /// and returns where each went. Faces keep their places; their loops
    /// and triangles, and every element's node list (ascending, the
    /// element-local order), are written in the new node ids.
    pub fn renumber_for_locality(&mut self) -> Renumbered {
        // every node's distinct neighbours (itself among them): the graph
        // of the blocks of the matrices the mesh makes
        let adjacency = Adjacency::without_edges(self);
        let offsets = &adjacency.node_element_offsets;
        let mut graph = super::Lists::default();
        let mut row = Vec::new();
        for v in 0..self.nodes.len() {
            row.clear();
            for &e in &adjacency.node_element_ids[offsets[v] as usize..offsets[v + 1] as usize] {
                row.extend_from_slice(&self.elements[e as usize].nodes);
            }
            row.sort_unstable();
            row.dedup();
            graph.push(row.iter().copied());
        }
        let neighbours = |v: usize| graph.get(v).iter().map(|&u| u as usize);
        let order = crate::solve::reverse_cuthill_mckee(self.nodes.len(), neighbours);
        let node = self.reorder_nodes(&order);
        // elements by their first node (ties in their old order)
        let mut by_first: Vec<u32> = (0..self.elements.len() as u32).collect();
        by_first.sort_by_key(|&e| (self.elements[e as usize].nodes.first().copied().unwrap_or(u32::MAX), e));
        let element = inverse(&by_first);
        let mut old = std::mem::take(&mut self.elements);
        self.elements = by_first.iter().map(|&e| std::mem::take(&mut old[e as usize])).collect();
        Renumbered { node, element }
    }

    /// Numbers the nodes in `order` (new node `b` is old node `order[b]`,
    /// a permutation), rewriting every face loop, triangle and element
    /// node list (ascending again); returns the new id of every old node.
    pub(crate) fn reorder_nodes(&mut self, order: &[u32]) -> Vec<u32> {
        let node = inverse(order);
        self.nodes = order.iter().map(|&old| self.nodes[old as usize]).collect();
        for face in &mut self.faces {
            face.vertices.iter_mut().for_each(|v| *v = node[*v as usize]);
            face.triangles.iter_mut().flatten().for_each(|v| *v = node[*v as usize]);
        }
        for element in &mut self.elements {
            element.nodes.iter_mut().for_each(|v| *v = node[*v as usize]);
            element.nodes.sort_unstable();
        }
        node
    }
}

/// The inverse of the permutation `order`: `inverse[order[b]] = b`.
fn inverse(order: &[u32]) -> Vec<u32> {
    let mut inverse = vec![0u32; order.len()];
    for (new, &old) in order.iter().enumerate() {
        inverse[old as usize] = new as u32;
    }
    inverse
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `Σ_e (largest - smallest node id of e)`, how far an element's reads
    /// of node data spread.
    fn spread(mesh: &PolyMesh) -> usize {
        mesh.elements.iter().map(|e| (e.nodes[e.nodes.len() - 1] - e.nodes[0]) as usize).sum()
    }

    /// A box of tetrahedra and polyhedra (plane cuts) with its nodes
    /// shuffled, renumbered: the same mesh (every element's node positions
    /// and faces' loops where the maps send them, a valid mesh), its
    /// elements in the order of their first nodes, and their nodes as close
    /// together as the generator's row-by-row numbering has them.
    #[test]
    fn a_shuffled_mesh_renumbered_is_the_same_mesh_close_together() {
        use crate::topology::{split_by_plane, SplitOptions};
        let mut mesh = crate::meshing::box_tet([0.0; 3], [2.0, 1.0, 1.0], [12, 6, 6]).unwrap();
        let plane = super::super::Plane { point: [0.9, 0.5, 0.5], normal: [1.0, 0.3, -0.2] };
        split_by_plane(&mut mesh, &plane, &SplitOptions::default()).unwrap();
        let structured = spread(&mesh);
        let n = mesh.nodes.len() as u32;
        let shuffle: Vec<u32> = (0..n).map(|b| (b as u64 * 7919 % n as u64) as u32).collect();
        mesh.reorder_nodes(&shuffle);
        let shuffled = mesh.clone();
        let moved = mesh.renumber_for_locality();
        mesh.validate().unwrap();
        assert_eq!(
            (mesh.nodes.len(), mesh.elements.len(), mesh.faces.len()),
            (shuffled.nodes.len(), shuffled.elements.len(), shuffled.faces.len())
        );
        for (old, &new) in moved.node.iter().enumerate() {
            assert_eq!(mesh.nodes[new as usize], shuffled.nodes[old]);
        }
        for (old, element) in shuffled.elements.iter().enumerate() {
            let renumbered = &mesh.elements[moved.element[old] as usize];
            let mut nodes: Vec<u32> = element.nodes.iter().map(|&v| moved.node[v as usize]).collect();
            nodes.sort_unstable();
            assert_eq!(renumbered.nodes[..], nodes[..], "element {old}");
            assert_eq!(renumbered.faces, element.faces, "element {old}");
        }
        for (face, old) in mesh.faces.iter().zip(&shuffled.faces) {
            let loop_: Vec<u32> = old.vertices.iter().map(|&v| moved.node[v as usize]).collect();
            assert_eq!(face.vertices[..], loop_[..]);
        }
        assert!(mesh.elements.windows(2).all(|w| w[0].nodes[0] <= w[1].nodes[0]));
        let (before, after) = (spread(&shuffled), spread(&mesh));
        println!("element spread: {structured} as generated, {before} shuffled, {after} renumbered");
        assert!(after <= structured && 5 * after < before, "{structured}, {before}, {after}");
    }
}
