//! A high-resolution surface embedded in the simulation mesh, with
//! collisions detected on its vertices (kaufmann2008 §9).
//!
//! **Nodal families** (martin2008 §7): each vertex is a fixed combination
//! of the shape functions of the element holding it, evaluated once at
//! rest ([`basis_map`]): the embedding reproduces every field the elements
//! can represent (linear fields exactly), and a vertex at a node follows
//! that node exactly.
//!
//! **Discontinuous Galerkin** (kaufmann2008 §8): the elements' fields jump
//! across faces, so the surface moves by moving least squares over the
//! stitched nodes ([`mls_map`]):
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

use rayon::prelude::*;

use super::PointMap;
use crate::mesh::PolyMesh;
use crate::param::ParamError;
use crate::store::harmonic::{winding_number, HarmonicOptions};
use crate::store::ElementStore;
use crate::Error;

/// A triangle surface embedded in the body, in rest coordinates (m).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
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
                                // p(x_i) centred on x, scaled by one length for
                                // all nodes (a scale per node would make the
                                // basis differ from node to node, and affine
                                // fields would no longer be reproduced)
                                let q = [1.0, (y[0] - x[0]) / reach, (y[1] - x[1]) / reach, (y[2] - x[2]) / reach];
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
            // p(x) centred on x is e₀: φ_i = θ_i e₀ᵀ A⁻¹ q_i, with A⁻¹ e₀
            // refused when A is (nearly) singular relative to its diagonal
            let scale = (0..4).map(|i| a[i][i].abs()).fold(0.0, f64::max);
            let e0 = [[1.0], [0.0], [0.0], [0.0]];
            let column = cleave_kernels::solve4::solve4(a, e0, 1e-10 * scale).map(|x| x.map(|r| r[0]));
            if let Some(c) = column.filter(|_| near.len() >= 4) {
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

/// The element holding each of `points` (rest frame): the candidate whose
/// boundary winds around the point most (1 inside, less on its boundary), among
/// the elements whose boxes hold it; `None` for a point in no element.
fn locate(mesh: &PolyMesh, points: &[[f64; 3]]) -> Vec<Option<u32>> {
    let n = mesh.elements.len();
    let boxes: Vec<([f64; 3], [f64; 3])> = (0..n)
        .map(|e| {
            let nodes = &mesh.elements[e].nodes;
            let lo = [0, 1, 2].map(|a| nodes.iter().map(|&v| mesh.nodes[v as usize][a]).fold(f64::INFINITY, f64::min));
            let hi =
                [0, 1, 2].map(|a| nodes.iter().map(|&v| mesh.nodes[v as usize][a]).fold(f64::NEG_INFINITY, f64::max));
            (lo, hi)
        })
        .collect();
    let cell =
        boxes.iter().map(|(lo, hi)| (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max)).sum::<f64>() / n.max(1) as f64;
    let key = |x: [f64; 3]| x.map(|v| (v / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (e, (lo, hi)) in boxes.iter().enumerate() {
        let (a, b) = (key(*lo), key(*hi));
        for i in a[0]..=b[0] {
            for j in a[1]..=b[1] {
                for k in a[2]..=b[2] {
                    grid.entry([i, j, k]).or_default().push(e as u32);
                }
            }
        }
    }
    let slack = 1e-9 * cell;
    points
        .par_iter()
        .map(|&x| {
            let candidates = grid.get(&key(x)).map_or(&[][..], |c| c.as_slice());
            let mut best: Option<(u32, f64)> = None;
            // a point at a node belongs to an element of that node
            if let Some(&e) = candidates
                .iter()
                .find(|&&e| mesh.elements[e as usize].nodes.iter().any(|&v| mesh.nodes[v as usize] == x))
            {
                return Some(e);
            }
            for &e in candidates {
                let (lo, hi) = boxes[e as usize];
                if (0..3).any(|a| x[a] < lo[a] - slack || x[a] > hi[a] + slack) {
                    continue;
                }
                let el = &mesh.elements[e as usize];
                let verts: Vec<[f64; 3]> = el.nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
                let local = |g: u32| el.nodes.binary_search(&g).map(|i| i as u32).unwrap_or(0);
                let triangles: Vec<[u32; 3]> = mesh.element_triangles(e as usize).map(|t| t.map(local)).collect();
                let w = winding_number(&verts, &triangles, x);
                if best.is_none_or(|(_, b)| w > b) {
                    best = Some((e, w));
                }
            }
            // inside: 1; on a face 1/2, an edge of a box 1/4, its corner
            // 1/8; outside: 0
            best.filter(|&(_, w)| w > 0.1).map(|(e, _)| e)
        })
        .collect()
}

/// The map from the nodes to `points` by the shape functions of the
/// elements holding them (see the module docs); a point outside the mesh
/// (a surface finer than a coarse mesh pokes out of it) is moved by
/// [`mls_map`] instead. `None` when the store's elements are not nodal
/// (discontinuous Galerkin).
pub fn basis_map(
    mesh: &PolyMesh,
    store: &ElementStore,
    harmonic: &HarmonicOptions,
    points: &[[f64; 3]],
) -> Result<Option<PointMap>, Error> {
    let owner = locate(mesh, points);
    let mut by_element: HashMap<u32, Vec<usize>> = HashMap::new();
    let mut outside: Vec<usize> = Vec::new();
    for (p, e) in owner.iter().enumerate() {
        match e {
            Some(e) => by_element.entry(*e).or_default().push(p),
            None => outside.push(p),
        }
    }
    let outside_points: Vec<[f64; 3]> = outside.iter().map(|&p| points[p]).collect();
    let mls = mls_map(mesh, &outside_points)?;
    let mut groups: Vec<(u32, Vec<usize>)> = by_element.into_iter().collect();
    groups.sort_unstable_by_key(|g| g.0);
    let values: Vec<Option<Vec<f64>>> = groups
        .par_iter()
        .map(|(e, ps)| {
            let xs: Vec<[f64; 3]> = ps.iter().map(|&p| points[p]).collect();
            store.shape_values(mesh, harmonic, *e as usize, &xs)
        })
        .collect::<Result<_, _>>()?;
    // where each point's row comes from: (group, place in it), or the MLS
    // row of an outside point
    enum Row {
        Element(usize, usize),
        Outside(usize),
    }
    let mut rows: Vec<Row> = (0..points.len()).map(|_| Row::Outside(0)).collect();
    for (g, (_, ps)) in groups.iter().enumerate() {
        for (i, &p) in ps.iter().enumerate() {
            rows[p] = Row::Element(g, i);
        }
    }
    for (i, &p) in outside.iter().enumerate() {
        rows[p] = Row::Outside(i);
    }
    let mut map = PointMap { offsets: vec![0], ..Default::default() };
    for row in &rows {
        match *row {
            Row::Element(g, i) => {
                let (e, ps) = &groups[g];
                let Some(v) = &values[g] else { return Ok(None) };
                for (a, &node) in mesh.elements[*e as usize].nodes.iter().enumerate() {
                    map.blocks.push(node);
                    map.weights.push(v[a * ps.len() + i]);
                }
            }
            Row::Outside(i) => {
                let (blocks, weights) = mls.row(i);
                map.blocks.extend_from_slice(blocks);
                map.weights.extend_from_slice(weights);
            }
        }
        map.offsets.push(map.blocks.len() as u32);
    }
    Ok(Some(map))
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
