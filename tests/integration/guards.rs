//! Run guards: a run provoked to go wrong stops with a diagnosis naming
//! the step, the quantity, its bound and where, and keeps its last good
//! frame and a checkpoint; in `"warn"` mode it reports and goes on; the
//! shipped scenes never trip them (tests/integration/scenes.rs runs every one).

use std::path::Path;

use cleave::scene::{LoadedScene, Run, RunOptions, SceneError, CHECKPOINT_FILE};

/// A 2 x 2 x 2 hexahedral cube dropped onto a plane, guards as given.
fn text(guards: &str, extra: &str) -> String {
    format!(
        r#"
[mesh]
generator = "box"
element = "hex"
min = [0.0, 0.0, 0.5]
max = [1.0, 1.0, 1.5]
cells = [2, 2, 2]

[material]
young = 1e5
poisson = 0.3
density = 1000.0

[simulation]
mode = "dynamic"
dt = 0.01
steps = 40
guards = "{guards}"

[[collider]]
plane = {{ point = [0.0, 0.0, 0.0], normal = [0.0, 0.0, 1.0] }}
stiffness = 1e6

[output]
every = 1
formats = ["vtu"]
{extra}
"#
    )
}

fn scene(guards: &str, extra: &str) -> LoadedScene {
    LoadedScene::parse(Path::new("guarded.toml"), text(guards, extra)).unwrap()
}

fn start(loaded: LoadedScene, dir: &Path) -> Run {
    Run::start(loaded, &RunOptions { out: Some(dir.to_path_buf()), ..Default::default() }).unwrap()
}

/// Steps `run` 5 times, then gives node 3 a velocity no force could have
/// produced (`speed`, m/s, up), and steps once more.
fn kick(run: &mut Run, speed: f64) -> Result<bool, SceneError> {
    for _ in 0..5 {
        assert!(run.step().unwrap());
    }
    let sim = run.simulation_mut();
    let mut v = sim.velocities().to_vec();
    v[3] = [0.0, 0.0, speed];
    sim.set_velocities(&v).unwrap();
    run.step()
}

#[test]
fn a_kicked_node_stops_the_run_with_its_diagnosis_and_last_good_state() {
    let dir = tempfile::tempdir().unwrap();
    let mut run = start(scene("stop", ""), dir.path());
    let error = kick(&mut run, 1e4).expect_err("the guard must stop the run");
    let SceneError::Stopped { diagnosis, last_good_step, .. } = &error else { panic!("{error}") };
    assert_eq!(*last_good_step, 5);
    assert!(diagnosis.starts_with("step 6: mechanical energy (J)"), "{diagnosis}");
    assert!(diagnosis.contains("nodes [3]"), "the kicked node is named: {diagnosis}");
    assert!(error.to_string().contains("checkpoint.bin"), "{error}");
    // the last good state is on disk: its frame (written at step 5) and a
    // checkpoint at step 5, from which the run resumes
    assert!(dir.path().join("frame_0005.vtu").exists());
    assert!(!dir.path().join("frame_0006.vtu").exists());
    let resumed = Run::resume(&dir.path().join(CHECKPOINT_FILE)).unwrap();
    assert_eq!(resumed.steps_taken(), 5);
}

#[test]
fn an_infinite_velocity_cannot_be_injected_and_a_huge_one_stops_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let mut run = start(scene("stop", ""), dir.path());
    let sim = run.simulation_mut();
    let mut v = sim.velocities().to_vec();
    v[0][2] = f64::NAN;
    let refused = sim.set_velocities(&v).unwrap_err().to_string();
    assert!(refused.contains("finite") && refused.contains("node 0"), "{refused}");
    let error = kick(&mut run, 1e300).expect_err("stopped");
    let SceneError::Stopped { diagnosis, last_good_step: 5, .. } = &error else { panic!("{error}") };
    assert!(diagnosis.contains("step 6"), "{diagnosis}");
}

#[test]
fn warn_mode_reports_and_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let mut run = start(scene("warn", ""), dir.path());
    assert!(kick(&mut run, 1e4).unwrap());
    assert_eq!(run.guard_warnings().len(), 1, "{:?}", run.guard_warnings());
    assert!(run.guard_warnings()[0].starts_with("step 6: mechanical energy"));
    while run.step().unwrap() {}
    let summary = run.finish().unwrap();
    assert_eq!(summary.steps, 40);
    assert!(summary.guard_warnings >= 1);
    assert_eq!(summary.guard_warnings_listed.len(), summary.guard_warnings.min(20));
}

#[test]
fn off_mode_checks_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let mut run = start(scene("off", ""), dir.path());
    assert!(kick(&mut run, 1e4).unwrap());
    assert!(run.guard_warnings().is_empty());
}

#[test]
fn inverted_and_stretched_elements_are_named() {
    // energy bound out of the way: the shape guards alone
    let loose = "[guards]\nenergy_growth = 1e30\n";
    let dir = tempfile::tempdir().unwrap();
    let mut run = start(scene("stop", loose), dir.path());
    assert!(run.step().unwrap());
    // mirror the cube through its middle plane x = 0.5: every element inverts
    let sim = run.simulation_mut();
    let u: Vec<[f64; 3]> = sim.mesh().nodes.iter().map(|x| [1.0 - 2.0 * x[0], 0.0, 0.0]).collect();
    sim.set_displacements(&u).unwrap();
    let error = run.step().expect_err("inverted");
    let SceneError::Stopped { diagnosis, .. } = &error else { panic!("{error}") };
    assert!(diagnosis.starts_with("step 2: fraction of inverted elements = 1.0"), "{diagnosis}");
    assert!(diagnosis.contains("elements [0, 1, 2, 3, 4, 5, 6, 7]"), "{diagnosis}");

    let stretch = format!("{loose}stretch = 1.5\n");
    let dir = tempfile::tempdir().unwrap();
    let mut run = start(scene("stop", &stretch), dir.path());
    assert!(run.step().unwrap());
    let sim = run.simulation_mut();
    let mut u = vec![[0.0; 3]; sim.mesh().nodes.len()];
    let far = sim.mesh().nodes.iter().position(|x| *x == [1.0, 1.0, 1.5]).unwrap();
    u[far] = [2.0, 2.0, 2.0];
    sim.set_displacements(&u).unwrap();
    let error = run.step().expect_err("stretched");
    let SceneError::Stopped { diagnosis, .. } = &error else { panic!("{error}") };
    assert!(diagnosis.starts_with("step 2: element stretch"), "{diagnosis}");
    assert!(diagnosis.contains(&far.to_string()), "the stretched element's nodes are named: {diagnosis}");
}

#[test]
fn guard_bounds_are_checked_with_their_line() {
    for (bad, key) in [
        ("[guards]\nstretch = 0.5\n", "guards.stretch"),
        ("[guards]\ninverted_fraction = 2.0\n", "guards.inverted_fraction"),
    ] {
        let e = LoadedScene::parse(Path::new("g.toml"), text("stop", bad)).unwrap_err().to_string();
        assert!(e.contains(key) && e.contains("g.toml:"), "{e}");
    }
    let e = LoadedScene::parse(Path::new("g.toml"), text("sometimes", "")).unwrap_err();
    assert!(e.to_string().contains("sometimes"), "{e}");
}

/// A body of every element kind at rest trips nothing: tetrahedra (closed
/// form), mean value hexahedra and harmonic (trilinear) hexahedra, whose
/// store keeps no surface triangles, and DG.
#[test]
fn bodies_of_every_kind_at_rest_trip_nothing() {
    use cleave::sim::{GuardLimits, Guards, Simulation, SimulationParams};
    use cleave::store::Family;
    let material = cleave::material::Material::new(1e5, 0.3, 1000.0).unwrap();
    let tets = cleave::meshing::box_tet([0.0; 3], [1.0; 3], [2, 2, 2]).unwrap();
    let hexes = cleave::meshing::box_hex([0.0; 3], [1.0; 3], [2, 2, 2]).unwrap();
    for (mesh, family) in [
        (tets.clone(), Family::MeanValue),
        (hexes.clone(), Family::MeanValue),
        (hexes, Family::Harmonic),
        (tets, Family::Dg),
    ] {
        let mut params = SimulationParams { material, gravity: [0.0; 3], ..Default::default() };
        params.basis.family = family;
        let mut sim = Simulation::new(mesh, params).unwrap();
        sim.step().unwrap();
        let trip = Guards::new(GuardLimits::default()).check(&sim, 1);
        assert!(trip.is_none(), "{family:?}: {}", trip.unwrap());
    }
}
