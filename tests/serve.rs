//! `eprop serve` over loopback: a live session that sends a trajectory writes the same series,
//! bit for bit, as the trajectory run in batch from a table (one process and mpirun -n 2);
//! every bad message, a second client, a stall and a vanished client get their error, the
//! server exits cleanly and its series stays readable. Every server runs under a deadline.

mod common;

use eprop::protocol::{self as p, Reply};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{channel, Receiver};
use std::time::{Duration, Instant};

/// A running `eprop serve` (or `mpirun ... eprop serve`).
struct Server {
    child: Child,
    addr: String,
    lines: Receiver<String>,
    stderr: Vec<String>,
}

fn eprop_cmd(ranks: usize) -> Command {
    if ranks == 1 {
        let mut c = Command::new(env!("CARGO_BIN_EXE_eprop"));
        c.env("RAYON_NUM_THREADS", "1");
        c
    } else {
        let mut c = Command::new("mpirun");
        c.args(["-n", &ranks.to_string(), "--oversubscribe"])
            .arg(env!("CARGO_BIN_EXE_eprop"))
            .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
            .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
            .env("OMPI_MCA_rmaps_base_oversubscribe", "1")
            .env("RAYON_NUM_THREADS", "1");
        c
    }
}

fn serve(ranks: usize, scenario: &Path, out: &Path, extra: &[&str]) -> Server {
    let mut child = eprop_cmd(ranks)
        .args([
            "serve",
            scenario.to_str().unwrap(),
            "--listen",
            "127.0.0.1:0",
            "-q",
            // the sessions of a test write one file in turn
            "--overwrite",
            "-o",
        ])
        .arg(out)
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let err = child.stderr.take().unwrap();
    let (tx, lines) = channel();
    std::thread::spawn(move || {
        for l in BufReader::new(err).lines().map_while(Result::ok) {
            if tx.send(l).is_err() {
                break;
            }
        }
    });
    let mut stderr = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(120);
    let addr = loop {
        let l = lines
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .unwrap_or_else(|_| {
                let _ = child.kill();
                panic!("no `listening on` line; stderr: {stderr:?}")
            });
        if let Some(a) = l.strip_prefix("eprop serve: listening on ") {
            break a.trim().to_string();
        }
        stderr.push(l);
    };
    Server {
        child,
        addr,
        lines,
        stderr,
    }
}

impl Server {
    /// Waits for the server to exit (killing it and failing past the deadline); returns its
    /// success, stdout and stderr.
    fn finish(self, seconds: u64) -> (bool, String, String) {
        let (status, out, err) = self.wait_all(seconds);
        (status.success(), out, err)
    }

    /// The exit code and the stderr of the server.
    fn finish_status(self, seconds: u64) -> (Option<i32>, String) {
        let (status, _, err) = self.wait_all(seconds);
        (status.code(), err)
    }

    fn wait_all(mut self, seconds: u64) -> (std::process::ExitStatus, String, String) {
        let deadline = Instant::now() + Duration::from_secs(seconds);
        let status = loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                break s;
            }
            if Instant::now() > deadline {
                let _ = self.child.kill();
                let _ = self.child.wait();
                panic!("the server did not exit within {seconds} s; stderr: {:?}", self.stderr);
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let mut out = String::new();
        self.child.stdout.take().unwrap().read_to_string(&mut out).unwrap();
        while let Ok(l) = self.lines.recv_timeout(Duration::from_millis(500)) {
            self.stderr.push(l);
        }
        (status, out, self.stderr.join("\n"))
    }
}

struct Client {
    s: TcpStream,
    /// The topologies and frames (version 2, streaming) read on the way to the replies.
    payloads: Vec<(p::Header, Vec<u8>)>,
}

impl Client {
    fn connect(addr: &str) -> Client {
        let s = TcpStream::connect(addr).unwrap();
        s.set_nodelay(true).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
        Client {
            s,
            payloads: Vec::new(),
        }
    }

    fn raw(&mut self, b: &[u8]) {
        self.s.write_all(b).unwrap();
    }

    /// The next reply; a topology or frame on the way is kept in `payloads`.
    fn reply(&mut self) -> Reply {
        loop {
            let mut b = [0u8; p::SERVER_SIZE];
            self.s.read_exact(&mut b).unwrap();
            match p::read_reply(&b) {
                Reply::Payload(h) => {
                    let mut data = vec![0u8; h.bytes as usize];
                    self.s.read_exact(&mut data).unwrap();
                    self.payloads.push((h, data));
                }
                r => return r,
            }
        }
    }

    fn hello(&mut self) -> p::Hello {
        self.raw(&p::client_hello(p::VERSION_1));
        match self.reply() {
            Reply::Hello(h) => h,
            r => panic!("{r:?}"),
        }
    }

    fn send(&mut self, kind: u32, index: u32, t: f64, v: [f64; 3]) -> Reply {
        self.raw(&p::client_message(kind, index, t, v));
        self.reply()
    }

    fn answer(&mut self, kind: u32, index: u32, t: f64, v: [f64; 3]) -> p::Answer {
        match self.send(kind, index, t, v) {
            Reply::Answer(a) => a,
            r => panic!("{r:?}"),
        }
    }

    fn error(&mut self) -> (u32, String) {
        match self.reply() {
            Reply::Error { code, message } => (code, message),
            r => panic!("expected an error, got {r:?}"),
        }
    }
}

/// A small cylinder scenario in `dir` with a live sphere on a path table and a live patch
/// load on a force table; returns the scenario and the two tables' rows.
fn scenario(dir: &Path, extra: &str) -> (PathBuf, Vec<[f64; 4]>, Vec<[f64; 4]>) {
    eprop_io::write_mesh(
        &eprop_io::generate::cylinder_mesh(1.0, 4.0, 3, 11).unwrap(),
        &dir.join("cyl.msh"),
    )
    .unwrap();
    // a press and release at times that are not step times, finely sampled
    let path: Vec<[f64; 4]> = (0..=240)
        .map(|k| {
            let t = k as f64 * 0.25 + 0.0137;
            [
                t,
                1.55 - 0.32 * (std::f64::consts::PI * t / 60.0).sin().max(0.0),
                0.01 * t,
                2.0,
            ]
        })
        .collect();
    let force: Vec<[f64; 4]> = (0..=30)
        .map(|k| {
            let t = k as f64 * 1.7;
            [t, 0.0, -0.05 * (t / 10.0).min(1.0), 0.002 * k as f64]
        })
        .collect();
    let csv = |rows: &[[f64; 4]], head: &str| {
        let mut s = format!("{head}\n");
        for r in rows {
            s += &format!("{},{},{},{}\n", r[0], r[1], r[2], r[3]);
        }
        s
    };
    std::fs::write(dir.join("path.csv"), csv(&path, "t,x,y,z")).unwrap();
    std::fs::write(dir.join("force.csv"), csv(&force, "t,fx,fy,fz")).unwrap();
    let sc = dir.join("s.toml");
    // serve's default mode, said in the scenario so that `eprop run` of it is the same
    let realtime = if extra.contains("integrator =") {
        ""
    } else {
        "realtime = true\n"
    };
    std::fs::write(
        &sc,
        common::paper(&format!(
            "[mesh]\nfile = \"cyl.msh\"\n[[fixed]]\ngroup = \"bottom\"\n\
             [[load]]\npatch = {{ center = [0.0, 1.0, 3.0], radius = 0.4 }}\ntable = \"force.csv\"\nlive = true\n\
             [[tool]]\nshape = \"sphere\"\nradius = 0.5\ntable = \"path.csv\"\nlive = true\n{extra}\
             [time]\nend = 70\n{realtime}[output]\nevery = 3\n"
        )),
    )
    .unwrap();
    (sc, path, force)
}

/// A scenario of `scenario` out of the real-time mode (its integrator chosen by `auto`).
fn not_realtime(sc: &Path) {
    let text = std::fs::read_to_string(sc)
        .unwrap()
        .replace("realtime = true\n", "realtime = false\n");
    std::fs::write(sc, text).unwrap();
}

fn batch(sc: &Path, out: &Path) {
    let o = common::serial(&["run", sc.to_str().unwrap(), "-q", "-o", out.to_str().unwrap()], 1);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Sends both tables' rows in time order, in small bursts so that the physics runs between
/// them, checking every answer; then bye.
fn drive(c: &mut Client, path: &[[f64; 4]], force: &[[f64; 4]], dt: f64) {
    drive_paced(c, path, force, dt, 3);
}

/// `drive` with a pause of `pause_ms` after every 25 messages, doubled (up to 1 s) while the
/// physics did not advance since the previous pause (a loaded machine).
fn drive_paced(c: &mut Client, path: &[[f64; 4]], force: &[[f64; 4]], dt: f64, pause_ms: u64) {
    let mut all: Vec<(u32, [f64; 4])> = path.iter().map(|r| (p::kind::POSE, *r)).collect();
    all.extend(force.iter().map(|r| (p::kind::FORCE, *r)));
    all.sort_by(|a, b| a.1[0].total_cmp(&b.1[0]));
    let mut last_step = 0;
    let (mut pause, mut step_at_pause) = (pause_ms, u64::MAX);
    for (k, (kind, r)) in all.iter().enumerate() {
        let a = c.answer(*kind, 0, r[0], [r[1], r[2], r[3]]);
        assert_eq!(a.kind, if *kind == p::kind::POSE { 2 } else { 3 });
        // the physics never runs ahead of the samples; the answer is from a step at or
        // before the sample, extrapolated towards it by at most one step
        assert!(a.t_step <= r[0] + 1e-12 && a.step >= last_step, "{a:?} at {r:?}");
        assert!(a.t >= a.t_step && a.t <= a.t_step + dt * (1.0 + 1e-12), "{a:?}");
        assert!(a.force.iter().chain(&a.displacement).all(|x| x.is_finite()));
        last_step = a.step;
        if k % 25 == 0 {
            pause = if a.step == step_at_pause {
                (2 * pause).min(1000)
            } else {
                pause_ms
            };
            step_at_pause = a.step;
            std::thread::sleep(Duration::from_millis(pause));
        }
    }
    match c.send(p::kind::BYE, 0, 0.0, [0.0; 3]) {
        Reply::Answer(a) => assert_eq!(a.kind, p::answer::BYE),
        r => panic!("{r:?}"),
    }
}

fn live_equals_batch(ranks: usize, extra: &str) {
    let d = tempfile::tempdir().unwrap();
    let (sc, path, force) = scenario(d.path(), extra);
    let one = d.path().join("batch.h5");
    batch(&sc, &one);
    let live = d.path().join("live.h5");
    let server = serve(ranks, &sc, &live, &["--timeout", "30", "--json"]);
    let mut c = Client::connect(&server.addr);
    let h = c.hello();
    assert_eq!((h.tools, h.loads, h.live_tools, h.live_loads, h.t0), (1, 1, 1, 1, 0.0));
    drive(&mut c, &path, &force, h.dt);
    let (ok, out, err) = server.finish(120);
    assert!(ok, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(report["session"]["ended"], "bye");
    assert_eq!(report["session"]["messages"], (path.len() + force.len() + 1) as u64);
    assert_eq!(report["processes"], ranks as u64);
    assert!(report["tools"][0]["contact_nodes"].as_u64().is_some());
    common::assert_same(&one, &live);
    // the tool did press: contact, force into the organ, then let go
    let f = hdf5::File::open(&live).unwrap();
    let n = f
        .dataset("eprop/tools/contact_nodes")
        .unwrap()
        .read_raw::<i64>()
        .unwrap();
    let n = &n[..common::steps_complete(&live) as usize];
    assert!(n.iter().max().unwrap() >= &2 && *n.last().unwrap() == 0, "{n:?}");
}

#[test]
fn a_live_session_writes_the_batch_series_bit_for_bit() {
    live_equals_batch(1, "");
}

#[test]
fn a_live_session_under_mpirun_writes_the_batch_series_bit_for_bit() {
    live_equals_batch(2, "");
}

#[test]
fn a_live_session_writes_the_batch_series_with_rkl2_and_implicit() {
    live_equals_batch(1, "[model]\nreading = \"paper\"\nintegrator = \"implicit\"\n");
    live_equals_batch(2, "[model]\nreading = \"paper\"\nintegrator = \"rkl2\"\n");
}

/// A server on the scenario of `scenario` (with `extra` keys and options) and a client that
/// has said hello; for the catalogue of bad sessions.
/// Samples to t = 30 (force) and t = 10 (pose), then waits until the physics has caught up
/// with them (a step at t >= 9).
fn catch_up(c: &mut Client) {
    c.answer(p::kind::FORCE, 0, 30.0, [0.0, -0.05, 0.0]);
    c.answer(p::kind::POSE, 0, 10.0, [1.5, 0.0, 2.0]);
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut k = 0;
    loop {
        k += 1;
        let a = c.answer(p::kind::POSE, 0, 10.0 + k as f64 * 1e-6, [1.5, 0.0, 2.0]);
        if a.t_step >= 9.0 {
            break;
        }
        assert!(Instant::now() < deadline, "the physics does not advance: {a:?}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn a_client_moving_a_sphere_deep_inside_the_organ_is_warned_about_once() {
    let d = tempfile::tempdir().unwrap();
    let (sc, _, _) = scenario(d.path(), "");
    let out = d.path().join("live.h5");
    for ranks in [1, 2] {
        let server = serve(ranks, &sc, &out, &["--timeout", "20"]);
        let mut c = Client::connect(&server.addr);
        c.hello();
        catch_up(&mut c);
        // the cylinder's axis (radius 1) is 1 deep, the sphere's radius 0.5; then out again and in
        c.answer(p::kind::FORCE, 0, 40.0, [0.0, -0.05, 0.0]);
        for (k, x) in [0.0, 0.1, 1.6, 0.0].iter().enumerate() {
            c.answer(p::kind::POSE, 0, 11.0 + k as f64, [*x, 0.0, 2.0]);
        }
        // until the physics has passed t = 12.5 (steps of 5/6)
        let deadline = Instant::now() + Duration::from_secs(30);
        for k in 1.. {
            let a = c.answer(p::kind::POSE, 0, 14.0 + k as f64 * 1e-6, [0.0, 0.0, 2.0]);
            if a.t_step >= 12.5 {
                break;
            }
            assert!(Instant::now() < deadline, "the physics does not advance: {a:?}");
            std::thread::sleep(Duration::from_millis(1));
        }
        match c.send(p::kind::BYE, 0, 0.0, [0.0; 3]) {
            Reply::Answer(a) => assert_eq!(a.kind, p::answer::BYE),
            r => panic!("{r:?}"),
        }
        let (status, err) = server.finish_status(60);
        assert_eq!(status, Some(0), "{ranks} ranks: {err}");
        let warning = "tool 1: the client moved its centre inside the organ";
        assert_eq!(err.matches(warning).count(), 1, "{ranks} ranks, once: {err}");
        assert!(
            err.contains("deeper than its radius 0.5") && err.contains("fix: move it"),
            "{err}"
        );
    }
}

/// The series of a session that ended early: its complete steps read back, to step 12 or later.
fn holds_steps_to_12(out: &Path) {
    let k = common::steps_complete(out);
    let f = hdf5::File::open(out).unwrap();
    // the counted steps of the room made for the scenario's
    let room = f.dataset("eprop/tools/step").unwrap().read_raw::<i64>().unwrap();
    assert!(room.len() >= k as usize, "{} rows, {k} steps", room.len());
    let steps = &room[..k as usize];
    assert!(*steps.last().unwrap() >= 12, "{steps:?}");
}

fn session(d: &Path, extra: &str, args: &[&str]) -> (Server, Client) {
    let (sc, _, _) = scenario(d, extra);
    let server = serve(1, &sc, &d.join("live.h5"), args);
    let mut c = Client::connect(&server.addr);
    c.hello();
    (server, c)
}

#[test]
fn every_bad_message_gets_its_error_and_the_server_exits_cleanly() {
    let d = tempfile::tempdir().unwrap();
    let d = d.path();
    type Case = (&'static str, Box<dyn Fn(&mut Client)>, u32, &'static str);
    let cases: Vec<Case> = vec![
        (
            "unknown kind",
            Box::new(|c| c.raw(&p::client_message(9, 0, 0.0, [0.0; 3]))),
            4,
            "unknown message kind 9",
        ),
        (
            "no such tool",
            Box::new(|c| c.raw(&p::client_message(p::kind::POSE, 3, 0.0, [0.0; 3]))),
            5,
            "no live tool 3",
        ),
        (
            "a tool that is not live",
            Box::new(|c| c.raw(&p::client_message(p::kind::POSE, 1, 0.0, [0.0; 3]))),
            5,
            "no live tool 1",
        ),
        (
            "no such load",
            Box::new(|c| c.raw(&p::client_message(p::kind::FORCE, 1, 0.0, [0.0; 3]))),
            5,
            "no live load 1",
        ),
        (
            "not finite",
            Box::new(|c| c.raw(&p::client_message(p::kind::POSE, 0, 0.0, [0.0, f64::NAN, 0.0]))),
            6,
            "not finite",
        ),
        (
            // finite, but the contact's distances overflow (it gave an indentation of -inf)
            "a position beyond reach",
            Box::new(|c| c.raw(&p::client_message(p::kind::POSE, 0, 0.0, [1e200, 0.0, 2.0]))),
            6,
            "the position of tool 0 at t = 0 has the component 1e200",
        ),
        (
            "back in time",
            Box::new(|c| {
                c.answer(p::kind::POSE, 0, 1.0, [1.6, 0.0, 2.0]);
                c.raw(&p::client_message(p::kind::POSE, 0, 0.5, [1.6, 0.0, 2.0]));
            }),
            6,
            "time 0.5 of tool 0 is not after its last sample's 1",
        ),
        (
            "a repeated time",
            Box::new(|c| {
                c.answer(p::kind::FORCE, 0, 2.0, [0.0; 3]);
                c.raw(&p::client_message(p::kind::FORCE, 0, 2.0, [0.0; 3]));
            }),
            6,
            "time 2 of load 0 is not after",
        ),
        (
            "a stall",
            Box::new(|c| {
                // tool samples only: the load's never come
                c.answer(p::kind::POSE, 0, 5.0, [1.6, 0.0, 2.0]);
            }),
            7,
            "no sample of load 0 at or beyond t = 0 within 1 s",
        ),
    ];
    let extra = "[[tool]]\nshape = \"sphere\"\nradius = 0.1\nstart = [5, 5, 5]\n";
    for (what, act, code, text) in cases {
        let (server, mut c) = session(d, extra, &["--timeout", "1"]);
        act(&mut c);
        let (got, message) = c.error();
        assert_eq!(got, code, "{what}: {message}");
        assert!(message.contains(text), "{what}: {message}");
        let (ok, _, err) = server.finish(60);
        assert!(!ok, "{what}: the server should fail");
        assert!(
            err.contains("error: eprop serve:") && err.contains(text),
            "{what}: {err}"
        );
    }
}

#[test]
fn a_bad_hello_a_vanished_client_and_no_client_end_the_run_cleanly() {
    let d = tempfile::tempdir().unwrap();
    let d = d.path();
    let (sc, _, _) = scenario(d, "");
    let out = d.join("live.h5");
    // not eprop at all, then a version from the future
    for (hello, code, text) in [
        (
            b"GET / HTTP/1.1\r\nHost: x\r\n\r\n..........".to_vec(),
            1,
            "not an eprop client",
        ),
        (p::client_hello(4).to_vec(), 2, "protocol version 4 is not supported"),
        // malformed requests of the surface stream (version 2)
        (
            p::client_hello_stream(p::Stream { every: 0, width: 4 }).to_vec(),
            9,
            "stream every 0 steps",
        ),
        (
            p::client_hello_stream(p::Stream { every: 1, width: 2 }).to_vec(),
            9,
            "stream value width 2",
        ),
        (
            {
                let mut b = p::client_hello_stream(p::Stream { every: 1, width: 4 });
                b[12] = 5;
                b.to_vec()
            },
            9,
            "stream kind 5",
        ),
        (
            {
                let mut b = p::client_hello(p::VERSION);
                b[30] = 1;
                b.to_vec()
            },
            9,
            "bytes 24..40 must be zero",
        ),
    ] {
        let server = serve(1, &sc, &out, &["--timeout", "20"]);
        let mut c = Client::connect(&server.addr);
        c.raw(&hello);
        let (got, message) = c.error();
        assert_eq!(got, code, "{message}");
        assert!(message.contains(text), "{message}");
        let (ok, _, err) = server.finish(60);
        assert!(!ok && err.contains(text), "{err}");
    }
    // nobody connects
    let server = serve(1, &sc, &out, &["--timeout", "1"]);
    let (ok, _, err) = server.finish(60);
    assert!(!ok && err.contains("no client connected within 1 s; fix:"), "{err}");
    // the client vanishes: without bye, and in the middle of a message; the series holds
    // every step computed, and reads back
    for (cut, text) in [
        (0, "closed the connection without bye"),
        (17, "in the middle of a message (17 of 40 bytes)"),
    ] {
        let server = serve(1, &sc, &out, &["--timeout", "20"]);
        let mut c = Client::connect(&server.addr);
        c.hello();
        catch_up(&mut c);
        c.raw(&[0u8; 40][..cut]);
        drop(c);
        let (ok, _, err) = server.finish(60);
        assert!(!ok && err.contains(text), "{err}");
        holds_steps_to_12(&out);
    }
}

#[test]
fn a_second_client_is_refused_while_the_first_goes_on() {
    let d = tempfile::tempdir().unwrap();
    let (server, mut c) = session(d.path(), "", &["--timeout", "20"]);
    c.answer(p::kind::POSE, 0, 0.5, [1.6, 0.0, 2.0]);
    let mut second = Client::connect(&server.addr);
    second.raw(&p::client_hello(p::VERSION_1));
    let (code, message) = second.error();
    assert_eq!(code, 3);
    // (it said "connect again after it ends", but a server takes no client after its session)
    assert_eq!(
        message, "another client holds the session; a server takes one client per run",
        "{message}"
    );
    // the first goes on, then the run ends while it is connected: it gets END
    c.answer(p::kind::FORCE, 0, 1e6, [0.0; 3]);
    let mut t = 1e6;
    let end = loop {
        t += 1.0;
        let _ = c.s.write_all(&p::client_message(p::kind::POSE, 0, t, [1.6, 0.0, 2.0]));
        match c.reply() {
            Reply::Answer(a) if a.kind == p::answer::END => break a,
            Reply::Answer(_) => std::thread::sleep(Duration::from_millis(2)),
            r => panic!("{r:?}"),
        }
    };
    assert!(end.t_step >= 70.0 - 1.0, "{end:?}");
    let (ok, out, err) = server.finish(60);
    assert!(ok, "{err}");
    assert!(out.contains("ended: run over"), "{out}");
}

#[test]
fn a_scenario_without_live_inputs_or_a_busy_port_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let (sc, _, _) = scenario(d.path(), "");
    let text = std::fs::read_to_string(&sc)
        .unwrap()
        .replace("live = true", "live = false");
    std::fs::write(&sc, text).unwrap();
    let o = common::serial(&["serve", sc.to_str().unwrap(), "--listen", "127.0.0.1:0"], 1);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("no [[tool]] or [[load]] has `live = true`") && err.contains("fix:"),
        "{err}"
    );
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let o = common::serial(&["serve", sc.to_str().unwrap(), "--listen", &addr], 1);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("cannot listen") && err.contains("fix:"),
        "{err}"
    );
}

/// SIGTERM (what SLURM sends at a time limit) while the client is quiet: on 1 process and
/// under mpirun -n 2 every process stops with status 3, the client gets the error, and the
/// series holds every step computed.
#[test]
fn sigterm_while_the_client_is_quiet_stops_every_process_and_keeps_the_series() {
    let d = tempfile::tempdir().unwrap();
    let d = d.path();
    let (sc, _, _) = scenario(d, "");
    let out = d.join("live.h5");
    for ranks in [1, 2] {
        let server = serve(ranks, &sc, &out, &["--timeout", "60"]);
        let mut c = Client::connect(&server.addr);
        c.hello();
        catch_up(&mut c);
        // SLURM signals every process of the job
        let pids: Vec<i32> = if ranks == 1 {
            vec![server.child.id() as i32]
        } else {
            common::children(server.child.id())
        };
        assert_eq!(pids.len(), ranks, "{pids:?}");
        for pid in &pids {
            Command::new("kill").args(["-TERM", &pid.to_string()]).status().unwrap();
        }
        let (code, message) = c.error();
        assert!(message.contains("stopped by SIGTERM"), "{code}: {message}");
        let status = server.finish_status(60);
        assert_eq!(status.0, Some(3), "{ranks} ranks: {}", status.1);
        assert!(status.1.contains("stopped by SIGTERM while waiting"), "{}", status.1);
        assert!(status.1.contains("complete output steps"), "{}", status.1);
        holds_steps_to_12(&out);
        // the client's samples are in no file: `run --restart` would go on along the
        // scenario's own path (it did, the tool jumping at the restart step); refused
        let o = common::serial(
            &["run", sc.to_str().unwrap(), "-q", "--restart", out.to_str().unwrap()],
            1,
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(
            err.contains("cannot restart: `eprop serve` wrote it, and its client's samples") && err.contains("fix:"),
            "{err}"
        );
        holds_steps_to_12(&out);
    }
}

/// The rows of both tables in time order, as (message kind, row).
fn in_time_order(path: &[[f64; 4]], force: &[[f64; 4]]) -> Vec<(u32, [f64; 4])> {
    let mut all: Vec<(u32, [f64; 4])> = path.iter().map(|r| (p::kind::POSE, *r)).collect();
    all.extend(force.iter().map(|r| (p::kind::FORCE, *r)));
    all.sort_by(|a, b| a.1[0].total_cmp(&b.1[0]));
    all
}

/// Sends rows until the server answers with an error, which it returns (the server must send
/// one, at the latest after the last row).
fn until_error(c: &mut Client, rows: &[(u32, [f64; 4])]) -> (u32, String) {
    for (kind, r) in rows {
        c.raw(&p::client_message(*kind, 0, r[0], [r[1], r[2], r[3]]));
        match c.reply() {
            Reply::Answer(_) => {}
            Reply::Error { code, message } => return (code, message),
            r => panic!("{r:?}"),
        }
    }
    c.error()
}

/// A live load of -1e300 turns the state non-finite: the served run stops as `eprop run` stops
/// on the same samples in a table (status 1, the same message), and the client gets error 8.
#[test]
fn a_live_load_that_turns_the_state_non_finite_stops_the_session_as_it_stops_a_run() {
    let d = tempfile::tempdir().unwrap();
    let (sc, path, _) = scenario(d.path(), "");
    // euler: the non-finite watch names the load (an implicit solve fails first)
    let text = std::fs::read_to_string(&sc)
        .unwrap()
        .replace("realtime = true\n", "realtime = false\n");
    std::fs::write(&sc, text).unwrap();
    let force: Vec<[f64; 4]> = (0..=30).map(|k| [k as f64 * 1.7, 0.0, 0.0, -1e300]).collect();
    let csv: String = std::iter::once("t,fx,fy,fz\n".to_string())
        .chain(force.iter().map(|r| format!("{},{},{},{}\n", r[0], r[1], r[2], r[3])))
        .collect();
    std::fs::write(d.path().join("force.csv"), csv).unwrap();
    let out = d.path().join("nan.h5");
    let o = common::serial(&["run", sc.to_str().unwrap(), "-q", "-o", out.to_str().unwrap()], 1);
    let batch = String::from_utf8_lossy(&o.stderr).trim().to_string();
    assert_eq!(o.status.code(), Some(1), "{batch}");
    assert!(
        batch.contains("no longer finite (NaN or inf)") && batch.contains("Likely cause: load 1"),
        "{batch}"
    );
    let rows = in_time_order(&path, &force);
    for ranks in [1, 2] {
        let server = serve(ranks, &sc, &out, &["--timeout", "30"]);
        let mut c = Client::connect(&server.addr);
        c.hello();
        let (code, message) = until_error(&mut c, &rows);
        assert_eq!(code, 8, "{message}");
        assert!(message.contains("no longer finite (NaN or inf)"), "{message}");
        let (status, err) = server.finish_status(60);
        assert_eq!(status, Some(1), "{ranks} ranks: {err}");
        assert!(err.contains(&batch), "{ranks} ranks: `{batch}` is not in: {err}");
        let (step, finite) = {
            let k = common::steps_complete(&out) as usize;
            let f = hdf5::File::open(&out).unwrap();
            let step = f.dataset("eprop/probes/step").unwrap().read_raw::<i64>().unwrap()[k - 1];
            let u = eprop_series::vtkhdf::read_step(&out, "displacement", k - 1).unwrap();
            (step, u.iter().all(|x| x.is_finite()))
        };
        assert!(finite, "step {step} of the series is not finite");
    }
}

/// A full disk: when the series is created (the disk filled once the server listens) and in
/// the middle of a session; the server ends with status 4 and the client gets error 8.
#[test]
fn a_full_disk_at_creation_and_mid_session_ends_with_status_4() {
    let d = tempfile::tempdir().unwrap();
    let (sc, _, _) = scenario(d.path(), "");
    // every output step complete at once: a disk filled all at once leaves no room to commit
    // later (a crash's loss, at most [output] flush seconds, is tested in tests/series.rs)
    let text = std::fs::read_to_string(&sc).unwrap();
    std::fs::write(
        &sc,
        text.replace("[output]\nevery = 3\n", "[output]\nevery = 3\nflush = 0\n"),
    )
    .unwrap();
    let Some(disk) = common::Tmpfs::mount("16m") else {
        return;
    };
    let out = disk.path().join("live.h5");
    // at creation: the estimate fits, then a filler takes the disk before step 0's samples
    // (2 ranks: the disk refuses a write inside HDF5's collective calls)
    for ranks in [1, 2] {
        let server = serve(ranks, &sc, &out, &["--timeout", "30"]);
        let filler = disk.fill();
        let mut c = Client::connect(&server.addr);
        c.hello();
        let (code, message) = until_error(
            &mut c,
            &[(p::kind::FORCE, [0.0; 4]), (p::kind::POSE, [0.0, 1.6, 0.0, 2.0])],
        );
        assert_eq!(code, 8, "{message}");
        assert!(
            message.contains("could not be created") && message.contains("ENOSPC"),
            "{message}"
        );
        let (status, err) = server.finish_status(60);
        assert_eq!(status, Some(4), "{ranks} ranks: {err}");
        assert!(
            err.contains("no space left on device (ENOSPC)")
                && err.contains("nothing was written")
                && err.contains("fix: free space"),
            "{err}"
        );
        std::fs::remove_file(&filler).unwrap();
        let _ = std::fs::remove_file(&out);
    }
    // mid-session: the disk fills while the client drives
    for ranks in [1, 2] {
        let server = serve(ranks, &sc, &out, &["--timeout", "30"]);
        let mut c = Client::connect(&server.addr);
        c.hello();
        catch_up(&mut c);
        let filler = disk.fill();
        let rows: Vec<(u32, [f64; 4])> = (1..2000)
            .flat_map(|k| {
                let t = 10.0 + 0.05 * k as f64;
                [
                    (p::kind::POSE, [t, 1.5, 0.0, 2.0]),
                    (p::kind::FORCE, [t + 20.0, 0.0, -0.05, 0.0]),
                ]
            })
            .collect();
        let (code, message) = until_error(&mut c, &rows);
        assert_eq!(code, 8, "{message}");
        assert!(
            message.contains("the disk is full (ENOSPC)") || message.contains("the disk is nearly full"),
            "{message}"
        );
        let (status, err) = server.finish_status(60);
        assert_eq!(status, Some(4), "{ranks} ranks: {err}");
        assert!(
            err.contains("the disk is") && err.contains("complete output steps") && err.contains("fix: free space"),
            "{err}"
        );
        assert!(err.matches("fix: free space").count() == 1, "one message: {err}");
        holds_steps_to_12(&out);
        std::fs::remove_file(&filler).unwrap();
        std::fs::remove_file(&out).unwrap();
    }
}

/// `eprop serve ARGS` that must be refused before it says it listens: status 1, every needle
/// in its message.
fn refused_before_listening(args: &[&str], needles: &[&str]) {
    let mut all = vec!["serve"];
    all.extend(args);
    all.extend(["--listen", "127.0.0.1:0", "--timeout", "2", "-q"]);
    let o = common::serial(&all, 1);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
    assert!(
        !err.contains("listening on"),
        "{args:?} listened before it refused: {err}"
    );
    for n in needles {
        assert!(err.contains(n), "{args:?}: `{n}` is not in: {err}");
    }
}

/// Every refusal of a served run comes before the `listening on` line: the step limits and
/// the free space (as `eprop run` checks them), an output that is an input or an existing
/// series, no live input, more than 32.
#[test]
fn a_served_run_is_refused_before_it_listens_and_respects_the_limits() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let (sc, _, _) = scenario(dir, "");
    let sc = sc.to_str().unwrap();
    let out = dir.join("live.h5");
    let o = out.to_str().unwrap();
    refused_before_listening(
        &[sc, "-o", o, "--steps", "1000000001"],
        &[
            "--steps = 1,000,000,001 steps, above the limit of 1,000,000,000",
            "fix:",
        ],
    );
    refused_before_listening(
        &[sc, "-o", o, "--steps", "1000000000"],
        &["the run would write about", "free", "--force"],
    );
    assert!(!out.exists());
    let mesh = dir.join("cyl.msh");
    refused_before_listening(&[sc, "-o", mesh.to_str().unwrap()], &["is the mesh", "fix:"]);
    refused_before_listening(
        &[sc, "-o", dir.join("path.csv").to_str().unwrap()],
        &["is the path table of [[tool]] 1"],
    );
    batch(Path::new(sc), &out);
    refused_before_listening(&[sc, "-o", o], &["holds an eprop series", "--overwrite"]);
    let text = std::fs::read_to_string(sc).unwrap();
    std::fs::write(dir.join("none.toml"), text.replace("live = true", "live = false")).unwrap();
    refused_before_listening(
        &[dir.join("none.toml").to_str().unwrap(), "-o", o, "--overwrite"],
        &["no [[tool]] or [[load]] has `live = true`"],
    );
    let loads: String = (0..33)
        .map(|k| {
            format!(
                "[[load]]\nnearest = [1.0, 0.0, {}]\nforce = [-0.01, 0.0, 0.0]\nlive = true\n",
                1.0 + 0.05 * k as f64
            )
        })
        .collect();
    std::fs::write(
        dir.join("many.toml"),
        format!("[mesh]\nfile = \"cyl.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"bottom\"\n{loads}[time]\nend = 5\n"),
    )
    .unwrap();
    refused_before_listening(
        &[dir.join("many.toml").to_str().unwrap(), "-o", o, "--overwrite"],
        &["load 33 is live, but only the first 32"],
    );
}

/// Bye before any sample of a live input: the client gets error 8 instead of a bye answer,
/// and the server ends with status 1 and the same message.
#[test]
fn bye_before_any_sample_of_a_live_input_is_an_error_to_both_sides() {
    let d = tempfile::tempdir().unwrap();
    let (sc, _, _) = scenario(d.path(), "");
    let out = d.path().join("live.h5");
    for (samples, name) in [(&[p::kind::POSE][..], "load 0"), (&[][..], "tool 0")] {
        let server = serve(1, &sc, &out, &["--timeout", "20"]);
        let mut c = Client::connect(&server.addr);
        c.hello();
        for &k in samples {
            c.answer(k, 0, 0.5, [1.6, 0.0, 2.0]);
        }
        let (code, message) = match c.send(p::kind::BYE, 0, 0.0, [0.0; 3]) {
            Reply::Error { code, message } => (code, message),
            r => panic!("bye before any sample of {name} was answered {r:?}"),
        };
        assert_eq!(code, 8, "{message}");
        let text = format!("bye before any sample of {name}");
        assert!(message.contains(&text), "{message}");
        let (status, err) = server.finish_status(60);
        assert_eq!(status, Some(1), "{err}");
        assert!(err.contains(&text) && err.contains("fix:"), "{err}");
    }
}

/// A client that sends without reading its answers: the server, blocked on an answer, reads
/// no more samples; it says so, not that the client sent none.
#[test]
fn a_client_that_does_not_read_its_answers_is_told_so() {
    let d = tempfile::tempdir().unwrap();
    let (sc, _, _) = scenario(d.path(), "");
    let server = serve(1, &sc, &d.path().join("live.h5"), &["--timeout", "1"]);
    let mut c = Client::connect(&server.addr);
    c.hello();
    let mut w = c.s.try_clone().unwrap();
    let writer = std::thread::spawn(move || {
        // far more than the socket buffers hold, at times the physics needs one by one
        for k in 0..2_000_000u64 {
            let t = k as f64 * 1e-5;
            let pose = p::client_message(p::kind::POSE, 0, t, [1.6, 0.0, 2.0]);
            let force = p::client_message(p::kind::FORCE, 0, t, [0.0; 3]);
            if w.write_all(&pose).and_then(|_| w.write_all(&force)).is_err() {
                return k;
            }
        }
        u64::MAX
    });
    std::thread::sleep(Duration::from_secs(4));
    // what the client reads afterwards: answers, perhaps an error, then the end
    let mut seen = Vec::new();
    let mut b = [0u8; p::SERVER_SIZE];
    while c.s.read_exact(&mut b).is_ok() {
        if let Reply::Error { code, message } = p::read_reply(&b) {
            seen.push(format!("{code}: {message}"));
        }
    }
    let sent = writer.join().unwrap();
    assert!(sent < u64::MAX, "the server read every message");
    let (status, err) = server.finish_status(60);
    assert_eq!(status, Some(1), "{err}");
    assert!(err.contains("the client does not read its answers"), "{err}");
    assert!(!err.contains("sent no sample"), "{err}");
    for s in &seen {
        assert!(s.contains("does not read its answers"), "{s}");
    }
}

/// A client whose samples run far ahead of the steps computed: the physics falls behind, and
/// the server says so once on stderr and in the summary.
#[test]
fn a_physics_behind_the_client_is_warned_of_once() {
    let d = tempfile::tempdir().unwrap();
    let (sc, _, _) = scenario(d.path(), "");
    let server = serve(1, &sc, &d.path().join("live.h5"), &["--timeout", "20", "--json"]);
    let mut c = Client::connect(&server.addr);
    let h = c.hello();
    c.answer(p::kind::FORCE, 0, 30.0, [0.0, -0.05, 0.0]);
    c.answer(p::kind::POSE, 0, 30.0, [1.6, 0.0, 2.0]);
    match c.send(p::kind::BYE, 0, 0.0, [0.0; 3]) {
        Reply::Answer(a) => assert_eq!(a.kind, p::answer::BYE),
        r => panic!("{r:?}"),
    }
    let (ok, out, err) = server.finish(120);
    assert!(ok, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    let behind = report["session"]["max_behind_steps"].as_f64().unwrap();
    assert!(behind >= 30.0 / h.dt - 1.0 - 1e-9, "{behind} steps, dt {}", h.dt);
    let warning = report["session"]["warning"].as_str().unwrap();
    assert!(
        warning.contains("the physics fell behind the client") && warning.contains("fix:"),
        "{warning}"
    );
    assert_eq!(
        err.matches("warning: the physics fell behind the client").count(),
        1,
        "{err}"
    );
}

#[test]
fn a_client_without_the_stream_gets_the_messages_of_version_1_and_nothing_else() {
    let d = tempfile::tempdir().unwrap();
    let (sc, path, force) = scenario(d.path(), "");
    let rows = in_time_order(&path[..40], &force[..6]);
    // version 1, and version 2 without a stream
    for version in [p::VERSION_1, p::VERSION_2] {
        let server = serve(1, &sc, &d.path().join("live.h5"), &["--timeout", "30"]);
        let mut c = Client::connect(&server.addr);
        c.raw(&p::client_hello(version));
        let mut b = [0u8; p::SERVER_SIZE];
        c.s.read_exact(&mut b).unwrap();
        let h = match p::read_reply(&b) {
            Reply::Hello(h) => h,
            r => panic!("{r:?}"),
        };
        // the hello of version 1: its version, the same fields, zeros after the step limit
        assert_eq!(h.version, version);
        assert_eq!(b, p::server_hello(&h));
        assert_eq!(&b[4..8], &version.to_le_bytes());
        assert!(b[64..].iter().all(|&x| x == 0), "{b:?}");
        // one 80-byte answer per message, read in lock step: a byte more would be read as
        // the next answer
        for (kind, r) in &rows {
            c.raw(&p::client_message(*kind, 0, r[0], [r[1], r[2], r[3]]));
            c.s.read_exact(&mut b).unwrap();
            match p::read_reply(&b) {
                Reply::Answer(a) => assert_eq!(a.kind, *kind, "{a:?}"),
                r => panic!("{r:?}"),
            }
        }
        // bye: its answer, then the connection closes with nothing else
        c.raw(&p::client_message(p::kind::BYE, 0, 0.0, [0.0; 3]));
        let mut rest = Vec::new();
        c.s.read_to_end(&mut rest).unwrap();
        assert_eq!(rest.len(), p::SERVER_SIZE);
        match p::read_reply(rest[..].try_into().unwrap()) {
            Reply::Answer(a) => assert_eq!(a.kind, p::answer::BYE),
            r => panic!("{r:?}"),
        }
        let (ok, _, err) = server.finish(120);
        assert!(ok, "{err}");
    }
}

/// A streaming session (frames every 3 steps, values of `width` bytes) on `ranks` processes:
/// the series is the batch run's, the topology is the surface `eprop export --surface` writes,
/// and every frame holds the series' displacements of the surface nodes at its step. Returns
/// the topology's payload.
fn stream_equals_series(ranks: usize, width: u32) -> Vec<u8> {
    let d = tempfile::tempdir().unwrap();
    let (sc, path, force) = scenario(d.path(), "");
    // the cheap steps of auto's euler on this small mesh: frames come while the client drives
    not_realtime(&sc);
    let live = d.path().join("live.h5");
    let server = serve(ranks, &sc, &live, &["--timeout", "30"]);
    let mut c = Client::connect(&server.addr);
    c.raw(&p::client_hello_stream(p::Stream { every: 3, width }));
    let h = match c.reply() {
        Reply::Hello(h) => h,
        r => panic!("{r:?}"),
    };
    assert_eq!(h.version, 2);
    // pauses long enough for the physics to catch up now and then: frames come with answers
    // (80 ms: with 3 processes on 2 busy cores, 20 ms pauses let only 2 frames through)
    drive_paced(&mut c, &path, &force, h.dt, 80);
    let (ok, _, err) = server.finish(120);
    assert!(ok, "{err}");
    // streaming changes nothing of the run: the batch series, bit for bit
    let one = d.path().join("batch.h5");
    batch(&sc, &one);
    common::assert_same(&one, &live);
    let (th, tb) = &c.payloads[0];
    assert_eq!((th.kind, th.width, th.every), (p::answer::TOPOLOGY, width, 3));
    let topo = p::read_topology(th, tb);
    assert_eq!(
        (topo.nodes.len(), topo.triangles.len()),
        (h.surface_nodes as usize, h.surface_triangles as usize)
    );
    // the surface of `eprop export --surface` at output step 0: the same triangles over the
    // same vertices
    let obj = d.path().join("surf");
    let o = common::serial(
        &[
            "export",
            live.to_str().unwrap(),
            "--surface",
            "obj",
            "--step",
            "0",
            "-o",
            obj.to_str().unwrap(),
        ],
        1,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(d.path().join("surf_000000.obj")).unwrap();
    let faces: Vec<[u32; 3]> = text
        .lines()
        .filter_map(|l| l.strip_prefix("f "))
        .map(|l| {
            let v: Vec<u32> = l.split(' ').map(|x| x.parse::<u32>().unwrap() - 1).collect();
            [v[0], v[1], v[2]]
        })
        .collect();
    assert_eq!(faces, topo.triangles);
    let (mesh, _) = eprop_series::vtkhdf::read_mesh(&live).unwrap();
    let cast = |x: f64| if width == 4 { f64::from(x as f32) } else { x };
    for (i, &g) in topo.nodes.iter().enumerate() {
        for k in 0..3 {
            assert_eq!(topo.rest[3 * i + k], cast(mesh.points[g as usize][k]));
        }
    }
    // every frame: the series' displacements at its step
    let steps = hdf5::File::open(&live)
        .unwrap()
        .dataset("eprop/tools/step")
        .unwrap()
        .read_raw::<i64>()
        .unwrap();
    let steps = &steps[..common::steps_complete(&live) as usize];
    let frames = &c.payloads[1..];
    assert!(frames.len() >= 3, "{} frames", frames.len());
    let (mut last, mut moved) = (None, false);
    for (fh, fb) in frames {
        assert_eq!(
            (fh.kind, fh.width, fh.nodes),
            (p::answer::FRAME, width, h.surface_nodes)
        );
        assert!(fh.step.is_multiple_of(3) && last.is_none_or(|k| fh.step > k), "{fh:?}");
        assert_eq!(fh.t_step, fh.step as f64 * h.dt);
        last = Some(fh.step);
        let j = steps.iter().position(|&k| k as u64 == fh.step).unwrap();
        let u = eprop_series::vtkhdf::read_step(&live, "displacement", j).unwrap();
        let got = p::read_values(fb, width);
        for (i, &g) in topo.nodes.iter().enumerate() {
            for k in 0..3 {
                assert_eq!(got[3 * i + k], cast(u[3 * g as usize + k]), "step {}", fh.step);
            }
        }
        moved |= got.iter().any(|&x| x != 0.0);
    }
    assert!(moved, "no frame shows the press");
    tb.clone()
}

#[test]
fn a_streaming_client_gets_the_surface_and_the_series_displacements() {
    stream_equals_series(1, 8);
    stream_equals_series(1, 4);
}

#[test]
fn a_streaming_client_under_mpirun_gets_the_bytes_of_one_process() {
    let one = stream_equals_series(1, 8);
    for ranks in [2, 3] {
        assert_eq!(stream_equals_series(ranks, 8), one, "{ranks} processes");
    }
}

/// A client that sends poses, then pauses: the server commits every step it computed when it
/// starts to wait (within [output] flush + 1 s), so a kill -9 in the pause loses nothing; on 1
/// and 2 processes (the commit is collective while rank 0 waits for the client).
#[test]
fn a_pause_of_the_client_leaves_every_computed_step_complete_and_a_kill_loses_nothing() {
    let d = tempfile::tempdir().unwrap();
    let d = d.path();
    let (sc, _, _) = scenario(d, "");
    let out = d.join("live.h5");
    for ranks in [1, 2] {
        let server = serve(
            ranks,
            &sc,
            &out,
            &["--timeout", "60", "--set", "output.every=1", "--set", "output.flush=1"],
        );
        let mut c = Client::connect(&server.addr);
        c.hello();
        // samples to t = 30 (force) and t = 10 (pose), until the physics has used them all
        c.answer(p::kind::FORCE, 0, 30.0, [0.0, -0.05, 0.0]);
        let mut latest = 10.0;
        let mut a = c.answer(p::kind::POSE, 0, latest, [1.5, 0.0, 2.0]);
        let deadline = Instant::now() + Duration::from_secs(30);
        let mut k = 0;
        while a.t_step < 9.5 {
            k += 1;
            latest = 10.0 + k as f64 * 1e-6;
            a = c.answer(p::kind::POSE, 0, latest, [1.5, 0.0, 2.0]);
            assert!(Instant::now() < deadline, "the physics does not advance: {a:?}");
            std::thread::sleep(Duration::from_millis(1));
        }
        // the pause: flush (1 s) + 1 s
        let paused = Instant::now();
        std::thread::sleep(Duration::from_secs(2));
        let pids: Vec<i32> = if ranks == 1 {
            vec![server.child.id() as i32]
        } else {
            common::children(server.child.id())
        };
        for pid in &pids {
            Command::new("kill").args(["-9", &pid.to_string()]).status().unwrap();
        }
        let waited = paused.elapsed().as_secs_f64();
        let _ = server.wait_all(60);
        let k = common::steps_complete(&out) as usize;
        let f = hdf5::File::open(&out).unwrap();
        let time = f.dataset("eprop/tools/time").unwrap().read_raw::<f64>().unwrap();
        let step = f.dataset("eprop/tools/step").unwrap().read_raw::<i64>().unwrap();
        assert!(k >= 2, "{ranks} ranks: {k} steps complete");
        let dt = time[1] - time[0];
        let last = time[k - 1];
        // every step the samples allowed: the next one needs a pose at or beyond last + dt
        assert!(
            last <= latest && last + dt > latest,
            "{ranks} ranks, {waited:.1} s into the pause: {k} complete steps, the last at t = {last} (step {}), but the client's poses reach t = {latest} (dt {dt})",
            step[k - 1]
        );
        assert_eq!(step[k - 1] as usize, k - 1, "every step is an output step");
    }
}
