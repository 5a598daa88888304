//! The screening term of the propagation (`[model] screening = l`, docs/model.md section 3):
//! d phi/dt = div(R grad phi) - (D/l^2) phi + Q. Its discrete steady state decays as the
//! analytic one, every integrator agrees with euler with it on, the kinematic contact keeps
//! its held rows, and a run writes the same bits on 1 and 3 processes.

mod common;

use eprop::simulate::Simulation;
use eprop_io::generate::{box_mesh, BoxCells};
use eprop_io::geom::norm;
use eprop_series::vtkhdf::ToolState;
use std::path::Path;

/// On a bar along x the screened operator's steady state is the discrete exponential
/// phi = exp(-k x) with 2 (cosh(k h) - 1) / h^2 = 1 / l^2 (the three-point stencil of the
/// median dual on the box's tetrahedra): L phi = 0 at every node off the bar's two ends, to
/// round-off, in all three components, whatever the conductivity (the end x = 1 is fixed). k tends to the analytic
/// 1/l at second order in h; a constant field loses D/l^2 of itself per unit time exactly.
#[test]
fn the_screened_steady_state_is_the_discrete_exponential_decay() {
    let l = 0.15;
    let mut rates = vec![];
    for (cells, conductivity) in [(12, 0.05), (24, 0.05), (48, 0.3)] {
        let h = 1.0 / cells as f64;
        let mesh = box_mesh([1.0, 0.2, 0.15], [cells, 2, 2], BoxCells::Tet).unwrap();
        let sim = common::sim(
            mesh,
            &format!("[[fixed]]\ngroup = \"xmax\"\n[material]\nconductivity = {conductivity}\n[model]\nscreening = {l}\n[time]\nsteps = 1\n"),
        );
        let x: Vec<[f64; 3]> = sim.setup().mesh.points.clone();
        let n = sim.n_owned();
        let active = sim.active()[..n].to_vec();
        let mut prop = sim.into_propagation();
        let k = (1.0 + h * h / (2.0 * l * l)).acosh() / h;
        let phi: Vec<[f64; 3]> = x
            .iter()
            .map(|p| [(-k * p[0]).exp(), -2.0 * (-k * p[0]).exp(), 0.5])
            .collect();
        let mut y = vec![[0.0; 3]; phi.len()];
        prop.apply(&phi, &mut y);
        let mut worst = 0.0f64;
        for i in (0..n).filter(|&i| active[i]) {
            if x[i][0] > 0.5 * h && x[i][0] < 1.0 - 0.5 * h {
                // the scale of the row's terms: D phi / h^2
                let scale = conductivity * phi[i][0].abs() / (h * h);
                worst = worst.max(y[i][0].abs() / scale);
                worst = worst.max(y[i][1].abs() / (2.0 * scale));
            }
            // the constant third component: -(D / l^2) 0.5 exactly, to round-off
            let c = -conductivity / (l * l) * 0.5;
            assert!((y[i][2] - c).abs() <= 1e-12 * c.abs(), "node {i}: {} vs {c}", y[i][2]);
        }
        println!(
            "{cells} cells: the discrete exponential's residual {worst:.2e} of D phi / h^2, k l = {:.6}",
            k * l
        );
        assert!(worst < 1e-12, "{cells} cells: {worst:e}");
        rates.push((h, k * l - 1.0));
    }
    // k l - 1 = -(h/l)^2 / 24 + ...: second order
    for (h, e) in &rates {
        let want = -(h / l) * (h / l) / 24.0;
        assert!(
            (e - want).abs() < 0.05 * want.abs(),
            "h {h}: k l - 1 = {e:e}, want {want:e}"
        );
    }
}

/// A punch pressed into the unit box with the screening on (kinematic contact): every
/// integrator's displacement within 1e-3 of euler's largest and its force within 5e-3 of
/// euler's peak at every step, with the same contact; the screening deepens neither: it
/// stiffens (a larger force) and localises (a smaller far displacement) against no screening.
fn punch_press(dir: &Path, kind: &str, settings: &str, screening: Option<f64>) -> (Vec<ToolState>, Vec<[f64; 3]>) {
    let scr = screening.map_or(String::new(), |l| format!("screening = {l}\n"));
    let model = format!("[model]\nintegrator = \"{kind}\"\n{scr}{settings}");
    let setup = common::setup(
        box_mesh([1.0; 3], [8; 3], BoxCells::Tet).unwrap(),
        &format!("[[fixed]]\ngroup = \"zmin\"\n[[tool]]\nshape = \"punch\"\nradius = 0.3\nnormal = [0, 0, -1]\nstart = [0.5, 0.5, 1.02]\nvelocity = [0, 0, -0.004]\n{model}[time]\ndt = 0.5\nsteps = 40\n"),
        dir,
    );
    let mut sim = Simulation::new(setup).expect("simulation builds");
    let mut out = vec![];
    while !sim.done() {
        sim.advance().unwrap();
        out.push(sim.tool_states()[0]);
    }
    let n = sim.n_owned();
    (out, sim.u()[..n].to_vec())
}

#[test]
fn every_integrator_agrees_with_euler_with_the_screening_on() {
    let d = tempfile::tempdir().unwrap();
    let (euler, ue) = punch_press(d.path(), "euler", "", Some(0.25));
    let peak = euler.iter().map(|t| norm(t.force)).fold(0.0, f64::max);
    let umax = ue.iter().map(|u| norm(*u)).fold(0.0, f64::max);
    assert!(peak > 0.0 && umax > 0.0);
    for (kind, settings) in [
        ("rkl2", ""),
        ("implicit", "[integrator]\npreconditioner = \"jacobi\"\n"),
        ("implicit", "[integrator]\npreconditioner = \"multigrid\"\n"),
        ("auto", ""),
    ] {
        let (other, uo) = punch_press(d.path(), kind, settings, Some(0.25));
        let mut worst = 0.0f64;
        for (k, (a, b)) in other.iter().zip(&euler).enumerate() {
            assert_eq!(a.contact_nodes, b.contact_nodes, "{kind} step {k}");
            worst = worst.max(norm(eprop_io::geom::sub(a.force, b.force)) / peak);
        }
        let du = uo
            .iter()
            .zip(&ue)
            .map(|(a, b)| norm(eprop_io::geom::sub(*a, *b)))
            .fold(0.0, f64::max)
            / umax;
        println!("{kind} {settings:?}: force {worst:.2e} of the peak, u {du:.2e} of the largest");
        assert!(worst < 5e-3, "{kind} {settings}: force {worst}");
        assert!(du < 1e-3, "{kind} {settings}: u {du}");
    }
    // against no screening: the same held face, a stiffer reaction, less far displacement
    let (plain, up) = punch_press(d.path(), "euler", "", None);
    let last = |s: &[ToolState]| -s.last().unwrap().force[2];
    assert!(last(&euler) > last(&plain), "{} vs {}", last(&euler), last(&plain));
    let far = |u: &[[f64; 3]]| u.iter().map(|v| v[2].abs()).sum::<f64>();
    assert!(far(&ue) < far(&up));
}

/// The screening on 1 and 3 processes, with euler, rkl2 and implicit (jacobi and
/// multigrid), a kinematic punch pressing: the same bits.
#[test]
fn screening_is_bitwise_identical_on_1_and_3_ranks() {
    let d = tempfile::tempdir().unwrap();
    let mesh = d.path().join("box.msh");
    eprop_io::write_mesh(&box_mesh([1.0; 3], [10; 3], BoxCells::Tet).unwrap(), &mesh).unwrap();
    for (kind, pre) in [
        ("euler", "jacobi"),
        ("rkl2", "jacobi"),
        ("implicit", "jacobi"),
        ("implicit", "multigrid"),
    ] {
        let sc = d.path().join(format!("{kind}-{pre}.toml"));
        std::fs::write(
            &sc,
            format!(
                "[mesh]\nfile = \"{}\"\n[model]\nreading = \"paper\"\nintegrator = \"{kind}\"\nscreening = 0.3\n[integrator]\npreconditioner = \"{pre}\"\n\
                 [[fixed]]\ngroup = \"zmin\"\n[[tool]]\nshape = \"punch\"\nradius = 0.3\nnormal = [0, 0, -1]\nstart = [0.45, 0.5, 1.02]\nvelocity = [0, 0, -0.006]\n\
                 [time]\ndt = 0.5\nsteps = 20\n[output]\nevery = 4\n",
                mesh.display()
            ),
        )
        .unwrap();
        let sc = sc.to_str().unwrap();
        let one = d.path().join(format!("{kind}-{pre}-1.h5"));
        let out = common::serial(&["run", sc, "-q", "-o", one.to_str().unwrap()], 1);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let three = d.path().join(format!("{kind}-{pre}-3.h5"));
        let out = common::mpirun(3, &["run", sc, "-q", "-o", three.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{kind} {pre}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        common::assert_same(&one, &three);
    }
}
