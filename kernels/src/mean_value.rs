//! Mean value coordinates of a closed triangulated polyhedron and their
//! gradients (wicke2007 §3.2; Floater, Kós & Reimers 2005; Ju, Schaefer &
//! Warren 2005).
//!
//! For a point `x` inside the element, with `d_j = |x_j - x|` and unit
//! vectors `u_j = (x_j - x) / d_j`, every surface triangle `(a, b, c)`
//! projects to a spherical triangle on the unit sphere around `x`. Its mean
//! vector (the integral of the unit normal over the spherical triangle) is
//!
//! ```text
//! m = ½ (β_bc n_bc + β_ca n_ca + β_ab n_ab),
//!     n_ij = (u_i × u_j) / |u_i × u_j|,  β_ij = atan2(|u_i × u_j|, u_i · u_j),
//! ```
//!
//! and it splits as `m = λ_a u_a + λ_b u_b + λ_c u_c` with
//! `λ_a = (m · n_bc) / (u_a · n_bc)` (and cyclically). The weights are
//! `w_j = Σ_{triangles ∋ j} λ_j / d_j` and the shape functions
//! `φ_j = w_j / Σ_l w_l`. Reversing every triangle flips the sign of every
//! `w_j` and leaves `φ_j` unchanged.
//!
//! Gradients `∇φ_j` (1/m) come from forward dual numbers carried through the
//! same arithmetic (the printed gradient formulas of wicke2007, eq. 20-21,
//! are garbled), so value and gradient can never disagree.
//!
//! Data layout of [`evaluate`]: `vertices[k]`, `triangles[t]` (local vertex
//! indices), `points[q]` in; `phi[a * Q + q]` and
//! `grad[(3 a + i) * Q + q]` (component `i` of `∇φ_a` at point `q`) out.
//! Lanes run over the points of one element: every lane shares the
//! element's vertices and triangles, so nothing is gathered.

use dyn_stack::{MemStack, StackReq};
use pulp::Simd;

use crate::dual::Dual;
use crate::lanes::{Lanes, Real};

#[inline(always)]
fn cross<R: Real>(a: [R; 3], b: [R; 3]) -> [R; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

#[inline(always)]
fn dot<R: Real>(a: [R; 3], b: [R; 3]) -> R {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Unit normal of the great circle through unit vectors `a`, `b` and the
/// arc angle between them.
#[inline(always)]
fn arc<R: Real>(a: [R; 3], b: [R; 3]) -> ([R; 3], R) {
    let c = cross(a, b);
    let s = dot(c, c).sqrt();
    let inv = s.constant(1.0) / s;
    ([c[0] * inv, c[1] * inv, c[2] * inv], s.atan2_upper(dot(a, b)))
}

/// Mean value weights `w_j` (with gradients) at `x`; `u`, `d`, `w` are
/// scratch of length `k` (`w` is the output). Every helper is
/// `#[inline(always)]` so that the SIMD instruction set chosen at run time
/// reaches all of the arithmetic.
#[inline(always)]
fn weights<R: Real>(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    x: [Dual<R>; 3],
    u: &mut [[Dual<R>; 3]],
    d: &mut [Dual<R>],
    w: &mut [Dual<R>],
) {
    let zero = x[0].constant(0.0);
    let half = x[0].constant(0.5);
    for (j, p) in vertices.iter().enumerate() {
        let r = [x[0].constant(p[0]) - x[0], x[1].constant(p[1]) - x[1], x[2].constant(p[2]) - x[2]];
        let len = dot(r, r).sqrt();
        let inv = len.constant(1.0) / len;
        u[j] = [r[0] * inv, r[1] * inv, r[2] * inv];
        d[j] = len;
        w[j] = zero;
    }
    for t in triangles {
        let (ia, ib, ic) = (t[0] as usize, t[1] as usize, t[2] as usize);
        let (ua, ub, uc) = (u[ia], u[ib], u[ic]);
        let (n_bc, b_bc) = arc(ub, uc);
        let (n_ca, b_ca) = arc(uc, ua);
        let (n_ab, b_ab) = arc(ua, ub);
        let m = [
            half * (b_bc * n_bc[0] + b_ca * n_ca[0] + b_ab * n_ab[0]),
            half * (b_bc * n_bc[1] + b_ca * n_ca[1] + b_ab * n_ab[1]),
            half * (b_bc * n_bc[2] + b_ca * n_ca[2] + b_ab * n_ab[2]),
        ];
        w[ia] = w[ia] + dot(m, n_bc) / (dot(ua, n_bc) * d[ia]);
        w[ib] = w[ib] + dot(m, n_ca) / (dot(ub, n_ca) * d[ib]);
        w[ic] = w[ic] + dot(m, n_ab) / (dot(uc, n_ab) * d[ic]);
    }
}

/// `φ_j` and `∇φ_j` at `x` into `w` (normalised in place).
#[inline(always)]
fn shape_functions<R: Real>(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    x: [Dual<R>; 3],
    u: &mut [[Dual<R>; 3]],
    d: &mut [Dual<R>],
    w: &mut [Dual<R>],
) {
    weights(vertices, triangles, x, u, d, w);
    let mut sum = w[0];
    for wj in &w[1..] {
        sum = sum + *wj;
    }
    for wj in w.iter_mut() {
        *wj = *wj / sum;
    }
}

/// Checks the sizes of an evaluation; panics on a caller bug.
fn check_layout(k: usize, triangles: &[[u32; 3]], points: usize, phi: &[f64], grad: &[f64]) {
    assert!(k >= 4, "a polyhedron has at least 4 vertices");
    assert!(triangles.iter().flatten().all(|&i| (i as usize) < k), "triangle index out of range");
    assert_eq!(phi.len(), k * points, "phi must hold k * Q values");
    assert_eq!(grad.len(), 3 * k * points, "grad must hold 3 k Q values");
}

/// The workspace [`evaluate`] and [`evaluate_scalar`] need for an element
/// with `k` vertices: `5 k` dual numbers of the widest lanes.
pub fn evaluate_scratch(k: usize) -> StackReq {
    let dual = StackReq::new::<[f64; 4 * crate::MAX_LANES]>(k);
    StackReq::all_of(&[StackReq::new::<[f64; 12 * crate::MAX_LANES]>(k), dual, dual])
}

/// Scalar reference of [`evaluate`] (plain `f64`, `std` functions).
pub fn evaluate_scalar(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    points: &[[f64; 3]],
    phi: &mut [f64],
    grad: &mut [f64],
    stack: &mut MemStack,
) {
    let (k, nq) = (vertices.len(), points.len());
    check_layout(k, triangles, nq, phi, grad);
    let z = Dual::constant_of(0.0);
    let (mut u, stack) = stack.make_with(k, |_| [z; 3]);
    let (mut d, stack) = stack.make_with(k, |_| z);
    let (mut w, _) = stack.make_with(k, |_| z);
    for (q, p) in points.iter().enumerate() {
        let x = [Dual::variable(p[0], 0), Dual::variable(p[1], 1), Dual::variable(p[2], 2)];
        shape_functions(vertices, triangles, x, &mut u, &mut d, &mut w);
        for (a, wa) in w.iter().enumerate() {
            phi[a * nq + q] = wa.v;
            for i in 0..3 {
                grad[(3 * a + i) * nq + q] = wa.d[i];
            }
        }
    }
}

struct Evaluate<'a> {
    vertices: &'a [[f64; 3]],
    triangles: &'a [[u32; 3]],
    points: &'a [[f64; 3]],
    phi: &'a mut [f64],
    grad: &'a mut [f64],
    stack: &'a mut MemStack,
}

impl pulp::WithSimd for Evaluate<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Evaluate { vertices, triangles, points, phi, grad, stack } = self;
        let (k, nq) = (vertices.len(), points.len());
        let width = Lanes::<S>::WIDTH;
        let z = Dual::constant_of(Lanes::splat(simd, 0.0));
        let (mut u, stack) = stack.make_with(k, |_| [z; 3]);
        let (mut d, stack) = stack.make_with(k, |_| z);
        let (mut w, _) = stack.make_with(k, |_| z);
        for q0 in (0..nq).step_by(width) {
            let (x, n) = Lanes::load_points(simd, points, q0);
            let x: [Dual<Lanes<S>>; 3] = std::array::from_fn(|i| Dual::variable(x[i], i));
            shape_functions(vertices, triangles, x, &mut u, &mut d, &mut w);
            for (a, wa) in w.iter().enumerate() {
                wa.v.store(&mut phi[a * nq + q0..a * nq + q0 + n]);
                for i in 0..3 {
                    let o = (3 * a + i) * nq + q0;
                    wa.d[i].store(&mut grad[o..o + n]);
                }
            }
        }
    }
}

/// Values and gradients of the mean value shape functions of one element
/// (`vertices`, outward or consistently oriented `triangles`) at `points`
/// strictly inside it; layout in the module docs; `stack` holds at least
/// [`evaluate_scratch`]. SIMD over points with the instruction set chosen
/// at run time.
pub fn evaluate(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    points: &[[f64; 3]],
    phi: &mut [f64],
    grad: &mut [f64],
    stack: &mut MemStack,
) {
    check_layout(vertices.len(), triangles, points.len(), phi, grad);
    crate::lanes::dispatch(Evaluate { vertices, triangles, points, phi, grad, stack });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cube with a corner cut off (k = 10), outward triangles.
    fn element() -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let v = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 1.0],
            [0.0, 1.0, 1.0],
            [1.0, 0.6, 1.0],
            [0.6, 1.0, 1.0],
            [1.0, 1.0, 0.6],
        ];
        let faces: [&[u32]; 7] = [
            &[0, 3, 2, 1],
            &[4, 5, 7, 8, 6],
            &[0, 1, 5, 4],
            &[1, 2, 9, 7, 5],
            &[2, 3, 6, 8, 9],
            &[3, 0, 4, 6],
            &[7, 9, 8],
        ];
        let t = faces.iter().flat_map(|f| (1..f.len() - 1).map(move |i| [f[0], f[i], f[i + 1]])).collect();
        (v, t)
    }

    /// Every instruction set this machine offers (forced one by one) gives
    /// the scalar reference's bits.
    #[test]
    fn instruction_sets_agree_bitwise() {
        let (v, t) = element();
        let pts: Vec<[f64; 3]> =
            (0..11).map(|i| [0.1 + 0.07 * i as f64, 0.5 - 0.03 * i as f64, 0.2 + 0.05 * i as f64]).collect();
        let n = v.len() * pts.len();
        let (mut phi0, mut grad0) = (vec![0.0; n], vec![0.0; 3 * n]);
        let mut buf = dyn_stack::MemBuffer::new(evaluate_scratch(v.len()));
        evaluate_scalar(&v, &t, &pts, &mut phi0, &mut grad0, MemStack::new(&mut buf));
        for level in crate::lanes::levels::available("mean value") {
            let (mut phi, mut grad) = (vec![0.0; n], vec![0.0; 3 * n]);
            let op = Evaluate {
                vertices: &v,
                triangles: &t,
                points: &pts,
                phi: &mut phi,
                grad: &mut grad,
                stack: MemStack::new(&mut buf),
            };
            crate::lanes::levels::run(level, op);
            assert_eq!((&phi, &grad), (&phi0, &grad0), "{level:?}");
        }
        let (mut phi, mut grad) = (vec![0.0; n], vec![0.0; 3 * n]);
        evaluate(&v, &t, &pts, &mut phi, &mut grad, MemStack::new(&mut buf));
        assert_eq!((&phi, &grad), (&phi0, &grad0), "the dispatched path");
    }
}
