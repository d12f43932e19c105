"""Type stubs of the compiled module (see `python/src/lib.rs`)."""

from os import PathLike
from typing import Any, Optional, Sequence, Tuple

import numpy as np
import numpy.typing as npt

Vec3 = Tuple[float, float, float] | Sequence[float]

class CleaveError(Exception):
    """An error of the engine; its message names the problem and the place."""

class Simulation:
    """A simulated elastic body. Units: m, Pa, kg/m^3, s."""

    @staticmethod
    def from_arrays(
        nodes: npt.NDArray[np.float64],
        cells: npt.NDArray[np.int64],
        young: float = 1e5,
        poisson: float = 0.3,
        density: float = 1000.0,
        gravity: Vec3 = (0.0, 0.0, -9.81),
        dt: float = 0.01,
    ) -> "Simulation":
        """Nodes (n x 3, m) and cells (m x 4 tetrahedra or m x 8 hexahedra)."""
    @staticmethod
    def from_file(
        path: str | PathLike[str],
        young: float = 1e5,
        poisson: float = 0.3,
        density: float = 1000.0,
        gravity: Vec3 = (0.0, 0.0, -9.81),
        dt: float = 0.01,
    ) -> "Simulation":
        """A mesh file (.mesh, .msh, .vtu, .node/.ele)."""
    @staticmethod
    def from_scene(path: str | PathLike[str]) -> "Simulation":
        """The simulation a scene file describes; `run` applies its cuts."""
    def step(self, steps: int = 1) -> None:
        """Implicit Euler steps, without the GIL."""
    def run(self, steps: int) -> None:
        """Steps as `cleave run` does: each step's scene cuts, then the step."""
    def solve_static(self) -> None:
        """The linear static solution under the loads and constraints."""
    def cut_plane(self, point: Vec3, normal: Vec3) -> int:
        """Cuts along a whole plane (rest frame, m); returns elements split."""
    def cut_polygon(self, points: Sequence[Vec3]) -> int:
        """Cuts by a planar convex polygon (rest frame, m); returns elements split."""
    def pin(self, node: int, u: Vec3) -> None:
        """Holds a node at displacement u (m)."""
    def unpin(self, node: int) -> None:
        """Releases a pinned node."""
    def add_collider(self, point: Vec3, normal: Vec3, stiffness: float) -> None:
        """A penalty plane; normal into the free side; stiffness in N/m."""
    @property
    def positions(self) -> npt.NDArray[np.float64]:
        """(n, 3) node positions, m."""
    @property
    def rest_positions(self) -> npt.NDArray[np.float64]:
        """(n, 3) rest positions, m."""
    @property
    def displacements(self) -> npt.NDArray[np.float64]:
        """(n, 3) displacements, m."""
    @property
    def velocities(self) -> npt.NDArray[np.float64]:
        """(n, 3) velocities, m/s."""
    @property
    def von_mises(self) -> npt.NDArray[np.float64]:
        """Von Mises stress per element, Pa."""
    @property
    def boundary_triangles(self) -> npt.NDArray[np.uint32]:
        """(t, 3) outward boundary triangles over node indices."""
    @property
    def num_elements(self) -> int: ...
    @property
    def steps(self) -> int: ...
    @property
    def time(self) -> float:
        """Simulated time, s."""
    @property
    def timings(self) -> dict[str, float]:
        """Wall time per phase so far, s."""

def run_scene(
    scene: str | PathLike[str], out: Optional[str | PathLike[str]] = None, steps: Optional[int] = None
) -> dict[str, Any]:
    """Runs a scene as `cleave run` does; returns its summary."""

def render(out: str | PathLike[str], stress: bool = False) -> int:
    """PNG pictures of a finished run's frames; returns how many."""
