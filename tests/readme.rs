//! The README's "Using it" block runs as written, line by line and in order, in a fresh copy of
//! the checkout (its tracked files, no build, no output): a line marked "needs the network"
//! (scripts/setup.sh) is not run; the test gives what it makes (the built eprop on PATH, .venv).

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The lines of the first ```sh block after "## Using it".
fn using_it() -> Vec<String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("README.md")).unwrap();
    let from = text
        .find("\n## Using it\n")
        .expect("README.md has a section \"## Using it\"");
    let rest = &text[from..];
    let start = rest.find("```sh\n").expect("\"Using it\" has a ```sh block") + 6;
    let end = rest[start..].find("```").unwrap() + start;
    rest[start..end].lines().map(String::from).collect()
}

/// The checkout's files as a fresh clone has them (tracked and new, not ignored) in `dir`.
fn fresh_copy(dir: &Path) -> bool {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let Ok(out) = Command::new("git")
        .args(["ls-files", "-z", "--cached", "--others", "--exclude-standard"])
        .current_dir(root)
        .output()
    else {
        common::skip("git is not installed: no fresh copy of the checkout");
        return false;
    };
    if !out.status.success() {
        common::skip("not a git checkout: no fresh copy of it");
        return false;
    }
    for f in out.stdout.split(|&b| b == 0).filter(|f| !f.is_empty()) {
        let rel = PathBuf::from(String::from_utf8_lossy(f).into_owned());
        let src = root.join(&rel);
        if !src.is_file() {
            continue; // deleted in the work tree
        }
        let dst = dir.join(&rel);
        std::fs::create_dir_all(dst.parent().unwrap()).unwrap();
        std::fs::copy(&src, &dst).unwrap();
    }
    true
}

#[test]
fn the_using_it_block_runs_in_a_fresh_clone() {
    let lines = using_it();
    assert!(lines.len() >= 10, "{lines:?}");
    for t in ["tetgen", "h5diff", "mpirun"] {
        if !common::tool(t) {
            return;
        }
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let venv = root.join(".venv");
    assert!(
        venv.join("bin/python").exists(),
        "{} is missing; fix: run scripts/setup.sh",
        venv.display()
    );
    let d = tempfile::tempdir().unwrap();
    let clone = d.path().join("eprop");
    if !fresh_copy(&clone) {
        return;
    }
    std::os::unix::fs::symlink(&venv, clone.join(".venv")).unwrap();
    let mut script =
        String::from("set -euo pipefail\ntrap 'echo \"README line failed (status $?): $BASH_COMMAND\" >&2' ERR\n");
    for l in &lines {
        if l.contains("needs the network") {
            common::unsupported(&format!(
                "README line not run (needs the network; the test gives the built eprop and .venv): {l}"
            ));
            continue;
        }
        script.push_str(l);
        script.push('\n');
    }
    let bin = Path::new(env!("CARGO_BIN_EXE_eprop")).parent().unwrap();
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());
    let mut child = Command::new("bash")
        .arg("-c")
        .arg(&script)
        .current_dir(&clone)
        .env("PATH", path)
        .env("RAYON_NUM_THREADS", "1")
        .env("MPLBACKEND", "Agg")
        .env_remove("EPROP")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(900);
    while child.try_wait().unwrap().is_none() {
        if Instant::now() > deadline {
            let _ = child.kill();
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "the README's \"Using it\" block failed:\n{}\n{err}",
        String::from_utf8_lossy(&out.stdout)
    );
    let o = clone.join("out");
    for f in [
        "cyl.msh",
        "box.msh",
        "kidney.1.ele",
        "kidney.vtu",
        "cyl1.h5",
        "cyl2.h5",
        "cyl4.h5",
        "kidney_like.h5",
        "kidney_like.png",
        "live.h5",
        "haptic.png",
    ] {
        assert!(o.join(f).is_file(), "the block wrote no out/{f}");
    }
    let log = std::fs::read_to_string(o.join("cyl1.log")).unwrap();
    assert!(
        log.contains("progress: step 50/100") && log.contains("progress: step 100/100"),
        "{log}"
    );
    assert_eq!(common::steps_complete(&o.join("cyl4.h5")), 101);
}
