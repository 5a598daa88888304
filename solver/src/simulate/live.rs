//! Live inputs: tools and loads whose samples a client sends while the run steps (`eprop
//! serve`). The simulation keeps their histories; a feed appends samples before a step and
//! lets go of those no later time needs.

use super::Simulation;
use crate::config::tables::History;
use crate::config::Trajectory;
use anyhow::{anyhow, bail, Result};

impl Simulation {
    /// Which inputs are live, the tools first, then the loads, in the scenario's order (the
    /// entity numbers of `apply_live_samples`).
    pub fn live_inputs(&self) -> Vec<bool> {
        let mut live: Vec<bool> = self.tools.iter().map(|t| t.tool.live).collect();
        live.extend(self.loads.iter().map(|l| l.live));
        live
    }

    /// Empties the histories of the live inputs: a client's samples become their histories.
    pub fn start_live_inputs(&mut self) {
        for run in self.tools.iter_mut().filter(|r| r.tool.live) {
            run.tool.path = Trajectory::Table(History::empty());
        }
        for l in self.loads.iter_mut().filter(|l| l.live) {
            l.history = Some(History::empty());
        }
    }

    /// Appends samples (entity as numbered by `live_inputs`, [t, x, y, z]) to the live
    /// inputs' histories. Errors name a sample the caller should have refused (an input that
    /// is not live, a time that goes back).
    pub fn apply_live_samples(&mut self, samples: &[(u32, [f64; 4])]) -> Result<()> {
        let nt = self.tools.len();
        for &(e, row) in samples {
            let e = e as usize;
            let h = if e < nt {
                match &mut self.tools[e].tool.path {
                    Trajectory::Table(h) => h,
                    Trajectory::Linear { .. } => bail!("internal: live tool {e} has no history"),
                }
            } else {
                self.loads
                    .get_mut(e - nt)
                    .and_then(|l| l.history.as_mut())
                    .ok_or_else(|| anyhow!("internal: live load {} has no history", e - nt))?
            };
            h.push(row)
                .map_err(|m| anyhow!("internal: a sample the session accepted: {m}"))?;
        }
        Ok(())
    }

    /// Forgets the live inputs' samples that no time from t on needs.
    pub fn forget_live_before(&mut self, t: f64) {
        for run in self.tools.iter_mut().filter(|r| r.tool.live) {
            if let Trajectory::Table(h) = &mut run.tool.path {
                h.forget_before(t);
            }
        }
        for l in self.loads.iter_mut().filter(|l| l.live) {
            if let Some(h) = &mut l.history {
                h.forget_before(t);
            }
        }
    }
}
