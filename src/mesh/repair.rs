//! Mesh repair: orienting every element's faces outward, and welding
//! duplicate nodes. Checks that find what to repair are in
//! [`super::validate`].

use rayon::prelude::*;

use super::{Cell, MeshError, PolyMesh};

impl PolyMesh {
    /// Makes every element's face references consistent and outward.
    ///
    /// Fails when an element is not closed or encloses no volume, or when
    /// two elements overlap across a face.
    pub fn orient(&mut self) -> Result<(), MeshError> {
        // each element's orientation alone (in parallel), the first error
        // in element order
        let flags: Vec<Result<Vec<bool>, MeshError>> =
            (0..self.elements.len()).into_par_iter().map(|e| self.element_orientation(e)).collect();
        for (e, f) in flags.into_iter().enumerate() {
            for (r, outward) in self.elements[e].faces.iter_mut().zip(f?) {
                r.outward = outward;
            }
        }
        let mut owner: Vec<Option<(usize, bool)>> = vec![None; self.faces.len()];
        for (e, el) in self.elements.iter().enumerate() {
            for r in &el.faces {
                match owner[r.face as usize] {
                    None => owner[r.face as usize] = Some((e, r.outward)),
                    Some((a, out)) if out == r.outward => {
                        return Err(MeshError::OverlappingElements { face: r.face as usize, a, b: e })
                    }
                    _ => {}
                }
            }
        }
        Ok(())
    }

    /// The outward flag of each face reference of element `e` that makes
    /// its faces agree along shared edges and its volume positive.
    fn element_orientation(&self, e: usize) -> Result<Vec<bool>, MeshError> {
        let refs = &self.elements[e].faces;
        // every edge of every face: (edge, face, whether the loop runs it
        // from the lower id to the higher), sorted by edge
        let mut uses: Vec<((u32, u32), u32, bool)> = Vec::new();
        for (k, r) in refs.iter().enumerate() {
            let v = &self.faces[r.face as usize].vertices;
            for i in 0..v.len() {
                let (a, b) = (v[i], v[(i + 1) % v.len()]);
                uses.push(((a.min(b), a.max(b)), k as u32, a < b));
            }
        }
        uses.sort_unstable();
        // each edge has exactly two faces; neighbours[k]: (other face, whether
        // both loops run the shared edge the same way)
        let mut neighbours: Vec<Vec<(u32, bool)>> = vec![Vec::new(); refs.len()];
        for group in uses.chunk_by(|x, y| x.0 == y.0) {
            if group.len() != 2 {
                return Err(MeshError::OpenElement { element: e, edge: group[0].0, count: group.len() });
            }
            let (x, y) = (group[0], group[1]);
            neighbours[x.1 as usize].push((y.1, x.2 == y.2));
            neighbours[y.1 as usize].push((x.1, x.2 == y.2));
        }
        // Breadth-first flip propagation: neighbours must traverse the shared
        // edge in opposite directions, so one running it the same way flips
        let mut flip: Vec<Option<bool>> = vec![None; refs.len()];
        flip[0] = Some(!refs[0].outward);
        let mut queue = vec![0usize];
        while let Some(k) = queue.pop() {
            let mine = flip[k].unwrap_or(false);
            for &(other, same) in &neighbours[k] {
                let want = mine != same;
                match flip[other as usize] {
                    None => {
                        flip[other as usize] = Some(want);
                        queue.push(other as usize);
                    }
                    Some(f) if f != want => {
                        let shared = uses
                            .chunk_by(|x, y| x.0 == y.0)
                            .find(|g| g.iter().any(|u| u.1 as usize == k) && g.iter().any(|u| u.1 == other))
                            .map_or((0, 0), |g| g[0].0);
                        return Err(MeshError::InconsistentOrientation { element: e, edge: shared });
                    }
                    _ => {}
                }
            }
        }
        // flip[k] == true means the loop runs against the element's chosen orientation
        let mut outward: Vec<bool> = (0..refs.len()).map(|k| !flip[k].unwrap_or(false)).collect();
        // the element's volume with these flags, as `element_volume` sums it
        let origin = self.nodes[self.elements[e].nodes[0] as usize];
        let v: f64 = refs
            .iter()
            .zip(&outward)
            .flat_map(|(r, &out)| self.faces[r.face as usize].triangles.iter().map(move |t| (t, out)))
            .map(|(t, out)| {
                let p = t.map(|i| self.nodes[i as usize]);
                let (b, c) = if out { (p[1], p[2]) } else { (p[2], p[1]) };
                cleave_kernels::tet::signed_volume(origin, p[0], b, c)
            })
            .sum();
        if v < 0.0 {
            outward.iter_mut().for_each(|o| *o = !*o);
        } else if v == 0.0 || v.is_nan() {
            return Err(MeshError::NonPositiveVolume { element: e, volume: v });
        }
        Ok(outward)
    }

    /// Merges nodes closer than `rel_tol` times the bounding box diagonal into
    /// the lowest id among them, drops nodes no element uses, and re-shares
    /// faces that became equal. Returns the new id of every old node
    /// (`u32::MAX` for a dropped one).
    pub fn weld(&mut self, rel_tol: f64) -> Result<Vec<u32>, MeshError> {
        let mut target: Vec<usize> = (0..self.nodes.len()).collect();
        for (a, b, _) in self.duplicate_nodes(rel_tol) {
            let root = |t: &[usize], mut x: usize| {
                while t[x] != x {
                    x = t[x];
                }
                x
            };
            let (ra, rb) = (root(&target, a), root(&target, b));
            target[ra.max(rb)] = ra.min(rb);
        }
        for i in 0..target.len() {
            target[i] = target[target[i]];
        }
        let cells: Vec<Cell> = self
            .elements
            .iter()
            .map(|el| {
                Cell::Polyhedron(
                    el.faces
                        .iter()
                        .map(|r| {
                            let mut lp: Vec<u32> = self.faces[r.face as usize]
                                .vertices
                                .iter()
                                .map(|&v| target[v as usize] as u32)
                                .collect();
                            lp.dedup();
                            if lp.len() > 1 && lp.first() == lp.last() {
                                lp.pop();
                            }
                            lp
                        })
                        .filter(|lp| lp.len() >= 3)
                        .collect(),
                )
            })
            .collect();
        let mut used = vec![false; self.nodes.len()];
        for c in &cells {
            if let Cell::Polyhedron(fs) = c {
                for &v in fs.iter().flatten() {
                    used[v as usize] = true;
                }
            }
        }
        let mut new_id = vec![u32::MAX; self.nodes.len()];
        let mut nodes = Vec::new();
        for (i, p) in self.nodes.iter().enumerate() {
            if used[i] {
                new_id[i] = nodes.len() as u32;
                nodes.push(*p);
            }
        }
        let cells: Vec<Cell> = cells
            .into_iter()
            .map(|c| match c {
                Cell::Polyhedron(fs) => Cell::Polyhedron(
                    fs.into_iter().map(|lp| lp.into_iter().map(|v| new_id[v as usize]).collect()).collect(),
                ),
                other => other,
            })
            .collect();
        *self = PolyMesh::from_cells(nodes, &cells)?;
        Ok((0..target.len()).map(|i| new_id[target[i]]).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::super::Cell;
    use super::*;

    #[test]
    fn weld_joins_two_tets_into_shared_face() {
        // two tets sharing a face, but with the face's nodes duplicated
        let nodes = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 1.0, 1.0],
        ];
        let mut m = PolyMesh::from_cells(nodes, &[Cell::Tet([0, 1, 2, 3]), Cell::Tet([4, 5, 6, 7])]).unwrap();
        assert_eq!(m.faces.len(), 8);
        assert!(matches!(m.validate(), Err(MeshError::DuplicateNodes { a: 1, b: 4, .. })));
        let map = m.weld(1e-9).unwrap();
        assert_eq!(map[4], 1);
        assert_eq!(m.nodes.len(), 5);
        assert_eq!(m.faces.len(), 7);
        m.validate().unwrap();
    }
}
