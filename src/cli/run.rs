//! `eprop run`: a scenario's output claimed and its simulation built, on one process or under
//! MPI, then stepped to its stop condition by the shared time loop (`drive`) with the
//! scenario's own inputs.

use crate::cli::drive::{self, Batch, Settings};
use anyhow::{bail, Result};
use eprop::config::integrator::Preconditioner;
use eprop::config::{Fuse, Scenario, Setup, Stop};
use eprop::distribute::comm::Comm;
use eprop::distribute::launch::start_alone;
use eprop::distribute::parts::GlobalSizes;
use eprop::guard::safety::{self, OutputLock};
use eprop::output::progress;
pub use eprop::output::progress::Every;
use eprop::output::series::check_output_dir;
use eprop::output::summary::Summary;
use eprop::simulate::distributed::build_mpi;
use eprop::simulate::{Simulation, StopToken};
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
    /// Substeps per fused sweep (overrides `[performance] fuse`).
    pub fuse: Option<Fuse>,
    /// How often a run without a terminal prints a progress line.
    pub progress_every: Every,
    /// `--set KEY=VALUE` overrides of scenario keys (`config::set`), in order.
    pub sets: Vec<String>,
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
    (eprop::config::output_file(scenario), how)
}

/// Resolves a scenario against its mesh with the command-line overrides applied. With
/// `slabs` and a VTKHDF mesh the mesh is not read: the setup is `Setup::deferred`, which every
/// process of the job finishes on its slab of the mesh (`distribute::slabs::start`).
fn resolve(scenario: Scenario, opts: &RunOptions, slabs: bool) -> Result<Setup> {
    let path = scenario.path.clone();
    let (file, _) = output_of(&scenario, opts);
    let mut setup = if slabs && eprop::config::local::slab_mesh(&scenario) {
        tracing::info!("scenario {} read; the mesh is read in slabs", path.display());
        Setup::deferred(scenario)?
    } else {
        tracing::info!("scenario {} read; reading the mesh", path.display());
        let setup = Setup::new(scenario)?;
        tracing::info!(
            "mesh {}: {} nodes, {} cells; scenario resolved",
            setup.mesh.source,
            setup.mesh.n_nodes(),
            setup.mesh.n_cells()
        );
        setup
    };
    setup.output.file = file;
    if let Some(s) = opts.steps {
        setup.time.stop = Stop::Steps(s);
    }
    if let Some(f) = opts.fuse {
        setup.performance.fuse = f;
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
    for s in &opts.sets {
        o.push(format!("--set '{}'", s.replace('\'', "'\\''")));
    }
    safety::restart_command(scenario, file, procs, &o)
}

/// Reads and resolves a scenario with the command-line overrides applied.
pub fn prepare(path: &Path, opts: &RunOptions) -> Result<Setup> {
    let scenario = Scenario::load_with(path, &opts.sets)?;
    let setup = resolve(scenario, opts, false)?;
    check_output_dir(&setup.output.file)?;
    Ok(setup)
}

/// The right of one run to write its output: held to the end of the run (on rank 0).
pub struct Claim {
    lock: OutputLock,
}

impl Claim {
    /// The writer lock of the output.
    pub fn lock(&self) -> &OutputLock {
        &self.lock
    }
}

/// A `--restart` file must be a regular file: says what it is otherwise (a missing file, a
/// directory, /dev/null).
fn restartable(r: &Path) -> Result<()> {
    let shown = r.display();
    let fix = "fix: give the output file (.h5) of the interrupted run";
    let meta = match std::fs::metadata(r) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{shown}: no such file to restart from; {fix}")
        }
        Err(e) => bail!("{shown}: cannot look at the file to restart from: {e}; {fix}"),
    };
    let t = meta.file_type();
    if t.is_file() {
        return Ok(());
    }
    let what = if t.is_dir() {
        "a directory"
    } else {
        eprop_io::input::special_kind(&t)
    };
    bail!("{shown}: is {what}, not a series to restart from; {fix}")
}

/// Reads a scenario and claims its output before reading the mesh and before anything is
/// opened for writing: the output must not be one of the run's inputs, must not be written by
/// another run (the lock), and an existing file is replaced only when it is a series and the
/// user said so (or continued, with --restart).
pub fn prepare_claimed(path: &Path, opts: &RunOptions) -> Result<(Setup, Claim)> {
    prepare_claimed_on(path, opts, false)
}

/// `prepare_claimed` for a run whose processes start from a VTKHDF mesh in slabs (`slabs`:
/// under mpirun; `resolve`).
fn prepare_claimed_on(path: &Path, opts: &RunOptions, slabs: bool) -> Result<(Setup, Claim)> {
    let scenario = Scenario::load_with(path, &opts.sets)?;
    let (file, role) = output_of(&scenario, opts);
    check_output_dir(&file)?;
    let inputs = scenario.inputs();
    safety::refuse_inputs(&file, &role, &inputs)?;
    safety::refuse_inputs(&safety::lock_path(&file), "the lock file of the output", &inputs)?;
    if let Some(r) = &opts.restart {
        restartable(r)?;
    }
    let lock = OutputLock::take(&file)?;
    match &opts.restart {
        Some(_) => {}
        None => {
            let overwrite = opts.overwrite || scenario.file.output.overwrite;
            let again = again(path, &file, 1, opts);
            safety::check_existing(&file, &role, overwrite, &again)?;
        }
    }
    let setup = resolve(scenario, opts, slabs)?;
    Ok((setup, Claim { lock }))
}

/// Starts MPI in a process alone when its run calls a library that needs it (hypre: the
/// `amg` preconditioner; `launch::start_alone`).
pub(crate) fn start_mpi_if_needed(setup: &Setup) -> Result<()> {
    if setup.integrator.preconditioner == Preconditioner::Amg {
        start_alone()?;
    }
    Ok(())
}

/// Runs a scenario file on this process alone (`world` None) or on every process of
/// `world`; returns the summary on the process that prints it. SIGTERM, SIGINT and SIGHUP stop
/// the run after a complete, written step (`crate::guard::signals`).
pub fn run_on(world: Option<&dyn Comm>, path: &Path, opts: &RunOptions) -> Result<Option<Summary>> {
    let stop = crate::guard::signals::install();
    match world {
        Some(w) => run_mpi(w, path, opts, stop),
        None => run(path, opts, stop).map(Some),
    }
}

/// Runs a scenario file on one process to its stop condition (or until `stop` is requested);
/// returns the summary.
pub fn run(path: &Path, opts: &RunOptions, stop: StopToken) -> Result<Summary> {
    let t0 = Instant::now();
    let (setup, claim) = prepare_claimed(path, opts)?;
    let sizes = GlobalSizes::of(&setup.mesh);
    start_mpi_if_needed(&setup)?;
    let notes = progress::SetupNotes::on((!opts.quiet).then_some(t0));
    let sim = Simulation::new(setup)?;
    drop(notes);
    let summary = run_simulation(sim, sizes, t0, opts, Some(&claim), 0, stop)?;
    drop(claim);
    Ok(summary.expect("one process has the summary"))
}

/// Runs a scenario under MPI. Rank 0 reads the scenario, claims the output and reads the
/// mesh, splits the node graph with METIS and sends every process its part; each process
/// builds its own geometry and operator, steps its part with halo exchanges and writes its
/// rows of the output file (collective MPI-IO). Returns the summary on rank 0.
pub fn run_mpi(world: &dyn Comm, path: &Path, opts: &RunOptions, stop: StopToken) -> Result<Option<Summary>> {
    let t0 = Instant::now();
    let mut claim = None;
    let notes = progress::SetupNotes::on((world.rank() == 0 && !opts.quiet).then_some(t0));
    let b = build_mpi(world, || {
        let (setup, c) = prepare_claimed_on(path, opts, world.size() > 1)?;
        claim = Some(c);
        Ok(setup)
    })?;
    drop(notes);
    let summary = run_simulation(b.sim, b.sizes, t0, opts, claim.as_ref(), b.rank0_scatter_peak, stop);
    drop(claim);
    summary
}

/// Steps a built simulation to its stop condition with the scenario's own inputs
/// (`drive::Batch`); every process writes its block of the series, rank 0 returns the summary.
fn run_simulation(
    sim: Simulation,
    sizes: GlobalSizes,
    t0: Instant,
    opts: &RunOptions,
    claim: Option<&Claim>,
    rank0_scatter_peak: u64,
    stop: StopToken,
) -> Result<Option<Summary>> {
    let again = again(
        &sim.setup().scenario.path,
        &sim.setup().output.file,
        sim.comm().size(),
        opts,
    );
    let settings = Settings {
        live: false,
        sizes,
        claim: claim.map(Claim::lock),
        restart: opts.restart.is_some(),
        steps_from_cli: opts.steps.is_some(),
        force: opts.force,
        quiet: opts.quiet,
        progress_every: opts.progress_every,
        again: "run again",
        next: format!("continue with `{again}`"),
        t0,
        rank0_scatter_peak,
        stop,
    };
    let checked = drive::check(&sim, &settings)?;
    drive::drive(sim, &mut Batch, &settings, checked)
}
