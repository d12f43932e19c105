//! Running a scene end to end: mesh, simulation, frames, summary.

use std::path::PathBuf;
use std::time::Instant;

use super::{BoxElement, Generator, LoadedScene, Mode, Quadrature};
use crate::io::read_mesh;
use crate::mesh::PolyMesh;
use crate::meshing::{box_hex, box_tet, clipped_box, random_convex};
use crate::output::{write_frame, write_summary, MeanMax, MeshCounts, SolverSummary, Summary};
use crate::sim::{FixedRegion, Simulation, SimulationParams};
use crate::store::{BasisOptions, QuadratureRule};
use crate::Error;

/// Command-line overrides of a scene.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Output folder instead of the scene's `output.dir`.
    pub out: Option<PathBuf>,
    /// Number of steps instead of the scene's `simulation.steps` (dynamic
    /// scenes; a static scene solves once).
    pub steps: Option<usize>,
}

impl LoadedScene {
    /// Builds the scene's mesh (read or generated).
    pub fn build_mesh(&self) -> Result<PolyMesh, Error> {
        let m = &self.scene.mesh;
        if let Some(file) = &m.file {
            return Ok(read_mesh(&self.resolve(file))?);
        }
        let (min, max) = (m.min.unwrap_or([0.0; 3]), m.max.unwrap_or([1.0; 3]));
        match (m.generator, m.element) {
            (Some(Generator::Box), Some(BoxElement::Hex)) => Ok(box_hex(min, max, m.cells.unwrap_or([1; 3]))?),
            (Some(Generator::Box), Some(BoxElement::Tet)) => Ok(box_tet(min, max, m.cells.unwrap_or([1; 3]))?),
            (Some(Generator::Box), Some(BoxElement::RandomConvex)) => {
                random_convex(min, max, m.planes.unwrap_or(8), m.seed.unwrap_or(1))
            }
            (Some(Generator::Box), Some(BoxElement::Clipped)) => {
                clipped_box(min, max, m.planes.unwrap_or(8), m.seed.unwrap_or(0))
            }
            _ => Err(self.invalid("mesh", "…", "needs mesh.file or a generator with an element kind").into()),
        }
    }

    /// The output folder: `--out`, else `output.dir` (relative to the scene),
    /// else `out/<scene name>`.
    pub fn output_dir(&self, opts: &RunOptions) -> PathBuf {
        if let Some(o) = &opts.out {
            return o.clone();
        }
        match &self.scene.output.dir {
            Some(d) => self.resolve(d),
            None => PathBuf::from("out").join(self.path.file_stem().unwrap_or_default()),
        }
    }

    /// Builds the simulation: mesh, material, fixed regions.
    pub fn build_simulation(&self) -> Result<Simulation, Error> {
        let mesh = self.build_mesh()?;
        let s = &self.scene;
        let quadrature = match s.basis.quadrature {
            Quadrature::Consistent => QuadratureRule::Consistent,
            Quadrature::Paper => QuadratureRule::Paper,
        };
        let basis = BasisOptions { quadrature };
        let params = SimulationParams { material: s.material(), gravity: s.simulation.gravity, basis };
        let mut sim = Simulation::new(mesh, params)?;
        for f in &s.fixed {
            sim.fix(FixedRegion {
                min: f.region.min,
                max: f.region.max,
                displacement: f.displacement,
                gradient: f.gradient,
            })?;
        }
        Ok(sim)
    }
}

/// Runs a scene: builds it, solves, writes frames and `summary.json` into the
/// output folder, and returns the summary.
pub fn run_scene(scene: &LoadedScene, opts: &RunOptions) -> Result<Summary, Error> {
    let started = Instant::now();
    let dir = scene.output_dir(opts);
    let mut sim = scene.build_simulation()?;
    let start = MeshCounts::of(&sim);
    let s = &scene.scene;
    let mut stats = Vec::new();
    let mut frames = 0;
    let steps = match s.simulation.mode {
        Mode::Static => {
            stats.push(sim.solve_static()?);
            1
        }
        Mode::Dynamic => {
            return Err(scene.unsupported("simulation.mode", "dynamic simulation is not implemented yet").into())
        }
    };
    let t = Instant::now();
    write_frame(&dir, 0, &sim, &s.output.formats)?;
    frames += 1;
    sim.record_output_time(t.elapsed().as_secs_f64());
    let adjacency = sim.mesh().adjacency();
    let (_, components) = adjacency.element_components(sim.mesh());
    let max_displacement =
        sim.displacements().iter().map(|u| (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()).fold(0.0, f64::max);
    let wall = *sim.timings();
    let total = started.elapsed().as_secs_f64();
    let summary = Summary {
        scene: scene.path.display().to_string(),
        mode: format!("{:?}", s.simulation.mode).to_lowercase(),
        threads: rayon::current_num_threads(),
        end: MeshCounts::of(&sim),
        start,
        components_end: components,
        steps,
        wall_time: wall,
        wall_time_total: total,
        ms_per_step: 1e3 * (wall.assembly + wall.solve) / steps as f64,
        max_displacement,
        elastic_energy: sim.elastic_energy(),
        kinetic_energy: sim.kinetic_energy(),
        solver: SolverSummary {
            kind: format!("{:?}", s.solver.kind).to_lowercase(),
            iterations: MeanMax::of(stats.iter().map(|s| s.iterations as f64)),
            residual: MeanMax::of(stats.iter().map(|s| s.residual)),
        },
        frames,
    };
    write_summary(&dir.join("summary.json"), &summary)?;
    Ok(summary)
}
