//! Smoothed-aggregation algebraic multigrid (Vanek, Mandel and Brezina 1996): the
//! preconditioner of the implicit solves where many Jacobi iterations would be needed
//! (`preconditioner = "auto"` or `"multigrid"`), one V-cycle per conjugate-gradient iteration
//! for the three components together.
//!
//! The TR-BDF2 matrix is A = V + c K with V the control volumes, K = -W the (positive)
//! diffusion matrix and c = theta tau. One scalar hierarchy serves the three components:
//! - level 0 is the solver's own A on every process (its pattern swept with the halo
//!   exchange, `Sweep::update_with`, on weights w_ij = -K_ij in f32): its smoothing
//!   couples the processes;
//! - the coarse levels are global and the same on every process: at setup every process
//!   gathers the free rows of K (global ids, `Comm::all_gather_var`) and builds the whole
//!   hierarchy from them in global id order, so aggregates cross process boundaries as if
//!   there were one process;
//! - restriction: each coarse row has an owner (the process of its largest prolongator
//!   entry), which sums it from the fine residuals of its support in global order (those of
//!   other processes arrive in one all-to-all on a fixed plan); every process then gathers
//!   the whole coarse vector, runs the coarse cycle itself, and prolongs to its own rows;
//! - aggregation on K's strong connections (`aggregate`), nodes in global id order;
//! - prolongator P = (I - omega D_F^-1 K_F) P_tent, P_tent the aggregates' constants, K_F
//!   the filtered K (its strong connections; the weak ones added to the diagonal),
//!   omega = 4 / (3 lambda_max(D_F^-1 K_F)) by power iteration;
//! - Galerkin coarse matrices kept apart, V_c = P^T V P and K_c = P^T K P, so that a new c
//!   only recombines A_c = V_c + c K_c (`set_coefficient`), the prolongators stay;
//! - smoothing: Chebyshev of degree 2 on D_A^-1 A over [0.1 lambda, max(1.1 lambda, Gershgorin)] (power
//!   iteration), the same polynomial before and after the coarse correction, so the V-cycle is
//!   a fixed symmetric positive-definite operator and conjugate gradients stay valid;
//! - coarsest level (at most COARSE_MAX rows, or where aggregation stalls): dense Cholesky.
//!
//! Every level's matrix is read once per kernel for the three columns. Every sum is in a
//! fixed order (global ids on level 0's transfers), so the cycle, and the iterates, are the
//! same bits on any thread and process count. The price: each process holds the global
//! coarse levels and level 0's global matrix (for the smoother's bounds), and repeats the
//! coarse cycle; setup gathers the whole fine matrix on every process (docs/integrators.md).

pub mod aggregate;
mod gather;
mod plan;

use super::csr::{self, Csr};
use super::{Precond, Sweep, V3};
use crate::distribute::comm::Comm;
use crate::distribute::field::NodeField;
use crate::distribute::halo::Halo;
use anyhow::{bail, Result};
use plan::Plan;
use rayon::prelude::*;
use std::sync::Arc;

/// Coarsening stops at this many rows (the coarsest level is solved directly).
pub(crate) const COARSE_MAX: usize = 400;
/// The largest coarsest level factored densely; a stalled coarsening above it is smoothed.
const DENSE_MAX: usize = 1500;
/// Strength of connection on the finest level (halved on each coarser one).
const EPS: f64 = 0.08;
/// Power iterations for the eigenvalue bounds.
const POWER_ITERATIONS: usize = 12;
/// Forward Euler substeps per level-0 matrix application of the cycle (three columns): a
/// V-cycle of 6.33 such applications took 6.0-6.3 times an operator application on the 70^3
/// box, 5.37 took 5.1 on the tetgen kidney and 6.31 took 5.2 on the liver
/// (`examples/multigrid.rs`), the operator application about one substep.
pub(crate) const SWEEP_COST: f64 = 0.95;
/// The Chebyshev degree of the smoother.
pub(crate) const DEGREE: usize = 2;

/// One level: A = V + c K on one pattern, its Chebyshev smoother and its work vectors. The
/// pattern, V, K and the transfers do not depend on c: hierarchies for other coefficients
/// share them (`Precond::derive`).
#[derive(Clone)]
struct Level {
    /// K on the level's pattern, which V and A share (rows' columns ascending, with the
    /// diagonal)
    k: Arc<Csr<f64>>,
    /// V on the pattern, or only its diagonal where V is diagonal (level 0: the control
    /// volumes), whose off-diagonal entries are zeros
    v: Mass,
    /// A = V + c K (what the bounds and the coarsest factor use) and rounded to f32 (what the
    /// cycle reads); neither kept for a level that only serves its bounds
    a: Vec<f64>,
    a32: Vec<f32>,
    bounds_only: bool,
    /// the rows this process computes, where the level is split over the processes (level
    /// 1 on several processes; None: every row here), and the gather's buffers
    own: Option<Arc<Own>>,
    send: Vec<f64>,
    recv: Vec<f64>,
    dinv: Vec<f64>,
    /// Chebyshev interval of D^-1 A
    lo: f64,
    hi: f64,
    /// prolongator to this level from the next coarser one and its transpose (empty on the
    /// coarsest level)
    p: Arc<Csr<f32>>,
    r: Arc<Csr<f32>>,
    x: Vec<V3>,
    b: Vec<V3>,
    t: Vec<V3>,
}

/// The V of a level's A = V + c K.
#[derive(Clone)]
enum Mass {
    Full(Arc<Vec<f64>>),
    Diagonal(Arc<Vec<f64>>),
}

/// A level's rows split over the processes: each computes its own rows of a kernel, then
/// every process gathers all of them (`Level::share`).
struct Own {
    /// this process's rows, ascending
    rows: Vec<u32>,
    /// values from each process (three per row) and the row of each gathered one, in
    /// arrival order
    counts: Vec<usize>,
    order: Vec<u32>,
}

impl Level {
    fn n(&self) -> usize {
        self.k.n_rows()
    }

    /// The level of K and V (rows' columns ascending): one pattern holding both, with the
    /// diagonal.
    fn new(k: &Csr<f64>, v: &Csr<f64>) -> Level {
        let n = k.n_rows();
        let mut ptr = Vec::with_capacity(n + 1);
        ptr.push(0u32);
        let (mut col, mut kv, mut vv) = (vec![], vec![], vec![]);
        for i in 0..n {
            let (mut p, pe) = (k.ptr[i] as usize, k.ptr[i + 1] as usize);
            let (mut q, qe) = (v.ptr[i] as usize, v.ptr[i + 1] as usize);
            let mut diag = false;
            while p < pe || q < qe {
                let jk = if p < pe { k.col[p] } else { u32::MAX };
                let jv = if q < qe { v.col[q] } else { u32::MAX };
                let j = jk.min(jv);
                if !diag && i as u32 <= j {
                    if i as u32 != j {
                        col.push(i as u32);
                        kv.push(0.0);
                        vv.push(0.0);
                    }
                    diag = true;
                }
                col.push(j);
                kv.push(if jk == j { k.val[p] } else { 0.0 });
                vv.push(if jv == j { v.val[q] } else { 0.0 });
                if jk == j {
                    p += 1;
                }
                if jv == j {
                    q += 1;
                }
            }
            if !diag {
                col.push(i as u32);
                kv.push(0.0);
                vv.push(0.0);
            }
            ptr.push(u32::try_from(col.len()).expect("a level of fewer than 2^32 entries"));
        }
        let z = vec![[0.0; 3]; n];
        // a diagonal V keeps its diagonal alone (the pattern's other entries hold zeros)
        let diagonal = (0..n).all(|i| v.row(i).all(|q| v.col[q] as usize == i));
        let v = if diagonal {
            Mass::Diagonal(Arc::new(
                (0..n)
                    .map(|i| {
                        (ptr[i] as usize..ptr[i + 1] as usize)
                            .find(|&p| col[p] as usize == i)
                            .map_or(0.0, |p| vv[p])
                    })
                    .collect(),
            ))
        } else {
            Mass::Full(Arc::new(vv))
        };
        Level {
            a: Vec::new(),
            a32: vec![],
            bounds_only: false,
            own: None,
            send: vec![],
            recv: vec![],
            dinv: vec![0.0; n],
            k: Arc::new(Csr {
                n_cols: n,
                ptr,
                col,
                val: kv,
            }),
            v,
            lo: 0.0,
            hi: 0.0,
            p: Arc::default(),
            r: Arc::default(),
            x: z.clone(),
            b: z.clone(),
            t: z,
        }
    }

    /// A = V + c K, its inverse diagonal and Chebyshev interval.
    fn combine(&mut self, c: f64) {
        let n = self.n();
        let k: &Csr<f64> = &self.k;
        self.a = match &self.v {
            Mass::Full(v) => v.iter().zip(k.val.iter()).map(|(v, k)| v + c * k).collect(),
            // the same sums: 0 + c k off the diagonal
            Mass::Diagonal(d) => (0..n)
                .flat_map(|i| {
                    k.row(i).map(move |p| {
                        let v = if k.col[p] as usize == i { d[i] } else { 0.0 };
                        v + c * k.val[p]
                    })
                })
                .collect(),
        };
        let a = &self.a;
        self.dinv = (0..n)
            .map(|i| {
                let d = k.row(i).find(|&p| k.col[p] as usize == i).map_or(0.0, |p| a[p]);
                if d > 0.0 {
                    1.0 / d
                } else {
                    0.0
                }
            })
            .collect();
        // Chebyshev over [lo, hi] must cover the whole spectrum of D^-1 A at the top, or it
        // amplifies the modes above hi and the preconditioner is no longer positive definite
        // (conjugate gradients then stop early on a wrong answer): hi is at least the
        // Gershgorin bound max_i sum_j |a_ij| / a_ii, which no eigenvalue exceeds; the power
        // iteration (from a smooth start it underestimates) sets the bottom of the interval.
        let lam = lambda_max(&k.ptr, &k.col, &self.a, &self.dinv);
        let gershgorin = (0..n)
            .map(|i| self.dinv[i] * k.row(i).map(|p| self.a[p].abs()).sum::<f64>())
            .fold(0.0, f64::max);
        // (1 + 1e-6): the cycle reads A rounded to f32 (a third fewer bytes; still a fixed
        // symmetric operator), whose bound may lie 1e-7 above this one
        self.hi = (1.1 * lam).max(gershgorin * (1.0 + 1e-6));
        self.lo = 0.1 * lam.min(self.hi);
        if self.bounds_only {
            self.a = vec![];
        } else {
            self.a32 = self.a.iter().map(|&a| a as f32).collect();
        }
    }

    /// Chebyshev smoothing of A x = b: `degree` steps from x = 0 (`zero`) or from x. A split
    /// level updates its own rows and gathers x after each step.
    fn smooth(&mut self, degree: usize, zero: bool, halo: &Halo) {
        let theta = 0.5 * (self.hi + self.lo);
        let delta = 0.5 * (self.hi - self.lo);
        if !(theta > 0.0) {
            return; // no unknowns that move
        }
        let sigma = theta / delta;
        let mut rho = 1.0 / sigma;
        // t holds the search direction d
        if zero {
            let (b, dinv) = (&self.b, &self.dinv);
            self.t
                .iter_mut()
                .zip(b)
                .zip(dinv)
                .for_each(|((d, b), w)| *d = [b[0] * w / theta, b[1] * w / theta, b[2] * w / theta]);
            self.x.copy_from_slice(&self.t);
        } else {
            self.cheb_step(0.0, 1.0 / theta, halo);
        }
        for _ in 1..degree {
            let rho_new = 1.0 / (2.0 * sigma - rho);
            self.cheb_step(rho_new * rho, 2.0 * rho_new / delta, halo);
            rho = rho_new;
        }
    }

    /// d = alpha d + beta D^-1 (b - A x), x += d: on every row, or on this process's rows
    /// and then x gathered.
    fn cheb_step(&mut self, alpha: f64, beta: f64, halo: &Halo) {
        match self.own.clone() {
            None => {
                csr::cheb_update(
                    &self.k.ptr,
                    &self.k.col,
                    &self.a32,
                    &self.dinv,
                    &self.x,
                    &self.b,
                    &mut self.t,
                    alpha,
                    beta,
                );
                csr::add(&mut self.x, &self.t);
            }
            Some(own) => {
                csr::cheb_step_rows(
                    &own.rows,
                    &self.k.ptr,
                    &self.k.col,
                    &self.a32,
                    &self.dinv,
                    &mut self.x,
                    &self.b,
                    &mut self.t,
                    alpha,
                    beta,
                );
                Self::share(&own, &mut self.x, halo, &mut self.send, &mut self.recv);
            }
        }
    }

    /// t = b - A x: on every row, or on this process's rows and then gathered.
    fn residual(&mut self, halo: &Halo) {
        match self.own.clone() {
            None => csr::residual(&self.k.ptr, &self.k.col, &self.a32, &self.x, &self.b, &mut self.t),
            Some(own) => {
                csr::residual_rows(
                    &own.rows,
                    &self.k.ptr,
                    &self.k.col,
                    &self.a32,
                    &self.x,
                    &self.b,
                    &mut self.t,
                );
                Self::share(&own, &mut self.t, halo, &mut self.send, &mut self.recv);
            }
        }
    }

    /// Every process's rows of v, gathered into v everywhere.
    fn share(own: &Own, v: &mut [V3], halo: &Halo, send: &mut Vec<f64>, recv: &mut Vec<f64>) {
        send.clear();
        for &i in &own.rows {
            send.extend_from_slice(&v[i as usize]);
        }
        halo.all_gather_into(send, &own.counts, recv);
        scatter(&own.order, recv, v);
    }
}

/// Gathered values (three per row, in arrival order) into the rows `order` of v.
fn scatter(order: &[u32], gathered: &[f64], v: &mut [V3]) {
    for (k, &a) in order.iter().enumerate() {
        v[a as usize] = [gathered[3 * k], gathered[3 * k + 1], gathered[3 * k + 2]];
    }
}

/// The largest eigenvalue of D^-1 M (M symmetric, D > 0 its diagonal) by power iteration
/// from a fixed start, summed in order.
fn lambda_max(ptr: &[u32], col: &[u32], val: &[f64], dinv: &[f64]) -> f64 {
    let n = dinv.len();
    if n == 0 {
        return 0.0;
    }
    let mut x: Vec<f64> = (0..n).map(|i| 1.0 + ((i * 7919) % 101) as f64 / 101.0).collect();
    let norm = |x: &[f64]| x.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut lam = 0.0;
    for _ in 0..POWER_ITERATIONS {
        let nx = norm(&x);
        if !(nx > 0.0) {
            break;
        }
        let y: Vec<f64> = (0..n)
            .into_par_iter()
            .with_min_len(4096)
            .map(|i| {
                dinv[i]
                    * (ptr[i] as usize..ptr[i + 1] as usize)
                        .map(|p| val[p] * x[col[p] as usize])
                        .sum::<f64>()
            })
            .collect();
        let ny = norm(&y);
        lam = ny / nx;
        if !(ny > 0.0) {
            break;
        }
        x = y.iter().map(|v| v / ny).collect();
    }
    lam
}

/// The direct solve of the coarsest level.
#[derive(Clone)]
enum Coarse {
    /// Lower Cholesky factor, dense by rows.
    Dense(Vec<f64>),
    /// Too large to factor: Chebyshev of high degree (symmetric too).
    Smooth,
}

/// The smoothed-aggregation hierarchy (a `Precond`): level 0 on this process's rows, the
/// coarse levels global and the same on every process; `T` the level-0 sweeps' operator
/// (`Sweep::Twin`).
#[derive(Clone)]
pub struct Multigrid<T> {
    /// the global free row (index among the free rows in global id order) of each owned row,
    /// u32::MAX where it does not move
    free_of: Arc<Vec<u32>>,
    /// owned rows
    owned: usize,
    /// level 0, global (free rows in global id order): its bounds serve the level-0
    /// smoother, its size the work estimate
    fine: Level,
    /// the level-0 sweeps' operator: the weights w_ij = V_i c_ij made exactly symmetric, in
    /// f32, on the solver's pattern (`Sweep::update_with`)
    sweep_op: Arc<T>,
    /// V_i of the owned rows (0 on rows that do not move) and the inverse diagonal of A
    vol: Arc<Vec<f64>>,
    dinv0: Vec<f64>,
    /// prolongator from levels[0] to the owned rows
    p0: Arc<Csr<f32>>,
    /// the restriction's communication and rows, and its buffers
    plan: Arc<Plan>,
    send_buf: Vec<f64>,
    recv_buf: Vec<f64>,
    mine: Vec<V3>,
    /// level-0 iterates (with the halo): the current one, the previous and the next, and
    /// the residual (the owned rows, then other processes' rows the restriction reads); empty
    /// while released (`Precond::release`), allocated again by the next application
    x0: NodeField<V3>,
    xp: NodeField<V3>,
    x1: NodeField<V3>,
    t0: Vec<V3>,
    /// the sizes of t0 and `mine`
    n_t: usize,
    n_mine: usize,
    /// the coarse levels (levels[0] is the fine level itself where it did not coarsen)
    levels: Vec<Level>,
    /// whether level 0 was aggregated (else levels[0] is level 0 itself, solved directly)
    coarsened: bool,
    coarse: Coarse,
    degree: usize,
    coefficient: f64,
    /// free rows over all rows, over every process
    free_fraction: f64,
    /// entries of the global prolongator from levels[0]
    p_nnz: usize,
}

impl<T: Send + Sync> Multigrid<T> {
    /// The hierarchy of A = V - theta tau W on the free rows (`vol` > 0, owned rows) of
    /// `s`'s compact operator over every process of `comm`; `gid` numbers the local nodes
    /// (owned, then halo). The coarse levels are built from the global matrix, its rows in an
    /// order computed from global ids, on every process alike, so the preconditioner does not
    /// depend on the partition. Three steps: the global matrix gathered (`gather`), the
    /// hierarchy built from it (`hierarchy`), the restriction's plan over the processes
    /// (`plan`).
    pub fn new<S: Sweep<Twin = T>>(s: &S, vol: &[f64], gid: &[u64], theta_tau: f64, comm: &dyn Comm) -> Result<Self> {
        let t0 = std::time::Instant::now();
        let Some(op) = s.coefficients() else {
            bail!("the multigrid preconditioner needs the compact scheme; fix: use [integrator] preconditioner = \"jacobi\"");
        };
        let n = vol.len();
        let (me, size) = (comm.rank(), comm.size());
        let g = gather::gather(op, vol, gid, comm);
        let sweep_op = s.twin(gather::sweep_weights(op, vol, gid, &g));
        let gather::Gathered { rows, k, free } = g;
        let m = rows.len();
        let v: Vec<f64> = rows.iter().map(|r| r.vol).collect();
        let mut levels = Self::hierarchy(k, &v);
        let coarsened = levels.len() >= 2;
        let (mut fine, p, r) = if coarsened {
            let mut fine = levels.remove(0);
            let (p, r) = (std::mem::take(&mut fine.p), std::mem::take(&mut fine.r));
            (fine, p, r)
        } else {
            // no coarsening: the fine level itself is the coarse problem
            let id = Arc::new(Csr::identity(m));
            (levels[0].clone(), id.clone(), id)
        };
        // only the fine level's bounds are used: no work vectors, no A kept
        (fine.x, fine.b, fine.t) = (vec![], vec![], vec![]);
        fine.bounds_only = true;
        let free_of: Vec<u32> = (0..n)
            .map(|i| if vol[i] > 0.0 { free[gid[i] as usize] } else { u32::MAX })
            .collect();
        // P's rows of the owned nodes
        let mut p0 = Csr {
            n_cols: p.n_cols,
            ptr: Vec::with_capacity(n + 1),
            col: vec![],
            val: vec![],
        };
        p0.ptr.push(0);
        for &k in &free_of {
            if k != u32::MAX {
                let s = p.row(k as usize);
                p0.col.extend_from_slice(&p.col[s.clone()]);
                p0.val.extend_from_slice(&p.val[s]);
            }
            p0.ptr.push(p0.col.len() as u32);
        }
        let plan = Plan::new(&r, &rows, &free_of, me, size);
        drop(r);
        // on several processes the first coarse level is split by the restriction's owners;
        // the coarser ones are small and every process runs them whole
        if size > 1 && coarsened && levels.len() > 1 {
            levels[0].own = Some(Arc::new(plan.own(me)));
        }
        let degree = DEGREE;
        let total = comm.sum_i128(n as i128).max(1) as f64;
        let (n_t, n_mine) = (plan.residual_len, plan.r.n_rows());
        let mut mg = Multigrid {
            free_of: Arc::new(free_of),
            owned: n,
            fine,
            sweep_op: Arc::new(sweep_op),
            vol: Arc::new(vol.to_vec()),
            dinv0: vec![0.0; n],
            p0: Arc::new(p0),
            plan: Arc::new(plan),
            send_buf: vec![],
            recv_buf: vec![],
            // the work buffers: made by the first application (`apply`)
            mine: vec![],
            x0: NodeField::filled(Default::default(), [0.0; 3]),
            xp: NodeField::filled(Default::default(), [0.0; 3]),
            x1: NodeField::filled(Default::default(), [0.0; 3]),
            t0: vec![],
            n_t,
            n_mine,
            levels,
            coarsened,
            coarse: Coarse::Smooth,
            degree,
            coefficient: f64::NAN,
            free_fraction: m as f64 / total,
            p_nnz: p.nnz(),
        };
        mg.set_coefficient(theta_tau)?;
        tracing::debug!(
            "multigrid: levels {:?}, operator complexity {:.2}, cycle {:.1} level-0 applications, degree {}, setup {:.3} s",
            mg.sizes(),
            mg.complexity(),
            mg.cycle_work(),
            mg.degree,
            t0.elapsed().as_secs_f64()
        );
        tracing::info!(
            target: "eprop::setup",
            "multigrid hierarchy {:?} rows, built in {:.1} s",
            mg.sizes(),
            t0.elapsed().as_secs_f64()
        );
        Ok(mg)
    }

    /// The levels of A = diag(v) + c K (K symmetric, rows' columns ascending with the
    /// diagonal stored), from level 0 to the coarsest; their coefficients are not yet set.
    fn hierarchy(k: Csr<f64>, v: &[f64]) -> Vec<Level> {
        let n = k.n_rows();
        let mut vm = Csr {
            n_cols: n,
            ptr: (0..=n as u32).collect(),
            col: (0..n as u32).collect(),
            val: v.to_vec(),
        };
        let mut k = k;
        let mut levels = vec![];
        let mut eps = EPS;
        loop {
            let n = k.n_rows();
            let mut level = Level::new(&k, &vm);
            if n <= COARSE_MAX || levels.len() >= 24 {
                levels.push(level);
                break;
            }
            let (agg, n_agg) = aggregate::aggregate(&k, eps);
            if n_agg == 0 || n_agg as f64 > 0.8 * n as f64 {
                levels.push(level);
                break;
            }
            // P = (I - omega D_F^-1 K_F) P_tent, K_F the filtered K
            let kf = aggregate::filtered(&k, eps);
            let dk = kf.diagonal();
            let dinv: Vec<f64> = dk.iter().map(|&d| if d > 0.0 { 1.0 / d } else { 0.0 }).collect();
            let lam = lambda_max(&kf.ptr, &kf.col, &kf.val, &dinv);
            let omega = if lam > 0.0 { 4.0 / (3.0 * lam) } else { 0.0 };
            let mut s = kf;
            for i in 0..n {
                for p in s.row(i) {
                    let delta = if s.col[p] as usize == i { 1.0 } else { 0.0 };
                    s.val[p] = delta - omega * dinv[i] * s.val[p];
                }
            }
            let p = s.matmul(&aggregate::tentative(&agg, n_agg));
            let r = p.transpose();
            let kc = r.matmul(&k.matmul(&p));
            let vc = r.matmul(&vm.matmul(&p));
            level.p = Arc::new(p.to());
            level.r = Arc::new(r.to());
            levels.push(level);
            k = kc;
            vm = vc;
            eps *= 0.5;
        }
        levels
    }

    /// A = V + c K on every level (the prolongators stay): new smoothers and coarse factor.
    pub fn set_coefficient(&mut self, c: f64) -> Result<()> {
        self.fine.combine(c);
        self.dinv0 = self
            .free_of
            .iter()
            .map(|&k| if k == u32::MAX { 0.0 } else { self.fine.dinv[k as usize] })
            .collect();
        for l in &mut self.levels {
            l.combine(c);
        }
        self.coefficient = c;
        let last = self.levels.last().expect("at least one level");
        let n = last.n();
        self.coarse = if n <= DENSE_MAX {
            let mut f = vec![0.0; n * n];
            for i in 0..n {
                for p in last.k.row(i) {
                    f[i * n + last.k.col[p] as usize] = last.a[p];
                }
            }
            for j in 0..n {
                let mut d = f[j * n + j];
                for k in 0..j {
                    d -= f[j * n + k] * f[j * n + k];
                }
                if !(d > 0.0) {
                    bail!("multigrid: the coarsest matrix is not positive definite (pivot {d:.3e} at row {j}); fix: use [integrator] preconditioner = \"jacobi\"");
                }
                let d = d.sqrt();
                f[j * n + j] = d;
                for i in j + 1..n {
                    let mut s = f[i * n + j];
                    for k in 0..j {
                        s -= f[i * n + k] * f[j * n + k];
                    }
                    f[i * n + j] = s / d;
                }
            }
            for i in 0..n {
                for j in i + 1..n {
                    f[i * n + j] = 0.0;
                }
            }
            Coarse::Dense(f)
        } else {
            Coarse::Smooth
        };
        // A in f64 served the bounds and the coarsest factor; the cycle reads the f32 copy
        for l in &mut self.levels {
            l.a = Vec::new();
        }
        Ok(())
    }

    /// The coefficient c of A = V + c K.
    pub fn coefficient(&self) -> f64 {
        self.coefficient
    }

    /// Rows of each level (level 0: the free owned rows).
    pub fn sizes(&self) -> Vec<usize> {
        let mut s = vec![self.fine.n()];
        if self.coarsened {
            s.extend(self.levels.iter().map(|l| l.n()));
        }
        s
    }

    /// Stored entries of all levels' matrices over level 0's (operator complexity).
    pub fn complexity(&self) -> f64 {
        let n0 = self.fine.k.nnz().max(1);
        let coarse: usize = if self.coarsened {
            self.levels.iter().map(|l| l.k.nnz()).sum()
        } else {
            0
        };
        (n0 + coarse) as f64 / n0 as f64
    }

    /// The work of one V-cycle in level-0 matrix applications (three columns): level 0's
    /// 2 degree sweeps (one from zero being cheaper, the residual makes up for it), each
    /// coarse level's too and the transfers, and the coarsest solve.
    pub fn cycle_work(&self) -> f64 {
        let n0 = self.fine.k.nnz().max(1) as f64;
        let mut w = (2 * self.degree) as f64 * n0 + 2.0 * self.p_nnz as f64;
        let last = self.levels.len() - 1;
        for (i, l) in self.levels.iter().enumerate() {
            if i < last {
                w += (2 * self.degree) as f64 * l.k.nnz() as f64 + 2.0 * l.p.nnz() as f64;
            } else {
                w += match self.coarse {
                    Coarse::Dense(_) => (l.n() * l.n()) as f64,
                    Coarse::Smooth => (4 * self.degree) as f64 * l.k.nnz() as f64,
                };
            }
        }
        w / n0
    }

    /// Chebyshev smoothing of A x0 = b on level 0 with the solver's operator (every process
    /// takes part: each sweep exchanges the halo of x0).
    fn smooth0<S: Sweep<Twin = T>>(&mut self, prop: &mut S, b: &[V3], zero: bool) {
        let (lo, hi) = (self.fine.lo, self.fine.hi);
        let theta = 0.5 * (hi + lo);
        let delta = 0.5 * (hi - lo);
        // a process without rows that move still sweeps (the exchanges pair up)
        let (theta, delta) = if theta > 0.0 { (theta, delta) } else { (1.0, 0.5) };
        let sigma = theta / delta;
        let mut rho = 1.0 / sigma;
        // the three-term form x_k+1 = x_k + alpha (x_k - x_k-1) + beta D^-1 (b - A x_k): each
        // sweep writes the next iterate, and the iterates rotate (no separate update pass)
        let mut first = zero;
        if zero {
            let x0 = &mut self.x0[..self.owned];
            for ((x, b), d) in x0.iter_mut().zip(b).zip(&self.dinv0[..]) {
                let w = d / theta;
                *x = [b[0] * w, b[1] * w, b[2] * w];
            }
        } else {
            self.sweep0(prop, b, 0.0, 1.0 / theta, false);
        }
        for _ in 1..self.degree {
            let rho_new = 1.0 / (2.0 * sigma - rho);
            self.sweep0(prop, b, rho_new * rho, 2.0 * rho_new / delta, first);
            first = false;
            rho = rho_new;
        }
    }

    /// One Chebyshev sweep of level 0: x1 = x0 + alpha (x0 - xp) + beta D^-1 (b - A x0) (xp
    /// taken as 0 when `from_zero`), then (xp, x0, x1) <- (x0, x1, xp).
    fn sweep0<S: Sweep<Twin = T>>(&mut self, prop: &mut S, b: &[V3], alpha: f64, beta: f64, from_zero: bool) {
        let n = self.owned;
        let c = self.coefficient;
        let Multigrid {
            vol,
            dinv0,
            xp,
            x0,
            x1,
            sweep_op,
            ..
        } = self;
        let (vol, dinv, xp) = (&vol[..], &dinv0[..], &xp[..n]);
        // (A x)_i = V_i x_i - c sum_j w_ij (x_j - x_i)
        prop.update_with(sweep_op, x0, &mut x1[..n], |i, xi, l, yi| {
            let (v, w) = (vol[i], beta * dinv[i]);
            let p = if from_zero { [0.0; 3] } else { xp[i] };
            for k in 0..3 {
                yi[k] = xi[k] + alpha * (xi[k] - p[k]) + w * (b[i][k] - (v * xi[k] - c * l[k]));
            }
        });
        std::mem::swap(&mut self.xp, &mut self.x0);
        std::mem::swap(&mut self.x0, &mut self.x1);
    }

    /// One V-cycle on levels[0].b into levels[0].x.
    fn cycle(&mut self, halo: &Halo) {
        let deg = self.degree;
        let last = self.levels.len() - 1;
        for l in 0..last {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            let lv = &mut fine[l];
            lv.smooth(deg, true, halo);
            lv.residual(halo);
            lv.r.spmv(&lv.t, &mut coarse[0].b);
        }
        let lv = &mut self.levels[last];
        match &self.coarse {
            Coarse::Dense(f) => {
                let n = lv.n();
                // L y = b, L^T x = y
                for i in 0..n {
                    let mut s = lv.b[i];
                    for k in 0..i {
                        let (l, y) = (f[i * n + k], lv.x[k]);
                        for d in 0..3 {
                            s[d] -= l * y[d];
                        }
                    }
                    let di = f[i * n + i];
                    lv.x[i] = [s[0] / di, s[1] / di, s[2] / di];
                }
                for i in (0..n).rev() {
                    let mut s = lv.x[i];
                    for k in i + 1..n {
                        let (l, y) = (f[k * n + i], lv.x[k]);
                        for d in 0..3 {
                            s[d] -= l * y[d];
                        }
                    }
                    let di = f[i * n + i];
                    lv.x[i] = [s[0] / di, s[1] / di, s[2] / di];
                }
            }
            Coarse::Smooth => {
                lv.smooth(4 * deg, true, halo);
            }
        }
        for l in (0..last).rev() {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            let lv = &mut fine[l];
            lv.p.spmv_add(&coarse[0].x, &mut lv.x);
            lv.smooth(deg, false, halo);
        }
    }
}

impl<S: Sweep<Twin = T>, T: Send + Sync + Clone + 'static> Precond<S> for Multigrid<T> {
    fn apply(&mut self, prop: &mut S, r: &[V3], z: &mut [V3]) {
        let n = self.owned;
        if self.x0.is_empty() {
            // not made yet, or released: every application writes these before it reads them
            let layout = prop.layout();
            self.x0 = NodeField::filled(layout, [0.0; 3]);
            self.xp = NodeField::filled(layout, [0.0; 3]);
            self.x1 = NodeField::filled(layout, [0.0; 3]);
            self.t0 = vec![[0.0; 3]; self.n_t];
            self.mine = vec![[0.0; 3]; self.n_mine];
        }
        // level 0: smoothing, residual, restriction
        self.smooth0(prop, r, true);
        {
            let (vol, c) = (&self.vol[..], self.coefficient);
            prop.update_with(&self.sweep_op, &mut self.x0, &mut self.t0[..n], |i, xi, l, ti| {
                let v = vol[i];
                for k in 0..3 {
                    ti[k] = r[i][k] - (v * xi[k] - c * l[k]);
                }
            });
        }
        // restriction: this process's coarse rows from the residuals of their supports, then
        // the whole coarse vector on every process
        let plan = &*self.plan;
        self.send_buf.clear();
        for list in &plan.send {
            for &l in list {
                self.send_buf.extend_from_slice(&self.t0[l as usize]);
            }
        }
        prop.halo().all_to_all_into(
            &self.send_buf,
            &plan.send_counts,
            &plan.recv_counts,
            self.t0[n..].as_flattened_mut(),
        );
        plan.r.spmv(&self.t0, &mut self.mine);
        prop.halo()
            .all_gather_into(self.mine.as_flattened(), &plan.coarse_counts, &mut self.recv_buf);
        scatter(&plan.order, &self.recv_buf, &mut self.levels[0].b);
        self.cycle(prop.halo());
        self.p0.spmv_add(&self.levels[0].x, &mut self.x0[..n]);
        self.smooth0(prop, r, false);
        z.copy_from_slice(&self.x0[..n]);
    }
    fn release(&mut self) {
        let empty = || NodeField::filled(Default::default(), [0.0; 3]);
        (self.x0, self.xp, self.x1) = (empty(), empty(), empty());
        (self.t0, self.mine, self.send_buf, self.recv_buf) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    }
    fn cost(&self) -> f64 {
        // the one-process cost (the same on any process count, for the automatic choice)
        SWEEP_COST * self.cycle_work() * self.free_fraction
    }
    /// The hierarchy for another theta tau: the same aggregates, transfers and Galerkin
    /// products (shared), recombined (`set_coefficient`: the same bits as one built for it).
    fn derive(&self, theta_tau: f64) -> Option<Result<Box<dyn Precond<S>>>> {
        let mut m = self.clone();
        Some(
            m.set_coefficient(theta_tau)
                .map(|()| Box::new(m) as Box<dyn Precond<S>>),
        )
    }
}
