//! The simulation: the state of one elastic body and the operations a host
//! drives frame by frame (the embedding API).
//!
//! ```
//! use cleave::{meshing::box_tet, material::Material, sim::{FixedRegion, Simulation, SimulationParams}};
//! let mesh = box_tet([0.0; 3], [4.0, 1.0, 1.0], [8, 2, 2])?;
//! let params = SimulationParams { material: Material::new(1e5, 0.3, 1000.0)?, ..Default::default() };
//! let mut sim = Simulation::new(mesh, params)?;
//! sim.fix(FixedRegion::clamp([-1.0; 3], [1e-3, 2.0, 2.0]))?;
//! let stats = sim.solve_static()?;
//! assert!(stats.residual < 1e-8);
//! let tip = sim.displacements().iter().map(|u| u[2]).fold(0.0, f64::min);
//! assert!(tip < -1.0); // the beam sags under its own weight
//! for _ in 0..3 {
//!     sim.step()?; // implicit Euler, corotated, from the static state
//! }
//! assert!(sim.kinetic_energy().is_finite());
//! # Ok::<(), cleave::Error>(())
//! ```

mod bodies;
mod body_force;
mod boundary;
mod corotation;
mod diagnostics;
mod discretization;
pub mod embedding;
mod guards;
mod params;
mod points;
mod rebuild;
mod refine;
mod state;
mod statics;
mod step;
mod timings;

pub use bodies::{step_bodies, BodyError};
pub use body_force::BodyForce;
pub use boundary::{Collider, FixedRegion};
pub use corotation::Corotation;
pub use diagnostics::Located;
pub use discretization::{Discretization, Model, NodalElements};
pub use embedding::EmbeddedSurface;
pub use guards::{GuardLimits, GuardMode, GuardTrip, Guards};
pub use params::{SimulationParams, CUT_ATTEMPTS};
pub use points::PointMap;
pub use refine::{principal, RefineReport, RefineRule, RefineSplit};
pub use step::StepStats;
pub use timings::{Phase, PhaseTimings};

use boundary::Boundary;
use state::NodeState;
use statics::StaticSystem;
use step::StepSystem;

use rayon::prelude::*;

use crate::assembly::SparsePattern;
use crate::dg::DgElements;
use crate::mesh::PolyMesh;
use crate::param::ParamError;
use crate::solve::{SolveError, SolverKind};
use crate::store::{ElementStore, Family};
use crate::Error;

/// One elastic body: its mesh, element data, state, boundary conditions
/// and the systems of its steps and static solves.
///
/// The unknowns come in blocks of three: the nodes of the nodal families,
/// the polynomial coefficients of the discontinuous Galerkin family. State,
/// masses and the step work on blocks; what a host reads per node
/// (positions, displacements, velocities) is the blocks themselves for
/// the nodal families and the stitched field for DG (kaufmann2008 eq. 17).
///
/// The work is split by concern: the step's phases in `step.rs`, the
/// static solve in `statics.rs`, topology changes in `rebuild.rs`,
/// read-back figures in `diagnostics.rs`; the elements are reached through
/// [`Discretization`].
///
/// A simulation serializes (serde) to everything its future steps depend
/// on, bit for bit: the mesh after cuts, element data, rotations, pattern,
/// state and counters ([`crate::checkpoint`] writes it). The solvers are
/// not stored: they are rebuilt from the pattern on the first step or
/// static solve after deserialization, as after a cut.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Simulation {
    /// The mesh in its rest configuration (with room for cuts, also as
    /// deserialized: see [`with_room_for_cuts`]).
    #[serde(deserialize_with = "deserialize_with_room")]
    mesh: PolyMesh,
    params: SimulationParams,
    /// Element data and per-element state.
    elements: Model,
    /// The global sparse structure of this topology.
    pattern: SparsePattern,
    /// Mass per block (kg): lumped nodal masses, or the exact (diagonal)
    /// masses of an orthonormal DG basis.
    masses: Vec<f64>,
    /// Gravity weight per block (kg): the masses for the nodal families,
    /// `ρ ∫ N_a` for DG.
    loads: Vec<f64>,
    boundary: Boundary,
    /// The body force's load per block (N); empty without one.
    body_loads: Vec<[f64; 3]>,
    /// State per block.
    state: NodeState,
    /// Per-node fields of a discretisation whose blocks are not nodes.
    nodes: NodeView,
    /// Collision points of a discretisation whose blocks are not nodes, or
    /// of an embedded surface, and each point's share of a collider's
    /// stiffness.
    contacts: Option<(PointMap, Vec<f64>)>,
    /// An embedded surface and its map from the blocks.
    embedded: Option<(EmbeddedSurface, PointMap)>,
    /// Outward triangles of the boundary surface (node ids), per topology:
    /// built when first asked for (a cut leaves it empty, so that making
    /// the system ready to step never waits for a pass over the mesh).
    #[serde(skip)]
    surface: std::sync::OnceLock<Vec<[u32; 3]>>,
    /// The step's system, solver and buffers (empty after
    /// deserialization until the first step).
    #[serde(skip)]
    system: StepSystem,
    /// The static problem's solver, made on first use.
    #[serde(skip)]
    statics: Option<StaticSystem>,
    steps: usize,
    /// Smallest diameter of a part a cut makes (m): `min_part` times the
    /// median element diameter of the mesh the simulation was built on.
    part_floor: f64,
    /// Cuts run again with one more element kept whole (see
    /// [`CUT_ATTEMPTS`]).
    cut_retries: usize,
    /// [`SolverKind::Auto`]'s CG went past its budget, and the steps are
    /// solved by Cholesky since (see [`Simulation::solver_kind`]).
    solver_fell_back: bool,
    /// The running mean of [`SolverKind::Auto`]'s CG iterations per step
    /// (from 0, the newest step weighing a sixteenth).
    auto_cg_iterations: f64,
    /// For every node, an upper bound of the diameters of the elements
    /// holding it (m), found on the first cut and raised by every change
    /// after it: how far from a cut the elements it looks at can lie.
    #[serde(skip)]
    node_diameters: Option<Vec<f64>>,
    /// Faces a DG cut integrated again (the others kept their moments).
    faces_integrated: usize,
    /// How many times each element's ancestors were refined (elements a
    /// cut adds start at 0).
    refine_levels: Vec<u8>,
    timings: PhaseTimings,
}

/// A copy of a simulation's state (displacements, positions, velocities
/// and the step count), to undo the steps taken since it was saved, as
/// long as the topology has not changed.
#[derive(Clone, Debug, Default)]
pub struct SavedState {
    state: NodeState,
    steps: usize,
}

impl SavedState {
    /// Copies `sim`'s state (reusing this copy's memory).
    pub fn save(&mut self, sim: &Simulation) {
        self.state.clone_from(&sim.state);
        self.steps = sim.steps;
    }

    /// Puts the saved state back into `sim`; an error if `sim`'s topology
    /// changed since (its number of blocks differs).
    pub fn restore(&self, sim: &mut Simulation) -> Result<(), Error> {
        if self.state.velocity.len() != sim.state.velocity.len() {
            let message =
                format!("a state of {} blocks restored into {}", self.state.velocity.len(), sim.state.velocity.len());
            return Err(Error::Internal(message));
        }
        sim.state.clone_from(&self.state);
        sim.steps = self.steps;
        if !sim.nodal() {
            sim.nodes.refresh(&sim.state);
        }
        Ok(())
    }
}

/// Per-node positions, displacements and velocities read from blocks that
/// are not nodes, through a point map.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
struct NodeView {
    map: PointMap,
    position: Vec<[f64; 3]>,
    displacement: Vec<[f64; 3]>,
    velocity: Vec<[f64; 3]>,
}

impl NodeView {
    /// Evaluates the node fields of `state`.
    fn refresh(&mut self, state: &NodeState) {
        self.map.apply(&state.position, &mut self.position);
        self.map.apply(&state.displacement, &mut self.displacement);
        self.map.apply(&state.velocity, &mut self.velocity);
    }
}

/// The lumped mass (kg) of every node of a nodal body, `m_v = Σ_e μ_v^e
/// V_e ρ` (wicke2007 eq. 18), each summed over the elements `pattern`
/// lists at `v`, in its order: a cut recomputes only the nodes whose
/// elements changed (see [`Simulation::apply_cut`]), and every other node
/// keeps its mass to the bit, however the store moved its elements.
fn nodal_masses(store: &ElementStore, pattern: &SparsePattern, density: f64) -> Vec<f64> {
    (0..pattern.num_blocks).into_par_iter().map(|v| store.lumped_mass(pattern.held_at(v), density)).collect()
}

/// Gives `mesh` room for the elements, faces and nodes cuts add
/// ([`crate::keep_room`]): a mesh read from a file or a checkpoint has
/// none, and the first blade cut across bunny_100k doubled its faces and
/// elements (about 30 MB), copying them and faulting in their pages:
/// 33-50 ms, 21-24 ms with the room (AMD EPYC Zen 4).
fn with_room_for_cuts(mesh: &mut PolyMesh) {
    crate::keep_room(&mut mesh.elements);
    crate::keep_room(&mut mesh.faces);
    crate::keep_room(&mut mesh.nodes);
}

/// A simulation's mesh as deserialized, [`with_room_for_cuts`]. (The
/// other topology-sized arrays, of the element store, the pattern and the
/// node state, are read without room: the first cut after a resume grows
/// them, and took 45-80 ms on bunny_100k against 25-30 ms for the first
/// cut of a simulation built afresh, AMD EPYC Zen 4.)
fn deserialize_with_room<'de, D: serde::Deserializer<'de>>(deserializer: D) -> Result<PolyMesh, D::Error> {
    let mut mesh = <PolyMesh as serde::Deserialize>::deserialize(deserializer)?;
    with_room_for_cuts(&mut mesh);
    Ok(mesh)
}

/// The rest positions of the blocks: the mesh nodes, or the coefficients
/// of the identity map.
fn rest<'a>(mesh: &'a PolyMesh, elements: &'a Model) -> &'a [[f64; 3]] {
    match elements {
        Model::Nodal(_) => &mesh.nodes,
        Model::Dg(d) => d.rest(),
    }
}

impl Simulation {
    /// Checks the parameters, validates `mesh`, builds the element store
    /// and the sparse pattern (for the discontinuous Galerkin family, the
    /// interior penalty is checked at the first step, static solve or cut:
    /// see [`Simulation::stabilise`]).
    pub fn new(mut mesh: PolyMesh, params: SimulationParams) -> Result<Self, Error> {
        params.check()?;
        mesh.validate()?;
        with_room_for_cuts(&mut mesh);
        let mut timings = PhaseTimings::default();
        let store = timings.time(Phase::Basis, || ElementStore::build(&mesh, &params.material, &params.basis))?;
        let density = params.material.density;
        let (elements, pattern, masses, loads) = if params.basis.family == Family::Dg {
            let dg = timings.time(Phase::Basis, || DgElements::new(&mesh, store, params.basis.dg, &[]));
            let pattern = timings.time(Phase::Assembly, || SparsePattern::build(dg.num_blocks(), &dg));
            let (masses, loads) = (dg.masses(density), dg.loads(density));
            (Model::Dg(Box::new(dg)), pattern, masses, loads)
        } else {
            let pattern = timings.time(Phase::Assembly, || SparsePattern::build(mesh.nodes.len(), &store));
            let masses = nodal_masses(&store, &pattern, density);
            let corotation = Corotation::new(&store);
            (Model::Nodal(NodalElements { store, corotation }), pattern, masses.clone(), masses)
        };
        let system = StepSystem::new(params.solver, &pattern, params.tolerance, params.max_iterations);
        let state = NodeState::at_rest(rest(&mesh, &elements));
        let part_floor = params.min_part * mesh.median_element_diameter();
        let mut sim = Simulation {
            mesh,
            params,
            elements,
            pattern,
            masses,
            loads,
            boundary: Boundary::default(),
            body_loads: Vec::new(),
            state,
            nodes: NodeView::default(),
            contacts: None,
            embedded: None,
            surface: std::sync::OnceLock::new(),
            system,
            statics: None,
            steps: 0,
            part_floor,
            cut_retries: 0,
            solver_fell_back: false,
            auto_cg_iterations: 0.0,
            node_diameters: None,
            faces_integrated: 0,
            refine_levels: Vec::new(),
            timings,
        };
        sim.refresh_dg()?;
        Ok(sim)
    }

    /// For the discontinuous Galerkin family, after the elements or the
    /// fixed regions changed: face terms, pattern, masses, node and
    /// collision maps and the system. The penalty is checked later, once,
    /// by [`Simulation::stabilise`]: a body built and then fixed in several
    /// regions factors its system once, not once per call.
    fn refresh_dg(&mut self) -> Result<(), Error> {
        let Model::Dg(dg) = &mut self.elements else {
            return Ok(());
        };
        dg.refresh(&self.mesh, &self.boundary.fixed);
        self.pattern = SparsePattern::build(dg.num_blocks(), &**dg);
        self.refresh_dg_dependents()
    }

    /// For the discontinuous Galerkin family with interior penalty: doubles
    /// the penalty until the rest system is positive definite, if the face
    /// terms were rebuilt whole since it was last checked (see
    /// [`DgElements::stabilise`]; one factorisation of the system, and one
    /// more per doubling). The step, the static solve and the cuts do this
    /// first; until then, [`Simulation::dg`]'s penalty and the energies and
    /// forces of the face terms are those of the penalty last checked (the
    /// options' at first).
    pub fn stabilise(&mut self) -> Result<(), SolveError> {
        let Model::Dg(dg) = &mut self.elements else {
            return Ok(());
        };
        if dg.is_stable() {
            return Ok(());
        }
        let t = std::time::Instant::now();
        dg.stabilise(&self.mesh, &self.boundary.fixed, &self.pattern)?;
        self.timings.add(Phase::Solve, t.elapsed().as_secs_f64());
        Ok(())
    }

    /// For the discontinuous Galerkin family, after its elements, face
    /// terms and pattern changed: masses and loads, the stitch and
    /// collision maps, the step's system, the body loads and the embedding.
    fn refresh_dg_dependents(&mut self) -> Result<(), Error> {
        let (Model::Dg(dg), mesh) = (&self.elements, &self.mesh) else {
            return Ok(());
        };
        let density = self.params.material.density;
        (self.masses, self.loads) = (dg.masses(density), dg.loads(density));
        self.nodes.map = dg.node_map(mesh);
        self.contacts = Some(dg.contact_points(mesh));
        self.nodes.refresh(&self.state);
        let p = &self.params;
        self.system = StepSystem::new(self.solver_kind(), &self.pattern, p.tolerance, p.max_iterations);
        self.statics = None;
        self.refresh_body_loads();
        self.refresh_embedding()
    }

    /// Embeds a surface (rest coordinates) in the body: it moves with the
    /// body by the shape functions of the elements holding its vertices
    /// (martin2008 §7), or for discontinuous Galerkin by moving least
    /// squares over the stitched nodes (kaufmann2008 §8; see
    /// [`embedding`]); the colliders act on its vertices instead of the
    /// nodes (kaufmann2008 §9), each with the collider's full stiffness,
    /// their forces and stiffness spread by the same weights. A vertex in no
    /// element (or out of reach of the nodes) is an error naming it.
    pub fn embed(&mut self, surface: EmbeddedSurface) -> Result<(), Error> {
        if let Some((i, v)) = surface.vertices.iter().enumerate().find(|(_, v)| !v.iter().all(|x| x.is_finite())) {
            return Err(ParamError::new("embedded vertex", format!("{i} at {v:?}"), "must be finite (m)").into());
        }
        let n = surface.vertices.len();
        if let Some(t) = surface.triangles.iter().find(|t| t.iter().any(|&v| v as usize >= n)) {
            return Err(ParamError::new("embedded triangle", t, format!("must index the {n} vertices")).into());
        }
        self.embedded = Some((surface, PointMap::default()));
        self.refresh_embedding()
    }

    /// Recomputes the embedded surface's map from the blocks (after a
    /// topology change) and makes its vertices the collision points.
    fn refresh_embedding(&mut self) -> Result<(), Error> {
        let Some((surface, _)) = self.embedded.take() else {
            return Ok(());
        };
        let map = match &self.elements {
            Model::Nodal(nodal) => {
                let harmonic = &self.params.basis.harmonic;
                embedding::basis_map(&self.mesh, &nodal.store, harmonic, &surface.vertices)?
                    .ok_or_else(|| Error::Internal("a nodal store without nodal shape functions".into()))?
            }
            Model::Dg(_) => embedding::compose(&embedding::mls_map(&self.mesh, &surface.vertices)?, &self.nodes.map),
        };
        self.contacts = Some((map.clone(), vec![1.0; surface.vertices.len()]));
        self.embedded = Some((surface, map));
        Ok(())
    }

    /// The embedded surface at the current positions, if one is embedded:
    /// its vertices (m) over the triangles it was given.
    pub fn embedded_surface(&self) -> Option<EmbeddedSurface> {
        let (surface, map) = self.embedded.as_ref()?;
        let mut vertices = Vec::new();
        map.apply(&self.state.position, &mut vertices);
        Some(EmbeddedSurface { vertices, triangles: surface.triangles.clone() })
    }

    /// The velocities of the embedded surface's vertices (m/s), if one is
    /// embedded.
    pub fn embedded_velocities(&self) -> Option<Vec<[f64; 3]>> {
        let (_, map) = self.embedded.as_ref()?;
        let mut v = Vec::new();
        map.apply(&self.state.velocity, &mut v);
        Some(v)
    }

    /// The embedded surface at rest, as it was given, if one is embedded.
    pub fn embedded_rest(&self) -> Option<&EmbeddedSurface> {
        self.embedded.as_ref().map(|(surface, _)| surface)
    }

    /// Adds a Dirichlet region (checked, see [`FixedRegion::check`]): the
    /// nodes inside it are held (nodal families), or the boundary faces
    /// whose vertices all lie inside it are held weakly (discontinuous
    /// Galerkin).
    pub fn fix(&mut self, region: FixedRegion) -> Result<(), Error> {
        region.check()?;
        self.boundary.fixed.push(region);
        self.refresh_dg()
    }

    /// Holds node `node` at displacement `u` (m), overriding fixed regions;
    /// pinning again moves it. Nodal families only: the discontinuous
    /// Galerkin family holds boundary faces, through fixed regions.
    pub fn pin(&mut self, node: usize, u: [f64; 3]) -> Result<(), Error> {
        let n = self.mesh.nodes.len();
        if self.elements.dg().is_some() {
            let allowed = "pins hold nodes of the nodal families; with family = dg use a fixed region";
            return Err(ParamError::new("node", node, allowed).into());
        }
        if node >= n {
            return Err(ParamError::new("node", node, format!("must name one of the mesh's {n} nodes")).into());
        }
        crate::param::finite("displacement", u, "must be finite (m)")?;
        self.boundary.pinned.insert(node as u32, u);
        Ok(())
    }

    /// Releases a pinned node (no effect if it was not pinned).
    pub fn unpin(&mut self, node: usize) {
        self.boundary.pinned.remove(&(node as u32));
    }

    /// Adds a penalty collision plane (checked by [`Collider::new`]).
    pub fn add_collider(&mut self, collider: Collider) {
        self.boundary.colliders.push(collider);
    }

    /// Checks that `values` holds one finite 3-vector per node.
    fn check_per_node(&self, name: &'static str, values: &[[f64; 3]]) -> Result<(), ParamError> {
        let n = self.mesh.nodes.len();
        if values.len() != n {
            return Err(ParamError::new(name, values.len(), format!("needs one value per node ({n})")));
        }
        match values.iter().position(|v| !v.iter().all(|x| x.is_finite())) {
            Some(i) => Err(ParamError::new(name, values[i], format!("must be finite (node {i})"))),
            None => Ok(()),
        }
    }

    /// Per-block values of per-node `values`: themselves (nodal), or each
    /// element's affine least-squares fit to its vertices (DG).
    fn blocks_of(&self, values: &[[f64; 3]]) -> Vec<[f64; 3]> {
        match &self.elements {
            Model::Nodal(_) => values.to_vec(),
            Model::Dg(d) => d.fit_affine(&self.mesh, values),
        }
    }

    /// Sets the velocities (m/s) from one per node, e.g. an initial spin
    /// (for DG, each element takes the affine field that fits its vertices
    /// best, exact for affine fields).
    pub fn set_velocities(&mut self, v: &[[f64; 3]]) -> Result<(), Error> {
        self.check_per_node("velocity", v)?;
        let blocks = self.blocks_of(v);
        self.state.velocity.copy_from_slice(&blocks);
        self.state.previous_velocity.copy_from_slice(&blocks);
        self.nodes.refresh(&self.state);
        Ok(())
    }

    /// Sets the displacements (m) from one per node, e.g. a rigidly rotated
    /// start (for DG as [`Simulation::set_velocities`]).
    pub fn set_displacements(&mut self, u: &[[f64; 3]]) -> Result<(), Error> {
        self.check_per_node("displacement", u)?;
        let blocks = self.blocks_of(u);
        self.state.displacement.copy_from_slice(&blocks);
        self.state.refresh_positions(rest(&self.mesh, &self.elements));
        self.nodes.refresh(&self.state);
        Ok(())
    }

    /// Drops what the step's solver carries from one step to the next: its
    /// analysis of the pattern (a CG ordering extends the last one after a
    /// cut), CG's past corrections and lagged coarse level, a factor. The
    /// next step then depends on nothing that serialization does not keep,
    /// exactly as after deserialization, at the price of a fresh analysis.
    /// [`crate::scene::Run`] calls it whenever it writes a checkpoint, so
    /// that a resumed run takes the same steps, bit for bit, as the run
    /// that went on.
    pub fn drop_solver_state(&mut self) {
        self.system = StepSystem::default();
        self.statics = None;
    }

    /// The parameters.
    pub fn params(&self) -> &SimulationParams {
        &self.params
    }

    /// The mesh (rest configuration).
    pub fn mesh(&self) -> &PolyMesh {
        &self.mesh
    }

    /// The sparsity pattern of the system matrix (this topology's).
    pub fn pattern(&self) -> &SparsePattern {
        &self.pattern
    }

    /// The element store.
    pub fn store(&self) -> &ElementStore {
        self.elements.store()
    }

    /// The corotation state (rotations of the last step, per element).
    pub fn corotation(&self) -> &Corotation {
        self.elements.corotation()
    }

    /// The discontinuous Galerkin discretisation, when the family is DG
    /// (its faces, penalty and bases).
    pub fn dg(&self) -> Option<&DgElements> {
        self.elements.dg()
    }

    /// Whether per-node fields are the blocks themselves.
    fn nodal(&self) -> bool {
        matches!(self.elements, Model::Nodal(_))
    }

    /// Nodal displacements (m).
    pub fn displacements(&self) -> &[[f64; 3]] {
        if self.nodal() {
            &self.state.displacement
        } else {
            &self.nodes.displacement
        }
    }

    /// Nodal displacements as a flat slice `[u0x, u0y, u0z, u1x, ...]` (m).
    pub fn displacements_flat(&self) -> &[f64] {
        bytemuck::cast_slice(self.displacements())
    }

    /// Nodal velocities (m/s).
    pub fn velocities(&self) -> &[[f64; 3]] {
        if self.nodal() {
            &self.state.velocity
        } else {
            &self.nodes.velocity
        }
    }

    /// Current node positions `x0 + u` (m).
    pub fn positions(&self) -> &[[f64; 3]] {
        if self.nodal() {
            &self.state.position
        } else {
            &self.nodes.position
        }
    }

    /// Current node positions as a flat slice `[x0, y0, z0, x1, ...]` (m),
    /// ready for a renderer's vertex buffer.
    pub fn positions_flat(&self) -> &[f64] {
        bytemuck::cast_slice(self.positions())
    }

    /// The state of the unknown blocks: positions, displacements and
    /// velocities (the nodes' for the nodal families, the coefficients'
    /// for DG).
    pub fn block_positions(&self) -> &[[f64; 3]] {
        &self.state.position
    }

    /// The block displacements (see [`Simulation::block_positions`]).
    pub fn block_displacements(&self) -> &[[f64; 3]] {
        &self.state.displacement
    }

    /// The block velocities (see [`Simulation::block_positions`]).
    pub fn block_velocities(&self) -> &[[f64; 3]] {
        &self.state.velocity
    }

    /// The boundary surface: outward triangles over node ids (index into
    /// [`Simulation::positions`]), built on the first call after a
    /// topology change.
    pub fn boundary_triangles(&self) -> &[[u32; 3]] {
        self.surface.get_or_init(|| self.mesh.boundary_triangles())
    }

    /// The plane colliders, in the order they were added.
    pub fn colliders(&self) -> &[Collider] {
        &self.boundary.colliders
    }

    /// Masses per unknown block (kg): lumped nodal masses, or for DG the
    /// exact masses `ρ V` of each element's orthonormal functions.
    pub fn masses(&self) -> &[f64] {
        &self.masses
    }

    /// The gravity weights per block (kg): `ρ ∫ N_a`, the masses for the
    /// nodal families; summed, the body's mass.
    pub fn loads(&self) -> &[f64] {
        &self.loads
    }

    /// Steps taken so far.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// How many times a cut was run again with one more element kept
    /// whole, because the element store found a part it made unhealthy.
    pub fn cut_retries(&self) -> usize {
        self.cut_retries
    }

    /// The solver the steps use: the parameters' [`SolverKind`], or
    /// [`SolverKind::Cholesky`] once [`SolverKind::Auto`]'s CG has gone
    /// past its budget ([`crate::solve::auto_cg_budget`]).
    pub fn solver_kind(&self) -> SolverKind {
        if self.solver_fell_back {
            SolverKind::Cholesky
        } else {
            self.params.solver
        }
    }

    /// How many faces the cuts of a DG body integrated again (the others
    /// kept their moments).
    pub fn faces_integrated(&self) -> usize {
        self.faces_integrated
    }

    /// Simulated time (s).
    pub fn time(&self) -> f64 {
        self.steps as f64 * self.params.dt
    }

    /// Wall time spent per phase so far.
    pub fn timings(&self) -> &PhaseTimings {
        &self.timings
    }

    /// Adds output time measured by the caller.
    pub fn record_output_time(&mut self, seconds: f64) {
        self.timings.add(Phase::Output, seconds);
    }
}
