//! Isotropic Hookean material.

use thiserror::Error;

/// Linear isotropic elastic material with mass density.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Young's modulus `E` (Pa).
    pub young: f64,
    /// Poisson's ratio `ν` (dimensionless).
    pub poisson: f64,
    /// Mass density `ρ` (kg/m^3).
    pub density: f64,
}

/// A material parameter outside its physical range.
#[derive(Clone, Debug, Error, PartialEq)]
#[error("material {name} = {value}: {allowed}")]
pub struct MaterialError {
    /// Parameter name as in a scene file.
    pub name: &'static str,
    /// The rejected value.
    pub value: f64,
    /// The allowed range.
    pub allowed: &'static str,
}

impl Material {
    /// Checks `E > 0`, `-1 < ν < 0.5`, `ρ > 0`, all finite.
    pub fn new(young: f64, poisson: f64, density: f64) -> Result<Self, MaterialError> {
        if !(young > 0.0 && young.is_finite()) {
            return Err(MaterialError { name: "young", value: young, allowed: "must be a finite number > 0 (Pa)" });
        }
        if !(poisson > -1.0 && poisson < 0.5) {
            return Err(MaterialError { name: "poisson", value: poisson, allowed: "must lie in (-1, 0.5)" });
        }
        if !(density > 0.0 && density.is_finite()) {
            return Err(MaterialError {
                name: "density",
                value: density,
                allowed: "must be a finite number > 0 (kg/m^3)",
            });
        }
        Ok(Material { young, poisson, density })
    }

    /// Lamé parameters `(λ, μ)` in Pa.
    pub fn lame(&self) -> (f64, f64) {
        cleave_kernels::elasticity::lame(self.young, self.poisson)
    }
}
