//! The output file as a product: restart continues bit for bit, a killed run leaves every
//! committed step readable, steps count only at a commit, readers see complete steps while the run goes on, appending does
//! not get slower with the number of steps, output options are honoured.

mod common;

use common::{assert_same, mpirun, processes, serial};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const CYL: &str = "[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 1.0\nramp = [[0.0, 0.0], [5.0, 1.0]]\n";

/// A generated cylinder and a scenario next to it; returns the scenario path.
fn scenario(dir: &Path, extra: &str, steps: u64) -> PathBuf {
    let mesh = dir.join("cyl.msh");
    if !mesh.exists() {
        eprop_io::write_mesh(&eprop_io::generate::cylinder_mesh(1.0, 4.0, 4, 14).unwrap(), &mesh).unwrap();
    }
    let sc = dir.join("s.toml");
    std::fs::write(
        &sc,
        common::paper(&format!(
            "[mesh]\nfile = \"cyl.msh\"\n{CYL}{extra}[time]\nsteps = {steps}\n"
        )),
    )
    .unwrap();
    sc
}

fn ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

use common::steps_complete;

#[test]
fn restart_continues_bit_for_bit_on_1_and_2_ranks() {
    let d = tempfile::tempdir().unwrap();
    let sc = scenario(d.path(), "[output]\nevery = 3\n", 30);
    let sc = sc.to_str().unwrap();
    let full = d.path().join("full.h5");
    ok(&serial(&["run", sc, "-q", "-o", full.to_str().unwrap()], 1));
    // stop at step 12 (an output step) on one count of processes, continue on the other
    for (first, then) in [(1, 2), (2, 1), (2, 2)] {
        let cut = d.path().join(format!("cut{first}{then}.h5"));
        let c = cut.to_str().unwrap();
        ok(&processes(first, &["run", sc, "-q", "-o", c, "--steps", "12"]));
        assert_eq!(steps_complete(&cut), 5);
        let out = processes(then, &["run", sc, "--restart", c]);
        ok(&out);
        assert!(String::from_utf8_lossy(&out.stdout).contains("restarted at step 12"));
        assert_same(&full, &cut);
    }
    assert_eq!(steps_complete(&full), 11);
}

#[test]
fn a_restart_of_a_complete_series_says_so_and_changes_nothing_on_1_and_2_ranks() {
    let d = tempfile::tempdir().unwrap();
    let sc = scenario(d.path(), "[output]\nevery = 2\n", 6);
    let sc = sc.to_str().unwrap();
    let h5 = d.path().join("a.h5");
    let h = h5.to_str().unwrap();
    ok(&serial(&["run", sc, "-q", "-o", h], 1));
    let before = std::fs::read(&h5).unwrap();
    for n in [1, 2] {
        let out = processes(n, &["run", sc, "--restart", h]);
        ok(&out);
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            text.contains("steps       6 to t = ") && text.contains("the series was complete already; nothing to do"),
            "{text}"
        );
        // no figures of a run that did not happen (they were -0.000 s and -0 node-substeps/s)
        assert!(
            !text.contains("-0") && !text.contains("speed") && !text.contains("restarted at"),
            "{text}"
        );
        assert!(text.contains("(4 steps)"), "{text}");
        // the JSON summary says it too, with no negative figures
        let out = serial(&["run", sc, "--restart", h, "--json"], 1);
        ok(&out);
        let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(json["already_complete"], true, "{json}");
        for k in ["output_seconds", "node_substeps_per_second", "wall_seconds"] {
            let v = json[k].as_f64().unwrap();
            assert!(v >= 0.0 && v.is_sign_positive(), "{k} = {v}");
        }
        assert_eq!(steps_complete(&h5), 4);
        assert_eq!(
            std::fs::read(&h5).unwrap(),
            before,
            "the file changed on {n} process(es)"
        );
    }
    // fewer steps asked than the series holds: said as such, the file as it was
    let out = serial(&["run", sc, "--restart", h, "--steps", "3"], 1);
    ok(&out);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("the series holds more steps than the 3 asked; nothing to do"),
        "{text}"
    );
    assert_eq!(std::fs::read(&h5).unwrap(), before);
}

#[test]
fn restart_refuses_another_scenario_or_mesh() {
    let d = tempfile::tempdir().unwrap();
    let sc = scenario(d.path(), "", 5);
    let h5 = d.path().join("a.h5");
    ok(&serial(
        &["run", sc.to_str().unwrap(), "-q", "-o", h5.to_str().unwrap()],
        1,
    ));
    // another scenario
    let other = d.path().join("other.toml");
    std::fs::write(
        &other,
        std::fs::read_to_string(&sc)
            .unwrap()
            .replace("normal = 1.0", "normal = 2.0"),
    )
    .unwrap();
    let out = serial(
        &["run", other.to_str().unwrap(), "-q", "--restart", h5.to_str().unwrap()],
        1,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("different scenario") && err.contains("fix:"), "{err}");
    // another mesh under the same name
    eprop_io::write_mesh(
        &eprop_io::generate::cylinder_mesh(1.0, 4.0, 4, 15).unwrap(),
        &d.path().join("cyl.msh"),
    )
    .unwrap();
    let out = serial(
        &["run", sc.to_str().unwrap(), "-q", "--restart", h5.to_str().unwrap()],
        1,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("different mesh"), "{err}");
    // a file that is not there, and float32 output
    let out = serial(&["run", sc.to_str().unwrap(), "-q", "--restart", "/nonexistent.h5"], 1);
    assert!(String::from_utf8_lossy(&out.stderr).contains("no such file to restart"));
    // what is there but is not a file is named for what it is (it was "no such file")
    for (what, said) in [
        (
            d.path().to_str().unwrap(),
            "is a directory, not a series to restart from; fix:",
        ),
        (
            "/dev/null",
            "/dev/null: is a character device, not a series to restart from; fix:",
        ),
    ] {
        let out = serial(&["run", sc.to_str().unwrap(), "-q", "--restart", what], 1);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains(said) && !err.contains("no such file"), "{err}");
    }
}

/// Starts `eprop run` (or mpirun) in the background.
fn spawn(ranks: usize, sc: &Path, h5: &Path) -> std::process::Child {
    let mut cmd = if ranks == 1 {
        Command::new(env!("CARGO_BIN_EXE_eprop"))
    } else {
        let mut c = Command::new("mpirun");
        c.args(["-n", &ranks.to_string(), "--oversubscribe"])
            .arg(env!("CARGO_BIN_EXE_eprop"));
        c
    };
    // --force: the step count is a stand-in for "until killed", far more than the disk holds
    cmd.args(["run", sc.to_str().unwrap(), "-q", "--force", "-o", h5.to_str().unwrap()])
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("RAYON_NUM_THREADS", "1")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// Opens the file while another process writes it; retries while a flush is under way.
fn read_live(h5: &Path) -> Option<(i64, Vec<f64>)> {
    for _ in 0..50 {
        let r = (|| -> hdf5::Result<(i64, Vec<f64>)> {
            let f = hdf5::File::open(h5)?;
            let Some(k) = common::count_of(&f) else {
                return Err(hdf5::Error::from("no step counter yet"));
            };
            if k == 0 {
                return Ok((0, vec![]));
            }
            let n = f.dataset("VTKHDF/NumberOfPoints")?.read_raw::<i64>()?[0] as usize;
            let u = f.dataset("VTKHDF/PointData/displacement")?;
            let rows = (k as usize - 1) * n;
            let last = u.read_slice_2d::<f64, _>(ndarray::s![rows..rows + n, ..])?;
            Ok((k, last.iter().copied().collect()))
        })();
        match r {
            Ok(x) => return Some(x),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
    None
}

#[test]
fn readers_see_complete_steps_while_the_run_goes_on() {
    for ranks in [1, 2] {
        let d = tempfile::tempdir().unwrap();
        let sc = scenario(d.path(), "", 100_000_000);
        let h5 = d.path().join("live.h5");
        let mut child = spawn(ranks, &sc, &h5);
        let t = Instant::now();
        let mut seen = vec![];
        // at least five reads, and until the count has grown (steps are committed about
        // once a second: a loaded machine may see the same count for a while)
        while !(seen.len() >= 5 && seen.last() > seen.first()) && t.elapsed() < Duration::from_secs(60) {
            std::thread::sleep(Duration::from_millis(300));
            if !h5.exists() {
                continue;
            }
            if let Some((k, last)) = read_live(&h5) {
                if k > 0 {
                    assert!(last.iter().all(|x| x.is_finite()), "step {k} holds non-finite values");
                    seen.push(k);
                }
            }
        }
        let _ = child.kill();
        let _ = child.wait();
        assert!(seen.len() >= 5, "{ranks} rank(s): too few reads succeeded: {seen:?}");
        assert!(
            seen.windows(2).all(|w| w[1] >= w[0]) && seen.last() > seen.first(),
            "{ranks} rank(s): the step count did not grow: {seen:?}"
        );
    }
}

/// The steps VTK reads (`NSteps`, and the extent of `Values`, which must equal it) and the
/// steps the file's displacement array has room for.
fn vtk_steps_and_room(h5: &Path) -> Option<(i64, usize, usize)> {
    let f = hdf5::File::open(h5).ok()?;
    let n = f.dataset("VTKHDF/NumberOfPoints").ok()?.read_raw::<i64>().ok()?[0] as usize;
    let ns = f.group("VTKHDF/Steps").ok()?.attr("NSteps").ok()?.read_scalar().ok()?;
    let values = f.dataset("VTKHDF/Steps/Values").ok()?.shape()[0];
    Some((
        ns,
        values,
        f.dataset("VTKHDF/PointData/displacement").ok()?.shape()[0] / n,
    ))
}

#[test]
fn written_steps_count_only_at_a_commit() {
    // [output] flush = 3600: after the first step nothing is committed until the run ends
    for ranks in [1, 2] {
        let d = tempfile::tempdir().unwrap();
        let sc = scenario(d.path(), "[output]\nflush = 3600\n", 100_000_000);
        let h5 = d.path().join("c.h5");
        let mut child = spawn(ranks, &sc, &h5);
        let t = Instant::now();
        // the first step is committed at once; the run then goes on for two seconds
        while !(h5.exists() && read_live(&h5).is_some_and(|(k, _)| k >= 1)) {
            assert!(
                t.elapsed() < Duration::from_secs(60),
                "{ranks} rank(s): no step committed"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        std::thread::sleep(Duration::from_secs(2));
        let (k, first) = read_live(&h5).expect("the file opens while the run goes on");
        assert_eq!(k, 1, "{ranks} rank(s): only the first step is counted before a commit");
        assert!(first.iter().all(|x| *x == 0.0));
        // a reader sees the file of the last commit: VTK reads the counted steps, of the room
        // made for the run
        let (ns, values, room) = vtk_steps_and_room(&h5).unwrap();
        assert_eq!((ns, values), (1, 1), "{ranks} rank(s)");
        assert!(room > 1, "{room}");
        if ranks == 1 {
            // a stop commits every step written
            assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
            let status = child.wait().unwrap();
            assert_eq!(status.code(), Some(3));
            let k = steps_complete(&h5);
            assert!(k >= 2, "{k} steps counted after the stop");
            let (ns, values, room) = vtk_steps_and_room(&h5).unwrap();
            assert_eq!((ns, values), (k, k as usize));
            assert!(room >= k as usize);
        } else {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
    // a crash loses the uncommitted steps, and --restart continues from the commit bit for bit
    let d = tempfile::tempdir().unwrap();
    let sc = scenario(d.path(), "[output]\nflush = 3600\n", 100_000_000);
    let h5 = d.path().join("k.h5");
    let mut child = spawn(1, &sc, &h5);
    let t = Instant::now();
    while !(h5.exists() && read_live(&h5).is_some_and(|(k, _)| k >= 1)) {
        assert!(t.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_secs(1));
    Command::new("kill")
        .args(["-9", &child.id().to_string()])
        .status()
        .unwrap();
    let _ = child.wait();
    assert_eq!(steps_complete(&h5), 1);
    let args = |o: &Path| {
        vec![
            "run".to_string(),
            sc.to_str().unwrap().to_string(),
            "-q".to_string(),
            "--steps".to_string(),
            "8".to_string(),
            "-o".to_string(),
            o.to_str().unwrap().to_string(),
        ]
    };
    let mut again: Vec<String> = args(&h5);
    again.truncate(5);
    again.extend(["--restart".to_string(), h5.to_str().unwrap().to_string()]);
    let again: Vec<&str> = again.iter().map(|s| s.as_str()).collect();
    ok(&serial(&again, 1));
    let whole = d.path().join("whole.h5");
    let whole_args = args(&whole);
    let whole_args: Vec<&str> = whole_args.iter().map(|s| s.as_str()).collect();
    ok(&serial(&whole_args, 1));
    assert_same(&whole, &h5);
    assert_eq!(steps_complete(&h5), 9);
}

#[test]
fn a_killed_run_leaves_every_flushed_step_and_restarts() {
    let d = tempfile::tempdir().unwrap();
    let sc = scenario(d.path(), "", 100_000_000);
    let h5 = d.path().join("k.h5");
    let mut child = spawn(1, &sc, &h5);
    let t = Instant::now();
    // until a commit after the first step (at least a second later, [output] flush)
    while !(h5.exists() && read_live(&h5).is_some_and(|(k, _)| k >= 2)) {
        assert!(t.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(50));
    }
    Command::new("kill")
        .args(["-9", &child.id().to_string()])
        .status()
        .unwrap();
    let status = child.wait().unwrap();
    assert!(!status.success());
    let (k, last) = read_live(&h5).expect("the file opens after kill -9");
    assert!(k >= 2, "only {k} steps complete");
    assert!(last.iter().all(|x| x.is_finite()));
    // continue to k + 20 steps and compare with a run that never stopped
    let target = (k + 20).to_string();
    ok(&serial(
        &[
            "run",
            sc.to_str().unwrap(),
            "-q",
            "--restart",
            h5.to_str().unwrap(),
            "--steps",
            &target,
        ],
        1,
    ));
    let whole = d.path().join("whole.h5");
    ok(&serial(
        &[
            "run",
            sc.to_str().unwrap(),
            "-q",
            "-o",
            whole.to_str().unwrap(),
            "--steps",
            &target,
        ],
        1,
    ));
    assert_same(&whole, &h5);
}

#[test]
fn appending_costs_the_same_for_every_step() {
    let d = tempfile::tempdir().unwrap();
    let sc = scenario(d.path(), "", 2000);
    let h5 = d.path().join("long.h5");
    let out = serial(
        &["run", sc.to_str().unwrap(), "-q", "--json", "-o", h5.to_str().unwrap()],
        1,
    );
    ok(&out);
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let first = s["output_append_first100_median_s"].as_f64().unwrap();
    let last = s["output_append_last100_median_s"].as_f64().unwrap();
    eprintln!("append: median of the first 100 steps {first:.2e} s, of the last 100 {last:.2e} s");
    // chunked, extendible datasets: the last appends must not cost a multiple of the first
    // (a rewrite of the series would make them ~2000x dearer); loose for a shared machine
    assert!(
        last < 20.0 * first + 1e-3,
        "appending slowed down: {first:e} s -> {last:e} s"
    );
    let f = hdf5::File::open(&h5).unwrap();
    let u = f.dataset("VTKHDF/PointData/displacement").unwrap();
    assert!(u.is_chunked());
    assert_eq!(steps_complete(&h5), 2001);
}

#[test]
fn output_options_select_fields_precision_and_compression() {
    let d = tempfile::tempdir().unwrap();
    let sc = scenario(
        d.path(),
        "[output]\nfields = [\"displacement\", \"energy\"]\nprecision = \"float32\"\ncompression = 4\n",
        6,
    );
    let h5 = d.path().join("o.h5");
    ok(&serial(
        &["run", sc.to_str().unwrap(), "-q", "-o", h5.to_str().unwrap()],
        1,
    ));
    let f = hdf5::File::open(&h5).unwrap();
    let pd = f.group("VTKHDF/PointData").unwrap();
    let mut names = pd.member_names().unwrap();
    names.sort();
    assert_eq!(names, ["displacement", "energy"]);
    let u = pd.dataset("displacement").unwrap();
    assert!(u.dtype().unwrap().is::<f32>());
    assert!(!u.filters().is_empty(), "no compression filter");
    // a float32 file cannot restart exactly
    let out = serial(
        &["run", sc.to_str().unwrap(), "-q", "--restart", h5.to_str().unwrap()],
        1,
    );
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("float32"));
    // float32 of the float64 run
    let full = d.path().join("full.h5");
    std::fs::write(
        &sc,
        std::fs::read_to_string(&sc)
            .unwrap()
            .replace("precision = \"float32\"", ""),
    )
    .unwrap();
    ok(&serial(
        &["run", sc.to_str().unwrap(), "-q", "-o", full.to_str().unwrap()],
        1,
    ));
    let a: Vec<f32> = u.read_raw().unwrap();
    let b: Vec<f64> = hdf5::File::open(&full)
        .unwrap()
        .dataset("VTKHDF/PointData/displacement")
        .unwrap()
        .read_raw()
        .unwrap();
    assert_eq!(a.len(), b.len());
    assert!(a.iter().zip(&b).all(|(x, y)| *x == *y as f32));
}

/// `/eprop/probes/{force,displacement}` are (steps, loads, 3) and `node` (loads,): a run
/// without loads has (steps, 0, 3), on one and two ranks and after a restart.
#[test]
fn probes_have_one_row_per_load_and_none_without_loads() {
    let d = tempfile::tempdir().unwrap();
    scenario(d.path(), "", 1); // the mesh
    let second = "[[load]]\nnearest = [-1.0, 0.0, 2.0]\nnormal = 0.5\n";
    let shapes = |h5: &Path| {
        let f = hdf5::File::open(h5).unwrap();
        let s = |n: &str| f.dataset(&format!("eprop/probes/{n}")).unwrap().shape();
        (s("node"), s("force"), s("displacement"), s("step"))
    };
    for (loads, body) in [(0, String::new()), (2, format!("{CYL}{second}"))] {
        let sc = d.path().join(format!("l{loads}.toml"));
        std::fs::write(
            &sc,
            common::paper(&format!(
                "[mesh]\nfile = \"cyl.msh\"\n[[fixed]]\ngroup = \"bottom\"\n{body}[time]\nsteps = 6\n"
            )),
        )
        .unwrap();
        let sc = sc.to_str().unwrap();
        for ranks in [1, 2] {
            let h5 = d.path().join(format!("l{loads}r{ranks}.h5"));
            let h = h5.to_str().unwrap();
            let run = |args: &[&str]| {
                if ranks == 1 {
                    serial(args, 1)
                } else {
                    mpirun(ranks, args)
                }
            };
            ok(&run(&["run", sc, "-q", "-o", h, "--steps", "3"]));
            assert_eq!(
                shapes(&h5),
                (vec![loads], vec![4, loads, 3], vec![4, loads, 3], vec![4])
            );
            ok(&run(&["run", sc, "-q", "--restart", h]));
            assert_eq!(
                shapes(&h5),
                (vec![loads], vec![7, loads, 3], vec![7, loads, 3], vec![7])
            );
            if loads == 2 {
                let f = hdf5::File::open(&h5).unwrap();
                let u = f
                    .dataset("eprop/probes/displacement")
                    .unwrap()
                    .read_raw::<f64>()
                    .unwrap();
                let last = &u[u.len() - 6..];
                assert!(
                    last[0] < 0.0 && last[3] > 0.0,
                    "both loads' contact moved inwards: {last:?}"
                );
            }
        }
    }
}

/// The mesh's cell tags are cell data of the series (a viewer colours by tissue), the same
/// rows at every step, also after a restart.
#[test]
fn cell_tags_are_cell_data_at_every_step() {
    let d = tempfile::tempdir().unwrap();
    let sc = scenario(d.path(), "", 4);
    let h5 = d.path().join("t.h5");
    let (sc, h) = (sc.to_str().unwrap(), h5.to_str().unwrap());
    ok(&mpirun(2, &["run", sc, "-q", "-o", h, "--steps", "2"]));
    ok(&serial(&["run", sc, "-q", "--restart", h], 1));
    let f = hdf5::File::open(&h5).unwrap();
    let tags = f.dataset("VTKHDF/CellData/tag").unwrap().read_raw::<i64>().unwrap();
    let cells = f.dataset("VTKHDF/NumberOfCells").unwrap().read_raw::<i64>().unwrap()[0];
    assert_eq!(tags.len() as i64, cells);
    let stored = f.dataset("eprop/cell_tags").unwrap().read_raw::<i64>().unwrap();
    assert_eq!(tags, stored);
    let offsets = f
        .dataset("VTKHDF/Steps/CellDataOffsets/tag")
        .unwrap()
        .read_raw::<i64>()
        .unwrap();
    assert_eq!(offsets, vec![0i64; 5], "one offset per output step (steps 0-4), all 0");
}
