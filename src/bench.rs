//! The throughput suite behind `cleave bench`: wall time of each pipeline
//! stage on generated meshes, reported with mesh sizes and rates.

use std::time::Instant;

use serde::Serialize;

use crate::assembly::SparsePattern;
use crate::material::Material;
use crate::meshing::box_tet;
use crate::solve::{Cholesky, LinearSolver};
use crate::store::{BasisOptions, ElementStore};
use crate::Error;

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
    /// Measurements in run order.
    pub measurements: Vec<Measurement>,
}

impl Report {
    /// A plain-text table of the report.
    pub fn to_table(&self) -> String {
        let mut s = format!(
            "threads: {}\n{:<24} {:<22} {:>10} {:>12} {:>16}\n",
            self.threads, "stage", "mesh", "elements", "ms", "elements/s"
        );
        for m in &self.measurements {
            s += &format!("{:<24} {:<22} {:>10} {:>12.3} {:>16.0}", m.name, m.mesh, m.elements, m.ms, m.elements_per_s);
            if let Some((k, v)) = &m.extra {
                s += &format!("  {k} = {v:.0}");
            }
            s.push('\n');
        }
        s
    }
}

/// Best of `reps` runs of `f`, in ms.
fn best_ms<T>(reps: usize, mut f: impl FnMut() -> T) -> (f64, T) {
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

/// Runs the suite (`quick`: small meshes, for smoke tests).
pub fn run_suite(quick: bool) -> Result<Report, Error> {
    let cells = if quick { [16, 4, 4] } else { [64, 16, 16] };
    let mesh = box_tet([0.0; 3], [4.0, 1.0, 1.0], cells)?;
    let material = Material::new(1e5, 0.3, 1000.0)?;
    let label = format!("box_tet {}x{}x{}", cells[0], cells[1], cells[2]);
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
    let (ms, store) = best_ms(5, || ElementStore::build(&mesh, &material, &BasisOptions::default()));
    let store = store?;
    push("tet K_e build", ms, None);
    let (ms, pattern) = best_ms(3, || SparsePattern::build(mesh.nodes.len(), &store));
    push("sparse pattern", ms, Some(("nnz".into(), pattern.nnz() as f64)));
    let mut values = vec![0.0; pattern.nnz()];
    let (ms, ()) = best_ms(5, || {
        values.fill(0.0);
        pattern.assemble(&store, &mut values, |b, i, o| o.copy_from_slice(store.batches[b].element_stiffness(i)))
    });
    push("assembly", ms, None);
    let mut chol = Cholesky::default();
    let (ms, r) = best_ms(1, || chol.analyze(pattern.symbolic.as_ref()));
    r?;
    push("cholesky symbolic", ms, Some(("nnz(L)".into(), chol.factor_nnz() as f64)));
    // a regular matrix: K plus a mass-like diagonal
    for d in 0..3 * nn {
        values[pattern.diagonal_slot(d)] += 1e3;
    }
    let (ms, r) = best_ms(2, || chol.factor(pattern.matrix(&values)));
    r?;
    push("cholesky numeric", ms, None);
    let b = vec![1.0; 3 * nn];
    let mut x = vec![0.0; 3 * nn];
    let (ms, r) = best_ms(3, || chol.solve(&b, &mut x));
    r?;
    push("cholesky solve", ms, None);
    Ok(Report { threads: rayon::current_num_threads(), measurements: out })
}
