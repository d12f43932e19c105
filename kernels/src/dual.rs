//! Forward dual numbers over any [`Real`]: a value with its gradient with
//! respect to a point `x ∈ R^3`, so a kernel written against [`Real`]
//! returns exact derivatives when run on `Dual<f64>` or `Dual<Lanes<S>>`
//! (the mean value gradients).

use std::ops::{Add, Div, Mul, Neg, Sub};

use crate::lanes::Real;

/// A forward dual number: a value and its gradient with respect to a point
/// `x ∈ R^3`.
#[derive(Clone, Copy, Debug)]
pub struct Dual<R> {
    /// Value.
    pub v: R,
    /// `∂/∂x_i` of the value.
    pub d: [R; 3],
}

impl<R: Real> Dual<R> {
    /// A constant (zero gradient).
    #[inline(always)]
    pub fn constant_of(v: R) -> Self {
        let z = v.constant(0.0);
        Dual { v, d: [z; 3] }
    }

    /// Coordinate `i` of the variable point, with value `v`.
    #[inline(always)]
    pub fn variable(v: R, i: usize) -> Self {
        let mut d = [v.constant(0.0); 3];
        d[i] = v.constant(1.0);
        Dual { v, d }
    }

    #[inline(always)]
    fn chain(self, v: R, dv: R) -> Self {
        Dual { v, d: [self.d[0] * dv, self.d[1] * dv, self.d[2] * dv] }
    }
}

impl<R: Real> Add for Dual<R> {
    type Output = Self;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Dual { v: self.v + o.v, d: [self.d[0] + o.d[0], self.d[1] + o.d[1], self.d[2] + o.d[2]] }
    }
}

impl<R: Real> Sub for Dual<R> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        Dual { v: self.v - o.v, d: [self.d[0] - o.d[0], self.d[1] - o.d[1], self.d[2] - o.d[2]] }
    }
}

impl<R: Real> Mul for Dual<R> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        Dual {
            v: self.v * o.v,
            d: [
                self.d[0].mul_add(o.v, self.v * o.d[0]),
                self.d[1].mul_add(o.v, self.v * o.d[1]),
                self.d[2].mul_add(o.v, self.v * o.d[2]),
            ],
        }
    }
}

impl<R: Real> Div for Dual<R> {
    type Output = Self;
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        let inv = self.v.constant(1.0) / o.v;
        let q = self.v * inv;
        // (a/b)' = (a' - q b') / b
        Dual {
            v: q,
            d: [(self.d[0] - q * o.d[0]) * inv, (self.d[1] - q * o.d[1]) * inv, (self.d[2] - q * o.d[2]) * inv],
        }
    }
}

impl<R: Real> Neg for Dual<R> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        Dual { v: -self.v, d: [-self.d[0], -self.d[1], -self.d[2]] }
    }
}

impl<R: Real> Real for Dual<R> {
    #[inline(always)]
    fn constant(self, v: f64) -> Self {
        Dual::constant_of(self.v.constant(v))
    }
    #[inline(always)]
    fn abs(self) -> Self {
        let s = self.v.constant(0.0).select_less(self.v, self.v.constant(1.0), self.v.constant(-1.0));
        self.chain(self.v.abs(), s)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        self.select_less(o, self, o)
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        self.select_less(o, o, self)
    }
    #[inline(always)]
    fn max_lane(self) -> f64 {
        self.v.max_lane()
    }
    #[inline(always)]
    fn select_less(self, other: Self, a: Self, b: Self) -> Self {
        let (s, o) = (self.v, other.v);
        Dual {
            v: s.select_less(o, a.v, b.v),
            d: [s.select_less(o, a.d[0], b.d[0]), s.select_less(o, a.d[1], b.d[1]), s.select_less(o, a.d[2], b.d[2])],
        }
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        self.chain(s, self.v.constant(0.5) / s)
    }
    /// `d atan2(y, x) = (x dy - y dx) / (x² + y²)`.
    #[inline(always)]
    fn atan2_upper(self, x: Self) -> Self {
        let v = self.v.atan2_upper(x.v);
        let inv = self.v.constant(1.0) / (x.v * x.v + self.v * self.v);
        let (a, b) = (x.v * inv, self.v * inv);
        Dual { v, d: [a * self.d[0] - b * x.d[0], a * self.d[1] - b * x.d[1], a * self.d[2] - b * x.d[2]] }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dual_derivatives_match_finite_differences() {
        let f = |x: [Dual<f64>; 3]| (x[0] * x[1] + x[2]).sqrt().atan2_upper(x[0] - x[2] * x[2]) / (x[1] + x[0]);
        let p = [0.7, 1.3, -0.4];
        let xd = [Dual::variable(p[0], 0), Dual::variable(p[1], 1), Dual::variable(p[2], 2)];
        let g = f(xd);
        for i in 0..3 {
            let h = 1e-6;
            let mut a = p;
            let mut b = p;
            a[i] += h;
            b[i] -= h;
            let fa = f(a.map(Dual::constant_of)).v;
            let fb = f(b.map(Dual::constant_of)).v;
            let fd = (fa - fb) / (2.0 * h);
            assert!((fd - g.d[i]).abs() < 1e-8 * fd.abs().max(1.0), "{i}: {fd} vs {}", g.d[i]);
        }
    }
}
