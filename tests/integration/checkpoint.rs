//! Checkpoint and resume: a run carried on from a checkpoint writes the
//! same frames and summary, bit for bit, as the run that was never
//! interrupted, including after `kill -9`; a damaged checkpoint is refused.

use std::path::{Path, PathBuf};
use std::process::Command;

use cleave::scene::{LoadedScene, Run, RunOptions, CHECKPOINT_FILE};

use crate::common;

fn scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name)
}

/// The summary without what the wall clock and the machine decide.
fn summary_without_timings(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    for key in ["wall_time", "wall_time_total", "ms_per_step", "threads"] {
        v.as_object_mut().unwrap().remove(key).expect("a summary field");
    }
    v
}

/// Every frame file of `a` exists in `b` with the same bytes; returns how
/// many were compared.
fn same_frames(a: &Path, b: &Path) -> usize {
    let mut compared = 0;
    for entry in std::fs::read_dir(a).unwrap() {
        let name = entry.unwrap().file_name();
        let name = name.to_string_lossy();
        if name.starts_with("frame_") || name == "run.pvd" {
            let (x, y) = (std::fs::read(a.join(&*name)).unwrap(), std::fs::read(b.join(&*name)));
            assert!(y.as_ref().is_ok_and(|y| *y == x), "{name} differs between {} and {}", a.display(), b.display());
            compared += 1;
        }
    }
    compared
}

/// Runs `name` for `steps` steps through the library, once straight and
/// once stopped after `stop_after` steps (the process keeps nothing but the
/// checkpoint) and resumed; the frames and summaries must be equal.
fn resumes_bitwise(name: &str, steps: usize, stop_after: usize) {
    let root = tempfile::tempdir().unwrap();
    let loaded = LoadedScene::load(&scene(name)).unwrap();
    let opts = |dir: &str| RunOptions {
        out: Some(root.path().join(dir)),
        steps: Some(steps),
        checkpoint_every: Some(stop_after),
    };
    let straight = cleave::scene::run_scene(&loaded, &opts("straight")).unwrap();
    let mut run = Run::start(loaded.clone(), &opts("stopped")).unwrap();
    while run.steps_taken() < stop_after {
        assert!(run.step().unwrap());
    }
    drop(run);
    let checkpoint = root.path().join("stopped").join(CHECKPOINT_FILE);
    let resumed = cleave::scene::resume_run(&checkpoint).unwrap();
    let compared = same_frames(&root.path().join("straight"), &root.path().join("stopped"));
    assert!(compared > 3, "{compared} frames compared");
    assert_eq!(
        summary_without_timings(&root.path().join("straight")),
        summary_without_timings(&root.path().join("stopped"))
    );
    assert_eq!(straight.end, resumed.end);
    println!("{name}: {compared} files equal after resuming at step {stop_after} of {steps}");
}

#[test]
fn mean_value_run_with_cuts_resumes_bitwise() {
    // cube_slice cuts at steps 20, 60 and 100: the checkpoint at 40 holds one
    // cut done and two to come
    resumes_bitwise("cube_slice.toml", 120, 40);
}

/// `cube_slice` with `[solver] kind = "<kind>"`, resumed at step 40 of
/// 120 (see [`resumes_bitwise`]).
fn cube_slice_with_solver_resumes_bitwise(kind: &str) {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(scene("cube_slice.toml")).unwrap();
    let changed = dir.path().join(format!("cube_slice_{kind}.toml"));
    std::fs::write(&changed, text.replace("[output]", &format!("[solver]\nkind = \"{kind}\"\n\n[output]"))).unwrap();
    resumes_bitwise(changed.to_str().unwrap(), 120, 40);
}

/// The conjugate gradients carry state from step to step (the ordering a
/// cut extended, the past corrections, a lagged coarse level) that a
/// checkpoint does not hold: the run drops it at every checkpoint, and the
/// resumed run steps as the straight one did.
#[test]
fn conjugate_gradient_run_with_cuts_resumes_bitwise() {
    cube_slice_with_solver_resumes_bitwise("cg");
}

/// The lagged Cholesky carries a factor of an earlier step's matrix and its
/// back-off from failed lagged solves (cube_slice's 576 unknowns are above
/// the envelope's size, and its contacts make some lagged solves fail).
#[test]
fn lagged_cholesky_run_with_cuts_resumes_bitwise() {
    cube_slice_with_solver_resumes_bitwise("lagged-cholesky");
}

#[test]
fn harmonic_run_resumes_bitwise() {
    resumes_bitwise("bunny_sliced_harmonic.toml", 6, 3);
}

#[test]
fn dg_run_with_cuts_resumes_bitwise() {
    // dg_bunny_from_cube lands on its collider and is cut at steps 20, 40
    // and 60: the checkpoint at 30 holds one cut done and two to come
    resumes_bitwise("dg_bunny_from_cube.toml", 70, 30);
}

#[test]
fn killed_run_resumes_bitwise() {
    let root = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_cleave");
    let run = |dir: &Path| {
        let mut c = Command::new(exe);
        c.args(["run", scene("cube_slice.toml").to_str().unwrap(), "--steps", "3000", "--checkpoint-every", "25"]);
        c.arg("--out").arg(dir);
        c
    };
    let (straight, killed) = (root.path().join("straight"), root.path().join("killed"));
    assert!(run(&straight).status().unwrap().success());
    let mut child = run(&killed).spawn().unwrap();
    let checkpoint = killed.join(CHECKPOINT_FILE);
    let waited = std::time::Instant::now();
    while !checkpoint.exists() {
        assert!(waited.elapsed().as_secs() < 120, "no checkpoint written");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    assert!(!killed.join("summary.json").exists(), "the run finished before it was killed");
    let resumed = Command::new(exe).arg("resume").arg(&checkpoint).output().unwrap();
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    let compared = same_frames(&straight, &killed);
    assert!(compared > 100, "{compared} frames compared");
    assert_eq!(summary_without_timings(&straight), summary_without_timings(&killed));
}

#[test]
fn damaged_checkpoints_are_refused_by_name() {
    let root = tempfile::tempdir().unwrap();
    let loaded = LoadedScene::load(&scene("cube_slice.toml")).unwrap();
    let opts = RunOptions { out: Some(root.path().to_path_buf()), steps: Some(2), checkpoint_every: Some(1) };
    cleave::scene::run_scene(&loaded, &opts).unwrap();
    let path = root.path().join(CHECKPOINT_FILE);
    let bytes = std::fs::read(&path).unwrap();
    let damaged = root.path().join("damaged.bin");
    let refuse = |b: &[u8]| {
        std::fs::write(&damaged, b).unwrap();
        let e = cleave::scene::resume_run(&damaged).expect_err("refused").to_string();
        assert!(e.contains("damaged.bin"), "{e}");
        e
    };
    assert!(refuse(&bytes[..bytes.len() / 2]).contains("truncated"));
    let mut flipped = bytes.clone();
    flipped[bytes.len() / 3] ^= 0x10;
    assert!(refuse(&flipped).contains("checksum"));
    let mut newer = bytes.clone();
    newer[8..12].copy_from_slice(&(cleave::checkpoint::FORMAT_VERSION + 1).to_le_bytes());
    assert!(refuse(&newer).contains("format version"));
    assert!(refuse(b"[mesh]\n").contains("not a cleave checkpoint"));
}

/// A simulation keeps room in its mesh for what cuts add, built or read
/// back from a checkpoint alike: without it, the first cut after a resume
/// copies the whole mesh into larger arrays.
#[test]
fn a_resumed_simulation_keeps_room_for_cuts() {
    let mesh = cleave::meshing::box_tet([0.0; 3], [1.0; 3], [4, 4, 4]).unwrap();
    let sim = cleave::sim::Simulation::new(mesh, Default::default()).unwrap();
    let read: cleave::sim::Simulation = common::checkpoint_round_trip(&sim);
    for (label, sim) in [("built", &sim), ("read", &read)] {
        let mesh = sim.mesh();
        for (array, len, capacity) in [
            ("elements", mesh.elements.len(), mesh.elements.capacity()),
            ("faces", mesh.faces.len(), mesh.faces.capacity()),
            ("nodes", mesh.nodes.len(), mesh.nodes.capacity()),
        ] {
            assert!(capacity >= len + len / 2, "{label}: {array} {len} with capacity {capacity}");
        }
    }
}
