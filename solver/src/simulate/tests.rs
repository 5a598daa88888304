//! Unit tests of the simulation's pieces: the mechanics update, its step bound, the loads.

use super::*;
use crate::config::Scenario;
use eprop_io::generate::{box_mesh, BoxCells};

/// A setup on the unit box of 2 x 2 x 2 hexahedra (27 nodes, spacing 0.5), its left face
/// fixed, with extra scenario keys, in the paper's reading unless they name one.
fn setup(keys: &str) -> Setup {
    let keys = if keys.contains("reading =") {
        keys.to_string()
    } else if keys.contains("[model]\n") {
        keys.replacen("[model]\n", "[model]\nreading = \"paper\"\n", 1)
    } else {
        format!("{keys}[model]\nreading = \"paper\"\n")
    };
    let text = format!("[mesh]\nfile = \"m.msh\"\n[[fixed]]\ngroup = \"xmin\"\n{keys}");
    let sc = Scenario::parse(std::path::Path::new("s.toml"), text).unwrap();
    Setup::with_mesh(sc, box_mesh([1.0; 3], [2; 3], BoxCells::Hex).unwrap()).unwrap()
}

const MODEL: &str = "[material]\nmass = 2.0\ndamping = 0.5\n[model]\nstiffness = 1.0\ncoupling = 1.5\n";

#[test]
fn the_mechanics_step_is_semi_implicit_euler() {
    for (exponent, push_z) in [(1.0, 1.5 * 2.0), (3.0, 1.5 * 4.0 * 2.0)] {
        let s = setup(&format!("{MODEL}exponent = {exponent:?}\n[time]\nsteps = 1\n"));
        // node 0 moves, node 1 is inactive and keeps its state
        let (dt, phi, force) = (0.25, [[0.0, 0.0, 2.0]; 2], [[4.0, 0.0, 0.0]; 2]);
        let mut u = [[1.0, 0.0, 0.0]; 2];
        let mut v = [[0.0, 2.0, 0.0]; 2];
        let m2 = mechanics_step(&s, dt, &phi, &force, &[true, false], &[], &mut u, &mut v);
        // a = (f - k u + kappa |phi|^(p-1) phi - g v) / m; v += dt a; u += dt v
        let a = [(4.0 - 1.0) / 2.0, (-0.5 * 2.0) / 2.0, push_z / 2.0];
        let v1 = [dt * a[0], 2.0 + dt * a[1], dt * a[2]];
        let u1 = [1.0 + dt * v1[0], dt * v1[1], dt * v1[2]];
        assert_eq!((u[0], v[0]), (u1, v1), "p = {exponent}");
        assert_eq!((u[1], v[1]), ([1.0, 0.0, 0.0], [0.0, 2.0, 0.0]));
        assert_eq!(m2, v1.iter().map(|x| x * x).sum::<f64>());
    }
}

/// |u| after many steps of a free node pulled back by its spring only.
fn free_swing(s: &Setup, dt: f64) -> f64 {
    let (mut u, mut v) = ([[1.0, 0.0, 0.0]], [[0.0; 3]]);
    for _ in 0..2000 {
        mechanics_step(s, dt, &[[0.0; 3]], &[[0.0; 3]], &[true], &[], &mut u, &mut v);
    }
    norm(u[0])
}

#[test]
fn the_mechanics_bound_separates_decay_from_growth() {
    for model in [
        MODEL,
        "[material]\nmass = 2.0\ndamping = 0.0\n",
        "[material]\nmass = 2.0\ndamping = 3.0\n[model]\nstiffness = 0.0\n",
    ] {
        let s = setup(&format!("{model}[time]\nsteps = 1\n"));
        let n = s.mesh.n_nodes();
        let active: Vec<bool> = (0..n).map(|i| !s.fixed[i]).collect();
        let (dt, bound) = mechanics_dt(&s, &active, n, &Serial).unwrap();
        assert_eq!(dt, SAFETY * bound);
        assert_eq!(
            bound,
            dt_bound_node(2.0, s.materials.at(0).damping, s.model.stiffness())
        );
        if s.model.stiffness() > 0.0 {
            // bounded below it (undamped: on an ellipse at most 1 / sqrt(1 - 0.9^2) wide)
            assert!(free_swing(&s, 0.9 * bound) < 2.5, "{model}");
            assert!(free_swing(&s, 1.01 * bound) > 1e3, "{model}");
        } else {
            // no spring: the velocity alone decays, |1 - dt g / m| < 1 below the bound
            assert_eq!(bound, 2.0 * 2.0 / 3.0);
        }
    }
    let fixed_dt = setup(&format!("{MODEL}[time]\nsteps = 1\ndt = 100.0\n"));
    let n = fixed_dt.mesh.n_nodes();
    let e = mechanics_dt(&fixed_dt, &vec![true; n], n, &Serial)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("dt = 100 is above the mechanics stability bound") && e.contains("fix:"),
        "{e}"
    );
    // no free node (every node fixed): said so, not as a bound that overflows
    let e = mechanics_dt(&fixed_dt, &vec![false; n], n, &Serial)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("every node of the mesh is fixed") && e.contains("fix:"),
        "{e}"
    );
    let free = setup("[material]\ndamping = 0.0\n[model]\nstiffness = 0.0\n[time]\nsteps = 1\n");
    let e = mechanics_dt(&free, &vec![true; n], n, &Serial).unwrap_err().to_string();
    assert!(
        e.contains("no step size is stable by itself; fix: set [time] dt"),
        "{e}"
    );
    let given = setup("[material]\ndamping = 0.0\n[model]\nstiffness = 0.0\n[time]\nsteps = 1\ndt = 0.5\n");
    assert_eq!(
        mechanics_dt(&given, &vec![true; n], n, &Serial).unwrap(),
        (0.5, f64::INFINITY)
    );
}

#[test]
fn a_load_takes_the_area_and_inward_normal_of_its_contact() {
    // the middle of the top face: 4 quarter faces of 0.5 x 0.5, normal +z
    let top = "[time]\nsteps = 1\n[[load]]\nnearest = [0.5, 0.5, 1.0]\nnormal = 2.0\n";
    let sim = Simulation::new(setup(top)).unwrap();
    let l = &sim.loads[0];
    assert_eq!((l.area, l.force), (0.25, [0.0, 0.0, -2.0]));
    let local = sim.local(l.nodes[0]).unwrap() as u32;
    assert_eq!(sim.load_local[0], [(local, 1.0, 1.0, 1.0)]);
    // a patch of that one node: the source enters as a flux of depth 0.1 through its area
    let patch =
        "[time]\nsteps = 1\n[[load]]\npatch = { center = [0.5, 0.5, 1.0], radius = 0.1 }\nforce = [0.0, 1.0, 0.0]\n";
    let sim = Simulation::new(setup(patch)).unwrap();
    let (l, mine) = (&sim.loads[0], &sim.load_local[0]);
    assert_eq!((l.area, l.force, l.depth), (0.25, [0.0, 1.0, 0.0], Some(0.1)));
    let vol = sim.dual.vol[mine[0].0 as usize];
    assert_eq!(vol, 0.0625);
    assert_eq!(mine[0], (mine[0].0, 1.0, 1.0, 0.25 * 0.1 / vol));
    // the centre of the box has no boundary area
    let centre = "[time]\nsteps = 1\n[[load]]\nnode = 14\nnormal = 1.0\n";
    let s = setup(centre);
    assert_eq!(s.mesh.points[s.loads[0].nodes[0] as usize], [0.5; 3]);
    let e = Simulation::new(s).err().unwrap().to_string();
    assert!(
        e.contains("load 1 on node 14: the node is inside the volume") && e.contains("fix:"),
        "{e}"
    );
}

#[test]
fn a_continuum_load_pushes_only_through_its_flux() {
    // Q = (D / l) q a / V
    assert_eq!(
        flux_source(0.2, 0.5, 3.0, 0.25, 0.0625),
        0.2 / 0.5 * 3.0 * 0.25 / 0.0625
    );
    // one node: no nodal force, the flux through its boundary dual area A over l = sqrt(A / pi)
    let top = "[model]\nreading = \"continuum\"\n[material]\nconductivity = [0.1, 0.1, 0.3]\n[time]\nsteps = 1\n[[load]]\nnearest = [0.5, 0.5, 1.0]\nnormal = 2.0\n";
    let mut sim = Simulation::new(setup(top)).unwrap();
    let l = sim.loads[0].clone();
    assert_eq!(
        (l.area, l.force, l.depth),
        (0.25, [0.0, 0.0, -2.0], Some((0.25 / std::f64::consts::PI).sqrt()))
    );
    let local = sim.local(l.nodes[0]).unwrap() as u32;
    assert_eq!(sim.load_local[0], [(local, 1.0, 0.0, 0.25)]);
    let q = sim.sources(0.0);
    assert!(sim
        .force
        .iter()
        .all(|f| *f == [0.0; 3] || *f == [-0.0; 3] || f.iter().all(|x| *x == 0.0)));
    let want = flux_source(
        0.3,
        l.depth.unwrap(),
        sim.setup.law.energy_density(8.0),
        0.25,
        sim.dual.vol[local as usize],
    );
    assert_eq!(q, vec![(local, [0.0, 0.0, -want])]);
}
