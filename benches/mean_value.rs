//! Criterion benchmarks of mean value elements: basis evaluation (points/s,
//! SIMD and scalar reference) and the element stiffness build
//! (elements/s) for batches of elements with 8, 12, 16 and 24 vertices.

use cleave_kernels::dyn_stack::{MemBuffer, MemStack};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

use cleave::material::Material;
use cleave::meshing::{element_with_vertices, replicate};
use cleave::store::{BasisOptions, ElementStore};
use cleave_kernels::{mean_value, quadrature};

fn basis(c: &mut Criterion) {
    let mut group = c.benchmark_group("mean_value_basis");
    for k in [8, 12, 16, 24] {
        let mesh = element_with_vertices(k).expect("a clipped box with k vertices");
        let nodes = &mesh.elements[0].nodes;
        let verts: Vec<[f64; 3]> = nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
        let tris: Vec<[u32; 3]> =
            mesh.element_triangles(0).map(|t| t.map(|g| nodes.binary_search(&g).unwrap() as u32)).collect();
        let nq = quadrature::paper_rule_len(k, tris.len());
        let (mut p, mut w, mut mu) = (vec![[0.0; 3]; nq], vec![0.0; nq], vec![0.0; k]);
        quadrature::paper_rule(&verts, &tris, &mut p, &mut w, &mut mu);
        let (mut phi, mut grad) = (vec![0.0; k * nq], vec![0.0; 3 * k * nq]);
        group.throughput(Throughput::Elements(nq as u64));
        group.bench_function(BenchmarkId::new("simd", k), |b| {
            let mut buf = MemBuffer::new(mean_value::evaluate_scratch(k, tris.len()));
            b.iter(|| mean_value::evaluate(&verts, &tris, &p, &mut phi, &mut grad, MemStack::new(&mut buf)))
        });
        group.bench_function(BenchmarkId::new("scalar", k), |b| {
            let mut buf = MemBuffer::new(mean_value::evaluate_scratch(k, tris.len()));
            b.iter(|| mean_value::evaluate_scalar(&verts, &tris, &p, &mut phi, &mut grad, MemStack::new(&mut buf)))
        });
    }
    group.finish();
}

fn stiffness(c: &mut Criterion) {
    let material = Material::new(1e5, 0.3, 1000.0).unwrap();
    let mut group = c.benchmark_group("mean_value_stiffness");
    group.sample_size(10);
    for k in [8, 12, 16, 24] {
        let one = element_with_vertices(k).expect("a clipped box with k vertices");
        let batch = replicate(&one, 10_000).unwrap();
        group.throughput(Throughput::Elements(10_000));
        group.bench_function(BenchmarkId::new("build_10k", k), |b| {
            b.iter(|| ElementStore::build(&batch, &material, &BasisOptions::default()).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, basis, stiffness);
criterion_main!(benches);
