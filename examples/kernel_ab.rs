//! Interleaved A/B timing of the `compact` substep variants on one mesh, so that the noise of
//! a shared machine falls on every variant alike: bursts of substeps, variants taken in turn,
//! min and median ns per node-substep per variant, and each variant's median relative to the
//! first ("morton 1/sweep": the substep as it was before temporal blocking).
//!   cargo run --release --example kernel_ab -- CELLS|SCENARIO.toml SECONDS [compact|compact32] [VARIANTS]
//! CELLS: the bench box of CELLS^3 cells; SCENARIO.toml: any scenario (an organ mesh).
//! Variants: node order (Morton: the space-filling curve; RCM: reverse Cuthill-McKee, see
//! `eprop_partition::rcm_keys`), coefficient precision, substeps per fused sweep
//! (`Propagation::substeps`; 1 = one sweep per substep), the vector kernel or the portable one
//! ("portable").
//! VARIANTS: names as printed, comma-separated (default: all).
use eprop::config::Fuse;
use eprop::discretize::operator::{Compact, Kernel, Operator};
use eprop::distribute::halo::Halo;
use eprop::propagate::Propagation;
use eprop_partition::Layout;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let what = a.get(1).cloned().unwrap_or("66".into());
    let secs: f64 = a.get(2).map(|s| s.parse()).transpose()?.unwrap_or(20.0);
    let scheme = a.get(3).cloned().unwrap_or("compact".into());
    // optional: the variants to time, by name, comma-separated (default: all)
    let only: Option<Vec<String>> = a.get(4).map(|s| s.split(',').map(|v| v.trim().to_string()).collect());
    let setup = match what.parse::<usize>() {
        Ok(cells) => eprop::config::Setup::bench_box(cells, &scheme)?,
        Err(_) => eprop::config::Setup::new(eprop::config::Scenario::load(std::path::Path::new(&what))?)?,
    };
    let sim = eprop::simulate::Simulation::new(setup)?;
    let n = sim.n_owned();
    let h = sim.step_plan().h;
    let Operator::Compact(base) = &sim.prop().op else {
        anyhow::bail!("kernel_ab times the compact scheme");
    };
    // the orders of the whole mesh restricted to this process's nodes, as `Plan::new` makes
    // them, relative to the simulation's own order
    let mesh = sim.global_mesh().expect("a serial simulation keeps its mesh");
    let (xadj, adj) = eprop_partition::node_graph(mesh.n_nodes(), &mesh.offsets, &mesh.conn);
    let t = Instant::now();
    let key = eprop_partition::rcm_keys(&xadj, &adj);
    let t_rcm = t.elapsed().as_secs_f64();
    let perm = |key: &[u64]| {
        let mut by_key: Vec<u32> = (0..n as u32).collect();
        by_key.sort_by_key(|&l| key[sim.gid()[l as usize] as usize]);
        let mut new_of = vec![0u32; n];
        for (r, &l) in by_key.iter().enumerate() {
            new_of[l as usize] = r as u32;
        }
        new_of
    };
    let mnew_of = perm(&eprop_partition::morton_keys(&mesh.points));
    let new_of = perm(&key);
    let morton = &base.permuted(&mnew_of);
    let rcm = base.permuted(&new_of);
    println!(
        "{n} nodes, {scheme}, {} substeps per mechanics step; bandwidth Morton {} RCM {} (RCM order {t_rcm:.2} s)",
        sim.step_plan().per_step,
        band(morton),
        band(&rcm)
    );
    print_shape(&rcm);
    let prop = |c: Compact| Propagation::new(Operator::Compact(c), Halo::serial(), Layout::serial(n), Fuse::Auto);
    let id: Vec<u32> = (0..n as u32).collect();
    let f64_coef = !morton.is_f32();
    // (name, order: 0 Morton 1 RCM, float32 coefficients, substeps per sweep (0: chosen by
    // the tuner, as in a run), the vector kernel (where the CPU has it)
    let mut spec: Vec<(&str, u8, bool, usize, bool)> = vec![
        ("morton 1/sweep", 0, false, 1, true),
        ("rcm 1/sweep", 1, false, 1, true),
        ("morton 4/sweep", 0, false, 4, true),
        ("rcm 2/sweep", 1, false, 2, true),
        ("rcm 3/sweep", 1, false, 3, true),
        ("rcm 4/sweep", 1, false, 4, true),
        ("rcm 8/sweep", 1, false, 8, true),
        ("rcm auto", 1, false, 0, true),
        ("rcm 4/sweep portable", 1, false, 4, false),
    ];
    if f64_coef {
        spec.push(("rcm f32 4/sweep", 1, true, 4, true));
    }
    if let Some(only) = &only {
        spec.retain(|v| only.iter().any(|o| o == v.0));
        anyhow::ensure!(!spec.is_empty(), "no variant named {only:?}");
    }
    let mut props: Vec<(String, Propagation, u8)> = spec
        .iter()
        .map(|&(name, order, single, fuse, vector)| {
            let mut c = if order == 0 {
                morton.permuted(&id)
            } else {
                rcm.permuted(&id)
            };
            if single {
                c = c.into_f32();
            }
            c.set_kernel(Kernel {
                vector: c.kernel().vector && vector,
            });
            let mut p = prop(c);
            if fuse > 0 {
                p.set_fuse(fuse); // 0: chosen by the tuner, as in a run
            }
            // the same O(1) field on every variant (no subnormal values, which would time the
            // floating-point assists instead of the kernel), by node
            for l in 0..n {
                let g = sim.gid()[l] as f64;
                let at = if order == 0 { mnew_of[l] } else { new_of[l] } as usize;
                p.phi[at] = [(0.37 * g).sin(), (0.11 * g).cos(), 1.0 + 1.0 / (1.0 + g)];
            }
            p.wavefront();
            (name.to_string(), p, order)
        })
        .collect();
    drop(rcm);
    // one source on the same node in every variant
    let q_of = |order: u8| {
        let at = if order == 0 { mnew_of[0] } else { new_of[0] };
        vec![(at, [1.0, 0.0, 0.0])]
    };
    let mut times: Vec<Vec<f64>> = vec![vec![]; props.len()];
    let burst = ((2e7 / n as f64).ceil() as usize).div_ceil(8) * 8; // about 0.4 s, a multiple of 8
    let t0 = Instant::now();
    while t0.elapsed().as_secs_f64() < secs {
        for (v, (_, p, order)) in props.iter_mut().enumerate() {
            let q = q_of(*order);
            p.substeps(h, &q, 8);
            let t = Instant::now();
            p.substeps(h, &q, burst);
            times[v].push(t.elapsed().as_secs_f64() / burst as f64 / n as f64 * 1e9);
        }
    }
    println!("{} rounds of {burst} substeps", times[0].len());
    let med = |v: &Vec<f64>| {
        let mut t = v.clone();
        t.sort_by(f64::total_cmp);
        (t[0], t[t.len() / 2])
    };
    let base = med(&times[0]).1;
    for (v, (name, p, _)) in props.iter_mut().enumerate() {
        let (lo, mid) = med(&times[v]);
        let lag = p.wavefront().map(|w| w.lag()).unwrap_or(0);
        println!(
            "{name:>18}  min {lo:6.2}  median {mid:6.2} ns/node-substep  speed x{:5.2}  (level lag {lag} rows, {} substeps per sweep)",
            base / mid,
            p.fuse()
        );
    }
    Ok(())
}

/// The largest distance between a row and a neighbour's index.
fn band(c: &Compact) -> usize {
    let n = c.row_ptr().len() - 1;
    (0..n)
        .flat_map(|i| {
            c.col()[c.coefficients().row(i)]
                .iter()
                .map(move |&j| i.abs_diff(j as usize))
        })
        .max()
        .unwrap_or(0)
}

/// Pairs per row, empty rows and the lags of a fused sweep's second level in the order of `rcm`.
fn print_shape(rcm: &Compact) {
    let n = rcm.row_ptr().len() - 1;
    let w = eprop::propagate::wavefront::Wavefront::new(rcm, Layout::serial(n), 2);
    let mut lags: Vec<u32> = w.deep[1].iter().map(|s| s.need - s.start).collect();
    lags.sort_unstable();
    let empty = (0..n).filter(|&i| rcm.coefficients().row(i).is_empty()).count();
    println!(
        "pairs per row {:.2}, empty rows {empty}, segment lag (RCM) median {} p90 {} max {}",
        rcm.col().len() as f64 / n as f64,
        lags[lags.len() / 2],
        lags[lags.len() * 9 / 10],
        lags[lags.len() - 1]
    );
}
