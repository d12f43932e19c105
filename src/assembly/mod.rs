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
//! The pattern knows unknowns and their couplings only ([`Couplings`]): an
//! element store of a nodal family is one such description, whose blocks
//! are nodes and whose entries are elements.
//!
//! Assembly is parallel and deterministic: each node gathers, in a fixed
//! order, the blocks of the elements around it into its own columns (see
//! [`SparsePattern`]), so every matrix entry receives its contributions in
//! the same order whatever the thread count, without locks or atomics.

mod constraints;
mod couplings;
mod pattern;

pub use constraints::Constraints;
pub use couplings::{Couplings, MAX_ENTRY_BLOCKS};
pub use pattern::{SparsePattern, Unlocated};

/// Asks the CPU to bring the cache line holding `value` into its caches
/// (a hint with no effect on results; nothing off x86-64).
#[inline(always)]
pub fn prefetch<T>(value: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch never faults, and `value` is a valid reference.
    #[allow(unused_unsafe)]
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        _mm_prefetch::<_MM_HINT_T0>((value as *const T).cast::<i8>());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = value;
}
