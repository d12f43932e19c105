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
//!   `[xx, yy, zz, xy, xz, yz]` with engineering shear strains (`2 e_xy`).

// Index loops mirror the formulas (rows, columns, components) in numeric
// kernels; iterator chains would hide them.
#![allow(clippy::needless_range_loop)]

pub mod corotation;
pub mod dual;
pub mod elasticity;
pub mod harmonic;
pub mod lanes;
pub mod mean_value;
pub mod quadrature;
pub mod rotation;
pub mod spectrum;
pub mod tet;
pub mod vec3;
