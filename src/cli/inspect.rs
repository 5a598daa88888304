//! The commands that look without stepping: `eprop info` (a mesh's geometry checks),
//! `eprop partition` (the quality of a split), `eprop check` (what a scenario derives) and
//! `eprop export-operator` (the compact operator as a CSR matrix).

use crate::cli::run::{prepare, RunOptions};
use anyhow::{bail, Result};
use eprop::config::{Scenario, Setup};
use eprop::diagnostics::{fixed, peak_rss};
use eprop::discretize::operator::{Compact, Operator};
use eprop::distribute::comm::Comm;
use eprop::guard::limits::Budget;
use eprop::simulate::{scheme_name, Simulation};
use eprop_mesh::Mesh;
use serde::Serialize;
use std::path::Path;

/// Quality of one split of the node graph.
#[derive(Serialize, Debug)]
pub struct SplitQuality {
    pub method: String,
    pub edge_cut: usize,
    pub imbalance: f64,
    pub owned: Vec<usize>,
    pub halo: Vec<usize>,
    pub neighbours: Vec<usize>,
    /// Wall time of the split, s.
    pub seconds: f64,
}

impl SplitQuality {
    /// The report's row of a split by `method` that took `seconds`.
    fn new(method: &str, q: eprop_partition::Quality, seconds: f64) -> Self {
        SplitQuality {
            method: method.to_string(),
            edge_cut: q.edge_cut,
            imbalance: q.imbalance,
            owned: q.owned,
            halo: q.halo,
            neighbours: q.neighbours,
            seconds,
        }
    }
}

/// What `eprop partition` reports: METIS and PT-Scotch beside a block split.
#[derive(Serialize, Debug)]
pub struct PartitionReport {
    pub file: String,
    pub nodes: usize,
    pub graph_edges: usize,
    pub parts: usize,
    /// Processes that split with PT-Scotch.
    pub processes: usize,
    pub splits: Vec<SplitQuality>,
    /// Peak resident memory of each process, bytes (a mesh read in slabs).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub peak_memory: Vec<u64>,
    /// Each process's share after the cells and coordinates moved to their owners (one part
    /// per process): owned nodes, halo nodes, cells.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub moved: Vec<[usize; 3]>,
}

/// The report on rank 0 (`None` on the other processes of `world`, which take part in the
/// PT-Scotch split).
pub fn partition_report(mesh: &Mesh, parts: usize, world: Option<&dyn Comm>) -> Result<Option<PartitionReport>> {
    use eprop_partition::{node_graph, quality, Method};
    let (xadj, adj) = node_graph(mesh.n_nodes(), &mesh.offsets, &mesh.conn);
    let root = world.is_none_or(|w| w.rank() == 0);
    let mut splits = Vec::new();
    let weights = eprop_partition::degree_weights(&xadj);
    let mut add = |name: &str, part: &[u32], seconds: f64| {
        let q = quality(&xadj, &adj, part, parts);
        splits.push(SplitQuality::new(name, q, seconds));
    };
    let mut scotch = None;
    if eprop::distribute::ptscotch::AVAILABLE && parts > 1 && parts <= mesh.n_nodes() {
        if world.is_none() {
            // MPI for PT-Scotch alone, started outside the timed split
            eprop::distribute::launch::start_alone()?;
        }
        let t = std::time::Instant::now();
        let part = eprop::distribute::ptscotch::split_whole(world, &xadj, &adj, &weights, parts)
            .map_err(|e| anyhow::anyhow!("{}: {e:#}", mesh.source))?;
        scotch = Some((part, t.elapsed().as_secs_f64()));
    }
    if !root {
        return Ok(None);
    }
    for (name, method) in [("metis", Method::Metis), ("block", Method::Block)] {
        // METIS balances the work per node (its neighbours + 1), as `mpirun eprop run` does
        let t = std::time::Instant::now();
        let part = eprop_partition::partition_weighted(&xadj, &adj, parts, method, Some(&weights))
            .map_err(|e| anyhow::anyhow!("{}: {e}", mesh.source))?;
        add(name, &part, t.elapsed().as_secs_f64());
        if let (Method::Metis, Some((part, seconds))) = (method, &scotch) {
            add("ptscotch", part, *seconds);
        }
    }
    Ok(Some(PartitionReport {
        file: mesh.source.clone(),
        nodes: mesh.n_nodes(),
        graph_edges: adj.len() / 2,
        parts,
        processes: world.map_or(1, |w| w.size()),
        splits,
        peak_memory: vec![],
        moved: vec![],
    }))
}

impl std::fmt::Display for PartitionReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{}: {} nodes, {} graph edges, {} parts{}",
            self.file,
            self.nodes,
            self.graph_edges,
            self.parts,
            if self.splits.iter().any(|s| s.method == "ptscotch") {
                format!(" (PT-Scotch on {} process(es))", self.processes)
            } else {
                String::new()
            }
        )?;
        for s in &self.splits {
            let halo: usize = s.halo.iter().sum();
            writeln!(
                f,
                "  {:<8} edge cut {} ({:.2}% of edges), imbalance {:.3}, halo nodes {} ({:.2}% of nodes), {:.3} s",
                s.method,
                s.edge_cut,
                100.0 * s.edge_cut as f64 / self.graph_edges.max(1) as f64,
                s.imbalance,
                halo,
                100.0 * halo as f64 / self.nodes.max(1) as f64,
                s.seconds
            )?;
        }
        if let (Some(&first), false) = (self.peak_memory.first(), self.peak_memory.is_empty()) {
            let mib = |b: u64| b as f64 / 1048576.0;
            let mean = self.peak_memory.iter().sum::<u64>() as f64 / self.peak_memory.len() as f64;
            let all: Vec<String> = self.peak_memory.iter().map(|&b| format!("{:.1}", mib(b))).collect();
            writeln!(
                f,
                "  peak memory per process: {} MiB (rank 0 {:.2}x the mean)",
                all.join(", "),
                first as f64 / mean.max(1.0)
            )?;
        }
        if !self.moved.is_empty() {
            let col = |k: usize| {
                self.moved
                    .iter()
                    .map(|m| m[k].to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            writeln!(
                f,
                "  moved to the owners: owned nodes {}; halo nodes {}; cells {}",
                col(0),
                col(1),
                col(2)
            )?;
        }
        // METIS beside the block split, or the splits there are
        let by = |name: &str| self.splits.iter().find(|s| s.method == name);
        let cols: Vec<&SplitQuality> = match (by("metis"), by("block")) {
            (Some(m), Some(b)) => vec![m, b],
            _ => self.splits.iter().collect(),
        };
        // a column as wide as its header ("ptscotch:own" is longer than the numbers' 10)
        let own = |s: &SplitQuality| format!("{}:own", s.method);
        write!(f, "  part  ")?;
        for s in &cols {
            write!(
                f,
                " {:>w$} {:>10} {:>10}",
                own(s),
                "halo",
                "nbrs",
                w = own(s).len().max(10)
            )?;
        }
        writeln!(f)?;
        for p in 0..self.parts {
            write!(f, "  {p:<4}  ")?;
            for s in &cols {
                let w = own(s).len().max(10);
                write!(f, " {:>w$} {:>10} {:>10}", s.owned[p], s.halo[p], s.neighbours[p])?;
            }
            writeln!(f)?;
        }
        Ok(())
    }
}

/// `eprop partition` of a VTKHDF mesh: every process of `world` reads its slab, the node
/// graph is built from the slabs and split by PT-Scotch (METIS on one process or where
/// PT-Scotch is absent); no process holds the whole mesh or graph. The report on rank 0
/// (`None` on the others), with every process's peak memory.
pub fn partition_report_slabs(path: &Path, parts: usize, world: Option<&dyn Comm>) -> Result<Option<PartitionReport>> {
    use eprop::distribute::slabs;
    let slab = slabs::read(world, path)?;
    let (rank, size) = world.map_or((0, 1), |w| (w.rank(), w.size()));
    let t = std::time::Instant::now();
    let cells = slabs::cells_to_owners(&slab, world.and_then(|w| w.handle()))?;
    let vtxdist = slabs::cuts(slab.nodes, size);
    let graph = slabs::node_graph(&cells, &vtxdist, vtxdist[rank], vtxdist[rank + 1])?;
    drop(cells);
    let (nodes, edges) = (slab.nodes, graph.adj.len());
    let (part, how) = slabs::split(&graph, parts, world)?;
    let seconds = world.map_or(0.0, |w| w.max(0.0)).max(t.elapsed().as_secs_f64());
    let q = slabs::quality(&graph, &part, parts, world);
    drop(graph);
    let edges = world.map_or(edges as i128, |w| w.sum_i128(edges as i128)) as usize;
    // one part per process: the cells and coordinates move to their owners
    let moved: Vec<[usize; 3]> = match parts == size {
        true => {
            let local = slabs::redistribute(&slab, &part, world.and_then(|w| w.handle()))?;
            drop(slab);
            let mine = [local.n_owned, local.global.len() - local.n_owned, local.cells.len()].map(|x| x as f64);
            world
                .map_or(mine.to_vec(), |w| w.all_gather(&mine))
                .chunks_exact(3)
                .map(|c| [c[0] as usize, c[1] as usize, c[2] as usize])
                .collect()
        }
        false => vec![],
    };
    let peak = peak_rss() as f64;
    let peak_memory: Vec<u64> = world
        .map_or(vec![peak], |w| w.all_gather(&[peak]))
        .iter()
        .map(|&b| b as u64)
        .collect();
    if rank != 0 {
        return Ok(None);
    }
    let method = match how {
        slabs::Splitter::Ptscotch => "ptscotch",
        slabs::Splitter::Metis => "metis",
    };
    Ok(Some(PartitionReport {
        file: path.display().to_string(),
        nodes,
        graph_edges: edges / 2,
        parts,
        processes: size,
        splits: vec![SplitQuality::new(method, q, seconds)],
        peak_memory,
        moved,
    }))
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
    /// Per tool: what it is, where it starts and how deep it is in the organ then.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub tools: Vec<String>,
    pub scheme: String,
    pub integrator: String,
    pub integrator_why: String,
    /// Whether auto's candidates were measured on trial steps (`check --measure`), not
    /// estimated from their models.
    pub measured: bool,
    /// What `substeps` counts, with its unit ("4 substeps", "14 stages").
    pub per_step: String,
    /// Which nodes and cells set the Euler substep (compact scheme).
    pub stiffness: Option<eprop::discretize::quality::Stiffness>,
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
    /// Seconds to write the output steps on the output's disk (a probe written there).
    pub output_seconds: Option<f64>,
    /// In the real-time mode: its steps against euler's at the same dt (`REALTIME_STEPS`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub realtime: Option<eprop::simulate::realtime::Comparison>,
    /// In the real-time mode without --measure: how to measure its error.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub realtime_note: Option<String>,
    pub warnings: Vec<String>,
}

/// `eprop check --measure` compares the real-time mode with euler over at most this many
/// steps, and for at most `REALTIME_SECONDS` of wall time.
pub const REALTIME_STEPS: u64 = 100;
pub const REALTIME_SECONDS: f64 = 60.0;

/// The scenario in the real-time mode and by euler, stepped side by side on one process
/// (`simulate::realtime::compare`).
fn realtime_against_euler(path: &Path, opts: &RunOptions, steps: u64) -> Result<eprop::simulate::realtime::Comparison> {
    let with = |extra: &[&str]| {
        let mut o = opts.clone();
        o.sets.extend(extra.iter().map(|s| s.to_string()));
        prepare(path, &o)
    };
    let rt = with(&["time.realtime=true"])?;
    let eu = with(&["time.realtime=false", "model.integrator=\"euler\""])?;
    eprop::simulate::realtime::compare_within(rt, eu, steps.min(REALTIME_STEPS), REALTIME_SECONDS)
}

/// Validates a scenario, builds its simulation on one process and times a few substeps. The
/// limits a run applies (steps, substeps, step sizes) are errors here too; what a run would
/// refuse about its output file or disk, and implausible loads, are warnings. `auto`'s choice
/// is its models' estimate (stability bound, cost per step, one trial solve for implicit)
/// unless `measure`, which runs its trial steps under the first loads as `run` does.
pub fn check(path: &Path, opts: &RunOptions, measure: bool) -> Result<CheckReport> {
    let mut setup = prepare(path, opts)?;
    setup.integrator.trials = measure;
    let sizes = eprop::distribute::parts::GlobalSizes::of(&setup.mesh);
    let mut sim = Simulation::new(setup)?;
    let budget = Budget::of(&sim, &sizes, opts.steps.is_some(), true).map_err(|e| anyhow::anyhow!(e))?;
    crate::guard::plausible::tool_reach(&sim).map_err(|e| anyhow::anyhow!(e))?;
    let n = sim.n_global();
    let per_substep = sim.time_substeps(5);
    let steps = budget.steps;
    let mesh = sim.global_mesh().unwrap_or(&sim.setup().mesh);
    let whole = eprop::simulate::WholeMesh::of(mesh, &crate::guard::plausible::load_nodes(&sim));
    let mut warnings = eprop::output::summary::warnings(&sim, &whole);
    warnings.extend(crate::guard::plausible::load_warnings(&sim, &whole));
    warnings.extend(crate::guard::plausible::tool_warnings(&sim));
    if sim.loads().iter().any(|l| l.nodes.len() == 1) {
        warnings.push(
            "a load on a single node is mesh-dependent (the source is singular); a `patch = { center, radius }` is not"
                .into(),
        );
    }
    // a scenario with a live input is one for `eprop serve`: its refusals too
    let live = sim.setup().tools.iter().any(|t| t.live) || sim.setup().loads.iter().any(|l| l.live);
    if live {
        if let Err(e) = crate::cli::serve::check_live(sim.setup()) {
            warnings.push(format!("`eprop serve` will refuse: {e:#}"));
        }
    }
    let file = &sim.setup().output.file;
    let inputs = sim.setup().scenario.inputs();
    if let Err(e) = eprop::guard::safety::refuse_inputs(file, "the output file", &inputs) {
        warnings.push(format!("`eprop run` will refuse: {e:#}"));
    } else if file.exists() {
        let overwrite = sim.setup().output.overwrite;
        let again = eprop::guard::safety::restart_command(path, file, 1, &[]);
        if let Err(e) = eprop::guard::safety::check_existing(file, "the output file", overwrite, &again) {
            warnings.push(format!("`eprop run` will refuse: {e:#}"));
        }
    }
    // in the real-time mode, or a scenario for `eprop serve` that takes it by default
    let serve_default = live
        && sim.setup().time.realtime.is_none()
        && sim.setup().integrator.kind == eprop::config::integrator::Kind::Auto;
    let in_mode = sim.setup().time.realtime() || serve_default;
    let realtime_note = (in_mode && !measure).then(|| {
        "the real-time mode's error is not measured; fix: `eprop check --measure` steps it beside euler at the same dt (up to 100 steps or 60 s)".to_string()
    });
    let realtime = if in_mode && measure {
        let c = realtime_against_euler(path, opts, budget.steps)?;
        if c.u_error > eprop::simulate::realtime::TOLERANCE {
            warnings.push(format!(
                "the real-time mode's u differs from euler's at the same dt by {:.2e} (relative, step {}), more than {:.0e}; fix: a smaller dt, or [time] realtime = false",
                c.u_error,
                c.u_error_step,
                eprop::simulate::realtime::TOLERANCE
            ));
        }
        Some(c)
    } else {
        None
    };
    let reclaimed = std::fs::metadata(file).map(|m| m.len()).unwrap_or(0);
    let what = format!("{} output steps", budget.output_steps);
    if let Err(e) = eprop::guard::safety::check_space(file, &budget, reclaimed, &what, false) {
        warnings.push(format!("`eprop run` will refuse without --force: {e:#}"));
    }
    Ok(CheckReport {
        scenario: path.display().to_string(),
        mesh: mesh.source.clone(),
        nodes: n,
        cells: mesh.n_cells(),
        fixed_nodes: sim.fixed_nodes(),
        loads: sim.loads().iter().map(|l| (l.nodes.len(), l.area)).collect(),
        tools: sim
            .tools()
            .iter()
            .map(|t| {
                let (s, p) = (&t.tool.shape, t.state.position);
                format!(
                    "{} of radius {} at ({}, {}, {}) at t = 0, indentation {:.4e}{}",
                    s.name(),
                    eprop::diagnostics::short(s.radius()),
                    fixed(p[0], 4),
                    fixed(p[1], 4),
                    fixed(p[2], 4),
                    t.state.indentation,
                    if t.tool.live { "; live (eprop serve)" } else { "" }
                )
            })
            .collect(),
        scheme: scheme_name(sim.setup().model.scheme()).to_string(),
        integrator: sim.step_plan().integrator.name().to_string(),
        integrator_why: sim.step_plan().why.clone(),
        measured: measure,
        per_step: sim.step_plan().per_step_phrase(),
        stiffness: sim.stiffness(),
        h: sim.step_plan().h,
        h_bound: sim.step_plan().h_bound,
        dt: sim.dt(),
        dt_bound: sim.dt_bound(),
        substeps: sim.step_plan().per_step,
        steps,
        output: file.display().to_string(),
        output_steps: budget.output_steps,
        output_mib: budget.output_bytes / 1048576.0,
        memory_mib: peak_rss() as f64 / 1048576.0,
        estimated_seconds: per_substep * 1.3 * sim.step_plan().cost * steps as f64,
        output_seconds: eprop::guard::limits::write_seconds(
            &eprop_series::outcome::dir_of(file),
            budget.step_bytes,
            budget.output_steps,
        ),
        realtime,
        realtime_note,
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
        for (k, t) in self.tools.iter().enumerate() {
            writeln!(f, "  tool {}      {t}", k + 1)?;
        }
        writeln!(
            f,
            "  scheme      {}, Euler substep h = {:.4e} (bound {:.4e}), dt = {:.4e} (bound {:.4e}), {} per step",
            self.scheme, self.h, self.h_bound, self.dt, self.dt_bound, self.per_step
        )?;
        writeln!(f, "  integrator  {}: {}", self.integrator, self.integrator_why)?;
        if !self.measured && self.integrator_why.starts_with("auto") {
            writeln!(
                f,
                "              (estimated from the models; `check --measure` runs auto's trial steps under the first loads, as `run` does)"
            )?;
        }
        if let Some(s) = &self.stiffness {
            writeln!(f, "{}", s.describe(12))?;
        }
        let writing = match self.output_seconds {
            Some(w) => format!(" ({} s of it writing the output)", eprop::diagnostics::fixed(w, 3)),
            None => String::new(),
        };
        writeln!(
            f,
            "  run         {} steps, about {} s on one process{writing}; {:.1} MiB of memory",
            self.steps,
            eprop::diagnostics::fixed(self.estimated_seconds + self.output_seconds.unwrap_or(0.0), 3),
            self.memory_mib
        )?;
        if let Some(note) = &self.realtime_note {
            writeln!(f, "  real time   {note}")?;
        }
        if let Some(c) = &self.realtime {
            let ms = |x: f64| eprop::diagnostics::fixed(1e3 * x, 3);
            writeln!(
                f,
                "  real time   u within {:.2e} of euler's at the same dt (the largest relative L2 error over {} steps, at step {}), tool force within {:.2e} of euler's peak; at most {} operator applications per step ({} taken at most); steps of {} / {} / {} ms (median / p99 / worst, one process; CPU {} / {} / {} ms)",
                c.u_error,
                c.steps,
                c.u_error_step,
                c.force_error,
                c.applications_bound,
                c.applications_max,
                ms(c.step_seconds[0]),
                ms(c.step_seconds[1]),
                ms(c.step_seconds[2]),
                ms(c.step_cpu_seconds[0]),
                ms(c.step_cpu_seconds[1]),
                ms(c.step_cpu_seconds[2])
            )?;
        }
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

/// What `eprop export-operator` wrote.
#[derive(Serialize, Debug)]
pub struct ExportReport {
    pub file: String,
    pub rows: usize,
    pub entries: usize,
    pub h: f64,
}

impl std::fmt::Display for ExportReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} rows, {} entries, h = {:.6e}",
            self.file, self.rows, self.entries, self.h
        )
    }
}

/// The compact operator L of a scenario as a CSR matrix over the nodes in input order, with
/// its diagonal (rows of fixed nodes are empty), columns increasing in each row.
pub fn operator_csr(sim: &Simulation, op: &Compact) -> (Vec<i64>, Vec<i64>, Vec<f64>) {
    let n = sim.n_owned();
    let mut rows: Vec<Vec<(i64, f64)>> = vec![vec![]; n];
    for i in 0..n {
        let g = sim.gid()[i] as usize;
        let r = op.coefficients().row(i);
        if r.is_empty() {
            continue;
        }
        let mut diag = 0.0;
        let mut row: Vec<(i64, f64)> = r
            .map(|p| {
                diag -= op.c(p);
                (sim.gid()[op.col()[p] as usize] as i64, op.c(p))
            })
            .collect();
        row.push((g as i64, diag));
        row.sort_by_key(|e| e.0);
        rows[g] = row;
    }
    let mut row_ptr = vec![0i64];
    let (mut col, mut val) = (vec![], vec![]);
    for r in &rows {
        for &(j, v) in r {
            col.push(j);
            val.push(v);
        }
        row_ptr.push(col.len() as i64);
    }
    (row_ptr, col, val)
}

/// Writes a scenario's compact operator L to `output` (HDF5: row_ptr, col, val, and vol, the
/// free nodes' control volumes; attributes h, the substep eprop would use, nodes, dt, the
/// mechanics step, and theta, TR-BDF2's implicit weight), built on one process.
pub fn export_operator(scenario: &Path, output: &Path, overwrite: bool) -> Result<ExportReport> {
    let sc = Scenario::load(scenario)?;
    let _lock = eprop::guard::safety::claim_file(
        output,
        "the operator file (export-operator -o)",
        &sc.inputs(),
        overwrite,
    )?;
    let setup = Setup::new(sc)?;
    let sim = Simulation::new(setup)?;
    let Operator::Compact(op) = &sim.prop().op else {
        bail!(
            "{}: export-operator needs [model] scheme = \"compact\"",
            scenario.display()
        );
    };
    let (row_ptr, col, val) = operator_csr(&sim, op);
    let h = sim.step_plan().h;
    let n = sim.n_owned();
    eprop_series::vtkhdf::write_csr(
        output,
        &row_ptr,
        &col,
        &val,
        &[
            ("h", h),
            ("nodes", n as f64),
            ("dt", sim.dt()),
            ("theta", eprop::propagate::integrate::implicit::THETA),
        ],
    )?;
    // the control volumes of the free nodes (0 on fixed rows), in input order: with L they
    // make the implicit integrator's matrix A = V - theta dt V L
    let mut vol = vec![0.0; n];
    for i in 0..n {
        if sim.active()[i] {
            vol[sim.gid()[i] as usize] = sim.volumes()[i];
        }
    }
    eprop_series::vtkhdf::add_dataset(output, "vol", &vol)?;
    Ok(ExportReport {
        file: output.display().to_string(),
        rows: n,
        entries: col.len(),
        h,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use eprop_io::generate::{box_mesh, BoxCells};

    fn sim(toml: &str) -> Simulation {
        let text = format!("[mesh]\nfile = \"m.msh\"\n[[fixed]]\ngroup = \"xmin\"\n[time]\nsteps = 1\n{toml}");
        let sc = Scenario::parse(Path::new("s.toml"), text).unwrap();
        let mesh = box_mesh([1.0; 3], [3; 3], BoxCells::Tet).unwrap();
        Simulation::new(Setup::with_mesh(sc, mesh).unwrap()).unwrap()
    }

    #[test]
    fn the_exported_operator_is_l_with_its_diagonal_in_input_order() {
        let s = sim("");
        let Operator::Compact(op) = &s.prop().op else {
            unreachable!()
        };
        let (row_ptr, col, val) = operator_csr(&s, op);
        let n = s.n_global();
        assert_eq!(row_ptr.len(), n + 1);
        let fixed = |g: usize| s.setup().fixed[s.local(g as u32).unwrap()];
        for g in 0..n {
            let (a, b) = (row_ptr[g] as usize, row_ptr[g + 1] as usize);
            // fixed rows are empty; every other row sums to zero with a negative diagonal
            assert_eq!(a == b, fixed(g), "row {g}");
            if a == b {
                continue;
            }
            assert!(col[a..b].windows(2).all(|w| w[0] < w[1]));
            let d = col[a..b].iter().position(|&c| c == g as i64).unwrap();
            assert!(val[a + d] < 0.0);
            let sum: f64 = val[a..b].iter().sum();
            assert!(sum.abs() <= 1e-12 * val[a + d].abs(), "row {g}: {sum}");
        }
        // V_i L_ij = V_j L_ji between free nodes (a_ij is symmetric)
        let vol = |g: usize| s.volumes()[s.local(g as u32).unwrap()];
        let at = |i: usize, j: i64| {
            (row_ptr[i]..row_ptr[i + 1])
                .find(|&p| col[p as usize] == j)
                .map(|p| val[p as usize])
        };
        for i in (0..n).filter(|&i| !fixed(i)) {
            for p in row_ptr[i]..row_ptr[i + 1] {
                let j = col[p as usize] as usize;
                if !fixed(j) {
                    let (ij, ji) = (vol(i) * val[p as usize], vol(j) * at(j, i as i64).unwrap());
                    assert!((ij - ji).abs() <= 1e-12 * ij.abs(), "({i}, {j}): {ij} {ji}");
                }
            }
        }
    }

    #[test]
    fn export_needs_the_compact_scheme() {
        let d = tempfile::tempdir().unwrap();
        eprop_io::write_mesh(
            &box_mesh([1.0; 3], [2; 3], BoxCells::Tet).unwrap(),
            &d.path().join("m.msh"),
        )
        .unwrap();
        let sc = d.path().join("s.toml");
        std::fs::write(
            &sc,
            "[mesh]\nfile = \"m.msh\"\nunit = \"m\"\n[model]\nscheme = \"paper\"\n[[fixed]]\ngroup = \"xmin\"\n[time]\nsteps = 1\n",
        )
        .unwrap();
        let e = export_operator(&sc, &d.path().join("op.h5"), false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("needs [model] scheme = \"compact\""), "{e}");
        std::fs::write(
            &sc,
            "[mesh]\nfile = \"m.msh\"\nunit = \"m\"\n[[fixed]]\ngroup = \"xmin\"\n[time]\nsteps = 1\n",
        )
        .unwrap();
        let r = export_operator(&sc, &d.path().join("op.h5"), false).unwrap();
        assert_eq!(r.rows, 27);
        assert!(r
            .to_string()
            .starts_with(&format!("{}: 27 rows", d.path().join("op.h5").display())));
    }
}
