//! Unit-test helpers: a `Comm` whose processes are threads of the test, so collectives and
//! the block scatter can be tested on several processes without MPI.

use crate::distribute::comm::{Comm, Wide};
use std::sync::{Barrier, Mutex};

struct Shared {
    size: usize,
    barrier: Barrier,
    /// `slots[from * size + to]`: the bytes `from` sends `to` in the current exchange.
    slots: Mutex<Vec<Vec<u8>>>,
}

/// One of `size` thread processes.
pub struct Threads<'a> {
    rank: usize,
    shared: &'a Shared,
}

impl Threads<'_> {
    /// Sends `out[q]` to process q; returns what every process sent here, in rank order.
    fn exchange(&self, out: Vec<Vec<u8>>) -> Vec<Vec<u8>> {
        let p = self.shared.size;
        {
            let mut s = self.shared.slots.lock().unwrap();
            for (q, b) in out.into_iter().enumerate() {
                s[self.rank * p + q] = b;
            }
        }
        self.shared.barrier.wait();
        let got = {
            let s = self.shared.slots.lock().unwrap();
            (0..p).map(|q| s[q * p + self.rank].clone()).collect()
        };
        self.shared.barrier.wait();
        got
    }

    fn gather_f64(&self, x: &[f64]) -> Vec<f64> {
        let bytes: Vec<u8> = x.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.exchange(vec![bytes; self.shared.size])
            .concat()
            .chunks(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    }
}

impl Comm for Threads<'_> {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.shared.size
    }
    fn max(&self, x: f64) -> f64 {
        self.gather_f64(&[x]).into_iter().fold(f64::NEG_INFINITY, f64::max)
    }
    fn min(&self, x: f64) -> f64 {
        self.gather_f64(&[x]).into_iter().fold(f64::INFINITY, f64::min)
    }
    fn sum_i128(&self, x: i128) -> i128 {
        let got = self.exchange(vec![x.to_le_bytes().to_vec(); self.shared.size]);
        got.iter()
            .map(|b| i128::from_le_bytes(b[..].try_into().unwrap()))
            .fold(0, i128::wrapping_add)
    }
    fn sum_wide(&self, x: &[Wide]) -> Vec<Wide> {
        let bytes: Vec<u8> = x.iter().flat_map(|w| w.words()).flat_map(|w| w.to_le_bytes()).collect();
        let mut sum = vec![Wide::default(); x.len()];
        for b in self.exchange(vec![bytes; self.shared.size]) {
            let words: Vec<u64> = b.chunks(8).map(|c| u64::from_le_bytes(c.try_into().unwrap())).collect();
            for (s, w) in sum.iter_mut().zip(words.chunks(4)) {
                *s = s.plus(Wide::from_words(w));
            }
        }
        sum
    }
    fn max_each(&self, x: &[f64]) -> Vec<f64> {
        let all = self.gather_f64(x);
        (0..x.len())
            .map(|k| {
                all.iter()
                    .skip(k)
                    .step_by(x.len())
                    .fold(f64::NEG_INFINITY, |m, &v| m.max(v))
            })
            .collect()
    }
    fn broadcast(&self, root: usize, x: &mut [f64]) {
        let all = self.gather_f64(x);
        x.copy_from_slice(&all[root * x.len()..(root + 1) * x.len()]);
    }
    fn all_to_all(&self, send: &[f64], counts: &[usize]) -> Vec<f64> {
        let mut out = Vec::with_capacity(counts.len());
        let mut at = 0;
        for &c in counts {
            out.push(send[at..at + c].iter().flat_map(|v| v.to_le_bytes()).collect());
            at += c;
        }
        let got = self.exchange(out).concat();
        got.chunks(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    }
    fn all_gather(&self, x: &[f64]) -> Vec<f64> {
        self.gather_f64(x)
    }
    fn all_gather_var(&self, x: &[f64]) -> (Vec<f64>, Vec<usize>) {
        let bytes: Vec<u8> = x.iter().flat_map(|v| v.to_le_bytes()).collect();
        let got = self.exchange(vec![bytes; self.shared.size]);
        let counts = got.iter().map(|b| b.len() / 8).collect();
        let all = got
            .concat()
            .chunks(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect();
        (all, counts)
    }
    fn abort(&self, _: i32) -> ! {
        panic!("abort on thread process {}", self.rank)
    }
}

/// Runs `f` on `size` thread processes; returns their results in rank order.
pub fn threads<T: Send>(size: usize, f: impl Fn(&Threads) -> T + Sync) -> Vec<T> {
    let shared = Shared {
        size,
        barrier: Barrier::new(size),
        slots: Mutex::new(vec![Vec::new(); size * size]),
    };
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..size)
            .map(|rank| {
                let (shared, f) = (&shared, &f);
                s.spawn(move || f(&Threads { rank, shared }))
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    })
}

#[test]
fn thread_processes_reduce_and_exchange() {
    let got = threads(3, |c| {
        let r = c.rank() as f64;
        let mut b = [r, 10.0 + r];
        c.broadcast(2, &mut b);
        // process r sends r+1 values to every process
        let send: Vec<f64> = (0..3)
            .flat_map(|_| (0..=c.rank()).map(|k| 10.0 * r + k as f64))
            .collect();
        (
            c.max(r),
            c.min(r),
            c.sum_i128(c.rank() as i128 + 1),
            b,
            c.all_to_all(&send, &[c.rank() + 1; 3]),
        )
    });
    for (max, min, sum, b, a2a) in got {
        assert_eq!((max, min, sum, b), (2.0, 0.0, 6, [2.0, 12.0]));
        assert_eq!(a2a, [0.0, 10.0, 11.0, 20.0, 21.0, 22.0]);
    }
    // the exact sum does not depend on how the terms are spread over processes
    let terms: Vec<f64> = (0..30)
        .map(|i| 1.0 / (i as f64 + 1.0) * if i % 2 == 0 { 1e8 } else { 1e-8 })
        .collect();
    let one = crate::distribute::comm::reproducible_sum(&crate::distribute::comm::Serial, terms.iter().copied());
    let sums = threads(4, |c| {
        crate::distribute::comm::reproducible_sum(c, terms.iter().skip(c.rank()).step_by(4).copied())
    });
    assert!(sums.iter().all(|&s| s == one), "{sums:?} vs {one}");
}
