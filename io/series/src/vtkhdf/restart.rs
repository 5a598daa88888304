//! A series reopened to continue it after its last complete step (`--restart`).

use super::create::make_count;
use super::{
    access, at, rows_of, values_set, Field, Layout, Resume, SeriesSpec, SeriesWriter, ToolSets, COUNT, LIVE_SESSION,
    STEP_SETS, TABLE_HASH,
};
use crate::outcome::Team;
use anyhow::{anyhow, Result};
use hdf5::{Dataset, File};
use ndarray::s;
use std::path::Path;

/// Refuses to continue a series whose identity attributes (`spec.ids`: the scenario, the mesh,
/// every table) differ from `spec`'s, or one in float32 (every process calls).
fn check_identity(t: &Team, ep: &hdf5::Group, spec: &SeriesSpec, path: &Path) -> Result<()> {
    let bad = |what: String| cannot_restart(path, what);
    let read = |what: &str| at(format!("reading the file to restart ({what})"));
    for (name, v) in &spec.ids {
        let got: u64 = t
            .settle_opt(read(name), ep.attr(name).and_then(|a| a.read_scalar()))?
            .ok_or_else(|| bad(format!("no {name} attribute")))?;
        if got != *v {
            return Err(match name.strip_prefix(TABLE_HASH) {
                Some(table) => anyhow!(
                    "{}: cannot restart: the table {table} changed since this file was written (its contents differ), so the continued series would mix two input histories; fix: restore {table} as it was, or start a new run (--overwrite)",
                    path.display()
                ),
                None => bad(format!("it was written for a different {}", name.trim_end_matches("_hash"))),
            });
        }
    }
    let live: f64 = t
        .settle_opt(read(LIVE_SESSION), ep.attr(LIVE_SESSION).and_then(|a| a.read_scalar()))?
        .unwrap_or(0.0);
    if live != 0.0 {
        return Err(anyhow!(
            "{}: cannot restart: `eprop serve` wrote it, and its client's samples (the live tools' and loads' inputs) are in no file, so a restart would continue it on the scenario's own paths and forces instead, as if the session had gone on that way; fix: start a new session or run in a new file (or --overwrite), or give the session's samples to `eprop run` as path and force tables",
            path.display()
        ));
    }
    let f32_file: u8 = t
        .settle_opt(read("float32"), ep.attr("float32").and_then(|a| a.read_scalar()))?
        .unwrap_or(0);
    if f32_file != 0 || spec.float32 {
        return Err(bad(
            "float32 output cannot restart exactly (precision = \"float64\" is)".into(),
        ));
    }
    Ok(())
}

/// The refusal of a restart for `what`.
fn cannot_restart(path: &Path, what: String) -> anyhow::Error {
    anyhow!(
        "{}: cannot restart: {what}; fix: restart with the scenario and mesh that wrote the file, or start a new run",
        path.display()
    )
}

/// `read` for `Team::settle`: what a failed read of the file to restart was.
fn read(what: &str) -> impl FnOnce() -> String {
    at(format!("reading the file to restart ({what})"))
}

/// The count of complete steps: the counter `/eprop/steps_complete` (with the dataset), or the
/// attribute of a series written before the counter was a dataset (every process calls).
fn read_count(t: &Team, ep: &hdf5::Group) -> Result<(i64, Option<Dataset>)> {
    match t.settle_opt(read(COUNT), ep.dataset(COUNT))? {
        Some(ds) => {
            let k = t.settle(read(COUNT), ds.read_raw::<i64>())?;
            Ok((k.first().copied().unwrap_or(0), Some(ds)))
        }
        None => Ok((
            t.settle(read(COUNT), ep.attr(COUNT).and_then(|a| a.read_scalar()))?,
            None,
        )),
    }
}

/// The datasets of a series to continue, as a writer without its counter and mirrors set:
/// fields, step tables, probes, cell offsets and tools (every process calls).
struct Opened {
    fields: Vec<Field>,
    steps: hdf5::Group,
    step_sets: Vec<Dataset>,
    values: Dataset,
    probes: [Dataset; 4],
    n_loads: usize,
    cell_offsets: Option<Dataset>,
    tools: Option<ToolSets>,
    checks: Option<super::checks::CheckSets>,
}

fn open_sets(t: &Team, file: &File, ep: &hdf5::Group, spec: &SeriesSpec, path: &Path) -> Result<Opened> {
    let bad = |what: String| cannot_restart(path, what);
    let top = t.settle(read("VTKHDF"), file.group("VTKHDF"))?;
    let pd = t.settle(read("PointData"), top.group("PointData"))?;
    let steps = t.settle(read("Steps"), top.group("Steps"))?;
    let pdo = t.settle(read("PointDataOffsets"), steps.group("PointDataOffsets"))?;
    let mut fields = Vec::new();
    for &(name, ncomp) in &spec.fields {
        let data = t
            .settle_opt(read(name), pd.dataset(name))?
            .ok_or_else(|| bad(format!("no field {name}")))?;
        let offsets = t.settle(read(name), pdo.dataset(name))?;
        fields.push(Field {
            name: name.to_string(),
            ncomp,
            data,
            offsets,
        });
    }
    let mut step_sets = Vec::new();
    for name in STEP_SETS {
        step_sets.push(t.settle(read(name), steps.dataset(name))?);
    }
    let values = t.settle(read("Values"), steps.dataset("Values"))?;
    let pr = t.settle(read("probes"), ep.group("probes"))?;
    let probe = |name: &str| t.settle(read(&format!("probes/{name}")), pr.dataset(name));
    let probes = [probe("time")?, probe("step")?, probe("force")?, probe("displacement")?];
    // the file's own count: a series written before (steps, 0, 3) keeps its one row of zeros
    let n_loads = probes[2].shape().get(1).copied().unwrap_or(0);
    let cell_offsets = match t.settle_opt(read("CellDataOffsets"), steps.group("CellDataOffsets"))? {
        Some(cdo) => t.settle_opt(read("CellDataOffsets/tag"), cdo.dataset("tag"))?,
        None => None,
    };
    let tools = match t.settle_opt(read("/eprop/tools"), ep.group("tools"))? {
        Some(g) => {
            let open = |name: &str| t.settle(read(name), g.dataset(name));
            let position = open("position")?;
            Some(ToolSets {
                n: position.shape().get(1).copied().unwrap_or(0),
                time: open("time")?,
                step: open("step")?,
                vectors: [position, open("force")?, open("displacement")?],
                scalars: [open("contact_area")?, open("indentation")?],
                contact_nodes: open("contact_nodes")?,
            })
        }
        None => None,
    };
    let checks = super::checks::CheckSets::open(t, ep)?;
    Ok(Opened {
        checks,
        fields,
        steps,
        step_sets,
        values,
        probes,
        n_loads,
        cell_offsets,
        tools,
    })
}

impl SeriesWriter {
    /// Opens a series written by `create` with the same `spec` to continue it after its last
    /// complete step (the counter's): rows written after it are overwritten as the run goes
    /// on, the count's mirrors are set to it, and a series written before this layout gets its
    /// counter. Every process calls under MPI. Refuses a file whose identity attributes
    /// (`spec.ids`) or layout differ, or whose count exceeds its rows.
    pub fn reopen(
        path: &Path,
        layout: Layout,
        spec: &SeriesSpec,
        comm: Option<&mpi::topology::SimpleCommunicator>,
    ) -> Result<(Self, Resume)> {
        let parallel = comm.is_some();
        let root = comm.is_none_or(|c| {
            use mpi::topology::Communicator;
            c.rank() == 0
        });
        let team = Team::new(path, comm);
        let t = &team;
        let file = t.settle_open(at("opening the file to restart"), access(comm).open_rw(path))?;
        t.hold(&file);
        let bad = |what: String| cannot_restart(path, what);
        // what a file may lack (then it is refused alike on every process)
        let ep = t
            .settle_opt(read("/eprop"), file.group("eprop"))?
            .ok_or_else(|| bad("no /eprop group (not an eprop series)".into()))?;
        check_identity(t, &ep, spec, path)?;
        let n: i64 = t.settle(
            read("NumberOfPoints"),
            file.dataset("VTKHDF/NumberOfPoints").and_then(|d| d.read_raw::<i64>()),
        )?[0];
        if n != layout.nodes as i64 {
            return Err(bad(format!("the file has {n} nodes, the mesh {}", layout.nodes)));
        }
        let (k, count) = read_count(t, &ep)?;
        if k < 1 {
            return Err(bad("the file holds no complete step".into()));
        }
        let o = open_sets(t, &file, &ep, spec, path)?;
        let nd = layout.nodes;
        // a count past the rows the file holds: changed by hand or damaged (the same answer
        // on every process: the shapes are the file's)
        for f in &o.fields {
            let rows = rows_of(&f.data);
            if (rows / nd.max(1)) < k as usize {
                return Err(anyhow!(
                    "{}: cannot restart: /eprop steps_complete = {k} but `{}` holds {} complete steps: the file was changed or damaged; fix: restore the file, or start a new run (--overwrite)",
                    path.display(),
                    f.name,
                    rows / nd.max(1)
                ));
            }
        }
        let k = k as usize;
        // the state at the last complete step
        let (b0, bl) = (spec.block_start, spec.block_len);
        let mut state = Vec::new();
        for name in ["displacement", "velocity", "potential"] {
            let f = o
                .fields
                .iter()
                .find(|f| f.name == name)
                .ok_or_else(|| bad(format!("the run did not write `{name}`, which a restart needs")))?;
            let rows = (k - 1) * nd + b0;
            let v = t.settle(read(name), f.data.read_slice_2d::<f64, _>(s![rows..rows + bl, ..]))?;
            state.push(v.iter().copied().collect::<Vec<f64>>());
        }
        let [probe_time, probe_step, probe_force, probe_disp] = o.probes;
        let last = |d: &Dataset| rows_of(d) >= k;
        if !last(&probe_time) || !last(&probe_step) {
            return Err(bad(format!("/eprop/probes holds fewer than its {k} complete steps")));
        }
        let time = t.settle(read("probes/time"), probe_time.read_slice_1d::<f64, _>(s![k - 1..k]))?[0];
        let step = t.settle(read("probes/step"), probe_step.read_slice_1d::<i64, _>(s![k - 1..k]))?[0];
        let count = match count {
            Some(c) => c,
            None => make_count(t, &ep, k, root)?,
        };
        let mut w = SeriesWriter {
            path: path.to_path_buf(),
            file,
            n_points: nd,
            block: (b0, bl),
            root,
            parallel,
            fields: o.fields,
            steps: o.steps,
            step_sets: o.step_sets,
            values: o.values,
            probe_time,
            probe_step,
            probe_force,
            probe_disp,
            count,
            n_loads: o.n_loads,
            n_steps: k,
            counted: k,
            room: 0,
            pending: Vec::new(),
            commit_every: 0.0,
            last_commit: std::time::Instant::now(),
            team,
            tools: o.tools,
            checks: o.checks,
            cell_offsets: o.cell_offsets,
        };
        w.room = w
            .per_step_sets()
            .map(|(d, per)| rows_of(d) / per.max(1))
            .min()
            .unwrap_or(0);
        if w.room < k {
            return Err(bad(format!(
                "its per-step tables hold fewer than its {k} complete steps"
            )));
        }
        w.recount()?;
        let mut it = state.into_iter();
        let resume = Resume {
            step: step as u64,
            time,
            u: it.next().unwrap_or_default(),
            v: it.next().unwrap_or_default(),
            phi: it.next().unwrap_or_default(),
        };
        Ok((w, resume))
    }

    /// Sets the count's mirrors to the counter's `counted` (every process calls): after a
    /// crash between them, or in a series written before this layout (whose `Values` is made
    /// again in one chunk of the room when it is smaller). Flushed and synced when anything
    /// changed.
    fn recount(&mut self) -> Result<()> {
        let k = self.counted;
        let t = &self.team;
        let what = || format!("counting {k} output steps");
        let ns: i64 = t.settle(what, self.steps.attr("NSteps").and_then(|a| a.read_scalar()))?;
        let attr: i64 = t.settle(
            what,
            self.file
                .group("eprop")
                .and_then(|g| g.attr(COUNT))
                .and_then(|a| a.read_scalar()),
        )?;
        let small = self.values.chunk().and_then(|c| c.first().copied()).unwrap_or(0) < self.room;
        if ns == k as i64 && attr == k as i64 && rows_of(&self.values) == k && !small {
            return Ok(());
        }
        // the times of the counted steps, as `Values` holds them (the same values), read by every
        // process: a read of one process alone leaves its metadata cache unlike the others',
        // and HDF5's collective calls that follow then wait forever
        let times = t
            .settle(what, self.probe_time.read_slice_1d::<f64, _>(s![..k]))?
            .to_vec();
        if small {
            t.settle(what, self.steps.unlink("Values"))?;
            self.values = t.settle(what, values_set(&self.steps, self.room, 0))?;
        }
        self.mirror(k, 0, &times)?;
        self.flush_sync(what)
    }

    /// Drops the last complete step (every process calls): the file then holds one step less.
    /// The counter first, so that a reader never counts a step whose rows will be overwritten.
    pub fn forget_last(&mut self) -> Result<()> {
        let k = self.n_steps.saturating_sub(1);
        let what = || format!("dropping output step {k}");
        self.write_count(k)?;
        self.flush_sync(what)?;
        self.mirror(k, k, &[])?;
        self.flush_sync(what)?;
        self.n_steps = k;
        self.counted = k;
        self.pending.clear();
        Ok(())
    }
}
