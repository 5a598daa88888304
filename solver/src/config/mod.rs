//! Scenario files (TOML) and their resolution against a mesh.
//!
//! Parsing checks every value by its type (numbers in range, shapes, the spellings of
//! choices, which selector a table may use); each section's resolver then does what needs
//! the mesh. Unknown keys are errors; every error names the file, the line and key, and the
//! fix.
//!
//! | section | module | resolves to |
//! |---|---|---|
//! | `[mesh]` | `mesh` | the `Mesh`, read and scaled |
//! | `[material]`, `[[material.region]]` | `material` | per-node tensor R, mass, damping |
//! | `[model]`, `[tissue]` | `model` | `Model` (as parsed), `TissueLaw` |
//! | `[[fixed]]` | `fixed` | per-node fixed flag |
//! | `[[load]]` | `loads` | `Load`s: contact nodes, weights, force (constant, ramped or a table) |
//! | `[[tool]]` | `tools` | `Tool`s: a rigid indenter's shape and path |
//! | `[time]` | `time` | `Time`: the stop condition, dt, h |
//! | `[output]` | `output` | `Output`: file, fields, precision |
//! | `[performance]` | `performance` | `Performance`: substeps per fused sweep, vector kernel, partitioner |
//!
//! Once resolved, `scales` refuses parameters whose products overflow or underflow (a load's
//! stress and energy density, the coupling's push, the continuum source).
//!
//! Selectors (`box`, `sphere`, ..., `patch`) are one type for the three tables that select
//! nodes (`select`); checked values and choices shared by sections are in `values`; command-line
//! overrides (`--set KEY=VALUE`) edit the text before it is parsed (`set`). A `Setup` is
//! serde-serialisable, so that `distribute::parts` can send each process its part: `wire` holds
//! the serde forms of the fields serde cannot derive.

mod fixed;
pub mod integrator;
pub mod keys;
mod loads;
pub mod local;
mod material;
pub mod mesh;
mod model;
mod output;
mod performance;
mod scales;
mod select;
pub mod set;
pub mod tables;
mod time;
pub mod tissue;
mod tools;
mod values;
pub(crate) mod wire;

pub use fixed::{FixedSet, Plane};
pub use loads::{Load, Push, FORCE_COLUMNS};
pub use material::{Conductivity, MaterialSec, Region};

/// A tissue of the paper reading's defaults (for tools that need one: `eprop info`'s operator).
pub const PAPER_TISSUE: crate::config::tissue::Tissue = crate::config::tissue::Tissue {
    r: crate::config::tissue::Tensor::new(
        model::PAPER.conductivity,
        0.0,
        0.0,
        0.0,
        model::PAPER.conductivity,
        0.0,
        0.0,
        0.0,
        model::PAPER.conductivity,
    ),
    mass: model::PAPER.mass,
    damping: model::PAPER.damping,
    stiffness: model::PAPER.stiffness,
    coupling: model::PAPER.coupling,
    law: TissueLaw {
        young: model::PAPER.young,
        beta: 0.0,
    },
    poisson: values::POISSON,
};
pub use mesh::{MeshSec, Unit};
pub use model::{Defaults, IntegratorSec, Model, Reading, Scheme, SchemeName, TissueSec, CONTINUUM, PAPER};
pub use output::{file_of as output_file, Field, Output, OutputSec};
pub use performance::{Fuse, Partitioner, Performance, PerformanceSec, MAX_FUSE};
pub use select::{distance, Entry, Keys, Selector};
pub use time::{steps_to, RealtimeSolver, Stop, Time, TimeSec};
pub use tools::{
    ContactLaw, Grip, Shape, ShapeName, Tool, ToolSec, Trajectory, PATH_COLUMNS, REACH, REACH_FIX, REACH_WHY,
};
pub use values::Precision;

use crate::config::tissue::{Materials, TissueLaw};
use anyhow::{anyhow, Result};
use eprop_mesh::Mesh;
use serde::{Deserialize, Serialize};
use std::ops::Range;
use std::path::{Path, PathBuf};
use toml::Spanned;
use values::defaults;

/// A file a run reads, and what it is to the run (for messages and the output checks).
#[derive(Clone, Debug)]
pub struct Input {
    pub role: String,
    pub path: std::path::PathBuf,
}

/// A scenario file as written.
#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    pub mesh: MeshSec,
    #[serde(default = "defaults")]
    pub material: MaterialSec,
    #[serde(default = "defaults")]
    pub model: Model,
    #[serde(default = "defaults")]
    pub tissue: TissueSec,
    #[serde(default)]
    pub fixed: Vec<Entry<FixedSet>>,
    #[serde(default)]
    pub load: Vec<Entry<Push>>,
    #[serde(default)]
    pub tool: Vec<Spanned<ToolSec>>,
    pub time: Spanned<TimeSec>,
    #[serde(default = "defaults")]
    pub output: OutputSec,
    #[serde(default = "defaults")]
    pub integrator: IntegratorSec,
    #[serde(default)]
    pub performance: PerformanceSec,
}

/// A scenario file, parsed. It travels to other processes as its path and text.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(into = "Source", try_from = "Source")]
pub struct Scenario {
    pub path: PathBuf,
    pub text: String,
    pub file: ScenarioFile,
}

/// A scenario's path and text, the form in which it is sent.
#[derive(Serialize, Deserialize)]
struct Source {
    #[serde(with = "crate::config::wire::path")]
    path: PathBuf,
    text: String,
}

impl From<Scenario> for Source {
    fn from(s: Scenario) -> Source {
        Source {
            path: s.path,
            text: s.text,
        }
    }
}

impl TryFrom<Source> for Scenario {
    type Error = anyhow::Error;
    fn try_from(s: Source) -> Result<Scenario> {
        Scenario::parse(&s.path, s.text)
    }
}

/// Where a byte of the scenario text is: line and column (1-based), the table it is in and
/// the key of its line (None on a table header or a continuation line).
#[derive(Debug, PartialEq)]
struct Place {
    line: usize,
    col: usize,
    section: Option<String>,
    key: Option<String>,
}

fn place(text: &str, at: usize) -> Place {
    let at = (0..=at.min(text.len()))
        .rev()
        .find(|&i| text.is_char_boundary(i))
        .unwrap_or(0);
    let before = &text[..at];
    let start = before.rfind('\n').map_or(0, |p| p + 1);
    let header = |l: &str| {
        let t = l.split('#').next().unwrap_or("").trim();
        t.starts_with('[')
            .then(|| t.trim_matches(['[', ']']).trim().to_string())
    };
    let this = text[start..].lines().next().unwrap_or("");
    let section = header(this).or_else(|| text[..start].lines().rev().find_map(header));
    let key = this.split_once('=').map(|(k, _)| k.trim()).filter(|k| {
        !k.is_empty() && header(this).is_none() && k.chars().all(|c| c.is_ascii_alphanumeric() || "_-.".contains(c))
    });
    Place {
        line: before.matches('\n').count() + 1,
        col: before.len() - start + 1,
        section,
        key: key.map(str::to_string),
    }
}

/// `"a", "b" or "c"` from serde's "unknown variant `x`, expected `a`, `b` or `c`", so a wrong
/// choice names the accepted spellings as they are written in the file.
fn plain(message: &str) -> String {
    if let Some(rest) = message.strip_prefix("unknown variant ") {
        let words: Vec<&str> = rest.split('`').skip(1).step_by(2).collect();
        if let Some((got, valid)) = words.split_first() {
            return format!(
                "`{got}` is not one of the accepted values; fix: use {}",
                select::either(valid, "\"")
            );
        }
    }
    message.to_string()
}

impl Scenario {
    pub fn load(path: &Path) -> Result<Scenario> {
        let text = eprop_io::read_input_text(path, "scenario")?;
        Self::parse(path, text)
    }

    /// Reads a scenario with `--set KEY=VALUE` overrides applied (`set`).
    pub fn load_with(path: &Path, sets: &[String]) -> Result<Scenario> {
        let text = eprop_io::read_input_text(path, "scenario")?;
        let text = set::apply(&text, sets).map_err(|e| anyhow!("{}: {e}", path.display()))?;
        Self::parse(path, text)
    }

    /// The `--set KEY` whose value (in the scenario text) holds byte `at`, if any.
    fn override_at(&self, at: usize) -> Option<String> {
        overridden(&self.text, at)
    }

    /// The tables the scenario names (force tables of loads, path tables of tools): the name as
    /// written in the scenario, and the file.
    pub fn tables(&self) -> Vec<(String, Input)> {
        let name = self.path.display();
        let base = self.path.parent().unwrap_or(Path::new("."));
        let mut out = vec![];
        for (k, l) in self.file.load.iter().enumerate() {
            if let Some(t) = &l.with.table {
                out.push((
                    t.get_ref().to_string(),
                    Input {
                        role: format!("the force table of [[load]] {} ({}, in {name})", k + 1, t.get_ref()),
                        path: base.join(t.get_ref()),
                    },
                ));
            }
        }
        for (k, t) in self.file.tool.iter().enumerate() {
            if let Some(f) = &t.get_ref().table {
                out.push((
                    f.get_ref().to_string(),
                    Input {
                        role: format!("the path table of [[tool]] {} ({}, in {name})", k + 1, f.get_ref()),
                        path: base.join(f.get_ref()),
                    },
                ));
            }
        }
        out
    }

    /// Every file a run of this scenario reads, with its role (for the refusal to write over
    /// one): the scenario, its mesh, and the tables of loads and tools. A section that reads
    /// another file adds it here.
    pub fn inputs(&self) -> Vec<Input> {
        let name = self.path.display();
        let mut out = vec![Input {
            role: format!("the scenario ({name})"),
            path: self.path.clone(),
        }];
        for p in eprop_io::mesh_files(&self.mesh_path()) {
            out.push(Input {
                role: format!("the mesh ({}, [mesh] file of {name})", p.display()),
                path: p,
            });
        }
        out.extend(self.tables().into_iter().map(|(_, i)| i));
        out
    }

    /// Parses and checks a scenario; an error names its line, column, table and key.
    pub fn parse(path: &Path, text: String) -> Result<Scenario> {
        let file: ScenarioFile = toml::from_str(&text).map_err(|e| {
            let msg = plain(e.message().trim());
            match e.span() {
                // a top-level table that is missing: an empty span at the start of the file,
                // whose first line is some other table
                Some(s) if s.is_empty() && s.start == 0 && msg.starts_with("missing field `") => {
                    let name = msg.trim_start_matches("missing field `").trim_end_matches('`');
                    anyhow!(
                        "{}: missing table [{name}]; fix: add a [{name}] table (`eprop run --help` lists its keys)",
                        path.display()
                    )
                }
                Some(s) if overridden(&text, s.start).is_some() => {
                    let p = place(&text, s.start);
                    let at = format!(
                        "{}: --set {}",
                        path.display(),
                        overridden(&text, s.start).unwrap_or_default()
                    );
                    anyhow!("{}", located(&at, p.section.as_deref(), p.key.as_deref(), &msg))
                }
                Some(s) => {
                    let p = place(&text, s.start);
                    let at = format!("{}:{}:{}", path.display(), p.line, p.col);
                    anyhow!("{}", located(&at, p.section.as_deref(), p.key.as_deref(), &msg))
                }
                None => anyhow!("{}", located(&path.display().to_string(), None, None, &msg)),
            }
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

    /// An error about `key` of table `section` (empty: the table itself), at the line of
    /// `span` when it is known (a default value has an empty span).
    pub fn error_at(&self, span: Range<usize>, section: &str, key: &str, msg: impl std::fmt::Display) -> anyhow::Error {
        let at = if span.is_empty() {
            self.path.display().to_string()
        } else if let Some(k) = self.override_at(span.start) {
            format!("{}: --set {k}", self.path.display())
        } else {
            format!("{}:{}", self.path.display(), place(&self.text, span.start).line)
        };
        let key = (!key.is_empty()).then_some(key);
        anyhow!("{}", located(&at, Some(section), key, &msg.to_string()))
    }

    /// The nodes a selector of table `section` picks on `mesh`, at least one; errors (`none`
    /// when it picks nothing) at the selector's line.
    pub fn select(&self, s: &Spanned<Selector>, section: &str, mesh: &Mesh, none: &str) -> Result<Vec<bool>> {
        let key = s.get_ref().key();
        let set = s
            .get_ref()
            .nodes(mesh)
            .map_err(|e| self.error_at(s.span(), section, key, e))?;
        if !set.iter().any(|&b| b) {
            return Err(self.error_at(s.span(), section, key, none));
        }
        Ok(set)
    }
}

/// The `--set KEY` recorded in a scenario text whose line holds byte `at` (or that made the
/// table whose header holds it), if any.
fn overridden(text: &str, at: usize) -> Option<String> {
    set::recorded(text)
        .into_iter()
        .rev()
        .find(|(_, r)| r.contains(&at))
        .map(|(k, _)| k)
        .or_else(|| set::made_by(text, at))
}

/// `AT: [section] key: message; fix: ...`, with a generic fix when the message has none.
fn located(at: &str, section: Option<&str>, key: Option<&str>, msg: &str) -> String {
    let what = match (section, key) {
        (Some(s), Some(k)) => format!("[{s}] {k}: "),
        (Some(s), None) => format!("[{s}]: "),
        _ => String::new(),
    };
    let fix = match (msg.contains("fix:"), section, key) {
        (true, _, _) => String::new(),
        (false, Some(s), Some(k)) => {
            format!("; fix: change `{k}` in [{s}] (`eprop run --help` lists every scenario key)")
        }
        _ => "; fix: see `eprop run --help` for the scenario keys".to_string(),
    };
    format!("{at}: {what}{msg}{fix}")
}

/// The scenario resolved against its mesh: what a simulation needs, for the whole mesh or,
/// restricted (`Setup::restrict`), for one process's part.
#[derive(Serialize, Deserialize)]
pub struct Setup {
    pub scenario: Scenario,
    #[serde(with = "crate::config::wire::mesh")]
    pub mesh: Mesh,
    /// Each node's tissue (the mesh's numbering): conductivity tensor, mass, damping,
    /// pull-back, coupling and tissue law.
    pub materials: Materials,
    /// Per node: fixed.
    pub fixed: Vec<bool>,
    /// The fixed supports' planes no node may cross (`fixed::support_plane`).
    pub supports: Vec<fixed::Plane>,
    pub loads: Vec<Load>,
    pub tools: Vec<Tool>,
    pub model: Model,
    /// The integrator of the propagation and its settings.
    pub integrator: integrator::Settings,
    pub law: TissueLaw,
    pub time: Time,
    pub output: Output,
    /// How the propagation is computed (`[performance]`; `eprop bench` sets it from its flags).
    pub performance: Performance,
}

impl Setup {
    /// Reads the mesh named by the scenario and resolves everything.
    pub fn new(scenario: Scenario) -> Result<Setup> {
        let mesh = mesh::read(&scenario)?;
        Self::with_mesh(scenario, mesh)
    }

    /// The bench scenario (`eprop bench`, the kernel examples and tests): the unit box of
    /// `cells`^3 tetrahedral cubes, the left face fixed, a normal load on the right face.
    /// `scheme` is "compact", "paper" or "compact32" (compact with float32 coefficients).
    pub fn bench_box(cells: usize, scheme: &str) -> Result<Setup> {
        let mesh = eprop_io::generate::box_mesh([1.0; 3], [cells; 3], eprop_io::generate::BoxCells::Tet)?;
        let (scheme, prec) = match scheme {
            "compact32" => ("compact", "float32"),
            s => (s, "float64"),
        };
        let text = format!(
            "[mesh]\nfile = \"generated\"\n[model]\nreading = \"paper\"\nscheme = \"{scheme}\"\noperator_precision = \"{prec}\"\n[[fixed]]\ngroup = \"xmin\"\n\
             [[load]]\nnearest = [1.0, 0.5, 0.5]\nnormal = 1.0\n[time]\nsteps = 1\n"
        );
        let sc = Scenario::parse(Path::new("bench.toml"), text)?;
        let mut s = Self::with_mesh(sc, mesh)?;
        s.mesh.source = format!("box {cells}^3 tet");
        Ok(s)
    }

    /// Resolves a scenario against an already loaded mesh, one section after the other.
    pub fn with_mesh(scenario: Scenario, mesh: Mesh) -> Result<Setup> {
        let mut s = Setup::without_mesh_sections(scenario, mesh)?;
        let (sc, f) = (&s.scenario, &s.scenario.file);
        s.materials = material::resolve(sc, &f.material, &f.model, s.law, f.tissue.poisson, &s.mesh)?;
        (s.fixed, s.supports) = fixed::resolve(sc, &f.fixed, &s.mesh)?;
        s.loads = loads::resolve(sc, &f.load, &s.mesh, &s.fixed)?;
        scales::check(&s)?;
        Ok(s)
    }

    /// The sections that need no mesh (time, output, the tissue law, tools, the model, the
    /// integrator and performance settings), beside `mesh`; the mesh's sections (materials,
    /// supports, loads) empty: `with_mesh` resolves them on the whole mesh, `resolve_local` on
    /// a process's share.
    pub(crate) fn without_mesh_sections(scenario: Scenario, mesh: Mesh) -> Result<Setup> {
        let (sc, f) = (&scenario, &scenario.file);
        let time = time::resolve(sc, &f.time)?;
        let output = output::resolve(sc);
        let law = f.tissue.law(f.model.reading);
        let tools = tools::resolve(sc, &f.tool)?;
        Ok(Setup {
            tools,
            model: f.model.clone(),
            integrator: f.integrator.settings(f.model.integrator),
            law,
            time,
            output,
            performance: f.performance.resolve(),
            materials: tissue::Materials::uniform(0, PAPER_TISSUE),
            fixed: Vec::new(),
            supports: Vec::new(),
            loads: Vec::new(),
            mesh,
            scenario,
        })
    }
}

/// When `[mesh] unit` or `scale` rescales the mesh file's coordinates: "; with [mesh] unit =
/// "mm" every length of the scenario, `nearest` and `patch` included, is in metres"; empty
/// otherwise.
pub(crate) fn unit_note(sc: &Scenario) -> String {
    let ms = &sc.file.mesh;
    match (ms.unit, ms.scale) {
        (Some(u), _) if u.metres() != 1.0 => format!(
            "; with [mesh] unit = \"{}\" the mesh is read in metres and every length of the scenario, `nearest` and `patch` included, is in metres",
            u.name()
        ),
        (None, Some(s)) if s != 1.0 => format!(
            "; with [mesh] scale = {} every length of the scenario, `nearest` and `patch` included, is in the scaled unit",
            crate::diagnostics::short(s)
        ),
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use eprop_io::generate::cylinder_mesh;

    const BASE: &str = "[mesh]\nfile = \"cyl.msh\"\n[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 1.0\n[time]\nsteps = 6\n";

    fn setup(text: &str) -> Result<Setup, String> {
        let sc = Scenario::parse(Path::new("s.toml"), text.to_string()).map_err(|e| format!("{e:#}"))?;
        Setup::with_mesh(sc, cylinder_mesh(1.0, 4.0, 3, 11).unwrap()).map_err(|e| format!("{e:#}"))
    }

    #[test]
    fn a_place_is_its_line_column_table_and_key() {
        let text = "[mesh]\nfile = \"a\"\n\n[[material.region]] # x\ntag = 3\nbox = [\n  [0, 0, 0],\n]\n";
        let at = |s: &str| place(text, text.find(s).unwrap());
        assert_eq!(
            at("\"a\""),
            Place {
                line: 2,
                col: 8,
                section: Some("mesh".into()),
                key: Some("file".into())
            }
        );
        let tag = at("3\n");
        assert_eq!(
            (tag.line, tag.section.as_deref(), tag.key.as_deref()),
            (5, Some("material.region"), Some("tag"))
        );
        let header = at("[[material");
        assert_eq!((header.section.as_deref(), header.key), (Some("material.region"), None));
        assert_eq!(at("  [0").key, None);
        assert_eq!(place(text, 10_000).line, 9);
    }

    #[test]
    fn a_wrong_choice_names_the_accepted_spellings() {
        assert_eq!(
            plain("unknown variant `magic`, expected `compact` or `paper`"),
            "`magic` is not one of the accepted values; fix: use \"compact\" or \"paper\""
        );
        assert_eq!(
            plain("unknown variant `x`, expected one of `a`, `b`, `c`"),
            "`x` is not one of the accepted values; fix: use \"a\", \"b\" or \"c\""
        );
        assert_eq!(plain("missing field `file`"), "missing field `file`");
    }

    #[test]
    fn parse_errors_name_the_line_table_key_and_fix() {
        let e = setup(&format!("{BASE}[model]\nscheme = \"magic\"\n")).err().unwrap();
        assert_eq!(
            e,
            "s.toml:11:10: [model] scheme: `magic` is not one of the accepted values; fix: use \"compact\" or \"paper\""
        );
        let e = setup(&BASE.replace("[time]\n", "[time]\nstepz = 3\n")).err().unwrap();
        assert!(e.starts_with("s.toml:9:1: [time] stepz: unknown field `stepz`"), "{e}");
        let e = setup(&format!("{BASE}[material]\nmass = -1.0\n")).err().unwrap();
        assert!(
            e.starts_with(
                "s.toml:11:8: [material] mass: -1 must be a positive number; fix: change `mass` in [material]"
            ),
            "{e}"
        );
        let e = setup(&format!("{BASE}[material]\nconductivity = \"high\"\n"))
            .err()
            .unwrap();
        assert!(
            e.contains("[material] conductivity: a string is not a conductivity; fix: a conductivity is a number"),
            "{e}"
        );
        let e = setup(&BASE.replace("[time]", "[times]")).err().unwrap();
        assert!(e.starts_with("s.toml:8:2: [times]: unknown field `times`"), "{e}");
        let e = setup(&format!("{BASE}[[material.region]]\nnodes = [1]\nmass = 2.0\n"))
            .err()
            .unwrap();
        assert!(
            e.contains("[material.region] nodes: `nodes` does not select a material region; fix: use `box`"),
            "{e}"
        );
    }

    #[test]
    fn resolver_errors_name_the_line_of_the_selector() {
        let e = setup(&BASE.replace("\"bottom\"", "\"nowhere\"")).err().unwrap();
        assert!(
            e.starts_with("s.toml:4: [fixed] group: no physical group `nowhere`"),
            "{e}"
        );
        let e = setup(&BASE.replace("group = \"bottom\"", "box = [[9, 9, 9], [10, 10, 10]]"))
            .err()
            .unwrap();
        assert!(e.starts_with("s.toml:4: [fixed] box: selects no node; fix:"), "{e}");
        let e = setup(&format!(
            "{BASE}[[material.region]]\nsphere = {{ center = [9, 9, 9], radius = 0.5 }}\nmass = 2.0\n"
        ))
        .err()
        .unwrap();
        assert!(
            e.starts_with("s.toml:11: [material.region] sphere: the region holds no node"),
            "{e}"
        );
        let e = setup(&BASE.replace("nearest = [1.0, 0.0, 2.0]", "nearest = [0.0, 0.0, 0.0]"))
            .err()
            .unwrap();
        assert!(
            e.starts_with("s.toml:6: [load] nearest: the load's node") && e.contains("fixed set"),
            "{e}"
        );
        let e = setup(&BASE.replace("nearest = [1.0, 0.0, 2.0]", "node = 999999"))
            .err()
            .unwrap();
        assert!(
            e.starts_with("s.toml:6: [load] node: node 999999 is not in the mesh; fix:"),
            "{e}"
        );
        let e = setup(&BASE.replace("[[fixed]]\ngroup = \"bottom\"\n", ""))
            .err()
            .unwrap();
        assert!(e.contains("no [[fixed]] set; fix:"), "{e}");
    }

    #[test]
    fn a_setup_holds_every_section_resolved() {
        let s = setup(&format!(
            "{BASE}[material]\nmass = 2.0\n[[material.region]]\nhalfspace = {{ point = [0, 0, 2], normal = [0, 0, 1] }}\nconductivity = [0.08, 0.05, 0.05]\ndamping = 3.0\n[model]\nreading = \"paper\"\nscheme = \"paper\"\n[tissue]\nbeta = 1.5\n[output]\nevery = 2\n"
        ))
        .unwrap();
        let n = s.mesh.n_nodes();
        let m = &s.materials;
        assert!((0..n).all(|i| m.at(i).mass == 2.0) && m.n_nodes() == n);
        let upper = (0..n).filter(|&i| s.mesh.points[i][2] >= 2.0 - 1e-9).count();
        assert_eq!((0..n).filter(|&i| m.at(i).damping == 3.0).count(), upper);
        assert_eq!((0..n).filter(|&i| m.r(i)[(0, 0)] == 0.08).count(), upper);
        // two tissues: the section's and the region's
        assert_eq!(m.tissues.len(), 2);
        assert!(s.fixed.iter().any(|&b| b) && s.fixed.len() == n);
        assert_eq!(s.loads.len(), 1);
        assert_eq!(s.model.scheme(), Scheme::Paper { correction: true });
        assert_eq!((s.law.young, s.law.beta), (100.0, 1.5));
        assert_eq!(s.time.stop, Stop::Steps(6));
        assert_eq!((s.output.every, s.output.file.clone()), (2, PathBuf::from("s.h5")));
    }
}
