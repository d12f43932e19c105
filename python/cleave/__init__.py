"""cleave: elastic solids on arbitrary polyhedral finite elements, with
cutting and refinement without remeshing (Python bindings of the Rust
engine). Units are SI: metres, pascals, kg/m^3, seconds.

    import cleave
    sim = cleave.Simulation.from_scene("scenes/cube_slice.toml")
    sim.run(100)                      # the scene's steps and cuts
    x = sim.positions                 # (n, 3) numpy array, m
"""

from ._cleave import CleaveError, Simulation, render, run_scene

__all__ = ["CleaveError", "Simulation", "render", "run_scene"]
