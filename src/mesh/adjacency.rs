//! Adjacency of a mesh: face -> elements, node -> elements, edge -> faces,
//! and connected components.

use std::collections::HashMap;

use super::PolyMesh;

/// Marker for "no element" in [`Adjacency::face_elements`].
pub const NONE: u32 = u32::MAX;

/// Adjacency tables of a [`PolyMesh`], built in one pass.
#[derive(Clone, Debug)]
pub struct Adjacency {
    /// For each face, the (up to two) elements it bounds; `NONE` pads.
    pub face_elements: Vec<[u32; 2]>,
    /// CSR offsets into `node_element_ids`, one row per node.
    pub node_element_offsets: Vec<u32>,
    /// Elements touching each node, in increasing element order.
    pub node_element_ids: Vec<u32>,
    /// For each undirected edge `(min, max)`, the faces whose loops contain it.
    pub edge_faces: HashMap<(u32, u32), Vec<u32>>,
}

impl Adjacency {
    /// Builds all tables of `mesh`.
    pub fn new(mesh: &PolyMesh) -> Self {
        let mut adjacency = Self::without_edges(mesh);
        for (f, face) in mesh.faces.iter().enumerate() {
            let v = &face.vertices;
            for i in 0..v.len() {
                let (a, b) = (v[i], v[(i + 1) % v.len()]);
                adjacency.edge_faces.entry((a.min(b), a.max(b))).or_default().push(f as u32);
            }
        }
        adjacency
    }

    /// The face and node tables of `mesh`, with `edge_faces` left empty
    /// (the edge table costs more than the others together).
    pub fn without_edges(mesh: &PolyMesh) -> Self {
        let mut face_elements = vec![[NONE; 2]; mesh.faces.len()];
        for (e, el) in mesh.elements.iter().enumerate() {
            for r in &el.faces {
                let slot = &mut face_elements[r.face as usize];
                if slot[0] == NONE {
                    slot[0] = e as u32;
                } else {
                    slot[1] = e as u32;
                }
            }
        }
        let mut counts = vec![0u32; mesh.nodes.len() + 1];
        for el in &mesh.elements {
            for &n in &el.nodes {
                counts[n as usize + 1] += 1;
            }
        }
        for i in 0..mesh.nodes.len() {
            counts[i + 1] += counts[i];
        }
        let mut fill = counts.clone();
        let mut ids = vec![0u32; counts[mesh.nodes.len()] as usize];
        for (e, el) in mesh.elements.iter().enumerate() {
            for &n in &el.nodes {
                ids[fill[n as usize] as usize] = e as u32;
                fill[n as usize] += 1;
            }
        }
        Adjacency { face_elements, node_element_offsets: counts, node_element_ids: ids, edge_faces: HashMap::new() }
    }

    /// Elements touching node `n`.
    pub fn node_elements(&self, n: usize) -> &[u32] {
        &self.node_element_ids[self.node_element_offsets[n] as usize..self.node_element_offsets[n + 1] as usize]
    }

    /// Whether face `f` lies on the boundary (bounds exactly one element).
    pub fn is_boundary_face(&self, f: usize) -> bool {
        self.face_elements[f][1] == NONE && self.face_elements[f][0] != NONE
    }

    /// Component label of every element (elements sharing a node are
    /// connected), labels numbered from 0 in order of first appearance, and
    /// the number of components.
    pub fn element_components(&self, mesh: &PolyMesh) -> (Vec<u32>, usize) {
        let edges = (0..mesh.nodes.len()).flat_map(|node| {
            let els = self.node_elements(node);
            els.iter().skip(1).map(move |&e| (els[0], e))
        });
        let root = crate::solve::component_roots(mesh.elements.len(), edges);
        // every root is its component's first element: labels by first
        // appearance are the roots in ascending order
        let mut label = vec![NONE; root.len()];
        let mut count = 0;
        for e in 0..root.len() {
            let r = root[e] as usize;
            if r == e {
                count += 1;
            }
            label[e] = if r == e { count - 1 } else { label[r] };
        }
        (label, count as usize)
    }
}
