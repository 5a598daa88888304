//! Accuracy and time of every integrator against euler (the paper's substeps) on one
//! scenario, one process: the largest relative L2 error of u over the steps, and of the first
//! tool's force against euler's peak, and the seconds of the run (setup excluded).
//!
//!   cargo run --release --example accuracy -- SCENARIO [KIND ...]
//!
//! KIND: euler/2 (euler at half its substep: the reference's own error), rkl2, implicit, auto
//! (default: all four). `[integrator] accuracy` comes from the scenario.
use eprop::linalg::V3;
use eprop::simulate::Simulation;
use std::time::Instant;

struct Run {
    u: Vec<Vec<V3>>,
    force: Vec<V3>,
    seconds: f64,
    applications: usize,
    chosen: String,
}

fn run(path: &std::path::Path, kind: &str) -> anyhow::Result<Run> {
    let integrator = match kind {
        "rkl2" | "implicit" | "auto" => kind,
        _ => "euler",
    };
    let build = |mut sets: Vec<String>| -> anyhow::Result<Simulation> {
        sets.push(format!("model.integrator={integrator}"));
        Simulation::new(eprop::config::Setup::new(eprop::config::Scenario::load_with(
            path, &sets,
        )?)?)
    };
    let mut s = build(vec![])?;
    if kind == "euler/2" {
        let h = s.step_plan().h;
        s = build(vec![format!("time.h={:?}", h / 2.0)])?;
    }
    let chosen = s.step_plan().integrator.to_string();
    let (mut u, mut force, mut applications) = (vec![], vec![], 0);
    let t = Instant::now();
    let mut seconds = 0.0;
    while !s.done() {
        let t0 = Instant::now();
        applications += s.advance()?.applications;
        seconds += t0.elapsed().as_secs_f64();
        u.push(s.u().owned().to_vec());
        if let Some(tool) = s.tool_states().first() {
            force.push(tool.force);
        }
    }
    let _ = t;
    Ok(Run {
        u,
        force,
        seconds,
        applications,
        chosen,
    })
}

/// ||a - b|| / ||b|| (`simulate::realtime::relative`).
fn rel(a: &[V3], b: &[V3]) -> f64 {
    eprop::simulate::realtime::relative(a, b)
}

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let path = std::path::PathBuf::from(&a[1]);
    let kinds: Vec<&str> = if a.len() > 2 {
        a[2..].iter().map(|s| s.as_str()).collect()
    } else {
        vec!["euler/2", "rkl2", "implicit", "auto"]
    };
    let e = run(&path, "euler")?;
    let peak = e.force.iter().map(|f| eprop_io::geom::norm(*f)).fold(0.0, f64::max);
    println!("{}: {} steps", path.display(), e.u.len());
    println!(
        "{:<10} {:<10} {:>14} {:>14} {:>12} {:>10}",
        "run", "integrator", "max err u", "max err force", "apps/step", "seconds"
    );
    let steps = e.u.len().max(1);
    println!(
        "{:<10} {:<10} {:>14} {:>14} {:>12.1} {:>10.2}",
        "euler",
        e.chosen,
        "-",
        "-",
        e.applications as f64 / steps as f64,
        e.seconds
    );
    for kind in kinds {
        let r = run(&path, kind)?;
        let err = r.u.iter().zip(&e.u).map(|(a, b)| rel(a, b)).fold(0.0, f64::max);
        let ferr = if peak > 0.0 {
            let m = r
                .force
                .iter()
                .zip(&e.force)
                .map(|(a, b)| eprop_io::geom::norm([a[0] - b[0], a[1] - b[1], a[2] - b[2]]))
                .fold(0.0, f64::max);
            format!("{:.2e}", m / peak)
        } else {
            "-".into()
        };
        println!(
            "{:<10} {:<10} {:>14.2e} {:>14} {:>12.1} {:>10.2}",
            kind,
            r.chosen,
            err,
            ferr,
            r.applications as f64 / steps as f64,
            r.seconds
        );
    }
    Ok(())
}
