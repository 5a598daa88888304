//! Interleaved A/B timing of the `compact` kernels on one generated box, so that the noise of
//! a shared machine falls on every variant alike: bursts of substeps, variants taken in turn,
//! min and median ns per node-substep per variant.
//!   cargo run --release --example kernel_ab -- CELLS SECONDS [compact|compact32]
use eprop::operator::{Kernel, Operator};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let cells: usize = a.get(1).map(|s| s.parse()).transpose()?.unwrap_or(66);
    let secs: f64 = a.get(2).map(|s| s.parse()).transpose()?.unwrap_or(20.0);
    let scheme = a.get(3).cloned().unwrap_or("compact".into());
    let setup = eprop::bench::box_setup(cells, &scheme)?;
    let mut sim = eprop::solver::Simulation::new(setup)?;
    let n = sim.n_owned();
    let variants: Vec<(String, Kernel)> = vec![
        (
            "portable".into(),
            Kernel {
                vector: false,
                prefetch: 0,
            },
        ),
        (
            "vector".into(),
            Kernel {
                vector: true,
                prefetch: 0,
            },
        ),
        (
            "vector+pf192".into(),
            Kernel {
                vector: true,
                prefetch: 192,
            },
        ),
        (
            "vector+pf384".into(),
            Kernel {
                vector: true,
                prefetch: 384,
            },
        ),
        (
            "vector+pf96".into(),
            Kernel {
                vector: true,
                prefetch: 96,
            },
        ),
    ];
    let q = vec![(0u32, [1.0, 0.0, 0.0])];
    let h = sim.step_plan().h;
    let mut times: Vec<Vec<f64>> = vec![vec![]; variants.len()];
    let burst = (2e7 / n as f64).ceil() as usize; // about 0.4 s
    let t0 = Instant::now();
    while t0.elapsed().as_secs_f64() < secs {
        for (v, (_, k)) in variants.iter().enumerate() {
            if let Operator::Compact(c) = &mut sim.prop.op {
                c.kernel = *k;
            }
            sim.prop.substep_serial(h, &q);
            let t = Instant::now();
            for _ in 0..burst {
                sim.prop.substep_serial(h, &q);
            }
            times[v].push(t.elapsed().as_secs_f64() / burst as f64 / n as f64 * 1e9);
        }
    }
    println!("{n} nodes, {scheme}, {} rounds", times[0].len());
    for (v, (name, _)) in variants.iter().enumerate() {
        let mut t = times[v].clone();
        t.sort_by(f64::total_cmp);
        println!(
            "{name:>14}  min {:6.2}  median {:6.2} ns/node-substep",
            t[0],
            t[t.len() / 2]
        );
    }
    Ok(())
}
