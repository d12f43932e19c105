//! Isotropic Hookean material.

use crate::param::{positive, ParamError};

/// Linear isotropic elastic material with mass density.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Material {
    /// Young's modulus `E` (Pa).
    pub young: f64,
    /// Poisson's ratio `ν` (dimensionless).
    pub poisson: f64,
    /// Mass density `ρ` (kg/m^3).
    pub density: f64,
}

impl Material {
    /// Checks `E > 0`, `-1 < ν < 0.5`, `ρ > 0`, all finite.
    pub fn new(young: f64, poisson: f64, density: f64) -> Result<Self, ParamError> {
        positive("young", young, "must be a finite number > 0 (Pa)")?;
        if !(poisson > -1.0 && poisson < 0.5) {
            return Err(ParamError::new("poisson", poisson, "must lie in (-1, 0.5)"));
        }
        positive("density", density, "must be a finite number > 0 (kg/m^3)")?;
        Ok(Material { young, poisson, density })
    }

    /// [`Material::new`] on this material's values.
    pub fn check(&self) -> Result<(), ParamError> {
        Material::new(self.young, self.poisson, self.density).map(|_| ())
    }

    /// Lamé parameters `(λ, μ)` in Pa.
    pub fn lame(&self) -> (f64, f64) {
        cleave_kernels::elasticity::lame(self.young, self.poisson)
    }
}
