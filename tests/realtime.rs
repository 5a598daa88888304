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
    let d = tempfile::tempdir().unwrap();
    let rt = common::setup_with(block(), PRESS, d.path(), &["time.realtime=true".into()]);
    let eu = common::setup_with(block(), PRESS, d.path(), &["model.integrator=\"euler\"".into()]);
    let c = compare(rt, eu, 80).unwrap();
    eprintln!("{c:?}");
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

#[test]
fn the_real_time_mode_gives_the_same_bits_on_1_to_4_processes() {
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
        .replace("end = 100.0", "end = 30.0\nrealtime = true")
        .replace("every = 1", "every = 3");
    std::fs::write(&sc, text).unwrap();
    let sc = sc.to_str().unwrap();
    let one = d.path().join("one.h5");
    let out = serial(&["run", sc, "-q", "-o", one.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for n in 1..=4 {
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
