//! Time integrators of the propagation (MODEL.md section 3): each advances the potential over
//! one mechanics step dt of the semi-discrete system d(phi)/dt = L phi + Q, with Q held
//! constant over the step and phi = 0 on the Dirichlet set. A `Stepper` owns its stability
//! limits and its choice of substeps or stages; the simulation only calls `advance`.

pub mod euler;
pub mod stability;

use crate::comm::Comm;
use crate::propagation::{Propagation, Sources};
use anyhow::Result;

pub use euler::Euler;

/// What a stepper chose for the step size dt, for the summary, `eprop check` and the output.
#[derive(Clone, Debug, PartialEq)]
pub struct StepPlan {
    /// The integrator's name as the scenario spells it.
    pub integrator: &'static str,
    /// The mechanics step the plan is for.
    pub dt: f64,
    /// The (sub)step size of one operator application.
    pub h: f64,
    /// The largest stable forward Euler substep of this operator (2 / spectral radius).
    pub h_bound: f64,
    /// Substeps (or stages) per mechanics step.
    pub per_step: usize,
    /// Why this integrator and this count, in a few words.
    pub why: String,
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
}
