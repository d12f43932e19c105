//! Evaluation of harmonic shape functions given by the method of fundamental
//! solutions (martin2008 §5, eq. 11).
//!
//! Each of the `k` shape functions of an element is a superposition of the
//! 3D fundamental solution of the Laplacian around `n` kernel centres `k_j`
//! (outside the element) plus a linear polynomial:
//!
//! ```text
//! N_a(x)  = Σ_j W[j][a] / |x - k_j|  +  c_a · (x - o)  +  d_a          [-]
//! ∇N_a(x) = -Σ_j W[j][a] (x - k_j) / |x - k_j|^3  +  c_a               [1/m]
//! ```
//!
//! with `W` in m, `c_a` in 1/m and the element's origin `o` in m. The
//! functions are harmonic wherever they are defined; the caller fits `W`,
//! `c`, `d` to the element's boundary values.
//!
//! Data layout of [`evaluate`]: `weights[j * k + a]`, `linear[a] = [c_a, d_a]`,
//! `points[q]` in; `phi[a * Q + q]` and `grad[(3 a + i) * Q + q]` out, the
//! layout of [`crate::mean_value`]. Lanes run over points; each lane reads
//! the same centre and weight, so nothing is gathered.

use dyn_stack::{MemStack, StackReq};
use pulp::Simd;

use crate::lanes::{Lanes, Real};

/// The coefficients of the `k` shape functions of one element.
#[derive(Clone, Copy, Debug)]
pub struct MfsFunctions<'a> {
    /// Kernel centres `k_j` (m), `n` of them.
    pub centres: &'a [[f64; 3]],
    /// Kernel weights `W[j][a]` (m), row-major `n x k`.
    pub weights: &'a [f64],
    /// Linear part `[c_a (1/m, 3), d_a]` of each function.
    pub linear: &'a [[f64; 4]],
    /// Origin `o` of the linear part (m).
    pub origin: [f64; 3],
}

impl MfsFunctions<'_> {
    /// Number of shape functions `k`.
    pub fn len(&self) -> usize {
        self.linear.len()
    }

    /// Whether there are no functions.
    pub fn is_empty(&self) -> bool {
        self.linear.is_empty()
    }

    fn check_layout(&self, points: usize, phi: &[f64], grad: &[f64]) {
        let k = self.len();
        assert_eq!(self.weights.len(), self.centres.len() * k, "weights must be n x k");
        assert_eq!(phi.len(), k * points, "phi must hold k * Q values");
        assert_eq!(grad.len(), 3 * k * points, "grad must hold 3 k Q values");
    }
}

/// Accumulates the kernel sums of all functions at the points `x` into
/// `acc[4 a + {0: value, 1..4: gradient}]`, then adds the linear part.
#[inline(always)]
fn accumulate<R: Real>(f: &MfsFunctions, x: [R; 3], acc: &mut [R]) {
    let k = f.len();
    let zero = x[0].constant(0.0);
    acc.fill(zero);
    for (j, c) in f.centres.iter().enumerate() {
        let r = [x[0] - x[0].constant(c[0]), x[1] - x[1].constant(c[1]), x[2] - x[2].constant(c[2])];
        let inv = x[0].constant(1.0) / (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
        let inv3 = inv * inv * inv;
        let g = [zero - r[0] * inv3, zero - r[1] * inv3, zero - r[2] * inv3];
        for (a, &w) in f.weights[j * k..(j + 1) * k].iter().enumerate() {
            let w = x[0].constant(w);
            let s = &mut acc[4 * a..4 * a + 4];
            s[0] = s[0] + w * inv;
            s[1] = s[1] + w * g[0];
            s[2] = s[2] + w * g[1];
            s[3] = s[3] + w * g[2];
        }
    }
    let o = f.origin;
    let local = [x[0] - x[0].constant(o[0]), x[1] - x[1].constant(o[1]), x[2] - x[2].constant(o[2])];
    for (a, l) in f.linear.iter().enumerate() {
        let s = &mut acc[4 * a..4 * a + 4];
        s[0] = s[0] + x[0].constant(l[0]) * local[0] + x[0].constant(l[1]) * local[1] + x[0].constant(l[2]) * local[2];
        s[0] = s[0] + x[0].constant(l[3]);
        for i in 0..3 {
            s[1 + i] = s[1 + i] + x[0].constant(l[i]);
        }
    }
}

/// The workspace [`evaluate`] and [`evaluate_scalar`] need for `k`
/// functions: `4 k` values of the widest lanes.
pub fn evaluate_scratch(k: usize) -> StackReq {
    StackReq::new::<[f64; crate::MAX_LANES]>(4 * k)
}

/// Scalar reference of [`evaluate`].
pub fn evaluate_scalar(f: &MfsFunctions, points: &[[f64; 3]], phi: &mut [f64], grad: &mut [f64], stack: &mut MemStack) {
    let (k, nq) = (f.len(), points.len());
    f.check_layout(nq, phi, grad);
    let (mut acc, _) = stack.make_with(4 * k, |_| 0.0);
    for (q, p) in points.iter().enumerate() {
        accumulate(f, *p, &mut acc);
        for a in 0..k {
            phi[a * nq + q] = acc[4 * a];
            for i in 0..3 {
                grad[(3 * a + i) * nq + q] = acc[4 * a + 1 + i];
            }
        }
    }
}

struct Evaluate<'a> {
    f: &'a MfsFunctions<'a>,
    points: &'a [[f64; 3]],
    phi: &'a mut [f64],
    grad: &'a mut [f64],
    stack: &'a mut MemStack,
}

impl pulp::WithSimd for Evaluate<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Evaluate { f, points, phi, grad, stack } = self;
        let (k, nq) = (f.len(), points.len());
        let width = Lanes::<S>::WIDTH;
        let (mut acc, _) = stack.make_with(4 * k, |_| Lanes::splat(simd, 0.0));
        for q0 in (0..nq).step_by(width) {
            let (x, n) = Lanes::load_points(simd, points, q0);
            accumulate(f, x, &mut acc);
            for a in 0..k {
                acc[4 * a].store(&mut phi[a * nq + q0..a * nq + q0 + n]);
                for i in 0..3 {
                    let o = (3 * a + i) * nq + q0;
                    acc[4 * a + 1 + i].store(&mut grad[o..o + n]);
                }
            }
        }
    }
}

/// Values and gradients of the MFS shape functions `f` at `points` (away
/// from the kernel centres); layout in the module docs. SIMD over points
/// with the instruction set chosen at run time; bitwise equal to
/// [`evaluate_scalar`]; `stack` holds at least [`evaluate_scratch`].
pub fn evaluate(f: &MfsFunctions, points: &[[f64; 3]], phi: &mut [f64], grad: &mut [f64], stack: &mut MemStack) {
    f.check_layout(points.len(), phi, grad);
    crate::lanes::dispatch(Evaluate { f, points, phi, grad, stack });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn functions() -> (Vec<[f64; 3]>, Vec<f64>, Vec<[f64; 4]>) {
        let centres: Vec<[f64; 3]> =
            (0..13).map(|j| [1.5 * (j as f64).cos(), 1.4 * (j as f64 * 0.7).sin(), 1.2 + 0.1 * j as f64]).collect();
        let k = 5;
        let weights = (0..13 * k).map(|i| ((i * 37 % 11) as f64 - 5.0) * 0.1).collect();
        let linear = (0..k).map(|a| [0.1 * a as f64, -0.2, 0.3, 0.05 * a as f64]).collect();
        (centres, weights, linear)
    }

    /// Every instruction set this machine offers (forced one by one) gives
    /// the scalar reference's bits, and the
    /// gradient matches central differences of the value.
    #[test]
    fn instruction_sets_agree_and_gradients_match_differences() {
        let (centres, weights, linear) = functions();
        let f = MfsFunctions { centres: &centres, weights: &weights, linear: &linear, origin: [0.1, 0.2, 0.3] };
        let pts: Vec<[f64; 3]> = (0..11).map(|i| [0.05 * i as f64, 0.3 - 0.02 * i as f64, 0.1]).collect();
        let n = f.len() * pts.len();
        let (mut phi0, mut grad0) = (vec![0.0; n], vec![0.0; 3 * n]);
        let mut buf = dyn_stack::MemBuffer::new(evaluate_scratch(f.len()));
        evaluate_scalar(&f, &pts, &mut phi0, &mut grad0, MemStack::new(&mut buf));
        for level in crate::lanes::levels::available("harmonic") {
            let (mut phi, mut grad) = (vec![0.0; n], vec![0.0; 3 * n]);
            crate::lanes::levels::run(
                level,
                Evaluate { f: &f, points: &pts, phi: &mut phi, grad: &mut grad, stack: MemStack::new(&mut buf) },
            );
            assert_eq!((&phi, &grad), (&phi0, &grad0), "{level:?}");
        }
        let (mut phi, mut grad) = (vec![0.0; n], vec![0.0; 3 * n]);
        evaluate(&f, &pts, &mut phi, &mut grad, MemStack::new(&mut buf));
        assert_eq!((&phi, &grad), (&phi0, &grad0), "the dispatched path");
        let h = 1e-6;
        let nq = pts.len();
        for (q, p) in pts.iter().enumerate() {
            for i in 0..3 {
                let (mut lo, mut hi) = (*p, *p);
                lo[i] -= h;
                hi[i] += h;
                let (mut pl, mut ph, mut g) = (vec![0.0; 5], vec![0.0; 5], vec![0.0; 15]);
                evaluate_scalar(&f, &[lo], &mut pl, &mut g, MemStack::new(&mut buf));
                evaluate_scalar(&f, &[hi], &mut ph, &mut g, MemStack::new(&mut buf));
                for a in 0..f.len() {
                    let fd = (ph[a] - pl[a]) / (2.0 * h);
                    assert!((fd - grad0[(3 * a + i) * nq + q]).abs() < 1e-7, "a {a} i {i} q {q}");
                }
            }
        }
    }
}
