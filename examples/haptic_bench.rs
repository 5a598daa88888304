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
//! `--stream 0,1,10` repeats each case without the surface stream (0) and with a frame every
//! K steps (protocol version 2, f32 values; `--width 8` for f64): the round trips then include
//! reading the frames. `--mesh a.msh,b.ele` adds cases on mesh files (any format eprop
//! reads): the nodes within 10% of the height from the bottom fixed, the sphere (radius 0.2 of
//! the largest extent) pressed 5% of the height into the top; `--cells ""` leaves the boxes out.
//!
//! Needs the release binary (target/release/eprop) and, for more than one rank, mpirun.

use eprop::protocol::{self as p, Reply};
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
        .filter(|x| !x.trim().is_empty())
        .map(|x| x.trim().parse().expect("a list of integers"))
        .collect()
}

fn eprop_bin() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("target/release/eprop")
}

/// One case: the mesh file in `dir` and the scenario's fixed set and tool.
struct Case {
    label: String,
    mesh: PathBuf,
    fixed: String,
    /// The sphere's radius and the pose the client holds it at.
    radius: f64,
    pose: [f64; 3],
}

fn box_case(dir: &Path, cells: usize) -> Case {
    let mesh = eprop_io::generate::box_mesh([1.0; 3], [cells; 3], eprop_io::generate::BoxCells::Tet).unwrap();
    let file = dir.join(format!("box{cells}.msh"));
    eprop_io::write_mesh(&mesh, &file).unwrap();
    Case {
        label: format!("box{}", (cells + 1).pow(3)),
        mesh: file,
        fixed: "group = \"zmin\"".into(),
        radius: 0.2,
        pose: [0.5, 0.5, 1.15],
    }
}

fn file_case(path: &Path) -> Case {
    let mesh = eprop_io::read_mesh(path).unwrap();
    let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
    for p in &mesh.points {
        for d in 0..3 {
            lo[d] = lo[d].min(p[d]);
            hi[d] = hi[d].max(p[d]);
        }
    }
    let h = hi[2] - lo[2];
    let extent = (0..3).map(|d| hi[d] - lo[d]).fold(0.0, f64::max);
    let radius = 0.2 * extent;
    let c = |d: usize| 0.5 * (lo[d] + hi[d]);
    Case {
        label: format!("{}{}", path.file_stem().unwrap().to_string_lossy(), mesh.points.len()),
        mesh: std::fs::canonicalize(path).unwrap(),
        fixed: format!(
            "halfspace = {{ point = [0.0, 0.0, {:e}], normal = [0.0, 0.0, -1.0] }}",
            lo[2] + 0.1 * h
        ),
        radius,
        pose: [c(0), c(1), hi[2] + radius - 0.05 * h],
    }
}

/// The scenario of one case, with dt = the Euler substep of the mesh.
fn scenario(dir: &Path, case: &Case) -> PathBuf {
    let body = |dt: &str| {
        format!(
            "[mesh]\nfile = {:?}\n[model]\nreading = \"paper\"\n[[fixed]]\n{}\n[[tool]]\nshape = \"sphere\"\nradius = {:e}\nstart = [{:e}, {:e}, {:e}]\nlive = true\n\
             [time]\nsteps = 1000000000\n{dt}[output]\nevery = 1000000000\nfields = [\"displacement\"]\n",
            case.mesh.to_str().unwrap(),
            case.fixed,
            case.radius,
            case.pose[0],
            case.pose[1],
            case.pose[2]
        )
    };
    let sc = dir.join(format!("{}.toml", case.label));
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
            // the cases of a scenario write its series in turn
            "--overwrite",
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
    frames: usize,
    frame_bytes: u64,
}

fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() as f64 * q) as usize).min(v.len() - 1)]
}

/// Sends poses (time-stamped far ahead) for `seconds`, paced at `rate` per second (0: back
/// to back); the round trips (frames read on the way included) and the physics steps seen.
fn phase(s: &mut TcpStream, t: &mut f64, pose: [f64; 3], rate: f64, seconds: f64) -> Phase {
    let start = Instant::now();
    let mut rtt = Vec::new();
    let mut steps = (u64::MAX, 0);
    let (mut frames, mut frame_bytes) = (0, 0);
    let mut buf = [0u8; p::SERVER_SIZE];
    let mut payload = Vec::new();
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
        let m = p::client_message(p::kind::POSE, 0, *t, pose);
        let sent = Instant::now();
        s.write_all(&m).unwrap();
        loop {
            s.read_exact(&mut buf).unwrap();
            match p::read_reply(&buf) {
                Reply::Answer(a) => {
                    steps = (steps.0.min(a.step), steps.1.max(a.step));
                    break;
                }
                Reply::Payload(h) => {
                    payload.resize(h.bytes as usize, 0);
                    s.read_exact(&mut payload).unwrap();
                    frames += 1;
                    frame_bytes += h.bytes;
                }
                r => panic!("{r:?}"),
            }
        }
        rtt.push(sent.elapsed().as_secs_f64());
        k += 1;
    }
    Phase {
        answers: rtt.len(),
        seconds: start.elapsed().as_secs_f64(),
        rtt,
        steps,
        frames,
        frame_bytes,
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let cells = list(&arg(&args, "--cells", "9,21,26,36"));
    let meshes = arg(&args, "--mesh", "");
    let ranks = list(&arg(&args, "--ranks", "1,2"));
    let streams = list(&arg(&args, "--stream", "0"));
    let width: u32 = arg(&args, "--width", "4").parse().unwrap();
    let seconds: f64 = arg(&args, "--seconds", "5").parse().unwrap();
    let rate: f64 = arg(&args, "--rate", "1000").parse().unwrap();
    assert!(
        eprop_bin().exists(),
        "build the release binary first: cargo build --release"
    );
    println!(
        "{:>14} {:>5} {:>10} {:>6} | {:>8} {:>8} {:>8} {:>9} {:>10} {:>8} | {:>9} {:>8} {:>8}",
        "mesh",
        "procs",
        "dt",
        "stream",
        "p50 ms",
        "p99 ms",
        "max ms",
        "answers/s",
        "physics/s",
        "frame kB",
        "b2b ans/s",
        "p50 ms",
        "p99 ms"
    );
    let dir = tempfile::tempdir().unwrap();
    let mut cases: Vec<Case> = cells.iter().map(|&c| box_case(dir.path(), c)).collect();
    cases.extend(
        meshes
            .split(',')
            .filter(|m| !m.is_empty())
            .map(|m| file_case(Path::new(m))),
    );
    for case in &cases {
        let sc = scenario(dir.path(), case);
        let dt: f64 = std::fs::read_to_string(&sc)
            .unwrap()
            .lines()
            .find_map(|l| l.strip_prefix("dt = ").map(|x| x.trim().parse().unwrap()))
            .unwrap();
        for &r in &ranks {
            for &k in &streams {
                let (mut child, addr) = start(r, &sc);
                let mut s = TcpStream::connect(&addr).unwrap();
                s.set_nodelay(true).unwrap();
                let hello = if k == 0 {
                    p::client_hello(p::VERSION_1)
                } else {
                    p::client_hello_stream(p::Stream { every: k as u32, width })
                };
                s.write_all(&hello).unwrap();
                let mut b = [0u8; p::SERVER_SIZE];
                s.read_exact(&mut b).unwrap();
                assert!(matches!(p::read_reply(&b), Reply::Hello(_)));
                let mut t = 1e9;
                // warm up: the topology, the physics starts and the first steps pass
                phase(&mut s, &mut t, case.pose, rate, 0.5);
                let mut paced = phase(&mut s, &mut t, case.pose, rate, seconds);
                let mut b2b = phase(&mut s, &mut t, case.pose, 0.0, seconds.min(3.0));
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
                let frame_kb = if paced.frames > 0 {
                    paced.frame_bytes as f64 / paced.frames as f64 / 1e3
                } else {
                    0.0
                };
                println!(
                    "{:>14} {:>5} {:>10.3e} {:>6} | {:>8.3} {:>8.3} {:>8.3} {:>9.0} {:>10.0} {:>8.1} | {:>9.0} {:>8.3} {:>8.3}",
                    case.label,
                    r,
                    dt,
                    k,
                    1e3 * quantile(&mut paced.rtt, 0.5),
                    1e3 * quantile(&mut paced.rtt, 0.99),
                    1e3 * quantile(&mut paced.rtt, 1.0),
                    paced.answers as f64 / paced.seconds,
                    physics,
                    frame_kb,
                    b2b.answers as f64 / b2b.seconds,
                    1e3 * quantile(&mut b2b.rtt, 0.5),
                    1e3 * quantile(&mut b2b.rtt, 0.99),
                );
            }
        }
    }
}
