//! Removing sliver tetrahedra (wicke2007 §4).
//!
//! A sliver is a tetrahedron whose four corners lie almost in a plane, with
//! no short edge ([`crate::mesh::quality`] below a threshold). Cuts never
//! make one (see [`super::split`]), but tetrahedral meshes from files can
//! hold some. A sliver is merged away, without remeshing:
//!
//! 1. its corners are projected onto their least-squares plane (the sliver
//!    plane), so it has no volume left;
//! 2. its faces towards the normal (upper) and away from it (lower) now
//!    both tile the same planar region; that region is retessellated into
//!    the cells of the two tilings' overlay, each cell becoming a face
//!    between the element above and the one below:
//!    - two upper and two lower faces (the corners form a quadrilateral
//!      whose diagonals are the upper and the lower shared edge): one new
//!      node where the diagonals cross, joined into every face on those
//!      edges, and four triangles around it;
//!    - one face on one side and three on the other (a corner inside the
//!      triangle of the others): the three faces, now also bounding the
//!      element across the single face;
//! 3. the sliver is deleted.
//!
//! The neighbours keep their shapes up to the projection (at most the
//! sliver's thickness); the total volume is unchanged when no corner lies
//! on the boundary (a corner on it moves the surface by at most that
//! thickness). A merge after which a neighbour is invalid, not convex, or
//! below the threshold and flatter than before is undone, so the worst
//! quality in the mesh never drops; merging one sliver of a cluster can
//! free another, so the sweeps repeat until one merges nothing.

use cleave_kernels::vec3::{add, cross, dot, norm, scale, sub};
use faer::{Mat, Side};

use super::rollback::Rollback;
use crate::mesh::Plane;
use crate::mesh::{face_geometry, Face, FaceLoop, FaceRef, MeshError, PolyMesh, ValidationOptions};

/// What [`merge_slivers`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SliverReport {
    /// Slivers merged away.
    pub merged: usize,
    /// Nodes created where diagonals crossed.
    pub new_nodes: usize,
    /// Slivers left, with their quality and the reason (ids after the
    /// merge's renumbering are not kept; these are ids before it).
    pub left: Vec<(u32, f64, &'static str)>,
}

/// Merges away every tetrahedron of quality below `min_quality` that can be
/// (see the module docs), then drops the deleted elements and unused nodes
/// and faces (elements and nodes are renumbered). Positions are rest
/// positions; call it before a simulation is built on the mesh.
pub fn merge_slivers(mesh: &mut PolyMesh, min_quality: f64) -> Result<SliverReport, MeshError> {
    let mut report = SliverReport::default();
    let mut deleted = vec![false; mesh.elements.len()];
    // merging one sliver of a cluster can flatten its neighbours further:
    // sweep until a sweep merges nothing
    loop {
        let mut slivers: Vec<(u32, f64)> = (0..mesh.elements.len())
            .filter(|&e| !deleted[e] && mesh.elements[e].nodes.len() == 4)
            .map(|e| (e as u32, mesh.element_quality(e)))
            .filter(|&(_, q)| q < min_quality)
            .collect();
        slivers.sort_by(|a, b| a.1.total_cmp(&b.1));
        report.left.clear();
        let merged_before = report.merged;
        for &(s, q) in &slivers {
            let e = s as usize;
            // an earlier merge of this sweep may have changed it
            if mesh.elements[e].nodes.len() != 4 || mesh.element_quality(e) >= min_quality {
                continue;
            }
            let corners = mesh.elements[e].nodes.clone();
            let rollback = Rollback::around_nodes(mesh, &corners);
            let around: Vec<usize> = rollback.elements().iter().map(|&x| x as usize).filter(|&x| x != e).collect();
            let before: Vec<f64> = around.iter().map(|&x| mesh.element_quality(x)).collect();
            let nodes_before = mesh.nodes.len();
            let outcome = merge_one(mesh, e, &around).and_then(|()| {
                mesh.check_elements(&around, &ValidationOptions::default())
                    .map_err(|_| "a neighbour became invalid")?;
                for (&x, &q0) in around.iter().zip(&before) {
                    if !mesh.is_convex(x, 1e-6) {
                        return Err("a neighbour became non-convex");
                    }
                    // no neighbour may become a sliver, nor a sliver
                    // neighbour flatter (it may no longer be mergeable)
                    if mesh.element_quality(x) < q0.min(min_quality) {
                        return Err("a neighbour would become flatter");
                    }
                }
                Ok(())
            });
            match outcome {
                Ok(()) => {
                    report.merged += 1;
                    report.new_nodes += mesh.nodes.len() - nodes_before;
                    deleted[e] = true;
                }
                Err(why) => {
                    rollback.restore(mesh);
                    report.left.push((s, q, why));
                }
            }
        }
        if report.merged == merged_before {
            break;
        }
    }
    // slivers no longer tetrahedra (a merge put a node on one of their edges)
    for e in (0..mesh.elements.len()).filter(|&e| !deleted[e] && mesh.elements[e].nodes.len() != 4) {
        let q = mesh.element_quality(e);
        if q < min_quality {
            report.left.push((e as u32, q, "not a tetrahedron any more"));
        }
    }
    if report.merged > 0 {
        let kept: Vec<usize> = (0..mesh.elements.len()).filter(|&e| !deleted[e]).collect();
        *mesh = mesh.extract(&kept)?.0;
    }
    Ok(report)
}

/// Merges sliver `e` away; `around` are the other elements holding one of
/// its corners (its neighbours among them). On error the mesh is left half
/// changed for the caller to roll back.
fn merge_one(mesh: &mut PolyMesh, e: usize, around: &[usize]) -> Result<(), &'static str> {
    let refs = mesh.elements[e].faces.clone();
    if refs.len() != 4 || refs.iter().any(|r| mesh.faces[r.face as usize].vertices.len() != 3) {
        return Err("not a tetrahedron of four triangles");
    }
    let corners = mesh.elements[e].nodes.clone();
    let plane = sliver_plane(mesh, &corners)?;
    let normal = plane.normal;
    // faces towards the normal and away from it, by their outward normals
    let (mut upper, mut lower) = (Vec::new(), Vec::new());
    for r in &refs {
        let g = face_geometry(&mesh.nodes, &mesh.faces[r.face as usize].vertices);
        let out = if r.outward { g.normal } else { scale(g.normal, -1.0) };
        match dot(out, normal) {
            c if c > 1e-3 => upper.push(*r),
            c if c < -1e-3 => lower.push(*r),
            _ => return Err("a face stands perpendicular to the sliver plane"),
        }
    }
    // the element across each face of the sliver
    let across = |mesh: &PolyMesh, f: u32| -> Option<usize> {
        around.iter().copied().find(|&x| mesh.elements[x].faces.iter().any(|r| r.face == f))
    };
    for &v in &corners {
        let x = mesh.nodes[v as usize];
        mesh.nodes[v as usize] = sub(x, scale(normal, plane.distance(x)));
    }
    match (upper.len(), lower.len()) {
        (2, 2) => merge_quadrilateral(mesh, normal, &upper, &lower, around, &across)?,
        (3, 1) => merge_cap(mesh, lower[0], &upper, &across)?,
        (1, 3) => merge_cap(mesh, upper[0], &lower, &across)?,
        _ => return Err("the faces do not split two and two or three and one"),
    }
    mesh.elements[e].faces.clear();
    mesh.elements[e].nodes.clear();
    for &x in around {
        mesh.refresh_element_nodes(x);
    }
    Ok(())
}

/// The least-squares plane of `corners`: their mean and the unit normal of
/// least spread (the eigenvector of the smallest eigenvalue of their
/// covariance).
fn sliver_plane(mesh: &PolyMesh, corners: &[u32]) -> Result<Plane, &'static str> {
    let points: Vec<[f64; 3]> = corners.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let centre = scale(points.iter().fold([0.0; 3], |m, &p| add(m, p)), 1.0 / points.len() as f64);
    let covariance =
        Mat::<f64>::from_fn(3, 3, |i, j| points.iter().map(|p| (p[i] - centre[i]) * (p[j] - centre[j])).sum());
    let eigen = covariance.self_adjoint_eigen(Side::Lower).map_err(|_| "no least-squares plane")?;
    let u = eigen.U();
    let normal = [u[(0, 0)], u[(1, 0)], u[(2, 0)]];
    let len = norm(normal);
    if !(len > 0.5) {
        return Err("no least-squares plane");
    }
    Ok(Plane { point: centre, normal: scale(normal, 1.0 / len) })
}

/// The two nodes the two faces share.
fn shared_edge(mesh: &PolyMesh, a: FaceRef, b: FaceRef) -> Option<(u32, u32)> {
    let (va, vb) = (&mesh.faces[a.face as usize].vertices, &mesh.faces[b.face as usize].vertices);
    let common: Vec<u32> = va.iter().copied().filter(|v| vb.contains(v)).collect();
    (common.len() == 2).then(|| (common[0], common[1]))
}

/// Two upper and two lower faces: the corners form a quadrilateral whose
/// diagonals (the shared edge of each pair) cross at a new node; four
/// triangles around it replace the sliver's faces.
fn merge_quadrilateral(
    mesh: &mut PolyMesh,
    normal: [f64; 3],
    upper: &[FaceRef],
    lower: &[FaceRef],
    around: &[usize],
    across: &dyn Fn(&PolyMesh, u32) -> Option<usize>,
) -> Result<(), &'static str> {
    let (p, q) = shared_edge(mesh, upper[0], upper[1]).ok_or("the upper faces share no edge")?;
    let (r, t) = shared_edge(mesh, lower[0], lower[1]).ok_or("the lower faces share no edge")?;
    // where the diagonals cross: p + α (q - p) = r + β (t - r), in the plane
    let (x_p, x_q, x_r, x_t) =
        (mesh.nodes[p as usize], mesh.nodes[q as usize], mesh.nodes[r as usize], mesh.nodes[t as usize]);
    let (d1, d2, w) = (sub(x_q, x_p), sub(x_t, x_r), sub(x_r, x_p));
    let denom = dot(cross(d1, d2), normal);
    if denom.abs() <= 1e-9 * norm(d1) * norm(d2) {
        return Err("the diagonals are parallel");
    }
    let alpha = dot(cross(w, d2), normal) / denom;
    let beta = dot(cross(w, d1), normal) / denom;
    if !(0.01..=0.99).contains(&alpha) || !(0.01..=0.99).contains(&beta) {
        return Err("the diagonals cross near a corner");
    }
    let x = mesh.nodes.len() as u32;
    mesh.nodes.push(add(x_p, scale(d1, alpha)));
    // the new node joins every face on either diagonal
    let mut faces: Vec<u32> = around.iter().flat_map(|&e| mesh.elements[e].faces.iter().map(|r| r.face)).collect();
    faces.sort_unstable();
    faces.dedup();
    for &f in &faces {
        mesh.faces[f as usize].insert_on_edge(p, q, x);
        mesh.faces[f as usize].insert_on_edge(r, t, x);
    }
    // the four triangles around it, each between the upper and the lower
    // face holding its outer edge, replace those faces in their owners
    let owners: Vec<(FaceRef, Option<usize>)> = upper.iter().chain(lower).map(|&f| (f, across(mesh, f.face))).collect();
    let owner = |f: FaceRef| owners.iter().find(|(g, _)| g.face == f.face).and_then(|&(_, o)| o);
    for &(f, o) in &owners {
        if let Some(o) = o {
            mesh.elements[o].faces.retain(|r| r.face != f.face);
        }
    }
    for (u, w) in [(p, r), (r, q), (q, t), (t, p)] {
        let holds = |mesh: &PolyMesh, f: &FaceRef| {
            let v = &mesh.faces[f.face as usize].vertices;
            v.contains(&u) && v.contains(&w)
        };
        let up = *upper.iter().find(|f| holds(mesh, f)).ok_or("no upper face holds a side")?;
        let down = *lower.iter().find(|f| holds(mesh, f)).ok_or("no lower face holds a side")?;
        let mut tri: FaceLoop = smallvec::smallvec![u, w, x];
        let n = face_geometry(&mesh.nodes, &tri).normal;
        if dot(n, normal) < 0.0 {
            tri.reverse();
        }
        let cell = mesh.faces.len() as u32;
        mesh.faces.push(Face { vertices: tri, triangles: Default::default() });
        mesh.triangulate_face(cell as usize);
        // the cell's loop runs about +normal: outward for the element below
        for (old, outward) in [(up, false), (down, true)] {
            if let Some(o) = owner(old) {
                mesh.elements[o].faces.push(FaceRef { face: cell, outward });
            }
        }
    }
    Ok(())
}

/// One face `single` on one side and three `others` on the other: a corner
/// lies inside the triangle of the other three, so the three faces also
/// bound the element across `single`, which takes them in its place.
fn merge_cap(
    mesh: &mut PolyMesh,
    single: FaceRef,
    others: &[FaceRef],
    across: &dyn Fn(&PolyMesh, u32) -> Option<usize>,
) -> Result<(), &'static str> {
    let base = &mesh.faces[single.face as usize].vertices;
    let apex = others
        .iter()
        .flat_map(|f| mesh.faces[f.face as usize].vertices.iter().copied())
        .find(|v| !base.contains(v))
        .ok_or("no apex")?;
    // the apex must lie well inside the base triangle
    let g = face_geometry(&mesh.nodes, base);
    let area = |a: [f64; 3], b: [f64; 3], c: [f64; 3]| dot(cross(sub(b, a), sub(c, a)), g.normal) / 2.0;
    let x = mesh.nodes[apex as usize];
    let b: Vec<[f64; 3]> = base.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let whole = area(b[0], b[1], b[2]);
    for i in 0..3 {
        if area(b[i], b[(i + 1) % 3], x) < 0.01 * whole {
            return Err("the apex lies near an edge of the base");
        }
    }
    if let Some(owner) = across(mesh, single.face) {
        let refs = &mut mesh.elements[owner].faces;
        refs.retain(|r| r.face != single.face);
        // the owner lies where the sliver was: same orientations
        refs.extend(others.iter().copied());
    }
    Ok(())
}
