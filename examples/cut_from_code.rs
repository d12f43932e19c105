//! Cutting from code: a slab of tetrahedra clamped at one end is cut by a
//! whole plane and then by a small square blade while it sags, and the
//! pieces are counted after each cut.
//!
//! ```text
//! cargo run --release --example cut_from_code
//! ```

use cleave::mesh::Plane;
use cleave::meshing::box_tet;
use cleave::sim::{FixedRegion, Simulation, SimulationParams};

fn main() -> Result<(), cleave::Error> {
    let mesh = box_tet([0.0; 3], [2.0, 0.5, 0.2], [16, 4, 2])?;
    let params = SimulationParams { dt: 0.005, gravity: [0.0, 0.0, -9.81], ..Default::default() };
    let mut sim = Simulation::new(mesh, params)?;
    sim.fix(FixedRegion::clamp([-1.0; 3], [1e-3, 1.0, 1.0]))?;
    let report = |sim: &Simulation, what: &str| {
        println!(
            "{what}: {} elements, {} nodes, volume {:.6} m³",
            sim.mesh().elements.len(),
            sim.mesh().nodes.len(),
            sim.mesh().total_volume()
        );
    };
    report(&sim, "start");
    for step in 0..200 {
        if step == 50 {
            // a whole plane across the free end (rest frame): the tip falls off
            let cut = sim.cut_plane(&Plane { point: [1.7, 0.25, 0.1], normal: [1.0, 0.2, 0.0] })?;
            println!("plane cut: {} elements split", cut.split.split_elements.len());
            report(&sim, "after the plane");
        }
        if step == 120 {
            // a square blade 0.3 m wide into the side (rest frame), a slit
            let blade = [[0.8, -0.1, -0.1], [0.8, 0.2, -0.1], [0.8, 0.2, 0.3], [0.8, -0.1, 0.3]];
            let cut = sim.cut_polygon(&blade)?;
            println!("blade cut: {} elements split", cut.cut.split.split_elements.len());
            report(&sim, "after the blade");
        }
        sim.step()?;
    }
    let lowest = sim.positions().iter().map(|x| x[2]).fold(f64::INFINITY, f64::min);
    println!("after 200 steps the lowest node is at z = {lowest:.3} m (the cut tip falls freely)");
    Ok(())
}
