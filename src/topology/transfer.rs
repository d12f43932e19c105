//! Carrying the state of the nodes across a topology change.
//!
//! A cut moves no node and changes no velocity: every node it makes takes
//! the state its parents give it (a node on an edge the linear
//! interpolation along the edge, where the displacement field is linear; a
//! pocket node the mean of the face it sits on; a duplicated node a copy of
//! its original), [`NodeOrigins::extend`]. The lumped masses of the nodes of
//! the changed elements change with them, which would change the momentum
//! `Σ m v` and the angular momentum `Σ m x × v` of a free body;
//! [`conserve_momentum`] restores both exactly (to rounding) by the
//! smallest rigid velocity correction of those nodes.

use cleave_kernels::vec3::{add, cross, dot, scale, sub};

use super::{CutReport, PolygonCutReport};

/// How the nodes a topology change made get their state: each is a
/// weighted sum of nodes that existed before it, in increasing id order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NodeOrigins {
    /// First new node id (the node count before the change).
    pub first: u32,
    /// Parents and weights of every new node, in id order from `first`.
    pub parents: Vec<Vec<(u32, f64)>>,
}

impl NodeOrigins {
    /// The origins of the nodes a plane cut made (edge nodes, then
    /// duplicates).
    pub fn of_cut(report: &CutReport) -> Result<Self, String> {
        Self::of_made(report, None)
    }

    /// The origins of the nodes a polygon cut made: edge nodes, the pocket
    /// node, then duplicates.
    pub fn of_polygon_cut(report: &PolygonCutReport) -> Result<Self, String> {
        Self::of_made(&report.cut, report.pocket.as_ref())
    }

    /// The origins of a cut's edge nodes and duplicates, and of its pocket
    /// node (placed among face vertices) if it made one; an error when the
    /// report's new nodes are not numbered in order from the node count
    /// before the cut, each from earlier nodes.
    fn of_made(cut: &CutReport, pocket: Option<&(u32, Vec<u32>)>) -> Result<Self, String> {
        let mut made: Vec<(u32, Vec<(u32, f64)>)> =
            cut.split.new_nodes.iter().map(|nn| (nn.id, vec![(nn.a, 1.0 - nn.t), (nn.b, nn.t)])).collect();
        if let Some((id, around)) = pocket {
            made.push((*id, around.iter().map(|&v| (v, 1.0 / around.len() as f64)).collect()));
        }
        made.extend(cut.duplicated.iter().map(|&(original, copy)| (copy, vec![(original, 1.0)])));
        made.sort_by_key(|(id, _)| *id);
        let first = cut.nodes_before;
        for (k, (id, parents)) in made.iter().enumerate() {
            if *id != first + k as u32 || parents.iter().any(|&(p, _)| p >= *id) {
                return Err(format!("new node {id} is out of order or made from a later node"));
            }
        }
        Ok(NodeOrigins { first, parents: made.into_iter().map(|(_, p)| p).collect() })
    }

    /// Number of nodes after the change.
    pub fn len(&self) -> usize {
        self.first as usize + self.parents.len()
    }

    /// Whether the change made no node.
    pub fn is_empty(&self) -> bool {
        self.parents.is_empty()
    }

    /// Appends the value of every new node to `values` (one per node before
    /// the change).
    pub fn extend(&self, values: &mut Vec<[f64; 3]>) {
        assert_eq!(values.len(), self.first as usize, "values must cover the nodes before the change");
        for parents in &self.parents {
            let value = parents.iter().fold([0.0; 3], |m, &(p, w)| add(m, scale(values[p as usize], w)));
            values.push(value);
        }
    }
}

/// Linear momentum `Σ m v` (kg m/s) and angular momentum `Σ m x × v`
/// about the origin (kg m²/s) of the listed nodes.
pub fn momenta(nodes: &[u32], mass: &[f64], x: &[[f64; 3]], v: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let (mut p, mut l) = ([0.0; 3], [0.0; 3]);
    for &i in nodes {
        let (m, xi, vi) = (mass[i as usize], x[i as usize], v[i as usize]);
        p = add(p, scale(vi, m));
        l = add(l, scale(cross(xi, vi), m));
    }
    (p, l)
}

/// Restores the momenta `before` (from [`momenta`] of the changed nodes
/// with their old masses and velocities) on the `nodes` whose masses
/// changed (sorted, new masses `mass`, positions `x`), by adding the rigid
/// velocity field `a + ω × (x - c)` of least kinetic energy: `c` the
/// nodes' centre of mass, `a = ΔP / M`, `ω = I⁻¹ (ΔL - c × ΔP)` with `I`
/// their inertia tensor about `c`. Where `I` is singular (collinear nodes)
/// only the linear momentum is restored.
pub fn conserve_momentum(
    nodes: &[u32],
    mass: &[f64],
    x: &[[f64; 3]],
    v: &mut [[f64; 3]],
    before: ([f64; 3], [f64; 3]),
) {
    let total: f64 = nodes.iter().map(|&i| mass[i as usize]).sum();
    if !(total > 0.0) {
        return;
    }
    let (p, l) = momenta(nodes, mass, x, v);
    let (dp, dl) = (sub(before.0, p), sub(before.1, l));
    let c = scale(nodes.iter().fold([0.0; 3], |s, &i| add(s, scale(x[i as usize], mass[i as usize]))), 1.0 / total);
    let mut inertia = [[0.0; 3]; 3];
    for &i in nodes {
        let (m, r) = (mass[i as usize], sub(x[i as usize], c));
        let rr = dot(r, r);
        for a in 0..3 {
            for b in 0..3 {
                inertia[a][b] += m * (if a == b { rr } else { 0.0 } - r[a] * r[b]);
            }
        }
    }
    let a = scale(dp, 1.0 / total);
    let rhs = sub(dl, cross(c, dp));
    let omega = solve3(inertia, rhs).unwrap_or([0.0; 3]);
    for &i in nodes {
        let r = sub(x[i as usize], c);
        v[i as usize] = add(v[i as usize], add(a, cross(omega, r)));
    }
}

/// `M⁻¹ b` for a symmetric 3x3 `M` by its adjugate, or `None` when `M` is
/// (nearly) singular.
fn solve3(m: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let c = [
        [
            m[1][1] * m[2][2] - m[1][2] * m[2][1],
            m[0][2] * m[2][1] - m[0][1] * m[2][2],
            m[0][1] * m[1][2] - m[0][2] * m[1][1],
        ],
        [
            m[1][2] * m[2][0] - m[1][0] * m[2][2],
            m[0][0] * m[2][2] - m[0][2] * m[2][0],
            m[0][2] * m[1][0] - m[0][0] * m[1][2],
        ],
        [
            m[1][0] * m[2][1] - m[1][1] * m[2][0],
            m[0][1] * m[2][0] - m[0][0] * m[2][1],
            m[0][0] * m[1][1] - m[0][1] * m[1][0],
        ],
    ];
    let det = m[0][0] * c[0][0] + m[0][1] * c[1][0] + m[0][2] * c[2][0];
    let trace = m[0][0] + m[1][1] + m[2][2];
    if !(det > 1e-12 * trace * trace * trace) {
        return None;
    }
    Some(std::array::from_fn(|r| (c[r][0] * b[0] + c[r][1] * b[1] + c[r][2] * b[2]) / det))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rigid_correction_restores_both_momenta() {
        let x = vec![[0.0, 0.0, 0.0], [1.0, 0.2, 0.0], [0.3, 1.0, 0.1], [0.2, 0.1, 0.9], [0.7, 0.7, 0.7]];
        let v = vec![[0.1, 0.0, -0.3], [0.5, 0.2, 0.0], [-0.2, 0.4, 0.1], [0.0, 0.0, 0.3], [0.3, -0.1, 0.2]];
        let old_mass = [1.0, 2.0, 1.5, 0.7, 1.1];
        let nodes: Vec<u32> = (0..5).collect();
        let before = momenta(&nodes, &old_mass, &x, &v);
        let new_mass = [1.2, 1.7, 1.5, 0.9, 1.0];
        let mut w = v.clone();
        conserve_momentum(&nodes, &new_mass, &x, &mut w, before);
        let after = momenta(&nodes, &new_mass, &x, &w);
        for i in 0..3 {
            assert!((after.0[i] - before.0[i]).abs() < 1e-14, "{after:?} vs {before:?}");
            assert!((after.1[i] - before.1[i]).abs() < 1e-14, "{after:?} vs {before:?}");
        }
    }

    #[test]
    fn new_nodes_interpolate_their_parents() {
        let origins = NodeOrigins { first: 2, parents: vec![vec![(0, 0.25), (1, 0.75)], vec![(2, 1.0)]] };
        let mut values = vec![[0.0, 4.0, 8.0], [4.0, 0.0, 0.0]];
        origins.extend(&mut values);
        assert_eq!(values[2], [3.0, 1.0, 2.0]);
        assert_eq!(values[3], values[2]);
    }
}
