//! Progressive cuts with a planar polygon (wicke2007 §5.2).
//!
//! 1. The elements that the polygon's plane crosses and whose section
//!    overlaps the polygon are split locally (their neighbours repaired).
//! 2. The faces in the plane (the caps, and interior faces that already lay
//!    in it and meet the polygon) are split along the lines of the
//!    polygon's edges, so each lies inside or outside the polygon; the new
//!    nodes join every face on their edge.
//! 3. Nodes strictly inside the polygon are duplicated and the faces inside
//!    it separated ([`super::cut`]'s separation): the material opens only
//!    where it was cut. Where no node lies inside, a node at the polygon's
//!    centroid fans the cap face around it and makes a pocket.
//!
//! The polygon must be convex and planar; positions are in the rest frame.

use rustc_hash::FxHashMap as HashMap;

use cleave_kernels::vec3::{add, cross, dot, lerp, norm, scale, sub};
use rayon::prelude::*;
use smallvec::SmallVec;

use super::cut::{cut_region, element_sides, separate, CutReport};
use super::split::{
    classify, on_plane_band, plane_basis, split_classified, Classification, NewNode, SplitError, SplitOptions, ON_PLANE,
};
use super::CutScope;
use crate::mesh::Plane;
use crate::mesh::{face_geometry, Face, FaceLoop, FaceRef, PolyMesh};

/// What a polygon cut changed, beyond a plane cut's report.
#[derive(Clone, Debug, PartialEq)]
pub struct PolygonCutReport {
    /// Split, new edge nodes (including those on the polygon's edge lines),
    /// duplicated nodes and touched elements.
    pub cut: CutReport,
    /// The pocket node and the face vertices it was placed among (its state
    /// is their mean), when one was needed.
    pub pocket: Option<(u32, Vec<u32>)>,
}

/// The elements using a face: at most two in a valid mesh (a third is
/// [`crate::mesh::MeshError::FaceSharedByMoreThanTwo`]), kept without a
/// heap list of their own.
#[derive(Clone, Copy, Debug, Default)]
struct FaceUsers {
    ids: [u32; 2],
    len: u8,
}

impl FaceUsers {
    fn push(&mut self, e: u32) {
        if let Some(slot) = self.ids.get_mut(self.len as usize) {
            *slot = e;
            self.len += 1;
        }
    }

    fn as_slice(&self) -> &[u32] {
        &self.ids[..self.len as usize]
    }
}

/// 2-D frame of the polygon's plane.
struct Frame {
    origin: [f64; 3],
    u: [f64; 3],
    w: [f64; 3],
}

impl Frame {
    fn project(&self, x: [f64; 3]) -> [f64; 2] {
        let d = sub(x, self.origin);
        [dot(d, self.u), dot(d, self.w)]
    }
}

/// Signed distance of `p` from the line through `a`, `b`, positive on the
/// left (the inside of a counter-clockwise polygon).
fn side_of(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> f64 {
    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
    let len = (ex * ex + ey * ey).sqrt();
    (ex * (p[1] - a[1]) - ey * (p[0] - a[0])) / len
}

/// Whether two convex polygons (any orientation) overlap, by separating
/// axes; touching counts as overlapping.
fn convex_overlap(a: &[[f64; 2]], b: &[[f64; 2]]) -> bool {
    for poly in [a, b] {
        for i in 0..poly.len() {
            let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
            let axis = [q[1] - p[1], p[0] - q[0]];
            let range = |pts: &[[f64; 2]]| {
                pts.iter()
                    .map(|x| x[0] * axis[0] + x[1] * axis[1])
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)))
            };
            let ((a0, a1), (b0, b1)) = (range(a), range(b));
            if a1 < b0 || b1 < a0 {
                return false;
            }
        }
    }
    true
}

/// Counter-clockwise convex hull order of points (by angle about their
/// mean, measured by a pseudo-angle that grows with it: `dx / (|dx| + |dy|)`
/// mapped onto `[0, 4)`, which orders like `atan2` without calling it).
fn ccw(points: &mut [[f64; 2]]) {
    let n = points.len() as f64;
    let c = points.iter().fold([0.0, 0.0], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
    let angle = |p: &[f64; 2]| {
        let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
        let t = dx / (dx.abs() + dy.abs());
        match (dy >= 0.0, t.is_nan()) {
            (_, true) => 0.0,
            (true, false) => 1.0 - t,
            (false, false) => 3.0 + t,
        }
    };
    points.sort_by(|p, q| angle(p).total_cmp(&angle(q)));
}

/// The plane of a cut polygon: through its vertex mean, with the unit
/// normal of its area vector (the polygon's vertices run counter-clockwise
/// about it). Fails unless the polygon has at least 3 finite vertices, an
/// area and lies in that plane.
pub fn polygon_plane(polygon: &[[f64; 3]]) -> Result<Plane, SplitError> {
    let n_pts = polygon.len();
    if n_pts < 3 || !polygon.iter().flatten().all(|x| x.is_finite()) {
        return Err(SplitError::InvalidPolygon("needs at least 3 finite points".into()));
    }
    let centroid = scale(polygon.iter().fold([0.0; 3], |m, p| add(m, *p)), 1.0 / n_pts as f64);
    let mut area = [0.0; 3];
    for i in 0..n_pts {
        area = add(area, cross(sub(polygon[i], centroid), sub(polygon[(i + 1) % n_pts], centroid)));
    }
    let len = norm(area);
    let size = polygon.iter().map(|p| norm(sub(*p, centroid))).fold(0.0, f64::max);
    if !(len > 1e-12 * size * size) {
        return Err(SplitError::InvalidPolygon("has no area".into()));
    }
    let normal = scale(area, 1.0 / len);
    if polygon.iter().any(|p| dot(sub(*p, centroid), normal).abs() > 1e-6 * size) {
        return Err(SplitError::InvalidPolygon("is not planar".into()));
    }
    Ok(Plane { point: centroid, normal })
}

/// Cuts `mesh` with the convex planar polygon `polygon` (see module docs).
pub fn cut_by_polygon(
    mesh: &mut PolyMesh,
    polygon: &[[f64; 3]],
    opts: &SplitOptions,
) -> Result<PolygonCutReport, SplitError> {
    cut_by_polygon_keeping(mesh, polygon, opts, &[], CutScope::whole())
}

/// [`cut_by_polygon`] leaving the sorted `keep_whole` elements as they
/// are: not split, given no new node, their faces in the plane not split
/// along the polygon's edges nor given a pocket; only the elements in
/// `scope` are looked at.
pub fn cut_by_polygon_keeping(
    mesh: &mut PolyMesh,
    polygon: &[[f64; 3]],
    opts: &SplitOptions,
    keep_whole: &[u32],
    scope: CutScope,
) -> Result<PolygonCutReport, SplitError> {
    let plan = plan_polygon_cut(mesh, polygon, opts, keep_whole, scope)?;
    cut_as_planned(mesh, plan, opts, keep_whole, scope)
}

/// What a polygon cut decides before it changes the mesh: the polygon's
/// plane, its 2-D frame and outline, and which elements to split.
pub(crate) struct PolygonPlan {
    plane: Plane,
    frame: Frame,
    /// The polygon's counter-clockwise outline in `frame`.
    outline: Vec<[f64; 2]>,
    /// The polygon's largest distance from its centroid (m).
    size: f64,
    classification: Classification,
}

/// The read-only part of [`cut_by_polygon_keeping`]: checks the polygon and
/// classifies the elements its plane crosses whose section overlaps it.
pub(crate) fn plan_polygon_cut(
    mesh: &PolyMesh,
    polygon: &[[f64; 3]],
    opts: &SplitOptions,
    keep_whole: &[u32],
    scope: CutScope,
) -> Result<PolygonPlan, SplitError> {
    // the polygon's plane and its counter-clockwise 2-D outline
    let plane = polygon_plane(polygon)?;
    let (n_pts, centroid, normal) = (polygon.len(), plane.point, plane.normal);
    let size = polygon.iter().map(|p| norm(sub(*p, centroid))).fold(0.0, f64::max);
    let (u, w) = plane_basis(normal);
    let frame = Frame { origin: centroid, u, w };
    let outline: Vec<[f64; 2]> = polygon.iter().map(|p| frame.project(*p)).collect();
    for i in 0..n_pts {
        if side_of(outline[i], outline[(i + 1) % n_pts], outline[(i + 2) % n_pts]) <= 0.0 {
            return Err(SplitError::InvalidPolygon("is not convex".into()));
        }
    }
    let dist = |x: [f64; 3]| plane.distance(x);

    // 1. split the crossed elements whose section overlaps the polygon
    let node_dist = plane.distances(&mesh.nodes);
    // (each element's test is independent: run in parallel)
    let candidates: Vec<usize> = scope.elements(mesh).collect();
    let chosen: Vec<u32> = candidates
        .into_par_iter()
        .map_init(Vec::new, |section, e| {
            let el = &mesh.elements[e];
            let d = el.nodes.iter().map(|&v| node_dist[v as usize]);
            if !(d.clone().any(|x| x > 0.0) && d.clone().any(|x| x < 0.0)) {
                return None;
            }
            // the section: crossings of the element's edges and vertices on the plane
            section.clear();
            for r in &el.faces {
                let lp = &mesh.faces[r.face as usize].vertices;
                for i in 0..lp.len() {
                    let (a, b) = (mesh.nodes[lp[i] as usize], mesh.nodes[lp[(i + 1) % lp.len()] as usize]);
                    let (da, db) = (dist(a), dist(b));
                    if da == 0.0 {
                        section.push(frame.project(a));
                    } else if da * db < 0.0 {
                        section.push(frame.project(lerp(a, b, da / (da - db))));
                    }
                }
            }
            let overlaps = section.len() >= 3 && {
                ccw(section);
                convex_overlap(section, &outline)
            };
            overlaps.then_some(e as u32)
        })
        .flatten()
        .collect();
    let classification = classify(mesh, &plane, Some(&chosen), keep_whole, opts, scope)?;
    Ok(PolygonPlan { plane, frame, outline, size, classification })
}

/// The part of [`cut_by_polygon_keeping`] that changes the mesh, as
/// [`plan_polygon_cut`] planned it on this `mesh` (unchanged since).
pub(crate) fn cut_as_planned(
    mesh: &mut PolyMesh,
    plan: PolygonPlan,
    opts: &SplitOptions,
    keep_whole: &[u32],
    scope: CutScope,
) -> Result<PolygonCutReport, SplitError> {
    let PolygonPlan { plane, frame, outline, size, classification } = plan;
    let n_pts = outline.len();
    let dist = |x: [f64; 3]| plane.distance(x);
    let nodes_before = mesh.nodes.len();
    let split = split_classified(mesh, &plane, classification)?;
    let protected = |e: &u32| keep_whole.binary_search(e).is_ok();
    let mut new_nodes = split.new_nodes.clone();

    // 2. the faces in the plane and who uses them, all within the region of
    // the elements near the plane or the elements it crossed (every face in
    // the plane, around a face in it or of a crossed element is one of
    // theirs); an element kept whole (a part would have been a sliver) is
    // cut around: its faces towards the other side take the place of the
    // cap it did not get
    let band = on_plane_band(mesh);
    let region = cut_region(mesh, &plane, &split, scope);
    // (read-only passes over the region, waiting on memory: the faces and
    // their users beside the elements' sides and snapping radii)
    let ((region_faces, mut users), (side, mut line_snap)) = rayon::join(
        || {
            let mut region_faces: Vec<u32> =
                region.iter().flat_map(|&e| mesh.elements[e as usize].faces.iter().map(|r| r.face)).collect();
            region_faces.sort_unstable();
            region_faces.dedup();
            let mut users: HashMap<u32, FaceUsers> = HashMap::default();
            users.reserve(region_faces.len());
            for &e in &region {
                for r in &mesh.elements[e as usize].faces {
                    users.entry(r.face).or_default().push(e);
                }
            }
            (region_faces, users)
        },
        || {
            // a vertex closer to a polygon edge's line than `snap` times the
            // largest element around it lies on the line: a face is then
            // split along a chord through it instead of next to it (the
            // parts stay planar and convex, only the cut's outline strays
            // from the line), so no node is made closer than that to a node
            // of an element on its edge
            let mut line_snap: HashMap<u32, f64> = HashMap::default();
            for &e in &region {
                let r = opts.snap * mesh.element_diameter(e as usize);
                for &v in &mesh.elements[e as usize].nodes {
                    let entry = line_snap.entry(v).or_insert(r);
                    *entry = entry.max(r);
                }
            }
            (element_sides(mesh, &plane, &region, &split), line_snap)
        },
    );
    let mut in_plane: Vec<u32> = split.caps.clone();
    let mut listed = vec![false; mesh.faces.len()];
    in_plane.iter().for_each(|&f| listed[f as usize] = true);
    let mut detour: Vec<u32> = Vec::new();
    for &e in &split.kept_whole {
        for r in &mesh.elements[e as usize].faces {
            let across = users[&r.face].as_slice().iter().any(|&o| side[o as usize] != side[e as usize]);
            if across && !listed[r.face as usize] {
                listed[r.face as usize] = true;
                in_plane.push(r.face);
                detour.push(r.face);
            }
        }
    }
    // a node lies on the plane when the split took it to (snapped), made it,
    // or it lies within the rounding band of it (a former cut's)
    let first_new = mesh.nodes.len() as u32 - split.new_nodes.len() as u32;
    let on_plane = |mesh: &PolyMesh, v: u32| {
        v >= first_new || split.on_plane.binary_search(&v).is_ok() || dist(mesh.nodes[v as usize]).abs() <= band
    };
    // (a face in the plane that does not meet the polygon has nothing to
    // open, nor any reason to be split along its edges' lines)
    let meets_polygon = |mesh: &PolyMesh, lp: &[u32]| {
        let loop2: Vec<[f64; 2]> = lp.iter().map(|&v| frame.project(mesh.nodes[v as usize])).collect();
        convex_overlap(&loop2, &outline)
    };
    // (each face's test reads only the mesh: in parallel, in order)
    let met: Vec<u32> = region_faces
        .par_iter()
        .copied()
        .filter(|&f| {
            let face = &mesh.faces[f as usize];
            !listed[f as usize]
                && users[&f].len == 2
                && face.vertices.iter().all(|&v| on_plane(mesh, v))
                && meets_polygon(mesh, &face.vertices)
        })
        .collect();
    met.iter().for_each(|&f| listed[f as usize] = true);
    in_plane.extend(met);
    // faces touching each node of the plane (stale entries are re-checked;
    // inline lists: a blade cut across bunny_100k lists 3,000 nodes, whose
    // heap lists took a third of this map's 0.95 ms), found in parallel
    // and listed in order
    let plane_vertices: rustc_hash::FxHashSet<u32> =
        in_plane.iter().flat_map(|&f| mesh.faces[f as usize].vertices.iter().copied()).collect();
    let touching: Vec<(u32, u32)> = region_faces
        .par_iter()
        .flat_map_iter(|&f| {
            let vertices = &mesh.faces[f as usize].vertices;
            vertices.iter().filter(|&v| plane_vertices.contains(v)).map(move |&v| (v, f))
        })
        .collect();
    let mut node_faces: HashMap<u32, SmallVec<[u32; 16]>> = HashMap::default();
    touching.into_iter().for_each(|(v, f)| node_faces.entry(v).or_default().push(f));
    let mut edge_node: HashMap<(u32, u32), u32> = HashMap::default();
    let mut touched_faces: Vec<u32> = Vec::new();
    // (the face's loop and its vertices' sides, reused from face to face)
    let (mut lp, mut s): (FaceLoop, Vec<i8>) = (FaceLoop::new(), Vec::new());
    for i in 0..n_pts {
        let (a2, b2) = (outline[i], outline[(i + 1) % n_pts]);
        let mut k = 0;
        while k < in_plane.len() {
            let f = in_plane[k] as usize;
            k += 1;
            lp.clone_from(&mesh.faces[f].vertices);
            s.clear();
            s.extend(lp.iter().map(|&v| {
                let d = side_of(a2, b2, frame.project(mesh.nodes[v as usize]));
                // (nodes made here lie on the line up to rounding)
                if d.abs() <= line_snap.get(&v).copied().unwrap_or(0.0).max(ON_PLANE * size) {
                    0
                } else if d > 0.0 {
                    1
                } else {
                    -1
                }
            }));
            // a proper crossing of a convex face has exactly two cut points
            // (vertices on the line, or sign changes); anything else is the
            // line grazing the face within the snapping distance
            let cuts = (0..s.len()).filter(|&j| s[j] == 0 || s[j] * s[(j + 1) % s.len()] < 0).count();
            let along_edge = (0..s.len()).any(|j| s[j] == 0 && s[(j + 1) % s.len()] == 0);
            if !(s.contains(&1) && s.contains(&-1)) || cuts != 2 || along_edge {
                continue;
            }
            // an element kept as it is keeps its faces and edges
            let guarded = |g: u32| users.get(&g).is_some_and(|u| u.as_slice().iter().any(protected));
            let crossed_guarded = (0..lp.len()).filter(|&j| s[j] * s[(j + 1) % lp.len()] < 0).any(|j| {
                let (va, vb) = (lp[j], lp[(j + 1) % lp.len()]);
                node_faces
                    .get(&va)
                    .is_some_and(|fs| fs.iter().any(|&g| mesh.faces[g as usize].vertices.contains(&vb) && guarded(g)))
            });
            if guarded(f as u32) || crossed_guarded {
                continue;
            }
            let (mut inside, mut outside) = (FaceLoop::new(), FaceLoop::new());
            for j in 0..lp.len() {
                let (va, vb) = (lp[j], lp[(j + 1) % lp.len()]);
                let (sa, sb) = (s[j], s[(j + 1) % lp.len()]);
                if sa >= 0 {
                    inside.push(va);
                }
                if sa <= 0 {
                    outside.push(va);
                }
                if sa * sb < 0 {
                    let key = (va.min(vb), va.max(vb));
                    let c = *edge_node.entry(key).or_insert_with(|| {
                        let (pa, pb) = (mesh.nodes[key.0 as usize], mesh.nodes[key.1 as usize]);
                        let (da, db) = (side_of(a2, b2, frame.project(pa)), side_of(a2, b2, frame.project(pb)));
                        let t = da / (da - db);
                        let x = lerp(pa, pb, t);
                        let id = mesh.nodes.len() as u32;
                        mesh.nodes.push(x);
                        new_nodes.push(NewNode { id, a: key.0, b: key.1, t });
                        id
                    });
                    // a node on an edge lies on a later line wherever both
                    // ends of its edge do
                    let radius = |v: u32| line_snap.get(&v).copied().unwrap_or(0.0);
                    let r = radius(va).max(radius(vb));
                    line_snap.entry(c).or_insert(r);
                    inside.push(c);
                    outside.push(c);
                    // the new node joins every other face on this edge
                    for g in node_faces.get(&va).cloned().unwrap_or_default() {
                        if g as usize == f {
                            continue;
                        }
                        if mesh.faces[g as usize].insert_on_edge(va, vb, c) {
                            node_faces.entry(c).or_default().push(g);
                            touched_faces.push(g);
                        }
                    }
                    node_faces.entry(c).or_default().push(f as u32);
                }
            }
            mesh.faces[f] = Face { vertices: inside, triangles: Default::default() };
            mesh.triangulate_face(f);
            let g = mesh.faces.len() as u32;
            for &v in &outside {
                node_faces.entry(v).or_default().push(g);
            }
            mesh.faces.push(Face { vertices: outside, triangles: Default::default() });
            mesh.triangulate_face(g as usize);
            let face_users = users.get(&(f as u32)).copied().unwrap_or_default();
            for &e in face_users.as_slice() {
                let r = mesh.elements[e as usize].faces.iter().find(|r| r.face as usize == f).copied();
                if let Some(r) = r {
                    mesh.elements[e as usize].faces.push(FaceRef { face: g, outward: r.outward });
                }
            }
            users.insert(g, face_users);
            touched_faces.push(f as u32);
            in_plane.push(g);
        }
    }
    // 3. inside faces, nodes strictly inside, a pocket if none
    let inside_polygon =
        |p: [f64; 2], margin: f64| (0..n_pts).all(|i| side_of(outline[i], outline[(i + 1) % n_pts], p) > margin);
    let face_centre =
        |mesh: &PolyMesh, f: u32| frame.project(face_geometry(&mesh.nodes, &mesh.faces[f as usize].vertices).centroid);
    let tol = ON_PLANE * size;
    let mut inside_faces: Vec<u32> =
        in_plane.iter().copied().filter(|&f| inside_polygon(face_centre(mesh, f), -tol)).collect();
    let node_inside = |mesh: &PolyMesh, v: u32| inside_polygon(frame.project(mesh.nodes[v as usize]), tol);
    let mut pocket = None;
    let has_inner = inside_faces.iter().any(|&f| mesh.faces[f as usize].vertices.iter().any(|&v| node_inside(mesh, v)));
    if !has_inner {
        // the pocket node goes to the vertex mean of the face in the plane
        // (inside the polygon) that leaves it the most room, and only where
        // it keeps `min_spacing` of the elements around it from its nodes
        let clearance = |mesh: &PolyMesh, f: u32| {
            // at the mean of the face's vertices, so that its state, their
            // mean, is the field's value there
            let lp = &mesh.faces[f as usize].vertices;
            let c = scale(lp.iter().fold([0.0; 3], |s, &v| add(s, mesh.nodes[v as usize])), 1.0 / lp.len() as f64);
            let c2 = frame.project(c);
            let mut pts: Vec<[f64; 2]> = lp.iter().map(|&v| frame.project(mesh.nodes[v as usize])).collect();
            ccw(&mut pts);
            let room =
                (0..pts.len()).map(|i| side_of(pts[i], pts[(i + 1) % pts.len()], c2)).fold(f64::INFINITY, f64::min);
            let size =
                users[&f].as_slice().iter().map(|&e| mesh.element_diameter(e as usize)).fold(f64::INFINITY, f64::min);
            (room / size, c)
        };
        let host = inside_faces
            .iter()
            .copied()
            .filter(|f| !detour.contains(f) && mesh.faces[*f as usize].vertices.iter().all(|&v| on_plane(mesh, v)))
            .filter(|f| !users[f].as_slice().iter().any(protected))
            .map(|f| (f, clearance(mesh, f)))
            .filter(|(_, (room, _))| *room >= opts.min_spacing)
            .max_by(|a, b| a.1 .0.total_cmp(&b.1 .0));
        if let Some((f, (_, position))) = host {
            let lp = mesh.faces[f as usize].vertices.to_vec();
            let c = mesh.nodes.len() as u32;
            mesh.nodes.push(position);
            let fan: Vec<u32> = (0..lp.len())
                .map(|i| {
                    let tri: FaceLoop = smallvec::smallvec![c, lp[i], lp[(i + 1) % lp.len()]];
                    if i == 0 {
                        mesh.faces[f as usize] = Face { vertices: tri, triangles: Default::default() };
                        mesh.triangulate_face(f as usize);
                        f
                    } else {
                        let g = mesh.faces.len() as u32;
                        mesh.faces.push(Face { vertices: tri, triangles: Default::default() });
                        mesh.triangulate_face(g as usize);
                        g
                    }
                })
                .collect();
            for &e in users.get(&f).copied().unwrap_or_default().as_slice() {
                if let Some(r) = mesh.elements[e as usize].faces.iter().find(|r| r.face == f).copied() {
                    for &g in &fan[1..] {
                        mesh.elements[e as usize].faces.push(FaceRef { face: g, outward: r.outward });
                    }
                }
            }
            inside_faces.extend(&fan[1..]);
            touched_faces.extend(&fan);
            pocket = Some((c, lp));
        }
    }
    // every element on a touched face gets its node list refreshed (the
    // split's parts and the elements it repaired have theirs already)
    let mut refreshed: Vec<u32> = Vec::new();
    for f in &touched_faces {
        refreshed.extend(users.get(f).copied().unwrap_or_default().as_slice());
    }
    refreshed.sort_unstable();
    refreshed.dedup();
    mesh.refresh_elements_nodes(&refreshed);
    let parts = split.split_elements.iter().flat_map(|&(a, b)| [a, b]);
    let mut touched: Vec<u32> = parts.chain(split.repaired_elements.iter().copied()).chain(refreshed).collect();
    touched.sort_unstable();
    touched.dedup();
    inside_faces.sort_unstable();
    // a node opens when it lies strictly inside (and, by `separate`, on no
    // face of the plane left joined outside the polygon)
    let mut inner = vec![false; mesh.nodes.len()];
    for &f in &inside_faces {
        for &v in &mesh.faces[f as usize].vertices {
            inner[v as usize] = node_inside(mesh, v);
        }
    }
    let (duplicated, renamed) = separate(
        mesh,
        &region,
        &side,
        |v| inner.get(v as usize).copied().unwrap_or(false),
        |f| inside_faces.binary_search(&f).is_ok(),
    );
    touched.extend(renamed);
    touched.sort_unstable();
    touched.dedup();
    let split = super::split::SplitReport { new_nodes, ..split };
    let cut = CutReport::new(mesh, plane, nodes_before, split, duplicated, touched);
    Ok(PolygonCutReport { cut, pocket })
}
