//! Time integrators of the propagation (MODEL.md section 3): each advances the potential over
//! one mechanics step dt of the semi-discrete system d(phi)/dt = L phi + Q, with Q held
//! constant over the step and phi = 0 on the Dirichlet set. A `Stepper` owns its stability
//! limits and its choice of substeps or stages; the simulation only calls `advance`.
//!
//! `euler` (the paper's substeps), `rkl2` (Runge-Kutta-Legendre super-time-stepping),
//! `implicit` (TR-BDF2 with preconditioned conjugate gradients) and the `auto` choice between
//! them (`choose`); docs/integrators.md gives their equations.

#[cfg(eprop_hypre)]
pub mod amg;
pub mod choose;
pub mod euler;
pub mod implicit;
pub mod multigrid;
pub mod rkl2;
pub mod stability;
pub mod stiffness;

use crate::discretize::operator::V3;
use crate::distribute::comm::Comm;
use crate::propagate::{Propagation, Sources};
use anyhow::Result;
use serde::{Deserialize, Serialize};

pub use euler::Euler;
pub use implicit::Implicit;
pub use rkl2::Rkl2;

/// What a stepper chose for the step size dt, for the summary, `eprop check` and the output.
#[derive(Clone, Debug, PartialEq)]
pub struct StepPlan {
    /// The integrator's name as the scenario spells it.
    pub integrator: &'static str,
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
            "euler" => format!("{} substeps", self.per_step),
            "rkl2" => format!("{} stages", self.per_step),
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
}

/// `[model] integrator`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    #[default]
    Auto,
    Euler,
    Rkl2,
    Implicit,
}

/// Every value of `[model] integrator`, as the scenario spells it.
pub const KINDS: [(&str, Kind); 4] = [
    ("auto", Kind::Auto),
    ("euler", Kind::Euler),
    ("rkl2", Kind::Rkl2),
    ("implicit", Kind::Implicit),
];

impl Kind {
    pub fn name(self) -> &'static str {
        KINDS.iter().find(|k| k.1 == self).map(|k| k.0).unwrap_or("auto")
    }
}

/// The preconditioner of the implicit solves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preconditioner {
    /// Smoothed-aggregation multigrid (`multigrid`): one V-cycle per iteration; each
    /// process's hierarchy is its own, so results agree across process counts to the solver
    /// tolerance, not bitwise.
    #[default]
    Multigrid,
    /// Diagonal: deterministic, the same bits on any number of processes.
    Jacobi,
    /// hypre BoomerAMG (algebraic multigrid): fewer iterations; agrees across process counts
    /// to the solver tolerance, not bitwise.
    Amg,
}

pub const PRECONDITIONERS: [(&str, Preconditioner); 3] = [
    ("multigrid", Preconditioner::Multigrid),
    ("jacobi", Preconditioner::Jacobi),
    ("amg", Preconditioner::Amg),
];

impl Preconditioner {
    pub fn name(self) -> &'static str {
        PRECONDITIONERS
            .iter()
            .find(|k| k.1 == self)
            .map(|k| k.0)
            .unwrap_or("multigrid")
    }
}

/// The integrator of a scenario with its settings, resolved (`[model] integrator` and the
/// `[integrator]` section, both checked while the scenario is parsed).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    pub kind: Kind,
    pub tolerance: f64,
    pub max_iterations: usize,
    pub max_stages: usize,
    pub preconditioner: Preconditioner,
}

pub const DEFAULT_TOLERANCE: f64 = 1e-8;
pub const DEFAULT_MAX_ITERATIONS: usize = 2000;
pub const DEFAULT_MAX_STAGES: usize = 4096;

impl Default for Settings {
    fn default() -> Self {
        Settings {
            kind: Kind::Auto,
            tolerance: DEFAULT_TOLERANCE,
            max_iterations: DEFAULT_MAX_ITERATIONS,
            max_stages: DEFAULT_MAX_STAGES,
            preconditioner: Preconditioner::Multigrid,
        }
    }
}

/// forward Euler's substep for the mechanics step dt on an operator whose bound is h_bound:
/// dt over ceil(dt / (SAFETY h_bound)) substeps.
pub fn euler_substep(dt: f64, h_bound: f64) -> f64 {
    if h_bound.is_finite() {
        dt / (dt / (euler::SAFETY * h_bound)).ceil().max(1.0)
    } else {
        dt
    }
}

/// A preconditioner M ~ A^-1 of the implicit solves, applied to the owned rows.
pub trait Precond: Send {
    /// z = M r on the owned rows (three components). Every process calls it at the same
    /// point (a preconditioner may sweep `prop`'s operator, exchanging its halo).
    fn apply(&mut self, prop: &mut Propagation, r: &[V3], z: &mut [V3]);
    /// The inverse diagonal when M is diagonal (the solver fuses it into its vector update).
    fn inverse_diagonal(&self) -> Option<&[f64]> {
        None
    }
    /// The cost of one application in forward Euler substeps beyond the conjugate-gradient
    /// iteration's own (`choose::CG_COST`; a diagonal one is fused into it: 0).
    fn cost(&self) -> f64 {
        0.0
    }
}
