//! gmsh `.msh` 4.1 ASCII: tetrahedra (type 4) and hexahedra (type 5);
//! lower-dimensional elements (boundary triangles, lines, points) are
//! skipped, as are sections other than `$MeshFormat`, `$Nodes` and
//! `$Elements`. Read by hand with the line-numbering tokenizer: every
//! error names its line, and no count in the file reserves memory beyond
//! what the rest of the file can hold.

use std::collections::HashMap;
use std::fmt::Write;
use std::path::Path;

use super::tokens::Tokens;
use super::{read_text, write_text, IoError};
use crate::mesh::{Cell, PolyMesh};

/// Nodes per element of the gmsh element types read (volume) or skipped
/// (points, lines, triangles, quadrangles, first and second order).
fn nodes_per_element(kind: usize) -> Option<usize> {
    Some(match kind {
        15 => 1,
        1 => 2,
        2 | 8 => 3,
        3 | 4 | 26 => 4,
        9 => 6,
        5 | 16 => 8,
        21 => 10,
        _ => return None,
    })
}

/// Reads the volume elements of a gmsh 4.1 ASCII mesh.
pub fn read_gmsh(path: &Path) -> Result<PolyMesh, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::os(path, e))?;
    if std::str::from_utf8(&bytes).is_err() {
        return Err(IoError::unsupported(path, "not a text file: binary .msh is not supported (save as ASCII 4.1)"));
    }
    let text = read_text(path)?;
    let mut t = Tokens::new(path, &text);
    let (mut nodes, mut tag_of): (Vec<[f64; 3]>, HashMap<usize, u32>) = (Vec::new(), HashMap::new());
    let (mut cells, mut format_seen, mut elements_seen) = (Vec::new(), false, false);
    while let Some(section) = t.peek() {
        t.next("a section")?;
        match section {
            "$MeshFormat" => {
                let line = t.line();
                let version = t.next("the format version")?;
                let binary = t.usize("the file type")?;
                t.usize("the data size")?;
                if !version.starts_with("4.") {
                    return Err(IoError::parse(path, line, format!("gmsh format {version} is not supported (4.1 is)")));
                }
                if binary != 0 {
                    return Err(IoError::parse(path, line, "binary .msh is not supported (save as ASCII 4.1)"));
                }
                expect(&mut t, "$EndMeshFormat")?;
                format_seen = true;
            }
            "$Nodes" if format_seen => {
                read_nodes(&mut t, &mut nodes, &mut tag_of)?;
                expect(&mut t, "$EndNodes")?;
            }
            "$Elements" if format_seen => {
                read_elements(&mut t, &tag_of, &mut cells)?;
                expect(&mut t, "$EndElements")?;
                elements_seen = true;
            }
            other if other.starts_with('$') && !other.starts_with("$End") && format_seen => {
                let end = format!("$End{}", &other[1..]);
                while t.next(&end)? != end {}
            }
            other => {
                let expected = if format_seen { "a section ($Nodes, $Elements, ...)" } else { "$MeshFormat first" };
                return Err(t.error(format!("expected {expected}, found '{other}'")));
            }
        }
    }
    if !format_seen {
        return Err(IoError::unsupported(path, "no $MeshFormat section: not a gmsh file"));
    }
    if !elements_seen || cells.is_empty() {
        return Err(IoError::unsupported(path, "no tetrahedra or hexahedra: not a volume mesh"));
    }
    PolyMesh::from_cells(nodes, &cells).map_err(|e| IoError::mesh(path, e))
}

/// The next token must be `end`.
fn expect(t: &mut Tokens, end: &str) -> Result<(), IoError> {
    let found = t.next(end)?;
    if found != end {
        return Err(t.error(format!("expected {end}, found '{found}'")));
    }
    Ok(())
}

/// `$Nodes`: blocks of tags, then coordinates.
fn read_nodes(t: &mut Tokens, nodes: &mut Vec<[f64; 3]>, tag_of: &mut HashMap<usize, u32>) -> Result<(), IoError> {
    let blocks = t.usize("the number of node blocks")?;
    let total = t.usize("the number of nodes")?;
    t.usize("the smallest node tag")?;
    t.usize("the largest node tag")?;
    nodes.reserve(t.capacity(total, 4));
    for _ in 0..blocks {
        let dim = t.usize("the entity dimension")?;
        t.usize("the entity tag")?;
        let parametric = t.usize("the parametric flag")?;
        let count = t.usize("the number of nodes in the block")?;
        let mut tags = Vec::with_capacity(t.capacity(count, 4));
        for _ in 0..count {
            tags.push(t.usize("a node tag")?);
        }
        for tag in tags {
            let line = t.line();
            let p = [t.f64("x")?, t.f64("y")?, t.f64("z")?];
            for _ in 0..if parametric == 1 { dim } else { 0 } {
                t.f64("a parametric coordinate")?;
            }
            let index = u32::try_from(nodes.len()).map_err(|_| t.error("more than 2^32 nodes"))?;
            if tag_of.insert(tag, index).is_some() {
                return Err(IoError::parse(t.path(), line, format!("node tag {tag} appears twice")));
            }
            nodes.push(p);
        }
    }
    if nodes.len() != total {
        return Err(t.error(format!("{} nodes in the blocks, the header says {total}", nodes.len())));
    }
    Ok(())
}

/// `$Elements`: blocks of one element type each.
fn read_elements(t: &mut Tokens, tag_of: &HashMap<usize, u32>, cells: &mut Vec<Cell>) -> Result<(), IoError> {
    let blocks = t.usize("the number of element blocks")?;
    t.usize("the number of elements")?;
    t.usize("the smallest element tag")?;
    t.usize("the largest element tag")?;
    for _ in 0..blocks {
        t.usize("the entity dimension")?;
        t.usize("the entity tag")?;
        let line = t.line();
        let kind = t.usize("the element type")?;
        let count = t.usize("the number of elements in the block")?;
        let Some(per) = nodes_per_element(kind) else {
            let message =
                format!("gmsh element type {kind} is not supported (linear tetrahedra 4 and hexahedra 5 are)");
            return Err(IoError::parse(t.path(), line, message));
        };
        if matches!(kind, 4 | 5) {
            cells.reserve(t.capacity(count, per + 1));
        }
        let mut ids = [0u32; 8];
        for _ in 0..count {
            let element = t.usize("an element tag")?;
            for id in ids.iter_mut().take(per.min(8)) {
                let line = t.line();
                let tag = t.usize("a node tag")?;
                *id = *tag_of.get(&tag).ok_or_else(|| {
                    let message = format!("element {element} refers to node tag {tag}, which does not exist");
                    IoError::parse(t.path(), line, message)
                })?;
            }
            for _ in 8..per {
                t.usize("a node tag")?;
            }
            match kind {
                4 => cells.push(Cell::Tet([ids[0], ids[1], ids[2], ids[3]])),
                5 => cells.push(Cell::Hex(ids)),
                _ => {}
            }
        }
    }
    Ok(())
}

/// Writes tetrahedra and hexahedra as gmsh 4.1 ASCII (one volume entity).
pub fn write_gmsh(path: &Path, nodes: &[[f64; 3]], cells: &[Cell]) -> Result<(), IoError> {
    let mut s = String::from("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n");
    let n = nodes.len();
    let _ = writeln!(s, "1 {n} 1 {n}\n3 1 0 {n}");
    for i in 1..=n {
        let _ = writeln!(s, "{i}");
    }
    for p in nodes {
        let _ = writeln!(s, "{:e} {:e} {:e}", p[0], p[1], p[2]);
    }
    s.push_str("$EndNodes\n$Elements\n");
    let tets: Vec<_> =
        cells.iter().filter_map(|c| if let Cell::Tet(t) = c { Some(t.to_vec()) } else { None }).collect();
    let hexes: Vec<_> =
        cells.iter().filter_map(|c| if let Cell::Hex(h) = c { Some(h.to_vec()) } else { None }).collect();
    if tets.len() + hexes.len() != cells.len() {
        return Err(IoError::unsupported(path, "gmsh output supports only tetrahedra and hexahedra"));
    }
    let blocks: Vec<(i32, &Vec<Vec<u32>>)> =
        [(4, &tets), (5, &hexes)].into_iter().filter(|(_, v)| !v.is_empty()).collect();
    let _ = writeln!(s, "{} {} 1 {}", blocks.len(), cells.len(), cells.len());
    let mut tag = 1;
    for (kind, list) in blocks {
        let _ = writeln!(s, "3 1 {kind} {}", list.len());
        for c in list {
            let v: Vec<String> = c.iter().map(|i| (i + 1).to_string()).collect();
            let _ = writeln!(s, "{tag} {}", v.join(" "));
            tag += 1;
        }
    }
    s.push_str("$EndElements\n");
    write_text(path, &s)
}
