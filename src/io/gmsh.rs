//! gmsh `.msh` 4.1 ASCII: tetrahedra (type 4) and hexahedra (type 5).
//! Reading goes through the `mshio` crate; lower-dimensional elements
//! (boundary triangles, lines, points) are skipped.

use std::collections::HashMap;
use std::fmt::Write;
use std::path::Path;

use super::{write_text, IoError};
use crate::mesh::{Cell, PolyMesh};

/// Reads the volume elements of a gmsh 4.1 mesh.
pub fn read_gmsh(path: &Path) -> Result<PolyMesh, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::os(path, e))?;
    let msh = mshio::parse_msh_bytes(&bytes).map_err(|e| {
        let msg = e.to_string();
        let line = first_line_number(&msg).unwrap_or(1);
        IoError::parse(path, line, format!("not a valid gmsh 4.1 file: {}", msg.lines().next().unwrap_or("")))
    })?;
    let Some(node_sec) = msh.data.nodes else {
        return Err(IoError::unsupported(path, "no $Nodes section"));
    };
    let Some(elem_sec) = msh.data.elements else {
        return Err(IoError::unsupported(path, "no $Elements section"));
    };
    // node tag -> index
    let mut nodes: Vec<[f64; 3]> = Vec::new();
    let mut tag_of: HashMap<u64, u32> = HashMap::new();
    let dense = node_sec.node_blocks.iter().all(|b| b.node_tags.is_none());
    for block in &node_sec.node_blocks {
        let start = nodes.len();
        for (i, nd) in block.nodes.iter().enumerate() {
            let p = [nd.x, nd.y, nd.z];
            if !p.iter().all(|x| x.is_finite()) {
                return Err(IoError::unsupported(path, format!("node {} has a non-finite coordinate", start + i + 1)));
            }
            nodes.push(p);
        }
        if let Some(tags) = &block.node_tags {
            for (&tag, &local) in tags {
                tag_of.insert(tag, (start + local) as u32);
            }
        }
    }
    let min_tag = node_sec.min_node_tag;
    let index = |tag: u64| -> Option<u32> {
        if dense {
            tag.checked_sub(min_tag).filter(|&i| (i as usize) < nodes.len()).map(|i| i as u32)
        } else {
            tag_of.get(&tag).copied()
        }
    };
    let mut cells = Vec::new();
    for block in &elem_sec.element_blocks {
        let kind = block.element_type as i32;
        for el in &block.elements {
            let mut ids = Vec::with_capacity(el.nodes.len());
            for &tag in &el.nodes {
                ids.push(index(tag).ok_or_else(|| {
                    IoError::unsupported(
                        path,
                        format!("element {} refers to node tag {tag}, which does not exist", el.element_tag),
                    )
                })?);
            }
            match kind {
                4 => cells.push(Cell::Tet([ids[0], ids[1], ids[2], ids[3]])),
                5 => cells.push(Cell::Hex(std::array::from_fn(|i| ids[i]))),
                // points, lines, triangles, quadrangles: boundary entities
                15 | 1 | 2 | 3 | 8 | 9 | 16 | 26 | 21 => {}
                other => {
                    return Err(IoError::unsupported(
                        path,
                        format!("gmsh element type {other} is not supported (linear tetrahedra 4 and hexahedra 5 are)"),
                    ))
                }
            }
        }
    }
    if cells.is_empty() {
        return Err(IoError::unsupported(path, "no tetrahedra or hexahedra: not a volume mesh"));
    }
    PolyMesh::from_cells(nodes, &cells).map_err(|e| IoError::mesh(path, e))
}

fn first_line_number(msg: &str) -> Option<usize> {
    let i = msg.find("line ")?;
    msg[i + 5..].split(|c: char| !c.is_ascii_digit()).next()?.parse().ok()
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
