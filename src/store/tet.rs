//! Closed-form linear tetrahedra (the mean value element with `k = 4`).

use rayon::prelude::*;

use super::{batch_for, BasisError, Batch, ElementKind};
use crate::material::Material;
use crate::mesh::PolyMesh;

/// Builds the tetrahedra `elements` into the end of the tetrahedra's batch
/// in `batches`: closed form, one quadrature point, constant gradients,
/// mass fractions 1/4 (no stored `K_e`, triangles or points). On error the
/// batch holds the new entries, partly filled.
pub(super) fn build_batch(
    batches: &mut Vec<Batch>,
    mesh: &PolyMesh,
    material: &Material,
    elements: &[u32],
) -> Result<(), BasisError> {
    let k = 4;
    let batch: &mut Batch = batch_for(batches, ElementKind::LinearTet, k, 1, material.lame());
    let start = batch.len();
    batch.extend_gathered(mesh, elements, 0, 0);
    batch.mass_fraction[start * k..].fill(0.25);
    let rest = &batch.rest[start * k..];
    (batch.volume[start..].par_iter_mut())
        .zip(batch.stress_grads[start * k..].par_chunks_mut(k))
        .enumerate()
        .try_for_each(|(i, (vol, grads))| {
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
        })
}
