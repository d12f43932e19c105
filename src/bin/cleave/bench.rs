//! The throughput suite behind `cleave bench`: wall time of each pipeline
//! stage on generated meshes and the bunny assets (found beside the crate's
//! manifest, whatever the working directory), reported with mesh sizes and
//! rates.

use std::time::Instant;

use serde::Serialize;

use cleave::assembly::SparsePattern;
use cleave::dg::DgElements;
use cleave::material::Material;
use cleave::mesh::{Plane, PolyMesh};
use cleave::meshing::{box_hex, box_tet, element_with_vertices, random_convex, replicate};
use cleave::sim::{Collider, FixedRegion, Simulation, SimulationParams};
use cleave::solve::{Cholesky, LinearSolver, SolverKind};
use cleave::store::dg::{DgOptions, Flux};
use cleave::store::{BasisOptions, ElementStore, Family};
use cleave::topology::{split_by_plane, SplitOptions};
use cleave::Error;
use cleave_kernels::lanes::{cap_simd_level, dispatched_level, SimdLevel};

/// A shipped asset, by its path in the crate (`assets/...`).
fn asset(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets").join(name)
}

/// `path` if the file is there; else says on stderr which rows are left
/// out and why (the suite reads its meshes from the source tree it was
/// built from, so a binary moved away from it, or a tree without the
/// shared data, runs without them).
fn present(path: std::path::PathBuf, rows: &str) -> Option<std::path::PathBuf> {
    if path.exists() {
        return Some(path);
    }
    eprintln!("bench: {rows} rows left out: {} not found", path.display());
    None
}

/// The highest instruction set the engine's kernels may use in a run of
/// the suite (see [`cap_simd_level`]): to measure the AVX2 path, or the
/// scalar one, on a machine with more. faer's own products choose theirs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MaxSimd {
    /// Plain `f64` (pulp's scalar backend).
    Scalar,
    /// x86-64-v3: AVX2.
    Avx2,
    /// x86-64-v4: AVX-512 (the best the machine offers, as without a cap).
    Avx512,
}

impl MaxSimd {
    fn level(self) -> SimdLevel {
        match self {
            MaxSimd::Scalar => SimdLevel::Scalar,
            MaxSimd::Avx2 => SimdLevel::Avx2,
            MaxSimd::Avx512 => SimdLevel::Avx512,
        }
    }
}

/// A part of the suite, to run alone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Group {
    /// Tetrahedral element build, pattern, assembly, Cholesky phases.
    Pipeline,
    /// Mean value and harmonic basis evaluation and element build.
    Basis,
    /// kaufmann2008 Table 1: DG integration, assembly and solve, and cuts.
    Dg,
    /// Global assembly, corotated steps and cuts on large meshes.
    Steps,
    /// Meshing surfaces (grid slicing, octree), embedded-surface updates
    /// and refinement steps.
    Meshing,
    /// Small bodies: one step of bodies of 1 to 300 elements, and 256
    /// bodies stepped together.
    Bodies,
    /// Every SIMD kernel against its scalar reference, at AVX2 and at
    /// AVX-512 (where the machine has them).
    Simd,
    /// The work `benches/peers` gives the peers, on bunny_100k: `K_e`,
    /// pattern, assembly, the Cholesky phases of `K + 10³ I`, and steps.
    Peers,
}

/// One measured stage.
#[derive(Clone, Debug, Serialize)]
pub struct Measurement {
    /// Stage name.
    pub name: String,
    /// Mesh description.
    pub mesh: String,
    /// Elements in the mesh.
    pub elements: usize,
    /// Nodes in the mesh.
    pub nodes: usize,
    /// Best wall time over the repetitions (ms).
    pub ms: f64,
    /// Elements per second at the best time.
    pub elements_per_s: f64,
    /// Stage-specific extra figure (e.g. nnz of the Cholesky factor).
    pub extra: Option<(String, f64)>,
}

/// The whole report.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// Worker threads.
    pub threads: usize,
    /// The instruction set the engine's kernels ran at (the machine's
    /// best, or the one `--max-simd` capped them at; the `simd` rows
    /// compare every level whatever the cap).
    pub simd: String,
    /// Measurements in run order.
    pub measurements: Vec<Measurement>,
}

impl Report {
    /// A plain-text table of the report.
    pub fn to_table(&self) -> String {
        let mut s = format!(
            "threads: {}, kernels at {}\n{:<24} {:<22} {:>10} {:>12} {:>16}\n",
            self.threads, self.simd, "stage", "mesh", "elements", "ms", "elements/s"
        );
        for m in &self.measurements {
            s += &format!("{:<24} {:<22} {:>10} {:>12.3} {:>16.0}", m.name, m.mesh, m.elements, m.ms, m.elements_per_s);
            if let Some((k, v)) = &m.extra {
                s += &if *v < 100.0 { format!("  {k} = {v:.2}") } else { format!("  {k} = {v:.0}") };
            }
            s.push('\n');
        }
        s
    }
}

/// Best of `reps` runs of `f`, in ms.
pub(crate) fn best_ms<T>(reps: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..reps {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
        out = Some(r);
    }
    (best, out.expect("at least one repetition"))
}

/// A basis evaluation kernel to time.
pub(crate) enum EvalKernel<'a> {
    /// Mean value coordinates, SIMD.
    MeanValue,
    /// Mean value coordinates, the scalar reference.
    MeanValueScalar,
    /// Fitted harmonic functions, SIMD.
    Harmonic(&'a cleave::store::harmonic::ElementBasis),
    /// Fitted harmonic functions, the scalar reference.
    HarmonicScalar(&'a cleave::store::harmonic::ElementBasis),
}

/// Wall time (ms) of evaluating `kernel` at the paper's points of `mesh`'s
/// single element `reps` times, and the number of points evaluated.
pub(crate) fn basis_eval_ms(mesh: &PolyMesh, reps: usize, kernel: EvalKernel) -> (f64, usize) {
    use cleave_kernels::dyn_stack::{MemBuffer, MemStack};
    use cleave_kernels::{harmonic, mean_value, quadrature};
    let nodes = &mesh.elements[0].nodes;
    let verts: Vec<[f64; 3]> = nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let tris: Vec<[u32; 3]> =
        mesh.element_triangles(0).map(|t| t.map(|g| nodes.binary_search(&g).unwrap_or(0) as u32)).collect();
    let k = verts.len();
    let nq = quadrature::paper_rule_len(k, tris.len());
    let (mut p, mut w, mut mu) = (vec![[0.0; 3]; nq], vec![0.0; nq], vec![0.0; k]);
    quadrature::paper_rule(&verts, &tris, &mut p, &mut w, &mut mu);
    let (mut phi, mut grad) = (vec![0.0; k * nq], vec![0.0; 3 * k * nq]);
    let req = mean_value::evaluate_scratch(k, tris.len()).or(harmonic::evaluate_scratch(k));
    let mut buf = MemBuffer::new(req);
    let (ms, ()) = best_ms(3, || {
        for _ in 0..reps {
            let stack = MemStack::new(&mut buf);
            match kernel {
                EvalKernel::MeanValue => mean_value::evaluate(&verts, &tris, &p, &mut phi, &mut grad, stack),
                EvalKernel::MeanValueScalar => {
                    mean_value::evaluate_scalar(&verts, &tris, &p, &mut phi, &mut grad, stack)
                }
                EvalKernel::Harmonic(b) => harmonic::evaluate(&b.functions(), &p, &mut phi, &mut grad, stack),
                EvalKernel::HarmonicScalar(b) => {
                    harmonic::evaluate_scalar(&b.functions(), &p, &mut phi, &mut grad, stack)
                }
            }
        }
    });
    (ms, reps * nq)
}

/// A measurement on `copies` disjoint `k`-vertex elements.
fn per_element(copies: usize, k: usize, name: String, ms: f64, extra: Option<(String, f64)>) -> Measurement {
    Measurement {
        name,
        mesh: format!("{copies} x {k}-vertex"),
        elements: copies,
        nodes: copies * k,
        ms,
        elements_per_s: copies as f64 / (ms * 1e-3),
        extra,
    }
}

/// Harmonic elements per vertex count: basis construction + `K_e` per
/// element on one thread and on all, each copy of the element scaled a
/// little (by `1 + 1e-6 c`) so that every one is fitted; then the same on
/// translated copies only, which share one fit (see
/// `store::harmonic::congruence`); and the evaluation kernel per point
/// against the mean value kernel at the same points.
fn harmonic_measurements(quick: bool, material: &Material) -> Result<Vec<Measurement>, Error> {
    use cleave::store::{harmonic, Family, HarmonicOptions};
    let copies = if quick { 20 } else { 200 };
    let options = BasisOptions {
        family: Family::Harmonic,
        harmonic: HarmonicOptions { trilinear_hexahedra: false, ..Default::default() },
        ..Default::default()
    };
    let single = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|e| Error::Internal(format!("a one-thread pool: {e}")))?;
    let mut out = Vec::new();
    for k in [8, 12, 24, 40] {
        let Some(one) = element_with_vertices(k) else { continue };
        let congruent = replicate(&one, copies)?;
        let mut batch = congruent.clone();
        let per = one.nodes.len();
        for (i, chunk) in batch.nodes.chunks_mut(per).enumerate() {
            let (first, s) = (chunk[0], 1.0 + 1e-6 * i as f64);
            chunk.iter_mut().for_each(|p| *p = std::array::from_fn(|d| first[d] + s * (p[d] - first[d])));
        }
        let (all_ms, store) = best_ms(3, || ElementStore::build(&batch, material, &options));
        store?;
        let (one_ms, store) = best_ms(3, || single.install(|| ElementStore::build(&batch, material, &options)));
        store?;
        let (shared_ms, store) = best_ms(3, || ElementStore::build(&congruent, material, &options));
        store?;
        // evaluation at the mean value rule's points, against that kernel
        let faces = harmonic::face_bases(&one, &[0], &options.harmonic)?;
        let basis = harmonic::element_basis(&one, 0, &faces, &options.harmonic)
            .ok_or(cleave::store::BasisError::HarmonicFit { element: 0 })?;
        let reps = if quick { 100 } else { 2000 };
        let (mv_ms, points) = basis_eval_ms(&one, reps, EvalKernel::MeanValue);
        let (hm_ms, _) = basis_eval_ms(&one, reps, EvalKernel::Harmonic(&basis));
        let m = |name, ms, extra| per_element(copies, k, name, ms, extra);
        let kernels = ("kernels".to_string(), basis.centres.len() as f64);
        out.push(m(format!("harmonic basis+K_e k={k} (1 thread)"), one_ms, Some(kernels.clone())));
        out.push(m(format!("harmonic basis+K_e k={k}"), all_ms, Some(kernels.clone())));
        out.push(m(format!("harmonic basis+K_e k={k} (congruent copies)"), shared_ms, Some(kernels)));
        let per_point = |ms: f64| points as f64 / (ms * 1e-3);
        out.push(m(
            format!("harmonic eval k={k} (1 thread)"),
            hm_ms,
            Some(("points/s vs mean value".into(), per_point(hm_ms) / per_point(mv_ms))),
        ));
    }
    Ok(out)
}

/// Runs the suite, or the group `only` (`quick`: small meshes, for smoke
/// tests), its kernels capped at `max_simd` (all but the `simd` group's,
/// which compares the levels).
pub(crate) fn run_suite(quick: bool, only: Option<Group>, max_simd: Option<MaxSimd>) -> Result<Report, Error> {
    let cap = max_simd.map(MaxSimd::level);
    cap_simd_level(cap);
    let simd = format!("{:?}", dispatched_level(SimdLevel::Avx512));
    let run = |group: Group| only.is_none_or(|o| o == group);
    let material = Material::new(1e5, 0.3, 1000.0)?;
    let mut out = Vec::new();
    if run(Group::Pipeline) {
        out.extend(pipeline_measurements(quick, &material)?);
    }
    if run(Group::Basis) {
        out.extend(basis_measurements(quick, &material)?);
        out.extend(harmonic_measurements(quick, &material)?);
    }
    if run(Group::Dg) {
        out.extend(table1_measurements(quick)?);
    }
    if run(Group::Steps) {
        out.extend(step_suite(quick, &material)?);
    }
    if run(Group::Meshing) {
        out.extend(meshing_measurements(quick)?);
    }
    if run(Group::Bodies) {
        out.extend(body_measurements(quick)?);
    }
    if run(Group::Simd) {
        out.extend(crate::simd::simd_measurements(quick, cap)?);
    }
    if only == Some(Group::Peers) {
        out.extend(peer_measurements(quick)?);
    }
    Ok(Report { threads: rayon::current_num_threads(), simd, measurements: out })
}

/// Tetrahedral `K_e` build, sparse pattern, assembly and the three Cholesky
/// phases on a box of tetrahedra.
fn pipeline_measurements(quick: bool, material: &Material) -> Result<Vec<Measurement>, Error> {
    let cells = if quick { [16, 4, 4] } else { [64, 16, 16] };
    let mesh = box_tet([0.0; 3], [4.0, 1.0, 1.0], cells)?;
    pipeline_on(&mesh, &format!("box_tet {}x{}x{}", cells[0], cells[1], cells[2]), material)
}

/// What the peer comparison (`benches/peers/run.sh`) measures of cleave,
/// on the same mesh and matrix as the peers: bunny_100k with E = 10⁷ Pa,
/// ν = 0.35, the pipeline of [`pipeline_on`] (Cholesky of `K + 10³ I`),
/// and corotated steps with conjugate gradients and with Cholesky.
fn peer_measurements(quick: bool) -> Result<Vec<Measurement>, Error> {
    let (name, steps) = if quick { ("bunny_5k", 2) } else { ("bunny_100k", 10) };
    let mesh = cleave::io::read_mesh(&asset(&format!("{name}.mesh")))?;
    let mut out = pipeline_on(&mesh, name, &Material::new(1e7, 0.35, 1000.0)?)?;
    out.extend(step_measurements(name, mesh.clone(), Support::Floor, SolverKind::Cg, 1e-6, steps, false)?);
    out.extend(step_measurements(name, mesh, Support::Floor, SolverKind::Cholesky, 1e-6, 2, false)?);
    Ok(out)
}

/// Tetrahedral `K_e` build, sparse pattern, assembly and the three Cholesky
/// phases (of `K + 10³ I`) on `mesh` (named `label` in the rows).
fn pipeline_on(mesh: &PolyMesh, label: &str, material: &Material) -> Result<Vec<Measurement>, Error> {
    let label = label.to_string();
    let (ne, nn) = (mesh.elements.len(), mesh.nodes.len());
    let mut out = Vec::new();
    let mut push = |name: &str, ms: f64, extra: Option<(String, f64)>| {
        out.push(Measurement {
            name: name.into(),
            mesh: label.clone(),
            elements: ne,
            nodes: nn,
            ms,
            elements_per_s: ne as f64 / (ms * 1e-3),
            extra,
        })
    };
    let (ms, store) = best_ms(5, || ElementStore::build(mesh, material, &BasisOptions::default()));
    let store = store?;
    push("tet K_e build", ms, None);
    let (ms, pattern) = best_ms(3, || SparsePattern::build(mesh.nodes.len(), &store));
    push("sparse pattern", ms, Some(("nnz".into(), pattern.nnz() as f64)));
    let mut values = vec![0.0; pattern.nnz()];
    let (ms, ()) =
        best_ms(5, || pattern.assemble(&mut values, |b, i, c, out| store.batches[b].block_column(i, c, out)));
    push("assembly", ms, None);
    let mut chol = Cholesky::default();
    let (ms, r) = best_ms(1, || chol.analyze(pattern.symbolic()));
    r?;
    // nnz(L) as CHOLMOD counts it (on and below the diagonal)
    push("cholesky symbolic", ms, Some(("nnz(L)".into(), chol.factor_nnz() as f64)));
    // a regular matrix: K plus a mass-like diagonal
    for d in 0..3 * nn {
        values[pattern.diagonal_slot(d)] += 1e3;
    }
    let (ms, r) = best_ms(2, || chol.factor(pattern.matrix(&values)));
    r?;
    // the flop rate, to compare with the machine's dense peak
    push("cholesky numeric", ms, Some(("GFLOP/s".into(), chol.factor_flops() / (ms * 1e6))));
    let mut sequential = Cholesky::new(faer::Par::Seq);
    sequential.analyze(pattern.symbolic())?;
    let (ms_sequential, r) = best_ms(2, || sequential.factor(pattern.matrix(&values)));
    r?;
    push("cholesky numeric (sequential)", ms_sequential, Some(("sequential / default".into(), ms_sequential / ms)));
    let b = vec![1.0; 3 * nn];
    let mut x = vec![0.0; 3 * nn];
    let (ms, r) = best_ms(3, || chol.solve(pattern.matrix(&values), &b, &mut x));
    r?;
    push("cholesky solve", ms, None);
    Ok(out)
}

/// Mean value elements per vertex count: basis evaluation (SIMD and
/// scalar) and `K_e` build.
fn basis_measurements(quick: bool, material: &Material) -> Result<Vec<Measurement>, Error> {
    let mut out = Vec::new();
    let copies = if quick { 1000 } else { 10_000 };
    for k in [8, 12, 16, 24] {
        let Some(one) = element_with_vertices(k) else { continue };
        let (simd_ms, points) = basis_eval_ms(&one, copies, EvalKernel::MeanValue);
        let (scalar_ms, _) = basis_eval_ms(&one, copies, EvalKernel::MeanValueScalar);
        let batch = replicate(&one, copies)?;
        let (ms, store) = best_ms(3, || ElementStore::build(&batch, material, &BasisOptions::default()));
        store?;
        let m = |name, ms, extra| per_element(copies, k, name, ms, extra);
        out.push(m(
            format!("MV basis k={k} (1 thread)"),
            simd_ms,
            Some(("points/s".into(), points as f64 / (simd_ms * 1e-3))),
        ));
        out.push(m(format!("MV basis k={k} scalar"), scalar_ms, Some(("simd speed-up".into(), scalar_ms / simd_ms))));
        out.push(m(format!("MV K_e build k={k}"), ms, None));
    }
    Ok(out)
}

/// Global assembly on a mixed mesh of about 100k elements, corotated
/// implicit steps and cuts on the bunnies (where their assets are), and
/// steps on a large box.
fn step_suite(quick: bool, material: &Material) -> Result<Vec<Measurement>, Error> {
    let mut out = Vec::new();
    let cells = if quick { [12, 6, 6] } else { [40, 20, 20] };
    let mut mixed = box_tet([0.0; 3], [2.0, 1.0, 1.0], cells)?;
    for (i, x) in [0.31, 0.77, 1.23, 1.61].iter().enumerate() {
        let normal = [1.0, 0.3 * i as f64, -0.2];
        split_by_plane(&mut mixed, &Plane { point: [*x, 0.5, 0.5], normal }, &SplitOptions::default())?;
    }
    let store = ElementStore::build(&mixed, material, &BasisOptions::default())?;
    let pattern = SparsePattern::build(mixed.nodes.len(), &store);
    let mut values = vec![0.0; pattern.nnz()];
    let (ms, ()) =
        best_ms(5, || pattern.assemble(&mut values, |b, i, c, out| store.batches[b].block_column(i, c, out)));
    let ne = mixed.elements.len();
    out.push(Measurement {
        name: "assembly (mixed)".into(),
        mesh: format!("box_tet {}x{}x{} + 4 cuts", cells[0], cells[1], cells[2]),
        elements: ne,
        nodes: mixed.nodes.len(),
        ms,
        elements_per_s: ne as f64 / (ms * 1e-3),
        extra: Some(("polyhedra".into(), (ne - store.batches[0].len()) as f64)),
    });
    // corotated implicit steps: the bunny (if its asset is here) and a box
    let bunny = if quick { None } else { present(asset("bunny_100k.mesh"), "bunny_100k step and cut") };
    if let Some(bunny) = bunny {
        // in the file's numbering, and renumbered for locality as a scene
        // loads it
        let mesh = cleave::io::read_mesh(&bunny)?;
        let mut renumbered = mesh.clone();
        renumbered.renumber_for_locality();
        for (label, mesh) in [("bunny_100k", mesh), ("bunny_100k renumbered", renumbered)] {
            for support in [Support::Floor, Support::ClampedBase, Support::Landing] {
                for tolerance in [1e-6, 1e-8] {
                    out.extend(step_measurements(label, mesh.clone(), support, SolverKind::Cg, tolerance, 20, false)?);
                }
            }
            out.extend(step_measurements(label, mesh.clone(), Support::Floor, SolverKind::Cholesky, 1e-6, 3, false)?);
            // the lagged factor as the clamped step's preconditioner: the
            // first step's factor kept while a solve needs at most 8
            // iterations (its factorisations averaged over the 20 steps)
            let lagged = SolverKind::LaggedCholesky;
            out.extend(step_measurements(label, mesh.clone(), Support::ClampedBase, lagged, 1e-6, 20, false)?);
            out.extend(large_cut_measurements(label, mesh)?);
        }
    }
    if let Some(bunny) = present(asset("bunny_5k.mesh"), "bunny_5k cut") {
        out.extend(cut_measurements(cleave::io::read_mesh(&bunny)?)?);
    }
    let cells = if quick { [16, 4, 4] } else { [100, 50, 34] };
    let mesh = box_tet([0.0; 3], [2.0, 1.0, 0.68], cells)?;
    let label = format!("box_tet {}x{}x{}", cells[0], cells[1], cells[2]);
    // (the first step of a million elements apart: its analysis and first
    // touch of the arrays would otherwise be most of the per-step rows)
    out.extend(step_measurements(&label, mesh, Support::Floor, SolverKind::Cg, 1e-6, 3, true)?);
    Ok(out)
}

/// kaufmann2008 Table 1 (ms on a Core 2 Duo 2.4 GHz): integration,
/// assembly and solve of BZ and IP with degrees 1 and 2 on 10x10x10
/// hexahedra, and trilinear CG on 15x15x15.
const TABLE1: [(&str, [f64; 3]); 5] = [
    ("DG BZ p1", [532.0, 22.0, 656.0]),
    ("DG IP p1", [1437.0, 87.0, 734.0]),
    ("DG BZ p2", [3062.0, 152.0, 7797.0]),
    ("DG IP p2", [8344.0, 621.0, 8484.0]),
    ("CG trilinear", [3750.0, 41.0, 641.0]),
];

/// The rows of kaufmann2008 Table 1, measured: a 1 m cube of 10x10x10
/// hexahedra (E = 1e5 Pa, ν = 0.3) held weakly at x = 0, per flux and
/// degree the integration (element and face terms: [`ElementStore::build`]
/// and [`DgElements::new`]), the assembly of `K` and the direct solve of
/// `K u = f_gravity` (factorisation and substitution, the ordering and
/// symbolic analysis done once before), each row with the paper's time
/// over ours; the trilinear CG row on 15x15x15 hexahedra (the same number
/// of unknowns); and a plane cut of the IP degree 1 body, whose
/// re-integration (only the faces it changed) is set against the full one.
fn table1_measurements(quick: bool) -> Result<Vec<Measurement>, Error> {
    let (n_dg, n_cg) = if quick { (4, 6) } else { (10, 15) };
    let material = Material::new(1e5, 0.3, 1000.0)?;
    let mut rows = Vec::new();
    for (index, (name, paper)) in TABLE1.iter().enumerate() {
        let dg = (index < 4).then_some(DgOptions {
            degree: if index < 2 { 1 } else { 2 },
            flux: if index % 2 == 0 { Flux::Bz } else { Flux::Ip },
            penalty: 1.0,
        });
        let n = if dg.is_some() { n_dg } else { n_cg };
        let mesh = box_hex([0.0; 3], [1.0; 3], [n; 3])?;
        let basis = match dg {
            Some(dg) => BasisOptions { family: Family::Dg, dg, ..Default::default() },
            None => BasisOptions { family: Family::Harmonic, ..Default::default() },
        };
        let fixed = FixedRegion::clamp([-1.0; 3], [1e-6, 2.0, 2.0]);
        let (integration, ()) = best_ms(3, || {
            let store = ElementStore::build(&mesh, &material, &basis);
            if let (Ok(store), Some(dg)) = (store, dg) {
                std::hint::black_box(DgElements::new(&mesh, store, dg, std::slice::from_ref(&fixed)));
            }
        });
        let params = SimulationParams {
            material,
            basis,
            gravity: [0.0, -9.81, 0.0],
            solver: SolverKind::Cholesky,
            ..Default::default()
        };
        let mut sim = Simulation::new(mesh, params)?;
        sim.fix(fixed)?;
        sim.solve_static()?;
        let (mut assembly, mut solve) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..3 {
            let before = *sim.timings();
            sim.solve_static()?;
            let t = *sim.timings();
            assembly = assembly.min(1e3 * (t.assembly - before.assembly));
            solve = solve.min(1e3 * (t.solve - before.solve));
        }
        let unknowns = 3 * sim.masses().len();
        let fill = 100.0 * sim.pattern().nnz() as f64 / (unknowns as f64).powi(2);
        let penalty = sim.dg().map_or(String::new(), |d| format!(", eta {}", d.penalty));
        let label = format!("hex {n}^3, {unknowns} DOFs{penalty}");
        let (ne, nn) = (sim.mesh().elements.len(), sim.mesh().nodes.len());
        let m = |stage: &str, ms: f64, extra: (String, f64)| Measurement {
            name: format!("{name} {stage}"),
            mesh: label.clone(),
            elements: ne,
            nodes: nn,
            ms,
            elements_per_s: ne as f64 / (ms * 1e-3),
            extra: Some(extra),
        };
        let vs = |i: usize, ms: f64| ("paper / ours".to_string(), paper[i] / ms);
        rows.push(m("integration", integration, vs(0, integration)));
        rows.push(m("assembly", assembly, vs(1, assembly)));
        rows.push(m("solve", solve, vs(2, solve)));
        rows.push(m("fill", 0.0, ("nonzeros %".into(), fill)));
        if index == 1 {
            let (before, faces_before) = (*sim.timings(), sim.faces_integrated());
            let total: usize = sim.mesh().elements.iter().map(|e| e.faces.len()).sum();
            let t = Instant::now();
            sim.cut_plane(&Plane { point: [0.53, 0.5, 0.5], normal: [1.0, 0.3, 0.2] })?;
            let cut = t.elapsed().as_secs_f64() * 1e3;
            let reintegration = 1e3 * (sim.timings().basis - before.basis);
            let share = 100.0 * (sim.faces_integrated() - faces_before) as f64 / total as f64;
            rows.push(m("cut re-integration", reintegration, ("full / cut".into(), integration / reintegration)));
            rows.push(m("cut faces integrated", 0.0, ("% of faces".into(), share)));
            rows.push(m("cut (to ready)", cut, ("full integration ms".into(), integration)));
        }
    }
    Ok(rows)
}

/// Wall time per step of the bunny before and after two plane cuts (the
/// cuts of `scenes/bunny_cut.toml`), and per cut from cut to ready system.
fn cut_measurements(mesh: PolyMesh) -> Result<Vec<Measurement>, Error> {
    let label = "bunny_5k";
    let mut sim = cut_simulation(mesh, SolverKind::default())?;
    let per_step = |sim: &mut Simulation| -> Result<f64, Error> {
        let t = Instant::now();
        for _ in 0..10 {
            sim.step()?;
        }
        Ok(t.elapsed().as_secs_f64() * 1e3 / 10.0)
    };
    let before = per_step(&mut sim)?;
    let (ne0, nn0) = (sim.mesh().elements.len(), sim.mesh().nodes.len());
    let t = Instant::now();
    sim.cut_plane(&Plane { point: [0.0, 6.5, 0.0], normal: [0.2, 1.0, 0.3] })?;
    sim.cut_plane(&Plane { point: [2.0, 0.0, 0.0], normal: [1.0, 0.1, 0.0] })?;
    let cut = t.elapsed().as_secs_f64() * 1e3 / 2.0;
    let after = per_step(&mut sim)?;
    let (ne1, nn1) = (sim.mesh().elements.len(), sim.mesh().nodes.len());
    let m = |name: &str, ms: f64, elements: usize, nodes: usize| Measurement {
        name: name.into(),
        mesh: label.into(),
        elements,
        nodes,
        ms,
        elements_per_s: elements as f64 / (ms * 1e-3),
        extra: Some(("steps/s".into(), 1e3 / ms)),
    };
    Ok(vec![
        m("step before cuts", before, ne0, nn0),
        Measurement { extra: None, ..m("plane cut (to ready)", cut, ne1, nn1) },
        m("step after cuts", after, ne1, nn1),
    ])
}

/// The bunny falling onto the ground (E = 5e6 Pa, ν = 0.35, ρ = 1000
/// kg/m³, h = 0.01 s), as in `scenes/bunny_cut.toml`, solved by `solver`.
fn cut_simulation(mesh: PolyMesh, solver: SolverKind) -> Result<Simulation, Error> {
    let params = SimulationParams {
        material: Material::new(5e6, 0.35, 1000.0)?,
        gravity: [0.0, -9.81, 0.0],
        dt: 0.01,
        mass_damping: 0.3,
        solver,
        ..Default::default()
    };
    let mut sim = Simulation::new(mesh, params)?;
    sim.add_collider(Collider::new([0.0, -0.05, 0.0], [0.0, 1.0, 0.0], 1e9)?);
    Ok(sim)
}

/// Time from a cut to a ready system (the conjugate gradients' analysis of
/// the new pattern done) on the large bunny `mesh`, named `label` in the
/// rows, after one step: six 3 m square blade cuts across its body (about
/// a thousand elements split each) and three plane cuts through its head,
/// each row the mean per cut with the mean number of elements the cut
/// crossed.
fn large_cut_measurements(label: &str, mesh: PolyMesh) -> Result<Vec<Measurement>, Error> {
    let mut sim = cut_simulation(mesh, SolverKind::Cg)?;
    sim.step()?;
    let mut rows = Vec::new();
    let mut measure = |sim: &mut Simulation,
                       name: &str,
                       cuts: usize,
                       cut: &mut dyn FnMut(&mut Simulation, usize) -> Result<usize, Error>|
     -> Result<(), Error> {
        let (mut ms, mut crossed, retries_before) = (0.0, 0, sim.cut_retries());
        let phases_before = *sim.timings();
        for i in 0..cuts {
            let t = Instant::now();
            crossed += cut(sim, i)?;
            ms += t.elapsed().as_secs_f64() * 1e3;
        }
        // (a retried cut, redone with its unhealthy elements kept whole,
        // costs about twice a first try: the mean includes it)
        let retried = sim.cut_retries() - retries_before;
        let (ne, nn) = (sim.mesh().elements.len(), sim.mesh().nodes.len());
        let row = |name: String, ms: f64, extra| Measurement {
            name,
            mesh: label.into(),
            elements: ne,
            nodes: nn,
            ms: ms / cuts as f64,
            elements_per_s: crossed as f64 / (ms * 1e-3),
            extra,
        };
        let per_cut = ("crossed per cut".to_string(), crossed as f64 / cuts as f64);
        let retries = format!("{retried} {} in {cuts} cuts", if retried == 1 { "retry" } else { "retries" });
        rows.push(row(format!("{name}, {retries}"), ms, Some(per_cut)));
        // where a cut's time goes, as the simulation books it: the split
        // and its bookkeeping (rollback, checks, node states, masses and
        // rotations), the touched elements' data, the pattern's update,
        // and the solver's analysis of the new pattern (the last two run
        // beside the elements' rebuild, and book the time they take past it)
        let (after, before) = (sim.timings(), phases_before);
        for (phase, seconds) in [
            ("split and bookkeeping", after.topology - before.topology),
            ("element data", after.basis - before.basis),
            ("pattern update", after.assembly - before.assembly),
            ("solver analysis", after.solve - before.solve),
        ] {
            rows.push(row(format!("{name}: {phase}"), seconds * 1e3, None));
        }
        Ok(())
    };
    measure(&mut sim, "blade cut (to ready)", 6, &mut |sim, i| {
        let (x, y, z, half) = (-2.0 + 0.7 * i as f64, 3.0, 0.0, 1.5);
        let square =
            [[x, y - half, z - half], [x, y + half, z - half], [x, y + half, z + half], [x, y - half, z + half]];
        let report = sim.cut_polygon(&square)?;
        Ok(report.cut.split.split_elements.len() + report.cut.split.kept_whole.len())
    })?;
    measure(&mut sim, "plane cut (to ready)", 3, &mut |sim, i| {
        let report = sim.cut_plane(&Plane { point: [0.0, 7.0 + 0.5 * i as f64, 0.0], normal: [0.1, 1.0, 0.0] })?;
        Ok(report.split.split_elements.len() + report.split.kept_whole.len())
    })?;
    Ok(rows)
}

/// How the stepped body is held.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Support {
    /// Free, above a floor 0.5 m below it (the bunny reaches it after about
    /// 32 steps of 0.01 s): until then every step is a rigid fall, whose
    /// velocities the warm start almost has (the peers' step).
    Floor,
    /// Its lowest 15 % (of its height) clamped: it sags and sways under
    /// gravity, so every step deforms it.
    ClampedBase,
    /// Free, 2 cm above a floor: it lands within 7 steps and bounces on
    /// it, its penalty contacts changing from step to step.
    Landing,
}

/// Per-phase wall time per step of `steps` corotated implicit Euler steps
/// of a body under gravity, held as `support` says (E = 1e7 Pa, ν = 0.35,
/// ρ = 1000 kg/m³, h = 0.01 s, CG to the relative residual `tolerance`),
/// and the step in passes over `K`: its time over that of one read of as
/// many `f64` values as `K` stores from memory, at the read bandwidth of
/// [`read_bandwidth`] (the same threads), the memory-bound unit the step's
/// kernels are measured in. With `first_apart`, the first step (which
/// analyses the pattern and touches every array for the first time: on a
/// million elements, seconds of page faults on a virtual machine whose
/// memory the host backs lazily) is a row of its own and the `steps`
/// after it are the per-step rows; without, the `steps` include it.
fn step_measurements(
    label: &str,
    mesh: PolyMesh,
    support: Support,
    solver: SolverKind,
    tolerance: f64,
    steps: usize,
    first_apart: bool,
) -> Result<Vec<Measurement>, Error> {
    let (ne, nn) = (mesh.elements.len(), mesh.nodes.len());
    let lowest = mesh.bounding_box().0;
    let params = SimulationParams {
        material: Material::new(1e7, 0.35, 1000.0)?,
        gravity: [0.0, -9.81, 0.0],
        dt: 0.01,
        mass_damping: 0.5,
        stiffness_damping: 0.001,
        solver,
        tolerance,
        ..Default::default()
    };
    let highest = mesh.bounding_box().1;
    let mut sim = Simulation::new(mesh, params)?;
    match support {
        Support::Floor => sim.add_collider(Collider::new([0.0, lowest[1] - 0.5, 0.0], [0.0, 1.0, 0.0], 1e9)?),
        Support::Landing => sim.add_collider(Collider::new([0.0, lowest[1] - 0.02, 0.0], [0.0, 1.0, 0.0], 1e9)?),
        Support::ClampedBase => {
            let top = lowest[1] + 0.15 * (highest[1] - lowest[1]);
            sim.fix(FixedRegion::clamp([-f64::MAX, -f64::MAX, -f64::MAX], [f64::MAX, top, f64::MAX]))?;
        }
    }
    let first = first_apart
        .then(|| {
            let before = sim.timings().steps();
            sim.step().map(|_| 1e3 * (sim.timings().steps() - before))
        })
        .transpose()?;
    let before = *sim.timings();
    let mut iterations = 0;
    for _ in 0..steps {
        iterations += sim.step()?.solve.iterations;
    }
    let t = *sim.timings();
    let per = |x: f64, y: f64| 1e3 * (x - y) / steps as f64;
    let mut kind = match solver {
        SolverKind::Cg => format!("cg {tolerance:.0e}"),
        _ => format!("{solver:?}").to_lowercase(),
    };
    match support {
        Support::Floor => {}
        Support::ClampedBase => kind.push_str(", clamped base"),
        Support::Landing => kind.push_str(", landing"),
    }
    let bytes_per_ms = read_bandwidth();
    let pass_ms = (8 * sim.pattern().nnz()) as f64 / bytes_per_ms;
    let m = |name: String, ms: f64, extra: Option<(String, f64)>| Measurement {
        name,
        mesh: label.to_string(),
        elements: ne,
        nodes: nn,
        ms,
        elements_per_s: ne as f64 / (ms * 1e-3),
        extra,
    };
    let (forces, asm, sol) =
        (per(t.forces, before.forces), per(t.assembly, before.assembly), per(t.solve, before.solve));
    let total = per(t.steps(), before.steps());
    let rest = total - forces - asm - sol;
    let first = first.map(|ms| m(format!("first step ({kind})"), ms, Some(("passes over K".into(), ms / pass_ms))));
    Ok(first
        .into_iter()
        .chain([
            m(format!("step forces ({kind})"), forces, None),
            m(format!("step assembly ({kind})"), asm, None),
            m(format!("step contacts+constraints+integrate ({kind})"), rest, None),
            m(format!("step solve ({kind})"), sol, Some(("iterations/step".into(), iterations as f64 / steps as f64))),
            m(format!("step total ({kind})"), total, Some(("passes over K".into(), total / pass_ms))),
            m("one pass over K (f64 read)".into(), pass_ms, Some(("read GB/s".into(), bytes_per_ms * 1e-6))),
        ])
        .collect())
}

/// Bytes per millisecond the threads read from memory: the best of five
/// parallel dot products of a 256 MB vector with itself (eight times the
/// last-level cache of the machines we measure on, so that the read
/// streams from memory; the lanes of [`cleave::solve::dot`] keep up with
/// it).
fn read_bandwidth() -> f64 {
    let values = vec![1.0f64; 32 << 20];
    let (ms, _) = best_ms(5, || cleave::solve::dot(&values, &values));
    (8 * values.len()) as f64 / ms
}

/// A row of a whole-mesh stage.
fn mesh_row(name: &str, label: String, mesh: &PolyMesh, ms: f64, extra: Option<(String, f64)>) -> Measurement {
    let n = mesh.elements.len();
    Measurement {
        name: name.into(),
        mesh: label,
        elements: n,
        nodes: mesh.nodes.len(),
        ms,
        elements_per_s: n as f64 / (ms * 1e-3),
        extra,
    }
}

/// Meshing bunny.obj by grid slicing (about 10^3, 10^4 and 10^5 elements)
/// and by octrees; the per-frame update of the full-resolution bunny
/// (`bunny_closed.obj`, 70k triangles, research use only: read from
/// `../shared/data` when it is there) embedded in a sliced mesh of about
/// 10^4 elements; one stress refinement step of the bent bar.
fn meshing_measurements(quick: bool) -> Result<Vec<Measurement>, Error> {
    use cleave::meshing::{grid_slice, octree};
    use cleave::sim::{EmbeddedSurface, RefineRule, RefineSplit, SimulationParams};
    let reps = if quick { 1 } else { 3 };
    let (surface, _) = cleave::surface::prepare(&cleave::io::read_surface(&asset("bunny.obj"))?)?;
    let mut out = Vec::new();
    let cells: &[f64] = if quick { &[1.0] } else { &[0.55, 0.26, 0.125] };
    for &cell in cells {
        let (ms, result) = best_ms(reps, || grid_slice(&surface, cell, &Default::default()));
        let (mesh, _) = result?;
        out.push(mesh_row("grid slice", format!("bunny.obj, cell {cell}"), &mesh, ms, None));
    }
    let depths: &[usize] = if quick { &[3] } else { &[4, 5, 6] };
    for &depth in depths {
        let (ms, result) = best_ms(reps, || octree(&surface, depth));
        let (mesh, _) = result?;
        out.push(mesh_row("octree", format!("bunny.obj, depth {depth}"), &mesh, ms, None));
    }
    let closed = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/bunny_closed.obj");
    let closed = if quick { None } else { present(closed, "embedded bunny_closed") };
    if let Some(closed) = closed {
        let (fine, _) = cleave::surface::prepare(&cleave::io::read_surface(&closed)?)?;
        // an octree mesh of about 10^4 mean value cells of the same bunny,
        // and its surface in it
        let mut sim = Simulation::new(octree(&fine, 6)?.0, SimulationParams::default())?;
        let label = format!("bunny_closed in {} octree cells", sim.mesh().elements.len());
        let embedded = EmbeddedSurface { vertices: fine.vertices.clone(), triangles: fine.triangles.clone() };
        let (ms, r) = best_ms(1, || sim.embed(embedded.clone()));
        r?;
        out.push(mesh_row(
            "embed (build)",
            label.clone(),
            sim.mesh(),
            ms,
            Some(("vertices".into(), fine.vertices.len() as f64)),
        ));
        let (ms, _) = best_ms(20, || sim.embedded_surface());
        out.push(mesh_row(
            "embedded update",
            label,
            sim.mesh(),
            ms,
            Some(("vertices".into(), fine.vertices.len() as f64)),
        ));
    }
    // one refinement step of the bent bar: stresses, splits, rebuild
    let bar = || -> Result<Simulation, Error> {
        let mut p = SimulationParams { gravity: [0.0, 0.0, -9.81], ..Default::default() };
        p.material = Material::new(1e6, 0.3, 1000.0)?;
        let mut sim = Simulation::new(box_hex([0.0; 3], [4.5, 1.0, 1.0], [18, 4, 4])?, p)?;
        sim.fix(cleave::sim::FixedRegion::clamp([-1.0; 3], [0.001, 2.0, 2.0]))?;
        sim.fix(cleave::sim::FixedRegion::clamp([4.499, -1.0, -1.0], [6.0, 2.0, 2.0]))?;
        sim.solve_static()?;
        Ok(sim)
    };
    let rule = RefineRule { threshold: 2e4, split: RefineSplit::Halves, max_level: 1 };
    let (mut best, mut split) = (f64::INFINITY, 0);
    for _ in 0..reps {
        let mut sim = bar()?;
        let t = Instant::now();
        split = sim.refine_by_stress(&rule)?.refined;
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
    }
    let sim = bar()?;
    out.push(mesh_row(
        "refine step (1-to-2)",
        "bar 18x4x4 hex".into(),
        sim.mesh(),
        best,
        Some(("split".into(), split as f64)),
    ));
    Ok(out)
}

/// A small body dropping on a plane (mean value elements, Cholesky).
fn small_body(mesh: PolyMesh) -> Result<Simulation, Error> {
    let lowest = mesh.bounding_box().0;
    let params = SimulationParams { gravity: [0.0, 0.0, -9.81], solver: SolverKind::Cholesky, ..Default::default() };
    let mut sim = Simulation::new(mesh, params)?;
    sim.add_collider(Collider::new([0.0, 0.0, lowest[2] - 0.05], [0.0, 0.1, 1.0], 1e6)?);
    Ok(sim)
}

/// Microseconds per step of bodies of 1 (24 nodes), 8, 40 and 300
/// elements and of random_cube_drop's body (30 convex cells), each alone
/// (best of 5 runs of `steps` steps after a first one), and 256 bodies of
/// 40 hexahedra, and of random_cube_drop's body, stepped together
/// (body-steps per second in `extra`).
fn body_measurements(quick: bool) -> Result<Vec<Measurement>, Error> {
    let steps = if quick { 20 } else { 200 };
    let single = element_with_vertices(24).ok_or_else(|| Error::Internal("no 24-vertex element".into()))?;
    let bodies: Vec<(String, PolyMesh)> = vec![
        ("1 element, 24 nodes".into(), single),
        ("8 hexahedra".into(), box_hex([0.0; 3], [1.0; 3], [2, 2, 2])?),
        ("40 hexahedra".into(), box_hex([0.0; 3], [1.0, 0.8, 0.4], [5, 4, 2])?),
        ("random_cube_drop".into(), random_convex([0.0, 0.0, 0.3], [1.0, 1.0, 1.3], 7, 1)?),
        ("300 hexahedra".into(), box_hex([0.0; 3], [2.0, 1.2, 1.0], [10, 6, 5])?),
    ];
    let mut out = Vec::new();
    for (label, mesh) in bodies {
        let mut sim = small_body(mesh)?;
        sim.step()?;
        let (ms, r) = best_ms(5, || (0..steps).try_for_each(|_| sim.step().map(|_| ())));
        r?;
        let ms = ms / steps as f64;
        let mut m = mesh_row("step (small body)", label, sim.mesh(), ms, Some(("us/step".into(), 1e3 * ms)));
        m.elements_per_s = sim.mesh().elements.len() as f64 / (ms * 1e-3);
        out.push(m);
    }
    let count = if quick { 16 } else { 256 };
    let rounds = if quick { 2 } else { 10 };
    // random_cube_drop's body: the unit box cut by 7 random planes (seed 1)
    let kinds = [
        ("40 hexahedra", box_hex([0.0; 3], [1.0, 0.8, 0.4], [5, 4, 2])?),
        ("random_cube_drop", random_convex([0.0, 0.0, 0.3], [1.0, 1.0, 1.3], 7, 1)?),
    ];
    for (label, mesh) in kinds {
        let mut set: Vec<Simulation> = (0..count).map(|_| small_body(mesh.clone())).collect::<Result<_, _>>()?;
        let mut stats = vec![cleave::sim::StepStats::default(); count];
        cleave::sim::step_bodies(&mut set, &mut stats).map_err(|e| e.error)?;
        let (ms, r) = best_ms(3, || (0..rounds).try_for_each(|_| cleave::sim::step_bodies(&mut set, &mut stats)));
        r.map_err(|e| e.error)?;
        let body_steps = (count * rounds) as f64 / (ms * 1e-3);
        let elements = set.iter().map(|s| s.mesh().elements.len()).sum::<usize>();
        out.push(Measurement {
            name: "bodies together".into(),
            mesh: format!("{count} x {label}"),
            elements,
            nodes: set.iter().map(|s| s.mesh().nodes.len()).sum(),
            ms: ms / rounds as f64,
            elements_per_s: elements as f64 * rounds as f64 / (ms * 1e-3),
            extra: Some(("body-steps/s".into(), body_steps)),
        });
    }
    Ok(out)
}
