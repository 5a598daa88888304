//! The first step of the multigrid setup: every process's free rows of K = -W gathered on
//! every process (global ids, `Comm::all_gather_var`), made exactly symmetric and renumbered
//! in an order computed from global ids alone, so the hierarchy built from them is the same
//! on every process and for every partition; and level 0's own weights on the solver's pattern.

use crate::distribute::comm::Comm;
use crate::linalg::csr::{AnyCsr, Csr};
use rayon::prelude::*;

/// One free row gathered from its process: global id, process, V_i, and where its pairs
/// (global id of j, V_i c_ij), ascending in j, start in the gathered values and how many.
pub(super) struct Row {
    pub gid: u64,
    pub rank: u32,
    pub vol: f64,
    at: usize,
    len: usize,
}

/// The global K of the free rows: the rows (in K's order), K (its rows' columns ascending,
/// with the diagonal) and the row of each global id (u32::MAX: not free).
pub(super) struct Gathered {
    pub rows: Vec<Row>,
    pub k: Csr<f64>,
    pub free: Vec<u32>,
}

/// K of the free rows (`vol` > 0, owned) of the coefficients `op` over every process of
/// `comm`; `gid` numbers the local nodes (owned, then halo).
pub(super) fn gather(op: &AnyCsr, vol: &[f64], gid: &[u64], comm: &dyn Comm) -> Gathered {
    let (all, rows) = collect(op, vol, gid, comm);
    let span = rows
        .iter()
        .flat_map(|r| std::iter::once(r.gid).chain((0..r.len).map(|k| all[r.at + 2 * k] as u64)))
        .max()
        .map_or(0, |g| g as usize + 1);
    let mut free = vec![u32::MAX; span];
    for (k, r) in rows.iter().enumerate() {
        free[r.gid as usize] = k as u32;
    }
    let built = symmetric(&all, &rows, &free);
    drop(all);
    renumber(rows, built, free)
}

/// This process's free rows, gathered on every process: the values and the rows in global
/// id order.
fn collect(op: &AnyCsr, vol: &[f64], gid: &[u64], comm: &dyn Comm) -> (Vec<f64>, Vec<Row>) {
    let n = vol.len();
    let mut send = vec![];
    let mut row: Vec<(u64, f64)> = vec![];
    for i in 0..n {
        if !(vol[i] > 0.0) {
            continue;
        }
        row.clear();
        for p in op.row(i) {
            row.push((gid[op.col()[p] as usize], vol[i] * op.value(p)));
        }
        row.sort_by_key(|e| e.0);
        send.extend_from_slice(&[gid[i] as f64, vol[i], row.len() as f64]);
        for &(g, a) in &row {
            send.extend_from_slice(&[g as f64, a]);
        }
    }
    let (all, counts) = comm.all_gather_var(&send);
    drop(send);
    let mut rows = vec![];
    let mut at = 0;
    for (q, &c) in counts.iter().enumerate() {
        let end = at + c;
        while at < end {
            let len = all[at + 2] as usize;
            rows.push(Row {
                gid: all[at] as u64,
                rank: q as u32,
                vol: all[at + 1],
                at: at + 3,
                len,
            });
            at += 3 + 2 * len;
        }
    }
    rows.sort_by_key(|r| r.gid);
    (all, rows)
}

/// K = -W: K_ij = -(V_i c_ij + V_j c_ji) / 2 between free rows (exactly symmetric),
/// K_ii = V_i sum_j c_ij over every neighbour in global order (as A's diagonal); row k's
/// entries (row index, value) with ascending columns.
fn symmetric(all: &[f64], rows: &[Row], free: &[u32]) -> Vec<Vec<(u32, f64)>> {
    let pair = |r: &Row, k: usize| (all[r.at + 2 * k] as u64, all[r.at + 2 * k + 1]);
    let back = |r: &Row, g: u64| {
        let (mut lo, mut hi) = (0, r.len);
        while lo < hi {
            let mid = (lo + hi) / 2;
            match pair(r, mid).0.cmp(&g) {
                std::cmp::Ordering::Less => lo = mid + 1,
                std::cmp::Ordering::Greater => hi = mid,
                std::cmp::Ordering::Equal => return Some(pair(r, mid).1),
            }
        }
        None
    };
    rows.par_iter()
        .enumerate()
        .with_min_len(1024)
        .map(|(k, r)| {
            let mut out = Vec::with_capacity(r.len + 1);
            let mut diag = 0.0;
            for e in 0..r.len {
                let (g, a) = pair(r, e);
                diag += a;
                let j = free[g as usize];
                if j != u32::MAX && j as usize != k {
                    let b = back(&rows[j as usize], r.gid).unwrap_or(a);
                    out.push((j, -0.5 * (a + b)));
                }
            }
            let at = out.partition_point(|e| (e.0 as usize) < k);
            out.insert(at, (k as u32, diag));
            out
        })
        .collect()
}

/// The free rows renumbered in reverse Cuthill-McKee order of K's graph, from global ids
/// (the same on every process): aggregates grown in an order with locality (on the 100^3
/// box 10 iterations per solve against 13 in the mesh's own order).
fn renumber(rows: Vec<Row>, built: Vec<Vec<(u32, f64)>>, mut free: Vec<u32>) -> Gathered {
    let m = rows.len();
    let mut xadj = Vec::with_capacity(m + 1);
    xadj.push(0);
    let mut adj = vec![];
    for (k, r) in built.iter().enumerate() {
        adj.extend(r.iter().filter(|e| e.0 as usize != k).map(|e| e.0));
        xadj.push(adj.len());
    }
    let order = eprop_partition::rcm_order(&xadj, &adj);
    drop((xadj, adj));
    let mut new_of = vec![0u32; m];
    for (k, &o) in order.iter().enumerate() {
        new_of[o as usize] = k as u32;
    }
    let mut slots: Vec<Option<Row>> = rows.into_iter().map(Some).collect();
    let rows: Vec<Row> = order
        .iter()
        .map(|&o| slots[o as usize].take().expect("a permutation"))
        .collect();
    // K in the new numbering, its rows' columns ascending
    let mut k = Csr {
        n_cols: m,
        ptr: Vec::with_capacity(m + 1),
        col: Vec::with_capacity(built.iter().map(Vec::len).sum()),
        val: vec![],
    };
    k.ptr.push(0);
    let mut r: Vec<(u32, f64)> = vec![];
    for &o in &order {
        r.clear();
        r.extend(built[o as usize].iter().map(|&(j, v)| (new_of[j as usize], v)));
        r.sort_by_key(|e| e.0);
        for &(j, v) in &r {
            k.col.push(j);
            k.val.push(v);
        }
        k.ptr
            .push(u32::try_from(k.col.len()).expect("a global matrix of fewer than 2^32 entries"));
    }
    drop(built);
    for (k, r) in rows.iter().enumerate() {
        free[r.gid as usize] = k as u32;
    }
    Gathered { rows, k, free }
}

/// Level 0's own weights for the smoothing sweeps, on the pattern of `op`: w_ij = -K_ij
/// (exactly symmetric; V_i c_ij towards nodes that do not move) in f32, so that a sweep reads
/// fewer bytes and the cycle stays a symmetric operator.
pub(super) fn sweep_weights(op: &AnyCsr, vol: &[f64], gid: &[u64], g: &Gathered) -> Vec<f32> {
    let (k, free) = (&g.k, &g.free);
    let mut w32 = vec![0.0f32; op.col().len()];
    for i in 0..vol.len() {
        if !(vol[i] > 0.0) {
            continue;
        }
        let row = k.row(free[gid[i] as usize] as usize);
        let (cols, vals) = (&k.col[row.clone()], &k.val[row]);
        for p in op.row(i) {
            let j = free
                .get(gid[op.col()[p] as usize] as usize)
                .copied()
                .unwrap_or(u32::MAX);
            let w = match cols.binary_search(&j) {
                Ok(at) if j != u32::MAX => -vals[at],
                _ => vol[i] * op.value(p),
            };
            w32[p] = w as f32;
        }
    }
    w32
}
