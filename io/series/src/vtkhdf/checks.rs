//! `/eprop/checks`: what each output step's state says of itself, a row per output step:
//! `step`, `inverted` (the cells the deformation inverted), `across` (the nodes across a
//! support's plane) and, with tools, `inside` (output steps, tools: the nodes inside each tool);
//! with kinematic tools, `/eprop/energy` (`work`, `stored`, `dissipated`: their energy account,
//! cumulative). Written by rank 0 into the room made at creation, before the step's commit,
//! like the tools' rows.

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
    /// absent in a series written before it was stored
    across: Option<Dataset>,
    /// `/eprop/energy`: work, stored, dissipated; absent without a kinematic tool
    energy: Option<[Dataset; 3]>,
}

/// The datasets of `/eprop/energy`, in the order of `append_checks`'s energy.
const ENERGY: [&str; 3] = ["work", "stored", "dissipated"];

impl CheckSets {
    /// Every dataset, each with one row per output step.
    pub(super) fn datasets(&self) -> impl Iterator<Item = &Dataset> {
        [&self.step, &self.inverted]
            .into_iter()
            .chain(&self.inside)
            .chain(&self.across)
            .chain(self.energy.iter().flatten())
    }

    /// The group of a series to continue (every process calls): None in a series written
    /// before it was stored (its steps then get no checks).
    pub(super) fn open(t: &crate::outcome::Team, ep: &hdf5::Group) -> Result<Option<CheckSets>> {
        let read = |what: &str| at(format!("reading /eprop/checks/{what}"));
        let Some(g) = t.settle_opt(read(""), ep.group("checks"))? else {
            return Ok(None);
        };
        let energy = match t.settle_opt(at("reading /eprop/energy"), ep.group("energy"))? {
            Some(e) => {
                let open = |what: &str| t.settle(at(format!("reading /eprop/energy/{what}")), e.dataset(what));
                Some([open(ENERGY[0])?, open(ENERGY[1])?, open(ENERGY[2])?])
            }
            None => None,
        };
        Ok(Some(CheckSets {
            step: t.settle(read("step"), g.dataset("step"))?,
            inverted: t.settle(read("inverted"), g.dataset("inverted"))?,
            inside: t.settle_opt(read("inside"), g.dataset("inside"))?,
            across: t.settle_opt(read("across"), g.dataset("across"))?,
            energy,
        }))
    }

    /// The energy account's row `k` (work, stored, dissipated), or None without one (every
    /// process calls and reads).
    pub(super) fn energy_row(&self, t: &crate::outcome::Team, k: usize) -> Result<Option<[f64; 3]>> {
        let Some(sets) = &self.energy else {
            return Ok(None);
        };
        let mut row = [0.0; 3];
        for (d, x) in sets.iter().zip(&mut row) {
            let v: Vec<f64> = t.settle(
                at(format!("reading /eprop/energy row {k}")),
                d.read_slice_1d::<f64, _>(s![k..k + 1]).map(|a| a.to_vec()),
            )?;
            *x = v.first().copied().unwrap_or(0.0);
        }
        Ok(Some(row))
    }
}

impl SeriesWriter {
    /// Adds `/eprop/checks` to a new series, before its first step (every process calls),
    /// with `inside` for `tools` tools (none without), and `/eprop/energy` with `energy`.
    pub fn add_checks(&mut self, tools: usize, energy: bool) -> Result<()> {
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
            across: Some(t.settle(mk("across"), table::<i64>(&g, "across", room, &[], c1))?),
            energy: match energy {
                false => None,
                true => {
                    let mk = |what: &str| at(format!("creating the output (/eprop/energy/{what})"));
                    let e = t.settle(mk(""), ep.create_group("energy"))?;
                    let one = |what: &str| t.settle(mk(what), table::<f64>(&e, what, room, &[], c1));
                    Some([one(ENERGY[0])?, one(ENERGY[1])?, one(ENERGY[2])?])
                }
            },
        };
        t.settle(at("writing the output (flush)"), self.file.flush())?;
        self.checks = Some(sets);
        Ok(())
    }

    /// Writes the checks' row of the next output step (every process calls; rank 0's values
    /// are written): call before `append`, which completes the step. Nothing in a series
    /// without them. `energy`: work, stored, dissipated (a series without `/eprop/energy`
    /// ignores it).
    pub fn append_checks(
        &mut self,
        step: u64,
        inverted: u64,
        inside: &[u64],
        across: u64,
        energy: Option<[f64; 3]>,
    ) -> Result<()> {
        self.make_slot()?;
        let (k, root) = (self.n_steps, self.root);
        let Some(cs) = &self.checks else {
            return Ok(());
        };
        let what = || format!("writing the checks of output step {k} (step {step})");
        let rows = || -> hdf5::Result<()> {
            cs.step.write_slice(&[step as i64], s![k..k + 1])?;
            cs.inverted.write_slice(&[inverted as i64], s![k..k + 1])?;
            if let Some(d) = &cs.across {
                d.write_slice(&[across as i64], s![k..k + 1])?;
            }
            if let (Some(sets), Some(e)) = (&cs.energy, energy) {
                for (d, x) in sets.iter().zip(e) {
                    d.write_slice(&[x], s![k..k + 1])?;
                }
            }
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

    /// The energy account (work, stored, dissipated) of output step `k`, or None in a series
    /// without one (every process calls).
    pub fn energy_at(&self, k: usize) -> Result<Option<[f64; 3]>> {
        match &self.checks {
            Some(cs) => cs.energy_row(&self.team, k),
            None => Ok(None),
        }
    }
}
