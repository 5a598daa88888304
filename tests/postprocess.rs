//! The post-processing scripts and VTK: every script draws a non-blank PNG from a real run (one
//! and two ranks), answers --help and fails cleanly on a missing file; VTK's vtkHDFReader sees
//! every step and reads the same displacement as h5py.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn python() -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    assert!(
        p.exists(),
        "{} is missing; fix: run scripts/setup.sh (it creates the post-processing environment)",
        p.display()
    );
    p
}

fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts").join(name)
}

fn py(args: &[&str]) -> std::process::Output {
    Command::new(python())
        .args(args)
        .env("MPLBACKEND", "Agg")
        .output()
        .unwrap()
}

/// A short run of the demo cylinder; returns the series.
fn run(dir: &Path, ranks: usize) -> PathBuf {
    let mesh = dir.join("cyl.msh");
    eprop_io::write_mesh(&eprop_io::generate::cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), &mesh).unwrap();
    let sc = dir.join("s.toml");
    std::fs::write(
        &sc,
        "[mesh]\nfile = \"cyl.msh\"\n[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 0.3\n[time]\nsteps = 12\n[output]\nevery = 3\n",
    )
    .unwrap();
    let h5 = dir.join(format!("run{ranks}.h5"));
    let args = ["run", sc.to_str().unwrap(), "-q", "-o", h5.to_str().unwrap()];
    let out = if ranks == 1 {
        common::serial(&args, 1)
    } else {
        common::mpirun(ranks, &args)
    };
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    h5
}

/// The PNG exists and is not one flat colour.
fn not_blank(png: &Path) {
    assert!(png.exists(), "{} was not written", png.display());
    let out = py(&[
        "-c",
        "import sys, matplotlib.image as m; a = m.imread(sys.argv[1]); print(float(a[..., :3].std()))",
        png.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let std: f64 = String::from_utf8_lossy(&out.stdout).trim().parse().unwrap();
    assert!(std > 0.01, "{} is blank (pixel std {std})", png.display());
}

#[test]
fn every_script_draws_a_picture_from_one_and_two_ranks() {
    let d = tempfile::tempdir().unwrap();
    for ranks in [1, 2] {
        let h5 = run(d.path(), ranks);
        let h = h5.to_str().unwrap();
        let o = |n: &str| d.path().join(format!("{n}{ranks}.png"));
        for (s, png, extra) in [
            ("history.py", o("history"), vec![]),
            ("force_displacement.py", o("fd"), vec![]),
            ("force_displacement.py", o("fd-step"), vec!["--at-step", "2"]),
            ("render.py", o("render"), vec!["--scale", "3"]),
        ] {
            let mut args = vec![script(s).to_str().unwrap().to_string(), h.to_string(), "-o".into()];
            args.push(png.to_str().unwrap().to_string());
            args.extend(extra.iter().map(|x| x.to_string()));
            let a: Vec<&str> = args.iter().map(|x| x.as_str()).collect();
            let out = py(&a);
            assert!(out.status.success(), "{s}: {}", String::from_utf8_lossy(&out.stderr));
            assert!(String::from_utf8_lossy(&out.stdout).contains(png.to_str().unwrap()));
            not_blank(&png);
        }
        let out = py(&[
            script("plot_series.py").to_str().unwrap(),
            h,
            "--out-dir",
            d.path().to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        for line in String::from_utf8_lossy(&out.stdout).lines() {
            not_blank(Path::new(line.trim()));
        }
    }
}

#[test]
fn scripts_teach_and_fail_cleanly() {
    for s in [
        "history.py",
        "force_displacement.py",
        "render.py",
        "plot_series.py",
        "bench_petsc.py",
    ] {
        let out = py(&[script(s).to_str().unwrap(), "--help"]);
        assert!(out.status.success(), "{s} --help");
        assert!(
            String::from_utf8_lossy(&out.stdout).contains("example"),
            "{s}: --help shows no example"
        );
    }
    for s in ["history.py", "force_displacement.py", "render.py"] {
        let out = py(&[script(s).to_str().unwrap(), "/nonexistent.h5", "-o", "/tmp/x.png"]);
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("no such file") && !err.contains("Traceback"), "{s}: {err}");
    }
}

#[test]
fn vtk_reads_every_step_as_h5py_does() {
    let d = tempfile::tempdir().unwrap();
    for ranks in [1, 2] {
        let h5 = run(d.path(), ranks);
        let code = r#"
import sys, h5py, numpy as np, vtk
from vtk.util import numpy_support as ns
path = sys.argv[1]
f = h5py.File(path, "r")
n = int(f["VTKHDF/NumberOfPoints"][0]); done = int(f["eprop"].attrs["steps_complete"])
r = vtk.vtkHDFReader(); r.SetFileName(path); r.UpdateInformation()
assert r.GetNumberOfSteps() == done, (r.GetNumberOfSteps(), done)
for k in (0, done - 1):
    r.SetStep(k); r.Update()
    u = ns.vtk_to_numpy(r.GetOutput().GetPointData().GetArray("displacement"))
    ref = f["VTKHDF/PointData/displacement"][k * n:(k + 1) * n]
    assert np.array_equal(u, ref), k
    assert r.GetOutput().GetNumberOfCells() == int(f["VTKHDF/NumberOfCells"][0])
print("steps", done, "vtk", vtk.vtkVersion.GetVTKVersion())
"#;
        let out = py(&["-c", code, h5.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(String::from_utf8_lossy(&out.stdout).contains("steps 5"));
    }
}
