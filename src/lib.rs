//! # cleave
//!
//! Elastic solids simulated with finite elements on arbitrary polyhedral
//! elements, so that cutting, fracture and adaptive refinement never need
//! tetrahedral remeshing.
//!
//! The library is the product; the `cleave` program is a thin layer over it.
//! Data flows as follows (see `DESIGN.md`):
//!
//! 1. [`mesh::PolyMesh`]: nodes, global faces with one triangulation each,
//!    elements as closed polyhedra; read by [`io`] or made by [`meshing`].
//! 2. [`store::ElementStore`]: elements batched by vertex count, with their
//!    stiffness matrices and lumped masses.
//! 3. [`assembly::SparsePattern`]: the global sparse structure, built once
//!    per topology, and deterministic parallel assembly.
//! 4. [`solve`]: sparse Cholesky (and iterative solvers).
//! 5. [`sim::Simulation`]: state, constraints and the solve of a step.
//! 6. [`scene`]: TOML scene files that drive all of the above, and
//!    [`output`] for frames and reports.
//!
//! Units are SI throughout: metres, pascals, kilograms, seconds.
//!
//! A body in a host loop: a box of hexahedra dropped onto a plane, cut in
//! two while it falls, its state read back after every step.
//!
//! ```
//! use cleave::mesh::Plane;
//! use cleave::meshing::box_hex;
//! use cleave::sim::{Collider, Simulation, SimulationParams};
//!
//! # fn main() -> Result<(), cleave::Error> {
//! let mesh = box_hex([0.0, 0.0, 0.5], [1.0, 0.5, 1.0], [4, 2, 2])?;
//! let mut sim = Simulation::new(mesh, SimulationParams { dt: 0.01, ..Default::default() })?;
//! sim.add_collider(Collider::new([0.0; 3], [0.0, 0.0, 1.0], 1e6)?);
//! for frame in 0..30 {
//!     if frame == 10 {
//!         sim.cut_plane(&Plane { point: [0.4, 0.25, 0.75], normal: [1.0, 0.0, 0.0] })?;
//!     }
//!     sim.step()?;
//!     let lowest = sim.positions().iter().map(|x| x[2]).fold(f64::INFINITY, f64::min);
//!     assert!(lowest > -0.05, "the plane holds the body (frame {frame}, z = {lowest})");
//! }
//! assert!(sim.mesh().elements.len() > 16, "the cut split the elements it crossed");
//! let stress = sim.von_mises(); // Pa, one per element
//! assert!(stress.iter().all(|s| s.is_finite()));
//! # Ok(())
//! # }
//! ```

// `!(x > 0.0)` is how this crate rejects NaN together with out-of-range
// values; `partial_cmp` would hide that intent.
#![warn(missing_docs)]
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Index loops mirror the formulas (rows, columns, components).
#![allow(clippy::needless_range_loop)]

pub mod assembly;
pub mod checkpoint;
pub mod dg;
pub mod io;
pub mod material;
pub mod mesh;
pub mod meshing;
pub mod output;
pub mod param;
pub mod render;
pub mod scene;
pub mod sim;
pub mod solve;
pub mod store;
pub mod surface;
pub mod topology;

use thiserror::Error;

/// Runs `f` on a thread of the current rayon pool (the caller's thread if
/// it is one) and waits for it. Parallel work started from outside the pool
/// pays a hand-over between threads for every parallel call, from inside
/// none; faer's supernodal factorisation makes thousands of them (on
/// bunny_100k, 2 cores, its parallel numeric Cholesky took 480 ms started
/// from the main thread and 360 ms inside the pool).
pub(crate) fn in_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::join(f, || ()).0
}

/// The room an array sized by a body's topology keeps for the growth cuts
/// bring, as a part of its length: half, when it is first sized and each
/// time a cut outgrows it (a swept blade adds about 2.5 % to bunny_100k's
/// arrays per cut). Growing copies the whole array and faults in its
/// pages, while room never written costs address space only. With an
/// eighth to spare when first sized, the third of six blade cuts across
/// bunny_100k took 32-49 ms where the second took 21-33 (the step
/// system's, the solver's and the coarse level's arrays outgrown), and
/// 24-33 ms with half (AMD EPYC Zen 4, 2 threads, eight runs alternated).
const ROOM: usize = 2;

/// Growths like the one at hand that an array growing fast keeps room
/// for: an array of elements of a vertex count the cuts make (the
/// element store's batches of 5- to 10-vertex parts) starts empty and
/// grows by a third or more with every blade cut, so [`ROOM`] alone had
/// it copied to a larger place at almost every cut, 0.5-1.2 ms each on
/// the rebuild's critical path. Six blade cuts across bunny_100k spent
/// 4.3-5.2 ms growing arrays with [`ROOM`] alone, 3.3-4.0 ms with this
/// and 2.4-3.0 ms with this up to the length (three alternated runs, AMD
/// EPYC Zen 4, the `cleave` program's allocator settings).
const AHEAD: usize = 4;

/// Makes `array`'s capacity at least `len`, with room to spare when it
/// grows: [`ROOM`], or [`AHEAD`] times this growth when that is more, up
/// to `len` itself (an array refined whole, eight times its length, keeps
/// no more than that to spare); a first sizing keeps [`ROOM`].
pub(crate) fn reserve_room<T>(array: &mut Vec<T>, len: usize) {
    if len > array.capacity() {
        let growth = if array.is_empty() { 0 } else { len - array.len() };
        let room = (len / ROOM).max((AHEAD * growth).min(len));
        array.reserve_exact(len + room - array.len());
    }
}

/// Gives `array`, sized elsewhere (a mesh as read), the room
/// [`reserve_room`] gives.
pub(crate) fn keep_room<T>(array: &mut Vec<T>) {
    array.reserve_exact(array.len() / ROOM);
}

/// Sets `array`'s length to `len` (new items `fill`) after
/// [`reserve_room`].
pub(crate) fn resize_with_room<T: Clone>(array: &mut Vec<T>, len: usize, fill: T) {
    reserve_to_write(array, len);
    array.resize(len, fill);
}

/// [`reserve_room`] for `len` items about to be written, their fresh pages
/// mapped at once ([`populate`]).
pub(crate) fn reserve_to_write<T>(array: &mut Vec<T>, len: usize) {
    reserve_room(array, len);
    populate(array, len);
}

/// Fewest fresh pages worth mapping in one call ([`populate`]).
const POPULATE_PAGES: usize = 8;

/// Maps in, in one call, the pages of `array`'s spare capacity that its
/// items up to `len` (at most its capacity) will take. An array a cut
/// grows is written past its old end at once: the kernel maps those fresh
/// pages faster in one `madvise(MADV_POPULATE_WRITE)` (Linux 5.14 on) than
/// at one page fault each. Six blade cuts across bunny_100k, alternated
/// runs (AMD EPYC Zen 4, 2 threads): 2,320 page faults a cut against
/// 1,060 with it, 4 % less CPU time. The contents are untouched; a
/// stretch shorter than [`POPULATE_PAGES`] pages, another system or a
/// kernel that refuses leaves the pages to fault in as they are written.
fn populate<T>(array: &mut Vec<T>, len: usize) {
    #[cfg(target_os = "linux")]
    {
        static PAGE: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
        // SAFETY: `sysconf` only reads a constant of the system
        let page = *PAGE.get_or_init(|| usize::try_from(unsafe { libc::sysconf(libc::_SC_PAGESIZE) }).unwrap_or(0));
        let size = std::mem::size_of::<T>();
        if page == 0 || len <= array.len() || len > array.capacity() {
            return;
        }
        let base = array.as_mut_ptr() as usize;
        let (start, end) = (base + array.len() * size, base + len * size);
        let (first, last) = (start.next_multiple_of(page), end - end % page);
        if last >= first + POPULATE_PAGES * page {
            // SAFETY: the whole pages from `first` to `last` lie within the
            // array's allocation, which `&mut` holds alone; populating maps
            // them writable without writing them (a refusal changes nothing)
            unsafe { libc::madvise(first as *mut libc::c_void, last - first, libc::MADV_POPULATE_WRITE) };
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (array, len);
}

/// `slice` cut into consecutive stretches of the given `lengths` (their sum
/// at most its length), for parallel tasks that each write their own.
pub(crate) fn stretches<T>(slice: &mut [T], lengths: impl IntoIterator<Item = usize>) -> Vec<&mut [T]> {
    let mut rest = slice;
    lengths
        .into_iter()
        .map(|len| {
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(len);
            rest = tail;
            head
        })
        .collect()
}

/// Any failure of cleave, by layer. Every variant names the place.
#[derive(Debug, Error)]
pub enum Error {
    /// A mesh is structurally or geometrically invalid.
    #[error("invalid mesh: {0}")]
    Mesh(#[from] mesh::MeshError),
    /// A file could not be read or written.
    #[error(transparent)]
    Io(#[from] io::IoError),
    /// A parameter is out of its allowed range.
    #[error("invalid parameter {0}")]
    Parameter(#[from] param::ParamError),
    /// A basis could not be built on an element.
    #[error(transparent)]
    Basis(#[from] store::BasisError),
    /// A plane split failed.
    #[error(transparent)]
    Split(#[from] topology::SplitError),
    /// A surface does not bound a solid.
    #[error("invalid surface: {0}")]
    Surface(#[from] surface::SurfaceError),
    /// A linear solve failed.
    #[error("solve failed: {0}")]
    Solve(#[from] solve::SolveError),
    /// A time step failed.
    #[error("step {step}: {source}")]
    Step {
        /// The step that failed (0 for the first).
        step: usize,
        /// Why its solve failed.
        source: solve::SolveError,
    },
    /// An invariant of cleave itself does not hold: a bug, to be reported.
    #[error("internal error (please report): {0}")]
    Internal(String),
}

#[cfg(test)]
mod tests {
    /// Stretches follow one another, empty ones included, and leave the
    /// rest of the slice out.
    #[test]
    fn stretches_cut_consecutive_parts() {
        let mut values = [0; 7];
        for (k, part) in super::stretches(&mut values, [2, 0, 3]).into_iter().enumerate() {
            part.fill(k + 1);
        }
        assert_eq!(values, [1, 1, 3, 3, 3, 0, 0]);
    }

    /// An array sized keeps half its length to spare, so growth within it
    /// stays in place; one outgrown takes half its new length to spare;
    /// new items take the fill, old ones stay; an array sized elsewhere
    /// takes the same room.
    #[test]
    fn arrays_keep_room_for_growth() {
        let mut array: Vec<u32> = Vec::new();
        super::resize_with_room(&mut array, 800, 7);
        assert_eq!((array.len(), array.capacity()), (800, 1200));
        let first = array.as_ptr();
        super::resize_with_room(&mut array, 1200, 8);
        assert_eq!((array.as_ptr(), array.capacity()), (first, 1200), "growth within the room stays in place");
        super::resize_with_room(&mut array, 1300, 9);
        assert_eq!(array.capacity(), 1950);
        assert_eq!((array[799], array[800], array[1199], array[1200], array[1299]), (7, 8, 8, 9, 9));
        super::resize_with_room(&mut array, 10, 0);
        assert_eq!((array.len(), array.capacity()), (10, 1950), "shrinking keeps the memory");
        let mut read = vec![1u8; 300];
        super::keep_room(&mut read);
        assert!(read.capacity() >= 450, "{}", read.capacity());
    }
}
