//! The time loop of `eprop run` and `eprop serve`. Before the output is opened, `check`: the
//! limits (`limits::Budget`), the free space and the load warnings. Then `drive`: the series
//! created (or reopened), and per step the inputs its `Feed` supplies, the step, and at output
//! steps the non-finite watch (`plausible::Watch`), the free-space check, the append and the
//! warning when the mesh first folds (`fold::Record`); the progress bar, the stop signal and the summary. The feed is all that differs: `Batch` for
//! `eprop run` (the scenario's own inputs), the client's session for `eprop serve`.

use crate::guard::plausible::{self, Look, Watch};
use anyhow::Result;
use eprop::config::Stop;
use eprop::distribute::launch::{Agreed, EXIT_ERROR, EXIT_STOPPED, EXIT_WRITE};
use eprop::distribute::parts::GlobalSizes;
use eprop::guard::limits::Budget;
use eprop::guard::safety::{self, OutputLock};
use eprop::output::progress::{Every, Progress};
use eprop::output::series::Series;
use eprop::output::summary::{summarize, Summary, Timing};
use eprop::simulate::{Simulation, StopToken};
use eprop_series::outcome::{dir_of, free_bytes, human_bytes, Cause, WriteFailed};
use std::time::Instant;

/// A feed ends the run before its next step: its message (on rank 0; empty elsewhere) and the
/// stop signal that ended it (0: none).
pub struct Halt {
    pub message: String,
    pub signal: i32,
}

/// What supplies a run's inputs step by step and hears its results. Every process calls each
/// method at the same point of the loop.
pub trait Feed {
    /// Before step 0 is written: the inputs at the start. `Some`: the run ends before it began
    /// (nothing is written).
    fn start(&mut self, _sim: &mut Simulation) -> Result<Option<Halt>> {
        Ok(None)
    }
    /// Before each step: the inputs the step needs. `Some`: the run ends with the last step
    /// computed (written to the series first).
    fn before_step(&mut self, _sim: &mut Simulation) -> Result<Option<Halt>> {
        Ok(None)
    }
    /// Before each step while written steps are not yet complete in the file: true when the
    /// inputs of the next step are not there yet (a client that pauses), so that the series
    /// is committed before the feed waits on. The same answer on every process.
    fn idle(&mut self, _sim: &mut Simulation) -> Result<bool> {
        Ok(false)
    }
    /// After step 0 is written and after each step.
    fn after_step(&mut self, _sim: &Simulation) {}
    /// The run ends in an error; `why` says it in a few words (for a client).
    fn failed(&mut self, _why: &str) {}
}

/// The feed of `eprop run`: the scenario's own loads and tool paths.
pub struct Batch;

impl Feed for Batch {}

/// How a run is driven: what it writes and what its messages advise.
pub struct Settings<'a> {
    pub sizes: GlobalSizes,
    /// The claim on the output (`safety::OutputLock`) of the process that took it (rank 0):
    /// a created series' inode is locked too.
    pub claim: Option<&'a OutputLock>,
    /// Continue the series in the output file (`--restart`).
    pub restart: bool,
    /// The inputs come from a client (`serve`): the series is marked so, and `run --restart`
    /// refuses it (the client's samples are in no file).
    pub live: bool,
    /// The step count came from `--steps`.
    pub steps_from_cli: bool,
    /// Start and write even when the disk is short of space (`--force`).
    pub force: bool,
    pub quiet: bool,
    /// Progress lines without a terminal: every N steps or T seconds (`--progress-every`).
    pub progress_every: Every,
    /// What starts the run anew after a failed creation: "run again".
    pub again: &'static str,
    /// What to do after the run stopped with its series intact: "continue with `...`".
    pub next: String,
    /// When the command started (for the setup time).
    pub t0: Instant,
    /// The stop the command's signal handler requests (`crate::guard::signals`): the run
    /// stops after the step in progress, written.
    pub stop: StopToken,
    pub rank0_scatter_peak: u64,
}

/// Rank 0's verdict, made every process's: an `Agreed` error on every process when rank 0's
/// `r` is one (rank 0 prints its message).
fn from_root(sim: &Simulation, r: Result<()>, status: u8) -> Result<()> {
    let root = sim.comm().rank() == 0;
    let failed = sim.comm().max(f64::from(u8::from(root && r.is_err())));
    match (failed > 0.0, r) {
        (false, _) => Ok(()),
        (true, Err(e)) => Err(Agreed::error(status, format!("{e:#}"))),
        (true, Ok(())) => Err(Agreed::error(status, "rank 0 refused the run")),
    }
}

/// The complete steps of a series, for messages.
fn holds(series: &Series) -> String {
    format!(
        "{} keeps its {} complete output steps (to step {})",
        series.path().display(),
        series.steps_complete(),
        series.complete_step()
    )
}

/// A failed output write, as the message every process ends with: what failed, the state of
/// the file, the fix and what to do `next`.
fn write_failed(e: anyhow::Error, state: &str, next: &str) -> anyhow::Error {
    match e.downcast_ref::<WriteFailed>() {
        Some(w) => Agreed::error(EXIT_WRITE, format!("{w}; {state}; fix: {}, then {next}", w.cause.fix())),
        None => e,
    }
}

/// A failed creation or reopening: status 4 (write again after freeing space) only when the
/// system names a write cause; otherwise (a file name HDF5 cannot take, a truncated or
/// damaged file to restart from) it is an error of the input, status 1.
fn open_failed(e: anyhow::Error, state: &str, next: &str, restart: bool) -> anyhow::Error {
    match e.downcast_ref::<WriteFailed>() {
        Some(w) if w.cause == Cause::Other => {
            let what = match restart {
                true => "is it a complete series written by `eprop run` (not truncated or damaged)? ",
                false => "is the output a valid file name? ",
            };
            Agreed::error(
                EXIT_ERROR,
                format!("{w}; {state}; fix: {what}{}, then {next}", w.cause.fix()),
            )
        }
        _ => write_failed(e, state, next),
    }
}

/// What the output system said, in a few words.
fn cause(e: &anyhow::Error) -> String {
    match e.downcast_ref::<WriteFailed>() {
        Some(w) => w.cause.text().to_string(),
        None => format!("{e:#}"),
    }
}

/// Refuses an output that would not fit on its disk (rank 0 looks; every process ends alike).
fn space(sim: &Simulation, budget: &Budget, s: &Settings) -> Result<()> {
    let file = &sim.setup().output.file;
    let reclaimed = if s.restart {
        0
    } else {
        std::fs::metadata(file).map(|m| m.len()).unwrap_or(0)
    };
    let what = format!(
        "{} output steps of {}{}",
        budget.output_steps,
        human_bytes(budget.step_bytes),
        if matches!(sim.setup().time.stop, Stop::Equilibrium { .. }) {
            format!(
                ", at most: if equilibrium is not reached before the cap of {} steps",
                budget.steps
            )
        } else {
            String::new()
        }
    );
    let r = if sim.comm().rank() == 0 {
        safety::check_space(file, budget, reclaimed, &what, s.force)
    } else {
        Ok(())
    };
    from_root(sim, r, EXIT_ERROR)
}

/// What `check` found: the run's budget and the warnings so far.
pub struct Checked {
    budget: Budget,
    warnings: Vec<String>,
}

/// The checks of a built simulation before anything is written (every process calls): the
/// limits on steps, substeps, step sizes and output (`Budget`), the free space for a new
/// series, and the load warnings (printed on rank 0 unless quiet).
pub fn check(sim: &Simulation, s: &Settings) -> Result<Checked> {
    let plan = sim.step_plan();
    tracing::info!(
        "{}: Euler substep h = {:.4e} (bound {:.4e}), dt = {:.4e}, {} per step; writing {}",
        plan.integrator.name(),
        plan.h,
        plan.h_bound,
        sim.dt(),
        plan.per_step_phrase(),
        sim.setup().output.file.display()
    );
    // every process computes the same verdicts from the same numbers
    let budget = Budget::of(sim, &s.sizes, s.steps_from_cli, !s.restart).map_err(|e| Agreed::error(EXIT_ERROR, e))?;
    plausible::tool_reach(sim).map_err(|e| Agreed::error(EXIT_ERROR, e))?;
    if !s.restart {
        space(sim, &budget, s)?;
    }
    let root = sim.comm().rank() == 0;
    // the whole mesh's bounds and the loads' nodes (reductions on a start from the slabs)
    let mut warnings = match sim.whole_mesh(&plausible::load_nodes(sim)) {
        Some(mesh) if root => plausible::load_warnings(sim, &mesh),
        _ => vec![],
    };
    // every process takes part (reductions); rank 0 keeps them
    let tools = plausible::tool_warnings(sim);
    if root {
        warnings.extend(tools);
    }
    if root && !s.quiet {
        for w in &warnings {
            eprintln!("warning: {w}");
        }
    }
    Ok(Checked { budget, warnings })
}

/// An error that ends the loop, and how a client hears of it.
struct Failure {
    why: String,
    error: anyhow::Error,
}

impl From<anyhow::Error> for Failure {
    fn from(error: anyhow::Error) -> Failure {
        Failure {
            why: format!("the run failed: {error:#}"),
            error,
        }
    }
}

/// Steps a checked simulation to its stop condition with the inputs of `feed`; every process
/// writes its block of the series, rank 0 returns the summary. SIGTERM, SIGINT and SIGHUP stop
/// the run after a complete, written step (`crate::guard::signals`).
pub fn drive(mut sim: Simulation, feed: &mut dyn Feed, s: &Settings, checked: Checked) -> Result<Option<Summary>> {
    let mut progress = None;
    let r = steps(&mut sim, feed, s, checked, &mut progress);
    // the bar goes before any message
    if let Some(p) = progress {
        p.finish();
    }
    r.map_err(|f| {
        feed.failed(&f.why);
        f.error
    })
}

/// The output side of the loop: the series and what was last written to it.
struct Output {
    series: Series,
    last_written: u64,
    watch: Watch,
    warnings: Vec<String>,
    budget: Budget,
}

impl Output {
    /// Writes the current step: its state must be finite (a warning the first time max |u|
    /// passes its limit) and, unless forced, the disk must hold it with room to spare
    /// (stopping before a write that cannot finish leaves the file closed cleanly).
    /// With `commit` the step is complete in the file when this returns, else at the next
    /// commit (`[output] flush`).
    fn write(&mut self, sim: &Simulation, s: &Settings, progress: &Progress, commit: bool) -> Result<(), Failure> {
        let root = sim.comm().rank() == 0;
        match self.watch.look(sim) {
            Look::NonFinite => {
                // the finite steps written before are kept
                self.complete(s)?;
                return Err(Failure {
                    why: format!("the state is no longer finite (NaN or inf) at step {}", sim.step()),
                    error: Agreed::error(
                        EXIT_ERROR,
                        format!(
                            "{}: at step {} (t = {:.6e}) the displacement, velocity, potential or a tool's state is no longer finite (NaN or inf), so the run stopped; {}. Likely cause: {}",
                            sim.setup().scenario.path.display(),
                            sim.step(),
                            sim.time(),
                            holds(&self.series),
                            plausible::nonfinite_cause(sim)
                        ),
                    ),
                });
            }
            Look::Finite(Some(w)) => {
                if root && !s.quiet {
                    progress.println(&format!("warning: {w}"));
                }
                self.warnings.push(w);
            }
            Look::Finite(None) => {}
        }
        let file = &sim.setup().output.file;
        if !s.force {
            let step_bytes = self.budget.step_bytes;
            let full = root
                && free_bytes(&dir_of(file))
                    .is_some_and(|free| (free as f64) < eprop::guard::limits::reserve(step_bytes));
            if sim.comm().max(f64::from(u8::from(full))) > 0.0 {
                // the steps written before are counted (a few bytes of the reserve)
                self.complete(s)?;
                let free = free_bytes(&dir_of(file)).unwrap_or(0);
                return Err(Failure {
                    why: format!(
                        "the disk is nearly full: output step {} was not written",
                        self.series.steps_written()
                    ),
                    error: Agreed::error(
                        EXIT_WRITE,
                        format!(
                            "{}: the disk is nearly full: {} free in {}, less than the {} kept free while writing (two output steps of about {} and 1 MiB, so that no write fails half-way), so output step {} was not written; {}; fix: free space on that disk (or move the file to a larger one), then {}",
                            file.display(),
                            human_bytes(free as f64),
                            dir_of(file).display(),
                            human_bytes(eprop::guard::limits::reserve(step_bytes)),
                            human_bytes(step_bytes),
                            self.series.steps_written(),
                            holds(&self.series),
                            s.next
                        ),
                    ),
                });
            }
        }
        let appended = self.series.append(sim, commit);
        appended.map_err(|e| self.failed(e, s))?;
        // the first output step with inverted cells, and the first with nodes across a
        // support: one warning each (every process takes part)
        for w in self.series.fold_warnings(sim) {
            if root && !s.quiet {
                progress.println(&format!("warning: {w}"));
            }
            self.warnings.push(w);
        }
        self.last_written = sim.step();
        Ok(())
    }

    /// Makes every written step complete in the file.
    fn complete(&mut self, s: &Settings) -> Result<(), Failure> {
        let committed = self.series.commit();
        committed.map_err(|e| self.failed(e, s))
    }

    /// A failed write of the series, with what the file keeps.
    fn failed(&self, e: anyhow::Error, s: &Settings) -> Failure {
        Failure {
            why: format!("the series could not be written: {}", cause(&e)),
            error: write_failed(e, &holds(&self.series), &s.next),
        }
    }
}

fn steps(
    sim: &mut Simulation,
    feed: &mut dyn Feed,
    s: &Settings,
    checked: Checked,
    progress: &mut Option<Progress>,
) -> Result<Option<Summary>, Failure> {
    let fresh = !s.restart;
    let show = sim.comm().rank() == 0 && !s.quiet;
    sim.set_stop(s.stop.clone());
    if let Some(h) = feed.start(sim)? {
        return Err(halted(h, None));
    }
    let series = Series::start(sim, &s.sizes, s.restart, s.live, s.claim).map_err(|e| Failure {
        why: format!("the series could not be created: {}", cause(&e)),
        error: match fresh {
            true if sim.setup().output.file.exists() => {
                open_failed(e, "nothing was written; the file is left as it is", s.again, false)
            }
            true => open_failed(
                e,
                "nothing was written (the unfinished file was removed)",
                s.again,
                false,
            ),
            false => open_failed(e, "the file holds what it held", "restart again", true),
        },
    })?;
    let budget = match fresh {
        true => checked.budget,
        // the restored step: what is left to write
        false => {
            let budget =
                Budget::of(sim, &s.sizes, s.steps_from_cli, fresh).map_err(|e| Agreed::error(EXIT_ERROR, e))?;
            space(sim, &budget, s)?;
            budget
        }
    };
    // a restart of a series that is complete already: nothing to step or write
    let already_complete = !fresh && sim.done();
    feed.after_step(sim);
    let restarted_at = sim.step();
    let setup_seconds = s.t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let every = sim.setup().output.every;
    let bar = progress.insert(Progress::new(show, restarted_at, sim.max_steps(), s.progress_every));
    let mut out = Output {
        series,
        last_written: sim.step(),
        watch: Watch::new(sim),
        warnings: checked.warnings,
        budget,
    };
    while !sim.done() {
        // a feed that would wait: what was written is made complete first (every process)
        if out.series.pending() && feed.idle(sim)? {
            out.complete(s)?;
        }
        if let Some(h) = feed.before_step(sim)? {
            // the series ends with the last step computed
            if out.last_written != sim.step() {
                out.write(sim, s, bar, true)?;
            }
            out.complete(s)?;
            return Err(halted(h, Some(holds(&out.series))));
        }
        sim.advance()?;
        // a stop request rides on the step's reduction: every process stops after this step
        let stop = sim.stop_signal();
        if sim.step().is_multiple_of(every) || sim.done() || stop != 0 {
            out.write(sim, s, bar, sim.done() || stop != 0)?;
        }
        feed.after_step(sim);
        bar.update(sim.step(), sim.max_speed());
        if stop != 0 {
            let name = crate::guard::signals::name(stop);
            return Err(Failure {
                why: format!("stopped by {name} after step {}", sim.step()),
                error: Agreed::error(
                    EXIT_STOPPED,
                    format!(
                        "stopped by {name} after step {} of {}: {}; {}",
                        sim.step(),
                        sim.max_steps(),
                        holds(&out.series),
                        s.next
                    ),
                ),
            });
        }
    }
    let timing = Timing {
        setup_seconds,
        wall_seconds: t1.elapsed().as_secs_f64(),
        restarted_from_step: s.restart.then_some(restarted_at),
        already_complete,
        rank0_scatter_peak: s.rank0_scatter_peak,
    };
    Ok(summarize(sim, &s.sizes, &out.series, timing, out.warnings))
}

/// The error of a run its feed ended: status 3 for a stop signal, 1 otherwise; with what the
/// series holds once there is one.
fn halted(h: Halt, holds: Option<String>) -> Failure {
    let status = if h.signal != 0 { EXIT_STOPPED } else { EXIT_ERROR };
    let message = match holds {
        Some(holds) => format!("{}; {holds}", h.message),
        None => h.message,
    };
    Failure {
        why: message.clone(),
        error: Agreed::error(status, message),
    }
}
