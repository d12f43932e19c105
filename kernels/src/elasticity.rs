//! Isotropic linear elasticity: stiffness blocks and stresses from gradients.
//!
//! For shape functions `φ_a` with gradients `g_a = ∇φ_a` at a quadrature
//! point of weight `w` (m^3), the 3x3 block of `B^T C B` that couples node `a`
//! (rows, displacement components `i`) with node `b` (columns, components
//! `j`) for an isotropic material with Lamé parameters `λ`, `μ` (Pa) is
//!
//! ```text
//! K_ab[i][j] += w (λ g_a[i] g_b[j] + μ g_a[j] g_b[i] + μ (g_a · g_b) δ_ij)   [N/m]
//! ```
//!
//! which is exactly `w B_a^T C B_b` with the 6x6 Voigt matrix `C` of
//! [`voigt_matrix`]; a test checks the two against each other.

use crate::lanes::Lanes;

/// Lamé parameters `(λ, μ)` in Pa from Young's modulus `E` (Pa) and Poisson's
/// ratio `ν` (dimensionless, `-1 < ν < 1/2`).
#[inline]
pub fn lame(young: f64, poisson: f64) -> (f64, f64) {
    let lambda = young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson));
    let mu = young / (2.0 * (1.0 + poisson));
    (lambda, mu)
}

/// The 6x6 isotropic constitutive matrix `C` (Pa), row-major, in the Voigt
/// order `[xx, yy, zz, xy, xz, yz]` with engineering shear strains.
pub fn voigt_matrix(lambda: f64, mu: f64) -> [[f64; 6]; 6] {
    let mut c = [[0.0; 6]; 6];
    for (i, row) in c.iter_mut().enumerate().take(3) {
        row[..3].fill(lambda);
        row[i] = lambda + 2.0 * mu;
    }
    for (i, row) in c.iter_mut().enumerate().skip(3) {
        row[i] = mu;
    }
    c
}

/// The isotropic block `w B_aᵀ C B_b` (N/m, row-major; see the module
/// docs) for gradients `g_a` (rows), `g_b` (columns), weight `w` (m³, a
/// quadrature weight or a tetrahedron's volume times a scale) and Lamé
/// parameters (Pa), evaluated entry by entry as
/// `g_a[i] (wλ g_b)[j] + g_a[j] (wμ g_b)[i] + δ_ij g_a · (wμ g_b)`. With gradients rotated by `R` it is the warped
/// block `R K_ab Rᵀ` ([`crate::corotation`]).
#[inline(always)]
pub fn block(ga: [f64; 3], gb: [f64; 3], w: f64, lambda: f64, mu: f64) -> [f64; 9] {
    let (l, m) = (w * lambda, w * mu);
    let lgb = [l * gb[0], l * gb[1], l * gb[2]];
    let mgb = [m * gb[0], m * gb[1], m * gb[2]];
    let d = ga[0] * mgb[0] + ga[1] * mgb[1] + ga[2] * mgb[2];
    [
        ga[0] * lgb[0] + ga[0] * mgb[0] + d,
        ga[0] * lgb[1] + ga[1] * mgb[0],
        ga[0] * lgb[2] + ga[2] * mgb[0],
        ga[1] * lgb[0] + ga[0] * mgb[1],
        ga[1] * lgb[1] + ga[1] * mgb[1] + d,
        ga[1] * lgb[2] + ga[2] * mgb[1],
        ga[2] * lgb[0] + ga[0] * mgb[2],
        ga[2] * lgb[1] + ga[1] * mgb[2],
        ga[2] * lgb[2] + ga[2] * mgb[2] + d,
    ]
}

/// Scratch values [`element_stiffness`] and its scalar reference need for
/// `k` nodes and `nq` quadrature points: the Gram matrix (`9 k²`) and the
/// gradient table transposed to point-major order (`3 k nq`).
pub fn stiffness_scratch_len(k: usize, nq: usize) -> usize {
    9 * k * k + 3 * k * nq
}

/// Checks the layout of a stiffness computation; panics on a caller bug.
fn check_table(grad: &[f64], weights: &[f64], k: usize, scratch: &[f64], ke: &[f64]) {
    assert_eq!(grad.len(), 3 * k * weights.len(), "grad must hold 3 k Q values");
    assert_eq!(ke.len(), 9 * k * k, "ke must be 3k x 3k");
    assert!(scratch.len() >= stiffness_scratch_len(k, weights.len()), "scratch too small");
}

/// `K_e` (row-major `3k x 3k`, into `ke`) from the Gram matrix of the
/// gradients `S[r][c] = ∫ G_r G_c` (`r = 3a + i`: component `i` of the
/// gradient of function `a`), for `k` functions and Lamé parameters `λ`,
/// `μ`: `K[3a+i][3b+j] = λ S[3a+i][3b+j] + μ S[3a+j][3b+i] + μ δ_ij tr`
/// with `tr = Σ_l S[3a+l][3b+l]`. `s` holds the full `S`, read on and
/// above the block diagonal: the blocks below are the mirror images of
/// those above (for a symmetric `S`, entry `(3b+j, 3a+i)` takes the same
/// operations on the same values as `(3a+i, 3b+j)`), copied rather than
/// computed again, so `K_e` is exactly symmetric.
pub fn stiffness_from_gram(s: &[f64], k: usize, lambda: f64, mu: f64, ke: &mut [f64]) {
    let n = 3 * k;
    for a in 0..k {
        for b in a..k {
            let tr = s[(3 * a) * n + 3 * b] + s[(3 * a + 1) * n + 3 * b + 1] + s[(3 * a + 2) * n + 3 * b + 2];
            for i in 0..3 {
                for j in 0..3 {
                    let v = lambda * s[(3 * a + i) * n + 3 * b + j] + mu * s[(3 * a + j) * n + 3 * b + i];
                    let v = v + if i == j { mu * tr } else { 0.0 };
                    ke[(3 * a + i) * n + 3 * b + j] = v;
                    ke[(3 * b + j) * n + 3 * a + i] = v;
                }
            }
        }
    }
}

/// Element stiffness `K_e = Σ_q w_q B_q^T C B_q` (N/m) for `k` nodes from a
/// gradient table, scalar reference of [`element_stiffness`].
///
/// Layout: `grad[(3a + i) Q + q]` is component `i` of `∇φ_a` at point `q`
/// (1/m), `weights[q]` its weight (m^3), `ke` the dense row-major
/// `3k x 3k` result (entry `(3a + i, 3b + j)` at `(3a + i) 3k + 3b + j`),
/// `scratch` at least [`stiffness_scratch_len`] values. Each Gram entry is
/// the sum `Σ_q (w_q G[r][q]) G[c][q]` taken in increasing `q` from zero,
/// without fused multiply-adds: the SIMD path sums each entry in one lane
/// in the same order, so both agree to the bit on every instruction set.
pub fn element_stiffness_scalar(
    grad: &[f64],
    weights: &[f64],
    k: usize,
    lambda: f64,
    mu: f64,
    scratch: &mut [f64],
    ke: &mut [f64],
) {
    check_table(grad, weights, k, scratch, ke);
    let (n, nq) = (3 * k, weights.len());
    let gram = &mut scratch[..n * n];
    for r in 0..n {
        for c in r..n {
            let (gr, gc) = (&grad[r * nq..(r + 1) * nq], &grad[c * nq..(c + 1) * nq]);
            let mut v = 0.0;
            for q in 0..nq {
                v += weights[q] * gr[q] * gc[q];
            }
            gram[r * n + c] = v;
            gram[c * n + r] = v;
        }
    }
    stiffness_from_gram(gram, k, lambda, mu, ke);
}

/// `out[c0..c0 + P w] = Σ_q (w_q g_q) T[q][c0..c0 + P w]` for `P` whole
/// packs of `w` lanes (row `r` of the Gram matrix, `g` its gradient row,
/// `T` the point-major table with `n` columns), one lane per entry summed
/// in increasing `q`; returns the columns done.
#[inline(always)]
fn packs_of_columns<S: pulp::Simd, const P: usize>(
    simd: S,
    weights: &[f64],
    g: &[f64],
    transposed: &[f64],
    n: usize,
    c0: usize,
    out: &mut [f64],
) -> usize {
    let columns = P * Lanes::<S>::WIDTH;
    let mut acc = [Lanes::splat(simd, 0.0); P];
    for (q, (&w, &g)) in weights.iter().zip(g).enumerate() {
        let a = Lanes::splat(simd, w * g);
        let (row, _) = S::as_simd_f64s(&transposed[q * n + c0..q * n + c0 + columns]);
        for (acc, &v) in acc.iter_mut().zip(row) {
            *acc = *acc + a * Lanes { v, simd };
        }
    }
    let (out, _) = S::as_mut_simd_f64s(&mut out[c0..c0 + columns]);
    for (out, acc) in out.iter_mut().zip(acc) {
        *out = acc.v;
    }
    columns
}

/// The Gram matrix with lanes over its columns: row `r` of `S` gathers
/// `Σ_q a_q G_t[q][c..c + W]` with `a_q = w_q G[r][q]`, one column per lane,
/// up to eight packs of lanes at once ([`packs_of_columns`]; one pack at a
/// time, each point's addition waited for the last: a 24-node element's
/// 72 x 72 matrix over 352 points took 0.32 ms, 0.17 ms in packs of eight,
/// one core of an AMD EPYC Zen 3, AVX2).
struct Gram<'a> {
    weights: &'a [f64],
    /// The gradient table in its own (row-major `n x nq`) order.
    grad: &'a [f64],
    /// The same table point-major, `nq x n`.
    transposed: &'a [f64],
    n: usize,
    gram: &'a mut [f64],
}

impl pulp::WithSimd for Gram<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let Gram { weights, grad, transposed, n, gram } = self;
        let nq = weights.len();
        let width = Lanes::<S>::WIDTH;
        for r in 0..n {
            let gr = &grad[r * nq..(r + 1) * nq];
            // from the pack holding the diagonal on (the entries left of it
            // are overwritten from their mirror images below), in runs of
            // 8, 4, 2 or 1 whole packs side by side: each entry is still one
            // lane's sum in increasing q, but the packs' additions no
            // longer wait for one another
            let mut c0 = r - r % width;
            while c0 < n {
                let out = &mut gram[r * n..(r + 1) * n];
                let packs = (n - c0) / width;
                c0 += match packs {
                    8.. => packs_of_columns::<S, 8>(simd, weights, gr, transposed, n, c0, out),
                    4..=7 => packs_of_columns::<S, 4>(simd, weights, gr, transposed, n, c0, out),
                    2..=3 => packs_of_columns::<S, 2>(simd, weights, gr, transposed, n, c0, out),
                    1 => packs_of_columns::<S, 1>(simd, weights, gr, transposed, n, c0, out),
                    // the last columns, fewer than a pack
                    _ => {
                        let mut acc = Lanes::splat(simd, 0.0);
                        for q in 0..nq {
                            let a = Lanes::splat(simd, weights[q] * gr[q]);
                            acc = acc + a * Lanes::load(simd, &transposed[q * n + c0..q * n + n]);
                        }
                        acc.store(&mut out[c0..]);
                        n - c0
                    }
                };
            }
        }
        for r in 0..n {
            for c in 0..r {
                gram[r * n + c] = gram[c * n + r];
            }
        }
    }
}

/// Element stiffness from a gradient table (see
/// [`element_stiffness_scalar`] for the layout and the summation order),
/// SIMD over the columns of the Gram matrix with the instruction set chosen
/// at run time; bitwise equal to the scalar reference.
pub fn element_stiffness(
    grad: &[f64],
    weights: &[f64],
    k: usize,
    lambda: f64,
    mu: f64,
    scratch: &mut [f64],
    ke: &mut [f64],
) {
    check_table(grad, weights, k, scratch, ke);
    let (n, nq) = (3 * k, weights.len());
    let (gram, transposed) = scratch.split_at_mut(n * n);
    let transposed = &mut transposed[..n * nq];
    for r in 0..n {
        for q in 0..nq {
            transposed[q * n + r] = grad[r * nq + q];
        }
    }
    crate::lanes::dispatch(Gram { weights, grad, transposed, n, gram });
    stiffness_from_gram(gram, k, lambda, mu, ke);
}

/// Cauchy stress (Pa, Voigt order) of the displacement gradient
/// `grad_u[i][j] = ∂u_i/∂x_j`.
#[inline]
pub fn stress(grad_u: [[f64; 3]; 3], lambda: f64, mu: f64) -> [f64; 6] {
    let tr = grad_u[0][0] + grad_u[1][1] + grad_u[2][2];
    [
        lambda * tr + 2.0 * mu * grad_u[0][0],
        lambda * tr + 2.0 * mu * grad_u[1][1],
        lambda * tr + 2.0 * mu * grad_u[2][2],
        mu * (grad_u[0][1] + grad_u[1][0]),
        mu * (grad_u[0][2] + grad_u[2][0]),
        mu * (grad_u[1][2] + grad_u[2][1]),
    ]
}

/// Von Mises equivalent stress (Pa) of a Voigt stress `[xx, yy, zz, xy, xz, yz]`.
#[inline]
pub fn von_mises(s: [f64; 6]) -> f64 {
    let d1 = s[0] - s[1];
    let d2 = s[1] - s[2];
    let d3 = s[2] - s[0];
    (0.5 * (d1 * d1 + d2 * d2 + d3 * d3) + 3.0 * (s[3] * s[3] + s[4] * s[4] + s[5] * s[5])).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `B_a` (6x3) for gradient `g` in Voigt order `[xx, yy, zz, xy, xz, yz]`.
    fn b_matrix(g: [f64; 3]) -> [[f64; 3]; 6] {
        [[g[0], 0.0, 0.0], [0.0, g[1], 0.0], [0.0, 0.0, g[2]], [g[1], g[0], 0.0], [g[2], 0.0, g[0]], [0.0, g[2], g[1]]]
    }

    #[test]
    fn block_formula_equals_bt_c_b() {
        let (l, m) = lame(2.5e5, 0.27);
        let c = voigt_matrix(l, m);
        let ga = [0.3, -1.2, 0.7];
        let gb = [-0.4, 0.9, 2.1];
        let block = block(ga, gb, 0.37, l, m);
        let (ba, bb) = (b_matrix(ga), b_matrix(gb));
        for i in 0..3 {
            for j in 0..3 {
                let mut s = 0.0;
                for p in 0..6 {
                    for q in 0..6 {
                        s += ba[p][i] * c[p][q] * bb[q][j];
                    }
                }
                let want = 0.37 * s;
                assert!((block[3 * i + j] - want).abs() <= 1e-12 * want.abs().max(1.0), "{i}{j}");
            }
        }
    }

    /// For 5 nodes (the Gram matrix's columns in one run of packs) and 13
    /// (several runs, the last partial).
    #[test]
    fn simd_stiffness_matches_scalar_bitwise_and_the_block_formula() {
        for (k, nq) in [(5, 7), (13, 11)] {
            stiffness_matches(k, nq);
        }
    }

    fn stiffness_matches(k: usize, nq: usize) {
        let (l, m) = lame(3e5, 0.31);
        let grad: Vec<f64> = (0..3 * k * nq).map(|i| ((i * 37 % 19) as f64 - 9.0) / 7.0 + 1e-3 * i as f64).collect();
        let weights: Vec<f64> = (0..nq).map(|q| 0.1 + q as f64 * 0.03).collect();
        let mut scratch = vec![0.0; stiffness_scratch_len(k, nq)];
        let (mut a, mut b) = (vec![0.0; 9 * k * k], vec![0.0; 9 * k * k]);
        element_stiffness_scalar(&grad, &weights, k, l, m, &mut scratch, &mut a);
        element_stiffness(&grad, &weights, k, l, m, &mut scratch, &mut b);
        assert_eq!(a, b, "the dispatched path");
        // every instruction set, forced
        let n = 3 * k;
        let mut transposed = vec![0.0; n * nq];
        for r in 0..n {
            for q in 0..nq {
                transposed[q * n + r] = grad[r * nq + q];
            }
        }
        for level in crate::lanes::levels::available("stiffness") {
            let mut gram = vec![0.0; n * n];
            let op = Gram { weights: &weights, grad: &grad, transposed: &transposed, n, gram: &mut gram };
            crate::lanes::levels::run(level, op);
            let mut c = vec![0.0; n * n];
            stiffness_from_gram(&gram, k, l, m, &mut c);
            assert_eq!(a, c, "{level:?}");
        }
        // against the block formula, point by point
        let n = 3 * k;
        for aa in 0..k {
            for bb in 0..k {
                let mut sum = [0.0; 9];
                for q in 0..nq {
                    let g = |v: usize| [0, 1, 2].map(|i| grad[(3 * v + i) * nq + q]);
                    let add = block(g(aa), g(bb), weights[q], l, m);
                    (0..9).for_each(|i| sum[i] += add[i]);
                }
                for i in 0..3 {
                    for j in 0..3 {
                        let want = sum[3 * i + j];
                        assert!((a[(3 * aa + i) * n + 3 * bb + j] - want).abs() <= 1e-12 * want.abs().max(1.0));
                    }
                }
            }
        }
    }

    #[test]
    fn stress_of_uniaxial_strain() {
        let (l, m) = lame(1e5, 0.3);
        let s = stress([[1e-3, 0.0, 0.0], [0.0; 3], [0.0; 3]], l, m);
        assert!((s[0] - (l + 2.0 * m) * 1e-3).abs() < 1e-9);
        assert!((s[1] - l * 1e-3).abs() < 1e-9);
        // pure shear: von Mises = sqrt(3) |tau|
        assert!((von_mises([0.0, 0.0, 0.0, 2.0, 0.0, 0.0]) - 2.0 * 3f64.sqrt()).abs() < 1e-12);
    }
}
