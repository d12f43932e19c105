//! Wall time per simulation phase.

use std::time::Instant;

/// The phases a simulation reports timings for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Basis functions, quadrature and element matrices.
    Basis,
    /// Element rotations and elastic forces (stiffness warping).
    Rotation,
    /// Pattern building and global assembly.
    Assembly,
    /// Factorisation and solves.
    Solve,
    /// Cuts, splits, merges and refinement.
    Topology,
    /// Writing frames and reports.
    Output,
}

/// Accumulated seconds per phase.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct PhaseTimings {
    /// Basis functions, quadrature and element matrices (s).
    pub basis: f64,
    /// Rotations and elastic forces (s).
    pub rotation: f64,
    /// Pattern and assembly (s).
    pub assembly: f64,
    /// Factorisation and solves (s).
    pub solve: f64,
    /// Topology changes (s).
    pub topology: f64,
    /// Output (s).
    pub output: f64,
}

impl PhaseTimings {
    /// Adds `seconds` to `phase`.
    pub fn add(&mut self, phase: Phase, seconds: f64) {
        *match phase {
            Phase::Basis => &mut self.basis,
            Phase::Rotation => &mut self.rotation,
            Phase::Assembly => &mut self.assembly,
            Phase::Solve => &mut self.solve,
            Phase::Topology => &mut self.topology,
            Phase::Output => &mut self.output,
        } += seconds;
    }

    /// Runs `f`, adding its wall time to `phase`.
    pub fn time<T>(&mut self, phase: Phase, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let out = f();
        self.add(phase, t.elapsed().as_secs_f64());
        out
    }

    /// Sum over all phases (s).
    pub fn total(&self) -> f64 {
        self.basis + self.rotation + self.assembly + self.solve + self.topology + self.output
    }
}
