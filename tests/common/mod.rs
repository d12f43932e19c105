//! Helpers shared by the cantilever tests.

use cleave::material::Material;
use cleave::mesh::PolyMesh;
use cleave::meshing::box_tet;
use cleave::sim::{FixedRegion, Simulation, SimulationParams};

/// Mean vertical deflection (m, positive down) of the tip face x = 4 of the
/// 4 x 1 x 1 m beam `mesh` clamped at x = 0 under self-weight
/// (E = 1e5 Pa, nu = 0.3, rho = 1000 kg/m^3).
pub fn tip_deflection(mesh: PolyMesh) -> f64 {
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

/// Tip deflections of the tetrahedral beams with 2, 4, 8, 16 cells across.
pub fn tet_sequence() -> Vec<f64> {
    [2, 4, 8, 16].iter().map(|&n| tip_deflection(box_tet([0.0; 3], [4.0, 1.0, 1.0], [4 * n, n, n]).unwrap())).collect()
}

/// Observed convergence rates of a sequence on meshes halved each time, and
/// the Richardson extrapolation of its limit with the last rate.
pub fn rates_and_limit(w: &[f64]) -> (Vec<f64>, f64) {
    let d: Vec<f64> = w.windows(2).map(|p| p[1] - p[0]).collect();
    let rates: Vec<f64> = d.windows(2).map(|q| (q[0] / q[1]).log2()).collect();
    let p = rates[rates.len() - 1];
    (rates, w[w.len() - 1] + d[d.len() - 1] / (2f64.powf(p) - 1.0))
}
