//! Many independent bodies stepped together: one body per task, each
//! stepped exactly as alone (its own loops run on the same pool), so the
//! results equal stepping the bodies one by one, bit for bit.

use rayon::prelude::*;

use super::{Simulation, StepStats};
use crate::Error;

/// A body of a set that failed to step: its index in the set and why.
#[derive(Debug)]
pub struct BodyError {
    /// The body's index in the slice given to [`step_bodies`].
    pub body: usize,
    /// Its error (naming the step).
    pub error: Error,
}

impl std::fmt::Display for BodyError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "body {}: {}", self.body, self.error)
    }
}

impl std::error::Error for BodyError {}

/// Steps every body of `bodies` once, in parallel over the bodies. Every
/// body is stepped (a failing one is left as its step left it); the first
/// failure by index is returned.
pub fn step_bodies(bodies: &mut [Simulation]) -> Result<Vec<StepStats>, BodyError> {
    let results: Vec<Result<StepStats, Error>> = bodies.par_iter_mut().map(Simulation::step).collect();
    let mut stats = Vec::with_capacity(results.len());
    for (body, r) in results.into_iter().enumerate() {
        stats.push(r.map_err(|error| BodyError { body, error })?);
    }
    Ok(stats)
}
