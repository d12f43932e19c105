//! The 4 x 1 x 1 m cantilever under self-weight (E = 1e5 Pa, nu = 0.3,
//! rho = 1000 kg/m^3) on tetrahedra converges under refinement to a tip
//! deflection between Euler-Bernoulli (37.67 m) and Timoshenko (40.12 m).

mod common;

#[test]
fn tip_deflection_converges_between_beam_theories() {
    let w = common::tet_sequence();
    println!("tip deflections (2, 4, 8, 16 cells across): {w:?}");
    // linear tetrahedra are too stiff: the deflection grows monotonically
    assert!(w.windows(2).all(|p| p[1] > p[0]), "{w:?}");
    // the increments shrink, and the observed rate grows towards the
    // asymptotic O(h^2) of linear elements (coarse pairs are pre-asymptotic:
    // 2 cells across the height cannot bend)
    let (rates, limit) = common::rates_and_limit(&w);
    println!("observed rates {rates:?}, extrapolated limit {limit:.3} m");
    assert!(rates.windows(2).all(|r| r[1] > r[0]), "{rates:?}");
    assert!(rates[rates.len() - 1] > 1.2 && rates[rates.len() - 1] < 2.5, "{rates:?}");
    assert!(w[3] > 37.67, "the finest mesh already passes Euler-Bernoulli: {}", w[3]);
    assert!(limit > 37.67 && limit < 40.12, "limit {limit}");
}
