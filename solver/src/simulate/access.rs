//! What a simulation shows of itself: read-only views of its state and setup, for the
//! commands, the tests and the examples. Its state changes only by its own steps
//! (`Simulation::advance`, `restore`, `set_dt`).

use super::contact::ToolRun;
use super::Simulation;
use crate::config::{Load, Setup};
use crate::discretize::geometry::Dual;
use crate::distribute::comm::Comm;
use crate::distribute::field::NodeField;
use crate::distribute::halo::BlockScatter;
use crate::linalg::V3;
use crate::propagate::integrate::Stepper;
use crate::propagate::Propagation;
use eprop_mesh::Mesh;

impl Simulation {
    /// This process's view of the scenario: its local mesh and per-node arrays in local
    /// numbering (loads keep global node indices).
    pub fn setup(&self) -> &Setup {
        &self.setup
    }

    /// The collectives of the processes that share the simulation.
    pub fn comm(&self) -> &dyn Comm {
        self.comm.as_ref()
    }

    /// The whole mesh, on the process that writes the static part of the output (rank 0 of
    /// several; the only process of one).
    pub fn global_mesh(&self) -> Option<&Mesh> {
        self.global.as_ref()
    }

    /// What the summary and the warnings take of the whole mesh (every process calls): its
    /// source, cell count, bounds and reader's warnings, and the input id and position of the
    /// nodes `nodes` (global indices). From the whole mesh where a process holds it; on a
    /// start from the slabs (no process holds it) by reductions over the processes' owned
    /// nodes. Some on rank 0 only.
    pub fn whole_mesh(&self, nodes: &[usize]) -> Option<WholeMesh<'_>> {
        if self.rows.is_none() {
            return self.global.as_ref().map(|m| WholeMesh::of(m, nodes));
        }
        let c = self.comm.as_ref();
        let n_owned = self.numbering.n_owned;
        let points = &self.setup.mesh.points[..n_owned];
        let bounds = crate::distribute::comm::bounds(c, points);
        // each node asked: its owner sends its id (two 32-bit halves) and its position
        let owner: std::collections::HashMap<u64, usize> = nodes
            .iter()
            .filter_map(|&g| {
                self.gid[..n_owned]
                    .iter()
                    .position(|&x| x == g as u64)
                    .map(|l| (g as u64, l))
            })
            .collect();
        let mut mine = Vec::with_capacity(6 * nodes.len());
        for &g in nodes {
            match owner.get(&(g as u64)) {
                Some(&l) => {
                    let id = self.setup.mesh.node_ids[l];
                    let p = points[l];
                    mine.extend([1.0, (id & 0xffff_ffff) as f64, (id >> 32) as f64, p[0], p[1], p[2]]);
                }
                None => mine.extend([0.0; 6]),
            }
        }
        let all = c.all_gather(&mine);
        if c.rank() != 0 {
            return None;
        }
        let found = nodes
            .iter()
            .enumerate()
            .map(|(k, &g)| {
                let w = all
                    .chunks_exact(6 * nodes.len())
                    .map(|r| &r[6 * k..6 * k + 6])
                    .find(|w| w[0] == 1.0)
                    .expect("every node has an owner");
                (g, w[1] as u64 | (w[2] as u64) << 32, [w[3], w[4], w[5]])
            })
            .collect();
        Some(WholeMesh {
            source: &self.setup.mesh.source,
            cells: self.rows.as_ref().map_or(0, |r| r.cells),
            bounds,
            warnings: &self.setup.mesh.warnings,
            nodes: found,
        })
    }

    /// Where the static mesh of an output comes from: every process's slab on a start from
    /// the slabs (`distribute::slabs`: each writes its slab's rows), else the whole mesh on
    /// the process that holds it.
    pub fn static_mesh(&self) -> eprop_series::vtkhdf::StaticMesh<'_> {
        use eprop_series::vtkhdf::StaticMesh;
        match &self.rows {
            Some(rows) => StaticMesh::Slabs(rows),
            None => StaticMesh::Whole(self.global.as_ref()),
        }
    }

    /// Nodes of the whole mesh.
    pub fn n_global(&self) -> usize {
        self.n_global
    }

    /// Global node index of each local node.
    pub fn gid(&self) -> &[u64] {
        &self.gid
    }

    /// This process's block of the global node order (the output's rows).
    pub fn blocks(&self) -> &BlockScatter {
        &self.blocks
    }

    /// The capacities C_i of the operator's rows (the control volumes weighted by young:
    /// `discretize::geometry::capacities`; the control volumes themselves when no tissue
    /// weighs).
    pub fn capacities(&self) -> &[f64] {
        self.capacity.as_deref().unwrap_or(&self.dual.vol)
    }

    /// Control volume of each local node (0 for a node of no cell).
    pub fn volumes(&self) -> &[f64] {
        &self.dual.vol
    }

    /// The dual geometry of the local mesh (what the operator's build left of it).
    pub fn dual(&self) -> &Dual {
        &self.dual
    }

    /// The propagation: the operator, its halo exchange and the potential.
    pub fn prop(&self) -> &Propagation {
        &self.prop
    }

    /// The propagation to drive by hand between steps: the kernel benchmarks (`eprop bench`)
    /// time its substeps and sweeps on the simulation's own operator and halo.
    pub fn prop_mut(&mut self) -> &mut Propagation {
        &mut self.prop
    }

    /// The scenario's tools as the run holds them (their trajectories and states).
    pub fn tools(&self) -> &[ToolRun] {
        &self.tools
    }

    /// The propagation alone, the simulation given up: to drive its operator and potential by
    /// hand (tests and experiments of the integrators and kernels).
    pub fn into_propagation(self) -> Propagation {
        self.prop
    }

    /// The same simulation stepping its propagation with `stepper` instead of the scenario's
    /// integrator (tests and experiments; `step_plan` then reports the new stepper's plan).
    pub fn with_stepper(mut self, stepper: Box<dyn Stepper>) -> Simulation {
        self.stepper = stepper;
        self
    }

    /// Nodes that move: not fixed and with a control volume.
    pub fn active(&self) -> &[bool] {
        &self.active
    }

    /// Displacement of each local node (halo entries as of the last exchange, if any).
    pub fn u(&self) -> &NodeField<V3> {
        &self.u
    }

    /// Velocity of each local node.
    pub fn v(&self) -> &NodeField<V3> {
        &self.v
    }

    /// Propagated potential of each local node.
    pub fn phi(&self) -> &NodeField<V3> {
        &self.prop.phi
    }

    /// The loads with their contact area and force direction resolved.
    pub fn loads(&self) -> &[Load] {
        &self.loads
    }

    /// Owned contact nodes of each load: (local index, probe weight, force weight, source
    /// weight).
    pub fn load_nodes(&self) -> &[Vec<(u32, f64, f64, f64)>] {
        &self.load_local
    }

    /// The mechanics step.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// Steps taken.
    pub fn step(&self) -> u64 {
        self.step
    }

    /// Simulated time: step times dt.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Largest |v| over every process after the last step.
    pub fn max_speed(&self) -> f64 {
        self.max_speed
    }

    /// The stop code (a signal's number) some process's token held before the last step (0:
    /// none), the same on every process.
    pub fn stop_signal(&self) -> i32 {
        self.stop_signal
    }

    /// Control volumes of this process's output block.
    pub fn vol_block(&self) -> &[f64] {
        &self.vol_block
    }

    /// Fixed nodes of the whole mesh.
    pub fn fixed_nodes(&self) -> usize {
        self.fixed_nodes
    }

    /// Nodes of the whole mesh that belong to no cell.
    pub(crate) fn inactive_nodes(&self) -> usize {
        self.inactive_nodes
    }

    /// The mechanics stability bound over every node.
    pub fn dt_bound(&self) -> f64 {
        self.dt_bound
    }

    /// Operator applications of every step this process advanced.
    pub(crate) fn applications(&self) -> &[u32] {
        &self.applications
    }
}

/// What the summary and the warnings take of the whole mesh (`Simulation::whole_mesh`).
pub struct WholeMesh<'a> {
    /// Where it came from.
    pub source: &'a str,
    /// Its volume cells.
    pub cells: usize,
    /// Its bounding box (lowest and highest coordinates).
    pub bounds: ([f64; 3], [f64; 3]),
    /// The reader's warnings about it.
    pub warnings: &'a [String],
    /// The nodes asked for: global index, input id, position.
    nodes: Vec<(usize, u64, [f64; 3])>,
}

impl<'a> WholeMesh<'a> {
    /// The view of a whole mesh a process holds, with the nodes `nodes` (global indices).
    pub fn of(m: &'a Mesh, nodes: &[usize]) -> WholeMesh<'a> {
        WholeMesh {
            source: &m.source,
            cells: m.n_cells(),
            bounds: m.bounds(),
            warnings: &m.warnings,
            nodes: nodes.iter().map(|&g| (g, m.node_ids[g], m.points[g])).collect(),
        }
    }

    /// The input id and position of node `g` (global index), one of the nodes asked for.
    pub fn node(&self, g: usize) -> (u64, [f64; 3]) {
        let &(_, id, p) = self.nodes.iter().find(|n| n.0 == g).expect("a node asked for");
        (id, p)
    }
}
