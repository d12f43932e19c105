//! Undoing a failed cut without copying the mesh.
//!
//! A cut only appends nodes, faces and elements, and rewrites elements (and
//! their faces) that share a node with an element reaching into the band
//! `|distance| <= band` around the cut's plane (`band` being the largest
//! snapping distance of the split, [`super::split::snap_band`]): splits change the crossed
//! elements and the faces around crossed edges, separation renames nodes on
//! (or, around elements kept whole, next to) the plane, and polygon cuts
//! split faces in the plane. [`Rollback::around_plane`] saves exactly those
//! elements and faces, so a cut that fails half-way can be undone in time
//! proportional to the region it touched.

use cleave_kernels::vec3::{dot, norm, sub};

use super::split::{snap_band, Plane, SplitOptions};
use crate::mesh::{Element, Face, PolyMesh};

/// What a cut may change, saved before it runs.
#[derive(Clone, Debug)]
pub struct Rollback {
    nodes: usize,
    faces: usize,
    elements: usize,
    saved_elements: Vec<(u32, Element)>,
    saved_faces: Vec<(u32, Face)>,
}

impl Rollback {
    /// Saves what a cut along `plane` with `opts` may change: the elements
    /// sharing a node with an element that reaches within the snapping band
    /// of the plane, and their faces.
    pub fn around_plane(mesh: &PolyMesh, plane: &Plane, opts: &SplitOptions) -> Self {
        let band = snap_band(mesh, opts);
        let len = norm(plane.normal);
        let dist = |v: u32| dot(sub(mesh.nodes[v as usize], plane.point), plane.normal) / len;
        let mut near = vec![false; mesh.nodes.len()];
        for el in &mesh.elements {
            let (lo, hi) = el
                .nodes
                .iter()
                .map(|&v| dist(v))
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), d| (lo.min(d), hi.max(d)));
            // a NaN plane reaches everything
            if !(lo > band || hi < -band) {
                el.nodes.iter().for_each(|&v| near[v as usize] = true);
            }
        }
        let mut saved_elements = Vec::new();
        let mut face_saved = vec![false; mesh.faces.len()];
        for (e, el) in mesh.elements.iter().enumerate() {
            if el.nodes.iter().any(|&v| near[v as usize]) {
                saved_elements.push((e as u32, el.clone()));
                el.faces.iter().for_each(|r| face_saved[r.face as usize] = true);
            }
        }
        let saved_faces =
            (0..mesh.faces.len()).filter(|&f| face_saved[f]).map(|f| (f as u32, mesh.faces[f].clone())).collect();
        Rollback {
            nodes: mesh.nodes.len(),
            faces: mesh.faces.len(),
            elements: mesh.elements.len(),
            saved_elements,
            saved_faces,
        }
    }

    /// Whether element `e` (of the mesh before the cut) was saved.
    pub fn saved_element(&self, e: usize) -> bool {
        self.saved_elements.binary_search_by_key(&(e as u32), |(id, _)| *id).is_ok()
    }

    /// Whether face `f` (of the mesh before the cut) was saved.
    pub fn saved_face(&self, f: usize) -> bool {
        self.saved_faces.binary_search_by_key(&(f as u32), |(id, _)| *id).is_ok()
    }

    /// Puts `mesh` back as it was when this was saved.
    pub fn restore(self, mesh: &mut PolyMesh) {
        mesh.nodes.truncate(self.nodes);
        mesh.faces.truncate(self.faces);
        mesh.elements.truncate(self.elements);
        for (f, face) in self.saved_faces {
            mesh.faces[f as usize] = face;
        }
        for (e, el) in self.saved_elements {
            mesh.elements[e as usize] = el;
        }
    }
}
