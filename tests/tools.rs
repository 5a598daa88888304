//! Tools and load tables: a tool that holds a load's displacement feels the load's force; a
//! tool lets go when it retreats and when the organ pulls a node away from it; a table of a
//! constant force is that force; tools are bitwise identical on 1-4 ranks; bad tables are
//! named with their row and fix.

mod common;

use eprop::simulate::Simulation;
use eprop_io::generate::{box_mesh, cylinder_mesh, BoxCells};
use std::path::Path;

fn sim_in(dir: &Path, mesh: eprop_io::Mesh, toml: &str) -> Simulation {
    Simulation::new(common::setup(mesh, toml, dir)).expect("simulation builds")
}

fn to_the_end(sim: &mut Simulation) {
    while !sim.done() {
        sim.advance().unwrap();
    }
}

const BOX_FIXED: &str = "[[fixed]]\ngroup = \"zmin\"\n";
const CENTRE_PATCH: &str = "patch = { center = [0.5, 0.5, 1.0], radius = 0.05 }";

/// A tool that holds the equilibrium displacement of a force load on the same node feels that
/// force, with the integrator `[model] integrator = kind` (and `[integrator]` settings).
fn tool_feels_the_loads_force(dir: &Path, force: f64, kind: &str, settings: &str) {
    let mesh = || box_mesh([1.0; 3], [8; 3], BoxCells::Tet).unwrap();
    let model = format!("[model]\nreading = \"paper\"\nintegrator = \"{kind}\"\n{settings}");
    // the load: a compressive force on the centre node of the top face, to equilibrium
    let mut load = sim_in(
        dir,
        mesh(),
        &format!(
            "{BOX_FIXED}[[load]]\n{CENTRE_PATCH}\nnormal = {force}\n{model}[time]\nequilibrium = 1e-10\nsteps = 2000\n"
        ),
    );
    to_the_end(&mut load);
    assert!(load.step() < 2000, "{kind}: the load reaches no equilibrium");
    let (f, u) = load.probes()[0];
    assert_eq!(f, [0.0, 0.0, -force]);
    // the propagated potential pushes too: the displacement is not f / k_e
    assert!(u[2] < -1.1 * force, "{kind}: {u:?}");
    // the tool: a punch of the patch's radius on the same node, moved to that depth and held
    std::fs::write(
        dir.join("hold.csv"),
        format!("t,x,y,z\n0,0.5,0.5,1\n20,0.5,0.5,{}\n", 1.0 + u[2]),
    )
    .unwrap();
    let mut tool = sim_in(
        dir,
        mesh(),
        &format!("{BOX_FIXED}[[tool]]\nshape = \"punch\"\nradius = 0.05\nnormal = [0, 0, -1]\ntable = \"hold.csv\"\n{model}[time]\nequilibrium = 1e-10\nsteps = 2000\n"),
    );
    assert_eq!(tool.step_plan().integrator.name(), kind);
    to_the_end(&mut tool);
    assert!(tool.step() < 2000, "{kind}: the tool reaches no equilibrium");
    let t = tool.tool_states()[0];
    assert_eq!(t.contact_nodes, 1, "{kind}");
    assert!(
        (t.displacement[2] - u[2]).abs() < 1e-14,
        "{kind}: {:?} {u:?}",
        t.displacement
    );
    assert!((t.indentation + u[2]).abs() < 1e-15, "{kind}: {}", t.indentation);
    assert!(
        (t.force[2] + force).abs() < 1e-6 * force && t.force[0].abs() < 1e-12 && t.force[1].abs() < 1e-12,
        "{kind}, force {force}: the tool feels {:?}",
        t.force
    );
    // and the organ is in the same state
    let (a, b) = (load.max_displacement().0, tool.max_displacement().0);
    assert!((a - b).abs() < 1e-6 * a, "{kind}: {a} {b}");
}

#[test]
fn a_tool_holding_a_loads_displacement_feels_the_loads_force() {
    let d = tempfile::tempdir().unwrap();
    for force in [0.1, 0.3] {
        tool_feels_the_loads_force(d.path(), force, "euler", "");
    }
}

#[test]
fn tools_work_with_every_integrator() {
    // the tools' sources join the loads' before the stepper, constant over the step: every
    // integrator `auto` may pick takes them
    let d = tempfile::tempdir().unwrap();
    tool_feels_the_loads_force(d.path(), 0.3, "rkl2", "");
    // implicit: the tool's source changes a little every step, so each solve leaves an error of
    // the tolerance in phi and max |v| stalls near it (2e-9 at the default 1e-8): an
    // equilibrium of 1e-10 needs a tighter tolerance
    let tight = "[integrator]\ntolerance = 1e-10\n";
    tool_feels_the_loads_force(d.path(), 0.3, "implicit", tight);
    let amg = "[integrator]\ntolerance = 1e-10\npreconditioner = \"amg\"\n";
    tool_feels_the_loads_force(d.path(), 0.3, "implicit", amg);
}

#[test]
fn a_tool_lets_go_when_it_retreats() {
    let d = tempfile::tempdir().unwrap();
    // press the side of the cylinder 0.25 deep, hold, retreat
    std::fs::write(
        d.path().join("path.csv"),
        "t,x,y,z\n0,1.55,0,2\n20,1.25,0,2\n40,1.25,0,2\n60,1.55,0,2\n",
    )
    .unwrap();
    let mut sim = sim_in(
        d.path(),
        cylinder_mesh(1.0, 4.0, 3, 11).unwrap(),
        "[[fixed]]\ngroup = \"bottom\"\n[[tool]]\nshape = \"sphere\"\nradius = 0.5\ntable = \"path.csv\"\n[time]\nend = 120\n",
    );
    let (mut pressed, mut peak) = (0u64, 0.0f64);
    let mut released_at = None;
    while !sim.done() {
        sim.advance().unwrap();
        let t = sim.tool_states()[0];
        if sim.time() <= 40.0 && sim.time() > 25.0 {
            // held: nodes on the sphere, pushed inwards (-x)
            assert!(t.contact_nodes >= 2, "t = {}: {t:?}", sim.time());
            assert!(t.force[0] < 0.0 && t.contact_area > 0.0, "{t:?}");
        }
        pressed = pressed.max(t.contact_nodes);
        peak = peak.max(sim.max_displacement().0);
        if sim.time() > 60.0 {
            assert_eq!(t.contact_nodes, 0, "t = {}", sim.time());
            assert_eq!((t.force, t.contact_area), ([0.0; 3], 0.0));
            released_at.get_or_insert(sim.step());
        }
    }
    assert!(pressed >= 2 && released_at.is_some());
    // once let go, the organ springs back (k_e = 1)
    let end = sim.max_displacement().0;
    assert!(end < 0.05 * peak, "peak {peak}, end {end}");
}

#[test]
fn a_tool_lets_go_of_a_node_the_organ_pulls_away() {
    let d = tempfile::tempdir().unwrap();
    // the punch holds the centre node 0.05 deep; from t = 20 a load pulls that node further
    // in than the punch goes, until t = 60, then stops
    std::fs::write(d.path().join("hold.csv"), "0,0.5,0.5,1\n10,0.5,0.5,0.95\n").unwrap();
    std::fs::write(
        d.path().join("pull.csv"),
        "t,fx,fy,fz\n20,0,0,0\n30,0,0,-0.3\n60,0,0,-0.3\n61,0,0,0\n",
    )
    .unwrap();
    let mut sim = sim_in(
        d.path(),
        box_mesh([1.0; 3], [8; 3], BoxCells::Tet).unwrap(),
        &format!("{BOX_FIXED}[[load]]\n{CENTRE_PATCH}\ntable = \"pull.csv\"\n[[tool]]\nshape = \"punch\"\nradius = 0.05\nnormal = [0, 0, -1]\ntable = \"hold.csv\"\n[time]\nend = 120\n"),
    );
    let mut phases = (false, false, false);
    while !sim.done() {
        sim.advance().unwrap();
        let t = sim.tool_states()[0];
        let (_, u) = sim.probes()[0];
        if (14.0..20.0).contains(&sim.time()) {
            assert_eq!(t.contact_nodes, 1);
            assert!(t.force[2] < 0.0);
            phases.0 = true;
        }
        if (45.0..60.0).contains(&sim.time()) {
            // pulled deeper than the punch: free, and no force on the punch
            assert_eq!((t.contact_nodes, t.force), (0, [0.0; 3]), "t = {}", sim.time());
            assert!(u[2] < -0.05, "{u:?}");
            phases.1 = true;
        }
        if sim.time() > 100.0 {
            // the pull is gone: the node comes back up to the punch, which holds it again
            assert_eq!(t.contact_nodes, 1, "t = {}", sim.time());
            assert!((u[2] + 0.05).abs() < 1e-14, "{u:?}");
            phases.2 = true;
        }
    }
    assert_eq!(phases, (true, true, true));
}

#[test]
fn a_table_of_a_constant_force_is_that_force() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("f.csv"), "0,0.1,-0.2,-0.3\n5,0.1,-0.2,-0.3\n").unwrap();
    let run = |load: &str| {
        let mut s = sim_in(
            d.path(),
            box_mesh([1.0; 3], [6; 3], BoxCells::Tet).unwrap(),
            &format!("{BOX_FIXED}[[load]]\n{CENTRE_PATCH}\n{load}\n[time]\nsteps = 15\n"),
        );
        to_the_end(&mut s);
        (s.u().to_vec(), s.probes())
    };
    let a = run("force = [0.1, -0.2, -0.3]");
    let b = run("table = \"f.csv\"");
    assert_eq!(a, b);
    // a ramp written as a table follows the same line
    std::fs::write(d.path().join("r.csv"), "t,fx,fy,fz\n0,0,0,0\n10,0,0,-1\n").unwrap();
    let mut s = sim_in(
        d.path(),
        box_mesh([1.0; 3], [4; 3], BoxCells::Tet).unwrap(),
        &format!("{BOX_FIXED}[[load]]\n{CENTRE_PATCH}\ntable = \"r.csv\"\n[time]\nsteps = 3\n"),
    );
    to_the_end(&mut s);
    assert_eq!(s.applied(2.5)[0].force, [0.0, 0.0, -0.25]);
    assert_eq!(s.applied(7.5)[0].force, [0.0, 0.0, -0.75]);
    assert_eq!(s.applied(50.0)[0].force, [0.0, 0.0, -1.0]);
}

#[test]
fn tools_are_bitwise_identical_on_1_to_4_ranks() {
    let d = tempfile::tempdir().unwrap();
    let mesh = d.path().join("cyl.msh");
    eprop_io::write_mesh(&cylinder_mesh(1.0, 4.0, 4, 14).unwrap(), &mesh).unwrap();
    std::fs::write(d.path().join("f.csv"), "t,fx,fy,fz\n0,0,0,0\n4,0,-0.2,0\n").unwrap();
    std::fs::write(d.path().join("p.csv"), "t,x,y,z\n0,0,0,4.3\n6,0,0,3.8\n").unwrap();
    let sc = d.path().join("s.toml");
    std::fs::write(
        &sc,
        format!(
            "[mesh]\nfile = \"{}\"\n[model]\nreading = \"paper\"\n[integrator]\npreconditioner = \"jacobi\"\n[[fixed]]\ngroup = \"bottom\"\n[[load]]\npatch = {{ center = [0.0, 1.0, 2.0], radius = 0.4 }}\ntable = \"f.csv\"\n\
             [[tool]]\nshape = \"sphere\"\nradius = 0.5\nstart = [1.5, 0.0, 2.0]\nvelocity = [-0.03, 0.0, 0.0]\n\
             [[tool]]\nshape = \"punch\"\nradius = 0.6\nnormal = [0, 0, -1]\ntable = \"p.csv\"\n[time]\nsteps = 10\n[output]\nevery = 2\n",
            mesh.display()
        ),
    )
    .unwrap();
    let sc = sc.to_str().unwrap();
    let one = d.path().join("one.h5");
    let out = common::serial(&["run", sc, "-q", "-o", one.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // the tools touch the organ within the run
    let f = hdf5::File::open(&one).unwrap();
    let nodes = f
        .dataset("eprop/tools/contact_nodes")
        .unwrap()
        .read_2d::<i64>()
        .unwrap();
    assert_eq!(nodes.shape(), [6, 2]);
    assert!(nodes[[5, 0]] > 0 && nodes[[5, 1]] > 0, "{nodes:?}");
    let force = f.dataset("eprop/tools/force").unwrap().read_raw::<f64>().unwrap();
    assert_eq!(force.len(), 6 * 2 * 3);
    for n in 2..=4 {
        let out_n = d.path().join(format!("n{n}.h5"));
        let out = common::mpirun(n, &["run", sc, "-q", "-o", out_n.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{n} ranks: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        common::assert_same(&one, &out_n);
    }
}

#[test]
fn tools_are_bitwise_identical_on_1_and_2_ranks_with_rkl2_and_implicit() {
    let d = tempfile::tempdir().unwrap();
    let mesh = d.path().join("cyl.msh");
    eprop_io::write_mesh(&cylinder_mesh(1.0, 4.0, 4, 14).unwrap(), &mesh).unwrap();
    std::fs::write(d.path().join("p.csv"), "t,x,y,z\n0,1.55,0,2\n6,1.3,0,2\n").unwrap();
    for kind in ["rkl2", "implicit"] {
        let sc = d.path().join(format!("{kind}.toml"));
        std::fs::write(
            &sc,
            format!(
                "[mesh]\nfile = \"{}\"\n[model]\nreading = \"paper\"\nintegrator = \"{kind}\"\n[integrator]\npreconditioner = \"jacobi\"\n[[fixed]]\ngroup = \"bottom\"\n\
                 [[load]]\npatch = {{ center = [0.0, 1.0, 2.0], radius = 0.4 }}\nnormal = 0.2\n\
                 [[tool]]\nshape = \"sphere\"\nradius = 0.5\ntable = \"p.csv\"\n[time]\ndt = 0.5\nsteps = 12\n[output]\nevery = 3\n",
                mesh.display()
            ),
        )
        .unwrap();
        let sc = sc.to_str().unwrap();
        let one = d.path().join(format!("{kind}1.h5"));
        let out = common::serial(&["run", sc, "-q", "-o", one.to_str().unwrap()], 1);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let f = hdf5::File::open(&one).unwrap();
        let nodes = f
            .dataset("eprop/tools/contact_nodes")
            .unwrap()
            .read_raw::<i64>()
            .unwrap();
        assert!(*nodes.last().unwrap() >= 2, "{kind}: {nodes:?}");
        let two = d.path().join(format!("{kind}2.h5"));
        let out = common::mpirun(2, &["run", sc, "-q", "-o", two.to_str().unwrap()]);
        assert!(out.status.success(), "{kind}: {}", String::from_utf8_lossy(&out.stderr));
        common::assert_same(&one, &two);
    }
}

#[test]
fn bad_tables_and_tools_are_named_with_their_fix() {
    let d = tempfile::tempdir().unwrap();
    eprop_io::write_mesh(
        &box_mesh([1.0; 3], [3; 3], BoxCells::Tet).unwrap(),
        &d.path().join("b.msh"),
    )
    .unwrap();
    std::fs::write(d.path().join("back.csv"), "t,fx,fy,fz\n0,0,0,0\n2,0,0,1\n1,0,0,2\n").unwrap();
    std::fs::write(d.path().join("nan.csv"), "t,x,y,z\n0,0,0,1\n1,0,nan,1\n").unwrap();
    std::fs::create_dir(d.path().join("dir.csv")).unwrap();
    let base =
        "[mesh]\nfile = \"b.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"zmin\"\n[time]\nsteps = 2\n";
    for (extra, want) in [
        (
            "[[load]]\nnearest = [0.5, 0.5, 1.0]\ntable = \"back.csv\"\n",
            vec!["s.toml:11: [load] table:", "back.csv:4: row 3 of the force table of [[load]] 1: time 1 does not come after the previous row's time 2; fix:"],
        ),
        (
            "[[tool]]\nshape = \"sphere\"\nradius = 0.2\ntable = \"nan.csv\"\n",
            vec!["nan.csv:3: row 2 of the path table of [[tool]] 1: y = NaN is not finite; fix:"],
        ),
        (
            "[[tool]]\nshape = \"sphere\"\nradius = 0.2\ntable = \"dir.csv\"\n",
            vec!["s.toml:12: [tool] table:", "dir.csv: is a directory, not a regular file", "fix:"],
        ),
        (
            "[[load]]\nnearest = [0.5, 0.5, 1.0]\ntable = \"missing.csv\"\n",
            vec!["missing.csv: no such table file", "fix: check the path"],
        ),
        (
            "[[tool]]\nshape = \"punch\"\nradius = 0.2\nstart = [0, 0, 2]\n",
            vec!["[tool]: a punch needs `normal = [nx, ny, nz]`"],
        ),
    ] {
        let sc = d.path().join("s.toml");
        std::fs::write(&sc, format!("{base}{extra}")).unwrap();
        let out = common::serial(&["check", sc.to_str().unwrap()], 1);
        assert!(!out.status.success(), "{extra}");
        let err = String::from_utf8_lossy(&out.stderr);
        for w in want {
            assert!(err.contains(w), "{extra}: {err}");
        }
    }
}

#[test]
fn a_run_with_tools_is_not_restarted() {
    let d = tempfile::tempdir().unwrap();
    eprop_io::write_mesh(
        &box_mesh([1.0; 3], [3; 3], BoxCells::Tet).unwrap(),
        &d.path().join("b.msh"),
    )
    .unwrap();
    let sc = d.path().join("s.toml");
    std::fs::write(
        &sc,
        "[mesh]\nfile = \"b.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"zmin\"\n[[tool]]\nshape = \"sphere\"\nradius = 0.3\nstart = [0.5, 0.5, 1.25]\nvelocity = [0, 0, -0.01]\n[time]\nsteps = 3\n",
    )
    .unwrap();
    let out = common::serial(&["run", sc.to_str().unwrap(), "-q"], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let h5 = d.path().join("s.h5");
    let out = common::serial(
        &["run", sc.to_str().unwrap(), "-q", "--restart", h5.to_str().unwrap()],
        1,
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--restart cannot continue a run with [[tool]]") && err.contains("fix:"),
        "{err}"
    );
}
