//! Trivariate monomials `ξ^a η^b ζ^c` up to degree 4, in graded order, with
//! the tables the discontinuous Galerkin family needs: products, partial
//! derivatives and the re-expression of a polynomial under an affine change
//! of variables `ξ' = α ξ + β`.
//!
//! Order: by degree, then by decreasing `a`, then decreasing `b`:
//! `1, ξ, η, ζ, ξ², ξη, ξζ, η², ηζ, ζ², ξ³, ...`, so the first 4 monomials
//! span the linear polynomials and the first 10 the quadratic ones.

/// The highest degree tabulated (products of two quadratics).
pub const MAX_DEGREE: usize = 4;

/// Number of monomials of degree at most `d` in three variables:
/// `(d + 1)(d + 2)(d + 3) / 6`.
pub const fn count(d: usize) -> usize {
    (d + 1) * (d + 2) * (d + 3) / 6
}

/// Number of monomials of degree at most [`MAX_DEGREE`].
pub const MAX_COUNT: usize = count(MAX_DEGREE);

/// The exponents `[a, b, c]` of every monomial up to [`MAX_DEGREE`], in the
/// order of the module docs.
pub const EXPONENTS: [[u8; 3]; MAX_COUNT] = exponents();

const fn exponents() -> [[u8; 3]; MAX_COUNT] {
    let mut out = [[0u8; 3]; MAX_COUNT];
    let mut i = 0;
    let mut d = 0;
    while d <= MAX_DEGREE {
        let mut a = d as i32;
        while a >= 0 {
            let mut b = d as i32 - a;
            while b >= 0 {
                out[i] = [a as u8, b as u8, (d as i32 - a - b) as u8];
                i += 1;
                b -= 1;
            }
            a -= 1;
        }
        d += 1;
    }
    out
}

/// Index of the monomial with exponents `e` (degree at most
/// [`MAX_DEGREE`]).
pub const fn index(e: [u8; 3]) -> usize {
    let (a, b, c) = (e[0] as usize, e[1] as usize, e[2] as usize);
    let d = a + b + c;
    // monomials of lower degree, then within degree d: those with a larger
    // `a` (d - a' + 1 of each), then those with this `a` and a larger `b`
    let mut before = if d == 0 { 0 } else { count(d - 1) };
    let mut x = d;
    while x > a {
        before += d - x + 1;
        x -= 1;
    }
    before + (d - a - b)
}

/// Degree of monomial `i`.
pub const fn degree(i: usize) -> usize {
    let e = EXPONENTS[i];
    (e[0] + e[1] + e[2]) as usize
}

/// Index of the product of monomials `i` and `j` (their degrees summing to
/// at most [`MAX_DEGREE`]).
pub const fn product(i: usize, j: usize) -> usize {
    let (a, b) = (EXPONENTS[i], EXPONENTS[j]);
    index([a[0] + b[0], a[1] + b[1], a[2] + b[2]])
}

/// `∂ m_i / ∂ξ_k = factor · m_j` as `Some((factor, j))`, `None` where it
/// vanishes.
pub const fn derivative(i: usize, k: usize) -> Option<(f64, usize)> {
    let mut e = EXPONENTS[i];
    if e[k] == 0 {
        return None;
    }
    let factor = e[k] as f64;
    e[k] -= 1;
    Some((factor, index(e)))
}

/// Values of every monomial of degree at most `d` at `x`, into `out`
/// (`count(d)` values), for any number type.
#[inline(always)]
pub fn values<R: crate::lanes::Real>(x: [R; 3], d: usize, out: &mut [R]) {
    let one = x[0].constant(1.0);
    let mut powers = [[one; MAX_DEGREE + 1]; 3];
    for k in 0..3 {
        for p in 1..=d {
            powers[k][p] = powers[k][p - 1] * x[k];
        }
    }
    for (i, o) in out.iter_mut().enumerate().take(count(d)) {
        let e = EXPONENTS[i];
        *o = powers[0][e[0] as usize] * powers[1][e[1] as usize] * powers[2][e[2] as usize];
    }
}

/// The matrix `S` (row-major, `count(d)` square) with
/// `m_i(α ξ + β) = Σ_j S[i][j] m_j(ξ)` for every monomial `m_i` of degree at
/// most `d`: the coefficients of a polynomial in the variables `ξ'` become
/// those in `ξ` as `c_ξ = Sᵀ c_ξ'`.
pub fn substitution(alpha: f64, beta: [f64; 3], d: usize, s: &mut [f64]) {
    let n = count(d);
    assert!(d <= MAX_DEGREE && s.len() >= n * n, "substitution table size");
    s[..n * n].fill(0.0);
    // (α ξ_k + β_k)^p = Σ_q C(p, q) α^q β_k^(p-q) ξ_k^q
    let binomial = |p: usize, q: usize| -> f64 {
        let mut c = 1.0;
        for t in 0..q {
            c = c * (p - t) as f64 / (t + 1) as f64;
        }
        c
    };
    for i in 0..n {
        let e = EXPONENTS[i];
        for qa in 0..=e[0] {
            for qb in 0..=e[1] {
                for qc in 0..=e[2] {
                    let factor = |k: usize, p: u8, q: u8| {
                        binomial(p as usize, q as usize) * alpha.powi(q as i32) * beta[k].powi((p - q) as i32)
                    };
                    let c = factor(0, e[0], qa) * factor(1, e[1], qb) * factor(2, e[2], qc);
                    s[i * n + index([qa, qb, qc])] += c;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indices_invert_the_exponent_table() {
        for (i, e) in EXPONENTS.iter().enumerate() {
            assert_eq!(index(*e), i, "{e:?}");
        }
        assert_eq!(&EXPONENTS[..4], &[[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]);
        assert_eq!(EXPONENTS[4], [2, 0, 0]);
        assert_eq!(count(1), 4);
        assert_eq!(count(2), 10);
        assert_eq!(MAX_COUNT, 35);
    }

    #[test]
    fn products_derivatives_and_substitution_agree_with_evaluation() {
        let x = [0.3, -0.7, 1.1];
        let mut v = [0.0; MAX_COUNT];
        values(x, MAX_DEGREE, &mut v);
        for i in 0..count(2) {
            for j in 0..count(2) {
                assert!((v[product(i, j)] - v[i] * v[j]).abs() < 1e-15);
            }
            for k in 0..3 {
                let h = 1e-6;
                let (mut a, mut b) = (x, x);
                a[k] += h;
                b[k] -= h;
                let (mut va, mut vb) = ([0.0; MAX_COUNT], [0.0; MAX_COUNT]);
                values(a, 2, &mut va);
                values(b, 2, &mut vb);
                let fd = (va[i] - vb[i]) / (2.0 * h);
                let exact = derivative(i, k).map_or(0.0, |(f, j)| f * v[j]);
                assert!((fd - exact).abs() < 1e-8, "d m{i} / d x{k}: {fd} vs {exact}");
            }
        }
        let (alpha, beta) = (0.6, [0.2, -1.3, 0.5]);
        let mut s = vec![0.0; count(4) * count(4)];
        substitution(alpha, beta, 4, &mut s);
        let y = [alpha * x[0] + beta[0], alpha * x[1] + beta[1], alpha * x[2] + beta[2]];
        let mut vy = [0.0; MAX_COUNT];
        values(y, 4, &mut vy);
        let n = count(4);
        for i in 0..n {
            let sum: f64 = (0..n).map(|j| s[i * n + j] * v[j]).sum();
            assert!((sum - vy[i]).abs() < 1e-12 * vy[i].abs().max(1.0), "{i}: {sum} vs {}", vy[i]);
        }
    }
}
