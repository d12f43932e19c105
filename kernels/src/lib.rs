//! Batched finite element kernels for polyhedral elasticity.
//!
//! This crate holds the arithmetic that makes cleave fast and nothing else: no
//! mesh types, no allocation inside hot loops, slices in and slices out. A
//! renderer or another engine can call it on its own.
//!
//! Conventions shared by every kernel:
//! - positions are `[f64; 3]` in metres, element-local node order is the order
//!   the caller gathered;
//! - a gradient of a shape function has units 1/m;
//! - stiffness blocks are row-major 3x3 `[f64; 9]` in N/m;
//! - strain and stress use the Voigt order of wicke2007 eq. 3:
//!   `[xx, yy, zz, xy, xz, yz]` with engineering shear strains (`2 e_xy`);
//! - a kernel that needs working memory takes it from the caller: a slice
//!   sized by its `*_scratch_len`, or a [`dyn_stack::MemStack`] sized by
//!   its `*_scratch` [`dyn_stack::StackReq`] (faer's convention), so no
//!   kernel allocates.

// Index loops mirror the formulas (rows, columns, components) in numeric
// kernels; iterator chains would hide them.
#![warn(missing_docs)]
#![allow(clippy::needless_range_loop)]

pub use dyn_stack;

pub mod corotation;
pub mod dual;
pub mod elasticity;
pub mod envelope;
pub mod harmonic;
pub mod inverse_factor;
pub mod lanes;
pub mod logarithm;

/// The widest SIMD register the kernels run on, in `f64` lanes (AVX-512):
/// workspace requests are sized for it.
pub const MAX_LANES: usize = 8;
pub mod mean_value;
pub mod moments;
pub mod polynomial;
pub mod quadrature;
pub mod rotation;
pub mod sliced;
pub mod solve4;
pub mod spectrum;
pub mod spmv;
pub mod tet;
pub mod vec3;
