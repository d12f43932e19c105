//! Mesh repair: orienting every element's faces outward, and welding
//! duplicate nodes. Checks that find what to repair are in
//! [`super::validate`].

use std::collections::HashMap;

use super::{Cell, MeshError, PolyMesh};

impl PolyMesh {
    /// Makes every element's face references consistent and outward.
    ///
    /// Fails when an element is not closed or encloses no volume, or when
    /// two elements overlap across a face.
    pub fn orient(&mut self) -> Result<(), MeshError> {
        for e in 0..self.elements.len() {
            self.orient_element(e)?;
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

    fn orient_element(&mut self, e: usize) -> Result<(), MeshError> {
        let refs = self.elements[e].faces.clone();
        // edge -> faces (local indices) that contain it
        let mut edge_faces: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
        for (k, r) in refs.iter().enumerate() {
            let v = &self.faces[r.face as usize].vertices;
            for i in 0..v.len() {
                let (a, b) = (v[i], v[(i + 1) % v.len()]);
                edge_faces.entry((a.min(b), a.max(b))).or_default().push(k);
            }
        }
        let mut sorted: Vec<_> = edge_faces.iter().collect();
        sorted.sort_unstable_by_key(|(k, _)| **k);
        for (edge, fs) in &sorted {
            if fs.len() != 2 {
                return Err(MeshError::OpenElement { element: e, edge: **edge, count: fs.len() });
            }
        }
        // Breadth-first flip propagation: neighbours must traverse the shared
        // edge in opposite directions.
        let dir = |mesh: &PolyMesh, k: usize, flip: bool, a: u32, b: u32| -> bool {
            let v = &mesh.faces[refs[k].face as usize].vertices;
            let n = v.len();
            let i = v.iter().position(|&x| x == a).expect("edge vertex in loop");
            let forward = v[(i + 1) % n] == b;
            forward != flip
        };
        let mut flip: Vec<Option<bool>> = vec![None; refs.len()];
        flip[0] = Some(!refs[0].outward);
        let mut queue = vec![0usize];
        while let Some(k) = queue.pop() {
            let v = self.faces[refs[k].face as usize].vertices.clone();
            for i in 0..v.len() {
                let (a, b) = (v[i], v[(i + 1) % v.len()]);
                for &other in &edge_faces[&(a.min(b), a.max(b))] {
                    if other == k {
                        continue;
                    }
                    let mine = dir(self, k, flip[k].unwrap(), a, b);
                    let want_flip_other = {
                        let theirs_unflipped = dir(self, other, false, a, b);
                        theirs_unflipped == mine
                    };
                    match flip[other] {
                        None => {
                            flip[other] = Some(want_flip_other);
                            queue.push(other);
                        }
                        Some(f) if f != want_flip_other => {
                            return Err(MeshError::InconsistentOrientation { element: e, edge: (a.min(b), a.max(b)) });
                        }
                        _ => {}
                    }
                }
            }
        }
        for (k, r) in self.elements[e].faces.iter_mut().enumerate() {
            // flip[k] == true means the loop runs against the element's chosen orientation
            r.outward = !flip[k].unwrap_or(false);
        }
        let v = self.element_volume(e);
        if v < 0.0 {
            for r in self.elements[e].faces.iter_mut() {
                r.outward = !r.outward;
            }
        } else if v == 0.0 || v.is_nan() {
            return Err(MeshError::NonPositiveVolume { element: e, volume: v });
        }
        Ok(())
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
