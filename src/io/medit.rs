//! INRIA Medit `.mesh` ASCII: `Vertices`, `Tetrahedra`, `Hexahedra` (other
//! sections of known size are skipped).

use std::fmt::Write;
use std::path::Path;

use super::tokens::Tokens;
use super::{read_text, write_text, IoError};
use crate::mesh::{Cell, PolyMesh};

/// Reads a Medit mesh of tetrahedra and/or hexahedra.
pub fn read_medit(path: &Path) -> Result<PolyMesh, IoError> {
    let text = read_text(path)?;
    let mut t = Tokens::new(path, &text);
    let mut nodes: Vec<[f64; 3]> = Vec::new();
    let mut cells: Vec<Cell> = Vec::new();
    let mut dim = 3usize;
    while let Some(kw) = t.peek() {
        let line = t.line();
        t.next("keyword")?;
        match kw.to_ascii_lowercase().as_str() {
            "meshversionformatted" => {
                t.usize("version")?;
            }
            "dimension" => {
                dim = t.usize("dimension")?;
                if dim != 3 {
                    return Err(IoError::parse(path, line, format!("dimension {dim} is not supported (expected 3)")));
                }
            }
            "vertices" => {
                let n = t.usize("vertex count")?;
                nodes.reserve(t.capacity(n, 4));
                for _ in 0..n {
                    let p = [t.f64("x")?, t.f64("y")?, t.f64("z")?];
                    t.f64("vertex reference")?;
                    nodes.push(p);
                }
            }
            "tetrahedra" => {
                let n = t.usize("tetrahedron count")?;
                for _ in 0..n {
                    let mut v = [0u32; 4];
                    for x in v.iter_mut() {
                        *x = t.index("tetrahedron vertex", 1, nodes.len())?;
                    }
                    t.f64("tetrahedron reference")?;
                    cells.push(Cell::Tet(v));
                }
            }
            "hexahedra" => {
                let n = t.usize("hexahedron count")?;
                for _ in 0..n {
                    let mut v = [0u32; 8];
                    for x in v.iter_mut() {
                        *x = t.index("hexahedron vertex", 1, nodes.len())?;
                    }
                    t.f64("hexahedron reference")?;
                    cells.push(Cell::Hex(v));
                }
            }
            "end" => break,
            other => {
                let per = match other {
                    "edges" => 3,
                    "triangles" => 4,
                    "quadrilaterals" => 5,
                    "prisms" => 7,
                    "corners" | "ridges" | "requiredvertices" | "requirededges" | "requiredtriangles" => 1,
                    "normals" | "tangents" => dim,
                    "normalatvertices" | "tangentatvertices" | "tangentatedges" => 2,
                    _ => return Err(IoError::parse(path, line, format!("unknown Medit keyword '{kw}'"))),
                };
                let n = t.usize(&format!("{kw} count"))?;
                for _ in 0..n * per {
                    t.f64(&format!("{kw} entry"))?;
                }
            }
        }
    }
    if cells.is_empty() {
        return Err(IoError::unsupported(path, "no Tetrahedra or Hexahedra section: not a volume mesh"));
    }
    PolyMesh::from_cells(nodes, &cells).map_err(|e| IoError::mesh(path, e))
}

/// Writes the tetrahedra and hexahedra given as cells (other cells are not
/// representable in Medit and are rejected).
pub fn write_medit(path: &Path, nodes: &[[f64; 3]], cells: &[Cell]) -> Result<(), IoError> {
    let mut s = String::from("MeshVersionFormatted 2\nDimension 3\nVertices\n");
    let _ = writeln!(s, "{}", nodes.len());
    for p in nodes {
        let _ = writeln!(s, "{:e} {:e} {:e} 1", p[0], p[1], p[2]);
    }
    let tets: Vec<_> = cells.iter().filter_map(|c| if let Cell::Tet(t) = c { Some(t) } else { None }).collect();
    let hexes: Vec<_> = cells.iter().filter_map(|c| if let Cell::Hex(h) = c { Some(h) } else { None }).collect();
    if tets.len() + hexes.len() != cells.len() {
        return Err(IoError::unsupported(path, "Medit stores only tetrahedra and hexahedra"));
    }
    if !tets.is_empty() {
        let _ = writeln!(s, "Tetrahedra\n{}", tets.len());
        for t in tets {
            let _ = writeln!(s, "{} {} {} {} 1", t[0] + 1, t[1] + 1, t[2] + 1, t[3] + 1);
        }
    }
    if !hexes.is_empty() {
        let _ = writeln!(s, "Hexahedra\n{}", hexes.len());
        for h in hexes {
            let v: Vec<String> = h.iter().map(|i| (i + 1).to_string()).collect();
            let _ = writeln!(s, "{} 1", v.join(" "));
        }
    }
    s.push_str("End\n");
    write_text(path, &s)
}
