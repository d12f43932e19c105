//! Stress-based refinement (martin2008 §6 and Fig. 8, kaufmann2008 Fig. 6):
//! elements whose stress is high are split where they are, with no
//! remeshing.
//!
//! The stress of an element is that of its corotated mean strain
//! `sym(Rᵀ F) - I` (the exact mean of the strain over the element, in the
//! rest frame). An element whose largest absolute principal stress exceeds
//! the threshold is split
//!
//! - **1-to-2** by the plane through its centroid perpendicular to that
//!   principal direction, or, for an element all of whose faces are
//!   perpendicular to the rest axes (a box of a grid and its parts), to
//!   the axis nearest to it: in a bent bar the principal directions are
//!   diagonal near the supports, and diagonal splits of boxes make wedges
//!   that bend stiffer than the boxes they came from (measured: the sag
//!   moved away from the fine mesh's), while axis splits keep boxes; or
//! - **1-to-8** by the three planes through its centroid perpendicular to
//!   the rest axes (a hexahedron of a grid into its eight octants),
//!
//! with the local plane split of cutting ([`crate::topology::split`]): new
//! nodes on crossed edges, which neighbours receive too, so the mesh stays
//! conforming; new nodes take the state interpolated along their edge; the
//! element data, pattern, masses and solvers are updated for the touched
//! elements only, as after a cut. An element is split at most `max_level`
//! times.

use faer::{Mat, Side};

use crate::mesh::{Plane, PolyMesh, ValidationOptions};
use crate::param::ParamError;
use crate::topology::{split_elements_by_plane, CutReport, PolygonCutReport, Rollback, SplitReport};
use crate::Error;

use super::{Phase, Simulation};

/// How a refined element is split.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RefineSplit {
    /// In two, across the largest principal stress.
    Halves,
    /// In eight, by the three axis planes through the centroid.
    Octants,
}

/// When and how elements are refined.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineRule {
    /// Largest absolute principal stress an element may carry (Pa).
    pub threshold: f64,
    /// How a refined element is split.
    pub split: RefineSplit,
    /// How many times an element (and its parts) may be refined.
    pub max_level: u8,
}

impl RefineRule {
    /// Checks `threshold > 0` (finite) and `max_level ∈ 1..=8`.
    pub fn check(&self) -> Result<(), ParamError> {
        if !(self.threshold > 0.0 && self.threshold.is_finite()) {
            return Err(ParamError::new("refine.threshold", self.threshold, "must be a finite stress > 0 (Pa)"));
        }
        if !(1..=8).contains(&self.max_level) {
            return Err(ParamError::new("refine.max_level", self.max_level, "must lie in 1..=8"));
        }
        Ok(())
    }
}

/// What one refinement pass did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RefineReport {
    /// Elements over the threshold that were split.
    pub refined: usize,
    /// Elements over the threshold left as they are (at `max_level`).
    pub at_max_level: usize,
    /// Elements after the pass.
    pub elements: usize,
}

/// The largest absolute principal value of a Voigt stress
/// `[xx, yy, zz, xy, xz, yz]` and its unit direction.
pub fn principal(s: [f64; 6]) -> (f64, [f64; 3]) {
    let m = [[s[0], s[3], s[4]], [s[3], s[1], s[5]], [s[4], s[5], s[2]]];
    let a = Mat::<f64>::from_fn(3, 3, |i, j| m[i][j]);
    let Ok(eigen) = a.self_adjoint_eigen(Side::Lower) else { return (0.0, [1.0, 0.0, 0.0]) };
    let (values, vectors) = (eigen.S(), eigen.U());
    let k = (0..3).max_by(|&i, &j| values[i].abs().total_cmp(&values[j].abs())).unwrap_or(0);
    (values[k].abs(), [vectors[(0, k)], vectors[(1, k)], vectors[(2, k)]])
}

/// Whether every face of element `e` is perpendicular to a rest axis.
fn axis_aligned(mesh: &PolyMesh, e: usize) -> bool {
    mesh.elements[e].faces.iter().all(|r| {
        let n = crate::mesh::face_geometry(&mesh.nodes, &mesh.faces[r.face as usize].vertices).normal;
        n.iter().filter(|c| c.abs() > 1e-12).count() == 1
    })
}

/// The axis (unit vector) nearest to direction `d`.
fn nearest_axis(d: [f64; 3]) -> [f64; 3] {
    let k = (0..3).max_by(|&i, &j| d[i].abs().total_cmp(&d[j].abs())).unwrap_or(0);
    std::array::from_fn(|i| f64::from(i == k))
}

/// Splits element `e` and, for octants, its parts, by the planes of
/// `normals` through `centre`; appends the splits to `report`.
fn split_element(
    mesh: &mut PolyMesh,
    e: u32,
    centre: [f64; 3],
    normals: &[[f64; 3]],
    report: &mut SplitReport,
) -> Result<(), Error> {
    let mut parts = vec![e];
    for &normal in normals {
        let plane = Plane { point: centre, normal };
        let s = split_elements_by_plane(mesh, &plane, &parts, &crate::topology::SplitOptions::default())?;
        parts.extend(s.split_elements.iter().map(|p| p.1));
        report.new_nodes.extend(s.new_nodes);
        report.split_elements.extend(s.split_elements);
        report.repaired_elements.extend(s.repaired_elements);
        report.kept_whole.extend(s.kept_whole);
        report.caps.extend(s.caps);
        report.on_plane.extend(s.on_plane);
    }
    Ok(())
}

impl Simulation {
    /// Splits every element whose stress exceeds `rule.threshold` (see the
    /// module docs) and brings the simulation up to date; on error it is
    /// left unchanged.
    pub fn refine_by_stress(&mut self, rule: &RefineRule) -> Result<RefineReport, Error> {
        rule.check()?;
        if matches!(self.elements, super::Model::Dg(_)) {
            let allowed = "refinement applies to the nodal families (mean value, harmonic)";
            return Err(ParamError::new("refine", "dg", allowed).into());
        }
        let t = std::time::Instant::now();
        let rebuild = |t: &super::PhaseTimings| t.basis + t.assembly + t.solve;
        let before = rebuild(&self.timings);
        let stresses = self.element_stresses();
        self.refine_levels.resize(self.mesh.elements.len(), 0);
        let mut report = RefineReport::default();
        let mut chosen: Vec<(u32, [f64; 3], [f64; 3])> = Vec::new();
        for (e, s) in stresses.iter().enumerate() {
            let (value, direction) = principal(*s);
            if value > rule.threshold {
                if self.refine_levels[e] >= rule.max_level {
                    report.at_max_level += 1;
                } else {
                    let direction = if axis_aligned(&self.mesh, e) { nearest_axis(direction) } else { direction };
                    chosen.push((e as u32, self.mesh.element_centroid(e), direction));
                }
            }
        }
        if chosen.is_empty() {
            report.elements = self.mesh.elements.len();
            return Ok(report);
        }
        let nodes: Vec<u32> =
            chosen.iter().flat_map(|c| self.mesh.elements[c.0 as usize].nodes.iter().copied()).collect();
        let rollback = Rollback::around_nodes(&self.mesh, &nodes);
        let nodes_before = self.mesh.nodes.len();
        let outcome = (|| {
            let mut split = SplitReport::default();
            for &(e, centre, direction) in &chosen {
                let normals: &[[f64; 3]] = match rule.split {
                    RefineSplit::Halves => &[direction],
                    RefineSplit::Octants => &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                };
                split_element(&mut self.mesh, e, centre, normals, &mut split)?;
            }
            let mut touched: Vec<u32> = split.split_elements.iter().flat_map(|&(a, b)| [a, b]).collect();
            touched.extend(&split.repaired_elements);
            touched.sort_unstable();
            touched.dedup();
            let list: Vec<usize> = touched.iter().map(|&e| e as usize).collect();
            self.mesh.check_elements(&list, &ValidationOptions::default())?;
            // (the report's plane names the first split; nothing reads it)
            let plane = Plane { point: chosen[0].1, normal: chosen[0].2 };
            let cut = CutReport::new(&self.mesh, plane, nodes_before, split, Vec::new(), touched);
            let applied = PolygonCutReport { cut, pocket: None };
            self.apply_cut(&applied)?;
            Ok(applied.cut.split)
        })();
        let split = match outcome {
            Ok(split) => split,
            Err(e) => {
                rollback.restore(&mut self.mesh);
                return Err(e);
            }
        };
        // parts inherit their parent's level, one up (in split order, so
        // the parts of parts follow their parents)
        self.refine_levels.resize(self.mesh.elements.len(), 0);
        for &(e, _, _) in &chosen {
            self.refine_levels[e as usize] += 1;
        }
        for &(kept, new) in &split.split_elements {
            self.refine_levels[new as usize] = self.refine_levels[kept as usize];
        }
        let (system, pattern) = (&mut self.system, &self.pattern);
        self.timings.time(Phase::Solve, || system.ensure_analysed(pattern))?;
        let topology = t.elapsed().as_secs_f64() - (rebuild(&self.timings) - before);
        self.timings.add(Phase::Topology, topology);
        report.refined = chosen.len();
        report.elements = self.mesh.elements.len();
        Ok(report)
    }
}
