//! TR-BDF2 (Bank et al. 1985; Hosea and Shampine 1996): an L-stable, second-order implicit
//! integrator whose two stages share one matrix, solved by preconditioned conjugate gradients
//! on the symmetric volume-weighted form.
//!
//! With W the symmetric matrix of the compact scheme (W_ij = a_ij, W_ii = -sum_j a_ij, so
//! V L = W on the free nodes), b = V Q, gamma = 2 - sqrt 2, theta = gamma / 2 and
//! A = V - theta tau W (symmetric positive definite on the free nodes):
//!   stage 1 (trapezoidal rule over gamma tau):  A Y = V phi^n + theta tau (W phi^n + 2 b)
//!   stage 2 (BDF2 over the rest of the step):   A phi^(n+1) = V (c1 Y - c2 phi^n) + theta tau b
//! with c1 = 1 / (gamma (2 - gamma)), c2 = (1 - gamma)^2 / (gamma (2 - gamma)). A steady state
//! W phi + b = 0 solves both stages. The three components of phi share A, so the solver
//! treats them as one system A (x) I3: every operator application serves the three
//! components at once, and each iteration's dot products (summed over the components) go
//! into one exact reduction (Chronopoulos-Gear conjugate gradients, one reduction per
//! iteration), so the iterates do not depend on the number of processes or threads.

use super::{Precond, Preconditioner, Settings, StepPlan, StepStats, Stepper};
use crate::discretize::operator::{Operator, V3};
use crate::distribute::comm::{exact_sums_par, Comm, Grid, Wide};
use crate::distribute::field::NodeField;
use crate::propagate::{Propagation, Sources};
use anyhow::{bail, Result};
use rayon::prelude::*;

pub const GAMMA: f64 = 2.0 - std::f64::consts::SQRT_2;
/// theta = gamma / 2 = 1 - 1/sqrt 2: the implicit weight of both stages.
pub const THETA: f64 = 1.0 - std::f64::consts::FRAC_1_SQRT_2;

const CH: usize = 2048;

/// The amplification of one TR-BDF2 step on y' = lambda y, z = tau lambda:
/// Y = (1 + theta z) / (1 - theta z), R = (c1 Y - c2) / (1 - theta z).
pub fn amplification(z: f64) -> f64 {
    let g2 = GAMMA * (2.0 - GAMMA);
    let (c1, c2) = (1.0 / g2, (1.0 - GAMMA) * (1.0 - GAMMA) / g2);
    let y = (1.0 + THETA * z) / (1.0 - THETA * z);
    (c1 * y - c2) / (1.0 - THETA * z)
}

/// Jacobi: z_i = r_i / A_ii.
pub struct Jacobi {
    inv: Vec<f64>,
}

impl Precond for Jacobi {
    fn apply(&mut self, _: &mut Propagation, r: &[V3], z: &mut [V3]) {
        z.par_iter_mut()
            .zip(r.par_iter())
            .zip(self.inv.par_iter())
            .for_each(|((z, r), d)| {
                *z = [r[0] * d, r[1] * d, r[2] * d];
            });
    }
    fn inverse_diagonal(&self) -> Option<&[f64]> {
        Some(&self.inv)
    }
}

/// The diagonal of A = V - theta tau W on the owned rows: V_i (1 + theta tau sum_j c_ij)
/// (zero on rows that do not move).
pub fn diagonal(op: &Operator, vol: &[f64], theta_tau: f64) -> Vec<f64> {
    let Operator::Compact(c) = op else {
        return vec![0.0; vol.len()];
    };
    (0..vol.len())
        .into_par_iter()
        .map(|i| {
            let (s, e) = (c.row_ptr[i] as usize, c.row_ptr[i + 1] as usize);
            if vol[i] > 0.0 {
                let sum: f64 = (s..e).map(|p| c.c(p)).sum();
                vol[i] * (1.0 + theta_tau * sum)
            } else {
                0.0
            }
        })
        .collect()
}

/// max_i V_i (1 + 2 theta tau sum_j |c_ij|) over the owned rows: |(A u)_i| <= this max |u|.
fn row_bound(op: &Operator, vol: &[f64], theta_tau: f64) -> f64 {
    let Operator::Compact(c) = op else {
        return 0.0;
    };
    (0..vol.len())
        .into_par_iter()
        .map(|i| {
            let (s, e) = (c.row_ptr[i] as usize, c.row_ptr[i + 1] as usize);
            let abs: f64 = (s..e).map(|p| c.c(p).abs()).sum();
            vol[i] * (1.0 + 2.0 * theta_tau * abs)
        })
        .reduce(|| 0.0, f64::max)
}

/// The preconditioner of A = V - theta_tau W (`vol`: the volumes of the rows that move).
fn preconditioner(
    kind: Preconditioner,
    prop: &Propagation,
    vol: &[f64],
    gid: &[u64],
    theta_tau: f64,
    comm: &dyn Comm,
    path: &str,
) -> Result<Box<dyn Precond>> {
    let _ = (comm, path);
    Ok(match kind {
        // auto starts on jacobi; the trial solve may switch it to multigrid (`Implicit::trial`)
        Preconditioner::Jacobi | Preconditioner::Auto => {
            let d = diagonal(&prop.op, vol, theta_tau);
            Box::new(Jacobi {
                inv: d.iter().map(|&d| if d > 0.0 { 1.0 / d } else { 0.0 }).collect(),
            })
        }
        Preconditioner::Multigrid => Box::new(
            super::multigrid::Multigrid::new(prop, vol, gid, theta_tau, comm).map_err(|e| anyhow::anyhow!("{path}: {e}"))?,
        ),
        #[cfg(eprop_hypre)]
        Preconditioner::Amg => Box::new(
            super::amg::Amg::new(prop, vol, theta_tau, comm).map_err(|e| anyhow::anyhow!("{path}: {e}"))?,
        ),
        #[cfg(not(eprop_hypre))]
        Preconditioner::Amg => bail!(
            "{path}: [integrator] preconditioner = \"amg\" needs hypre, and this eprop was built without it; fix: use \"multigrid\" or \"jacobi\", or install hypre with 32-bit integers (Debian: libhypre-dev; elsewhere set HYPRE_DIR) and rebuild: it is found at build time"
        ),
    })
}

/// The matrix of one level (sub-steps of dt / 2^level): theta tau, the bound of its rows and
/// its preconditioner.
struct Level {
    theta_tau: f64,
    a_bound: f64,
    pre: Box<dyn Precond>,
}

/// `preconditioner = "auto"` tries multigrid only where jacobi's trial solve takes at least
/// this many iterations (below it, a V-cycle's cost, several operator applications, leaves no
/// room to win: the stiff tetgen kidney of 313k nodes took 31 with jacobi and 9 with
/// multigrid, and a step 3x longer with multigrid).
pub const MULTIGRID_FROM: usize = 40;
/// ... and takes it only where its trial solve is this many times cheaper than jacobi's (its
/// setup, and a recombination per error-control level, are not in the trial).
pub const MULTIGRID_MARGIN: f64 = 1.5;

/// The relative tolerance of the error estimate's filter solves with a diagonal preconditioner
/// (an estimate needs two digits). With a multigrid each filter pass is one preconditioned
/// step instead (`one_step`): conjugate gradients to 1e-1 stopped there after one iteration
/// on the 70^3 box, and one iteration to 1e-2 moved the error ratios by at most 1.2 %.
pub const FILTER_TOLERANCE: f64 = 1e-2;
/// How often the estimate goes through (V - theta tau W)^-1 V.
pub const FILTER_PASSES: usize = 2;

/// Conjugate-gradient iterations of the last step's solves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SolveStats {
    pub iterations: [usize; 2],
}

pub struct Implicit {
    plan: StepPlan,
    /// The relative error per mechanics step (`Settings::accuracy`; infinite: one TR-BDF2 step
    /// per mechanics step, no estimate).
    accuracy: f64,
    kind: Preconditioner,
    /// How `preconditioner = "auto"` chose (empty otherwise)
    pre_note: String,
    /// The level whose matrix theta_tau, a_bound and pre hold, and the other levels built
    level: u32,
    levels: Vec<Option<Level>>,
    /// Sub-steps of the last mechanics step: (accepted, rejected).
    pub substeps: (usize, usize),
    /// The estimated relative error of the last mechanics step (sum over its sub-steps).
    pub error: f64,
    theta_tau: f64,
    /// max_i V_i (1 + 2 theta tau sum_j |c_ij|): bounds |(A u)_i| / max |u| on every process
    a_bound: f64,
    /// V_i of the owned rows that move, 0 elsewhere
    vol: Vec<f64>,
    /// global ids of the local nodes (owned, then halo)
    gid: Vec<u64>,
    pre: Box<dyn Precond>,
    tol: f64,
    max_iterations: usize,
    path: String,
    step: u64,
    pub last: SolveStats,
    // work vectors
    phi_n: NodeField<V3>,
    y: NodeField<V3>,
    u: NodeField<V3>,
    e: NodeField<V3>,
    b: Vec<V3>,
    r: Vec<V3>,
    w: Vec<V3>,
    p: Vec<V3>,
    s: Vec<V3>,
}

impl Implicit {
    /// The TR-BDF2 stepper for the mechanics step dt on `prop`'s operator (compact scheme);
    /// `vol` are the control volumes, `active` the nodes that move and `gid` their global ids
    /// (owned first).
    pub fn new(
        prop: &Propagation,
        vol: &[f64],
        active: &[bool],
        gid: &[u64],
        dt: f64,
        h_bound: f64,
        settings: &Settings,
        path: &str,
        per_step: usize,
        why: String,
        comm: &dyn Comm,
    ) -> Result<Implicit> {
        let layout = prop.layout();
        let n = layout.n_owned;
        let theta_tau = THETA * dt;
        let vol: Vec<f64> = (0..n).map(|i| if active[i] { vol[i] } else { 0.0 }).collect();
        let a_bound = comm.max(row_bound(&prop.op, &vol, theta_tau));
        let pre = preconditioner(settings.preconditioner, prop, &vol, gid, theta_tau, comm, path)?;
        let z = || NodeField::filled(layout, [0.0; 3]);
        let zo = || vec![[0.0; 3]; n];
        Ok(Implicit {
            plan: StepPlan {
                integrator: super::Kind::Implicit,
                dt,
                h: super::euler_substep(dt, h_bound),
                step: dt,
                h_bound,
                per_step,
                cost: super::choose::CG_COST * per_step as f64,
                why,
            },
            accuracy: f64::INFINITY,
            kind: settings.preconditioner,
            pre_note: String::new(),
            level: 0,
            levels: Vec::new(),
            substeps: (0, 0),
            error: 0.0,
            theta_tau,
            a_bound,
            vol,
            gid: gid.to_vec(),
            pre,
            tol: settings.tolerance,
            max_iterations: settings.max_iterations,
            path: path.to_string(),
            step: 0,
            last: SolveStats::default(),
            phi_n: z(),
            y: z(),
            u: z(),
            e: z(),
            b: zo(),
            r: zo(),
            w: zo(),
            p: zo(),
            s: zo(),
        })
    }

    /// The cost in forward Euler substeps of `apps` operator applications of this
    /// integrator's solves: each at `choose::CG_COST`, plus one preconditioner application
    /// each at its own cost (`Precond::cost`; 0 for Jacobi, fused into the vector update).
    pub fn cost_of(&self, apps: usize) -> f64 {
        (super::choose::CG_COST + self.pre.cost()) * apps as f64
    }

    /// Numbers the next step 1 again (after the automatic choice's trial steps).
    pub fn restart_count(&mut self) {
        self.step = 0;
    }

    /// Turns the error control on: sub-steps of dt / 2^k, as many as `accuracy` (the relative
    /// error per mechanics step) needs (`Control`).
    pub fn set_accuracy(&mut self, accuracy: f64) {
        self.accuracy = accuracy;
    }

    /// Makes `level`'s matrix (sub-steps of dt / 2^level) the current one, building its
    /// preconditioner the first time.
    fn set_level(&mut self, level: u32, prop: &Propagation, comm: &dyn Comm) -> Result<()> {
        if level == self.level {
            return Ok(());
        }
        let k = level as usize;
        if self.levels.len() <= k.max(self.level as usize) {
            self.levels.resize_with(k.max(self.level as usize) + 1, || None);
        }
        let next = match self.levels[k].take() {
            Some(l) => l,
            None => {
                let theta_tau = THETA * self.plan.dt * 0.5f64.powi(level as i32);
                // a multigrid keeps its hierarchy and recombines it (setup once per run)
                let pre = match self.pre.derive(theta_tau) {
                    Some(derived) => derived?,
                    None => preconditioner(self.kind, prop, &self.vol, &self.gid, theta_tau, comm, &self.path)?,
                };
                Level {
                    theta_tau,
                    a_bound: comm.max(row_bound(&prop.op, &self.vol, theta_tau)),
                    pre,
                }
            }
        };
        let mut old = Level {
            theta_tau: self.theta_tau,
            a_bound: self.a_bound,
            pre: std::mem::replace(&mut self.pre, next.pre),
        };
        // one level's preconditioner runs at a time: the others keep no work buffers
        old.pre.release();
        self.levels[self.level as usize] = Some(old);
        (self.theta_tau, self.a_bound, self.level) = (next.theta_tau, next.a_bound, level);
        Ok(())
    }

    /// The error of the TR-BDF2 step just taken (phi_n to prop.phi through self.y) against
    /// its tolerance: Hosea and Shampine's embedded third-order estimate,
    ///   est = tau/3 ((1 - sqrt 2) f(phi_n) + f(Y) - gamma f(phi_n+1)),  f = L phi + Q
    /// (Q cancels: V est = tau/3 W z, z = (1 - sqrt 2) phi_n + Y - gamma phi_n+1), filtered as
    /// in ode23tb through A e = V est so that stiff modes, which TR-BDF2 damps, do not count;
    /// then ||e|| / (accuracy max(||phi_n||, ||phi_n+1||, floor)), every norm an exact sum over
    /// every process. Returns the ratio and the operator applications it took.
    fn estimate(&mut self, prop: &mut Propagation, comm: &dyn Comm, floor: &mut f64) -> Result<(f64, usize)> {
        let n = self.vol.len();
        let c = (self.theta_tau / THETA) / 3.0;
        let a0 = 1.0 - std::f64::consts::SQRT_2;
        for i in 0..n {
            let (p0, y, p1) = (self.phi_n[i], self.y[i], prop.phi[i]);
            self.e[i] = std::array::from_fn(|d| a0 * p0[d] + y[d] - GAMMA * p1[d]);
        }
        {
            let Implicit { vol, e, b, .. } = self;
            let vol = &vol[..];
            prop.update_to(e, b, |i, _, l, bi| {
                let v = vol[i] * c;
                *bi = [v * l[0], v * l[1], v * l[2]];
            });
        }
        let mut e = std::mem::replace(&mut self.e, NodeField::filled(Default::default(), [0.0; 3]));
        let mut it = 0;
        let mut per_pass = [0usize; FILTER_PASSES];
        for pass in 0..FILTER_PASSES {
            if pass > 0 {
                for i in 0..n {
                    let v = self.vol[i];
                    self.b[i] = [v * e[i][0], v * e[i][1], v * e[i][2]];
                }
            }
            let step = if self.pre.inverse_diagonal().is_some() {
                e[..n].iter_mut().for_each(|x| *x = [0.0; 3]);
                self.solve(prop, &mut e, comm, 3, FILTER_TOLERANCE.max(self.tol))
                    .map(|k| (k, k + 2))
            } else {
                self.one_step(prop, &mut e, comm).map(|()| (1, 1))
            };
            match step {
                Ok((k, apps)) => {
                    per_pass[pass] = k;
                    it += apps
                }
                Err(err) => {
                    self.e = e;
                    return Err(err);
                }
            }
        }
        self.e = e;
        tracing::trace!(
            "implicit step {}: the estimate's filter solves took {per_pass:?} iterations",
            self.step + 1
        );
        let (e, p0, p1) = (&self.e[..n], &self.phi_n[..n], &prop.phi[..n]);
        let [ee, s0, s1] = super::squares(comm, n, |i| [e[i], p0[i], p1[i]]);
        // the first attempt of a mechanics step sets the floor: from phi = 0 the first
        // sub-steps see a tiny phi, against which nothing short is accurate
        let scale = s0.max(s1).sqrt().max(*floor);
        if *floor == 0.0 {
            *floor = scale;
        }
        let err = ee.sqrt();
        let ratio = if err <= super::ROUNDOFF * scale {
            0.0
        } else {
            err / (self.accuracy * scale)
        };
        Ok((ratio, 1 + it))
    }

    /// The first conjugate-gradient iterate of A e = self.b from e = 0, e = alpha M b with
    /// alpha = (b, M b) / (M b, A M b): one V-cycle and one operator application, the error
    /// estimate's filter with a multigrid (module notes). Sums exact over every process.
    fn one_step(&mut self, prop: &mut Propagation, e: &mut NodeField<V3>, comm: &dyn Comm) -> Result<()> {
        let n = self.vol.len();
        let Implicit {
            vol,
            pre,
            b,
            w,
            u,
            theta_tau,
            a_bound,
            ..
        } = self;
        pre.apply(prop, b, &mut u[..n]);
        let [mb, mu] = max_abs2(b, &u[..n]);
        let (gamma, delta, _) = apply_and_dots(prop, vol, *theta_tau, u, w, b, b, [mb, mu, mb], *a_bound, comm);
        if !gamma.is_finite() || !delta.is_finite() {
            bail!(
                "{}: implicit: the error estimate of step {} produced a non-finite value; fix: check the scenario's conductivity and dt (eprop check), or use [model] integrator = \"rkl2\"",
                self.path,
                self.step + 1
            );
        }
        let alpha = if gamma == 0.0 {
            0.0
        } else if gamma > 0.0 && delta > 0.0 {
            gamma / delta
        } else {
            bail!(
                "{}: implicit: the error estimate of step {} met a matrix or preconditioner that is not positive definite ((b, M b) = {gamma:.3e}, (M b, A M b) = {delta:.3e}); fix: use [integrator] preconditioner = \"jacobi\"",
                self.path,
                self.step + 1
            );
        };
        let u = &self.u[..n];
        e[..n]
            .par_iter_mut()
            .zip(u.par_iter())
            .for_each(|(e, u)| *e = [alpha * u[0], alpha * u[1], alpha * u[2]]);
        Ok(())
    }

    /// Replaces the planned applications per step, their cost and the reason (the automatic
    /// choice).
    pub fn set_plan(&mut self, per_step: usize, cost: f64, why: String) {
        self.plan.per_step = per_step;
        self.plan.cost = cost;
        self.plan.why = why;
    }

    /// Iterations of one solve of A x = V z from x = 0, z a pseudo-random field of the global
    /// node ids (the same on any number of processes): the automatic choice's estimate of
    /// the iterations per solve. `gid` covers the owned nodes.
    ///
    /// With `preconditioner = "auto"` the first trial also settles the preconditioner:
    /// jacobi, unless jacobi takes at least `MULTIGRID_FROM` iterations and a multigrid's
    /// trial solve costs less than 1 / `MULTIGRID_MARGIN` of jacobi's (iterations times the
    /// cost of one, `CG_COST` plus the V-cycle's). The counts are the same on any number of
    /// processes, and so is the choice.
    pub fn trial(&mut self, prop: &mut Propagation, gid: &[u64], comm: &dyn Comm) -> Result<usize> {
        let it = self.trial_solve(prop, gid, comm)?;
        if self.kind != Preconditioner::Auto {
            return Ok(it);
        }
        self.kind = Preconditioner::Jacobi;
        if it < MULTIGRID_FROM {
            self.pre_note = format!("auto: jacobi, {it} iterations per solve in a trial");
            return Ok(it);
        }
        let mg = match super::multigrid::Multigrid::new(prop, &self.vol, &self.gid, self.theta_tau, comm) {
            Ok(m) => m,
            Err(e) => {
                self.pre_note = format!("auto: jacobi ({it} iterations per solve in a trial; multigrid: {e})");
                return Ok(it);
            }
        };
        let jacobi = std::mem::replace(&mut self.pre, Box::new(mg));
        let (cost_j, mg_it) = (it as f64 * super::choose::CG_COST, self.trial_solve(prop, gid, comm));
        match mg_it {
            Ok(k) if k as f64 * (super::choose::CG_COST + self.pre.cost()) * MULTIGRID_MARGIN < cost_j => {
                self.kind = Preconditioner::Multigrid;
                self.pre_note = format!("auto: multigrid, {k} iterations per solve in a trial against jacobi's {it}");
                Ok(k)
            }
            Ok(k) => {
                self.pre = jacobi;
                self.pre_note = format!("auto: jacobi, {it} iterations per solve in a trial against multigrid's {k} at several times the cost each");
                Ok(it)
            }
            Err(_) => {
                self.pre = jacobi;
                self.pre_note =
                    format!("auto: jacobi, {it} iterations per solve in a trial (multigrid's trial did not converge)");
                Ok(it)
            }
        }
    }

    /// The preconditioner in use.
    pub fn preconditioner_name(&self) -> &'static str {
        self.kind.name()
    }

    /// The preconditioner in use and how it was chosen (or the trial's `it` iterations per
    /// solve), for the summary and `eprop check`.
    pub fn preconditioner_phrase(&self, it: usize) -> String {
        if self.pre_note.is_empty() {
            format!(
                "{} preconditioner ({it} iterations per solve in a trial)",
                self.kind.name()
            )
        } else {
            format!("{} preconditioner ({})", self.kind.name(), self.pre_note)
        }
    }

    /// One trial solve with the current preconditioner (`trial`).
    fn trial_solve(&mut self, prop: &mut Propagation, gid: &[u64], comm: &dyn Comm) -> Result<usize> {
        use super::stability::hash_unit;
        let n = self.vol.len();
        for i in 0..n {
            let g = gid[i];
            let v = self.vol[i];
            self.b[i] = [v * hash_unit(3 * g), v * hash_unit(3 * g + 1), v * hash_unit(3 * g + 2)];
        }
        let mut x = NodeField::filled(prop.layout(), [0.0; 3]);
        self.solve(prop, &mut x, comm, 0, self.tol)
    }

    /// Solves A x = self.b for the three components, starting from x; returns the iterations
    /// (each one operator application; the solve makes two more to start).
    fn solve(
        &mut self,
        prop: &mut Propagation,
        x: &mut NodeField<V3>,
        comm: &dyn Comm,
        stage: usize,
        tol: f64,
    ) -> Result<usize> {
        let n = self.vol.len();
        let tt = self.theta_tau;
        let a_bound = self.a_bound;
        let Implicit {
            vol,
            pre,
            b,
            r,
            w,
            p,
            s,
            u,
            ..
        } = self;
        let (vol, b_) = (&vol[..], &b[..]);
        // r = b - A x; u = M r
        prop.update_to(x, r, |i, xi, l, ri| {
            let v = vol[i];
            for d in 0..3 {
                ri[d] = b_[i][d] - v * (xi[d] - tt * l[d]);
            }
        });
        pre.apply(prop, r, &mut u[..n]);
        // The tolerance is relative to ||x||_A^2 = (b, A^-1 b). A diagonal preconditioner
        // measures it as (b, M b), consistently with (r, M r): both see smooth modes scaled
        // alike. A multigrid's (r, M r) is close to the error's A-norm itself (M A is near I
        // on every mode), and M b would cost a V-cycle: (b, x_k) measures it instead, exact
        // at the start and carried by the recurrences of x_k and p_k through (b, u_k), which
        // the operator pass sums with the other two.
        let energy = pre.inverse_diagonal().is_none();
        let mut scale = if energy {
            let x_ = &x[..n];
            exact_sums_par(comm, n, |i| {
                [b_[i][0] * x_[i][0] + b_[i][1] * x_[i][1] + b_[i][2] * x_[i][2]]
            })[0]
        } else {
            pre.apply(prop, b_, p);
            let p_ = &p[..];
            let bb: [f64; 3] = exact_sums_par(comm, n, |i| {
                [b_[i][0] * p_[i][0], b_[i][1] * p_[i][1], b_[i][2] * p_[i][2]]
            });
            bb[0] + bb[1] + bb[2]
        };
        let mb = b_.par_iter().map(|v| max_abs(*v)).reduce(|| 0.0, f64::max);
        let what = if stage == 0 {
            "the trial solve (a pseudo-random right-hand side, to estimate the work per step)".to_string()
        } else if stage == 3 {
            format!("the error estimate's solve of step {}", self.step + 1)
        } else {
            format!("the solve of stage {stage} of step {}", self.step + 1)
        };
        let [mr, mu] = max_abs2(r, &u[..n]);
        let (mut gamma, mut delta, mut bu) = apply_and_dots(prop, vol, tt, u, w, r, b_, [mr, mu, mb], a_bound, comm);
        let (mut alpha, mut gamma_prev, mut bp) = (0.0f64, 0.0f64, 0.0f64);
        let mut it = 0usize;
        loop {
            if !gamma.is_finite() || !delta.is_finite() {
                bail!(
                    "{}: implicit: {what} produced a non-finite residual; fix: check the scenario's conductivity and dt (eprop check), or use [model] integrator = \"rkl2\"",
                    self.path
                );
            }
            if gamma < 0.0 {
                bail!(
                    "{}: implicit: {what}: the preconditioner is not positive definite (r M r = {gamma:.3e}), so conjugate gradients cannot converge; fix: use [integrator] preconditioner = \"jacobi\"",
                    self.path
                );
            }
            if gamma <= tol * tol * scale {
                return Ok(it);
            }
            if it >= self.max_iterations {
                bail!(
                    "{}: implicit: {what} did not converge in {} iterations (relative residual {:.3e} > tolerance {:.1e}); \
                     fix: raise [integrator] max_iterations, or loosen [integrator] tolerance, or use [integrator] preconditioner = \"amg\", or [model] integrator = \"rkl2\"",
                    self.path,
                    self.max_iterations,
                    (gamma / scale.max(f64::MIN_POSITIVE)).sqrt(),
                    tol
                );
            }
            let (beta, den) = if it == 0 {
                (0.0, delta)
            } else {
                let beta = gamma / gamma_prev;
                (beta, delta - beta * gamma / alpha)
            };
            if !(den > 0.0) {
                bail!(
                    "{}: implicit: {what} broke down (the matrix is not positive definite: curvature {den:.3e}); fix: use [model] integrator = \"rkl2\" or \"euler\"",
                    self.path
                );
            }
            alpha = gamma / den;
            gamma_prev = gamma;
            // p = u + beta p, x += alpha p: (b, p) and (b, x) follow
            if energy {
                bp = bu + beta * bp;
                scale += alpha * bp;
            }
            let (a, bt) = (alpha, beta);
            let inv = pre.inverse_diagonal();
            let xo = &mut x[..n];
            let uo = &mut u[..n];
            // p = u + beta p, s = w + beta s, x += alpha p, r -= alpha s, u = M r (Jacobi)
            let m2 = p
                .par_chunks_mut(CH)
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
                .reduce(|| [0.0; 2], |a, b| [a[0].max(b[0]), a[1].max(b[1])]);
            let [mr, mu] = if inv.is_none() {
                pre.apply(prop, r, &mut u[..n]);
                max_abs2(r, &u[..n])
            } else {
                m2
            };
            (gamma, delta, bu) = apply_and_dots(prop, vol, tt, u, w, r, b_, [mr, mu, mb], a_bound, comm);
            it += 1;
        }
    }
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
        .reduce(|| [0.0; 2], |a, b| [a[0].max(b[0]), a[1].max(b[1])])
}

/// w = A u with the dot products (r, u), (w, u) and (b, u) over the three components in the
/// same pass, summed exactly over every process: each row's three products are added in a
/// fixed order, then put on a grid that comes from bounds known before the pass
/// (|r_i . u_i| <= 3 max|r| max|u|, |w_i . u_i| <= 3 a_bound max|u|^2,
/// |b_i . u_i| <= 3 max|b| max|u|), so one collective brings the maxima and one the sums.
#[allow(clippy::too_many_arguments)]
fn apply_and_dots(
    prop: &mut Propagation,
    vol: &[f64],
    tt: f64,
    u: &mut NodeField<V3>,
    w: &mut [V3],
    r: &[V3],
    b: &[V3],
    local_max: [f64; 3],
    a_bound: f64,
    comm: &dyn Comm,
) -> (f64, f64, f64) {
    let m = comm.max_each(&local_max);
    let (mr, mu, mb) = (m[0], m[1], m[2]);
    // 3.01: the three products of a row and their rounding
    let g_ru = Grid::new(3.01 * mr * mu);
    let g_wu = Grid::new(3.01 * a_bound * mu * mu);
    let g_bu = Grid::new(3.01 * mb * mu);
    let acc: Acc = prop.fold_to(
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

impl Stepper for Implicit {
    fn plan(&self) -> &StepPlan {
        &self.plan
    }
    fn last_error(&self) -> Option<f64> {
        self.accuracy.is_finite().then_some(self.error)
    }
    fn replayed(&mut self, error: Option<f64>) {
        self.step += 1;
        self.error = error.unwrap_or(0.0);
    }

    fn advance(&mut self, prop: &mut Propagation, q: &Sources, comm: &dyn Comm) -> Result<StepStats> {
        if !self.accuracy.is_finite() {
            let applications = self.tr_bdf2(prop, q, comm)?;
            self.step += 1;
            self.substeps = (1, 0);
            return Ok(StepStats { applications });
        }
        let mut c = super::Control::new(0, 3.0);
        let mut applications = 0;
        let (mut accepted, mut rejected) = (0, 0);
        let mut floor = 0.0;
        let mut error = 0.0;
        while !c.done() {
            if c.level > super::MAX_LEVEL {
                bail!(
                    "{}: implicit: step {} needs TR-BDF2 steps shorter than dt / 2^{} to keep [integrator] accuracy = {:e}; fix: loosen accuracy, or use [model] integrator = \"euler\", or lower dt",
                    self.path,
                    self.step + 1,
                    super::MAX_LEVEL,
                    self.accuracy
                );
            }
            self.set_level(c.level, prop, comm)?;
            applications += self.tr_bdf2(prop, q, comm)?;
            let (ratio, apps) = self.estimate(prop, comm, &mut floor)?;
            applications += apps;
            tracing::trace!(
                "implicit step {} level {} pos {} ratio {ratio:.3e} its {:?}",
                self.step + 1,
                c.level,
                c.pos,
                self.last.iterations
            );
            let added = ratio * self.accuracy;
            if c.after(ratio) {
                accepted += 1;
                error += added;
            } else {
                rejected += 1;
                // back to phi_n (prop.phi's buffer is free)
                std::mem::swap(&mut self.phi_n, &mut prop.phi);
            }
        }
        self.set_level(0, prop, comm)?;
        self.step += 1;
        self.substeps = (accepted, rejected);
        self.error = error;
        tracing::debug!(
            "implicit step {}: {accepted} TR-BDF2 steps, {rejected} rejected",
            self.step
        );
        Ok(StepStats { applications })
    }
}

impl Implicit {
    /// One TR-BDF2 step of the current level's length from prop.phi (kept in phi_n, the
    /// stage value in y); returns the operator applications.
    fn tr_bdf2(&mut self, prop: &mut Propagation, q: &Sources, comm: &dyn Comm) -> Result<usize> {
        let n = self.vol.len();
        let tt = self.theta_tau;
        // phi^n, and stage 1's right-hand side V phi + theta tau (W phi + 2 V Q)
        std::mem::swap(&mut self.phi_n, &mut prop.phi);
        {
            let vol = &self.vol;
            prop.update_to(&mut self.phi_n, &mut self.b, |i, x, l, bi| {
                let v = vol[i];
                for d in 0..3 {
                    bi[d] = v * (x[d] + tt * l[d]);
                }
            });
            for &(i, qi) in q {
                let v = vol[i as usize];
                for d in 0..3 {
                    self.b[i as usize][d] += 2.0 * tt * v * qi[d];
                }
            }
        }
        let mut y = std::mem::replace(&mut self.y, NodeField::filled(Default::default(), [0.0; 3]));
        y[..n].copy_from_slice(&self.phi_n[..n]);
        let it1 = self.solve(prop, &mut y, comm, 1, self.tol);
        let it1 = match it1 {
            Ok(it) => it,
            Err(e) => {
                self.y = y;
                return Err(e);
            }
        };
        // stage 2: V (c1 Y - c2 phi^n) + theta tau V Q, from phi^n + (Y - phi^n) / gamma
        let g2 = GAMMA * (2.0 - GAMMA);
        let (c1, c2) = (1.0 / g2, (1.0 - GAMMA) * (1.0 - GAMMA) / g2);
        let mut x = std::mem::replace(&mut prop.phi, NodeField::filled(Default::default(), [0.0; 3]));
        for i in 0..n {
            let (yi, pi, v) = (y[i], self.phi_n[i], self.vol[i]);
            for d in 0..3 {
                self.b[i][d] = v * (c1 * yi[d] - c2 * pi[d]);
                x[i][d] = pi[d] + (yi[d] - pi[d]) / GAMMA;
            }
        }
        for &(i, qi) in q {
            let v = self.vol[i as usize];
            for d in 0..3 {
                self.b[i as usize][d] += tt * v * qi[d];
            }
        }
        self.y = y;
        let it2 = self.solve(prop, &mut x, comm, 2, self.tol);
        prop.phi = x;
        let it2 = it2?;
        self.last = SolveStats { iterations: [it1, it2] };
        tracing::trace!("implicit step {}: {it1} + {it2} iterations", self.step + 1);
        Ok(1 + (it1 + 2) + (it2 + 2))
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

    #[test]
    fn tr_bdf2_is_second_order_and_l_stable_where_crank_nicolson_rings() {
        for z in [-1e-2f64, -2e-3] {
            let err = amplification(z) - z.exp();
            assert!(err.abs() < 0.1 * z.abs().powi(3), "{z}: {err:e}");
        }
        let cn = |z: f64| (1.0 + z / 2.0) / (1.0 - z / 2.0);
        for k in 0..400 {
            let z = -(10f64.powf(-3.0 + k as f64 * 0.025));
            assert!(amplification(z).abs() <= 1.0, "{z}");
        }
        // a sliver mode at tau lambda = -1e4: TR-BDF2 damps it to 0, Crank-Nicolson flips its
        // sign and keeps 99.96% of it every step
        assert!(amplification(-1e4).abs() < 1e-3);
        assert!(cn(-1e4) < -0.999);
        assert!(amplification(-1e12).abs() < 1e-11);
    }
}
