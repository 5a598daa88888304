//! The largest stable forward Euler substep of an operator (docs/model.md section 3). Other
//! integrators size their stages from the same spectral bound.

use crate::discretize::operator::{Compact, Operator};
use crate::distribute::comm::{reproducible_sum, Comm};
use crate::distribute::field::NodeField;
use crate::linalg::V3;
use crate::propagate::Propagation;
use eprop_io::geom::{dot, scale};

/// A deterministic pseudo-random number in [-1, 1) from an integer (SplitMix64).
pub fn hash_unit(mut x: u64) -> f64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Largest stable substep h of forward Euler for the operator of `prop`.
///
/// `compact`: the spectrum of L is real and non-positive (L = V^-1 W, W symmetric negative
/// semi-definite), so h < 2 / rho with rho bounded by Gershgorin. `paper`: L is not
/// symmetric and its spectrum may be complex, so the bound comes from the amplification
/// operator itself: a start value from power iteration on L, then h is reduced until
/// repeated substeps of I + hL no longer grow a random vector. Start vectors hash the
/// global node id and norms are exact sums: the same h on any number of processes.
/// `active` and `gid` cover the local nodes (owned, then halo).
pub(crate) fn euler_bound(prop: &mut Propagation, active: &[bool], gid: &[u64], comm: &dyn Comm) -> f64 {
    match &prop.op {
        Operator::Compact(c) => {
            let g = comm.max(c.gershgorin());
            if g > 0.0 {
                2.0 / g
            } else {
                f64::INFINITY
            }
        }
        Operator::Paper(_) => paper_bound(prop, active, gid, comm),
    }
}

fn paper_bound(prop: &mut Propagation, active: &[bool], gid: &[u64], comm: &dyn Comm) -> f64 {
    let layout = prop.layout();
    let n = layout.n_owned;
    let start = NodeField::from_vec(
        layout,
        (0..layout.n_local)
            .map(|i| {
                let g = gid[i];
                if active[i] {
                    [hash_unit(3 * g), hash_unit(3 * g + 1), hash_unit(3 * g + 2)]
                } else {
                    [0.0; 3]
                }
            })
            .collect(),
    );
    let nrm = |x: &[V3]| reproducible_sum(comm, x[..n].iter().map(|v| dot(*v, *v))).sqrt();
    // power iteration on L: growth rate of |L^k x|
    let mut x = start.clone();
    let mut y = prop.zeros();
    let mut logs = Vec::new();
    for _ in 0..60 {
        prop.apply_to(&mut x, &mut y);
        let ny = nrm(&y);
        let nx = nrm(&x);
        if ny == 0.0 || nx == 0.0 {
            return f64::INFINITY;
        }
        logs.push((ny / nx).ln());
        let s = 1.0 / ny;
        for (xi, yi) in x.owned_mut().iter_mut().zip(y.owned()) {
            *xi = scale(*yi, s);
        }
    }
    let tail = &logs[logs.len() - 20..];
    let rho = (tail.iter().sum::<f64>() / tail.len() as f64).exp();
    let mut h = 2.0 / (1.05 * rho);
    // check the amplification I + hL on a random vector; shrink until it does not grow
    for _ in 0..12 {
        let mut x = start.clone();
        let mut growth = Vec::new();
        for _ in 0..120 {
            prop.apply_to(&mut x, &mut y);
            let nx = nrm(&x);
            for (xi, yi) in x.owned_mut().iter_mut().zip(y.owned()) {
                xi[0] += h * yi[0];
                xi[1] += h * yi[1];
                xi[2] += h * yi[2];
            }
            let nn = nrm(&x);
            growth.push(nn / nx);
            let s = 1.0 / nn.max(1e-300);
            x.owned_mut().iter_mut().for_each(|v| *v = scale(*v, s));
        }
        let late = &growth[growth.len() - 40..];
        let g = (late.iter().map(|v| v.ln()).sum::<f64>() / late.len() as f64).exp();
        if g <= 1.0 + 1e-9 {
            return h;
        }
        h *= 0.8;
    }
    h
}

/// The median of the Gershgorin bounds of the owned rows `0..n_owned` over every process
/// (empty rows left out): a bisection on the value with exact counts, so the same on any number of processes.
pub(crate) fn median_bound(op: &Compact, n_owned: usize, comm: &dyn Comm) -> f64 {
    let mut g = op.row_bounds();
    g.truncate(n_owned);
    g.retain(|&x| x > 0.0);
    let total = comm.sum_i128(g.len() as i128);
    if total == 0 {
        return 0.0;
    }
    let (mut lo, mut hi) = (
        comm.min(g.iter().copied().fold(f64::INFINITY, f64::min)),
        comm.max(g.iter().copied().fold(0.0, f64::max)),
    );
    // the smallest value v with count(g <= v) > total / 2 (the element at index total / 2 in
    // increasing order, as `median_positive`), to 1e-15 relative
    let want = total / 2 + 1;
    for _ in 0..200 {
        if hi <= lo * (1.0 + 1e-15) {
            break;
        }
        let mid = (lo * hi).sqrt().clamp(lo, hi);
        let below = comm.sum_i128(g.iter().filter(|&&x| x <= mid).count() as i128);
        if below >= want {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}
