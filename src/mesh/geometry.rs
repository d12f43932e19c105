//! Geometry: oriented planes, and face loops (normal, area, centroid,
//! planarity, folds).

use cleave_kernels::vec3::{add, cross, dot, norm, scale, sub};
use smallvec::SmallVec;

/// An oriented plane through `point` with normal `normal` (need not be unit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// A point on the plane (m).
    pub point: [f64; 3],
    /// The normal; the positive side is where it points.
    pub normal: [f64; 3],
}

impl Plane {
    /// Checks that the point is finite and the normal finite and non-zero.
    pub fn check(&self) -> Result<(), crate::param::ParamError> {
        crate::param::finite("point", self.point, "must be finite (m)")?;
        let n = norm(self.normal);
        if !(n > 0.0 && n.is_finite()) {
            return Err(crate::param::ParamError::new("normal", self.normal, "must be finite and non-zero"));
        }
        Ok(())
    }

    /// Signed distance of `x` from the plane (m), positive on the normal's
    /// side.
    pub fn distance(&self, x: [f64; 3]) -> f64 {
        dot(sub(x, self.point), self.normal) / norm(self.normal)
    }

    /// [`Plane::distance`] of every point.
    pub fn distances(&self, points: &[[f64; 3]]) -> Vec<f64> {
        points.iter().map(self.distance_to()).collect()
    }

    /// [`Plane::distance`] as the function [`Plane::distances`] applies
    /// (the unit normal computed once: the same value for the same point,
    /// to the last bit, whichever of the two gives it).
    pub fn distance_to(&self) -> impl Fn(&[f64; 3]) -> f64 + Copy + Send + Sync {
        let (n, point) = (scale(self.normal, 1.0 / norm(self.normal)), self.point);
        move |x| dot(sub(*x, point), n)
    }
}

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
    loop_geometry(vertices.len(), |i| nodes[vertices[i] as usize])
}

/// [`face_geometry`] of the loop of the `n` points `point(0)`, ...,
/// `point(n - 1)`.
pub fn loop_geometry(n: usize, point: impl Fn(usize) -> [f64; 3]) -> FaceGeometry {
    let LoopPlane { normal, area, centroid } = loop_plane(n, &point);
    let max_deviation = (0..n).map(|i| dot(sub(point(i), centroid), normal).abs()).fold(0.0, f64::max);
    FaceGeometry { normal, area, centroid, max_deviation, diameter: super::diameter_of(n, point) }
}

/// The plane of a face loop: the part of [`FaceGeometry`] that the
/// geometry of a polyhedron needs (its faces' planes and areas), without
/// the planarity and the diameter (a pass over every pair of points).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopPlane {
    /// Unit normal by Newell's method (right-hand rule along the loop).
    pub normal: [f64; 3],
    /// Area of the loop projected on its normal plane (m^2).
    pub area: f64,
    /// Area centroid of the loop (m).
    pub centroid: [f64; 3],
}

/// The [`LoopPlane`] of the loop of the `n` points `point(0)`, ...,
/// `point(n - 1)`: the same bits as [`loop_geometry`]'s.
pub fn loop_plane(n: usize, point: impl Fn(usize) -> [f64; 3]) -> LoopPlane {
    // (point `i` and its successor, without a division per access)
    let edge = |i: usize| (point(i), point(if i + 1 == n { 0 } else { i + 1 }));
    let mean = scale((0..n).fold([0.0; 3], |acc, i| add(acc, point(i))), 1.0 / n as f64);
    let mut area_vec = [0.0; 3];
    let mut c = [0.0; 3];
    let mut wsum = 0.0;
    for i in 0..n {
        let (a, b) = edge(i);
        let t = cross(sub(a, mean), sub(b, mean));
        area_vec = add(area_vec, t);
    }
    let len = norm(area_vec);
    let normal = if len > 0.0 { scale(area_vec, 1.0 / len) } else { [0.0; 3] };
    for i in 0..n {
        let (a, b) = edge(i);
        let w = dot(cross(sub(a, mean), sub(b, mean)), normal);
        wsum += w;
        c = add(c, scale(add(add(a, b), mean), w / 3.0));
    }
    let centroid = if wsum.abs() > 0.0 { scale(c, 1.0 / wsum) } else { mean };
    LoopPlane { normal, area: 0.5 * len, centroid }
}

/// Closed face loops of keyed points (a key names a point: two loops share
/// an edge where they hold the same two keys next to each other).
pub type Loops<K> = super::lists::Lists<(K, [f64; 3])>;

/// The depth (m) of the deepest fold of a closed surface given as planar
/// face loops. At an edge where faces `f` and `g` meet, the fold's depth
/// is the smaller of how far `g`'s points lie outside `f`'s plane and how
/// far `f`'s lie outside `g`'s; both are positive only at a reflex edge,
/// and a closed surface without reflex edges bounds a convex body. The
/// loops run counter-clockwise seen from outside. Negative for a strictly
/// convex surface.
pub fn fold_depth<K: Copy + Ord>(loops: &Loops<K>) -> f64 {
    fold_depth_on(loops, &loop_planes(loops))
}

/// The [`LoopPlane`] of every loop of `loops`, in order (on the stack for
/// the elements cuts make: thousands per cut).
pub fn loop_planes<K: Copy>(loops: &Loops<K>) -> SmallVec<[LoopPlane; 16]> {
    loops.iter().map(|lp| loop_plane(lp.len(), |i| lp[i].1)).collect()
}

/// [`fold_depth`] of `loops` whose planes, [`loop_planes`], are known.
pub fn fold_depth_on<K: Copy + Ord>(loops: &Loops<K>, planes: &[LoopPlane]) -> f64 {
    let outside = |f: usize, g: usize| {
        let LoopPlane { centroid: c, normal: n, .. } = planes[f];
        loops.get(g).iter().map(|p| dot(sub(p.1, c), n)).fold(f64::NEG_INFINITY, f64::max)
    };
    // every loop's edges, sorted: a loop meets the first loop (in loop
    // order) that holds the same edge (a sort, not a hash map: cuts and
    // element builds measure thousands of elements)
    let mut edges: SmallVec<[((K, K), usize); 64]> = SmallVec::with_capacity(loops.values().len());
    for (k, lp) in loops.iter().enumerate() {
        for i in 0..lp.len() {
            let (a, b) = (lp[i].0, lp[(i + 1) % lp.len()].0);
            edges.push(((a.min(b), a.max(b)), k));
        }
    }
    edges.sort_unstable();
    let mut worst = f64::NEG_INFINITY;
    for uses in edges.chunk_by(|x, y| x.0 == y.0) {
        let first = uses[0].1;
        for &(_, k) in &uses[1..] {
            // (a fold no deeper than `outside(k, first)` cannot deepen the
            // worst one found: the other side is measured only when it may)
            let one_side = outside(k, first);
            if !(one_side <= worst) {
                worst = worst.max(one_side.min(outside(first, k)));
            }
        }
    }
    worst
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
