//! The batch scripts: scripts/eprop.slurm (its directives, the binary from EPROP or PATH, a dry
//! run through a stand-in `srun`, SIGTERM passed on to the ranks and the restart it advises; the
//! large-mesh steps: box, convert to .vtkhdf, partition check, the output continued when it
//! exists), scripts/scale_study.sh (bash -n) and
//! scripts/run_mpi.sh (--oversubscribe only for more ranks than cores, the binary from EPROP).

mod common;

use std::io::BufRead;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts").join(name)
}

/// An executable shell script `name` in `dir`.
fn stand_in(dir: &Path, name: &str, body: &str) {
    let p = dir.join(name);
    std::fs::write(&p, format!("#!/bin/bash\n{body}\n")).unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
}

/// PATH with `dir` first and without any directory that holds an `eprop`.
fn path_with(dir: &Path) -> String {
    let rest = std::env::var("PATH").unwrap_or_default();
    let mut parts = vec![dir.to_str().unwrap().to_string()];
    parts.extend(
        rest.split(':')
            .filter(|p| !Path::new(p).join("eprop").exists())
            .map(String::from),
    );
    parts.join(":")
}

fn bash_n(s: &Path) {
    let out = Command::new("bash").arg("-n").arg(s).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// A cylinder and a scenario of `steps` steps, output every `every`.
fn scenario(dir: &Path, steps: u64, every: u64) -> PathBuf {
    eprop_io::write_mesh(
        &eprop_io::generate::cylinder_mesh(1.0, 4.0, 3, 11).unwrap(),
        &dir.join("cyl.msh"),
    )
    .unwrap();
    let sc = dir.join("s.toml");
    std::fs::write(
        &sc,
        format!("[mesh]\nfile = \"cyl.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 0.3\n[time]\nsteps = {steps}\n[output]\nevery = {every}\n"),
    )
    .unwrap();
    sc
}

#[test]
fn the_slurm_script_runs_its_command_and_passes_sigterm_on() {
    let s = script("eprop.slurm");
    bash_n(&s);
    let text = std::fs::read_to_string(&s).unwrap();
    // SLURM reads #SBATCH lines only before the first command
    let first_command = text
        .lines()
        .position(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .unwrap();
    let directives: Vec<&str> = text
        .lines()
        .take(first_command)
        .filter(|l| l.starts_with("#SBATCH"))
        .collect();
    assert!(directives.contains(&"#SBATCH --signal=B:TERM@120"), "{directives:?}");
    assert!(!text.contains("target/release/eprop\" run"), "a fixed binary path");
    if Command::new("sbatch").arg("--version").output().is_ok() {
        let out = Command::new("sbatch")
            .args(["--test-only"])
            .arg(&s)
            .arg("scenarios/cylinder.toml")
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    } else {
        common::unsupported("sbatch is not installed: the job script is checked with bash -n and a stand-in srun");
    }
    let d = tempfile::tempdir().unwrap();
    let bin = d.path().join("bin");
    std::fs::create_dir(&bin).unwrap();
    // srun on one task: drop its options, run the command
    stand_in(&bin, "srun", "while [[ $1 == -* ]]; do shift; done\nexec \"$@\"");
    let path = path_with(&bin);
    let eprop = env!("CARGO_BIN_EXE_eprop");
    let job = |args: &[&str], with_eprop: bool| {
        let mut c = Command::new("bash");
        c.arg(&s).args(args).current_dir(d.path()).env("PATH", &path);
        c.env_remove("EPROP").env_remove("EPROP_MODULES");
        if with_eprop {
            c.env("EPROP", eprop);
        }
        c
    };
    // no binary: a message that says how to give one
    let out = job(&["s.toml"], false).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.code() == Some(1) && err.contains("EPROP=") && err.contains("fix:"),
        "{err}"
    );
    let out = job(&[], true).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    // EPROP_MODULES: `module load` them before the run (a stand-in `module` that notes its
    // arguments; it ends the job so that nothing else runs)
    let noted = d.path().join("module.args");
    stand_in(
        &bin,
        "module",
        &format!("printf '%s ' \"$@\" > {}; exit 7", noted.display()),
    );
    let out = job(&["s.toml"], true)
        .env("EPROP_MODULES", "gcc/13 openmpi hdf5/mpi")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(7), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(
        std::fs::read_to_string(&noted).unwrap(),
        "load gcc/13 openmpi hdf5/mpi "
    );
    std::fs::remove_file(bin.join("module")).unwrap();
    // a run to the end, with progress lines in the log
    let sc = scenario(d.path(), 12, 4);
    let h5 = d.path().join("short.h5");
    let out = job(
        &[
            sc.to_str().unwrap(),
            "-o",
            h5.to_str().unwrap(),
            "--progress-every",
            "6",
        ],
        true,
    )
    .output()
    .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("progress: step 6/12") && err.contains("progress: step 12/12"),
        "{err}"
    );
    assert_eq!(common::steps_complete(&h5), 4);
    // SIGTERM to the job script (what SLURM does at --signal=B:TERM@120): the rank stops
    // after a written step with status 3 and the restart the comment advises completes it
    let sc = scenario(d.path(), 4000, 200);
    let h5 = d.path().join("long.h5");
    let mut child = job(
        &[
            sc.to_str().unwrap(),
            "-o",
            h5.to_str().unwrap(),
            "--progress-every",
            "1",
        ],
        true,
    )
    .stderr(Stdio::piped())
    .stdout(Stdio::piped())
    .spawn()
    .unwrap();
    let mut lines = std::io::BufReader::new(child.stderr.take().unwrap()).lines();
    let mut log = String::new();
    for l in lines.by_ref() {
        let l = l.unwrap();
        log.push_str(&l);
        log.push('\n');
        if l.starts_with("progress: step 1/") {
            break;
        }
    }
    let pid = child.id() as i32;
    // SAFETY: a signal to the child this test started
    assert_eq!(unsafe { libc::kill(pid, libc::SIGTERM) }, 0);
    for l in lines {
        log.push_str(&l.unwrap());
        log.push('\n');
    }
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(3), "{log}");
    assert!(log.contains("--restart"), "{log}");
    let done = common::steps_complete(&h5);
    assert!(
        (1..21).contains(&done),
        "{done} steps of 21: the run ended before its end"
    );
    let out = job(&[sc.to_str().unwrap(), "--restart", h5.to_str().unwrap(), "-q"], true)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(common::steps_complete(&h5), 21);
}

#[test]
fn the_slurm_script_makes_the_vtkhdf_checks_the_split_and_continues_its_output() {
    let s = script("eprop.slurm");
    let d = tempfile::tempdir().unwrap();
    let bin = d.path().join("bin");
    std::fs::create_dir(&bin).unwrap();
    stand_in(&bin, "srun", "while [[ $1 == -* ]]; do shift; done\nexec \"$@\"");
    let path = path_with(&bin);
    std::fs::write(
        d.path().join("box.toml"),
        "[mesh]\nfile = \"box.vtkhdf\"\n[model]\nreading = \"paper\"\nintegrator = \"euler\"\n\
         [[fixed]]\nhalfspace = { point = [0, 0, 0.01], normal = [0, 0, -1] }\n\
         [[load]]\nnearest = [0.5, 0.5, 1.0]\nnormal = 0.05\n[time]\nsteps = 4\n[output]\nevery = 2\n",
    )
    .unwrap();
    let job = |convert: &str| {
        let mut c = Command::new("bash");
        c.arg(&s)
            .args(["box.toml", "-q"])
            .current_dir(d.path())
            .env("PATH", &path)
            .env("EPROP", env!("CARGO_BIN_EXE_eprop"))
            .env("EPROP_BOX", "4,4,4")
            .env("EPROP_CONVERT", convert)
            .env("EPROP_PARTITION_CHECK", "1")
            .env("EPROP_OUTPUT", "run.h5")
            .env_remove("EPROP_MODULES")
            .env_remove("EPROP_REQUEUE");
        c.output().unwrap()
    };
    let out = job("box.msh");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("fix:"));
    // the box, its .vtkhdf, the split of it and the run
    let out = job("box.msh box.vtkhdf");
    let (so, se) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "{se}");
    assert!(d.path().join("box.vtkhdf").exists() && !d.path().join("box.vtkhdf.part.vtkhdf").exists());
    assert!(so.contains("edge cut") && so.contains("125 nodes"), "{so}");
    assert_eq!(common::steps_complete(&d.path().join("run.h5")), 3);
    // again: the mesh is kept, the output is continued, not replaced
    let before = std::fs::metadata(d.path().join("box.vtkhdf"))
        .unwrap()
        .modified()
        .unwrap();
    let out = job("box.msh box.vtkhdf");
    let se = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{se}");
    assert!(se.contains("--restart") && !se.contains("eprop convert"), "{se}");
    assert_eq!(
        std::fs::metadata(d.path().join("box.vtkhdf"))
            .unwrap()
            .modified()
            .unwrap(),
        before
    );
    assert_eq!(common::steps_complete(&d.path().join("run.h5")), 3);
}

#[test]
fn the_scale_study_script_parses() {
    bash_n(&script("scale_study.sh"));
}

#[test]
fn run_mpi_oversubscribes_only_past_the_cores() {
    let s = script("run_mpi.sh");
    bash_n(&s);
    let d = tempfile::tempdir().unwrap();
    let bin = d.path().join("bin");
    std::fs::create_dir(&bin).unwrap();
    let args_file = d.path().join("mpirun.args");
    stand_in(
        &bin,
        "mpirun",
        &format!("printf '%s ' \"$@\" > {}", args_file.display()),
    );
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let path = path_with(&bin);
    let run = |n: usize, eprop: Option<&str>| {
        let mut c = Command::new("bash");
        c.arg(&s)
            .args(["s.toml", &n.to_string(), "-o", "x.h5"])
            .env("PATH", &path);
        c.env_remove("EPROP").env_remove("MPIRUN_OPTS");
        if let Some(e) = eprop {
            c.env("EPROP", e);
        }
        let out = c.output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        std::fs::read_to_string(&args_file).unwrap()
    };
    let eprop = env!("CARGO_BIN_EXE_eprop");
    let a = run(cores, Some(eprop));
    assert!(!a.contains("--oversubscribe"), "{a}");
    assert!(
        a.starts_with(&format!("-n {cores} {eprop} run s.toml --quiet -o x.h5")),
        "{a}"
    );
    let a = run(cores + 1, Some(eprop));
    assert!(
        a.starts_with(&format!("-n {} --oversubscribe {eprop} run", cores + 1)),
        "{a}"
    );
    // without EPROP and none on PATH: this checkout's build
    let a = run(1, None);
    let own = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/release/eprop");
    assert!(a.contains(own.to_str().unwrap()), "{a}");
    let out = Command::new("bash").arg(&s).args(["s.toml", "two"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("fix:"));
    // a real run on 2 ranks (oversubscribed only on a one-core machine)
    let sc = scenario(d.path(), 6, 3);
    let h5 = d.path().join("r.h5");
    let out = Command::new("bash")
        .arg(&s)
        .args([sc.to_str().unwrap(), "2", "-o", h5.to_str().unwrap()])
        .env("EPROP", eprop)
        .env_remove("OMPI_MCA_rmaps_base_oversubscribe")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(common::steps_complete(&h5), 3);
}
