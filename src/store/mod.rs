//! The element store: elements batched by vertex count, structure of arrays.
//!
//! A [`Batch`] holds every element with the same number of nodes `k` and
//! keeps, per element, flat arrays of fixed stride: node ids (`k`), gathered
//! rest positions (`k`), volume, lumped mass fractions (`k`), the element
//! stiffness `K_e` (`9 k^2`, row-major `3k x 3k`) and the shape function
//! gradients at the element's stress point (`k`). Kernels run over a batch
//! as over plain slices; a batch is rebuilt alone when its elements change.
//!
//! Tetrahedra form the `k = 4` batch and use the closed form (`tet`). The
//! other elements use the scene's family: mean value shape functions on
//! convex elements (`mean_value`), or harmonic ones on any planar-faced
//! element ([`harmonic`]), where hexahedra keep the closed-form trilinear
//! basis (`trilinear`).

pub mod dg;
mod evaluate;
pub mod harmonic;
mod health;
mod mean_value;
mod tet;
mod trilinear;

use rayon::prelude::*;

pub use harmonic::HarmonicOptions;
pub use health::HealthFloors;

use thiserror::Error;

use crate::material::Material;
use crate::mesh::PolyMesh;
use cleave_kernels::corotation::MAX_NODES;
use cleave_kernels::spectrum::{stiffness_spectrum, tet_spectrum, RigidModes, Spectrum};

/// An element the basis cannot be built on.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum BasisError {
    /// The mean value family needs convex elements.
    #[error("element {element} is not convex; mean value elements must be convex (use family = \"harmonic\")")]
    NonConvex {
        /// The element's id.
        element: usize,
    },
    /// More vertices than the kernels accept.
    #[error("element {element} has {vertices} vertices; at most {max} are supported")]
    TooManyVertices {
        /// The element's id.
        element: usize,
        /// The face's vertices.
        vertices: usize,
        /// The largest vertex count supported.
        max: usize,
    },
    /// The element is flat or inverted at rest.
    #[error("element {element} is degenerate (volume {volume:.3e} m^3)")]
    DegenerateElement {
        /// The element's id.
        element: usize,
        /// The volume (m^3).
        volume: f64,
    },
    /// No interior point sees the whole boundary, so the element cannot be
    /// split into positive sub-tetrahedra for its quadrature.
    #[error("element {element} is not star-shaped; split it into star-shaped parts")]
    NotStarShaped {
        /// The element's id.
        element: usize,
    },
    /// The MFS least-squares system is rank deficient (coincident kernels
    /// or a degenerate face).
    #[error("the harmonic basis of element {element} cannot be fitted (degenerate face or element)")]
    HarmonicFit {
        /// The element's id.
        element: usize,
    },
    /// The element stiffness has a soft mode: its seventh eigenvalue is
    /// negligible against its largest (certified below the floor, see
    /// [`HealthFloors`]).
    #[error("element {element} has a soft mode: λ7/λmax of its stiffness is below the floor {floor:.0e} (estimated at {ratio:.2e}; two nodes almost on top of each other, or a sliver)")]
    SoftElement {
        /// The element's id.
        element: usize,
        /// λ7/λmax of the element stiffness as [`Batch::stiffness_spectrum`]
        /// estimates it (from above: the floor's certificate decides).
        ratio: f64,
        /// The floor it must reach.
        floor: f64,
    },
    /// The element stiffness resists a rigid motion.
    #[error("element {element}: its stiffness resists a rigid motion (|K q| / λmax = {residual:.2e})")]
    RigidModes {
        /// The element's id.
        element: usize,
        /// Largest `|K q| / λmax` over the unit rigid modes `q`.
        residual: f64,
    },
    /// A node gets a negligible share of the element's mass.
    #[error(
        "element {element}: node {node} gets {fraction:.2e} of the mean nodal mass share, below the floor {floor:.0e}"
    )]
    LightNode {
        /// The element's id.
        element: usize,
        /// The node's id.
        node: usize,
        /// The node's share relative to the mean share.
        fraction: f64,
        /// The floor it must reach.
        floor: f64,
    },
}

impl BasisError {
    /// The element the error names.
    pub fn element(&self) -> usize {
        match *self {
            BasisError::NonConvex { element }
            | BasisError::TooManyVertices { element, .. }
            | BasisError::DegenerateElement { element, .. }
            | BasisError::NotStarShaped { element }
            | BasisError::HarmonicFit { element }
            | BasisError::SoftElement { element, .. }
            | BasisError::RigidModes { element, .. }
            | BasisError::LightNode { element, .. } => element,
        }
    }
}

/// How the elements of a batch are represented.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
pub enum ElementKind {
    /// Closed-form linear tetrahedra (no stored `K_e`).
    #[default]
    LinearTet,
    /// Mean value shape functions (wicke2007).
    MeanValue,
    /// Closed-form trilinear hexahedra (harmonic family).
    Trilinear,
    /// Harmonic shape functions by MFS (martin2008).
    Harmonic,
    /// Discontinuous Galerkin polynomials (kaufmann2008): `k` is the number
    /// of basis functions and the "nodes" are the element's own
    /// coefficient blocks.
    Dg,
}

/// The shape function family of the elements other than tetrahedra.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Family {
    /// Mean value coordinates; every element must be convex.
    #[default]
    MeanValue,
    /// Harmonic coordinates; hexahedra trilinear, any planar-faced element.
    Harmonic,
    /// Discontinuous Galerkin polynomials on every element, tetrahedra
    /// included (see [`dg`]).
    Dg,
}

/// All elements with `k` nodes, as structure of arrays.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Batch {
    /// Nodes per element.
    pub k: usize,
    /// Representation of the batch's elements.
    pub kind: ElementKind,
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
    /// Quadrature points per element of the rule the batch's elements
    /// were built with (the rule itself is not kept: nothing reads it
    /// after the build).
    pub points_per_element: usize,
    /// The polynomial basis of each element (discontinuous Galerkin
    /// batches only; empty otherwise).
    pub dg: Vec<dg::DgBasis>,
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

    /// Copies entry `from` over entry `to` in every per-element array (each
    /// holds the same number of values per element, possibly none); entry
    /// `from` is left to be dropped (its basis, if any, swapped in).
    fn copy_entry(&mut self, from: usize, to: usize) {
        fn copy<T: Copy>(v: &mut [T], n: usize, from: usize, to: usize) {
            let per = v.len() / n;
            v.copy_within(from * per..(from + 1) * per, to * per);
        }
        let n = self.len();
        if from == to {
            return;
        }
        copy(&mut self.elements, n, from, to);
        copy(&mut self.nodes, n, from, to);
        copy(&mut self.rest, n, from, to);
        copy(&mut self.volume, n, from, to);
        copy(&mut self.mass_fraction, n, from, to);
        copy(&mut self.stiffness, n, from, to);
        copy(&mut self.stress_grads, n, from, to);
        copy(&mut self.triangles, n, from, to);
        if !self.dg.is_empty() {
            self.dg.swap(from, to);
        }
    }

    /// Keeps the first `len` entries.
    fn truncate(&mut self, len: usize) {
        fn keep<T>(v: &mut Vec<T>, n: usize, len: usize) {
            if let Some(per) = v.len().checked_div(n) {
                v.truncate(len * per);
            }
        }
        let n = self.len();
        keep(&mut self.nodes, n, len);
        keep(&mut self.rest, n, len);
        keep(&mut self.volume, n, len);
        keep(&mut self.mass_fraction, n, len);
        keep(&mut self.stiffness, n, len);
        keep(&mut self.stress_grads, n, len);
        keep(&mut self.triangles, n, len);
        keep(&mut self.dg, n, len);
        self.elements.truncate(len);
    }

    /// Appends the `elements` (mesh ids) with their nodes and rest
    /// positions gathered from `mesh`, every other per-element array
    /// zero-filled: `stiffness` values and `triangles` per element as
    /// given.
    fn extend_gathered(&mut self, mesh: &PolyMesh, elements: &[u32], stiffness: usize, triangles: usize) {
        // (with room to spare, [`crate::reserve_room`]: the first cut would
        // otherwise copy the whole batch of a mesh's tetrahedra to grow it)
        use crate::{reserve_room, reserve_to_write, resize_with_room};
        let (k, n) = (self.k, self.len() + elements.len());
        reserve_room(&mut self.elements, n);
        self.elements.extend_from_slice(elements);
        let start = self.nodes.len();
        reserve_to_write(&mut self.nodes, n * k);
        self.nodes.extend(elements.iter().flat_map(|&e| mesh.elements[e as usize].nodes.iter().copied()));
        reserve_to_write(&mut self.rest, n * k);
        self.rest.extend(self.nodes[start..].iter().map(|&v| mesh.nodes[v as usize]));
        resize_with_room(&mut self.volume, n, 0.0);
        resize_with_room(&mut self.mass_fraction, n * k, 0.0);
        resize_with_room(&mut self.stiffness, n * stiffness, 0.0);
        resize_with_room(&mut self.stress_grads, n * k, [0.0; 3]);
        resize_with_room(&mut self.triangles, n * triangles, [0; 3]);
    }

    /// Removes entry `i`; the last entry takes its place.
    fn swap_remove(&mut self, i: usize) {
        let last = self.len() - 1;
        self.copy_entry(last, i);
        self.truncate(last);
    }

    /// Appends the entries of `other` (same kind, `k` and quadrature size).
    fn append(&mut self, mut other: Batch) {
        self.elements.append(&mut other.elements);
        self.nodes.append(&mut other.nodes);
        self.rest.append(&mut other.rest);
        self.volume.append(&mut other.volume);
        self.mass_fraction.append(&mut other.mass_fraction);
        self.stiffness.append(&mut other.stiffness);
        self.stress_grads.append(&mut other.stress_grads);
        self.triangles.append(&mut other.triangles);
        self.dg.append(&mut other.dg);
    }

    /// The mass (kg) entry `i` gives its `a`-th node: `μ_a V ρ`.
    #[inline]
    fn mass_share(&self, i: usize, a: usize, density: f64) -> f64 {
        self.mass_fraction[i * self.k + a] * self.volume[i] * density
    }

    /// Whether the batch holds closed-form linear tetrahedra (no stored
    /// `K_e`: their blocks come from their gradients).
    #[inline]
    pub fn is_tet(&self) -> bool {
        self.kind == ElementKind::LinearTet
    }

    /// The row-major 3x3 block `K_ab` (N/m) of entry `i`: for tetrahedra
    /// `V (λ g_a g_bᵀ + μ g_b g_aᵀ + μ (g_a · g_b) I)`, otherwise read from
    /// the stored `K_e`.
    #[inline]
    pub fn block(&self, i: usize, a: usize, b: usize) -> [f64; 9] {
        let k = self.k;
        if self.is_tet() {
            let g = &self.stress_grads[i * k..(i + 1) * k];
            return cleave_kernels::elasticity::block(g[a], g[b], self.volume[i], self.lame.0, self.lame.1);
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
        let n = 3 * self.k;
        let mut ke = vec![0.0; n * n];
        self.element_matrix_into(i, &mut ke);
        ke
    }

    /// [`Batch::element_matrix`] into `ke` (`9 k^2` values): the stored
    /// `K_e` copied whole, or a tetrahedron's blocks from its gradients.
    pub fn element_matrix_into(&self, i: usize, ke: &mut [f64]) {
        let (k, n) = (self.k, 3 * self.k);
        if !self.is_tet() {
            ke.copy_from_slice(&self.stiffness[i * n * n..(i + 1) * n * n]);
            return;
        }
        for a in 0..k {
            for b in 0..k {
                let blk = self.block(i, a, b);
                for r in 0..3 {
                    ke[(3 * a + r) * n + 3 * b..(3 * a + r) * n + 3 * b + 3].copy_from_slice(&blk[3 * r..3 * r + 3]);
                }
            }
        }
    }

    /// How the coefficients of entries `range` move rigidly: a polynomial
    /// basis by its first (constant) coefficient and the identity's
    /// coefficients, a nodal one by moving its nodes.
    fn rigid_modes(&self, range: std::ops::Range<usize>) -> RigidModes<'_> {
        let x = &self.rest[range.start * self.k..range.end * self.k];
        match self.kind {
            ElementKind::Dg => RigidModes::Modal(x),
            _ => RigidModes::Nodal(x),
        }
    }

    /// The spectrum of entry `i`'s stiffness: `λ_max`, `λ₇` and the rigid
    /// residual, exact for a tetrahedron, else estimated (by power and
    /// inverse iteration, [`cleave_kernels::spectrum`]). The health check
    /// certifies the floor on `λ₇ / λ_max` without it; this is the measure
    /// itself, for diagnostics and error messages.
    pub fn stiffness_spectrum(&self, i: usize) -> Spectrum {
        if self.is_tet() {
            let x = std::array::from_fn(|a| self.rest[4 * i + a]);
            let g = std::array::from_fn(|a| self.stress_grads[4 * i + a]);
            return tet_spectrum(&x, &g, self.volume[i], self.lame.0, self.lame.1);
        }
        let n = 3 * self.k;
        let mut ke = vec![0.0; n * n];
        self.element_matrix_into(i, &mut ke);
        stiffness_spectrum(&ke, self.rigid_modes(i..i + 1))
    }

    /// The gradient `Σ_a v_a ⊗ ḡ_a` (row-major, `G[r][c] = ∂v_r/∂x_c`) of the
    /// nodal field `v` (indexed by node id) at entry `i`'s stress point,
    /// `ḡ_a` its shape function gradients there (1/m): the deformation
    /// gradient `F` for positions, `F - I` for displacements; exact for
    /// tetrahedra, the volume average for polyhedra.
    #[inline]
    pub fn field_gradient(&self, i: usize, v: &[[f64; 3]]) -> [f64; 9] {
        let k = self.k;
        let mut f = [[0.0; 9]];
        let (nodes, grads) = (&self.nodes[i * k..(i + 1) * k], &self.stress_grads[i * k..(i + 1) * k]);
        cleave_kernels::corotation::deformation_gradients(k, nodes, v, grads, &mut f);
        f[0]
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

/// Points `locate` of every entry of `batch` from entry `first` on, batch
/// `b` of its store, at its place.
fn locate_entries(locate: &mut [(u32, u32)], b: usize, batch: &Batch, first: usize) {
    for (i, &e) in batch.elements.iter().enumerate().skip(first) {
        locate[e as usize] = (b as u32, i as u32);
    }
}

/// The batch of `kind`, `k` and `nq` quadrature points per element in
/// `batches`, appended (empty, with the Lamé parameters `lame`) if there
/// is none.
fn batch_for(batches: &mut Vec<Batch>, kind: ElementKind, k: usize, nq: usize, lame: (f64, f64)) -> &mut Batch {
    let b = match batches.iter().position(|b| b.kind == kind && b.k == k && b.points_per_element == nq) {
        Some(b) => b,
        None => {
            batches.push(Batch { k, kind, lame, points_per_element: nq, ..Default::default() });
            batches.len() - 1
        }
    };
    &mut batches[b]
}

/// Builds the `elements` (mesh ids) into `batches`, each batch's new
/// entries past its old ones (new batches appended for new kinds, vertex
/// counts or quadratures), and checks their health (see
/// [`ElementStore::build`]); returns the number of faces a discontinuous
/// Galerkin build integrated. On error every batch is as it was.
fn build_into(
    batches: &mut Vec<Batch>,
    mesh: &PolyMesh,
    material: &Material,
    options: &BasisOptions,
    elements: &[u32],
    inherit: &(dyn Fn(u32) -> Option<dg::DgBasis> + Sync),
) -> Result<usize, BasisError> {
    let old_len: Vec<usize> = batches.iter().map(Batch::len).collect();
    let built = build_new_entries(batches, mesh, material, options, elements, inherit);
    if built.is_err() {
        batches.truncate(old_len.len());
        for (batch, &len) in batches.iter_mut().zip(&old_len) {
            batch.truncate(len);
        }
    }
    built
}

/// [`build_into`] without putting the batches back on error.
fn build_new_entries(
    batches: &mut Vec<Batch>,
    mesh: &PolyMesh,
    material: &Material,
    options: &BasisOptions,
    elements: &[u32],
    inherit: &(dyn Fn(u32) -> Option<dg::DgBasis> + Sync),
) -> Result<usize, BasisError> {
    let mut by_kind: std::collections::BTreeMap<(ElementKind, usize), Vec<u32>> = Default::default();
    let mut faces_integrated = 0;
    for &e in elements {
        let (el, e) = (&mesh.elements[e as usize], e as usize);
        let k = el.nodes.len();
        if k > MAX_NODES {
            return Err(BasisError::TooManyVertices { element: e, vertices: k, max: MAX_NODES });
        }
        let kind = match (k, options.family) {
            (_, Family::Dg) => ElementKind::Dg,
            (4, _) => ElementKind::LinearTet,
            (_, Family::MeanValue) => ElementKind::MeanValue,
            (_, Family::Harmonic)
                if options.harmonic.trilinear_hexahedra && trilinear::hex_corners(mesh, e).is_some() =>
            {
                ElementKind::Trilinear
            }
            (_, Family::Harmonic) => ElementKind::Harmonic,
        };
        // one batch holds every discontinuous Galerkin element: its
        // size is the number of basis functions, whatever the vertices
        let k = if kind == ElementKind::Dg { options.dg.size() } else { k };
        by_kind.entry((kind, k)).or_default().push(e as u32);
    }
    let face_bases = if by_kind.keys().any(|(kind, _)| *kind == ElementKind::Harmonic) {
        let harmonic: Vec<u32> = by_kind
            .iter()
            .filter(|((kind, _), _)| *kind == ElementKind::Harmonic)
            .flat_map(|(_, v)| v.iter().copied())
            .collect();
        harmonic::face_bases(mesh, &harmonic, &options.harmonic)?
    } else {
        Vec::new()
    };
    let mut first: Vec<usize> = batches.iter().map(Batch::len).collect();
    for ((kind, k), elements) in by_kind {
        match kind {
            ElementKind::LinearTet => tet::build_batch(batches, mesh, material, &elements)?,
            ElementKind::MeanValue => {
                mean_value::build_batch(batches, mesh, material, options.quadrature, k, &elements)?
            }
            ElementKind::Trilinear => trilinear::build_batch(batches, mesh, material, &elements)?,
            ElementKind::Harmonic => {
                harmonic::build_batch(batches, mesh, material, &face_bases, &options.harmonic, k, &elements)?
            }
            ElementKind::Dg => {
                let (batch, integrated) = dg::build_batch(mesh, material, &options.dg, elements, inherit)?;
                faces_integrated += integrated;
                batch_for(batches, batch.kind, batch.k, batch.points_per_element, batch.lame).append(batch);
            }
        }
    }
    // (a batch made here holds only new entries)
    first.resize(batches.len(), 0);
    let mut verdicts = health::assess(batches, &first, &options.health);
    let refined = match options.quadrature {
        QuadratureRule::Consistent => take_soft_mean_value(batches, &first, &mut verdicts),
        _ => Default::default(),
    };
    health::first_failure(batches, &first, verdicts)?;
    let mut first: Vec<usize> = batches.iter().map(Batch::len).collect();
    for (k, elements) in refined {
        let rule = QuadratureRule::ConsistentGauss(REFINED_QUADRATURE_ORDER);
        mean_value::build_batch(batches, mesh, material, rule, k, &elements)?;
    }
    first.resize(batches.len(), 0);
    health::check_all(batches, &first, &options.health)?;
    Ok(faces_integrated)
}

/// Removes from the new entries of the mean value `batches` (those from
/// `first[b]` on, with their `verdicts`) the entries whose one failure is
/// a soft mode, and returns their element ids by vertex count, to be built
/// again with the finer rule.
fn take_soft_mean_value(
    batches: &mut [Batch],
    first: &[usize],
    verdicts: &mut [Vec<Result<(), BasisError>>],
) -> std::collections::BTreeMap<usize, Vec<u32>> {
    let mut soft: std::collections::BTreeMap<usize, Vec<u32>> = Default::default();
    for ((batch, verdicts), &from) in batches.iter_mut().zip(verdicts.iter_mut()).zip(first) {
        if batch.kind != ElementKind::MeanValue {
            continue;
        }
        let failing = (0..verdicts.len()).filter(|&i| matches!(verdicts[i], Err(BasisError::SoftElement { .. })));
        // (from the last: the entry moved into a freed place, the batch's
        // last, is never one still to be removed)
        for i in failing.collect::<Vec<_>>().into_iter().rev() {
            soft.entry(batch.k).or_default().push(batch.elements[from + i]);
            batch.swap_remove(from + i);
            let _soft = verdicts.swap_remove(i);
        }
    }
    soft.values_mut().for_each(|elements| elements.sort_unstable());
    soft
}

/// Gauss–Legendre order per direction of the rule that integrates the mean
/// value elements the paper's points leave soft ([`ElementStore::build`]):
/// 27 points per surface triangle.
pub const REFINED_QUADRATURE_ORDER: usize = 3;

/// How mean value elements are integrated (wicke2007 §3.4 and beyond).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
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
    /// The points and weights of `Reference(n)` with the gradient
    /// correction of `Consistent`: what `Consistent` falls back to for an
    /// element whose stiffness the paper's points leave with a soft mode
    /// (see [`ElementStore::build`]).
    ConsistentGauss(usize),
}

/// Options of the basis construction.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BasisOptions {
    /// Family of the elements that are not tetrahedra.
    pub family: Family,
    /// Quadrature of mean value elements.
    pub quadrature: QuadratureRule,
    /// Fit and quadrature of harmonic elements.
    pub harmonic: HarmonicOptions,
    /// The health every built element must have.
    pub health: HealthFloors,
    /// Degree and face terms of the discontinuous Galerkin family.
    pub dg: dg::DgOptions,
}

impl BasisOptions {
    /// Checks the harmonic fit and quadrature and the health floors.
    pub fn check(&self) -> Result<(), crate::param::ParamError> {
        self.harmonic.check()?;
        self.dg.check()?;
        self.health.check()
    }
}

/// How [`ElementStore::update`] moved the batch entries, in the order it
/// did: per-element state kept beside the store replays it to stay aligned.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct StoreChanges {
    /// `(batch, index)` of every entry removed, in order; each removal
    /// moves the batch's last entry into `index` (swap-remove).
    pub removed: Vec<(u32, u32)>,
    /// `(batch, first index, count)` of the entries appended afterwards
    /// (a batch index past the previous batch count is a new batch).
    pub appended: Vec<(u32, u32, u32)>,
    /// Faces whose moments a discontinuous Galerkin update integrated (the
    /// others kept theirs).
    pub faces_integrated: usize,
}

/// Every element of a mesh, batched by vertex count.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ElementStore {
    /// Batches, one per `(kind, k)` and quadrature size: in increasing
    /// `(kind, k)` when built, then the mean value elements the finer rule
    /// integrates (see [`ElementStore::build`]); batches that later updates
    /// need are appended.
    pub batches: Vec<Batch>,
    /// For each mesh element: `(batch, index in batch)`.
    pub locate: Vec<(u32, u32)>,
}

/// The nodal families' couplings: blocks are nodes, entries are elements
/// (grouped by batch, identified by their mesh ids).
impl crate::assembly::Couplings for ElementStore {
    fn groups(&self) -> usize {
        self.batches.len()
    }
    fn entries(&self, group: usize) -> usize {
        self.batches[group].len()
    }
    fn blocks(&self, group: usize, entry: usize) -> &[u32] {
        self.batches[group].element_nodes(entry)
    }
    fn id(&self, group: usize, entry: usize) -> u32 {
        self.batches[group].elements[entry]
    }
    fn locate(&self, id: u32) -> (u32, u32) {
        self.locate[id as usize]
    }
}

impl ElementStore {
    /// Builds the store: gathers every element into its batch and computes
    /// volumes, mass fractions, `K_e` and stress-point gradients.
    ///
    /// With the `Consistent` rule, a mean value element whose stiffness
    /// fails the health check by a soft mode alone is built again with
    /// `ConsistentGauss(REFINED_QUADRATURE_ORDER)` and checked again: the
    /// paper's points (one per surface triangle and per vertex) can miss
    /// the stiffness of a small corner of a poor element, which is then
    /// under-integrated rather than soft. (A bunny_100k tetrahedron of
    /// quality 0.02 that a blade cut left with three edge nodes near one
    /// corner: λ₇/λmax 3.8e-7 with the paper's points, 1.6e-5 with 27 per
    /// triangle, 1.5e-5 converged with 512.) An element still soft is the
    /// error it was.
    pub fn build(mesh: &PolyMesh, material: &Material, options: &BasisOptions) -> Result<Self, BasisError> {
        let mut store = ElementStore::default();
        let all: Vec<u32> = (0..mesh.elements.len() as u32).collect();
        build_into(&mut store.batches, mesh, material, options, &all, &|_| None)?;
        store.locate = vec![(u32::MAX, u32::MAX); mesh.elements.len()];
        for (b, batch) in store.batches.iter().enumerate() {
            locate_entries(&mut store.locate, b, batch, 0);
        }
        Ok(store)
    }

    /// Rebuilds the data of the `changed` elements (mesh ids; ids past the
    /// store's element count are new elements) after a topology change and
    /// keeps every other element's data as it is: removed entries are
    /// filled by their batch's last entry, rebuilt ones are appended. Returns
    /// those moves, so that per-element state kept elsewhere (rotations)
    /// can follow them. On error the store is unchanged.
    ///
    /// The rebuilt entries are built in place, past the end of their
    /// batches; the removals then run among the old entries, and the last
    /// of the new entries fill the places they left at the old entries'
    /// end: what moves is as many entries as were removed (a blade cut
    /// across bunny_100k removes few of the polyhedra it rebuilds), not
    /// every rebuilt one. The new entries of a batch hold one contiguous
    /// stretch, in an order the moves rotate.
    pub fn update(
        &mut self,
        mesh: &PolyMesh,
        material: &Material,
        options: &BasisOptions,
        changed: &[u32],
        parents: &[(u32, u32)],
    ) -> Result<StoreChanges, BasisError> {
        // a discontinuous Galerkin element keeps its frame and the moments
        // of its unchanged faces; a new one takes its parent's
        let (batches, locate) = (&mut self.batches, &mut self.locate);
        let inherit = |e: u32| -> Option<dg::DgBasis> {
            let from = parents.iter().find(|p| p.0 == e).map_or(e, |p| p.1);
            let &(b, i) = locate.get(from as usize)?;
            batches.get(b as usize)?.dg.get(i as usize).cloned()
        };
        let inherited: std::collections::HashMap<u32, dg::DgBasis> = match options.family {
            Family::Dg => changed.iter().filter_map(|&e| Some((e, inherit(e)?))).collect(),
            _ => Default::default(),
        };
        let inherit = |e: u32| inherited.get(&e).cloned();
        let old_len: Vec<usize> = batches.iter().map(Batch::len).collect();
        let faces_integrated = build_into(batches, mesh, material, options, changed, &inherit)?;
        let mut moves = StoreChanges { faces_integrated, ..Default::default() };
        // the removals, among each batch's old entries
        let mut end = old_len.clone();
        for &e in changed {
            if let Some(&(b, i)) = locate.get(e as usize) {
                let (batch, last) = (&mut batches[b as usize], &mut end[b as usize]);
                *last -= 1;
                batch.copy_entry(*last, i as usize);
                moves.removed.push((b, i));
                if (i as usize) < *last {
                    locate[batch.elements[i as usize] as usize] = (b, i);
                }
            }
        }
        // the new entries close up behind the old ones
        locate.resize(mesh.elements.len(), (u32::MAX, u32::MAX));
        for (b, batch) in batches.iter_mut().enumerate() {
            let (before, kept) = (old_len.get(b).copied().unwrap_or(0), end.get(b).copied().unwrap_or(0));
            let fresh = batch.len() - before;
            for (hole, from) in (kept..before).zip((before.max(batch.len() - (before - kept))..batch.len()).rev()) {
                batch.copy_entry(from, hole);
            }
            batch.truncate(kept + fresh);
            if fresh > 0 {
                moves.appended.push((b as u32, kept as u32, fresh as u32));
                locate_entries(locate, b, batch, kept);
            }
        }
        Ok(moves)
    }

    /// The nodes of element `e` (a mesh id) as the store holds them, in
    /// its local order; none for an element it does not hold.
    pub fn element_nodes(&self, e: u32) -> &[u32] {
        match self.locate.get(e as usize) {
            Some(&(b, i)) if b != u32::MAX => self.batches[b as usize].element_nodes(i as usize),
            _ => &[],
        }
    }

    /// The nodes of the listed elements (mesh ids; unknown ones are
    /// skipped), as the store holds them: before an [`ElementStore::update`]
    /// these are the nodes the elements had before the change.
    pub fn nodes_of(&self, elements: &[u32]) -> Vec<u32> {
        elements.iter().flat_map(|&e| self.element_nodes(e).iter().copied()).collect()
    }

    /// Lumped nodal masses (kg): `m_i = Σ_e μ_i^e V_e ρ` (wicke2007 eq. 18),
    /// summed in the store's order.
    pub fn lumped_masses(&self, num_nodes: usize, density: f64) -> Vec<f64> {
        let mut m = vec![0.0; num_nodes];
        for b in &self.batches {
            for i in 0..b.len() {
                for a in 0..b.k {
                    m[b.nodes[i * b.k + a] as usize] += b.mass_share(i, a, density);
                }
            }
        }
        m
    }

    /// The lumped mass (kg) of the node the entries `held` (`(batch, entry,
    /// local)`, as [`crate::assembly::SparsePattern::held_at`] lists them)
    /// share: `m = Σ_e μ^e V_e ρ`, summed in that order.
    pub fn lumped_mass(&self, held: impl Iterator<Item = (usize, usize, usize)>, density: f64) -> f64 {
        held.fold(0.0, |m, (b, i, a)| m + self.batches[b].mass_share(i, a, density))
    }

    /// Total rest volume (m^3).
    pub fn total_volume(&self) -> f64 {
        self.batches.iter().flat_map(|b| b.volume.iter()).sum()
    }
}

/// The slots of one element in a batch being built.
pub(crate) struct Slots<'a> {
    /// Mesh element id.
    pub element: usize,
    /// Rest positions of the element's nodes (m), element-local order.
    pub verts: &'a [[f64; 3]],
    /// Outward surface triangles in local indices (empty if not gathered).
    pub triangles: &'a [[u32; 3]],
    pub volume: &'a mut f64,
    pub mass_fraction: &'a mut [f64],
    pub stiffness: &'a mut [f64],
    pub stress_grads: &'a mut [[f64; 3]],
    /// The element's quadrature points (m) and weights (m³), scratch of
    /// the rule's length for the builder to fill.
    pub points: &'a mut [[f64; 3]],
    pub weights: &'a mut [f64],
}

/// Gathers the `k`-node `elements` into the end of their batch in
/// `batches` (of `kind` with `nq` quadrature points per element, appended
/// if there is none): nodes, rest positions and, when `with_triangles`,
/// the `2k - 4` outward surface triangles in local indices; then fills
/// every new element's slots in parallel, with per-thread scratch from
/// `scratch`, by `build`. On error the batch holds the new entries,
/// partly filled ([`build_into`] takes them off).
#[allow(clippy::too_many_arguments)]
pub(crate) fn fill_batch<S>(
    batches: &mut Vec<Batch>,
    mesh: &PolyMesh,
    material: &Material,
    kind: ElementKind,
    k: usize,
    nq: usize,
    elements: &[u32],
    with_triangles: bool,
    scratch: impl Fn() -> S + Sync + Send,
    build: impl Fn(&mut S, Slots) -> Result<(), BasisError> + Sync + Send,
) -> Result<(), BasisError> {
    let batch = batch_for(batches, kind, k, nq, material.lame());
    let (start, n) = (batch.len(), elements.len());
    let nt = if with_triangles { 2 * k - 4 } else { 0 };
    batch.extend_gathered(mesh, elements, 9 * k * k, nt);
    let nodes = &batch.nodes[start * k..];
    let rest = &batch.rest[start * k..];
    let triangles = &mut batch.triangles[start * nt..];
    if with_triangles {
        // (each element's triangles in its own stretch, in parallel; the
        // first element in order with a wrong count is named)
        let wrong = triangles.par_chunks_mut(nt.max(1)).zip(elements).enumerate().find_map_first(|(i, (out, &e))| {
            let local = &nodes[i * k..(i + 1) * k];
            let mut count = 0;
            for t in mesh.element_triangles(e as usize) {
                if let Some(slot) = out.get_mut(count) {
                    *slot = t.map(|g| local.binary_search(&g).expect("triangle vertex is an element node") as u32);
                }
                count += 1;
            }
            // a closed triangulated sphere with k vertices has 2k - 4 triangles
            (count != nt).then_some(e as usize)
        });
        if let Some(element) = wrong {
            return Err(BasisError::DegenerateElement { element, volume: mesh.element_volume(element) });
        }
    }
    let triangles = &batch.triangles[start * nt..];
    (batch.volume[start..].par_iter_mut())
        .zip(batch.mass_fraction[start * k..].par_chunks_mut(k))
        .zip(batch.stiffness[start * 9 * k * k..].par_chunks_mut(9 * k * k))
        .zip(batch.stress_grads[start * k..].par_chunks_mut(k))
        .enumerate()
        .try_for_each_init(
            || (scratch(), vec![[0.0; 3]; nq], vec![0.0; nq]),
            |(s, points, weights), (i, (((volume, mass_fraction), stiffness), stress_grads))| {
                let slots = Slots {
                    element: elements[i] as usize,
                    verts: &rest[i * k..(i + 1) * k],
                    triangles: &triangles[i * nt..(i + 1) * nt],
                    volume,
                    mass_fraction,
                    stiffness,
                    stress_grads,
                    points,
                    weights,
                };
                build(s, slots)
            },
        )?;
    debug_assert_eq!(batch.len(), start + n);
    Ok(())
}
