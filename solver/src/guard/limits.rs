//! Bounds on what a run may ask for: steps, substeps per step and step sizes, checked with
//! arithmetic that cannot wrap or saturate silently, and the size of the output it writes.
//! `eprop check` and `eprop run` apply the same checks, so what `check` accepts runs.

use crate::config::integrator::Kind;
use crate::config::{Output, Precision, Stop};
use crate::distribute::parts::GlobalSizes;
use crate::propagate::integrate::StepPlan;
use crate::simulate::Simulation;
use anyhow::Result;

/// Most mechanics steps a run may take.
pub(crate) const MAX_STEPS: u64 = 1_000_000_000;
pub use crate::propagate::integrate::MAX_SUBSTEPS;
/// Most Euler substeps a mechanics step may stand for, whatever the integrator (the ratio of dt
/// to the stable Euler substep; the benchmark liver has 1.8e4).
pub(crate) const MAX_RATIO: f64 = 1e12;
/// Smallest step size (dt or h) accepted: far below any unit system of a tissue simulation, so
/// a smaller one comes from an overflow or a units mistake and would leave the time at 0.
pub(crate) const MIN_STEP: f64 = 1e-30;

/// `1,000,000`.
pub(crate) fn grouped(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// Where the stop condition's count comes from, for messages.
fn steps_key(stop: &Stop, from_cli: bool) -> &'static str {
    match (stop, from_cli) {
        (_, true) => "--steps",
        (Stop::Equilibrium { .. }, false) => "[time] steps (the cap of equilibrium)",
        _ => "[time] steps",
    }
}

/// The number of steps the stop condition asks for, or why it is refused. `from_cli`: the
/// count was given as `--steps`.
pub fn steps(stop: &Stop, dt: f64, path: &str, from_cli: bool) -> Result<u64, String> {
    let n = match *stop {
        Stop::Steps(n) | Stop::Equilibrium { max_steps: n, .. } => n as f64,
        Stop::End(t) => crate::config::steps_to(t, dt),
    };
    if n > MAX_STEPS as f64 || n.is_nan() {
        let what = match *stop {
            Stop::End(t) => format!(
                "[time] end = {} with dt = {} means {} steps",
                crate::diagnostics::short(t),
                crate::diagnostics::fixed(dt, 4),
                crate::diagnostics::fixed(n, 3)
            ),
            _ => format!("{} = {} steps", steps_key(stop, from_cli), grouped(n as u64)),
        };
        let fix = match stop {
            Stop::End(_) => "a smaller [time] end, or a larger dt ([time] dt, or the [material] mass, damping and [model] stiffness that bound it)",
            _ => "fewer steps",
        };
        return Err(format!(
            "{path}: {what}, above the limit of {} steps per run; fix: {fix} (a long study can be continued with --restart)",
            grouped(MAX_STEPS)
        ));
    }
    Ok(n as u64)
}

/// Refuses a step size that is not a normal number above `MIN_STEP`, and a substep count
/// above `MAX_SUBSTEPS`. `user_dt`: the scenario gave dt; `user_h`: the scenario's h.
pub(crate) fn step_sizes(plan: &StepPlan, user_dt: bool, user_h: Option<f64>, path: &str) -> Result<(), String> {
    let dt = plan.dt;
    if !(dt.is_normal() && dt >= MIN_STEP) {
        let (what, fix) = if user_dt {
            (
                format!("[time] dt = {}", crate::diagnostics::short(dt)),
                "a larger [time] dt",
            )
        } else {
            (
                format!(
                    "the mechanics step dt = {} (the stability bound of [material] mass, damping and [model] stiffness)",
                    crate::diagnostics::fixed(dt, 4)
                ),
                "check the units of mass, damping and stiffness, or set [time] dt",
            )
        };
        return Err(format!(
            "{path}: {what} is below {MIN_STEP:e}: steps that small leave the time at 0; fix: {fix}"
        ));
    }
    // the Euler substeps one mechanics step stands for: past MAX_RATIO the operator is too
    // stiff against dt for any integrator in double precision (the implicit solve breaks down)
    let ratio = dt / (crate::propagate::integrate::euler::SAFETY * plan.h_bound);
    if plan.integrator != Kind::Euler && !(ratio <= MAX_RATIO) {
        return Err(format!(
            "{path}: the mechanics step dt = {dt:.4e} spans {ratio:.3e} stable Euler substeps per mechanics step (Euler bound {:.3e} from [material] conductivity on this mesh), above the limit of {MAX_RATIO:e} for any integrator ({} included): no integrator resolves so stiff an operator in double precision; fix: a smaller [material] conductivity (check its units and the mesh's, [mesh] scale) or a smaller [time] dt",
            plan.h_bound, plan.integrator.name()
        ));
    }
    if plan.per_step > MAX_SUBSTEPS {
        // a count that saturated says nothing: the ratio it came from does
        let h_max = user_h.unwrap_or(crate::propagate::integrate::euler::SAFETY * plan.h_bound);
        let needed = if plan.per_step == usize::MAX {
            dt / h_max
        } else {
            plan.per_step as f64
        };
        let dt_from = if user_dt {
            ""
        } else {
            " (automatic: from [material] mass, damping and [model] stiffness)"
        };
        let why = match user_h {
            Some(h) => format!("[time] h = {}", crate::diagnostics::short(h)),
            None => format!(
                "h at most {h_max:.3e}, {} of the stability bound of [material] conductivity on this mesh",
                crate::propagate::integrate::euler::SAFETY
            ),
        };
        return Err(format!(
            "{path}: the propagation needs {needed:.3e} substeps per mechanics step (dt = {dt:.4e}{dt_from} over {why}), above the limit of {}; fix: a smaller [time] dt or conductivity{}",
            grouped(MAX_SUBSTEPS as u64),
            if user_h.is_some() { ", or a larger [time] h" } else { "" }
        ));
    }
    // the integrator's own step (Euler's substep, the RKL2 super-step, dt for implicit): the
    // Euler substep of another integrator is a yardstick, never taken
    if !(plan.step.is_normal() && plan.step >= MIN_STEP) {
        return Err(format!(
            "{path}: the propagation step of {} ({}) = {} is below {MIN_STEP:e}; fix: check [material] conductivity and the mesh's units ([mesh] scale)",
            plan.integrator.name(),
            if plan.integrator == Kind::Euler { "its substep h" } else { "its own step" },
            crate::diagnostics::fixed(plan.step, 4)
        ));
    }
    Ok(())
}

/// Output steps a run writes from step `from` (written already when `fresh` is false) to
/// `to`: every `every`-th step, and the last.
pub fn output_steps(from: u64, to: u64, every: u64, fresh: bool) -> u64 {
    let every = every.max(1);
    if to <= from {
        return u64::from(fresh);
    }
    to / every - from / every + u64::from(!to.is_multiple_of(every)) + u64::from(fresh)
}

/// Bytes of the output: (the static part, one output step), as stored uncompressed.
pub fn output_bytes(sizes: &GlobalSizes, output: &Output, loads: usize, scenario_len: usize) -> (f64, f64) {
    let n = sizes.nodes as f64;
    let width = if output.precision == Precision::Float32 {
        4.0
    } else {
        8.0
    };
    let comps: usize = output.fields().iter().map(|f| f.components()).sum();
    let step = n * comps as f64 * width
        // step tables, offsets and probes
        + 8.0 * (8.0 + output.fields.len() as f64 + 6.0 * loads.max(1) as f64);
    let cells = sizes.cells as f64;
    let fixed = n * (24.0 + 8.0 + 8.0) // points, node ids, control volumes
        + sizes.conn as f64 * 8.0
        + cells * (8.0 + 1.0 + 4.0) // offsets, types, tags
        + scenario_len as f64
        + 256.0 * 1024.0; // metadata and the first chunks of the tables
    (fixed, step)
}

/// An equilibrium tolerance is refused below this fraction of the velocity a node gains in one
/// step from the largest load (100 times the rounding floor of max |v| at rest).
pub(crate) const EQUILIBRIUM_FLOOR: f64 = 1e-14;

/// Refuses an equilibrium tolerance that double precision cannot resolve: at rest, rounding
/// keeps max |v| near 1e-16 of `v_scale` = max |F| dt / min m, so a smaller tolerance is never
/// reached and the run takes its whole cap of steps.
pub fn equilibrium(stop: &Stop, v_scale: f64, path: &str) -> Result<(), String> {
    let Stop::Equilibrium { tol, max_steps } = *stop else {
        return Ok(());
    };
    let floor = EQUILIBRIUM_FLOOR * v_scale;
    if tol < floor {
        return Err(format!(
            "{path}: [time] equilibrium = {tol:e} is below what double precision resolves here ({EQUILIBRIUM_FLOOR:e} of the speed {v_scale:.3e} the largest load gives a node in one step; rounding keeps max |v| near 1e-16 of it), so the run would take all {} steps of its cap; fix: a tolerance of at least {floor:.1e}, or `steps = N` alone for a fixed count",
            grouped(max_steps)
        ));
    }
    Ok(())
}

/// The speed the largest load gives a node in one step (0 without loads; every process calls).
fn speed_scale(sim: &Simulation) -> f64 {
    let f = sim
        .loads
        .iter()
        .map(|l| {
            let peak = l
                .ramp
                .as_ref()
                .map_or(1.0, |r| r.iter().fold(0.0f64, |m, p| m.max(p[1].abs())));
            eprop_io::geom::norm(l.force) * peak
        })
        .fold(0.0f64, f64::max);
    let tissues = &sim.setup().materials.tissues;
    let m = sim
        .comm()
        .min(tissues.iter().map(|t| t.mass).fold(f64::INFINITY, f64::min));
    f * sim.dt() / m
}

/// What a run will do, checked against the limits: its steps and output.
#[derive(Clone, Debug)]
pub struct Budget {
    /// The step the run stops at (at the latest).
    pub steps: u64,
    /// Output steps this run writes.
    pub output_steps: u64,
    /// Bytes it writes (at most: uncompressed).
    pub output_bytes: f64,
    /// Bytes of one output step.
    pub step_bytes: f64,
    /// Bytes up to the first output step (with the static part of a new series).
    pub start_bytes: f64,
}

/// The free space kept on the output's disk before every write, so that no write fails half
/// way (under MPI a write the disk refuses inside HDF5 cannot be recovered): two output steps
/// and 1 MiB for HDF5's metadata.
pub fn reserve(step_bytes: f64) -> f64 {
    2.0 * step_bytes + (1u64 << 20) as f64
}

impl Budget {
    /// The checks of a built simulation (the same on every process); `from_cli`: the step
    /// count came from `--steps`; `fresh`: a new series (not a restart from `sim.step`).
    pub fn of(sim: &Simulation, sizes: &GlobalSizes, from_cli: bool, fresh: bool) -> Result<Budget, String> {
        let path = sim.setup().scenario.path.display().to_string();
        let time = &sim.setup().time;
        step_sizes(sim.step_plan(), time.dt.is_some(), time.h, &path)?;
        let steps = steps(&time.stop, sim.dt(), &path, from_cli)?;
        equilibrium(&time.stop, speed_scale(sim), &path)?;
        let out = &sim.setup().output;
        let output_steps = output_steps(sim.step(), steps, out.every, fresh);
        let (fixed, step) = output_bytes(sizes, out, sim.loads.len(), sim.setup().scenario.text.len());
        let new = if fresh { fixed } else { 0.0 };
        Ok(Budget {
            steps,
            output_steps,
            output_bytes: new + step * output_steps as f64,
            start_bytes: new + if output_steps > 0 { step } else { 0.0 },
            step_bytes: step,
        })
    }
}

/// Seconds to write `steps` output steps of `step_bytes` each into `dir`, from a probe written
/// there now: a few blocks of one step's size (64 MiB at most in all) and one sync, as a run
/// writes its steps between flushes. None when the probe cannot be written or the disk is
/// short of four times its size.
pub fn write_seconds(dir: &std::path::Path, step_bytes: f64, steps: u64) -> Option<f64> {
    use std::io::Write;
    let block = (step_bytes as usize).clamp(4096, 32 << 20);
    let count = ((64usize << 20) / block).clamp(2, 8);
    let free = eprop_series::outcome::free_bytes(dir)?;
    if (free as f64) < 4.0 * (block * count) as f64 {
        return None;
    }
    let probe = dir.join(format!(".eprop-write-probe-{}", std::process::id()));
    let data = vec![0x5au8; block];
    let t = std::time::Instant::now();
    let written = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .and_then(|mut f| {
            for _ in 0..count {
                f.write_all(&data)?;
            }
            f.sync_data()
        });
    let seconds = t.elapsed().as_secs_f64();
    let _ = std::fs::remove_file(&probe);
    written.ok()?;
    Some(seconds / (block * count) as f64 * step_bytes * steps as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan(dt: f64, h: f64, per_step: usize) -> StepPlan {
        StepPlan {
            integrator: Kind::Euler,
            dt,
            h,
            step: h,
            h_bound: h / 0.9,
            per_step,
            cost: per_step as f64,
            why: String::new(),
        }
    }

    #[test]
    fn step_counts_are_bounded_without_wrapping() {
        assert_eq!(steps(&Stop::Steps(100), 0.1, "s", false), Ok(100));
        assert_eq!(steps(&Stop::End(1.0), 0.1, "s", false), Ok(10));
        let e = steps(&Stop::Steps(1_000_000_000_000), 0.1, "s.toml", false).unwrap_err();
        assert!(
            e.starts_with("s.toml: [time] steps = 1,000,000,000,000 steps, above the limit of 1,000,000,000")
                && e.contains("fix:"),
            "{e}"
        );
        assert!(steps(&Stop::Steps(u64::MAX), 0.1, "s", true)
            .unwrap_err()
            .contains("--steps"));
        let e = steps(&Stop::End(1e300), 0.1, "s", false).unwrap_err();
        assert!(e.contains("[time] end = 1e300") && e.contains("larger dt"), "{e}");
        let e = steps(
            &Stop::Equilibrium {
                tol: 1e-300,
                max_steps: u64::MAX,
            },
            0.1,
            "s",
            false,
        )
        .unwrap_err();
        assert!(e.contains("the cap of equilibrium"), "{e}");
    }

    #[test]
    fn step_sizes_and_substeps_are_bounded() {
        assert!(step_sizes(&plan(0.1, 0.01, 10), false, None, "s").is_ok());
        let e = step_sizes(&plan(1e-300, 1e-301, 10), true, None, "s").unwrap_err();
        assert!(e.contains("[time] dt = 1e-300 is below 1e-30"), "{e}");
        let e = step_sizes(&plan(2e-308, 1e-309, 10), false, None, "s").unwrap_err();
        assert!(e.contains("stability bound of [material] mass"), "{e}");
        // conductivity = 1e300: the count saturated; the message gives the ratio
        let mut p = plan(0.1, 0.1 / usize::MAX as f64, usize::MAX);
        p.h_bound = 1e-300;
        let e = step_sizes(&p, false, None, "s").unwrap_err();
        assert!(
            e.contains("needs 1.111e299 substeps") && e.contains("conductivity"),
            "{e}"
        );
        let e = step_sizes(&plan(0.1, 1e-300, usize::MAX), false, Some(1e-300), "s").unwrap_err();
        assert!(e.contains("[time] h = 1e-300") && e.contains("1.000e299"), "{e}");
        assert!(step_sizes(&plan(0.1, 0.1 / 2e6, 2_000_000), false, None, "s").is_err());
        // another integrator takes no Euler substep, but past 1e12 of them per step no
        // integrator resolves the operator (conductivity = 1e300 under auto)
        let mut p = plan(0.1, 1e-302, 129);
        (p.integrator, p.step, p.h_bound) = (Kind::Implicit, 0.1, 1e-302);
        let e = step_sizes(&p, false, None, "s").unwrap_err();
        assert!(
            e.contains("substeps per mechanics step") && e.contains("implicit included") && e.contains("conductivity"),
            "{e}"
        );
        (p.h, p.h_bound) = (1e-9, 1e-9);
        assert!(step_sizes(&p, false, None, "s").is_ok());
    }

    #[test]
    fn an_unresolvable_equilibrium_is_refused() {
        let eq = |tol| Stop::Equilibrium {
            tol,
            max_steps: 1_000_000,
        };
        assert!(equilibrium(&eq(1e-6), 0.75, "s").is_ok());
        assert!(equilibrium(&Stop::Steps(3), 0.75, "s").is_ok());
        assert!(equilibrium(&eq(1e-300), 0.0, "s").is_ok());
        let e = equilibrium(&eq(1e-300), 0.75, "s.toml").unwrap_err();
        assert!(
            e.starts_with("s.toml: [time] equilibrium = 1e-300 is below what double precision resolves")
                && e.contains("all 1,000,000 steps")
                && e.contains("fix: a tolerance of at least 7.5e-15"),
            "{e}"
        );
    }

    #[test]
    fn output_steps_count_the_grid_the_last_and_the_first() {
        assert_eq!(output_steps(0, 10, 1, true), 11);
        assert_eq!(output_steps(0, 10, 3, true), 5); // 0 3 6 9 10
        assert_eq!(output_steps(12, 30, 3, false), 6); // 15 .. 30
        assert_eq!(output_steps(5, 5, 1, false), 0);
        assert_eq!(output_steps(0, MAX_STEPS, 1, true), MAX_STEPS + 1);
        assert_eq!(grouped(1234567), "1,234,567");
        assert_eq!(grouped(12), "12");
    }
}
