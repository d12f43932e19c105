//! Criterion benchmarks of cutting during a simulation: from a cut to a
//! ready system (split, separation, rebuild of the touched elements, pattern
//! update, CG analysis), on a box of tetrahedra after one step. Rates are
//! per element the cut crosses (`Throughput::Elements`). And the health
//! check every element a cut makes goes through: the stiffness spectrum
//! estimate of a hexahedron's and a wedge's `K_e` (elements/s).

use criterion::{criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion, Throughput};

use cleave::mesh::Plane;
use cleave::meshing::box_tet;
use cleave::sim::{FixedRegion, Simulation, SimulationParams};
use cleave::solve::SolverKind;

/// A clamped 4 x 1 x 1 m bar of `cells` cubes (six tetrahedra each),
/// stepped once, solved by CG.
fn bar(cells: [usize; 3]) -> Simulation {
    let mesh = box_tet([0.0; 3], [4.0, 1.0, 1.0], cells).unwrap();
    let params = SimulationParams { solver: SolverKind::Cg, ..Default::default() };
    let mut sim = Simulation::new(mesh, params).unwrap();
    sim.fix(FixedRegion::clamp([-1.0; 3], [1e-3, 2.0, 2.0])).unwrap();
    sim.step().unwrap();
    sim
}

fn cut(c: &mut Criterion) {
    let mut group = c.benchmark_group("cut_to_ready");
    group.sample_size(10);
    for cells in [[40, 10, 10], [80, 20, 20]] {
        let elements = 6 * cells.iter().product::<usize>();
        // a slanted plane through the middle, and a blade square in it
        let plane = Plane { point: [2.03, 0.5, 0.5], normal: [1.0, 0.2, 0.1] };
        let blade = [[2.1, -0.1, 0.2], [1.98, 0.5, 0.2], [1.94, 0.5, 0.8], [2.06, -0.1, 0.8]];
        let crossed = |cut: &dyn Fn(&mut Simulation) -> (usize, usize)| {
            let (split, kept) = cut(&mut bar(cells));
            Throughput::Elements((split + kept) as u64)
        };
        group.throughput(crossed(&|sim| {
            let r = sim.cut_plane(&plane).unwrap();
            (r.split.split_elements.len(), r.split.kept_whole.len())
        }));
        group.bench_function(BenchmarkId::new("plane", elements), |b| {
            b.iter_batched(|| bar(cells), |mut sim| sim.cut_plane(&plane).unwrap(), BatchSize::PerIteration)
        });
        group.throughput(crossed(&|sim| {
            let r = sim.cut_polygon(&blade).unwrap().cut;
            (r.split.split_elements.len(), r.split.kept_whole.len())
        }));
        group.bench_function(BenchmarkId::new("blade", elements), |b| {
            b.iter_batched(|| bar(cells), |mut sim| sim.cut_polygon(&blade).unwrap(), BatchSize::PerIteration)
        });
    }
    group.finish();
}

/// `K_e` (row-major) of the polyhedron on `x` made of the tetrahedra
/// `tets`, each a linear element (E = 1e5 Pa, ν = 0.3): sound, with exactly
/// the rigid modes in its null space.
fn tetrahedral_stiffness(x: &[[f64; 3]], tets: &[[usize; 4]]) -> Vec<f64> {
    use cleave_kernels::{elasticity, tet};
    let n = 3 * x.len();
    let (lambda, mu) = elasticity::lame(1e5, 0.3);
    let mut k = vec![0.0; n * n];
    for t in tets {
        let (volume, g) = tet::gradients(&t.map(|a| x[a])).unwrap();
        for a in 0..4 {
            for b in 0..4 {
                let block = elasticity::block(g[a], g[b], volume.abs(), lambda, mu);
                for r in 0..3 {
                    for c in 0..3 {
                        k[(3 * t[a] + r) * n + 3 * t[b] + c] += block[3 * r + c];
                    }
                }
            }
        }
    }
    k
}

fn health(c: &mut Criterion) {
    use cleave_kernels::spectrum::{
        stiffness_certificates, stiffness_spectra, stiffness_spectrum, Certificate, RigidModes, Spectrum,
    };
    let mut group = c.benchmark_group("health_spectrum");
    let cube: Vec<[f64; 3]> = (0..8).map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64]).collect();
    let wedge: Vec<[f64; 3]> =
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]];
    let shapes = [
        (
            "hexahedron",
            tetrahedral_stiffness(
                &cube,
                &[[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7], [0, 5, 1, 7]],
            ),
            cube,
        ),
        ("wedge", tetrahedral_stiffness(&wedge, &[[0, 1, 2, 3], [1, 2, 3, 4], [2, 3, 4, 5]]), wedge),
    ];
    // one element alone, and a run of 32 (what the store's health check
    // gives one task: four AVX-512 or eight AVX2 lane groups)
    const RUN: usize = 32;
    for (name, k, x) in &shapes {
        group.throughput(Throughput::Elements(1));
        group.bench_function(*name, |b| b.iter(|| stiffness_spectrum(k, RigidModes::Nodal(x))));
        let ks: Vec<f64> = (0..RUN).flat_map(|_| k.iter().copied()).collect();
        let xs: Vec<[f64; 3]> = (0..RUN).flat_map(|_| x.iter().copied()).collect();
        let mut out = vec![Spectrum::default(); RUN];
        group.throughput(Throughput::Elements(RUN as u64));
        group.bench_function(format!("{name}_run_of_{RUN}"), |b| {
            b.iter(|| stiffness_spectra(&ks, RigidModes::Nodal(&xs), &mut out))
        });
        // the store's check: the floor on λ₇ certified, not λ₇ estimated
        let mut certified = vec![Certificate::default(); RUN];
        group.bench_function(format!("{name}_run_of_{RUN}_certified"), |b| {
            b.iter(|| stiffness_certificates(&ks, RigidModes::Nodal(&xs), 1e-6, &mut certified))
        });
    }
    group.finish();
}

criterion_group!(benches, cut, health);
criterion_main!(benches);
