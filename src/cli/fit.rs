//! `eprop fit`: chosen scenario parameters fitted to a measured curve by least squares
//! (docs/fit.md).
//!
//! The curve is a CSV file of two named columns: x (the time, or the indentation of a tool) and
//! y (the force of a tool, or the displacement of a load's probe or of a node). Each evaluation
//! is a full simulation of the scenario with the parameters applied through the same overrides
//! as `--set` (`config::set`), in this process or on every process of the MPI job (rank 0
//! decides the parameters and broadcasts them and the curve; the simulations are rank
//! independent, so the fit is the same on any number of processes). Nothing is written for an
//! evaluation: the measured quantity is sampled at every step and interpolated linearly at the
//! curve's x.
//!
//! The minimiser is a small bounded Levenberg-Marquardt of our own (`lm`) rather than a crate's:
//! each residual vector costs a full simulation, so the Jacobian is by forward differences in the
//! bounded (log for positive bounds) parameter space with steps that stay inside the bounds; the
//! bounds are honoured by projection with the parameters held at a bound where the gradient
//! pushes out; and every evaluation prints a progress line. The `levenberg-marquardt` crate
//! drives its own evaluations and Jacobian without bounds, and argmin has no bounded
//! Levenberg-Marquardt.

use crate::cli::run::start_mpi_if_needed;
use anyhow::{anyhow, bail, Result};
use eprop::config::Input;
use eprop::config::{Reading, Scenario, Setup};
use eprop::diagnostics::short;
use eprop::distribute::comm::Comm;
use eprop::distribute::launch::is_root;
use eprop::distribute::launch::{Agreed, EXIT_ERROR, EXIT_STOPPED};
use eprop::guard::safety;
use eprop::linalg::V3;
use eprop::simulate::distributed::build_mpi;
use eprop::simulate::{Simulation, StopToken};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The parameters `--param` knows by a short name, and the scenario key each one sets. Any
/// other scenario key is named by its TOML path (`load.1.normal`).
pub const NAMES: &[(&str, &str)] = &[
    ("young", "tissue.young"),
    ("beta", "tissue.beta"),
    ("conductivity", "material.conductivity"),
    ("mass", "material.mass"),
    ("damping", "material.damping"),
    ("stiffness", "model.stiffness"),
    ("coupling", "model.coupling"),
    ("exponent", "model.exponent"),
];

/// What `eprop fit` was asked.
#[derive(Clone, Debug)]
pub struct FitOptions {
    /// The measured curves: `FILE` or `FILE:KEY=VALUE,...` (`parse_spec`).
    pub data: Vec<String>,
    /// `NAME=LO:HI`, one per fitted parameter.
    pub params: Vec<String>,
    /// `NAME=VALUE`: starting values (default: the middle of the bounds).
    pub starts: Vec<String>,
    /// The tool (1-based) whose force or indentation is measured.
    pub tool: usize,
    /// The load (1-based) whose probe displacement is measured.
    pub load: usize,
    /// A node (the mesh file's id) whose displacement is measured instead of a load's probe.
    pub node: Option<u64>,
    /// Overrides of other scenario keys, applied to every evaluation before the parameters.
    pub sets: Vec<String>,
    /// Report prefix: PREFIX.json, PREFIX.csv, PREFIX.png.
    pub prefix: Option<PathBuf>,
    pub max_evaluations: usize,
    pub tolerance: f64,
    pub quiet: bool,
    pub plot: bool,
    pub overwrite: bool,
}

/// One fitted parameter.
#[derive(Clone, Debug)]
struct Param {
    name: String,
    key: String,
    lo: f64,
    hi: f64,
    start: f64,
    /// Fitted as ln(value) (both bounds positive).
    log: bool,
}

impl Param {
    fn z(&self, p: f64) -> f64 {
        if self.log {
            p.ln()
        } else {
            p
        }
    }
    fn p(&self, z: f64) -> f64 {
        let p = if self.log { z.exp() } else { z };
        p.clamp(self.lo, self.hi)
    }
}

fn refused(msg: String) -> anyhow::Error {
    Agreed::error(EXIT_ERROR, msg)
}

fn number(s: &str) -> Option<f64> {
    s.trim().parse::<f64>().ok().filter(|v| v.is_finite())
}

/// sqrt(lo hi) for 0 < lo < hi, in logarithms where the product underflows or overflows
/// (1e-300:1e-299 starts at 3.2e-300, not 0; 1e299:1e300 at 3.2e299, not inf).
fn geometric_mean(lo: f64, hi: f64) -> f64 {
    let p = lo * hi;
    if p.is_normal() {
        p.sqrt()
    } else {
        (0.5 * (lo.ln() + hi.ln())).exp().clamp(lo, hi)
    }
}

/// `NAME=LO:HI` (and its `--start NAME=VALUE`) as a parameter.
fn parse_params(params: &[String], starts: &[String]) -> Result<Vec<Param>> {
    let known = NAMES.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", ");
    if params.is_empty() {
        return Err(refused(format!(
            "no parameter to fit; fix: name one with its bounds, e.g. --param young=20:500 (known names: {known}; or a scenario key path such as load.1.normal)"
        )));
    }
    let mut out: Vec<Param> = vec![];
    for s in params {
        let (name, range) = s.split_once('=').ok_or_else(|| {
            refused(format!(
                "--param {s}: not NAME=LO:HI; fix: give the parameter and its bounds, e.g. --param young=20:500"
            ))
        })?;
        let name = name.trim();
        let key = match NAMES.iter().find(|(n, _)| *n == name) {
            Some((_, k)) => k.to_string(),
            None if name.contains('.') => name.to_string(),
            None => {
                return Err(refused(format!(
                    "--param {s}: unknown parameter `{name}`; fix: one of {known}, or a scenario key by its TOML path (as --set takes it), e.g. load.1.normal"
                )))
            }
        };
        let (lo, hi) = match range.split_once(':').map(|(a, b)| (number(a), number(b))) {
            Some((Some(lo), Some(hi))) => (lo, hi),
            _ => {
                return Err(refused(format!(
                    "--param {s}: `{range}` is not LO:HI; fix: two finite numbers, the lower bound first, e.g. --param {name}=20:500"
                )))
            }
        };
        if lo >= hi {
            return Err(refused(format!(
                "--param {s}: the lower bound {} is not below the upper bound {}; fix: LO < HI, e.g. --param {name}={}:{}",
                short(lo),
                short(hi),
                short(lo.min(hi)),
                short(if lo == hi { 2.0 * hi.abs().max(1.0) } else { lo.max(hi) })
            )));
        }
        if out.iter().any(|p| p.key == key) {
            return Err(refused(format!(
                "--param {s}: `{name}` ({key}) is fitted twice; fix: give each parameter once"
            )));
        }
        let log = lo > 0.0;
        let start = if log {
            geometric_mean(lo, hi)
        } else {
            0.5 * lo + 0.5 * hi
        };
        out.push(Param {
            name: name.to_string(),
            key,
            lo,
            hi,
            start,
            log,
        });
    }
    for s in starts {
        let (name, v) = s.split_once('=').ok_or_else(|| {
            refused(format!(
                "--start {s}: not NAME=VALUE; fix: a fitted parameter and its starting value, e.g. --start young=80"
            ))
        })?;
        let name = name.trim();
        let Some(p) = out.iter_mut().find(|p| p.name == name) else {
            return Err(refused(format!(
                "--start {s}: `{name}` is not a fitted parameter; fix: give it a --param {name}=LO:HI, or start one of {}",
                params.iter().filter_map(|p| p.split_once('=').map(|(n, _)| n.trim())).collect::<Vec<_>>().join(", ")
            )));
        };
        match number(v) {
            Some(v) if (p.lo..=p.hi).contains(&v) => p.start = v,
            _ => {
                return Err(refused(format!(
                    "--start {s}: `{}` is not a number within the bounds {}:{}; fix: a start inside the bounds of --param {name}",
                    v.trim(),
                    short(p.lo),
                    short(p.hi)
                )))
            }
        }
    }
    Ok(out)
}

/// What the curve's x column is.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum XKind {
    Time,
    Indentation,
    /// A rest coordinate along a line of nodes (a profile at the tool's deepest step).
    X,
    Y,
    Z,
}

/// What the curve's y column is.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum YKind {
    Force,
    Displacement,
    /// One component of the displacement (signed).
    Ux,
    Uy,
    Uz,
}

impl XKind {
    pub fn name(&self) -> &'static str {
        match self {
            XKind::Time => "time",
            XKind::Indentation => "indentation",
            XKind::X => "x",
            XKind::Y => "y",
            XKind::Z => "z",
        }
    }
    const ALL: [XKind; 5] = [XKind::Time, XKind::Indentation, XKind::X, XKind::Y, XKind::Z];
    /// The axis of a profile's x (0, 1, 2), None for time and indentation.
    fn axis(&self) -> Option<usize> {
        match self {
            XKind::X => Some(0),
            XKind::Y => Some(1),
            XKind::Z => Some(2),
            _ => None,
        }
    }
    fn is_length(&self) -> bool {
        *self != XKind::Time
    }
}

impl YKind {
    pub fn name(&self) -> &'static str {
        match self {
            YKind::Force => "force",
            YKind::Displacement => "displacement",
            YKind::Ux => "ux",
            YKind::Uy => "uy",
            YKind::Uz => "uz",
        }
    }
    const ALL: [YKind; 5] = [YKind::Force, YKind::Displacement, YKind::Ux, YKind::Uy, YKind::Uz];
    /// The measured component of a displacement (None: its magnitude, or a force).
    fn component(&self) -> Option<usize> {
        match self {
            YKind::Ux => Some(0),
            YKind::Uy => Some(1),
            YKind::Uz => Some(2),
            _ => None,
        }
    }
}

/// One `--data FILE[:KEY=VALUE,...]`: a curve file and what it measures.
#[derive(Clone, Debug, PartialEq)]
pub struct CurveSpec {
    pub file: PathBuf,
    /// Its weight in the sum of squares (default 1).
    pub weight: f64,
    /// The tool (1-based) of a force, an indentation or a profile's deepest step.
    pub tool: usize,
    /// The load (1-based) whose probe a displacement is.
    pub load: usize,
    /// The node (mesh file id) whose displacement is measured instead of a load's probe.
    pub node: Option<u64>,
    /// A profile's line: the two rest coordinates other than its x, in the x column's unit.
    pub line: [Option<f64>; 3],
    /// A node is on the line within this distance (the x column's unit; default 1e-6 of the
    /// mesh's extent).
    pub tol: Option<f64>,
}

/// The keys a `--data` suffix takes, for messages.
pub const DATA_KEYS: &str =
    "weight=W, tool=K, load=K, node=ID, and for a profile x=, y=, z= (two of them: the line) and tol=";

/// `FILE` or `FILE:KEY=VALUE,...` (the tool, load and node default to --tool, --load, --node).
pub fn parse_spec(s: &str, tool: usize, load: usize, node: Option<u64>) -> Result<CurveSpec> {
    let mut spec = CurveSpec {
        file: PathBuf::from(s),
        weight: 1.0,
        tool,
        load,
        node,
        line: [None; 3],
        tol: None,
    };
    let Some((file, keys)) = s
        .rsplit_once(':')
        .filter(|(_, k)| k.contains('=') && !Path::new(s).exists())
    else {
        return Ok(spec);
    };
    spec.file = PathBuf::from(file);
    for kv in keys.split(',') {
        let bad = |why: &str| {
            refused(format!(
                "--data {s}: `{kv}` {why}; fix: FILE:KEY=VALUE,... with the keys {DATA_KEYS}, e.g. --data dent.csv:node=42,weight=0.5"
            ))
        };
        let (k, v) = kv.split_once('=').ok_or_else(|| bad("is not KEY=VALUE"))?;
        let (k, v) = (k.trim(), v.trim());
        let count = |v: &str| v.parse::<u64>().ok().filter(|&n| n > 0);
        match k {
            "weight" => {
                spec.weight = number(v)
                    .filter(|&w| w > 0.0)
                    .ok_or_else(|| bad("is not a positive weight"))?
            }
            "tool" => spec.tool = count(v).ok_or_else(|| bad("is not a tool number (1, 2, ...)"))? as usize,
            "load" => spec.load = count(v).ok_or_else(|| bad("is not a load number (1, 2, ...)"))? as usize,
            "node" => spec.node = Some(v.parse().map_err(|_| bad("is not a node id"))?),
            "x" | "y" | "z" => {
                let a = usize::from(k.as_bytes()[0] - b'x');
                spec.line[a] = Some(number(v).ok_or_else(|| bad("is not a finite coordinate"))?)
            }
            "tol" => {
                spec.tol = Some(
                    number(v)
                        .filter(|&t| t > 0.0)
                        .ok_or_else(|| bad("is not a positive distance"))?,
                )
            }
            _ => return Err(bad("is not a known key")),
        }
    }
    Ok(spec)
}

/// A measured curve: x and y in the scenario's units (the header's units applied).
#[derive(Clone, Debug)]
struct Curve {
    spec: CurveSpec,
    x_kind: XKind,
    y_kind: YKind,
    x: Vec<f64>,
    y: Vec<f64>,
    /// The factors the file's x and y were multiplied by (its header's units), 1 without.
    factor: [f64; 2],
    /// The header's units as written (rank 0; empty without).
    units: [String; 2],
}

/// The accepted column names, for messages and --help.
pub const X_NAMES: &str = "`time` (or `t`), `indentation`, or `x`, `y`, `z` (a profile along a line of nodes)";
pub const Y_NAMES: &str = "`force`, `displacement`, or `ux`, `uy`, `uz` (one component)";

/// A header name without case or spaces, and its unit in brackets: "Force (N)" is (`force`, `N`).
fn column(s: &str) -> (String, Option<String>) {
    let s = s.trim();
    match s.find(['(', '[']) {
        Some(k) => {
            let unit = s[k + 1..].trim_end().trim_end_matches([')', ']']).trim().to_string();
            (s[..k].trim().to_ascii_lowercase(), Some(unit))
        }
        None => (s.to_ascii_lowercase(), None),
    }
}

/// A header name without case, spaces or a unit in brackets: "Force (N)" is `force`.
fn column_name(s: &str) -> String {
    column(s).0
}

/// The units a column of this kind takes, with their factors to SI.
fn units_of(length: bool, time: bool) -> &'static [(&'static str, f64)] {
    const LENGTH: &[(&str, f64)] = &[("m", 1.0), ("cm", 1e-2), ("mm", 1e-3), ("um", 1e-6), ("µm", 1e-6)];
    const TIME: &[(&str, f64)] = &[("s", 1.0), ("ms", 1e-3), ("min", 60.0)];
    const FORCE: &[(&str, f64)] = &[("N", 1.0), ("mN", 1e-3), ("uN", 1e-6), ("µN", 1e-6), ("kN", 1e3)];
    match (length, time) {
        (true, _) => LENGTH,
        (_, true) => TIME,
        _ => FORCE,
    }
}

/// The factor of a column's unit in the scenario's units; None without a unit. A unit the
/// column does not take, or any unit in the paper's unit-free reading, is refused with the fix.
fn unit_factor(
    name: &Path,
    line: usize,
    col: &str,
    unit: Option<&str>,
    length: bool,
    time: bool,
    reading: Reading,
) -> Result<f64> {
    let name = name.display();
    let Some(unit) = unit else { return Ok(1.0) };
    let known = units_of(length, time);
    let list = known.iter().map(|(u, _)| *u).collect::<Vec<_>>().join(", ");
    let bare = column_name(col);
    if reading == Reading::Paper {
        return Err(refused(format!(
            "{name}:{line}: the column `{col}` has the unit `{unit}`, and the scenario reads the paper's unit-free model ([model] reading = \"paper\"), whose values have no unit to convert to; fix: write the header `{bare}` and the values in the scenario's own units"
        )));
    }
    match known.iter().find(|(u, _)| *u == unit) {
        Some((_, f)) => Ok(*f),
        None => Err(refused(format!(
            "{name}:{line}: the column `{col}` has the unit `{unit}`, which eprop does not know for a {}; fix: one of {list} (e.g. `{bare} ({})`), or convert the values to one of them",
            if length { "length" } else if time { "time" } else { "force" },
            known[0].0
        ))),
    }
}

fn fields(line: &str) -> Vec<&str> {
    if line.contains(',') {
        line.split(',').map(str::trim).collect()
    } else {
        line.split_whitespace().collect()
    }
}

/// Reads a curve: a header row naming x and y, then rows of two numbers with x increasing;
/// blank lines and lines starting with `#` are skipped. The header's units are converted to the
/// scenario's (`reading`: the paper's reading has none).
fn read_curve(spec: &CurveSpec, reading: Reading) -> Result<Curve> {
    let path = &spec.file;
    let name = path.display();
    let text = std::fs::read_to_string(path).map_err(|e| {
        anyhow!("{name}: cannot read the measured curve: {e}; fix: give a CSV file with a header row, e.g. `indentation,force`")
    })?;
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let Some((hl, header)) = lines.next() else {
        bail!("{name}: the file is empty; fix: a header row (e.g. `time,displacement`), then one row per point");
    };
    let cols = fields(header);
    if cols.len() != 2 {
        bail!(
            "{name}:{hl}: the header has {} column(s), `{header}`; fix: two columns, x then y, e.g. `indentation,force` or `time,displacement`",
            cols.len()
        );
    }
    let ((xn, xu), (yn, yu)) = (column(cols[0]), column(cols[1]));
    let x_kind = match XKind::ALL.iter().find(|k| k.name() == xn || (xn == "t" && **k == XKind::Time)) {
        Some(k) => *k,
        None if number(cols[0]).is_some() => bail!(
            "{name}:{hl}: the first row is numbers, not a header; fix: add a header row naming the columns, x ({X_NAMES}) then y ({Y_NAMES}), e.g. `time,displacement`"
        ),
        None => bail!(
            "{name}:{hl}: the x column is named `{}`; fix: name it {X_NAMES} (a unit in brackets may follow: `indentation (mm)`)",
            cols[0]
        ),
    };
    let Some(&y_kind) = YKind::ALL.iter().find(|k| k.name() == yn) else {
        bail!(
            "{name}:{hl}: the y column is named `{}`; fix: name it {Y_NAMES} (a unit in brackets may follow: `force (N)`)",
            cols[1]
        );
    };
    if x_kind.axis().is_some() && y_kind == YKind::Force {
        bail!(
            "{name}:{hl}: a profile along {} measures a displacement, not a force; fix: name the y column `displacement` (or `ux`, `uy`, `uz`)",
            x_kind.name()
        );
    }
    let fx = unit_factor(
        path,
        hl,
        cols[0],
        xu.as_deref(),
        x_kind.is_length(),
        x_kind == XKind::Time,
        reading,
    )?;
    let fy = unit_factor(path, hl, cols[1], yu.as_deref(), y_kind != YKind::Force, false, reading)?;
    let (mut x, mut y) = (vec![], vec![]);
    for (k, line) in lines {
        let f = fields(line);
        if f.len() != 2 {
            bail!(
                "{name}:{k}: {} value(s) in `{line}`; fix: two numbers per row, x then y",
                f.len()
            );
        }
        let (Some(a), Some(b)) = (number(f[0]), number(f[1])) else {
            let bad = if number(f[0]).is_none() { f[0] } else { f[1] };
            bail!("{name}:{k}: `{bad}` is not a finite number; fix: two finite numbers per row, x then y");
        };
        if let Some(&last) = x.last() {
            if a * fx <= last {
                bail!(
                    "{name}:{k}: x = {} does not increase (the row before has {}); fix: sort the rows by x and keep one row per x",
                    eprop::diagnostics::short(a),
                    eprop::diagnostics::short(last / fx)
                );
            }
        }
        x.push(a * fx);
        y.push(b * fy);
    }
    if x.len() < 2 {
        bail!(
            "{name}: {} data point(s); fix: give at least 2 points (and more points than fitted parameters)",
            x.len()
        );
    }
    Ok(Curve {
        spec: spec.clone(),
        x_kind,
        y_kind,
        x,
        y,
        factor: [fx, fy],
        units: [xu.unwrap_or_default(), yu.unwrap_or_default()],
    })
}

/// Rank 0's values, made every process's (the same length everywhere after).
fn broadcast(world: Option<&dyn Comm>, v: &mut Vec<f64>) {
    if let Some(w) = world {
        let mut n = [v.len() as f64];
        w.broadcast(0, &mut n);
        v.resize(n[0] as usize, 0.0);
        w.broadcast(0, v);
    }
}

/// What is measured of one curve in a simulation. With `evaluate` (which steps the simulation)
/// the only code here that reads a simulation: its public methods, and the fields `global` (the
/// node ids), `comm`, `u`, `time`, `step` and `stop_signal`.
struct Probe {
    x: XKind,
    y: YKind,
    tool: usize,
    load: usize,
    /// The measured node's local index where this process owns it (None elsewhere); None for
    /// a load's probe.
    node: Option<Option<usize>>,
    /// A profile: its nodes' rest coordinates along the axis (increasing) and local indices
    /// where this process has them.
    line: Vec<(f64, Option<usize>)>,
    /// The sampled polyline (time or indentation), or a profile's values at the deepest step.
    xs: Vec<f64>,
    ys: Vec<f64>,
    /// A profile: the deepest indentation of its tool so far.
    deepest: f64,
}

impl Probe {
    fn new(sim: &Simulation, scenario: &Path, c: &Curve) -> Result<Probe> {
        let path = scenario.display();
        let s = &c.spec;
        let file = s.file.display();
        let tools = sim.tool_states().len();
        let loads = sim.probes().len();
        let needs_tool = c.x_kind == XKind::Indentation || c.y_kind == YKind::Force;
        if needs_tool && !(1..=tools).contains(&s.tool) {
            bail!(
                "{path}: the curve {file}'s {} is a tool's, and the scenario has {tools} [[tool]] table(s) (tool {}); fix: a scenario with a [[tool]], or --tool 1..={tools} (or --data {file}:tool=K)",
                if c.y_kind == YKind::Force { "force" } else { "indentation" },
                s.tool
            );
        }
        let mut node = None;
        let mut line = vec![];
        if let Some(a) = c.x_kind.axis() {
            if tools > 0 && !(1..=tools).contains(&s.tool) {
                bail!("{path}: the profile {file} is taken at the deepest step of tool {}, and the scenario has {tools} [[tool]] table(s); fix: --data {file}:tool=1..={tools}", s.tool);
            }
            let others: Vec<usize> = (0..3).filter(|&b| b != a).collect();
            if others.iter().any(|&b| s.line[b].is_none()) || s.line[a].is_some() {
                bail!(
                    "{path}: the profile {file} runs along {}: name its line by the two other rest coordinates, in the x column's unit; fix: --data {file}:{}=VALUE,{}=VALUE",
                    c.x_kind.name(),
                    ["x", "y", "z"][others[0]],
                    ["x", "y", "z"][others[1]]
                );
            }
            // rank 0 has the whole mesh: the nodes on the line, broadcast
            let mut on: Vec<f64> = vec![];
            if let Some(m) = sim.global_mesh() {
                let (lo, hi) = m.bounds();
                let tol = s
                    .tol
                    .map_or(1e-6 * eprop::config::distance(hi, lo), |t| t * c.factor[0]);
                let mut hits: Vec<(f64, usize)> = m
                    .points
                    .iter()
                    .enumerate()
                    .filter(|(_, p)| {
                        others
                            .iter()
                            .all(|&b| (p[b] - s.line[b].unwrap_or(0.0) * c.factor[0]).abs() <= tol)
                    })
                    .map(|(g, p)| (p[a], g))
                    .collect();
                hits.sort_by(|p, q| p.0.total_cmp(&q.0));
                hits.dedup_by(|p, q| p.0 == q.0);
                on = hits.iter().flat_map(|&(x, g)| [x, g as f64]).collect();
            }
            broadcast(Some(sim.comm()), &mut on);
            if on.len() < 4 {
                bail!(
                    "{path}: the profile {file}: {} node(s) of the mesh lie on its line ({}); fix: the rest coordinates of a line of nodes (in the x column's unit), or a wider tol=",
                    on.len() / 2,
                    others.iter().map(|&b| format!("{} = {}", ["x", "y", "z"][b], short(s.line[b].unwrap_or(0.0)))).collect::<Vec<_>>().join(", ")
                );
            }
            line = on.chunks(2).map(|p| (p[0], sim.local(p[1] as u32))).collect();
        } else if c.y_kind != YKind::Force {
            match s.node {
                Some(id) => {
                    // rank 0 has the whole mesh and its node ids
                    let g = match sim.global_mesh() {
                        Some(m) => m.node_ids.iter().position(|&x| x == id).map_or(-1.0, |g| g as f64),
                        None => -1.0,
                    };
                    let g = sim.comm().max(g);
                    if g < 0.0 {
                        bail!("{path}: --node {id}: the mesh has no node with that id; fix: a node id of the mesh file (as [[load]] node = ID takes it) for the curve {file}");
                    }
                    node = Some(sim.local(g as u32));
                }
                None if !(1..=loads).contains(&s.load) => bail!(
                    "{path}: the curve {file}'s displacement is a load's probe, and the scenario has {loads} [[load]] table(s) (load {}); fix: a scenario with a [[load]], --load 1..={loads}, or --node ID (or --data {file}:node=ID) for a node's displacement",
                    s.load
                ),
                None => {}
            }
        }
        Ok(Probe {
            x: c.x_kind,
            y: c.y_kind,
            tool: s.tool.saturating_sub(1),
            load: s.load.saturating_sub(1),
            node,
            line,
            xs: vec![],
            ys: vec![],
            deepest: f64::NEG_INFINITY,
        })
    }

    /// The measured quantity of a displacement `d`.
    fn of(&self, d: V3) -> f64 {
        match self.y.component() {
            Some(k) => d[k],
            None => eprop_io::geom::norm(d),
        }
    }

    /// Samples the simulation now (after each step); false when what it sampled is not finite.
    /// The same on every process.
    fn sample(&mut self, sim: &Simulation) -> bool {
        let tool = || sim.tool_states()[self.tool];
        if self.x.axis().is_some() {
            // a profile: at the deepest step of the tool (the last step without a tool)
            let deeper = match sim.tool_states().get(self.tool) {
                Some(t) => t.indentation > self.deepest,
                None => sim.done(),
            };
            if deeper {
                self.deepest = sim.tool_states().get(self.tool).map_or(0.0, |t| t.indentation);
                let u = sim.u();
                let local: Vec<f64> = self
                    .line
                    .iter()
                    .map(|(_, l)| l.map_or(f64::NEG_INFINITY, |i| self.of(u[i])))
                    .collect();
                self.xs = self.line.iter().map(|p| p.0).collect();
                self.ys = sim.comm().max_each(&local);
            }
            return self.ys.iter().all(|v| v.is_finite());
        }
        let x = match self.x {
            XKind::Indentation => tool().indentation,
            _ => sim.time(),
        };
        let y = match (self.y, self.node) {
            (YKind::Force, _) => eprop_io::geom::norm(tool().force),
            (_, None) => self.of(sim.probes()[self.load].1),
            (_, Some(local)) => {
                let none = if self.y.component().is_some() {
                    f64::NEG_INFINITY
                } else {
                    0.0
                };
                sim.comm().max(local.map_or(none, |i| self.of(sim.u()[i])))
            }
        };
        // indentation: the loading branch, the steps where the tool passes its deepest so far
        if self.x == XKind::Time || self.xs.last().is_none_or(|&l| x > l) {
            self.xs.push(x);
            self.ys.push(y);
        }
        x.is_finite() && y.is_finite()
    }

    /// The measured y at the curve's x, or why there is none.
    fn at(&self, c: &Curve) -> std::result::Result<Vec<f64>, String> {
        c.x.iter()
            .map(|&x| interpolate(&self.xs, &self.ys, x))
            .collect::<Option<Vec<f64>>>()
            .ok_or_else(|| {
                let what = match c.x_kind {
                    XKind::Time => "time",
                    XKind::Indentation => "indentation (loading branch)",
                    _ => "profile's nodes along its line",
                };
                format!(
                    "the curve's x {} .. {} is beyond the simulated {what} {:.6e} .. {:.6e} ({})",
                    short(c.x[0]),
                    short(c.x[c.x.len() - 1]),
                    self.xs.first().copied().unwrap_or(f64::NAN),
                    self.xs.last().copied().unwrap_or(f64::NAN),
                    c.spec.file.display()
                )
            })
    }
}

/// An evaluation that gave no curve: why, in a few words.
type Outcome = std::result::Result<Vec<f64>, String>;

/// One full simulation with the parameter values `p` applied; the measured y at every curve's
/// x (the curves one after the other), or why there is none (a state that is no longer finite,
/// x beyond the simulated range). A request on `stop` (a signal) ends it after the step in
/// progress.
fn evaluate(
    world: Option<&dyn Comm>,
    stop: &StopToken,
    scenario: &Path,
    opts: &FitOptions,
    params: &[Param],
    p: &[f64],
    curves: &[Curve],
) -> Result<Outcome> {
    let mut p = p.to_vec();
    broadcast(world, &mut p); // rank 0 decides
    let mut sets = opts.sets.clone();
    sets.extend(params.iter().zip(&p).map(|(q, v)| format!("{}={v:?}", q.key)));
    let make = || Setup::new(Scenario::load_with(scenario, &sets)?);
    let mut sim = match world {
        None => {
            let setup = make()?;
            start_mpi_if_needed(&setup)?;
            Simulation::new(setup)?
        }
        Some(w) => build_mpi(w, make)?.sim,
    };
    sim.set_stop(stop.clone());
    let mut probes = curves
        .iter()
        .map(|c| Probe::new(&sim, scenario, c))
        .collect::<Result<Vec<_>>>()?;
    // every probe samples (a profile's is collective), whatever the others found
    let mut sample_all = |sim: &Simulation| {
        let mut ok = true;
        for p in probes.iter_mut() {
            ok &= p.sample(sim);
        }
        ok
    };
    let mut finite = sample_all(&sim);
    while finite && !sim.done() {
        sim.advance()?;
        if sim.stop_signal() != 0 {
            return Err(Agreed::error(
                EXIT_STOPPED,
                format!(
                    "stopped by {} during an evaluation (step {} of {}); nothing was written",
                    crate::guard::signals::name(sim.stop_signal()),
                    sim.step(),
                    sim.max_steps()
                ),
            ));
        }
        finite = sample_all(&sim);
    }
    let mut out = match finite {
        false => Err(format!(
            "the state is no longer finite at step {} (t = {:.6e})",
            sim.step(),
            sim.time()
        )),
        true => probes
            .iter()
            .zip(curves)
            .map(|(p, c)| p.at(c))
            .collect::<std::result::Result<Vec<Vec<f64>>, String>>()
            .map(|v| v.concat()),
    };
    // the curve is rank 0's (it is the same on every process: the simulation is rank independent)
    if world.is_some() {
        let failed = sim.comm().max(f64::from(u8::from(out.is_err())));
        match out.as_mut() {
            Ok(_) if failed > 0.0 => out = Err("another process had no curve".into()),
            Ok(v) => sim.comm().broadcast(0, v),
            Err(_) => {}
        }
    }
    Ok(out)
}

/// y at x on the polyline (xs increasing); None outside [xs_0, xs_last].
fn interpolate(xs: &[f64], ys: &[f64], x: f64) -> Option<f64> {
    let (first, last) = (*xs.first()?, *xs.last()?);
    if !(x >= first && x <= last) {
        return None;
    }
    let k = xs.partition_point(|&v| v <= x);
    if k == xs.len() {
        return Some(ys[xs.len() - 1]);
    }
    let (x0, x1, y0, y1) = (xs[k - 1], xs[k], ys[k - 1], ys[k]);
    Some(y0 + (y1 - y0) * (x - x0) / (x1 - x0))
}

/// A bounded Levenberg-Marquardt on residual vectors that each cost a full simulation.
pub mod lm {
    /// Why the search stopped.
    #[derive(Clone, Debug, PartialEq)]
    pub enum Stop {
        /// An accepted step reduced the sum of squares by less than the tolerance (relative).
        Reduction,
        /// The step changed every parameter by less than the tolerance.
        Step,
        /// The residual is zero.
        Exact,
        /// The evaluation budget is spent.
        Evaluations,
        /// No step reduced the sum of squares, however short.
        NoDecrease,
        /// Every parameter is at a bound that the gradient pushes against.
        Bounds,
    }

    impl Stop {
        pub fn text(&self) -> &'static str {
            match self {
                Stop::Reduction => "the sum of squares decreased by less than the tolerance",
                Stop::Step => "the step changed every parameter by less than the tolerance",
                Stop::Exact => "the residual is zero",
                Stop::Evaluations => "the evaluation budget (--max-evaluations) is spent",
                Stop::NoDecrease => "no step reduced the sum of squares",
                Stop::Bounds => "every parameter is held at a bound",
            }
        }
    }

    /// The problem in the fitting coordinates z (each within [lo, hi]).
    pub struct Problem<'a> {
        pub lo: Vec<f64>,
        pub hi: Vec<f64>,
        /// The residuals at z, or why there are none (a rejected point).
        pub residuals: &'a mut dyn FnMut(&[f64], &str) -> anyhow::Result<Result<Vec<f64>, String>>,
        /// Maximum evaluations of the search (the start counts).
        pub max_evaluations: usize,
        /// Relative reduction of the sum of squares, and step in z relative to |z| (>= 1) ...
        pub tolerance: f64,
    }

    /// The search's end point.
    pub struct Solution {
        pub z: Vec<f64>,
        pub r: Vec<f64>,
        /// dr/dz at `z` (rows: residuals), or None when it was never computed there.
        pub jacobian: Option<Vec<Vec<f64>>>,
        pub evaluations: usize,
        pub iterations: usize,
        pub stop: Stop,
    }

    fn ss(r: &[f64]) -> f64 {
        r.iter().map(|v| v * v).sum()
    }

    /// Forward-difference step of coordinate j: 1e-6 of its range, pointing into the bounds.
    fn fd_step(lo: f64, hi: f64, z: f64) -> f64 {
        let h = 1e-6 * (hi - lo);
        if z + h <= hi {
            h
        } else {
            -h
        }
    }

    /// Solves A x = b (n small) by Gaussian elimination with partial pivoting; None when A is
    /// singular.
    pub fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
        let n = b.len();
        let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        if !(scale > 0.0) || !scale.is_finite() {
            return None;
        }
        for c in 0..n {
            let p = (c..n).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
            if !(a[p][c].abs() > 1e-14 * scale) {
                return None;
            }
            a.swap(c, p);
            b.swap(c, p);
            for r in c + 1..n {
                let f = a[r][c] / a[c][c];
                for k in c..n {
                    a[r][k] -= f * a[c][k];
                }
                b[r] -= f * b[c];
            }
        }
        let mut x = vec![0.0; n];
        for c in (0..n).rev() {
            let s: f64 = (c + 1..n).map(|k| a[c][k] * x[k]).sum();
            x[c] = (b[c] - s) / a[c][c];
        }
        Some(x)
    }

    /// The inverse of a small symmetric positive definite matrix (None when singular).
    pub fn inverse(a: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
        let n = a.len();
        let mut cols = vec![];
        for j in 0..n {
            let mut e = vec![0.0; n];
            e[j] = 1.0;
            cols.push(solve(a.to_vec(), e)?);
        }
        Some((0..n).map(|i| (0..n).map(|j| cols[j][i]).collect()).collect())
    }

    /// The Jacobian dr/dz at z (r0 = r(z)) by forward differences, one evaluation per column
    /// (the other side of z when the first is rejected).
    pub fn jacobian(
        p: &mut Problem,
        z: &[f64],
        r0: &[f64],
        names: &[String],
        evals: &mut usize,
    ) -> anyhow::Result<Vec<Vec<f64>>> {
        let (m, n) = (r0.len(), z.len());
        let mut jac = vec![vec![0.0; n]; m];
        for j in 0..n {
            let mut h = fd_step(p.lo[j], p.hi[j], z[j]);
            let mut tried = 0;
            let rj = loop {
                let mut zz = z.to_vec();
                zz[j] += h;
                *evals += 1;
                match (p.residuals)(&zz, &format!("derivative {}", names[j]))? {
                    Ok(r) => break r,
                    Err(why) if tried == 0 && z[j] - h >= p.lo[j] && z[j] - h <= p.hi[j] => {
                        tracing::info!("derivative {}: {why}; the other side", names[j]);
                        h = -h;
                        tried += 1;
                    }
                    Err(why) => anyhow::bail!(
                        "the derivative by {} could not be computed: {why}; fix: narrow its bounds away from where the simulation fails",
                        names[j]
                    ),
                }
            };
            for i in 0..m {
                jac[i][j] = (rj[i] - r0[i]) / h;
            }
        }
        Ok(jac)
    }

    /// Minimises |r(z)|^2 from z0 within [lo, hi]: Levenberg-Marquardt with Marquardt's
    /// scaling diag(J^T J), steps projected onto the bounds, and the coordinates at a bound
    /// held there while the gradient pushes out of it.
    pub fn minimize(p: &mut Problem, z0: Vec<f64>, names: &[String]) -> anyhow::Result<Solution> {
        let n = z0.len();
        let mut evals = 1;
        let mut r = match (p.residuals)(&z0, "start")? {
            Ok(r) => r,
            Err(why) => anyhow::bail!(
                "at the starting values {why}; fix: a scenario whose run covers the curve (a later [time] end, a deeper tool path) and stays finite, or other starting values"
            ),
        };
        let mut z = z0;
        let mut cost = ss(&r);
        let mut lambda = 1e-3;
        let mut iterations = 0;
        let done = |z: Vec<f64>, r, jacobian, evaluations, iterations, stop| Solution {
            z,
            r,
            jacobian,
            evaluations,
            iterations,
            stop,
        };
        loop {
            if cost == 0.0 {
                return Ok(done(z, r, None, evals, iterations, Stop::Exact));
            }
            if evals + n + 1 > p.max_evaluations {
                return Ok(done(z, r, None, evals, iterations, Stop::Evaluations));
            }
            iterations += 1;
            let jac = jacobian(p, &z, &r, names, &mut evals)?;
            let m = r.len();
            let mut a = vec![vec![0.0; n]; n];
            let mut g = vec![0.0; n];
            for i in 0..m {
                for j in 0..n {
                    g[j] += jac[i][j] * r[i];
                    for k in 0..n {
                        a[j][k] += jac[i][j] * jac[i][k];
                    }
                }
            }
            // held: at a bound with the descent direction -g pointing out of it
            let free: Vec<usize> = (0..n)
                .filter(|&j| !((z[j] <= p.lo[j] && g[j] > 0.0) || (z[j] >= p.hi[j] && g[j] < 0.0)))
                .collect();
            if free.is_empty() {
                return Ok(done(z, r, Some(jac), evals, iterations, Stop::Bounds));
            }
            let dmax = free.iter().map(|&j| a[j][j]).fold(0.0f64, f64::max);
            loop {
                if evals >= p.max_evaluations {
                    return Ok(done(z, r, Some(jac), evals, iterations, Stop::Evaluations));
                }
                if lambda > 1e16 {
                    return Ok(done(z, r, Some(jac), evals, iterations, Stop::NoDecrease));
                }
                let sub: Vec<Vec<f64>> = free
                    .iter()
                    .map(|&j| {
                        free.iter()
                            .map(|&k| {
                                a[j][k]
                                    + if j == k {
                                        lambda * a[j][j].max(1e-12 * dmax)
                                    } else {
                                        0.0
                                    }
                            })
                            .collect()
                    })
                    .collect();
                let rhs: Vec<f64> = free.iter().map(|&j| -g[j]).collect();
                let Some(d) = solve(sub, rhs) else {
                    lambda *= 10.0;
                    continue;
                };
                let mut zt = z.clone();
                for (&j, dj) in free.iter().zip(&d) {
                    zt[j] = (z[j] + dj).clamp(p.lo[j], p.hi[j]);
                }
                let small = (0..n).all(|j| (zt[j] - z[j]).abs() <= p.tolerance * z[j].abs().max(1.0));
                if zt == z {
                    return Ok(done(z, r, Some(jac), evals, iterations, Stop::Step));
                }
                evals += 1;
                let trial = (p.residuals)(&zt, &format!("step (lambda {lambda:.0e})"))?;
                match trial {
                    Ok(rt) if ss(&rt) < cost => {
                        let ct = ss(&rt);
                        let reduction = (cost - ct) / cost;
                        z = zt;
                        r = rt;
                        cost = ct;
                        lambda = (lambda / 10.0).max(1e-12);
                        if cost == 0.0 {
                            return Ok(done(z, r, None, evals, iterations, Stop::Exact));
                        }
                        if reduction <= p.tolerance {
                            return Ok(done(z, r, None, evals, iterations, Stop::Reduction));
                        }
                        if small {
                            return Ok(done(z, r, None, evals, iterations, Stop::Step));
                        }
                        break;
                    }
                    _ => {
                        if small {
                            return Ok(done(z, r, Some(jac), evals, iterations, Stop::Step));
                        }
                        lambda *= 10.0;
                    }
                }
            }
        }
    }
}

/// A fitted parameter in the report.
#[derive(Serialize, Debug, Clone)]
pub struct Fitted {
    pub name: String,
    /// The scenario key it sets.
    pub key: String,
    pub lower: f64,
    pub upper: f64,
    pub start: f64,
    pub value: f64,
    /// Fitted as ln(value) (positive bounds).
    pub log: bool,
    /// Whether the value is at one of its bounds (within 1e-9 relative).
    pub at_bound: bool,
    /// Approximate standard error: sqrt of the diagonal of s^2 (J^T J)^-1 (None when J^T J
    /// is singular: the parameter is not determined by the curves).
    pub standard_error: Option<f64>,
    /// The RMS over the curve's points of value * dy/d(value): how much y moves for a
    /// relative change of the parameter (one curve; with several, each curve's is in `curves`).
    pub sensitivity: Option<f64>,
    /// `sensitivity` over the data's scale (the report's `relative_to`); with several curves,
    /// the weighted RMS of each curve's.
    pub sensitivity_relative: f64,
}

/// One curve of a fit in the report.
#[derive(Serialize, Debug, Clone)]
pub struct CurveReport {
    pub data: String,
    pub x: XKind,
    pub y: YKind,
    /// The header's units as written ("" without), converted to the scenario's units: the
    /// report's values are in the scenario's units.
    pub x_unit: String,
    pub y_unit: String,
    pub weight: f64,
    pub points: usize,
    pub rms: f64,
    pub rms_relative: f64,
    pub relative_to: String,
    /// Per parameter (in `parameters` order): the RMS of value * dy/d(value) over this curve.
    pub sensitivity: Vec<f64>,
    /// The scale of the relative figures (`relative_to`).
    #[serde(skip)]
    pub range: f64,
}

/// The report of `eprop fit`.
#[derive(Serialize, Debug, Clone)]
pub struct FitReport {
    pub scenario: String,
    /// The curve files (one: its name; several: joined by ", ").
    pub data: String,
    /// The first curve's columns.
    pub x: XKind,
    pub y: YKind,
    /// Over every curve.
    pub points: usize,
    pub parameters: Vec<Fitted>,
    /// sqrt(mean of the squared residuals) (one curve; None with several: see `curves`).
    pub rms: Option<f64>,
    /// `rms` over the data's scale (`relative_to`); with several curves, the weighted RMS of
    /// each curve's relative RMS.
    pub rms_relative: f64,
    /// What the relative figures are relative to: "the data range" (max y - min y), or, for a
    /// flat curve, "max |y| (a flat curve)"; a curve of zeros has no scale: its relative figures
    /// are the absolute ones ("1 (a curve of zeros)"); several curves: "each curve's scale".
    pub relative_to: String,
    pub curves: Vec<CurveReport>,
    pub evaluations: usize,
    pub iterations: usize,
    pub stop: String,
    pub processes: usize,
    pub seconds: f64,
    /// The files written: PREFIX.json, PREFIX.csv and PREFIX.png (when it was drawn).
    pub files: Vec<String>,
    /// Why there is no PNG, when there is none.
    pub plot_note: Option<String>,
    /// Per point: its curve (0-based), x, measured, fitted.
    #[serde(skip)]
    pub rows: Vec<(usize, f64, f64, f64)>,
    /// Per point, value * dy/d(value) of each parameter (the Jacobian's columns scaled by
    /// the parameters, in the point's curve's units).
    #[serde(skip)]
    pub scaled_jacobian: Vec<Vec<f64>>,
}

impl std::fmt::Display for FitReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.curves.len() == 1 {
            writeln!(
                f,
                "eprop fit {} to {} ({} points, {} against {})",
                self.scenario,
                self.data,
                self.points,
                self.y.name(),
                self.x.name()
            )?;
        } else {
            writeln!(
                f,
                "eprop fit {} to {} curves ({} points)",
                self.scenario,
                self.curves.len(),
                self.points
            )?;
        }
        for p in &self.parameters {
            let se = match p.standard_error {
                Some(s) => format!("+- {s:.3e} ({:.2e} relative)", s / p.value.abs().max(f64::MIN_POSITIVE)),
                None => "+- undetermined (the curves do not fix it)".to_string(),
            };
            let sens = match p.sensitivity {
                Some(s) => format!("{s:.3e} ({:.2e} of {})", p.sensitivity_relative, self.relative_to),
                None => format!("{:.2e} of {}", p.sensitivity_relative, self.relative_to),
            };
            writeln!(
                f,
                "  {:<14} {:.6e} {se}; bounds {}:{}{}; sensitivity {sens}",
                p.name,
                p.value,
                short(p.lower),
                short(p.upper),
                if p.at_bound { " (AT A BOUND)" } else { "" },
            )?;
        }
        match self.rms {
            Some(rms) => writeln!(
                f,
                "  rms residual   {rms:.6e} ({:.3e} of {})",
                self.rms_relative, self.relative_to
            )?,
            None => {
                for (k, c) in self.curves.iter().enumerate() {
                    writeln!(
                        f,
                        "  curve {:<8} {} ({} against {}, weight {}, {} points): rms {:.6e} ({:.3e} of {})",
                        k + 1,
                        c.data,
                        c.y.name(),
                        c.x.name(),
                        short(c.weight),
                        c.points,
                        c.rms,
                        c.rms_relative,
                        c.relative_to
                    )?;
                }
                writeln!(
                    f,
                    "  rms residual   {:.3e} relative (weighted over the curves)",
                    self.rms_relative
                )?;
            }
        }
        writeln!(
            f,
            "  search         {} evaluations, {} iterations, {:.2} s on {} process(es); stopped: {}",
            self.evaluations, self.iterations, self.seconds, self.processes, self.stop
        )?;
        write!(f, "  files          {}", self.files.join(", "))?;
        if let Some(n) = &self.plot_note {
            write!(f, "\n  note           {n}")?;
        }
        Ok(())
    }
}

/// The report files of a prefix.
fn files_of(prefix: &Path) -> [PathBuf; 3] {
    let with = |ext: &str| {
        let mut s = prefix.as_os_str().to_os_string();
        s.push(ext);
        PathBuf::from(s)
    };
    [with(".json"), with(".csv"), with(".png")]
}

/// The default prefix: `<data stem>_fit` beside the data.
fn default_prefix(data: &Path) -> PathBuf {
    let stem = data
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "curve".into());
    data.with_file_name(format!("{stem}_fit"))
}

/// scripts/plot_fit.py of the checkout the executable was built in (target/release/eprop), or
/// of the source tree it was built from.
fn plot_script() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok();
    let from_exe = exe
        .iter()
        .flat_map(|e| e.ancestors().skip(1))
        .map(|d| d.join("scripts/plot_fit.py"));
    let built = std::iter::once(Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/plot_fit.py"));
    from_exe.chain(built).find(|p| p.is_file())
}

/// Why there is no PNG, and the fix.
struct NoPlot {
    why: String,
    fix: String,
}

/// Draws PREFIX.png with scripts/plot_fit.py; Err: why not, and what to do.
fn plot(prefix: &Path, png: &Path) -> std::result::Result<(), NoPlot> {
    let install = format!(
        "install matplotlib (pip install -r scripts/requirements.txt), then `python3 scripts/plot_fit.py {}`",
        prefix.display()
    );
    let script = plot_script().ok_or_else(|| NoPlot {
        why: "scripts/plot_fit.py was not found beside the eprop executable".into(),
        fix: format!("run scripts/plot_fit.py {} from an eprop checkout", prefix.display()),
    })?;
    // the checkout's environment (scripts/setup.sh makes .venv) where there is one
    let venv = script
        .parent()
        .and_then(Path::parent)
        .map(|d| d.join(".venv/bin/python"));
    let python = venv.filter(|p| p.is_file()).unwrap_or_else(|| PathBuf::from("python3"));
    let out = std::process::Command::new(&python)
        .arg(&script)
        .arg(prefix)
        .arg("-o")
        .arg(png)
        .output()
        .map_err(|e| NoPlot {
            why: format!("{} could not be started ({e})", python.display()),
            fix: install.clone(),
        })?;
    if out.status.success() {
        return Ok(());
    }
    let err = String::from_utf8_lossy(&out.stderr);
    if err.contains("No module named") {
        return Err(NoPlot {
            why: format!(
                "{} has no matplotlib ({})",
                python.display(),
                err.lines().last().unwrap_or("").trim()
            ),
            fix: install,
        });
    }
    // matplotlib is there: the script itself failed
    Err(NoPlot {
        why: format!("{} failed: {}", script.display(), err.trim()),
        fix: format!(
            "the report and curve are written; draw them yourself from {}.csv, or report the failure with those files",
            prefix.display()
        ),
    })
}

/// The scale the relative figures of a report are over, and its name: the data range, or max
/// |y| for a flat curve, or 1 for a curve of zeros.
fn data_scale(y: &[f64]) -> (f64, &'static str) {
    let (lo, hi) = y
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    // halves first: the range of values near f64::MAX does not overflow
    let range = 2.0 * (0.5 * hi - 0.5 * lo);
    let top = lo.abs().max(hi.abs());
    if range > 0.0 {
        (range, "the data range")
    } else if top > 0.0 {
        (top, "max |y| (a flat curve)")
    } else {
        (1.0, "1 (a curve of zeros)")
    }
}

/// The largest power of two at most max |y| (1 for a curve of zeros; within 2^-1000 ..
/// 2^1000, normal numbers): the unit the search measures residuals in.
fn power_of_two_near(y: &[f64]) -> f64 {
    let top = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if top > 0.0 && top.is_finite() {
        2f64.powi((top.log2().floor() as i32).clamp(-1000, 1000))
    } else {
        1.0
    }
}

/// On rank 0: checks the scenario with the parameters at their starting values, reads the
/// measured curves (their units converted to the scenario's) and claims the report files; None
/// on the other processes.
fn claim(
    w: Option<&dyn Comm>,
    scenario: &Path,
    opts: &FitOptions,
    specs: &[CurveSpec],
    params: &[Param],
    prefix: &Path,
) -> Result<Option<(Vec<Curve>, Vec<safety::OutputLock>)>> {
    let n = params.len();
    let [json_file, csv_file, png_file] = files_of(prefix);
    eprop::distribute::launch::on_root(w, || {
        // the scenario with the parameters at their starting values: the keys are checked here
        let mut sets = opts.sets.clone();
        sets.extend(params.iter().map(|q| format!("{}={:?}", q.key, q.start)));
        let sc = Scenario::load_with(scenario, &sets)?;
        let curves = specs
            .iter()
            .map(|s| read_curve(s, sc.file.model.reading))
            .collect::<Result<Vec<Curve>>>()?;
        let points: usize = curves.iter().map(|c| c.x.len()).sum();
        if points <= n {
            bail!(
                "{}: {points} points for {n} fitted parameter(s); fix: give more points than parameters",
                specs
                    .iter()
                    .map(|s| s.file.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        // the automatic dt follows mass, damping and stiffness, and the discretisation with it
        let moves_dt = ["material.mass", "material.damping", "model.stiffness"];
        if sc.file.time.get_ref().dt.is_none() && !opts.quiet {
            for p in params.iter().filter(|p| moves_dt.contains(&p.key.as_str())) {
                eprintln!(
                    "warning: {}: [time] dt is automatic, and it follows the fitted {}: the step count and the discretisation change with it, so the residual jumps and the search may stop in a local minimum; fix: set [time] dt (or --set time.dt=VALUE) below the stability bound over the bounds",
                    scenario.display(),
                    p.name
                );
            }
        }
        let mut inputs = sc.inputs();
        for s in specs {
            inputs.push(Input {
                role: format!("the measured curve (--data {})", s.file.display()),
                path: s.file.clone(),
            });
        }
        let mut locks = vec![];
        for (f, role) in [
            (&json_file, "the report (PREFIX.json)"),
            (&csv_file, "the fitted curve (PREFIX.csv)"),
        ] {
            locks.push(safety::claim_file(f, role, &inputs, opts.overwrite)?);
        }
        if opts.plot {
            locks.push(safety::claim_file(
                &png_file,
                "the plot (PREFIX.png)",
                &inputs,
                opts.overwrite,
            )?);
        }
        Ok((curves, locks))
    })
}

/// Rank 0's curves on every process (each process parsed the same `specs`), and rank 0's locks
/// on the report files.
fn share_curves(
    w: Option<&dyn Comm>,
    specs: &[CurveSpec],
    claimed: Option<(Vec<Curve>, Vec<safety::OutputLock>)>,
) -> (Vec<Curve>, Option<Vec<safety::OutputLock>>) {
    let (curves, locks) = match claimed {
        Some((c, l)) => (Some(c), Some(l)),
        None => (None, None),
    };
    let shared = specs
        .iter()
        .enumerate()
        .map(|(k, spec)| {
            let mine = curves.as_ref().map(|c| &c[k]);
            let mut x = mine.map_or(vec![], |c| c.x.clone());
            let mut y = mine.map_or(vec![], |c| c.y.clone());
            let mut kinds = mine.map_or(vec![], |c| {
                vec![
                    XKind::ALL.iter().position(|&v| v == c.x_kind).unwrap_or(0) as f64,
                    YKind::ALL.iter().position(|&v| v == c.y_kind).unwrap_or(0) as f64,
                    c.factor[0],
                    c.factor[1],
                ]
            });
            broadcast(w, &mut x);
            broadcast(w, &mut y);
            broadcast(w, &mut kinds);
            Curve {
                spec: spec.clone(),
                x_kind: XKind::ALL[kinds[0] as usize],
                y_kind: YKind::ALL[kinds[1] as usize],
                x,
                y,
                factor: [kinds[2], kinds[3]],
                units: mine.map_or_else(Default::default, |c| c.units.clone()),
            }
        })
        .collect();
    (shared, locks)
}

/// A curve as the search sees it: its residuals divided by `scale` (a power of two near its
/// largest |y| over sqrt(weight)), its points' range in the residual vector, its relative scale.
struct Part {
    scale: f64,
    start: usize,
    end: usize,
    range: f64,
    relative_to: &'static str,
}

fn parts(curves: &[Curve]) -> Vec<Part> {
    let mut start = 0;
    curves
        .iter()
        .map(|c| {
            let unit = power_of_two_near(&c.y);
            let scale = if c.spec.weight == 1.0 {
                unit
            } else {
                unit / c.spec.weight.sqrt()
            };
            let (range, relative_to) = data_scale(&c.y);
            let p = Part {
                scale,
                start,
                end: start + c.x.len(),
                range,
                relative_to,
            };
            start = p.end;
            p
        })
        .collect()
}

/// The fitted parameters: values, standard errors from the covariance of the sensitivities
/// `jp` (dy/dp over each curve's scale, as the search sees the residuals) and the weighted
/// relative sensitivities.
fn fitted_parameters(
    params: &[Param],
    value: &[f64],
    jp: &[Vec<f64>],
    ssr: f64,
    curves: &[CurveReport],
) -> Vec<Fitted> {
    let n = params.len();
    let m = jp.len();
    let mut a = vec![vec![0.0; n]; n];
    for row in jp {
        for j in 0..n {
            for k in 0..n {
                a[j][k] += row[j] * row[k];
            }
        }
    }
    let s2 = ssr / (m - n) as f64;
    let cov = lm::inverse(&a);
    let weights: f64 = curves.iter().map(|c| c.weight).sum();
    params
        .iter()
        .enumerate()
        .map(|(j, q)| {
            let v = value[j];
            let (sensitivity, sensitivity_relative) = match curves {
                [c] => (Some(c.sensitivity[j]), c.sensitivity[j] / c.range),
                _ => (
                    None,
                    (curves
                        .iter()
                        .map(|c| c.weight * (c.sensitivity[j] / c.range).powi(2))
                        .sum::<f64>()
                        / weights)
                        .sqrt(),
                ),
            };
            Fitted {
                name: q.name.clone(),
                key: q.key.clone(),
                lower: q.lo,
                upper: q.hi,
                start: q.start,
                value: v,
                log: q.log,
                at_bound: (v - q.lo).abs() <= 1e-9 * (q.hi - q.lo) || (q.hi - v).abs() <= 1e-9 * (q.hi - q.lo),
                standard_error: cov
                    .as_ref()
                    .map(|c| (s2 * c[j][j]).max(0.0).sqrt())
                    .filter(|s| s.is_finite()),
                sensitivity,
                sensitivity_relative,
            }
        })
        .collect()
}

/// On rank 0: writes the report (PREFIX.json), the fitted curves (PREFIX.csv) and the plot
/// (PREFIX.png); returns the report as written, None on the other processes.
fn write_report(
    w: Option<&dyn Comm>,
    mut report: FitReport,
    opts: &FitOptions,
    prefix: &Path,
) -> Result<Option<FitReport>> {
    let [json_file, csv_file, png_file] = files_of(prefix);
    eprop::distribute::launch::on_root(w, || {
        report.files = vec![json_file.display().to_string(), csv_file.display().to_string()];
        if opts.plot {
            report.files.push(png_file.display().to_string());
        }
        // x, measured, fitted, residual, then value * dy/d(value) of each parameter, then the
        // curve (1-based, in --data order)
        let mut csv = String::from("x,measured,fitted,residual");
        for p in &report.parameters {
            csv.push_str(&format!(",sensitivity_{}", p.name));
        }
        csv.push_str(",curve\n");
        for (&(c, x, y, f), s) in report.rows.iter().zip(&report.scaled_jacobian) {
            csv.push_str(&format!("{x:?},{y:?},{f:?},{:?}", f - y));
            for v in s {
                csv.push_str(&format!(",{v:?}"));
            }
            csv.push_str(&format!(",{}\n", c + 1));
        }
        std::fs::write(&csv_file, csv).map_err(|e| anyhow!("{}: cannot write: {e}", csv_file.display()))?;
        let write_json = |r: &FitReport| {
            std::fs::write(&json_file, serde_json::to_string_pretty(r)? + "\n")
                .map_err(|e| anyhow!("{}: cannot write: {e}", json_file.display()))
        };
        write_json(&report)?;
        if opts.plot {
            if let Err(no) = plot(prefix, &png_file) {
                report.files.pop();
                report.plot_note = Some(format!("no PNG: {}; fix: {}", no.why, no.fix));
                write_json(&report)?;
            }
        }
        Ok(report.clone())
    })
}

/// Fits the parameters on this process alone (`world` None) or on every process of `world`;
/// returns the report on rank 0.
pub fn fit_on(world: Option<&dyn Comm>, scenario: &Path, opts: &FitOptions) -> Result<Option<FitReport>> {
    let stop = crate::guard::signals::install();
    let t0 = Instant::now();
    let w = world;
    let root = is_root(w);
    let processes = w.map_or(1, |w| w.size());
    let params = checked_options(opts)?;
    let specs = opts
        .data
        .iter()
        .map(|s| parse_spec(s, opts.tool, opts.load, opts.node))
        .collect::<Result<Vec<_>>>()?;
    let prefix = opts.prefix.clone().unwrap_or_else(|| default_prefix(&specs[0].file));
    // rank 0 reads the curves and claims the report files; every process gets the curves
    let claimed = claim(w, scenario, opts, &specs, &params, &prefix)?;
    let (curves, locks) = share_curves(w, &specs, claimed);
    let parts = parts(&curves);
    let measured: Vec<f64> = curves.iter().flat_map(|c| c.y.iter().copied()).collect();
    // the residuals as the search sees them: each curve's divided by a power of two near its
    // largest |y| (over sqrt(weight)), so that a force in N and a displacement in m weigh alike,
    // their squares do not overflow (values past 1e154), and one curve's search is the same bit
    // for bit at any scale (a power of two scales exactly)
    let scale_of: Vec<f64> = parts
        .iter()
        .flat_map(|p| std::iter::repeat_n(p.scale, p.end - p.start))
        .collect();
    let names: Vec<String> = params.iter().map(|p| p.name.clone()).collect();
    let values = |z: &[f64]| -> Vec<f64> { params.iter().zip(z).map(|(p, &z)| p.p(z)).collect() };
    let show = root && !opts.quiet;
    let mut count = 0usize;
    // per curve: its RMS, absolute and relative, of the residuals r (as the search sees them)
    let rms_of = |r: &[f64]| -> Vec<(f64, f64)> {
        parts
            .iter()
            .map(|p| {
                let rr = &r[p.start..p.end];
                let rms = p.scale * (rr.iter().map(|v| v * v).sum::<f64>() / rr.len() as f64).sqrt();
                (rms, rms / p.range)
            })
            .collect()
    };
    let weights: Vec<f64> = curves.iter().map(|c| c.spec.weight).collect();
    let weighted = |rel: &[(f64, f64)]| -> f64 {
        (rel.iter().zip(&weights).map(|((_, r), w)| w * r * r).sum::<f64>() / weights.iter().sum::<f64>()).sqrt()
    };
    let mut residuals = |z: &[f64], what: &str| -> Result<Outcome> {
        count += 1;
        let p = values(z);
        let out = evaluate(w, &stop, scenario, opts, &params, &p, &curves)?;
        let r = out.map(|f| {
            f.iter()
                .zip(&measured)
                .zip(&scale_of)
                .map(|((a, b), s)| (a - b) / s)
                .collect::<Vec<f64>>()
        });
        if show {
            let ps: Vec<String> = names.iter().zip(&p).map(|(n, v)| format!("{n} = {v:.6e}")).collect();
            let how = match &r {
                Ok(r) => {
                    let each = rms_of(r);
                    match each.as_slice() {
                        [(rms, rel)] => format!("rms {rms:.4e} ({rel:.3e} of {})", parts[0].relative_to),
                        _ => format!(
                            "rms {:.3e} relative (curves {})",
                            weighted(&each),
                            each.iter()
                                .map(|(_, r)| format!("{r:.3e}"))
                                .collect::<Vec<_>>()
                                .join(", ")
                        ),
                    }
                }
                Err(why) => format!("rejected: {why}"),
            };
            eprintln!("fit {count:>3} {what}: {}; {how}", ps.join(", "));
        }
        Ok(r)
    };
    let mut problem = lm::Problem {
        lo: params.iter().map(|p| p.z(p.lo)).collect(),
        hi: params.iter().map(|p| p.z(p.hi)).collect(),
        residuals: &mut residuals,
        max_evaluations: opts.max_evaluations,
        tolerance: opts.tolerance,
    };
    let z0: Vec<f64> = params.iter().map(|p| p.z(p.start)).collect();
    // the scenario named once
    let named = |e: anyhow::Error| -> anyhow::Error {
        let name = scenario.display().to_string();
        match e.downcast_ref::<Agreed>() {
            Some(_) => e,
            None if format!("{e:#}").starts_with(&name) => refused(format!("{e:#}")),
            None => refused(format!("{name}: {e:#}")),
        }
    };
    let sol = lm::minimize(&mut problem, z0, &names).map_err(named)?;
    let mut evaluations = sol.evaluations;
    // the sensitivities at the end point
    let jac = match sol.jacobian {
        Some(j) => j,
        None => lm::jacobian(&mut problem, &sol.z, &sol.r, &names, &mut evaluations).map_err(named)?,
    };
    drop(problem);
    let value = values(&sol.z);
    let m = sol.r.len();
    // in each curve's scale, as the search saw them (the squares finite)
    let ssr: f64 = sol.r.iter().map(|v| v * v).sum();
    let jp = parameter_jacobian(&jac, &params, &value);
    let each = rms_of(&sol.r);
    let curve_reports = curve_reports(&curves, &parts, &each, &jp, &value);
    let parameters = fitted_parameters(&params, &value, &jp, ssr, &curve_reports);
    let rows = report_rows(&curves, &sol.r, &scale_of);
    let one = curve_reports.len() == 1;
    let report = FitReport {
        scenario: scenario.display().to_string(),
        data: curve_reports
            .iter()
            .map(|c| c.data.clone())
            .collect::<Vec<_>>()
            .join(", "),
        x: curves[0].x_kind,
        y: curves[0].y_kind,
        points: m,
        parameters,
        rms: one.then_some(each[0].0),
        rms_relative: if one { each[0].1 } else { weighted(&each) },
        relative_to: if one {
            parts[0].relative_to.to_string()
        } else {
            "each curve's scale (weighted)".to_string()
        },
        curves: curve_reports,
        evaluations,
        iterations: sol.iterations,
        stop: sol.stop.text().to_string(),
        processes,
        seconds: t0.elapsed().as_secs_f64(),
        files: vec![],
        plot_note: None,
        rows,
        scaled_jacobian: jp
            .iter()
            .zip(&scale_of)
            .map(|(row, s)| row.iter().zip(&value).map(|(d, v)| s * (d * v)).collect())
            .collect(),
    };
    let written = write_report(w, report, opts, &prefix)?;
    drop(locks);
    Ok(written)
}

/// The report's rows: (curve, x, measured y, fitted y), the fitted from the residuals as the
/// search saw them (each over its curve's scale).
fn report_rows(curves: &[Curve], r: &[f64], scale_of: &[f64]) -> Vec<(usize, f64, f64, f64)> {
    curves
        .iter()
        .enumerate()
        .flat_map(|(k, c)| c.x.iter().zip(&c.y).map(move |(&x, &y)| (k, x, y)))
        .zip(r.iter().zip(scale_of))
        .map(|((k, x, y), (r, s))| (k, x, y, y + s * r))
        .collect()
}

/// The options a fit refuses before anything is read (tolerance, evaluations, curves), and
/// its parameters.
fn checked_options(opts: &FitOptions) -> Result<Vec<Param>> {
    if !(opts.tolerance > 0.0 && opts.tolerance < 1.0) {
        return Err(refused(format!(
            "--tolerance {}: must be between 0 and 1 (relative); fix: e.g. --tolerance 1e-6",
            opts.tolerance
        )));
    }
    let params = parse_params(&opts.params, &opts.starts)?;
    let n = params.len();
    if opts.max_evaluations < 2 * n + 2 {
        return Err(refused(format!(
            "--max-evaluations {}: too few for {n} parameter(s) (the start, a derivative per parameter and a step); fix: at least {}",
            opts.max_evaluations,
            2 * n + 2
        )));
    }
    if opts.data.is_empty() {
        return Err(refused(
            "no measured curve; fix: --data CURVE.csv (repeatable: --data press.csv --data dent.csv:node=42,weight=0.5)".into(),
        ));
    }
    Ok(params)
}

/// The Jacobian in the parameters: dy/dp = dy/dz dz/dp (p dy/dp = dy/dz for log coordinates).
fn parameter_jacobian(jac: &[Vec<f64>], params: &[Param], value: &[f64]) -> Vec<Vec<f64>> {
    jac.iter()
        .map(|row| {
            row.iter()
                .zip(params)
                .zip(value)
                .map(|((d, q), v)| if q.log { d / v } else { *d })
                .collect()
        })
        .collect()
}

/// Each curve's report: its RMS (`each`: absolute, relative) and its sensitivity to each
/// parameter (the RMS of p dy/dp over its points).
fn curve_reports(
    curves: &[Curve],
    parts: &[Part],
    each: &[(f64, f64)],
    jp: &[Vec<f64>],
    value: &[f64],
) -> Vec<CurveReport> {
    let n = value.len();
    curves
        .iter()
        .zip(parts)
        .zip(each)
        .map(|((c, p), &(rms, rms_relative))| CurveReport {
            data: c.spec.file.display().to_string(),
            x: c.x_kind,
            y: c.y_kind,
            x_unit: c.units[0].clone(),
            y_unit: c.units[1].clone(),
            weight: c.spec.weight,
            points: c.x.len(),
            rms,
            rms_relative,
            relative_to: p.relative_to.to_string(),
            sensitivity: (0..n)
                .map(|j| {
                    p.scale
                        * (jp[p.start..p.end]
                            .iter()
                            .map(|row| (row[j] * value[j]).powi(2))
                            .sum::<f64>()
                            / c.x.len() as f64)
                            .sqrt()
                })
                .collect(),
            range: p.range,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_is_linear_and_bounded() {
        let (xs, ys) = ([0.0, 1.0, 3.0], [0.0, 2.0, 6.0]);
        assert_eq!(interpolate(&xs, &ys, 0.5), Some(1.0));
        assert_eq!(interpolate(&xs, &ys, 2.0), Some(4.0));
        assert_eq!(interpolate(&xs, &ys, 3.0), Some(6.0));
        assert_eq!(interpolate(&xs, &ys, 0.0), Some(0.0));
        assert_eq!(interpolate(&xs, &ys, 3.0001), None);
        assert_eq!(interpolate(&xs, &ys, -1e-12), None);
    }

    #[test]
    fn lm_recovers_an_exponential_within_bounds() {
        // y = a exp(-b t) from (a, b) = (2, 0.5), fitted in (ln a, ln b)
        let t: Vec<f64> = (0..20).map(|k| k as f64 * 0.25).collect();
        let y: Vec<f64> = t.iter().map(|t| 2.0 * (-0.5 * t).exp()).collect();
        let mut f = |z: &[f64], _: &str| -> anyhow::Result<Outcome> {
            let (a, b) = (z[0].exp(), z[1].exp());
            Ok(Ok(t.iter().zip(&y).map(|(t, y)| a * (-b * t).exp() - y).collect()))
        };
        let mut p = lm::Problem {
            lo: vec![0.1f64.ln(), 0.01f64.ln()],
            hi: vec![10f64.ln(), 5f64.ln()],
            residuals: &mut f,
            max_evaluations: 200,
            tolerance: 1e-10,
        };
        let s = lm::minimize(&mut p, vec![0.5f64.ln(), 2f64.ln()], &["a".into(), "b".into()]).unwrap();
        assert!((s.z[0].exp() - 2.0).abs() < 1e-6, "{:?}", s.z);
        assert!((s.z[1].exp() - 0.5).abs() < 1e-6, "{:?}", s.z);
        // a bound below the truth: held at the bound
        let mut p2 = lm::Problem {
            lo: vec![0.1f64.ln(), 0.01f64.ln()],
            hi: vec![1.5f64.ln(), 5f64.ln()],
            residuals: &mut f,
            max_evaluations: 200,
            tolerance: 1e-10,
        };
        let s = lm::minimize(&mut p2, vec![0.5f64.ln(), 2f64.ln()], &["a".into(), "b".into()]).unwrap();
        assert!((s.z[0].exp() - 1.5).abs() < 1e-12, "{:?}", s.z);
    }

    #[test]
    fn parameters_and_curves_are_checked() {
        let p = |s: &[&str]| parse_params(&s.iter().map(|s| s.to_string()).collect::<Vec<_>>(), &[]);
        let e = format!("{:#}", p(&["yung=1:2"]).unwrap_err());
        assert!(e.contains("unknown parameter `yung`; fix: one of young"), "{e}");
        let e = format!("{:#}", p(&["young=2:1"]).unwrap_err());
        assert!(e.contains("lower bound 2 is not below the upper bound 1; fix"), "{e}");
        let ok = p(&["young=20:500", "load.1.normal=-1:1"]).unwrap();
        assert!(ok[0].log && (ok[0].start - 100.0).abs() < 1e-12);
        assert!(!ok[1].log && ok[1].start == 0.0 && ok[1].key == "load.1.normal");
        assert_eq!(column_name(" Force (N)"), "force");
    }
}
