//! A step allocates nothing once the first step of a topology has sized its
//! buffers: counted by a global allocator on the threads that run the
//! steps (the test's and the workers of its own thread pools, each
//! prepared by `cleave::solve::prepare_thread`).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use cleave::material::Material;
use cleave::mesh::Plane;
use cleave::meshing::{box_tet, random_convex};
use cleave::sim::{step_bodies, Collider, FixedRegion, Simulation, SimulationParams, StepStats};
use cleave::solve::SolverKind;

/// Counts allocations (and reallocations) of marked threads while
/// `COUNTING` is set.
struct Counting;

static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    static MARKED: Cell<bool> = const { Cell::new(false) };
}

fn count() {
    if COUNTING.load(Ordering::Relaxed) && MARKED.with(Cell::get) {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
}

// SAFETY: every call is forwarded to the system allocator unchanged.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Held by each test: the counter is global, so the tests of this file
/// take turns.
static ONE_TEST_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// A pool of two threads, marked, whose dense kernels have made their
/// buffers (as a real-time host prepares its threads: see
/// `cleave::solve::prepare_thread`), and started: a worker's first look
/// for work registers it with the work-stealing queues' memory reclaimer
/// (an allocation), which a thread still starting would make while
/// another counts.
fn marked_pool() -> rayon::ThreadPool {
    let start = |_| {
        cleave::solve::prepare_thread();
        MARKED.with(|m| m.set(true));
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).start_handler(start).build().unwrap();
    pool.broadcast(|_| ());
    pool
}

/// Allocations made by `f` on the marked threads.
fn allocations_of(f: impl FnOnce()) -> usize {
    ALLOCATIONS.store(0, Ordering::SeqCst);
    COUNTING.store(true, Ordering::SeqCst);
    f();
    COUNTING.store(false, Ordering::SeqCst);
    ALLOCATIONS.load(Ordering::SeqCst)
}

/// Allocations made by `steps` steps of `sim`.
fn allocations_of_steps(sim: &mut Simulation, steps: usize) -> usize {
    allocations_of(|| {
        for _ in 0..steps {
            sim.step().unwrap();
        }
    })
}

/// A bar of tetrahedra cut once (so mean value polyhedra join them),
/// clamped at one end, one node pinned, resting on a collider it presses
/// into.
fn body(solver: SolverKind) -> Simulation {
    let mesh = box_tet([0.0; 3], [3.0, 1.0, 1.0], [6, 3, 3]).unwrap();
    let params = SimulationParams {
        material: Material::new(1e5, 0.3, 1000.0).unwrap(),
        solver,
        tolerance: 1e-8,
        ..Default::default()
    };
    let mut sim = Simulation::new(mesh, params).unwrap();
    sim.fix(FixedRegion::clamp([-1.0; 3], [1e-3, 2.0, 2.0])).unwrap();
    sim.pin(7, [0.0, 0.0, 0.01]).unwrap();
    sim.add_collider(Collider::new([0.0, 0.0, 0.02], [0.0, 0.0, 1.0], 1e6).unwrap());
    sim.cut_plane(&Plane { point: [1.7, 0.5, 0.5], normal: [1.0, 0.3, 0.2] }).unwrap();
    sim
}

#[test]
fn a_step_allocates_nothing_after_the_first() {
    let _turn = ONE_TEST_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pool = marked_pool();
    MARKED.with(|m| m.set(true));
    // the counter sees an allocation on the pool's threads
    let one = pool.install(|| allocations_of(|| drop(std::hint::black_box(Vec::<u64>::with_capacity(8)))));
    assert_eq!(one, 1, "the counting allocator counts");
    // 112 nodes: Cholesky factorises in the envelope, SparseCholesky as
    // sparse supernodal
    for solver in [SolverKind::Cholesky, SolverKind::SparseCholesky, SolverKind::Cg, SolverKind::CgRest] {
        let mut sim = body(solver);
        pool.install(|| {
            sim.step().unwrap();
            let stats = sim.step().unwrap();
            assert!(stats.contacts > 0, "{solver:?}: the body presses into the collider");
            let n = allocations_of_steps(&mut sim, 5);
            assert_eq!(n, 0, "{solver:?}: five steps allocated {n} times");
        });
        // a cut changes the sizes: its first step may allocate, the next not
        sim.cut_plane(&Plane { point: [0.9, 0.5, 0.5], normal: [1.0, -0.2, 0.1] }).unwrap();
        pool.install(|| {
            sim.step().unwrap();
            let n = allocations_of_steps(&mut sim, 3);
            assert_eq!(n, 0, "{solver:?} after a cut: three steps allocated {n} times");
        });
    }
    // a bar of 576 nodes has too many aggregates for the coarse level to
    // solve their system exactly: its cycle factors and solves a block per
    // group of aggregates, made again every few steps
    let mesh = box_tet([0.0; 3], [3.0, 1.0, 1.0], [15, 5, 5]).unwrap();
    let params = SimulationParams {
        material: Material::new(1e5, 0.3, 1000.0).unwrap(),
        solver: SolverKind::Cg,
        tolerance: 1e-8,
        ..Default::default()
    };
    let mut sim = Simulation::new(mesh, params).unwrap();
    sim.fix(FixedRegion::clamp([-1.0; 3], [1e-3, 2.0, 2.0])).unwrap();
    let pool = marked_pool();
    // which thread factors which of its blocks at a refresh is up to the
    // scheduler: here each thread of a new pool in turn steps alone (the
    // other waits for the body, so that the steps' parallel work is all
    // its own), the first to lock the body its first step and six more,
    // the other six more, so that the other's first dense factors come in
    // counted steps
    let body = std::sync::Mutex::new((sim, false));
    let counts = pool.broadcast(|_| {
        let (sim, stepped) = &mut *body.lock().unwrap();
        if !std::mem::replace(stepped, true) {
            sim.step().unwrap();
        }
        allocations_of_steps(sim, 6)
    });
    assert_eq!(counts, [0, 0], "the larger bar: six steps allocated these many times on each thread");
}

#[test]
fn bodies_stepped_together_allocate_nothing_after_the_first_step() {
    let _turn = ONE_TEST_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pool = marked_pool();
    MARKED.with(|m| m.set(true));
    let mut bodies: Vec<Simulation> = (0..16)
        .map(|i| {
            let mesh = random_convex([0.0, 0.0, 0.1], [0.5, 0.5, 0.6], 3 + i % 4, i as u64).unwrap();
            let mut sim = Simulation::new(mesh, SimulationParams::default()).unwrap();
            sim.add_collider(Collider::new([0.0; 3], [0.0, 0.0, 1.0], 1e6).unwrap());
            sim
        })
        .collect();
    let mut stats = vec![StepStats::default(); bodies.len()];
    pool.install(|| {
        step_bodies(&mut bodies, &mut stats).unwrap();
        let n = allocations_of(|| {
            for _ in 0..5 {
                step_bodies(&mut bodies, &mut stats).unwrap();
            }
        });
        assert_eq!(n, 0, "five steps of 16 bodies allocated {n} times");
    });
}
