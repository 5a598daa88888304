//! TR-BDF2 (Bank et al. 1985; Hosea and Shampine 1996): an L-stable, second-order implicit
//! integrator whose two stages share one matrix, solved by preconditioned conjugate gradients
//! on the symmetric volume-weighted form (`solver`, `linalg::cg`), and its embedded error
//! estimate.
//!
//! With W the symmetric matrix of the compact scheme (W_ij = a_ij, W_ii = -sum_j a_ij, so
//! V L = W on the free nodes), b = V Q, gamma = 2 - sqrt 2, theta = gamma / 2 and
//! A = V - theta tau W (symmetric positive definite on the free nodes):
//!   stage 1 (trapezoidal rule over gamma tau):  A Y = V phi^n + theta tau (W phi^n + 2 b)
//!   stage 2 (BDF2 over the rest of the step):   A phi^(n+1) = V (c1 Y - c2 phi^n) + theta tau b
//! with c1 = 1 / (gamma (2 - gamma)), c2 = (1 - gamma)^2 / (gamma (2 - gamma)). A steady state
//! W phi + b = 0 solves both stages. The three components of phi share A and are solved as
//! one system A (x) I3 whose dot products are exact sums, so the iterates do not depend on
//! the number of processes or threads.

use super::solver::Solver;
use super::{ErrorState, StepPlan, StepStats, Stepper};
use crate::config::integrator::{Preconditioner, Settings};
use crate::distribute::comm::Comm;
use crate::distribute::field::NodeField;
use crate::linalg::V3;
use crate::propagate::{Propagation, Sources};
use anyhow::{bail, Result};

pub(crate) const GAMMA: f64 = 2.0 - std::f64::consts::SQRT_2;
/// theta = gamma / 2 = 1 - 1/sqrt 2: the implicit weight of both stages.
pub const THETA: f64 = 1.0 - std::f64::consts::FRAC_1_SQRT_2;

/// The amplification of one TR-BDF2 step on y' = lambda y, z = tau lambda:
/// Y = (1 + theta z) / (1 - theta z), R = (c1 Y - c2) / (1 - theta z).
pub fn amplification(z: f64) -> f64 {
    let g2 = GAMMA * (2.0 - GAMMA);
    let (c1, c2) = (1.0 / g2, (1.0 - GAMMA) * (1.0 - GAMMA) / g2);
    let y = (1.0 + THETA * z) / (1.0 - THETA * z);
    (c1 * y - c2) / (1.0 - THETA * z)
}

/// The relative tolerance of the error estimate's filter solves with a diagonal preconditioner
/// (an estimate needs two digits). With a multigrid each filter pass is one preconditioned
/// step instead (`Solver::first_iterate`): conjugate gradients to 1e-1 stopped there after one
/// iteration on the 70^3 box, and one iteration to 1e-2 moved the error ratios by at most 1.2 %.
pub(crate) const FILTER_TOLERANCE: f64 = 1e-2;
/// How often the estimate goes through (V - theta tau W)^-1 V.
pub(crate) const FILTER_PASSES: usize = 2;

/// The level whose filter carries a sub-step's error estimate to the end of its mechanics step
/// where a tool moved the potential of the rows it holds at the step's start (`carry`), None
/// where nothing is carried (nothing moved, or the sub-step ends the mechanics step).
///
/// A tool sets its held nodes' potential at the start of each mechanics step (a newly caught
/// node by a jump): a discontinuity of the data, whose layer in the free nodes around them
/// relaxes as fast as the cells it crosses. The sub-steps inside it are never in their
/// asymptotic range (on the head atlas the estimate of the first sub-step fell from 288 to 273
/// times the tolerance over six halvings), so the control halved down to dt / 2^17 and climbed
/// back in 60 sub-steps (7 rejected), each held to the tolerance although the layer's error
/// decays within the step. But within a mechanics step the operator
/// and the sources are constant, so an error committed at t_e is carried to the step's end
/// (all the mechanics reads) by exp((t_end - t_e) L), which damps the layer's fast modes. The
/// estimate is filtered further by (V - theta s W)^-1 V (`CARRY_PASSES` = 3 times), s the
/// longest dt / 2^j with 3 theta s <= t_end - t_e, which damps no mode more than the rest of
/// the step does: (1 + theta s lambda)^3 <= exp(3 theta s lambda) <= exp((t_end - t_e)
/// lambda). What counts is then the error the step ends with; the last sub-step's is its
/// own.
pub(crate) fn carry_level(carry: bool, level: u32, pos: u64) -> Option<u32> {
    // sub-steps of dt / 2^level left after this one
    let left = (1u64 << level).checked_sub(pos + 1).filter(|&k| k > 0 && carry)?;
    // the longest dt / 2^j with CARRY_PASSES theta dt / 2^j <= left dt / 2^level
    let reach = left as f64 / (CARRY_PASSES as f64 * THETA);
    Some((level as f64 - reach.log2()).ceil().max(0.0) as u32)
}

/// How often the estimate goes through (V - theta s W)^-1 V to carry it to the end of its
/// mechanics step (`carry_level`).
pub(crate) const CARRY_PASSES: usize = 3;

/// Conjugate-gradient iterations of the last step's solves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SolveStats {
    pub iterations: [usize; 2],
}

pub struct Implicit {
    plan: StepPlan,
    /// The error control (an infinite accuracy: one TR-BDF2 step per mechanics step, no
    /// estimate).
    errors: ErrorState,
    /// The solves of the current level and the levels built.
    solver: Solver,
    pub last: SolveStats,
    /// Whether a tool changed the potential of a row it holds over this mechanics step at its
    /// start (on any process: `Propagation::held_moved`), so that the estimate is carried to
    /// the step's end (`carry_level`).
    carry: bool,
    // work vectors: phi at the step's start, the stage value, the estimate and the right-hand
    // side
    phi_n: NodeField<V3>,
    y: NodeField<V3>,
    e: NodeField<V3>,
    b: Vec<V3>,
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
        comm: &dyn Comm,
    ) -> Result<Implicit> {
        let layout = prop.layout();
        let solver = Solver::new(prop, vol, active, gid, dt, settings, path, comm)?;
        let z = || NodeField::filled(layout, [0.0; 3]);
        Ok(Implicit {
            plan: StepPlan {
                integrator: super::Kind::Implicit,
                dt,
                h: super::euler_substep(dt, h_bound),
                step: dt,
                h_bound,
                // the chooser sets them from its trial (`set_plan`)
                per_step: 0,
                cost: 0.0,
                why: String::new(),
            },
            errors: ErrorState::new(1.0),
            solver,
            last: SolveStats::default(),
            carry: false,
            phi_n: z(),
            y: z(),
            e: z(),
            b: vec![[0.0; 3]; layout.n_owned],
        })
    }

    /// The cost in forward Euler substeps of `apps` operator applications of this
    /// integrator's solves: each at `choose::CG_COST`, plus one preconditioner application
    /// each at its own cost (`Precond::cost`; 0 for Jacobi, fused into the vector update).
    pub fn cost_of(&self, apps: usize) -> f64 {
        (super::choose::CG_COST + self.solver.preconditioner_cost()) * apps as f64
    }

    /// The real-time mode: at most `k` conjugate-gradient iterations per stage
    /// (`Solver::set_fixed`), so at most `applications_bound` operator applications per step.
    pub fn set_fixed(&mut self, k: usize) {
        self.solver.set_fixed(k);
    }

    /// Builds `kind` as the preconditioner (`Solver::set_preconditioner`).
    pub fn set_preconditioner(&mut self, kind: Preconditioner, prop: &Propagation, comm: &dyn Comm) -> Result<()> {
        self.solver.set_preconditioner(kind, prop, comm)
    }

    /// The real-time mode with a direct solver (`Solver::set_direct`); Err says why not (the
    /// solves then stay iterative). Returns the unknowns, the factor's entries and A's.
    pub fn set_direct(&mut self, prop: &Propagation, comm: &dyn Comm) -> Result<(usize, f64, usize)> {
        self.solver.set_direct(prop, comm)?;
        let d = self.solver.direct().expect("set");
        Ok((d.unknowns(), d.factor_entries(), d.matrix_entries()))
    }

    /// The most operator applications one step takes in the real-time mode: the stage 1
    /// right-hand side's, then per stage its iterations and the two that start it.
    pub fn applications_bound(k: usize) -> usize {
        1 + 2 * (k + 2)
    }

    /// Numbers the next step 1 again (after the automatic choice's trial steps).
    pub fn restart_count(&mut self) {
        self.errors.step = 0;
    }

    /// Turns the error control on: sub-steps of dt / 2^k, as many as `accuracy` (the relative
    /// error per mechanics step) needs (`Control`).
    pub fn set_accuracy(&mut self, accuracy: f64) {
        self.errors.accuracy = accuracy;
    }

    /// Replaces the planned applications per step, their cost and the reason (the automatic
    /// choice).
    pub fn set_plan(&mut self, per_step: usize, cost: f64, why: String) {
        self.plan.per_step = per_step;
        self.plan.cost = cost;
        self.plan.why = why;
    }

    /// Iterations of one trial solve, which with `preconditioner = "auto"` also settles the
    /// preconditioner (`Solver::trial`).
    pub fn trial(&mut self, prop: &mut Propagation, gid: &[u64], comm: &dyn Comm) -> Result<usize> {
        self.solver.trial(prop, gid, comm)
    }

    /// The preconditioner in use.
    pub fn preconditioner_name(&self) -> &'static str {
        self.solver.preconditioner_name()
    }

    /// The preconditioner in use and how it was chosen (`Solver::preconditioner_phrase`).
    pub fn preconditioner_phrase(&self, it: usize) -> String {
        self.solver.preconditioner_phrase(it)
    }

    /// One pass of the estimate's filter at the solver's level: e <- (V - theta tau W)^-1 b,
    /// with b = V e where `b_from_e` (else the b already made), by the diagonal level's solve
    /// or the preconditioner's first iterate. Returns the iterations and the operator
    /// applications it took.
    fn filter(&mut self, prop: &mut Propagation, comm: &dyn Comm, b_from_e: bool) -> Result<(usize, usize)> {
        let n = self.b.len();
        let step = self.errors.step;
        if b_from_e {
            let vol = self.solver.vol();
            for i in 0..n {
                let (v, e) = (vol[i], self.e[i]);
                self.b[i] = [v * e[0], v * e[1], v * e[2]];
            }
        }
        Ok(if self.solver.diagonal() {
            self.e[..n].iter_mut().for_each(|x| *x = [0.0; 3]);
            let tol = FILTER_TOLERANCE.max(self.solver.tolerance());
            let k = self.solver.solve(prop, &mut self.e, &self.b, comm, 3, step, tol)?;
            (k, k + 2)
        } else {
            self.solver.first_iterate(prop, &mut self.e, &self.b, comm, step)?;
            (1, 1)
        })
    }

    /// The error of the TR-BDF2 step just taken (phi_n to prop.phi through self.y) against
    /// its tolerance: Hosea and Shampine's embedded third-order estimate,
    ///   est = tau/3 ((1 - sqrt 2) f(phi_n) + f(Y) - gamma f(phi_n+1)),  f = L phi + Q
    /// (Q cancels: V est = tau/3 W z, z = (1 - sqrt 2) phi_n + Y - gamma phi_n+1), filtered as
    /// in ode23tb through A e = V est so that stiff modes, which TR-BDF2 damps, do not count;
    /// then ||e|| / (accuracy max(||phi_n||, ||phi_n+1||, floor)) (`SubSteps::ratio`), every
    /// norm an exact sum over every process. Returns the ratio and the operator applications
    /// it took.
    fn estimate(&mut self, prop: &mut Propagation, comm: &dyn Comm, sub: &mut super::SubSteps) -> Result<(f64, usize)> {
        let n = self.b.len();
        let step = self.errors.step;
        let c = (self.solver.theta_tau() / THETA) / 3.0;
        let a0 = 1.0 - std::f64::consts::SQRT_2;
        for i in 0..n {
            let (p0, y, p1) = (self.phi_n[i], self.y[i], prop.phi[i]);
            self.e[i] = std::array::from_fn(|d| a0 * p0[d] + y[d] - GAMMA * p1[d]);
        }
        let vol = self.solver.vol();
        prop.update_to(&mut self.e, &mut self.b, |i, _, l, bi| {
            let v = vol[i] * c;
            *bi = [v * l[0], v * l[1], v * l[2]];
        });
        let mut it = 0;
        let mut per_pass = [0usize; FILTER_PASSES];
        for pass in 0..FILTER_PASSES {
            // the first pass's right-hand side is the one just made, the others V e
            let (k, apps) = self.filter(prop, comm, pass > 0)?;
            per_pass[pass] = k;
            it += apps;
        }
        tracing::trace!(
            "implicit step {}: the estimate's filter solves took {per_pass:?} iterations",
            step + 1
        );
        // held rows: the error carried to the end of the mechanics step
        if let Some(level) = carry_level(self.carry, sub.control.level, sub.control.pos) {
            self.solver.set_level(level, prop, comm)?;
            for _ in 0..CARRY_PASSES {
                it += self.filter(prop, comm, true)?.1;
            }
        }
        let (e, p0, p1) = (&self.e[..n], &self.phi_n[..n], &prop.phi[..n]);
        let (ratio, _, _) = sub.ratio(super::squares(comm, n, |i| [e[i], p0[i], p1[i]]));
        Ok((ratio, 1 + it))
    }

    /// One TR-BDF2 step of the current level's length from prop.phi (kept in phi_n, the
    /// stage value in y); returns the operator applications.
    fn tr_bdf2(&mut self, prop: &mut Propagation, q: &Sources, comm: &dyn Comm) -> Result<usize> {
        let n = self.b.len();
        let (tt, tol, step) = (self.solver.theta_tau(), self.solver.tolerance(), self.errors.step);
        let vol = self.solver.vol();
        // phi^n, and stage 1's right-hand side V phi + theta tau (W phi + 2 V Q)
        std::mem::swap(&mut self.phi_n, &mut prop.phi);
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
        self.y[..n].copy_from_slice(&self.phi_n[..n]);
        let it1 = self.solver.solve(prop, &mut self.y, &self.b, comm, 1, step, tol)?;
        // stage 2: V (c1 Y - c2 phi^n) + theta tau V Q, from phi^n + (Y - phi^n) / gamma
        let g2 = GAMMA * (2.0 - GAMMA);
        let (c1, c2) = (1.0 / g2, (1.0 - GAMMA) * (1.0 - GAMMA) / g2);
        let mut x = std::mem::replace(&mut prop.phi, NodeField::filled(Default::default(), [0.0; 3]));
        let vol = self.solver.vol();
        for i in 0..n {
            let (yi, pi, v) = (self.y[i], self.phi_n[i], vol[i]);
            for d in 0..3 {
                self.b[i][d] = v * (c1 * yi[d] - c2 * pi[d]);
                x[i][d] = pi[d] + (yi[d] - pi[d]) / GAMMA;
            }
        }
        for &(i, qi) in q {
            let v = vol[i as usize];
            for d in 0..3 {
                self.b[i as usize][d] += tt * v * qi[d];
            }
        }
        let it2 = self.solver.solve(prop, &mut x, &self.b, comm, 2, step, tol);
        prop.phi = x;
        let it2 = it2?;
        self.last = SolveStats { iterations: [it1, it2] };
        tracing::trace!("implicit step {}: {it1} + {it2} iterations", step + 1);
        Ok(1 + self.solver.applications(it1) + self.solver.applications(it2))
    }
}

impl Stepper for Implicit {
    fn plan(&self) -> &StepPlan {
        &self.plan
    }
    fn last_error(&self) -> Option<f64> {
        self.errors.last_error()
    }
    fn tighten(&mut self, factor: f64) -> bool {
        self.solver.tighten(factor)
    }
    fn set_budget(&mut self, budget: Option<usize>) {
        self.errors.budget = budget;
    }
    fn replayed(&mut self, error: Option<f64>) {
        self.errors.replayed(error)
    }

    fn advance(&mut self, prop: &mut Propagation, q: &Sources, comm: &dyn Comm) -> Result<StepStats> {
        if !self.errors.on() {
            let applications = self.tr_bdf2(prop, q, comm)?;
            self.errors.step += 1;
            self.errors.substeps = (1, 0);
            return Ok(StepStats { applications });
        }
        // a held row's potential changed at the step's start, on any process
        self.carry = comm.max(if prop.held_moved() { 1.0 } else { 0.0 }) > 0.0;
        let mut sub = self.errors.begin(0, 3.0);
        let mut applications = 0;
        while !sub.control.done() {
            if sub.control.level > super::MAX_LEVEL {
                bail!(
                    "{}: implicit: step {} needs TR-BDF2 steps shorter than dt / 2^{} to keep [integrator] accuracy = {:e}; fix: loosen accuracy, or use [model] integrator = \"euler\", or lower dt",
                    self.solver.path(),
                    self.errors.step + 1,
                    super::MAX_LEVEL,
                    self.errors.accuracy
                );
            }
            self.solver.set_level(sub.control.level, prop, comm)?;
            applications += self.tr_bdf2(prop, q, comm)?;
            let (ratio, apps) = self.estimate(prop, comm, &mut sub)?;
            applications += apps;
            self.errors.within_budget(applications)?;
            tracing::trace!(
                "implicit step {} level {} pos {} ratio {ratio:.3e} its {:?}",
                self.errors.step + 1,
                sub.control.level,
                sub.control.pos,
                self.last.iterations
            );
            if !sub.after(ratio) {
                // back to phi_n (prop.phi's buffer is free)
                std::mem::swap(&mut self.phi_n, &mut prop.phi);
            }
        }
        self.solver.set_level(0, prop, comm)?;
        self.errors.step += 1;
        self.errors.end(&sub);
        let (accepted, rejected) = sub.counts();
        tracing::debug!(
            "implicit step {}: {accepted} TR-BDF2 steps, {rejected} rejected, {applications} operator applications",
            self.errors.step
        );
        Ok(StepStats { applications })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_estimate_is_carried_to_the_step_end_no_further_than_the_step_damps() {
        // nothing held, or the last sub-step of the mechanics step: nothing carried
        assert_eq!(carry_level(false, 3, 0), None);
        assert_eq!(carry_level(true, 0, 0), None);
        assert_eq!(carry_level(true, 3, 7), None);
        for level in 1..20u32 {
            // (the sub-steps before the last one)
            for pos in [0, 1, (1u64 << level) / 2, (1u64 << level) - 2]
                .into_iter()
                .filter(|&p| p + 1 < 1 << level)
            {
                let j = carry_level(true, level, pos).unwrap();
                let left = ((1u64 << level) - pos - 1) as f64 / (1u64 << level) as f64;
                let s = 0.5f64.powi(j as i32);
                // within the time left (three passes at theta s each), and the longest such
                assert!(
                    CARRY_PASSES as f64 * THETA * s <= left * (1.0 + 1e-12),
                    "{level} {pos} {j}"
                );
                assert!(
                    j == 0 || CARRY_PASSES as f64 * THETA * 2.0 * s > left,
                    "{level} {pos} {j}"
                );
                // three passes damp no mode more than exp(-left lambda)
                for x in [1e-3, 1.0, 30.0, 1e6] {
                    let passes = (1.0 + THETA * s * x).powi(CARRY_PASSES as i32).recip();
                    assert!(passes >= (-left * x).exp(), "{level} {pos} {x}");
                }
            }
        }
        // after the first sub-step of dt / 8 7/8 dt are left, less than 3 theta dt = 0.879 dt:
        // dt / 2; after the first of dt / 16 15/16 dt: dt
        assert_eq!(carry_level(true, 3, 0), Some(1));
        assert_eq!(carry_level(true, 4, 0), Some(0));
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
