//! Distributed runs: `mpirun -n 1..4` must write bitwise the same datasets as one process,
//! for both schemes, on a generated mesh and on a real organ mesh; a failing rank must end
//! the whole job with a non-zero exit, quickly.

mod common;

use common::{assert_same, mpirun, serial};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

fn check_ranks(mesh: &Path, extra: &str, tag: &str) {
    let d = tempfile::Builder::new().prefix(tag).tempdir().unwrap();
    let sc = d.path().join("s.toml");
    std::fs::write(
        &sc,
        common::paper(&format!(
            "[mesh]\nfile = \"{}\"\n{extra}[time]\nsteps = 8\n[output]\nevery = 2\n",
            mesh.display()
        )),
    )
    .unwrap();
    let sc = sc.to_str().unwrap();
    let one = d.path().join("one.h5");
    let out = serial(&["run", sc, "-q", "-o", one.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let two_threads = d.path().join("threads.h5");
    let out = serial(&["run", sc, "-q", "-o", two_threads.to_str().unwrap()], 2);
    assert!(out.status.success());
    assert_same(&one, &two_threads);
    for n in 1..=4 {
        let f = d.path().join(format!("n{n}.h5"));
        let out = mpirun(n, &["run", sc, "-q", "-o", f.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{n} ranks: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("on {n} process")));
        assert_same(&one, &f);
    }
}

const CYL: &str = "[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 1.0\n";

#[test]
fn bitwise_identical_on_1_to_4_ranks_generated_mesh() {
    let d = tempfile::tempdir().unwrap();
    let mesh = d.path().join("cyl.msh");
    eprop_io::write_mesh(&eprop_io::generate::cylinder_mesh(1.0, 4.0, 4, 14).unwrap(), &mesh).unwrap();
    check_ranks(&mesh, CYL, "compact");
    check_ranks(
        &mesh,
        &format!("[model]\nreading = \"paper\"\nscheme = \"paper\"\n{CYL}"),
        "paper",
    );
    check_ranks(
        &mesh,
        &format!("[model]\nreading = \"paper\"\nscheme = \"paper\"\npaper_correction = false\n{CYL}"),
        "paper-raw",
    );
}

/// Float32 output with deflate on several ranks (parallel HDF5 writes filtered chunks only
/// without a type conversion): the same bits as one process, and each value is the float64
/// run's value rounded to float32.
#[test]
fn float32_deflated_output_on_1_and_2_ranks() {
    let d = tempfile::tempdir().unwrap();
    let mesh = d.path().join("cyl.msh");
    eprop_io::write_mesh(&eprop_io::generate::cylinder_mesh(1.0, 4.0, 4, 14).unwrap(), &mesh).unwrap();
    let scenario = |name: &str, output: &str| {
        let sc = d.path().join(name);
        std::fs::write(
            &sc,
            format!(
                "[mesh]\nfile = \"{}\"\n[model]\nreading = \"paper\"\n{CYL}[time]\nsteps = 6\n[output]\nevery = 2\n{output}",
                mesh.display()
            ),
        )
        .unwrap();
        sc.to_str().unwrap().to_string()
    };
    let narrow = scenario("f32.toml", "precision = \"float32\"\ncompression = 4\n");
    let wide = scenario("f64.toml", "");
    let one = d.path().join("one.h5");
    let out = serial(&["run", &narrow, "-q", "-o", one.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let two = d.path().join("two.h5");
    let out = mpirun(2, &["run", &narrow, "-q", "-o", two.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "2 ranks: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_same(&one, &two);
    let full = d.path().join("f64.h5");
    let out = serial(&["run", &wide, "-q", "-o", full.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (a, b) = (hdf5::File::open(&two).unwrap(), hdf5::File::open(&full).unwrap());
    let u32s = a.dataset("VTKHDF/PointData/displacement").unwrap();
    assert!(u32s.dtype().unwrap().is::<f32>());
    assert!(u32s
        .filters()
        .iter()
        .any(|f| matches!(f, hdf5::filters::Filter::Deflate(_))));
    let x = u32s.read_raw::<f32>().unwrap();
    let y = b
        .dataset("VTKHDF/PointData/displacement")
        .unwrap()
        .read_raw::<f64>()
        .unwrap();
    assert_eq!(x.len(), y.len());
    assert!(x.iter().any(|&v| v != 0.0));
    assert!(x.iter().zip(&y).all(|(&p, &q)| p.to_bits() == (q as f32).to_bits()));
}

#[test]
fn bitwise_identical_on_1_to_4_ranks_mixed_elements() {
    use eprop_io::generate::{box_mesh, BoxCells};
    let d = tempfile::tempdir().unwrap();
    let box_case =
        "[[fixed]]\nhalfspace = { point = [0.0, 0.0, 0.001], normal = [0.0, 0.0, -1.0] }\n[[load]]\npatch = { center = [0.5, 0.5, 1.0], radius = 0.3 }\nnormal = 1.0\n";
    for (cells, file) in [(BoxCells::PyramidTet, "pyr.vtu"), (BoxCells::Hex, "hex.msh")] {
        let mesh = d.path().join(file);
        eprop_io::write_mesh(&box_mesh([1.0, 1.0, 1.0], [5, 4, 6], cells).unwrap(), &mesh).unwrap();
        check_ranks(&mesh, box_case, file);
        check_ranks(
            &mesh,
            &format!("[model]\nreading = \"paper\"\nscheme = \"paper\"\n{box_case}"),
            &format!("{file}-paper"),
        );
    }
}

/// Writes `dir/s.toml` (`head`, then 4 steps, every step written) and runs it on one process
/// with one substep per sweep (`--fuse 1`) to `dir/plain.h5`: the reference of the fused runs.
/// Returns the scenario's path, the reference's and the run's stdout.
fn unfused(dir: &Path, head: &str) -> (String, std::path::PathBuf, String) {
    let sc = dir.join("s.toml");
    std::fs::write(&sc, format!("{head}[time]\nsteps = 4\n[output]\nevery = 1\n")).unwrap();
    let sc = sc.to_str().unwrap().to_string();
    let plain = dir.join("plain.h5");
    let out = mpirun(1, &["run", &sc, "-q", "--fuse", "1", "-o", plain.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    (sc, plain, String::from_utf8_lossy(&out.stdout).to_string())
}

/// Temporal blocking (`Propagation::substeps`, on by default on one process) against one sweep
/// per substep (`--fuse 1`): bitwise the same output on one process and on 1-4 ranks, for fused
/// sweeps of 2, 3 and 8 substeps (7 substeps per step: full and shorter sweeps both run), set
/// on the command line and in `[performance]`, and with processes that group their substeps
/// differently (a process with two threads does not fuse).
#[test]
fn fused_sweeps_are_bitwise_one_sweep_per_substep_on_1_to_4_ranks() {
    let d = tempfile::Builder::new().prefix("fused").tempdir().unwrap();
    let mesh = d.path().join("cyl.msh");
    eprop_io::write_mesh(&eprop_io::generate::cylinder_mesh(1.0, 4.0, 4, 14).unwrap(), &mesh).unwrap();
    let (sc, plain, stdout) = unfused(
        d.path(),
        &format!(
            "[mesh]\nfile = \"{}\"\n[model]\nreading = \"paper\"\n{CYL}",
            mesh.display()
        ),
    );
    let sc = sc.as_str();
    assert!(stdout.contains("7 substeps"), "{stdout}");
    for fuse in ["2", "3", "8"] {
        for n in 1..=4 {
            let f = d.path().join(format!("f{fuse}n{n}.h5"));
            let out = mpirun(n, &["-vv", "run", sc, "-q", "--fuse", fuse, "-o", f.to_str().unwrap()]);
            let log = String::from_utf8_lossy(&out.stderr);
            assert!(out.status.success(), "fuse {fuse}, {n} ranks: {log}");
            // every process fuses as told (not tuned, not left at one substep per sweep)
            let want = format!("propagation: {fuse} substeps per sweep");
            assert_eq!(log.matches(&want).count(), n, "fuse {fuse}, {n} ranks: {log}");
            assert!(log.contains("wavefront: "), "fuse {fuse}, {n} ranks: {log}");
            assert_same(&plain, &f);
        }
    }
    // the same from the scenario's [performance] table (the scenario text differs, so the
    // reference is the unfused run of this scenario)
    let text = std::fs::read_to_string(sc).unwrap();
    let table = d.path().join("t.toml");
    std::fs::write(&table, format!("{text}[performance]\nfuse = 4\n")).unwrap();
    let table = table.to_str().unwrap();
    let (t1, t4) = (d.path().join("t1.h5"), d.path().join("t4.h5"));
    let out = mpirun(1, &["run", table, "-q", "--fuse", "1", "-o", t1.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = mpirun(3, &["-vv", "run", table, "-q", "-o", t4.to_str().unwrap()]);
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{log}");
    assert_eq!(log.matches("propagation: 4 substeps per sweep").count(), 3, "{log}");
    assert_same(&t1, &t4);
    // processes that fuse and processes that do not (two threads: the wavefront is
    // sequential) pair their halo messages (one exchange per substep) and give the same bits
    for (fuse, threads) in [
        ("4", &["1", "2"][..]),
        ("8", &["2", "1", "1"]),
        ("3", &["1", "2", "1", "2"]),
    ] {
        let f = d.path().join(format!("mixed{fuse}-{}.h5", threads.len()));
        let mut cmd = Command::new("mpirun");
        cmd.arg("--oversubscribe");
        for (k, t) in threads.iter().enumerate() {
            if k > 0 {
                cmd.arg(":");
            }
            cmd.args([
                "-x",
                &format!("RAYON_NUM_THREADS={t}"),
                "-n",
                "1",
                env!("CARGO_BIN_EXE_eprop"),
            ]);
            cmd.args(["run", sc, "-q", "--fuse", fuse, "-o", f.to_str().unwrap()]);
        }
        let out = cmd
            .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
            .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "fuse {fuse}, threads {threads:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert_same(&plain, &f);
    }
}

/// Both schemes on a shared organ mesh (skipped without the shared data).
fn organ(name: &str, setting: &str, tag: &str) {
    let Some(mesh) = common::shared_mesh(name) else {
        return;
    };
    check_ranks(&mesh, setting, tag);
    check_ranks(
        &mesh,
        &format!("[model]\nreading = \"paper\"\nscheme = \"paper\"\n{setting}"),
        &format!("{tag}-paper"),
    );
}

#[test]
fn bitwise_identical_on_1_to_4_ranks_organ_mesh() {
    // fixed on the left lobe's end, pressed on the top
    organ(
        "sofa_liver2.msh",
        "[material]\nconductivity = [0.08, 0.05, 0.05]\n[[fixed]]\nhalfspace = { point = [-1.0, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }\n[[load]]\nnearest = [0.0, 0.7, 0.0]\nnormal = 1.0\n",
        "liver",
    );
}

#[test]
fn bitwise_identical_on_1_to_4_ranks_vtu_liver() {
    // fixed at the left tip, pressed on the top
    organ(
        "mor_liverFine.vtu",
        "[[fixed]]\nhalfspace = { point = [-4.0, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }\n[[load]]\nnearest = [0.0, 5.2, 0.5]\nnormal = 1.0\n",
        "vtu-liver",
    );
}

#[test]
fn bitwise_identical_on_1_to_4_ranks_every_deterministic_integrator() {
    let d = tempfile::tempdir().unwrap();
    let mesh = d.path().join("cyl.msh");
    eprop_io::write_mesh(&eprop_io::generate::cylinder_mesh(1.0, 4.0, 4, 14).unwrap(), &mesh).unwrap();
    // stiff enough for tens of stages and iterations; a tolerance that is not the default
    // (it travels in the part sent to every rank)
    let stiff = format!("[material]\nconductivity = 2.0\n{CYL}");
    check_ranks(
        &mesh,
        &format!("[model]\nreading = \"paper\"\nintegrator = \"rkl2\"\n{stiff}"),
        "rkl2",
    );
    check_ranks(
        &mesh,
        &format!(
            "[model]\nreading = \"paper\"\nintegrator = \"implicit\"\n[integrator]\ntolerance = 1e-10\npreconditioner = \"jacobi\"\n{stiff}"
        ),
        "implicit",
    );
    check_ranks(
        &mesh,
        &format!("[integrator]\npreconditioner = \"jacobi\"\n{stiff}"),
        "auto",
    );
    // the multigrid's coarse levels are global: the same bits too, on a box large enough to
    // coarsen twice, under error control
    let cube = d.path().join("cube.msh");
    eprop_io::write_mesh(
        &eprop_io::generate::box_mesh([1.0; 3], [14, 14, 14], eprop_io::generate::BoxCells::Tet).unwrap(),
        &cube,
    )
    .unwrap();
    check_ranks(
        &cube,
        "[model]\nreading = \"paper\"\nintegrator = \"implicit\"\n[integrator]\npreconditioner = \"multigrid\"\naccuracy = 1e-4\n[material]\nconductivity = 0.5\n[[fixed]]\ngroup = \"xmin\"\n[[load]]\nnearest = [1.0, 0.5, 0.5]\nnormal = 1.0\n",
        "multigrid",
    );
}

#[test]
fn bitwise_identical_on_1_to_4_ranks_every_integrator_organ_mesh() {
    let Some(mesh) = common::shared_mesh("mor_liverFine.vtu") else {
        return;
    };
    let case = "[material]\nconductivity = 0.3\n[[fixed]]\nhalfspace = { point = [-4.0, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }\n[[load]]\nnearest = [0.0, 5.2, 0.5]\nnormal = 1.0\n";
    for (kind, pre) in [("rkl2", "jacobi"), ("implicit", "jacobi"), ("implicit", "multigrid")] {
        check_ranks(
            &mesh,
            &format!("[model]\nreading = \"paper\"\nintegrator = \"{kind}\"\n[integrator]\npreconditioner = \"{pre}\"\n{case}"),
            kind,
        );
    }
}

/// Implicit runs with the preconditioner `pre` on 1 to `max_ranks` ranks agree with the
/// Jacobi path to the solver tolerance.
fn preconditioned_runs_agree(pre: &str, max_ranks: usize) {
    let d = tempfile::tempdir().unwrap();
    let mesh = d.path().join("cyl.msh");
    eprop_io::write_mesh(&eprop_io::generate::cylinder_mesh(1.0, 4.0, 4, 14).unwrap(), &mesh).unwrap();
    let scenario = |pre: &str| {
        let sc = d.path().join(format!("{pre}.toml"));
        std::fs::write(
            &sc,
            format!(
                "[mesh]\nfile = \"{}\"\n[model]\nreading = \"paper\"\nintegrator = \"implicit\"\n[integrator]\ntolerance = 1e-10\npreconditioner = \"{pre}\"\n[material]\nconductivity = 2.0\n{CYL}[time]\nsteps = 8\n",
                mesh.display()
            ),
        )
        .unwrap();
        sc
    };
    let read = |f: &Path| -> Vec<f64> {
        let h = hdf5::File::open(f).unwrap();
        h.dataset("VTKHDF/PointData/displacement")
            .unwrap()
            .read_raw::<f64>()
            .unwrap()
    };
    let (other, jacobi) = (scenario(pre), scenario("jacobi"));
    let reference = d.path().join("jacobi.h5");
    let out = serial(
        &["run", jacobi.to_str().unwrap(), "-q", "-o", reference.to_str().unwrap()],
        1,
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let want = read(&reference);
    let norm = want.iter().map(|x| x * x).sum::<f64>().sqrt();
    for n in 1..=max_ranks {
        let f = d.path().join(format!("{pre}{n}.h5"));
        let out = mpirun(n, &["run", other.to_str().unwrap(), "-q", "-o", f.to_str().unwrap()]);
        assert!(out.status.success(), "{n}: {}", String::from_utf8_lossy(&out.stderr));
        assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("{pre} preconditioner")));
        let got = read(&f);
        let diff = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
        assert!(
            diff < 1e-8 * norm,
            "{pre}, {n} ranks: relative difference {}",
            diff / norm
        );
    }
}

#[test]
fn amg_preconditioned_runs_agree_across_ranks_to_the_solver_tolerance() {
    if !eprop::linalg::HAS_AMG {
        common::skip("hypre was not found when eprop was built (libhypre-dev or HYPRE_DIR)");
        return;
    }
    // hypre's V-cycle follows the partition
    preconditioned_runs_agree("amg", 3);
}

#[test]
fn multigrid_preconditioned_runs_agree_across_ranks_to_the_solver_tolerance() {
    // (and bitwise across ranks: bitwise_identical_on_1_to_4_ranks_every_deterministic_integrator)
    preconditioned_runs_agree("multigrid", 3);
}

/// A generated cylinder in `dir` and a scenario on it with `steps` steps.
fn cylinder_scenario(dir: &Path, rings: usize, layers: usize, steps: u64) -> std::path::PathBuf {
    let mesh = dir.join("cyl.msh");
    eprop_io::write_mesh(
        &eprop_io::generate::cylinder_mesh(1.0, 4.0, rings, layers).unwrap(),
        &mesh,
    )
    .unwrap();
    let sc = dir.join("s.toml");
    std::fs::write(
        &sc,
        format!(
            "[mesh]\nfile = \"{}\"\n[model]\nreading = \"paper\"\n{CYL}[time]\nsteps = {steps}\n",
            mesh.display()
        ),
    )
    .unwrap();
    sc
}

/// A one-cube box (8 nodes, 6 tetrahedra) in `dir` and a one-step scenario on it.
fn tiny_box_scenario(dir: &Path) -> std::path::PathBuf {
    let tiny = dir.join("tiny.msh");
    eprop_io::write_mesh(
        &eprop_io::generate::box_mesh([1.0; 3], [1, 1, 1], eprop_io::generate::BoxCells::Tet).unwrap(),
        &tiny,
    )
    .unwrap();
    let sc = dir.join("tiny.toml");
    std::fs::write(
        &sc,
        format!(
            "[mesh]\nfile = \"{}\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"xmin\"\n[time]\nsteps = 1\n",
            tiny.display()
        ),
    )
    .unwrap();
    sc
}

#[test]
fn a_failing_rank_ends_the_job_quickly() {
    let d = tempfile::tempdir().unwrap();
    let sc = cylinder_scenario(d.path(), 3, 11, 5);
    // the output directory does not exist: every rank fails
    let t = Instant::now();
    let out = mpirun(2, &["run", sc.to_str().unwrap(), "-q", "-o", "/nonexistent/dir/x.h5"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("output directory"));
    // a hang detector, generous for a loaded machine
    assert!(t.elapsed() < Duration::from_secs(120));
    // more ranks than nodes of a tiny mesh
    let sc = tiny_box_scenario(d.path());
    let t = Instant::now();
    let out = mpirun(
        2,
        &[
            "run",
            sc.to_str().unwrap(),
            "-q",
            "-o",
            d.path().join("t.h5").to_str().unwrap(),
        ],
    );
    assert!(
        out.status.success(),
        "2 ranks on 8 nodes must work: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    // a hang detector, generous for a loaded machine
    assert!(t.elapsed() < Duration::from_secs(120));
}

#[test]
fn a_killed_rank_ends_the_job_and_leaves_a_readable_file() {
    let d = tempfile::tempdir().unwrap();
    let sc = cylinder_scenario(d.path(), 6, 24, 100_000_000);
    let h5 = d.path().join("k.h5");
    let mut child = Command::new("mpirun")
        .args(["-n", "2", "--oversubscribe"])
        .arg(env!("CARGO_BIN_EXE_eprop"))
        // --force: the step count is a stand-in for "until killed", far more than the disk holds
        .args(["run", sc.to_str().unwrap(), "-q", "--force", "-o", h5.to_str().unwrap()])
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("RAYON_NUM_THREADS", "1")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // wait until both ranks run and some steps are in the file
    let t = Instant::now();
    let ranks = loop {
        let r = common::children(child.id());
        // the file is created, then its first step flushed (a slow or loaded machine may take
        // seconds for either): kill only once a step is complete
        // the counter, not its attribute: a commit sets the attribute first and the counter
        // last, so a kill between the two leaves the attribute one commit ahead
        let written = || common::count_of(&hdf5::File::open(&h5).ok()?);
        if r.len() == 2 && written().is_some_and(|k| k >= 1) {
            break r;
        }
        assert!(t.elapsed() < Duration::from_secs(120), "the job did not start");
        std::thread::sleep(Duration::from_millis(100));
    };
    let killed = Instant::now();
    Command::new("kill")
        .args(["-9", &ranks[1].to_string()])
        .status()
        .unwrap();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if killed.elapsed() > Duration::from_secs(90) {
            let _ = child.kill();
            panic!("mpirun still runs 90 s after a rank was killed");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(!status.success(), "mpirun exited 0 after a rank was killed");
    eprintln!("mpirun ended {:.2} s after kill -9", killed.elapsed().as_secs_f64());
    // every flushed step is readable
    let f = hdf5::File::open(&h5).expect("the file opens after the crash");
    let done = common::steps_complete(&h5);
    assert!(done >= 1, "no complete step in the file");
    let n: i64 = f.dataset("VTKHDF/NumberOfPoints").unwrap().read_raw::<i64>().unwrap()[0];
    let u = f.dataset("VTKHDF/PointData/displacement").unwrap();
    assert!(u.shape()[0] as i64 >= done * n);
    let last = eprop_series::vtkhdf::read_step(&h5, "displacement", done as usize - 1).unwrap();
    assert!(last.iter().all(|x| x.is_finite()));
}

#[test]
fn more_ranks_than_nodes_is_a_clear_error() {
    let d = tempfile::tempdir().unwrap();
    let sc = tiny_box_scenario(d.path());
    let out = mpirun(
        9,
        &[
            "run",
            sc.to_str().unwrap(),
            "-q",
            "-o",
            d.path().join("t.h5").to_str().unwrap(),
        ],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("9 parts for 8 nodes") && err.contains("fix:"), "{err}");
    assert_eq!(err.matches("9 parts for 8 nodes").count(), 1, "printed once: {err}");
}

#[test]
fn bench_runs_on_one_and_two_ranks() {
    let d = tempfile::tempdir().unwrap();
    for n in [1, 2] {
        let j = d.path().join(format!("b{n}.json"));
        let out = Command::new("timeout")
            // a hang detector, generous for a loaded machine
            .args(["600", "mpirun", "-n", &n.to_string(), "--oversubscribe"])
            .arg(env!("CARGO_BIN_EXE_eprop"))
            .args([
                "bench",
                "--cells",
                "6",
                "--schemes",
                "compact,paper,compact32",
                "--json",
            ])
            .arg(&j)
            .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
            .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
            .env("RAYON_NUM_THREADS", "1")
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let cases: serde_json::Value = serde_json::from_slice(&std::fs::read(&j).unwrap()).unwrap();
        let cases = cases.as_array().unwrap();
        assert_eq!(cases.len(), 3);
        for c in cases {
            assert_eq!(c["processes"].as_u64(), Some(n as u64));
            assert_eq!(c["nodes"].as_u64(), Some(343));
            assert!(c["node_substeps_per_second"].as_f64().unwrap() > 0.0);
            assert!(c["bytes_per_node_substep"].as_f64().unwrap() > 100.0);
        }
    }
}

/// Every dataset of two series but the scenario text (whose `[performance]` key differs),
/// bit for bit (`common::assert_same` without `/eprop/scenario`).
fn assert_same_results(a: &Path, b: &Path) {
    let (fa, fb, names) = common::open_pair(a, b);
    let k = common::steps_complete(a) as usize;
    assert_eq!(k as i64, common::steps_complete(b));
    let n = fa.dataset("VTKHDF/NumberOfPoints").unwrap().read_raw::<i64>().unwrap()[0] as usize;
    for name in names.iter().filter(|n| n.as_str() != "/eprop/scenario") {
        assert_eq!(
            common::counted_bits(&fa, name, k, n),
            common::counted_bits(&fb, name, k, n),
            "{name} of {} and {}",
            a.display(),
            b.display()
        );
    }
}

/// `[performance] partitioner = "ptscotch"`: PT-Scotch splits the node graph on every process
/// (each given a slab); the series has the bits of METIS's split on 2 and 3 ranks, and the
/// PT-Scotch split is the same on repeated runs (`mpirun eprop partition`), and another split
/// than METIS's (so the comparison compares something).
#[test]
fn ptscotch_split_gives_the_bits_of_the_metis_split_on_2_and_3_ranks() {
    let d = tempfile::Builder::new().prefix("ptscotch").tempdir().unwrap();
    let mesh = d.path().join("cyl.msh");
    eprop_io::write_mesh(&eprop_io::generate::cylinder_mesh(1.0, 4.0, 4, 14).unwrap(), &mesh).unwrap();
    let sc = d.path().join("s.toml");
    std::fs::write(
        &sc,
        common::paper(&format!(
            "[mesh]\nfile = \"{}\"\n{CYL}[time]\nsteps = 8\n[output]\nevery = 2\n",
            mesh.display()
        )),
    )
    .unwrap();
    let sc = sc.to_str().unwrap();
    // the split's own check on a larger graph (9,261 nodes), where PT-Scotch's threads, left
    // on, split differently from run to run
    let boxm = d.path().join("box.msh");
    let cube = eprop_io::generate::box_mesh([1.0; 3], [20; 3], eprop_io::generate::BoxCells::Tet).unwrap();
    eprop_io::write_mesh(&cube, &boxm).unwrap();
    let mut other_split = false;
    for n in [2, 3] {
        let metis = d.path().join(format!("metis{n}.h5"));
        let out = mpirun(n, &["run", sc, "-v", "-o", metis.to_str().unwrap()]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert!(String::from_utf8_lossy(&out.stderr).contains(&format!("into {n} parts (METIS)")));
        let scotch = d.path().join(format!("scotch{n}.h5"));
        let set = ["--set", "performance.partitioner=ptscotch"];
        let out = mpirun(
            n,
            &[&["run", sc, "-v", "-o", scotch.to_str().unwrap()][..], &set].concat(),
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{err}");
        if err.contains("this build has no PT-Scotch") {
            common::skip("this build has no PT-Scotch (libptscotch-dev)");
            return;
        }
        assert!(err.contains(&format!("into {n} parts (PT-Scotch)")), "{err}");
        assert!(!err.contains("split by METIS"), "{err}");
        assert_same_results(&metis, &scotch);
        // the split itself, twice
        let report = || {
            let out = mpirun(
                n,
                &["partition", boxm.to_str().unwrap(), "--parts", &n.to_string(), "--json"],
            );
            assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
            let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            let split = |name: &str| {
                let s = v["splits"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .find(|s| s["method"] == name)
                    .unwrap();
                (s["edge_cut"].clone(), s["owned"].clone(), s["halo"].clone())
            };
            (split("metis"), split("ptscotch"))
        };
        let (m, first) = report();
        for _ in 0..2 {
            assert_eq!(report().1, first, "PT-Scotch on {n} processes");
        }
        other_split |= first != m;
    }
    assert!(other_split, "PT-Scotch split as METIS did on 2 and 3 processes");
}

/// `eprop partition` of a .vtkhdf mesh (`eprop convert`): every process reads its slab and the
/// node graph is built from the slabs; the split and its measures are those of the whole mesh
/// (METIS on one process, PT-Scotch on the same slabs under mpirun), and after the cells and
/// coordinates move to their owners each process holds its owned nodes and exactly the halo
/// nodes the split's measure counts.
#[test]
fn a_vtkhdf_mesh_is_split_in_slabs_as_the_whole_mesh_is() {
    let d = tempfile::Builder::new().prefix("slabs").tempdir().unwrap();
    let (msh, h5) = (d.path().join("box.msh"), d.path().join("box.vtkhdf"));
    let cube = eprop_io::generate::box_mesh([1.0; 3], [20, 18, 16], eprop_io::generate::BoxCells::Tet).unwrap();
    eprop_io::write_mesh(&cube, &msh).unwrap();
    let out = serial(&["convert", msh.to_str().unwrap(), h5.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let json = |out: std::process::Output| -> serde_json::Value {
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_slice(&out.stdout).unwrap()
    };
    let split = |v: &serde_json::Value, name: &str| {
        v["splits"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["method"] == name)
            .map(|s| {
                (
                    s["edge_cut"].clone(),
                    s["owned"].clone(),
                    s["halo"].clone(),
                    s["neighbours"].clone(),
                )
            })
    };
    let whole = json(serial(
        &["partition", msh.to_str().unwrap(), "--parts", "3", "--json"],
        1,
    ));
    let slabs = json(serial(
        &["partition", h5.to_str().unwrap(), "--parts", "3", "--json"],
        1,
    ));
    assert_eq!(split(&slabs, "metis").unwrap(), split(&whole, "metis").unwrap());
    assert_eq!(slabs["graph_edges"], whole["graph_edges"]);
    for n in [2, 3] {
        let parts = n.to_string();
        let whole = json(mpirun(
            n,
            &["partition", msh.to_str().unwrap(), "--parts", &parts, "--json"],
        ));
        let slabs = json(mpirun(
            n,
            &["partition", h5.to_str().unwrap(), "--parts", &parts, "--json"],
        ));
        let Some(scotch) = split(&whole, "ptscotch") else {
            common::skip("this build has no PT-Scotch (libptscotch-dev)");
            return;
        };
        let mine = split(&slabs, "ptscotch").expect("PT-Scotch split the slabs");
        assert_eq!(mine, scotch, "{n} processes");
        assert_eq!(slabs["peak_memory"].as_array().unwrap().len(), n);
        let moved = slabs["moved"].as_array().unwrap();
        let col = |k: usize| -> Vec<u64> { moved.iter().map(|m| m[k].as_u64().unwrap()).collect() };
        let as_vec =
            |v: &serde_json::Value| -> Vec<u64> { v.as_array().unwrap().iter().map(|x| x.as_u64().unwrap()).collect() };
        assert_eq!(col(0), as_vec(&mine.1));
        assert_eq!(col(1), as_vec(&mine.2));
        assert_eq!(col(0).iter().sum::<u64>(), cube.n_nodes() as u64);
        assert!(col(2).iter().sum::<u64>() > cube.n_cells() as u64);
    }
}
