//! Scenario files (TOML). Unknown keys are errors; every error names the file, the line or
//! key, and the fix. `Setup` is the scenario resolved against its mesh: per-node materials,
//! the Dirichlet set and the loads, ready for the solver.

use crate::material::{check_spd, Tensor, TissueLaw};
use anyhow::{anyhow, bail, Result};
use eprop_io::geom::{dot, norm, sub};
use eprop_io::Mesh;
use serde::Deserialize;
use std::path::{Path, PathBuf};

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    pub mesh: MeshSec,
    #[serde(default)]
    pub material: MaterialSec,
    #[serde(default)]
    pub model: ModelSec,
    #[serde(default)]
    pub tissue: TissueSec,
    #[serde(default)]
    pub fixed: Vec<SelectSec>,
    #[serde(default)]
    pub load: Vec<LoadSec>,
    pub time: TimeSec,
    #[serde(default)]
    pub output: OutputSec,
    /// Settings of the `rkl2` and `implicit` integrators.
    #[serde(default)]
    pub integrator: crate::integrate::IntegratorSec,
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct MeshSec {
    pub file: String,
    /// Every coordinate is multiplied by this on reading (1000 reads a mesh in metres as mm).
    #[serde(default = "one")]
    pub scale: f64,
    /// Refuse inverted cells instead of reorienting them (as `eprop info --strict`).
    #[serde(default)]
    pub strict: bool,
}

/// A conductivity: a scalar, three diagonal values, a full symmetric 3x3 table, or diagonal
/// values along the axes of an orthonormal frame (`{ diagonal = [...], axes = [[...], ...] }`).
#[derive(Deserialize, Debug, Clone)]
#[serde(untagged)]
pub enum Conductivity {
    Scalar(f64),
    Diagonal([f64; 3]),
    Full([[f64; 3]; 3]),
    Frame { diagonal: [f64; 3], axes: [[f64; 3]; 3] },
}

impl Conductivity {
    pub fn tensor(&self) -> Tensor {
        match self {
            Conductivity::Scalar(r) => Tensor::identity() * *r,
            Conductivity::Diagonal(d) => Tensor::from_diagonal(&nalgebra::Vector3::from(*d)),
            Conductivity::Full(m) => Tensor::from_fn(|i, j| m[i][j]),
            Conductivity::Frame { diagonal, axes } => {
                // R = sum_k d_k a_k a_k^T
                let mut t = Tensor::zeros();
                for k in 0..3 {
                    let a = nalgebra::Vector3::from(axes[k]);
                    t += a * a.transpose() * diagonal[k];
                }
                t
            }
        }
    }

    /// The axes of a frame must be orthonormal (to 1e-6).
    pub fn check_frame(&self) -> std::result::Result<(), String> {
        if let Conductivity::Frame { axes, .. } = self {
            for i in 0..3 {
                for j in 0..3 {
                    let d: f64 = (0..3).map(|c| axes[i][c] * axes[j][c]).sum();
                    let want = if i == j { 1.0 } else { 0.0 };
                    if !((d - want).abs() <= 1e-6) {
                        return Err(format!(
                            "the axes are not orthonormal (axis {} . axis {} = {d:.6}); fix: give three unit vectors at right angles",
                            i + 1,
                            j + 1
                        ));
                    }
                }
            }
        }
        Ok(())
    }
}

fn default_mass() -> f64 {
    1.0
}
fn default_damping() -> f64 {
    2.0
}
fn default_conductivity() -> Conductivity {
    Conductivity::Scalar(0.05)
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct MaterialSec {
    #[serde(default = "default_mass")]
    pub mass: f64,
    #[serde(default = "default_damping")]
    pub damping: f64,
    #[serde(default = "default_conductivity")]
    pub conductivity: Conductivity,
    #[serde(default)]
    pub region: Vec<RegionSec>,
}

impl Default for MaterialSec {
    fn default() -> Self {
        MaterialSec {
            mass: 1.0,
            damping: 2.0,
            conductivity: default_conductivity(),
            region: vec![],
        }
    }
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct HalfSpace {
    pub point: [f64; 3],
    pub normal: [f64; 3],
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct Sphere {
    pub center: [f64; 3],
    pub radius: f64,
}

/// A set of nodes: by box, sphere, half-space, node ids, physical tag or group name.
#[derive(Deserialize, Debug, Clone, Default)]
#[serde(deny_unknown_fields)]
pub struct SelectSec {
    #[serde(rename = "box")]
    pub bbox: Option<[[f64; 3]; 2]>,
    pub sphere: Option<Sphere>,
    pub halfspace: Option<HalfSpace>,
    pub nodes: Option<Vec<u64>>,
    pub tag: Option<i32>,
    pub group: Option<String>,
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct RegionSec {
    #[serde(rename = "box")]
    pub bbox: Option<[[f64; 3]; 2]>,
    pub sphere: Option<Sphere>,
    pub halfspace: Option<HalfSpace>,
    pub tag: Option<i32>,
    pub group: Option<String>,
    pub conductivity: Option<Conductivity>,
    pub mass: Option<f64>,
    pub damping: Option<f64>,
}

fn default_scheme() -> String {
    "compact".into()
}
fn one() -> f64 {
    1.0
}
fn yes() -> bool {
    true
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct ModelSec {
    #[serde(default = "default_scheme")]
    pub scheme: String,
    #[serde(default = "yes")]
    pub paper_correction: bool,
    #[serde(default = "one")]
    pub stiffness: f64,
    #[serde(default = "one")]
    pub coupling: f64,
    #[serde(default = "one")]
    pub exponent: f64,
    /// Storage of the compact operator's coefficients: "float64" (default) or "float32".
    #[serde(default = "default_precision")]
    pub operator_precision: String,
    /// Integrator of the propagation: "auto" (default), "euler", "rkl2" or "implicit".
    #[serde(default = "default_integrator")]
    pub integrator: String,
}

fn default_integrator() -> String {
    "auto".into()
}

impl Default for ModelSec {
    fn default() -> Self {
        ModelSec {
            scheme: default_scheme(),
            paper_correction: true,
            stiffness: 1.0,
            coupling: 1.0,
            exponent: 1.0,
            operator_precision: default_precision(),
            integrator: default_integrator(),
        }
    }
}

fn default_young() -> f64 {
    100.0
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct TissueSec {
    #[serde(default = "default_young")]
    pub young: f64,
    #[serde(default)]
    pub beta: f64,
}

impl Default for TissueSec {
    fn default() -> Self {
        TissueSec {
            young: 100.0,
            beta: 0.0,
        }
    }
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct LoadSec {
    pub node: Option<u64>,
    pub nearest: Option<[f64; 3]>,
    /// A contact patch: every surface node within `radius` of `center`, weighted by its
    /// boundary dual area.
    pub patch: Option<Sphere>,
    pub force: Option<[f64; 3]>,
    pub normal: Option<f64>,
    /// Piecewise-linear ramp: [[t0, s0], [t1, s1], ...]; the force is scaled by s(t).
    pub ramp: Option<Vec<[f64; 2]>>,
}

#[derive(Deserialize, Debug, Clone, Default)]
#[serde(deny_unknown_fields)]
pub struct TimeSec {
    pub steps: Option<u64>,
    pub end: Option<f64>,
    pub equilibrium: Option<f64>,
    pub dt: Option<f64>,
    /// Propagation substep; chosen automatically when absent.
    pub h: Option<f64>,
}

fn default_every() -> u64 {
    1
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct OutputSec {
    pub file: Option<String>,
    #[serde(default = "default_every")]
    pub every: u64,
    /// Point arrays written every output step.
    #[serde(default = "default_fields")]
    pub fields: Vec<String>,
    /// "float64" (default; needed for an exact restart) or "float32".
    #[serde(default = "default_precision")]
    pub precision: String,
    /// gzip (deflate) level of the point arrays, 0 (off, default) to 9.
    #[serde(default)]
    pub compression: u8,
}

/// Every point array eprop can write, with its number of components.
pub const FIELDS: [(&str, usize); 4] = [("displacement", 3), ("velocity", 3), ("potential", 3), ("energy", 1)];

fn default_fields() -> Vec<String> {
    FIELDS.iter().map(|f| f.0.to_string()).collect()
}

fn default_precision() -> String {
    "float64".into()
}

impl Default for OutputSec {
    fn default() -> Self {
        OutputSec {
            file: None,
            every: 1,
            fields: default_fields(),
            precision: default_precision(),
            compression: 0,
        }
    }
}

/// A scenario file, parsed.
#[derive(Clone, Debug)]
pub struct Scenario {
    pub path: PathBuf,
    pub text: String,
    pub file: ScenarioFile,
}

/// Line of `key` inside the n-th table named `section` (1-based), for messages.
pub fn locate(text: &str, section: &str, index: usize, key: &str) -> Option<usize> {
    let mut cur = String::new();
    let mut count = 0usize;
    for (ln, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.starts_with('[') {
            cur = t.trim_matches(|c| c == '[' || c == ']').trim().to_string();
            if cur == section {
                count += 1;
            }
            continue;
        }
        if cur == section && count == index + 1 {
            if let Some((k, _)) = t.split_once('=') {
                if k.trim() == key {
                    return Some(ln + 1);
                }
            }
        }
    }
    None
}

impl Scenario {
    pub fn load(path: &Path) -> Result<Scenario> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow!("{}: cannot read the scenario: {e}; fix: check the path", path.display()))?;
        Self::parse(path, text)
    }

    pub fn parse(path: &Path, text: String) -> Result<Scenario> {
        let file: ScenarioFile = toml::from_str(&text).map_err(|e| {
            let (line, col) = e.span().map(|s| line_col(&text, s.start)).unwrap_or((0, 0));
            anyhow!(
                "{}:{}:{}: {}; fix: see `eprop run --help` for the scenario keys",
                path.display(),
                line,
                col,
                e.message().trim()
            )
        })?;
        Ok(Scenario {
            path: path.to_path_buf(),
            text,
            file,
        })
    }

    /// The mesh path, resolved relative to the scenario file.
    pub fn mesh_path(&self) -> PathBuf {
        let base = self.path.parent().unwrap_or(Path::new("."));
        base.join(&self.file.mesh.file)
    }

    /// The output path: the scenario's, relative to the scenario file, or `<stem>.h5` beside it.
    pub fn output_path(&self) -> PathBuf {
        let base = self.path.parent().unwrap_or(Path::new("."));
        match &self.file.output.file {
            Some(f) => base.join(f),
            None => base.join(format!(
                "{}.h5",
                self.path.file_stem().and_then(|s| s.to_str()).unwrap_or("out")
            )),
        }
    }

    fn err(&self, section: &str, index: usize, key: &str, msg: impl std::fmt::Display) -> anyhow::Error {
        let line = locate(&self.text, section, index, key)
            .map(|l| format!(":{l}"))
            .unwrap_or_default();
        let mut msg = msg.to_string();
        if !msg.contains("fix:") {
            msg += &format!("; fix: change `{key}` in [{section}] (`eprop run --help` lists every scenario key)");
        }
        anyhow!("{}{line}: [{section}] {key}: {msg}", self.path.display())
    }
}

fn line_col(text: &str, byte: usize) -> (usize, usize) {
    let before = &text[..byte.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.len() - before.rfind('\n').map(|p| p + 1).unwrap_or(0) + 1;
    (line, col)
}

/// How a run stops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Stop {
    Steps(u64),
    End(f64),
    /// max |v| below the tolerance, at most `max_steps` steps
    Equilibrium {
        tol: f64,
        max_steps: u64,
    },
}

/// A resolved load.
#[derive(Clone, Debug)]
pub struct Load {
    /// Contact nodes (global indices) and their weights (summing to 1).
    pub nodes: Vec<u32>,
    /// Their ids in the mesh file, for messages.
    pub node_ids: Vec<u64>,
    pub weights: Vec<f64>,
    /// Force at ramp scale 1.
    pub force: [f64; 3],
    /// |sum of the contact nodes' boundary dual areas|, filled in by the solver.
    pub area: f64,
    pub ramp: Option<Vec<[f64; 2]>>,
    /// Normal load magnitude (force direction is set from the boundary normal).
    pub normal: Option<f64>,
    /// Contact patches: the source enters through the patch surface as a flux of depth
    /// `depth` (the patch radius): Q_i = q |A_i| depth / V_i, so the energy put in does not
    /// depend on the mesh. None: the paper's nodal source Q_c = q.
    pub depth: Option<f64>,
}

impl Load {
    /// Ramp scale at time t (piecewise linear, constant beyond the ends).
    pub fn scale(&self, t: f64) -> f64 {
        let Some(r) = &self.ramp else { return 1.0 };
        if t <= r[0][0] {
            return r[0][1];
        }
        for w in r.windows(2) {
            if t <= w[1][0] {
                let a = (t - w[0][0]) / (w[1][0] - w[0][0]);
                return w[0][1] + a * (w[1][1] - w[0][1]);
            }
        }
        r[r.len() - 1][1]
    }
}

/// Model switches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scheme {
    Compact,
    Paper { correction: bool },
}

/// The scenario resolved against its mesh.
pub struct Setup {
    pub scenario: Scenario,
    pub mesh: Mesh,
    pub r: Vec<Tensor>,
    pub mass: Vec<f64>,
    pub damping: Vec<f64>,
    pub fixed: Vec<bool>,
    pub loads: Vec<Load>,
    pub scheme: Scheme,
    pub stiffness: f64,
    pub coupling: f64,
    pub exponent: f64,
    pub law: TissueLaw,
    pub stop: Stop,
    pub dt: Option<f64>,
    pub h: Option<f64>,
    pub output: PathBuf,
    pub every: u64,
    pub integrator: crate::integrate::Settings,
}

fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl Setup {
    /// Reads the mesh named by the scenario and resolves everything.
    pub fn new(scenario: Scenario) -> Result<Setup> {
        let ms = &scenario.file.mesh;
        if !(ms.scale > 0.0 && ms.scale.is_finite()) {
            return Err(scenario.err("mesh", 0, "scale", format!("{} must be a positive number; fix: the factor from the mesh's length unit to the scenario's (1000 turns metres into mm)", ms.scale)));
        }
        let opts = eprop_io::ReadOptions { strict: ms.strict };
        let mut mesh = eprop_io::read_mesh_with(&scenario.mesh_path(), &opts)
            .map_err(|e| anyhow!("{e}\n  (mesh named by {} [mesh] file)", scenario.path.display()))?;
        if ms.scale != 1.0 {
            for p in mesh.points.iter_mut() {
                for x in p.iter_mut() {
                    *x *= ms.scale;
                }
            }
        }
        Self::with_mesh(scenario, mesh)
    }

    /// Resolves a scenario against an already loaded mesh.
    pub fn with_mesh(scenario: Scenario, mesh: Mesh) -> Result<Setup> {
        let f = scenario.file.clone();
        let n = mesh.n_nodes();
        let sc = &scenario;

        // material
        let m = &f.material;
        if !(m.mass > 0.0 && m.mass.is_finite()) {
            return Err(sc.err("material", 0, "mass", format!("{} must be a positive number", m.mass)));
        }
        if !(m.damping >= 0.0 && m.damping.is_finite()) {
            return Err(sc.err(
                "material",
                0,
                "damping",
                format!("{} must be zero or positive", m.damping),
            ));
        }
        m.conductivity
            .check_frame()
            .map_err(|e| sc.err("material", 0, "conductivity", e))?;
        let r0 = m.conductivity.tensor();
        check_spd(&r0).map_err(|e| sc.err("material", 0, "conductivity", e))?;
        let mut r = vec![r0; n];
        let mut mass = vec![m.mass; n];
        let mut damping = vec![m.damping; n];
        for (k, reg) in m.region.iter().enumerate() {
            let sel = SelectSec {
                bbox: reg.bbox,
                sphere: reg.sphere.clone(),
                halfspace: reg.halfspace.clone(),
                nodes: None,
                tag: reg.tag,
                group: reg.group.clone(),
            };
            let set = select(sc, &mesh, &sel, "material.region", k)?;
            if !set.iter().any(|&b| b) {
                return Err(sc.err(
                    "material.region",
                    k,
                    "box",
                    "the region holds no node; fix: check its bounds against the mesh (eprop info MESH)",
                ));
            }
            if let Some(c) = &reg.conductivity {
                c.check_frame()
                    .map_err(|e| sc.err("material.region", k, "conductivity", e))?;
            }
            let rt = reg.conductivity.as_ref().map(|c| c.tensor());
            if let Some(rt) = &rt {
                check_spd(rt).map_err(|e| sc.err("material.region", k, "conductivity", e))?;
            }
            if let Some(ms) = reg.mass {
                if !(ms > 0.0 && ms.is_finite()) {
                    return Err(sc.err("material.region", k, "mass", format!("{ms} must be a positive number")));
                }
            }
            if let Some(d) = reg.damping {
                if !(d >= 0.0 && d.is_finite()) {
                    return Err(sc.err("material.region", k, "damping", format!("{d} must be zero or positive")));
                }
            }
            for i in 0..n {
                if set[i] {
                    if let Some(rt) = rt {
                        r[i] = rt;
                    }
                    if let Some(ms) = reg.mass {
                        mass[i] = ms;
                    }
                    if let Some(d) = reg.damping {
                        damping[i] = d;
                    }
                }
            }
        }

        // model
        let md = &f.model;
        let scheme = match md.scheme.as_str() {
            "compact" => Scheme::Compact,
            "paper" => Scheme::Paper {
                correction: md.paper_correction,
            },
            other => {
                return Err(sc.err(
                    "model",
                    0,
                    "scheme",
                    format!("`{other}` is not a scheme; fix: use \"compact\" or \"paper\""),
                ))
            }
        };
        if !["float64", "float32"].contains(&md.operator_precision.as_str()) {
            return Err(sc.err(
                "model",
                0,
                "operator_precision",
                format!(
                    "`{}` is not a precision; fix: use \"float64\" or \"float32\"",
                    md.operator_precision
                ),
            ));
        }
        let integrator = crate::integrate::Settings::resolve(&md.integrator, &f.integrator)
            .map_err(|(section, key, msg)| sc.err(section, 0, key, msg))?;
        if !(md.stiffness >= 0.0 && md.stiffness.is_finite()) {
            return Err(sc.err("model", 0, "stiffness", "must be zero or positive"));
        }
        if !md.coupling.is_finite() {
            return Err(sc.err("model", 0, "coupling", "must be a finite number"));
        }
        if !(md.exponent > 0.0 && md.exponent.is_finite()) {
            return Err(sc.err("model", 0, "exponent", "must be positive"));
        }
        let t = &f.tissue;
        if !(t.young > 0.0 && t.young.is_finite()) {
            return Err(sc.err("tissue", 0, "young", "must be positive"));
        }
        if !(t.beta >= 0.0 && t.beta.is_finite()) {
            return Err(sc.err(
                "tissue",
                0,
                "beta",
                "must be zero (linear) or positive (exponential stiffening)",
            ));
        }

        // Dirichlet set
        if f.fixed.is_empty() {
            bail!(
                "{}: no [[fixed]] set; fix: fix part of the organ (for example `[[fixed]] group = \"bottom\"`), \
                 otherwise energy never leaves the body and the run has no steady state",
                sc.path.display()
            );
        }
        let mut fixed = vec![false; n];
        for (k, fx) in f.fixed.iter().enumerate() {
            let set = select(sc, &mesh, fx, "fixed", k)?;
            if !set.iter().any(|&b| b) {
                return Err(sc.err(
                    "fixed",
                    k,
                    selector_key(fx),
                    "selects no node; fix: check it against the mesh (eprop info MESH)",
                ));
            }
            for i in 0..n {
                fixed[i] |= set[i];
            }
        }

        // every piece of the mesh needs its own fixed node, else its energy never leaves
        let (comp, ncomp) = eprop_io::mesh::components(&mesh);
        if ncomp > 1 {
            let mut has_cells = vec![false; ncomp];
            let mut held = vec![false; ncomp];
            let mut size = vec![0usize; ncomp];
            for c in 0..mesh.n_cells() {
                has_cells[comp[mesh.cell(c)[0] as usize] as usize] = true;
            }
            for i in 0..n {
                size[comp[i] as usize] += 1;
                held[comp[i] as usize] |= fixed[i];
            }
            if let Some(q) = (0..ncomp).find(|&q| has_cells[q] && !held[q]) {
                let any = (0..n).find(|&i| comp[i] as usize == q).unwrap_or(0);
                bail!(
                    "{}: the mesh has {} separate pieces and the one with node {} ({} nodes) holds no fixed node; \
                     fix: add a [[fixed]] set on that piece (every piece needs its own)",
                    sc.path.display(),
                    has_cells.iter().filter(|&&b| b).count(),
                    mesh.node_ids[any],
                    size[q]
                );
            }
        }

        // loads
        let mut loads = Vec::new();
        for (k, l) in f.load.iter().enumerate() {
            let key = if l.node.is_some() {
                "node"
            } else if l.nearest.is_some() {
                "nearest"
            } else {
                "patch"
            };
            let (nodes, weights): (Vec<u32>, Vec<f64>) = match (l.node, l.nearest, &l.patch) {
                (Some(id), None, None) => match mesh.node_ids.iter().position(|&x| x == id) {
                    Some(i) => (vec![i as u32], vec![1.0]),
                    None => {
                        return Err(sc.err(
                            "load",
                            k,
                            "node",
                            format!("node {id} is not in the mesh; fix: use a node id of the mesh file"),
                        ))
                    }
                },
                (None, Some(p), None) => {
                    if !finite3(&p) {
                        return Err(sc.err("load", k, "nearest", "has a non-finite coordinate"));
                    }
                    let n = nearest_surface_node(&mesh, p)
                        .ok_or_else(|| sc.err("load", k, "nearest", "the mesh has no surface node"))?;
                    (vec![n], vec![1.0])
                }
                (None, None, Some(ps)) => {
                    if !(finite3(&ps.center) && ps.radius > 0.0 && ps.radius.is_finite()) {
                        return Err(sc.err(
                            "load",
                            k,
                            "patch",
                            "needs a finite center and a positive radius",
                        ));
                    }
                    let area = surface_node_areas(&mesh);
                    let picked: Vec<u32> = (0..mesh.n_nodes())
                        .filter(|&i| area[i] > 0.0 && norm(sub(mesh.points[i], ps.center)) <= ps.radius)
                        .map(|i| i as u32)
                        .collect();
                    if picked.is_empty() {
                        return Err(sc.err(
                            "load",
                            k,
                            "patch",
                            format!(
                                "no surface node within {} of {:?}; fix: move the center onto the surface or widen the radius (eprop info MESH gives the bounds)",
                                ps.radius, ps.center
                            ),
                        ));
                    }
                    let total: f64 = picked.iter().map(|&i| area[i as usize]).sum();
                    let w = picked.iter().map(|&i| area[i as usize] / total).collect();
                    (picked, w)
                }
                _ => {
                    return Err(sc.err(
                        "load",
                        k,
                        "node",
                        "give exactly one of `node = ID`, `nearest = [x, y, z]` or `patch = { center = [x, y, z], radius = R }`",
                    ))
                }
            };
            if let Some(&bad) = nodes.iter().find(|&&n| fixed[n as usize]) {
                return Err(sc.err(
                    "load",
                    k,
                    key,
                    format!(
                        "the load's node {} is in the fixed set; fix: load free nodes or shrink the [[fixed]] set",
                        mesh.node_ids[bad as usize]
                    ),
                ));
            }
            let (force, normal) = match (l.force, l.normal) {
                (Some(fv), None) => {
                    if !finite3(&fv) {
                        return Err(sc.err("load", k, "force", "has a non-finite component"));
                    }
                    (fv, None)
                }
                (None, Some(mag)) => {
                    if !mag.is_finite() {
                        return Err(sc.err("load", k, "normal", "must be a finite number"));
                    }
                    ([0.0; 3], Some(mag))
                }
                _ => {
                    return Err(sc.err(
                        "load",
                        k,
                        "force",
                        "give exactly one of `force = [fx, fy, fz]` or `normal = magnitude`",
                    ))
                }
            };
            if let Some(rp) = &l.ramp {
                if rp.is_empty()
                    || rp.windows(2).any(|w| !(w[1][0] > w[0][0]))
                    || rp.iter().any(|p| !p[0].is_finite() || !p[1].is_finite())
                {
                    return Err(sc.err(
                        "load",
                        k,
                        "ramp",
                        "must be [[t, scale], ...] with finite values and strictly increasing times",
                    ));
                }
            }
            loads.push(Load {
                depth: l.patch.as_ref().map(|p| p.radius),
                node_ids: nodes.iter().map(|&n| mesh.node_ids[n as usize]).collect(),
                nodes,
                weights,
                force,
                area: 0.0,
                ramp: l.ramp.clone(),
                normal,
            });
        }

        // time
        let tm = &f.time;
        let stop = match (tm.steps, tm.end, tm.equilibrium) {
            (Some(s), None, None) => Stop::Steps(s),
            (None, Some(e), None) if e > 0.0 && e.is_finite() => Stop::End(e),
            (None, Some(_), None) => return Err(sc.err("time", 0, "end", "must be a positive time")),
            (s, None, Some(tol)) if tol > 0.0 && tol.is_finite() => Stop::Equilibrium {
                tol,
                max_steps: s.unwrap_or(1_000_000),
            },
            (_, None, Some(_)) => {
                return Err(sc.err("time", 0, "equilibrium", "must be a positive velocity tolerance"))
            }
            (None, None, None) => {
                return Err(sc.err(
                    "time",
                    0,
                    "steps",
                    "say when to stop: `steps = N`, `end = T` or `equilibrium = tol`",
                ))
            }
            _ => {
                return Err(sc.err(
                    "time",
                    0,
                    "steps",
                    "give one of `steps`, `end` or `equilibrium` (steps may cap equilibrium)",
                ))
            }
        };
        for (key, v) in [("dt", tm.dt), ("h", tm.h)] {
            if let Some(v) = v {
                if !(v > 0.0 && v.is_finite()) {
                    return Err(sc.err("time", 0, key, "must be a positive number"));
                }
            }
        }
        if f.output.every == 0 {
            return Err(sc.err("output", 0, "every", "must be at least 1"));
        }
        let names: Vec<&str> = FIELDS.iter().map(|f| f.0).collect();
        for (k, name) in f.output.fields.iter().enumerate() {
            if !names.contains(&name.as_str()) {
                return Err(sc.err(
                    "output",
                    0,
                    "fields",
                    format!("`{name}` is not a field; fix: choose from {names:?}"),
                ));
            }
            if f.output.fields[..k].contains(name) {
                return Err(sc.err("output", 0, "fields", format!("`{name}` is listed twice")));
            }
        }
        if f.output.fields.is_empty() {
            return Err(sc.err("output", 0, "fields", format!("is empty; fix: list some of {names:?}")));
        }
        if !["float64", "float32"].contains(&f.output.precision.as_str()) {
            return Err(sc.err(
                "output",
                0,
                "precision",
                format!(
                    "`{}` is not a precision; fix: use \"float64\" or \"float32\"",
                    f.output.precision
                ),
            ));
        }
        if f.output.compression > 9 {
            return Err(sc.err("output", 0, "compression", "must be a gzip level from 0 (off) to 9"));
        }
        let output = scenario.output_path();
        Ok(Setup {
            law: TissueLaw {
                young: t.young,
                beta: t.beta,
            },
            stiffness: md.stiffness,
            coupling: md.coupling,
            exponent: md.exponent,
            scheme,
            stop,
            dt: tm.dt,
            h: tm.h,
            every: f.output.every,
            integrator,
            output,
            scenario,
            mesh,
            r,
            mass,
            damping,
            fixed,
            loads,
        })
    }
}

impl Setup {
    /// The view of one process: the plan's cells and nodes renumbered locally (owned, then
    /// halo) with their per-node arrays. Loads keep their global node indices.
    pub fn restrict(&self, plan: &eprop_partition::Plan) -> Setup {
        let pick = |g: &u32| *g as usize;
        let ids = &plan.numbering.global;
        Setup {
            scenario: self.scenario.clone(),
            mesh: crate::solver::local_mesh(&self.mesh, plan),
            r: ids.iter().map(|g| self.r[pick(g)]).collect(),
            mass: ids.iter().map(|g| self.mass[pick(g)]).collect(),
            damping: ids.iter().map(|g| self.damping[pick(g)]).collect(),
            fixed: ids.iter().map(|g| self.fixed[pick(g)]).collect(),
            loads: self.loads.clone(),
            scheme: self.scheme,
            stiffness: self.stiffness,
            coupling: self.coupling,
            exponent: self.exponent,
            law: self.law,
            stop: self.stop,
            dt: self.dt,
            h: self.h,
            output: self.output.clone(),
            every: self.every,
            integrator: self.integrator.clone(),
        }
    }
}

fn selector_key(s: &SelectSec) -> &'static str {
    if s.bbox.is_some() {
        "box"
    } else if s.sphere.is_some() {
        "sphere"
    } else if s.halfspace.is_some() {
        "halfspace"
    } else if s.nodes.is_some() {
        "nodes"
    } else if s.tag.is_some() {
        "tag"
    } else {
        "group"
    }
}

/// Nodes selected by one selector (exactly one of its keys must be set).
pub fn select(sc: &Scenario, mesh: &Mesh, s: &SelectSec, section: &str, k: usize) -> Result<Vec<bool>> {
    let n = mesh.n_nodes();
    let count = [
        s.bbox.is_some(),
        s.sphere.is_some(),
        s.halfspace.is_some(),
        s.nodes.is_some(),
        s.tag.is_some(),
        s.group.is_some(),
    ]
    .iter()
    .filter(|&&b| b)
    .count();
    if count != 1 {
        return Err(sc.err(
            section,
            k,
            selector_key(s),
            "give exactly one of box, sphere, halfspace, nodes, tag or group",
        ));
    }
    let mut set = vec![false; n];
    if let Some(b) = &s.bbox {
        if !finite3(&b[0]) || !finite3(&b[1]) || (0..3).any(|d| b[0][d] > b[1][d]) {
            return Err(sc.err(
                section,
                k,
                "box",
                "must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min <= max",
            ));
        }
        for (i, p) in mesh.points.iter().enumerate() {
            set[i] = (0..3).all(|d| p[d] >= b[0][d] && p[d] <= b[1][d]);
        }
    } else if let Some(sp) = &s.sphere {
        if !(finite3(&sp.center) && sp.radius > 0.0 && sp.radius.is_finite()) {
            return Err(sc.err(section, k, "sphere", "needs a finite center and a positive radius"));
        }
        for (i, p) in mesh.points.iter().enumerate() {
            set[i] = norm(sub(*p, sp.center)) <= sp.radius;
        }
    } else if let Some(h) = &s.halfspace {
        let nn = norm(h.normal);
        if !(finite3(&h.point) && nn > 0.0 && nn.is_finite()) {
            return Err(sc.err(section, k, "halfspace", "needs a finite point and a non-zero normal"));
        }
        // the half-space is the side the normal points to, boundary included (with a tolerance)
        let (lo, hi) = mesh.bounds();
        let tol = 1e-9 * norm(sub(hi, lo));
        for (i, p) in mesh.points.iter().enumerate() {
            set[i] = dot(sub(*p, h.point), h.normal) / nn >= -tol;
        }
    } else if let Some(ids) = &s.nodes {
        let index: std::collections::HashMap<u64, usize> =
            mesh.node_ids.iter().enumerate().map(|(i, &id)| (id, i)).collect();
        for id in ids {
            match index.get(id) {
                Some(&i) => set[i] = true,
                None => return Err(sc.err(section, k, "nodes", format!("node {id} is not in the mesh"))),
            }
        }
    } else {
        let tags: Vec<(Option<u8>, i32)> = if let Some(t) = s.tag {
            vec![(None, t)]
        } else {
            let name = s.group.as_ref().unwrap();
            let found: Vec<(Option<u8>, i32)> = mesh
                .group_names
                .iter()
                .filter(|(_, v)| *v == name)
                .map(|((d, t), _)| (Some(*d), *t))
                .collect();
            if found.is_empty() {
                let known: Vec<&str> = mesh.group_names.values().map(|s| s.as_str()).collect();
                return Err(sc.err(
                    section,
                    k,
                    "group",
                    format!(
                        "no physical group `{name}` in {}; known groups: {:?}; fix: name one of those, or select by `tag = N`, `box`, `sphere` or `halfspace` (.vtu, .vtk and TetGen files carry tags but no group names)",
                        mesh.source, known
                    ),
                ));
            }
            found
        };
        for &(dim, t) in &tags {
            if dim.is_none() || dim == Some(3) {
                for c in 0..mesh.n_cells() {
                    if mesh.cell_tags[c] == t {
                        for &v in mesh.cell(c) {
                            set[v as usize] = true;
                        }
                    }
                }
            }
            for fct in 0..mesh.facets.len() {
                if mesh.facets.tags[fct] == t && dim.is_none_or(|d| d == mesh.facets.dim[fct]) {
                    for &v in mesh.facets.nodes(fct) {
                        set[v as usize] = true;
                    }
                }
            }
        }
    }
    Ok(set)
}

/// The surface node nearest to a point (surface = on a boundary face of the volume cells).
/// The boundary dual area of every node: each boundary face's area shared equally by its
/// corners (exact for the median dual of triangles; quadrilaterals are split evenly).
pub fn surface_node_areas(mesh: &Mesh) -> Vec<f64> {
    let mut area = vec![0.0; mesh.n_nodes()];
    for (c, f) in eprop_io::mesh::boundary_faces(mesh) {
        let cell = mesh.cell(c as usize);
        let face = mesh.kinds[c as usize].faces()[f as usize];
        let pts: Vec<[f64; 3]> = face.iter().map(|&l| mesh.points[cell[l] as usize]).collect();
        let a = norm(eprop_io::geom::loop_area(&pts)) / face.len() as f64;
        for &l in face {
            area[cell[l] as usize] += a;
        }
    }
    area
}

pub fn nearest_surface_node(mesh: &Mesh, p: [f64; 3]) -> Option<u32> {
    let mut on_surface = vec![false; mesh.n_nodes()];
    for (c, f) in eprop_io::mesh::boundary_faces(mesh) {
        let cell = mesh.cell(c as usize);
        for &l in mesh.kinds[c as usize].faces()[f as usize].iter() {
            on_surface[cell[l] as usize] = true;
        }
    }
    (0..mesh.n_nodes())
        .filter(|&i| on_surface[i])
        .min_by(|&a, &b| {
            let da = norm(sub(mesh.points[a], p));
            let db = norm(sub(mesh.points[b], p));
            da.partial_cmp(&db).unwrap().then(a.cmp(&b))
        })
        .map(|i| i as u32)
}
