//! The real-time mode's step times on a scenario (docs/realtime.md), without the comparison
//! with euler that `eprop check --measure` makes (euler at 1 ms on a mesh with slivers takes
//! seconds a step): the plan, then each step's CPU and wall time, median / p99 / worst, over
//! the scenario's steps (or `--steps N`), one process.
//!
//!     cargo run --release --example realtime_steps -- scenarios/organs/kidney_realtime.toml [--steps N] [--set key=value]...
//!
//! `--set` overrides a scenario key as `eprop run --set` does (e.g. `--set time.realtime=true`).

use eprop::config::{Scenario, Setup};
use eprop::simulate::realtime::percentiles;
use eprop::simulate::Simulation;
use std::path::PathBuf;
use std::time::Instant;

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

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut path = None;
    let (mut steps, mut sets) = (u64::MAX, Vec::new());
    let mut k = 0;
    while k < args.len() {
        match args[k].as_str() {
            "--steps" => {
                steps = args[k + 1].parse()?;
                k += 1;
            }
            "--set" => {
                sets.push(args[k + 1].clone());
                k += 1;
            }
            p => path = Some(PathBuf::from(p)),
        }
        k += 1;
    }
    let path =
        path.ok_or_else(|| anyhow::anyhow!("usage: realtime_steps SCENARIO [--steps N] [--set key=value]..."))?;
    let t0 = Instant::now();
    let mut sim = Simulation::new(Setup::new(Scenario::load_with(&path, &sets)?)?)?;
    let setup = t0.elapsed().as_secs_f64();
    let plan = sim.step_plan().clone();
    println!("{}: {} nodes, setup {setup:.2} s", path.display(), sim.n_global());
    println!("plan: {} applications per step: {}", plan.per_step, plan.why);
    let (mut cpu, mut wall, mut apps) = (Vec::new(), Vec::new(), 0);
    let mut k = 0;
    while k < steps && !sim.done() {
        let (t, c) = (Instant::now(), cpu_seconds());
        let st = sim.advance()?;
        wall.push(t.elapsed().as_secs_f64());
        cpu.push(cpu_seconds() - c);
        apps = apps.max(st.applications);
        k += 1;
    }
    let force = sim.tool_states().first().map_or(0.0, |t| eprop_io::geom::norm(t.force));
    let [c50, c99, cmax] = percentiles(&cpu).map(|s| 1e3 * s);
    let [w50, w99, wmax] = percentiles(&wall).map(|s| 1e3 * s);
    println!(
        "{k} steps, at most {apps} applications a step; CPU {c50:.3} / {c99:.3} / {cmax:.3} ms, wall {w50:.3} / {w99:.3} / {wmax:.3} ms (median / p99 / worst); steps over 1 ms (CPU): {}; tool force at the end {force:.3e} N",
        cpu.iter().filter(|&&c| c > 1e-3).count()
    );
    Ok(())
}
