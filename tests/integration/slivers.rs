//! Sliver merging (wicke2007 §4) on tetrahedral meshes: a sliver with one
//! face below and three above disappears into the element below with the
//! volume unchanged; the slivers of the bunny's TetGen mesh are merged into a
//! valid mesh on which the patch test still passes, and the worst quality
//! never drops.

use cleave::mesh::{Cell, PolyMesh};
use cleave::store::BasisOptions;
use cleave::topology::merge_slivers;

use crate::common;

const MIN_QUALITY: f64 = 0.02;

fn worst_quality(mesh: &PolyMesh) -> f64 {
    (0..mesh.elements.len()).map(|e| mesh.element_quality(e)).fold(f64::INFINITY, f64::min)
}

/// A double pyramid over the triangle `a b d` (apexes `T` above, `B`
/// below) whose upper half is three tetrahedra around a node `c` just above
/// the triangle's centroid: the tetrahedron `a b d c` is a sliver of height
/// `height`, with one face below and three above.
fn double_pyramid_with_sliver(height: f64) -> PolyMesh {
    let nodes = vec![
        [0.0, 0.0, 0.0],          // a
        [1.0, 0.0, 0.0],          // b
        [0.3, 0.9, 0.0],          // d
        [1.3 / 3.0, 0.3, height], // c, above the centroid
        [0.43, 0.3, 0.8],         // T
        [0.43, 0.3, -0.8],        // B
    ];
    let (a, b, d, c, t, bottom) = (0, 1, 2, 3, 4, 5);
    let cells = [[a, b, d, c], [a, b, c, t], [b, d, c, t], [d, a, c, t], [a, b, d, bottom]].map(Cell::Tet);
    let mut mesh = PolyMesh::from_cells(nodes, &cells).unwrap();
    mesh.orient().unwrap();
    mesh
}

#[test]
fn a_sliver_with_one_face_below_is_merged_into_the_element_below() {
    let mut mesh = double_pyramid_with_sliver(0.005);
    assert!(mesh.element_quality(0) < MIN_QUALITY, "the setup makes a sliver");
    let v0 = mesh.total_volume();
    let report = merge_slivers(&mut mesh, MIN_QUALITY).unwrap();
    assert_eq!((report.merged, report.new_nodes), (1, 0), "{report:?}");
    assert!(report.left.is_empty());
    assert_eq!(mesh.elements.len(), 4);
    // the element below took the three faces above: it holds the node now
    let counts: Vec<usize> = mesh.elements.iter().map(|el| el.nodes.len()).collect();
    assert_eq!(counts.iter().filter(|&&k| k == 5).count(), 1, "{counts:?}");
    // the corners moved straight up or down (the least-squares plane of
    // a, b, d and c above their centroid is level), which keeps the volume
    // of the double pyramid
    assert!((mesh.total_volume() - v0).abs() <= 1e-12 * v0, "{} -> {}", v0, mesh.total_volume());
    mesh.validate().unwrap();
    assert!(worst_quality(&mesh) >= MIN_QUALITY);
    let (error, interior) = common::patch_error(mesh, BasisOptions::default());
    assert_eq!(interior, 1);
    assert!(error < 1e-9, "patch test error {error:e}");
}

#[test]
fn the_bunny_slivers_are_merged_into_a_valid_mesh() {
    let mut mesh = cleave::io::read_mesh(std::path::Path::new("assets/bunny_5k.mesh")).unwrap();
    let before: usize = (0..mesh.elements.len()).filter(|&e| mesh.element_quality(e) < MIN_QUALITY).count();
    let worst = worst_quality(&mesh);
    let report = merge_slivers(&mut mesh, MIN_QUALITY).unwrap();
    println!("{before} slivers: {} merged ({} new nodes), {} left", report.merged, report.new_nodes, report.left.len());
    assert!(report.merged > before / 2, "{report:?}");
    mesh.validate().unwrap();
    let after = (0..mesh.elements.len()).filter(|&e| mesh.element_quality(e) < MIN_QUALITY).count();
    assert_eq!(after, report.left.len(), "every sliver left is reported");
    assert!(worst_quality(&mesh) >= worst, "the worst element got worse");
    let (error, _) = common::patch_error(mesh, BasisOptions::default());
    assert!(error < 1e-9, "patch test error {error:e}");
}
