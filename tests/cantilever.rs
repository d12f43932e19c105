//! The 4 x 1 x 1 m cantilever under self-weight (E = 1e5 Pa, nu = 0.3,
//! rho = 1000 kg/m^3) converges under refinement to a tip deflection
//! between Euler-Bernoulli (37.67 m) and Timoshenko (40.12 m) theory.

use cleave::material::Material;
use cleave::meshing::box_tet;
use cleave::sim::{FixedRegion, Simulation, SimulationParams};

/// Mean vertical displacement of the tip face x = 4 (m, positive down).
fn tip_deflection(cells: [usize; 3]) -> f64 {
    let mesh = box_tet([0.0; 3], [4.0, 1.0, 1.0], cells).unwrap();
    let params = SimulationParams { material: Material::new(1e5, 0.3, 1000.0).unwrap(), ..Default::default() };
    let mut sim = Simulation::new(mesh, params).unwrap();
    sim.fix(FixedRegion::clamp([-1.0; 3], [1e-3, 2.0, 2.0])).unwrap();
    let stats = sim.solve_static().unwrap();
    assert!(stats.residual < 1e-9, "residual {}", stats.residual);
    let tip: Vec<f64> = sim
        .mesh()
        .nodes
        .iter()
        .zip(sim.displacements())
        .filter(|(x, _)| x[0] > 4.0 - 1e-9)
        .map(|(_, u)| -u[2])
        .collect();
    tip.iter().sum::<f64>() / tip.len() as f64
}

#[test]
fn tip_deflection_converges_between_beam_theories() {
    let levels = [[8, 2, 2], [16, 4, 4], [32, 8, 8], [64, 16, 16]];
    let w: Vec<f64> = levels.iter().map(|&c| tip_deflection(c)).collect();
    for (c, d) in levels.iter().zip(&w) {
        println!("cells {c:?}: tip deflection {d:.4} m");
    }
    // linear tetrahedra are too stiff: the deflection grows monotonically
    assert!(w.windows(2).all(|p| p[1] > p[0]), "{w:?}");
    // the increments shrink, and on the finest pair at a rate approaching the
    // asymptotic O(h^2) of linear elements (the coarse pairs are
    // pre-asymptotic: 2 cells across the height cannot bend)
    let d: Vec<f64> = w.windows(2).map(|p| p[1] - p[0]).collect();
    let rates: Vec<f64> = d.windows(2).map(|q| (q[0] / q[1]).log2()).collect();
    println!("increments {d:?}, observed rates {rates:?}");
    assert!(d.windows(2).all(|q| q[1] < q[0]), "{d:?}");
    assert!(rates.windows(2).all(|r| r[1] > r[0]), "rates grow towards 2: {rates:?}");
    assert!(rates[rates.len() - 1] > 1.2 && rates[rates.len() - 1] < 2.5, "{rates:?}");
    assert!(w[3] > 37.67, "the finest mesh already passes Euler-Bernoulli: {}", w[3]);
    // Richardson extrapolation with the last observed rate
    let p = rates[rates.len() - 1];
    let limit = w[3] + d[2] / (2f64.powf(p) - 1.0);
    println!("extrapolated limit {limit:.3} m");
    assert!(limit > 37.67 && limit < 40.12, "limit {limit}");
}
