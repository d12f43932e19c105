//! Small fixed-size vector helpers on `[f64; 3]`, inlined into every kernel.

/// `a - b`
#[inline(always)]
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a + b`
#[inline(always)]
pub fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `s a`
#[inline(always)]
pub fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// `a . b`
#[inline(always)]
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a x b`
#[inline(always)]
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Euclidean length `|a|`.
#[inline(always)]
pub fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// `a + t (b - a)`
#[inline(always)]
pub fn lerp(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])]
}

/// Axis-aligned bounding box `(min, max)` of `points` (`(+inf, -inf)` when
/// there are none).
pub fn bounding_box(points: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// Distance from `p` to the closed triangle `t` (its closest point, by
/// the region of the triangle's plane the projection falls in).
pub fn point_triangle_distance(p: [f64; 3], t: &[[f64; 3]; 3]) -> f64 {
    // closest point by barycentric regions (Ericson, Real-Time Collision
    // Detection, 5.1.5)
    let (a, b, c) = (t[0], t[1], t[2]);
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return norm(ap);
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return norm(bp);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return norm(sub(p, add(a, scale(ab, d1 / (d1 - d3)))));
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return norm(cp);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return norm(sub(p, add(a, scale(ac, d2 / (d2 - d6)))));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return norm(sub(p, add(b, scale(sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6))))));
    }
    let denom = va + vb + vc;
    if denom.abs() < f64::MIN_POSITIVE {
        return norm(ap);
    }
    let (v, w) = (vb / denom, vc / denom);
    norm(sub(p, add(a, add(scale(ab, v), scale(ac, w)))))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against the nearest of a dense grid of the triangle's points (at
    /// most the grid's spacing farther), on points all around triangles of
    /// several shapes, a degenerate one included.
    #[test]
    fn point_triangle_distance_matches_a_dense_sampling() {
        let triangles = [
            [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            [[0.2, -0.3, 0.1], [1.4, 0.5, -0.2], [0.1, 0.2, 1.3]],
            [[0.0, 0.0, 0.0], [2.0, 0.1, 0.0], [4.0, 0.2, 0.0]],
        ];
        let steps = 400;
        for t in &triangles {
            let grid: Vec<[f64; 3]> = (0..=steps)
                .flat_map(|i| (0..=steps - i).map(move |j| (i, j)))
                .map(|(i, j)| {
                    let (u, v) = (i as f64 / steps as f64, j as f64 / steps as f64);
                    add(t[0], add(scale(sub(t[1], t[0]), u), scale(sub(t[2], t[0]), v)))
                })
                .collect();
            let spacing = (0..3).map(|i| norm(sub(t[(i + 1) % 3], t[i]))).fold(0.0, f64::max) / steps as f64;
            for s in 0..300 {
                let a = s as f64 * 0.7;
                let p = [1.5 * a.sin(), 1.5 * (1.3 * a).cos(), 0.8 * (0.9 * a).sin() + 0.2];
                let sampled = grid.iter().map(|&q| norm(sub(p, q))).fold(f64::INFINITY, f64::min);
                let exact = point_triangle_distance(p, t);
                assert!(exact <= sampled + 1e-12 && sampled <= exact + spacing, "{p:?}: {exact} against {sampled}");
            }
        }
    }
}
