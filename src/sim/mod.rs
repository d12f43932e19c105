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

mod boundary;
mod corotation;
mod diagnostics;
mod discretization;
mod params;
mod rebuild;
mod state;
mod statics;
mod step;
mod timings;

pub use boundary::{Collider, FixedRegion};
pub use corotation::Corotation;
pub use diagnostics::Located;
pub use discretization::{Discretization, NodalElements};
pub use params::{SimulationParams, CUT_ATTEMPTS};
pub use step::StepStats;
pub use timings::{Phase, PhaseTimings};

use boundary::Boundary;
use state::NodeState;
use statics::StaticSystem;
use step::StepSystem;

use crate::assembly::SparsePattern;
use crate::mesh::PolyMesh;
use crate::param::ParamError;
use crate::store::ElementStore;
use crate::Error;

/// One elastic body: its mesh, element data, state, boundary conditions
/// and the systems of its steps and static solves.
///
/// The work is split by concern: the step's phases in `step.rs`, the
/// static solve in `statics.rs`, topology changes in `rebuild.rs`,
/// read-back figures in `diagnostics.rs`; the elements are reached through
/// [`Discretization`].
pub struct Simulation {
    /// The mesh in its rest configuration.
    mesh: PolyMesh,
    params: SimulationParams,
    /// Element data and per-element state.
    elements: NodalElements,
    /// The global sparse structure of this topology.
    pattern: SparsePattern,
    /// Lumped nodal masses (kg).
    masses: Vec<f64>,
    boundary: Boundary,
    state: NodeState,
    /// Outward triangles of the boundary surface (node ids), per topology.
    surface: Vec<[u32; 3]>,
    /// The step's system, solver and buffers.
    system: StepSystem,
    /// The static problem's solver, made on first use.
    statics: Option<StaticSystem>,
    steps: usize,
    /// Cuts run again with one more element kept whole (see
    /// [`CUT_ATTEMPTS`]).
    cut_retries: usize,
    timings: PhaseTimings,
}

impl Simulation {
    /// Checks the parameters, validates `mesh`, builds the element store
    /// and the sparse pattern.
    pub fn new(mesh: PolyMesh, params: SimulationParams) -> Result<Self, Error> {
        params.check()?;
        mesh.validate()?;
        let mut timings = PhaseTimings::default();
        let store = timings.time(Phase::Basis, || ElementStore::build(&mesh, &params.material, &params.basis))?;
        let pattern = timings.time(Phase::Assembly, || SparsePattern::build(mesh.nodes.len(), &store));
        let masses = store.lumped_masses(mesh.nodes.len(), params.material.density);
        let corotation = Corotation::new(&store);
        let system = StepSystem::new(params.solver, &pattern, params.tolerance, params.max_iterations);
        let (state, surface) = (NodeState::at_rest(&mesh.nodes), mesh.boundary_triangles());
        Ok(Simulation {
            mesh,
            params,
            elements: NodalElements { store, corotation },
            pattern,
            masses,
            boundary: Boundary::default(),
            state,
            surface,
            system,
            statics: None,
            steps: 0,
            cut_retries: 0,
            timings,
        })
    }

    /// Adds a Dirichlet region (checked, see [`FixedRegion::check`]).
    pub fn fix(&mut self, region: FixedRegion) -> Result<(), Error> {
        region.check()?;
        self.boundary.fixed.push(region);
        Ok(())
    }

    /// Holds node `node` at displacement `u` (m), overriding fixed regions;
    /// pinning again moves it.
    pub fn pin(&mut self, node: usize, u: [f64; 3]) -> Result<(), Error> {
        let n = self.mesh.nodes.len();
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

    /// Sets nodal velocities (m/s), e.g. an initial spin.
    pub fn set_velocities(&mut self, v: &[[f64; 3]]) -> Result<(), Error> {
        self.check_per_node("velocity", v)?;
        self.state.velocity.copy_from_slice(v);
        self.state.previous_velocity.copy_from_slice(v);
        Ok(())
    }

    /// Sets nodal displacements (m), e.g. a rigidly rotated start.
    pub fn set_displacements(&mut self, u: &[[f64; 3]]) -> Result<(), Error> {
        self.check_per_node("displacement", u)?;
        self.state.displacement.copy_from_slice(u);
        self.state.refresh_positions(&self.mesh.nodes);
        Ok(())
    }

    /// The parameters.
    pub fn params(&self) -> &SimulationParams {
        &self.params
    }

    /// The mesh (rest configuration).
    pub fn mesh(&self) -> &PolyMesh {
        &self.mesh
    }

    /// The element store.
    pub fn store(&self) -> &ElementStore {
        &self.elements.store
    }

    /// The corotation state (rotations of the last step, per element).
    pub fn corotation(&self) -> &Corotation {
        &self.elements.corotation
    }

    /// Nodal displacements (m).
    pub fn displacements(&self) -> &[[f64; 3]] {
        &self.state.displacement
    }

    /// Nodal displacements as a flat slice `[u0x, u0y, u0z, u1x, ...]` (m).
    pub fn displacements_flat(&self) -> &[f64] {
        bytemuck::cast_slice(&self.state.displacement)
    }

    /// Nodal velocities (m/s).
    pub fn velocities(&self) -> &[[f64; 3]] {
        &self.state.velocity
    }

    /// Current node positions `x0 + u` (m).
    pub fn positions(&self) -> &[[f64; 3]] {
        &self.state.position
    }

    /// Current node positions as a flat slice `[x0, y0, z0, x1, ...]` (m),
    /// ready for a renderer's vertex buffer.
    pub fn positions_flat(&self) -> &[f64] {
        bytemuck::cast_slice(&self.state.position)
    }

    /// The boundary surface: outward triangles over node ids (index into
    /// [`Simulation::positions`]), rebuilt when the topology changes.
    pub fn boundary_triangles(&self) -> &[[u32; 3]] {
        &self.surface
    }

    /// Lumped nodal masses (kg).
    pub fn masses(&self) -> &[f64] {
        &self.masses
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
