//! The integrators of the propagation (docs/integrators.md): each converges at its order on a
//! discrete eigenvector of L (where the semi-discrete solution is exact), agrees with euler on
//! the cylinder and on a real organ mesh within its own error estimate, reaches the same
//! equilibrium, and fails with an error that names the fix.

mod common;

use common::sim;
use eprop::config::integrator::Settings;
use eprop::distribute::comm::Serial;
use eprop::linalg::V3;
use eprop::propagate::integrate::{Euler, Implicit, Rkl2, StepPlan, StepStats, Stepper};
use eprop::propagate::{Propagation, Sources};
use eprop::simulate::Simulation;
use eprop_io::generate::{box_mesh, cylinder_mesh, BoxCells};
use std::f64::consts::PI;

/// Box [0,1]^3 with every wall fixed: sin(pi x) sin(pi y) sin(pi z) vanishes there.
const WALLS: &str = "[[fixed]]\ngroup = \"xmin\"\n[[fixed]]\ngroup = \"xmax\"\n[[fixed]]\ngroup = \"ymin\"\n[[fixed]]\ngroup = \"ymax\"\n[[fixed]]\ngroup = \"zmin\"\n[[fixed]]\ngroup = \"zmax\"\n";

fn rel(a: &[V3], b: &[V3]) -> f64 {
    let (mut d, mut s) = (0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        for k in 0..3 {
            d += (x[k] - y[k]) * (x[k] - y[k]);
            s += y[k] * y[k];
        }
    }
    (d / s).sqrt()
}

fn settings() -> Settings {
    Settings {
        tolerance: 1e-13,
        ..Settings::default()
    }
}

/// A stepper of the given kind for the mechanics step `dt` on a simulation's propagation
/// `prop` (its control volumes `vol`, nodes that move `active`, forward Euler bound `hb`):
/// "euler" with `k` substeps, "rkl2" with the fewest stable stages, "implicit".
fn stepper(
    prop: &Propagation,
    vol: &[f64],
    active: &[bool],
    hb: f64,
    kind: &str,
    dt: f64,
    k: usize,
) -> Box<dyn Stepper> {
    let layout = prop.layout();
    match kind {
        "euler" => Box::new(Euler::new(hb, dt, Some(dt / k as f64), "t", "compact").unwrap()),
        "rkl2" => Box::new(Rkl2::new(hb, dt, 1, 1 << 20, layout, "t", String::new()).unwrap()),
        _ => {
            let gid: Vec<u64> = (0..layout.n_local as u64).collect();
            Box::new(Implicit::new(prop, vol, active, &gid, dt, hb, &settings(), "t", &Serial).unwrap())
        }
    }
}

/// sin(pi x) sin(pi y) sin(pi z) times `dir` on the owned nodes that move (0 elsewhere): an
/// eigenvector of the unit Kuhn box's L with walls on every face.
fn box_mode(s: &Simulation, dir: V3) -> Vec<V3> {
    let pts = &s.mesh().points;
    (0..s.n_owned())
        .map(|i| {
            let p = pts[i];
            let f = if s.active()[i] {
                (PI * p[0]).sin() * (PI * p[1]).sin() * (PI * p[2]).sin()
            } else {
                0.0
            };
            [dir[0] * f, dir[1] * f, dir[2] * f]
        })
        .collect()
}

#[test]
fn each_integrator_converges_at_its_order_on_an_eigenvector_of_l() {
    let mesh = box_mesh([1.0; 3], [20, 20, 20], BoxCells::Tet).unwrap();
    let s = sim(
        mesh,
        &format!("[material]\nconductivity = 0.1\n{WALLS}[time]\nsteps = 1\n"),
    );
    let n = s.n_owned();
    // v = sin(pi x) sin(pi y) sin(pi z) (1, -2, 0.5) is an eigenvector of the Kuhn box's L
    let v = box_mode(&s, [1.0, -2.0, 0.5]);
    let (vol, active, hb) = (s.volumes().to_vec(), s.active().to_vec(), s.step_plan().h_bound);
    let mut prop = s.into_propagation();
    let mut lv = vec![[0.0; 3]; n];
    prop.apply(&v, &mut lv);
    let lambda = {
        let (mut num, mut den) = (0.0, 0.0);
        for i in 0..n {
            num += v[i][0] * lv[i][0];
            den += v[i][0] * v[i][0];
        }
        num / den
    };
    let scaled: Vec<V3> = v
        .iter()
        .map(|x| [lambda * x[0], lambda * x[1], lambda * x[2]])
        .collect();
    assert!(rel(&lv, &scaled) < 1e-12, "not an eigenvector: {}", rel(&lv, &scaled));
    assert!(lambda < -2.0 && lambda > -3.5, "lambda {lambda}"); // about -3 pi^2 0.1
                                                                // to t = 1 / |lambda|; steps of lambda dt = -1/4, -1/8, -1/16
    let t_end = -1.0 / lambda;
    let exact: Vec<V3> = v.iter().map(|x| x.map(|c| c * (lambda * t_end).exp())).collect();
    for (kind, order) in [("euler", 1.0), ("rkl2", 2.0), ("implicit", 2.0)] {
        let mut errors = vec![];
        for level in 0..3 {
            // euler: 256 substeps per step of dt, dt halving; its error follows h = dt / 256
            let steps = 4usize << level;
            let dt = t_end / steps as f64;
            let mut st = stepper(&prop, &vol, &active, hb, kind, dt, 256);
            if kind == "rkl2" && level == 0 {
                // stiff: a super-step of many Euler bounds, several stages
                assert!(dt / hb > 15.0 && st.plan().per_step >= 6, "{}", dt / hb);
            }
            prop.phi.owned_mut().copy_from_slice(&v);
            for _ in 0..steps {
                st.advance(&mut prop, &[], &Serial).unwrap();
            }
            errors.push(rel(prop.phi.owned(), &exact));
        }
        let rates: Vec<f64> = errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
        eprintln!("{kind}: errors {errors:?}, rates {rates:?}");
        for r in &rates {
            assert!((r - order).abs() < 0.15, "{kind}: rate {r}, errors {errors:?}");
        }
        assert!(errors[2] < 1e-3, "{kind}: {errors:?}");
    }
}

#[test]
fn rkl2_and_implicit_take_sources_consistently_and_keep_a_steady_state() {
    // phi* solves L phi* + Q = 0 (Q := -L phi*): every integrator leaves it where it is
    let mesh = box_mesh([1.0, 0.5, 0.5], [8, 4, 4], BoxCells::Tet).unwrap();
    let s = sim(
        mesh,
        &format!("[material]\nconductivity = 0.5\n{WALLS}[time]\nsteps = 1\n"),
    );
    let n = s.n_owned();
    let target: Vec<V3> = (0..n)
        .map(|i| {
            let p = s.mesh().points[i];
            if s.active()[i] {
                [p[0] * (1.0 - p[0]), p[1].sin(), p[2] * p[0] - 0.1]
            } else {
                [0.0; 3]
            }
        })
        .collect();
    let (vol, active, hb) = (s.volumes().to_vec(), s.active().to_vec(), s.step_plan().h_bound);
    let mut prop = s.into_propagation();
    let mut l = vec![[0.0; 3]; n];
    prop.apply(&target, &mut l);
    let q: Vec<(u32, V3)> = (0..n)
        .filter(|&i| active[i])
        .map(|i| (i as u32, l[i].map(|c| -c)))
        .collect();
    for kind in ["euler", "rkl2", "implicit"] {
        let mut st = stepper(&prop, &vol, &active, hb, kind, 0.7, 200);
        prop.phi.owned_mut().copy_from_slice(&target);
        for _ in 0..3 {
            st.advance(&mut prop, &q, &Serial).unwrap();
        }
        let e = rel(prop.phi.owned(), &target);
        assert!(e < 1e-12, "{kind}: the steady state moved by {e}");
    }
}

/// Runs every stepper twice per mechanics step at dt / 2: the step-doubling error estimate.
struct Halves(Box<dyn Stepper>);

impl Stepper for Halves {
    fn plan(&self) -> &StepPlan {
        self.0.plan()
    }
    fn advance(
        &mut self,
        prop: &mut Propagation,
        q: &Sources,
        comm: &dyn eprop::distribute::comm::Comm,
    ) -> anyhow::Result<StepStats> {
        let a = self.0.advance(prop, q, comm)?;
        let b = self.0.advance(prop, q, comm)?;
        Ok(StepStats {
            applications: a.applications + b.applications,
        })
    }
}

/// Runs `steps` mechanics steps of a scenario with each integrator; checks that rkl2 and
/// implicit agree with euler (phi and u) within the sum of both error estimates: step
/// doubling, |X(dt) - X(dt/2)| (2^p / (2^p - 1)), p their orders.
fn agree_with_euler(mesh: eprop_mesh::Mesh, toml: &str, steps: usize) {
    let run = |kind: &str, halve: bool| -> (Vec<V3>, Vec<V3>) {
        let s = sim(mesh.clone(), toml);
        let dt = s.dt();
        let hb = s.step_plan().h_bound;
        let k = (dt / (0.9 * hb)).ceil() as usize;
        let st: Box<dyn Stepper> = if halve {
            Box::new(Halves(stepper(
                s.prop(),
                s.volumes(),
                s.active(),
                hb,
                kind,
                dt / 2.0,
                k,
            )))
        } else {
            stepper(s.prop(), s.volumes(), s.active(), hb, kind, dt, k)
        };
        let mut s = s.with_stepper(st);
        for _ in 0..steps {
            s.advance().unwrap();
        }
        (s.phi().owned().to_vec(), s.u().owned().to_vec())
    };
    let norm = |a: &[V3]| a.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
    let diff = |a: &[V3], b: &[V3]| {
        a.iter()
            .zip(b)
            .flat_map(|(x, y)| (0..3).map(move |k| (x[k] - y[k]) * (x[k] - y[k])))
            .sum::<f64>()
            .sqrt()
    };
    let (pe, ue) = run("euler", false);
    let (pe2, ue2) = run("euler", true);
    // euler: first order in its substep
    let est_e = (2.0 * diff(&pe, &pe2), 2.0 * diff(&ue, &ue2));
    for kind in ["rkl2", "implicit"] {
        let (p1, u1) = run(kind, false);
        let (p2, u2) = run(kind, true);
        let est = (4.0 / 3.0 * diff(&p1, &p2), 4.0 / 3.0 * diff(&u1, &u2));
        let (dp, du) = (diff(&p1, &pe), diff(&u1, &ue));
        eprintln!(
            "{kind}: |phi - euler| {:.2e} (estimates {:.2e} + euler {:.2e}), |u - euler| {:.2e} (estimates {:.2e} + {:.2e}), relative to |phi| {:.2e}, |u| {:.2e}",
            dp,
            est.0,
            est_e.0,
            du,
            est.1,
            est_e.1,
            norm(&pe),
            norm(&ue)
        );
        // the estimates are asymptotic: a factor 2 of slack, and a floor at roundoff
        assert!(dp <= 2.0 * (est.0 + est_e.0) + 1e-12 * norm(&pe), "{kind}: phi");
        assert!(du <= 2.0 * (est.1 + est_e.1) + 1e-12 * norm(&ue), "{kind}: u");
        assert!(du <= 1e-3 * norm(&ue), "{kind}: u differs from euler's by {du:.2e}");
    }
}

#[test]
fn rkl2_and_implicit_agree_with_euler_on_the_cylinder() {
    let mesh = cylinder_mesh(1.0, 4.0, 4, 14).unwrap();
    // a conductivity that asks euler for about 60 substeps per step
    agree_with_euler(
        mesh,
        "[material]\nconductivity = 0.8\n[[fixed]]\ngroup = \"bottom\"\n[[load]]\npatch = { center = [1.0, 0.0, 2.0], radius = 0.6 }\nnormal = 1.0\n[time]\nsteps = 8\n",
        8,
    );
}

#[test]
fn rkl2_and_implicit_agree_with_euler_on_an_organ_mesh() {
    let Some(path) = common::shared_mesh("mor_liverFine.vtu") else {
        return;
    };
    let mesh = eprop_io::read_mesh(&path).unwrap();
    // the SOFA liver (4293 nodes, tetrahedra of very different sizes): about 250 substeps
    agree_with_euler(
        mesh,
        "[material]\nconductivity = 0.3\n[[fixed]]\nhalfspace = { point = [-4.0, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }\n[[load]]\npatch = { center = [0.0, 5.2, 0.5], radius = 1.0 }\nnormal = 1.0\n[time]\nsteps = 6\n",
        6,
    );
}

/// A direct solve of L phi + Q = 0 on the free nodes (conjugate gradients on the symmetric
/// form W phi = -V Q, to roundoff).
fn direct(s: &Simulation, q: &[(u32, V3)]) -> Vec<V3> {
    let eprop::discretize::operator::Operator::Compact(op) = &s.prop().op else {
        panic!()
    };
    let n = s.n_owned();
    let vol = s.volumes();
    let active = s.active();
    let apply = |x: &[V3], y: &mut [V3]| {
        for i in 0..n {
            let mut acc = [0.0; 3];
            if active[i] {
                for p in op.coefficients().row(i) {
                    let j = op.col()[p] as usize;
                    for d in 0..3 {
                        acc[d] += op.c(p) * vol[i] * (x[j][d] - x[i][d]);
                    }
                }
            }
            y[i] = acc.map(|a| -a);
        }
    };
    let mut b = vec![[0.0; 3]; n];
    for &(i, qi) in q {
        b[i as usize] = qi.map(|c| c * vol[i as usize]);
    }
    let dot = |a: &[V3], b: &[V3]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| x[0] * y[0] + x[1] * y[1] + x[2] * y[2])
            .sum::<f64>()
    };
    let mut x = vec![[0.0; 3]; n];
    let mut r = b.clone();
    let mut p = r.clone();
    let mut ap = vec![[0.0; 3]; n];
    let mut rr = dot(&r, &r);
    let b2 = rr;
    for _ in 0..20 * n {
        apply(&p, &mut ap);
        let alpha = rr / dot(&p, &ap);
        for i in 0..n {
            for d in 0..3 {
                x[i][d] += alpha * p[i][d];
                r[i][d] -= alpha * ap[i][d];
            }
        }
        let rr2 = dot(&r, &r);
        if rr2 < 1e-32 * b2 {
            break;
        }
        for i in 0..n {
            for d in 0..3 {
                p[i][d] = r[i][d] + rr2 / rr * p[i][d];
            }
        }
        rr = rr2;
    }
    x
}

#[test]
fn every_integrator_reaches_the_same_equilibrium() {
    let mesh = box_mesh([1.0, 0.5, 0.5], [8, 4, 4], BoxCells::Tet).unwrap();
    let base = "[material]\nconductivity = [1.0, 0.6, 0.8]\n[[fixed]]\ngroup = \"xmin\"\n[[load]]\npatch = { center = [1.0, 0.25, 0.25], radius = 0.2 }\nforce = [1.0, 0.5, -0.3]\n[time]\nequilibrium = 1e-13\nsteps = 20000\n[integrator]\ntolerance = 1e-14\n";
    let mut results = vec![];
    for kind in ["euler", "rkl2", "implicit"] {
        let mut s = sim(
            mesh.clone(),
            &format!("[model]\nreading = \"paper\"\nintegrator = \"{kind}\"\n{base}"),
        );
        assert_eq!(s.step_plan().integrator.name(), kind);
        while !s.done() {
            s.advance().unwrap();
        }
        assert!(s.max_speed() < 1e-13, "{kind}: no equilibrium after {} steps", s.step());
        let q: Vec<(u32, V3)> = {
            // the sources of the last step (constant load)
            let a = s.applied(s.time());
            s.load_nodes()[0]
                .iter()
                .map(|&(i, _, _, sw)| {
                    (
                        i,
                        a[0].force.map(|f| f * sw * a[0].q / eprop_io::geom::norm(a[0].force)),
                    )
                })
                .collect()
        };
        let exact = direct(&s, &q);
        let e = rel(s.phi().owned(), &exact);
        eprintln!("{kind}: {} steps, |phi - direct| / |direct| = {e:.2e}", s.step());
        assert!(e < 1e-9, "{kind}: equilibrium off the direct solve by {e}");
        results.push((s.phi().owned().to_vec(), s.u().owned().to_vec()));
    }
    for (k, r) in results.iter().enumerate().skip(1) {
        assert!(rel(&r.0, &results[0].0) < 1e-9, "{k}: phi");
        assert!(rel(&r.1, &results[0].1) < 1e-9, "{k}: u");
    }
}

fn build_err(mesh: eprop_mesh::Mesh, toml: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let setup = common::setup(mesh, toml, dir.path());
    match Simulation::new(setup) {
        Ok(_) => panic!("{toml}: built"),
        Err(e) => format!("{e:#}"),
    }
}

const STIFF: &str = "[material]\nconductivity = 2.0\n[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 1.0\n[time]\nsteps = 2\n";

#[test]
fn a_solve_that_does_not_converge_is_an_error_that_names_the_fix() {
    let mesh = cylinder_mesh(1.0, 4.0, 4, 14).unwrap();
    // at setup: the trial solve that estimates the work
    let e = build_err(
        mesh.clone(),
        &format!("[model]\nreading = \"paper\"\nintegrator = \"implicit\"\n[integrator]\nmax_iterations = 1\ntolerance = 1e-14\n{STIFF}"),
    );
    assert!(
        e.contains("did not converge in 1 iterations") && e.contains("fix:") && e.contains("max_iterations"),
        "{e}"
    );
    // during a step
    let s = sim(mesh, STIFF);
    let st = Settings {
        max_iterations: 1,
        tolerance: 1e-14,
        ..Settings::default()
    };
    let hb = s.step_plan().h_bound;
    let implicit = Box::new(
        Implicit::new(
            s.prop(),
            s.volumes(),
            s.active(),
            s.gid(),
            s.dt(),
            hb,
            &st,
            "s.toml",
            &Serial,
        )
        .unwrap(),
    );
    let mut s = s.with_stepper(implicit);
    let e = format!("{:#}", s.advance().expect_err("one iteration is not enough"));
    assert!(
        e.contains("s.toml") && e.contains("stage 1 of step 1") && e.contains("fix:"),
        "{e}"
    );
}

#[test]
fn refusals_name_what_works() {
    let mesh = cylinder_mesh(1.0, 4.0, 4, 14).unwrap();
    let e = build_err(
        mesh.clone(),
        &format!("[model]\nreading = \"paper\"\nintegrator = \"rkl2\"\n[integrator]\nmax_stages = 3\n{STIFF}"),
    );
    assert!(
        e.contains("max_stages = 3") && e.contains("fix:") && e.contains("implicit"),
        "{e}"
    );
    for kind in ["rkl2", "implicit"] {
        let e = build_err(
            mesh.clone(),
            &format!("[model]\nreading = \"paper\"\nscheme = \"paper\"\nintegrator = \"{kind}\"\n{STIFF}"),
        );
        assert!(
            e.contains("compact") && e.contains("\"euler\"") && e.contains("fix:"),
            "{e}"
        );
        let e = build_err(
            mesh.clone(),
            &format!("[model]\nreading = \"paper\"\nintegrator = \"{kind}\"\n{STIFF}")
                .replace("steps = 2", "steps = 2\nh = 0.001"),
        );
        assert!(e.contains("[time] h") && e.contains("fix:"), "{e}");
    }
    // auto on the paper scheme: euler
    let s = sim(
        mesh.clone(),
        &format!("[model]\nreading = \"paper\"\nscheme = \"paper\"\n{STIFF}"),
    );
    assert_eq!(s.step_plan().integrator.name(), "euler");
    assert!(s.step_plan().why.contains("paper"), "{}", s.step_plan().why);
    // auto on a stiff compact case: not euler, and it says why
    let s = sim(mesh, &STIFF.replace("2.0", "20.0"));
    assert_ne!(s.step_plan().integrator.name(), "euler", "{:?}", s.step_plan());
    assert!(
        s.step_plan().why.starts_with("auto:") && s.step_plan().why.contains("euler"),
        "{}",
        s.step_plan().why
    );
}

#[test]
fn scenario_keys_are_checked() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.toml");
    let mesh = cylinder_mesh(1.0, 4.0, 3, 6).unwrap();
    for (text, want) in [
        ("integrator = \"rk4\"\n", "\"rkl2\" or \"implicit\""),
        ("[integrator]\ntolerance = 2.0\n", "between 0 and 1"),
        ("[integrator]\naccuracy = 0.0\n", "inf for no error control"),
        ("[integrator]\npreconditioner = \"ilu\"\n", "\"jacobi\""),
        ("[integrator]\nmax_iterations = 0\n", "at least 1"),
        ("[integrator]\nmax_stages = 1\n", "at least 2"),
    ] {
        let full = format!("[mesh]\nfile = \"x.msh\"\n[model]\nreading = \"paper\"\n{text}[[fixed]]\ngroup = \"bottom\"\n[time]\nsteps = 1\n");
        // a bad value fails the parse, at its line
        let e = eprop::config::Scenario::parse(&p, full)
            .and_then(|sc| eprop::config::Setup::with_mesh(sc, mesh.clone()))
            .err()
            .map(|e| format!("{e:#}"))
            .unwrap();
        assert!(e.contains(want) && e.contains("fix:") && e.contains("s.toml:"), "{e}");
    }
}

#[test]
fn a_restarted_run_continues_bit_for_bit_with_rkl2_and_implicit() {
    // both take their step from phi^n alone: nothing is lost when a run stops
    let d = tempfile::tempdir().unwrap();
    eprop_io::write_mesh(&cylinder_mesh(1.0, 4.0, 4, 14).unwrap(), &d.path().join("cyl.msh")).unwrap();
    for kind in ["rkl2", "implicit"] {
        let sc = d.path().join(format!("{kind}.toml"));
        std::fs::write(
            &sc,
            format!(
                "[mesh]\nfile = \"cyl.msh\"\n[model]\nreading = \"paper\"\nintegrator = \"{kind}\"\n{}[output]\nevery = 2\n",
                STIFF
                    .replace("steps = 2", "steps = 12")
                    .replace("normal = 1.0", "normal = 1.0\nramp = [[0.0, 0.0], [5.0, 1.0]]")
            ),
        )
        .unwrap();
        let (full, cut) = (
            d.path().join(format!("{kind}_full.h5")),
            d.path().join(format!("{kind}_cut.h5")),
        );
        let sc = sc.to_str().unwrap();
        for args in [
            vec!["run", sc, "-q", "-o", full.to_str().unwrap()],
            vec!["run", sc, "-q", "-o", cut.to_str().unwrap(), "--steps", "6"],
            vec!["run", sc, "-q", "--restart", cut.to_str().unwrap()],
        ] {
            let out = common::serial(&args, 1);
            assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        }
        common::assert_same(&full, &cut);
    }
}

#[test]
fn info_check_and_the_summary_say_what_sets_the_substep_and_which_integrator_runs() {
    let d = tempfile::tempdir().unwrap();
    // a box with one node pushed almost onto its neighbour: flat cells around it
    let mut mesh = box_mesh([1.0; 3], [6, 6, 6], BoxCells::Tet).unwrap();
    let c = mesh.points.iter().position(|p| *p == [0.5, 0.5, 0.5]).unwrap();
    for x in mesh.points[c].iter_mut() {
        *x += 0.16;
    }
    // the moved node or the one it almost touches sets the substep
    let nb = mesh
        .points
        .iter()
        .position(|p| p.iter().all(|x| (x - 4.0 / 6.0).abs() < 1e-12))
        .unwrap();
    let ids = [mesh.node_id(c), mesh.node_id(nb)];
    let named = |t: &str| ids.iter().any(|id| t.contains(&format!("set by node {id},")));
    let m = d.path().join("sliver.msh");
    eprop_io::write_mesh(&mesh, &m).unwrap();
    let out = common::serial(&["info", m.to_str().unwrap()], 1);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    assert!(
        named(&text) && text.contains("stiffest") && text.contains("quality"),
        "{text}"
    );
    let sc = d.path().join("s.toml");
    std::fs::write(
        &sc,
        "[mesh]\nfile = \"sliver.msh\"\n[model]\nreading = \"paper\"\n[material]\nconductivity = 1.0\n[[fixed]]\ngroup = \"xmin\"\n[[load]]\npatch = { center = [1.0, 0.5, 0.5], radius = 0.3 }\nnormal = 1.0\n[time]\nsteps = 3\n",
    )
    .unwrap();
    let out = common::serial(&["check", sc.to_str().unwrap()], 1);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    assert!(
        text.contains("integrator  ") && text.contains("auto: ") && named(&text),
        "{text}"
    );
    let out = common::serial(
        &[
            "run",
            sc.to_str().unwrap(),
            "-q",
            "-o",
            d.path().join("s.h5").to_str().unwrap(),
        ],
        1,
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    assert!(
        text.contains("operator applications per step") && text.contains("auto: "),
        "{text}"
    );
}

#[test]
fn the_error_estimates_match_the_true_error_on_an_eigenvector() {
    // one step of tau lambda = -1/4 and -1/8 from v (an eigenvector of L, where the exact step
    // is exp(tau lambda) v): implicit's embedded estimate and rkl2's step doubling against
    // the true relative error, with an accuracy loose enough that one (super-)step is taken
    let mesh = box_mesh([1.0; 3], [12, 12, 12], BoxCells::Tet).unwrap();
    let s = sim(
        mesh,
        &format!("[material]\nconductivity = 0.1\n{WALLS}[time]\nsteps = 1\n"),
    );
    let n = s.n_owned();
    let v = box_mode(&s, [1.0, 0.5, -1.0]);
    let (vol, active, hb) = (s.volumes().to_vec(), s.active().to_vec(), s.step_plan().h_bound);
    let gid = s.gid().to_vec();
    let mut prop = s.into_propagation();
    let mut lv = vec![[0.0; 3]; n];
    prop.apply(&v, &mut lv);
    let lambda = (0..n).map(|i| v[i][0] * lv[i][0]).sum::<f64>() / (0..n).map(|i| v[i][0] * v[i][0]).sum::<f64>();
    // implicit with jacobi filters the estimate by conjugate gradients, with a multigrid by
    // one preconditioned step
    for kind in ["implicit", "implicit, multigrid", "rkl2"] {
        let mut ratios = vec![];
        for z in [0.25, 0.125] {
            let dt = z / -lambda;
            let mut st: Box<dyn Stepper> = if kind == "rkl2" {
                let mut r = Rkl2::new(hb, dt, 1, 1 << 20, prop.layout(), "t", String::new()).unwrap();
                r.set_accuracy(0.5);
                Box::new(r)
            } else {
                let mut set = settings();
                if kind.ends_with("multigrid") {
                    set.preconditioner = eprop::config::integrator::Preconditioner::Multigrid;
                }
                let mut imp = Implicit::new(&prop, &vol, &active, &gid, dt, hb, &set, "t", &Serial).unwrap();
                imp.set_accuracy(0.5);
                Box::new(imp)
            };
            prop.phi.owned_mut().copy_from_slice(&v);
            st.advance(&mut prop, &[], &Serial).unwrap();
            let exact: Vec<V3> = v.iter().map(|x| x.map(|c| c * (lambda * dt).exp())).collect();
            let truth = rel(prop.phi.owned(), &exact);
            let est = st.last_error().unwrap();
            eprintln!("{kind}, tau lambda = -{z}: estimate {est:.3e}, true error {truth:.3e}");
            ratios.push(est / truth);
        }
        // rkl2 keeps the halves, whose error the doubling estimates; implicit estimates its
        // own step's (to the filter's (1 - theta z)^-2)
        for r in &ratios {
            assert!(*r > 0.3 && *r < 3.0, "{kind}: estimate over true error {ratios:?}");
        }
    }
}

#[test]
fn auto_replays_its_trial_steps_and_gives_the_bits_of_the_integrator_it_chose() {
    // a stiff 16^3 box under an impulsive patch load: auto takes rkl2 for a short run and
    // implicit for a long one (the first steps' transient weighs less), and the run replays
    // the chosen one's trial steps instead of computing them again
    let d = tempfile::tempdir().unwrap();
    eprop_io::write_mesh(
        &box_mesh([1.0; 3], [16, 16, 16], BoxCells::Tet).unwrap(),
        &d.path().join("box.msh"),
    )
    .unwrap();
    // and a sphere that reaches the box at step 3 and presses on (its contact sources are
    // known in advance): rkl2, replayed from step 3
    let patch = "[[load]]\npatch = { center = [1.0, 0.5, 0.5], radius = 0.2 }\nnormal = 1.0\n";
    let sphere = "[tissue]\nyoung = 1.0\n[[tool]]\nshape = \"sphere\"\nlaw = \"foundation\"\nradius = 0.3\nstart = [1.32, 0.5, 0.5]\nvelocity = [-0.02, 0.0, 0.0]\n";
    for (steps, want, push) in [(2, "rkl2", patch), (60, "implicit", patch), (60, "rkl2", sphere)] {
        let sc = d.path().join(format!("box{steps}{want}{}.toml", push.len()));
        std::fs::write(
            &sc,
            format!(
                "[mesh]\nfile = \"box.msh\"\n[material]\nconductivity = 2.0\n[model]\nreading = \"paper\"\n[[fixed]]\ngroup = \"xmin\"\n{push}[time]\nsteps = {steps}\n[output]\nevery = 1\n"
            ),
        )
        .unwrap();
        let sc = sc.to_str().unwrap();
        let (auto, named) = (
            d.path().join(format!("auto{steps}{want}{}.h5", push.len())),
            d.path().join(format!("{want}{steps}{}.h5", push.len())),
        );
        let out = common::serial(&["-vv", "run", sc, "-o", auto.to_str().unwrap()], 1);
        let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{text}");
        assert!(
            text.contains(&format!("integrator  {want}, ")) && text.contains("auto: "),
            "{steps} steps: {text}"
        );
        assert_eq!(
            text.matches("replayed from the automatic choice's trial").count(),
            steps.min(3),
            "{text}"
        );
        let set = format!("model.integrator={want}");
        let out = common::serial(&["run", sc, "-q", "--set", &set, "-o", named.to_str().unwrap()], 1);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let (fa, fb, names) = common::open_pair(&auto, &named);
        let fields: Vec<_> = names.iter().filter(|n| n.contains("PointData")).collect();
        assert!(fields.len() >= 3, "{names:?}");
        for name in fields {
            assert!(
                common::bits(&fa, name) == common::bits(&fb, name),
                "{steps} steps, {name} differs"
            );
        }
    }
}

/// `[time] equilibrium` stops on the steady equations, not on max |v| alone (docs/model.md
/// section 6): on an organ mesh in the paper's reading with a point load, every integrator's
/// stop state is within 1e-8 (relative, max norm of u) of euler's steady state.
#[test]
fn every_integrator_stops_at_the_steady_state_on_an_organ_mesh() {
    let Some(path) = common::shared_mesh("sofa_liver2.msh") else {
        return;
    };
    let mesh = eprop_io::read_mesh(&path).unwrap();
    // the SOFA liver (507 nodes) held at its left end, a point load on its right lobe
    let base = "[[fixed]]\nhalfspace = { point = [-0.9, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }\n[[load]]\nnearest = [0.94, 0.1, 0.33]\nforce = [-0.3, 0.2, -0.1]\n[time]\nsteps = 400000\n";
    let run = |kind: &str, tol: f64| {
        let mut s = sim(
            mesh.clone(),
            &format!("[model]\nreading = \"paper\"\nintegrator = \"{kind}\"\n{base}equilibrium = {tol:e}\n"),
        );
        while !s.done() {
            s.advance().unwrap();
        }
        let r = s.steady_residuals();
        eprintln!(
            "{kind} ({}): {} steps, max |v| = {:.3e}, residuals {r:?}",
            s.step_plan().integrator.name(),
            s.step(),
            s.max_speed()
        );
        assert!(
            r.is_some_and(|r| r.within(tol)),
            "{kind}: stopped at step {} off the steady state: {r:?}",
            s.step()
        );
        s.u().owned().to_vec()
    };
    let steady = run("euler", 1e-14);
    let scale = common::max_abs(&steady);
    for kind in ["auto", "implicit", "rkl2", "euler"] {
        let u = run(kind, 1e-11);
        let off = u
            .iter()
            .zip(&steady)
            .flat_map(|(a, b)| (0..3).map(move |d| (a[d] - b[d]).abs()))
            .fold(0.0f64, f64::max)
            / scale;
        eprintln!("{kind}: |u - u_steady| / |u_steady| = {off:.2e}");
        assert!(off < 1e-8, "{kind}: the stop state is {off:.2e} from the steady state");
    }
}
