//! Criterion benchmarks of harmonic (MFS) elements: basis construction and
//! `K_e` per element (elements/s) for convex elements with 8, 12, 24 and
//! 40 vertices, and the evaluation kernel (points/s).

use cleave_kernels::dyn_stack::{MemBuffer, MemStack};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

use cleave::material::Material;
use cleave::meshing::{element_with_vertices, replicate};
use cleave::store::{harmonic, BasisOptions, ElementStore, Family, HarmonicOptions};

fn options() -> BasisOptions {
    BasisOptions {
        family: Family::Harmonic,
        harmonic: HarmonicOptions { trilinear_hexahedra: false, ..Default::default() },
        ..Default::default()
    }
}

fn construction(c: &mut Criterion) {
    let material = Material::new(1e5, 0.3, 1000.0).unwrap();
    let mut group = c.benchmark_group("harmonic_basis_and_stiffness");
    group.sample_size(10);
    for k in [8, 12, 24, 40] {
        let Some(one) = element_with_vertices(k) else { continue };
        let batch = replicate(&one, 20).unwrap();
        group.throughput(Throughput::Elements(20));
        group.bench_function(BenchmarkId::new("build_20", k), |b| {
            b.iter(|| ElementStore::build(&batch, &material, &options()).unwrap())
        });
    }
    group.finish();
}

fn evaluation(c: &mut Criterion) {
    let mut group = c.benchmark_group("harmonic_eval");
    let opts = options().harmonic;
    for k in [8, 12, 24, 40] {
        let Some(one) = element_with_vertices(k) else { continue };
        let faces = harmonic::face_bases(&one, &[0], &opts).unwrap();
        let basis = harmonic::element_basis(&one, 0, &faces, &opts).unwrap();
        let c0 = one.element_centroid(0);
        let pts: Vec<[f64; 3]> = one.nodes.iter().map(|p| std::array::from_fn(|i| 0.7 * c0[i] + 0.3 * p[i])).collect();
        let (mut phi, mut grad) = (vec![0.0; k * pts.len()], vec![0.0; 3 * k * pts.len()]);
        group.throughput(Throughput::Elements(pts.len() as u64));
        group.bench_function(BenchmarkId::new("simd", k), |b| {
            let mut buf = MemBuffer::new(cleave_kernels::harmonic::evaluate_scratch(k));
            b.iter(|| {
                cleave_kernels::harmonic::evaluate(
                    &basis.functions(),
                    &pts,
                    &mut phi,
                    &mut grad,
                    MemStack::new(&mut buf),
                )
            })
        });
    }
    group.finish();
}

criterion_group!(benches, construction, evaluation);
criterion_main!(benches);
