//! Time integrators of the propagation (docs/model.md section 3): each advances the potential over
//! one mechanics step dt of the semi-discrete system d(phi)/dt = L phi + Q, with Q held
//! constant over the step and phi = 0 on the Dirichlet set. A `Stepper` owns its stability
//! limits and its choice of substeps or stages; the simulation only calls `advance`.
//!
//! `euler` (the paper's substeps), `rkl2` (Runge-Kutta-Legendre super-time-stepping),
//! `implicit` (TR-BDF2 with preconditioned conjugate gradients) and the `auto` choice between
//! them (`choose`); docs/integrators.md gives their equations.

pub mod choose;
pub mod euler;
pub mod implicit;
pub mod rkl2;
pub mod solver;
pub mod stability;

use crate::config::integrator::Kind;
use crate::distribute::comm::Comm;
use crate::linalg::V3;
use crate::propagate::{Propagation, Sources};
use anyhow::Result;

pub use euler::Euler;
pub use implicit::Implicit;
pub use rkl2::Rkl2;

/// Most substeps (or stages) of the propagation per mechanics step.
pub const MAX_SUBSTEPS: usize = 1_000_000;

/// What a stepper chose for the step size dt, for the summary, `eprop check` and the output.
#[derive(Clone, Debug, PartialEq)]
pub struct StepPlan {
    /// The integrator (its name as the scenario spells it: `Kind::name`).
    pub integrator: Kind,
    /// The mechanics step the plan is for.
    pub dt: f64,
    /// A stable forward Euler substep for dt: `euler`'s substep, and for the other
    /// integrators the one euler would take (so that code timing or checking Euler substeps
    /// works whatever the integrator).
    pub h: f64,
    /// The integrator's own step: the Euler substep, the RKL2 super-step, or dt (implicit).
    pub step: f64,
    /// The largest stable forward Euler substep of this operator (2 / spectral radius).
    pub h_bound: f64,
    /// Substeps (or stages, or estimated operator applications) per mechanics step.
    pub per_step: usize,
    /// Estimated work per mechanics step, in forward Euler substeps.
    pub cost: f64,
    /// Why this integrator and this count, in a few words.
    pub why: String,
}

impl StepPlan {
    /// The count per step with its unit: "4 substeps", "14 stages", "about 65 operator
    /// applications".
    pub fn per_step_phrase(&self) -> String {
        match self.integrator {
            Kind::Euler => format!("{} substeps", self.per_step),
            Kind::Rkl2 => format!("{} stages", self.per_step),
            _ => format!("about {} operator applications", self.per_step),
        }
    }
}

/// What one `advance` did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepStats {
    /// Operator applications (each one halo exchange).
    pub applications: usize,
}

/// An integrator of d(phi)/dt = L phi + Q over one mechanics step.
pub trait Stepper {
    fn plan(&self) -> &StepPlan;
    /// Advances `prop.phi` over the plan's dt with the constant sources `q`.
    fn advance(&mut self, prop: &mut Propagation, q: &Sources, comm: &dyn Comm) -> Result<StepStats>;
    /// The estimated relative error ||e|| / ||phi|| the last step added (error-controlled
    /// integrators; None for the others).
    fn last_error(&self) -> Option<f64> {
        None
    }
    /// A step was replayed from the automatic choice's trial (`choose::Replay`): counts it,
    /// with its estimated error.
    fn replayed(&mut self, _error: Option<f64>) {}
    /// A run to equilibrium found max |v| small but the potential's steady residual above its
    /// tolerance: an integrator whose fixed point is the steady state only to its solves'
    /// tolerance (implicit) solves `factor` times tighter from now on (to a floor); returns
    /// whether it did. Euler's and rkl2's fixed points are the steady state itself.
    fn tighten(&mut self, _factor: f64) -> bool {
        false
    }
    /// The most operator applications a step may take before it stops with `OverBudget`
    /// (None: no limit). Error-controlled integrators check it after each sub-step; the others
    /// ignore it (`auto` measures only the former).
    fn set_budget(&mut self, _budget: Option<usize>) {}
}

/// forward Euler's substep for the mechanics step dt on an operator whose bound is h_bound:
/// dt over ceil(dt / (SAFETY h_bound)) substeps.
pub(crate) fn euler_substep(dt: f64, h_bound: f64) -> f64 {
    if h_bound.is_finite() {
        dt / (dt / (euler::SAFETY * h_bound)).ceil().max(1.0)
    } else {
        dt
    }
}

/// Sums of squares over the owned rows `0..n` of every process, exact (the same bits on any
/// number of processes and threads): K values per row.
pub fn squares<const K: usize, F>(comm: &dyn Comm, n: usize, rows: F) -> [f64; K]
where
    F: Fn(usize) -> [V3; K] + Sync,
{
    crate::distribute::comm::reproducible_sums_par(comm, n, |i| {
        rows(i).map(|v| v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    })
}

/// The most levels (halvings of the mechanics step) the error control may take: a step of
/// dt / 2^MAX_LEVEL that is still not accurate enough is an error that names the fixes. The
/// layer a tool's contact starts is as fast as the cells it touches relax: the head atlas under
/// a sphere (dt = 0.03 s) needed dt / 2^18, so 16 levels refused it (docs/integrators.md; since
/// implicit carries its estimate to the step's end there, `implicit::carry_level`, dt / 2^8).
pub(crate) const MAX_LEVEL: u32 = 30;

/// A step that changes phi by so little against its size is accurate whatever its estimate:
/// relative errors below this (roundoff of the norms) are taken as zero.
pub(crate) const ROUNDOFF: f64 = 1e-13;

/// Error control over the levels of one mechanics step: sub-steps of dt / 2^level, the level
/// raised after a rejected sub-step (by as many halvings as the estimate asks for, order `p`
/// of the estimate in the sub-step) and lowered after a sub-step well inside the accuracy when
/// the position allows the longer sub-step. The tolerance is per sub-step (error per step, not
/// per unit step: the errors that force short sub-steps are those of an initial layer, which
/// decay rather than add up). Every decision comes from globally reduced norms, so every
/// process takes the same sub-steps; a mechanics step starts at `start` whatever the last one
/// did, so a restarted run continues bit for bit.
///
/// A doubled sub-step multiplies the estimate by 2^p where the error is asymptotic; in an
/// initial layer it grows less (by 3-5 instead of 8 for TR-BDF2 on the 70^3 box). The growth
/// the last lowering brought within this mechanics step (the ratio of the next sub-step to the
/// one before it, between 2 and 2^p) predicts the next one.
#[derive(Clone, Copy, Debug)]
pub struct Control {
    /// Current level and the position in the mechanics step in units of dt / 2^level.
    pub level: u32,
    pub pos: u64,
    /// Error exponent: the estimate per sub-step scales like (dt / 2^level)^p.
    p: f64,
    /// The factor a doubled sub-step is expected to multiply the estimate by
    growth: f64,
    /// The ratio of the sub-step before the last lowering, until the next sub-step's is known
    lowered_from: Option<f64>,
}

impl Control {
    pub fn new(start: u32, p: f64) -> Control {
        let mut c = Control {
            level: start,
            pos: 0,
            p,
            growth: 0.0,
            lowered_from: None,
        };
        c.growth = c.asymptotic();
        c
    }
    /// The factor a doubled sub-step multiplies the estimate by where the error is asymptotic.
    fn asymptotic(&self) -> f64 {
        2f64.powf(self.p.max(0.5))
    }
    /// The sub-step's share of dt.
    pub fn fraction(&self) -> f64 {
        0.5f64.powi(self.level as i32)
    }
    pub fn done(&self) -> bool {
        self.pos >= 1u64 << self.level
    }
    /// After a sub-step whose error over its tolerance is `ratio` (<= 1: accepted, when the
    /// caller accepted it): whether it was accepted; the next level is set.
    pub fn after(&mut self, ratio: f64) -> bool {
        // the estimate scales like (length)^p: one halving divides the ratio by 2^p
        let q = self.p.max(0.5);
        // what the last lowering did to the estimate (a rejection right after it counts too)
        if let Some(before) = self.lowered_from.take() {
            self.growth = if before > 0.0 && ratio.is_finite() {
                (ratio / before).clamp(2.0, self.asymptotic())
            } else {
                self.asymptotic()
            };
        }
        if !(ratio <= 1.0) {
            let halvings = if ratio.is_finite() {
                ((ratio / 0.8).log2() / q).ceil().clamp(1.0, 8.0) as u32
            } else {
                4
            };
            self.level += halvings;
            self.pos <<= halvings;
            return false;
        }
        self.pos += 1;
        // one level up when the longer sub-step would still be inside the accuracy (with a
        // margin) and starts here
        if self.level > 0 && ratio * self.growth < 0.5 && self.pos.is_multiple_of(2) && !self.done() {
            self.level -= 1;
            self.pos /= 2;
            self.lowered_from = Some(ratio);
        }
        true
    }
}

/// What an error-controlled stepper (rkl2, implicit) keeps of its control between mechanics
/// steps: the accuracy, the mechanics steps taken (for messages) and what the last one did.
#[derive(Clone, Debug)]
pub struct ErrorState {
    /// The relative error per mechanics step (infinite: no control, no estimate).
    pub accuracy: f64,
    /// The share of the accuracy the estimate is held to (1: all of it).
    share: f64,
    /// Mechanics steps taken.
    pub step: u64,
    /// Sub-steps of the last mechanics step: (accepted, rejected).
    pub substeps: (usize, usize),
    /// The estimated relative error of the last mechanics step (sum over its sub-steps).
    pub error: f64,
    /// The most operator applications a mechanics step may take (`auto`'s trial: past it the
    /// candidate cannot win, and the step stops with `OverBudget`); None: no limit.
    pub budget: Option<usize>,
}

/// A step stopped once its operator applications passed the stepper's budget
/// (`Stepper::set_budget`): `applications` were taken when it stopped.
#[derive(Debug, Clone, Copy)]
pub struct OverBudget {
    pub applications: usize,
}

impl std::fmt::Display for OverBudget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the step stopped after {} operator applications, past its budget",
            self.applications
        )
    }
}

impl std::error::Error for OverBudget {}

impl ErrorState {
    /// No error control yet (`accuracy` infinite); the estimate is to be held to `share` of
    /// the accuracy once it is set.
    pub fn new(share: f64) -> ErrorState {
        ErrorState {
            accuracy: f64::INFINITY,
            share,
            step: 0,
            substeps: (0, 0),
            error: 0.0,
            budget: None,
        }
    }

    /// Err(`OverBudget`) once a step's `applications` so far pass the budget (checked after
    /// each sub-step, the same on every process: the counts are).
    pub fn within_budget(&self, applications: usize) -> Result<()> {
        match self.budget {
            Some(b) if applications > b => Err(OverBudget { applications }.into()),
            _ => Ok(()),
        }
    }

    /// Whether the error is controlled (a finite accuracy).
    pub fn on(&self) -> bool {
        self.accuracy.is_finite()
    }

    /// The last step's estimated error where the error is controlled (`Stepper::last_error`).
    pub fn last_error(&self) -> Option<f64> {
        self.on().then_some(self.error)
    }

    /// A step replayed with its estimated error (`Stepper::replayed`).
    pub fn replayed(&mut self, error: Option<f64>) {
        self.step += 1;
        self.error = error.unwrap_or(0.0);
    }

    /// The sub-steps of a mechanics step from `level` (sub-steps of dt / 2^level), the
    /// estimate of order `p` in the sub-step.
    pub fn begin(&self, level: u32, p: f64) -> SubSteps {
        SubSteps {
            control: Control::new(level, p),
            floor: 0.0,
            share: self.share,
            accuracy: self.accuracy,
            accepted: 0,
            rejected: 0,
            error: 0.0,
        }
    }

    /// Keeps what the mechanics step's sub-steps did.
    pub fn end(&mut self, s: &SubSteps) {
        self.substeps = (s.accepted, s.rejected);
        self.error = s.error;
    }
}

/// One mechanics step's sub-steps under error control (`ErrorState::begin`): the levels
/// (`Control`), the floor under the norm of phi and what was accepted.
pub struct SubSteps {
    pub control: Control,
    /// Set by the first attempt: from phi = 0 the first sub-steps see a tiny phi, against which
    /// nothing short is accurate.
    floor: f64,
    /// The estimate is held to share times accuracy (`ErrorState`).
    share: f64,
    accuracy: f64,
    accepted: usize,
    rejected: usize,
    /// The sum of the accepted sub-steps' estimated errors.
    error: f64,
}

impl SubSteps {
    /// A sub-step's error over its tolerance, from exact sums of squares over every process
    /// (`squares`) of the error estimate and of phi at the sub-step's start and end:
    /// ||e|| / (share accuracy max(||phi_start||, ||phi_end||, floor)), 0 where the error is at
    /// roundoff. Returns the ratio, ||e|| and the scale it was measured against.
    pub fn ratio(&mut self, [ee, s0, s1]: [f64; 3]) -> (f64, f64, f64) {
        let scale = s0.max(s1).sqrt().max(self.floor);
        if self.floor == 0.0 {
            self.floor = scale;
        }
        let err = ee.sqrt();
        let ratio = if err <= ROUNDOFF * scale {
            0.0
        } else {
            err / (self.share * self.accuracy * scale)
        };
        (ratio, err, scale)
    }

    /// After a sub-step of error ratio `ratio`: whether it is accepted (else the caller takes
    /// phi back to the sub-step's start); the control moves on.
    pub fn after(&mut self, ratio: f64) -> bool {
        let added = ratio * self.share * self.accuracy;
        let accepted = self.control.after(ratio);
        if accepted {
            self.accepted += 1;
            self.error += added;
        } else {
            self.rejected += 1;
        }
        accepted
    }

    /// Sub-steps accepted and rejected so far.
    pub fn counts(&self) -> (usize, usize) {
        (self.accepted, self.rejected)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs a control to the end of a step with the error ratio `ratio(level, pos)`; returns
    /// the accepted (level, pos) in order.
    fn walk(start: u32, ratio: impl Fn(u32, u64) -> f64) -> Vec<(u32, u64)> {
        let mut c = Control::new(start, 3.0);
        let mut taken = vec![];
        let mut covered = 0.0;
        for _ in 0..10_000 {
            if c.done() {
                break;
            }
            let (l, p, f) = (c.level, c.pos, c.fraction());
            if c.after(ratio(l, p)) {
                taken.push((l, p));
                covered += f;
            }
        }
        assert!(c.done() && (covered - 1.0f64).abs() < 1e-12, "{taken:?}");
        taken
    }

    #[test]
    fn the_control_covers_the_step_and_halves_as_the_estimate_asks() {
        // accurate everywhere: one step of dt
        assert_eq!(walk(0, |_, _| 0.1), vec![(0, 0)]);
        // the error of a sub-step of dt / 2^l is 1000 / 8^l: level 4 is the first below 0.8
        // (1000 / 4096); a rejection at level 0 asks for ceil(log2(1250) / 3) = 4 halvings
        let t = walk(0, |l, _| 1000.0 / 8f64.powi(l as i32));
        assert_eq!(t[0], (4, 0));
        // once well inside (1000 / 8^4 * 8 = 1.95 > 0.5), it stays at level 4
        assert!(t.iter().all(|&(l, _)| l == 4) && t.len() == 16, "{t:?}");
        // an initial layer: only the first sixteenth is hard; the control climbs back up on
        // aligned positions
        let t = walk(0, |l, p| {
            let start = p as f64 * 0.5f64.powi(l as i32);
            if start < 1.0 / 16.0 {
                1000.0 / 8f64.powi(l as i32)
            } else {
                1e-3
            }
        });
        assert!(t.len() < 12 && t.last().unwrap().0 < 4, "{t:?}");
        // an estimate that triples, not octuples, per doubling (an initial layer's): after one
        // lowering (5 -> 4, 0.041 -> 0.123) the observed growth 3 allows the next (0.37 at
        // level 3); the asymptotic factor 8 would keep level 4 for the rest (17 sub-steps)
        let t = walk(5, |l, _| 10.0 / 3f64.powi(l as i32));
        assert_eq!(t.len(), 10, "{t:?}");
        assert_eq!(t.last().unwrap().0, 3, "{t:?}");
        // a ratio that is not finite (a blown-up step) halves four times
        let mut c = Control::new(0, 3.0);
        assert!(!c.after(f64::NAN) && c.level == 4 && c.pos == 0);
    }
}
