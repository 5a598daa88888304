//! `eprop bench`: the speed of the propagation kernel against the memory bandwidth of the
//! same machine, measured in the same process.
//!
//! For each generated mesh and scheme: node-substeps per second of the explicit substep (the
//! kernel, halo exchange included), the bytes a substep must move at least (operator arrays
//! plus the potential read and written once), the bandwidth that implies, and its fraction of
//! a STREAM-like triad measured here; full steps per second with one substep per step (the
//! haptic configuration: dt = h); peak memory per node; halo waiting share; output cost.

use anyhow::Result;
use eprop::config::{Field, Performance, Setup};
use eprop::diagnostics::{median, peak_rss};
use eprop::distribute::comm::{Comm, Handle};
use eprop::distribute::parts::GlobalSizes;
use eprop::output::series::{field_blocks, layout, VERSION};
use eprop::simulate::distributed::{build_mpi, Built};
use eprop::simulate::Simulation;
use eprop_series::vtkhdf::{SeriesSpec, SeriesWriter};
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// One measured case.
#[derive(Serialize, Debug, Clone)]
pub struct Case {
    pub mesh: String,
    pub nodes: usize,
    pub cells: usize,
    pub scheme: String,
    pub processes: usize,
    pub threads: usize,
    pub substeps_timed: usize,
    pub seconds_per_substep: f64,
    /// Node-substeps per second as the Euler stepper runs them (`substeps_per_sweep` fused).
    pub node_substeps_per_second: f64,
    /// Substeps per fused sweep (1: none) in `node_substeps_per_second`.
    pub substeps_per_sweep: usize,
    /// Node-substeps per second with one substep per sweep (one substep per mechanics step).
    pub single_node_substeps_per_second: f64,
    /// Bytes per node that one substep streams at least (whole mesh / nodes) with one substep
    /// per sweep; GB/s and the fraction of the triad count these bytes per substep, so a fused
    /// sweep can exceed the triad.
    pub bytes_per_node_substep: f64,
    pub achieved_gb_per_s: f64,
    pub triad_gb_per_s: f64,
    pub fraction_of_triad: f64,
    /// Full steps (one substep + mechanics) per second.
    pub full_steps_per_second: f64,
    /// Share of the substep time spent waiting for halos (largest process).
    pub halo_wait_share: f64,
    /// Seconds to append one output step (all fields, float64) and commit it (flushed and
    /// synced to the disk, as `[output] flush = 0` does).
    pub output_seconds_per_step: f64,
    /// Peak resident memory (largest process) and per node (sum over processes / nodes).
    pub peak_mib: f64,
    pub bytes_per_node: f64,
    pub setup_seconds: f64,
}

/// A STREAM-like triad a[i] = b[i] + s c[i] on arrays of `n` f64 with the rayon pool of this
/// process; best of `reps`, counting 24 bytes per element (no write-allocate).
pub fn triad(n: usize, reps: usize) -> f64 {
    use rayon::prelude::*;
    let mut a = vec![0.0f64; n];
    let b: Vec<f64> = (0..n).map(|i| i as f64).collect();
    let c: Vec<f64> = (0..n).map(|i| (n - i) as f64).collect();
    let mut best = f64::INFINITY;
    for r in 0..reps {
        let s = 1.0 + r as f64 * 1e-3;
        let t = Instant::now();
        a.par_chunks_mut(1 << 16)
            .zip(b.par_chunks(1 << 16))
            .zip(c.par_chunks(1 << 16))
            .for_each(|((a, b), c)| {
                for i in 0..a.len() {
                    a[i] = b[i] + s * c[i];
                }
            });
        best = best.min(t.elapsed().as_secs_f64());
    }
    std::hint::black_box(&a);
    24.0 * n as f64 / best / 1e9
}

/// Measures one built simulation. Every process calls (collectives inside).
pub fn measure(
    mut sim: Simulation,
    sizes: GlobalSizes,
    triad_gbs: f64,
    setup_seconds: f64,
    tmp: &Path,
) -> Result<Case> {
    let n = sizes.nodes;
    // the scenario's sources
    let q = sim.sources(0.0);
    let h = sim.step_plan().h;
    // the substep as the Euler stepper runs it (fused sweeps of `fuse` substeps where they
    // apply), and one substep per sweep, in alternating chunks
    // let the process choose its fusion depth first (the same calls on every process)
    while !sim.prop().tuned() && sim.prop().fuses() {
        sim.prop_mut().substeps(h, &q, 8);
    }
    let fuse = sim.prop().fuse();
    let sweep = if sim.prop().fuses() { fuse } else { 1 };
    let run = |sim: &mut Simulation, depth: usize, count: usize| {
        sim.prop_mut().set_fuse(depth);
        sim.prop_mut().substeps(h, &q, count);
    };
    // calibrate: about 2 s of substeps per variant, the same count on every process
    run(&mut sim, fuse, 2 * sweep);
    run(&mut sim, 1, 2);
    let t = Instant::now();
    run(&mut sim, fuse, 4 * sweep);
    let t1 = sim.comm().max(t.elapsed().as_secs_f64()) / (4 * sweep) as f64;
    let k = ((2.0 / t1.max(1e-9)) as usize).clamp(10 * sweep, 20_000);
    let chunk = (k / 10).div_ceil(sweep).max(1) * sweep;
    let (mut times, mut single) = (Vec::new(), Vec::new());
    let mut waited = 0.0;
    for _ in 0..10 {
        sim.comm().max(0.0); // line the processes up
        let w0 = sim.prop().halo.wait_seconds();
        let t = Instant::now();
        run(&mut sim, fuse, chunk);
        times.push(sim.comm().max(t.elapsed().as_secs_f64()) / chunk as f64);
        waited += sim.prop().halo.wait_seconds() - w0;
        sim.comm().max(0.0);
        let t = Instant::now();
        run(&mut sim, 1, chunk);
        single.push(sim.comm().max(t.elapsed().as_secs_f64()) / chunk as f64);
    }
    sim.prop_mut().set_fuse(fuse);
    let per_substep = median(&times);
    let per_single = median(&single);
    let waited = sim.comm().max(waited) / (10 * chunk) as f64;
    let bytes = sim
        .comm()
        .sum_i128(sim.prop().op.stream_bytes_rows(sim.n_owned()) as i128) as f64
        / n as f64;
    // full steps with one substep each (dt = h)
    sim.set_dt(sim.dt().min(h))?;
    let mut steps = Vec::new();
    for _ in 0..5 {
        sim.comm().max(0.0);
        let t = Instant::now();
        let m = (chunk / 2).max(1);
        for _ in 0..m {
            sim.advance()?;
        }
        steps.push(sim.comm().max(t.elapsed().as_secs_f64()) / m as f64);
    }
    let per_step = median(&steps);
    // output: a few appends of every field
    // one name for every process (rank 0's pid)
    let mut id = [std::process::id() as f64];
    sim.comm().broadcast(0, &mut id);
    let file = tmp.join(format!("eprop-bench-{}.h5", id[0] as u64));
    let spec = SeriesSpec {
        fields: Field::ALL.iter().map(|f| (f.name(), f.components())).collect(),
        n_loads: 1,
        load_nodes: vec![0],
        scenario: "",
        version: VERSION,
        block_start: sim.blocks().start,
        block_len: sim.blocks().len,
        control_volumes: sim.vol_block(),
        attrs: vec![],
        ids: vec![],
        float32: false,
        compression: 0,
        output_steps: 5,
    };
    let io = sim.comm().handle().map(Handle::communicator);
    let mut out = SeriesWriter::create_from(&file, layout(&sizes), sim.static_mesh(), &spec, io)?;
    let mut writes = Vec::new();
    for _ in 0..5 {
        let t = Instant::now();
        let data = field_blocks(&sim, &Field::ALL);
        let refs: Vec<&[f64]> = data.iter().map(|d| d.as_slice()).collect();
        out.append(sim.time(), sim.step(), &refs, &sim.probes(), true)?;
        writes.push(sim.comm().max(t.elapsed().as_secs_f64()));
    }
    drop(out);
    if sim.comm().rank() == 0 {
        let _ = std::fs::remove_file(&file);
    }
    let rss = peak_rss() as f64;
    let peak = sim.comm().max(rss);
    let total_rss = eprop::distribute::comm::reproducible_sum(sim.comm(), [rss].into_iter());
    let rate = n as f64 / per_substep;
    Ok(Case {
        mesh: sim.global_mesh().map(|m| m.source.clone()).unwrap_or_default(),
        nodes: n,
        cells: sizes.cells,
        scheme: match &sim.prop().op {
            eprop::discretize::operator::Operator::Compact(c) if c.is_f32() => "compact32".to_string(),
            _ => eprop::simulate::scheme_name(sim.setup().model.scheme()).to_string(),
        },
        processes: sim.comm().size(),
        threads: rayon::current_num_threads(),
        substeps_timed: 10 * chunk,
        seconds_per_substep: per_substep,
        node_substeps_per_second: rate,
        substeps_per_sweep: sweep,
        single_node_substeps_per_second: n as f64 / per_single,
        bytes_per_node_substep: bytes,
        achieved_gb_per_s: rate * bytes / 1e9,
        triad_gb_per_s: triad_gbs,
        fraction_of_triad: rate * bytes / 1e9 / triad_gbs,
        full_steps_per_second: 1.0 / per_step,
        halo_wait_share: waited / per_substep,
        output_seconds_per_step: median(&writes),
        peak_mib: peak / 1048576.0,
        bytes_per_node: total_rss / n as f64,
        setup_seconds,
    })
}

/// Runs every case on this process (or, under MPI, on every process of `world`), computed as
/// `perf` says.
pub fn bench(
    world: Option<&dyn Comm>,
    cells: &[usize],
    schemes: &[String],
    perf: Performance,
    tmp: &Path,
    mut report: impl FnMut(&Case),
) -> Result<Vec<Case>> {
    let mut cases = Vec::new();
    // the triad of every process at once, summed (the bandwidth the processes share)
    let triad_gbs = {
        let mine = triad(1 << 24, 5);
        world.map_or(mine, |w| w.all_gather(&[mine]).iter().sum())
    };
    for &nc in cells {
        for scheme in schemes {
            let t0 = Instant::now();
            let case = match world {
                None => {
                    let mut setup = Setup::bench_box(nc, scheme)?;
                    setup.performance = perf;
                    let sizes = GlobalSizes::of(&setup.mesh);
                    let sim = Simulation::new(setup)?;
                    let s = t0.elapsed().as_secs_f64();
                    measure(sim, sizes, triad_gbs, s, tmp)?
                }
                Some(w) => {
                    let Built { sim, sizes, .. } = build_mpi(w, || {
                        Setup::bench_box(nc, scheme).map(|mut s| {
                            s.performance = perf;
                            s
                        })
                    })?;
                    let s = t0.elapsed().as_secs_f64();
                    measure(sim, sizes, triad_gbs, s, tmp)?
                }
            };
            report(&case);
            cases.push(case);
        }
    }
    Ok(cases)
}

/// The table header and one row per case.
pub fn header() -> String {
    format!(
        "{:>9} {:>8} {:>5} {:>9} {:>10} {:>3} {:>10} {:>7} {:>7} {:>7} {:>6} {:>10} {:>6} {:>8} {:>8}",
        "nodes",
        "scheme",
        "procs",
        "ns/node",
        "node-sub/s",
        "sw",
        "1/sweep",
        "B/node",
        "GB/s",
        "triad",
        "frac",
        "steps/s",
        "halo%",
        "out s",
        "B/node*"
    )
}

pub fn row(c: &Case) -> String {
    format!(
        "{:>9} {:>8} {:>5} {:>9.2} {:>10.3e} {:>3} {:>10.3e} {:>7.0} {:>7.2} {:>7.2} {:>6.2} {:>10.1} {:>6.1} {:>8.4} {:>8.0}",
        c.nodes,
        c.scheme.split(' ').next().unwrap_or(""),
        c.processes,
        1e9 / c.node_substeps_per_second,
        c.node_substeps_per_second,
        c.substeps_per_sweep,
        c.single_node_substeps_per_second,
        c.bytes_per_node_substep,
        c.achieved_gb_per_s,
        c.triad_gb_per_s,
        c.fraction_of_triad,
        c.full_steps_per_second,
        100.0 * c.halo_wait_share,
        c.output_seconds_per_step,
        c.bytes_per_node
    )
}
