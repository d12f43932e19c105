//! Meshing a closed surface by slicing it with a regular grid
//! (kaufmann2008 §10, Fig. 5).
//!
//! Every grid cell inside the surface stays a hexahedron. A cell the
//! surface passes through becomes the exact polyhedra `cell ∩ inside`: its
//! faces are the surface triangles clipped to the cell and, on each of its
//! six squares, the part of the square inside the surface. Several pieces
//! in one cell (two ears through it) become several elements. Pieces
//! smaller than a fraction of a cell are merged into the face neighbour
//! they share the largest face with.
//!
//! **Exact conformity.** Every point is named by what it lies on: a grid
//! vertex, a surface vertex, a surface edge crossing a grid plane, or a
//! surface triangle crossing a grid line. Its position is computed from
//! that name alone, so every cell that meets it gets the same node, and
//! every side test against a grid plane gives the same answer in every
//! cell. The grid is shifted off the surface's vertices; a configuration
//! that is still degenerate (a surface edge through a grid line) shifts it
//! again.
//!
//! **Inside.** The squares' inside parts come from the surface crossings
//! of the grid lines: walking a line, every crossing enters or leaves the
//! solid (the sign of the triangle normal along the line), so the status of
//! every piece of a line is exact and agrees with the clipped triangles.

use rustc_hash::FxHashMap as HashMap;

use cleave_kernels::vec3::{cross, dot, norm, sub};

use crate::io::Surface;
use crate::mesh::{Cell, PolyMesh};
use crate::param::ParamError;
use crate::Error;

/// What a point lies on, besides grid planes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Feature {
    /// Nothing: a grid vertex.
    Grid,
    /// A surface vertex.
    Vertex(u32),
    /// A surface edge (lower id first).
    Edge(u32, u32),
    /// The inside of a surface triangle.
    Triangle(u32),
}

/// The name of a point: its feature and the grid planes it lies on (plane
/// index per axis, `-1` for none).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct Key {
    feature: Feature,
    planes: [i32; 3],
}

impl Key {
    fn plane_count(&self) -> usize {
        self.planes.iter().filter(|&&p| p >= 0).count()
    }
}

/// A degenerate meeting of the surface and the grid (shift and retry).
struct Degenerate;

/// The regular grid: origin (m), cell size (m), cells per axis.
struct Grid {
    origin: [f64; 3],
    h: f64,
    cells: [i32; 3],
}

impl Grid {
    /// Coordinate of plane `i` of axis `a` (m).
    fn plane(&self, a: usize, i: i32) -> f64 {
        self.origin[a] + i as f64 * self.h
    }
}

/// How [`grid_slice`] slices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SliceOptions {
    /// Pieces smaller than this fraction of a cell's volume are merged
    /// into a face neighbour (default 0.05).
    pub merge_below: f64,
    /// Surface simplification, as a fraction of a cell (default 0: exact
    /// pieces). Exact pieces keep every surface vertex, and points a hair
    /// apart where the surface passes close to a grid plane or line: nodes
    /// of tiny mass and nearly soft elements for the nodal families. With
    /// `simplify > 0` the surface inside a cell is replaced by a fan over
    /// its boundary loop on the cell's faces from its centroid, and points of
    /// those loops closer than `simplify` cells to another are dropped
    /// (martin2008's way: coarse elements, with the exact surface embedded
    /// in them). The boundary then approximates the surface to about the
    /// cell's curvature error; patches with several boundary loops (a thin
    /// part through a cell) stay exact.
    pub simplify: f64,
}

impl Default for SliceOptions {
    fn default() -> Self {
        SliceOptions { merge_below: 0.05, simplify: 0.0 }
    }
}

/// What [`grid_slice`] made.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SliceReport {
    /// Whole hexahedra.
    pub hexahedra: usize,
    /// Cut-out pieces (after merging).
    pub pieces: usize,
    /// Pieces merged into a neighbour.
    pub merged: usize,
    /// Grid shifts needed to avoid degenerate meetings.
    pub shifts: usize,
    /// The grid's cells per axis.
    pub cells: [usize; 3],
}

/// The points of a slicing, named and placed once.
struct Points<'a> {
    surface: &'a Surface,
    normals: Vec<[f64; 3]>,
    grid: &'a Grid,
    ids: HashMap<Key, u32>,
    keys: Vec<Key>,
    positions: Vec<[f64; 3]>,
}

impl Points<'_> {
    /// The position of a point, from its name alone.
    fn place(&self, key: &Key) -> Result<[f64; 3], Degenerate> {
        let g = self.grid;
        let mut p = match key.feature {
            Feature::Grid => [0.0; 3],
            Feature::Vertex(v) => self.surface.vertices[v as usize],
            Feature::Edge(a, b) => {
                let ax = (0..3).find(|&k| key.planes[k] >= 0).ok_or(Degenerate)?;
                let (pa, pb) = (self.surface.vertices[a as usize], self.surface.vertices[b as usize]);
                let t = (g.plane(ax, key.planes[ax]) - pa[ax]) / (pb[ax] - pa[ax]);
                [0, 1, 2].map(|k| pa[k] + t * (pb[k] - pa[k]))
            }
            Feature::Triangle(t) => {
                if key.plane_count() != 2 {
                    return Err(Degenerate);
                }
                let free = (0..3).find(|&k| key.planes[k] < 0).ok_or(Degenerate)?;
                let n = self.normals[t as usize];
                let p0 = self.surface.vertices[self.surface.triangles[t as usize][0] as usize];
                let mut x = [0.0; 3];
                let mut rhs = dot(n, p0);
                for k in 0..3 {
                    if k != free {
                        x[k] = g.plane(k, key.planes[k]);
                        rhs -= n[k] * x[k];
                    }
                }
                x[free] = rhs / n[free];
                x
            }
        };
        for k in 0..3 {
            if key.planes[k] >= 0 {
                p[k] = g.plane(k, key.planes[k]);
            }
        }
        if p.iter().all(|x| x.is_finite()) {
            Ok(p)
        } else {
            Err(Degenerate)
        }
    }

    /// The node id of a point (made on first use) and its position.
    fn node(&mut self, key: Key) -> Result<(u32, [f64; 3]), Degenerate> {
        if let Some(&id) = self.ids.get(&key) {
            return Ok((id, self.positions[id as usize]));
        }
        let p = self.place(&key)?;
        let id = self.positions.len() as u32;
        self.positions.push(p);
        self.keys.push(key);
        self.ids.insert(key, id);
        Ok((id, p))
    }
}

/// A polygon vertex during clipping.
#[derive(Clone, Copy)]
struct ClipVertex {
    key: Key,
    id: u32,
    p: [f64; 3],
}

/// The feature a segment between two points of triangle `t` lies on.
fn join(a: Feature, b: Feature, t: u32) -> Feature {
    match (a, b) {
        (Feature::Vertex(u), Feature::Vertex(w)) => Feature::Edge(u.min(w), u.max(w)),
        (Feature::Vertex(u), Feature::Edge(x, y)) | (Feature::Edge(x, y), Feature::Vertex(u)) if u == x || u == y => {
            Feature::Edge(x, y)
        }
        (Feature::Edge(x, y), Feature::Edge(x2, y2)) if (x, y) == (x2, y2) => Feature::Edge(x, y),
        _ => Feature::Triangle(t),
    }
}

/// Clips `poly` (triangle `t`'s piece) to the side `keep` (`+1`: above,
/// `-1`: below) of plane `i` of axis `a`.
fn clip(
    points: &mut Points,
    poly: &[ClipVertex],
    t: u32,
    a: usize,
    i: i32,
    keep: f64,
) -> Result<Vec<ClipVertex>, Degenerate> {
    let c = points.grid.plane(a, i);
    let side = |v: &ClipVertex| -> Result<i8, Degenerate> {
        if v.key.planes[a] == i {
            return Ok(0);
        }
        let s = keep * (v.p[a] - c);
        if s > 0.0 {
            Ok(1)
        } else if s < 0.0 {
            Ok(-1)
        } else {
            Err(Degenerate)
        }
    };
    let mut out = Vec::with_capacity(poly.len() + 2);
    let n = poly.len();
    for k in 0..n {
        let (p, q) = (poly[k], poly[(k + 1) % n]);
        let (sp, sq) = (side(&p)?, side(&q)?);
        if sp >= 0 {
            out.push(p);
        }
        if sp * sq < 0 {
            let mut planes = [-1; 3];
            for m in 0..3 {
                if p.key.planes[m] == q.key.planes[m] {
                    planes[m] = p.key.planes[m];
                }
            }
            planes[a] = i;
            let key = Key { feature: join(p.key.feature, q.key.feature, t), planes };
            let bad = match key.feature {
                Feature::Edge(..) => key.plane_count() > 1,
                Feature::Triangle(_) => key.plane_count() != 2,
                _ => true,
            };
            if bad {
                return Err(Degenerate);
            }
            let (id, pos) = points.node(key)?;
            out.push(ClipVertex { key, id, p: pos });
        }
    }
    Ok(out)
}

/// A grid square: its axis, its plane along that axis, and its cell
/// indices along the next two axes (cyclically).
type Square = (usize, i32, i32, i32);

/// A grid line: the free axis and the plane indices of the other two axes
/// (in increasing axis order).
type Line = (usize, [i32; 2]);

/// The line through a point on two planes.
fn line_of(key: &Key) -> Line {
    let free = (0..3).find(|&k| key.planes[k] < 0).unwrap_or(0);
    let others: Vec<i32> = (0..3).filter(|&k| k != free).map(|k| key.planes[k]).collect();
    (free, [others[0], others[1]])
}

/// A crossing of a grid line: coordinate along it (m), `+1` entering the
/// solid or `-1` leaving it, and the node.
type Crossing = (f64, i32, u32);

/// Everything one slicing pass computes.
struct Sliced {
    positions: Vec<[f64; 3]>,
    cells: Vec<Cell>,
    volumes: Vec<f64>,
}

/// The volume of a closed polyhedron given by outward face loops (m^3).
fn loops_volume(positions: &[[f64; 3]], faces: &[Vec<u32>]) -> f64 {
    faces
        .iter()
        .map(|f| {
            let p0 = positions[f[0] as usize];
            (1..f.len() - 1)
                .map(|k| dot(p0, cross(positions[f[k] as usize], positions[f[k + 1] as usize])) / 6.0)
                .sum::<f64>()
        })
        .sum()
}

/// A cut-out piece: its face loops, and which of them are surface pieces.
struct Piece {
    faces: Vec<Vec<u32>>,
    surface: Vec<bool>,
}

/// The pieces with their surfaces simplified (see [`SliceOptions`]):
/// a piece whose surface patch has one boundary loop gets a fan over that
/// loop from the patch's area centroid (a new point) instead, and the points of those loops closer than
/// `spacing` (m) to a kept point are dropped from every loop holding them,
/// if they lie on one grid plane (where a cap meets one square's face, so
/// both faces of every element at the point lose it alike and the mesh
/// stays closed and conforming). Points of pieces kept exact (patches with
/// no or several boundary loops) are never dropped.
fn simplified(pieces: Vec<Piece>, points: &Points, positions: &mut Vec<[f64; 3]>, spacing: f64) -> Vec<Piece> {
    // the boundary loop of each piece's surface patch, if it has one
    let caps: Vec<Option<Vec<u32>>> = pieces
        .iter()
        .map(|piece| {
            let edges: Vec<(u32, u32)> = piece
                .faces
                .iter()
                .zip(&piece.surface)
                .filter(|(_, &s)| s)
                .flat_map(|(f, _)| (0..f.len()).map(move |k| (f[k], f[(k + 1) % f.len()])))
                .collect();
            let set: std::collections::HashSet<(u32, u32)> = edges.iter().copied().collect();
            let boundary: Vec<(u32, u32)> = edges.iter().copied().filter(|&(a, b)| !set.contains(&(b, a))).collect();
            match chain_loops(&boundary) {
                Ok(mut loops) if loops.len() == 1 => loops.pop(),
                _ => None,
            }
        })
        .collect();
    // points that stay: grid vertices and every point of an exact piece
    let n = points.positions.len();
    let mut keep = vec![false; n];
    for (piece, cap) in pieces.iter().zip(&caps) {
        for &v in piece.faces.iter().flatten() {
            if cap.is_none() || points.keys[v as usize].feature == Feature::Grid {
                keep[v as usize] = true;
            }
        }
    }
    let cell = |p: [f64; 3]| p.map(|x| (x / spacing).floor() as i64);
    let mut kept: HashMap<[i64; 3], Vec<u32>> = HashMap::default();
    for v in (0..n).filter(|&v| keep[v]) {
        kept.entry(cell(points.positions[v])).or_default().push(v as u32);
    }
    // candidates: the cap loops' points on one grid plane, where a cap
    // meets one square's face (a point on a grid line is where two squares
    // and a cap meet, and dropping it would open the element)
    for v in caps.iter().flatten().flatten() {
        if points.keys[*v as usize].plane_count() != 1 && !keep[*v as usize] {
            keep[*v as usize] = true;
            kept.entry(cell(points.positions[*v as usize])).or_default().push(*v);
        }
    }
    let mut candidates: Vec<u32> = caps.iter().flatten().flatten().copied().filter(|&v| !keep[v as usize]).collect();
    candidates.sort_unstable();
    candidates.dedup();
    let mut dropped = vec![false; n];
    for v in candidates {
        if keep[v as usize] || dropped[v as usize] {
            continue;
        }
        let p = points.positions[v as usize];
        let c = cell(p);
        let near = (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    kept.get(&[c[0] + dx, c[1] + dy, c[2] + dz]).into_iter().flatten().any(|&w| {
                        let q = points.positions[w as usize];
                        (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>() < spacing * spacing
                    })
                })
            })
        });
        if near {
            dropped[v as usize] = true;
        } else {
            keep[v as usize] = true;
            kept.entry(c).or_default().push(v);
        }
    }
    let filter = |lp: &[u32]| -> Vec<u32> { lp.iter().copied().filter(|&v| !dropped[v as usize]).collect() };
    let mut out = Vec::with_capacity(pieces.len());
    for (piece, cap) in pieces.into_iter().zip(caps) {
        let Some(cap) = cap else {
            out.push(piece);
            continue;
        };
        let cap = filter(&cap);
        if cap.len() < 3 {
            continue;
        }
        let mut faces: Vec<Vec<u32>> = piece
            .faces
            .iter()
            .zip(&piece.surface)
            .filter(|(_, &s)| !s)
            .map(|(f, _)| filter(f))
            .filter(|f| f.len() >= 3)
            .collect();
        // the cap: a fan over the loop from the area centroid of the
        // surface patch it replaces
        let (mut area, mut centre) = (0.0, [0.0; 3]);
        for f in piece.faces.iter().zip(&piece.surface).filter(|(_, &s)| s).map(|(f, _)| f) {
            let p0 = points.positions[f[0] as usize];
            for k in 1..f.len() - 1 {
                let (p1, p2) = (points.positions[f[k] as usize], points.positions[f[k + 1] as usize]);
                let a = 0.5 * norm(cross(sub(p1, p0), sub(p2, p0)));
                area += a;
                centre = [0, 1, 2].map(|i| centre[i] + a * (p0[i] + p1[i] + p2[i]) / 3.0);
            }
        }
        if !(area > 0.0) {
            continue;
        }
        let c = positions.len() as u32;
        positions.push(centre.map(|x| x / area));
        faces.extend((0..cap.len()).map(|k| vec![c, cap[k], cap[(k + 1) % cap.len()]]));
        let surface = vec![false; faces.len()];
        out.push(Piece { faces, surface });
    }
    out
}

/// One slicing pass on `grid`; `simplify` (m): see [`simplified`] (0:
/// exact pieces).
fn slice(surface: &Surface, grid: &Grid, simplify: f64) -> Result<Sliced, Degenerate> {
    let normals: Vec<[f64; 3]> = surface
        .triangles
        .iter()
        .map(|t| {
            let p = t.map(|v| surface.vertices[v as usize]);
            cross(sub(p[1], p[0]), sub(p[2], p[0]))
        })
        .collect();
    let mut points =
        Points { surface, normals, grid, ids: HashMap::default(), keys: Vec::new(), positions: Vec::new() };
    // 1. the surface triangles clipped to the cells
    let mut pieces: HashMap<[i32; 3], Vec<Vec<u32>>> = HashMap::default();
    let mut crossings: HashMap<Line, Vec<Crossing>> = HashMap::default();
    let cell_of = |x: f64, a: usize| ((x - grid.origin[a]) / grid.h).floor() as i32;
    for (t, tri) in surface.triangles.iter().enumerate() {
        let t32 = t as u32;
        let start: Vec<ClipVertex> = tri
            .iter()
            .map(|&v| {
                let key = Key { feature: Feature::Vertex(v), planes: [-1; 3] };
                points.node(key).map(|(id, p)| ClipVertex { key, id, p })
            })
            .collect::<Result<_, _>>()?;
        let lo = [0, 1, 2].map(|a| cell_of(start.iter().map(|v| v.p[a]).fold(f64::INFINITY, f64::min), a));
        let hi = [0, 1, 2].map(|a| cell_of(start.iter().map(|v| v.p[a]).fold(f64::NEG_INFINITY, f64::max), a));
        // clip by x slabs, then y, then z: each axis's planes once
        let mut slabs = vec![(lo, start)];
        for a in 0..3 {
            let mut next = Vec::new();
            for (cell, poly) in slabs {
                for i in lo[a]..=hi[a] {
                    let below = clip(&mut points, &poly, t32, a, i, 1.0)?;
                    if below.len() < 3 {
                        continue;
                    }
                    let piece = clip(&mut points, &below, t32, a, i + 1, -1.0)?;
                    if piece.len() >= 3 {
                        let mut c = cell;
                        c[a] = i;
                        next.push((c, piece));
                    }
                }
            }
            slabs = next;
        }
        for (cell, poly) in slabs {
            for v in &poly {
                if v.key.plane_count() == 2 && matches!(v.key.feature, Feature::Triangle(_)) {
                    let (free, others) = line_of(&v.key);
                    let dir = if points.normals[t][free] < 0.0 { 1 } else { -1 };
                    crossings.entry((free, others)).or_default().push((v.p[free], dir, v.id));
                }
            }
            pieces.entry(cell).or_default().push(poly.iter().map(|v| v.id).collect());
        }
    }
    for list in crossings.values_mut() {
        list.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.2.cmp(&y.2)));
        list.dedup_by_key(|c| c.2);
        // the walk along a line must alternate in, out
        let mut w = 0;
        for c in list.iter() {
            w += c.1;
            if !(0..=1).contains(&w) {
                return Err(Degenerate);
            }
        }
        if w != 0 {
            return Err(Degenerate);
        }
    }
    // 2. the inside part of every square a piece touches
    let inside_before = |line: &Line, x: f64| -> i32 {
        crossings.get(line).map_or(0, |l| l.iter().take_while(|c| c.0 < x).map(|c| c.1).sum())
    };
    let grid_node = |points: &mut Points, ijk: [i32; 3]| points.node(Key { feature: Feature::Grid, planes: ijk });
    // squares as (axis, plane, u, v); regions oriented about +axis
    let mut squares: HashMap<Square, Vec<(u32, u32)>> = HashMap::default();
    let mut cell_list: Vec<[i32; 3]> = pieces.keys().copied().collect();
    cell_list.sort();
    for cell in &cell_list {
        for poly in &pieces[cell] {
            for k in 0..poly.len() {
                let (p, q) = (poly[k], poly[(k + 1) % poly.len()]);
                let (kp, kq) = (points.keys[p as usize], points.keys[q as usize]);
                for a in 0..3 {
                    let upper = cell[a] + 1;
                    if kp.planes[a] == upper && kq.planes[a] == upper {
                        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
                        squares.entry((a, upper, cell[b], cell[c])).or_default().push((q, p));
                    }
                }
            }
        }
        // every square of a cell with pieces gets its edge parts
        for a in 0..3 {
            for up in [0, 1] {
                let (b, c) = ((a + 1) % 3, (a + 2) % 3);
                squares.entry((a, cell[a] + up, cell[b], cell[c])).or_default();
            }
        }
    }
    let mut regions: HashMap<Square, Vec<Vec<u32>>> = HashMap::default();
    let mut square_list: Vec<_> = squares.keys().copied().collect();
    square_list.sort();
    for sq in square_list {
        let (a, i, u, v) = sq;
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let mut edges = squares[&sq].clone();
        // the square's sides, counter-clockwise about +a: along +b, +c, -b, -c
        let corner = |s: i32, r: i32| {
            let mut ijk = [0; 3];
            ijk[a] = i;
            ijk[b] = s;
            ijk[c] = r;
            ijk
        };
        let sides = [
            ((u, v), (u + 1, v), b),
            ((u + 1, v), (u + 1, v + 1), c),
            ((u + 1, v + 1), (u, v + 1), b),
            ((u, v + 1), (u, v), c),
        ];
        for (from, to, along) in sides {
            let (p0, p1) = (corner(from.0, from.1), corner(to.0, to.1));
            let (id0, x0) = grid_node(&mut points, p0)?;
            let (id1, x1) = grid_node(&mut points, p1)?;
            let other: Vec<i32> = (0..3).filter(|&k| k != along).map(|k| p0[k]).collect();
            let line: Line = (along, [other[0], other[1]]);
            let (lo, hi) = (x0[along].min(x1[along]), x0[along].max(x1[along]));
            let mut stops: Vec<(f64, u32)> = vec![(x0[along], id0)];
            let mut w = inside_before(&line, lo);
            let mut status = Vec::new();
            let between: Vec<Crossing> = crossings
                .get(&line)
                .map_or(Vec::new(), |l| l.iter().filter(|c| c.0 > lo && c.0 < hi).copied().collect());
            // inside status of the parts in increasing coordinate
            status.push(w);
            for cr in &between {
                w += cr.1;
                status.push(w);
            }
            let forward = x1[along] > x0[along];
            if forward {
                stops.extend(between.iter().map(|c| (c.0, c.2)));
            } else {
                stops.extend(between.iter().rev().map(|c| (c.0, c.2)));
                status.reverse();
            }
            stops.push((x1[along], id1));
            for k in 0..stops.len() - 1 {
                if status[k] > 0 {
                    edges.push((stops[k].1, stops[k + 1].1));
                }
            }
        }
        let loops = chain_loops(&edges)?;
        let loops = if loops.len() > 1 {
            without_holes(loops, &Plane2d { positions: &points.positions, b, c })?
        } else {
            loops
        };
        regions.insert(sq, loops);
    }
    // 3. the pieces of every cell: connected sets of its polygons
    let mut all: Vec<Piece> = Vec::new();
    for cell in &cell_list {
        let surface_polys = pieces[cell].len();
        let mut polys: Vec<Vec<u32>> = pieces[cell].clone();
        for a in 0..3 {
            let (b, c) = ((a + 1) % 3, (a + 2) % 3);
            for up in [0, 1] {
                for lp in &regions[&(a, cell[a] + up, cell[b], cell[c])] {
                    let mut lp = lp.clone();
                    if up == 0 {
                        lp.reverse();
                    }
                    polys.push(lp);
                }
            }
        }
        for comp in components(&polys)? {
            let surface: Vec<bool> = comp.iter().map(|&k| k < surface_polys).collect();
            all.push(Piece { faces: comp.iter().map(|&k| polys[k].clone()).collect(), surface });
        }
    }
    if simplify > 0.0 {
        let mut positions = points.positions.clone();
        all = simplified(all, &points, &mut positions, simplify);
        points.positions = positions;
    }
    let mut cells_out = Vec::new();
    let mut volumes = Vec::new();
    for piece in all {
        volumes.push(loops_volume(&points.positions, &piece.faces));
        cells_out.push(Cell::Polyhedron(piece.faces));
    }
    // 4. whole hexahedra: cells without pieces whose corners are inside
    for i in 0..grid.cells[0] {
        for j in 0..grid.cells[1] {
            let line: Line = (2, [i, j]);
            let w0 = inside_before(&line, f64::NEG_INFINITY);
            debug_assert_eq!(w0, 0);
            for k in 0..grid.cells[2] {
                if pieces.contains_key(&[i, j, k]) || inside_before(&line, grid.plane(2, k)) <= 0 {
                    continue;
                }
                let mut ids = [0u32; 8];
                for (n, (di, dj, dk)) in
                    [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
                        .into_iter()
                        .enumerate()
                {
                    ids[n] = grid_node(&mut points, [i + di, j + dj, k + dk])?.0;
                }
                cells_out.push(Cell::Hex(ids));
                volumes.push(grid.h.powi(3));
            }
        }
    }
    Ok(Sliced { positions: points.positions, cells: cells_out, volumes })
}

/// Chains directed edges into closed loops (each node starts at most one
/// edge).
fn chain_loops(edges: &[(u32, u32)]) -> Result<Vec<Vec<u32>>, Degenerate> {
    let mut next: HashMap<u32, u32> = HashMap::with_capacity_and_hasher(edges.len(), Default::default());
    for &(p, q) in edges {
        if next.insert(p, q).is_some() {
            return Err(Degenerate);
        }
    }
    let mut starts: Vec<u32> = next.keys().copied().collect();
    starts.sort();
    let mut loops = Vec::new();
    for s in starts {
        if !next.contains_key(&s) {
            continue;
        }
        let mut lp = vec![s];
        let mut at = next.remove(&s).ok_or(Degenerate)?;
        while at != s {
            lp.push(at);
            at = next.remove(&at).ok_or(Degenerate)?;
        }
        if lp.len() < 3 {
            return Err(Degenerate);
        }
        loops.push(lp);
    }
    Ok(loops)
}

/// The points of a grid square's plane in its two in-plane coordinates.
struct Plane2d<'a> {
    positions: &'a [[f64; 3]],
    b: usize,
    c: usize,
}

impl Plane2d<'_> {
    /// Point `i` as `[b, c]` coordinates.
    fn at(&self, i: u32) -> [f64; 2] {
        let p = self.positions[i as usize];
        [p[self.b], p[self.c]]
    }
}

/// Twice the signed area of a loop in the plane.
fn signed_area(lp: &[u32], p: &Plane2d) -> f64 {
    (0..lp.len())
        .map(|k| {
            let (a, b) = (p.at(lp[k]), p.at(lp[(k + 1) % lp.len()]));
            a[0] * b[1] - a[1] * b[0]
        })
        .sum()
}

/// Whether segments `a`-`b` and `c`-`d` cross at a point inside both.
fn segments_cross(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    let o = |p: [f64; 2], q: [f64; 2], r: [f64; 2]| (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]);
    let (d1, d2, d3, d4) = (o(a, b, c), o(a, b, d), o(c, d, a), o(c, d, b));
    ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0)) && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
}

/// Whether `q` lies inside the loop `lp` (even-odd rule).
fn point_in_loop(q: [f64; 2], lp: &[u32], p: &Plane2d) -> bool {
    let mut inside = false;
    for k in 0..lp.len() {
        let (a, b) = (p.at(lp[k]), p.at(lp[(k + 1) % lp.len()]));
        if (a[1] > q[1]) != (b[1] > q[1]) && q[0] < a[0] + (q[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]) {
            inside = !inside;
        }
    }
    inside
}

/// Turns the loops of a square's inside part (counter-clockwise outer
/// loops, clockwise holes) into simple faces: each hole is joined to the
/// loop around it by two bridges between existing points, which splits
/// that loop in two. No point is added, so the faces around stay as they
/// are.
fn without_holes(loops: Vec<Vec<u32>>, p: &Plane2d) -> Result<Vec<Vec<u32>>, Degenerate> {
    let (mut outer, holes): (Vec<Vec<u32>>, Vec<Vec<u32>>) = loops.into_iter().partition(|l| signed_area(l, p) > 0.0);
    for hole in holes {
        let q = p.at(hole[0]);
        // the smallest outer loop around the hole
        let host = (0..outer.len())
            .filter(|&k| point_in_loop(q, &outer[k], p))
            .min_by(|&x, &y| signed_area(&outer[x], p).total_cmp(&signed_area(&outer[y], p)))
            .ok_or(Degenerate)?;
        let around = outer.swap_remove(host);
        let others: Vec<&Vec<u32>> =
            outer.iter().chain(std::iter::once(&hole)).chain(std::iter::once(&around)).collect();
        let clear = |a: u32, b: u32, extra: &[(u32, u32)]| {
            let (pa, pb) = (p.at(a), p.at(b));
            others.iter().all(|l| {
                (0..l.len()).all(|k| {
                    let (c, d) = (l[k], l[(k + 1) % l.len()]);
                    [a, b].contains(&c) || [a, b].contains(&d) || !segments_cross(pa, pb, p.at(c), p.at(d))
                })
            }) && extra.iter().all(|&(c, d)| !segments_cross(pa, pb, p.at(c), p.at(d)))
        };
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (i, &o) in around.iter().enumerate() {
            for (j, &h) in hole.iter().enumerate() {
                let (a, b) = (p.at(o), p.at(h));
                pairs.push(((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2), i, j));
            }
        }
        pairs.sort_by(|x, y| x.0.total_cmp(&y.0).then((x.1, x.2).cmp(&(y.1, y.2))));
        let &(_, i, j) = pairs.iter().find(|&&(_, i, j)| clear(around[i], hole[j], &[])).ok_or(Degenerate)?;
        let &(_, k, l) = pairs
            .iter()
            .find(|&&(_, k, l)| k != i && l != j && clear(around[k], hole[l], &[(around[i], hole[j])]))
            .ok_or(Degenerate)?;
        // around[i..=k], hole[l..=j]; and around[k..=i], hole[j..=l]
        let walk = |lp: &[u32], from: usize, to: usize| {
            let mut out = vec![lp[from]];
            let mut at = from;
            while at != to {
                at = (at + 1) % lp.len();
                out.push(lp[at]);
            }
            out
        };
        let mut first = walk(&around, i, k);
        first.extend(walk(&hole, l, j));
        let mut second = walk(&around, k, i);
        second.extend(walk(&hole, j, l));
        outer.push(first);
        outer.push(second);
    }
    Ok(outer)
}

/// Groups polygons into closed surfaces connected through shared edges;
/// every edge of a group must be used exactly twice, once each way.
fn components(polys: &[Vec<u32>]) -> Result<Vec<Vec<usize>>, Degenerate> {
    let mut parent: Vec<usize> = (0..polys.len()).collect();
    fn find(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    let mut by_edge: HashMap<(u32, u32), usize> = HashMap::default();
    for (k, p) in polys.iter().enumerate() {
        for m in 0..p.len() {
            let (a, b) = (p[m], p[(m + 1) % p.len()]);
            if by_edge.insert((a, b), k).is_some() {
                return Err(Degenerate);
            }
        }
    }
    for (&(a, b), &k) in &by_edge {
        let other = *by_edge.get(&(b, a)).ok_or(Degenerate)?;
        let (x, y) = (find(&mut parent, k), find(&mut parent, other));
        parent[x] = y;
    }
    let mut groups: HashMap<usize, Vec<usize>> = HashMap::default();
    for k in 0..polys.len() {
        let r = find(&mut parent, k);
        groups.entry(r).or_default().push(k);
    }
    let mut out: Vec<Vec<usize>> = groups.into_values().collect();
    out.sort();
    Ok(out)
}

/// Meshes the inside of `surface` (closed, outward: see
/// [`crate::surface::prepare`]) by a grid of cell size `cell` (m) (see the
/// module docs and [`SliceOptions`]).
pub fn grid_slice(surface: &Surface, cell: f64, options: &SliceOptions) -> Result<(PolyMesh, SliceReport), Error> {
    let SliceOptions { merge_below, simplify } = *options;
    if !(cell > 0.0 && cell.is_finite()) {
        return Err(ParamError::new("meshing.cell", cell, "must be a finite cell size > 0 (m)").into());
    }
    if !(0.0..0.5).contains(&merge_below) {
        return Err(
            ParamError::new("meshing.merge_below", merge_below, "must lie in [0, 0.5) (fraction of a cell)").into()
        );
    }
    let (lo, hi) = surface.bounding_box();
    let cells_needed = (0..3).map(|a| ((hi[a] - lo[a]) / cell).ceil() + 3.0).fold(1.0, |n, c| n * c);
    if !(cells_needed < 2e9) {
        return Err(
            ParamError::new("meshing.cell", cell, "gives more than 2e9 grid cells over the surface's box").into()
        );
    }
    // shifts off the surface: irrational fractions of a cell
    let shifts = [0.5 + 0.0137, 0.5 + 0.2917, 0.5 + 0.4141, 0.5 - 0.1733, 0.5 + 0.0771, 0.5 - 0.3819];
    for (n, s) in shifts.iter().enumerate() {
        let origin = [0, 1, 2].map(|a| lo[a] - cell * (s + 0.031 * a as f64));
        let cells = [0, 1, 2].map(|a| ((hi[a] - origin[a]) / cell).floor() as i32 + 2);
        let grid = Grid { origin, h: cell, cells };
        match slice(surface, &grid, simplify * cell) {
            Ok(sliced) => {
                let mut report = SliceReport { shifts: n, cells: cells.map(|c| c as usize), ..Default::default() };
                let cells = merge_small(
                    sliced.cells,
                    &sliced.volumes,
                    &sliced.positions,
                    merge_below * cell.powi(3),
                    &mut report,
                );
                report.hexahedra = cells.iter().filter(|c| matches!(c, Cell::Hex(_))).count();
                report.pieces = cells.len() - report.hexahedra;
                // drop the nodes that clipping made and later cut away
                let (positions, cells) = used_nodes_only(sliced.positions, cells);
                // (conforming by construction; `from_cells` checks every
                // element closed and positive, a simulation validates it)
                let mesh = PolyMesh::from_cells(positions, &cells)?;
                return Ok((mesh, report));
            }
            Err(Degenerate) => continue,
        }
    }
    Err(ParamError::new(
        "meshing.cell",
        cell,
        "meets the surface degenerately on every grid shift tried; change it slightly",
    )
    .into())
}

/// The positions the cells use, in order, and the cells renumbered.
fn used_nodes_only(positions: Vec<[f64; 3]>, cells: Vec<Cell>) -> (Vec<[f64; 3]>, Vec<Cell>) {
    let mut id = vec![u32::MAX; positions.len()];
    for c in &cells {
        match c {
            Cell::Hex(h) => h.iter().for_each(|&v| id[v as usize] = 0),
            Cell::Tet(t) => t.iter().for_each(|&v| id[v as usize] = 0),
            Cell::Polyhedron(f) => f.iter().flatten().for_each(|&v| id[v as usize] = 0),
        }
    }
    let mut kept = Vec::new();
    for (i, p) in positions.into_iter().enumerate() {
        if id[i] == 0 {
            id[i] = kept.len() as u32;
            kept.push(p);
        }
    }
    let cells = cells
        .into_iter()
        .map(|c| match c {
            Cell::Hex(h) => Cell::Hex(h.map(|v| id[v as usize])),
            Cell::Tet(t) => Cell::Tet(t.map(|v| id[v as usize])),
            Cell::Polyhedron(f) => {
                Cell::Polyhedron(f.into_iter().map(|l| l.into_iter().map(|v| id[v as usize]).collect()).collect())
            }
        })
        .collect();
    (kept, cells)
}

/// Merges every cell smaller than `min_volume` (m^3) into the face
/// neighbour it shares the largest face area with, smallest first.
fn merge_small(
    cells: Vec<Cell>,
    volumes: &[f64],
    positions: &[[f64; 3]],
    min_volume: f64,
    report: &mut SliceReport,
) -> Vec<Cell> {
    let mut faces: Vec<Option<Vec<Vec<u32>>>> = cells.iter().map(|c| Some(c.face_loops())).collect();
    let mut volume: Vec<f64> = volumes.to_vec();
    let mut grown = vec![false; cells.len()];
    let face_key = |f: &[u32]| {
        let mut k = f.to_vec();
        k.sort_unstable();
        k
    };
    // the faces of the cells that share a node with a small one: the only
    // faces a merge can look up
    let small: Vec<usize> = (0..cells.len()).filter(|&e| volume[e] < min_volume).collect();
    let mut near = vec![false; positions.len()];
    for &e in &small {
        faces[e].iter().flatten().flatten().for_each(|&v| near[v as usize] = true);
    }
    let mut owners: HashMap<Vec<u32>, Vec<usize>> = HashMap::default();
    for (e, fs) in faces.iter().enumerate() {
        for f in fs.iter().flatten().filter(|f| f.iter().all(|&v| near[v as usize])) {
            owners.entry(face_key(f)).or_default().push(e);
        }
    }
    let area = |f: &[u32]| {
        let p0 = positions[f[0] as usize];
        let mut s = [0.0; 3];
        for k in 1..f.len() - 1 {
            let c = cross(sub(positions[f[k] as usize], p0), sub(positions[f[k + 1] as usize], p0));
            s = [s[0] + c[0], s[1] + c[1], s[2] + c[2]];
        }
        0.5 * dot(s, s).sqrt()
    };
    let mut order = small;
    order.sort_by(|&a, &b| volume[a].total_cmp(&volume[b]).then(a.cmp(&b)));
    for e in order {
        if faces[e].is_none() || volume[e] >= min_volume {
            continue;
        }
        let mut best: Option<(usize, f64)> = None;
        for f in faces[e].as_ref().into_iter().flatten() {
            for &n in owners.get(&face_key(f)).into_iter().flatten() {
                if n != e && faces[n].is_some() && best.is_none_or(|(_, a)| area(f) > a) {
                    best = Some((n, area(f)));
                }
            }
        }
        let Some((n, _)) = best else { continue };
        let mine = faces[e].take().unwrap_or_default();
        let theirs = faces[n].take().unwrap_or_default();
        let shared: rustc_hash::FxHashSet<Vec<u32>> =
            mine.iter().map(|f| face_key(f)).filter(|k| theirs.iter().any(|g| face_key(g) == *k)).collect();
        let union: Vec<Vec<u32>> = theirs.into_iter().chain(mine).filter(|f| !shared.contains(&face_key(f))).collect();
        for f in &union {
            for u in owners.get_mut(&face_key(f)).into_iter().flatten() {
                if *u == e {
                    *u = n;
                }
            }
        }
        faces[n] = Some(union);
        volume[n] += volume[e];
        grown[n] = true;
        report.merged += 1;
    }
    // a hexahedron that took in a piece is a polyhedron now
    faces
        .into_iter()
        .zip(cells)
        .zip(grown)
        .filter_map(|((f, c), grown)| match (f, c) {
            (Some(_), c @ Cell::Hex(_)) if !grown => Some(c),
            (Some(f), _) => Some(Cell::Polyhedron(f)),
            (None, _) => None,
        })
        .collect()
}
