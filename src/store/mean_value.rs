//! Mean value elements (wicke2007 §3.2–3.4): convex polyhedra with
//! triangulated faces, integrated by the chosen [`QuadratureRule`].

use cleave_kernels::quadrature::{
    boundary_moments, consistency_correction, paper_rule, paper_rule_len, reference_rule,
};
use cleave_kernels::{elasticity, mean_value};
use rayon::prelude::*;

use cleave_kernels::dyn_stack::{MemBuffer, MemStack};

use super::{fill_batch, BasisError, Batch, ElementKind, QuadratureRule, Slots};
use crate::material::Material;
use crate::mesh::PolyMesh;

/// Deepest fold a mean value element may have, relative to its diameter
/// ([`PolyMesh::non_convexity`]): the snapping of cuts bends caps by up to
/// `SplitOptions::snap` (0.1) of the element they cross, which wicke2007
/// §4 accepts (mean value coordinates are well defined on any closed
/// triangulated polyhedron); an L-prism's notch (about 0.3) is refused.
const CONVEXITY_TOLERANCE: f64 = 0.1;

/// Per-thread scratch of the batch build.
struct Scratch {
    phi: Vec<f64>,
    grad: Vec<f64>,
    gram: Vec<f64>,
    moments: Vec<[f64; 3]>,
    mu: Vec<f64>,
    /// The basis kernel's workspace.
    stack: MemBuffer,
}

/// Builds the `k`-vertex mean value elements `elements` into the end of
/// their batch in `batches` (see [`fill_batch`]).
pub(super) fn build_batch(
    batches: &mut Vec<Batch>,
    mesh: &PolyMesh,
    material: &Material,
    rule: QuadratureRule,
    k: usize,
    elements: &[u32],
) -> Result<(), BasisError> {
    let (lambda, mu_lame) = material.lame();
    let nt = 2 * k - 4;
    let nq = match rule {
        QuadratureRule::Consistent | QuadratureRule::Paper => paper_rule_len(k, nt),
        QuadratureRule::Reference(order) | QuadratureRule::ConsistentGauss(order) => nt * order.pow(3),
    };
    // (in parallel, the first in order named: the same error on any pool)
    if let Some(&e) = elements.par_iter().find_first(|&&e| !mesh.is_convex(e as usize, CONVEXITY_TOLERANCE)) {
        return Err(BasisError::NonConvex { element: e as usize });
    }
    let scratch = || Scratch {
        phi: vec![0.0; k * nq],
        grad: vec![0.0; 3 * k * nq],
        gram: vec![0.0; elasticity::stiffness_scratch_len(k, nq)],
        moments: vec![[0.0; 3]; k],
        mu: vec![0.0; paper_rule_len(k, nt)],
        stack: MemBuffer::new(mean_value::evaluate_scratch(k, nt)),
    };
    fill_batch(batches, mesh, material, ElementKind::MeanValue, k, nq, elements, true, scratch, |s, slot| {
        let Slots {
            element,
            verts,
            triangles: tris,
            volume: vol,
            mass_fraction: mu,
            stiffness: ke,
            stress_grads: sg,
            points: pts,
            weights: wts,
        } = slot;
        // the paper's rule gives the lumped masses in every case
        let np = paper_rule_len(k, nt);
        let v = match rule {
            QuadratureRule::Consistent | QuadratureRule::Paper => paper_rule(verts, tris, pts, wts, mu),
            QuadratureRule::Reference(order) | QuadratureRule::ConsistentGauss(order) => {
                let mut paper_pts = vec![[0.0; 3]; np];
                let v = paper_rule(verts, tris, &mut paper_pts, &mut s.mu[..np], mu);
                let (p, w) = reference_rule(verts, tris, order);
                pts.copy_from_slice(&p);
                wts.copy_from_slice(&w);
                v
            }
        };
        if !(v > 0.0) {
            return Err(BasisError::DegenerateElement { element, volume: v });
        }
        // the rule's cones from the centroid to the surface triangles must
        // all be positive (the element star-shaped about its centroid)
        if wts.iter().any(|&w| !(w > 0.0)) || mu.iter().any(|&m| !(m > 0.0)) {
            return Err(BasisError::NotStarShaped { element });
        }
        *vol = v;
        mean_value::evaluate(verts, tris, pts, &mut s.phi, &mut s.grad, MemStack::new(&mut s.stack));
        if matches!(rule, QuadratureRule::Consistent | QuadratureRule::ConsistentGauss(_)) {
            consistency_correction(verts, tris, wts, &mut s.grad, &mut s.moments);
        }
        elasticity::element_stiffness(&s.grad, wts, k, lambda, mu_lame, &mut s.gram, ke);
        // stress point: the exact mean of the gradient, ∮ φ_a n / V
        boundary_moments(verts, tris, &mut s.moments);
        for (g, m) in sg.iter_mut().zip(&s.moments) {
            *g = [m[0] / v, m[1] / v, m[2] / v];
        }
        Ok(())
    })
}
