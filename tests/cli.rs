//! The `eprop` binary end to end: a run writes a series that reads back with the values
//! computed in memory; bad input fails cleanly with a message that names the problem.

mod common;

use std::path::Path;
use std::process::Command;

fn eprop(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_eprop")).args(args).output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

const SCENARIO: &str = "[mesh]\nfile = \"cyl.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 1.0\n[time]\nsteps = 6\n[output]\nfile = \"out.h5\"\nevery = 2\n";

fn workdir(name: &str) -> tempfile::TempDir {
    let d = tempfile::Builder::new().prefix(name).tempdir().unwrap();
    let (ok, _, err) = eprop(&["mesh", "cylinder", "-o", d.path().join("cyl.msh").to_str().unwrap()]);
    assert!(ok, "{err}");
    d
}

#[test]
fn output_reads_back_with_the_values_computed() {
    let d = workdir("roundtrip");
    let sc = d.path().join("s.toml");
    std::fs::write(&sc, SCENARIO).unwrap();
    let (ok, out, err) = eprop(&["run", sc.to_str().unwrap(), "--quiet"]);
    assert!(ok, "{err}");
    assert!(out.contains("max |u|"), "{out}");
    // the same run in memory
    let mut s = eprop::simulate::Simulation::new(
        eprop::config::Setup::new(eprop::config::Scenario::load(&sc).unwrap()).unwrap(),
    )
    .unwrap();
    let h5 = d.path().join("out.h5");
    let mut k = 0;
    let check = |s: &eprop::simulate::Simulation, k: usize| {
        let u = eprop_series::vtkhdf::read_step(&h5, "displacement", k).unwrap();
        let p = eprop_series::vtkhdf::read_step(&h5, "potential", k).unwrap();
        let e = eprop_series::vtkhdf::read_step(&h5, "energy", k).unwrap();
        assert_eq!(u, s.in_output_order(s.u()), "displacement at output step {k}");
        assert_eq!(p, s.in_output_order(s.phi()), "potential at output step {k}");
        assert_eq!(e.len(), s.u().len());
    };
    check(&s, k);
    while !s.done() {
        s.advance().unwrap();
        if s.step().is_multiple_of(2) {
            k += 1;
            check(&s, k);
        }
    }
    assert!(
        eprop_series::vtkhdf::read_step(&h5, "displacement", k + 1).is_err(),
        "more steps than written"
    );
}

fn expect_failure(dir: &Path, scenario: &str, needles: &[&str]) {
    let sc = dir.join("bad.toml");
    std::fs::write(&sc, scenario).unwrap();
    let (ok, _, err) = eprop(&["run", sc.to_str().unwrap(), "--quiet"]);
    assert!(!ok, "a bad scenario ran: {scenario}");
    assert!(!err.contains("panicked"), "panic: {err}");
    for n in needles {
        assert!(err.contains(n), "message `{err}` lacks `{n}`");
    }
    assert!(
        err.contains("bad.toml") || err.contains(".msh") || err.contains(".h5"),
        "message names no file: {err}"
    );
    assert!(err.contains("fix:"), "message gives no fix: {err}");
}

#[test]
fn bad_scenarios_fail_cleanly() {
    let d = workdir("bad");
    let p = d.path();
    expect_failure(
        p,
        &SCENARIO.replace("cyl.msh", "missing.msh"),
        &["missing.msh", "no such mesh file"],
    );
    expect_failure(
        p,
        &SCENARIO.replace("[time]\n", "[time]\nstepz = 3\n"),
        &["unknown field", "stepz", "bad.toml:"],
    );
    expect_failure(
        p,
        &format!("{SCENARIO}[material]\nmass = -1.0\n"),
        &["mass", "positive", "bad.toml:"],
    );
    expect_failure(p, &format!("{SCENARIO}[material]\nmass = 0.0\n"), &["mass"]);
    expect_failure(
        p,
        &SCENARIO.replace("nearest = [1.0, 0.0, 2.0]", "nearest = [0.0, 0.0, 0.0]"),
        &["fixed set"],
    );
    expect_failure(p, &SCENARIO.replace("steps = 6", "steps = \"six\""), &["bad.toml:"]);
    expect_failure(
        p,
        &SCENARIO.replace("group = \"bottom\"", "group = \"nowhere\""),
        &["nowhere", "known groups"],
    );
    expect_failure(
        p,
        &format!("{SCENARIO}[material]\nconductivity = [0.1, -0.1, 0.1]\n"),
        &["conductivity", "positive definite"],
    );
    expect_failure(
        p,
        &SCENARIO.replace("steps = 6", "steps = 6\ndt = 100.0"),
        &["dt", "stability bound"],
    );
    expect_failure(
        p,
        &SCENARIO.replace("out.h5", "no/such/dir/out.h5"),
        &["output directory"],
    );
}

#[test]
fn every_kind_of_bad_scenario_is_named() {
    let d = workdir("bad2");
    let p = d.path();
    let with = |extra: &str| format!("{SCENARIO}{extra}");
    let cases: Vec<(String, Vec<&str>)> = vec![
        (with("[material]\ndamping = -1.0\n"), vec!["damping", "zero or positive"]),
        (with("[material]\nmass = nan\n"), vec!["mass"]),
        (SCENARIO.replace("normal = 1.0", "normal = nan"), vec!["normal", "finite"]),
        (SCENARIO.replace("steps = 6", "steps = 6\nh = 50.0"), vec!["h = 50", "stability bound"]),
        (
            with("[material]\nconductivity = { diagonal = [0.1, 0.1, 0.1], axes = [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]] }\n"),
            vec!["conductivity", "orthonormal"],
        ),
        (
            with("[[material.region]]\nbox = [[10.0, 10.0, 10.0], [11.0, 11.0, 11.0]]\nmass = 2.0\n"),
            vec!["region", "holds no node"],
        ),
        (
            SCENARIO.replace("nearest = [1.0, 0.0, 2.0]", "patch = { center = [9.0, 9.0, 9.0], radius = 0.1 }"),
            vec!["patch", "no surface node"],
        ),
        (
            SCENARIO.replace("nearest = [1.0, 0.0, 2.0]", "patch = { center = [0.0, 0.0, 0.0], radius = 0.5 }"),
            vec!["fixed set"],
        ),
        (
            SCENARIO.replace("normal = 1.0", "normal = 1.0\nramp = [[1.0, 0.0], [0.5, 1.0]]"),
            vec!["ramp", "increasing"],
        ),
        (SCENARIO.replace("every = 2", "every = 2\nfields = []"), vec!["fields", "empty"]),
        (SCENARIO.replace("every = 2", "every = 2\nfields = [\"strain\"]"), vec!["strain", "not a field"]),
        (SCENARIO.replace("every = 2", "every = 2\nprecision = \"float16\""), vec!["precision"]),
        (SCENARIO.replace("every = 2", "every = 2\ncompression = 12"), vec!["compression"]),
        (SCENARIO.replace("every = 2", "every = 0"), vec!["every", "at least 1"]),
        (
            SCENARIO.replace("[model]\n", "[model]\nscheme = \"magic\"\n"),
            vec!["scheme", "compact"],
        ),
        (
            SCENARIO.replace("[model]\n", "[model]\noperator_precision = \"half\"\n"),
            vec!["operator_precision"],
        ),
        (with("[tissue]\nyoung = 0.0\n"), vec!["young"]),
        (SCENARIO.replace("[[fixed]]\ngroup = \"bottom\"\n", ""), vec!["no [[fixed]] set"]),
        (SCENARIO.replace("steps = 6", "end = -1.0"), vec!["end", "positive"]),
        (SCENARIO.replace("nearest = [1.0, 0.0, 2.0]", "node = 999999"), vec!["999999", "not in the mesh"]),
        (with("[material]\nconductivity = \"high\"\n"), vec!["bad.toml:"]),
        (SCENARIO.replace("[time]", "[times]"), vec!["bad.toml:"]),
    ];
    assert!(cases.len() >= 20);
    for (text, needles) in &cases {
        expect_failure(p, text, needles);
    }
}

#[test]
fn each_piece_of_the_mesh_needs_a_fixed_node() {
    let d = workdir("pieces");
    // two cylinders side by side in one file; only the first one's bottom is fixed
    let mut m = eprop_io::generate::cylinder_mesh(1.0, 4.0, 3, 11).unwrap();
    let b = eprop_io::generate::cylinder_mesh(1.0, 4.0, 3, 11).unwrap();
    let off = m.n_nodes() as u32;
    let id0 = m.node_ids.iter().max().unwrap() + 1;
    m.points.extend(b.points.iter().map(|p| [p[0] + 5.0, p[1], p[2]]));
    m.node_ids.extend(b.node_ids.iter().map(|i| i + id0));
    for c in 0..b.n_cells() {
        let nodes: Vec<u32> = b.cell(c).iter().map(|&v| v + off).collect();
        m.push_cell(b.kinds[c], &nodes, b.cell_tags[c]);
    }
    eprop_io::write_mesh(&m, &d.path().join("two.msh")).unwrap();
    let text = SCENARIO
        .replace("cyl.msh", "two.msh")
        .replace("group = \"bottom\"", "box = [[-2.0, -2.0, -0.1], [2.0, 2.0, 0.1]]");
    expect_failure(d.path(), &text, &["separate pieces", "fixed", "fix:"]);
}

#[test]
fn info_reports_the_geometry_checks() {
    let d = workdir("info");
    let (ok, out, err) = eprop(&["info", d.path().join("cyl.msh").to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["nodes"], 444);
    let (vol, sum) = (v["volume"].as_f64().unwrap(), v["control_volume_sum"].as_f64().unwrap());
    assert!(((vol - sum) / vol).abs() < 1e-12);
    assert!(v["max_closure_error"].as_f64().unwrap() < 1e-12);
    assert!(v["stable_h_r005"].as_f64().unwrap() > 0.0);
    let faces = v["boundary_faces"].as_u64().unwrap();
    assert!(faces > 0 && v["surface_facets"].as_u64().unwrap() > 0, "{out}");
    // a .vtk of volume cells only (as other tools write them): info reports the boundary
    // faces it finds (two tetrahedra sharing a face: 6 boundary faces)
    let vtk = d.path().join("two.vtk");
    std::fs::write(
        &vtk,
        "# vtk DataFile Version 2.0\ntwo tets\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 5 double\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n0 0 -1\nCELLS 2 10\n4 0 1 2 3\n4 0 2 1 4\nCELL_TYPES 2\n10\n10\n",
    )
    .unwrap();
    let (ok, out, err) = eprop(&["info", vtk.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(
        out.contains("surface facets   none stored in the file; 6 boundary faces found"),
        "{out}"
    );
    let (ok, out, _) = eprop(&["info", d.path().join("cyl.msh").to_str().unwrap()]);
    // a good mesh: nothing to repair, and no advice to
    assert!(
        out.contains("(no cell needs repair") && !out.contains("repair the cells"),
        "{out}"
    );
    assert!(
        ok && out.contains(&format!("surface facets   504 stored; {faces} boundary faces found")),
        "{out}"
    );
    let (ok, _, err) = eprop(&["info", "/nonexistent/x.msh"]);
    assert!(!ok && err.contains("no such mesh file"));
}

#[test]
fn gmsh_versions_read_alike() {
    // the same tetrahedron written in formats 1, 2.2 and 4.1
    let v1 =
        "$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n$ELM\n2\n1 4 7 1 4 1 2 3 4\n2 2 3 3 3 1 2 3\n$ENDELM\n";
    let v2 = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$PhysicalNames\n2\n2 3 \"base\"\n3 7 \"tissue\"\n$EndPhysicalNames\n$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n$Elements\n2\n1 4 2 7 1 1 2 3 4\n2 2 2 3 3 1 2 3\n$EndElements\n";
    let v4 = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$PhysicalNames\n2\n2 3 \"base\"\n3 7 \"tissue\"\n$EndPhysicalNames\n$Entities\n0 0 1 1\n1 0 0 0 1 1 0 1 3 0\n1 0 0 0 1 1 1 1 7 0\n$EndEntities\n$Nodes\n1 4 1 4\n3 1 0 4\n1\n2\n3\n4\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n$Elements\n2 2 1 2\n2 1 2 1\n2 1 2 3\n3 1 4 1\n1 1 2 3 4\n$EndElements\n";
    for (name, text) in [("v1", v1), ("v2", v2), ("v4", v4)] {
        let m = eprop_io::gmsh::parse(name, text).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(m.n_nodes(), 4, "{name}");
        assert_eq!(m.n_cells(), 1, "{name}");
        assert_eq!(m.cell_tags[0], 7, "{name}");
        assert_eq!(m.facets.len(), 1, "{name}");
        assert_eq!(m.facets.tags[0], 3, "{name}");
    }
    // truncation and a bad node reference name the line
    let cut = &v2[..v2.find("$EndElements").unwrap() - 10];
    let e = eprop_io::gmsh::parse("cut.msh", cut).unwrap_err().to_string();
    assert!(e.contains("cut.msh:"), "{e}");
    let bad = v2.replace("1 4 2 7 1 1 2 3 4", "1 4 2 7 1 1 2 3 9");
    let e = eprop_io::gmsh::parse("bad.msh", &bad).unwrap_err().to_string();
    assert!(e.contains("bad.msh:18") && e.contains("node 9"), "{e}");
}

#[test]
fn verbose_logs_the_setup_phases_and_quiet_prints_nothing_else() {
    let d = workdir("verbose");
    let sc = d.path().join("s.toml");
    std::fs::write(&sc, SCENARIO).unwrap();
    let (ok, out, err) = eprop(&["-v", "run", sc.to_str().unwrap(), "-q"]);
    assert!(ok, "{err}");
    for phase in [
        "reading the mesh",
        "scenario resolved",
        "stable substep",
        "substeps per step",
    ] {
        assert!(err.contains(phase), "-v lacks `{phase}`: {err}");
    }
    assert!(!err.contains('\u{1b}'), "colour codes on a pipe");
    assert!(out.contains("max |u|"));
    let (ok, _, err) = eprop(&["run", sc.to_str().unwrap(), "-q", "--overwrite"]);
    assert!(ok && err.is_empty(), "quiet run wrote to stderr: {err}");
}

/// Without a terminal (stderr captured, as in a batch job's log) a run prints a progress line
/// every `--progress-every` steps on rank 0 only; `--quiet` and `--progress-every 0` print none,
/// and the default (every 10 s) none in a run this short.
#[test]
fn progress_lines_appear_without_a_terminal() {
    let d = workdir("progress");
    let sc = d.path().join("s.toml");
    std::fs::write(&sc, SCENARIO).unwrap();
    let sc = sc.to_str().unwrap();
    let h5 = d.path().join("p.h5");
    let h = h5.to_str().unwrap();
    let lines = |err: &str| -> Vec<String> {
        err.lines()
            .filter(|l| l.starts_with("progress: step "))
            .map(String::from)
            .collect()
    };
    let (ok, _, err) = eprop(&["run", sc, "-o", h, "--progress-every", "2"]);
    assert!(ok, "{err}");
    let got = lines(&err);
    assert_eq!(got.len(), 3, "{err}");
    for (l, k) in got.iter().zip([2, 4, 6]) {
        assert!(l.starts_with(&format!("progress: step {k}/6 (")), "{l}");
        assert!(l.contains("steps/s, ETA ") && l.contains("max|v| "), "{l}");
    }
    // two ranks: the same lines, once
    let out = common::mpirun(2, &["run", sc, "-o", h, "--overwrite", "--progress-every", "3"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let got = lines(&err);
    assert_eq!(got.len(), 2, "{err}");
    assert!(got[0].starts_with("progress: step 3/6 (50.0 %)") && got[1].starts_with("progress: step 6/6 (100.0 %)"));
    for extra in [&["--progress-every", "2", "-q"][..], &["--progress-every", "0"], &[]] {
        let mut args = vec!["run", sc, "-o", h, "--overwrite"];
        args.extend_from_slice(extra);
        let (ok, _, err) = eprop(&args);
        assert!(ok, "{err}");
        assert!(lines(&err).is_empty(), "{extra:?}: {err}");
    }
    let (ok, _, err) = eprop(&["run", sc, "-o", h, "--overwrite", "--progress-every", "soon"]);
    assert!(!ok && err.contains("`soon`") && err.contains("fix:"), "{err}");
}

#[test]
fn export_writes_the_deformed_surface_of_each_chosen_step() {
    let d = workdir("export");
    let sc = d.path().join("s.toml");
    std::fs::write(&sc, SCENARIO).unwrap();
    let (ok, _, err) = eprop(&["run", sc.to_str().unwrap(), "--quiet"]);
    assert!(ok, "{err}");
    let h5 = d.path().join("out.h5");
    let prefix = d.path().join("frames/cyl");
    let (p, h) = (prefix.to_str().unwrap(), h5.to_str().unwrap());
    // 4 output steps (0, 2, 4, 6): every second one
    let (ok, out, err) = eprop(&[
        "export",
        h,
        "--surface",
        "obj",
        "--every",
        "2",
        "-o",
        p,
        "--scalar",
        "energy",
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("2 file(s)"), "{out}");
    let obj = std::fs::read_to_string(d.path().join("frames/cyl_000002.obj")).unwrap();
    let v: Vec<[f64; 3]> = obj
        .lines()
        .filter(|l| l.starts_with("v "))
        .map(|l| {
            let x: Vec<f64> = l
                .split_whitespace()
                .skip(1)
                .take(3)
                .map(|t| t.parse().unwrap())
                .collect();
            [x[0], x[1], x[2]]
        })
        .collect();
    let faces = obj.lines().filter(|l| l.starts_with("f ")).count();
    // a closed triangulated surface: V - E + F = 2 with E = 3F / 2
    assert_eq!(v.len() as i64 - (3 * faces as i64) / 2 + faces as i64, 2);
    // the vertices are the rest surface moved by step 2's displacement
    let mesh = eprop_io::read_mesh(&d.path().join("cyl.msh")).unwrap();
    let u = eprop_series::vtkhdf::read_step(&h5, "displacement", 2).unwrap();
    let moved: Vec<[f64; 3]> = (0..mesh.n_nodes())
        .map(|g| {
            let p = mesh.points[g];
            [p[0] + u[3 * g], p[1] + u[3 * g + 1], p[2] + u[3 * g + 2]]
        })
        .collect();
    for x in &v {
        assert!(
            moved
                .iter()
                .any(|m| (0..3).all(|k| (m[k] - x[k]).abs() <= 1e-12 * (1.0 + x[k].abs()))),
            "{x:?}"
        );
    }
    // the other formats, one step each
    for f in ["stl", "ply", "vtu"] {
        let (ok, _, err) = eprop(&["export", h, "--surface", f, "--step", "3", "-o", p]);
        assert!(ok, "{f}: {err}");
        assert!(
            std::fs::metadata(d.path().join(format!("frames/cyl_000003.{f}")))
                .unwrap()
                .len()
                > 100
        );
    }
    // an existing file is refused without --overwrite, replaced with it; bad arguments are named
    let (ok, _, err) = eprop(&["export", h, "--surface", "stl", "--step", "3", "-o", p]);
    assert!(!ok && err.contains("exists") && err.contains("--overwrite"), "{err}");
    let (ok, _, err) = eprop(&["export", h, "--surface", "stl", "--step", "3", "-o", p, "--overwrite"]);
    assert!(ok, "{err}");
    // one step to a name with the format's extension is that name (it was s.obj_000001.obj)
    let named = d.path().join("frames/one.obj");
    let (ok, out, err) = eprop(&["export", h, "--step", "1", "-o", named.to_str().unwrap()]);
    assert!(ok && out.contains("1 file(s)"), "{err}");
    assert!(named.is_file() && !d.path().join("frames/one.obj_000001.obj").exists());
    let (ok, _, err) = eprop(&["export", h, "--surface", "gltf", "-o", p]);
    assert!(!ok && err.contains("obj, stl, ply or vtu"), "{err}");
    let (ok, _, err) = eprop(&["export", h, "--step", "9", "-o", p]);
    assert!(!ok && err.contains("output steps 0 to 3"), "{err}");
    let (ok, _, err) = eprop(&["export", h, "--scalar", "nothing", "--step", "1", "-o", p]);
    assert!(!ok && err.contains("--scalar"), "{err}");
}

#[test]
fn a_set_override_runs_as_the_edited_file() {
    let d = workdir("set");
    let (sc, edited) = (d.path().join("s.toml"), d.path().join("e.toml"));
    std::fs::write(&sc, SCENARIO).unwrap();
    let text = SCENARIO
        .replace("normal = 1.0", "normal = 2.0")
        .replace("steps = 6", "steps = 4")
        .replace("out.h5", "edited.h5")
        + "[material]\nconductivity = 0.1\n";
    std::fs::write(&edited, text).unwrap();
    let (ok, _, err) = eprop(&["run", edited.to_str().unwrap(), "-q"]);
    assert!(ok, "{err}");
    let sets = ["load.1.normal=2.0", "time.steps=4", "material.conductivity=0.1"];
    let mut args = vec!["run", sc.to_str().unwrap(), "-q"];
    for s in &sets {
        args.extend(["--set", s]);
    }
    let (ok, _, err) = eprop(&args);
    assert!(ok, "{err}");
    // every dataset bit for bit but the scenario text, which records the overrides
    let f = hdf5::File::open(d.path().join("out.h5")).unwrap();
    let g = hdf5::File::open(d.path().join("edited.h5")).unwrap();
    let (mut names, mut other) = (vec![], vec![]);
    common::datasets(&f, &mut names);
    common::datasets(&g, &mut other);
    names.sort();
    other.sort();
    assert_eq!(names, other);
    assert!(names.len() >= 20, "{names:?}");
    let text = names
        .iter()
        .find(|n| n.ends_with("/scenario"))
        .expect("the scenario text");
    let stored: Vec<u8> = f.dataset(text).unwrap().read_raw().unwrap();
    let stored = String::from_utf8(stored).unwrap();
    assert!(
        stored.contains("normal = 2.0") && stored.ends_with("# eprop --set material.conductivity=0.1\n"),
        "{stored}"
    );
    for n in names.iter().filter(|n| *n != text) {
        assert_eq!(common::bits(&f, n), common::bits(&g, n), "{n}");
    }
    // a restart with other overrides is a changed scenario: refused
    let out = d.path().join("out.h5");
    let (ok, _, err) = eprop(&[
        "run",
        sc.to_str().unwrap(),
        "-q",
        "--restart",
        out.to_str().unwrap(),
        "--set",
        "time.steps=4",
    ]);
    assert!(!ok && err.contains("written for a different scenario"), "{err}");
    let (ok, _, err) = eprop(&["check", sc.to_str().unwrap(), "--set", "time.stepz=3"]);
    assert!(!ok);
    assert!(
        err.contains("s.toml: --set time.stepz: [time] stepz: unknown field `stepz`"),
        "{err}"
    );
    let (ok, _, err) = eprop(&["check", sc.to_str().unwrap(), "--set", "material.mass=-1"]);
    assert!(!ok);
    assert!(
        err.contains("--set material.mass: [material] mass: -1 must be a positive number"),
        "{err}"
    );
    let (ok, _, err) = eprop(&["check", sc.to_str().unwrap(), "--set", "time.steps=[1,"]);
    assert!(!ok);
    assert!(
        err.contains("--set time.steps: `[1,` is not a TOML value; fix:"),
        "{err}"
    );
    let (ok, _, err) = eprop(&["check", sc.to_str().unwrap(), "--set", "load.2.normal=1"]);
    assert!(!ok);
    assert!(err.contains("1-based index 1..=1"), "{err}");
    for cmd in ["run", "check", "serve"] {
        let (ok, out, _) = eprop(&[cmd, "--help"]);
        assert!(
            ok && out.contains("--set <KEY=VALUE>") && out.contains("load.1.normal=2.0"),
            "{cmd}: {out}"
        );
    }
}

/// A bad option value is a bad command line, status 2, however it is spelt (a zero gave 1
/// and a negative value 2), with the message and its fix.
#[test]
fn a_bad_option_value_is_status_2_however_it_is_spelt() {
    for (args, said) in [
        (
            vec!["serve", "s.toml", "--listen", "127.0.0.1:0", "--timeout", "0"],
            "must be a positive number of seconds",
        ),
        (
            vec!["serve", "s.toml", "--listen", "127.0.0.1:0", "--timeout=-1"],
            "must be a positive number of seconds",
        ),
        (
            vec!["serve", "s.toml", "--listen", "127.0.0.1:0", "--timeout", "nan"],
            "must be a positive number of seconds",
        ),
        (
            vec!["serve", "s.toml", "--listen", ":99999"],
            "must be HOST:PORT with a port of 0 to 65535",
        ),
        (
            vec!["serve", "s.toml", "--listen", "127.0.0.1:99999"],
            "must be HOST:PORT",
        ),
        (
            vec!["export", "s.h5", "-o", "x", "--every", "0"],
            "must be a whole number of at least 1",
        ),
        (vec!["export", "s.h5", "-o", "x", "--step=-1"], "invalid value '-1'"),
        (
            vec![
                "fit",
                "s.toml",
                "--data",
                "c.csv",
                "--param",
                "young=1:2",
                "--tolerance",
                "0",
            ],
            "must be between 0 and 1",
        ),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_eprop")).args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(said), "{args:?}: {err}");
    }
}

/// `--set` on what the file does not have names the override, never a line past the end of the
/// file (`--set load.1.normal=1` on a scenario without [[load]] blamed line 42 of 40).
#[test]
fn a_set_on_what_the_file_lacks_names_the_override() {
    let d = workdir("set-missing");
    let sc = d.path().join("s.toml");
    // without [[load]] and without [time]
    let text = "[mesh]\nfile = \"cyl.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"bottom\"\n";
    std::fs::write(&sc, text).unwrap();
    let lines = text.lines().count();
    for (set, said) in [
        (
            "load.1.normal=1",
            "s.toml: --set load.1.normal: the scenario has no [[load]] table, so it has no entry 1 to change; fix: add a [[load]] table",
        ),
        ("foo.x=1", "s.toml: --set foo.x: [foo]: unknown field `foo`"),
        ("time.dt=0.1", "s.toml: --set time.dt: [time]: say when to stop"),
    ] {
        let (ok, _, err) = eprop(&["check", sc.to_str().unwrap(), "--set", set]);
        assert!(!ok);
        assert!(err.contains(said), "{set}: {err}");
        for past in lines + 1..lines + 10 {
            assert!(!err.contains(&format!("s.toml:{past}")), "{set}: {err}");
        }
    }
}

/// export claims each file as every writer does: a series a run is writing (its lock held,
/// through its own name or a link named like an export file) is not replaced even with
/// --overwrite (it replaced a 15 MB series with a 23 kB surface), and an existing FIFO is
/// refused at once (the export blocked in open() forever).
#[test]
fn export_respects_a_running_series_and_refuses_a_fifo() {
    let d = workdir("export-claim");
    let sc = d.path().join("s.toml");
    std::fs::write(&sc, SCENARIO).unwrap();
    let (ok, _, err) = eprop(&["run", sc.to_str().unwrap(), "--quiet"]);
    assert!(ok, "{err}");
    let h5 = d.path().join("out.h5");
    let h = h5.to_str().unwrap();
    let export = |prefix: &Path| {
        let mut child = Command::new(env!("CARGO_BIN_EXE_eprop"))
            .args([
                "export",
                h,
                "--surface",
                "vtu",
                "--step",
                "0",
                "--overwrite",
                "-o",
                prefix.to_str().unwrap(),
            ])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let start = std::time::Instant::now();
        while child.try_wait().unwrap().is_none() {
            if start.elapsed().as_secs() > 20 {
                let _ = child.kill();
                panic!("the export blocked");
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let out = child.wait_with_output().unwrap();
        (out.status.code(), String::from_utf8_lossy(&out.stderr).to_string())
    };
    // a run writing run_000000.vtu (its lock held as a run holds it)
    let running = d.path().join("run_000000.vtu");
    std::fs::copy(&h5, &running).unwrap();
    let size = std::fs::metadata(&running).unwrap().len();
    let lock = eprop::guard::safety::OutputLock::take(&running).unwrap();
    let (code, err) = export(&d.path().join("run"));
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("is writing this file now") && err.contains("fix:"),
        "{err}"
    );
    assert_eq!(
        std::fs::metadata(&running).unwrap().len(),
        size,
        "the series was replaced"
    );
    // a link named like an export file, to a series being written
    let link = d.path().join("z_000000.vtu");
    std::os::unix::fs::symlink(&running, &link).unwrap();
    let (code, err) = export(&d.path().join("z"));
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("is writing this file now"), "{err}");
    assert_eq!(
        std::fs::metadata(&running).unwrap().len(),
        size,
        "the series was replaced"
    );
    drop(lock);
    // a FIFO where an export file goes
    let fifo = d.path().join("u_000000.vtu");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let (code, err) = export(&d.path().join("u"));
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("is not a regular file") && err.contains("fix:"), "{err}");
}

/// A lock in the way of an export names export's own fix (another -o prefix), not a series'
/// `-o FILE.h5`.
#[test]
fn a_lock_in_the_way_of_an_export_names_the_export_option() {
    let d = tempfile::tempdir().unwrap();
    let sc = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/cylinder_indent.toml");
    let h5 = d.path().join("s.h5");
    let (ok, _, err) = eprop(&[
        "run",
        sc.to_str().unwrap(),
        "-q",
        "--steps",
        "2",
        "-o",
        h5.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let prefix = d.path().join("frame");
    // a lock file that is not eprop's beside the export's file
    std::fs::write(d.path().join("frame_000000.obj.lock"), "not a lock").unwrap();
    let (ok, _, err) = eprop(&[
        "export",
        h5.to_str().unwrap(),
        "--step",
        "0",
        "-o",
        prefix.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(
        err.contains("is not an eprop lock file") && err.contains("another -o PREFIX"),
        "{err}"
    );
    assert!(!err.contains("FILE.h5"), "{err}");
}

/// `export --unit`: a mesh read in mm and run in the continuum reading is written in metres by
/// default, in mm with `--unit mm` or `--unit mesh` (the same bits times 1000); an unknown unit,
/// and any unit in the paper's unit-free reading, are refused with the fix.
#[test]
fn export_writes_the_mesh_unit_on_request() {
    let d = workdir("export_unit");
    let at = |n: &str| d.path().join(n).to_str().unwrap().to_string();
    let (ok, _, err) = eprop(&[
        "mesh",
        "box",
        "--size",
        "20,20,10",
        "--cells",
        "4,4,2",
        "-o",
        &at("b.msh"),
    ]);
    assert!(ok, "{err}");
    std::fs::write(
        d.path().join("c.toml"),
        "[mesh]\nfile = \"b.msh\"\nunit = \"mm\"\n[[fixed]]\ngroup = \"zmin\"\n[[load]]\nnearest = [0.02, 0.02, 0.01]\nnormal = 0.01\n[time]\nsteps = 2\n",
    )
    .unwrap();
    let (ok, _, err) = eprop(&["run", &at("c.toml"), "--quiet", "-o", &at("c.h5")]);
    assert!(ok, "{err}");
    let vertices = |f: &str| -> Vec<f64> {
        std::fs::read_to_string(d.path().join(f))
            .unwrap()
            .lines()
            .filter(|l| l.starts_with("v "))
            .flat_map(|l| {
                l[2..]
                    .split_whitespace()
                    .map(|x| x.parse::<f64>().unwrap())
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let h5 = at("c.h5");
    for (name, unit) in [("m.obj", None), ("mm.obj", Some("mm")), ("own.obj", Some("mesh"))] {
        let out = at(name);
        let mut args = vec!["export", h5.as_str(), "--step", "2", "-o", out.as_str()];
        if let Some(u) = unit {
            args.extend(["--unit", u]);
        }
        let (ok, _, err) = eprop(&args);
        assert!(ok, "{err}");
    }
    let (m, mm, own) = (vertices("m.obj"), vertices("mm.obj"), vertices("own.obj"));
    assert!(!m.is_empty() && m.len() == mm.len());
    let span = m.iter().fold(0.0f64, |a, &x| a.max(x.abs()));
    assert!(span > 0.015 && span < 0.03, "metres by default: {span}");
    for (a, b) in m.iter().zip(&mm) {
        assert!(
            (a * 1000.0 - b).abs() <= 1e-9 * b.abs().max(1.0),
            "{a} m against {b} mm"
        );
    }
    assert_eq!(mm, own, "--unit mesh is the mesh file's unit, mm");
    let (ok, _, err) = eprop(&[
        "export",
        &at("c.h5"),
        "--step",
        "1",
        "-o",
        &at("x.obj"),
        "--unit",
        "inch",
    ]);
    assert!(
        !ok && err.contains("not a length unit") && err.contains("fix:"),
        "{err}"
    );
    // the paper reading has no unit to convert
    std::fs::write(d.path().join("p.toml"), SCENARIO).unwrap();
    let (ok, _, err) = eprop(&["run", &at("p.toml"), "--quiet", "-o", &at("p.h5")]);
    assert!(ok, "{err}");
    let (ok, _, err) = eprop(&["export", &at("p.h5"), "--step", "1", "-o", &at("y.obj"), "--unit", "mm"]);
    assert!(
        !ok && err.contains("unit-free") && err.contains("fix: leave out --unit"),
        "{err}"
    );
}
