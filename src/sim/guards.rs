//! Run guards: checks after every step that a run has not gone wrong
//! physically, with a diagnosis naming the step, the elements or nodes
//! involved, the quantity and its bound.
//!
//! Checked, in this order:
//!
//! 1. **non-finite state**: every position and velocity finite;
//! 2. **energy**: the mechanical energy `H = T + E_elastic + E_contact +
//!    V_gravity` ([`Simulation::mechanical_energy`]). Implicit Euler and
//!    damping only dissipate `H`, and the penalty colliders and gravity are
//!    inside it, so `H` may not grow past its reference by more than what
//!    the colliders supply plus `energy_growth` times the energy scale
//!    `|H_ref - V_ref| + M |g| L` (`M` the mass, `L` the rest bounding
//!    box's diagonal: what gravity can supply over the body's size). A
//!    penalty collider supplies energy when a point enters it: the step
//!    that carries the point to depth `d` applies no force yet (the active
//!    set is the step's start), so its spring `½ k d²` appears from
//!    nothing; the guards add that up, point entry by point entry. The
//!    reference is taken after the
//!    first step (prescribed displacements have then been applied) and
//!    again after every topology change (a cut's state transfer, or a
//!    refinement, moves energy by a small amount) or prescribed motion;
//! 3. **inversion**: the fraction of elements whose deformed volume (over
//!    their face triangles) is not positive;
//! 4. **stretch**: an element's deformed diameter over its rest diameter.
//!
//! A solve that fails (the iterative solver stagnating at its iteration
//! cap, a non-positive pivot) is reported by the step itself as an error;
//! the scene runner treats it as a guard that fires and stops, whatever
//! the mode, since there is no next state to go on with.

use super::diagnostics::ShapeExtremes;
use super::Simulation;
use crate::param::{positive, ParamError};

/// What a run does when a guard fires.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GuardMode {
    /// Stop with the diagnosis, keeping the last good state.
    #[default]
    Stop,
    /// Report the diagnosis and go on.
    Warn,
    /// Check nothing.
    Off,
}

/// The bounds the guards check.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GuardLimits {
    /// Growth of the mechanical energy allowed over its reference, as a
    /// fraction of the energy scale (see the module docs).
    pub energy_growth: f64,
    /// Fraction of inverted elements allowed (0 to 1).
    pub inverted_fraction: f64,
    /// Largest element stretch allowed (deformed over rest diameter).
    pub stretch: f64,
}

impl Default for GuardLimits {
    /// 10 % of the energy scale, 1 % of the elements inverted, a stretch
    /// of 5 (the shipped scenes stay below 1.6).
    fn default() -> Self {
        GuardLimits { energy_growth: 0.1, inverted_fraction: 0.01, stretch: 5.0 }
    }
}

impl GuardLimits {
    /// Checks every bound is finite and positive (and the fraction at most 1).
    pub fn check(&self) -> Result<(), ParamError> {
        positive("energy_growth", self.energy_growth, "must be finite and > 0")?;
        positive("inverted_fraction", self.inverted_fraction, "must be finite and > 0")?;
        if self.inverted_fraction > 1.0 {
            return Err(ParamError::new("inverted_fraction", self.inverted_fraction, "must be at most 1"));
        }
        positive("stretch", self.stretch, "must be finite and > 0")?;
        if self.stretch < 1.0 {
            return Err(ParamError::new("stretch", self.stretch, "must be at least 1 (the stretch of a rigid motion)"));
        }
        Ok(())
    }
}

/// A guard that fired: what, where, and the bound it crossed.
#[derive(Clone, Debug, PartialEq)]
pub struct GuardTrip {
    /// The step whose result was checked (1-based: the state after it).
    pub step: usize,
    /// The quantity checked.
    pub quantity: &'static str,
    /// Its value.
    pub value: f64,
    /// Its bound.
    pub bound: f64,
    /// The elements involved (at most eight).
    pub elements: Vec<usize>,
    /// The nodes involved (at most eight).
    pub nodes: Vec<usize>,
}

/// How many elements or nodes a diagnosis names at most.
pub const NAMED: usize = 8;

impl std::fmt::Display for GuardTrip {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "step {}: {} = {:.6e} beyond its bound {:.6e}", self.step, self.quantity, self.value, self.bound)?;
        if !self.elements.is_empty() {
            write!(f, "; elements {:?}", self.elements)?;
        }
        if !self.nodes.is_empty() {
            write!(f, "; nodes {:?}", self.nodes)?;
        }
        Ok(())
    }
}

/// The guards of one run: the limits and the energy reference.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Guards {
    /// The bounds.
    pub limits: GuardLimits,
    /// The energy reference `H_ref` (J) and its scale (J), once taken.
    reference: Option<(f64, f64)>,
    /// The energy the colliders supplied since the reference (J).
    supplied: f64,
    /// The collision points behind a collider at the last check (see
    /// [`Simulation::contact_depths`]), sorted.
    in_contact: Vec<usize>,
}

impl Guards {
    /// Guards with `limits`, their reference taken at the next check.
    pub fn new(limits: GuardLimits) -> Self {
        Guards { limits, reference: None, supplied: 0.0, in_contact: Vec::new() }
    }

    /// Takes the energy reference again at the next check (after a
    /// topology change or prescribed motion).
    pub fn rebase(&mut self) {
        self.reference = None;
        self.supplied = 0.0;
        self.in_contact.clear();
    }

    /// Checks the state `sim` reached after step `step`; returns the first
    /// guard that fires, in the order of the module docs.
    pub fn check(&mut self, sim: &Simulation, step: usize) -> Option<GuardTrip> {
        let trip = |quantity, value, bound, elements: Vec<usize>, nodes: Vec<usize>| GuardTrip {
            step,
            quantity,
            value,
            bound,
            elements,
            nodes,
        };
        let bad: Vec<usize> = (0..sim.positions().len())
            .filter(|&i| !(sim.positions()[i].iter().chain(&sim.velocities()[i]).all(|v| v.is_finite())))
            .take(NAMED)
            .collect();
        if !bad.is_empty() {
            return Some(trip(
                "non-finite position or velocity (count of nodes named)",
                bad.len() as f64,
                0.0,
                vec![],
                bad,
            ));
        }
        let energy = sim.mechanical_energy();
        let fresh = self.reference.is_none();
        let (reference, scale) = *self.reference.get_or_insert_with(|| (energy, energy_scale(sim, energy)));
        let (before, mut now) = (std::mem::take(&mut self.in_contact), Vec::new());
        sim.contact_depths(|p, depth, stiffness| {
            if !fresh && before.binary_search(&p).is_err() {
                self.supplied += 0.5 * stiffness * depth * depth;
            }
            now.push(p);
        });
        self.in_contact = now;
        let bound = reference + self.supplied + self.limits.energy_growth * scale;
        if !(energy <= bound) {
            let fastest = sim.max_node_speed().at;
            return Some(trip("mechanical energy (J)", energy, bound, vec![], vec![fastest]));
        }
        let shape = ShapeExtremes::of(sim);
        let elements = sim.mesh().elements.len().max(1);
        let fraction = shape.inverted_count as f64 / elements as f64;
        if fraction > self.limits.inverted_fraction {
            return Some(trip(
                "fraction of inverted elements",
                fraction,
                self.limits.inverted_fraction,
                shape.inverted,
                vec![],
            ));
        }
        if !(shape.stretch.value <= self.limits.stretch) {
            let e = shape.stretch.at;
            let nodes = sim.mesh().elements[e].nodes.iter().take(NAMED).map(|&v| v as usize).collect();
            return Some(trip(
                "element stretch (deformed / rest diameter)",
                shape.stretch.value,
                self.limits.stretch,
                vec![e],
                nodes,
            ));
        }
        None
    }
}

/// `|H - V| + M |g| L`: the kinetic, elastic and contact energy at the
/// reference, plus what gravity can supply over the body's size (J); one
/// joule times the mass where both vanish (a body at rest without gravity).
fn energy_scale(sim: &Simulation, energy: f64) -> f64 {
    let mass: f64 = sim.loads().iter().sum();
    let g = sim.params().gravity;
    let (lo, hi) = sim.mesh().bounding_box();
    let diagonal = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let gravity = mass * (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt() * diagonal;
    let scale = (energy - sim.gravity_energy()).abs() + gravity;
    if scale > 0.0 {
        scale
    } else {
        mass.max(f64::MIN_POSITIVE)
    }
}
