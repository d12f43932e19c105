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
//! `3k x 3k` per element.
//!
//! These kernels run as plain `f64` code, element after element. They used
//! to run on SIMD lanes over elements too (the formulas are written over
//! [`Real`]), but with this layout every lane value is gathered from a
//! different element, and the packing cost more than the lanes saved:
//! measured per element on an AVX-512 machine, the lane versions took 2.2x
//! (forces, `k` = 4 to 20), 3.5x (tetrahedron forces), 5x (deformation
//! gradients) and, per warped block, 3.5x the time of this code. Lanes pay
//! where the arithmetic per gathered value is large: the polar
//! decomposition ([`crate::rotation`]) keeps them (7.5x faster).

use crate::lanes::Real;

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

/// Runs `$body` with a constant `$n` that holds `$k` nodes: 8, 32 or
/// [`MAX_NODES`], so that per-node stack arrays of small elements are small
/// (zeroing room for 256 nodes of AVX-512 lanes cost more than the
/// arithmetic of a hexahedron).
macro_rules! with_room {
    ($k:expr, $n:ident => $body:expr) => {
        match $k {
            0..=8 => {
                const $n: usize = 8;
                $body
            }
            9..=32 => {
                const $n: usize = 32;
                $body
            }
            _ => {
                const $n: usize = MAX_NODES;
                $body
            }
        }
    };
}

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

/// The deformation gradient `F = Σ_a x[nodes[e k + a]] ⊗ grads[e k + a]`
/// of every element of a batch (layout in the module docs).
pub fn deformation_gradients(k: usize, nodes: &[u32], x: &[[f64; 3]], grads: &[[f64; 3]], out: &mut [[f64; 9]]) {
    check(k, out.len(), nodes, grads.len());
    assert!(k <= MAX_NODES, "at most {MAX_NODES} nodes per element");
    with_room!(k, N => {
        let mut v = [[0.0; 3]; N];
        for (e, f) in out.iter_mut().enumerate() {
            for a in 0..k {
                v[a] = x[nodes[e * k + a] as usize];
            }
            *f = field_gradient(&v[..k], &grads[e * k..(e + 1) * k]);
        }
    })
}

/// Forces `-V R σ g_a` (N) and rotated gradients `R g_a` (1/m) of every
/// tetrahedron of a batch, from its rotation, deformation gradient,
/// gradients (4 per element) and volume (m³).
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
    for e in 0..n {
        let g = [grads[4 * e], grads[4 * e + 1], grads[4 * e + 2], grads[4 * e + 3]];
        let (f, rg) = tet_element(&rotations[e], &gradients[e], &g, volumes[e], lambda, mu);
        forces[4 * e..4 * e + 4].copy_from_slice(&f);
        rotated[4 * e..4 * e + 4].copy_from_slice(&rg);
    }
}

/// Elastic forces `f_e = -R K_e (Rᵀ x_e - X_e)` (N) of every element of a
/// batch with `k` nodes (layout in the module docs; `stiffness` holds
/// `9 k²` values per element).
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
    let n = 3 * k;
    with_room!(k, N => {
        let mut xe = [[0.0; 3]; N];
        let mut u = [[0.0; 3]; N];
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
    })
}

/// The warped blocks `scale R K_ab Rᵀ` (N/m, row-major) of one element for
/// every node `a` and the given node `b`, from its `3k x 3k` stiffness.
pub fn warped_column(r: &[f64; 9], stiffness: &[f64], k: usize, b: usize, scale: f64, out: &mut [[f64; 9]]) {
    assert_eq!(stiffness.len(), 9 * k * k, "K_e must be 3k x 3k");
    assert!(out.len() >= k && b < k, "one block per node");
    let n = 3 * k;
    for (a, o) in out.iter_mut().enumerate().take(k) {
        let kab: [f64; 9] = std::array::from_fn(|rc| stiffness[(3 * a + rc / 3) * n + 3 * b + rc % 3]);
        *o = warped(r, &kab, scale);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::elasticity::block;

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

    /// A batch of 11 elements with 5 nodes each over 30 positions.
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

    /// The batched kernels against the formulas written out with dense
    /// matrices, element by element.
    #[test]
    fn batched_kernels_match_the_formulas_element_by_element() {
        let Batch { k, nodes, x, grads, rest, stiffness, rotations } = batch();
        let n = rotations.len();
        let (mut f, mut forces) = (vec![[0.0; 9]; n], vec![[0.0; 3]; n * k]);
        deformation_gradients(k, &nodes, &x, &grads, &mut f);
        element_forces_batch(k, &nodes, &x, &rest, &stiffness, &rotations, &mut forces);
        let close = |a: f64, b: f64, scale: f64| (a - b).abs() <= 1e-12 * scale;
        for e in 0..n {
            let xe = |a: usize| x[nodes[e * k + a] as usize];
            for (rc, &got) in f[e].iter().enumerate() {
                let want: f64 = (0..k).map(|a| xe(a)[rc / 3] * grads[e * k + a][rc % 3]).sum();
                assert!(close(got, want, 10.0), "F of element {e}");
            }
            let r = &rotations[e];
            let ke = &stiffness[e * 9 * k * k..(e + 1) * 9 * k * k];
            // u = Rᵀ x - X, then f = -R K u
            let u: Vec<f64> = (0..3 * k)
                .map(|i| (0..3).map(|p| r[3 * p + i % 3] * xe(i / 3)[p]).sum::<f64>() - rest[e * k + i / 3][i % 3])
                .collect();
            let ku: Vec<f64> = (0..3 * k).map(|i| (0..3 * k).map(|j| ke[i * 3 * k + j] * u[j]).sum()).collect();
            let scale = ku.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for a in 0..k {
                for p in 0..3 {
                    let want = -(0..3).map(|q| r[3 * p + q] * ku[3 * a + q]).sum::<f64>();
                    assert!(close(forces[e * k + a][p], want, scale), "force on node {a} of element {e}");
                }
            }
        }
        // warped blocks R K_ab Rᵀ of one element's column b = 2
        let (e, b, scale) = (3, 2, 0.7);
        let ke = &stiffness[e * 9 * k * k..(e + 1) * 9 * k * k];
        let mut col = vec![[0.0; 9]; k];
        warped_column(&rotations[e], ke, k, b, scale, &mut col);
        let r = &rotations[e];
        for (a, blk) in col.iter().enumerate() {
            let kab = |p: usize, q: usize| ke[(3 * a + p) * 3 * k + 3 * b + q];
            for p in 0..3 {
                for q in 0..3 {
                    let want: f64 = (0..3)
                        .flat_map(|s| (0..3).map(move |t| (s, t)))
                        .map(|(s, t)| r[3 * p + s] * kab(s, t) * r[3 * q + t])
                        .sum();
                    assert!(close(blk[3 * p + q], scale * want, 1e5), "warped block {a}");
                }
            }
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
        deformation_gradients(4, &nodes, &moved, &g, &mut f);
        let (mut forces, mut rotated) = ([[0.0; 3]; 4], [[0.0; 3]; 4]);
        tet_forces(&[r], &f, &g, &[v.abs()], 2e5, 7e4, &mut forces, &mut rotated);
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
