//! Harmonic (MFS) shape functions on single elements: partition of unity,
//! linear reproduction, the Lagrange property, gradients against finite
//! differences, the boundary fit error at and away from the collocation
//! points, and the cube against the trilinear hexahedron.

use cleave::mesh::PolyMesh;
use cleave::meshing::{clipped_box, prism};
use cleave::store::harmonic::{
    element_basis, element_basis_measured, face_bases, star_point, ElementBasis, EvaluationWork, FitError,
    HarmonicOptions,
};
use cleave_kernels::dyn_stack::{MemBuffer, MemStack};
use cleave_kernels::harmonic::{evaluate, evaluate_scratch};
use cleave_kernels::quadrature::cone_rule;
use proptest::prelude::*;

/// The basis of element 0 of `mesh`, its fit error at the collocation
/// points, and interior points (a cone rule).
fn basis(mesh: &PolyMesh, options: &HarmonicOptions) -> (ElementBasis, FitError, Vec<[f64; 3]>) {
    let faces = face_bases(mesh, &[0], options).unwrap();
    let (b, fit) = element_basis_measured(mesh, 0, &faces, options).expect("fit");
    let el = &mesh.elements[0];
    let verts: Vec<[f64; 3]> = el.nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let tris: Vec<[u32; 3]> =
        mesh.element_triangles(0).map(|t| t.map(|v| el.nodes.binary_search(&v).unwrap() as u32)).collect();
    let apex = star_point(&verts, &tris, mesh.element_diameter(0)).expect("star-shaped");
    let (mut pts, mut w) = (Vec::new(), Vec::new());
    cone_rule(&verts, &tris, apex, 2, &mut pts, &mut w);
    (b, fit, pts)
}

/// A star-shaped (non-convex) polygon with `n` tips, radii alternating.
fn star(n: usize, r_in: f64, r_out: f64, twist: f64) -> Vec<[f64; 2]> {
    (0..2 * n)
        .map(|i| {
            let a = std::f64::consts::PI * i as f64 / n as f64 + twist;
            let r = if i % 2 == 0 { r_out } else { r_in };
            [r * a.cos(), r * a.sin()]
        })
        .collect()
}

/// An L-shaped polygon with arm widths `a`, `b` (unit square minus a corner).
fn l_shape(a: f64, b: f64) -> Vec<[f64; 2]> {
    vec![[0.0, 0.0], [1.0, 0.0], [1.0, b], [a, b], [a, 1.0], [0.0, 1.0]]
}

/// The shortest edge of element 0 (m).
fn shortest_edge(mesh: &PolyMesh) -> f64 {
    let mut shortest = f64::INFINITY;
    for r in &mesh.elements[0].faces {
        let loop_ = &mesh.faces[r.face as usize].vertices;
        for (i, &a) in loop_.iter().enumerate() {
            let (p, q) = (mesh.nodes[a as usize], mesh.nodes[loop_[(i + 1) % loop_.len()] as usize]);
            shortest = shortest.min((0..3).map(|d| (p[d] - q[d]).powi(2)).sum::<f64>().sqrt());
        }
    }
    shortest
}

/// Partition of unity and linear reproduction at `pts` (exact by the
/// projected linear term) and the Lagrange property at the nodes (up to
/// the fit error); the element store's evaluation by matrix products
/// agrees with the point-by-point kernel to rounding.
fn check_reproduction(mesh: &PolyMesh, b: &ElementBasis, pts: &[[f64; 3]]) -> Result<f64, TestCaseError> {
    let k = b.linear.len();
    let nodes: Vec<[f64; 3]> = mesh.elements[0].nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let nq = pts.len();
    let (mut phi, mut grad) = (vec![0.0; k * nq], vec![0.0; 3 * k * nq]);
    let mut buf = MemBuffer::new(evaluate_scratch(b.functions().len()));
    evaluate(&b.functions(), pts, &mut phi, &mut grad, MemStack::new(&mut buf));
    let size = mesh.element_diameter(0);
    let (mut phi_products, mut grad_products) = (vec![0.0; k * nq], vec![0.0; 3 * k * nq]);
    let mut work = EvaluationWork::default();
    b.evaluate(pts, &mut phi_products, &mut grad_products, &mut work);
    let (mut phi_alone, mut grad_alone) = (vec![0.0; k * nq], vec![0.0; 3 * k * nq]);
    b.values(pts, &mut phi_alone, &mut work);
    b.gradients(pts, &mut grad_alone, &mut work);
    prop_assert!(phi_alone == phi_products && grad_alone == grad_products, "values or gradients alone differ");
    let apart = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    prop_assert!(apart(&phi, &phi_products) < 1e-11, "values by products differ by {}", apart(&phi, &phi_products));
    prop_assert!(
        apart(&grad, &grad_products) < 1e-11 / size,
        "gradients by products differ by {}",
        apart(&grad, &grad_products)
    );
    for q in 0..nq {
        let sum: f64 = (0..k).map(|a| phi[a * nq + q]).sum();
        prop_assert!((sum - 1.0).abs() < 1e-12, "partition of unity {sum}");
        for i in 0..3 {
            let x: f64 = (0..k).map(|a| phi[a * nq + q] * nodes[a][i]).sum();
            prop_assert!((x - pts[q][i]).abs() < 1e-12 * size, "linear reproduction {}", x - pts[q][i]);
            for j in 0..3 {
                let g: f64 = (0..k).map(|a| grad[(3 * a + j) * nq + q] * nodes[a][i]).sum();
                let want = if i == j { 1.0 } else { 0.0 };
                prop_assert!((g - want).abs() < 1e-11, "sum x_a grad phi_a = I: {g}");
            }
        }
    }
    let (mut phi, mut grad) = (vec![0.0; k * k], vec![0.0; 3 * k * k]);
    let mut buf = MemBuffer::new(evaluate_scratch(b.functions().len()));
    evaluate(&b.functions(), &nodes, &mut phi, &mut grad, MemStack::new(&mut buf));
    let lagrange = (0..k)
        .flat_map(|a| (0..k).map(move |c| (a, c)))
        .map(|(a, c)| (phi[a * k + c] - if a == c { 1.0 } else { 0.0 }).abs())
        .fold(0.0, f64::max);
    Ok(lagrange)
}

/// The error of the element's functions against their boundary values at
/// points that are not collocation points: a face grid of a spacing the fit
/// does not use (the faces' own functions give the targets there; nodes
/// off a face are 0 on it), and points at odd fractions of every edge
/// (where the targets are linear). Returns the RMS and the largest error.
fn off_collocation_error(mesh: &PolyMesh, b: &ElementBasis, options: &HarmonicOptions) -> (f64, f64) {
    let faces = face_bases(mesh, &[0], options).unwrap();
    let el = &mesh.elements[0];
    let k = el.nodes.len();
    let h = 0.0917 * mesh.element_diameter(0);
    let mut points: Vec<[f64; 3]> = Vec::new();
    let mut targets: Vec<Vec<f64>> = Vec::new();
    for r in &el.faces {
        let face = &mesh.faces[r.face as usize];
        let basis = faces[r.face as usize].as_ref().expect("face basis");
        basis.interior_samples(&mesh.nodes, face, h, |p, vals| {
            let mut t = vec![0.0; k];
            for (j, &v) in face.vertices.iter().enumerate() {
                t[el.nodes.binary_search(&v).unwrap()] = vals[j];
            }
            points.push(p);
            targets.push(t);
        });
        for (j, &a) in face.vertices.iter().enumerate() {
            let c = face.vertices[(j + 1) % face.vertices.len()];
            for s in [0.13, 0.41, 0.77] {
                let (pa, pc) = (mesh.nodes[a as usize], mesh.nodes[c as usize]);
                points.push(std::array::from_fn(|i| pa[i] + s * (pc[i] - pa[i])));
                let mut t = vec![0.0; k];
                t[el.nodes.binary_search(&a).unwrap()] = 1.0 - s;
                t[el.nodes.binary_search(&c).unwrap()] = s;
                targets.push(t);
            }
        }
    }
    let nq = points.len();
    let (mut phi, mut grad) = (vec![0.0; k * nq], vec![0.0; 3 * k * nq]);
    let mut buf = MemBuffer::new(evaluate_scratch(b.functions().len()));
    evaluate(&b.functions(), &points, &mut phi, &mut grad, MemStack::new(&mut buf));
    let (mut sum, mut worst, mut count) = (0.0, 0.0f64, 0usize);
    for (q, t) in targets.iter().enumerate() {
        for a in 0..k {
            let e = (phi[a * nq + q] - t[a]).abs();
            sum += e * e;
            worst = worst.max(e);
            count += 1;
        }
    }
    ((sum / count as f64).sqrt(), worst)
}

/// Bounds of the MFS fit error (not exactness: the boundary values are
/// fitted in the least-squares sense). martin2008 reports L2 boundary
/// errors of 2-3 % with 5 samples per edge; with the default 3 we require
/// an RMS below 3 % and a Lagrange defect at the nodes below 25 % (the
/// hat functions' kinks at corners are where MFS fits worst).
const MAX_RMS: f64 = 0.03;
const MAX_LAGRANGE: f64 = 0.25;
/// Away from the collocation points the error is about the same (measured
/// up to 3.1 %, on six-tipped stars with thin tips).
const MAX_RMS_AWAY: f64 = 0.04;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Random convex polyhedra (a box clipped by random planes). Elements
    /// with almost coincident nodes (an edge below 5 % of the diameter) are
    /// skipped: MFS cannot tell such nodes apart (martin2008 §5 merges them
    /// into one joint function); cuts make them rare (they snap nodes onto
    /// the plane and leave no part flatter than `SplitOptions::min_quality`).
    #[test]
    fn convex_elements_reproduce_linear_fields(seed in 0u64..1_000_000, planes in 1usize..6) {
        let mesh = clipped_box([0.0; 3], [1.0, 0.8, 1.2], planes, seed).unwrap();
        prop_assume!(shortest_edge(&mesh) > 0.05 * mesh.element_diameter(0));
        let opts = HarmonicOptions::default();
        let (b, fit, pts) = basis(&mesh, &opts);
        let lagrange = check_reproduction(&mesh, &b, &pts)?;
        prop_assert!(lagrange < MAX_LAGRANGE && fit.rms < MAX_RMS, "lagrange {lagrange:.2e} rms {:.2e}", fit.rms);
        let (rms, _) = off_collocation_error(&mesh, &b, &opts);
        prop_assert!(rms < MAX_RMS_AWAY, "rms away from the collocation points {rms:.2e}");
    }

    /// Random non-convex prisms: stars with 3 to 6 tips and L shapes, no
    /// taller than wide, L arms at least 0.4 wide and star tips at least
    /// 0.45 wide at their base (`2 r_in sin(π / tips)`). (The kernel offset
    /// is a fraction of the element's diameter, so on a tall prism with a
    /// thin arm the kernels sit further from the arm than its width and the
    /// RMS error passes 3 %: 3.5 % for arms of 0.3 on a prism of height
    /// 1.5; 3.0-3.1 % for the 0.40-wide tips of a six-tipped star with
    /// `r_in` = 0.4 and a height of 0.9 to 0.99, against 2.5 % at 0.45.)
    #[test]
    fn nonconvex_elements_reproduce_linear_fields(
        tips in 3usize..7, r_in in 0.4f64..0.7, twist in 0.0f64..1.0, height in 0.3f64..1.0,
    ) {
        prop_assume!(2.0 * r_in * (std::f64::consts::PI / tips as f64).sin() >= 0.45);
        let mesh = prism(&star(tips, r_in, 1.0, twist), height).unwrap();
        let opts = HarmonicOptions::default();
        let (b, fit, pts) = basis(&mesh, &opts);
        let lagrange = check_reproduction(&mesh, &b, &pts)?;
        prop_assert!(lagrange < MAX_LAGRANGE && fit.rms < MAX_RMS, "lagrange {lagrange:.2e} rms {:.2e}", fit.rms);
        let (rms, _) = off_collocation_error(&mesh, &b, &opts);
        prop_assert!(rms < MAX_RMS_AWAY, "star: rms away from the collocation points {rms:.2e}");
        let mesh = prism(&l_shape(r_in, 1.0 - r_in), height).unwrap();
        let (b, fit, pts) = basis(&mesh, &opts);
        let lagrange = check_reproduction(&mesh, &b, &pts)?;
        prop_assert!(lagrange < MAX_LAGRANGE && fit.rms < MAX_RMS, "lagrange {lagrange:.2e} rms {:.2e}", fit.rms);
        let (rms, _) = off_collocation_error(&mesh, &b, &opts);
        prop_assert!(rms < MAX_RMS_AWAY, "L: rms away from the collocation points {rms:.2e}");
    }
}

/// The fit error of the boundary values falls as kernels are added.
#[test]
fn boundary_error_falls_with_more_kernels() {
    let mesh = prism(&star(5, 0.5, 1.0, 0.2), 0.8).unwrap();
    let mut last = f64::INFINITY;
    for samples in [1, 2, 3, 5] {
        let opts = HarmonicOptions { edge_samples: samples, ..Default::default() };
        let t = std::time::Instant::now();
        let (b, fit, _) = basis(&mesh, &opts);
        let (rms, max) = off_collocation_error(&mesh, &b, &opts);
        println!(
            "star prism (k = {}), {samples} samples per edge ({:.2} ms): {} kernels, error rms {:.2e} at the collocation points, rms {rms:.2e} (max {max:.2e}) away from them",
            b.linear.len(),
            t.elapsed().as_secs_f64() * 1e3,
            b.centres.len(),
            fit.rms,
        );
        assert!(rms < last, "{samples} samples: rms {rms} not below {last}");
        last = rms;
    }
}

/// The element store's fit, which skips measuring the error, gives the
/// same functions, bit for bit.
#[test]
fn measuring_the_fit_error_changes_nothing_else() {
    let mesh = prism(&star(4, 0.5, 1.0, 0.1), 0.7).unwrap();
    let options = HarmonicOptions::default();
    let faces = face_bases(&mesh, &[0], &options).unwrap();
    let plain = element_basis(&mesh, 0, &faces, &options).expect("fit");
    let (measured, fit) = element_basis_measured(&mesh, 0, &faces, &options).expect("fit");
    assert_eq!(
        (&plain.centres, &plain.weights, &plain.linear),
        (&measured.centres, &measured.weights, &measured.linear)
    );
    assert!(fit.rms > 0.0 && fit.rms <= fit.max && fit.max < 0.25, "{fit:?}");
}
