//! The continuum reading (docs/model.md): a mesh file in metres and the same mesh in
//! millimetres, each with its `[mesh] unit`, give the same physical result under the same
//! scenario, on one and two processes; a scenario converted by hand (a `scale`) agrees too; a
//! patch load of fixed radius converges as the mesh is refined, at equilibrium and during the
//! transient; a continuum mesh without a unit is an error that names the fix.

mod common;

use common::{mpirun, processes, serial};
use eprop::config::{Scenario, Setup};
use eprop::linalg::V3;
use eprop::simulate::Simulation;
use eprop_io::generate::{box_mesh, BoxCells};
use eprop_mesh::Mesh;
use std::path::Path;

/// A 0.1 m cube in metres, its bottom face tagged `zmin`.
fn cube(n: usize) -> Mesh {
    box_mesh([0.1; 3], [n; 3], BoxCells::Tet).unwrap()
}

fn in_mm(m: &Mesh) -> Mesh {
    let mut mm = m.clone();
    for p in mm.points.iter_mut() {
        for x in p.iter_mut() {
            *x *= 1000.0;
        }
    }
    mm
}

/// Every length in metres: a patch on the top face, a material region, the bottom fixed.
const BODY: &str = "[[material.region]]\nbox = [[0.0, 0.0, 0.05], [0.1, 0.1, 0.1]]\nconductivity = [0.2, 0.1, 0.1]\n\
[[fixed]]\ngroup = \"zmin\"\n[[load]]\npatch = { center = [0.05, 0.05, 0.1], radius = 0.02 }\nnormal = 0.5\n\
[[load]]\nnearest = [0.1, 0.05, 0.05]\nforce = [-0.01, 0.0, 0.0]\nramp = [[0.0, 0.0], [0.05, 1.0]]\n\
[time]\nsteps = 12\ndt = 0.005\n[output]\nevery = 1\n";

/// Every floating-point dataset of two series (but the scenario text) agrees to `rel` of the
/// dataset's largest magnitude; returns the largest relative difference seen.
fn assert_close(a: &Path, b: &Path, rel: f64) -> f64 {
    let (fa, fb, na) = common::open_pair(a, b);
    let mut worst = 0.0f64;
    let mut compared = 0;
    for name in na.iter().filter(|n| !n.ends_with("/scenario")) {
        let (da, db) = (fa.dataset(name).unwrap(), fb.dataset(name).unwrap());
        if !da.dtype().unwrap().is::<f64>() {
            assert_eq!(common::bits(&fa, name), common::bits(&fb, name), "{name}");
            continue;
        }
        let (x, y) = (da.read_raw::<f64>().unwrap(), db.read_raw::<f64>().unwrap());
        assert_eq!(x.len(), y.len(), "{name}");
        let big = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let diff = x.iter().zip(&y).fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
        let r = if big > 0.0 { diff / big } else { diff };
        assert!(
            r <= rel,
            "{name}: relative difference {r:e} between {} and {}",
            a.display(),
            b.display()
        );
        worst = worst.max(r);
        compared += 1;
    }
    assert!(compared >= 8, "{na:?}");
    worst
}

#[test]
fn a_mesh_in_metres_and_in_millimetres_gives_the_same_result_on_1_and_2_ranks() {
    let d = tempfile::tempdir().unwrap();
    let m = cube(6);
    eprop_io::write_mesh(&m, &d.path().join("m.msh")).unwrap();
    eprop_io::write_mesh(&in_mm(&m), &d.path().join("mm.msh")).unwrap();
    let mut outs = vec![];
    for (file, unit) in [("m.msh", "m"), ("mm.msh", "mm")] {
        let sc = d.path().join(format!("{unit}.toml"));
        std::fs::write(&sc, format!("[mesh]\nfile = \"{file}\"\nunit = \"{unit}\"\n{BODY}")).unwrap();
        let sc = sc.to_str().unwrap().to_string();
        let one = d.path().join(format!("{unit}1.h5"));
        let o = serial(&["run", &sc, "-q", "-o", one.to_str().unwrap()], 1);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let two = d.path().join(format!("{unit}2.h5"));
        let o = mpirun(2, &["run", &sc, "-q", "-o", two.to_str().unwrap()]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        // two ranks: bit for bit the same as one
        common::assert_same(&one, &two);
        outs.push((one, two));
    }
    let w1 = assert_close(&outs[0].0, &outs[1].0, 1e-10);
    let w2 = assert_close(&outs[0].1, &outs[1].1, 1e-10);
    println!("m against mm: largest relative difference {w1:e} (1 rank), {w2:e} (2 ranks)");
    // it moved: the comparison is not of zeros
    let f = hdf5::File::open(&outs[0].0).unwrap();
    let u = f
        .dataset("/eprop/probes/displacement")
        .unwrap()
        .read_raw::<f64>()
        .unwrap();
    assert!(u.iter().any(|x| x.abs() > 1e-6), "{u:?}");
}

/// A sphere of 20 mm radius pressing the top of the cube at 0.2 m/s, in a mesh file in metres and in
/// millimetres: the same force, contact set, indentation and u, on one and two processes.
#[test]
fn a_tool_in_metres_and_in_millimetres_gives_the_same_result() {
    let d = tempfile::tempdir().unwrap();
    let m = cube(10);
    eprop_io::write_mesh(&m, &d.path().join("m.msh")).unwrap();
    eprop_io::write_mesh(&in_mm(&m), &d.path().join("mm.msh")).unwrap();
    let body = "[[fixed]]\ngroup = \"zmin\"\n[[tool]]\nshape = \"sphere\"\nradius = 0.02\n\
start = [0.05, 0.05, 0.122]\nvelocity = [0.0, 0.0, -0.2]\n[time]\nsteps = 12\ndt = 0.005\n";
    let mut outs = vec![];
    for (file, unit) in [("m.msh", "m"), ("mm.msh", "mm")] {
        let sc = d.path().join(format!("t{unit}.toml"));
        std::fs::write(&sc, format!("[mesh]\nfile = \"{file}\"\nunit = \"{unit}\"\n{body}")).unwrap();
        let sc = sc.to_str().unwrap().to_string();
        for ranks in [1, 2] {
            let out = d.path().join(format!("t{unit}{ranks}.h5"));
            let args = ["run", &sc, "-q", "-o", out.to_str().unwrap()];
            let o = processes(ranks, &args);
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            outs.push(out);
        }
        let n = outs.len();
        common::assert_same(&outs[n - 2], &outs[n - 1]);
    }
    let w = assert_close(&outs[0], &outs[2], 1e-10);
    println!("a tool in m against mm: largest relative difference {w:e}");
    let f = hdf5::File::open(&outs[0]).unwrap();
    let force = f.dataset("/eprop/tools/force").unwrap().read_raw::<f64>().unwrap();
    let nodes = f
        .dataset("/eprop/tools/contact_nodes")
        .unwrap()
        .read_raw::<i64>()
        .unwrap();
    assert!(force.iter().any(|x| x.abs() > 1e-4), "{force:?}");
    assert!(nodes.iter().any(|&k| k > 1), "{nodes:?}");
}

/// u after every step of a scenario on a mesh file (read as `[mesh]` says), in the mesh's node
/// order, and the probes.
fn run(mesh: Mesh, mesh_keys: &str, body: &str) -> (Vec<Vec<V3>>, Vec<Vec<(V3, V3)>>) {
    let d = tempfile::tempdir().unwrap();
    let text = format!("[mesh]\nfile = \"x.msh\"\n{mesh_keys}{body}");
    eprop_io::write_mesh(&mesh, &d.path().join("x.msh")).unwrap();
    let sc = Scenario::parse(&d.path().join("s.toml"), text).unwrap();
    let mut s = Simulation::new(Setup::new(sc).unwrap()).unwrap();
    let (mut us, mut probes) = (vec![], vec![]);
    while !s.done() {
        s.advance().unwrap();
        let mut u = vec![[0.0; 3]; s.n_global()];
        for i in 0..s.n_owned() {
            u[s.gid()[i] as usize] = s.u()[i];
        }
        us.push(u);
        probes.push(s.probes());
    }
    (us, probes)
}

fn rel_diff(a: &[V3], b: &[V3]) -> f64 {
    let big = b.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
    let d = a
        .iter()
        .flatten()
        .zip(b.iter().flatten())
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    d / big
}

#[test]
fn a_scenario_converted_by_hand_agrees() {
    // the mesh in mm read with scale = 1e-3 (metres per file unit), the scenario's lengths
    // unchanged (metres): the same as the mesh in metres
    let m = cube(5);
    let (ua, pa) = run(m.clone(), "unit = \"m\"\n", BODY);
    let (ub, pb) = run(in_mm(&m), "scale = 1e-3\n", BODY);
    let (uc, _) = run(in_mm(&m), "unit = \"mm\"\n", BODY);
    let mut worst = 0.0f64;
    for k in 0..ua.len() {
        worst = worst.max(rel_diff(&ub[k], &ua[k])).max(rel_diff(&uc[k], &ua[k]));
        for (x, y) in pa[k].iter().zip(&pb[k]) {
            worst = worst.max(rel_diff(&[x.1], &[y.1]));
        }
    }
    println!("scale = 1e-3 and unit = \"mm\" against metres: {worst:e}");
    assert!(worst <= 1e-10, "{worst:e}");
    assert!(common::max_abs(ua.last().unwrap()) > 1e-6);
}

#[test]
fn a_continuum_mesh_without_a_unit_is_an_error_that_names_the_fix() {
    let d = tempfile::tempdir().unwrap();
    eprop_io::write_mesh(&cube(2), &d.path().join("x.msh")).unwrap();
    let sc = |mesh: &str| {
        Scenario::parse(
            &d.path().join("s.toml"),
            format!("[mesh]\nfile = \"x.msh\"\n{mesh}[model]\nreading = \"continuum\"\n[[fixed]]\ngroup = \"zmin\"\n[time]\nsteps = 1\n"),
        )
        .unwrap()
    };
    let e = format!("{:#}", Setup::new(sc("")).err().unwrap());
    assert!(
        e.contains("[mesh] unit is missing") && e.contains("unit = \"mm\""),
        "{e}"
    );
    let e = format!("{:#}", Setup::new(sc("unit = \"mm\"\nscale = 2.0\n")).err().unwrap());
    assert!(e.contains("unit and scale both given; fix:"), "{e}");
    assert!(Setup::new(sc("unit = \"mm\"\n")).is_ok());
    let bad = Scenario::parse(
        &d.path().join("s.toml"),
        "[mesh]\nfile = \"x.msh\"\nunit = \"inch\"\n[time]\nsteps = 1\n".into(),
    )
    .err()
    .unwrap();
    assert!(
        format!("{bad:#}").contains("\"m\", \"cm\", \"mm\" or \"um\""),
        "{bad:#}"
    );
    // the paper reading takes the coordinates as they are
    let paper = Scenario::parse(
        &d.path().join("s.toml"),
        "[mesh]\nfile = \"x.msh\"\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"zmin\"\n[time]\nsteps = 1\n"
            .into(),
    )
    .unwrap();
    assert_eq!(Setup::new(paper).unwrap().mesh.points, cube(2).points);
}

/// uz at the node at `at` (a node of every refinement) after each step.
fn probe_history(n: usize, at: [f64; 3], body: &str) -> Vec<f64> {
    let m = cube(n);
    let node = m
        .points
        .iter()
        .position(|p| (0..3).all(|d| (p[d] - at[d]).abs() < 1e-12))
        .expect("the probe is a node");
    let (us, _) = run(m, "unit = \"m\"\n", body);
    us.iter().map(|u| u[node][2]).collect()
}

/// The convergence of a patch load of fixed radius (docs/model.md, "Convergence"): the
/// difference between the 2nd and 3rd of three refinements at most half of that between the
/// 1st and 2nd, at a probe below the patch, during the transient and at equilibrium.
#[test]
fn a_patch_load_converges_with_refinement() {
    let body =
        "[[fixed]]\ngroup = \"zmin\"\n[[load]]\npatch = { center = [0.05, 0.05, 0.1], radius = 0.02 }\nnormal = 0.5\n\
[time]\nend = 0.6\ndt = 0.005\n";
    let (transient, end) = (9, 119); // t = 0.05 s and 0.6 s (steps 10 and 120)
    for at in [[0.05, 0.05, 0.1], [0.05, 0.05, 0.075]] {
        let h: Vec<Vec<f64>> = [4, 8, 16].iter().map(|&n| probe_history(n, at, body)).collect();
        for (what, k) in [("transient (t = 0.05 s)", transient), ("equilibrium (t = 0.6 s)", end)] {
            let (a, b, c) = (h[0][k], h[1][k], h[2][k]);
            let ratio = (c - b).abs() / (b - a).abs();
            println!("probe {at:?}, {what}: uz = {a:.6e} / {b:.6e} / {c:.6e}, ratio of differences {ratio:.3}");
            assert!(ratio <= 0.5, "probe {at:?} {what}: ratio {ratio}");
        }
    }
}

#[test]
fn check_warns_of_scales_far_from_the_defaults() {
    let d = tempfile::tempdir().unwrap();
    // a 0.1 m cube written in mm but declared in metres: it spans 173 m
    eprop_io::write_mesh(&in_mm(&cube(4)), &d.path().join("mm.msh")).unwrap();
    let check = |mesh: &str, extra: &str| {
        let sc = d.path().join("s.toml");
        std::fs::write(
            &sc,
            format!("[mesh]\nfile = \"mm.msh\"\n{mesh}[[fixed]]\ngroup = \"zmin\"\n{extra}[time]\nsteps = 2\n"),
        )
        .unwrap();
        let o = serial(&["check", sc.to_str().unwrap()], 1);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        )
    };
    let load = "[[load]]\npatch = { center = [0.05, 0.05, 0.1], radius = 0.02 }\nnormal = 0.5\n";
    let good = check("unit = \"mm\"\n", load);
    assert!(!good.contains("far from"), "{good}");
    let wrong = check(
        "unit = \"m\"\n",
        &load.replace("[0.05, 0.05, 0.1]", "[50.0, 50.0, 100.0]"),
    );
    assert!(
        wrong.contains("the mesh spans 1.7321e2 m")
            && wrong.contains("read with [mesh] unit = \"m\"")
            && wrong.contains("fix: check [mesh] unit"),
        "{wrong}"
    );
    // a stress of a million times young, a conductivity, a relaxation time and a young far off
    let off = check(
        "unit = \"mm\"\n",
        &format!("[material]\nconductivity = 1e-5\nmass = 1e8\n[tissue]\nyoung = 1e-3\n{load}"),
    );
    for want in [
        "times [tissue] young",
        "the energy crosses the mesh in",
        "the mechanics relax in",
        "[tissue] young = 0.001 Pa is far",
    ] {
        assert!(off.contains(want), "{want}: {off}");
    }
}
