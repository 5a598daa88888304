//! `[time]`: when the run stops, and the optional fixed step sizes.

use super::values::opt_positive;
use super::Scenario;
use anyhow::Result;
use serde::{Deserialize, Serialize};
use toml::Spanned;

#[derive(Deserialize, Debug, Clone, Default)]
#[serde(deny_unknown_fields)]
pub struct TimeSec {
    pub steps: Option<u64>,
    #[serde(default, deserialize_with = "opt_positive")]
    pub end: Option<f64>,
    /// Stop once max |v| falls below this (at most `steps` steps, 10^6 without).
    #[serde(default, deserialize_with = "opt_positive")]
    pub equilibrium: Option<f64>,
    /// Mechanics step; chosen automatically when absent.
    #[serde(default, deserialize_with = "opt_positive")]
    pub dt: Option<f64>,
    /// Propagation substep; chosen automatically when absent.
    #[serde(default, deserialize_with = "opt_positive")]
    pub h: Option<f64>,
    /// The real-time mode: a fixed, bounded work per step chosen at setup (docs/realtime.md);
    /// absent: off for `eprop run`, on for `eprop serve`.
    pub realtime: Option<bool>,
    /// How the real-time mode solves its stages (docs/realtime.md); ignored outside it.
    #[serde(default)]
    pub realtime_solver: Option<RealtimeSolver>,
}

/// `[time] realtime_solver`: how the real-time mode solves the stages of its steps
/// (docs/realtime.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RealtimeSolver {
    /// Direct where it can be (CHOLMOD built in, the mesh within `linalg::direct`'s limits),
    /// else the fixed iterations.
    #[default]
    Auto,
    /// Direct, or an error that says why it cannot be.
    Direct,
    /// A fixed number of preconditioned conjugate-gradient iterations per stage (the
    /// preconditioner of `[integrator] preconditioner`, a multigrid unless it names one).
    Iterative,
}

impl RealtimeSolver {
    pub fn name(self) -> &'static str {
        match self {
            RealtimeSolver::Auto => "auto",
            RealtimeSolver::Direct => "direct",
            RealtimeSolver::Iterative => "iterative",
        }
    }
}

/// How a run stops.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Stop {
    Steps(u64),
    End(f64),
    /// max |v| below the tolerance, at most `max_steps` steps
    Equilibrium {
        tol: f64,
        max_steps: u64,
    },
}

/// `[time]` resolved.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Time {
    pub stop: Stop,
    pub dt: Option<f64>,
    pub h: Option<f64>,
    /// `realtime` as the scenario says it (None: the command's default, `Time::realtime`).
    pub realtime: Option<bool>,
    /// `realtime_solver` (auto where the scenario does not say).
    #[serde(default)]
    pub realtime_solver: RealtimeSolver,
}

impl Time {
    /// Whether the run is in the real-time mode (the scenario's say, else off).
    pub fn realtime(&self) -> bool {
        self.realtime.unwrap_or(false)
    }
}

/// The steps of a run to `end` with mechanics step dt: ceil(end / dt), an end a rounding
/// error past a whole number of steps not counting another (a float: its size is checked by
/// `guard::limits::steps` before it is made an integer).
pub fn steps_to(end: f64, dt: f64) -> f64 {
    (end / dt - 1e-9).ceil().max(0.0)
}

/// The stop condition from `steps`, `end` and `equilibrium` (the values are checked already).
pub fn resolve(sc: &Scenario, sec: &Spanned<TimeSec>) -> Result<Time> {
    let tm = sec.get_ref();
    let stop = match (tm.steps, tm.end, tm.equilibrium) {
        (Some(s), None, None) => Stop::Steps(s),
        (None, Some(e), None) => Stop::End(e),
        (s, None, Some(tol)) => Stop::Equilibrium {
            tol,
            max_steps: s.unwrap_or(1_000_000),
        },
        (None, None, None) => {
            return Err(sc.error_at(
                sec.span(),
                "time",
                "",
                "say when to stop: `steps = N`, `end = T` or `equilibrium = tol`",
            ))
        }
        _ => {
            return Err(sc.error_at(
                sec.span(),
                "time",
                "",
                "give one of `steps`, `end` or `equilibrium` (steps may cap equilibrium)",
            ))
        }
    };
    Ok(Time {
        stop,
        dt: tm.dt,
        h: tm.h,
        realtime: tm.realtime,
        realtime_solver: tm.realtime_solver.unwrap_or_default(),
    })
}

#[cfg(test)]
mod tests {
    use super::super::Scenario;
    use super::*;

    fn time(keys: &str) -> Result<Time, String> {
        let text = format!("[mesh]\nfile = \"m.msh\"\n[time]\n{keys}\n");
        let sc = Scenario::parse(std::path::Path::new("t.toml"), text).map_err(|e| e.to_string())?;
        resolve(&sc, &sc.file.time).map_err(|e| e.to_string())
    }

    #[test]
    fn one_stop_condition() {
        assert_eq!(time("steps = 5").unwrap().stop, Stop::Steps(5));
        assert_eq!(
            time("end = 2.5\ndt = 0.1").unwrap(),
            Time {
                stop: Stop::End(2.5),
                dt: Some(0.1),
                h: None,
                realtime: None,
                realtime_solver: RealtimeSolver::Auto,
            }
        );
        assert_eq!(
            time("equilibrium = 1e-3").unwrap().stop,
            Stop::Equilibrium {
                tol: 1e-3,
                max_steps: 1_000_000
            }
        );
        assert_eq!(
            time("equilibrium = 1e-3\nsteps = 7").unwrap().stop,
            Stop::Equilibrium {
                tol: 1e-3,
                max_steps: 7
            }
        );
        assert_eq!(
            time("steps = 1\nrealtime_solver = \"direct\"").unwrap().realtime_solver,
            RealtimeSolver::Direct
        );
        let bad = time("steps = 1\nrealtime_solver = \"cholesky\"").unwrap_err();
        assert!(
            bad.contains("realtime_solver") && bad.contains("\"auto\", \"direct\" or \"iterative\""),
            "{bad}"
        );
        let none = time("dt = 0.1").unwrap_err();
        assert!(none.starts_with("t.toml:3: [time]: say when to stop"), "{none}");
        assert!(none.contains("fix:"), "{none}");
        assert!(time("steps = 3\nend = 1.0").unwrap_err().contains("give one of"));
        let bad = time("steps = 3\nh = -1.0").unwrap_err();
        assert!(
            bad.starts_with("t.toml:5:5: [time] h: -1 must be a positive number"),
            "{bad}"
        );
    }
}
