//! Convergence of the discontinuous Galerkin family on a manufactured
//! solution: `u*(x) = q sin(πx) sin(πy) sin(πz)` on the unit cube, clamped
//! (it vanishes on the boundary), under the body force that produces it,
//! `b = -[(λ + μ) ∇∇φ q + μ Δφ q]`. The L2 error of interior penalty falls
//! as `h²` for degree 1 and `h³` for degree 2 (fitted over three meshes,
//! asserted within 0.2) on grids and on grids cut into convex cells of
//! many shapes.

use std::f64::consts::PI;

use crate::common;

use cleave::material::Material;
use cleave::mesh::Plane;
use cleave::mesh::PolyMesh;
use cleave::meshing::{box_hex, box_tet};
use cleave::sim::{FixedRegion, Simulation, SimulationParams};
use cleave::store::dg::{DgOptions, Flux};
use cleave::store::{BasisOptions, Family};
use cleave::topology::{split_by_plane, SplitOptions};

const Q: [f64; 3] = [1e-3, -2e-3, 1.5e-3];

fn exact(x: [f64; 3]) -> [f64; 3] {
    let phi = (PI * x[0]).sin() * (PI * x[1]).sin() * (PI * x[2]).sin();
    Q.map(|q| q * phi)
}

/// `b = -[(λ + μ) H(φ) q + μ Δφ q]` (N/m³).
fn body_force(lambda: f64, mu: f64) -> impl Fn([f64; 3]) -> [f64; 3] + Send + Sync {
    move |x: [f64; 3]| {
        let (s, c): (Vec<f64>, Vec<f64>) = x.iter().map(|&v| ((PI * v).sin(), (PI * v).cos())).unzip();
        let phi = s[0] * s[1] * s[2];
        let h = |i: usize, j: usize| -> f64 {
            if i == j {
                -PI * PI * phi
            } else {
                let k = 3 - i - j;
                PI * PI * c[i] * c[j] * s[k]
            }
        };
        let laplacian = -3.0 * PI * PI * phi;
        std::array::from_fn(|i| -((lambda + mu) * (0..3).map(|j| h(i, j) * Q[j]).sum::<f64>() + mu * laplacian * Q[i]))
    }
}

/// The L2 error (m·m^1.5) of the solved field against `u*`.
fn l2_error(sim: &Simulation) -> f64 {
    let (mesh, dg) = (sim.mesh(), sim.dg().unwrap());
    let m = dg.size();
    let u = sim.block_displacements();
    let mut sum = 0.0;
    let mut n = vec![0.0; m];
    for e in 0..mesh.elements.len() {
        let (pts, wts) = common::element_cone_rule(mesh, e, 5);
        let basis = dg.basis(e as u32);
        for (p, w) in pts.iter().zip(&wts) {
            basis.values(*p, &mut n);
            let want = exact(*p);
            let got: [f64; 3] = std::array::from_fn(|k| (0..m).map(|a| u[e * m + a][k] * n[a]).sum());
            sum += w * (0..3).map(|k| (got[k] - want[k]).powi(2)).sum::<f64>();
        }
    }
    sum.sqrt()
}

/// The L2 error and mean element size on `mesh`.
fn solve(mesh: PolyMesh, degree: usize, flux: Flux) -> (f64, f64) {
    let material = Material::new(1e5, 0.3, 1000.0).unwrap();
    let (lambda, mu) = material.lame();
    let h = (1.0 / mesh.elements.len() as f64).cbrt();
    let params = SimulationParams {
        material,
        gravity: [0.0; 3],
        basis: BasisOptions { family: Family::Dg, dg: DgOptions { degree, flux, penalty: 1.0 }, ..Default::default() },
        ..Default::default()
    };
    let mut sim = Simulation::new(mesh, params).unwrap();
    sim.fix(FixedRegion::clamp([-1.0; 3], [2.0; 3])).unwrap();
    sim.set_body_force(body_force(lambda, mu)).unwrap();
    sim.solve_static().unwrap();
    (l2_error(&sim), h)
}

/// Least-squares slope of `log e` against `log h`.
fn rate(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    let (lx, ly): (Vec<f64>, Vec<f64>) = points.iter().map(|(e, h)| (h.ln(), e.ln())).unzip();
    let (mx, my) = (lx.iter().sum::<f64>() / n, ly.iter().sum::<f64>() / n);
    let sxy: f64 = lx.iter().zip(&ly).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = lx.iter().map(|x| (x - mx).powi(2)).sum();
    sxy / sxx
}

fn hexes(n: usize) -> PolyMesh {
    box_hex([0.0; 3], [1.0; 3], [n; 3]).unwrap()
}

fn tets(n: usize) -> PolyMesh {
    box_tet([0.0; 3], [1.0; 3], [n; 3]).unwrap()
}

/// `mesh` cut by three planes as a simulation cuts: convex cells of many
/// shapes (wedges, pentagonal prisms, cut corners) beside the uncut ones,
/// their size falling with the grid's.
fn cut(mut mesh: PolyMesh) -> PolyMesh {
    for (point, normal) in [
        ([0.37, 0.5, 0.5], [1.0, 0.4, 0.2]),
        ([0.5, 0.61, 0.5], [-0.3, 1.0, 0.5]),
        ([0.5, 0.5, 0.29], [0.2, -0.6, 1.0]),
    ] {
        split_by_plane(&mut mesh, &Plane { point, normal }, &SplitOptions::default()).unwrap();
    }
    mesh
}

/// The L2 errors `(e, h)` of `degree` and `flux` on `make(n)` for the grid
/// sizes `n` (`h = 1/n`).
fn errors(make: impl Fn(usize) -> PolyMesh, sizes: &[usize], degree: usize, flux: Flux) -> Vec<(f64, f64)> {
    sizes.iter().map(|&n| (solve(make(n), degree, flux).0, 1.0 / n as f64)).collect()
}

/// The rate over the two finest grids of `e`.
fn finest_rate(e: &[(f64, f64)]) -> f64 {
    rate(&e[e.len() - 2..])
}

/// Degree 2 on hexahedra and cut hexahedra at `h³` (fitted over three
/// grids). Degree 1 on tetrahedra at `h²` over the two finest of three
/// grids, and on cut tetrahedra at the same rate (within 0.15) and
/// accuracy: linear polynomials converge late, like the continuous linear
/// tetrahedra (local rates 1.24, 1.70, 1.87 from 2³ to 12³ cubes for both;
/// DG's errors are 2.2 times smaller), while the best approximation in the
/// space converges at 2 from the start: linear polynomials are stiff in
/// the shear a clamped bubble needs. On hexahedra they converge later
/// still (measured: 1.2 to 1.65 from 4³ to 16³); Babuška–Zlámal's flux,
/// not consistent, does not converge (measured: rate -0.13 from 2³ to 8³
/// tetrahedral cubes). Neither is asserted.
#[test]
fn interior_penalty_converges_at_order_p_plus_one_in_l2() {
    type Case = (&'static str, fn(usize) -> PolyMesh, usize, &'static [usize]);
    let cases: [Case; 4] = [
        ("hexahedra", hexes, 2, &[2, 4, 8]),
        ("cut hexahedra", |n| cut(hexes(n)), 2, &[2, 4, 8]),
        ("tetrahedra", tets, 1, &[6, 9, 12]),
        ("cut tetrahedra", |n| cut(tets(n)), 1, &[6, 9, 12]),
    ];
    let mut linear: Vec<(f64, Vec<(f64, f64)>)> = Vec::new();
    for (label, make, degree, sizes) in cases {
        let e = errors(make, sizes, degree, Flux::Ip);
        let (fitted, finest) = (rate(&e), finest_rate(&e));
        println!("IP degree {degree} on {label}: (L2 error, h) {e:?}, fitted rate {fitted:.2}, finest {finest:.2}");
        if degree == 2 {
            assert!((fitted - 3.0).abs() < 0.2, "IP degree 2 on {label}: rate {fitted:.2}, want 3");
        } else {
            linear.push((finest, e));
        }
    }
    let [(tets_rate, tets_errors), (cut_rate, cut_errors)] = &linear[..] else { unreachable!() };
    assert!((tets_rate - 2.0).abs() < 0.2, "IP degree 1 on tetrahedra: rate {tets_rate:.2}, want 2");
    assert!((cut_rate - tets_rate).abs() < 0.15, "cut tetrahedra converge at {cut_rate:.2}, uncut at {tets_rate:.2}");
    for ((a, h), (b, _)) in tets_errors.iter().zip(cut_errors) {
        assert!(*b < 1.2 * a, "h = {h:.3}: cut {b:.3e} vs uncut {a:.3e}");
    }
}
