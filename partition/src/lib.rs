//! eprop-partition: the node graph of a mesh, METIS k-way partitions of it, and the plan of a
//! distributed run: which nodes a process owns, which it mirrors (halo), which cells it
//! keeps, and what it sends to and receives from each neighbour.
//!
//! The crate takes plain slices (cell offsets and connectivity) so it depends on no mesh type.

use anyhow::{anyhow, bail, Result};
use serde::{Deserialize, Serialize};

/// Node-to-cell incidence in CSR form: the cells of node i, increasing, are
/// `cells[ptr[i]..ptr[i + 1]]`.
pub fn incidence(n_nodes: usize, offsets: &[usize], conn: &[u32]) -> (Vec<usize>, Vec<u32>) {
    let mut ptr = vec![0usize; n_nodes + 1];
    for &v in conn {
        ptr[v as usize + 1] += 1;
    }
    for i in 0..n_nodes {
        ptr[i + 1] += ptr[i];
    }
    let mut fill = ptr.clone();
    let mut cells = vec![0u32; conn.len()];
    for c in 0..offsets.len() - 1 {
        for &v in &conn[offsets[c]..offsets[c + 1]] {
            cells[fill[v as usize]] = c as u32;
            fill[v as usize] += 1;
        }
    }
    (ptr, cells)
}

/// Node adjacency (nodes that share a cell) in CSR form, neighbours sorted, no self loops.
pub fn node_graph(n_nodes: usize, offsets: &[usize], conn: &[u32]) -> (Vec<usize>, Vec<u32>) {
    let (ptr, cells) = incidence(n_nodes, offsets, conn);
    let mut xadj = Vec::with_capacity(n_nodes + 1);
    xadj.push(0);
    let mut adj = Vec::new();
    let mut buf = Vec::new();
    for i in 0..n_nodes {
        buf.clear();
        for &c in &cells[ptr[i]..ptr[i + 1]] {
            let c = c as usize;
            buf.extend(
                conn[offsets[c]..offsets[c + 1]]
                    .iter()
                    .copied()
                    .filter(|&j| j as usize != i),
            );
        }
        buf.sort_unstable();
        buf.dedup();
        adj.extend_from_slice(&buf);
        xadj.push(adj.len());
    }
    (xadj, adj)
}

/// How nodes are split among parts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// METIS k-way on the node graph (minimises the edge cut).
    Metis,
    /// Contiguous blocks of the input numbering (for comparison).
    Block,
}

/// Part of every node, in `0..nparts`.
pub fn partition(xadj: &[usize], adj: &[u32], nparts: usize, method: Method) -> Result<Vec<u32>> {
    partition_weighted(xadj, adj, nparts, method, None)
}

/// Work per node for balancing: its number of neighbours plus one (the stored pairs of its
/// operator row and its own update).
pub fn degree_weights(xadj: &[usize]) -> Vec<u32> {
    xadj.windows(2).map(|w| (w[1] - w[0] + 1) as u32).collect()
}

/// Like `partition`, with optional node weights that METIS balances instead of node counts.
pub fn partition_weighted(
    xadj: &[usize],
    adj: &[u32],
    nparts: usize,
    method: Method,
    weights: Option<&[u32]>,
) -> Result<Vec<u32>> {
    let n = xadj.len() - 1;
    if nparts == 0 {
        bail!("cannot split into 0 parts");
    }
    if nparts > n {
        bail!("{nparts} parts for {n} nodes: every part needs at least one node; fix: run on at most {n} processes");
    }
    if nparts == 1 {
        return Ok(vec![0; n]);
    }
    match method {
        Method::Block => Ok((0..n).map(|i| (i * nparts / n) as u32).collect()),
        Method::Metis => {
            let xadj_i: Vec<metis::Idx> = xadj.iter().map(|&x| x as metis::Idx).collect();
            let adj_i: Vec<metis::Idx> = adj.iter().map(|&x| x as metis::Idx).collect();
            let mut part = vec![0 as metis::Idx; n];
            let w: Vec<metis::Idx> = weights
                .map(|w| w.iter().map(|&x| x as metis::Idx).collect())
                .unwrap_or_default();
            let mut g = metis::Graph::new(1, nparts as metis::Idx, &xadj_i, &adj_i)
                .map_err(|e| anyhow!("METIS rejected the node graph: {e:?}"))?
                .set_option(metis::option::Seed(1));
            if weights.is_some() {
                if w.len() != n {
                    bail!("{} node weights for {n} nodes", w.len());
                }
                g = g.set_vwgt(&w);
            }
            g.part_kway(&mut part).map_err(|e| anyhow!("METIS failed: {e:?}"))?;
            let part: Vec<u32> = part.iter().map(|&p| p as u32).collect();
            if let Err(e) = check_parts(&part, nparts) {
                bail!("METIS: {e} ({nparts} parts of {n} nodes); fix: run on fewer processes");
            }
            Ok(part)
        }
    }
}

/// Checks a part vector (a part per node): every part in `0..nparts`, and none left empty (each
/// process owns at least one node). Err names the first fault.
pub fn check_parts(part: &[u32], nparts: usize) -> std::result::Result<(), String> {
    let mut count = vec![0usize; nparts];
    for (i, &p) in part.iter().enumerate() {
        match count.get_mut(p as usize) {
            Some(c) => *c += 1,
            None => return Err(format!("node {i} is in part {p} of {nparts}")),
        }
    }
    match count.iter().position(|&c| c == 0) {
        Some(empty) => Err(format!("part {empty} is left empty")),
        None => Ok(()),
    }
}

/// Edge cut, load imbalance (largest part / mean) and halo size per part.
#[derive(Debug, Clone)]
pub struct Quality {
    pub edge_cut: usize,
    pub imbalance: f64,
    pub owned: Vec<usize>,
    pub halo: Vec<usize>,
    pub neighbours: Vec<usize>,
}

pub fn quality(xadj: &[usize], adj: &[u32], part: &[u32], nparts: usize) -> Quality {
    let n = part.len();
    let mut cut = 0usize;
    let mut owned = vec![0usize; nparts];
    let mut halo_sets: Vec<std::collections::BTreeSet<u32>> = vec![Default::default(); nparts];
    let mut nb: Vec<std::collections::BTreeSet<u32>> = vec![Default::default(); nparts];
    for i in 0..n {
        let pi = part[i];
        owned[pi as usize] += 1;
        for &j in &adj[xadj[i]..xadj[i + 1]] {
            let pj = part[j as usize];
            if pj != pi {
                if (j as usize) > i {
                    cut += 1;
                }
                halo_sets[pi as usize].insert(j);
                nb[pi as usize].insert(pj);
            }
        }
    }
    let mean = n as f64 / nparts as f64;
    Quality {
        edge_cut: cut,
        imbalance: owned.iter().copied().max().unwrap_or(0) as f64 / mean,
        owned,
        halo: halo_sets.iter().map(|s| s.len()).collect(),
        neighbours: nb.iter().map(|s| s.len()).collect(),
    }
}

/// The local numbering of one process: owned interior nodes (no neighbour on another
/// process), owned border nodes (sent to some neighbour), then halo nodes (copies of other
/// processes' nodes, by increasing global id). Per-node arrays of a process follow it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LocalNumbering {
    /// Global id of each local node (owned first, then halo).
    pub global: Vec<u32>,
    /// Owned nodes `0..n_interior` need no halo value; `n_interior..n_owned` do.
    pub n_interior: usize,
    pub n_owned: usize,
}

impl LocalNumbering {
    /// One process owning `n` nodes in their given order, no halo.
    pub fn serial(global: Vec<u32>) -> LocalNumbering {
        let n = global.len();
        LocalNumbering {
            global,
            n_interior: n,
            n_owned: n,
        }
    }
    pub fn n_local(&self) -> usize {
        self.global.len()
    }
    pub fn n_halo(&self) -> usize {
        self.global.len() - self.n_owned
    }
    /// The ranges of the local numbering, without the ids.
    pub fn layout(&self) -> Layout {
        Layout {
            n_interior: self.n_interior,
            n_owned: self.n_owned,
            n_local: self.global.len(),
        }
    }
}

/// The ranges of a local numbering: `interior() ++ border() == owned()`, then `halo()`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Layout {
    pub n_interior: usize,
    pub n_owned: usize,
    pub n_local: usize,
}

impl Layout {
    /// One process with `n` nodes, all owned and interior.
    pub fn serial(n: usize) -> Layout {
        Layout {
            n_interior: n,
            n_owned: n,
            n_local: n,
        }
    }
    pub fn interior(&self) -> std::ops::Range<usize> {
        0..self.n_interior
    }
    pub fn border(&self) -> std::ops::Range<usize> {
        self.n_interior..self.n_owned
    }
    pub fn owned(&self) -> std::ops::Range<usize> {
        0..self.n_owned
    }
    pub fn halo(&self) -> std::ops::Range<usize> {
        self.n_owned..self.n_local
    }
}

/// Who sends what to whom in a halo exchange: per neighbour process, the local indices of the
/// owned nodes to send and of the halo nodes to receive into, both ordered by global id, so the
/// two sides agree without negotiation.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct HaloPattern {
    pub neighbours: Vec<Neighbour>,
}

impl HaloPattern {
    /// Nodes received per exchange.
    pub fn n_recv(&self) -> usize {
        self.neighbours.iter().map(|n| n.recv.len()).sum()
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Neighbour {
    pub rank: usize,
    pub send: Vec<u32>,
    pub recv: Vec<u32>,
}

/// What one process holds and exchanges: its numbering, its halo pattern and its cells
/// (every cell with an owned node, in global order). Owned nodes are sorted by an optional
/// locality key (ties and no key: by global id).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub rank: usize,
    pub numbering: LocalNumbering,
    pub pattern: HaloPattern,
    /// Global ids of the local cells, increasing.
    pub cells: Vec<u32>,
}

impl Plan {
    /// The plan of `rank` for a partition of the whole mesh, with one layer of halo: the nodes
    /// of other processes that share a cell with an owned node, numbered after the owned nodes
    /// by increasing global id (every process can compute every plan from the same inputs; no
    /// messages are needed). `key`, when given, is a locality key per global node (for example
    /// a space-filling-curve index) that orders owned nodes.
    pub fn new(
        n_nodes: usize,
        offsets: &[usize],
        conn: &[u32],
        part: &[u32],
        rank: usize,
        key: Option<&[u64]>,
    ) -> Plan {
        let me = rank as u32;
        let n_cells = offsets.len() - 1;
        let cell = |c: usize| &conn[offsets[c]..offsets[c + 1]];
        // the cells of the owned nodes
        let cells: Vec<u32> = (0..n_cells)
            .filter(|&c| cell(c).iter().any(|&v| part[v as usize] == me))
            .map(|c| c as u32)
            .collect();
        // the halo, increasing global id; border: owned nodes that share a cell with a node of
        // another process
        let mut halo: Vec<u32> = vec![];
        let mut border: Vec<u32> = vec![];
        for &c in &cells {
            let nodes = cell(c as usize);
            if nodes.iter().any(|&v| part[v as usize] != me) {
                halo.extend(nodes.iter().filter(|&&a| part[a as usize] != me));
                border.extend(nodes.iter().filter(|&&a| part[a as usize] == me));
            }
        }
        halo.sort_unstable();
        halo.dedup();
        border.sort_unstable();
        border.dedup();
        let by_key = |v: &mut Vec<u32>| {
            if let Some(k) = key {
                v.sort_by_key(|&g| (k[g as usize], g));
            }
        };
        let mut interior: Vec<u32> = (0..n_nodes as u32)
            .filter(|&v| part[v as usize] == me && border.binary_search(&v).is_err())
            .collect();
        by_key(&mut interior);
        by_key(&mut border);
        let n_interior = interior.len();
        let n_owned = n_interior + border.len();
        let mut global = interior;
        global.extend_from_slice(&border);
        global.extend_from_slice(&halo);
        let n_local = global.len();
        let mut local = std::collections::HashMap::with_capacity(n_local);
        for (l, &g) in global.iter().enumerate() {
            local.insert(g, l as u32);
        }
        // per neighbour q: the owned nodes that share a cell with one of q's nodes (q's halo
        // of them), by global id, and the halo nodes q owns
        let mut ranks: Vec<u32> = global[n_owned..].iter().map(|&g| part[g as usize]).collect();
        ranks.sort_unstable();
        ranks.dedup();
        let mut send: Vec<Vec<u32>> = vec![vec![]; ranks.len()];
        for &c in &cells {
            let nodes = cell(c as usize);
            for &b in nodes.iter().filter(|&&b| part[b as usize] != me) {
                let q = ranks.binary_search(&part[b as usize]).expect("a halo node's owner");
                send[q].extend(nodes.iter().filter(|&&a| part[a as usize] == me));
            }
        }
        let neighbours = ranks
            .iter()
            .zip(send)
            .map(|(&q, mut s)| {
                s.sort_unstable();
                s.dedup();
                Neighbour {
                    rank: q as usize,
                    send: s.iter().map(|g| local[g]).collect(),
                    recv: (n_owned..n_local)
                        .filter(|&l| part[global[l] as usize] == q)
                        .map(|l| l as u32)
                        .collect(),
                }
            })
            .collect();
        Plan {
            rank,
            numbering: LocalNumbering {
                global,
                n_interior,
                n_owned,
            },
            pattern: HaloPattern { neighbours },
            cells,
        }
    }

    pub fn n_halo(&self) -> usize {
        self.numbering.n_halo()
    }
}

/// A Morton (Z-order) index of every point inside the points' bounding box: sorting by it
/// keeps nodes that are close in space close in memory.
pub fn morton_keys(points: &[[f64; 3]]) -> Vec<u64> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for d in 0..3 {
            lo[d] = lo[d].min(p[d]);
            hi[d] = hi[d].max(p[d]);
        }
    }
    let spread = |mut x: u64| {
        x &= 0x1f_ffff;
        x = (x | x << 32) & 0x1f00000000ffff;
        x = (x | x << 16) & 0x1f0000ff0000ff;
        x = (x | x << 8) & 0x100f00f00f00f00f;
        x = (x | x << 4) & 0x10c30c30c30c30c3;
        (x | x << 2) & 0x1249249249249249
    };
    points
        .iter()
        .map(|p| {
            let mut k = 0u64;
            for d in 0..3 {
                let w = hi[d] - lo[d];
                let t = if w > 0.0 {
                    ((p[d] - lo[d]) / w).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                k |= spread((t * 2097151.0) as u64) << d;
            }
            k
        })
        .collect()
}

/// Reverse Cuthill-McKee order of a graph in CSR form (`node_graph`): each connected component
/// from a pseudo-peripheral node (George and Liu), neighbours taken by increasing degree, the
/// whole order reversed. Neighbours of a node end up within a narrow band of positions (one or
/// two breadth-first levels), which is what lets several substeps share one sweep over the rows.
/// Returns the nodes in their new order; deterministic.
pub fn rcm_order(xadj: &[usize], adj: &[u32]) -> Vec<u32> {
    let n = xadj.len() - 1;
    let deg = |v: usize| xadj[v + 1] - xadj[v];
    let mut level = vec![u32::MAX; n];
    let mut placed = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut queue = Vec::new();
    let mut buf = Vec::new();
    // breadth-first levels of the component of `root` (among nodes not yet placed):
    // (eccentricity, the last level's node of least degree), `level` left set on the component
    let bfs = |root: usize, level: &mut [u32], placed: &[bool], queue: &mut Vec<u32>| -> (u32, usize) {
        for &v in queue.iter() {
            level[v as usize] = u32::MAX;
        }
        queue.clear();
        queue.push(root as u32);
        level[root] = 0;
        let mut head = 0;
        while head < queue.len() {
            let v = queue[head] as usize;
            head += 1;
            for &w in &adj[xadj[v]..xadj[v + 1]] {
                let w = w as usize;
                if !placed[w] && level[w] == u32::MAX {
                    level[w] = level[v] + 1;
                    queue.push(w as u32);
                }
            }
        }
        let ecc = level[*queue.last().unwrap() as usize];
        let far = queue
            .iter()
            .rev()
            .take_while(|&&v| level[v as usize] == ecc)
            .min_by_key(|&&v| (deg(v as usize), v))
            .copied()
            .unwrap() as usize;
        (ecc, far)
    };
    for first in 0..n {
        if placed[first] {
            continue;
        }
        // pseudo-peripheral start: move to the far end while the eccentricity grows
        let mut root = first;
        let (mut ecc, mut far) = bfs(root, &mut level, &placed, &mut queue);
        for _ in 0..8 {
            let (e, f) = bfs(far, &mut level, &placed, &mut queue);
            if e <= ecc {
                break;
            }
            (root, ecc, far) = (far, e, f);
        }
        for &v in queue.iter() {
            level[v as usize] = u32::MAX;
        }
        queue.clear();
        // Cuthill-McKee from root
        let start = order.len();
        order.push(root as u32);
        placed[root] = true;
        let mut head = start;
        while head < order.len() {
            let v = order[head] as usize;
            head += 1;
            buf.clear();
            buf.extend(
                adj[xadj[v]..xadj[v + 1]]
                    .iter()
                    .copied()
                    .filter(|&w| !placed[w as usize]),
            );
            buf.sort_unstable_by_key(|&w| (deg(w as usize), w));
            for &w in &buf {
                placed[w as usize] = true;
            }
            order.extend_from_slice(&buf);
        }
    }
    order.reverse();
    order
}

/// Locality keys from `rcm_order`: the position of every node in it (for `Plan::new`).
pub fn rcm_keys(xadj: &[usize], adj: &[u32]) -> Vec<u64> {
    let mut key = vec![0u64; xadj.len() - 1];
    for (k, &v) in rcm_order(xadj, adj).iter().enumerate() {
        key[v as usize] = k as u64;
    }
    key
}

/// The largest |position(i) - position(j)| over the edges of a graph under an order given by
/// keys (the bandwidth of the reordered matrix).
pub fn bandwidth(xadj: &[usize], adj: &[u32], key: &[u64]) -> u64 {
    (0..xadj.len() - 1)
        .flat_map(|i| {
            adj[xadj[i]..xadj[i + 1]]
                .iter()
                .map(move |&j| key[i].abs_diff(key[j as usize]))
        })
        .max()
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A strip of 6 tetrahedra in a row (nodes 0..=8) is enough to see the plan agree.
    fn strip() -> (usize, Vec<usize>, Vec<u32>) {
        let mut conn = vec![];
        let mut off = vec![0];
        for k in 0..6u32 {
            conn.extend_from_slice(&[k, k + 1, k + 2, k + 3]);
            off.push(conn.len());
        }
        (9, off, conn)
    }

    #[test]
    fn a_part_vector_is_checked() {
        assert_eq!(check_parts(&[0, 1, 1, 0], 2), Ok(()));
        assert_eq!(check_parts(&[0, 0, 2], 3), Err("part 1 is left empty".into()));
        assert_eq!(check_parts(&[0, 3], 2), Err("node 1 is in part 3 of 2".into()));
    }

    #[test]
    fn plans_agree_on_what_crosses() {
        let (n, off, conn) = strip();
        let (xadj, adj) = node_graph(n, &off, &conn);
        for method in [Method::Block, Method::Metis] {
            for k in 1..=4 {
                let part = partition(&xadj, &adj, k, method).unwrap();
                let key: Vec<u64> = (0..n as u64).rev().collect();
                let plans: Vec<Plan> = (0..k)
                    .map(|r| Plan::new(n, &off, &conn, &part, r, if r % 2 == 0 { Some(&key) } else { None }))
                    .collect();
                assert_eq!(plans.iter().map(|p| p.numbering.n_owned).sum::<usize>(), n);
                for p in &plans {
                    for nb in &p.pattern.neighbours {
                        let q = &plans[nb.rank];
                        let other = q.pattern.neighbours.iter().find(|x| x.rank == p.rank).unwrap();
                        let sent: Vec<u32> = nb.send.iter().map(|&l| p.numbering.global[l as usize]).collect();
                        let got: Vec<u32> = other.recv.iter().map(|&l| q.numbering.global[l as usize]).collect();
                        assert_eq!(sent, got);
                    }
                    // interior nodes have no neighbour on another process; border nodes do
                    for l in 0..p.numbering.n_owned {
                        let g = p.numbering.global[l];
                        let c = (0..off.len() - 1).filter(|&c| conn[off[c]..off[c + 1]].contains(&g));
                        let foreign = c
                            .flat_map(|c| conn[off[c]..off[c + 1]].to_vec())
                            .any(|v| part[v as usize] as usize != p.rank);
                        assert_eq!(foreign, l >= p.numbering.n_interior);
                    }
                    // every halo node is received from exactly one neighbour
                    assert_eq!(p.pattern.n_recv(), p.n_halo());
                    let layout = p.numbering.layout();
                    assert_eq!(layout.interior().end, layout.border().start);
                    assert_eq!(layout.owned().end, layout.halo().start);
                    assert_eq!(layout.halo().end, p.numbering.n_local());
                }
            }
        }
        assert!(partition(&xadj, &adj, 10, Method::Metis).is_err());
    }

    /// A grid of nx x ny x nz nodes with hexahedra (8 nodes each).
    fn grid(nx: usize, ny: usize, nz: usize) -> (usize, Vec<usize>, Vec<u32>) {
        let id = |x: usize, y: usize, z: usize| (x + nx * (y + ny * z)) as u32;
        let (mut off, mut conn) = (vec![0], vec![]);
        for z in 0..nz - 1 {
            for y in 0..ny - 1 {
                for x in 0..nx - 1 {
                    for (dx, dy, dz) in [
                        (0, 0, 0),
                        (1, 0, 0),
                        (1, 1, 0),
                        (0, 1, 0),
                        (0, 0, 1),
                        (1, 0, 1),
                        (1, 1, 1),
                        (0, 1, 1),
                    ] {
                        conn.push(id(x + dx, y + dy, z + dz));
                    }
                    off.push(conn.len());
                }
            }
        }
        (nx * ny * nz, off, conn)
    }

    /// A plan written the plain way (every cell of an owned node, its other nodes the halo; to
    /// each neighbour the owned nodes that share a cell with its nodes): (global ids,
    /// n_interior, n_owned, per neighbour (rank, send, recv), cells).
    #[allow(clippy::type_complexity)]
    fn reference_plan(
        n_nodes: usize,
        offsets: &[usize],
        conn: &[u32],
        part: &[u32],
        me: u32,
        key: Option<&[u64]>,
    ) -> (Vec<u32>, usize, usize, Vec<(usize, Vec<u32>, Vec<u32>)>, Vec<u32>) {
        let cells: Vec<u32> = (0..offsets.len() - 1)
            .filter(|&c| conn[offsets[c]..offsets[c + 1]].iter().any(|&v| part[v as usize] == me))
            .map(|c| c as u32)
            .collect();
        let owned: Vec<u32> = (0..n_nodes as u32).filter(|&v| part[v as usize] == me).collect();
        let mut halo: Vec<u32> = cells
            .iter()
            .flat_map(|&c| conn[offsets[c as usize]..offsets[c as usize + 1]].iter().copied())
            .filter(|&v| part[v as usize] != me)
            .collect();
        halo.sort_unstable();
        halo.dedup();
        let mut send: std::collections::BTreeMap<u32, Vec<u32>> = Default::default();
        for &c in &cells {
            let nodes = &conn[offsets[c as usize]..offsets[c as usize + 1]];
            for &a in nodes.iter().filter(|&&a| part[a as usize] == me) {
                for &b in nodes {
                    if part[b as usize] != me {
                        send.entry(part[b as usize]).or_default().push(a);
                    }
                }
            }
        }
        let mut border: Vec<u32> = send.values().flatten().copied().collect();
        border.sort_unstable();
        border.dedup();
        let by_key = |v: &mut Vec<u32>| {
            if let Some(k) = key {
                v.sort_by_key(|&g| (k[g as usize], g));
            }
        };
        let mut interior: Vec<u32> = owned.into_iter().filter(|g| border.binary_search(g).is_err()).collect();
        by_key(&mut interior);
        by_key(&mut border);
        let (n_interior, n_owned) = (interior.len(), interior.len() + border.len());
        let mut global = interior;
        global.extend_from_slice(&border);
        global.extend_from_slice(&halo);
        let local = |g: &u32| global.iter().position(|x| x == g).unwrap() as u32;
        let nbs = send
            .into_iter()
            .map(|(q, mut s)| {
                s.sort_unstable();
                s.dedup();
                let r: Vec<u32> = halo.iter().filter(|&&h| part[h as usize] == q).map(local).collect();
                (q as usize, s.iter().map(local).collect(), r)
            })
            .collect();
        (global, n_interior, n_owned, nbs, cells)
    }

    #[test]
    fn plans_are_the_reference_plans() {
        let (n, off, conn) = grid(7, 6, 5);
        let (xadj, adj) = node_graph(n, &off, &conn);
        let key = rcm_keys(&xadj, &adj);
        for k in 1..=4 {
            let part = partition(&xadj, &adj, k, Method::Metis).unwrap();
            for r in 0..k {
                for key in [Some(&key[..]), None] {
                    let p = Plan::new(n, &off, &conn, &part, r, key);
                    let (global, ni, no, nbs, cells) = reference_plan(n, &off, &conn, &part, r as u32, key);
                    assert_eq!(
                        (&p.numbering.global, p.numbering.n_interior, p.numbering.n_owned),
                        (&global, ni, no)
                    );
                    assert_eq!(p.cells, cells);
                    let got: Vec<(usize, Vec<u32>, Vec<u32>)> = p
                        .pattern
                        .neighbours
                        .iter()
                        .map(|x| (x.rank, x.send.clone(), x.recv.clone()))
                        .collect();
                    assert_eq!(got, nbs);
                    assert_eq!(p.pattern.n_recv(), p.n_halo());
                    assert_eq!(k > 1, !nbs.is_empty(), "{k} parts, rank {r}");
                }
            }
        }
    }

    #[test]
    fn node_weights_balance_work_not_counts() {
        // a path of 200 nodes whose first 50 weigh 7 each: the split must balance the weights
        let n = 200usize;
        let mut xadj = vec![0usize];
        let mut adj = vec![];
        for i in 0..n {
            if i > 0 {
                adj.push(i as u32 - 1);
            }
            if i + 1 < n {
                adj.push(i as u32 + 1);
            }
            xadj.push(adj.len());
        }
        let w: Vec<u32> = (0..n).map(|i| if i < 50 { 7 } else { 1 }).collect();
        let part = partition_weighted(&xadj, &adj, 2, Method::Metis, Some(&w)).unwrap();
        let mut sum = [0u32; 2];
        for i in 0..n {
            sum[part[i] as usize] += w[i];
        }
        let total = sum[0] + sum[1];
        assert!(sum[0].max(sum[1]) as f64 <= 0.56 * total as f64, "weights {sum:?}");
        assert!(partition_weighted(&xadj, &adj, 2, Method::Metis, Some(&w[..10])).is_err());
    }

    #[test]
    fn rcm_is_a_permutation_with_a_narrow_band() {
        // a 12 x 12 grid numbered column by column with a scrambled id: RCM must bring the band
        // down to about one grid line
        let w = 12usize;
        let n = w * w;
        let id = |x: usize, y: usize| ((x * w + y) * 37 % n) as u32; // 37 is prime to 144
        let mut nbrs = vec![vec![]; n];
        for x in 0..w {
            for y in 0..w {
                if x + 1 < w {
                    nbrs[id(x, y) as usize].push(id(x + 1, y));
                    nbrs[id(x + 1, y) as usize].push(id(x, y));
                }
                if y + 1 < w {
                    nbrs[id(x, y) as usize].push(id(x, y + 1));
                    nbrs[id(x, y + 1) as usize].push(id(x, y));
                }
            }
        }
        // a second component: an isolated node
        nbrs.push(vec![]);
        let mut xadj = vec![0];
        let mut adj = vec![];
        for mut l in nbrs {
            l.sort_unstable();
            adj.extend(l);
            xadj.push(adj.len());
        }
        let order = rcm_order(&xadj, &adj);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..n as u32 + 1).collect::<Vec<_>>());
        let ident: Vec<u64> = (0..n as u64 + 1).collect();
        let before = bandwidth(&xadj, &adj, &ident);
        let after = bandwidth(&xadj, &adj, &rcm_keys(&xadj, &adj));
        assert!(before > 60, "{before}");
        assert!(after <= w as u64 + 1, "bandwidth {after}");
        assert_eq!(rcm_order(&xadj, &adj), order, "deterministic");
    }
}
