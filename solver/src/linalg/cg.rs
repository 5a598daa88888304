//! Preconditioned conjugate gradients on A = V - c W = V (I - c L), symmetric positive definite
//! on the rows that move (V the control volumes, W = V L the symmetric matrix of the compact
//! scheme, c = theta tau of the implicit integrator). The three components share A, so the
//! solver treats them as one system A (x) I3: every operator application serves the three
//! components at once, and each iteration's dot products (summed over the components) go into
//! one exact reduction (Chronopoulos and Gear's form, one reduction per iteration, the
//! operator pass computing w = A u and the products together), so the iterates do not depend
//! on the number of processes or threads.

use super::csr::AnyCsr;
use super::{Precond, Sweep, V3};
use crate::distribute::comm::{reproducible_sums_par, Comm, SumGrid, Wide};
use crate::distribute::field::NodeField;
use eprop_partition::Layout;
use rayon::prelude::*;

/// Rows per block of the fused vector update.
const CH: usize = 2048;

/// The matrix A = V - c W on the owned rows: `vol` the volumes of the rows that move (0
/// elsewhere), `c` = theta tau and `bound` >= max_i V_i (1 + 2 c sum_j |c_ij|) over every
/// process (so |(A u)_i| <= bound max |u|: the grid of the exact dot products).
#[derive(Clone, Copy)]
pub struct Shifted<'a> {
    pub vol: &'a [f64],
    pub c: f64,
    pub bound: f64,
}

/// max_i V_i (1 + 2 c sum_j |c_ij| + c s_i) over the owned rows of this process (s_i the
/// screening sink): |(A u)_i| <= this max |u|.
pub(crate) fn row_bound(coef: Option<&AnyCsr>, sink: Option<&[f64]>, vol: &[f64], c: f64) -> f64 {
    let Some(coef) = coef else {
        return 0.0;
    };
    (0..vol.len())
        .into_par_iter()
        .map(|i| {
            let abs: f64 = coef.row(i).map(|p| coef.value(p).abs()).sum();
            match sink {
                None => vol[i] * (1.0 + 2.0 * c * abs),
                Some(s) => vol[i] * (1.0 + c * (2.0 * abs + s[i])),
            }
        })
        .reduce(|| 0.0, f64::max)
}

/// The solver's work vectors (the owned rows; `u`, which the operator reads, with the halo).
pub struct Work {
    r: Vec<V3>,
    w: Vec<V3>,
    p: Vec<V3>,
    s: Vec<V3>,
    u: NodeField<V3>,
}

impl Work {
    pub fn new(layout: Layout) -> Work {
        let zo = || vec![[0.0; 3]; layout.n_owned];
        Work {
            r: zo(),
            w: zo(),
            p: zo(),
            s: zo(),
            u: NodeField::filled(layout, [0.0; 3]),
        }
    }
}

/// Why a solve stopped without an answer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Failure {
    /// A residual or a product that is not finite.
    NonFinite,
    /// (r, M r) < 0: the preconditioner is not positive definite.
    Indefinite { rmr: f64 },
    /// The curvature (p, A p) is not positive: the matrix is not positive definite.
    Breakdown { curvature: f64 },
    /// The iteration limit, with the relative residual reached.
    Unconverged { residual: f64 },
    /// `first_iterate`: (b, M b) or (M b, A M b) not positive.
    NotDefinite { bmb: f64, curvature: f64 },
}

/// Solves A x = b for the three components, starting from x, to (r, M r) <= tol^2 (x, A x)
/// (below); returns the iterations (each one operator application; the solve makes two more
/// to start). Every sum is exact over every process.
pub fn solve<S: Sweep>(
    sweep: &mut S,
    a: Shifted,
    pre: &mut dyn Precond<S>,
    b: &[V3],
    x: &mut NodeField<V3>,
    work: &mut Work,
    tol: f64,
    max_iterations: usize,
    comm: &dyn Comm,
) -> Result<usize, Failure> {
    let n = a.vol.len();
    let (vol, tt) = (a.vol, a.c);
    let Work { r, w, p, s, u } = work;
    // a held row of A is its volume alone: x there is b / V at once, and no residual is
    // left there (the search directions stay zero on it)
    for &i in sweep.frozen() {
        let i = i as usize;
        x[i] = [0, 1, 2].map(|d| b[i][d] / vol[i]);
    }
    // r = b - A x; u = M r
    sweep.update_to(x, r, |i, xi, l, ri| {
        let v = vol[i];
        for d in 0..3 {
            ri[d] = b[i][d] - v * (xi[d] - tt * l[d]);
        }
    });
    mask(sweep, r);
    precondition(pre, sweep, r, &mut u[..n]);
    // The tolerance is relative to ||x||_A^2 = (b, A^-1 b). A diagonal preconditioner
    // measures it as (b, M b), consistently with (r, M r): both see smooth modes scaled
    // alike. A multigrid's (r, M r) is close to the error's A-norm itself (M A is near I
    // on every mode), and M b would cost a V-cycle: (b, x_k) measures it instead, exact
    // at the start and carried by the recurrences of x_k and p_k through (b, u_k), which
    // the operator pass sums with the other two.
    // With held rows (`Sweep::frozen`) (b, x_k) is not an energy of the free rows' system
    // (their right-hand side also has the held values' share): (b, M b) on the free rows
    // measures it then.
    // Every process must take the same branch (each has its own collectives): whether any
    // holds rows is agreed first (the preconditioner's kind is the same everywhere).
    let energy = pre.inverse_diagonal().is_none() && comm.max(f64::from(u8::from(!sweep.frozen().is_empty()))) == 0.0;
    let mut scale = if energy {
        let x_ = &x[..n];
        reproducible_sums_par(comm, n, |i| {
            [b[i][0] * x_[i][0] + b[i][1] * x_[i][1] + b[i][2] * x_[i][2]]
        })[0]
    } else {
        let held = sweep.frozen().to_vec();
        let masked;
        let b = if held.is_empty() {
            b
        } else {
            let mut m = b.to_vec();
            for &i in &held {
                m[i as usize] = [0.0; 3];
            }
            masked = m;
            &masked[..]
        };
        precondition(pre, sweep, b, p);
        let p_ = &p[..];
        let bb: [f64; 3] = reproducible_sums_par(comm, n, |i| {
            [b[i][0] * p_[i][0], b[i][1] * p_[i][1], b[i][2] * p_[i][2]]
        });
        bb[0] + bb[1] + bb[2]
    };
    let mb = b.par_iter().map(|v| max_abs(*v)).reduce(|| 0.0, f64::max);
    let [mr, mu] = max_abs2(r, &u[..n]);
    let (mut gamma, mut delta, mut bu) = apply_and_dots(sweep, a, u, w, r, b, [mr, mu, mb], comm);
    let (mut alpha, mut gamma_prev, mut bp) = (0.0f64, 0.0f64, 0.0f64);
    let mut it = 0usize;
    loop {
        if !gamma.is_finite() || !delta.is_finite() {
            return Err(Failure::NonFinite);
        }
        if gamma < 0.0 {
            return Err(Failure::Indefinite { rmr: gamma });
        }
        // (a zero residual is solved whatever the scale: held rows can leave nothing free)
        if gamma <= tol * tol * scale || gamma == 0.0 {
            return Ok(it);
        }
        if it >= max_iterations {
            return Err(Failure::Unconverged {
                residual: (gamma / scale.max(f64::MIN_POSITIVE)).sqrt(),
            });
        }
        let (beta, den) = if it == 0 {
            (0.0, delta)
        } else {
            let beta = gamma / gamma_prev;
            (beta, delta - beta * gamma / alpha)
        };
        if !(den > 0.0) {
            return Err(Failure::Breakdown { curvature: den });
        }
        alpha = gamma / den;
        gamma_prev = gamma;
        // p = u + beta p, x += alpha p: (b, p) and (b, x) follow
        if energy {
            bp = bu + beta * bp;
            scale += alpha * bp;
        }
        let inv = pre.inverse_diagonal();
        let m2 = update(p, s, &mut x[..n], r, &mut u[..n], w, alpha, beta, inv);
        let [mr, mu] = if inv.is_none() {
            precondition(pre, sweep, r, &mut u[..n]);
            max_abs2(r, &u[..n])
        } else {
            m2
        };
        (gamma, delta, bu) = apply_and_dots(sweep, a, u, w, r, b, [mr, mu, mb], comm);
        it += 1;
    }
}

/// The vector part of an iteration in one pass: p = u + beta p, s = w + beta s, x += alpha p,
/// r -= alpha s, and with a diagonal preconditioner `inv` u = M r and the largest magnitudes of
/// r and u (else zeros).
fn update(
    p: &mut [V3],
    s: &mut [V3],
    xo: &mut [V3],
    r: &mut [V3],
    uo: &mut [V3],
    w: &[V3],
    a: f64,
    bt: f64,
    inv: Option<&[f64]>,
) -> [f64; 2] {
    p.par_chunks_mut(CH)
        .zip(s.par_chunks_mut(CH))
        .zip(xo.par_chunks_mut(CH))
        .zip(r.par_chunks_mut(CH))
        .zip(uo.par_chunks_mut(CH))
        .zip(w.par_chunks(CH))
        .enumerate()
        .map(|(k, (((((p, s), x), r), u), w))| {
            let mut m = [0.0f64; 2];
            for j in 0..p.len() {
                for d in 0..3 {
                    p[j][d] = u[j][d] + bt * p[j][d];
                    s[j][d] = w[j][d] + bt * s[j][d];
                    x[j][d] += a * p[j][d];
                    r[j][d] -= a * s[j][d];
                }
                if let Some(inv) = inv {
                    let di = inv[k * CH + j];
                    u[j] = [r[j][0] * di, r[j][1] * di, r[j][2] * di];
                    m = max2(m, r[j], u[j]);
                }
            }
            m
        })
        .reduce(|| [0.0; 2], larger2)
}

/// The first conjugate-gradient iterate of A x = b from x = 0, x = alpha M b with
/// alpha = (b, M b) / (M b, A M b): one preconditioner and one operator application (the
/// implicit integrator's error filter with a multigrid). Sums exact over every process.
pub(crate) fn first_iterate<S: Sweep>(
    sweep: &mut S,
    a: Shifted,
    pre: &mut dyn Precond<S>,
    b: &[V3],
    x: &mut NodeField<V3>,
    work: &mut Work,
    comm: &dyn Comm,
) -> Result<(), Failure> {
    let n = a.vol.len();
    let Work { w, u, .. } = work;
    precondition(pre, sweep, b, &mut u[..n]);
    let [mb, mu] = max_abs2(b, &u[..n]);
    let (gamma, delta, _) = apply_and_dots(sweep, a, u, w, b, b, [mb, mu, mb], comm);
    if !gamma.is_finite() || !delta.is_finite() {
        return Err(Failure::NonFinite);
    }
    let alpha = if gamma == 0.0 {
        0.0
    } else if gamma > 0.0 && delta > 0.0 {
        gamma / delta
    } else {
        return Err(Failure::NotDefinite {
            bmb: gamma,
            curvature: delta,
        });
    };
    let u = &u[..n];
    x[..n]
        .par_iter_mut()
        .zip(u.par_iter())
        .for_each(|(e, u)| *e = [alpha * u[0], alpha * u[1], alpha * u[2]]);
    Ok(())
}

/// Zero at the rows the operator holds (`Sweep::frozen`): with a zero residual there, the
/// iteration stays on the free rows, where the matrix is symmetric.
fn mask<S: Sweep>(sweep: &S, u: &mut [V3]) {
    for &i in sweep.frozen() {
        u[i as usize] = [0.0; 3];
    }
}

/// z = M r on the owned rows, zero at the held rows (`mask`).
fn precondition<S: Sweep>(pre: &mut dyn Precond<S>, sweep: &mut S, r: &[V3], z: &mut [V3]) {
    pre.apply(sweep, r, z);
    mask(sweep, z);
}

/// The largest component magnitude of v (infinite for a non-finite one).
#[inline(always)]
fn max_abs(v: V3) -> f64 {
    // f64::max skips a NaN: test every component, not the maximum
    if v.iter().all(|x| x.is_finite()) {
        v[0].abs().max(v[1].abs()).max(v[2].abs())
    } else {
        f64::INFINITY
    }
}

/// The larger of `m` and the magnitudes of r's and u's components (infinite for a non-finite
/// one, which `max` would skip).
#[inline(always)]
fn max2(m: [f64; 2], r: V3, u: V3) -> [f64; 2] {
    [m[0].max(max_abs(r)), m[1].max(max_abs(u))]
}

/// Largest component magnitudes of r and u on this process.
fn max_abs2(r: &[V3], u: &[V3]) -> [f64; 2] {
    r.par_iter()
        .zip(u.par_iter())
        .fold(|| [0.0; 2], |m, (r, u)| max2(m, *r, *u))
        .reduce(|| [0.0; 2], larger2)
}

/// The larger of each pair: two maxima merged.
fn larger2(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0].max(b[0]), a[1].max(b[1])]
}

/// w = A u with the dot products (r, u), (w, u) and (b, u) over the three components in the
/// same pass, summed exactly over every process: each row's three products are added in a
/// fixed order, then put on a grid that comes from bounds known before the pass
/// (|r_i . u_i| <= 3 max|r| max|u|, |w_i . u_i| <= 3 a.bound max|u|^2,
/// |b_i . u_i| <= 3 max|b| max|u|), so one collective brings the maxima and one the sums.
fn apply_and_dots<S: Sweep>(
    sweep: &mut S,
    a: Shifted,
    u: &mut NodeField<V3>,
    w: &mut [V3],
    r: &[V3],
    b: &[V3],
    local_max: [f64; 3],
    comm: &dyn Comm,
) -> (f64, f64, f64) {
    let (vol, tt) = (a.vol, a.c);
    let m = comm.max_each(&local_max);
    let (mr, mu, mb) = (m[0], m[1], m[2]);
    // 3.01: the three products of a row and their rounding
    let g_ru = SumGrid::new(3.01 * mr * mu);
    let g_wu = SumGrid::new(3.01 * a.bound * mu * mu);
    let g_bu = SumGrid::new(3.01 * mb * mu);
    let acc: Acc = sweep.fold_to(
        u,
        w,
        |acc: &mut Acc, i, ui, l, wi| {
            let v = vol[i];
            for d in 0..3 {
                wi[d] = v * (ui[d] - tt * l[d]);
            }
            let (ri, bi) = (r[i], b[i]);
            acc.part[0] += g_ru.fixed(ri[0] * ui[0] + ri[1] * ui[1] + ri[2] * ui[2]);
            acc.part[1] += g_wu.fixed(wi[0] * ui[0] + wi[1] * ui[1] + wi[2] * ui[2]);
            acc.part[2] += g_bu.fixed(bi[0] * ui[0] + bi[1] * ui[1] + bi[2] * ui[2]);
        },
        Acc::merge,
    );
    let total = comm.sum_wide(&acc.wide());
    (g_ru.value(total[0]), g_wu.value(total[1]), g_bu.value(total[2]))
}

/// Exact partial sums of one block of rows (an i128 holds a block's integers: at most 2048
/// terms of 2^100) and of merged blocks (256 bits).
#[derive(Default)]
struct Acc {
    part: [i128; 3],
    merged: [Wide; 3],
}

impl Acc {
    fn wide(&self) -> [Wide; 3] {
        std::array::from_fn(|k| self.merged[k].add_i128(self.part[k]))
    }
    fn merge(a: Acc, b: Acc) -> Acc {
        let (wa, wb) = (a.wide(), b.wide());
        Acc {
            part: [0; 3],
            merged: std::array::from_fn(|k| wa[k].plus(wb[k])),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_nan_in_any_component_makes_the_maximum_infinite() {
        assert_eq!(max_abs([1.0, -3.0, 2.0]), 3.0);
        for k in 0..3 {
            let mut v = [1.0, 2.0, 3.0];
            v[k] = f64::NAN;
            assert_eq!(max_abs(v), f64::INFINITY, "{v:?}");
            assert_eq!(max2([0.0; 2], v, [1.0; 3]), [f64::INFINITY, 1.0]);
        }
    }
}
