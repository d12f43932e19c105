//! The discontinuous Galerkin family (kaufmann2008) as a discretisation the
//! step runs: element-owned coefficient blocks (`m` per element, element
//! `e` owning blocks `e m .. e m + m`), volume terms from the element store
//! ([`crate::store::dg`]), face terms ([`faces`]) coupling face neighbours,
//! the penalty chosen as the paper does, and the maps from coefficients to
//! mesh nodes (the stitched field, eq. 17) and to collision points.

pub mod faces;

use crate::assembly::{Couplings, SparsePattern};
use crate::mesh::PolyMesh;
use crate::sim::{Corotation, Discretization, FixedRegion, PointMap};
use crate::solve::{Cholesky, LinearSolver, SolveError};
use crate::store::dg::{DgBasis, DgOptions, Flux, MAX_BASIS};
use crate::store::ElementStore;
use faces::{consistency_block, BoundaryFace, InteriorFace};
use rayon::prelude::*;

/// How many times the interior penalty is doubled at most.
pub const MAX_DOUBLINGS: usize = 40;

/// The discontinuous Galerkin discretisation of one body.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct DgElements {
    /// Volume terms and bases, one batch.
    pub store: ElementStore,
    /// Rotations and volume forces per element.
    pub corotation: Corotation,
    /// Degree, flux and starting penalty.
    pub options: DgOptions,
    /// The penalty `η` in use (doubled from the options' for `Ip` by
    /// [`DgElements::stabilise`]).
    pub penalty: f64,
    /// Whether [`DgElements::stabilise`] checked the penalty since the
    /// face terms were last rebuilt whole ([`DgElements::refresh`]).
    stable: bool,
    /// Interior faces.
    pub interior: Vec<InteriorFace>,
    /// Boundary faces in fixed regions.
    pub boundary: Vec<BoundaryFace>,
    interior_blocks: Vec<u32>,
    boundary_blocks: Vec<u32>,
    /// Entry index by mesh face id (`u32::MAX` where none).
    interior_index: Vec<u32>,
    boundary_index: Vec<u32>,
    interior_forces: Vec<[f64; 3]>,
    boundary_forces: Vec<[f64; 3]>,
    /// Rotations of the last update, per element (row-major).
    rotations: Vec<[f64; 9]>,
    /// The coefficients of the identity map `X⁰`, per block (m).
    rest: Vec<[f64; 3]>,
    /// Lamé parameters (Pa).
    lame: (f64, f64),
}

const IDENTITY: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

#[inline]
fn rotate(r: &[f64; 9], v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| r[3 * i] * v[0] + r[3 * i + 1] * v[1] + r[3 * i + 2] * v[2])
}

#[inline]
fn mat_vec(b: &[f64; 9], v: [f64; 3]) -> [f64; 3] {
    rotate(b, v)
}

/// The consistency blocks of an interior face (`r2 = 2m` local functions)
/// for the local pair `(α, β)` with signs `χ`: the one from `β`'s side (warped by its rotation
/// `r_t`) and the one from `α`'s side (warped by `r_s`), before the second
/// is transposed (see [`faces`]).
fn consistency_pair(
    f: &InteriorFace,
    r2: usize,
    (alpha, beta): (usize, usize),
    (chi_s, chi_t): (f64, f64),
    (rs, rt): (&[f64; 9], &[f64; 9]),
    (lambda, mu): (f64, f64),
) -> ([f64; 9], [f64; 9]) {
    let b1 = consistency_block(rotate(rt, f.normal), rotate(rt, f.grad[alpha * r2 + beta]), 0.5 * chi_s, lambda, mu);
    let b2 = consistency_block(rotate(rs, f.normal), rotate(rs, f.grad[beta * r2 + alpha]), 0.5 * chi_t, lambda, mu);
    (b1, b2)
}

#[inline]
fn mat_t_vec(b: &[f64; 9], v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| b[i] * v[0] + b[3 + i] * v[1] + b[6 + i] * v[2])
}

#[inline]
fn transpose(b: [f64; 9]) -> [f64; 9] {
    std::array::from_fn(|rc| b[(rc % 3) * 3 + rc / 3])
}

impl DgElements {
    /// The discretisation of `mesh` from its element store (built with the
    /// discontinuous Galerkin family), with the boundary faces held by
    /// `fixed`, at the options' penalty.
    pub fn new(mesh: &PolyMesh, store: ElementStore, options: DgOptions, fixed: &[FixedRegion]) -> Self {
        let corotation = Corotation::new(&store);
        let lame = store.batches.first().map_or((0.0, 0.0), |b| b.lame);
        let mut dg = DgElements {
            store,
            corotation,
            options,
            penalty: options.penalty,
            stable: false,
            interior: Vec::new(),
            boundary: Vec::new(),
            interior_blocks: Vec::new(),
            boundary_blocks: Vec::new(),
            interior_index: Vec::new(),
            boundary_index: Vec::new(),
            interior_forces: Vec::new(),
            boundary_forces: Vec::new(),
            rotations: Vec::new(),
            rest: Vec::new(),
            lame,
        };
        dg.refresh(mesh, fixed);
        dg
    }

    /// Basis functions per element.
    pub fn size(&self) -> usize {
        self.options.size()
    }

    /// The basis of element `e`.
    pub fn basis(&self, e: u32) -> &DgBasis {
        let (b, i) = self.store.locate[e as usize];
        &self.store.batches[b as usize].dg[i as usize]
    }

    /// The volume of element `e` (m³).
    pub fn volume(&self, e: u32) -> f64 {
        let (b, i) = self.store.locate[e as usize];
        self.store.batches[b as usize].volume[i as usize]
    }

    /// Number of coefficient blocks (`m` per element).
    pub fn num_blocks(&self) -> usize {
        self.store.locate.len() * self.size()
    }

    /// The coefficients of the identity map per block (m): the rest state.
    pub fn rest(&self) -> &[[f64; 3]] {
        &self.rest
    }

    /// Rebuilds the face terms at the current penalty (after the elements
    /// or the fixed regions changed), the rest state and the buffers; the
    /// penalty is then to be checked again ([`DgElements::stabilise`]).
    pub fn refresh(&mut self, mesh: &PolyMesh, fixed: &[FixedRegion]) {
        self.refresh_around(mesh, fixed, None);
        self.stable = false;
    }

    /// Whether the penalty was checked ([`DgElements::stabilise`]) since the
    /// face terms were last rebuilt whole.
    pub fn is_stable(&self) -> bool {
        self.stable
    }

    /// [`DgElements::refresh`] after a topology change that rebuilt the
    /// elements `rebuilt` (sorted; the penalty and the fixed regions the
    /// same): the faces of the other elements keep their integrals.
    pub fn refresh_after_change(&mut self, mesh: &PolyMesh, fixed: &[FixedRegion], rebuilt: &[u32]) {
        let mut flags = vec![false; self.store.locate.len()];
        rebuilt.iter().for_each(|&e| flags[e as usize] = true);
        let previous = faces::Previous {
            interior: (std::mem::take(&mut self.interior), std::mem::take(&mut self.interior_index)),
            boundary: (std::mem::take(&mut self.boundary), std::mem::take(&mut self.boundary_index)),
            rebuilt: flags,
        };
        self.refresh_around(mesh, fixed, Some(previous));
    }

    fn refresh_around(&mut self, mesh: &PolyMesh, fixed: &[FixedRegion], previous: Option<faces::Previous>) {
        let m = self.size();
        let (store, lame, flux) = (&self.store, self.lame, self.options.flux);
        let basis = |e: u32| -> &DgBasis {
            let (b, i) = store.locate[e as usize];
            &store.batches[b as usize].dg[i as usize]
        };
        let volume = |e: u32| -> f64 {
            let (b, i) = store.locate[e as usize];
            store.batches[b as usize].volume[i as usize]
        };
        let (interior, boundary) = faces::build(mesh, fixed, self.penalty, lame, flux, &basis, &volume, previous);
        let blocks = |e: u32| (0..m as u32).map(move |a| e * m as u32 + a);
        self.interior_blocks =
            interior.iter().flat_map(|f| blocks(f.elements[0]).chain(blocks(f.elements[1]))).collect();
        self.boundary_blocks = boundary.iter().flat_map(|f| blocks(f.element)).collect();
        self.interior_index = vec![u32::MAX; mesh.faces.len()];
        for (i, f) in interior.iter().enumerate() {
            self.interior_index[f.face as usize] = i as u32;
        }
        self.boundary_index = vec![u32::MAX; mesh.faces.len()];
        for (i, f) in boundary.iter().enumerate() {
            self.boundary_index[f.face as usize] = i as u32;
        }
        self.interior_forces = vec![[0.0; 3]; interior.len() * 2 * m];
        self.boundary_forces = vec![[0.0; 3]; boundary.len() * m];
        self.interior = interior;
        self.boundary = boundary;
        let n = self.store.locate.len();
        self.rotations = vec![IDENTITY; n];
        self.rest = vec![[0.0; 3]; n * m];
        for b in &self.store.batches {
            for (i, &e) in b.elements.iter().enumerate() {
                self.rest[e as usize * m..(e as usize + 1) * m].copy_from_slice(&b.rest[i * m..(i + 1) * m]);
            }
        }
    }

    /// Lumped (here exact, the basis being orthonormal) masses per block
    /// (kg): `ρ V` for every function of an element.
    pub fn masses(&self, density: f64) -> Vec<f64> {
        self.store.lumped_masses(self.num_blocks(), density)
    }

    /// The gravity weights per block (kg): `ρ ∫ N_a = ρ V` for the constant
    /// function, zero for the others.
    pub fn loads(&self, density: f64) -> Vec<f64> {
        let m = self.size();
        let mut out = vec![0.0; self.num_blocks()];
        for b in &self.store.batches {
            for (i, &e) in b.elements.iter().enumerate() {
                out[e as usize * m] = density * b.volume[i];
            }
        }
        out
    }

    /// The stitched field of kaufmann2008 eq. 17 as a point map: each mesh
    /// node the volume-weighted mean of its elements' polynomials there
    /// (nodes of no element read nothing).
    pub fn node_map(&self, mesh: &PolyMesh) -> PointMap {
        let m = self.size();
        let adjacency = crate::mesh::Adjacency::without_edges(mesh);
        let mut map = PointMap { offsets: vec![0], ..Default::default() };
        let mut values = [0.0; MAX_BASIS];
        for (v, x) in mesh.nodes.iter().enumerate() {
            let around = adjacency.node_elements(v);
            let total: f64 = around.iter().map(|&e| self.volume(e)).sum();
            for &e in around {
                self.basis(e).values(*x, &mut values);
                let w = self.volume(e) / total;
                for (a, &value) in values.iter().enumerate().take(m) {
                    map.blocks.push(e * m as u32 + a as u32);
                    map.weights.push(w * value);
                }
            }
            map.offsets.push(map.blocks.len() as u32);
        }
        map
    }

    /// Collision points: every element's own copy of each of its vertices
    /// (its polynomial there), with the share `1 / (elements at the
    /// vertex)` of a collider's stiffness each, so that a mesh node pushes
    /// back as hard as a node of a nodal mesh.
    pub fn contact_points(&self, mesh: &PolyMesh) -> (PointMap, Vec<f64>) {
        let m = self.size();
        let adjacency = crate::mesh::Adjacency::without_edges(mesh);
        let mut map = PointMap { offsets: vec![0], ..Default::default() };
        let mut share = Vec::new();
        let mut values = [0.0; MAX_BASIS];
        for (e, el) in mesh.elements.iter().enumerate() {
            let basis = self.basis(e as u32);
            for &v in &el.nodes {
                basis.values(mesh.nodes[v as usize], &mut values);
                for (a, &value) in values.iter().enumerate().take(m) {
                    map.blocks.push(e as u32 * m as u32 + a as u32);
                    map.weights.push(value);
                }
                map.offsets.push(map.blocks.len() as u32);
                share.push(1.0 / adjacency.node_elements(v as usize).len() as f64);
            }
        }
        (map, share)
    }

    /// Per-element coefficients of the affine fields fitted, element by
    /// element and in the least-squares sense, to the values `node_values`
    /// (one per mesh node) at its vertices (kaufmann2008 §7's fit); exact
    /// for affine fields such as a uniform velocity or a rigid spin.
    pub fn fit_affine(&self, mesh: &PolyMesh, node_values: &[[f64; 3]]) -> Vec<[f64; 3]> {
        let m = self.size();
        let mut out = vec![[0.0; 3]; self.num_blocks()];
        for (e, el) in mesh.elements.iter().enumerate() {
            // normal equations of u(x) = u0 + B (x - c) over the vertices
            let c = {
                let mut c = [0.0; 3];
                for &v in &el.nodes {
                    (0..3).for_each(|k| c[k] += mesh.nodes[v as usize][k] / el.nodes.len() as f64);
                }
                c
            };
            let mut a = [[0.0; 4]; 4];
            let mut rhs = [[0.0; 3]; 4];
            for &v in &el.nodes {
                let x = mesh.nodes[v as usize];
                let p = [1.0, x[0] - c[0], x[1] - c[1], x[2] - c[2]];
                for i in 0..4 {
                    for j in 0..4 {
                        a[i][j] += p[i] * p[j];
                    }
                    for k in 0..3 {
                        rhs[i][k] += p[i] * node_values[v as usize][k];
                    }
                }
            }
            let Some(sol) = cleave_kernels::solve4::solve4(a, rhs, 1e-300) else { continue };
            // u(x) = (u0 - B c) + B x, and x = Σ_a X⁰_a N_a
            let b: [[f64; 3]; 3] = std::array::from_fn(|k| std::array::from_fn(|l| sol[1 + l][k]));
            let shift: [f64; 3] = std::array::from_fn(|k| sol[0][k] - (0..3).map(|l| b[k][l] * c[l]).sum::<f64>());
            for a in 0..m {
                let x0 = self.rest[e * m + a];
                let mut u: [f64; 3] = std::array::from_fn(|k| (0..3).map(|l| b[k][l] * x0[l]).sum());
                if a == 0 {
                    (0..3).for_each(|k| u[k] += shift[k]);
                }
                out[e * m + a] = u;
            }
        }
        out
    }

    /// The mesh with every element given its own copies of its vertices
    /// (for writing the discontinuous field), and for each copy its element
    /// and original node.
    pub fn exploded(&self, mesh: &PolyMesh) -> Result<(PolyMesh, Vec<(u32, u32)>), crate::mesh::MeshError> {
        let mut nodes = Vec::new();
        let mut copies = Vec::new();
        let mut cells = Vec::with_capacity(mesh.elements.len());
        for (e, el) in mesh.elements.iter().enumerate() {
            let base = nodes.len() as u32;
            for &v in &el.nodes {
                nodes.push(mesh.nodes[v as usize]);
                copies.push((e as u32, v));
            }
            let local = |v: u32| base + el.nodes.binary_search(&v).map_or(0, |i| i as u32);
            let loops = el
                .faces
                .iter()
                .map(|r| {
                    let mut l: Vec<u32> = mesh.faces[r.face as usize].vertices.iter().map(|&v| local(v)).collect();
                    if !r.outward {
                        l.reverse();
                    }
                    l
                })
                .collect();
            cells.push(crate::mesh::Cell::Polyhedron(loops));
        }
        Ok((PolyMesh::from_cells(nodes, &cells)?, copies))
    }

    /// Doubles the interior penalty (from the one in use) until the
    /// rest-state system `K + ε diag` is positive definite (kaufmann2008
    /// §10: "start with a low value and double it"), rebuilding the face
    /// terms each time; `Bz` is stable for any penalty and is left as it
    /// is. `ε` is `1e-8` of the mean diagonal entry, far below what an
    /// insufficient penalty makes negative and far above rounding, so
    /// that the six rigid modes of a free body do not count. Nothing to do
    /// (no factorisation) if the penalty was checked since the face terms
    /// were last rebuilt whole.
    pub fn stabilise(
        &mut self,
        mesh: &PolyMesh,
        fixed: &[FixedRegion],
        pattern: &SparsePattern,
    ) -> Result<(), SolveError> {
        if self.stable || self.options.flux != Flux::Ip {
            self.stable = true;
            return Ok(());
        }
        let mut cholesky = Cholesky::default();
        cholesky.analyze(pattern.symbolic())?;
        let mut values = vec![0.0; pattern.nnz()];
        for _ in 0..MAX_DOUBLINGS {
            pattern.assemble(&mut values, |g, i, b, out| self.rest_stiffness_column(g, i, b, out));
            let n = 3 * pattern.num_blocks;
            let mean = (0..n).map(|d| values[pattern.diagonal_slot(d)]).sum::<f64>() / n as f64;
            for d in 0..n {
                values[pattern.diagonal_slot(d)] += 1e-8 * mean;
            }
            match cholesky.factor(pattern.matrix(&values)) {
                Ok(()) => {
                    self.stable = true;
                    return Ok(());
                }
                Err(SolveError::NotPositiveDefinite { .. }) => {
                    self.penalty *= 2.0;
                    self.refresh(mesh, fixed);
                }
                Err(e) => return Err(e),
            }
        }
        Err(SolveError::NotPositiveDefinite { pivot: 0, n: 3 * pattern.num_blocks })
    }

    /// The energy `½ uᵀ K u` of the face terms at block positions `x` (J),
    /// with the elements' rotations extracted at `x` (warm-started from the
    /// stored ones; identities if not `warp`): from the face forces there
    /// (`u = X - X⁰`; a boundary face's forces less its load), computed
    /// into fresh buffers, so the stored state is untouched.
    pub fn face_energy(&self, x: &[[f64; 3]], warp: bool) -> f64 {
        let mut rotations = vec![IDENTITY; self.rotations.len()];
        for (bi, batch) in self.store.batches.iter().enumerate() {
            let (_, at) = self.corotation.rotations_at(&self.store, bi, x, warp);
            for (&e, r) in batch.elements.iter().zip(at) {
                rotations[e as usize] = r;
            }
        }
        let mut interior_forces = vec![[0.0; 3]; self.interior_forces.len()];
        let mut boundary_forces = vec![[0.0; 3]; self.boundary_forces.len()];
        self.face_forces_with(x, warp, &rotations, &mut interior_forces, &mut boundary_forces);
        let u = |blk: u32| -> [f64; 3] { std::array::from_fn(|k| x[blk as usize][k] - self.rest[blk as usize][k]) };
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let m = self.size();
        let interior: f64 = self.interior_blocks.iter().zip(&interior_forces).map(|(&blk, f)| dot(u(blk), *f)).sum();
        let boundary: f64 = self
            .boundary_blocks
            .iter()
            .zip(&boundary_forces)
            .enumerate()
            .map(|(k, (&blk, f))| {
                let load = self.boundary[k / m].load[k % m];
                dot(u(blk), [f[0] - load[0], f[1] - load[1], f[2] - load[2]])
            })
            .sum();
        -0.5 * (interior + boundary)
    }

    /// Adds every boundary face's load (the prescribed displacement's
    /// right-hand side, N) to its element's blocks in `out`.
    pub fn add_boundary_loads(&self, out: &mut [[f64; 3]]) {
        let m = self.size();
        for f in &self.boundary {
            for (a, load) in f.load.iter().enumerate() {
                let o = &mut out[f.element as usize * m + a];
                (0..3).for_each(|k| o[k] += load[k]);
            }
        }
    }

    /// The rotation of element `e` as of the last update.
    fn rotation(&self, e: u32) -> &[f64; 9] {
        &self.rotations[e as usize]
    }

    /// `χ` of local function `α` of an interior face with `m` functions a side.
    fn sign(alpha: usize, m: usize) -> f64 {
        if alpha < m {
            1.0
        } else {
            -1.0
        }
    }

    /// The warped (by `r`) interior face blocks of column `beta`, times
    /// `scale`.
    fn interior_column(&self, i: usize, beta: usize, scale: f64, warp: bool, out: &mut [[f64; 9]]) {
        let (f, m) = (&self.interior[i], self.size());
        let r2 = 2 * m;
        let (lambda, mu) = self.lame;
        let rot = |alpha: usize| -> &[f64; 9] {
            if warp {
                self.rotation(f.elements[usize::from(alpha >= m)])
            } else {
                &IDENTITY
            }
        };
        let consistent = self.options.flux == Flux::Ip;
        let (rt, chi_t) = (rot(beta), Self::sign(beta, m));
        for (alpha, o) in out.iter_mut().enumerate().take(r2) {
            let chi_s = Self::sign(alpha, m);
            let p = f.weight * chi_s * chi_t * f.mass[alpha * r2 + beta];
            let mut block = [p, 0.0, 0.0, 0.0, p, 0.0, 0.0, 0.0, p];
            if consistent {
                let (b1, b2) = consistency_pair(f, r2, (alpha, beta), (chi_s, chi_t), (rot(alpha), rt), (lambda, mu));
                let b2 = transpose(b2);
                (0..9).for_each(|q| block[q] += b1[q] + b2[q]);
            }
            *o = block.map(|v| scale * v);
        }
    }

    /// The boundary face blocks of column `b`, times `scale` (unwarped).
    fn boundary_column(&self, i: usize, b: usize, scale: f64, out: &mut [[f64; 9]]) {
        let (f, m) = (&self.boundary[i], self.size());
        let (lambda, mu) = self.lame;
        let consistent = self.options.flux == Flux::Ip;
        for (a, o) in out.iter_mut().enumerate().take(m) {
            let p = f.weight * f.mass[a * m + b];
            let mut block = [p, 0.0, 0.0, 0.0, p, 0.0, 0.0, 0.0, p];
            if consistent {
                let b1 = consistency_block(f.normal, f.grad[a * m + b], 1.0, lambda, mu);
                let b2 = transpose(consistency_block(f.normal, f.grad[b * m + a], 1.0, lambda, mu));
                (0..9).for_each(|q| block[q] += b1[q] + b2[q]);
            }
            *o = block.map(|v| scale * v);
        }
    }

    /// Face forces at block positions `x` with the rotations of the last
    /// update (see [`faces`]).
    fn face_forces(&mut self, x: &[[f64; 3]], warp: bool) {
        let (mut interior, mut boundary) =
            (std::mem::take(&mut self.interior_forces), std::mem::take(&mut self.boundary_forces));
        self.face_forces_with(x, warp, &self.rotations, &mut interior, &mut boundary);
        (self.interior_forces, self.boundary_forces) = (interior, boundary);
    }

    /// The face forces at block positions `x` (N) with the elements'
    /// rotations `rotations` (row-major, by element id) into
    /// `interior_forces` and `boundary_forces`.
    fn face_forces_with(
        &self,
        x: &[[f64; 3]],
        warp: bool,
        rotations: &[[f64; 9]],
        interior_forces: &mut [[f64; 3]],
        boundary_forces: &mut [[f64; 3]],
    ) {
        let m = self.size();
        let r2 = 2 * m;
        let this = self;
        let rotation = |e: u32| if warp { &rotations[e as usize] } else { &IDENTITY };
        interior_forces.par_chunks_mut(r2).enumerate().for_each(|(i, out)| {
            let f = &this.interior[i];
            let blocks = &this.interior_blocks[i * r2..(i + 1) * r2];
            // z^t_β = X_β - R_t X⁰_β per side t, and X_β - X⁰_β
            let mut z = [[[0.0; 3]; 2 * MAX_BASIS]; 2];
            let mut u = [[0.0; 3]; 2 * MAX_BASIS];
            for (beta, &blk) in blocks.iter().enumerate() {
                let (xb, x0) = (x[blk as usize], this.rest[blk as usize]);
                u[beta] = std::array::from_fn(|k| xb[k] - x0[k]);
                for (side, zs) in z.iter_mut().enumerate() {
                    let r = rotation(f.elements[side]);
                    let rx0 = rotate(r, x0);
                    zs[beta] = std::array::from_fn(|k| xb[k] - rx0[k]);
                }
            }
            out.iter_mut().for_each(|o| *o = [0.0; 3]);
            // f_α = -Σ_β block(α, β) z_β with the side of each term
            let (lambda, mu) = this.lame;
            let consistent = this.options.flux == Flux::Ip;
            for beta in 0..r2 {
                let t = usize::from(beta >= m);
                let chi_t = Self::sign(beta, m);
                let rt = rotation(f.elements[t]);
                for alpha in 0..r2 {
                    let s = usize::from(alpha >= m);
                    let chi_s = Self::sign(alpha, m);
                    let p = f.weight * chi_s * chi_t * f.mass[alpha * r2 + beta];
                    let mut fa = [p * u[beta][0], p * u[beta][1], p * u[beta][2]];
                    if consistent {
                        let rs = rotation(f.elements[s]);
                        let (b1, b2) = consistency_pair(f, r2, (alpha, beta), (chi_s, chi_t), (rs, rt), (lambda, mu));
                        let (v1, v2) = (mat_vec(&b1, z[t][beta]), mat_t_vec(&b2, z[s][beta]));
                        (0..3).for_each(|k| fa[k] += v1[k] + v2[k]);
                    }
                    (0..3).for_each(|k| out[alpha][k] -= fa[k]);
                }
            }
        });
        boundary_forces.par_chunks_mut(m).enumerate().for_each(|(i, out)| {
            let f = &this.boundary[i];
            let mut column = [[0.0; 9]; MAX_BASIS];
            for (a, o) in out.iter_mut().enumerate() {
                *o = f.load[a];
            }
            for b in 0..m {
                this.boundary_column(i, b, 1.0, &mut column);
                let blk = f.element as usize * m + b;
                let u: [f64; 3] = std::array::from_fn(|k| x[blk][k] - this.rest[blk][k]);
                for a in 0..m {
                    let v = mat_vec(&column[a], u);
                    (0..3).for_each(|k| out[a][k] -= v[k]);
                }
            }
        });
    }
}

impl Couplings for DgElements {
    fn groups(&self) -> usize {
        self.store.batches.len() + 2
    }
    fn entries(&self, group: usize) -> usize {
        let nb = self.store.batches.len();
        match group {
            g if g < nb => self.store.batches[g].len(),
            g if g == nb => self.interior.len(),
            _ => self.boundary.len(),
        }
    }
    fn blocks(&self, group: usize, entry: usize) -> &[u32] {
        let (nb, m) = (self.store.batches.len(), self.size());
        match group {
            g if g < nb => self.store.batches[g].element_nodes(entry),
            g if g == nb => &self.interior_blocks[entry * 2 * m..(entry + 1) * 2 * m],
            _ => &self.boundary_blocks[entry * m..(entry + 1) * m],
        }
    }
    fn id(&self, group: usize, entry: usize) -> u32 {
        let nb = self.store.batches.len();
        match group {
            g if g < nb => 3 * self.store.batches[g].elements[entry],
            g if g == nb => 3 * self.interior[entry].face + 1,
            _ => 3 * self.boundary[entry].face + 2,
        }
    }
    fn locate(&self, id: u32) -> (u32, u32) {
        let nb = self.store.batches.len() as u32;
        match id % 3 {
            0 => self.store.locate[(id / 3) as usize],
            1 => (nb, self.interior_index[(id / 3) as usize]),
            _ => (nb + 1, self.boundary_index[(id / 3) as usize]),
        }
    }
}

impl Discretization for DgElements {
    fn update(&mut self, x: &[[f64; 3]], warp: bool) -> usize {
        let iterations = self.corotation.update(&self.store, x, warp);
        for (b, batch) in self.store.batches.iter().enumerate() {
            for (i, &e) in batch.elements.iter().enumerate() {
                self.rotations[e as usize] = *self.corotation.rotation(b, i);
            }
        }
        self.face_forces(x, warp);
        iterations
    }
    fn force(&self, group: usize, entry: usize, local: usize) -> [f64; 3] {
        let (nb, m) = (self.store.batches.len(), self.size());
        match group {
            g if g < nb => self.corotation.force(&self.store, g, entry, local),
            g if g == nb => self.interior_forces[entry * 2 * m + local],
            _ => self.boundary_forces[entry * m + local],
        }
    }
    fn stiffness_column(&self, group: usize, entry: usize, b: usize, scale: f64, out: &mut [[f64; 9]]) {
        let nb = self.store.batches.len();
        match group {
            g if g < nb => self.corotation.block_column(&self.store, g, entry, b, scale, out),
            g if g == nb => self.interior_column(entry, b, scale, true, out),
            _ => self.boundary_column(entry, b, scale, out),
        }
    }
    fn prefetch(&self, group: usize, entry: usize) {
        // element entries as the nodal families; a face entry's data is
        // read in the order faces are stored
        if group < self.store.batches.len() {
            self.corotation.prefetch(&self.store, group, entry);
        }
    }
    fn rest_stiffness_column(&self, group: usize, entry: usize, b: usize, out: &mut [[f64; 9]]) {
        let nb = self.store.batches.len();
        match group {
            g if g < nb => self.store.batches[g].block_column(entry, b, out),
            g if g == nb => self.interior_column(entry, b, 1.0, false, out),
            _ => self.boundary_column(entry, b, 1.0, out),
        }
    }
    fn block_frames(&self, num_blocks: usize, _scratch: &mut Vec<[f64; 4]>, frames: &mut Vec<[f64; 9]>) {
        let m = self.size();
        frames.clear();
        frames.extend((0..num_blocks).map(|blk| self.rotations[blk / m]));
    }
}
