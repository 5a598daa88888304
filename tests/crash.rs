//! Crashes and damage: a kill at any write of a commit (SIGKILL injected by strace at every
//! pwrite64 of one commit, on 1 and 2 ranks) leaves a series whose `--restart` is bit for bit
//! the uninterrupted run; a disk filled by another process while one process commits keeps
//! every counted step readable and the restart completes the run; every reader of a series
//! (export, restart, the Python module and the plots through it) refuses a damaged header
//! before it allocates from it; a test that cannot mount its disk fails where every test must
//! run.

mod common;

use common::{assert_same, eprop, finish, ok, refused, spawn, stderr, steps_complete, wait_for_steps, Tmpfs};
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

const CYL: &str = "[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 0.3\n";

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The cylinder (`cyl.msh`, made once) and a scenario `NAME` of `steps` steps, each an output
/// step, with `output` lines added to its `[output]` table.
fn scenario(dir: &Path, name: &str, steps: u64, output: &str) -> PathBuf {
    let mesh = dir.join("cyl.msh");
    if !mesh.exists() {
        eprop_io::write_mesh(&eprop_io::generate::cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), &mesh).unwrap();
    }
    let sc = dir.join(name);
    let text = format!("[mesh]\nfile = \"cyl.msh\"\n{CYL}[time]\nsteps = {steps}\n[output]\nevery = 1\n{output}");
    std::fs::write(&sc, common::paper(&text)).unwrap();
    sc
}

/// `eprop ARGS` on `ranks` processes (mpirun's MPMD form for more than one), rank `traced`
/// under `strace STRACE`.
fn traced(ranks: usize, traced: usize, args: &[&str], strace: &[String]) -> Command {
    let eprop = env!("CARGO_BIN_EXE_eprop");
    let mut c = match ranks {
        1 => {
            let mut c = Command::new("strace");
            c.args(strace).arg(eprop).args(args);
            c
        }
        _ => {
            let mut c = Command::new("mpirun");
            c.arg("--oversubscribe");
            for r in 0..ranks {
                if r > 0 {
                    c.arg(":");
                }
                c.args(["-n", "1"]);
                if r == traced {
                    c.arg("strace").args(strace);
                }
                c.arg(eprop).args(args);
            }
            c
        }
    };
    c.env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_rmaps_base_oversubscribe", "1")
        .env("RAYON_NUM_THREADS", "1");
    c
}

/// The pwrite64 calls of rank `rank`'s process in a run: at each sync (fsync, fdatasync),
/// how many it had made, and how many in all. Strace counts an injection's `when=N` per
/// thread: every pwrite64 must come from one thread.
fn writes_of(ranks: usize, rank: usize, args: &[&str], dir: &Path) -> (Vec<usize>, usize) {
    let log = dir.join(format!("trace{ranks}.{rank}"));
    let strace: Vec<String> = ["-f", "-o", s(&log), "-e", "trace=pwrite64,fsync,fdatasync"]
        .map(String::from)
        .to_vec();
    let o = traced(ranks, rank, args, &strace).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&log).unwrap();
    let (mut syncs, mut n, mut writers) = (vec![], 0, std::collections::BTreeSet::new());
    for line in text.lines() {
        let pid = line.split_whitespace().next().unwrap_or("");
        if line.contains(" pwrite64(") {
            n += 1;
            writers.insert(pid.to_string());
        } else if line.contains(" fsync(") || line.contains(" fdatasync(") {
            syncs.push(n);
        }
    }
    assert_eq!(writers.len(), 1, "pwrite64 from several threads: {writers:?}");
    (syncs, n)
}

/// Every count of the series agrees: the counter, its attribute, `NSteps` and the extent of
/// `Values` (which VTK reads as `NSteps` values).
fn mirrors_agree(h5: &Path) {
    let f = hdf5::File::open(h5).unwrap();
    let k = common::count_of(&f).unwrap();
    let attr: i64 = f
        .group("eprop")
        .unwrap()
        .attr("steps_complete")
        .unwrap()
        .read_scalar()
        .unwrap();
    let ns: i64 = f
        .group("VTKHDF/Steps")
        .unwrap()
        .attr("NSteps")
        .unwrap()
        .read_scalar()
        .unwrap();
    let values = f.dataset("VTKHDF/Steps/Values").unwrap().shape()[0] as i64;
    assert_eq!((attr, ns, values), (k, k, k), "{}", h5.display());
}

/// Kills rank `rank` of a `ranks`-process run at each of its pwrite64 calls from `from` to
/// `to` (strace), restarts the series each time on `ranks` processes, and compares it with
/// `whole`; returns how often each count of complete steps was found after the kill.
fn kill_at_each_write(
    dir: &Path,
    sc: &Path,
    whole: &Path,
    (ranks, rank): (usize, usize),
    (from, to): (usize, usize),
) -> std::collections::BTreeMap<i64, usize> {
    let h5 = dir.join(format!("killed{ranks}.h5"));
    let mut found = std::collections::BTreeMap::new();
    for n in from..=to {
        let _ = std::fs::remove_file(&h5);
        let inject = format!("inject=pwrite64:signal=SIGKILL:when={n}");
        let strace: Vec<String> = ["-f", "-o", "/dev/null", "-e", "trace=pwrite64", "-e", &inject]
            .map(String::from)
            .to_vec();
        let args = ["run", s(sc), "-q", "-o", s(&h5), "--overwrite"];
        let o = traced(ranks, rank, &args, &strace).output().unwrap();
        let what = format!("{ranks} rank(s), rank {rank} killed at its pwrite64 number {n}");
        assert!(
            o.status.signal() == Some(9) || (ranks > 1 && !o.status.success()),
            "{what}: not killed ({:?}): {}",
            o.status,
            String::from_utf8_lossy(&o.stderr)
        );
        *found.entry(steps_complete(&h5)).or_insert(0) += 1;
        let o = eprop(ranks, &["run", s(sc), "-q", "--restart", s(&h5)]);
        assert!(o.status.success(), "{what}: the restart failed: {}", stderr(&o));
        assert_same(whole, &h5);
        mirrors_agree(&h5);
    }
    found
}

/// The pwrite64 calls of output step `step`'s append and commit on one rank: after the sync
/// that ended the commit before, to the one that ends it (the last commit: to the last write,
/// the close's included). Every output step is a commit of two syncs (`flush = 0`); a sync
/// may come before them (the creation's, under MPI-IO).
fn commit_writes((syncs, total): &(Vec<usize>, usize), commits: usize, step: usize) -> (usize, usize) {
    let first = syncs.len() - 2 * commits;
    let end = |j: usize| syncs[first + 2 * j + 1];
    let to = if step + 1 == commits { *total } else { end(step) };
    (end(step - 1) + 1, to)
}

#[test]
fn a_kill_at_any_write_of_a_commit_leaves_a_series_the_restart_completes_bit_for_bit() {
    if !common::tool("strace") {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let steps = 8;
    let sc = scenario(dir, "s.toml", steps, "flush = 0\n");
    let whole = dir.join("whole.h5");
    ok(&eprop(1, &["run", s(&sc), "-q", "-o", s(&whole)]));
    mirrors_agree(&whole);
    let commits = steps as usize + 1;
    // one process: a commit in the middle of the run, and the last with the file's close
    let t = dir.join("t.h5");
    let args = ["run", s(&sc), "-q", "-o", s(&t), "--overwrite"];
    let w = writes_of(1, 0, &args, dir);
    for step in [steps as usize / 2, steps as usize] {
        let (from, to) = commit_writes(&w, commits, step);
        assert!(to - from >= 10, "{from}..{to}");
        let found = kill_at_each_write(dir, &sc, &whole, (1, 0), (from, to));
        println!("1 rank, output step {step}: pwrite64 {from}..={to}, all bit for bit; counts found: {found:?}");
        // a kill before the counter's write (the commit's last) leaves the commit before
        assert!(found.contains_key(&(step as i64)), "{found:?}");
        assert!(
            found.keys().all(|&k| k == step as i64 || k == step as i64 + 1),
            "{found:?}"
        );
    }
    // two processes, each killed in turn at every write of a commit in the middle
    for rank in [0, 1] {
        let w = writes_of(2, rank, &args, dir);
        let (from, to) = commit_writes(&w, commits, steps as usize / 2);
        assert!(to >= from, "{from}..{to}");
        let found = kill_at_each_write(dir, &sc, &whole, (2, rank), (from, to));
        println!("2 ranks, rank {rank} killed, output step {}: pwrite64 {from}..={to}, all bit for bit; counts found: {found:?}", steps / 2);
    }
}

/// Every step the counter names is readable, and finite, in u, v and phi.
fn counted_steps_readable(h5: &Path) -> i64 {
    let k = steps_complete(h5);
    assert!(k >= 1, "{}: no complete step", h5.display());
    for j in 0..k as usize {
        for name in ["displacement", "velocity", "potential"] {
            let v = eprop_series::vtkhdf::read_step(h5, name, j)
                .unwrap_or_else(|e| panic!("{}: step {j} of {k} is unreadable: {e:#}", h5.display()));
            assert!(v.iter().all(|x| x.is_finite()), "step {j}: {name} is not finite");
        }
    }
    k
}

#[test]
fn a_disk_filled_by_another_process_during_a_commit_keeps_every_counted_step_and_the_restart_completes() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // slow steps (many substeps): several seconds for the run even on a fast machine, so
    // that the filler lands mid-run (the test checks that it did)
    let sc = scenario(dir, "s.toml", 800, "");
    let text = std::fs::read_to_string(&sc).unwrap();
    std::fs::write(&sc, text.replace("steps = 800\n", "steps = 800\nh = 0.0004\n")).unwrap();
    let whole = dir.join("whole.h5");
    ok(&eprop(1, &["run", s(&sc), "-q", "-o", s(&whole)]));
    // 28 MiB of output: a disk the run fits on, and after the filler is gone, room for the
    // rest of the run besides what the stopped run wrote (a restart's estimate counts no
    // space the file holds)
    let Some(disk) = Tmpfs::mount("64m") else { return };
    // the filler comes at once after the first commit, or a little later, while steps are
    // written and committed (every second by default)
    for (i, wait) in [0u64, 500, 1500].into_iter().enumerate() {
        let h5 = disk.path().join(format!("o{i}.h5"));
        let mut job = spawn(1, &["run", s(&sc), "-q", "-o", s(&h5)]);
        wait_for_steps(&h5, 1, &mut job);
        std::thread::sleep(Duration::from_millis(wait));
        assert!(
            job.try_wait().unwrap().is_none(),
            "the run ended within {wait} ms of its first commit, before the disk was filled: \
             make its steps slower (h)"
        );
        let filler = disk.fill();
        let o = finish(job, 180, "the run on a full disk");
        refused(&o, 4, &["complete output steps", "fix: free space", "--restart"]);
        let k = counted_steps_readable(&h5);
        mirrors_agree(&h5);
        std::fs::remove_file(&filler).unwrap();
        let o = eprop(1, &["run", s(&sc), "-q", "--restart", s(&h5)]);
        assert!(
            o.status.success(),
            "filled after {wait} ms ({k} steps counted): {}",
            stderr(&o)
        );
        assert_same(&whole, &h5);
        std::fs::remove_file(&h5).unwrap();
        println!("filled {wait} ms after the first commit: {k} steps counted, all readable, restart bit for bit");
    }
}

/// The post-processing environment's python (scripts/setup.sh makes it), or None (a skip).
fn python() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    if p.exists() {
        Some(p)
    } else {
        common::skip(&format!("{} is missing (scripts/setup.sh makes it)", p.display()));
        None
    }
}

/// A copy of `h5` named `name`, damaged by `damage`.
fn damaged(h5: &Path, name: &str, damage: impl FnOnce(&Path)) -> PathBuf {
    let p = h5.with_file_name(name);
    std::fs::copy(h5, &p).unwrap();
    damage(&p);
    p
}

#[test]
fn every_reader_refuses_a_damaged_header_before_it_allocates() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = scenario(dir, "s.toml", 4, "");
    let h5 = dir.join("s.h5");
    ok(&eprop(1, &["run", s(&sc), "-q", "-o", s(&h5)]));
    let count = |k: i64| move |p: &Path| common::set_steps_complete(p, k);
    let cases = [
        damaged(&h5, "k12.h5", count(1_000_000_000_000)),
        damaged(&h5, "k8.h5", count(100_000_000)),
        damaged(&h5, "kneg.h5", count(-3)),
        damaged(&h5, "n0.h5", |p| {
            let f = hdf5::File::open_rw(p).unwrap();
            f.dataset("VTKHDF/NumberOfPoints").unwrap().write(&[0i64]).unwrap();
        }),
        // a series written before the counter was a dataset: its attribute
        damaged(&h5, "old.h5", |p| {
            let f = hdf5::File::open_rw(p).unwrap();
            let ep = f.group("eprop").unwrap();
            if ep.link_exists("steps_complete") {
                ep.unlink("steps_complete").unwrap();
            }
            drop((ep, f));
            common::set_steps_complete(p, 1_000_000_000_000);
        }),
    ];
    let py = python();
    for case in &cases {
        let name = case.file_name().unwrap().to_string_lossy().to_string();
        // export: refused at once, nothing written
        let t = Instant::now();
        let prefix = dir.join(format!("x_{name}"));
        let o = eprop(1, &["export", s(case), "-o", s(&prefix)]);
        refused(&o, 1, &[&name, "a damaged series", "fix:"]);
        assert!(
            t.elapsed() < Duration::from_secs(20),
            "{name}: export took {:?}",
            t.elapsed()
        );
        assert!(!dir.join(format!("x_{name}_000000.obj")).exists());
        // the library's readers
        let e = eprop_series::vtkhdf::read_mesh(case).unwrap_err().to_string();
        assert!(e.contains("a damaged series") && e.contains("fix:"), "{e}");
        assert!(eprop_series::vtkhdf::read_step(case, "displacement", 0).is_err());
        // restart
        let o = eprop(1, &["run", s(&sc), "-q", "--restart", s(case)]);
        assert_eq!(o.status.code(), Some(1), "{name}: {}", stderr(&o));
        // the Python module, and the plots through it
        if let Some(py) = &py {
            for script in ["eprop_series.py", "plot_series.py"] {
                let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts").join(script);
                let o = Command::new(py)
                    .arg(&path)
                    .arg(case)
                    .env("MPLBACKEND", "Agg")
                    .output()
                    .unwrap();
                let e = stderr(&o);
                assert!(!o.status.success(), "{script} {name}: {e}");
                assert!(
                    e.contains("a damaged series") && e.contains("fix:") && !e.contains("Traceback"),
                    "{script} {name}: {e}"
                );
            }
        }
    }
    // the undamaged series is read by all of them
    ok(&eprop(1, &["export", s(&h5), "-o", s(&dir.join("good"))]));
    assert!(dir.join("good_000004.obj").exists());
}

/// A test that cannot mount its tmpfs returns having tested nothing: under
/// `EPROP_REQUIRE_ALL=1` (CI) that is a failure, as every skip is. Shown by running the probe
/// below with a `mount` that always fails.
#[test]
fn a_tmpfs_that_cannot_be_mounted_fails_the_test_where_everything_must_run() {
    let d = tempfile::tempdir().unwrap();
    let mount = d.path().join("mount");
    std::fs::write(&mount, "#!/bin/sh\necho 'mount: only root can do that' >&2\nexit 32\n").unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&mount, std::fs::Permissions::from_mode(0o755)).unwrap();
    let path = format!("{}:{}", d.path().display(), std::env::var("PATH").unwrap_or_default());
    let probe = |require: &str| {
        Command::new(std::env::current_exe().unwrap())
            .args(["--exact", "tmpfs_probe", "--include-ignored", "--nocapture"])
            .env("PATH", &path)
            .env("EPROP_REQUIRE_ALL", require)
            .env("EPROP_SKIP_LOG", d.path().join("skipped.log"))
            .output()
            .unwrap()
    };
    let o = probe("1");
    let out = String::from_utf8_lossy(&o.stdout).to_string() + &stderr(&o);
    assert!(
        !o.status.success(),
        "a test without its tmpfs passed under EPROP_REQUIRE_ALL=1: {out}"
    );
    assert!(
        out.contains("cannot mount a tmpfs") && out.contains("EPROP_REQUIRE_ALL=1"),
        "{out}"
    );
    // elsewhere it is a skip, logged
    let o = probe("0");
    assert!(o.status.success(), "{}", stderr(&o));
    let log = std::fs::read_to_string(d.path().join("skipped.log")).unwrap();
    assert!(log.contains("tmpfs_probe: cannot mount a tmpfs"), "{log}");
}

#[test]
#[ignore = "a probe run by a_tmpfs_that_cannot_be_mounted_fails_the_test_where_everything_must_run"]
fn tmpfs_probe() {
    let Some(_disk) = Tmpfs::mount("1m") else { return };
    panic!("the tmpfs was mounted by a `mount` that always fails");
}
