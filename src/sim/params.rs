//! The parameters of a simulation and their checks.

use crate::material::Material;
use crate::param::{finite, non_negative, positive, ParamError};
use crate::solve::SolverKind;
use crate::store::BasisOptions;
use crate::topology::SplitOptions;

/// How many times a cut is tried, each time keeping whole one more element
/// whose parts the element store found unhealthy.
pub const CUT_ATTEMPTS: usize = 16;

/// Physical and numerical parameters of a simulation.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
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
    /// Smallest diameter of a part a cut makes, as a fraction of the
    /// body's median rest element diameter when the simulation is built
    /// (it raises `cut.min_diameter` to that length). Default `0.1`. Every
    /// split already keeps its parts above about `cut.snap` of their
    /// element, but cuts through the same place compound: the soak's
    /// 75th cut left a lone tetrahedron of 1.3 cm in a bunny whose median
    /// element spans 0.72 m, and the floor's penalty contact, meeting a
    /// body that moves about its own size in a step, tore it apart
    /// (stretch 10 at 1 m/s, dt 0.01 s). A part below the floor is not
    /// made: its element is kept whole and the cut follows its faces.
    pub min_part: f64,
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
            min_part: 0.1,
        }
    }
}

impl SimulationParams {
    /// Checks every value against its allowed range; the error names the
    /// parameter (`young`, `dt`, `tolerance`, `offset`, `snap`, ...) as the
    /// field that holds it.
    pub fn check(&self) -> Result<(), ParamError> {
        self.material.check()?;
        finite("gravity", self.gravity, "must be finite (m/s^2)")?;
        self.basis.check()?;
        positive("dt", self.dt, "must be a finite number > 0 (s)")?;
        non_negative("mass_damping", self.mass_damping, "must be a finite number >= 0 (1/s)")?;
        non_negative("stiffness_damping", self.stiffness_damping, "must be a finite number >= 0 (s)")?;
        if !(self.tolerance > 0.0 && self.tolerance < 1.0) {
            return Err(ParamError::new("tolerance", self.tolerance, "must lie in (0, 1)"));
        }
        if self.max_iterations == 0 {
            return Err(ParamError::new("max_iterations", 0, "must be at least 1"));
        }
        if !(self.min_part >= 0.0 && self.min_part < 1.0) {
            return Err(ParamError::new(
                "min_part",
                self.min_part,
                "must lie in [0, 1) (fraction of the median element diameter)",
            ));
        }
        self.cut.check()
    }
}
