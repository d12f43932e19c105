//! A few hundred small deformable bodies dropping onto a plane, stepped
//! together with [`cleave::sim::step_bodies`] (one body per task, each
//! stepped exactly as alone): boxes cut by random planes into convex
//! cells, single convex elements with 6 to 20 vertices, and boxes of
//! hexahedra cut in two.
//!
//! ```text
//! cargo run --release --example many_bodies -- [BODIES] [STEPS]
//! ```
//!
//! Defaults: 300 bodies, 400 steps of 5 ms. Writes every 20th frame as one
//! OBJ of all boundaries to `out/many_bodies/frame_NNNN.obj` and prints
//! body-steps per second.

use std::path::Path;
use std::time::Instant;

use cleave::material::Material;
use cleave::mesh::{Plane, PolyMesh};
use cleave::meshing::{box_hex, clipped_box, random_convex};
use cleave::sim::{step_bodies, Collider, Simulation, SimulationParams, StepStats};

/// Body `i` of the set, its lowest corner at `origin` (m).
fn body(i: usize, origin: [f64; 3]) -> Result<Simulation, cleave::Error> {
    let size = 0.25 + 0.05 * (i % 3) as f64;
    let max = [origin[0] + size, origin[1] + size, origin[2] + size];
    let seed = i as u64;
    let mesh: PolyMesh = match i % 3 {
        0 => random_convex(origin, max, 3 + i % 5, seed)?,
        1 => clipped_box(origin, max, 2 + i % 6, seed)?,
        _ => box_hex(origin, max, [2, 2, 2])?,
    };
    let params = SimulationParams {
        material: Material::new(2e5, 0.3, 1000.0)?,
        gravity: [0.0, 0.0, -9.81],
        dt: 5e-3,
        mass_damping: 0.2,
        stiffness_damping: 2e-3,
        ..Default::default()
    };
    let mut sim = Simulation::new(mesh, params)?;
    if i % 3 == 2 {
        let c = [origin[0] + 0.5 * size, origin[1] + 0.5 * size, origin[2] + 0.5 * size];
        sim.cut_plane(&Plane { point: c, normal: [1.0, 0.4 * (i % 4) as f64, 0.3] })?;
    }
    sim.add_collider(Collider::new([0.0; 3], [0.0, 0.0, 1.0], 2e6)?);
    // a tumble: spin about the vertical, a little sideways drift
    let spin = 1.5 * ((i % 7) as f64 - 3.0);
    let center = [origin[0] + 0.5 * size, origin[1] + 0.5 * size];
    let v: Vec<[f64; 3]> =
        sim.positions().iter().map(|x| [-spin * (x[1] - center[1]) + 0.05, spin * (x[0] - center[0]), -0.5]).collect();
    sim.set_velocities(&v)?;
    Ok(sim)
}

/// Kinetic plus gravitational energy of all bodies (J), by lumped masses.
fn energy(bodies: &[Simulation]) -> f64 {
    bodies
        .iter()
        .flat_map(|b| b.masses().iter().zip(b.positions()).zip(b.velocities()))
        .map(|((m, x), v)| m * (0.5 * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) + 9.81 * x[2]))
        .sum()
}

/// Every body's boundary in one OBJ.
fn write_frame(dir: &Path, frame: usize, bodies: &[Simulation]) -> Result<(), cleave::io::IoError> {
    let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
    for sim in bodies {
        let offset = vertices.len() as u32;
        vertices.extend_from_slice(sim.positions());
        triangles.extend(sim.boundary_triangles().iter().map(|t| t.map(|v| v + offset)));
    }
    cleave::io::write_surface_obj(&dir.join(format!("frame_{frame:04}.obj")), &vertices, &triangles)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let count: usize = args.next().map_or(Ok(300), |a| a.parse())?;
    let steps: usize = args.next().map_or(Ok(400), |a| a.parse())?;
    let side = (count as f64).sqrt().ceil() as usize;
    let mut bodies = (0..count)
        .map(|i| {
            let (x, y) = ((i % side) as f64 * 0.6, (i / side) as f64 * 0.6);
            body(i, [x, y, 0.3 + 0.4 * (i % 4) as f64])
        })
        .collect::<Result<Vec<_>, _>>()?;
    let elements: usize = bodies.iter().map(|b| b.mesh().elements.len()).sum();
    let nodes: usize = bodies.iter().map(|b| b.mesh().nodes.len()).sum();
    println!("{count} bodies, {elements} elements, {nodes} nodes");
    let dir = Path::new("out/many_bodies");
    std::fs::create_dir_all(dir)?;
    let mut stats = vec![StepStats::default(); count];
    let start = Instant::now();
    let (mut stepping, mut fastest) = (0.0, 0.0f64);
    let start_energy = energy(&bodies);
    let mut most_energy = start_energy;
    for step in 0..=steps {
        if step % 20 == 0 {
            write_frame(dir, step / 20, &bodies)?;
        }
        if step < steps {
            let t = Instant::now();
            step_bodies(&mut bodies, &mut stats)?;
            stepping += t.elapsed().as_secs_f64();
            let speed = |v: &[f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            fastest = bodies.iter().flat_map(|b| b.velocities()).map(speed).fold(fastest, f64::max);
            most_energy = most_energy.max(energy(&bodies));
        }
    }
    let lowest = bodies.iter().flat_map(|b| b.positions()).fold(f64::INFINITY, |m, x| m.min(x[2]));
    println!(
        "{steps} steps in {:.2} s ({:.2} s stepping): {:.0} body-steps/s, {:.3} ms per step of all bodies; lowest node z = {lowest:.4} m",
        start.elapsed().as_secs_f64(),
        stepping,
        (count * steps) as f64 / stepping,
        1e3 * stepping / steps as f64,
    );
    // plausibility: kinetic plus gravitational energy never above the start
    // (nothing but gravity supplies energy; damping and the plane take it)
    println!(
        "energy (kinetic + gravity): {start_energy:.2} J at the start, at most {most_energy:.2} J, {:.2} J at the end; fastest node {fastest:.2} m/s",
        energy(&bodies)
    );
    println!("frames in {}", dir.display());
    Ok(())
}
