//! Splitting convex elements by a plane.
//!
//! Every element that has nodes on both sides of the plane (among the chosen
//! ones, for a local split) is replaced by its two parts. One new node is
//! made per crossed global edge and shared by every element on that edge;
//! every crossed face is split into two faces shared like the original; both
//! parts get a common cap. The mesh stays conforming by construction and the
//! total volume is unchanged (the cap is shared with opposite orientations).
//!
//! **Snapping** (wicke2007 §5.1: nodes that would be created too close to
//! existing nodes are snapped to the existing geometry). A node closer to
//! the plane than [`SplitOptions::snap`] times the diameter of the smallest
//! crossed element holding it is taken to lie on the plane: no edge from it
//! is crossed, and the caps pass through it. So every new node lies at
//! least that far from the nodes of its edge. A cap through a snapped node
//! is no longer planar; it is stored as planar pieces (the ear of each
//! snapped node, then the planar rest), so every face stays planar and the
//! part on the snapped node's side is non-convex by at most its distance
//! from the plane (wicke2007 §4 accepts such slightly non-convex elements:
//! mean value coordinates are well defined on them).
//!
//! **Elements kept whole.** An element is not split when either part would
//! be unhealthy: a [`quality`] below [`SplitOptions::min_quality`] (a sliver,
//! wicke2007 §4), two nodes closer than [`SplitOptions::min_spacing`] times
//! the part's diameter (a soft mode: the quadrature cannot see the thin
//! region between such nodes, and their lumped masses vanish), or a face
//! that lies in the plane. An element kept whole still receives the new
//! nodes its split neighbours make on its edges, unless they would come too
//! close to its own nodes, in which case those neighbours are kept whole
//! too. A cut then follows the faces of the elements kept whole, so the cut
//! surface strays from the plane by at most one element. Nothing moves, so
//! the volume stays exact.

use rustc_hash::FxHashMap as HashMap;

use cleave_kernels::vec3::{add, cross, dot, lerp, norm, scale, sub};
use rayon::prelude::*;
use smallvec::SmallVec;
use thiserror::Error;

use super::CutScope;
use crate::mesh::{
    closest_of, diameter, diameter_of, fold_depth_on, loop_planes, quality, ElementFaces, ElementNodes, Face, FaceLoop,
    FaceRef, Loops, Plane, PolyMesh,
};

/// Tolerances of a split.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SplitOptions {
    /// Snapping radius, as a fraction of the diameter of the smallest crossed
    /// element holding a node: a node closer to the plane lies on it.
    /// Default `0.1` (see [`SplitOptions::default`]).
    pub snap: f64,
    /// Smallest [`quality`] a part of a split element may have. Default
    /// `0.02`: a part that thin spans about 0.5 % of its diameter.
    pub min_quality: f64,
    /// Smallest distance between two nodes of an element the split makes or
    /// changes, as a fraction of that element's diameter. Default `0.05`.
    pub min_spacing: f64,
    /// Smallest diameter a part may have (m). Default `0`: no floor. Each
    /// split's parts span at least about `snap` of their element, but
    /// cuts through the same region compound that, and a part a hundredth
    /// of its original element, moving its own size in a step, is torn
    /// apart by contact; a simulation's cuts set this floor from the body
    /// (see [`crate::sim::SimulationParams::min_part`]).
    pub min_diameter: f64,
}

impl Default for SplitOptions {
    /// `snap = 0.1`, `min_quality = 0.02`, `min_spacing = 0.05`, no
    /// `min_diameter`: measured on
    /// the bunny and random convex boxes cut by hundreds of planes, these
    /// keep the seventh eigenvalue of every element's `K_e` above `1e-4` of
    /// its largest (1e-11 before snapping) and every lumped mass above a
    /// few percent of its elements' mean nodal mass, while snapping bends a
    /// cap by at most a tenth of its element.
    fn default() -> Self {
        SplitOptions { snap: 0.1, min_quality: 0.02, min_spacing: 0.05, min_diameter: 0.0 }
    }
}

impl SplitOptions {
    /// No snapping and nothing kept whole: the parts are exactly the
    /// element's intersections with the two half-spaces, however thin (for
    /// building convex cells of an exact plane arrangement; a simulation's
    /// cuts use the defaults).
    pub fn exact() -> Self {
        SplitOptions { snap: 0.0, min_quality: 0.0, min_spacing: 0.0, min_diameter: 0.0 }
    }

    /// Deepest fold a part of a split may have, as a fraction of the part's
    /// diameter (see [`crate::mesh::PolyMesh::non_convexity`]): the snapping
    /// radius, plus the planarity tolerance of a cap (`1e-6`), within which
    /// the split takes cap points to lie on the plane.
    pub fn max_fold(&self) -> f64 {
        self.snap + CAP_PLANARITY
    }

    /// Checks `snap ∈ [0, 0.5)`, `min_quality ∈ [0, 1)`, `min_spacing ∈
    /// [0, 0.5)`, `min_diameter` finite and `>= 0`.
    pub fn check(&self) -> Result<(), crate::param::ParamError> {
        use crate::param::ParamError;
        if !(self.snap >= 0.0 && self.snap < 0.5) {
            return Err(ParamError::new("snap", self.snap, "must lie in [0, 0.5) (fraction of an element's diameter)"));
        }
        if !(self.min_quality >= 0.0 && self.min_quality < 1.0) {
            return Err(ParamError::new("min_quality", self.min_quality, "must lie in [0, 1)"));
        }
        if !(self.min_spacing >= 0.0 && self.min_spacing < 0.5) {
            return Err(ParamError::new(
                "min_spacing",
                self.min_spacing,
                "must lie in [0, 0.5) (fraction of a diameter)",
            ));
        }
        crate::param::non_negative("min_diameter", self.min_diameter, "must be a finite number >= 0 (m)").map(|_| ())
    }
}

/// A node created on an edge: position `x_a + t (x_b - x_a)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NewNode {
    /// The new node's id.
    pub id: u32,
    /// Edge end nodes.
    pub a: u32,
    /// Edge end nodes.
    pub b: u32,
    /// Position along the edge in `(0, 1)`.
    pub t: f64,
}

/// What a split changed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SplitReport {
    /// Nodes created on crossed edges (state is interpolated from `a`, `b`).
    pub new_nodes: Vec<NewNode>,
    /// For each split element: `(kept id, new id)`; the kept id holds the
    /// positive part, the new id (appended) the negative part.
    pub split_elements: Vec<(u32, u32)>,
    /// Elements that were not split but gained nodes or face halves, in
    /// increasing order.
    pub repaired_elements: Vec<u32>,
    /// Elements the plane crosses that were kept whole because a part would
    /// have been unhealthy (see the module docs), in increasing order.
    pub kept_whole: Vec<u32>,
    /// The cap faces of the split elements (planar pieces, several per
    /// element where the cap passes through snapped nodes).
    pub caps: Vec<u32>,
    /// Nodes of the crossed elements taken to lie on the plane (snapped or
    /// exactly on it), in increasing order; the new nodes lie on it too.
    pub on_plane: Vec<u32>,
}

/// A split that cannot be carried out.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum SplitError {
    /// The plane's normal is zero or not finite.
    #[error("the split plane has an invalid normal {0:?}")]
    InvalidPlane([f64; 3]),
    /// An element the plane crosses is not convex enough to split.
    #[error("element {element} is crossed by the plane but is not convex (face {face} lies in the plane)")]
    NonConvexElement {
        /// The element's id.
        element: usize,
        /// The face's id.
        face: usize,
    },
    /// A cut polygon that cannot be used.
    #[error("the cut polygon {0}")]
    InvalidPolygon(String),
    /// The section of an element is not one polygon of at least 3 corners.
    #[error("element {element}: the plane does not cross it in one polygon")]
    DegenerateCap {
        /// The element's id.
        element: usize,
    },
}

/// Splits every element that `plane` crosses (see the module docs).
pub fn split_by_plane(mesh: &mut PolyMesh, plane: &Plane, opts: &SplitOptions) -> Result<SplitReport, SplitError> {
    split(mesh, plane, None, &[], opts, CutScope::whole())
}

/// Splits those of `elements` that `plane` crosses, and repairs the
/// neighbours so the mesh stays conforming (see the module docs).
pub fn split_elements_by_plane(
    mesh: &mut PolyMesh,
    plane: &Plane,
    elements: &[u32],
    opts: &SplitOptions,
) -> Result<SplitReport, SplitError> {
    split(mesh, plane, Some(elements), &[], opts, CutScope::whole())
}

/// How `plane` would split every element of `mesh` it crosses, without
/// changing anything.
pub(crate) fn classify_split(
    mesh: &PolyMesh,
    plane: &Plane,
    opts: &SplitOptions,
) -> Result<Classification, SplitError> {
    classify(mesh, plane, None, &[], opts, CutScope::whole())
}

/// How a plane meets a mesh, decided before anything changes.
pub(crate) struct Classification {
    /// Signed distance of every node from the plane (m).
    pub dist: Vec<f64>,
    /// Side of every node: `0` on the plane (snapped), else the sign of its
    /// distance.
    pub side: Vec<i8>,
    /// Elements with nodes strictly on both sides of the plane (when only
    /// some elements may be split, those sharing a node with one of them),
    /// in increasing order: the only ones a split can change.
    pub straddling: Vec<usize>,
    /// Elements to split, in increasing order.
    pub crossed: Vec<usize>,
    /// Elements with nodes on both sides that are kept whole.
    pub kept_whole: Vec<usize>,
    /// Nodes of straddling elements that lie on the plane, in increasing
    /// order.
    pub on_plane: Vec<u32>,
}

impl Classification {
    /// Whether the split would snap a node that is not exactly on the plane
    /// or keep an element whole (a generator that wants exact, convex
    /// plane cells draws another plane then).
    pub fn snaps_or_keeps(&self) -> bool {
        !self.kept_whole.is_empty() || self.on_plane.iter().any(|&v| self.dist[v as usize] != 0.0)
    }
}

/// The crossing of edge `(a, b)` (any order) with the plane, as the edge
/// parameter `t` from its smaller end and the position; one formula for
/// the classification and the split, so both see the same point.
fn crossing(nodes: &[[f64; 3]], dist: &[f64], a: u32, b: u32) -> (u32, u32, f64, [f64; 3]) {
    let (lo, hi) = (a.min(b), a.max(b));
    let t = dist[lo as usize] / (dist[lo as usize] - dist[hi as usize]);
    (lo, hi, t, lerp(nodes[lo as usize], nodes[hi as usize], t))
}

/// Classifies the nodes and elements around `plane` (see the module docs).
pub(crate) fn classify(
    mesh: &PolyMesh,
    plane: &Plane,
    only: Option<&[u32]>,
    keep_whole: &[u32],
    opts: &SplitOptions,
    scope: CutScope,
) -> Result<Classification, SplitError> {
    let len = norm(plane.normal);
    if !(len > 0.0) || !len.is_finite() || !plane.point.iter().all(|x| x.is_finite()) {
        return Err(SplitError::InvalidPlane(plane.normal));
    }
    let dist = plane.distances(&mesh.nodes);
    let mut chosen = vec![only.is_none(); mesh.elements.len()];
    for &e in only.unwrap_or(&[]) {
        if let Some(c) = chosen.get_mut(e as usize) {
            *c = true;
        }
    }
    let mut straddling: Vec<usize> = scope
        .elements(mesh)
        .filter(|&e| {
            let d = mesh.elements[e].nodes.iter().map(|&v| dist[v as usize]);
            d.clone().any(|x| x > 0.0) && d.clone().any(|x| x < 0.0)
        })
        .collect();
    if let Some(only) = only {
        // elements sharing no node with one that may be split change in
        // nothing, nor do their snapped nodes matter
        let mut near = vec![false; mesh.nodes.len()];
        for &e in only.iter().filter(|&&e| (e as usize) < mesh.elements.len()) {
            mesh.elements[e as usize].nodes.iter().for_each(|&v| near[v as usize] = true);
        }
        straddling.retain(|&e| mesh.elements[e].nodes.iter().any(|&v| near[v as usize]));
    }
    // snapping radius of each node: `snap` times the smallest straddling
    // element holding it
    let mut radius: HashMap<u32, f64> = HashMap::default();
    for &e in &straddling {
        let r = opts.snap * mesh.element_diameter(e);
        for &v in &mesh.elements[e].nodes {
            let entry = radius.entry(v).or_insert(r);
            *entry = entry.min(r);
        }
    }
    // (a node's side from its distance's sign, NaN on the negative side;
    // then the nodes with a snapping radius that lie within it)
    let mut side: Vec<i8> = dist
        .iter()
        .map(|&d| {
            if d > 0.0 {
                1
            } else if d == 0.0 {
                0
            } else {
                -1
            }
        })
        .collect();
    for (&v, &r) in &radius {
        if dist[v as usize].abs() <= r {
            side[v as usize] = 0;
        }
    }
    let mut on_plane: Vec<u32> = radius.keys().copied().filter(|&v| side[v as usize] == 0).collect();
    on_plane.sort_unstable();
    let has_both = |e: usize| {
        let nodes = &mesh.elements[e].nodes;
        nodes.iter().any(|&v| side[v as usize] > 0) && nodes.iter().any(|&v| side[v as usize] < 0)
    };
    let protected = |e: usize| keep_whole.binary_search(&(e as u32)).is_ok();
    // every element with nodes on both sides is split, or kept whole: when
    // not chosen, protected or unhealthy once split
    let both: Vec<usize> = straddling.iter().copied().filter(|&e| has_both(e)).collect();
    // (the trial splits are independent: run in parallel)
    let kept_by_trial: Vec<bool> = both
        .par_iter()
        .map_init(TrialParts::default, |parts, &e| {
            !chosen[e] || protected(e) || !split_is_healthy(mesh, e, &dist, &side, plane, opts, parts)
        })
        .collect();
    let mut keep = vec![false; mesh.elements.len()];
    both.iter().zip(&kept_by_trial).for_each(|(&e, &k)| keep[e] = k);
    // the elements on each crossed edge (every element holding an edge with
    // ends on opposite sides has nodes on both sides), as sorted pairs
    let mut edge_users: Vec<((u32, u32), usize)> = Vec::new();
    for &e in &both {
        for r in &mesh.elements[e].faces {
            let v = &mesh.faces[r.face as usize].vertices;
            for i in 0..v.len() {
                let (a, b) = (v[i], v[(i + 1) % v.len()]);
                if side[a as usize] * side[b as usize] < 0 {
                    edge_users.push(((a.min(b), a.max(b)), e));
                }
            }
        }
    }
    edge_users.sort_unstable();
    edge_users.dedup();
    let users_of = |key: (u32, u32)| {
        let first = edge_users.partition_point(|u| u.0 < key);
        edge_users[first..].iter().take_while(move |u| u.0 == key).map(|u| u.1)
    };
    // an element kept whole receives the new nodes on its edges that split
    // neighbours make; where one would come too close to its nodes (or the
    // element is protected), every element on that edge is kept whole
    // (until nothing changes)
    let mut kept: Vec<usize> = both.iter().copied().filter(|&e| keep[e]).collect();
    let mut k = 0;
    while k < kept.len() {
        let e = kept[k];
        k += 1;
        let el = &mesh.elements[e];
        let mut points: Vec<[f64; 3]> = el.nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
        let own = points.len();
        let mut gained: Vec<(u32, u32)> = Vec::new();
        for r in &el.faces {
            let v = &mesh.faces[r.face as usize].vertices;
            for i in 0..v.len() {
                let key = (v[i].min(v[(i + 1) % v.len()]), v[i].max(v[(i + 1) % v.len()]));
                let split_user = users_of(key).any(|o| !keep[o]);
                if split_user && !gained.contains(&key) {
                    gained.push(key);
                    points.push(crossing(&mesh.nodes, &dist, key.0, key.1).3);
                }
            }
        }
        if gained.is_empty() {
            continue;
        }
        let limit = opts.min_spacing * diameter(&points[..own]);
        for (g, key) in gained.iter().enumerate() {
            let p = points[own + g];
            let close = points.iter().enumerate().any(|(j, &q)| j != own + g && norm(sub(p, q)) < limit);
            if close || protected(e) {
                for o in users_of(*key) {
                    if !keep[o] {
                        keep[o] = true;
                        kept.push(o);
                    }
                }
            }
        }
    }
    let (mut kept_whole, crossed): (Vec<usize>, Vec<usize>) =
        both.iter().filter(|&&e| chosen[e]).partition(|&&e| keep[e]);
    kept_whole.sort_unstable();
    Ok(Classification { dist, side, straddling, crossed, kept_whole, on_plane })
}

/// A point of a prospective part: a node, or the crossing on an edge
/// `(a, b)`, `a < b`, as one integer ordered as the pair of variants would
/// be (the nodes by id, then the edges by their ends): node `v` is `v`,
/// edge `(a, b)` is `(a + 1) 2³² + b`. Sorting and matching points is
/// the trial split's most frequent operation; an enum of the two
/// variants compared with branches took 4 % of a blade cut's CPU time.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
struct Point(u64);

impl Point {
    fn node(v: u32) -> Self {
        Point(u64::from(v))
    }

    /// The crossing on the edge between nodes `a` and `b` (either order).
    fn edge(a: u32, b: u32) -> Self {
        let (a, b) = (a.min(b), a.max(b));
        Point(((u64::from(a) + 1) << 32) | u64::from(b))
    }

    /// The node, or the edge's ends.
    fn parts(self) -> Result<u32, (u32, u32)> {
        match u32::try_from(self.0) {
            Ok(v) => Ok(v),
            Err(_) => Err((((self.0 >> 32) - 1) as u32, self.0 as u32)),
        }
    }
}

/// The two parts a trial split builds, kept by each thread from one trial
/// to the next (their room reused).
#[derive(Default)]
struct TrialParts {
    /// The face loops of the positive and the negative part, outward.
    loops: [Loops<Point>; 2],
    /// The points where a face meets the plane.
    on_plane: Vec<[f64; 3]>,
    /// The cap's positions, and a part's points (each once).
    cap_positions: Vec<[f64; 3]>,
    points: Vec<(Point, [f64; 3])>,
}

/// Whether both parts that splitting element `e` would make are healthy:
/// no face of `e` lies (partly) in the plane, the cap is one loop, and each
/// part sees its centroid from every face (the cones of the quadrature),
/// has a [`quality`] of at least `min_quality`, no two points closer than
/// `min_spacing` times its diameter and no fold deeper than `snap` times
/// it. The parts are built from the same points, clipped face
/// loops and cap pieces as the split itself.
fn split_is_healthy(
    mesh: &PolyMesh,
    e: usize,
    dist: &[f64],
    side: &[i8],
    plane: &Plane,
    opts: &SplitOptions,
    parts: &mut TrialParts,
) -> bool {
    let el = &mesh.elements[e];
    let position = |p: Point| match p.parts() {
        Ok(v) => mesh.nodes[v as usize],
        Err((a, b)) => crossing(&mesh.nodes, dist, a, b).3,
    };
    let TrialParts { loops, on_plane, cap_positions, points } = parts;
    loops.iter_mut().for_each(Loops::clear);
    for r in &el.faces {
        let v = &mesh.faces[r.face as usize].vertices;
        if v.iter().all(|&x| side[x as usize] == 0) || face_partly_on_plane(&mesh.nodes, dist, v, side, on_plane) {
            return false;
        }
        for (part, sign) in loops.iter_mut().zip([1i8, -1]) {
            if !v.iter().any(|&x| side[x as usize] == sign) {
                continue;
            }
            // the face's points on this part's side, and its crossings
            let points = (0..v.len()).flat_map(|i| {
                let (a, b) = (v[i], v[(i + 1) % v.len()]);
                let node = (side[a as usize] * sign >= 0).then_some(Point::node(a));
                let edge = (side[a as usize] * side[b as usize] < 0).then_some(Point::edge(a, b));
                node.into_iter().chain(edge)
            });
            let keyed = points.map(|p| (p, position(p)));
            part.push(keyed);
            if !r.outward {
                part.reverse_last();
            }
        }
    }
    // the cap closes the positive part: its loop is the chain of the
    // positive faces' unmatched edges (outward of the negative part)
    let Some(cap) = cap_loop(&loops[0]) else {
        return false;
    };
    cap_positions.clear();
    cap_positions.extend(cap.iter().map(|&p| position(p)));
    for piece in cap_pieces(cap_positions, plane) {
        loops[0].push(piece.iter().rev().map(|&i| (cap[i], cap_positions[i])));
        loops[1].push(piece.iter().map(|&i| (cap[i], cap_positions[i])));
    }
    loops.iter().all(|part| {
        points.clear();
        points.extend_from_slice(part.values());
        points.sort_unstable_by_key(|p| p.0);
        points.dedup_by_key(|p| p.0);
        let o = points[0].1;
        let (mut volume, mut centroid) = (0.0, [0.0; 3]);
        for lp in part.iter() {
            for i in 1..lp.len().saturating_sub(1) {
                let (a, b, c) = (lp[0].1, lp[i].1, lp[i + 1].1);
                let v = cleave_kernels::tet::signed_volume(o, a, b, c);
                volume += v;
                centroid = add(centroid, scale(add(add(o, a), add(b, c)), v / 4.0));
            }
        }
        let centroid = scale(centroid, 1.0 / volume);
        let d = diameter_of(points.len(), |i| points[i].1);
        // the quadrature of a mean value element takes cones from its
        // centroid to its faces: every face must see the centroid inside;
        // and no face may be a sliver of no area (a clipped loop whose
        // points snapping left on one line)
        // (the faces' planes serve the fold's depth below as well)
        let planes = loop_planes(part);
        let star =
            planes.iter().all(|g| dot(sub(centroid, g.centroid), g.normal) < 0.0 && g.area > MIN_FACE_AREA * d * d);
        // (the pair pass last: the cheaper tests settle most parts)
        let spacing = || closest_of(points.len(), |i| points[i].1);
        star && quality(volume, d) >= opts.min_quality
            && d >= opts.min_diameter
            && spacing() >= opts.min_spacing * d
            && fold_depth_on(part, &planes) <= opts.max_fold() * d
    })
}

/// Whether the points where face loop `v` meets the plane (its vertices on
/// it, side 0, and the crossings of its edges) are three or more off one
/// line. An exact plane meets a convex face in a segment, so this happens
/// only by snapping: that part of the face would become part of the cap,
/// or both halves of the face would hold the same edge. `on` is room for
/// those points.
fn face_partly_on_plane(nodes: &[[f64; 3]], dist: &[f64], v: &[u32], side: &[i8], on: &mut Vec<[f64; 3]>) -> bool {
    on.clear();
    for i in 0..v.len() {
        let (a, b) = (v[i], v[(i + 1) % v.len()]);
        if side[a as usize] == 0 {
            on.push(nodes[a as usize]);
        }
        if side[a as usize] * side[b as usize] < 0 {
            on.push(crossing(nodes, dist, a, b).3);
        }
    }
    if on.len() < 3 {
        return false;
    }
    // farthest pair, then the largest distance from the line through it
    let (mut a, mut b, mut far) = (0, 1, 0.0);
    for i in 0..on.len() {
        for j in i + 1..on.len() {
            let d = norm(sub(on[i], on[j]));
            if d > far {
                (a, b, far) = (i, j, d);
            }
        }
    }
    let axis = scale(sub(on[b], on[a]), 1.0 / far);
    on.iter().any(|&p| norm(cross(sub(p, on[a]), axis)) > CAP_PLANARITY * far)
}

/// The cap of a split element from the closed surface of its positive
/// part without the cap (`faces`, loops outward): the chain of the edges
/// that only one face holds in one direction, which is the cap's loop
/// outward of the negative part (counter-clockwise about the plane's
/// normal). Built from the faces rather than by sorting points about a
/// centre, so it holds for a cap bent through snapped nodes. `None` unless
/// those edges form one simple loop of at least three points. (Sorted
/// lists, not hash maps: a cut builds thousands of caps.)
fn cap_loop<K: Copy + Ord>(faces: &Loops<K>) -> Option<Vec<K>> {
    let mut directed: SmallVec<[(K, K); 48]> = SmallVec::with_capacity(faces.values().len());
    for lp in faces.iter() {
        for i in 0..lp.len() {
            directed.push((lp[i].0, lp[(i + 1) % lp.len()].0));
        }
    }
    directed.sort_unstable();
    // the edges held once, whose reverse no face holds, by their first point
    let mut next: SmallVec<[(K, K); 16]> = SmallVec::new();
    for uses in directed.chunk_by(|x, y| x == y) {
        let (a, b) = uses[0];
        if uses.len() == 1 && directed.binary_search(&(b, a)).is_err() {
            next.push((a, b));
        }
    }
    if next.windows(2).any(|w| w[0].0 == w[1].0) {
        return None;
    }
    let after = |a: K| next.binary_search_by_key(&a, |e| e.0).ok().map(|i| next[i].1);
    let start = next.first()?.0;
    let mut lp = vec![start];
    let mut at = after(start)?;
    while at != start {
        if lp.len() > next.len() {
            return None;
        }
        lp.push(at);
        at = after(at)?;
    }
    (lp.len() == next.len() && lp.len() >= 3).then_some(lp)
}

/// The smallest area of a face of a split part, relative to the square of
/// the part's diameter: far below any face a cut makes on purpose, far
/// above the rounding left in a loop whose points lie on one line.
const MIN_FACE_AREA: f64 = 1e-10;

/// Relative height above which a cap point is off the plane (of the cap's
/// diameter): far below the `1e-3` planarity of a valid face, far above
/// the rounding of a crossing point.
const CAP_PLANARITY: f64 = 1e-6;

/// The planar pieces of a cap whose `points` run counter-clockwise about
/// the plane's normal. The loop is triangulated by ear clipping (which
/// avoids flat triangles where the loop has collinear points, as the
/// points from one face do); the triangles with every corner on the plane
/// merge into the polygons their edge-connected groups form (the dual of a
/// polygon's triangulation is a tree, so each group is a simple polygon),
/// and the others (the ears of snapped nodes) stay triangles. Returns loops
/// of indices into `points`, oriented like the loop.
fn cap_pieces(points: &[[f64; 3]], plane: &Plane) -> Vec<Vec<usize>> {
    // (the work lists on the stack: a cut builds thousands of caps)
    let local: SmallVec<[u32; 16]> = (0..points.len() as u32).collect();
    let triangles = crate::mesh::triangulate_loop(points, &local);
    let tolerance = CAP_PLANARITY * diameter(points);
    let flat: SmallVec<[bool; 16]> =
        triangles.iter().map(|t| t.iter().all(|&i| plane.distance(points[i as usize]).abs() <= tolerance)).collect();
    // (each directed edge is one triangle's: a sorted list finds it)
    let mut by_edge: SmallVec<[((u32, u32), usize); 48]> = SmallVec::with_capacity(3 * triangles.len());
    for (k, t) in triangles.iter().enumerate() {
        for i in 0..3 {
            by_edge.push(((t[i], t[(i + 1) % 3]), k));
        }
    }
    by_edge.sort_unstable();
    let triangle_on = |edge: (u32, u32)| by_edge.binary_search_by_key(&edge, |x| x.0).ok().map(|i| by_edge[i].1);
    let mut done: SmallVec<[bool; 16]> = smallvec::smallvec![false; triangles.len()];
    let mut pieces = Vec::new();
    for start in 0..triangles.len() {
        if done[start] {
            continue;
        }
        done[start] = true;
        let mut lp: Vec<usize> = triangles[start].iter().map(|&i| i as usize).collect();
        if flat[start] {
            // grow the loop across its edges into flat neighbours
            let mut i = 0;
            while i < lp.len() {
                let (a, b) = (lp[i] as u32, lp[(i + 1) % lp.len()] as u32);
                match triangle_on((b, a)) {
                    Some(k) if flat[k] && !done[k] => {
                        done[k] = true;
                        let t = triangles[k];
                        let apex = (0..3).map(|j| t[j]).find(|&v| v != a && v != b).expect("a triangle has 3 corners");
                        lp.insert(i + 1, apex as usize);
                    }
                    _ => i += 1,
                }
            }
        }
        pieces.push(lp);
    }
    pieces
}

/// Splits `only` those elements (all if `None`) that `plane` crosses,
/// leaving the sorted `keep_whole` elements as they are: not split and
/// given no new node (the elements on their crossed edges stay whole too);
/// only the elements in `scope` are looked at.
pub(crate) fn split(
    mesh: &mut PolyMesh,
    plane: &Plane,
    only: Option<&[u32]>,
    keep_whole: &[u32],
    opts: &SplitOptions,
    scope: CutScope,
) -> Result<SplitReport, SplitError> {
    let classification = classify(mesh, plane, only, keep_whole, opts, scope)?;
    split_classified(mesh, plane, classification)
}

/// Splits the elements as [`classify`] decided on this `mesh` (unchanged
/// since) for `plane`: the part of [`split`] that changes the mesh.
pub(crate) fn split_classified(
    mesh: &mut PolyMesh,
    plane: &Plane,
    classification: Classification,
) -> Result<SplitReport, SplitError> {
    let Classification { dist, side, straddling, crossed, kept_whole, on_plane } = classification;
    let mut report =
        SplitReport { kept_whole: kept_whole.iter().map(|&e| e as u32).collect(), on_plane, ..Default::default() };
    if crossed.is_empty() {
        return Ok(report);
    }
    let mut nearby_faces: Vec<u32> =
        straddling.iter().flat_map(|&e| mesh.elements[e].faces.iter().map(|r| r.face)).collect();
    nearby_faces.sort_unstable();
    nearby_faces.dedup();
    // 1. crossing nodes, one per crossed edge
    let mut edge_node: HashMap<(u32, u32), u32> = HashMap::default();
    let mut new_node = |mesh: &mut PolyMesh, report: &mut SplitReport, a: u32, b: u32| -> u32 {
        let (lo, hi, t, x) = crossing(&mesh.nodes, &dist, a, b);
        *edge_node.entry((lo, hi)).or_insert_with(|| {
            let id = mesh.nodes.len() as u32;
            mesh.nodes.push(x);
            report.new_nodes.push(NewNode { id, a: lo, b: hi, t });
            id
        })
    };
    let side_of = |x: u32| side.get(x as usize).copied().unwrap_or(0);
    // 2. split the crossed faces: face -> (positive part, negative part);
    // the faces are found and their crossings made in order, the parts'
    // loops and triangles built in parallel, then written in order
    let mut face_parts: HashMap<u32, (u32, u32)> = HashMap::default();
    let mut split_faces: Vec<u32> = Vec::new();
    for &e in &crossed {
        for k in 0..mesh.elements[e].faces.len() {
            let f = mesh.elements[e].faces[k].face;
            let v = &mesh.faces[f as usize].vertices;
            if face_parts.contains_key(&f)
                || !(v.iter().any(|&x| side[x as usize] > 0) && v.iter().any(|&x| side[x as usize] < 0))
            {
                continue;
            }
            // (listed once; its negative part's id is known when written)
            face_parts.insert(f, (f, u32::MAX));
            split_faces.push(f);
            for i in 0..mesh.faces[f as usize].vertices.len() {
                let v = &mesh.faces[f as usize].vertices;
                let (a, b) = (v[i], v[(i + 1) % v.len()]);
                if side[a as usize] * side[b as usize] < 0 {
                    new_node(mesh, &mut report, a, b);
                }
            }
        }
    }
    let (faces, nodes) = (&mesh.faces, &mesh.nodes);
    let halves: Vec<(Face, Face)> = split_faces
        .par_iter()
        .map(|&f| {
            let v = &faces[f as usize].vertices;
            // (a convex face's parts gain at most the two crossings)
            let (mut pos, mut neg) = (FaceLoop::with_capacity(v.len() + 2), FaceLoop::with_capacity(v.len() + 2));
            for i in 0..v.len() {
                let (a, b) = (v[i], v[(i + 1) % v.len()]);
                let sa = side[a as usize];
                if sa >= 0 {
                    pos.push(a);
                }
                if sa <= 0 {
                    neg.push(a);
                }
                if sa * side[b as usize] < 0 {
                    let c = edge_node[&(a.min(b), a.max(b))];
                    pos.push(c);
                    neg.push(c);
                }
            }
            let part =
                |vertices: FaceLoop| Face { triangles: crate::mesh::triangulate_loop(nodes, &vertices), vertices };
            (part(pos), part(neg))
        })
        .collect();
    for (&f, (pos, neg)) in split_faces.iter().zip(halves) {
        mesh.faces[f as usize] = pos;
        face_parts.insert(f, (f, mesh.faces.len() as u32));
        mesh.faces.push(neg);
    }
    // 2b. neighbours that are not split: both halves of a split face they
    // share, and the new nodes on their edges in their other faces' loops
    let is_crossed = {
        let mut m = vec![false; mesh.elements.len()];
        crossed.iter().for_each(|&e| m[e] = true);
        m
    };
    // faces changed so far: split ones, and below those that gain a node
    let mut changed: Vec<bool> = vec![false; mesh.faces.len()];
    face_parts.keys().for_each(|&f| changed[f as usize] = true);
    let mut on_crossed_edge = vec![false; mesh.nodes.len()];
    for &(a, b) in edge_node.keys() {
        on_crossed_edge[a as usize] = true;
        on_crossed_edge[b as usize] = true;
    }
    let mut new_on_edges = Vec::new();
    // (a face on a crossed edge is a face of an element holding that edge,
    // which straddles the plane)
    for f in nearby_faces.iter().map(|&f| f as usize) {
        let v = &mesh.faces[f].vertices;
        if changed[f] || v.iter().filter(|&&x| on_crossed_edge[x as usize]).count() < 2 {
            continue;
        }
        new_on_edges.clear();
        for i in 0..v.len() {
            let (a, b) = (v[i], v[(i + 1) % v.len()]);
            if let Some(&c) = edge_node.get(&(a.min(b), a.max(b))) {
                new_on_edges.push((a, b, c));
            }
        }
        for &(a, b, c) in &new_on_edges {
            mesh.faces[f].insert_on_edge(a, b, c);
            changed[f] = true;
        }
    }
    for &e in &straddling {
        if is_crossed[e] {
            continue;
        }
        let refs = &mesh.elements[e].faces;
        let touches = refs.iter().any(|r| changed[r.face as usize]);
        if !touches {
            continue;
        }
        let mut new_refs = ElementFaces::with_capacity(refs.len() + 2);
        for r in refs {
            match face_parts.get(&r.face) {
                Some(&(fp, fneg)) => {
                    new_refs.push(FaceRef { face: fp, outward: r.outward });
                    new_refs.push(FaceRef { face: fneg, outward: r.outward });
                }
                None => new_refs.push(*r),
            }
        }
        mesh.elements[e].faces = new_refs;
        report.repaired_elements.push(e as u32);
    }
    mesh.refresh_elements_nodes(&report.repaired_elements);
    // 3. split the elements: each one's parts (their faces, caps and
    // nodes) found in parallel, since each reads only the faces above and
    // the nodes, then written in order (the first failure in order is the
    // one reported)
    let (faces, nodes) = (&mesh.faces, &mesh.nodes);
    let elements = &mesh.elements;
    let parts: Vec<Result<ElementParts, SplitError>> = crossed
        .par_iter()
        .map_init(
            || (Loops::default(), Vec::new()),
            |(outward, positions), &e| {
                // (each part takes at most every face and a cap piece or two)
                let room = elements[e].faces.len() + 2;
                let (mut pos_faces, mut neg_faces) =
                    (ElementFaces::with_capacity(room), ElementFaces::with_capacity(room));
                for r in &elements[e].faces {
                    if let Some(&(fp, fneg)) = face_parts.get(&r.face) {
                        pos_faces.push(FaceRef { face: fp, outward: r.outward });
                        neg_faces.push(FaceRef { face: fneg, outward: r.outward });
                        continue;
                    }
                    let v = &faces[r.face as usize].vertices;
                    if v.iter().any(|&x| side_of(x) > 0) {
                        pos_faces.push(*r);
                    } else if v.iter().any(|&x| side_of(x) < 0) {
                        neg_faces.push(*r);
                    } else {
                        return Err(SplitError::NonConvexElement { element: e, face: r.face as usize });
                    }
                }
                outward.clear();
                for r in &pos_faces {
                    outward.push(faces[r.face as usize].vertices.iter().map(|&v| (v, nodes[v as usize])));
                    if !r.outward {
                        outward.reverse_last();
                    }
                }
                let cap_points = cap_loop(outward).ok_or(SplitError::DegenerateCap { element: e })?;
                positions.clear();
                positions.extend(cap_points.iter().map(|&p| nodes[p as usize]));
                // the cap pieces run counter-clockwise about +n: out of the negative part
                let caps: Vec<Face> = cap_pieces(positions, plane)
                    .into_iter()
                    .map(|piece| {
                        let vertices: FaceLoop = piece.iter().map(|&i| cap_points[i]).collect();
                        Face { triangles: crate::mesh::triangulate_loop(nodes, &vertices), vertices }
                    })
                    .collect();
                let loops = |refs: &[FaceRef]| {
                    let faces = refs.iter().map(|r| &faces[r.face as usize].vertices[..]);
                    crate::mesh::loop_nodes(faces.chain(caps.iter().map(|c| &c.vertices[..])))
                };
                let (pos_nodes, neg_nodes) = (loops(&pos_faces), loops(&neg_faces));
                Ok(ElementParts { pos_faces, neg_faces, caps, pos_nodes, neg_nodes })
            },
        )
        .collect();
    for (&e, parts) in crossed.iter().zip(parts) {
        let ElementParts { mut pos_faces, mut neg_faces, caps, pos_nodes, neg_nodes } = parts?;
        for cap in caps {
            let id = mesh.faces.len() as u32;
            mesh.faces.push(cap);
            pos_faces.push(FaceRef { face: id, outward: false });
            neg_faces.push(FaceRef { face: id, outward: true });
            report.caps.push(id);
        }
        mesh.elements[e] = crate::mesh::Element { faces: pos_faces, nodes: pos_nodes };
        let ne = mesh.elements.len();
        mesh.elements.push(crate::mesh::Element { faces: neg_faces, nodes: neg_nodes });
        report.split_elements.push((e as u32, ne as u32));
    }
    Ok(report)
}

/// The two parts of a crossed element, before they are written into the
/// mesh: their faces (without the caps), the cap pieces between them, and
/// their sorted nodes (the caps' included).
struct ElementParts {
    pos_faces: ElementFaces,
    neg_faces: ElementFaces,
    caps: Vec<Face>,
    pos_nodes: ElementNodes,
    neg_nodes: ElementNodes,
}

/// Relative distance (of the mesh's bounding box diagonal) within which a
/// node not in a crossed element counts as lying on a cut plane: nodes a
/// former cut put on the same plane (up to rounding).
pub(crate) const ON_PLANE: f64 = 1e-9;

/// The largest distance (m) from a plane at which a node outside the
/// crossed elements counts as lying on it: [`ON_PLANE`] of the mesh's
/// bounding box diagonal.
pub(crate) fn on_plane_band(mesh: &PolyMesh) -> f64 {
    let (lo, hi) = mesh.bounding_box();
    ON_PLANE * norm(sub(hi, lo))
}

/// Two unit vectors `(u, w)` with `(u, w, n)` right-handed.
pub(crate) fn plane_basis(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let a = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let u = cross(a, n);
    let u = scale(u, 1.0 / norm(u));
    (u, cross(n, u))
}

#[cfg(test)]
mod tests {
    use super::Point;
    use proptest::prelude::*;

    /// A node or an edge as the pair of variants the integer stands for:
    /// nodes first, by id, then edges by their ends.
    fn variant(p: Result<u32, (u32, u32)>) -> (u8, u32, u32) {
        match p {
            Ok(v) => (0, v, 0),
            Err((a, b)) => (1, a, b),
        }
    }

    fn point() -> impl Strategy<Value = Result<u32, (u32, u32)>> {
        let ids = prop_oneof![0..8u32, (u32::MAX - 8)..=u32::MAX, any::<u32>()];
        prop_oneof![
            ids.clone().prop_map(Ok),
            (ids.clone(), ids).prop_filter("an edge joins two nodes", |(a, b)| a != b).prop_map(Err),
        ]
    }

    fn make(p: Result<u32, (u32, u32)>) -> Point {
        match p {
            Ok(v) => Point::node(v),
            Err((a, b)) => Point::edge(a, b),
        }
    }

    proptest! {
        /// Points compare as their variants would and give back their node
        /// or their edge's ends (in increasing order), at every id.
        #[test]
        fn points_order_as_nodes_then_edges(p in point(), q in point()) {
            let sorted = |p: Result<u32, (u32, u32)>| p.map_err(|(a, b)| (a.min(b), a.max(b)));
            let (p, q) = (sorted(p), sorted(q));
            prop_assert_eq!(make(p).parts(), p);
            prop_assert_eq!(make(p).cmp(&make(q)), variant(p).cmp(&variant(q)));
        }
    }
}
