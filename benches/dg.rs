//! Criterion benchmarks of the discontinuous Galerkin family on
//! kaufmann2008's Table 1 mesh (10x10x10 hexahedra): integration (element
//! terms and face terms) and the assembly of the rest stiffness, per flux
//! and degree. Rates are per element. `cleave bench --only dg` prints the
//! same stages beside the paper's times, with the solve and a cut.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

use cleave::assembly::SparsePattern;
use cleave::dg::DgElements;
use cleave::material::Material;
use cleave::meshing::box_hex;
use cleave::sim::Discretization;
use cleave::store::dg::{DgOptions, Flux};
use cleave::store::{BasisOptions, ElementStore, Family};

fn table1(c: &mut Criterion) {
    let material = Material::new(1e5, 0.3, 1000.0).unwrap();
    let mesh = box_hex([0.0; 3], [1.0; 3], [10; 3]).unwrap();
    let mut group = c.benchmark_group("dg_table1");
    group.sample_size(10);
    group.throughput(Throughput::Elements(mesh.elements.len() as u64));
    for (degree, flux) in [(1, Flux::Bz), (1, Flux::Ip), (2, Flux::Bz), (2, Flux::Ip)] {
        let options = DgOptions { degree, flux, penalty: 4.0 };
        let basis = BasisOptions { family: Family::Dg, dg: options, ..Default::default() };
        let name = format!("{flux:?}_p{degree}");
        group.bench_function(BenchmarkId::new("integration", &name), |b| {
            b.iter(|| {
                let store = ElementStore::build(&mesh, &material, &basis).unwrap();
                DgElements::new(&mesh, store, options, &[])
            })
        });
        let store = ElementStore::build(&mesh, &material, &basis).unwrap();
        let dg = DgElements::new(&mesh, store, options, &[]);
        let pattern = SparsePattern::build(dg.num_blocks(), &dg);
        let mut values = vec![0.0; pattern.nnz()];
        group.bench_function(BenchmarkId::new("assembly", &name), |b| {
            b.iter(|| pattern.assemble(&mut values, |g, e, blk, out| dg.rest_stiffness_column(g, e, blk, out)))
        });
    }
    group.finish();
}

criterion_group!(benches, table1);
criterion_main!(benches);
