//! The start of an iterative solve from the corrections of the solves
//! before it (the projection of Fischer 1998, "Projection techniques for
//! iterative solution of Ax = b with successive right-hand sides").
//!
//! A step's system changes little from one step to the next, and so does
//! what its solve adds to the caller's guess: the best start in the span
//! of the last few such corrections `V = [v_1 … v_s]` takes much of the
//! next one's error away before the first iteration. With `r = b - A x`
//! the residual of the guess, the correction `V y` with `(Vᵀ A V) y = Vᵀ
//! r` makes the new error the smallest in the energy norm over `x + span
//! V` (so never larger than the guess's own). The corrections are stored
//! interleaved, so that one read of the matrix makes all their products
//! ([`block_products_of_vectors`]), and two passes over them do the rest
//! (or one, [`SolutionHistory::project_summed`], when a pass over the
//! matrix that has other work made the products and their sums); the
//! matrix is the current one, so nothing is assumed of how it changed. A
//! correction whose part energy-orthogonal to the older ones is below
//! [`DEPENDENT`] of its own energy adds nothing and is left out of the
//! solve.
//!
//! Where the history does not predict the next correction (a body
//! bouncing on penalty contacts, whose active set changes from step to
//! step), its products are wasted: once the history is full, a projection
//! that leaves more than [`WORTH`] of the residual makes it sit out the
//! next solve, then two, four, up to [`MOST_SKIPPED`], until one pays
//! again (the corrections are still kept meanwhile).
//!
//! Every sum runs over fixed chunks and the chunk sums in order, so the
//! start has the same bits on any number of threads; the buffers are sized
//! with the unknowns, so a solve allocates nothing.

use cleave_kernels::spmv::VECTORS;
use rayon::prelude::*;

#[cfg(doc)]
use cleave_kernels::spmv::block_products_of_vectors;

/// The most corrections a history keeps: as many as one product takes.
pub(super) const MOST_KEPT: usize = VECTORS;

/// A projection pays when it leaves at most this fraction of the
/// residual's norm: its products and passes cost about as much as two
/// iterations, and ten times smaller a residual saves some fifteen of a
/// deforming bunny_100k's. (Bouncing on the floor, its projections mostly
/// left half of the residual or more, and the steps took 60.7 iterations
/// projecting every time against 61.5 without.)
pub(super) const WORTH: f64 = 0.1;

/// The most solves a history sits out after a projection that did not pay.
const MOST_SKIPPED: usize = 8;

/// Values per chunk of the fused passes.
const CHUNK: usize = 4096;

/// A correction is left out of the solve when the square of its part
/// energy-orthogonal to the older ones is at most this fraction of its
/// energy `vᵀ A v`.
const DEPENDENT: f64 = 1e-10;

/// The last corrections of a solver's solves, kept until its unknowns
/// change.
#[derive(Default)]
pub(super) struct SolutionHistory {
    /// The most corrections kept (at most [`MOST_KEPT`]).
    capacity: usize,
    /// The corrections, interleaved: entry `i` of the one in slot `k` at
    /// `[MOST_KEPT * i + k]`; slots `0..len` hold corrections (the oldest
    /// at `next` once all are full), the others finite values that are
    /// never read (zeros, or a former topology's corrections).
    corrections: Vec<f64>,
    len: usize,
    next: usize,
    /// `A v` of each slot for the current matrix, interleaved the same
    /// way, made by each projection.
    products: Vec<f64>,
    /// The guess the current solve started from.
    start: Vec<f64>,
    /// Per-chunk sums of `Vᵀ A V` and `Vᵀ r`.
    partial: Vec<ProjectionSums>,
    /// Solves left to sit out, and how many the next failure sits out.
    skipped: usize,
    backoff: usize,
}

/// Entries of the lower triangle of `Vᵀ A V` and of `Vᵀ r` for `s` corrections.
const fn sums_len(s: usize) -> usize {
    s * (s + 1) / 2 + s
}

/// The sums a projection solves with, slot by slot: `Vᵀ A V` (every pair)
/// and `Vᵀ r`.
#[derive(Clone, Copy, Debug)]
pub(super) struct ProjectionSums {
    gram: [f64; MOST_KEPT * MOST_KEPT],
    projected: [f64; MOST_KEPT],
}

impl Default for ProjectionSums {
    fn default() -> Self {
        ProjectionSums { gram: [0.0; MOST_KEPT * MOST_KEPT], projected: [0.0; MOST_KEPT] }
    }
}

impl ProjectionSums {
    /// The sums over the unknowns whose corrections are `v`, their products
    /// `a_v` (both interleaved) and residuals `r`, in one pass over them in
    /// order.
    pub fn of(v: &[f64], a_v: &[f64], r: &[f64]) -> Self {
        let mut sums = ProjectionSums::default();
        let rows = v.chunks_exact(MOST_KEPT).zip(a_v.chunks_exact(MOST_KEPT));
        for ((v, a_v), r) in rows.zip(r) {
            for (i, gram) in sums.gram.chunks_exact_mut(MOST_KEPT).enumerate() {
                gram.iter_mut().zip(a_v).for_each(|(g, a_v)| *g += v[i] * a_v);
                sums.projected[i] += v[i] * r;
            }
        }
        sums
    }

    /// The sums of two sets of unknowns.
    pub fn plus(mut self, other: Self) -> Self {
        self.gram.iter_mut().zip(other.gram).for_each(|(a, b)| *a += b);
        self.projected.iter_mut().zip(other.projected).for_each(|(a, b)| *a += b);
        self
    }
}

impl SolutionHistory {
    /// A history keeping up to `capacity` corrections (at most
    /// [`MOST_KEPT`]; none: no projection).
    pub fn new(capacity: usize) -> Self {
        SolutionHistory { capacity: capacity.min(MOST_KEPT), ..Default::default() }
    }

    /// Forgets every correction and sizes the buffers for `n` unknowns
    /// (reusing their storage, whose stale values are never read: a slot is
    /// written by [`SolutionHistory::record`] before it counts, and every
    /// product by the projection that reads it; not clearing them saves
    /// writing 2 x 8 values per unknown on every cut, 1 ms on bunny_100k).
    pub fn resize(&mut self, n: usize) {
        (self.len, self.next, self.skipped, self.backoff) = (0, 0, 0, 0);
        for buffer in [&mut self.corrections, &mut self.products] {
            crate::resize_with_room(buffer, MOST_KEPT * n, 0.0);
        }
        crate::resize_with_room(&mut self.start, n, 0.0);
        self.partial.resize(n.div_ceil(CHUNK), ProjectionSums::default());
    }

    /// Notes the guess `x` a solve starts from.
    pub fn begin(&mut self, x: &[f64]) {
        if self.capacity > 0 && x.len() == self.start.len() {
            self.start.copy_from_slice(x);
        }
    }

    /// Keeps the correction from the guess noted by [`begin`] to the
    /// solution `x`, in place of the oldest when full.
    ///
    /// [`begin`]: SolutionHistory::begin
    pub fn record(&mut self, x: &[f64]) {
        if self.capacity == 0 || x.len() != self.start.len() {
            return;
        }
        let slot = match self.len < self.capacity {
            true => self.len,
            false => self.next,
        };
        let kept = self.corrections.par_chunks_mut(MOST_KEPT * CHUNK).zip(x.par_chunks(CHUNK));
        kept.zip(self.start.par_chunks(CHUNK)).for_each(|((v, x), start)| {
            v.chunks_exact_mut(MOST_KEPT).zip(x).zip(start).for_each(|((v, x), s)| v[slot] = x - s);
        });
        if self.len < self.capacity {
            self.len += 1;
        } else {
            self.next = (self.next + 1) % self.capacity;
        }
    }

    /// Whether this solve should project (counts a solve sat out).
    pub fn wanted(&mut self) -> bool {
        if self.skipped > 0 {
            self.skipped -= 1;
            return false;
        }
        self.len > 0
    }

    /// Whether the next solve projects, unless its guess already meets
    /// the goal (what [`SolutionHistory::wanted`] then answers).
    pub fn would_project(&self) -> bool {
        self.skipped == 0 && self.len > 0
    }

    /// The corrections and the buffer of their products, interleaved, for
    /// the products to be made by a pass over the matrix that has other
    /// work (which sums them for [`SolutionHistory::project_summed`]).
    pub fn products_to_make(&mut self) -> (&[f64], &mut [f64]) {
        (&self.corrections, &mut self.products)
    }

    /// Takes note of how much of the residual's norm a projection left (a
    /// history not yet full is not judged: its newest corrections are the
    /// ones that predict).
    pub fn judge(&mut self, left: f64) {
        if self.len < self.capacity {
            return;
        }
        if left <= WORTH {
            self.backoff = 0;
        } else {
            self.backoff = (2 * self.backoff).clamp(1, MOST_SKIPPED);
            self.skipped = self.backoff;
        }
    }

    /// Adds to `x` the correction `V y` of the module docs and takes `A V y`
    /// from the residual `r` of `x`; `products(v, a_v)` writes `A v` of
    /// every slot of the interleaved `v` into `a_v`, interleaved the same
    /// way. Returns whether it did (not without corrections of `x`'s
    /// length, nor when none has energy or the correction is not finite).
    pub fn project(&mut self, products: impl FnOnce(&[f64], &mut [f64]), x: &mut [f64], r: &mut [f64]) -> bool {
        if self.len == 0 || x.len() != self.start.len() || r.len() != x.len() {
            return false;
        }
        products(&self.corrections, &mut self.products);
        // every v_i · (A v_j) and v_i · r per chunk of unknowns, in one pass
        // over its rows, the chunks' sums then in order
        let (corrections, products) = (&self.corrections, &self.products);
        let chunks = r.len().div_ceil(CHUNK);
        self.partial[..chunks].par_iter_mut().enumerate().for_each(|(c, sums)| {
            let range = c * CHUNK..(c * CHUNK + CHUNK).min(r.len());
            let interleaved = MOST_KEPT * range.start..MOST_KEPT * range.end;
            *sums = ProjectionSums::of(&corrections[interleaved.clone()], &products[interleaved], &r[range]);
        });
        let sums = self.partial[..chunks].iter().fold(ProjectionSums::default(), |a, &b| a.plus(b));
        self.project_summed(&sums, x, r)
    }

    /// [`SolutionHistory::project`] with the products of the corrections
    /// made by the caller (into the buffer of
    /// [`SolutionHistory::products_to_make`]) and summed into `sums`
    /// (`r` the residual they were summed with).
    pub fn project_summed(&mut self, sums: &ProjectionSums, x: &mut [f64], r: &mut [f64]) -> bool {
        let s = self.len;
        if s == 0 || x.len() != self.start.len() || r.len() != x.len() {
            return false;
        }
        // the slots oldest first
        let order: [usize; MOST_KEPT] = std::array::from_fn(|k| (self.next + k) % s);
        let Some(y) = coefficients(&order[..s], sums) else { return false };
        // the coefficient of each slot
        let mut by_slot = [0.0; MOST_KEPT];
        order[..s].iter().zip(&y).for_each(|(&slot, &y)| by_slot[slot] = y);
        let (corrections, products) = (&self.corrections, &self.products);
        let vectors = corrections.par_chunks(MOST_KEPT * CHUNK).zip(products.par_chunks(MOST_KEPT * CHUNK));
        x.par_chunks_mut(CHUNK).zip(r.par_chunks_mut(CHUNK)).zip(vectors).for_each(|((x, r), (v, a_v))| {
            let rows = v.chunks_exact(MOST_KEPT).zip(a_v.chunks_exact(MOST_KEPT));
            for ((x, r), (v, a_v)) in x.iter_mut().zip(r.iter_mut()).zip(rows) {
                for k in 0..s {
                    *x += by_slot[k] * v[k];
                    *r -= by_slot[k] * a_v[k];
                }
            }
        });
        true
    }
}

/// The solution `y` of `(Vᵀ A V) y = Vᵀ r` for the corrections in `order`
/// (of the sums by slot `sums`), by a Cholesky factorisation that leaves
/// out (`y_k = 0`) each correction the module docs call dependent; `None`
/// when all are, or `y` is not finite.
fn coefficients(order: &[usize], sums: &ProjectionSums) -> Option<[f64; MOST_KEPT]> {
    let s = order.len();
    let width = sums_len(s);
    // the lower triangle of the slots in order, row by row, then Vᵀ r
    let mut total = [0.0f64; sums_len(MOST_KEPT)];
    let mut at = 0;
    for (k, &i) in order.iter().enumerate() {
        for &j in &order[..=k] {
            total[at] = sums.gram[MOST_KEPT * i + j];
            at += 1;
        }
    }
    for (k, &i) in order.iter().enumerate() {
        total[at + k] = sums.projected[i];
    }
    // the lower triangle of Vᵀ A V, factored in place: row k's entries
    // at k (k + 1) / 2 ..
    let at = |k: usize, j: usize| k * (k + 1) / 2 + j;
    let (mut l, rhs) = (total, &total[s * (s + 1) / 2..width]);
    let mut kept = [false; MOST_KEPT];
    for k in 0..s {
        let energy = total[at(k, k)];
        for j in 0..k {
            let sum: f64 = (0..j).filter(|&q| kept[q]).map(|q| l[at(k, q)] * l[at(j, q)]).sum();
            l[at(k, j)] = if kept[j] { (l[at(k, j)] - sum) / l[at(j, j)] } else { 0.0 };
        }
        let pivot = energy - (0..k).filter(|&q| kept[q]).map(|q| l[at(k, q)] * l[at(k, q)]).sum::<f64>();
        kept[k] = energy > 0.0 && pivot > DEPENDENT * energy;
        l[at(k, k)] = if kept[k] { pivot.sqrt() } else { 0.0 };
    }
    if !kept.iter().any(|&k| k) {
        return None;
    }
    // L z = Vᵀ r, then Lᵀ y = z, over the kept corrections
    let mut y = [0.0f64; MOST_KEPT];
    for k in (0..s).filter(|&k| kept[k]) {
        let sum: f64 = (0..k).filter(|&q| kept[q]).map(|q| l[at(k, q)] * y[q]).sum();
        y[k] = (rhs[k] - sum) / l[at(k, k)];
    }
    for k in (0..s).rev().filter(|&k| kept[k]) {
        let sum: f64 = (k + 1..s).filter(|&q| kept[q]).map(|q| l[at(q, k)] * y[q]).sum();
        y[k] = (y[k] - sum) / l[at(k, k)];
    }
    y.iter().all(|y| y.is_finite()).then_some(y)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The diagonal matrix `diag(1, 2, …, n)` as a product.
    fn diagonal(v: &[f64], a_v: &mut [f64]) {
        a_v.iter_mut().zip(v).enumerate().for_each(|(i, (y, x))| *y = (i + 1) as f64 * x);
    }

    /// [`diagonal`] of every slot of interleaved vectors.
    fn diagonal_of_slots(v: &[f64], a_v: &mut [f64]) {
        for (i, (y, x)) in a_v.chunks_exact_mut(MOST_KEPT).zip(v.chunks_exact(MOST_KEPT)).enumerate() {
            y.iter_mut().zip(x).for_each(|(y, x)| *y = (i + 1) as f64 * x);
        }
    }

    /// A history of `capacity` for `n` unknowns holding the corrections
    /// `kept` (each recorded from a zero guess).
    fn history_of(capacity: usize, n: usize, kept: &[Vec<f64>]) -> SolutionHistory {
        let mut history = SolutionHistory::new(capacity);
        history.resize(n);
        for v in kept {
            history.begin(&vec![0.0; n]);
            history.record(v);
        }
        history
    }

    /// `n` values of a smooth function, the `k`-th of a family.
    fn wave(n: usize, k: usize) -> Vec<f64> {
        (0..n).map(|i| ((i * (k + 2)) as f64 * 0.01).sin() + 0.1 * k as f64).collect()
    }

    #[test]
    fn a_solution_in_the_span_of_the_history_is_found_at_once() {
        let n = 10_000;
        let kept: Vec<Vec<f64>> = (0..3).map(|k| wave(n, k)).collect();
        let mut history = history_of(3, n, &kept);
        // b = A (0.5 v0 - 2 v2), from x = 0: r = b
        let solution: Vec<f64> = (0..n).map(|i| 0.5 * kept[0][i] - 2.0 * kept[2][i]).collect();
        let mut r = vec![0.0; n];
        diagonal(&solution, &mut r);
        let mut x = vec![0.0; n];
        assert!(history.project(diagonal_of_slots, &mut x, &mut r));
        let error = x.iter().zip(&solution).map(|(x, s)| (x - s).abs()).fold(0.0, f64::max);
        let residual = r.iter().map(|r| r.abs()).fold(0.0, f64::max);
        assert!(error < 1e-10 && residual < 1e-8, "error {error:e}, residual {residual:e}");
    }

    #[test]
    fn the_correction_from_the_guess_is_kept() {
        let n = 2000;
        let mut history = history_of(2, n, &[]);
        let guess = wave(n, 1);
        let solution: Vec<f64> = guess.iter().zip(wave(n, 4)).map(|(g, w)| g + 3.0 * w).collect();
        history.begin(&guess);
        history.record(&solution);
        assert_eq!(history.len, 1);
        let kept = history.corrections.iter().step_by(MOST_KEPT);
        let error = kept.zip(wave(n, 4)).map(|(v, w)| (v - 3.0 * w).abs()).fold(0.0, f64::max);
        assert!(error < 1e-14, "error {error:e}");
    }

    #[test]
    fn dependent_corrections_and_a_full_history_are_handled() {
        let n = 5000;
        let v = wave(n, 5);
        // the same correction three times: the oldest is overwritten, and
        // the two kept span one direction
        let mut history = history_of(2, n, &[v.clone(), v.clone(), v.clone()]);
        assert_eq!((history.len, history.next), (2, 1));
        let mut r = vec![0.0; n];
        diagonal(&v, &mut r);
        r.iter_mut().for_each(|r| *r *= 3.0);
        let mut x = vec![0.0; n];
        assert!(history.project(diagonal_of_slots, &mut x, &mut r));
        let error = x.iter().zip(&v).map(|(x, v)| (x - 3.0 * v).abs()).fold(0.0, f64::max);
        assert!(error < 1e-9, "error {error:e}");
        // unknowns of another length: no projection, nothing touched
        let (mut short_x, mut short_r) = (vec![1.0; 10], vec![2.0; 10]);
        assert!(!history.project(diagonal_of_slots, &mut short_x, &mut short_r));
        assert_eq!((short_x, short_r), (vec![1.0; 10], vec![2.0; 10]));
        // a matrix with no energy along the history: no projection
        let mut x = vec![0.0; n];
        assert!(!history.project(|_, a_v| a_v.fill(0.0), &mut x, &mut r));
        // resized for other unknowns: nothing kept
        history.resize(n + 1);
        let (mut x, mut r) = (vec![0.0; n + 1], vec![1.0; n + 1]);
        assert!(!history.project(diagonal_of_slots, &mut x, &mut r));
    }

    #[test]
    fn a_history_that_does_not_pay_sits_out_more_and_more_solves() {
        let n = 100;
        let mut history = history_of(2, n, &[wave(n, 1)]);
        history.judge(0.5);
        assert!(history.wanted(), "a history not yet full is not judged");
        history.record(&wave(n, 2));
        let mut pattern = Vec::new();
        for left in [0.5, 0.5, 0.5, 0.01, 0.5] {
            while !history.wanted() {
                pattern.push(false);
            }
            pattern.push(true);
            history.judge(left);
        }
        let sat_out: Vec<usize> = pattern.split(|&p| p).map(|run| run.len()).collect();
        assert_eq!(sat_out, [0, 1, 2, 4, 0, 0], "{pattern:?}");
        // eight at most
        (0..6).for_each(|_| history.judge(0.5));
        assert_eq!(history.skipped, MOST_SKIPPED);
        history.resize(n);
        assert!(!history.wanted(), "an empty history projects nothing");
        assert_eq!(history.skipped, 0);
    }

    #[test]
    fn the_projection_leaves_a_residual_orthogonal_to_the_history() {
        // with a history that cannot hold the solution, the corrected error
        // has no smaller energy along any kept direction (the Galerkin
        // condition: the new residual is orthogonal to every correction)
        let n = 3000;
        let kept: Vec<Vec<f64>> = (0..4).map(|k| wave(n, 3 * k)).collect();
        let mut history = history_of(4, n, &kept);
        let solution: Vec<f64> = (0..n).map(|i| (i as f64 * 0.011).cos()).collect();
        let mut r = vec![0.0; n];
        diagonal(&solution, &mut r);
        let norm_before: f64 = r.iter().map(|r| r * r).sum::<f64>().sqrt();
        let mut x = vec![0.0; n];
        assert!(history.project(diagonal_of_slots, &mut x, &mut r));
        for v in &kept {
            let along: f64 = v.iter().zip(&r).map(|(v, r)| v * r).sum();
            let scale = norm_before * v.iter().map(|v| v * v).sum::<f64>().sqrt();
            assert!(along.abs() < 1e-10 * scale, "v · r = {along:e} against {scale:e}");
        }
    }
}
