//! The polyhedral mesh: nodes, global faces shared by elements, elements as
//! closed polyhedra.
//!
//! Every face is a planar vertex loop stored once and referenced by the one
//! (boundary) or two (interior) elements it bounds. A reference carries the
//! orientation: `outward == true` means the loop is counter-clockwise seen
//! from outside that element (its right-hand normal points out of it). Each
//! face carries one triangulation of its loop that every element touching it
//! uses, which keeps mean value shape functions C0 across the face.
//!
//! Units: node positions are in metres.

mod adjacency;
mod geometry;
mod lists;
mod order;
mod repair;
mod triangulate;
mod validate;

pub use adjacency::Adjacency;
pub use geometry::{
    face_geometry, fold_depth, fold_depth_on, loop_geometry, loop_planes, FaceGeometry, LoopPlane, Loops, Plane,
};
pub use lists::Lists;
pub use order::Renumbered;
pub use triangulate::triangulate_loop;
pub use validate::{MeshError, ValidationOptions};

use rayon::prelude::*;
use smallvec::SmallVec;

use cleave_kernels::vec3::{add, scale, sub};

/// Sets `nodes` to the sorted, distinct nodes of the faces `refs`, in its
/// own storage (a cut refreshes thousands of node lists).
fn collect_nodes(faces: &[Face], refs: &[FaceRef], nodes: &mut ElementNodes) {
    collect_loop_nodes(refs.iter().map(|r| &faces[r.face as usize].vertices[..]), nodes);
}

/// The sorted, distinct nodes of the vertex `loops` (the node list of an
/// element with those faces).
pub(crate) fn loop_nodes<'a>(loops: impl Iterator<Item = &'a [u32]>) -> ElementNodes {
    let mut nodes = ElementNodes::new();
    collect_loop_nodes(loops, &mut nodes);
    nodes
}

/// [`loop_nodes`] into `nodes`, gathered on the stack first: every node
/// appears in several loops (a hexahedron's 8 in 24 places), and only the
/// distinct ones may take `nodes`' inline room.
fn collect_loop_nodes<'a>(loops: impl Iterator<Item = &'a [u32]>, nodes: &mut ElementNodes) {
    let mut all: SmallVec<[u32; 64]> = SmallVec::new();
    for lp in loops {
        all.extend_from_slice(lp);
    }
    all.sort_unstable();
    all.dedup();
    nodes.clear();
    nodes.extend_from_slice(&all);
}

/// A face's vertex loop, inline up to six vertices: every face of a
/// tetrahedral or hexahedral mesh and most faces a cut makes need no heap
/// storage of their own (a mesh of a million elements holds two million
/// faces, and a cut copies and rewrites thousands).
pub type FaceLoop = SmallVec<[u32; 6]>;

/// A face's triangles, inline up to four (a loop of six vertices).
pub type FaceTriangles = SmallVec<[[u32; 3]; 4]>;

/// An element's face references, inline up to eight (a tetrahedron's four,
/// a hexahedron's six, most cut pieces').
pub type ElementFaces = SmallVec<[FaceRef; 8]>;

/// An element's nodes, inline up to twelve (a tetrahedron's four, a
/// hexahedron's eight, most cut pieces').
pub type ElementNodes = SmallVec<[u32; 12]>;

/// A global face: a vertex loop and its triangulation.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Face {
    /// Node ids around the face, counter-clockwise about the face normal.
    pub vertices: FaceLoop,
    /// Triangles of the loop in node ids, each oriented like the loop.
    pub triangles: FaceTriangles,
}

impl Face {
    /// Inserts node `c`, which lies on the loop edge between `a` and `b`,
    /// into the loop, and splits the one triangle on that edge in two, so
    /// the surface the face describes is unchanged (re-triangulating a
    /// slightly non-planar face would move it). Returns whether the edge was
    /// found.
    pub fn insert_on_edge(&mut self, a: u32, b: u32, c: u32) -> bool {
        let m = self.vertices.len();
        let Some(p) = (0..m).find(|&p| {
            let (x, y) = (self.vertices[p], self.vertices[(p + 1) % m]);
            (x == a && y == b) || (x == b && y == a)
        }) else {
            return false;
        };
        self.vertices.insert(p + 1, c);
        for t in 0..self.triangles.len() {
            let tri = self.triangles[t];
            for i in 0..3 {
                let (x, y, z) = (tri[i], tri[(i + 1) % 3], tri[(i + 2) % 3]);
                if (x == a && y == b) || (x == b && y == a) {
                    self.triangles[t] = [x, c, z];
                    self.triangles.push([c, y, z]);
                    return true;
                }
            }
        }
        true
    }
}

/// One element's reference to a global face.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FaceRef {
    /// Index into [`PolyMesh::faces`].
    pub face: u32,
    /// Whether the face loop's normal points out of this element.
    pub outward: bool,
}

/// A polyhedral element: its faces and (derived) its sorted node ids.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Element {
    /// The faces bounding this element.
    pub faces: ElementFaces,
    /// The element's nodes in increasing id order (the element-local order).
    pub nodes: ElementNodes,
}

/// A volume cell as read from a file, before faces are shared.
#[derive(Clone, Debug, PartialEq)]
pub enum Cell {
    /// Linear tetrahedron, any orientation.
    Tet([u32; 4]),
    /// Hexahedron in VTK order: bottom loop 0-1-2-3, top loop 4-5-6-7.
    Hex([u32; 8]),
    /// General polyhedron as a list of face loops (any orientation).
    Polyhedron(Vec<Vec<u32>>),
}

impl Cell {
    /// The face loops of the cell in its own numbering.
    pub fn face_loops(&self) -> Vec<Vec<u32>> {
        self.loops().iter().map(|lp| lp.to_vec()).collect()
    }

    /// [`Cell::face_loops`] inline (a tetrahedron's or a hexahedron's
    /// need no heap storage: a mesh reads a million of them).
    fn loops(&self) -> SmallVec<[FaceLoop; 6]> {
        match self {
            Cell::Tet(t) => {
                [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]].iter().map(|f| f.iter().map(|&i| t[i]).collect()).collect()
            }
            Cell::Hex(h) => [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
                .iter()
                .map(|f| f.iter().map(|&i| h[i]).collect())
                .collect(),
            Cell::Polyhedron(faces) => faces.iter().map(|lp| FaceLoop::from_slice(lp)).collect(),
        }
    }
}

/// A conforming mesh of polyhedral elements.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PolyMesh {
    /// Node rest positions in metres.
    pub nodes: Vec<[f64; 3]>,
    /// Global faces.
    pub faces: Vec<Face>,
    /// Elements.
    pub elements: Vec<Element>,
}

/// The key under which a face loop is shared: its sorted vertex set.
pub(crate) fn face_key(vertices: &[u32]) -> FaceLoop {
    let mut k = FaceLoop::from_slice(vertices);
    k.sort_unstable();
    k
}

/// Largest distance between two of `points` (m).
pub(crate) fn diameter(points: &[[f64; 3]]) -> f64 {
    diameter_of(points.len(), |i| points[i])
}

/// [`diameter`] of the `n` points `point(0..n)`, without gathering them.
pub(crate) fn diameter_of(n: usize, point: impl Fn(usize) -> [f64; 3]) -> f64 {
    pair_squares(n, point).fold(0.0, f64::max).sqrt()
}

/// Smallest distance between two of the `n` points `point(0..n)` (m;
/// infinite for fewer than two): one square root, of the smallest square,
/// which is the smallest of the distances bit for bit.
pub(crate) fn closest_of(n: usize, point: impl Fn(usize) -> [f64; 3]) -> f64 {
    pair_squares(n, point).fold(f64::INFINITY, f64::min).sqrt()
}

/// The squared distance of every pair `i < j` of the `n` points
/// `point(0..n)`, in the order of `i`, then `j`.
fn pair_squares(n: usize, point: impl Fn(usize) -> [f64; 3]) -> impl Iterator<Item = f64> {
    (0..n).flat_map(move |i| (i + 1..n).map(move |j| (i, j))).map(move |(i, j)| {
        let d = sub(point(i), point(j));
        cleave_kernels::vec3::dot(d, d)
    })
}

/// Shape quality `ρ = 6√2 V / d³` of a cell of volume `V` and diameter
/// `d`: scale invariant, 1 for the regular tetrahedron (about 0.27 for the
/// tetrahedra of a Kuhn-split cube, 1.63 for a cube), and tending to 0 as
/// the cell flattens (a sliver) or collapses onto a line (a needle). A cell
/// of quality `ρ` has a width of at most about `ρ d` in some direction, so
/// its shape function gradients grow like `1 / ρ`.
pub fn quality(volume: f64, diameter: f64) -> f64 {
    6.0 * std::f64::consts::SQRT_2 * volume / diameter.powi(3)
}

impl PolyMesh {
    /// Builds a mesh from volume cells, sharing faces with equal vertex sets
    /// and orienting every face reference outward.
    ///
    /// Structural problems (indices out of range, faces with fewer than three
    /// distinct vertices, faces shared by more than two cells) are reported
    /// here; geometric ones by [`PolyMesh::validate`].
    pub fn from_cells(nodes: Vec<[f64; 3]>, cells: &[Cell]) -> Result<Self, MeshError> {
        let n = nodes.len();
        if let Some(node) = nodes.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
            return Err(MeshError::NonFiniteNode { node, position: nodes[node] });
        }
        let mut mesh = PolyMesh { nodes, faces: Vec::new(), elements: Vec::with_capacity(cells.len()) };
        let mut by_key: rustc_hash::FxHashMap<FaceLoop, u32> = Default::default();
        let mut users: Vec<u8> = Vec::new();
        for (e, cell) in cells.iter().enumerate() {
            let loops = cell.loops();
            let mut refs = ElementFaces::with_capacity(loops.len());
            for lp in loops {
                if let Some(&bad) = lp.iter().find(|&&v| v as usize >= n) {
                    return Err(MeshError::NodeIndexOutOfRange { element: e, index: bad as usize, nodes: n });
                }
                let key = face_key(&lp);
                let distinct = {
                    let mut d = key.clone();
                    d.dedup();
                    d.len()
                };
                if distinct < 3 || distinct != lp.len() {
                    return Err(MeshError::DegenerateFace { element: e, vertices: lp.to_vec() });
                }
                let next = mesh.faces.len() as u32;
                let f = *by_key.entry(key).or_insert(next);
                if f == next {
                    mesh.faces.push(Face { vertices: lp.clone(), triangles: FaceTriangles::new() });
                    users.push(0);
                }
                users[f as usize] += 1;
                if users[f as usize] > 2 {
                    return Err(MeshError::FaceSharedByMoreThanTwo { face: f as usize, element: e });
                }
                // Same cyclic direction as the stored loop?
                let same = same_direction(&mesh.faces[f as usize].vertices, &lp);
                refs.push(FaceRef { face: f, outward: same });
            }
            mesh.elements.push(Element { faces: refs, nodes: ElementNodes::new() });
        }
        let faces = &mesh.faces;
        mesh.elements.par_iter_mut().for_each(|el| collect_nodes(faces, &el.faces, &mut el.nodes));
        mesh.triangulate_all();
        mesh.orient()?;
        Ok(mesh)
    }

    /// Number of nodes.
    pub fn num_nodes(&self) -> usize {
        self.nodes.len()
    }

    /// Number of elements.
    pub fn num_elements(&self) -> usize {
        self.elements.len()
    }

    /// Recomputes the sorted node list of element `e` from its faces.
    pub(crate) fn refresh_element_nodes(&mut self, e: usize) {
        let element = &mut self.elements[e];
        collect_nodes(&self.faces, &element.faces, &mut element.nodes);
    }

    /// [`PolyMesh::refresh_element_nodes`] for each of `elements` (each
    /// once), in parallel.
    pub(crate) fn refresh_elements_nodes(&mut self, elements: &[u32]) {
        let (faces, all) = (&self.faces, &self.elements);
        let lists: Vec<ElementNodes> = elements
            .par_iter()
            .map(|&e| {
                let mut nodes = ElementNodes::new();
                collect_nodes(faces, &all[e as usize].faces, &mut nodes);
                nodes
            })
            .collect();
        for (&e, nodes) in elements.iter().zip(lists) {
            self.elements[e as usize].nodes = nodes;
        }
    }

    /// (Re)computes the triangulation of every face.
    pub(crate) fn triangulate_all(&mut self) {
        let nodes = &self.nodes;
        self.faces.par_iter_mut().for_each(|f| f.triangles = triangulate_loop(nodes, &f.vertices));
    }

    /// (Re)computes the triangulation of face `f` from its loop.
    pub(crate) fn triangulate_face(&mut self, f: usize) {
        let tris = triangulate_loop(&self.nodes, &self.faces[f].vertices);
        self.faces[f].triangles = tris;
    }

    /// The oriented (outward) triangles of element `e`.
    pub fn element_triangles(&self, e: usize) -> impl Iterator<Item = [u32; 3]> + '_ {
        self.elements[e].faces.iter().flat_map(move |r| {
            let out = r.outward;
            self.faces[r.face as usize].triangles.iter().map(move |t| if out { *t } else { [t[0], t[2], t[1]] })
        })
    }

    /// Signed volume of element `e` in m^3 (positive when its faces point
    /// outward), by the divergence theorem over its face triangles.
    pub fn element_volume(&self, e: usize) -> f64 {
        self.element_volume_at(e, &self.nodes)
    }

    /// Signed volume of element `e` (m^3) with its nodes at `positions`
    /// (indexed by node id), over its face triangles: not positive once
    /// the element is inverted.
    pub fn element_volume_at(&self, e: usize, positions: &[[f64; 3]]) -> f64 {
        let origin = positions[self.elements[e].nodes[0] as usize];
        self.element_triangles(e)
            .map(|t| {
                let p = |i: usize| positions[t[i] as usize];
                cleave_kernels::tet::signed_volume(origin, p(0), p(1), p(2))
            })
            .sum()
    }

    /// Volume centroid of element `e` (m), exact for its triangulated boundary.
    pub fn element_centroid(&self, e: usize) -> [f64; 3] {
        let origin = self.nodes[self.elements[e].nodes[0] as usize];
        let mut v = 0.0;
        let mut c = [0.0; 3];
        for t in self.element_triangles(e) {
            let (a, b, d) = (self.nodes[t[0] as usize], self.nodes[t[1] as usize], self.nodes[t[2] as usize]);
            let vt = cleave_kernels::tet::signed_volume(origin, a, b, d);
            v += vt;
            c = add(c, scale(add(add(origin, a), add(b, d)), vt / 4.0));
        }
        if v == 0.0 {
            return self.vertex_mean(e);
        }
        scale(c, 1.0 / v)
    }

    /// Mean of the element's vertex positions (m).
    pub fn vertex_mean(&self, e: usize) -> [f64; 3] {
        let nodes = &self.elements[e].nodes;
        let s = nodes.iter().fold([0.0; 3], |acc, &n| add(acc, self.nodes[n as usize]));
        scale(s, 1.0 / nodes.len() as f64)
    }

    /// Total volume of all elements (m^3).
    pub fn total_volume(&self) -> f64 {
        (0..self.elements.len()).map(|e| self.element_volume(e)).sum()
    }

    /// Whether element `e` is convex up to folds no deeper than `rel_tol`
    /// times its diameter (see [`PolyMesh::non_convexity`]).
    pub fn is_convex(&self, e: usize, rel_tol: f64) -> bool {
        self.non_convexity(e) <= rel_tol
    }

    /// How far element `e` is from convex: the depth of its deepest fold,
    /// over its diameter (0 or less for a convex element). At an edge where
    /// faces `f` and `g` meet, the fold's depth is the smaller of how far
    /// `g`'s vertices lie outside `f`'s plane and how far `f`'s lie outside
    /// `g`'s; both are positive only at a reflex edge. A closed surface
    /// without reflex edges bounds a convex body, so this measures local
    /// non-convexity: an L-prism's notch gives about a third of its
    /// diameter, the fold of a cap bent through a snapped node its
    /// distance from the cut plane.
    pub fn non_convexity(&self, e: usize) -> f64 {
        let faces = &self.elements[e].faces;
        let points = faces.iter().map(|r| self.faces[r.face as usize].vertices.len()).sum();
        let mut loops = Loops::with_capacity(faces.len(), points);
        for r in faces {
            let lp = &self.faces[r.face as usize].vertices;
            let point = |&v: &u32| (v, self.nodes[v as usize]);
            match r.outward {
                true => loops.push(lp.iter().map(point)),
                false => loops.push(lp.iter().rev().map(point)),
            }
        }
        fold_depth(&loops) / self.element_diameter(e)
    }

    /// Largest distance between two nodes of element `e` (m).
    pub fn element_diameter(&self, e: usize) -> f64 {
        let nodes = &self.elements[e].nodes;
        diameter_of(nodes.len(), |i| self.nodes[nodes[i] as usize])
    }

    /// The median of the element diameters (m); 0 without elements.
    pub fn median_element_diameter(&self) -> f64 {
        let mut d: Vec<f64> = (0..self.elements.len()).map(|e| self.element_diameter(e)).collect();
        if d.is_empty() {
            return 0.0;
        }
        let mid = d.len() / 2;
        *d.select_nth_unstable_by(mid, f64::total_cmp).1
    }

    /// Shape quality of element `e`: [`quality`] of its volume and
    /// diameter (1 for a regular tetrahedron, 0 for a flat element).
    pub fn element_quality(&self, e: usize) -> f64 {
        quality(self.element_volume(e), self.element_diameter(e))
    }

    /// Axis-aligned bounding box `(min, max)` of the nodes (m).
    pub fn bounding_box(&self) -> ([f64; 3], [f64; 3]) {
        cleave_kernels::vec3::bounding_box(&self.nodes)
    }

    /// A new mesh holding only `elements` (in that order), with unused nodes
    /// and faces dropped; returns it and the new id of every old node
    /// (`u32::MAX` for dropped ones).
    pub fn extract(&self, elements: &[usize]) -> Result<(PolyMesh, Vec<u32>), MeshError> {
        let mut new_id = vec![u32::MAX; self.nodes.len()];
        let mut nodes = Vec::new();
        for &e in elements {
            for &v in &self.elements[e].nodes {
                if new_id[v as usize] == u32::MAX {
                    new_id[v as usize] = nodes.len() as u32;
                    nodes.push(self.nodes[v as usize]);
                }
            }
        }
        let cells: Vec<Cell> = elements
            .iter()
            .map(|&e| {
                Cell::Polyhedron(
                    self.elements[e]
                        .faces
                        .iter()
                        .map(|r| self.faces[r.face as usize].vertices.iter().map(|&v| new_id[v as usize]).collect())
                        .collect(),
                )
            })
            .collect();
        Ok((PolyMesh::from_cells(nodes, &cells)?, new_id))
    }

    /// Outward triangles (node ids) of the faces that bound exactly one
    /// element: the boundary surface.
    pub fn boundary_triangles(&self) -> Vec<[u32; 3]> {
        let mut users = vec![(0u8, true); self.faces.len()];
        for el in &self.elements {
            for r in &el.faces {
                let u = &mut users[r.face as usize];
                *u = (u.0.saturating_add(1), r.outward);
            }
        }
        self.faces
            .iter()
            .zip(&users)
            .filter(|(_, u)| u.0 == 1)
            .flat_map(|(f, u)| f.triangles.iter().map(move |t| if u.1 { *t } else { [t[0], t[2], t[1]] }))
            .collect()
    }

    /// Total area of the faces that bound exactly one element (m^2).
    pub fn boundary_area(&self) -> f64 {
        let mut users = vec![0u8; self.faces.len()];
        for el in &self.elements {
            for r in &el.faces {
                users[r.face as usize] = users[r.face as usize].saturating_add(1);
            }
        }
        self.faces
            .iter()
            .zip(&users)
            .filter(|(_, &u)| u == 1)
            .map(|(f, _)| face_geometry(&self.nodes, &f.vertices).area)
            .sum()
    }

    /// Element counts keyed by vertex count, in increasing vertex count.
    pub fn count_by_vertex_count(&self) -> std::collections::BTreeMap<usize, usize> {
        let mut m = std::collections::BTreeMap::new();
        for el in &self.elements {
            *m.entry(el.nodes.len()).or_insert(0) += 1;
        }
        m
    }

    /// Adjacency tables (face -> elements, node -> elements, edge -> faces).
    pub fn adjacency(&self) -> Adjacency {
        Adjacency::new(self)
    }
}

/// Whether two loops over the same vertex set run in the same cyclic direction.
fn same_direction(a: &[u32], b: &[u32]) -> bool {
    let n = a.len();
    let Some(start) = b.iter().position(|&v| v == a[0]) else {
        return true;
    };
    b[(start + 1) % n] == a[1]
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn unit_tet() -> PolyMesh {
        let nodes = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        PolyMesh::from_cells(nodes, &[Cell::Tet([0, 1, 2, 3])]).unwrap()
    }

    /// The farthest and the closest pair of a few points, and the limits
    /// of fewer than two.
    #[test]
    fn diameter_and_closest_pair() {
        let points = [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [3.0, 4.0, 0.0], [0.0, 4.0, 0.0]];
        let point = |i: usize| points[i];
        assert_eq!(diameter_of(4, point), 5.0);
        assert_eq!(closest_of(4, point), 3.0);
        assert_eq!(diameter_of(1, point), 0.0);
        assert_eq!(closest_of(1, point), f64::INFINITY);
    }

    #[test]
    fn tet_volume_and_centroid() {
        let m = unit_tet();
        assert!((m.element_volume(0) - 1.0 / 6.0).abs() < 1e-15);
        let c = m.element_centroid(0);
        for x in c {
            assert!((x - 0.25).abs() < 1e-15);
        }
        assert!(m.is_convex(0, 1e-9));
    }

    #[test]
    fn inverted_tet_is_oriented_outward() {
        let nodes = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let m = PolyMesh::from_cells(nodes, &[Cell::Tet([0, 2, 1, 3])]).unwrap();
        assert!((m.element_volume(0) - 1.0 / 6.0).abs() < 1e-15);
    }

    #[test]
    fn two_tets_share_one_face() {
        let nodes = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]];
        let m = PolyMesh::from_cells(nodes, &[Cell::Tet([0, 1, 2, 3]), Cell::Tet([1, 2, 3, 4])]).unwrap();
        assert_eq!(m.faces.len(), 7);
        let shared: Vec<_> =
            m.elements[0].faces.iter().filter(|r| m.elements[1].faces.iter().any(|s| s.face == r.face)).collect();
        assert_eq!(shared.len(), 1);
        let other = m.elements[1].faces.iter().find(|s| s.face == shared[0].face).unwrap();
        assert_ne!(shared[0].outward, other.outward);
    }
}
