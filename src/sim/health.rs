//! Run-health figures read back from a simulation: how far its elements
//! stretch, how fast its nodes move, how light its lightest node is. A run
//! whose body tears a node away or explodes an element shows it here
//! before anyone looks at a frame.

use cleave_kernels::vec3::{norm, sub};

use super::Simulation;
use crate::mesh::diameter;

/// A figure and where it was found.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Located {
    /// The value.
    pub value: f64,
    /// The element or node it belongs to.
    pub at: usize,
}

impl Simulation {
    /// The largest stretch of an element: its deformed diameter over its
    /// rest diameter (1 for a rigid motion), and the element.
    pub fn worst_stretch(&self) -> Located {
        let (mesh, x) = (&self.mesh, &self.position);
        let mut worst = Located { value: 1.0, at: 0 };
        let mut rest = Vec::new();
        let mut now = Vec::new();
        for (e, el) in mesh.elements.iter().enumerate() {
            rest.clear();
            now.clear();
            rest.extend(el.nodes.iter().map(|&v| mesh.nodes[v as usize]));
            now.extend(el.nodes.iter().map(|&v| x[v as usize]));
            let stretch = diameter(&now) / diameter(&rest);
            if stretch > worst.value {
                worst = Located { value: stretch, at: e };
            }
        }
        worst
    }

    /// The fastest node: its speed (m/s) and id.
    pub fn max_node_speed(&self) -> Located {
        let mut fastest = Located::default();
        for (i, v) in self.velocity.iter().enumerate() {
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
        let n = self.mesh.nodes.len();
        let (mut sum, mut count) = (vec![0.0; n], vec![0u32; n]);
        for b in &self.store.batches {
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

    /// Potential energy of gravity `-Σ m_i g · x_i` (J), zero at the origin.
    pub fn gravity_energy(&self) -> f64 {
        let g = self.params.gravity;
        -self.masses.iter().zip(&self.position).map(|(m, x)| m * (g[0] * x[0] + g[1] * x[1] + g[2] * x[2])).sum::<f64>()
    }

    /// Energy stored in the penalty springs of the colliders, `Σ ½ k d²`
    /// over the nodes at depth `d` behind a collider (J).
    pub fn contact_energy(&self) -> f64 {
        let mut e = 0.0;
        for c in &self.colliders {
            for x in &self.position {
                let d = c.depth(*x);
                if d > 0.0 {
                    e += 0.5 * c.stiffness * d * d;
                }
            }
        }
        e
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
        self.mesh.nodes.iter().zip(&self.position).map(|(x0, x)| norm(sub(*x, *x0))).fold(0.0, f64::max)
    }
}
