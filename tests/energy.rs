//! The kinematic tools' energy account (docs/tools.md, "Energy"): over a press, a hold and a
//! release the tools' work equals the change of the energy the potential stores plus what its
//! relaxation dissipates, at every step; the dissipation never decreases; and where the energy
//! spreads slowly against the tool's speed the release's force lies below the press's
//! (hysteresis).

mod common;

use eprop::simulate::kinematic::Energy;
use eprop::simulate::Simulation;
use eprop_io::generate::{box_mesh, BoxCells};
use eprop_series::vtkhdf::ToolState;
use std::path::Path;

const PUNCH: &str = "shape = \"punch\"\nradius = 0.005\nnormal = [0, 0, -1]";
const SPHERE: &str = "shape = \"sphere\"\nradius = 0.005";

/// A tool pressed 4 mm into the top centre of a 40 x 40 x 20 mm block (bottom fixed) over
/// 0.4 s, held 0.2 s, withdrawn over 0.4 s, at `conductivity` (m^2/s): each step's tool
/// state and energy account.
fn press(dir: &Path, tool: &str, conductivity: f64) -> Vec<(ToolState, Energy)> {
    let lift = if tool.contains("sphere") { 0.005 } else { 0.0 };
    std::fs::write(
        dir.join("path.csv"),
        format!(
            "t,x,y,z\n0,0.02,0.02,{top}\n0.4,0.02,0.02,{low}\n0.6,0.02,0.02,{low}\n1.0,0.02,0.02,{top}\n",
            top = 0.02 + lift,
            low = 0.016 + lift
        ),
    )
    .unwrap();
    let mesh = box_mesh([0.04, 0.04, 0.02], [12, 12, 6], BoxCells::Tet).unwrap();
    let text = format!(
        "[[fixed]]\ngroup = \"zmin\"\n[material]\nconductivity = {conductivity}\n[[tool]]\n{tool}\ntable = \"path.csv\"\n[time]\ndt = 0.01\nend = 1.0\n[model]\nreading = \"continuum\"\n"
    );
    let setup = common::setup_with(mesh, &text, dir, &["mesh.unit=\"m\"".to_string()]);
    let mut sim = Simulation::new(setup).expect("simulation builds");
    assert_eq!(sim.tool_energy(), Some(Energy::default()));
    let mut out = Vec::new();
    while !sim.done() {
        sim.advance().unwrap();
        out.push((sim.tool_states()[0], sim.tool_energy().unwrap()));
    }
    out
}

/// |work - (stored + dissipated)| at most 1e-3 of the work at every step, the dissipation
/// never negative nor decreasing (to round-off), the work positive once the tool presses.
fn balanced(tool: &str, steps: &[(ToolState, Energy)]) -> (f64, f64) {
    let mut worst = 0.0f64;
    let mut last = 0.0f64;
    for (k, (_, e)) in steps.iter().enumerate() {
        let gap = (e.work - (e.stored + e.dissipated)).abs();
        let scale = e.work.abs().max(1e-300);
        if e.work != 0.0 {
            worst = worst.max(gap / scale);
        }
        assert!(gap <= 1e-3 * e.work.abs(), "{tool}: step {}: {e:?}", k + 1);
        let tol = 1e-9 * e.work.abs();
        assert!(e.dissipated >= -tol, "{tool}: step {}: {e:?}", k + 1);
        assert!(
            e.dissipated >= last - tol,
            "{tool}: step {}: dissipation falls: {last} -> {e:?}",
            k + 1
        );
        assert!(e.stored >= 0.0, "{tool}: step {}: {e:?}", k + 1);
        last = e.dissipated;
    }
    let end = steps.last().unwrap().1;
    assert!(end.work > 0.0, "{tool}: {end:?}");
    (worst, end.dissipated / end.work)
}

#[test]
fn a_press_hold_release_balances_the_tools_work_with_the_stored_and_dissipated_energy() {
    let d = tempfile::tempdir().unwrap();
    for tool in [PUNCH, SPHERE] {
        for conductivity in [0.1, 2e-3] {
            let steps = press(d.path(), tool, conductivity);
            let (worst, lost) = balanced(tool, &steps);
            let peak = steps[39].1;
            println!(
                "{tool}: conductivity {conductivity}: at the press's end work {:.4e} J stored {:.4e} J dissipated {:.4e} J; at the end work {:.4e} J, {:.1} % dissipated; largest |balance| / work {worst:.2e}",
                peak.work,
                peak.stored,
                peak.dissipated,
                steps.last().unwrap().1.work,
                100.0 * lost
            );
        }
    }
}

#[test]
fn where_the_energy_spreads_slowly_the_release_force_lies_below_the_press_force() {
    let d = tempfile::tempdir().unwrap();
    for tool in [PUNCH, SPHERE] {
        let steps = press(d.path(), tool, 2e-3);
        let f = |k: usize| -steps[k - 1].0.force[2];
        // the same depths pressing (steps 10, 20, 30) and withdrawing (90, 80, 70)
        for (a, b) in [(10, 90), (20, 80), (30, 70)] {
            assert!(
                f(b) < f(a),
                "{tool}: {} pressing at step {a}, {} withdrawing at {b}",
                f(a),
                f(b)
            );
        }
        // the hold relaxes the force; the loop encloses the dissipated energy
        assert!(f(60) < f(40), "{tool}: {} {}", f(40), f(60));
        let e = steps.last().unwrap().1;
        assert!(e.dissipated > 0.1 * e.work, "{tool}: {e:?}");
        println!(
            "{tool}: F at 1 / 2 / 3 mm pressing {:.4e} / {:.4e} / {:.4e} N, withdrawing {:.4e} / {:.4e} / {:.4e} N; {:.1} % of the work dissipated",
            f(10),
            f(20),
            f(30),
            f(90),
            f(80),
            f(70),
            100.0 * e.dissipated / e.work
        );
    }
}
