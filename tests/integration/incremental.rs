//! After a cut only the touched elements are rebuilt: the updated element
//! store and sparse pattern must equal the ones built from scratch on the
//! cut mesh (element data bitwise, the pattern's structure exactly, the
//! assembled matrix up to the summation order). A cut that fails is undone
//! from what [`Rollback`] saved, which must cover everything a cut changes.

use cleave::assembly::SparsePattern;
use cleave::material::Material;
use cleave::mesh::Plane;
use cleave::mesh::PolyMesh;
use cleave::meshing::box_tet;
use cleave::sim::{Simulation, SimulationParams};
use cleave::solve::{BlockStructure, SolverKind};
use cleave::store::{BasisOptions, ElementStore, HealthFloors};
use cleave::topology::{
    cut_by_plane, cut_by_plane_keeping, cut_by_polygon, cut_by_polygon_keeping, node_diameters, polygon_plane,
    CutReport, CutScope, CutShape, PolygonCutReport, Reach, Rollback, SplitOptions,
};
use proptest::prelude::*;

use crate::common;

/// The store, pattern and mesh of one topology.
struct System {
    mesh: PolyMesh,
    store: ElementStore,
    pattern: SparsePattern,
}

fn material() -> Material {
    Material::new(1e5, 0.3, 1000.0).unwrap()
}

/// The default basis without the health check: the raw topology of a cut
/// may make an element the simulation would refuse (it retries the cut
/// keeping that element whole); these tests compare updates with fresh
/// builds of the same mesh, whatever its elements.
fn basis() -> BasisOptions {
    let health = HealthFloors { stiffness_ratio: 0.0, mass_fraction: 0.0, rigid_residual: f64::INFINITY };
    BasisOptions { health, ..Default::default() }
}

impl System {
    fn new(mesh: PolyMesh) -> Self {
        let store = ElementStore::build(&mesh, &material(), &basis()).unwrap();
        let pattern = SparsePattern::build(mesh.nodes.len(), &store);
        System { mesh, store, pattern }
    }

    /// Applies `cut` to the mesh and updates store and pattern in place.
    fn cut(&mut self, cut: impl FnOnce(&mut PolyMesh) -> CutReport) {
        let report = cut(&mut self.mesh);
        let old_nodes = self.store.nodes_of(&report.touched);
        // (the structure from the mesh alone, before the store is rebuilt)
        let mesh = &self.mesh;
        let nodes = |e: u32| mesh.elements.get(e as usize).map_or(&[][..], |el| &el.nodes[..]);
        let unlocated = self.pattern.update(mesh.nodes.len(), &nodes, &report.touched, &old_nodes);
        self.store.update(mesh, &material(), &basis(), &report.touched, &[]).unwrap();
        self.pattern.locate(&self.store, unlocated);
    }

    fn matrix(&self) -> Vec<f64> {
        let mut values = vec![0.0; self.pattern.nnz()];
        let store = &self.store;
        self.pattern.assemble(&mut values, |b, i, c, out| store.batches[b].block_column(i, c, out));
        values
    }

    /// Compares with a system built from scratch on the same mesh.
    fn check(&self) {
        let fresh = System::new(self.mesh.clone());
        assert_eq!(self.store.locate.len(), self.mesh.elements.len());
        for e in 0..self.mesh.elements.len() {
            let (b, i) = self.store.locate[e];
            let (fb, fi) = fresh.store.locate[e];
            let (x, y) = (&self.store.batches[b as usize], &fresh.store.batches[fb as usize]);
            let (i, fi) = (i as usize, fi as usize);
            assert_eq!(x.elements[i], e as u32);
            assert_eq!((x.kind, x.k), (y.kind, y.k), "element {e}");
            assert_eq!(x.element_nodes(i), y.element_nodes(fi), "element {e}");
            assert_eq!(x.volume[i], y.volume[fi], "element {e}");
            assert_eq!(x.element_matrix(i), y.element_matrix(fi), "element {e}");
            let k = x.k;
            assert_eq!(x.mass_fraction[i * k..(i + 1) * k], y.mass_fraction[fi * k..(fi + 1) * k]);
            assert_eq!(x.stress_grads[i * k..(i + 1) * k], y.stress_grads[fi * k..(fi + 1) * k]);
        }
        assert_eq!(self.pattern.symbolic().col_ptr(), fresh.pattern.symbolic().col_ptr());
        assert_eq!(self.pattern.symbolic().row_idx(), fresh.pattern.symbolic().row_idx());
        // the block structure kept with the pattern is the one its scalar rows hold
        let read = BlockStructure::new(self.pattern.symbolic()).unwrap();
        assert_eq!(self.pattern.blocks(), &read);
        let (a, b) = (self.matrix(), fresh.matrix());
        let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (p, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!((x - y).abs() <= 1e-13 * scale, "entry {p}: {x} vs {y}");
        }
        for d in 0..3 * self.mesh.nodes.len() {
            assert_eq!(self.pattern.diagonal_slot(d), fresh.pattern.diagonal_slot(d));
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(60))]

    #[test]
    fn updates_after_cuts_equal_a_fresh_build(
        seed in 0u64..10_000,
        planes in prop::collection::vec(common::plane_strategy(0.1, 0.9), 1..4),
    ) {
        let mesh = common::cube_of_polyhedra_or_tets(seed, 6);
        let mut system = System::new(mesh);
        for (i, plane) in planes.iter().enumerate() {
            if i % 2 == 0 {
                system.cut(|m| cut_by_plane(m, plane, &SplitOptions::default()).unwrap());
            } else {
                let polygon = common::rectangle_in_plane(plane, (0.3, 0.3), 0.0);
                system.cut(|m| cut_by_polygon(m, &polygon, &SplitOptions::default()).unwrap().cut);
            }
            system.check();
        }
    }
}

#[test]
fn a_cut_that_touches_nothing_changes_nothing() {
    let mut system = System::new(box_tet([0.0; 3], [1.0; 3], [2, 2, 2]).unwrap());
    let before = system.matrix();
    system.cut(|m| {
        cut_by_plane(m, &Plane { point: [5.0, 0.0, 0.0], normal: [1.0, 0.0, 0.0] }, &Default::default()).unwrap()
    });
    assert_eq!(system.matrix(), before);
    system.check();
}

/// A cut rewrites the pattern's arrays in place: the columns it touched
/// are written where they now start and the others move within the same
/// arrays (no new ones, whose pages a cut across a large mesh would fault
/// in), while the arrays' capacity holds what the cut adds.
#[test]
fn a_small_cut_updates_the_pattern_in_place() {
    let mut system = System::new(box_tet([0.0; 3], [1.0; 3], [10, 10, 10]).unwrap());
    let rows = |s: &System| {
        let rows = s.pattern.blocks().columns().rows;
        (rows.as_ptr(), rows.len())
    };
    let (before, len) = rows(&system);
    let plane = Plane { point: [0.52, 0.5, 0.5], normal: [1.0, 0.1, 0.2] };
    let polygon = common::rectangle_in_plane(&plane, (0.15, 0.15), 0.1);
    system.cut(|m| cut_by_polygon(m, &polygon, &SplitOptions::default()).unwrap().cut);
    let (after, new_len) = rows(&system);
    assert!(new_len > len, "the cut added no entries: it tests nothing");
    assert_eq!(before, after, "the update laid the rows out in new memory");
    system.check();
}

/// Conjugate gradients work on the pattern's 3x3 blocks: a body they solve
/// never has the scalar rows made, through steps and cuts, while a
/// Cholesky solve has them made, and made again after a cut, equal to
/// those of a pattern built afresh.
#[test]
fn only_a_scalar_solver_makes_the_scalar_rows() {
    let blade = [[0.53, -0.1, 0.2], [0.63, 0.6, 0.2], [0.63, 0.6, 0.8], [0.53, -0.1, 0.8]];
    for (solver, scalar) in [(SolverKind::Cg, false), (SolverKind::Cholesky, true)] {
        let mesh = box_tet([0.0; 3], [2.0, 1.0, 1.0], [8, 4, 4]).unwrap();
        let params = SimulationParams { solver, gravity: [0.0, -9.81, 0.0], ..Default::default() };
        let mut sim = Simulation::new(mesh, params).unwrap();
        sim.step().unwrap();
        assert_eq!(sim.pattern().holds_scalar(), scalar, "{solver:?}: after a step");
        sim.cut_polygon(&blade).unwrap();
        sim.step().unwrap();
        assert_eq!(sim.pattern().holds_scalar(), scalar, "{solver:?}: after a cut and a step");
        // a checkpoint writes the scalar rows without keeping them
        let read: SparsePattern = common::checkpoint_round_trip(sim.pattern());
        assert_eq!(sim.pattern().holds_scalar(), scalar, "{solver:?}: after a checkpoint");
        assert_eq!(read.symbolic().row_idx(), sim.pattern().symbolic().row_idx());
        let fresh = SparsePattern::build(sim.mesh().nodes.len(), sim.store());
        let (a, b) = (sim.pattern().symbolic(), fresh.symbolic());
        assert_eq!((a.col_ptr(), a.row_idx()), (b.col_ptr(), b.row_idx()), "{solver:?}");
    }
}

#[test]
fn a_cut_along_a_layer_of_nodes_only_renames_and_still_matches() {
    // x = 0.5 runs through a layer of nodes: nothing is split, the elements
    // on the negative side only move to the copies of the layer's nodes
    let mut system = System::new(box_tet([0.0; 3], [1.0; 3], [2, 2, 2]).unwrap());
    let plane = Plane { point: [0.5, 0.0, 0.0], normal: [1.0, 0.0, 0.0] };
    system.cut(|m| {
        let report = cut_by_plane(m, &plane, &SplitOptions::default()).unwrap();
        assert!(report.split.split_elements.is_empty() && !report.duplicated.is_empty());
        report
    });
    system.check();
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// Everything a cut changes in the mesh it had is saved beforehand, and
    /// restoring puts the mesh back exactly; the cut that saves its
    /// rollback beside its read-only part is the plain cut.
    #[test]
    fn rollback_saves_all_a_cut_changes(
        seed in 0u64..10_000,
        plane in common::plane_strategy(0.1, 0.9),
        polygon in any::<bool>(),
        half in (0.1f64..0.6, 0.1f64..0.6),
    ) {
        let before = common::cube_of_polyhedra_or_tets(seed, 6);
        let (mut mesh, mut plain) = (before.clone(), before.clone());
        let corners = common::rectangle_in_plane(&plane, half, 0.3);
        let opts = SplitOptions::default();
        let shape = if polygon { CutShape::Polygon(&corners) } else { CutShape::Plane(&plane) };
        let (rollback, report) = Rollback::cut(&mut mesh, shape, &opts, &[], CutScope::whole());
        let plain_report = if polygon {
            cut_by_polygon(&mut plain, &corners, &opts).unwrap()
        } else {
            PolygonCutReport { cut: cut_by_plane(&mut plain, &plane, &opts).unwrap(), pocket: None }
        };
        prop_assert_eq!(report.unwrap(), plain_report);
        prop_assert!(mesh == plain);
        for e in 0..before.elements.len() {
            prop_assert!(mesh.elements[e] == before.elements[e] || rollback.saved_element(e), "element {} not saved", e);
        }
        for f in 0..before.faces.len() {
            prop_assert!(mesh.faces[f] == before.faces[f] || rollback.saved_face(f), "face {} not saved", f);
        }
        rollback.restore(&mut mesh);
        prop_assert!(mesh == before);
    }
    /// A cut that looks only at the elements holding a node in its `Reach`
    /// (plus those it appends) makes the same mesh and report as one over
    /// the whole mesh, and its rollback saves everything it changes (for a
    /// whole plane, the same as over the whole mesh); after a first cut, so
    /// that element sizes differ.
    #[test]
    fn a_cut_over_its_scope_equals_a_cut_over_the_whole_mesh(
        seed in 0u64..10_000,
        first in common::plane_strategy(0.2, 0.8),
        plane in common::plane_strategy(0.1, 0.9),
        polygon in any::<bool>(),
        half in (0.1f64..0.6, 0.1f64..0.6),
    ) {
        let mut whole = common::cube_of_polyhedra_or_tets(seed, 6);
        cut_by_plane(&mut whole, &first, &SplitOptions::default()).unwrap();
        let before = whole.clone();
        let mut scoped = whole.clone();
        let corners = common::rectangle_in_plane(&plane, half, 0.3);
        let cut_plane = if polygon { polygon_plane(&corners).unwrap() } else { plane };
        let reach =
            if polygon { Reach::of_polygon(&whole, &cut_plane, &corners) } else { Reach::of_plane(&whole, &plane) };
        let listed = reach.elements(&whole, &node_diameters(&whole));
        let scope = CutScope::listed(&scoped, &listed);
        let saved = (Rollback::around_plane(&whole, &cut_plane, CutScope::whole()), Rollback::around_plane(&scoped, &cut_plane, scope));
        if !polygon {
            prop_assert_eq!(saved.0.elements(), saved.1.elements());
        }
        let opts = SplitOptions::default();
        if polygon {
            let a = cut_by_polygon_keeping(&mut whole, &corners, &opts, &[], CutScope::whole());
            let b = cut_by_polygon_keeping(&mut scoped, &corners, &opts, &[], scope);
            prop_assert_eq!(a.map(|r| r.cut), b.map(|r| r.cut));
        } else {
            let a = cut_by_plane_keeping(&mut whole, &plane, &opts, &[], CutScope::whole());
            let b = cut_by_plane_keeping(&mut scoped, &plane, &opts, &[], scope);
            prop_assert_eq!(a, b);
        }
        prop_assert!(whole == scoped);
        for e in 0..before.elements.len() {
            prop_assert!(scoped.elements[e] == before.elements[e] || saved.1.saved_element(e), "element {} not saved", e);
        }
        for f in 0..before.faces.len() {
            prop_assert!(scoped.faces[f] == before.faces[f] || saved.1.saved_face(f), "face {} not saved", f);
        }
    }
}

/// A simulation's cut looks only at the elements its pattern lists near
/// the plane: it makes the same mesh as a cut over the whole mesh, cut
/// after cut (a blade, a plane, a blade across both).
#[test]
fn a_simulation_cut_over_its_scope_equals_a_cut_over_the_whole_mesh() {
    let mut mesh = box_tet([0.0; 3], [2.0, 1.0, 1.0], [12, 6, 6]).unwrap();
    let params = SimulationParams { min_part: 0.0, ..Default::default() };
    let opts = params.cut;
    let mut sim = Simulation::new(mesh.clone(), params).unwrap();
    sim.step().unwrap();
    let blade = |x: f64, tilt: f64| [[x, -0.1, 0.2], [x + tilt, 0.6, 0.2], [x + tilt, 0.6, 0.8], [x, -0.1, 0.8]];
    for (i, polygon) in [blade(0.53, 0.1), blade(1.21, -0.05)].iter().enumerate() {
        sim.cut_polygon(polygon).unwrap();
        cut_by_polygon(&mut mesh, polygon, &opts).unwrap();
        assert_eq!(sim.cut_retries(), 0, "no element kept whole on a retry");
        assert!(sim.mesh() == &mesh, "blade {i}: the meshes differ");
        let plane = Plane { point: [0.9 + 0.2 * i as f64, 0.5, 0.5], normal: [1.0, 0.3, -0.2] };
        sim.cut_plane(&plane).unwrap();
        cut_by_plane(&mut mesh, &plane, &opts).unwrap();
        assert!(sim.mesh() == &mesh, "plane {i}: the meshes differ");
        sim.step().unwrap();
    }
}

#[test]
fn a_cut_that_fails_half_way_leaves_the_simulation_as_it_was() {
    // every tetrahedron gives each node a quarter of its mass; with a mass
    // floor of 0.99 of the mean share, every polyhedron a cut makes (whose
    // shares differ) fails the store's health check after the mesh changed.
    // The simulation retries, keeping one more element whole each time; the
    // plane crosses far more elements than it has attempts, so the cut fails
    let mesh = box_tet([0.0; 3], [1.0; 3], [4, 4, 4]).unwrap();
    let health = HealthFloors { mass_fraction: 0.99, ..Default::default() };
    let basis = BasisOptions { health, ..Default::default() };
    let params = SimulationParams { basis, ..Default::default() };
    let (mut sim, mut twin) =
        (Simulation::new(mesh.clone(), params.clone()).unwrap(), Simulation::new(mesh.clone(), params).unwrap());
    sim.step().unwrap();
    twin.step().unwrap();
    let (u, v) = (sim.displacements().to_vec(), sim.velocities().to_vec());
    let err = sim.cut_plane(&Plane { point: [0.37, 0.0, 0.0], normal: [1.0, 0.2, 0.1] }).unwrap_err();
    assert!(err.to_string().contains("mean nodal mass share"), "{err}");
    assert_eq!(sim.cut_retries(), cleave::sim::CUT_ATTEMPTS - 1);
    assert!(sim.mesh() == &mesh, "the mesh was not restored");
    // (each attempt built its elements past the end of their batches and
    // took them off again)
    assert!(sim.store() == twin.store(), "the element store was not restored");
    assert_eq!((sim.displacements(), sim.velocities()), (&u[..], &v[..]));
    // the pattern, updated beside the store's rebuild, was put back (its
    // columns may sum their elements in another order)
    let (a, b) = (sim.pattern().symbolic(), twin.pattern().symbolic());
    assert_eq!((a.col_ptr(), a.row_idx()), (b.col_ptr(), b.row_idx()));
    sim.step().unwrap();
    twin.step().unwrap();
    let scale = twin.displacements().iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
    for (x, y) in sim.displacements().iter().flatten().zip(twin.displacements().iter().flatten()) {
        assert!((x - y).abs() <= 1e-12 * scale, "{x} vs {y}");
    }
}

/// A cut recomputes the masses of the nodes whose elements it changed
/// (before or after) and leaves every other node's to the bit, while each
/// stays the sum over its elements (the store's, summed in its own order:
/// to rounding) and the total the body's.
#[test]
fn a_cut_recomputes_the_masses_of_the_nodes_it_changed_only() {
    let mesh = box_tet([0.0; 3], [2.0, 1.0, 1.0], [12, 6, 6]).unwrap();
    let params = SimulationParams { min_part: 0.0, ..Default::default() };
    let density = params.material.density;
    let mut sim = Simulation::new(mesh, params).unwrap();
    let blade = |x: f64, tilt: f64| [[x, -0.1, 0.2], [x + tilt, 0.6, 0.2], [x + tilt, 0.6, 0.8], [x, -0.1, 0.8]];
    for polygon in [blade(0.53, 0.1), blade(1.21, -0.05), blade(0.9, 0.3)] {
        let before = sim.masses().to_vec();
        let report = sim.cut_polygon(&polygon).unwrap().cut;
        let mut changed = vec![false; sim.mesh().nodes.len()];
        report.old_nodes.iter().for_each(|&v| changed[v as usize] = true);
        for &e in &report.touched {
            sim.mesh().elements[e as usize].nodes.iter().for_each(|&v| changed[v as usize] = true);
        }
        assert!(changed.iter().any(|&c| c) && !changed.iter().all(|&c| c));
        let fresh = sim.store().lumped_masses(changed.len(), density);
        assert_eq!(sim.masses().len(), fresh.len());
        for (v, (&m, &f)) in sim.masses().iter().zip(&fresh).enumerate() {
            assert!((m - f).abs() <= 1e-14 * f, "node {v}: mass {m} against {f} summed afresh");
            if !changed[v] {
                assert_eq!(m.to_bits(), before[v].to_bits(), "node {v} untouched by the cut");
            }
        }
        let total: f64 = sim.masses().iter().sum();
        let body = density * sim.store().total_volume();
        assert!((total - body).abs() <= 1e-12 * body, "total mass {total} against {body}");
    }
}
