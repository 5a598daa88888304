//! The client side of `eprop serve` on rank 0: a network thread that owns the socket, takes
//! one client, answers every message at once from the latest physics results (extrapolated
//! linearly in time) and queues the samples for the physics; and the state it shares with
//! the main thread, which waits for the samples each step needs and publishes each step's
//! results. The network thread never calls MPI.

use super::protocol::{self as p, Code, Hello, Message, Stream, Topology, CLIENT_SIZE};
use eprop::linalg::V3;
use eprop::simulate::StopToken;
use serde::Serialize;
use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How often the network thread looks at the listener and the run while the client is quiet.
const TICK: Duration = Duration::from_millis(5);

/// An answer not sent within this time is stuck: the client does not read.
const STUCK: Duration = Duration::from_millis(100);
/// Steps the physics may lag behind the client's latest sample before it is said to fall
/// behind (a client a step or two ahead is the normal state of a live session).
pub const BEHIND: f64 = 10.0;
/// The window of the lag as it happens: once per window whose worst lag passed `BEHIND`
/// steps, serve prints a `lag` line on stderr.
pub const LAG_WINDOW: Duration = Duration::from_secs(1);

/// What a client that sends without reading its answers is told.
const NOT_READING: &str = "the client does not read its answers: the server could not send one";

/// The tools and loads of the run, tools first: entity k < tools is tool k, entity
/// tools + l is load l.
#[derive(Clone, Debug)]
pub struct Entities {
    pub tools: usize,
    pub live: Vec<bool>,
}

impl Entities {
    pub fn name(&self, e: usize) -> String {
        if e < self.tools {
            format!("tool {e}")
        } else {
            format!("load {}", e - self.tools)
        }
    }
}

/// A physics result of one tool or load.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Outcome {
    pub step: u64,
    pub t: f64,
    pub force: V3,
    pub displacement: V3,
}

impl Outcome {
    /// The answer that ends a session (`kind`: end of run or bye) with this last result.
    fn final_answer(&self, kind: u32) -> p::Answer {
        p::Answer {
            kind,
            index: 0,
            flags: 0,
            step: self.step,
            t_step: self.t,
            t: self.t,
            force: self.force,
            displacement: self.displacement,
        }
    }
}

/// Where the session is.
#[derive(Clone, Debug, PartialEq)]
enum Phase {
    /// No client yet.
    Waiting,
    Connected,
    /// The client said bye: the inputs hold their last samples.
    Bye,
    /// The session ended in an error (the client's or the run's), with the code the client
    /// gets.
    Failed(Code, String),
    /// The run reached its end.
    Finished,
}

struct State {
    phase: Phase,
    /// Samples not yet taken by the physics: (entity, [t, x, y, z]).
    pending: Vec<(u32, [f64; 4])>,
    /// Time of each entity's last sample.
    latest: Vec<f64>,
    /// Each entity's last two results (older, newer).
    results: Vec<(Option<Outcome>, Outcome)>,
    client: Option<String>,
    messages: u64,
    answers: u64,
    /// Why the session ended, once it has.
    ended: Option<String>,
    /// Since when the network thread has been sending an answer (None: it is not sending).
    /// A send that does not finish means the client does not read: meanwhile the thread
    /// reads none of the client's samples.
    sending: Option<Instant>,
    /// The surface stream the client asked for (version 2), while it is connected.
    stream: Option<Stream>,
    /// The latest frame published (a step that is a multiple of the stream's every).
    frame: Option<Arc<Frame>>,
}

/// The surface nodes' displacements at one physics step (3 per node, the topology's order).
#[derive(Debug)]
pub struct Frame {
    pub step: u64,
    pub t: f64,
    pub u: Vec<f64>,
}

type Shared = Arc<(Mutex<State>, Condvar)>;

fn lock(s: &Shared) -> MutexGuard<'_, State> {
    s.0.lock().unwrap_or_else(|e| e.into_inner())
}

/// What the session did, for the summary.
#[derive(Serialize, Debug, Clone, Default)]
pub struct SessionSummary {
    pub listen: String,
    pub client: Option<String>,
    pub messages: u64,
    pub answers: u64,
    /// "bye", "run over", or the error that ended it.
    pub ended: String,
    /// Seconds the physics waited for the client's samples.
    pub waited_seconds: f64,
    /// The most steps the physics lagged behind the client's latest sample when it took a
    /// step's samples (more than BEHIND: the physics is slower than the client).
    pub max_behind_steps: f64,
    /// Said when the physics fell behind the client, with the fix.
    pub warning: Option<String>,
    /// How many `lag` lines serve printed (one per second in which it lagged more than
    /// BEHIND steps).
    pub lag_reports: u64,
}

/// The network thread and the state it shares with the physics.
pub struct Session {
    shared: Shared,
    thread: Option<JoinHandle<()>>,
    ents: Entities,
    timeout: Duration,
    listen: String,
    waited: Duration,
    /// The step dt, and the most the client's latest sample was ahead of a step's time.
    dt: f64,
    behind: f64,
    warned: bool,
    /// The lag as it happens: the worst lead over the current window of `LAG_WINDOW`, when
    /// the window started, and the lag lines printed.
    window_worst: f64,
    window_start: Instant,
    lag_reports: u64,
    /// Every how many steps the client wants a frame (0: none), as of the last `wait`.
    every: u64,
    /// The command's stop (a signal), looked at while waiting for the client.
    stop: StopToken,
    /// When the wait for the current step's samples began (a wait cut short by `poll` goes on
    /// from there: the timeout counts from the first).
    since: Option<Instant>,
}

/// What a wait gave: the samples that arrived, or none yet within its poll.
pub enum Waited {
    Samples(Vec<(u32, [f64; 4])>),
    NotYet,
}

impl Session {
    /// Starts the network thread on a bound listener; `surface` is what a streaming client
    /// gets (None: the mesh has none).
    pub fn start(
        listener: TcpListener,
        ents: Entities,
        hello: Hello,
        surface: Option<Arc<Topology>>,
        timeout: Duration,
        stop: StopToken,
    ) -> std::io::Result<Session> {
        listener.set_nonblocking(true)?;
        let listen = listener.local_addr()?.to_string();
        let n = ents.live.len();
        let shared: Shared = Arc::new((
            Mutex::new(State {
                phase: Phase::Waiting,
                pending: Vec::new(),
                latest: vec![f64::NEG_INFINITY; n],
                results: vec![
                    (
                        None,
                        Outcome {
                            t: hello.t0,
                            ..Outcome::default()
                        }
                    );
                    n
                ],
                client: None,
                messages: 0,
                answers: 0,
                ended: None,
                sending: None,
                stream: None,
                frame: None,
            }),
            Condvar::new(),
        ));
        let (s, e) = (shared.clone(), ents.clone());
        let dt = hello.dt;
        let thread = std::thread::Builder::new()
            .name("eprop-serve".into())
            .spawn(move || network(listener, s, e, hello, surface, timeout))?;
        Ok(Session {
            shared,
            thread: Some(thread),
            ents,
            timeout,
            listen,
            dt,
            behind: 0.0,
            warned: false,
            window_worst: 0.0,
            window_start: Instant::now(),
            lag_reports: 0,
            every: 0,
            waited: Duration::ZERO,
            stop,
            since: None,
        })
    }

    /// Waits until every live entity has a sample at or beyond time t (or the client said
    /// bye) and takes the samples that arrived; an error when the session failed or the
    /// client did not deliver within the timeout. With `poll`, gives up after that long
    /// (`Waited::NotYet`); the next wait goes on with the same timeout.
    pub fn wait(&mut self, t: f64, poll: Option<Duration>) -> Result<Waited, String> {
        let called = Instant::now();
        let start = *self.since.get_or_insert(called);
        let cv = &self.shared.1;
        let mut g = lock(&self.shared);
        let out = loop {
            match &g.phase {
                Phase::Failed(_, msg) => break Err(msg.clone()),
                Phase::Finished => break Err("internal: the session is over".into()),
                _ => {}
            }
            let missing = (0..self.ents.live.len()).find(|&e| self.ents.live[e] && !(g.latest[e] >= t));
            match missing {
                None => break Ok(Waited::Samples(std::mem::take(&mut g.pending))),
                // after bye every live input holds its last sample (a bye before any sample
                // of one ended the session instead: `serve_client`)
                Some(_) if g.phase == Phase::Bye => break Ok(Waited::Samples(std::mem::take(&mut g.pending))),
                Some(_) if poll.is_some_and(|p| called.elapsed() >= p) => break Ok(Waited::NotYet),
                Some(e) => {
                    let left = self.timeout.saturating_sub(start.elapsed());
                    if left.is_zero() {
                        let unread = g.sending.filter(|&since| since <= start || since.elapsed() >= STUCK);
                        let msg = if let Some(since) = unread {
                            format!(
                                "{} (for {:.1} s), so it read none of the samples sent since; the next step needs one of {} at or beyond t = {}; fix: read the answer to every message",
                                NOT_READING,
                                since.elapsed().as_secs_f64(),
                                self.ents.name(e),
                                eprop::diagnostics::short(t)
                            )
                        } else if g.phase == Phase::Waiting {
                            format!(
                                "no client connected within {} s; fix: start the client or raise --timeout",
                                self.timeout.as_secs_f64()
                            )
                        } else {
                            format!(
                                "the client sent no sample of {} at or beyond t = {} within {} s (stalled); fix: keep sending, say bye, or raise --timeout",
                                self.ents.name(e),
                                eprop::diagnostics::short(t),
                                self.timeout.as_secs_f64()
                            )
                        };
                        fail(&mut g, Code::Timeout, &msg);
                        cv.notify_all();
                        break Err(msg);
                    }
                    let sig = self.stop.requested();
                    if sig != 0 {
                        let msg = format!(
                            "stopped by {} while waiting for the client's samples at t = {}",
                            crate::guard::signals::name(sig),
                            eprop::diagnostics::short(t)
                        );
                        fail(&mut g, Code::Server, &msg);
                        cv.notify_all();
                        break Err(msg);
                    }
                    // in slices, so that a stop signal is seen while the client is quiet
                    let slice = match poll {
                        Some(p) => left
                            .min(Duration::from_millis(100))
                            .min(p.saturating_sub(called.elapsed())),
                        None => left.min(Duration::from_millis(100)),
                    };
                    g = cv.wait_timeout(g, slice).unwrap_or_else(|e| e.into_inner()).0;
                }
            }
        };
        self.every = match (&g.phase, g.stream) {
            (Phase::Connected, Some(s)) => u64::from(s.every),
            _ => 0,
        };
        // how far the client is ahead of this step: the physics falls behind when the lead grows
        let lead = (0..self.ents.live.len())
            .filter(|&e| self.ents.live[e] && g.latest[e].is_finite())
            .map(|e| g.latest[e] - t)
            .fold(0.0f64, f64::max);
        drop(g);
        self.waited += called.elapsed();
        if !matches!(out, Ok(Waited::NotYet)) {
            self.since = None;
        }
        if matches!(out, Ok(Waited::Samples(_))) && lead > self.behind {
            self.behind = lead;
            if !self.warned && self.dt > 0.0 && lead / self.dt > BEHIND {
                self.warned = true;
                eprintln!("warning: {}", self.behind_warning());
            }
        }
        if out.is_ok() {
            self.lag_as_it_happens(lead, t);
        }
        out
    }

    /// Keeps the worst lead of the current window and, once the window is over, prints its
    /// worst when it passed `BEHIND` steps (`lag_line`).
    fn lag_as_it_happens(&mut self, lead: f64, t: f64) {
        self.window_worst = self.window_worst.max(lead);
        if self.window_start.elapsed() < LAG_WINDOW {
            return;
        }
        if self.dt > 0.0 && self.window_worst / self.dt > BEHIND {
            self.lag_reports += 1;
            eprintln!("{}", lag_line(self.window_worst, self.dt, t));
        }
        (self.window_worst, self.window_start) = (0.0, Instant::now());
    }

    /// The warning when the physics falls behind the client.
    fn behind_warning(&self) -> String {
        format!(
            "the physics fell behind the client: when a step took its samples, the client's latest sample was up to {:.0} steps ({:.3e} s of simulated time) ahead, so the answers come from older steps than the client's time; fix: compute steps faster than the client sends them: a larger dt matched to the client's sample period (docs/protocol.md, \"Real-time settings\"), a coarser mesh, [model] integrator = \"implicit\" on a stiff mesh, or more processes",
            self.behind / self.dt,
            self.behind
        )
    }

    /// The results of a physics step, one per entity (those of non-live entities are kept
    /// but not asked for).
    /// With a frame of the surface when a streaming client wants this step's.
    pub fn publish(&self, outcomes: &[Outcome], frame: Option<Frame>) {
        let frame = frame.map(Arc::new);
        let mut g = lock(&self.shared);
        for (r, o) in g.results.iter_mut().zip(outcomes) {
            *r = (Some(r.1), *o);
        }
        let old = match frame {
            Some(f) => g.frame.replace(f),
            None => None,
        };
        // the frame replaced is freed after the lock
        drop(g);
        drop(old);
    }

    /// Every how many steps the client wants a frame of the surface (0: no stream, or the
    /// client is gone), as of the last `wait`.
    pub fn stream_every(&self) -> u64 {
        self.every
    }

    /// The stop signal the command received (0: none).
    pub fn stop_requested(&self) -> i32 {
        self.stop.requested()
    }

    /// Ends the session because the run failed (the client gets the error).
    pub fn fail(&self, msg: &str) {
        let mut g = lock(&self.shared);
        fail(&mut g, Code::Server, msg);
        self.shared.1.notify_all();
    }

    /// Ends the session at the end of the run and stops the network thread.
    pub fn finish(mut self) -> SessionSummary {
        {
            let mut g = lock(&self.shared);
            if !matches!(g.phase, Phase::Failed(..)) {
                g.phase = Phase::Finished;
            }
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let g = lock(&self.shared);
        SessionSummary {
            listen: self.listen.clone(),
            client: g.client.clone(),
            messages: g.messages,
            answers: g.answers,
            ended: g.ended.clone().unwrap_or_else(|| "no client".into()),
            waited_seconds: self.waited.as_secs_f64(),
            max_behind_steps: if self.dt > 0.0 { self.behind / self.dt } else { 0.0 },
            warning: self.warned.then(|| self.behind_warning()),
            lag_reports: self.lag_reports,
        }
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        if let Some(t) = self.thread.take() {
            {
                let mut g = lock(&self.shared);
                if !matches!(g.phase, Phase::Failed(..)) {
                    g.phase = Phase::Finished;
                }
            }
            let _ = t.join();
        }
    }
}

fn fail(g: &mut State, code: Code, msg: &str) {
    if !matches!(g.phase, Phase::Failed(..) | Phase::Finished) {
        g.phase = Phase::Failed(code, msg.to_string());
        g.ended.get_or_insert_with(|| format!("error: {msg}"));
    }
}

/// The answer to a message about entity `e` at client time `tc`: its latest result,
/// extrapolated linearly from its last two results to tc, at most `reach` physics intervals
/// ahead (1 in protocol versions 1 and 2, `LAG_REACH` in version 3), and its flags: whether it
/// reaches beyond one interval (the physics lags) and whether tc is beyond the reach.
fn extrapolate(results: &(Option<Outcome>, Outcome), tc: f64, reach: f64) -> (f64, V3, V3, u16) {
    let (prev, last) = results;
    match prev {
        Some(p) if last.t > p.t => {
            let span = last.t - p.t;
            let t = tc.clamp(last.t, last.t + reach * span);
            let a = (t - last.t) / span;
            let ext = |x: V3, y: V3| {
                [
                    y[0] + a * (y[0] - x[0]),
                    y[1] + a * (y[1] - x[1]),
                    y[2] + a * (y[2] - x[2]),
                ]
            };
            let mut flags = 0;
            if reach > 1.0 && a > 1.0 {
                flags |= p::flags::EXTRAPOLATED;
            }
            if reach > 1.0 && t < tc {
                flags |= p::flags::BEHIND;
            }
            (
                t,
                ext(p.force, last.force),
                ext(p.displacement, last.displacement),
                flags,
            )
        }
        _ => (last.t, last.force, last.displacement, 0),
    }
}

/// The line serve prints while the physics lags: the worst lead of the client over the last
/// second, in steps and seconds of simulated time, at the step's time t.
fn lag_line(worst: f64, dt: f64, t: f64) -> String {
    format!(
        "lag: the physics is up to {:.0} steps ({} s of simulated time) behind the client over the last second, at t = {}; answers are extrapolated (version 3 flags them)",
        worst / dt,
        eprop::diagnostics::short(worst),
        eprop::diagnostics::short(t)
    )
}

/// Writes one server message; false when the client is gone.
fn send(stream: &mut TcpStream, b: &[u8; p::SERVER_SIZE]) -> bool {
    stream.write_all(b).is_ok()
}

/// What ended a connection.
enum End {
    Bye,
    /// The run ended: send END.
    RunOver,
    /// An error: the code to send (None: the client is gone), the text.
    Error(Option<Code>, String),
}

/// The network thread: waits for a client, serves it, refuses any other.
fn network(
    listener: TcpListener,
    shared: Shared,
    ents: Entities,
    hello: Hello,
    surface: Option<Arc<Topology>>,
    timeout: Duration,
) {
    let stream = loop {
        match listener.accept() {
            Ok((s, _)) => break s,
            Err(e) if e.kind() == ErrorKind::WouldBlock || e.kind() == ErrorKind::Interrupted => {
                let g = lock(&shared);
                if matches!(g.phase, Phase::Failed(..) | Phase::Finished) {
                    return;
                }
                drop(g);
                std::thread::sleep(TICK);
            }
            Err(e) => {
                let mut g = lock(&shared);
                fail(&mut g, Code::Server, &format!("the listening socket failed: {e}"));
                shared.1.notify_all();
                return;
            }
        }
    };
    let peer = stream.peer_addr().map(|a| a.to_string()).unwrap_or_else(|_| "?".into());
    {
        let mut g = lock(&shared);
        if g.phase == Phase::Waiting {
            g.phase = Phase::Connected;
        }
        g.client = Some(peer);
    }
    let mut stream = stream;
    let end = serve_client(
        &mut stream,
        &listener,
        &shared,
        &ents,
        &hello,
        surface.as_deref(),
        timeout,
    );
    let mut g = lock(&shared);
    match end {
        End::Bye => {
            if g.phase == Phase::Connected {
                g.phase = Phase::Bye;
            }
            g.ended.get_or_insert_with(|| "bye".into());
        }
        End::RunOver => {
            g.ended.get_or_insert_with(|| "run over".into());
            let (_, last) = first_live(&g, &ents);
            let a = last.final_answer(p::answer::END);
            drop(g);
            send(&mut stream, &p::answer(&a));
            g = lock(&shared);
        }
        End::Error(code, msg) => {
            fail(&mut g, code.unwrap_or(Code::Server), &msg);
            if let Some(code) = code {
                drop(g);
                send(&mut stream, &p::error(code, &msg));
                g = lock(&shared);
            }
        }
    }
    shared.1.notify_all();
    drop(g);
    let _ = stream.shutdown(std::net::Shutdown::Both);
}

fn first_live(g: &State, ents: &Entities) -> (usize, Outcome) {
    let e = ents.live.iter().position(|&b| b).unwrap_or(0);
    (e, g.results.get(e).map(|r| r.1).unwrap_or_default())
}

/// Refuses a second client, if one is knocking.
fn refuse_others(listener: &TcpListener) {
    while let Ok((mut s, _)) = listener.accept() {
        let _ = s.set_nonblocking(false);
        let _ = s.set_write_timeout(Some(Duration::from_secs(1)));
        let _ = s.write_all(&p::error(
            Code::Busy,
            "another client holds the session; a server takes one client per run",
        ));
        let _ = s.shutdown(std::net::Shutdown::Both);
    }
}

/// Reads exactly one client message, looking at the run and the listener while waiting.
/// Ok(None): the run ended or failed meanwhile.
fn read_one(
    stream: &mut TcpStream,
    listener: &TcpListener,
    shared: &Shared,
    last_look: &mut Instant,
) -> Result<Option<[u8; CLIENT_SIZE]>, End> {
    let mut buf = [0u8; CLIENT_SIZE];
    Ok(read_into(stream, listener, shared, last_look, &mut buf, 0)?.map(|_| buf))
}

/// Fills `buf[have..]`, as `read_one`.
fn read_into(
    stream: &mut TcpStream,
    listener: &TcpListener,
    shared: &Shared,
    last_look: &mut Instant,
    buf: &mut [u8],
    mut have: usize,
) -> Result<Option<()>, End> {
    loop {
        if last_look.elapsed() >= TICK {
            *last_look = Instant::now();
            refuse_others(listener);
            let g = lock(shared);
            match &g.phase {
                Phase::Finished => return Ok(None),
                Phase::Failed(code, msg) => return Err(End::Error(Some(*code), msg.clone())),
                _ => {}
            }
        }
        match stream.read(&mut buf[have..]) {
            Ok(0) if have == 0 => return Err(End::Error(None, "the client closed the connection without bye".into())),
            Ok(0) => {
                return Err(End::Error(
                    None,
                    format!(
                        "the client closed the connection in the middle of a message ({have} of {CLIENT_SIZE} bytes)"
                    ),
                ))
            }
            Ok(n) => {
                have += n;
                if have == buf.len() {
                    return Ok(Some(()));
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                ) => {}
            Err(e) => return Err(End::Error(None, format!("the connection failed: {e}"))),
        }
    }
}

/// What a send that failed means.
fn send_failed(e: std::io::Error, timeout: Duration) -> End {
    let msg = match e.kind() {
        ErrorKind::WouldBlock | ErrorKind::TimedOut => format!(
            "{NOT_READING} within {} s; fix: read the answer to every message",
            timeout.as_secs_f64()
        ),
        _ => format!("the client left while the server sent an answer ({e})"),
    };
    End::Error(None, msg)
}

/// The client's hello, its magic read first so that another protocol is refused at once.
fn read_opening(
    stream: &mut TcpStream,
    listener: &TcpListener,
    shared: &Shared,
    last_look: &mut Instant,
) -> Result<p::Opening, End> {
    let mut first = [0u8; CLIENT_SIZE];
    let mut opening = None;
    for (from, to) in [(0, 8), (8, CLIENT_SIZE)] {
        match read_into(stream, listener, shared, last_look, &mut first[..to], from) {
            Ok(Some(())) => {}
            Ok(None) => return Err(End::RunOver),
            Err(e) => return Err(e),
        }
        match p::read_hello(&first) {
            Ok(o) => opening = Some(o),
            Err((code, msg)) if to == CLIENT_SIZE || code == Code::NotEprop => return Err(End::Error(Some(code), msg)),
            Err(_) => {}
        }
    }
    let Some(opening) = opening else {
        return Err(End::Error(Some(Code::NotEprop), "internal: no hello read".into()));
    };
    Ok(opening)
}

/// A bye: the run told to end, and the client its last answer (or why the run cannot end).
fn say_bye(stream: &mut TcpStream, shared: &Shared, ents: &Entities) -> End {
    let cv = &shared.1;
    let mut g = lock(shared);
    g.messages += 1;
    // an input without any sample has no value to hold: the run cannot go on,
    // and the client hears so instead of a bye answer
    if let Some(e) = (0..ents.live.len()).find(|&e| ents.live[e] && g.latest[e] == f64::NEG_INFINITY) {
        drop(g);
        return End::Error(
            Some(Code::Server),
            format!(
                "bye before any sample of {}: the run has no input for it; fix: send a sample of every live tool and load before bye",
                ents.name(e)
            ),
        );
    }
    if g.phase == Phase::Connected {
        g.phase = Phase::Bye;
    }
    g.ended = Some("bye".into());
    let (_, last) = first_live(&g, ents);
    g.answers += 1;
    cv.notify_all();
    drop(g);
    let a = last.final_answer(p::answer::BYE);
    send(stream, &p::answer(&a));
    End::Bye
}

/// The entity of a pose of tool `index` at `t`: a live tool, its position within reach.
fn live_tool(ents: &Entities, index: u32, t: f64, position: &[f64; 3]) -> Result<usize, End> {
    let e = index as usize;
    if e >= ents.tools || !ents.live[e] {
        return Err(End::Error(
            Some(Code::Index),
            format!("no live tool {index} (the hello's live_tools mask lists them)"),
        ));
    }
    if let Some(x) = position.iter().find(|x| !(x.abs() <= eprop::config::REACH)) {
        return Err(End::Error(
            Some(Code::Sample),
            format!(
                "the position of tool {index} at t = {} has the component {}, beyond +-{}, {}; fix: {}",
                eprop::diagnostics::short(t),
                eprop::diagnostics::short(*x),
                eprop::diagnostics::short(eprop::config::REACH),
                eprop::config::REACH_WHY,
                eprop::config::REACH_FIX
            ),
        ));
    }
    Ok(e)
}

fn serve_client(
    stream: &mut TcpStream,
    listener: &TcpListener,
    shared: &Shared,
    ents: &Entities,
    hello: &Hello,
    surface: Option<&Topology>,
    timeout: Duration,
) -> End {
    let _ = stream.set_nodelay(true);
    let _ = stream.set_read_timeout(Some(TICK));
    let _ = stream.set_write_timeout(Some(timeout));
    let mut last_look = Instant::now();
    let opening = match read_opening(stream, listener, shared, &mut last_look) {
        Ok(o) => o,
        Err(e) => return e,
    };
    let stream_req = opening.stream;
    let reach = if opening.version >= p::VERSION_3 {
        p::LAG_REACH
    } else {
        1.0
    };
    let mut hello = Hello {
        version: opening.version,
        ..*hello
    };
    let mut topology = None;
    if let Some(s) = stream_req {
        let Some(t) = surface.filter(|t| !t.triangles.is_empty()) else {
            return End::Error(
                Some(Code::Stream),
                "the mesh has no outer surface to stream; fix: ask for no stream".into(),
            );
        };
        hello.surface_nodes = t.nodes.len() as u32;
        hello.surface_triangles = t.triangles.len() as u32;
        topology = Some(p::topology(t, s));
        // before the hello: the physics learns of the stream with the first samples
        lock(shared).stream = Some(s);
    }
    if !send(stream, &p::server_hello(&hello)) {
        return End::Error(None, "the client left after its hello".into());
    }
    if let Some(t) = topology {
        if let Err(e) = stream.write_all(&t) {
            return send_failed(e, timeout);
        }
    }
    let mut frame_sent: Option<u64> = None;
    let cv = &shared.1;
    loop {
        let b = match read_one(stream, listener, shared, &mut last_look) {
            Ok(Some(b)) => b,
            Ok(None) => return End::RunOver,
            Err(e) => return e,
        };
        let msg = match p::read_message(&b) {
            Ok(m) => m,
            Err((code, text)) => return End::Error(Some(code), text),
        };
        let (e, kind, index, t, v) = match msg {
            Message::Bye => return say_bye(stream, shared, ents),
            Message::Pose { index, t, position } => match live_tool(ents, index, t, &position) {
                Ok(e) => (e, p::answer::TOOL, index, t, position),
                Err(end) => return end,
            },
            Message::Force { index, t, force } => {
                let e = ents.tools + index as usize;
                if e >= ents.live.len() || !ents.live[e] {
                    return End::Error(
                        Some(Code::Index),
                        format!("no live load {index} (the hello's live_loads mask lists them)"),
                    );
                }
                (e, p::answer::LOAD, index, t, force)
            }
        };
        let mut g = lock(shared);
        g.messages += 1;
        if !(t > g.latest[e]) {
            let last = g.latest[e];
            drop(g);
            return End::Error(
                Some(Code::Sample),
                format!(
                    "time {} of {} is not after its last sample's {}",
                    eprop::diagnostics::short(t),
                    ents.name(e),
                    eprop::diagnostics::short(last)
                ),
            );
        }
        g.latest[e] = t;
        g.pending.push((e as u32, [t, v[0], v[1], v[2]]));
        let (te, force, displacement, flags) = extrapolate(&g.results[e], t, reach);
        let last = g.results[e].1;
        g.answers += 1;
        g.sending = Some(Instant::now());
        // the latest frame, if the client streams and has not had it
        let frame = match (stream_req, &g.frame) {
            (Some(s), Some(f)) if frame_sent.is_none_or(|k| f.step > k) => Some((s, f.clone())),
            _ => None,
        };
        drop(g);
        cv.notify_all();
        let a = p::Answer {
            kind,
            index,
            flags,
            step: last.step,
            t_step: last.t,
            t: te,
            force,
            displacement,
        };
        let mut sent = stream.write_all(&p::answer(&a));
        if let (Ok(()), Some((s, f))) = (&sent, frame) {
            frame_sent = Some(f.step);
            sent = stream.write_all(&p::frame(f.step, f.t, &f.u, s.width));
        }
        lock(shared).sending = None;
        if let Err(e) = sent {
            return send_failed(e, timeout);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_extrapolate_linearly_at_most_one_step_ahead() {
        let o = |step: u64, t: f64, f: f64| Outcome {
            step,
            t,
            force: [0.0, 0.0, f],
            displacement: [f / 10.0, 0.0, 0.0],
        };
        // one result: as it is
        assert_eq!(
            extrapolate(&(None, o(0, 0.0, 1.0)), 0.5, 1.0),
            (0.0, [0.0, 0.0, 1.0], [0.1, 0.0, 0.0], 0)
        );
        let r = (Some(o(3, 0.3, 1.0)), o(4, 0.4, 2.0));
        let (t, f, d, flags) = extrapolate(&r, 0.45, 1.0);
        assert_eq!((t, flags), (0.45, 0));
        assert!((f[2] - 2.5).abs() < 1e-12 && (d[0] - 0.25).abs() < 1e-12, "{f:?} {d:?}");
        // never further than one interval, never back in time
        assert_eq!(extrapolate(&r, 9.0, 1.0).0, 0.5);
        assert!((extrapolate(&r, 9.0, 1.0).1[2] - 3.0).abs() < 1e-12);
        assert_eq!(extrapolate(&r, 0.1, 1.0), (0.4, [0.0, 0.0, 2.0], [0.2, 0.0, 0.0], 0));
        assert_eq!(extrapolate(&r, 9.0, 1.0).3, 0);
    }

    #[test]
    fn a_lagging_physics_is_extrapolated_further_and_flagged_in_version_3() {
        let o = |step: u64, t: f64, f: f64| Outcome {
            step,
            t,
            force: [0.0, 0.0, f],
            displacement: [0.0; 3],
        };
        let r = (Some(o(3, 0.3, 1.0)), o(4, 0.4, 2.0));
        let reach = p::LAG_REACH;
        // within one step: as in versions 1 and 2, no flag
        assert_eq!(extrapolate(&r, 0.45, reach).3, 0);
        // three steps behind: extrapolated to the client's time, flagged
        let (t, f, _, flags) = extrapolate(&r, 0.7, reach);
        assert!((t - 0.7).abs() < 1e-12 && (f[2] - 5.0).abs() < 1e-9, "{t} {f:?}");
        assert_eq!(flags, p::flags::EXTRAPOLATED);
        // beyond the reach: stops there, and says the answer is still behind
        let (t, f, _, flags) = extrapolate(&r, 9.0, reach);
        assert!((t - 1.4).abs() < 1e-12 && (f[2] - 12.0).abs() < 1e-9, "{t} {f:?}");
        assert_eq!(flags, p::flags::EXTRAPOLATED | p::flags::BEHIND);
        // the flags travel in bytes 6..8 and leave the index as it was
        let a = p::Answer {
            kind: p::answer::TOOL,
            index: 7,
            flags,
            step: 4,
            t_step: 0.4,
            t,
            force: f,
            displacement: [0.0; 3],
        };
        let b = p::answer(&a);
        assert_eq!(u16::from_le_bytes([b[4], b[5]]), 7);
        assert_eq!(u16::from_le_bytes([b[6], b[7]]), 3);
        assert_eq!(p::read_reply(&b), p::Reply::Answer(a));
    }
}
