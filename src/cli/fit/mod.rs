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
//!
//! The modules: `curve` the measured curves (`--data`, the CSV reader and its units), `params`
//! the fitted parameters (`--param`, `--start`, the options checked first), `probe` one
//! evaluation (a simulation stepped and sampled), `lm` the search, `report` the report
//! (standard errors, sensitivities, PREFIX.json / .csv / .png). Here: the options, rank 0's
//! claims and curves shared with every process, and `fit_on`, which runs the search.

mod curve;
mod lm;
mod params;
mod probe;
mod report;

use anyhow::{bail, Result};
use eprop::config::Input;
use eprop::config::Scenario;
use eprop::distribute::comm::Comm;
use eprop::distribute::launch::is_root;
use eprop::distribute::launch::{Agreed, EXIT_ERROR};
use eprop::guard::safety;
use std::path::{Path, PathBuf};
use std::time::Instant;

use curve::{parse_spec, read_curve, Curve, CurveSpec, XKind, YKind};
use params::{checked_options, parameter_jacobian, Param};
use probe::evaluate;
use report::{curve_reports, default_prefix, files_of, fitted_parameters, parts, report_rows, write_report, FitReport};

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

fn refused(msg: String) -> anyhow::Error {
    Agreed::error(EXIT_ERROR, msg)
}

fn number(s: &str) -> Option<f64> {
    s.trim().parse::<f64>().ok().filter(|v| v.is_finite())
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

/// An evaluation that gave no curve: why, in a few words.
type Outcome = std::result::Result<Vec<f64>, String>;

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

/// Fits the parameters on this process alone (`world` None) or on every process of `world`;
/// returns the report on rank 0.
pub fn fit_on(world: Option<&dyn Comm>, scenario: &Path, opts: &FitOptions) -> Result<Option<FitReport>> {
    let stop = crate::guard::signals::install();
    let (t0, w) = (Instant::now(), world);
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
    let show = is_root(w) && !opts.quiet;
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
