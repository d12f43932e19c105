"""Independent check of cleave's VTU output with meshio (test helper).

usage: check_vtu.py TET_VTU CELLS VOLUME POLY_VTU POLY_CELLS
Exits non-zero with a message on the first mismatch.
"""
import sys

import meshio
import numpy as np


def tet_volume(points, tets):
    a, b, c, d = (points[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a)) / 6.0


def main():
    tet_path, cells, volume, poly_path, poly_cells = sys.argv[1:6]
    m = meshio.read(tet_path)
    rest = m.points - m.point_data["displacement"]
    tets = m.cells_dict["tetra"]
    assert len(tets) == int(cells), f"{len(tets)} tetra cells, expected {cells}"
    v = tet_volume(rest, tets)
    assert v.min() > 0, "a tetra is inverted"
    assert abs(v.sum() - float(volume)) < 1e-9 * float(volume), f"volume {v.sum()} != {volume}"
    assert set(m.cell_data) >= {"von_mises", "element_id", "vertex_count"}, m.cell_data.keys()
    p = meshio.read(poly_path)
    n = sum(len(block.data) for block in p.cells)
    kinds = {block.type for block in p.cells}
    assert n == int(poly_cells), f"{n} cells, expected {poly_cells}"
    assert any(k.startswith("polyhedron") for k in kinds), kinds
    print(f"meshio: {tet_path}: {len(tets)} tetra, volume {v.sum():.12f}; {poly_path}: {n} cells {sorted(kinds)}")


if __name__ == "__main__":
    main()
