//! The 4 x 4 linear systems of affine least-squares fits (normal
//! equations of the basis `(1, x, y, z)`).

/// Solves `a x = b` for `R` right-hand sides by Gaussian elimination with
/// partial pivoting; `None` when a pivot is not above `min_pivot` in
/// magnitude (the caller's measure of singular).
pub fn solve4<const R: usize>(mut a: [[f64; 4]; 4], mut b: [[f64; R]; 4], min_pivot: f64) -> Option<[[f64; R]; 4]> {
    for col in 0..4 {
        let pivot = (col..4).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        // (false for a NaN pivot too)
        (a[pivot][col].abs() > min_pivot).then_some(())?;
        a.swap(col, pivot);
        b.swap(col, pivot);
        for row in col + 1..4 {
            let factor = a[row][col] / a[col][col];
            for k in col..4 {
                a[row][k] -= factor * a[col][k];
            }
            for k in 0..R {
                b[row][k] -= factor * b[col][k];
            }
        }
    }
    let mut x = [[0.0; R]; 4];
    for row in (0..4).rev() {
        for k in 0..R {
            let s: f64 = (row + 1..4).map(|j| a[row][j] * x[j][k]).sum();
            x[row][k] = (b[row][k] - s) / a[row][row];
        }
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_pivoting_system_and_refuses_a_singular_one() {
        let a = [[0.0, 2.0, 0.0, 1.0], [1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 3.0, 0.0], [2.0, 0.0, 1.0, 4.0]];
        let want = [1.0, -2.0, 0.5, 3.0];
        let b: [[f64; 1]; 4] = std::array::from_fn(|i| [(0..4).map(|j| a[i][j] * want[j]).sum()]);
        let x = solve4(a, b, 1e-300).unwrap();
        for i in 0..4 {
            assert!((x[i][0] - want[i]).abs() < 1e-14, "{x:?}");
        }
        let mut singular = a;
        singular[3] = singular[1];
        assert!(solve4(singular, b, 1e-12).is_none());
    }
}
