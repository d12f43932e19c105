//! Harmonic elements (martin2008 §4-6): shape functions harmonic inside
//! each element and equal to the shared face functions on its boundary,
//! fitted by the method of fundamental solutions; convex and non-convex
//! elements with planar faces.
//!
//! Integration: the element is split into the sub-tetrahedra from a point
//! that sees its whole boundary (a star point; found for convex and
//! star-shaped non-convex elements), and each sub-tetrahedron carries two
//! rules: a collapsed Gauss rule of `quadrature_order^3` points for the
//! consistent mass the lumped masses come from, and for the stiffness the
//! symmetric 4-point rule of degree 2 (or, for `quadrature_order` 3 and up,
//! the mass rule). An element with no star point is
//! first cut by a grid of half its diameter into the exact pieces
//! `element ∩ box` (the grid slicer of [`crate::meshing::grid_slice`]),
//! finer where a piece is still not star-shaped (three levels): every
//! sub-tetrahedron then lies inside the element and has a positive weight,
//! so any planar-faced polyhedron is integrated. (A vertex whose faces
//! twist so that no point near it sees them all is never separated by
//! slicing; the tiny pieces around it left on the last level take signed
//! cones, exact for polynomials.) The gradients are then shifted per
//! element so that `Σ_q w_q ∇N_a = ∮ b_a n`, with the face moments shared by
//! both sides of every face: the discrete divergence theorem holds exactly
//! and the patch test passes whatever the MFS error. Masses are lumped by
//! row scaling of the consistent mass (HRZ), which keeps them positive.
//!
//! Why two rules: the 8-point collapsed rule (order 2) is exact for
//! degree 1 only, the 4-point rule for degree 2. For `K_e` the 4-point
//! rule is the better one at half the points: on the box of the harmonic
//! tests its `K_e` lies nearer the trilinear one (4.8e-2 against 5.8e-2).
//! For the lumped masses it is worse, the products `N_a N_b` being far from
//! quadratic: they move three times as far from 1/8 (1.0e-3 against
//! 3.5e-4), so the masses keep the 8-point rule, for which only the values
//! (one kernel matrix, not four) are evaluated. A 24-node element's build
//! takes a tenth less than with the 8-point rule for both (one core, AMD
//! EPYC Zen 3: 3.25 against 3.6 ms).

mod congruence;
mod element;
mod face;
mod mfs;

use crate::param::ParamError;
use cleave_kernels::quadrature::{cone_rule, cone_rule_degree2, shift_gradients, volume_centroid};
use cleave_kernels::tet::signed_volume;
use cleave_kernels::{elasticity, vec3};
use rayon::prelude::*;
use std::collections::HashMap;

pub(crate) use element::winding_number;
pub use element::{element_basis, element_basis_measured, ElementBasis, EvaluationWork, POINT_RUN};
pub use face::{FaceBasis, FaceFunction};
pub use mfs::FitError;

use super::{fill_batch, BasisError, Batch, ElementKind, Slots};
use crate::material::Material;
use crate::mesh::PolyMesh;

/// Parameters of the MFS fit and of the quadrature of harmonic elements.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HarmonicOptions {
    /// Offset `ξ` of the kernel centres outside the boundary, relative to
    /// the element (or face) diameter (martin2008 eq. 12; 0.1).
    pub offset: f64,
    /// Kernel samples inside every edge (3; an element's collocation points
    /// are 1.75 times as dense along its edges and 2.5 times along each
    /// direction of its faces, a face function's three times).
    pub edge_samples: usize,
    /// Gauss points per direction of the collapsed rule on each
    /// sub-tetrahedron (2: exact for degree 1; 3: degree 3): the masses'
    /// rule, and from 3 up the stiffness's too (1 and 2 give the stiffness
    /// the 4-point rule of degree 2; see the module docs).
    pub quadrature_order: usize,
    /// Whether hexahedra use the closed-form trilinear basis (true) or are
    /// fitted like every other element (false: a reference for tests).
    pub trilinear_hexahedra: bool,
}

impl Default for HarmonicOptions {
    fn default() -> Self {
        HarmonicOptions { offset: 0.1, edge_samples: 3, quadrature_order: 2, trilinear_hexahedra: true }
    }
}

impl HarmonicOptions {
    /// Checks `offset ∈ (0, 1]`, `edge_samples ∈ 1..=10`,
    /// `quadrature_order ∈ 1..=6`.
    pub fn check(&self) -> Result<(), ParamError> {
        if !(self.offset > 0.0 && self.offset <= 1.0) {
            return Err(ParamError::new("offset", self.offset, "must be in (0, 1] (fraction of the element size)"));
        }
        if !(1..=10).contains(&self.edge_samples) {
            return Err(ParamError::new("edge_samples", self.edge_samples, "must be in 1..=10"));
        }
        if !(1..=6).contains(&self.quadrature_order) {
            return Err(ParamError::new("quadrature_order", self.quadrature_order, "must be in 1..=6"));
        }
        Ok(())
    }
}

/// The face functions of every face of the `elements` (indexed by global
/// face id; `None` for faces of no listed element).
pub fn face_bases(
    mesh: &PolyMesh,
    elements: &[u32],
    options: &HarmonicOptions,
) -> Result<Vec<Option<FaceBasis>>, BasisError> {
    let mut owner = vec![None; mesh.faces.len()];
    for &e in elements {
        for r in &mesh.elements[e as usize].faces {
            owner[r.face as usize].get_or_insert(e as usize);
        }
    }
    owner
        .par_iter()
        .enumerate()
        .map(|(f, owner)| match owner {
            None => Ok(None),
            Some(e) => FaceBasis::build(&mesh.nodes, &mesh.faces[f], options)
                .map(Some)
                .ok_or(BasisError::HarmonicFit { element: *e }),
        })
        .collect()
}

/// A point from which every surface triangle spans a positive
/// sub-tetrahedron (at least `1e-3` of the diameter from every triangle's
/// plane), by subgradient ascent of the smallest such distance from the
/// centroid; `None` if none is found (the element is not star-shaped).
pub fn star_point(verts: &[[f64; 3]], triangles: &[[u32; 3]], diameter: f64) -> Option<[f64; 3]> {
    star_point_clear_by(verts, triangles, diameter, 1e-3)
}

/// [`star_point`] with the clearance `clearance` (fraction of the
/// diameter): the pieces of a sliced element near a vertex whose kernel is
/// thin accept a point closer to their faces.
fn star_point_clear_by(
    verts: &[[f64; 3]],
    triangles: &[[u32; 3]],
    diameter: f64,
    clearance_floor: f64,
) -> Option<[f64; 3]> {
    let planes: Vec<([f64; 3], [f64; 3])> = triangles
        .iter()
        .filter_map(|t| {
            let p = t.map(|i| verts[i as usize]);
            let n = vec3::cross(vec3::sub(p[1], p[0]), vec3::sub(p[2], p[0]));
            let l = vec3::norm(n);
            (l > 0.0).then(|| (p[0], vec3::scale(n, 1.0 / l)))
        })
        .collect();
    let clearance = |x: [f64; 3]| {
        planes.iter().map(|(p, n)| (vec3::dot(vec3::sub(*p, x), *n), *n)).fold((f64::INFINITY, [0.0; 3]), |a, b| {
            if b.0 < a.0 {
                b
            } else {
                a
            }
        })
    };
    let positive = |x: [f64; 3]| {
        triangles.iter().all(|t| {
            let p = t.map(|i| verts[i as usize]);
            signed_volume(x, p[0], p[1], p[2]) >= 0.0
        })
    };
    let (_, mut x) = volume_centroid(verts, triangles);
    let mut step = 0.1 * diameter;
    for _ in 0..400 {
        let (d, n) = clearance(x);
        if d > clearance_floor * diameter && positive(x) {
            return Some(x);
        }
        x = vec3::sub(x, vec3::scale(n, step));
        step *= 0.985;
    }
    None
}

/// How many times a piece without a star point is sliced again, each time
/// by a grid twice as fine.
const SLICE_LEVELS: usize = 3;

/// Calls `cone(vertices, triangles, apex)` for every piece of the closed
/// surface `surface` cut by a grid of cell `cell` (m), slicing again where
/// a piece has no star point; false where that fails `levels` deep.
fn sliced_cones(
    surface: &crate::io::Surface,
    cell: f64,
    levels: usize,
    cone: &mut impl FnMut(&[[f64; 3]], &[[u32; 3]], [f64; 3]),
) -> bool {
    let Ok((pieces, _)) =
        crate::meshing::grid_slice(surface, cell, &crate::meshing::SliceOptions { merge_below: 0.0, simplify: 0.0 })
    else {
        return false;
    };
    (0..pieces.elements.len()).all(|e| {
        let verts: Vec<[f64; 3]> = pieces.elements[e].nodes.iter().map(|&v| pieces.nodes[v as usize]).collect();
        let local = |g: u32| pieces.elements[e].nodes.binary_search(&g).map(|i| i as u32).unwrap_or(0);
        let triangles: Vec<[u32; 3]> = pieces.element_triangles(e).map(|t| t.map(local)).collect();
        // a thin piece has no point clear of its faces, but a convex one is
        // seen whole from its centroid; on the last level, a piece still
        // without a star point (a vertex whose faces twist so that no
        // point sees them all, which slicing never separates) takes signed
        // cones from its centroid: exact for polynomials, and its
        // negative weights are a sliver of the element's (the store's
        // health check still judges the result)
        let centroid = Some(pieces.element_centroid(e)).filter(|_| levels == 0 || pieces.is_convex(e, 0.0));
        match star_point_clear_by(&verts, &triangles, pieces.element_diameter(e), 1e-6).or(centroid) {
            Some(apex) => {
                cone(&verts, &triangles, apex);
                true
            }
            None => {
                levels > 0
                    && sliced_cones(&crate::io::Surface { vertices: verts, triangles }, 0.5 * cell, levels - 1, cone)
            }
        }
    })
}

/// A quadrature rule: points (m) and weights (m³).
pub type Rule = (Vec<[f64; 3]>, Vec<f64>);

/// The two quadrature rules of a harmonic element, on the same
/// sub-tetrahedra (see the module docs).
#[derive(Clone, Debug)]
pub struct ElementRules {
    /// The collapsed rule of `quadrature_order³` points per
    /// sub-tetrahedron, for the consistent mass the lumped masses come
    /// from.
    pub mass: Rule,
    /// The rule of the stiffness: the 4-point rule of degree 2 per
    /// sub-tetrahedron for `quadrature_order` 1 or 2; `None` from 3 up,
    /// where the mass rule serves both (see [`ElementRules::stiffness`]).
    pub degree2: Option<Rule>,
}

impl ElementRules {
    /// The stiffness's rule: the 4-point rule, or the mass rule.
    pub fn stiffness(&self) -> &Rule {
        self.degree2.as_ref().unwrap_or(&self.mass)
    }
}

/// The quadrature rules of an element from its vertices and outward
/// triangles (see the module docs); `None` if no slicing gives pieces with
/// star points.
pub fn element_rules(verts: &[[f64; 3]], triangles: &[[u32; 3]], diameter: f64, order: usize) -> Option<ElementRules> {
    let (mut mass, mut degree2): (Rule, Option<Rule>) = (Default::default(), (order <= 2).then(Default::default));
    let mut cone = |verts: &[[f64; 3]], triangles: &[[u32; 3]], apex: [f64; 3]| {
        cone_rule(verts, triangles, apex, order, &mut mass.0, &mut mass.1);
        if let Some((points, weights)) = degree2.as_mut() {
            cone_rule_degree2(verts, triangles, apex, points, weights);
        }
    };
    match star_point(verts, triangles, diameter) {
        Some(apex) => cone(verts, triangles, apex),
        None => {
            let surface = crate::io::Surface { vertices: verts.to_vec(), triangles: triangles.to_vec() };
            if !sliced_cones(&surface, 0.5 * diameter, SLICE_LEVELS, &mut cone) {
                return None;
            }
        }
    }
    Some(ElementRules { mass, degree2 })
}

/// Per-thread scratch of the batch build.
struct Scratch {
    /// The mass rule's points, moved with the element.
    mass_points: Vec<[f64; 3]>,
    /// Values at the mass rule's points.
    phi: Vec<f64>,
    /// Gradients at the stiffness rule's points.
    grad: Vec<f64>,
    gram: Vec<f64>,
    moments: Vec<[f64; 3]>,
    /// The basis evaluation's workspace.
    evaluation: EvaluationWork,
}

/// Builds the `k`-node harmonic elements `elements` into the end of their
/// batch in `batches` (see [`fill_batch`]); `faces` holds the face
/// functions of their faces.
pub(super) fn build_batch(
    batches: &mut Vec<Batch>,
    mesh: &PolyMesh,
    material: &Material,
    faces: &[Option<FaceBasis>],
    options: &HarmonicOptions,
    k: usize,
    elements: &[u32],
) -> Result<(), BasisError> {
    let (lambda, mu) = material.lame();
    // elements equal up to a translation share one fit and one rule
    // (see [`congruence`]): both are made for the first of each shape
    let template = congruence::templates(mesh, elements);
    let firsts: Vec<usize> = (0..elements.len()).filter(|&i| template[i] == i).collect();
    let mut copies = vec![0usize; elements.len()];
    template.iter().for_each(|&t| copies[t] += 1);
    // the rules first: elements sliced for want of a star point have more
    // points, and the batch holds as many per element as the largest rule
    // (the others padded with points of zero weight); the fits of shapes
    // with copies too, while an element of a shape of its own is fitted
    // when its slots are filled (so that no more fits are held at once
    // than there are threads: a 24-node fit is about 50 kB)
    let fitted: Vec<(usize, ElementRules, Option<ElementBasis>)> = firsts
        .par_iter()
        .map(|&i| {
            let e = elements[i];
            let el = &mesh.elements[e as usize];
            let verts: Vec<[f64; 3]> = el.nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
            let local = |g: u32| el.nodes.binary_search(&g).map(|i| i as u32).unwrap_or(0);
            let triangles: Vec<[u32; 3]> = mesh.element_triangles(e as usize).map(|t| t.map(local)).collect();
            let rules = element_rules(&verts, &triangles, mesh.element_diameter(e as usize), options.quadrature_order)
                .ok_or(BasisError::NotStarShaped { element: e as usize })?;
            let fit = || {
                element_basis(mesh, e as usize, faces, options).ok_or(BasisError::HarmonicFit { element: e as usize })
            };
            let basis = if copies[i] > 1 { Some(fit()?) } else { None };
            Ok((i, rules, basis))
        })
        .collect::<Result<_, BasisError>>()?;
    // where in `fitted` the template of each batch element is
    let mut fit_of = vec![usize::MAX; elements.len()];
    fitted.iter().enumerate().for_each(|(t, f)| fit_of[f.0] = t);
    let index_of: HashMap<u32, usize> = elements.iter().enumerate().map(|(i, &e)| (e, i)).collect();
    let nq = fitted.iter().map(|f| f.1.stiffness().0.len()).max().unwrap_or(0);
    let scratch = || Scratch {
        mass_points: Vec::new(),
        phi: Vec::new(),
        grad: vec![0.0; 3 * k * nq],
        gram: vec![0.0; elasticity::stiffness_scratch_len(k, nq)],
        moments: vec![[0.0; 3]; k],
        evaluation: EvaluationWork::default(),
    };
    fill_batch(batches, mesh, material, ElementKind::Harmonic, k, nq, elements, true, scratch, |s, slot| {
        let Slots { element, volume, mass_fraction, stiffness, stress_grads, points, weights, .. } = slot;
        let degenerate = || BasisError::DegenerateElement { element, volume: mesh.element_volume(element) };
        let i = index_of[&(element as u32)];
        let (first, rules, fit) = &fitted[fit_of[template[i]]];
        let (rule_points, rule_weights) = rules.stiffness();
        let shift = congruence::offset(mesh, elements[*first], element as u32);
        let m = rule_points.len();
        for (p, q) in points[..m].iter_mut().zip(rule_points) {
            *p = vec3::add(*q, shift);
        }
        weights[..m].copy_from_slice(rule_weights);
        // padding: a point of the rule, weighted zero
        points[m..].fill(rule_points[0]);
        weights[m..].fill(0.0);
        let v: f64 = weights.iter().sum();
        if !(v > 0.0) {
            return Err(degenerate());
        }
        *volume = v;
        let basis = match fit {
            Some(fit) => fit.translated(shift),
            None => element_basis(mesh, element, faces, options).ok_or(BasisError::HarmonicFit { element })?,
        };
        // (one evaluation of both where one rule serves both)
        match rules.degree2 {
            Some(_) => basis.gradients(points, &mut s.grad, &mut s.evaluation),
            None => {
                s.phi.resize(k * nq, 0.0);
                basis.evaluate(points, &mut s.phi, &mut s.grad, &mut s.evaluation);
            }
        }
        boundary_moments(mesh, element, faces, &mut s.moments);
        shift_gradients(weights, &mut s.grad, &s.moments);
        elasticity::element_stiffness(&s.grad, weights, k, lambda, mu, &mut s.gram, stiffness);
        // HRZ lumping: diagonal of the consistent mass (by the mass rule),
        // rescaled to sum 1
        let (mass_points, mass_weights) = &rules.mass;
        // (the values at the mass rule's points, `stride` apart per node)
        let stride = match rules.degree2 {
            Some(_) => {
                s.mass_points.clear();
                s.mass_points.extend(mass_points.iter().map(|q| vec3::add(*q, shift)));
                s.phi.resize(k * mass_points.len(), 0.0);
                basis.values(&s.mass_points, &mut s.phi, &mut s.evaluation);
                mass_points.len()
            }
            None => nq,
        };
        for (a, m) in mass_fraction.iter_mut().enumerate() {
            *m = s.phi[a * stride..(a + 1) * stride].iter().zip(mass_weights).map(|(p, w)| p * p * w).sum();
        }
        let total: f64 = mass_fraction.iter().sum();
        mass_fraction.iter_mut().for_each(|m| *m /= total);
        for (g, m) in stress_grads.iter_mut().zip(s.moments.iter()) {
            *g = vec3::scale(*m, 1.0 / v);
        }
        if stiffness.iter().chain(mass_fraction.iter()).any(|x| !x.is_finite()) {
            return Err(BasisError::HarmonicFit { element });
        }
        Ok(())
    })
}

/// `∮ b_a n` (m^2) for every node `a` of element `e` (element-local order)
/// from the shared face moments, with the element's outward orientation.
pub fn boundary_moments(mesh: &PolyMesh, e: usize, faces: &[Option<FaceBasis>], out: &mut [[f64; 3]]) {
    let el = &mesh.elements[e];
    out.fill([0.0; 3]);
    for r in &el.faces {
        let face = &mesh.faces[r.face as usize];
        let basis = faces[r.face as usize].as_ref().expect("face functions of a harmonic element");
        let sign = if r.outward { 1.0 } else { -1.0 };
        for (&v, m) in face.vertices.iter().zip(&basis.moments) {
            let a = el.nodes.binary_search(&v).expect("face vertex is an element node");
            out[a] = vec3::add(out[a], vec3::scale(*m, sign));
        }
    }
}
