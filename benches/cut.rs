//! Criterion benchmarks of cutting during a simulation: from a cut to a
//! ready system (split, separation, rebuild of the touched elements, pattern
//! update, CG analysis), on a box of tetrahedra after one step. Rates are
//! per element the cut crosses (`Throughput::Elements`).

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

criterion_group!(benches, cut);
criterion_main!(benches);
