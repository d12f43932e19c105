//! Self-intersection of a triangle surface: a uniform grid of triangle
//! bounding boxes finds the candidate pairs, and a pair crosses when an
//! edge of one passes through the other (signed-volume tests; touching and
//! coplanar contact do not count).

use std::collections::HashMap;

use cleave_kernels::tet::signed_volume;

/// Whether segment `p`-`q` passes through the inside of triangle `t`.
fn segment_crosses(p: [f64; 3], q: [f64; 3], t: [[f64; 3]; 3]) -> bool {
    let (sp, sq) = (signed_volume(t[0], t[1], t[2], p), signed_volume(t[0], t[1], t[2], q));
    if !((sp > 0.0 && sq < 0.0) || (sp < 0.0 && sq > 0.0)) {
        return false;
    }
    let s = [signed_volume(p, q, t[0], t[1]), signed_volume(p, q, t[1], t[2]), signed_volume(p, q, t[2], t[0])];
    s.iter().all(|&x| x > 0.0) || s.iter().all(|&x| x < 0.0)
}

/// Whether triangles `a` and `b` (vertex ids) cross. Neighbours across an
/// edge never do; triangles sharing one vertex cross when an edge opposite
/// the shared vertex passes through the other triangle.
fn triangles_cross(vertices: &[[f64; 3]], a: [u32; 3], b: [u32; 3]) -> bool {
    let shared = a.iter().filter(|v| b.contains(v)).count();
    if shared >= 2 {
        return false;
    }
    let (pa, pb) = (a.map(|v| vertices[v as usize]), b.map(|v| vertices[v as usize]));
    let edges_through = |x: [u32; 3], px: [[f64; 3]; 3], y: [u32; 3], py: [[f64; 3]; 3]| {
        (0..3).any(|i| {
            let (u, w) = (x[i], x[(i + 1) % 3]);
            !(y.contains(&u) || y.contains(&w)) && segment_crosses(px[i], px[(i + 1) % 3], py)
        })
    };
    edges_through(a, pa, b, pb) || edges_through(b, pb, a, pa)
}

/// The first pair `(a, b)`, `a < b`, of crossing triangles (lowest `a`,
/// then lowest `b`), or `None`.
pub(super) fn first_crossing(vertices: &[[f64; 3]], triangles: &[[u32; 3]]) -> Option<(usize, usize)> {
    let boxes: Vec<([f64; 3], [f64; 3])> = triangles
        .iter()
        .map(|t| {
            let p = t.map(|v| vertices[v as usize]);
            let lo = [0, 1, 2].map(|k| p[0][k].min(p[1][k]).min(p[2][k]));
            let hi = [0, 1, 2].map(|k| p[0][k].max(p[1][k]).max(p[2][k]));
            (lo, hi)
        })
        .collect();
    let mean_size = boxes
        .iter()
        .map(|(lo, hi)| ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt())
        .sum::<f64>()
        / boxes.len() as f64;
    let cell = if mean_size > 0.0 { 2.0 * mean_size } else { 1.0 };
    let range = |(lo, hi): &([f64; 3], [f64; 3])| {
        let a = lo.map(|x| (x / cell).floor() as i64);
        let b = hi.map(|x| (x / cell).floor() as i64);
        (a, b)
    };
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (t, bx) in boxes.iter().enumerate() {
        let (a, b) = range(bx);
        for i in a[0]..=b[0] {
            for j in a[1]..=b[1] {
                for k in a[2]..=b[2] {
                    grid.entry([i, j, k]).or_default().push(t as u32);
                }
            }
        }
    }
    let overlap =
        |x: &([f64; 3], [f64; 3]), y: &([f64; 3], [f64; 3])| (0..3).all(|k| x.0[k] <= y.1[k] && y.0[k] <= x.1[k]);
    for (t, bx) in boxes.iter().enumerate() {
        let (a, b) = range(bx);
        let mut best: Option<usize> = None;
        for i in a[0]..=b[0] {
            for j in a[1]..=b[1] {
                for k in a[2]..=b[2] {
                    for &s in grid.get(&[i, j, k]).into_iter().flatten() {
                        let s = s as usize;
                        if s > t
                            && best.is_none_or(|b| s < b)
                            && overlap(bx, &boxes[s])
                            && triangles_cross(vertices, triangles[t], triangles[s])
                        {
                            best = Some(s);
                        }
                    }
                }
            }
        }
        if let Some(s) = best {
            return Some((t, s));
        }
    }
    None
}
