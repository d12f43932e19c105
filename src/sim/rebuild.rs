//! Topology changes applied to a running simulation, in one place: a cut
//! changes the mesh, then everything built on it follows in a fixed order
//! (element data, node state, sparse pattern, masses, momenta, rotations,
//! the solvers; the boundary surface is rebuilt when next asked for).

use crate::mesh::{Plane, PolyMesh, ValidationOptions};
use crate::topology::{
    conserve_momentum, momenta, node_diameters, open_pinched_nodes, pinched_nodes, polygon_plane, raise_node_diameters,
    CutReport, CutScope, CutShape, NodeOrigins, PolygonCutReport, Reach, Rollback, SplitOptions,
};
use crate::Error;
use rayon::prelude::*;

use super::{Model, Phase, PhaseTimings, Simulation, CUT_ATTEMPTS};

impl Simulation {
    /// Cuts the body along a whole plane given in the rest (material)
    /// frame: elements the plane crosses are split into convex parts, and
    /// the two sides separate (wicke2007 §5). New nodes on edges take the
    /// state interpolated along their edge, duplicated nodes the state of
    /// their original; only the touched elements' data and the pattern's
    /// columns of their nodes are rebuilt. On error the simulation is left
    /// unchanged.
    pub fn cut_plane(&mut self, plane: &Plane) -> Result<CutReport, Error> {
        self.cut(CutShape::Plane(plane)).map(|report| report.cut)
    }

    /// Cuts the body with a convex planar polygon given in the rest frame
    /// (wicke2007 §5.2): the material opens only inside the polygon, with a
    /// pocket where no node lies inside it. A swept blade is a sequence of
    /// such cuts. State and rebuild as in [`Simulation::cut_plane`].
    pub fn cut_polygon(&mut self, polygon: &[[f64; 3]]) -> Result<PolygonCutReport, Error> {
        self.cut(CutShape::Polygon(polygon))
    }

    /// The split options of a cut: the parameters' with their
    /// `min_diameter` raised to the body's part floor
    /// ([`super::SimulationParams::min_part`]).
    fn cut_options(&self) -> SplitOptions {
        let opts = self.params.cut;
        SplitOptions { min_diameter: opts.min_diameter.max(self.part_floor), ..opts }
    }

    /// The elements a cut along `plane` (and, for a polygon cut, within
    /// reach of `polygon`) must look at (see [`CutScope`]): for the nodal
    /// families, every element the pattern lists at a node in the cut's
    /// [`Reach`], in increasing order; `None` (the whole mesh) for the
    /// discontinuous Galerkin family, whose pattern's blocks are not nodes,
    /// or a plane that is not a number.
    fn cut_scope(&mut self, plane: &Plane, polygon: Option<&[[f64; 3]]>) -> Option<Vec<u32>> {
        let Model::Nodal(_) = &self.elements else { return None };
        let mesh = &self.mesh;
        if self.node_diameters.as_ref().is_none_or(|d| d.len() != mesh.nodes.len()) {
            self.node_diameters = Some(node_diameters(mesh));
        }
        let diameters = self.node_diameters.as_deref()?;
        let reach = match polygon {
            Some(polygon) => Reach::of_polygon(mesh, plane, polygon),
            None => Reach::of_plane(mesh, plane),
        };
        if !(plane.check().is_ok() && self.pattern.num_blocks == mesh.nodes.len()) {
            return None;
        }
        // (marked, then listed in order: each element sits at several nodes)
        let mut marked = vec![false; mesh.elements.len()];
        (0..mesh.nodes.len())
            .filter(|&v| reach.contains(mesh.nodes[v], diameters[v]))
            .flat_map(|v| self.pattern.elements_at(v))
            .for_each(|e| marked[e as usize] = true);
        Some((0..mesh.elements.len() as u32).filter(|&e| marked[e as usize]).collect())
    }

    /// Cuts the mesh in place along `shape`, leaving whole the
    /// elements found unhealthy before and looking only at the elements in
    /// scope, and brings everything else up to date.
    /// When the element store finds an element the cut made or changed
    /// unhealthy (see [`crate::store::HealthFloors`]), the cut is undone
    /// and run again with the element it came from kept whole, up to
    /// [`CUT_ATTEMPTS`] times; on any other error the mesh is rolled back.
    fn cut(&mut self, shape: CutShape) -> Result<PolygonCutReport, Error> {
        // (a polygon without a plane fails before anything changes)
        let (plane, polygon) = match shape {
            CutShape::Plane(plane) => (*plane, None),
            CutShape::Polygon(polygon) => (polygon_plane(polygon)?, Some(polygon)),
        };
        // (the penalty is the body's as it was built: a cut keeps it)
        self.stabilise()?;
        let t = std::time::Instant::now();
        let rebuild = |t: &PhaseTimings| t.basis + t.assembly + t.solve;
        let before = rebuild(&self.timings);
        let mut keep_whole: Vec<u32> = Vec::new();
        // (every attempt starts from the same mesh: the scope holds for all)
        let listed = self.cut_scope(&plane, polygon);
        let opts = self.cut_options();
        let size = |mesh: &PolyMesh| (mesh.nodes.len(), mesh.elements.len(), mesh.faces.len());
        let size_before = size(&self.mesh);
        let result = loop {
            let scope = listed.as_deref().map_or(CutScope::whole(), |l| CutScope::listed(&self.mesh, l));
            let (rollback, cut) = Rollback::cut(&mut self.mesh, shape, &opts, &keep_whole, scope);
            let outcome = match cut {
                Err(error) => Err((None, error.into())),
                // a cut that misses the body, or meets it only along faces
                // it leaves joined, changes nothing: the element data, the
                // pattern, its analysis and the solver's carried state stand
                Ok(report) if report.cut.touched.is_empty() && size(&self.mesh) == size_before => Ok(report),
                Ok(report) => match self.apply_cut(&report) {
                    Ok(()) => Ok(report),
                    Err(error) => {
                        let parent = unhealthy_parent(&error, &report.cut);
                        Err((parent, error))
                    }
                },
            };
            match outcome {
                Ok(report) => break Ok(report),
                Err((Some(parent), _)) if keep_whole.len() + 1 < CUT_ATTEMPTS => {
                    rollback.restore(&mut self.mesh);
                    if let Err(at) = keep_whole.binary_search(&parent) {
                        keep_whole.insert(at, parent);
                    }
                    self.cut_retries += 1;
                }
                Err((_, error)) => {
                    rollback.restore(&mut self.mesh);
                    break Err(error);
                }
            }
        };
        // the new pattern's analysis (Cholesky ordering and symbolic
        // factorisation, or the block structure of CG) makes the system
        // ready: `apply_cut` ran it, and here one that failed runs again
        // and reports; the cut itself stands even if that fails
        let result = result.and_then(|report| {
            let (system, pattern) = (&mut self.system, &self.pattern);
            self.timings.time(Phase::Solve, || system.ensure_analysed(pattern))?;
            Ok(report)
        });
        // rebuilding element data and pattern, and the analysis, are booked
        // under their own phases
        let topology = t.elapsed().as_secs_f64() - (rebuild(&self.timings) - before);
        self.timings.add(Phase::Topology, topology);
        result
    }

    /// Checks the touched elements of a cut mesh and rebuilds their data
    /// (the store checks their health) while the pattern's columns of
    /// their nodes are updated, the solver analyses the new pattern and
    /// the state is carried over to the new nodes ([`NodeOrigins`]), then
    /// updates the masses, restores the momenta of the nodes whose masses
    /// changed, and brings the rotations (untouched elements keep theirs,
    /// new ones get theirs) up to date, and leaves the boundary surface to
    /// be rebuilt when next asked for. Nothing but the mesh has changed
    /// when it fails (the pattern is put back, and the solver analyses it
    /// again when next asked to; the carried states are taken off).
    pub(super) fn apply_cut(&mut self, report: &PolygonCutReport) -> Result<(), Error> {
        let (mesh, cut) = (&self.mesh, &report.cut);
        let touched = &cut.touched;
        // only the touched elements changed (the two sides of a cut carry
        // coincident nodes by design, which a whole-mesh check would flag)
        let list: Vec<usize> = touched.iter().map(|&e| e as usize).collect();
        let check = |mesh: &PolyMesh| mesh.check_elements(&list, &ValidationOptions::default());
        // the negative part of a split element inherits from its positive part
        let parents: Vec<(u32, u32)> = cut.split.split_elements.iter().map(|&(kept, new)| (new, kept)).collect();
        let kind = self.solver_kind();
        let nodal = match &mut self.elements {
            Model::Nodal(nodal) => nodal,
            Model::Dg(_) => {
                check(mesh)?;
                return self.apply_cut_dg(cut, &parents);
            }
        };
        let origins = NodeOrigins::of_polygon_cut(report).map_err(|m| Error::Internal(format!("{m} after a cut")))?;
        if origins.len() != mesh.nodes.len() {
            let message = format!("{} node states for {} nodes after a cut", origins.len(), mesh.nodes.len());
            return Err(Error::Internal(message));
        }
        // the check of the touched elements and their data (on every thread)
        // beside the pattern's structure, which reads only the mesh, the
        // solver's analysis of it (mostly moving arrays, on one thread) and
        // the node states carried over; all are undone if the check or the
        // store refuses an element
        let (store, pattern, system, p) = (&mut nodal.store, &mut self.pattern, &mut self.system, &self.params);
        let (state, masses) = (&mut self.state, &self.masses);
        let n = mesh.nodes.len();
        let elements_of = |e: u32| mesh.elements.get(e as usize).map_or(&[][..], |el| &el.nodes[..]);
        let t = std::time::Instant::now();
        let ((built, check_seconds, store_seconds), (((unlocated, pattern_seconds), ((), analysis_seconds)), carried)) =
            rayon::join(
                || {
                    let (checked, check_seconds) = timed(|| check(mesh));
                    let (built, store_seconds) = match checked {
                        Ok(()) => {
                            timed(|| store.update(mesh, &p.material, &p.basis, touched, &parents).map_err(Error::from))
                        }
                        Err(error) => (Err(error.into()), 0.0),
                    };
                    (built, check_seconds, store_seconds)
                },
                || {
                    let update = timed(|| pattern.update(n, &elements_of, touched, &cut.old_nodes));
                    // (an analysis that fails is run again, and reported, by the caller)
                    let analysis = timed(|| {
                        system.renew(kind, pattern, p.tolerance, p.max_iterations);
                        let _analysed = system.ensure_analysed(pattern);
                    });
                    let carried = carry_node_states(cut, mesh, &origins, masses, state);
                    ((update, analysis), carried)
                },
            );
        // (the branches overlap: the rebuild books its time, the pattern and
        // the analysis the time they took past it; the check is the cut's)
        let beside = (t.elapsed().as_secs_f64() - check_seconds - store_seconds).max(0.0);
        self.timings.add(Phase::Basis, store_seconds);
        self.timings.add(Phase::Assembly, pattern_seconds.min(beside));
        self.timings.add(Phase::Solve, (beside - pattern_seconds).clamp(0.0, analysis_seconds));
        let (changed_nodes, before) = carried;
        let changes = match built {
            Ok(changes) => changes,
            Err(error) => {
                // the store still holds the elements as they were; the
                // carried node states are taken off (the columns to put
                // back: those of the touched elements now)
                let nodes_before = cut.nodes_before as usize;
                for field in [&mut state.displacement, &mut state.velocity, &mut state.previous_velocity] {
                    field.truncate(nodes_before);
                }
                let store = &nodal.store;
                let now: Vec<u32> = touched.iter().flat_map(|&e| elements_of(e).iter().copied()).collect();
                let undo = pattern.update(cut.nodes_before as usize, &|e| store.element_nodes(e), touched, &now);
                pattern.locate(store, undo);
                system.renew(kind, pattern, p.tolerance, p.max_iterations);
                return Err(error);
            }
        };
        if let Some(diameters) = &mut self.node_diameters {
            raise_node_diameters(mesh, touched.par_iter().map(|&e| e as usize), diameters);
        }
        let store = &nodal.store;
        // the pattern's entries located in the new store, beside the
        // rotations (which do not read it)
        let corotation = &mut nodal.corotation;
        let (masses, loads) = (&mut self.masses, &mut self.loads);
        let (locate_seconds, ()) = rayon::join(
            || timed(|| pattern.locate(store, unlocated)).1,
            || {
                state.refresh_positions(&mesh.nodes);
                corotation.apply_changes(store, &changes, &state.position, p.corotated);
            },
        );
        self.timings.add(Phase::Assembly, locate_seconds);
        // only the changed nodes' masses change ([`super::nodal_masses`]),
        // read through the located pattern (each node's sum in its order)
        let changed_masses: Vec<f64> = changed_nodes
            .par_iter()
            .map(|&v| store.lumped_mass(pattern.held_at(v as usize), p.material.density))
            .collect();
        masses.resize(n, 0.0);
        changed_nodes.iter().zip(changed_masses).for_each(|(&v, m)| masses[v as usize] = m);
        loads.clone_from(masses);
        conserve_momentum(&changed_nodes, masses, &state.position, &mut state.velocity, before);
        self.statics = None;
        self.surface = std::sync::OnceLock::new();
        self.refresh_body_loads();
        self.refresh_embedding()
    }

    /// [`Simulation::apply_cut`] for the discontinuous Galerkin family: the
    /// touched elements are rebuilt in their parents' frames (only the
    /// faces the cut changed are integrated again), and each takes its
    /// parent's polynomials re-expressed in its own basis (the paper's
    /// heuristic of copying the coefficients, made exact: the fields do not
    /// change, so neither do momentum and angular momentum).
    fn apply_cut_dg(&mut self, cut: &CutReport, parents: &[(u32, u32)]) -> Result<(), Error> {
        let Model::Dg(dg) = &mut self.elements else {
            return Err(Error::Internal("a nodal body in the DG rebuild".into()));
        };
        let (mesh, touched, m) = (&self.mesh, &cut.touched, dg.size());
        let existing = dg.store.locate.len() as u32;
        let parent = |e: u32| parents.iter().find(|p| p.0 == e).map_or(e, |p| p.1);
        // the parents' bases and fields before the cut
        let mut old = std::collections::HashMap::new();
        for &e in touched {
            let p = parent(e);
            if p < existing && !old.contains_key(&p) {
                let blocks = p as usize * m..(p as usize + 1) * m;
                let state = &self.state;
                let fields = (
                    state.displacement[blocks.clone()].to_vec(),
                    state.velocity[blocks.clone()].to_vec(),
                    state.previous_velocity[blocks].to_vec(),
                );
                old.insert(p, (dg.basis(p).coefficients, fields));
            }
        }
        let t = std::time::Instant::now();
        let changes = dg.store.update(mesh, &self.params.material, &self.params.basis, touched, parents)?;
        let blocks = dg.num_blocks();
        for field in [&mut self.state.displacement, &mut self.state.velocity, &mut self.state.previous_velocity] {
            field.resize(blocks, [0.0; 3]);
        }
        for &e in touched {
            let Some((c_parent, (u, v, w))) = old.get(&parent(e)) else { continue };
            let transfer = crate::store::dg::transfer(c_parent, &dg.basis(e).coefficients, m);
            let state = &mut self.state;
            let at = e as usize * m..(e as usize + 1) * m;
            for (field, from) in
                [(&mut state.displacement, u), (&mut state.velocity, v), (&mut state.previous_velocity, w)]
            {
                for (j, out) in field[at.clone()].iter_mut().enumerate() {
                    *out = std::array::from_fn(|k| (0..m).map(|i| transfer[i * m + j] * from[i][k]).sum());
                }
            }
        }
        // DG glues elements through faces only: nodes the cut left between
        // pieces that touch at a vertex or along an edge are opened, so
        // that the stitched field never averages two pieces (this renames
        // nodes only; the bases, found by vertex positions, stay valid)
        let mut candidates: Vec<u32> =
            touched.iter().flat_map(|&e| mesh.elements[e as usize].nodes.iter().copied()).collect();
        candidates.extend(cut.duplicated.iter().map(|p| p.0));
        let pinched = pinched_nodes(mesh, candidates);
        let undo = (!pinched.is_empty()).then(|| Rollback::around_nodes(mesh, &pinched));
        open_pinched_nodes(&mut self.mesh, &pinched);
        let mesh = &self.mesh;
        dg.refresh_after_change(mesh, &self.boundary.fixed, touched);
        self.timings.add(Phase::Basis, t.elapsed().as_secs_f64());
        self.state.refresh_positions(dg.rest());
        dg.corotation.apply_changes(&dg.store, &changes, &self.state.position, self.params.corotated);
        let t = std::time::Instant::now();
        self.pattern = crate::assembly::SparsePattern::build(blocks, &**dg);
        self.timings.add(Phase::Assembly, t.elapsed().as_secs_f64());
        self.surface = std::sync::OnceLock::new();
        self.faces_integrated += changes.faces_integrated;
        // (the caller's rollback undoes the cut; the opened nodes first)
        self.refresh_dg_dependents().inspect_err(|_| {
            if let Some(undo) = undo {
                undo.restore(&mut self.mesh);
            }
        })
    }
}

/// The node states of a cut mesh `mesh` carried over to its new nodes
/// ([`NodeOrigins`]), appended to the `state`'s displacements and
/// velocities; returns the nodes whose masses change (those of the
/// touched elements, before and after the cut, ascending) and the linear
/// and angular momenta of the old ones among them, with their old
/// `masses` and velocities ([`momenta`]).
fn carry_node_states(
    cut: &CutReport,
    mesh: &PolyMesh,
    origins: &NodeOrigins,
    masses: &[f64],
    state: &mut super::NodeState,
) -> (Vec<u32>, ([f64; 3], [f64; 3])) {
    let mut changed_nodes = cut.old_nodes.clone();
    changed_nodes.extend(cut.touched.iter().flat_map(|&e| mesh.elements[e as usize].nodes.iter().copied()));
    changed_nodes.sort_unstable();
    changed_nodes.dedup();
    let old_changed = &changed_nodes[..changed_nodes.partition_point(|&v| v < cut.nodes_before)];
    let before = momenta(old_changed, masses, &state.position, &state.velocity);
    origins.extend(&mut state.displacement);
    origins.extend(&mut state.velocity);
    origins.extend(&mut state.previous_velocity);
    (changed_nodes, before)
}

/// `f`'s result and the wall time it took (s).
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t = std::time::Instant::now();
    let out = f();
    (out, t.elapsed().as_secs_f64())
}

/// The element a cut kept whole would have avoided `error`: an unhealthy
/// element the cut touched is the element with its id, or (a negative
/// part, appended) the element whose positive part kept the id.
fn unhealthy_parent(error: &Error, cut: &CutReport) -> Option<u32> {
    let Error::Basis(b) = error else {
        return None;
    };
    let e = b.element() as u32;
    cut.touched.binary_search(&e).ok()?;
    Some(cut.split.split_elements.iter().find(|p| p.1 == e).map_or(e, |p| p.0))
}
