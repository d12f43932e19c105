//! One implicit Euler step of corotated elasticity, as six numbered phases,
//! each timed on its own:
//!
//! ```text
//! 1. forces       rotations R_e at the current positions, elastic forces
//! 2. assembly     A = (h² + h β) K_R, the warped stiffness
//! 3. contacts     A += (1 + h α) M, b = M v + h (f_gravity + f_elastic);
//!                 penalty contacts linearised into A and b
//! 4. constraints  prescribed velocities eliminated symmetrically
//! 5. solve        A v⁺ = b, warm-started from 2 v - v⁻ (SolverKind::Auto:
//!                 by CG, by Cholesky once CG proves slow)
//! 6. integrate    x⁺ = x + h v⁺
//! ```
//!
//! Every buffer a step writes lives in [`StepSystem`] and is reused: after
//! the first step of a topology, a step allocates nothing.

use rayon::prelude::*;

use crate::assembly::{Constraints, SparsePattern};
use crate::solve::{auto_cg_budget, make_solver, LinearSolver, SolveError, SolveStats, SolverChoice, SolverKind};
use crate::Error;

use super::{rest, Boundary, Discretization, NodeState, Phase, PointMap, Simulation};

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

/// The linear system of a step, its solver and the buffers every step
/// reuses (sized per topology).
pub(crate) struct StepSystem {
    solver: Box<dyn LinearSolver>,
    /// What `solver` is, and its tolerance and iteration cap.
    made: (SolverChoice, f64, usize),
    /// Whether the solver has analysed this topology's pattern.
    analysed: bool,
    /// Whether the solver holds this topology's rest-state reference.
    referenced: bool,
    /// The matrix values on the pattern.
    pub values: Vec<f64>,
    rhs: Vec<f64>,
    /// The unknown velocities (m/s), flat.
    velocity: Vec<f64>,
    /// Elastic force per node (N).
    force: Vec<[f64; 3]>,
    constraints: Constraints,
    /// Rest-state matrix of the rotated preconditioner, and a right-hand
    /// side its constraints write into.
    reference: Vec<f64>,
    reference_rhs: Vec<f64>,
    /// Per-node frames of the rotated preconditioner and their quaternion
    /// sums.
    frames: Vec<[f64; 9]>,
    frame_sums: Vec<[f64; 4]>,
}

impl Default for StepSystem {
    /// An empty system (of no unknowns), replaced on the first step.
    fn default() -> Self {
        StepSystem::new(SolverKind::default(), &SparsePattern::empty(), 1e-8, 1)
    }
}

impl StepSystem {
    /// A system for `pattern` solved by `kind`.
    pub fn new(kind: SolverKind, pattern: &SparsePattern, tolerance: f64, max_iterations: usize) -> Self {
        let mut system = StepSystem {
            solver: make_solver(kind, 0, tolerance, max_iterations),
            made: (SolverChoice::of(kind, 0), tolerance, max_iterations),
            analysed: false,
            referenced: false,
            values: Vec::new(),
            rhs: Vec::new(),
            velocity: Vec::new(),
            force: Vec::new(),
            constraints: Constraints::free(0),
            reference: Vec::new(),
            reference_rhs: Vec::new(),
            frames: Vec::new(),
            frame_sums: Vec::new(),
        };
        system.renew(kind, pattern, tolerance, max_iterations);
        system
    }

    /// Makes this the system of a new topology's `pattern`, keeping the
    /// buffers' memory (with room for cuts: [`crate::reserve_room`]), the
    /// solver's too when the same solver serves the new size (it analyses
    /// the new pattern before the next solve): after a cut the next step
    /// writes into pages it already has.
    pub fn renew(&mut self, kind: SolverKind, pattern: &SparsePattern, tolerance: f64, max_iterations: usize) {
        let n = 3 * pattern.num_blocks;
        let made = (SolverChoice::of(kind, n), tolerance, max_iterations);
        if made != self.made {
            (self.solver, self.made) = (make_solver(kind, n, tolerance, max_iterations), made);
        }
        (self.analysed, self.referenced) = (false, false);
        // (every value is written by the next assembly, every entry of the
        // vectors by the next step: only their lengths matter)
        crate::resize_with_room(&mut self.values, pattern.nnz(), 0.0);
        crate::resize_with_room(&mut self.rhs, n, 0.0);
        crate::resize_with_room(&mut self.velocity, n, 0.0);
        crate::resize_with_room(&mut self.force, pattern.num_blocks, [0.0; 3]);
        self.constraints = Constraints::free(n);
        for buffer in [&mut self.reference, &mut self.reference_rhs] {
            buffer.clear();
        }
        self.frames.clear();
        self.frame_sums.clear();
    }

    /// Whether this system was made for `pattern` (a deserialized
    /// simulation's is empty).
    fn fits(&self, pattern: &SparsePattern) -> bool {
        self.values.len() == pattern.nnz() && self.force.len() == pattern.num_blocks
    }

    /// Analyses the pattern once per topology (time booked under
    /// [`Phase::Solve`] by the caller).
    pub fn ensure_analysed(&mut self, pattern: &SparsePattern) -> Result<(), SolveError> {
        if !self.analysed {
            self.solver.analyze_pattern(pattern.system())?;
            self.analysed = true;
        }
        Ok(())
    }
}

impl Simulation {
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
        self.stabilise().and_then(|()| self.advance()).map_err(|source| Error::Step { step, source })
    }

    fn advance(&mut self) -> Result<StepStats, SolveError> {
        if !self.system.fits(&self.pattern) {
            let p = &self.params;
            self.system = StepSystem::new(self.solver_kind(), &self.pattern, p.tolerance, p.max_iterations);
        }
        let n = 3 * self.pattern.num_blocks;
        let may_fall_back =
            self.solver_kind() == SolverKind::Auto && SolverChoice::of(SolverKind::Auto, n) == SolverChoice::Cg;
        let h = self.params.dt;
        let (c_k, c_m) = (h * h + h * self.params.stiffness_damping, 1.0 + h * self.params.mass_damping);
        let (pattern, system, timings) = (&self.pattern, &mut self.system, &mut self.timings);
        let (elements, state, warp) = (&mut self.elements, &self.state, self.params.corotated);
        // 1.
        let body = &self.body_loads;
        let rotation_iterations = timings.time(Phase::Forces, || forces(elements, pattern, state, warp, body, system));
        // 2.
        let masses = &self.masses;
        timings.time(Phase::Assembly, || assemble(elements, pattern, masses, (c_k, c_m), system));
        // 3.
        let (masses, loads, gravity, boundary) = (&self.masses, &self.loads, self.params.gravity, &self.boundary);
        let points = self.contacts.as_ref();
        let contacts = timings.time(Phase::Contacts, || {
            inertia_and_loads(masses, loads, state, gravity, h, system);
            match points {
                None => contact(pattern, boundary, state, h, system),
                Some((map, share)) => contact_points(pattern, boundary, map, share, state, h, system),
            }
        });
        // 4.
        let nodal = points.is_none();
        timings.time(Phase::Constraints, || {
            constrain(pattern, boundary, nodal.then_some(&self.mesh.nodes[..]), masses, state, h, system)
        });
        // 5.
        let mut solve_step = |system: &mut StepSystem| {
            timings.time(Phase::Solve, || solve(elements, pattern, masses, state, nodal, c_m, c_k, system))
        };
        // (Auto hands the steps to Cholesky when this step's CG did not
        // converge, and then solves it again, or when CG's running mean of
        // iterations passes its budget)
        let solved = solve_step(system);
        let average = &mut self.auto_cg_iterations;
        let fall_back = may_fall_back
            && match &solved {
                Ok(stats) => {
                    *average += (stats.iterations as f64 - *average) / 16.0;
                    *average > auto_cg_budget(n) as f64
                }
                Err(error) => matches!(error, SolveError::NotConverged { .. }),
            };
        if fall_back {
            self.solver_fell_back = true;
            let p = &self.params;
            system.renew(SolverKind::Cholesky, pattern, p.tolerance, p.max_iterations);
        }
        let solve = match solved {
            Err(_) if fall_back => solve_step(system)?,
            solved => solved?,
        };
        // 6.
        let (state, nodes, rest) = (&mut self.state, &mut self.nodes, rest(&self.mesh, &self.elements));
        timings.time(Phase::Integrate, || {
            state.integrate(rest, &system.velocity, h);
            if !nodal {
                nodes.refresh(state);
            }
        });
        self.steps += 1;
        Ok(StepStats { solve, rotation_iterations, contacts })
    }
}

/// Phase 1: rotations and elastic forces at the current positions,
/// gathered per block, plus the body force's loads (if any); returns the
/// most rotation iterations.
fn forces(
    elements: &mut impl Discretization,
    pattern: &SparsePattern,
    state: &NodeState,
    warp: bool,
    body: &[[f64; 3]],
    system: &mut StepSystem,
) -> usize {
    let iterations = elements.update(&state.position, warp);
    pattern.gather(&mut system.force, |b, i, a| elements.force(b, i, a));
    for (f, b) in system.force.iter_mut().zip(body) {
        (0..3).for_each(|k| f[k] += b[k]);
    }
    iterations
}

/// Phase 2: the warped stiffness times `c_k = h² + h β` into the values,
/// and the mass `c_m M` on their diagonal.
fn assemble(
    elements: &impl Discretization,
    pattern: &SparsePattern,
    masses: &[f64],
    (c_k, c_m): (f64, f64),
    system: &mut StepSystem,
) {
    let blocks = |b, i, bb, out: &mut [[f64; 9]]| elements.stiffness_column(b, i, bb, c_k, out);
    let mass = |j: usize| [c_m * masses.get(j).copied().unwrap_or(0.0); 3];
    pattern.assemble_prefetched(&mut system.values, blocks, |b, i| elements.prefetch(b, i), mass);
}

/// Phase 3a: the right-hand side `M v + h (W g + f)`, `W` the gravity
/// weights (the masses for nodal blocks).
fn inertia_and_loads(masses: &[f64], loads: &[f64], state: &NodeState, g: [f64; 3], h: f64, system: &mut StepSystem) {
    let blocks = system.rhs.par_chunks_mut(3).zip(&system.force).zip(&state.velocity);
    blocks.zip(masses.par_iter().zip(loads)).for_each(|(((rhs, f), v), (&m, &w))| {
        (0..3).for_each(|d| rhs[d] = m * v[d] + h * (w * g[d] + f[d]));
    });
}

/// Phase 3b: every node behind a collider gets the penalty force
/// `k d n` (into the right-hand side, times `h`) and its linearisation
/// `h² k n nᵀ` (into the matrix); returns the number of such contacts.
fn contact(pattern: &SparsePattern, boundary: &Boundary, state: &NodeState, h: f64, system: &mut StepSystem) -> usize {
    let mut contacts = 0;
    for c in &boundary.colliders {
        for (i, xi) in state.position.iter().enumerate() {
            let depth = c.depth(*xi);
            if depth > 0.0 {
                contacts += 1;
                for r in 0..3 {
                    system.rhs[3 * i + r] += h * c.stiffness * depth * c.normal[r];
                    for col in 0..3 {
                        let slot = pattern.block_slot(i, r, col);
                        system.values[slot] += h * h * c.stiffness * c.normal[r] * c.normal[col];
                    }
                }
            }
        }
    }
    contacts
}

/// Phase 3b for blocks that are not points: every collision point (a
/// weighted sum of blocks) behind a collider gets its share `s_p` of the
/// penalty, `k s_p d n` distributed to its blocks by their weights
/// (times `h`), with the linearisation `h² k s_p w_i w_j n nᵀ`
/// (kaufmann2008 §9: `K_ij -= W_i A W_j`, `F_i += b W_i`); returns the
/// number of such contacts.
fn contact_points(
    pattern: &SparsePattern,
    boundary: &Boundary,
    map: &PointMap,
    share: &[f64],
    state: &NodeState,
    h: f64,
    system: &mut StepSystem,
) -> usize {
    let mut contacts = 0;
    for c in &boundary.colliders {
        for (p, &sp) in share.iter().enumerate() {
            let (blocks, weights) = map.row(p);
            let mut x = [0.0; 3];
            for (&i, &w) in blocks.iter().zip(weights) {
                (0..3).for_each(|k| x[k] += w * state.position[i as usize][k]);
            }
            let depth = c.depth(x);
            if !(depth > 0.0) {
                continue;
            }
            contacts += 1;
            let k = c.stiffness * sp;
            for (&i, &wi) in blocks.iter().zip(weights) {
                let i = i as usize;
                (0..3).for_each(|r| system.rhs[3 * i + r] += h * k * depth * c.normal[r] * wi);
                for (&j, &wj) in blocks.iter().zip(weights) {
                    let j = j as usize;
                    // a pair the pattern does not couple (blocks of elements
                    // apart, under an embedded vertex) is lumped onto the
                    // diagonal: the linearisation is then stiffer, never softer
                    let (base, stride, w) = match pattern.block_offset(i, j) {
                        Some(base) => (base, pattern.column_stride(j), wi * wj),
                        None => (pattern.block_slot(i, 0, 0), pattern.column_stride(i), (wi * wj).abs()),
                    };
                    for r in 0..3 {
                        for col in 0..3 {
                            system.values[base + col * stride + r] += h * h * k * w * c.normal[r] * c.normal[col];
                        }
                    }
                }
            }
        }
    }
    contacts
}

/// Phase 4: every prescribed node moves to its target in this step: its
/// velocity `(u_target - u) / h` is eliminated from the system. Blocks
/// that are not nodes (`rest` is `None`) have no prescribed values: their
/// fixed regions act weakly, through face terms.
fn constrain(
    pattern: &SparsePattern,
    boundary: &Boundary,
    rest: Option<&[[f64; 3]]>,
    masses: &[f64],
    state: &NodeState,
    h: f64,
    system: &mut StepSystem,
) {
    let constraints = &mut system.constraints;
    constraints.reset(3 * masses.len());
    let Some(rest) = rest else { return };
    boundary.prescribe(rest, masses, &state.displacement, |i, u| {
        (0..3).for_each(|d| constraints.fix(3 * i + d, (u[d] - state.displacement[i][d]) / h));
    });
    constraints.apply(pattern, &mut system.values, &mut system.rhs);
}

/// Phase 5: the rotated preconditioner's reference and frames when the
/// solver wants them, the blocks' positions where blocks are nodes
/// (`nodal`), then factor and solve, warm-started from the velocity
/// extrapolated linearly from the last two steps.
#[allow(clippy::too_many_arguments)]
fn solve(
    elements: &impl Discretization,
    pattern: &SparsePattern,
    masses: &[f64],
    state: &NodeState,
    nodal: bool,
    c_m: f64,
    c_k: f64,
    system: &mut StepSystem,
) -> Result<SolveStats, SolveError> {
    system.ensure_analysed(pattern)?;
    if system.solver.wants_frames() {
        if !system.referenced {
            let reference = &mut system.reference;
            reference.resize(pattern.nnz(), 0.0);
            pattern.assemble(reference, |b, i, bb, out| {
                elements.rest_stiffness_column(b, i, bb, out);
                out.iter_mut().for_each(|blk| blk.iter_mut().for_each(|v| *v *= c_k));
            });
            for (i, m) in masses.iter().enumerate() {
                (0..3).for_each(|d| reference[pattern.diagonal_slot(3 * i + d)] += c_m * m);
            }
            system.reference_rhs.resize(3 * masses.len(), 0.0);
            system.constraints.apply(pattern, reference, &mut system.reference_rhs);
            system.solver.set_reference(pattern.matrix(reference))?;
            system.referenced = true;
        }
        elements.block_frames(masses.len(), &mut system.frame_sums, &mut system.frames);
        system.solver.set_frames(&system.frames);
    }
    for ((v, now), before) in system.velocity.chunks_exact_mut(3).zip(&state.velocity).zip(&state.previous_velocity) {
        (0..3).for_each(|d| v[d] = 2.0 * now[d] - before[d]);
    }
    if nodal {
        system.solver.set_positions(&state.position);
    }
    let values = &system.values;
    system.solver.factor_values(pattern.system(), values)?;
    let stats = system.solver.solve_values(pattern.system(), values, &system.rhs, &mut system.velocity)?;
    if system.velocity.iter().any(|v| !v.is_finite()) {
        return Err(SolveError::NonFinite);
    }
    Ok(stats)
}
