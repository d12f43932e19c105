//! Stiffness warping (corotated linear elasticity): the per-element state
//! of a step.
//!
//! For every element: the mean deformation gradient `F = Σ_b x_b ⊗ ḡ_b`
//! (exact for tetrahedra; the volume average for polyhedra, `ḡ_b` being the
//! mean shape function gradients), its rotation `R` (polar decomposition,
//! warm-started from the previous step), the elastic forces
//! `f_e = -R K_e (Rᵀ x_e - X_e)` (N) and, for assembly, the warped blocks
//! `R K_ab Rᵀ`. The arithmetic is in [`cleave_kernels::corotation`] and
//! [`cleave_kernels::rotation`]; this module keeps the state per batch,
//! aligned with the [`ElementStore`]'s entries across topology changes.

use cleave_kernels::corotation::{deformation_gradients, element_forces_batch, tet_forces, warped_column};
use cleave_kernels::elasticity::block;
use cleave_kernels::rotation::{polar_rotations, rotation_matrix};
use rayon::prelude::*;

use crate::assembly::prefetch;
use crate::store::{Batch, ElementStore, StoreChanges};

/// Elements per parallel task of the per-element passes.
const TASK: usize = 256;

const IDENTITY: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

/// Per-batch state of the warping.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
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

impl BatchState {
    /// Room for `n` entries of a batch of `k`-node elements; new entries
    /// start at the identity.
    fn resize(&mut self, n: usize, b: &Batch) {
        self.quaternion.resize(n, [1.0, 0.0, 0.0, 0.0]);
        self.rotation.resize(n, IDENTITY);
        self.gradient.resize(n, IDENTITY);
        self.force.resize(n * b.k, [0.0; 3]);
        self.rotated_grads.resize(if b.is_tet() { n * b.k } else { 0 }, [0.0; 3]);
    }

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

    /// The deformation gradients and rotations (both row-major) of every
    /// entry of batch `b` at positions `x` (m), the rotations warm-started
    /// from the stored ones (SIMD over elements, as in a step) without
    /// storing them; identities if not `warp`.
    fn rotations_at(&self, b: &Batch, x: &[[f64; 3]], warp: bool) -> (Vec<[f64; 9]>, Vec<[f64; 9]>) {
        let (mut gradients, mut rotations, mut q) =
            (vec![IDENTITY; b.len()], vec![IDENTITY; b.len()], self.quaternion.clone());
        gradients_and_rotations(b, x, warp, 0..b.len(), &mut gradients, &mut q, &mut rotations);
        (gradients, rotations)
    }

    /// Deformation gradients, rotations (if `warp`), forces and, for
    /// tetrahedra, rotated gradients of the entries `range` of batch `b` at
    /// positions `x` (m); returns the largest number of rotation iterations.
    ///
    /// One parallel pass over chunks of elements does all four, so that a
    /// chunk's gradients and rotations are read back from the cache (in
    /// four passes over bunny_100k's 97k tetrahedra, they went to memory
    /// and back between them: 5.0-5.2 ms per step, one pass 4.5-4.6 ms,
    /// 2 cores, Intel Xeon).
    fn update_range(&mut self, b: &Batch, x: &[[f64; 3]], warp: bool, range: std::ops::Range<usize>) -> usize {
        let (k, first, end) = (b.k, range.start, range.end);
        let chunk = if b.is_tet() { TASK } else { (TASK / 8).max(1) };
        let per = 9 * k * k;
        // a chunk from entry `at`: its gradients, rotations and forces
        let elements = |at: usize,
                        f: &mut [[f64; 9]],
                        q: &mut [[f64; 4]],
                        r: &mut [[f64; 9]],
                        force: &mut [[f64; 3]],
                        rotated: Option<&mut [[f64; 3]]>|
         -> usize {
            let iterations = chunk_rotations(b, x, warp, at, f, q, r);
            let span = at * k..(at + f.len()) * k;
            match rotated {
                Some(rotated) => {
                    let (lambda, mu) = b.lame;
                    let volumes = &b.volume[at..at + f.len()];
                    tet_forces(r, f, &b.stress_grads[span], volumes, lambda, mu, force, rotated);
                }
                None => {
                    let ke = &b.stiffness[at * per..(at + f.len()) * per];
                    element_forces_batch(k, &b.nodes[span.clone()], x, &b.rest[span], ke, r, force);
                }
            }
            iterations
        };
        let state = (self.gradient[range.clone()].par_chunks_mut(chunk))
            .zip(self.quaternion[range.clone()].par_chunks_mut(chunk))
            .zip(self.rotation[range.clone()].par_chunks_mut(chunk))
            .zip(self.force[first * k..end * k].par_chunks_mut(chunk * k))
            .enumerate();
        let most = match b.is_tet() {
            true => state
                .zip(self.rotated_grads[first * k..end * k].par_chunks_mut(chunk * k))
                .map(|((c, (((f, q), r), force)), rotated)| elements(first + c * chunk, f, q, r, force, Some(rotated)))
                .max(),
            false => state.map(|(c, (((f, q), r), force))| elements(first + c * chunk, f, q, r, force, None)).max(),
        };
        most.unwrap_or(0)
    }
}

/// The deformation gradients of the entries `range` of batch `b` at
/// positions `x` (m) into `gradient`, and, if `warp`, their rotations
/// (row-major) into `rotation`, in parallel over chunks of entries (see
/// [`chunk_rotations`]); the three slices hold the range's entries.
/// Returns the largest number of rotation iterations.
fn gradients_and_rotations(
    b: &Batch,
    x: &[[f64; 3]],
    warp: bool,
    range: std::ops::Range<usize>,
    gradient: &mut [[f64; 9]],
    quaternion: &mut [[f64; 4]],
    rotation: &mut [[f64; 9]],
) -> usize {
    let chunks = gradient.par_chunks_mut(TASK).zip(quaternion.par_chunks_mut(TASK)).zip(rotation.par_chunks_mut(TASK));
    let most = chunks.enumerate().map(|(c, ((f, q), r))| chunk_rotations(b, x, warp, range.start + c * TASK, f, q, r));
    most.max().unwrap_or(0)
}

/// The deformation gradients `f` of the entries of batch `b` from entry
/// `at` on (as many as `f` holds) at positions `x` (m), and, if `warp`,
/// their rotations `r` (row-major; SIMD over elements, the polar
/// decomposition warm-started from the quaternions `q`, which it
/// updates). Returns the largest number of rotation iterations.
fn chunk_rotations(
    b: &Batch,
    x: &[[f64; 3]],
    warp: bool,
    at: usize,
    f: &mut [[f64; 9]],
    q: &mut [[f64; 4]],
    r: &mut [[f64; 9]],
) -> usize {
    let span = at * b.k..(at + f.len()) * b.k;
    deformation_gradients(b.k, &b.nodes[span.clone()], x, &b.stress_grads[span], f);
    if !warp {
        return 0;
    }
    let iterations = polar_rotations(f, q);
    r.iter_mut().zip(q.iter()).for_each(|(r, q)| *r = rotation_matrix(*q));
    iterations
}

/// Rotations, forces and warped blocks of every element.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Corotation {
    batches: Vec<BatchState>,
}

impl Corotation {
    /// Identity rotations for every element of `store`.
    pub fn new(store: &ElementStore) -> Self {
        let mut corotation = Corotation::default();
        corotation.batches.resize_with(store.batches.len(), BatchState::default);
        for (b, st) in store.batches.iter().zip(&mut corotation.batches) {
            st.resize(b.len(), b);
            if b.is_tet() {
                st.rotated_grads.copy_from_slice(&b.stress_grads);
            }
        }
        corotation
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
            st.resize(end, bt);
            st.update_range(bt, x, warp, start as usize..end);
        }
    }

    /// The rotation (row-major) of entry `i` of batch `batch` as of the last
    /// update (the identity before the first, or when not warped).
    #[inline]
    pub fn rotation(&self, batch: usize, i: usize) -> &[f64; 9] {
        &self.batches[batch].rotation[i]
    }

    /// The rotation quaternion of entry `i` of batch `batch`.
    pub fn quaternion(&self, batch: usize, i: usize) -> [f64; 4] {
        self.batches[batch].quaternion[i]
    }

    /// Writes a rotation per node (row-major) into `frames`: the normalised
    /// sum of the quaternions of the elements around it, each sign-aligned
    /// with the sum so far (identity for nodes of no element); `sum` is
    /// scratch. Both are resized to `num_nodes`.
    pub fn node_frames(
        &self,
        store: &ElementStore,
        num_nodes: usize,
        sum: &mut Vec<[f64; 4]>,
        frames: &mut Vec<[f64; 9]>,
    ) {
        sum.clear();
        sum.resize(num_nodes, [0.0; 4]);
        for (b, st) in store.batches.iter().zip(&self.batches) {
            for (i, q) in st.quaternion.iter().enumerate() {
                for &v in &b.nodes[i * b.k..(i + 1) * b.k] {
                    let s = &mut sum[v as usize];
                    let sign = if s[0] * q[0] + s[1] * q[1] + s[2] * q[2] + s[3] * q[3] < 0.0 { -1.0 } else { 1.0 };
                    (0..4).for_each(|c| s[c] += sign * q[c]);
                }
            }
        }
        frames.clear();
        frames.extend(sum.iter().map(|s| {
            let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2] + s[3] * s[3]).sqrt();
            let q = if len > 0.0 { s.map(|c| c / len) } else { [1.0, 0.0, 0.0, 0.0] };
            rotation_matrix(q)
        }));
    }

    /// The deformation gradients and rotations (row-major) of every entry
    /// of batch `batch` of `store` at positions `x` (m): rotations extracted
    /// there, warm-started from the stored ones (identities if not `warp`).
    pub fn rotations_at(
        &self,
        store: &ElementStore,
        batch: usize,
        x: &[[f64; 3]],
        warp: bool,
    ) -> (Vec<[f64; 9]>, Vec<[f64; 9]>) {
        self.batches[batch].rotations_at(&store.batches[batch], x, warp)
    }

    /// Elastic force on local node `a` of entry `i` of batch `batch` (N).
    #[inline]
    pub fn force(&self, store: &ElementStore, batch: usize, i: usize, a: usize) -> [f64; 3] {
        self.batches[batch].force[i * store.batches[batch].k + a]
    }

    /// Prefetches what [`Corotation::block_column`] reads of entry `i` of
    /// `batch`: its rotated gradients and volume (tetrahedra), or its
    /// rotation and the start of `K_e`.
    #[inline]
    pub fn prefetch(&self, store: &ElementStore, batch: usize, i: usize) {
        let (bt, st) = (&store.batches[batch], &self.batches[batch]);
        let k = bt.k;
        if bt.is_tet() {
            if let (Some(a), Some(b), Some(v)) =
                (st.rotated_grads.get(i * k), st.rotated_grads.get((i + 1) * k - 1), bt.volume.get(i))
            {
                prefetch(a);
                prefetch(b);
                prefetch(v);
            }
        } else if let (Some(r), Some(ke)) = (st.rotation.get(i), bt.stiffness.get(i * 9 * k * k)) {
            prefetch(r);
            prefetch(ke);
        }
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
        let (bt, st) = (&store.batches[batch], &self.batches[batch]);
        let k = bt.k;
        if bt.is_tet() {
            // the isotropic block of the rotated gradients is R K_ab Rᵀ
            let g = &st.rotated_grads[i * k..(i + 1) * k];
            let w = scale * bt.volume[i];
            for (o, ga) in out.iter_mut().zip(g) {
                *o = block(*ga, g[b], w, bt.lame.0, bt.lame.1);
            }
            return;
        }
        let ke = &bt.stiffness[i * 9 * k * k..(i + 1) * 9 * k * k];
        warped_column(&st.rotation[i], ke, k, b, scale, out);
    }

    /// Elastic energy `½ Σ_e (Rᵀx - X)ᵀ K_e (Rᵀx - X)` (J) at positions `x`,
    /// with each element's rotation `R` extracted at `x` (warm-started from
    /// the stored one; the identity if not `warp`): a step leaves the
    /// rotations of the positions it started from, which would misstate
    /// the energy of a body turning fast.
    ///
    /// A linear tetrahedron's strain is constant, so its energy is
    /// `V (μ ε:ε + ½ λ (tr ε)²)` with `ε = sym(Rᵀ F) - I`, the same
    /// quadratic form without assembling `K_e`.
    pub fn energy(&self, store: &ElementStore, x: &[[f64; 3]], warp: bool) -> f64 {
        use cleave_kernels::corotation::MAX_NODES;
        let per_batch = |(b, st): (&Batch, &BatchState)| -> f64 {
            let k = b.k;
            let (gradients, rotations) = st.rotations_at(b, x, warp);
            let (lambda, mu) = b.lame;
            let element = |i: usize| -> f64 {
                let r = &rotations[i];
                if b.is_tet() {
                    let f = &gradients[i];
                    // ε = sym(Rᵀ F) - I
                    let rf: [[f64; 3]; 3] = std::array::from_fn(|p| {
                        std::array::from_fn(|q| r[p] * f[q] + r[3 + p] * f[3 + q] + r[6 + p] * f[6 + q])
                    });
                    let strain = |p: usize, q: usize| 0.5 * (rf[p][q] + rf[q][p]) - f64::from(p == q);
                    let trace = strain(0, 0) + strain(1, 1) + strain(2, 2);
                    let contracted: f64 =
                        (0..3).flat_map(|p| (0..3).map(move |q| (p, q))).map(|(p, q)| strain(p, q).powi(2)).sum();
                    return b.volume[i] * (mu * contracted + 0.5 * lambda * trace * trace);
                }
                let (mut u, mut f) = ([[0.0; 3]; MAX_NODES], [[0.0; 3]; MAX_NODES]);
                for a in 0..k {
                    let xa = x[b.nodes[i * k + a] as usize];
                    let l = [
                        r[0] * xa[0] + r[3] * xa[1] + r[6] * xa[2],
                        r[1] * xa[0] + r[4] * xa[1] + r[7] * xa[2],
                        r[2] * xa[0] + r[5] * xa[1] + r[8] * xa[2],
                    ];
                    let xr = b.rest[i * k + a];
                    u[a] = [l[0] - xr[0], l[1] - xr[1], l[2] - xr[2]];
                }
                b.apply_stiffness(i, &u[..k], &mut f[..k]);
                0.5 * u[..k].iter().zip(&f[..k]).map(|(u, f)| u[0] * f[0] + u[1] * f[1] + u[2] * f[2]).sum::<f64>()
            };
            // the element energies summed in element order: the same bits on
            // any number of threads
            let energies: Vec<f64> = (0..b.len()).into_par_iter().with_min_len(TASK).map(element).collect();
            energies.iter().sum()
        };
        store.batches.iter().zip(&self.batches).map(per_batch).sum()
    }
}
