//! Timing of the multigrid preconditioner against the operator application it replaces
//! iterations of, on a scenario's mesh and mechanics step: ms per V-cycle (three components),
//! per operator application, and the hierarchy's sizes. Median of interleaved repetitions.
//!   cargo run --release --example multigrid -- SCENARIO [SECONDS]
use eprop::linalg::multigrid::Multigrid;
use eprop::linalg::Precond;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let path = std::path::PathBuf::from(&a[1]);
    let secs: f64 = a.get(2).map(|s| s.parse()).transpose()?.unwrap_or(10.0);
    let setup = eprop::config::Setup::new(eprop::config::Scenario::load(&path)?)?;
    let sim = eprop::simulate::Simulation::new(setup)?;
    let n = sim.n_owned();
    let layout = sim.prop().layout();
    let vol: Vec<f64> = (0..n)
        .map(|i| if sim.active()[i] { sim.volumes()[i] } else { 0.0 })
        .collect();
    let tt = eprop::propagate::integrate::implicit::THETA * sim.dt();
    let t = Instant::now();
    let mut mg = Multigrid::new(sim.prop(), &vol, sim.gid(), tt, &eprop::distribute::comm::Serial)?;
    let mut prop = sim.into_propagation();
    let setup_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    mg.set_coefficient(tt)?;
    let recombine_s = t.elapsed().as_secs_f64();
    let r: Vec<[f64; 3]> = (0..n)
        .map(|i| [(i as f64).sin(), (2.0 * i as f64).cos(), 1.0])
        .collect();
    let mut z = vec![[0.0; 3]; n];
    let mut x = eprop::distribute::field::NodeField::filled(layout, [1.0, 2.0, 3.0]);
    let mut y = vec![[0.0; 3]; n];
    let (mut tc, mut ta) = (vec![], vec![]);
    let t0 = Instant::now();
    while t0.elapsed().as_secs_f64() < secs {
        let t = Instant::now();
        mg.apply(&mut prop, &r, &mut z);
        tc.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        prop.apply_to(&mut x, &mut y);
        ta.push(t.elapsed().as_secs_f64());
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2] * 1e3
    };
    let (c, ap) = (med(&mut tc), med(&mut ta));
    println!(
        "{{\"nodes\": {n}, \"levels\": {:?}, \"complexity\": {:.3}, \"cycle_work\": {:.2}, \"setup_s\": {setup_s:.3}, \"recombine_s\": {recombine_s:.3}, \"cycle_ms\": {c:.3}, \"apply_ms\": {ap:.3}, \"cycle_over_apply\": {:.2}}}",
        mg.sizes(),
        mg.complexity(),
        mg.cycle_work(),
        c / ap
    );
    Ok(())
}
