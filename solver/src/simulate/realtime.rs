//! The real-time mode measured against the reference (docs/realtime.md): the same scenario
//! stepped in the real-time mode and by forward Euler at the same dt, u and the tools' forces
//! compared step by step, and the real-time steps' wall-clock times. `eprop check` prints it
//! for a scenario in the real-time mode; the tests hold it within `TOLERANCE`.

use super::Simulation;
use crate::config::Setup;
use crate::linalg::V3;
use anyhow::Result;
use serde::Serialize;
use std::time::Instant;

/// The relative error of u the real-time mode is held to (against euler at the same dt).
pub const TOLERANCE: f64 = 1e-2;

/// What a comparison measured.
#[derive(Serialize, Debug, Clone)]
pub struct Comparison {
    pub steps: u64,
    /// The largest relative L2 error of u over the steps, ||u - u_euler|| / ||u_euler||
    /// (steps where euler's u is zero count their absolute error), and its step.
    pub u_error: f64,
    pub u_error_step: u64,
    /// The largest difference of a tool's force from euler's, relative to euler's peak
    /// force (0 without tools).
    pub force_error: f64,
    /// The real-time mode's operator applications: the bound of its plan and the most a step
    /// took.
    pub applications_bound: usize,
    pub applications_max: usize,
    /// Wall-clock seconds of the real-time steps: median, 99th percentile, worst.
    pub step_seconds: [f64; 3],
    /// The same in CPU seconds of the process (every thread): on a loaded machine what the
    /// step costs, where the wall clock also counts the time other work held the core.
    pub step_cpu_seconds: [f64; 3],
}

/// CPU seconds of this process so far (every thread).
fn cpu_seconds() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes the timespec it is given
    let ok = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) } == 0;
    if ok {
        ts.tv_sec as f64 + 1e-9 * ts.tv_nsec as f64
    } else {
        0.0
    }
}

/// ||a - b|| / ||b|| (the absolute difference where b is zero).
pub fn relative(a: &[V3], b: &[V3]) -> f64 {
    let (mut d, mut s) = (0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        for k in 0..3 {
            d += (x[k] - y[k]) * (x[k] - y[k]);
            s += y[k] * y[k];
        }
    }
    if s > 0.0 {
        (d / s).sqrt()
    } else {
        d.sqrt()
    }
}

/// The median, 99th percentile and largest of `v` (zeros when empty).
pub fn percentiles(v: &[f64]) -> [f64; 3] {
    if v.is_empty() {
        return [0.0; 3];
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let at = |q: f64| s[((q * (s.len() - 1) as f64).round() as usize).min(s.len() - 1)];
    [at(0.5), at(0.99), s[s.len() - 1]]
}

/// Steps `realtime` (a setup in the real-time mode) and `euler` (the same scenario with
/// `integrator = "euler"`, not in the real-time mode) side by side for at most `steps`
/// steps (one process) and compares them.
pub fn compare(realtime: Setup, euler: Setup, steps: u64) -> Result<Comparison> {
    compare_within(realtime, euler, steps, f64::INFINITY)
}

/// `compare`, stopped after the step in which the comparison's wall time passes `seconds`
/// (euler at the real-time mode's dt may need millions of substeps a step on a mesh with
/// slivers); `Comparison::steps` says how many steps were compared.
pub fn compare_within(realtime: Setup, euler: Setup, steps: u64, seconds: f64) -> Result<Comparison> {
    let start = Instant::now();
    let mut rt = Simulation::new(realtime)?;
    let mut eu = Simulation::new(euler)?;
    let bound = rt.step_plan().per_step;
    let (mut u_error, mut u_error_step, mut apps_max) = (0.0f64, 0, 0);
    let (mut forces, mut diffs, mut times, mut cpu) = (0.0f64, 0.0f64, Vec::new(), Vec::new());
    let mut k = 0;
    while k < steps && !rt.done() && !eu.done() && start.elapsed().as_secs_f64() < seconds {
        let (t, c) = (Instant::now(), cpu_seconds());
        let st = rt.advance()?;
        times.push(t.elapsed().as_secs_f64());
        cpu.push(cpu_seconds() - c);
        apps_max = apps_max.max(st.applications);
        eu.advance()?;
        k += 1;
        let e = relative(rt.u().owned(), eu.u().owned());
        if e > u_error {
            (u_error, u_error_step) = (e, k);
        }
        for (a, b) in rt.tool_states().iter().zip(eu.tool_states()) {
            forces = forces.max(eprop_io::geom::norm(b.force));
            let d = [
                a.force[0] - b.force[0],
                a.force[1] - b.force[1],
                a.force[2] - b.force[2],
            ];
            diffs = diffs.max(eprop_io::geom::norm(d));
        }
    }
    Ok(Comparison {
        steps: k,
        u_error,
        u_error_step,
        force_error: if forces > 0.0 { diffs / forces } else { 0.0 },
        applications_bound: bound,
        applications_max: apps_max,
        step_seconds: percentiles(&times),
        step_cpu_seconds: percentiles(&cpu),
    })
}
