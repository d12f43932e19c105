//! Pictures of a finished run (`cleave render OUT_DIR`).

use std::path::Path;

use crate::io::{read_vtu_frame, IoError};
use crate::mesh::Plane;
use crate::output::{nodal_average, Pictures};
use crate::render::Surface;

use super::LoadedScene;

/// Renders every frame of the finished run in `dir` to `frame_NNNN.png`
/// beside its `frame_NNNN.vtu` (the frames `run.pvd` lists, else every
/// `frame_NNNN.vtu` in order), coloured by von Mises stress if `stress`.
/// The ground plane and the up direction come from the scene that
/// `summary.json` names, when it can be read (else no ground, and `+z` up).
/// Returns the number of pictures.
pub fn render_run(dir: &Path, stress: bool) -> Result<usize, IoError> {
    let frames = frame_files(dir)?;
    let (up, ground) = scene_view(dir);
    let mut pictures = Pictures::new(stress);
    for name in &frames {
        let path = dir.join(name);
        let frame = read_vtu_frame(&path)?;
        let positions = &frame.mesh.nodes;
        let rest: Vec<[f64; 3]> = match &frame.displacement {
            Some(u) => positions.iter().zip(u).map(|(x, u)| [x[0] - u[0], x[1] - u[1], x[2] - u[2]]).collect(),
            None => positions.clone(),
        };
        let stress = match (&frame.von_mises, stress) {
            (Some(v), true) => Some(nodal_average(&frame.mesh, v)),
            _ => None,
        };
        let triangles = frame.mesh.boundary_triangles();
        let surface = Surface { rest: &rest, positions, triangles: &triangles, stress: stress.as_deref() };
        pictures.draw(&path.with_extension("png"), &surface, up, ground)?;
    }
    Ok(frames.len())
}

/// The main frames of the run in `dir`, in order.
fn frame_files(dir: &Path) -> Result<Vec<String>, IoError> {
    let pvd = dir.join("run.pvd");
    if let Ok(text) = std::fs::read_to_string(&pvd) {
        let files: Vec<String> =
            text.split("file=\"").skip(1).filter_map(|s| s.split('"').next()).map(String::from).collect();
        if !files.is_empty() {
            return Ok(files);
        }
    }
    let mut files: Vec<String> = std::fs::read_dir(dir)
        .map_err(|e| IoError::os(dir, e))?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| {
            n.starts_with("frame_") && n.ends_with(".vtu") && n[6..n.len() - 4].bytes().all(|b| b.is_ascii_digit())
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(IoError::os(
            dir,
            std::io::Error::other("no frame_NNNN.vtu here (a run written with formats = [\"vtu\"])"),
        ));
    }
    Ok(files)
}

/// The up direction (against gravity) and the first collider's plane of
/// the scene that `summary.json` in `dir` names.
fn scene_view(dir: &Path) -> ([f64; 3], Option<Plane>) {
    let scene = std::fs::read_to_string(dir.join("summary.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .and_then(|v| v.get("scene")?.as_str().map(String::from))
        .and_then(|p| LoadedScene::load(Path::new(&p)).ok());
    let Some(scene) = scene else { return ([0.0, 0.0, 1.0], None) };
    let g = scene.scene.simulation.gravity;
    let ground = scene.scene.collider.first().map(|c| Plane { point: c.plane.point, normal: c.plane.normal });
    ([-g[0], -g[1], -g[2]], ground)
}
