//! Closed triangle surfaces as input to meshing: the checks that make a
//! surface bound a solid, and the repairs that are unambiguous.
//!
//! A surface bounds a solid when it is *closed* (every edge has exactly two
//! triangles), *manifold* (the triangles around every vertex form one fan),
//! *consistently oriented* (the two triangles of an edge run through it in
//! opposite directions), *outward* (its enclosed volume is positive) and
//! *free of self-intersections*. [`prepare`] checks these in that order
//! after two repairs with only one possible answer: vertices at the same
//! position are merged, and triangles are flipped to agree with their
//! neighbours and to face outward. Anything else is an error naming the
//! first bad edge, vertex or triangle (1-based, as in the file).

mod intersect;

use std::collections::HashMap;

use cleave_kernels::vec3::{cross, dot, norm, sub};
use thiserror::Error;

use crate::io::Surface;

/// Why a surface does not bound a solid. Triangle and vertex numbers are
/// 1-based, as in OBJ files.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum SurfaceError {
    /// No triangles.
    #[error("the surface has no triangles")]
    Empty,
    /// A triangle with a repeated vertex or no area.
    #[error("triangle {triangle} is degenerate (a repeated vertex or no area)")]
    Degenerate {
        /// The triangle (1-based).
        triangle: usize,
    },
    /// An edge with one triangle: the surface has a hole.
    #[error("the surface is open: edge {a}-{b} of triangle {triangle} has no neighbour")]
    Open {
        /// The edge's vertices (1-based).
        a: usize,
        /// The edge's vertices (1-based).
        b: usize,
        /// The triangle (1-based).
        triangle: usize,
    },
    /// An edge with more than two triangles.
    #[error("the surface is not manifold: edge {a}-{b} has {count} triangles (first: {triangle})")]
    NonManifoldEdge {
        /// The edge's vertices (1-based).
        a: usize,
        /// The edge's vertices (1-based).
        b: usize,
        /// How many triangles share it.
        count: usize,
        /// The first of them (1-based).
        triangle: usize,
    },
    /// A vertex whose triangles form more than one fan.
    #[error("the surface is not manifold at vertex {vertex}: its triangles form {fans} separate fans")]
    NonManifoldVertex {
        /// The vertex (1-based).
        vertex: usize,
        /// Number of fans.
        fans: usize,
    },
    /// No orientation makes two triangles agree on their shared edges.
    #[error("the surface is not orientable: triangle {triangle} cannot agree with its neighbours")]
    NonOrientable {
        /// The triangle (1-based).
        triangle: usize,
    },
    /// Two triangles cross.
    #[error("the surface intersects itself: triangles {first} and {second} cross")]
    SelfIntersecting {
        /// The triangles (1-based).
        first: usize,
        /// The triangles (1-based).
        second: usize,
    },
}

/// What [`prepare`] repaired.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SurfaceReport {
    /// Vertices merged into an earlier one at the same position.
    pub merged_vertices: usize,
    /// Triangles flipped to agree with their neighbours or to face outward.
    pub flipped_triangles: usize,
    /// Connected pieces of the surface.
    pub components: usize,
    /// Enclosed volume after the repairs (m^3).
    pub volume: f64,
    /// Area (m^2).
    pub area: f64,
}

/// Checks and repairs `surface` (see the module docs): returns the surface
/// with merged vertices (unused ones dropped, order kept) and outward
/// triangles, or the first problem found.
pub fn prepare(surface: &Surface) -> Result<(Surface, SurfaceReport), SurfaceError> {
    if surface.triangles.is_empty() {
        return Err(SurfaceError::Empty);
    }
    let mut report = SurfaceReport::default();
    let (vertices, remap) = merge_duplicates(&surface.vertices, &surface.triangles);
    report.merged_vertices = surface.vertices.len() - vertices.len();
    let mut triangles: Vec<[u32; 3]> = surface.triangles.iter().map(|t| t.map(|v| remap[v as usize])).collect();
    for (t, tri) in triangles.iter().enumerate() {
        let p = tri.map(|v| vertices[v as usize]);
        if tri[0] == tri[1]
            || tri[1] == tri[2]
            || tri[0] == tri[2]
            || norm(cross(sub(p[1], p[0]), sub(p[2], p[0]))) == 0.0
        {
            return Err(SurfaceError::Degenerate { triangle: t + 1 });
        }
    }
    let neighbours = edge_neighbours(&triangles)?;
    check_vertex_fans(&triangles, &neighbours, vertices.len())?;
    let (flipped, components) = orient(&mut triangles, &neighbours, &vertices)?;
    report.flipped_triangles = flipped;
    report.components = components;
    if let Some((a, b)) = intersect::first_crossing(&vertices, &triangles) {
        return Err(SurfaceError::SelfIntersecting { first: a + 1, second: b + 1 });
    }
    report.volume = enclosed_volume(&vertices, &triangles);
    report.area = triangles
        .iter()
        .map(|t| {
            let p = t.map(|v| vertices[v as usize]);
            0.5 * norm(cross(sub(p[1], p[0]), sub(p[2], p[0])))
        })
        .sum();
    Ok((Surface { vertices, triangles }, report))
}

/// Enclosed volume of a closed, outward surface (m^3), by the divergence
/// theorem over its triangles.
pub fn enclosed_volume(vertices: &[[f64; 3]], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let p = t.map(|v| vertices[v as usize]);
            dot(p[0], cross(p[1], p[2])) / 6.0
        })
        .sum()
}

/// Merges vertices at bit-identical positions (the first one stays) and
/// drops vertices of no triangle; returns the kept positions in order and
/// the new id of every old vertex.
fn merge_duplicates(vertices: &[[f64; 3]], triangles: &[[u32; 3]]) -> (Vec<[f64; 3]>, Vec<u32>) {
    let mut used = vec![false; vertices.len()];
    for t in triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let mut first: HashMap<[u64; 3], u32> = HashMap::new();
    let mut kept = Vec::new();
    let mut remap = vec![u32::MAX; vertices.len()];
    for (i, p) in vertices.iter().enumerate() {
        if !used[i] {
            continue;
        }
        // +0.0 and -0.0 are the same position
        let key = p.map(|x| (x + 0.0).to_bits());
        remap[i] = *first.entry(key).or_insert_with(|| {
            kept.push(*p);
            kept.len() as u32 - 1
        });
    }
    (kept, remap)
}

/// For every triangle and each of its edges `(t[i], t[i+1])`, the other
/// triangle on that edge; an error for an edge with one or more than two.
fn edge_neighbours(triangles: &[[u32; 3]]) -> Result<Vec<[u32; 3]>, SurfaceError> {
    // the triangles on each edge, with the edge's place in each
    type Users = Vec<(u32, u8)>;
    let mut edges: HashMap<(u32, u32), Users> = HashMap::with_capacity(triangles.len() * 3 / 2);
    for (t, tri) in triangles.iter().enumerate() {
        for i in 0..3 {
            let (a, b) = (tri[i], tri[(i + 1) % 3]);
            edges.entry((a.min(b), a.max(b))).or_default().push((t as u32, i as u8));
        }
    }
    let mut out = vec![[u32::MAX; 3]; triangles.len()];
    // report the edge of the lowest triangle first, whatever the hash order
    let mut sorted: Vec<((u32, u32), Users)> = edges.into_iter().collect();
    sorted.sort_by_key(|(e, users)| (users[0].0, *e));
    for ((a, b), users) in sorted {
        let (a1, b1, triangle) = (a as usize + 1, b as usize + 1, users[0].0 as usize + 1);
        match users.len() {
            1 => return Err(SurfaceError::Open { a: a1, b: b1, triangle }),
            2 => {
                let ((t, i), (s, j)) = (users[0], users[1]);
                out[t as usize][i as usize] = s;
                out[s as usize][j as usize] = t;
            }
            count => return Err(SurfaceError::NonManifoldEdge { a: a1, b: b1, count, triangle }),
        }
    }
    Ok(out)
}

/// Checks that the triangles around every vertex form one fan.
fn check_vertex_fans(triangles: &[[u32; 3]], neighbours: &[[u32; 3]], n: usize) -> Result<(), SurfaceError> {
    let mut around: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (t, tri) in triangles.iter().enumerate() {
        for &v in tri {
            around[v as usize].push(t as u32);
        }
    }
    let mut seen: Vec<u32> = Vec::new();
    let mut stack: Vec<u32> = Vec::new();
    for (v, tris) in around.iter().enumerate() {
        // walk across edges through v from the first triangle
        seen.clear();
        stack.clear();
        stack.push(tris[0]);
        while let Some(t) = stack.pop() {
            if seen.contains(&t) {
                continue;
            }
            seen.push(t);
            let tri = triangles[t as usize];
            for i in 0..3 {
                if tri[i] as usize == v || tri[(i + 1) % 3] as usize == v {
                    stack.push(neighbours[t as usize][i]);
                }
            }
        }
        if seen.len() != tris.len() {
            let fans = 1 + usize::from(seen.len() < tris.len());
            return Err(SurfaceError::NonManifoldVertex { vertex: v + 1, fans });
        }
    }
    Ok(())
}

/// Flips triangles so that neighbours agree (breadth first from the lowest
/// triangle of each component) and every component encloses a positive
/// volume; returns the number flipped and the number of components.
fn orient(
    triangles: &mut [[u32; 3]],
    neighbours: &[[u32; 3]],
    vertices: &[[f64; 3]],
) -> Result<(usize, usize), SurfaceError> {
    let n = triangles.len();
    let mut component = vec![u32::MAX; n];
    let mut flip = vec![false; n];
    let mut components = 0u32;
    let mut queue = std::collections::VecDeque::new();
    // `flip[t]` makes t agree with the seed; agreement on an edge (a, b) of
    // t means the neighbour runs b -> a
    let runs = |tri: [u32; 3], flipped: bool, a: u32, b: u32| {
        let t = if flipped { [tri[0], tri[2], tri[1]] } else { tri };
        (0..3).any(|i| t[i] == a && t[(i + 1) % 3] == b)
    };
    let mut members: Vec<Vec<u32>> = Vec::new();
    for seed in 0..n {
        if component[seed] != u32::MAX {
            continue;
        }
        component[seed] = components;
        members.push(vec![seed as u32]);
        queue.push_back(seed);
        while let Some(t) = queue.pop_front() {
            let tri = if flip[t] { [triangles[t][0], triangles[t][2], triangles[t][1]] } else { triangles[t] };
            for i in 0..3 {
                let (a, b) = (tri[i], tri[(i + 1) % 3]);
                let s = neighbours[t][(0..3)
                    .find(|&j| {
                        let o = triangles[t];
                        let (x, y) = (o[j], o[(j + 1) % 3]);
                        (x == a && y == b) || (x == b && y == a)
                    })
                    .expect("edge of its own triangle")] as usize;
                let need = !runs(triangles[s], false, b, a);
                if component[s] == u32::MAX {
                    component[s] = components;
                    flip[s] = need;
                    members[components as usize].push(s as u32);
                    queue.push_back(s);
                } else if flip[s] != need {
                    return Err(SurfaceError::NonOrientable { triangle: s + 1 });
                }
            }
        }
        components += 1;
    }
    for (t, f) in flip.iter().enumerate() {
        if *f {
            triangles[t].swap(1, 2);
        }
    }
    for m in &members {
        let tris: Vec<[u32; 3]> = m.iter().map(|&t| triangles[t as usize]).collect();
        if enclosed_volume(vertices, &tris) < 0.0 {
            for &t in m {
                triangles[t as usize].swap(1, 2);
                flip[t as usize] = !flip[t as usize];
            }
        }
    }
    Ok((flip.iter().filter(|f| **f).count(), components as usize))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The unit cube's surface, outward.
    pub(crate) fn cube() -> Surface {
        let vertices = (0..8).map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64]).collect();
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let triangles = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        Surface { vertices, triangles }
    }

    /// Triangles rotated to start at their lowest vertex (same orientation).
    fn canonical(s: &Surface) -> Vec<[u32; 3]> {
        s.triangles
            .iter()
            .map(|t| {
                let i = (0..3).min_by_key(|&i| t[i]).unwrap();
                [t[i], t[(i + 1) % 3], t[(i + 2) % 3]]
            })
            .collect()
    }

    #[test]
    fn the_cube_is_a_closed_outward_surface() {
        let (s, r) = prepare(&cube()).unwrap();
        assert_eq!(r.flipped_triangles, 0);
        assert_eq!(r.components, 1);
        assert!((r.volume - 1.0).abs() < 1e-15 && (r.area - 6.0).abs() < 1e-15);
        assert_eq!(s, cube());
    }

    #[test]
    fn flipped_triangles_and_an_inside_out_surface_are_repaired() {
        let mut s = cube();
        s.triangles[3].swap(0, 1);
        s.triangles[7].swap(1, 2);
        let (fixed, r) = prepare(&s).unwrap();
        assert_eq!(r.flipped_triangles, 2);
        assert_eq!(canonical(&fixed), canonical(&cube()));
        for t in &mut s.triangles {
            t.swap(1, 2);
        }
        let (fixed, r) = prepare(&s).unwrap();
        assert_eq!(r.flipped_triangles, 10);
        assert!((r.volume - 1.0).abs() < 1e-15);
        assert_eq!(canonical(&fixed), canonical(&cube()));
    }

    #[test]
    fn duplicate_vertices_are_merged() {
        let mut s = cube();
        // triangle soup: every triangle its own three vertices
        let soup: Vec<[f64; 3]> = s.triangles.iter().flat_map(|t| t.map(|v| s.vertices[v as usize])).collect();
        s.triangles = (0..s.triangles.len() as u32).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        s.vertices = soup;
        let (fixed, r) = prepare(&s).unwrap();
        assert_eq!((fixed.vertices.len(), r.merged_vertices), (8, 28));
        assert!((r.volume - 1.0).abs() < 1e-15);
    }

    #[test]
    fn bad_surfaces_give_one_clear_error_each() {
        let mut open = cube();
        open.triangles.pop();
        let e = prepare(&open).unwrap_err();
        assert!(matches!(e, SurfaceError::Open { .. }), "{e}");
        assert!(e.to_string().contains("open"), "{e}");

        let mut fin = cube();
        fin.vertices.push([0.5, 0.5, 2.0]);
        fin.triangles.push([4, 5, 8]);
        fin.triangles.push([5, 4, 8]);
        let e = prepare(&fin).unwrap_err();
        assert!(matches!(e, SurfaceError::NonManifoldEdge { a: 5, b: 6, count: 4, .. }), "{e}");

        // two cubes sharing one corner: manifold edges, a pinched vertex
        let mut two = cube();
        let shifted: Vec<[f64; 3]> = cube().vertices.iter().map(|p| [p[0] + 1.0, p[1] + 1.0, p[2] + 1.0]).collect();
        let base = two.vertices.len() as u32;
        two.vertices.extend(shifted.iter().skip(1));
        for t in cube().triangles {
            two.triangles.push(t.map(|v| if v == 0 { 7 } else { base + v - 1 }));
        }
        let e = prepare(&two).unwrap_err();
        assert!(matches!(e, SurfaceError::NonManifoldVertex { vertex: 8, .. }), "{e}");

        // a second cube poking through the first
        let mut crossing = cube();
        let base = crossing.vertices.len() as u32;
        crossing.vertices.extend(cube().vertices.iter().map(|p| [p[0] + 0.5, p[1] + 0.25, p[2] + 0.25]));
        crossing.triangles.extend(cube().triangles.iter().map(|t| t.map(|v| v + base)));
        let e = prepare(&crossing).unwrap_err();
        assert!(matches!(e, SurfaceError::SelfIntersecting { .. }), "{e}");

        let mut flat = cube();
        flat.triangles[0] = [0, 0, 1];
        assert_eq!(prepare(&flat).unwrap_err(), SurfaceError::Degenerate { triangle: 1 });
        assert_eq!(prepare(&Surface::default()).unwrap_err(), SurfaceError::Empty);
    }

    #[test]
    fn the_projective_plane_is_not_orientable() {
        // the six-vertex triangulation of the real projective plane: closed
        // and manifold, but no orientation makes neighbours agree
        let vertices = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.1, 0.3],
            [0.2, 1.0, 0.7],
            [-0.9, 0.4, 0.1],
            [0.3, -1.0, 0.5],
            [0.1, 0.2, 1.0],
        ];
        let triangles = vec![
            [0, 1, 2],
            [0, 2, 3],
            [0, 3, 4],
            [0, 4, 5],
            [0, 5, 1],
            [1, 2, 4],
            [2, 3, 5],
            [3, 4, 1],
            [4, 5, 2],
            [5, 1, 3],
        ];
        let e = prepare(&Surface { vertices, triangles }).unwrap_err();
        assert!(matches!(e, SurfaceError::NonOrientable { .. }), "{e}");
    }
}
