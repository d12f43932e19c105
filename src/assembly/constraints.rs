//! Dirichlet constraints imposed by symmetric elimination.

use super::SparsePattern;

/// Prescribed values of some scalar unknowns.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Constraints {
    /// Whether each scalar unknown is prescribed.
    pub fixed: Vec<bool>,
    /// The prescribed value of each fixed unknown (ignored where free).
    pub value: Vec<f64>,
}

impl Constraints {
    /// No unknown fixed, for `n` scalar unknowns.
    pub fn free(n: usize) -> Self {
        Constraints { fixed: vec![false; n], value: vec![0.0; n] }
    }

    /// No unknown fixed, for `n` scalar unknowns, in the memory this
    /// already holds.
    pub fn reset(&mut self, n: usize) {
        self.fixed.clear();
        self.fixed.resize(n, false);
        self.value.clear();
        self.value.resize(n, 0.0);
    }

    /// Fixes scalar unknown `d` to `v`.
    pub fn fix(&mut self, d: usize, v: f64) {
        self.fixed[d] = true;
        self.value[d] = v;
    }

    /// Number of fixed unknowns.
    pub fn count(&self) -> usize {
        self.fixed.iter().filter(|&&f| f).count()
    }

    /// Turns `A x = b` into the symmetric system on which the fixed unknowns
    /// take their values: `b -= A x̄` (x̄ the prescribed values, zero where
    /// free), fixed rows and columns are zeroed except the diagonal, which
    /// keeps `A_dd` (or 1 if that is not positive) with `b_d = A_dd x̄_d`.
    pub fn apply(&self, pattern: &SparsePattern, values: &mut [f64], rhs: &mut [f64]) {
        if !self.fixed.contains(&true) {
            return;
        }
        let col_ptr = pattern.symbolic.col_ptr();
        let row_idx = pattern.symbolic.row_idx();
        let n = col_ptr.len() - 1;
        for j in 0..n {
            if self.fixed[j] && self.value[j] != 0.0 {
                let xj = self.value[j];
                for p in col_ptr[j]..col_ptr[j + 1] {
                    rhs[row_idx[p]] -= values[p] * xj;
                }
            }
        }
        for j in 0..n {
            let range = col_ptr[j]..col_ptr[j + 1];
            if self.fixed[j] {
                let d = pattern.diagonal_slot(j);
                let diag = if values[d] > 0.0 { values[d] } else { 1.0 };
                values[range].iter_mut().for_each(|v| *v = 0.0);
                values[d] = diag;
                rhs[j] = diag * self.value[j];
            } else {
                for p in range {
                    if self.fixed[row_idx[p]] {
                        values[p] = 0.0;
                    }
                }
            }
        }
    }
}
