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

use super::cut::cut_classified;
use super::polygon::{cut_as_planned, plan_polygon_cut, polygon_plane, PolygonCutReport, PolygonPlan};
use super::split::{classify, on_plane_band, Classification, SplitError, SplitOptions};
use super::CutScope;
use crate::mesh::Plane;
use crate::mesh::{Element, Face, FaceRef, Lists, PolyMesh};
use rayon::prelude::*;

/// What a cut cuts along: a whole plane, or a convex planar polygon (rest
/// frame, m).
#[derive(Clone, Copy, Debug)]
pub enum CutShape<'a> {
    /// [`super::cut_by_plane_keeping`]'s cut.
    Plane(&'a Plane),
    /// [`super::cut_by_polygon_keeping`]'s cut.
    Polygon(&'a [[f64; 3]]),
}

/// What a cut may change, saved before it runs (flat, so saving costs no
/// allocation per element or face).
#[derive(Clone, Debug)]
pub struct Rollback {
    nodes: usize,
    faces: usize,
    elements: usize,
    /// Saved elements (sorted ids), their face references and nodes.
    elements_saved: Vec<u32>,
    element_faces: Lists<FaceRef>,
    element_nodes: Lists<u32>,
    /// Saved faces (sorted ids), their loops and triangles.
    faces_saved: Vec<u32>,
    face_vertices: Lists<u32>,
    face_triangles: Lists<[u32; 3]>,
    /// Saved node positions (for changes that move nodes).
    positions: Vec<(u32, [f64; 3])>,
}

impl Rollback {
    /// Cuts `mesh` along `shape` as [`super::cut_by_plane_keeping`] or
    /// [`super::cut_by_polygon_keeping`] do (same arguments, same result),
    /// and returns the rollback that undoes the cut, whether it succeeded
    /// or failed half-way. The rollback ([`Rollback::around_plane`]) is
    /// saved on one thread while the cut's read-only part, the
    /// classification of the elements around the plane, runs on the
    /// others: both only read the mesh, and both wait on memory more than
    /// they compute.
    pub fn cut(
        mesh: &mut PolyMesh,
        shape: CutShape,
        opts: &SplitOptions,
        keep_whole: &[u32],
        scope: CutScope,
    ) -> (Rollback, Result<PolygonCutReport, SplitError>) {
        let plane = match shape {
            CutShape::Plane(plane) => *plane,
            CutShape::Polygon(polygon) => match polygon_plane(polygon) {
                Ok(plane) => plane,
                // (the mesh is untouched: a rollback that saves nothing)
                Err(error) => return (Self::save(mesh, &[], &[], Vec::new()), Err(error)),
            },
        };
        /// The read-only part's outcome.
        enum Plan {
            Plane(Classification),
            Polygon(PolygonPlan),
        }
        let read_only = &*mesh;
        let (rollback, plan) = rayon::join(
            || Self::around_plane(read_only, &plane, scope),
            || match shape {
                CutShape::Plane(_) => classify(read_only, &plane, None, keep_whole, opts, scope).map(Plan::Plane),
                CutShape::Polygon(polygon) => {
                    plan_polygon_cut(read_only, polygon, opts, keep_whole, scope).map(Plan::Polygon)
                }
            },
        );
        let cut = plan.and_then(|plan| match plan {
            Plan::Plane(classification) => {
                let cut = cut_classified(mesh, &plane, classification, scope)?;
                Ok(PolygonCutReport { cut, pocket: None })
            }
            Plan::Polygon(plan) => cut_as_planned(mesh, plan, opts, keep_whole, scope),
        });
        (rollback, cut)
    }

    /// Saves what a cut along `plane` may change: the elements sharing a
    /// node with an element that reaches the plane, and their faces; only
    /// the elements in `scope` are looked at (they hold all of those).
    pub fn around_plane(mesh: &PolyMesh, plane: &Plane, scope: CutScope) -> Self {
        let band = on_plane_band(mesh);
        let distance = plane.distance_to();
        let candidates: Vec<usize> = scope.elements(mesh).collect();
        // (each element's test reads only its own nodes: in parallel)
        let reaching: Vec<usize> = candidates
            .par_iter()
            .copied()
            .filter(|&e| {
                let (lo, hi) =
                    mesh.elements[e].nodes.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                        let d = distance(&mesh.nodes[v as usize]);
                        (lo.min(d), hi.max(d))
                    });
                // a NaN plane reaches everything
                !(lo > band || hi < -band)
            })
            .collect();
        let mut near = vec![false; mesh.nodes.len()];
        for e in reaching {
            mesh.elements[e].nodes.iter().for_each(|&v| near[v as usize] = true);
        }
        Self::save(mesh, &candidates, &near, Vec::new())
    }

    /// Saves what a change that moves `nodes` and rewires the elements
    /// around them may change: their positions, the elements holding one of
    /// them, and those elements' faces.
    pub fn around_nodes(mesh: &PolyMesh, nodes: &[u32]) -> Self {
        let mut near = vec![false; mesh.nodes.len()];
        nodes.iter().for_each(|&v| near[v as usize] = true);
        let positions = nodes.iter().map(|&v| (v, mesh.nodes[v as usize])).collect();
        let candidates: Vec<usize> = (0..mesh.elements.len()).collect();
        Self::save(mesh, &candidates, &near, positions)
    }

    /// The ids of the saved elements, in increasing order.
    pub fn elements(&self) -> &[u32] {
        &self.elements_saved
    }

    /// Saves the elements among `candidates` (in increasing order) holding
    /// a `near` node, their faces, and `positions`.
    fn save(mesh: &PolyMesh, candidates: &[usize], near: &[bool], positions: Vec<(u32, [f64; 3])>) -> Self {
        // (found in parallel, saved in order, each array allocated once)
        let elements_saved: Vec<u32> = candidates
            .par_iter()
            .filter(|&&e| mesh.elements[e].nodes.iter().any(|&v| near[v as usize]))
            .map(|&e| e as u32)
            .collect();
        let elements = elements_saved.iter().map(|&e| &mesh.elements[e as usize]);
        let element_faces = Lists::of(elements.clone().map(|el| &el.faces[..]));
        let element_nodes = Lists::of(elements.map(|el| &el.nodes[..]));
        let mut faces_saved: Vec<u32> = element_faces.values().iter().map(|r| r.face).collect();
        faces_saved.par_sort_unstable();
        faces_saved.dedup();
        let faces = faces_saved.iter().map(|&f| &mesh.faces[f as usize]);
        let face_vertices = Lists::of(faces.clone().map(|face| &face.vertices[..]));
        let face_triangles = Lists::of(faces.map(|face| &face.triangles[..]));
        Rollback {
            nodes: mesh.nodes.len(),
            faces: mesh.faces.len(),
            elements: mesh.elements.len(),
            elements_saved,
            element_faces,
            element_nodes,
            faces_saved,
            face_vertices,
            face_triangles,
            positions,
        }
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
                Face { vertices: self.face_vertices.get(i).into(), triangles: self.face_triangles.get(i).into() };
        }
        for (i, &e) in self.elements_saved.iter().enumerate() {
            mesh.elements[e as usize] =
                Element { faces: self.element_faces.get(i).into(), nodes: self.element_nodes.get(i).into() };
        }
    }
}
