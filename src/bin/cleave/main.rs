//! `cleave`: run scenes, inspect meshes, measure throughput.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod bench;
mod simd;

use cleave::mesh::ValidationOptions;
use cleave::scene::{resume_run, run_scene, LoadedScene, RunOptions};

#[derive(Parser)]
#[command(name = "cleave", version, about = "Elastic solids on polyhedral finite elements")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene file and write frames and summary.json.
    Run {
        /// The scene (TOML).
        scene: PathBuf,
        /// Output folder (default: the scene's output.dir).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Number of steps (default: the scene's simulation.steps).
        #[arg(long)]
        steps: Option<usize>,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Write OUT/checkpoint.bin every N steps (dynamic scenes), to
        /// carry the run on with `cleave resume`.
        #[arg(long, value_name = "N")]
        checkpoint_every: Option<usize>,
    },
    /// Carry a run on from its checkpoint (bit for bit as if it had not
    /// stopped), into the same output folder.
    Resume {
        /// The checkpoint (OUT/checkpoint.bin).
        checkpoint: PathBuf,
        /// Worker threads (default: all cores; results do not depend on it).
        #[arg(long)]
        threads: Option<usize>,
    },
    /// Print counts, volume, bounding box and a validation report of a mesh.
    Info {
        /// A mesh file (.mesh, .msh, .vtu, .node/.ele).
        mesh: PathBuf,
    },
    /// Render every frame of a finished run (its VTU frames) to PNG.
    Render {
        /// The run's output folder.
        dir: PathBuf,
        /// Colour by von Mises stress (with a legend) instead of plain
        /// with cut faces in a second colour.
        #[arg(long)]
        stress: bool,
    },
    /// Run the throughput suite.
    Bench {
        /// Write the report as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Smaller meshes, for a quick check.
        #[arg(long)]
        quick: bool,
        /// Run one part of the suite only.
        #[arg(long, value_enum)]
        only: Option<bench::Group>,
        /// Cap the engine's kernels at this instruction set (default: the
        /// best the machine offers); the `simd` part compares every level
        /// whatever the cap.
        #[arg(long, value_enum)]
        max_simd: Option<bench::MaxSimd>,
    },
}

/// Runs `work` on a pool of `threads` workers (default: all cores). The
/// work runs on a worker itself, so the engine's parallel loops start on
/// the calling worker instead of handing every loop to the pool and
/// sleeping until it is done (a context switch per loop, which cost a small
/// body most of its step).
fn in_pool<T: Send>(threads: Option<usize>, work: impl FnOnce() -> T + Send) -> Result<T, String> {
    if threads == Some(0) {
        return Err("--threads must be at least 1".into());
    }
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads.unwrap_or(0)).build().map_err(|e| e.to_string())?;
    Ok(pool.install(work))
}

fn run(cli: Cli) -> Result<(), String> {
    match cli.command {
        Command::Run { scene, out, steps, threads, checkpoint_every } => {
            let loaded = LoadedScene::load(&scene).map_err(|e| e.to_string())?;
            let opts = RunOptions { out, steps, checkpoint_every };
            let dir = loaded.output_dir(&opts);
            let summary = in_pool(threads, || run_scene(&loaded, &opts))?.map_err(|e| e.to_string())?;
            report(&summary, &dir);
            Ok(())
        }
        Command::Resume { checkpoint, threads } => {
            let summary = in_pool(threads, || resume_run(&checkpoint))?.map_err(|e| e.to_string())?;
            report(&summary, checkpoint.parent().unwrap_or(std::path::Path::new(".")));
            Ok(())
        }
        Command::Render { dir, stress } => {
            let t = std::time::Instant::now();
            let n = cleave::scene::render_run(&dir, stress).map_err(|e| e.to_string())?;
            println!("{}: {n} pictures in {:.2} s", dir.display(), t.elapsed().as_secs_f64());
            Ok(())
        }
        Command::Info { mesh } => {
            let ext = mesh.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
            if matches!(ext.as_deref(), Some("obj" | "stl")) {
                return surface_info(&mesh);
            }
            let m = cleave::io::read_mesh(&mesh).map_err(|e| e.to_string())?;
            let (lo, hi) = m.bounding_box();
            println!("{}", mesh.display());
            println!("  nodes     {}", m.nodes.len());
            println!("  faces     {}", m.faces.len());
            println!("  elements  {}", m.elements.len());
            for (k, n) in m.count_by_vertex_count() {
                println!("    {k:>3} vertices: {n}");
            }
            println!("  volume    {:.9e}", m.total_volume());
            println!(
                "  bbox      [{:.6e}, {:.6e}, {:.6e}] .. [{:.6e}, {:.6e}, {:.6e}]",
                lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
            );
            let adj = m.adjacency();
            let (_, components) = adj.element_components(&m);
            let unused = (0..m.nodes.len()).filter(|&i| adj.node_elements(i).is_empty()).count();
            println!("  components {components}");
            if unused > 0 {
                println!("  note: {unused} node(s) belong to no element (they are held fixed in a simulation)");
            }
            let problems = m.check(&ValidationOptions::default(), 20);
            if problems.is_empty() {
                println!("  validation: ok");
                Ok(())
            } else {
                for p in &problems {
                    println!("  problem: {p}");
                }
                Err(format!("{} problem(s) found (first 20 shown)", problems.len()))
            }
        }
        Command::Bench { json, threads, quick, only, max_simd } => {
            let report = in_pool(threads, || bench::run_suite(quick, only, max_simd))?.map_err(|e| e.to_string())?;
            println!("{}", report.to_table());
            if let Some(path) = json {
                let text = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?;
                cleave::io::write_text(&path, &text).map_err(|e| e.to_string())?;
                println!("report written to {}", path.display());
            }
            Ok(())
        }
    }
}

/// The line a finished run prints.
fn report(summary: &cleave::output::Summary, dir: &std::path::Path) {
    println!(
        "{}: {} nodes, {} elements, {} step(s) in {:.3} s; max displacement {:.6e} m; output in {}",
        summary.scene,
        summary.end.nodes,
        summary.end.elements,
        summary.steps,
        summary.wall_time_total,
        summary.max_displacement,
        dir.display()
    );
    if summary.guard_warnings > 0 {
        println!("  {} guard warning(s); the first: {}", summary.guard_warnings, summary.guard_warnings_listed[0]);
    }
}

/// `cleave info` of a triangle surface: counts, the checks that make it
/// bound a solid, and what was repaired.
fn surface_info(path: &std::path::Path) -> Result<(), String> {
    let raw = cleave::io::read_surface(path).map_err(|e| e.to_string())?;
    println!("{}", path.display());
    println!("  vertices  {}", raw.vertices.len());
    println!("  triangles {}", raw.triangles.len());
    let (lo, hi) = raw.bounding_box();
    println!(
        "  bbox      [{:.6e}, {:.6e}, {:.6e}] .. [{:.6e}, {:.6e}, {:.6e}]",
        lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
    );
    let (_, report) = cleave::surface::prepare(&raw).map_err(|e| format!("{}: {e}", path.display()))?;
    println!("  closed, manifold, oriented, no self-intersection: ok");
    println!("  components {}", report.components);
    println!("  volume    {:.9e}", report.volume);
    println!("  area      {:.9e}", report.area);
    if report.merged_vertices > 0 || report.flipped_triangles > 0 {
        println!(
            "  repaired: {} duplicate vertices merged, {} triangles turned",
            report.merged_vertices, report.flipped_triangles
        );
    }
    println!("  mesh it with [meshing] method = \"grid-slice\" (cell) or \"octree\" (max_depth) in a scene");
    Ok(())
}

/// Largest allocation (bytes) glibc serves from its heap; larger ones get
/// their own mapping.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MMAP_THRESHOLD: libc::c_int = 2 << 20;

/// Free memory (bytes) at the top of glibc's heap that it keeps rather
/// than hands back to the system.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const TRIM_THRESHOLD: libc::c_int = 64 << 20;

/// Keeps glibc's large allocations in mappings of their own. By default
/// glibc raises that threshold to the size of any mapped block freed (up
/// to 32 MiB), after which the arrays a cut grows (the pattern's, the step
/// system's, the solver's: 4-21 MB each on bunny_100k) come from the heap,
/// where `realloc` copies them; a mapped block grows by moving its pages
/// (`mremap`). Below 2 MiB the heap reuses its warm pages for a cut's
/// temporary arrays (with 256 KiB the cuts after the growth took a few ms
/// more). Six blade cuts across bunny_100k (the steps bench's), alternated
/// runs on one machine: the cut that outgrows the arrays' room took 73-76
/// ms with glibc's moving threshold and 49-50 ms with this one, the six
/// cuts 50.8-52.6 ms against 46.2-47.3 ms on average.
///
/// Setting the threshold also fixes glibc's trim threshold at 128 KiB:
/// every cut's temporary arrays, freed at the top of the heap, went back
/// to the system and were faulted in again by the next cut. Keeping up to
/// [`TRIM_THRESHOLD`] instead: six blade cuts across bunny_100k, `perf`
/// over four runs each, twice alternated (AMD EPYC Zen 4): page faults 2.2-
/// 2.7 against 1.7 thread-ms per cut, mapping the growth's pages 2.6-2.8
/// against 2.0-2.2, heap trims 0.1 against none: 1.2 thread-ms of the
/// kernel's time less per cut. (A library leaves the process's allocator
/// alone: an application embedding cleave on glibc can make the same
/// calls.)
fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` only sets parameters of the allocator, before any
    // thread of ours allocates; a refusal (return 0) leaves the default
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD);
        libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD);
    }
}

fn main() -> ExitCode {
    tune_allocator();
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
