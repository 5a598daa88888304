//! Output steps appended into the room made for them, and the commits that count them.

use super::{at, keep, resize, values_set, write_rows, SeriesWriter, ToolState, COUNT, MAX_ROOM};
use anyhow::{anyhow, Result};
use ndarray::{s, ArrayView3};

impl SeriesWriter {
    /// Seconds between commits: steps appended in between are written but counted (and
    /// synced) only at the next commit. 0 (the default) commits every step.
    pub fn commit_every(&mut self, seconds: f64) {
        self.commit_every = seconds.max(0.0);
    }

    /// Room for output step `n_steps` (every process calls): a full room grows (by as many
    /// steps as it holds, at most `MAX_ROOM`), after a commit.
    pub(super) fn make_slot(&mut self) -> Result<()> {
        if self.n_steps < self.room {
            return Ok(());
        }
        let more = self.room.clamp(64, MAX_ROOM);
        self.grow(self.room + more)
    }

    /// Room for `total` output steps in all (every process calls): a restart that runs
    /// longer than the run that wrote the file grows it once, before its first step (by at most
    /// `MAX_ROOM` steps; a longer run grows again as it goes).
    pub fn reserve(&mut self, total: usize) -> Result<()> {
        let target = total.min(self.room + MAX_ROOM);
        if target > self.room || self.values_chunk() < self.room {
            self.grow(target.max(self.room))?;
        }
        Ok(())
    }

    /// Entries in a chunk of `Values` (its extent must stay in its one chunk, `values_set`).
    fn values_chunk(&self) -> usize {
        self.values.chunk().and_then(|c| c.first().copied()).unwrap_or(0)
    }

    /// Grows every per-step dataset to room for `room` steps (every process calls): the steps
    /// written are committed first, then the datasets grow (their new chunks allocated now),
    /// `Values` is made again in one chunk of the new room, and the file is flushed and synced,
    /// all before the next step is written. This changes HDF5's metadata (ARCHITECTURE.md:
    /// the one case outside the crash guarantee).
    fn grow(&mut self, room: usize) -> Result<()> {
        self.commit()?;
        let t = &self.team;
        let what = || format!("making room for {room} output steps");
        let mut grown = Ok(());
        for (ds, per) in self.per_step_sets() {
            if super::rows_of(ds) < room * per {
                keep(&mut grown, resize(ds, room * per));
            }
        }
        t.settle(what, grown)?;
        if self.values_chunk() < room {
            let k = self.counted;
            t.settle(what, self.steps.unlink("Values"))?;
            self.values = t.settle(what, values_set(&self.steps, room, k))?;
            // read by every process: a read of one process alone leaves its metadata cache
            // unlike the others', and HDF5's collective calls that follow then wait forever
            let times = t
                .settle(what, self.probe_time.read_slice_1d::<f64, _>(s![..k]))?
                .to_vec();
            let written = match self.root && k > 0 {
                true => self.values.write_slice(&times, s![..k]),
                false => Ok(()),
            };
            t.settle(what, written)?;
        }
        self.flush_sync(what)?;
        self.room = room;
        Ok(())
    }

    /// Writes the tools' rows of the next output step (every process calls; rank 0's rows are
    /// written): call before `append`, which completes the step. A failure is a `WriteFailed`
    /// on every process.
    pub fn append_tools(&mut self, time: f64, step: u64, rows: &[ToolState]) -> Result<()> {
        self.make_slot()?;
        let (k, root) = (self.n_steps, self.root);
        let tt = self
            .tools
            .as_ref()
            .ok_or_else(|| anyhow!("internal: the series has no tools"))?;
        if rows.len() != tt.n {
            return Err(anyhow!("internal: {} tool rows for {} tools", rows.len(), tt.n));
        }
        let what = || format!("writing the tools of output step {k} (step {step})");
        let n = tt.n;
        let rows_of_root = || -> hdf5::Result<()> {
            tt.time.write_slice(&[time], s![k..k + 1])?;
            tt.step.write_slice(&[step as i64], s![k..k + 1])?;
            let pick = |f: fn(&ToolState) -> [f64; 3]| rows.iter().flat_map(f).collect::<Vec<f64>>();
            let vectors = [pick(|r| r.position), pick(|r| r.force), pick(|r| r.displacement)];
            for (d, v) in tt.vectors.iter().zip(&vectors) {
                let view = ArrayView3::from_shape((1, n, 3), v).map_err(hdf5::Error::from)?;
                d.write_slice(view, s![k..k + 1, .., ..])?;
            }
            let area: Vec<f64> = rows.iter().map(|r| r.contact_area).collect();
            let depth: Vec<f64> = rows.iter().map(|r| r.indentation).collect();
            for (d, v) in tt.scalars.iter().zip([area, depth]) {
                let view = ndarray::ArrayView2::from_shape((1, n), &v).map_err(hdf5::Error::from)?;
                d.write_slice(view, s![k..k + 1, ..])?;
            }
            let count: Vec<i64> = rows.iter().map(|r| r.contact_nodes as i64).collect();
            let view = ndarray::ArrayView2::from_shape((1, n), &count).map_err(hdf5::Error::from)?;
            tt.contact_nodes.write_slice(view, s![k..k + 1, ..])
        };
        self.team.settle(what, if root { rows_of_root() } else { Ok(()) })
    }

    /// Appends one output step (every process calls): `data[f]` holds field f for this
    /// process's block of nodes (node-major, components interleaved); `probes[l]` = (applied
    /// force, contact displacement) of load l (used on rank 0). The rows go to the step's room
    /// (nothing but rows of uncounted steps changes). The step is then committed when `commit`
    /// is true, when it is the first, or when the commit interval has passed (rank 0's clock
    /// decides for every process); returns whether it was. A failure at any point leaves the
    /// file at its last commit; a failure is a `WriteFailed` on every process.
    pub fn append(
        &mut self,
        time: f64,
        step: u64,
        data: &[&[f64]],
        probes: &[([f64; 3], [f64; 3])],
        commit: bool,
    ) -> Result<bool> {
        self.make_slot()?;
        let k = self.n_steps;
        let n = self.n_points;
        let (b0, bl) = self.block;
        let root = self.root;
        let t = &self.team;
        let what = || format!("writing output step {k} (step {step})");
        // the rows, collectively: one agreement per field
        for (f, d) in self.fields.iter().zip(data) {
            t.settle(what, write_rows(&f.data, k * n + b0, bl, f.ncomp, d, self.parallel))?;
        }
        let nl = self.n_loads;
        let mut fr = vec![0.0; nl * 3];
        let mut ds = vec![0.0; nl * 3];
        for (l, (f, u)) in probes.iter().enumerate().take(nl) {
            fr[3 * l..3 * l + 3].copy_from_slice(f);
            ds[3 * l..3 * l + 3].copy_from_slice(u);
        }
        // the field offsets and the small per-step tables, from rank 0 alone (independent writes)
        let tables = || -> hdf5::Result<()> {
            for f in &self.fields {
                f.offsets.write_slice(&[(k * n) as i64], s![k..k + 1])?;
            }
            for (i, set) in self.step_sets.iter().enumerate() {
                set.write_slice(&[if i == 1 { 1i64 } else { 0 }], s![k..k + 1])?;
            }
            if let Some(c) = &self.cell_offsets {
                c.write_slice(&[0i64], s![k..k + 1])?;
            }
            self.probe_time.write_slice(&[time], s![k..k + 1])?;
            self.probe_step.write_slice(&[step as i64], s![k..k + 1])?;
            for (dset, v) in [(&self.probe_force, &fr), (&self.probe_disp, &ds)]
                .into_iter()
                .filter(|_| nl > 0)
            {
                let view = ArrayView3::from_shape((1, nl, 3), v).map_err(hdf5::Error::from)?;
                dset.write_slice(view, s![k..k + 1, .., ..])?;
            }
            Ok(())
        };
        t.settle(what, if root { tables() } else { Ok(()) })?;
        self.n_steps = k + 1;
        self.pending.push(time);
        let due = commit
            || self.counted == 0
            || self.commit_every <= 0.0
            || self.last_commit.elapsed().as_secs_f64() >= self.commit_every;
        if self.team.root_decides(due) {
            self.commit()?;
            return Ok(true);
        }
        Ok(false)
    }

    /// Sets the mirrors of the count to `k` (every process calls): `Values` to `k` entries, of
    /// which those from `from` on are `times` (rank 0 writes), `NSteps` and the `steps_complete`
    /// attribute. They reach the file at the next flush.
    pub(super) fn mirror(&self, k: usize, from: usize, times: &[f64]) -> Result<()> {
        let t = &self.team;
        let what = || format!("counting {k} output steps");
        t.settle(what, resize(&self.values, k))?;
        let written = match self.root && k > from {
            true => self.values.write_slice(times, s![from..k]),
            false => Ok(()),
        };
        t.settle(what, written)?;
        let ns = k as i64;
        let mut counted = self.steps.attr("NSteps").and_then(|a| a.write_scalar(&ns));
        keep(
            &mut counted,
            self.file
                .group("eprop")
                .and_then(|g| g.attr(COUNT))
                .and_then(|a| a.write_scalar(&ns)),
        );
        t.settle(what, counted)
    }

    /// Writes the count of complete steps, `k` (every process calls; rank 0 writes it): one
    /// write of 8 bytes at the counter's fixed place.
    pub(super) fn write_count(&self, k: usize) -> Result<()> {
        let written = match self.root {
            true => self.count.write(&[k as i64]),
            false => Ok(()),
        };
        self.team.settle(|| format!("counting {k} output steps"), written)
    }

    /// Makes every appended step complete in the file (every process calls; nothing to do
    /// when none is pending). The rows were written when appended; the mirrors of the count
    /// (`Values`, `NSteps`, the attribute) are set, the file is flushed and synced, and then
    /// the counter alone is written, flushed and synced: a crash at any point leaves the file
    /// at its previous commit or at this one. Under MPI-IO each flush is a sync on every process.
    pub fn commit(&mut self) -> Result<()> {
        if self.counted == self.n_steps {
            return Ok(());
        }
        let k = self.n_steps;
        let what = format!("completing output steps {} to {}", self.counted, k - 1);
        self.mirror(k, self.counted, &self.pending)?;
        self.flush_sync(at(&what))?;
        self.write_count(k)?;
        self.flush_sync(at(&what))?;
        self.counted = k;
        self.pending.clear();
        self.last_commit = std::time::Instant::now();
        Ok(())
    }
}
