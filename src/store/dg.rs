//! Discontinuous Galerkin elements (kaufmann2008 §4-7): on every element,
//! vector polynomials of degree 1 or 2 with element-owned coefficients,
//! on any planar-faced polyhedron, convex or not.
//!
//! Each element has a frame, a centre `c` (the mean of its vertices) and a
//! scale `s` (the largest distance from `c` to a vertex), and the monomials
//! `P_j(ξ)` of `ξ = (x - c) / s` up to the degree (4 or 10 of them). The
//! basis is their Gram–Schmidt orthonormalisation over the element,
//!
//! ```text
//! N_i = Σ_j C_ij P_j,  C = L⁻¹,  L Lᵀ = G,  G_ij = (1/V) ∫_K P_i P_j dV,
//! ```
//!
//! so `(1/V) ∫_K N_i N_j = δ_ij`: the consistent mass matrix is diagonal,
//! `ρ V` per coefficient, exactly (no lumping). The nested spans of the
//! monomials do not depend on the frame, so neither does the basis (up to
//! rounding): the frame only keeps the integrals well conditioned. `N_0 = 1`
//! and the others integrate to zero, so gravity acts on the first
//! coefficient only, with weight `ρ V`.
//!
//! Every integral is exact: volume moments `∫_K ξ^α` (degree up to twice
//! the basis degree) come from the face moments by the divergence theorem
//! ([`cleave_kernels::moments`]), and each face's moments are kept with the
//! element so that after a cut only the faces it changed are integrated
//! again (the children of a split keep their parent's frame).
//!
//! From them: the element stiffness `K_ab = ∫ B_aᵀ C B_b` (through the
//! Gram matrix of the gradients, [`cleave_kernels::elasticity`]), the mean
//! gradients `ḡ_a = (1/V) ∫ ∇N_a` (the deformation gradient of the
//! corotation is `F = Σ_a x_a ⊗ ḡ_a`), and the coefficients `X⁰` of the
//! identity map, `Σ_a X⁰_a N_a(x) = x` (kaufmann2008 §7: the rest state of
//! a non-nodal basis), which play the part of rest positions.

use cleave_kernels::elasticity::stiffness_from_gram;
use cleave_kernels::moments::{add_face_to_volume, face_moments, MAX_FACE_VERTICES};
use cleave_kernels::polynomial::{count, derivative, product, values};
use rayon::prelude::*;

use super::{BasisError, Batch, ElementKind};
use crate::material::Material;
use crate::mesh::PolyMesh;
use crate::param::ParamError;

/// The most basis functions of an element (degree 2).
pub const MAX_BASIS: usize = count(2);

/// How the faces glue the elements (kaufmann2008 §4).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Flux {
    /// Interior penalty: consistent, symmetric, stable for a large enough
    /// penalty (doubled from the given one until the system is positive
    /// definite).
    #[default]
    Ip,
    /// Babuška–Zlámal: the penalty on the jumps alone; stable for any
    /// penalty, not consistent.
    Bz,
}

/// Options of the discontinuous Galerkin family.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DgOptions {
    /// Polynomial degree, 1 (4 functions) or 2 (10).
    pub degree: usize,
    /// The face terms.
    pub flux: Flux,
    /// The penalty `η` (dimensionless): the face weight is
    /// `η_f = η (λ + 2μ) area(f) (1/vol(K⁻) + 1/vol(K⁺))` (Pa/m), the
    /// paper's eq. 7 scaled by the P-wave modulus so that `η` needs no
    /// units; for boundary faces `2 η (λ + 2μ) area / vol(K)`. With `Ip`
    /// the starting value.
    pub penalty: f64,
}

impl Default for DgOptions {
    /// Degree 1, interior penalty starting at `η = 1` (the paper's
    /// experiments end at 10 to 100 after doubling).
    fn default() -> Self {
        DgOptions { degree: 1, flux: Flux::Ip, penalty: 1.0 }
    }
}

impl DgOptions {
    /// Checks `degree ∈ {1, 2}` and `penalty` finite `> 0`.
    pub fn check(&self) -> Result<(), ParamError> {
        if !(1..=2).contains(&self.degree) {
            return Err(ParamError::new("degree", self.degree, "must be 1 or 2"));
        }
        crate::param::positive("penalty", self.penalty, "must be a finite number > 0").map(|_| ())
    }

    /// Basis functions per element.
    pub fn size(&self) -> usize {
        count(self.degree)
    }
}

/// One face of an element with its moments in the element's frame.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FaceMoments {
    /// The mesh face.
    pub face: u32,
    /// Its vertex loop, counter-clockwise about the element's outward
    /// normal.
    pub vertices: Vec<u32>,
    /// Its plane in the frame: outward unit normal and offset `[a, b]`.
    pub plane: [f64; 4],
    /// `∫_F ξ^α dA_ξ` for `|α|` up to twice the degree.
    pub moments: Vec<f64>,
}

/// The orthonormal polynomial basis of one element (see the module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DgBasis {
    /// Centre `c` (m) and scale `s` (m): `ξ = (x - c) / s`.
    pub frame: [f64; 4],
    /// Number of basis functions `m`.
    pub size: usize,
    /// `C` (row-major, `m x m`, lower triangular): `N_i = Σ_j C_ij P_j`.
    #[serde(with = "serde_big_array::BigArray")]
    pub coefficients: [f64; MAX_BASIS * MAX_BASIS],
    /// The element's faces and their moments.
    pub faces: Vec<FaceMoments>,
    /// `∫_K ξ^α dV_ξ` for `|α|` up to twice the degree.
    pub moments: Vec<f64>,
}

impl DgBasis {
    /// The frame coordinates `ξ = (x - c) / s` of `x` (m).
    pub fn local(&self, x: [f64; 3]) -> [f64; 3] {
        let s = self.frame[3];
        std::array::from_fn(|k| (x[k] - self.frame[k]) / s)
    }

    /// The values `N_i(x)` of the basis at `x` (m) into `out` (`m` values).
    pub fn values(&self, x: [f64; 3], out: &mut [f64]) {
        let m = self.size;
        let mut p = [0.0; MAX_BASIS];
        values(self.local(x), if m == 4 { 1 } else { 2 }, &mut p);
        for (i, o) in out.iter_mut().enumerate().take(m) {
            *o = (0..=i).map(|j| self.coefficients[i * m + j] * p[j]).sum();
        }
    }
}

/// `L` with `L Lᵀ = g` (row-major `n x n`, lower), or `None` unless `g` is
/// positive definite.
fn cholesky(g: &[f64], n: usize) -> Option<[f64; MAX_BASIS * MAX_BASIS]> {
    let mut l = [0.0; MAX_BASIS * MAX_BASIS];
    for j in 0..n {
        let d = g[j * n + j] - (0..j).map(|p| l[j * n + p] * l[j * n + p]).sum::<f64>();
        if !(d > 0.0) {
            return None;
        }
        let d = d.sqrt();
        l[j * n + j] = d;
        for i in j + 1..n {
            l[i * n + j] = (g[i * n + j] - (0..j).map(|p| l[i * n + p] * l[j * n + p]).sum::<f64>()) / d;
        }
    }
    Some(l)
}

/// The inverse of a lower triangular `n x n` matrix (row-major).
pub(crate) fn lower_inverse(l: &[f64], n: usize) -> [f64; MAX_BASIS * MAX_BASIS] {
    let mut c = [0.0; MAX_BASIS * MAX_BASIS];
    for j in 0..n {
        c[j * n + j] = 1.0 / l[j * n + j];
        for i in j + 1..n {
            let s: f64 = (j..i).map(|p| l[i * n + p] * c[p * n + j]).sum();
            c[i * n + j] = -s / l[i * n + i];
        }
    }
    c
}

/// `T` (row-major `m x m`) with `N^parent_i = Σ_j T_ij N^child_j` for two
/// bases in one frame given by their coefficients (`C_parent C_child⁻¹`):
/// a field with parent coefficients `U` has child coefficients `Tᵀ U`.
pub fn transfer(parent: &[f64], child: &[f64], m: usize) -> [f64; MAX_BASIS * MAX_BASIS] {
    // C_child⁻¹ = L_child, lower triangular
    let l = lower_inverse(child, m);
    let mut t = [0.0; MAX_BASIS * MAX_BASIS];
    for i in 0..m {
        for j in 0..=i {
            t[i * m + j] = (j..=i).map(|p| parent[i * m + p] * l[p * m + j]).sum();
        }
    }
    t
}

/// The frame of element `e`: the mean of its vertices and the largest
/// distance from it to a vertex.
fn frame_of(mesh: &PolyMesh, e: usize) -> [f64; 4] {
    let nodes = &mesh.elements[e].nodes;
    let mut c = [0.0; 3];
    for &v in nodes {
        (0..3).for_each(|k| c[k] += mesh.nodes[v as usize][k] / nodes.len() as f64);
    }
    let s = nodes
        .iter()
        .map(|&v| {
            let x = mesh.nodes[v as usize];
            ((x[0] - c[0]).powi(2) + (x[1] - c[1]).powi(2) + (x[2] - c[2]).powi(2)).sqrt()
        })
        .fold(0.0, f64::max);
    [c[0], c[1], c[2], s]
}

/// The faces of element `e` with their outward loops, their moments taken
/// from `cache` where a face with the same loop is there (same frame), and
/// the loops still to integrate listed in `todo` as `(index, loop)`.
fn faces_of(mesh: &PolyMesh, e: usize, cache: Option<&DgBasis>, todo: &mut Vec<usize>) -> Vec<FaceMoments> {
    let mut out = Vec::with_capacity(mesh.elements[e].faces.len());
    for r in &mesh.elements[e].faces {
        let mut vertices = mesh.faces[r.face as usize].vertices.to_vec();
        if !r.outward {
            vertices.reverse();
        }
        // the same polygon (a cut renames nodes it duplicates: compare where
        // the vertices are, which a cut never changes)
        let same = |f: &FaceMoments| {
            f.vertices.len() == vertices.len()
                && f.vertices.iter().zip(&vertices).all(|(&a, &b)| mesh.nodes[a as usize] == mesh.nodes[b as usize])
        };
        match cache.and_then(|b| b.faces.iter().find(|f| same(f))) {
            Some(known) => out.push(FaceMoments { face: r.face, vertices, ..known.clone() }),
            None => {
                todo.push(out.len());
                out.push(FaceMoments { face: r.face, vertices, plane: [0.0; 4], moments: Vec::new() });
            }
        }
    }
    out
}

/// Builds the batch of discontinuous Galerkin `elements`. `inherit(e)` is
/// the basis element `e` takes its frame and face moments from (its own
/// before a cut changed it, or its parent's), if any. Returns the batch and
/// the number of faces integrated (the others were reused).
pub(super) fn build_batch(
    mesh: &PolyMesh,
    material: &Material,
    options: &DgOptions,
    elements: Vec<u32>,
    inherit: &(dyn Fn(u32) -> Option<DgBasis> + Sync),
) -> Result<(Batch, usize), BasisError> {
    let (m, d) = (options.size(), 2 * options.degree);
    let nm = count(d);
    // 1. frames and faces, reusing the moments of unchanged faces
    let mut bases = Vec::with_capacity(elements.len());
    let mut todo: Vec<(usize, usize)> = Vec::new();
    for (i, &e) in elements.iter().enumerate() {
        let parent = inherit(e);
        let frame = parent.as_ref().map_or_else(|| frame_of(mesh, e as usize), |p| p.frame);
        let mut list = Vec::new();
        let faces = faces_of(mesh, e as usize, parent.as_ref(), &mut list);
        if let Some(f) = faces.iter().find(|f| !(3..=MAX_FACE_VERTICES).contains(&f.vertices.len())) {
            let volume = mesh.element_volume(e as usize);
            let _ = f;
            return Err(BasisError::DegenerateElement { element: e as usize, volume });
        }
        todo.extend(list.into_iter().map(|f| (i, f)));
        let basis = DgBasis { frame, size: m, coefficients: [0.0; MAX_BASIS * MAX_BASIS], faces, moments: Vec::new() };
        bases.push(basis);
    }
    // 2. the new faces' moments, batched by vertex count (SIMD over faces)
    let integrated = todo.len();
    todo.sort_by_key(|&(i, f)| (bases[i].faces[f].vertices.len(), i, f));
    let mut start = 0;
    while start < todo.len() {
        let n = bases[todo[start].0].faces[todo[start].1].vertices.len();
        let end = start + todo[start..].iter().take_while(|&&(i, f)| bases[i].faces[f].vertices.len() == n).count();
        let group = &todo[start..end];
        let vertices: Vec<[f64; 3]> = group
            .iter()
            .flat_map(|&(i, f)| {
                let basis = &bases[i];
                basis.faces[f].vertices.iter().map(move |&v| basis.local(mesh.nodes[v as usize]))
            })
            .collect();
        let mut moments = vec![0.0; group.len() * nm];
        let mut planes = vec![[0.0; 4]; group.len()];
        const CHUNK: usize = 64;
        moments
            .par_chunks_mut(CHUNK * nm)
            .zip(planes.par_chunks_mut(CHUNK))
            .zip(vertices.par_chunks(CHUNK * n))
            .for_each(|((mo, pl), ve)| face_moments(n, d, ve, mo, pl));
        for (j, &(i, f)) in group.iter().enumerate() {
            let face = &mut bases[i].faces[f];
            face.plane = planes[j];
            face.moments = moments[j * nm..(j + 1) * nm].to_vec();
        }
        start = end;
    }
    // 3. per element: volume moments, basis, volume terms
    let n = elements.len();
    let (lambda, mu) = material.lame();
    let mut volume = vec![0.0; n];
    let mut stiffness = vec![0.0; n * 9 * m * m];
    let mut stress_grads = vec![[0.0; 3]; n * m];
    let mut rest = vec![[0.0; 3]; n * m];
    bases
        .par_iter_mut()
        .zip(volume.par_iter_mut())
        .zip(stiffness.par_chunks_mut(9 * m * m))
        .zip(stress_grads.par_chunks_mut(m))
        .zip(rest.par_chunks_mut(m))
        .enumerate()
        .try_for_each(|(i, ((((basis, vol), ke), grads), x0))| {
            let element = elements[i] as usize;
            let degenerate = || BasisError::DegenerateElement { element, volume: mesh.element_volume(element) };
            let mut mu_v = vec![0.0; nm];
            for f in &basis.faces {
                add_face_to_volume(d, &f.moments, f.plane, &mut mu_v);
            }
            let v_xi = mu_v[0];
            if !(v_xi > 0.0) {
                return Err(degenerate());
            }
            let g: Vec<f64> = (0..m * m).map(|ij| mu_v[product(ij / m, ij % m)] / v_xi).collect();
            let l = cholesky(&g, m).ok_or_else(degenerate)?;
            let c = lower_inverse(&l, m);
            let s = basis.frame[3];
            *vol = s * s * s * v_xi;
            // gradients of the basis: (1/s) Σ_j C_aj ∂P_j, over monomials of degree <= p - 1
            let ng = count(options.degree - 1);
            let mut grad = [[[0.0; MAX_BASIS]; 3]; MAX_BASIS];
            for a in 0..m {
                for j in 0..=a {
                    for k in 0..3 {
                        if let Some((factor, lower)) = derivative(j, k) {
                            grad[a][k][lower] += c[a * m + j] * factor / s;
                        }
                    }
                }
            }
            // S[3a+k][3b+q] = ∫ ∂_k N_a ∂_q N_b dV = s³ Σ g g' μ
            let nn = 3 * m;
            let mut gram = vec![0.0; nn * nn];
            for a in 0..m {
                for k in 0..3 {
                    for b in 0..m {
                        for q in 0..3 {
                            let mut sum = 0.0;
                            for l1 in 0..ng {
                                for l2 in 0..ng {
                                    sum += grad[a][k][l1] * grad[b][q][l2] * mu_v[product(l1, l2)];
                                }
                            }
                            gram[(3 * a + k) * nn + 3 * b + q] = s * s * s * sum;
                        }
                    }
                }
            }
            stiffness_from_gram(&gram, m, lambda, mu, ke);
            for a in 0..m {
                grads[a] = std::array::from_fn(|k| {
                    s * s * s * (0..ng).map(|l1| grad[a][k][l1] * mu_v[l1]).sum::<f64>() / *vol
                });
                // X⁰_a = c δ_a0 + s L_{1+k, a}
                x0[a] = std::array::from_fn(|k| {
                    let centre = if a == 0 { basis.frame[k] } else { 0.0 };
                    centre + s * l[(1 + k) * m + a]
                });
            }
            basis.coefficients = c;
            basis.moments = mu_v;
            Ok(())
        })?;
    let nodes: Vec<u32> = elements.iter().flat_map(|&e| (0..m as u32).map(move |a| e * m as u32 + a)).collect();
    let batch = Batch {
        k: m,
        kind: ElementKind::Dg,
        elements,
        nodes,
        rest,
        volume,
        mass_fraction: vec![1.0; n * m],
        stiffness,
        lame: (lambda, mu),
        stress_grads,
        triangles: Default::default(),
        points_per_element: 0,
        dg: bases,
    };
    Ok((batch, integrated))
}
