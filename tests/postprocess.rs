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
        "[mesh]\nfile = \"cyl.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 0.3\n[time]\nsteps = 12\n[output]\nevery = 3\n",
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
        "force_indentation.py",
        "haptic_client.py",
        "eprop_series.py",
        "test_postprocess.py",
    ] {
        let out = py(&[script(s).to_str().unwrap(), "--help"]);
        assert!(out.status.success(), "{s} --help");
        assert!(
            String::from_utf8_lossy(&out.stdout).contains("example"),
            "{s}: --help shows no example"
        );
    }
    // the scenario haptic_client.py's example serves has live inputs
    let out = py(&[script("haptic_client.py").to_str().unwrap(), "--help"]);
    let help = String::from_utf8_lossy(&out.stdout);
    let served: Vec<&str> = help
        .lines()
        .filter_map(|l| l.trim().strip_prefix("eprop serve "))
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    assert_eq!(served, ["scenarios/cylinder_live.toml"], "{help}");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join(served[0])).unwrap();
    assert!(text.contains("live = true"), "{}", served[0]);
    for s in [
        "history.py",
        "force_displacement.py",
        "render.py",
        "force_indentation.py",
    ] {
        let out = py(&[script(s).to_str().unwrap(), "/nonexistent.h5", "-o", "/tmp/x.png"]);
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("no such file") && !err.contains("Traceback"), "{s}: {err}");
    }
    // negative values as written (argparse took them for options: "expected one argument")
    let out = py(&[
        script("render.py").to_str().unwrap(),
        "/nonexistent.h5",
        "-o",
        "/tmp/x.png",
        "--view",
        "-y",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no such file") && !err.contains("expected one argument"),
        "{err}"
    );
    let out = py(&[
        script("haptic_client.py").to_str().unwrap(),
        "127.0.0.1:1",
        "--from",
        "-0.00047,0,2",
        "--to",
        "-1e-3,0,2",
        "--connect-timeout",
        "0.1",
        "-o",
        "/tmp/x.png",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && !err.contains("expected one argument") && !err.contains("Traceback"),
        "{err}"
    );
}

/// The demo's indentation in `dir` (a shorter press): the scenario and its series.
fn indentation(dir: &Path, ranks: usize) -> (PathBuf, PathBuf) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    eprop_io::write_mesh(
        &eprop_io::generate::cylinder_mesh(1.0, 4.0, 3, 11).unwrap(),
        &dir.join("cylinder.msh"),
    )
    .unwrap();
    for f in ["cylinder_indent.toml", "cylinder_live.toml", "cylinder_indent_path.csv"] {
        std::fs::copy(root.join(f), dir.join(f)).unwrap();
    }
    let sc = dir.join("cylinder_indent.toml");
    let h5 = dir.join(format!("indent{ranks}.h5"));
    let args = [
        "run",
        sc.to_str().unwrap(),
        "-q",
        "-o",
        h5.to_str().unwrap(),
        "--steps",
        "90",
    ];
    let out = if ranks == 1 {
        common::serial(&args, 1)
    } else {
        common::mpirun(ranks, &args)
    };
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    (sc, h5)
}

#[test]
fn the_tool_scripts_draw_an_indentation_and_drive_a_live_session() {
    use std::io::BufRead;
    let d = tempfile::tempdir().unwrap();
    for ranks in [1, 2] {
        let (_, h5) = indentation(d.path(), ranks);
        let png = d.path().join(format!("fi{ranks}.png"));
        let out = py(&[
            script("force_indentation.py").to_str().unwrap(),
            h5.to_str().unwrap(),
            "-o",
            png.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert!(String::from_utf8_lossy(&out.stdout).contains(png.to_str().unwrap()));
        not_blank(&png);
    }
    // a run without tools is named as such
    let plain = run(d.path(), 1);
    let out = py(&[
        script("force_indentation.py").to_str().unwrap(),
        plain.to_str().unwrap(),
        "-o",
        "/tmp/x.png",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("no [[tool]]") && !err.contains("Traceback"),
        "{err}"
    );
    // the haptic client drives a served sphere in and out at 500 messages a second
    let sc = d.path().join("cylinder_live.toml");
    let mut server = Command::new(env!("CARGO_BIN_EXE_eprop"))
        .args([
            "serve",
            sc.to_str().unwrap(),
            "--listen",
            "127.0.0.1:0",
            "-q",
            "--timeout",
            "30",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = std::io::BufReader::new(server.stderr.take().unwrap()).lines();
    let addr = loop {
        let l = err.next().expect("eprop serve says where it listens").unwrap();
        if let Some(a) = l.strip_prefix("eprop serve: listening on ") {
            break a.to_string();
        }
    };
    let png = d.path().join("haptic.png");
    let csv = d.path().join("answers.csv");
    let obj = d.path().join("last.obj");
    let out = py(&[
        script("haptic_client.py").to_str().unwrap(),
        &addr,
        "--stream",
        "5",
        "--obj",
        obj.to_str().unwrap(),
        "--from",
        "1.85,0,2",
        "--to",
        "1.5,0,2",
        "--duration",
        "40",
        "--back",
        "--speed",
        "100",
        "--rate",
        "500",
        "-o",
        png.to_str().unwrap(),
        "--csv",
        csv.to_str().unwrap(),
    ]);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    let status = loop {
        if let Some(s) = server.try_wait().unwrap() {
            break s;
        }
        if std::time::Instant::now() > deadline {
            let _ = server.kill();
            panic!("eprop serve did not end");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(status.success(), "eprop serve failed");
    assert!(String::from_utf8_lossy(&out.stderr).contains("round trip p50"));
    // protocol version 3: the client counts the answers the server flagged as extrapolated
    assert!(
        String::from_utf8_lossy(&out.stderr).contains(" answers extrapolated beyond the latest physics step"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    not_blank(&png);
    let rows = std::fs::read_to_string(&csv).unwrap();
    assert!(rows.lines().count() > 300, "{} answers", rows.lines().count());
    // the sphere pressed: some answer carries a force into the cylinder (-x)
    let fx_min = rows
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(7).unwrap().parse::<f64>().unwrap())
        .fold(0.0, f64::min);
    assert!(fx_min < -0.1, "{fx_min}");
    // the flags column: 0 to 3
    assert!(rows.lines().next().unwrap().ends_with(",flags"));
    assert!(rows
        .lines()
        .skip(1)
        .all(|l| l.rsplit(',').next().unwrap().parse::<u16>().unwrap() < 4));
    // the streamed surface's last frame, as OBJ: the surface `eprop export` writes at that
    // step (f32 coordinates)
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("surface: ") && err.contains(" frames (steps "), "{err}");
    let text = std::fs::read_to_string(&obj).unwrap();
    let step: usize = text
        .lines()
        .next()
        .and_then(|l| l.strip_prefix("# eprop serve: deformed surface at step "))
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    assert!(step > 0 && step.is_multiple_of(5), "{step}");
    let prefix = d.path().join("exported");
    let o = common::serial(
        &[
            "export",
            d.path().join("cylinder_live.h5").to_str().unwrap(),
            "--surface",
            "obj",
            "--step",
            &step.to_string(),
            "-o",
            prefix.to_str().unwrap(),
        ],
        1,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let exported = std::fs::read_to_string(d.path().join(format!("exported_{step:06}.obj"))).unwrap();
    let parse = |t: &str, tag: &str| -> Vec<Vec<f64>> {
        t.lines()
            .filter_map(|l| l.strip_prefix(tag))
            .map(|l| l.split_whitespace().map(|x| x.parse().unwrap()).collect())
            .collect()
    };
    assert_eq!(parse(&text, "f "), parse(&exported, "f "));
    let (a, b) = (parse(&text, "v "), parse(&exported, "v "));
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert!(
            x.iter().zip(y).all(|(p, q)| (p - q).abs() <= 1e-6 * (1.0 + q.abs())),
            "{x:?} {y:?}"
        );
    }
    // a client without a server says so
    let out = py(&[
        script("haptic_client.py").to_str().unwrap(),
        "127.0.0.1:1",
        "--from",
        "0,0,0",
        "--to",
        "1,0,0",
        "--connect-timeout",
        "0.3",
        "-o",
        "/tmp/x.png",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("cannot connect") && !err.contains("Traceback"),
        "{err}"
    );
}

/// scripts/eprop_series.py and the scripts built on it, on a run with a load, one with a tool
/// only and one with neither (scripts/test_postprocess.py: the module's arrays and surface,
/// force_displacement.py's tool curve and refusal, history.py's lines, render.py's camera).
#[test]
fn the_python_module_reads_load_tool_and_bare_runs() {
    let d = tempfile::tempdir().unwrap();
    let load = run(d.path(), 1);
    let (_, tool) = indentation(d.path(), 1);
    let sc = d.path().join("bare.toml");
    std::fs::write(
        &sc,
        "[mesh]\nfile = \"cyl.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"bottom\"\n[time]\nsteps = 4\n",
    )
    .unwrap();
    let bare = d.path().join("bare.h5");
    let out = common::serial(&["run", sc.to_str().unwrap(), "-q", "-o", bare.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = py(&[
        script("test_postprocess.py").to_str().unwrap(),
        "--load",
        load.to_str().unwrap(),
        "--tool",
        tool.to_str().unwrap(),
        "--bare",
        bare.to_str().unwrap(),
        "--tmp",
        d.path().join("pictures").to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}{}", String::from_utf8_lossy(&out.stderr));
    for t in ["test_module", "test_force_displacement", "test_history", "test_render"] {
        assert!(text.contains(&format!("{t}: ok")), "{text}");
    }
}

#[test]
fn vtk_reads_every_step_and_the_cell_tags_as_h5py_does() {
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
    tag = ns.vtk_to_numpy(r.GetOutput().GetCellData().GetArray("tag"))
    assert np.array_equal(tag, f["VTKHDF/CellData/tag"][:]), k
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
