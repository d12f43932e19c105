//! The elements a cut looks at.
//!
//! A cut along a plane changes only elements near it, but finding them
//! takes a pass over the whole mesh (every element's node list, one heap
//! list each). A caller that knows which elements hold each node (the
//! simulation does: its sparse pattern lists them) can name a superset
//! instead, [`CutScope::listed`], and every search of the cut then visits
//! only those, plus the elements the cut appends. The listed elements
//! must be every element holding a node within [`cut_reach`] of the plane:
//! every element a cut splits, repairs, keeps whole, saves for its rollback
//! or separates holds such a node (its nodes lie within its diameter of
//! the plane, or of an element that reaches the plane's rounding band), so
//! the cut is the same as over the whole mesh.

use super::split::on_plane_band;
use crate::mesh::PolyMesh;

/// The elements a cut looks at: the whole mesh, or a sorted list made
/// before the cut together with every element appended since.
#[derive(Clone, Copy, Debug)]
pub struct CutScope<'a> {
    /// The listed elements, sorted (`None`: all).
    listed: Option<&'a [u32]>,
    /// Elements from this id on are appended and always looked at.
    appended: usize,
}

impl<'a> CutScope<'a> {
    /// Every element of the mesh.
    pub fn whole() -> Self {
        CutScope { listed: None, appended: 0 }
    }

    /// The sorted `listed` elements of `mesh`, which must include every
    /// element holding a node within [`cut_reach`] of the cut's plane, and
    /// the elements appended to `mesh` from now on.
    pub fn listed(mesh: &PolyMesh, listed: &'a [u32]) -> Self {
        debug_assert!(listed.windows(2).all(|w| w[0] < w[1]), "listed elements sorted and distinct");
        CutScope { listed: Some(listed), appended: mesh.elements.len() }
    }

    /// The elements in scope that `mesh` holds now, in increasing order.
    pub(crate) fn elements(&self, mesh: &PolyMesh) -> impl Iterator<Item = usize> + 'a {
        let now = mesh.elements.len();
        let (listed, appended) = match self.listed {
            Some(listed) => (listed, self.appended.min(now)),
            None => (&[][..], 0),
        };
        listed.iter().map(|&e| e as usize).filter(move |&e| e < appended).chain(appended..now)
    }
}

/// The distance (m) from a cut's plane within which a node's elements must
/// be listed in a [`CutScope`]: the largest element diameter of `mesh`
/// (`max_diameter`, m) plus the plane's rounding band, with a margin of a
/// hundredth for rounding.
pub fn cut_reach(mesh: &PolyMesh, max_diameter: f64) -> f64 {
    1.01 * (max_diameter + on_plane_band(mesh))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::meshing::box_tet;

    #[test]
    fn a_listed_scope_adds_the_appended_elements_and_drops_removed_ones() {
        let mut mesh = box_tet([0.0; 3], [1.0; 3], [2, 1, 1]).unwrap();
        let n = mesh.elements.len();
        let listed = [1u32, 3, (n - 1) as u32];
        let scope = CutScope::listed(&mesh, &listed);
        assert_eq!(scope.elements(&mesh).collect::<Vec<_>>(), vec![1, 3, n - 1]);
        let extra = mesh.elements[0].clone();
        mesh.elements.push(extra);
        assert_eq!(scope.elements(&mesh).collect::<Vec<_>>(), vec![1, 3, n - 1, n]);
        mesh.elements.truncate(n - 1);
        assert_eq!(scope.elements(&mesh).collect::<Vec<_>>(), vec![1, 3]);
        assert_eq!(CutScope::whole().elements(&mesh).count(), n - 1);
    }
}
