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

/// Steps every body of `bodies` once, in parallel over the bodies, and
/// writes each body's [`StepStats`] into `stats` (one per body). Every body
/// is stepped (a failing one is left as its step left it); the failure of
/// the lowest index is returned. Nothing is allocated unless a body fails.
pub fn step_bodies(bodies: &mut [Simulation], stats: &mut [StepStats]) -> Result<(), BodyError> {
    assert_eq!(bodies.len(), stats.len(), "one StepStats per body");
    let failure = bodies
        .par_iter_mut()
        .zip(stats.par_iter_mut())
        .enumerate()
        .filter_map(|(body, (sim, stats))| match sim.step() {
            Ok(s) => {
                *stats = s;
                None
            }
            Err(error) => Some(BodyError { body, error }),
        })
        .min_by_key(|e| e.body);
    failure.map_or(Ok(()), Err)
}
