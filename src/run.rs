//! `eprop run`: a scenario stepped to its stop condition on one process or under MPI, with
//! its output series, progress bar and summary.

use crate::launch::build_mpi;
use crate::parts::GlobalSizes;
use crate::progress::Progress;
use crate::scenario::{Scenario, Setup, Stop};
use crate::series::{check_output_dir, Series};
use crate::solver::Simulation;
use crate::summary::{summarize, Summary, Timing};
use anyhow::{bail, Result};
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
}

/// Reads and resolves a scenario with the command-line overrides applied.
pub fn prepare(path: &Path, opts: &RunOptions) -> Result<Setup> {
    let scenario = Scenario::load(path)?;
    tracing::info!("scenario {} read; reading the mesh", path.display());
    let mut setup = Setup::new(scenario)?;
    tracing::info!(
        "mesh {}: {} nodes, {} cells; scenario resolved",
        setup.mesh.source,
        setup.mesh.n_nodes(),
        setup.mesh.n_cells()
    );
    if let Some(o) = &opts.output {
        setup.output.file = o.clone();
    }
    if let Some(s) = opts.steps {
        setup.time.stop = Stop::Steps(s);
    }
    if let Some(r) = &opts.restart {
        if !r.is_file() {
            bail!(
                "{}: no such file to restart from; fix: give the output file of the interrupted run",
                r.display()
            );
        }
        if !setup.tools.is_empty() {
            bail!(
                "{}: --restart cannot continue a run with [[tool]] tables (a tool's contact set and last reaction are not stored in the series); fix: run the scenario again from the start",
                r.display()
            );
        }
        setup.output.file = r.clone();
    }
    check_output_dir(&setup.output.file)?;
    Ok(setup)
}

/// Runs a scenario file on this process alone (`world` None) or on every process of
/// `world`; returns the summary on the process that prints it.
pub fn run_on(world: Option<SimpleCommunicator>, path: &Path, opts: &RunOptions) -> Result<Option<Summary>> {
    match world {
        Some(w) => run_mpi(w, path, opts),
        None => run(path, opts).map(Some),
    }
}

/// Runs a scenario file on one process to its stop condition; returns the summary.
pub fn run(path: &Path, opts: &RunOptions) -> Result<Summary> {
    let t0 = Instant::now();
    let setup = prepare(path, opts)?;
    let sizes = GlobalSizes::of(&setup.mesh);
    let sim = Simulation::new(setup)?;
    run_simulation(sim, sizes, t0, opts, None, 0).map(|s| s.expect("one process has the summary"))
}

/// Runs a scenario under MPI. Rank 0 reads the scenario and the mesh, splits the node graph
/// with METIS and sends every process its part; each process builds its own geometry and
/// operator, steps its part with halo exchanges and writes its rows of the output file
/// (collective MPI-IO). Returns the summary on rank 0.
pub fn run_mpi(world: SimpleCommunicator, path: &Path, opts: &RunOptions) -> Result<Option<Summary>> {
    let t0 = Instant::now();
    let b = build_mpi(world, || prepare(path, opts))?;
    run_simulation(b.sim, b.sizes, t0, opts, Some(&b.io_comm), b.rank0_scatter_peak)
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
    let mut series = Series::start(&mut sim, &sizes, opts.restart.is_some(), io_comm)?;
    let restarted_at = sim.step;
    let setup_seconds = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let every = sim.setup.output.every;
    let show = sim.comm.rank() == 0 && !opts.quiet;
    let mut progress = Progress::new(show, restarted_at, sim.max_steps());
    while !sim.done() {
        sim.advance()?;
        if sim.step.is_multiple_of(every) || sim.done() {
            series.append(&sim)?;
        }
        progress.update(sim.step, sim.max_speed);
    }
    progress.finish();
    let timing = Timing {
        setup_seconds,
        wall_seconds: t1.elapsed().as_secs_f64(),
        restarted_from_step: opts.restart.as_ref().map(|_| restarted_at),
        rank0_scatter_peak,
    };
    Ok(summarize(&sim, &sizes, &series, timing))
}
