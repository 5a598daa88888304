//! Restoring mechanics: the equilibrium it must reach, and the paper's damping study.

mod common;

use common::sim;
use eprop_io::generate::cylinder_mesh;
use eprop_io::geom::norm;

#[test]
fn equilibrium_is_force_plus_pushed_potential_over_stiffness() {
    for (k, kappa, p) in [(1.0, 1.0, 1.0), (2.0, 0.5, 2.0), (0.5, 3.0, 0.5)] {
        let toml = format!(
            "[model]\nreading = \"paper\"\nstiffness = {k}\ncoupling = {kappa}\nexponent = {p}\n[[fixed]]\ngroup = \"bottom\"\n\
             [[load]]\nnearest = [1.0, 0.0, 2.0]\nforce = [-0.5, 0.2, 0.1]\n[time]\nequilibrium = 1e-12\nsteps = 200000\n"
        );
        let mut s = sim(cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), &toml);
        while !s.done() {
            s.advance().unwrap();
        }
        assert!(s.max_speed() < 1e-12, "no equilibrium after {} steps", s.step());
        let c = s.local(s.loads()[0].nodes[0]).unwrap();
        let scale = norm(s.u()[c]);
        for i in 0..s.u().len() {
            if !s.active()[i] {
                assert_eq!(s.u()[i], [0.0; 3]);
                continue;
            }
            let ph = s.phi()[i];
            let m = norm(ph);
            let push = if m > 0.0 { kappa * m.powf(p - 1.0) } else { 0.0 };
            let f = if i == c { [-0.5, 0.2, 0.1] } else { [0.0; 3] };
            for d in 0..3 {
                let want = (f[d] + push * ph[d]) / k;
                assert!(
                    (s.u()[i][d] - want).abs() < 1e-9 * scale,
                    "k={k} kappa={kappa} p={p} node {i}: u = {} want {want}",
                    s.u()[i][d]
                );
            }
        }
    }
}

/// Contact displacement after 20 steps with the paper's literal reading (k_e = 0).
fn contact_after_20(force: f64, damping: f64) -> f64 {
    let toml = format!(
        "[material]\ndamping = {damping}\n[model]\nreading = \"paper\"\nstiffness = 0.0\nexponent = 1.0\n[tissue]\nbeta = 0.0\n\
         [[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = {force}\n[time]\nsteps = 20\ndt = 0.1\n"
    );
    let mut s = sim(cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), &toml);
    while !s.done() {
        s.advance().unwrap();
    }
    norm(s.u()[s.local(s.loads()[0].nodes[0]).unwrap()])
}

#[test]
fn paper_figure_5_nonlinear_in_force_and_falling_with_damping() {
    let forces = [5.0, 10.0, 20.0, 40.0];
    for g in [1.0, 4.0, 6.0] {
        let u: Vec<f64> = forces.iter().map(|&f| contact_after_20(f, g)).collect();
        for w in 0..forces.len() - 1 {
            // displacement per unit force grows with force: faster than linear
            assert!(
                u[w + 1] / forces[w + 1] > u[w] / forces[w] * 1.001,
                "g = {g}: {u:?} is not superlinear"
            );
        }
    }
    for &f in &forces {
        let (u1, u4, u6) = (
            contact_after_20(f, 1.0),
            contact_after_20(f, 4.0),
            contact_after_20(f, 6.0),
        );
        assert!(
            u1 > u4 && u4 > u6,
            "F = {f}: displacement must fall with damping: {u1} {u4} {u6}"
        );
    }
}

#[test]
fn exponential_tissue_law_stores_less_energy_than_linear_at_the_same_stress() {
    use eprop::config::tissue::TissueLaw;
    let lin = TissueLaw {
        young: 100.0,
        beta: 0.0,
    };
    let exp = TissueLaw {
        young: 100.0,
        beta: 5.0,
    };
    for sigma in [0.1, 1.0, 10.0, 100.0] {
        let (ql, qe) = (lin.energy_density(sigma), exp.energy_density(sigma));
        assert!(qe < ql && qe > 0.0);
        // q = integral of sigma d eps, checked by quadrature of the strain
        let n = 20000;
        let mut q = 0.0;
        for k in 0..n {
            let (s0, s1) = (sigma * k as f64 / n as f64, sigma * (k + 1) as f64 / n as f64);
            q += 0.5 * (s0 + s1) * (exp.strain(s1) - exp.strain(s0));
        }
        assert!((q - qe).abs() < 1e-6 * qe, "sigma {sigma}: {q} vs {qe}");
    }
    // tiny beta tends to the linear law
    let near = TissueLaw {
        young: 100.0,
        beta: 1e-9,
    };
    assert!((near.energy_density(3.0) - lin.energy_density(3.0)).abs() < 1e-9);
}
