//! Pictures: a cube's silhouette against its exact projected area, the
//! second colour of faces a cut opens, and whole runs rendered from their
//! frames.

use cleave::mesh::Plane;
use cleave::meshing::box_hex;
use cleave::render::{Image, Renderer, Surface};
use cleave::sim::{Simulation, SimulationParams};

const BACKGROUND: [u8; 3] = [250, 250, 250];

/// Pixels whose colour `keep` accepts.
fn count(image: &Image, keep: impl Fn([u8; 3]) -> bool) -> usize {
    (0..image.height())
        .flat_map(|y| (0..image.width()).map(move |x| (x, y)))
        .filter(|&(x, y)| keep(image.get(x, y)))
        .count()
}

/// Orange-ish: the cut colour, whatever the shading.
fn is_cut_colour(c: [u8; 3]) -> bool {
    c[0] as i32 > c[2] as i32 + 40 && c[0] > c[1]
}

#[test]
fn a_cube_covers_its_projected_area() {
    // the camera looks along d = (cos 25° cos -60°, cos 25° sin -60°, sin 25°)
    // (up = +z, first horizontal axis x): a unit cube's silhouette is
    // |d_x| + |d_y| + |d_z| square metres
    let mesh = box_hex([0.0; 3], [1.0; 3], [2, 2, 2]).unwrap();
    let triangles = mesh.boundary_triangles();
    let surface = Surface { rest: &mesh.nodes, positions: &mesh.nodes, triangles: &triangles, stress: None };
    let renderer = Renderer::new(&surface, [0.0, 0.0, 1.0], None, 800, 600);
    let image = renderer.render(&surface);
    let covered = count(&image, |c| c != BACKGROUND) as f64;
    let (az, el) = ((-60.0f64).to_radians(), 25.0f64.to_radians());
    let want_m2 = (el.cos() * az.cos()).abs() + (el.cos() * az.sin()).abs() + el.sin().abs();
    // pixels per metre: the fit puts the projected extents, with a margin
    // of 1.6, into half the image; measured here from the cube's own width
    let scale = renderer.pixels_per_metre();
    let got_m2 = covered / (scale * scale);
    println!("silhouette {got_m2:.4} m², projected area {want_m2:.4} m² ({covered} pixels at {scale:.1} px/m)");
    assert!((got_m2 - want_m2).abs() < 0.02 * want_m2, "{got_m2} against {want_m2}");
    assert_eq!(count(&image, is_cut_colour), 0, "an uncut cube shows no cut face");
}

#[test]
fn a_cut_shows_its_second_colour_once_the_pieces_part() {
    let mesh = box_hex([0.0; 3], [1.0; 3], [3, 3, 3]).unwrap();
    let first_triangles = mesh.boundary_triangles();
    let first = Surface { rest: &mesh.nodes, positions: &mesh.nodes, triangles: &first_triangles, stress: None };
    let renderer =
        Renderer::new(&first, [0.0, 0.0, 1.0], Some(Plane { point: [0.0; 3], normal: [0.0, 0.0, 1.0] }), 640, 480);
    let mut sim = Simulation::new(mesh, SimulationParams::default()).unwrap();
    sim.cut_plane(&Plane { point: [0.5, 0.5, 0.5], normal: [1.0, 0.2, 0.1] }).unwrap();
    // move the piece on the positive side away, opening the cut
    let mesh = sim.mesh();
    let mut positions = mesh.nodes.clone();
    for e in 0..mesh.elements.len() {
        let c = mesh.element_centroid(e);
        if (c[0] - 0.5) + 0.2 * (c[1] - 0.5) + 0.1 * (c[2] - 0.5) > 0.0 {
            for &n in &mesh.elements[e].nodes {
                positions[n as usize] =
                    [mesh.nodes[n as usize][0] + 0.6, mesh.nodes[n as usize][1], mesh.nodes[n as usize][2]];
            }
        }
    }
    let triangles = sim.boundary_triangles();
    let image = renderer.render(&Surface { rest: &mesh.nodes, positions: &positions, triangles, stress: None });
    let cut = count(&image, is_cut_colour);
    println!("{cut} pixels in the cut colour");
    assert!(cut > 1000, "the opened cut shows its colour ({cut} pixels)");
}

#[test]
fn a_run_renders_from_its_frames_with_a_stress_legend() {
    let dir = tempfile::tempdir().unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = cleave::scene::LoadedScene::load(&root.join("scenes/cube_slice.toml")).unwrap();
    let out = dir.path().join("cube_slice");
    let opts = cleave::scene::RunOptions { out: Some(out.clone()), steps: Some(60), ..Default::default() };
    cleave::scene::run_scene(&scene, &opts).unwrap();
    let n = cleave::scene::render_run(&out, true).unwrap();
    assert!(n >= 2, "{n} pictures");
    let last = out.join(format!("frame_{:04}.png", n - 1));
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&last).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (960, 720));
    let pixels = &buf[..info.buffer_size()];
    let distinct: std::collections::HashSet<&[u8]> = pixels.chunks_exact(3).collect();
    assert!(distinct.len() > 50, "the picture is not blank ({} colours)", distinct.len());
}
