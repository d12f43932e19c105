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

/// The weighted kernel column of the MFS fit for the centre `c` (scaled
/// coordinates): `out_i = w_i (1 / |x_i - c|)` over the points given by
/// coordinate (`coords[d][i]`), the same values as the plain loop of
/// [`kernel_column_scalar`]: `1/r` by four Newton steps from a first guess
/// made of the bits of `r²` (within 1.2 units in the last place), the same
/// bits at every register width.
pub fn kernel_column(coords: [&[f64]; 3], c: [f64; 3], weights: &[f64], out: &mut [f64]) {
    assert!(coords.iter().all(|x| x.len() == out.len()) && weights.len() == out.len(), "one value per point");
    crate::lanes::dispatch(KernelColumn { coords, c, weights, out });
}

/// [`kernel_column`] without dispatch: the scalar reference.
pub fn kernel_column_scalar(coords: [&[f64]; 3], c: [f64; 3], weights: &[f64], out: &mut [f64]) {
    column_loop(coords, c, weights, out);
}

struct KernelColumn<'a> {
    coords: [&'a [f64]; 3],
    c: [f64; 3],
    weights: &'a [f64],
    out: &'a mut [f64],
}

impl pulp::WithSimd for KernelColumn<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        column_loop(self.coords, self.c, self.weights, self.out);
    }
}

/// The loop of [`kernel_column`], inlined where it runs so that the
/// compiler vectorises it for the instruction set at hand.
#[inline(always)]
fn column_loop(coords: [&[f64]; 3], c: [f64; 3], weights: &[f64], out: &mut [f64]) {
    let n = out.len();
    let (x, y, z, w) = (&coords[0][..n], &coords[1][..n], &coords[2][..n], &weights[..n]);
    for i in 0..n {
        let (dx, dy, dz) = (x[i] - c[0], y[i] - c[1], z[i] - c[2]);
        out[i] = w[i] * inverse_sqrt(squared_length(dx, dy, dz));
    }
}

/// `dx² + dy² + dz²` with two fused multiply-adds (exactly rounded, so
/// the same bits in every lane and in the scalar reference).
#[inline(always)]
fn squared_length(dx: f64, dy: f64, dz: f64) -> f64 {
    dx.mul_add(dx, dy.mul_add(dy, dz * dz))
}

/// `1 / √s` for `s > 0` by four Newton steps `y ← y (3/2 - (s/2) y²)`
/// from the first guess that halving the bit pattern of `s` gives (the
/// exponent halved and negated by one integer subtraction, within 3.5 % of
/// the root; the errors after each step are 1.8e-3, 4.7e-6, 3.3e-11 and
/// then rounding's). Each step is a multiplication, a fused
/// multiply-add and a multiplication: fused operations round exactly once
/// wherever they run, so the vectorised loops give the scalar bits at
/// every register width (the scalar reference, built for plain x86-64,
/// calls the library's `fma` for them: slow, but the same bits). Against
/// four unfused operations per step, the kernel column of the simd bench
/// (248 centres x 744 points) went from 13.9 to 9.8 ms at AVX-512 and
/// from 19.1 to 14.6 ms at AVX2 (Intel Xeon). The division and the square
/// root it replaces share one unit, which bounded the kernel columns
/// whatever the width (`s = 0` gives `∞`, as `1 / √0` does).
#[inline(always)]
fn inverse_sqrt(s: f64) -> f64 {
    const FIRST_GUESS: u64 = 0x5fe6_eb50_c7b5_37a9;
    let mut y = f64::from_bits(FIRST_GUESS.wrapping_sub(s.to_bits() >> 1));
    let half = 0.5 * s;
    for _ in 0..4 {
        y *= (-half).mul_add(y * y, 1.5);
    }
    if s == 0.0 {
        f64::INFINITY
    } else {
        y
    }
}

/// The value and gradient of the kernel `1 / |x - c|` at the points `x_i`
/// given by coordinate (`coords[d][i]`): `value_i = 1 / r_i` (1/m) and
/// `gradient[d]_i = -(x_i - c)_d / r_i³` (1/m²), `r_i = |x_i - c|`. One
/// column of each of the four kernel matrices whose products with the
/// weights give the functions' values and gradients at many points at once
/// (the element store's path; [`evaluate`] sums point by point). `1/r` by
/// the Newton steps of [`kernel_column`], the same bits at every register
/// width.
pub fn kernel_columns_with_gradient(coords: [&[f64]; 3], c: [f64; 3], value: &mut [f64], gradient: [&mut [f64]; 3]) {
    let n = value.len();
    assert!(coords.iter().all(|x| x.len() == n) && gradient.iter().all(|g| g.len() == n), "one value per point");
    crate::lanes::dispatch(GradientColumns { coords, c, value, gradient });
}

/// [`kernel_columns_with_gradient`] without dispatch: the scalar reference.
pub fn kernel_columns_with_gradient_scalar(
    coords: [&[f64]; 3],
    c: [f64; 3],
    value: &mut [f64],
    gradient: [&mut [f64]; 3],
) {
    gradient_loop(coords, c, value, gradient);
}

struct GradientColumns<'a> {
    coords: [&'a [f64]; 3],
    c: [f64; 3],
    value: &'a mut [f64],
    gradient: [&'a mut [f64]; 3],
}

impl pulp::WithSimd for GradientColumns<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        gradient_loop(self.coords, self.c, self.value, self.gradient);
    }
}

/// The loop of [`kernel_columns_with_gradient`], inlined where it runs so
/// that the compiler vectorises it for the instruction set at hand.
#[inline(always)]
fn gradient_loop(coords: [&[f64]; 3], c: [f64; 3], value: &mut [f64], gradient: [&mut [f64]; 3]) {
    let n = value.len();
    let (x, y, z) = (&coords[0][..n], &coords[1][..n], &coords[2][..n]);
    let [gx, gy, gz] = gradient;
    let (gx, gy, gz) = (&mut gx[..n], &mut gy[..n], &mut gz[..n]);
    for i in 0..n {
        let (dx, dy, dz) = (x[i] - c[0], y[i] - c[1], z[i] - c[2]);
        let inv = inverse_sqrt(squared_length(dx, dy, dz));
        let inv3 = inv * inv * inv;
        value[i] = inv;
        (gx[i], gy[i], gz[i]) = (-dx * inv3, -dy * inv3, -dz * inv3);
    }
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

    /// The Newton reciprocal square root over a hundred binades: its
    /// relative error `δ` (from the residual `1 - s y² ≈ 2δ`, taken with
    /// fused products so that it is exact to first order) stays within the
    /// rounding of the steps, and `y` within two units in the last place of
    /// the correctly rounded square root's reciprocal.
    #[test]
    fn the_newton_inverse_square_root_is_within_rounding() {
        let mut worst = 0.0f64;
        for e in -50..50 {
            for i in 0..4000 {
                let s = (1.0 + i as f64 / 4000.0) * 2f64.powi(e);
                let y = inverse_sqrt(s);
                let p = s * y;
                let residual = -(p.mul_add(y, -1.0) + s.mul_add(y, -p) * y);
                let ulp = f64::EPSILON * y;
                worst = worst.max((0.5 * residual * y).abs() / ulp);
                assert!((y - 1.0 / s.sqrt()).abs() <= 2.0 * ulp, "s = {s:e}: {y:e}");
            }
        }
        assert!(worst <= 1.5, "{worst} ulp");
        assert_eq!(inverse_sqrt(0.0), f64::INFINITY);
        assert!(inverse_sqrt(f64::NAN).is_nan());
    }

    #[test]
    fn kernel_columns_agree_on_every_instruction_set() {
        let n = 37;
        let coords: [Vec<f64>; 3] =
            std::array::from_fn(|d| (0..n).map(|i| ((i * (d + 3)) as f64 * 0.37).sin()).collect());
        let weights: Vec<f64> = (0..n).map(|i| if i < 5 { 10.0 } else { 1.0 }).collect();
        let (c, coords) = ([1.7, -0.4, 2.1], [&coords[0][..], &coords[1][..], &coords[2][..]]);
        let mut reference = vec![0.0; n];
        kernel_column_scalar(coords, c, &weights, &mut reference);
        for (i, v) in reference.iter().enumerate() {
            let r = (0..3).map(|d| (coords[d][i] - c[d]).powi(2)).sum::<f64>().sqrt();
            assert!((v - weights[i] / r).abs() <= 1e-15 * v.abs(), "point {i}");
        }
        for level in crate::lanes::levels::available("kernel column") {
            let mut out = vec![0.0; n];
            crate::lanes::levels::run(level, KernelColumn { coords, c, weights: &weights, out: &mut out });
            assert_eq!(out, reference, "{level:?}");
        }
    }

    /// The kernel's value and gradient columns: the same bits on every
    /// instruction set, `1/r` to rounding, and the gradient against central
    /// differences of the value.
    #[test]
    fn kernel_gradient_columns_agree_on_every_instruction_set_and_with_differences() {
        let n = 37;
        let coords: [Vec<f64>; 3] =
            std::array::from_fn(|d| (0..n).map(|i| ((i * (d + 3)) as f64 * 0.37).sin()).collect());
        let (c, coords) = ([1.7, -0.4, 2.1], [&coords[0][..], &coords[1][..], &coords[2][..]]);
        /// The value column and the three gradient columns.
        type Columns = [Vec<f64>; 4];
        let columns = |fill: &mut dyn FnMut(&mut Columns)| {
            let mut out: Columns = std::array::from_fn(|_| vec![0.0; n]);
            fill(&mut out);
            out
        };
        let reference = columns(&mut |[v, gx, gy, gz]| kernel_columns_with_gradient_scalar(coords, c, v, [gx, gy, gz]));
        for (i, v) in reference[0].iter().enumerate() {
            let r = (0..3).map(|d| (coords[d][i] - c[d]).powi(2)).sum::<f64>().sqrt();
            assert!((v - 1.0 / r).abs() <= 1e-15 * v.abs(), "point {i}");
            for d in 0..3 {
                let h = 1e-6;
                let at = |s: f64| {
                    let r = (0..3).map(|e| (coords[e][i] + if e == d { s } else { 0.0 } - c[e]).powi(2)).sum::<f64>();
                    1.0 / r.sqrt()
                };
                let fd = (at(h) - at(-h)) / (2.0 * h);
                assert!((fd - reference[1 + d][i]).abs() <= 1e-7 * (1.0 + fd.abs()), "point {i}, direction {d}");
            }
        }
        for level in crate::lanes::levels::available("kernel gradient columns") {
            let got = columns(&mut |[v, gx, gy, gz]| {
                crate::lanes::levels::run(level, GradientColumns { coords, c, value: v, gradient: [gx, gy, gz] })
            });
            assert_eq!(got, reference, "{level:?}");
        }
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
