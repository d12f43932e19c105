//! Wavefront OBJ: triangle surfaces in, boundary surfaces out.

use std::fmt::Write;
use std::path::Path;

use super::{write_text, IoError};
use crate::mesh::PolyMesh;

/// A triangle surface (m), counter-clockwise seen from outside.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Surface {
    /// Vertex positions.
    pub vertices: Vec<[f64; 3]>,
    /// Triangles as 0-based vertex indices.
    pub triangles: Vec<[u32; 3]>,
}

impl Surface {
    /// Axis-aligned bounding box `(min, max)` of the vertices (m).
    pub fn bounding_box(&self) -> ([f64; 3], [f64; 3]) {
        cleave_kernels::vec3::bounding_box(&self.vertices)
    }
}

/// Reads an OBJ surface (polygons are triangulated; groups are merged).
pub fn read_obj_surface(path: &Path) -> Result<Surface, IoError> {
    let opts = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    let (models, _) = tobj::load_obj(path, &opts).map_err(|e| match e {
        tobj::LoadError::OpenFileFailed => {
            IoError::os(path, std::io::Error::new(std::io::ErrorKind::NotFound, "cannot open file"))
        }
        other => IoError::parse(path, 0, format!("not a valid OBJ file: {other}")),
    })?;
    let mut s = Surface::default();
    for m in models {
        let base = s.vertices.len() as u32;
        for p in m.mesh.positions.chunks_exact(3) {
            let v = [p[0], p[1], p[2]];
            if !v.iter().all(|x| x.is_finite()) {
                return Err(IoError::unsupported(
                    path,
                    format!("vertex {} has a non-finite coordinate", s.vertices.len() + 1),
                ));
            }
            s.vertices.push(v);
        }
        for t in m.mesh.indices.chunks_exact(3) {
            s.triangles.push([base + t[0], base + t[1], base + t[2]]);
        }
    }
    if s.triangles.is_empty() {
        return Err(IoError::unsupported(path, "no faces: not a surface"));
    }
    Ok(s)
}

/// Writes the boundary surface of `mesh` (triangulated, outward) at the node
/// positions `positions` (rest positions plus displacement, m).
pub fn write_boundary_obj(path: &Path, mesh: &PolyMesh, positions: &[[f64; 3]]) -> Result<(), IoError> {
    write_surface_obj(path, positions, &mesh.boundary_triangles())
}

/// Writes the triangle surface `triangles` over `vertices` (m).
pub fn write_surface_obj(path: &Path, vertices: &[[f64; 3]], triangles: &[[u32; 3]]) -> Result<(), IoError> {
    let mut s = String::new();
    for p in vertices {
        let _ = writeln!(s, "v {} {} {}", p[0], p[1], p[2]);
    }
    for t in triangles {
        let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    write_text(path, &s)
}
