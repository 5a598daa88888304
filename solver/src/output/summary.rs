//! The summary of a run: what it computed (largest displacement, energy, contact
//! displacements), how (scheme, integrator, steps) and at what cost (time, memory, output).

use crate::config::Stop;
use crate::diagnostics::{fixed, peak_rss, spread};
use crate::distribute::parts::GlobalSizes;
use crate::output::series::Series;
use crate::simulate::{scheme_name, Simulation, WholeMesh};
use eprop_series::vtkhdf::ToolState;
use serde::Serialize;

#[derive(Serialize, Debug, Clone)]
pub struct LoadSummary {
    /// The (first) contact node's id; `contact_nodes` nodes over `contact_area` in all.
    pub node: u64,
    pub contact_nodes: usize,
    pub contact_area: f64,
    pub force: [f64; 3],
    pub displacement: [f64; 3],
}

/// A tool at the end of a run: its shape and its last reading.
#[derive(Serialize, Debug, Clone)]
pub struct ToolSummary {
    pub shape: String,
    pub radius: f64,
    #[serde(flatten)]
    pub state: ToolState,
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
    /// What `substeps` counts, with its unit ("4 substeps", "14 stages").
    pub per_step: String,
    pub h: f64,
    pub h_bound: f64,
    /// Substeps (or stages) per step as planned.
    pub substeps: usize,
    /// Operator applications per step of this run: min, median, max.
    pub applications_per_step: [u32; 3],
    pub dt: f64,
    pub steps: u64,
    /// The steps the run asks for (`--steps`, `[time] steps` or `end`).
    pub steps_asked: u64,
    pub time: f64,
    pub wall_seconds: f64,
    pub setup_seconds: f64,
    /// The step a restarted run continued from.
    pub restarted_from_step: Option<u64>,
    /// A restart found the series complete already: no step was computed or written.
    pub already_complete: bool,
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
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub tools: Vec<ToolSummary>,
    /// Cells inverted at the last output step, and the most at an output step of this run
    /// (since its restart) with that step's time.
    pub inverted_cells: u64,
    pub max_inverted_cells: u64,
    pub max_inverted_time: f64,
    /// Per tool: active nodes inside it at the last output step, and the most at one.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub inside_nodes: Vec<u64>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub max_inside_nodes: Vec<u64>,
    /// The fixed supports' planes, the nodes across them at the last output step and the most
    /// at one.
    pub supports: usize,
    pub across_nodes: u64,
    pub max_across_nodes: u64,
    /// The kinematic tools' energy account at the end: work, stored, dissipated (J).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub energy: Option<[f64; 3]>,
    /// The energy's unit in the printed summary: " J" in the continuum reading, nothing in
    /// the paper's unit-free one.
    #[serde(skip)]
    pub energy_unit: &'static str,
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
        if self.already_complete {
            // nothing ran: no figures of a run that did not happen
            match self.steps > self.steps_asked {
                true => writeln!(
                    f,
                    "  steps       {} to t = {}: the series holds more steps than the {} asked; nothing to do",
                    self.steps,
                    fixed(self.time, 6),
                    self.steps_asked
                )?,
                false => writeln!(
                    f,
                    "  steps       {} to t = {}: the series was complete already; nothing to do",
                    self.steps,
                    fixed(self.time, 6)
                )?,
            }
            return write!(f, "  output      {} ({} steps)", self.output, self.output_steps);
        }
        writeln!(
            f,
            "  scheme      {}, Euler substep h = {:.4e} (bound {:.4e}), {} per step, dt = {:.4e}",
            self.scheme, self.h, self.h_bound, self.per_step, self.dt
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
                "  steps       {} to t = {} (restarted at step {k})",
                self.steps,
                fixed(self.time, 6)
            )?,
            None => writeln!(f, "  steps       {} to t = {}", self.steps, fixed(self.time, 6))?,
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
            "  max |u|     {:.6e} at node {} ({}, {}, {})",
            self.max_displacement,
            self.max_displacement_node,
            fixed(self.max_displacement_at[0], 4),
            fixed(self.max_displacement_at[1], 4),
            fixed(self.max_displacement_at[2], 4)
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
                "  load {}      {at}, F = ({}, {}, {}), u = ({:.5e}, {:.5e}, {:.5e})",
                k + 1,
                fixed(l.force[0], 4),
                fixed(l.force[1], 4),
                fixed(l.force[2], 4),
                l.displacement[0] + 0.0, // + 0.0: never -0
                l.displacement[1] + 0.0,
                l.displacement[2] + 0.0
            )?;
        }
        for (k, ts) in self.tools.iter().enumerate() {
            let t = &ts.state;
            writeln!(
                f,
                "  tool {}      {} r = {} at ({}, {}, {}), indentation {:.4e}, {} contact nodes (area {:.4e}), F = ({:.4e}, {:.4e}, {:.4e})",
                k + 1,
                ts.shape,
                crate::diagnostics::short(ts.radius),
                fixed(t.position[0], 4),
                fixed(t.position[1], 4),
                fixed(t.position[2], 4),
                t.indentation,
                t.contact_nodes,
                t.contact_area,
                t.force[0] + 0.0, // + 0.0: never -0
                t.force[1] + 0.0,
                t.force[2] + 0.0
            )?;
        }
        if self.max_inverted_cells > 0 {
            writeln!(
                f,
                "  inverted    {} cells (max {} at t = {})",
                self.inverted_cells,
                self.max_inverted_cells,
                fixed(self.max_inverted_time, 6)
            )?;
        } else {
            writeln!(f, "  inverted    0 cells")?;
        }
        if !self.inside_nodes.is_empty() {
            let now: u64 = self.inside_nodes.iter().sum();
            let most: u64 = self.max_inside_nodes.iter().sum();
            let per = match self.inside_nodes.len() {
                1 => String::new(),
                _ => format!(
                    " ({})",
                    self.inside_nodes
                        .iter()
                        .enumerate()
                        .map(|(k, n)| format!("tool {}: {n}", k + 1))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            };
            match most {
                0 => writeln!(f, "  inside      {now} nodes in tools{per}")?,
                _ => writeln!(
                    f,
                    "  inside      {now} nodes in tools{per} (at most {most} at an output step)"
                )?,
            }
        }
        self.supports_and_work(f)?;
        for w in &self.warnings {
            writeln!(f, "  warning     {w}")?;
        }
        write!(f, "  output      {} ({} steps)", self.output, self.output_steps)
    }
}

impl Summary {
    /// The summary's lines on supports (nodes across) and on the kinematic tools' energy account.
    fn supports_and_work(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.supports > 0 {
            match self.max_across_nodes {
                0 => writeln!(f, "  across      0 nodes through supports")?,
                m => writeln!(
                    f,
                    "  across      {} nodes through supports (at most {m} at an output step)",
                    self.across_nodes
                )?,
            }
        }
        if let Some([w, s, d]) = self.energy {
            let gap = w - (s + d);
            let rel = if w != 0.0 { gap / w.abs() } else { 0.0 };
            writeln!(
            f,
            "  work        tools' work {w:.6e}{j} = stored {s:.6e}{j} + dissipated {d:.6e}{j} (balance {rel:.1e} of the work)",
            j = self.energy_unit
        )?;
        }
        Ok(())
    }
}

/// The seconds a run took and where it started from.
pub struct Timing {
    /// From the start to the first step (reading, setup, static output).
    pub setup_seconds: f64,
    /// From the first step to the last (output included).
    pub wall_seconds: f64,
    /// The step a restarted run continued from.
    pub restarted_from_step: Option<u64>,
    /// A restart found the series complete already (no step was computed).
    pub already_complete: bool,
    /// Peak resident memory of rank 0 once the parts were sent (distributed runs).
    pub rank0_scatter_peak: u64,
}

/// The reader's warnings about the mesh and the simulation's about its nodes.
pub fn warnings(sim: &Simulation, mesh: &WholeMesh) -> Vec<String> {
    let mut warnings = mesh.warnings.to_vec();
    if sim.inactive_nodes() > 0 {
        warnings.push(format!(
            "{} node(s) belong to no cell and stay at rest",
            sim.inactive_nodes()
        ));
    }
    warnings
}

/// The summary of a finished run, on the process that holds the whole mesh (rank 0); every
/// process calls (reductions inside).
pub fn summarize(
    sim: &Simulation,
    sizes: &GlobalSizes,
    series: &Series,
    t: Timing,
    run_warnings: Vec<String>,
) -> Option<Summary> {
    let (umax, imax) = sim.max_displacement();
    let total = sim.total_energy();
    let probes = sim.probes();
    let halo_wait = sim.comm().max(sim.prop.halo.wait_seconds());
    let peak = sim.comm().max(peak_rss() as f64);
    let mesh = sim.whole_mesh(&[imax as usize])?;
    let mut warnings = warnings(sim, &mesh);
    warnings.extend(run_warnings);
    if let Stop::Equilibrium { tol, .. } = sim.setup().time.stop {
        let residuals = sim.steady_residuals();
        if sim.max_speed() >= tol {
            warnings.push(format!(
                "equilibrium not reached after {} steps (max |v| = {:.3e} > {tol:e})",
                sim.step(),
                sim.max_speed()
            ));
        } else if let Some(r) = residuals.filter(|r| !r.within(tol)) {
            warnings.push(format!(
                "equilibrium not reached after {} steps (max |v| = {:.3e}, but the steady equations' relative residuals are {:.3e} (potential) and {:.3e} (mechanics), not both <= {tol:e})",
                sim.step(),
                sim.max_speed(),
                r.potential,
                r.mechanics
            ));
        }
    }
    let (max_node, max_at) = mesh.node(imax as usize);
    let plan = sim.step_plan();
    let (append_first, append_last) = series.append_medians();
    let n = sizes.nodes;
    Some(Summary {
        scenario: sim.setup().scenario.path.display().to_string(),
        mesh: mesh.source.to_string(),
        nodes: n,
        cells: mesh.cells,
        processes: sim.comm().size(),
        fixed_nodes: sim.fixed_nodes(),
        scheme: scheme_name(sim.setup().model.scheme()).to_string(),
        integrator: plan.integrator.name().to_string(),
        integrator_why: plan.why.clone(),
        per_step: plan.per_step_phrase(),
        h: plan.h,
        h_bound: plan.h_bound,
        substeps: plan.per_step,
        applications_per_step: spread(sim.applications()),
        dt: sim.dt(),
        steps: sim.step(),
        steps_asked: sim.max_steps(),
        time: sim.time(),
        wall_seconds: t.wall_seconds,
        setup_seconds: t.setup_seconds,
        output_seconds: series.seconds(),
        output_append_first100_median_s: append_first,
        output_append_last100_median_s: append_last,
        halo_wait_seconds: halo_wait,
        // + 0.0: never -0 (an empty sum is -0)
        node_substeps_per_second: (n as f64 * sim.applications().iter().map(|&a| a as f64).sum::<f64>())
            / t.wall_seconds.max(1e-12)
            + 0.0,
        restarted_from_step: t.restarted_from_step,
        already_complete: t.already_complete,
        peak_memory_mib: peak / 1048576.0,
        rank0_scatter_peak_mib: t.rank0_scatter_peak as f64 / 1048576.0,
        max_displacement: umax,
        max_displacement_node: max_node,
        max_displacement_at: max_at,
        total_energy: total,
        max_speed: sim.max_speed(),
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
        tools: sim
            .tools
            .iter()
            .map(|t| ToolSummary {
                shape: t.tool.shape.name().to_string(),
                radius: t.tool.shape.radius(),
                state: t.state,
            })
            .collect(),
        inverted_cells: series.folds.last.inverted,
        max_inverted_cells: series.folds.most,
        max_inverted_time: series.folds.most_time,
        inside_nodes: series.folds.last.inside.clone(),
        max_inside_nodes: series.folds.most_inside.clone(),
        supports: sim.setup().supports.len(),
        across_nodes: series.folds.last.across,
        max_across_nodes: series.folds.most_across,
        energy: sim.tool_energy().map(|e| [e.work, e.stored, e.dissipated]),
        energy_unit: match sim.setup().model.reading {
            crate::config::Reading::Continuum => " J",
            crate::config::Reading::Paper => "",
        },
        output: series.path().display().to_string(),
        output_steps: series.steps_written(),
        warnings,
    })
}
