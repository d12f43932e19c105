//! The seam between the step pipeline and a family of elements.
//!
//! A step needs from a discretisation its unknowns and how they couple
//! ([`Couplings`], for the sparse pattern), and per step its state at the
//! current positions, the elastic forces and the stiffness blocks of each
//! coupling entry. The nodal families (tetrahedra, mean value, harmonic,
//! trilinear) are [`NodalElements`]: blocks are nodes, entries are
//! elements. A family with element-owned unknowns implements
//! [`Discretization`] with its own blocks and entries (its face couplings
//! among them) and leaves the step as it is.

use crate::assembly::Couplings;
use crate::dg::DgElements;
use crate::store::ElementStore;

use super::Corotation;

/// What the step pipeline asks of a family of elements (see the module
/// docs). Positions `x` are given per block (m).
pub trait Discretization: Couplings {
    /// Phase 1 of a step: the state of every entry at positions `x`
    /// (rotations if `warp`, elastic forces); returns the largest number of
    /// rotation iterations.
    fn update(&mut self, x: &[[f64; 3]], warp: bool) -> usize;
    /// Elastic force (N) of entry `entry` of `group` on its local block
    /// `local`, as of the last [`Discretization::update`].
    fn force(&self, group: usize, entry: usize, local: usize) -> [f64; 3];
    /// `scale` times the stiffness blocks `K_ab` (N/m, row-major, warped by
    /// the rotations of the last update) of the entry, for every local `a`
    /// and the given local `b`.
    fn stiffness_column(&self, group: usize, entry: usize, b: usize, scale: f64, out: &mut [[f64; 9]]);
    /// A hint that the entry's data for [`Discretization::stiffness_column`]
    /// is about to be read.
    fn prefetch(&self, group: usize, entry: usize);
    /// The rest-state (unwarped) stiffness blocks `K_ab` (N/m) of the entry
    /// for every local `a` and the given local `b`.
    fn rest_stiffness_column(&self, group: usize, entry: usize, b: usize, out: &mut [[f64; 9]]);
    /// A rotation per block (row-major) for a preconditioner applied in
    /// rotated frames, written into `frames` (resized to `num_blocks`);
    /// `scratch` is the caller's.
    fn block_frames(&self, num_blocks: usize, scratch: &mut Vec<[f64; 4]>, frames: &mut Vec<[f64; 9]>);
}

/// The nodal families: the element store and the corotation state of its
/// elements.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct NodalElements {
    /// Element data, batched by vertex count.
    pub store: ElementStore,
    /// Rotations and forces per element, aligned with the store's entries.
    pub corotation: Corotation,
}

impl Couplings for NodalElements {
    fn groups(&self) -> usize {
        self.store.groups()
    }
    fn entries(&self, group: usize) -> usize {
        self.store.entries(group)
    }
    fn blocks(&self, group: usize, entry: usize) -> &[u32] {
        self.store.blocks(group, entry)
    }
    fn id(&self, group: usize, entry: usize) -> u32 {
        self.store.id(group, entry)
    }
    fn locate(&self, id: u32) -> (u32, u32) {
        Couplings::locate(&self.store, id)
    }
}

impl Discretization for NodalElements {
    fn update(&mut self, x: &[[f64; 3]], warp: bool) -> usize {
        self.corotation.update(&self.store, x, warp)
    }
    #[inline]
    fn force(&self, group: usize, entry: usize, local: usize) -> [f64; 3] {
        self.corotation.force(&self.store, group, entry, local)
    }
    #[inline]
    fn stiffness_column(&self, group: usize, entry: usize, b: usize, scale: f64, out: &mut [[f64; 9]]) {
        self.corotation.block_column(&self.store, group, entry, b, scale, out)
    }
    #[inline]
    fn prefetch(&self, group: usize, entry: usize) {
        self.corotation.prefetch(&self.store, group, entry)
    }
    #[inline]
    fn rest_stiffness_column(&self, group: usize, entry: usize, b: usize, out: &mut [[f64; 9]]) {
        self.store.batches[group].block_column(entry, b, out)
    }
    fn block_frames(&self, num_blocks: usize, scratch: &mut Vec<[f64; 4]>, frames: &mut Vec<[f64; 9]>) {
        self.corotation.node_frames(&self.store, num_blocks, scratch, frames)
    }
}

/// The discretisation of a body: one of the families.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub enum Model {
    /// Nodal elements (tetrahedra, mean value, harmonic, trilinear).
    Nodal(NodalElements),
    /// Discontinuous Galerkin elements.
    Dg(Box<DgElements>),
}

impl Model {
    /// The element store.
    pub fn store(&self) -> &ElementStore {
        match self {
            Model::Nodal(n) => &n.store,
            Model::Dg(d) => &d.store,
        }
    }

    /// The per-element rotations and forces.
    pub fn corotation(&self) -> &Corotation {
        match self {
            Model::Nodal(n) => &n.corotation,
            Model::Dg(d) => &d.corotation,
        }
    }

    /// The discontinuous Galerkin discretisation, if this is one.
    pub fn dg(&self) -> Option<&DgElements> {
        match self {
            Model::Nodal(_) => None,
            Model::Dg(d) => Some(d),
        }
    }
}

/// Calls `$body` with `$d` bound to the inner discretisation of `$model`.
macro_rules! dispatch {
    ($model:expr, $d:ident => $body:expr) => {
        match $model {
            Model::Nodal($d) => $body,
            Model::Dg($d) => $body,
        }
    };
}

impl Couplings for Model {
    fn groups(&self) -> usize {
        dispatch!(self, d => d.groups())
    }
    fn entries(&self, group: usize) -> usize {
        dispatch!(self, d => d.entries(group))
    }
    fn blocks(&self, group: usize, entry: usize) -> &[u32] {
        dispatch!(self, d => d.blocks(group, entry))
    }
    fn id(&self, group: usize, entry: usize) -> u32 {
        dispatch!(self, d => d.id(group, entry))
    }
    fn locate(&self, id: u32) -> (u32, u32) {
        dispatch!(self, d => d.locate(id))
    }
}

impl Discretization for Model {
    fn update(&mut self, x: &[[f64; 3]], warp: bool) -> usize {
        dispatch!(self, d => d.update(x, warp))
    }
    #[inline]
    fn force(&self, group: usize, entry: usize, local: usize) -> [f64; 3] {
        dispatch!(self, d => d.force(group, entry, local))
    }
    #[inline]
    fn stiffness_column(&self, group: usize, entry: usize, b: usize, scale: f64, out: &mut [[f64; 9]]) {
        dispatch!(self, d => d.stiffness_column(group, entry, b, scale, out))
    }
    #[inline]
    fn prefetch(&self, group: usize, entry: usize) {
        dispatch!(self, d => d.prefetch(group, entry))
    }
    #[inline]
    fn rest_stiffness_column(&self, group: usize, entry: usize, b: usize, out: &mut [[f64; 9]]) {
        dispatch!(self, d => d.rest_stiffness_column(group, entry, b, out))
    }
    fn block_frames(&self, num_blocks: usize, scratch: &mut Vec<[f64; 4]>, frames: &mut Vec<[f64; 9]>) {
        dispatch!(self, d => d.block_frames(num_blocks, scratch, frames))
    }
}
