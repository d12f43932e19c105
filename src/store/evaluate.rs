//! The shape functions of a built element evaluated at arbitrary points
//! (rest frame): what embeds a surface in the elements (martin2008 §7).
//!
//! Each kind uses its own basis: barycentric coordinates on tetrahedra,
//! the trilinear map inverted by Newton's method on hexahedra, mean value
//! coordinates, and the harmonic element's MFS fit (made once per call).
//! Points should lie in the element or on its boundary; a point on the
//! boundary of a mean value element (where the coordinates' formula
//! divides by zero) is moved a hair inside first, and a point at a node
//! takes that node's function exactly.

use cleave_kernels::dyn_stack::{MemBuffer, MemStack};
use cleave_kernels::tet::signed_volume;
use cleave_kernels::{harmonic as harmonic_kernel, mean_value, vec3};

use super::harmonic::{element_basis, face_bases, HarmonicOptions};
use super::{trilinear, BasisError, ElementKind, ElementStore};
use crate::mesh::PolyMesh;

impl ElementStore {
    /// Values of element `e`'s shape functions at `points` (node-major:
    /// `out[a * points.len() + p]`, `a` in the element-local node order),
    /// or `None` for a discontinuous Galerkin element (whose polynomials are
    /// not nodal).
    pub fn shape_values(
        &self,
        mesh: &PolyMesh,
        harmonic: &HarmonicOptions,
        e: usize,
        points: &[[f64; 3]],
    ) -> Result<Option<Vec<f64>>, BasisError> {
        let (b, _) = self.locate[e];
        let kind = self.batches[b as usize].kind;
        let el = &mesh.elements[e];
        let verts: Vec<[f64; 3]> = el.nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
        let (k, np) = (verts.len(), points.len());
        let mut out = vec![0.0; k * np];
        let local = |g: u32| el.nodes.binary_search(&g).map(|i| i as u32).unwrap_or(0);
        let triangles: Vec<[u32; 3]> = mesh.element_triangles(e).map(|t| t.map(local)).collect();
        let degenerate = || BasisError::DegenerateElement { element: e, volume: mesh.element_volume(e) };
        match kind {
            ElementKind::Dg => return Ok(None),
            ElementKind::LinearTet => {
                let v = signed_volume(verts[0], verts[1], verts[2], verts[3]);
                for (p, &x) in points.iter().enumerate() {
                    out[p] = signed_volume(x, verts[1], verts[2], verts[3]) / v;
                    out[np + p] = signed_volume(verts[0], x, verts[2], verts[3]) / v;
                    out[2 * np + p] = signed_volume(verts[0], verts[1], x, verts[3]) / v;
                    out[3 * np + p] = signed_volume(verts[0], verts[1], verts[2], x) / v;
                }
            }
            ElementKind::Trilinear => {
                let corners = trilinear::hex_corners(mesh, e).ok_or_else(degenerate)?;
                for (p, &x) in points.iter().enumerate() {
                    let n = trilinear::values_at(&verts, &corners, x).ok_or_else(degenerate)?;
                    for (a, &c) in corners.iter().enumerate() {
                        out[c * np + p] = n[a];
                    }
                }
            }
            ElementKind::MeanValue => {
                let mut grad = vec![0.0; 3 * k * np];
                let mut stack = MemBuffer::new(mean_value::evaluate_scratch(k, triangles.len()));
                mean_value::evaluate(&verts, &triangles, points, &mut out, &mut grad, MemStack::new(&mut stack));
                // the formula is singular on the boundary: such points are
                // moved a hair inside
                let centre = mesh.element_centroid(e);
                for p in 0..np {
                    if (0..k).any(|a| !out[a * np + p].is_finite()) {
                        let x = vec3::add(points[p], vec3::scale(vec3::sub(centre, points[p]), 1e-9));
                        let (mut one, mut g) = (vec![0.0; k], vec![0.0; 3 * k]);
                        mean_value::evaluate(&verts, &triangles, &[x], &mut one, &mut g, MemStack::new(&mut stack));
                        (0..k).for_each(|a| out[a * np + p] = one[a]);
                    }
                }
            }
            ElementKind::Harmonic => {
                let faces = face_bases(mesh, &[e as u32], harmonic)?;
                let basis = element_basis(mesh, e, &faces, harmonic).ok_or(BasisError::HarmonicFit { element: e })?;
                let mut grad = vec![0.0; 3 * k * np];
                let mut stack = MemBuffer::new(harmonic_kernel::evaluate_scratch(k));
                harmonic_kernel::evaluate(&basis.functions(), points, &mut out, &mut grad, MemStack::new(&mut stack));
            }
        }
        // a point at a node follows that node exactly (every family's value
        // there, up to the rounding of the evaluation)
        for (p, x) in points.iter().enumerate() {
            if let Some(a) = verts.iter().position(|v| v == x) {
                (0..k).for_each(|b| out[b * np + p] = f64::from(a == b));
            }
        }
        if out.iter().any(|v| !v.is_finite()) {
            return Err(degenerate());
        }
        Ok(Some(out))
    }
}
