//! Meshing a closed surface (kaufmann2008 §10, martin2008 §7): grid
//! slicing fills exactly the surface's inside and its boundary is the
//! surface; octree leaves meet without hanging nodes; both pass the patch
//! test; bad surfaces are refused with one clear error each.

use crate::common;

use std::collections::HashMap;

use cleave::io::{read_surface, Surface};
use cleave::mesh::PolyMesh;
use cleave::meshing::{grid_slice, octree};
use cleave::store::{BasisOptions, Family, HealthFloors};
use cleave::surface::{prepare, SurfaceReport};
use cleave_kernels::vec3::{cross, norm, sub};

fn bunny() -> (Surface, SurfaceReport) {
    prepare(&read_surface(&common::asset("bunny.obj")).unwrap()).unwrap()
}

fn boundary_area(mesh: &PolyMesh) -> f64 {
    mesh.boundary_triangles()
        .iter()
        .map(|t| {
            let p = t.map(|v| mesh.nodes[v as usize]);
            0.5 * norm(cross(sub(p[1], p[0]), sub(p[2], p[0])))
        })
        .sum()
}

/// Every face bounds one or two elements, and no node of an element lies
/// on one of its faces without being in that face's loop (a hanging node).
fn assert_conforming(mesh: &PolyMesh) {
    let mut owners: HashMap<u32, Vec<usize>> = HashMap::new();
    for (e, el) in mesh.elements.iter().enumerate() {
        for f in &el.faces {
            owners.entry(f.face).or_default().push(e);
        }
    }
    assert!(owners.values().all(|o| o.len() == 1 || o.len() == 2));
    for (&f, elements) in &owners {
        let face = &mesh.faces[f as usize];
        let plane = cleave::mesh::face_geometry(&mesh.nodes, &face.vertices);
        let size = plane.diameter;
        for &e in elements {
            for &v in &mesh.elements[e].nodes {
                let p = mesh.nodes[v as usize];
                let off = cleave_kernels::vec3::dot(sub(p, plane.centroid), plane.normal).abs();
                if face.vertices.contains(&v) || off > 1e-12 * size {
                    continue;
                }
                assert!(!inside_face(mesh, face, p), "node {v} lies on face {f} of element {e} but is not in its loop");
            }
        }
    }
}

/// Whether `p` (in the face's plane) lies inside or on the face's loop.
fn inside_face(mesh: &PolyMesh, face: &cleave::mesh::Face, p: [f64; 3]) -> bool {
    let area = |t: &[u32; 3]| {
        let q = t.map(|v| mesh.nodes[v as usize]);
        norm(cross(sub(q[1], q[0]), sub(q[2], q[0])))
    };
    face.triangles.iter().any(|t| {
        let q = t.map(|v| mesh.nodes[v as usize]);
        let parts = [[q[0], q[1], p], [q[1], q[2], p], [q[2], q[0], p]];
        let sum: f64 = parts.iter().map(|s| norm(cross(sub(s[1], s[0]), sub(s[2], s[0])))).sum();
        sum <= area(t) * (1.0 + 1e-9)
    })
}

#[test]
fn sliced_bunny_fills_the_surface_exactly_at_four_resolutions() {
    let (surface, report) = bunny();
    for cell in [2.0, 1.0, 0.5, 0.3] {
        let (mesh, r) = grid_slice(&surface, cell, &Default::default()).unwrap();
        let volume = mesh.total_volume();
        let area = boundary_area(&mesh);
        println!(
            "cell {cell}: {} elements ({} hexahedra, {} pieces, {} merged), {} nodes, volume error {:.1e}, area error {:.1e}",
            mesh.elements.len(),
            r.hexahedra,
            r.pieces,
            r.merged,
            mesh.nodes.len(),
            (volume - report.volume) / report.volume,
            (area - report.area) / report.area,
        );
        assert!(((volume - report.volume) / report.volume).abs() < 1e-9);
        assert!(((area - report.area) / report.area).abs() < 1e-9);
        mesh.validate().unwrap();
        assert_conforming(&mesh);
        for e in 0..mesh.elements.len() {
            assert!(mesh.element_volume(e) > 1e-3 * 0.05 * cell.powi(3), "element {e} is too small");
        }
    }
}

#[test]
fn octree_bunny_keeps_whole_cells_without_hanging_nodes() {
    let (surface, report) = bunny();
    for depth in [3, 4, 5] {
        let (mesh, r) = octree(&surface, depth).unwrap();
        println!(
            "depth {depth}: {} elements by depth {:?}, {} dropped, {} nodes",
            mesh.elements.len(),
            r.leaves_by_depth,
            r.dropped,
            mesh.nodes.len()
        );
        mesh.validate().unwrap();
        assert_conforming(&mesh);
        // the volume is the kept cubes' volumes
        let cubes: f64 = (0..mesh.elements.len()).map(|e| mesh.element_diameter(e).powi(3) / 3f64.sqrt().powi(3)).sum();
        assert!((mesh.total_volume() - cubes).abs() < 1e-9 * cubes);
        // it covers the surface's inside and more, by less than the cells crossing it
        assert!(mesh.total_volume() > report.volume);
        assert!(r.leaves_by_depth.iter().filter(|&&n| n > 0).count() >= 2, "depths mix");
    }
}

#[test]
fn octree_meshes_pass_the_patch_test_across_depth_transitions() {
    let (surface, _) = bunny();
    let (mesh, r) = octree(&surface, 4).unwrap();
    assert!(r.leaves_by_depth[3] > 0 && r.leaves_by_depth[4] > 0);
    for family in [Family::MeanValue, Family::Harmonic] {
        let (err, interior) = common::patch_error(mesh.clone(), BasisOptions { family, ..Default::default() });
        println!("{family:?}: patch error {err:.1e} over {interior} interior nodes");
        assert!(interior > 50);
        assert!(err < 1e-9, "{family:?}: {err:e}");
    }
}

#[test]
fn sliced_meshes_pass_the_patch_test_with_harmonic_elements() {
    let (surface, _) = bunny();
    let (mesh, _) = grid_slice(&surface, 1.0, &Default::default()).unwrap();
    // exact pieces keep surface vertices a hair from grid planes: nodes of
    // small mass share and nearly soft elements, which the default health
    // floors refuse (the DG family has no nodes; see the scenes); the
    // integration of non-convex, non-star-shaped pieces is checked here
    let health = HealthFloors { mass_fraction: 0.0, stiffness_ratio: 0.0, ..Default::default() };
    let (err, interior) =
        common::patch_error(mesh.clone(), BasisOptions { family: Family::Harmonic, health, ..Default::default() });
    println!("harmonic: patch error {err:.1e} over {interior} interior nodes");
    assert!(interior > 20);
    assert!(err < 1e-9, "{err:e}");
    // mean value elements must be convex and seen from their centroid: the
    // pieces are refused by name
    let params =
        cleave::sim::SimulationParams { basis: BasisOptions { health, ..Default::default() }, ..Default::default() };
    let e = cleave::sim::Simulation::new(mesh, params).err().expect("non-convex pieces");
    assert!(matches!(e, cleave::Error::Basis(_)) && e.to_string().contains("element"), "{e}");
}

/// With the surface inside each cell simplified to a fan over its loop on
/// the cell's faces, a sliced bunny runs with harmonic elements: the mesh
/// is valid and conforming, its volume within 2 % of the surface's, every
/// element's stiffness healthy, and a drop stays bounded (no node faster
/// than twice free fall, no element stretched by half).
#[test]
fn a_simplified_sliced_bunny_runs_with_harmonic_elements() {
    use cleave::meshing::SliceOptions;
    use cleave::sim::{Collider, Simulation, SimulationParams};
    let (surface, report) = bunny();
    let (mesh, _) = grid_slice(&surface, 1.0, &SliceOptions { merge_below: 0.05, simplify: 0.2 }).unwrap();
    mesh.validate().unwrap();
    assert_conforming(&mesh);
    let error = (mesh.total_volume() - report.volume) / report.volume;
    println!("simplified: {} elements, {} nodes, volume error {error:.2e}", mesh.elements.len(), mesh.nodes.len());
    assert!(error.abs() < 0.02, "{error}");
    let health = HealthFloors { mass_fraction: 0.0, ..Default::default() };
    let mut params = SimulationParams {
        basis: BasisOptions { family: Family::Harmonic, health, ..Default::default() },
        gravity: [0.0, -9.81, 0.0],
        mass_damping: 0.3,
        ..Default::default()
    };
    params.material = cleave::material::Material::new(5e6, 0.35, 1000.0).unwrap();
    let mut sim = Simulation::new(mesh, params).unwrap();
    sim.add_collider(Collider::new([0.0, -0.5, 0.0], [0.0, 1.0, 0.0], 1e9).unwrap());
    let steps = 100;
    let (mut fastest, mut stretch) = (0.0f64, 0.0f64);
    for _ in 0..steps {
        sim.step().unwrap();
        fastest = fastest.max(sim.max_node_speed().value);
        stretch = stretch.max(sim.worst_stretch().value);
    }
    let free_fall = 9.81 * sim.time();
    println!("drop: fastest node {fastest:.2} m/s (free fall {free_fall:.2}), worst stretch {stretch:.3}");
    assert!(fastest < 2.0 * free_fall && stretch < 1.5);
}
