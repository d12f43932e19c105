//! Cuts through deformed, moving bodies never build an element with a soft
//! mode nor leave a node with a negligible mass, and a cut keeps the
//! momenta exactly and the energy to a stated tolerance (issue 11).
//!
//! Every element a cut touches is checked with a full eigendecomposition
//! (faer), independent of the store's own estimate: exactly six eigenvalues
//! of `K_e` within `1e-10 λmax` of zero (the rigid modes), none below
//! `-1e-12 λmax`, and `λ7 / λmax` above the store's floor.

use cleave::io::read_mesh;
use cleave::mesh::Plane;
use cleave::mesh::PolyMesh;
use cleave::meshing::random_convex;
use cleave::sim::{Collider, Simulation, SimulationParams};
use cleave::store::{BasisOptions, HealthFloors};
use cleave::topology::{merge_slivers, SplitOptions};
use faer::{Mat, Side};
use rand_chacha::rand_core::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::common;

/// What the cuts of a run left at worst.
#[derive(Debug)]
struct Worst {
    /// Smallest `λ7 / λmax` of a touched element.
    ratio: f64,
    /// Smallest node mass over the mean nodal mass of its elements.
    mass: f64,
    /// Largest relative change of linear and angular momentum at a cut.
    momentum: f64,
    /// Largest relative gain and loss of kinetic plus elastic energy at a
    /// cut.
    energy_gain: f64,
    energy_loss: f64,
    /// Cuts made.
    cuts: usize,
    /// Cuts the simulation ran again keeping an unhealthy part's element
    /// whole.
    retries: usize,
}

impl Worst {
    fn new() -> Self {
        Worst {
            ratio: f64::INFINITY,
            mass: f64::INFINITY,
            momentum: 0.0,
            energy_gain: 0.0,
            energy_loss: 0.0,
            cuts: 0,
            retries: 0,
        }
    }
}

fn uniform(rng: &mut ChaCha8Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

/// The exact spectrum checks of the module docs on `elements`; returns the
/// smallest `λ7 / λmax`. With `strict`, a bad spectrum fails the test.
fn check_spectra(sim: &Simulation, elements: &[u32], strict: bool) -> f64 {
    let store = sim.store();
    let mut worst = f64::INFINITY;
    for &e in elements {
        let (b, i) = store.locate[e as usize];
        let batch = &store.batches[b as usize];
        let n = 3 * batch.k;
        let ke = batch.element_matrix(i as usize);
        let ev = Mat::<f64>::from_fn(n, n, |r, c| ke[r * n + c]).self_adjoint_eigenvalues(Side::Lower).unwrap();
        let top = ev[n - 1];
        let zeros = ev.iter().filter(|l| l.abs() <= 1e-10 * top).count();
        let ratio = ev[6] / top;
        worst = worst.min(ratio);
        if strict {
            assert_eq!(zeros, 6, "element {e} ({} nodes): {zeros} zero modes, λ7/λmax {ratio:.2e}", batch.k);
            assert!(ev[0] >= -1e-12 * top, "element {e}: negative eigenvalue {:.3e} of {top:.3e}", ev[0]);
            let floor = HealthFloors::default().stiffness_ratio;
            assert!(ratio >= floor, "element {e} ({} nodes): soft mode, λ7/λmax {ratio:.2e}", batch.k);
        }
    }
    worst
}

fn relative_change(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt();
    d / (0..3).map(|i| a[i] * a[i]).sum::<f64>().sqrt().max(f64::MIN_POSITIVE)
}

/// Drops `mesh` (moving at 2 m/s, onto a plane below it) and cuts it
/// `cuts` times with random planes (one in four) and random rectangles
/// through its bounding box, two steps apart, checking every cut.
fn cut_while_moving(mesh: PolyMesh, params: SimulationParams, cuts: usize, seed: u64, strict: bool) -> Worst {
    let (lo, hi) = mesh.bounding_box();
    let size = (0..3).map(|i| (hi[i] - lo[i]).powi(2)).sum::<f64>().sqrt();
    let young = params.material.young;
    let mut sim = Simulation::new(mesh, params).unwrap();
    let below = [lo[0], lo[1], lo[2] - 0.05 * size];
    sim.add_collider(Collider::new(below, [0.0, 0.0, 1.0], 1e3 * young * size).unwrap());
    let v = vec![[0.3, -0.2, -2.0]; sim.mesh().nodes.len()];
    sim.set_velocities(&v).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut worst = Worst::new();
    worst.mass = sim.min_mass_ratio().value;
    for c in 0..cuts {
        for _ in 0..2 {
            sim.step().unwrap();
        }
        let point: [f64; 3] = std::array::from_fn(|i| lo[i] + (0.15 + 0.7 * uniform(&mut rng)) * (hi[i] - lo[i]));
        let normal: [f64; 3] = std::array::from_fn(|_| 2.0 * uniform(&mut rng) - 1.0);
        let plane = Plane { point, normal };
        let (p0, l0) = (sim.linear_momentum(), sim.angular_momentum());
        let e0 = sim.kinetic_energy() + sim.elastic_energy();
        let touched = if c % 4 == 0 {
            sim.cut_plane(&plane).unwrap().touched
        } else {
            let half = (size * (0.1 + 0.3 * uniform(&mut rng)), size * (0.1 + 0.3 * uniform(&mut rng)));
            let polygon = common::rectangle_in_plane(&plane, half, 3.0 * uniform(&mut rng));
            sim.cut_polygon(&polygon).unwrap().cut.touched
        };
        worst.cuts += 1;
        worst.ratio = worst.ratio.min(check_spectra(&sim, &touched, strict));
        worst.mass = worst.mass.min(sim.min_mass_ratio().value);
        let (p1, l1) = (sim.linear_momentum(), sim.angular_momentum());
        worst.momentum = worst.momentum.max(relative_change(p0, p1)).max(relative_change(l0, l1));
        let e1 = sim.kinetic_energy() + sim.elastic_energy();
        worst.energy_gain = worst.energy_gain.max((e1 - e0) / e0);
        worst.energy_loss = worst.energy_loss.max((e0 - e1) / e0);
    }
    worst.retries = sim.cut_retries();
    worst
}

fn bunny() -> PolyMesh {
    let mut mesh = read_mesh(&common::asset("bunny_5k.mesh")).unwrap();
    merge_slivers(&mut mesh, 0.02).unwrap();
    mesh
}

fn params() -> SimulationParams {
    SimulationParams {
        material: cleave::material::Material::new(5e6, 0.35, 1000.0).unwrap(),
        mass_damping: 0.3,
        stiffness_damping: 0.002,
        ..Default::default()
    }
}

/// The floors this test holds every cut to; `energy` bounds the relative
/// change of kinetic plus elastic energy at a cut.
fn assert_healthy(label: &str, w: &Worst, energy: f64) {
    println!("{label}: {w:?}");
    let floors = HealthFloors::default();
    // the store checks an estimate of λ7/λmax that may read a few percent
    // high (inverse and power iteration), so the exact value may sit just
    // below its floor
    assert!(w.ratio >= 0.9 * floors.stiffness_ratio, "{label}: λ7/λmax {:.2e}", w.ratio);
    assert!(w.mass >= floors.mass_fraction, "{label}: mass ratio {:.2e}", w.mass);
    // the momenta are restored exactly, up to rounding
    assert!(w.momentum < 1e-12, "{label}: momentum changed by {:.2e}", w.momentum);
    assert!(w.energy_gain < energy && w.energy_loss < energy, "{label}: energy changed by {w:?}");
}

#[test]
fn cutting_a_moving_bunny_makes_no_soft_element_and_no_light_node() {
    for seed in 0..4 {
        let w = cut_while_moving(bunny(), params(), 30, seed, true);
        // measured up to 4e-4: the state of a new node is interpolated
        // linearly along its edge, where the shape functions of a
        // polyhedron are not linear
        assert_healthy(&format!("bunny_5k, seed {seed}"), &w, 1e-3);
    }
}

#[test]
fn cutting_moving_random_convex_boxes_makes_no_soft_element_and_no_light_node() {
    for seed in 0..10 {
        let mesh = random_convex([0.0; 3], [1.0, 0.8, 0.6], 6, seed).unwrap();
        let w = cut_while_moving(mesh, params(), 20, 100 + seed, true);
        // coarse: a cut rebuilds a third of the 20-60 cells; measured up
        // to 4.2e-2
        assert_healthy(&format!("random convex box, seed {seed}"), &w, 5e-2);
    }
}

/// The test can fail: without snapping and without keeping unhealthy
/// elements whole (and with the store's health check off), the same kind
/// of cuts makes soft elements (issue 11 measured 1e-11 on the bunny).
#[test]
fn without_snapping_the_same_cuts_make_soft_elements() {
    let lax = HealthFloors { stiffness_ratio: 0.0, mass_fraction: 0.0, rigid_residual: f64::INFINITY };
    let params = SimulationParams {
        basis: BasisOptions { health: lax, ..Default::default() },
        cut: SplitOptions { snap: 1e-4, min_spacing: 0.0, ..Default::default() },
        ..params()
    };
    let w = cut_while_moving(bunny(), params, 30, 0, false);
    println!("without snapping: {w:?}");
    assert!(w.ratio < HealthFloors::default().stiffness_ratio, "λ7/λmax {:.2e}", w.ratio);
}

/// Cuts through one place compound: each split keeps its parts above about
/// the snapping radius of their element, but the parts of parts shrink
/// geometrically. Forty planes in random directions through points within
/// a twentieth of an element of one point make no part smaller than the
/// floor (`min_part` of the median element diameter); with the floor off,
/// the same cuts make parts several times smaller than it.
#[test]
fn cuts_through_one_place_make_no_part_below_the_floor() {
    let smallest_part = |min_part: f64| {
        let mesh = bunny();
        let floor = SimulationParams::default().min_part * mesh.median_element_diameter();
        let mut sim = Simulation::new(mesh, SimulationParams { min_part, ..params() }).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let centre = sim.mesh().element_centroid(1000);
        let mut smallest = f64::INFINITY;
        for _ in 0..40 {
            let normal: [f64; 3] = std::array::from_fn(|_| uniform(&mut rng) - 0.5);
            let point = std::array::from_fn(|k| centre[k] + 0.5 * floor * (uniform(&mut rng) - 0.5));
            let Ok(report) = sim.cut_plane(&Plane { point, normal }) else { continue };
            for &(kept, new) in &report.split.split_elements {
                for e in [kept, new] {
                    smallest = smallest.min(sim.mesh().element_diameter(e as usize));
                }
            }
        }
        (smallest, floor)
    };
    let (with, floor) = smallest_part(SimulationParams::default().min_part);
    let (without, _) = smallest_part(0.0);
    println!("smallest part: {with:.3e} m with the floor {floor:.3e} m, {without:.3e} m without");
    assert!(with >= floor, "a part of {with:.3e} m under the floor {floor:.3e} m");
    assert!(without < 0.5 * floor, "without the floor the cuts made no part under it: {without:.3e} m");
}
