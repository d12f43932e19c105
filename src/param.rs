//! A parameter outside its allowed range: one error type for every layer
//! that checks its inputs (material, simulation, colliders, fixed regions,
//! basis options), naming the parameter in the engine's terms. A scene maps
//! the name to its key and line.

use thiserror::Error;

/// A parameter outside its allowed range.
#[derive(Clone, Debug, Error, PartialEq)]
#[error("{name} = {value}: {allowed}")]
pub struct ParamError {
    /// The parameter, as the engine names it (`young`, `dt`, ...).
    pub name: &'static str,
    /// The rejected value, printed.
    pub value: String,
    /// What is allowed, with the unit.
    pub allowed: String,
}

impl ParamError {
    /// `name = value` is outside `allowed`.
    pub fn new(name: &'static str, value: impl std::fmt::Debug, allowed: impl Into<String>) -> Self {
        ParamError { name, value: format!("{value:?}"), allowed: allowed.into() }
    }
}

/// `Err` unless `v` is finite and `> 0`.
pub(crate) fn positive(name: &'static str, v: f64, allowed: &'static str) -> Result<f64, ParamError> {
    if v > 0.0 && v.is_finite() {
        Ok(v)
    } else {
        Err(ParamError::new(name, v, allowed))
    }
}

/// `Err` unless `v` is finite and `>= 0`.
pub(crate) fn non_negative(name: &'static str, v: f64, allowed: &'static str) -> Result<f64, ParamError> {
    if v >= 0.0 && v.is_finite() {
        Ok(v)
    } else {
        Err(ParamError::new(name, v, allowed))
    }
}

/// `Err` unless every component of `v` is finite.
pub(crate) fn finite<const N: usize>(
    name: &'static str,
    v: [f64; N],
    allowed: &'static str,
) -> Result<[f64; N], ParamError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(ParamError::new(name, v, allowed))
    }
}
