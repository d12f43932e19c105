"""Every frame of a run read by two independent readers (test helper).

usage: check_frames.py OUT_DIR START_CELLS START_VOLUME END_CELLS END_VOLUME

Reads the run's main frames (`run.pvd`) with meshio and with VTK's own
XML reader (the one ParaView uses): every frame of a run of at most
BIG_FRAME cells, the first and the last of larger ones (a frame of 10^5
polyhedra takes meshio seconds). In every frame read, both readers must
see the same cells in the same order, numbered 0..n-1 by `element_id`,
and VTK's cells enclose the run's rest volume, START_VOLUME, which cuts
keep (points minus `displacement`; the volume of the cells' outer surface
by vtkMassProperties).
In the first and the last frame, meshio's cells, face by face by the
divergence theorem, enclose the same volume to 1e-9 relative. The first frame must hold
START_CELLS cells of total rest volume START_VOLUME (m^3), the last
END_CELLS and END_VOLUME, as the run's summary.json says. Exits non-zero
with a message at the first mismatch.
"""
import re
import sys

import meshio
import numpy as np
import vtk
from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy


def polyhedra_volume(rest, cells):
    """The volume the polyhedra `cells` (each a list of outward faces, each
    face a list of point indices) enclose at the points `rest`: over every
    face's fan triangles (a, b, c), the sum of det(a, b, c) / 6. The faces
    are grouped by vertex count, so the sum runs as array operations."""
    by_size = {}
    for cell in cells:
        for face in cell:
            by_size.setdefault(len(face), []).append(face)
    volume = 0.0
    for faces in by_size.values():
        p = rest[np.asarray(faces)]
        for j in range(1, p.shape[1] - 1):
            volume += np.einsum("ij,ij->", p[:, 0], np.cross(p[:, j], p[:, j + 1])) / 6.0
    return volume


def meshio_frame(path, with_volume):
    m = meshio.read(path)
    rest = m.points - m.point_data["displacement"]
    cells, volume = 0, 0.0
    for block in m.cells:
        cells += len(block.data)
        if not with_volume:
            continue
        if block.type == "tetra":
            t = block.data
            a, b, c, d = (rest[t[:, i]] for i in range(4))
            volume += np.einsum("ij,ij->", b - a, np.cross(c - a, d - a)) / 6.0
        elif block.type.startswith("polyhedron"):
            volume += polyhedra_volume(rest, block.data)
        else:
            raise AssertionError(f"{path}: unexpected cell type {block.type}")
    ids = np.concatenate(m.cell_data["element_id"])
    return cells, volume, ids


BIG_FRAME = 20000


def vtk_frame(path):
    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(path)
    reader.Update()
    grid = reader.GetOutput()
    n = grid.GetNumberOfCells()
    kinds = {grid.GetCellType(c) for c in range(n)}
    assert kinds <= {vtk.VTK_TETRA, vtk.VTK_POLYHEDRON}, f"{path}: VTK reads cell types {kinds}"
    # the rest configuration's outer surface, triangulated, and its volume
    rest = vtk_to_numpy(grid.GetPoints().GetData()) - vtk_to_numpy(grid.GetPointData().GetArray("displacement"))
    points = vtk.vtkPoints()
    points.SetData(numpy_to_vtk(np.ascontiguousarray(rest), deep=True))
    grid.SetPoints(points)
    surface = vtk.vtkDataSetSurfaceFilter()
    surface.SetInputData(grid)
    triangles = vtk.vtkTriangleFilter()
    triangles.SetInputConnection(surface.GetOutputPort())
    mass = vtk.vtkMassProperties()
    mass.SetInputConnection(triangles.GetOutputPort())
    mass.Update()
    element_id = vtk_to_numpy(grid.GetCellData().GetArray("element_id"))
    return n, mass.GetVolume(), element_id


def main():
    out, start_cells, start_volume, end_cells, end_volume = sys.argv[1:6]
    pvd = open(f"{out}/run.pvd").read()
    frames = re.findall(r'file="([^"]+)"', pvd)
    assert frames, f"{out}/run.pvd lists no frames"
    times = [float(t) for t in re.findall(r'timestep="([^"]+)"', pvd)]
    assert times == sorted(times), f"{out}/run.pvd: times out of order"
    checked = []
    big = max(int(start_cells), int(end_cells)) > BIG_FRAME
    for i, name in enumerate(frames):
        if big and 0 < i < len(frames) - 1:
            continue
        path = f"{out}/{name}"
        ends = i in (0, len(frames) - 1)
        n_m, v_m, ids_m = meshio_frame(path, with_volume=ends)
        n_v, v_v, ids_v = vtk_frame(path)
        assert n_m == n_v, f"{path}: meshio reads {n_m} cells, VTK {n_v}"
        assert abs(v_v - float(start_volume)) <= 1e-9 * float(start_volume), f"{path}: VTK's cells enclose {v_v} m^3 of {start_volume}"
        assert not ends or abs(v_m - v_v) <= 1e-9 * abs(v_v), f"{path}: volume {v_m} (meshio) != {v_v} (VTK)"
        assert (np.sort(ids_m) == np.arange(n_m)).all(), f"{path}: element_id is not a numbering"
        assert (ids_m == ids_v).all(), f"{path}: the readers order the cells differently"
        want = [(start_cells, start_volume)] if i == 0 else []
        if i == len(frames) - 1:
            want.append((end_cells, end_volume))
        for cells, volume in want:
            assert n_m == int(cells), f"{path}: {n_m} cells, summary.json says {cells}"
            assert abs(v_v - float(volume)) <= 1e-9 * float(volume), f"{path}: volume {v_v}, summary.json {volume}"
        checked.append(n_m)
    print(f"{out}: {len(checked)} of {len(frames)} frames read by meshio and VTK alike, {checked[0]} -> {checked[-1]} cells")


if __name__ == "__main__":
    main()
