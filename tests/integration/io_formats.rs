//! Round trips through every format, the shipped bunny in two formats, and
//! malformed files that must end in errors naming file and line.

use std::path::Path;

use cleave::io::{
    read_gmsh, read_medit, read_mesh, read_obj_surface, read_tetgen, read_vtu, write_boundary_obj, write_gmsh,
    write_medit, write_tetgen, write_vtu, IoError, VtuFields,
};
use cleave::mesh::{Cell, PolyMesh};
use cleave::meshing::{box_hex, random_convex};

fn assets() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/assets"))
}

/// A small irregular tet + hex test set as cells.
fn tet_cells() -> (Vec<[f64; 3]>, Vec<Cell>) {
    let nodes =
        vec![[0.0, 0.0, 0.0], [1.0, 0.1, 0.0], [0.2, 1.0, 0.1], [0.1, 0.2, 1.3], [1.1, 1.2, 0.9], [0.3, -0.1, -1.0]];
    (nodes, vec![Cell::Tet([0, 1, 2, 3]), Cell::Tet([1, 2, 3, 4]), Cell::Tet([0, 2, 1, 5])])
}

fn hex_cells() -> (Vec<[f64; 3]>, Vec<Cell>) {
    let m = box_hex([0.0; 3], [2.0, 1.0, 1.0], [2, 1, 1]).unwrap();
    let nodes = m.nodes.clone();
    let cells = vec![Cell::Hex([0, 1, 4, 3, 6, 7, 10, 9]), Cell::Hex([1, 2, 5, 4, 7, 8, 11, 10])];
    (nodes, cells)
}

fn same_mesh(a: &PolyMesh, b: &PolyMesh) {
    assert_eq!(a.nodes.len(), b.nodes.len());
    for (p, q) in a.nodes.iter().zip(&b.nodes) {
        for i in 0..3 {
            assert!((p[i] - q[i]).abs() <= 1e-15 * p[i].abs().max(1.0), "{p:?} vs {q:?}");
        }
    }
    assert_eq!(a.elements.len(), b.elements.len());
    for e in 0..a.elements.len() {
        assert_eq!(a.elements[e].nodes, b.elements[e].nodes);
        assert!((a.element_volume(e) - b.element_volume(e)).abs() < 1e-14);
    }
    assert_eq!(a.faces.len(), b.faces.len());
}

#[test]
fn medit_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    for (nodes, cells) in [tet_cells(), hex_cells()] {
        let want = PolyMesh::from_cells(nodes.clone(), &cells).unwrap();
        let p = dir.path().join("m.mesh");
        write_medit(&p, &nodes, &cells).unwrap();
        same_mesh(&want, &read_medit(&p).unwrap());
    }
}

#[test]
fn gmsh_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    for (nodes, cells) in [tet_cells(), hex_cells()] {
        let want = PolyMesh::from_cells(nodes.clone(), &cells).unwrap();
        let p = dir.path().join("m.msh");
        write_gmsh(&p, &nodes, &cells).unwrap();
        same_mesh(&want, &read_gmsh(&p).unwrap());
    }
}

#[test]
fn tetgen_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let (nodes, cells) = tet_cells();
    let want = PolyMesh::from_cells(nodes.clone(), &cells).unwrap();
    write_tetgen(&dir.path().join("m.node"), &nodes, &cells).unwrap();
    same_mesh(&want, &read_tetgen(&dir.path().join("m.ele")).unwrap());
    same_mesh(&want, &read_mesh(&dir.path().join("m.node")).unwrap());
}

#[test]
fn vtu_round_trip_with_polyhedra() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = random_convex([0.0; 3], [1.0; 3], 6, 3).unwrap();
    let p = dir.path().join("m.vtu");
    let u: Vec<[f64; 3]> = mesh.nodes.iter().map(|x| [0.1 * x[0], 0.0, -x[2]]).collect();
    write_vtu(&p, &mesh, &mesh.nodes, &VtuFields { point_vectors: vec![("displacement", &u)], ..Default::default() })
        .unwrap();
    let back = read_vtu(&p).unwrap();
    back.validate().unwrap();
    assert_eq!(back.elements.len(), mesh.elements.len());
    assert_eq!(back.nodes, mesh.nodes);
    for e in 0..mesh.elements.len() {
        assert_eq!(back.elements[e].nodes, mesh.elements[e].nodes);
        assert!((back.element_volume(e) - mesh.element_volume(e)).abs() < 1e-14);
    }
    // tets and hexes
    let (nodes, cells) = tet_cells();
    let tets = PolyMesh::from_cells(nodes, &cells).unwrap();
    write_vtu(&p, &tets, &tets.nodes, &VtuFields::default()).unwrap();
    same_mesh(&tets, &read_vtu(&p).unwrap());
}

#[test]
fn obj_boundary_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = box_hex([0.0; 3], [1.0; 3], [2, 2, 2]).unwrap();
    let p = dir.path().join("s.obj");
    write_boundary_obj(&p, &mesh, &mesh.nodes).unwrap();
    let s = read_obj_surface(&p).unwrap();
    assert_eq!(s.triangles.len(), 6 * 4 * 2);
    // enclosed volume by the divergence theorem = 1, so the winding is outward
    let vol: f64 = s
        .triangles
        .iter()
        .map(|t| {
            cleave_kernels::tet::signed_volume(
                [0.0; 3],
                s.vertices[t[0] as usize],
                s.vertices[t[1] as usize],
                s.vertices[t[2] as usize],
            )
        })
        .sum();
    assert!((vol - 1.0).abs() < 1e-12, "{vol}");
}

#[test]
fn shipped_bunny_reads_the_same_from_medit_and_gmsh() {
    let a = read_mesh(&assets().join("bunny_5k.mesh")).unwrap();
    let b = read_mesh(&assets().join("bunny_5k.msh")).unwrap();
    assert_eq!(a.elements.len(), 6916);
    assert_eq!(a.nodes.len(), 2144);
    same_mesh(&a, &b);
    a.validate().unwrap();
    // the data README: the tet volumes sum to the OBJ volume 194.28837
    assert!((a.total_volume() - 194.28837).abs() < 1e-4, "{}", a.total_volume());
}

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn parse_error(r: Result<PolyMesh, IoError>) -> (usize, String) {
    match r {
        Err(IoError::Parse { line, message, .. }) => (line, message),
        other => panic!("expected a parse error, got {other:?}"),
    }
}

const GOOD_MEDIT: &str = "MeshVersionFormatted 2\nDimension 3\nVertices\n4\n0 0 0 1\n1 0 0 1\n0 1 0 1\n0 0 1 1\nTetrahedra\n1\n1 2 3 4 1\nEnd\n";

#[test]
fn malformed_medit_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    assert!(read_medit(&write(d, "good.mesh", GOOD_MEDIT)).is_ok());
    // truncated inside the tetrahedra
    let (line, msg) = parse_error(read_medit(&write(d, "t.mesh", &GOOD_MEDIT[..GOOD_MEDIT.len() - 10])));
    assert!(msg.contains("end of file") || msg.contains("expected"), "{msg}");
    assert!(line >= 10);
    // wrong vertex count: the 'Tetrahedra' keyword is read as a coordinate
    let (line, msg) = parse_error(read_medit(&write(d, "c.mesh", &GOOD_MEDIT.replace("Vertices\n4", "Vertices\n5"))));
    assert_eq!(line, 9);
    assert!(msg.contains("Tetrahedra"), "{msg}");
    // NaN coordinate
    let (line, msg) = parse_error(read_medit(&write(d, "n.mesh", &GOOD_MEDIT.replace("1 0 0 1", "nan 0 0 1"))));
    assert_eq!(line, 6);
    assert!(msg.contains("not finite"), "{msg}");
    // index out of range
    let (line, msg) = parse_error(read_medit(&write(d, "i.mesh", &GOOD_MEDIT.replace("1 2 3 4 1", "1 2 3 9 1"))));
    assert_eq!(line, 11);
    assert!(msg.contains("9") && msg.contains("out of range"), "{msg}");
    // unknown keyword
    let (_, msg) = parse_error(read_medit(&write(d, "k.mesh", &GOOD_MEDIT.replace("End", "Bogus 3"))));
    assert!(msg.contains("Bogus"));
    // the error's Display names the file and line
    let e = read_medit(&write(d, "x.mesh", &GOOD_MEDIT.replace("1 2 3 4 1", "1 2 3 9 1"))).unwrap_err().to_string();
    assert!(e.contains("x.mesh:11:"), "{e}");
}

#[test]
fn malformed_tetgen_gmsh_vtu_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write(d, "a.node", "4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n");
    write(d, "a.ele", "1 4 0\n1 1 2 3 5\n");
    let (line, msg) = parse_error(read_tetgen(&d.join("a.ele")));
    assert_eq!(line, 2);
    assert!(msg.contains("out of range"), "{msg}");
    let gm = write(d, "g.msh", "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 2 1 2\n3 1 0 2\n1\n");
    assert!(matches!(read_gmsh(&gm), Err(IoError::Parse { .. })));
    let vtu = write(d, "v.vtu", "<VTKFile type=\"UnstructuredGrid\"><UnstructuredGrid><Piece><Points><DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">0 0 0 1 0 0 0 1 0 0 0 1</DataArray></Points><Cells><DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">0 1 2 7</DataArray><DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">4</DataArray><DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">10</DataArray></Cells></Piece></UnstructuredGrid></VTKFile>");
    let (_, msg) = parse_error(read_vtu(&vtu));
    assert!(msg.contains("point 7"), "{msg}");
    // a polyhedron cell without its faceoffsets entry
    let poly = write(d, "p.vtu", "<VTKFile type=\"UnstructuredGrid\"><UnstructuredGrid><Piece><Points><DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">0 0 0 1 0 0 0 1 0 0 0 1</DataArray></Points><Cells><DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">0 1 2 3</DataArray><DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">4</DataArray><DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">42</DataArray><DataArray type=\"Int64\" Name=\"faces\" format=\"ascii\">4 3 0 2 1</DataArray><DataArray type=\"Int64\" Name=\"faceoffsets\" format=\"ascii\"></DataArray></Cells></Piece></UnstructuredGrid></VTKFile>");
    let (_, msg) = parse_error(read_vtu(&poly));
    assert!(msg.contains("faceoffsets"), "{msg}");
    assert!(matches!(read_mesh(&d.join("missing.mesh")), Err(IoError::Os { .. })));
    assert!(matches!(read_mesh(&d.join("surface.obj")), Err(IoError::Unsupported { .. })));
}

/// Truncated and corrupted files of every format (Medit, gmsh, TetGen's
/// `.node` and `.ele`, VTU with tetrahedra and polyhedra, OBJ surfaces) end
/// in an error, never a panic; a corruption that still reads (a digit
/// changed in a coordinate) is counted and reported, and what it reads is a
/// mesh of finite nodes.
#[test]
fn damaged_files_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (nodes, cells) = tet_cells();
    let mesh = PolyMesh::from_cells(nodes.clone(), &cells).unwrap();
    let poly = random_convex([0.0; 3], [1.0; 3], 3, 1).unwrap();
    write_medit(&d.join("m.mesh"), &nodes, &cells).unwrap();
    write_gmsh(&d.join("m.msh"), &nodes, &cells).unwrap();
    write_tetgen(&d.join("t.node"), &nodes, &cells).unwrap();
    write_vtu(&d.join("m.vtu"), &mesh, &mesh.nodes, &VtuFields::default()).unwrap();
    write_vtu(&d.join("p.vtu"), &poly, &poly.nodes, &VtuFields::default()).unwrap();
    write_boundary_obj(&d.join("s.obj"), &poly, &poly.nodes).unwrap();
    let read = |p: &Path| -> Result<usize, String> {
        let nodes = if p.extension().is_some_and(|e| e == "obj") {
            read_obj_surface(p).map_err(|e| e.to_string())?.vertices
        } else {
            read_mesh(p).map_err(|e| e.to_string())?.nodes
        };
        assert!(nodes.iter().flatten().all(|x| x.is_finite()), "{}: a non-finite node read as valid", p.display());
        Ok(nodes.len())
    };
    let mut seed = 12345u64;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    // (the file to damage, the file to read: a TetGen pair is read by either)
    let cases = [
        ("m.mesh", "m.mesh"),
        ("m.msh", "m.msh"),
        ("t.node", "t.ele"),
        ("t.ele", "t.node"),
        ("m.vtu", "m.vtu"),
        ("p.vtu", "p.vtu"),
        ("s.obj", "s.obj"),
    ];
    let mut report = Vec::new();
    for (damage, read_as) in cases {
        let original = std::fs::read(d.join(damage)).unwrap();
        let (mut errors, mut readable) = (0, 0);
        for k in 0..60 {
            let mut damaged = original.clone();
            if k % 2 == 0 {
                damaged.truncate((next() as usize) % original.len());
            } else {
                for _ in 0..3 {
                    let i = (next() as usize) % damaged.len();
                    damaged[i] = b"0123456789 .-eE\nx#"[(next() as usize) % 18];
                }
            }
            std::fs::write(d.join(damage), &damaged).unwrap();
            match read(&d.join(read_as)) {
                Ok(_) => readable += 1,
                Err(_) => errors += 1,
            }
        }
        std::fs::write(d.join(damage), &original).unwrap();
        assert!(errors > 0, "{damage}: no damage was noticed");
        report.push(format!("{damage}: {errors} errors, {readable} still read"));
    }
    println!("60 damaged versions of each file: {report:?}");
}

/// A count in a header that the file's data does not back (10^11 or 10^18
/// vertices or cells) ends in an error naming the file, before anything
/// that size is allocated.
#[test]
fn huge_counts_in_headers_are_errors_not_aborts() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let medit = "MeshVersionFormatted 2\nDimension 3\nVertices\n99999999999\n0 0 0 1\n1 0 0 1\nEnd\n";
    std::fs::write(d.join("h.mesh"), medit).unwrap();
    let medit_cells = "MeshVersionFormatted 2\nDimension 3\nVertices\n4\n0 0 0 1\n1 0 0 1\n0 1 0 1\n0 0 1 1\nTetrahedra\n1000000000000000000\n1 2 3 4 1\nEnd\n";
    std::fs::write(d.join("c.mesh"), medit_cells).unwrap();
    std::fs::write(d.join("h.node"), "1000000000000000000 3 0 0\n1 0 0 0\n").unwrap();
    std::fs::write(d.join("h.ele"), "1 4 0\n1 1 2 3 4\n").unwrap();
    std::fs::write(d.join("e.node"), "4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n").unwrap();
    std::fs::write(d.join("e.ele"), "1000000000000000000 4 0\n1 1 2 3 4\n").unwrap();
    for name in ["h.mesh", "c.mesh", "h.node", "e.ele"] {
        let err = read_mesh(&d.join(name)).unwrap_err().to_string();
        println!("{name}: {err}");
        let file = if name.starts_with('h') && name.ends_with("node") { "h.node" } else { name };
        assert!(err.contains(file), "names the file: {err}");
    }
}
