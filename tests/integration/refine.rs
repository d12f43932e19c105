//! Stress-based refinement (martin2008 Fig. 8): a bent bar refined where
//! its stress is high approaches the fine mesh's deflection with fewer
//! elements than uniform refinement; volume, state and health hold.

use cleave::meshing::box_hex;
use cleave::sim::{FixedRegion, RefineRule, RefineSplit, Simulation, SimulationParams};

/// The bar of 36 hexahedra (or `refine` times finer per axis), held at
/// both ends, sagging under its own weight.
fn bar(refine: usize) -> Simulation {
    let r = refine;
    let mesh = box_hex([0.0; 3], [4.5, 1.0, 1.0], [9 * r, 2 * r, 2 * r]).unwrap();
    let mut params = SimulationParams { gravity: [0.0, 0.0, -9.81], ..Default::default() };
    params.material.young = 1e6;
    let mut sim = Simulation::new(mesh, params).unwrap();
    for (lo, hi) in [(-1.0, 0.001), (4.499, 6.0)] {
        sim.fix(FixedRegion::clamp([lo, -1.0, -1.0], [hi, 2.0, 2.0])).unwrap();
    }
    sim
}

/// The sag measured as the compliance `Σ_i m_i g u_i` over the bar's
/// weight `Σ_i m_i g` (m): the weighted mean deflection, which a
/// conforming refinement approaches from below.
fn sag(sim: &Simulation) -> f64 {
    let m = sim.masses();
    let work: f64 = m.iter().zip(sim.displacements()).map(|(m, u)| -m * u[2]).sum();
    work / m.iter().sum::<f64>()
}

#[test]
fn refining_where_the_stress_is_high_beats_uniform_refinement() {
    let reference = {
        let mut s = bar(4);
        s.solve_static().unwrap();
        sag(&s)
    };
    let mut coarse = bar(1);
    coarse.solve_static().unwrap();
    let mut uniform = bar(2);
    uniform.solve_static().unwrap();
    let mut adaptive = bar(1);
    adaptive.solve_static().unwrap();
    let volume = adaptive.mesh().total_volume();
    let rule = RefineRule { threshold: 1.8e4, split: RefineSplit::Halves, max_level: 2 };
    loop {
        let before = adaptive.displacements().to_vec();
        let n = adaptive.mesh().nodes.len();
        let report = adaptive.refine_by_stress(&rule).unwrap();
        // the old nodes keep their state; new nodes lie between old ones
        assert_eq!(&adaptive.displacements()[..n], &before[..]);
        assert!(adaptive.displacements().iter().flatten().all(|x| x.is_finite()));
        if report.refined == 0 {
            break;
        }
        adaptive.solve_static().unwrap();
        assert!((adaptive.mesh().total_volume() - volume).abs() < 1e-12 * volume);
        adaptive.mesh().validate().unwrap();
    }
    let err = |s: &Simulation| (sag(s) - reference).abs() / reference;
    let (na, nu) = (adaptive.mesh().elements.len(), uniform.mesh().elements.len());
    println!(
        "sag: fine ({} elements) {reference:.5e} m; coarse 36: error {:.2e}; uniform {nu}: {:.2e}; adaptive {na}: {:.2e}",
        9 * 2 * 2 * 64,
        err(&coarse),
        err(&uniform),
        err(&adaptive)
    );
    assert!(na < nu, "adaptive {na} < uniform {nu}");
    assert!(err(&adaptive) < err(&coarse));
}
