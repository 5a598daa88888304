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
    let t = std::fs::read_to_string(p).unwrap();
    t.contains("shared/meshes") || t.contains("organ_meshes.sh")
}

/// Whether `../shared/meshes` is beside the checkout; when it is, the tetgen meshes of the
/// kidney, heart and prostate scenarios are made once (scripts/organ_meshes.sh).
fn shared_present() -> bool {
    static MADE: std::sync::Once = std::sync::Once::new();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let ok = root.join("../shared/meshes").is_dir();
    if !ok {
        common::skip("../shared/meshes not found (the shared organ meshes are not beside this checkout)");
        return false;
    }
    MADE.call_once(|| {
        let out = std::process::Command::new(root.join("scripts/organ_meshes.sh"))
            .output()
            .expect("scripts/organ_meshes.sh runs");
        assert!(
            out.status.success(),
            "scripts/organ_meshes.sh: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    });
    true
}

/// Makes the mesh of organs/kidney_like.toml (scripts/organ_like.py and tetgen, as its comment
/// says) when it is missing; false (a `skip`) without tetgen.
fn kidney_like_made() -> bool {
    static MADE: std::sync::Once = std::sync::Once::new();
    if !common::tool("tetgen") {
        return false;
    }
    MADE.call_once(|| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let meshes = root.join("scenarios/organs/meshes");
        if meshes.join("kidney_like.1.ele").exists() {
            return;
        }
        // made in a temporary directory and renamed into place: parallel tests see all or none
        let tmp = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
        let off = tmp.path().join("kidney_like.off");
        for (prog, args) in [
            (
                "python3",
                vec![
                    root.join("scripts/organ_like.py").to_str().unwrap().to_string(),
                    "-o".into(),
                    off.to_str().unwrap().into(),
                ],
            ),
            (
                "tetgen",
                vec!["-pq1.4".into(), "-Q".into(), off.to_str().unwrap().into()],
            ),
        ] {
            let out = std::process::Command::new(prog).args(&args).output().unwrap();
            assert!(out.status.success(), "{prog}: {}", String::from_utf8_lossy(&out.stderr));
        }
        std::fs::create_dir_all(&meshes).unwrap();
        for ext in ["node", "face", "ele"] {
            let name = format!("kidney_like.1.{ext}");
            std::fs::rename(tmp.path().join(&name), meshes.join(&name)).unwrap();
        }
    });
    true
}

/// The JSON an eprop command printed; the command must have succeeded.
fn json_of(out: std::process::Output, what: impl std::fmt::Display) -> serde_json::Value {
    assert!(out.status.success(), "{what}: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn every_shipped_scenario_passes_check() {
    let all = scenarios();
    assert!(all.len() >= 6, "{all:?}");
    for p in all {
        if needs_shared(&p) && !shared_present() {
            continue;
        }
        if std::fs::read_to_string(&p).unwrap().contains("organ_like.py") && !kidney_like_made() {
            continue;
        }
        let out = common::serial(&["check", p.to_str().unwrap(), "--json"], 1);
        let v = json_of(out, p.display());
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
                "--overwrite",
                "-o",
                h5.to_str().unwrap(),
            ];
            let out = common::processes(n, &args);
            let v = json_of(out, format!("{} on {n}", p.display()));
            let m = v["max_displacement"].as_f64().unwrap();
            assert!(m > 0.0 && m.is_finite(), "{}: max |u| = {m}", p.display());
            last.push(h5);
        }
        common::assert_same(&last[0], &last[1]);
    }
}

/// Every mesh in `../shared/meshes/tet/` runs 20 steps of a generic scenario: fixed on its
/// lowest 15 % in x, pressed at the surface node nearest the middle of its top (largest y).
#[test]
fn every_shared_tet_mesh_runs_twenty_steps() {
    let Some(dir) = common::shared_dir("tet") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap().flatten() {
        let p = e.path();
        let m = eprop_io::read_mesh(&p).unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
        let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
        for q in &m.points {
            for k in 0..3 {
                lo[k] = lo[k].min(q[k]);
                hi[k] = hi[k].max(q[k]);
            }
        }
        let x = lo[0] + 0.15 * (hi[0] - lo[0]);
        let (cx, cz) = ((lo[0] + hi[0]) / 2.0, (lo[2] + hi[2]) / 2.0);
        let s = d.path().join(format!("s{n}.toml"));
        std::fs::write(
            &s,
            format!(
                "[mesh]\nfile = {:?}\n[model]\nreading = \"paper\"\n[[fixed]]\nhalfspace = {{ point = [{x:?}, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }}\n\
                 [[load]]\nnearest = [{cx:?}, {:?}, {cz:?}]\nnormal = 1.0\n[time]\nsteps = 20\n[output]\nevery = 10\n",
                p.to_str().unwrap(),
                hi[1]
            ),
        )
        .unwrap();
        let h5 = d.path().join(format!("s{n}.h5"));
        let out = common::serial(
            &["run", s.to_str().unwrap(), "-q", "--json", "-o", h5.to_str().unwrap()],
            1,
        );
        let v = json_of(out, p.display());
        assert_eq!(v["steps"].as_u64(), Some(20), "{}", p.display());
        let u = v["max_displacement"].as_f64().unwrap();
        assert!(u > 0.0 && u.is_finite(), "{}: max |u| = {u}", p.display());
        n += 1;
    }
    assert!(n >= 5, "expected the five shared tet meshes, found {n}");
}
