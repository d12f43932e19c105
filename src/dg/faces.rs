//! The face terms of the discontinuous Galerkin family (kaufmann2008 §5,
//! §7): interior faces glue two elements, boundary faces in a fixed region
//! impose the prescribed displacement weakly.
//!
//! On an interior face with unit normal `n` pointing from its element `K⁻`
//! into `K⁺`, the jump of a field is `⟦u⟧ = (u⁻ - u⁺) ⊗ n`, i.e. side
//! signs `χ⁻ = 1`, `χ⁺ = -1`. With `I = ∫_f N^s_a ∇N^t_b dA` and
//! `M = ∫_f N^s_a N^t_b dA` for local functions `α = (s, a)`, `β = (t, b)`:
//!
//! ```text
//! consistency  B(α, β)_ij = -½ χ_s (λ n_i I_j + μ (δ_ij I·n + I_i n_j))    -∫⟦v⟧:{σ(u)}
//! symmetry     B(β, α)ᵀ                                                   -∫⟦u⟧:{σ(v)}
//! penalty      P(α, β)    = η_f χ_s χ_t M δ_ij                              ∫ η_f ⟦u⟧:⟦v⟧
//! ```
//!
//! interior penalty (`Ip`) takes all three, Babuška–Zlámal (`Bz`) the
//! penalty alone. Warped (§7): the consistency term of trial side `t` turns
//! with `R_t` (`R_t B Rᵀ_t` is `B` of the rotated `n` and `I`), the
//! symmetry term of test side `s` with `R_s`, the penalty not at all; the
//! forces are `-[R_t B (R_tᵀ X - X⁰)]` and so on, so a rigid motion of the
//! whole body leaves no force. A boundary face in a fixed region has one
//! side, full (not halved) consistency terms and a right-hand side from
//! the prescribed displacement `g(x) = d + A x`:
//!
//! ```text
//! ℓ(N_a e_i) = -∫ (λ ∂_i N_a (g·n) + μ (g_i ∇N_a·n + (g·∇N_a) n_i)) + η_f ∫ g_i N_a
//! ```
//!
//! (its consistency terms are not warped: fixed regions hold parts that do
//! not turn). Every integral is exact: the face moments of the element on
//! one side, and the other side's polynomials re-expressed in its frame.

use cleave_kernels::polynomial::{derivative, product, substitution};
use rayon::prelude::*;

use crate::mesh::PolyMesh;
use crate::sim::FixedRegion;
use crate::store::dg::{DgBasis, Flux, MAX_BASIS};

/// The integrals of one interior face, per pair of local functions
/// `α = side · m + a` (side 0 is `K⁻`).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct InteriorFace {
    /// The mesh face.
    pub face: u32,
    /// `[K⁻, K⁺]`.
    pub elements: [u32; 2],
    /// Unit normal from `K⁻` into `K⁺`.
    pub normal: [f64; 3],
    /// `η_f` (Pa/m).
    pub weight: f64,
    /// `∫ N_α N_β dA` (m²), row-major `2m x 2m`.
    pub mass: Vec<f64>,
    /// `∫ N_α ∇N_β dA` (m), row-major `2m x 2m`.
    pub grad: Vec<[f64; 3]>,
}

/// The integrals of one boundary face in a fixed region.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BoundaryFace {
    /// The mesh face.
    pub face: u32,
    /// Its element.
    pub element: u32,
    /// Outward unit normal.
    pub normal: [f64; 3],
    /// `η_f` (Pa/m).
    pub weight: f64,
    /// `∫ N_a N_b dA` (m²), row-major `m x m`.
    pub mass: Vec<f64>,
    /// `∫ N_a ∇N_b dA` (m), row-major `m x m`.
    pub grad: Vec<[f64; 3]>,
    /// The load `ℓ(N_a e_i)` of the prescribed displacement (N), `m`.
    pub load: Vec<[f64; 3]>,
}

/// `B` of the module docs: `-scale (λ n_i I_j + μ (δ_ij I·n + I_i n_j))`.
#[inline]
pub fn consistency_block(n: [f64; 3], i: [f64; 3], scale: f64, lambda: f64, mu: f64) -> [f64; 9] {
    let d = i[0] * n[0] + i[1] * n[1] + i[2] * n[2];
    std::array::from_fn(|rc| {
        let (r, c) = (rc / 3, rc % 3);
        let diagonal = if r == c { d } else { 0.0 };
        -scale * (lambda * n[r] * i[c] + mu * (diagonal + i[r] * n[c]))
    })
}

/// The coefficients of element `b`'s basis in monomials of `frame`'s `ξ`
/// (row-major `m x m`): `N_a = Σ_j E_aj P_j(ξ)`.
fn coefficients_in(b: &DgBasis, frame: [f64; 4]) -> [f64; MAX_BASIS * MAX_BASIS] {
    let m = b.size;
    let degree = if m == 4 { 1 } else { 2 };
    // ξ_b = α ξ + β
    let alpha = frame[3] / b.frame[3];
    let beta = std::array::from_fn(|k| (frame[k] - b.frame[k]) / b.frame[3]);
    let mut s = [0.0; MAX_BASIS * MAX_BASIS];
    substitution(alpha, beta, degree, &mut s);
    let mut e = [0.0; MAX_BASIS * MAX_BASIS];
    for a in 0..m {
        for j in 0..m {
            e[a * m + j] = (0..m).map(|i| b.coefficients[a * m + i] * s[i * m + j]).sum();
        }
    }
    e
}

/// `∫_f N_α N_β` and `∫_f N_α ∇N_β` (physical units) for the functions
/// given by coefficient rows `e` (`r` rows of `m` monomials of the frame
/// with scale `s`), from the face moments `q` in that frame.
fn face_integrals(e: &[f64], r: usize, m: usize, s: f64, q: &[f64]) -> (Vec<f64>, Vec<[f64; 3]>) {
    // derivative coefficients: ∂_k N_β = (1/s) Σ_l d[β][k][l] P_l
    let mut d = vec![[[0.0; MAX_BASIS]; 3]; r];
    for b in 0..r {
        for j in 0..m {
            for k in 0..3 {
                if let Some((factor, lower)) = derivative(j, k) {
                    d[b][k][lower] += e[b * m + j] * factor;
                }
            }
        }
    }
    // h[i][j] = ∫ P_i P_j dA_ξ
    let h: Vec<f64> = (0..m * m).map(|ij| q[product(ij / m, ij % m)]).collect();
    // eh = e h (r x m)
    let mut eh = vec![0.0; r * m];
    for a in 0..r {
        for j in 0..m {
            eh[a * m + j] = (0..m).map(|i| e[a * m + i] * h[i * m + j]).sum();
        }
    }
    let (area, length) = (s * s, s);
    let mut mass = vec![0.0; r * r];
    let mut grad = vec![[0.0; 3]; r * r];
    for a in 0..r {
        for b in 0..r {
            mass[a * r + b] = area * (0..m).map(|j| eh[a * m + j] * e[b * m + j]).sum::<f64>();
            grad[a * r + b] = std::array::from_fn(|k| length * (0..m).map(|l| eh[a * m + l] * d[b][k][l]).sum::<f64>());
        }
    }
    (mass, grad)
}

/// The moments of `face` in `basis`'s frame, with its plane.
fn moments_of(basis: &DgBasis, face: u32) -> Option<(&[f64], [f64; 4])> {
    basis.faces.iter().find(|f| f.face == face).map(|f| (f.moments.as_slice(), f.plane))
}

/// The integrals of the interior face `face` between elements `minus` and
/// `plus`, with weight `weight`.
pub fn interior(face: u32, minus: (u32, &DgBasis), plus: (u32, &DgBasis), weight: f64) -> Option<InteriorFace> {
    let (bm, bp) = (minus.1, plus.1);
    let m = bm.size;
    let (q, plane) = moments_of(bm, face)?;
    let mut e = vec![0.0; 2 * m * m];
    e[..m * m].copy_from_slice(&bm.coefficients[..m * m]);
    e[m * m..].copy_from_slice(&coefficients_in(bp, bm.frame)[..m * m]);
    let (mass, grad) = face_integrals(&e, 2 * m, m, bm.frame[3], q);
    Some(InteriorFace { face, elements: [minus.0, plus.0], normal: [plane[0], plane[1], plane[2]], weight, mass, grad })
}

/// The integrals of boundary face `face` of `element` held by `region`,
/// with weight `weight` and the Lamé parameters for its load.
pub fn boundary(
    face: u32,
    element: (u32, &DgBasis),
    region: &FixedRegion,
    weight: f64,
    lame: (f64, f64),
    flux: Flux,
) -> Option<BoundaryFace> {
    let b = element.1;
    let m = b.size;
    let (q, plane) = moments_of(b, face)?;
    let n = [plane[0], plane[1], plane[2]];
    let (mass, grad) = face_integrals(&b.coefficients[..m * m], m, m, b.frame[3], q);
    // the load needs ∫ N_a, ∫ x_l N_a, ∫ ∇N_a and ∫ x_l ∇N_a: the same
    // integrals against the functions 1 and ξ_l (x_l = c_l + s ξ_l)
    let mut rows = vec![0.0; (m + 4) * m];
    rows[..m * m].copy_from_slice(&b.coefficients[..m * m]);
    for l in 0..4 {
        rows[(m + l) * m + l] = 1.0; // P_0 = 1, P_1..3 = ξ
    }
    let (mix_mass, mix_grad) = face_integrals(&rows, m + 4, m, b.frame[3], q);
    let r = m + 4;
    let (c, s) = ([b.frame[0], b.frame[1], b.frame[2]], b.frame[3]);
    let (lambda, mu) = lame;
    let load = (0..m)
        .map(|a| {
            // ∫ p N_a and ∫ p ∇N_a for p = 1 and p = x_l
            let one = mix_mass[m * r + a];
            let one_grad = mix_grad[m * r + a];
            let x_mass = |l: usize| c[l] * one + s * mix_mass[(m + 1 + l) * r + a];
            let x_grad = |l: usize| -> [f64; 3] {
                let g = mix_grad[(m + 1 + l) * r + a];
                std::array::from_fn(|k| c[l] * one_grad[k] + s * g[k])
            };
            // ∫ g_j N_a and ∫ g_j ∂_k N_a for g_j = d_j + Σ_l A_jl x_l
            let g_mass: [f64; 3] = std::array::from_fn(|j| {
                region.displacement[j] * one + (0..3).map(|l| region.gradient[j][l] * x_mass(l)).sum::<f64>()
            });
            let g_grad: [[f64; 3]; 3] = std::array::from_fn(|j| {
                std::array::from_fn(|k| {
                    region.displacement[j] * one_grad[k]
                        + (0..3).map(|l| region.gradient[j][l] * x_grad(l)[k]).sum::<f64>()
                })
            });
            let gn_grad: [f64; 3] = std::array::from_fn(|k| (0..3).map(|j| g_grad[j][k] * n[j]).sum());
            std::array::from_fn(|i| {
                // -∫ (λ ∂_i N_a (g·n) + μ (g_i ∇N_a·n + (g·∇N_a) n_i)) + η_f ∫ g_i N_a
                let g_dot_grad_a: f64 = (0..3).map(|j| g_grad[j][j]).sum();
                let consistency =
                    lambda * gn_grad[i] + mu * ((0..3).map(|k| g_grad[i][k] * n[k]).sum::<f64>() + g_dot_grad_a * n[i]);
                let consistency = if flux == Flux::Ip { consistency } else { 0.0 };
                -consistency + weight * g_mass[i]
            })
        })
        .collect();
    Some(BoundaryFace { face, element: element.0, normal: n, weight, mass, grad, load })
}

/// Face integrals computed before, to be taken over (moved, not copied)
/// where nothing they depend on changed.
pub struct Previous {
    /// The interior faces and, per mesh face, the index of its entry.
    pub interior: (Vec<InteriorFace>, Vec<u32>),
    /// The boundary faces and, per mesh face, the index of its entry.
    pub boundary: (Vec<BoundaryFace>, Vec<u32>),
    /// Per element, whether it was rebuilt (or is new) since.
    pub rebuilt: Vec<bool>,
}

impl Previous {
    fn unchanged(&self, e: u32) -> bool {
        self.rebuilt.get(e as usize) == Some(&false)
    }

    /// The index of the earlier interior entry of face `f` between `minus`
    /// and `plus`, if neither element was rebuilt.
    fn interior(&self, f: u32, minus: u32, plus: u32) -> Option<u32> {
        let (faces, index) = &self.interior;
        let i = *index.get(f as usize)?;
        let old = faces.get(i as usize)?;
        (self.unchanged(minus) && self.unchanged(plus) && old.elements == [minus, plus]).then_some(i)
    }

    /// Whether face `f` of element `e` had a boundary entry (`Some(index)`)
    /// or none (`Some(None)`), if `e` was not rebuilt (the fixed regions
    /// are the same); `None` when it must be computed.
    fn boundary(&self, f: u32, e: u32) -> Option<Option<u32>> {
        if !self.unchanged(e) {
            return None;
        }
        let (faces, index) = &self.boundary;
        let i = *index.get(f as usize)?;
        Some(faces.get(i as usize).filter(|old| old.element == e).map(|_| i))
    }
}

/// A face's integrals: kept from before (by index) or new.
enum Entry<T> {
    Kept(u32),
    New(T),
}

/// The entries in face order, the kept ones moved out of `old`.
fn resolve<T: Default>(entries: Vec<Entry<T>>, old: &mut [T]) -> Vec<T> {
    entries
        .into_iter()
        .map(|entry| match entry {
            Entry::Kept(i) => std::mem::take(&mut old[i as usize]),
            Entry::New(face) => face,
        })
        .collect()
}

/// The faces of the mesh between elements, and the boundary faces whose
/// vertices all lie in a fixed region (the last region holding them),
/// with their integrals, for penalty `η`, Lamé parameters `lame` and
/// `flux`. `basis(e)` and `volume(e)` describe element `e`. With
/// `previous` (after a topology change, at the same penalty and fixed
/// regions), a face whose elements were not rebuilt keeps its integrals:
/// only the faces around changed elements are integrated again.
#[allow(clippy::too_many_arguments)]
pub fn build<'s>(
    mesh: &PolyMesh,
    fixed: &[FixedRegion],
    penalty: f64,
    lame: (f64, f64),
    flux: Flux,
    basis: &(dyn Fn(u32) -> &'s DgBasis + Sync),
    volume: &(dyn Fn(u32) -> f64 + Sync),
    mut previous: Option<Previous>,
) -> (Vec<InteriorFace>, Vec<BoundaryFace>) {
    let mut users: Vec<Vec<u32>> = vec![Vec::new(); mesh.faces.len()];
    for (e, el) in mesh.elements.iter().enumerate() {
        for r in &el.faces {
            users[r.face as usize].push(e as u32);
        }
    }
    let modulus = lame.0 + 2.0 * lame.1;
    let area = |b: &DgBasis, f: u32| moments_of(b, f).map_or(0.0, |(q, _)| q[0] * b.frame[3] * b.frame[3]);
    let before = previous.as_ref();
    let interior: Vec<Entry<InteriorFace>> = (0..mesh.faces.len() as u32)
        .into_par_iter()
        .filter_map(|f| match users[f as usize].as_slice() {
            &[a, b] => {
                let (minus, plus) = (a.min(b), a.max(b));
                if let Some(i) = before.and_then(|p| p.interior(f, minus, plus)) {
                    return Some(Entry::Kept(i));
                }
                let bm = basis(minus);
                let weight = penalty * modulus * area(bm, f) * (1.0 / volume(minus) + 1.0 / volume(plus));
                interior(f, (minus, bm), (plus, basis(plus)), weight).map(Entry::New)
            }
            _ => None,
        })
        .collect();
    let boundary_faces: Vec<Entry<BoundaryFace>> = (0..mesh.faces.len() as u32)
        .into_par_iter()
        .filter_map(|f| {
            let &[e] = users[f as usize].as_slice() else { return None };
            if let Some(kept) = before.and_then(|p| p.boundary(f, e)) {
                return kept.map(Entry::Kept);
            }
            let vertices = &mesh.faces[f as usize].vertices;
            let region = fixed.iter().rev().find(|r| vertices.iter().all(|&v| r.contains(mesh.nodes[v as usize])))?;
            let b = basis(e);
            let weight = 2.0 * penalty * modulus * area(b, f) / volume(e);
            boundary(f, (e, b), region, weight, lame, flux).map(Entry::New)
        })
        .collect();
    let (mut old_interior, mut old_boundary) =
        previous.take().map_or((Vec::new(), Vec::new()), |p| (p.interior.0, p.boundary.0));
    (resolve(interior, &mut old_interior), resolve(boundary_faces, &mut old_boundary))
}
