//! The live coupling's speed: a client of `eprop serve` at 1 kHz, and one as fast as it can.
//!
//! For each unit box (N^3 cells, Kuhn tetrahedra, zmin fixed) and process count: `eprop serve`
//! runs a live sphere pressed 0.05 into the top face, with dt = the Euler substep (one
//! substep per mechanics step, the haptic configuration). The client sends poses time-stamped
//! far ahead of the physics, so the physics never waits and runs as fast as it can, and
//!   - at 1 kHz (paced by the wall clock) for `--seconds`: round trip p50, p99, max, answers
//!     per second, and the physics steps per second seen in the answers' step numbers;
//!   - then back to back (the next message when the answer is in) for `--seconds`: the answer
//!     rate and its round trip.
//!
//!     cargo build --release && cargo run --release --example haptic_bench -- --cells 9,21,26,36 --ranks 1,2
//!
//! Needs the release binary (target/release/eprop) and, for more than one rank, mpirun.

use eprop::cli::serve::protocol::{self as p, Reply};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn arg(args: &[String], key: &str, default: &str) -> String {
    args.iter()
        .position(|a| a == key)
        .and_then(|i| args.get(i + 1).cloned())
        .unwrap_or_else(|| default.to_string())
}

fn list(s: &str) -> Vec<usize> {
    s.split(',')
        .map(|x| x.trim().parse().expect("a list of integers"))
        .collect()
}

fn eprop_bin() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("target/release/eprop")
}

/// The scenario of one case, with dt = the Euler substep of the mesh.
fn scenario(dir: &Path, cells: usize) -> PathBuf {
    let mesh = eprop_io::generate::box_mesh([1.0; 3], [cells; 3], eprop_io::generate::BoxCells::Tet).unwrap();
    eprop_io::write_mesh(&mesh, &dir.join("box.msh")).unwrap();
    let body = |dt: &str| {
        format!(
            "[mesh]\nfile = \"box.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"zmin\"\n[[tool]]\nshape = \"sphere\"\nradius = 0.2\nstart = [0.5, 0.5, 1.15]\nlive = true\n\
             [time]\nsteps = 1000000000\n{dt}[output]\nevery = 1000000000\nfields = [\"displacement\"]\n"
        )
    };
    let sc = dir.join("haptic.toml");
    std::fs::write(&sc, body("")).unwrap();
    let out = Command::new(eprop_bin())
        .args(["check", sc.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let h = v["h"].as_f64().unwrap();
    std::fs::write(&sc, body(&format!("dt = {h:e}\n"))).unwrap();
    sc
}

fn start(ranks: usize, sc: &Path) -> (Child, String) {
    let mut cmd = if ranks == 1 {
        Command::new(eprop_bin())
    } else {
        let mut c = Command::new("mpirun");
        c.args(["-n", &ranks.to_string(), "--oversubscribe"]).arg(eprop_bin());
        c
    };
    let mut child = cmd
        .args([
            "serve",
            sc.to_str().unwrap(),
            "--listen",
            "127.0.0.1:0",
            "-q",
            "--timeout",
            "60",
        ])
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_rmaps_base_oversubscribe", "1")
        .env("RAYON_NUM_THREADS", "1")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let addr = loop {
        let l = lines.next().expect("eprop serve prints its address").unwrap();
        if let Some(a) = l.strip_prefix("eprop serve: listening on ") {
            break a.to_string();
        }
    };
    std::thread::spawn(move || for _ in lines {});
    (child, addr)
}

struct Phase {
    answers: usize,
    seconds: f64,
    rtt: Vec<f64>,
    steps: (u64, u64),
}

fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() as f64 * q) as usize).min(v.len() - 1)]
}

/// Sends poses (time-stamped far ahead) for `seconds`, paced at `rate` per second (0: back
/// to back); the round trips and the physics steps seen.
fn phase(s: &mut TcpStream, t: &mut f64, rate: f64, seconds: f64) -> Phase {
    let start = Instant::now();
    let mut rtt = Vec::new();
    let mut steps = (u64::MAX, 0);
    let mut buf = [0u8; p::SERVER_SIZE];
    let mut k = 0u64;
    while start.elapsed().as_secs_f64() < seconds {
        if rate > 0.0 {
            let due = start + Duration::from_secs_f64(k as f64 / rate);
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
        *t += 1.0;
        let m = p::client_message(p::kind::POSE, 0, *t, [0.5, 0.5, 1.15]);
        let sent = Instant::now();
        s.write_all(&m).unwrap();
        s.read_exact(&mut buf).unwrap();
        rtt.push(sent.elapsed().as_secs_f64());
        match p::read_reply(&buf) {
            Reply::Answer(a) => {
                steps = (steps.0.min(a.step), steps.1.max(a.step));
            }
            r => panic!("{r:?}"),
        }
        k += 1;
    }
    Phase {
        answers: rtt.len(),
        seconds: start.elapsed().as_secs_f64(),
        rtt,
        steps,
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let cells = list(&arg(&args, "--cells", "9,21,26,36"));
    let ranks = list(&arg(&args, "--ranks", "1,2"));
    let seconds: f64 = arg(&args, "--seconds", "5").parse().unwrap();
    let rate: f64 = arg(&args, "--rate", "1000").parse().unwrap();
    assert!(
        eprop_bin().exists(),
        "build the release binary first: cargo build --release"
    );
    println!(
        "{:>7} {:>5} {:>10} | {:>8} {:>8} {:>8} {:>9} {:>10} | {:>9} {:>8} {:>8}",
        "nodes", "procs", "dt", "p50 ms", "p99 ms", "max ms", "answers/s", "physics/s", "b2b ans/s", "p50 ms", "p99 ms"
    );
    for &c in &cells {
        let dir = tempfile::tempdir().unwrap();
        let sc = scenario(dir.path(), c);
        let dt: f64 = std::fs::read_to_string(&sc)
            .unwrap()
            .lines()
            .find_map(|l| l.strip_prefix("dt = ").map(|x| x.trim().parse().unwrap()))
            .unwrap();
        for &r in &ranks {
            let (mut child, addr) = start(r, &sc);
            let mut s = TcpStream::connect(&addr).unwrap();
            s.set_nodelay(true).unwrap();
            s.write_all(&p::client_hello(p::VERSION_1)).unwrap();
            let mut b = [0u8; p::SERVER_SIZE];
            s.read_exact(&mut b).unwrap();
            assert!(matches!(p::read_reply(&b), Reply::Hello(_)));
            let mut t = 1e9;
            // warm up: the physics starts and the first steps pass
            phase(&mut s, &mut t, rate, 0.5);
            let mut paced = phase(&mut s, &mut t, rate, seconds);
            let mut b2b = phase(&mut s, &mut t, 0.0, seconds.min(3.0));
            // leaving without bye ends the run (and every rank) with an error: no kill needed
            drop(s);
            let deadline = Instant::now() + Duration::from_secs(60);
            while child.try_wait().unwrap().is_none() {
                if Instant::now() > deadline {
                    let _ = child.kill();
                    panic!("eprop serve did not stop");
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            let physics = (paced.steps.1 - paced.steps.0) as f64 / paced.seconds;
            println!(
                "{:>7} {:>5} {:>10.3e} | {:>8.3} {:>8.3} {:>8.3} {:>9.0} {:>10.0} | {:>9.0} {:>8.3} {:>8.3}",
                (c + 1).pow(3),
                r,
                dt,
                1e3 * quantile(&mut paced.rtt, 0.5),
                1e3 * quantile(&mut paced.rtt, 0.99),
                1e3 * quantile(&mut paced.rtt, 1.0),
                paced.answers as f64 / paced.seconds,
                physics,
                b2b.answers as f64 / b2b.seconds,
                1e3 * quantile(&mut b2b.rtt, 0.5),
                1e3 * quantile(&mut b2b.rtt, 0.99),
            );
        }
    }
}
