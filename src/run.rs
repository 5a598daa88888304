//! `eprop run` and `eprop info`: drivers that tie scenario, solver and output together.

use crate::distribute::{self, GlobalSizes};
use crate::geometry::{compact_coefficients, Dual, Incidence};
use crate::material::Tensor;
use crate::operator::Compact;
use crate::scenario::{Scenario, Setup, FIELDS};
use crate::solver::{check_output_dir, scheme_name, Simulation, SAFETY};
use anyhow::Result;
use eprop_io::geom::{cell_quality, cell_volume, norm};
use eprop_io::vtkhdf::{Layout, SeriesSpec, SeriesWriter};
use eprop_io::Mesh;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub const VERSION: &str = concat!("eprop ", env!("CARGO_PKG_VERSION"));

/// Command-line overrides of a scenario.
#[derive(Default, Clone)]
pub struct RunOptions {
    pub output: Option<PathBuf>,
    pub steps: Option<u64>,
    pub quiet: bool,
    /// Continue the series in this file from its last complete step.
    pub restart: Option<PathBuf>,
}

#[derive(Serialize, Debug, Clone)]
pub struct LoadSummary {
    /// The (first) contact node's id; `contact_nodes` nodes over `contact_area` in all.
    pub node: u64,
    pub contact_nodes: usize,
    pub contact_area: f64,
    pub force: [f64; 3],
    pub displacement: [f64; 3],
}

/// What a run reports at the end.
#[derive(Serialize, Debug, Clone)]
pub struct Summary {
    pub scenario: String,
    pub mesh: String,
    pub nodes: usize,
    pub cells: usize,
    pub processes: usize,
    pub fixed_nodes: usize,
    pub scheme: String,
    /// The integrator of the propagation, and why it was chosen.
    pub integrator: String,
    pub integrator_why: String,
    pub h: f64,
    pub h_bound: f64,
    /// Substeps (or stages) per step as planned.
    pub substeps: usize,
    /// Operator applications per step of this run: min, median, max.
    pub applications_per_step: [u32; 3],
    pub dt: f64,
    pub steps: u64,
    pub time: f64,
    pub wall_seconds: f64,
    pub setup_seconds: f64,
    /// The step a restarted run continued from.
    pub restarted_from_step: Option<u64>,
    /// Time spent writing output (included in wall_seconds after the first step).
    pub output_seconds: f64,
    /// Median time of one output append over the first and the last 100 output steps.
    pub output_append_first100_median_s: f64,
    pub output_append_last100_median_s: f64,
    /// Largest time any process waited for halo messages.
    pub halo_wait_seconds: f64,
    pub node_substeps_per_second: f64,
    /// Largest peak resident memory of any process.
    pub peak_memory_mib: f64,
    /// Peak resident memory of rank 0 once the parts were sent (distributed runs).
    pub rank0_scatter_peak_mib: f64,
    pub max_displacement: f64,
    pub max_displacement_node: u64,
    pub max_displacement_at: [f64; 3],
    pub total_energy: f64,
    pub max_speed: f64,
    pub loads: Vec<LoadSummary>,
    pub output: String,
    pub output_steps: usize,
    pub warnings: Vec<String>,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "eprop run: {}", self.scenario)?;
        writeln!(
            f,
            "  mesh        {} ({} nodes, {} cells, {} fixed) on {} process(es)",
            self.mesh, self.nodes, self.cells, self.fixed_nodes, self.processes
        )?;
        writeln!(
            f,
            "  scheme      {}, h = {:.4e} (bound {:.4e}), {} substeps per step, dt = {:.4e}",
            self.scheme, self.h, self.h_bound, self.substeps, self.dt
        )?;
        let [lo, med, hi] = self.applications_per_step;
        writeln!(
            f,
            "  integrator  {}, operator applications per step {lo} / {med} / {hi} (min / median / max): {}",
            self.integrator, self.integrator_why
        )?;
        match self.restarted_from_step {
            Some(k) => writeln!(
                f,
                "  steps       {} to t = {:.6} (restarted at step {k})",
                self.steps, self.time
            )?,
            None => writeln!(f, "  steps       {} to t = {:.6}", self.steps, self.time)?,
        }
        writeln!(
            f,
            "  speed       {:.3} s setup, {:.3} s stepping ({:.3} s output, {:.3} s halo wait), {:.3e} node-substeps/s",
            self.setup_seconds,
            self.wall_seconds,
            self.output_seconds,
            self.halo_wait_seconds,
            self.node_substeps_per_second
        )?;
        if self.processes > 1 {
            writeln!(
                f,
                "  memory      {:.1} MiB peak per process, rank 0 {:.1} MiB after reading and scattering the mesh",
                self.peak_memory_mib, self.rank0_scatter_peak_mib
            )?;
        } else {
            writeln!(f, "  memory      {:.1} MiB peak", self.peak_memory_mib)?;
        }
        writeln!(
            f,
            "  max |u|     {:.6e} at node {} ({:.4}, {:.4}, {:.4})",
            self.max_displacement,
            self.max_displacement_node,
            self.max_displacement_at[0],
            self.max_displacement_at[1],
            self.max_displacement_at[2]
        )?;
        writeln!(
            f,
            "  energy      sum V|phi| = {:.6e}, max |v| = {:.3e}",
            self.total_energy, self.max_speed
        )?;
        for (k, l) in self.loads.iter().enumerate() {
            let at = if l.contact_nodes > 1 {
                format!("patch of {} nodes (area {:.4e})", l.contact_nodes, l.contact_area)
            } else {
                format!("node {}", l.node)
            };
            writeln!(
                f,
                "  load {}      {at}, F = ({:.4}, {:.4}, {:.4}), u = ({:.5e}, {:.5e}, {:.5e})",
                k + 1,
                l.force[0],
                l.force[1],
                l.force[2],
                l.displacement[0],
                l.displacement[1],
                l.displacement[2]
            )?;
        }
        for w in &self.warnings {
            writeln!(f, "  warning     {w}")?;
        }
        write!(f, "  output      {} ({} steps)", self.output, self.output_steps)
    }
}

/// Min, median and max of a list (zeros when empty).
fn spread(v: &[u32]) -> [u32; 3] {
    let mut v = v.to_vec();
    v.sort_unstable();
    match (v.first(), v.last()) {
        (Some(&lo), Some(&hi)) => [lo, v[v.len() / 2], hi],
        _ => [0; 3],
    }
}

/// Runs a scenario file on one process to its stop condition; returns the summary.
pub fn run(path: &Path, opts: &RunOptions) -> Result<Summary> {
    let t0 = Instant::now();
    let setup = prepare(path, opts)?;
    let sizes = GlobalSizes::of(&setup.mesh);
    let sim = Simulation::new(setup)?;
    run_simulation(sim, sizes, t0, opts, None, 0).map(|s| s.expect("one process has the summary"))
}

/// Reads and resolves a scenario with the command-line overrides applied.
pub fn prepare(path: &Path, opts: &RunOptions) -> Result<Setup> {
    let scenario = Scenario::load(path)?;
    tracing::info!("scenario {} read; reading the mesh", path.display());
    let mut setup = Setup::new(scenario)?;
    tracing::info!(
        "mesh {}: {} nodes, {} cells; scenario resolved",
        setup.mesh.source,
        setup.mesh.n_nodes(),
        setup.mesh.n_cells()
    );
    if let Some(o) = &opts.output {
        setup.output = o.clone();
    }
    if let Some(s) = opts.steps {
        setup.stop = crate::scenario::Stop::Steps(s);
    }
    if let Some(r) = &opts.restart {
        if !r.is_file() {
            anyhow::bail!(
                "{}: no such file to restart from; fix: give the output file of the interrupted run",
                r.display()
            );
        }
        setup.output = r.clone();
    }
    check_output_dir(&setup.output)?;
    Ok(setup)
}

/// An error already reported by another process (rank 0); this process exits quietly.
#[derive(Debug)]
pub struct ReportedElsewhere;

impl std::fmt::Display for ReportedElsewhere {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "the run failed on rank 0 (see its message)")
    }
}

impl std::error::Error for ReportedElsewhere {}

/// An error found by rank 0 before the parts were sent, and sent to every process instead.
#[derive(Debug)]
pub struct Collective(pub String);

impl std::fmt::Display for Collective {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Collective {}

/// Rank 0's split of the whole mesh: the METIS part of every node and the locality keys.
fn split(setup: &Setup, size: usize) -> Result<(Vec<u32>, Vec<u64>)> {
    let mesh = &setup.mesh;
    crate::distribute::log_memory("reading the scenario and mesh");
    tracing::info!("splitting {} nodes into {size} parts (METIS)", mesh.n_nodes());
    let (xadj, adj) = eprop_partition::node_graph(mesh.n_nodes(), &mesh.offsets, &mesh.conn);
    let weights = eprop_partition::degree_weights(&xadj);
    let part = eprop_partition::partition_weighted(&xadj, &adj, size, eprop_partition::Method::Metis, Some(&weights))
        .map_err(|e| anyhow::anyhow!("{}: {e}", mesh.source))?;
    Ok((part, eprop_partition::morton_keys(&mesh.points)))
}

/// Runs a scenario under MPI. Rank 0 reads the scenario and the mesh, splits the node graph
/// with METIS and sends every process its part; each process builds its own geometry and
/// operator, steps its part with halo exchanges and writes its rows of the output file
/// (collective MPI-IO). Returns the summary on rank 0.
pub fn run_mpi(world: mpi::topology::SimpleCommunicator, path: &Path, opts: &RunOptions) -> Result<Option<Summary>> {
    run_mpi_with(world, || prepare(path, opts), opts)
}

/// `run_mpi` with the whole-mesh setup made by `make_setup` on rank 0 (not called elsewhere).
pub fn run_mpi_with(
    world: mpi::topology::SimpleCommunicator,
    make_setup: impl FnOnce() -> Result<Setup>,
    opts: &RunOptions,
) -> Result<Option<Summary>> {
    let t0 = Instant::now();
    let b = build_mpi(world, make_setup)?;
    run_simulation(b.sim, b.sizes, t0, opts, Some(&b.io_comm), b.rank0_scatter_peak)
}

/// A distributed simulation ready to step.
pub struct Built {
    pub sim: Simulation,
    pub sizes: GlobalSizes,
    /// A communicator of the same processes for collective output.
    pub io_comm: mpi::topology::SimpleCommunicator,
    pub rank0_scatter_peak: u64,
}

/// Rank 0 makes the whole-mesh setup, splits it and sends every process its part; every
/// process builds its simulation.
pub fn build_mpi(
    world: mpi::topology::SimpleCommunicator,
    make_setup: impl FnOnce() -> Result<Setup>,
) -> Result<Built> {
    use mpi::point_to_point::{Destination, Source};
    use mpi::topology::Communicator;
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    let io_comm = world.duplicate();
    let halo_comm = world.duplicate();
    // message: 1 + encoded part, or 0 + error text; parts are built and sent one at a time
    let (mine, global, sizes) = if rank == 0 {
        match make_setup().and_then(|s| split(&s, size).map(|p| (s, p))) {
            Ok((setup, (part, keys))) => {
                let mesh = &setup.mesh;
                let sizes = GlobalSizes::of(mesh);
                let plan_of =
                    |r| eprop_partition::Plan::new(mesh.n_nodes(), &mesh.offsets, &mesh.conn, &part, r, Some(&keys));
                for r in 1..size {
                    let plan = plan_of(r);
                    tracing::debug!(
                        "part {r}: {} owned, {} halo, {} neighbours",
                        plan.numbering.n_owned,
                        plan.n_halo(),
                        plan.pattern.neighbours.len()
                    );
                    let mut msg = vec![1u8];
                    msg.extend_from_slice(&distribute::encode(&setup.restrict(&plan), &plan, sizes));
                    world.process_at_rank(r as i32).send(&msg[..]);
                }
                let plan = plan_of(0);
                let part = distribute::Part {
                    setup: setup.restrict(&plan),
                    plan,
                    sizes,
                };
                (part, Some(setup), sizes)
            }
            Err(e) => {
                let mut msg = vec![0u8];
                msg.extend_from_slice(format!("{e:#}").as_bytes());
                for r in 1..size {
                    world.process_at_rank(r as i32).send(&msg[..]);
                }
                return Err(Collective(format!("{e:#}")).into());
            }
        }
    } else {
        let (msg, _) = world.process_at_rank(0).receive_vec::<u8>();
        if msg.first() != Some(&1) {
            return Err(ReportedElsewhere.into());
        }
        let part = distribute::decode(&msg[1..])?;
        let sizes = part.sizes;
        (part, None, sizes)
    };
    let rank0_scatter_peak = if rank == 0 { distribute::peak_rss() } else { 0 };
    tracing::info!(
        "rank {rank}: part received ({} owned, {} halo nodes); building geometry and operator",
        mine.plan.numbering.n_owned,
        mine.plan.n_halo()
    );
    let halo = crate::scatter::Halo::new(mine.plan.pattern.clone(), halo_comm);
    let comm = crate::comm::Mpi::new(world);
    let sim = Simulation::new_with(mine.setup, Box::new(comm), halo, mine.plan, global.map(|s| s.mesh))?;
    Ok(Built {
        sim,
        sizes,
        io_comm,
        rank0_scatter_peak,
    })
}

/// Runs a prepared simulation; every process writes its block of the series, rank 0 returns
/// the summary.
pub fn run_simulation(
    mut sim: Simulation,
    sizes: GlobalSizes,
    t0: Instant,
    opts: &RunOptions,
    io_comm: Option<&mpi::topology::SimpleCommunicator>,
    rank0_scatter_peak: u64,
) -> Result<Option<Summary>> {
    let root = sim.comm.rank() == 0;
    let n = sizes.nodes;
    let layout = Layout {
        nodes: sizes.nodes,
        cells: sizes.cells,
        conn: sizes.conn,
    };
    let osec = sim.setup.scenario.file.output.clone();
    let fields: Vec<(&str, usize)> = FIELDS
        .iter()
        .filter(|f| osec.fields.iter().any(|x| x == f.0))
        .copied()
        .collect();
    let mut text_hash = distribute::Fnv::default();
    text_hash.bytes(sim.setup.scenario.text.as_bytes());
    let spec = SeriesSpec {
        fields: fields.clone(),
        ids: vec![("scenario_hash", text_hash.0), ("mesh_hash", sizes.mesh_hash)],
        float32: osec.precision == "float32",
        compression: osec.compression,
        n_loads: sim.loads.len(),
        load_nodes: sim.loads.iter().map(|l| l.nodes[0] as u64).collect(),
        scenario: &sim.setup.scenario.text,
        version: VERSION,
        block_start: sim.blocks.start,
        block_len: sim.blocks.len,
        control_volumes: &sim.vol_block,
        attrs: vec![
            ("dt", sim.dt),
            ("h", sim.step_plan().h),
            ("substeps", sim.step_plan().per_step as f64),
            ("processes", sim.comm.size() as f64),
        ],
    };
    let write = |sim: &Simulation, out: &mut SeriesWriter| -> Result<f64> {
        let t = Instant::now();
        let no = sim.n_owned();
        let c = sim.comm.as_ref();
        let mut data = Vec::with_capacity(fields.len());
        for (name, _) in &fields {
            data.push(match *name {
                "displacement" => sim.blocks.collect(sim.u[..no].as_flattened(), 3, c),
                "velocity" => sim.blocks.collect(sim.v[..no].as_flattened(), 3, c),
                "potential" => sim.blocks.collect(sim.prop.phi[..no].as_flattened(), 3, c),
                _ => {
                    let energy: Vec<f64> = sim.prop.phi[..no].iter().map(|p| norm(*p)).collect();
                    sim.blocks.collect(&energy, 1, c)
                }
            });
        }
        let refs: Vec<&[f64]> = data.iter().map(|d| d.as_slice()).collect();
        out.append(sim.time, sim.step, &refs, &sim.probes())?;
        Ok(t.elapsed().as_secs_f64())
    };
    tracing::info!(
        "h = {:.4e} (bound {:.4e}), dt = {:.4e}, {} substeps per step; writing {}",
        sim.step_plan().h,
        sim.step_plan().h_bound,
        sim.dt,
        sim.step_plan().per_step,
        sim.setup.output.display()
    );
    let (mut out, mut output_seconds) = if opts.restart.is_some() {
        let (out, resume) = SeriesWriter::reopen(&sim.setup.output, layout, &spec, io_comm)?;
        sim.restore(resume.step, &resume.u, &resume.v, &resume.phi);
        (out, 0.0)
    } else {
        let mut out = SeriesWriter::create(&sim.setup.output, layout, sim.global.as_ref(), &spec, io_comm)?;
        crate::distribute::log_memory("the static output");
        let t = write(&sim, &mut out)?;
        crate::distribute::log_memory("the first output step");
        (out, t)
    };
    let restarted_at = sim.step;
    let mut appends = vec![output_seconds];
    let setup_seconds = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let every = sim.setup.every;
    let max_steps = sim.max_steps();
    let mut last_report = Instant::now();
    // a progress bar on rank 0 when a person watches (stderr is a terminal) and not --quiet
    let bar = root && !opts.quiet && std::io::IsTerminal::is_terminal(&std::io::stderr());
    while !sim.done() {
        sim.advance()?;
        let is_last = sim.done();
        if sim.step.is_multiple_of(every) || is_last {
            let t = write(&sim, &mut out)?;
            appends.push(t);
            output_seconds += t;
        }
        if bar && last_report.elapsed().as_secs_f64() > 0.2 {
            let done = (sim.step - restarted_at) as f64;
            let rate = done / t1.elapsed().as_secs_f64().max(1e-9);
            let frac = (sim.step as f64 / max_steps.max(1) as f64).min(1.0);
            let eta = (max_steps.saturating_sub(sim.step)) as f64 / rate.max(1e-9);
            let w = 30;
            let fill = (frac * w as f64) as usize;
            eprint!(
                "\r  [{}{}] step {}/{} {:.1} steps/s ETA {:.0} s max|v| {:.2e}   ",
                "#".repeat(fill),
                "-".repeat(w - fill),
                sim.step,
                max_steps,
                rate,
                eta,
                sim.max_speed
            );
            last_report = Instant::now();
        }
    }
    if bar {
        eprint!("\r{}\r", " ".repeat(100));
    }
    let wall = t1.elapsed().as_secs_f64();
    let median = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let k = appends.len().min(100);
    let (append_first, append_last) = (median(&appends[..k]), median(&appends[appends.len() - k..]));
    let (umax, imax) = sim.max_displacement();
    let total = sim.total_energy();
    let probes = sim.probes();
    let halo_wait = sim.comm.max(sim.prop.halo.wait_seconds());
    let peak = sim.comm.max(distribute::peak_rss() as f64);
    let Some(mesh) = sim.global.as_ref() else {
        return Ok(None);
    };
    let mut warnings = mesh.warnings.clone();
    if sim.inactive_nodes > 0 {
        warnings.push(format!(
            "{} node(s) belong to no cell and stay at rest",
            sim.inactive_nodes
        ));
    }
    if let crate::scenario::Stop::Equilibrium { tol, .. } = sim.setup.stop {
        if sim.max_speed >= tol {
            warnings.push(format!(
                "equilibrium not reached after {} steps (max |v| = {:.3e} > {tol:e})",
                sim.step, sim.max_speed
            ));
        }
    }
    let imax = imax as usize;
    Ok(Some(Summary {
        scenario: sim.setup.scenario.path.display().to_string(),
        mesh: mesh.source.clone(),
        nodes: n,
        cells: mesh.n_cells(),
        processes: sim.comm.size(),
        fixed_nodes: sim.fixed_nodes,
        scheme: scheme_name(sim.setup.scheme).to_string(),
        integrator: sim.step_plan().integrator.to_string(),
        integrator_why: sim.step_plan().why.clone(),
        h: sim.step_plan().h,
        h_bound: sim.step_plan().h_bound,
        substeps: sim.step_plan().per_step,
        applications_per_step: spread(&sim.applications),
        dt: sim.dt,
        steps: sim.step,
        time: sim.time,
        wall_seconds: wall,
        setup_seconds,
        output_seconds,
        output_append_first100_median_s: append_first,
        output_append_last100_median_s: append_last,
        halo_wait_seconds: halo_wait,
        node_substeps_per_second: (n as f64 * sim.applications.iter().map(|&a| a as f64).sum::<f64>())
            / wall.max(1e-12),
        restarted_from_step: opts.restart.as_ref().map(|_| restarted_at),
        peak_memory_mib: peak / 1048576.0,
        rank0_scatter_peak_mib: rank0_scatter_peak as f64 / 1048576.0,
        max_displacement: umax,
        max_displacement_node: mesh.node_ids[imax],
        max_displacement_at: mesh.points[imax],
        total_energy: total,
        max_speed: sim.max_speed,
        loads: sim
            .loads
            .iter()
            .zip(&probes)
            .map(|(l, (f, d))| LoadSummary {
                node: l.node_ids[0],
                contact_nodes: l.nodes.len(),
                contact_area: l.area,
                force: *f,
                displacement: *d,
            })
            .collect(),
        output: out.path().display().to_string(),
        output_steps: out.steps_written(),
        warnings,
    }))
}

/// What `eprop info` reports about a mesh.
#[derive(Serialize, Debug)]
pub struct MeshInfo {
    pub file: String,
    pub nodes: usize,
    pub cells: usize,
    pub cell_kinds: Vec<(String, usize)>,
    pub surface_facets: usize,
    pub groups: Vec<(u8, i32, String)>,
    pub bounds: [[f64; 3]; 2],
    pub volume: f64,
    pub control_volume_sum: f64,
    pub max_closure_error: f64,
    pub min_quality: f64,
    pub max_quality: f64,
    pub stable_h_r005: f64,
    /// Which nodes and cells set the stable substep (conductivity 0.05).
    pub stiffness: crate::integrate::stiffness::Stiffness,
    pub unreferenced_nodes: usize,
    pub warnings: Vec<String>,
}

pub fn mesh_info(mesh: &Mesh) -> MeshInfo {
    let n = mesh.n_nodes();
    let inc = Incidence::new(mesh);
    let dual = Dual::build(mesh, &inc, n, None);
    let volume: f64 = (0..mesh.n_cells())
        .map(|c| cell_volume(mesh.kinds[c], mesh.cell(c), &mesh.points))
        .sum();
    let (mut qmin, mut qmax) = (f64::INFINITY, 0.0f64);
    for c in 0..mesh.n_cells() {
        let q = cell_quality(mesh.kinds[c], mesh.cell(c), &mesh.points);
        qmin = qmin.min(q);
        qmax = qmax.max(q);
    }
    let r = vec![Tensor::identity() * 0.05; n];
    let a = compact_coefficients(mesh, &inc, &dual, &r);
    let active: Vec<bool> = dual.vol.iter().map(|&v| v > 0.0).collect();
    let op = Compact::new(&dual, &a, &active);
    let g = op.gershgorin();
    let stiffness = crate::integrate::stiffness::analyse(mesh, &op, &dual.vol, &r, &|c| mesh.cell_id(c));
    let (lo, hi) = mesh.bounds();
    let unref = dual.vol.iter().filter(|&&v| v <= 0.0).count();
    let mut warnings = mesh.warnings.clone();
    if unref > 0 {
        warnings.push(format!("{unref} node(s) belong to no cell"));
    }
    MeshInfo {
        file: mesh.source.clone(),
        nodes: n,
        cells: mesh.n_cells(),
        cell_kinds: mesh
            .kind_counts()
            .into_iter()
            .map(|(k, c)| (k.name().to_string(), c))
            .collect(),
        surface_facets: mesh.facets.len(),
        groups: mesh.group_names.iter().map(|((d, t), s)| (*d, *t, s.clone())).collect(),
        bounds: [lo, hi],
        volume,
        control_volume_sum: dual.vol.iter().sum(),
        max_closure_error: dual.max_closure_error(),
        min_quality: qmin,
        max_quality: qmax,
        stable_h_r005: SAFETY * 2.0 / g,
        stiffness,
        unreferenced_nodes: unref,
        warnings,
    }
}

impl std::fmt::Display for MeshInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "{}", self.file)?;
        let kinds: Vec<String> = self.cell_kinds.iter().map(|(k, c)| format!("{c} {k}")).collect();
        writeln!(f, "  nodes            {}", self.nodes)?;
        writeln!(f, "  cells            {} ({})", self.cells, kinds.join(", "))?;
        writeln!(f, "  surface facets   {}", self.surface_facets)?;
        for (d, t, s) in &self.groups {
            writeln!(f, "  group            {s:?} (dim {d}, tag {t})")?;
        }
        writeln!(
            f,
            "  bounds           [{:.4}, {:.4}, {:.4}] .. [{:.4}, {:.4}, {:.4}]",
            self.bounds[0][0],
            self.bounds[0][1],
            self.bounds[0][2],
            self.bounds[1][0],
            self.bounds[1][1],
            self.bounds[1][2]
        )?;
        writeln!(f, "  volume           {:.12e}", self.volume)?;
        writeln!(
            f,
            "  sum of V_i       {:.12e} (relative difference {:.1e})",
            self.control_volume_sum,
            ((self.control_volume_sum - self.volume) / self.volume).abs()
        )?;
        writeln!(
            f,
            "  closure error    {:.2e} (max |sum_j S_ij + A_i| / dual area)",
            self.max_closure_error
        )?;
        writeln!(
            f,
            "  cell quality     {:.4} .. {:.4} (1 = regular)",
            self.min_quality, self.max_quality
        )?;
        write!(
            f,
            "  stable h         {:.4e} (compact, conductivity 0.05, {SAFETY} of the bound)\n{}",
            self.stable_h_r005,
            self.stiffness.describe(17)
        )?;
        for w in &self.warnings {
            write!(f, "\n  warning          {w}")?;
        }
        Ok(())
    }
}

/// Quality of one split of the node graph.
#[derive(Serialize, Debug)]
pub struct SplitQuality {
    pub method: String,
    pub edge_cut: usize,
    pub imbalance: f64,
    pub owned: Vec<usize>,
    pub halo: Vec<usize>,
    pub neighbours: Vec<usize>,
}

/// What `eprop partition` reports: METIS beside a block split.
#[derive(Serialize, Debug)]
pub struct PartitionReport {
    pub file: String,
    pub nodes: usize,
    pub graph_edges: usize,
    pub parts: usize,
    pub splits: Vec<SplitQuality>,
}

pub fn partition_report(mesh: &Mesh, parts: usize) -> Result<PartitionReport> {
    use eprop_partition::{node_graph, quality, Method};
    let (xadj, adj) = node_graph(mesh.n_nodes(), &mesh.offsets, &mesh.conn);
    let mut splits = Vec::new();
    let weights = eprop_partition::degree_weights(&xadj);
    for (name, method) in [("metis", Method::Metis), ("block", Method::Block)] {
        // METIS balances the work per node (its neighbours + 1), as `mpirun eprop run` does
        let part = eprop_partition::partition_weighted(&xadj, &adj, parts, method, Some(&weights))
            .map_err(|e| anyhow::anyhow!("{}: {e}", mesh.source))?;
        let q = quality(&xadj, &adj, &part, parts);
        splits.push(SplitQuality {
            method: name.to_string(),
            edge_cut: q.edge_cut,
            imbalance: q.imbalance,
            owned: q.owned,
            halo: q.halo,
            neighbours: q.neighbours,
        });
    }
    Ok(PartitionReport {
        file: mesh.source.clone(),
        nodes: mesh.n_nodes(),
        graph_edges: adj.len() / 2,
        parts,
        splits,
    })
}

impl std::fmt::Display for PartitionReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{}: {} nodes, {} graph edges, {} parts",
            self.file, self.nodes, self.graph_edges, self.parts
        )?;
        for s in &self.splits {
            let halo: usize = s.halo.iter().sum();
            writeln!(
                f,
                "  {:<6} edge cut {} ({:.2}% of edges), imbalance {:.3}, halo nodes {} ({:.2}% of nodes)",
                s.method,
                s.edge_cut,
                100.0 * s.edge_cut as f64 / self.graph_edges.max(1) as f64,
                s.imbalance,
                halo,
                100.0 * halo as f64 / self.nodes.max(1) as f64
            )?;
        }
        writeln!(
            f,
            "  part   {:>10} {:>10} {:>10} {:>10} {:>10} {:>10}",
            "metis:own", "halo", "nbrs", "block:own", "halo", "nbrs"
        )?;
        let (m, b) = (&self.splits[0], &self.splits[1]);
        for p in 0..self.parts {
            writeln!(
                f,
                "  {:<4}   {:>10} {:>10} {:>10} {:>10} {:>10} {:>10}",
                p, m.owned[p], m.halo[p], m.neighbours[p], b.owned[p], b.halo[p], b.neighbours[p]
            )?;
        }
        Ok(())
    }
}

/// What `eprop check` derives from a scenario without running it.
#[derive(Serialize, Debug)]
pub struct CheckReport {
    pub scenario: String,
    pub mesh: String,
    pub nodes: usize,
    pub cells: usize,
    pub fixed_nodes: usize,
    /// Per load: contact nodes and contact area.
    pub loads: Vec<(usize, f64)>,
    pub scheme: String,
    pub integrator: String,
    pub integrator_why: String,
    /// Which nodes and cells set the Euler substep (compact scheme).
    pub stiffness: Option<crate::integrate::stiffness::Stiffness>,
    pub h: f64,
    pub h_bound: f64,
    pub dt: f64,
    pub dt_bound: f64,
    pub substeps: usize,
    pub steps: u64,
    pub output: String,
    pub output_steps: u64,
    pub output_mib: f64,
    pub memory_mib: f64,
    pub estimated_seconds: f64,
    pub warnings: Vec<String>,
}

/// Validates a scenario, builds its simulation on one process and times a few substeps.
pub fn check(path: &Path, opts: &RunOptions) -> Result<CheckReport> {
    let setup = prepare(path, opts)?;
    let mut sim = Simulation::new(setup)?;
    let n = sim.n_global;
    let q: Vec<(u32, [f64; 3])> = vec![];
    let t = Instant::now();
    let reps = 5;
    for _ in 0..reps {
        sim.prop.substep(sim.step_plan().h, &q);
    }
    let per_substep = t.elapsed().as_secs_f64() / reps as f64;
    let steps = sim.max_steps();
    let every = sim.setup.every.max(1);
    let output_steps = steps / every + 1 + u64::from(!steps.is_multiple_of(every));
    let fields: usize = FIELDS
        .iter()
        .filter(|f| sim.setup.scenario.file.output.fields.iter().any(|x| x == f.0))
        .map(|f| f.1)
        .sum();
    let width = if sim.setup.scenario.file.output.precision == "float32" {
        4.0
    } else {
        8.0
    };
    let mesh = sim.global.as_ref().unwrap_or(&sim.setup.mesh);
    let mut warnings = mesh.warnings.clone();
    if sim.inactive_nodes > 0 {
        warnings.push(format!(
            "{} node(s) belong to no cell and stay at rest",
            sim.inactive_nodes
        ));
    }
    if sim.loads.iter().any(|l| l.nodes.len() == 1) {
        warnings.push(
            "a load on a single node is mesh-dependent (the source is singular); a `patch = { center, radius }` is not"
                .into(),
        );
    }
    Ok(CheckReport {
        scenario: path.display().to_string(),
        mesh: mesh.source.clone(),
        nodes: n,
        cells: mesh.n_cells(),
        fixed_nodes: sim.fixed_nodes,
        loads: sim.loads.iter().map(|l| (l.nodes.len(), l.area)).collect(),
        scheme: scheme_name(sim.setup.scheme).to_string(),
        integrator: sim.step_plan().integrator.to_string(),
        integrator_why: sim.step_plan().why.clone(),
        stiffness: crate::integrate::stiffness::of_simulation(&sim),
        h: sim.step_plan().h,
        h_bound: sim.step_plan().h_bound,
        dt: sim.dt,
        dt_bound: sim.dt_bound,
        substeps: sim.step_plan().per_step,
        steps,
        output: sim.setup.output.display().to_string(),
        output_steps,
        output_mib: (n * fields) as f64 * width * output_steps as f64 / 1048576.0,
        memory_mib: distribute::peak_rss() as f64 / 1048576.0,
        estimated_seconds: per_substep * 1.3 * sim.step_plan().cost * steps as f64,
        warnings,
    })
}

impl std::fmt::Display for CheckReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "{}: ok", self.scenario)?;
        writeln!(
            f,
            "  mesh        {} ({} nodes, {} cells)",
            self.mesh, self.nodes, self.cells
        )?;
        writeln!(f, "  fixed       {} nodes", self.fixed_nodes)?;
        for (k, (n, a)) in self.loads.iter().enumerate() {
            writeln!(f, "  load {}      {n} contact node(s), contact area {a:.4e}", k + 1)?;
        }
        writeln!(
            f,
            "  scheme      {}, h = {:.4e} (bound {:.4e}), dt = {:.4e} (bound {:.4e}), {} substeps per step",
            self.scheme, self.h, self.h_bound, self.dt, self.dt_bound, self.substeps
        )?;
        writeln!(f, "  integrator  {}: {}", self.integrator, self.integrator_why)?;
        if let Some(s) = &self.stiffness {
            writeln!(f, "{}", s.describe(12))?;
        }
        writeln!(
            f,
            "  run         {} steps, about {:.3} s on one process; {:.1} MiB of memory",
            self.steps, self.estimated_seconds, self.memory_mib
        )?;
        write!(
            f,
            "  output      {} ({} steps, about {:.1} MiB)",
            self.output, self.output_steps, self.output_mib
        )?;
        for w in &self.warnings {
            write!(f, "\n  warning     {w}")?;
        }
        Ok(())
    }
}
