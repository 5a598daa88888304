//! `eprop fit`: parameters recovered from curves eprop itself made with known values (a patch
//! load's probe displacement over time, a tool's force against its indentation), on one process
//! and under `mpirun -n 2` with the same result; bad curves and parameters refused with status 1
//! and a message naming the fix.

mod common;

use common::{mpirun, serial};
use std::path::{Path, PathBuf};
use std::process::Output;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn text(o: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn read(f: &hdf5::File, name: &str) -> Vec<f64> {
    f.dataset(name)
        .unwrap_or_else(|e| panic!("{name}: {e}"))
        .read_raw::<f64>()
        .unwrap()
}

/// The cylinder pressed by a patch load, run to t = 60 with a fixed dt (the automatic dt follows
/// the fitted damping, and the discretisation with it: a residual with jumps).
fn patch_scenario(dir: &Path) -> PathBuf {
    let sc = dir.join("patch.toml");
    std::fs::write(
        &sc,
        format!(
            "[mesh]\nfile = \"{}\"\n[model]\nreading = \"paper\"\n[material]\nmass = 1.0\ndamping = 2.0\nconductivity = 0.05\n[tissue]\nyoung = 100.0\n\
[[fixed]]\ngroup = \"bottom\"\n[[load]]\npatch = {{ center = [1.0, 0.0, 2.0], radius = 0.4 }}\nnormal = 0.3\n[time]\nend = 60.0\ndt = 0.2\n",
            repo().join("scenarios/cylinder.msh").display()
        ),
    )
    .unwrap();
    sc
}

/// Runs `scenario` with `sets` and writes the curve `header` of every `every`-th step to `csv`:
/// the load probe's |u| over time, or the tool's |F| against its indentation on the loading
/// branch (indentation above 0 and deeper than every step before).
fn make_curve(scenario: &Path, sets: &[&str], csv: &Path, header: &str, every: usize) {
    make_curve_at(scenario, sets, csv, header, every, None)
}

/// `make_curve`, with |u| of the node at 0-based index `node` (output order) for the
/// displacement.
fn make_curve_at(scenario: &Path, sets: &[&str], csv: &Path, header: &str, every: usize, node: Option<usize>) {
    let h5 = csv.with_extension("h5");
    let mut args = vec!["run", scenario.to_str().unwrap(), "-q", "-o", h5.to_str().unwrap()];
    for s in sets {
        args.extend(["--set", s]);
    }
    let out = serial(&args, 1);
    assert!(out.status.success(), "{}", text(&out));
    let f = hdf5::File::open(&h5).unwrap();
    let mut rows = vec![header.to_string()];
    if header.starts_with("time") {
        let t = read(&f, "eprop/probes/time");
        let (u, at, stride) = match node {
            None => (read(&f, "eprop/probes/displacement"), 0, 3),
            // every step is written: step k's rows follow step k-1's
            Some(i) => {
                let n = f.dataset("VTKHDF/NumberOfPoints").unwrap().read_raw::<i64>().unwrap()[0] as usize;
                (read(&f, "VTKHDF/PointData/displacement"), 3 * i, 3 * n)
            }
        };
        for k in (2..t.len()).step_by(every) {
            let d = &u[stride * k + at..stride * k + at + 3];
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if t[k] <= 60.0 {
                rows.push(format!("{:?},{n:?}", t[k]));
            }
        }
    } else {
        let depth = read(&f, "eprop/tools/indentation");
        let force = read(&f, "eprop/tools/force");
        let mut deepest = f64::NEG_INFINITY;
        for (k, &d) in depth.iter().enumerate() {
            let fk = &force[3 * k..3 * k + 3];
            if d > deepest && d > 0.0 && k % every == 0 {
                let n = (fk[0] * fk[0] + fk[1] * fk[1] + fk[2] * fk[2]).sqrt();
                rows.push(format!("{d:?},{n:?}"));
            }
            deepest = deepest.max(d);
        }
    }
    assert!(rows.len() > 8, "{} rows: {rows:?}", rows.len());
    std::fs::write(csv, rows.join("\n") + "\n").unwrap();
}

fn report(prefix: &Path) -> serde_json::Value {
    let p = prefix.with_extension("json");
    serde_json::from_str(&std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))).unwrap()
}

fn value(r: &serde_json::Value, name: &str) -> f64 {
    r["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == name)
        .unwrap_or_else(|| panic!("no {name} in {r}"))["value"]
        .as_f64()
        .unwrap()
}

fn assert_recovered(r: &serde_json::Value, name: &str, truth: f64) {
    let v = value(r, name);
    assert!(
        ((v - truth) / truth).abs() < 1e-3,
        "{name}: fitted {v}, made with {truth}: {r:#}"
    );
}

/// The two fits of the tests: (curve made with damping 1.5 and young 150, fitted from starts at
/// the bounds' geometric means 122.5 and 2.0) and (a press made with young 70, fitted from 100).
fn fit_args<'a>(scenario: &'a str, csv: &'a str, prefix: &'a str, patch: bool) -> Vec<&'a str> {
    let mut a = vec!["fit", scenario, "--data", csv, "-o", prefix, "--no-plot"];
    if patch {
        a.extend(["--param", "young=30:500", "--param", "damping=0.5:8"]);
    } else {
        a.extend(["--param", "young=20:500"]);
    }
    a
}

#[test]
fn fit_recovers_young_and_damping_from_a_patch_load_displacement_over_time() {
    let d = tempfile::tempdir().unwrap();
    let sc = patch_scenario(d.path());
    let csv = d.path().join("patch.csv");
    make_curve(
        &sc,
        &["tissue.young=150.0", "material.damping=1.5"],
        &csv,
        "time,displacement",
        12,
    );
    let prefix = d.path().join("patch_fit");
    let out = serial(
        &fit_args(
            sc.to_str().unwrap(),
            csv.to_str().unwrap(),
            prefix.to_str().unwrap(),
            true,
        ),
        1,
    );
    assert!(out.status.success(), "{}", text(&out));
    let r = report(&prefix);
    assert_recovered(&r, "young", 150.0);
    assert_recovered(&r, "damping", 1.5);
    assert!(r["rms_relative"].as_f64().unwrap() < 1e-6, "{r:#}");
    assert_eq!(r["x"], "time");
    assert_eq!(r["y"], "displacement");
    // one progress line per evaluation, and the report printed
    let err = String::from_utf8_lossy(&out.stderr);
    let lines = err.lines().filter(|l| l.starts_with("fit ")).count();
    assert_eq!(lines as u64, r["evaluations"].as_u64().unwrap(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("rms residual") && stdout.contains("damping"),
        "{stdout}"
    );
    // the CSV: a row per point, the fitted column within the rms of the measured one
    let rows = std::fs::read_to_string(prefix.with_extension("csv")).unwrap();
    let data = std::fs::read_to_string(&csv).unwrap();
    assert!(
        rows.starts_with("x,measured,fitted,residual,sensitivity_young,sensitivity_damping,curve\n"),
        "{rows}"
    );
    assert_eq!(rows.lines().count(), data.lines().count());
    for (a, b) in rows.lines().skip(1).zip(data.lines().skip(1)) {
        let v: Vec<f64> = a.split(',').map(|s| s.parse().unwrap()).collect();
        let w: Vec<f64> = b.split(',').map(|s| s.parse().unwrap()).collect();
        assert_eq!((v[0], v[1]), (w[0], w[1]));
        assert!((v[2] - v[1]).abs() <= 1e-6 * v[1].abs().max(1e-3), "{a}");
    }
    // sensitivities and standard errors are reported
    for p in r["parameters"].as_array().unwrap() {
        assert!(p["sensitivity"].as_f64().unwrap() > 0.0, "{p}");
        assert!(p["standard_error"].as_f64().is_some(), "{p}");
    }
}

#[test]
fn fit_recovers_young_and_damping_from_a_node_displacement() {
    let d = tempfile::tempdir().unwrap();
    let sc = patch_scenario(d.path());
    let csv = d.path().join("node.csv");
    // node 230 of the cylinder mesh (index 229, at (0.67, 0, 2.18), beside the patch)
    make_curve_at(
        &sc,
        &["tissue.young=150.0", "material.damping=1.5"],
        &csv,
        "time,displacement",
        12,
        Some(229),
    );
    let prefix = d.path().join("node_fit");
    let mut args = fit_args(
        sc.to_str().unwrap(),
        csv.to_str().unwrap(),
        prefix.to_str().unwrap(),
        true,
    );
    args.extend(["--node", "230"]);
    let out = serial(&args, 1);
    assert!(out.status.success(), "{}", text(&out));
    let r = report(&prefix);
    assert_recovered(&r, "young", 150.0);
    assert_recovered(&r, "damping", 1.5);
    // a node the mesh does not have
    let mut args = fit_args(
        sc.to_str().unwrap(),
        csv.to_str().unwrap(),
        prefix.to_str().unwrap(),
        true,
    );
    args.extend(["--node", "99999", "--overwrite"]);
    let out = serial(&args, 1);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--node 99999: the mesh has no node with that id; fix:"));
}

#[test]
fn fit_recovers_young_from_a_tool_force_against_indentation() {
    let d = tempfile::tempdir().unwrap();
    let sc = repo().join("scenarios/cylinder_indent.toml");
    let csv = d.path().join("press.csv");
    make_curve(&sc, &["tissue.young=70.0"], &csv, "indentation,force", 3);
    let prefix = d.path().join("press_fit");
    let out = serial(
        &fit_args(
            sc.to_str().unwrap(),
            csv.to_str().unwrap(),
            prefix.to_str().unwrap(),
            false,
        ),
        1,
    );
    assert!(out.status.success(), "{}", text(&out));
    let r = report(&prefix);
    assert_recovered(&r, "young", 70.0);
    assert_eq!(r["x"], "indentation");
    assert_eq!(r["y"], "force");
    // the scenario's own output was not written by the evaluations
    assert!(!repo().join("scenarios/cylinder_indent.h5.lock").exists());
}

/// The same fits on two processes: every process runs every evaluation, and the result is the
/// one process's, value for value.
#[test]
fn fit_under_mpirun_2_gives_the_one_process_result() {
    let d = tempfile::tempdir().unwrap();
    let patch = patch_scenario(d.path());
    let press = repo().join("scenarios/cylinder_indent.toml");
    let cases = [
        (
            patch.clone(),
            "patch",
            vec!["tissue.young=150.0", "material.damping=1.5"],
            true,
            12,
            None,
        ),
        (
            patch.clone(),
            "node",
            vec!["tissue.young=150.0", "material.damping=1.5"],
            true,
            12,
            Some(229),
        ),
        (press, "press", vec!["tissue.young=70.0"], false, 3, None),
    ];
    for (sc, name, sets, two, every, node) in cases {
        let header = if two { "time,displacement" } else { "indentation,force" };
        let csv = d.path().join(format!("{name}.csv"));
        make_curve_at(&sc, &sets, &csv, header, every, node);
        let one = d.path().join(format!("{name}_one"));
        let two_ranks = d.path().join(format!("{name}_two"));
        let (s, c) = (sc.to_str().unwrap(), csv.to_str().unwrap());
        let id = node.map(|i: usize| (i + 1).to_string());
        let mut a1 = fit_args(s, c, one.to_str().unwrap(), two);
        let mut a2 = fit_args(s, c, two_ranks.to_str().unwrap(), two);
        if let Some(id) = &id {
            a1.extend(["--node", id.as_str()]);
            a2.extend(["--node", id.as_str()]);
        }
        let out = serial(&a1, 1);
        assert!(out.status.success(), "{}", text(&out));
        let out = mpirun(2, &a2);
        assert!(out.status.success(), "{name} on 2 ranks: {}", text(&out));
        let (a, b) = (report(&one), report(&two_ranks));
        assert_eq!(b["processes"], 2);
        for key in ["rms", "evaluations", "iterations"] {
            assert_eq!(a[key], b[key], "{name}: {key}");
        }
        for (p, q) in a["parameters"]
            .as_array()
            .unwrap()
            .iter()
            .zip(b["parameters"].as_array().unwrap())
        {
            assert_eq!(p["value"], q["value"], "{name}: {p} against {q}");
            assert_eq!(p["standard_error"], q["standard_error"]);
        }
        // one process prints the progress (rank 0)
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(
            err.lines().filter(|l| l.starts_with("fit ")).count() as u64,
            b["evaluations"].as_u64().unwrap(),
            "{err}"
        );
        if two {
            assert_recovered(&b, "young", 150.0);
            assert_recovered(&b, "damping", 1.5);
        } else {
            assert_recovered(&b, "young", 70.0);
        }
    }
}

/// The PNG of measured against fitted, drawn by scripts/plot_fit.py when python has matplotlib.
#[test]
fn fit_draws_the_png_or_says_why_not() {
    let d = tempfile::tempdir().unwrap();
    let sc = repo().join("scenarios/cylinder_indent.toml");
    let csv = d.path().join("press.csv");
    make_curve(&sc, &["tissue.young=70.0"], &csv, "indentation,force", 6);
    let prefix = d.path().join("press_fit");
    let (s, c, p) = (sc.to_str().unwrap(), csv.to_str().unwrap(), prefix.to_str().unwrap());
    let out = serial(&["fit", s, "--data", c, "--param", "young=20:500", "-o", p, "-q"], 1);
    assert!(out.status.success(), "{}", text(&out));
    let r = report(&prefix);
    let png = prefix.with_extension("png");
    match r["plot_note"].as_str() {
        None => {
            let bytes = std::fs::read(&png).unwrap();
            assert!(bytes.len() > 1000 && bytes.starts_with(b"\x89PNG"), "{}", png.display());
        }
        Some(note) => {
            assert!(note.starts_with("no PNG: ") && note.contains("fix:"), "{note}");
            assert!(!png.exists());
            common::skip(&format!("no matplotlib: {note}"));
        }
    }
    // the script teaches and fails cleanly
    let python = repo().join(".venv/bin/python");
    if python.is_file() {
        let script = repo().join("scripts/plot_fit.py");
        let out = std::process::Command::new(&python)
            .arg(&script)
            .arg("--help")
            .output()
            .unwrap();
        assert!(out.status.success() && String::from_utf8_lossy(&out.stdout).contains("example"));
        let out = std::process::Command::new(&python)
            .arg(&script)
            .arg("/nonexistent_fit")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains("no such file") && !err.contains("Traceback"),
            "{err}"
        );
    }
    // the report files are not replaced without --overwrite
    let again = serial(&["fit", s, "--data", c, "--param", "young=20:500", "-o", p, "-q"], 1);
    assert_eq!(again.status.code(), Some(1), "{}", text(&again));
    assert!(
        String::from_utf8_lossy(&again.stderr).contains("--overwrite"),
        "{}",
        text(&again)
    );
}

#[test]
fn bad_curves_and_parameters_are_refused_naming_the_fix() {
    let d = tempfile::tempdir().unwrap();
    let sc = patch_scenario(d.path());
    let s = sc.to_str().unwrap();
    let good = "time,displacement\n1.0,0.1\n2.0,0.2\n3.0,0.25\n";
    let refuse = |name: &str, csv: &str, params: &[&str], wants: &[&str]| {
        let f = d.path().join(format!("{name}.csv"));
        std::fs::write(&f, csv).unwrap();
        let prefix = d.path().join(format!("{name}_fit"));
        let mut args = vec![
            "fit",
            s,
            "--data",
            f.to_str().unwrap(),
            "-o",
            prefix.to_str().unwrap(),
            "--no-plot",
        ];
        for p in params {
            args.extend(["--param", p]);
        }
        let out = serial(&args, 1);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{name}: {}", text(&out));
        assert!(err.contains("fix:"), "{name}: {err}");
        for w in wants {
            assert!(err.contains(w), "{name}: wants `{w}` in: {err}");
        }
        assert!(!prefix.with_extension("json").exists(), "{name}");
    };
    refuse(
        "one_column",
        "time\n1.0\n2.0\n",
        &["young=20:500"],
        &["one_column.csv:1: the header has 1 column(s)", "two columns"],
    );
    refuse(
        "stress",
        "time,stress\n1.0,0.1\n2.0,0.2\n",
        &["young=20:500"],
        &[
            "stress.csv:1: the y column is named `stress`",
            "`force`, `displacement`, or `ux`, `uy`, `uz`",
        ],
    );
    refuse(
        "no_header",
        "1.0,0.1\n2.0,0.2\n",
        &["young=20:500"],
        &["no_header.csv:1: the first row is numbers, not a header"],
    );
    refuse(
        "bad_number",
        "# measured\ntime,displacement\n1.0,0.1\n2.0,abc\n",
        &["young=20:500"],
        &["bad_number.csv:4: `abc` is not a finite number"],
    );
    refuse(
        "unsorted",
        "time,displacement\n1.0,0.1\n3.0,0.2\n2.0,0.3\n",
        &["young=20:500"],
        &["unsorted.csv:4: x = 2 does not increase", "sort the rows by x"],
    );
    refuse(
        "one_point",
        "time,displacement\n1.0,0.1\n",
        &["young=20:500"],
        &["one_point.csv: 1 data point(s)", "at least 2 points"],
    );
    refuse(
        "too_few",
        "time,displacement\n1.0,0.1\n2.0,0.2\n",
        &["young=20:500", "damping=0.5:8"],
        &["2 points for 2 fitted parameter(s)", "more points than parameters"],
    );
    refuse(
        "unknown",
        good,
        &["yuong=20:500"],
        &[
            "--param yuong=20:500: unknown parameter `yuong`",
            "young, beta, conductivity",
        ],
    );
    refuse(
        "inverted",
        good,
        &["young=500:20"],
        &[
            "--param young=500:20: the lower bound 500 is not below the upper bound 20",
            "LO < HI",
        ],
    );
    refuse(
        "equal",
        good,
        &["young=5:5"],
        &["the lower bound 5 is not below the upper bound 5"],
    );
    refuse("no_range", good, &["young=20"], &["`20` is not LO:HI"]);
    refuse(
        "beyond",
        "time,displacement\n1.0,0.1\n2.0,0.2\n500.0,0.3\n",
        &["young=20:500"],
        &["beyond the simulated time", "a later [time] end"],
    );
    // a curve of a tool on a scenario without one
    refuse(
        "no_tool",
        "indentation,force\n0.1,0.1\n0.2,0.2\n0.3,0.25\n",
        &["young=20:500"],
        &["0 [[tool]] table(s)", "a scenario with a [[tool]]"],
    );
}

/// Reports of curves at the edges of double precision: values past 1e154 (their squares
/// overflowed: rms inf), a flat curve (rms_relative was null and plot_fit.py crashed), bounds
/// whose product underflows or overflows (the start sqrt(lo hi) was 0 or inf), and a curve x of
/// 1e300 (printed with 301 digits).
#[test]
fn fit_reports_huge_flat_and_extreme_curves_sensibly() {
    let d = tempfile::tempdir().unwrap();
    let sc = repo().join("scenarios/cylinder_indent.toml");
    let s = sc.to_str().unwrap();
    let curve = |name: &str, rows: &str| {
        let p = d.path().join(name);
        std::fs::write(&p, format!("indentation,force\n{rows}")).unwrap();
        p
    };
    let fit = |csv: &Path, param: &str, plot: bool| {
        let prefix = csv.with_file_name(format!("{}_fit", csv.file_stem().unwrap().to_str().unwrap()));
        let mut a = vec![
            "fit",
            s,
            "--data",
            csv.to_str().unwrap(),
            "--param",
            param,
            "-o",
            prefix.to_str().unwrap(),
            "-q",
        ];
        if !plot {
            a.push("--no-plot");
        }
        (serial(&a, 1), prefix)
    };
    // huge: the simulated force (about 1) is nothing beside the data; the residuals are the data
    let rows: Vec<f64> = vec![1.1e160, 1.9e160, 3.3e160, 5.5e160, 7.9e160];
    let table: String = rows
        .iter()
        .enumerate()
        .map(|(k, y)| format!("{},{y:e}\n", 0.05 * (k + 1) as f64))
        .collect();
    let (out, prefix) = fit(&curve("huge.csv", &table), "young=20:500", false);
    assert!(out.status.success(), "{}", text(&out));
    let r = report(&prefix);
    let rms = r["rms"].as_f64().expect("a finite rms");
    let want = (rows.iter().map(|y| (y / 1e160).powi(2)).sum::<f64>() / 5.0).sqrt() * 1e160;
    assert!((rms / want - 1.0).abs() < 1e-3, "rms {rms}, want about {want}: {r:#}");
    assert!(r["rms_relative"].as_f64().is_some_and(f64::is_finite), "{r:#}");
    // flat: relative to max |y|, said so, and the plot script draws it
    let (out, prefix) = fit(
        &curve("flat.csv", "0.05,0.3\n0.1,0.3\n0.15,0.3\n0.2,0.3\n0.25,0.3\n"),
        "young=20:500",
        true,
    );
    assert!(out.status.success(), "{}", text(&out));
    let r = report(&prefix);
    let rel = r["rms_relative"].as_f64().expect("rms_relative is a number");
    assert!((rel - r["rms"].as_f64().unwrap() / 0.3).abs() < 1e-12, "{r:#}");
    assert_eq!(r["relative_to"], "max |y| (a flat curve)");
    if let Some(note) = r["plot_note"].as_str() {
        assert!(note.contains("no matplotlib"), "the script failed: {note}");
    }
    // bounds whose product underflows: the start is their geometric mean, not 0
    let (out, prefix) = fit(
        &curve("tiny.csv", "0.05,0.3\n0.1,0.3\n0.15,0.3\n"),
        "young=1e-300:1e-299",
        false,
    );
    assert!(!text(&out).contains("0 must be a positive number"), "{}", text(&out));
    if out.status.success() {
        let start = report(&prefix)["parameters"][0]["start"].as_f64().unwrap();
        assert!((start / 10f64.powf(-299.5) - 1.0).abs() < 1e-9, "{start}");
    }
    let (out, _) = fit(
        &curve("vast.csv", "0.05,0.3\n0.1,0.3\n0.15,0.3\n"),
        "young=1e299:1e300",
        false,
    );
    assert!(!text(&out).contains("inf must be a positive number"), "{}", text(&out));
    // a curve x of 1e300 in the message as written
    let (out, _) = fit(&curve("far.csv", "1e299,1\n1e300,2\n"), "young=20:500", false);
    let err = text(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("the curve's x 1e299 .. 1e300 is beyond"), "{err}");
    assert!(!err.contains("000000000000"), "{err}");
}

/// The deepest step's |u| of the cylinder's surface nodes on the line x = 1, y = 0 (ids 20, 57,
/// ..., 427: every 37th), as `z,displacement` rows, and the force against the indentation, from
/// one run of the demo press.
fn press_and_profile(scenario: &Path, sets: &[&str], dir: &Path) -> (PathBuf, PathBuf) {
    let press = dir.join("press.csv");
    make_curve(scenario, sets, &press, "indentation,force", 3);
    let h5 = press.with_extension("h5");
    let f = hdf5::File::open(&h5).unwrap();
    let depth = read(&f, "eprop/tools/indentation");
    let deepest = (0..depth.len()).fold(0, |k, i| if depth[i] > depth[k] { i } else { k });
    let n = f.dataset("VTKHDF/NumberOfPoints").unwrap().read_raw::<i64>().unwrap()[0] as usize;
    let u = read(&f, "VTKHDF/PointData/displacement");
    let mut rows = vec!["z,displacement".to_string()];
    for k in 0..12 {
        let i = 19 + 37 * k; // 0-based index of node id 20 + 37 k, at z = 4 k / 11
        let d = &u[3 * n * deepest + 3 * i..3 * n * deepest + 3 * i + 3];
        rows.push(format!(
            "{:?},{:?}",
            4.0 * k as f64 / 11.0,
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        ));
    }
    let profile = dir.join("profile.csv");
    std::fs::write(&profile, rows.join("\n") + "\n").unwrap();
    (press, profile)
}

/// Two curves at once: the force against the indentation and the surface profile at the deepest
/// step. The kinematic sphere's force goes with young and (a little) with damping, the dent with
/// damping only: neither curve alone pins both, together they do (1 and 2 processes alike).
#[test]
fn fit_recovers_young_and_damping_from_a_force_and_a_profile_together() {
    let d = tempfile::tempdir().unwrap();
    let sc = repo().join("scenarios/cylinder_indent.toml");
    let sets = ["tissue.young=70.0", "material.damping=3.0", "time.dt=0.5"];
    let (press, profile) = press_and_profile(&sc, &sets, d.path());
    let line = format!("{}:x=1,y=0,weight=2", profile.display());
    let run = |prefix: &Path, ranks: usize| {
        let args = [
            "fit",
            sc.to_str().unwrap(),
            "--data",
            press.to_str().unwrap(),
            "--data",
            line.as_str(),
            "--param",
            "young=20:500",
            "--param",
            "damping=0.5:8",
            "--set",
            "time.dt=0.5",
            "-o",
            prefix.to_str().unwrap(),
            "--no-plot",
        ];
        let out = if ranks == 1 {
            serial(&args, 1)
        } else {
            mpirun(ranks, &args)
        };
        assert!(out.status.success(), "{}", text(&out));
        out
    };
    let prefix = d.path().join("both");
    let out = run(&prefix, 1);
    let r = report(&prefix);
    assert_recovered(&r, "young", 70.0);
    assert_recovered(&r, "damping", 3.0);
    let curves = r["curves"].as_array().unwrap();
    assert_eq!(curves.len(), 2, "{r:#}");
    assert_eq!(
        (curves[0]["x"].as_str(), curves[0]["y"].as_str()),
        (Some("indentation"), Some("force"))
    );
    assert_eq!(
        (curves[1]["x"].as_str(), curves[1]["y"].as_str()),
        (Some("z"), Some("displacement"))
    );
    assert_eq!(curves[1]["weight"], 2.0);
    assert_eq!(curves[1]["points"], 12);
    for c in curves {
        assert!(c["rms_relative"].as_f64().unwrap() < 1e-6, "{c}");
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("to 2 curves") && stdout.contains("curve 2"), "{stdout}");
    // the CSV: every point of both curves, with its curve
    let rows = std::fs::read_to_string(prefix.with_extension("csv")).unwrap();
    let points = std::fs::read_to_string(&press).unwrap().lines().count() - 1 + 12;
    assert_eq!(rows.lines().count(), 1 + points, "{rows}");
    assert!(rows.lines().next().unwrap().ends_with(",curve"));
    assert_eq!(rows.lines().filter(|l| l.ends_with(",2")).count(), 12, "{rows}");
    // the plot script reads a report of several curves
    let python = repo().join(".venv/bin/python");
    if python.is_file() {
        let png = d.path().join("both.png");
        let out = std::process::Command::new(&python)
            .arg(repo().join("scripts/plot_fit.py"))
            .arg(&prefix)
            .arg("-o")
            .arg(&png)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", text(&out));
        assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
    }
    // two processes: the same fit, value for value
    let two = d.path().join("both_two");
    run(&two, 2);
    let q = report(&two);
    for (a, b) in r["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .zip(q["parameters"].as_array().unwrap())
    {
        assert_eq!(a["value"], b["value"], "{a} against {b}");
    }
    assert_eq!(r["evaluations"], q["evaluations"]);
}

/// A small block in the continuum reading (SI), pressed 1.5 mm by a sphere of 5 mm.
fn block_scenario(dir: &Path) -> PathBuf {
    let mesh = dir.join("block.msh");
    let out = serial(
        &[
            "mesh",
            "box",
            "--size",
            "0.04,0.04,0.02",
            "--cells",
            "6,6,3",
            "--kind",
            "tet",
            "-o",
            mesh.to_str().unwrap(),
        ],
        1,
    );
    assert!(out.status.success(), "{}", text(&out));
    let sc = dir.join("block.toml");
    std::fs::write(
        &sc,
        "[mesh]\nfile = \"block.msh\"\nunit = \"m\"\n[model]\nreading = \"continuum\"\n[tissue]\nyoung = 5000.0\n\
[[fixed]]\ngroup = \"zmin\"\n[[tool]]\nshape = \"sphere\"\nradius = 0.005\nstart = [0.02, 0.02, 0.0252]\nvelocity = [0.0, 0.0, -0.01]\n\
[time]\nend = 0.4\n",
    )
    .unwrap();
    sc
}

/// A header's units are applied: the same press written in mm and mN, and in m and N, fits the
/// same young; a unit eprop does not know, or a unit in the paper's unit-free reading, is refused
/// with the file, the line and the fix.
#[test]
fn fit_applies_the_units_of_the_header_and_refuses_unknown_ones() {
    let d = tempfile::tempdir().unwrap();
    let sc = block_scenario(d.path());
    let si = d.path().join("si.csv");
    make_curve(&sc, &["tissue.young=3000.0"], &si, "indentation,force", 1);
    let text_si = std::fs::read_to_string(&si).unwrap();
    // the same points in mm and mN, a comment line first
    let mut mm = vec![
        "# the press of the block, in mm and mN".to_string(),
        "indentation (mm), force (mN)".to_string(),
    ];
    for l in text_si.lines().skip(1) {
        let v: Vec<f64> = l.split(',').map(|s| s.parse().unwrap()).collect();
        mm.push(format!("{:?},{:?}", v[0] * 1e3, v[1] * 1e3));
    }
    let mm_csv = d.path().join("mm.csv");
    std::fs::write(&mm_csv, mm.join("\n") + "\n").unwrap();
    let fit = |csv: &Path| {
        let prefix = csv.with_file_name(format!("{}_fit", csv.file_stem().unwrap().to_str().unwrap()));
        let out = serial(
            &[
                "fit",
                sc.to_str().unwrap(),
                "--data",
                csv.to_str().unwrap(),
                "--param",
                "young=500:50000",
                "-o",
                prefix.to_str().unwrap(),
                "--no-plot",
                "-q",
            ],
            1,
        );
        (out, prefix)
    };
    let (out, p_si) = fit(&si);
    assert!(out.status.success(), "{}", text(&out));
    let (out, p_mm) = fit(&mm_csv);
    assert!(out.status.success(), "{}", text(&out));
    let (a, b) = (report(&p_si), report(&p_mm));
    assert_recovered(&a, "young", 3000.0);
    assert_recovered(&b, "young", 3000.0);
    assert_eq!(b["curves"][0]["x_unit"], "mm");
    assert_eq!(b["curves"][0]["y_unit"], "mN");
    // the report is in the scenario's units (m, N)
    let rows = std::fs::read_to_string(p_mm.with_extension("csv")).unwrap();
    let first: Vec<f64> = rows
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .map(|s| s.parse().unwrap())
        .collect();
    let orig: Vec<f64> = text_si
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .map(|s| s.parse().unwrap())
        .collect();
    assert!(
        (first[0] - orig[0]).abs() <= 1e-12 * orig[0].abs(),
        "{first:?} {orig:?}"
    );
    // a unit it does not know: the file, the header's line and the fix
    let bad = d.path().join("inches.csv");
    std::fs::write(
        &bad,
        "# a comment\n\nindentation (in),force (N)\n0.001,0.01\n0.002,0.03\n",
    )
    .unwrap();
    let (out, prefix) = fit(&bad);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(
        err.contains("inches.csv:3: the column `indentation (in)` has the unit `in`, which eprop does not know for a length; fix: one of m, cm, mm, um"),
        "{err}"
    );
    assert!(!prefix.with_extension("json").exists());
    let bad = d.path().join("pounds.csv");
    std::fs::write(&bad, "indentation (mm),force (lbf)\n1,0.01\n2,0.03\n").unwrap();
    let (out, _) = fit(&bad);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(
        err.contains("pounds.csv:1: the column `force (lbf)` has the unit `lbf`") && err.contains("fix: one of N, mN"),
        "{err}"
    );
    // the paper's reading has no units to convert to
    let paper = repo().join("scenarios/cylinder_indent.toml");
    let curve = d.path().join("paper.csv");
    std::fs::write(&curve, "indentation (mm),force\n0.1,0.2\n0.2,0.5\n").unwrap();
    let out = serial(
        &[
            "fit",
            paper.to_str().unwrap(),
            "--data",
            curve.to_str().unwrap(),
            "--param",
            "young=20:500",
            "--no-plot",
        ],
        1,
    );
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(
        err.contains("paper.csv:1: the column `indentation (mm)` has the unit `mm`, and the scenario reads the paper's unit-free model")
            && err.contains("fix: write the header `indentation`"),
        "{err}"
    );
    // a bad --data suffix
    let out = serial(
        &[
            "fit",
            paper.to_str().unwrap(),
            "--data",
            &format!("{}:weight=-1", curve.display()),
            "--param",
            "young=20:500",
        ],
        1,
    );
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(
        err.contains("`weight=-1` is not a positive weight; fix: FILE:KEY=VALUE"),
        "{err}"
    );
}
