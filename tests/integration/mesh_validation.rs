//! Every validation error, triggered by a small hand-made bad mesh, with the
//! place it names.

use cleave::mesh::{Cell, Element, Face, FaceRef, MeshError, PolyMesh};
use cleave::meshing::box_hex;

fn tet_nodes() -> Vec<[f64; 3]> {
    vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
}

fn unit_tet() -> PolyMesh {
    PolyMesh::from_cells(tet_nodes(), &[Cell::Tet([0, 1, 2, 3])]).unwrap()
}

fn message(r: Result<impl std::fmt::Debug, MeshError>) -> (MeshError, String) {
    let e = r.expect_err("must fail");
    let m = e.to_string();
    (e, m)
}

#[test]
fn empty_mesh() {
    let (e, m) = message(PolyMesh::default().validate());
    assert_eq!(e, MeshError::Empty);
    assert!(m.contains("no elements"));
}

#[test]
fn non_finite_coordinate() {
    let mut nodes = tet_nodes();
    nodes[2][1] = f64::NAN;
    let (e, m) = message(PolyMesh::from_cells(nodes, &[Cell::Tet([0, 1, 2, 3])]));
    assert!(matches!(e, MeshError::NonFiniteNode { node: 2, .. }));
    assert!(m.contains("node 2") && m.contains("non-finite"));
    let mut mesh = unit_tet();
    mesh.nodes[3][0] = f64::INFINITY;
    assert!(matches!(mesh.validate(), Err(MeshError::NonFiniteNode { node: 3, .. })));
}

#[test]
fn index_out_of_range() {
    let (e, m) = message(PolyMesh::from_cells(tet_nodes(), &[Cell::Tet([0, 1, 2, 7])]));
    assert_eq!(e, MeshError::NodeIndexOutOfRange { element: 0, index: 7, nodes: 4 });
    assert!(m.contains("element 0") && m.contains("node 7"));
    let mut mesh = unit_tet();
    mesh.elements[0].faces[0].face = 99;
    assert!(matches!(mesh.validate(), Err(MeshError::FaceIndexOutOfRange { element: 0, index: 99, .. })));
}

#[test]
fn face_with_fewer_than_three_distinct_vertices() {
    let cell = Cell::Polyhedron(vec![vec![0, 2, 1], vec![0, 1, 3], vec![1, 2, 3], vec![0, 3, 3]]);
    let (e, m) = message(PolyMesh::from_cells(tet_nodes(), &[cell]));
    assert!(matches!(e, MeshError::DegenerateFace { element: 0, .. }));
    assert!(m.contains("fewer than 3 distinct"));
}

#[test]
fn zero_area_face() {
    let mut mesh = unit_tet();
    mesh.nodes[2] = [0.5, 0.0, 0.0]; // face (0, 2, 1) collapses onto a line
    let (e, _) = message(mesh.validate());
    assert!(matches!(e, MeshError::ZeroAreaFace { .. }), "{e}");
}

#[test]
fn non_planar_face() {
    let mut mesh = box_hex([0.0; 3], [1.0; 3], [1, 1, 1]).unwrap();
    mesh.nodes[6][2] += 0.1; // lift one top corner
    let (e, m) = message(mesh.validate());
    assert!(matches!(e, MeshError::NonPlanarFace { .. }), "{e}");
    assert!(m.contains("not planar") && m.contains("face"));
}

#[test]
fn open_element() {
    let mut mesh = unit_tet();
    mesh.elements[0].faces.pop();
    let (e, m) = message(mesh.validate());
    assert!(matches!(e, MeshError::OpenElement { element: 0, count: 1, .. }), "{e}");
    assert!(m.contains("not closed"));
    let (e, _) = message(mesh.orient());
    assert!(matches!(e, MeshError::OpenElement { .. }));
}

#[test]
fn inconsistent_orientation_is_reported_and_fixed_by_orient() {
    let mut mesh = unit_tet();
    mesh.elements[0].faces[1].outward = !mesh.elements[0].faces[1].outward;
    let (e, m) = message(mesh.validate());
    assert!(matches!(e, MeshError::InconsistentOrientation { element: 0, .. }), "{e}");
    assert!(m.contains("orient"));
    mesh.orient().unwrap();
    mesh.validate().unwrap();
    assert!((mesh.element_volume(0) - 1.0 / 6.0).abs() < 1e-15);
}

#[test]
fn inward_element_is_reported_and_fixed_by_orient() {
    let mut mesh = unit_tet();
    for r in &mut mesh.elements[0].faces {
        r.outward = !r.outward;
    }
    let (e, _) = message(mesh.validate());
    assert_eq!(e, MeshError::InwardElement { element: 0 });
    mesh.orient().unwrap();
    mesh.validate().unwrap();
}

#[test]
fn zero_volume_element() {
    let faces = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];
    let nodes = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
    let mesh = PolyMesh {
        nodes,
        faces: faces.iter().map(|f| Face { vertices: f[..].into(), triangles: [*f][..].into() }).collect(),
        elements: vec![Element {
            faces: (0..4).map(|f| FaceRef { face: f, outward: true }).collect(),
            nodes: [0, 1, 2, 3][..].into(),
        }],
    };
    let (e, m) = message(mesh.validate());
    assert!(matches!(e, MeshError::NonPositiveVolume { element: 0, .. } | MeshError::ZeroAreaFace { .. }), "{e}");
    assert!(m.contains("volume") || m.contains("zero area"));
    assert!(mesh.clone().orient().is_err());
}

#[test]
fn duplicate_nodes_are_reported_and_welded() {
    let mut nodes = tet_nodes();
    nodes.push([1.0, 0.0, 1e-13]);
    let mut mesh = PolyMesh::from_cells(nodes, &[Cell::Tet([0, 1, 2, 3])]).unwrap();
    let (e, m) = message(mesh.validate());
    assert!(matches!(e, MeshError::DuplicateNodes { a: 1, b: 4, .. }), "{e}");
    assert!(m.contains("weld"));
    mesh.weld(1e-9).unwrap();
    mesh.validate().unwrap();
    assert_eq!(mesh.nodes.len(), 4);
}

#[test]
fn face_shared_by_three_elements() {
    let mut nodes = tet_nodes();
    nodes.push([1.0, 1.0, 1.0]);
    nodes.push([-1.0, -1.0, -1.0]);
    let cells = [Cell::Tet([0, 1, 2, 3]), Cell::Tet([1, 2, 3, 4]), Cell::Tet([1, 2, 3, 5])];
    let (e, m) = message(PolyMesh::from_cells(nodes, &cells));
    assert!(matches!(e, MeshError::FaceSharedByMoreThanTwo { element: 2, .. }), "{e}");
    assert!(m.contains("more than two"));
}

#[test]
fn overlapping_elements() {
    let (e, m) = message(PolyMesh::from_cells(tet_nodes(), &[Cell::Tet([0, 1, 2, 3]), Cell::Tet([0, 1, 2, 3])]));
    assert!(matches!(e, MeshError::OverlappingElements { a: 0, b: 1, .. }), "{e}");
    assert!(m.contains("overlap"));
}

/// A local check of several elements (after a cut, in parallel) names the
/// first bad one in the order it was given, whatever the thread count.
#[test]
fn checking_listed_elements_names_the_first_bad_one_in_their_order() {
    let mut mesh = box_hex([0.0; 3], [1.0; 3], [4, 4, 4]).unwrap();
    let faces = mesh.faces.len() as u32;
    for e in [9, 41] {
        mesh.elements[e].faces[0].face = faces + e as u32;
    }
    let listed: Vec<usize> = (0..mesh.elements.len()).rev().collect();
    for threads in [1, 2, 4] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let checked = pool.install(|| mesh.check_elements(&listed, &Default::default()));
        let (e, m) = message(checked);
        assert_eq!(
            e,
            MeshError::FaceIndexOutOfRange { element: 41, index: (faces + 41) as usize, faces: faces as usize }
        );
        assert!(m.contains("41"), "{m}");
        let good: Vec<usize> = (0..mesh.elements.len()).filter(|&e| e != 9 && e != 41).collect();
        assert!(pool.install(|| mesh.check_elements(&good, &Default::default())).is_ok());
    }
}
