//! Boundary conditions: prescribed displacements (fixed regions and pinned
//! nodes) and penalty collision planes.

use std::collections::BTreeMap;

use crate::mesh::Plane;
use crate::param::{finite, non_negative, ParamError};

/// Nodes inside an axis-aligned box held at `u(x) = displacement + gradient x`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
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

    /// Checks the box (`min`, `max` finite, `min <= max`), `displacement`
    /// and `gradient` (finite).
    pub fn check(&self) -> Result<(), ParamError> {
        finite("min", self.min, "must be finite (m)")?;
        finite("max", self.max, "must be finite (m)")?;
        if (0..3).any(|i| self.min[i] > self.max[i]) {
            return Err(ParamError::new("max", self.max, format!("must be >= min = {:?} on every axis (m)", self.min)));
        }
        finite("displacement", self.displacement, "must be finite (m)")?;
        if !self.gradient.iter().flatten().all(|v| v.is_finite()) {
            return Err(ParamError::new("gradient", self.gradient, "must be finite"));
        }
        Ok(())
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

/// A penalty collision plane: nodes behind it are pushed out with force
/// `stiffness · depth` along its normal.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Collider {
    /// A point on the plane (m).
    pub point: [f64; 3],
    /// Unit normal, pointing into the free half-space.
    pub normal: [f64; 3],
    /// Penalty stiffness (N/m).
    pub stiffness: f64,
}

impl Collider {
    /// A plane collider; the normal is normalised, values are checked
    /// (`point`, `normal` as [`Plane::check`], `stiffness` finite `>= 0`).
    pub fn new(point: [f64; 3], normal: [f64; 3], stiffness: f64) -> Result<Self, ParamError> {
        Plane { point, normal }.check()?;
        non_negative("stiffness", stiffness, "must be a finite number >= 0 (N/m)")?;
        let len = (normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2]).sqrt();
        Ok(Collider { point, normal: normal.map(|x| x / len), stiffness })
    }

    /// Penetration depth of position `x` (m, positive behind the plane).
    pub fn depth(&self, x: [f64; 3]) -> f64 {
        (0..3).map(|i| (self.point[i] - x[i]) * self.normal[i]).sum()
    }
}

/// Everything that holds or pushes the body.
#[derive(Clone, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct Boundary {
    /// Dirichlet regions; a later one wins where they overlap.
    pub fixed: Vec<FixedRegion>,
    /// Nodes held at a displacement, overriding the regions.
    pub pinned: BTreeMap<u32, [f64; 3]>,
    /// Penalty planes.
    pub colliders: Vec<Collider>,
    /// A body force density besides gravity: a closure, which no
    /// checkpoint can hold, so it is not serialized (see
    /// [`crate::checkpoint`], which refuses a body with one).
    #[serde(skip)]
    pub body: Option<super::body_force::BodyForce>,
}

impl Boundary {
    /// Calls `hold(node, u)` for every prescribed node with its target
    /// displacement `u` (m): nodes without mass (of no element) at their
    /// current displacement, so the system stays regular; nodes in a fixed
    /// region at the region's value (the last region holding the node);
    /// then the pinned nodes, which may repeat a node and then win.
    pub fn prescribe(
        &self,
        rest: &[[f64; 3]],
        masses: &[f64],
        displacement: &[[f64; 3]],
        mut hold: impl FnMut(usize, [f64; 3]),
    ) {
        for (i, x) in rest.iter().enumerate() {
            if !(masses[i] > 0.0) {
                hold(i, displacement[i]);
            } else if let Some(r) = self.fixed.iter().rev().find(|r| r.contains(*x)) {
                hold(i, r.value(*x));
            }
        }
        for (&i, u) in &self.pinned {
            hold(i as usize, *u);
        }
    }
}
