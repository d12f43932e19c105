//! Structured boxes of hexahedra, or of tetrahedra (six per cube, conforming).

use crate::mesh::{Cell, MeshError, PolyMesh};

/// Node positions of a `cells[0] x cells[1] x cells[2]` grid over
/// `[min, max]` (m), x fastest, and the id of grid point `(i, j, k)`.
fn grid(min: [f64; 3], max: [f64; 3], cells: [usize; 3]) -> (Vec<[f64; 3]>, impl Fn(usize, usize, usize) -> u32) {
    let [nx, ny, nz] = cells.map(|c| c + 1);
    let mut nodes = Vec::with_capacity(nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let t = [i as f64 / cells[0] as f64, j as f64 / cells[1] as f64, k as f64 / cells[2] as f64];
                nodes.push([0, 1, 2].map(|d| min[d] + t[d] * (max[d] - min[d])));
            }
        }
    }
    (nodes, move |i, j, k| (i + nx * (j + ny * k)) as u32)
}

fn check(min: [f64; 3], max: [f64; 3], cells: [usize; 3]) -> Result<(), MeshError> {
    if cells.contains(&0) || (0..3).any(|d| !(max[d] > min[d])) {
        return Err(MeshError::InvalidBox { min, max, cells });
    }
    Ok(())
}

/// A box of `cells` hexahedra over `[min, max]`.
pub fn box_hex(min: [f64; 3], max: [f64; 3], cells: [usize; 3]) -> Result<PolyMesh, MeshError> {
    check(min, max, cells)?;
    let (nodes, id) = grid(min, max, cells);
    let mut out = Vec::with_capacity(cells.iter().product());
    for k in 0..cells[2] {
        for j in 0..cells[1] {
            for i in 0..cells[0] {
                out.push(Cell::Hex([
                    id(i, j, k),
                    id(i + 1, j, k),
                    id(i + 1, j + 1, k),
                    id(i, j + 1, k),
                    id(i, j, k + 1),
                    id(i + 1, j, k + 1),
                    id(i + 1, j + 1, k + 1),
                    id(i, j + 1, k + 1),
                ]));
            }
        }
    }
    PolyMesh::from_cells(nodes, &out)
}

/// A box of `6 * cells` tetrahedra over `[min, max]`: every cube is split
/// into the six tetrahedra around its main diagonal (Kuhn's subdivision),
/// whose face diagonals agree between neighbouring cubes.
pub fn box_tet(min: [f64; 3], max: [f64; 3], cells: [usize; 3]) -> Result<PolyMesh, MeshError> {
    check(min, max, cells)?;
    let (nodes, id) = grid(min, max, cells);
    const PERMS: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    let mut out = Vec::with_capacity(6 * cells.iter().product::<usize>());
    for k in 0..cells[2] {
        for j in 0..cells[1] {
            for i in 0..cells[0] {
                for p in PERMS {
                    let mut c = [i, j, k];
                    let mut t = [id(c[0], c[1], c[2]); 4];
                    for (s, &axis) in p.iter().enumerate() {
                        c[axis] += 1;
                        t[s + 1] = id(c[0], c[1], c[2]);
                    }
                    out.push(Cell::Tet(t));
                }
            }
        }
    }
    PolyMesh::from_cells(nodes, &out)
}

/// A box of non-convex L-shaped prisms and hexahedra over `[min, max]`:
/// the `cells` grid (even in x and y) is grouped into 2x2 columns per
/// layer, each an L of three cells (an 8-node non-convex loop on top and
/// bottom, one quadrilateral per grid edge on the sides, 16 nodes) and the
/// hexahedron in its notch. The mesh is conforming: every side face is one
/// grid quadrilateral.
pub fn box_l_prisms(min: [f64; 3], max: [f64; 3], cells: [usize; 3]) -> Result<PolyMesh, MeshError> {
    check(min, max, cells)?;
    if cells[0] % 2 != 0 || cells[1] % 2 != 0 {
        return Err(MeshError::InvalidBox { min, max, cells });
    }
    let (nodes, id) = grid(min, max, cells);
    const L: [[usize; 2]; 8] = [[0, 0], [1, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2], [0, 1]];
    let mut out = Vec::new();
    for k in 0..cells[2] {
        for j in (0..cells[1]).step_by(2) {
            for i in (0..cells[0]).step_by(2) {
                let at = |p: [usize; 2], dz: usize| id(i + p[0], j + p[1], k + dz);
                let mut faces = vec![L.iter().map(|&p| at(p, 0)).collect(), L.iter().map(|&p| at(p, 1)).collect()];
                for s in 0..8 {
                    let (a, b) = (L[s], L[(s + 1) % 8]);
                    faces.push(vec![at(a, 0), at(b, 0), at(b, 1), at(a, 1)]);
                }
                out.push(Cell::Polyhedron(faces));
                out.push(Cell::Hex([
                    at([1, 1], 0),
                    at([2, 1], 0),
                    at([2, 2], 0),
                    at([1, 2], 0),
                    at([1, 1], 1),
                    at([2, 1], 1),
                    at([2, 2], 1),
                    at([1, 2], 1),
                ]));
            }
        }
    }
    PolyMesh::from_cells(nodes, &out)
}

/// One prism element: the polygon `outline` (x, y in m, any simple loop,
/// convex or not) extruded from `z = 0` to `z = height`.
pub fn prism(outline: &[[f64; 2]], height: f64) -> Result<PolyMesh, MeshError> {
    let n = outline.len();
    let nodes: Vec<[f64; 3]> =
        [0.0, height].iter().flat_map(|&z| outline.iter().map(move |p| [p[0], p[1], z])).collect();
    let mut faces: Vec<Vec<u32>> = vec![(0..n as u32).collect(), (n as u32..2 * n as u32).collect()];
    for s in 0..n {
        let (a, b) = (s as u32, ((s + 1) % n) as u32);
        faces.push(vec![a, b, b + n as u32, a + n as u32]);
    }
    PolyMesh::from_cells(nodes, &[Cell::Polyhedron(faces)])
}
