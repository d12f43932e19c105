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
//! `w_j` and leaves `φ_j` unchanged; so does any common factor, and the
//! evaluation takes `2 m` for `m` (one multiplication of dual numbers less
//! per coordinate and triangle). It forms `λ_a / d_a` as `(m · n_bc) /
//! ((x_a - x) · n_bc)`, and `u_j` from `x_j - x`, the offset's gradient
//! `-I` applied directly instead of carried through dual products.
//!
//! Gradients `∇φ_j` (1/m) come from forward dual numbers carried through the
//! same arithmetic (the printed gradient formulas of wicke2007, eq. 20-21,
//! are garbled), so value and gradient can never disagree.
//!
//! The arcs belong to edges, not triangles: the two triangles on an edge
//! see it in opposite directions, where `n_ji = -n_ij` and `β_ji = β_ij`
//! hold exactly in floating point (the cross product's two terms swap, the
//! dot product's are the same). So each edge's arc is computed once per
//! point, half the arcs of a per-triangle loop (each arc takes a square
//! root, a division and an arctangent on dual numbers: the evaluation of an
//! 8- or 16-vertex element runs 16 % fewer instructions, callgrind), and the
//! results are the same bits.
//!
//! Data layout of [`evaluate`]: `vertices[k]`, `triangles[t]` (local vertex
//! indices), `points[q]` in; `phi[a * Q + q]` and
//! `grad[(3 a + i) * Q + q]` (component `i` of `∇φ_a` at point `q`) out.
//! Lanes run over the points of one element: every lane shares the
//! element's vertices and triangles, so nothing is gathered.

use dyn_stack::{DynArray, MemStack, StackReq};
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
fn arc<R: Real>(a: [Dual<R>; 3], b: [Dual<R>; 3]) -> ([Dual<R>; 3], Dual<R>) {
    let (n, s) = unit_and_length(cross(a, b));
    (n, s.atan2_upper(dot(a, b)))
}

/// `c / |c|` and `|c|` with one division: `ρ = 1 / |c|` gives the
/// length's gradient `∇|c| = ρ ∇(c · c) / 2` and the reciprocal's
/// `∇ρ = -ρ² ∇|c|`.
#[inline(always)]
fn unit_and_length<R: Real>(c: [Dual<R>; 3]) -> ([Dual<R>; 3], Dual<R>) {
    let q = dot(c, c);
    let s = q.v.sqrt();
    let rho = s.constant(1.0) / s;
    let half_rho = s.constant(0.5) * rho;
    let length = Dual { v: s, d: [q.d[0] * half_rho, q.d[1] * half_rho, q.d[2] * half_rho] };
    let minus_rho2 = s.constant(0.0) - rho * rho;
    let inv = Dual { v: rho, d: [length.d[0] * minus_rho2, length.d[1] * minus_rho2, length.d[2] * minus_rho2] };
    ([c[0] * inv, c[1] * inv, c[2] * inv], length)
}

/// `r / |r|` for the offset `r = x_j - x` of a vertex from the point, with
/// its gradient `∂(r_i / |r|) / ∂x_k = (u_i u_k - δ_ik) / |r|`.
#[inline(always)]
fn unit_offset<R: Real>(r: [R; 3]) -> [Dual<R>; 3] {
    let s = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    let rho = s.constant(1.0) / s;
    let u = [r[0] * rho, r[1] * rho, r[2] * rho];
    // (written out: a closure the compiler does not inline runs without
    // the instruction set chosen at run time, and took twice the time)
    let w = [u[0] * rho, u[1] * rho, u[2] * rho];
    let (u01, u02, u12) = (u[0] * w[1], u[0] * w[2], u[1] * w[2]);
    [
        Dual { v: u[0], d: [u[0] * w[0] - rho, u01, u02] },
        Dual { v: u[1], d: [u01, u[1] * w[1] - rho, u12] },
        Dual { v: u[2], d: [u02, u12, u[2] * w[2] - rho] },
    ]
}

/// `r · n` for the offset `r = x_j - x` of a vertex from the point (its
/// gradient `-I`): `∇(r · n) = (∇n)ᵀ r - n`, without carrying the offset's
/// constant gradient through a product of dual numbers.
#[inline(always)]
fn offset_dot<R: Real>(r: [R; 3], n: [Dual<R>; 3]) -> Dual<R> {
    let v = r[0] * n[0].v + r[1] * n[1].v + r[2] * n[2].v;
    let d = [
        r[0] * n[0].d[0] + r[1] * n[1].d[0] + r[2] * n[2].d[0] - n[0].v,
        r[0] * n[0].d[1] + r[1] * n[1].d[1] + r[2] * n[2].d[1] - n[1].v,
        r[0] * n[0].d[2] + r[1] * n[1].d[2] + r[2] * n[2].d[2] - n[2].v,
    ];
    Dual { v, d }
}

/// Marks an arc that runs against its edge's stored direction.
const FLIPPED: u32 = 1 << 31;

/// The scratch of one element's evaluation, from the caller's stack (see
/// [`evaluate_scratch`]): the edges of its surface triangles, each
/// unordered vertex pair once (`ends`, in the direction of its first
/// triangle, numbered through a `k x k` table of directed pairs that
/// [`Work::new`] keeps only while it lists them), per triangle its
/// arcs `b→c`, `c→a`, `a→b` as edge numbers ([`FLIPPED`] set where the arc
/// runs against its edge); and the per-point arrays: `u`, the offsets
/// `x_j - x` (values only) and `w` per vertex (`w` the output of
/// [`weights`]), `normals`, `angles` per edge.
struct Work<'s, R> {
    ends: DynArray<'s, [u32; 2]>,
    arcs: DynArray<'s, [u32; 3]>,
    edges: usize,
    u: DynArray<'s, [Dual<R>; 3]>,
    offsets: DynArray<'s, [R; 3]>,
    w: DynArray<'s, Dual<R>>,
    normals: DynArray<'s, [Dual<R>; 3]>,
    angles: DynArray<'s, Dual<R>>,
}

impl<'s, R: Real> Work<'s, R> {
    /// The edges of `triangles` (vertex numbers below `k`) and zeroed
    /// per-point arrays (`zero` a zero of the lanes).
    fn new(stack: &'s mut MemStack, k: usize, triangles: &[[u32; 3]], zero: R) -> Self {
        let nt = triangles.len();
        let (mut table, stack) = stack.make_with(k * k, |_| u32::MAX);
        let (mut ends, stack) = stack.make_with(3 * nt, |_| [0u32; 2]);
        let (mut arcs, stack) = stack.make_with(nt, |_| [0u32; 3]);
        let mut edges = 0;
        for (t, codes) in triangles.iter().zip(arcs.iter_mut()) {
            for (code, (i, j)) in codes.iter_mut().zip([(t[1], t[2]), (t[2], t[0]), (t[0], t[1])]) {
                let (i, j) = (i as usize, j as usize);
                if table[i * k + j] == u32::MAX {
                    ends[edges] = [i as u32, j as u32];
                    table[i * k + j] = edges as u32;
                    table[j * k + i] = edges as u32 | FLIPPED;
                    edges += 1;
                }
                *code = table[i * k + j];
            }
        }
        let z = Dual::constant_of(zero);
        let (u, stack) = stack.make_with(k, |_| [z; 3]);
        let (offsets, stack) = stack.make_with(k, |_| [zero; 3]);
        let (w, stack) = stack.make_with(k, |_| z);
        let (normals, stack) = stack.make_with(edges, |_| [z; 3]);
        let (angles, _) = stack.make_with(edges, |_| z);
        Work { ends, arcs, edges, u, offsets, w, normals, angles }
    }
}

/// The arc of `code` from the per-edge `normals` and `angles`: the edge's,
/// its normal negated where the arc is [`FLIPPED`].
#[inline(always)]
fn arc_of<R: Real>(code: u32, normals: &[[Dual<R>; 3]], angles: &[Dual<R>]) -> ([Dual<R>; 3], Dual<R>) {
    let e = (code & !FLIPPED) as usize;
    let n = normals[e];
    (if code & FLIPPED == 0 { n } else { [-n[0], -n[1], -n[2]] }, angles[e])
}

/// Mean value weights `2 w_j` at `x`, with their gradients with respect
/// to `x`, into `work.w`. Every helper is `#[inline(always)]` so that the
/// SIMD instruction set chosen at run time reaches all of the arithmetic.
#[inline(always)]
fn weights<R: Real>(vertices: &[[f64; 3]], triangles: &[[u32; 3]], x: [R; 3], work: &mut Work<R>) {
    let Work { ends, arcs, edges, u, offsets, w, normals, angles } = work;
    let zero = Dual::constant_of(x[0].constant(0.0));
    for (j, p) in vertices.iter().enumerate() {
        let r = [x[0].constant(p[0]) - x[0], x[1].constant(p[1]) - x[1], x[2].constant(p[2]) - x[2]];
        u[j] = unit_offset(r);
        offsets[j] = r;
        w[j] = zero;
    }
    for (e, &[i, j]) in ends[..*edges].iter().enumerate() {
        (normals[e], angles[e]) = arc(u[i as usize], u[j as usize]);
    }
    for (t, codes) in triangles.iter().zip(arcs.iter()) {
        let (ia, ib, ic) = (t[0] as usize, t[1] as usize, t[2] as usize);
        let (n_bc, b_bc) = arc_of(codes[0], normals, angles);
        let (n_ca, b_ca) = arc_of(codes[1], normals, angles);
        let (n_ab, b_ab) = arc_of(codes[2], normals, angles);
        let m = [
            b_bc * n_bc[0] + b_ca * n_ca[0] + b_ab * n_ab[0],
            b_bc * n_bc[1] + b_ca * n_ca[1] + b_ab * n_ab[1],
            b_bc * n_bc[2] + b_ca * n_ca[2] + b_ab * n_ab[2],
        ];
        w[ia] = w[ia] + dot(m, n_bc) / offset_dot(offsets[ia], n_bc);
        w[ib] = w[ib] + dot(m, n_ca) / offset_dot(offsets[ib], n_ca);
        w[ic] = w[ic] + dot(m, n_ab) / offset_dot(offsets[ic], n_ab);
    }
}

/// `φ_j` and `∇φ_j` at `x` into `work.w` (normalised in place).
#[inline(always)]
fn shape_functions<R: Real>(vertices: &[[f64; 3]], triangles: &[[u32; 3]], x: [R; 3], work: &mut Work<R>) {
    weights(vertices, triangles, x, work);
    let w = &mut *work.w;
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
/// with `k` vertices and `triangles` surface triangles: the edge tables
/// (`k² + 5 T` integers) and `3 k + 4 · 3T` dual numbers of the widest
/// lanes (`3 T` bounds the edges, shared or not).
pub fn evaluate_scratch(k: usize, triangles: usize) -> StackReq {
    let dual = |n: usize| StackReq::new::<[f64; 4 * crate::MAX_LANES]>(n);
    let point = |n: usize| StackReq::new::<[f64; 12 * crate::MAX_LANES]>(n);
    StackReq::all_of(&[
        StackReq::new::<u32>(k * k),
        StackReq::new::<[u32; 2]>(3 * triangles),
        StackReq::new::<[u32; 3]>(triangles),
        point(k),
        dual(k),
        dual(k),
        point(3 * triangles),
        dual(3 * triangles),
    ])
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
    let mut work = Work::new(stack, k, triangles, 0.0);
    for (q, p) in points.iter().enumerate() {
        shape_functions(vertices, triangles, *p, &mut work);
        for (a, wa) in work.w.iter().enumerate() {
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
        let mut work = Work::new(stack, k, triangles, Lanes::splat(simd, 0.0));
        for q0 in (0..nq).step_by(width) {
            let (x, n) = Lanes::load_points(simd, points, q0);
            shape_functions(vertices, triangles, x, &mut work);
            for (a, wa) in work.w.iter().enumerate() {
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

    /// The weights with each triangle computing its own three arcs (the
    /// plain form of the formula in the module docs, with its `½`), on
    /// `f64` duals, times 2 (exactly).
    fn weights_per_triangle(v: &[[f64; 3]], t: &[[u32; 3]], p: [f64; 3]) -> Vec<Dual<f64>> {
        let r: Vec<[f64; 3]> = v.iter().map(|q| std::array::from_fn(|i| q[i] - p[i])).collect();
        let u: Vec<[Dual<f64>; 3]> = r.iter().map(|&r| unit_offset(r)).collect();
        let mut w = vec![Dual::constant_of(0.0); v.len()];
        let half = Dual::constant_of(0.5);
        for t in t {
            let [a, b, c] = t.map(|i| i as usize);
            let [(n_bc, b_bc), (n_ca, b_ca), (n_ab, b_ab)] = [arc(u[b], u[c]), arc(u[c], u[a]), arc(u[a], u[b])];
            let m: [Dual<f64>; 3] = std::array::from_fn(|i| half * (b_bc * n_bc[i] + b_ca * n_ca[i] + b_ab * n_ab[i]));
            w[a] = w[a] + dot(m, n_bc) / offset_dot(r[a], n_bc);
            w[b] = w[b] + dot(m, n_ca) / offset_dot(r[b], n_ca);
            w[c] = w[c] + dot(m, n_ab) / offset_dot(r[c], n_ab);
        }
        let two = Dual::constant_of(2.0);
        w.into_iter().map(|w| two * w).collect()
    }

    /// Arcs computed once per edge, the reversed ones negated, give the
    /// bits of every triangle computing its own (and `2 m` those of `m`,
    /// doubled).
    #[test]
    fn arcs_per_edge_give_the_bits_of_arcs_per_triangle() {
        let (v, t) = element();
        let mut buf = dyn_stack::MemBuffer::new(evaluate_scratch(v.len(), t.len()));
        for i in 0..23 {
            let p = [0.05 + 0.04 * i as f64, 0.9 - 0.035 * i as f64, 0.1 + 0.037 * i as f64];
            let mut work = Work::new(MemStack::new(&mut buf), v.len(), &t, 0.0);
            assert_eq!(work.edges, 3 * v.len() - 6, "a closed surface's edges, each once");
            weights(&v, &t, p, &mut work);
            for (a, (per_edge, per_triangle)) in work.w.iter().zip(weights_per_triangle(&v, &t, p)).enumerate() {
                let bits = |w: &Dual<f64>| [w.v, w.d[0], w.d[1], w.d[2]].map(f64::to_bits);
                assert_eq!(bits(per_edge), bits(&per_triangle), "weight {a} at {p:?}");
            }
        }
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
        let mut buf = dyn_stack::MemBuffer::new(evaluate_scratch(v.len(), t.len()));
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
