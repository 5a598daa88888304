//! The parallel split of `[performance] partitioner = "ptscotch"`: PT-Scotch's ParMETIS V3
//! layer (`ParMETIS_V3_PartKway` of `libptscotchparmetisv3`, Debian's libptscotch-dev, through
//! the hand-written declarations below; `build.rs` finds and links it). Every process of the
//! job passes one contiguous slab of the node graph (its rows, with global neighbour ids) and
//! gets the part of each of its rows.
//!
//! The layer ignores ParMETIS's options and `ubvec`, and does not report its own failures nor
//! the edge cut: the caller checks the parts it gets (`parts::split`) and measures the cut.
//! Determinism: PT-Scotch's default strategy with its pseudo-random generator reset before
//! every call (`SCOTCH_randomReset`; Debian's build has a fixed seed), so a graph split on the
//! same number of processes gets the same parts on every run. A different process count may
//! give another split, which changes no result (a run's bits do not depend on its partition).

use super::comm::Comm;
use serde::{Deserialize, Serialize};

/// Rows `vtxdist[r]..vtxdist[r + 1]` of the node graph for process r: `xadj` from 0, `adj`
/// the global ids of the rows' neighbours, `weights` the work of each row
/// (`eprop_partition::degree_weights`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Slab {
    pub vtxdist: Vec<u32>,
    pub xadj: Vec<u32>,
    pub adj: Vec<u32>,
    pub weights: Vec<u32>,
}

impl Slab {
    /// The slab of process `r` of `size` from the whole graph: the rows are cut into `size`
    /// contiguous blocks of nearly equal length.
    pub fn of(xadj: &[usize], adj: &[u32], weights: &[u32], size: usize, r: usize) -> Slab {
        let n = xadj.len() - 1;
        let vtxdist: Vec<u32> = (0..=size).map(|q| (q * n / size) as u32).collect();
        let (lo, hi) = (vtxdist[r] as usize, vtxdist[r + 1] as usize);
        Slab {
            xadj: xadj[lo..=hi].iter().map(|&x| (x - xadj[lo]) as u32).collect(),
            adj: adj[xadj[lo]..xadj[hi]].to_vec(),
            weights: weights[lo..hi].to_vec(),
            vtxdist,
        }
    }

    /// Its rows.
    pub fn n_rows(&self) -> usize {
        self.xadj.len() - 1
    }
}

/// Whether this build has PT-Scotch.
pub const AVAILABLE: bool = cfg!(eprop_ptscotch);

#[cfg(eprop_ptscotch)]
mod ffi {
    use crate::distribute::comm::RawComm;
    use std::os::raw::{c_float, c_int};

    /// SCOTCH_Num: int in the build that `build.rs` accepts.
    pub type Num = c_int;
    pub const METIS_OK: c_int = 1;

    extern "C" {
        pub fn ParMETIS_V3_PartKway(
            vtxdist: *const Num,
            xadj: *mut Num,
            adjncy: *mut Num,
            vwgt: *mut Num,
            adjwgt: *mut Num,
            wgtflag: *const Num,
            numflag: *const Num,
            ncon: *const Num,
            nparts: *const Num,
            tpwgts: *const c_float,
            ubvec: *const c_float,
            options: *const Num,
            edgecut: *mut Num,
            part: *mut Num,
            comm: *mut RawComm,
        ) -> c_int;
        pub fn SCOTCH_randomReset();
    }
}

/// PT-Scotch on one thread per process: its threaded stages split differently from run to
/// run, so its thread count is set to 1 (`SCOTCH_PTHREAD_NUMBER`, which it reads when a call
/// sets up its threads) before its first call, at a time this process does not read its
/// environment elsewhere.
#[cfg(eprop_ptscotch)]
fn one_thread() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| std::env::set_var("SCOTCH_PTHREAD_NUMBER", "1"));
}

/// The part (in `0..nparts`) of each row of this process's slab, or why there is none.
/// Every process of `comm` calls, each with its slab of the same graph.
#[cfg(eprop_ptscotch)]
pub(crate) fn part_kway(slab: &Slab, nparts: usize, comm: super::comm::RawComm) -> Result<Vec<u32>, String> {
    use ffi::Num;
    let to_num = |v: &[u32]| -> Result<Vec<Num>, String> {
        v.iter()
            .map(|&x| Num::try_from(x).map_err(|_| format!("{x} does not fit PT-Scotch's 32-bit integers")))
            .collect()
    };
    let vtxdist = to_num(&slab.vtxdist)?;
    let mut xadj = to_num(&slab.xadj)?;
    let mut adj = to_num(&slab.adj)?;
    let mut vwgt = to_num(&slab.weights)?;
    let n = slab.n_rows();
    // a zero-length slice's pointer is dangling, never null: PT-Scotch reads none of it
    let mut part: Vec<Num> = vec![-1; n.max(1)];
    // equal targets (the layer takes them as proportions)
    let tpwgts = vec![1.0f32; nparts];
    let ubvec = [1.05f32];
    let options: [Num; 3] = [0, 0, 0];
    let (wgtflag, numflag, ncon, np) = (2 as Num, 0 as Num, 1 as Num, nparts as Num);
    let mut edgecut: Num = 0;
    let mut comm = comm;
    // SAFETY: the arrays have the lengths the ParMETIS V3 interface reads (vtxdist: processes
    // + 1, xadj: rows + 1, adjncy: xadj[rows], vwgt and part: rows, tpwgts: nparts), and the
    // communicator is a valid one that every process passes at the same time
    one_thread();
    let code = unsafe {
        ffi::SCOTCH_randomReset();
        ffi::ParMETIS_V3_PartKway(
            vtxdist.as_ptr(),
            xadj.as_mut_ptr(),
            adj.as_mut_ptr(),
            vwgt.as_mut_ptr(),
            std::ptr::null_mut(),
            &wgtflag,
            &numflag,
            &ncon,
            &np,
            tpwgts.as_ptr(),
            ubvec.as_ptr(),
            options.as_ptr(),
            &mut edgecut,
            part.as_mut_ptr(),
            &mut comm,
        )
    };
    if code != ffi::METIS_OK {
        return Err(format!("PT-Scotch failed (code {code})"));
    }
    part.truncate(n);
    part.iter()
        .map(|&p| {
            u32::try_from(p)
                .ok()
                .filter(|&p| (p as usize) < nparts)
                .ok_or_else(|| format!("PT-Scotch gave part {p} for {nparts} parts"))
        })
        .collect()
}

/// Without PT-Scotch in the build: never called (`AVAILABLE` is false).
#[cfg(not(eprop_ptscotch))]
pub(crate) fn part_kway(_: &Slab, _: usize, _: super::comm::RawComm) -> Result<Vec<u32>, String> {
    Err("this build has no PT-Scotch".into())
}

/// The PT-Scotch split of a whole graph that every process of `world` holds (`eprop
/// partition`): each passes its slab, every process gets every node's part in `0..nparts`.
/// One process (`None`) splits alone on MPI_COMM_SELF (MPI started for it).
pub fn split_whole(
    world: Option<&dyn Comm>,
    xadj: &[usize],
    adj: &[u32],
    weights: &[u32],
    nparts: usize,
) -> anyhow::Result<Vec<u32>> {
    use anyhow::{anyhow, bail};
    if !AVAILABLE {
        bail!("this build has no PT-Scotch (see build.rs)");
    }
    let (rank, size) = world.map_or((0, 1), |w| (w.rank(), w.size()));
    let slab = Slab::of(xadj, adj, weights, size, rank);
    let mine = match world.and_then(|w| w.handle()) {
        Some(h) => {
            let own = h.duplicate();
            part_kway(&slab, nparts, own.raw())
        }
        None => {
            super::launch::start_alone()?;
            let raw = super::comm::Serial
                .raw()
                .ok_or_else(|| anyhow!("internal: MPI_COMM_SELF is not available"))?;
            part_kway(&slab, nparts, raw)
        }
    };
    // a part left empty is an error, as on every other path of the split
    let checked = |part: Vec<u32>| -> anyhow::Result<Vec<u32>> {
        eprop_partition::check_parts(&part, nparts).map_err(|e| anyhow!("PT-Scotch: {e}"))?;
        Ok(part)
    };
    let Some(w) = world else {
        return mine.map_err(|e| anyhow!(e)).and_then(checked);
    };
    let failed = w.max(f64::from(u8::from(mine.is_err())));
    if failed > 0.0 {
        bail!(
            "PT-Scotch failed{}",
            mine.err().map(|e| format!(": {e}")).unwrap_or_default()
        );
    }
    let local: Vec<f64> = mine.unwrap_or_default().iter().map(|&p| p as f64).collect();
    let (all, _) = w.all_gather_var(&local);
    checked(all.iter().map(|&p| p as u32).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slabs_cover_the_graph_in_order() {
        // a path of 10 nodes in 3 slabs
        let n = 10usize;
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
        let w = eprop_partition::degree_weights(&xadj);
        let slabs: Vec<Slab> = (0..3).map(|r| Slab::of(&xadj, &adj, &w, 3, r)).collect();
        assert_eq!(slabs[0].vtxdist, vec![0, 3, 6, 10]);
        assert_eq!(slabs.iter().map(Slab::n_rows).sum::<usize>(), n);
        let joined: Vec<u32> = slabs.iter().flat_map(|s| s.adj.clone()).collect();
        assert_eq!(joined, adj);
        assert_eq!(slabs[2].xadj, vec![0, 2, 4, 6, 7]);
        assert_eq!(slabs[1].weights, vec![3, 3, 3]);
    }
}
