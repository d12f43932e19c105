//! The element store: elements batched by vertex count, structure of arrays.
//!
//! A [`Batch`] holds every element with the same number of nodes `k` and
//! keeps, per element, flat arrays of fixed stride: node ids (`k`), gathered
//! rest positions (`k`), volume, lumped mass fractions (`k`), the element
//! stiffness `K_e` (`9 k^2`, row-major `3k x 3k`) and the shape function
//! gradients at the element's stress point (`k`). Kernels run over a batch
//! as over plain slices; a batch is rebuilt alone when its elements change.
//!
//! Tetrahedra form the `k = 4` batch and use the closed form ([`tet`]); all
//! other convex elements use mean value shape functions ([`mean_value`]).

mod mean_value;
mod tet;

use thiserror::Error;

use crate::material::Material;
use crate::mesh::PolyMesh;

/// An element the basis cannot be built on.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum BasisError {
    /// The mean value family needs convex elements.
    #[error("element {element} is not convex; mean value elements must be convex (use family = \"harmonic\")")]
    NonConvex { element: usize },
    /// More vertices than the kernels accept.
    #[error("element {element} has {vertices} vertices; at most {max} are supported")]
    TooManyVertices { element: usize, vertices: usize, max: usize },
    /// The element is flat or inverted at rest.
    #[error("element {element} is degenerate (volume {volume:.3e} m^3)")]
    DegenerateElement { element: usize, volume: f64 },
}

/// All elements with `k` nodes, as structure of arrays.
#[derive(Clone, Debug, Default)]
pub struct Batch {
    /// Nodes per element.
    pub k: usize,
    /// Mesh element id of each batch entry.
    pub elements: Vec<u32>,
    /// Node ids, `k` per element (element-local order).
    pub nodes: Vec<u32>,
    /// Rest positions (m), `k` per element.
    pub rest: Vec<[f64; 3]>,
    /// Rest volume (m^3), one per element.
    pub volume: Vec<f64>,
    /// Lumped mass fraction of each node, `k` per element, summing to 1.
    pub mass_fraction: Vec<f64>,
    /// Element stiffness (N/m), `9 k^2` per element, row-major `3k x 3k`
    /// (empty for tetrahedra, whose blocks come from their gradients).
    pub stiffness: Vec<f64>,
    /// Lamé parameters `(λ, μ)` of the batch's material (Pa).
    pub lame: (f64, f64),
    /// Shape function gradients at the stress point (1/m), `k` per element.
    pub stress_grads: Vec<[f64; 3]>,
    /// Surface triangles in local indices, outward, `2k - 4` per element
    /// (empty for the closed-form tetrahedra).
    pub triangles: Vec<[u32; 3]>,
    /// Quadrature points (m), `points_per_element` per element.
    pub points: Vec<[f64; 3]>,
    /// Quadrature weights (m^3), `points_per_element` per element.
    pub weights: Vec<f64>,
    /// Quadrature points per element.
    pub points_per_element: usize,
}

impl Batch {
    /// Number of elements in the batch.
    pub fn len(&self) -> usize {
        self.elements.len()
    }

    /// Whether the batch is empty.
    pub fn is_empty(&self) -> bool {
        self.elements.is_empty()
    }

    /// Node ids of batch entry `i`.
    pub fn element_nodes(&self, i: usize) -> &[u32] {
        &self.nodes[i * self.k..(i + 1) * self.k]
    }

    /// Whether the batch holds closed-form linear tetrahedra.
    pub fn is_tet(&self) -> bool {
        self.stiffness.is_empty()
    }

    /// The row-major 3x3 block `K_ab` (N/m) of entry `i`: for tetrahedra
    /// `V (λ g_a g_bᵀ + μ g_b g_aᵀ + μ (g_a · g_b) I)`, otherwise read from
    /// the stored `K_e`.
    #[inline]
    pub fn block(&self, i: usize, a: usize, b: usize) -> [f64; 9] {
        let k = self.k;
        if self.is_tet() {
            let g = &self.stress_grads[i * k..(i + 1) * k];
            let mut out = [0.0; 9];
            cleave_kernels::elasticity::add_block(&mut out, g[a], g[b], self.volume[i], self.lame.0, self.lame.1);
            return out;
        }
        let ke = &self.stiffness[i * 9 * k * k..(i + 1) * 9 * k * k];
        let n = 3 * k;
        std::array::from_fn(|rc| ke[(3 * a + rc / 3) * n + 3 * b + rc % 3])
    }

    /// The blocks `K_ab` of entry `i` for all `a` and the given `b`.
    pub fn block_column(&self, i: usize, b: usize, out: &mut [[f64; 9]]) {
        for (a, o) in out.iter_mut().enumerate() {
            *o = self.block(i, a, b);
        }
    }

    /// The dense row-major `3k x 3k` element stiffness `K_e` of entry `i`.
    pub fn element_matrix(&self, i: usize) -> Vec<f64> {
        let (k, n) = (self.k, 3 * self.k);
        let mut ke = vec![0.0; n * n];
        for a in 0..k {
            for b in 0..k {
                let blk = self.block(i, a, b);
                for r in 0..3 {
                    ke[(3 * a + r) * n + 3 * b..(3 * a + r) * n + 3 * b + 3].copy_from_slice(&blk[3 * r..3 * r + 3]);
                }
            }
        }
        ke
    }

    /// `K_e u` for entry `i` and element-local displacements `u` (`k`
    /// 3-vectors, m): forces in N.
    pub fn apply_stiffness(&self, i: usize, u: &[[f64; 3]], out: &mut [[f64; 3]]) {
        let k = self.k;
        for (a, o) in out.iter_mut().enumerate().take(k) {
            let mut f = [0.0; 3];
            for (b, ub) in u.iter().enumerate().take(k) {
                let blk = self.block(i, a, b);
                for r in 0..3 {
                    f[r] += blk[3 * r] * ub[0] + blk[3 * r + 1] * ub[1] + blk[3 * r + 2] * ub[2];
                }
            }
            *o = f;
        }
    }
}

/// How mean value elements are integrated (wicke2007 §3.4 and beyond).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum QuadratureRule {
    /// The paper's points and weights with the per-element gradient
    /// correction that makes the discrete divergence theorem exact, so the
    /// patch test passes (default).
    #[default]
    Consistent,
    /// The paper's heuristic rule as printed (fails the patch test slightly).
    Paper,
    /// Gauss–Legendre on the sub-tetrahedra from the centroid, `n^3` points
    /// per surface triangle (slow; a reference for tests).
    Reference(usize),
}

/// Options of the basis construction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BasisOptions {
    /// Quadrature of mean value elements.
    pub quadrature: QuadratureRule,
}

/// Every element of a mesh, batched by vertex count.
#[derive(Clone, Debug, Default)]
pub struct ElementStore {
    /// Batches in increasing `k`.
    pub batches: Vec<Batch>,
    /// For each mesh element: `(batch, index in batch)`.
    pub locate: Vec<(u32, u32)>,
}

impl ElementStore {
    /// Builds the store: gathers every element into its batch and computes
    /// volumes, mass fractions, `K_e` and stress-point gradients.
    pub fn build(mesh: &PolyMesh, material: &Material, options: &BasisOptions) -> Result<Self, BasisError> {
        let mut by_k: std::collections::BTreeMap<usize, Vec<u32>> = Default::default();
        for (e, el) in mesh.elements.iter().enumerate() {
            by_k.entry(el.nodes.len()).or_default().push(e as u32);
        }
        let mut store = ElementStore { batches: Vec::new(), locate: vec![(0, 0); mesh.elements.len()] };
        for (b, (k, elements)) in by_k.into_iter().enumerate() {
            for (i, &e) in elements.iter().enumerate() {
                store.locate[e as usize] = (b as u32, i as u32);
            }
            let batch = if k == 4 {
                tet::build_batch(mesh, material, elements)?
            } else {
                mean_value::build_batch(mesh, material, options.quadrature, k, elements)?
            };
            store.batches.push(batch);
        }
        Ok(store)
    }

    /// Lumped nodal masses (kg): `m_i = Σ_e μ_i^e V_e ρ` (wicke2007 eq. 18).
    pub fn lumped_masses(&self, num_nodes: usize, density: f64) -> Vec<f64> {
        let mut m = vec![0.0; num_nodes];
        for b in &self.batches {
            for i in 0..b.len() {
                for a in 0..b.k {
                    m[b.nodes[i * b.k + a] as usize] += b.mass_fraction[i * b.k + a] * b.volume[i] * density;
                }
            }
        }
        m
    }

    /// Total rest volume (m^3).
    pub fn total_volume(&self) -> f64 {
        self.batches.iter().flat_map(|b| b.volume.iter()).sum()
    }

    /// Displacement gradient `∂u_i/∂x_j` at the stress point of every element
    /// (by mesh element id), from nodal displacements `u` (m).
    pub fn displacement_gradients(&self, u: &[[f64; 3]]) -> Vec<[[f64; 3]; 3]> {
        let mut out = vec![[[0.0; 3]; 3]; self.locate.len()];
        for b in &self.batches {
            for i in 0..b.len() {
                let mut g = [[0.0; 3]; 3];
                for a in 0..b.k {
                    let ua = u[b.nodes[i * b.k + a] as usize];
                    let ga = b.stress_grads[i * b.k + a];
                    for r in 0..3 {
                        for c in 0..3 {
                            g[r][c] += ua[r] * ga[c];
                        }
                    }
                }
                out[b.elements[i] as usize] = g;
            }
        }
        out
    }
}
