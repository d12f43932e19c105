//! Mesh generators: boxes of hexahedra or tetrahedra, and boxes cut into
//! random convex cells.

mod box_grid;
mod random_convex;
mod samples;

pub use box_grid::{box_hex, box_l_prisms, box_tet, prism};
pub use random_convex::{clipped_box, random_convex};
pub use samples::{element_with_vertices, replicate};
