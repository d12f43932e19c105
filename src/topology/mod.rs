//! Topology changes of a [`crate::mesh::PolyMesh`]: plane splits that
//! leave no slivers, cuts built on them (whole planes and progressive
//! polygons), the opening of pinched nodes, and the rollback of a cut that
//! fails.

mod cut;
mod pinch;
mod polygon;
mod rollback;
mod scope;
mod sliver;
mod split;
mod transfer;

pub use cut::{cut_by_plane, cut_by_plane_keeping, CutReport};
pub use pinch::{open_pinched_nodes, pinched_nodes};
pub use polygon::{cut_by_polygon, cut_by_polygon_keeping, polygon_plane, PolygonCutReport};
pub use rollback::{CutShape, Rollback};
pub use scope::{node_diameters, raise_node_diameters, CutScope, Reach};
pub use sliver::{merge_slivers, SliverReport};
pub(crate) use split::classify_split;
pub use split::{split_by_plane, split_elements_by_plane, NewNode, SplitError, SplitOptions, SplitReport};
pub use transfer::{conserve_momentum, momenta, NodeOrigins};
