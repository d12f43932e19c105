//! A body force density `b(x)` (N/m³, at rest positions, constant in time)
//! besides gravity, turned into a load per block: `F_a = ∫ b N_a dV`.
//!
//! For the discontinuous Galerkin family the integral is taken exactly for
//! polynomial `b` up to degree 5 (a Gauss rule of order 4 per direction on
//! the signed sub-tetrahedra of each element's surface triangles from its
//! centroid); for the nodal families each element's `∫ b dV` (same rule) is
//! shared among its nodes like its mass (a lumped load, consistent with the
//! lumped mass).

use std::sync::Arc;

use cleave_kernels::quadrature::cone_rule;

use super::{Model, Simulation};
use crate::mesh::PolyMesh;
use crate::store::dg::MAX_BASIS;
use crate::Error;

/// A body force density field (N/m³) of rest position (m).
pub type BodyForce = Arc<dyn Fn([f64; 3]) -> [f64; 3] + Send + Sync>;

/// Points and weights (m³) of the reference rule on element `e`.
fn element_rule(mesh: &PolyMesh, e: usize, order: usize) -> (Vec<[f64; 3]>, Vec<f64>) {
    let nodes = &mesh.elements[e].nodes;
    let verts: Vec<[f64; 3]> = nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let tris: Vec<[u32; 3]> = mesh
        .element_triangles(e)
        .filter_map(|t| {
            let local = t.map(|g| nodes.binary_search(&g).ok().map(|i| i as u32));
            Some([local[0]?, local[1]?, local[2]?])
        })
        .collect();
    let (mut points, mut weights) = (Vec::new(), Vec::new());
    cone_rule(&verts, &tris, mesh.element_centroid(e), order, &mut points, &mut weights);
    (points, weights)
}

/// The load `F_a = ∫ b N_a dV` (N) of `force` on every block of `model`.
pub(super) fn loads(mesh: &PolyMesh, model: &Model, blocks: usize, force: &BodyForce) -> Vec<[f64; 3]> {
    let mut out = vec![[0.0; 3]; blocks];
    let store = model.store();
    for b in &store.batches {
        let k = b.k;
        for (i, &e) in b.elements.iter().enumerate() {
            let (points, weights) = element_rule(mesh, e as usize, if b.dg.is_empty() { 3 } else { 4 });
            if let Some(basis) = b.dg.get(i) {
                let mut n = [0.0; MAX_BASIS];
                for (p, w) in points.iter().zip(&weights) {
                    let f = force(*p);
                    basis.values(*p, &mut n);
                    for a in 0..k {
                        let o = &mut out[b.nodes[i * k + a] as usize];
                        (0..3).for_each(|c| o[c] += w * n[a] * f[c]);
                    }
                }
            } else {
                let mut total = [0.0; 3];
                for (p, w) in points.iter().zip(&weights) {
                    let f = force(*p);
                    (0..3).for_each(|c| total[c] += w * f[c]);
                }
                for a in 0..k {
                    let share = b.mass_fraction[i * k + a];
                    let o = &mut out[b.nodes[i * k + a] as usize];
                    (0..3).for_each(|c| o[c] += share * total[c]);
                }
            }
        }
    }
    out
}

impl Simulation {
    /// Whether a body force is applied.
    pub fn has_body_force(&self) -> bool {
        self.boundary.body.is_some()
    }

    /// Integrates the body force's loads again (after a topology change).
    pub(super) fn refresh_body_loads(&mut self) {
        if let Some(force) = &self.boundary.body {
            self.body_loads = loads(&self.mesh, &self.elements, self.masses.len(), force);
        }
    }

    /// Applies the body force density `force` (N/m³, a function of the rest
    /// position in m, constant in time) in addition to gravity, in steps
    /// and static solves; replaces an earlier one. Its loads are
    /// integrated now and again after every topology change; a value that
    /// is not finite is an error naming the element block.
    pub fn set_body_force(
        &mut self,
        force: impl Fn([f64; 3]) -> [f64; 3] + Send + Sync + 'static,
    ) -> Result<(), Error> {
        let force: BodyForce = Arc::new(force);
        let loads = loads(&self.mesh, &self.elements, self.masses.len(), &force);
        if let Some(i) = loads.iter().position(|f| !f.iter().all(|v| v.is_finite())) {
            let allowed = "must be finite wherever the body is";
            return Err(
                crate::param::ParamError::new("body_force", format!("{:?} on block {i}", loads[i]), allowed).into()
            );
        }
        self.body_loads = loads;
        self.boundary.body = Some(force);
        Ok(())
    }
}
