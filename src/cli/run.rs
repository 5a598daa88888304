//! `eprop run`: a scenario stepped to its stop condition on one process or under MPI, with
//! its output series, progress bar and summary.

use crate::config::{Scenario, Setup, Stop};
use crate::distribute::parts::GlobalSizes;
use crate::guard::limits::Budget;
use crate::guard::plausible::{self, Look, Watch};
use crate::guard::safety::{self, Agreed, OutputLock, EXIT_ERROR, EXIT_STOPPED, EXIT_WRITE};
pub use crate::output::progress::Every;
use crate::output::progress::Progress;
use crate::output::series::{check_output_dir, Series};
use crate::output::summary::{summarize, Summary, Timing};
use crate::simulate::distributed::build_mpi;
use crate::simulate::Simulation;
use anyhow::{bail, Result};
use eprop_series::outcome::{dir_of, free_bytes, human_bytes, WriteFailed};
use mpi::topology::SimpleCommunicator;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Command-line overrides of a scenario.
#[derive(Default, Clone)]
pub struct RunOptions {
    pub output: Option<PathBuf>,
    pub steps: Option<u64>,
    pub quiet: bool,
    /// Continue the series in this file from its last complete step.
    pub restart: Option<PathBuf>,
    /// Replace an existing series in the output file.
    pub overwrite: bool,
    /// Start even when the output would not fit on its disk (and write until it refuses).
    pub force: bool,
    /// How often a run without a terminal prints a progress line.
    pub progress_every: Every,
}

/// The output file of a scenario with the command-line overrides, and how it was named.
fn output_of(scenario: &Scenario, opts: &RunOptions) -> (PathBuf, String) {
    if let Some(r) = &opts.restart {
        return (r.clone(), "the restart file (--restart)".into());
    }
    if let Some(o) = &opts.output {
        return (o.clone(), "the output file (--output)".into());
    }
    let name = scenario.path.display();
    let how = match &scenario.file.output.file {
        Some(_) => format!("the output file ([output] file of {name})"),
        None => format!("the output file (the default for {name})"),
    };
    (crate::config::output_file(scenario), how)
}

/// Resolves a scenario against its mesh with the command-line overrides applied.
fn resolve(scenario: Scenario, opts: &RunOptions) -> Result<Setup> {
    let path = scenario.path.clone();
    tracing::info!("scenario {} read; reading the mesh", path.display());
    let (file, _) = output_of(&scenario, opts);
    let mut setup = Setup::new(scenario)?;
    tracing::info!(
        "mesh {}: {} nodes, {} cells; scenario resolved",
        setup.mesh.source,
        setup.mesh.n_nodes(),
        setup.mesh.n_cells()
    );
    setup.output.file = file;
    if let Some(s) = opts.steps {
        setup.time.stop = Stop::Steps(s);
    }
    if let Some(r) = &opts.restart {
        if !setup.tools.is_empty() {
            bail!(
                "{}: --restart cannot continue a run with [[tool]] tables (a tool's contact set and last reaction are not stored in the series); fix: run the scenario again from the start",
                r.display()
            );
        }
    }
    Ok(setup)
}

/// The command that continues this job's series and finishes the job: the options given that
/// change the job (--steps, --force, -q) are kept.
fn again(scenario: &Path, file: &Path, procs: usize, opts: &RunOptions) -> String {
    let mut o = vec![];
    if let Some(n) = opts.steps {
        o.push(format!("--steps {n}"));
    }
    if opts.force {
        o.push("--force".into());
    }
    if opts.quiet {
        o.push("-q".into());
    }
    safety::restart_command(scenario, file, procs, &o)
}

/// Reads and resolves a scenario with the command-line overrides applied.
pub fn prepare(path: &Path, opts: &RunOptions) -> Result<Setup> {
    let scenario = Scenario::load(path)?;
    let setup = resolve(scenario, opts)?;
    check_output_dir(&setup.output.file)?;
    Ok(setup)
}

/// The right of one run to write its output: held to the end of the run (on rank 0).
pub struct Claim {
    _lock: OutputLock,
}

/// Reads a scenario and claims its output before reading the mesh and before anything is
/// opened for writing: the output must not be one of the run's inputs, must not be written by
/// another run (the lock), and an existing file is replaced only when it is a series and the
/// user said so (or continued, with --restart).
pub fn prepare_claimed(path: &Path, opts: &RunOptions) -> Result<(Setup, Claim)> {
    let scenario = Scenario::load(path)?;
    let (file, role) = output_of(&scenario, opts);
    check_output_dir(&file)?;
    let inputs = scenario.inputs();
    safety::refuse_inputs(&file, &role, &inputs)?;
    safety::refuse_inputs(&safety::lock_path(&file), "the lock file of the output", &inputs)?;
    if let Some(r) = opts.restart.as_ref().filter(|r| !r.is_file()) {
        bail!(
            "{}: no such file to restart from; fix: give the output file of the interrupted run",
            r.display()
        );
    }
    let lock = OutputLock::take(&file)?;
    match &opts.restart {
        Some(_) => {}
        None => {
            let overwrite = opts.overwrite || scenario.file.output.overwrite;
            // --restart cannot continue a scenario with tools: not advised then
            let again = match scenario.file.tool.is_empty() {
                true => again(path, &file, 1, opts),
                false => String::new(),
            };
            safety::check_existing(&file, &role, overwrite, &again)?;
        }
    }
    let setup = resolve(scenario, opts)?;
    Ok((setup, Claim { _lock: lock }))
}

/// Runs a scenario file on this process alone (`world` None) or on every process of
/// `world`; returns the summary on the process that prints it. SIGTERM, SIGINT and SIGHUP stop
/// the run after a complete, written step (`crate::guard::signals`).
pub fn run_on(world: Option<SimpleCommunicator>, path: &Path, opts: &RunOptions) -> Result<Option<Summary>> {
    crate::guard::signals::install();
    match world {
        Some(w) => run_mpi(w, path, opts),
        None => run(path, opts).map(Some),
    }
}

/// Runs a scenario file on one process to its stop condition; returns the summary.
pub fn run(path: &Path, opts: &RunOptions) -> Result<Summary> {
    let t0 = Instant::now();
    let (setup, claim) = prepare_claimed(path, opts)?;
    let sizes = GlobalSizes::of(&setup.mesh);
    let sim = Simulation::new(setup)?;
    let summary = run_simulation(sim, sizes, t0, opts, None, 0)?;
    drop(claim);
    Ok(summary.expect("one process has the summary"))
}

/// Runs a scenario under MPI. Rank 0 reads the scenario, claims the output and reads the
/// mesh, splits the node graph with METIS and sends every process its part; each process
/// builds its own geometry and operator, steps its part with halo exchanges and writes its
/// rows of the output file (collective MPI-IO). Returns the summary on rank 0.
pub fn run_mpi(world: SimpleCommunicator, path: &Path, opts: &RunOptions) -> Result<Option<Summary>> {
    let t0 = Instant::now();
    let mut claim = None;
    let b = build_mpi(world, || {
        let (setup, c) = prepare_claimed(path, opts)?;
        claim = Some(c);
        Ok(setup)
    })?;
    let summary = run_simulation(b.sim, b.sizes, t0, opts, Some(&b.io_comm), b.rank0_scatter_peak);
    drop(claim);
    summary
}

/// Rank 0's verdict, made every process's: an `Agreed` error on every process when rank 0's
/// `r` is one (rank 0 prints its message).
fn from_root(sim: &Simulation, r: Result<()>, status: u8) -> Result<()> {
    let root = sim.comm.rank() == 0;
    let failed = sim.comm.max(f64::from(u8::from(root && r.is_err())));
    match (failed > 0.0, r) {
        (false, _) => Ok(()),
        (true, Err(e)) => Err(Agreed::error(status, format!("{e:#}"))),
        (true, Ok(())) => Err(Agreed::error(status, "rank 0 refused the run")),
    }
}

/// The complete steps of a series, for messages: "12 complete steps (to step 110)".
fn holds(series: &Series, last: u64) -> String {
    format!(
        "{} keeps its {} complete output steps (to step {last})",
        series.path().display(),
        series.steps_written()
    )
}

/// A failed output write, as the message every process ends with: what failed, the state of
/// the file, the fix and what to do `next`.
pub(crate) fn write_failed(e: anyhow::Error, state: &str, next: &str) -> anyhow::Error {
    match e.downcast_ref::<WriteFailed>() {
        Some(w) => Agreed::error(EXIT_WRITE, format!("{w}; {state}; fix: {}, then {next}", w.cause.fix())),
        None => e,
    }
}

/// Steps a built simulation to its stop condition; every process writes its block of the
/// series, rank 0 returns the summary.
fn run_simulation(
    mut sim: Simulation,
    sizes: GlobalSizes,
    t0: Instant,
    opts: &RunOptions,
    io_comm: Option<&SimpleCommunicator>,
    rank0_scatter_peak: u64,
) -> Result<Option<Summary>> {
    let plan = sim.step_plan();
    tracing::info!(
        "{}: Euler substep h = {:.4e} (bound {:.4e}), dt = {:.4e}, {} per step; writing {}",
        plan.integrator,
        plan.h,
        plan.h_bound,
        sim.dt,
        plan.per_step_phrase(),
        sim.setup.output.file.display()
    );
    let fresh = opts.restart.is_none();
    let from_cli = opts.steps.is_some();
    // every process computes the same verdicts from the same numbers
    Budget::of(&sim, &sizes, from_cli, fresh).map_err(|e| Agreed::error(EXIT_ERROR, e))?;
    let file = sim.setup.output.file.clone();
    let scenario = sim.setup.scenario.path.clone();
    let procs = sim.comm.size();
    let again = again(&scenario, &file, procs, opts);
    let root = sim.comm.rank() == 0;
    let show = root && !opts.quiet;
    let space = |sim: &Simulation, budget: &Budget| {
        let reclaimed = if fresh {
            std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0)
        } else {
            0
        };
        let what = format!(
            "{} output steps of {}{}",
            budget.output_steps,
            human_bytes(budget.step_bytes),
            if matches!(sim.setup.time.stop, Stop::Equilibrium { .. }) {
                format!(
                    ", at most: if equilibrium is not reached before the cap of {} steps",
                    budget.steps
                )
            } else {
                String::new()
            }
        );
        let r = if root {
            safety::check_space(&file, budget.output_bytes, reclaimed, &what, opts.force)
        } else {
            Ok(())
        };
        from_root(sim, r, EXIT_ERROR)
    };
    if fresh {
        let budget = Budget::of(&sim, &sizes, from_cli, fresh).map_err(|e| Agreed::error(EXIT_ERROR, e))?;
        space(&sim, &budget)?;
    }
    let mut warnings = match &sim.global {
        Some(mesh) if root => plausible::load_warnings(&sim, mesh),
        _ => vec![],
    };
    if show {
        for w in &warnings {
            eprintln!("warning: {w}");
        }
    }
    let mut series = Series::start(&mut sim, &sizes, !fresh, io_comm).map_err(|e| match fresh {
        true if file.exists() => write_failed(e, "nothing was written; the file is left as it is", "run again"),
        true => write_failed(e, "nothing was written (the unfinished file was removed)", "run again"),
        false => write_failed(e, "the file holds what it held", "restart again"),
    })?;
    let budget = Budget::of(&sim, &sizes, from_cli, fresh).map_err(|e| Agreed::error(EXIT_ERROR, e))?;
    if !fresh {
        space(&sim, &budget)?;
    }
    let restarted_at = sim.step;
    let mut last_written = sim.step;
    let setup_seconds = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let every = sim.setup.output.every;
    let mut progress = Progress::new(show, restarted_at, sim.max_steps(), opts.progress_every);
    let mut watch = Watch::new(&sim);
    let next = format!("continue with `{again}`");
    while !sim.done() {
        sim.advance()?;
        let stop = sim.stop_signal;
        if sim.step.is_multiple_of(every) || sim.done() || stop != 0 {
            match watch.look(&sim) {
                Look::NonFinite => {
                    progress.finish();
                    return Err(Agreed::error(
                        EXIT_ERROR,
                        format!(
                            "{}: at step {} (t = {:.6e}) the displacement, velocity or potential is no longer finite (NaN or inf), so the run stopped; {}. Likely cause: {}",
                            scenario.display(),
                            sim.step,
                            sim.time,
                            holds(&series, last_written),
                            plausible::nonfinite_cause(&sim)
                        ),
                    ));
                }
                Look::Finite(Some(w)) => {
                    if show {
                        progress.println(&format!("warning: {w}"));
                    }
                    warnings.push(w);
                }
                Look::Finite(None) => {}
            }
            if !opts.force {
                // the disk must hold this step with room to spare: stopping before a write
                // that cannot finish leaves the file closed cleanly
                let full = root
                    && free_bytes(&dir_of(&file))
                        .is_some_and(|free| (free as f64) < 2.0 * budget.step_bytes + (1u64 << 20) as f64);
                if sim.comm.max(f64::from(u8::from(full))) > 0.0 {
                    progress.finish();
                    let free = free_bytes(&dir_of(&file)).unwrap_or(0);
                    return Err(Agreed::error(
                        EXIT_WRITE,
                        format!(
                            "{}: the disk is full: no space left on device (ENOSPC) for output step {} ({} free in {}, a step needs about {}); {}; fix: free space on that disk (or move the file to a larger one), then {next}",
                            file.display(),
                            series.steps_written(),
                            human_bytes(free as f64),
                            dir_of(&file).display(),
                            human_bytes(budget.step_bytes),
                            holds(&series, last_written)
                        ),
                    ));
                }
            }
            if let Err(e) = series.append(&sim) {
                progress.finish();
                return Err(write_failed(e, &holds(&series, last_written), &next));
            }
            last_written = sim.step;
        }
        progress.update(sim.step, sim.max_speed);
        if stop != 0 {
            progress.finish();
            return Err(Agreed::error(
                EXIT_STOPPED,
                format!(
                    "stopped by {} after step {} of {}: {}; {next}",
                    crate::guard::signals::name(stop),
                    sim.step,
                    sim.max_steps(),
                    holds(&series, last_written)
                ),
            ));
        }
    }
    progress.finish();
    let timing = Timing {
        setup_seconds,
        wall_seconds: t1.elapsed().as_secs_f64(),
        restarted_from_step: opts.restart.as_ref().map(|_| restarted_at),
        rank0_scatter_peak,
    };
    Ok(summarize(&sim, &sizes, &series, timing, warnings))
}
