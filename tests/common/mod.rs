#![allow(dead_code)]
//! Helpers shared by the integration tests.

use eprop::config::{Scenario, Setup};
use eprop::simulate::Simulation;
use eprop_io::Mesh;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The log of tests that did not test what they are for (one line each: test, reason);
/// `scripts/test.sh` empties it before the tests and prints it after.
pub fn skip_log() -> PathBuf {
    Path::new(env!("CARGO_TARGET_TMPDIR")).join("eprop-skipped.log")
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

/// Like `skip`, for what a machine may lawfully lack (a CPU feature, the right to mount a
/// file system): logged and said, never a failure.
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

/// Every dataset of two files (the same set), compared bit for bit.
pub fn assert_same(a: &Path, b: &Path) {
    let (fa, fb, na) = open_pair(a, b);
    assert!(na.len() >= 20, "{na:?}");
    for name in &na {
        let (x, y) = (bits(&fa, name), bits(&fb, name));
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

/// The `/eprop` `steps_complete` attribute of a series: how many output steps it holds.
pub fn steps_complete(h5: &Path) -> i64 {
    let f = hdf5::File::open(h5).unwrap_or_else(|e| panic!("{}: {e}", h5.display()));
    f.group("eprop")
        .unwrap()
        .attr("steps_complete")
        .unwrap()
        .read_scalar()
        .unwrap()
}

/// A tmpfs of `size` mounted in a temporary directory, unmounted when dropped; None (said and
/// logged) where mounting is not permitted.
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
                unsupported(&format!(
                    "cannot mount a tmpfs ({}): the full-disk cases did not run",
                    String::from_utf8_lossy(&o.stderr).trim()
                ));
                None
            }
            Err(e) => {
                unsupported(&format!("no `mount` ({e}): the full-disk cases did not run"));
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
