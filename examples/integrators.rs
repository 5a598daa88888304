//! Time per mechanics step and accuracy of every integrator on one scenario, steps taken in
//! turn (euler, rkl2, implicit with Jacobi, with multigrid and with AMG, one step each, then again), so
//! the noise of a shared machine falls on all alike. Under mpirun every rank takes part.
//!
//!   cargo run --release --example integrators -- SCENARIO STEPS EULER_STEPS [REFERENCE]
//!
//! euler runs EULER_STEPS steps only (it is slow); the others STEPS. REFERENCE: a file of u
//! after STEPS steps of euler (f64, little-endian, input node order); when EULER_STEPS equals
//! STEPS the run writes it, otherwise it reads it and prints the relative L2 error of u.
use eprop::config::integrator::{Kind, Preconditioner};
use eprop::distribute::comm::Comm;
use eprop::distribute::launch::{launch, start_alone};
use eprop::simulate::Simulation;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    // on one process or on every process of an MPI job
    launch(compare)
}

fn compare(world: Option<&dyn Comm>) -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let path = std::path::PathBuf::from(&a[1]);
    let steps: usize = a[2].parse()?;
    let euler_steps: usize = a[3].parse()?;
    let reference = a.get(4).map(std::path::PathBuf::from);
    if world.is_none() {
        start_alone()?; // hypre (amg) takes an MPI communicator
    }
    let variants = [
        ("euler", Kind::Euler, Preconditioner::Jacobi),
        ("rkl2", Kind::Rkl2, Preconditioner::Jacobi),
        ("implicit jacobi", Kind::Implicit, Preconditioner::Jacobi),
        ("implicit multigrid", Kind::Implicit, Preconditioner::Multigrid),
        ("implicit amg", Kind::Implicit, Preconditioner::Amg),
    ];
    let mut sims: Vec<Simulation> = vec![];
    for (_, kind, pre) in &variants {
        let make = || -> anyhow::Result<eprop::config::Setup> {
            let sets = [
                format!("model.integrator={}", kind.name()),
                format!("integrator.preconditioner={}", pre.name()),
            ];
            eprop::config::Setup::new(eprop::config::Scenario::load_with(&path, &sets)?)
        };
        let sim = match world {
            Some(w) => eprop::simulate::distributed::build_mpi(w, make)?.sim,
            None => Simulation::new(make()?)?,
        };
        sims.push(sim);
    }
    let root = sims[0].comm().rank() == 0;
    let mut times: Vec<Vec<f64>> = vec![vec![]; variants.len()];
    let mut apps: Vec<Vec<usize>> = vec![vec![]; variants.len()];
    for step in 0..steps {
        for (k, sim) in sims.iter_mut().enumerate() {
            if k == 0 && step >= euler_steps {
                continue;
            }
            sim.comm().max(0.0); // line the processes up
            let t = Instant::now();
            let st = sim.advance()?;
            let dt = sim.comm().max(t.elapsed().as_secs_f64());
            times[k].push(dt);
            apps[k].push(st.applications);
        }
        if root {
            eprintln!("step {} done", step + 1);
        }
    }
    // accuracy: u after `steps` steps against euler's
    let errors: Vec<Option<f64>> = match &reference {
        Some(r) if euler_steps == steps => {
            let sim = &sims[0];
            let mine = sim.in_output_order(sim.u());
            let all = sim.comm().all_gather(&mine);
            if root {
                let bytes: Vec<u8> = all.iter().flat_map(|x| x.to_le_bytes()).collect();
                std::fs::write(r, bytes)?;
                println!("wrote the euler reference {}", r.display());
            }
            vec![None; variants.len()]
        }
        Some(r) => {
            let bytes = std::fs::read(r)?;
            let want: Vec<f64> = bytes
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
                .collect();
            sims.iter()
                .enumerate()
                .map(|(k, sim)| {
                    if k == 0 {
                        return None;
                    }
                    let mine = sim.in_output_order(sim.u());
                    let w = &want[3 * sim.blocks().start..3 * (sim.blocks().start + sim.blocks().len)];
                    let c = sim.comm();
                    let d = eprop::distribute::comm::reproducible_sum(
                        c,
                        mine.iter().zip(w).map(|(a, b)| (a - b) * (a - b)),
                    );
                    let n = eprop::distribute::comm::reproducible_sum(c, w.iter().map(|b| b * b));
                    Some((d / n).sqrt())
                })
                .collect()
        }
        None => vec![None; variants.len()],
    };
    if root {
        let med = |v: &[f64]| {
            let mut v = v.to_vec();
            v.sort_by(f64::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
        };
        let euler = med(&times[0]);
        println!(
            "{} processes, {} nodes; euler {} substeps per step",
            sims[0].comm().size(),
            sims[0].n_global(),
            sims[0].step_plan().per_step
        );
        println!(
            "{:<18} {:>10} {:>12} {:>12} {:>10} {:>12}",
            "integrator", "apps/step", "s/step med", "s/step min", "vs euler", "rel err u"
        );
        for (k, (name, _, _)) in variants.iter().enumerate() {
            let mut a = apps[k].clone();
            a.sort_unstable();
            let t = med(&times[k]);
            let tmin = times[k].iter().copied().fold(f64::INFINITY, f64::min);
            println!(
                "{:<18} {:>10} {:>12.4} {:>12.4} {:>9.1}x {:>12}",
                name,
                a.get(a.len() / 2).copied().unwrap_or(0),
                t,
                tmin,
                euler / t,
                errors[k].map(|e| format!("{e:.2e}")).unwrap_or("-".into())
            );
        }
    }
    Ok(())
}
