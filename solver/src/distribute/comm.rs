//! Collective communication between the processes of a run: reductions, broadcasts, gathers
//! and the all-to-all of the output scatter. (Point-to-point halo messages are `halo::Halo`.)
//!
//! `Serial` is the one-process case; `Mpi` uses rsmpi collectives. Every reduction whose
//! result feeds the computation is exact (max, min, or a fixed-point sum), so the result does
//! not depend on how many processes there are or how the mesh was split.
//!
//! `Comm` is the one communicator the rest of the crate holds. A library that takes an MPI
//! communicator itself gets it from the `Comm` as an opaque `Handle` (`Comm::handle`: the
//! series' collective output) or as a C handle (`Comm::raw`: hypre), so that only this module
//! names MPI's types.

pub trait Comm {
    fn rank(&self) -> usize;
    fn size(&self) -> usize;
    fn max(&self, x: f64) -> f64;
    fn min(&self, x: f64) -> f64;
    /// Sums the integer parts of every process in rank order (exact below 2^127 in all: for
    /// counts).
    fn sum_i128(&self, x: i128) -> i128;
    /// Sums 256-bit integers over every process, element by element (exact).
    fn sum_wide(&self, x: &[Wide]) -> Vec<Wide>;
    /// The largest of every process's values, element by element.
    fn max_each(&self, x: &[f64]) -> Vec<f64>;
    /// Broadcasts `x` from `root`.
    fn broadcast(&self, root: usize, x: &mut [f64]);
    /// Personalised all-to-all: `send` holds `counts[q]` values for process q, in rank order;
    /// returns what every process sent here, in rank order.
    fn all_to_all(&self, send: &[f64], counts: &[usize]) -> Vec<f64>;
    /// Every process's `x`, in rank order.
    fn all_gather(&self, x: &[f64]) -> Vec<f64>;
    /// Every process's `x` of any length, in rank order, with the lengths.
    fn all_gather_var(&self, x: &[f64]) -> (Vec<f64>, Vec<usize>);
    /// Ends every process after an error on this one.
    fn abort(&self, code: i32) -> !;
    /// The MPI communicator of these processes, for a library that takes one (the series'
    /// collective output); None on one process without MPI.
    fn handle(&self) -> Option<&Handle> {
        None
    }
    /// The C handle of these processes' communicator, for a C library that takes one
    /// (hypre): `handle`'s, or for one process without one MPI_COMM_SELF once MPI runs (the
    /// launcher starts it: `launch::start_alone`); None otherwise.
    fn raw(&self) -> Option<RawComm> {
        match self.handle() {
            Some(h) => Some(h.raw()),
            None if self.size() == 1 && mpi::environment::is_initialized() => {
                // SAFETY: MPI runs, so its predefined self communicator is valid
                Some(RawComm(unsafe { mpi::ffi::RSMPI_COMM_SELF }))
            }
            None => None,
        }
    }
}

/// An MPI communicator, opaque: what `Comm::handle` gives a library that takes a
/// communicator (the series crate's collective output, built on rsmpi).
pub struct Handle(mpi::topology::SimpleCommunicator);

impl Handle {
    /// The communicator as rsmpi has it, for a library built on rsmpi (eprop-series).
    pub fn communicator(&self) -> &mpi::topology::SimpleCommunicator {
        &self.0
    }

    /// Its C handle (`MPI_Comm`), for a C library.
    pub fn raw(&self) -> RawComm {
        use mpi::raw::AsRaw;
        RawComm(self.0.as_raw())
    }

    /// Another communicator of the same processes, whose messages never meet this one's
    /// (MPI_Comm_dup: every process calls).
    pub(crate) fn duplicate(&self) -> Handle {
        Handle(self.0.duplicate())
    }
}

/// The C handle of an MPI communicator (`MPI_Comm`), for the declarations of a C library's
/// functions that take one (hypre's): passed as MPI_Comm itself (a transparent wrapper).
#[repr(transparent)]
#[derive(Clone, Copy, Debug)]
pub struct RawComm(mpi::ffi::MPI_Comm);

/// A 256-bit two's-complement integer (`hi * 2^128 + lo`): the accumulator of `reproducible_sum`.
/// Terms are below 2^100 in magnitude, so about 2^155 of them fit: no node count overflows it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Wide {
    pub hi: i128,
    pub lo: u128,
}

impl Wide {
    pub fn from_i128(x: i128) -> Wide {
        Wide {
            hi: if x < 0 { -1 } else { 0 },
            lo: x as u128,
        }
    }
    pub fn plus(self, o: Wide) -> Wide {
        let (lo, carry) = self.lo.overflowing_add(o.lo);
        Wide {
            hi: self.hi.wrapping_add(o.hi).wrapping_add(carry as i128),
            lo,
        }
    }
    pub fn add_i128(self, x: i128) -> Wide {
        self.plus(Wide::from_i128(x))
    }
    fn neg(self) -> Wide {
        let (lo, carry) = (!self.lo).overflowing_add(1);
        Wide {
            hi: (!self.hi).wrapping_add(carry as i128),
            lo,
        }
    }
    /// The value as f64: exactly rounded while it fits in an i128, the nearest or next-nearest
    /// f64 beyond (a function of the integer alone, so the same on any number of processes).
    pub fn to_f64(self) -> f64 {
        if self.hi == (self.lo as i128 >> 127) {
            return self.lo as i128 as f64;
        }
        let (neg, m) = if self.hi < 0 { (true, self.neg()) } else { (false, self) };
        let v = m.hi as f64 * 2f64.powi(128) + m.lo as f64;
        if neg {
            -v
        } else {
            v
        }
    }
    /// The four 64-bit words, least significant first (for messages).
    pub fn words(self) -> [u64; 4] {
        [
            self.lo as u64,
            (self.lo >> 64) as u64,
            self.hi as u64,
            (self.hi >> 64) as u64,
        ]
    }
    pub fn from_words(w: &[u64]) -> Wide {
        Wide {
            lo: w[0] as u128 | (w[1] as u128) << 64,
            hi: (w[2] as u128 | (w[3] as u128) << 64) as i128,
        }
    }
}

/// The bounding box (lowest and highest coordinates) of every process's `points` (exact: a
/// max over the processes of each coordinate and its negation). Every process calls.
pub fn bounds(comm: &dyn Comm, points: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut ends = [f64::NEG_INFINITY; 6];
    for p in points {
        for d in 0..3 {
            ends[d] = ends[d].max(-p[d]);
            ends[d + 3] = ends[d + 3].max(p[d]);
        }
    }
    let ends = comm.max_each(&ends);
    ([-ends[0], -ends[1], -ends[2]], [ends[3], ends[4], ends[5]])
}

/// A reproducible, order-independent sum of f64 values spread over processes: the sum of the
/// terms truncated to one fixed-point grid, added exactly (not the exact sum of the terms).
///
/// What it guarantees: with e = ceil(log2 M), M the largest |x| over every process, each term
/// is truncated to the grid 2^(e-100) and the truncated terms are added exactly (256-bit
/// integers, which no count of terms overflows). The result is therefore a function of the
/// multiset of terms only: the same on any number of processes, in any order, on any thread
/// count. Its error is below N 2^(e-100) for N terms (relative to the largest term, N 2^-100),
/// plus one rounding of the total to f64. A non-finite term gives NaN.
pub fn reproducible_sum(comm: &dyn Comm, local: impl Iterator<Item = f64> + Clone) -> f64 {
    let [s] = reproducible_sums(comm, local.map(|x| [x]));
    s
}

/// `reproducible_sum` of K sums at once (one reduction of the maxima, one of the sums).
pub(crate) fn reproducible_sums<const K: usize>(
    comm: &dyn Comm,
    local: impl Iterator<Item = [f64; K]> + Clone,
) -> [f64; K] {
    let mut m = [0.0f64; K];
    for x in local.clone() {
        for k in 0..K {
            // a non-finite term makes the largest magnitude infinite (which survives the max
            // reduction, where NaN might not), and the sum NaN
            m[k] = if x[k].is_finite() {
                m[k].max(x[k].abs())
            } else {
                f64::INFINITY
            };
        }
    }
    let m = comm.max_each(&m);
    let mut out = [0.0; K];
    let mut scales = [(1.0, 1.0); K];
    for k in 0..K {
        if !m[k].is_finite() {
            out[k] = f64::NAN;
        } else if m[k] > 0.0 {
            let e = m[k].log2().ceil() as i32;
            let q = 100 - e; // |x| * 2^q <= 2^100
                             // two factors, so neither over- nor underflows for any finite M
            scales[k] = (2f64.powi(q / 2), 2f64.powi(q - q / 2));
        }
    }
    let mut part = [Wide::default(); K];
    for x in local {
        for k in 0..K {
            let (sa, sb) = scales[k];
            part[k] = part[k].add_i128((x[k] * sa * sb) as i128);
        }
    }
    let total = comm.sum_wide(&part);
    for k in 0..K {
        if m[k].is_finite() && m[k] > 0.0 {
            let (sa, sb) = scales[k];
            out[k] = total[k].to_f64() / sa / sb;
        }
    }
    out
}

/// `reproducible_sums` of K sums over the terms `term(0..n)`, computed by the rayon threads in
/// blocks (the same result: the terms are truncated to the same grid and added exactly, so the
/// grouping does not matter). For the dot products of the implicit solves, where one pass
/// over a few hundred thousand nodes must cost no more than an operator application.
pub fn reproducible_sums_par<const K: usize, F>(comm: &dyn Comm, n: usize, term: F) -> [f64; K]
where
    F: Fn(usize) -> [f64; K] + Sync,
{
    use rayon::prelude::*;
    const BLOCK: usize = 4096;
    let blocks = n.div_ceil(BLOCK);
    let range = |b: usize| b * BLOCK..((b + 1) * BLOCK).min(n);
    let m = (0..blocks)
        .into_par_iter()
        .map(|b| {
            let mut m = [0.0f64; K];
            for i in range(b) {
                let x = term(i);
                for k in 0..K {
                    m[k] = if x[k].is_finite() {
                        m[k].max(x[k].abs())
                    } else {
                        f64::INFINITY
                    };
                }
            }
            m
        })
        .reduce(
            || [0.0; K],
            |a, b| {
                let mut c = [0.0; K];
                for k in 0..K {
                    c[k] = a[k].max(b[k]);
                }
                c
            },
        );
    let m = comm.max_each(&m);
    let grids: [SumGrid; K] = std::array::from_fn(|k| SumGrid::new(m[k]));
    let part = (0..blocks)
        .into_par_iter()
        .map(|b| {
            // one block's integers fit an i128: 4096 terms of at most 2^100
            let mut part = [0i128; K];
            for i in range(b) {
                let x = term(i);
                for k in 0..K {
                    part[k] += grids[k].fixed(x[k]);
                }
            }
            part.map(Wide::from_i128)
        })
        .reduce(
            || [Wide::default(); K],
            |a, b| {
                let mut c = a;
                for k in 0..K {
                    c[k] = c[k].plus(b[k]);
                }
                c
            },
        );
    let total = comm.sum_wide(&part);
    std::array::from_fn(|k| grids[k].value(total[k]))
}

/// The fixed-point grid of a reproducible sum whose terms are at most `m` in magnitude (`m` the same
/// on every process: a maximum or a bound reduced with `Comm::max`): terms are truncated to
/// 2^(e-100), e = ceil(log2 m), and added as integers, as `reproducible_sums` does. A bound above the
/// largest term only coarsens the grid (each doubling costs one of the 100 bits); a
/// non-finite bound makes the sum NaN.
#[derive(Clone, Copy, Debug)]
pub struct SumGrid {
    sa: f64,
    sb: f64,
    /// 0: every term is zero; 1: a grid; 2: NaN
    state: u8,
}

impl SumGrid {
    pub fn new(m: f64) -> SumGrid {
        if !m.is_finite() {
            return SumGrid {
                sa: 0.0,
                sb: 0.0,
                state: 2,
            };
        }
        if !(m > 0.0) {
            return SumGrid {
                sa: 0.0,
                sb: 0.0,
                state: 0,
            };
        }
        let e = m.log2().ceil() as i32;
        let q = 100 - e; // |x| * 2^q <= 2^100
        SumGrid {
            sa: 2f64.powi(q / 2),
            sb: 2f64.powi(q - q / 2),
            state: 1,
        }
    }
    /// The term on the grid, as an integer (|x| <= m).
    #[inline(always)]
    pub fn fixed(&self, x: f64) -> i128 {
        truncate(x * self.sa * self.sb)
    }
    /// The sum of the integers of every process, as f64.
    pub fn value(&self, total: Wide) -> f64 {
        match self.state {
            0 => 0.0,
            1 => total.to_f64() / self.sa / self.sb,
            _ => f64::NAN,
        }
    }
}

/// `y as i128` (truncation toward zero) for |y| <= 2^100, by two 64-bit conversions (one
/// instruction each) instead of the 128-bit library call: y = hi 2^62 + lo exactly, with
/// hi = trunc(y 2^-62) and lo = y - hi 2^62 (exact: it keeps the low bits of y), |lo| < 2^62,
/// and lo has the sign of y, so truncating lo truncates y.
#[inline(always)]
fn truncate(y: f64) -> i128 {
    const S: f64 = (1u64 << 62) as f64;
    let hi = (y * (1.0 / S)) as i64; // truncates; |hi| <= 2^38
    let lo = y - hi as f64 * S;
    ((hi as i128) << 62) + lo as i64 as i128
}

/// Exclusive prefix sums of message sizes (MPI displacements).
pub(crate) fn displacements(counts: &[i32]) -> Vec<i32> {
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
    fn sum_wide(&self, x: &[Wide]) -> Vec<Wide> {
        x.to_vec()
    }
    fn max_each(&self, x: &[f64]) -> Vec<f64> {
        x.to_vec()
    }
    fn broadcast(&self, _: usize, _: &mut [f64]) {}
    fn all_to_all(&self, send: &[f64], _: &[usize]) -> Vec<f64> {
        send.to_vec()
    }
    fn all_gather(&self, x: &[f64]) -> Vec<f64> {
        x.to_vec()
    }
    fn all_gather_var(&self, x: &[f64]) -> (Vec<f64>, Vec<usize>) {
        (x.to_vec(), vec![x.len()])
    }
    fn abort(&self, code: i32) -> ! {
        std::process::exit(code)
    }
}

/// Several processes under MPI.
pub struct Mpi {
    world: Handle,
}

use mpi::collective::SystemOperation;
use mpi::datatype::PartitionMut;
use mpi::topology::Communicator;
use mpi::traits::*;

impl Mpi {
    /// The processes of `world` (the launcher's, or a duplicate of it).
    pub(crate) fn new(world: Handle) -> Mpi {
        Mpi { world }
    }

    /// The processes of an MPI job: its world communicator.
    pub(crate) fn of_job(universe: &mpi::environment::Universe) -> Mpi {
        Mpi::new(Handle(universe.world()))
    }

    fn comm(&self) -> &mpi::topology::SimpleCommunicator {
        &self.world.0
    }

    /// Waits until every process has called.
    pub(crate) fn barrier(&self) {
        self.comm().barrier();
    }
}

impl Comm for Mpi {
    fn rank(&self) -> usize {
        self.comm().rank() as usize
    }
    fn size(&self) -> usize {
        self.comm().size() as usize
    }
    fn all_to_all(&self, send: &[f64], counts: &[usize]) -> Vec<f64> {
        let sc: Vec<i32> = counts.iter().map(|&c| c as i32).collect();
        let mut rc = vec![0i32; sc.len()];
        self.comm().all_to_all_into(&sc[..], &mut rc[..]);
        let (sd, rd) = (displacements(&sc), displacements(&rc));
        let mut out = vec![0.0; rc.iter().sum::<i32>() as usize];
        {
            let sp = mpi::datatype::Partition::new(send, &sc[..], &sd[..]);
            let mut rp = PartitionMut::new(&mut out[..], &rc[..], &rd[..]);
            self.comm().all_to_all_varcount_into(&sp, &mut rp);
        }
        out
    }
    fn all_gather(&self, x: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; x.len() * self.size()];
        self.comm().all_gather_into(x, &mut out[..]);
        out
    }
    fn all_gather_var(&self, x: &[f64]) -> (Vec<f64>, Vec<usize>) {
        let n = i32::try_from(x.len()).expect("a gather of more than 2^31 values");
        let mut counts = vec![0i32; self.size()];
        self.comm().all_gather_into(&n, &mut counts[..]);
        let d = displacements(&counts);
        let mut out = vec![0.0; counts.iter().map(|&c| c as usize).sum()];
        {
            let mut rp = PartitionMut::new(&mut out[..], &counts[..], &d[..]);
            self.comm().all_gather_varcount_into(x, &mut rp);
        }
        (out, counts.iter().map(|&c| c as usize).collect())
    }
    fn max(&self, x: f64) -> f64 {
        let mut y = 0.0;
        self.comm().all_reduce_into(&x, &mut y, SystemOperation::max());
        y
    }
    fn min(&self, x: f64) -> f64 {
        let mut y = 0.0;
        self.comm().all_reduce_into(&x, &mut y, SystemOperation::min());
        y
    }
    fn sum_i128(&self, x: i128) -> i128 {
        let parts = [(x as u128 >> 64) as u64, x as u128 as u64];
        let mut all = vec![0u64; 2 * self.size()];
        self.comm().all_gather_into(&parts[..], &mut all[..]);
        all.chunks(2)
            .map(|p| (((p[0] as u128) << 64) | p[1] as u128) as i128)
            .fold(0i128, |a, b| a.wrapping_add(b))
    }
    fn sum_wide(&self, x: &[Wide]) -> Vec<Wide> {
        let words: Vec<u64> = x.iter().flat_map(|w| w.words()).collect();
        let mut all = vec![0u64; words.len() * self.size()];
        self.comm().all_gather_into(&words[..], &mut all[..]);
        let mut out = vec![Wide::default(); x.len()];
        for part in all.chunks(words.len().max(1)) {
            for (k, o) in out.iter_mut().enumerate() {
                *o = o.plus(Wide::from_words(&part[4 * k..4 * k + 4]));
            }
        }
        out
    }
    fn max_each(&self, x: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; x.len()];
        self.comm().all_reduce_into(x, &mut y[..], SystemOperation::max());
        y
    }
    fn broadcast(&self, root: usize, x: &mut [f64]) {
        self.comm().process_at_rank(root as i32).broadcast_into(x);
    }
    fn abort(&self, code: i32) -> ! {
        self.comm().abort(code)
    }
    fn handle(&self) -> Option<&Handle> {
        Some(&self.world)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wide_integers_add_past_i128() {
        let mut w = Wide::default();
        for _ in 0..4 {
            w = w.add_i128(i128::MAX);
        }
        // 4 (2^127 - 1) = 2^129 - 4
        assert_eq!(
            w,
            Wide {
                hi: 1,
                lo: u128::MAX - 3
            }
        );
        assert_eq!(w.to_f64(), 2f64.powi(129));
        for _ in 0..8 {
            w = w.add_i128(i128::MIN);
        }
        // 2^129 - 4 - 2^130 = -2^129 - 4
        assert_eq!(w.to_f64(), -(2f64.powi(129)));
        assert_eq!(Wide::from_words(&w.words()), w);
        assert_eq!(Wide::from_i128(-5).to_f64(), -5.0);
        assert_eq!(Wide::from_i128(-5).add_i128(5), Wide::default());
    }

    #[test]
    fn reproducible_sum_takes_any_order_and_does_not_overflow() {
        // 2^28 terms of the largest magnitude would wrap a 128-bit accumulator (2^28 2^100 >
        // 2^127); in 256 bits they add exactly
        let n = 1usize << 28;
        let s = reproducible_sum(&Serial, (0..n).map(|_| 1.0));
        assert_eq!(s, n as f64);
        let s = reproducible_sum(&Serial, (0..n).map(|i| if i % 3 == 0 { -1e300 } else { 1e300 }));
        assert_eq!(s, 1e300 * (n as f64 - 2.0 * n.div_ceil(3) as f64));
        // order does not matter, even with cancellation
        let x: Vec<f64> = (0..1000)
            .map(|i| ((i * 7919) % 1000) as f64 * 1e-3 - 0.5 + 1e-17 * i as f64)
            .collect();
        let mut y = x.clone();
        y.reverse();
        y.rotate_left(317);
        assert_eq!(
            reproducible_sum(&Serial, x.iter().copied()),
            reproducible_sum(&Serial, y.iter().copied())
        );
        // extreme magnitudes and non-finite terms
        assert_eq!(reproducible_sum(&Serial, [f64::MAX, -f64::MAX, 1.0].into_iter()), 0.0);
        assert_eq!(reproducible_sum(&Serial, [5e-324, 5e-324].into_iter()), 1e-323);
        assert!(reproducible_sum(&Serial, [1.0, f64::NAN].into_iter()).is_nan());
        assert!(reproducible_sum(&Serial, [f64::NAN, 1.0].into_iter()).is_nan());
        assert!(reproducible_sum(&Serial, [1.0, f64::INFINITY].into_iter()).is_nan());
        assert_eq!(reproducible_sum(&Serial, std::iter::empty()), 0.0);
        let [a, b] = reproducible_sums(&Serial, [[1.0, 2.0], [3.0, -2.0]].into_iter());
        assert_eq!((a, b), (4.0, 0.0));
    }

    #[test]
    fn parallel_exact_sums_equal_the_serial_ones() {
        let x: Vec<f64> = (0..100_003u64)
            .map(|i| {
                let r = crate::propagate::integrate::stability::hash_unit(i);
                r * 10f64.powi((i % 37) as i32 - 18)
            })
            .collect();
        let serial = reproducible_sums(&Serial, x.iter().map(|&v| [v, v * v, -v, 0.0]));
        let par = reproducible_sums_par(&Serial, x.len(), |i| [x[i], x[i] * x[i], -x[i], 0.0]);
        assert_eq!(serial.map(f64::to_bits), par.map(f64::to_bits));
        for y in [
            0.0,
            -0.0,
            1.5,
            -1.5,
            2f64.powi(100),
            -(2f64.powi(100)),
            2f64.powi(62) - 512.0,
            -(2f64.powi(70)) - 4096.0,
            0.999,
            -0.999,
            3.7e25,
            -3.7e25,
        ] {
            assert_eq!(truncate(y), y as i128, "{y}");
        }
        assert!(reproducible_sums_par(&Serial, 2, |i| [if i == 1 { f64::NAN } else { 1.0 }])[0].is_nan());
        assert_eq!(reproducible_sums_par(&Serial, 0, |_| [1.0]), [0.0]);
    }
}
