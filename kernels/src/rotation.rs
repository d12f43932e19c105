//! Rotation extraction: the rotation `R` of the polar decomposition
//! `F = R S` of a deformation gradient, robust for flat, degenerate and
//! inverted `F`, always proper (`det R = +1`), warm-started.
//!
//! `R` maximises `tr(Rᵀ F)` over rotations. Writing `R ← R exp([δ]×)` and
//! `M = Rᵀ F`, the objective is, to second order,
//!
//! ```text
//! tr M + a · δ - ½ δᵀ H δ,   a = (M₃₂ - M₂₃, M₁₃ - M₃₁, M₂₁ - M₁₂),
//!                            H = tr(M) I - sym(M),
//! ```
//!
//! so Newton's step is `δ = H⁻¹ a` (quadratic convergence), used where `H`
//! is safely positive definite. Elsewhere (far from the solution, flat,
//! degenerate or inverted `F`) the step is that of Müller, Bender, Chentanez
//! & Macklin (2016, "A robust method to extract the rotational part of
//! deformations"), `δ = a / (|tr M| + 1e-9)`, which converges from anywhere.
//! The quaternion update `q ← normalise(q ⊗ (1, δ/2))` turns by
//! `2 atan(|δ|/2)`, has the same fixed point as the exponential map
//! (`a = 0`: `Rᵀ F` symmetric) and needs only a square root. A lane stops
//! updating once `|δ| < TOLERANCE`, so each element's result does not depend
//! on its lane neighbours, the lane width or the thread count.
//!
//! Layout: `f[e]` is `F` row-major (`F[r][c] = f[e][3r + c]`), `q[e]` the
//! unit quaternion `(w, x, y, z)` of `R`, read as the warm start and written
//! as the result.

use pulp::Simd;

use crate::lanes::{Lanes, Real};

/// Convergence threshold on the rotation update angle (rad).
pub const TOLERANCE: f64 = 1e-13;

/// Iteration cap (a cold start from the identity to a half turn takes ~40).
pub const MAX_ITERATIONS: usize = 100;

/// Row-major rotation matrix of the unit quaternion `q = (w, x, y, z)`.
#[inline(always)]
pub fn rotation_matrix<R: Real>(q: [R; 4]) -> [R; 9] {
    let [w, x, y, z] = q;
    let one = w.constant(1.0);
    let two = w.constant(2.0);
    [
        one - two * (y * y + z * z),
        two * (x * y - w * z),
        two * (x * z + w * y),
        two * (x * y + w * z),
        one - two * (x * x + z * z),
        two * (y * z - w * x),
        two * (x * z - w * y),
        two * (y * z + w * x),
        one - two * (x * x + y * y),
    ]
}

/// One element (or one pack of elements): the iteration of the module docs.
/// Returns the quaternion and the number of iterations run.
#[inline(always)]
fn extract<R: Real>(f: [R; 9], mut q: [R; 4]) -> ([R; 4], usize) {
    let zero = q[0].constant(0.0);
    let one = q[0].constant(1.0);
    let half = q[0].constant(0.5);
    let tol = q[0].constant(TOLERANCE);
    for it in 0..MAX_ITERATIONS {
        let r = rotation_matrix(q);
        // M = Rᵀ F
        let mut m = [zero; 9];
        for i in 0..3 {
            for j in 0..3 {
                m[3 * i + j] = r[i] * f[j] + r[3 + i] * f[3 + j] + r[6 + i] * f[6 + j];
            }
        }
        let a = [m[7] - m[5], m[2] - m[6], m[3] - m[1]];
        let tr = m[0] + m[4] + m[8];
        // H = tr(M) I - sym(M)
        let (h00, h11, h22) = (tr - m[0], tr - m[4], tr - m[8]);
        let (h01, h02, h12) = (-half * (m[1] + m[3]), -half * (m[2] + m[6]), -half * (m[5] + m[7]));
        // adjugate and determinant of H
        let c00 = h11 * h22 - h12 * h12;
        let c01 = h02 * h12 - h01 * h22;
        let c02 = h01 * h12 - h02 * h11;
        let c11 = h00 * h22 - h02 * h02;
        let c12 = h01 * h02 - h00 * h12;
        let c22 = h00 * h11 - h01 * h01;
        let det = h00 * c00 + h01 * c01 + h02 * c02;
        let inv_det = one / det;
        let newton = [
            (c00 * a[0] + c01 * a[1] + c02 * a[2]) * inv_det,
            (c01 * a[0] + c11 * a[1] + c12 * a[2]) * inv_det,
            (c02 * a[0] + c12 * a[1] + c22 * a[2]) * inv_det,
        ];
        let inv_tr = one / (tr.abs() + q[0].constant(1e-9));
        let robust = [a[0] * inv_tr, a[1] * inv_tr, a[2] * inv_tr];
        // H safely positive definite: leading minors positive relative to its size
        let size = (h00 + h11 + h22).abs() + q[0].constant(1e-300);
        let eps = q[0].constant(1e-3);
        let pd = h00.min(c22).min(det / (size * size)) / size; // > eps where definite
        let step: [R; 3] = [
            eps.select_less(pd, newton[0], robust[0]),
            eps.select_less(pd, newton[1], robust[1]),
            eps.select_less(pd, newton[2], robust[2]),
        ];
        let angle = (step[0] * step[0] + step[1] * step[1] + step[2] * step[2]).sqrt();
        if angle.max_lane() < TOLERANCE {
            return (q, it);
        }
        // q ⊗ (1, δ/2)
        let (hx, hy, hz) = (step[0] * half, step[1] * half, step[2] * half);
        let [w, x, y, z] = q;
        let n = [
            w - x * hx - y * hy - z * hz,
            x + w * hx + y * hz - z * hy,
            y + w * hy + z * hx - x * hz,
            z + w * hz + x * hy - y * hx,
        ];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2] + n[3] * n[3]).sqrt();
        let inv = one / len;
        // converged lanes keep their quaternion
        q = [
            angle.select_less(tol, q[0], n[0] * inv),
            angle.select_less(tol, q[1], n[1] * inv),
            angle.select_less(tol, q[2], n[2] * inv),
            angle.select_less(tol, q[3], n[3] * inv),
        ];
    }
    (q, MAX_ITERATIONS)
}

/// Scalar reference of [`polar_rotations`]; returns the largest iteration count.
pub fn polar_rotations_scalar(f: &[[f64; 9]], q: &mut [[f64; 4]]) -> usize {
    assert_eq!(f.len(), q.len());
    let mut most = 0;
    for (fe, qe) in f.iter().zip(q.iter_mut()) {
        let (r, it) = extract(*fe, *qe);
        *qe = r;
        most = most.max(it);
    }
    most
}

struct Polar<'a> {
    f: &'a [[f64; 9]],
    q: &'a mut [[f64; 4]],
}

impl pulp::WithSimd for Polar<'_> {
    type Output = usize;
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> usize {
        let width = Lanes::<S>::WIDTH;
        let mut most = 0;
        let mut fl = [[0.0f64; 16]; 9];
        let mut ql = [[0.0f64; 16]; 4];
        // whole lane groups here, the rest by the scalar reference (the two
        // agree to the bit)
        let full = self.f.len() - self.f.len() % width;
        for e0 in (0..full).step_by(width) {
            for l in 0..width {
                let e = e0 + l;
                for c in 0..9 {
                    fl[c][l] = self.f[e][c];
                }
                for c in 0..4 {
                    ql[c][l] = self.q[e][c];
                }
            }
            let fv: [Lanes<S>; 9] = core::array::from_fn(|c| Lanes::load(simd, &fl[c][..width]));
            let qv: [Lanes<S>; 4] = core::array::from_fn(|c| Lanes::load(simd, &ql[c][..width]));
            let (r, it) = extract(fv, qv);
            most = most.max(it);
            for (c, lane) in r.iter().enumerate() {
                lane.store(&mut ql[c][..width]);
            }
            for l in 0..width {
                self.q[e0 + l] = [ql[0][l], ql[1][l], ql[2][l], ql[3][l]];
            }
        }
        most.max(polar_rotations_scalar(&self.f[full..], &mut self.q[full..]))
    }
}

/// Rotations of many deformation gradients (layout in the module docs), SIMD
/// over elements with the instruction set chosen at run time; returns the
/// largest iteration count of a lane group.
pub fn polar_rotations(f: &[[f64; 9]], q: &mut [[f64; 4]]) -> usize {
    assert_eq!(f.len(), q.len());
    crate::lanes::dispatch(Polar { f, q })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mat_mul(a: [f64; 9], b: [f64; 9]) -> [f64; 9] {
        core::array::from_fn(|i| (0..3).map(|k| a[3 * (i / 3) + k] * b[3 * k + i % 3]).sum())
    }

    fn det(a: [f64; 9]) -> f64 {
        a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) + a[2] * (a[3] * a[7] - a[4] * a[6])
    }

    fn quat(angle: f64, axis: [f64; 3]) -> [f64; 4] {
        let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
        let s = (0.5 * angle).sin() / n;
        [(0.5 * angle).cos(), axis[0] * s, axis[1] * s, axis[2] * s]
    }

    #[test]
    fn recovers_rotation_of_stretched_and_sheared_gradients() {
        let cases: Vec<([f64; 4], [f64; 9])> = vec![
            (quat(1.2, [1.0, 2.0, -0.5]), [1.3, 0.1, 0.0, 0.1, 0.8, 0.2, 0.0, 0.2, 1.1]),
            (quat(3.0, [0.0, 0.0, 1.0]), [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]),
            (quat(0.4, [-1.0, 0.3, 0.2]), [2.0, 0.3, 0.1, 0.3, 0.5, 0.0, 0.1, 0.0, 0.9]),
        ];
        let mut f: Vec<[f64; 9]> = cases.iter().map(|(q, s)| mat_mul(rotation_matrix(*q), *s)).collect();
        // more elements than any lane width, with different iteration counts
        for i in 0..21 {
            let t = i as f64;
            f.push(mat_mul(
                rotation_matrix(quat(0.15 * t, [t.sin(), 1.0, t.cos()])),
                [1.0 + 0.01 * t, 0.1, 0.0, 0.0, 0.9, 0.05 * t.sin(), 0.02, 0.0, 1.1],
            ));
        }
        let mut qs = vec![[1.0, 0.0, 0.0, 0.0]; f.len()];
        polar_rotations_scalar(&f, &mut qs);
        for level in crate::lanes::levels::available("rotation") {
            let mut qv = vec![[1.0, 0.0, 0.0, 0.0]; f.len()];
            crate::lanes::levels::run(level, Polar { f: &f, q: &mut qv });
            assert_eq!(qs, qv, "{level:?}: SIMD and scalar agree bitwise");
        }
        // the dispatched path, uncapped and capped at every level (the cap is
        // process-wide: another test dispatching meanwhile runs at this
        // level, which changes only its speed)
        use crate::lanes::{cap_simd_level, SimdLevel};
        for cap in [None, Some(SimdLevel::Scalar), Some(SimdLevel::Avx2), Some(SimdLevel::Avx512)] {
            cap_simd_level(cap);
            let mut qv = vec![[1.0, 0.0, 0.0, 0.0]; f.len()];
            polar_rotations(&f, &mut qv);
            assert_eq!(qs, qv, "the dispatched path capped at {cap:?}");
        }
        cap_simd_level(None);
        for ((want, _), got) in cases.iter().zip(&qs) {
            let (a, b) = (rotation_matrix(*want), rotation_matrix(*got));
            for i in 0..9 {
                assert!((a[i] - b[i]).abs() < 1e-12, "{a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn degenerate_and_inverted_gradients_give_proper_rotations() {
        let f = vec![
            [0.0; 9],                                         // collapsed to a point
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0],    // flattened
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0],   // reflected (inverted)
            [-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0], // point-inverted
        ];
        let mut q = vec![[1.0, 0.0, 0.0, 0.0]; f.len()];
        polar_rotations(&f, &mut q);
        for qe in &q {
            let r = rotation_matrix(*qe);
            assert!(r.iter().all(|x| x.is_finite()));
            assert!((det(r) - 1.0).abs() < 1e-12);
            let rtr = mat_mul([r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8]], r);
            for i in 0..9 {
                assert!((rtr[i] - f64::from(i % 4 == 0)).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn warm_start_converges_in_few_iterations() {
        let q0 = quat(0.7, [0.2, 1.0, 0.4]);
        let s = [1.1, 0.05, 0.0, 0.05, 0.95, 0.02, 0.0, 0.02, 1.02];
        let f = vec![mat_mul(rotation_matrix(q0), s)];
        let mut cold = vec![[1.0, 0.0, 0.0, 0.0]];
        let cold_it = polar_rotations_scalar(&f, &mut cold);
        let f2 = vec![mat_mul(rotation_matrix(quat(0.71, [0.2, 1.0, 0.4])), s)];
        let mut warm = cold.clone();
        let warm_it = polar_rotations_scalar(&f2, &mut warm);
        assert!(warm_it < cold_it && warm_it <= 8, "warm {warm_it}, cold {cold_it}");
    }
}
