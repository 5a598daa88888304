//! `eprop serve`: a scenario whose live tools and loads are driven by a client over TCP
//! (docs/protocol.md).
//!
//! Rank 0 holds the socket in a network thread (`session`), which answers each client message
//! at once from the latest physics results. The main thread of every process runs the
//! physics in the time loop of `eprop run` (`drive`), fed by the client (`Live`): before step
//! k (time t_k) rank 0 waits until the client has sent a sample of every live input at or
//! beyond t_k (or bye) and broadcasts the new samples; every process appends them to the same
//! histories, so step k uses the inputs interpolated at t_k exactly as a batch run with the
//! same samples in a table does, and writes the same series. A client of protocol version 2
//! may ask for the deformed surface (`stream`): rank 0 gathers the surface nodes'
//! displacements every K steps and the network thread sends them after its answers.

pub use eprop::protocol;
pub mod session;
pub mod stream;

use crate::cli::drive::{self, Feed, Halt, Settings};
use crate::cli::run::{prepare_claimed, start_mpi_if_needed, RunOptions};
use anyhow::{anyhow, bail, Result};
use eprop::config::Setup;
use eprop::distribute::comm::Comm;
use eprop::distribute::parts::GlobalSizes;
use eprop::linalg::V3;
use eprop::output::summary::Summary;
use eprop::simulate::distributed::build_mpi;
use eprop::simulate::Simulation;
use protocol::{Hello, MAX_LIVE};
use serde::Serialize;
use session::{Entities, Frame, Outcome, Session, SessionSummary, Waited};
use std::net::TcpListener;
use std::path::Path;
use std::sync::Arc;
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
        )?;
        if let Some(w) = &s.warning {
            write!(f, "\n  warning     {w}")?;
        }
        Ok(())
    }
}

/// Binds the listening socket (rank 0, before the setup, so a busy port fails at once).
fn bind(addr: &str) -> Result<TcpListener> {
    TcpListener::bind(addr).map_err(|e| {
        anyhow!("{addr}: cannot listen: {e}; fix: give a free port of this machine as --listen HOST:PORT (port 0 picks one)")
    })
}

/// Says where the server listens, once every check of the run has passed.
fn announce(l: &TcpListener, addr: &str) {
    let at = l
        .local_addr()
        .map(|a| a.to_string())
        .unwrap_or_else(|_| addr.to_string());
    eprintln!("eprop serve: listening on {at}");
}

/// The scenario must give the client something to drive.
pub(crate) fn check_live(setup: &Setup) -> Result<()> {
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
pub fn serve_on(world: Option<&dyn Comm>, path: &Path, opts: &ServeOptions) -> Result<Option<ServeReport>> {
    let t0 = Instant::now();
    // (the command line checks it as it is read)
    if !(opts.timeout > 0.0 && opts.timeout <= 1e9) {
        bail!(
            "timeout {}: must be a positive number of seconds (at most 1e9); fix: give, say, 10",
            opts.timeout
        );
    }
    let stop = crate::guard::signals::install();
    let listener = std::cell::RefCell::new(None);
    // the output claimed as `eprop run` claims it (not an input, one writer, no silent
    // replacement), held to the end of the session
    let claim = std::cell::RefCell::new(None);
    let make = || -> Result<Setup> {
        *listener.borrow_mut() = Some(bind(&opts.listen)?);
        let (mut setup, c) = prepare_claimed(path, &opts.run)?;
        *claim.borrow_mut() = Some(c);
        // serve runs in the real-time mode unless the scenario says realtime = false or names
        // an integrator, and then writes about 30 steps a second of simulated time unless it
        // names `every`
        let named = setup.integrator.kind != eprop::config::integrator::Kind::Auto;
        if *setup.time.realtime.get_or_insert(!named) {
            if let Some(dt) = setup.time.dt {
                setup.output.every_for_realtime(dt);
            }
        }
        check_live(&setup)?;
        Ok(setup)
    };
    let (sim, sizes, peak) = match world {
        None => {
            let setup = make()?;
            let sizes = GlobalSizes::of(&setup.mesh);
            start_mpi_if_needed(&setup)?;
            (Simulation::new(setup)?, sizes, 0)
        }
        Some(w) => {
            let b = build_mpi(w, make)?;
            (b.sim, b.sizes, b.rank0_scatter_peak)
        }
    };
    let claim = claim.into_inner();
    let settings = Settings {
        live: true,
        sizes,
        claim: claim.as_ref().map(|c| c.lock()),
        restart: false,
        steps_from_cli: opts.run.steps.is_some(),
        force: opts.run.force,
        quiet: opts.run.quiet,
        progress_every: opts.run.progress_every,
        again: "serve again",
        next: "serve again".into(),
        t0,
        rank0_scatter_peak: peak,
        stop,
    };
    let report = serve_simulation(sim, &settings, listener.into_inner(), opts);
    drop(claim);
    report
}

/// The live inputs, tools first (`Entities`).
fn entities(sim: &Simulation) -> Entities {
    Entities {
        tools: sim.tools().len(),
        live: sim.live_inputs(),
    }
}

/// Rank 0 waits for the samples that cover time t and sends them to every process; every
/// process appends them and learns every how many steps the client wants a frame of the
/// surface (`every`, 0: none). `Some`: the session ended (rank 0 has the message), with the
/// stop signal that ended it (0: the client or a timeout).
/// With `poll`, rank 0 gives up waiting after that long and every process hears `NotYet`
/// (nothing applied), so that they can commit the series together before waiting on.
fn inputs(
    sim: &mut Simulation,
    session: Option<&mut Session>,
    t: f64,
    every: &mut u64,
    poll: Option<Duration>,
) -> Result<Inputs> {
    let (got, wanted, signal) = match session {
        Some(s) => {
            let got = s.wait(t, poll);
            (got, s.stream_every(), s.stop_requested())
        }
        None => (Ok(Waited::Samples(Vec::new())), 0, 0),
    };
    let c = sim.comm();
    // head: [0, 1 (the session ended) or 2 (not yet), samples, the stop signal rank 0 has
    // seen, every]
    let mut head = match &got {
        Ok(Waited::Samples(samples)) => [0.0, samples.len() as f64, 0.0, wanted as f64],
        Ok(Waited::NotYet) => [2.0, 0.0, 0.0, *every as f64],
        Err(_) => [1.0, 0.0, f64::from(signal), 0.0],
    };
    c.broadcast(0, &mut head);
    *every = head[3] as u64;
    if head[0] == 2.0 {
        return Ok(Inputs::NotYet);
    }
    if head[0] != 0.0 {
        return Ok(Inputs::Halt(Halt {
            message: match got {
                Err(msg) => format!("eprop serve: {msg}"),
                Ok(_) => String::new(),
            },
            signal: head[2] as i32,
        }));
    }
    let mut flat: Vec<f64> = match &got {
        Ok(Waited::Samples(samples)) => samples
            .iter()
            .flat_map(|(e, r)| [*e as f64, r[0], r[1], r[2], r[3]])
            .collect(),
        _ => Vec::new(),
    };
    flat.resize(5 * head[1] as usize, 0.0);
    c.broadcast(0, &mut flat);
    let samples: Vec<(u32, [f64; 4])> = flat
        .chunks_exact(5)
        .map(|s| (s[0] as u32, [s[1], s[2], s[3], s[4]]))
        .collect();
    sim.apply_live_samples(&samples)?;
    Ok(Inputs::Ready)
}

/// What `inputs` found.
enum Inputs {
    /// The samples the step needs are applied.
    Ready,
    /// None yet within the poll (nothing applied).
    NotYet,
    /// The session ended.
    Halt(Halt),
}

/// How long the server waits for the client's samples before it commits the written steps (or
/// `[output] flush`, if shorter): a pausing client leaves every computed step complete in the
/// file, and a client that keeps up costs no extra commit.
const IDLE: Duration = Duration::from_millis(100);

/// Each entity's result at the current step (every process calls: the loads' probes are
/// reductions).
fn outcomes(sim: &Simulation, any_live_load: bool) -> Vec<Outcome> {
    let mut out: Vec<Outcome> = sim
        .tool_states()
        .iter()
        .map(|t| Outcome {
            step: sim.step(),
            t: sim.time(),
            force: t.force,
            displacement: t.displacement,
        })
        .collect();
    let probes: Vec<(V3, V3)> = if any_live_load {
        sim.probes()
    } else {
        vec![([0.0; 3], [0.0; 3]); sim.loads().len()]
    };
    out.extend(probes.iter().map(|&(f, d)| Outcome {
        step: sim.step(),
        t: sim.time(),
        force: f,
        displacement: d,
    }));
    out
}

/// The feed of a served run: the client's samples before each step, the step's results to
/// the client after it (rank 0 holds the session; every process calls).
struct Live {
    session: Option<Session>,
    any_live_load: bool,
    /// The surface a streaming client gets (rank 0).
    surface: Option<Arc<protocol::Topology>>,
    /// Every how many steps the client wants a frame (0: no stream), as of the last inputs.
    every: u64,
    /// The surface nodes' owners, once a client streams.
    gather: Option<stream::Gather>,
    /// Per tool: where a live sphere's centre was last checked against the organ's inside
    /// (None: not yet, or not a live sphere), and whether it was found deep inside (said once).
    inside: Vec<(Option<V3>, bool)>,
    /// The end of the session an `idle` poll found, for the next `before_step`.
    halt: Option<Halt>,
}

impl Live {
    /// Warns once per live sphere whose centre a client moved inside the organ, deeper than
    /// its radius (every process calls; checked again only after it moved half a radius, so
    /// a still tool costs nothing).
    fn look_inside(&mut self, sim: &Simulation, t: f64) {
        for (k, run) in sim.tools().iter().enumerate() {
            let tool = &run.tool;
            let radius = tool.shape.radius();
            let (last, warned) = &mut self.inside[k];
            if !tool.live || *warned || !matches!(tool.shape, eprop::config::Shape::Sphere { .. }) {
                continue;
            }
            let c = tool.path.at(t);
            if last.is_some_and(|p| eprop_io::geom::norm(eprop_io::geom::sub(c, p)) < 0.5 * radius) {
                continue;
            }
            *last = Some(c);
            if let Some(depth) = crate::guard::plausible::sphere_deep_inside(sim, tool, c) {
                *warned = true;
                // a warning, not a progress line: said under -q too
                if sim.comm().rank() == 0 {
                    eprintln!(
                        "warning: tool {}: the client moved its centre inside the organ at t = {}, {} from the nearest surface node, deeper than its radius {}: the surface behind it counts as pressed by up to that depth, a large foundation force and source; fix: move it from outside onto the surface it should press",
                        k + 1,
                        eprop::diagnostics::short(t),
                        eprop::diagnostics::fixed(depth, 4),
                        eprop::diagnostics::short(radius)
                    );
                }
            }
        }
    }

    /// The inputs of time t, and the surface's owners once a client streams.
    fn inputs(&mut self, sim: &mut Simulation, t: f64) -> Result<Option<Halt>> {
        if let Some(h) = self.halt.take() {
            return Ok(Some(h));
        }
        let halt = match inputs(sim, self.session.as_mut(), t, &mut self.every, None)? {
            Inputs::Halt(h) => Some(h),
            _ => None,
        };
        self.gather_once(sim)?;
        Ok(halt)
    }

    fn gather_once(&mut self, sim: &Simulation) -> Result<()> {
        if self.every > 0 && self.gather.is_none() {
            let nodes = self.surface.as_ref().map(|s| s.nodes.as_slice());
            self.gather = Some(stream::Gather::new(sim, nodes)?);
        }
        Ok(())
    }
}

impl Feed for Live {
    fn start(&mut self, sim: &mut Simulation) -> Result<Option<Halt>> {
        let start = sim.time();
        let halt = self.inputs(sim, start)?;
        if halt.is_none() {
            sim.tools_at_rest();
        }
        Ok(halt)
    }

    fn idle(&mut self, sim: &mut Simulation) -> Result<bool> {
        if self.halt.is_some() {
            return Ok(false);
        }
        let t_next = (sim.step() + 1) as f64 * sim.dt();
        let flush = Duration::from_secs_f64(sim.setup().output.flush.clamp(0.0, 1e9));
        let poll = Some(IDLE.min(flush));
        Ok(
            match inputs(sim, self.session.as_mut(), t_next, &mut self.every, poll)? {
                Inputs::NotYet => true,
                Inputs::Ready => {
                    self.gather_once(sim)?;
                    false
                }
                Inputs::Halt(h) => {
                    self.halt = Some(h);
                    false
                }
            },
        )
    }

    fn before_step(&mut self, sim: &mut Simulation) -> Result<Option<Halt>> {
        let t_next = (sim.step() + 1) as f64 * sim.dt();
        if let Some(h) = self.inputs(sim, t_next)? {
            return Ok(Some(h));
        }
        self.look_inside(sim, t_next);
        let now = sim.time();
        sim.forget_live_before(now);
        Ok(None)
    }

    fn after_step(&mut self, sim: &Simulation) {
        let o = outcomes(sim, self.any_live_load);
        let frame = match &self.gather {
            Some(g) if self.every > 0 && sim.step().is_multiple_of(self.every) => g.collect(sim),
            _ => None,
        };
        if let Some(s) = &self.session {
            s.publish(
                &o,
                frame.map(|u| Frame {
                    step: sim.step(),
                    t: sim.time(),
                    u,
                }),
            );
        }
    }

    fn failed(&mut self, why: &str) {
        if let Some(s) = &self.session {
            s.fail(why);
        }
    }
}

/// Checks the run as `eprop run` does, then says where it listens and serves the client
/// while the shared time loop (`drive`) steps the simulation.
fn serve_simulation(
    mut sim: Simulation,
    settings: &Settings,
    listener: Option<TcpListener>,
    opts: &ServeOptions,
) -> Result<Option<ServeReport>> {
    // every refusal comes before the listening line
    let checked = drive::check(&sim, settings)?;
    let ents = entities(&sim);
    let any_live_load = ents.live[ents.tools..].iter().any(|&b| b);
    // live inputs start empty: the client's samples are their history
    sim.start_live_inputs();
    let mask = |from: usize, to: usize| {
        (from..to)
            .filter(|&e| ents.live[e])
            .fold(0u32, |m, e| m | 1 << (e - from))
    };
    let hello = Hello {
        version: protocol::VERSION_1,
        tools: ents.tools as u32,
        loads: (ents.live.len() - ents.tools) as u32,
        live_tools: mask(0, ents.tools),
        live_loads: mask(ents.tools, ents.live.len()),
        dt: sim.dt(),
        t0: sim.time(),
        timeout: opts.timeout,
        max_steps: sim.max_steps(),
        surface_nodes: 0,
        surface_triangles: 0,
    };
    // what a streaming client gets: the surface of the whole mesh (rank 0)
    let surface = match &listener {
        Some(_) => {
            let at = Instant::now();
            let s = stream::topology(&sim).map(Arc::new);
            if let Some(s) = &s {
                tracing::info!(
                    "the surface a streaming client gets: {} nodes, {} triangles ({:.3} s)",
                    s.nodes.len(),
                    s.triangles.len(),
                    at.elapsed().as_secs_f64()
                );
            }
            s
        }
        None => None,
    };
    let timeout = Duration::from_secs_f64(opts.timeout);
    let session = match listener {
        Some(l) => {
            announce(&l, &opts.listen);
            Some(
                Session::start(l, ents.clone(), hello, surface.clone(), timeout, settings.stop.clone())
                    .map_err(|e| anyhow!("eprop serve: cannot start the network thread: {e}"))?,
            )
        }
        None => None,
    };
    let mut feed = Live {
        session,
        any_live_load,
        surface,
        every: 0,
        gather: None,
        inside: vec![(None, false); sim.tools().len()],
        halt: None,
    };
    let summary = drive::drive(sim, &mut feed, settings, checked)?;
    let session = feed.session.map(Session::finish);
    Ok(summary
        .zip(session)
        .map(|(summary, session)| ServeReport { summary, session }))
}
