//! Preconditioned conjugate gradients, warm-started from the caller's
//! guess moved to the best start in the span of the last solves'
//! corrections (`history.rs`) and corrected by the coarse solution of its
//! residual, with an additive multilevel preconditioner: 3x3 block Jacobi
//! plus the coarse correction of the rigid motions of node aggregates
//! (`coarse.rs`), `z = D⁻¹ r + P B Pᵀ r`, `B ≈ (Pᵀ A P)⁻¹` the exact solve
//! on the rigid motions of aggregates of aggregates plus the exact solves
//! on the blocks of the aggregates' motions within each of them
//! (`aggregate_cycle.rs`).
//!
//! The matrix stores both triangles and is symmetric, so `y = A x` is
//! computed row by row as `y_i = (column i) · x`, in parallel without
//! write conflicts, reading the pattern's 3x3 block structure (one 32-bit
//! block row index per 9 values instead of a 64-bit index per value) and
//! the values rounded to `f32`: a quarter of the bytes of a scalar `f64`
//! product. The iteration takes its products in the sliced layout of
//! `kernels/src/sliced.rs` (eight block columns side by side, one per
//! SIMD lane), into which the values are written as they are rounded
//! when the solve before iterated ([`SLICED_FROM`]; else the products
//! read the column layout): on bunny_100k with its base clamped, CG to
//! 1e-8 (2 cores, Intel Xeon, AVX-512, five runs of 20 steps of each
//! alternated), the solve took 56 ms per step (median) against 65 ms with
//! the products on the column layout, for the same 55.7 iterations (and
//! filling the sliced values in a pass of their own after a solve's
//! fourth product, 3 ms more per step on one thread than writing them as
//! they are rounded). The iteration's vectors stay `f64`, and the
//! residual it must meet is taken with the `f64` values (see
//! [`ConjugateGradient::solve`]). One pass per iteration updates `x` and
//! `r`, applies the preconditioner and forms both dot products; the product
//! forms `p · A p`. Sums run over fixed chunks in parallel and the chunk
//! sums in order, so the iterates are bitwise independent of the thread
//! count.
//!
//! Storing only the upper triangle (each block then serves `y_j` and, by
//! a scatter, `y_i`; a chunk's sums into earlier rows kept in a halo of
//! its own and added in chunk order) reads a little over half the bytes,
//! but was measured slower: on bunny_100k with its base clamped (2 cores,
//! AMD EPYC Zen 3, AVX2) 1.14 to 1.36 ms per product against 0.79 to 0.90
//! ms for both triangles, timed side by side in the same steps (136k of
//! 255k block rows, halos of 11k rows). The product is not bound by
//! bandwidth alone there; the scatter's read-modify-writes of rows the
//! next column reads again cost more than the bytes saved.
//!
//! The iteration runs in the solver's own numbering of the blocks, a
//! reverse Cuthill–McKee order of the block graph (or the mesh's own, as
//! local), the blocks a cut appends numbered after it (`ordering.rs`):
//! the values are carried into it as they are rounded, the
//! right-hand side and the guess on entry, the solution back on exit. A
//! mesh numbered as its file numbers it makes the product gather from all
//! over the vector; on bunny_100k (2 cores, AMD EPYC) the renumbering took
//! the CG step with its base clamped from 102 to 87 iterations (the
//! aggregates follow the order too) and its solve from about 140 to 63 ms.

use std::ops::Range;

use cleave_kernels::sliced::{SlicedLayout, WINDOW};
use cleave_kernels::spmv::{block_products, block_products_of_vectors, BlockColumns, Value, VECTORS};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat, SymbolicSparseColMatRef};
use rayon::prelude::*;

use super::coarse::{aggregate_limit, CoarseSpace, Correction};
use super::history::{ProjectionSums, SolutionHistory};
use super::ordering::{anchored_order, Along, AlongGroups, Renumbering};
use super::{Cholesky, LinearSolver, SolveError, SolveStats, SystemPattern};

/// Chunk length of the deterministic reductions.
const CHUNK: usize = 4096;

/// Blocks per chunk of the iteration's fused passes (their sums are taken
/// per chunk, then in order).
pub(super) const CHUNK_BLOCKS: usize = 1024;

// (a chunk's product takes whole windows of the sliced layout)
const _: () = assert!(CHUNK_BLOCKS % WINDOW == 0);

/// Iterations of a solve from which the next solve's rounding pass writes
/// the values sliced as well: the writes cost about what four sliced
/// products save, which a body in free fall, no iteration or one per step,
/// would pay for nothing (bunny_100k falling at 1e-6, 2 cores, Intel Xeon:
/// the solve 11.7-15.2 ms per step without, 14.3-16.1 ms slicing at every
/// solve, four alternated runs of 20 steps).
const SLICED_FROM: usize = 4;

/// PCG solver (see module docs).
///
/// On the steps of `cleave bench` (bunny_100k, 53k unknowns), the coarse
/// level and its deflated start take the body falling onto a plane from
/// 86 iterations per step with block Jacobi alone to 1.6 at a relative
/// residual of 1e-6 (5.5 at 1e-8): its motion is nearly rigid. With its
/// base clamped, sagging and swaying, the body deforms: with the 32
/// aggregates of aggregates alone (one dense level) the step took 86
/// iterations at 1e-6 and 140 at 1e-8 from that start, 58 and 107 from
/// the span of the last 8 corrections (`history.rs`); with the 687
/// aggregates' block Jacobi added, 43 and 80 (2 cores, AMD EPYC: solve 53
/// against 62 ms at 1e-6, 84 against 100 ms at 1e-8). The coarse level is
/// assembled and factored again every 4 solves, or within a solve that
/// outgrows it (`COARSE_REFRESH`, `CoarseAge`).
///
/// What limits the iterations is the fine level and the unsmoothed
/// aggregates, not the balance or exactness of the coarse one: on the
/// clamped steps, solving the aggregates' system exactly (a limit of 800,
/// above its 687 aggregates) took as many iterations as the limit of 66,
/// and weighing block Jacobi's share by 0.6 to 1.7 gave 51.6 to 54.5
/// iterations per step against 52.0 (12 steps at 1e-6, 2 cores, AMD EPYC
/// Zen 3).
pub struct ConjugateGradient {
    /// Relative residual `|b - A x| / |b|` to reach.
    pub tolerance: f64,
    /// Iteration cap; reaching it is an error.
    pub max_iterations: usize,
    /// The matrix's 3x3 block structure in the solver's own numbering of
    /// the blocks (see [`ConjugateGradient::analyze_blocks`]), in which
    /// every vector and value of the iteration lives.
    numbering: Renumbering,
    /// Inverted diagonal blocks of the current matrix, each symmetric and
    /// stored as its upper triangle `[m00, m01, m02, m11, m12, m22]`.
    inverse_blocks: Vec<[f64; 6]>,
    /// The caller's block structure, on which the `f64` residual is taken
    /// from the caller's values (see [`ConjugateGradient::solve`]): a copy
    /// kept by [`LinearSolver::analyze`] and
    /// [`LinearSolver::analyze_blocks`] for `solve`, which is not given it
    /// again; empty after [`LinearSolver::analyze_pattern`], whose
    /// [`LinearSolver::solve_values`] is (a copy of 1 ms per cut on
    /// bunny_100k saved).
    given: BlockStructure,
    /// The matrix values in the solver's layout rounded to `f32` (the
    /// coarse level's products are summed from them; the iteration's
    /// products read them sliced, `sliced_values`), and as they are only
    /// for a matrix beyond `f32`'s range (empty otherwise: see
    /// [`Operator`]).
    values32: Vec<f32>,
    values: Vec<f64>,
    /// The layout of the iteration's products: the block structure sliced
    /// (`kernels/src/sliced.rs`), laid out for the current structure by the
    /// first solve on it (`sliced_laid`), and `values32` in it, written as
    /// they are rounded when the solve before iterated
    /// ([`SLICED_FROM`]: `slice`), so current (`sliced_current`).
    sliced: SlicedLayout,
    sliced_values: Vec<f32>,
    sliced_laid: bool,
    slice: bool,
    sliced_current: bool,
    /// A vector in the caller's numbering, and its product.
    x_given: Vec<f64>,
    r_given: Vec<f64>,
    /// Whether every rounded value is finite (else the iteration reads the
    /// `f64` values).
    rounded: bool,
    /// Whether the values last given to [`LinearSolver::factor`] are still
    /// to be carried into `values32` (by the next solve's first pass).
    pending: bool,
    /// Per-chunk sums of the fused passes.
    partial: Vec<f64>,
    partial_pairs: Vec<[f64; 2]>,
    /// Per-chunk restrictions `Pᵀ r` of the update pass (one coarse vector
    /// per chunk; one value per chunk without a coarse level).
    partial_restrictions: Vec<f64>,
    /// The right-hand side and the solution in the solver's numbering.
    b: Vec<f64>,
    x: Vec<f64>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    ap: Vec<f64>,
    /// The blocks' positions in the solver's numbering (empty when the
    /// caller gave none, or positions of another length), handed to the
    /// coarse level when it is refreshed.
    positions: Vec<[f64; 3]>,
    /// `Rᵀ r` and `A₀⁻¹ Rᵀ r` of the rotated preconditioner.
    rotated: Vec<f64>,
    /// The rotated rest-state preconditioner, when chosen.
    rest: Option<RestPreconditioner>,
    /// The coarse level added to block Jacobi, when chosen.
    coarse: Option<CoarseSpace>,
    /// When the coarse level is assembled and factored again.
    coarse_age: CoarseAge,
    /// The last corrections of the guess, from whose span each solve
    /// starts (see [`SolutionHistory`]).
    history: SolutionHistory,
}

/// Corrections a solver keeps to start the next solve from. Over 31
/// steps of bunny_100k as `cleave bench` steps it (AMD EPYC, 2 cores), 8
/// took the body with its base clamped from 85 to 50 iterations per step
/// at 1e-6 and from 139 to 92 at 1e-8 (55 and 97 when a young history was
/// judged by [`super::history::WORTH`] too), falling onto a plane from 1.6
/// to 1.0 and from 5.5 to 2.9, for one product of 8 vectors (1.2 to 1.5
/// ms there, against 2.8 to 3.0 ms for 8 products of one) and two passes,
/// about 2.2 ms, per projecting step. (A first version measured 4: 55 and
/// 108 clamped; 12: 49 and 96; and whole solutions kept instead of
/// corrections, 8: 57 and 111.)
const KEPT_CORRECTIONS: usize = 8;

/// The drift of the recurrence residual from the exact one that the
/// values rounded to `f32` cause, relative to the exact residual the
/// recurrence started from (`2⁻²⁴` times an amplification of tens to
/// hundreds). On bunny_100k with its base clamped, the recurrence (and
/// the history's projection before it, when its products took the rounded
/// values too) met 1e-8 where the exact residual was 16 to 28 times that,
/// having started from 3 to 6 million times it: a drift of about 5e-6. It
/// only decides when a reliable update is worth its exact product: the
/// exact residual is what a solve must meet.
const ROUNDED_DRIFT: f64 = 1e-5;

/// The fraction of the last exact residual at which the recurrence is
/// replaced on the way to the goal, when the drift from that residual
/// could reach half the goal: the drift is then still about
/// [`ROUNDED_DRIFT`] / `REPLACE_AT`, 1%, of the residual replaced.
const REPLACE_AT: f64 = 1e-3;

/// The most the exact residual may exceed the recurrence's for the
/// iteration to go on in its direction after the replacement. (Kept
/// through a larger drift, on the soft bar of the tests at 1e-8 where the
/// exact residual was 1.7 times the recurrence's, the direction took 900
/// iterations for three digits that a new round took in fewer than 100.)
const DRIFTED: f64 = 1.1;

/// The caller's block structure, `f64` values and right-hand side (its
/// layout and numbering), from which exact residuals are taken.
#[derive(Clone, Copy)]
struct Caller<'a> {
    structure: BlockColumns<'a>,
    values: &'a [f64],
    b: &'a [f64],
}

/// The matrix an iteration's products take: the values rounded to `f32`
/// (in the solver's sliced layout, or its column layout when they were not
/// sliced); the solver's `f64` copy of a matrix beyond `f32`'s range; or,
/// for the rare round that needs the exact values (the rounded
/// ones stalled), the caller's `f64` values on its structure, the vectors
/// carried to its numbering and back (no copy of 18 MB on bunny_100k kept
/// for it, to be sized at every cut).
#[derive(Clone, Copy)]
enum Operator<'a> {
    Rounded,
    Copied(&'a [f64]),
    Caller(Caller<'a>),
}

/// What a round of [`ConjugateGradient::iterate`] is given: the goal for
/// the exact residual's norm, the most iterations, and the norm of the
/// exact residual it starts from.
#[derive(Clone, Copy, Debug)]
struct Round {
    goal: f64,
    budget: usize,
    start: f64,
}

/// How a round ended: its iterations, the norm of the exact residual (held
/// in `self.r`), and whether the rounded values stalled it (they met the
/// goal where the exact residual had not halved).
#[derive(Clone, Copy, Debug)]
struct Ended {
    iterations: usize,
    residual: f64,
    stalled: bool,
}

/// Solves a coarse level serves before it is assembled and factored
/// again from the matrix of the moment. A step's matrix moves little from
/// one step to the next (the rotations turn, the contacts come and go),
/// and any symmetric positive definite coarse solve keeps the
/// preconditioner one: a lagged coarse level changes how fast the
/// iteration converges, never what it converges to. On bunny_100k (20
/// steps as `cleave bench` takes them, AMD EPYC 2 cores) a level refreshed
/// every 2, 4 or 8 solves took the same iterations to 0.1 per step as one
/// refreshed every solve (clamped base: 43.1 at 1e-6, 79.8 at 1e-8;
/// falling: 1.6 and 5.5), and a refresh costs 4.4 ms (2.0 summing the
/// values' runs, 1.4 assembling `Pᵀ A P`, 0.9 factoring). Once the falling
/// body lands, its contacts change from step to step and a lag costs
/// iterations: over 60 steps at 1e-8 (on the floor from the 34th), every
/// 4 solves took 55.9 per step, every 8 64.6, every 16 66.0, every solve
/// 37.5 (Intel Xeon model 207; before the rule of
/// [`CoarseAge::outgrown_within`]).
const COARSE_REFRESH: usize = 4;

/// Iterations a solve on a lagged coarse level may take beyond half again
/// those of the first solve after the level was made: about what making it
/// again costs on bunny_100k (4.4 ms, 5 to 8 iterations), so that a few
/// iterations more never trigger it.
const LAG_SLACK: usize = 8;

/// The age of the coarse level's factor: solves since it was made, the
/// iterations of the first of them and of the last. It is made again
/// when it has served [`COARSE_REFRESH`] solves, when a solve took more
/// than [`CoarseAge::outgrown`] iterations (a lagged level that stopped
/// fitting the matrix, after a jump in the contacts or the constraints:
/// such a solve makes it again as soon as it has spent that many, and goes
/// on from where it is, and the solves after it start on levels made for
/// them, see [`CoarseAge::outgrown_within`]), after a failed solve, and
/// after every analysis. The counts are deterministic, so is the choice.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct CoarseAge {
    /// `None`: no factor fits the current pattern (or the last solve failed).
    solves: Option<usize>,
    first: usize,
    last: usize,
    /// Solves still to start on a level made for them.
    fresh: usize,
}

impl CoarseAge {
    /// Whether the next factor must make the coarse level again.
    fn due(&self) -> bool {
        match self.solves {
            None => true,
            Some(solves) => {
                solves >= COARSE_REFRESH || self.fresh > 0 || self.outgrown().is_some_and(|most| self.last > most)
            }
        }
    }

    /// The most iterations a solve may take on a lagged level (one made
    /// before the last solve) before it is made again: half again the
    /// first solve's after it was made, plus [`LAG_SLACK`].
    fn outgrown(&self) -> Option<usize> {
        self.solves.filter(|&solves| solves > 0).map(|_| 3 * self.first / 2 + LAG_SLACK)
    }

    /// The coarse level was made from the current matrix.
    fn refreshed(&mut self) {
        *self = CoarseAge { solves: Some(0), first: 0, last: 0, fresh: self.fresh };
    }

    /// A lagged level stopped fitting within a solve and was made again:
    /// the next [`COARSE_REFRESH`] solves start on a level made for them.
    /// The matrix is changing faster than a lag allows (a body landing: its
    /// contacts change from step to step), and a level that outgrows within
    /// a solve wastes the iterations spent on it, as its refresh restarts
    /// the iteration. Without this rule, bunny_100k falling onto a plane
    /// took 79, 141, 227, 244, 300 and 324 iterations in its first steps on
    /// the floor, and every other later step outgrew its level: 55.9
    /// iterations per step over 60 steps at 1e-8 and 40.1 at 1e-6, against
    /// 40.8 and 29.2 with it (and its solve 72 -> 59 ms per step, three
    /// alternated runs of each, Intel Xeon model 207); with its base
    /// clamped, 55.7 and 36.8 either way.
    fn outgrown_within(&mut self) {
        self.fresh = COARSE_REFRESH + 1;
    }

    /// A solve ended, in `iterations` iterations, or failed (`None`).
    fn solved(&mut self, iterations: Option<usize>) {
        match (self.solves, iterations) {
            (Some(solves), Some(iterations)) => {
                if solves == 0 {
                    self.first = iterations;
                }
                (self.solves, self.last) = (Some(solves + 1), iterations);
                self.fresh = self.fresh.saturating_sub(1);
            }
            _ => self.solves = None,
        }
    }
}

/// The 3x3 block structure of a matrix in the layout of
/// `assembly::SparsePattern`, where every block column repeats its block
/// rows in its three scalar columns: block rows of block column `j` at
/// `rows[ptr[j]..ptr[j + 1]]`, its first value at `start[j]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BlockStructure {
    pub(super) ptr: Vec<u32>,
    pub(super) rows: Vec<u32>,
    pub(super) start: Vec<usize>,
}

impl BlockStructure {
    /// The block structure of `pattern`, or an error naming the first
    /// block column that is not a repeated 3x3 block column.
    pub fn new(pattern: SymbolicSparseColMatRef<'_, usize>) -> Result<Self, SolveError> {
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        let blocks = pattern.ncols() / 3;
        let first_rows = |j: usize| &ri[cp[3 * j]..cp[3 * j + 1]];
        // (the columns are checked and listed in parallel: a cut's new
        // pattern is analysed before the next step)
        let irregular = (0..blocks).into_par_iter().find_first(|&j| {
            let rows = first_rows(j);
            let regular = rows.len() % 3 == 0
                && rows.chunks(3).all(|r| r[0] % 3 == 0 && r[1] == r[0] + 1 && r[2] == r[0] + 2)
                && (1..3).all(|c| ri[cp[3 * j + c]..cp[3 * j + c + 1]] == *rows);
            !regular
        });
        if let Some(j) = irregular {
            return Err(SolveError::Analysis(format!("block column {j} is not a repeated 3x3 block column")));
        }
        let mut ptr = Vec::with_capacity(blocks + 1);
        ptr.push(0u32);
        for j in 0..blocks {
            let end = *ptr.last().expect("starts with 0") as usize + first_rows(j).len() / 3;
            ptr.push(u32::try_from(end).map_err(|_| SolveError::Analysis("over 2^32 blocks".into()))?);
        }
        let rows = (0..blocks)
            .into_par_iter()
            .flat_map_iter(|j| first_rows(j).iter().step_by(3).map(|&r| (r / 3) as u32))
            .collect();
        let start = (0..blocks).map(|j| cp[3 * j]).collect();
        Ok(BlockStructure { ptr, rows, start })
    }

    /// The structure of block columns given directly (by a caller that laid
    /// the pattern out, without reading its scalar rows): block rows of
    /// column `j` at `rows[ptr[j]..ptr[j + 1]]`, its `9 × rows` values from
    /// `start[j]` on, for a matrix of `nnz` values. Checked (in parallel):
    /// `ptr` runs from 0 to `rows.len()`, every column's rows ascend below
    /// the number of blocks, and the columns' values follow one another up
    /// to `nnz`; an error names the first block column that fails.
    pub fn from_columns(ptr: Vec<u32>, rows: Vec<u32>, start: Vec<usize>, nnz: usize) -> Result<Self, SolveError> {
        let blocks = start.len();
        let shape_ok = ptr.len() == blocks + 1
            && ptr.first() == Some(&0)
            && ptr.last().map(|&p| p as usize) == Some(rows.len())
            && ptr.windows(2).all(|w| w[0] <= w[1])
            && start.first().is_none_or(|&s| s == 0);
        if !shape_ok {
            return Err(SolveError::Analysis("the block columns' offsets are inconsistent".into()));
        }
        let bad = (0..blocks).into_par_iter().find_first(|&j| {
            let column = &rows[ptr[j] as usize..ptr[j + 1] as usize];
            let end = if j + 1 < blocks { start[j + 1] } else { nnz };
            let ascending =
                column.windows(2).all(|w| w[0] < w[1]) && column.last().is_none_or(|&r| (r as usize) < blocks);
            !(ascending && start[j].checked_add(9 * column.len()) == Some(end))
        });
        match bad {
            Some(j) => Err(SolveError::Analysis(format!("block column {j} is not laid out in order"))),
            None => Ok(BlockStructure { ptr, rows, start }),
        }
    }

    /// [`BlockStructure::from_columns`] for columns in order by
    /// construction (a pattern updated after a cut, whose new columns are
    /// sorted as they are made and whose other columns were checked when
    /// first laid out): the check, a pass over every block row (17 % of
    /// the update's instructions after a blade cut across bunny_100k), runs
    /// in debug builds only.
    pub(crate) fn from_ordered_columns(ptr: Vec<u32>, rows: Vec<u32>, start: Vec<usize>, nnz: usize) -> Self {
        debug_assert!(Self::from_columns(ptr.clone(), rows.clone(), start.clone(), nnz).is_ok());
        BlockStructure { ptr, rows, start }
    }

    /// The block rows of block column `j`.
    pub fn column_rows(&self, j: usize) -> &[u32] {
        &self.rows[self.ptr[j] as usize..self.ptr[j + 1] as usize]
    }

    /// Number of block rows over all block columns.
    pub fn rows_len(&self) -> usize {
        self.rows.len()
    }

    /// Takes the block rows out (the storage a caller may reuse).
    pub fn into_rows(self) -> Vec<u32> {
        self.rows
    }

    /// The first value of block column `j`.
    #[inline]
    pub fn start(&self, j: usize) -> usize {
        self.start[j]
    }

    /// The scalar compressed columns of the structure (the inverse of
    /// [`BlockStructure::new`]): block column `j`'s three scalar columns
    /// each hold the scalar rows `3 r, 3 r + 1, 3 r + 2` of its block rows
    /// `r`, one after another from value `start[j]` on.
    pub fn scalar(&self) -> SymbolicSparseColMat<usize> {
        let n = 3 * self.len();
        let stride = |j: usize| 3 * self.column_rows(j).len();
        let col_ptr: Vec<usize> =
            (0..n).map(|c| self.start[c / 3] + (c % 3) * stride(c / 3)).chain([self.values_len()]).collect();
        let mut row_idx = vec![0usize; self.values_len()];
        let lengths = (0..self.len()).map(|j| 3 * stride(j));
        crate::stretches(&mut row_idx, lengths).into_par_iter().enumerate().with_min_len(64).for_each(|(j, out)| {
            let third = stride(j);
            for (o, &r) in out[..third].chunks_exact_mut(3).zip(self.column_rows(j)) {
                o.copy_from_slice(&[3 * r as usize, 3 * r as usize + 1, 3 * r as usize + 2]);
            }
            out.copy_within(..third, third);
            out.copy_within(..third, 2 * third);
        });
        // SAFETY: the columns follow one another from 0 to the end of the
        // rows (`start`, checked when the structure was made), and each
        // holds its block rows' scalar rows, ascending and below `n`
        unsafe { SymbolicSparseColMat::new_unchecked(n, n, col_ptr, None, row_idx) }
    }

    /// Number of values the structure lays out.
    pub fn values_len(&self) -> usize {
        self.start.last().map_or(0, |&s| s + 9 * self.column_rows(self.len() - 1).len())
    }

    /// Number of block columns.
    pub fn len(&self) -> usize {
        self.start.len()
    }

    /// Whether there are no block columns.
    pub fn is_empty(&self) -> bool {
        self.start.is_empty()
    }

    /// The structure as the product kernel takes it.
    pub fn columns(&self) -> BlockColumns<'_> {
        BlockColumns { ptr: &self.ptr, rows: &self.rows, start: &self.start }
    }
}

/// `z = R A₀⁻¹ Rᵀ r`: the Cholesky factor of the rest-state matrix `A₀`
/// applied in per-block rotated frames `R`.
struct RestPreconditioner {
    cholesky: Cholesky,
    frames: Vec<[f64; 9]>,
    ready: bool,
}

impl ConjugateGradient {
    /// A solver with the given tolerance and iteration cap.
    pub fn new(tolerance: f64, max_iterations: usize) -> Self {
        ConjugateGradient {
            tolerance,
            max_iterations,
            numbering: Renumbering::default(),
            inverse_blocks: Vec::new(),
            given: BlockStructure::default(),
            values32: Vec::new(),
            values: Vec::new(),
            sliced: SlicedLayout::default(),
            sliced_values: Vec::new(),
            sliced_laid: false,
            slice: true,
            sliced_current: false,
            x_given: Vec::new(),
            r_given: Vec::new(),
            rounded: false,
            pending: false,
            partial: Vec::new(),
            partial_pairs: Vec::new(),
            partial_restrictions: Vec::new(),
            b: Vec::new(),
            x: Vec::new(),
            r: Vec::new(),
            z: Vec::new(),
            p: Vec::new(),
            ap: Vec::new(),
            positions: Vec::new(),
            rotated: Vec::new(),
            rest: None,
            coarse: None,
            history: SolutionHistory::new(KEPT_CORRECTIONS),
            coarse_age: CoarseAge::default(),
        }
    }

    /// Carries the caller's values `given` (those [`LinearSolver::factor`]
    /// took) into the solver's layout and makes what depends on them, in
    /// one parallel pass over them: the values rounded to `f32`, the
    /// diagonal blocks inverted (block Jacobi, from the `f64` values), the
    /// values checked (a finite value beyond `f32`'s range rounds to
    /// infinity, and then the iteration takes the `f64` values throughout,
    /// copied as well), the residual `self.r = b - A x` of the guess, and
    /// (when `project`) the products of the history's corrections, all
    /// three in the solver's numbering; then the coarse level when it is
    /// due. Returns `|r|` and the projection's sums (`Vᵀ A V`, `Vᵀ r`).
    ///
    /// The pass reads the matrix once where the rounding, the first exact
    /// residual and the projection's products read it three times, and
    /// the projected residual is then exact: the recurrence that starts
    /// from it drifts from a residual thousands of times smaller than the
    /// guess's, and needs no reliable update on the way to 1e-8 once the
    /// history predicts well. On bunny_100k with its base clamped, CG to
    /// 1e-8, 20 steps as `cleave bench` takes them (2 cores, Intel Xeon,
    /// four runs of each alternated): 1.55 exact residuals per solve
    /// instead of 3.05, the rounding, the exact residuals and the
    /// projection 5.9 ms instead of 8.1, the solve 51.9 -> 49.7 ms per
    /// step, 56.05 -> 55.7 iterations.
    fn carry_values(
        &mut self,
        given: &[f64],
        b: &[f64],
        x: &[f64],
        project: bool,
    ) -> Result<(f64, Option<ProjectionSums>), SolveError> {
        let (v, a_v) = match project {
            true => self.history.products_to_make(),
            false => (&[][..], &mut [][..]),
        };
        let inverse = |b| {
            let m = invert3(b);
            [m[0], m[1], m[2], m[4], m[5], m[8]]
        };
        if !self.sliced_laid {
            let blocks = self.numbering.blocks();
            self.sliced.renew(blocks.columns(), blocks.len());
            crate::resize_with_room(&mut self.sliced_values, self.sliced.values_len(), 0.0);
            self.sliced_laid = true;
        }
        // each task's columns: their rounded values sliced, r = b - A x, A
        // V, and their sums
        let (view, layout, starts) = (self.numbering.old_columns(), &self.sliced, &self.numbering.blocks().start);
        let sliced = AlongGroups { values: &mut self.sliced_values, layout, first: 0 };
        let parts = ((Along::columns(&mut self.r, 3), Along::columns(a_v, 3 * VECTORS)), sliced);
        type Parts<'a> = ((Along<'a, f64>, Along<'a, f64>), AlongGroups<'a>);
        let slicing = self.slice;
        let task = |columns: Range<usize>, rounded: &[f32], ((r, a_v), sliced): &mut Parts<'_>| {
            if slicing {
                let groups = layout.groups_of(columns.clone());
                layout.fill(rounded, starts[columns.start], groups, sliced.values);
            }
            let unknowns = 3 * columns.start..3 * columns.end;
            block_products(view, given, x, columns.start, r.0);
            r.0.iter_mut().zip(&b[unknowns.clone()]).for_each(|(r, b)| *r = b - *r);
            let squares: f64 = r.0.iter().map(|r| r * r).sum();
            let sums = (!a_v.0.is_empty()).then(|| {
                block_products_of_vectors(view, given, v, columns.start, a_v.0);
                ProjectionSums::of(&v[VECTORS * unknowns.start..VECTORS * unknowns.end], a_v.0, r.0)
            });
            (squares, sums)
        };
        let combine = |(a, s): (f64, Option<ProjectionSums>), (b, t): (f64, Option<ProjectionSums>)| {
            (a + b, s.zip(t).map(|(s, t)| s.plus(t)))
        };
        let (finite, rounded, (squares, sums)) = self.numbering.round_values(
            given,
            &mut self.values32,
            &mut self.inverse_blocks,
            inverse,
            parts,
            task,
            combine,
        );
        if !finite {
            return Err(SolveError::NonFinite);
        }
        self.pending = false;
        (self.rounded, self.sliced_current) = (rounded, slicing);
        if rounded {
            self.values.clear();
        } else {
            // (the one allocation a solve may make, for a matrix no
            // physical body has: its values and inverted diagonal blocks
            // were checked above)
            self.values.resize(given.len(), 0.0);
            self.numbering.carry_exact(given, &mut self.values);
        }
        if self.coarse_age.due() {
            self.refresh_coarse()?;
        }
        // one coarse vector per chunk of the update pass (one value per
        // chunk without a coarse level)
        let m = self.coarse.as_ref().map_or(1, |c| c.window_len().max(1));
        self.partial_restrictions.resize(self.partial_pairs.len() * m, 0.0);
        Ok((squares.sqrt(), sums))
    }

    /// Preconditions with the rotated rest-state Cholesky factor (see
    /// [`super::SolverKind::CgRest`]) once a reference matrix is given.
    pub fn with_rest_preconditioner(mut self) -> Self {
        self.rest = Some(RestPreconditioner { cholesky: Cholesky::default(), frames: Vec::new(), ready: false });
        self
    }

    /// `y = A x` through the block structure (see module docs), for values
    /// `val` stored as `f64` or `f32`; returns `x · y`, summed per fixed
    /// chunk of blocks and the chunk sums in order (the same bits on any
    /// number of threads).
    fn matvec<T: Value>(&self, val: &[T], x: &[f64], y: &mut [f64], partial: &mut [f64]) -> f64 {
        let structure = self.numbering.blocks().columns();
        y.par_chunks_mut(3 * CHUNK_BLOCKS).zip(partial.par_iter_mut()).enumerate().for_each(|(c, (yc, part))| {
            *part = block_products(structure, val, x, c * CHUNK_BLOCKS, yc);
        });
        partial.iter().sum()
    }

    /// [`ConjugateGradient::matvec`] with `values32` in the sliced layout:
    /// the iteration's product (when they were sliced, [`SLICED_FROM`]).
    fn sliced_matvec(&self, x: &[f64], y: &mut [f64], partial: &mut [f64]) -> f64 {
        let (layout, values) = (&self.sliced, &self.sliced_values);
        y.par_chunks_mut(3 * CHUNK_BLOCKS).zip(partial.par_iter_mut()).enumerate().for_each(|(c, (yc, part))| {
            *part = layout.products(values, x, c * CHUNK_BLOCKS, yc);
        });
        partial.iter().sum()
    }

    /// `self.r = b - A x` with the `caller`'s `f64` values and right-hand
    /// side `b` (in its layout and numbering), for `x` in the solver's
    /// numbering; returns `|r|`. (The product runs on the caller's
    /// structure: the solver's copy of the values is `f32`.)
    fn exact_residual(&mut self, caller: Caller<'_>, x: &[f64]) -> f64 {
        let mut partial = std::mem::take(&mut self.partial);
        self.caller_product(caller, x, &mut partial);
        self.partial = partial;
        self.r_given.par_iter_mut().zip(caller.b).for_each(|(r, b)| *r = b - *r);
        self.numbering.to_new(as_blocks(&self.r_given), as_blocks_mut(&mut self.r));
        dot(&self.r, &self.r).sqrt()
    }

    /// `self.r_given = A x` with the `caller`'s `f64` values on its
    /// structure and numbering, for `x` in the solver's numbering (carried
    /// into `self.x_given`); returns `x · A x`, summed per fixed chunk of
    /// the caller's blocks (into `partial`) and the chunk sums in order.
    fn caller_product(&mut self, caller: Caller<'_>, x: &[f64], partial: &mut [f64]) -> f64 {
        let (mut x_given, mut y_given) = (std::mem::take(&mut self.x_given), std::mem::take(&mut self.r_given));
        self.numbering.to_old(as_blocks(x), as_blocks_mut(&mut x_given));
        y_given.par_chunks_mut(3 * CHUNK_BLOCKS).zip(partial.par_iter_mut()).enumerate().for_each(|(c, (y, part))| {
            *part = block_products(caller.structure, caller.values, &x_given, c * CHUNK_BLOCKS, y);
        });
        (self.x_given, self.r_given) = (x_given, y_given);
        partial.iter().sum()
    }

    /// [`ConjugateGradient::iterate`] on the `f64` values (`exact`) or on
    /// the values rounded to `f32`: the `f64` values are the solver's copy
    /// for a matrix beyond `f32`'s range, else the caller's.
    fn iterate_on(
        &mut self,
        exact: bool,
        caller: Caller<'_>,
        round: Round,
        x: &mut [f64],
    ) -> Result<Ended, SolveError> {
        let values = std::mem::take(&mut self.values);
        let operator = match (exact, self.rounded) {
            (false, _) => Operator::Rounded,
            (true, false) => Operator::Copied(&values),
            (true, true) => Operator::Caller(caller),
        };
        let out = self.iterate(operator, caller, round, x);
        self.values = values;
        out
    }

    /// `y = A x` with the matrix of `operator` (see
    /// [`ConjugateGradient::matvec`]); returns `x · y`.
    fn product(&mut self, operator: Operator<'_>, x: &[f64], y: &mut [f64], partial: &mut [f64]) -> f64 {
        match operator {
            Operator::Rounded if self.sliced_current => self.sliced_matvec(x, y, partial),
            Operator::Rounded => self.matvec(&self.values32, x, y, partial),
            Operator::Copied(values) => self.matvec(values, x, y, partial),
            Operator::Caller(caller) => {
                let x_ay = self.caller_product(caller, x, partial);
                self.numbering.to_new(as_blocks(&self.r_given), as_blocks_mut(y));
                x_ay
            }
        }
    }

    /// Preconditioned CG on `A d = r` from `d = 0`, `r` the exact residual
    /// held in `self.r` (of norm `round.start`), adding `d` to `x`, until
    /// the exact residual is at most `round.goal` or `round.budget`
    /// iterations are spent; `self.r` is then the exact residual. With a
    /// coarse level it starts from the coarse solution instead, `d = P
    /// A_c⁻¹ Pᵀ r` (see [`ConjugateGradient::deflate`]).
    ///
    /// The recurrence `r -= α A p` takes the products of `operator`: on the
    /// rounded ones it drifts from the exact residual `b - A x` by about
    /// [`ROUNDED_DRIFT`] of the exact residual it started from. So the
    /// recurrence is replaced by the exact residual (a reliable update, as
    /// in Sleijpen and van der Vorst 1996, "Reliable updated residuals in
    /// hybrid Bi-CG methods") on the way to the goal, once it has fallen to
    /// [`REPLACE_AT`] of the last exact residual, if the drift from that one
    /// could reach half the goal: the search direction is kept, so the
    /// iteration goes on where a new round would begin again from the
    /// coarse level's start, unless the drift was beyond [`DRIFTED`]. When
    /// the recurrence meets the goal, the exact residual is taken, and a
    /// new round begins from it if it does not meet it too. (Kept through
    /// a replacement at the goal, on a bar whose rounded values could not
    /// quite meet the goal, the direction was replaced at every iteration
    /// and lost its way. On bunny_100k with its base clamped, CG to
    /// 1e-8, 20 steps as `cleave bench` takes them, 2 cores, Intel Xeon
    /// with AVX-512: a new round from the exact residual whenever the
    /// recurrence met the goal took 79.8 iterations per step (the first
    /// steps 89 to 125 per solve, 14 to 30 of them after the first round),
    /// reliable updates 65.9 (the last steps 44 or 45 per solve). Falling
    /// onto a plane, 5.5 and 2.6 at 1e-8, 1.65 and 0.55 at 1e-6.)
    fn iterate(
        &mut self,
        operator: Operator<'_>,
        caller: Caller<'_>,
        round: Round,
        x: &mut [f64],
    ) -> Result<Ended, SolveError> {
        if !self.rest.as_ref().is_some_and(|p| p.ready) {
            self.deflate(operator, x);
        }
        self.precondition_residual()?;
        self.p.copy_from_slice(&self.z);
        let mut rz = dot(&self.r, &self.z);
        // block Jacobi is applied inside the update pass; the rotated
        // rest-state factor needs the whole residual first
        let blockwise = !self.rest.as_ref().is_some_and(|p| p.ready);
        let rounded = matches!(operator, Operator::Rounded);
        let mut replaced = round.start;
        for it in 0..round.budget {
            let (mut ap, mut partial) = (std::mem::take(&mut self.ap), std::mem::take(&mut self.partial));
            let p = std::mem::take(&mut self.p);
            let pap = self.product(operator, &p, &mut ap, &mut partial);
            self.p = p;
            (self.ap, self.partial) = (ap, partial);
            if !(pap > 0.0) {
                return Err(SolveError::NonPositiveCurvature { iteration: it, curvature: pap });
            }
            let alpha = rz / pap;
            let smoother =
                blockwise.then_some(Smoother { inverse: &self.inverse_blocks, coarse: self.coarse.as_ref() });
            let partial = (&mut self.partial_pairs[..], &mut self.partial_restrictions[..]);
            let [rr, rz_blockwise] = update(x, &mut self.r, &mut self.z, &self.p, &self.ap, smoother, alpha, partial);
            let residual = rr.sqrt();
            if !residual.is_finite() {
                return Err(SolveError::NonFinite);
            }
            let drifting = rounded && residual <= REPLACE_AT * replaced && ROUNDED_DRIFT * replaced > 0.5 * round.goal;
            if residual <= round.goal || drifting {
                let exact = self.exact_residual(caller, x);
                if exact <= round.goal || !exact.is_finite() {
                    return Ok(Ended { iterations: it + 1, residual: exact, stalled: false });
                }
                if residual <= round.goal || exact > DRIFTED * residual {
                    // met by the recurrence but not by the exact residual,
                    // or the recurrence drifted too far for its direction
                    // to serve the exact residual: a new round begins from
                    // it (with the coarse level's start), on the exact
                    // values if the rounded ones did not halve it
                    return Ok(Ended { iterations: it + 1, residual: exact, stalled: exact > 0.5 * replaced });
                }
                replaced = exact;
                self.precondition_residual()?;
                let rz_new = dot(&self.r, &self.z);
                next_direction(&mut self.p, &self.z, None, rz_new / rz);
                rz = rz_new;
                continue;
            }
            // (the coarse correction's share of r · z is known before it is
            // prolonged, so the prolongation forms the next direction)
            let rz_new = if blockwise {
                rz_blockwise + self.coarse.as_mut().map_or(0.0, |c| c.solve(&self.partial_restrictions))
            } else {
                self.precondition_residual()?;
                dot(&self.r, &self.z)
            };
            let beta = rz_new / rz;
            rz = rz_new;
            let coarse = self.coarse.as_ref().filter(|_| blockwise);
            next_direction(&mut self.p, &self.z, coarse, beta);
        }
        let exact = self.exact_residual(caller, x);
        Ok(Ended { iterations: round.budget, residual: exact, stalled: false })
    }

    /// `self.z` = the preconditioner applied to `self.r`.
    fn precondition_residual(&mut self) -> Result<(), SolveError> {
        let (r, mut z) = (std::mem::take(&mut self.r), std::mem::take(&mut self.z));
        let out = self.precondition(&r, &mut z);
        (self.r, self.z) = (r, z);
        out
    }

    /// Makes the coarse level (if any) from the values the iteration reads
    /// (the preconditioner need not be exact, and the rounded ones are half
    /// the bytes) and the last positions given.
    fn refresh_coarse(&mut self) -> Result<(), SolveError> {
        let Some(coarse) = self.coarse.as_mut() else { return Ok(()) };
        coarse.set_positions(&self.positions);
        self.coarse_age = CoarseAge { fresh: self.coarse_age.fresh, ..CoarseAge::default() };
        match self.rounded {
            true => coarse.factor(self.numbering.blocks(), &self.values32)?,
            false => coarse.factor(self.numbering.blocks(), &self.values)?,
        }
        self.coarse_age.refreshed();
        // (a level made with rotations restricts into longer windows)
        let m = coarse.window_len().max(1);
        self.partial_restrictions.resize(self.partial_pairs.len() * m, 0.0);
        Ok(())
    }

    /// The solve of [`LinearSolver::solve`] in the solver's numbering (`b`
    /// and `x`), the `caller`'s structure, values and right-hand side for
    /// the exact residual.
    fn solve_own(&mut self, caller: Caller<'_>, b: &[f64], x: &mut [f64]) -> Result<SolveStats, SolveError> {
        let norm_b = dot(b, b).sqrt();
        if norm_b == 0.0 {
            x.fill(0.0);
            return Ok(SolveStats { iterations: 0, residual: 0.0 });
        }
        let goal = self.tolerance * norm_b;
        // (new values are carried in the pass that takes the first residual
        // and, when the history will project, its exact products)
        let made = self.pending && self.history.would_project();
        let (mut norm_r, sums) = match self.pending {
            true => self.carry_values(caller.values, b, x, made)?,
            false => (self.exact_residual(caller, x), None),
        };
        let (mut iterations, mut exact) = (0, !self.rounded);
        self.history.begin(x);
        // (the exact residual the recurrence starts from: products on the
        // rounded values drift from it as the iteration's do)
        let mut drift_from = norm_r;
        if norm_r > goal && self.history.wanted() && self.project_on_history(exact, sums.as_ref(), x) {
            // (on the products the pass made, the projected residual is
            // exact; on the values the iteration reads, it counts once the
            // exact one confirms it)
            let before = norm_r;
            norm_r = dot(&self.r, &self.r).sqrt();
            self.history.judge(norm_r / before);
            if sums.is_some() {
                drift_from = norm_r;
            } else if norm_r <= goal {
                norm_r = self.exact_residual(caller, x);
            }
        }
        // (a lagged coarse level serves until the solve has spent as many
        // iterations as it may, see CoarseAge)
        let mut lagged = self.coarse.as_ref().and(self.coarse_age.outgrown());
        loop {
            if norm_r <= goal {
                self.history.record(x);
                return Ok(SolveStats { iterations, residual: norm_r / norm_b });
            }
            if !norm_r.is_finite() {
                return Err(SolveError::NonFinite);
            }
            let budget = self.max_iterations - iterations;
            if budget == 0 {
                return Err(SolveError::NotConverged {
                    iterations,
                    residual: norm_r / norm_b,
                    tolerance: self.tolerance,
                });
            }
            let budget = lagged.map_or(budget, |most| budget.min(most.saturating_sub(iterations).max(1)));
            let ended = self.iterate_on(exact, caller, Round { goal, budget, start: drift_from }, x)?;
            iterations += ended.iterations;
            norm_r = ended.residual;
            drift_from = norm_r;
            if norm_r > goal && lagged.is_some_and(|most| iterations >= most) {
                // the level no longer fits the matrix: made again, the
                // iteration goes on from here
                self.refresh_coarse()?;
                self.coarse_age.outgrown_within();
                lagged = None;
                continue;
            }
            exact |= ended.stalled;
        }
    }

    /// `x` and its residual `self.r` moved to the best start in the span of
    /// the last corrections ([`SolutionHistory::project`]), with the
    /// products and `sums` [`ConjugateGradient::carry_values`] made, else
    /// with products on the `f64` values when `exact`, else on the rounded
    /// ones; returns whether they moved.
    fn project_on_history(&mut self, exact: bool, sums: Option<&ProjectionSums>, x: &mut [f64]) -> bool {
        if let Some(sums) = sums {
            return self.history.project_summed(sums, x, &mut self.r);
        }
        let (mut history, mut r) = (std::mem::take(&mut self.history), std::mem::take(&mut self.r));
        let structure = self.numbering.blocks().columns();
        let products = |v: &[f64], a_v: &mut [f64]| {
            let chunks = a_v.par_chunks_mut(3 * VECTORS * CHUNK_BLOCKS).enumerate();
            chunks.for_each(|(c, a_v)| match exact {
                true => block_products_of_vectors(structure, &self.values, v, c * CHUNK_BLOCKS, a_v),
                false => block_products_of_vectors(structure, &self.values32, v, c * CHUNK_BLOCKS, a_v),
            });
        };
        let moved = history.project(products, x, &mut r);
        (self.history, self.r) = (history, r);
        moved
    }

    /// The coarse level's start: `x += w` and `r -= A w` for `w = P T
    /// A₂⁻¹ Tᵀ Pᵀ r`, the exact solution of the residual's equation on the
    /// rigid motions of the aggregates of aggregates (on all aggregates
    /// when their system is solved exactly), after which the residual has
    /// no component there (a deflated start, as in Saad, Yeung, Erhel and
    /// Guyomarc'h 2000). The error the preconditioner reduces slowest,
    /// motions of whole regions, is then gone before the first iteration:
    /// a step that moves the body rigidly, as a free fall does, starts
    /// within a few digits of its answer (bunny_100k falling: 1.7
    /// iterations per step at 1e-6 where the start `x` alone took 21). `A
    /// w` is a product on the `values` the round iterates on, so `r` stays
    /// the residual of that matrix.
    fn deflate(&mut self, operator: Operator<'_>, x: &mut [f64]) {
        let Some(coarse) = self.coarse.as_mut() else { return };
        let mut w = std::mem::take(&mut self.z);
        w.fill(0.0);
        coarse.correct(&self.r, &mut w, Correction::Groups);
        let (mut aw, mut partial) = (std::mem::take(&mut self.ap), std::mem::take(&mut self.partial));
        self.product(operator, &w, &mut aw, &mut partial);
        (x.par_iter_mut().zip(&w)).zip(self.r.par_iter_mut().zip(&aw)).for_each(|((x, w), (r, aw))| {
            *x += w;
            *r -= aw;
        });
        (self.z, self.ap, self.partial) = (w, aw, partial);
    }

    fn precondition(&mut self, r: &[f64], z: &mut [f64]) -> Result<(), SolveError> {
        if let Some(rest) = self.rest.as_mut().filter(|p| p.ready) {
            // (the factor and the frames are in the caller's numbering:
            // Rᵀ r is formed there, R A₀⁻¹ Rᵀ r carried back)
            let (order, rank) = (self.numbering.order(), self.numbering.rank());
            let t = &mut self.rotated;
            t.resize(r.len(), 0.0);
            t.par_chunks_mut(3).zip(&rest.frames).zip(rank).for_each(|((t, m), &b)| {
                let v = &r[3 * b as usize..3 * b as usize + 3];
                (0..3).for_each(|i| t[i] = m[i] * v[0] + m[3 + i] * v[1] + m[6 + i] * v[2]);
            });
            rest.cholesky.solve_in_place(t)?;
            z.par_chunks_mut(3).zip(order).for_each(|(z, &o)| {
                let (m, v) = (&rest.frames[o as usize], &t[3 * o as usize..3 * o as usize + 3]);
                (0..3).for_each(|i| z[i] = row_times(m, i, v));
            });
            return Ok(());
        }
        z.par_chunks_mut(3).zip(r.par_chunks(3)).zip(&self.inverse_blocks).for_each(|((z, r), m)| {
            z.copy_from_slice(&symmetric_times(m, r));
        });
        if let Some(coarse) = self.coarse.as_mut() {
            coarse.correct(r, z, Correction::Whole);
        }
        Ok(())
    }
}

/// The preconditioner the update pass applies: block Jacobi (the inverted
/// diagonal blocks) and, with a coarse level, the restriction of the new
/// residual per chunk of blocks.
struct Smoother<'a> {
    inverse: &'a [[f64; 6]],
    coarse: Option<&'a CoarseSpace>,
}

/// One pass of a CG iteration over fixed chunks of blocks: `x += α p`,
/// `r -= α A p`, and, given the smoother, `z = D⁻¹ r` and each chunk's
/// `Pᵀ r` (into the chunk's run of `partial.1`, sized by
/// [`ConjugateGradient::factor`]); returns `[r · r, r · z]` (`r · z` is 0
/// without a smoother), each summed per chunk (into `partial.0`) and the
/// chunk sums in order.
#[allow(clippy::too_many_arguments)]
fn update(
    x: &mut [f64],
    r: &mut [f64],
    z: &mut [f64],
    p: &[f64],
    ap: &[f64],
    smoother: Option<Smoother<'_>>,
    alpha: f64,
    partial: (&mut [[f64; 2]], &mut [f64]),
) -> [f64; 2] {
    let len = 3 * CHUNK_BLOCKS;
    let (partial, restrictions) = partial;
    let (inverse, coarse) = smoother.map_or((None, None), |s| (Some(s.inverse), s.coarse));
    let m = restrictions.len() / partial.len().max(1);
    (x.par_chunks_mut(len).zip(r.par_chunks_mut(len)).zip(z.par_chunks_mut(len)))
        .zip(p.par_chunks(len).zip(ap.par_chunks(len)))
        .zip(partial.par_iter_mut().zip(restrictions.par_chunks_mut(m.max(1))))
        .enumerate()
        .for_each(|(c, ((((x, r), z), (p, ap)), (part, restricted)))| {
            let (mut rr, mut rz) = (0.0, 0.0);
            for (q, (((x, r), z), (p, ap))) in x
                .chunks_exact_mut(3)
                .zip(r.chunks_exact_mut(3))
                .zip(z.chunks_exact_mut(3))
                .zip(p.chunks_exact(3).zip(ap.chunks_exact(3)))
                .enumerate()
            {
                // (the new residual is kept in registers: read back from
                // its two scalar stores as one vector, it stalled the
                // pass on the failed store forwarding)
                let new: [f64; 3] = std::array::from_fn(|d| r[d] - alpha * ap[d]);
                for d in 0..3 {
                    x[d] += alpha * p[d];
                }
                r.copy_from_slice(&new);
                rr += new[0] * new[0] + new[1] * new[1] + new[2] * new[2];
                if let Some(inverse) = inverse {
                    let zn = symmetric_times(&inverse[c * CHUNK_BLOCKS + q], &new);
                    z.copy_from_slice(&zn);
                    rz += new[0] * zn[0] + new[1] * zn[1] + new[2] * zn[2];
                }
            }
            if let Some(coarse) = coarse {
                coarse.restrict(c, r, restricted);
            }
            *part = [rr, rz];
        });
    partial.iter().fold([0.0; 2], |s, p| [s[0] + p[0], s[1] + p[1]])
}

/// The next search direction `p = z + P e + β p` per chunk of blocks: `z`
/// block Jacobi's share of the preconditioned residual, `P e` the coarse
/// level's (its last solve), when there is one.
fn next_direction(p: &mut [f64], z: &[f64], coarse: Option<&CoarseSpace>, beta: f64) {
    let len = 3 * CHUNK_BLOCKS;
    p.par_chunks_mut(len).zip(z.par_chunks(len)).enumerate().for_each(|(c, (p, z))| match coarse {
        Some(coarse) => {
            for (q, (p, z)) in p.chunks_exact_mut(3).zip(z.chunks_exact(3)).enumerate() {
                let add = coarse.prolonged(c * CHUNK_BLOCKS + q);
                (0..3).for_each(|d| p[d] = (z[d] + add[d]) + beta * p[d]);
            }
        }
        None => p.iter_mut().zip(z).for_each(|(p, z)| *p = z + beta * *p),
    });
}

/// The symmetric 3x3 matrix `m` (upper triangle `[m00, m01, m02, m11, m12,
/// m22]`) times the 3-vector `v`.
#[inline(always)]
fn symmetric_times(m: &[f64; 6], v: &[f64]) -> [f64; 3] {
    [
        m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
        m[1] * v[0] + m[3] * v[1] + m[4] * v[2],
        m[2] * v[0] + m[4] * v[1] + m[5] * v[2],
    ]
}

/// Row `i` of the row-major 3x3 matrix `m` times the 3-vector `v`.
#[inline(always)]
fn row_times(m: &[f64; 9], i: usize, v: &[f64]) -> f64 {
    m[3 * i] * v[0] + m[3 * i + 1] * v[1] + m[3 * i + 2] * v[2]
}

/// `y = A x` for symmetric `A` stored in both triangles.
pub fn symmetric_matvec(a: SparseColMatRef<'_, usize, f64>, x: &[f64], y: &mut [f64]) {
    let (sym, val) = a.parts();
    let (cp, ri) = (sym.col_ptr(), sym.row_idx());
    y.par_iter_mut().with_min_len(512).enumerate().for_each(|(i, yi)| {
        let mut s = 0.0;
        for p in cp[i]..cp[i + 1] {
            s += val[p] * x[ri[p]];
        }
        *yi = s;
    });
}

/// Chunk sums [`dot`] keeps on the stack (vectors up to `4096 · 1024`
/// values); longer vectors keep theirs on the heap.
const STACK_CHUNKS: usize = 1024;

/// `Σ a_i b_i`, summed in fixed chunks in parallel and the chunk sums in
/// order (deterministic: the same bits on any number of threads).
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    let chunks = a.len().div_ceil(CHUNK);
    let sum_into = |partial: &mut [f64]| -> f64 {
        partial
            .par_iter_mut()
            .zip(a.par_chunks(CHUNK).zip(b.par_chunks(CHUNK)))
            .for_each(|(s, (x, y))| *s = lane_dot(x, y));
        partial.iter().sum()
    };
    if chunks <= STACK_CHUNKS {
        sum_into(&mut [0.0; STACK_CHUNKS][..chunks])
    } else {
        sum_into(&mut vec![0.0; chunks])
    }
}

/// Lanes of [`lane_dot`]'s independent sums.
const LANES: usize = 8;

/// `Σ x_i y_i` of one chunk: [`LANES`] running sums, lane `l` taking every
/// entry `i ≡ l (mod LANES)`, then the lanes and the tail in order. (One
/// running sum waits out an addition's latency per entry; independent
/// lanes vectorise and keep up with memory.)
fn lane_dot(x: &[f64], y: &[f64]) -> f64 {
    let mut lanes = [0.0; LANES];
    let (xs, ys) = (x.chunks_exact(LANES), y.chunks_exact(LANES));
    let tail: f64 = xs.remainder().iter().zip(ys.remainder()).map(|(p, q)| p * q).sum();
    for (xs, ys) in xs.zip(ys) {
        for l in 0..LANES {
            lanes[l] += xs[l] * ys[l];
        }
    }
    lanes.iter().sum::<f64>() + tail
}

/// A vector of 3-blocks as its blocks.
fn as_blocks(v: &[f64]) -> &[[f64; 3]] {
    bytemuck::cast_slice(v)
}

/// [`as_blocks`], mutable.
fn as_blocks_mut(v: &mut [f64]) -> &mut [[f64; 3]] {
    bytemuck::cast_slice_mut(v)
}

/// Inverse of a 3x3 matrix (row-major); the identity where it is singular.
fn invert3(m: [f64; 9]) -> [f64; 9] {
    let c = [
        m[4] * m[8] - m[5] * m[7],
        m[2] * m[7] - m[1] * m[8],
        m[1] * m[5] - m[2] * m[4],
        m[5] * m[6] - m[3] * m[8],
        m[0] * m[8] - m[2] * m[6],
        m[2] * m[3] - m[0] * m[5],
        m[3] * m[7] - m[4] * m[6],
        m[1] * m[6] - m[0] * m[7],
        m[0] * m[4] - m[1] * m[3],
    ];
    let det = m[0] * c[0] + m[1] * c[3] + m[2] * c[6];
    if det.abs() > 0.0 && det.is_finite() {
        c.map(|x| x / det)
    } else {
        [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    }
}

impl ConjugateGradient {
    /// The analysis of a pattern whose 3x3 block structure is `blocks`:
    /// the solver's numbering of the blocks, the coarse level's aggregates,
    /// and the arrays of the iteration, sized.
    fn analyze_structure(&mut self, blocks: &BlockStructure) -> Result<(), SolveError> {
        let n = 3 * blocks.len();
        // (the arrays of the previous topology's analysis are reused: a
        // solver renewed by a cut writes into pages it already has)
        self.numbering.renew(blocks);
        self.history.resize(n);
        // (named in the caller's numbering)
        if let Some(block) = self.numbering.missing_diagonal() {
            return Err(SolveError::Analysis(format!("block {block} has no diagonal")));
        }
        let blocks = self.numbering.blocks();
        crate::resize_with_room(&mut self.inverse_blocks, n / 3, [0.0; 6]);
        // (the rotated rest-state factor replaces block Jacobi and its
        // coarse level, and takes the new reference before a solve)
        let limit = aggregate_limit(blocks.values_len());
        let old = self.coarse.take().unwrap_or_default();
        self.coarse = self.rest.is_none().then(|| {
            let visit = anchored_order(blocks, self.numbering.analysed());
            CoarseSpace::renew(blocks, &visit, limit, CHUNK_BLOCKS, old)
        });
        self.coarse_age = CoarseAge::default();
        self.positions.clear();
        if let Some(rest) = self.rest.as_mut() {
            rest.ready = false;
        }
        // (every entry is written before it is read in a solve; the arrays
        // keep room for the next cuts, [`crate::reserve_room`])
        crate::resize_with_room(&mut self.values32, blocks.values_len(), 0.0);
        (self.sliced_laid, self.sliced_current) = (false, false);
        self.values.clear();
        for v in [&mut self.b, &mut self.x, &mut self.r, &mut self.z, &mut self.p, &mut self.ap, &mut self.x_given] {
            crate::resize_with_room(v, n, 0.0);
        }
        crate::resize_with_room(&mut self.r_given, n, 0.0);
        let chunks = (n / 3).div_ceil(CHUNK_BLOCKS);
        self.partial.resize(chunks, 0.0);
        self.partial_pairs.resize(chunks, [0.0; 2]);
        Ok(())
    }

    /// Takes note of new `values` (see [`LinearSolver::factor`]).
    fn take_values(&mut self, values: &[f64]) -> Result<(), SolveError> {
        if values.len() != self.values32.len() {
            return Err(SolveError::NotReady);
        }
        self.pending = true;
        Ok(())
    }

    /// Solves with the matrix of `values` on the block structure
    /// `structure` the solver was analysed for (see
    /// [`LinearSolver::solve`]).
    fn solve_with(
        &mut self,
        structure: &BlockStructure,
        values: &[f64],
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, SolveError> {
        if b.iter().chain(x.iter()).any(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite);
        }
        let n = self.b.len();
        let analysed = 3 * structure.len() == n && structure.values_len() == self.values32.len();
        if !analysed || values.len() != self.values32.len() || b.len() != n || x.len() != n {
            return Err(SolveError::NotReady);
        }
        // (no values given since the analysis: none laid out to iterate on)
        if !self.pending && !self.sliced_laid {
            return Err(SolveError::NotReady);
        }
        let (mut b_own, mut x_own) = (std::mem::take(&mut self.b), std::mem::take(&mut self.x));
        self.numbering.to_new(as_blocks(b), as_blocks_mut(&mut b_own));
        self.numbering.to_new(as_blocks(x), as_blocks_mut(&mut x_own));
        let caller = Caller { structure: structure.columns(), values, b };
        let stats = self.solve_own(caller, &b_own, &mut x_own);
        self.coarse_age.solved(stats.as_ref().ok().map(|s| s.iterations));
        self.slice = stats.as_ref().map_or(true, |s| s.iterations >= SLICED_FROM);
        self.numbering.to_old(as_blocks(&x_own), as_blocks_mut(x));
        (self.b, self.x) = (b_own, x_own);
        stats
    }
}

impl LinearSolver for ConjugateGradient {
    fn analyze(&mut self, pattern: SymbolicSparseColMatRef<'_, usize>) -> Result<(), SolveError> {
        let blocks = BlockStructure::new(pattern)?;
        self.analyze_blocks(pattern, &blocks)
    }

    /// Keeps a copy of `blocks` for [`LinearSolver::solve`], which is not
    /// given the structure again.
    fn analyze_blocks(
        &mut self,
        pattern: SymbolicSparseColMatRef<'_, usize>,
        blocks: &BlockStructure,
    ) -> Result<(), SolveError> {
        if 3 * blocks.len() != pattern.nrows() || blocks.values_len() != pattern.row_idx().len() {
            return Err(SolveError::Analysis("the block structure is not the pattern's".into()));
        }
        self.analyze_structure(blocks)?;
        self.given.clone_from(blocks);
        Ok(())
    }

    /// The iteration reads the block structure alone, never the scalar
    /// rows; [`LinearSolver::solve_values`] is given the structure again,
    /// so no copy is kept.
    fn analyze_pattern(&mut self, pattern: SystemPattern<'_>) -> Result<(), SolveError> {
        self.given = BlockStructure::default();
        self.analyze_structure(pattern.blocks())
    }

    fn factor_values(&mut self, _pattern: SystemPattern<'_>, values: &[f64]) -> Result<(), SolveError> {
        self.take_values(values)
    }

    fn solve_values(
        &mut self,
        pattern: SystemPattern<'_>,
        values: &[f64],
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, SolveError> {
        self.solve_with(pattern.blocks(), values, b, x)
    }

    /// Takes note of new values: the next solve carries them into the
    /// solver's layout in the pass that takes its first residual (and the
    /// projection's products), and that solve reports a value that is not
    /// finite.
    fn factor(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError> {
        self.take_values(matrix.parts().1)
    }

    /// Mixed precision: the iteration's products read the values rounded
    /// to `f32` (half the memory traffic of this memory-bound loop), its
    /// vectors and sums stay `f64`. The residual it reports is `b - A x`
    /// with the `f64` values: when the iteration meets the tolerance on the
    /// rounded matrix but not on the exact one, it carries on from the
    /// exact residual (and on the way there, replaces the drifting
    /// recurrence by the exact residual in the same direction: a reliable
    /// update, Sleijpen and van der Vorst 1996), and should the exact
    /// residual not have halved since the last one (the rounded matrix too
    /// far from the exact one), it iterates on the `f64` values from
    /// there. The iteration runs in the
    /// solver's numbering of the blocks: `b` and the guess `x` are carried
    /// there, the solution back.
    fn solve(
        &mut self,
        matrix: SparseColMatRef<'_, usize, f64>,
        b: &[f64],
        x: &mut [f64],
    ) -> Result<SolveStats, SolveError> {
        let given = std::mem::take(&mut self.given);
        let solved = self.solve_with(&given, matrix.parts().1, b, x);
        self.given = given;
        solved
    }

    fn set_reference(&mut self, matrix: SparseColMatRef<'_, usize, f64>) -> Result<(), SolveError> {
        if let Some(rest) = self.rest.as_mut() {
            rest.cholesky.analyze(matrix.symbolic())?;
            rest.cholesky.factor(matrix)?;
            rest.ready = true;
        }
        Ok(())
    }

    fn wants_frames(&self) -> bool {
        self.rest.is_some()
    }

    /// The positions are kept for the next refresh of the coarse level
    /// (made again every few solves, see the solver's docs): a lagged level
    /// keeps the rigid motions it was made with, so that its factor stays
    /// the one of its own `Pᵀ A P`.
    fn set_positions(&mut self, positions: &[[f64; 3]]) {
        self.positions.clear();
        // (positions of another length are refused: the coarse level then
        // keeps translations alone)
        if self.coarse.is_some() && positions.len() == self.numbering.order().len() {
            self.positions.resize(positions.len(), [0.0; 3]);
            self.numbering.to_new(positions, &mut self.positions);
        }
    }

    fn set_frames(&mut self, frames: &[[f64; 9]]) {
        if let Some(rest) = self.rest.as_mut() {
            rest.frames.clear();
            rest.frames.extend_from_slice(frames);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::sparse::SymbolicSparseColMat;

    #[test]
    fn block_columns_given_directly_are_checked() {
        let (pattern, _) = chain(5, 1.0);
        let read = BlockStructure::new(pattern.as_ref()).unwrap();
        let nnz = pattern.row_idx().len();
        let parts = || (read.ptr.clone(), read.rows.clone(), read.start.clone());
        let (ptr, rows, start) = parts();
        assert_eq!(BlockStructure::from_columns(ptr, rows, start, nnz).unwrap(), read);
        // rows out of order, a row past the blocks, values that do not follow
        // one another, the wrong number of values, offsets that do not close
        let (ptr, mut rows, start) = parts();
        rows.swap(0, 1);
        assert!(BlockStructure::from_columns(ptr, rows, start, nnz).is_err());
        let (ptr, mut rows, start) = parts();
        *rows.last_mut().unwrap() = 5;
        assert!(BlockStructure::from_columns(ptr, rows, start, nnz).is_err());
        let (ptr, rows, mut start) = parts();
        start[2] += 1;
        assert!(BlockStructure::from_columns(ptr, rows, start, nnz).is_err());
        let (ptr, rows, start) = parts();
        assert!(BlockStructure::from_columns(ptr, rows, start, nnz + 9).is_err());
        let (mut ptr, rows, start) = parts();
        *ptr.last_mut().unwrap() -= 1;
        assert!(BlockStructure::from_columns(ptr, rows, start, nnz).is_err());
        // a solver given another pattern's structure refuses it
        let (other, _) = chain(4, 1.0);
        let mut cg = ConjugateGradient::new(1e-8, 100);
        assert!(cg.analyze_blocks(other.as_ref(), &read).is_err());
        assert!(cg.analyze_blocks(pattern.as_ref(), &read).is_ok());
    }

    /// A solve asked before any values were given since the analysis is
    /// refused; given them, it solves.
    #[test]
    fn a_solve_before_the_values_is_refused() {
        let (pattern, values) = chain(40, 1.0);
        let matrix = SparseColMatRef::new(pattern.as_ref(), &values);
        let (b, mut x) = (vec![1.0; pattern.nrows()], vec![0.0; pattern.nrows()]);
        let mut cg = ConjugateGradient::new(1e-8, 100);
        cg.analyze(pattern.as_ref()).unwrap();
        assert_eq!(cg.solve(matrix, &b, &mut x), Err(SolveError::NotReady));
        cg.factor(matrix).unwrap();
        assert!(cg.solve(matrix, &b, &mut x).is_ok());
        // (and again, after the analysis of the same pattern)
        cg.analyze(pattern.as_ref()).unwrap();
        assert_eq!(cg.solve(matrix, &b, &mut x), Err(SolveError::NotReady));
    }

    /// A symmetric positive definite chain of `n` 3x3 blocks in the layout
    /// of `assembly::SparsePattern` (each block column repeating its block
    /// rows in its three scalar columns): `scale` times a diagonally
    /// dominant matrix whose entries carry digits below `f32`'s precision.
    fn chain(n: usize, scale: f64) -> (SymbolicSparseColMat<usize>, Vec<f64>) {
        let entry = |i: usize, j: usize| -> f64 {
            let (a, b) = (i.min(j), i.max(j));
            if a == b {
                return scale * (8.0 + 1e-9 * a as f64);
            }
            scale * (-0.5 - 1e-9 * ((a * 31 + b * 17) % 13) as f64)
        };
        let (mut col_ptr, mut row_idx, mut values) = (vec![0usize], Vec::new(), Vec::new());
        for bj in 0..n {
            let rows: Vec<usize> = (bj.saturating_sub(1)..(bj + 2).min(n)).collect();
            for c in 0..3 {
                for &bi in &rows {
                    for r in 0..3 {
                        row_idx.push(3 * bi + r);
                        values.push(entry(3 * bi + r, 3 * bj + c));
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        (SymbolicSparseColMat::new_checked(3 * n, 3 * n, col_ptr, None, row_idx), values)
    }

    /// A bar of `nx x n x n` blocks coupled like springs to their six
    /// neighbours, `A = L ⊗ I + ε I` with `L` the lattice graph's
    /// Laplacian: its long waves have eigenvalues near `ε`, which block
    /// Jacobi resolves a few blocks per iteration.
    fn soft_bar(nx: usize, n: usize, epsilon: f64) -> (SymbolicSparseColMat<usize>, Vec<f64>) {
        let id = |x: usize, y: usize, z: usize| x + nx * (y + n * z);
        let (mut col_ptr, mut row_idx, mut values) = (vec![0usize], Vec::new(), Vec::new());
        for bj in 0..nx * n * n {
            let (x, y, z) = (bj % nx, (bj / nx) % n, bj / (nx * n));
            let mut rows = vec![bj];
            for (step, at, len) in [(x, 0, nx), (y, 1, n), (z, 2, n)] {
                let [a, b, c] = [x, y, z];
                if step > 0 {
                    rows.push(match at {
                        0 => id(a - 1, b, c),
                        1 => id(a, b - 1, c),
                        _ => id(a, b, c - 1),
                    });
                }
                if step + 1 < len {
                    rows.push(match at {
                        0 => id(a + 1, b, c),
                        1 => id(a, b + 1, c),
                        _ => id(a, b, c + 1),
                    });
                }
            }
            rows.sort_unstable();
            let degree = (rows.len() - 1) as f64;
            for c in 0..3 {
                for &bi in &rows {
                    for r in 0..3 {
                        row_idx.push(3 * bi + r);
                        let value = match (bi == bj, r == c) {
                            (_, false) => 0.0,
                            (true, true) => degree + epsilon,
                            (false, true) => -1.0,
                        };
                        values.push(value);
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let unknowns = 3 * nx * n * n;
        (SymbolicSparseColMat::new_checked(unknowns, unknowns, col_ptr, None, row_idx), values)
    }

    /// The coarse level must earn its place: on the soft bar it takes CG to
    /// the same residual in under half of block Jacobi's iterations (324
    /// against 133 when written, with the aggregates' translations alone).
    #[test]
    fn the_coarse_level_cuts_the_iterations_of_smooth_error() {
        let (pattern, values) = soft_bar(64, 4, 1e-4);
        let n = pattern.nrows();
        let b: Vec<f64> = (0..n).map(|i| 1.0 + (i as f64 * 0.01).sin()).collect();
        let iterations = |two_level| iterations_from_zero(&pattern, &values, &b, 1e-8, two_level);
        let (jacobi, two_level) = (iterations(false), iterations(true));
        println!("soft bar: block Jacobi {jacobi}, two-level {two_level} iterations");
        assert!(two_level * 2 < jacobi, "two-level {two_level} against block Jacobi {jacobi} iterations");
    }

    /// The coarse level's start: a right-hand side made by a rigid motion
    /// of the whole soft bar (a translation, which the aggregates'
    /// translations hold together), the long wave block Jacobi resolves
    /// slowest, is met at the start, before any iteration; without the
    /// coarse level it takes over a hundred. (The bar's values are exact
    /// in `f32`, so that the rounded products the iteration takes do not
    /// blur `b = A u`, which the near-null motion makes small.)
    #[test]
    fn a_motion_the_coarse_space_holds_is_solved_at_the_start() {
        let (pattern, values) = soft_bar(64, 4, 1.0 / 1024.0);
        let n = pattern.nrows();
        let matrix = SparseColMatRef::new(pattern.as_ref(), &values);
        let translation: Vec<f64> = (0..n).map(|i| [0.3, -0.2, 0.5][i % 3]).collect();
        let mut b = vec![0.0; n];
        symmetric_matvec(matrix, &translation, &mut b);
        let iterations = |two_level| iterations_from_zero(&pattern, &values, &b, 1e-6, two_level);
        let (jacobi, two_level) = (iterations(false), iterations(true));
        println!("a translation of the soft bar: block Jacobi {jacobi}, two-level {two_level} iterations");
        assert!(two_level <= 1 && jacobi > 50, "two-level {two_level}, block Jacobi {jacobi} iterations");
    }

    /// Each solve starts from the span of the corrections before it: a
    /// right-hand side whose solution is a combination of the last ones'
    /// (here `b₃ = 2 b₂ - b₁`, all solved from a zero guess, the first two
    /// more closely) is solved at the start, where a solver without that
    /// history iterates; a new pattern forgets it. (A uniform bar: on the
    /// soft one the error of the products on rounded values alone takes a
    /// few iterations to remove, 12 against 54 when written.) The same
    /// holds when the values are given again before every solve, and the
    /// pass that carries them makes the projection's products.
    #[test]
    fn a_solve_starts_from_the_corrections_before_it() {
        let (pattern, values) = soft_bar(48, 4, 1.0);
        let n = pattern.nrows();
        let matrix = SparseColMatRef::new(pattern.as_ref(), &values);
        let load = |phase: f64| -> Vec<f64> { (0..n).map(|i| (i as f64 * 0.013 + phase).sin()).collect() };
        // (b₂ close to a multiple of b₁: the projection of its solve pays,
        // so the history does not sit out the third)
        let (b1, b2) = (load(0.0), load(0.7));
        let b2: Vec<f64> = b1.iter().zip(&b2).map(|(b1, b2)| 1.5 * b1 + 0.01 * b2).collect();
        let b3: Vec<f64> = b1.iter().zip(&b2).map(|(b1, b2)| 2.0 * b2 - b1).collect();
        let solve = |cg: &mut ConjugateGradient, b: &[f64]| {
            let mut x = vec![0.0; n];
            let stats = cg.solve(matrix, b, &mut x).unwrap();
            assert!(residual(&pattern, &values, b, &x) <= 1e-6);
            stats.iterations
        };
        let ready = || {
            let mut cg = ConjugateGradient::new(1e-6, 5000);
            cg.analyze(pattern.as_ref()).unwrap();
            cg.factor(matrix).unwrap();
            cg
        };
        let mut cg = ready();
        // (the first two closer than the third needs: their combination
        // then meets its tolerance)
        cg.tolerance = 1e-10;
        let first = [solve(&mut cg, &b1), solve(&mut cg, &b2)];
        cg.tolerance = 1e-6;
        let with_history = solve(&mut cg, &b3);
        // the values given again before every solve, as a step gives them:
        // the projection takes the products and sums of the pass that
        // carries them (exact, so the start meets the tolerance as well)
        let mut refactored = ready();
        refactored.tolerance = 1e-10;
        for b in [&b1, &b2] {
            refactored.factor(matrix).unwrap();
            solve(&mut refactored, b);
        }
        refactored.tolerance = 1e-6;
        refactored.factor(matrix).unwrap();
        let carried = solve(&mut refactored, &b3);
        assert_eq!(carried, 0, "the history's start from the carrying pass's products");
        let fresh = solve(&mut ready(), &b3);
        cg.analyze(pattern.as_ref()).unwrap();
        cg.factor(matrix).unwrap();
        let forgotten = solve(&mut cg, &b3);
        println!("soft bar: {first:?}, then {with_history} iterations with the history, {fresh} without, {forgotten} after a new analysis");
        assert!(with_history == 0 && fresh > 10 && forgotten == fresh, "{with_history}, {fresh}, {forgotten}");
    }

    /// The coarse level is made again after [`COARSE_REFRESH`] solves, when
    /// a solve takes more than half again the iterations of the first
    /// after it, after a failed solve, after an analysis, and for each of
    /// the solves after one in which it outgrew.
    #[test]
    fn the_coarse_level_is_made_again_when_old_or_outgrown() {
        let mut age = CoarseAge::default();
        assert!(age.due(), "a new analysis");
        age.refreshed();
        for _ in 0..COARSE_REFRESH - 1 {
            age.solved(Some(20));
            assert!(!age.due(), "{age:?}");
        }
        age.solved(Some(20));
        assert!(age.due(), "served {COARSE_REFRESH} solves");
        age.refreshed();
        assert_eq!(age.outgrown(), None, "a fresh level serves the first solve whole");
        age.solved(Some(10));
        assert_eq!(age.outgrown(), Some(15 + LAG_SLACK));
        age.solved(Some(15 + LAG_SLACK));
        assert!(!age.due(), "{age:?}");
        age.solved(Some(16 + LAG_SLACK));
        assert!(age.due(), "{age:?}");
        age.refreshed();
        age.solved(None);
        assert!(age.due(), "a failed solve");
        // made again within a solve: each of the next solves starts on a
        // level of its own, then the level lags again
        age.refreshed();
        age.solved(Some(10));
        age.refreshed();
        age.outgrown_within();
        age.solved(Some(40));
        for solve in 0..COARSE_REFRESH {
            assert!(age.due(), "solve {solve} after the level outgrew: {age:?}");
            age.refreshed();
            age.solved(Some(20));
        }
        assert!(!age.due(), "lagging again: {age:?}");
    }

    /// A lagged coarse level serves a matrix it fits, and one made for a
    /// matrix far from the current one (a thousand times stiffer: more
    /// than any step's change) is made again in the middle of the solve
    /// once it has spent the iterations [`CoarseAge::outgrown`] allows:
    /// the solve meets its tolerance (checked apart from the solver) in
    /// about those iterations plus a fresh solver's.
    #[test]
    fn a_lagged_coarse_level_that_no_longer_fits_is_made_again_within_the_solve() {
        let (pattern, soft) = soft_bar(24, 4, 1e-3);
        let (_, stiff) = soft_bar(24, 4, 1.0);
        let n = pattern.nrows();
        let load = |phase: f64| -> Vec<f64> { (0..n).map(|i| (i as f64 * 0.37 + phase).sin()).collect() };
        let solve = |cg: &mut ConjugateGradient, values: &[f64], b: &[f64]| {
            let matrix = SparseColMatRef::new(pattern.as_ref(), values);
            cg.factor(matrix).unwrap();
            let mut x = vec![0.0; n];
            let stats = cg.solve(matrix, b, &mut x).unwrap();
            assert!(residual(&pattern, values, b, &x) <= 1e-8);
            stats.iterations
        };
        let mut cg = ConjugateGradient::new(1e-8, 5000).analysed(&pattern);
        let first = solve(&mut cg, &stiff, &load(0.0));
        let again = solve(&mut cg, &stiff, &load(1.0));
        assert_eq!(cg.coarse_age.solves, Some(2), "the level served a second solve of its matrix");
        let most = cg.coarse_age.outgrown().unwrap();
        let lagged = solve(&mut cg, &soft, &load(2.0));
        let fresh = solve(&mut ConjugateGradient::new(1e-8, 5000).analysed(&pattern), &soft, &load(2.0));
        println!("stiff bar {first} and {again} iterations; soft bar {lagged} on the stiff bar's coarse level (made again after {most}), {fresh} on its own");
        assert_eq!(cg.coarse_age.solves, Some(1), "made again within the soft bar's solve");
        assert!(lagged > most && lagged <= most + fresh + 2, "{lagged} iterations: {most} allowed, {fresh} fresh");
    }

    impl ConjugateGradient {
        /// The solver analysed for `pattern`.
        fn analysed(mut self, pattern: &SymbolicSparseColMat<usize>) -> Self {
            self.analyze(pattern.as_ref()).unwrap();
            self
        }
    }

    /// The iterations a new solver (with its coarse level or without) takes
    /// from a zero guess to the relative residual `tolerance`, which an
    /// independent check confirms.
    fn iterations_from_zero(
        pattern: &SymbolicSparseColMat<usize>,
        values: &[f64],
        b: &[f64],
        tolerance: f64,
        two_level: bool,
    ) -> usize {
        let matrix = SparseColMatRef::new(pattern.as_ref(), values);
        let mut cg = ConjugateGradient::new(tolerance, 5000);
        cg.analyze(pattern.as_ref()).unwrap();
        if !two_level {
            cg.coarse = None;
        }
        cg.factor(matrix).unwrap();
        let mut x = vec![0.0; b.len()];
        let stats = cg.solve(matrix, b, &mut x).unwrap();
        assert!(residual(pattern, values, b, &x) <= tolerance);
        stats.iterations
    }

    /// `|b - A x| / |b|` with the `f64` values, computed apart from the solver.
    fn residual(pattern: &SymbolicSparseColMat<usize>, values: &[f64], b: &[f64], x: &[f64]) -> f64 {
        let mut r = vec![0.0; b.len()];
        super::super::relative_residual(SparseColMatRef::new(pattern.as_ref(), values), b, x, &mut r)
    }

    /// The drift of the recurrence on the rounded values is replaced by the
    /// exact residual on the way (see [`ConjugateGradient::iterate`]): a
    /// solve far below what `f32` values resolve takes about the iterations
    /// of one on the `f64` values (81 against 75 when written), where a new
    /// round from the exact residual whenever the recurrence met the goal
    /// took nearly half again as many (108).
    #[test]
    fn a_rounded_solve_keeps_its_direction_through_the_drift() {
        let (pattern, values) = soft_bar(48, 3, 0.0123456789);
        let matrix = SparseColMatRef::new(pattern.as_ref(), &values);
        let n = pattern.nrows();
        let b: Vec<f64> = (0..n).map(|i| 1.0 + (i as f64 * 0.37).sin()).collect();
        let iterations = |rounded: bool| {
            let mut cg = ConjugateGradient::new(1e-11, 2000);
            cg.analyze(pattern.as_ref()).unwrap();
            cg.factor(matrix).unwrap();
            if !rounded {
                cg.rounded = false;
                cg.values.resize(values.len(), 0.0);
                cg.numbering.carry_exact(&values, &mut cg.values);
            }
            let mut x = vec![0.0; n];
            let stats = cg.solve(matrix, &b, &mut x).unwrap();
            assert!(residual(&pattern, &values, &b, &x) <= 1e-11);
            stats.iterations
        };
        let (rounded, exact) = (iterations(true), iterations(false));
        println!("rounded values {rounded}, exact values {exact} iterations");
        assert!(rounded * 10 <= exact * 11, "rounded values {rounded} against exact values {exact} iterations");
    }

    /// Where the rounded values cannot meet the tolerance (the bar's
    /// smallest eigenvalues, `ε = 3e-7` beside diagonals of 3 to 6, lose a
    /// tenth of themselves to `f32`), the solve goes on with products on the
    /// caller's `f64` values, through its own numbering and back, and meets
    /// it; the solver keeps no `f64` copy of its own.
    #[test]
    fn where_the_rounded_values_stall_the_callers_values_finish() {
        let (pattern, values) = soft_bar(16, 2, 3e-7);
        let matrix = SparseColMatRef::new(pattern.as_ref(), &values);
        let n = pattern.nrows();
        let b: Vec<f64> = (0..n).map(|i| 1.0 + (i as f64 * 0.37).sin()).collect();
        let mut cg = ConjugateGradient::new(3e-9, 2000);
        cg.analyze(pattern.as_ref()).unwrap();
        cg.factor(matrix).unwrap();
        let mut x = vec![0.0; n];
        let stats = cg.solve(matrix, &b, &mut x).unwrap();
        let exact = residual(&pattern, &values, &b, &x);
        assert!(exact <= 3e-9, "exact residual {exact:e}");
        // (a residual 3e-9 of `b` on a matrix of condition 4e7: the two
        // sums, in different orders, agree to two or three digits, 6e-4
        // to 2.2e-3 of it as the preconditioner changed; the recurrence on
        // the rounded values, which this tells apart from the exact
        // residual, drifts from it by about ROUNDED_DRIFT of `b`, thousands
        // of times this residual)
        assert!((stats.residual - exact).abs() <= 1e-2 * exact, "reported {:e}, exact {exact:e}", stats.residual);
        assert!(cg.rounded && cg.values.is_empty(), "no f64 copy for a matrix within f32's range");
    }

    /// A matrix positive on smooth vectors but indefinite on oscillating
    /// ones (the chain's couplings `+10` instead of `-0.5`, against a
    /// diagonal of 8): the block and coarse factors exist, the iteration
    /// meets the negative curvature and says so.
    #[test]
    fn an_indefinite_matrix_ends_in_its_curvature() {
        let (pattern, mut values) = chain(40, 1.0);
        let (col_ptr, row_idx) = (pattern.col_ptr(), pattern.row_idx());
        for c in 0..pattern.ncols() {
            for at in col_ptr[c]..col_ptr[c + 1] {
                if row_idx[at] / 3 != c / 3 {
                    values[at] *= -20.0;
                }
            }
        }
        let b: Vec<f64> = (0..120).map(|i| (i as f64 * 2.1).sin()).collect();
        let mut cg = ConjugateGradient::new(1e-10, 500);
        cg.analyze(pattern.as_ref()).unwrap();
        let matrix = SparseColMatRef::new(pattern.as_ref(), &values);
        cg.factor(matrix).unwrap();
        let mut x = vec![0.0; 120];
        match cg.solve(matrix, &b, &mut x) {
            Err(SolveError::NonPositiveCurvature { iteration, curvature }) => {
                assert!(iteration < 500 && curvature <= 0.0, "iteration {iteration}, curvature {curvature:e}");
            }
            other => panic!("an indefinite matrix gave {other:?}"),
        }
    }

    /// The iteration reads `f32` values, but the residual it reports and
    /// meets is the `f64` one: at a tolerance below what the rounded matrix
    /// can reach (its entries differ from the exact ones at 1e-8), it must
    /// refine; and a matrix beyond `f32`'s range is iterated on its `f64`
    /// values.
    #[test]
    fn the_reported_residual_is_the_exact_one() {
        for scale in [1.0, 1e40] {
            let (pattern, values) = chain(40, scale);
            let b: Vec<f64> = (0..120).map(|i| scale * (i as f64 * 0.37).sin()).collect();
            let mut cg = ConjugateGradient::new(1e-13, 500);
            cg.analyze(pattern.as_ref()).unwrap();
            let matrix = SparseColMatRef::new(pattern.as_ref(), &values);
            cg.factor(matrix).unwrap();
            let mut x = vec![0.0; 120];
            let stats = cg.solve(matrix, &b, &mut x).unwrap();
            assert_eq!(cg.rounded, scale == 1.0, "scale {scale}: whether the f32 values are usable");
            let exact = residual(&pattern, &values, &b, &x);
            assert!(exact <= 1e-13, "scale {scale}: exact residual {exact:e} above the tolerance");
            assert!(
                (stats.residual - exact).abs() <= 1e-15,
                "scale {scale}: reported {:e}, exact {exact:e}",
                stats.residual
            );
        }
    }
}
