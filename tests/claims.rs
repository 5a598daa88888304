//! The paper's claims, checked on the shipped scenarios (scenarios/cylinder*.toml): the
//! homogeneous cylinder deforms symmetrically about the load axis, the anisotropic one
//! (r_x = 0.08) spreads further along x, the heterogeneous halves deform differently, and the
//! displacement after 20 iterations grows faster than linearly with the force and falls with g.

use eprop::config::{Scenario, Setup};
use eprop::simulate::Simulation;
use std::path::Path;

type V3 = [f64; 3];

/// Runs a shipped scenario (its text edited by `edit`) for `steps`; returns the points, the
/// displacements (input node order) and the first load's contact displacement.
fn run(name: &str, steps: u64, edit: &dyn Fn(String) -> String) -> (Vec<V3>, Vec<V3>, V3) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name);
    let text = edit(std::fs::read_to_string(&path).unwrap());
    let text = eprop::config::set::apply(&text, &[format!("time.steps={steps}")]).unwrap();
    let sc = Scenario::parse(&path, text).unwrap();
    let mut sim = Simulation::new(Setup::new(sc).unwrap()).unwrap();
    while !sim.done() {
        sim.advance().unwrap();
    }
    let u = sim.in_output_order(sim.u());
    let u: Vec<V3> = u.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
    let probe = sim.probes()[0].1;
    (sim.global_mesh().unwrap().points.clone(), u, probe)
}

fn norm(v: V3) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Second moments of |u| about the load point (1, 0, 2) along x and along y.
fn moments(p: &[V3], u: &[V3]) -> (f64, f64) {
    let (mut w, mut mx, mut my) = (0.0, 0.0, 0.0);
    for (p, u) in p.iter().zip(u) {
        let m = norm(*u);
        w += m;
        mx += m * (p[0] - 1.0).powi(2);
        my += m * p[1].powi(2);
    }
    (mx / w, my / w)
}

#[test]
fn homogeneous_cylinder_deforms_symmetrically_about_the_load_axis() {
    let (p, u, _) = run("cylinder.toml", 100, &|s| s);
    let umax = u.iter().map(|v| norm(*v)).fold(0.0, f64::max);
    let mut worst: f64 = 0.0;
    let mut pairs = 0;
    for i in 0..p.len() {
        if p[i][1].abs() < 1e-9 {
            continue;
        }
        let j = (0..p.len())
            .find(|&j| {
                (p[j][0] - p[i][0]).abs() < 1e-9 && (p[j][1] + p[i][1]).abs() < 1e-9 && (p[j][2] - p[i][2]).abs() < 1e-9
            })
            .expect("the cylinder is mirror-symmetric in y");
        let d = [u[i][0] - u[j][0], u[i][1] + u[j][1], u[i][2] - u[j][2]];
        worst = worst.max(norm(d));
        pairs += 1;
    }
    eprintln!("mirror asymmetry: {:.3e} of max |u| over {pairs} pairs", worst / umax);
    assert!(pairs > 100);
    assert!(worst < 0.05 * umax, "asymmetry {:.3e} of max |u|", worst / umax);
}

#[test]
fn anisotropic_cylinder_spreads_further_along_x() {
    let (p, u0, _) = run("cylinder.toml", 100, &|s| s);
    let (_, u1, _) = run("cylinder_anisotropic.toml", 100, &|s| s);
    let (x0, y0) = moments(&p, &u0);
    let (x1, y1) = moments(&p, &u1);
    eprintln!("second moments of |u| about the load: homogeneous x {x0:.4} y {y0:.4}; anisotropic x {x1:.4} y {y1:.4}");
    assert!(
        x1 / y1 > 1.02 * (x0 / y0),
        "x/y spread: anisotropic {} vs homogeneous {}",
        x1 / y1,
        x0 / y0
    );
    assert!(x1 > x0, "r_x = 0.08 must carry the deformation deeper along x");
}

#[test]
fn heterogeneous_halves_deform_differently() {
    // r_x = 0.08 only above the load (z > 2): there the deformation reaches deeper along x
    // than below, unlike the homogeneous cylinder; compare the x-spread of |u| per half
    let spread = |p: &[V3], u: &[V3], upper: bool| -> f64 {
        let sel: Vec<usize> = (0..p.len())
            .filter(|&i| (p[i][2] - 2.0).abs() > 1e-9 && (p[i][2] > 2.0) == upper)
            .collect();
        let (pp, uu): (Vec<V3>, Vec<V3>) = sel.iter().map(|&i| (p[i], u[i])).unzip();
        moments(&pp, &uu).0
    };
    let (p, u0, _) = run("cylinder.toml", 100, &|s| s);
    let (_, u1, _) = run("cylinder_heterogeneous.toml", 100, &|s| s);
    let r0 = spread(&p, &u0, true) / spread(&p, &u0, false);
    let r1 = spread(&p, &u1, true) / spread(&p, &u1, false);
    eprintln!("x-spread of |u|, upper / lower half: homogeneous {r0:.4}, heterogeneous {r1:.4}");
    assert!(
        r1 > 1.01 * r0,
        "the upper half (r_x = 0.08) must spread further along x: {r1} vs {r0}"
    );
}

#[test]
fn figure_5_displacement_is_superlinear_in_force_and_falls_with_damping() {
    let contact = |force: f64, g: f64| {
        let (_, _, d) = run("cylinder.toml", 20, &|s: String| {
            s.replace("damping = 2.0", &format!("damping = {g}"))
                .replace("normal = 0.3", &format!("normal = {force}"))
                .replace("scheme = \"compact\"", "scheme = \"compact\"\nstiffness = 0.0")
                .replace("steps = 100", "steps = 20\ndt = 0.1")
        });
        norm(d)
    };
    for g in [1.0, 4.0, 6.0] {
        let (a, b) = (contact(0.5, g), contact(1.0, g));
        eprintln!("g = {g}: |u| = {a:.5} at F = 0.5, {b:.5} at F = 1.0");
        assert!(
            b > 2.0 * a * 1.001,
            "g = {g}: doubling the force must more than double |u| ({a} -> {b})"
        );
    }
    let (a, b, c) = (contact(1.0, 1.0), contact(1.0, 4.0), contact(1.0, 6.0));
    assert!(a > b && b > c, "|u| must fall with damping: {a} {b} {c}");
}

#[test]
fn a_contact_patch_is_far_less_mesh_dependent_than_a_node() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/cylinder_patch.toml");
    let base = std::fs::read_to_string(&path).unwrap();
    let contact = |text: &str, rings: usize, layers: usize| {
        let mesh = eprop_io::generate::cylinder_mesh(1.0, 4.0, rings, layers).unwrap();
        let text = eprop::config::set::apply(text, &["time.steps=60".to_string()]).unwrap();
        let sc = Scenario::parse(&path, text).unwrap();
        let mut sim = Simulation::new(Setup::with_mesh(sc, mesh).unwrap()).unwrap();
        while !sim.done() {
            sim.advance().unwrap();
        }
        norm(sim.probes()[0].1)
    };
    let node = base.replace(
        "patch = { center = [1.0, 0.0, 2.0], radius = 0.4 }",
        "nearest = [1.0, 0.0, 2.0]",
    );
    let (p1, p2) = (contact(&base, 3, 11), contact(&base, 6, 22));
    let (n1, n2) = (contact(&node, 3, 11), contact(&node, 6, 22));
    let (dp, dn) = ((p2 / p1 - 1.0).abs(), (n2 / n1 - 1.0).abs());
    eprintln!(
        "refining 2x: patch |u| {p1:.4} -> {p2:.4} ({:.1}%), node |u| {n1:.4} -> {n2:.4} ({:.1}%)",
        100.0 * dp,
        100.0 * dn
    );
    assert!(dp < 0.5 * dn, "the patch should change much less than the single node");
}
