//! Harmonic elements in the store and in simulations: the cube against the
//! trilinear hexahedron, the patch test on a mesh mixing tetrahedra,
//! hexahedra, convex and non-convex polyhedra (cantilever convergence is in
//! `tests/integration/convergence.rs`).

use crate::common;

use cleave::material::Material;
use cleave::mesh::Plane;
use cleave::mesh::PolyMesh;
use cleave::meshing::box_l_prisms;
use cleave::sim::{Simulation, SimulationParams};
use cleave::store::{BasisOptions, ElementKind, ElementStore, Family, HarmonicOptions};
use cleave::topology::{split_elements_by_plane, SplitOptions};

fn harmonic(trilinear_hexahedra: bool) -> BasisOptions {
    BasisOptions {
        family: Family::Harmonic,
        harmonic: HarmonicOptions { trilinear_hexahedra, ..Default::default() },
        ..Default::default()
    }
}

fn material() -> Material {
    Material::new(1e5, 0.3, 1000.0).unwrap()
}

/// On a box the harmonic element is the trilinear one up to the MFS error:
/// as kernels and quadrature points are added, its K_e converges to the
/// closed form's (measured: 4.8e-2 with the defaults, whose stiffness takes
/// the 4-point rule of degree 2, against 5.8e-2 with the 8-point rule of
/// degree 1 the masses keep; 1.1e-2 with 5 samples per edge, 1.7e-3 with 8)
/// and the lumped masses to 1/8.
#[test]
fn harmonic_box_converges_to_trilinear_hexahedron() {
    let mesh = cleave::meshing::box_hex([0.0; 3], [1.0, 0.7, 0.5], [1, 1, 1]).unwrap();
    let exact = ElementStore::build(&mesh, &material(), &harmonic(true)).unwrap();
    assert_eq!(exact.batches[0].kind, ElementKind::Trilinear);
    assert!(exact.batches[0].mass_fraction.iter().all(|m| (m - 0.125).abs() < 1e-12));
    let norm = |m: &[f64]| m.iter().map(|x| x * x).sum::<f64>().sqrt();
    let a = exact.batches[0].element_matrix(0);
    let mut last = f64::INFINITY;
    for (edge_samples, quadrature_order) in [(3, 2), (5, 3), (8, 3)] {
        let mut options = harmonic(false);
        options.harmonic.edge_samples = edge_samples;
        options.harmonic.quadrature_order = quadrature_order;
        let fitted = ElementStore::build(&mesh, &material(), &options).unwrap();
        assert_eq!(fitted.batches[0].kind, ElementKind::Harmonic);
        assert!((fitted.batches[0].volume[0] - 0.35).abs() < 1e-14);
        let b = fitted.batches[0].element_matrix(0);
        let diff: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
        let rel = norm(&diff) / norm(&a);
        let mass = fitted.batches[0].mass_fraction.iter().map(|m| (m - 0.125).abs()).fold(0.0, f64::max);
        println!("box, {edge_samples} samples per edge: |K_harmonic - K_trilinear| / |K_trilinear| = {rel:.2e}, mass {mass:.1e}");
        assert!(rel < 0.7 * last && mass < 1e-3, "{rel} after {last}, mass {mass}");
        if edge_samples == 3 {
            assert!(rel < 5e-2, "the degree-2 stiffness rule: {rel}");
        }
        last = rel;
    }
    assert!(last < 5e-3, "{last}");
}

/// Every K_e of the mixed mesh has exactly the rigid motions in its null
/// space, no negative eigenvalue and a healthy seventh eigenvalue (by a
/// full eigendecomposition, [`common::spectra`]).
fn check_element_matrices(store: &ElementStore) {
    let summary = common::spectra(store, 1e-4);
    println!("mixed mesh spectra: {summary:?}");
}

/// A mesh of L-prisms and hexahedra, with some hexahedra split by planes
/// through three corners (a tetrahedron and a 7-node piece) and by oblique
/// planes (convex polyhedra whose neighbours gain nodes).
fn mixed_mesh() -> PolyMesh {
    let mut mesh = box_l_prisms([0.0; 3], [1.0, 1.0, 0.5], [4, 4, 2]).unwrap();
    let hexes: Vec<u32> =
        (0..mesh.elements.len() as u32).filter(|&e| mesh.elements[e as usize].nodes.len() == 8).collect();
    let corner = |e: u32| {
        let c = mesh.element_centroid(e as usize);
        Plane { point: [c[0] + 0.125, c[1], c[2]], normal: [1.0, 1.0, 1.0] }
    };
    let plane = corner(hexes[0]);
    split_elements_by_plane(&mut mesh, &plane, &[hexes[0]], &SplitOptions::default()).unwrap();
    let c = mesh.element_centroid(hexes[3] as usize);
    let oblique = Plane { point: c, normal: [0.3, -1.0, 0.4] };
    split_elements_by_plane(&mut mesh, &oblique, &[hexes[3]], &SplitOptions::default()).unwrap();
    mesh
}

#[test]
fn patch_test_on_mixed_mesh() {
    let mesh = mixed_mesh();
    let store = ElementStore::build(&mesh, &material(), &harmonic(true)).unwrap();
    let kinds: Vec<(ElementKind, usize, usize)> = store.batches.iter().map(|b| (b.kind, b.k, b.len())).collect();
    println!("mixed mesh batches (kind, nodes, elements): {kinds:?}");
    for kind in [ElementKind::LinearTet, ElementKind::Trilinear, ElementKind::Harmonic] {
        assert!(kinds.iter().any(|k| k.0 == kind), "no {kind:?} element");
    }
    let nonconvex = (0..mesh.elements.len()).filter(|&e| !mesh.is_convex(e, 1e-9)).count();
    let convex_harmonic = store
        .batches
        .iter()
        .filter(|b| b.kind == ElementKind::Harmonic)
        .flat_map(|b| b.elements.iter())
        .filter(|&&e| mesh.is_convex(e as usize, 1e-9))
        .count();
    assert!(nonconvex > 0 && convex_harmonic > 0, "{nonconvex} non-convex, {convex_harmonic} convex harmonic");
    check_element_matrices(&store);
    let volume: f64 = store.total_volume();
    assert!((volume - 0.5).abs() < 1e-12, "volume {volume}");
    let (err, interior) = common::patch_error(mesh, harmonic(true));
    println!("patch test, mixed harmonic mesh: error {err:.2e} over {interior} interior nodes");
    assert!(interior > 0 && err < 1e-9, "{err}");
}

/// A single non-convex element (martin2008 Fig. 1): rotated rigidly by 90°
/// it carries no elastic force with warping, and in free fall its centre of
/// mass follows gravity exactly while it stays finite.
#[test]
fn nonconvex_element_has_no_ghost_forces_and_falls_freely() {
    let outline: Vec<[f64; 2]> = (0..10)
        .map(|i| {
            let a = std::f64::consts::PI * i as f64 / 5.0;
            let r = if i % 2 == 0 { 1.0 } else { 0.45 };
            [r * a.cos(), r * a.sin()]
        })
        .collect();
    let mesh = cleave::meshing::prism(&outline, 0.4).unwrap();
    assert!(!mesh.is_convex(0, 1e-9));
    let params = SimulationParams { material: material(), basis: harmonic(true), ..Default::default() };
    let mut sim = Simulation::new(mesh, params).unwrap();
    let u: Vec<[f64; 3]> = sim.mesh().nodes.iter().map(|x| [-x[1] - x[0], x[0] - x[1], 0.0]).collect();
    sim.set_displacements(&u).unwrap();
    let weight: f64 = sim.masses().iter().sum::<f64>() * 9.81;
    let ghost = sim.elastic_forces().iter().flatten().map(|f| f.abs()).fold(0.0, f64::max) / weight;
    println!("star prism rotated by 90 degrees: largest elastic force {ghost:.1e} of its weight");
    assert!(ghost < 1e-9, "{ghost}");
    sim.set_displacements(&vec![[0.0; 3]; u.len()]).unwrap();
    let steps = 100;
    for _ in 0..steps {
        sim.step().unwrap();
    }
    let p = sim.linear_momentum();
    let mass: f64 = sim.masses().iter().sum();
    let t = steps as f64 * sim.params().dt;
    assert!((p[2] / mass + 9.81 * t).abs() < 1e-9 * 9.81 * t, "vertical velocity {}", p[2] / mass);
    assert!(sim.positions().iter().flatten().all(|x| x.is_finite()));
}

/// A U-shaped prism with tall arms is not star-shaped: no cone from one
/// point integrates it. It is integrated over the pieces a grid cuts it
/// into instead: exact volume, positive weights, a healthy stiffness (the
/// store's check: six rigid modes and `λ7/λmax` above its floor).
#[test]
fn non_star_shaped_element_is_integrated_over_its_pieces() {
    let u = [[0.0, 0.0], [3.0, 0.0], [3.0, 5.0], [2.0, 5.0], [2.0, 1.0], [1.0, 1.0], [1.0, 5.0], [0.0, 5.0]];
    let mesh = cleave::meshing::prism(&u, 1.0).unwrap();
    let verts = mesh.nodes.clone();
    let triangles: Vec<[u32; 3]> = mesh.element_triangles(0).collect();
    assert!(cleave::store::harmonic::star_point(&verts, &triangles, mesh.element_diameter(0)).is_none());
    // the rules the store builds it with: over the pieces, all weights positive
    let order = HarmonicOptions::default().quadrature_order;
    let rules = cleave::store::harmonic::element_rules(&verts, &triangles, mesh.element_diameter(0), order).unwrap();
    for (_, weights) in [rules.stiffness(), &rules.mass] {
        assert!(weights.iter().all(|&w| w >= 0.0));
        assert!((weights.iter().sum::<f64>() - 11.0).abs() < 1e-12);
    }
    let store = ElementStore::build(&mesh, &material(), &harmonic(true)).unwrap();
    let b = &store.batches[0];
    assert!((b.volume[0] - 11.0).abs() < 1e-12, "volume {}", b.volume[0]);
    let ratio = b.stiffness_spectrum(0).ratio();
    println!("{} quadrature points, λ7/λmax {ratio:.2e}", b.points_per_element);
    assert!(ratio > 1e-4);
}

/// Copies of an element moved by a translation share one fit (the store
/// fits each shape once): each copy's `K_e` is the one the copy gets when
/// built alone, to rounding. A copy scaled by `1 + 1e-6` is another shape
/// and is fitted on its own: a cache that took it for the first (a key
/// relative to the diameter is blind to scale) would give it a `K_e` off
/// by 1e-6.
#[test]
fn translated_copies_share_a_fit_and_scaled_ones_do_not() {
    let one = cleave::meshing::element_with_vertices(12).unwrap();
    let mut mesh = cleave::meshing::replicate(&one, 3).unwrap();
    let per = one.nodes.len();
    let first = mesh.nodes[2 * per];
    mesh.nodes[2 * per..]
        .iter_mut()
        .for_each(|p| *p = std::array::from_fn(|d| first[d] + (1.0 + 1e-6) * (p[d] - first[d])));
    let options = harmonic(false);
    let together = ElementStore::build(&mesh, &material(), &options).unwrap();
    let b = &together.batches[0];
    assert_eq!((b.kind, b.len()), (ElementKind::Harmonic, 3));
    let n = (3 * b.k) * (3 * b.k);
    for e in 0..3 {
        let (alone_mesh, _) = mesh.extract(&[e]).unwrap();
        let alone = ElementStore::build(&alone_mesh, &material(), &options).unwrap();
        let i = b.elements.iter().position(|&x| x as usize == e).unwrap();
        let (shared, own) = (&b.stiffness[i * n..(i + 1) * n], &alone.batches[0].stiffness[..n]);
        let scale = own.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let diff = shared.iter().zip(own).fold(0.0f64, |m, (a, b)| m.max((a - b).abs())) / scale;
        println!("copy {e}: K_e differs from its own fit by {diff:.2e}");
        assert!(diff < 1e-9, "copy {e}: K_e differs from its own fit by {diff:.2e}");
    }
}
