//! Reading stress: a cantilever of random convex cells, clamped at one end,
//! solved statically under its own weight; the most stressed element and
//! the stress near the clamp against the free end.
//!
//! ```text
//! cargo run --release --example read_stress
//! ```

use cleave::material::Material;
use cleave::meshing::random_convex;
use cleave::sim::{FixedRegion, Simulation, SimulationParams};

fn main() -> Result<(), cleave::Error> {
    let mesh = random_convex([0.0; 3], [2.0, 0.4, 0.4], 40, 7)?;
    let params = SimulationParams {
        material: Material::new(1e7, 0.3, 1000.0)?,
        gravity: [0.0, 0.0, -9.81],
        ..Default::default()
    };
    let mut sim = Simulation::new(mesh, params)?;
    sim.fix(FixedRegion::clamp([-1.0; 3], [1e-3, 1.0, 1.0]))?;
    sim.solve_static()?;
    let stress = sim.von_mises(); // Pa, one per element
    let (worst, most) = stress.iter().enumerate().fold((0, 0.0f64), |w, (e, &s)| if s > w.1 { (e, s) } else { w });
    let centroid = sim.mesh().element_centroid(worst);
    println!(
        "{} elements; the most stressed, {worst}, carries {most:.3e} Pa at x = {:.2} m",
        stress.len(),
        centroid[0]
    );
    let mean_where = |lo: f64, hi: f64| {
        let (sum, n) = (0..stress.len())
            .filter(|&e| (lo..hi).contains(&sim.mesh().element_centroid(e)[0]))
            .fold((0.0, 0), |(s, n), e| (s + stress[e], n + 1));
        sum / f64::from(n.max(1))
    };
    println!("mean von Mises near the clamp (x < 0.4 m): {:.3e} Pa", mean_where(0.0, 0.4));
    println!("mean von Mises at the free end (x > 1.6 m): {:.3e} Pa", mean_where(1.6, 2.0));
    Ok(())
}
