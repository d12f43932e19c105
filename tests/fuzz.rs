//! Fuzzing of every reader (`.mesh`, `.msh`, `.node`/`.ele`, `.vtu`,
//! `.obj`, `.stl`) and of the scene parser, on stable Rust.
//!
//! Each target starts from a seed corpus: small meshes written in the
//! target's format (a box of hexahedra, and the first tetrahedra of the
//! shipped `assets/bunny_5k.mesh`), the shipped scenes for the parser. Each
//! input is a seed changed by one to four mutations drawn from a seeded
//! generator (bit flips, special bytes, deleted, repeated or spliced
//! ranges, a number replaced by a hostile one such as `99999999999`,
//! `-1`, `nan` or `1e308`, truncation). Every input must end in `Ok` or
//! an error, and:
//!
//! - never panic (caught and reported with the input, which is kept under
//!   `target/fuzz-findings/`);
//! - never take more than [`SLOW`] (a hang);
//! - never make one allocation larger than `64 x` the input's size plus
//!   1 MiB (a count in the file trusted before the data backing it).
//!
//! Inputs per target: `CLEAVE_FUZZ_INPUTS`, default 25,000 (about 5 s per
//! target in release). The generator's seeds are fixed, so every run
//! draws the same inputs: the default keeps the test run short, and a
//! longer campaign (`CLEAVE_FUZZ_INPUTS=1000000`) reaches further. Findings
//! fixed in the readers are kept as regression inputs under
//! `tests/fuzz/<target>/` and run first, every time.

use std::alloc::{GlobalAlloc, Layout, System};

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rand_chacha::rand_core::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

use cleave::io::{
    read_mesh, read_surface, read_vtu_frame, write_gmsh, write_medit, write_tetgen, write_vtu, VtuFields,
};
use cleave::mesh::{Cell, PolyMesh};

thread_local! {
    /// The largest single allocation request of this thread since the last
    /// reset (bytes). Per thread, so the targets run side by side; the
    /// readers parse on the calling thread.
    static LARGEST: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

fn record(size: usize) {
    // `try_with`: nothing is recorded while the thread is being torn down
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
}

struct Watching;

// SAFETY: forwards to the system allocator; only records sizes.
unsafe impl GlobalAlloc for Watching {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        record(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        record(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Watching = Watching;

/// An input slower than this is a hang.
const SLOW: Duration = Duration::from_secs(2);

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn inputs() -> usize {
    std::env::var("CLEAVE_FUZZ_INPUTS").ok().and_then(|v| v.parse().ok()).unwrap_or(25_000)
}

/// Numbers that break readers which trust them.
const HOSTILE: &[&str] = &[
    "0",
    "-1",
    "1",
    "2",
    "3",
    "4",
    "8",
    "99999999999",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "2147483648",
    "-2147483649",
    "1e308",
    "-1e308",
    "1e-320",
    "nan",
    "inf",
    "-inf",
    "-0",
    "0x10",
    "1.5",
    "",
];

/// Bytes that change the structure of text formats.
const SPECIAL: &[u8] = b"\n\r\t #-+.e0<>\"=/\0\xff";

/// One mutation of `input`, `others` for splices.
fn mutate(rng: &mut ChaCha8Rng, input: &mut Vec<u8>, others: &[Vec<u8>]) {
    let below = |rng: &mut ChaCha8Rng, n: usize| if n == 0 { 0 } else { (rng.next_u64() % n as u64) as usize };
    let n = input.len();
    match below(rng, 8) {
        0 if n > 0 => {
            let i = below(rng, n);
            input[i] ^= 1 << below(rng, 8);
        }
        1 if n > 0 => {
            let i = below(rng, n);
            input[i] = SPECIAL[below(rng, SPECIAL.len())];
        }
        2 if n > 0 => {
            let (a, len) = (below(rng, n), 1 + below(rng, 64));
            input.drain(a..(a + len).min(n));
        }
        3 if n > 0 => {
            let (a, len) = (below(rng, n), 1 + below(rng, 256));
            let piece: Vec<u8> = input[a..(a + len).min(n)].to_vec();
            let at = below(rng, n + 1);
            input.splice(at..at, piece);
        }
        4 | 5 => {
            // a number replaced by a hostile one
            let starts: Vec<usize> = (0..n)
                .filter(|&i| input[i].is_ascii_digit() && (i == 0 || !input[i - 1].is_ascii_alphanumeric()))
                .collect();
            if let Some(&s) = starts.get(below(rng, starts.len().max(1))) {
                let e =
                    (s..n).find(|&i| !(input[i].is_ascii_alphanumeric() || b".-+".contains(&input[i]))).unwrap_or(n);
                let hostile = HOSTILE[below(rng, HOSTILE.len())].as_bytes();
                input.splice(s..e, hostile.iter().copied());
            }
        }
        6 if !others.is_empty() => {
            let other = &others[below(rng, others.len())];
            let (a, b) = (below(rng, n + 1), below(rng, other.len() + 1));
            input.truncate(a);
            input.extend_from_slice(&other[b..]);
        }
        _ => input.truncate(below(rng, n + 1)),
    }
}

/// What a target reads: it writes the input into its files and reads them.
struct Target {
    seeds: Vec<Vec<u8>>,
    /// Reads the input (already written to `file`); returns whether it was
    /// accepted.
    read: fn(&Path) -> bool,
    /// The input's file name in the work folder.
    file: &'static str,
}

/// A small mesh of each kind the seeds carry: a box of tetrahedra, and the
/// first tetrahedra of the shipped bunny with their nodes.
fn seed_meshes() -> Vec<(Vec<[f64; 3]>, Vec<Cell>)> {
    let cube = cleave::meshing::box_tet([0.0; 3], [1.0, 2.0, 1.0], [1, 1, 1]).unwrap();
    let tet = |n: &[u32]| Cell::Tet([n[0], n[1], n[2], n[3]]);
    let cube_cells = cube.elements.iter().map(|e| tet(&e.nodes)).collect();
    let bunny = read_mesh(&root().join("assets/bunny_5k.mesh")).unwrap();
    let tets: Vec<Vec<u32>> = bunny.elements.iter().take(6).map(|e| e.nodes.to_vec()).collect();
    let mut used: Vec<u32> = tets.iter().flatten().copied().collect();
    used.sort_unstable();
    used.dedup();
    let renumber = |v: u32| used.binary_search(&v).unwrap() as u32;
    let bunny_cells =
        tets.iter().map(|t| Cell::Tet([renumber(t[0]), renumber(t[1]), renumber(t[2]), renumber(t[3])])).collect();
    let bunny_nodes = used.iter().map(|&v| bunny.nodes[v as usize]).collect();
    vec![(cube.nodes.clone(), cube_cells), (bunny_nodes, bunny_cells)]
}

/// The seeds of a mesh format: each seed mesh written by `write` into `dir`.
fn mesh_seeds(dir: &Path, file: &str, write: impl Fn(&Path, &[[f64; 3]], &[Cell])) -> Vec<Vec<u8>> {
    seed_meshes()
        .iter()
        .map(|(nodes, cells)| {
            let path = dir.join(file);
            write(&path, nodes, cells);
            std::fs::read(&path).unwrap()
        })
        .collect()
}

fn accepts_mesh(path: &Path) -> bool {
    read_mesh(path).is_ok_and(|m| m.validate().is_ok())
}

fn targets(dir: &Path, name: &'static str) -> Target {
    let scenes = || -> Vec<Vec<u8>> {
        let mut files: Vec<PathBuf> =
            std::fs::read_dir(root().join("scenes")).unwrap().map(|e| e.unwrap().path()).collect();
        files.sort();
        files.iter().map(|p| std::fs::read(p).unwrap()).collect()
    };
    match name {
        "medit" => Target {
            seeds: mesh_seeds(dir, "seed.mesh", |p, n, c| write_medit(p, n, c).unwrap()),
            read: accepts_mesh,
            file: "input.mesh",
        },
        "gmsh" => Target {
            seeds: mesh_seeds(dir, "seed.msh", |p, n, c| write_gmsh(p, n, c).unwrap()),
            read: accepts_mesh,
            file: "input.msh",
        },
        "tetgen-node" | "tetgen-ele" => {
            // the other file of the pair stays the bunny seed's
            let (nodes, cells) = seed_meshes().pop().unwrap();
            write_tetgen(&dir.join("input.node"), &nodes, &cells).unwrap();
            let ext = if name == "tetgen-node" { "node" } else { "ele" };
            Target {
                seeds: vec![std::fs::read(dir.join(format!("input.{ext}"))).unwrap()],
                read: accepts_mesh,
                file: if ext == "node" { "input.node" } else { "input.ele" },
            }
        }
        "vtu" => Target {
            seeds: mesh_seeds(dir, "seed.vtu", |p, nodes, cells| {
                let mesh = PolyMesh::from_cells(nodes.to_vec(), cells).unwrap();
                let u = vec![[0.25, 0.0, -0.5]; nodes.len()];
                let stress = vec![1.5; mesh.elements.len()];
                let fields = VtuFields {
                    point_vectors: vec![("displacement", &u)],
                    cell_scalars: vec![("von_mises", &stress)],
                    cell_ints: vec![],
                };
                write_vtu(p, &mesh, nodes, &fields).unwrap()
            }),
            read: |p| {
                let frame = read_vtu_frame(p).is_ok();
                accepts_mesh(p) || frame
            },
            file: "input.vtu",
        },
        "obj" | "stl" => {
            let file = if name == "obj" { "input.obj" } else { "input.stl" };
            let mut seeds = Vec::new();
            if name == "obj" {
                // the shipped bunny's first 120 vertices and the triangles
                // among them, and a closed tetrahedron
                let text = std::fs::read_to_string(root().join("assets/bunny.obj")).unwrap();
                let within = |l: &str| l.split_whitespace().skip(1).all(|v| v.parse::<usize>().is_ok_and(|i| i <= 120));
                let (mut v, mut head) = (0, String::new());
                for l in text.lines() {
                    let keep = match l.split_whitespace().next() {
                        Some("v") => (v < 120).then(|| v += 1).is_some(),
                        Some("f") => within(l),
                        _ => false,
                    };
                    if keep {
                        head.push_str(l);
                        head.push('\n');
                    }
                }
                seeds.push(head.into_bytes());
                seeds.push(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n".to_vec());
            } else {
                let tri = "facet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n  vertex 0 1 0\n endloop\nendfacet\n";
                seeds.push(format!("solid s\n{tri}{tri}endsolid s\n").into_bytes());
                let mut binary = vec![0u8; 80];
                binary.extend_from_slice(&2u32.to_le_bytes());
                for _ in 0..2 {
                    for v in [0.0f32, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
                        binary.extend_from_slice(&v.to_le_bytes());
                    }
                    binary.extend_from_slice(&[0, 0]);
                }
                seeds.push(binary);
            }
            Target {
                seeds,
                // accepted when read; the repair and checks run on it too
                read: |p| read_surface(p).map(|s| cleave::surface::prepare(&s).is_ok()).is_ok(),
                file,
            }
        }
        "scene" => Target {
            seeds: scenes(),
            read: |p| {
                let text = String::from_utf8_lossy(&std::fs::read(p).unwrap()).into_owned();
                cleave::scene::LoadedScene::parse(p, text).is_ok()
            },
            file: "input.toml",
        },
        _ => unreachable!("no target {name}"),
    }
}

/// Runs one input; returns a finding, if any.
fn run_one(target: &Target, path: &Path, input: &[u8]) -> Result<bool, String> {
    // (a new file each time: ext4 writes a file truncated and rewritten
    // back to the disk when it is closed, which made this fuzzer spend
    // four fifths of its time waiting on the disk)
    let _ = std::fs::remove_file(path);
    std::fs::write(path, input).unwrap();
    LARGEST.with(|l| l.set(0));
    let started = Instant::now();
    let outcome = std::panic::catch_unwind(|| (target.read)(path));
    let (elapsed, largest) = (started.elapsed(), LARGEST.with(std::cell::Cell::get));
    let accepted = outcome.map_err(|p| {
        let message = p.downcast_ref::<String>().cloned().or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()));
        format!("panic: {}", message.unwrap_or_default())
    })?;
    if elapsed > SLOW {
        return Err(format!("hang: {elapsed:?}"));
    }
    let allowed = 64 * input.len() + (1 << 20);
    if largest > allowed {
        return Err(format!("one allocation of {largest} bytes for an input of {} bytes", input.len()));
    }
    Ok(accepted)
}

/// Fuzzes `name`: its regression inputs, then `inputs()` mutated seeds.
fn fuzz(name: &'static str) {
    let work = tempfile::tempdir().unwrap();
    let target = targets(work.path(), name);
    let path = work.path().join(target.file);
    for seed in &target.seeds {
        assert!(run_one(&target, &path, seed).unwrap(), "{name}: a seed is refused");
    }
    let quiet = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let mut findings = Vec::new();
    let regressions = root().join("tests/fuzz").join(name);
    let mut replayed = 0;
    if let Ok(entries) = std::fs::read_dir(&regressions) {
        for entry in entries {
            let input = std::fs::read(entry.unwrap().path()).unwrap();
            replayed += 1;
            if let Err(f) = run_one(&target, &path, &input) {
                findings.push((f, input));
            }
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed ^ name.len() as u64 ^ u64::from(name.as_bytes()[0]));
    let (started, total) = (Instant::now(), inputs());
    let mut accepted = 0;
    for _ in 0..total {
        let mut input = target.seeds[(rng.next_u64() % target.seeds.len() as u64) as usize].clone();
        for _ in 0..1 + rng.next_u64() % 4 {
            mutate(&mut rng, &mut input, &target.seeds);
        }
        match run_one(&target, &path, &input) {
            Ok(ok) => accepted += usize::from(ok),
            Err(f) if findings.len() < 20 => findings.push((f, input)),
            Err(_) => {}
        }
    }
    std::panic::set_hook(quiet);
    let kept = root().join("target/fuzz-findings").join(name);
    for (i, (finding, input)) in findings.iter().enumerate() {
        std::fs::create_dir_all(&kept).unwrap();
        std::fs::write(kept.join(format!("finding_{i}")), input).unwrap();
        eprintln!("{name}: {finding} (input kept as {})", kept.join(format!("finding_{i}")).display());
    }
    println!(
        "{name}: {replayed} regression inputs, {total} mutated inputs ({accepted} accepted) in {:.1} s, {} findings",
        started.elapsed().as_secs_f64(),
        findings.len()
    );
    assert!(findings.is_empty(), "{name}: {} findings, the first: {}", findings.len(), findings[0].0);
}

#[test]
fn medit() {
    fuzz("medit");
}

#[test]
fn gmsh() {
    fuzz("gmsh");
}

#[test]
fn tetgen_node() {
    fuzz("tetgen-node");
}

#[test]
fn tetgen_ele() {
    fuzz("tetgen-ele");
}

#[test]
fn vtu() {
    fuzz("vtu");
}

#[test]
fn obj() {
    fuzz("obj");
}

#[test]
fn stl() {
    fuzz("stl");
}

#[test]
fn scene() {
    fuzz("scene");
}
