#![allow(dead_code)]
//! Helpers shared by the integration tests.

use eprop::config::{Scenario, Setup};
use eprop::simulate::Simulation;
use eprop_mesh::Mesh;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The log of tests that did not test what they are for (one line each: test, reason);
/// `scripts/test.sh` empties it before the tests and prints it after. `EPROP_SKIP_LOG` names
/// another (a test that runs a probe of its own, which must not count in the suite's log).
pub fn skip_log() -> PathBuf {
    match std::env::var_os("EPROP_SKIP_LOG") {
        Some(p) => PathBuf::from(p),
        None => Path::new(env!("CARGO_TARGET_TMPDIR")).join("eprop-skipped.log"),
    }
}

fn log_skip(line: &str) {
    use std::io::Write;
    println!("skipped: {line}");
    eprintln!("skipped: {line}");
    if let Ok(mut f) = std::fs::OpenOptions::new().create(true).append(true).open(skip_log()) {
        let _ = writeln!(f, "{line}");
    }
}

/// The test calling this does not test what it is for because `reason` (a tool or the shared
/// data is missing): it says so, is logged (`skip_log`) and, under `EPROP_REQUIRE_ALL=1` (set
/// by CI, where everything is installed), fails.
pub fn skip(reason: &str) {
    let test = std::thread::current().name().unwrap_or("?").to_string();
    let line = format!("{test}: {reason}");
    log_skip(&line);
    if std::env::var("EPROP_REQUIRE_ALL").is_ok_and(|v| v == "1") {
        panic!("skipped with EPROP_REQUIRE_ALL=1 (everything must be installed here): {line}");
    }
}

/// For a part of a test that a machine may lawfully lack while the test still tests what it
/// is for (a stand-in replaces `sbatch`; a README line that needs the network is supplied):
/// logged and said, never a failure. A test that returns early instead, having tested nothing,
/// calls `skip`.
pub fn unsupported(reason: &str) {
    let test = std::thread::current().name().unwrap_or("?").to_string();
    log_skip(&format!("{test}: {reason} (not required)"));
}

/// `../shared/meshes/DIR`, or None (a `skip`) when the shared data is absent.
pub fn shared_dir(dir: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes").join(dir);
    if p.is_dir() {
        Some(p)
    } else {
        skip(&format!(
            "{} not found (the shared organ meshes are not beside this checkout)",
            p.display()
        ));
        None
    }
}

/// `../shared/meshes/tet/NAME`, or None (a `skip`) when the shared data is absent.
pub fn shared_mesh(name: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/meshes/tet")
        .join(name);
    if p.exists() {
        Some(p)
    } else {
        skip(&format!(
            "{} not found (the shared organ meshes are not beside this checkout)",
            p.display()
        ));
        None
    }
}

/// Whether a command-line tool runs (`NAME -h`); a `skip` when it does not.
pub fn tool(name: &str) -> bool {
    let ok = Command::new(name).arg("-h").output().is_ok();
    if !ok {
        skip(&format!("`{name}` is not installed (scripts/setup.sh installs it)"));
    }
    ok
}

/// A scenario text in the paper's reading (`[model] reading = "paper"`) unless it names a
/// reading: the cases written before the continuum reading.
pub fn paper(toml: &str) -> String {
    if toml.contains("reading =") {
        toml.to_string()
    } else if toml.contains("[model]\n") {
        toml.replacen("[model]\n", "[model]\nreading = \"paper\"\n", 1)
    } else {
        format!("{toml}[model]\nreading = \"paper\"\n")
    }
}

/// A scenario from text (in the paper's reading unless it names one, `paper`), resolved
/// against a mesh already in memory.
pub fn setup(mesh: Mesh, toml: &str, dir: &Path) -> Setup {
    setup_with(mesh, toml, dir, &[])
}

/// A scenario from text with `--set KEY=VALUE` overrides, resolved against a mesh already in
/// memory.
pub fn setup_with(mesh: Mesh, toml: &str, dir: &Path, sets: &[String]) -> Setup {
    let path = dir.join("test.toml");
    let full = paper(&format!("[mesh]\nfile = \"unused.msh\"\n{toml}"));
    let full = eprop::config::set::apply(&full, sets).expect("overrides apply");
    let sc = Scenario::parse(&path, full).expect("scenario parses");
    Setup::with_mesh(sc, mesh).expect("scenario resolves")
}

pub fn sim(mesh: Mesh, toml: &str) -> Simulation {
    let dir = std::env::temp_dir();
    Simulation::new(setup(mesh, toml, &dir)).expect("simulation builds")
}

pub fn max_abs(v: &[[f64; 3]]) -> f64 {
    v.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()))
}

pub fn mpirun(n: usize, args: &[&str]) -> std::process::Output {
    mpirun_env(n, args, &[])
}

/// `mpirun` with extra environment variables for every process.
pub fn mpirun_env(n: usize, args: &[&str], env: &[(&str, &str)]) -> std::process::Output {
    Command::new("mpirun")
        .args(["-n", &n.to_string(), "--oversubscribe"])
        .arg(env!("CARGO_BIN_EXE_eprop"))
        .args(args)
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_rmaps_base_oversubscribe", "1")
        .env("RAYON_NUM_THREADS", "1")
        .envs(env.iter().copied())
        .output()
        .expect("mpirun is installed (scripts/test.sh installs openmpi-bin)")
}

/// eprop on `n` processes: one without mpirun (`serial`, one thread), more by `mpirun -n`.
pub fn processes(n: usize, args: &[&str]) -> std::process::Output {
    match n {
        1 => serial(args, 1),
        _ => mpirun(n, args),
    }
}

pub fn serial(args: &[&str], threads: usize) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_eprop"))
        .args(args)
        .env("RAYON_NUM_THREADS", threads.to_string())
        .output()
        .unwrap()
}

/// Every dataset of a group, recursively (full paths).
pub fn datasets(g: &hdf5::Group, out: &mut Vec<String>) {
    for d in g.datasets().unwrap() {
        out.push(d.name());
    }
    for sub in g.groups().unwrap() {
        datasets(&sub, out);
    }
}

pub fn bits(f: &hdf5::File, name: &str) -> Vec<u64> {
    let ds = f.dataset(name).unwrap();
    let t = ds.dtype().unwrap();
    if t.is::<f64>() {
        ds.read_raw::<f64>().unwrap().iter().map(|x| x.to_bits()).collect()
    } else if t.is::<f32>() {
        ds.read_raw::<f32>()
            .unwrap()
            .iter()
            .map(|x| x.to_bits() as u64)
            .collect()
    } else if t.is::<i64>() {
        ds.read_raw::<i64>().unwrap().iter().map(|&x| x as u64).collect()
    } else if t.is::<i32>() {
        ds.read_raw::<i32>().unwrap().iter().map(|&x| x as u64).collect()
    } else if t.is::<u8>() {
        ds.read_raw::<u8>().unwrap().iter().map(|&x| x as u64).collect()
    } else {
        panic!("{name}: unexpected type")
    }
}

/// Two series opened, and the names of their datasets, which must be the same set (sorted).
pub fn open_pair(a: &Path, b: &Path) -> (hdf5::File, hdf5::File, Vec<String>) {
    let fa = hdf5::File::open(a).unwrap();
    let fb = hdf5::File::open(b).unwrap();
    let (mut na, mut nb) = (vec![], vec![]);
    datasets(&fa, &mut na);
    datasets(&fb, &mut nb);
    na.sort();
    nb.sort();
    assert_eq!(na, nb, "different datasets");
    (fa, fb, na)
}

/// The values of a series' dataset a reader sees, as bits: a per-step dataset (its first
/// dimension may grow) has room for its run's steps, of which only the `k` complete ones are
/// read (`n` rows each for point data, one row for the tables).
pub fn counted_bits(f: &hdf5::File, name: &str, k: usize, n: usize) -> Vec<u64> {
    let v = bits(f, name);
    let ds = f.dataset(name).unwrap();
    if !ds.is_resizable() {
        return v;
    }
    let shape = ds.shape();
    let row: usize = shape[1..].iter().product();
    let per = if name.starts_with("/VTKHDF/PointData/") { n } else { 1 };
    let rows = (k * per).min(shape[0]);
    v[..rows * row].to_vec()
}

/// Every dataset of two series (the same set), compared bit for bit as a reader sees them:
/// the same count of complete steps, and the same values of every dataset in those steps
/// (`counted_bits`; a series continued to fewer steps than it first had room for keeps that
/// room).
pub fn assert_same(a: &Path, b: &Path) {
    let (fa, fb, na) = open_pair(a, b);
    assert!(na.len() >= 20, "{na:?}");
    let k = steps_complete(a);
    assert_eq!(
        k,
        steps_complete(b),
        "steps_complete of {} and {}",
        a.display(),
        b.display()
    );
    let n = fa.dataset("VTKHDF/NumberOfPoints").unwrap().read_raw::<i64>().unwrap()[0] as usize;
    for name in &na {
        let (x, y) = (
            counted_bits(&fa, name, k as usize, n),
            counted_bits(&fb, name, k as usize, n),
        );
        assert_eq!(x.len(), y.len(), "{name}");
        let diff = x.iter().zip(&y).filter(|(p, q)| p != q).count();
        assert_eq!(
            diff,
            0,
            "{name}: {diff} values differ between {} and {}",
            a.display(),
            b.display()
        );
    }
}

/// Pids of the `eprop` processes started by `parent` (mpirun).
pub fn children(parent: u32) -> Vec<i32> {
    let mut out = vec![];
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
            continue;
        };
        // pid (comm) state ppid ...
        let Some(close) = stat.rfind(')') else { continue };
        let comm = &stat[stat.find('(').unwrap_or(0) + 1..close];
        let ppid: u32 = stat[close + 2..]
            .split_whitespace()
            .nth(1)
            .and_then(|x| x.parse().ok())
            .unwrap_or(0);
        if ppid == parent && comm == "eprop" {
            out.push(pid);
        }
    }
    out
}

/// The count of complete steps of a series: its counter, the dataset `/eprop/steps_complete`
/// (in a series written before it was one, the attribute of that name).
pub fn steps_complete(h5: &Path) -> i64 {
    let f = hdf5::File::open(h5).unwrap_or_else(|e| panic!("{}: {e}", h5.display()));
    count_of(&f).unwrap_or_else(|| panic!("{}: no steps_complete", h5.display()))
}

/// The counter of an open series (None: none readable).
pub fn count_of(f: &hdf5::File) -> Option<i64> {
    let ep = f.group("eprop").ok()?;
    match ep.link_exists("steps_complete") {
        true => ep
            .dataset("steps_complete")
            .ok()?
            .read_raw::<i64>()
            .ok()?
            .first()
            .copied(),
        false => ep.attr("steps_complete").ok()?.read_scalar().ok(),
    }
}

/// Sets the count of complete steps of a series by hand (its counter and the attribute that
/// mirrors it), as an editor or a damaged disk might.
pub fn set_steps_complete(h5: &Path, k: i64) {
    let f = hdf5::File::open_rw(h5).unwrap();
    let ep = f.group("eprop").unwrap();
    if ep.link_exists("steps_complete") {
        ep.dataset("steps_complete").unwrap().write(&[k]).unwrap();
    }
    ep.attr("steps_complete").unwrap().write_scalar(&k).unwrap();
}

/// A tmpfs of `size` mounted in a temporary directory, unmounted when dropped; None where it
/// cannot be mounted: a `skip` (the full-disk cases, which return then, did not run), which
/// fails under `EPROP_REQUIRE_ALL=1`.
pub struct Tmpfs {
    dir: tempfile::TempDir,
}

impl Tmpfs {
    pub fn mount(size: &str) -> Option<Tmpfs> {
        let dir = tempfile::tempdir().unwrap();
        let st = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(dir.path())
            .output();
        match st {
            Ok(o) if o.status.success() => Some(Tmpfs { dir }),
            Ok(o) => {
                skip(&format!(
                    "cannot mount a tmpfs ({}): the full-disk cases did not run",
                    String::from_utf8_lossy(&o.stderr).trim()
                ));
                None
            }
            Err(e) => {
                skip(&format!("no `mount` ({e}): the full-disk cases did not run"));
                None
            }
        }
    }
    pub fn path(&self) -> &Path {
        self.dir.path()
    }
    /// The lines of /proc/self/mountinfo whose mount point is this tmpfs's path.
    fn mountinfo(&self) -> Vec<String> {
        let path = self.path().to_string_lossy().to_string();
        let mounts = std::fs::read_to_string("/proc/self/mountinfo").unwrap_or_default();
        mounts
            .lines()
            .filter(|l| l.split(' ').nth(4) == Some(path.as_str()))
            .map(str::to_string)
            .collect()
    }
    /// Whether a tmpfs is still mounted at the path.
    pub fn mounted(&self) -> bool {
        self.mountinfo().iter().any(|l| l.contains(" - tmpfs "))
    }
    /// What the disk is now, for a failure's message: whether the tmpfs is still mounted at its
    /// path (its line of /proc/self/mountinfo) and the free bytes there.
    pub fn state(&self) -> String {
        format!(
            "{}: {} bytes free, mounted: {:?}",
            self.path().display(),
            eprop_series::outcome::free_bytes(self.path()).unwrap_or(0),
            self.mountinfo()
        )
    }
    /// Waits (up to 30 s) until no process holds a file of this tmpfs that was deleted: such a
    /// file keeps its space until closed, so a filler sized before its release leaves far
    /// more room than asked (a full suite once saw 46 MB free where 1.8 MB were left). Returns
    /// the holders seen ("pid command: file"), printed for the test's log.
    pub fn wait_unheld(&self) -> Vec<String> {
        let dir = self.path().to_string_lossy().to_string();
        let holders = || {
            let mut out = vec![];
            for e in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
                let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
                    continue;
                };
                for fd in std::fs::read_dir(e.path().join("fd")).into_iter().flatten().flatten() {
                    let Ok(target) = std::fs::read_link(fd.path()) else {
                        continue;
                    };
                    let t = target.to_string_lossy();
                    if t.starts_with(&dir) && t.ends_with(" (deleted)") {
                        let cmd = std::fs::read_to_string(format!("/proc/{pid}/cmdline"))
                            .unwrap_or_default()
                            .replace('\0', " ");
                        out.push(format!("{pid} {}: {t}", cmd.trim()));
                    }
                }
            }
            out
        };
        let (start, mut seen) = (std::time::Instant::now(), vec![]);
        loop {
            let now = holders();
            if now.is_empty() || start.elapsed() > std::time::Duration::from_secs(30) {
                break;
            }
            for h in now {
                if !seen.contains(&h) {
                    seen.push(h);
                }
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        if !seen.is_empty() {
            eprintln!("{}: deleted files still held open: {seen:?}", self.path().display());
        }
        seen
    }
    /// Fills the file system (a filler file takes every free byte) once no deleted file holds
    /// space (`wait_unheld`).
    pub fn fill(&self) -> PathBuf {
        self.wait_unheld();
        use std::io::Write;
        let p = self.path().join("filler");
        let mut f = std::fs::OpenOptions::new().create(true).append(true).open(&p).unwrap();
        let block = vec![0u8; 4096];
        let e = loop {
            if let Err(e) = f.write_all(&block) {
                break e;
            }
        };
        // only a full disk ends the filler (ENOSPC = 28 on Linux)
        assert_eq!(e.raw_os_error(), Some(28), "filling {}: {e}", p.display());
        let _ = f.sync_all();
        p
    }
    /// Fills the file system, then frees `bytes` of the filler: the disk has about that much
    /// room (checked with statvfs).
    pub fn leave_free(&self, bytes: u64) -> PathBuf {
        let p = self.fill();
        let f = std::fs::OpenOptions::new().write(true).open(&p).unwrap();
        f.set_len(std::fs::metadata(&p).unwrap().len() - bytes).unwrap();
        f.sync_all().unwrap();
        drop(f);
        let free = eprop_series::outcome::free_bytes(self.path()).unwrap();
        assert!(
            free <= bytes + 64 * 1024,
            "{}: {free} bytes free after leaving {bytes}",
            self.path().display()
        );
        p
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(self.dir.path()).status();
    }
}

/// `eprop ARGS` on one process (`ranks` 1) or under mpirun.
pub fn command(ranks: usize, args: &[&str]) -> Command {
    let mut c = if ranks == 1 {
        Command::new(env!("CARGO_BIN_EXE_eprop"))
    } else {
        let mut c = Command::new("mpirun");
        c.args(["-n", &ranks.to_string(), "--oversubscribe"])
            .arg(env!("CARGO_BIN_EXE_eprop"));
        c
    };
    c.args(args)
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_rmaps_base_oversubscribe", "1")
        .env("RAYON_NUM_THREADS", "1");
    c
}

pub fn spawn(ranks: usize, args: &[&str]) -> Child {
    command(ranks, args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Waits for a child; a hang detector: kills it and fails after `secs` seconds.
pub fn finish(mut child: Child, secs: u64, what: &str) -> Output {
    let t = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            return child.wait_with_output().unwrap();
        }
        if t.elapsed() > Duration::from_secs(secs) {
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!(
                "{what}: still running after {secs} s (a hang): {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `eprop ARGS` to its end, under a hang detector of 180 s.
pub fn eprop(ranks: usize, args: &[&str]) -> Output {
    finish(spawn(ranks, args), 180, &args.join(" "))
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

pub fn ok(o: &Output) {
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        stderr(o)
    );
}

/// The command failed with `status` and its message holds every needle.
pub fn refused(o: &Output, status: i32, needles: &[&str]) {
    let e = stderr(o);
    assert_eq!(
        o.status.code(),
        Some(status),
        "stderr: {e}\nstdout: {}",
        String::from_utf8_lossy(&o.stdout)
    );
    for n in needles {
        assert!(e.contains(n), "`{n}` is not in: {e}");
    }
}

/// steps_complete of a file another process writes (None while it cannot be opened).
pub fn live_steps(h5: &Path) -> Option<i64> {
    count_of(&hdf5::File::open(h5).ok()?)
}

/// Waits until a running job has written `k` complete steps.
pub fn wait_for_steps(h5: &Path, k: i64, child: &mut Child) {
    let t = Instant::now();
    while live_steps(h5).unwrap_or(0) < k {
        if let Some(st) = child.try_wait().unwrap() {
            let mut err = String::new();
            if let Some(mut e) = child.stderr.take() {
                use std::io::Read;
                let _ = e.read_to_string(&mut err);
            }
            panic!("the run ended ({st}) before it wrote {k} steps: {err}");
        }
        assert!(t.elapsed() < Duration::from_secs(120), "no {k} steps after 120 s");
        std::thread::sleep(Duration::from_millis(20));
    }
}
