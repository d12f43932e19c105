//! The least-squares fit of the method of fundamental solutions
//! (martin2008 §5, eq. 11-14), in 2D (faces) and 3D (elements).
//!
//! In coordinates scaled to the element (`x̂ = (x - o) / s`, so the fit is
//! well scaled whatever the units), each of the `k` functions is
//! `N(x̂) = Σ_j w_j ψ(|x̂ - k̂_j|) + c · x̂ + d` with `ψ(r) = log r` in 2D and
//! `ψ(r) = 1/r` in 3D. The `m` collocation equations (2.5 to 3 per kernel)
//! `N(ĉ_i) = b(ĉ_i)` (weighted: `W A c = W b`) are solved in the
//! least-squares sense, once for all `k` right-hand sides (faer, sequential:
//! the caller runs elements in parallel):
//!
//! - by the normal equations `AᵀW²A c = AᵀW²b` and a Cholesky factorisation,
//!   when the factor's diagonal shows a well-conditioned `A` (the element
//!   kernel matrices of the harmonic tests have condition numbers of `10³`
//!   to `10⁶`, so
//!   `AᵀA`'s are far from the `10¹⁶` of double precision; this halves the
//!   work of a QR factorisation, and the fitted values agree with the QR
//!   solution's to the digits the fit error has);
//! - else (coincident or clustered kernels) by a Householder QR
//!   factorisation, which also detects a rank-deficient `A`.
//!
//! The fitted coefficients are then projected, with the smallest change,
//! onto those that reproduce constants and linear functions exactly:
//! `Σ_a N_a = 1` and `Σ_a x̂_a N_a = x̂` hold for the coefficients
//! themselves, so partition of unity and linear reproduction hold to
//! rounding everywhere, whatever the MFS error (the linear term makes the
//! exact solution representable; the projection removes the rounding the
//! solve amplifies on ill-conditioned kernel matrices).

use std::cell::RefCell;

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt;
use faer::linalg::matmul::matmul;
use faer::linalg::qr::no_pivoting::{factor, solve};
use faer::reborrow::IntoConst;
use faer::{Accum, Conj, MatMut, MatRef, Par};

/// The fundamental solution of the Laplacian in `D` dimensions (up to a
/// constant factor), `ψ(r) = ln r` in 2D and `1/r` in 3D, in place of each
/// squared distance `r²` of `values` (in 2D as `½ ln r²`, by the vectorised
/// logarithm of [`cleave_kernels::logarithm`]).
fn kernel_of_squared<const D: usize>(values: &mut [f64]) {
    if D == 2 {
        cleave_kernels::logarithm::ln_in_place(values);
        values.iter_mut().for_each(|v| *v *= 0.5);
    } else {
        values.iter_mut().for_each(|v| *v = 1.0 / v.sqrt());
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
}

/// How far fitted functions lie from their targets at the collocation
/// points (dimensionless: the targets are shape function values).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitError {
    /// Largest deviation `|N_a(c_i) - b_a(c_i)|`.
    pub max: f64,
    /// Root mean square of the deviations.
    pub rms: f64,
}

impl<const D: usize> Fit<D> {
    /// Values of every function at the scaled point `x` into `out` (`k`).
    pub fn values(&self, x: [f64; D], out: &mut [f64]) {
        const CHUNK: usize = 32;
        let (n, k) = (self.centres.len(), self.k);
        out.fill(0.0);
        let mut psi = [0.0; CHUNK];
        for (chunk, centres) in self.centres.chunks(CHUNK).enumerate() {
            let psi = &mut psi[..centres.len()];
            for (p, c) in psi.iter_mut().zip(centres) {
                *p = (0..D).map(|i| (x[i] - c[i]) * (x[i] - c[i])).sum::<f64>();
            }
            kernel_of_squared::<D>(psi);
            for (j, psi) in (chunk * CHUNK..).zip(psi.iter()) {
                for (o, w) in out.iter_mut().zip(&self.coefficients[j * k..(j + 1) * k]) {
                    *o += w * psi;
                }
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
/// (`coords[d][i]`): the kernel column of centre `c` (in 3D by the
/// dispatched kernel of [`cleave_kernels::harmonic::kernel_column`]).
fn kernel_column<const D: usize>(coords: &[Vec<f64>; D], c: [f64; D], weights: &[f64], out: &mut [f64]) {
    if let (Some(coords), Some(c)) = (<&[Vec<f64>; 3]>::try_from(&coords[..]).ok(), <[f64; 3]>::try_from(&c[..]).ok()) {
        cleave_kernels::harmonic::kernel_column([&coords[0], &coords[1], &coords[2]], c, weights, out);
    } else {
        for (i, v) in out.iter_mut().enumerate() {
            *v = (0..D).map(|d| (coords[d][i] - c[d]) * (coords[d][i] - c[d])).sum::<f64>();
        }
        kernel_of_squared::<D>(out);
        out.iter_mut().zip(weights).for_each(|(v, w)| *v *= w);
    }
}

/// The fit's arrays, kept per thread and reused: a 24-node element's
/// system is about 1.5 MB, and allocated afresh for every element its
/// pages were returned and faulted in again each time. They keep the size
/// of the largest fit the thread has made (the 40-node bench element's:
/// about 7 MB).
#[derive(Default)]
struct Workspace {
    /// The kernel matrix, the right-hand sides, the normal equations'
    /// matrix and the fitted values, one after another (the QR
    /// factorisation, rarely needed, allocates its copy of the matrix).
    values: Vec<f64>,
    /// faer's scratch and its size (bytes).
    stack: Option<(usize, MemBuffer)>,
}

impl Workspace {
    /// Slices of the given lengths, from storage grown as needed (its old
    /// contents left: every caller overwrites what it reads).
    fn arrays<const N: usize>(values: &mut Vec<f64>, lengths: [usize; N]) -> [&mut [f64]; N] {
        let total = lengths.iter().sum();
        if values.len() < total {
            values.resize(total, 0.0);
        }
        let mut parts = crate::stretches(values, lengths).into_iter();
        std::array::from_fn(|_| parts.next().expect("one stretch per length"))
    }

    /// faer's scratch of at least `req`.
    fn stack(stack: &mut Option<(usize, MemBuffer)>, req: StackReq) -> &mut MemStack {
        let bytes = req.size_bytes();
        if stack.as_ref().is_none_or(|(have, _)| *have < bytes) {
            *stack = Some((bytes, MemBuffer::new(req)));
        }
        MemStack::new(&mut stack.as_mut().expect("set above").1)
    }
}

thread_local! {
    static WORKSPACE: RefCell<Workspace> = RefCell::default();
}

/// The largest ratio of the Cholesky factor's diagonal entries (a lower
/// bound of the condition number of `A`) at which the normal equations are
/// solved: `10⁵` leaves the relative error of their solution, about
/// `ε cond(A)²`, far below the fit's own (the kernel matrices of the
/// harmonic tests stay under `6·10⁴`).
pub(super) const NORMAL_EQUATIONS_MAX_RATIO: f64 = 1e5;

/// How the least-squares problem was solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Method {
    /// Cholesky factorisation of the normal equations.
    NormalEquations,
    /// Householder QR factorisation of the kernel matrix.
    Qr,
}

/// Fits `k` functions to `targets` (row-major `m x k`) at the scaled
/// `collocation` points, with kernels at `centres`; `nodes` are the scaled
/// node positions whose linear functions the result reproduces exactly.
/// The first `k` collocation points must be the nodes: their equations
/// weigh [`NODE_WEIGHT`] times more, which keeps the Lagrange property
/// `N_a(x_b) ≈ δ_ab` where the hat functions' kinks make the fit hardest.
/// With `measure`, also returns the fit's error (one more product of the
/// kernel matrix with the coefficients, about a tenth of the fit: the
/// element store, which never reads it, skips it).
/// Returns `None` when the system is rank deficient or the result not finite.
pub(super) fn fit<const D: usize>(
    centres: Vec<[f64; D]>,
    collocation: &[[f64; D]],
    targets: &[f64],
    nodes: &[[f64; D]],
    measure: bool,
) -> Option<(Fit<D>, Option<FitError>)> {
    let methods = [Method::NormalEquations, Method::Qr];
    fit_by(centres, collocation, targets, nodes, &methods, measure).map(|(fit, _, error)| (fit, error))
}

/// [`fit`] by the first of `methods` that succeeds (a test compares them);
/// also returns the method used.
pub(super) fn fit_by<const D: usize>(
    centres: Vec<[f64; D]>,
    collocation: &[[f64; D]],
    targets: &[f64],
    nodes: &[[f64; D]],
    methods: &[Method],
    measure: bool,
) -> Option<(Fit<D>, Method, Option<FitError>)> {
    let (n, m, k) = (centres.len(), collocation.len(), nodes.len());
    let cols = n + D + 1;
    assert_eq!(targets.len(), m * k);
    if m < cols {
        return None;
    }
    let row_weight = |i: usize| if i < k { NODE_WEIGHT } else { 1.0 };
    let weights: Vec<f64> = (0..m).map(row_weight).collect();
    let coords: [Vec<f64>; D] = std::array::from_fn(|d| collocation.iter().map(|c| c[d]).collect());
    let block = factor::recommended_block_size::<f64>(m, cols);
    let scratch = StackReq::any_of(&[
        llt::factor::cholesky_in_place_scratch::<f64>(cols, Par::Seq, Default::default()),
        factor::qr_in_place_scratch::<f64>(m, cols, block, Par::Seq, Default::default()),
        solve::solve_lstsq_in_place_scratch::<f64>(m, cols, block, k, Par::Seq),
    ]);
    let mut coefficients = vec![0.0; cols * k];
    let (mut max_error, mut sum_sq) = (0.0f64, 0.0);
    let mut fit_in = |work: &mut Workspace| {
        let [a, rhs, gram, values] =
            Workspace::arrays(&mut work.values, [m * cols, m * k, cols * cols.max(block), m * k]);
        let stack = Workspace::stack(&mut work.stack, scratch);
        // filled column by column, as faer stores it, each kernel column by
        // one loop over the points' coordinates held as separate arrays (it
        // vectorises; the per-entry closure of `Mat::from_fn` took a fifth
        // of a 24-node element's build)
        for (j, column) in a.chunks_exact_mut(m).enumerate() {
            match j {
                j if j < n => kernel_column::<D>(&coords, centres[j], &weights, column),
                j if j < n + D => {
                    column.iter_mut().zip(&weights).zip(&coords[j - n]).for_each(|((v, w), x)| *v = w * x)
                }
                _ => column.copy_from_slice(&weights),
            }
        }
        for (col, rhs) in rhs.chunks_exact_mut(m).enumerate() {
            rhs.iter_mut().enumerate().for_each(|(i, r)| *r = weights[i] * targets[i * k + col]);
        }
        let a = MatRef::from_column_major_slice(a, m, cols);
        let rhs = MatMut::from_column_major_slice_mut(rhs, m, k);
        let method = methods.iter().copied().find(|method| match method {
            Method::NormalEquations => {
                solve_normal_equations(a, rhs.as_ref(), gram, &mut coefficients, stack).is_some()
            }
            Method::Qr => {
                let Some(x) = solve_qr(a, rhs.as_ref(), gram, values, stack) else { return false };
                MatMut::from_row_major_slice_mut(&mut coefficients, cols, k).copy_from(x);
                true
            }
        });
        cleave_kernels::lanes::clear_upper_registers();
        let method = method?;
        reproduce_linear::<D>(&mut coefficients, n, nodes)?;
        if !coefficients.iter().all(|c| c.is_finite()) {
            return None;
        }
        if !measure {
            return Some(method);
        }
        // the fit's deviations from the targets, by one matrix product
        let c = MatRef::from_row_major_slice(&coefficients, cols, k);
        let mut values = MatMut::from_column_major_slice_mut(values, m, k);
        matmul(values.as_mut(), Accum::Replace, a, c, 1.0, Par::Seq);
        cleave_kernels::lanes::clear_upper_registers();
        for i in 0..m {
            for a in 0..k {
                let d = values[(i, a)] / weights[i] - targets[i * k + a];
                max_error = max_error.max(d.abs());
                sum_sq += d * d;
            }
        }
        Some(method)
    };
    // (a fit on this thread may already hold the workspace: a faer or
    // rayon call that waits runs other jobs of the pool meanwhile, and one
    // may be another fit; that one takes a workspace of its own)
    let method = WORKSPACE.with(|cell| match cell.try_borrow_mut() {
        Ok(mut work) => fit_in(&mut work),
        Err(_) => fit_in(&mut Workspace::default()),
    })?;
    let error = measure.then(|| FitError { max: max_error, rms: (sum_sq / (m * k) as f64).sqrt() });
    Some((Fit { centres, coefficients, k }, method, error))
}

/// Rows of the normal equations' matrix `aᵀa` formed by one product each
/// ([`solve_normal_equations`]). On a 24-node element (628 x 252 kernel
/// matrix) panels of 16 to 24 rows took 0.54 ms where faer's triangular
/// product took 0.68 and the full square 1.07 (one core, Intel Xeon): the
/// panels do the lower triangle's work plus the small blocks on its
/// diagonal, with the wide products the matrix-product kernels run best.
/// On AMD EPYC Zen 4 (one core): 0.80 ms by panels of 24 (8 to 32 within
/// 0.76-0.82), 0.87 triangular, 1.43 the full square, which runs at
/// 56 GFLOPS: the panels' useful work runs at about 50, near the core's
/// peak. With the Cholesky factor (0.17 ms), the right-hand side (0.14)
/// and the triangular solves (0.07), the normal equations are 1.2 of a
/// 24-node element's 2.2 ms.
const GRAM_PANEL: usize = 24;

/// The least-squares solution of `a x = rhs` by the normal equations
/// `aᵀa x = aᵀ rhs`, written into `out` (row-major `cols x k`, the fit's
/// coefficients). `aᵀa`'s lower triangle is formed into `gram` by panels of
/// [`GRAM_PANEL`] rows (the blocks on the diagonal whole; their upper
/// halves are never read), the right-hand side as `(rhsᵀ a)ᵀ` straight
/// into `out` (0.09 ms on a 24-node element against 0.16 for `aᵀ rhs` into
/// a column-major matrix, and the triangular solves run faster on it).
/// `None` when the Cholesky factor fails or its diagonal spans more than
/// [`NORMAL_EQUATIONS_MAX_RATIO`].
fn solve_normal_equations(
    a: MatRef<f64>,
    rhs: MatRef<f64>,
    gram: &mut [f64],
    out: &mut [f64],
    stack: &mut MemStack,
) -> Option<()> {
    let cols = a.ncols();
    let mut g = MatMut::from_column_major_slice_mut(&mut gram[..cols * cols], cols, cols);
    for first in (0..cols).step_by(GRAM_PANEL) {
        let rows = GRAM_PANEL.min(cols - first);
        let end = first + rows;
        let panel = g.as_mut().submatrix_mut(first, 0, rows, end);
        matmul(panel, Accum::Replace, a.subcols(first, rows).transpose(), a.subcols(0, end), 1.0, Par::Seq);
    }
    llt::factor::cholesky_in_place(g.as_mut(), Default::default(), Par::Seq, stack, Default::default()).ok()?;
    let diagonal = (0..cols).map(|i| g[(i, i)]);
    let (lo, hi) = diagonal.fold((f64::INFINITY, 0.0f64), |(lo, hi), d| (lo.min(d), hi.max(d)));
    if !(lo > 0.0 && hi <= NORMAL_EQUATIONS_MAX_RATIO * lo) {
        return None;
    }
    let mut x = MatMut::from_row_major_slice_mut(&mut out[..cols * rhs.ncols()], cols, rhs.ncols());
    matmul(x.as_mut().transpose_mut(), Accum::Replace, rhs.transpose(), a, 1.0, Par::Seq);
    llt::solve::solve_in_place_with_conj(g.as_ref(), Conj::No, x, Par::Seq, stack);
    Some(())
}

/// The least-squares solution of `a x = rhs` by a Householder QR
/// factorisation of a copy of `a` (its block reflectors in `h`);
/// `x` is written into `out`. `None` when `R` is rank deficient (coincident
/// kernels make the solve meaningless).
fn solve_qr<'o>(
    a: MatRef<f64>,
    rhs: MatRef<f64>,
    h: &mut [f64],
    out: &'o mut [f64],
    stack: &mut MemStack,
) -> Option<MatRef<'o, f64>> {
    let (m, cols) = a.shape();
    let block = factor::recommended_block_size::<f64>(m, cols);
    let mut qr = a.to_owned();
    let mut h = MatMut::from_column_major_slice_mut(&mut h[..block * cols], block, cols);
    factor::qr_in_place(qr.as_mut(), h.as_mut(), Par::Seq, stack, Default::default());
    let rmax = (0..cols).map(|i| qr[(i, i)].abs()).fold(0.0, f64::max);
    if !(rmax > 0.0) || (0..cols).any(|i| !(qr[(i, i)].abs() > 1e-13 * rmax)) {
        return None;
    }
    let mut x = MatMut::from_column_major_slice_mut(&mut out[..m * rhs.ncols()], m, rhs.ncols());
    x.copy_from(rhs);
    solve::solve_lstsq_in_place_with_conj(qr.as_ref(), h.as_ref(), qr.as_ref(), Conj::No, x.as_mut(), Par::Seq, stack);
    Some(x.into_const().subrows(0, cols))
}

/// Projects the coefficients (row-major `(n + D + 1) x k`) onto the affine
/// set where `Σ_a C[:, a] = e_const` and `Σ_a x̂_a,i C[:, a] = e_lin_i`
/// with the least change: `C -= (C P - T) (PᵀP)⁻¹ Pᵀ`, `P = [1, x̂_a]`
/// (`PᵀP` padded to 4 x 4 with the identity in 2D). `None` when the nodes
/// do not span the space (`PᵀP` singular).
fn reproduce_linear<const D: usize>(c: &mut [f64], n: usize, nodes: &[[f64; D]]) -> Option<()> {
    let k = nodes.len();
    let dim = D + 1;
    // the rows of P, zero beyond `dim`
    let p: Vec<[f64; 4]> = nodes
        .iter()
        .map(|x| {
            let mut row = [0.0; 4];
            row[0] = 1.0;
            row[1..dim].copy_from_slice(x);
            row
        })
        .collect();
    let gram: [[f64; 4]; 4] = std::array::from_fn(|r| {
        std::array::from_fn(|s| match (r < dim && s < dim, r == s) {
            (true, _) => p.iter().map(|pa| pa[r] * pa[s]).sum(),
            (false, diagonal) => f64::from(u8::from(diagonal)),
        })
    });
    let identity: [[f64; 4]; 4] = std::array::from_fn(|r| std::array::from_fn(|s| f64::from(u8::from(r == s))));
    let largest = (0..4).map(|i| gram[i][i]).fold(0.0, f64::max);
    let inverse = cleave_kernels::solve4::solve4(gram, identity, 1e-12 * largest)?;
    // Q = (PᵀP)⁻¹ Pᵀ, one row of 4 per node
    let q: Vec<[f64; 4]> =
        p.iter().map(|pa| std::array::from_fn(|l| (0..4).map(|s| inverse[l][s] * pa[s]).sum())).collect();
    let target = |row: usize, l: usize| if (l == 0 && row == n + D) || (l > 0 && row == n + l - 1) { 1.0 } else { 0.0 };
    for (row, ci) in c.chunks_exact_mut(k).enumerate().take(n + D + 1) {
        // the residual E = C P - T of this row
        let mut e = [0.0; 4];
        for (c, pa) in ci.iter().zip(&p) {
            (0..4).for_each(|l| e[l] += c * pa[l]);
        }
        (0..dim).for_each(|l| e[l] -= target(row, l));
        for (v, qa) in ci.iter_mut().zip(&q) {
            *v -= (0..4).map(|l| e[l] * qa[l]).sum::<f64>();
        }
    }
    Some(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The inputs of a fit.
    struct Problem {
        centres: Vec<[f64; 3]>,
        collocation: Vec<[f64; 3]>,
        targets: Vec<f64>,
        nodes: Vec<[f64; 3]>,
    }

    /// The fit of the trilinear functions of the cube `[-1/2, 1/2]³` on its
    /// surface, with kernels `0.1` outside it: nodes, then a grid of each
    /// face at spacing `1/8` (collocation) or `1/4` (kernels).
    fn cube_problem() -> Problem {
        let nodes: Vec<[f64; 3]> =
            (0..8).map(|i| [i & 1, (i >> 1) & 1, (i >> 2) & 1].map(|b| b as f64 - 0.5)).collect();
        let trilinear = |p: [f64; 3]| -> Vec<f64> {
            nodes.iter().map(|x| (0..3).map(|d| 0.5 + 2.0 * x[d] * p[d]).product()).collect()
        };
        let face_grid = |steps: usize, offset: f64| {
            let mut points = Vec::new();
            for axis in 0..3 {
                for side in [-0.5f64, 0.5] {
                    for i in 0..=steps {
                        for j in 0..=steps {
                            let (u, v) = (i as f64 / steps as f64 - 0.5, j as f64 / steps as f64 - 0.5);
                            let mut p = [0.0; 3];
                            p[axis] = side + offset * side.signum();
                            p[(axis + 1) % 3] = u;
                            p[(axis + 2) % 3] = v;
                            points.push(p);
                        }
                    }
                }
            }
            points
        };
        let mut collocation = nodes.clone();
        collocation.extend(face_grid(8, 0.0));
        let targets = collocation.iter().flat_map(|&p| trilinear(p)).collect();
        Problem { centres: face_grid(4, 0.1), collocation, targets, nodes }
    }

    #[test]
    fn normal_equations_agree_with_qr() {
        let Problem { centres, collocation, targets, nodes } = cube_problem();
        let by = |method| fit_by(centres.clone(), &collocation, &targets, &nodes, &[method], true).expect("a fit");
        let ((normal, used, normal_error), (qr, _, qr_error)) = (by(Method::NormalEquations), by(Method::Qr));
        assert_eq!(used, Method::NormalEquations);
        let (normal_error, qr_error) = (normal_error.expect("measured"), qr_error.expect("measured"));
        let (default, unmeasured) = fit(centres.clone(), &collocation, &targets, &nodes, false).expect("a fit");
        assert_eq!(default.coefficients, normal.coefficients, "the default takes the normal equations here");
        assert_eq!(unmeasured, None);
        assert!(normal_error.max < 0.05, "the fit itself: {normal_error:?}");
        assert!((normal_error.max - qr_error.max).abs() < 1e-9, "{normal_error:?} {qr_error:?}");
        assert!((normal_error.rms - qr_error.rms).abs() < 1e-10, "{normal_error:?} {qr_error:?}");
        let (mut a, mut b) = (vec![0.0; 8], vec![0.0; 8]);
        for i in 0..50 {
            let t = i as f64 / 49.0;
            let p = [0.45 * (7.0 * t).sin(), 0.45 * (5.0 * t).cos(), t - 0.5];
            normal.values(p, &mut a);
            qr.values(p, &mut b);
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() < 1e-9, "at {p:?}: {x} against {y}");
            }
        }
    }

    /// A fit that starts while another on the same thread holds the
    /// workspace (a job the pool runs while that fit waits) takes a
    /// workspace of its own, and gives the same coefficients: the CI once
    /// panicked with "RefCell already borrowed" there.
    #[test]
    fn a_fit_inside_a_fit_on_the_same_thread_has_its_own_workspace() {
        let Problem { centres, collocation, targets, nodes } = cube_problem();
        let alone = fit(centres.clone(), &collocation, &targets, &nodes, false).expect("a fit").0;
        let nested = WORKSPACE.with_borrow_mut(|_held| fit(centres, &collocation, &targets, &nodes, false));
        assert_eq!(nested.expect("a fit").0.coefficients, alone.coefficients);
    }

    /// Two kernels `10⁻⁷` apart make the normal equations untrustworthy;
    /// the fit then takes the QR factorisation, which still fits.
    #[test]
    fn clustered_kernels_fall_back_to_qr() {
        let Problem { mut centres, collocation, targets, nodes } = cube_problem();
        centres.push([centres[3][0] + 1e-7, centres[3][1], centres[3][2]]);
        let normal = fit_by(centres.clone(), &collocation, &targets, &nodes, &[Method::NormalEquations], false);
        assert!(normal.is_none(), "the normal equations must refuse");
        let methods = [Method::NormalEquations, Method::Qr];
        let (_, used, error) = fit_by(centres, &collocation, &targets, &nodes, &methods, true).expect("a QR fit");
        assert_eq!(used, Method::Qr);
        let error = error.expect("measured");
        assert!(error.max < 0.05, "{error:?}");
    }

    #[test]
    fn coincident_kernels_are_refused_by_both_methods() {
        let Problem { mut centres, collocation, targets, nodes } = cube_problem();
        centres.push(centres[3]);
        for method in [Method::NormalEquations, Method::Qr] {
            assert!(fit_by(centres.clone(), &collocation, &targets, &nodes, &[method], true).is_none(), "{method:?}");
        }
        assert!(fit(centres, &collocation, &targets, &nodes, false).is_none());
    }
}
