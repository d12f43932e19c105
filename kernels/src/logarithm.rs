//! The natural logarithm of every value of a slice, vectorised: the kernel
//! of the 2D method of fundamental solutions is `ln r`, one per entry of a
//! face's kernel matrix and per centre at each point it is evaluated at,
//! and the C library's scalar `ln` took a tenth of a 24-node harmonic
//! element's build.
//!
//! The classic reduction (as in fdlibm's `log`): `x = 2^e m` with
//! `m ∈ [√2/2, √2)`, `f = m - 1`, `s = f / (2 + f)`, and
//! `ln m = f - f²/2 + s (f²/2 + R(s²))` with `R` a minimax polynomial of
//! degree 7 in `s²` (fdlibm's coefficients, error below `2^-58.45`); then
//! `ln x = e ln 2 + ln m`, with `ln 2` split so that `e ln2_hi` is exact.
//! The result is within one unit in the last place of `ln x`.
//!
//! The loop is branch-free adds, multiplies, one division and bit
//! operations, no fused multiply-add, inlined where it is dispatched so
//! the compiler vectorises it for the instruction set at hand: every
//! instruction set gives the same bits as [`ln_in_place_scalar`]. Values
//! outside the positive normal numbers (zero, negatives, subnormals,
//! infinities, NaN) take `f64::ln`, whose results they get.

const MANTISSA: u64 = (1 << 52) - 1;
const ONE_BITS: u64 = 0x3ff0_0000_0000_0000;
/// `2^52` as the bits of an `f64`: or-ed with a biased exponent below
/// `2^11` it reads as `2^52 + exponent`, exactly.
const TWO_52_BITS: u64 = 0x4330_0000_0000_0000;
const LN2_HI: f64 = 0.693_147_180_369_123_8;
const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
const LG1: f64 = 0.666_666_666_666_673_5;
const LG2: f64 = 0.399_999_999_994_094_2;
const LG3: f64 = 0.285_714_287_436_623_9;
const LG4: f64 = 0.222_221_984_321_497_84;
const LG5: f64 = 0.181_835_721_616_180_5;
const LG6: f64 = 0.153_138_376_992_093_73;
const LG7: f64 = 0.147_981_986_051_165_86;

/// `ln x` for a positive normal `x` (see the module docs).
#[inline(always)]
fn ln_normal(x: f64) -> f64 {
    let bits = x.to_bits();
    let m = f64::from_bits((bits & MANTISSA) | ONE_BITS);
    let biased = f64::from_bits((bits >> 52) | TWO_52_BITS) - f64::from_bits(TWO_52_BITS);
    let big = m > std::f64::consts::SQRT_2;
    let m = if big { 0.5 * m } else { m };
    let e = biased - if big { 1022.0 } else { 1023.0 };
    let f = m - 1.0;
    let s = f / (2.0 + f);
    let z = s * s;
    let w = z * z;
    let r = z * (LG1 + w * (LG3 + w * (LG5 + w * LG7))) + w * (LG2 + w * (LG4 + w * LG6));
    let half_f2 = 0.5 * f * f;
    e * LN2_HI - ((half_f2 - (s * (half_f2 + r) + e * LN2_LO)) - f)
}

fn is_normal_positive(x: f64) -> bool {
    (f64::MIN_POSITIVE..f64::INFINITY).contains(&x)
}

/// Replaces every value of `values` by its natural logarithm; SIMD with
/// the instruction set chosen at run time, bitwise equal to
/// [`ln_in_place_scalar`].
pub fn ln_in_place(values: &mut [f64]) {
    if values.iter().all(|&x| is_normal_positive(x)) {
        crate::lanes::dispatch(LnInPlace { values });
    } else {
        ln_in_place_scalar(values);
    }
}

/// [`ln_in_place`] without dispatch: the scalar reference.
pub fn ln_in_place_scalar(values: &mut [f64]) {
    for x in values {
        *x = if is_normal_positive(*x) { ln_normal(*x) } else { x.ln() };
    }
}

struct LnInPlace<'a> {
    values: &'a mut [f64],
}

impl pulp::WithSimd for LnInPlace<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        for x in self.values.iter_mut() {
            *x = ln_normal(*x);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance in units in the last place of `b`.
    fn ulps(a: f64, b: f64) -> f64 {
        let ulp = f64::from_bits(b.abs().to_bits() + 1) - b.abs();
        (a - b).abs() / ulp
    }

    /// Within one unit in the last place of the C library's `ln`, over
    /// every binade from `2^-1022` to `2^1023` and densely around 1 (where
    /// `ln` is small and relative accuracy is hardest), on every
    /// instruction set with the same bits; the values the reduction does
    /// not cover get `f64::ln`'s.
    #[test]
    fn matches_the_library_logarithm_on_every_instruction_set() {
        let mut x: Vec<f64> = (-1022..1023)
            .flat_map(|e| (0..16).map(move |i| 2f64.powi(e) * (1.0 + i as f64 / 16.0 + 1e-3 * (i * e) as f64 % 0.06)))
            .collect();
        x.extend((1..4000).map(|i| 1.0 + (i as f64 - 2000.0) * 1e-7));
        x.extend((1..4000).map(|i| 0.5 + i as f64 * 3.7e-4));
        x.extend([std::f64::consts::SQRT_2, std::f64::consts::FRAC_1_SQRT_2, 1.0, 2.0, f64::MAX, f64::MIN_POSITIVE]);
        let mut reference = x.clone();
        ln_in_place_scalar(&mut reference);
        for (&x, &y) in x.iter().zip(&reference) {
            assert!(ulps(y, x.ln()) <= 1.0, "ln {x:e}: {y:e} against {:e}", x.ln());
        }
        for level in crate::lanes::levels::available("logarithm") {
            let mut values = x.clone();
            crate::lanes::levels::run(level, LnInPlace { values: &mut values });
            assert_eq!(values, reference, "{level:?}");
        }
        let mut dispatched = x.clone();
        ln_in_place(&mut dispatched);
        assert_eq!(dispatched, reference, "the dispatched path");
        let special = [0.0, -0.0, -1.0, 1e-310, f64::INFINITY, f64::NEG_INFINITY, f64::NAN, 3.0];
        let mut values = special;
        ln_in_place(&mut values);
        for (v, x) in values.iter().zip(special) {
            assert!(if v.is_nan() { x.ln().is_nan() } else { *v == x.ln() || ulps(*v, x.ln()) <= 1.0 }, "ln {x}: {v}");
        }
    }
}
