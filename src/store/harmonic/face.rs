//! Face functions: the boundary values of harmonic elements (martin2008 §4).
//!
//! The shape function of node `a` restricted to a face is the face's own
//! 2D function `b_a`, computed once per global face and shared by the two
//! elements on it, so neighbours see the same boundary values:
//!
//! - a triangle: the linear (barycentric) functions, the linear tetrahedron's;
//! - a convex quadrilateral: the bilinear functions of its isoparametric map,
//!   the trilinear hexahedron's (on a rectangle they are its 2D harmonic
//!   coordinates; elsewhere they keep harmonic elements conforming with
//!   trilinear neighbours);
//! - any other polygon, convex or not: 2D harmonic coordinates by MFS
//!   (kernel `log r`), fitted to the hat functions along its edges.
//!
//! Each face also stores its moments `m_a = ∫_F b_a n dA` (m^2, along the
//! loop's normal), the boundary integrals the consistent quadrature of its
//! elements matches, so the patch test holds across every face.

use cleave_kernels::vec3::{add, cross, dot, norm, scale, sub};

use super::mfs::{fit, Fit};
use super::HarmonicOptions;
use crate::mesh::face_geometry;
use crate::mesh::Face;

/// The boundary functions of one global face, in its loop order.
pub enum FaceFunction {
    /// Barycentric functions of a triangle.
    Linear,
    /// Bilinear functions of a convex quadrilateral `x(ξ, η)`, loop vertex
    /// `0, 1, 2, 3` at `(0,0), (1,0), (1,1), (0,1)`.
    Bilinear,
    /// 2D harmonic coordinates by MFS in the face's plane.
    Harmonic(Box<PlanarMfs>),
}

/// An MFS fit on a face: scaled in-plane coordinates `(x - o)·[u, v] / s`.
pub struct PlanarMfs {
    origin: [f64; 3],
    axes: [[f64; 3]; 2],
    scale: f64,
    fit: Fit<2>,
}

impl PlanarMfs {
    fn local(&self, p: [f64; 3]) -> [f64; 2] {
        let d = sub(p, self.origin);
        [dot(d, self.axes[0]) / self.scale, dot(d, self.axes[1]) / self.scale]
    }

    /// Values of the loop vertices' functions at `p` (projected on the plane).
    pub fn values(&self, p: [f64; 3], out: &mut [f64]) {
        self.fit.values(self.local(p), out);
    }
}

/// A face's functions and moments.
pub struct FaceBasis {
    /// The functions.
    pub function: FaceFunction,
    /// `∫_F b_a n dA` (m^2) per loop vertex, `n` along the loop.
    pub moments: Vec<[f64; 3]>,
}

/// The 7-point degree-5 rule on a triangle (Radon): barycentric points and
/// weights summing to 1.
fn triangle_rule() -> [([f64; 3], f64); 7] {
    let s = 15f64.sqrt();
    let (a1, b1, w1) = ((6.0 - s) / 21.0, (9.0 + 2.0 * s) / 21.0, (155.0 - s) / 1200.0);
    let (a2, b2, w2) = ((6.0 + s) / 21.0, (9.0 - 2.0 * s) / 21.0, (155.0 + s) / 1200.0);
    [
        ([1.0 / 3.0; 3], 9.0 / 40.0),
        ([a1, a1, b1], w1),
        ([a1, b1, a1], w1),
        ([b1, a1, a1], w1),
        ([a2, a2, b2], w2),
        ([a2, b2, a2], w2),
        ([b2, a2, a2], w2),
    ]
}

fn bilinear(xi: f64, eta: f64) -> [f64; 4] {
    [(1.0 - xi) * (1.0 - eta), xi * (1.0 - eta), xi * eta, (1.0 - xi) * eta]
}

/// The isoparametric point and the area vector `x_ξ × x_η` of a quad.
fn bilinear_map(p: &[[f64; 3]], xi: f64, eta: f64) -> ([f64; 3], [f64; 3]) {
    let n = bilinear(xi, eta);
    let x = (0..4).fold([0.0; 3], |acc, a| add(acc, scale(p[a], n[a])));
    let dxi = add(scale(sub(p[1], p[0]), 1.0 - eta), scale(sub(p[2], p[3]), eta));
    let deta = add(scale(sub(p[3], p[0]), 1.0 - xi), scale(sub(p[2], p[1]), xi));
    (x, cross(dxi, deta))
}

/// Whether the loop `p` (4 points) is a strictly convex quadrilateral.
fn is_convex_quad(p: &[[f64; 3]], normal: [f64; 3]) -> bool {
    (0..4).all(|i| {
        let (a, b, c) = (p[i], p[(i + 1) % 4], p[(i + 2) % 4]);
        dot(cross(sub(b, a), sub(c, b)), normal) > 0.0
    })
}

/// Points strictly inside the triangle `(a, b, c)` on a barycentric grid of
/// spacing about `h`, with their barycentric coordinates.
pub(super) fn triangle_grid(t: [[f64; 3]; 3], h: f64, mut visit: impl FnMut([f64; 3], [f64; 3])) {
    let longest = (0..3).map(|i| norm(sub(t[(i + 1) % 3], t[i]))).fold(0.0, f64::max);
    let level = (longest / h).ceil().max(1.0) as usize;
    for i in 1..level {
        for j in 1..level - i {
            let l = [i as f64 / level as f64, j as f64 / level as f64, (level - i - j) as f64 / level as f64];
            let p = add(add(scale(t[0], l[0]), scale(t[1], l[1])), scale(t[2], l[2]));
            visit(p, l);
        }
    }
}

impl FaceBasis {
    /// Builds the functions of `face`; `None` when the MFS fit fails (a
    /// degenerate face).
    pub fn build(nodes: &[[f64; 3]], face: &Face, options: &HarmonicOptions) -> Option<Self> {
        let loop_pts: Vec<[f64; 3]> = face.vertices.iter().map(|&v| nodes[v as usize]).collect();
        let kf = loop_pts.len();
        let g = face_geometry(nodes, &face.vertices);
        let position = |v: u32| face.vertices.iter().position(|&w| w == v).expect("triangle vertex on its loop");
        let function = if kf == 3 {
            FaceFunction::Linear
        } else if kf == 4 && is_convex_quad(&loop_pts, g.normal) {
            FaceFunction::Bilinear
        } else {
            FaceFunction::Harmonic(Box::new(planar_mfs(&loop_pts, g.normal, g.centroid, g.diameter, options)?))
        };
        let mut moments = vec![[0.0; 3]; kf];
        match &function {
            FaceFunction::Linear | FaceFunction::Harmonic(_) => {
                let mut vals = vec![0.0; kf];
                for t in &face.triangles {
                    let p = t.map(|v| nodes[v as usize]);
                    let area_vec = scale(cross(sub(p[1], p[0]), sub(p[2], p[0])), 0.5);
                    for (l, w) in triangle_rule() {
                        let x = add(add(scale(p[0], l[0]), scale(p[1], l[1])), scale(p[2], l[2]));
                        match &function {
                            FaceFunction::Harmonic(mfs) => mfs.values(x, &mut vals),
                            _ => {
                                vals.fill(0.0);
                                for i in 0..3 {
                                    vals[position(t[i])] = l[i];
                                }
                            }
                        }
                        for (m, v) in moments.iter_mut().zip(&vals) {
                            *m = add(*m, scale(area_vec, w * v));
                        }
                    }
                }
            }
            FaceFunction::Bilinear => {
                let (gp, gw) = cleave_kernels::quadrature::gauss_legendre(2);
                for (&xi, &wx) in gp.iter().zip(&gw) {
                    for (&eta, &wy) in gp.iter().zip(&gw) {
                        let (_, area_vec) = bilinear_map(&loop_pts, xi, eta);
                        for (m, n) in moments.iter_mut().zip(bilinear(xi, eta)) {
                            *m = add(*m, scale(area_vec, wx * wy * n));
                        }
                    }
                }
            }
        }
        Some(FaceBasis { function, moments })
    }

    /// Visits points strictly inside the face at spacing about `h` (m) with
    /// the values of the loop vertices' functions there (loop order).
    pub fn interior_samples(&self, nodes: &[[f64; 3]], face: &Face, h: f64, visit: impl FnMut([f64; 3], &[f64])) {
        self.interior(nodes, face, h, true, visit);
    }

    /// The points of [`FaceBasis::interior_samples`] alone (the MFS face
    /// functions are not evaluated there).
    pub fn interior_points(&self, nodes: &[[f64; 3]], face: &Face, h: f64, mut visit: impl FnMut([f64; 3])) {
        self.interior(nodes, face, h, false, |p, _| visit(p));
    }

    /// [`FaceBasis::interior_samples`], with the MFS functions' values
    /// only when `values` (zeros otherwise).
    fn interior(&self, nodes: &[[f64; 3]], face: &Face, h: f64, values: bool, mut visit: impl FnMut([f64; 3], &[f64])) {
        let kf = face.vertices.len();
        let mut vals = vec![0.0; kf];
        match &self.function {
            FaceFunction::Bilinear => {
                let p: Vec<[f64; 3]> = face.vertices.iter().map(|&v| nodes[v as usize]).collect();
                let longest = (0..4).map(|i| norm(sub(p[(i + 1) % 4], p[i]))).fold(0.0, f64::max);
                let level = (longest / h).ceil().max(1.0) as usize;
                for i in 1..level {
                    for j in 1..level {
                        let (xi, eta) = (i as f64 / level as f64, j as f64 / level as f64);
                        visit(bilinear_map(&p, xi, eta).0, &bilinear(xi, eta));
                    }
                }
            }
            FaceFunction::Linear | FaceFunction::Harmonic(_) => {
                for t in &face.triangles {
                    let p = t.map(|v| nodes[v as usize]);
                    triangle_grid(p, h, |x, l| {
                        match &self.function {
                            FaceFunction::Harmonic(mfs) => {
                                if values {
                                    mfs.values(x, &mut vals)
                                }
                            }
                            _ => {
                                vals.fill(0.0);
                                for i in 0..3 {
                                    let at = face.vertices.iter().position(|&w| w == t[i]).expect("vertex on loop");
                                    vals[at] = l[i];
                                }
                            }
                        }
                        visit(x, &vals);
                    });
                }
            }
        }
    }
}

/// In-plane coordinates of the loop and helpers of the 2D fit.
struct Polygon {
    pts: Vec<[f64; 2]>,
}

impl Polygon {
    /// Whether `p` is inside (crossing number).
    fn contains(&self, p: [f64; 2]) -> bool {
        let n = self.pts.len();
        let mut inside = false;
        for i in 0..n {
            let (a, b) = (self.pts[i], self.pts[(i + 1) % n]);
            if (a[1] > p[1]) != (b[1] > p[1]) {
                let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
                if p[0] < x {
                    inside = !inside;
                }
            }
        }
        inside
    }

    /// Distance from `p` to the boundary.
    fn distance(&self, p: [f64; 2]) -> f64 {
        let n = self.pts.len();
        (0..n)
            .map(|i| {
                let (a, b) = (self.pts[i], self.pts[(i + 1) % n]);
                let (d, e) = ([b[0] - a[0], b[1] - a[1]], [p[0] - a[0], p[1] - a[1]]);
                let t = ((e[0] * d[0] + e[1] * d[1]) / (d[0] * d[0] + d[1] * d[1])).clamp(0.0, 1.0);
                ((e[0] - t * d[0]).powi(2) + (e[1] - t * d[1]).powi(2)).sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// Outward unit normal of edge `i` (from point `i` to `i + 1`), for a
    /// counter-clockwise loop.
    fn edge_normal(&self, i: usize) -> [f64; 2] {
        let (a, b) = (self.pts[i], self.pts[(i + 1) % self.pts.len()]);
        let d = [b[0] - a[0], b[1] - a[1]];
        let l = (d[0] * d[0] + d[1] * d[1]).sqrt();
        [d[1] / l, -d[0] / l]
    }
}

/// Places kernel centres: each sample moved outward by `offset`, kept only
/// when `clear_outside(c, offset / 2)` (it lies outside the region, at
/// least `offset / 2` from its boundary) and it is `offset / 4` from every
/// centre kept before (martin2008 §5: centres inside a non-convex element
/// or clustered at a concave corner are dropped).
pub(super) fn place_centres<const D: usize>(
    samples: impl IntoIterator<Item = ([f64; D], [f64; D])>,
    offset: f64,
    clear_outside: impl Fn([f64; D], f64) -> bool,
) -> Vec<[f64; D]> {
    let mut centres: Vec<[f64; D]> = Vec::new();
    for (s, n) in samples {
        let c: [f64; D] = std::array::from_fn(|i| s[i] + offset * n[i]);
        let ok = centres.iter().all(|k| (0..D).map(|i| (k[i] - c[i]).powi(2)).sum::<f64>() >= (0.25 * offset).powi(2))
            && clear_outside(c, 0.5 * offset);
        if ok {
            centres.push(c);
        }
    }
    centres
}

/// The 2D MFS fit of a polygon's harmonic coordinates.
fn planar_mfs(
    loop_pts: &[[f64; 3]],
    normal: [f64; 3],
    centroid: [f64; 3],
    diameter: f64,
    options: &HarmonicOptions,
) -> Option<PlanarMfs> {
    let kf = loop_pts.len();
    let u = {
        let e = sub(loop_pts[1], loop_pts[0]);
        scale(e, 1.0 / norm(e))
    };
    let v = cross(normal, u);
    let mut mfs = PlanarMfs {
        origin: centroid,
        axes: [u, v],
        scale: diameter,
        fit: Fit { centres: Vec::new(), coefficients: Vec::new(), k: kf },
    };
    let poly = Polygon { pts: loop_pts.iter().map(|&p| mfs.local(p)).collect() };
    if !(diameter > 0.0) || poly.pts.iter().any(|p| !p[0].is_finite() || !p[1].is_finite()) {
        return None;
    }
    // kernel samples: nodes (mean of the adjacent edge normals) and
    // `edge_samples` points inside every edge
    let normalize = |n: [f64; 2]| {
        let l = (n[0] * n[0] + n[1] * n[1]).sqrt();
        [n[0] / l, n[1] / l]
    };
    let mut samples = Vec::new();
    for i in 0..kf {
        let (np, nn) = (poly.edge_normal((i + kf - 1) % kf), poly.edge_normal(i));
        samples.push((poly.pts[i], normalize([np[0] + nn[0], np[1] + nn[1]])));
    }
    let edge_points = |i: usize, count: usize| {
        let (a, b) = (poly.pts[i], poly.pts[(i + 1) % kf]);
        (1..=count).map(move |s| {
            let t = s as f64 / (count + 1) as f64;
            ([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])], t)
        })
    };
    for i in 0..kf {
        samples.extend(edge_points(i, options.edge_samples).map(|(p, _)| (p, poly.edge_normal(i))));
    }
    let centres =
        place_centres(samples, options.offset, |c, clearance| !poly.contains(c) && poly.distance(c) >= clearance);
    // collocation at three times the density: nodes and edge points, with
    // the hat functions as targets
    let mut colloc = Vec::new();
    let mut targets = Vec::new();
    for i in 0..kf {
        colloc.push(poly.pts[i]);
        targets.extend((0..kf).map(|a| if a == i { 1.0 } else { 0.0 }));
    }
    let dense = 3 * (options.edge_samples + 1) - 1;
    for i in 0..kf {
        for (p, t) in edge_points(i, dense) {
            colloc.push(p);
            targets.extend((0..kf).map(|a| {
                if a == i {
                    1.0 - t
                } else if a == (i + 1) % kf {
                    t
                } else {
                    0.0
                }
            }));
        }
    }
    mfs.fit = fit(centres, &colloc, &targets, &poly.pts, false)?.0;
    Some(mfs)
}
