//! The multigrid preconditioner of the implicit solves (docs/integrators.md): the same
//! solution as Jacobi-preconditioned conjugate gradients, iterations that do not grow with the
//! resolution, a symmetric V-cycle, and coefficients recombined exactly.

mod common;

use common::sim;
use eprop::config::integrator::{Preconditioner, Settings};
use eprop::distribute::comm::Serial;
use eprop::linalg::multigrid::Multigrid;
use eprop::linalg::Precond;
use eprop::linalg::V3;
use eprop::propagate::integrate::implicit::THETA;
use eprop::propagate::integrate::{Implicit, Stepper};
use eprop::simulate::Simulation;
use eprop_io::generate::{box_mesh, BoxCells};

/// The box: fixed on one face, a patch load on the opposite one.
const BOX: &str = "[material]\nconductivity = 0.05\n[[fixed]]\ngroup = \"xmin\"\n[[load]]\npatch = { center = [1.0, 0.5, 0.5], radius = 0.2 }\nnormal = 1.0\n[time]\nsteps = 1\n";

fn box_sim(n: usize) -> Simulation {
    sim(box_mesh([1.0; 3], [n, n, n], BoxCells::Tet).unwrap(), BOX)
}

fn implicit(s: &Simulation, pre: Preconditioner, tolerance: f64) -> Implicit {
    let settings = Settings {
        tolerance,
        preconditioner: pre,
        ..Settings::default()
    };
    let hb = s.step_plan().h_bound;
    Implicit::new(
        s.prop(),
        s.volumes(),
        s.active(),
        s.gid(),
        s.dt(),
        hb,
        &settings,
        "t",
        &Serial,
    )
    .unwrap()
}

/// Free-row volumes as the implicit stepper takes them.
fn volumes(s: &Simulation) -> Vec<f64> {
    (0..s.n_owned())
        .map(|i| if s.active()[i] { s.volumes()[i] } else { 0.0 })
        .collect()
}

fn pseudo_random(n: usize, seed: u64) -> Vec<V3> {
    let mut x = seed.wrapping_mul(0x9E3779B97F4A7C15) | 1;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    (0..n).map(|_| [next(), next(), next()]).collect()
}

fn dot(a: &[V3], b: &[V3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| x[0] * y[0] + x[1] * y[1] + x[2] * y[2])
        .sum()
}

#[test]
fn multigrid_cg_reaches_the_jacobi_cg_solution() {
    let s = box_sim(20);
    let n = s.n_owned();
    // a step of TR-BDF2 from a rough potential with sources on a few nodes
    let phi0 = pseudo_random(n, 7);
    let q: Vec<(u32, V3)> = (0..n as u32)
        .filter(|&i| s.active()[i as usize])
        .step_by(37)
        .map(|i| (i, [1.0, -0.5, 0.25]))
        .collect();
    let mut results = vec![];
    let steppers = [Preconditioner::Jacobi, Preconditioner::Multigrid].map(|pre| implicit(&s, pre, 1e-11));
    let active = s.active().to_vec();
    let mut prop = s.into_propagation();
    for mut st in steppers {
        for i in 0..n {
            prop.phi[i] = if active[i] { phi0[i] } else { [0.0; 3] };
        }
        st.advance(&mut prop, &q, &Serial).unwrap();
        results.push((prop.phi.owned().to_vec(), st.last.iterations));
    }
    let (a, b) = (&results[0].0, &results[1].0);
    let diff: Vec<V3> = a
        .iter()
        .zip(b)
        .map(|(x, y)| [x[0] - y[0], x[1] - y[1], x[2] - y[2]])
        .collect();
    let rel = (dot(&diff, &diff) / dot(a, a)).sqrt();
    assert!(rel < 1e-9, "relative difference {rel:e}");
    // and with far fewer iterations
    let (j, m) = (results[0].1, results[1].1);
    assert!(m[0] * 5 < j[0] && m[1] * 5 < j[1], "jacobi {j:?}, multigrid {m:?}");
}

#[test]
fn multigrid_iterations_do_not_grow_with_the_resolution() {
    let mut its = vec![];
    for n in [10, 20, 30] {
        let s = box_sim(n);
        let mut st = implicit(&s, Preconditioner::Multigrid, 1e-8);
        let gid = s.gid().to_vec();
        its.push(st.trial(&mut s.into_propagation(), &gid, &Serial).unwrap());
    }
    let (lo, hi) = (its.iter().min().unwrap(), its.iter().max().unwrap());
    assert!(
        *lo >= 1 && *hi * 2 <= *lo * 3,
        "iterations on 10^3, 20^3, 30^3: {its:?}"
    );
}

#[test]
fn the_v_cycle_is_symmetric_and_positive() {
    let s = box_sim(16);
    let n = s.n_owned();
    let vol = volumes(&s);
    let mut mg = Multigrid::new(s.prop(), &vol, s.gid(), THETA * s.dt(), &Serial).unwrap();
    let mut prop = s.into_propagation();
    assert!(mg.sizes().len() >= 2, "{:?}", mg.sizes());
    let mask = |v: Vec<V3>| -> Vec<V3> {
        v.into_iter()
            .zip(&vol)
            .map(|(x, &w)| if w > 0.0 { x } else { [0.0; 3] })
            .collect()
    };
    for seed in 1..4 {
        let (x, y) = (mask(pseudo_random(n, seed)), mask(pseudo_random(n, seed + 100)));
        let (mut mx, mut my) = (vec![[0.0; 3]; n], vec![[0.0; 3]; n]);
        mg.apply(&mut prop, &x, &mut mx);
        mg.apply(&mut prop, &y, &mut my);
        let (a, b) = (dot(&x, &my), dot(&y, &mx));
        let scale = (dot(&x, &x) * dot(&my, &my)).sqrt();
        assert!((a - b).abs() <= 1e-12 * scale, "x.My {a:e} y.Mx {b:e}");
        assert!(dot(&x, &mx) > 0.0);
        // applying twice gives the same bits
        let mut again = vec![[0.0; 3]; n];
        mg.apply(&mut prop, &x, &mut again);
        assert_eq!(again, mx);
    }
}

#[test]
fn a_new_coefficient_recombines_to_the_hierarchy_built_for_it() {
    let s = box_sim(12);
    let n = s.n_owned();
    let vol = volumes(&s);
    let (c1, c2) = (THETA * s.dt(), 0.3 * THETA * s.dt());
    let mut a = Multigrid::new(s.prop(), &vol, s.gid(), c1, &Serial).unwrap();
    a.set_coefficient(c2).unwrap();
    let mut b = Multigrid::new(s.prop(), &vol, s.gid(), c2, &Serial).unwrap();
    let mut prop = s.into_propagation();
    assert_eq!(a.coefficient(), c2);
    let x = pseudo_random(n, 3);
    let (mut za, mut zb) = (vec![[0.0; 3]; n], vec![[0.0; 3]; n]);
    a.apply(&mut prop, &x, &mut za);
    b.apply(&mut prop, &x, &mut zb);
    assert_eq!(za, zb);
}

#[test]
fn the_automatic_preconditioner_takes_multigrid_only_where_jacobi_iterates_long() {
    // the box at its automatic dt: jacobi iterates long, multigrid takes over
    let s = box_sim(20);
    let mut st = implicit(&s, Preconditioner::Auto, 1e-8);
    let gid = s.gid().to_vec();
    let it = st.trial(&mut s.into_propagation(), &gid, &Serial).unwrap();
    assert_eq!(
        st.preconditioner_name(),
        "multigrid",
        "{}",
        st.preconditioner_phrase(it)
    );
    assert!(st.preconditioner_phrase(it).contains("against jacobi's"));
    // a conductivity 100 times smaller: few jacobi iterations, multigrid not worth its cycle
    let weak = BOX.replace("conductivity = 0.05", "conductivity = 0.0005");
    let s = sim(box_mesh([1.0; 3], [20, 20, 20], BoxCells::Tet).unwrap(), &weak);
    let mut st = implicit(&s, Preconditioner::Auto, 1e-8);
    let gid = s.gid().to_vec();
    let it = st.trial(&mut s.into_propagation(), &gid, &Serial).unwrap();
    assert_eq!(st.preconditioner_name(), "jacobi", "{}", st.preconditioner_phrase(it));
    assert!(it < eprop::propagate::integrate::solver::MULTIGRID_FROM);
}
