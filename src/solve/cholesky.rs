//! Sparse Cholesky `A = L L^T` through faer's low-level API: the symbolic
//! factorisation (ordering, elimination tree, supernodes) once per pattern,
//! the numeric one into kept buffers whenever values change.
//!
//! The fill-reducing ordering is METIS nested dissection on the graph of
//! 3x3 blocks (nodes), expanded to the scalar unknowns; on 3-D meshes it
//! gives markedly less fill than faer's built-in AMD (measured by
//! `cleave bench`), and as little as CHOLMOD's METIS ordering (measured by
//! `benches/peers/run.sh`). AMD remains the fallback if METIS fails.
//!
//! The triangular solves of a factor of at least 2M values run in parallel
//! over its elimination tree (`tree_solve.rs`), with the same bits on any
//! number of threads: on bunny_100k (33M values) 16.5 ms against faer's
//! sequential 28 ms, 2 cores.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky, SymbolicCholeskyRaw,
    SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

use super::tree_solve::TreeSolve;
use super::{LinearSolver, SolveError, SolveStats};

/// Unknowns from which the default numeric factorisation runs in parallel
/// (see [`Cholesky::new`]; measured at 6.6k unknowns, no gain, and 53k,
/// 1.5x on 2 cores).
pub const PARALLEL_CHOLESKY_MIN_UNKNOWNS: usize = 30_000;

/// Direct sparse Cholesky solver.
#[derive(Default)]
pub struct Cholesky {
    symbolic: Option<SymbolicCholesky<usize>>,
    l_values: Vec<f64>,
    scratch: Option<MemBuffer>,
    /// `b - A x`, for the residual a solve reports.
    residual: Vec<f64>,
    factored: bool,
    par: Option<Par>,
    /// The parallel triangular solves of a supernodal factor.
    tree: Option<TreeSolve>,
    /// The right-hand side in the factor's order.
    permuted: Vec<f64>,
}

impl Cholesky {
    /// A solver whose numeric factorisation runs with `par`. By default it
    /// runs sequentially below [`PARALLEL_CHOLESKY_MIN_UNKNOWNS`] unknowns,
    /// and from there on with faer's parallel supernodal factorisation over
    /// the current rayon pool, inside the pool (no hand-over between
    /// threads per parallel call). On bunny_100k (53k unknowns, 2 cores)
    /// the parallel one factored `K + 10³ I` in 360 ms against 550 ms, and
    /// `scenes/bunny_slices.toml` spent 34.5 s solving against 36.6 s; on
    /// bunny_5k (6.6k unknowns) it was no faster, and steps with it were
    /// slower. The parallel factor has the same bits as the sequential one
    /// whatever the pool's size (checked on both bunnies with pools of 1 to
    /// 4 threads, and by `parallel_factor_has_the_same_bits_on_any_pool`).
    pub fn new(par: Par) -> Self {
        Cholesky { par: Some(par), ..Default::default() }
    }

    /// The parallelism of the numeric factorisation of `unknowns` unknowns.
    fn par(&self, unknowns: usize) -> Par {
        self.par.unwrap_or(if unknowns >= PARALLEL_CHOLESKY_MIN_UNKNOWNS { Par::rayon(0) } else { Par::Seq })
    }

    /// Whether a factor is ready (a pattern analysed, values factored).
    pub fn is_factored(&self) -> bool {
        self.factored
    }

    /// Overwrites `x` with `A⁻¹ x` for the last factored `A` (in parallel
    /// over the current rayon pool for a large factor, see module docs).
    pub fn solve_in_place(&mut self, x: &mut [f64]) -> Result<(), SolveError> {
        let (Some(sym), Some(buf), true) = (self.symbolic.as_ref(), self.scratch.as_mut(), self.factored) else {
            return Err(SolveError::NotReady);
        };
        if let (Some(tree), SymbolicCholeskyRaw::Supernodal(supernodal), Some(perm)) =
            (self.tree.as_mut(), sym.raw(), sym.perm())
        {
            let (fwd, inv) = perm.arrays();
            self.permuted.clear();
            self.permuted.extend(fwd.iter().map(|&f| x[f]));
            crate::in_pool(|| tree.solve_in_place(supernodal, &self.l_values, &mut self.permuted));
            x.iter_mut().zip(inv).for_each(|(x, &i)| *x = self.permuted[i]);
            return Ok(());
        }
        let llt = LltRef::<'_, usize, f64>::new(sym, &self.l_values);
        let n = x.len();
        // (a small or simplicial factor: faer's parallel solves sum in an
        // order that depends on the thread count, so they run sequentially)
        llt.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(x, n, 1),
            Par::Seq,
            MemStack::new(buf),
        );
        cleave_kernels::lanes::clear_upper_registers();
        Ok(())
    }

    /// Number of entries of `L` on and below its diagonal, once analysed,
    /// as sparse direct solvers count their fill (CHOLMOD's `nnz(L)`): the
    /// stored entries less the upper triangles of the supernodes' diagonal
    /// blocks (stored, never used), `w (w - 1) / 2` for a supernode of `w`
    /// columns; explicit zeros the relaxed supernodes carry still count, as
    /// in CHOLMOD.
    pub fn factor_nnz(&self) -> usize {
        let Some(sym) = self.symbolic.as_ref() else { return 0 };
        match sym.raw() {
            SymbolicCholeskyRaw::Simplicial(s) => s.len_val(),
            SymbolicCholeskyRaw::Supernodal(s) => {
                let (begin, end) = (s.supernode_begin(), s.supernode_end());
                let upper: usize = begin.iter().zip(end).map(|(&b, &e)| (e - b) * (e - b).saturating_sub(1) / 2).sum();
                sym.len_val() - upper
            }
        }
    }

    /// Floating-point operations of one numeric factorisation, once
    /// analysed, as CHOLMOD counts them: `Σ_j c_j²` over the columns of `L`,
    /// `c_j` the column's entries on and below the diagonal (a multiply and
    /// an add each), so that a time gives the factorisation's flop rate.
    pub fn factor_flops(&self) -> f64 {
        let Some(sym) = self.symbolic.as_ref() else { return 0.0 };
        match sym.raw() {
            SymbolicCholeskyRaw::Simplicial(s) => s.col_ptr().windows(2).map(|w| ((w[1] - w[0]) as f64).powi(2)).sum(),
            SymbolicCholeskyRaw::Supernodal(s) => {
                let rows = s.col_ptr_for_row_idx();
                (0..s.n_supernodes())
                    .map(|k| {
                        let width = s.supernode_end()[k] - s.supernode_begin()[k];
                        let below = rows[k + 1] - rows[k];
                        (0..width).map(|c| ((width - c + below) as f64).powi(2)).sum::<f64>()
                    })
                    .sum()
            }
        }
    }
}

impl LinearSolver for Cholesky {
    fn analyze(&mut self, pattern: SymbolicSparseColMatRef<'_, usize>) -> Result<(), SolveError> {
        let nd = nested_dissection(pattern);
        let ordering = match &nd {
            Some((fwd, inv)) => SymmetricOrdering::Custom(PermRef::new_checked(fwd, inv, pattern.nrows())),
            None => SymmetricOrdering::Amd,
        };
        let sym = factorize_symbolic_cholesky(pattern, Side::Lower, ordering, CholeskySymbolicParams::default())
            .map_err(|e| SolveError::Analysis(format!("{e:?}")))?;
        let par = self.par(pattern.nrows());
        let req = sym
            .factorize_numeric_llt_scratch::<f64>(par, Default::default())
            .or(sym.solve_in_place_scratch::<f64>(1, par));
        self.scratch = Some(MemBuffer::new(req));
        self.l_values = vec![0.0; sym.len_val()];
        self.tree = match (sym.raw(), sym.perm()) {
            (SymbolicCholeskyRaw::Supernodal(s), Some(_)) => TreeSolve::new(s),
            _ => None,
        };
        self.symbolic = Some(sym);
        self.factored = false;
        Ok(())
    }

    fn factor(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError> {
        let par = self.par(matrix.nrows());
        let (Some(sym), Some(buf)) = (self.symbolic.as_ref(), self.scratch.as_mut()) else {
            return Err(SolveError::NotReady);
        };
        if matrix.parts().1.iter().any(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite);
        }
        self.factored = false;
        let l_values = &mut self.l_values;
        let factored = crate::in_pool(|| {
            let factored = sym.factorize_numeric_llt(
                l_values,
                matrix,
                Side::Lower,
                LltRegularization::default(),
                par,
                MemStack::new(buf),
                Default::default(),
            );
            // (this thread's; the other threads' are cleared by the next
            // dispatched kernel they run: clearing them all here would
            // take a broadcast, which allocates)
            cleave_kernels::lanes::clear_upper_registers();
            factored
        });
        factored.map_err(|e| match e {
            faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index } => {
                SolveError::NotPositiveDefinite { pivot: index, n: matrix.nrows() }
            }
        })?;
        self.factored = true;
        Ok(())
    }

    fn solve(
        &mut self,
        matrix: SparseColMatRef<'_, usize, f64>,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, SolveError> {
        let mut residual = std::mem::take(&mut self.residual);
        let stats = super::direct_solve(matrix, b, x, &mut residual, |x| self.solve_in_place(x));
        self.residual = residual;
        stats
    }
}

/// METIS nested dissection of the block graph of `pattern` (a repeated
/// 3x3 block structure), as scalar `(forward, inverse)` permutations, or
/// `None` when the pattern is not blocked or METIS fails.
fn nested_dissection(pattern: SymbolicSparseColMatRef<'_, usize>) -> Option<(Vec<usize>, Vec<usize>)> {
    let n = pattern.nrows();
    if n % 3 != 0 || n == 0 {
        return None;
    }
    let nb = n / 3;
    let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
    let mut xadj: Vec<metis_sys::idx_t> = Vec::with_capacity(nb + 1);
    let mut adjncy: Vec<metis_sys::idx_t> = Vec::new();
    xadj.push(0);
    for j in 0..nb {
        for &r in ri[cp[3 * j]..cp[3 * j + 1]].iter().step_by(3) {
            if r / 3 != j {
                adjncy.push(metis_sys::idx_t::try_from(r / 3).ok()?);
            }
        }
        xadj.push(metis_sys::idx_t::try_from(adjncy.len()).ok()?);
    }
    let mut nvtxs = metis_sys::idx_t::try_from(nb).ok()?;
    let mut perm = vec![0 as metis_sys::idx_t; nb];
    let mut iperm = vec![0 as metis_sys::idx_t; nb];
    let mut options = [0 as metis_sys::idx_t; metis_sys::METIS_NOPTIONS as usize];
    // METIS draws from one random number generator for the whole process
    // (GKlib's), seeded at each call: two calls at once (two simulations on
    // two threads) would interleave its draws and order differently, so one
    // call runs at a time and every ordering is reproducible
    static METIS: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one_at_a_time = METIS.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    // SAFETY: the arrays have the lengths METIS_NodeND documents (nvtxs + 1,
    // xadj[nvtxs], nvtxs, nvtxs, METIS_NOPTIONS) and live across the calls;
    // a null vwgt means unit weights.
    let status = unsafe {
        metis_sys::METIS_SetDefaultOptions(options.as_mut_ptr());
        // two separators tried per bisection, the better kept: on
        // bunny_100k nnz(L) 29.2M -> 28.6M (CHOLMOD with METIS: 28.5M), for
        // 60 ms more of analysis (200 -> 260 ms), once per topology
        options[metis_sys::moptions_et_METIS_OPTION_NSEPS as usize] = 2;
        metis_sys::METIS_NodeND(
            &mut nvtxs,
            xadj.as_mut_ptr(),
            adjncy.as_mut_ptr(),
            std::ptr::null_mut(),
            options.as_mut_ptr(),
            perm.as_mut_ptr(),
            iperm.as_mut_ptr(),
        )
    };
    if status != metis_sys::rstatus_et_METIS_OK {
        return None;
    }
    // METIS: row i of the reordered matrix is row perm[i] of the original
    let fwd: Vec<usize> = perm.iter().flat_map(|&p| (0..3).map(move |c| 3 * p as usize + c)).collect();
    let mut inv = vec![0usize; n];
    for (i, &f) in fwd.iter().enumerate() {
        inv[f] = i;
    }
    Some((fwd, inv))
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use faer::sparse::SymbolicSparseColMat;

    /// The stiffness of a box of `cells` tetrahedral cells plus `10³ I`
    /// (a regular matrix with large supernodes), and a right-hand side.
    pub(crate) fn box_system(cells: usize) -> (crate::assembly::SparsePattern, Vec<f64>, Vec<f64>) {
        use crate::assembly::SparsePattern;
        use crate::store::{BasisOptions, ElementStore};
        let mesh = crate::meshing::box_tet([0.0; 3], [1.0; 3], [cells; 3]).unwrap();
        let material = crate::material::Material::new(1e5, 0.3, 1000.0).unwrap();
        let store = ElementStore::build(&mesh, &material, &BasisOptions::default()).unwrap();
        let pattern = SparsePattern::build(mesh.nodes.len(), &store);
        let mut values = vec![0.0; pattern.nnz()];
        pattern.assemble(&mut values, |b, i, c, out| store.batches[b].block_column(i, c, out));
        (0..3 * mesh.nodes.len()).for_each(|d| values[pattern.diagonal_slot(d)] += 1e3);
        let b = (0..3 * mesh.nodes.len()).map(|i| (i as f64 * 0.37).sin()).collect();
        (pattern, values, b)
    }

    /// The tree solve's tasks for `chol`'s factor (analysed), whatever its
    /// size.
    fn partition(chol: &Cholesky) -> Option<TreeSolve> {
        match chol.symbolic.as_ref().map(|s| s.raw()) {
            Some(SymbolicCholeskyRaw::Supernodal(s)) => TreeSolve::partition(s),
            _ => None,
        }
    }

    /// The parallel numeric factorisation of a stiffness with large
    /// supernodes (a 12 x 12 x 12 cell box, 6.6k unknowns) gives the
    /// sequential factor's solution bit for bit on pools of 1, 2 and 4
    /// threads.
    #[test]
    fn parallel_factor_has_the_same_bits_on_any_pool() {
        let (pattern, values, b) = box_system(12);
        let solve = |par: Par| {
            let mut chol = Cholesky::new(par);
            chol.analyze(pattern.symbolic()).unwrap();
            let mut x = vec![0.0; b.len()];
            chol.factor(pattern.matrix(&values)).unwrap();
            chol.solve(pattern.matrix(&values), &b, &mut x).unwrap();
            x.iter().map(|v| v.to_bits()).collect::<Vec<u64>>()
        };
        let sequential = solve(Par::Seq);
        for threads in [1, 2, 4] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            assert!(pool.install(|| solve(Par::rayon(0))) == sequential, "{threads} threads");
        }
    }

    /// The tree-parallel triangular solves (both their parts: subtrees and
    /// top supernodes by panels) agree with faer's sequential supernodal
    /// solve to rounding, and give the same bits on pools of 1, 2 and 4
    /// threads.
    #[test]
    fn tree_solve_agrees_with_the_sequential_solve_on_any_pool() {
        let (pattern, values, b) = box_system(12);
        let mut chol = Cholesky::new(Par::Seq);
        chol.analyze(pattern.symbolic()).unwrap();
        chol.factor(pattern.matrix(&values)).unwrap();
        chol.tree = partition(&chol);
        let (tasks, top) = chol.tree.as_ref().expect("a supernodal factor").shape();
        assert!(tasks > 2 && top > 0, "{tasks} tasks, {top} top supernodes");
        let sym = chol.symbolic.as_ref().unwrap();
        let mut reference = b.clone();
        let mut stack = MemBuffer::new(sym.solve_in_place_scratch::<f64>(1, Par::Seq));
        LltRef::<'_, usize, f64>::new(sym, &chol.l_values).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut reference, b.len(), 1),
            Par::Seq,
            MemStack::new(&mut stack),
        );
        let scale = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let mut bits = Vec::new();
        for threads in [1, 2, 4] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let mut x = b.clone();
            pool.install(|| chol.solve_in_place(&mut x)).unwrap();
            let worst = x.iter().zip(&reference).fold(0.0f64, |m, (x, r)| m.max((x - r).abs()));
            assert!(worst <= 1e-12 * scale, "{threads} threads: off by {worst:e} of {scale:e}");
            bits.push(x.iter().map(|v| v.to_bits()).collect::<Vec<u64>>());
        }
        assert!(bits.iter().all(|x| *x == bits[0]), "the bits depend on the threads");
    }

    /// A matrix of two uncoupled bodies (a forest of two elimination trees,
    /// one much smaller) is solved to rounding by the tree solve.
    #[test]
    fn tree_solve_handles_a_forest() {
        let (big, big_values, big_b) = box_system(6);
        let (small, small_values, small_b) = box_system(2);
        // the two matrices side by side, the small one's unknowns after
        let (nb, ns) = (big_b.len(), small_b.len());
        let (bs, ss) = (big.symbolic(), small.symbolic());
        let mut col_ptr = bs.col_ptr().to_vec();
        let mut row_idx = bs.row_idx().to_vec();
        col_ptr.extend(ss.col_ptr()[1..].iter().map(|p| p + row_idx.len()));
        row_idx.extend(ss.row_idx().iter().map(|r| r + nb));
        let pattern = SymbolicSparseColMat::new_checked(nb + ns, nb + ns, col_ptr, None, row_idx);
        let values = [big_values, small_values].concat();
        let b = [big_b, small_b].concat();
        let matrix = faer::sparse::SparseColMatRef::new(pattern.as_ref(), &values);
        let mut chol = Cholesky::default();
        chol.analyze(pattern.as_ref()).unwrap();
        chol.factor(matrix).unwrap();
        chol.tree = partition(&chol);
        let (tasks, top) = chol.tree.as_ref().expect("a supernodal factor").shape();
        assert!(tasks >= 2 && top > 0, "{tasks} tasks, {top} top supernodes");
        let mut x = vec![0.0; b.len()];
        let stats = chol.solve(matrix, &b, &mut x).unwrap();
        assert!(stats.residual < 1e-13, "residual {:e}", stats.residual);
    }

    /// `L`'s entries on and below the diagonal: `n (n + 1) / 2` for a dense
    /// pattern of `n` unknowns (one supernode, whose stored upper triangle
    /// does not count), 6 per node for nodes coupled to no other.
    #[test]
    fn fill_counts_the_lower_triangle() {
        for nodes in [1, 2, 5, 40] {
            let n = 3 * nodes;
            let col_ptr: Vec<usize> = (0..=n).map(|j| j * n).collect();
            let row_idx: Vec<usize> = (0..n).flat_map(|_| 0..n).collect();
            let mut chol = Cholesky::default();
            chol.analyze(SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx).as_ref()).unwrap();
            assert_eq!(chol.factor_nnz(), n * (n + 1) / 2, "{nodes} nodes coupled");
            let col_ptr: Vec<usize> = (0..=n).map(|j| 3 * j).collect();
            let row_idx: Vec<usize> = (0..n).flat_map(|j| 3 * (j / 3)..3 * (j / 3) + 3).collect();
            let mut chol = Cholesky::default();
            chol.analyze(SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx).as_ref()).unwrap();
            assert_eq!(chol.factor_nnz(), 6 * nodes, "{nodes} nodes apart");
        }
    }
}
