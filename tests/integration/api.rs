//! The embedding API, through the public surface only: what a host
//! application does frame by frame.

use cleave::mesh::Plane;
use cleave::mesh::{Cell, PolyMesh};
use cleave::sim::{Collider, Simulation, SimulationParams};

/// Volume enclosed by a closed outward triangle surface (m^3).
fn enclosed_volume(x: &[[f64; 3]], tris: &[[u32; 3]]) -> f64 {
    tris.iter()
        .map(|t| cleave_kernels::tet::signed_volume([0.0; 3], x[t[0] as usize], x[t[1] as usize], x[t[2] as usize]))
        .sum()
}

#[test]
fn a_host_builds_pins_steps_cuts_and_reads_back() {
    // a 2 x 1 x 1 bar of two hexahedra, made in code
    let nodes: Vec<[f64; 3]> = (0..12).map(|i| [(i % 3) as f64, ((i / 3) % 2) as f64, (i / 6) as f64]).collect();
    let cells = [Cell::Hex([0, 1, 4, 3, 6, 7, 10, 9]), Cell::Hex([1, 2, 5, 4, 7, 8, 11, 10])];
    let mesh = PolyMesh::from_cells(nodes, &cells).unwrap();
    let mut sim =
        Simulation::new(mesh, SimulationParams { dt: 0.01, mass_damping: 0.5, ..Default::default() }).unwrap();
    sim.add_collider(Collider::new([0.0, 0.0, -0.2], [0.0, 0.0, 1.0], 1e6).unwrap());
    // hold the left end, drag one corner of it
    for v in [0, 3, 6, 9] {
        sim.pin(v, [0.0; 3]).unwrap();
    }
    sim.pin(9, [0.0, 0.0, 0.05]).unwrap();
    assert!(sim.pin(99, [0.0; 3]).is_err(), "pinning a missing node is an error, not a panic");
    for _ in 0..20 {
        sim.step().unwrap();
    }
    assert!((sim.positions()[9][2] - 1.05).abs() < 1e-12, "the dragged node follows its pin");
    // positions are rest + displacement, as a flat buffer too
    for ((x, x0), u) in sim.positions().iter().zip(&sim.mesh().nodes).zip(sim.displacements()) {
        (0..3).for_each(|i| assert_eq!(x[i], x0[i] + u[i]));
    }
    assert_eq!(sim.positions_flat().len(), 3 * sim.mesh().nodes.len());
    // the boundary surface is closed and outward
    let v = enclosed_volume(sim.positions(), sim.boundary_triangles());
    assert!(v > 1.5 && v < 2.5, "enclosed volume {v}");
    // cut the free end off mid-run and go on
    let before = sim.mesh().elements.len();
    sim.cut_plane(&Plane { point: [1.5, 0.5, 0.5], normal: [1.0, 0.0, 0.2] }).unwrap();
    assert!(sim.mesh().elements.len() > before);
    let rest = enclosed_volume(&sim.mesh().nodes, sim.boundary_triangles());
    assert!((rest - 2.0).abs() < 1e-12, "the boundary after the cut encloses the body: {rest}");
    for _ in 0..20 {
        sim.step().unwrap();
    }
    assert_eq!(sim.velocities().len(), sim.positions().len());
    assert_eq!(sim.von_mises().len(), sim.mesh().elements.len());
    assert!(sim.von_mises().iter().all(|s| s.is_finite() && *s >= 0.0));
    let t = sim.timings();
    let phases = [t.forces, t.assembly, t.contacts, t.constraints, t.solve, t.integrate, t.topology];
    assert!(phases.iter().all(|&p| p > 0.0), "every step phase and the cuts are timed: {t:?}");
    assert_eq!(sim.steps(), 40);
}

#[test]
fn nodes_of_no_element_are_held_and_do_not_make_the_system_singular() {
    let nodes = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [5.0, 5.0, 5.0]];
    let mesh = PolyMesh::from_cells(nodes, &[Cell::Tet([0, 1, 2, 3])]).unwrap();
    let mut sim = Simulation::new(mesh, SimulationParams::default()).unwrap();
    sim.fix(cleave::sim::FixedRegion::clamp([-1.0; 3], [2.0, 2.0, 1e-3])).unwrap();
    sim.solve_static().unwrap();
    assert_eq!(sim.displacements()[4], [0.0; 3]);
    for _ in 0..3 {
        sim.step().unwrap();
    }
    assert_eq!(sim.displacements()[4], [0.0; 3]);
}
