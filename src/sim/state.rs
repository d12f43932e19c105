//! The state of the nodes: displacement, position and velocity.

/// Per-node state of a body (one entry per mesh node).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct NodeState {
    /// Displacement from the rest position (m).
    pub displacement: Vec<[f64; 3]>,
    /// Current position `x0 + u` (m), kept in step with `displacement`.
    pub position: Vec<[f64; 3]>,
    /// Velocity (m/s).
    pub velocity: Vec<[f64; 3]>,
    /// Velocity of the step before (for the warm start of a step's solve).
    pub previous_velocity: Vec<[f64; 3]>,
}

impl NodeState {
    /// Nodes at rest at positions `rest` (m).
    pub fn at_rest(rest: &[[f64; 3]]) -> Self {
        let n = rest.len();
        NodeState {
            displacement: vec![[0.0; 3]; n],
            position: rest.to_vec(),
            velocity: vec![[0.0; 3]; n],
            previous_velocity: vec![[0.0; 3]; n],
        }
    }

    /// Recomputes the positions from the rest positions `rest` and the
    /// displacements.
    pub fn refresh_positions(&mut self, rest: &[[f64; 3]]) {
        self.position.clear();
        self.position.extend(rest.iter().zip(&self.displacement).map(|(x, u)| [x[0] + u[0], x[1] + u[1], x[2] + u[2]]));
    }

    /// Takes the velocities `v` (m/s, flat) of a step of `h` seconds:
    /// the old velocities become the previous ones, the displacements move
    /// by `h v`.
    pub fn integrate(&mut self, rest: &[[f64; 3]], v: &[f64], h: f64) {
        self.previous_velocity.copy_from_slice(&self.velocity);
        for (i, vi) in v.chunks_exact(3).enumerate() {
            let vi = [vi[0], vi[1], vi[2]];
            self.velocity[i] = vi;
            (0..3).for_each(|d| self.displacement[i][d] += h * vi[d]);
        }
        self.refresh_positions(rest);
    }
}
