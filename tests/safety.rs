//! Data safety and honest results, one catalogue per promise: an output never replaces an
//! input; a series is replaced only when asked and another file never; one writer per file;
//! implausible inputs and results are warned about; counts and step sizes are bounded and a
//! state that is not finite stops the run; SIGTERM stops a job after a complete step that a
//! restart continues bit for bit; a full disk (at creation and mid-run, on 2 ranks) stops
//! every rank cleanly, never hangs, and the file is restartable once space is free.

mod common;

use common::{
    assert_same, command, eprop, finish, live_steps, ok, refused, spawn, stderr, steps_complete, wait_for_steps, Tmpfs,
};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

const CYL: &str = "[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 0.3\n";

/// A generated cylinder `cyl.msh` (once) and a scenario `NAME` in `dir`.
fn cylinder(dir: &Path, name: &str, extra: &str, steps: u64) -> PathBuf {
    let mesh = dir.join("cyl.msh");
    if !mesh.exists() {
        eprop_io::write_mesh(&eprop_io::generate::cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), &mesh).unwrap();
    }
    let sc = dir.join(name);
    std::fs::write(
        &sc,
        common::paper(&format!(
            "[mesh]\nfile = \"cyl.msh\"\n{CYL}{extra}[time]\nsteps = {steps}\n"
        )),
    )
    .unwrap();
    sc
}

/// Replaces `from` by `to` in a scenario file.
fn edit(sc: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(sc).unwrap();
    assert!(text.contains(from), "`{from}` is not in {}", sc.display());
    std::fs::write(sc, text.replace(from, to)).unwrap();
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The bytes of files, to show they did not change.
fn contents(paths: &[&Path]) -> Vec<Vec<u8>> {
    paths.iter().map(|p| std::fs::read(p).unwrap()).collect()
}

/// The last complete step of a series: its step number, and every value of u, v and phi
/// finite.
fn last_step(h5: &Path) -> (u64, bool) {
    let f = hdf5::File::open(h5).unwrap();
    let k = steps_complete(h5) as usize;
    let n = f.dataset("VTKHDF/NumberOfPoints").unwrap().read_raw::<i64>().unwrap()[0] as usize;
    let step = f.dataset("eprop/probes/step").unwrap().read_raw::<i64>().unwrap()[k - 1] as u64;
    let mut finite = true;
    for name in ["displacement", "velocity", "potential"] {
        let v = eprop_series::vtkhdf::read_step(h5, name, k - 1).unwrap();
        assert_eq!(v.len(), 3 * n);
        finite &= v.iter().all(|x| x.is_finite());
    }
    (step, finite)
}

#[test]
fn an_output_that_is_an_input_is_refused_and_the_inputs_stay_unchanged() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 3);
    let mesh = dir.join("cyl.msh");
    std::os::unix::fs::symlink(&mesh, dir.join("soft.h5")).unwrap();
    std::fs::hard_link(&mesh, dir.join("hard.h5")).unwrap();
    std::fs::hard_link(&mesh, dir.join("hard.msh")).unwrap();
    std::fs::create_dir(dir.join("sub")).unwrap();
    let before = contents(&[&mesh, &sc]);
    let up = dir.join("sub/../cyl.msh");
    let cases: Vec<(usize, Vec<&str>, &str)> = vec![
        (1, vec!["run", s(&sc), "-o", s(&mesh)], "is the mesh"),
        (1, vec!["run", s(&sc), "-o", s(&sc)], "is the scenario"),
        (1, vec!["run", s(&sc), "-o", s(&up)], "is the mesh"),
        (1, vec!["run", s(&sc), "-o", "soft.h5"], "is the mesh"),
        (1, vec!["run", s(&sc), "-o", "hard.h5"], "a link to the same file"),
        (
            1,
            vec!["run", s(&sc), "--restart", s(&mesh)],
            "the restart file (--restart) is the mesh",
        ),
        (2, vec!["run", s(&sc), "-o", s(&mesh)], "is the mesh"),
        (2, vec!["run", s(&sc), "-o", "hard.h5"], "a link to the same file"),
        (1, vec!["export-operator", s(&sc), "-o", s(&mesh)], "the operator file"),
        (1, vec!["export-operator", s(&sc), "-o", "soft.h5"], "is the mesh"),
        (1, vec!["convert", s(&mesh), "hard.msh"], "the converted mesh"),
    ];
    for (ranks, args, needle) in cases {
        let o = finish(
            command(ranks, &args)
                .current_dir(dir)
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap(),
            120,
            &args.join(" "),
        );
        refused(&o, 1, &[needle, "destroy that input", "fix:"]);
        assert_eq!(contents(&[&mesh, &sc]), before, "{args:?} changed an input");
    }
    // [output] file naming the mesh
    let named = cylinder(dir, "named.toml", "[output]\nfile = \"cyl.msh\"\n", 3);
    let o = eprop(1, &["run", s(&named)]);
    refused(&o, 1, &["[output] file of", "is the mesh"]);
    assert_eq!(contents(&[&mesh, &sc]), before);
    // a TetGen mesh is three files: each is an input
    let tet = eprop_io::generate::box_mesh([1.0; 3], [2; 3], eprop_io::generate::BoxCells::Tet).unwrap();
    let (node, ele, face) = eprop_io::testwrite::tetgen(&tet);
    for (ext, text) in [("node", &node), ("ele", &ele), ("face", &face)] {
        std::fs::write(dir.join(format!("b.{ext}")), text).unwrap();
    }
    std::fs::write(
        dir.join("t.toml"),
        "[mesh]\nfile = \"b.ele\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"xmin\"\n[time]\nsteps = 1\n",
    )
    .unwrap();
    let tet_before = contents(&[&dir.join("b.node"), &dir.join("b.face")]);
    for out in ["b.node", "b.face"] {
        let o = eprop(1, &["run", s(&dir.join("t.toml")), "-o", s(&dir.join(out))]);
        refused(&o, 1, &["is the mesh", "destroy that input"]);
    }
    assert_eq!(contents(&[&dir.join("b.node"), &dir.join("b.face")]), tet_before);
}

#[test]
fn a_series_is_replaced_only_when_asked_and_another_file_never() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 3);
    let h5 = dir.join("s.h5");
    ok(&eprop(1, &["run", s(&sc), "-q"]));
    let first = contents(&[&h5]);
    // again: refused, with the steps it holds and the three choices
    let o = eprop(1, &["run", s(&sc), "-q"]);
    refused(
        &o,
        1,
        &[
            "s.h5",
            "holds an eprop series of 4 complete step(s)",
            "--restart",
            "--overwrite",
            "-o FILE.h5",
        ],
    );
    assert_eq!(contents(&[&h5]), first, "a refused run changed the series");
    // on 2 ranks too
    refused(&eprop(2, &["run", s(&sc), "-q"]), 1, &["holds an eprop series"]);
    // replaced when asked: --overwrite, or [output] overwrite = true
    ok(&eprop(1, &["run", s(&sc), "-q", "--overwrite", "--steps", "5"]));
    assert_eq!(steps_complete(&h5), 6);
    let again = cylinder(dir, "s.toml", "[output]\noverwrite = true\n", 3);
    ok(&eprop(2, &["run", s(&again), "-q"]));
    assert_eq!(steps_complete(&h5), 4);
    // a file that is not a series: never, not even with --overwrite
    let txt = dir.join("notes.txt");
    std::fs::write(&txt, "keep me").unwrap();
    let op = dir.join("op.h5");
    ok(&eprop(1, &["export-operator", s(&sc), "-o", s(&op)]));
    let others = contents(&[&txt, &op]);
    for out in [&txt, &op] {
        for extra in [&[][..], &["--overwrite"][..]] {
            let mut args = vec!["run", s(&sc), "-q", "-o", s(out)];
            args.extend(extra);
            let o = eprop(1, &args);
            refused(
                &o,
                1,
                &["eprop never replaces such a file, not even with --overwrite", "fix:"],
            );
        }
    }
    assert_eq!(contents(&[&txt, &op]), others);
    // --restart continues a series as before
    ok(&eprop(1, &["run", s(&sc), "-q", "--restart", s(&h5), "--steps", "5"]));
    assert_eq!(steps_complete(&h5), 6);
}

#[test]
fn a_second_writer_is_refused_while_a_job_writes() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // slow steps (many substeps) so that the first job runs while the others try
    let sc = cylinder(dir, "s.toml", "", 20_000);
    edit(&sc, "steps = 20000", "steps = 20000\nh = 0.002\n");
    let h5 = dir.join("shared.h5");
    let mut first = spawn(2, &["run", s(&sc), "-q", "-o", s(&h5)]);
    wait_for_steps(&h5, 2, &mut first);
    for (ranks, extra) in [(1, None), (1, Some("--overwrite")), (2, None)] {
        let mut args = vec!["run", s(&sc), "-q", "-o", s(&h5)];
        args.extend(extra);
        let o = eprop(ranks, &args);
        refused(&o, 1, &["another eprop run (pid", "is writing this file now", "fix:"]);
    }
    let o = eprop(1, &["run", s(&sc), "-q", "--restart", s(&h5)]);
    refused(&o, 1, &["is writing this file now"]);
    // readers are not writers: the file opens while the job runs
    assert!(live_steps(&h5).is_some());
    // the job goes on undisturbed and stops cleanly
    assert!(first.try_wait().unwrap().is_none(), "the first job ended");
    for pid in common::children(first.id()) {
        Command::new("kill").args(["-TERM", &pid.to_string()]).status().unwrap();
    }
    let o = finish(first, 120, "the first job");
    refused(&o, 3, &["stopped by SIGTERM"]);
    assert!(!dir.join("shared.h5.lock").exists(), "the lock file stays");
    let (_, finite) = last_step(&h5);
    assert!(finite);
}

/// The run's JSON summary (it must succeed).
fn summary(args: &[&str]) -> serde_json::Value {
    let o = eprop(1, args);
    ok(&o);
    serde_json::from_slice(&o.stdout).unwrap()
}

fn warnings(v: &serde_json::Value) -> Vec<String> {
    v["warnings"]
        .as_array()
        .expect("warnings is a list")
        .iter()
        .map(|w| w.as_str().unwrap().to_string())
        .collect()
}

fn has(ws: &[String], needles: &[&str]) -> bool {
    ws.iter().any(|w| needles.iter().all(|n| w.contains(n)))
}

#[test]
fn implausible_loads_and_displacements_are_warned_about() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // the cylinder pressed with 1000 (sigma/young about 80): a warning, the same numbers
    let sc = cylinder(dir, "s.toml", "", 20);
    edit(&sc, "normal = 0.3", "normal = 1000.0");
    let run = summary(&["run", s(&sc), "--json", "-o", s(&dir.join("a.h5"))]);
    let ws = warnings(&run);
    assert!(has(&ws, &["load 1", "times [tissue] young = 100", "fix:"]), "{ws:?}");
    assert!(
        has(&ws, &["max |u|", "at step 1 ", "passed 10 % of the mesh's diagonal"]),
        "{ws:?}"
    );
    assert_eq!(
        ws.iter().filter(|w| w.contains("passed 10 %")).count(),
        1,
        "warned once"
    );
    // the warnings change no number: the library's simulation of the same scenario, which
    // has no warnings, gives the same max |u| to the last bit
    let u = run["max_displacement"].as_f64().unwrap();
    assert!(u > 1e3, "max |u| = {u}");
    let mesh = eprop_io::read_mesh(&dir.join("cyl.msh")).unwrap();
    let mut sim = common::sim(
        mesh,
        &std::fs::read_to_string(&sc)
            .unwrap()
            .replace("[mesh]\nfile = \"cyl.msh\"\n", ""),
    );
    while !sim.done() {
        sim.advance().unwrap();
    }
    assert_eq!(sim.max_displacement().0.to_bits(), u.to_bits());
    let chk = summary(&["check", s(&sc), "--json"]);
    assert!(has(&warnings(&chk), &["times [tissue] young"]), "{chk}");
    // a plausible scenario has none of these
    let fine = cylinder(dir, "fine.toml", "", 20);
    let ws = warnings(&summary(&["run", s(&fine), "--json"]));
    assert!(
        !has(&ws, &["young"]) && !has(&ws, &["passed 10 %"]) && !has(&ws, &["nearest"]),
        "{ws:?}"
    );
    // an organ in metres (0.1 units) pressed with 1: the warning suggests [mesh] scale
    let small = eprop_io::generate::box_mesh([0.1; 3], [6; 3], eprop_io::generate::BoxCells::Tet).unwrap();
    eprop_io::write_mesh(&small, &dir.join("m.msh")).unwrap();
    std::fs::write(
        dir.join("metres.toml"),
        "[mesh]\nfile = \"m.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"xmin\"\n[[load]]\nnearest = [0.1, 0.05, 0.05]\nforce = [-1.0, 0.0, 0.0]\n[time]\nsteps = 2\n",
    )
    .unwrap();
    for cmd in ["check", "run"] {
        let ws = warnings(&summary(&[cmd, s(&dir.join("metres.toml")), "--json"]));
        assert!(has(&ws, &["young", "`[mesh] scale = 1000`"]), "{cmd}: {ws:?}");
    }
    // nearest far from every node; a contact area tiny for the mesh
    let far = cylinder(dir, "far.toml", "", 2);
    std::fs::write(
        &far,
        std::fs::read_to_string(&far)
            .unwrap()
            .replace("[1.0, 0.0, 2.0]", "[1000.0, 0.0, 2.0]"),
    )
    .unwrap();
    for cmd in ["check", "run"] {
        let ws = warnings(&summary(&[cmd, s(&far), "--json"]));
        assert!(
            has(
                &ws,
                &["`nearest = [1000, 0, 2]` picks node", "away from the point", "fix:"]
            ),
            "{ws:?}"
        );
    }
    // a needle 10 km long and 1 cm thick: a node's boundary area is tiny for its extent
    let needle = eprop_io::generate::box_mesh([1e4, 0.01, 0.01], [1, 1, 1], eprop_io::generate::BoxCells::Tet).unwrap();
    eprop_io::write_mesh(&needle, &dir.join("plate.msh")).unwrap();
    std::fs::write(
        dir.join("plate.toml"),
        "[mesh]\nfile = \"plate.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"xmin\"\n[[load]]\nnearest = [1e4, 0.01, 0.01]\nforce = [0.0, 0.0, -1e-9]\n[time]\nsteps = 1\n",
    )
    .unwrap();
    let ws = warnings(&summary(&["check", s(&dir.join("plate.toml")), "--json"]));
    assert!(
        has(&ws, &["contact area", "below 1e-6 of the squared extent"]),
        "{ws:?}"
    );
}

#[test]
fn counts_and_step_sizes_past_their_limits_are_refused_by_check_and_run() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let cases: [(&str, &str, &[&str]); 8] = [
        (
            "[material]\nconductivity = 1e300\n",
            "steps = 5",
            &["substeps per mechanics step", "above the limit", "conductivity"],
        ),
        ("", "steps = 5\nh = 1e-300", &["[time] h = 1e-300", "above the limit"]),
        (
            "",
            "steps = 1000000000000",
            &["[time] steps = 1,000,000,000,000", "above the limit of 1,000,000,000"],
        ),
        ("", "end = 1e300", &["[time] end = 1e300", "above the limit"]),
        (
            "",
            "equilibrium = 1e-300",
            &["[time] equilibrium = 1e-300", "double precision", "all 1,000,000 steps"],
        ),
        (
            "[material]\nmass = 1e-308\n",
            "steps = 5",
            &["dt = ", "is below 1e-30", "mass, damping and stiffness"],
        ),
        ("", "steps = 5\ndt = 1e-300", &["[time] dt = 1e-300 is below 1e-30"]),
        (
            "[model]\nreading = \"paper\"\nstiffness = 1e300\n",
            "steps = 5",
            &["is below 1e-30", "stiffness"],
        ),
    ];
    for (k, (extra, time, needles)) in cases.iter().enumerate() {
        let sc = cylinder(dir, &format!("c{k}.toml"), extra, 5);
        edit(&sc, "steps = 5", time);
        for args in [vec!["check", s(&sc)], vec!["run", s(&sc), "-q"]] {
            let o = eprop(1, &args);
            let mut all = needles.to_vec();
            all.push("fix:");
            refused(&o, 1, &all);
        }
        assert!(!dir.join(format!("c{k}.h5")).exists(), "case {k} wrote output");
    }
    // --steps past the limit
    let sc = cylinder(dir, "s.toml", "", 5);
    refused(
        &eprop(1, &["run", s(&sc), "--steps", "1000000000000"]),
        1,
        &["--steps = 1,000,000,000,000"],
    );
    // 2 ranks refuse alike and end
    let sc = cylinder(dir, "c2r.toml", "[material]\nconductivity = 1e300\n", 5);
    refused(&eprop(2, &["run", s(&sc), "-q"]), 1, &["substeps per mechanics step"]);
}

#[test]
fn check_estimates_steps_and_output_size_for_any_input() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    for (extra, steps) in [
        ("", 40u64),
        ("[output]\nevery = 7\n", 40),
        ("[output]\nprecision = \"float32\"\nfields = [\"energy\"]\n", 40),
    ] {
        let sc = cylinder(dir, "s.toml", extra, steps);
        let chk = summary(&["check", s(&sc), "--json"]);
        let h5 = dir.join("s.h5");
        let _ = std::fs::remove_file(&h5);
        let run = summary(&["run", s(&sc), "--json"]);
        assert_eq!(chk["steps"].as_u64(), Some(steps));
        assert_eq!(chk["output_steps"].as_u64(), run["output_steps"].as_u64(), "{extra}");
        let size = std::fs::metadata(&h5).unwrap().len() as f64;
        let est = chk["output_mib"].as_f64().unwrap() * 1048576.0;
        // an upper bound (uncompressed, with room for metadata), not a wild one
        assert!(
            est >= size && est < 3.0 * size + 2e6,
            "{extra}: estimated {est}, wrote {size}"
        );
    }
    // the largest count check accepts, estimated without wrapping
    let sc = cylinder(dir, "big.toml", "[output]\nevery = 1000000\n", 1_000_000_000);
    let chk = summary(&["check", s(&sc), "--json"]);
    assert_eq!(chk["steps"].as_u64(), Some(1_000_000_000));
    assert_eq!(chk["output_steps"].as_u64(), Some(1001));
    assert!(chk["estimated_seconds"].as_f64().unwrap() > 1.0);
    // a run whose output would not fit is refused before it starts
    let sc = cylinder(dir, "huge.toml", "", 1_000_000_000);
    let o = eprop(1, &["run", s(&sc), "-q"]);
    refused(&o, 1, &["the run would write about", "free", "--force"]);
    assert!(!dir.join("huge.h5").exists());
    let chk = summary(&["check", s(&sc), "--json"]);
    assert!(has(&warnings(&chk), &["will refuse without --force"]), "{chk}");
}

#[test]
fn a_state_that_is_not_finite_stops_the_run_on_1_and_2_ranks() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 10);
    // the energy density q = sigma^2 / (2 young), about 3e179, passes the check made when the
    // scenario is read (1e200), but the squares of the potential overflow at step 1
    edit(&sc, "normal = 0.3", "force = [1e90, 0.0, 0.0]");
    for ranks in [1, 2] {
        let h5 = dir.join(format!("nan{ranks}.h5"));
        let o = eprop(ranks, &["run", s(&sc), "-q", "-o", s(&h5)]);
        refused(
            &o,
            1,
            &[
                "at step 1 ",
                "no longer finite (NaN or inf)",
                "keeps its 1 complete output steps (to step 0)",
                "Likely cause: load 1",
                "fix:",
            ],
        );
        assert!(!stderr(&o).contains("max |u|"));
        assert_eq!(steps_complete(&h5), 1);
        let (step, finite) = last_step(&h5);
        assert!(step == 0 && finite);
    }
}

#[test]
fn a_restart_from_a_state_that_is_not_finite_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 4);
    let h5 = dir.join("s.h5");
    ok(&eprop(1, &["run", s(&sc), "-q"]));
    // one NaN in the velocity of the last step
    restart_refused_after_writing(&sc, &h5, "velocity", [f64::NAN, 0.0, 0.0]);
}

/// Writes `value` into point field `field` of one node at output step 4 (the last of a
/// 4-step run) of the series `h5`, then checks that `--restart` refuses it on 1 and 2 ranks
/// and leaves the file as it is.
fn restart_refused_after_writing(sc: &Path, h5: &Path, field: &str, value: [f64; 3]) {
    {
        let f = hdf5::File::open_rw(h5).unwrap();
        let n = f.dataset("VTKHDF/NumberOfPoints").unwrap().read_raw::<i64>().unwrap()[0] as usize;
        let ds = f.dataset(&format!("VTKHDF/PointData/{field}")).unwrap();
        let row = 4 * n + n / 2;
        ds.write_slice(&ndarray::arr2(&[value]), ndarray::s![row..row + 1, ..])
            .unwrap();
    }
    let before = contents(&[h5]);
    for ranks in [1, 2] {
        let o = eprop(ranks, &["run", s(sc), "-q", "--restart", s(h5), "--steps", "8"]);
        refused(&o, 1, &["cannot restart", "(step 4) holds NaN or inf", "fix:"]);
    }
    assert_eq!(contents(&[h5]), before);
}

#[test]
fn only_regular_files_are_read() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 2);
    let fifo = |name: &str| {
        let p = dir.join(name);
        assert!(Command::new("mkfifo").arg(&p).status().unwrap().success());
        p
    };
    let mesh = fifo("pipe.msh");
    edit(&sc, "cyl.msh", "pipe.msh");
    let scenario = fifo("pipe.toml");
    for args in [
        vec!["run", s(&sc), "-q"],
        vec!["check", s(&sc)],
        vec!["run", s(&scenario), "-q"],
        vec!["info", s(&mesh)],
    ] {
        let o = finish(spawn(1, &args), 60, &args.join(" "));
        refused(&o, 1, &["is a FIFO (named pipe), not a regular file", "fix:"]);
    }
    let _ = mesh;
}

#[test]
fn misleading_messages_say_what_is_wrong() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // a huge mass: the bound does not overflow into "no step size is stable"
    let sc = cylinder(dir, "s.toml", "[material]\nmass = 1e308\n", 5);
    let o = eprop(1, &["check", s(&sc)]);
    let e = format!("{}{}", String::from_utf8_lossy(&o.stdout), stderr(&o));
    assert!(!e.contains("no step size is stable"), "{e}");
    // dt = 2 sqrt(m / k) = 2e154 (0.9 of it): huge but right, and stepped by the implicit
    // integrator (auto), whose counts stay readable
    assert!(e.contains("dt = 1.8000e154"), "{e}");
    assert!(!e.contains("18446744073709551615"), "{e}");
    // run --help names the real default output
    let o = eprop(1, &["run", "--help"]);
    let help = String::from_utf8_lossy(&o.stdout);
    assert!(help.contains("<scenario stem>.h5"), "{help}");
    assert!(help.contains("Exit status") && help.contains("--overwrite") && help.contains("--force"));
    // the reader's messages (io crate): a link loop, a file that ends before its elements
    std::os::unix::fs::symlink(dir.join("l2.msh"), dir.join("l1.msh")).unwrap();
    std::os::unix::fs::symlink(dir.join("l1.msh"), dir.join("l2.msh")).unwrap();
    refused(
        &eprop(1, &["info", s(&dir.join("l1.msh"))]),
        1,
        &["symbolic link loop", "fix:"],
    );
    let text = std::fs::read_to_string(dir.join("cyl.msh")).unwrap();
    std::fs::write(dir.join("cut.msh"), &text[..text.find("$Elements").unwrap()]).unwrap();
    refused(
        &eprop(1, &["info", s(&dir.join("cut.msh"))]),
        1,
        &["$Elements", "truncated"],
    );
}

#[test]
fn sigterm_on_2_ranks_stops_after_one_step_and_the_restart_is_bit_for_bit() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // every 3rd step is written; slow steps (many substeps) so the signal lands mid-run
    let sc = cylinder(dir, "s.toml", "[output]\nevery = 3\n", 2000);
    edit(&sc, "steps = 2000", "steps = 2000\nh = 0.002\n");
    let cut = dir.join("cut.h5");
    let mut job = spawn(2, &["run", s(&sc), "-q", "-o", s(&cut)]);
    wait_for_steps(&cut, 3, &mut job);
    // SLURM signals every process of the job; one rank alone is enough to stop them all
    let ranks = common::children(job.id());
    assert_eq!(ranks.len(), 2, "{ranks:?}");
    Command::new("kill")
        .args(["-TERM", &ranks[1].to_string()])
        .status()
        .unwrap();
    let o = finish(job, 120, "the signalled job");
    refused(
        &o,
        3,
        &[
            "stopped by SIGTERM after step ",
            "continue with `mpirun -n 2 eprop run",
            "--restart",
        ],
    );
    let e = stderr(&o);
    let at: u64 = e
        .split("after step ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{e}"));
    let (last, finite) = last_step(&cut);
    assert_eq!(last, at, "the step it stopped after is the last in the file");
    assert!(finite && at < 2000);
    // continue (on 2 ranks) to step at + 10 and compare with a run that never stopped
    let target = (at + 10).to_string();
    ok(&eprop(
        2,
        &["run", s(&sc), "-q", "--restart", s(&cut), "--steps", &target],
    ));
    let whole = dir.join("whole.h5");
    ok(&eprop(1, &["run", s(&sc), "-q", "-o", s(&whole), "--steps", &target]));
    assert_same(&whole, &cut);
    // one process: SIGINT (Ctrl-C) alike
    let one = dir.join("one.h5");
    let mut run = spawn(1, &["run", s(&sc), "-q", "-o", s(&one)]);
    wait_for_steps(&one, 3, &mut run);
    Command::new("kill")
        .args(["-INT", &run.id().to_string()])
        .status()
        .unwrap();
    let o = finish(run, 120, "the interrupted run");
    refused(&o, 3, &["stopped by SIGINT", "continue with `eprop run"]);
    assert!(last_step(&one).1);
}

#[test]
fn a_full_disk_at_creation_and_mid_run_on_2_ranks_stops_every_rank_cleanly() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // at creation: the static mesh alone does not fit (a 6727-node cylinder in 512 KiB)
    let Some(small) = Tmpfs::mount("512k") else { return };
    eprop_io::write_mesh(
        &eprop_io::generate::cylinder_mesh(1.0, 4.0, 8, 30).unwrap(),
        &dir.join("big.msh"),
    )
    .unwrap();
    std::fs::write(
        dir.join("big.toml"),
        format!("[mesh]\nfile = \"big.msh\"\n[model]\nreading = \"paper\"\n{CYL}[time]\nsteps = 20\n"),
    )
    .unwrap();
    let out = small.path().join("big.h5");
    for ranks in [1, 2] {
        // refused before it starts: the estimate does not fit
        let o = eprop(ranks, &["run", s(&dir.join("big.toml")), "-q", "-o", s(&out)]);
        refused(&o, 1, &["the run would write about", "--force"]);
        // forced: the static part and the first step do not fit either, so it does not start
        let o = eprop(
            ranks,
            &["run", s(&dir.join("big.toml")), "-q", "-o", s(&out), "--force"],
        );
        refused(
            &o,
            1,
            &[
                "big.h5",
                "the first output step needs about",
                "not even --force starts",
                "fix: free space",
            ],
        );
        assert!(!out.exists(), "an unfinished file stays");
        assert!(!small.path().join("big.h5.lock").exists());
    }
    drop(small);

    // mid-run: a filler takes the free space while the job writes (forced: past the start's
    // refusal, so the disk itself says ENOSPC). The job writes every tenth step: writing every
    // step it filled the 64 MiB on its own within seconds (about 150 output steps a second),
    // before a loaded machine's watcher had read its first three steps
    let Some(disk) = Tmpfs::mount("64m") else { return };
    let sc = cylinder(dir, "s.toml", "", 20_000);
    edit(&sc, "steps = 20000", "steps = 20000\nh = 0.002\n");
    let slow = cylinder(dir, "slow.toml", "[output]\nevery = 10\n", 20_000);
    edit(&slow, "steps = 20000", "steps = 20000\nh = 0.002\n");
    for ranks in [2, 1] {
        let h5 = disk.path().join(format!("run{ranks}.h5"));
        let mut job = spawn(ranks, &["run", s(&slow), "-q", "-o", s(&h5), "--force"]);
        wait_for_steps(&h5, 3, &mut job);
        let filler = disk.fill();
        let o = finish(job, 180, "the job on a full disk");
        // (the write the disk refuses is a step's fields or its checks: "writing output step
        // 65" or "writing the checks of output step 65")
        refused(
            &o,
            4,
            &[
                "writing ",
                "output step ",
                "no space left on device (ENOSPC)",
                "fix: free space",
                "then continue with `",
                "--restart",
            ],
        );
        assert_eq!(stderr(&o).matches("ENOSPC").count(), 1, "one message: {}", stderr(&o));
        restart_completes(dir, &slow, &h5, ranks, filler);
    }
    // a run that cannot write all its steps is refused unless forced; forced, it writes until
    // the disk refuses a write (inside HDF5's collective calls on 2 ranks), then every rank
    // ends with status 4 and the file keeps every step before
    let h5 = disk.path().join("tight.h5");
    let filler = disk.leave_free(1800 * 1024);
    assert!(disk.mounted(), "the tmpfs is not found in mountinfo: {}", disk.state());
    // what the disk was before and after a run that did not stop as it should (seen twice in
    // a full suite before `fill` waited for deleted files to be let go: a series removed just
    // before still held its space when the filler was sized, and gave it back under the run)
    let before = disk.state();
    let o = eprop(2, &["run", s(&sc), "-q", "-o", s(&h5), "--steps", "1000"]);
    if o.status.code() != Some(1) {
        eprintln!(
            "unforced tight run: status {:?}; before: {before}; after: {}",
            o.status.code(),
            disk.state()
        );
    }
    refused(&o, 1, &["the run would write about", "free while writing", "--force"]);
    let before = disk.state();
    let o = eprop(2, &["run", s(&sc), "-q", "-o", s(&h5), "--steps", "1000", "--force"]);
    if o.status.code() != Some(4) {
        eprintln!(
            "tight run: status {:?}, {} bytes written, filler {} bytes; before: {before}; after: {}",
            o.status.code(),
            std::fs::metadata(&h5).map_or(0, |m| m.len()),
            std::fs::metadata(&filler).map_or(0, |m| m.len()),
            disk.state()
        );
    }
    refused(
        &o,
        4,
        &[
            "complete output steps",
            "then continue with `mpirun -n 2 eprop run",
            "--restart",
        ],
    );
    restart_completes(dir, &sc, &h5, 2, filler);
}

/// The series a full disk stopped is readable to its last complete step, which is finite;
/// once the `filler` is gone, `--restart` on `ranks` completes it bit for bit.
fn restart_completes(dir: &Path, sc: &Path, h5: &Path, ranks: usize, filler: PathBuf) {
    let (last, finite) = last_step(h5);
    assert!(finite, "the last complete step is not finite");
    std::fs::remove_file(&filler).unwrap();
    let target = (last + 10).to_string();
    ok(&eprop(
        ranks,
        &["run", s(sc), "-q", "--restart", s(h5), "--steps", &target],
    ));
    let whole = dir.join("whole.h5");
    let _ = std::fs::remove_file(&whole);
    ok(&eprop(1, &["run", s(sc), "-q", "-o", s(&whole), "--steps", &target]));
    assert_same(&whole, h5);
    std::fs::remove_file(h5).unwrap();
}

/// The shipped sphere press (scenarios/cylinder_indent.toml with its path table and mesh)
/// copied into `dir`; returns the scenario's path there.
fn indent_scenario(dir: &Path) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    for f in ["cylinder_indent.toml", "cylinder_indent_path.csv", "cylinder.msh"] {
        std::fs::copy(root.join(f), dir.join(f)).unwrap();
    }
    dir.join("cylinder_indent.toml")
}

/// The tables a scenario reads (a tool's path, a load's forces) are inputs too: `-o`,
/// `[output] file` and `serve -o` naming one are refused and the table stays as it was.
#[test]
fn an_output_that_is_a_load_or_tool_table_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = indent_scenario(dir);
    let path = dir.join("cylinder_indent_path.csv");
    std::fs::write(dir.join("forces.csv"), "0,0,0,0\n1,-0.1,0,0\n").unwrap();
    let with_load = dir.join("load.toml");
    std::fs::write(
        &with_load,
        format!(
            "[mesh]\nfile = \"cylinder.msh\"\n[model]\nreading = \"paper\"\n{}\n[[load]]\nnearest = [1.0, 0.0, 2.0]\ntable = \"forces.csv\"\n[time]\nsteps = 3\n[output]\nfile = \"forces.csv\"\n",
            "[[fixed]]\ngroup = \"bottom\""
        ),
    )
    .unwrap();
    let forces = dir.join("forces.csv");
    let before = contents(&[&sc, &path, &forces, &dir.join("cylinder.msh")]);
    refused(
        &eprop(1, &["run", s(&sc), "-q", "-o", s(&path)]),
        1,
        &["is the path table of [[tool]] 1", "fix:"],
    );
    refused(
        &eprop(2, &["run", s(&sc), "-q", "-o", s(&path)]),
        1,
        &["is the path table of [[tool]] 1"],
    );
    refused(
        &eprop(1, &["run", s(&with_load), "-q"]),
        1,
        &["is the force table of [[load]] 1", "fix:"],
    );
    refused(
        &eprop(1, &["export-operator", s(&sc), "-o", s(&path)]),
        1,
        &["the path table of [[tool]] 1"],
    );
    assert_eq!(before, contents(&[&sc, &path, &forces, &dir.join("cylinder.msh")]));
}

#[test]
fn a_second_writer_through_a_symbolic_or_hard_link_is_refused_and_the_restart_command_finishes_the_job() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 20_000);
    edit(&sc, "steps = 20000", "steps = 100\nh = 0.002\n");
    let h5 = dir.join("shared.h5");
    // the job's length comes from the command line: the printed restart command must keep it
    let mut first = spawn(1, &["run", s(&sc), "-q", "-o", s(&h5), "--steps", "20000"]);
    wait_for_steps(&h5, 2, &mut first);
    std::os::unix::fs::symlink(&h5, dir.join("soft.h5")).unwrap();
    std::fs::create_dir(dir.join("other")).unwrap();
    let hard = dir.join("other/hard.h5");
    std::fs::hard_link(&h5, &hard).unwrap();
    let soft = dir.join("soft.h5");
    for (out, extra) in [
        (&soft, None),
        (&soft, Some("--overwrite")),
        (&hard, Some("--overwrite")),
    ] {
        let mut args = vec!["run", s(&sc), "-q", "-o", s(out)];
        args.extend(extra);
        refused(&eprop(1, &args), 1, &["is writing this file now", "fix:"]);
    }
    refused(
        &eprop(1, &["run", s(&sc), "-q", "-o", s(&hard), "--overwrite"]),
        1,
        &["a hard link to the same file"],
    );
    for link in [&soft, &hard] {
        refused(
            &eprop(1, &["run", s(&sc), "-q", "--restart", s(link)]),
            1,
            &["is writing this file now"],
        );
        refused(
            &eprop(1, &["export-operator", s(&sc), "-o", s(link), "--overwrite"]),
            1,
            &["is writing this file now"],
        );
    }
    assert!(first.try_wait().unwrap().is_none(), "the first job ended");
    Command::new("kill")
        .args(["-TERM", &first.id().to_string()])
        .status()
        .unwrap();
    let o = finish(first, 120, "the first job");
    refused(&o, 3, &["stopped by SIGTERM", "--steps 20000 -q`"]);
    let e = stderr(&o);
    let cmd = e
        .split("continue with `")
        .nth(1)
        .and_then(|r| r.split('`').next())
        .unwrap();
    assert_eq!(
        cmd,
        format!("eprop run {} --restart {} --steps 20000 -q", s(&sc), s(&h5))
    );
    assert!(last_step(&h5).1);
    // the links name the same series: a restart through one goes on once the writer is gone
    assert!(!dir.join("shared.h5.lock").exists());
    let k = steps_complete(&h5);
    ok(&eprop(
        1,
        &[
            "run",
            s(&sc),
            "-q",
            "--restart",
            s(&soft),
            "--steps",
            &(k + 3).to_string(),
        ],
    ));
    assert!(steps_complete(&h5) > k);
}

#[test]
fn a_lock_file_that_is_not_ours_is_neither_followed_nor_overwritten_nor_removed() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 1);
    let victim = dir.join("victim.msh");
    std::fs::write(&victim, "a mesh someone needs").unwrap();
    std::os::unix::fs::symlink(&victim, dir.join("a.h5.lock")).unwrap();
    refused(
        &eprop(1, &["run", s(&sc), "-q", "-o", s(&dir.join("a.h5"))]),
        1,
        &["a.h5.lock: the lock file of the output is a symbolic link", "fix:"],
    );
    refused(
        &eprop(2, &["run", s(&sc), "-q", "-o", s(&dir.join("a.h5"))]),
        1,
        &["is a symbolic link"],
    );
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "a mesh someone needs");
    assert!(std::fs::symlink_metadata(dir.join("a.h5.lock"))
        .unwrap()
        .file_type()
        .is_symlink());
    let notes = dir.join("b.h5.lock");
    std::fs::write(&notes, "my notes").unwrap();
    for cmd in [
        vec!["run", s(&sc), "-q", "-o", s(&dir.join("b.h5"))],
        vec!["mesh", "box", "--cells", "1,1,1", "-o", s(&dir.join("b.h5"))],
    ] {
        refused(
            &eprop(1, &cmd),
            1,
            &[
                "b.h5.lock: the lock file of the output exists and is not an eprop lock file",
                "fix:",
            ],
        );
    }
    assert_eq!(std::fs::read_to_string(&notes).unwrap(), "my notes");
    assert!(!dir.join("a.h5").exists() && !dir.join("b.h5").exists());
    // the lock file of a run killed with -9 is ours: the next run takes it, then removes it
    std::fs::write(dir.join("c.h5.lock"), "eprop lock\npid 1 on elsewhere\n").unwrap();
    ok(&eprop(1, &["run", s(&sc), "-q", "-o", s(&dir.join("c.h5"))]));
    assert!(!dir.join("c.h5.lock").exists());
}

#[test]
fn every_command_that_writes_refuses_an_existing_file_unless_overwrite() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 2);
    let mesh = dir.join("cyl.msh");
    let series = dir.join("s.h5");
    ok(&eprop(1, &["run", s(&sc), "-q", "-o", s(&series)]));
    let notes = dir.join("notes.txt");
    std::fs::write(&notes, "keep me").unwrap();
    let keep = [&mesh, &series, &notes];
    let before = contents(&[&mesh, &series, &notes]);
    for target in keep {
        for cmd in [
            vec!["export-operator", s(&sc), "-o", s(target)],
            vec!["mesh", "box", "--cells", "1,1,1", "-o", s(target)],
            vec!["mesh", "cylinder", "-o", s(target)],
            vec!["bench", "--cells", "2", "--schemes", "compact", "--json", s(target)],
        ] {
            if cmd[0] == "export-operator" && target == &mesh {
                continue; // an input: refused as such below
            }
            refused(&eprop(1, &cmd), 1, &["exists", "--overwrite", "fix:"]);
        }
    }
    refused(
        &eprop(1, &["convert", s(&mesh), s(&notes)]),
        1,
        &["exists", "--overwrite"],
    );
    // never an input, not even with --overwrite
    refused(
        &eprop(1, &["convert", s(&mesh), s(&mesh), "--overwrite"]),
        1,
        &["is the input mesh"],
    );
    refused(
        &eprop(1, &["export-operator", s(&sc), "-o", s(&mesh), "--overwrite"]),
        1,
        &["is the mesh"],
    );
    assert_eq!(before, contents(&[&mesh, &series, &notes]));
    // with --overwrite they replace the file, and a new file needs nothing
    let out = dir.join("out.msh");
    ok(&eprop(1, &["convert", s(&mesh), s(&out)]));
    ok(&eprop(1, &["convert", s(&mesh), s(&out), "--overwrite"]));
    ok(&eprop(
        1,
        &["mesh", "box", "--cells", "1,1,1", "-o", s(&out), "--overwrite"],
    ));
    ok(&eprop(1, &["mesh", "--overwrite", "cylinder", "-o", s(&out)]));
    ok(&eprop(1, &["export-operator", s(&sc), "-o", s(&series), "--overwrite"]));
    let j = dir.join("b.json");
    ok(&eprop(
        1,
        &["bench", "--cells", "2", "--schemes", "compact", "--json", s(&j)],
    ));
    assert!(std::fs::read_to_string(&j).unwrap().starts_with('['));
    assert!(!dir.join("b.json.lock").exists() && !dir.join("out.msh.lock").exists());
}

/// The CSR datasets of an exported operator.
fn operator(h5: &Path) -> (Vec<i64>, Vec<i64>, Vec<f64>) {
    let f = hdf5::File::open(h5).unwrap();
    (
        f.dataset("row_ptr").unwrap().read_raw().unwrap(),
        f.dataset("col").unwrap().read_raw().unwrap(),
        f.dataset("val").unwrap().read_raw().unwrap(),
    )
}

#[test]
fn export_operator_on_2_ranks_has_one_writer() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 2);
    let one = dir.join("one.h5");
    ok(&eprop(1, &["export-operator", s(&sc), "-o", s(&one)]));
    for k in 0..3 {
        let two = dir.join(format!("two{k}.h5"));
        let o = eprop(2, &["export-operator", s(&sc), "-o", s(&two)]);
        ok(&o);
        let out = String::from_utf8_lossy(&o.stdout).to_string();
        assert_eq!(out.matches(" rows").count(), 1, "one report: {out}");
        assert_eq!(operator(&one), operator(&two));
        assert!(!dir.join(format!("two{k}.h5.lock")).exists());
        // the second time the file exists: refused on every rank alike, the file kept
        let o = eprop(2, &["export-operator", s(&sc), "-o", s(&two)]);
        refused(&o, 1, &["exists", "--overwrite"]);
        assert_eq!(stderr(&o).matches("exists").count(), 1, "{}", stderr(&o));
        assert_eq!(operator(&one), operator(&two));
    }
}

#[test]
fn a_restart_with_a_changed_load_table_is_refused_naming_the_table() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let table = dir.join("forces.csv");
    std::fs::write(&table, "t,fx,fy,fz\n0,0,0,0\n1,-0.1,0,0\n").unwrap();
    let sc = cylinder(
        dir,
        "s.toml",
        "[[load]]\nnearest = [0.0, 1.0, 3.0]\ntable = \"forces.csv\"\n",
        3,
    );
    let h5 = dir.join("t.h5");
    ok(&eprop(1, &["run", s(&sc), "-q", "-o", s(&h5)]));
    let whole = dir.join("whole.h5");
    ok(&eprop(1, &["run", s(&sc), "-q", "-o", s(&whole), "--steps", "6"]));
    std::fs::write(&table, "t,fx,fy,fz\n0,0,0,0\n1,-0.5,0,0\n").unwrap();
    for ranks in [1, 2] {
        refused(
            &eprop(ranks, &["run", s(&sc), "-q", "--restart", s(&h5), "--steps", "6"]),
            1,
            &["cannot restart: the table forces.csv changed", "fix:"],
        );
    }
    assert_eq!(steps_complete(&h5), 4);
    std::fs::write(&table, "t,fx,fy,fz\n0,0,0,0\n1,-0.1,0,0\n").unwrap();
    ok(&eprop(1, &["run", s(&sc), "-q", "--restart", s(&h5), "--steps", "6"]));
    assert_same(&whole, &h5);
}

#[test]
fn a_tiny_disk_is_refused_before_anything_is_written_even_forced() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 3);
    for size in ["4k", "8k"] {
        let Some(disk) = Tmpfs::mount(size) else { return };
        let out = disk.path().join("o.h5");
        for ranks in [1, 2] {
            let o = eprop(ranks, &["run", s(&sc), "-q", "-o", s(&out), "--force"]);
            refused(&o, 1, &["not even --force starts", "fix: free space"]);
            assert!(!out.exists(), "{size}, {ranks} rank(s): a file stays");
            assert!(!disk.path().join("o.h5.lock").exists());
        }
    }
}

/// Every size of a small disk from 4 KiB to 400 KiB (refused before the start), then sizes
/// where a forced run starts and the disk refuses a write in the middle of the run, on 2
/// ranks: each run ends by itself (under a time limit) with status 0, 1 or 4, never a signal
/// or a hang, and a file it leaves is a readable series with finite steps.
#[test]
fn a_sweep_of_small_disks_on_2_ranks_never_hangs_or_crashes() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 300);
    let mut sizes: Vec<u64> = (1..=16).map(|k| 4 * k).collect();
    sizes.extend((1..=21).map(|k| 64 + 16 * k));
    sizes.extend((0..=12).map(|k| 1200 + 100 * k));
    let mut seen = std::collections::BTreeMap::new();
    for kib in sizes {
        let Some(disk) = Tmpfs::mount(&format!("{kib}k")) else {
            return;
        };
        let out = disk.path().join("o.h5");
        let job = spawn(2, &["run", s(&sc), "-q", "-o", s(&out), "--force"]);
        let o = finish(job, 60, &format!("2 ranks on a {kib} KiB disk"));
        let code = o.status.code();
        assert!(
            matches!(code, Some(0 | 1 | 4)),
            "{kib} KiB: status {:?}: {}",
            o.status,
            stderr(&o)
        );
        if out.exists() {
            let (_, finite) = last_step(&out);
            assert!(finite, "{kib} KiB: the last step is not finite");
        }
        assert!(!disk.path().join("o.h5.lock").exists(), "{kib} KiB: the lock stays");
        *seen.entry(code).or_insert(0) += 1;
    }
    eprintln!("statuses over the sweep: {seen:?}");
}

/// A run with a tool (a path table) stopped part-way, by its step count or by SIGTERM,
/// continues with `--restart` on 1 or 2 ranks to the series of the uninterrupted run, bit for
/// bit; the refusal of an existing series advises that restart.
#[test]
fn a_tool_run_restarts_bit_for_bit_and_the_refusal_advises_it() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = indent_scenario(dir);
    let whole = dir.join("whole.h5");
    ok(&eprop(1, &["run", s(&sc), "-q", "-o", s(&whole), "--steps", "60"]));
    for (first, then) in [(1, 2), (2, 1)] {
        let h5 = dir.join(format!("cut{first}{then}.h5"));
        ok(&eprop(first, &["run", s(&sc), "-q", "-o", s(&h5), "--steps", "25"]));
        let o = eprop(first, &["run", s(&sc), "-q", "-o", s(&h5), "--steps", "60"]);
        refused(&o, 1, &["holds an eprop series", "continue it with `", "--restart"]);
        ok(&eprop(
            then,
            &["run", s(&sc), "-q", "--restart", s(&h5), "--steps", "60"],
        ));
        assert_same(&whole, &h5);
    }
    // stopped by SIGTERM while it presses, then continued
    let h5 = dir.join("term.h5");
    let mut job = spawn(2, &["run", s(&sc), "-q", "-o", s(&h5), "--steps", "60"]);
    wait_for_steps(&h5, 10, &mut job);
    for pid in common::children(job.id()) {
        Command::new("kill").args(["-TERM", &pid.to_string()]).status().unwrap();
    }
    let o = finish(job, 60, "the tool run stopped by SIGTERM");
    if o.status.code() == Some(0) {
        eprintln!("the tool run finished before SIGTERM came: nothing to continue");
        return;
    }
    refused(&o, 3, &["--restart"]);
    ok(&eprop(1, &["run", s(&sc), "-q", "--restart", s(&h5), "--steps", "60"]));
    assert_same(&whole, &h5);
}

#[test]
fn a_state_near_overflow_stops_the_run_and_is_not_restarted_from() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // products whose squares overflow (the energy |phi| and max |u| would be written as inf)
    // but that pass the check made when the scenario is read (young = 1e-300 and coupling =
    // 1e300 are refused there): the watch stops them at step 1 and names the cause
    for (name, extra, cause) in [
        ("young", "[tissue]\nyoung = 1e-180\n", "[tissue] young"),
        (
            "coupling",
            "[model]\nreading = \"paper\"\ncoupling = 1e170\n",
            "[model] coupling = 1e170 times load 1's energy density",
        ),
    ] {
        let sc = cylinder(dir, &format!("{name}.toml"), extra, 10);
        for ranks in [1, 2] {
            let h5 = dir.join(format!("{name}{ranks}.h5"));
            let o = eprop(ranks, &["run", s(&sc), "-q", "-o", s(&h5)]);
            refused(
                &o,
                1,
                &["no longer finite (NaN or inf)", "Likely cause:", cause, "fix:"],
            );
            assert!(!stderr(&o).contains("grew without bound"), "{}", stderr(&o));
            assert!(!stderr(&o).contains("young = 0.000"), "{}", stderr(&o));
            let (_, finite) = last_step(&h5);
            assert!(finite);
        }
    }
    // a restart from a last step whose potential is finite but whose energy |phi| overflows
    let sc = cylinder(dir, "s.toml", "", 4);
    let h5 = dir.join("s.h5");
    ok(&eprop(1, &["run", s(&sc), "-q"]));
    restart_refused_after_writing(&sc, &h5, "potential", [1e308, 1e308, 0.0]);
}

#[test]
fn nonsense_geometry_is_refused_or_warned_about() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // a scale that makes volumes overflow and the contact stress underflow (a load of zero)
    let sc = cylinder(dir, "big.toml", "", 4);
    edit(&sc, "file = \"cyl.msh\"\n", "file = \"cyl.msh\"\nscale = 1e100\n");
    for cmd in ["run", "check"] {
        let o = eprop(1, &[cmd, s(&sc)]);
        refused(&o, 1, &["[mesh] scale = 1e100 makes the mesh span", "fix:"]);
    }
    assert!(!dir.join("big.h5").exists());
    // a `nearest` point 1e150 away (every node equally far: node 1, "in the fixed set") is
    // refused as what it is
    let sc = cylinder(dir, "far.toml", "", 4);
    edit(&sc, "nearest = [1.0, 0.0, 2.0]", "nearest = [1e150, 0.0, 2.0]");
    for cmd in ["run", "check"] {
        let o = eprop(1, &[cmd, s(&sc)]);
        refused(
            &o,
            1,
            &[
                "[load] nearest: [1e150, 0e0, 2e0] is 1.0000e150 from the centre of the mesh",
                "fix:",
            ],
        );
        assert!(!stderr(&o).contains("fixed set"), "{}", stderr(&o));
    }
    // 20 extents away: still the nearest node, with its warning
    edit(&sc, "nearest = [1e150, 0.0, 2.0]", "nearest = [100.0, 0.0, 2.0]");
    let ws = warnings(&summary(&["check", s(&sc), "--json"]));
    assert!(has(&ws, &["load 1", "`nearest = [100, 0, 2]`", "fix:"]), "{ws:?}");
}

#[test]
fn an_unwritable_name_or_a_damaged_restart_file_is_status_1_not_disk_full() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 4);
    // a name HDF5 cannot take (not UTF-8)
    use std::os::unix::ffi::OsStrExt;
    let bad = dir.join(std::ffi::OsStr::from_bytes(b"\xff.h5"));
    let o = command(1, &["run", s(&sc), "-q", "-o"]).arg(&bad).output().unwrap();
    refused(
        &o,
        1,
        &[
            "creating the output file failed",
            "is the output a valid file name?",
            "fix:",
        ],
    );
    let h5 = dir.join("s.h5");
    ok(&eprop(1, &["run", s(&sc), "-q"]));
    // a truncated copy
    let cut = dir.join("cut.h5");
    std::fs::copy(&h5, &cut).unwrap();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&cut)
        .unwrap()
        .set_len(20_000)
        .unwrap();
    for ranks in [1, 2] {
        let o = eprop(ranks, &["run", s(&sc), "-q", "--restart", s(&cut), "--steps", "8"]);
        refused(
            &o,
            1,
            &["opening the file to restart failed", "not truncated or damaged", "fix:"],
        );
    }
    // a tampered count of complete steps
    common::set_steps_complete(&h5, 301);
    for ranks in [1, 2] {
        let o = eprop(ranks, &["run", s(&sc), "-q", "--restart", s(&h5), "--steps", "8"]);
        refused(
            &o,
            1,
            &[
                "steps_complete = 301 but `",
                "holds 5 complete steps",
                "changed or damaged",
                "fix:",
            ],
        );
    }
}

#[test]
fn a_missing_time_table_is_named_as_such() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let sc = cylinder(dir, "s.toml", "", 4);
    edit(&sc, "[time]\nsteps = 4\n", "");
    for cmd in ["run", "check"] {
        let o = eprop(1, &[cmd, s(&sc)]);
        refused(&o, 1, &["s.toml: missing table [time]; fix: add a [time] table"]);
        assert!(!stderr(&o).contains("[mesh]"), "{}", stderr(&o));
    }
}

#[test]
fn a_generator_refuses_sizes_whose_mesh_its_reader_would_refuse() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    for (args, name) in [
        (vec!["box", "--size", "1e150,1e150,1e150"], "box.msh"),
        (vec!["box", "--size", "1e-100,1e-100,1e-100"], "small.msh"),
    ] {
        let out = dir.join(name);
        let mut a = vec!["mesh"];
        a.extend(args);
        a.extend(["-o", s(&out)]);
        let o = eprop(1, &a);
        refused(&o, 1, &["must lie between 1e-60 and 1e60", "fix:"]);
        assert!(!out.exists());
    }
}

#[test]
fn check_warns_about_what_serve_refuses() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let tool = "[[tool]]\nshape = \"sphere\"\nradius = 0.1\nstart = [0, 0, 10]\nlive = true\n";
    let sc = cylinder(dir, "live.toml", &tool.repeat(33), 4);
    let ws = warnings(&summary(&["check", s(&sc), "--json"]));
    assert!(
        has(&ws, &["`eprop serve` will refuse", "tool or load 33 is live", "fix:"]),
        "{ws:?}"
    );
    let sc = cylinder(dir, "ok.toml", &tool.repeat(32), 4);
    let ws = warnings(&summary(&["check", s(&sc), "--json"]));
    assert!(!has(&ws, &["`eprop serve` will refuse"]), "{ws:?}");
}

/// Parameters whose products overflow or underflow are refused when the scenario is read, by
/// `check` and `run` alike (on 2 ranks too), naming the keys, their values and the fix;
/// nothing is written. An overflowing mechanics bound is not blamed on "stiffness = 0 and
/// damping = 0".
#[test]
fn products_that_overflow_or_underflow_are_refused_when_the_scenario_is_read() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let continuum = "[model]\nreading = \"continuum\"\n[material]\nconductivity = 1e-300\n";
    let cases: [(&str, &str, &[&str]); 6] = [
        (
            "[tissue]\nyoung = 1e-300\n",
            "",
            &["[tissue] young = 1e-300", "q(sigma) is about", "above 1e200"],
        ),
        (
            "[tissue]\nyoung = 1e300\n",
            "",
            &["[tissue] young = 1e300", "below 1e-200", "underflows"],
        ),
        (
            "[model]\nreading = \"paper\"\ncoupling = 1e300\n",
            "",
            &["[model] coupling = 1e300", "a push of about 3.9e298", "above 1e200"],
        ),
        (
            "",
            "normal = 1e250",
            &["load 1's force 1.0000e250", "contact stress sigma", "above 1e200"],
        ),
        (
            continuum,
            "",
            &["[material] conductivity 1e-300 m^2/s", "flux source", "below 1e-200"],
        ),
        (
            "[material]\nmass = 1e300\ndamping = 1e-300\n[model]\nreading = \"paper\"\nstiffness = 0.0\n",
            "",
            &["[material] mass = 1e300, damping = 1e-300 and [model] stiffness = 0 overflows"],
        ),
    ];
    for (k, (extra, load, needles)) in cases.iter().enumerate() {
        let sc = cylinder(dir, &format!("p{k}.toml"), extra, 5);
        if !load.is_empty() {
            edit(&sc, "normal = 0.3", load);
        }
        if extra.contains("continuum") {
            edit(&sc, "file = \"cyl.msh\"\n", "file = \"cyl.msh\"\nunit = \"m\"\n");
        }
        for args in [vec!["check", s(&sc)], vec!["run", s(&sc), "-q"]] {
            let o = eprop(1, &args);
            let mut all = needles.to_vec();
            all.push("fix:");
            refused(&o, 1, &all);
            assert!(!stderr(&o).contains("stiffness = 0 and damping = 0"), "{}", stderr(&o));
            assert!(!stderr(&o).contains("no longer finite"), "{}", stderr(&o));
        }
        assert!(!dir.join(format!("p{k}.h5")).exists(), "case {k} wrote output");
    }
    let o = eprop(2, &["run", s(&dir.join("p0.toml")), "-q"]);
    refused(&o, 1, &["[tissue] young = 1e-300", "above 1e200", "fix:"]);
    // a scale that puts the load's point at the mesh's fixed end says so
    let sc = cylinder(dir, "scaled.toml", "", 2);
    edit(&sc, "file = \"cyl.msh\"\n", "file = \"cyl.msh\"\nscale = 1e59\n");
    let o = eprop(1, &["check", s(&sc)]);
    refused(
        &o,
        1,
        &[
            "is in the fixed set",
            "(the mesh spans (-1.0000e59, -9.8481e58, 0.0000) .. (1.0000e59, 9.8481e58, 4.0000e59); with [mesh] scale = 1e59 every length of the scenario",
            "fix:",
        ],
    );
    // a support given in the file's millimetres where the scenario's lengths are metres
    // holds every node: said at its line, with the mesh's extent as read (not as a stability
    // bound that overflows)
    std::fs::write(
        dir.join("all.toml"),
        "[mesh]\nfile = \"cyl.msh\"\nunit = \"mm\"\n[model]\nreading = \"continuum\"\n[[fixed]]\nhalfspace = { point = [0, 0, 2], normal = [0, 0, -1] }\n[[load]]\nnearest = [0.001, 0, 0.004]\nforce = [0, 0, -0.1]\n[time]\nsteps = 1\n",
    )
    .unwrap();
    let o = eprop(1, &["check", s(&dir.join("all.toml"))]);
    refused(
        &o,
        1,
        &[
            "all.toml:7: [fixed] halfspace: selects every node of the mesh, so nothing can move",
            "(the mesh spans (-0.001000, -0.000985, 0.000000) .. (0.001000, 0.000985, 0.004000); with [mesh] unit = \"mm\" the mesh is read in metres",
            "fix:",
        ],
    );
    // the same cylinder in the continuum reading, its mesh read in mm and in m, and the
    // paper's defaults: accepted
    for (k, extra) in [
        "[model]\nreading = \"continuum\"\n",
        "[model]\nreading = \"continuum\"\n[tissue]\nyoung = 1e6\n",
        "",
    ]
    .iter()
    .enumerate()
    {
        let sc = cylinder(dir, &format!("ok{k}.toml"), extra, 2);
        if extra.contains("continuum") {
            edit(&sc, "file = \"cyl.msh\"\n", "file = \"cyl.msh\"\nunit = \"mm\"\n");
            ok(&eprop(1, &["check", s(&sc)]));
            edit(&sc, "unit = \"mm\"", "unit = \"m\"");
        }
        ok(&eprop(1, &["check", s(&sc)]));
    }
}

/// A run of more than 20 digits in `text` (a number printed in full), if any.
fn long_number(text: &str) -> Option<String> {
    let mut run = String::new();
    for c in text.chars().chain(std::iter::once(' ')) {
        if c.is_ascii_digit() {
            run.push(c);
        } else if run.len() > 20 {
            return Some(run);
        } else {
            run.clear();
        }
    }
    None
}

/// A negative zero in `text` ("-0", "-0.000", "-0.0000e0"), if any.
fn negative_zero(text: &str) -> Option<String> {
    let b = text.as_bytes();
    for (i, _) in text.match_indices("-0") {
        let rest: String = text[i + 1..].chars().take_while(|c| *c == '0' || *c == '.').collect();
        let next = b.get(i + 1 + rest.len()).copied();
        if !matches!(next, Some(b'1'..=b'9')) {
            return Some(text[i..(i + 12).min(text.len())].to_string());
        }
    }
    None
}

/// Every number in a message (errors, warnings, check's report, the summary) is short: fixed
/// for moderate magnitudes, exponent form for huge or tiny ones, never 300 digits and never a
/// negative zero.
#[test]
fn messages_print_no_long_decimals_and_no_negative_zero() {
    assert_eq!(
        long_number("dt = 1000000000000000000000000 s"),
        Some("1000000000000000000000000".into())
    );
    assert_eq!(long_number("12345678901234567890 and 1e300"), None);
    assert_eq!(negative_zero("F = (-0.3000, -0.0000, 1)"), Some("-0.0000, 1)".into()));
    assert_eq!(negative_zero("u = (-0.0000e0)"), Some("-0.0000e0)".into()));
    assert_eq!(negative_zero("-0.5 and -0.01 and --overwrite"), None);
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::write(dir.join("late.csv"), "t,fx,fy,fz\n0,0,0,0\n1e300,1,0,0\n1e299,1,0,0\n").unwrap();
    let tool = |r: &str, start: &str| {
        format!("[[tool]]\nshape = \"sphere\"\nradius = {r}\nstart = {start}\nvelocity = [-0.01, 0, 0]\n")
    };
    let cases: Vec<(String, &str, &str)> = vec![
        // the summary of a plain run: F = (-0.3000, -0.0000, -0.0000) before
        (String::new(), "", ""),
        (String::new(), "steps = 3", "steps = 3\ndt = 1e300"),
        (String::new(), "steps = 3", "steps = 3\nh = 1e300"),
        (
            String::new(),
            "normal = 0.3",
            "normal = 0.3\nramp = [[0, 0], [1e300, 1]]",
        ),
        (String::new(), "normal = 0.3", "table = \"late.csv\""),
        (
            String::new(),
            "nearest = [1.0, 0.0, 2.0]",
            "nearest = [1e5, 1e-20, -1e5]",
        ),
        ("[material]\nmass = -1e300\n".into(), "", ""),
        ("[integrator]\ntolerance = 1e300\n".into(), "", ""),
        ("[tissue]\nyoung = 1e300\n".into(), "", ""),
        (tool("0.1", "[1e300, 0, 2]"), "", ""),
        (tool("1e300", "[0, 0, 10]"), "", ""),
        (tool("0.1", "[-1e40, 0, 2]"), "", ""),
    ];
    for (k, (extra, from, to)) in cases.iter().enumerate() {
        let sc = cylinder(dir, &format!("m{k}.toml"), extra, 3);
        if !from.is_empty() {
            edit(&sc, from, to);
        }
        for args in [vec!["check", s(&sc)], vec!["run", s(&sc), "--overwrite"]] {
            let o = eprop(1, &args);
            let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), stderr(&o));
            assert_eq!(long_number(&text), None, "case {k} ({extra}{to}), {}: {text}", args[0]);
            assert_eq!(
                negative_zero(&text),
                None,
                "case {k} ({extra}{to}), {}: {text}",
                args[0]
            );
        }
    }
}

/// A sphere whose centre starts inside the organ deeper than its radius is warned about by
/// `check` and at the start of `run` (what happens: a large foundation force from step 0, and
/// the fix); one that starts outside is not.
#[test]
fn a_sphere_started_deep_inside_the_organ_is_warned_about() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let inside = "[[tool]]\nshape = \"sphere\"\nradius = 0.8\nstart = [0, 0, 2]\nvelocity = [0.01, 0, 0]\n";
    let sc = cylinder(dir, "in.toml", inside, 2);
    let needles = [
        "tool 1: its centre starts inside the organ",
        "deeper than its radius 0.8",
        "a large foundation force and source from step 0",
        "fix: start it outside the organ",
    ];
    let ws = warnings(&summary(&["check", s(&sc), "--json"]));
    assert!(has(&ws, &needles), "{ws:?}");
    assert!(!has(&ws, &["never reaches the organ's surface"]), "{ws:?}");
    let o = eprop(1, &["run", s(&sc)]);
    ok(&o);
    assert!(needles.iter().all(|n| stderr(&o).contains(n)), "{}", stderr(&o));
    let o = eprop(2, &["run", s(&sc), "--overwrite"]);
    ok(&o);
    assert!(stderr(&o).contains(needles[0]), "{}", stderr(&o));
    // pressing from outside, and a sphere inside but within its radius of the surface
    for (k, start) in ["[1.85, 0, 2]", "[0.5, 0, 2]"].iter().enumerate() {
        let sc = cylinder(dir, &format!("out{k}.toml"), &inside.replace("[0, 0, 2]", start), 2);
        let ws = warnings(&summary(&["check", s(&sc), "--json"]));
        assert!(!has(&ws, &["starts inside the organ"]), "{start}: {ws:?}");
    }
}
