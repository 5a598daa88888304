//! The restriction from level 0 to the first coarse level over the processes, the last step
//! of the multigrid setup: which process sums each coarse row, what each process sends and
//! receives for it, and how the first coarse level is split among the processes.

use super::gather::Row;
use super::Own;
use crate::linalg::csr::Csr;

/// The restriction from level 0 to the first coarse level over the processes: every coarse
/// row has one owner, which sums it from the fine residuals of its support in global order
/// (other processes' residuals received behind its own); then every process gathers the
/// whole coarse vector. The same bits on any process count.
#[derive(Default)]
pub(super) struct Plan {
    /// per process q: the owned rows whose residual q needs (ascending global id)
    pub send: Vec<Vec<u32>>,
    /// values sent to and received from each process (three per row; none to itself)
    pub send_counts: Vec<usize>,
    pub recv_counts: Vec<usize>,
    /// the residual's length here: the owned rows, then those received, in arrival order
    pub residual_len: usize,
    /// the rows of R = P^T this process sums, over the residual's positions
    pub r: Csr<f32>,
    /// coarse values gathered from each process (three per row) and the coarse row of each,
    /// in arrival order
    pub coarse_counts: Vec<usize>,
    pub order: Vec<u32>,
}

impl Plan {
    /// The restriction's plan on process `me` of `size` from the global restriction `r` = P^T
    /// (columns: the free rows `rows` in global order): a coarse row belongs to the process of
    /// its largest entry's fine row (the first of equal ones).
    pub(super) fn new(r: &Csr<f32>, rows: &[Row], free_of: &[u32], me: usize, size: usize) -> Plan {
        let nc = r.n_rows();
        let owner: Vec<u32> = (0..nc)
            .map(|a| {
                let mut best = (f32::NEG_INFINITY, None);
                for q in r.row(a) {
                    if r.val[q] > best.0 {
                        best = (r.val[q], Some(r.col[q]));
                    }
                }
                best.1.map_or(0, |i| rows[i as usize].rank)
            })
            .collect();
        let mut order = vec![];
        let mut coarse_counts = vec![0; size];
        for q in 0..size {
            for a in 0..nc {
                if owner[a] as usize == q {
                    order.push(a as u32);
                    coarse_counts[q] += 3;
                }
            }
        }
        // the fine rows this process's coarse rows read, ascending, and their positions
        // where each fine row's residual is: an owned row at its local index, another
        // process's at n + its place in arrival order (process order, then global order)
        let n = free_of.len();
        let mut pos = vec![u32::MAX; rows.len()];
        for (l, &k) in free_of.iter().enumerate() {
            if k != u32::MAX {
                pos[k as usize] = l as u32;
            }
        }
        let mut foreign = vec![];
        let mut seen = vec![false; rows.len()];
        for a in (0..nc).filter(|&a| owner[a] as usize == me) {
            for q in r.row(a) {
                let i = r.col[q] as usize;
                if rows[i].rank as usize != me && !seen[i] {
                    seen[i] = true;
                    foreign.push(i as u32);
                }
            }
        }
        foreign.sort_unstable_by_key(|&i| (rows[i as usize].rank, i));
        let mut recv_counts = vec![0; size];
        for (k, &i) in foreign.iter().enumerate() {
            pos[i as usize] = (n + k) as u32;
            recv_counts[rows[i as usize].rank as usize] += 3;
        }
        let mut mine = Csr {
            n_cols: n + foreign.len(),
            ptr: vec![0],
            col: vec![],
            val: vec![],
        };
        for a in (0..nc).filter(|&a| owner[a] as usize == me) {
            for q in r.row(a) {
                mine.col.push(pos[r.col[q] as usize]);
                mine.val.push(r.val[q]);
            }
            mine.ptr.push(mine.col.len() as u32);
        }
        // what the other processes' coarse rows read of this process's rows
        let mut wanted: Vec<Vec<u32>> = vec![vec![]; size];
        for a in (0..nc).filter(|&a| owner[a] as usize != me) {
            for q in r.row(a) {
                let i = r.col[q] as usize;
                if rows[i].rank as usize == me {
                    wanted[owner[a] as usize].push(i as u32);
                }
            }
        }
        let send: Vec<Vec<u32>> = wanted
            .into_iter()
            .map(|mut w| {
                w.sort_unstable();
                w.dedup();
                w.into_iter().map(|i| pos[i as usize]).collect()
            })
            .collect();
        let send_counts = send.iter().map(|s| 3 * s.len()).collect();
        Plan {
            send,
            send_counts,
            recv_counts,
            residual_len: n + foreign.len(),
            r: mine,
            coarse_counts,
            order,
        }
    }

    /// The first coarse level's rows split among the processes as the restriction's owners
    /// (each computes its rows of the smoothing and the residual, then all gather them).
    pub(super) fn own(&self, me: usize) -> Own {
        let first: usize = self.coarse_counts[..me].iter().sum::<usize>() / 3;
        let mine = self.coarse_counts[me] / 3;
        Own {
            rows: self.order[first..first + mine].to_vec(),
            counts: self.coarse_counts.clone(),
            order: self.order.clone(),
        }
    }
}
