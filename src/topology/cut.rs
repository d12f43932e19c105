//! Cutting along a whole plane: split every element the plane crosses,
//! then separate the material on the plane by duplicating the nodes that
//! lie on it (wicke2007 §5.1 with §5.2's node duplication over the whole
//! plane).
//!
//! After the split every element lies on one side of the plane. A node
//! used by elements on both sides is duplicated: the elements on the
//! negative side take the copy, so the faces on the plane that the two
//! sides shared become two boundary faces and the body opens there.
//! Positions are in the mesh's rest (material) frame.

use super::split::{classify, on_plane_band, split_classified, Classification, SplitError, SplitOptions, SplitReport};
use super::CutScope;
use crate::mesh::Plane;
use crate::mesh::{Face, PolyMesh};
use rayon::slice::ParallelSliceMut;

/// What a plane cut changed: everything a simulation needs to bring its
/// element data, sparse pattern and node state up to date.
#[derive(Clone, Debug, PartialEq)]
pub struct CutReport {
    /// The cut's plane (rest frame).
    pub plane: Plane,
    /// The node count before the cut: nodes from this id on are new.
    pub nodes_before: u32,
    /// The split (new nodes on edges, split elements).
    pub split: SplitReport,
    /// `(original, copy)` for every duplicated node; the copy starts with
    /// the original's state.
    pub duplicated: Vec<(u32, u32)>,
    /// Every element whose faces or nodes changed, in increasing order.
    pub touched: Vec<u32>,
    /// The nodes the touched elements held before the cut, in increasing
    /// order (the columns of the sparse pattern the cut changes, and the
    /// nodes whose lumped masses it changes).
    pub old_nodes: Vec<u32>,
}

impl CutReport {
    /// The report of a cut along `plane` of a mesh that had `nodes_before`
    /// nodes and now is `mesh`: [`CutReport::old_nodes`] are the nodes of
    /// the touched elements now, each duplicate named by its original,
    /// less the nodes the cut made. (A cut only adds nodes to an element,
    /// renames them to their duplicates or hands them to the element's
    /// other part, which is touched too.)
    pub(crate) fn new(
        mesh: &PolyMesh,
        plane: Plane,
        nodes_before: usize,
        split: SplitReport,
        duplicated: Vec<(u32, u32)>,
        touched: Vec<u32>,
    ) -> Self {
        let nodes_before = nodes_before as u32;
        let mut original: rustc_hash::FxHashMap<u32, u32> = duplicated.iter().map(|&(o, c)| (c, o)).collect();
        original.retain(|_, o| *o < nodes_before);
        let mut old_nodes: Vec<u32> = touched
            .iter()
            .flat_map(|&e| mesh.elements[e as usize].nodes.iter())
            .filter_map(|v| if *v < nodes_before { Some(*v) } else { original.get(v).copied() })
            .collect();
        old_nodes.par_sort_unstable();
        old_nodes.dedup();
        CutReport { plane, nodes_before, split, duplicated, touched, old_nodes }
    }
}

/// The elements a separation along `plane` can involve, in increasing
/// order: those with a node on the plane (within [`on_plane_band`], or
/// taken to lie on it by `split`) or shared with an element `split` split or
/// kept whole. Every element holding a node that elements on both sides use
/// is among them: such a node lies on the plane, or on an element the plane
/// crossed. Only the elements in `scope` are looked at.
pub(crate) fn cut_region(mesh: &PolyMesh, plane: &Plane, split: &SplitReport, scope: CutScope) -> Vec<u32> {
    let band = on_plane_band(mesh);
    let mut marked: Vec<bool> = plane.distances(&mesh.nodes).iter().map(|d| d.abs() <= band).collect();
    split.on_plane.iter().for_each(|&v| marked[v as usize] = true);
    let crossed = split.split_elements.iter().flat_map(|&(a, b)| [a, b]).chain(split.kept_whole.iter().copied());
    for e in crossed {
        mesh.elements[e as usize].nodes.iter().for_each(|&v| marked[v as usize] = true);
    }
    scope
        .elements(mesh)
        .filter(|&e| mesh.elements[e].nodes.iter().any(|&v| marked[v as usize]))
        .map(|e| e as u32)
        .collect()
}

/// Side of the `region` elements with respect to `plane` (+1 or -1, 0 for
/// elements outside the region): the side of the element's vertex
/// farthest from the plane among those `split` did not take to lie on it
/// (a snapped node can lie farther than an unsnapped one of a smaller
/// element). After a split no element straddles the plane but those kept
/// whole, which go with their larger part.
pub(crate) fn element_sides(mesh: &PolyMesh, plane: &Plane, region: &[u32], split: &SplitReport) -> Vec<i8> {
    let first_new = mesh.nodes.len() as u32 - split.new_nodes.len() as u32;
    let on_plane = |v: u32| v >= first_new || split.on_plane.binary_search(&v).is_ok();
    let mut side = vec![0; mesh.elements.len()];
    for &e in region {
        let nodes = &mesh.elements[e as usize].nodes;
        let farthest = |off: bool| {
            nodes
                .iter()
                .filter(|&&v| !off || !on_plane(v))
                .map(|&v| plane.distance(mesh.nodes[v as usize]))
                .fold(0.0f64, |m, d| if d.abs() > m.abs() { d } else { m })
        };
        let off = farthest(true);
        let d = if off != 0.0 { off } else { farthest(false) };
        side[e as usize] = if d < 0.0 { -1 } else { 1 };
    }
    side
}

/// Splits along `plane` and separates the two sides (see module docs).
pub fn cut_by_plane(mesh: &mut PolyMesh, plane: &Plane, opts: &SplitOptions) -> Result<CutReport, SplitError> {
    cut_by_plane_keeping(mesh, plane, opts, &[], CutScope::whole())
}

/// [`cut_by_plane`] leaving the sorted `keep_whole` elements as they are:
/// not split and given no new node (the cut goes around them; the
/// simulation retries a cut so when the element store finds a part
/// unhealthy), looking only at the elements in `scope`.
pub fn cut_by_plane_keeping(
    mesh: &mut PolyMesh,
    plane: &Plane,
    opts: &SplitOptions,
    keep_whole: &[u32],
    scope: CutScope,
) -> Result<CutReport, SplitError> {
    let classification = classify(mesh, plane, None, keep_whole, opts, scope)?;
    cut_classified(mesh, plane, classification, scope)
}

/// [`cut_by_plane_keeping`] once [`classify`] has decided, on this `mesh`
/// (unchanged since), which elements to split: the part that changes the
/// mesh.
pub(crate) fn cut_classified(
    mesh: &mut PolyMesh,
    plane: &Plane,
    classification: Classification,
    scope: CutScope,
) -> Result<CutReport, SplitError> {
    let nodes_before = mesh.nodes.len();
    let split = split_classified(mesh, plane, classification)?;
    let region = cut_region(mesh, plane, &split, scope);
    let side = element_sides(mesh, plane, &region, &split);
    let (duplicated, mut touched) = separate(mesh, &region, &side, |_| true, |_| true);
    touched.extend(split.split_elements.iter().flat_map(|&(a, b)| [a, b]));
    touched.extend(split.repaired_elements.iter().copied());
    touched.sort_unstable();
    touched.dedup();
    Ok(CutReport::new(mesh, *plane, nodes_before, split, duplicated, touched))
}

/// Opens the material between the two sides of a cut: every node that
/// `may_split(node)` allows, that elements on both sides use and that lies
/// on no face the two sides share unless `separable(face)`, is duplicated,
/// the negative side taking the copy; a face shared by the two
/// sides is separated (the negative side gets its own copy) when
/// `separable(face)`, and every other face of the negative side has its
/// nodes renamed. Only the `region` elements ([`cut_region`]) are looked
/// at, with their `side`s. Returns the `(original, copy)` pairs and the
/// elements whose faces changed.
pub(crate) fn separate(
    mesh: &mut PolyMesh,
    region: &[u32],
    side: &[i8],
    may_split: impl Fn(u32) -> bool,
    separable: impl Fn(u32) -> bool,
) -> (Vec<(u32, u32)>, Vec<u32>) {
    // which sides use each node and each face
    let bit = |e: u32| if side[e as usize] > 0 { 1u8 } else { 2 };
    let mut used = vec![0u8; mesh.nodes.len()];
    let mut face_sides = vec![0u8; mesh.faces.len()];
    let mut region_faces = Vec::new();
    for &e in region {
        let el = &mesh.elements[e as usize];
        el.nodes.iter().for_each(|&v| used[v as usize] |= bit(e));
        el.faces.iter().for_each(|r| face_sides[r.face as usize] |= bit(e));
        region_faces.extend(el.faces.iter().map(|r| r.face));
    }
    // a node on a face the two sides share but keep joined stays single
    // (opening it would tear that face)
    for &f in &region_faces {
        if face_sides[f as usize] == 3 && !separable(f) {
            mesh.faces[f as usize].vertices.iter().for_each(|&v| used[v as usize] = 0);
        }
    }
    let mut copy = vec![u32::MAX; mesh.nodes.len()];
    let mut duplicated = Vec::new();
    for v in 0..used.len() {
        if used[v] == 3 && may_split(v as u32) {
            copy[v] = mesh.nodes.len() as u32;
            mesh.nodes.push(mesh.nodes[v]);
            duplicated.push((v as u32, copy[v]));
        }
    }
    let mut touched = Vec::new();
    if duplicated.is_empty() {
        return (duplicated, touched);
    }
    let remap = |v: &u32| if copy[*v as usize] != u32::MAX { copy[*v as usize] } else { *v };
    // (the face each face became, for the few faces renamed or copied)
    let mut done: rustc_hash::FxHashMap<u32, u32> = Default::default();
    for e in region.iter().map(|&e| e as usize) {
        // (node lists are refreshed below, so they still hold the originals)
        if side[e] > 0 || !mesh.elements[e].nodes.iter().any(|&v| copy[v as usize] != u32::MAX) {
            continue;
        }
        let mut changed = false;
        for k in 0..mesh.elements[e].faces.len() {
            let f = mesh.elements[e].faces[k].face as usize;
            // a duplicated node, or a copy (ids past `copy`) of an earlier rename
            changed |= mesh.faces[f].vertices.iter().any(|&v| copy.get(v as usize).is_none_or(|&c| c != u32::MAX));
            if face_sides[f] == 3 && separable(f as u32) {
                // shared with the positive side: the negative element gets
                // its own copy of the face on the duplicated nodes
                let moved = *done.entry(f as u32).or_insert_with(|| {
                    let face = &mesh.faces[f];
                    let moved = Face {
                        vertices: face.vertices.iter().map(remap).collect(),
                        triangles: face.triangles.iter().map(|t| t.map(|v| remap(&v))).collect(),
                    };
                    mesh.faces.push(moved);
                    mesh.faces.len() as u32 - 1
                });
                mesh.elements[e].faces[k].face = moved;
            } else if face_sides[f] == 2 && !done.contains_key(&(f as u32)) {
                // used by negative elements only: rename its nodes in place
                done.insert(f as u32, f as u32);
                let face = &mut mesh.faces[f];
                face.vertices.iter_mut().for_each(|v| *v = remap(v));
                face.triangles.iter_mut().for_each(|t| *t = t.map(|v| remap(&v)));
            }
        }
        if changed {
            touched.push(e as u32);
        }
    }
    mesh.refresh_elements_nodes(&touched);
    (duplicated, touched)
}
