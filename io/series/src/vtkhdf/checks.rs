//! `/eprop/checks`: what each output step's state says of itself, a row per output step:
//! `step`, `inverted` (the cells the deformation inverted) and, with tools, `inside` (output
//! steps, tools: the nodes inside each tool). Written by rank 0 into the room made at creation,
//! before the step's commit, like the tools' rows.

use super::{at, table, SeriesWriter};
use anyhow::{anyhow, Result};
use hdf5::Dataset;
use ndarray::s;

/// The datasets of `/eprop/checks`.
pub(super) struct CheckSets {
    step: Dataset,
    inverted: Dataset,
    /// (steps, tools); absent without tools
    inside: Option<Dataset>,
}

impl CheckSets {
    /// Every dataset, each with one row per output step.
    pub(super) fn datasets(&self) -> impl Iterator<Item = &Dataset> {
        [&self.step, &self.inverted].into_iter().chain(&self.inside)
    }

    /// The group of a series to continue (every process calls): None in a series written
    /// before it was stored (its steps then get no checks).
    pub(super) fn open(t: &crate::outcome::Team, ep: &hdf5::Group) -> Result<Option<CheckSets>> {
        let read = |what: &str| at(format!("reading /eprop/checks/{what}"));
        let Some(g) = t.settle_opt(read(""), ep.group("checks"))? else {
            return Ok(None);
        };
        Ok(Some(CheckSets {
            step: t.settle(read("step"), g.dataset("step"))?,
            inverted: t.settle(read("inverted"), g.dataset("inverted"))?,
            inside: t.settle_opt(read("inside"), g.dataset("inside"))?,
        }))
    }
}

impl SeriesWriter {
    /// Adds `/eprop/checks` to a new series, before its first step (every process calls),
    /// with `inside` for `tools` tools (none without).
    pub fn add_checks(&mut self, tools: usize) -> Result<()> {
        if self.n_steps > 0 {
            return Err(anyhow!("internal: the checks are added to a new series"));
        }
        let t = &self.team;
        let room = self.room;
        let c1 = room.clamp(1, 1024);
        let mk = |what: &str| at(format!("creating the output (/eprop/checks/{what})"));
        let ep = t.settle(mk(""), self.file.group("eprop"))?;
        let g = t.settle(mk(""), ep.create_group("checks"))?;
        let sets = CheckSets {
            step: t.settle(mk("step"), table::<i64>(&g, "step", room, &[], c1))?,
            inverted: t.settle(mk("inverted"), table::<i64>(&g, "inverted", room, &[], c1))?,
            inside: match tools {
                0 => None,
                n => Some(t.settle(mk("inside"), table::<i64>(&g, "inside", room, &[n], room.clamp(1, 256)))?),
            },
        };
        t.settle(at("writing the output (flush)"), self.file.flush())?;
        self.checks = Some(sets);
        Ok(())
    }

    /// Writes the checks' row of the next output step (every process calls; rank 0's values
    /// are written): call before `append`, which completes the step. Nothing in a series
    /// without them.
    pub fn append_checks(&mut self, step: u64, inverted: u64, inside: &[u64]) -> Result<()> {
        self.make_slot()?;
        let (k, root) = (self.n_steps, self.root);
        let Some(cs) = &self.checks else {
            return Ok(());
        };
        let what = || format!("writing the checks of output step {k} (step {step})");
        let rows = || -> hdf5::Result<()> {
            cs.step.write_slice(&[step as i64], s![k..k + 1])?;
            cs.inverted.write_slice(&[inverted as i64], s![k..k + 1])?;
            if let Some(d) = &cs.inside {
                let v: Vec<i64> = inside.iter().map(|&x| x as i64).collect();
                if v.len() != d.shape().get(1).copied().unwrap_or(0) {
                    return Err(format!("internal: {} counts for {:?}", v.len(), d.shape()).into());
                }
                let view = ndarray::ArrayView2::from_shape((1, v.len()), &v).map_err(hdf5::Error::from)?;
                d.write_slice(view, s![k..k + 1, ..])?;
            }
            Ok(())
        };
        self.team.settle(what, if root { rows() } else { Ok(()) })
    }
}
