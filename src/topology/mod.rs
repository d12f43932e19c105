//! Topology changes of a [`crate::mesh::PolyMesh`]: plane splits (and, built
//! on them, cuts, sliver merges and refinement).

mod cut;
mod polygon;
mod split;

pub use cut::{cut_by_plane, CutReport};
pub use polygon::{cut_by_polygon, PolygonCutReport};
pub use split::{split_by_plane, split_elements_by_plane, NewNode, Plane, SplitError, SplitOptions, SplitReport};
