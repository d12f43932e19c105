//! The triangular solves of a supernodal Cholesky factor `A = L Lᵀ`
//! (`L y = b`, then `Lᵀ x = y`, in the factor's permuted order), run in
//! parallel over independent subtrees of the supernodal elimination tree,
//! with the same bits on any number of threads.
//!
//! faer numbers the supernodes in a topological order of the elimination
//! tree (a child before its parent), and the rows below a supernode are
//! columns of its ancestors. The analysis cuts the tree into tasks, sets
//! of whole subtrees holding at most `1 / TASKS` of the factor's values
//! each, and the supernodes above them (the top separators of the nested
//! dissection), whose dense columns are solved in panels, each panel's
//! product split over the threads in fixed chunks:
//!
//! - forward, every task solves a copy of its own columns and sums what it
//!   subtracts from its ancestors' rows (all in the top) in a buffer of its
//!   own; the copies are written back and the buffers subtracted in task
//!   order, then the top supernodes are solved in order;
//! - backward, the top supernodes are solved first (in reverse order), then
//!   every task reads its ancestors' values into its buffer and solves a
//!   copy of its own columns, written back in task order.
//!
//! The tasks and chunks depend on the factor's structure alone, never on
//! the threads.

use cleave_kernels::lanes::clear_upper_registers;
use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve::{solve_lower_triangular_in_place, solve_upper_triangular_in_place};
use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;
use faer::{Accum, MatMut, MatRef, Par};
use rayon::prelude::*;

/// A task holds at most this fraction of the factor's values (`1 / TASKS`):
/// enough tasks to balance two to eight threads, few enough that the top
/// supernodes above them stay a small share of the work.
const TASKS: usize = 32;

/// The smallest factor (stored values) solved by tasks. Measured on boxes
/// of tetrahedra plus a diagonal (AMD EPYC, 2 threads, against faer's
/// sequential solve): a factor of 0.32M values solved in 194 µs against
/// 142, 1.6M in 553–693 µs against 599–610, 3.1M in 1.28 ms against 1.77,
/// 5.3M in 2.7–3.2 ms against 4.8–4.9, bunny_100k's 33M in 16.5 ms
/// against 28.
pub(super) const MIN_VALUES: usize = 1 << 21;

/// Flags a row's place in a task's boundary (else it is the row's place
/// in the task's copy of its columns).
const BOUNDARY: u32 = 1 << 31;

/// The task partition of one factor's structure and the buffers of its
/// solves.
pub(super) struct TreeSolve {
    tasks: Vec<Task>,
    /// Supernodes outside every task, ascending.
    top: Vec<usize>,
    /// Where each row index of a task's supernode lives (aligned with the
    /// factor's row indices; see [`BOUNDARY`]); unused for the top.
    place: Vec<u32>,
    /// Where each supernode's first column lives in its task's copy
    /// (unused for the top).
    local_start: Vec<u32>,
    /// A top supernode's rows: its columns' values, then those of its rows
    /// below.
    column: Vec<f64>,
}

/// Whole subtrees, solved by one thread.
struct Task {
    /// Ascending (children before parents).
    supernodes: Vec<usize>,
    /// The values of the supernodes' columns, in that order.
    x: Vec<f64>,
    /// The rows outside the task that its supernodes reach, ascending.
    boundary: Vec<usize>,
    /// Forward: the sums subtracted from the boundary rows; backward: the
    /// boundary rows' values.
    values: Vec<f64>,
    /// One supernode's `L_bot x_top` (forward) or gathered rows (backward),
    /// as long as the task's longest pattern.
    products: Vec<f64>,
}

/// Supernode `s` of a factor: its columns and its rows below them.
struct Supernode<'a> {
    columns: std::ops::Range<usize>,
    pattern: &'a [usize],
    /// Index of its first row in the factor's row indices.
    first_row: usize,
    /// Column-major, `columns.len() + pattern.len()` rows.
    values: MatRef<'a, f64>,
}

fn supernode<'a>(symbolic: &'a SymbolicSupernodalCholesky<usize>, values: &'a [f64], s: usize) -> Supernode<'a> {
    let columns = symbolic.supernode_begin()[s]..symbolic.supernode_end()[s];
    let rows = symbolic.col_ptr_for_row_idx()[s]..symbolic.col_ptr_for_row_idx()[s + 1];
    let pattern = &symbolic.row_idx()[rows.clone()];
    let stored = &values[symbolic.col_ptr_for_val()[s]..symbolic.col_ptr_for_val()[s + 1]];
    let values = MatRef::from_column_major_slice(stored, columns.len() + pattern.len(), columns.len());
    Supernode { columns, pattern, first_row: rows.start, values }
}

impl TreeSolve {
    /// The tasks of `symbolic`'s elimination tree, or `None` for a factor
    /// of fewer than [`MIN_VALUES`] values (or too many columns for
    /// [`BOUNDARY`]).
    pub fn new(symbolic: &SymbolicSupernodalCholesky<usize>) -> Option<Self> {
        (symbolic.len_val() >= MIN_VALUES).then(|| Self::partition(symbolic)).flatten()
    }

    /// The tasks of `symbolic`'s elimination tree whatever its size, or
    /// `None` when it has too many columns for [`BOUNDARY`].
    pub fn partition(symbolic: &SymbolicSupernodalCholesky<usize>) -> Option<Self> {
        if symbolic.nrows() >= BOUNDARY as usize {
            return None;
        }
        let count = symbolic.n_supernodes();
        let (begin, end) = (symbolic.supernode_begin(), symbolic.supernode_end());
        let row_ptr = symbolic.col_ptr_for_row_idx();
        let rows = symbolic.row_idx();
        // the supernode of every column, and every supernode's parent: the
        // supernode of its first row below its columns
        let mut of_column = vec![0usize; symbolic.nrows()];
        for s in 0..count {
            of_column[begin[s]..end[s]].fill(s);
        }
        let parent: Vec<Option<usize>> =
            (0..count).map(|s| rows[row_ptr[s]..row_ptr[s + 1]].first().map(|&r| of_column[r])).collect();
        // values per subtree (children come before their parent)
        let own = |s: usize| (end[s] - begin[s]) * (end[s] - begin[s] + row_ptr[s + 1] - row_ptr[s]);
        let mut work: Vec<usize> = (0..count).map(own).collect();
        for s in 0..count {
            if let Some(p) = parent[s] {
                work[p] += work[s];
            }
        }
        let total: usize = (0..count).filter(|&s| parent[s].is_none()).map(|s| work[s]).sum();
        let limit = total.div_ceil(TASKS).max(1);
        // a supernode is in the top when its subtree exceeds the limit; the
        // subtrees right under the top, by root, are merged into tasks
        // while the sum stays within the limit
        let in_top: Vec<bool> = work.iter().map(|&w| w > limit).collect();
        let top: Vec<usize> = (0..count).filter(|&s| in_top[s]).collect();
        let mut task_of = vec![u32::MAX; count];
        let mut sums: Vec<usize> = Vec::new();
        for root in (0..count).filter(|&s| !in_top[s] && parent[s].is_none_or(|p| in_top[p])) {
            match sums.last_mut() {
                Some(sum) if *sum + work[root] <= limit => *sum += work[root],
                _ => sums.push(work[root]),
            }
            task_of[root] = (sums.len() - 1) as u32;
        }
        // (parents come after their children: the task of a supernode is
        // its root's, found from the root down)
        for s in (0..count).rev() {
            if let Some(p) = parent[s].filter(|_| task_of[s] == u32::MAX && !in_top[s]) {
                task_of[s] = task_of[p];
            }
        }
        let mut members = vec![Vec::new(); sums.len()];
        (0..count).filter(|&s| !in_top[s]).for_each(|s| members[task_of[s] as usize].push(s));
        let (mut place, mut local_start) = (vec![0u32; rows.len()], vec![0u32; count]);
        let tasks = members
            .into_iter()
            .enumerate()
            .map(|(id, supernodes)| {
                let mut width = 0;
                for &s in &supernodes {
                    local_start[s] = width as u32;
                    width += end[s] - begin[s];
                }
                let mine = |r: usize| task_of[of_column[r]] == id as u32;
                let mut boundary: Vec<usize> = supernodes
                    .iter()
                    .flat_map(|&s| &rows[row_ptr[s]..row_ptr[s + 1]])
                    .copied()
                    .filter(|&r| !mine(r))
                    .collect();
                boundary.sort_unstable();
                boundary.dedup();
                for &s in &supernodes {
                    for (place, &r) in
                        place[row_ptr[s]..row_ptr[s + 1]].iter_mut().zip(&rows[row_ptr[s]..row_ptr[s + 1]])
                    {
                        *place = if mine(r) {
                            local_start[of_column[r]] + (r - begin[of_column[r]]) as u32
                        } else {
                            BOUNDARY | boundary.binary_search(&r).expect("listed above") as u32
                        };
                    }
                }
                let longest = supernodes.iter().map(|&s| row_ptr[s + 1] - row_ptr[s]).max().unwrap_or(0);
                let values = vec![0.0; boundary.len()];
                Task { supernodes, x: vec![0.0; width], boundary, values, products: vec![0.0; longest] }
            })
            .collect();
        Some(TreeSolve { tasks, top, place, local_start, column: Vec::new() })
    }

    /// Tasks and top supernodes.
    #[cfg(test)]
    pub fn shape(&self) -> (usize, usize) {
        (self.tasks.len(), self.top.len())
    }

    /// Overwrites `x` with `(L Lᵀ)⁻¹ x`, `L` the factor with structure
    /// `symbolic` (the one given to [`TreeSolve::new`]) and `values`. The
    /// tasks' copies of their columns carry them from the forward solve to
    /// the backward one (the top supernodes touch no task's columns).
    pub fn solve_in_place(&mut self, symbolic: &SymbolicSupernodalCholesky<usize>, values: &[f64], x: &mut [f64]) {
        self.forward(symbolic, values, x);
        self.backward(symbolic, values, x);
    }

    /// `x ← L⁻¹ x` (the task columns' part in the tasks' copies only).
    fn forward(&mut self, symbolic: &SymbolicSupernodalCholesky<usize>, values: &[f64], x: &mut [f64]) {
        let (place, local_start) = (&self.place, &self.local_start);
        let shared = &*x;
        self.tasks.par_iter_mut().for_each(|task| {
            task.copy_from(symbolic, shared);
            task.values.fill(0.0);
            for &s in &task.supernodes {
                let node = supernode(symbolic, values, s);
                let at = local_start[s] as usize;
                let products = &mut task.products[..node.pattern.len()];
                solve_columns(&node, &mut task.x[at..at + node.columns.len()], products);
                for (&at, &p) in place[node.first_row..].iter().zip(products.iter()) {
                    if at & BOUNDARY == 0 {
                        task.x[at as usize] -= p;
                    } else {
                        task.values[(at & !BOUNDARY) as usize] += p;
                    }
                }
            }
        });
        for task in &self.tasks {
            task.boundary.iter().zip(&task.values).for_each(|(&r, v)| x[r] -= v);
        }
        for &s in &self.top {
            let node = supernode(symbolic, values, s);
            self.column.clear();
            self.column.extend_from_slice(&x[node.columns.clone()]);
            self.column.resize(node.values.nrows(), 0.0);
            forward_in_panels(node.values, &mut self.column);
            let (x_top, products) = self.column.split_at(node.columns.len());
            x[node.columns.clone()].copy_from_slice(x_top);
            node.pattern.iter().zip(products).for_each(|(&r, p)| x[r] += p);
        }
    }

    /// `x ← L⁻ᵀ x`, after [`TreeSolve::forward`] (whose solved task columns
    /// are in the tasks' copies).
    fn backward(&mut self, symbolic: &SymbolicSupernodalCholesky<usize>, values: &[f64], x: &mut [f64]) {
        for &s in self.top.iter().rev() {
            let node = supernode(symbolic, values, s);
            self.column.clear();
            self.column.extend_from_slice(&x[node.columns.clone()]);
            self.column.extend(node.pattern.iter().map(|&r| x[r]));
            backward_in_panels(node.values, &mut self.column);
            x[node.columns.clone()].copy_from_slice(&self.column[..node.columns.len()]);
        }
        let (place, local_start) = (&self.place, &self.local_start);
        let shared = &*x;
        self.tasks.par_iter_mut().for_each(|task| {
            task.values.iter_mut().zip(&task.boundary).for_each(|(v, &r)| *v = shared[r]);
            for &s in task.supernodes.iter().rev() {
                let node = supernode(symbolic, values, s);
                let gathered = &mut task.products[..node.pattern.len()];
                for (g, &at) in gathered.iter_mut().zip(&place[node.first_row..]) {
                    *g = if at & BOUNDARY == 0 { task.x[at as usize] } else { task.values[(at & !BOUNDARY) as usize] };
                }
                let at = local_start[s] as usize;
                solve_columns_transposed(&node, &mut task.x[at..at + node.columns.len()], gathered);
            }
        });
        for task in &self.tasks {
            task.copy_to(symbolic, x);
        }
    }
}

impl Task {
    /// The task's copy of its columns of `x`.
    fn copy_from(&mut self, symbolic: &SymbolicSupernodalCholesky<usize>, x: &[f64]) {
        let (begin, end) = (symbolic.supernode_begin(), symbolic.supernode_end());
        let mut at = 0;
        for &s in &self.supernodes {
            let w = end[s] - begin[s];
            self.x[at..at + w].copy_from_slice(&x[begin[s]..end[s]]);
            at += w;
        }
    }

    /// Writes the task's copy back into `x`.
    fn copy_to(&self, symbolic: &SymbolicSupernodalCholesky<usize>, x: &mut [f64]) {
        let (begin, end) = (symbolic.supernode_begin(), symbolic.supernode_end());
        let mut at = 0;
        for &s in &self.supernodes {
            let w = end[s] - begin[s];
            x[begin[s]..end[s]].copy_from_slice(&self.x[at..at + w]);
            at += w;
        }
    }
}

/// Forward step of one supernode: `x_top ← L_top⁻¹ x_top`, then
/// `products = L_bot x_top` (to be subtracted from the rows below).
fn solve_columns(node: &Supernode<'_>, x_top: &mut [f64], products: &mut [f64]) {
    let w = node.columns.len();
    let (l_top, l_bot) = node.values.split_at_row(w);
    let mut x_top = MatMut::from_column_major_slice_mut(x_top, w, 1);
    solve_lower_triangular_in_place(l_top, x_top.as_mut(), Par::Seq);
    let out = MatMut::from_column_major_slice_mut(products, l_bot.nrows(), 1);
    matmul(out, Accum::Replace, l_bot, x_top.as_ref(), 1.0, Par::Seq);
    clear_upper_registers();
}

/// Backward step of one supernode, given the solved values of its rows
/// below: `x_top ← L_top⁻ᵀ (x_top - L_botᵀ gathered)`.
fn solve_columns_transposed(node: &Supernode<'_>, x_top: &mut [f64], gathered: &[f64]) {
    let w = node.columns.len();
    let (l_top, l_bot) = node.values.split_at_row(w);
    let mut x_top = MatMut::from_column_major_slice_mut(x_top, w, 1);
    let below = MatRef::from_column_major_slice(gathered, gathered.len(), 1);
    matmul(x_top.as_mut(), Accum::Add, l_bot.transpose(), below, -1.0, Par::Seq);
    solve_upper_triangular_in_place(l_top.transpose(), x_top, Par::Seq);
    clear_upper_registers();
}

/// Columns per panel of a top supernode: the panel's triangle is solved by
/// one thread, the rows below it (or, backward, its columns) in fixed
/// chunks by all.
const PANEL: usize = 64;

/// Rows per parallel chunk of a panel's forward product.
const PANEL_ROWS: usize = 256;

/// Columns per parallel chunk of a panel's backward product.
const PANEL_COLUMNS: usize = 8;

/// Forward solve of one supernode by panels of [`PANEL`] columns, in
/// parallel within each: `column` holds the supernode's columns' values,
/// solved in place, then zeros, which become minus the products to add to
/// its rows below (`-L_bot x_top`).
fn forward_in_panels(l: MatRef<'_, f64>, column: &mut [f64]) {
    let w = l.ncols();
    for c in (0..w).step_by(PANEL) {
        let end = (c + PANEL).min(w);
        let (head, below) = column.split_at_mut(end);
        let panel = &mut head[c..];
        solve_lower_triangular_in_place(
            l.submatrix(c, c, end - c, end - c),
            MatMut::from_column_major_slice_mut(panel, end - c, 1),
            Par::Seq,
        );
        clear_upper_registers();
        let panel = MatRef::from_column_major_slice(panel, end - c, 1);
        below.par_chunks_mut(PANEL_ROWS).enumerate().for_each(|(k, rows)| {
            let (first, n) = (end + k * PANEL_ROWS, rows.len());
            let out = MatMut::from_column_major_slice_mut(rows, n, 1);
            matmul(out, Accum::Add, l.submatrix(first, c, n, end - c), panel, -1.0, Par::Seq);
            clear_upper_registers();
        });
    }
}

/// Backward solve of one supernode by panels of [`PANEL`] columns, last
/// first, in parallel within each: `column` holds the supernode's columns'
/// values, solved in place, then the solved values of its rows below.
fn backward_in_panels(l: MatRef<'_, f64>, column: &mut [f64]) {
    let w = l.ncols();
    let last = w.div_ceil(PANEL);
    for p in (0..last).rev() {
        let (c, end) = (p * PANEL, ((p + 1) * PANEL).min(w));
        let (head, below) = column.split_at_mut(end);
        let below = MatRef::from_column_major_slice(below, below.len(), 1);
        let panel = &mut head[c..];
        panel.par_chunks_mut(PANEL_COLUMNS).enumerate().for_each(|(k, columns)| {
            let (first, n) = (c + k * PANEL_COLUMNS, columns.len());
            let lhs = l.submatrix(end, first, below.nrows(), n).transpose();
            let out = MatMut::from_column_major_slice_mut(columns, n, 1);
            matmul(out, Accum::Add, lhs, below, -1.0, Par::Seq);
            clear_upper_registers();
        });
        solve_upper_triangular_in_place(
            l.submatrix(c, c, end - c, end - c).transpose(),
            MatMut::from_column_major_slice_mut(panel, end - c, 1),
            Par::Seq,
        );
    }
    clear_upper_registers();
}
