//! STL triangle surfaces (ASCII and binary, through `stl_io`).

use std::path::Path;

use super::{IoError, Surface};

/// Reads an STL surface. STL stores every triangle with its own three
/// corners; shared corners are merged later by
/// [`crate::surface::prepare`].
pub fn read_stl_surface(path: &Path) -> Result<Surface, IoError> {
    let mut file = std::fs::File::open(path).map_err(|e| IoError::os(path, e))?;
    let mesh =
        stl_io::read_stl(&mut file).map_err(|e| IoError::parse(path, 0, format!("not a valid STL file: {e}")))?;
    let vertices: Vec<[f64; 3]> = mesh.vertices.iter().map(|v| [v[0] as f64, v[1] as f64, v[2] as f64]).collect();
    if let Some(i) = vertices.iter().position(|v| !v.iter().all(|x| x.is_finite())) {
        return Err(IoError::unsupported(path, format!("vertex {} has a non-finite coordinate", i + 1)));
    }
    let triangles: Vec<[u32; 3]> = mesh.faces.iter().map(|f| f.vertices.map(|v| v as u32)).collect();
    if triangles.is_empty() {
        return Err(IoError::unsupported(path, "no triangles: not a surface"));
    }
    Ok(Surface { vertices, triangles })
}

/// Reads a triangle surface by extension: `.obj` or `.stl`.
pub fn read_surface(path: &Path) -> Result<Surface, IoError> {
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("obj") => super::read_obj_surface(path),
        Some("stl") => read_stl_surface(path),
        _ => Err(IoError::unsupported(path, "a surface must be .obj or .stl")),
    }
}
