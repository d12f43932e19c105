//! Closed-form linear tetrahedra (the mean value element with `k = 4`).

use rayon::prelude::*;

use super::{BasisError, Batch, ElementKind};
use crate::material::Material;
use crate::mesh::PolyMesh;

/// Closed-form linear tetrahedra: one quadrature point, constant gradients,
/// mass fractions 1/4.
pub(super) fn build_batch(mesh: &PolyMesh, material: &Material, elements: Vec<u32>) -> Result<Batch, BasisError> {
    let k = 4;
    let n = elements.len();
    let nodes: Vec<u32> = elements.iter().flat_map(|&e| mesh.elements[e as usize].nodes.iter().copied()).collect();
    let rest: Vec<[f64; 3]> = nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let mut volume = vec![0.0; n];
    let mut stress_grads = vec![[0.0; 3]; n * k];
    volume.par_iter_mut().zip(stress_grads.par_chunks_mut(k)).enumerate().try_for_each(|(i, (vol, grads))| {
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
        Ok(())
    })?;
    Ok(Batch {
        k,
        kind: ElementKind::LinearTet,
        elements,
        nodes,
        rest,
        volume,
        mass_fraction: vec![0.25; n * k],
        stiffness: Vec::new(),
        lame: material.lame(),
        stress_grads,
        triangles: Default::default(),
        points: Vec::new(),
        weights: Vec::new(),
        points_per_element: 1,
        stiffness_ratio: Vec::new(),
        dg: Vec::new(),
    })
}
