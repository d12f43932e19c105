//! Mean value elements (wicke2007 §3.2–3.4): convex polyhedra with
//! triangulated faces, integrated by the chosen [`QuadratureRule`].

use cleave_kernels::quadrature::{
    boundary_moments, consistency_correction, paper_rule, paper_rule_len, reference_rule,
};
use cleave_kernels::{elasticity, mean_value};
use rayon::prelude::*;

use super::{BasisError, Batch, QuadratureRule};
use crate::material::Material;
use crate::mesh::PolyMesh;

/// Largest vertex count a mean value element may have.
pub const MAX_VERTICES: usize = 256;

/// Relative tolerance of the convexity check (of the element diameter); it
/// admits the snapping of cut planes (`1e-4` of an edge).
const CONVEXITY_TOLERANCE: f64 = 1e-3;

/// Per-thread scratch of the batch build.
struct Scratch {
    phi: Vec<f64>,
    grad: Vec<f64>,
    gram: Vec<f64>,
    moments: Vec<[f64; 3]>,
    mu: Vec<f64>,
}

/// Builds the batch of `k`-vertex mean value elements `elements`.
pub(super) fn build_batch(
    mesh: &PolyMesh,
    material: &Material,
    rule: QuadratureRule,
    k: usize,
    elements: Vec<u32>,
) -> Result<Batch, BasisError> {
    let (lambda, mu_lame) = material.lame();
    let n = elements.len();
    let nt = 2 * k - 4;
    let nq = match rule {
        QuadratureRule::Consistent | QuadratureRule::Paper => paper_rule_len(k, nt),
        QuadratureRule::Reference(order) => nt * order.pow(3),
    };
    for &e in &elements {
        if k > MAX_VERTICES {
            return Err(BasisError::TooManyVertices { element: e as usize, vertices: k, max: MAX_VERTICES });
        }
        if !mesh.is_convex(e as usize, CONVEXITY_TOLERANCE) {
            return Err(BasisError::NonConvex { element: e as usize });
        }
    }
    let nodes: Vec<u32> = elements.iter().flat_map(|&e| mesh.elements[e as usize].nodes.iter().copied()).collect();
    let rest: Vec<[f64; 3]> = nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let mut triangles = vec![[0u32; 3]; n * nt];
    for (i, &e) in elements.iter().enumerate() {
        let local = &nodes[i * k..(i + 1) * k];
        let tris: Vec<[u32; 3]> = mesh
            .element_triangles(e as usize)
            .map(|t| t.map(|g| local.binary_search(&g).expect("triangle vertex is an element node") as u32))
            .collect();
        if tris.len() != nt {
            // a closed triangulated sphere with k vertices has 2k - 4 triangles
            return Err(BasisError::DegenerateElement { element: e as usize, volume: mesh.element_volume(e as usize) });
        }
        triangles[i * nt..(i + 1) * nt].copy_from_slice(&tris);
    }
    let mut volume = vec![0.0; n];
    let mut mass_fraction = vec![0.0; n * k];
    let mut stiffness = vec![0.0; n * 9 * k * k];
    let mut stress_grads = vec![[0.0; 3]; n * k];
    let mut points = vec![[0.0; 3]; n * nq];
    let mut weights = vec![0.0; n * nq];
    let scratch = || Scratch {
        phi: vec![0.0; k * nq],
        grad: vec![0.0; 3 * k * nq],
        gram: vec![0.0; 9 * k * k],
        moments: vec![[0.0; 3]; k],
        mu: vec![0.0; paper_rule_len(k, nt)],
    };
    volume
        .par_iter_mut()
        .zip(mass_fraction.par_chunks_mut(k))
        .zip(stiffness.par_chunks_mut(9 * k * k))
        .zip(stress_grads.par_chunks_mut(k))
        .zip(points.par_chunks_mut(nq))
        .zip(weights.par_chunks_mut(nq))
        .enumerate()
        .try_for_each_init(scratch, |s, (i, (((((vol, mu), ke), sg), pts), wts))| {
            let verts = &rest[i * k..(i + 1) * k];
            let tris = &triangles[i * nt..(i + 1) * nt];
            let element = elements[i] as usize;
            // the paper's rule gives the lumped masses in every case
            let np = paper_rule_len(k, nt);
            let mut paper_pts = [[0.0; 3]; 0].to_vec();
            let v = match rule {
                QuadratureRule::Consistent | QuadratureRule::Paper => paper_rule(verts, tris, pts, wts, mu),
                QuadratureRule::Reference(order) => {
                    paper_pts.resize(np, [0.0; 3]);
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
            *vol = v;
            mean_value::evaluate(verts, tris, pts, &mut s.phi, &mut s.grad);
            if rule == QuadratureRule::Consistent {
                consistency_correction(verts, tris, wts, &mut s.grad, &mut s.moments);
            }
            elasticity::element_stiffness(&s.grad, wts, k, lambda, mu_lame, &mut s.gram, ke);
            // stress point: the exact mean of the gradient, ∮ φ_a n / V
            boundary_moments(verts, tris, &mut s.moments);
            for (g, m) in sg.iter_mut().zip(&s.moments) {
                *g = [m[0] / v, m[1] / v, m[2] / v];
            }
            Ok(())
        })?;
    Ok(Batch {
        k,
        elements,
        nodes,
        rest,
        volume,
        mass_fraction,
        stiffness,
        lame: material.lame(),
        stress_grads,
        triangles,
        points,
        weights,
        points_per_element: nq,
    })
}
