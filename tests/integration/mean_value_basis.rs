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

/// The distance between the two closest vertices.
fn closest_vertices(p: &Polyhedron) -> f64 {
    let v = &p.vertices;
    (0..v.len()).flat_map(|a| (a + 1..v.len()).map(move |b| norm(sub(v[a], v[b])))).fold(f64::INFINITY, f64::min)
}

/// The first gradient `grad` (as [`eval`] lays them out at `pts`) that
/// central differences of step `h` with one Richardson step (error
/// `O(h⁴)`) miss by more than 1e-6 of the largest at its point and
/// direction (at least 1e-3): `(vertex, direction, difference, gradient)`.
fn gradient_mismatch(p: &Polyhedron, pts: &[[f64; 3]], grad: &[f64], h: f64) -> Option<(usize, usize, f64, f64)> {
    let k = p.vertices.len();
    let central = |x: [f64; 3], i: usize, h: f64| {
        let (mut xp, mut xm) = (x, x);
        xp[i] += h;
        xm[i] -= h;
        let (fp, _) = eval(p, &[xp]);
        let (fm, _) = eval(p, &[xm]);
        fp.iter().zip(&fm).map(|(a, b)| (a - b) / (2.0 * h)).collect::<Vec<f64>>()
    };
    for (q, x) in pts.iter().enumerate() {
        for i in 0..3 {
            let (d1, d2) = (central(*x, i, h), central(*x, i, 0.5 * h));
            let scale_g = (0..k).map(|a| grad[(3 * a + i) * pts.len() + q].abs()).fold(0.0, f64::max);
            for a in 0..k {
                let fd = (4.0 * d2[a] - d1[a]) / 3.0;
                let g = grad[(3 * a + i) * pts.len() + q];
                let miss = (fd - g).abs();
                if miss.is_nan() || miss >= 1e-6 * scale_g.max(1e-3) {
                    return Some((a, i, fd, g));
                }
            }
        }
    }
    None
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
        // vertices a few 1e-7 apart (several clipping planes meeting near
        // one point, which no split of the engine makes: see
        // `SplitOptions::min_spacing`) leave rounding of about 1e-11 in the
        // values, which differences over 1e-4 of the diameter divide by
        // it: such a polyhedron is checked with a longer step in
        // `gradients_at_clustered_vertices_match_longer_differences`
        prop_assume!(closest_vertices(&p) > 1e-3 * diameter(&p));
        let pts = interior_points(&p, seed);
        let (_, grad) = eval(&p, &pts);
        let h = 1e-4 * diameter(&p);
        if let Some((a, i, fd, g)) = gradient_mismatch(&p, &pts, &grad, h) {
            prop_assert!(false, "a {} i {}: fd {} vs {}", a, i, fd, g);
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

/// The cube clipped so that three vertices lie within 3e-7 of one another
/// (drawn by `gradients_match_central_differences` without a seed): the
/// values' rounding, about 1e-11, makes differences over 1e-4 of the
/// diameter miss the gradients by more than 1e-6 of them, and shorter
/// steps miss by more (that error grows as 1 / h); over 1e-3 of it the
/// truncation error (as h⁴, large next to the cluster) misses them too,
/// and 3e-4 of it, between the two, matches them. The partition of unity
/// and linear reproduction hold there.
#[test]
fn gradients_at_clustered_vertices_match_longer_differences() {
    let vertices = vec![
        [0.0, 1.0, 0.0],
        [0.75, 0.0, 1.0],
        [0.75, 1.0, 1.0],
        [0.46459776721376056, 1.0, 0.0],
        [0.46459776721376056, 0.0, 0.0],
        [0.75, 0.0, 0.42364494018854126],
        [0.75, 1.0, 0.42364494018854126],
        [0.658405662003986, 0.0, 1.0],
        [0.4981708808079671, 1.0, 1.0],
        [0.0, 1.0, 0.5526395491415868],
        [0.0, 0.6281575018428888, 0.0],
        [0.0, 0.8984280701331597, 0.5380241814842371],
        [0.3897676813418033, 0.0, 0.0],
        [0.05045226123737732, 0.35521192792440054, 0.0],
        [0.43615769215686717, 0.0, 0.8004199847411394],
        [0.10630159800671801, 0.3302204394189671, 0.5517232387643977],
        [0.46459776721376056, 0.6111685066166139, 0.0],
        [0.5243796669411174, 1.0, 0.08873896706099824],
        [0.1966601408663145, 1.0, 0.7292415398905139],
        [0.10630153843040502, 0.33022075786870153, 0.5517232310868149],
        [0.3192386757983024, 0.07383320223403812, 0.0],
        [0.1063015737741773, 0.33022045026255625, 0.5517229993764905],
    ];
    #[rustfmt::skip]
    let triangles = vec![
        [10, 0, 3], [3, 16, 10], [13, 10, 4], [12, 20, 4], [16, 4, 10], [20, 13, 4], [2, 8, 7], [7, 1, 2],
        [4, 5, 1], [7, 14, 12], [4, 1, 7], [12, 4, 7], [3, 0, 9], [9, 18, 3], [6, 17, 8], [8, 2, 6],
        [18, 8, 3], [17, 3, 8], [0, 10, 11], [0, 11, 9], [1, 6, 2], [6, 1, 5], [16, 5, 4], [16, 6, 5],
        [6, 16, 17], [17, 16, 3], [19, 8, 18], [19, 7, 8], [19, 14, 7], [14, 19, 15], [18, 11, 19], [11, 18, 9],
        [11, 10, 19], [15, 10, 21], [19, 10, 15], [21, 10, 13], [15, 12, 14], [12, 21, 20], [12, 15, 21], [20, 21, 13],
    ];
    let p = Polyhedron { vertices, triangles };
    assert!(closest_vertices(&p) < 1e-6 * diameter(&p));
    let pts = interior_points(&p, 0);
    let (phi, grad) = eval(&p, &pts);
    let h = diameter(&p);
    assert!(gradient_mismatch(&p, &pts, &grad, 1e-4 * h).is_some(), "the rounding no longer shows");
    assert_eq!(gradient_mismatch(&p, &pts, &grad, 3e-4 * h), None);
    let (k, nq) = (p.vertices.len(), pts.len());
    for (q, x) in pts.iter().enumerate() {
        assert!(((0..k).map(|a| phi[a * nq + q]).sum::<f64>() - 1.0).abs() < 1e-12);
        for (i, want) in x.iter().enumerate() {
            let xi: f64 = (0..k).map(|a| phi[a * nq + q] * p.vertices[a][i]).sum();
            assert!((xi - want).abs() < 1e-12 * h);
        }
    }
}
