//! Tools and load tables: a tool that holds a load's displacement feels the load's force; a
//! tool lets go when it retreats and when the organ pulls a node away from it; a table of a
//! constant force is that force; tools are bitwise identical on 1-4 ranks; bad tables are
//! named with their row and fix.

mod common;

use eprop::config::tissue::TissueLaw;
use eprop::simulate::contact;
use eprop::simulate::Simulation;
use eprop_io::generate::{box_mesh, cylinder_mesh, BoxCells};
use eprop_io::geom::norm;
use eprop_series::vtkhdf::ToolState;
use std::path::Path;

fn sim_in(dir: &Path, mesh: eprop_mesh::Mesh, toml: &str) -> Simulation {
    Simulation::new(common::setup(mesh, toml, dir)).expect("simulation builds")
}

fn to_the_end(sim: &mut Simulation) {
    while !sim.done() {
        sim.advance().unwrap();
    }
}

const BOX_FIXED: &str = "[[fixed]]\ngroup = \"zmin\"\n";
const CENTRE_PATCH: &str = "patch = { center = [0.5, 0.5, 1.0], radius = 0.05 }";

/// A punch of radius 0.3 pressed into the top of the unit box at constant speed, with the
/// integrator `[model] integrator = kind` (and `[integrator]` settings): its state after every
/// step. Its face covers the same top nodes all along, each with the face's offset as its overlap.
fn punch_press(dir: &Path, law: &str, kind: &str, settings: &str) -> Vec<ToolState> {
    let model = format!("[model]\nintegrator = \"{kind}\"\n{settings}");
    let mut sim = sim_in(
        dir,
        box_mesh([1.0; 3], [8; 3], BoxCells::Tet).unwrap(),
        &format!("{BOX_FIXED}[[tool]]\nshape = \"punch\"\nlaw = \"{law}\"\nradius = 0.3\nnormal = [0, 0, -1]\nstart = [0.5, 0.5, 1.02]\nvelocity = [0, 0, -0.004]\n{model}[time]\ndt = 0.5\nsteps = 40\n"),
    );
    assert_eq!(
        sim.step_plan().integrator.name(),
        if kind == "auto" {
            sim.step_plan().integrator.name()
        } else {
            kind
        }
    );
    let mut out = vec![sim.tool_states()[0]];
    while !sim.done() {
        sim.advance().unwrap();
        out.push(sim.tool_states()[0]);
    }
    out
}

#[test]
fn a_punch_feels_the_foundation_pressure_of_its_depth() {
    let d = tempfile::tempdir().unwrap();
    let states = punch_press(d.path(), "foundation", "euler", "");
    let law = TissueLaw {
        young: 100.0,
        beta: 0.0,
    };
    let mut touched = false;
    for (k, t) in states.iter().enumerate() {
        // the face's offset below the top, z = 1: the indentation, negative before contact
        let depth = 1.0 - (1.02 - 0.004 * 0.5 * k as f64);
        assert!((t.indentation - depth).abs() < 1e-14, "step {k}: {t:?}");
        if depth <= 0.0 {
            assert_eq!(
                (t.force, t.contact_nodes, t.contact_area),
                ([0.0; 3], 0, 0.0),
                "step {k}"
            );
            continue;
        }
        touched = true;
        // 21 top nodes under the face (|x - c| <= 0.3 on the 1/8 grid: 1 + 4 + 4 + 4 + 8),
        // each of area 1/64, all pressed by p(depth): F = -p sum A_i, straight down
        let p = contact::pressure(&law, depth, 0.3);
        assert_eq!(t.contact_nodes, 21, "step {k}");
        assert!((t.contact_area - 21.0 / 64.0).abs() < 1e-15, "{t:?}");
        assert!(
            (t.force[2] + p * t.contact_area).abs() < 1e-13 * p,
            "step {k}: {t:?} p = {p}"
        );
        assert!(t.force[0].abs() < 1e-13 * p && t.force[1].abs() < 1e-13 * p, "{t:?}");
        // the nodes it covers sit on its face (the kinematic projection)
        assert!(t.displacement[2] <= -depth + 1e-14, "{t:?}");
    }
    assert!(touched);
    // the law: p = E e^2 / (2 e0) below e0 = SMOOTH_STRAIN, E (e - e0/2) above, C1 at e0
    let e0 = contact::SMOOTH_STRAIN;
    assert_eq!(contact::pressure(&law, 0.0, 1.0), 0.0);
    assert_eq!(contact::pressure(&law, -1.0, 1.0), 0.0);
    assert!((contact::pressure(&law, 0.5 * e0, 1.0) - 100.0 * e0 / 8.0).abs() < 1e-15);
    assert!((contact::pressure(&law, 0.3, 1.0) - 100.0 * (0.3 - e0 / 2.0)).abs() < 1e-12);
    let slope = |x: f64| (contact::pressure(&law, x + 1e-9, 1.0) - contact::pressure(&law, x - 1e-9, 1.0)) / 2e-9;
    assert!((slope(e0) - 100.0).abs() < 1e-4, "{}", slope(e0));
}

#[test]
fn the_tool_force_is_the_same_for_every_integrator() {
    // the force depends on the tool's position only: the same bits whichever integrator runs
    // (not `amg` here: hypre would make this test process an MPI process, and the mpirun of the
    // tests beside it would inherit its environment)
    let d = tempfile::tempdir().unwrap();
    let euler = punch_press(d.path(), "foundation", "euler", "");
    let force = |s: &[ToolState]| {
        s.iter()
            .map(|t| (t.force, t.contact_nodes, t.contact_area, t.indentation))
            .collect::<Vec<_>>()
    };
    assert!(euler.last().unwrap().force[2] < 0.0);
    for (kind, settings) in [("rkl2", ""), ("implicit", ""), ("auto", "")] {
        let other = punch_press(d.path(), "foundation", kind, settings);
        assert_eq!(force(&other), force(&euler), "{kind} {settings}");
    }
}

#[test]
fn the_kinematic_punch_force_agrees_with_euler_for_every_integrator() {
    // the reaction depends on the propagated potential: every integrator within 5e-3 of
    // euler's force at every step (relative to the largest; a derivative of the potential at
    // the contact, so a few times its 1e-3 accuracy), the same contact all along
    let d = tempfile::tempdir().unwrap();
    let euler = punch_press(d.path(), "kinematic", "euler", "");
    let peak = euler.iter().map(|t| norm(t.force)).fold(0.0, f64::max);
    assert!(euler.last().unwrap().force[2] < 0.0 && peak > 0.0);
    for (kind, settings) in [
        ("rkl2", ""),
        ("implicit", ""),
        ("implicit", "[integrator]\npreconditioner = \"multigrid\"\n"),
        ("auto", ""),
    ] {
        let other = punch_press(d.path(), "kinematic", kind, settings);
        let mut worst = 0.0f64;
        for (k, (a, b)) in other.iter().zip(&euler).enumerate() {
            assert_eq!(a.contact_nodes, b.contact_nodes, "{kind} step {k}");
            worst = worst.max(norm(eprop_io::geom::sub(a.force, b.force)) / peak);
        }
        println!("{kind} {settings:?}: largest force difference {worst:.2e} of the peak");
        assert!(worst < 5e-3, "{kind} {settings}: {worst}");
    }
}

/// A sphere pressed at constant speed into the top centre of the unit box (radius 0.25,
/// 0.45 deep) or the side of the cylinder (radius 0.5, 0.7 deep), past its radius: the
/// states after every step and the distance moved per step.
fn sphere_press(dir: &Path, cylinder: bool) -> (Vec<ToolState>, f64) {
    let (mesh, fixed, shape, velocity) = if cylinder {
        (
            cylinder_mesh(1.0, 4.0, 4, 14).unwrap(),
            "[[fixed]]\ngroup = \"bottom\"\n",
            "radius = 0.5\nstart = [1.55, 0.0, 2.0]",
            [-0.015, 0.0, 0.0],
        )
    } else {
        (
            box_mesh([1.0; 3], [10; 3], BoxCells::Tet).unwrap(),
            BOX_FIXED,
            "radius = 0.25\nstart = [0.5, 0.5, 1.3]",
            [0.0, 0.0, -0.01],
        )
    };
    let mut sim = sim_in(
        dir,
        mesh,
        &format!(
            "{fixed}[[tool]]\nshape = \"sphere\"\nlaw = \"foundation\"\n{shape}\nvelocity = [{}, {}, {}]\n[time]\ndt = 0.5\nsteps = 100\n",
            velocity[0], velocity[1], velocity[2]
        ),
    );
    let mut out = vec![sim.tool_states()[0]];
    while !sim.done() {
        sim.advance().unwrap();
        out.push(sim.tool_states()[0]);
    }
    (out, 0.5 * norm(velocity))
}

#[test]
fn a_monotone_press_never_loses_force_and_its_indentation_passes_the_radius() {
    let d = tempfile::tempdir().unwrap();
    for cylinder in [false, true] {
        let (states, step) = sphere_press(d.path(), cylinder);
        let mut first = None;
        for (k, w) in states.windows(2).enumerate() {
            let (a, b) = (norm(w[0].force), norm(w[1].force));
            assert!(b >= a, "cylinder {cylinder}, step {}: |F| {a} -> {b}", k + 1);
            assert!(w[1].contact_nodes >= w[0].contact_nodes && w[1].contact_area >= w[0].contact_area);
            // along a straight path the indentation grows by exactly the distance moved
            assert!(
                (w[1].indentation - w[0].indentation - step).abs() < 1e-12,
                "{k}: {:?} {:?}",
                w[0],
                w[1]
            );
            if b > 0.0 && first.is_none() {
                first = Some(k);
            }
        }
        let last = states.last().unwrap();
        assert!(
            first.is_some() && first.unwrap() > 0,
            "cylinder {cylinder}: contact from the start"
        );
        let (deep, radius) = if cylinder { (0.7, 0.5) } else { (0.45, 0.25) };
        assert!(
            (last.indentation - deep).abs() < 0.01 && deep > radius,
            "cylinder {cylinder}: {last:?}"
        );
        // pressed along -x (cylinder) or -z (box)
        let axis = if cylinder { 0 } else { 2 };
        assert!(
            last.force[axis] < 0.0 && last.force[axis].abs() > 0.99 * norm(last.force),
            "{last:?}"
        );
        println!(
            "cylinder {cylinder}: |F| = {:.4e} at indentation {:.4} ({} nodes, area {:.4e})",
            norm(last.force),
            last.indentation,
            last.contact_nodes,
            last.contact_area
        );
    }
}

#[test]
fn a_tool_far_from_the_organ_has_no_force_and_a_negative_indentation() {
    let d = tempfile::tempdir().unwrap();
    let mut sim = sim_in(
        d.path(),
        box_mesh([1.0; 3], [6; 3], BoxCells::Tet).unwrap(),
        &format!("{BOX_FIXED}[[tool]]\nshape = \"sphere\"\nradius = 0.2\nstart = [0.5, 0.5, 3.0]\nvelocity = [0, 0, -0.01]\n[[tool]]\nshape = \"punch\"\nradius = 0.2\nnormal = [0, 0, -1]\nstart = [0.5, 0.5, 2.5]\n[time]\nsteps = 5\n"),
    );
    to_the_end(&mut sim);
    let t = sim.tool_states();
    let z = 3.0 - 0.01 * sim.time();
    for (k, (t, gap)) in t.iter().zip([z - 0.2 - 1.0, 1.5]).enumerate() {
        assert_eq!(
            (t.force, t.contact_nodes, t.contact_area, t.displacement),
            ([0.0; 3], 0, 0.0, [0.0; 3]),
            "tool {k}"
        );
        assert!((t.indentation + gap).abs() < 1e-14, "tool {k}: {t:?}, gap {gap}");
    }
    assert_eq!(sim.max_displacement().0, 0.0);
}

/// The force of a sphere (radius 0.3, foundation 0.3) pressed into the top centre of the unit
/// box of n^3 cells, at each indentation of `depths`.
fn sphere_force_curve(dir: &Path, n: usize, depths: &[f64]) -> Vec<f64> {
    let sim = sim_in(
        dir,
        box_mesh([1.0; 3], [n; 3], BoxCells::Tet).unwrap(),
        &format!("{BOX_FIXED}[[tool]]\nshape = \"sphere\"\nlaw = \"foundation\"\nradius = 0.3\nstart = [0.5, 0.5, 1.3]\nvelocity = [0, 0, -1]\n[time]\nsteps = 1\n"),
    );
    let times: Vec<f64> = std::iter::once(0.0).chain(depths.iter().copied()).collect();
    let s = sim.tool_survey(0, &times);
    for (st, &d) in s[1..].iter().zip(depths) {
        assert!((st.indentation - d).abs() < 1e-12, "{st:?} {d}");
    }
    s[1..].iter().map(|t| -t.force[2]).collect()
}

#[test]
fn the_force_indentation_curve_converges_with_the_mesh() {
    let d = tempfile::tempdir().unwrap();
    let depths: Vec<f64> = (1..=12).map(|k| 0.04 * k as f64).collect();
    let curves: Vec<Vec<f64>> = [8, 16, 32]
        .iter()
        .map(|&n| sphere_force_curve(d.path(), n, &depths))
        .collect();
    let diff = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    let (d12, d23) = (diff(&curves[0], &curves[1]), diff(&curves[1], &curves[2]));
    let peak = curves[2].iter().fold(0.0f64, |m, x| m.max(*x));
    println!("depths {depths:?}");
    for (n, c) in [8, 16, 32].iter().zip(&curves) {
        println!("n = {n}: {c:?}");
    }
    println!(
        "max |F_8 - F_16| = {d12:.4e}, max |F_16 - F_32| = {d23:.4e} (ratio {:.3}), peak {peak:.4e}",
        d23 / d12
    );
    assert!(d23 <= 0.5 * d12, "{d12} {d23}");
    // every curve rises with the depth
    for c in &curves {
        assert!(c.windows(2).all(|w| w[1] > w[0]), "{c:?}");
    }
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
        "[[fixed]]\ngroup = \"bottom\"\n[[tool]]\nshape = \"sphere\"\nradius = 0.5\ntable = \"path.csv\"\n[time]\nend = 200\n",
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
    // once let go, the organ springs back (k_e = 1): 5.3 % of the peak is left at t = 200
    // (4.8 % when the sphere took the nodes it pressed to its nearest point: they slid away
    // along it and less of the organ was deformed at the release; the decay rate is the same)
    let end = sim.max_displacement().0;
    assert!(end < 0.06 * peak, "peak {peak}, end {end}");
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
        &format!("{BOX_FIXED}[[load]]\n{CENTRE_PATCH}\ntable = \"pull.csv\"\n[[tool]]\nshape = \"punch\"\nlaw = \"foundation\"\nradius = 0.05\nfoundation = 5\nnormal = [0, 0, -1]\ntable = \"hold.csv\"\n[time]\nend = 120\n"),
    );
    let mut phases = (false, false, false);
    let mut held = [0.0; 3];
    while !sim.done() {
        sim.advance().unwrap();
        let t = sim.tool_states()[0];
        let (_, u) = sim.probes()[0];
        if (14.0..20.0).contains(&sim.time()) {
            assert_eq!(t.contact_nodes, 1);
            assert!(t.force[2] < 0.0);
            assert!((u[2] + 0.05).abs() < 1e-14, "held on the face: {u:?}");
            held = t.force;
            phases.0 = true;
        }
        if (45.0..60.0).contains(&sim.time()) {
            // pulled deeper than the punch: the node moves freely; the foundation's force is
            // that of the punch's depth in the rest surface, whatever the node does
            assert_eq!((t.contact_nodes, t.force), (1, held), "t = {}", sim.time());
            assert!(u[2] < -0.05, "{u:?}");
            phases.1 = true;
        }
        if sim.time() > 100.0 {
            // the pull is gone: the node comes back up to the punch, which holds it again
            assert_eq!((t.contact_nodes, t.force), (1, held), "t = {}", sim.time());
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
            "{n} ranks: {:?} {}",
            out.status,
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
        assert!(
            out.status.success(),
            "{kind}: {:?} {} {}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
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
    std::fs::write(
        d.path().join("huge.csv"),
        "t,x,y,z\n0,1e308,1e308,0\n10,-1e308,-1e308,0\n",
    )
    .unwrap();
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
        // each row finite, but the path between them passes through infinity (it wrote
        // positions of NaN and an indentation of -inf with status 0)
        (
            "[[tool]]\nshape = \"sphere\"\nradius = 0.2\ntable = \"huge.csv\"\n",
            vec!["huge.csv:2: row 1 of the path table of [[tool]] 1: x = 1e308 is beyond +-1e100, where the contact's distances overflow; fix:"],
        ),
        (
            "[[tool]]\nshape = \"sphere\"\nradius = 0.2\nstart = [1e200, 0, 2]\n",
            vec!["[tool]: `start` has the component 1e200, beyond +-1e100", "fix:"],
        ),
        // a straight path that leaves the range by the last step
        (
            "[[tool]]\nshape = \"sphere\"\nradius = 0.2\nstart = [0, 0, 2]\nvelocity = [0, 0, 1e100]\n",
            vec!["tool 1's path `start` + t `velocity` is at (0, 0, ", "beyond +-1e100", "fix: a smaller velocity"],
        ),
    ] {
        let sc = d.path().join("s.toml");
        std::fs::write(&sc, format!("{base}{extra}")).unwrap();
        let o = d.path().join("o.h5");
        let (s, o) = (sc.to_str().unwrap(), o.to_str().unwrap());
        for args in [vec!["check", s], vec!["run", s, "-q", "--overwrite", "-o", o]] {
            let out = common::serial(&args, 1);
            assert_eq!(out.status.code(), Some(1), "{args:?} {extra}");
            let err = String::from_utf8_lossy(&out.stderr);
            for w in &want {
                assert!(err.contains(w), "{args:?} {extra}: {err}");
            }
        }
    }
}

/// A straight-path tool: a run continued with `--restart` is the uninterrupted run, bit for bit
/// (a path table is tested with SIGTERM in tests/safety.rs).
#[test]
fn a_run_with_a_moving_tool_restarts_bit_for_bit() {
    let d = tempfile::tempdir().unwrap();
    eprop_io::write_mesh(
        &box_mesh([1.0; 3], [3; 3], BoxCells::Tet).unwrap(),
        &d.path().join("b.msh"),
    )
    .unwrap();
    let sc = d.path().join("s.toml");
    std::fs::write(
        &sc,
        "[mesh]\nfile = \"b.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"zmin\"\n[[tool]]\nshape = \"sphere\"\nradius = 0.3\nstart = [0.5, 0.5, 1.25]\nvelocity = [0, 0, -0.01]\n[time]\nsteps = 40\n",
    )
    .unwrap();
    let (whole, cut) = (d.path().join("whole.h5"), d.path().join("cut.h5"));
    let run = |args: &[&str]| {
        let out = common::serial(args, 1);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    };
    let s = sc.to_str().unwrap();
    run(&["run", s, "-q", "-o", whole.to_str().unwrap()]);
    run(&["run", s, "-q", "-o", cut.to_str().unwrap(), "--steps", "17"]);
    run(&["run", s, "-q", "--restart", cut.to_str().unwrap()]);
    common::assert_same(&whole, &cut);
}

#[test]
fn check_warns_of_a_tool_as_of_a_load_in_metres() {
    // a 0.18 x 0.1 x 0.1 box (an organ in metres read as mm) pressed by a 10 mm sphere moving
    // 1 unit per time; one never reaching it; one too small to press more than a speck
    let d = tempfile::tempdir().unwrap();
    eprop_io::write_mesh(
        &box_mesh([0.18, 0.1, 0.1], [9, 5, 5], BoxCells::Tet).unwrap(),
        &d.path().join("m.msh"),
    )
    .unwrap();
    for (tool, want) in [
        (
            "law = \"foundation\"\nradius = 0.01\nstart = [0.1, 0.06, 0.12]\nvelocity = [0, 0, -0.05]",
            "times [tissue] young = 100, far outside the tissue law's range",
        ),
        (
            "radius = 0.01\nstart = [0.1, 0.06, 0.5]\nvelocity = [0, 0, -0.0001]",
            "it never reaches the organ's surface by t = ",
        ),
        ("radius = 1e-6\nstart = [0.09, 0.05, 0.1]", "it presses a speck"),
        (
            "radius = 0.005\nstart = [0.1, 0.06, 0.106]\nvelocity = [0, 0, -0.0001]",
            "the tool can pass between them into the organ",
        ),
    ] {
        let sc = d.path().join("s.toml");
        std::fs::write(
            &sc,
            format!("[mesh]\nfile = \"m.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"zmin\"\n[[tool]]\nshape = \"sphere\"\n{tool}\n[time]\nsteps = 100\n"),
        )
        .unwrap();
        let out = common::serial(&["check", sc.to_str().unwrap()], 1);
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            text.contains("warning") && text.contains("tool 1: ") && text.contains(want),
            "{tool}: {text}"
        );
        assert!(
            text.contains("if it is in metres, `[mesh] scale = 1000` reads it in millimetres"),
            "{text}"
        );
    }
    // the demo gets none
    let demo = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/cylinder_indent.toml");
    let out = common::serial(&["check", demo.to_str().unwrap()], 1);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && !text.contains("tool 1: "), "{text}");
}

/// The series' counts of inverted cells (`/eprop/checks/inverted`) and nodes inside the tools.
fn checks(h5: &Path) -> (Vec<i64>, Vec<i64>) {
    let f = hdf5::File::open(h5).unwrap();
    let k = common::steps_complete(h5) as usize;
    let inverted = f.dataset("eprop/checks/inverted").unwrap().read_raw::<i64>().unwrap();
    let inside = f.dataset("eprop/checks/inside").unwrap().read_raw::<i64>().unwrap();
    (inverted[..k].to_vec(), inside[..k].to_vec())
}

#[test]
fn a_press_that_folds_the_mesh_is_reported_in_the_summary_and_the_series_on_any_rank_count() {
    // the demo with the elastic-foundation law and young = 100: its sources grow with the
    // contact stress and push the dent through the cylinder's cells (the kinematic contact,
    // the demo's own, does not: checked at the end)
    let demo = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/cylinder_indent.toml");
    let d = tempfile::tempdir().unwrap();
    let (one, two) = (d.path().join("one.h5"), d.path().join("two.h5"));
    let args = |out: &Path| {
        vec![
            "run".to_string(),
            demo.to_str().unwrap().to_string(),
            "-o".into(),
            out.to_str().unwrap().to_string(),
            "--set".into(),
            "tissue.young=100".into(),
            "--set".into(),
            "tool.1.law=\"foundation\"".into(),
            "--set".into(),
            "time.end=30".into(),
        ]
    };
    let a1 = args(&one);
    let out = common::serial(&a1.iter().map(|s| s.as_str()).collect::<Vec<_>>(), 1);
    common::ok(&out);
    let (inverted, inside) = checks(&one);
    let most = *inverted.iter().max().unwrap();
    assert!(inverted[0] == 0 && most > 0, "{inverted:?}");
    assert_eq!(inside.len(), inverted.len(), "one tool: a count per output step");
    let first = inverted.iter().position(|&n| n > 0).unwrap();
    let err = common::stderr(&out);
    assert!(
        err.contains(&format!(
            "warning: {} cell(s) inverted at step {first} ",
            inverted[first]
        )) && err.contains("cause: the tools' prescribed paths: tool 1 (sphere r = 0.8) is pressed")
            && !err.contains("smaller force, a larger contact patch"),
        "{err}"
    );
    let summary = String::from_utf8_lossy(&out.stdout);
    let last = inverted[inverted.len() - 1];
    assert!(
        summary.contains(&format!("  inverted    {last} cells (max {most} at t = ")),
        "{summary}"
    );
    assert!(
        summary.contains(&format!("  inside      {} nodes in tools", inside[inside.len() - 1])),
        "{summary}"
    );
    let a2 = args(&two);
    let out = common::mpirun(2, &a2.iter().map(|s| s.as_str()).collect::<Vec<_>>());
    common::ok(&out);
    assert_eq!(checks(&two), (inverted, inside));
    common::assert_same(&one, &two);
    // the demo's own contact at young = 100: the tissue is where the tool puts it, no cell
    // folds, no node is inside the sphere
    let kin = d.path().join("kin.h5");
    let out = common::serial(
        &[
            "run",
            demo.to_str().unwrap(),
            "-o",
            kin.to_str().unwrap(),
            "--set",
            "tissue.young=100",
            "-q",
        ],
        1,
    );
    common::ok(&out);
    let (inverted, inside) = checks(&kin);
    assert!(
        inverted.iter().all(|&n| n == 0) && inside.iter().all(|&n| n == 0),
        "{inverted:?} {inside:?}"
    );
}

#[test]
fn a_deep_press_is_blamed_on_the_tool_never_on_a_force() {
    // the demo's sphere pressed 0.9 into the cylinder (of diagonal 4.9): max |u| passes 10 %
    // of the diagonal; the warning names the tool's depth, and no force
    let d = tempfile::tempdir().unwrap();
    let msh = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/cylinder.msh");
    let sc = d.path().join("deep.toml");
    std::fs::write(
        &sc,
        format!(
            "[mesh]\nfile = \"{}\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"bottom\"\n[[tool]]\nshape = \"sphere\"\nradius = 0.8\nstart = [1.85, 0.0, 2.0]\nvelocity = [-0.02, 0.0, 0.0]\n[time]\nend = 47.5\n",
            msh.display()
        ),
    )
    .unwrap();
    let out = common::serial(
        &[
            "run",
            sc.to_str().unwrap(),
            "-o",
            d.path().join("deep.h5").to_str().unwrap(),
        ],
        1,
    );
    common::ok(&out);
    let err = common::stderr(&out);
    assert!(
        err.contains("passed 10 % of the mesh's diagonal")
            && err.contains("cause: the tools' prescribed paths (tool 1 is ")
            && !err.contains("a smaller force"),
        "{err}"
    );
}

#[test]
fn a_kinematic_tool_under_multigrid_runs_on_three_ranks_where_only_one_holds_its_nodes() {
    // a punch at a corner of a block: only the process owning those nodes holds rows; the
    // implicit solves with a multigrid must still agree on their collectives (a hang before)
    let d = tempfile::tempdir().unwrap();
    let mesh = d.path().join("block.msh");
    eprop_io::write_mesh(
        &box_mesh([0.04, 0.04, 0.02], [12, 12, 6], BoxCells::Tet).unwrap(),
        &mesh,
    )
    .unwrap();
    let sc = d.path().join("s.toml");
    std::fs::write(
        &sc,
        format!(
            "[mesh]\nfile = \"{}\"\nunit = \"m\"\n[model]\nintegrator = \"implicit\"\n[integrator]\npreconditioner = \"multigrid\"\n[[fixed]]\ngroup = \"zmin\"\n\
             [[tool]]\nshape = \"punch\"\nradius = 0.004\nnormal = [0, 0, -1]\nstart = [0.005, 0.005, 0.02]\nvelocity = [0, 0, -0.002]\n[time]\ndt = 0.02\nsteps = 25\n[output]\nevery = 5\n",
            mesh.display()
        ),
    )
    .unwrap();
    let sc = sc.to_str().unwrap();
    let one = d.path().join("one.h5");
    let out = common::serial(&["run", sc, "-q", "-o", one.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let three = d.path().join("three.h5");
    let job = common::spawn(3, &["run", sc, "-q", "-o", three.to_str().unwrap()]);
    let out = common::finish(job, 600, "three processes");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let force = |h5: &Path| {
        hdf5::File::open(h5)
            .unwrap()
            .dataset("eprop/tools/force")
            .unwrap()
            .read_raw::<f64>()
            .unwrap()
    };
    let (a, b) = (force(&one), force(&three));
    let peak = a.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    assert!(peak > 0.0);
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).abs() <= 1e-4 * peak, "{a:?} {b:?}");
    }
}

/// A sphere that starts to press a cylinder whose propagation is fast against dt (conductivity
/// 5e4, dt = 0.7): the layer each contact step starts needs implicit sub-steps down to about
/// dt / 2^22. The error control takes them (it allows dt / 2^30) and the run ends with every
/// node out of the sphere, where it once stopped with "needs TR-BDF2 steps shorter than
/// dt / 2^16" at the first contact.
#[test]
fn a_contact_layer_far_faster_than_dt_is_resolved_by_the_implicit_error_control() {
    let d = tempfile::tempdir().unwrap();
    let mut sim = sim_in(
        d.path(),
        cylinder_mesh(1.0, 4.0, 4, 14).unwrap(),
        "[[fixed]]\ngroup = \"bottom\"\n[[tool]]\nshape = \"sphere\"\nradius = 0.8\nstart = [1.85, 0.0, 2.0]\nvelocity = [-0.00875, 0.0, 0.0]\n[material]\nmass = 1.0\ndamping = 2.0\nconductivity = 5e4\n[model]\nintegrator = \"implicit\"\n[time]\ndt = 0.7\nend = 30.0\n",
    );
    let mut touched = 0;
    while !sim.done() {
        sim.advance().unwrap();
        assert_eq!(sim.inspect().inside[0], 0);
        touched = touched.max(sim.tool_states()[0].contact_nodes);
    }
    assert!(touched > 0, "the sphere never touched");
}
