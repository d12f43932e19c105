//! Global sparse assembly: a pattern built once per topology, values written
//! every time through precomputed slots.
//!
//! Unknowns come in 3-vectors ("blocks": a node's displacement for the
//! nodal families, one polynomial coefficient vector for DG), so the pattern
//! is built on blocks and expanded to a scalar compressed-column matrix in
//! which the three columns of a block column share one row structure. The
//! matrix stores both triangles (it is symmetric): the Cholesky solver reads
//! the lower one, matrix-vector products read it as compressed rows.
//!
//! Assembly is parallel and deterministic: elements of a batch are coloured
//! so that no two elements of one colour share a block; colours run one after
//! another, elements within a colour in parallel. Every matrix entry thus
//! receives its contributions in the same order whatever the thread count.

mod constraints;
mod pattern;

pub use constraints::Constraints;
pub use pattern::SparsePattern;
