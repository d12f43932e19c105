//! A high-resolution surface embedded in the simulation mesh and moved by
//! moving least squares (kaufmann2008 §8), with collisions detected on its
//! vertices (§9).
//!
//! At a material point `x`, the displacement is the affine field fitted to
//! the nodes' displacements `ũ_i` (the stitched field for DG) by weighted
//! least squares, `min Σ_i θ_i(x) |a(x)ᵀ p(x_i) - ũ_i|²` with
//! `p = (1, x, y, z)` and truncated Gaussians `θ_i(d) = exp(-(d/h_i)²)` for
//! `d < 2.5 h_i`, `h_i` the mean distance from node `i` to the nodes of its
//! elements (the local sampling density). The solution is linear in the
//! `ũ_i`: `ũ(x) = Σ_i φ_i(x) ũ_i` with `φ_i = θ_i p(x)ᵀ A(x)⁻¹ p(x_i)` and
//! `A = Σ_i θ_i p(x_i) p(x_i)ᵀ`, so that affine fields (rigid motions among
//! them) are reproduced exactly. The weights are computed once per
//! topology and composed with the map from the unknowns to the nodes: each
//! frame's surface is one sparse product.

use std::collections::HashMap;

use super::PointMap;
use crate::mesh::PolyMesh;
use crate::param::ParamError;

/// A triangle surface embedded in the body, in rest coordinates (m).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EmbeddedSurface {
    /// Vertex positions at rest (m).
    pub vertices: Vec<[f64; 3]>,
    /// Triangles over the vertices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

/// How far a Gaussian reaches, in units of its node's spacing.
const CUTOFF: f64 = 2.5;

/// The mean distance from every node to the other nodes of its elements
/// (m); nodes of no element get the mesh's mean.
fn spacings(mesh: &PolyMesh) -> Vec<f64> {
    let (mut sum, mut count) = (vec![0.0; mesh.nodes.len()], vec![0u32; mesh.nodes.len()]);
    for el in &mesh.elements {
        for &a in &el.nodes {
            for &b in &el.nodes {
                if a != b {
                    let (p, q) = (mesh.nodes[a as usize], mesh.nodes[b as usize]);
                    sum[a as usize] += ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
                    count[a as usize] += 1;
                }
            }
        }
    }
    let used: Vec<f64> = sum.iter().zip(&count).filter(|(_, &c)| c > 0).map(|(s, &c)| s / c as f64).collect();
    let mean = used.iter().sum::<f64>() / used.len().max(1) as f64;
    sum.iter().zip(&count).map(|(s, &c)| if c > 0 { s / c as f64 } else { mean }).collect()
}

/// Solves the symmetric 4 x 4 system `a c = e₀` by Gaussian elimination
/// with partial pivoting; `None` when `a` is (nearly) singular relative to
/// its diagonal.
fn first_column_of_inverse(mut a: [[f64; 4]; 4]) -> Option<[f64; 4]> {
    let scale = (0..4).map(|i| a[i][i].abs()).fold(0.0, f64::max);
    let mut b = [1.0, 0.0, 0.0, 0.0];
    for col in 0..4 {
        let pivot = (col..4).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if !(a[pivot][col].abs() > 1e-10 * scale) {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        for row in col + 1..4 {
            let f = a[row][col] / a[col][col];
            for k in col..4 {
                a[row][k] -= f * a[col][k];
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = [0.0; 4];
    for row in (0..4).rev() {
        let s: f64 = (row + 1..4).map(|j| a[row][j] * x[j]).sum();
        x[row] = (b[row] - s) / a[row][row];
    }
    Some(x)
}

/// The MLS shape functions of `points` over the mesh nodes: a point map
/// from nodes to points (see the module docs). A point where no four
/// nodes in reach span space even with the reach grown eight times is an
/// error naming it.
pub fn mls_map(mesh: &PolyMesh, points: &[[f64; 3]]) -> Result<PointMap, ParamError> {
    let h = spacings(mesh);
    let reach = h.iter().fold(0.0f64, |m, &v| m.max(v)) * CUTOFF;
    // a uniform grid of the nodes, cells as large as the largest reach
    let cell = |x: [f64; 3]| -> [i64; 3] { x.map(|v| (v / reach).floor() as i64) };
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (i, y) in mesh.nodes.iter().enumerate() {
        grid.entry(cell(*y)).or_default().push(i as u32);
    }
    let mut map = PointMap { offsets: vec![0], ..Default::default() };
    let mut near: Vec<(u32, f64, [f64; 4])> = Vec::new();
    for (p, &x) in points.iter().enumerate() {
        let centre = cell(x);
        let mut grow = 1.0f64;
        loop {
            // every node within `grow` reaches lies in these cells
            let r = grow.ceil() as i64;
            near.clear();
            for dx in -r..=r {
                for dy in -r..=r {
                    for dz in -r..=r {
                        let Some(nodes) = grid.get(&[centre[0] + dx, centre[1] + dy, centre[2] + dz]) else { continue };
                        for &i in nodes {
                            let y = mesh.nodes[i as usize];
                            let d = ((y[0] - x[0]).powi(2) + (y[1] - x[1]).powi(2) + (y[2] - x[2]).powi(2)).sqrt();
                            let hi = h[i as usize] * grow;
                            if d < CUTOFF * hi {
                                // p(x_i) centred on x and scaled by the spacing
                                let q = [1.0, (y[0] - x[0]) / hi, (y[1] - x[1]) / hi, (y[2] - x[2]) / hi];
                                near.push((i, (-(d / hi).powi(2)).exp(), q));
                            }
                        }
                    }
                }
            }
            near.sort_by_key(|n| n.0);
            let mut a = [[0.0; 4]; 4];
            for (_, w, q) in &near {
                for r in 0..4 {
                    for c in 0..4 {
                        a[r][c] += w * q[r] * q[c];
                    }
                }
            }
            // p(x) centred on x is e₀: φ_i = θ_i e₀ᵀ A⁻¹ q_i
            if let Some(c) = first_column_of_inverse(a).filter(|_| near.len() >= 4) {
                for (i, w, q) in &near {
                    map.blocks.push(*i);
                    map.weights.push(w * (c[0] * q[0] + c[1] * q[1] + c[2] * q[2] + c[3] * q[3]));
                }
                map.offsets.push(map.blocks.len() as u32);
                break;
            }
            grow *= 2.0;
            if grow > 8.0 {
                let allowed = "must lie within reach of four nodes that span space";
                return Err(ParamError::new("embedded vertex", format!("{p} at {x:?}"), allowed));
            }
        }
    }
    Ok(map)
}

/// `outer ∘ inner`: the map from `inner`'s blocks to `outer`'s points.
pub fn compose(outer: &PointMap, inner: &PointMap) -> PointMap {
    let mut out = PointMap { offsets: vec![0], ..Default::default() };
    let mut row: HashMap<u32, f64> = HashMap::new();
    for p in 0..outer.len() {
        row.clear();
        let (mid, w) = outer.row(p);
        for (&m, &wm) in mid.iter().zip(w) {
            let (blocks, wb) = inner.row(m as usize);
            for (&b, &w2) in blocks.iter().zip(wb) {
                *row.entry(b).or_insert(0.0) += wm * w2;
            }
        }
        let mut entries: Vec<(u32, f64)> = row.iter().map(|(&b, &w)| (b, w)).collect();
        entries.sort_by_key(|e| e.0);
        for (b, w) in entries {
            out.blocks.push(b);
            out.weights.push(w);
        }
        out.offsets.push(out.blocks.len() as u32);
    }
    out
}
