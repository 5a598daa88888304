//! Moving per-node values between processes: the halo exchange (owners to the processes that
//! mirror their nodes, every substep) and the block scatter (owned values to contiguous blocks
//! of the global node order, for output and restart).
//!
//! `Halo` is a begin/end pair: `start` packs the owned values the neighbours need and posts
//! the messages, the caller works on rows that read owned values only (calling
//! `Exchange::progress` between pieces so MPI moves rendezvous-size messages while it works),
//! and `finish` waits and writes the halo entries. Halo entries are written nowhere else.

use crate::distribute::comm::{displacements, Comm, Handle};
use eprop_partition::{HaloPattern, Neighbour};
use mpi::ffi;
use mpi::raw::AsRaw;
use std::cell::{Cell, RefCell, RefMut};

/// The halo exchange of one process.
pub struct Halo {
    pattern: HaloPattern,
    /// A communicator of its own (no message of the exchange can meet another's); none on one
    /// process.
    comm: Option<Handle>,
    bufs: RefCell<Buffers>,
    waited: Cell<f64>,
}

/// Message buffers per neighbour, reused by every exchange.
#[derive(Default)]
struct Buffers {
    send: Vec<Vec<f64>>,
    recv: Vec<Vec<f64>>,
}

impl Halo {
    /// One process: nothing to exchange.
    pub fn serial() -> Halo {
        Halo {
            pattern: HaloPattern::default(),
            comm: None,
            bufs: Default::default(),
            waited: Default::default(),
        }
    }

    /// A halo along `pattern` that exchanges nothing (tests: halo entries written by hand
    /// stand for the owners' values).
    pub fn without_comm(pattern: HaloPattern) -> Halo {
        Halo {
            pattern,
            comm: None,
            bufs: Default::default(),
            waited: Default::default(),
        }
    }

    /// Exchanges along `pattern` over `comm` (which the halo keeps to itself).
    pub(crate) fn new(pattern: HaloPattern, comm: Handle) -> Halo {
        Halo {
            pattern,
            comm: Some(comm),
            bufs: Default::default(),
            waited: Default::default(),
        }
    }

    pub fn pattern(&self) -> &HaloPattern {
        &self.pattern
    }

    /// Posts the exchange of `data` (items of `stride` f64, local numbering): the owned values
    /// the neighbours need are copied out now, so `data` may be read while the messages are in
    /// flight; `Exchange::finish` writes the halo entries.
    pub fn start(&self, data: &[f64], stride: usize) -> Exchange<'_> {
        self.start_part(data, stride, stride)
    }

    /// `start` for items of `stride` f64 of which only the first `width` are exchanged (a
    /// padded layout sends what an unpadded one does, so processes may use either).
    pub fn start_part(&self, data: &[f64], stride: usize, width: usize) -> Exchange<'_> {
        assert!(width <= stride);
        let mut bufs = self.bufs.borrow_mut();
        let nbs = &self.pattern.neighbours;
        let mut reqs = Vec::with_capacity(2 * nbs.len());
        if let Some(comm) = self.comm.as_ref().map(Handle::communicator) {
            let Buffers { send, recv } = &mut *bufs;
            send.resize_with(nbs.len(), Vec::new);
            recv.resize_with(nbs.len(), Vec::new);
            for (nb, b) in nbs.iter().zip(send.iter_mut()) {
                b.clear();
                for &l in &nb.send {
                    b.extend_from_slice(&data[l as usize * stride..l as usize * stride + width]);
                }
            }
            for (nb, b) in nbs.iter().zip(recv.iter_mut()) {
                b.resize(nb.recv.len() * width, 0.0);
            }
            let raw = comm.as_raw();
            let idle = |k: usize| send[k].is_empty() && recv[k].is_empty();
            let idle: Vec<bool> = (0..nbs.len()).map(idle).collect();
            // SAFETY: the buffers stay borrowed (and so neither move nor change) by the
            // returned `Exchange` until every request completes, in `finish` or in its drop.
            unsafe {
                post(&mut reqs, nbs, recv, &idle, |b, n, rank, r| {
                    ffi::MPI_Irecv(b, n, ffi::RSMPI_DOUBLE, rank, 0, raw, r)
                });
                post(&mut reqs, nbs, send, &idle, |b, n, rank, r| {
                    ffi::MPI_Isend(b, n, ffi::RSMPI_DOUBLE, rank, 0, raw, r)
                });
            }
        }
        Exchange {
            halo: self,
            bufs,
            reqs,
            stride,
            width,
            open: true,
        }
    }

    /// Overwrites the halo entries of `data` with their owners' values (no overlap).
    pub fn exchange(&self, data: &mut [f64], stride: usize) {
        self.start(data, stride).finish(data);
    }

    /// Personalised all-to-all over the halo's communicator, the counts known on both sides:
    /// `send` holds `send_counts[q]` values for process q, and the result `recv_counts[q]`
    /// values from q, in rank order.
    /// The result goes into `out`, exactly as long. On one process nothing moves (`send` and
    /// `out` are empty).
    pub fn all_to_all_into(&self, send: &[f64], send_counts: &[usize], recv_counts: &[usize], out: &mut [f64]) {
        assert_eq!(
            out.len(),
            recv_counts.iter().sum::<usize>(),
            "all_to_all_into: receive length"
        );
        let Some(comm) = self.comm.as_ref().map(Handle::communicator) else {
            out.copy_from_slice(send);
            return;
        };
        use mpi::datatype::{Partition, PartitionMut};
        use mpi::traits::*;
        let sc: Vec<i32> = send_counts.iter().map(|&c| count(c)).collect();
        let rc: Vec<i32> = recv_counts.iter().map(|&c| count(c)).collect();
        let (sd, rd) = (displacements(&sc), displacements(&rc));
        let sp = Partition::new(send, &sc[..], &sd[..]);
        let mut rp = PartitionMut::new(&mut out[..], &rc[..], &rd[..]);
        comm.all_to_all_varcount_into(&sp, &mut rp);
    }

    /// Every process's `x` (`counts[q]` values from process q, known everywhere), in rank
    /// order, into `out` (resized). On one process it is `x` itself.
    pub fn all_gather_into(&self, x: &[f64], counts: &[usize], out: &mut Vec<f64>) {
        let Some(comm) = self.comm.as_ref().map(Handle::communicator) else {
            out.clear();
            out.extend_from_slice(x);
            return;
        };
        use mpi::datatype::PartitionMut;
        use mpi::traits::*;
        let c: Vec<i32> = counts.iter().map(|&c| count(c)).collect();
        let d = displacements(&c);
        out.resize(counts.iter().sum(), 0.0);
        let mut rp = PartitionMut::new(&mut out[..], &c[..], &d[..]);
        comm.all_gather_varcount_into(x, &mut rp);
    }

    /// Seconds spent waiting in `finish` so far.
    pub fn wait_seconds(&self) -> f64 {
        self.waited.get()
    }
}

/// Posts one message per neighbour that is not idle, its buffer in `bufs`, with `call`
/// (`MPI_Irecv` or `MPI_Isend`, given the buffer, its length, the neighbour's rank and the
/// request to fill) and keeps the requests.
///
/// # Safety
/// Every buffer must neither move nor change until its request completes.
unsafe fn post(
    reqs: &mut Vec<ffi::MPI_Request>,
    nbs: &[Neighbour],
    bufs: &mut [Vec<f64>],
    idle: &[bool],
    call: impl Fn(*mut std::ffi::c_void, i32, i32, &mut ffi::MPI_Request) -> i32,
) {
    for ((nb, b), _) in nbs.iter().zip(bufs.iter_mut()).zip(idle).filter(|x| !*x.1) {
        let mut r = ffi::RSMPI_REQUEST_NULL;
        call(b.as_mut_ptr().cast(), count(b.len()), nb.rank as i32, &mut r);
        reqs.push(r);
    }
}

fn count(n: usize) -> i32 {
    i32::try_from(n).expect("a halo message of more than 2^31 values")
}

/// An exchange in flight.
pub struct Exchange<'h> {
    halo: &'h Halo,
    bufs: RefMut<'h, Buffers>,
    reqs: Vec<ffi::MPI_Request>,
    stride: usize,
    width: usize,
    open: bool,
}

impl Exchange<'_> {
    /// Lets MPI move the messages (a test of every request); call it between pieces of work.
    pub fn progress(&mut self) {
        if self.reqs.is_empty() {
            return;
        }
        let mut flag = 0;
        // SAFETY: the requests are live or null; completed ones become null.
        unsafe {
            ffi::MPI_Testall(
                self.reqs.len() as i32,
                self.reqs.as_mut_ptr(),
                &mut flag,
                ffi::RSMPI_STATUSES_IGNORE,
            );
        }
    }

    fn wait(&mut self) {
        if self.open && !self.reqs.is_empty() {
            // SAFETY: as in `progress`
            unsafe {
                ffi::MPI_Waitall(
                    self.reqs.len() as i32,
                    self.reqs.as_mut_ptr(),
                    ffi::RSMPI_STATUSES_IGNORE,
                );
            }
        }
        self.open = false;
    }

    /// Waits for the messages and writes the received values into the halo entries of `data`.
    pub fn finish(mut self, data: &mut [f64]) {
        let t = std::time::Instant::now();
        self.wait();
        let halo = self.halo;
        halo.waited.set(halo.waited.get() + t.elapsed().as_secs_f64());
        let (s, w) = (self.stride, self.width);
        for (nb, buf) in halo.pattern.neighbours.iter().zip(self.bufs.recv.iter()) {
            for (k, &l) in nb.recv.iter().enumerate() {
                data[l as usize * s..l as usize * s + w].copy_from_slice(&buf[k * w..(k + 1) * w]);
            }
        }
    }
}

impl Drop for Exchange<'_> {
    /// An exchange dropped unfinished (an early return) still completes its messages before
    /// its buffers are released.
    fn drop(&mut self) {
        self.wait();
    }
}

/// Moves owned values into contiguous blocks of the global node order for output: process r
/// holds rows `start..start + len`, with `start = r N / P`. Built once; each use is one
/// all-to-all, so no process ever holds a global array.
pub struct BlockScatter {
    pub start: usize,
    pub len: usize,
    send_order: Vec<u32>,
    counts: Vec<usize>,
    recv_counts: Vec<usize>,
    place: Vec<u32>,
}

impl BlockScatter {
    pub fn new(gid_owned: &[u64], n_global: usize, comm: &dyn Comm) -> BlockScatter {
        let p = comm.size();
        let first = |r: usize| (r * n_global) / p;
        let owner = |g: u64| {
            // the last r with first(r) <= g
            let mut r = ((g as usize + 1) * p).div_ceil(n_global.max(1)).min(p) - 1;
            while first(r) > g as usize {
                r -= 1;
            }
            while r + 1 < p && first(r + 1) <= g as usize {
                r += 1;
            }
            r
        };
        let mut items: Vec<(usize, u64, u32)> = gid_owned
            .iter()
            .enumerate()
            .map(|(l, &g)| (owner(g), g, l as u32))
            .collect();
        items.sort_unstable();
        let mut counts = vec![0usize; p];
        for it in &items {
            counts[it.0] += 1;
        }
        let gids: Vec<f64> = items.iter().map(|it| it.1 as f64).collect();
        let me = comm.rank();
        let start = first(me);
        let got = comm.all_to_all(&gids, &counts);
        let cf: Vec<f64> = counts.iter().map(|&c| c as f64).collect();
        let recv_counts = comm.all_to_all(&cf, &vec![1; p]).iter().map(|&c| c as usize).collect();
        BlockScatter {
            recv_counts,
            start,
            len: first(me + 1) - start,
            send_order: items.iter().map(|it| it.2).collect(),
            counts,
            place: got.iter().map(|&g| (g as usize - start) as u32).collect(),
        }
    }

    /// This process's block of a per-node array (`stride` values per node) from the owned values.
    pub fn collect(&self, owned: &[f64], stride: usize, comm: &dyn Comm) -> Vec<f64> {
        let mut send = Vec::with_capacity(self.send_order.len() * stride);
        for &l in &self.send_order {
            send.extend_from_slice(&owned[l as usize * stride..(l as usize + 1) * stride]);
        }
        let counts: Vec<usize> = self.counts.iter().map(|c| c * stride).collect();
        let got = comm.all_to_all(&send, &counts);
        let mut out = vec![0.0; self.len * stride];
        for (k, &at) in self.place.iter().enumerate() {
            out[at as usize * stride..(at as usize + 1) * stride].copy_from_slice(&got[k * stride..(k + 1) * stride]);
        }
        out
    }

    /// The inverse of `collect`: the owned values (local order) from this process's block.
    pub fn distribute(&self, block: &[f64], stride: usize, comm: &dyn Comm) -> Vec<f64> {
        let mut send = Vec::with_capacity(self.place.len() * stride);
        for &at in &self.place {
            send.extend_from_slice(&block[at as usize * stride..(at as usize + 1) * stride]);
        }
        let counts: Vec<usize> = self.recv_counts.iter().map(|c| c * stride).collect();
        let got = comm.all_to_all(&send, &counts);
        let mut out = vec![0.0; self.send_order.len() * stride];
        for (k, &l) in self.send_order.iter().enumerate() {
            out[l as usize * stride..(l as usize + 1) * stride].copy_from_slice(&got[k * stride..(k + 1) * stride]);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::distribute::comm::Serial;

    #[test]
    fn a_serial_halo_changes_nothing() {
        let h = Halo::serial();
        let mut x = vec![1.0, 2.0, 3.0];
        let mut e = h.start(&x, 3);
        e.progress();
        e.finish(&mut x);
        assert_eq!(x, [1.0, 2.0, 3.0]);
        assert_eq!(h.pattern().n_recv(), 0);
    }

    #[test]
    fn one_block_is_the_global_order() {
        // owned nodes in local order hold global ids 2, 0, 1
        let b = BlockScatter::new(&[2, 0, 1], 3, &Serial);
        assert_eq!((b.start, b.len), (0, 3));
        let block = b.collect(&[20.0, 21.0, 0.0, 1.0, 10.0, 11.0], 2, &Serial);
        assert_eq!(block, [0.0, 1.0, 10.0, 11.0, 20.0, 21.0]);
        assert_eq!(b.distribute(&block, 2, &Serial), [20.0, 21.0, 0.0, 1.0, 10.0, 11.0]);
    }
}
