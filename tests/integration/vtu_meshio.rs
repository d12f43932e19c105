//! Our VTU output read by an independent reader (meshio, from PyPI).
//!
//! Skipped, with the reason printed, where Python or meshio is missing;
//! under CI (`CLEAVE_CI` set, as `.ci/run` does) a missing meshio is a
//! failure, since `.ci/run` installs it.

use std::path::Path;
use std::process::Command;

use cleave::io::{write_vtu, VtuFields};
use cleave::meshing::random_convex;
use cleave::scene::{run_scene, LoadedScene, RunOptions};

fn meshio_available() -> Result<(), String> {
    match Command::new("python3").args(["-c", "import meshio, numpy"]).output() {
        Ok(o) if o.status.success() => Ok(()),
        Ok(o) => Err(format!("meshio is not importable: {}", String::from_utf8_lossy(&o.stderr).trim())),
        Err(e) => Err(format!("python3 is not available: {e}")),
    }
}

#[test]
fn meshio_reads_our_tetra_and_polyhedron_files() {
    if let Err(why) = meshio_available() {
        assert!(std::env::var_os("CLEAVE_CI").is_none(), "CI must run this test: {why}");
        println!("skipped: {why}");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = LoadedScene::load(&root.join("scenes/cantilever_tet.toml")).unwrap();
    let out = dir.path().join("cantilever");
    let summary = run_scene(&scene, &RunOptions { out: Some(out.clone()), ..Default::default() }).unwrap();
    let poly = random_convex([0.0; 3], [1.0; 3], 8, 2).unwrap();
    let poly_path = dir.path().join("poly.vtu");
    write_vtu(&poly_path, &poly, &poly.nodes, &VtuFields::default()).unwrap();
    let status = Command::new("python3")
        .arg(root.join("tests/check_vtu.py"))
        .arg(out.join("frame_0000.vtu"))
        .arg(summary.start.elements.to_string())
        .arg("4.0")
        .arg(&poly_path)
        .arg(poly.elements.len().to_string())
        .status()
        .unwrap();
    assert!(status.success(), "meshio rejected our VTU output");
}
