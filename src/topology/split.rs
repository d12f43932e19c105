//! Splitting convex elements by a plane.
//!
//! Every element that has nodes strictly on both sides of the plane (among
//! the chosen ones, for a local split) is replaced by its two convex parts.
//! One new node is made per crossed global edge and shared by every element
//! on that edge; every crossed face is split into two faces shared like the
//! original; both parts get a common cap face. A node closer to the plane
//! than `snap` times its shortest edge in the elements the plane crosses is
//! taken to lie on it (used instead of a new node), so no edge shorter than
//! that fraction ever appears. The mesh stays conforming by construction
//! and the total volume is unchanged (the cap is shared with opposite
//! orientations).
//!
//! Slivers (wicke2007 §4) are not made in the first place: an element whose
//! part on either side would have a [`quality`] below
//! [`SplitOptions::min_quality`] is kept whole (its neighbours' new nodes
//! still join its faces). A cut then follows that element's faces on its
//! thin side, so the cut surface strays from the plane by at most the
//! thickness of the sliver it avoided. Unlike merging slivers after the fact
//! by projecting them onto a plane, this moves no node, so the total volume
//! stays exact and every element stays convex (the next split needs that).

use std::collections::HashMap;

use cleave_kernels::vec3::{cross, dot, lerp, norm, scale, sub};
use thiserror::Error;

use crate::mesh::{diameter, quality, Face, FaceRef, PolyMesh};

/// An oriented plane through `point` with normal `normal` (need not be unit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// A point on the plane (m).
    pub point: [f64; 3],
    /// The normal; the positive side is where it points.
    pub normal: [f64; 3],
}

impl Plane {
    /// Signed distance of `x` from the plane (m), positive on the normal's
    /// side.
    pub fn distance(&self, x: [f64; 3]) -> f64 {
        dot(sub(x, self.point), self.normal) / norm(self.normal)
    }

    /// [`Plane::distance`] of every point.
    pub fn distances(&self, points: &[[f64; 3]]) -> Vec<f64> {
        let n = scale(self.normal, 1.0 / norm(self.normal));
        points.iter().map(|&x| dot(sub(x, self.point), n)).collect()
    }
}

/// Tolerances of a split.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplitOptions {
    /// Relative snapping distance (fraction of a node's shortest edge in the
    /// crossed elements). Default `1e-4`.
    pub snap: f64,
    /// Smallest [`quality`] a part of a split element may have; an element
    /// that would leave a flatter part is kept whole. Default `0.02`: a part
    /// that thin spans about 0.5 % of its element's diameter.
    pub min_quality: f64,
}

impl Default for SplitOptions {
    fn default() -> Self {
        SplitOptions { snap: 1e-4, min_quality: 0.02 }
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
    /// Elements the plane crosses that were kept whole because one of their
    /// parts would have been a sliver, in increasing order.
    pub kept_whole: Vec<u32>,
    /// The cap face of each split element (same order as `split_elements`).
    pub caps: Vec<u32>,
}

/// A split that cannot be carried out.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum SplitError {
    /// The plane's normal is zero or not finite.
    #[error("the split plane has an invalid normal {0:?}")]
    InvalidPlane([f64; 3]),
    /// An element the plane crosses is not convex enough to split.
    #[error("element {element} is crossed by the plane but is not convex (face {face} lies in the plane)")]
    NonConvexElement { element: usize, face: usize },
    /// A cut polygon that cannot be used.
    #[error("the cut polygon {0}")]
    InvalidPolygon(String),
    /// The cap polygon of an element has fewer than 3 corners.
    #[error("element {element}: the plane crosses it in fewer than 3 points")]
    DegenerateCap { element: usize },
}

/// Splits every element that `plane` crosses (see the module docs).
pub fn split_by_plane(mesh: &mut PolyMesh, plane: &Plane, opts: &SplitOptions) -> Result<SplitReport, SplitError> {
    split(mesh, plane, None, opts)
}

/// Splits those of `elements` that `plane` crosses, and repairs the
/// neighbours so the mesh stays conforming (see the module docs).
pub fn split_elements_by_plane(
    mesh: &mut PolyMesh,
    plane: &Plane,
    elements: &[u32],
    opts: &SplitOptions,
) -> Result<SplitReport, SplitError> {
    split(mesh, plane, Some(elements), opts)
}

fn split(
    mesh: &mut PolyMesh,
    plane: &Plane,
    only: Option<&[u32]>,
    opts: &SplitOptions,
) -> Result<SplitReport, SplitError> {
    let len = norm(plane.normal);
    if !(len > 0.0) || !len.is_finite() || !plane.point.iter().all(|x| x.is_finite()) {
        return Err(SplitError::InvalidPlane(plane.normal));
    }
    let n = scale(plane.normal, 1.0 / len);
    // only elements with nodes strictly on both sides can be split or hold
    // an edge the plane crosses; a node of theirs closer to the plane than
    // `snap` times its shortest edge in them lies on it
    let dist = plane.distances(&mesh.nodes);
    let straddling: Vec<usize> = (0..mesh.elements.len())
        .filter(|&e| {
            let d = mesh.elements[e].nodes.iter().map(|&v| dist[v as usize]);
            d.clone().any(|x| x > 0.0) && d.clone().any(|x| x < 0.0)
        })
        .collect();
    let mut nearby_faces: Vec<u32> =
        straddling.iter().flat_map(|&e| mesh.elements[e].faces.iter().map(|r| r.face)).collect();
    nearby_faces.sort_unstable();
    nearby_faces.dedup();
    let mut h = vec![f64::INFINITY; mesh.nodes.len()];
    for &f in &nearby_faces {
        let v = &mesh.faces[f as usize].vertices;
        for i in 0..v.len() {
            let (a, b) = (v[i] as usize, v[(i + 1) % v.len()] as usize);
            let l = norm(sub(mesh.nodes[a], mesh.nodes[b]));
            h[a] = h[a].min(l);
            h[b] = h[b].min(l);
        }
    }
    let side: Vec<i8> = dist
        .iter()
        .zip(&h)
        .map(|(&d, &h)| {
            if d == 0.0 || d.abs() <= opts.snap * h {
                0
            } else if d > 0.0 {
                1
            } else {
                -1
            }
        })
        .collect();
    let mut chosen = vec![only.is_none(); mesh.elements.len()];
    for &e in only.unwrap_or(&[]) {
        if let Some(c) = chosen.get_mut(e as usize) {
            *c = true;
        }
    }
    let mut report = SplitReport::default();
    let (crossed, kept_whole): (Vec<usize>, Vec<usize>) = straddling
        .iter()
        .copied()
        .filter(|&e| chosen[e])
        .filter(|&e| {
            let nodes = &mesh.elements[e].nodes;
            nodes.iter().any(|&v| side[v as usize] > 0) && nodes.iter().any(|&v| side[v as usize] < 0)
        })
        .partition(|&e| {
            let [pos, neg] = part_qualities(mesh, e, &dist, &side, plane.point);
            pos.min(neg) >= opts.min_quality
        });
    report.kept_whole = kept_whole.iter().map(|&e| e as u32).collect();
    if crossed.is_empty() {
        return Ok(report);
    }
    // 1. crossing nodes, one per crossed edge
    let mut edge_node: HashMap<(u32, u32), u32> = HashMap::new();
    let mut crossing = |mesh: &mut PolyMesh, report: &mut SplitReport, a: u32, b: u32| -> u32 {
        let key = (a.min(b), a.max(b));
        *edge_node.entry(key).or_insert_with(|| {
            let (lo, hi) = key;
            let t = dist[lo as usize] / (dist[lo as usize] - dist[hi as usize]);
            let id = mesh.nodes.len() as u32;
            mesh.nodes.push(lerp(mesh.nodes[lo as usize], mesh.nodes[hi as usize], t));
            report.new_nodes.push(NewNode { id, a: lo, b: hi, t });
            id
        })
    };
    // 2. split the crossed faces: face -> (positive part, negative part)
    let mut face_parts: HashMap<u32, (u32, u32)> = HashMap::new();
    for &e in &crossed {
        for r in mesh.elements[e].faces.clone() {
            if face_parts.contains_key(&r.face) {
                continue;
            }
            let v = mesh.faces[r.face as usize].vertices.clone();
            let has_pos = v.iter().any(|&x| side[x as usize] > 0);
            let has_neg = v.iter().any(|&x| side[x as usize] < 0);
            if !(has_pos && has_neg) {
                continue;
            }
            let (mut pos, mut neg) = (Vec::new(), Vec::new());
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
                    let c = crossing(mesh, &mut report, a, b);
                    pos.push(c);
                    neg.push(c);
                }
            }
            let f_pos = r.face;
            mesh.faces[f_pos as usize] = Face { vertices: pos, triangles: Vec::new() };
            let f_neg = mesh.faces.len() as u32;
            mesh.faces.push(Face { vertices: neg, triangles: Vec::new() });
            mesh.triangulate_face(f_pos as usize);
            mesh.triangulate_face(f_neg as usize);
            face_parts.insert(r.face, (f_pos, f_neg));
        }
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
        let mut new_refs = Vec::with_capacity(refs.len() + 2);
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
        mesh.refresh_element_nodes(e);
        report.repaired_elements.push(e as u32);
    }
    // 3. split the elements
    let (u, w) = plane_basis(n);
    for &e in &crossed {
        let refs = mesh.elements[e].faces.clone();
        let (mut pos_faces, mut neg_faces) = (Vec::new(), Vec::new());
        let mut cap_points: Vec<u32> = Vec::new();
        for r in &refs {
            if let Some(&(fp, fneg)) = face_parts.get(&r.face) {
                pos_faces.push(FaceRef { face: fp, outward: r.outward });
                neg_faces.push(FaceRef { face: fneg, outward: r.outward });
                cap_points.extend(
                    mesh.faces[fp as usize]
                        .vertices
                        .iter()
                        .filter(|&&x| (x as usize) >= side.len() || side[x as usize] == 0),
                );
                continue;
            }
            let v = &mesh.faces[r.face as usize].vertices;
            cap_points.extend(v.iter().filter(|&&x| side[x as usize] == 0));
            if v.iter().any(|&x| side[x as usize] > 0) {
                pos_faces.push(*r);
            } else if v.iter().any(|&x| side[x as usize] < 0) {
                neg_faces.push(*r);
            } else {
                return Err(SplitError::NonConvexElement { element: e, face: r.face as usize });
            }
        }
        cap_points.sort_unstable();
        cap_points.dedup();
        if cap_points.len() < 3 {
            return Err(SplitError::DegenerateCap { element: e });
        }
        // order the cap counter-clockwise about +n
        let c = scale(
            cap_points.iter().fold([0.0; 3], |acc, &p| cleave_kernels::vec3::add(acc, mesh.nodes[p as usize])),
            1.0 / cap_points.len() as f64,
        );
        let angle = |p: u32| {
            let d = sub(mesh.nodes[p as usize], c);
            dot(d, w).atan2(dot(d, u))
        };
        cap_points.sort_by(|&a, &b| angle(a).total_cmp(&angle(b)));
        let cap = mesh.faces.len() as u32;
        mesh.faces.push(Face { vertices: cap_points, triangles: Vec::new() });
        mesh.triangulate_face(cap as usize);
        // the cap's normal is +n: it points out of the negative part
        pos_faces.push(FaceRef { face: cap, outward: false });
        neg_faces.push(FaceRef { face: cap, outward: true });
        mesh.elements[e].faces = pos_faces;
        mesh.refresh_element_nodes(e);
        let ne = mesh.elements.len();
        mesh.elements.push(crate::mesh::Element { faces: neg_faces, nodes: Vec::new() });
        mesh.refresh_element_nodes(ne);
        report.split_elements.push((e as u32, ne as u32));
        report.caps.push(cap);
    }
    Ok(report)
}

/// The [`quality`] of the positive and the negative part that splitting
/// element `e` would make, from the same vertices and edge crossings the
/// split uses. Each part's volume is the sum over its clipped faces of the
/// cones from a point on the cap (the cap itself adds nothing).
fn part_qualities(mesh: &PolyMesh, e: usize, dist: &[f64], side: &[i8], on_plane: [f64; 3]) -> [f64; 2] {
    let el = &mesh.elements[e];
    let mut volume = [0.0; 2];
    let mut points: [Vec<[f64; 3]>; 2] = [Vec::new(), Vec::new()];
    let mut lp = Vec::new();
    for (p, sign) in [1i8, -1].into_iter().enumerate() {
        for r in &el.faces {
            let v = &mesh.faces[r.face as usize].vertices;
            lp.clear();
            for i in 0..v.len() {
                let (a, b) = (v[i] as usize, v[(i + 1) % v.len()] as usize);
                if side[a] * sign >= 0 {
                    lp.push(mesh.nodes[a]);
                }
                if side[a] * side[b] < 0 {
                    lp.push(lerp(mesh.nodes[a], mesh.nodes[b], dist[a] / (dist[a] - dist[b])));
                }
            }
            if !r.outward {
                lp.reverse();
            }
            for i in 1..lp.len().saturating_sub(1) {
                volume[p] += cleave_kernels::tet::signed_volume(on_plane, lp[0], lp[i], lp[i + 1]);
            }
            points[p].extend_from_slice(&lp);
        }
    }
    [0, 1].map(|p| quality(volume[p], diameter(&points[p])))
}

/// The largest distance (m) from a plane at which a split may take a node
/// to lie on it: `snap` times the mesh's bounding box diagonal, which no
/// edge exceeds.
pub(crate) fn snap_band(mesh: &PolyMesh, opts: &SplitOptions) -> f64 {
    let (lo, hi) = mesh.bounding_box();
    opts.snap * norm(sub(hi, lo))
}

/// Two unit vectors `(u, w)` with `(u, w, n)` right-handed.
pub(crate) fn plane_basis(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let a = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let u = cross(a, n);
    let u = scale(u, 1.0 / norm(u));
    (u, cross(n, u))
}
