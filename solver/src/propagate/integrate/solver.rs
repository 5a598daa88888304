//! The implicit integrator's linear solves (like PETSc's KSP over its PC): the matrix
//! A = V - theta tau W of each level of the error control (sub-steps of dt / 2^level), its
//! preconditioner (the one the scenario names, or the one `preconditioner = "auto"` chooses by
//! trial solves) and conjugate gradients with exact dot products (`linalg::cg`), whose
//! failures become messages that name the scenario's fixes.

use super::implicit::THETA;
use crate::config::integrator::{Preconditioner, Settings};
use crate::distribute::comm::Comm;
use crate::distribute::field::NodeField;
use crate::linalg::cg::{self, Failure, Shifted};
use crate::linalg::direct::Direct;
use crate::linalg::jacobi::Jacobi;
use crate::linalg::multigrid::Multigrid;
use crate::linalg::{Precond, Sweep, V3};
use crate::propagate::Propagation;
use anyhow::{anyhow, Result};

/// `preconditioner = "auto"` tries multigrid only where jacobi's trial solve takes at least
/// this many iterations (below it, a V-cycle's cost, several operator applications, leaves no
/// room to win: the stiff tetgen kidney of 313k nodes took 31 with jacobi and 9 with
/// multigrid, and a step 3x longer with multigrid).
pub const MULTIGRID_FROM: usize = 40;
/// ... and takes it only where its trial solve is this many times cheaper than jacobi's (its
/// setup, and a recombination per error-control level, are not in the trial).
pub(crate) const MULTIGRID_MARGIN: f64 = 1.5;

/// The preconditioner of A = V - theta_tau W (`vol`: the volumes of the rows that move).
fn preconditioner(
    kind: Preconditioner,
    prop: &Propagation,
    vol: &[f64],
    gid: &[u64],
    theta_tau: f64,
    comm: &dyn Comm,
    path: &str,
) -> Result<Box<dyn Precond<Propagation>>> {
    let _ = (comm, path);
    Ok(match kind {
        // auto starts on jacobi; the trial solve may switch it to multigrid (`Solver::trial`)
        Preconditioner::Jacobi | Preconditioner::Auto => Box::new(Jacobi::new(prop.coefficients(), prop.sink(), vol, theta_tau)),
        Preconditioner::Multigrid => Box::new(
            Multigrid::new(prop, vol, gid, theta_tau, comm).map_err(|e| anyhow!("{path}: {e}"))?,
        ),
        #[cfg(eprop_hypre)]
        Preconditioner::Amg => Box::new(
            crate::linalg::amg::Amg::new(prop, vol, theta_tau, comm).map_err(|e| anyhow!("{path}: {e}"))?,
        ),
        #[cfg(not(eprop_hypre))]
        Preconditioner::Amg => anyhow::bail!(
            "{path}: [integrator] preconditioner = \"amg\" needs hypre, and this eprop was built without it; fix: use \"multigrid\" or \"jacobi\", or install hypre with 32-bit integers (Debian: libhypre-dev; elsewhere set HYPRE_DIR) and rebuild: it is found at build time"
        ),
    })
}

/// The matrix of one level (sub-steps of dt / 2^level): theta tau, the bound of its rows and
/// its preconditioner.
struct Level {
    theta_tau: f64,
    a_bound: f64,
    pre: Box<dyn Precond<Propagation>>,
}

/// The solves of the implicit integrator (`Implicit`).
pub struct Solver {
    kind: Preconditioner,
    /// How `preconditioner = "auto"` chose (empty otherwise)
    note: String,
    /// theta dt: theta tau of level 0
    theta_dt: f64,
    /// The level whose matrix theta_tau, a_bound and pre hold, and the other levels built
    level: u32,
    levels: Vec<Option<Level>>,
    theta_tau: f64,
    /// max_i V_i (1 + 2 theta tau sum_j |c_ij|): bounds |(A u)_i| / max |u| on every process
    a_bound: f64,
    pre: Box<dyn Precond<Propagation>>,
    /// V_i of the owned rows that move, 0 elsewhere
    vol: Vec<f64>,
    /// global ids of the local nodes (owned, then halo)
    gid: Vec<u64>,
    tol: f64,
    max_iterations: usize,
    /// The real-time mode's iterations per solve (`set_fixed`): a solve stops there whether
    /// or not it reached `tol` (None: to `tol`, failing at `max_iterations`).
    fixed: Option<usize>,
    /// The real-time mode's direct solver of level 0's matrix (`set_direct`): the stages
    /// solve with it instead of conjugate gradients.
    direct: Option<Direct>,
    path: String,
    work: cg::Work,
}

/// The tightest tolerance `Solver::tighten` sets: conjugate gradients still converge there in
/// double precision.
pub(crate) const TIGHTEST: f64 = 1e-13;

impl Solver {
    /// The solves of TR-BDF2 steps of dt on `prop`'s operator: `vol` the control volumes,
    /// `active` the nodes that move and `gid` their global ids (owned first).
    pub fn new(
        prop: &Propagation,
        vol: &[f64],
        active: &[bool],
        gid: &[u64],
        dt: f64,
        settings: &Settings,
        path: &str,
        comm: &dyn Comm,
    ) -> Result<Solver> {
        let layout = prop.layout();
        let n = layout.n_owned;
        let theta_tau = THETA * dt;
        let vol: Vec<f64> = (0..n).map(|i| if active[i] { vol[i] } else { 0.0 }).collect();
        let a_bound = comm.max(cg::row_bound(prop.coefficients(), prop.sink(), &vol, theta_tau));
        let pre = preconditioner(settings.preconditioner, prop, &vol, gid, theta_tau, comm, path)?;
        Ok(Solver {
            kind: settings.preconditioner,
            note: String::new(),
            theta_dt: theta_tau,
            level: 0,
            levels: Vec::new(),
            theta_tau,
            a_bound,
            pre,
            vol,
            gid: gid.to_vec(),
            tol: settings.tolerance,
            max_iterations: settings.max_iterations,
            fixed: None,
            direct: None,
            path: path.to_string(),
            work: cg::Work::new(layout),
        })
    }

    /// The scenario's path, for messages.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// V_i of the owned rows that move, 0 elsewhere.
    pub fn vol(&self) -> &[f64] {
        &self.vol
    }

    /// theta tau of the current level.
    pub fn theta_tau(&self) -> f64 {
        self.theta_tau
    }

    /// The relative tolerance of the stages' solves (`[integrator] tolerance`).
    pub fn tolerance(&self) -> f64 {
        self.tol
    }

    /// Solves `factor` times tighter (at most down to `TIGHTEST`); whether the tolerance
    /// changed (`Stepper::tighten`: TR-BDF2's fixed point is the steady state only to it).
    pub fn tighten(&mut self, factor: f64) -> bool {
        let t = (self.tol * factor).max(TIGHTEST);
        let tighter = t < self.tol;
        if tighter {
            tracing::debug!(
                "implicit: the solves' tolerance {:.1e} -> {t:.1e} for the steady state",
                self.tol
            );
            self.tol = t;
        }
        tighter
    }

    /// The real-time mode: every stage's solve takes at most `k` iterations and stops there
    /// without failing (the work per step is bounded; `tol` still stops it earlier).
    pub fn set_fixed(&mut self, k: usize) {
        self.fixed = Some(k);
    }

    /// Makes `kind` the preconditioner of the current level (built here): the real-time
    /// mode starts on jacobi, which costs nothing to build, and builds the one it will
    /// iterate with only once the direct solver is refused (`choose::realtime`).
    pub fn set_preconditioner(&mut self, kind: Preconditioner, prop: &Propagation, comm: &dyn Comm) -> Result<()> {
        self.pre = preconditioner(kind, prop, &self.vol, &self.gid, self.theta_tau, comm, &self.path)?;
        self.kind = kind;
        Ok(())
    }

    /// The real-time mode with a direct solver: factorises level 0's matrix (`Direct::new`)
    /// and solves the stages with it; on failure (returned: why) the solves stay iterative.
    pub fn set_direct(&mut self, prop: &Propagation, comm: &dyn Comm) -> Result<()> {
        if self.level != 0 {
            anyhow::bail!("not at level 0");
        }
        self.direct = Some(Direct::new(prop, &self.vol, self.theta_tau, &self.gid, comm)?);
        Ok(())
    }

    /// The direct solver, if the stages use one.
    pub fn direct(&self) -> Option<&Direct> {
        self.direct.as_ref()
    }

    /// The operator applications of a stage's solve that took `it` iterations: the two that
    /// start conjugate gradients and one per iteration, none with the direct solver.
    pub fn applications(&self, it: usize) -> usize {
        if self.direct.is_some() {
            0
        } else {
            it + 2
        }
    }

    /// The real-time mode's iterations per solve, if it is on.
    pub fn fixed(&self) -> Option<usize> {
        self.fixed
    }

    /// Whether the preconditioner is diagonal (fused into the iteration).
    pub fn diagonal(&self) -> bool {
        self.pre.inverse_diagonal().is_some()
    }

    /// The cost of one preconditioner application in forward Euler substeps
    /// (`Precond::cost`).
    pub fn preconditioner_cost(&self) -> f64 {
        self.pre.cost()
    }

    /// Makes `level`'s matrix (sub-steps of dt / 2^level) the current one, building its
    /// preconditioner the first time.
    pub fn set_level(&mut self, level: u32, prop: &Propagation, comm: &dyn Comm) -> Result<()> {
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
                let theta_tau = self.theta_dt * 0.5f64.powi(level as i32);
                // a multigrid keeps its hierarchy and recombines it (setup once per run)
                let pre = match self.pre.derive(theta_tau) {
                    Some(derived) => derived?,
                    None => preconditioner(self.kind, prop, &self.vol, &self.gid, theta_tau, comm, &self.path)?,
                };
                Level {
                    theta_tau,
                    a_bound: comm.max(cg::row_bound(prop.coefficients(), prop.sink(), &self.vol, theta_tau)),
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

    /// Solves A x = b for the three components, starting from x, to the relative tolerance
    /// `tol`; returns the iterations (each one operator application; the solve makes two more
    /// to start). `stage` says which solve it is in messages: 0 the trial, 1 and 2 the stages
    /// of step `step` + 1, 3 its error estimate's.
    pub fn solve(
        &mut self,
        prop: &mut Propagation,
        x: &mut NodeField<V3>,
        b: &[V3],
        comm: &dyn Comm,
        stage: usize,
        step: u64,
        tol: f64,
    ) -> Result<usize> {
        let a = Shifted {
            vol: &self.vol,
            c: self.theta_tau,
            bound: self.a_bound,
        };
        // the real-time mode's direct solver takes the stages (at level 0, its matrix)
        if let (Some(d), 1 | 2, 0) = (&mut self.direct, stage, self.level) {
            d.solve(&*prop, x, b, comm).map_err(|e| {
                anyhow!(
                    "{}: implicit: the solve of stage {stage} of step {}: {e}",
                    self.path,
                    step + 1
                )
            })?;
            return Ok(0);
        }
        // the real-time mode's stages stop after their fixed iterations (not the trial)
        let fixed = self.fixed.filter(|_| stage == 1 || stage == 2);
        let limit = fixed.unwrap_or(self.max_iterations);
        match cg::solve(prop, a, &mut *self.pre, b, x, &mut self.work, tol, limit, comm) {
            Err(Failure::Unconverged { .. }) if fixed.is_some() => Ok(limit),
            r => r.map_err(|f| self.failed(f, stage, step, tol)),
        }
    }

    /// The solve's failure as the scenario's error, with its fixes.
    fn failed(&self, f: Failure, stage: usize, step: u64, tol: f64) -> anyhow::Error {
        let what = if stage == 0 {
            "the trial solve (a pseudo-random right-hand side, to estimate the work per step)".to_string()
        } else if stage == 3 {
            format!("the error estimate's solve of step {}", step + 1)
        } else {
            format!("the solve of stage {stage} of step {}", step + 1)
        };
        let path = &self.path;
        match f {
            // (NotDefinite is `first_iterate`'s alone)
            Failure::NonFinite | Failure::NotDefinite { .. } => anyhow!(
                "{path}: implicit: {what} produced a non-finite residual; fix: check the scenario's conductivity and dt (eprop check), or use [model] integrator = \"rkl2\""
            ),
            Failure::Indefinite { rmr: gamma } => anyhow!(
                "{path}: implicit: {what}: the preconditioner is not positive definite (r M r = {gamma:.3e}), so conjugate gradients cannot converge; fix: use [integrator] preconditioner = \"jacobi\""
            ),
            Failure::Unconverged { residual } => anyhow!(
                "{path}: implicit: {what} did not converge in {} iterations (relative residual {residual:.3e} > tolerance {tol:.1e}); \
                 fix: raise [integrator] max_iterations, or loosen [integrator] tolerance, or use [integrator] preconditioner = \"amg\", or [model] integrator = \"rkl2\"",
                self.max_iterations,
            ),
            Failure::Breakdown { curvature: den } => anyhow!(
                "{path}: implicit: {what} broke down (the matrix is not positive definite: curvature {den:.3e}); fix: use [model] integrator = \"rkl2\" or \"euler\""
            ),
        }
    }

    /// The first conjugate-gradient iterate of A x = b from x = 0 (`cg::first_iterate`): one
    /// preconditioner and one operator application, the error estimate's filter of step
    /// `step` + 1 with a multigrid.
    pub fn first_iterate(
        &mut self,
        prop: &mut Propagation,
        x: &mut NodeField<V3>,
        b: &[V3],
        comm: &dyn Comm,
        step: u64,
    ) -> Result<()> {
        let a = Shifted {
            vol: &self.vol,
            c: self.theta_tau,
            bound: self.a_bound,
        };
        cg::first_iterate(prop, a, &mut *self.pre, b, x, &mut self.work, comm).map_err(|f| match f {
            Failure::NotDefinite { bmb: gamma, curvature: delta } => anyhow!(
                "{}: implicit: the error estimate of step {} met a matrix or preconditioner that is not positive definite ((b, M b) = {gamma:.3e}, (M b, A M b) = {delta:.3e}); fix: use [integrator] preconditioner = \"jacobi\"",
                self.path,
                step + 1
            ),
            _ => anyhow!(
                "{}: implicit: the error estimate of step {} produced a non-finite value; fix: check the scenario's conductivity and dt (eprop check), or use [model] integrator = \"rkl2\"",
                self.path,
                step + 1
            ),
        })
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
            self.note = format!("auto: jacobi, {it} iterations per solve in a trial");
            return Ok(it);
        }
        let mg = match Multigrid::new(&*prop, &self.vol, &self.gid, self.theta_tau, comm) {
            Ok(m) => m,
            Err(e) => {
                self.note = format!("auto: jacobi ({it} iterations per solve in a trial; multigrid: {e})");
                return Ok(it);
            }
        };
        let jacobi = std::mem::replace(&mut self.pre, Box::new(mg));
        let (cost_j, mg_it) = (it as f64 * super::choose::CG_COST, self.trial_solve(prop, gid, comm));
        match mg_it {
            Ok(k) if k as f64 * (super::choose::CG_COST + self.pre.cost()) * MULTIGRID_MARGIN < cost_j => {
                self.kind = Preconditioner::Multigrid;
                self.note = format!("auto: multigrid, {k} iterations per solve in a trial against jacobi's {it}");
                Ok(k)
            }
            Ok(k) => {
                self.pre = jacobi;
                self.note = format!("auto: jacobi, {it} iterations per solve in a trial against multigrid's {k} at several times the cost each");
                Ok(it)
            }
            Err(_) => {
                self.pre = jacobi;
                self.note =
                    format!("auto: jacobi, {it} iterations per solve in a trial (multigrid's trial did not converge)");
                Ok(it)
            }
        }
    }

    /// One trial solve with the current preconditioner (`trial`).
    fn trial_solve(&mut self, prop: &mut Propagation, gid: &[u64], comm: &dyn Comm) -> Result<usize> {
        use super::stability::hash_unit;
        let n = self.vol.len();
        let b: Vec<V3> = (0..n)
            .map(|i| {
                let (g, v) = (gid[i], self.vol[i]);
                [v * hash_unit(3 * g), v * hash_unit(3 * g + 1), v * hash_unit(3 * g + 2)]
            })
            .collect();
        let mut x = NodeField::filled(prop.layout(), [0.0; 3]);
        self.solve(prop, &mut x, &b, comm, 0, 0, self.tol)
    }

    /// The preconditioner in use.
    pub fn preconditioner_name(&self) -> &'static str {
        self.kind.name()
    }

    /// The preconditioner in use and how it was chosen (or the trial's `it` iterations per
    /// solve), for the summary and `eprop check`.
    pub fn preconditioner_phrase(&self, it: usize) -> String {
        if self.note.is_empty() {
            format!(
                "{} preconditioner ({it} iterations per solve in a trial)",
                self.kind.name()
            )
        } else {
            format!("{} preconditioner ({})", self.kind.name(), self.note)
        }
    }
}
