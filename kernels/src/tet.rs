//! Closed-form linear tetrahedron: volume and barycentric gradients.
//!
//! For a tetrahedron with vertices `x_0..x_3` the barycentric coordinates
//! `λ_a` are linear, so their gradients `g_a = ∇λ_a` are constant:
//!
//! ```text
//! V   = (x_1 - x_0) · ((x_2 - x_0) × (x_3 - x_0)) / 6         [m^3]
//! g_1 = ((x_2 - x_0) × (x_3 - x_0)) / (6 V)                   [1/m]
//! g_2 = ((x_3 - x_0) × (x_1 - x_0)) / (6 V)
//! g_3 = ((x_1 - x_0) × (x_2 - x_0)) / (6 V)
//! g_0 = -(g_1 + g_2 + g_3)
//! ```
//!
//! `V` is signed: positive when `x_3` lies on the side of the triangle
//! `(x_0, x_1, x_2)` that its counter-clockwise normal points to.

use crate::vec3::{cross, dot, scale, sub};

/// Signed volume of the tetrahedron `(a, b, c, d)` in m^3.
#[inline]
pub fn signed_volume(a: [f64; 3], b: [f64; 3], c: [f64; 3], d: [f64; 3]) -> f64 {
    dot(sub(b, a), cross(sub(c, a), sub(d, a))) / 6.0
}

/// Signed volume and the four barycentric gradients of a tetrahedron.
///
/// Returns `None` when the volume is zero or not finite (a flat or degenerate
/// tetrahedron has no gradients).
#[inline]
pub fn gradients(x: &[[f64; 3]; 4]) -> Option<(f64, [[f64; 3]; 4])> {
    let e1 = sub(x[1], x[0]);
    let e2 = sub(x[2], x[0]);
    let e3 = sub(x[3], x[0]);
    let c23 = cross(e2, e3);
    let six_v = dot(e1, c23);
    if six_v == 0.0 || !six_v.is_finite() {
        return None;
    }
    let inv = 1.0 / six_v;
    let g1 = scale(c23, inv);
    let g2 = scale(cross(e3, e1), inv);
    let g3 = scale(cross(e1, e2), inv);
    let g0 = [-(g1[0] + g2[0] + g3[0]), -(g1[1] + g2[1] + g3[1]), -(g1[2] + g2[2] + g3[2])];
    Some((six_v / 6.0, [g0, g1, g2, g3]))
}
