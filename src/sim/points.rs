//! Points driven by the unknowns: a sparse linear map from unknown blocks
//! to points, `x_p = Σ_i w_pi X_i`. For the nodal families it is the
//! identity (a node is its own block); for discontinuous Galerkin it
//! evaluates element polynomials at mesh nodes (the stitched field of
//! kaufmann2008 eq. 17) or at element vertices (collision points).

/// A sparse map from blocks to points (compressed rows).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PointMap {
    /// Row offsets into `blocks` and `weights`, one row per point.
    pub offsets: Vec<u32>,
    /// The blocks each point reads.
    pub blocks: Vec<u32>,
    /// Their weights.
    pub weights: Vec<f64>,
}

impl PointMap {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Whether the map has no point.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The blocks and weights of point `p`.
    pub fn row(&self, p: usize) -> (&[u32], &[f64]) {
        let (a, b) = (self.offsets[p] as usize, self.offsets[p + 1] as usize);
        (&self.blocks[a..b], &self.weights[a..b])
    }

    /// `out[p] = Σ_i w_pi values[i]` for every point (`out` resized).
    pub fn apply(&self, values: &[[f64; 3]], out: &mut Vec<[f64; 3]>) {
        out.clear();
        out.extend((0..self.len()).map(|p| {
            let (blocks, weights) = self.row(p);
            let mut s = [0.0; 3];
            for (&i, &w) in blocks.iter().zip(weights) {
                let v = values[i as usize];
                s = [s[0] + w * v[0], s[1] + w * v[1], s[2] + w * v[2]];
            }
            s
        }));
    }
}
