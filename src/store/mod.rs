//! The element store: elements batched by vertex count, structure of arrays.
//!
//! A [`Batch`] holds every element with the same number of nodes `k` and
//! keeps, per element, flat arrays of fixed stride: node ids (`k`), gathered
//! rest positions (`k`), volume, lumped mass fractions (`k`), the element
//! stiffness `K_e` (`9 k^2`, row-major `3k x 3k`) and the shape function
//! gradients at the element's stress point (`k`). Kernels run over a batch
//! as over plain slices; a batch is rebuilt alone when its elements change.

use rayon::prelude::*;
use thiserror::Error;

use crate::material::Material;
use crate::mesh::PolyMesh;

/// An element the basis cannot be built on.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum BasisError {
    /// No basis family handles this element yet.
    #[error("element {element} has {vertices} vertices and {faces} faces; only linear tetrahedra are supported by this build")]
    UnsupportedElement {
        element: usize,
        vertices: usize,
        faces: usize,
    },
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
    /// Element stiffness (N/m), `9 k^2` per element, row-major `3k x 3k`.
    pub stiffness: Vec<f64>,
    /// Shape function gradients at the stress point (1/m), `k` per element.
    pub stress_grads: Vec<[f64; 3]>,
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

    /// Stiffness of batch entry `i`.
    pub fn element_stiffness(&self, i: usize) -> &[f64] {
        let s = 9 * self.k * self.k;
        &self.stiffness[i * s..(i + 1) * s]
    }
}

/// Every element of a mesh, batched by vertex count.
#[derive(Clone, Debug, Default)]
pub struct ElementStore {
    /// Batches in increasing `k`.
    pub batches: Vec<Batch>,
    /// For each mesh element: `(batch, index in batch)`.
    pub locate: Vec<(u32, u32)>,
}

/// Whether element `e` of `mesh` is a linear tetrahedron.
fn is_tet(mesh: &PolyMesh, e: usize) -> bool {
    let el = &mesh.elements[e];
    el.nodes.len() == 4 && el.faces.len() == 4
}

impl ElementStore {
    /// Builds the store: gathers every element into its batch and computes
    /// volumes, mass fractions, `K_e` and stress-point gradients.
    pub fn build(mesh: &PolyMesh, material: &Material) -> Result<Self, BasisError> {
        let mut by_k: std::collections::BTreeMap<usize, Vec<u32>> = Default::default();
        for (e, el) in mesh.elements.iter().enumerate() {
            if !is_tet(mesh, e) {
                return Err(BasisError::UnsupportedElement {
                    element: e,
                    vertices: el.nodes.len(),
                    faces: el.faces.len(),
                });
            }
            by_k.entry(el.nodes.len()).or_default().push(e as u32);
        }
        let mut store = ElementStore {
            batches: Vec::new(),
            locate: vec![(0, 0); mesh.elements.len()],
        };
        for (b, (k, elements)) in by_k.into_iter().enumerate() {
            for (i, &e) in elements.iter().enumerate() {
                store.locate[e as usize] = (b as u32, i as u32);
            }
            store.batches.push(build_tet_batch(mesh, material, k, elements)?);
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

/// Closed-form linear tetrahedra: one quadrature point, constant gradients,
/// mass fractions 1/4.
fn build_tet_batch(mesh: &PolyMesh, material: &Material, k: usize, elements: Vec<u32>) -> Result<Batch, BasisError> {
    let (lambda, mu) = material.lame();
    let n = elements.len();
    let nodes: Vec<u32> = elements
        .iter()
        .flat_map(|&e| mesh.elements[e as usize].nodes.iter().copied())
        .collect();
    let rest: Vec<[f64; 3]> = nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let mut volume = vec![0.0; n];
    let mut stiffness = vec![0.0; n * 9 * k * k];
    let mut stress_grads = vec![[0.0; 3]; n * k];
    volume
        .par_iter_mut()
        .zip(stiffness.par_chunks_mut(9 * k * k))
        .zip(stress_grads.par_chunks_mut(k))
        .enumerate()
        .try_for_each(|(i, ((vol, ke), grads))| {
            let x: [[f64; 3]; 4] = std::array::from_fn(|a| rest[i * k + a]);
            let bad = || BasisError::DegenerateElement {
                element: elements[i] as usize,
                volume: cleave_kernels::tet::signed_volume(x[0], x[1], x[2], x[3]),
            };
            let (v, g) = cleave_kernels::tet::gradients(&x).ok_or_else(bad)?;
            // local node order is sorted by id, so the sign of v is arbitrary
            let v = v.abs();
            if !(v > 0.0) {
                return Err(bad());
            }
            *vol = v;
            grads.copy_from_slice(&g);
            cleave_kernels::elasticity::element_stiffness(&g, &[v], k, lambda, mu, ke);
            Ok(())
        })?;
    Ok(Batch {
        k,
        elements,
        nodes,
        rest,
        volume,
        mass_fraction: vec![0.25; n * k],
        stiffness,
        stress_grads,
    })
}
