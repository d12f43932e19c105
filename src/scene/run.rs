//! Running a scene end to end: mesh, simulation, frames, summary.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
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
use crate::sim::{EmbeddedSurface, GuardMode, Guards, Located, SavedState, Simulation};
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
    /// Write `checkpoint.bin` into the output folder every this many steps
    /// (dynamic scenes; see [`crate::checkpoint`]).
    pub checkpoint_every: Option<usize>,
}

impl LoadedScene {
    /// Builds the scene's mesh (read or generated; a volume mesh read from
    /// a file renumbered for locality), with its slivers merged away when
    /// `mesh.merge_slivers` asks for it.
    pub fn build_mesh(&self) -> Result<PolyMesh, SceneError> {
        let mut mesh = self.read_or_generate_mesh()?;
        if let Some(q) = self.scene.mesh.merge_slivers {
            merge_slivers(&mut mesh, q).map_err(|e| self.engine(e))?;
        }
        // (a file's numbering is whatever made the file; the generators and
        // the meshing number cell by cell already)
        if self.scene.mesh.file.is_some() && self.scene.meshing.is_none() {
            mesh.renumber_for_locality();
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
fn progress_bar(steps: usize) -> indicatif::ProgressBar {
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
    let mut run = Run::start(scene.clone(), opts)?;
    if scene.scene.simulation.mode == Mode::Static {
        run.solve_static()?;
    } else {
        while run.step()? {}
    }
    run.finish()
}

/// Continues the run a checkpoint was taken of (see [`Run::resume`]) to its
/// end, and returns the summary.
pub fn resume_run(checkpoint: &Path) -> Result<Summary, SceneError> {
    let mut run = Run::resume(checkpoint)?;
    while run.step()? {}
    run.finish()
}

/// Refinement passes of a static scene at most (each pass refines every
/// element over its threshold once).
const MAX_REFINE_PASSES: usize = 8;

/// The name of the checkpoint file in a run's output folder.
pub const CHECKPOINT_FILE: &str = "checkpoint.bin";

/// Most guard warnings a summary lists (a run counts them all).
const LISTED_WARNINGS: usize = 20;

/// What a run has done so far, besides the simulation: what a checkpoint
/// stores to carry a run on, and what its summary reports.
#[derive(serde::Serialize, serde::Deserialize)]
struct Progress {
    /// Steps taken.
    step: usize,
    /// Frames written.
    frames: usize,
    /// Iterations and relative residual of every solve.
    solves: Vec<(usize, f64)>,
    worst_stretch: Located,
    max_node_speed: Located,
    min_mass_ratio: Located,
    /// The frames of `run.pvd`: time (s) and file.
    collection: Vec<(f64, String)>,
    start: MeshCounts,
    pictures: Option<Pictures>,
    guards: Guards,
    /// Guard warnings (the first [`LISTED_WARNINGS`]) and their count.
    warnings: Vec<String>,
    warning_count: usize,
    /// Wall time (s) of the run's earlier processes, before a resume.
    wall_before: f64,
}

/// A checkpoint's content: the scene as it was read, the run's settings,
/// its progress and the simulation (generic so that writing borrows what
/// reading owns).
#[derive(serde::Serialize, serde::Deserialize)]
struct Saved<P, S> {
    scene_path: PathBuf,
    scene_text: String,
    dir: PathBuf,
    steps: usize,
    checkpoint_every: Option<usize>,
    progress: P,
    sim: S,
}

/// A scene run, step by step: what `cleave run` and `cleave resume` drive,
/// and what a host can drive itself (reaching the simulation between
/// steps through [`Run::simulation_mut`]).
///
/// Every step of a dynamic run applies the scene's cuts at that step,
/// steps, checks the guards (`[simulation] guards`), refines, writes the
/// frame when one is due and a checkpoint when one is due. A guard that
/// fires in `"stop"` mode (or a failed solve, in any mode) undoes the
/// step, writes the last good frame and a checkpoint of it, and ends the
/// run with [`SceneError::Stopped`].
pub struct Run {
    scene: LoadedScene,
    dir: PathBuf,
    /// Steps the run takes in all.
    steps: usize,
    checkpoint_every: Option<usize>,
    formats: Vec<Format>,
    started: Instant,
    bar: indicatif::ProgressBar,
    sim: Simulation,
    progress: Progress,
    /// The state before the current step, to undo it.
    last_good: SavedState,
}

impl Run {
    /// Builds the scene's simulation; a dynamic run writes its first frame.
    pub fn start(scene: LoadedScene, opts: &RunOptions) -> Result<Self, SceneError> {
        if opts.checkpoint_every == Some(0) {
            return Err(scene.invalid("simulation", 0, "--checkpoint-every must be at least 1"));
        }
        let started = Instant::now();
        let dir = scene.output_dir(opts);
        let sim = scene.build_simulation()?;
        let s = &scene.scene;
        let steps = match s.simulation.mode {
            Mode::Static => 1,
            Mode::Dynamic => opts.steps.unwrap_or(s.simulation.steps),
        };
        let progress = Progress {
            step: 0,
            frames: 0,
            solves: Vec::new(),
            worst_stretch: Located { value: 1.0, at: 0 },
            max_node_speed: Located::default(),
            min_mass_ratio: sim.min_mass_ratio(),
            collection: Vec::new(),
            start: MeshCounts::of(&sim),
            pictures: s
                .formats()
                .contains(&Format::Png)
                .then(|| Pictures::new(s.output.color == PictureColor::VonMises)),
            guards: Guards::new(s.guards.limits()),
            warnings: Vec::new(),
            warning_count: 0,
            wall_before: 0.0,
        };
        let mut run = Run {
            formats: s.formats(),
            bar: progress_bar(if s.simulation.mode == Mode::Dynamic { steps } else { 0 }),
            scene,
            dir,
            steps,
            checkpoint_every: opts.checkpoint_every,
            started,
            sim,
            progress,
            last_good: SavedState::default(),
        };
        if run.scene.scene.simulation.mode == Mode::Dynamic {
            run.write_frame(0)?;
        }
        Ok(run)
    }

    /// Reads a checkpoint (written by `--checkpoint-every` or by a guard
    /// that stopped a run) and carries its run on from there, writing into
    /// the same output folder; the steps and frames that follow are the
    /// same, bit for bit, as those of the run that was not interrupted.
    pub fn resume(checkpoint: &Path) -> Result<Self, SceneError> {
        let saved: Saved<Progress, Simulation> =
            crate::checkpoint::read(checkpoint).map_err(|e| SceneError::Checkpoint(Box::new(e)))?;
        let scene = LoadedScene::parse(&saved.scene_path, saved.scene_text)?;
        Ok(Run {
            formats: scene.scene.formats(),
            bar: progress_bar(saved.steps.saturating_sub(saved.progress.step)),
            scene,
            dir: saved.dir,
            steps: saved.steps,
            checkpoint_every: saved.checkpoint_every,
            started: Instant::now(),
            sim: saved.sim,
            progress: saved.progress,
            last_good: SavedState::default(),
        })
    }

    /// The simulation, to read or change between steps.
    pub fn simulation_mut(&mut self) -> &mut Simulation {
        &mut self.sim
    }

    /// The output folder.
    pub fn output_dir(&self) -> &Path {
        &self.dir
    }

    /// Steps taken so far.
    pub fn steps_taken(&self) -> usize {
        self.progress.step
    }

    /// Guard warnings so far (the first few, see [`Summary::guard_warnings`]).
    pub fn guard_warnings(&self) -> &[String] {
        &self.progress.warnings
    }

    /// The engine's error `e` at this run's scene.
    fn engine(&self, e: impl Into<Error>) -> SceneError {
        self.scene.engine(e)
    }

    /// A static run: solves, then refines and solves again until no
    /// element is over its threshold (or every such one is at its level),
    /// writing a frame per solve.
    pub fn solve_static(&mut self) -> Result<(), SceneError> {
        let solve = self.sim.solve_static().map_err(|e| self.engine(e))?;
        self.progress.solves.push((solve.iterations, solve.residual));
        self.write_frame(0)?;
        let mut passes = 0;
        while passes < MAX_REFINE_PASSES && self.refine()? > 0 {
            passes += 1;
            let solve = self.sim.solve_static().map_err(|e| self.engine(e))?;
            self.progress.solves.push((solve.iterations, solve.residual));
            self.write_frame(passes)?;
        }
        Ok(())
    }

    /// Runs every refinement rule once; returns how many elements were split.
    fn refine(&mut self) -> Result<usize, SceneError> {
        let mut refined = 0;
        for r in &self.scene.scene.refine {
            refined += self.sim.refine_by_stress(&r.rule()).map_err(|e| self.scene.engine(e))?.refined;
        }
        Ok(refined)
    }

    /// Takes the next step of a dynamic run; returns whether steps remain.
    pub fn step(&mut self) -> Result<bool, SceneError> {
        if self.progress.step >= self.steps {
            return Ok(false);
        }
        let step = self.progress.step + 1;
        for cut in self.scene.scene.cut.iter().filter(|c| c.step == step) {
            let cut = match (&cut.plane, &cut.polygon) {
                (Some(p), _) => self.sim.cut_plane(&p.plane()).map(|_| ()),
                (None, Some(polygon)) => self.sim.cut_polygon(polygon).map(|_| ()),
                (None, None) => Ok(()),
            };
            cut.map_err(|e| self.scene.engine(e))?;
            let ratio = self.sim.min_mass_ratio();
            if ratio.value < self.progress.min_mass_ratio.value {
                self.progress.min_mass_ratio = ratio;
            }
            self.progress.guards.rebase();
        }
        let mode = self.scene.scene.simulation.guards;
        self.last_good.save(&self.sim);
        let solve = match self.sim.step() {
            Ok(stats) => stats.solve,
            Err(e) => return Err(self.stop(e.to_string())),
        };
        if mode != GuardMode::Off {
            if let Some(trip) = self.progress.guards.check(&self.sim, step) {
                if mode == GuardMode::Stop {
                    if let Err(e) = self.last_good.restore(&mut self.sim) {
                        return Err(self.engine(e));
                    }
                    return Err(self.stop(trip.to_string()));
                }
                eprintln!("warning: {}: guard: {trip}", self.scene.path.display());
                if self.progress.warnings.len() < LISTED_WARNINGS {
                    self.progress.warnings.push(trip.to_string());
                }
                self.progress.warning_count += 1;
            }
        }
        self.progress.solves.push((solve.iterations, solve.residual));
        self.progress.step = step;
        if self.refine()? > 0 {
            self.progress.guards.rebase();
        }
        let every = self.scene.scene.output.every;
        if step % every == 0 {
            self.write_frame(step / every)?;
        }
        if self.checkpoint_every.is_some_and(|n| step % n == 0) {
            self.checkpoint()?;
        }
        self.bar.inc(1);
        Ok(step < self.steps)
    }

    /// Ends the run at its last good state: a checkpoint of it, its frame
    /// (unless one was written at that step), and the error naming what
    /// stopped it.
    fn stop(&mut self, diagnosis: String) -> SceneError {
        self.bar.abandon();
        let every = self.scene.scene.output.every;
        let step = self.progress.step;
        let written = self.checkpoint().and_then(|()| match step % every {
            0 => Ok(()),
            _ => self.write_frame(step / every + 1),
        });
        if let Err(e) = written {
            return e;
        }
        SceneError::Stopped { path: self.scene.path.clone(), diagnosis, last_good_step: step, dir: self.dir.clone() }
    }

    /// Writes `checkpoint.bin` into the output folder (atomically).
    pub fn checkpoint(&mut self) -> Result<(), SceneError> {
        // the wall time so far goes with the checkpoint
        self.progress.wall_before += self.started.elapsed().as_secs_f64();
        self.started = Instant::now();
        std::fs::create_dir_all(&self.dir).map_err(|e| self.engine(crate::io::IoError::os(&self.dir, e)))?;
        if self.sim.has_body_force() {
            let allowed = "a body force is a closure, which a checkpoint cannot hold";
            return Err(self.engine(crate::param::ParamError::new("checkpoint", "body force", allowed)));
        }
        let saved = Saved {
            scene_path: self.scene.path.clone(),
            scene_text: self.scene.text.clone(),
            dir: std::path::absolute(&self.dir).unwrap_or_else(|_| self.dir.clone()),
            steps: self.steps,
            checkpoint_every: self.checkpoint_every,
            progress: &self.progress,
            sim: &self.sim,
        };
        crate::checkpoint::write(&self.dir.join(CHECKPOINT_FILE), &saved)
            .map_err(|e| SceneError::Checkpoint(Box::new(e)))?;
        // the run goes on from what the checkpoint holds, as a resumed one
        self.sim.drop_solver_state();
        Ok(())
    }

    /// Writes frame `index` in every format, the pictures and the time
    /// series, and updates the run-health figures.
    fn write_frame(&mut self, index: usize) -> Result<(), SceneError> {
        self.write_frame_files(index).map_err(|e| self.scene.engine(e))
    }

    fn write_frame_files(&mut self, index: usize) -> Result<(), Error> {
        let t = Instant::now();
        let (dir, sim, p) = (&self.dir, &mut self.sim, &mut self.progress);
        write_frame(dir, index, sim, &self.formats)?;
        if let Some(pictures) = p.pictures.as_mut() {
            pictures.write(dir, index, sim)?;
        }
        if self.formats.contains(&Format::Vtu) {
            // rewritten with every frame, so that an interrupted run leaves
            // one that lists what it wrote
            p.collection.push((sim.time(), format!("frame_{index:04}.vtu")));
            write_collection(&dir.join("run.pvd"), &p.collection)?;
        }
        let (stretch, speed) = (sim.worst_stretch(), sim.max_node_speed());
        if stretch.value > p.worst_stretch.value {
            p.worst_stretch = stretch;
        }
        if speed.value > p.max_node_speed.value {
            p.max_node_speed = speed;
        }
        sim.record_output_time(t.elapsed().as_secs_f64());
        p.frames += 1;
        Ok(())
    }

    /// Writes `summary.json` and returns the summary.
    pub fn finish(self) -> Result<Summary, SceneError> {
        self.bar.finish_and_clear();
        let (sim, p, s) = (&self.sim, &self.progress, &self.scene.scene);
        let adjacency = sim.mesh().adjacency();
        let (_, components) = adjacency.element_components(sim.mesh());
        let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let free_fall_speed = norm(s.simulation.velocity) + norm(s.simulation.gravity) * sim.time();
        let wall = *sim.timings();
        let steps = self.steps;
        let summary = Summary {
            scene: self.scene.path.display().to_string(),
            mode: format!("{:?}", s.simulation.mode).to_lowercase(),
            threads: rayon::current_num_threads(),
            end: MeshCounts::of(sim),
            start: p.start.clone(),
            components_end: components,
            steps,
            wall_time: wall,
            wall_time_total: p.wall_before + self.started.elapsed().as_secs_f64(),
            ms_per_step: 1e3 * wall.steps() / steps.max(1) as f64,
            max_displacement: sim.max_displacement(),
            elastic_energy: sim.elastic_energy(),
            kinetic_energy: sim.kinetic_energy(),
            solver: SolverSummary {
                kind: format!("{:?}", s.solver.kind.kind()).to_lowercase(),
                kind_at_end: format!("{:?}", sim.solver_kind()).to_lowercase(),
                iterations: MeanMax::of(p.solves.iter().map(|s| s.0 as f64)),
                residual: MeanMax::of(p.solves.iter().map(|s| s.1)),
            },
            frames: p.frames,
            worst_stretch: p.worst_stretch,
            max_node_speed: p.max_node_speed,
            free_fall_speed,
            min_mass_ratio: p.min_mass_ratio,
            cut_retries: sim.cut_retries(),
            dg: sim.dg().map(|d| DgSummary { penalty: d.penalty, faces_integrated: sim.faces_integrated() }),
            guard_warnings: p.warning_count,
            guard_warnings_listed: p.warnings.clone(),
        };
        write_summary(&self.dir.join("summary.json"), &summary).map_err(|e| self.scene.engine(e))?;
        Ok(summary)
    }
}
