//! Many small bodies stepped together equal the same bodies stepped one by
//! one, bit for bit, whatever the number of threads.

use cleave::meshing::random_convex;
use cleave::sim::{step_bodies, Collider, Simulation, SimulationParams, StepStats};
use cleave::solve::{SolverKind, ENVELOPE_MAX_UNKNOWNS};

/// Body `i`: a box cut by random planes into convex cells, tumbling onto
/// a plane.
fn body(i: u64) -> Simulation {
    body_solved_by(i, SolverKind::Auto)
}

fn body_solved_by(i: u64, solver: SolverKind) -> Simulation {
    let size = 0.5 + 0.1 * (i % 5) as f64;
    let mesh = random_convex([0.0, 0.0, 0.2], [size, size, 0.2 + size], 3 + (i % 4) as usize, i).unwrap();
    let mut sim = Simulation::new(mesh, SimulationParams { solver, ..Default::default() }).unwrap();
    sim.add_collider(Collider::new([0.0; 3], [0.1 * (i % 3) as f64, 0.0, 1.0], 1e6).unwrap());
    let n = sim.mesh().nodes.len();
    sim.set_velocities(&vec![[0.3 * (i % 2) as f64, -0.2, -1.0]; n]).unwrap();
    sim
}

fn run(threads: usize, together: bool) -> Vec<Vec<[f64; 3]>> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        let mut bodies: Vec<Simulation> = (0..12).map(body).collect();
        let mut stats = vec![StepStats::default(); bodies.len()];
        for _ in 0..40 {
            if together {
                step_bodies(&mut bodies, &mut stats).unwrap();
            } else {
                for b in &mut bodies {
                    b.step().unwrap();
                }
            }
        }
        bodies.iter().map(|b| b.positions().to_vec()).collect()
    })
}

#[test]
fn bodies_stepped_together_equal_bodies_stepped_one_by_one() {
    let alone = run(1, false);
    assert!(alone.iter().flatten().flatten().all(|x| x.is_finite()));
    for threads in [1, 2, 4] {
        assert_eq!(run(threads, true), alone, "{threads} threads");
    }
}

/// The small-system path (envelope Cholesky) and the large-system path
/// (sparse supernodal Cholesky) step the same body alike, to rounding.
#[test]
fn the_envelope_and_the_sparse_cholesky_step_alike() {
    let run = |solver: SolverKind, steps: usize| {
        let mut sim = body_solved_by(7, solver);
        assert!(3 * sim.mesh().nodes.len() <= ENVELOPE_MAX_UNKNOWNS, "a small body");
        for _ in 0..steps {
            sim.step().unwrap();
        }
        sim.displacements().to_vec()
    };
    for steps in [1, 60] {
        let (small, large) = (run(SolverKind::Cholesky, steps), run(SolverKind::SparseCholesky, steps));
        let scale = large.iter().flatten().fold(0.0f64, |m, u| m.max(u.abs()));
        let diff = small.iter().flatten().zip(large.iter().flatten()).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        println!("{steps} steps: largest displacement {scale:.3e} m, paths differ by {diff:.1e} m");
        assert!(scale > 1e-3 && diff <= 1e-11 * scale, "{steps} steps: {diff:e} of {scale:e}");
    }
}
