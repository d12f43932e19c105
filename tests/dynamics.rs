//! Corotated implicit dynamics: no ghost forces under rotation, momentum in
//! free flight, a dropped body coming to rest on a plane, Cholesky against
//! CG, and trajectories independent of the thread count.

use cleave::material::Material;
use cleave::mesh::PolyMesh;
use cleave::meshing::{box_tet, random_convex};
use cleave::sim::{Collider, Simulation, SimulationParams};
use cleave::solve::SolverKind;
use cleave::topology::Plane;

fn rotate(axis: usize, angle: f64, p: [f64; 3]) -> [f64; 3] {
    let (s, c) = angle.sin_cos();
    let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut q = p;
    q[i] = c * p[i] - s * p[j];
    q[j] = s * p[i] + c * p[j];
    q
}

fn params(corotated: bool) -> SimulationParams {
    SimulationParams { material: Material::new(1e5, 0.3, 1000.0).unwrap(), corotated, ..Default::default() }
}

/// Largest nodal elastic force after rotating the body rigidly by 90°
/// about `axis`, relative to its weight.
fn ghost_force(mesh: PolyMesh, axis: usize, corotated: bool) -> f64 {
    let mut sim = Simulation::new(mesh, params(corotated)).unwrap();
    let u: Vec<[f64; 3]> = sim
        .mesh()
        .nodes
        .iter()
        .map(|&x| {
            let y = rotate(axis, std::f64::consts::FRAC_PI_2, x);
            [y[0] - x[0], y[1] - x[1], y[2] - x[2]]
        })
        .collect();
    sim.set_displacements(&u).unwrap();
    let weight: f64 = sim.masses().iter().sum::<f64>() * 9.81;
    let f = sim.elastic_forces();
    f.iter().map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()).fold(0.0, f64::max) / weight
}

#[test]
fn rigid_rotation_carries_no_elastic_force() {
    for mesh in
        [box_tet([0.0; 3], [2.0, 1.0, 0.5], [4, 2, 2]).unwrap(), random_convex([0.0; 3], [1.0; 3], 6, 4).unwrap()]
    {
        for axis in 0..3 {
            let warped = ghost_force(mesh.clone(), axis, true);
            let linear = ghost_force(mesh.clone(), axis, false);
            println!("axis {axis}: corotated {warped:.2e}, linear {linear:.2e} of the weight");
            assert!(warped < 1e-10, "ghost force {warped:e}");
            assert!(linear > 1.0, "linear elasticity must show ghost forces: {linear}");
        }
    }
}

#[test]
fn free_flight_conserves_linear_momentum() {
    let mesh = random_convex([0.0; 3], [1.0, 0.6, 0.4], 5, 9).unwrap();
    let p = SimulationParams { gravity: [0.0; 3], dt: 0.005, tolerance: 1e-12, ..params(true) };
    let mut sim = Simulation::new(mesh, p).unwrap();
    // translation plus a spin about an off-centre axis
    let v: Vec<[f64; 3]> =
        sim.mesh().nodes.iter().map(|x| [0.3 - 2.0 * x[1], 0.1 + 2.0 * x[0], -0.2 + 0.5 * x[1]]).collect();
    sim.set_velocities(&v).unwrap();
    let (p0, l0) = (sim.linear_momentum(), sim.angular_momentum());
    let scale_p = p0.iter().map(|x| x.abs()).fold(0.0, f64::max);
    let scale_l = l0.iter().map(|x| x.abs()).fold(0.0, f64::max);
    for _ in 0..200 {
        sim.step().unwrap();
    }
    let (p1, l1) = (sim.linear_momentum(), sim.angular_momentum());
    for i in 0..3 {
        assert!((p1[i] - p0[i]).abs() < 1e-10 * scale_p, "linear momentum {p0:?} -> {p1:?}");
    }
    // implicit Euler damps the spin: allow 10 % over 1 s of flight
    let drift = (0..3).map(|i| (l1[i] - l0[i]).abs()).fold(0.0, f64::max) / scale_l;
    println!("angular momentum drift after 200 steps: {drift:.3e}");
    assert!(drift < 0.1, "angular momentum drift {drift}");
}

#[test]
fn dropped_cube_comes_to_rest_above_the_plane() {
    // wicke2007 Fig. 2: a cube cut into convex cells falls on the ground
    let mesh = random_convex([0.0, 0.0, 0.3], [1.0, 1.0, 1.3], 5, 1).unwrap();
    let p = SimulationParams { dt: 0.005, mass_damping: 1.0, ..params(true) };
    let mut sim = Simulation::new(mesh, p).unwrap();
    let stiffness = 1e7;
    sim.add_collider(Collider::new([0.0; 3], [0.0, 0.0, 1.0], stiffness).unwrap());
    let mass: f64 = sim.masses().iter().sum();
    let weight = mass * 9.81;
    let lowest = |sim: &Simulation| sim.positions().iter().map(|x| x[2]).fold(f64::INFINITY, f64::min);
    let mut deepest: f64 = 0.0;
    for _ in 0..2000 {
        sim.step().unwrap();
        deepest = deepest.max(-lowest(&sim));
        assert!(sim.kinetic_energy().is_finite());
    }
    // documented tolerances: during the impact, the whole kinetic energy
    // stored in one penalty spring, ½ M v² = ½ k d² with v = sqrt(2 g 0.3 m);
    // at rest, the whole weight on one node, d = M g / k
    let impact = (2.0 * 9.81 * 0.3f64).sqrt() * (mass / stiffness).sqrt();
    let resting = weight / stiffness;
    let final_depth = -lowest(&sim);
    println!("deepest penetration {deepest:.3e} m (bound {impact:.3e}), at rest {final_depth:.3e} m (bound {resting:.3e}), kinetic energy {:.3e} J", sim.kinetic_energy());
    assert!(deepest < impact, "penetration {deepest}");
    assert!(final_depth < resting, "resting penetration {final_depth}");
    assert!(sim.kinetic_energy() < 1e-6 * weight, "comes to rest");
}

#[test]
fn cholesky_and_cg_take_the_same_step() {
    let run = |solver| {
        let mesh = box_tet([0.0; 3], [2.0, 0.5, 0.5], [8, 2, 2]).unwrap();
        let p = SimulationParams { solver, tolerance: 1e-12, ..params(true) };
        let mut sim = Simulation::new(mesh, p).unwrap();
        sim.fix(cleave::sim::FixedRegion::clamp([-1.0; 3], [1e-3, 1.0, 1.0])).unwrap();
        for _ in 0..5 {
            sim.step().unwrap();
        }
        sim.velocities().to_vec()
    };
    let a = run(SolverKind::Cholesky);
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for kind in [SolverKind::Cg, SolverKind::CgRest] {
        let b = run(kind);
        for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
            assert!((x - y).abs() < 1e-9 * scale, "{kind:?}: {x} vs {y}");
        }
    }
}

#[test]
fn rotated_rest_preconditioner_needs_few_iterations_under_rotation() {
    // a beam spinning about its axis: the warped system differs from the
    // rest one by the rotations the preconditioner undoes
    let iterations = |solver| {
        let mesh = box_tet([0.0; 3], [2.0, 0.5, 0.5], [12, 3, 3]).unwrap();
        let p = SimulationParams { solver, tolerance: 1e-8, gravity: [0.0; 3], dt: 0.01, ..params(true) };
        let mut sim = Simulation::new(mesh, p).unwrap();
        let v: Vec<[f64; 3]> =
            sim.mesh().nodes.iter().map(|x| [0.0, -3.0 * (x[2] - 0.25), 3.0 * (x[1] - 0.25)]).collect();
        sim.set_velocities(&v).unwrap();
        (0..30).map(|_| sim.step().unwrap().solve.iterations).max().unwrap()
    };
    let (jacobi, rest) = (iterations(SolverKind::Cg), iterations(SolverKind::CgRest));
    println!("largest CG iterations per step: block Jacobi {jacobi}, rotated rest Cholesky {rest}");
    assert!(rest < jacobi / 2, "{rest} vs {jacobi}");
}

#[test]
fn trajectories_are_bitwise_independent_of_the_thread_count() {
    for solver in [SolverKind::Cholesky, SolverKind::Cg] {
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
                let mesh = random_convex([0.0, 0.0, 0.2], [1.0, 1.0, 1.2], 6, 3).unwrap();
                let mut sim = Simulation::new(mesh, SimulationParams { solver, ..params(true) }).unwrap();
                sim.add_collider(Collider::new([0.0; 3], [0.1, 0.0, 1.0], 1e6).unwrap());
                for step in 0..100 {
                    // cuts rebuild part of the system in place: that too
                    // must not depend on the threads
                    if step == 40 {
                        let cut = sim.cut_plane(&Plane { point: [0.5, 0.5, 0.7], normal: [1.0, 0.2, 0.1] }).unwrap();
                        assert!(!cut.split.split_elements.is_empty());
                    }
                    if step == 60 {
                        let blade = [[0.2, 0.3, -0.1], [0.2, 0.3, 0.9], [0.2, 0.9, 0.9], [0.2, 0.9, -0.1]];
                        assert!(!sim.cut_polygon(&blade).unwrap().cut.touched.is_empty());
                    }
                    sim.step().unwrap();
                }
                sim.displacements().iter().flatten().map(|v| v.to_bits()).collect::<Vec<u64>>()
            })
        };
        assert_eq!(run(1), run(2), "{solver:?}");
    }
}
