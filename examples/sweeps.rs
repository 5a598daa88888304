//! Interleaved timing of the sweeps integrators are made of, on a scenario's mesh: a forward
//! Euler substep, an RKL2 stage, an operator application, one conjugate-gradient iteration's
//! exact dot products. Min and median ms per sweep.
//!   cargo run --release --example sweeps -- SCENARIO [SECONDS]
use eprop::propagate::integrate::Stepper;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let path = std::path::PathBuf::from(&a[1]);
    let secs: f64 = a.get(2).map(|s| s.parse()).transpose()?.unwrap_or(20.0);
    let setup = eprop::config::Setup::new(eprop::config::Scenario::load(&path)?)?;
    let sim = eprop::simulate::Simulation::new(setup)?;
    let n = sim.n_owned();
    let layout = sim.prop().layout();
    let q = vec![(0u32, [1.0, 0.0, 0.0])];
    let h = 1e-5;
    let mut x = eprop::distribute::field::NodeField::filled(layout, [1.0, 2.0, 3.0]);
    let mut y = vec![[0.0; 3]; layout.n_local];
    let z = vec![[0.5; 3]; layout.n_local];
    let m = vec![[0.25; 3]; layout.n_local];
    let names = [
        "euler substep",
        "apply_to",
        "update_to rkl2",
        "exact dots 6",
        "rkl2 step/stage",
        "implicit step/app",
    ];
    let mut times: Vec<Vec<f64>> = vec![vec![]; names.len()];
    let mut rk = eprop::propagate::integrate::Rkl2::new(1e-5, 1e-3, 1, 100000, layout, "x", String::new())?;
    let stages = rk.plan().per_step;
    let settings = eprop::config::integrator::Settings::default();
    let active: Vec<bool> = (0..layout.n_local)
        .map(|i| sim.volumes()[i] > 0.0 && !sim.setup().fixed[i])
        .collect();
    let mut imp = eprop::propagate::integrate::Implicit::new(
        sim.prop(),
        sim.volumes(),
        &active,
        sim.gid(),
        0.5,
        1e-5,
        &settings,
        "x",
        sim.comm(),
    )?;
    // one process (`Simulation::new`): its collectives are the serial ones
    let comm = &eprop::distribute::comm::Serial;
    let mut prop = sim.into_propagation();
    let q2: Vec<(u32, [f64; 3])> = (0..n as u32).step_by(97).map(|i| (i, [1.0, 0.5, 0.25])).collect();
    let t0 = Instant::now();
    while t0.elapsed().as_secs_f64() < secs {
        for v in 0..names.len() {
            let reps = if v >= 4 { 1 } else { 10 };
            let mut apps = stages;
            let t = Instant::now();
            for _ in 0..reps {
                match v {
                    0 => prop.substep(h, &q),
                    1 => prop.apply_to(&mut x, &mut y),
                    2 => {
                        let (zr, mr) = (&z[..], &m[..]);
                        prop.update_to(&mut x, &mut y, |i, xi, l, yi| {
                            for d in 0..3 {
                                yi[d] = 0.3 * xi[d] + 0.2 * yi[d] + 0.5 * zr[i][d] + 1e-6 * l[d] + 1e-7 * mr[i][d];
                            }
                        })
                    }
                    3 => {
                        let (yr, zr) = (&y[..], &z[..]);
                        let s: [f64; 6] = eprop::distribute::comm::reproducible_sums_par(comm, n, |i| {
                            let (a, b, c) = (yr[i], zr[i], x[i]);
                            [
                                a[0] * b[0],
                                a[1] * b[1],
                                a[2] * b[2],
                                c[0] * b[0],
                                c[1] * b[1],
                                c[2] * b[2],
                            ]
                        });
                        std::hint::black_box(s);
                    }
                    4 => {
                        rk.advance(&mut prop, &q, comm)?;
                    }
                    _ => {
                        apps = imp.advance(&mut prop, &q2, comm)?.applications;
                    }
                }
            }
            let per = t.elapsed().as_secs_f64() / reps as f64 * 1e3 / if v >= 4 { apps as f64 } else { 1.0 };
            times[v].push(per);
        }
    }
    for (name, t) in names.iter().zip(times.iter_mut()) {
        t.sort_by(f64::total_cmp);
        println!(
            "{name:<18} min {:.3} ms  median {:.3} ms  ({} samples)",
            t[0],
            t[t.len() / 2],
            t.len()
        );
    }
    println!("{n} nodes, rkl2 {stages} stages");
    Ok(())
}
