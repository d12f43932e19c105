//! Mesh generators: boxes of hexahedra or tetrahedra, boxes cut into
//! random convex cells, and closed surfaces sliced by a grid or embedded in an octree.

mod box_grid;
mod grid_slice;
mod octree;
mod random_convex;
mod samples;

pub use box_grid::{box_hex, box_l_prisms, box_tet, prism};
pub use grid_slice::{grid_slice, SliceOptions, SliceReport};
pub use octree::{octree, OctreeReport};
pub use random_convex::{clipped_box, random_convex};
pub use samples::{element_with_vertices, replicate};
