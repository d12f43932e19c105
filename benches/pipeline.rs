//! Criterion benchmarks of the static pipeline on a box of tetrahedra:
//! element stiffness build, pattern build, assembly, Cholesky factorisation
//! and solve (on the larger box a factor of about 5M values: the triangular
//! solves run in parallel over the elimination tree).
//! Rates are reported per element (`Throughput::Elements`).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

use cleave::assembly::SparsePattern;
use cleave::material::Material;
use cleave::meshing::box_tet;
use cleave::solve::{Cholesky, LinearSolver};
use cleave::store::ElementStore;

fn pipeline(c: &mut Criterion) {
    let material = Material::new(1e5, 0.3, 1000.0).unwrap();
    let mut group = c.benchmark_group("tet_pipeline");
    group.sample_size(10);
    for cells in [[16, 4, 4], [40, 10, 10]] {
        let mesh = box_tet([0.0; 3], [4.0, 1.0, 1.0], cells).unwrap();
        let n = mesh.elements.len();
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::new("stiffness", n), &mesh, |b, m| {
            b.iter(|| ElementStore::build(m, &material, &Default::default()).unwrap())
        });
        let store = ElementStore::build(&mesh, &material, &Default::default()).unwrap();
        group.bench_with_input(BenchmarkId::new("pattern", n), &store, |b, s| {
            b.iter(|| SparsePattern::build(mesh.nodes.len(), s))
        });
        let pattern = SparsePattern::build(mesh.nodes.len(), &store);
        let mut values = vec![0.0; pattern.nnz()];
        group.bench_function(BenchmarkId::new("assembly", n), |b| {
            b.iter(|| pattern.assemble(&mut values, |b, i, c, out| store.batches[b].block_column(i, c, out)))
        });
        for d in 0..3 * mesh.nodes.len() {
            values[pattern.diagonal_slot(d)] += 1e3;
        }
        let mut chol = Cholesky::default();
        chol.analyze(pattern.symbolic()).unwrap();
        group.bench_function(BenchmarkId::new("cholesky_numeric", n), |b| {
            b.iter(|| chol.factor(pattern.matrix(&values)).unwrap())
        });
        // (factored here too: a filter may skip the factorisation's bench)
        chol.factor(pattern.matrix(&values)).unwrap();
        let rhs: Vec<f64> = (0..3 * mesh.nodes.len()).map(|i| (i as f64 * 0.37).sin()).collect();
        let mut x = rhs.clone();
        group.bench_function(BenchmarkId::new("cholesky_solve", n), |b| {
            b.iter(|| {
                x.copy_from_slice(&rhs);
                chol.solve_in_place(&mut x).unwrap()
            })
        });
    }
    group.finish();
}

criterion_group!(benches, pipeline);
criterion_main!(benches);
