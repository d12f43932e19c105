//! Python bindings of cleave (`import cleave`): build a simulation from
//! numpy arrays, a mesh file or a scene, step it (without the GIL), cut it,
//! pin nodes, add colliders, and read its state back as numpy arrays.
//! Engine errors are raised as `cleave.CleaveError` with the engine's
//! message.

use std::path::{Path, PathBuf};

use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use cleave::material::Material;
use cleave::mesh::{Cell, Plane, PolyMesh};
use cleave::scene::{run_scene as run_scene_file, LoadedScene, RunOptions};
use cleave::sim::{Collider, Simulation as Engine, SimulationParams};

pyo3::create_exception!(
    cleave,
    CleaveError,
    PyException,
    "An error of the cleave engine; its message names the problem and the place."
);

/// The engine's error as a `CleaveError`.
fn err(e: impl std::fmt::Display) -> PyErr {
    CleaveError::new_err(e.to_string())
}

/// `values` (a flat list of triples) as an `n x 3` array.
fn triples<'py, T: numpy::Element + Copy>(py: Python<'py>, values: &[[T; 3]]) -> PyResult<Bound<'py, PyArray2<T>>> {
    let flat: Vec<T> = values.iter().flatten().copied().collect();
    PyArray1::from_vec(py, flat).reshape([values.len(), 3])
}

/// A simulated elastic body (see `cleave::sim::Simulation`). Units are SI:
/// metres, pascals, kg/m³, seconds.
#[pyclass(module = "cleave")]
struct Simulation {
    engine: Engine,
    /// The scene's cuts (step, plane or polygon), when built from a scene.
    cuts: Vec<cleave::scene::CutSpec>,
}

#[pymethods]
impl Simulation {
    /// A simulation of the mesh with nodes `nodes` (`n x 3`, m) and cells
    /// `cells` (`m x 4` tetrahedra or `m x 8` hexahedra, node indices).
    #[staticmethod]
    #[pyo3(signature = (nodes, cells, young=1e5, poisson=0.3, density=1000.0, gravity=(0.0, 0.0, -9.81), dt=0.01))]
    fn from_arrays(
        nodes: PyReadonlyArray2<'_, f64>,
        cells: PyReadonlyArray2<'_, i64>,
        young: f64,
        poisson: f64,
        density: f64,
        gravity: (f64, f64, f64),
        dt: f64,
    ) -> PyResult<Self> {
        let (nodes, cells) = (nodes.as_array(), cells.as_array());
        if nodes.ncols() != 3 {
            return Err(err(format!("nodes must be n x 3, not {:?}", nodes.shape())));
        }
        let points: Vec<[f64; 3]> = nodes.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect();
        let index = |v: i64| -> PyResult<u32> {
            u32::try_from(v)
                .ok()
                .filter(|&i| (i as usize) < points.len())
                .ok_or_else(|| err(format!("cell node index {v} is out of range (there are {} nodes)", points.len())))
        };
        let mut list = Vec::with_capacity(cells.nrows());
        for row in cells.rows() {
            let ids: Vec<u32> = row.iter().map(|&v| index(v)).collect::<PyResult<_>>()?;
            list.push(match ids.len() {
                4 => Cell::Tet([ids[0], ids[1], ids[2], ids[3]]),
                8 => Cell::Hex(std::array::from_fn(|i| ids[i])),
                k => return Err(err(format!("cells must have 4 (tetrahedra) or 8 (hexahedra) nodes, not {k}"))),
            });
        }
        let mesh = PolyMesh::from_cells(points, &list).map_err(err)?;
        Self::from_mesh(mesh, young, poisson, density, gravity, dt)
    }

    /// A simulation of the mesh in `path` (.mesh, .msh, .vtu, .node/.ele).
    #[staticmethod]
    #[pyo3(signature = (path, young=1e5, poisson=0.3, density=1000.0, gravity=(0.0, 0.0, -9.81), dt=0.01))]
    fn from_file(
        path: PathBuf,
        young: f64,
        poisson: f64,
        density: f64,
        gravity: (f64, f64, f64),
        dt: f64,
    ) -> PyResult<Self> {
        let mesh = cleave::io::read_mesh(&path).map_err(err)?;
        Self::from_mesh(mesh, young, poisson, density, gravity, dt)
    }

    /// The simulation a scene file describes (mesh, material, parameters,
    /// fixed regions, colliders); its cuts are applied by `run` or
    /// `cuts_at`.
    #[staticmethod]
    fn from_scene(path: PathBuf) -> PyResult<Self> {
        let scene = LoadedScene::load(&path).map_err(err)?;
        let engine = scene.build_simulation().map_err(err)?;
        Ok(Simulation { engine, cuts: scene.scene.cut.clone() })
    }

    /// Advances `steps` implicit Euler steps (the GIL is released while
    /// stepping).
    #[pyo3(signature = (steps=1))]
    fn step(&mut self, py: Python<'_>, steps: usize) -> PyResult<()> {
        let engine = &mut self.engine;
        py.detach(|| (0..steps).try_for_each(|_| engine.step().map(|_| ()))).map_err(err)
    }

    /// Steps as the scene's `cleave run` does: at every step, first the
    /// scene's cuts of that step, then the step (the GIL is released).
    fn run(&mut self, py: Python<'_>, steps: usize) -> PyResult<()> {
        let (engine, cuts) = (&mut self.engine, &self.cuts);
        py.detach(|| -> Result<(), cleave::Error> {
            for _ in 0..steps {
                let next = engine.steps() + 1;
                for cut in cuts.iter().filter(|c| c.step == next) {
                    match (&cut.plane, &cut.polygon) {
                        (Some(p), _) => drop(engine.cut_plane(&p.plane())?),
                        (None, Some(polygon)) => drop(engine.cut_polygon(polygon)?),
                        (None, None) => {}
                    }
                }
                engine.step()?;
            }
            Ok(())
        })
        .map_err(err)
    }

    /// Solves the linear static problem under the loads and constraints.
    fn solve_static(&mut self, py: Python<'_>) -> PyResult<()> {
        let engine = &mut self.engine;
        py.detach(|| engine.solve_static().map(|_| ())).map_err(err)
    }

    /// Cuts the body along the whole plane through `point` with `normal`
    /// (rest frame, m); returns the number of elements split.
    fn cut_plane(&mut self, point: [f64; 3], normal: [f64; 3]) -> PyResult<usize> {
        self.engine.cut_plane(&Plane { point, normal }).map(|r| r.split.split_elements.len()).map_err(err)
    }

    /// Cuts the body by the planar convex polygon `points` (rest frame, m);
    /// returns the number of elements split.
    fn cut_polygon(&mut self, points: Vec<[f64; 3]>) -> PyResult<usize> {
        self.engine.cut_polygon(&points).map(|r| r.cut.split.split_elements.len()).map_err(err)
    }

    /// Holds node `node` at displacement `u` (m) from the next step on.
    fn pin(&mut self, node: usize, u: [f64; 3]) -> PyResult<()> {
        self.engine.pin(node, u).map_err(err)
    }

    /// Releases a pinned node.
    fn unpin(&mut self, node: usize) {
        self.engine.unpin(node);
    }

    /// Adds a penalty plane through `point` with `normal` (pointing into
    /// the free side) and `stiffness` (N/m).
    fn add_collider(&mut self, point: [f64; 3], normal: [f64; 3], stiffness: f64) -> PyResult<()> {
        self.engine.add_collider(Collider::new(point, normal, stiffness).map_err(err)?);
        Ok(())
    }

    /// Node positions (`n x 3`, m).
    #[getter]
    fn positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        triples(py, self.engine.positions())
    }

    /// Node rest positions (`n x 3`, m).
    #[getter]
    fn rest_positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        triples(py, &self.engine.mesh().nodes)
    }

    /// Node displacements (`n x 3`, m).
    #[getter]
    fn displacements<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        triples(py, self.engine.displacements())
    }

    /// Node velocities (`n x 3`, m/s).
    #[getter]
    fn velocities<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        triples(py, self.engine.velocities())
    }

    /// Von Mises stress of every element (Pa).
    #[getter]
    fn von_mises<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.engine.von_mises())
    }

    /// The boundary surface: outward triangles over node indices (`t x 3`).
    #[getter]
    fn boundary_triangles<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<u32>>> {
        triples(py, self.engine.boundary_triangles())
    }

    /// Number of elements.
    #[getter]
    fn num_elements(&self) -> usize {
        self.engine.mesh().elements.len()
    }

    /// Steps taken.
    #[getter]
    fn steps(&self) -> usize {
        self.engine.steps()
    }

    /// Simulated time (s).
    #[getter]
    fn time(&self) -> f64 {
        self.engine.time()
    }

    /// Wall time per phase so far (s), as a dict.
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = self.engine.timings();
        let dict = PyDict::new(py);
        for (name, v) in [
            ("basis", t.basis),
            ("forces", t.forces),
            ("assembly", t.assembly),
            ("contacts", t.contacts),
            ("constraints", t.constraints),
            ("solve", t.solve),
            ("integrate", t.integrate),
            ("topology", t.topology),
            ("output", t.output),
        ] {
            dict.set_item(name, v)?;
        }
        Ok(dict)
    }
}

impl Simulation {
    fn from_mesh(
        mesh: PolyMesh,
        young: f64,
        poisson: f64,
        density: f64,
        gravity: (f64, f64, f64),
        dt: f64,
    ) -> PyResult<Self> {
        let params = SimulationParams {
            material: Material::new(young, poisson, density).map_err(err)?,
            gravity: [gravity.0, gravity.1, gravity.2],
            dt,
            ..Default::default()
        };
        Ok(Simulation { engine: Engine::new(mesh, params).map_err(err)?, cuts: Vec::new() })
    }
}

/// Runs a scene file as `cleave run` does (frames and summary.json into
/// `out`, or the scene's folder) and returns its summary as a dict.
#[pyfunction]
#[pyo3(signature = (scene, out=None, steps=None))]
fn run_scene(py: Python<'_>, scene: PathBuf, out: Option<PathBuf>, steps: Option<usize>) -> PyResult<Py<PyAny>> {
    let loaded = LoadedScene::load(&scene).map_err(err)?;
    let summary =
        py.detach(|| run_scene_file(&loaded, &RunOptions { out, steps, ..Default::default() })).map_err(err)?;
    let json = serde_json::to_string(&summary).map_err(err)?;
    let loads = py.import("json")?.getattr("loads")?;
    Ok(loads.call1((json,))?.unbind())
}

/// Renders every frame of a finished run in `out` to PNG; returns the
/// number of pictures.
#[pyfunction]
#[pyo3(signature = (out, stress=false))]
fn render(py: Python<'_>, out: PathBuf, stress: bool) -> PyResult<usize> {
    py.detach(|| cleave::scene::render_run(Path::new(&out), stress)).map_err(err)
}

#[pymodule]
fn _cleave(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Simulation>()?;
    m.add_function(wrap_pyfunction!(run_scene, m)?)?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add("CleaveError", m.py().get_type::<CleaveError>())?;
    Ok(())
}
