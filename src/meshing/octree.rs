//! Embedding a closed surface in an adaptive octree (martin2008 §7, Fig. 7).
//!
//! The bounding cube of the surface is split into eight while a cell meets
//! the surface (exact triangle-box overlap) and is shallower than
//! `max_depth`; then the leaves are balanced 2:1 across faces (a leaf's
//! face neighbours are at most one level finer), which bounds how many
//! nodes a face carries. Leaves entirely outside the surface are dropped;
//! the others, including every leaf the surface passes through, are
//! elements.
//!
//! **No hanging nodes.** A leaf whose neighbour across a side is finer
//! splits that side into the neighbour's squares, and every square's loop
//! holds every node on its edges (the corners of finer leaves along it).
//! Both sides of a shared square therefore list the same nodes and share
//! one face: the mesh is conforming and the basis functions of any family
//! stay continuous. Leaves are convex (cubes with flat, subdivided sides).

use rustc_hash::{FxHashMap as HashMap, FxHashSet as HashSet};

use cleave_kernels::vec3::{cross, dot, sub};

use crate::io::Surface;
use crate::mesh::{Cell, PolyMesh};
use crate::param::ParamError;
use crate::Error;

/// What [`octree`] made.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OctreeReport {
    /// Kept leaves (elements) by depth.
    pub leaves_by_depth: Vec<usize>,
    /// Leaves dropped as outside.
    pub dropped: usize,
    /// Leaves the surface passes through.
    pub crossing: usize,
}

/// A cell: depth and integer corner in units of the finest cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
struct Octant {
    depth: u32,
    corner: [i64; 3],
}

/// The eight corners of the cube at `corner` with edge `u` (finest units),
/// in binary order (x fastest): also the corners of its children of edge
/// `u` when `u` is half the cube's.
fn cube_corners(corner: [i64; 3], u: i64) -> [[i64; 3]; 8] {
    std::array::from_fn(|k| {
        let k = k as i64;
        [corner[0] + u * (k & 1), corner[1] + u * ((k >> 1) & 1), corner[2] + u * ((k >> 2) & 1)]
    })
}

/// Whether triangle `t` overlaps the box `centre ± half` (separating axis
/// test: the box's axes, the triangle's normal and the nine edge crosses).
fn triangle_meets_box(t: [[f64; 3]; 3], centre: [f64; 3], half: f64) -> bool {
    let v = t.map(|p| sub(p, centre));
    let e = [sub(v[1], v[0]), sub(v[2], v[1]), sub(v[0], v[2])];
    let separated = |axis: [f64; 3]| {
        let r = half * (axis[0].abs() + axis[1].abs() + axis[2].abs());
        let p = v.map(|x| dot(x, axis));
        let (lo, hi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        lo > r || hi < -r
    };
    let unit = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    if unit.iter().any(|&a| separated(a)) || separated(cross(e[0], e[1])) {
        return false;
    }
    !unit.iter().any(|&u| e.iter().any(|&ed| separated(cross(u, ed))))
}

/// The surface's triangles binned by the xy-cells of a grid their
/// bounding boxes overlap: what a vertical ray can cross.
struct Columns {
    size: f64,
    bins: HashMap<[i64; 2], Vec<u32>>,
}

impl Columns {
    fn new(surface: &Surface, size: f64) -> Self {
        let mut bins: HashMap<[i64; 2], Vec<u32>> = HashMap::default();
        for (t, tri) in surface.triangles.iter().enumerate() {
            let p = tri.map(|v| surface.vertices[v as usize]);
            let lo = [0, 1].map(|a| (p[0][a].min(p[1][a]).min(p[2][a]) / size).floor() as i64);
            let hi = [0, 1].map(|a| (p[0][a].max(p[1][a]).max(p[2][a]) / size).floor() as i64);
            for i in lo[0]..=hi[0] {
                for j in lo[1]..=hi[1] {
                    bins.entry([i, j]).or_default().push(t as u32);
                }
            }
        }
        Columns { size, bins }
    }

    /// The triangles a vertical ray through `p` can cross.
    fn at(&self, p: [f64; 3]) -> &[u32] {
        let key = [(p[0] / self.size).floor() as i64, (p[1] / self.size).floor() as i64];
        self.bins.get(&key).map_or(&[], |v| v.as_slice())
    }
}

/// Whether `p` is inside the closed outward `surface`: the parity of the
/// crossings of a ray along +z through `triangles` (those of its column;
/// the caller keeps `p` off the surface's edges by the shifted root cube).
fn inside(surface: &Surface, triangles: &[u32], p: [f64; 3]) -> bool {
    let mut crossings = 0;
    for &t in triangles {
        let q = surface.triangles[t as usize].map(|v| surface.vertices[v as usize]);
        let d = |a: [f64; 3], b: [f64; 3]| (a[0] - p[0]) * (b[1] - p[1]) - (a[1] - p[1]) * (b[0] - p[0]);
        let s = [d(q[0], q[1]), d(q[1], q[2]), d(q[2], q[0])];
        if !(s.iter().all(|&x| x > 0.0) || s.iter().all(|&x| x < 0.0)) {
            continue;
        }
        let n = cross(sub(q[1], q[0]), sub(q[2], q[0]));
        let z = q[0][2] - (n[0] * (p[0] - q[0][0]) + n[1] * (p[1] - q[0][1])) / n[2];
        if z > p[2] {
            crossings += 1;
        }
    }
    crossings % 2 == 1
}

/// Meshes the inside of `surface` (closed, outward) by the leaves of an
/// octree of depth at most `max_depth` (1..=10) refined toward the surface
/// (see the module docs).
pub fn octree(surface: &Surface, max_depth: usize) -> Result<(PolyMesh, OctreeReport), Error> {
    if !(1..=10).contains(&max_depth) {
        return Err(ParamError::new("meshing.max_depth", max_depth, "must lie in 1..=10").into());
    }
    let d = max_depth as u32;
    let (lo, hi) = surface.bounding_box();
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    // a root cube a little larger than the box, shifted off the surface
    let size = extent * 1.0731;
    let origin = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]) - 0.5 * size - 0.00713 * size * (a as f64 + 1.0));
    let finest = size / (1u64 << d) as f64;
    let units = |depth: u32| 1i64 << (d - depth);
    let position = |c: [i64; 3]| [0, 1, 2].map(|a| origin[a] + c[a] as f64 * finest);
    let box_of = |o: &Octant| {
        let half = 0.5 * units(o.depth) as f64 * finest;
        let c = position(o.corner);
        ([c[0] + half, c[1] + half, c[2] + half], half)
    };
    // refine toward the surface; each cell keeps the triangles it meets
    let all: Vec<u32> = (0..surface.triangles.len() as u32).collect();
    let mut leaves: HashMap<Octant, bool> = HashMap::default(); // leaf -> crossed
    let mut stack = vec![(Octant { depth: 0, corner: [0; 3] }, all.clone())];
    while let Some((o, tris)) = stack.pop() {
        let (centre, half) = box_of(&o);
        let met: Vec<u32> = tris
            .into_iter()
            .filter(|&t| {
                triangle_meets_box(surface.triangles[t as usize].map(|v| surface.vertices[v as usize]), centre, half)
            })
            .collect();
        if met.is_empty() || o.depth == d {
            leaves.insert(o, !met.is_empty());
            continue;
        }
        for corner in cube_corners(o.corner, units(o.depth + 1)) {
            stack.push((Octant { depth: o.depth + 1, corner }, met.clone()));
        }
    }
    // the leaf holding a finest-unit point
    let leaf_at = |leaves: &HashMap<Octant, bool>, p: [i64; 3]| -> Option<Octant> {
        let n = 1i64 << d;
        if p.iter().any(|&x| x < 0 || x >= n) {
            return None;
        }
        (0..=d)
            .map(|depth| Octant { depth, corner: p.map(|x| x - x.rem_euclid(units(depth))) })
            .find(|o| leaves.contains_key(o))
    };
    // 2:1 balance across faces
    loop {
        let mut split: Vec<Octant> = Vec::new();
        for o in leaves.keys() {
            let u = units(o.depth);
            for a in 0..3 {
                for side in [-1i64, 1] {
                    // the finer neighbours touch the side at unit distance
                    let mut p = o.corner;
                    p[a] += if side < 0 { -1 } else { u };
                    for s in 0..4i64 {
                        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
                        let mut q = p;
                        q[b] += if s & 1 == 1 { u - 1 } else { 0 };
                        q[c] += if s & 2 == 2 { u - 1 } else { 0 };
                        if let Some(n) = leaf_at(&leaves, q) {
                            if n.depth > o.depth + 1 {
                                split.push(*o);
                            }
                        }
                    }
                }
            }
        }
        if split.is_empty() {
            break;
        }
        split.sort();
        split.dedup();
        for o in split {
            let Some(crossed) = leaves.remove(&o) else { continue };
            for corner in cube_corners(o.corner, units(o.depth + 1)) {
                let child = Octant { depth: o.depth + 1, corner };
                let (centre, half) = box_of(&child);
                let meets = crossed
                    && surface
                        .triangles
                        .iter()
                        .any(|t| triangle_meets_box(t.map(|v| surface.vertices[v as usize]), centre, half));
                leaves.insert(child, meets);
            }
        }
    }
    // keep the leaves the surface crosses and those inside
    let columns = Columns::new(surface, finest * 4.0);
    let mut sorted: Vec<(Octant, bool)> = leaves.iter().map(|(o, c)| (*o, *c)).collect();
    sorted.sort();
    let mut report = OctreeReport { leaves_by_depth: vec![0; d as usize + 1], ..Default::default() };
    let kept: Vec<Octant> = sorted
        .iter()
        .filter(|(o, crossed)| *crossed || inside(surface, columns.at(box_of(o).0), box_of(o).0))
        .map(|(o, _)| *o)
        .collect();
    report.crossing = sorted.iter().filter(|(_, c)| *c).count();
    report.dropped = sorted.len() - kept.len();
    let kept_set: HashSet<Octant> = kept.iter().copied().collect();
    // which sides of the kept leaves meet finer kept leaves (split into
    // the four squares of those leaves)
    let split_side = |o: &Octant, a: usize, side: i64| -> bool {
        let u = units(o.depth);
        if u == 1 {
            return false;
        }
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let mut probe = o.corner;
        probe[a] += if side == 0 { -1 } else { u };
        (0..4).any(|s: i64| {
            let mut q = probe;
            q[b] += (s & 1) * (u / 2);
            q[c] += ((s >> 1) & 1) * (u / 2);
            leaf_at(&leaves, q).is_some_and(|n| n.depth > o.depth && kept_set.contains(&n))
        })
    };
    // nodes: the corners of the kept leaves, and the corners of the squares
    // of split sides (a square's corner no kept leaf has still bounds it)
    let mut node_ids: HashMap<[i64; 3], u32> = HashMap::default();
    let mut nodes: Vec<[f64; 3]> = Vec::new();
    let mut add = |c: [i64; 3], node_ids: &mut HashMap<[i64; 3], u32>| {
        node_ids.entry(c).or_insert_with(|| {
            nodes.push(position(c));
            nodes.len() as u32 - 1
        });
    };
    let mut splits: Vec<[bool; 6]> = Vec::with_capacity(kept.len());
    for o in &kept {
        let u = units(o.depth);
        for c in cube_corners(o.corner, u) {
            add(c, &mut node_ids);
        }
        let mut sides = [false; 6];
        for a in 0..3 {
            for side in [0i64, 1] {
                sides[2 * a + side as usize] = split_side(o, a, side);
                if sides[2 * a + side as usize] {
                    let (b, c) = ((a + 1) % 3, (a + 2) % 3);
                    for s in 0..3i64 {
                        for r in 0..3i64 {
                            let mut q = o.corner;
                            q[a] += side * u;
                            q[b] += s * (u / 2);
                            q[c] += r * (u / 2);
                            add(q, &mut node_ids);
                        }
                    }
                }
            }
        }
        splits.push(sides);
    }
    // a square's loop: its corners and every node on its edges, in order
    let square_loop = |corner: [i64; 3], a: usize, u: i64| -> Vec<u32> {
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let at = |s: i64, r: i64| {
            let mut p = corner;
            p[b] += s;
            p[c] += r;
            p
        };
        let mut lp = Vec::new();
        let walk = [(at(0, 0), b, 1i64), (at(u, 0), c, 1), (at(u, u), b, -1), (at(0, u), c, -1)];
        for (start, axis, dir) in walk {
            for step in 0..u {
                let mut p = start;
                p[axis] += dir * step;
                if let Some(&id) = node_ids.get(&p) {
                    lp.push(id);
                }
            }
        }
        lp
    };
    let mut cells = Vec::with_capacity(kept.len());
    for (o, sides) in kept.iter().zip(&splits) {
        report.leaves_by_depth[o.depth as usize] += 1;
        let u = units(o.depth);
        let mut faces = Vec::new();
        for a in 0..3 {
            let (b, c) = ((a + 1) % 3, (a + 2) % 3);
            for side in [0i64, 1] {
                let mut base = o.corner;
                base[a] += side * u;
                if sides[2 * a + side as usize] {
                    let h = u / 2;
                    for s in 0..4i64 {
                        let mut q = base;
                        q[b] += (s & 1) * h;
                        q[c] += ((s >> 1) & 1) * h;
                        faces.push(square_loop(q, a, h));
                    }
                } else {
                    faces.push(square_loop(base, a, u));
                }
            }
        }
        cells.push(Cell::Polyhedron(faces));
    }
    // (conforming by construction; a simulation validates it)
    let mesh = PolyMesh::from_cells(nodes, &cells)?;
    Ok((mesh, report))
}
