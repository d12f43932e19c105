//! A surface embedded in the simulation mesh by moving least squares
//! (kaufmann2008 §8) and colliding on its vertices (§9).

use cleave::material::Material;
use cleave::meshing::box_hex;
use cleave::sim::embedding::mls_map;
use cleave::sim::{Collider, EmbeddedSurface, Simulation, SimulationParams};
use cleave::solve::SolverKind;
use cleave::store::dg::{DgOptions, Flux};
use cleave::store::{BasisOptions, Family};

/// An icosphere of radius `r` about `c`, refined twice (162 vertices).
fn sphere(c: [f64; 3], r: f64) -> EmbeddedSurface {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<[f64; 3]> = vec![
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ];
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..2 {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::new();
        for t in &f {
            let m: [u32; 3] = std::array::from_fn(|i| {
                let (a, b) = (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3]));
                *mid.entry((a, b)).or_insert_with(|| {
                    let (p, q) = (v[a as usize], v[b as usize]);
                    v.push(std::array::from_fn(|k| 0.5 * (p[k] + q[k])));
                    v.len() as u32 - 1
                })
            });
            next.extend([[t[0], m[0], m[2]], [t[1], m[1], m[0]], [t[2], m[2], m[1]], m]);
        }
        f = next;
    }
    let vertices = v
        .iter()
        .map(|p| {
            let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            std::array::from_fn(|k| c[k] + r * p[k] / l)
        })
        .collect();
    EmbeddedSurface { vertices, triangles: f }
}

/// The largest component of `got[i] - expected(rest[i])` over all points.
fn worst_miss(got: &[[f64; 3]], rest: &[[f64; 3]], expected: impl Fn([f64; 3]) -> [f64; 3]) -> f64 {
    got.iter()
        .zip(rest)
        .map(|(p, &x)| {
            let want = expected(x);
            (0..3).map(|k| (p[k] - want[k]).abs()).fold(0.0, f64::max)
        })
        .fold(0.0, f64::max)
}

fn params(dg: bool) -> SimulationParams {
    let basis = if dg {
        BasisOptions {
            family: Family::Dg,
            dg: DgOptions { degree: 1, flux: Flux::Ip, penalty: 1.0 },
            ..Default::default()
        }
    } else {
        BasisOptions { family: Family::Harmonic, ..Default::default() }
    };
    SimulationParams {
        material: Material::new(2e5, 0.3, 1000.0).unwrap(),
        basis,
        dt: 0.005,
        mass_damping: 1.0,
        solver: SolverKind::Cholesky,
        ..Default::default()
    }
}

/// Rotated rigidly (with DG and with trilinear hexahedra), the embedded
/// sphere turns with the body exactly: MLS reproduces affine fields.
#[test]
fn an_embedded_surface_follows_a_rigid_motion_exactly() {
    for dg in [false, true] {
        let mut sim = Simulation::new(box_hex([0.0; 3], [1.0; 3], [3, 3, 3]).unwrap(), params(dg)).unwrap();
        let surface = sphere([0.5; 3], 0.4);
        sim.embed(surface.clone()).unwrap();
        let (s, c) = (0.6f64.sin(), 0.6f64.cos());
        let turn = |x: [f64; 3]| [c * x[0] - s * x[1] + 0.2, s * x[0] + c * x[1], x[2] - 0.3];
        let u: Vec<[f64; 3]> = sim
            .mesh()
            .nodes
            .iter()
            .map(|&x| {
                let y = turn(x);
                [y[0] - x[0], y[1] - x[1], y[2] - x[2]]
            })
            .collect();
        sim.set_displacements(&u).unwrap();
        let moved = sim.embedded_surface().unwrap().vertices;
        let worst = worst_miss(&moved, &surface.vertices, turn);
        assert!(worst < 1e-12, "dg {dg}: {worst:e}");
    }
}

/// At the mesh nodes of a deformed DG body, the MLS field differs from the
/// stitched one by no more than its weights allow:
/// `|ũ(x_k) - ũ_k| = |Σ_i φ_i(x_k) (ũ_i - ũ_k)| <= Σ_i |φ_i(x_k)| |ũ_i - ũ_k|`
/// (the weights sum to one), and by much less than the displacement.
#[test]
fn at_the_nodes_the_mls_field_stays_within_what_its_weights_allow() {
    let mut sim = Simulation::new(box_hex([0.0, 0.0, 0.3], [1.0, 1.0, 1.3], [3, 3, 3]).unwrap(), params(true)).unwrap();
    sim.add_collider(Collider::new([0.0; 3], [0.0, 0.0, 1.0], 1e7).unwrap());
    for _ in 0..60 {
        sim.step().unwrap();
    }
    let nodes = sim.mesh().nodes.clone();
    let map = mls_map(sim.mesh(), &nodes).unwrap();
    let u = sim.displacements();
    let mut mls = Vec::new();
    map.apply(u, &mut mls);
    let (mut worst, mut scale): (f64, f64) = (0.0, 0.0);
    for k in 0..nodes.len() {
        let (near, w) = map.row(k);
        let sum: f64 = w.iter().sum();
        assert!((sum - 1.0).abs() < 1e-12, "weights sum to {sum}");
        let bound: f64 = near
            .iter()
            .zip(w)
            .map(|(&i, &wi)| wi.abs() * (0..3).map(|c| (u[i as usize][c] - u[k][c]).powi(2)).sum::<f64>().sqrt())
            .sum();
        let gap = (0..3).map(|c| (mls[k][c] - u[k][c]).powi(2)).sum::<f64>().sqrt();
        assert!(gap <= bound * (1.0 + 1e-12) + 1e-15, "node {k}: {gap:e} > {bound:e}");
        worst = worst.max(gap);
        scale = scale.max((0..3).map(|c| u[k][c].powi(2)).sum::<f64>().sqrt());
    }
    println!("MLS against stitched at the nodes: {worst:.2e} m of displacements up to {scale:.2e} m");
    assert!(worst < 0.05 * scale, "{worst:e} vs {scale:e}");
}

/// A body whose embedded sphere reaches 0.15 m below its coarse mesh falls
/// 0.3 m on a plane: the sphere's vertices collide (none sinks further than
/// the body moves in one step at the impact speed, `√(2 g 0.3) h` = 12 mm:
/// contacts are found at the start of a step), and the coarse nodes never
/// come within 0.1 m of the plane; without the embedded collisions they
/// reach it.
#[test]
fn collisions_on_embedded_vertices_hold_the_surface_above_the_plane() {
    for dg in [true, false] {
        let run = |embedded: bool| -> (f64, f64) {
            let mesh = box_hex([0.0, 0.0, 0.45], [1.0, 1.0, 1.25], [2, 2, 2]).unwrap();
            let mut sim = Simulation::new(mesh, params(dg)).unwrap();
            sim.add_collider(Collider::new([0.0; 3], [0.0, 0.0, 1.0], 2e7).unwrap());
            if embedded {
                sim.embed(sphere([0.5, 0.5, 0.7], 0.4)).unwrap();
            }
            let (mut lowest_surface, mut lowest_node) = (f64::INFINITY, f64::INFINITY);
            for _ in 0..300 {
                sim.step().unwrap();
                if let Some(surface) = sim.embedded_surface() {
                    let z = surface.vertices.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
                    lowest_surface = lowest_surface.min(z);
                }
                lowest_node = lowest_node.min(sim.positions().iter().map(|p| p[2]).fold(f64::INFINITY, f64::min));
            }
            (lowest_surface, lowest_node)
        };
        let ((surface, node), (_, bare)) = (run(true), run(false));
        println!(
            "dg {dg}: lowest embedded vertex {surface:.4} m, lowest node {node:.4} m; without embedding {bare:.4} m"
        );
        let one_step = (2.0 * 9.81 * 0.3f64).sqrt() * 0.005;
        assert!(surface > -one_step, "dg {dg}: the embedded surface sank to {surface}");
        assert!(node > 0.1, "dg {dg}: a node came down to {node}");
        assert!(bare < 0.01, "dg {dg}: without embedded collisions the nodes reach the plane ({bare})");
    }
}

/// Embedded by the elements' shape functions (martin2008 §7), a surface
/// follows every linear field exactly, and its vertices at nodes follow
/// those nodes: on trilinear hexahedra, harmonic L-prisms, mean value
/// convex cells and tetrahedra.
#[test]
fn element_embedding_reproduces_linear_fields_and_follows_the_nodes() {
    use cleave::meshing::{box_l_prisms, box_tet, random_convex};
    let cases = [
        ("trilinear hexahedra", box_hex([0.0; 3], [1.0; 3], [3, 3, 3]).unwrap(), Family::Harmonic),
        ("harmonic L-prisms", box_l_prisms([0.0; 3], [1.0; 3], [2, 2, 2]).unwrap(), Family::Harmonic),
        ("mean value cells", random_convex([0.0; 3], [1.0; 3], 8, 3).unwrap(), Family::MeanValue),
        ("tetrahedra", box_tet([0.0; 3], [1.0; 3], [2, 2, 2]).unwrap(), Family::MeanValue),
    ];
    let field =
        |x: [f64; 3]| [0.01 + 0.02 * x[0] - 0.03 * x[2], -0.02 + 0.01 * x[1], 0.04 * x[0] + 0.01 * x[1] - 0.02 * x[2]];
    for (name, mesh, family) in cases {
        let params = SimulationParams { basis: BasisOptions { family, ..Default::default() }, ..Default::default() };
        let mut sim = Simulation::new(mesh, params).unwrap();
        // the sphere inside, and three vertices put at nodes
        let mut surface = sphere([0.5; 3], 0.35);
        let at_nodes = [0usize, 5, 11];
        for (i, &n) in at_nodes.iter().enumerate() {
            surface.vertices[i] = sim.mesh().nodes[n];
        }
        sim.embed(surface.clone()).unwrap();
        let u: Vec<[f64; 3]> = sim.mesh().nodes.iter().map(|&x| field(x)).collect();
        sim.set_displacements(&u).unwrap();
        let moved = sim.embedded_surface().unwrap().vertices;
        let worst = worst_miss(&moved, &surface.vertices, |x| {
            let u = field(x);
            [x[0] + u[0], x[1] + u[1], x[2] + u[2]]
        });
        println!("{name}: linear field reproduced to {worst:.1e} m");

        assert!(worst < 1e-12, "{name}: {worst:e}");
        for (i, &n) in at_nodes.iter().enumerate() {
            assert_eq!(moved[i], sim.positions()[n], "{name}: vertex {i} at node {n}");
        }
    }
}

/// Moving least squares reproduces affine fields on a graded mesh too
/// (nodes of very different spacings): the basis is centred and scaled
/// the same way for every node (a per-node scale broke this: 0.1 m off here).
#[test]
fn mls_reproduces_affine_fields_on_graded_meshes() {
    let mesh = cleave::meshing::random_convex([0.0; 3], [1.0; 3], 10, 7).unwrap();
    let points: Vec<[f64; 3]> = (0..200)
        .map(|i| {
            [
                0.1 + 0.8 * ((i * 37 % 200) as f64 / 200.0),
                0.1 + 0.8 * ((i * 91 % 200) as f64 / 200.0),
                0.1 + 0.8 * (i as f64 / 200.0),
            ]
        })
        .collect();
    let map = mls_map(&mesh, &points).unwrap();
    let field = |x: [f64; 3]| [0.3 + x[0] - 2.0 * x[2], x[1] * 0.5, -x[0] + x[1] + x[2]];
    let values: Vec<[f64; 3]> = mesh.nodes.iter().map(|&x| field(x)).collect();
    let mut out = Vec::new();
    map.apply(&values, &mut out);
    let worst = worst_miss(&out, &points, field);
    assert!(worst < 1e-12, "{worst:e}");
}
