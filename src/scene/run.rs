//! Running a scene end to end: mesh, simulation, frames, summary.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

use super::{BoxElement, Generator, LoadedScene, MeshingMethod, Mode, PictureColor, SceneError};
use crate::io::{read_mesh, read_surface, write_collection};
use crate::mesh::PolyMesh;
use crate::meshing::{
    box_hex, box_l_prisms, box_tet, clipped_box, grid_slice, octree, prism, random_convex, SliceOptions,
};
use crate::output::{
    write_frame, write_summary, DgSummary, Format, MeanMax, MeshCounts, Pictures, SolverSummary, Summary,
};
use crate::sim::{EmbeddedSurface, Located, Simulation};
use crate::surface::prepare;
use crate::topology::merge_slivers;
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
    /// Builds the scene's mesh (read or generated), with its slivers merged
    /// away when `mesh.merge_slivers` asks for it.
    pub fn build_mesh(&self) -> Result<PolyMesh, SceneError> {
        let mut mesh = self.read_or_generate_mesh()?;
        if let Some(q) = self.scene.mesh.merge_slivers {
            merge_slivers(&mut mesh, q).map_err(|e| self.engine(e))?;
        }
        Ok(mesh)
    }

    /// The engine's error `e`, met while building or running this scene.
    pub fn engine(&self, e: impl Into<Error>) -> SceneError {
        SceneError::Engine { path: self.path.clone(), source: Box::new(e.into()) }
    }

    fn read_or_generate_mesh(&self) -> Result<PolyMesh, SceneError> {
        let m = &self.scene.mesh;
        if let Some(file) = &m.file {
            let path = self.resolve(file);
            return match &self.scene.meshing {
                None => read_mesh(&path).map_err(|e| self.engine(e)),
                Some(me) => {
                    let raw = read_surface(&path).map_err(|e| self.engine(e))?;
                    let (surface, _) = prepare(&raw).map_err(|e| self.engine(e))?;
                    let meshed = match me.method {
                        MeshingMethod::GridSlice => {
                            let options = SliceOptions {
                                merge_below: me.merge_below.unwrap_or(0.05),
                                simplify: me.simplify.unwrap_or(0.0),
                            };
                            grid_slice(&surface, me.cell.unwrap_or(f64::NAN), &options).map(|(mesh, _)| mesh)
                        }
                        MeshingMethod::Octree => octree(&surface, me.max_depth.unwrap_or(0)).map(|(mesh, _)| mesh),
                    };
                    meshed.map_err(|e| self.engine(e))
                }
            };
        }
        let (min, max) = (m.min.unwrap_or([0.0; 3]), m.max.unwrap_or([1.0; 3]));
        let generated: Result<PolyMesh, Error> = match (m.generator, m.element) {
            (Some(Generator::Box), Some(BoxElement::Hex)) => {
                box_hex(min, max, m.cells.unwrap_or([1; 3])).map_err(Error::from)
            }
            (Some(Generator::Box), Some(BoxElement::Tet)) => {
                box_tet(min, max, m.cells.unwrap_or([1; 3])).map_err(Error::from)
            }
            (Some(Generator::Box), Some(BoxElement::LPrism)) => {
                box_l_prisms(min, max, m.cells.unwrap_or([2, 2, 1])).map_err(Error::from)
            }
            (Some(Generator::Prism), _) => {
                prism(m.outline.as_deref().unwrap_or_default(), m.height.unwrap_or(1.0)).map_err(Error::from)
            }
            (Some(Generator::Box), Some(BoxElement::RandomConvex)) => {
                random_convex(min, max, m.planes.unwrap_or(8), m.seed.unwrap_or(1))
            }
            (Some(Generator::Box), Some(BoxElement::Clipped)) => {
                clipped_box(min, max, m.planes.unwrap_or(8), m.seed.unwrap_or(0))
            }
            _ => return Err(self.invalid("mesh", "…", "needs mesh.file or a generator with an element kind")),
        };
        generated.map_err(|e| self.engine(e))
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

    /// Builds the simulation: mesh, material, solver, fixed regions,
    /// colliders and initial velocity.
    pub fn build_simulation(&self) -> Result<Simulation, SceneError> {
        let mesh = self.build_mesh()?;
        let s = &self.scene;
        let engine = |e: Error| self.engine(e);
        let mut sim = Simulation::new(mesh, s.params()).map_err(engine)?;
        for f in &s.fixed {
            sim.fix(f.region()).map_err(engine)?;
        }
        for c in &s.collider {
            sim.add_collider(c.collider().map_err(|e| self.engine(e))?);
        }
        if let Some(file) = &s.mesh.embed {
            let surface = read_surface(&self.resolve(file)).map_err(|e| self.engine(e))?;
            let surface = EmbeddedSurface { vertices: surface.vertices, triangles: surface.triangles };
            sim.embed(surface).map_err(engine)?;
        }
        let v0 = s.simulation.velocity;
        if v0 != [0.0; 3] {
            sim.set_velocities(&vec![v0; sim.mesh().nodes.len()]).map_err(engine)?;
        }
        Ok(sim)
    }
}

/// A progress bar over `steps`, drawn only on a terminal.
fn progress(steps: usize) -> indicatif::ProgressBar {
    if !std::io::stderr().is_terminal() || steps < 2 {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(steps as u64);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} steps  {per_sec}  eta {eta}") {
        bar.set_style(style);
    }
    bar
}

/// Runs a scene: builds it, solves or steps it, writes frames and
/// `summary.json` into the output folder, and returns the summary.
pub fn run_scene(scene: &LoadedScene, opts: &RunOptions) -> Result<Summary, SceneError> {
    run(scene, opts).map_err(|e| match e {
        Failure::Scene(e) => e,
        Failure::Engine(e) => scene.engine(e),
    })
}

/// What stops a run: the scene, or the engine running it.
enum Failure {
    Scene(SceneError),
    Engine(Error),
}

impl From<SceneError> for Failure {
    fn from(e: SceneError) -> Self {
        Failure::Scene(e)
    }
}

impl<E: Into<Error>> From<E> for Failure {
    fn from(e: E) -> Self {
        Failure::Engine(e.into())
    }
}

/// Refinement passes of a static scene at most (each pass refines every
/// element over its threshold once).
const MAX_REFINE_PASSES: usize = 8;

/// Runs every refinement rule once; returns how many elements were split.
fn refine(sim: &mut Simulation, rules: &[super::RefineSpec]) -> Result<usize, Error> {
    let mut refined = 0;
    for r in rules {
        refined += sim.refine_by_stress(&r.rule())?.refined;
    }
    Ok(refined)
}

fn run(scene: &LoadedScene, opts: &RunOptions) -> Result<Summary, Failure> {
    let started = Instant::now();
    let dir = scene.output_dir(opts);
    let mut sim = scene.build_simulation()?;
    let start = MeshCounts::of(&sim);
    let s = &scene.scene;
    let mut stats = Vec::new();
    let mut frames = 0;
    let (mut worst_stretch, mut max_node_speed) = (Located { value: 1.0, at: 0 }, Located::default());
    let mut min_mass_ratio = sim.min_mass_ratio();
    let formats = s.formats();
    // the time series for ParaView, rewritten with every frame so that an
    // interrupted run leaves one that lists what it wrote
    let mut collection: Vec<(f64, String)> = Vec::new();
    let mut pictures = formats.contains(&Format::Png).then(|| Pictures::new(s.output.color == PictureColor::VonMises));
    let mut write = |sim: &mut Simulation, index: usize| -> Result<(), Error> {
        let t = Instant::now();
        write_frame(&dir, index, sim, &formats)?;
        if let Some(pictures) = pictures.as_mut() {
            pictures.write(&dir, index, sim)?;
        }
        if formats.contains(&Format::Vtu) {
            collection.push((sim.time(), format!("frame_{index:04}.vtu")));
            write_collection(&dir.join("run.pvd"), &collection)?;
        }
        let (stretch, speed) = (sim.worst_stretch(), sim.max_node_speed());
        if stretch.value > worst_stretch.value {
            worst_stretch = stretch;
        }
        if speed.value > max_node_speed.value {
            max_node_speed = speed;
        }
        sim.record_output_time(t.elapsed().as_secs_f64());
        frames += 1;
        Ok(())
    };
    let steps = match s.simulation.mode {
        Mode::Static => {
            stats.push(sim.solve_static()?);
            write(&mut sim, 0)?;
            // refinement: solve again on the refined mesh until no element
            // is over its threshold (or every such one is at its level)
            let mut passes = 0;
            while passes < MAX_REFINE_PASSES && refine(&mut sim, &s.refine)? > 0 {
                passes += 1;
                stats.push(sim.solve_static()?);
                write(&mut sim, passes)?;
            }
            1
        }
        Mode::Dynamic => {
            let steps = opts.steps.unwrap_or(s.simulation.steps);
            write(&mut sim, 0)?;
            let bar = progress(steps);
            for step in 1..=steps {
                for cut in s.cut.iter().filter(|c| c.step == step) {
                    match (&cut.plane, &cut.polygon) {
                        (Some(p), _) => {
                            sim.cut_plane(&p.plane())?;
                        }
                        (None, Some(polygon)) => {
                            sim.cut_polygon(polygon)?;
                        }
                        (None, None) => {}
                    }
                    let ratio = sim.min_mass_ratio();
                    if ratio.value < min_mass_ratio.value {
                        min_mass_ratio = ratio;
                    }
                }
                stats.push(sim.step()?.solve);
                refine(&mut sim, &s.refine)?;
                if step % s.output.every == 0 {
                    write(&mut sim, step / s.output.every)?;
                }
                bar.inc(1);
            }
            bar.finish_and_clear();
            steps
        }
    };
    let adjacency = sim.mesh().adjacency();
    let (_, components) = adjacency.element_components(sim.mesh());
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let free_fall_speed = norm(s.simulation.velocity) + norm(s.simulation.gravity) * sim.time();
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
        ms_per_step: 1e3 * wall.steps() / steps.max(1) as f64,
        max_displacement: sim.max_displacement(),
        elastic_energy: sim.elastic_energy(),
        kinetic_energy: sim.kinetic_energy(),
        solver: SolverSummary {
            kind: format!("{:?}", s.solver.kind.kind()).to_lowercase(),
            iterations: MeanMax::of(stats.iter().map(|s| s.iterations as f64)),
            residual: MeanMax::of(stats.iter().map(|s| s.residual)),
        },
        frames,
        worst_stretch,
        max_node_speed,
        free_fall_speed,
        min_mass_ratio,
        cut_retries: sim.cut_retries(),
        dg: sim.dg().map(|d| DgSummary { penalty: d.penalty, faces_integrated: sim.faces_integrated() }),
    };
    write_summary(&dir.join("summary.json"), &summary)?;
    Ok(summary)
}
