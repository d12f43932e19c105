//! A box cut by random planes: every cell of the plane arrangement is a
//! convex element (the meshes of wicke2007 Fig. 2).

use rand_chacha::rand_core::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::box_hex;
use crate::mesh::PolyMesh;
use crate::topology::{split_by_plane, Plane, SplitOptions};

/// Uniform number in `[0, 1)` from 53 random bits.
fn uniform(rng: &mut ChaCha8Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// The box `[min, max]` (one hexahedron) split by `planes` planes, each
/// through a uniform random point of the box with a uniform random
/// direction. Reproducible from `seed` (ChaCha8).
pub fn random_convex(min: [f64; 3], max: [f64; 3], planes: usize, seed: u64) -> Result<PolyMesh, crate::Error> {
    let mut mesh = box_hex(min, max, [1, 1, 1])?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let opts = SplitOptions::default();
    for _ in 0..planes {
        let point = [0, 1, 2].map(|d| min[d] + uniform(&mut rng) * (max[d] - min[d]));
        // uniform direction: normalised Gaussian-free sampling on the sphere
        let z = 2.0 * uniform(&mut rng) - 1.0;
        let phi = 2.0 * std::f64::consts::PI * uniform(&mut rng);
        let r = (1.0 - z * z).sqrt();
        let normal = [r * phi.cos(), r * phi.sin(), z];
        split_by_plane(&mut mesh, &Plane { point, normal }, &opts)?;
    }
    Ok(mesh)
}
