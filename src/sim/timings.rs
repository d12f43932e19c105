//! Wall time per simulation phase.

use std::time::Instant;

/// The phases a simulation reports timings for: building element data, the
/// six phases of a step (see `step.rs`), topology changes and output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Basis functions, quadrature and element matrices.
    Basis,
    /// Step phase 1: element rotations and elastic forces.
    Forces,
    /// Step phase 2 (and pattern building): global assembly.
    Assembly,
    /// Step phase 3: masses, loads and penalty contacts.
    Contacts,
    /// Step phase 4: prescribed values.
    Constraints,
    /// Step phase 5: analysis, factorisation and solves.
    Solve,
    /// Step phase 6: the new velocities and positions.
    Integrate,
    /// Cuts, splits, merges and refinement.
    Topology,
    /// Writing frames and reports.
    Output,
}

/// Accumulated seconds per phase.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PhaseTimings {
    /// Basis functions, quadrature and element matrices (s).
    pub basis: f64,
    /// Rotations and elastic forces (s).
    pub forces: f64,
    /// Pattern and assembly (s).
    pub assembly: f64,
    /// Masses, loads and contacts (s).
    pub contacts: f64,
    /// Constraints (s).
    pub constraints: f64,
    /// Analysis, factorisation and solves (s).
    pub solve: f64,
    /// Integration (s).
    pub integrate: f64,
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
            Phase::Forces => &mut self.forces,
            Phase::Assembly => &mut self.assembly,
            Phase::Contacts => &mut self.contacts,
            Phase::Constraints => &mut self.constraints,
            Phase::Solve => &mut self.solve,
            Phase::Integrate => &mut self.integrate,
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

    /// The six phases of the steps (s).
    pub fn steps(&self) -> f64 {
        self.forces + self.assembly + self.contacts + self.constraints + self.solve + self.integrate
    }

    /// Sum over all phases (s).
    pub fn total(&self) -> f64 {
        self.basis + self.steps() + self.topology + self.output
    }
}
