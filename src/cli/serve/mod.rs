//! `eprop serve`: a scenario whose live tools and loads are driven by a client over TCP
//! (docs/protocol.md).
//!
//! Rank 0 holds the socket in a network thread (`session`), which answers each client message
//! at once from the latest physics results. The main thread of every process runs the
//! physics: before step k (time t_k) rank 0 waits until the client has sent a sample of
//! every live input at or beyond t_k (or bye) and broadcasts the new samples; every process
//! appends them to the same histories, so step k uses the inputs interpolated at t_k exactly
//! as a batch run with the same samples in a table does, and writes the same series.

pub mod protocol;
pub mod session;

use crate::cli::run::{prepare_claimed, write_failed, RunOptions};
use crate::config::tables::History;
use crate::config::{Setup, Trajectory};
use crate::discretize::operator::V3;
use crate::distribute::parts::{Collective, GlobalSizes, ReportedElsewhere};
use crate::output::progress::Progress;
use crate::output::series::Series;
use crate::output::summary::{summarize, Summary, Timing};
use crate::simulate::distributed::build_mpi;
use crate::simulate::Simulation;
use anyhow::{anyhow, bail, Result};
use mpi::topology::SimpleCommunicator;
use protocol::{Hello, MAX_LIVE};
use serde::Serialize;
use session::{Entities, Outcome, Session, SessionSummary};
use std::net::TcpListener;
use std::path::Path;
use std::time::{Duration, Instant};

/// `eprop serve` options.
#[derive(Clone)]
pub struct ServeOptions {
    /// Address to listen on (`127.0.0.1:PORT`; port 0 picks a free one).
    pub listen: String,
    /// Seconds the run waits for the client (to connect, then for each step's samples).
    pub timeout: f64,
    pub run: RunOptions,
}

/// What `eprop serve` reports at the end: the run's summary and the session's.
#[derive(Serialize, Debug, Clone)]
pub struct ServeReport {
    #[serde(flatten)]
    pub summary: Summary,
    pub session: SessionSummary,
}

impl std::fmt::Display for ServeReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "{}", self.summary)?;
        let s = &self.session;
        write!(
            f,
            "  session     {} on {}: {} messages, {} answers, the physics waited {:.3} s for samples; ended: {}",
            s.client.as_deref().unwrap_or("no client"),
            s.listen,
            s.messages,
            s.answers,
            s.waited_seconds,
            s.ended
        )
    }
}

/// Binds the listening socket (rank 0, before the setup, so a busy port fails at once).
fn bind(addr: &str) -> Result<TcpListener> {
    let l = TcpListener::bind(addr).map_err(|e| {
        anyhow!("{addr}: cannot listen: {e}; fix: give a free port of this machine as --listen HOST:PORT (port 0 picks one)")
    })?;
    let at = l
        .local_addr()
        .map(|a| a.to_string())
        .unwrap_or_else(|_| addr.to_string());
    eprintln!("eprop serve: listening on {at}");
    Ok(l)
}

/// The scenario must give the client something to drive.
fn check_live(setup: &Setup) -> Result<()> {
    let path = setup.scenario.path.display();
    let (tools, loads): (Vec<usize>, Vec<usize>) = (
        (0..setup.tools.len()).filter(|&k| setup.tools[k].live).collect(),
        (0..setup.loads.len()).filter(|&k| setup.loads[k].live).collect(),
    );
    if tools.is_empty() && loads.is_empty() {
        bail!("{path}: no [[tool]] or [[load]] has `live = true`, so the client would drive nothing; fix: add `live = true` to the tool or load the client moves");
    }
    if let Some(k) = tools.iter().chain(&loads).find(|&&k| k >= MAX_LIVE) {
        bail!("{path}: tool or load {} is live, but only the first {MAX_LIVE} tools and loads can be; fix: list the live ones first", k + 1);
    }
    Ok(())
}

/// Runs a scenario driven by a client on this process alone or on every process of `world`;
/// returns the report on rank 0.
pub fn serve_on(world: Option<SimpleCommunicator>, path: &Path, opts: &ServeOptions) -> Result<Option<ServeReport>> {
    let t0 = Instant::now();
    crate::guard::signals::install();
    let listener = std::cell::RefCell::new(None);
    // the output claimed as `eprop run` claims it (not an input, one writer, no silent
    // replacement), held to the end of the session
    let claim = std::cell::RefCell::new(None);
    let make = || -> Result<Setup> {
        *listener.borrow_mut() = Some(bind(&opts.listen)?);
        let (setup, c) = prepare_claimed(path, &opts.run)?;
        *claim.borrow_mut() = Some(c);
        check_live(&setup)?;
        Ok(setup)
    };
    let (sim, sizes, io_comm) = match world {
        None => {
            let setup = make()?;
            let sizes = GlobalSizes::of(&setup.mesh);
            (Simulation::new(setup)?, sizes, None)
        }
        Some(w) => {
            let b = build_mpi(w, make)?;
            (b.sim, b.sizes, Some(b.io_comm))
        }
    };
    let report = serve_simulation(sim, sizes, listener.into_inner(), io_comm.as_ref(), opts, t0);
    drop(claim);
    report
}

/// The live inputs, tools first (`Entities`).
fn entities(sim: &Simulation) -> Entities {
    let mut live: Vec<bool> = sim.tools.iter().map(|t| t.tool.live).collect();
    live.extend(sim.loads.iter().map(|l| l.live));
    Entities {
        tools: sim.tools.len(),
        live,
    }
}

/// Appends samples (entity, [t, x, y, z]) to the live inputs' histories.
fn apply(sim: &mut Simulation, samples: &[(u32, [f64; 4])]) -> Result<()> {
    let nt = sim.tools.len();
    for &(e, row) in samples {
        let e = e as usize;
        let h = if e < nt {
            match &mut sim.tools[e].tool.path {
                Trajectory::Table(h) => h,
                Trajectory::Linear { .. } => bail!("internal: live tool {e} has no history"),
            }
        } else {
            sim.loads[e - nt]
                .history
                .as_mut()
                .ok_or_else(|| anyhow!("internal: live load {} has no history", e - nt))?
        };
        h.push(row)
            .map_err(|m| anyhow!("internal: a sample the session accepted: {m}"))?;
    }
    Ok(())
}

/// Drops the samples no time from t on needs.
fn forget_before(sim: &mut Simulation, t: f64) {
    for run in sim.tools.iter_mut().filter(|r| r.tool.live) {
        if let Trajectory::Table(h) = &mut run.tool.path {
            h.forget_before(t);
        }
    }
    for l in sim.loads.iter_mut().filter(|l| l.live) {
        if let Some(h) = &mut l.history {
            h.forget_before(t);
        }
    }
}

/// Rank 0 waits for the samples that cover time t and sends them to every process; every
/// process appends them. Err: the session ended (rank 0 has the message).
/// How the session ended before a step: rank 0's message, and the stop signal that ended it
/// (0: the client or a timeout).
struct Ended {
    msg: String,
    signal: i32,
}

fn inputs(sim: &mut Simulation, session: Option<&mut Session>, t: f64) -> Result<Result<(), Ended>> {
    let got = match session {
        Some(s) => s.wait(t),
        None => Ok(Vec::new()),
    };
    let c = sim.comm.as_ref();
    // head: [0 or 1 (the session ended), samples, the stop signal rank 0 has seen]
    let mut head = match &got {
        Ok(samples) => [0.0, samples.len() as f64, 0.0],
        Err(_) => [1.0, 0.0, f64::from(crate::guard::signals::pending())],
    };
    c.broadcast(0, &mut head);
    if head[0] != 0.0 {
        let msg = got.err().unwrap_or_default();
        return Ok(Err(Ended {
            msg,
            signal: head[2] as i32,
        }));
    }
    let mut flat: Vec<f64> = match &got {
        Ok(samples) => samples
            .iter()
            .flat_map(|(e, r)| [*e as f64, r[0], r[1], r[2], r[3]])
            .collect(),
        Err(_) => Vec::new(),
    };
    flat.resize(5 * head[1] as usize, 0.0);
    c.broadcast(0, &mut flat);
    let samples: Vec<(u32, [f64; 4])> = flat
        .chunks_exact(5)
        .map(|s| (s[0] as u32, [s[1], s[2], s[3], s[4]]))
        .collect();
    apply(sim, &samples)?;
    Ok(Ok(()))
}

/// Each entity's result at the current step (every process calls: the loads' probes are
/// reductions).
fn outcomes(sim: &Simulation, any_live_load: bool) -> Vec<Outcome> {
    let mut out: Vec<Outcome> = sim
        .tool_states()
        .iter()
        .map(|t| Outcome {
            step: sim.step,
            t: sim.time,
            force: t.force,
            displacement: t.displacement,
        })
        .collect();
    let probes: Vec<(V3, V3)> = if any_live_load {
        sim.probes()
    } else {
        vec![([0.0; 3], [0.0; 3]); sim.loads.len()]
    };
    out.extend(probes.iter().map(|&(f, d)| Outcome {
        step: sim.step,
        t: sim.time,
        force: f,
        displacement: d,
    }));
    out
}

/// What a series holds, for messages.
fn keeps(series: &Series, last: u64) -> String {
    format!(
        "{} keeps its {} complete output steps (to step {last})",
        series.path().display(),
        series.steps_written()
    )
}

/// The error every process returns when the session ended: rank 0 prints it once; a stop
/// signal ends every process with the stop status.
fn ended(rank: usize, e: Ended) -> anyhow::Error {
    let msg = e.msg;
    if e.signal != 0 {
        return crate::guard::safety::Agreed::error(crate::guard::safety::EXIT_STOPPED, format!("eprop serve: {msg}"));
    }
    if rank == 0 {
        Collective(format!("eprop serve: {msg}")).into()
    } else {
        ReportedElsewhere.into()
    }
}

fn serve_simulation(
    mut sim: Simulation,
    sizes: GlobalSizes,
    listener: Option<TcpListener>,
    io_comm: Option<&SimpleCommunicator>,
    opts: &ServeOptions,
    t0: Instant,
) -> Result<Option<ServeReport>> {
    let rank = sim.comm.rank();
    let ents = entities(&sim);
    let any_live_load = ents.live[ents.tools..].iter().any(|&b| b);
    // live inputs start empty: the client's samples are their history
    for run in sim.tools.iter_mut().filter(|r| r.tool.live) {
        run.tool.path = Trajectory::Table(History::empty());
    }
    for l in sim.loads.iter_mut().filter(|l| l.live) {
        l.history = Some(History::empty());
    }
    let mask = |from: usize, to: usize| {
        (from..to)
            .filter(|&e| ents.live[e])
            .fold(0u32, |m, e| m | 1 << (e - from))
    };
    let hello = Hello {
        tools: ents.tools as u32,
        loads: (ents.live.len() - ents.tools) as u32,
        live_tools: mask(0, ents.tools),
        live_loads: mask(ents.tools, ents.live.len()),
        dt: sim.dt,
        t0: sim.time,
        timeout: opts.timeout,
        max_steps: sim.max_steps(),
    };
    let timeout = Duration::from_secs_f64(opts.timeout);
    let mut session = match listener {
        Some(l) => Some(
            Session::start(l, ents.clone(), hello, timeout)
                .map_err(|e| anyhow!("eprop serve: cannot start the network thread: {e}"))?,
        ),
        None => None,
    };
    // step 0: its inputs, then the series as in batch
    let start = sim.time;
    if let Err(msg) = inputs(&mut sim, session.as_mut(), start)? {
        drop(session);
        return Err(ended(rank, msg));
    }
    sim.tools_at_rest();
    let mut series = Series::start(&mut sim, &sizes, false, io_comm).map_err(|e| {
        write_failed(
            e,
            "nothing was written (the unfinished file was removed)",
            "serve again",
        )
    })?;
    let mut written = sim.step;
    if let Some(s) = &session {
        s.publish(&outcomes(&sim, any_live_load));
    } else if any_live_load {
        outcomes(&sim, any_live_load);
    }
    let setup_seconds = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let every = sim.setup.output.every;
    let mut progress = Progress::new(
        rank == 0 && !opts.run.quiet,
        sim.step,
        sim.max_steps(),
        opts.run.progress_every,
    );
    let mut failure = None;
    while !sim.done() {
        let t_next = (sim.step + 1) as f64 * sim.dt;
        if let Err(msg) = inputs(&mut sim, session.as_mut(), t_next)? {
            failure = Some(msg);
            break;
        }
        let now = sim.time;
        forget_before(&mut sim, now);
        if let Err(e) = sim.advance() {
            if let Some(s) = &session {
                s.fail(&format!("the run failed: {e:#}"));
            }
            return Err(e);
        }
        // a stop signal rides on the step's reduction: every process stops after this step
        let stop = sim.stop_signal;
        if sim.step.is_multiple_of(every) || sim.done() || stop != 0 {
            if let Err(e) = series.append(&sim) {
                let e = write_failed(e, &keeps(&series, written), "serve again");
                if let Some(s) = &session {
                    s.fail(&format!("the series could not be written: {e:#}"));
                }
                return Err(e);
            }
            written = sim.step;
        }
        let o = outcomes(&sim, any_live_load);
        if let Some(s) = &session {
            s.publish(&o);
        }
        progress.update(sim.step, sim.max_speed);
        if stop != 0 {
            progress.finish();
            let msg = format!(
                "eprop serve: stopped by {} after step {} of {}: {}",
                crate::guard::signals::name(stop),
                sim.step,
                sim.max_steps(),
                keeps(&series, written)
            );
            if let Some(s) = &session {
                s.fail(&msg);
            }
            drop(session);
            return Err(crate::guard::safety::Agreed::error(
                crate::guard::safety::EXIT_STOPPED,
                msg,
            ));
        }
    }
    progress.finish();
    // the series ends with the last step computed, whatever the client did
    if written != sim.step {
        series
            .append(&sim)
            .map_err(|e| write_failed(e, &keeps(&series, written), "serve again"))?;
    }
    if let Some(mut e) = failure {
        drop(session);
        if e.signal != 0 {
            e.msg = format!("{}; {}", e.msg, keeps(&series, sim.step));
        }
        return Err(ended(rank, e));
    }
    let timing = Timing {
        setup_seconds,
        wall_seconds: t1.elapsed().as_secs_f64(),
        restarted_from_step: None,
        rank0_scatter_peak: 0,
    };
    let warnings = match &sim.global {
        Some(mesh) => crate::guard::plausible::load_warnings(&sim, mesh),
        None => vec![],
    };
    let summary = summarize(&sim, &sizes, &series, timing, warnings);
    let session = session.map(Session::finish);
    Ok(summary
        .zip(session)
        .map(|(summary, session)| ServeReport { summary, session }))
}
