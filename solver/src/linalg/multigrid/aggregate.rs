//! Aggregation of smoothed-aggregation multigrid (Vanek, Mandel and Brezina 1996) on the
//! graph of strong connections of a symmetric matrix: nodes are visited in index order, so
//! the aggregates depend on the matrix and the numbering only.

use crate::linalg::csr::Csr;

/// Not yet in an aggregate.
const NONE: u32 = u32::MAX;

/// Whether (i, j), i != j, is a strong connection: |k_ij| > eps sqrt(|k_ii k_jj|).
#[inline]
fn strong(k_ij: f64, d_i: f64, d_j: f64, eps: f64) -> bool {
    k_ij.abs() > eps * (d_i * d_j).abs().sqrt()
}

/// The aggregate of every row of `k` and the number of aggregates:
/// 1. a node whose strong neighbours are all free starts an aggregate with them;
/// 2. a node left over joins the aggregate of step 1 it is most strongly connected to;
/// 3. nodes still left over form aggregates with their free strong neighbours (alone if none).
///
/// Every node is in exactly one aggregate and no aggregate is empty.
pub(crate) fn aggregate(k: &Csr<f64>, eps: f64) -> (Vec<u32>, usize) {
    let n = k.n_rows();
    let d = k.diagonal();
    let mut agg = vec![NONE; n];
    let mut count = 0u32;
    let d = &d;
    let strong_of = |i: usize| {
        k.row(i)
            .map(move |p| (k.col[p] as usize, k.val[p]))
            .filter(move |&(j, v)| j != i && strong(v, d[i], d[j], eps))
    };
    // 1: root aggregates
    for i in 0..n {
        if agg[i] != NONE {
            continue;
        }
        let mut any = false;
        let mut free = true;
        for (j, _) in strong_of(i) {
            any = true;
            if agg[j] != NONE {
                free = false;
                break;
            }
        }
        if any && free {
            agg[i] = count;
            for (j, _) in strong_of(i) {
                agg[j] = count;
            }
            count += 1;
        }
    }
    // 2: join the most strongly connected aggregate of step 1
    let first = agg.clone();
    for i in 0..n {
        if first[i] != NONE {
            continue;
        }
        let mut best: Option<(f64, u32)> = None;
        for (j, v) in strong_of(i) {
            if first[j] != NONE && best.is_none_or(|(b, _)| v.abs() > b) {
                best = Some((v.abs(), first[j]));
            }
        }
        if let Some((_, a)) = best {
            agg[i] = a;
        }
    }
    // 3: what is left
    for i in 0..n {
        if agg[i] != NONE {
            continue;
        }
        agg[i] = count;
        for (j, _) in strong_of(i) {
            if agg[j] == NONE {
                agg[j] = count;
            }
        }
        count += 1;
    }
    (agg, count as usize)
}

/// The filtered matrix of the prolongator smoothing (Vanek, Mandel and Brezina 1996): the
/// diagonal and the strong connections of `k`, each row's weak entries added to its diagonal
/// (so row sums stay), in the order of the row's entries.
pub fn filtered(k: &Csr<f64>, eps: f64) -> Csr<f64> {
    let n = k.n_rows();
    let d = k.diagonal();
    let mut f = Csr {
        n_cols: k.n_cols,
        ptr: Vec::with_capacity(n + 1),
        col: Vec::with_capacity(k.nnz()),
        val: Vec::with_capacity(k.nnz()),
    };
    f.ptr.push(0);
    for i in 0..n {
        let mut weak = 0.0;
        let mut at = None;
        for p in k.row(i) {
            let j = k.col[p] as usize;
            if j == i {
                at = Some(f.col.len());
            } else if !strong(k.val[p], d[i], d[j], eps) {
                weak += k.val[p];
                continue;
            }
            f.col.push(j as u32);
            f.val.push(k.val[p]);
        }
        if let Some(a) = at {
            f.val[a] += weak;
        }
        f.ptr.push(f.col.len() as u32);
    }
    f
}

/// The tentative prolongator: P_ia = 1 where node i is in aggregate a.
pub(crate) fn tentative(agg: &[u32], n_agg: usize) -> Csr<f64> {
    Csr {
        n_cols: n_agg,
        ptr: (0..=agg.len() as u32).collect(),
        col: agg.to_vec(),
        val: vec![1.0; agg.len()],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 7-point Laplacian of an n^3 grid (Dirichlet outside), rows in lexicographic order,
    /// and one with some rows decoupled (no strong neighbours) and a weak coupling.
    fn grid(n: usize) -> Csr<f64> {
        let id = |x: usize, y: usize, z: usize| (x * n + y) * n + z;
        let mut ptr = vec![0];
        let (mut col, mut val) = (vec![], vec![]);
        for x in 0..n {
            for y in 0..n {
                for z in 0..n {
                    let mut row = vec![(id(x, y, z), 6.0)];
                    for (dx, dy, dz) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                        if x + dx < n && y + dy < n && z + dz < n {
                            row.push((id(x + dx, y + dy, z + dz), -1.0));
                        }
                        if x >= dx && y >= dy && z >= dz {
                            row.push((id(x - dx, y - dy, z - dz), -1.0));
                        }
                    }
                    row.sort_by_key(|e| e.0);
                    for (j, v) in row {
                        col.push(j as u32);
                        val.push(v);
                    }
                    ptr.push(col.len() as u32);
                }
            }
        }
        Csr {
            n_cols: n * n * n,
            ptr,
            col,
            val,
        }
    }

    fn check_cover(agg: &[u32], count: usize) {
        let mut size = vec![0usize; count];
        for &a in agg {
            assert!((a as usize) < count, "node outside every aggregate");
            size[a as usize] += 1;
        }
        assert!(size.iter().all(|&s| s > 0), "an empty aggregate");
        assert_eq!(size.iter().sum::<usize>(), agg.len());
    }

    #[test]
    fn every_node_is_in_exactly_one_aggregate() {
        for n in [1, 2, 5, 12] {
            let k = grid(n);
            let (agg, count) = aggregate(&k, 0.08);
            check_cover(&agg, count);
            if n >= 5 {
                // 3-D: aggregates of several nodes
                assert!(count * 4 < n * n * n, "{n}: {count} aggregates");
            }
        }
        // weak couplings (below eps) and decoupled rows: singletons, still covered
        let mut k = grid(6);
        for (p, v) in k.val.iter_mut().enumerate() {
            if *v < 0.0 && p % 3 == 0 {
                *v = -1e-6;
            }
        }
        let (agg, count) = aggregate(&k, 0.08);
        check_cover(&agg, count);
        // the same matrix gives the same aggregates
        assert_eq!(aggregate(&k, 0.08), (agg, count));
        let empty = Csr {
            n_cols: 0,
            ptr: vec![0],
            col: vec![],
            val: vec![],
        };
        assert_eq!(aggregate(&empty, 0.08), (vec![], 0));
    }
}
