//! Every shipped scenario passes `eprop check`; the organ scenarios run 20 steps on one and two
//! ranks (skipped with a message when the shared organ meshes are not beside the checkout).

mod common;

use std::path::{Path, PathBuf};

fn scenarios() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let mut out = vec![];
    for dir in [root.clone(), root.join("organs")] {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = e.path();
            if p.extension().is_some_and(|x| x == "toml") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

fn needs_shared(p: &Path) -> bool {
    std::fs::read_to_string(p).unwrap().contains("shared/meshes")
}

fn shared_present() -> bool {
    let ok = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes").is_dir();
    if !ok {
        eprintln!("skipped: the shared organ meshes are not beside this checkout");
    }
    ok
}

#[test]
fn every_shipped_scenario_passes_check() {
    let all = scenarios();
    assert!(all.len() >= 6, "{all:?}");
    for p in all {
        if needs_shared(&p) && !shared_present() {
            continue;
        }
        let out = common::serial(&["check", p.to_str().unwrap(), "--json"], 1);
        assert!(
            out.status.success(),
            "{}: {}",
            p.display(),
            String::from_utf8_lossy(&out.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert!(v["substeps"].as_u64().unwrap() >= 1);
        assert!(v["fixed_nodes"].as_u64().unwrap() >= 1);
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(
            text.starts_with('#'),
            "{}: no comment block saying what it reproduces",
            p.display()
        );
    }
}

#[test]
fn organ_scenarios_run_on_one_and_two_ranks() {
    if !shared_present() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    for p in scenarios().into_iter().filter(|p| needs_shared(p)) {
        let mut last = vec![];
        for n in [1, 2] {
            let h5 = d.path().join(format!("o{n}.h5"));
            let args = [
                "run",
                p.to_str().unwrap(),
                "-q",
                "--steps",
                "20",
                "--json",
                "-o",
                h5.to_str().unwrap(),
            ];
            let out = if n == 1 {
                common::serial(&args, 1)
            } else {
                common::mpirun(n, &args)
            };
            assert!(
                out.status.success(),
                "{} on {n}: {}",
                p.display(),
                String::from_utf8_lossy(&out.stderr)
            );
            let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            let m = v["max_displacement"].as_f64().unwrap();
            assert!(m > 0.0 && m.is_finite(), "{}: max |u| = {m}", p.display());
            last.push(h5);
        }
        common::assert_same(&last[0], &last[1]);
    }
}
