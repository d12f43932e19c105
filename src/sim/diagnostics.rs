//! Figures read back from a simulation without changing it: energies,
//! momenta, stresses, forces, and the run-health figures (how far its
//! elements stretch, how fast its nodes move, how light its lightest node
//! is). A run whose body tears a node away or explodes an element shows it
//! here before anyone looks at a frame.

use cleave_kernels::elasticity::{stress, von_mises};
use cleave_kernels::vec3::{cross, norm, sub};

use rayon::prelude::*;

use super::{Discretization, Model, Simulation};
use crate::mesh::diameter;

/// A figure and where it was found.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Located {
    /// The value.
    pub value: f64,
    /// The element or node it belongs to.
    pub at: usize,
}

impl Simulation {
    /// Von Mises stress of every element (Pa), of
    /// [`Simulation::element_stresses`].
    pub fn von_mises(&self) -> Vec<f64> {
        self.element_stresses().into_iter().map(von_mises).collect()
    }

    /// Stress of every element (Pa, Voigt `[xx, yy, zz, xy, xz, yz]`, rest
    /// frame): of the corotated mean strain `sym(Rᵀ F) - I`, with each
    /// element's rotation extracted at the current positions (the identity
    /// when not corotated).
    pub fn element_stresses(&self) -> Vec<[f64; 6]> {
        let (l, m) = self.params.material.lame();
        let (x, store, corotation) = (&self.state.position, self.elements.store(), self.elements.corotation());
        let mut out = vec![[0.0; 6]; self.mesh.elements.len()];
        for (bi, b) in store.batches.iter().enumerate() {
            let (gradients, rotations) = corotation.rotations_at(store, bi, x, self.params.corotated);
            for (i, (f, r)) in gradients.iter().zip(&rotations).enumerate() {
                // Rᵀ F - I
                let g: [[f64; 3]; 3] = std::array::from_fn(|p| {
                    std::array::from_fn(|q| r[p] * f[q] + r[3 + p] * f[3 + q] + r[6 + p] * f[6 + q] - f64::from(p == q))
                });
                out[b.elements[i] as usize] = stress(g, l, m);
            }
        }
        out
    }

    /// Elastic energy (J) at the current positions, with each element's
    /// rotation extracted there (the identity when not corotated); for DG
    /// with the quadratic form of the face terms at those rotations.
    pub fn elastic_energy(&self) -> f64 {
        let (x, warp) = (&self.state.position, self.params.corotated);
        let volume = self.elements.corotation().energy(self.elements.store(), x, warp);
        match &self.elements {
            Model::Nodal(_) => volume,
            Model::Dg(d) => volume + d.face_energy(x, warp),
        }
    }

    /// Kinetic energy `½ Σ m_i |v_i|²` (J).
    pub fn kinetic_energy(&self) -> f64 {
        let v = &self.state.velocity;
        self.masses.iter().zip(v).map(|(m, v)| 0.5 * m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])).sum()
    }

    /// Linear momentum `Σ w_i v_i` (kg m/s), `w` the gravity weights
    /// (`ρ ∫ N_i`: the masses for the nodal families).
    pub fn linear_momentum(&self) -> [f64; 3] {
        let mut p = [0.0; 3];
        for (m, v) in self.loads.iter().zip(&self.state.velocity) {
            (0..3).for_each(|i| p[i] += m * v[i]);
        }
        p
    }

    /// Angular momentum `Σ m_i x_i × v_i` about the origin (kg m²/s) (for
    /// DG exact: the basis is orthonormal).
    pub fn angular_momentum(&self) -> [f64; 3] {
        let mut l = [0.0; 3];
        for ((m, x), v) in self.masses.iter().zip(&self.state.position).zip(&self.state.velocity) {
            let c = cross(*x, *v);
            (0..3).for_each(|i| l[i] += m * c[i]);
        }
        l
    }

    /// Elastic forces on every block at the current positions (N), with
    /// rotations extracted there (the identity when not corotated); the
    /// simulation keeps the rotations of its last step.
    pub fn elastic_forces(&self) -> Vec<[f64; 3]> {
        let (x, warp) = (&self.state.position, self.params.corotated);
        let mut f = vec![[0.0; 3]; x.len()];
        match &self.elements {
            Model::Nodal(n) => {
                let (store, mut corotation) = (&n.store, n.corotation.clone());
                corotation.update(store, x, warp);
                self.pattern.gather(&mut f, |b, i, a| corotation.force(store, b, i, a));
            }
            Model::Dg(d) => {
                let mut d = d.clone();
                d.update(x, warp);
                self.pattern.gather(&mut f, |b, i, a| d.force(b, i, a));
            }
        }
        f
    }

    /// The largest stretch of an element: its deformed diameter over its
    /// rest diameter (1 for a rigid motion), and the element.
    pub fn worst_stretch(&self) -> Located {
        ShapeExtremes::of(self).stretch
    }

    /// The fastest node: its speed (m/s) and id.
    pub fn max_node_speed(&self) -> Located {
        let mut fastest = Located::default();
        for (i, v) in self.velocities().iter().enumerate() {
            let s = norm(*v);
            if s > fastest.value {
                fastest = Located { value: s, at: i };
            }
        }
        fastest
    }

    /// The lightest node relative to its elements: its lumped mass over
    /// the mean nodal mass `ρ V_e / k_e` of the elements holding it, and
    /// the node (nodes of no element are skipped).
    pub fn min_mass_ratio(&self) -> Located {
        if self.elements.dg().is_some() {
            // every function of a DG element has the element's mass
            return Located { value: 1.0, at: 0 };
        }
        let n = self.mesh.nodes.len();
        let (mut sum, mut count) = (vec![0.0; n], vec![0u32; n]);
        for b in &self.elements.store().batches {
            for i in 0..b.len() {
                let share = b.volume[i] * self.params.material.density / b.k as f64;
                for &v in b.element_nodes(i) {
                    sum[v as usize] += share;
                    count[v as usize] += 1;
                }
            }
        }
        let mut lightest = Located { value: f64::INFINITY, at: 0 };
        for i in (0..n).filter(|&i| count[i] > 0) {
            let ratio = self.masses[i] / (sum[i] / count[i] as f64);
            if ratio < lightest.value {
                lightest = Located { value: ratio, at: i };
            }
        }
        lightest
    }

    /// Potential energy of gravity `-Σ w_i g · x_i` (J), zero at the
    /// origin, `w` the gravity weights.
    pub fn gravity_energy(&self) -> f64 {
        let g = self.params.gravity;
        -self
            .loads
            .iter()
            .zip(&self.state.position)
            .map(|(m, x)| m * (g[0] * x[0] + g[1] * x[1] + g[2] * x[2]))
            .sum::<f64>()
    }

    /// Energy stored in the penalty springs of the colliders, `Σ ½ k d²`
    /// over the nodes at depth `d` behind a collider (J).
    pub fn contact_energy(&self) -> f64 {
        let mut e = 0.0;
        self.contact_depths(|_, depth, stiffness| e += 0.5 * stiffness * depth * depth);
        e
    }

    /// Calls `f(index, depth, stiffness)` for every collision point behind
    /// a collider (`index` numbers the pairs of collider and point, collider
    /// after collider; `stiffness` is the point's share of the collider's,
    /// N/m): the nodes, or the collision points of a discretisation whose
    /// blocks are not nodes.
    pub(super) fn contact_depths(&self, mut f: impl FnMut(usize, f64, f64)) {
        let mut points = Vec::new();
        let (positions, share): (&[[f64; 3]], Option<&[f64]>) = match &self.contacts {
            None => (&self.state.position, None),
            Some((map, share)) => {
                map.apply(&self.state.position, &mut points);
                (&points, Some(share))
            }
        };
        for (c, collider) in self.boundary.colliders.iter().enumerate() {
            for (p, x) in positions.iter().enumerate() {
                let d = collider.depth(*x);
                if d > 0.0 {
                    f(c * positions.len() + p, d, collider.stiffness * share.map_or(1.0, |s| s[p]));
                }
            }
        }
    }

    /// Total mechanical energy: kinetic, elastic, gravity and contact (J).
    /// Implicit Euler and damping only dissipate it, and a cut changes it
    /// only by the small amount its state transfer costs, so it should
    /// never grow (beyond the work of prescribed motion).
    pub fn mechanical_energy(&self) -> f64 {
        self.kinetic_energy() + self.elastic_energy() + self.gravity_energy() + self.contact_energy()
    }

    /// The largest distance a node has moved from its rest position (m).
    pub fn max_displacement(&self) -> f64 {
        self.mesh.nodes.iter().zip(self.positions()).map(|(x0, x)| norm(sub(*x, *x0))).fold(0.0, f64::max)
    }
}

/// The elements of extreme shape: the inverted ones (deformed volume over
/// their face triangles not positive) and the most stretched one.
pub(super) struct ShapeExtremes {
    /// How many elements have a non-positive deformed volume.
    pub inverted_count: usize,
    /// The first [`super::guards::NAMED`] of them.
    pub inverted: Vec<usize>,
    /// The largest stretch and its element.
    pub stretch: Located,
}

/// Elements per parallel task.
const TASK: usize = 1024;

/// One element's shape at the current positions: its id, deformed volume
/// (m³) and stretch.
type Shape = (usize, f64, f64);

impl ShapeExtremes {
    /// One pass over the elements at the current node positions: over the
    /// element store's batches (contiguous nodes and rest positions, a
    /// closed-form volume for tetrahedra) for the nodal families, over the
    /// mesh for DG,
    /// whose store holds coefficient blocks. The same result on any number
    /// of threads (chunks are combined in order).
    pub(super) fn of(sim: &Simulation) -> Self {
        let mut out = ShapeExtremes { inverted_count: 0, inverted: Vec::new(), stretch: Located { value: 1.0, at: 0 } };
        let (x, mesh) = (sim.positions(), sim.mesh());
        if sim.dg().is_some() {
            out.scan(mesh.elements.len(), |e, now, rest| {
                let el = &mesh.elements[e];
                rest.extend(el.nodes.iter().map(|&v| mesh.nodes[v as usize]));
                now.extend(el.nodes.iter().map(|&v| x[v as usize]));
                let volume = mesh.element_volume_at(e, x);
                (e, volume, diameter(now) / diameter(rest))
            });
            return out;
        }
        for b in &sim.store().batches {
            let k = b.k;
            out.scan(b.len(), |i, now, _| {
                now.extend(b.nodes[i * k..(i + 1) * k].iter().map(|&v| x[v as usize]));
                let (rest, e) = (&b.rest[i * k..(i + 1) * k], b.elements[i] as usize);
                let volume = if b.is_tet() {
                    let rest_sign = cleave_kernels::tet::signed_volume(rest[0], rest[1], rest[2], rest[3]).signum();
                    rest_sign * cleave_kernels::tet::signed_volume(now[0], now[1], now[2], now[3])
                } else {
                    // over the mesh's face triangles: every kind of element
                    // has them (the store keeps its own only for some)
                    mesh.element_volume_at(e, x)
                };
                (e, volume, diameter(now) / diameter(rest))
            });
        }
        out
    }

    /// Adds the shapes of `count` elements, `shape(i, now, rest)` measuring
    /// the `i`-th with two cleared buffers to fill as it needs.
    fn scan(&mut self, count: usize, shape: impl Fn(usize, &mut Vec<[f64; 3]>, &mut Vec<[f64; 3]>) -> Shape + Sync) {
        let named = super::guards::NAMED;
        let chunks: Vec<(Vec<usize>, usize, Located)> = (0..count.div_ceil(TASK))
            .into_par_iter()
            .map(|c| {
                let (mut inverted, mut inverted_count) = (Vec::new(), 0);
                let mut worst = Located { value: 1.0, at: 0 };
                let (mut now, mut rest) = (Vec::new(), Vec::new());
                for i in c * TASK..((c + 1) * TASK).min(count) {
                    now.clear();
                    rest.clear();
                    let (id, volume, stretch) = shape(i, &mut now, &mut rest);
                    if !(volume > 0.0) {
                        inverted_count += 1;
                        if inverted.len() < named {
                            inverted.push(id);
                        }
                    }
                    if !(stretch <= worst.value) {
                        worst = Located { value: stretch, at: id };
                    }
                }
                (inverted, inverted_count, worst)
            })
            .collect();
        for (inverted, inverted_count, worst) in chunks {
            self.inverted_count += inverted_count;
            let room = named - self.inverted.len().min(named);
            self.inverted.extend(inverted.into_iter().take(room));
            if !(worst.value <= self.stretch.value) {
                self.stretch = worst;
            }
        }
    }
}
