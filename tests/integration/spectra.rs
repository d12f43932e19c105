//! The spectrum of every element kind, on random meshes and on meshes cut
//! by planes and polygons: exactly the six rigid modes in the null space,
//! no negative eigenvalue, and a seventh eigenvalue above a floor measured
//! per kind (see [`common::spectra`]). The floors sit under the measured
//! worst by a factor of a few; a soft element (issue 11 measured 1e-11)
//! fails them by orders of magnitude.

use cleave::material::Material;
use cleave::mesh::Plane;
use cleave::mesh::PolyMesh;
use cleave::meshing::{box_hex, box_l_prisms, box_tet, random_convex};
use cleave::sim::{Simulation, SimulationParams};
use cleave::store::{BasisOptions, ElementKind, ElementStore, Family, HarmonicOptions, QuadratureRule};

use crate::common;

fn material() -> Material {
    Material::new(1e5, 0.3, 1000.0).unwrap()
}

fn options(family: Family, quadrature: QuadratureRule, trilinear_hexahedra: bool) -> BasisOptions {
    BasisOptions {
        family,
        quadrature,
        harmonic: HarmonicOptions { trilinear_hexahedra, ..Default::default() },
        ..Default::default()
    }
}

/// `mesh` cut by `cuts` planes and rectangles from `seed` through its
/// bounding box by a simulation with `basis` (which retries a cut keeping
/// whole an element whose part the store refuses): the mesh it accepts.
fn cut(mesh: PolyMesh, basis: &BasisOptions, cuts: usize, seed: u64) -> PolyMesh {
    let (lo, hi) = mesh.bounding_box();
    let params = SimulationParams { material: material(), basis: *basis, ..Default::default() };
    let mut sim = Simulation::new(mesh, params).unwrap();
    for c in 0..cuts {
        let t = (seed * 7 + c as u64) as f64;
        let point: [f64; 3] =
            std::array::from_fn(|i| lo[i] + (0.3 + 0.4 * (t * (1.3 + i as f64)).sin().abs()) * (hi[i] - lo[i]));
        let plane = Plane { point, normal: [(t * 2.1).sin(), (t * 0.9).cos(), 0.3 + (t * 1.7).sin()] };
        if c % 2 == 0 {
            sim.cut_plane(&plane).unwrap();
        } else {
            sim.cut_polygon(&common::rectangle_in_plane(&plane, (0.3, 0.2), t)).unwrap();
        }
    }
    sim.mesh().clone()
}

/// Builds `mesh` with `basis`, checks every element's spectrum against
/// `floor` and returns the worst ratio of the elements of `kind`.
fn worst(label: &str, mesh: &PolyMesh, basis: &BasisOptions, kind: ElementKind, floor: f64) -> f64 {
    let store = ElementStore::build(mesh, &material(), basis).unwrap_or_else(|e| panic!("{label}: {e}"));
    let summary = common::spectra(&store, floor);
    let of_kind = store.batches.iter().filter(|b| b.kind == kind).map(|b| b.len()).sum::<usize>();
    assert!(of_kind > 0, "{label}: no {kind:?} element");
    println!("{label}: {} elements ({of_kind} {kind:?}), worst λ7/λmax {:.2e}", summary.elements, summary.worst_ratio);
    summary.worst_ratio
}

#[test]
fn linear_tetrahedra() {
    let bunny = cleave::io::read_mesh(&common::asset("bunny_5k.mesh")).unwrap();
    let basis = BasisOptions::default();
    worst(
        "tetrahedra, box",
        &box_tet([0.0; 3], [2.0, 1.0, 0.5], [6, 3, 2]).unwrap(),
        &basis,
        ElementKind::LinearTet,
        1e-2,
    );
    // TetGen's slivers (quality down to 0.014) are the softest tetrahedra
    worst("tetrahedra, bunny_5k", &bunny, &basis, ElementKind::LinearTet, 1e-5);
}

#[test]
fn mean_value_elements_with_each_rule() {
    for (rule, floor) in
        [(QuadratureRule::Consistent, 1e-4), (QuadratureRule::Paper, 1e-4), (QuadratureRule::Reference(3), 1e-4)]
    {
        let basis = options(Family::MeanValue, rule, true);
        for seed in 0..6 {
            let mesh = random_convex([0.0; 3], [1.0; 3], 10, seed).unwrap();
            worst(&format!("mean value {rule:?}, random convex {seed}"), &mesh, &basis, ElementKind::MeanValue, floor);
        }
    }
}

#[test]
fn mean_value_elements_after_cuts() {
    let basis = BasisOptions::default();
    for seed in 0..8 {
        let mesh = cut(random_convex([0.0; 3], [1.0; 3], 8, seed).unwrap(), &basis, 4, seed);
        worst(&format!("mean value, cut random convex {seed}"), &mesh, &basis, ElementKind::MeanValue, 1e-6);
        let mesh = cut(box_tet([0.0; 3], [1.0; 3], [3, 3, 3]).unwrap(), &basis, 4, seed);
        worst(&format!("mean value, cut tetrahedra {seed}"), &mesh, &basis, ElementKind::MeanValue, 1e-6);
    }
}

#[test]
fn trilinear_and_harmonic_elements_with_and_after_cuts() {
    let trilinear = options(Family::Harmonic, QuadratureRule::Consistent, true);
    worst(
        "trilinear, box",
        &box_hex([0.0; 3], [2.0, 1.0, 0.5], [4, 2, 2]).unwrap(),
        &trilinear,
        ElementKind::Trilinear,
        1e-2,
    );
    let fitted = options(Family::Harmonic, QuadratureRule::Consistent, false);
    worst(
        "harmonic, box",
        &box_hex([0.0; 3], [1.0, 0.7, 0.5], [2, 2, 1]).unwrap(),
        &fitted,
        ElementKind::Harmonic,
        1e-3,
    );
    let prisms = box_l_prisms([0.0; 3], [1.0, 1.0, 0.5], [2, 2, 1]).unwrap();
    worst("harmonic, L-prisms", &prisms, &trilinear, ElementKind::Harmonic, 1e-3);
    for seed in 0..4 {
        let mesh = cut(box_hex([0.0; 3], [1.0; 3], [2, 2, 2]).unwrap(), &trilinear, 3, seed);
        worst(&format!("harmonic, cut hexahedra {seed}"), &mesh, &trilinear, ElementKind::Harmonic, 1e-6);
        let mesh = cut(random_convex([0.0; 3], [1.0; 3], 6, seed).unwrap(), &trilinear, 3, seed);
        worst(&format!("harmonic, cut random convex {seed}"), &mesh, &trilinear, ElementKind::Harmonic, 1e-6);
    }
}
