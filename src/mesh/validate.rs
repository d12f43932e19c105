//! Mesh validation: every structural and geometric defect, by place.
//!
//! [`PolyMesh::validate`] stops at the first problem; [`PolyMesh::check`]
//! lists them all (for `cleave info`). Every error names the problem and the
//! place (node, face or element id, zero-based).

use rayon::prelude::*;
use rustc_hash::FxHashMap as HashMap;
use smallvec::SmallVec;

use cleave_kernels::vec3::{dot, sub};
use thiserror::Error;

use super::{face_geometry, PolyMesh};

/// A structural or geometric defect of a mesh.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum MeshError {
    /// The mesh has no element.
    #[error("the mesh has no elements")]
    Empty,
    /// A box generator was given an empty box or zero cells.
    #[error("a generated box needs min < max on every axis and at least one cell per axis (min {min:?}, max {max:?}, cells {cells:?})")]
    InvalidBox {
        /// Box corner (m).
        min: [f64; 3],
        /// Box corner (m).
        max: [f64; 3],
        /// Cells per axis.
        cells: [usize; 3],
    },
    /// A node coordinate is NaN or infinite.
    #[error("node {node} has a non-finite coordinate {position:?}")]
    NonFiniteNode {
        /// The node's id.
        node: usize,
        /// The position (m).
        position: [f64; 3],
    },
    /// A cell refers to a node that does not exist.
    #[error("element {element} refers to node {index}, but the mesh has {nodes} nodes")]
    NodeIndexOutOfRange {
        /// The element's id.
        element: usize,
        /// The offending index.
        index: usize,
        /// How many nodes there are.
        nodes: usize,
    },
    /// An element refers to a face that does not exist.
    #[error("element {element} refers to face {index}, but the mesh has {faces} faces")]
    FaceIndexOutOfRange {
        /// The element's id.
        element: usize,
        /// The offending index.
        index: usize,
        /// How many faces there are.
        faces: usize,
    },
    /// A face loop repeats a vertex or has fewer than three.
    #[error("element {element} has a face with fewer than 3 distinct vertices or a repeated vertex: {vertices:?}")]
    DegenerateFace {
        /// The element's id.
        element: usize,
        /// The face's vertices.
        vertices: Vec<u32>,
    },
    /// A face has (almost) no area.
    #[error("face {face} has zero area")]
    ZeroAreaFace {
        /// The face's id.
        face: usize,
    },
    /// A face's vertices are not in one plane.
    #[error("face {face} is not planar: a vertex is {deviation:.3e} m off its plane, more than {tolerance:.1e} of the face size")]
    NonPlanarFace {
        /// The face's id.
        face: usize,
        /// Largest distance of a vertex from the best plane, relative to the face's diameter.
        deviation: f64,
        /// The allowed value.
        tolerance: f64,
    },
    /// An element's boundary is not closed.
    #[error("element {element} is not closed: edge ({}, {}) is used by {count} of its faces instead of 2", .edge.0, .edge.1)]
    OpenElement {
        /// The element's id.
        element: usize,
        /// The edge, as its two node ids.
        edge: (u32, u32),
        /// How many faces of the element use the edge.
        count: usize,
    },
    /// Two faces of an element traverse a shared edge in the same direction.
    #[error("element {element} has inconsistently oriented faces along edge ({}, {}) (fix with PolyMesh::orient)", .edge.0, .edge.1)]
    InconsistentOrientation {
        /// The element's id.
        element: usize,
        /// The edge, as its two node ids.
        edge: (u32, u32),
    },
    /// An element's faces are consistently oriented but point inward.
    #[error("element {element} has inward-pointing faces (fix with PolyMesh::orient)")]
    InwardElement {
        /// The element's id.
        element: usize,
    },
    /// An element encloses no volume or is inside out.
    #[error("element {element} has non-positive volume {volume:.3e} m^3")]
    NonPositiveVolume {
        /// The element's id.
        element: usize,
        /// The volume (m^3).
        volume: f64,
    },
    /// Two nodes are at (almost) the same place.
    #[error("nodes {a} and {b} are duplicates ({distance:.3e} m apart; fix with PolyMesh::weld)")]
    DuplicateNodes {
        /// One node.
        a: usize,
        /// The other node.
        b: usize,
        /// Their distance (m).
        distance: f64,
    },
    /// A face bounds more than two elements.
    #[error("face {face} is shared by more than two elements (element {element} is the third)")]
    FaceSharedByMoreThanTwo {
        /// The face's id.
        face: usize,
        /// The element's id.
        element: usize,
    },
    /// The two elements on an interior face both claim it points out of them.
    #[error("face {face} is oriented outward for both elements {a} and {b}: they overlap")]
    OverlappingElements {
        /// The face's id.
        face: usize,
        /// One element.
        a: usize,
        /// The other element.
        b: usize,
    },
}

/// Tolerances of [`PolyMesh::validate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValidationOptions {
    /// A face is planar when every vertex is within `planarity` times the
    /// face's diameter of its best plane. Default `1e-3`: cutting snaps nodes
    /// that lie within `1e-4` of an edge length to a cut plane, and such caps
    /// stay well inside this bound.
    pub planarity: f64,
    /// Two nodes closer than `duplicate` times the bounding box diagonal are
    /// duplicates. Default `1e-9`; `0` skips the check (cut meshes carry
    /// coincident nodes on the two sides of every cut).
    pub duplicate: f64,
}

impl Default for ValidationOptions {
    fn default() -> Self {
        ValidationOptions { planarity: 1e-3, duplicate: 1e-9 }
    }
}

impl PolyMesh {
    /// Returns the first defect found, checking nodes, faces, then elements.
    pub fn validate(&self) -> Result<(), MeshError> {
        match self.check(&ValidationOptions::default(), 1).into_iter().next() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Lists up to `limit` defects with the given tolerances.
    pub fn check(&self, opts: &ValidationOptions, limit: usize) -> Vec<MeshError> {
        let mut out = Vec::new();
        macro_rules! push {
            ($e:expr) => {{
                out.push($e);
                if out.len() >= limit {
                    return out;
                }
            }};
        }
        if self.elements.is_empty() {
            push!(MeshError::Empty);
        }
        for (i, p) in self.nodes.iter().enumerate() {
            if !p.iter().all(|x| x.is_finite()) {
                push!(MeshError::NonFiniteNode { node: i, position: *p });
            }
        }
        if !out.is_empty() {
            return out; // geometry below would be meaningless
        }
        let mut users = vec![0usize; self.faces.len()];
        for (e, el) in self.elements.iter().enumerate() {
            for r in &el.faces {
                if r.face as usize >= self.faces.len() {
                    push!(MeshError::FaceIndexOutOfRange {
                        element: e,
                        index: r.face as usize,
                        faces: self.faces.len()
                    });
                    continue;
                }
                users[r.face as usize] += 1;
                if users[r.face as usize] == 3 {
                    push!(MeshError::FaceSharedByMoreThanTwo { face: r.face as usize, element: e });
                }
            }
        }
        for (f, face) in self.faces.iter().enumerate() {
            if let Some(&bad) = face.vertices.iter().find(|&&v| v as usize >= self.nodes.len()) {
                let element =
                    self.elements.iter().position(|el| el.faces.iter().any(|r| r.face as usize == f)).unwrap_or(0);
                push!(MeshError::NodeIndexOutOfRange { element, index: bad as usize, nodes: self.nodes.len() });
                continue;
            }
            if let Some(problem) = self.face_shape_problem(f, opts) {
                push!(problem);
            }
        }
        for e in 0..self.elements.len() {
            if let Some(problem) = self.element_shape_problem(e) {
                push!(problem);
            }
        }
        let mut owner: Vec<Option<(usize, bool)>> = vec![None; self.faces.len()];
        for (e, el) in self.elements.iter().enumerate() {
            for r in &el.faces {
                let Some(slot) = owner.get_mut(r.face as usize) else {
                    continue;
                };
                match *slot {
                    None => *slot = Some((e, r.outward)),
                    Some((a, out)) if out == r.outward => {
                        push!(MeshError::OverlappingElements { face: r.face as usize, a, b: e })
                    }
                    _ => {}
                }
            }
        }
        for (a, b, distance) in self.duplicate_nodes(opts.duplicate) {
            push!(MeshError::DuplicateNodes { a, b, distance });
        }
        out
    }

    /// Checks only `elements` (after a local topology change): their faces'
    /// indices, areas and planarity, closedness, orientation and volume.
    /// The elements are checked in parallel; the error is the first in
    /// their order.
    pub fn check_elements(&self, elements: &[usize], opts: &ValidationOptions) -> Result<(), MeshError> {
        elements.par_iter().find_map_first(|&e| self.element_problem(e, opts)).map_or(Ok(()), Err)
    }

    /// The first problem [`PolyMesh::check_elements`] finds with element `e`.
    fn element_problem(&self, e: usize, opts: &ValidationOptions) -> Option<MeshError> {
        for r in &self.elements[e].faces {
            let f = r.face as usize;
            if f >= self.faces.len() {
                return Some(MeshError::FaceIndexOutOfRange { element: e, index: f, faces: self.faces.len() });
            }
            if let Some(&bad) = self.faces[f].vertices.iter().find(|&&v| v as usize >= self.nodes.len()) {
                return Some(MeshError::NodeIndexOutOfRange {
                    element: e,
                    index: bad as usize,
                    nodes: self.nodes.len(),
                });
            }
            if let Some(problem) = self.face_shape_problem(f, opts) {
                return Some(problem);
            }
        }
        self.element_shape_problem(e)
    }

    /// A face with (almost) no area or off its plane.
    fn face_shape_problem(&self, f: usize, opts: &ValidationOptions) -> Option<MeshError> {
        let g = face_geometry(&self.nodes, &self.faces[f].vertices);
        if g.area <= 1e-14 * g.diameter * g.diameter || g.area == 0.0 {
            Some(MeshError::ZeroAreaFace { face: f })
        } else if g.max_deviation > opts.planarity * g.diameter {
            Some(MeshError::NonPlanarFace { face: f, deviation: g.max_deviation, tolerance: opts.planarity })
        } else {
            None
        }
    }

    /// An element that is open, inconsistently oriented, inward or flat.
    fn element_shape_problem(&self, e: usize) -> Option<MeshError> {
        if let Err(err) = self.check_element_closed(e) {
            return Some(err);
        }
        let v = self.element_volume(e);
        if v < 0.0 {
            Some(MeshError::InwardElement { element: e })
        } else if !(v > 0.0) {
            Some(MeshError::NonPositiveVolume { element: e, volume: v })
        } else {
            None
        }
    }

    /// Checks that every edge of element `e` is used by exactly two of its
    /// faces in opposite directions.
    fn check_element_closed(&self, e: usize) -> Result<(), MeshError> {
        // every directed use of an edge as (lower node, higher node, +1 along
        // it or -1 against), sorted: the uses of one edge lie together (a
        // sort, not a hash map, on the stack: a cut checks thousands of
        // elements)
        let mut uses: SmallVec<[((u32, u32), i32); 64]> = SmallVec::new();
        for r in &self.elements[e].faces {
            let v = &self.faces[r.face as usize].vertices;
            for i in 0..v.len() {
                let (mut a, mut b) = (v[i], v[(i + 1) % v.len()]);
                if !r.outward {
                    std::mem::swap(&mut a, &mut b);
                }
                uses.push(((a.min(b), a.max(b)), if a < b { 1 } else { -1 }));
            }
        }
        uses.sort_unstable();
        for edge_uses in uses.chunk_by(|x, y| x.0 == y.0) {
            let (edge, count) = (edge_uses[0].0, edge_uses.len());
            if count != 2 {
                return Err(MeshError::OpenElement { element: e, edge, count });
            }
            if edge_uses.iter().map(|u| u.1).sum::<i32>() != 0 {
                return Err(MeshError::InconsistentOrientation { element: e, edge });
            }
        }
        Ok(())
    }

    /// Pairs of nodes closer than `rel_tol` times the bounding box diagonal,
    /// as `(lower id, higher id, distance)`, found with a hash grid.
    pub fn duplicate_nodes(&self, rel_tol: f64) -> Vec<(usize, usize, f64)> {
        let (lo, hi) = self.bounding_box();
        let diag = cleave_kernels::vec3::norm(sub(hi, lo));
        let tol = rel_tol * diag;
        if !(tol > 0.0) {
            return Vec::new();
        }
        let cell = |p: [f64; 3]| -> [i64; 3] { [0, 1, 2].map(|i| ((p[i] - lo[i]) / tol).floor() as i64) };
        let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::default();
        for (i, p) in self.nodes.iter().enumerate() {
            grid.entry(cell(*p)).or_default().push(i);
        }
        let mut out = Vec::new();
        for (i, p) in self.nodes.iter().enumerate() {
            let c = cell(*p);
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        if let Some(list) = grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                            for &j in list {
                                if j > i {
                                    let d = sub(self.nodes[j], *p);
                                    let dist = dot(d, d).sqrt();
                                    if dist <= tol {
                                        out.push((i, j, dist));
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        out.sort_by_key(|&(a, b, _)| (a, b));
        out
    }
}
