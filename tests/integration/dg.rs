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

/// `p` rotated by `angle` about the unit `axis` (Rodrigues).
fn rotate(axis: [f64; 3], angle: f64, p: [f64; 3]) -> [f64; 3] {
    let (s, c) = angle.sin_cos();
    let d = axis[0] * p[0] + axis[1] * p[1] + axis[2] * p[2];
    let x = [axis[1] * p[2] - axis[2] * p[1], axis[2] * p[0] - axis[0] * p[2], axis[0] * p[1] - axis[1] * p[0]];
    std::array::from_fn(|i| p[i] * c + x[i] * s + axis[i] * d * (1.0 - c))
}

/// A rigid rotation by 90° (and a translation) is reproduced exactly: every
/// element's own polynomial puts its vertices where the rotation does (no
/// jump), and with warping no elastic force remains (1e-10 of the weight),
/// where unwarped DG pushes with forces comparable to the weight.
#[test]
fn rigid_motions_leave_no_jump_and_no_ghost_force() {
    let axis = {
        let a: [f64; 3] = [0.3, -0.8, 0.52];
        let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        a.map(|v| v / l)
    };
    for (name, mesh) in meshes() {
        for (degree, flux) in [(1, Flux::Ip), (2, Flux::Ip), (1, Flux::Bz)] {
            let ghost = |corotated: bool| -> (f64, f64) {
                let p = SimulationParams { corotated, ..params(degree, flux) };
                let mut sim = Simulation::new(mesh.clone(), p).unwrap();
                let moved: Vec<[f64; 3]> = sim
                    .mesh()
                    .nodes
                    .iter()
                    .map(|&x| {
                        let y = rotate(axis, std::f64::consts::FRAC_PI_2, x);
                        [y[0] - x[0] + 0.3, y[1] - x[1], y[2] - x[2] - 1.0]
                    })
                    .collect();
                sim.set_displacements(&moved).unwrap();
                // no jump: each element's own copy of each vertex
                let (dg, x) = (sim.dg().unwrap(), sim.block_positions());
                let m = dg.size();
                let mut jump: f64 = 0.0;
                let mut n = vec![0.0; m];
                for (e, el) in sim.mesh().elements.iter().enumerate() {
                    for &v in &el.nodes {
                        let rest = sim.mesh().nodes[v as usize];
                        dg.basis(e as u32).values(rest, &mut n);
                        let want = [
                            rest[0] + moved[v as usize][0],
                            rest[1] + moved[v as usize][1],
                            rest[2] + moved[v as usize][2],
                        ];
                        for k in 0..3 {
                            let got: f64 = (0..m).map(|a| x[e * m + a][k] * n[a]).sum();
                            jump = jump.max((got - want[k]).abs());
                        }
                    }
                }
                let weight: f64 = sim.loads().iter().sum::<f64>() * 9.81;
                let f = sim.elastic_forces();
                let worst = f.iter().map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()).fold(0.0, f64::max);
                (worst / weight, jump)
            };
            let ((warped, jump), (plain, _)) = (ghost(true), ghost(false));
            println!("{name}, degree {degree}, {flux:?}: ghost force {warped:.1e} (unwarped {plain:.1e}) of the weight, jump {jump:.1e} m");
            assert!(jump < 1e-12, "{name}: jump {jump:e}");
            assert!(warped < 1e-10, "{name}, degree {degree}, {flux:?}: ghost force {warped:e}");
            assert!(plain > 1e-2, "{name}: unwarped {plain:e}");
        }
    }
}

/// A falling DG body cut by a plane and then by a polygon: each cut
/// carries the fields over exactly (momentum, angular momentum and kinetic
/// energy change by rounding only), integrates again only the faces it
/// changed (the face terms of the others kept are those a full rebuild
/// gives), and the run is the same bits on 1 and 2 threads.
#[test]
fn cuts_carry_the_fields_over_exactly_and_runs_do_not_depend_on_threads() {
    use cleave::mesh::Plane;
    use cleave::meshing::box_tet;
    use cleave::sim::Collider;
    use cleave::solve::SolverKind;
    let run = |degree: usize| -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
        let mesh = box_tet([0.0, 0.0, 0.3], [2.0, 1.0, 1.3], [6, 3, 3]).unwrap();
        let p = SimulationParams {
            material: Material::new(5e4, 0.3, 1000.0).unwrap(),
            dt: 0.005,
            solver: SolverKind::Cholesky,
            ..params(degree, Flux::Ip)
        };
        let mut sim = Simulation::new(mesh, p).unwrap();
        sim.add_collider(Collider::new([0.0; 3], [0.0, 0.0, 1.0], 1e7).unwrap());
        let v: Vec<[f64; 3]> =
            sim.mesh().nodes.iter().map(|x| [0.2, -0.5 * (x[2] - 0.8), 0.5 * (x[1] - 0.5)]).collect();
        sim.set_velocities(&v).unwrap();
        for step in 0..40 {
            if step == 10 || step == 20 {
                let before = (sim.linear_momentum(), sim.angular_momentum(), sim.kinetic_energy());
                let faces_before = sim.faces_integrated();
                if step == 10 {
                    sim.cut_plane(&Plane { point: [1.03, 0.5, 0.8], normal: [1.0, 0.2, 0.1] }).unwrap();
                } else {
                    let square = [[0.5, -0.1, 0.6], [0.5, 1.1, 0.6], [1.5, 1.1, 0.62], [1.5, -0.1, 0.62]];
                    sim.cut_polygon(&square).unwrap();
                }
                let after = (sim.linear_momentum(), sim.angular_momentum(), sim.kinetic_energy());
                let total: usize = sim.mesh().elements.iter().map(|e| e.faces.len()).sum();
                let integrated = sim.faces_integrated() - faces_before;
                assert!(integrated > 0 && integrated < total / 2, "{integrated} of {total} faces integrated");
                let scale = before.0.iter().chain(&before.1).fold(0.0f64, |m, v| m.max(v.abs()));
                for i in 0..3 {
                    assert!((after.0[i] - before.0[i]).abs() < 1e-12 * scale, "momentum {before:?} -> {after:?}");
                    assert!(
                        (after.1[i] - before.1[i]).abs() < 1e-12 * scale,
                        "angular momentum {before:?} -> {after:?}"
                    );
                }
                assert!((after.2 - before.2).abs() < 1e-12 * before.2, "kinetic energy {} -> {}", before.2, after.2);
                // the faces the cut left alone kept their integrals: the
                // same as integrating every face again
                let dg = sim.dg().unwrap();
                let mut full = dg.clone();
                full.refresh(sim.mesh(), &[]);
                assert!(full.interior == dg.interior && full.boundary == dg.boundary, "incremental face terms differ");
            }
            sim.step().unwrap();
        }
        (sim.block_positions().to_vec(), sim.block_velocities().to_vec())
    };
    for degree in [1, 2] {
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| run(degree))
        };
        let (one, two) = (on(1), on(2));
        assert!(one == two, "degree {degree}: 1 and 2 threads differ");
    }
}

/// Two polygon cuts free one block of a 2x2x1 grid along two of its faces,
/// so that it touches the rest along an edge only. A nodal body hangs on
/// that edge; a DG body glues through faces only, so the edge's nodes are
/// opened and the freed block shares no node with the rest (its stitched
/// field is its own).
#[test]
fn a_block_left_touching_along_an_edge_gets_its_own_nodes() {
    let blades = [
        [[1.0, -0.5, -0.5], [1.0, 1.0, -0.5], [1.0, 1.0, 1.5], [1.0, -0.5, 1.5]],
        [[-0.5, 1.0, -0.5], [1.0, 1.0, -0.5], [1.0, 1.0, 1.5], [-0.5, 1.0, 1.5]],
    ];
    for dg in [false, true] {
        let mesh = box_hex([0.0; 3], [2.0, 2.0, 1.0], [2, 2, 1]).unwrap();
        let p = if dg { params(1, Flux::Ip) } else { SimulationParams::default() };
        let mut sim = Simulation::new(mesh, p).unwrap();
        for blade in &blades {
            sim.cut_polygon(blade).unwrap();
        }
        let mesh = sim.mesh();
        let pinched = cleave::topology::pinched_nodes(mesh, 0..mesh.nodes.len() as u32);
        let corner = &mesh.elements[0].nodes;
        let shared = mesh.elements[1..].iter().flat_map(|e| &e.nodes).filter(|v| corner.contains(v)).count();
        if dg {
            assert!(pinched.is_empty() && shared == 0, "DG: pinched {pinched:?}, {shared} shared");
        } else {
            assert!(pinched.len() == 2 && shared > 0, "nodal: pinched {pinched:?}, {shared} shared");
        }
    }
}

/// The interior penalty is checked once, lazily: building the body and
/// fixing it leave the starting penalty unchecked, the first step (or
/// [`Simulation::stabilise`]) doubles it to the smallest power-of-two
/// multiple that makes the rest system positive definite (a body started
/// at half of it doubles to it again, one started at it keeps it), and
/// fixing another region after steps makes the next step check again.
#[test]
fn the_penalty_is_checked_once_before_the_first_step() {
    let mesh = box_hex([0.0; 3], [1.0, 0.8, 0.6], [3, 2, 2]).unwrap();
    let clamp = FixedRegion::clamp([-1.0; 3], [0.01, 2.0, 2.0]);
    let settled = |start: f64| -> f64 {
        let mut p = params(2, Flux::Ip);
        p.basis.dg.penalty = start;
        let mut sim = Simulation::new(mesh.clone(), p).unwrap();
        sim.fix(clamp).unwrap();
        assert!(!sim.dg().unwrap().is_stable() && sim.dg().unwrap().penalty == start);
        sim.stabilise().unwrap();
        assert!(sim.dg().unwrap().is_stable());
        sim.dg().unwrap().penalty
    };
    let found = settled(1.0);
    assert!(found > 1.0, "degree 2 on hexahedra needs more than the starting penalty: {found}");
    assert_eq!(settled(found / 2.0), found, "a penalty of half was enough");
    assert_eq!(settled(found), found);

    let mut sim = Simulation::new(mesh.clone(), params(2, Flux::Ip)).unwrap();
    sim.fix(clamp).unwrap();
    sim.step().unwrap();
    assert!(sim.dg().unwrap().is_stable() && sim.dg().unwrap().penalty == found);
    sim.fix(FixedRegion::clamp([0.99, -1.0, -1.0], [2.0; 3])).unwrap();
    assert!(!sim.dg().unwrap().is_stable());
    sim.step().unwrap();
    assert!(sim.dg().unwrap().is_stable() && sim.dg().unwrap().penalty >= found);
}
