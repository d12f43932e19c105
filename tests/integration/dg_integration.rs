//! Exact integration for the discontinuous Galerkin family: the moments the
//! divergence theorem gives (volume -> faces -> edges) against a Gauss rule
//! of high order on the signed sub-tetrahedra of each element's surface
//! triangles from its centroid (exact for polynomials of degree 9, and
//! valid for non-convex, even not star-shaped, elements since the signed
//! volumes cancel outside), and against closed forms.

use crate::common;

use cleave::material::Material;
use cleave::mesh::{Plane, PolyMesh};
use cleave::meshing::{box_l_prisms, box_tet, prism, random_convex};
use cleave::store::dg::{DgOptions, Flux};
use cleave::store::{BasisOptions, ElementStore, Family};
use cleave::topology::{cut_by_plane, SplitOptions};
use cleave_kernels::polynomial::{count, values, EXPONENTS};

fn basis(degree: usize) -> BasisOptions {
    BasisOptions { family: Family::Dg, dg: DgOptions { degree, flux: Flux::Ip, penalty: 1.0 }, ..Default::default() }
}

/// The meshes of the test: convex random cells, non-convex L-prisms, a
/// five-pointed star prism, and the pieces of a box of tetrahedra cut by
/// three planes as a simulation cuts (snapped).
fn meshes() -> Vec<(&'static str, PolyMesh)> {
    let star: Vec<[f64; 2]> = (0..10)
        .map(|i| {
            let (r, t) = (if i % 2 == 0 { 1.0 } else { 0.38 }, std::f64::consts::PI * i as f64 / 5.0);
            [r * t.cos() + 3.0, r * t.sin() - 2.0]
        })
        .collect();
    let mut cut = box_tet([0.5, -1.0, 2.0], [2.5, 1.0, 3.0], [4, 4, 2]).unwrap();
    for (p, n) in
        [([1.3, 0.0, 2.5], [1.0, 0.3, 0.1]), ([1.0, 0.2, 2.4], [0.2, 1.0, -0.4]), ([1.8, 0.0, 2.6], [0.3, -0.2, 1.0])]
    {
        cut_by_plane(&mut cut, &Plane { point: p, normal: n }, &SplitOptions::default()).unwrap();
    }
    vec![
        ("random convex", random_convex([-1.0, 2.0, 0.5], [1.0, 3.0, 2.0], 8, 5).unwrap()),
        ("L-prisms", box_l_prisms([10.0, 0.0, 0.0], [12.0, 2.0, 1.0], [2, 2, 1]).unwrap()),
        ("star prism", prism(&star, 0.7).unwrap()),
        ("cut tetrahedra", cut),
    ]
}

/// `∫ ξ^α dV_ξ` of element `e` in the frame `(c, s)` by the signed cone
/// rule (`n = 5` points per direction).
fn reference_moments(mesh: &PolyMesh, e: usize, frame: [f64; 4], d: usize) -> Vec<f64> {
    let (pts, wts) = common::element_cone_rule(mesh, e, 5);
    let s = frame[3];
    let mut out = vec![0.0; count(d)];
    let mut m = vec![0.0; count(4)];
    for (p, w) in pts.iter().zip(&wts) {
        let xi: [f64; 3] = std::array::from_fn(|k| (p[k] - frame[k]) / s);
        values(xi, d, &mut m);
        for (o, v) in out.iter_mut().zip(&m) {
            *o += w * v / (s * s * s);
        }
    }
    out
}

#[test]
fn moments_up_to_degree_four_match_a_high_order_rule_on_convex_and_non_convex_elements() {
    let material = Material::new(1e5, 0.3, 1.0).unwrap();
    for (name, mesh) in meshes() {
        let store = ElementStore::build(&mesh, &material, &basis(2)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let batch = &store.batches[0];
        let mut worst: f64 = 0.0;
        for (i, b) in batch.dg.iter().enumerate() {
            let e = batch.elements[i] as usize;
            let want = reference_moments(&mesh, e, b.frame, 4);
            let scale = want.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            for (alpha, (got, want)) in b.moments.iter().zip(&want).enumerate() {
                let error = (got - want).abs() / scale;
                worst = worst.max(error);
                assert!(error < 1e-12, "{name}, element {e}, monomial {:?}: {got} vs {want}", EXPONENTS[alpha]);
            }
            // volume and centroid in physical units
            let s = b.frame[3];
            let volume = s * s * s * b.moments[0];
            assert!((volume - mesh.element_volume(e)).abs() < 1e-12 * volume, "{name}: volume");
            let centroid: [f64; 3] = std::array::from_fn(|k| b.frame[k] + s * b.moments[1 + k] / b.moments[0]);
            let c = mesh.element_centroid(e);
            for k in 0..3 {
                assert!((centroid[k] - c[k]).abs() < 1e-12 * s, "{name}: centroid {centroid:?} vs {c:?}");
            }
        }
        println!("{name}: {} elements, worst relative moment error {worst:.1e}", batch.len());
    }
}

/// `∫ N_i N_j dV = V δ_ij` by the reference rule, for both degrees.
#[test]
fn bases_are_orthonormal_under_the_reference_rule() {
    let material = Material::new(1e5, 0.3, 1.0).unwrap();
    for (name, mesh) in meshes() {
        for degree in [1, 2] {
            let store = ElementStore::build(&mesh, &material, &basis(degree)).unwrap();
            let batch = &store.batches[0];
            let m = batch.k;
            for (i, b) in batch.dg.iter().enumerate() {
                let e = batch.elements[i] as usize;
                let (pts, wts) = common::element_cone_rule(&mesh, e, 4);
                let mut gram = vec![0.0; m * m];
                let mut n = vec![0.0; m];
                for (p, w) in pts.iter().zip(&wts) {
                    b.values(*p, &mut n);
                    for a in 0..m {
                        for c in 0..m {
                            gram[a * m + c] += w * n[a] * n[c];
                        }
                    }
                }
                let v = batch.volume[i];
                for a in 0..m {
                    for c in 0..m {
                        let want = if a == c { 1.0 } else { 0.0 };
                        let got = gram[a * m + c] / v;
                        assert!(
                            (got - want).abs() < 1e-11,
                            "{name}, degree {degree}, element {e}: G[{a}][{c}] = {got}"
                        );
                    }
                }
            }
        }
    }
}

/// A single tetrahedron: `∫ x^a y^b z^c` over the unit tetrahedron is
/// `a! b! c! / (a + b + c + 3)!`.
#[test]
fn the_unit_tetrahedron_has_its_closed_form_moments() {
    let mesh = PolyMesh::from_cells(
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        &[cleave::mesh::Cell::Tet([0, 1, 2, 3])],
    )
    .unwrap();
    let store = ElementStore::build(&mesh, &Material::new(1e5, 0.3, 1.0).unwrap(), &basis(2)).unwrap();
    let b = &store.batches[0].dg[0];
    let factorial = |n: u8| (1..=n as u64).product::<u64>() as f64;
    // moments of x^α from those of ξ^α: x = c + s ξ, so compare through the
    // reference rule's frame-free form: evaluate ∫ x^α via the basis frame
    let (c, s) = ([b.frame[0], b.frame[1], b.frame[2]], b.frame[3]);
    for (alpha, e) in EXPONENTS.iter().enumerate().take(count(4)) {
        let want = factorial(e[0]) * factorial(e[1]) * factorial(e[2]) / factorial(e[0] + e[1] + e[2] + 3);
        // ∫ x^α dV = s³ ∫ Π (c_k + s ξ_k)^α_k dξ, expanded with the substitution table
        let mut sub = vec![0.0; count(4) * count(4)];
        cleave_kernels::polynomial::substitution(s, c, 4, &mut sub);
        let got: f64 = (0..count(4)).map(|j| sub[alpha * count(4) + j] * b.moments[j]).sum::<f64>() * s * s * s;
        assert!((got - want).abs() < 1e-14, "{e:?}: {got} vs {want}");
    }
}
