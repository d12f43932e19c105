//! Geometry of face loops: normal, area, centroid and planarity.

use cleave_kernels::vec3::{add, cross, dot, norm, scale, sub};

/// Geometric summary of a planar (or almost planar) face loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceGeometry {
    /// Unit normal by Newell's method (right-hand rule along the loop).
    pub normal: [f64; 3],
    /// Area of the loop projected on its normal plane (m^2).
    pub area: f64,
    /// Area centroid of the loop (m).
    pub centroid: [f64; 3],
    /// Largest distance of a vertex from the plane through `centroid` with
    /// normal `normal` (m).
    pub max_deviation: f64,
    /// Largest distance between two vertices (m).
    pub diameter: f64,
}

/// Normal, area, centroid and planarity of the loop `vertices` over `nodes`.
///
/// The normal is Newell's area vector, robust for non-convex and slightly
/// non-planar loops; a loop of zero area gets a zero normal.
pub fn face_geometry(nodes: &[[f64; 3]], vertices: &[u32]) -> FaceGeometry {
    let p = |i: usize| nodes[vertices[i % vertices.len()] as usize];
    let n = vertices.len();
    let mean = scale((0..n).fold([0.0; 3], |acc, i| add(acc, p(i))), 1.0 / n as f64);
    let mut area_vec = [0.0; 3];
    let mut c = [0.0; 3];
    let mut wsum = 0.0;
    for i in 0..n {
        let (a, b) = (sub(p(i), mean), sub(p(i + 1), mean));
        let t = cross(a, b);
        area_vec = add(area_vec, t);
    }
    let len = norm(area_vec);
    let normal = if len > 0.0 { scale(area_vec, 1.0 / len) } else { [0.0; 3] };
    for i in 0..n {
        let (a, b) = (p(i), p(i + 1));
        let w = dot(cross(sub(a, mean), sub(b, mean)), normal);
        wsum += w;
        c = add(c, scale(add(add(a, b), mean), w / 3.0));
    }
    let centroid = if wsum.abs() > 0.0 { scale(c, 1.0 / wsum) } else { mean };
    let mut max_deviation: f64 = 0.0;
    let mut d2: f64 = 0.0;
    for i in 0..n {
        max_deviation = max_deviation.max(dot(sub(p(i), centroid), normal).abs());
        for j in i + 1..n {
            let d = sub(p(i), p(j));
            d2 = d2.max(dot(d, d));
        }
    }
    FaceGeometry { normal, area: 0.5 * len, centroid, max_deviation, diameter: d2.sqrt() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_square() {
        let nodes = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        let g = face_geometry(&nodes, &[0, 1, 2, 3]);
        assert_eq!(g.normal, [0.0, 0.0, 1.0]);
        assert!((g.area - 1.0).abs() < 1e-15);
        assert!((g.centroid[0] - 0.5).abs() < 1e-15 && (g.centroid[1] - 0.5).abs() < 1e-15);
        assert_eq!(g.max_deviation, 0.0);
    }

    #[test]
    fn l_shape_centroid() {
        // L made of three unit squares: centroid (5/6, 5/6)
        let nodes =
            [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 2.0, 0.0]];
        let g = face_geometry(&nodes, &[0, 1, 2, 3, 4, 5]);
        assert!((g.area - 3.0).abs() < 1e-14);
        assert!((g.centroid[0] - 5.0 / 6.0).abs() < 1e-14);
        assert!((g.centroid[1] - 5.0 / 6.0).abs() < 1e-14);
    }
}
