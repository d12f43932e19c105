//! TetGen `.node` / `.ele` pairs (linear tetrahedra).

use std::fmt::Write;
use std::path::{Path, PathBuf};

use super::tokens::Tokens;
use super::{read_text, write_text, IoError};
use crate::mesh::{Cell, PolyMesh};

/// Reads `stem.node` and `stem.ele`, given either path. Indices may start at
/// 0 or 1 (TetGen's `-z`); the first node's number decides.
pub fn read_tetgen(path: &Path) -> Result<PolyMesh, IoError> {
    let node_path = path.with_extension("node");
    let ele_path = path.with_extension("ele");
    let node_text = read_text(&node_path)?;
    let mut t = Tokens::new(&node_path, &node_text);
    let n = t.usize("node count")?;
    let dim = t.usize("dimension")?;
    if dim != 3 {
        return Err(t.error(format!("dimension {dim} is not supported (expected 3)")));
    }
    let attrs = t.usize("attribute count")?;
    let markers = t.usize("boundary marker flag")?;
    let mut nodes = Vec::with_capacity(t.capacity(n, 4));
    let mut base = 0;
    for i in 0..n {
        let id = t.usize("node number")?;
        if i == 0 {
            base = id;
        }
        if id != base + i {
            return Err(t.error(format!("node number {id} out of sequence (expected {})", base + i)));
        }
        nodes.push([t.f64("x")?, t.f64("y")?, t.f64("z")?]);
        for _ in 0..attrs + markers.min(1) {
            t.f64("node attribute")?;
        }
    }
    let ele_text = read_text(&ele_path)?;
    let mut t = Tokens::new(&ele_path, &ele_text);
    let m = t.usize("tetrahedron count")?;
    let per = t.usize("nodes per tetrahedron")?;
    if per != 4 && per != 10 {
        return Err(t.error(format!("{per} nodes per tetrahedron is not supported (expected 4 or 10)")));
    }
    let attrs = t.usize("region attribute flag")?;
    let mut cells = Vec::with_capacity(t.capacity(m, 5));
    for _ in 0..m {
        t.usize("tetrahedron number")?;
        let mut v = [0u32; 4];
        for x in v.iter_mut() {
            *x = t.index("tetrahedron vertex", base, nodes.len())?;
        }
        for _ in 4..per {
            t.index("tetrahedron vertex", base, nodes.len())?;
        }
        for _ in 0..attrs {
            t.f64("region attribute")?;
        }
        cells.push(Cell::Tet(v));
    }
    PolyMesh::from_cells(nodes, &cells).map_err(|e| IoError::mesh(&ele_path, e))
}

/// Writes `stem.node` and `stem.ele` (1-based) for tetrahedral cells.
pub fn write_tetgen(path: &Path, nodes: &[[f64; 3]], cells: &[Cell]) -> Result<(), IoError> {
    let stem: PathBuf = path.with_extension("");
    let mut s = String::new();
    let _ = writeln!(s, "{} 3 0 0", nodes.len());
    for (i, p) in nodes.iter().enumerate() {
        let _ = writeln!(s, "{} {:e} {:e} {:e}", i + 1, p[0], p[1], p[2]);
    }
    write_text(&stem.with_extension("node"), &s)?;
    let mut s = String::new();
    let _ = writeln!(s, "{} 4 0", cells.len());
    for (i, c) in cells.iter().enumerate() {
        let Cell::Tet(t) = c else {
            return Err(IoError::unsupported(path, "TetGen .ele stores only tetrahedra"));
        };
        let _ = writeln!(s, "{} {} {} {} {}", i + 1, t[0] + 1, t[1] + 1, t[2] + 1, t[3] + 1);
    }
    write_text(&stem.with_extension("ele"), &s)
}
