//! Frames (VTU, OBJ, PNG) and the run summary (`summary.json`).

use std::collections::BTreeMap;
use std::path::Path;

use serde::Serialize;

use crate::dg::DgElements;
use crate::io::{write_boundary_obj, write_surface_obj, write_surface_vtu, write_vtu, IoError, VtuFields};
use crate::mesh::{Plane, PolyMesh};
use crate::render::{write_png, Renderer, Surface};
use crate::sim::{Located, PhaseTimings, Simulation};

/// Frame formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// VTK unstructured grid with polyhedron cells, the deformed positions
    /// and per-node and per-cell fields.
    Vtu,
    /// The boundary surface as OBJ.
    Obj,
    /// A rendered picture of the boundary surface ([`Pictures`]).
    Png,
}

/// The pictures of a run (`frame_NNNN.png`): the camera and the original
/// boundary are taken from the first frame written.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Pictures {
    renderer: Option<Renderer>,
    stress: bool,
}

/// Size of a picture (pixels).
pub const PICTURE_SIZE: (u32, u32) = (960, 720);

impl Pictures {
    /// Pictures coloured by von Mises stress if `stress`, else plain with
    /// cut faces in a second colour.
    pub fn new(stress: bool) -> Self {
        Pictures { renderer: None, stress }
    }

    /// Renders frame `index` of `sim` into `dir`.
    pub fn write(&mut self, dir: &Path, index: usize, sim: &Simulation) -> Result<(), IoError> {
        let stress = self.stress.then(|| nodal_average(sim.mesh(), &sim.von_mises()));
        let surface = Surface {
            rest: &sim.mesh().nodes,
            positions: sim.positions(),
            triangles: sim.boundary_triangles(),
            stress: stress.as_deref(),
        };
        let g = sim.params().gravity;
        let ground = sim.colliders().first().map(|c| Plane { point: c.point, normal: c.normal });
        self.draw(&dir.join(format!("frame_{index:04}.png")), &surface, [-g[0], -g[1], -g[2]], ground)
    }

    /// Renders `surface` to the PNG `path`; the first surface drawn fits
    /// the camera (with `up` up on screen, over `ground`), which later
    /// ones keep.
    pub fn draw(
        &mut self,
        path: &Path,
        surface: &Surface<'_>,
        up: [f64; 3],
        ground: Option<Plane>,
    ) -> Result<(), IoError> {
        let renderer =
            self.renderer.get_or_insert_with(|| Renderer::new(surface, up, ground, PICTURE_SIZE.0, PICTURE_SIZE.1));
        write_png(path, &renderer.render(surface))
    }
}

/// The mean of `values` (one per element) over the elements around each
/// node.
pub fn nodal_average(mesh: &PolyMesh, values: &[f64]) -> Vec<f64> {
    let (mut sum, mut count) = (vec![0.0; mesh.nodes.len()], vec![0u32; mesh.nodes.len()]);
    for (el, &v) in mesh.elements.iter().zip(values) {
        for &n in &el.nodes {
            sum[n as usize] += v;
            count[n as usize] += 1;
        }
    }
    sum.iter().zip(&count).map(|(s, &c)| if c > 0 { s / f64::from(c) } else { 0.0 }).collect()
}

/// Writes frame `index` of `sim` in `formats` into `dir`
/// (`frame_NNNN.vtu`, `frame_NNNN.obj`; PNG is [`Pictures`]'s). Points are the deformed positions;
/// `displacement` lets a reader recover the rest ones.
pub fn write_frame(dir: &Path, index: usize, sim: &Simulation, formats: &[Format]) -> Result<(), IoError> {
    let positions = sim.positions();
    for f in formats {
        match f {
            Format::Vtu => {
                let mesh = sim.mesh();
                let counts: Vec<i64> = mesh.elements.iter().map(|e| e.nodes.len() as i64).collect();
                let vm = sim.von_mises();
                let mut point_vectors = vec![("displacement", sim.displacements()), ("velocity", sim.velocities())];
                if sim.dg().is_some() {
                    // the nodal field of DG is the stitched one (kaufmann2008 eq. 17)
                    point_vectors.push(("displacement_stitched", sim.displacements()));
                }
                let fields = VtuFields {
                    point_vectors,
                    cell_scalars: vec![("von_mises", &vm)],
                    cell_ints: vec![("vertex_count", &counts)],
                };
                write_vtu(&dir.join(format!("frame_{index:04}.vtu")), mesh, positions, &fields)?;
                if let Some(dg) = sim.dg() {
                    write_dg_elements(&dir.join(format!("frame_{index:04}_dg.vtu")), sim, dg, &vm)?;
                }
                if let (Some(surface), Some(rest), Some(v)) =
                    (sim.embedded_surface(), sim.embedded_rest(), sim.embedded_velocities())
                {
                    let u: Vec<[f64; 3]> = surface
                        .vertices
                        .iter()
                        .zip(&rest.vertices)
                        .map(|(x, x0)| [x[0] - x0[0], x[1] - x0[1], x[2] - x0[2]])
                        .collect();
                    let path = dir.join(format!("frame_{index:04}_embedded.vtu"));
                    write_surface_vtu(
                        &path,
                        &surface.vertices,
                        &surface.triangles,
                        &[("displacement", &u), ("velocity", &v)],
                    )?;
                }
            }
            Format::Obj => {
                write_boundary_obj(&dir.join(format!("frame_{index:04}.obj")), sim.mesh(), positions)?;
                if let Some(surface) = sim.embedded_surface() {
                    let path = dir.join(format!("frame_{index:04}_embedded.obj"));
                    write_surface_obj(&path, &surface.vertices, &surface.triangles)?;
                }
            }
            // pictures keep a camera across frames: written by [`Pictures`]
            Format::Png => {}
        }
    }
    Ok(())
}

/// The discontinuous field itself: every element with its own copy of its
/// vertices, placed and moved by its own polynomial (the jumps between
/// elements show), with `displacement` and `velocity` per copy.
fn write_dg_elements(path: &Path, sim: &Simulation, dg: &DgElements, von_mises: &[f64]) -> Result<(), IoError> {
    let mesh = sim.mesh();
    let m = dg.size();
    let (exploded, copies) = dg.exploded(mesh).map_err(|e| IoError::mesh(path, e))?;
    let (x, v) = (sim.block_positions(), sim.block_velocities());
    let mut n = vec![0.0; m];
    let mut position = Vec::with_capacity(copies.len());
    let (mut displacement, mut velocity) = (Vec::with_capacity(copies.len()), Vec::with_capacity(copies.len()));
    for &(e, node) in &copies {
        let rest = mesh.nodes[node as usize];
        dg.basis(e).values(rest, &mut n);
        let field = |f: &[[f64; 3]]| -> [f64; 3] {
            std::array::from_fn(|k| (0..m).map(|a| f[e as usize * m + a][k] * n[a]).sum())
        };
        let p = field(x);
        position.push(p);
        displacement.push([p[0] - rest[0], p[1] - rest[1], p[2] - rest[2]]);
        velocity.push(field(v));
    }
    let fields = VtuFields {
        point_vectors: vec![("displacement", &displacement), ("velocity", &velocity)],
        cell_scalars: vec![("von_mises", von_mises)],
        cell_ints: vec![],
    };
    write_vtu(path, &exploded, &position, &fields)
}

/// Mean and maximum of a per-step quantity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct MeanMax {
    /// Mean over steps.
    pub mean: f64,
    /// Maximum over steps.
    pub max: f64,
}

impl MeanMax {
    /// Statistics of `values` (zeros when empty).
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let (mut n, mut sum, mut max) = (0usize, 0.0, f64::NEG_INFINITY);
        for v in values {
            n += 1;
            sum += v;
            max = max.max(v);
        }
        if n == 0 {
            return MeanMax::default();
        }
        MeanMax { mean: sum / n as f64, max }
    }
}

/// Solver statistics of a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SolverSummary {
    /// The scene's solver: `"auto"`, `"cholesky"`, `"cg"`, ...
    pub kind: String,
    /// The solver of the last step: `kind`, or `"cholesky"` where `"auto"`
    /// handed the steps to Cholesky ([`crate::solve::SolverKind::Auto`]).
    pub kind_at_end: String,
    /// Iterations per solve.
    pub iterations: MeanMax,
    /// Relative residual per solve.
    pub residual: MeanMax,
}

/// Mesh counts at one moment.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct MeshCounts {
    /// Nodes.
    pub nodes: usize,
    /// Elements.
    pub elements: usize,
    /// Elements by vertex count.
    pub elements_by_vertex_count: BTreeMap<usize, usize>,
    /// Total volume (m^3).
    pub volume: f64,
    /// The lowest element quality `6√2 V / d³` (1 for a regular
    /// tetrahedron, towards 0 for slivers).
    pub worst_quality: f64,
}

/// Everything `summary.json` holds.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Summary {
    /// The scene file.
    pub scene: String,
    /// `"static"` or `"dynamic"`.
    pub mode: String,
    /// Worker threads used.
    pub threads: usize,
    /// Mesh at the start.
    pub start: MeshCounts,
    /// Mesh at the end.
    pub end: MeshCounts,
    /// Connected components at the end.
    pub components_end: usize,
    /// Steps run (1 for a static solve).
    pub steps: usize,
    /// Wall time by phase (s).
    pub wall_time: PhaseTimings,
    /// Total wall time (s).
    pub wall_time_total: f64,
    /// Mean wall time per step (ms).
    pub ms_per_step: f64,
    /// Largest nodal displacement magnitude (m).
    pub max_displacement: f64,
    /// Final elastic energy (J).
    pub elastic_energy: f64,
    /// Final kinetic energy (J).
    pub kinetic_energy: f64,
    /// Solver statistics.
    pub solver: SolverSummary,
    /// Frames written.
    pub frames: usize,
    /// The largest element stretch (deformed over rest diameter) over the
    /// written frames, and the element.
    pub worst_stretch: Located,
    /// The fastest node (m/s) over the written frames, and the node.
    pub max_node_speed: Located,
    /// The speed free fall reaches by the end of the run, `|v0| + |g| t`
    /// (m/s): what no node should exceed by much.
    pub free_fall_speed: f64,
    /// The smallest lumped mass of a node over the mean nodal mass of its
    /// elements, over the run (checked at the start and after every cut),
    /// and the node.
    pub min_mass_ratio: Located,
    /// Cuts run again with one more element kept whole because the element
    /// store found a part unhealthy.
    pub cut_retries: usize,
    /// Discontinuous Galerkin only: the penalty `η` in use (doubled from
    /// the scene's until the system was positive definite, for `ip`), and
    /// the faces the cuts integrated again.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dg: Option<DgSummary>,
    /// How many times a guard fired in `"warn"` mode.
    pub guard_warnings: usize,
    /// The first of those diagnoses.
    pub guard_warnings_listed: Vec<String>,
}

/// The discontinuous Galerkin figures of a run.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DgSummary {
    /// The penalty `η` in use.
    pub penalty: f64,
    /// Faces the cuts integrated again (the others kept their moments).
    pub faces_integrated: usize,
}

impl MeshCounts {
    /// Counts of `sim`'s mesh.
    pub fn of(sim: &Simulation) -> Self {
        let mesh = sim.mesh();
        MeshCounts {
            nodes: mesh.nodes.len(),
            elements: mesh.elements.len(),
            elements_by_vertex_count: mesh.count_by_vertex_count(),
            volume: mesh.total_volume(),
            worst_quality: (0..mesh.elements.len()).map(|e| mesh.element_quality(e)).fold(f64::INFINITY, f64::min),
        }
    }
}

/// Writes `summary` as pretty JSON to `path`.
pub fn write_summary(path: &Path, summary: &Summary) -> Result<(), IoError> {
    let text = serde_json::to_string_pretty(summary).expect("summary serialises");
    crate::io::write_text(path, &text)
}
