//! Mean value shape functions on random convex polyhedra with 4 to ~40
//! vertices: partition of unity, linear reproduction, positivity, gradients
//! against finite differences, face continuity, SIMD against scalar, and
//! the linear tetrahedron as the k = 4 case.

use cleave::mesh::Plane;
use cleave::mesh::PolyMesh;
use cleave::meshing::box_hex;
use cleave::topology::{split_by_plane, SplitOptions};
use cleave_kernels::dyn_stack::{MemBuffer, MemStack};
use cleave_kernels::mean_value::{evaluate, evaluate_scalar, evaluate_scratch};
use cleave_kernels::vec3::{add, dot, norm, scale, sub};
use proptest::prelude::*;

/// A convex polyhedron: vertices and outward triangles in local indices.
#[derive(Clone, Debug)]
struct Polyhedron {
    vertices: Vec<[f64; 3]>,
    triangles: Vec<[u32; 3]>,
}

/// Element `e` of `mesh` as a [`Polyhedron`].
fn polyhedron(mesh: &PolyMesh, e: usize) -> Polyhedron {
    let nodes = &mesh.elements[e].nodes;
    Polyhedron {
        vertices: nodes.iter().map(|&v| mesh.nodes[v as usize]).collect(),
        triangles: mesh.element_triangles(e).map(|t| t.map(|g| nodes.binary_search(&g).unwrap() as u32)).collect(),
    }
}

/// The unit cube clipped by `planes` planes tangent to spheres of radius
/// 0.25..0.45 around its centre: a convex polyhedron with 4 to ~40 vertices.
fn clipped_cube(dirs: &[(f64, f64, f64)]) -> Polyhedron {
    let mut mesh = box_hex([0.0; 3], [1.0; 3], [1, 1, 1]).unwrap();
    for &(z, phi, r) in dirs {
        let s = (1.0 - z * z).sqrt();
        let n = [s * phi.cos(), s * phi.sin(), z];
        let point = add([0.5; 3], scale(n, r));
        // the positive side (kept as element 0) contains the centre
        split_by_plane(&mut mesh, &Plane { point, normal: scale(n, -1.0) }, &SplitOptions::exact()).unwrap();
    }
    polyhedron(&mesh, 0)
}

fn polyhedron_strategy() -> impl Strategy<Value = Polyhedron> {
    prop::collection::vec((-1.0f64..1.0, 0.0f64..std::f64::consts::TAU, 0.25f64..0.45), 0..22)
        .prop_map(|d| clipped_cube(&d))
}

/// Points strictly inside: convex combinations of the centroid and vertices.
fn interior_points(p: &Polyhedron, seed: u64) -> Vec<[f64; 3]> {
    let k = p.vertices.len();
    let c = scale(p.vertices.iter().fold([0.0; 3], |a, &v| add(a, v)), 1.0 / k as f64);
    (0..9)
        .map(|i| {
            let j = (seed as usize + 7 * i) % k;
            let t = 0.05 + 0.9 * (((seed + i as u64 * 31) % 97) as f64 / 97.0);
            add(c, scale(sub(p.vertices[j], c), t))
        })
        .collect()
}

fn diameter(p: &Polyhedron) -> f64 {
    let mut d: f64 = 0.0;
    for a in &p.vertices {
        for b in &p.vertices {
            d = d.max(norm(sub(*a, *b)));
        }
    }
    d
}

fn eval(p: &Polyhedron, pts: &[[f64; 3]]) -> (Vec<f64>, Vec<f64>) {
    let k = p.vertices.len();
    let (mut phi, mut grad) = (vec![0.0; k * pts.len()], vec![0.0; 3 * k * pts.len()]);
    let mut buf = MemBuffer::new(evaluate_scratch(p.vertices.len(), p.triangles.len()));
    evaluate(&p.vertices, &p.triangles, pts, &mut phi, &mut grad, MemStack::new(&mut buf));
    (phi, grad)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn partition_of_unity_and_linear_reproduction(p in polyhedron_strategy(), seed in 0u64..1000) {
        let k = p.vertices.len();
        prop_assert_eq!(p.triangles.len(), 2 * k - 4);
        let pts = interior_points(&p, seed);
        let nq = pts.len();
        let (phi, grad) = eval(&p, &pts);
        let h = diameter(&p);
        for (q, x) in pts.iter().enumerate() {
            let sum: f64 = (0..k).map(|a| phi[a * nq + q]).sum();
            prop_assert!((sum - 1.0).abs() < 1e-12, "sum {}", sum);
            for a in 0..k {
                prop_assert!(phi[a * nq + q] > 0.0, "positivity: phi_{} = {}", a, phi[a * nq + q]);
            }
            for i in 0..3 {
                let xi: f64 = (0..k).map(|a| phi[a * nq + q] * p.vertices[a][i]).sum();
                prop_assert!((xi - x[i]).abs() < 1e-12 * h, "x_{}: {} vs {}", i, xi, x[i]);
                let g: f64 = (0..k).map(|a| grad[(3 * a + i) * nq + q]).sum();
                prop_assert!(g.abs() < 1e-12 / h * k as f64, "sum of gradients {}", g);
                for j in 0..3 {
                    // Σ_a x_a[j] ∂_i φ_a = δ_ij
                    let m: f64 = (0..k).map(|a| p.vertices[a][j] * grad[(3 * a + i) * nq + q]).sum();
                    let want = if i == j { 1.0 } else { 0.0 };
                    prop_assert!((m - want).abs() < 1e-12 * k as f64, "grad reproduction {} {}: {}", i, j, m);
                }
            }
        }
    }

    #[test]
    fn gradients_match_central_differences(p in polyhedron_strategy(), seed in 0u64..1000) {
        let k = p.vertices.len();
        let pts = interior_points(&p, seed);
        let (_, grad) = eval(&p, &pts);
        let h = 1e-4 * diameter(&p);
        // central differences with one Richardson step: error O(h^4)
        let central = |x: [f64; 3], i: usize, h: f64| {
            let (mut xp, mut xm) = (x, x);
            xp[i] += h;
            xm[i] -= h;
            let (fp, _) = eval(&p, &[xp]);
            let (fm, _) = eval(&p, &[xm]);
            fp.iter().zip(&fm).map(|(a, b)| (a - b) / (2.0 * h)).collect::<Vec<f64>>()
        };
        for (q, x) in pts.iter().enumerate() {
            for i in 0..3 {
                let (d1, d2) = (central(*x, i, h), central(*x, i, 0.5 * h));
                let scale_g = (0..k).map(|a| grad[(3 * a + i) * pts.len() + q].abs()).fold(0.0, f64::max);
                for a in 0..k {
                    let fd = (4.0 * d2[a] - d1[a]) / 3.0;
                    let g = grad[(3 * a + i) * pts.len() + q];
                    prop_assert!((fd - g).abs() < 1e-6 * scale_g.max(1e-3), "a {} i {}: fd {} vs {}", a, i, fd, g);
                }
            }
        }
    }

    #[test]
    fn simd_matches_scalar_reference(p in polyhedron_strategy(), seed in 0u64..1000) {
        let k = p.vertices.len();
        let pts = interior_points(&p, seed);
        let (phi, grad) = eval(&p, &pts);
        let (mut phi_s, mut grad_s) = (vec![0.0; phi.len()], vec![0.0; grad.len()]);
        let mut buf = MemBuffer::new(evaluate_scratch(p.vertices.len(), p.triangles.len()));
        evaluate_scalar(&p.vertices, &p.triangles, &pts, &mut phi_s, &mut grad_s, MemStack::new(&mut buf));
        for (a, b) in phi.iter().zip(&phi_s) {
            prop_assert!((a - b).abs() <= 1e-13 * b.abs().max(1.0 / k as f64), "{} vs {}", a, b);
        }
        let gmax = grad_s.iter().fold(0.0f64, |m, g| m.max(g.abs()));
        for (a, b) in grad.iter().zip(&grad_s) {
            prop_assert!((a - b).abs() <= 1e-13 * gmax, "{} vs {}", a, b);
        }
    }

    #[test]
    fn values_on_a_face_are_the_triangle_interpolation(p in polyhedron_strategy(), t in 0usize..1000, w in (0.2f64..1.0, 0.2f64..1.0, 0.2f64..1.0)) {
        let k = p.vertices.len();
        let tri = p.triangles[t % p.triangles.len()];
        let (a, b, c) = (p.vertices[tri[0] as usize], p.vertices[tri[1] as usize], p.vertices[tri[2] as usize]);
        // a barycentric point of the triangle away from its edges (the
        // approach to the face is uniform only there), approached from inside
        let sum = w.0 + w.1 + w.2;
        let (l0, l1, l2) = (w.0 / sum, w.1 / sum, w.2 / sum);
        let on = add(add(scale(a, l0), scale(b, l1)), scale(c, l2));
        // the triangles are outward, so the inward normal is -(b - a) × (c - a)
        let inward = scale(cleave_kernels::vec3::cross(sub(b, a), sub(c, a)), -1.0);
        // approach the face along its inward normal and extrapolate the
        // values linearly to the face (offsets of 1e-4 and 2e-4 of the
        // triangle's in-radius: cut elements carry triangles down to 1e-4 of
        // the element, and the approach is linear in offset / in-radius)
        let area2 = norm(cleave_kernels::vec3::cross(sub(b, a), sub(c, a)));
        let inradius = area2 / (norm(sub(b, a)) + norm(sub(c, b)) + norm(sub(a, c)));
        let offset = |d: f64| eval(&p, &[add(on, scale(inward, d * inradius / norm(inward)))]).0;
        // sliver triangles (from snapped cuts, in-radius down to 1e-6 of the
        // element) cannot be approached closer than rounding allows; the
        // quadrature never comes near them, so they are not tested here
        prop_assume!(inradius > 1e-3 * diameter(&p));
        let (near, far) = (offset(1e-4), offset(2e-4));
        let phi: Vec<f64> = near.iter().zip(&far).map(|(n, f)| 2.0 * n - f).collect();
        let mut want = vec![0.0; k];
        want[tri[0] as usize] += l0;
        want[tri[1] as usize] += l1;
        want[tri[2] as usize] += l2;
        for j in 0..k {
            prop_assert!((phi[j] - want[j]).abs() < 1e-6, "phi_{} = {} vs {}", j, phi[j], want[j]);
        }
    }
}

#[test]
fn vertex_counts_cover_4_to_40() {
    let mut seen = std::collections::BTreeSet::new();
    for n in 0..22 {
        let dirs: Vec<_> =
            (0..n).map(|i| ((i as f64 * 0.37).sin(), i as f64 * 2.39996, if n > 12 { 0.3 } else { 0.45 })).collect();
        seen.insert(clipped_cube(&dirs).vertices.len());
    }
    // a single corner cut leaves a tetrahedron-free cube; the tetrahedron case is tested separately
    assert!(*seen.iter().next_back().unwrap() >= 36, "largest element has {:?} vertices", seen);
}

#[test]
fn tetrahedron_gives_the_linear_element() {
    let vertices = vec![[0.1, 0.0, 0.2], [1.3, 0.1, 0.0], [0.2, 0.9, -0.1], [0.3, 0.2, 1.1]];
    let mesh = PolyMesh::from_cells(vertices.clone(), &[cleave::mesh::Cell::Tet([0, 1, 2, 3])]).unwrap();
    let p = polyhedron(&mesh, 0);
    let (vol, g) =
        cleave_kernels::tet::gradients(&[p.vertices[0], p.vertices[1], p.vertices[2], p.vertices[3]]).unwrap();
    assert!(vol.abs() > 0.0);
    let pts = interior_points(&p, 3);
    let (phi, grad) = eval(&p, &pts);
    let nq = pts.len();
    for (q, x) in pts.iter().enumerate() {
        for a in 0..4 {
            // λ_a(x) = λ_a(x_0) + g_a · (x - x_0), with λ_a(x_0) = δ_a0
            let lin = if a == 0 { 1.0 } else { 0.0 } + dot(g[a], sub(*x, p.vertices[0]));
            assert!((phi[a * nq + q] - lin).abs() < 1e-12, "phi {} vs {}", phi[a * nq + q], lin);
            for i in 0..3 {
                assert!((grad[(3 * a + i) * nq + q] - g[a][i]).abs() < 1e-12 * norm(g[a]));
            }
        }
    }
}
