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
//! # Ok::<(), cleave::Error>(())
//! ```

mod timings;

pub use timings::{Phase, PhaseTimings};

use cleave_kernels::elasticity::{stress, von_mises};

use crate::assembly::{Constraints, SparsePattern};
use crate::material::Material;
use crate::mesh::PolyMesh;
use crate::solve::{solve_checked, Cholesky, LinearSolver, SolveStats};
use crate::store::{BasisOptions, ElementStore};
use crate::Error;

/// Physical and numerical parameters of a simulation.
#[derive(Clone, Debug, PartialEq)]
pub struct SimulationParams {
    /// The material of every element.
    pub material: Material,
    /// Gravitational acceleration (m/s^2).
    pub gravity: [f64; 3],
    /// Basis construction options (quadrature of mean value elements).
    pub basis: BasisOptions,
}

impl Default for SimulationParams {
    fn default() -> Self {
        SimulationParams {
            material: Material { young: 1e5, poisson: 0.3, density: 1000.0 },
            gravity: [0.0, 0.0, -9.81],
            basis: BasisOptions::default(),
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

/// One elastic body: mesh, element data, state and solver.
pub struct Simulation {
    mesh: PolyMesh,
    params: SimulationParams,
    store: ElementStore,
    pattern: SparsePattern,
    masses: Vec<f64>,
    fixed: Vec<FixedRegion>,
    pinned: std::collections::BTreeMap<u32, [f64; 3]>,
    displacement: Vec<[f64; 3]>,
    velocity: Vec<[f64; 3]>,
    solver: Box<dyn LinearSolver>,
    timings: PhaseTimings,
}

impl Simulation {
    /// Validates `mesh` and builds the element store and the sparse pattern.
    pub fn new(mesh: PolyMesh, params: SimulationParams) -> Result<Self, Error> {
        Material::new(params.material.young, params.material.poisson, params.material.density)?;
        if !params.gravity.iter().all(|g| g.is_finite()) {
            return Err(Error::Parameter(format!("gravity {:?} must be finite", params.gravity)));
        }
        mesh.validate()?;
        let mut timings = PhaseTimings::default();
        let store = timings.time(Phase::Basis, || ElementStore::build(&mesh, &params.material, &params.basis))?;
        let pattern = timings.time(Phase::Assembly, || SparsePattern::build(mesh.nodes.len(), &store));
        let masses = store.lumped_masses(mesh.nodes.len(), params.material.density);
        let n = mesh.nodes.len();
        Ok(Simulation {
            mesh,
            params,
            store,
            pattern,
            masses,
            fixed: Vec::new(),
            pinned: Default::default(),
            displacement: vec![[0.0; 3]; n],
            velocity: vec![[0.0; 3]; n],
            solver: Box::new(Cholesky::default()),
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
    pub fn positions(&self) -> Vec<[f64; 3]> {
        self.mesh.nodes.iter().zip(&self.displacement).map(|(x, u)| [x[0] + u[0], x[1] + u[1], x[2] + u[2]]).collect()
    }

    /// Lumped nodal masses (kg).
    pub fn masses(&self) -> &[f64] {
        &self.masses
    }

    /// Wall time spent per phase so far.
    pub fn timings(&self) -> &PhaseTimings {
        &self.timings
    }

    /// Adds output time measured by the caller.
    pub fn record_output_time(&mut self, seconds: f64) {
        self.timings.add(Phase::Output, seconds);
    }

    /// Von Mises stress of every element at its stress point (Pa).
    pub fn von_mises(&self) -> Vec<f64> {
        let (l, m) = self.params.material.lame();
        self.store.displacement_gradients(&self.displacement).into_iter().map(|g| von_mises(stress(g, l, m))).collect()
    }

    /// Elastic energy `½ uᵀ K u` (J) of the current displacement.
    pub fn elastic_energy(&self) -> f64 {
        let mut e = 0.0;
        for b in &self.store.batches {
            let k = b.k;
            for i in 0..b.len() {
                let ke = b.element_stiffness(i);
                let u: Vec<f64> = b.element_nodes(i).iter().flat_map(|&v| self.displacement[v as usize]).collect();
                for r in 0..3 * k {
                    let row = &ke[r * 3 * k..(r + 1) * 3 * k];
                    e += 0.5 * u[r] * row.iter().zip(&u).map(|(a, b)| a * b).sum::<f64>();
                }
            }
        }
        e
    }

    /// Kinetic energy `½ Σ m_i |v_i|²` (J).
    pub fn kinetic_energy(&self) -> f64 {
        self.masses.iter().zip(&self.velocity).map(|(m, v)| 0.5 * m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])).sum()
    }

    /// The Dirichlet constraints of the current fixed regions; nodes that
    /// belong to no element are held at rest so the system stays regular.
    fn constraints(&self) -> Constraints {
        let n = self.mesh.nodes.len();
        let mut c = Constraints::free(3 * n);
        let mut used = vec![false; n];
        for el in &self.mesh.elements {
            for &v in &el.nodes {
                used[v as usize] = true;
            }
        }
        for (i, x) in self.mesh.nodes.iter().enumerate() {
            if !used[i] {
                (0..3).for_each(|d| c.fix(3 * i + d, 0.0));
                continue;
            }
            if let Some(r) = self.fixed.iter().rev().find(|r| r.contains(*x)) {
                let u = r.value(*x);
                (0..3).for_each(|d| c.fix(3 * i + d, u[d]));
            }
        }
        for (&i, u) in &self.pinned {
            (0..3).for_each(|d| c.fix(3 * i as usize + d, u[d]));
        }
        c
    }

    /// Solves the linear static problem `K u = f_gravity` with the fixed
    /// regions as Dirichlet conditions, and stores `u`.
    pub fn solve_static(&mut self) -> Result<SolveStats, Error> {
        let n = self.mesh.nodes.len();
        let mut values = vec![0.0; self.pattern.nnz()];
        let store = &self.store;
        self.timings.time(Phase::Assembly, || {
            self.pattern
                .assemble(store, &mut values, |b, i, out| out.copy_from_slice(store.batches[b].element_stiffness(i)))
        });
        let g = self.params.gravity;
        let mut rhs: Vec<f64> = self.masses.iter().flat_map(|&m| [m * g[0], m * g[1], m * g[2]]).collect();
        let constraints = self.constraints();
        constraints.apply(&self.pattern, &mut values, &mut rhs);
        let matrix = self.pattern.matrix(&values);
        let mut x = vec![0.0; 3 * n];
        let solver = &mut self.solver;
        let stats = self.timings.time(Phase::Solve, || -> Result<SolveStats, Error> {
            solver.analyze(self.pattern.symbolic.as_ref())?;
            solver.factor(matrix)?;
            Ok(solve_checked(solver.as_mut(), matrix, &rhs, &mut x)?)
        })?;
        self.displacement = x.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        Ok(stats)
    }
}
