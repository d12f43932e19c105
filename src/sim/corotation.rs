//! Stiffness warping (corotated linear elasticity) per element.
//!
//! For every element: the mean deformation gradient `F = Σ_b x_b ⊗ ḡ_b`
//! (exact for tetrahedra; the volume average for polyhedra, `ḡ_b` being the
//! mean shape function gradients), its rotation `R` (polar decomposition,
//! warm-started from the previous step), the elastic forces
//!
//! ```text
//! f_e = -R K_e (Rᵀ x_e - X_e)                                        [N]
//! ```
//!
//! and, for assembly, the warped blocks `R K_ab Rᵀ`. For tetrahedra
//! `K_ab = V (λ g_a g_bᵀ + μ g_b g_aᵀ + μ (g_a·g_b) I)`, so the warped block
//! is the same formula with rotated gradients `R g_a`, and the force is
//! `f_a = -V R σ g_a` with `σ = λ tr(ε) I + 2 μ ε`, `ε = sym(Rᵀ F) - I`: no
//! element matrix is stored or multiplied.

use cleave_kernels::rotation::{polar_rotations, rotation_matrix};
use rayon::prelude::*;

use crate::store::{Batch, ElementStore, StoreChanges};

/// Elements per parallel task of the per-element passes.
const TASK: usize = 256;

/// Per-batch state of the warping.
#[derive(Clone, Debug, Default)]
struct BatchState {
    /// Rotation of each element as a unit quaternion (warm start).
    quaternion: Vec<[f64; 4]>,
    /// Rotation matrix of each element (row-major).
    rotation: Vec<[f64; 9]>,
    /// Deformation gradient of each element (row-major).
    gradient: Vec<[f64; 9]>,
    /// Elastic force on each element node (N), `k` per element.
    force: Vec<[f64; 3]>,
    /// Rotated shape function gradients `R g_a` (tetrahedra), `k` per element.
    rotated_grads: Vec<[f64; 3]>,
}

const IDENTITY: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

impl BatchState {
    /// Removes entry `i` of a batch of `k`-node elements; the last entry
    /// takes its place (as [`ElementStore::update`] does).
    fn swap_remove(&mut self, i: usize, k: usize) {
        fn take_last<T: Copy>(v: &mut Vec<T>, i: usize, per: usize) {
            let n = v.len() / per.max(1);
            if per == 0 || n == 0 {
                return;
            }
            v.copy_within((n - 1) * per.., i * per);
            v.truncate((n - 1) * per);
        }
        take_last(&mut self.quaternion, i, 1);
        take_last(&mut self.rotation, i, 1);
        take_last(&mut self.gradient, i, 1);
        take_last(&mut self.force, i, k);
        if !self.rotated_grads.is_empty() {
            take_last(&mut self.rotated_grads, i, k);
        }
    }

    /// The rotation (row-major) of entry `i` of batch `b` at positions `x`
    /// (m), warm-started from the stored one, without storing it; the
    /// identity if not `warp`.
    fn rotation_at(&self, b: &Batch, i: usize, x: &[[f64; 3]], warp: bool) -> [f64; 9] {
        if !warp {
            return IDENTITY;
        }
        let mut q = [self.quaternion[i]];
        polar_rotations(&[b.field_gradient(i, x)], &mut q);
        rotation_matrix(q[0])
    }

    /// Deformation gradients, rotations (if `warp`), forces and, for
    /// tetrahedra, rotated gradients of the entries `range` of batch `b` at
    /// positions `x` (m); returns the largest number of rotation iterations.
    fn update_range(&mut self, b: &Batch, x: &[[f64; 3]], warp: bool, range: std::ops::Range<usize>) -> usize {
        let k = b.k;
        let first = range.start;
        // 1. deformation gradients
        self.gradient[range.clone()]
            .par_iter_mut()
            .with_min_len(TASK)
            .enumerate()
            .for_each(|(j, f)| *f = b.field_gradient(first + j, x));
        // 2. rotations, SIMD over elements, warm-started
        let mut most = 0;
        if warp {
            most = self.quaternion[range.clone()]
                .par_chunks_mut(TASK)
                .zip(self.gradient[range.clone()].par_chunks(TASK))
                .map(|(q, f)| polar_rotations(f, q))
                .max()
                .unwrap_or(0);
            self.rotation[range.clone()]
                .par_iter_mut()
                .zip(&self.quaternion[range.clone()])
                .for_each(|(r, q)| *r = rotation_matrix(*q));
        }
        // 3. forces (and rotated gradients of tetrahedra)
        let (rotation, gradient) = (&self.rotation, &self.gradient);
        let forces = &mut self.force[first * k..range.end * k];
        if b.is_tet() {
            forces
                .par_chunks_mut(k)
                .zip(self.rotated_grads[first * k..range.end * k].par_chunks_mut(k))
                .enumerate()
                .with_min_len(TASK)
                .for_each(|(j, (f, rg))| {
                    let i = first + j;
                    tet_forces(b, i, &rotation[i], &gradient[i], f, rg)
                });
        } else {
            forces.par_chunks_mut(k).enumerate().with_min_len(TASK / 8).for_each(|(j, f)| {
                let i = first + j;
                let r = &rotation[i];
                let u: Vec<[f64; 3]> = (0..k)
                    .map(|a| {
                        let (xa, xr) = (x[b.nodes[i * k + a] as usize], b.rest[i * k + a]);
                        let l = mat_t_vec(r, xa);
                        [l[0] - xr[0], l[1] - xr[1], l[2] - xr[2]]
                    })
                    .collect();
                b.apply_stiffness(i, &u, f);
                for fa in f.iter_mut() {
                    let w = mat_vec(r, *fa);
                    *fa = [-w[0], -w[1], -w[2]];
                }
            });
        }
        most
    }
}

/// Rotations, forces and warped blocks of every element.
#[derive(Clone, Debug, Default)]
pub struct Corotation {
    batches: Vec<BatchState>,
}

/// `v` as `n` copies of `value`, in the memory it already has.
fn refill<T: Copy>(v: &mut Vec<T>, n: usize, value: T) {
    v.clear();
    v.resize(n, value);
}

#[inline]
fn mat_vec(m: &[f64; 9], v: [f64; 3]) -> [f64; 3] {
    [
        m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
        m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
        m[6] * v[0] + m[7] * v[1] + m[8] * v[2],
    ]
}

#[inline]
fn mat_t_vec(m: &[f64; 9], v: [f64; 3]) -> [f64; 3] {
    [
        m[0] * v[0] + m[3] * v[1] + m[6] * v[2],
        m[1] * v[0] + m[4] * v[1] + m[7] * v[2],
        m[2] * v[0] + m[5] * v[1] + m[8] * v[2],
    ]
}

impl Corotation {
    /// Identity rotations for every element of `store`.
    pub fn new(store: &ElementStore) -> Self {
        let mut corotation = Corotation::default();
        corotation.reset(store);
        corotation
    }

    /// Identity rotations for every element of `store` after its elements
    /// changed, reusing the arrays this already holds.
    pub fn reset(&mut self, store: &ElementStore) {
        let identity = IDENTITY;
        self.batches.resize_with(store.batches.len(), BatchState::default);
        for (b, st) in store.batches.iter().zip(&mut self.batches) {
            refill(&mut st.quaternion, b.len(), [1.0, 0.0, 0.0, 0.0]);
            refill(&mut st.rotation, b.len(), identity);
            refill(&mut st.gradient, b.len(), identity);
            refill(&mut st.force, b.len() * b.k, [0.0; 3]);
            st.rotated_grads.clear();
            if b.is_tet() {
                st.rotated_grads.extend_from_slice(&b.stress_grads);
            }
        }
    }

    /// Recomputes rotations (if `warp`; identity otherwise) and elastic
    /// forces at node positions `x` (m). Returns the largest number of
    /// rotation iterations.
    pub fn update(&mut self, store: &ElementStore, x: &[[f64; 3]], warp: bool) -> usize {
        let mut most = 0;
        for (b, st) in store.batches.iter().zip(&mut self.batches) {
            most = most.max(st.update_range(b, x, warp, 0..b.len()));
        }
        most
    }

    /// Follows the moves of an [`ElementStore::update`]: untouched elements
    /// keep their rotation (the warm start of the next polar decomposition)
    /// wherever their entry moved, and the appended elements get theirs
    /// from positions `x` (m), cold-started from the identity, with their
    /// forces, so that energies and stresses read right after a topology
    /// change are those of the current rotations.
    pub fn apply_changes(&mut self, store: &ElementStore, changes: &StoreChanges, x: &[[f64; 3]], warp: bool) {
        for &(b, i) in &changes.removed {
            let (st, k) = (&mut self.batches[b as usize], store.batches[b as usize].k);
            st.swap_remove(i as usize, k);
        }
        self.batches.resize_with(store.batches.len(), BatchState::default);
        for &(b, start, count) in &changes.appended {
            let (bt, st) = (&store.batches[b as usize], &mut self.batches[b as usize]);
            let end = (start + count) as usize;
            st.quaternion.resize(end, [1.0, 0.0, 0.0, 0.0]);
            st.rotation.resize(end, IDENTITY);
            st.gradient.resize(end, IDENTITY);
            st.force.resize(end * bt.k, [0.0; 3]);
            if bt.is_tet() {
                st.rotated_grads.resize(end * bt.k, [0.0; 3]);
            }
            st.update_range(bt, x, warp, start as usize..end);
        }
    }

    /// A rotation per node (row-major): the normalised sum of the
    /// quaternions of the elements around it, each sign-aligned with the
    /// first (identity for nodes of no element).
    pub fn node_frames(&self, store: &ElementStore, num_nodes: usize) -> Vec<[f64; 9]> {
        let mut sum = vec![[0.0f64; 4]; num_nodes];
        for (b, st) in store.batches.iter().zip(&self.batches) {
            for (i, q) in st.quaternion.iter().enumerate() {
                for &v in &b.nodes[i * b.k..(i + 1) * b.k] {
                    let s = &mut sum[v as usize];
                    let sign = if s[0] * q[0] + s[1] * q[1] + s[2] * q[2] + s[3] * q[3] < 0.0 { -1.0 } else { 1.0 };
                    (0..4).for_each(|c| s[c] += sign * q[c]);
                }
            }
        }
        sum.iter()
            .map(|s| {
                let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2] + s[3] * s[3]).sqrt();
                let q = if len > 0.0 { s.map(|c| c / len) } else { [1.0, 0.0, 0.0, 0.0] };
                rotation_matrix(q)
            })
            .collect()
    }

    /// Rotation (row-major) of entry `i` of batch `batch` of `store` at
    /// positions `x` (m): extracted there, warm-started from the stored
    /// one (the identity if not `warp`).
    pub fn rotation_at(&self, store: &ElementStore, batch: usize, i: usize, x: &[[f64; 3]], warp: bool) -> [f64; 9] {
        self.batches[batch].rotation_at(&store.batches[batch], i, x, warp)
    }

    /// Elastic force on local node `a` of entry `i` of batch `batch` (N).
    #[inline]
    pub fn force(&self, store: &ElementStore, batch: usize, i: usize, a: usize) -> [f64; 3] {
        self.batches[batch].force[i * store.batches[batch].k + a]
    }

    /// The warped blocks `scale R K_ab Rᵀ` (N/m, row-major) of entry `i` of
    /// `batch` for every local `a` and the given `b`.
    #[inline]
    pub fn block_column(
        &self,
        store: &ElementStore,
        batch: usize,
        i: usize,
        b: usize,
        scale: f64,
        out: &mut [[f64; 9]],
    ) {
        let bt = &store.batches[batch];
        let st = &self.batches[batch];
        if bt.is_tet() {
            // K_ab[p][q] = w (λ g_a[p] g_b[q] + μ g_a[q] g_b[p] + μ δ_pq g_a·g_b)
            let g = &st.rotated_grads[i * 4..i * 4 + 4];
            let w = scale * bt.volume[i];
            let gb = g[b];
            let (l, m) = (w * bt.lame.0, w * bt.lame.1);
            let lgb = [l * gb[0], l * gb[1], l * gb[2]];
            let mgb = [m * gb[0], m * gb[1], m * gb[2]];
            for (o, ga) in out.iter_mut().zip(g) {
                let d = ga[0] * mgb[0] + ga[1] * mgb[1] + ga[2] * mgb[2];
                *o = [
                    ga[0] * lgb[0] + ga[0] * mgb[0] + d,
                    ga[0] * lgb[1] + ga[1] * mgb[0],
                    ga[0] * lgb[2] + ga[2] * mgb[0],
                    ga[1] * lgb[0] + ga[0] * mgb[1],
                    ga[1] * lgb[1] + ga[1] * mgb[1] + d,
                    ga[1] * lgb[2] + ga[2] * mgb[1],
                    ga[2] * lgb[0] + ga[0] * mgb[2],
                    ga[2] * lgb[1] + ga[1] * mgb[2],
                    ga[2] * lgb[2] + ga[2] * mgb[2] + d,
                ];
            }
            return;
        }
        let r = &st.rotation[i];
        for (a, o) in out.iter_mut().enumerate() {
            let k = bt.block(i, a, b);
            // R K Rᵀ
            let mut rk = [0.0; 9];
            for p in 0..3 {
                for q in 0..3 {
                    rk[3 * p + q] = r[3 * p] * k[q] + r[3 * p + 1] * k[3 + q] + r[3 * p + 2] * k[6 + q];
                }
            }
            *o = std::array::from_fn(|pq| {
                let (p, q) = (pq / 3, pq % 3);
                scale * (rk[3 * p] * r[3 * q] + rk[3 * p + 1] * r[3 * q + 1] + rk[3 * p + 2] * r[3 * q + 2])
            });
        }
    }

    /// Elastic energy `½ Σ_e (Rᵀx - X)ᵀ K_e (Rᵀx - X)` (J) at positions `x`,
    /// with each element's rotation `R` extracted at `x` (warm-started from
    /// the stored one; the identity if not `warp`): a step leaves the
    /// rotations of the positions it started from, which would misstate
    /// the energy of a body turning fast.
    pub fn energy(&self, store: &ElementStore, x: &[[f64; 3]], warp: bool) -> f64 {
        store
            .batches
            .iter()
            .zip(&self.batches)
            .map(|(b, st)| {
                (0..b.len())
                    .into_par_iter()
                    .with_min_len(TASK)
                    .map(|i| {
                        let k = b.k;
                        let r = st.rotation_at(b, i, x, warp);
                        let u: Vec<[f64; 3]> = (0..k)
                            .map(|a| {
                                let l = mat_t_vec(&r, x[b.nodes[i * k + a] as usize]);
                                let xr = b.rest[i * k + a];
                                [l[0] - xr[0], l[1] - xr[1], l[2] - xr[2]]
                            })
                            .collect();
                        let mut f = vec![[0.0; 3]; k];
                        b.apply_stiffness(i, &u, &mut f);
                        0.5 * u.iter().zip(&f).map(|(u, f)| u[0] * f[0] + u[1] * f[1] + u[2] * f[2]).sum::<f64>()
                    })
                    .collect::<Vec<f64>>()
                    .iter()
                    .sum::<f64>()
            })
            .sum()
    }
}

/// Forces `f_a = -V R σ g_a` and rotated gradients `R g_a` of tetrahedron `i`.
#[inline]
fn tet_forces(b: &Batch, i: usize, r: &[f64; 9], f: &[f64; 9], out: &mut [[f64; 3]], rg: &mut [[f64; 3]]) {
    let (lambda, mu) = b.lame;
    // M = Rᵀ F, ε = sym(M) - I
    let mut m = [0.0; 9];
    for p in 0..3 {
        for q in 0..3 {
            m[3 * p + q] = r[p] * f[q] + r[3 + p] * f[3 + q] + r[6 + p] * f[6 + q];
        }
    }
    let e = [
        m[0] - 1.0,
        0.5 * (m[1] + m[3]),
        0.5 * (m[2] + m[6]),
        0.5 * (m[1] + m[3]),
        m[4] - 1.0,
        0.5 * (m[5] + m[7]),
        0.5 * (m[2] + m[6]),
        0.5 * (m[5] + m[7]),
        m[8] - 1.0,
    ];
    let tr = e[0] + e[4] + e[8];
    let s: [f64; 9] = std::array::from_fn(|pq| 2.0 * mu * e[pq] + if pq % 4 == 0 { lambda * tr } else { 0.0 });
    let v = b.volume[i];
    for a in 0..4 {
        let g = b.stress_grads[i * 4 + a];
        let sg = mat_vec(&s, g);
        let w = mat_vec(r, sg);
        out[a] = [-v * w[0], -v * w[1], -v * w[2]];
        rg[a] = mat_vec(r, g);
    }
}
