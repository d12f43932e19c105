//! The scene schema (`DESIGN.md`, "The scene file and the CLI").

use serde::Deserialize;

use super::{LoadedScene, SceneError};
use crate::material::Material;
use crate::mesh::Plane;
use crate::output::Format;
use crate::param::ParamError;
use crate::sim::{Collider, FixedRegion, GuardLimits, GuardMode, SimulationParams};
use crate::solve::SolverKind;
use crate::store::dg::{DgOptions, Flux as DgFlux};
use crate::store::{self, BasisOptions, HarmonicOptions, HealthFloors, QuadratureRule};
use crate::topology::{polygon_plane, SplitOptions};

/// A whole scene.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Where the mesh comes from.
    pub mesh: MeshSpec,
    /// How a surface mesh is filled with elements.
    pub meshing: Option<MeshingSpec>,
    /// Material constants.
    pub material: MaterialSpec,
    /// Shape function family.
    #[serde(default)]
    pub basis: BasisSpec,
    /// Time stepping.
    #[serde(default)]
    pub simulation: SimulationSpec,
    /// Linear solver.
    #[serde(default)]
    pub solver: SolverSpec,
    /// Dirichlet boxes.
    #[serde(default)]
    pub fixed: Vec<FixedSpec>,
    /// Penalty collision planes.
    #[serde(default)]
    pub collider: Vec<ColliderSpec>,
    /// Cuts during the run.
    #[serde(default)]
    pub cut: Vec<CutSpec>,
    /// How every cut splits the elements it crosses.
    #[serde(default)]
    pub cutting: CuttingSpec,
    /// Adaptive refinement rules.
    #[serde(default)]
    pub refine: Vec<RefineSpec>,
    /// The bounds of the run guards (see [`crate::sim::Guards`]).
    #[serde(default)]
    pub guards: GuardsSpec,
    /// Output files.
    #[serde(default)]
    pub output: OutputSpec,
}

/// `[mesh]`: a file, or a generator.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// Mesh file (relative to the scene).
    pub file: Option<String>,
    /// Generator name (`"box"`).
    pub generator: Option<Generator>,
    /// Box corner (m).
    pub min: Option<[f64; 3]>,
    /// Box corner (m).
    pub max: Option<[f64; 3]>,
    /// Cells per axis.
    pub cells: Option<[usize; 3]>,
    /// Element kind of a generated box.
    pub element: Option<BoxElement>,
    /// Number of random planes (`random-convex`).
    pub planes: Option<usize>,
    /// Random seed (`random-convex`).
    pub seed: Option<u64>,
    /// Polygon `[[x, y], ...]` of a `prism` (m), convex or not.
    pub outline: Option<Vec<[f64; 2]>>,
    /// Height of a `prism` along z (m).
    pub height: Option<f64>,
    /// Merge tetrahedra of quality `6√2 V / d³` below this away before the
    /// run (wicke2007 §4; see `topology::merge_slivers`), in (0, 1).
    pub merge_slivers: Option<f64>,
    /// A surface (OBJ, relative to the scene) embedded in the body: it
    /// moves with it by moving least squares, collides instead of the
    /// nodes, and is written per frame as `frame_NNNN_embedded.obj`
    /// (kaufmann2008 §8-9).
    pub embed: Option<String>,
}

/// Mesh generators.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Generator {
    /// An axis-aligned box.
    Box,
    /// One element: a polygon `outline` extruded by `height` along z.
    Prism,
}

/// Element kinds of a generated box.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum BoxElement {
    /// Hexahedra.
    Hex,
    /// Tetrahedra, six per cube.
    Tet,
    /// The box cut by random planes into convex cells.
    RandomConvex,
    /// The box clipped by random planes into one convex element.
    Clipped,
    /// Non-convex L-shaped prisms and hexahedra (cells even in x and y).
    LPrism,
}

/// `[meshing]` for surface input.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MeshingSpec {
    /// How the inside is filled.
    pub method: MeshingMethod,
    /// Grid cell size (m), for `grid-slice`.
    pub cell: Option<f64>,
    /// Octree depth (1..=10), for `octree`.
    pub max_depth: Option<usize>,
    /// `grid-slice`: pieces below this fraction of a cell's volume are
    /// merged into a face neighbour (default 0.05).
    pub merge_below: Option<f64>,
    /// `grid-slice`: surface simplification as a fraction of a cell
    /// (default 0: exact pieces; about 0.1 for the nodal families, see
    /// [`crate::meshing::SliceOptions`]).
    pub simplify: Option<f64>,
}

/// Meshing methods for surface input.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum MeshingMethod {
    /// Slice by a regular grid into hexahedra and exact cut-out pieces
    /// (kaufmann2008 §10).
    GridSlice,
    /// Embed in an adaptive octree (martin2008 §7).
    Octree,
}

/// `[material]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Density (kg/m^3).
    pub density: f64,
}

/// `[basis]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BasisSpec {
    /// Shape function family.
    #[serde(default)]
    pub family: Family,
    /// DG polynomial degree (1 or 2).
    pub degree: Option<usize>,
    /// DG flux.
    pub flux: Option<Flux>,
    /// DG penalty `η` (dimensionless; the interior penalty's starting
    /// value, doubled until the system is positive definite).
    pub penalty: Option<f64>,
    /// Quadrature of mean value elements.
    #[serde(default)]
    pub quadrature: Quadrature,
    /// Harmonic only: kernel offset relative to the element size (0.1).
    pub offset: Option<f64>,
    /// Harmonic only: kernel samples inside every edge (3).
    pub edge_samples: Option<usize>,
    /// Harmonic only: Gauss points per direction on each sub-tetrahedron (2).
    pub quadrature_order: Option<usize>,
    /// The health check's floor on a node's lumped mass share in an
    /// element, relative to the mean share (default 0.01; see
    /// [`crate::store::HealthFloors`]). Meshes sliced from surfaces carry
    /// nodes of small share in otherwise stiff, healthy elements.
    pub mass_floor: Option<f64>,
}

impl Default for BasisSpec {
    fn default() -> Self {
        BasisSpec {
            family: Family::MeanValue,
            degree: None,
            flux: None,
            penalty: None,
            quadrature: Quadrature::Consistent,
            offset: None,
            edge_samples: None,
            quadrature_order: None,
            mass_floor: None,
        }
    }
}

/// Quadrature rules of mean value elements (see
/// [`crate::store::QuadratureRule`]).
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Quadrature {
    /// The paper's points with the consistency correction (passes the patch test).
    #[default]
    Consistent,
    /// The paper's heuristic rule as printed.
    Paper,
}

/// Shape function families.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Family {
    /// Mean value coordinates (linear on tetrahedra).
    #[default]
    MeanValue,
    /// Harmonic coordinates by the method of fundamental solutions.
    Harmonic,
    /// Discontinuous Galerkin.
    Dg,
}

/// DG fluxes.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Flux {
    /// Interior penalty.
    Ip,
    /// Bassi–Rebay / Brezzi (BZ).
    Bz,
}

/// `[simulation]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SimulationSpec {
    /// Static or dynamic.
    #[serde(default)]
    pub mode: Mode,
    /// Time step (s).
    #[serde(default = "default_dt")]
    pub dt: f64,
    /// Number of steps.
    #[serde(default = "default_steps")]
    pub steps: usize,
    /// Gravity (m/s^2).
    #[serde(default = "default_gravity")]
    pub gravity: [f64; 3],
    /// Stiffness warping.
    #[serde(default = "default_true")]
    pub corotated: bool,
    /// Rayleigh damping.
    #[serde(default)]
    pub damping: DampingSpec,
    /// Initial velocity of every node (m/s).
    #[serde(default)]
    pub velocity: [f64; 3],
    /// What a dynamic run does when a guard fires: `"stop"` (the
    /// default: stop with the diagnosis, the last good frame and a
    /// checkpoint), `"warn"` (report and go on) or `"off"`.
    #[serde(default)]
    pub guards: GuardMode,
}

/// `[guards]`: the bounds of the run guards, each optional.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GuardsSpec {
    /// Growth of the mechanical energy allowed, as a fraction of the
    /// energy scale (default 0.1).
    #[serde(default = "default_energy_growth")]
    pub energy_growth: f64,
    /// Fraction of inverted elements allowed (default 0.01).
    #[serde(default = "default_inverted_fraction")]
    pub inverted_fraction: f64,
    /// Largest element stretch allowed (default 5).
    #[serde(default = "default_stretch")]
    pub stretch: f64,
}

fn default_energy_growth() -> f64 {
    GuardLimits::default().energy_growth
}
fn default_inverted_fraction() -> f64 {
    GuardLimits::default().inverted_fraction
}
fn default_stretch() -> f64 {
    GuardLimits::default().stretch
}

impl Default for GuardsSpec {
    fn default() -> Self {
        let l = GuardLimits::default();
        GuardsSpec { energy_growth: l.energy_growth, inverted_fraction: l.inverted_fraction, stretch: l.stretch }
    }
}

impl GuardsSpec {
    /// The engine's limits.
    pub fn limits(&self) -> GuardLimits {
        GuardLimits {
            energy_growth: self.energy_growth,
            inverted_fraction: self.inverted_fraction,
            stretch: self.stretch,
        }
    }
}

fn default_dt() -> f64 {
    0.01
}
fn default_steps() -> usize {
    200
}
fn default_gravity() -> [f64; 3] {
    [0.0, 0.0, -9.81]
}
fn default_true() -> bool {
    true
}

impl Default for SimulationSpec {
    fn default() -> Self {
        SimulationSpec {
            mode: Mode::Static,
            dt: default_dt(),
            steps: default_steps(),
            gravity: default_gravity(),
            corotated: true,
            damping: DampingSpec::default(),
            velocity: [0.0; 3],
            guards: GuardMode::Stop,
        }
    }
}

/// Simulation modes.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// One linear static solve.
    #[default]
    Static,
    /// Implicit Euler time stepping.
    Dynamic,
}

/// Rayleigh damping `D = mass M + stiffness K`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DampingSpec {
    /// Mass-proportional coefficient (1/s).
    #[serde(default)]
    pub mass: f64,
    /// Stiffness-proportional coefficient (s).
    #[serde(default)]
    pub stiffness: f64,
}

/// `[solver]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    /// Direct or iterative.
    #[serde(default)]
    pub kind: SolverName,
    /// Relative residual tolerance of iterative solvers.
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
    /// Iteration cap of iterative solvers.
    #[serde(default = "default_max_iterations")]
    pub max_iterations: usize,
}

fn default_max_iterations() -> usize {
    2000
}

fn default_tolerance() -> f64 {
    1e-8
}

impl Default for SolverSpec {
    fn default() -> Self {
        SolverSpec { kind: SolverName::Auto, tolerance: default_tolerance(), max_iterations: default_max_iterations() }
    }
}

/// Solvers as a scene names them (see [`SolverKind`]).
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum SolverName {
    /// `"auto"`: Cholesky for small systems, CG for large ones.
    #[default]
    Auto,
    /// `"cholesky"`: envelope factorisation for small systems, sparse
    /// supernodal above.
    Cholesky,
    /// `"sparse-cholesky"`: the sparse supernodal factorisation at every size.
    SparseCholesky,
    /// `"lagged-cholesky"`: the sparse supernodal factor kept across steps
    /// as the preconditioner of CG, factored again when the matrix has
    /// drifted from it (the envelope factorisation for small systems).
    LaggedCholesky,
    /// `"cg"`: conjugate gradients preconditioned by block Jacobi plus a
    /// coarse correction (the rigid motions of aggregates of nodes).
    Cg,
    /// `"cg-rest"`: CG preconditioned by the rotated rest-state factor.
    CgRest,
}

impl SolverName {
    /// The engine's solver kind.
    pub fn kind(self) -> SolverKind {
        match self {
            SolverName::Auto => SolverKind::Auto,
            SolverName::Cholesky => SolverKind::Cholesky,
            SolverName::SparseCholesky => SolverKind::SparseCholesky,
            SolverName::LaggedCholesky => SolverKind::LaggedCholesky,
            SolverName::Cg => SolverKind::Cg,
            SolverName::CgRest => SolverKind::CgRest,
        }
    }
}

/// An axis-aligned box.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    /// Corner (m).
    pub min: [f64; 3],
    /// Corner (m).
    pub max: [f64; 3],
}

/// `[[fixed]]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FixedSpec {
    /// Nodes inside (boundary included) are prescribed.
    #[serde(rename = "box")]
    pub region: BoxSpec,
    /// Constant displacement (m).
    #[serde(default)]
    pub displacement: [f64; 3],
    /// Displacement gradient (dimensionless), applied to rest positions.
    #[serde(default)]
    pub gradient: [[f64; 3]; 3],
}

/// A plane in a scene.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlaneSpec {
    /// A point on it (m).
    pub point: [f64; 3],
    /// Its normal.
    pub normal: [f64; 3],
}

/// `[[collider]]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ColliderSpec {
    /// The collision plane; its normal points into the free half-space.
    pub plane: PlaneSpec,
    /// Penalty stiffness (N/m).
    pub stiffness: f64,
}

/// `[[cut]]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CutSpec {
    /// Step at which the cut happens.
    pub step: usize,
    /// A planar cut polygon (m).
    pub polygon: Option<Vec<[f64; 3]>>,
    /// A full split plane.
    pub plane: Option<PlaneSpec>,
}

/// `[cutting]`: the tolerances of every cut's split (see
/// [`crate::topology::SplitOptions`]), each optional (the defaults of
/// [`crate::topology::SplitOptions::default`] and
/// [`SimulationParams::min_part`]).
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CuttingSpec {
    /// Snapping radius, as a fraction of the diameter of the smallest
    /// crossed element holding a node (default 0.1).
    pub snap: Option<f64>,
    /// Smallest shape quality of a part (default 0.02).
    pub min_quality: Option<f64>,
    /// Smallest distance between two nodes of an element a cut makes or
    /// changes, as a fraction of its diameter (default 0.05).
    pub min_spacing: Option<f64>,
    /// Smallest diameter of a part, as a fraction of the body's median
    /// element diameter (default 0.1).
    pub min_part: Option<f64>,
}

/// `[[refine]]`: split elements whose stress is high (see
/// [`crate::sim::RefineRule`]).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RefineSpec {
    /// Refinement criterion.
    pub criterion: RefineCriterion,
    /// Largest absolute principal stress an element may carry (Pa).
    pub threshold: f64,
    /// `"1-to-2"` (across the principal direction) or `"1-to-8"` (octants).
    pub split: RefineSplitName,
    /// How many times an element may be refined (default 3).
    pub max_level: Option<u8>,
}

/// Refinement criteria.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum RefineCriterion {
    /// The largest absolute principal stress.
    Stress,
}

/// Refinement splits, by their scene names.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
pub enum RefineSplitName {
    /// In two.
    #[serde(rename = "1-to-2")]
    Halves,
    /// In eight.
    #[serde(rename = "1-to-8")]
    Octants,
}

impl RefineSpec {
    /// The engine's rule.
    pub fn rule(&self) -> crate::sim::RefineRule {
        crate::sim::RefineRule {
            threshold: self.threshold,
            split: match self.split {
                RefineSplitName::Halves => crate::sim::RefineSplit::Halves,
                RefineSplitName::Octants => crate::sim::RefineSplit::Octants,
            },
            max_level: self.max_level.unwrap_or(3),
        }
    }
}

/// `[output]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// Output folder (relative to the scene file).
    pub dir: Option<String>,
    /// Write a frame every this many steps.
    #[serde(default = "default_every")]
    pub every: usize,
    /// Frame formats.
    #[serde(default = "default_formats")]
    pub formats: Vec<FormatName>,
    /// What colours the pictures: `"plain"` (cut faces in a second colour)
    /// or `"von-mises"` (stress, with a legend).
    #[serde(default)]
    pub color: PictureColor,
}

/// What colours a picture.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum PictureColor {
    /// The body in one colour, faces opened by cuts in another.
    #[default]
    Plain,
    /// Von Mises stress (Pa), averaged at the nodes, with a legend.
    VonMises,
}

fn default_every() -> usize {
    1
}
fn default_formats() -> Vec<FormatName> {
    vec![FormatName::Vtu]
}

impl Default for OutputSpec {
    fn default() -> Self {
        OutputSpec { dir: None, every: 1, formats: default_formats(), color: PictureColor::Plain }
    }
}

/// Frame formats as a scene names them.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum FormatName {
    /// `"vtu"`: VTK unstructured grid with polyhedron cells.
    Vtu,
    /// `"obj"`: boundary surface as OBJ.
    Obj,
    /// `"png"`: a rendered picture of the boundary surface.
    Png,
}

impl FormatName {
    /// The output format.
    pub fn format(self) -> Format {
        match self {
            FormatName::Vtu => Format::Vtu,
            FormatName::Obj => Format::Obj,
            FormatName::Png => Format::Png,
        }
    }
}

/// The scene key of an engine parameter of [`SimulationParams`].
fn key_of(name: &str) -> String {
    match name {
        "young" | "poisson" | "density" => format!("material.{name}"),
        "gravity" | "dt" => format!("simulation.{name}"),
        "mass_damping" | "stiffness_damping" => "simulation.damping".into(),
        "tolerance" | "max_iterations" => format!("solver.{name}"),
        "offset" | "edge_samples" | "quadrature_order" | "degree" | "penalty" => format!("basis.{name}"),
        "mass_fraction" => "basis.mass_floor".into(),
        "snap" | "min_quality" | "min_spacing" | "min_part" => format!("cutting.{name}"),
        _ => "simulation".into(),
    }
}

fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl Scene {
    /// Range checks of every value; errors name the key and its line.
    pub(crate) fn check(&self, s: &LoadedScene) -> Result<(), SceneError> {
        self.guards.limits().check().map_err(|e| s.param(&format!("guards.{}", e.name), e))?;
        let m = &self.mesh;
        match (&m.file, &m.generator) {
            (Some(_), Some(_)) => {
                return Err(s.invalid("mesh.generator", "…", "give either mesh.file or mesh.generator, not both"))
            }
            (None, None) => return Err(s.invalid("mesh", "{}", "needs mesh.file or mesh.generator")),
            (None, Some(Generator::Box)) => {
                let (Some(min), Some(max)) = (m.min, m.max) else {
                    return Err(s.invalid("mesh", "box", "a box generator needs min = [x, y, z] and max = [x, y, z]"));
                };
                if !finite3(&min) || !finite3(&max) || (0..3).any(|i| min[i] >= max[i]) {
                    return Err(s.invalid(
                        "mesh.max",
                        format!("{max:?}"),
                        "must be finite and greater than mesh.min on every axis (m)",
                    ));
                }
                match m.element {
                    None => {
                        return Err(s.invalid(
                            "mesh",
                            "box",
                            "a box generator needs element = \"hex\" | \"tet\" | \"l-prism\" | \"random-convex\" | \"clipped\"",
                        ))
                    }
                    Some(BoxElement::RandomConvex | BoxElement::Clipped) => {
                        let planes = m.planes.unwrap_or(8);
                        if planes > 10_000 {
                            return Err(s.invalid("mesh.planes", planes, "must be at most 10000"));
                        }
                    }
                    Some(_) => {
                        let cells = m.cells.unwrap_or([1; 3]);
                        if cells.contains(&0) || cells.iter().product::<usize>() > 50_000_000 {
                            return Err(s.invalid(
                                "mesh.cells",
                                format!("{cells:?}"),
                                "needs at least 1 cell per axis and at most 5e7 cells",
                            ));
                        }
                    }
                }
            }
            (None, Some(Generator::Prism)) => {
                let outline = m.outline.as_deref().unwrap_or_default();
                if outline.len() < 3 || outline.iter().flatten().any(|x| !x.is_finite()) {
                    return Err(s.invalid(
                        "mesh.outline",
                        "…",
                        "a prism needs an outline of at least 3 finite [x, y] points (m)",
                    ));
                }
                let height = m.height.unwrap_or(f64::NAN);
                if !(height > 0.0 && height.is_finite()) {
                    return Err(s.invalid("mesh.height", height, "a prism needs a finite height > 0 (m)"));
                }
            }
            (Some(_), None) => {}
        }
        if let Some(q) = m.merge_slivers {
            if !(q > 0.0 && q < 1.0) {
                return Err(s.invalid("mesh.merge_slivers", q, "a quality threshold in (0, 1), e.g. 0.02"));
            }
        }
        let surface_file = m.file.as_deref().is_some_and(|f| {
            let lower = f.to_ascii_lowercase();
            lower.ends_with(".obj") || lower.ends_with(".stl")
        });
        match (&self.meshing, surface_file) {
            (None, true) => {
                return Err(s.invalid(
                    "mesh.file",
                    m.file.as_deref().unwrap_or_default(),
                    "is a surface: add [meshing] with method = \"grid-slice\" (and cell) or \"octree\" (and max_depth)",
                ))
            }
            (Some(_), false) => {
                return Err(s.invalid("meshing", "…", "applies to a surface mesh.file (.obj or .stl) only"))
            }
            (Some(me), true) => match me.method {
                MeshingMethod::GridSlice => {
                    let cell = me.cell.unwrap_or(f64::NAN);
                    if !(cell > 0.0 && cell.is_finite()) {
                        return Err(s.invalid("meshing.cell", cell, "grid-slice needs a finite cell size > 0 (m)"));
                    }
                    if let Some(f) = me.merge_below {
                        if !(0.0..0.5).contains(&f) {
                            return Err(s.invalid(
                                "meshing.merge_below",
                                f,
                                "must lie in [0, 0.5) (fraction of a cell)",
                            ));
                        }
                    }
                }
                MeshingMethod::Octree => {
                    let d = me.max_depth.unwrap_or(0);
                    if !(1..=10).contains(&d) {
                        return Err(s.invalid("meshing.max_depth", d, "octree needs max_depth in 1..=10"));
                    }
                }
            },
            (None, false) => {}
        }
        let b = &self.basis;
        if b.family == Family::MeanValue
            && (b.offset.is_some() || b.edge_samples.is_some() || b.quadrature_order.is_some())
        {
            return Err(s.invalid(
                "basis.offset",
                "…",
                "offset, edge_samples and quadrature_order apply to family = \"harmonic\" only",
            ));
        }
        let params = self.params();
        let dg_keys = b.degree.is_some() || b.flux.is_some() || b.penalty.is_some();
        if b.family != Family::Dg && dg_keys {
            return Err(s.invalid("basis.degree", "…", "degree, flux and penalty apply to family = \"dg\" only"));
        }
        params.check().map_err(|e| s.param(&key_of(e.name), e))?;
        let sim = &self.simulation;
        crate::param::finite("velocity", sim.velocity, "must be finite (m/s)")
            .map_err(|e| s.param("simulation.velocity", e))?;
        if sim.steps > 10_000_000 {
            return Err(s.invalid("simulation.steps", sim.steps, "must be at most 1e7"));
        }
        for (i, f) in self.fixed.iter().enumerate() {
            f.region().check().map_err(|e| {
                let key = match e.name {
                    "min" | "max" => format!("fixed.{i}.box"),
                    name => format!("fixed.{i}.{name}"),
                };
                s.param(&key, e)
            })?;
        }
        for (i, c) in self.collider.iter().enumerate() {
            c.collider().map_err(|e| {
                let key = if e.name == "stiffness" {
                    format!("collider.{i}.stiffness")
                } else {
                    format!("collider.{i}.plane")
                };
                s.param(&key, e)
            })?;
        }
        for (i, c) in self.cut.iter().enumerate() {
            match (&c.plane, &c.polygon) {
                (Some(p), None) => p.plane().check().map_err(|e| s.param(&format!("cut.{i}.plane"), e))?,
                (None, Some(poly)) => {
                    polygon_plane(poly).map_err(|e| s.invalid(&format!("cut.{i}.polygon"), "…", &e.to_string()))?;
                }
                _ => return Err(s.invalid(&format!("cut.{i}"), "…", "give exactly one of plane or polygon")),
            }
            if self.simulation.mode == Mode::Static {
                return Err(s.invalid(&format!("cut.{i}.step"), c.step, "cuts need mode = \"dynamic\""));
            }
        }
        for r in &self.refine {
            if let Err(e) = r.rule().check() {
                return Err(s.invalid(e.name, &e.value, &e.allowed));
            }
            if self.basis.family == Family::Dg {
                return Err(s.invalid("refine", "dg", "refinement applies to the mean value and harmonic families"));
            }
        }
        if self.output.every == 0 {
            return Err(s.invalid("output.every", 0, "must be at least 1"));
        }
        Ok(())
    }

    /// The material of the scene (range-checked at load).
    pub fn material(&self) -> Material {
        Material { young: self.material.young, poisson: self.material.poisson, density: self.material.density }
    }

    /// The engine's options for the scene's basis.
    pub fn basis_options(&self) -> BasisOptions {
        let b = &self.basis;
        let family = match b.family {
            Family::MeanValue => store::Family::MeanValue,
            Family::Harmonic => store::Family::Harmonic,
            Family::Dg => store::Family::Dg,
        };
        let quadrature = match b.quadrature {
            Quadrature::Consistent => QuadratureRule::Consistent,
            Quadrature::Paper => QuadratureRule::Paper,
        };
        let d = HarmonicOptions::default();
        let harmonic = HarmonicOptions {
            offset: b.offset.unwrap_or(d.offset),
            edge_samples: b.edge_samples.unwrap_or(d.edge_samples),
            quadrature_order: b.quadrature_order.unwrap_or(d.quadrature_order),
            ..d
        };
        let d = DgOptions::default();
        let dg = DgOptions {
            degree: b.degree.unwrap_or(d.degree),
            flux: match b.flux {
                None => d.flux,
                Some(Flux::Ip) => DgFlux::Ip,
                Some(Flux::Bz) => DgFlux::Bz,
            },
            penalty: b.penalty.unwrap_or(d.penalty),
        };
        let d = HealthFloors::default();
        let health = HealthFloors { mass_fraction: b.mass_floor.unwrap_or(d.mass_fraction), ..d };
        BasisOptions { family, quadrature, harmonic, dg, health }
    }

    /// The engine's simulation parameters of the scene.
    pub fn params(&self) -> SimulationParams {
        let (sim, c, d) = (&self.simulation, &self.cutting, SimulationParams::default());
        SimulationParams {
            material: self.material(),
            gravity: sim.gravity,
            basis: self.basis_options(),
            dt: sim.dt,
            mass_damping: sim.damping.mass,
            stiffness_damping: sim.damping.stiffness,
            corotated: sim.corotated,
            solver: self.solver.kind.kind(),
            tolerance: self.solver.tolerance,
            max_iterations: self.solver.max_iterations,
            cut: SplitOptions {
                snap: c.snap.unwrap_or(d.cut.snap),
                min_quality: c.min_quality.unwrap_or(d.cut.min_quality),
                min_spacing: c.min_spacing.unwrap_or(d.cut.min_spacing),
                ..d.cut
            },
            min_part: c.min_part.unwrap_or(d.min_part),
        }
    }

    /// The frame formats of the scene (all implemented, checked at load).
    pub fn formats(&self) -> Vec<Format> {
        self.output.formats.iter().map(|f| f.format()).collect()
    }
}

impl FixedSpec {
    /// The engine's fixed region.
    pub fn region(&self) -> FixedRegion {
        FixedRegion {
            min: self.region.min,
            max: self.region.max,
            displacement: self.displacement,
            gradient: self.gradient,
        }
    }
}

impl ColliderSpec {
    /// The engine's collider (checked).
    pub fn collider(&self) -> Result<Collider, ParamError> {
        Collider::new(self.plane.point, self.plane.normal, self.stiffness)
    }
}

impl PlaneSpec {
    /// The engine's plane.
    pub fn plane(&self) -> Plane {
        Plane { point: self.point, normal: self.normal }
    }
}
