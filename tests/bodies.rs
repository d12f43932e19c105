//! Many small bodies stepped together equal the same bodies stepped one by
//! one, bit for bit, whatever the number of threads.

use cleave::meshing::random_convex;
use cleave::sim::{step_bodies, Collider, Simulation, SimulationParams};

/// Body `i`: a box cut by random planes into convex cells, tumbling onto
/// a plane.
fn body(i: u64) -> Simulation {
    let size = 0.5 + 0.1 * (i % 5) as f64;
    let mesh = random_convex([0.0, 0.0, 0.2], [size, size, 0.2 + size], 3 + (i % 4) as usize, i).unwrap();
    let mut sim = Simulation::new(mesh, SimulationParams::default()).unwrap();
    sim.add_collider(Collider::new([0.0; 3], [0.1 * (i % 3) as f64, 0.0, 1.0], 1e6).unwrap());
    let n = sim.mesh().nodes.len();
    sim.set_velocities(&vec![[0.3 * (i % 2) as f64, -0.2, -1.0]; n]).unwrap();
    sim
}

fn run(threads: usize, together: bool) -> Vec<Vec<[f64; 3]>> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        let mut bodies: Vec<Simulation> = (0..12).map(body).collect();
        for _ in 0..40 {
            if together {
                step_bodies(&mut bodies).unwrap();
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
