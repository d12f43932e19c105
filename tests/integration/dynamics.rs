//! Corotated implicit dynamics: no ghost forces under rotation, momentum in
//! free flight, a dropped body coming to rest on a plane, Cholesky against
//! CG, and trajectories independent of the thread count.

use cleave::material::Material;
use cleave::mesh::Plane;
use cleave::mesh::PolyMesh;
use cleave::meshing::{box_hex, box_tet, random_convex};
use cleave::sim::{Collider, Simulation, SimulationParams};
use cleave::solve::SolverKind;

use crate::common;

/// `p` rotated by `angle` (rad) about the unit `axis` through the origin
/// (Rodrigues).
fn rotate(axis: [f64; 3], angle: f64, p: [f64; 3]) -> [f64; 3] {
    let (s, c) = angle.sin_cos();
    let d = axis[0] * p[0] + axis[1] * p[1] + axis[2] * p[2];
    let x = [axis[1] * p[2] - axis[2] * p[1], axis[2] * p[0] - axis[0] * p[2], axis[0] * p[1] - axis[1] * p[0]];
    std::array::from_fn(|i| p[i] * c + x[i] * s + axis[i] * d * (1.0 - c))
}

fn params(corotated: bool) -> SimulationParams {
    SimulationParams { material: Material::new(1e5, 0.3, 1000.0).unwrap(), corotated, ..Default::default() }
}

/// Largest nodal elastic force after rotating the body rigidly by `angle`
/// about `axis`, relative to its weight.
fn ghost_force(mesh: PolyMesh, axis: [f64; 3], angle: f64, corotated: bool) -> f64 {
    let mut sim = Simulation::new(mesh, params(corotated)).unwrap();
    let u: Vec<[f64; 3]> = sim
        .mesh()
        .nodes
        .iter()
        .map(|&x| {
            let y = rotate(axis, angle, x);
            [y[0] - x[0], y[1] - x[1], y[2] - x[2]]
        })
        .collect();
    sim.set_displacements(&u).unwrap();
    let weight: f64 = sim.masses().iter().sum::<f64>() * 9.81;
    let f = sim.elastic_forces();
    f.iter().map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()).fold(0.0, f64::max) / weight
}

/// Rigid rotations about random axes by random angles up to a half turn
/// leave no elastic force with warping (measured up to 1e-14 of the
/// weight: rounding of the rotation extraction), where plain linear
/// elasticity pushes with forces comparable to the weight.
#[test]
fn rigid_rotation_carries_no_elastic_force() {
    let mut worst: f64 = 0.0;
    for (m, mesh) in
        [box_tet([0.0; 3], [2.0, 1.0, 0.5], [4, 2, 2]).unwrap(), random_convex([0.0; 3], [1.0; 3], 6, 4).unwrap()]
            .into_iter()
            .enumerate()
    {
        for r in 0..8 {
            let t = (m * 8 + r) as f64;
            let axis = [(t * 1.3).sin(), (t * 2.9).cos(), 0.4 + (t * 0.7).sin()];
            let len = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
            let axis = axis.map(|x| x / len);
            let angle = 0.3 + 2.8 * ((t * 3.7).sin() * 0.5 + 0.5);
            let warped = ghost_force(mesh.clone(), axis, angle, true);
            let linear = ghost_force(mesh.clone(), axis, angle, false);
            worst = worst.max(warped);
            assert!(linear > 0.1, "linear elasticity must show ghost forces: {linear}");
        }
    }
    println!("largest ghost force with warping: {worst:.2e} of the weight");
    assert!(worst < 1e-13, "ghost force {worst:e}");
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
    // implicit Euler damps the spin, by little at this step (measured
    // 2.9e-5 over 1 s of flight)
    let drift = (0..3).map(|i| (l1[i] - l0[i]).abs()).fold(0.0, f64::max) / scale_l;
    println!("angular momentum drift after 200 steps: {drift:.3e}");
    assert!(drift < 5e-5, "angular momentum drift {drift}");
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
    // at rest: the kinetic energy is a negligible part of the energy the
    // drop released, M g h with h = 0.3 m (measured 2.3e-8 of it)
    assert!(sim.kinetic_energy() < 1e-7 * weight * 0.3, "comes to rest: {} J", sim.kinetic_energy());
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

/// The bunny (2,153 nodes, 6,907 elements: above every parallel grain
/// size of the rotations, the assembly, the pattern and CG) falls, is cut
/// by a plane and a polygon, and lands; positions, velocities and stresses
/// after 40 steps are the same bits on 1, 2 and 4 threads, with either
/// solver.
#[test]
fn trajectories_are_bitwise_independent_of_the_thread_count() {
    let mut bunny = cleave::io::read_mesh(&common::asset("bunny_5k.mesh")).unwrap();
    cleave::topology::merge_slivers(&mut bunny, 0.02).unwrap();
    // (renumbered for locality, CG keeps the mesh's own order)
    let mut renumbered = bunny.clone();
    renumbered.renumber_for_locality();
    for (solver, bunny) in [(SolverKind::Cholesky, &bunny), (SolverKind::Cg, &bunny), (SolverKind::Cg, &renumbered)] {
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
                let p = SimulationParams { solver, gravity: [0.0, -9.81, 0.0], ..params(true) };
                let mut sim = Simulation::new(bunny.clone(), p).unwrap();
                sim.add_collider(Collider::new([0.0, -0.1, 0.0], [0.0, 1.0, 0.0], 1e7).unwrap());
                sim.set_velocities(&vec![[0.0, -3.0, 0.5]; sim.mesh().nodes.len()]).unwrap();
                for step in 0..40 {
                    // cuts rebuild part of the system in place: that too
                    // must not depend on the threads
                    if step == 10 {
                        let cut = sim.cut_plane(&Plane { point: [0.0, 6.0, 0.0], normal: [0.2, 1.0, 0.3] }).unwrap();
                        assert!(!cut.split.split_elements.is_empty());
                    }
                    if step == 20 {
                        let blade = [[-1.5, 1.5, -4.5], [-1.5, 5.5, -4.5], [-1.5, 5.5, 0.0], [-1.5, 1.5, 0.0]];
                        assert!(!sim.cut_polygon(&blade).unwrap().cut.touched.is_empty());
                    }
                    sim.step().unwrap();
                }
                let bits = |v: &[[f64; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<u64>>();
                let stress: Vec<u64> = sim.von_mises().iter().map(|x| x.to_bits()).collect();
                (bits(sim.positions()), bits(sim.velocities()), stress)
            })
        };
        let one = run(1);
        assert_eq!(one, run(2), "{solver:?}, 2 threads");
        assert_eq!(one, run(4), "{solver:?}, 4 threads");
    }
    // a Cholesky factor large enough for faer to split its dense kernels
    // and triangular solves across threads (6,144 tetrahedra; the
    // triangular solves summed in a thread-dependent order until they ran
    // sequentially)
    let statics = |threads: usize| {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
            let mesh = box_tet([0.0; 3], [4.0, 1.0, 1.0], [32, 8, 8]).unwrap();
            let p = SimulationParams { solver: SolverKind::Cholesky, ..params(true) };
            let mut sim = Simulation::new(mesh, p).unwrap();
            sim.fix(cleave::sim::FixedRegion::clamp([-1.0; 3], [1e-3, 2.0, 2.0])).unwrap();
            sim.solve_static().unwrap();
            sim.step().unwrap();
            sim.positions().iter().flatten().map(|x| x.to_bits()).collect::<Vec<u64>>()
        })
    };
    let one = statics(1);
    assert!(one == statics(2) && one == statics(4), "a large Cholesky solve depends on the thread count");
}

/// The physics does not depend on how the nodes are numbered: bunny_5k
/// falling onto a plane and cut by a plane, in the file's numbering and
/// renumbered for locality, ends at the same positions (node for node
/// through the renumbering) to the solver's tolerance.
#[test]
fn a_renumbered_mesh_moves_as_the_mesh_it_came_from() {
    let bunny = cleave::io::read_mesh(&common::asset("bunny_5k.mesh")).unwrap();
    let mut renumbered = bunny.clone();
    let moved = renumbered.renumber_for_locality();
    let run = |mesh: PolyMesh| {
        let p = SimulationParams {
            solver: SolverKind::Cg,
            tolerance: 1e-12,
            gravity: [0.0, -9.81, 0.0],
            material: Material::new(5e6, 0.35, 1000.0).unwrap(),
            ..Default::default()
        };
        let mut sim = Simulation::new(mesh, p).unwrap();
        sim.add_collider(Collider::new([0.0, -0.1, 0.0], [0.0, 1.0, 0.0], 1e8).unwrap());
        sim.set_velocities(&vec![[0.0, -3.0, 0.5]; sim.mesh().nodes.len()]).unwrap();
        for step in 0..30 {
            if step == 10 {
                sim.cut_plane(&Plane { point: [0.0, 6.0, 0.0], normal: [0.2, 1.0, 0.3] }).unwrap();
            }
            sim.step().unwrap();
        }
        sim
    };
    let (a, b) = (run(bunny), run(renumbered));
    // (the cut appends its nodes in each mesh's order: compare the first
    // nodes through the renumbering, and the node counts)
    assert_eq!(a.mesh().nodes.len(), b.mesh().nodes.len());
    let size = 10.0;
    let mut worst = 0.0f64;
    for (old, &new) in moved.node.iter().enumerate() {
        let (p, q) = (a.positions()[old], b.positions()[new as usize]);
        worst = worst.max((0..3).map(|d| (p[d] - q[d]).abs()).fold(0.0, f64::max));
    }
    println!("largest difference of a node's position: {worst:.2e} m");
    assert!(worst < 1e-8 * size, "{worst:.2e} m");
}

/// Several simulations running at once on their own threads (sharing the
/// rayon pool, each ordering its system with METIS) give the same bits as
/// one running alone. (METIS seeds one process-wide random generator at
/// each call: concurrent orderings differed until its calls were made one
/// at a time.)
#[test]
fn simulations_running_at_once_give_the_same_bits_as_one_alone() {
    let run = || {
        let mesh = box_tet([0.0; 3], [4.0, 1.0, 1.0], [16, 4, 4]).unwrap();
        let mut sim = Simulation::new(mesh, SimulationParams { solver: SolverKind::Cholesky, ..params(true) }).unwrap();
        sim.fix(cleave::sim::FixedRegion::clamp([-1.0; 3], [1e-3, 2.0, 2.0])).unwrap();
        sim.solve_static().unwrap();
        for _ in 0..3 {
            sim.step().unwrap();
        }
        sim.positions().iter().flatten().map(|x| x.to_bits()).collect::<Vec<u64>>()
    };
    let alone = run();
    let threads: Vec<_> = (0..8).map(|_| std::thread::spawn(run)).collect();
    for t in threads {
        assert!(t.join().unwrap() == alone, "a simulation running beside others differs");
    }
}

/// A cut keeps the rotation of every element it does not touch (the warm
/// start of the next polar decomposition) wherever the store moved its
/// entry, and gives the new ones theirs: the step after a cut needs no
/// more rotation iterations than the same step without the cut, where a
/// cold start from the identity (a fresh simulation in the uncut body's
/// state) needs more.
#[test]
fn a_cut_keeps_the_rotations_of_untouched_elements() {
    let spinning = || {
        let mesh = box_tet([0.0; 3], [2.0, 0.5, 0.5], [12, 3, 3]).unwrap();
        let p = SimulationParams { gravity: [0.0; 3], ..params(true) };
        let mut sim = Simulation::new(mesh, p).unwrap();
        let v: Vec<[f64; 3]> =
            sim.mesh().nodes.iter().map(|x| [0.0, -6.0 * (x[2] - 0.25), 6.0 * (x[1] - 0.25)]).collect();
        sim.set_velocities(&v).unwrap();
        for _ in 0..30 {
            sim.step().unwrap();
        }
        sim
    };
    let quaternion = |sim: &Simulation, id: u32| {
        let (b, i) = sim.store().locate[id as usize];
        sim.corotation().quaternion(b as usize, i as usize)
    };
    let (mut uncut, mut cut) = (spinning(), spinning());
    let before: Vec<[f64; 4]> = (0..cut.mesh().elements.len() as u32).map(|e| quaternion(&cut, e)).collect();
    assert!(before.iter().all(|q| q[0].abs() < 0.7), "the bar has turned by more than 90 degrees");
    let report = cut.cut_plane(&Plane { point: [1.03, 0.25, 0.25], normal: [1.0, 0.2, 0.1] }).unwrap();
    assert!(!report.split.split_elements.is_empty());
    let untouched: Vec<u32> = (0..before.len() as u32).filter(|e| report.touched.binary_search(e).is_err()).collect();
    assert!(untouched.len() > before.len() / 2);
    for &e in &untouched {
        assert_eq!(quaternion(&cut, e), before[e as usize], "element {e} lost its rotation");
    }
    let mut cold = Simulation::new(uncut.mesh().clone(), uncut.params().clone()).unwrap();
    cold.set_displacements(uncut.displacements()).unwrap();
    cold.set_velocities(uncut.velocities()).unwrap();
    let cold = cold.step().unwrap().rotation_iterations;
    let kept = cut.step().unwrap().rotation_iterations;
    let without = uncut.step().unwrap().rotation_iterations;
    println!("rotation iterations in the step after the cut: {kept}; without the cut {without}; cold start {cold}");
    assert!(kept <= without, "{kept} after the cut vs {without} without");
    assert!(cold > kept, "a cold start needs more: {cold} vs {kept}");
}

/// A uniform stretch `1 + s` along x, turned rigidly, stores
/// `V (μ s² + ½ λ s²)` (the strain `diag(s, 0, 0)` everywhere): the
/// closed-form energy of tetrahedra, the `½ uᵀ K u` of hexahedra, and the
/// discontinuous Galerkin energy, whose face terms vanish on a field without
/// jumps.
#[test]
fn stretched_and_turned_body_stores_the_energy_of_its_strain() {
    let (s, axis, angle) = (1e-3, [0.0, 0.6, 0.8], 0.9);
    let tets = || box_tet([0.0; 3], [2.0, 1.0, 1.0], [4, 2, 2]).unwrap();
    let hexes = cleave::meshing::box_hex([0.0; 3], [2.0, 1.0, 1.0], [4, 2, 2]).unwrap();
    let mut dg = params(true);
    dg.basis.family = cleave::store::Family::Dg;
    for (mesh, params) in [(tets(), params(true)), (hexes, params(true)), (tets(), dg)] {
        let mut sim = Simulation::new(mesh, params).unwrap();
        let u: Vec<[f64; 3]> = sim
            .mesh()
            .nodes
            .iter()
            .map(|&x| {
                let y = rotate(axis, angle, [x[0] * (1.0 + s), x[1], x[2]]);
                [y[0] - x[0], y[1] - x[1], y[2] - x[2]]
            })
            .collect();
        sim.set_displacements(&u).unwrap();
        let (lambda, mu) = sim.params().material.lame();
        let expected = 2.0 * (mu * s * s + 0.5 * lambda * s * s);
        let energy = sim.elastic_energy();
        // the strain is a difference of order 1e-3: rounding in F costs about
        // 1e-13 of it, the rotation extraction a little more
        assert!((energy - expected).abs() <= 1e-9 * expected, "{energy} J against {expected} J");
    }
}

/// [`SolverKind::Auto`] steps a well-conditioned body by CG and keeps CG;
/// it hands the steps to Cholesky for good where CG alone does not
/// converge (a thin beam at E = 1e10 Pa resting on a soft floor: that step
/// is solved again) and where CG takes many iterations step after step
/// (ν = 0.49), also in a simulation read back from a checkpoint.
#[test]
fn auto_hands_the_steps_cg_is_slow_on_to_cholesky() {
    let body = |dims: [usize; 3], young: f64, poisson: f64, solver: SolverKind| {
        let size = dims.map(|n| 0.2 * n as f64);
        let mesh = box_hex([0.0; 3], size, dims).unwrap();
        let material = Material::new(young, poisson, 1000.0).unwrap();
        let params = SimulationParams { material, gravity: [0.0, 0.0, -9.81], dt: 0.02, solver, ..Default::default() };
        let mut sim = Simulation::new(mesh, params).unwrap();
        sim.add_collider(Collider::new([0.0, 0.0, -0.05], [0.0, 0.1, 1.0], 1e6).unwrap());
        sim
    };
    let (beam, block) = ([40, 2, 2], [10, 6, 5]);
    let mut cg = body(beam, 1e10, 0.35, SolverKind::Cg);
    let failed = (0..20).map(|_| cg.step()).find_map(Result::err);
    assert!(failed.as_ref().is_some_and(|e| e.to_string().contains("did not converge")), "{failed:?}");
    let mut stiff = body(beam, 1e10, 0.35, SolverKind::Auto);
    let mut nearly_incompressible = body(block, 1e7, 0.49, SolverKind::Auto);
    for sim in [&mut stiff, &mut nearly_incompressible] {
        for _ in 0..20 {
            sim.step().unwrap();
        }
        assert_eq!(sim.solver_kind(), SolverKind::Cholesky);
    }
    let read: Simulation = common::checkpoint_round_trip(&stiff);
    assert_eq!(read.solver_kind(), SolverKind::Cholesky);
    // the same block at E = 1e5 Pa, ν = 0.35 lands in about 25 iterations
    // a step (more on a few)
    let mut soft = body(block, 1e5, 0.35, SolverKind::Auto);
    let iterations: Vec<usize> = (0..30).map(|_| soft.step().unwrap().solve.iterations).collect();
    assert_eq!(soft.solver_kind(), SolverKind::Auto, "{iterations:?}");
    assert!(iterations[10..].iter().all(|&i| i > 1), "{iterations:?}");
}
