//! The least-squares fit of the method of fundamental solutions
//! (martin2008 §5, eq. 11-14), in 2D (faces) and 3D (elements).
//!
//! In coordinates scaled to the element (`x̂ = (x - o) / s`, so the fit is
//! well scaled whatever the units), each of the `k` functions is
//! `N(x̂) = Σ_j w_j ψ(|x̂ - k̂_j|) + c · x̂ + d` with `ψ(r) = log r` in 2D and
//! `ψ(r) = 1/r` in 3D. The `m ≈ 3n` collocation equations
//! `N(ĉ_i) = b(ĉ_i)` are solved in the least-squares sense by a Householder
//! QR factorisation (faer, sequential: the caller runs elements in
//! parallel), once for all `k` right-hand sides.
//!
//! The fitted coefficients are then projected, with the smallest change,
//! onto those that reproduce constants and linear functions exactly:
//! `Σ_a N_a = 1` and `Σ_a x̂_a N_a = x̂` hold for the coefficients
//! themselves, so partition of unity and linear reproduction hold to
//! rounding everywhere, whatever the MFS error (the linear term makes the
//! exact solution representable; the projection removes the rounding the
//! QR solve amplifies on ill-conditioned kernel matrices).

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::qr::no_pivoting::factor;
use faer::linalg::solvers::DenseSolveCore;
use faer::{Conj, Mat, Par};

/// The fundamental solution of the Laplacian in `D` dimensions (up to a
/// constant factor): `log r` in 2D, `1/r` in 3D.
fn kernel<const D: usize>(r: f64) -> f64 {
    if D == 2 {
        r.ln()
    } else {
        1.0 / r
    }
}

/// Weight of the collocation equations at the nodes relative to the others.
pub(super) const NODE_WEIGHT: f64 = 10.0;

/// Coefficients of `k` MFS functions in scaled coordinates: row-major
/// `(n + D + 1) x k`, rows `0..n` the kernel weights, rows `n..n + D` the
/// linear coefficients, row `n + D` the constant.
pub(super) struct Fit<const D: usize> {
    /// Kernel centres in scaled coordinates.
    pub centres: Vec<[f64; D]>,
    /// Coefficients, row-major `(n + D + 1) x k`.
    pub coefficients: Vec<f64>,
    /// Number of functions.
    pub k: usize,
    /// Largest deviation `|N_a(c_i) - b_a(c_i)|` at the collocation points.
    pub max_error: f64,
    /// Root mean square of the same deviations.
    pub rms_error: f64,
}

impl<const D: usize> Fit<D> {
    /// Values of every function at the scaled point `x` into `out` (`k`).
    pub fn values(&self, x: [f64; D], out: &mut [f64]) {
        let (n, k) = (self.centres.len(), self.k);
        out.fill(0.0);
        for (j, c) in self.centres.iter().enumerate() {
            let psi = kernel::<D>(distance(x, *c));
            for (o, w) in out.iter_mut().zip(&self.coefficients[j * k..(j + 1) * k]) {
                *o += w * psi;
            }
        }
        for i in 0..=D {
            let xi = if i < D { x[i] } else { 1.0 };
            for (o, w) in out.iter_mut().zip(&self.coefficients[(n + i) * k..(n + i + 1) * k]) {
                *o += w * xi;
            }
        }
    }
}

/// `out_i = w_i ψ(|x_i - c|)` for the points `x_i` given by coordinate
/// (`coords[d][i]`): the kernel column of centre `c`, the same values as
/// `w_i * kernel(distance(x_i, c))` (in 3D by the dispatched kernel of
/// [`cleave_kernels::harmonic::kernel_column`]).
fn kernel_column<const D: usize>(coords: &[Vec<f64>; D], c: [f64; D], weights: &[f64], out: &mut [f64]) {
    if let (Some(coords), Some(c)) = (<&[Vec<f64>; 3]>::try_from(&coords[..]).ok(), <[f64; 3]>::try_from(&c[..]).ok()) {
        cleave_kernels::harmonic::kernel_column([&coords[0], &coords[1], &coords[2]], c, weights, out);
    } else {
        for (i, v) in out.iter_mut().enumerate() {
            let r2 = (0..D).map(|d| (coords[d][i] - c[d]) * (coords[d][i] - c[d])).sum::<f64>();
            *v = weights[i] * kernel::<D>(r2.sqrt());
        }
    }
}

fn distance<const D: usize>(a: [f64; D], b: [f64; D]) -> f64 {
    (0..D).map(|i| (a[i] - b[i]) * (a[i] - b[i])).sum::<f64>().sqrt()
}

/// Fits `k` functions to `targets` (row-major `m x k`) at the scaled
/// `collocation` points, with kernels at `centres`; `nodes` are the scaled
/// node positions whose linear functions the result reproduces exactly.
/// The first `k` collocation points must be the nodes: their equations
/// weigh [`NODE_WEIGHT`] times more, which keeps the Lagrange property
/// `N_a(x_b) ≈ δ_ab` where the hat functions' kinks make the fit hardest.
/// Returns `None` when the system is rank deficient or the result not finite.
pub(super) fn fit<const D: usize>(
    centres: Vec<[f64; D]>,
    collocation: &[[f64; D]],
    targets: &[f64],
    nodes: &[[f64; D]],
) -> Option<Fit<D>> {
    let (n, m, k) = (centres.len(), collocation.len(), nodes.len());
    let cols = n + D + 1;
    assert_eq!(targets.len(), m * k);
    if m < cols {
        return None;
    }
    let row_weight = |i: usize| if i < k { NODE_WEIGHT } else { 1.0 };
    // filled column by column, as faer stores it, each kernel column by one
    // loop over the points' coordinates held as separate arrays (it
    // vectorises; the per-entry closure of `Mat::from_fn` took a fifth of a
    // 24-node element's build)
    let weights: Vec<f64> = (0..m).map(row_weight).collect();
    let coords: [Vec<f64>; D] = std::array::from_fn(|d| collocation.iter().map(|c| c[d]).collect());
    let mut a = Mat::<f64>::zeros(m, cols);
    for j in 0..cols {
        let column = a.col_mut(j).try_as_col_major_mut().expect("a fresh matrix is column-major").as_slice_mut();
        match j {
            j if j < n => kernel_column::<D>(&coords, centres[j], &weights, column),
            j if j < n + D => column.iter_mut().zip(&weights).zip(&coords[j - n]).for_each(|((v, w), x)| *v = w * x),
            _ => column.copy_from_slice(&weights),
        }
    }
    let system = a.clone();
    let mut rhs = Mat::<f64>::from_fn(m, k, |i, a| row_weight(i) * targets[i * k + a]);
    let block = factor::recommended_block_size::<f64>(m, cols);
    let mut mem = MemBuffer::new(StackReq::any_of(&[
        factor::qr_in_place_scratch::<f64>(m, cols, block, Par::Seq, Default::default()),
        faer::linalg::qr::no_pivoting::solve::solve_lstsq_in_place_scratch::<f64>(m, cols, block, k, Par::Seq),
    ]));
    let stack = MemStack::new(&mut mem);
    let mut h = Mat::<f64>::zeros(block, cols);
    factor::qr_in_place(a.as_mut(), h.as_mut(), Par::Seq, stack, Default::default());
    // a rank-deficient R (coincident kernels) makes the solve meaningless
    let rmax = (0..cols).map(|i| a[(i, i)].abs()).fold(0.0, f64::max);
    if !(rmax > 0.0) || (0..cols).any(|i| !(a[(i, i)].abs() > 1e-13 * rmax)) {
        return None;
    }
    faer::linalg::qr::no_pivoting::solve::solve_lstsq_in_place_with_conj(
        a.as_ref(),
        h.as_ref(),
        a.as_ref(),
        Conj::No,
        rhs.as_mut(),
        Par::Seq,
        stack,
    );
    let mut coefficients: Vec<f64> = (0..cols).flat_map(|r| (0..k).map(move |c| (r, c))).map(|rc| rhs[rc]).collect();
    reproduce_linear::<D>(&mut coefficients, n, nodes)?;
    if !coefficients.iter().all(|c| c.is_finite()) {
        return None;
    }
    // the fit's deviations from the targets, by one matrix product
    let c = Mat::<f64>::from_fn(cols, k, |r, a| coefficients[r * k + a]);
    let mut values = Mat::<f64>::zeros(m, k);
    faer::linalg::matmul::matmul(values.as_mut(), faer::Accum::Replace, system.as_ref(), c.as_ref(), 1.0, Par::Seq);
    let (mut max_error, mut sum_sq) = (0.0f64, 0.0);
    for i in 0..m {
        for a in 0..k {
            let d = values[(i, a)] / row_weight(i) - targets[i * k + a];
            max_error = max_error.max(d.abs());
            sum_sq += d * d;
        }
    }
    let rms_error = (sum_sq / (m * k) as f64).sqrt();
    Some(Fit { centres, coefficients, k, max_error, rms_error })
}

/// Projects the coefficients (row-major `(n + D + 1) x k`) onto the affine
/// set where `Σ_a C[:, a] = e_const` and `Σ_a x̂_a,i C[:, a] = e_lin_i`
/// with the least change: `C -= (C P - T) (PᵀP)⁻¹ Pᵀ`, `P = [1, x̂_a]`.
fn reproduce_linear<const D: usize>(c: &mut [f64], n: usize, nodes: &[[f64; D]]) -> Option<()> {
    let k = nodes.len();
    let rows = n + D + 1;
    let p = |a: usize, l: usize| if l == 0 { 1.0 } else { nodes[a][l - 1] };
    // Gram matrix PᵀP ((D+1)²) and its inverse by Gauss–Jordan
    let dim = D + 1;
    let g = Mat::<f64>::from_fn(dim, dim, |r, s| (0..k).map(|a| p(a, r) * p(a, s)).sum());
    let ginv = g.partial_piv_lu().inverse();
    if !ginv.col_iter().all(|col| col.iter().all(|v| v.is_finite())) {
        return None;
    }
    let target = |row: usize, l: usize| if (l == 0 && row == n + D) || (l > 0 && row == n + l - 1) { 1.0 } else { 0.0 };
    for row in 0..rows {
        let ci = &mut c[row * k..(row + 1) * k];
        // residual E = C P - T of this row
        let e: Vec<f64> = (0..dim).map(|l| (0..k).map(|a| ci[a] * p(a, l)).sum::<f64>() - target(row, l)).collect();
        let eg: Vec<f64> = (0..dim).map(|s| (0..dim).map(|r| e[r] * ginv[(r, s)]).sum()).collect();
        for (a, v) in ci.iter_mut().enumerate() {
            *v -= (0..dim).map(|s| eg[s] * p(a, s)).sum::<f64>();
        }
    }
    Some(())
}
