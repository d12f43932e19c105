//! Undoing a failed cut without copying the mesh.
//!
//! A cut only appends nodes, faces and elements, and rewrites elements (and
//! their faces) that share a node with an element reaching the cut's plane
//! (straddling it, or with a node within `split::on_plane_band` of it):
//! splits change the crossed elements and the faces around crossed edges
//! (every node they snap belongs to a straddling element), separation
//! renames nodes on (or, around elements kept whole, next to) the plane, and
//! polygon cuts split faces in the plane. [`Rollback::around_plane`] saves exactly those
//! elements and faces, so a cut that fails half-way can be undone in time
//! proportional to the region it touched.

use super::split::on_plane_band;
use super::CutScope;
use crate::mesh::Plane;
use crate::mesh::{Element, Face, FaceRef, PolyMesh};

/// What a cut may change, saved before it runs (flat, so saving costs no
/// allocation per element or face).
#[derive(Clone, Debug)]
pub struct Rollback {
    nodes: usize,
    faces: usize,
    elements: usize,
    /// Saved elements (sorted ids), their face references and nodes.
    elements_saved: Vec<u32>,
    element_faces: Flat<FaceRef>,
    element_nodes: Flat<u32>,
    /// Saved faces (sorted ids), their loops and triangles.
    faces_saved: Vec<u32>,
    face_vertices: Flat<u32>,
    face_triangles: Flat<[u32; 3]>,
    /// Saved node positions (for changes that move nodes).
    positions: Vec<(u32, [f64; 3])>,
}

/// Lists of values, one after another.
#[derive(Clone, Debug)]
struct Flat<T> {
    values: Vec<T>,
    ends: Vec<usize>,
}

impl<T: Copy> Flat<T> {
    fn new() -> Self {
        Flat { values: Vec::new(), ends: Vec::new() }
    }

    fn push(&mut self, list: &[T]) {
        self.values.extend_from_slice(list);
        self.ends.push(self.values.len());
    }

    fn get(&self, i: usize) -> Vec<T> {
        let start = if i == 0 { 0 } else { self.ends[i - 1] };
        self.values[start..self.ends[i]].to_vec()
    }
}

impl Rollback {
    /// Saves what a cut along `plane` may change: the elements sharing a
    /// node with an element that reaches the plane, and their faces; only
    /// the elements in `scope` are looked at (they hold all of those).
    pub fn around_plane(mesh: &PolyMesh, plane: &Plane, scope: CutScope) -> Self {
        let band = on_plane_band(mesh);
        let dist = plane.distances(&mesh.nodes);
        let mut near = vec![false; mesh.nodes.len()];
        for e in scope.elements(mesh) {
            let el = &mesh.elements[e];
            let (lo, hi) = el.nodes.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(dist[v as usize]), hi.max(dist[v as usize]))
            });
            // a NaN plane reaches everything
            if !(lo > band || hi < -band) {
                el.nodes.iter().for_each(|&v| near[v as usize] = true);
            }
        }
        Self::save(mesh, scope.elements(mesh), &near, Vec::new())
    }

    /// Saves what a change that moves `nodes` and rewires the elements
    /// around them may change: their positions, the elements holding one of
    /// them, and those elements' faces.
    pub fn around_nodes(mesh: &PolyMesh, nodes: &[u32]) -> Self {
        let mut near = vec![false; mesh.nodes.len()];
        nodes.iter().for_each(|&v| near[v as usize] = true);
        let positions = nodes.iter().map(|&v| (v, mesh.nodes[v as usize])).collect();
        Self::save(mesh, 0..mesh.elements.len(), &near, positions)
    }

    /// The ids of the saved elements, in increasing order.
    pub fn elements(&self) -> &[u32] {
        &self.elements_saved
    }

    /// Saves the elements among `candidates` (in increasing order) holding
    /// a `near` node, their faces, and `positions`.
    fn save(
        mesh: &PolyMesh,
        candidates: impl Iterator<Item = usize>,
        near: &[bool],
        positions: Vec<(u32, [f64; 3])>,
    ) -> Self {
        let mut saved = Rollback {
            nodes: mesh.nodes.len(),
            faces: mesh.faces.len(),
            elements: mesh.elements.len(),
            elements_saved: Vec::new(),
            element_faces: Flat::new(),
            element_nodes: Flat::new(),
            faces_saved: Vec::new(),
            face_vertices: Flat::new(),
            face_triangles: Flat::new(),
            positions,
        };
        for e in candidates {
            let el = &mesh.elements[e];
            if el.nodes.iter().any(|&v| near[v as usize]) {
                saved.elements_saved.push(e as u32);
                saved.element_faces.push(&el.faces);
                saved.element_nodes.push(&el.nodes);
                saved.faces_saved.extend(el.faces.iter().map(|r| r.face));
            }
        }
        saved.faces_saved.sort_unstable();
        saved.faces_saved.dedup();
        for &f in &saved.faces_saved {
            let face = &mesh.faces[f as usize];
            saved.face_vertices.push(&face.vertices);
            saved.face_triangles.push(&face.triangles);
        }
        saved
    }

    /// Whether element `e` (of the mesh before the cut) was saved.
    pub fn saved_element(&self, e: usize) -> bool {
        self.elements_saved.binary_search(&(e as u32)).is_ok()
    }

    /// Whether face `f` (of the mesh before the cut) was saved.
    pub fn saved_face(&self, f: usize) -> bool {
        self.faces_saved.binary_search(&(f as u32)).is_ok()
    }

    /// Puts `mesh` back as it was when this was saved.
    pub fn restore(self, mesh: &mut PolyMesh) {
        mesh.nodes.truncate(self.nodes);
        for (v, x) in self.positions {
            mesh.nodes[v as usize] = x;
        }
        mesh.faces.truncate(self.faces);
        mesh.elements.truncate(self.elements);
        for (i, &f) in self.faces_saved.iter().enumerate() {
            mesh.faces[f as usize] =
                Face { vertices: self.face_vertices.get(i), triangles: self.face_triangles.get(i) };
        }
        for (i, &e) in self.elements_saved.iter().enumerate() {
            mesh.elements[e as usize] = Element { faces: self.element_faces.get(i), nodes: self.element_nodes.get(i) };
        }
    }
}
