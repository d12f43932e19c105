//! The 3D MFS fit of one element's harmonic shape functions (martin2008 §5).
//!
//! Kernel centres (`1/r`) come from samples of the element's nodes, edges
//! (`edge_samples` inside each) and faces (a grid of twice the spacing), each
//! moved outward by `offset` times the element's diameter along the
//! (averaged) outward normal; centres that land inside a non-convex element,
//! too close to its surface or to another centre are dropped. Collocation
//! points sample the same places more densely (per kernel sample,
//! `EDGE_COLLOCATION_DENSITY` along edges, `FACE_COLLOCATION_DENSITY` along
//! each direction of a face); their targets are `δ_ab` at nodes, the hat
//! functions on edges and the shared face functions inside faces. One
//! factorisation serves all `k` functions.

use std::collections::BTreeMap;

use cleave_kernels::harmonic::{self, MfsFunctions};
use cleave_kernels::vec3::{add, cross, dot, norm, point_triangle_distance, scale, sub};
use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use super::face::{place_centres, FaceBasis};
use super::mfs::{fit, FitError};
use super::HarmonicOptions;
use crate::mesh::face_geometry;
use crate::mesh::PolyMesh;

/// Spacing of the face samples relative to the edge samples': the face
/// functions are smooth inside faces, so sparser kernels there cost little
/// accuracy and keep the least-squares system small. Sparser still buys
/// little time for the accuracy it costs. At 2.25, with the collocation
/// points as they are, a 24-node build took 5 % less (2.19 against 2.30 ms,
/// one core, AMD EPYC Zen 4, alternated), while the mean error away from
/// the collocation points of the harmonic tests' families rose by a tenth
/// (convex 0.38 to 0.42 %, star 1.09 to 1.21 %) and the box's `K_e` at 5
/// and 8 edge samples moved from 1.07e-2 and 1.5e-3 to 1.8e-2 and 4.2e-3
/// off the trilinear one (past 2.05 its longest faces lose a level of
/// kernels). With the collocation points spaced out in proportion (1.42
/// `h`) the build took 2.04-2.18 ms, but the box's `K_e` at 3 samples
/// (5.02e-2) broke that test's bound of 5e-2.
const FACE_SPACING: f64 = 2.0;

/// Collocation points per kernel sample along an edge. The fit's cost is
/// proportional to the number of equations, and on a 24-node element the
/// edges held 43 % of them at 2.5 per sample; 1.75 (six points inside an
/// edge of three kernel samples) fits no worse, the edges' share of the
/// least-squares weight then matching the faces' better. Over 300 random
/// convex elements and 90 star and L prisms (the harmonic tests'
/// families), the worst RMS error away from the collocation points went
/// from 1.25 / 2.33 / 2.32 % (convex / star / L) to 1.18 / 2.26 / 2.30 %,
/// the box's `K_e` from 5.81e-2 to 5.70e-2 off the trilinear one, with a
/// seventh fewer equations; at 1.5 the L prisms' error rises (2.59 %).
const EDGE_COLLOCATION_DENSITY: f64 = 1.75;

/// Collocation points per kernel sample along a line in a face (its square
/// per area). 2.5 instead of 3 left the fit error away from the collocation
/// points within 3 % of its value (RMS 0.72 % against 0.70 %, worst 2.96 %
/// against 2.95 %) with a sixth fewer equations; 2.0 (edges at 2.5) raised
/// the convex elements' worst error from 1.25 to 1.76 %.
const FACE_COLLOCATION_DENSITY: f64 = 2.5;

/// The fitted shape functions of one element, in world units.
#[derive(Clone, Debug)]
pub struct ElementBasis {
    /// Kernel centres (m).
    pub centres: Vec<[f64; 3]>,
    /// Kernel weights (m), row-major `n x k`.
    pub weights: Vec<f64>,
    /// Linear parts `[c (1/m), d]`, one per node (element-local order).
    pub linear: Vec<[f64; 4]>,
    /// Origin of the linear parts (m).
    pub origin: [f64; 3],
}

impl ElementBasis {
    /// The same functions moved by `offset` (m): `N'(x) = N(x - offset)`,
    /// the basis of a copy of the element translated by it.
    pub fn translated(&self, offset: [f64; 3]) -> ElementBasis {
        ElementBasis {
            centres: self.centres.iter().map(|&c| add(c, offset)).collect(),
            origin: add(self.origin, offset),
            ..self.clone()
        }
    }

    /// The functions in the layout of the evaluation kernel.
    pub fn functions(&self) -> MfsFunctions<'_> {
        MfsFunctions { centres: &self.centres, weights: &self.weights, linear: &self.linear, origin: self.origin }
    }

    /// Values and gradients of the functions at `points` (m), in the layout
    /// of [`cleave_kernels::harmonic::evaluate`] (`phi[a * Q + q]`,
    /// `grad[(3 a + i) * Q + q]`), by matrix products: per run of
    /// [`POINT_RUN`] points, the kernel's value and gradient matrices
    /// (points x centres) times the weights (centres x functions), the
    /// linear parts added after. The same sums as the point-by-point
    /// kernel (equal to rounding, not bitwise), in a blocked order that
    /// keeps the products in registers: on a 24-node element's 352 points,
    /// about 0.2 ms where the point-by-point kernel took 0.53 ms (one core,
    /// AMD EPYC). `work` is the caller's, reused.
    pub fn evaluate(&self, points: &[[f64; 3]], phi: &mut [f64], grad: &mut [f64], work: &mut EvaluationWork) {
        self.evaluate_parts(points, Some(phi), Some(grad), work);
    }

    /// The values alone of [`ElementBasis::evaluate`] (`phi[a * Q + q]`):
    /// one kernel matrix and one product instead of four.
    pub fn values(&self, points: &[[f64; 3]], phi: &mut [f64], work: &mut EvaluationWork) {
        self.evaluate_parts(points, Some(phi), None, work);
    }

    /// The gradients alone of [`ElementBasis::evaluate`]
    /// (`grad[(3 a + i) * Q + q]`).
    pub fn gradients(&self, points: &[[f64; 3]], grad: &mut [f64], work: &mut EvaluationWork) {
        self.evaluate_parts(points, None, Some(grad), work);
    }

    /// [`ElementBasis::evaluate`] of the values, the gradients or both.
    fn evaluate_parts(
        &self,
        points: &[[f64; 3]],
        mut phi: Option<&mut [f64]>,
        mut grad: Option<&mut [f64]>,
        work: &mut EvaluationWork,
    ) {
        let (n, k, nq) = (self.centres.len(), self.linear.len(), points.len());
        assert!(phi.as_ref().is_none_or(|phi| phi.len() == k * nq), "phi holds k Q values");
        assert!(grad.as_ref().is_none_or(|grad| grad.len() == 3 * k * nq), "grad holds 3 k Q values");
        let weights = MatRef::from_row_major_slice(&self.weights, n, k);
        // (the values alone take the four matrices' room for one, four
        // times as many points at once)
        let lead = if grad.is_some() { POINT_RUN } else { 4 * POINT_RUN };
        work.matrices.resize(4 * POINT_RUN * n, 0.0);
        work.ones.resize(lead, 1.0);
        for first in (0..nq).step_by(lead) {
            let run = lead.min(nq - first);
            for (d, coords) in work.coords.iter_mut().enumerate() {
                coords.clear();
                coords.extend(points[first..first + run].iter().map(|p| p[d]));
            }
            let coords = [&work.coords[0][..], &work.coords[1][..], &work.coords[2][..]];
            // four column-major matrices of `run` rows, `lead` apart (the
            // value matrix alone when the gradients are not asked for)
            let (value, gradients) = work.matrices.split_at_mut(lead * n);
            let (gx, rest) = gradients.split_at_mut(gradients.len() / 3);
            let (gy, gz) = rest.split_at_mut(rest.len() / 2);
            for (j, &c) in self.centres.iter().enumerate() {
                let at = j * lead..j * lead + run;
                if grad.is_some() {
                    let gradient = [&mut gx[at.clone()], &mut gy[at.clone()], &mut gz[at.clone()]];
                    harmonic::kernel_columns_with_gradient(coords, c, &mut value[at.clone()], gradient);
                } else {
                    harmonic::kernel_column(coords, c, &work.ones[..run], &mut value[at]);
                }
            }
            // out (run x k, columns `stride` apart) = kernel (run x n) W
            let product = |out: &mut [f64], stride: usize, kernel: &[f64]| {
                let out = MatMut::from_column_major_slice_with_stride_mut(out, run, k, stride);
                let kernel = MatRef::from_column_major_slice_with_stride(kernel, run, n, lead);
                matmul(out, Accum::Replace, kernel, weights, 1.0, Par::Seq);
            };
            if let Some(phi) = phi.as_deref_mut() {
                product(&mut phi[first..], nq, value);
            }
            if let Some(grad) = grad.as_deref_mut() {
                for (d, kernel) in [&*gx, &*gy, &*gz].into_iter().enumerate() {
                    product(&mut grad[d * nq + first..], 3 * nq, kernel);
                }
            }
        }
        cleave_kernels::lanes::clear_upper_registers();
        for (a, l) in self.linear.iter().enumerate() {
            if let Some(phi) = phi.as_deref_mut() {
                for (q, p) in points.iter().enumerate() {
                    let x = sub(*p, self.origin);
                    phi[a * nq + q] += l[0] * x[0] + l[1] * x[1] + l[2] * x[2] + l[3];
                }
            }
            if let Some(grad) = grad.as_deref_mut() {
                for (i, g) in grad[3 * a * nq..3 * (a + 1) * nq].chunks_exact_mut(nq).enumerate() {
                    g.iter_mut().for_each(|g| *g += l[i]);
                }
            }
        }
    }
}

/// Points per run of [`ElementBasis::evaluate`]: its four kernel matrices
/// of a 24-node element (248 centres) take 0.5 MB, within a core's second
/// level cache (96 or 128 were no faster). [`ElementBasis::values`] runs
/// four times as many points in the same room: the lumped masses' 352
/// points of a 24-node element in two products instead of six, 0.17
/// instead of 0.21 ms (one core, Intel Xeon).
pub const POINT_RUN: usize = 64;

/// The scratch of [`ElementBasis::evaluate`], reused across elements.
#[derive(Default)]
pub struct EvaluationWork {
    matrices: Vec<f64>,
    coords: [Vec<f64>; 3],
    /// Unit row weights of the value-only kernel columns.
    ones: Vec<f64>,
}

/// Generalised winding number of the closed surface `triangles` around `p`
/// (1 inside, 0 outside): the sum of the triangles' solid angles over 4π
/// (Van Oosterom & Strackee).
pub(crate) fn winding_number(verts: &[[f64; 3]], triangles: &[[u32; 3]], p: [f64; 3]) -> f64 {
    let mut omega = 0.0;
    for t in triangles {
        let [a, b, c] = t.map(|i| sub(verts[i as usize], p));
        let (la, lb, lc) = (norm(a), norm(b), norm(c));
        let num = dot(a, cross(b, c));
        let den = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la;
        omega += 2.0 * num.atan2(den);
    }
    omega / (4.0 * std::f64::consts::PI)
}

/// A face's plane, the slab around it that holds its triangles, and the
/// half-space that holds the element.
struct FacePlane {
    /// Outward unit normal.
    normal: [f64; 3],
    /// `normal · x` on the plane.
    offset: f64,
    /// How far the face's vertices (and so its triangles) lie from the
    /// plane, at most.
    deviation: f64,
    /// How far beyond the plane the element's vertices reach, at most
    /// (rounding for a convex element): the element's convex hull, and so
    /// the element, lies in `normal · x <= offset + hull`.
    hull: f64,
    /// The face's triangles, as a range of the element's.
    triangles: std::ops::Range<usize>,
}

/// The closed surface of an element in scaled coordinates (diameter 1),
/// for placing kernel centres outside it.
struct Boundary<'a> {
    verts: &'a [[f64; 3]],
    triangles: &'a [[u32; 3]],
    faces: Vec<FacePlane>,
}

impl Boundary<'_> {
    /// Whether `c` lies outside the element, at least `clearance` from its
    /// surface. A face whose slab is `clearance` or more from `c` has its
    /// triangles as far; only the others' are measured. A point beyond a
    /// face's half-space is outside the element's convex hull; only the
    /// others (near a fold of a non-convex element) take a winding number.
    fn clear_outside(&self, c: [f64; 3], clearance: f64) -> bool {
        let clear = self.faces.iter().all(|f| {
            (dot(f.normal, c) - f.offset).abs() - f.deviation >= clearance
                || self.triangles[f.triangles.clone()]
                    .iter()
                    .all(|t| point_triangle_distance(c, &t.map(|i| self.verts[i as usize])) >= clearance)
        });
        clear
            && (self.faces.iter().any(|f| dot(f.normal, c) - f.offset > f.hull)
                || winding_number(self.verts, self.triangles, c) < 0.5)
    }
}

fn unit(v: [f64; 3]) -> Option<[f64; 3]> {
    let l = norm(v);
    (l > 1e-9).then(|| scale(v, 1.0 / l))
}

/// Fits the shape functions of element `e`; `faces[f]` are the face
/// functions of every face of the element. `None` when the fit fails.
pub fn element_basis(
    mesh: &PolyMesh,
    e: usize,
    faces: &[Option<FaceBasis>],
    options: &HarmonicOptions,
) -> Option<ElementBasis> {
    fit_element(mesh, e, faces, options, false).map(|(basis, _)| basis)
}

/// [`element_basis`] and the MFS fit's error: how far the functions lie
/// from their boundary values at the collocation points.
pub fn element_basis_measured(
    mesh: &PolyMesh,
    e: usize,
    faces: &[Option<FaceBasis>],
    options: &HarmonicOptions,
) -> Option<(ElementBasis, FitError)> {
    fit_element(mesh, e, faces, options, true).and_then(|(basis, error)| Some((basis, error?)))
}

/// The fit of [`element_basis`], with its error when `measure`.
fn fit_element(
    mesh: &PolyMesh,
    e: usize,
    faces: &[Option<FaceBasis>],
    options: &HarmonicOptions,
    measure: bool,
) -> Option<(ElementBasis, Option<FitError>)> {
    let el = &mesh.elements[e];
    let k = el.nodes.len();
    let x: Vec<[f64; 3]> = el.nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let local = |v: u32| el.nodes.binary_search(&v).expect("face vertex is an element node");
    let origin = scale(x.iter().fold([0.0; 3], |acc, p| add(acc, *p)), 1.0 / k as f64);
    let size = mesh.element_diameter(e);
    let hat = |p: [f64; 3]| scale(sub(p, origin), 1.0 / size);
    let triangles: Vec<[u32; 3]> = mesh.element_triangles(e).map(|t| t.map(|v| local(v) as u32)).collect();
    // outward unit normals of faces, edges and nodes
    let mut node_normal = vec![[0.0; 3]; k];
    let mut edges: BTreeMap<(usize, usize), [f64; 3]> = BTreeMap::new();
    let mut face_normals = Vec::with_capacity(el.faces.len());
    for r in &el.faces {
        let face = &mesh.faces[r.face as usize];
        let n = face_geometry(&mesh.nodes, &face.vertices).normal;
        let n = if r.outward { n } else { scale(n, -1.0) };
        face_normals.push(n);
        let m = face.vertices.len();
        for i in 0..m {
            let (a, b) = (local(face.vertices[i]), local(face.vertices[(i + 1) % m]));
            node_normal[a] = add(node_normal[a], n);
            let en = edges.entry((a.min(b), a.max(b))).or_insert([0.0; 3]);
            *en = add(*en, n);
        }
    }
    let mean_edge = edges.keys().map(|&(a, b)| norm(sub(x[a], x[b]))).sum::<f64>() / edges.len() as f64;
    let h = mean_edge / (options.edge_samples + 1) as f64;
    // kernel samples in scaled coordinates
    let mut samples = Vec::new();
    for (a, n) in node_normal.iter().enumerate() {
        if let Some(n) = unit(*n) {
            samples.push((hat(x[a]), n));
        }
    }
    let edge_points = |(a, b): (usize, usize), count: usize| {
        let (pa, pb) = (x[a], x[b]);
        (1..=count).map(move |s| {
            let t = s as f64 / (count + 1) as f64;
            (add(pa, scale(sub(pb, pa), t)), t)
        })
    };
    for (&ab, n) in &edges {
        if let Some(n) = unit(*n) {
            samples.extend(edge_points(ab, options.edge_samples).map(|(p, _)| (hat(p), n)));
        }
    }
    for (r, n) in el.faces.iter().zip(&face_normals) {
        let f = r.face as usize;
        faces[f]
            .as_ref()?
            .interior_points(&mesh.nodes, &mesh.faces[f], FACE_SPACING * h, |p| samples.push((hat(p), *n)));
    }
    let scaled: Vec<[f64; 3]> = x.iter().map(|&p| hat(p)).collect();
    let mut first_triangle = 0;
    let face_planes = el.faces.iter().zip(&face_normals).map(|(r, &normal)| {
        let face = &mesh.faces[r.face as usize];
        let on_face: Vec<f64> = face.vertices.iter().map(|&v| dot(normal, scaled[local(v)])).collect();
        let offset = on_face.iter().sum::<f64>() / on_face.len() as f64;
        let deviation = on_face.iter().map(|h| (h - offset).abs()).fold(0.0, f64::max);
        let hull = scaled.iter().map(|&v| dot(normal, v) - offset).fold(0.0, f64::max);
        let triangles = first_triangle..first_triangle + face.triangles.len();
        first_triangle = triangles.end;
        FacePlane { normal, offset, deviation, hull, triangles }
    });
    let boundary = Boundary { verts: &scaled, triangles: &triangles, faces: face_planes.collect() };
    let centres = place_centres(samples, options.offset, |c, clearance| boundary.clear_outside(c, clearance));
    // collocation points and targets
    let mut colloc = Vec::new();
    let mut targets = Vec::new();
    for (a, p) in scaled.iter().enumerate() {
        colloc.push(*p);
        targets.extend((0..k).map(|b| if a == b { 1.0 } else { 0.0 }));
    }
    let dense = (EDGE_COLLOCATION_DENSITY * (options.edge_samples + 1) as f64).round() as usize - 1;
    for &(a, b) in edges.keys() {
        for (p, t) in edge_points((a, b), dense) {
            colloc.push(hat(p));
            targets.extend((0..k).map(|c| {
                if c == a {
                    1.0 - t
                } else if c == b {
                    t
                } else {
                    0.0
                }
            }));
        }
    }
    for r in &el.faces {
        let f = r.face as usize;
        let face = &mesh.faces[f];
        let at: Vec<usize> = face.vertices.iter().map(|&v| local(v)).collect();
        faces[f].as_ref()?.interior_samples(
            &mesh.nodes,
            face,
            FACE_SPACING * h / FACE_COLLOCATION_DENSITY.sqrt(),
            |p, vals| {
                colloc.push(hat(p));
                let row = targets.len();
                targets.resize(row + k, 0.0);
                for (&a, v) in at.iter().zip(vals) {
                    targets[row + a] = *v;
                }
            },
        );
    }
    let (fitted, error) = fit::<3>(centres, &colloc, &targets, &scaled, measure)?;
    let n = fitted.centres.len();
    // back to world units: 1/|x̂ - k̂| = s/|x - k|, c·x̂ = (c/s)·(x - o)
    let c = &fitted.coefficients;
    let basis = ElementBasis {
        centres: fitted.centres.iter().map(|&p| add(origin, scale(p, size))).collect(),
        weights: c[..n * k].iter().map(|w| w * size).collect(),
        linear: (0..k)
            .map(|a| [c[n * k + a] / size, c[(n + 1) * k + a] / size, c[(n + 2) * k + a] / size, c[(n + 3) * k + a]])
            .collect(),
        origin,
    };
    Some((basis, error))
}
