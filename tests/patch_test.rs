//! Patch test: a linear displacement imposed on the boundary of a mesh is
//! reproduced at every interior node (to 1e-9), with no body force.

use std::path::Path;

use cleave::io::read_mesh;
use cleave::mesh::PolyMesh;
use cleave::meshing::box_tet;
use cleave::sim::{Simulation, SimulationParams};

const GRAD: [[f64; 3]; 3] = [[1e-3, 2e-3, -1e-3], [-2e-3, 5e-4, 3e-3], [1e-3, -1e-3, 2e-3]];
const SHIFT: [f64; 3] = [0.01, -0.02, 0.005];

fn linear_field(x: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| SHIFT[i] + (0..3).map(|j| GRAD[i][j] * x[j]).sum::<f64>())
}

/// Pins the boundary nodes to the linear field, solves, and returns the
/// largest error over all nodes relative to the field's size, and the
/// number of interior nodes.
fn patch_error(mesh: PolyMesh) -> (f64, usize) {
    let adj = mesh.adjacency();
    let mut boundary = vec![false; mesh.nodes.len()];
    for (f, face) in mesh.faces.iter().enumerate() {
        if adj.is_boundary_face(f) {
            face.vertices.iter().for_each(|&v| boundary[v as usize] = true);
        }
    }
    let params = SimulationParams { gravity: [0.0; 3], ..Default::default() };
    let mut sim = Simulation::new(mesh, params).unwrap();
    for (i, &b) in boundary.iter().enumerate() {
        if b {
            sim.pin(i, linear_field(sim.mesh().nodes[i])).unwrap();
        }
    }
    sim.solve_static().unwrap();
    let scale = sim
        .mesh()
        .nodes
        .iter()
        .map(|&x| linear_field(x).iter().map(|v| v.abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max);
    let err = sim
        .mesh()
        .nodes
        .iter()
        .zip(sim.displacements())
        .map(|(&x, u)| {
            let want = linear_field(x);
            (0..3).map(|i| (u[i] - want[i]).abs()).fold(0.0, f64::max)
        })
        .fold(0.0, f64::max);
    (err / scale, boundary.iter().filter(|&&b| !b).count())
}

#[test]
fn patch_test_on_the_irregular_bunny_tet_mesh() {
    let mesh = read_mesh(&Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/bunny_5k.mesh")).unwrap();
    let (err, interior) = patch_error(mesh);
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
    let (err, interior) = patch_error(mesh);
    assert_eq!(interior, 4 * 4 * 4);
    assert!(err < 1e-9, "relative patch test error {err:e}");
}
