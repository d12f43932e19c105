//! Triangulation of a planar face loop by ear clipping.
//!
//! Faces produced by cutting carry collinear vertices (a node inserted on an
//! edge of a neighbour), and harmonic elements have non-convex faces, so a fan
//! from the first vertex is not enough. We clip, at each step, the valid ear
//! (convex corner, no other vertex inside) whose smallest angle is largest;
//! degenerate (collinear) ears are clipped only when nothing else is left.

use cleave_kernels::vec3::{cross, dot, norm, sub};

use smallvec::SmallVec;

use super::geometry::face_geometry;
use super::FaceTriangles;

/// Loop lengths triangulated without a heap allocation for the work lists.
const LOCAL: usize = 24;

/// Triangles (in node ids, oriented like the loop) covering the loop.
pub fn triangulate_loop(nodes: &[[f64; 3]], vertices: &[u32]) -> FaceTriangles {
    let n = vertices.len();
    if n == 3 {
        return smallvec::smallvec![[vertices[0], vertices[1], vertices[2]]];
    }
    let normal = face_geometry(nodes, vertices).normal;
    // 2D coordinates in the face plane.
    let u = {
        let a = if normal[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        let c = cross(normal, a);
        let l = norm(c);
        [c[0] / l, c[1] / l, c[2] / l]
    };
    let v = cross(normal, u);
    let o = nodes[vertices[0] as usize];
    // (on the stack for the loops cuts make: thousands per cut)
    let pts: SmallVec<[[f64; 2]; LOCAL]> = vertices
        .iter()
        .map(|&i| {
            let d = sub(nodes[i as usize], o);
            [dot(d, u), dot(d, v)]
        })
        .collect();
    let mut ring: SmallVec<[usize; LOCAL]> = (0..n).collect();
    let mut out = FaceTriangles::with_capacity(n - 2);
    while ring.len() > 3 {
        let m = ring.len();
        let mut best: Option<(usize, f64)> = None;
        let mut fallback: Option<(usize, f64)> = None;
        for k in 0..m {
            let (ia, ib, ic) = (ring[(k + m - 1) % m], ring[k], ring[(k + 1) % m]);
            let (a, b, c) = (pts[ia], pts[ib], pts[ic]);
            let area2 = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            let scale2 = dist2(a, b).max(dist2(b, c)).max(dist2(a, c));
            if area2 <= 1e-14 * scale2 {
                // reflex or collinear corner: keep the least bad as fallback
                let q = area2 / scale2.max(f64::MIN_POSITIVE);
                if fallback.is_none_or(|(_, fq)| q > fq) {
                    fallback = Some((k, q));
                }
                continue;
            }
            let blocked = ring
                .iter()
                .any(|&j| j != ia && j != ib && j != ic && inside_or_on(pts[j], a, b, c) && pts[j] != a && pts[j] != c);
            if blocked {
                continue;
            }
            let q = min_angle_sin(a, b, c);
            if best.is_none_or(|(_, bq)| q > bq) {
                best = Some((k, q));
            }
        }
        let k = best.or(fallback).map(|(k, _)| k).unwrap_or(0);
        let m = ring.len();
        out.push([vertices[ring[(k + m - 1) % m]], vertices[ring[k]], vertices[ring[(k + 1) % m]]]);
        ring.remove(k);
    }
    out.push([vertices[ring[0]], vertices[ring[1]], vertices[ring[2]]]);
    out
}

fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)
}

/// Whether `p` lies inside triangle `(a, b, c)` or on its boundary, up to a
/// relative tolerance: a node inserted on an edge (a T-junction repair) is
/// computed by interpolation and may sit a rounding error off the line.
fn inside_or_on(p: [f64; 2], a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> bool {
    let s = |p: [f64; 2], q: [f64; 2], r: [f64; 2]| {
        let v = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]);
        v + 1e-10 * dist2(p, q)
    };
    s(a, b, p) >= 0.0 && s(b, c, p) >= 0.0 && s(c, a, p) >= 0.0
}

/// Sine of the smallest angle of a counter-clockwise triangle (a quality in [0, 1]).
fn min_angle_sin(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    let area2 = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    let (ab, bc, ca) = (dist2(a, b).sqrt(), dist2(b, c).sqrt(), dist2(c, a).sqrt());
    // The smallest angle is opposite the shortest side; its sine is twice the
    // area over the product of the two sides that enclose it.
    let enclosing = ab * bc * ca / ab.min(bc).min(ca);
    area2 / enclosing
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(nodes: &[[f64; 3]], tris: &[[u32; 3]]) -> f64 {
        tris.iter()
            .map(|t| {
                let (a, b, c) = (nodes[t[0] as usize], nodes[t[1] as usize], nodes[t[2] as usize]);
                0.5 * cross(sub(b, a), sub(c, a))[2]
            })
            .sum()
    }

    #[test]
    fn square_with_collinear_vertex() {
        let nodes = [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        let t = triangulate_loop(&nodes, &[0, 1, 2, 3, 4]);
        assert_eq!(t.len(), 3);
        assert!((area(&nodes, &t) - 1.0).abs() < 1e-15);
        for tri in &t {
            let (a, b, c) = (nodes[tri[0] as usize], nodes[tri[1] as usize], nodes[tri[2] as usize]);
            assert!(cross(sub(b, a), sub(c, a))[2] > 1e-12, "no flat triangle: {tri:?}");
        }
    }

    #[test]
    fn vertex_a_rounding_error_off_an_edge_is_not_cut_off() {
        // node 4 sits on edge 3-0 up to rounding (a T-junction repair)
        let t = 0.37;
        let nodes = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.2, 0.8, 0.0],
            [0.3, 1.0, 0.0],
            [0.3 * (1.0 - t) - 1e-15, 1.0 * (1.0 - t), 0.0],
        ];
        let tris = triangulate_loop(&nodes, &[0, 1, 2, 3, 4]);
        assert_eq!(tris.len(), 3);
        for tri in &tris {
            let (a, b, c) = (nodes[tri[0] as usize], nodes[tri[1] as usize], nodes[tri[2] as usize]);
            assert!(cross(sub(b, a), sub(c, a))[2] > 1e-3, "degenerate triangle {tri:?}");
        }
    }

    #[test]
    fn non_convex_l() {
        let nodes =
            [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 2.0, 0.0]];
        let t = triangulate_loop(&nodes, &[0, 1, 2, 3, 4, 5]);
        assert_eq!(t.len(), 4);
        assert!((area(&nodes, &t) - 3.0).abs() < 1e-14);
        for tri in &t {
            let (a, b, c) = (nodes[tri[0] as usize], nodes[tri[1] as usize], nodes[tri[2] as usize]);
            assert!(cross(sub(b, a), sub(c, a))[2] > 0.0);
        }
    }
}
