//! The measured curves: `--data FILE:KEY=VALUE,...`, what their x and y columns are, and the
//! CSV reader that converts the header's units to the scenario's.

use super::{number, refused};
use anyhow::{anyhow, bail, Result};
use eprop::config::Reading;
use serde::Serialize;
use std::path::{Path, PathBuf};

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
    pub(super) const ALL: [XKind; 5] = [XKind::Time, XKind::Indentation, XKind::X, XKind::Y, XKind::Z];
    /// The axis of a profile's x (0, 1, 2), None for time and indentation.
    pub(super) fn axis(&self) -> Option<usize> {
        match self {
            XKind::X => Some(0),
            XKind::Y => Some(1),
            XKind::Z => Some(2),
            _ => None,
        }
    }
    pub(super) fn is_length(&self) -> bool {
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
    pub(super) const ALL: [YKind; 5] = [YKind::Force, YKind::Displacement, YKind::Ux, YKind::Uy, YKind::Uz];
    /// The measured component of a displacement (None: its magnitude, or a force).
    pub(super) fn component(&self) -> Option<usize> {
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
pub(super) struct Curve {
    pub(super) spec: CurveSpec,
    pub(super) x_kind: XKind,
    pub(super) y_kind: YKind,
    pub(super) x: Vec<f64>,
    pub(super) y: Vec<f64>,
    /// The factors the file's x and y were multiplied by (its header's units), 1 without.
    pub(super) factor: [f64; 2],
    /// The header's units as written (rank 0; empty without).
    pub(super) units: [String; 2],
}

/// The accepted column names, for messages and --help.
pub const X_NAMES: &str = "`time` (or `t`), `indentation`, or `x`, `y`, `z` (a profile along a line of nodes)";
pub const Y_NAMES: &str = "`force`, `displacement`, or `ux`, `uy`, `uz` (one component)";

/// A header name without case or spaces, and its unit in brackets: "Force (N)" is (`force`, `N`).
pub(super) fn column(s: &str) -> (String, Option<String>) {
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
pub(super) fn column_name(s: &str) -> String {
    column(s).0
}

/// The units a column of this kind takes, with their factors to SI.
pub(super) fn units_of(length: bool, time: bool) -> &'static [(&'static str, f64)] {
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
pub(super) fn unit_factor(
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

pub(super) fn fields(line: &str) -> Vec<&str> {
    if line.contains(',') {
        line.split(',').map(str::trim).collect()
    } else {
        line.split_whitespace().collect()
    }
}

/// Reads a curve: a header row naming x and y, then rows of two numbers with x increasing;
/// blank lines and lines starting with `#` are skipped. The header's units are converted to the
/// scenario's (`reading`: the paper's reading has none).
pub(super) fn read_curve(spec: &CurveSpec, reading: Reading) -> Result<Curve> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn column_names_drop_units_and_case() {
        assert_eq!(column_name(" Force (N)"), "force");
    }
}
