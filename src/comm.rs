//! Collective communication between the processes of a run: reductions, broadcasts, gathers
//! and the all-to-all of the output scatter. (Point-to-point halo messages are `scatter::Halo`.)
//!
//! `Serial` is the one-process case; `Mpi` uses rsmpi collectives. Every reduction whose
//! result feeds the computation is exact (max, min, or a fixed-point sum), so the result does
//! not depend on how many processes there are or how the mesh was split.

pub trait Comm {
    fn rank(&self) -> usize;
    fn size(&self) -> usize;
    fn max(&self, x: f64) -> f64;
    fn min(&self, x: f64) -> f64;
    /// Sums the integer parts of every process in rank order (exact).
    fn sum_i128(&self, x: i128) -> i128;
    /// Broadcasts `x` from `root`.
    fn broadcast(&self, root: usize, x: &mut [f64]);
    /// Personalised all-to-all: `send` holds `counts[q]` values for process q, in rank order;
    /// returns what every process sent here, in rank order.
    fn all_to_all(&self, send: &[f64], counts: &[usize]) -> Vec<f64>;
    /// Every process's `x`, in rank order.
    fn all_gather(&self, x: &[f64]) -> Vec<f64>;
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
    fn all_to_all(&self, send: &[f64], _: &[usize]) -> Vec<f64> {
        send.to_vec()
    }
    fn all_gather(&self, x: &[f64]) -> Vec<f64> {
        x.to_vec()
    }
    fn abort(&self, code: i32) -> ! {
        std::process::exit(code)
    }
}

/// Several processes under MPI.
pub struct Mpi {
    pub world: mpi::topology::SimpleCommunicator,
}

use mpi::collective::SystemOperation;
use mpi::datatype::PartitionMut;
use mpi::topology::Communicator;
use mpi::traits::*;

impl Mpi {
    pub fn new(world: mpi::topology::SimpleCommunicator) -> Mpi {
        Mpi { world }
    }
}

impl Comm for Mpi {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }
    fn size(&self) -> usize {
        self.world.size() as usize
    }
    fn all_to_all(&self, send: &[f64], counts: &[usize]) -> Vec<f64> {
        let sc: Vec<i32> = counts.iter().map(|&c| c as i32).collect();
        let mut rc = vec![0i32; sc.len()];
        self.world.all_to_all_into(&sc[..], &mut rc[..]);
        let (sd, rd) = (displacements(&sc), displacements(&rc));
        let mut out = vec![0.0; rc.iter().sum::<i32>() as usize];
        {
            let sp = mpi::datatype::Partition::new(send, &sc[..], &sd[..]);
            let mut rp = PartitionMut::new(&mut out[..], &rc[..], &rd[..]);
            self.world.all_to_all_varcount_into(&sp, &mut rp);
        }
        out
    }
    fn all_gather(&self, x: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; x.len() * self.size()];
        self.world.all_gather_into(x, &mut out[..]);
        out
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
    fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }
}
