//! cleave embedded in a host's frame loop: the host owns the clock, steps
//! the body once per frame, drags one node around with a pin (as a mouse
//! would) and reads the positions back to draw them.
//!
//! ```text
//! cargo run --release --example host_loop
//! ```

use cleave::meshing::box_hex;
use cleave::sim::{Collider, Simulation, SimulationParams};

fn main() -> Result<(), cleave::Error> {
    let mesh = box_hex([0.0, 0.0, 0.0], [1.0, 0.3, 0.3], [10, 3, 3])?;
    let params = SimulationParams { dt: 1.0 / 60.0, gravity: [0.0, 0.0, -9.81], ..Default::default() };
    let mut sim = Simulation::new(mesh, params)?;
    sim.add_collider(Collider::new([0.0, 0.0, -0.01], [0.0, 0.0, 1.0], 1e6)?);
    // the node the "mouse" holds: the top corner at the far end
    let grabbed = sim.mesh().nodes.iter().position(|x| *x == [1.0, 0.3, 0.3]).expect("a corner node");
    for frame in 0..120 {
        // the host's input: lift the corner up and back down over two seconds
        let lift = 0.3 * (std::f64::consts::PI * frame as f64 / 120.0).sin();
        sim.pin(grabbed, [0.0, 0.0, lift])?;
        sim.step()?;
        // the host's drawing: here, the height of the grabbed corner
        if frame % 20 == 0 {
            let x = sim.positions()[grabbed];
            println!("frame {frame:3}: corner at z = {:.3} m, {:.0} µs per step so far", x[2], 1e6 * step_time(&sim));
        }
    }
    Ok(())
}

/// Wall time per step so far (s).
fn step_time(sim: &Simulation) -> f64 {
    let t = sim.timings();
    (t.forces + t.assembly + t.contacts + t.constraints + t.solve + t.integrate) / sim.steps().max(1) as f64
}
