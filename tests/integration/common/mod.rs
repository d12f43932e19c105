//! Helpers shared by the integration tests (each test binary uses a part).
#![allow(dead_code)]

use cleave::material::Material;
use cleave::mesh::Plane;
use cleave::mesh::PolyMesh;
use cleave::meshing::box_tet;
use cleave::sim::{FixedRegion, Simulation, SimulationParams};
use cleave::solve::SolverKind;
use cleave::store::BasisOptions;
use proptest::prelude::*;

/// The path of a file in `assets/`.
pub fn asset(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets").join(name)
}

/// The linear field of the patch tests, `u(x) = d + G x` (m).
pub fn linear_field(x: [f64; 3]) -> [f64; 3] {
    const G: [[f64; 3]; 3] = [[1e-3, 2e-3, -1e-3], [-2e-3, 5e-4, 3e-3], [1e-3, -1e-3, 2e-3]];
    const D: [f64; 3] = [0.01, -0.02, 0.005];
    std::array::from_fn(|i| D[i] + (0..3).map(|j| G[i][j] * x[j]).sum::<f64>())
}

/// The patch test: boundary nodes pinned to [`linear_field`], no body
/// force, static solve with the basis `basis`. Returns the largest nodal error
/// relative to the field's size, and the number of interior nodes.
pub fn patch_error(mesh: PolyMesh, basis: BasisOptions) -> (f64, usize) {
    let adj = mesh.adjacency();
    let mut boundary = vec![false; mesh.nodes.len()];
    for (f, face) in mesh.faces.iter().enumerate() {
        if adj.is_boundary_face(f) {
            face.vertices.iter().for_each(|&v| boundary[v as usize] = true);
        }
    }
    let interior = boundary.iter().filter(|&&b| !b).count();
    let params = SimulationParams { gravity: [0.0; 3], basis, ..Default::default() };
    let mut sim = Simulation::new(mesh, params).unwrap();
    for (i, &b) in boundary.iter().enumerate() {
        if b {
            sim.pin(i, linear_field(sim.mesh().nodes[i])).unwrap();
        }
    }
    sim.solve_static().unwrap();
    let size = |v: [f64; 3]| v.iter().map(|x| x.abs()).fold(0.0, f64::max);
    let scale = sim.mesh().nodes.iter().map(|&x| size(linear_field(x))).fold(0.0, f64::max);
    let err = sim
        .mesh()
        .nodes
        .iter()
        .zip(sim.displacements())
        .map(|(&x, u)| {
            let want = linear_field(x);
            size([u[0] - want[0], u[1] - want[1], u[2] - want[2]])
        })
        .fold(0.0, f64::max);
    (err / scale, interior)
}

/// Planes through points of `[lo, hi]^3` with any non-degenerate normal.
pub fn plane_strategy(lo: f64, hi: f64) -> impl Strategy<Value = Plane> {
    (lo..hi, lo..hi, lo..hi, -1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0)
        .prop_filter("non-zero normal", |p| p.3.abs() + p.4.abs() + p.5.abs() > 1e-2)
        .prop_map(|(x, y, z, a, b, c)| Plane { point: [x, y, z], normal: [a, b, c] })
}

/// The unit cube as polyhedra or tetrahedra, by the parity of `seed`: cut
/// by `planes` random planes from `seed` (even), or a 3x3x3 box of
/// tetrahedra (odd).
pub fn cube_of_polyhedra_or_tets(seed: u64, planes: usize) -> PolyMesh {
    if seed % 2 == 0 {
        cleave::meshing::random_convex([0.0; 3], [1.0; 3], planes, seed).unwrap()
    } else {
        box_tet([0.0; 3], [1.0; 3], [3, 3, 3]).unwrap()
    }
}

/// The rectangle of half sides `half` centred on `plane.point` in the
/// plane, turned by `twist` (radians) about its normal, counter-clockwise
/// about the normal.
pub fn rectangle_in_plane(plane: &Plane, half: (f64, f64), twist: f64) -> [[f64; 3]; 4] {
    let n = plane.normal;
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let n = [n[0] / len, n[1] / len, n[2] / len];
    let a = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let cr =
        |a: [f64; 3], b: [f64; 3]| [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let u0 = cr(n, a);
    let l = (u0[0] * u0[0] + u0[1] * u0[1] + u0[2] * u0[2]).sqrt();
    let u0 = [u0[0] / l, u0[1] / l, u0[2] / l];
    let w0 = cr(n, u0);
    let (c, s) = (twist.cos(), twist.sin());
    let u = [c * u0[0] + s * w0[0], c * u0[1] + s * w0[1], c * u0[2] + s * w0[2]];
    let w = cr(n, u);
    let p = plane.point;
    let corner = |a: f64, b: f64| [p[0] + a * u[0] + b * w[0], p[1] + a * u[1] + b * w[1], p[2] + a * u[2] + b * w[2]];
    [corner(-half.0, -half.1), corner(half.0, -half.1), corner(half.0, half.1), corner(-half.0, half.1)]
}

/// Mean vertical deflection (m, positive down) of the tip face x = 4 of the
/// 4 x 1 x 1 m beam `mesh` clamped at x = 0 under self-weight
/// (E = 1e5 Pa, nu = 0.3, rho = 1000 kg/m^3) with the basis `basis`.
pub fn tip_deflection(mesh: PolyMesh, basis: BasisOptions) -> f64 {
    let params = SimulationParams {
        basis,
        material: Material::new(1e5, 0.3, 1000.0).unwrap(),
        solver: SolverKind::Cholesky,
        ..Default::default()
    };
    let mut sim = Simulation::new(mesh, params).unwrap();
    sim.fix(FixedRegion::clamp([-1.0; 3], [1e-3, 2.0, 2.0])).unwrap();
    let stats = sim.solve_static().unwrap();
    assert!(stats.residual < 1e-9, "residual {}", stats.residual);
    let tip: Vec<f64> = sim
        .mesh()
        .nodes
        .iter()
        .zip(sim.displacements())
        .filter(|(x, _)| x[0] > 4.0 - 1e-9)
        .map(|(_, u)| -u[2])
        .collect();
    tip.iter().sum::<f64>() / tip.len() as f64
}

/// Tip deflections of the tetrahedral beams with 2, 4, 8, 16 cells across.
pub fn tet_sequence() -> Vec<f64> {
    [2, 4, 8, 16]
        .iter()
        .map(|&n| tip_deflection(box_tet([0.0; 3], [4.0, 1.0, 1.0], [4 * n, n, n]).unwrap(), BasisOptions::default()))
        .collect()
}

/// What [`spectra`] found over the elements of a store.
#[derive(Clone, Copy, Debug)]
pub struct SpectrumSummary {
    /// Elements checked.
    pub elements: usize,
    /// Smallest `λ7 / λmax`.
    pub worst_ratio: f64,
    /// Largest asymmetry `|K - Kᵀ| / max |K|`.
    pub asymmetry: f64,
}

/// Checks every element stiffness of `store` by a full eigendecomposition
/// (faer, independent of the store's own estimate): symmetric to `1e-12`
/// of its largest entry, exactly six eigenvalues within `1e-10 λmax` of
/// zero (the rigid modes), none below `-1e-12 λmax`, and `λ7 / λmax` of at
/// least `floor`. Panics naming the element otherwise.
pub fn spectra(store: &cleave::store::ElementStore, floor: f64) -> SpectrumSummary {
    use faer::{Mat, Side};
    let mut out = SpectrumSummary { elements: 0, worst_ratio: f64::INFINITY, asymmetry: 0.0 };
    for b in &store.batches {
        let n = 3 * b.k;
        for i in 0..b.len() {
            let e = b.elements[i];
            let ke = b.element_matrix(i);
            let scale = ke.iter().fold(0.0f64, |a, x| a.max(x.abs()));
            for r in 0..n {
                for c in 0..r {
                    out.asymmetry = out.asymmetry.max((ke[r * n + c] - ke[c * n + r]).abs() / scale);
                }
            }
            let ev = Mat::<f64>::from_fn(n, n, |r, c| 0.5 * (ke[r * n + c] + ke[c * n + r]))
                .self_adjoint_eigenvalues(Side::Lower)
                .unwrap();
            let top = ev[n - 1];
            let zeros = ev.iter().filter(|l| l.abs() <= 1e-10 * top).count();
            let ratio = ev[6] / top;
            assert_eq!(zeros, 6, "element {e} ({:?}, {} nodes): {zeros} zero modes, λ7/λmax {ratio:.2e}", b.kind, b.k);
            assert!(ev[0] >= -1e-12 * top, "element {e} ({:?}): eigenvalue {:.3e} of {top:.3e}", b.kind, ev[0]);
            assert!(ratio >= floor, "element {e} ({:?}, {} nodes): λ7/λmax {ratio:.2e} < {floor:.0e}", b.kind, b.k);
            out.worst_ratio = out.worst_ratio.min(ratio);
            out.elements += 1;
        }
    }
    assert!(out.asymmetry <= 1e-12, "asymmetry {:.2e}", out.asymmetry);
    out
}

/// The signed cone rule over element `e` of `mesh` from its centroid
/// (`n` points per direction): points (m) and weights (m³).
pub fn element_cone_rule(mesh: &cleave::mesh::PolyMesh, e: usize, n: usize) -> (Vec<[f64; 3]>, Vec<f64>) {
    let nodes = &mesh.elements[e].nodes;
    let verts: Vec<[f64; 3]> = nodes.iter().map(|&v| mesh.nodes[v as usize]).collect();
    let tris: Vec<[u32; 3]> =
        mesh.element_triangles(e).map(|t| t.map(|g| nodes.binary_search(&g).unwrap() as u32)).collect();
    let (mut pts, mut wts) = (Vec::new(), Vec::new());
    cleave_kernels::quadrature::cone_rule(&verts, &tris, mesh.element_centroid(e), n, &mut pts, &mut wts);
    (pts, wts)
}

/// `value` written to a checkpoint file (in a temporary folder, removed
/// after) and read back.
pub fn checkpoint_round_trip<T: serde::Serialize + serde::de::DeserializeOwned>(value: &T) -> T {
    let folder = tempfile::tempdir().unwrap();
    let path = folder.path().join("checkpoint.bin");
    cleave::checkpoint::write(&path, value).unwrap();
    cleave::checkpoint::read(&path).unwrap()
}
