//! Random convex cells: a box cut by random planes into many convex
//! elements (the meshes of wicke2007 Fig. 2), or clipped by random planes
//! into one convex element (Fig. 1).

use rand_chacha::rand_core::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::box_hex;
use crate::mesh::Plane;
use crate::mesh::PolyMesh;
use crate::topology::{classify_split, split_by_plane, SplitOptions};

/// Uniform number in `[0, 1)` from 53 random bits.
fn uniform(rng: &mut ChaCha8Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A uniformly distributed unit vector.
fn direction(rng: &mut ChaCha8Rng) -> [f64; 3] {
    let z = 2.0 * uniform(rng) - 1.0;
    let phi = 2.0 * std::f64::consts::PI * uniform(rng);
    let r = (1.0 - z * z).sqrt();
    [r * phi.cos(), r * phi.sin(), z]
}

/// The box `[min, max]` (one hexahedron) split by `planes` planes, each
/// through a uniform random point of the box with a uniform random
/// direction. Reproducible from `seed` (ChaCha8).
pub fn random_convex(min: [f64; 3], max: [f64; 3], planes: usize, seed: u64) -> Result<PolyMesh, crate::Error> {
    let mut mesh = box_hex(min, max, [1, 1, 1])?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for _ in 0..planes {
        split_by_clean_plane(&mut mesh, &mut rng, |rng| {
            let point = [0, 1, 2].map(|d| min[d] + uniform(rng) * (max[d] - min[d]));
            Plane { point, normal: direction(rng) }
        })?;
    }
    Ok(mesh)
}

/// Splits `mesh` by the first plane `draw` makes that snaps no node onto
/// itself and keeps no element whole, so that every cell stays an exact
/// convex polyhedron whose nodes are at least `min_spacing` of its
/// diameter apart; after 100 draws, by the last one.
fn split_by_clean_plane(
    mesh: &mut PolyMesh,
    rng: &mut ChaCha8Rng,
    mut draw: impl FnMut(&mut ChaCha8Rng) -> Plane,
) -> Result<(), crate::Error> {
    let opts = SplitOptions::default();
    let mut plane = draw(rng);
    for _ in 1..100 {
        if !classify_split(mesh, &plane, &opts)?.snaps_or_keeps() {
            break;
        }
        plane = draw(rng);
    }
    split_by_plane(mesh, &plane, &opts)?;
    Ok(())
}

/// One convex element: the box `[min, max]` clipped by `planes` random
/// planes at 60 to 95 % of the half extent from the centre (keeping the
/// centre's side), so vertices and faces multiply while the element stays
/// round. Reproducible from `seed`.
pub fn clipped_box(min: [f64; 3], max: [f64; 3], planes: usize, seed: u64) -> Result<PolyMesh, crate::Error> {
    let mut mesh = box_hex(min, max, [1, 1, 1])?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let centre: [f64; 3] = std::array::from_fn(|d| 0.5 * (min[d] + max[d]));
    for _ in 0..planes {
        // the positive part keeps element id 0 and contains the centre
        split_by_clean_plane(&mut mesh, &mut rng, |rng| {
            let n = direction(rng);
            let r = 0.6 + 0.35 * uniform(rng);
            let point = std::array::from_fn(|d| centre[d] + r * 0.5 * (max[d] - min[d]) * n[d]);
            Plane { point, normal: n.map(|x| -x) }
        })?;
    }
    Ok(mesh.extract(&[0])?.0)
}
