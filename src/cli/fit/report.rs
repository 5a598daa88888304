//! The fit's report: the fitted parameters with their standard errors and sensitivities, each
//! curve's residuals, written as PREFIX.json and PREFIX.csv and drawn as PREFIX.png.

use super::curve::{Curve, XKind, YKind};
use super::lm;
use super::params::Param;
use super::FitOptions;
use anyhow::{anyhow, Result};
use eprop::diagnostics::short;
use eprop::distribute::comm::Comm;
use serde::Serialize;
use std::path::{Path, PathBuf};

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
pub(super) fn files_of(prefix: &Path) -> [PathBuf; 3] {
    let with = |ext: &str| {
        let mut s = prefix.as_os_str().to_os_string();
        s.push(ext);
        PathBuf::from(s)
    };
    [with(".json"), with(".csv"), with(".png")]
}

/// The default prefix: `<data stem>_fit` beside the data.
pub(super) fn default_prefix(data: &Path) -> PathBuf {
    let stem = data
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "curve".into());
    data.with_file_name(format!("{stem}_fit"))
}

/// scripts/plot_fit.py of the checkout the executable was built in (target/release/eprop), or
/// of the source tree it was built from.
pub(super) fn plot_script() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok();
    let from_exe = exe
        .iter()
        .flat_map(|e| e.ancestors().skip(1))
        .map(|d| d.join("scripts/plot_fit.py"));
    let built = std::iter::once(Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/plot_fit.py"));
    from_exe.chain(built).find(|p| p.is_file())
}

/// Why there is no PNG, and the fix.
pub(super) struct NoPlot {
    pub(super) why: String,
    pub(super) fix: String,
}

/// Draws PREFIX.png with scripts/plot_fit.py; Err: why not, and what to do.
pub(super) fn plot(prefix: &Path, png: &Path) -> std::result::Result<(), NoPlot> {
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
pub(super) fn data_scale(y: &[f64]) -> (f64, &'static str) {
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
pub(super) fn power_of_two_near(y: &[f64]) -> f64 {
    let top = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if top > 0.0 && top.is_finite() {
        2f64.powi((top.log2().floor() as i32).clamp(-1000, 1000))
    } else {
        1.0
    }
}

/// A curve as the search sees it: its residuals divided by `scale` (a power of two near its
/// largest |y| over sqrt(weight)), its points' range in the residual vector, its relative scale.
pub(super) struct Part {
    pub(super) scale: f64,
    pub(super) start: usize,
    pub(super) end: usize,
    pub(super) range: f64,
    pub(super) relative_to: &'static str,
}

pub(super) fn parts(curves: &[Curve]) -> Vec<Part> {
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
pub(super) fn fitted_parameters(
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
pub(super) fn write_report(
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

/// The report's rows: (curve, x, measured y, fitted y), the fitted from the residuals as the
/// search saw them (each over its curve's scale).
pub(super) fn report_rows(curves: &[Curve], r: &[f64], scale_of: &[f64]) -> Vec<(usize, f64, f64, f64)> {
    curves
        .iter()
        .enumerate()
        .flat_map(|(k, c)| c.x.iter().zip(&c.y).map(move |(&x, &y)| (k, x, y)))
        .zip(r.iter().zip(scale_of))
        .map(|((k, x, y), (r, s))| (k, x, y, y + s * r))
        .collect()
}

/// Each curve's report: its RMS (`each`: absolute, relative) and its sensitivity to each
/// parameter (the RMS of p dy/dp over its points).
pub(super) fn curve_reports(
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
