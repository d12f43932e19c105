//! The elements a cut looks at.
//!
//! A cut along a plane changes only elements near it, but finding them
//! takes a pass over the whole mesh (every element's node list, one heap
//! list each). A caller that knows which elements hold each node (the
//! simulation does: its sparse pattern lists them) can name a superset
//! instead, [`CutScope::listed`], and every search of the cut then visits
//! only those, plus the elements the cut appends.
//!
//! The listed elements must be every element holding a node in the cut's
//! [`Reach`]: a node whose distance from the plane, and for a polygon from
//! the polygon's bounding box, is at most the largest diameter of the
//! elements holding it (plus the plane's rounding band; an upper bound of
//! those diameters will do, see [`node_diameters`]). Every element a cut
//! splits, repairs, keeps whole, saves for its rollback or separates holds
//! such a node:
//! - an element that straddles the plane or reaches its rounding band has
//!   every node within its own diameter (plus the band) of the plane, and a
//!   neighbour sharing a node with it holds that node;
//! - a polygon's cut changes only elements whose section meets the polygon
//!   (every node within its diameter of the polygon), their neighbours
//!   across crossed edges, the users of faces in the plane that meet the
//!   polygon and the elements holding nodes inside it.
//!
//! So the cut is the same as over the whole mesh.

use rayon::prelude::*;

use super::split::on_plane_band;
use crate::mesh::{Plane, PolyMesh};

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
    /// element holding a node in the cut's [`Reach`], and the elements
    /// appended to `mesh` from now on.
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

/// Elements per task of [`node_diameters`]: each task keeps its own
/// array of the nodes' diameters.
const DIAMETER_TASK: usize = 8192;

/// For every node of `mesh`, the largest diameter of the elements holding
/// it (m; 0 for a node no element holds). Runs of elements in parallel,
/// each raising its own array, merged by the largest value (the same
/// values on any number of threads): the first cut of a body computes it,
/// and on bunny_100k one thread took 16-22 ms, most of it waiting on
/// every element's node list in memory.
pub fn node_diameters(mesh: &PolyMesh) -> Vec<f64> {
    let n = mesh.nodes.len();
    let raised = |mut out: Vec<f64>, e: usize| {
        raise(mesh, e, mesh.element_diameter(e), &mut out);
        out
    };
    let larger = |mut a: Vec<f64>, b: Vec<f64>| {
        a.iter_mut().zip(b).for_each(|(a, b)| *a = a.max(b));
        a
    };
    (0..mesh.elements.len())
        .into_par_iter()
        .fold_chunks(DIAMETER_TASK, || vec![0.0; n], raised)
        .reduce(|| vec![0.0; n], larger)
}

/// Raises `diameters` (see [`node_diameters`]) to the diameters of the
/// `elements` of `mesh` (after they changed), growing it to the mesh's
/// node count: an upper bound stays one. (The elements' diameters are
/// found in parallel, then their nodes raised: a maximum, the same in any
/// order.)
pub fn raise_node_diameters(
    mesh: &PolyMesh,
    elements: impl IntoParallelIterator<Item = usize>,
    diameters: &mut Vec<f64>,
) {
    diameters.resize(mesh.nodes.len(), 0.0);
    let sized: Vec<(usize, f64)> = elements.into_par_iter().map(|e| (e, mesh.element_diameter(e))).collect();
    sized.into_iter().for_each(|(e, d)| raise(mesh, e, d, diameters));
}

/// Raises the diameters of element `e`'s nodes to its diameter `d`.
fn raise(mesh: &PolyMesh, e: usize, d: f64, diameters: &mut [f64]) {
    for &v in &mesh.elements[e].nodes {
        diameters[v as usize] = diameters[v as usize].max(d);
    }
}

/// The nodes whose elements a [`CutScope`] must list (see the module
/// docs): those within reach of the cut's plane and, for a polygon, of
/// the polygon's bounding box, the reach of a node being the largest
/// diameter of the elements holding it plus the plane's rounding band,
/// with a margin of a hundredth for rounding.
#[derive(Clone, Copy, Debug)]
pub struct Reach {
    plane: Plane,
    /// The rounding band of the plane (m, [`on_plane_band`]).
    band: f64,
    /// The polygon's bounding box (m), if any.
    bounds: Option<([f64; 3], [f64; 3])>,
}

impl Reach {
    /// The reach of a cut of `mesh` along the whole `plane`.
    pub fn of_plane(mesh: &PolyMesh, plane: &Plane) -> Self {
        Reach { plane: *plane, band: on_plane_band(mesh), bounds: None }
    }

    /// The reach of a cut of `mesh` with `polygon`, which lies in `plane`.
    pub fn of_polygon(mesh: &PolyMesh, plane: &Plane, polygon: &[[f64; 3]]) -> Self {
        Reach { bounds: Some(cleave_kernels::vec3::bounding_box(polygon)), ..Self::of_plane(mesh, plane) }
    }

    /// Whether a node at `x` held by elements no larger than `diameter`
    /// (m) is in reach (never for a position that is not a number).
    pub fn contains(&self, x: [f64; 3], diameter: f64) -> bool {
        let r = 1.01 * (diameter + self.band);
        let in_slab = self.plane.distance(x).abs() <= r;
        in_slab && self.bounds.is_none_or(|(lo, hi)| (0..3).all(|k| lo[k] - r <= x[k] && x[k] <= hi[k] + r))
    }

    /// The elements of `mesh` holding a node in reach, in increasing order,
    /// by a pass over the whole mesh (for callers without a node-to-element
    /// map); `diameters` as [`node_diameters`] gives them.
    pub fn elements(&self, mesh: &PolyMesh, diameters: &[f64]) -> Vec<u32> {
        // (a node past `diameters` is taken to be in reach)
        let diameter = |v: usize| diameters.get(v).copied().unwrap_or(f64::INFINITY);
        let inside: Vec<bool> = mesh.nodes.iter().enumerate().map(|(v, &x)| self.contains(x, diameter(v))).collect();
        (0..mesh.elements.len() as u32)
            .filter(|&e| mesh.elements[e as usize].nodes.iter().any(|&v| inside[v as usize]))
            .collect()
    }
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

    /// The runs' arrays merged in parallel give the element-by-element
    /// raise's values, on any number of threads.
    #[test]
    fn node_diameters_of_parallel_runs_equal_the_element_by_element_raise() {
        let mut mesh = box_tet([0.0; 3], [1.0; 3], [20, 20, 20]).unwrap();
        assert!(mesh.elements.len() > 4 * DIAMETER_TASK, "several runs");
        // (nodes moved a little, so that a node's elements differ in size)
        for (i, p) in mesh.nodes.iter_mut().enumerate() {
            p.iter_mut().enumerate().for_each(|(d, x)| *x += 0.01 * (((i * 7919 + d * 31) % 13) as f64 / 13.0 - 0.5));
        }
        let mut one_by_one = Vec::new();
        raise_node_diameters(&mesh, 0..mesh.elements.len(), &mut one_by_one);
        assert_eq!(node_diameters(&mesh), one_by_one);
        let single = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        assert_eq!(single.install(|| node_diameters(&mesh)), one_by_one);
        let spread = one_by_one.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &d| (lo.min(d), hi.max(d)));
        assert!(spread.1 > 1.05 * spread.0, "the diameters differ: {spread:?}");
    }

    #[test]
    fn a_polygon_reaches_only_the_elements_near_it() {
        // 10 x 10 x 10 cells of 0.1 m: the diameter of every tetrahedron is
        // the cell's diagonal, about 0.173 m
        let mesh = box_tet([0.0; 3], [1.0; 3], [10, 10, 10]).unwrap();
        let diameters = node_diameters(&mesh);
        assert!(diameters.iter().all(|&d| (d - 0.1 * 3f64.sqrt()).abs() < 1e-12));
        let plane = Plane { point: [0.55, 0.0, 0.0], normal: [1.0, 0.0, 0.0] };
        let square = [[0.55, 0.0, 0.0], [0.55, 0.2, 0.0], [0.55, 0.2, 0.2], [0.55, 0.0, 0.2]];
        let (slab, near) = (Reach::of_plane(&mesh, &plane), Reach::of_polygon(&mesh, &plane, &square));
        let d = diameters[0];
        // in reach: within a diameter of the plane, and of the polygon's box
        assert!(slab.contains([0.55 + 0.99 * d, 0.9, 0.9], d) && !slab.contains([0.55 + 1.1 * d, 0.5, 0.5], d));
        assert!(near.contains([0.55, 0.2 + 0.99 * d, 0.1], d) && !near.contains([0.55, 0.2 + 1.1 * d, 0.1], d));
        assert!(!near.contains([f64::NAN; 3], d));
        let (slab, near) = (slab.elements(&mesh, &diameters), near.elements(&mesh, &diameters));
        // every element meeting the polygon, fewer than the plane's slab holds
        assert!(near.iter().all(|e| slab.binary_search(e).is_ok()));
        assert!(4 * near.len() < slab.len(), "{} of {}", near.len(), slab.len());
        let meets = |e: usize| {
            let x = mesh.elements[e].nodes.iter().map(|&v| mesh.nodes[v as usize]);
            x.clone().any(|p| p[0] < 0.55)
                && x.clone().any(|p| p[0] > 0.55)
                && x.clone().all(|p| p[1] < 0.3 && p[2] < 0.3)
        };
        let missing: Vec<usize> =
            (0..mesh.elements.len()).filter(|&e| meets(e) && near.binary_search(&(e as u32)).is_err()).collect();
        assert!(missing.is_empty(), "{missing:?}");
    }
}
