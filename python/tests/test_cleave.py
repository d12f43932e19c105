"""The Python API against the engine's own run (the CLI's code path):
same states to 1e-12, and engine errors as CleaveError with the engine's
message. Run with `python3 -m pytest python/tests`."""

import json
import pathlib

import meshio
import numpy as np
import pytest

import cleave

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCENES = ROOT / "scenes"


def last_frame(out):
    frames = sorted(out.glob("frame_[0-9][0-9][0-9][0-9].vtu"))
    return meshio.read(frames[-1])


def test_static_cantilever_matches_the_run(tmp_path):
    summary = cleave.run_scene(SCENES / "cantilever_tet.toml", out=tmp_path)
    sim = cleave.Simulation.from_scene(SCENES / "cantilever_tet.toml")
    sim.solve_static()
    frame = last_frame(tmp_path)
    assert sim.num_elements == summary["end"]["elements"]
    np.testing.assert_allclose(sim.displacements, frame.point_data["displacement"], rtol=0, atol=1e-12)
    assert summary == json.loads((tmp_path / "summary.json").read_text())


def test_cut_scene_matches_the_run(tmp_path):
    steps = 60  # through the cuts at steps 20 and 60
    summary = cleave.run_scene(SCENES / "cube_slice.toml", out=tmp_path, steps=steps)
    sim = cleave.Simulation.from_scene(SCENES / "cube_slice.toml")
    sim.run(steps)
    assert sim.steps == steps and sim.num_elements == summary["end"]["elements"]
    assert summary["end"]["elements"] > summary["start"]["elements"], "the scene's cuts happened"
    frame = last_frame(tmp_path)
    np.testing.assert_allclose(sim.positions, frame.points, rtol=0, atol=1e-12)
    np.testing.assert_allclose(sim.velocities, frame.point_data["velocity"], rtol=0, atol=1e-12)
    assert sim.von_mises.shape == (sim.num_elements,)
    assert sim.boundary_triangles.max() < len(sim.positions)


def test_arrays_in_state_out_and_a_cut():
    nodes = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=float)
    hexes = np.array([[0, 1, 3, 2, 4, 5, 7, 6]])
    sim = cleave.Simulation.from_arrays(nodes, hexes, young=1e5, gravity=(0, 0, -9.81), dt=0.01)
    sim.add_collider((0, 0, -0.05), (0, 0, 1), 1e6)
    sim.step(5)
    assert sim.positions.shape == (8, 3) and sim.time == pytest.approx(0.05)
    assert sim.positions[:, 2].min() < 0.0, "the cube falls"
    assert sim.cut_plane((0.5, 0.5, 0.5), (1, 0, 0)) == 1
    assert sim.num_elements == 2
    sim.pin(0, (0.0, 0.0, 0.0))
    sim.step(2)
    assert set(sim.timings) >= {"forces", "assembly", "solve"}


def test_bad_arguments_raise_the_engines_message():
    nodes = np.eye(4, 3)
    with pytest.raises(cleave.CleaveError, match="poisson"):
        cleave.Simulation.from_arrays(nodes, np.array([[0, 1, 2, 3]]), poisson=0.5)
    with pytest.raises(cleave.CleaveError, match="out of range"):
        cleave.Simulation.from_arrays(nodes, np.array([[0, 1, 2, 9]]))
    with pytest.raises(cleave.CleaveError, match="missing.toml"):
        cleave.Simulation.from_scene(SCENES / "missing.toml")
