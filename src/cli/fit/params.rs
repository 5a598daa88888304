//! The fitted parameters: `--param NAME=LO:HI` and `--start`, their fitting coordinates (log
//! where both bounds are positive), the options a fit refuses before anything is read.

use super::{number, refused, FitOptions};
use anyhow::Result;
use eprop::diagnostics::short;

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

/// One fitted parameter.
#[derive(Clone, Debug)]
pub(super) struct Param {
    pub(super) name: String,
    pub(super) key: String,
    pub(super) lo: f64,
    pub(super) hi: f64,
    pub(super) start: f64,
    /// Fitted as ln(value) (both bounds positive).
    pub(super) log: bool,
}

impl Param {
    pub(super) fn z(&self, p: f64) -> f64 {
        if self.log {
            p.ln()
        } else {
            p
        }
    }
    pub(super) fn p(&self, z: f64) -> f64 {
        let p = if self.log { z.exp() } else { z };
        p.clamp(self.lo, self.hi)
    }
}

/// sqrt(lo hi) for 0 < lo < hi, in logarithms where the product underflows or overflows
/// (1e-300:1e-299 starts at 3.2e-300, not 0; 1e299:1e300 at 3.2e299, not inf).
pub(super) fn geometric_mean(lo: f64, hi: f64) -> f64 {
    let p = lo * hi;
    if p.is_normal() {
        p.sqrt()
    } else {
        (0.5 * (lo.ln() + hi.ln())).exp().clamp(lo, hi)
    }
}

/// `NAME=LO:HI` (and its `--start NAME=VALUE`) as a parameter.
pub(super) fn parse_params(params: &[String], starts: &[String]) -> Result<Vec<Param>> {
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

/// The options a fit refuses before anything is read (tolerance, evaluations, curves), and
/// its parameters.
pub(super) fn checked_options(opts: &FitOptions) -> Result<Vec<Param>> {
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
pub(super) fn parameter_jacobian(jac: &[Vec<f64>], params: &[Param], value: &[f64]) -> Vec<Vec<f64>> {
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

#[cfg(test)]
mod tests {
    use super::*;

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
    }
}
