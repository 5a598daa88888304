//! Runge-Kutta-Legendre super-time-stepping, second order (RKL2; Meyer, Balsara and Aslam,
//! J. Comput. Phys. 257, 2014). One super-step of size tau takes s stages, each one operator
//! application (one halo exchange, no reduction), and is stable for
//! tau <= h_bound (s^2 + s - 2) / 4: the stage count grows like sqrt(tau / h_bound), not like
//! tau / h_bound as forward Euler's substeps do.
//!
//! With M(Y) = L Y + Q (Q held over the step):
//!   Y0 = phi^n,  Y1 = Y0 + mu~1 tau M(Y0),
//!   Yj = mu_j Y(j-1) + nu_j Y(j-2) + (1 - mu_j - nu_j) Y0 + mu~j tau M(Y(j-1)) + gamma~j tau M(Y0),
//!   phi^(n+1) = Ys,
//! b_j = (j^2 + j - 2) / (2 j (j + 1)) (b_0 = b_1 = 1/3), a_j = 1 - b_j, w1 = 4 / (s^2 + s - 2),
//! mu~1 = b_1 w1, mu_j = (2j - 1)/j b_j/b_(j-1), nu_j = -(j - 1)/j b_j/b_(j-2), mu~j = mu_j w1,
//! gamma~j = -a_(j-1) mu~j. A steady state M(phi) = 0 is a fixed point of every stage.

use super::euler::SAFETY;
use super::{ErrorState, StepPlan, StepStats, Stepper};
use crate::distribute::comm::Comm;
use crate::distribute::field::NodeField;
use crate::linalg::V3;
use crate::propagate::{Propagation, Sources};
use anyhow::{bail, Result};
use eprop_partition::Layout;

/// Cost of one RKL2 stage in forward Euler substeps: the same operator sweep, plus three
/// more vectors read (Y(j-2), Y0, M(Y0)). Measured (examples/sweeps.rs) on a 271k-node liver.
pub(crate) const STAGE_COST: f64 = 1.3;

/// Coefficients of one stage j >= 2: (mu, nu, mu~, gamma~).
type Stage = (f64, f64, f64, f64);

/// Stage coefficients of an s-stage RKL2 super-step: mu~1 and the stages 2..=s.
pub fn coefficients(s: usize) -> (f64, Vec<Stage>) {
    assert!(s >= 2, "RKL2 needs at least two stages");
    let b = |j: usize| -> f64 {
        if j < 2 {
            1.0 / 3.0
        } else {
            let j = j as f64;
            (j * j + j - 2.0) / (2.0 * j * (j + 1.0))
        }
    };
    let a = |j: usize| 1.0 - b(j);
    let sf = s as f64;
    let w1 = 4.0 / (sf * sf + sf - 2.0);
    let stages = (2..=s)
        .map(|j| {
            let jf = j as f64;
            let mu = (2.0 * jf - 1.0) / jf * b(j) / b(j - 1);
            let nu = -(jf - 1.0) / jf * b(j) / b(j - 2);
            let mut_ = mu * w1;
            (mu, nu, mut_, -a(j - 1) * mut_)
        })
        .collect();
    (b(1) * w1, stages)
}

/// The stability polynomial R_s(z) of an s-stage super-step (amplification of a mode with
/// tau lambda = z), evaluated by running the stages on the scalar problem y' = lambda y.
pub fn amplification(s: usize, z: f64) -> f64 {
    let (mt1, stages) = coefficients(s);
    let y0 = 1.0;
    let (mut y2, mut y1) = (y0, y0 + mt1 * z * y0);
    for &(mu, nu, mt, gt) in &stages {
        let y = mu * y1 + nu * y2 + (1.0 - mu - nu) * y0 + mt * z * y1 + gt * z * y0;
        (y2, y1) = (y1, y);
    }
    y1
}

/// The fewest stages whose super-step `tau` is stable with the safety margin on an operator
/// whose forward Euler bound is `h_bound`: SAFETY h_bound (s^2 + s - 2) / 4 >= tau.
/// A count past `MAX_COUNT` (or a ratio that is not finite) is `usize::MAX`: the callers
/// refuse it by its size (`crate::guard::limits`), and no arithmetic on it wraps.
pub(crate) fn stages_for(tau: f64, h_bound: f64) -> usize {
    if !h_bound.is_finite() {
        return 2;
    }
    let r = tau / (SAFETY * h_bound); // s^2 + s - 2 >= 4 r
    let s0 = ((-1.0 + (9.0 + 16.0 * r).sqrt()) / 2.0).ceil().max(2.0);
    if !(s0 <= MAX_COUNT) {
        return usize::MAX;
    }
    // in floating point: s^2 of a count near MAX_COUNT does not fit in 64 bits
    let mut s = s0;
    while s * s + s - 2.0 < 4.0 * r {
        s += 1.0;
    }
    s as usize
}

/// rkl2 holds its step-doubling estimate to this share of the accuracy: the estimate assumes
/// the asymptotic regime, which the modes RKL2 damps little (tau lambda of -1 to -50) are not
/// in; at the full accuracy a sphere pressing the SOFA liver (scenarios/organs/liver_indent.toml)
/// left u 2.0e-2 and the force 3.2e-2 of the peak from euler's, at a tenth of it 1.9e-4 and
/// 8.4e-4.
pub(crate) const DOUBLING_SHARE: f64 = 0.1;

/// Stage and super-step counts above this are saturated to `usize::MAX` (far above any limit).
pub(crate) const MAX_COUNT: f64 = 1e15;

pub struct Rkl2 {
    plan: StepPlan,
    /// super-steps per mechanics step, stages per super-step
    supersteps: usize,
    stages: usize,
    mt1: f64,
    coef: Vec<Stage>,
    y0: NodeField<V3>,
    m0: NodeField<V3>,
    ya: NodeField<V3>,
    yb: NodeField<V3>,
    /// The error control (an infinite accuracy: `supersteps` super-steps of the stability
    /// bound's stages, no estimate), the Euler bound and the first level tried.
    errors: ErrorState,
    h_bound: f64,
    start_level: u32,
    /// Owned values at the start of a super-step and of its single-step result (the step
    /// doubling estimate).
    start: Vec<V3>,
    full: Vec<V3>,
    path: String,
}

impl Rkl2 {
    /// `supersteps` super-steps per mechanics step dt, each with the fewest stable stages on
    /// an operator whose Euler bound is `h_bound`; more than `max_stages` stages per step is
    /// an error that names the fixes. `path` (the scenario) goes into errors.
    pub fn new(
        h_bound: f64,
        dt: f64,
        supersteps: usize,
        max_stages: usize,
        layout: Layout,
        path: &str,
        why: String,
    ) -> Result<Rkl2> {
        let supersteps = supersteps.max(1);
        let tau = dt / supersteps as f64;
        let stages = stages_for(tau, h_bound);
        let per_step = stages.saturating_mul(supersteps);
        if per_step > max_stages {
            let count = if per_step == usize::MAX {
                format!("more than {MAX_COUNT:e}")
            } else {
                per_step.to_string()
            };
            bail!(
                "{path}: rkl2 needs {count} stages per step on this mesh (dt = {dt:.4e}, stable Euler substep {h_bound:.4e}), more than [integrator] max_stages = {max_stages}; \
                 fix: use [model] integrator = \"implicit\", or repair the cells `eprop check` names as the stiffest, or lower dt, or raise max_stages"
            );
        }
        let (mt1, coef) = coefficients(stages);
        let z = || NodeField::filled(layout, [0.0; 3]);
        let start_level = (supersteps as f64).log2().ceil() as u32;
        Ok(Rkl2 {
            errors: ErrorState::new(DOUBLING_SHARE),
            h_bound,
            start_level,
            start: Vec::new(),
            full: Vec::new(),
            path: path.to_string(),
            plan: StepPlan {
                integrator: super::Kind::Rkl2,
                dt,
                h: super::euler_substep(dt, h_bound),
                step: tau,
                h_bound,
                per_step,
                cost: STAGE_COST * per_step as f64,
                why,
            },
            supersteps,
            stages,
            mt1,
            coef,
            y0: z(),
            m0: z(),
            ya: z(),
            yb: z(),
        })
    }

    /// Numbers the next step 1 again (after the automatic choice's trial steps).
    pub fn restart_count(&mut self) {
        self.errors.step = 0;
    }

    /// Turns the error control on: super-steps of dt / 2^k (from the level of the super-step
    /// count given to `new`), as many as `accuracy` (the relative error per mechanics step)
    /// needs, each checked by step doubling (`Control`).
    pub fn set_accuracy(&mut self, accuracy: f64) {
        self.errors.accuracy = accuracy;
        if accuracy.is_finite() {
            let n = self.y0.layout().n_owned;
            self.start = vec![[0.0; 3]; n];
            self.full = vec![[0.0; 3]; n];
        }
    }

    /// Replaces the plan's reason (the automatic choice says why it chose rkl2).
    pub fn set_why(&mut self, why: String) {
        self.plan.why = why;
    }

    /// Uses `stages` stages per super-step from here on.
    fn set_stages(&mut self, stages: usize) {
        if stages != self.stages {
            (self.mt1, self.coef) = coefficients(stages);
            self.stages = stages;
        }
    }

    /// One mechanics step under error control: each super-step of tau is taken once with
    /// the stages tau needs and again as two halves; the halves are kept, and
    /// |halves - single| / 3 (Richardson, second order) is its error, against
    /// accuracy max(||phi_start||, ||phi_end||, floor), every norm an exact sum over every
    /// process. Returns the operator applications.
    fn controlled(&mut self, prop: &mut Propagation, q: &Sources, comm: &dyn Comm) -> Result<usize> {
        let n = prop.layout().n_owned;
        let mut sub = self.errors.begin(self.start_level, 3.0);
        let mut apps = 0usize;
        let (step, accuracy) = (self.errors.step, self.errors.accuracy);
        while !sub.control.done() {
            let c = &sub.control;
            if c.level > super::MAX_LEVEL {
                bail!(
                    "{}: rkl2: step {} needs super-steps shorter than dt / 2^{} to keep [integrator] accuracy = {:e}; fix: loosen accuracy, or use [model] integrator = \"implicit\", or lower dt",
                    self.path,
                    step + 1,
                    super::MAX_LEVEL,
                    accuracy
                );
            }
            let tau = self.plan.dt * c.fraction();
            let (one, half) = (stages_for(tau, self.h_bound), stages_for(tau / 2.0, self.h_bound));
            if one == usize::MAX || apps.saturating_add(one + 2 * half) > super::MAX_SUBSTEPS {
                bail!(
                    "{}: rkl2: step {} needs more than {} stages to keep [integrator] accuracy = {:e}; fix: use [model] integrator = \"implicit\", or loosen accuracy, or lower dt",
                    self.path,
                    step + 1,
                    super::MAX_SUBSTEPS,
                    accuracy
                );
            }
            self.start.copy_from_slice(&prop.phi[..n]);
            self.set_stages(one);
            self.superstep(prop, q, tau);
            self.full.copy_from_slice(&prop.phi[..n]);
            prop.phi[..n].copy_from_slice(&self.start);
            self.set_stages(half);
            self.superstep(prop, q, tau / 2.0);
            self.superstep(prop, q, tau / 2.0);
            apps += one + 2 * half;
            self.errors.within_budget(apps)?;
            let (p0, p1, f) = (&self.start[..], &prop.phi[..n], &self.full[..]);
            let (ratio, err, scale) = sub.ratio(super::squares(comm, n, |i| {
                [std::array::from_fn(|d| (p1[i][d] - f[i][d]) / 3.0), p0[i], p1[i]]
            }));
            tracing::trace!(
                "rkl2 step {} level {} pos {} stages {one}/{half} err {err:.3e} scale {scale:.3e} ratio {ratio:.3e}",
                step + 1,
                sub.control.level,
                sub.control.pos
            );
            if !sub.after(ratio) {
                prop.phi[..n].copy_from_slice(&self.start);
            }
        }
        self.errors.end(&sub);
        let (accepted, rejected) = sub.counts();
        tracing::debug!(
            "rkl2 step {}: {accepted} super-steps (doubled), {rejected} rejected",
            step + 1
        );
        Ok(apps)
    }

    /// Stages per super-step and super-steps per mechanics step.
    pub fn shape(&self) -> (usize, usize) {
        (self.stages, self.supersteps)
    }

    fn superstep(&mut self, prop: &mut Propagation, q: &Sources, tau: f64) {
        let Rkl2 {
            mt1,
            coef,
            y0,
            m0,
            ya,
            yb,
            ..
        } = self;
        std::mem::swap(y0, &mut prop.phi);
        // M(Y0) = L Y0 + Q; Y1 = Y0 + mu~1 tau M(Y0); Y(j-2) starts as Y0
        prop.update_to(y0, m0, |_, _, l, m| *m = l);
        for &(i, qi) in q {
            let m = &mut m0[i as usize];
            for d in 0..3 {
                m[d] += qi[d];
            }
        }
        let n = prop.layout().n_owned;
        let c1 = *mt1 * tau;
        for i in 0..n {
            let (y, m) = (y0[i], m0[i]);
            ya[i] = [y[0] + c1 * m[0], y[1] + c1 * m[1], y[2] + c1 * m[2]];
            yb[i] = y;
        }
        for &(mu, nu, mt, gt) in coef.iter() {
            let (a0, at, gt) = (1.0 - mu - nu, mt * tau, gt * tau);
            let (y0r, m0r) = (&**y0, &**m0);
            // yb holds Y(j-2) and becomes Yj; ya (Y(j-1)) is the operator's input
            prop.update_to(ya, yb, |i, x, l, y| {
                let (z, m) = (y0r[i], m0r[i]);
                for d in 0..3 {
                    y[d] = mu * x[d] + nu * y[d] + a0 * z[d] + at * l[d] + gt * m[d];
                }
            });
            for &(i, qi) in q {
                let y = &mut yb[i as usize];
                for d in 0..3 {
                    y[d] += at * qi[d];
                }
            }
            std::mem::swap(ya, yb);
        }
        std::mem::swap(ya, &mut prop.phi);
    }
}

impl Stepper for Rkl2 {
    fn plan(&self) -> &StepPlan {
        &self.plan
    }
    fn last_error(&self) -> Option<f64> {
        self.errors.last_error()
    }
    fn set_budget(&mut self, budget: Option<usize>) {
        self.errors.budget = budget;
    }
    fn replayed(&mut self, error: Option<f64>) {
        self.errors.replayed(error)
    }
    fn advance(&mut self, prop: &mut Propagation, q: &Sources, comm: &dyn Comm) -> Result<StepStats> {
        if self.errors.on() {
            let applications = self.controlled(prop, q, comm)?;
            self.errors.step += 1;
            return Ok(StepStats { applications });
        }
        let tau = self.plan.dt / self.supersteps as f64;
        for _ in 0..self.supersteps {
            self.superstep(prop, q, tau);
        }
        self.errors.step += 1;
        Ok(StepStats {
            applications: self.plan.per_step,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stability_polynomial_is_second_order_and_bounded_on_the_interval() {
        for s in [2usize, 3, 4, 7, 16, 45, 121, 300] {
            // second order: R(z) - (1 + z + z^2/2) = O(z^3)
            for z in [-1e-2f64, -2e-3] {
                let err = amplification(s, z) - (1.0 + z + z * z / 2.0);
                assert!(err.abs() < 2.0 * z.abs().powi(3), "s = {s}, z = {z}: {err:e}");
            }
            // |R| <= 1 on [-SAFETY (s^2 + s - 2) / 2, 0], the interval `stages_for` keeps to,
            // and strictly below 1 past the first modes: stiff modes are damped
            let edge = SAFETY * ((s * s + s - 2) as f64) / 2.0;
            for k in 1..=2000 {
                let z = -edge * k as f64 / 2000.0;
                let r = amplification(s, z);
                assert!(r.abs() <= 1.0, "s = {s}, z = {z}: R = {r}");
                if z < -1.0 {
                    assert!(r.abs() < 1.0 - 1e-3, "s = {s}, z = {z}: R = {r}");
                }
            }
            // past the interval the polynomial grows: the bound is not loose
            let past = -((s * s + s - 2) as f64) / 2.0 * 1.2;
            assert!(amplification(s, past).abs() > 1.0, "s = {s}");
        }
    }

    #[test]
    fn stages_are_the_fewest_stable_ones() {
        for r in [0.5, 1.0, 3.3, 10.0, 528.0, 3665.0, 21001.0] {
            let s = stages_for(r * SAFETY, 1.0);
            assert!(((s * s + s - 2) as f64) >= 4.0 * r && s >= 2);
            if s > 2 {
                let t = s - 1;
                assert!(((t * t + t - 2) as f64) < 4.0 * r, "{r}: {s}");
            }
        }
        // stages grow like sqrt(dt / h): 21001 Euler substeps need 290 stages
        assert_eq!(stages_for(21001.0 * SAFETY, 1.0), 290);
        assert_eq!(stages_for(1.0, f64::INFINITY), 2);
    }
}
