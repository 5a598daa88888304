//! Communication between the processes of a run: halo exchange, reductions, gathers.
//!
//! `Serial` is the one-process case; `Mpi` uses rsmpi point-to-point messages for halos and
//! collectives for the rest. Every reduction whose result feeds the computation is exact
//! (max, min, or a fixed-point sum), so the result does not depend on how many processes
//! there are or how the mesh was split.

use eprop_partition::Plan;

pub trait Comm {
    fn rank(&self) -> usize;
    fn size(&self) -> usize;
    /// Overwrites the halo entries of `data` (items of `stride` f64) with their owners' values.
    fn exchange(&self, data: &mut [f64], stride: usize);
    fn max(&self, x: f64) -> f64;
    fn min(&self, x: f64) -> f64;
    /// Sums the integer parts of every process in rank order (exact).
    fn sum_i128(&self, x: i128) -> i128;
    /// Broadcasts `x` from `root`.
    fn broadcast(&self, root: usize, x: &mut [f64]);
    /// Gathers owned items (`stride` f64 each) to rank 0 in global node order.
    fn gather(&self, owned: &[f64], stride: usize) -> Option<Vec<f64>>;
    /// Ends every process after an error on this one.
    fn abort(&self, code: i32) -> !;
}

/// An exact, order-independent sum of f64 values spread over processes: every value is
/// rounded to a fixed-point grid set by the global largest magnitude, and integers add
/// associatively. Relative accuracy about 2^-100 of the largest term.
pub fn exact_sum(comm: &dyn Comm, local: impl Iterator<Item = f64> + Clone) -> f64 {
    let m = comm.max(local.clone().fold(0.0f64, |a, x| a.max(x.abs())));
    if m == 0.0 || !m.is_finite() {
        return if m == 0.0 { 0.0 } else { f64::NAN };
    }
    let e = m.log2().ceil() as i32;
    let k = 100 - e; // |x| * 2^k < 2^100
    let (a, b) = (k / 2, k - k / 2);
    let (sa, sb) = (2f64.powi(a), 2f64.powi(b));
    let part: i128 = local.map(|x| (x * sa * sb) as i128).sum();
    let total = comm.sum_i128(part);
    (total as f64) / sa / sb
}

/// Exclusive prefix sums of message sizes (MPI displacements).
fn displacements(counts: &[i32]) -> Vec<i32> {
    let mut d = Vec::with_capacity(counts.len());
    let mut at = 0;
    for &c in counts {
        d.push(at);
        at += c;
    }
    d
}

/// One process: nothing to exchange.
pub struct Serial;

impl Comm for Serial {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn exchange(&self, _: &mut [f64], _: usize) {}
    fn max(&self, x: f64) -> f64 {
        x
    }
    fn min(&self, x: f64) -> f64 {
        x
    }
    fn sum_i128(&self, x: i128) -> i128 {
        x
    }
    fn broadcast(&self, _: usize, _: &mut [f64]) {}
    fn gather(&self, owned: &[f64], _: usize) -> Option<Vec<f64>> {
        Some(owned.to_vec())
    }
    fn abort(&self, code: i32) -> ! {
        std::process::exit(code)
    }
}

/// Several processes under MPI.
pub struct Mpi {
    pub world: mpi::topology::SimpleCommunicator,
    pub plan: Plan,
    /// Global ids of every rank's owned nodes, concatenated in rank order (rank 0 only).
    owned_all: Vec<u32>,
    counts: Vec<usize>,
    n_global: usize,
}

use mpi::collective::SystemOperation;
use mpi::datatype::PartitionMut;
use mpi::point_to_point::{Destination, Source};
use mpi::topology::Communicator;
use mpi::traits::*;

impl Mpi {
    pub fn new(world: mpi::topology::SimpleCommunicator, plan: Plan, n_global: usize) -> Mpi {
        let size = world.size() as usize;
        let root = world.process_at_rank(0);
        let mine: Vec<u32> = plan.global[..plan.n_owned].to_vec();
        let n_mine = mine.len() as i32;
        let (owned_all, counts) = if world.rank() == 0 {
            let mut counts = vec![0i32; size];
            root.gather_into_root(&n_mine, &mut counts[..]);
            let displs = displacements(&counts);
            let mut all = vec![0u32; counts.iter().sum::<i32>() as usize];
            {
                let mut part = PartitionMut::new(&mut all[..], &counts[..], &displs[..]);
                root.gather_varcount_into_root(&mine[..], &mut part);
            }
            (all, counts.iter().map(|&c| c as usize).collect())
        } else {
            root.gather_into(&n_mine);
            root.gather_varcount_into(&mine[..]);
            (vec![], vec![])
        };
        Mpi {
            world,
            plan,
            owned_all,
            counts,
            n_global,
        }
    }
}

impl Comm for Mpi {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }
    fn size(&self) -> usize {
        self.world.size() as usize
    }
    fn exchange(&self, data: &mut [f64], stride: usize) {
        let nbs = &self.plan.neighbours;
        let sends: Vec<Vec<f64>> = nbs
            .iter()
            .map(|nb| {
                let mut b = Vec::with_capacity(nb.send.len() * stride);
                for &l in &nb.send {
                    b.extend_from_slice(&data[l as usize * stride..(l as usize + 1) * stride]);
                }
                b
            })
            .collect();
        let mut recvs: Vec<Vec<f64>> = nbs.iter().map(|nb| vec![0.0; nb.recv.len() * stride]).collect();
        mpi::request::scope(|scope| {
            let mut reqs = Vec::with_capacity(2 * nbs.len());
            for (nb, buf) in nbs.iter().zip(recvs.iter_mut()) {
                reqs.push(
                    self.world
                        .process_at_rank(nb.rank as i32)
                        .immediate_receive_into(scope, &mut buf[..]),
                );
            }
            let mut sreqs = Vec::with_capacity(nbs.len());
            for (nb, buf) in nbs.iter().zip(sends.iter()) {
                sreqs.push(
                    self.world
                        .process_at_rank(nb.rank as i32)
                        .immediate_send(scope, &buf[..]),
                );
            }
            for r in reqs {
                r.wait();
            }
            for r in sreqs {
                r.wait();
            }
        });
        for (nb, buf) in nbs.iter().zip(recvs.iter()) {
            for (k, &l) in nb.recv.iter().enumerate() {
                data[l as usize * stride..(l as usize + 1) * stride]
                    .copy_from_slice(&buf[k * stride..(k + 1) * stride]);
            }
        }
    }
    fn max(&self, x: f64) -> f64 {
        let mut y = 0.0;
        self.world.all_reduce_into(&x, &mut y, SystemOperation::max());
        y
    }
    fn min(&self, x: f64) -> f64 {
        let mut y = 0.0;
        self.world.all_reduce_into(&x, &mut y, SystemOperation::min());
        y
    }
    fn sum_i128(&self, x: i128) -> i128 {
        let parts = [(x as u128 >> 64) as u64, x as u128 as u64];
        let mut all = vec![0u64; 2 * self.size()];
        self.world.all_gather_into(&parts[..], &mut all[..]);
        all.chunks(2)
            .map(|p| (((p[0] as u128) << 64) | p[1] as u128) as i128)
            .fold(0i128, |a, b| a.wrapping_add(b))
    }
    fn broadcast(&self, root: usize, x: &mut [f64]) {
        self.world.process_at_rank(root as i32).broadcast_into(x);
    }
    fn gather(&self, owned: &[f64], stride: usize) -> Option<Vec<f64>> {
        let root = self.world.process_at_rank(0);
        if self.world.rank() == 0 {
            let counts: Vec<i32> = self.counts.iter().map(|&c| (c * stride) as i32).collect();
            let displs = displacements(&counts);
            let mut buf = vec![0.0; self.owned_all.len() * stride];
            {
                let mut part = PartitionMut::new(&mut buf[..], &counts[..], &displs[..]);
                root.gather_varcount_into_root(owned, &mut part);
            }
            let mut out = vec![0.0; self.n_global * stride];
            for (k, &g) in self.owned_all.iter().enumerate() {
                out[g as usize * stride..(g as usize + 1) * stride].copy_from_slice(&buf[k * stride..(k + 1) * stride]);
            }
            Some(out)
        } else {
            root.gather_varcount_into(owned);
            None
        }
    }
    fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }
}
