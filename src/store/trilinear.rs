//! Closed-form trilinear hexahedra, the harmonic family's special case
//! (martin2008 §4: harmonic coordinates reproduce trilinear hexahedra).
//!
//! `N_a(ξ, η, ζ)` are the products of 1D hats on the unit cube mapped by
//! `x(ξ) = Σ_a x_a N_a(ξ)`; gradients are `J⁻ᵀ ∇_ξ N_a` and the element is
//! integrated by 2x2x2 Gauss points, exact for the patch test on any
//! hexahedron (the cofactor terms are polynomials of degree 3 per
//! direction). Masses are `∫ N_a / V`; the stress-point gradient is the mean
//! `Σ_q w_q ∇N_a / V`.

use cleave_kernels::elasticity;
use cleave_kernels::quadrature::gauss_legendre;

use super::{fill_batch, BasisError, Batch, ElementKind, Slots};
use crate::material::Material;
use crate::mesh::PolyMesh;

/// Reference corners in VTK order: bottom `0-1-2-3`, top `4-5-6-7`.
const CORNERS: [[f64; 3]; 8] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [1.0, 1.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [1.0, 0.0, 1.0],
    [1.0, 1.0, 1.0],
    [0.0, 1.0, 1.0],
];

/// The element-local indices of element `e`'s nodes in VTK hexahedron
/// order, if `e` is a hexahedron: 8 nodes, 6 quadrilateral faces, and a
/// positive Jacobian at every Gauss point.
pub(super) fn hex_corners(mesh: &PolyMesh, e: usize) -> Option<[usize; 8]> {
    let el = &mesh.elements[e];
    if el.nodes.len() != 8 || el.faces.len() != 6 {
        return None;
    }
    let loops: Vec<&[u32]> = el.faces.iter().map(|r| &mesh.faces[r.face as usize].vertices[..]).collect();
    if loops.iter().any(|l| l.len() != 4) {
        return None;
    }
    // bottom: the first face, ordered so its normal points inward
    let r = &el.faces[0];
    let mut bottom = loops[0].to_vec();
    if r.outward {
        bottom.reverse();
    }
    let is_edge = |a: u32, b: u32| {
        loops.iter().any(|l| (0..4).any(|i| (l[i] == a && l[(i + 1) % 4] == b) || (l[i] == b && l[(i + 1) % 4] == a)))
    };
    let mut ids = [0u32; 8];
    for i in 0..4 {
        ids[i] = bottom[i];
        ids[i + 4] = *el.nodes.iter().find(|&&t| !bottom.contains(&t) && is_edge(bottom[i], t))?;
    }
    let local: Vec<usize> = ids.iter().map(|v| el.nodes.binary_search(v).ok()).collect::<Option<_>>()?;
    let mut distinct = local.clone();
    distinct.sort_unstable();
    distinct.dedup();
    if distinct.len() != 8 {
        return None;
    }
    let corners: [usize; 8] = std::array::from_fn(|i| local[i]);
    let x: Vec<[f64; 3]> = el.nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let (g, _) = gauss_legendre(2);
    let ok = g.iter().all(|&a| {
        g.iter().all(|&b| g.iter().all(|&c| jacobian(&x, &corners, [a, b, c]).map(|(det, _)| det > 0.0) == Some(true)))
    });
    ok.then_some(corners)
}

/// Shape functions and their reference gradients at `xi`.
fn reference(xi: [f64; 3]) -> ([f64; 8], [[f64; 3]; 8]) {
    let mut n = [0.0; 8];
    let mut d = [[0.0; 3]; 8];
    for (a, c) in CORNERS.iter().enumerate() {
        let h: [f64; 3] = std::array::from_fn(|i| if c[i] > 0.5 { xi[i] } else { 1.0 - xi[i] });
        let dh: [f64; 3] = std::array::from_fn(|i| if c[i] > 0.5 { 1.0 } else { -1.0 });
        n[a] = h[0] * h[1] * h[2];
        d[a] = [dh[0] * h[1] * h[2], h[0] * dh[1] * h[2], h[0] * h[1] * dh[2]];
    }
    (n, d)
}

/// `det J` and `J⁻¹` (row-major) of the map at `xi`; `None` if singular.
fn jacobian(x: &[[f64; 3]], corners: &[usize; 8], xi: [f64; 3]) -> Option<(f64, [[f64; 3]; 3])> {
    let (_, d) = reference(xi);
    let mut j = [[0.0; 3]; 3]; // J[r][c] = ∂x_r/∂ξ_c
    for a in 0..8 {
        for r in 0..3 {
            for c in 0..3 {
                j[r][c] += x[corners[a]][r] * d[a][c];
            }
        }
    }
    let cof = |r: usize, c: usize| {
        let (r1, r2, c1, c2) = ((r + 1) % 3, (r + 2) % 3, (c + 1) % 3, (c + 2) % 3);
        j[r1][c1] * j[r2][c2] - j[r1][c2] * j[r2][c1]
    };
    let det = j[0][0] * cof(0, 0) + j[0][1] * cof(0, 1) + j[0][2] * cof(0, 2);
    (det != 0.0 && det.is_finite()).then(|| (det, std::array::from_fn(|r| std::array::from_fn(|c| cof(c, r) / det))))
}

/// The shape function values (reference corner order) at the point `x`
/// of the hexahedron with nodes `nodes` and corners `corners`: the
/// reference point by Newton's method on the trilinear map; `None` if it
/// does not converge (a point far outside, or a degenerate map).
pub(super) fn values_at(nodes: &[[f64; 3]], corners: &[usize; 8], x: [f64; 3]) -> Option<[f64; 8]> {
    let size = corners
        .iter()
        .map(|&c| cleave_kernels::vec3::norm(cleave_kernels::vec3::sub(nodes[c], nodes[corners[0]])))
        .fold(0.0, f64::max);
    let mut xi = [0.5; 3];
    for _ in 0..30 {
        let (n, _) = reference(xi);
        let mut r = [0.0; 3];
        for a in 0..8 {
            for k in 0..3 {
                r[k] += n[a] * nodes[corners[a]][k];
            }
        }
        let r = [r[0] - x[0], r[1] - x[1], r[2] - x[2]];
        if (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt() <= 1e-12 * size {
            return Some(n);
        }
        let (_, inv) = jacobian(nodes, corners, xi)?;
        for i in 0..3 {
            xi[i] -= inv[i][0] * r[0] + inv[i][1] * r[1] + inv[i][2] * r[2];
        }
    }
    None
}

/// Builds the trilinear hexahedra `elements` into the end of their batch in
/// `batches` (see [`fill_batch`]).
pub(super) fn build_batch(
    batches: &mut Vec<Batch>,
    mesh: &PolyMesh,
    material: &Material,
    elements: &[u32],
) -> Result<(), BasisError> {
    let (lambda, mu) = material.lame();
    let (k, nq) = (8, 8);
    let (g, gw) = gauss_legendre(2);
    let scratch = || (vec![0.0; 3 * k * nq], vec![0.0; elasticity::stiffness_scratch_len(k, nq)]);
    fill_batch(
        batches,
        mesh,
        material,
        ElementKind::Trilinear,
        k,
        nq,
        elements,
        false,
        scratch,
        |(grad, gram), slot| {
            let Slots { element, verts, volume, mass_fraction, stiffness, stress_grads, points, weights, .. } = slot;
            let corners = hex_corners(mesh, element)
                .ok_or(BasisError::DegenerateElement { element, volume: mesh.element_volume(element) })?;
            mass_fraction.fill(0.0);
            stress_grads.fill([0.0; 3]);
            for q in 0..nq {
                let xi = [g[q & 1], g[(q >> 1) & 1], g[q >> 2]];
                let (n, d) = reference(xi);
                let (det, jinv) = jacobian(verts, &corners, xi)
                    .ok_or(BasisError::DegenerateElement { element, volume: mesh.element_volume(element) })?;
                let w = det * gw[q & 1] * gw[(q >> 1) & 1] * gw[q >> 2];
                weights[q] = w;
                points[q] = (0..8).fold([0.0; 3], |p, a| std::array::from_fn(|i| p[i] + n[a] * verts[corners[a]][i]));
                for (a, &local) in corners.iter().enumerate() {
                    // ∇N = J⁻ᵀ ∇_ξ N: component i = Σ_c J⁻¹[c][i] ∂N/∂ξ_c
                    let gi: [f64; 3] = std::array::from_fn(|i| (0..3).map(|c| jinv[c][i] * d[a][c]).sum());
                    for i in 0..3 {
                        grad[(3 * local + i) * nq + q] = gi[i];
                        stress_grads[local][i] += w * gi[i];
                    }
                    mass_fraction[local] += w * n[a];
                }
            }
            let v: f64 = weights.iter().sum();
            *volume = v;
            mass_fraction.iter_mut().for_each(|m| *m /= v);
            stress_grads.iter_mut().for_each(|s| *s = s.map(|c| c / v));
            elasticity::element_stiffness(grad, weights, k, lambda, mu, gram, stiffness);
            Ok(())
        },
    )
}
