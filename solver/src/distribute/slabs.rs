//! The distributed start from a VTKHDF mesh: no process holds the whole mesh or its graph.
//!
//! - `read`: every process reads its slab of the file (`eprop_series::vtkhdf::read_slab`,
//!   MPI-IO): a contiguous share of the cells and of the points.
//! - `cells_to_owners`: each cell goes to the owner of every one of its nodes' slabs, so each
//!   process gets every cell that touches a node of its slab (the one layer of halo cells the
//!   median dual needs), in increasing global cell order.
//! - `node_graph`: the rows of the node graph of the process's slab of nodes, built from those
//!   cells (the same rows as `eprop_partition::node_graph` of the whole mesh), as the
//!   `ptscotch::Slab` that PT-Scotch's ParMETIS V3 layer splits.
//! - `split`: PT-Scotch on several processes; METIS on one process, and as the fallback where
//!   PT-Scotch is absent or fails (then the graph is gathered on every process: a fallback of
//!   size N).
//! - `quality`: the split's edge cut, imbalance, halo and neighbours, as
//!   `eprop_partition::quality` measures them on the whole graph, from the slabs (the parts of
//!   the neighbours in other slabs asked of their owners).

use super::checks;
use super::comm::{Comm, Handle, Mpi};
use super::parts::{GlobalSizes, Part, StableHash};
use super::ptscotch::{self, Slab};
use crate::config::Setup;
use anyhow::{anyhow, bail, Result};
use eprop_mesh::CellKind;
use eprop_mesh::Mesh;
use eprop_partition::Plan;
use eprop_series::vtkhdf::{block, read_slab, MeshSlab};
use std::path::Path;

/// Reads this process's slab of the VTKHDF mesh at `path` (every process of `world` calls);
/// a failure on any process is an error on every one.
pub fn read(world: Option<&dyn Comm>, path: &Path) -> Result<MeshSlab> {
    let slab = read_slab(path, world.and_then(|w| w.handle()).map(Handle::communicator));
    let Some(w) = world else {
        return slab;
    };
    if w.max(f64::from(u8::from(slab.is_err()))) > 0.0 {
        return match slab {
            Err(e) => Err(e),
            Ok(_) => Err(super::parts::ReportedElsewhere.into()),
        };
    }
    slab
}

/// The slab boundaries of `n` things on `size` processes (`size + 1` entries).
pub fn cuts(n: usize, size: usize) -> Vec<usize> {
    (0..=size).map(|r| block(n, size, r)).collect()
}

/// The process whose slab (of `cuts`) holds `g`.
fn owner(cuts: &[usize], g: usize) -> usize {
    cuts.partition_point(|&c| c <= g) - 1
}

/// Cells with their global indices (`ids`), global node indices in `conn`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cells {
    pub ids: Vec<u64>,
    pub kinds: Vec<CellKind>,
    pub offsets: Vec<usize>,
    pub conn: Vec<u32>,
    pub tags: Vec<i32>,
}

impl Cells {
    pub fn len(&self) -> usize {
        self.ids.len()
    }
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
    pub fn cell(&self, c: usize) -> &[u32] {
        &self.conn[self.offsets[c]..self.offsets[c + 1]]
    }
}

/// The all-to-all of `u32` streams: `send` holds the stream for process q at
/// `counts[0] + ... + counts[q - 1]`; the streams received, in process order, and their
/// lengths.
fn all_to_all_u32(world: &Handle, send: &[u32], counts: &[usize]) -> (Vec<u32>, Vec<usize>) {
    use mpi::datatype::{Partition, PartitionMut};
    use mpi::traits::*;
    let c = world.communicator();
    let sc: Vec<i32> = counts
        .iter()
        .map(|&n| i32::try_from(n).expect("a message of more than 2^31 values"))
        .collect();
    let mut rc = vec![0i32; sc.len()];
    c.all_to_all_into(&sc[..], &mut rc[..]);
    let (sd, rd) = (super::comm::displacements(&sc), super::comm::displacements(&rc));
    let mut out = vec![0u32; rc.iter().map(|&n| n as usize).sum()];
    {
        let sp = Partition::new(send, &sc[..], &sd[..]);
        let mut rp = PartitionMut::new(&mut out[..], &rc[..], &rd[..]);
        c.all_to_all_varcount_into(&sp, &mut rp);
    }
    (out, rc.iter().map(|&n| n as usize).collect())
}

/// Every cell that touches a node of this process's slab of nodes (every process of `world`
/// calls; one process keeps its slab's cells). A cell travels as its global index, tag, VTK
/// type and node count, and its nodes.
pub fn cells_to_owners(slab: &MeshSlab, world: Option<&Handle>) -> Result<Cells> {
    use mpi::topology::Communicator;
    let size = world.map_or(1, |w| w.communicator().size() as usize);
    let node_cuts = cuts(slab.nodes, size);
    send_cells(slab, world, |g| owner(&node_cuts, g as usize))
}

/// Every cell of the slab sent to the distinct processes `dest` names for its nodes; the
/// cells received, in increasing global order.
fn send_cells(slab: &MeshSlab, world: Option<&Handle>, dest: impl Fn(u32) -> usize) -> Result<Cells> {
    use mpi::topology::Communicator;
    let size = world.map_or(1, |w| w.communicator().size() as usize);
    if u32::try_from(slab.cells).is_err() {
        bail!("{} cells do not fit the 32-bit cell messages", slab.cells);
    }
    let owners_of = |c: usize, out: &mut Vec<usize>| {
        out.clear();
        out.extend(slab.cell(c).iter().map(|&g| dest(g)));
        out.sort_unstable();
        out.dedup();
    };
    let mut counts = vec![0usize; size];
    let mut buf = Vec::with_capacity(8);
    for c in 0..slab.n_cells() {
        owners_of(c, &mut buf);
        for &q in &buf {
            counts[q] += 3 + slab.cell(c).len();
        }
    }
    let mut at: Vec<usize> = counts
        .iter()
        .scan(0, |s, &n| {
            let a = *s;
            *s += n;
            Some(a)
        })
        .collect();
    let mut send = vec![0u32; counts.iter().sum()];
    for c in 0..slab.n_cells() {
        owners_of(c, &mut buf);
        let nodes = slab.cell(c);
        for &q in &buf {
            let head = [
                (slab.cell_start + c) as u32,
                slab.cell_tags[c] as u32,
                (u32::from(slab.kinds[c].vtk_type()) << 8) | nodes.len() as u32,
            ];
            send[at[q]..at[q] + 3].copy_from_slice(&head);
            send[at[q] + 3..at[q] + 3 + nodes.len()].copy_from_slice(nodes);
            at[q] += 3 + nodes.len();
        }
    }
    let got = match world {
        Some(w) if size > 1 => all_to_all_u32(w, &send, &counts).0,
        _ => send,
    };
    let mut cells = Cells {
        offsets: vec![0],
        ..Default::default()
    };
    let mut i = 0;
    while i < got.len() {
        let (id, tag, code) = (got[i], got[i + 1], got[i + 2]);
        let n = (code & 0xff) as usize;
        let kind = eprop_io::vtk::volume_cell(i64::from(code >> 8))
            .map(|(k, _)| k)
            .ok_or_else(|| anyhow!("internal: a cell message names VTK type {}", code >> 8))?;
        cells.ids.push(u64::from(id));
        cells.tags.push(tag as i32);
        cells.kinds.push(kind);
        cells.conn.extend_from_slice(&got[i + 3..i + 3 + n]);
        cells.offsets.push(cells.conn.len());
        i += 3 + n;
    }
    Ok(cells)
}

/// The rows `lo..hi` of the node graph (neighbours in increasing global order) from `cells`,
/// which must hold every cell that touches one of those nodes; `vtxdist` the slab boundaries
/// of every process.
pub fn node_graph(cells: &Cells, vtxdist: &[usize], lo: usize, hi: usize) -> Result<Slab> {
    let rows = hi - lo;
    let mut ptr = vec![0usize; rows + 1];
    for &g in &cells.conn {
        let g = g as usize;
        if (lo..hi).contains(&g) {
            ptr[g - lo + 1] += 1;
        }
    }
    for i in 0..rows {
        ptr[i + 1] += ptr[i];
    }
    let mut fill = ptr.clone();
    let mut inc = vec![0u32; ptr[rows]];
    for c in 0..cells.len() {
        for &g in cells.cell(c) {
            let g = g as usize;
            if (lo..hi).contains(&g) {
                inc[fill[g - lo]] = c as u32;
                fill[g - lo] += 1;
            }
        }
    }
    drop(fill);
    let as_u32 = |x: usize| u32::try_from(x).map_err(|_| anyhow!("{x} does not fit the graph's 32-bit integers"));
    let mut xadj = Vec::with_capacity(rows + 1);
    xadj.push(0u32);
    let mut adj: Vec<u32> = Vec::new();
    let mut buf = Vec::new();
    for i in 0..rows {
        buf.clear();
        for &c in &inc[ptr[i]..ptr[i + 1]] {
            buf.extend(cells.cell(c as usize).iter().copied().filter(|&j| j as usize != lo + i));
        }
        buf.sort_unstable();
        buf.dedup();
        adj.extend_from_slice(&buf);
        xadj.push(as_u32(adj.len())?);
    }
    let weights = xadj.windows(2).map(|w| w[1] - w[0] + 1).collect();
    Ok(Slab {
        vtxdist: vtxdist.iter().map(|&x| as_u32(x)).collect::<Result<_>>()?,
        xadj,
        adj,
        weights,
    })
}

/// Asks the owners (by `cuts`) of the sorted global ids `ids` for `width` words each
/// (`answer(g)`, which the owner of g computes); the answers in the order of `ids` (every
/// process of `world` calls; one process answers itself).
fn lookup(
    ids: &[u32],
    cuts: &[usize],
    width: usize,
    world: Option<&Handle>,
    answer: impl Fn(u32, &mut Vec<u32>),
) -> Vec<u32> {
    let Some(w) = world else {
        let mut out = Vec::with_capacity(ids.len() * width);
        ids.iter().for_each(|&g| answer(g, &mut out));
        return out;
    };
    let size = cuts.len() - 1;
    let mut counts = vec![0usize; size];
    ids.iter().for_each(|&j| counts[owner(cuts, j as usize)] += 1);
    // sorted ids are in owner order (slabs are contiguous); each owner answers in the order asked
    let (asked, asked_counts) = all_to_all_u32(w, ids, &counts);
    let mut answers = Vec::with_capacity(asked.len() * width);
    asked.iter().for_each(|&g| answer(g, &mut answers));
    let back: Vec<usize> = asked_counts.iter().map(|&n| n * width).collect();
    all_to_all_u32(w, &answers, &back).0
}

/// A process's share of the mesh after the split: every cell that touches a node it owns
/// (one layer of halo cells), and the nodes of those cells: its owned nodes in increasing
/// global order, then the halo nodes in increasing global order, with their coordinates and
/// input ids.
#[derive(Clone, Debug, Default)]
pub struct Local {
    pub cells: Cells,
    /// Global index of each local node.
    pub global: Vec<u32>,
    pub n_owned: usize,
    /// The part (process) that owns each local node.
    pub part: Vec<u32>,
    pub points: Vec<[f64; 3]>,
    pub node_ids: Vec<u64>,
}

/// Moves cells and coordinates to their owners (every process of `world` calls, one part per
/// process): `part` the part of each node of this process's slab (`split`). The parts of the
/// cells' nodes are asked of the slabs' owners, each cell goes to every part among its nodes,
/// and the coordinates of the nodes of a process's cells come from the slabs that hold them.
pub fn redistribute(slab: &MeshSlab, part: &[u32], world: Option<&Handle>) -> Result<Local> {
    use mpi::topology::Communicator;
    let (rank, size) = world.map_or((0, 1), |w| {
        (w.communicator().rank() as usize, w.communicator().size() as usize)
    });
    let node_cuts = cuts(slab.nodes, size);
    let lo = node_cuts[rank] as u32;
    if part.len() != slab.points.len() || part.iter().any(|&p| p as usize >= size) {
        bail!("internal: a part per node of the slab, one part per process");
    }
    // the parts of the nodes of this slab's cells
    let mut ids: Vec<u32> = slab.conn.clone();
    ids.sort_unstable();
    ids.dedup();
    let parts = lookup(&ids, &node_cuts, 1, world, |g, out| out.push(part[(g - lo) as usize]));
    let cells = send_cells(slab, world, |g| parts[ids.binary_search(&g).expect("asked")] as usize)?;
    drop((ids, parts));
    // the nodes of the cells received: parts, coordinates and ids from the slabs
    let mut ids: Vec<u32> = cells.conn.clone();
    ids.sort_unstable();
    ids.dedup();
    let words = lookup(&ids, &node_cuts, 9, world, |g, out| {
        let k = (g - lo) as usize;
        out.push(part[k]);
        for x in slab.points[k] {
            let b = x.to_bits();
            out.extend([b as u32, (b >> 32) as u32]);
        }
        let i = slab.node_ids[k];
        out.extend([i as u32, (i >> 32) as u32]);
    });
    let word = |w: &[u32]| u64::from(w[0]) | (u64::from(w[1]) << 32);
    let (mut owned, mut halo) = (Vec::new(), Vec::new());
    for (k, w) in words.chunks_exact(9).enumerate() {
        match w[0] as usize == rank {
            true => owned.push(k),
            false => halo.push(k),
        }
    }
    let n_owned = owned.len();
    let order: Vec<usize> = owned.into_iter().chain(halo).collect();
    let pick = |k: usize| &words[9 * k..9 * k + 9];
    Ok(Local {
        global: order.iter().map(|&k| ids[k]).collect(),
        n_owned,
        part: order.iter().map(|&k| pick(k)[0]).collect(),
        points: order
            .iter()
            .map(|&k| {
                let w = pick(k);
                [1, 3, 5].map(|a| f64::from_bits(word(&w[a..a + 2])))
            })
            .collect(),
        node_ids: order.iter().map(|&k| word(&pick(k)[7..9])).collect(),
        cells,
    })
}

/// How the slabs were split.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Splitter {
    Ptscotch,
    Metis,
}

/// The part (in `0..nparts`) of each row of this process's slab of the graph (every process
/// of `world` calls): PT-Scotch on several processes where the build has it, else METIS on
/// the gathered graph (one process: the slab is the whole graph).
pub fn split(graph: &Slab, nparts: usize, world: Option<&dyn Comm>) -> Result<(Vec<u32>, Splitter)> {
    let size = world.map_or(1, |w| w.size());
    let n = *graph.vtxdist.last().unwrap_or(&0) as usize;
    if nparts == 0 || nparts > n {
        bail!("{nparts} parts of {n} nodes; fix: ask for 1 to {n} parts");
    }
    if size > 1 && ptscotch::AVAILABLE {
        let w = world.expect("several processes have a communicator");
        let handle = w.handle().ok_or_else(|| anyhow!("internal: a job without MPI"))?;
        let own = handle.duplicate();
        let mine = ptscotch::part_kway(graph, nparts, own.raw());
        let mut count = vec![0.0f64; nparts];
        if let Ok(p) = &mine {
            p.iter().for_each(|&q| count[q as usize] += 1.0);
        }
        let failed = w.max(f64::from(u8::from(mine.is_err())));
        let total = w.all_gather(&count);
        let empty = (0..nparts).find(|&q| (0..size).map(|r| total[r * nparts + q]).sum::<f64>() == 0.0);
        match (failed > 0.0, empty) {
            (false, None) => return Ok((mine.unwrap_or_default(), Splitter::Ptscotch)),
            (true, _) => tracing::warn!(
                "PT-Scotch failed{}: the nodes are split by METIS",
                mine.err().map(|e| format!(": {e}")).unwrap_or_default()
            ),
            (false, Some(q)) => tracing::warn!("PT-Scotch left part {q} empty: the nodes are split by METIS"),
        }
    } else if size > 1 {
        tracing::warn!("this build has no PT-Scotch (see build.rs): the nodes are split by METIS");
    }
    // METIS on the whole graph, gathered where it is in slabs
    let (xadj, adj) = match world.filter(|_| size > 1) {
        None => (
            graph.xadj.iter().map(|&x| x as usize).collect::<Vec<_>>(),
            graph.adj.clone(),
        ),
        Some(w) => {
            let degrees: Vec<f64> = graph.xadj.windows(2).map(|d| f64::from(d[1] - d[0])).collect();
            let (deg, _) = w.all_gather_var(&degrees);
            let local: Vec<f64> = graph.adj.iter().map(|&j| f64::from(j)).collect();
            let (adj, _) = w.all_gather_var(&local);
            let mut xadj = vec![0usize];
            deg.iter().for_each(|&d| xadj.push(xadj[xadj.len() - 1] + d as usize));
            (xadj, adj.iter().map(|&j| j as u32).collect())
        }
    };
    let weights = eprop_partition::degree_weights(&xadj);
    let part =
        eprop_partition::partition_weighted(&xadj, &adj, nparts, eprop_partition::Method::Metis, Some(&weights))?;
    let r = world.map_or(0, |w| w.rank());
    let (lo, hi) = (graph.vtxdist[r] as usize, graph.vtxdist[r + 1] as usize);
    Ok((part[lo..hi].to_vec(), Splitter::Metis))
}

/// The parts of the neighbours of this slab's rows that lie in other slabs (every process of
/// `world` calls): `(ids, parts)`, the ids sorted.
fn remote_parts(graph: &Slab, part: &[u32], rank: usize, world: Option<&Handle>) -> (Vec<u32>, Vec<u32>) {
    if world.is_none() {
        return (vec![], vec![]);
    }
    let cuts: Vec<usize> = graph.vtxdist.iter().map(|&x| x as usize).collect();
    let (lo, hi) = (cuts[rank] as u32, cuts[rank + 1] as u32);
    let mut ids: Vec<u32> = graph.adj.iter().copied().filter(|&j| j < lo || j >= hi).collect();
    ids.sort_unstable();
    ids.dedup();
    let parts = lookup(&ids, &cuts, 1, world, |g, out| out.push(part[(g - lo) as usize]));
    (ids, parts)
}

/// The quality of a split from the slabs (every process of `world` calls; every process gets
/// the whole report): what `eprop_partition::quality` gives for the whole graph.
pub fn quality(graph: &Slab, part: &[u32], nparts: usize, world: Option<&dyn Comm>) -> eprop_partition::Quality {
    let rank = world.map_or(0, |w| w.rank());
    let lo = graph.vtxdist[rank];
    let (ids, parts) = remote_parts(graph, part, rank, world.and_then(|w| w.handle()));
    let part_of = |j: u32| -> u32 {
        match j.checked_sub(lo).map(|k| k as usize).filter(|&k| k < part.len()) {
            Some(k) => part[k],
            None => parts[ids.binary_search(&j).expect("every remote neighbour was asked")],
        }
    };
    let mut cut = 0i128;
    let mut owned = vec![0.0f64; nparts];
    let mut halo = vec![0.0f64; nparts];
    let mut touches = vec![0.0f64; nparts * nparts];
    let mut seen = Vec::new();
    for (i, &pi) in part.iter().enumerate() {
        owned[pi as usize] += 1.0;
        seen.clear();
        let g = lo + i as u32;
        for &j in &graph.adj[graph.xadj[i] as usize..graph.xadj[i + 1] as usize] {
            let pj = part_of(j);
            if pj != pi {
                cut += i128::from(j > g);
                seen.push(pj);
                touches[pi as usize * nparts + pj as usize] = 1.0;
            }
        }
        // this node is a halo node of every other part among its neighbours'
        seen.sort_unstable();
        seen.dedup();
        seen.iter().for_each(|&p| halo[p as usize] += 1.0);
    }
    let (cut, owned, halo, touches) = match world {
        Some(w) => {
            let sum = |v: &[f64]| -> Vec<f64> {
                let all = w.all_gather(v);
                (0..v.len())
                    .map(|k| all.iter().skip(k).step_by(v.len()).sum())
                    .collect()
            };
            (w.sum_i128(cut), sum(&owned), sum(&halo), w.max_each(&touches))
        }
        None => (cut, owned, halo, touches),
    };
    let n: f64 = owned.iter().sum();
    let mean = n / nparts as f64;
    eprop_partition::Quality {
        edge_cut: cut as usize,
        imbalance: owned.iter().copied().fold(0.0, f64::max) / mean,
        owned: owned.iter().map(|&x| x as usize).collect(),
        halo: halo.iter().map(|&x| x as usize).collect(),
        neighbours: (0..nparts)
            .map(|p| {
                touches[p * nparts..(p + 1) * nparts]
                    .iter()
                    .filter(|&&t| t > 0.0)
                    .count()
            })
            .collect(),
    }
}

/// The collectives of a local resolution (`config::local::Reduce`) on a `Comm`, and the halo
/// exchange of the plan.
struct Reducer<'a>(&'a dyn Comm, &'a super::halo::Halo);

impl crate::config::local::Reduce for Reducer<'_> {
    fn max(&self, x: f64) -> f64 {
        self.0.max(x)
    }
    fn max_each(&self, x: &[f64]) -> Vec<f64> {
        self.0.max_each(x)
    }
    fn all_gather_var(&self, x: &[f64]) -> Vec<f64> {
        self.0.all_gather_var(x).0
    }
    fn exchange(&self, x: &mut [f64]) {
        self.1.exchange(x, 1);
    }
}

/// A process's plan from its share of the mesh after `redistribute`: `Plan::new` on the local
/// nodes numbered by increasing global index (so its halo and its send and receive lists come
/// in global order, as on the whole mesh), owned nodes ordered by reverse Cuthill-McKee on
/// the local graph; its ids then mapped back to global ones.
pub fn plan_of(local: &Local, rank: usize) -> Plan {
    let mut sorted = local.global.clone();
    sorted.sort_unstable();
    let n = sorted.len();
    let index = |g: u32| sorted.binary_search(&g).expect("a local node") as u32;
    let mut part = vec![0u32; n];
    for (l, &g) in local.global.iter().enumerate() {
        part[index(g) as usize] = local.part[l];
    }
    let conn: Vec<u32> = local.cells.conn.iter().map(|&g| index(g)).collect();
    let (xadj, adj) = eprop_partition::node_graph(n, &local.cells.offsets, &conn);
    let keys = eprop_partition::rcm_keys(&xadj, &adj);
    drop((xadj, adj));
    let mut plan = Plan::new(n, &local.cells.offsets, &conn, &part, rank, Some(&keys));
    for g in plan.numbering.global.iter_mut() {
        *g = sorted[*g as usize];
    }
    for c in plan.cells.iter_mut() {
        *c = local.cells.ids[*c as usize] as u32;
    }
    plan
}

/// The local mesh of a plan (its numbering: owned, then halo nodes) from the share.
fn local_mesh(local: &Local, plan: &Plan, source: &str) -> Mesh {
    let at: std::collections::HashMap<u32, u32> =
        local.global.iter().enumerate().map(|(k, &g)| (g, k as u32)).collect();
    let ids = &plan.numbering.global;
    let to_plan: std::collections::HashMap<u32, u32> = ids.iter().enumerate().map(|(l, &g)| (g, l as u32)).collect();
    let mut m = Mesh::new(source);
    m.points = ids.iter().map(|g| local.points[at[g] as usize]).collect();
    m.node_ids = ids.iter().map(|g| local.node_ids[at[g] as usize]).collect();
    let cells = &local.cells;
    m.conn.reserve(cells.conn.len());
    let mut buf = Vec::with_capacity(8);
    for c in 0..cells.len() {
        buf.clear();
        buf.extend(cells.cell(c).iter().map(|g| to_plan[g]));
        m.push_cell(cells.kinds[c], &buf, cells.tags[c]);
    }
    m
}

/// `GlobalSizes::of` the whole mesh from the slabs: the hash runs through the slabs in rank
/// order, one section (points, cells, kinds, ids) after the other, each process continuing
/// its predecessor's state.
fn sizes_of(slab: &MeshSlab, world: &Handle, comm: &dyn Comm) -> GlobalSizes {
    use mpi::point_to_point::{Destination, Source};
    use mpi::topology::Communicator;
    use mpi::traits::Root;
    let c = world.communicator();
    let (rank, size) = (c.rank() as usize, c.size() as usize);
    let sections: [&dyn Fn(&mut StableHash); 4] = [
        &|h| slab.points.iter().flatten().for_each(|x| h.u64(x.to_bits())),
        &|h| slab.conn.iter().for_each(|&x| h.u64(u64::from(x))),
        &|h| {
            slab.kinds
                .iter()
                .for_each(|&k| h.u64(u64::from(crate::config::wire::kind_code(k))))
        },
        &|h| slab.node_ids.iter().for_each(|&i| h.u64(i)),
    ];
    let mut state = StableHash::default().finish();
    for (k, section) in sections.iter().enumerate() {
        if rank > 0 {
            (state, _) = c.process_at_rank(rank as i32 - 1).receive::<u64>();
        } else if k > 0 && size > 1 {
            (state, _) = c.process_at_rank(size as i32 - 1).receive::<u64>();
        }
        let mut h = StableHash::resume(state);
        section(&mut h);
        state = h.finish();
        if rank + 1 < size {
            c.process_at_rank(rank as i32 + 1).send(&state);
        } else if k + 1 < sections.len() && size > 1 {
            c.process_at_rank(0).send(&state);
        }
    }
    c.process_at_rank(size as i32 - 1).broadcast_into(&mut state);
    GlobalSizes {
        nodes: slab.nodes,
        cells: slab.cells,
        conn: comm.sum_i128(slab.conn.len() as i128) as usize,
        mesh_hash: state,
    }
}

/// The start of a run from a VTKHDF mesh in slabs (every process of `world` calls, each with
/// the `deferred` setup rank 0 made): each reads its slab, the node graph is built and split
/// into one part per process, cells and coordinates move to their owners (`redistribute`),
/// the whole mesh's checks are made of the shares (`checks`), and each process builds its
/// plan and resolves the scenario on its local mesh (`Setup::resolve_local`). Returns the
/// process's part, with its slab for the static output (every process writes its slab's
/// rows); no process reads the whole mesh (the summary and the warnings take what they need
/// of it by reductions, `Simulation::whole_mesh`).
/// An error on any process is every process's (printed once, by rank 0).
pub fn start(world: &Handle, setup: Setup) -> Result<(Part, Option<Mesh>)> {
    use mpi::topology::Communicator;
    let comm = Mpi::new(world.duplicate());
    let (rank, size) = (
        world.communicator().rank() as usize,
        world.communicator().size() as usize,
    );
    let made = start_here(world, &comm, setup);
    let made = agree(world, &comm, made)?;
    tracing::debug!("rank {rank} of {size}: part made from the slabs");
    Ok((made, None))
}

fn start_here(world: &Handle, comm: &dyn Comm, setup: Setup) -> Result<Part> {
    let (rank, size) = (comm.rank(), comm.size());
    let sc = &setup.scenario;
    let path = sc.mesh_path();
    let factor = crate::config::mesh::factor(sc)?;
    let named = |e: anyhow::Error| match e.is::<super::parts::ReportedElsewhere>() {
        true => e,
        false => anyhow!("{e:#}\n  (mesh named by {} [mesh] file)", sc.path.display()),
    };
    let mut slab = read(Some(comm), &path).map_err(named)?;
    crate::diagnostics::log_memory("reading the slab of the mesh");
    // the whole mesh's checks, as one process makes them of the mesh it reads (unscaled)
    let (n_slab_nodes, source) = (slab.nodes, path.display().to_string());
    checks::first(comm, vec![checks::coordinates(&slab, &source)]).map_err(named)?;
    checks::count(slab.cells, &source).map_err(named)?;
    let cells = cells_to_owners(&slab, Some(world))?;
    let vtxdist = cuts(slab.nodes, size);
    let graph = node_graph(&cells, &vtxdist, vtxdist[rank], vtxdist[rank + 1])?;
    drop(cells);
    let (part, how) = split(&graph, size, Some(comm))?;
    tracing::info!("{} nodes split into {size} parts ({how:?}) from the slabs", slab.nodes);
    drop(graph);
    let mut local = redistribute(&slab, &part, Some(world))?;
    drop(part);
    let t = std::time::Instant::now();
    checks::first(comm, checks::cells(&local, &source)).map_err(named)?;
    tracing::debug!("the cells checked in {:.3} s", t.elapsed().as_secs_f64());
    if factor != 1.0 {
        slab.points.iter_mut().flatten().for_each(|x| *x *= factor);
        local.points.iter_mut().flatten().for_each(|x| *x *= factor);
    }
    let sizes = sizes_of(&slab, world, comm);
    let found = comm.sum_i128(local.n_owned as i128) as usize;
    if found != n_slab_nodes {
        bail!(
            "{source}: {} of its {n_slab_nodes} nodes are in no cell, which a run under mpirun from a .vtkhdf mesh does not handle yet; fix: run from the mesh file it was converted from, or on one process",
            n_slab_nodes - found
        );
    }
    let plan = plan_of(&local, rank);
    let mut mesh = local_mesh(&local, &plan, &source);
    drop(local);
    crate::diagnostics::log_memory("the local mesh from the slabs");
    let bounds = super::comm::bounds(comm, &mesh.points[..plan.numbering.n_owned]);
    let halo = super::halo::Halo::new(plan.pattern.clone(), world.duplicate());
    let t = std::time::Instant::now();
    let (gid, n_owned) = (&plan.numbering.global, plan.numbering.n_owned);
    let pieces = crate::config::local::piece_labels(&mesh, gid, n_owned, &Reducer(comm, &halo));
    let comps = checks::components(&pieces, gid, n_owned, comm);
    tracing::debug!("{comps} component(s) counted in {:.3} s", t.elapsed().as_secs_f64());
    // the whole mesh's warnings (of the summary) ride with the local mesh
    mesh.warnings.extend(checks::components_warning(comps));
    let setup = {
        let global = crate::config::local::Global {
            n_owned: plan.numbering.n_owned,
            gid: &plan.numbering.global,
            n_nodes: n_slab_nodes,
            bounds,
            red: &Reducer(comm, &halo),
            pieces: &pieces,
        };
        setup.resolve_local(mesh, &global)?
    };
    // the slab stays for the static output, which every process writes its rows of
    Ok(Part {
        setup,
        plan,
        sizes,
        rows: Some(slab),
    })
}

/// Every process's outcome agreed: an error anywhere is reported by rank 0 (`Collective`, the
/// message of the lowest process that has one) and is `ReportedElsewhere` on the others.
fn agree<T>(world: &Handle, comm: &dyn Comm, made: Result<T>) -> Result<T> {
    use mpi::point_to_point::{Destination, Source};
    use mpi::topology::Communicator;
    let (rank, size) = (comm.rank(), comm.size());
    let own = match &made {
        Err(e) if !e.is::<super::parts::ReportedElsewhere>() => Some(format!("{e:#}")),
        _ => None,
    };
    let failed = comm.max(f64::from(u8::from(made.is_err())));
    if failed == 0.0 {
        return made;
    }
    let first = comm.min(if own.is_some() { rank as f64 } else { size as f64 }) as usize;
    let c = world.communicator();
    if first == size {
        return Err(super::parts::ReportedElsewhere.into());
    }
    if rank == first && rank != 0 {
        c.process_at_rank(0).send(own.as_deref().unwrap_or_default().as_bytes());
    }
    if rank == 0 {
        let msg = match first {
            0 => own.unwrap_or_default(),
            q => String::from_utf8_lossy(&c.process_at_rank(q as i32).receive_vec::<u8>().0).into_owned(),
        };
        return Err(super::parts::Collective(msg).into());
    }
    Err(super::parts::ReportedElsewhere.into())
}

#[cfg(test)]
mod tests {
    use super::*;
    use eprop_io::generate::{box_mesh, BoxCells};

    /// The slab of process r of `size` of a mesh, as `read_slab` gives it.
    fn slab_of(m: &eprop_mesh::Mesh, size: usize, r: usize) -> MeshSlab {
        let (c0, c1) = (block(m.n_cells(), size, r), block(m.n_cells(), size, r + 1));
        let (p0, p1) = (block(m.n_nodes(), size, r), block(m.n_nodes(), size, r + 1));
        let base = m.offsets[c0];
        MeshSlab {
            nodes: m.n_nodes(),
            cells: m.n_cells(),
            node_start: p0,
            points: m.points[p0..p1].to_vec(),
            node_ids: m.node_ids[p0..p1].to_vec(),
            cell_start: c0,
            conn_start: m.offsets[c0],
            kinds: m.kinds[c0..c1].to_vec(),
            offsets: m.offsets[c0..=c1].iter().map(|&o| o - base).collect(),
            conn: m.conn[m.offsets[c0]..m.offsets[c1]].to_vec(),
            cell_tags: m.cell_tags[c0..c1].to_vec(),
        }
    }

    #[test]
    fn the_rows_of_a_slab_are_those_of_the_whole_graph() {
        let m = box_mesh([1.0; 3], [3, 4, 2], BoxCells::Wedge).unwrap();
        let (xadj, adj) = eprop_partition::node_graph(m.n_nodes(), &m.offsets, &m.conn);
        let w = eprop_partition::degree_weights(&xadj);
        let size = 3;
        let vtxdist = cuts(m.n_nodes(), size);
        for r in 0..size {
            // the cells that touch the slab's nodes, from every process's slab of cells
            let mut cells = Cells {
                offsets: vec![0],
                ..Default::default()
            };
            for c in 0..m.n_cells() {
                if m.cell(c).iter().any(|&g| owner(&vtxdist, g as usize) == r) {
                    cells.ids.push(c as u64);
                    cells.kinds.push(m.kinds[c]);
                    cells.tags.push(m.cell_tags[c]);
                    cells.conn.extend_from_slice(m.cell(c));
                    cells.offsets.push(cells.conn.len());
                }
            }
            let got = node_graph(&cells, &vtxdist, vtxdist[r], vtxdist[r + 1]).unwrap();
            assert_eq!(got, Slab::of(&xadj, &adj, &w, size, r));
        }
        // one process: the slab's own cells, its graph the whole graph, METIS's split and quality
        let one = slab_of(&m, 1, 0);
        let cells = cells_to_owners(&one, None).unwrap();
        assert_eq!(cells.conn, m.conn);
        assert_eq!(cells.ids, (0..m.n_cells() as u64).collect::<Vec<_>>());
        let g = node_graph(&cells, &cuts(m.n_nodes(), 1), 0, m.n_nodes()).unwrap();
        let (part, how) = split(&g, 3, None).unwrap();
        assert_eq!(how, Splitter::Metis);
        let whole =
            eprop_partition::partition_weighted(&xadj, &adj, 3, eprop_partition::Method::Metis, Some(&w)).unwrap();
        assert_eq!(part, whole);
        let (a, b) = (
            quality(&g, &part, 3, None),
            eprop_partition::quality(&xadj, &adj, &whole, 3),
        );
        assert_eq!(
            (a.edge_cut, a.imbalance, &a.owned, &a.halo, &a.neighbours),
            (b.edge_cut, b.imbalance, &b.owned, &b.halo, &b.neighbours)
        );
    }

    #[test]
    fn one_process_keeps_everything_in_order() {
        let m = box_mesh([1.0; 3], [2, 3, 2], BoxCells::Tet).unwrap();
        let slab = slab_of(&m, 1, 0);
        let local = redistribute(&slab, &vec![0; m.n_nodes()], None).unwrap();
        assert_eq!(local.n_owned, m.n_nodes());
        assert_eq!(local.global, (0..m.n_nodes() as u32).collect::<Vec<_>>());
        assert_eq!((&local.points, &local.node_ids), (&m.points, &m.node_ids));
        assert_eq!((&local.cells.conn, &local.cells.tags), (&m.conn, &m.cell_tags));
    }

    #[test]
    fn owners_by_slab() {
        let c = cuts(10, 3);
        assert_eq!(c, vec![0, 3, 6, 10]);
        let o: Vec<usize> = (0..10).map(|g| owner(&c, g)).collect();
        assert_eq!(o, vec![0, 0, 0, 1, 1, 1, 2, 2, 2, 2]);
    }
}
