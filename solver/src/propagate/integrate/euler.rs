//! Forward Euler substeps, the paper's integrator: phi <- phi + h (L phi + Q), ceil(dt / h_max)
//! substeps of equal size h per mechanics step, h_max = 0.9 of the stability bound unless the
//! scenario gives h (which must not exceed the bound).

use super::{StepPlan, StepStats, Stepper};
use crate::distribute::comm::Comm;
use crate::propagate::{Propagation, Sources};
use anyhow::{bail, Result};

/// Safety factor applied to every stability bound for the automatic choices.
pub const SAFETY: f64 = 0.9;

pub struct Euler {
    plan: StepPlan,
}

impl Euler {
    /// Substeps for the mechanics step `dt` on an operator whose Euler bound is `h_bound`;
    /// `user_h` is the scenario's `[time] h`. `path` (the scenario) and `scheme` go into errors.
    pub fn new(h_bound: f64, dt: f64, user_h: Option<f64>, path: &str, scheme: &str) -> Result<Euler> {
        let h_max = match user_h {
            Some(h) if h > h_bound => bail!(
                "{path}: [time] h = {} is above the stability bound {h_bound:.6e} of the {scheme} scheme on this mesh; fix: use h <= {:.6e} or leave h out (automatic)",
                crate::diagnostics::short(h),
                SAFETY * h_bound
            ),
            Some(h) => h,
            None => SAFETY * h_bound,
        };
        let substeps = if h_max.is_finite() {
            (dt / h_max).ceil().max(1.0) as usize
        } else {
            1
        };
        let why = if user_h.is_some() {
            "the scenario's h".to_string()
        } else {
            format!("{SAFETY} of the stability bound")
        };
        Ok(Euler {
            plan: StepPlan {
                integrator: super::Kind::Euler,
                dt,
                h: dt / substeps as f64,
                step: dt / substeps as f64,
                h_bound,
                per_step: substeps,
                cost: substeps as f64,
                why,
            },
        })
    }
}

impl Euler {
    /// Replaces the plan's reason (the automatic choice says why it chose euler).
    pub fn set_why(&mut self, why: String) {
        self.plan.why = why;
    }
}

impl Stepper for Euler {
    fn plan(&self) -> &StepPlan {
        &self.plan
    }
    fn advance(&mut self, prop: &mut Propagation, q: &Sources, _: &dyn Comm) -> Result<StepStats> {
        // fused sweeps where they apply: bitwise the same as one substep at a time
        prop.substeps(self.plan.h, q, self.plan.per_step);
        Ok(StepStats {
            applications: self.plan.per_step,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn substeps_cover_dt_in_equal_parts_below_the_bound() {
        let e = Euler::new(0.1, 1.0, None, "s", "compact").unwrap();
        let p = e.plan();
        assert_eq!(p.per_step, 12); // 1 / 0.09 = 11.1
        assert!(p.h <= SAFETY * 0.1 && (p.h * 12.0 - 1.0).abs() < 1e-15);
        assert_eq!(
            Euler::new(0.1, 1.0, Some(0.05), "s", "compact")
                .unwrap()
                .plan()
                .per_step,
            20
        );
        let err = Euler::new(0.1, 1.0, Some(0.2), "s", "compact")
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("above the stability bound") && err.contains("fix:"),
            "{err}"
        );
        assert_eq!(
            Euler::new(f64::INFINITY, 1.0, None, "s", "compact")
                .unwrap()
                .plan()
                .per_step,
            1
        );
    }
}
