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

mod corotation;
mod health;
mod timings;

pub use corotation::Corotation;
pub use health::Located;
pub use timings::{Phase, PhaseTimings};

use cleave_kernels::elasticity::{stress, von_mises};

use crate::assembly::{Constraints, SparsePattern};
use crate::material::Material;
use crate::mesh::{PolyMesh, ValidationOptions};
use crate::solve::{make_solver, solve_checked, LinearSolver, SolveStats, SolverKind};
use crate::store::{BasisOptions, ElementStore};
use crate::topology::{
    conserve_momentum, cut_by_plane_keeping, cut_by_polygon_keeping, momenta, polygon_plane, CutReport, NodeOrigins,
    Plane, PolygonCutReport, Rollback, SplitOptions,
};
use crate::Error;

/// How many times a cut is tried, each time keeping whole one more element
/// whose parts the element store found unhealthy.
pub const CUT_ATTEMPTS: usize = 16;

/// Physical and numerical parameters of a simulation.
#[derive(Clone, Debug, PartialEq)]
pub struct SimulationParams {
    /// The material of every element.
    pub material: Material,
    /// Gravitational acceleration (m/s^2).
    pub gravity: [f64; 3],
    /// Basis construction options (quadrature of mean value elements).
    pub basis: BasisOptions,
    /// Time step (s).
    pub dt: f64,
    /// Rayleigh damping `D = mass_damping M + stiffness_damping K`
    /// (1/s and s).
    pub mass_damping: f64,
    /// See `mass_damping`.
    pub stiffness_damping: f64,
    /// Stiffness warping (corotated elasticity); `false` is plain linear
    /// elasticity, which shows ghost forces under rotation.
    pub corotated: bool,
    /// The linear solver of a step.
    pub solver: SolverKind,
    /// Relative residual of the iterative solver.
    pub tolerance: f64,
    /// Iteration cap of the iterative solver.
    pub max_iterations: usize,
    /// How cuts split elements: snapping and the health of the parts.
    pub cut: SplitOptions,
}

impl Default for SimulationParams {
    fn default() -> Self {
        SimulationParams {
            material: Material { young: 1e5, poisson: 0.3, density: 1000.0 },
            gravity: [0.0, 0.0, -9.81],
            basis: BasisOptions::default(),
            dt: 0.01,
            mass_damping: 0.0,
            stiffness_damping: 0.0,
            corotated: true,
            solver: SolverKind::Auto,
            tolerance: 1e-8,
            max_iterations: 2000,
            cut: SplitOptions::default(),
        }
    }
}

/// Nodes inside an axis-aligned box held at `u(x) = displacement + gradient x`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FixedRegion {
    /// Box corner (m).
    pub min: [f64; 3],
    /// Box corner (m).
    pub max: [f64; 3],
    /// Constant part of the prescribed displacement (m).
    pub displacement: [f64; 3],
    /// Linear part: `u_i += Σ_j gradient[i][j] x_j` at rest position `x`.
    pub gradient: [[f64; 3]; 3],
}

impl FixedRegion {
    /// Nodes in the box held at rest.
    pub fn clamp(min: [f64; 3], max: [f64; 3]) -> Self {
        FixedRegion { min, max, displacement: [0.0; 3], gradient: [[0.0; 3]; 3] }
    }

    /// Whether rest position `x` lies in the box (boundary included).
    pub fn contains(&self, x: [f64; 3]) -> bool {
        (0..3).all(|i| x[i] >= self.min[i] && x[i] <= self.max[i])
    }

    /// Prescribed displacement at rest position `x` (m).
    pub fn value(&self, x: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| self.displacement[i] + (0..3).map(|j| self.gradient[i][j] * x[j]).sum::<f64>())
    }
}

/// A penalty collision plane: nodes behind it are pushed out with force
/// `stiffness · depth` along its normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Collider {
    /// A point on the plane (m).
    pub point: [f64; 3],
    /// Unit normal, pointing into the free half-space.
    pub normal: [f64; 3],
    /// Penalty stiffness (N/m).
    pub stiffness: f64,
}

impl Collider {
    /// A plane collider; the normal is normalised, values are checked.
    pub fn new(point: [f64; 3], normal: [f64; 3], stiffness: f64) -> Result<Self, Error> {
        let len = (normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2]).sqrt();
        if !(len > 0.0) || !len.is_finite() || !point.iter().all(|v| v.is_finite()) || !(stiffness >= 0.0) {
            return Err(Error::Parameter(format!(
                "collider plane needs a finite point, a non-zero normal and stiffness >= 0 (got {point:?}, {normal:?}, {stiffness})"
            )));
        }
        Ok(Collider { point, normal: normal.map(|x| x / len), stiffness })
    }

    /// Penetration depth of position `x` (m, positive behind the plane).
    pub fn depth(&self, x: [f64; 3]) -> f64 {
        (0..3).map(|i| (self.point[i] - x[i]) * self.normal[i]).sum()
    }
}

/// What one time step did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepStats {
    /// The linear solve.
    pub solve: SolveStats,
    /// Largest number of rotation iterations of an element group.
    pub rotation_iterations: usize,
    /// Nodes in contact with a collider.
    pub contacts: usize,
}

/// One elastic body: mesh, element data, state and solver.
pub struct Simulation {
    mesh: PolyMesh,
    params: SimulationParams,
    store: ElementStore,
    pattern: SparsePattern,
    masses: Vec<f64>,
    fixed: Vec<FixedRegion>,
    pinned: std::collections::BTreeMap<u32, [f64; 3]>,
    colliders: Vec<Collider>,
    displacement: Vec<[f64; 3]>,
    /// Current positions `x0 + u` (m), kept in step with `displacement`.
    position: Vec<[f64; 3]>,
    /// Outward triangles of the boundary surface (node ids), per topology.
    boundary: Vec<[u32; 3]>,
    velocity: Vec<[f64; 3]>,
    /// Velocity of the step before (for the warm start of iterative solves).
    previous_velocity: Vec<[f64; 3]>,
    corotation: Corotation,
    solver: Box<dyn LinearSolver>,
    analysed: bool,
    /// Whether the solver holds the rest-state reference of this topology.
    referenced: bool,
    values: Vec<f64>,
    steps: usize,
    /// Cuts run again with one more element kept whole (see
    /// [`CUT_ATTEMPTS`]).
    cut_retries: usize,
    timings: PhaseTimings,
}

impl Simulation {
    /// Validates `mesh` and the parameters, builds the element store and the
    /// sparse pattern.
    pub fn new(mesh: PolyMesh, params: SimulationParams) -> Result<Self, Error> {
        Material::new(params.material.young, params.material.poisson, params.material.density)?;
        if !params.gravity.iter().all(|g| g.is_finite()) {
            return Err(Error::Parameter(format!("gravity {:?} must be finite", params.gravity)));
        }
        if !(params.dt > 0.0 && params.dt.is_finite()) {
            return Err(Error::Parameter(format!("time step {} must be a finite number > 0 (s)", params.dt)));
        }
        let (a, b) = (params.mass_damping, params.stiffness_damping);
        if !(a >= 0.0 && b >= 0.0 && (a + b).is_finite()) {
            return Err(Error::Parameter("Rayleigh damping coefficients must be finite and >= 0".into()));
        }
        if !(params.tolerance > 0.0 && params.tolerance < 1.0) {
            return Err(Error::Parameter(format!("solver tolerance {} must lie in (0, 1)", params.tolerance)));
        }
        mesh.validate()?;
        let mut timings = PhaseTimings::default();
        let store = timings.time(Phase::Basis, || ElementStore::build(&mesh, &params.material, &params.basis))?;
        let pattern = timings.time(Phase::Assembly, || SparsePattern::build(mesh.nodes.len(), &store));
        let masses = store.lumped_masses(mesh.nodes.len(), params.material.density);
        let n = mesh.nodes.len();
        let corotation = Corotation::new(&store);
        let solver = make_solver(params.solver, 3 * n, params.tolerance, params.max_iterations);
        let values = vec![0.0; pattern.nnz()];
        let (position, boundary) = (mesh.nodes.clone(), mesh.boundary_triangles());
        Ok(Simulation {
            mesh,
            params,
            store,
            pattern,
            masses,
            fixed: Vec::new(),
            pinned: Default::default(),
            colliders: Vec::new(),
            displacement: vec![[0.0; 3]; n],
            position,
            boundary,
            velocity: vec![[0.0; 3]; n],
            previous_velocity: vec![[0.0; 3]; n],
            corotation,
            solver,
            analysed: false,
            referenced: false,
            values,
            steps: 0,
            cut_retries: 0,
            timings,
        })
    }

    /// Adds a Dirichlet region (checked for finite values).
    pub fn fix(&mut self, region: FixedRegion) -> Result<(), Error> {
        let finite = region.min.iter().chain(&region.max).chain(&region.displacement).all(|v| v.is_finite())
            && region.gradient.iter().flatten().all(|v| v.is_finite());
        if !finite {
            return Err(Error::Parameter(format!("fixed region {region:?} has a non-finite value")));
        }
        self.fixed.push(region);
        Ok(())
    }

    /// Holds node `node` at displacement `u` (m), overriding fixed regions;
    /// pinning again moves it.
    pub fn pin(&mut self, node: usize, u: [f64; 3]) -> Result<(), Error> {
        if node >= self.mesh.nodes.len() {
            return Err(Error::Parameter(format!(
                "cannot pin node {node}: the mesh has {} nodes",
                self.mesh.nodes.len()
            )));
        }
        if !u.iter().all(|v| v.is_finite()) {
            return Err(Error::Parameter(format!("cannot pin node {node} at non-finite displacement {u:?}")));
        }
        self.pinned.insert(node as u32, u);
        Ok(())
    }

    /// Releases a pinned node (no effect if it was not pinned).
    pub fn unpin(&mut self, node: usize) {
        self.pinned.remove(&(node as u32));
    }

    /// Adds a penalty collision plane.
    pub fn add_collider(&mut self, collider: Collider) {
        self.colliders.push(collider);
    }

    /// Sets nodal velocities (m/s), e.g. an initial spin.
    pub fn set_velocities(&mut self, v: &[[f64; 3]]) -> Result<(), Error> {
        if v.len() != self.velocity.len() || !v.iter().flatten().all(|x| x.is_finite()) {
            return Err(Error::Parameter(format!("need {} finite velocities", self.velocity.len())));
        }
        self.velocity.copy_from_slice(v);
        self.previous_velocity.copy_from_slice(v);
        Ok(())
    }

    /// Sets nodal displacements (m), e.g. a rigidly rotated start.
    pub fn set_displacements(&mut self, u: &[[f64; 3]]) -> Result<(), Error> {
        if u.len() != self.displacement.len() || !u.iter().flatten().all(|x| x.is_finite()) {
            return Err(Error::Parameter(format!("need {} finite displacements", self.displacement.len())));
        }
        self.displacement.copy_from_slice(u);
        self.refresh_positions();
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
        &self.store
    }

    /// Nodal displacements (m).
    pub fn displacements(&self) -> &[[f64; 3]] {
        &self.displacement
    }

    /// Nodal displacements as a flat slice `[u0x, u0y, u0z, u1x, ...]` (m).
    pub fn displacements_flat(&self) -> &[f64] {
        bytemuck::cast_slice(&self.displacement)
    }

    /// Nodal velocities (m/s).
    pub fn velocities(&self) -> &[[f64; 3]] {
        &self.velocity
    }

    /// Current node positions `x0 + u` (m).
    pub fn positions(&self) -> &[[f64; 3]] {
        &self.position
    }

    /// Current node positions as a flat slice `[x0, y0, z0, x1, ...]` (m),
    /// ready for a renderer's vertex buffer.
    pub fn positions_flat(&self) -> &[f64] {
        bytemuck::cast_slice(&self.position)
    }

    /// The boundary surface: outward triangles over node ids (index into
    /// [`Simulation::positions`]), rebuilt when the topology changes.
    pub fn boundary_triangles(&self) -> &[[u32; 3]] {
        &self.boundary
    }

    /// Recomputes the positions from the rest positions and displacements.
    fn refresh_positions(&mut self) {
        self.position.clear();
        self.position.extend(
            self.mesh.nodes.iter().zip(&self.displacement).map(|(x, u)| [x[0] + u[0], x[1] + u[1], x[2] + u[2]]),
        );
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

    /// Von Mises stress of every element (Pa): of the corotated mean strain
    /// `sym(Rᵀ F) - I`, with each element's rotation extracted at the
    /// current positions (the identity when not corotated).
    pub fn von_mises(&self) -> Vec<f64> {
        let (l, m) = self.params.material.lame();
        let x = &self.position;
        let mut out = vec![0.0; self.mesh.elements.len()];
        for (bi, b) in self.store.batches.iter().enumerate() {
            for i in 0..b.len() {
                let r = self.corotation.rotation_at(&self.store, bi, i, x, self.params.corotated);
                let f = b.field_gradient(i, x);
                // Rᵀ F - I
                let g: [[f64; 3]; 3] = std::array::from_fn(|p| {
                    std::array::from_fn(|q| r[p] * f[q] + r[3 + p] * f[3 + q] + r[6 + p] * f[6 + q] - f64::from(p == q))
                });
                out[b.elements[i] as usize] = von_mises(stress(g, l, m));
            }
        }
        out
    }

    /// Elastic energy (J) at the current positions, with each element's
    /// rotation extracted there (the identity when not corotated).
    pub fn elastic_energy(&self) -> f64 {
        self.corotation.energy(&self.store, &self.position, self.params.corotated)
    }

    /// Kinetic energy `½ Σ m_i |v_i|²` (J).
    pub fn kinetic_energy(&self) -> f64 {
        self.masses.iter().zip(&self.velocity).map(|(m, v)| 0.5 * m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])).sum()
    }

    /// Linear momentum `Σ m_i v_i` (kg m/s).
    pub fn linear_momentum(&self) -> [f64; 3] {
        let mut p = [0.0; 3];
        for (m, v) in self.masses.iter().zip(&self.velocity) {
            (0..3).for_each(|i| p[i] += m * v[i]);
        }
        p
    }

    /// Angular momentum `Σ m_i x_i × v_i` about the origin (kg m²/s).
    pub fn angular_momentum(&self) -> [f64; 3] {
        let mut l = [0.0; 3];
        for ((m, x), v) in self.masses.iter().zip(&self.position).zip(&self.velocity) {
            let c = cleave_kernels::vec3::cross(*x, *v);
            (0..3).for_each(|i| l[i] += m * c[i]);
        }
        l
    }

    /// Elastic forces on every node at the current positions (N), with
    /// rotations updated (or the identity when not corotated).
    pub fn elastic_forces(&mut self) -> Vec<[f64; 3]> {
        let x = self.position.clone();
        self.corotation.update(&self.store, &x, self.params.corotated);
        let mut f = vec![[0.0; 3]; x.len()];
        let (store, corotation) = (&self.store, &self.corotation);
        self.pattern.gather(&mut f, |b, i, a| corotation.force(store, b, i, a));
        f
    }

    /// Cuts the body along a whole plane given in the rest (material)
    /// frame: elements the plane crosses are split into convex parts, and
    /// the two sides separate (wicke2007 §5). New nodes on edges take the
    /// state interpolated along their edge, duplicated nodes the state of
    /// their original; only the touched elements' data and the pattern's
    /// columns of their nodes are rebuilt. On error the simulation is left
    /// unchanged.
    pub fn cut_plane(&mut self, plane: &Plane) -> Result<CutReport, Error> {
        let opts = self.params.cut;
        let cut = |mesh: &mut PolyMesh, keep: &[u32]| -> Result<PolygonCutReport, Error> {
            let cut = cut_by_plane_keeping(mesh, plane, &opts, keep)?;
            Ok(PolygonCutReport { cut, pocket: None })
        };
        self.cut(plane, cut).map(|report| report.cut)
    }

    /// Cuts the body with a convex planar polygon given in the rest frame
    /// (wicke2007 §5.2): the material opens only inside the polygon, with a
    /// pocket where no node lies inside it. A swept blade is a sequence of
    /// such cuts. State and rebuild as in [`Simulation::cut_plane`].
    pub fn cut_polygon(&mut self, polygon: &[[f64; 3]]) -> Result<PolygonCutReport, Error> {
        let plane = polygon_plane(polygon)?;
        let opts = self.params.cut;
        self.cut(&plane, |mesh, keep| Ok(cut_by_polygon_keeping(mesh, polygon, &opts, keep)?))
    }

    /// Runs `cut` (a cut along `plane`, leaving the elements it is given
    /// whole) on the mesh in place and brings everything else up to date.
    /// When the element store finds an element the cut made or changed
    /// unhealthy (see [`crate::store::HealthFloors`]), the cut is undone
    /// and run again with the element it came from kept whole, up to
    /// [`CUT_ATTEMPTS`] times; on any other error the mesh is rolled back.
    fn cut(
        &mut self,
        plane: &Plane,
        cut: impl Fn(&mut PolyMesh, &[u32]) -> Result<PolygonCutReport, Error>,
    ) -> Result<PolygonCutReport, Error> {
        let t = std::time::Instant::now();
        let rebuild = |t: &PhaseTimings| t.basis + t.assembly + t.solve;
        let before = rebuild(&self.timings);
        let mut keep_whole: Vec<u32> = Vec::new();
        let result = loop {
            let rollback = Rollback::around_plane(&self.mesh, plane);
            let (nodes_before, elements_before) = (self.mesh.nodes.len(), self.mesh.elements.len() as u32);
            let outcome = match cut(&mut self.mesh, &keep_whole) {
                Err(error) => Err((None, error)),
                Ok(report) => match self.apply_cut(&report, nodes_before) {
                    Ok(()) => Ok(report),
                    Err(error) => {
                        // an unhealthy element this cut touched comes from
                        // the element with its id, or (a negative part) from
                        // its positive part's
                        let parent = match &error {
                            Error::Basis(b) if report.cut.touched.binary_search(&(b.element() as u32)).is_ok() => {
                                let e = b.element() as u32;
                                let split = &report.cut.split.split_elements;
                                Some(if e < elements_before {
                                    e
                                } else {
                                    split.iter().find(|p| p.1 == e).map_or(e, |p| p.0)
                                })
                            }
                            _ => None,
                        };
                        Err((parent, error))
                    }
                },
            };
            match outcome {
                Ok(report) => break Ok(report),
                Err((Some(parent), _)) if keep_whole.len() + 1 < CUT_ATTEMPTS => {
                    rollback.restore(&mut self.mesh);
                    if let Err(at) = keep_whole.binary_search(&parent) {
                        keep_whole.insert(at, parent);
                    }
                    self.cut_retries += 1;
                }
                Err((_, error)) => {
                    rollback.restore(&mut self.mesh);
                    break Err(error);
                }
            }
        };
        // the new pattern's analysis (Cholesky ordering and symbolic
        // factorisation, or the block structure of CG) makes the system
        // ready; the cut itself stands even if that fails
        let result = result.and_then(|report| {
            self.ensure_analysed()?;
            Ok(report)
        });
        // rebuilding element data and pattern, and the analysis, are booked
        // under their own phases
        let topology = t.elapsed().as_secs_f64() - (rebuild(&self.timings) - before);
        self.timings.add(Phase::Topology, topology);
        result
    }

    /// Checks the touched elements of a cut mesh and rebuilds their data
    /// (the store checks their health), then carries the state over to the
    /// new nodes ([`NodeOrigins`]), updates the pattern's columns of their
    /// nodes and the masses, restores the momenta of the nodes whose masses
    /// changed, and brings the rotations (untouched elements keep theirs,
    /// new ones get theirs) and the solver up to date. Nothing but the mesh
    /// has changed when it fails.
    fn apply_cut(&mut self, report: &PolygonCutReport, nodes_before: usize) -> Result<(), Error> {
        let mesh = &self.mesh;
        let touched = &report.cut.touched;
        // only the touched elements changed (the two sides of a cut carry
        // coincident nodes by design, which a whole-mesh check would flag)
        let list: Vec<usize> = touched.iter().map(|&e| e as usize).collect();
        mesh.check_elements(&list, &ValidationOptions::default())?;
        let origins = NodeOrigins::of_polygon_cut(report, nodes_before)
            .map_err(|m| Error::Parameter(format!("internal: {m} after a cut")))?;
        if origins.len() != mesh.nodes.len() {
            let message = format!("internal: {} node states for {} nodes after a cut", origins.len(), mesh.nodes.len());
            return Err(Error::Parameter(message));
        }
        // the touched elements' nodes before the cut, then their new data
        let old_nodes = self.store.nodes_of(touched);
        let t = std::time::Instant::now();
        let changes = self.store.update(mesh, &self.params.material, &self.params.basis, touched)?;
        self.timings.add(Phase::Basis, t.elapsed().as_secs_f64());
        // the nodes whose mass changes: those of the touched elements,
        // before and after
        let mut changed_nodes = old_nodes.clone();
        changed_nodes.extend(self.store.nodes_of(touched));
        changed_nodes.sort_unstable();
        changed_nodes.dedup();
        let old_changed: Vec<u32> = changed_nodes.iter().copied().filter(|&v| (v as usize) < nodes_before).collect();
        let before = momenta(&old_changed, &self.masses, &self.position, &self.velocity);
        origins.extend(&mut self.displacement);
        origins.extend(&mut self.velocity);
        origins.extend(&mut self.previous_velocity);
        let t = std::time::Instant::now();
        self.pattern.update(self.mesh.nodes.len(), &self.store, touched, &old_nodes);
        self.timings.add(Phase::Assembly, t.elapsed().as_secs_f64());
        self.masses = self.store.lumped_masses(self.mesh.nodes.len(), self.params.material.density);
        self.refresh_positions();
        conserve_momentum(&changed_nodes, &self.masses, &self.position, &mut self.velocity, before);
        self.corotation.apply_changes(&self.store, &changes, &self.position, self.params.corotated);
        self.refresh_topology();
        Ok(())
    }

    /// After the mesh, element store, pattern, masses and rotations
    /// changed: solver, scratch and the boundary follow.
    fn refresh_topology(&mut self) {
        let n = self.mesh.nodes.len();
        self.solver = make_solver(self.params.solver, 3 * n, self.params.tolerance, self.params.max_iterations);
        self.analysed = false;
        self.referenced = false;
        // every entry is written by the next assembly
        self.values.resize(self.pattern.nnz(), 0.0);
        self.boundary = self.mesh.boundary_triangles();
    }

    /// Prescribed displacements: fixed regions, then pins; nodes of no
    /// element are held at rest so the system stays regular.
    fn prescribed(&self) -> Vec<Option<[f64; 3]>> {
        let mut out = vec![None; self.mesh.nodes.len()];
        for (i, x) in self.mesh.nodes.iter().enumerate() {
            // a node of no element has no mass (every element gives its
            // nodes positive mass fractions)
            if !(self.masses[i] > 0.0) {
                out[i] = Some(self.displacement[i]);
            } else if let Some(r) = self.fixed.iter().rev().find(|r| r.contains(*x)) {
                out[i] = Some(r.value(*x));
            }
        }
        for (&i, u) in &self.pinned {
            out[i as usize] = Some(*u);
        }
        out
    }

    /// Analyses the pattern once per topology.
    fn ensure_analysed(&mut self) -> Result<(), Error> {
        if !self.analysed {
            let t = std::time::Instant::now();
            self.solver.analyze(self.pattern.symbolic.as_ref())?;
            self.timings.add(Phase::Solve, t.elapsed().as_secs_f64());
            self.analysed = true;
        }
        Ok(())
    }

    /// Factors and solves `A x = rhs` for the current `values`, with `x` as
    /// the warm start.
    fn solve_system(&mut self, rhs: &[f64], x: &mut [f64]) -> Result<SolveStats, Error> {
        self.ensure_analysed()?;
        let matrix = self.pattern.matrix(&self.values);
        let solver = &mut self.solver;
        let stats = self.timings.time(Phase::Solve, || -> Result<SolveStats, Error> {
            solver.factor(matrix)?;
            Ok(solve_checked(solver.as_mut(), matrix, rhs, x)?)
        })?;
        if x.iter().any(|v| !v.is_finite()) {
            return Err(crate::solve::SolveError::NonFinite.into());
        }
        Ok(stats)
    }

    /// For preconditioners in rotated frames: the rest-state matrix
    /// `c_m M + c_k K` with the same constraints, once per topology, and the
    /// node frames of this step.
    fn prepare_rotated_reference(&mut self, c_m: f64, c_k: f64, constraints: &Constraints) -> Result<(), Error> {
        let t = std::time::Instant::now();
        if !self.referenced {
            let mut rest = vec![0.0; self.pattern.nnz()];
            let store = &self.store;
            self.pattern.assemble(&mut rest, |b, i, bb, out| {
                store.batches[b].block_column(i, bb, out);
                out.iter_mut().for_each(|blk| blk.iter_mut().for_each(|v| *v *= c_k));
            });
            for (i, m) in self.masses.iter().enumerate() {
                (0..3).for_each(|d| rest[self.pattern.diagonal_slot(3 * i + d)] += c_m * m);
            }
            let mut unused = vec![0.0; 3 * self.masses.len()];
            constraints.apply(&self.pattern, &mut rest, &mut unused);
            self.solver.set_reference(self.pattern.matrix(&rest))?;
            self.referenced = true;
        }
        self.solver.set_frames(&self.corotation.node_frames(&self.store, self.mesh.nodes.len()));
        self.timings.add(Phase::Solve, t.elapsed().as_secs_f64());
        Ok(())
    }

    /// Solves the linear static problem `K u = f_gravity` with the fixed
    /// regions as Dirichlet conditions, and stores `u`.
    pub fn solve_static(&mut self) -> Result<SolveStats, Error> {
        let store = &self.store;
        let values = &mut self.values;
        let pattern = &self.pattern;
        self.timings.time(Phase::Assembly, || {
            pattern.assemble(values, |b, i, bb, out| store.batches[b].block_column(i, bb, out))
        });
        let g = self.params.gravity;
        let mut rhs: Vec<f64> = self.masses.iter().flat_map(|&m| [m * g[0], m * g[1], m * g[2]]).collect();
        let mut constraints = Constraints::free(rhs.len());
        for (i, p) in self.prescribed().iter().enumerate() {
            if let Some(u) = p {
                (0..3).for_each(|d| constraints.fix(3 * i + d, u[d]));
            }
        }
        constraints.apply(&self.pattern, &mut self.values, &mut rhs);
        let mut x = vec![0.0; rhs.len()];
        // a static system has no mass term and no warm start: `auto` takes
        // the direct solver whatever the size
        let stats = if self.params.solver == SolverKind::Auto {
            let dynamic = std::mem::replace(&mut self.solver, make_solver(SolverKind::Cholesky, 0, 1.0, 1));
            let analysed = std::mem::replace(&mut self.analysed, false);
            let stats = self.solve_system(&rhs, &mut x);
            self.solver = dynamic;
            self.analysed = analysed;
            stats?
        } else {
            self.solve_system(&rhs, &mut x)?
        };
        self.displacement = x.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        self.refresh_positions();
        Ok(stats)
    }

    /// Advances one implicit Euler step of corotated elasticity:
    ///
    /// ```text
    /// ((1 + h α) M + (h² + h β) K_R) v⁺ = M v + h (f_gravity + f_elastic(x) + f_contact(x))
    /// x⁺ = x + h v⁺
    /// ```
    ///
    /// with `K_R` the warped stiffness, `f_elastic = -R K (Rᵀ x - X)`,
    /// Rayleigh damping `α M + β K_R`, and the penalty contacts linearised
    /// into the same solve. Prescribed nodes move to their target in one
    /// step. Errors name the step.
    pub fn step(&mut self) -> Result<StepStats, Error> {
        let step = self.steps;
        self.advance().map_err(|e| match e {
            Error::Solve(source) => Error::Step { step, source },
            other => other,
        })
    }

    fn advance(&mut self) -> Result<StepStats, Error> {
        let h = self.params.dt;
        let n = self.mesh.nodes.len();
        let warp = self.params.corotated;
        let (store, corotation, x) = (&self.store, &mut self.corotation, &self.position);
        let rotation_iterations = self.timings.time(Phase::Rotation, || corotation.update(store, x, warp));
        let c_k = h * h + h * self.params.stiffness_damping;
        let c_m = 1.0 + h * self.params.mass_damping;
        let mut force = vec![[0.0; 3]; n];
        {
            let (pattern, values, corotation) = (&self.pattern, &mut self.values, &self.corotation);
            self.timings.time(Phase::Assembly, || {
                pattern.assemble(values, |b, i, bb, out| corotation.block_column(store, b, i, bb, c_k, out));
                pattern.gather(&mut force, |b, i, a| corotation.force(store, b, i, a));
            });
        }
        let g = self.params.gravity;
        let mut rhs = vec![0.0; 3 * n];
        for i in 0..n {
            let m = self.masses[i];
            for d in 0..3 {
                let slot = self.pattern.diagonal_slot(3 * i + d);
                self.values[slot] += c_m * m;
                rhs[3 * i + d] = m * self.velocity[i][d] + h * (m * g[d] + force[i][d]);
            }
        }
        let mut contacts = 0;
        for c in &self.colliders {
            for (i, xi) in self.position.iter().enumerate() {
                let depth = c.depth(*xi);
                if depth > 0.0 {
                    contacts += 1;
                    for r in 0..3 {
                        rhs[3 * i + r] += h * c.stiffness * depth * c.normal[r];
                        for col in 0..3 {
                            let slot = self.pattern.block_slot(i, r, col);
                            self.values[slot] += h * h * c.stiffness * c.normal[r] * c.normal[col];
                        }
                    }
                }
            }
        }
        let mut constraints = Constraints::free(3 * n);
        for (i, p) in self.prescribed().iter().enumerate() {
            if let Some(u) = p {
                (0..3).for_each(|d| constraints.fix(3 * i + d, (u[d] - self.displacement[i][d]) / h));
            }
        }
        constraints.apply(&self.pattern, &mut self.values, &mut rhs);
        // warm start: the velocity extrapolated linearly from the last two steps
        if self.solver.wants_frames() {
            self.prepare_rotated_reference(c_m, c_k, &constraints)?;
        }
        let mut v: Vec<f64> = self
            .velocity
            .iter()
            .zip(&self.previous_velocity)
            .flat_map(|(v, p)| [2.0 * v[0] - p[0], 2.0 * v[1] - p[1], 2.0 * v[2] - p[2]])
            .collect();
        let solve = self.solve_system(&rhs, &mut v)?;
        self.previous_velocity.copy_from_slice(&self.velocity);
        for i in 0..n {
            let vi = [v[3 * i], v[3 * i + 1], v[3 * i + 2]];
            self.velocity[i] = vi;
            (0..3).for_each(|d| self.displacement[i][d] += h * vi[d]);
        }
        self.refresh_positions();
        self.steps += 1;
        Ok(StepStats { solve, rotation_iterations, contacts })
    }
}
