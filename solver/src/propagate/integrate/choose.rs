//! The stepper of a scenario: the integrator it names, or for `auto` the cheapest one that
//! is accurate enough, from an estimate of the work per mechanics step (in forward Euler
//! substeps, the unit of `euler`):
//! - euler: ceil(dt / (0.9 h_bound)) substeps;
//! - rkl2: its stages times STAGE_COST, with super-steps short enough that the median node's
//!   modes stay resolved (tau / h_median <= Z_RKL2);
//! - implicit: 2 (k + 2) + 1 operator applications times CG_COST and 2 (k + 1) preconditioner
//!   applications at their own cost (a multigrid V-cycle: `multigrid::SWEEP_COST` per level-0
//!   matrix application of the cycle), k the iterations of a trial solve made here (the same
//!   on any number of processes with jacobi and multigrid).
//!
//! Under error control, where a load pushes or a tool presses, the candidates that may win are
//! measured instead on three mechanics steps from phi = 0 under the first sources (fewer when
//! the run takes fewer), and their mean over the run's length replaces the model
//! (`run_average`): a load switched on at once starts a transient that costs the first steps
//! many short sub-steps, and most so for implicit. The candidates are measured in the order of
//! their models, the second only where a lower bound known beforehand can still win, each
//! trial only while it can (a step stops inside, at the sub-step past its budget), and the
//! chosen one replays its trial steps in the run (`Replay`). `eprop check` leaves the trial
//! out unless asked (`check --measure`): the models alone.
//!
//! Only the compact scheme has candidates besides euler; euler stays unless another is MARGIN
//! times cheaper.

use super::euler::SAFETY;
use super::rkl2::{stages_for, STAGE_COST};
use super::{Euler, Implicit, Rkl2, Stepper};
use crate::config::integrator::{Kind, Preconditioner, Settings};
use crate::config::RealtimeSolver;
use crate::distribute::comm::Comm;
use crate::linalg::V3;
use crate::propagate::{Propagation, Sources};
use anyhow::{bail, Result};

/// Cost of one conjugate-gradient iteration of `implicit` (Jacobi) in forward Euler
/// substeps: the operator sweep with its dot products and a pass over eleven vectors.
/// Measured as `rkl2::STAGE_COST`.
pub(crate) const CG_COST: f64 = 2.4;
/// `rkl2` takes super-steps short enough that the median node's modes see tau / h <= Z_RKL2
/// (past that, its stages damp them little and they lose accuracy).
pub(crate) const Z_RKL2: f64 = 20.0;
/// Under error control each rkl2 super-step is taken once and again as two halves (step
/// doubling): 1 + sqrt 2 times the stages of the super-step alone.
pub(crate) const DOUBLING: f64 = 1.0 + std::f64::consts::SQRT_2;

/// The fewest operator applications of a controlled TR-BDF2 step: the right-hand side, two
/// solves that start converged (two each), the estimate's and its two filter passes (one each
/// with a multigrid), as at a steady state. A lower bound of every step's.
pub(crate) const LEAST_CONTROLLED: usize = 8;

/// Operator applications of one controlled TR-BDF2 step whose solves take `it` iterations:
/// the two stages, the estimate's operator application and its two filter solves (with
/// jacobi about 0.4 of the iterations of a stage's solve; a multigrid's two filter steps are
/// one application each, so this overestimates them there, and auto measures before it
/// chooses).
pub(crate) fn controlled_applications(it: usize, controlled: bool) -> usize {
    let stages = 2 * (it + 2) + 1;
    if controlled {
        stages + 1 + 2 * ((2 * it).div_ceil(5) + 2)
    } else {
        stages
    }
}

/// The accuracy in a plan's words.
fn accuracy_phrase(a: f64) -> String {
    if a.is_finite() {
        format!("accuracy {a:e} per step, error-controlled")
    } else {
        "no error control (accuracy = inf)".into()
    }
}

/// `auto` keeps euler unless another integrator is estimated this many times cheaper.
pub(crate) const MARGIN: f64 = 1.5;

/// What the choice needs to know about the scenario and its operator.
pub struct Context<'a> {
    pub settings: &'a Settings,
    /// The scheme's name and whether it is `compact` (symmetric, real spectrum).
    pub scheme: &'static str,
    pub compact: bool,
    /// The forward Euler stability bound of the operator (2 / spectral radius bound).
    pub h_bound: f64,
    /// The mechanics step and the scenario's `[time] h`.
    pub dt: f64,
    pub user_h: Option<f64>,
    /// The scenario file, for messages.
    pub path: &'a str,
    /// The propagation (a trial solve runs its sweeps; its potential is left alone).
    pub prop: &'a mut Propagation,
    /// Control volumes, the nodes that move and global ids (local numbering, owned first).
    pub vol: &'a [f64],
    pub active: &'a [bool],
    pub gid: &'a [u64],
    /// The sources (owned rows) of the first step a load pushes or a tool presses and of the
    /// two steps after it, and the run's length: `auto` measures the candidates on these.
    pub trial: Option<TrialRun>,
    /// The real-time mode (`[time] realtime`; None: off) and how it solves its stages
    /// (`[time] realtime_solver`): `realtime` builds the stepper.
    pub realtime: Option<RealtimeSolver>,
    pub comm: &'a dyn Comm,
}

/// Sources of a trial step, on the owned rows.
pub type Trial = Vec<(u32, V3)>;

/// What the trial steps need: the sources of the first step a load pushes or a tool presses
/// and of the two steps after it (fewer where the run takes fewer steps from that one), and
/// the run's steps from that first one (None: not known, a run to equilibrium).
#[derive(Clone)]
pub struct TrialRun {
    pub sources: Vec<Trial>,
    /// The run's step (from 0) whose sources are `sources[0]`.
    pub first: u64,
    pub steps: Option<u64>,
}

/// The applications per step over a run of `steps` steps whose first three steps took
/// `apps` (a trial from phi = 0): the first two as measured (the start's transient, which
/// error control resolves with short sub-steps) and the third for every later step. A run of
/// unknown length counts the third alone, the cost it settles to.
pub(crate) fn run_average(apps: [usize; 3], steps: Option<u64>) -> f64 {
    let [a, b, c] = apps.map(|x| x as f64);
    match steps {
        None => c,
        Some(0 | 1) => a,
        Some(2) => (a + b) / 2.0,
        Some(n) => (a + b + (n - 2) as f64 * c) / n as f64,
    }
}

/// "three trial steps", "one trial step", ... in a message.
fn trial_words(k: usize) -> String {
    match k {
        1 => "one trial step".into(),
        2 => "two trial steps".into(),
        3 => "three trial steps".into(),
        _ => format!("{k} trial steps"),
    }
}

/// The run's length in a message.
fn over(steps: Option<u64>) -> String {
    match steps {
        Some(n) => format!("averaged over the run's {n} steps"),
        None => "the third (the run's length is not known)".into(),
    }
}

/// A count for a message: whole below 1e9, else in exponent form (a saturated count is
/// `usize::MAX`, which says nothing in full).
fn count(x: f64) -> String {
    if x < 1e9 {
        format!("{x:.0}")
    } else {
        format!("{x:.3e}")
    }
}

/// Super-steps per mechanics step for RKL2: enough that tau / h_median <= Z_RKL2.
fn rkl2_supersteps(dt: f64, h_median: f64) -> usize {
    if h_median.is_finite() && h_median > 0.0 {
        (dt / h_median / Z_RKL2).ceil().max(1.0) as usize
    } else {
        1
    }
}

/// The median node's own Euler bound (2 / its Gershgorin bound), over every process.
fn median_h(prop: &Propagation, comm: &dyn Comm) -> f64 {
    match &prop.op {
        crate::discretize::operator::Operator::Compact(c) => {
            let g = super::stability::median_bound(c, prop.layout().n_owned, comm);
            if g > 0.0 {
                2.0 / g
            } else {
                f64::INFINITY
            }
        }
        _ => f64::INFINITY,
    }
}

fn euler(cx: &Context, why: String) -> Result<Box<dyn Stepper>> {
    let mut e = Euler::new(cx.h_bound, cx.dt, cx.user_h, cx.path, cx.scheme)?;
    if !why.is_empty() {
        e.set_why(why);
    }
    Ok(Box::new(e))
}

/// The implicit stepper on the context's operator with `settings` (the scenario's, or the
/// real-time mode's lighter start).
fn implicit(cx: &Context, settings: &Settings) -> Result<Implicit> {
    Implicit::new(
        cx.prop, cx.vol, cx.active, cx.gid, cx.dt, cx.h_bound, settings, cx.path, cx.comm,
    )
}

/// A trial step as it ran: the potential after it (every local row, the halo's too), its
/// operator applications and estimated error.
struct Recorded {
    phi: Vec<V3>,
    applications: usize,
    error: Option<f64>,
}

/// What trial steps did: each whole step, the largest estimated error, and the operator
/// applications of a step stopped inside (past its budget), if one was.
struct Steps {
    recorded: Vec<Recorded>,
    error: f64,
    stopped_at: Option<usize>,
}

/// Mechanics steps of `st` from phi = 0 under the trial sources (phi is zero again
/// afterwards). Before each step `budget` sees the applications of the steps so far and
/// bounds the step's own (None: no bound); a step past it stops inside and ends the trial.
fn trial_steps(
    st: &mut dyn Stepper,
    cx: &mut Context,
    sources: &[Trial],
    budget: &dyn Fn(&[usize]) -> Option<usize>,
) -> Result<Steps> {
    let zero = |p: &mut Propagation| p.phi.iter_mut().for_each(|x| *x = [0.0; 3]);
    zero(cx.prop);
    let mut run = || -> Result<Steps> {
        let (mut steps, mut err) = (Vec::with_capacity(sources.len()), 0.0f64);
        for q in sources {
            let apps: Vec<usize> = steps.iter().map(|r: &Recorded| r.applications).collect();
            st.set_budget(budget(&apps));
            let applications = match st.advance(cx.prop, q, cx.comm) {
                Ok(s) => s.applications,
                Err(e) => match e.downcast_ref::<super::OverBudget>() {
                    Some(o) => {
                        return Ok(Steps {
                            recorded: steps,
                            error: err,
                            stopped_at: Some(o.applications),
                        })
                    }
                    None => return Err(e),
                },
            };
            let error = st.last_error();
            err = err.max(error.unwrap_or(0.0));
            steps.push(Recorded {
                phi: cx.prop.phi.to_vec(),
                applications,
                error,
            });
        }
        Ok(Steps {
            recorded: steps,
            error: err,
            stopped_at: None,
        })
    };
    let r = run();
    st.set_budget(None);
    zero(cx.prop);
    r
}

/// The most applications the next step may take, after steps that took `apps`, for the
/// candidate still to win: the largest `a` for which `wins_with(apps and a)` (None: any).
/// `wins_with` falls as `a` grows.
fn budget_of(apps: &[usize], wins_with: &dyn Fn(&[usize]) -> bool) -> Option<usize> {
    let with = |a: usize| {
        let mut v = apps.to_vec();
        v.push(a);
        wins_with(&v)
    };
    const MOST: usize = 1 << 48;
    if with(MOST) {
        return None;
    }
    if !with(0) {
        return Some(0);
    }
    // with(lo) and !with(hi)
    let (mut lo, mut hi) = (0usize, MOST);
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if with(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(lo)
}

/// The least the run's applications per step can average, `steps` steps from the first push,
/// when the first trial steps took `apps` and every later step takes at least `least`.
fn least_average(apps: &[usize], least: f64, steps: Option<u64>) -> f64 {
    match steps {
        Some(n) if n as usize >= apps.len() && n > 0 => {
            let known: f64 = apps.iter().map(|&a| a as f64).sum();
            (known + (n as usize - apps.len()) as f64 * least) / n as f64
        }
        Some(n) => apps.iter().take(n.max(1) as usize).map(|&a| a as f64).sum::<f64>() / n.max(1) as f64,
        // a run to equilibrium counts the third step alone
        None => least,
    }
}

/// The operator applications of recorded trial steps (0 for those not taken).
fn applications(r: &[Recorded]) -> [usize; 3] {
    std::array::from_fn(|k| r.get(k).map_or(0, |r| r.applications))
}

/// The chosen integrator, which first replays its own trial steps where the run repeats them
/// exactly: the same sources and the same potential on the owned rows before the step, bit
/// for bit on every process. A stepper computes the same bits from the same input (its state
/// between mechanics steps is only a cache: built preconditioners, counters), so a replayed
/// step is the step it would compute, and the trial's work is not done twice. Where anything
/// differs (a tool in contact, a load that follows the deformation, a restart), the record is
/// dropped and the stepper computes.
pub struct Replay {
    inner: Box<dyn Stepper>,
    /// The trial's sources and its steps not yet replayed, in order.
    sources: Vec<Trial>,
    recorded: Vec<Recorded>,
    /// The potential the next recorded step started from (None: zero).
    before: Option<Vec<V3>>,
    /// Steps to take before the first recorded one (a run's steps before anything pushes).
    wait: u64,
}

impl Replay {
    fn new(inner: Box<dyn Stepper>, trial: TrialRun, recorded: Vec<Recorded>) -> Replay {
        let mut sources = trial.sources;
        sources.truncate(recorded.len());
        Replay {
            inner,
            sources,
            recorded,
            before: None,
            wait: trial.first,
        }
    }

    /// Whether the step about to run is the next recorded one, on every process.
    fn repeats(&self, prop: &Propagation, q: &Sources, comm: &dyn Comm) -> bool {
        let n = prop.layout().n_owned;
        let same = |a: V3, b: V3| (0..3).all(|d| a[d].to_bits() == b[d].to_bits());
        let sources = self
            .sources
            .first()
            .is_some_and(|t| t.len() == q.len() && t.iter().zip(q).all(|(a, b)| a.0 == b.0 && same(a.1, b.1)));
        let phi = match &self.before {
            None => prop.phi[..n].iter().all(|x| x.iter().all(|v| v.to_bits() == 0)),
            Some(b) => prop.phi[..n].iter().zip(&b[..n]).all(|(x, y)| same(*x, *y)),
        };
        comm.min(if sources && phi { 1.0 } else { 0.0 }) == 1.0
    }
}

impl Stepper for Replay {
    fn plan(&self) -> &super::StepPlan {
        self.inner.plan()
    }
    fn last_error(&self) -> Option<f64> {
        self.inner.last_error()
    }
    fn tighten(&mut self, factor: f64) -> bool {
        self.inner.tighten(factor)
    }
    fn set_budget(&mut self, budget: Option<usize>) {
        self.inner.set_budget(budget)
    }
    fn advance(&mut self, prop: &mut Propagation, q: &Sources, comm: &dyn Comm) -> Result<super::StepStats> {
        if self.wait > 0 {
            // before the first recorded step; whether the run then repeats the trial is
            // checked on the inputs, so a run that does not (a restart) only computes
            self.wait -= 1;
            return self.inner.advance(prop, q, comm);
        }
        if !self.recorded.is_empty() {
            if self.repeats(prop, q, comm) {
                let r = self.recorded.remove(0);
                self.sources.remove(0);
                prop.phi.copy_from_slice(&r.phi);
                // the last one's potential is not needed to compare with
                self.before = (!self.recorded.is_empty()).then_some(r.phi);
                self.inner.replayed(r.error);
                tracing::debug!(
                    "{} step replayed from the automatic choice's trial ({} operator applications)",
                    self.inner.plan().integrator.name(),
                    r.applications
                );
                return Ok(super::StepStats {
                    applications: r.applications,
                });
            }
            (self.recorded, self.sources, self.before) = (Vec::new(), Vec::new(), None);
        }
        self.inner.advance(prop, q, comm)
    }
    fn replayed(&mut self, error: Option<f64>) {
        self.inner.replayed(error)
    }
}

/// The stepper of the scenario.
pub fn build(cx: &mut Context) -> Result<Box<dyn Stepper>> {
    let s = cx.settings;
    if s.kind != Kind::Euler && s.kind != Kind::Auto && !cx.compact {
        bail!(
            "{}: [model] integrator = \"{}\" needs the symmetric compact scheme (the {} scheme's spectrum is complex, where neither rkl2's stability interval nor conjugate gradients hold); fix: use integrator = \"euler\" or \"auto\" with this scheme, or scheme = \"compact\"",
            cx.path,
            s.kind.name(),
            cx.scheme
        );
    }
    if s.kind != Kind::Euler && s.kind != Kind::Auto && cx.user_h.is_some() {
        bail!(
            "{}: [time] h sets forward Euler's substep, and [model] integrator = \"{}\" takes no substep; fix: leave h out, or use integrator = \"euler\"",
            cx.path,
            s.kind.name()
        );
    }
    if let Some(solver) = cx.realtime {
        return realtime(cx, solver);
    }
    let layout = cx.prop.layout();
    match s.kind {
        Kind::Euler => euler(cx, String::new()),
        Kind::Rkl2 => {
            let n = rkl2_supersteps(cx.dt, median_h(cx.prop, cx.comm));
            let st = stages_for(cx.dt / n as f64, cx.h_bound);
            let mut r = Rkl2::new(
                cx.h_bound,
                cx.dt,
                n,
                s.max_stages,
                layout,
                cx.path,
                format!(
                    "the scenario's choice: {st} stages per super-step, {n} super-step(s) per step to start, {}",
                    accuracy_phrase(s.accuracy)
                ),
            )?;
            r.set_accuracy(s.accuracy);
            Ok(Box::new(r))
        }
        Kind::Implicit => {
            let mut imp = implicit(cx, cx.settings)?;
            imp.set_accuracy(s.accuracy);
            // a trial solve estimates the work per step (for `eprop check` and the summary)
            let it = imp.trial(cx.prop, cx.gid, cx.comm)?;
            let apps = controlled_applications(it, s.accuracy.is_finite());
            let cost = imp.cost_of(apps);
            imp.set_plan(
                apps,
                cost,
                format!(
                    "the scenario's choice: TR-BDF2, {}, {}",
                    imp.preconditioner_phrase(it),
                    accuracy_phrase(s.accuracy)
                ),
            );
            Ok(Box::new(imp))
        }
        Kind::Auto => auto(cx),
    }
}

/// The real-time mode's relative tolerance: the trial solve that sets the iterations per
/// stage solves to it, and a stage's solve stops early once there.
pub(crate) const REALTIME_TOLERANCE: f64 = 1e-6;
/// The real-time mode's iterations per stage solve lie within these (the upper one bounds
/// the work on a mesh whose trial needs more; a stage starts from the step's potential, so
/// it needs fewer than a trial from zero).
pub(crate) const REALTIME_ITERATIONS: (usize, usize) = (2, 40);

/// The real-time mode (`[time] realtime`, docs/realtime.md): TR-BDF2 with one step per
/// mechanics step, no error control, and direct solves (`linalg::direct`: a factor made
/// here once) where `solver` allows them and they can be made (`Auto` falls back to the
/// iterations, `Direct` fails with the reason); otherwise at most k preconditioned
/// conjugate-gradient iterations per stage, k fixed here at setup from the iterations a
/// trial solve from zero takes to `REALTIME_TOLERANCE` (clamped to `REALTIME_ITERATIONS`).
/// Each step is then at most `Implicit::applications_bound(k)` operator applications and
/// 2 (k + 2) preconditioner applications, whatever the loads and tools do. The settings
/// (`simulate::build_stepper`) name the preconditioner (a multigrid unless the scenario
/// names one, built only for the iterations) and no accuracy.
fn realtime(cx: &mut Context, solver: RealtimeSolver) -> Result<Box<dyn Stepper>> {
    if !cx.compact {
        bail!(
            "{}: [time] realtime = true runs the implicit integrator, which needs the symmetric compact scheme (the {} scheme's spectrum is complex); fix: use [model] scheme = \"compact\", or realtime = false",
            cx.path,
            cx.scheme
        );
    }
    if cx.user_h.is_some() {
        bail!(
            "{}: [time] h sets forward Euler's substep, and [time] realtime = true takes none (one implicit step per dt); fix: leave h out, or set realtime = false",
            cx.path
        );
    }
    // the stepper starts on jacobi (nothing to build): the preconditioner the fixed
    // iterations need (a multigrid unless the scenario names one) is built only when they
    // are taken, after the direct solver is refused
    let light = Settings {
        preconditioner: Preconditioner::Jacobi,
        ..cx.settings.clone()
    };
    let mut imp = implicit(cx, &light)?;
    // a direct solver where the mesh is small enough and CHOLMOD is there (unless the
    // scenario asks for the iterations)
    let tried = match solver {
        RealtimeSolver::Iterative => Err(anyhow::anyhow!("[time] realtime_solver = \"iterative\"")),
        _ => imp.set_direct(cx.prop, cx.comm),
    };
    let no_direct = match tried {
        Ok((unknowns, factor, entries)) => {
            // the cost in operator applications: stage 1's right-hand side, then per stage
            // two triangular solves, each reading the factor once
            let per_step = 1;
            let solves = 4.0 * factor / entries.max(1) as f64;
            imp.set_plan(
                per_step,
                CG_COST * (per_step as f64 + solves),
                format!(
                    "real time: TR-BDF2, one step per dt, direct solves (a sparse Cholesky factor of {unknowns} unknowns, {factor:.3e} entries, made once; {per_step} operator application and 4 triangular solves per step, about {solves:.0} applications' worth), no error control"
                ),
            );
            return Ok(Box::new(imp));
        }
        Err(e) if solver == RealtimeSolver::Direct => bail!(
            "{}: [time] realtime_solver = \"direct\": the real-time mode cannot solve this scenario directly: {e}; fix: realtime_solver = \"auto\" or \"iterative\" (the fixed iterations)",
            cx.path
        ),
        Err(e) => e.to_string(),
    };
    tracing::debug!("real time: no direct solver ({no_direct}): fixed iterations");
    imp.set_preconditioner(cx.settings.preconditioner, cx.prop, cx.comm)?;
    let it = imp.trial(cx.prop, cx.gid, cx.comm)?;
    let k = it.clamp(REALTIME_ITERATIONS.0, REALTIME_ITERATIONS.1);
    imp.set_fixed(k);
    let apps = Implicit::applications_bound(k);
    let cost = imp.cost_of(apps);
    imp.set_plan(
        apps,
        cost,
        format!(
            "real time: TR-BDF2, one step per dt, at most {k} iterations per stage ({} applications per step), {}, no error control (no direct solver: {no_direct})",
            apps,
            imp.preconditioner_phrase(it)
        ),
    );
    Ok(Box::new(imp))
}

/// A candidate's cost per step in forward Euler substeps and what the message says of it.
struct Measured {
    cost: f64,
    /// the trial steps' applications and largest estimated error, where they ran
    trial: Option<(Vec<usize>, f64)>,
    record: Option<Vec<Recorded>>,
    /// the applications of the trial steps taken until the candidate could no longer win (its
    /// trial stopped; the last one's inside its step)
    stopped: Option<Vec<usize>>,
}

/// What a candidate must beat: the best cost per step so far, whether that is euler's (which
/// another candidate beats only by MARGIN), and the least applications any step of the
/// candidate takes.
#[derive(Clone, Copy)]
struct Limit {
    best: f64,
    euler: bool,
    least: f64,
}

/// The candidate's cost: from its trial steps where the error is controlled and a load
/// pushes or a tool presses (`run_average` of their applications times `per_application`),
/// else `model`; infinite when the trial fails. The trial stops early, inside the step that
/// passes it, once the steps taken and `limit.least` for the rest of the run cannot beat
/// `limit.best`.
fn measure(st: &mut dyn Stepper, cx: &mut Context, model: f64, per_application: f64, limit: Limit) -> Measured {
    let (Some(q), true) = (cx.trial.clone(), cx.settings.accuracy.is_finite()) else {
        return Measured {
            cost: model,
            trial: None,
            record: None,
            stopped: None,
        };
    };
    let name = st.plan().integrator;
    let k = q.sources.len();
    tracing::info!(
        target: "eprop::setup",
        "auto: measuring {name} over {} under the first loads (the chosen integrator replays them)",
        trial_words(k)
    );
    let t = std::time::Instant::now();
    let at_least = |apps: &[usize]| per_application * least_average(apps, limit.least, q.steps);
    let go_on = |apps: &[usize]| wins(at_least(apps), limit.euler, limit.best);
    // a step stops inside once the candidate cannot win; the last too, costed as a whole by
    // `run_average`, which is at least `least_average` (its last step at least `least`)
    let budget = |apps: &[usize]| budget_of(apps, &go_on);
    match trial_steps(st, cx, &q.sources, &budget) {
        Ok(Steps {
            recorded,
            stopped_at: Some(partial),
            ..
        }) => {
            let mut apps: Vec<usize> = recorded.iter().map(|r| r.applications).collect();
            apps.push(partial);
            tracing::info!(
                target: "eprop::setup",
                "auto: {name}: {apps:?} operator applications in {:.1} s: it cannot win, its trial stops inside step {}",
                t.elapsed().as_secs_f64(),
                apps.len()
            );
            Measured {
                cost: at_least(&apps),
                trial: None,
                record: None,
                stopped: Some(apps),
            }
        }
        Ok(Steps {
            recorded, error: err, ..
        }) => {
            let apps = applications(&recorded);
            let taken = apps[..recorded.len()].to_vec();
            tracing::info!(
                target: "eprop::setup",
                "auto: {name}: {taken:?} operator applications in {:.1} s",
                t.elapsed().as_secs_f64()
            );
            Measured {
                cost: per_application * run_average(apps, q.steps),
                trial: Some((taken, err)),
                record: Some(recorded),
                stopped: None,
            }
        }
        Err(_) => Measured {
            cost: f64::INFINITY,
            trial: None,
            record: None,
            stopped: None,
        },
    }
}

/// Whether a candidate of `cost` per step beats the best so far, `best` (euler's when `euler`:
/// another integrator must be MARGIN times cheaper than it).
fn wins(cost: f64, euler: bool, best: f64) -> bool {
    cost * if euler { MARGIN } else { 1.0 } < best
}

/// A candidate whose lower bound `bound` per step can still beat the best so far (`best`: the
/// integrator and its cost per step): measured (`measure`, every later step at least `least`
/// applications), and made the best where its cost beats it; None where it was not measured.
#[allow(clippy::too_many_arguments)]
fn consider(
    st: &mut dyn Stepper,
    cx: &mut Context,
    kind: Kind,
    model: f64,
    per_application: f64,
    bound: f64,
    least: f64,
    best: &mut (Kind, f64),
) -> Option<Measured> {
    let euler = best.0 == Kind::Euler;
    if !wins(bound, euler, best.1) {
        return None;
    }
    let m = measure(
        st,
        cx,
        model,
        per_application,
        Limit {
            best: best.1,
            euler,
            least,
        },
    );
    if m.cost.is_finite() && m.stopped.is_none() && wins(m.cost, euler, best.1) {
        *best = (kind, m.cost);
    }
    Some(m)
}

/// `auto`: the cheapest of euler, rkl2 and implicit at the accuracy (module notes). Each
/// candidate has a lower bound on its cost per step known before its trial steps: rkl2 at
/// least one doubled super-step over dt (2 STAGE_COST stages_for(dt)), implicit at least
/// LEAST_CONTROLLED applications. The candidates are measured in the order of their models,
/// the second only where its bound can still beat the first, and each trial only while it
/// can win (`least_average`).
fn auto(cx: &mut Context) -> Result<Box<dyn Stepper>> {
    let s = cx.settings;
    if !cx.compact {
        return euler(
            cx,
            format!(
                "auto: on the {} scheme (complex spectrum) only euler is stable",
                cx.scheme
            ),
        );
    }
    if cx.user_h.is_some() {
        return euler(cx, "auto: the scenario sets the Euler substep h".into());
    }
    let mut c = Candidates::new(cx)?;
    let best = c.measure(cx);
    let steps = cx.trial.as_ref().map(|q| q.steps).unwrap_or(None);
    let others = c.describe(steps);
    // the chosen one replays its trial steps where the run repeats them
    let replay = |st: Box<dyn Stepper>, rec: Option<Vec<Recorded>>| -> Box<dyn Stepper> {
        match (rec, cx.trial.clone()) {
            (Some(rec), Some(q)) => Box::new(Replay::new(st, q, rec)),
            _ => st,
        }
    };
    match best {
        Kind::Rkl2 => {
            let mut r = c.rkl2.expect("rkl2 was built");
            r.set_why(format!(
                "auto: rkl2 is the cheapest: {others}; {}",
                accuracy_phrase(s.accuracy)
            ));
            Ok(replay(Box::new(r), c.rkl2_m.and_then(|m| m.record)))
        }
        Kind::Implicit => {
            let (mut i, it) = c.imp.expect("implicit was tried");
            let m = c.imp_m.expect("implicit was measured");
            let apps = m.cost / i.cost_of(1);
            i.set_plan(
                apps.round() as usize,
                m.cost,
                format!(
                    "auto: implicit (TR-BDF2, {}) is the cheapest: {others}; {}",
                    i.preconditioner_phrase(it),
                    accuracy_phrase(s.accuracy)
                ),
            );
            Ok(replay(Box::new(i), m.record))
        }
        _ => euler(
            cx,
            format!(
                "auto: euler, no other is {MARGIN}x cheaper: {others}; accuracy {:e} per step for the others",
                s.accuracy
            ),
        ),
    }
}

/// What `auto` weighs against euler's `substeps` per step: rkl2 (`n` super-steps of `st`
/// stages) and implicit (with its trial's iterations per solve), each with the cost its model
/// predicts, the bound below which no step goes, and what its trial steps measured.
struct Candidates {
    substeps: f64,
    n: usize,
    st: usize,
    controlled: bool,
    /// whether the candidates are measured on trial steps (error control and a first push)
    measured: bool,
    rkl2: Option<Rkl2>,
    rkl2_model: f64,
    rkl2_bound: f64,
    rkl2_m: Option<Measured>,
    imp: Option<(Implicit, usize)>,
    imp_model: Option<f64>,
    imp_bound: Option<f64>,
    imp_m: Option<Measured>,
}

impl Candidates {
    /// The candidates of the compact scheme, their models and bounds (implicit after a trial
    /// solve, where it can win).
    fn new(cx: &mut Context) -> Result<Candidates> {
        let s = cx.settings;
        let layout = cx.prop.layout();
        let substeps = if cx.h_bound.is_finite() {
            (cx.dt / (SAFETY * cx.h_bound)).ceil().max(1.0)
        } else {
            1.0
        };
        let n = rkl2_supersteps(cx.dt, median_h(cx.prop, cx.comm));
        let st = stages_for(cx.dt / n as f64, cx.h_bound);
        let controlled = s.accuracy.is_finite();
        let doubling = if controlled { DOUBLING } else { 1.0 };
        let measured = controlled && cx.trial.is_some();
        // rkl2: the stability model's cost; a candidate when its super-steps alone (without the
        // doubling, which the trial measures with the levels the control takes) beat euler
        let rkl2_model = doubling * STAGE_COST * st.saturating_mul(n) as f64;
        let mut rkl2 = None;
        if st.saturating_mul(n) <= s.max_stages && rkl2_model / doubling < substeps {
            let mut r = Rkl2::new(cx.h_bound, cx.dt, n, s.max_stages, layout, cx.path, String::new())?;
            r.set_accuracy(s.accuracy);
            rkl2 = Some(r);
        }
        let rkl2_bound = if measured {
            2.0 * STAGE_COST * stages_for(cx.dt, cx.h_bound).min(st.saturating_mul(n)) as f64
        } else {
            rkl2_model
        };
        // implicit costs at least one iteration per stage: a trial solve only where it can win
        let floor = CG_COST * (2.0 * 3.0 + 1.0);
        let mut imp = None;
        if floor * MARGIN < substeps {
            let mut i = implicit(cx, cx.settings)?;
            if let Ok(it) = i.trial(cx.prop, cx.gid, cx.comm) {
                i.set_accuracy(s.accuracy);
                imp = Some((i, it));
            }
        }
        let imp_model = imp
            .as_ref()
            .map(|(i, it)| i.cost_of(controlled_applications(*it, controlled)));
        let imp_bound = imp
            .as_ref()
            .zip(imp_model)
            .map(|((i, _), m)| if measured { i.cost_of(LEAST_CONTROLLED) } else { m });
        Ok(Candidates {
            substeps,
            n,
            st,
            controlled,
            measured,
            rkl2,
            rkl2_model,
            rkl2_bound,
            rkl2_m: None,
            imp,
            imp_model,
            imp_bound,
            imp_m: None,
        })
    }

    /// Measures the candidates in the order of their models (a guess), the second only where
    /// it can still win, and each trial only while it can; returns the cheapest integrator.
    fn measure(&mut self, cx: &mut Context) -> Kind {
        let mut best = (Kind::Euler, self.substeps);
        let order = match self.imp_model {
            Some(m) if m < self.rkl2_model => [Kind::Implicit, Kind::Rkl2],
            _ => [Kind::Rkl2, Kind::Implicit],
        };
        for kind in order {
            if kind == Kind::Rkl2 {
                if let Some(r) = self.rkl2.as_mut() {
                    let (model, bound) = (self.rkl2_model, self.rkl2_bound);
                    let least = bound / STAGE_COST;
                    self.rkl2_m = consider(r, cx, kind, model, STAGE_COST, bound, least, &mut best);
                    r.restart_count();
                }
            } else if let Some((i, _)) = self.imp.as_mut() {
                let (model, bound) = (
                    self.imp_model.unwrap_or(f64::INFINITY),
                    self.imp_bound.unwrap_or(f64::INFINITY),
                );
                let per = i.cost_of(1);
                self.imp_m = consider(i, cx, kind, model, per, bound, LEAST_CONTROLLED as f64, &mut best);
                i.restart_count();
            }
        }
        best.0
    }

    /// Every candidate's cost per step in words (a run of `steps` steps).
    fn describe(&self, steps: Option<u64>) -> String {
        let (st, n, measured) = (self.st, self.n, self.measured);
        let predicted = |t: &Option<(Vec<usize>, f64)>| match t {
            Some((_, e)) => format!(", predicted error {e:.1e}"),
            None => String::new(),
        };
        let in_trial = |what: &str, t: &Option<(Vec<usize>, f64)>, open: &str, close: &str| match t {
            Some((a, _)) => format!(
                "{open}{what} in {} {}, {}{close}",
                trial_words(a.len()),
                a.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(", "),
                over(steps)
            ),
            None => String::new(),
        };
        let rkl2_text = match (&self.rkl2, &self.rkl2_m) {
            (Some(_), Some(m)) if m.trial.is_some() => format!(
                ", rkl2 ~{:.0} stages{} (~{} substeps{})",
                m.cost / STAGE_COST,
                in_trial("stages", &m.trial, " (", ")"),
                count(m.cost),
                predicted(&m.trial)
            ),
            (
                Some(_),
                Some(Measured {
                    stopped: Some(a), cost, ..
                }),
            ) => format!(
                ", rkl2 at least ~{} substeps (its trial stopped after {a:?} stages, {}: it cannot win)",
                count(*cost),
                over(steps)
            ),
            (Some(_), Some(m)) => format!(
                ", rkl2 {} stages (~{} substeps)",
                count(st.saturating_mul(n) as f64),
                count(m.cost)
            ),
            (Some(_), None) if measured => format!(
                ", rkl2 at least ~{} substeps (not tried: it cannot win)",
                count(self.rkl2_bound)
            ),
            _ => format!(
                ", rkl2 {} stages (~{} substeps)",
                count(st.saturating_mul(n) as f64),
                count(self.rkl2_model)
            ),
        };
        let imp_text = match (&self.imp, &self.imp_m) {
            (Some((i, it)), Some(Measured { stopped: Some(a), cost, .. })) => format!(
                ", implicit ({}) at least ~{cost:.0} substeps ({it} iterations per solve in a trial; its trial stopped after {a:?} applications, {}: it cannot win)",
                i.preconditioner_name(),
                over(steps)
            ),
            (Some((i, it)), Some(m)) => format!(
                ", implicit ({}) ~{:.0} applications ({it} iterations per solve in a trial{}; ~{:.0} substeps{})",
                i.preconditioner_name(),
                m.cost / i.cost_of(1),
                in_trial("applications", &m.trial, "; ", ""),
                m.cost,
                predicted(&m.trial)
            ),
            (Some((i, it)), None) if measured => format!(
                ", implicit ({}) at least ~{:.0} substeps ({it} iterations per solve in a trial; not tried further: it cannot win)",
                i.preconditioner_name(),
                self.imp_bound.unwrap_or(f64::INFINITY)
            ),
            (Some((i, it)), None) => format!(
                ", implicit ({}) ~{} applications ({it} iterations per solve in a trial; ~{:.0} substeps)",
                i.preconditioner_name(),
                controlled_applications(*it, self.controlled),
                self.imp_model.unwrap_or(f64::INFINITY)
            ),
            (None, _) => String::new(),
        };
        format!("per step euler {} substeps{rkl2_text}{imp_text}", count(self.substeps))
    }
}

#[cfg(test)]
mod tests {
    use super::{least_average, run_average};

    #[test]
    fn a_stopped_trial_bounds_the_run_average_from_below() {
        // every later step takes at least `least`: the bound never exceeds the run's average,
        // and is the average itself when the run is no longer than the steps known
        let apps = [1263, 573, 493];
        let least = 200.0;
        for steps in [Some(1), Some(2), Some(3), Some(8), Some(30), None] {
            let full = run_average(apps, steps);
            for j in 1..=3 {
                let lb = least_average(&apps[..j], least, steps);
                assert!(lb <= full + 1e-9, "{steps:?} after {j}: {lb} > {full}");
            }
        }
        assert_eq!(
            least_average(&apps[..1], least, Some(30)),
            (1263.0 + 29.0 * least) / 30.0
        );
        assert_eq!(least_average(&apps[..2], least, Some(2)), run_average(apps, Some(2)));
        assert_eq!(least_average(&apps[..1], least, Some(1)), 1263.0);
        assert_eq!(least_average(&apps[..2], least, None), least);
    }

    #[test]
    fn the_run_average_weighs_the_start_by_the_runs_length() {
        // implicit on the 50^3 box: a costly first step, then one sub-step per step
        let implicit = [551, 126, 21];
        let rkl2 = [939, 391, 337];
        assert_eq!(run_average(implicit, Some(1)), 551.0);
        assert_eq!(run_average(implicit, Some(2)), (551.0 + 126.0) / 2.0);
        assert_eq!(run_average(implicit, Some(10)), (551.0 + 126.0 + 8.0 * 21.0) / 10.0);
        assert_eq!(run_average(implicit, None), 21.0);
        // a multigrid application costs about 6.5 rkl2 stages: a short run takes the cheap
        // start, a long one the cheap steps
        let dearer = 6.5;
        assert!(run_average(rkl2, Some(3)) < dearer * run_average(implicit, Some(3)));
        assert!(run_average(rkl2, Some(200)) > dearer * run_average(implicit, Some(200)));
    }
}
