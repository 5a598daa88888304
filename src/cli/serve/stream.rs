//! The surface stream of `eprop serve` (protocol version 2): the outer surface of the whole
//! mesh (`export::Surface`, the surface `eprop export --surface` writes) and, at the steps a
//! streaming client wants, its nodes' displacements gathered on rank 0 in the surface's order.

use super::protocol::Topology;
use crate::cli::export::Surface;
use anyhow::{bail, Result};
use eprop::simulate::Simulation;

/// The topology a streaming client gets: the surface of the whole mesh with its rest
/// coordinates (on the process that holds the whole mesh: rank 0).
pub fn topology(sim: &Simulation) -> Option<Topology> {
    let mesh = sim.global_mesh()?;
    let s = Surface::of(mesh);
    let rest = s.nodes.iter().flat_map(|&g| mesh.points[g as usize]).collect();
    Some(Topology {
        rest,
        nodes: s.nodes,
        triangles: s.triangles,
    })
}

/// Which owned nodes of each process are surface nodes, and where rank 0 puts their values.
pub struct Gather {
    /// (surface index, local index) of this process's owned surface nodes.
    mine: Vec<(u32, u32)>,
    /// Rank 0: the surface index of each node in the order the processes' values arrive.
    order: Vec<u32>,
    n: usize,
}

impl Gather {
    /// Every process calls (collective); `nodes` are the surface's global node ids, in
    /// increasing order, on rank 0.
    pub fn new(sim: &Simulation, nodes: Option<&[u32]>) -> Result<Gather> {
        let c = sim.comm();
        let mut n = [nodes.map_or(0, |v| v.len()) as f64];
        c.broadcast(0, &mut n);
        let mut ids: Vec<f64> = match nodes {
            Some(v) if c.rank() == 0 => v.iter().map(|&g| f64::from(g)).collect(),
            _ => vec![0.0; n[0] as usize],
        };
        c.broadcast(0, &mut ids);
        let mut mine: Vec<(u32, u32)> = sim.gid()[..sim.n_owned()]
            .iter()
            .enumerate()
            .filter_map(|(i, &g)| {
                ids.binary_search_by(|x| x.total_cmp(&(g as f64)))
                    .ok()
                    .map(|j| (j as u32, i as u32))
            })
            .collect();
        mine.sort_unstable();
        let mut counts = vec![0usize; c.size()];
        counts[0] = mine.len();
        let send: Vec<f64> = mine.iter().map(|&(j, _)| f64::from(j)).collect();
        let order: Vec<u32> = c.all_to_all(&send, &counts).iter().map(|&j| j as u32).collect();
        if c.rank() == 0 && order.len() != ids.len() {
            bail!(
                "internal: {} of the {} surface nodes are owned by a process",
                order.len(),
                ids.len()
            );
        }
        Ok(Gather {
            mine,
            order,
            n: ids.len(),
        })
    }

    /// The surface nodes' displacements (3 per node, in the surface's order) on rank 0,
    /// copied bit for bit from their owners; every process calls (collective).
    pub fn collect(&self, sim: &Simulation) -> Option<Vec<f64>> {
        let c = sim.comm();
        let u = sim.u().owned();
        let send: Vec<f64> = self.mine.iter().flat_map(|&(_, i)| u[i as usize]).collect();
        let mut counts = vec![0usize; c.size()];
        counts[0] = send.len();
        let got = c.all_to_all(&send, &counts);
        if c.rank() != 0 {
            return None;
        }
        let mut out = vec![0.0; 3 * self.n];
        for (&j, v) in self.order.iter().zip(got.chunks_exact(3)) {
            out[3 * j as usize..3 * j as usize + 3].copy_from_slice(v);
        }
        Some(out)
    }
}
