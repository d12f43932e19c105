//! Patch test: a linear displacement imposed on the boundary of a mesh is
//! reproduced at every interior node (to 1e-9), with no body force.

use std::path::Path;

use cleave::io::read_mesh;
use cleave::meshing::box_tet;
use cleave::store::{BasisOptions, QuadratureRule};

use crate::common;

#[test]
fn patch_test_on_the_irregular_bunny_tet_mesh() {
    let mesh = read_mesh(&Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/bunny_5k.mesh")).unwrap();
    let (err, interior) =
        common::patch_error(mesh, BasisOptions { quadrature: QuadratureRule::Consistent, ..Default::default() });
    assert!(interior > 300, "the bunny has interior nodes ({interior})");
    assert!(err < 1e-9, "relative patch test error {err:e}");
}

#[test]
fn patch_test_on_a_perturbed_tet_box() {
    let mut mesh = box_tet([0.0; 3], [1.0; 3], [5, 5, 5]).unwrap();
    // move interior nodes by a deterministic pseudo-random offset
    for (i, p) in mesh.nodes.iter_mut().enumerate() {
        if p.iter().all(|&x| x > 1e-9 && x < 1.0 - 1e-9) {
            let h = |k: usize| (((i * 7919 + k * 104729) % 1000) as f64 / 1000.0 - 0.5) * 0.08;
            for (k, x) in p.iter_mut().enumerate() {
                *x += h(k);
            }
        }
    }
    mesh.validate().unwrap();
    let (err, interior) =
        common::patch_error(mesh, BasisOptions { quadrature: QuadratureRule::Consistent, ..Default::default() });
    assert_eq!(interior, 4 * 4 * 4);
    assert!(err < 1e-9, "relative patch test error {err:e}");
}
