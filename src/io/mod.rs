//! Mesh file formats: reading volume meshes and surfaces, writing frames.
//!
//! | format | read | write |
//! |---|---|---|
//! | Medit `.mesh` (tetrahedra, hexahedra) | yes | yes |
//! | gmsh `.msh` 4.1 ASCII (tetrahedra, hexahedra) | yes | yes |
//! | TetGen `.node` + `.ele` | yes | yes |
//! | VTK `.vtu` (tetra, hexahedron, polyhedron) | yes | yes |
//! | Wavefront `.obj` triangle surface | yes (tobj) | boundary surface |
//! | STL triangle surface (ASCII, binary) | yes (stl_io) | no |
//!
//! Every error names the file and, for text formats, the line.

mod gmsh;
mod medit;
mod obj;
mod stl;
mod tetgen;
mod tokens;
mod vtu;

use std::path::{Path, PathBuf};

use thiserror::Error;

use crate::mesh::{MeshError, PolyMesh};

pub use gmsh::{read_gmsh, write_gmsh};
pub use medit::{read_medit, write_medit};
pub use obj::{read_obj_surface, write_boundary_obj, write_surface_obj, Surface};
pub use stl::{read_stl_surface, read_surface};
pub use tetgen::{read_tetgen, write_tetgen};
pub use vtu::{read_vtu, read_vtu_frame, write_collection, write_surface_vtu, write_vtu, VtuFields, VtuFrame};

/// A failure to read or write a mesh file.
#[derive(Debug, Error)]
pub enum IoError {
    /// The file could not be opened, read or written.
    #[error("{}: {source}", .path.display())]
    Os {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The file's content does not follow its format.
    #[error("{}:{line}: {message}", .path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// The line (1-based).
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// The file is valid but uses something cleave does not read.
    #[error("{}: {message}", .path.display())]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The file was read but the mesh it describes is invalid.
    #[error("{}: invalid mesh: {source}", .path.display())]
    Mesh {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: MeshError,
    },
}

impl IoError {
    pub(crate) fn os(path: &Path, source: std::io::Error) -> Self {
        IoError::Os { path: path.to_path_buf(), source }
    }
    pub(crate) fn parse(path: &Path, line: usize, message: impl Into<String>) -> Self {
        IoError::Parse { path: path.to_path_buf(), line, message: message.into() }
    }
    pub(crate) fn unsupported(path: &Path, message: impl Into<String>) -> Self {
        IoError::Unsupported { path: path.to_path_buf(), message: message.into() }
    }
    pub(crate) fn mesh(path: &Path, source: MeshError) -> Self {
        IoError::Mesh { path: path.to_path_buf(), source }
    }
}

/// Reads a volume mesh, choosing the format by extension (`.mesh`, `.msh`,
/// `.vtu`, `.node`, `.ele`). The mesh is built and oriented but not
/// validated: call [`PolyMesh::validate`].
pub fn read_mesh(path: &Path) -> Result<PolyMesh, IoError> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    match ext.as_str() {
        "mesh" => read_medit(path),
        "msh" => read_gmsh(path),
        "vtu" => read_vtu(path),
        "node" | "ele" => read_tetgen(path),
        "obj" => Err(IoError::unsupported(
            path,
            "an .obj file is a surface; mesh its interior with a [meshing] section in the scene",
        )),
        _ => Err(IoError::unsupported(
            path,
            format!("unknown mesh extension '.{ext}' (expected .mesh, .msh, .vtu, .node/.ele)"),
        )),
    }
}

/// The whole text of the file at `path`; the error names the file.
pub fn read_text(path: &Path) -> Result<String, IoError> {
    std::fs::read_to_string(path).map_err(|e| IoError::os(path, e))
}

/// Writes `text` to `path`, creating its folder; the error names the file
/// or folder.
pub fn write_text(path: &Path, text: &str) -> Result<(), IoError> {
    if let Some(dir) = path.parent() {
        if !dir.as_os_str().is_empty() {
            std::fs::create_dir_all(dir).map_err(|e| IoError::os(dir, e))?;
        }
    }
    std::fs::write(path, text).map_err(|e| IoError::os(path, e))
}
