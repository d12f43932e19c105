//! Corotated (stiffness-warped) linear elasticity per element, from slices.
//!
//! For an element with `k` nodes at current positions `x_a` (m), rest
//! positions `X_a` (m), stress-point shape function gradients `g_a` (1/m)
//! and stiffness `K_e` (N/m, `3k x 3k`):
//!
//! ```text
//! F   = Σ_a x_a ⊗ g_a                     deformation gradient (exact for
//!                                          tetrahedra, the volume mean else)
//! R   = polar rotation of F               (crate::rotation)
//! f_e = -R K_e (Rᵀ x_e - X_e)             elastic forces (N)
//! K_R = R K_ab Rᵀ                         warped blocks (N/m)
//! ```
//!
//! A tetrahedron needs no `K_e`: with rotated gradients `R g_a`, its warped
//! block is the isotropic block formula ([`crate::elasticity::block`]) and its forces are
//! `f_a = -V R σ g_a`, `σ = λ tr(ε) I + 2μ ε`, `ε = sym(Rᵀ F) - I`.
//!
//! Data layout: per batch of `n` elements with `k` nodes each, `nodes[e k +
//! a]` indexes the positions `x`, `grads[e k + a]` and `rest[e k + a]` are
//! per element node, matrices are row-major `[f64; 9]`, `K_e` row-major
//! `3k x 3k` per element. Each kernel is written once over [`Real`]: the
//! scalar reference runs it on `f64`, the fast path on [`Lanes`] over
//! elements (or over the blocks of a column), with the same operations in
//! the same order, so both agree to the bit on every instruction set.

use pulp::Simd;

use crate::lanes::{Lanes, Real};

/// `Σ_a v_a ⊗ g_a` (row-major): `v` the `k` nodal values, `g` their
/// gradients.
#[inline(always)]
fn field_gradient<R: Real>(v: &[[R; 3]], g: &[[R; 3]]) -> [R; 9] {
    let zero = v[0][0].constant(0.0);
    let mut m = [zero; 9];
    for (va, ga) in v.iter().zip(g) {
        for r in 0..3 {
            for c in 0..3 {
                m[3 * r + c] = m[3 * r + c] + va[r] * ga[c];
            }
        }
    }
    m
}

#[inline(always)]
fn mat_vec<R: Real>(m: &[R; 9], v: [R; 3]) -> [R; 3] {
    [
        m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
        m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
        m[6] * v[0] + m[7] * v[1] + m[8] * v[2],
    ]
}

#[inline(always)]
fn mat_t_vec<R: Real>(m: &[R; 9], v: [R; 3]) -> [R; 3] {
    [
        m[0] * v[0] + m[3] * v[1] + m[6] * v[2],
        m[1] * v[0] + m[4] * v[1] + m[7] * v[2],
        m[2] * v[0] + m[5] * v[1] + m[8] * v[2],
    ]
}

/// Forces `-V R σ g_a` and rotated gradients `R g_a` of one tetrahedron.
#[inline(always)]
fn tet_element<R: Real>(
    r: &[R; 9],
    f: &[R; 9],
    g: &[[R; 3]; 4],
    volume: R,
    lambda: R,
    mu: R,
) -> ([[R; 3]; 4], [[R; 3]; 4]) {
    let one = volume.constant(1.0);
    let half = volume.constant(0.5);
    let two = volume.constant(2.0);
    let zero = volume.constant(0.0);
    // M = Rᵀ F, ε = sym(M) - I
    let mut m = [zero; 9];
    for p in 0..3 {
        for q in 0..3 {
            m[3 * p + q] = r[p] * f[q] + r[3 + p] * f[3 + q] + r[6 + p] * f[6 + q];
        }
    }
    let e = [
        m[0] - one,
        half * (m[1] + m[3]),
        half * (m[2] + m[6]),
        half * (m[1] + m[3]),
        m[4] - one,
        half * (m[5] + m[7]),
        half * (m[2] + m[6]),
        half * (m[5] + m[7]),
        m[8] - one,
    ];
    let tr = e[0] + e[4] + e[8];
    let s: [R; 9] = std::array::from_fn(|pq| two * mu * e[pq] + if pq % 4 == 0 { lambda * tr } else { zero });
    let mut forces = [[zero; 3]; 4];
    let mut rotated = [[zero; 3]; 4];
    for a in 0..4 {
        let sg = mat_vec(&s, g[a]);
        let w = mat_vec(r, sg);
        forces[a] = [-(volume * w[0]), -(volume * w[1]), -(volume * w[2])];
        rotated[a] = mat_vec(r, g[a]);
    }
    (forces, rotated)
}

/// `R K Rᵀ` of one 3x3 block `K` (row-major), times `scale`: `R K` first,
/// then its rows against the rows of `R`.
#[inline(always)]
fn warped<R: Real>(r: &[R; 9], k: &[R; 9], scale: R) -> [R; 9] {
    let zero = scale.constant(0.0);
    let mut rk = [zero; 9];
    for p in 0..3 {
        for q in 0..3 {
            rk[3 * p + q] = r[3 * p] * k[q] + r[3 * p + 1] * k[3 + q] + r[3 * p + 2] * k[6 + q];
        }
    }
    std::array::from_fn(|pq| {
        let (p, q) = (pq / 3, pq % 3);
        scale * (rk[3 * p] * r[3 * q] + rk[3 * p + 1] * r[3 * q + 1] + rk[3 * p + 2] * r[3 * q + 2])
    })
}

/// The largest node count the general-element kernels take (their
/// per-element arrays live on the stack).
pub const MAX_NODES: usize = 256;

/// `f = -R K (Rᵀ x - X)` of one element with `k` nodes (see the module
/// docs); `u` is scratch of `k` values.
#[inline(always)]
fn element_forces<R: Real>(
    r: &[R; 9],
    ke: impl Fn(usize, usize) -> R,
    x: &[[R; 3]],
    rest: &[[R; 3]],
    u: &mut [[R; 3]],
    out: &mut [[R; 3]],
) {
    let k = x.len();
    let zero = r[0].constant(0.0);
    for a in 0..k {
        let l = mat_t_vec(r, x[a]);
        u[a] = [l[0] - rest[a][0], l[1] - rest[a][1], l[2] - rest[a][2]];
    }
    for a in 0..k {
        let mut f = [zero; 3];
        for b in 0..k {
            for rr in 0..3 {
                let row = 3 * a + rr;
                f[rr] =
                    f[rr] + (ke(row, 3 * b) * u[b][0] + ke(row, 3 * b + 1) * u[b][1] + ke(row, 3 * b + 2) * u[b][2]);
            }
        }
        let w = mat_vec(r, f);
        out[a] = [-w[0], -w[1], -w[2]];
    }
}

/// Checks the layout of a batch; panics on a caller bug.
fn check(k: usize, n: usize, nodes: &[u32], per_node: usize) {
    assert_eq!(nodes.len(), n * k, "nodes must hold k per element");
    assert_eq!(per_node, n * k, "per-node arrays must hold k per element");
}

/// Scalar reference of [`deformation_gradients`].
pub fn deformation_gradients_scalar(k: usize, nodes: &[u32], x: &[[f64; 3]], grads: &[[f64; 3]], out: &mut [[f64; 9]]) {
    check(k, out.len(), nodes, grads.len());
    let mut v = [[0.0; 3]; MAX_NODES];
    for (e, f) in out.iter_mut().enumerate() {
        for a in 0..k {
            v[a] = x[nodes[e * k + a] as usize];
        }
        *f = field_gradient(&v[..k], &grads[e * k..(e + 1) * k]);
    }
}

/// Packs `WIDTH` elements' values (the last group padded with its first
/// element) into lanes.
#[inline(always)]
fn pack<S: Simd, const N: usize>(simd: S, width: usize, value: impl Fn(usize, usize) -> f64) -> [Lanes<S>; N] {
    std::array::from_fn(|c| {
        let mut lanes = [0.0f64; 16];
        for (l, slot) in lanes.iter_mut().enumerate().take(width) {
            *slot = value(l, c);
        }
        Lanes::load(simd, &lanes[..width])
    })
}

/// Stores lanes `c` of `values` into `out(l, c)` for the first `n` lanes.
#[inline(always)]
fn unpack<S: Simd, const N: usize>(
    values: [Lanes<S>; N],
    width: usize,
    n: usize,
    mut out: impl FnMut(usize, usize, f64),
) {
    for (c, lane) in values.iter().enumerate() {
        let mut lanes = [0.0f64; 16];
        lane.store(&mut lanes[..width]);
        for (l, &v) in lanes.iter().enumerate().take(n) {
            out(l, c, v);
        }
    }
}

struct Gradients<'a> {
    k: usize,
    nodes: &'a [u32],
    x: &'a [[f64; 3]],
    grads: &'a [[f64; 3]],
    out: &'a mut [[f64; 9]],
}

impl pulp::WithSimd for Gradients<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Gradients { k, nodes, x, grads, out } = self;
        let width = Lanes::<S>::WIDTH;
        let z = Lanes::splat(simd, 0.0);
        let mut v = [[z; 3]; MAX_NODES];
        let mut g = [[z; 3]; MAX_NODES];
        for e0 in (0..out.len()).step_by(width) {
            let n = width.min(out.len() - e0);
            let element = |l: usize| e0 + if l < n { l } else { 0 };
            for a in 0..k {
                v[a] = pack(simd, width, |l, c| x[nodes[element(l) * k + a] as usize][c]);
                g[a] = pack(simd, width, |l, c| grads[element(l) * k + a][c]);
            }
            let f = field_gradient(&v[..k], &g[..k]);
            unpack(f, width, n, |l, c, val| out[e0 + l][c] = val);
        }
    }
}

/// The deformation gradient `F = Σ_a x[nodes[e k + a]] ⊗ grads[e k + a]`
/// of every element of a batch (layout in the module docs), SIMD over
/// elements; bitwise equal to [`deformation_gradients_scalar`].
pub fn deformation_gradients(k: usize, nodes: &[u32], x: &[[f64; 3]], grads: &[[f64; 3]], out: &mut [[f64; 9]]) {
    check(k, out.len(), nodes, grads.len());
    assert!(k <= MAX_NODES, "at most {MAX_NODES} nodes per element");
    pulp::Arch::new().dispatch(Gradients { k, nodes, x, grads, out });
}

/// Scalar reference of [`tet_forces`].
#[allow(clippy::too_many_arguments)]
pub fn tet_forces_scalar(
    rotations: &[[f64; 9]],
    gradients: &[[f64; 9]],
    grads: &[[f64; 3]],
    volumes: &[f64],
    lambda: f64,
    mu: f64,
    forces: &mut [[f64; 3]],
    rotated: &mut [[f64; 3]],
) {
    for e in 0..volumes.len() {
        let g = [grads[4 * e], grads[4 * e + 1], grads[4 * e + 2], grads[4 * e + 3]];
        let (f, rg) = tet_element(&rotations[e], &gradients[e], &g, volumes[e], lambda, mu);
        forces[4 * e..4 * e + 4].copy_from_slice(&f);
        rotated[4 * e..4 * e + 4].copy_from_slice(&rg);
    }
}

struct TetForces<'a> {
    rotations: &'a [[f64; 9]],
    gradients: &'a [[f64; 9]],
    grads: &'a [[f64; 3]],
    volumes: &'a [f64],
    lame: (f64, f64),
    forces: &'a mut [[f64; 3]],
    rotated: &'a mut [[f64; 3]],
}

impl pulp::WithSimd for TetForces<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let TetForces { rotations, gradients, grads, volumes, lame, forces, rotated } = self;
        let width = Lanes::<S>::WIDTH;
        let (lambda, mu) = (Lanes::splat(simd, lame.0), Lanes::splat(simd, lame.1));
        for e0 in (0..volumes.len()).step_by(width) {
            let n = width.min(volumes.len() - e0);
            let element = |l: usize| e0 + if l < n { l } else { 0 };
            let r: [Lanes<S>; 9] = pack(simd, width, |l, c| rotations[element(l)][c]);
            let f: [Lanes<S>; 9] = pack(simd, width, |l, c| gradients[element(l)][c]);
            let g: [[Lanes<S>; 3]; 4] = std::array::from_fn(|a| pack(simd, width, |l, c| grads[4 * element(l) + a][c]));
            let [vol]: [Lanes<S>; 1] = pack(simd, width, |l, _| volumes[element(l)]);
            let (fo, rg) = tet_element(&r, &f, &g, vol, lambda, mu);
            for a in 0..4 {
                unpack(fo[a], width, n, |l, c, v| forces[4 * (e0 + l) + a][c] = v);
                unpack(rg[a], width, n, |l, c, v| rotated[4 * (e0 + l) + a][c] = v);
            }
        }
    }
}

/// Forces `-V R σ g_a` (N) and rotated gradients `R g_a` (1/m) of every
/// tetrahedron of a batch, from its rotation, deformation gradient,
/// gradients (4 per element) and volume (m³), SIMD over elements; bitwise
/// equal to [`tet_forces_scalar`].
#[allow(clippy::too_many_arguments)]
pub fn tet_forces(
    rotations: &[[f64; 9]],
    gradients: &[[f64; 9]],
    grads: &[[f64; 3]],
    volumes: &[f64],
    lambda: f64,
    mu: f64,
    forces: &mut [[f64; 3]],
    rotated: &mut [[f64; 3]],
) {
    let n = volumes.len();
    assert!(rotations.len() == n && gradients.len() == n, "one rotation and gradient per element");
    assert!(grads.len() == 4 * n && forces.len() == 4 * n && rotated.len() == 4 * n, "four per element");
    pulp::Arch::new().dispatch(TetForces { rotations, gradients, grads, volumes, lame: (lambda, mu), forces, rotated });
}

/// Scalar reference of [`element_forces_batch`].
pub fn element_forces_scalar(
    k: usize,
    nodes: &[u32],
    x: &[[f64; 3]],
    rest: &[[f64; 3]],
    stiffness: &[f64],
    rotations: &[[f64; 9]],
    forces: &mut [[f64; 3]],
) {
    check(k, rotations.len(), nodes, rest.len());
    let n = 3 * k;
    let mut xe = [[0.0; 3]; MAX_NODES];
    let mut u = [[0.0; 3]; MAX_NODES];
    for (e, r) in rotations.iter().enumerate() {
        for a in 0..k {
            xe[a] = x[nodes[e * k + a] as usize];
        }
        let ke = &stiffness[e * n * n..(e + 1) * n * n];
        element_forces(
            r,
            |row, col| ke[row * n + col],
            &xe[..k],
            &rest[e * k..(e + 1) * k],
            &mut u[..k],
            &mut forces[e * k..(e + 1) * k],
        );
    }
}

struct ElementForces<'a> {
    k: usize,
    nodes: &'a [u32],
    x: &'a [[f64; 3]],
    rest: &'a [[f64; 3]],
    stiffness: &'a [f64],
    rotations: &'a [[f64; 9]],
    forces: &'a mut [[f64; 3]],
}

impl pulp::WithSimd for ElementForces<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let ElementForces { k, nodes, x, rest, stiffness, rotations, forces } = self;
        let width = Lanes::<S>::WIDTH;
        let n3 = 3 * k;
        let z = Lanes::splat(simd, 0.0);
        let (mut xe, mut re, mut u, mut out) =
            ([[z; 3]; MAX_NODES], [[z; 3]; MAX_NODES], [[z; 3]; MAX_NODES], [[z; 3]; MAX_NODES]);
        for e0 in (0..rotations.len()).step_by(width) {
            let n = width.min(rotations.len() - e0);
            let element = |l: usize| e0 + if l < n { l } else { 0 };
            let r: [Lanes<S>; 9] = pack(simd, width, |l, c| rotations[element(l)][c]);
            for a in 0..k {
                xe[a] = pack(simd, width, |l, c| x[nodes[element(l) * k + a] as usize][c]);
                re[a] = pack(simd, width, |l, c| rest[element(l) * k + a][c]);
            }
            let ke = |row: usize, col: usize| -> Lanes<S> {
                let [v] = pack(simd, width, |l, _| stiffness[element(l) * n3 * n3 + row * n3 + col]);
                v
            };
            element_forces(&r, ke, &xe[..k], &re[..k], &mut u[..k], &mut out[..k]);
            for (a, fa) in out.iter().enumerate().take(k) {
                unpack(*fa, width, n, |l, c, v| forces[(e0 + l) * k + a][c] = v);
            }
        }
    }
}

/// Elastic forces `f_e = -R K_e (Rᵀ x_e - X_e)` (N) of every element of a
/// batch with `k` nodes (layout in the module docs; `stiffness` holds
/// `9 k²` values per element), SIMD over elements; bitwise equal to
/// [`element_forces_scalar`].
pub fn element_forces_batch(
    k: usize,
    nodes: &[u32],
    x: &[[f64; 3]],
    rest: &[[f64; 3]],
    stiffness: &[f64],
    rotations: &[[f64; 9]],
    forces: &mut [[f64; 3]],
) {
    check(k, rotations.len(), nodes, rest.len());
    assert!(k <= MAX_NODES, "at most {MAX_NODES} nodes per element");
    assert_eq!(stiffness.len(), rotations.len() * 9 * k * k, "9 k² stiffness values per element");
    pulp::Arch::new().dispatch(ElementForces { k, nodes, x, rest, stiffness, rotations, forces });
}

/// Scalar reference of [`warped_column`].
pub fn warped_column_scalar(r: &[f64; 9], stiffness: &[f64], k: usize, b: usize, scale: f64, out: &mut [[f64; 9]]) {
    let n = 3 * k;
    for (a, o) in out.iter_mut().enumerate().take(k) {
        let kab: [f64; 9] = std::array::from_fn(|rc| stiffness[(3 * a + rc / 3) * n + 3 * b + rc % 3]);
        *o = warped(r, &kab, scale);
    }
}

struct WarpedColumn<'a> {
    r: &'a [f64; 9],
    stiffness: &'a [f64],
    k: usize,
    b: usize,
    scale: f64,
    out: &'a mut [[f64; 9]],
}

impl pulp::WithSimd for WarpedColumn<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let WarpedColumn { r, stiffness, k, b, scale, out } = self;
        let width = Lanes::<S>::WIDTH;
        let n3 = 3 * k;
        let rl: [Lanes<S>; 9] = std::array::from_fn(|c| Lanes::splat(simd, r[c]));
        let s = Lanes::splat(simd, scale);
        for a0 in (0..k).step_by(width) {
            let n = width.min(k - a0);
            let block = |l: usize| a0 + if l < n { l } else { 0 };
            let kab: [Lanes<S>; 9] =
                pack(simd, width, |l, rc| stiffness[(3 * block(l) + rc / 3) * n3 + 3 * b + rc % 3]);
            let w = warped(&rl, &kab, s);
            unpack(w, width, n, |l, c, v| out[a0 + l][c] = v);
        }
    }
}

/// The warped blocks `scale R K_ab Rᵀ` (N/m, row-major) of one element for
/// every node `a` and the given node `b`, from its `3k x 3k` stiffness,
/// SIMD over `a`; bitwise equal to [`warped_column_scalar`].
pub fn warped_column(r: &[f64; 9], stiffness: &[f64], k: usize, b: usize, scale: f64, out: &mut [[f64; 9]]) {
    assert_eq!(stiffness.len(), 9 * k * k, "K_e must be 3k x 3k");
    assert!(out.len() >= k && b < k, "one block per node");
    pulp::Arch::new().dispatch(WarpedColumn { r, stiffness, k, b, scale, out });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::elasticity::block;
    use crate::lanes::levels;

    fn rotation(t: f64) -> [f64; 9] {
        let q = [(0.5 * t).cos(), 0.3 * (0.5 * t).sin(), 0.8 * (0.5 * t).sin(), 0.52 * (0.5 * t).sin()];
        let l = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
        crate::rotation::rotation_matrix(q.map(|c| c / l))
    }

    /// Inputs of every corotation kernel for one batch.
    struct Batch {
        k: usize,
        nodes: Vec<u32>,
        x: Vec<[f64; 3]>,
        grads: Vec<[f64; 3]>,
        rest: Vec<[f64; 3]>,
        stiffness: Vec<f64>,
        rotations: Vec<[f64; 9]>,
    }

    /// A batch of 11 elements with 5 nodes each (more than any lane width,
    /// not a multiple of it) over 30 positions.
    fn batch() -> Batch {
        let (k, n) = (5, 11);
        let nodes: Vec<u32> = (0..n * k).map(|i| ((i * 7 + 3) % 30) as u32).collect();
        let x: Vec<[f64; 3]> =
            (0..30).map(|i| [(i as f64 * 0.37).sin(), (i as f64 * 0.91).cos(), 0.1 * i as f64]).collect();
        let grads: Vec<[f64; 3]> =
            (0..n * k).map(|i| [(i as f64).cos(), (i as f64 * 1.3).sin(), 0.2 - 0.01 * i as f64]).collect();
        let rest: Vec<[f64; 3]> = (0..n * k).map(|i| [0.1 * i as f64, (i as f64 * 0.5).sin(), 0.3]).collect();
        let stiffness: Vec<f64> = (0..n * 9 * k * k).map(|i| ((i * 31 % 17) as f64 - 8.0) * 1e3).collect();
        let rotations: Vec<[f64; 9]> = (0..n).map(|e| rotation(0.4 * e as f64)).collect();
        Batch { k, nodes, x, grads, rest, stiffness, rotations }
    }

    #[test]
    fn every_kernel_matches_its_scalar_reference_bitwise_on_every_level() {
        let Batch { k, nodes, x, grads, rest, stiffness, rotations } = batch();
        let n = rotations.len();
        let mut want_f = vec![[0.0; 9]; n];
        deformation_gradients_scalar(k, &nodes, &x, &grads, &mut want_f);
        let mut want_forces = vec![[0.0; 3]; n * k];
        element_forces_scalar(k, &nodes, &x, &rest, &stiffness, &rotations, &mut want_forces);
        let tet_grads: Vec<[f64; 3]> = grads[..4 * n].to_vec();
        let volumes: Vec<f64> = (0..n).map(|e| 0.1 + 0.01 * e as f64).collect();
        let (mut want_tf, mut want_rg) = (vec![[0.0; 3]; 4 * n], vec![[0.0; 3]; 4 * n]);
        tet_forces_scalar(&rotations, &want_f, &tet_grads, &volumes, 2e5, 7e4, &mut want_tf, &mut want_rg);
        let mut want_col = vec![[0.0; 9]; k];
        warped_column_scalar(&rotations[3], &stiffness[3 * 9 * k * k..4 * 9 * k * k], k, 2, 0.7, &mut want_col);
        for level in levels::available("corotation") {
            let mut f = vec![[0.0; 9]; n];
            levels::run(level, Gradients { k, nodes: &nodes, x: &x, grads: &grads, out: &mut f });
            assert_eq!(f, want_f, "{level:?}: deformation gradients");
            let mut forces = vec![[0.0; 3]; n * k];
            let op = ElementForces {
                k,
                nodes: &nodes,
                x: &x,
                rest: &rest,
                stiffness: &stiffness,
                rotations: &rotations,
                forces: &mut forces,
            };
            levels::run(level, op);
            assert_eq!(forces, want_forces, "{level:?}: element forces");
            let (mut tf, mut rg) = (vec![[0.0; 3]; 4 * n], vec![[0.0; 3]; 4 * n]);
            let op = TetForces {
                rotations: &rotations,
                gradients: &want_f,
                grads: &tet_grads,
                volumes: &volumes,
                lame: (2e5, 7e4),
                forces: &mut tf,
                rotated: &mut rg,
            };
            levels::run(level, op);
            assert_eq!((tf, rg), (want_tf.clone(), want_rg.clone()), "{level:?}: tetrahedron forces");
            let mut col = vec![[0.0; 9]; k];
            let op = WarpedColumn {
                r: &rotations[3],
                stiffness: &stiffness[3 * 9 * k * k..4 * 9 * k * k],
                k,
                b: 2,
                scale: 0.7,
                out: &mut col,
            };
            levels::run(level, op);
            assert_eq!(col, want_col, "{level:?}: warped blocks");
        }
    }

    /// A rigidly rotated tetrahedron carries no force; its warped block is
    /// `R K Rᵀ` of the rest block.
    #[test]
    fn rigid_rotation_gives_no_tetrahedron_force_and_warped_blocks_rotate() {
        let x = [[0.1, 0.0, 0.2], [1.3, 0.1, 0.0], [0.2, 0.9, -0.1], [0.3, 0.2, 1.1]];
        let (v, g) = crate::tet::gradients(&x).unwrap();
        let r = rotation(1.1);
        let moved: Vec<[f64; 3]> = x.iter().map(|p| mat_vec(&r, *p)).collect();
        let nodes = [0u32, 1, 2, 3];
        let mut f = [[0.0; 9]];
        deformation_gradients_scalar(4, &nodes, &moved, &g, &mut f);
        let (mut forces, mut rotated) = ([[0.0; 3]; 4], [[0.0; 3]; 4]);
        tet_forces_scalar(&[r], &f, &g, &[v.abs()], 2e5, 7e4, &mut forces, &mut rotated);
        assert!(forces.iter().flatten().all(|c| c.abs() < 1e-9), "{forces:?}");
        let (l, m) = (2e5, 7e4);
        let k = block(g[0], g[2], v.abs(), l, m);
        let kr = block(rotated[0], rotated[2], v.abs(), l, m);
        let want = warped(&r, &k, 1.0);
        for i in 0..9 {
            assert!(
                (kr[i] - want[i]).abs() < 1e-9 * k.iter().fold(0.0f64, |a, x| a.max(x.abs())),
                "{kr:?} vs {want:?}"
            );
        }
    }
}
