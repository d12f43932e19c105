//! Exact integrals of monomials over planar polygons and polyhedra, by the
//! divergence theorem (kaufmann2008 §6; the recursion of Chin, Lasserre &
//! Sukumar 2015 for homogeneous functions, which reduces volumes to faces
//! and faces to edges, on convex and non-convex shapes alike).
//!
//! For `f` homogeneous of degree `q` (every monomial `m_α` is, with
//! `q = |α|`) and the vector field `(x - x₀) f`:
//!
//! ```text
//! ∫_K f dV = 1/(3 + q) Σ_F b_F ∫_F f dA             (x₀ = 0)
//! ∫_F f dA = 1/(2 + q) [ Σ_e d_e ∫_e f ds + ∫_F x₀·∇f dA ]
//! ```
//!
//! with `a_F` the outward unit normal of face `F`, `b_F = a_F · x` on it,
//! `x₀ = b_F a_F` the foot of the origin on the face's plane, `d_e` the
//! distance from `x₀` to edge `e` along the edge's outward normal in the
//! plane, and `x₀·∇m_α = Σ_k x₀_k α_k m_{α - e_k}` a polynomial of degree
//! `q - 1` (so face moments follow degree by degree). Edge integrals use
//! three-point Gauss–Legendre, exact to degree 5. Everything is exact up to
//! rounding; callers pass coordinates centred on and scaled to the element
//! (order 1) so that rounding stays at the level of `1e-15`.
//!
//! Data layout of [`face_moments`]: `vertices[f n + i]` (the `n` vertices of
//! face `f`, counter-clockwise about its outward normal) in;
//! `moments[f c + α]` (`c = count(d)` monomials of degree at most `d`) and
//! `planes[f] = [a_x, a_y, a_z, b]` out. Lanes run over faces.

use pulp::Simd;

use crate::lanes::{Lanes, Real};
use crate::polynomial::{count, derivative, values, EXPONENTS, MAX_COUNT, MAX_DEGREE};

/// Gauss–Legendre points and weights on `[0, 1]` (three points).
const GAUSS: [(f64, f64); 3] =
    [(0.5 - 0.387_298_334_620_741_7, 5.0 / 18.0), (0.5, 8.0 / 18.0), (0.5 + 0.387_298_334_620_741_7, 5.0 / 18.0)];

/// The most vertices a face may have in [`face_moments`].
pub const MAX_FACE_VERTICES: usize = 64;

#[inline(always)]
fn cross<R: Real>(a: [R; 3], b: [R; 3]) -> [R; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

#[inline(always)]
fn dot<R: Real>(a: [R; 3], b: [R; 3]) -> R {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Moments of one polygon `v` (see the module docs) into `out`
/// (`count(d)` values); returns its plane `[a, b]`.
#[inline(always)]
fn polygon<R: Real>(v: &[[R; 3]], d: usize, out: &mut [R]) -> [R; 4] {
    let n = v.len();
    let zero = v[0][0].constant(0.0);
    // Newell's area vector, the unit normal and the plane offset
    let mut area = [zero; 3];
    let mut mean = [zero; 3];
    for i in 0..n {
        let c = cross(v[i], v[(i + 1) % n]);
        for k in 0..3 {
            area[k] = area[k] + c[k];
            mean[k] = mean[k] + v[i][k];
        }
    }
    // a face without area (coincident vertices) contributes nothing
    let len = dot(area, area).sqrt();
    let tiny = zero.constant(f64::MIN_POSITIVE);
    let inv = len.select_less(tiny, zero, zero.constant(1.0) / len.max(tiny));
    let a = [area[0] * inv, area[1] * inv, area[2] * inv];
    let scale = zero.constant(1.0 / n as f64);
    let b = dot(a, [mean[0] * scale, mean[1] * scale, mean[2] * scale]);
    let x0 = [a[0] * b, a[1] * b, a[2] * b];
    // Σ_e d_e ∫_e m_α ds
    let c = count(d);
    let mut edge_sum = [zero; MAX_COUNT];
    let mut m = [zero; MAX_COUNT];
    for i in 0..n {
        let (p, q) = (v[i], v[(i + 1) % n]);
        let t = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
        // outward in-plane normal times the edge length: t × a
        let nl = cross(t, a);
        // d_e L = (p - x₀)·(t × a) (the length cancels against ds = L dt)
        let dl = dot([p[0] - x0[0], p[1] - x0[1], p[2] - x0[2]], nl);
        for &(s, w) in &GAUSS {
            let s = zero.constant(s);
            let x = [p[0] + s * t[0], p[1] + s * t[1], p[2] + s * t[2]];
            values(x, d, &mut m);
            let f = dl * zero.constant(w);
            for (e, mv) in edge_sum.iter_mut().zip(&m).take(c) {
                *e = *e + f * *mv;
            }
        }
    }
    // degree by degree (lower degrees come first in the order)
    for alpha in 0..c {
        let e = EXPONENTS[alpha];
        let q = (e[0] + e[1] + e[2]) as usize;
        let mut s = edge_sum[alpha];
        for k in 0..3 {
            if let Some((factor, lower)) = derivative(alpha, k) {
                s = s + x0[k] * zero.constant(factor) * out[lower];
            }
        }
        out[alpha] = s * zero.constant(1.0 / (2 + q) as f64);
    }
    [a[0], a[1], a[2], b]
}

/// Checks the layout of a batch of faces; panics on a caller bug.
fn check(n: usize, d: usize, vertices: &[[f64; 3]], moments: &[f64], planes: &[[f64; 4]]) {
    assert!((3..=MAX_FACE_VERTICES).contains(&n), "a face has 3 to {MAX_FACE_VERTICES} vertices");
    assert!(d <= MAX_DEGREE, "degree at most {MAX_DEGREE}");
    let faces = planes.len();
    assert_eq!(vertices.len(), n * faces, "n vertices per face");
    assert_eq!(moments.len(), count(d) * faces, "count(d) moments per face");
}

/// A batch of faces whose moments run with their degree a constant `D`,
/// so that the loops over monomials unroll and their sums stay in
/// registers (with the degree a variable they went through the stack, a
/// store and a load per power and sum: 20480 hexagons at degree 2 took
/// 3.8 ms at AVX-512 and 2.5 ms at AVX2 on AMD Zen 4, 0.58 and 0.76 ms
/// with the degree a constant; at degree 4, 11.9 and 8.0 ms before, 7.3
/// and 6.2 ms after: its 35 sums do not fit the registers, and spills
/// of 512-bit vectors move twice the bytes).
trait AtDegree {
    /// The moments of degree at most `D`.
    fn run<const D: usize>(self);
}

/// `batch.run::<d>()` for a degree `d` checked at most [`MAX_DEGREE`].
#[inline(always)]
fn at_degree(d: usize, batch: impl AtDegree) {
    match d {
        0 => batch.run::<0>(),
        1 => batch.run::<1>(),
        2 => batch.run::<2>(),
        3 => batch.run::<3>(),
        4 => batch.run::<4>(),
        d => unreachable!("degree {d}: checked at most {MAX_DEGREE}"),
    }
}

/// Scalar reference of [`face_moments`].
pub fn face_moments_scalar(n: usize, d: usize, vertices: &[[f64; 3]], moments: &mut [f64], planes: &mut [[f64; 4]]) {
    check(n, d, vertices, moments, planes);
    at_degree(d, Faces { n, d, vertices, moments, planes });
}

/// The operands of [`face_moments`].
struct Faces<'a> {
    n: usize,
    d: usize,
    vertices: &'a [[f64; 3]],
    moments: &'a mut [f64],
    planes: &'a mut [[f64; 4]],
}

/// The scalar reference's faces, one at a time.
impl AtDegree for Faces<'_> {
    #[inline(always)]
    fn run<const D: usize>(self) {
        let Faces { n, vertices, moments, planes, .. } = self;
        let c = count(D);
        for (f, plane) in planes.iter_mut().enumerate() {
            *plane = polygon(&vertices[f * n..(f + 1) * n], D, &mut moments[f * c..(f + 1) * c]);
        }
    }
}

impl pulp::WithSimd for Faces<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        at_degree(self.d, Lanewise { faces: self, simd });
    }
}

/// [`Faces`] in groups of a vector's lanes of `S`.
struct Lanewise<'a, S> {
    faces: Faces<'a>,
    simd: S,
}

impl<S: Simd> AtDegree for Lanewise<'_, S> {
    #[inline(always)]
    fn run<const D: usize>(self) {
        let Lanewise { faces: Faces { n, vertices, moments, planes, .. }, simd } = self;
        let width = Lanes::<S>::WIDTH;
        let c = count(D);
        let z = Lanes::splat(simd, 0.0);
        let mut v = [[z; 3]; MAX_FACE_VERTICES];
        let mut out = [z; MAX_COUNT];
        let faces = planes.len();
        for f0 in (0..faces).step_by(width) {
            let lanes = width.min(faces - f0);
            let face = |l: usize| f0 + if l < lanes { l } else { 0 };
            for (i, vi) in v.iter_mut().enumerate().take(n) {
                *vi = std::array::from_fn(|k| {
                    let mut x = [0.0f64; 16];
                    for (l, slot) in x.iter_mut().enumerate().take(width) {
                        *slot = vertices[face(l) * n + i][k];
                    }
                    Lanes::load(simd, &x[..width])
                });
            }
            let plane = polygon(&v[..n], D, &mut out);
            let mut x = [0.0f64; 16];
            for (alpha, value) in out.iter().enumerate().take(c) {
                value.store(&mut x[..width]);
                for l in 0..lanes {
                    moments[(f0 + l) * c + alpha] = x[l];
                }
            }
            for (k, value) in plane.iter().enumerate() {
                value.store(&mut x[..width]);
                for l in 0..lanes {
                    planes[f0 + l][k] = x[l];
                }
            }
        }
    }
}

/// Moments `∫_F m_α dA` (`|α| <= d`) and planes of a batch of faces with
/// `n` vertices each (layout in the module docs), SIMD over faces; bitwise
/// equal to [`face_moments_scalar`].
pub fn face_moments(n: usize, d: usize, vertices: &[[f64; 3]], moments: &mut [f64], planes: &mut [[f64; 4]]) {
    check(n, d, vertices, moments, planes);
    crate::lanes::dispatch(Faces { n, d, vertices, moments, planes });
}

/// Adds face `F`'s share `b_F / (3 + |α|) ∫_F m_α dA` of every volume
/// moment `∫_K m_α dV` (`|α| <= d`) to `volume`: summed over the faces of a
/// closed polyhedron, with moments and planes from [`face_moments`] (faces
/// counter-clockwise about the outward normal), it gives the polyhedron's
/// moments.
pub fn add_face_to_volume(d: usize, face: &[f64], plane: [f64; 4], volume: &mut [f64]) {
    for (alpha, v) in volume.iter_mut().enumerate().take(count(d)) {
        let e = EXPONENTS[alpha];
        let q = (e[0] + e[1] + e[2]) as f64;
        *v += plane[3] * face[alpha] / (3.0 + q);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lanes::levels;

    /// The unit cube's six faces, outward.
    fn cube() -> Vec<[[f64; 3]; 4]> {
        let c = |i: usize| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64];
        [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
            .iter()
            .map(|f| f.map(c))
            .collect()
    }

    #[test]
    fn cube_moments_are_exact_and_every_level_agrees_bitwise() {
        let d = 4;
        let faces = cube();
        let shift = [-0.3, 0.2, -0.45];
        let vertices: Vec<[f64; 3]> =
            faces.iter().flatten().map(|p| [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]]).collect();
        let (mut m, mut planes) = (vec![0.0; 6 * count(d)], vec![[0.0; 4]; 6]);
        face_moments_scalar(4, d, &vertices, &mut m, &mut planes);
        let mut volume = vec![0.0; count(d)];
        for f in 0..6 {
            add_face_to_volume(d, &m[f * count(d)..(f + 1) * count(d)], planes[f], &mut volume);
        }
        // ∫ x^a y^b z^c over the shifted cube: product of 1-D integrals
        let one = |p: u8, lo: f64| ((lo + 1.0).powi(p as i32 + 1) - lo.powi(p as i32 + 1)) / (p as f64 + 1.0);
        for (alpha, e) in EXPONENTS.iter().enumerate().take(count(d)) {
            let want = one(e[0], shift[0]) * one(e[1], shift[1]) * one(e[2], shift[2]);
            assert!((volume[alpha] - want).abs() < 1e-15, "{e:?}: {} vs {want}", volume[alpha]);
        }
        for level in levels::available("moments") {
            let (mut m2, mut p2) = (vec![0.0; 6 * count(d)], vec![[0.0; 4]; 6]);
            levels::run(level, Faces { n: 4, d, vertices: &vertices, moments: &mut m2, planes: &mut p2 });
            assert_eq!((&m2, &p2), (&m, &planes), "{level:?}");
        }
    }
}
