//! The integrator of the propagation as a scenario names it (`[model] integrator`) and its
//! settings (`[integrator]`), typed: the kind, the accuracy, the implicit solves' tolerance,
//! preconditioner and limits. `propagate::integrate` builds the stepper from them.

use serde::{Deserialize, Serialize};

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
pub(crate) const KINDS: [(&str, Kind); 4] = [
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

impl std::fmt::Display for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The preconditioner of the implicit solves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preconditioner {
    /// Jacobi, or multigrid where a trial solve shows it cheaper (`Implicit::trial`): both
    /// the same bits on any number of processes, so the choice is too.
    #[default]
    Auto,
    /// Diagonal: deterministic, the same bits on any number of processes.
    Jacobi,
    /// Smoothed-aggregation multigrid (`multigrid`): one V-cycle per iteration, a handful of
    /// iterations whatever the resolution; its coarse levels are global, so it gives the same
    /// bits on any number of processes.
    Multigrid,
    /// hypre BoomerAMG (algebraic multigrid): fewer iterations; agrees across process counts
    /// to the solver tolerance, not bitwise.
    Amg,
}

pub(crate) const PRECONDITIONERS: [(&str, Preconditioner); 4] = [
    ("auto", Preconditioner::Auto),
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
            .unwrap_or("jacobi")
    }
}

/// The integrator of a scenario with its settings, resolved (`[model] integrator` and the
/// `[integrator]` section, both checked while the scenario is parsed).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    pub kind: Kind,
    /// The relative error each mechanics step may add to the potential, ||e|| / ||phi|| over
    /// every node (`[integrator] accuracy`); infinite: no error control (the stability bound
    /// alone sets rkl2's and implicit's steps).
    pub accuracy: f64,
    /// The relative residual of the implicit solves (`[integrator] tolerance`; by default
    /// CG_SHARE times the accuracy).
    pub tolerance: f64,
    pub max_iterations: usize,
    pub max_stages: usize,
    pub preconditioner: Preconditioner,
    /// Whether `auto` measures its candidates on trial steps under the first loads (false:
    /// their models alone, as `eprop check` without --measure estimates). Not a scenario key.
    #[serde(default = "yes")]
    pub trials: bool,
}

fn yes() -> bool {
    true
}

pub(crate) const DEFAULT_ACCURACY: f64 = 1e-3;
/// The implicit solves' default tolerance as a share of the accuracy: a solve need not be
/// much more exact than the step it serves.
pub(crate) const CG_SHARE: f64 = 1e-2;
pub(crate) const DEFAULT_TOLERANCE: f64 = CG_SHARE * DEFAULT_ACCURACY;
/// The implicit solves' default tolerance without error control (`accuracy = inf`).
pub(crate) const UNCONTROLLED_TOLERANCE: f64 = 1e-8;
pub(crate) const DEFAULT_MAX_ITERATIONS: usize = 2000;
pub(crate) const DEFAULT_MAX_STAGES: usize = 4096;

impl Default for Settings {
    fn default() -> Self {
        Settings {
            kind: Kind::Auto,
            accuracy: DEFAULT_ACCURACY,
            tolerance: DEFAULT_TOLERANCE,
            max_iterations: DEFAULT_MAX_ITERATIONS,
            max_stages: DEFAULT_MAX_STAGES,
            preconditioner: Preconditioner::Auto,
            trials: true,
        }
    }
}
