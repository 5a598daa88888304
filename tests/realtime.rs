//! The real-time mode (`[time] realtime = true`, docs/realtime.md): within 1e-2 of euler at
//! the same dt with a tool pressing, at most the operator applications per step its plan
//! bounds, and the same bits on 1..4 processes (with the direct solver where the library has
//! CHOLMOD, with the fixed multigrid iterations otherwise).

mod common;

use common::{assert_same, mpirun, serial};
use eprop::config::integrator::Kind;
use eprop::simulate::realtime::{compare, TOLERANCE};
use eprop::simulate::Simulation;
use eprop_io::generate::{box_mesh, BoxCells};
use std::path::Path;

/// A 40 x 40 x 30 mm block in the continuum reading, held at its base, pressed from above by
/// a sphere of 6 mm at 40 mm/s from 0.5 mm above it, 1 ms steps: an organ's scale, loads and
/// time step.
const PRESS: &str = "[model]\nreading = \"continuum\"\n[[fixed]]\ngroup = \"zmin\"\n[[tool]]\nshape = \"sphere\"\nradius = 0.006\nstart = [0.021, 0.019, 0.0365]\nvelocity = [0.0, 0.0, -0.04]\n[time]\nsteps = 80\ndt = 0.001\n";

fn block() -> eprop_io::Mesh {
    box_mesh([0.04, 0.04, 0.03], [10, 10, 8], BoxCells::Tet).unwrap()
}

#[test]
fn the_real_time_mode_is_within_1e_2_of_euler_with_a_tool_pressing() {
    within_1e_2_of_euler("auto");
}

/// `[time] realtime_solver = "direct"` (where the library has CHOLMOD) and `"iterative"`:
/// each within the mode's bound of euler, each as its plan says.
#[test]
fn both_real_time_solvers_are_within_1e_2_of_euler() {
    if eprop::linalg::direct::HAS_DIRECT {
        within_1e_2_of_euler("direct");
    } else {
        let d = tempfile::tempdir().unwrap();
        let sets = ["time.realtime=true".into(), "time.realtime_solver=\"direct\"".into()];
        let e = Simulation::new(common::setup_with(block(), PRESS, d.path(), &sets))
            .err()
            .expect("direct refused without CHOLMOD")
            .to_string();
        assert!(
            e.contains("realtime_solver = \"direct\"") && e.contains("CHOLMOD"),
            "{e}"
        );
    }
    within_1e_2_of_euler("iterative");
}

fn within_1e_2_of_euler(solver: &str) {
    let d = tempfile::tempdir().unwrap();
    let sets = [
        "time.realtime=true".into(),
        format!("time.realtime_solver=\"{solver}\""),
    ];
    let rt = common::setup_with(block(), PRESS, d.path(), &sets);
    let eu = common::setup_with(block(), PRESS, d.path(), &["model.integrator=\"euler\"".into()]);
    let why = Simulation::new(common::setup_with(block(), PRESS, d.path(), &sets))
        .unwrap()
        .step_plan()
        .why
        .clone();
    let direct = match solver {
        "direct" => true,
        "iterative" => false,
        _ => eprop::linalg::direct::HAS_DIRECT,
    };
    assert_eq!(why.contains("direct solves"), direct, "{solver}: {why}");
    let c = compare(rt, eu, 80).unwrap();
    eprintln!("{solver}: {c:?}");
    assert_eq!(c.steps, 80);
    assert!(c.u_error < TOLERANCE, "u differs from euler's by {:.2e}", c.u_error);
    assert!(
        c.force_error < TOLERANCE,
        "the tool force differs by {:.2e} of the peak",
        c.force_error
    );
    // the counter: no step took more operator applications than the plan's bound
    assert!(
        c.applications_max > 0 && c.applications_max <= c.applications_bound,
        "{c:?}"
    );
}

#[test]
fn every_real_time_step_is_bounded_by_its_plan() {
    let d = tempfile::tempdir().unwrap();
    let setup = common::setup_with(block(), PRESS, d.path(), &["time.realtime=true".into()]);
    let mut s = Simulation::new(setup).unwrap();
    let plan = s.step_plan().clone();
    assert_eq!(plan.integrator, Kind::Implicit);
    assert!(plan.why.contains("real time"), "{}", plan.why);
    if eprop::linalg::direct::HAS_DIRECT {
        // the direct solver (a factor made at setup): stage 1's right-hand side alone
        assert!(plan.why.contains("direct solves"), "{}", plan.why);
        assert_eq!(plan.per_step, 1);
    } else {
        // 1 + 2 (k + 2) with k within the real-time mode's clamp
        let k = (plan.per_step - 1) / 2 - 2;
        assert_eq!(plan.per_step, 1 + 2 * (k + 2));
        assert!((2..=40).contains(&k), "{k}");
    }
    let mut counts = Vec::new();
    while !s.done() {
        counts.push(s.advance().unwrap().applications);
    }
    assert!(
        counts.iter().all(|&a| a <= plan.per_step),
        "{counts:?} > {}",
        plan.per_step
    );
    // the tool touches and presses: the held rows change every step, the bound holds
    assert!(s.tool_states()[0].force[2].abs() > 0.0);
}

/// A mesh above `linalg::direct::MAX_NODES`: `realtime_solver = "direct"` is refused with
/// the reason, auto takes the fixed iterations.
#[test]
fn the_direct_real_time_solver_is_refused_on_a_mesh_too_big() {
    let d = tempfile::tempdir().unwrap();
    let big = || box_mesh([0.04, 0.04, 0.03], [40, 40, 37], BoxCells::Tet).unwrap();
    assert!(big().points.len() > eprop::linalg::direct::MAX_NODES);
    let sets = ["time.realtime=true".into(), "time.realtime_solver=\"direct\"".into()];
    let e = Simulation::new(common::setup_with(big(), PRESS, d.path(), &sets))
        .err()
        .expect("direct refused")
        .to_string();
    assert!(e.contains("realtime_solver = \"direct\"") && e.contains("fix:"), "{e}");
    if eprop::linalg::direct::HAS_DIRECT {
        assert!(e.contains("above the direct solver's 60000"), "{e}");
    }
}

#[test]
fn the_real_time_mode_gives_the_same_bits_on_1_to_4_processes() {
    same_bits_on(1..=4, "auto");
}

/// The fixed iterations (`realtime_solver = "iterative"`) on 1 and 3 processes.
#[test]
fn the_iterative_real_time_solver_gives_the_same_bits_on_1_and_3_processes() {
    same_bits_on([1, 3], "iterative");
}

fn same_bits_on(counts: impl IntoIterator<Item = usize>, solver: &str) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let d = tempfile::tempdir().unwrap();
    let sc = d.path().join("indent.toml");
    let text = std::fs::read_to_string(root.join("cylinder_indent.toml"))
        .unwrap()
        .replace("\"cylinder.msh\"", &format!("{:?}", root.join("cylinder.msh")))
        .replace(
            "\"cylinder_indent_path.csv\"",
            &format!("{:?}", root.join("cylinder_indent_path.csv")),
        )
        .replace(
            "end = 100.0",
            &format!("end = 30.0\nrealtime = true\nrealtime_solver = \"{solver}\""),
        )
        .replace("every = 1", "every = 3");
    std::fs::write(&sc, text).unwrap();
    let sc = sc.to_str().unwrap();
    let one = d.path().join("one.h5");
    let out = serial(&["run", sc, "-q", "-o", one.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for n in counts {
        let f = d.path().join(format!("n{n}.h5"));
        let out = mpirun(n, &["run", sc, "-q", "-o", f.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{n} ranks: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert_same(&one, &f);
    }
}
