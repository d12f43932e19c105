//! The linear static problem `K u = f_gravity`, with its own solver.

use crate::assembly::Constraints;
use crate::solve::{make_solver, LinearSolver, SolveError, SolveStats, SolverKind};
use crate::Error;

use super::{Discretization, Model, Phase, Simulation};

/// The solver of the static problem, kept beside the step's (their
/// matrices differ; both write the simulation's one values buffer).
pub(crate) struct StaticSystem {
    solver: Box<dyn LinearSolver>,
    /// Whether `solver` has analysed this topology's pattern.
    analysed: bool,
}

impl StaticSystem {
    /// The solver for `kind`: a static system has no mass term and no warm
    /// start, so `auto` takes the direct solver whatever the size.
    fn new(kind: SolverKind, unknowns: usize, tolerance: f64, max_iterations: usize) -> Self {
        let kind = if kind == SolverKind::Auto { SolverKind::Cholesky } else { kind };
        StaticSystem { solver: make_solver(kind, unknowns, tolerance, max_iterations), analysed: false }
    }
}

impl Simulation {
    /// Solves the linear static problem `K u = f_gravity` with the fixed
    /// regions and pins as Dirichlet conditions, and stores `u`.
    pub fn solve_static(&mut self) -> Result<SolveStats, Error> {
        self.stabilise()?;
        let (pattern, elements) = (&self.pattern, &self.elements);
        let values = &mut self.system.values;
        self.timings.time(Phase::Assembly, || {
            pattern.assemble(values, |b, i, bb, out| elements.rest_stiffness_column(b, i, bb, out))
        });
        let g = self.params.gravity;
        let mut rhs: Vec<f64> = self.loads.iter().flat_map(|&m| [m * g[0], m * g[1], m * g[2]]).collect();
        for (r, b) in rhs.chunks_exact_mut(3).zip(&self.body_loads) {
            (0..3).for_each(|k| r[k] += b[k]);
        }
        match &self.elements {
            Model::Nodal(_) => {
                let mut constraints = Constraints::free(rhs.len());
                self.boundary.prescribe(&self.mesh.nodes, &self.masses, &self.state.displacement, |i, u| {
                    (0..3).for_each(|d| constraints.fix(3 * i + d, u[d]));
                });
                constraints.apply(pattern, values, &mut rhs);
            }
            // fixed regions act weakly: their loads join the right-hand side
            Model::Dg(dg) => dg.add_boundary_loads(bytemuck::cast_slice_mut(&mut rhs)),
        }
        let mut x = vec![0.0; rhs.len()];
        let p = &self.params;
        let statics =
            self.statics.get_or_insert_with(|| StaticSystem::new(p.solver, rhs.len(), p.tolerance, p.max_iterations));
        let stats = self.timings.time(Phase::Solve, || -> Result<SolveStats, SolveError> {
            if !statics.analysed {
                statics.solver.analyze_pattern(pattern.system())?;
                statics.analysed = true;
            }
            statics.solver.factor_values(pattern.system(), values)?;
            let stats = statics.solver.solve_values(pattern.system(), values, &rhs, &mut x)?;
            if x.iter().any(|v| !v.is_finite()) {
                return Err(SolveError::NonFinite);
            }
            Ok(stats)
        })?;
        self.state.displacement = x.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        self.state.refresh_positions(super::rest(&self.mesh, &self.elements));
        self.nodes.refresh(&self.state);
        Ok(stats)
    }
}
