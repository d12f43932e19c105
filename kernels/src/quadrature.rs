//! Quadrature on a polyhedron given by its vertices and outward surface
//! triangles (local indices).
//!
//! - [`paper_rule`]: wicke2007 §3.4: one point per vertex at
//!   `0.8 x_i + 0.2 c` with weight `μ_i V / 2`, one per surface triangle at
//!   `0.9 c_f + 0.1 c` with weight `κ_f V / 2`, where
//!   `μ_i = Σ_{f ∋ i} V(f, c) / (3 V)` (eq. 14) and `κ_f = V(f, c) / V`
//!   (eq. 15); the weights sum to `V`.
//! - [`consistency_correction`]: shifts every gradient `∇φ_a` by the same
//!   vector per element so that the discrete divergence theorem holds,
//!   `Σ_q w_q ∇φ_a(x_q) = ∮ φ_a n` (exact: `φ_a` is linear on each surface
//!   triangle, so `∮ φ_a n = Σ_{f ∋ a} A_f n_f / 3`). The shift keeps
//!   partition of unity and linear reproduction of the gradients, and makes
//!   the element pass the patch test exactly whatever the points.
//! - [`reference_rule`]: tensor Gauss–Legendre on the Duffy-collapsed
//!   sub-tetrahedra `(c, f)`, `n^3` points each, for tests.
//! - [`cone_rule`] and [`cone_rule_degree2`]: the collapsed rule, or the
//!   symmetric 4-point rule of degree 2, on the sub-tetrahedra from any
//!   apex that sees the whole surface (the harmonic elements' rules).
//!
//! Units: positions in m, weights in m^3.

use crate::tet::signed_volume;
use crate::vec3::{add, cross, lerp, scale, sub};

/// Volume (m^3) and centroid (m) of the polyhedron.
pub fn volume_centroid(vertices: &[[f64; 3]], triangles: &[[u32; 3]]) -> (f64, [f64; 3]) {
    let o = vertices[0];
    let mut v = 0.0;
    let mut c = [0.0; 3];
    for t in triangles {
        let (a, b, d) = (vertices[t[0] as usize], vertices[t[1] as usize], vertices[t[2] as usize]);
        let vt = signed_volume(o, a, b, d);
        v += vt;
        c = add(c, scale(add(add(o, a), add(b, d)), vt / 4.0));
    }
    (v, scale(c, 1.0 / v))
}

/// Number of points of [`paper_rule`]: `k + T`.
pub fn paper_rule_len(k: usize, triangles: usize) -> usize {
    k + triangles
}

/// The paper's rule: fills `points`, `weights` (length `k + T`) and the
/// lumped mass fractions `mu` (length `k`, summing to 1); returns the volume.
pub fn paper_rule(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    points: &mut [[f64; 3]],
    weights: &mut [f64],
    mu: &mut [f64],
) -> f64 {
    let k = vertices.len();
    assert_eq!(points.len(), k + triangles.len());
    assert_eq!(weights.len(), points.len());
    assert_eq!(mu.len(), k);
    let (vol, c) = volume_centroid(vertices, triangles);
    mu.fill(0.0);
    for (f, t) in triangles.iter().enumerate() {
        let (a, b, d) = (vertices[t[0] as usize], vertices[t[1] as usize], vertices[t[2] as usize]);
        let vf = signed_volume(c, a, b, d);
        for &i in t {
            mu[i as usize] += vf / (3.0 * vol);
        }
        let cf = scale(add(add(a, b), d), 1.0 / 3.0);
        points[k + f] = lerp(c, cf, 0.9);
        weights[k + f] = 0.5 * vf;
    }
    for i in 0..k {
        points[i] = lerp(c, vertices[i], 0.8);
        weights[i] = 0.5 * mu[i] * vol;
    }
    vol
}

/// `∮ φ_a n` for every vertex `a` (m^2): `Σ_{f ∋ a} A_f n_f / 3`.
pub fn boundary_moments(vertices: &[[f64; 3]], triangles: &[[u32; 3]], out: &mut [[f64; 3]]) {
    out.fill([0.0; 3]);
    for t in triangles {
        let (a, b, d) = (vertices[t[0] as usize], vertices[t[1] as usize], vertices[t[2] as usize]);
        let an = scale(cross(sub(b, a), sub(d, a)), 1.0 / 6.0); // A n / 3
        for &i in t {
            out[i as usize] = add(out[i as usize], an);
        }
    }
}

/// Shifts the gradient table `grad[(3a + i) Q + q]` so that
/// `Σ_q w_q ∇φ_a(x_q) = ∮ φ_a n` for every `a` (see module docs), for
/// shape functions linear on the surface triangles. `moments` is scratch of
/// length `k`.
pub fn consistency_correction(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    weights: &[f64],
    grad: &mut [f64],
    moments: &mut [[f64; 3]],
) {
    boundary_moments(vertices, triangles, moments);
    shift_gradients(weights, grad, moments);
}

/// Shifts the gradient table `grad[(3a + i) Q + q]` by one vector per
/// function so that `Σ_q w_q ∇φ_a(x_q) = moments[a]`, the boundary integral
/// `∮ φ_a n` (m^2) of whatever boundary values the family uses.
pub fn shift_gradients(weights: &[f64], grad: &mut [f64], moments: &[[f64; 3]]) {
    let (k, nq) = (moments.len(), weights.len());
    assert_eq!(grad.len(), 3 * k * nq);
    let vol: f64 = weights.iter().sum();
    for a in 0..k {
        for i in 0..3 {
            let row = &mut grad[(3 * a + i) * nq..(3 * a + i + 1) * nq];
            let integral: f64 = row.iter().zip(weights).map(|(g, w)| g * w).sum();
            let shift = (moments[a][i] - integral) / vol;
            row.iter_mut().for_each(|g| *g += shift);
        }
    }
}

/// Gauss–Legendre nodes and weights on `[0, 1]` (Newton on `P_n`).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n {
        let mut z = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, z);
            for j in 2..=n {
                let p2 = ((2 * j - 1) as f64 * z * p1 - (j - 1) as f64 * p0) / j as f64;
                p0 = p1;
                p1 = p2;
            }
            if n == 1 {
                p0 = 1.0;
                p1 = z;
            }
            dp = n as f64 * (z * p1 - p0) / (z * z - 1.0);
            let dz = p1 / dp;
            z -= dz;
            if dz.abs() < 1e-16 {
                break;
            }
        }
        x[i] = 0.5 * (1.0 - z);
        w[i] = 1.0 / ((1.0 - z * z) * dp * dp);
    }
    (x, w)
}

/// The reference rule: [`cone_rule`] from the centroid.
pub fn reference_rule(vertices: &[[f64; 3]], triangles: &[[u32; 3]], n: usize) -> (Vec<[f64; 3]>, Vec<f64>) {
    let (_, c) = volume_centroid(vertices, triangles);
    let mut pts = Vec::new();
    let mut wts = Vec::new();
    cone_rule(vertices, triangles, c, n, &mut pts, &mut wts);
    (pts, wts)
}

/// Gauss rule on the cone of the surface from `apex`: for every surface
/// triangle `(A, B, C)`, the sub-tetrahedron `(c, A, B, C)` (`c` the apex)
/// mapped from the unit cube by `x = c + s (A - c + t (B - A) + t r (C - B))`
/// (Jacobian `6 V s² t`), with `n` Gauss–Legendre points per direction,
/// appended to `points`, `weights`. Exact for polynomials of degree
/// `2n - 3`; the weights are positive and every point strictly inside when
/// the element is star-shaped with respect to `apex` (every sub-tetrahedron
/// positive).
pub fn cone_rule(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    apex: [f64; 3],
    n: usize,
    points: &mut Vec<[f64; 3]>,
    weights: &mut Vec<f64>,
) {
    let c = apex;
    let (g, gw) = gauss_legendre(n);
    for t in triangles {
        let (a, b, d) = (vertices[t[0] as usize], vertices[t[1] as usize], vertices[t[2] as usize]);
        let six_v = 6.0 * signed_volume(c, a, b, d);
        for (i, &s) in g.iter().enumerate() {
            for (j, &tt) in g.iter().enumerate() {
                for (l, &r) in g.iter().enumerate() {
                    let base = add(sub(a, c), add(scale(sub(b, a), tt), scale(sub(d, b), tt * r)));
                    points.push(add(c, scale(base, s)));
                    weights.push(six_v * s * s * tt * gw[i] * gw[j] * gw[l]);
                }
            }
        }
    }
}

/// Barycentric coordinate of the symmetric 4-point tetrahedral rule
/// (Hammer–Marlowe–Stroud): each point is `a` of one vertex and `b` of the
/// other three, `a = (5 + 3√5) / 20`, `b = (5 - √5) / 20`.
const DEGREE2_A: f64 = 0.585_410_196_624_968_5;
const DEGREE2_B: f64 = 0.138_196_601_125_010_5;

/// The symmetric 4-point rule of degree 2 (weights `V / 4`, every point
/// strictly inside) on every sub-tetrahedron `(apex, A, B, C)` of the
/// surface triangles, appended to `points`, `weights`: exact for quadratic
/// polynomials with half the points of the collapsed rule of [`cone_rule`]
/// with `n = 2` (which is exact for degree 1 only). The weights take the
/// sign of each sub-tetrahedron, as [`cone_rule`]'s do.
pub fn cone_rule_degree2(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    apex: [f64; 3],
    points: &mut Vec<[f64; 3]>,
    weights: &mut Vec<f64>,
) {
    for t in triangles {
        let corners = [apex, vertices[t[0] as usize], vertices[t[1] as usize], vertices[t[2] as usize]];
        let quarter = 0.25 * signed_volume(corners[0], corners[1], corners[2], corners[3]);
        for heavy in 0..4 {
            let p = corners
                .iter()
                .enumerate()
                .fold([0.0; 3], |p, (i, &c)| add(p, scale(c, if i == heavy { DEGREE2_A } else { DEGREE2_B })));
            points.push(p);
            weights.push(quarter);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube() -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let v = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 1.0],
            [1.0, 1.0, 1.0],
            [0.0, 1.0, 1.0],
        ];
        let quads = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]];
        let t = quads.iter().flat_map(|q: &[u32; 4]| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        (v, t)
    }

    #[test]
    fn gauss_legendre_integrates_polynomials() {
        for n in 1..8 {
            let (x, w) = gauss_legendre(n);
            for p in 0..2 * n {
                let got: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(p as i32)).sum();
                assert!((got - 1.0 / (p + 1) as f64).abs() < 1e-14, "n {n} degree {p}");
            }
        }
    }

    #[test]
    fn rules_integrate_volume_and_moments() {
        let (v, t) = cube();
        let (vol, c) = volume_centroid(&v, &t);
        assert!((vol - 1.0).abs() < 1e-15 && c.iter().all(|x| (x - 0.5).abs() < 1e-15));
        let q = paper_rule_len(8, t.len());
        let (mut p, mut w, mut mu) = (vec![[0.0; 3]; q], vec![0.0; q], vec![0.0; 8]);
        paper_rule(&v, &t, &mut p, &mut w, &mut mu);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        assert!((mu.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        let (p, w) = reference_rule(&v, &t, 4);
        // ∫ x^2 y z over the unit cube = 1/12
        let got: f64 = p.iter().zip(&w).map(|(p, w)| w * p[0] * p[0] * p[1] * p[2]).sum();
        assert!((got - 1.0 / 12.0).abs() < 1e-14, "{got}");
    }

    /// The 4-point rule integrates every monomial of degree 2 exactly over
    /// the unit cube from an off-centre apex, and not every one of degree 3.
    #[test]
    fn degree2_cone_rule_is_exact_for_quadratics_only() {
        let (v, t) = cube();
        let (mut p, mut w) = (Vec::new(), Vec::new());
        cone_rule_degree2(&v, &t, [0.3, 0.6, 0.45], &mut p, &mut w);
        assert_eq!(p.len(), 4 * t.len());
        let integral = |f: &dyn Fn([f64; 3]) -> f64| p.iter().zip(&w).map(|(&x, w)| w * f(x)).sum::<f64>();
        // ∫ x^i y^j z^l over the unit cube = 1 / ((i+1)(j+1)(l+1))
        for (i, j, l) in
            [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (2, 0, 0), (0, 2, 0), (1, 1, 0), (0, 1, 1), (1, 0, 1)]
        {
            let got = integral(&|x| x[0].powi(i) * x[1].powi(j) * x[2].powi(l));
            let want = 1.0 / ((i + 1) * (j + 1) * (l + 1)) as f64;
            assert!((got - want).abs() < 1e-14, "x^{i} y^{j} z^{l}: {got} against {want}");
        }
        let cubic = integral(&|x| x[0].powi(3));
        assert!((cubic - 0.25).abs() > 1e-6, "degree 3 is not exact: {cubic}");
    }
}
