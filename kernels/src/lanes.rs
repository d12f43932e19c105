//! The arithmetic types kernels are generic over: plain `f64` (the scalar
//! reference) and SIMD lanes with runtime dispatch through `pulp`
//! ([`crate::dual`] adds forward derivatives over either).
//!
//! A kernel written once against [`Real`] runs as the scalar reference
//! (`f64`) and as the fast path ([`Lanes`]). Both use the same arithmetic in
//! the same order (no fused multiply-add, one `atan` polynomial accurate to
//! 4e-16 against `std` for both, every sum taken within one lane), so they
//! agree to the bit: results do not depend on the instruction set the
//! machine offers. Every kernel's test forces each level this machine has
//! (scalar, AVX2, AVX-512) and compares bits.

use core::ops::{Add, Div, Mul, Neg, Sub};

use pulp::Simd;

/// A real number, or a pack of them processed together.
pub trait Real:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self> + Neg<Output = Self>
{
    /// The constant `v` in every lane (uses `self` only for its SIMD token).
    fn constant(self, v: f64) -> Self;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// Lane-wise minimum.
    fn min(self, o: Self) -> Self;
    /// Lane-wise maximum.
    fn max(self, o: Self) -> Self;
    /// Lane-wise `if self < other { a } else { b }`.
    fn select_less(self, other: Self, a: Self, b: Self) -> Self;
    /// The largest lane.
    fn max_lane(self) -> f64;
    /// `self * a + b` (not fused).
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self {
        self * a + b
    }
    /// `atan2(self, x)` for `self >= 0`: the angle in `[0, π]` of the point
    /// `(x, self)`. Range reduction to `t = min / max ∈ [0, 1]`, then
    /// `atan(t)` as `π/4 + atan((t - 1) / (t + 1))` above 0.66, by Cephes'
    /// rational function (relative error below 4e-16, tested against `std`).
    /// The reduced argument takes one division, `(min - max) / (min + max)`
    /// or `min / max` chosen before it; the numerator and denominator
    /// polynomials are split in halves in `z²` (Estrin), so the chain of
    /// dependent operations is short: a mean value basis evaluates an
    /// arctangent per edge and point, and waited on this chain.
    #[inline(always)]
    fn atan2_upper(self, x: Self) -> Self {
        let ax = x.abs();
        let lo = self.min(ax);
        let hi = self.max(ax);
        let (zero, one) = (self.constant(0.0), self.constant(1.0));
        // 1 where min / max > 0.66
        let big = (self.constant(0.66) * hi).select_less(lo, one, zero);
        let num = big.mul_add(zero - hi, lo);
        let den = big.mul_add(lo, hi).max(self.constant(f64::MIN_POSITIVE));
        let tr = num / den;
        let z = tr * tr;
        let z2 = z * z;
        let c = |k: f64| self.constant(k);
        // p = P0 z⁴ + P1 z³ + P2 z² + P3 z + P4
        let p = (c(ATAN_P[0]).mul_add(z, c(ATAN_P[1]))).mul_add(z2, c(ATAN_P[2]).mul_add(z, c(ATAN_P[3])));
        let p = p.mul_add(z, c(ATAN_P[4]));
        // q = z⁵ + Q0 z⁴ + Q1 z³ + Q2 z² + Q3 z + Q4
        let q = (z + c(ATAN_Q[0])).mul_add(z2, c(ATAN_Q[1]).mul_add(z, c(ATAN_Q[2])));
        let q = q.mul_add(z2, c(ATAN_Q[3]).mul_add(z, c(ATAN_Q[4])));
        let r = tr.mul_add(z * p / q, tr);
        // + π/4 (with the low-order part of π/4) where reduced
        let a = big
            .mul_add(self.constant(core::f64::consts::FRAC_PI_4) + self.constant(0.5 * 6.123_233_995_736_766e-17), r);
        // angle of (|x|, y): a if y <= |x|, else π/2 - a
        let a = ax.select_less(self, self.constant(core::f64::consts::FRAC_PI_2) - a, a);
        // reflect for x < 0
        x.select_less(self.constant(0.0), self.constant(core::f64::consts::PI) - a, a)
    }
}

impl Real for f64 {
    #[inline(always)]
    fn constant(self, v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f64::abs(self)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        f64::min(self, o)
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        f64::max(self, o)
    }
    #[inline(always)]
    fn select_less(self, other: Self, a: Self, b: Self) -> Self {
        if self < other {
            a
        } else {
            b
        }
    }
    #[inline(always)]
    fn max_lane(self) -> f64 {
        self
    }
}

/// A pack of `f64` lanes of the SIMD instruction set `S`.
///
/// `mul_add` is deliberately not fused: every lane then rounds exactly like
/// the scalar `f64` reference, so results agree to the bit across AVX-512,
/// AVX2 and the scalar fallback.
#[derive(Clone, Copy, Debug)]
pub struct Lanes<S: Simd> {
    /// The lanes.
    pub v: S::f64s,
    /// The instruction set token (zero-sized).
    pub simd: S,
}

impl<S: Simd> Lanes<S> {
    /// Number of `f64` lanes of `S`.
    pub const WIDTH: usize = core::mem::size_of::<S::f64s>() / 8;

    /// Loads up to `WIDTH` values, padding with zeros.
    #[inline(always)]
    pub fn load(simd: S, values: &[f64]) -> Self {
        match S::as_simd_f64s(values).0.first() {
            Some(&v) => Lanes { v, simd },
            None => Lanes { v: simd.partial_load_f64s(values), simd },
        }
    }

    /// Stores up to `WIDTH` lanes into `out`.
    #[inline(always)]
    pub fn store(self, out: &mut [f64]) {
        match S::as_mut_simd_f64s(out).0.first_mut() {
            Some(v) => *v = self.v,
            None => self.simd.partial_store_f64s(out, self.v),
        }
    }

    /// The coordinates of the points `points[q0..]` (at most `WIDTH`) as
    /// lanes, the last group padded with copies of its first point (so
    /// padding lanes stay where the caller's points are); returns the lanes
    /// and the number of real points.
    #[inline(always)]
    pub fn load_points(simd: S, points: &[[f64; 3]], q0: usize) -> ([Self; 3], usize) {
        let width = Self::WIDTH;
        let n = width.min(points.len() - q0);
        let mut coords = [[0.0f64; 16]; 3];
        for (i, lanes) in coords.iter_mut().enumerate() {
            for (l, p) in points[q0..q0 + n].iter().enumerate() {
                lanes[l] = p[i];
            }
            let first = lanes[0];
            lanes[n..width].fill(first);
        }
        (std::array::from_fn(|i| Self::load(simd, &coords[i][..width])), n)
    }

    /// The same value in every lane.
    #[inline(always)]
    pub fn splat(simd: S, v: f64) -> Self {
        Lanes { v: simd.splat_f64s(v), simd }
    }

    /// Sum of the lanes.
    #[inline(always)]
    pub fn reduce_sum(self) -> f64 {
        self.simd.reduce_sum_f64s(self.v)
    }
}

macro_rules! lane_op {
    ($tr:ident, $f:ident, $op:ident) => {
        impl<S: Simd> $tr for Lanes<S> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                Lanes { v: self.simd.$op(self.v, o.v), simd: self.simd }
            }
        }
    };
}
lane_op!(Add, add, add_f64s);
lane_op!(Sub, sub, sub_f64s);
lane_op!(Mul, mul, mul_f64s);
lane_op!(Div, div, div_f64s);

impl<S: Simd> Neg for Lanes<S> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        Lanes { v: self.simd.neg_f64s(self.v), simd: self.simd }
    }
}

/// Cephes' rational approximation of `atan` on `[-0.42, 0.66]`.
const ATAN_P: [f64; 5] = [
    -8.750_608_600_031_904e-1,
    -1.615_753_718_733_365e1,
    -7.500_855_792_314_705e1,
    -1.228_866_684_490_136e2,
    -6.485_021_904_942_025e1,
];
const ATAN_Q: [f64; 5] = [
    2.485_846_490_142_306e1,
    1.650_270_098_316_988_6e2,
    4.328_810_604_912_903e2,
    4.853_903_996_359_137e2,
    1.945_506_571_482_614e2,
];

impl<S: Simd> Real for Lanes<S> {
    #[inline(always)]
    fn constant(self, v: f64) -> Self {
        Lanes::splat(self.simd, v)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Lanes { v: self.simd.sqrt_f64s(self.v), simd: self.simd }
    }
    #[inline(always)]
    fn abs(self) -> Self {
        Lanes { v: self.simd.abs_f64s(self.v), simd: self.simd }
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        Lanes { v: self.simd.min_f64s(self.v, o.v), simd: self.simd }
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        Lanes { v: self.simd.max_f64s(self.v, o.v), simd: self.simd }
    }
    #[inline(always)]
    fn select_less(self, other: Self, a: Self, b: Self) -> Self {
        let m = self.simd.less_than_f64s(self.v, other.v);
        Lanes { v: self.simd.select_f64s(m, a.v, b.v), simd: self.simd }
    }
    #[inline(always)]
    fn max_lane(self) -> f64 {
        self.simd.reduce_max_f64s(self.v)
    }
}

/// An instruction set the SIMD kernels run on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimdLevel {
    /// Plain `f64`, one lane (pulp's scalar backend).
    Scalar,
    /// x86-64-v3: AVX2 (4 lanes).
    Avx2,
    /// x86-64-v4: AVX-512 (8 lanes).
    Avx512,
}

impl SimdLevel {
    /// The levels this machine runs, lowest first.
    pub fn available() -> Vec<SimdLevel> {
        let mut out = vec![SimdLevel::Scalar];
        #[cfg(target_arch = "x86_64")]
        {
            if pulp::x86::V3::try_new().is_some() {
                out.push(SimdLevel::Avx2);
            }
            if pulp::x86::V4::try_new().is_some() {
                out.push(SimdLevel::Avx512);
            }
        }
        out
    }

    /// Runs `op` at this level; panics where the machine lacks it (see
    /// [`SimdLevel::available`]).
    pub fn run<Op: pulp::WithSimd>(self, op: Op) -> Op::Output {
        match self {
            // `Simd::vectorize` compiles the kernel inside the level's
            // target features (a closure handed to the inherent `vectorize`
            // is not inlined there: the lanes then cost a call each)
            SimdLevel::Scalar => pulp::Simd::vectorize(pulp::Scalar::new(), op),
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 => pulp::Simd::vectorize(pulp::x86::V3::try_new().expect("AVX2 is available"), op),
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => pulp::Simd::vectorize(pulp::x86::V4::try_new().expect("AVX-512 is available"), op),
            #[cfg(not(target_arch = "x86_64"))]
            _ => unreachable!("only scalar runs off x86-64"),
        }
    }
}

/// `Σ a_k b_k` in a fixed order: four interleaved partial sums, then a
/// fixed tree, then the tail. Inlined into a dispatched kernel, the four
/// independent sums fill wide registers, and the result is the same bits
/// at every instruction set (no fused multiply-add, one order).
#[inline(always)]
pub(crate) fn ordered_dot(a: &[f64], b: &[f64]) -> f64 {
    const LANES: usize = 4;
    let (ac, bc) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (at, bt) = (ac.remainder(), bc.remainder());
    let mut s = [0.0f64; LANES];
    for (x, y) in ac.zip(bc) {
        for l in 0..LANES {
            s[l] += x[l] * y[l];
        }
    }
    let mut sum = (s[0] + s[2]) + (s[1] + s[3]);
    for (x, y) in at.iter().zip(bt) {
        sum += x * y;
    }
    sum
}

/// The level every kernel runs at: 0 for the best the machine offers, else
/// `1 + SimdLevel as u8`, resolved to one the machine has when set.
static CAP: core::sync::atomic::AtomicU8 = core::sync::atomic::AtomicU8::new(0);

/// Caps the instruction set of every kernel dispatched from now on, for the
/// whole process (`None`: the best the machine offers, the default); a
/// level the machine lacks caps at the best below it. Results are the same
/// bits at every level (see the module docs); only speed differs, which is
/// what `cleave bench --only simd` measures.
pub fn cap_simd_level(level: Option<SimdLevel>) {
    let resolved = level.map_or(0, |cap| {
        let best = SimdLevel::available().into_iter().rev().find(|&l| l as u8 <= cap as u8);
        1 + best.unwrap_or(SimdLevel::Scalar) as u8
    });
    CAP.store(resolved, core::sync::atomic::Ordering::Relaxed);
}

/// Runs `op` at the best level the machine offers within the cap.
#[inline]
pub fn dispatch<Op: pulp::WithSimd>(op: Op) -> Op::Output {
    match CAP.load(core::sync::atomic::Ordering::Relaxed) {
        0 => pulp::Arch::new().dispatch(op),
        1 => SimdLevel::Scalar.run(op),
        2 => SimdLevel::Avx2.run(op),
        _ => SimdLevel::Avx512.run(op),
    }
}

/// Clears the upper halves of the vector registers (`vzeroupper`) where the
/// machine has AVX. faer's matrix-product kernels are assembly that returns
/// with those halves in use; until something clears them, every plain
/// (SSE) floating-point instruction after it waits on them, and the engine
/// outside its dispatched kernels is built for baseline x86-64, so all of
/// it is plain SSE. A scan over 4,000 points took 0.36 ms after a faer
/// product against 0.12 ms once they were cleared (one core, AMD EPYC
/// Zen 4). Call this where a faer call that may run a product returns to
/// the engine's own code.
#[inline]
pub fn clear_upper_registers() {
    #[cfg(target_arch = "x86_64")]
    if is_x86_feature_detected!("avx") {
        // SAFETY: the machine has AVX, as `zero_upper` requires.
        unsafe { zero_upper() }
    }
}

/// `vzeroupper`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn zero_upper() {
    core::arch::x86_64::_mm256_zeroupper()
}

/// The level a kernel runs at that wider registers than `ceiling` do not
/// speed up: the best the machine has at or below both `ceiling` and the
/// cap. The block sparse product ran 7 to 9% slower at AVX-512 than at
/// AVX2 and than its scalar reference (`cleave bench --only simd`, Intel
/// Xeon with AVX-512, medians of 9 rounds, two runs), and its explicit
/// AVX2 code no faster at AVX-512 (0.36 against 0.33 ms on bunny_100k),
/// so it runs at AVX2 there. The bits are the same at every level.
#[inline]
pub fn dispatched_level(ceiling: SimdLevel) -> SimdLevel {
    level_within(ceiling, CAP.load(core::sync::atomic::Ordering::Relaxed))
}

/// The best level the machine has at or below both `ceiling` and the cap
/// `cap` (as [`CAP`] stores it).
#[inline]
fn level_within(ceiling: SimdLevel, cap: u8) -> SimdLevel {
    let cap = match cap {
        0 => SimdLevel::Avx512,
        1 => SimdLevel::Scalar,
        2 => SimdLevel::Avx2,
        _ => SimdLevel::Avx512,
    };
    let highest = (ceiling as u8).min(cap as u8);
    #[cfg(target_arch = "x86_64")]
    {
        if highest >= SimdLevel::Avx512 as u8 && pulp::x86::V4::try_new().is_some() {
            return SimdLevel::Avx512;
        }
        if highest >= SimdLevel::Avx2 as u8 && pulp::x86::V3::try_new().is_some() {
            return SimdLevel::Avx2;
        }
    }
    SimdLevel::Scalar
}

/// Running a kernel on every instruction set this machine offers, for the
/// tests that hold each kernel's SIMD path bitwise equal to its scalar
/// reference.
#[cfg(test)]
pub(crate) mod levels {
    use super::SimdLevel;

    /// The levels this machine runs; prints them, so that a test's output
    /// says which ran (a missing one is named, not silently skipped).
    pub(crate) fn available(test: &str) -> Vec<SimdLevel> {
        let out = SimdLevel::available();
        let missing: Vec<SimdLevel> =
            [SimdLevel::Avx2, SimdLevel::Avx512].into_iter().filter(|l| !out.contains(l)).collect();
        println!("{test}: ran on {out:?}; not on this machine: {missing:?}");
        out
    }

    /// Runs `op` with the instruction set `level`.
    pub(crate) fn run<Op: pulp::WithSimd>(level: SimdLevel, op: Op) -> Op::Output {
        level.run(op)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The width of the registers a kernel runs on.
    struct Width;
    impl pulp::WithSimd for Width {
        type Output = usize;
        fn with_simd<S: Simd>(self, _simd: S) -> usize {
            S::F64_LANES
        }
    }

    /// A kernel dispatched within a ceiling runs at the best level the
    /// machine has up to it and the cap, never above. (The cap itself is
    /// process-wide, and another test sets it: this one passes it.)
    #[test]
    fn a_ceiling_holds_a_kernel_below_it() {
        let available = SimdLevel::available();
        let lanes = |level: SimdLevel| [1, 4, 8][level as usize];
        for ceiling in [SimdLevel::Scalar, SimdLevel::Avx2, SimdLevel::Avx512] {
            for (cap, capped) in
                [(0, SimdLevel::Avx512), (1, SimdLevel::Scalar), (2, SimdLevel::Avx2), (3, SimdLevel::Avx512)]
            {
                let highest = (ceiling as u8).min(capped as u8);
                let best = available.iter().copied().filter(|&l| l as u8 <= highest).max_by_key(|&l| l as u8);
                let level = level_within(ceiling, cap);
                assert_eq!(Some(level), best, "within {ceiling:?}, cap {cap}, on {available:?}");
                assert_eq!(level.run(Width), lanes(level));
            }
        }
    }

    struct AtanCheck;
    impl pulp::WithSimd for AtanCheck {
        type Output = f64;
        fn with_simd<S: Simd>(self, simd: S) -> f64 {
            let mut worst: f64 = 0.0;
            let n = 20_000;
            for i in 0..=n {
                let phi = std::f64::consts::PI * i as f64 / n as f64;
                for r in [1e-3, 1.0, 7.5] {
                    let (y, x) = (r * phi.sin(), r * phi.cos());
                    let got = Lanes::splat(simd, y).atan2_upper(Lanes::splat(simd, x)).reduce_sum()
                        / Lanes::<S>::WIDTH as f64;
                    let want = y.atan2(x);
                    worst = worst.max((got - want).abs() / want.abs().max(1e-300));
                }
            }
            worst
        }
    }

    #[test]
    fn atan2_polynomial_matches_std() {
        let worst = crate::lanes::dispatch(AtanCheck);
        assert!(worst < 4e-16, "relative error {worst:e}");
        let worst = pulp::WithSimd::with_simd(AtanCheck, pulp::Scalar::new());
        assert!(worst < 4e-16, "relative error {worst:e}");
        let mut worst: f64 = 0.0;
        for i in 0..=20_000 {
            let phi = std::f64::consts::PI * i as f64 / 20_000.0;
            let got = Real::atan2_upper(phi.sin(), phi.cos());
            worst = worst.max((got - phi.sin().atan2(phi.cos())).abs() / phi.max(1e-300));
        }
        assert!(worst < 4e-16, "f64: relative error {worst:e}");
    }
}
