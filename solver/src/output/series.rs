//! The output series of a run: the file created (or reopened to continue it), each output
//! step's fields collected from the owned nodes into this process's block of the global
//! node order (`BlockScatter`), and appended.

use crate::config::{Field, Precision};
use crate::diagnostics::{log_memory, median};
use crate::distribute::comm::Handle;
use crate::distribute::launch::{Agreed, EXIT_ERROR};
use crate::distribute::parts::{GlobalSizes, StableHash};
use crate::guard::safety::OutputLock;
use crate::simulate::Simulation;
use anyhow::{anyhow, Result};
use eprop_io::geom::norm;
use eprop_series::outcome::WriteFailed;
use eprop_series::vtkhdf::{Layout, SeriesSpec, SeriesWriter, CREATING, LIVE_SESSION, TABLE_HASH};
use std::path::Path;
use std::time::Instant;

/// Program name and version, stored in every series.
pub const VERSION: &str = concat!("eprop ", env!("CARGO_PKG_VERSION"));

/// The whole mesh's sizes as the series lays them out.
pub fn layout(sizes: &GlobalSizes) -> Layout {
    Layout {
        nodes: sizes.nodes,
        cells: sizes.cells,
        conn: sizes.conn,
    }
}

/// This process's block of each field (global node order, flattened), collected from the
/// owned nodes of every process (one all-to-all for every field together; every process calls).
pub fn field_blocks(sim: &Simulation, fields: &[Field]) -> Vec<Vec<f64>> {
    let no = sim.n_owned();
    let widths: Vec<usize> = fields.iter().map(|f| f.components()).collect();
    let w: usize = widths.iter().sum();
    // every field of a node side by side: one exchange for all of them
    let mut packed = Vec::with_capacity(no * w);
    for i in 0..no {
        for f in fields {
            match f {
                Field::Displacement => packed.extend_from_slice(&sim.u()[i]),
                Field::Velocity => packed.extend_from_slice(&sim.v()[i]),
                Field::Potential => packed.extend_from_slice(&sim.prop.phi[i]),
                Field::Energy => packed.push(norm(sim.prop.phi[i])),
            }
        }
    }
    let block = sim.blocks().collect(&packed, w, sim.comm());
    let rows = block.len() / w.max(1);
    let mut out: Vec<Vec<f64>> = widths.iter().map(|&c| Vec::with_capacity(rows * c)).collect();
    for row in block.chunks_exact(w.max(1)) {
        let mut at = 0;
        for (o, &c) in out.iter_mut().zip(&widths) {
            o.extend_from_slice(&row[at..at + c]);
            at += c;
        }
    }
    out
}

/// Checks that a path's directory exists before a long run starts.
pub fn check_output_dir(path: &Path) -> Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        return Err(anyhow!(
            "{}: the output directory does not exist; fix: create it or choose another [output] file / --output",
            path.display()
        ));
    }
    Ok(())
}

/// The room a series makes for the output steps after step `from` (and `from` itself when
/// `fresh`): all of them, or for an equilibrium run, whose length is not known, a first 64
/// (the file grows as the run goes on).
fn room(sim: &Simulation, from: u64, fresh: bool) -> usize {
    let every = sim.setup().output.every;
    let steps = crate::guard::limits::output_steps(from, sim.max_steps(), every, fresh) as usize;
    match sim.setup().time.stop {
        crate::config::Stop::Equilibrium { .. } => steps.min(64),
        _ => steps,
    }
}

/// A run's output series, open for appending.
pub struct Series {
    writer: SeriesWriter,
    fields: Vec<Field>,
    /// Seconds of every append of this run.
    appends: Vec<f64>,
    /// The simulation step of the last appended and of the last complete output step.
    appended_step: u64,
    complete_step: u64,
    /// The inverted cells and nodes inside tools of the output steps this run appended.
    pub(crate) folds: crate::guard::fold::Record,
}

impl Series {
    /// Creates the series of a simulation's `[output]` and writes its static part and the
    /// initial step; with `restart`, reopens the series instead and restores the simulation
    /// to its last complete step. Every process calls; under MPI they write collectively, on
    /// the simulation's communicator (`Comm::handle`). `claim`, the lock of the process that
    /// claimed the output, holds a created file's inode too (`OutputLock::hold_output`).
    /// `live`: the inputs come from a client (`serve`); the series is marked so
    /// (`eprop_series::vtkhdf::LIVE_SESSION`), and no restart continues it.
    pub fn start(
        sim: &mut Simulation,
        sizes: &GlobalSizes,
        restart: bool,
        live: bool,
        claim: Option<&OutputLock>,
    ) -> Result<Series> {
        let output = &sim.setup().output;
        let flush = output.flush;
        let fields = output.fields();
        let mut text_hash = StableHash::default();
        text_hash.bytes(sim.setup().scenario.text.as_bytes());
        // every table the scenario names is an input too: a restart refuses a changed one
        // (rank 0 reads them, as it read the scenario; an unreadable one hashes to 0)
        let named = sim.setup().scenario.tables();
        let mut hashes: Vec<f64> = named
            .iter()
            .map(|(_, input)| {
                let mut h = StableHash::default();
                match sim.comm().rank() == 0 {
                    true => std::fs::read(&input.path).map_or(0.0, |bytes| {
                        h.bytes(&bytes);
                        f64::from_bits(h.finish())
                    }),
                    false => 0.0,
                }
            })
            .collect();
        sim.comm().broadcast(0, &mut hashes);
        let tables: Vec<(String, u64)> = named
            .iter()
            .zip(&hashes)
            .map(|((name, _), h)| (format!("{TABLE_HASH}{name}"), h.to_bits()))
            .collect();
        let plan = sim.step_plan();
        let mut attrs = vec![
            ("dt", sim.dt()),
            ("h", plan.h),
            ("substeps", plan.per_step as f64),
            ("processes", sim.comm().size() as f64),
        ];
        if live {
            attrs.push((LIVE_SESSION, 1.0));
        }
        let mut ids = vec![("scenario_hash", text_hash.finish()), ("mesh_hash", sizes.mesh_hash)];
        ids.extend(tables.iter().map(|(n, h)| (n.as_str(), *h)));
        let spec = SeriesSpec {
            fields: fields.iter().map(|f| (f.name(), f.components())).collect(),
            ids,
            float32: output.precision == Precision::Float32,
            compression: output.compression,
            n_loads: sim.loads.len(),
            load_nodes: sim.loads.iter().map(|l| l.nodes[0] as u64).collect(),
            scenario: &sim.setup().scenario.text,
            version: VERSION,
            block_start: sim.blocks().start,
            block_len: sim.blocks().len,
            control_volumes: sim.vol_block(),
            output_steps: room(sim, sim.step(), true),
            attrs,
        };
        let file = output.file.clone();
        let io = sim.comm().handle().map(Handle::communicator);
        if restart {
            let (mut writer, resume) = SeriesWriter::reopen(&file, layout(sizes), &spec, io)?;
            // the norms too: the energy |phi| and max |u| of a component near f64::MAX overflow
            let finite = [&resume.u, &resume.v, &resume.phi].iter().all(|x| {
                x.chunks(3)
                    .all(|c| c.iter().all(|c| c.is_finite()) && c.iter().map(|c| c * c).sum::<f64>().sqrt().is_finite())
            });
            if !writer.all(finite) {
                return Err(Agreed::error(
                    EXIT_ERROR,
                    format!(
                        "{}: cannot restart: its last complete step (step {}) holds NaN or inf values (or values whose magnitude overflows), which a restart would continue; fix: find the cause (see the warnings of `eprop check`) and start a new run (--overwrite)",
                        file.display(),
                        resume.step
                    ),
                ));
            }
            sim.restore(resume.step, &resume.u, &resume.v, &resume.phi);
            // the energy account goes on from the restart step's row
            if let Some(e) = writer.energy_at(writer.steps_complete().saturating_sub(1))? {
                sim.resume_energy(e[0], e[2]);
            }
            // a step off the output grid (a run stopped by a signal, or a shorter run's last
            // step) is a restart point only: continuing drops it, so the series is the one an
            // uninterrupted run writes
            let every = sim.setup().output.every;
            if !resume.step.is_multiple_of(every) && resume.step < sim.max_steps() && writer.steps_written() > 1 {
                writer.forget_last()?;
            }
            // room for the rest of the run, made before its first step
            writer.reserve(writer.steps_complete() + room(sim, resume.step, false))?;
            writer.commit_every(flush);
            return Ok(Series {
                writer,
                fields,
                appends: Vec::new(),
                appended_step: resume.step,
                complete_step: resume.step,
                folds: Default::default(),
            });
        }
        let created =
            SeriesWriter::create_from(&file, layout(sizes), sim.static_mesh(), &spec, io).and_then(|mut writer| {
                // a new file is a new inode: the writer lock covers its hard links from now on
                if let Some(lock) = claim {
                    lock.hold_output(&file);
                }
                if !sim.tools.is_empty() {
                    writer.add_tools(sim.tools.len())?;
                }
                writer.add_checks(sim.tools.len(), sim.tool_energy().is_some())?;
                log_memory("the static output");
                writer.commit_every(flush);
                let mut series = Series {
                    writer,
                    fields,
                    appends: Vec::new(),
                    appended_step: sim.step(),
                    complete_step: sim.step(),
                    folds: Default::default(),
                };
                series.append(sim, true)?;
                log_memory("the first output step");
                Ok(series)
            });
        match created {
            // a file this run began holds no complete step: it goes (once every process has
            // closed it), so that running again needs no --overwrite
            Err(e) if e.downcast_ref::<WriteFailed>().is_some_and(|w| w.what != CREATING) => {
                if sim.comm().rank() == 0 {
                    let _ = std::fs::remove_file(&file);
                }
                Err(e)
            }
            // the creation itself failed (a full disk at the superblock): an empty file it
            // left holds nothing of anyone's and goes too; any other file stays as it is
            Err(e) if e.downcast_ref::<WriteFailed>().is_some() => {
                if sim.comm().rank() == 0 && std::fs::symlink_metadata(&file).is_ok_and(|m| m.is_file() && m.len() == 0)
                {
                    let _ = std::fs::remove_file(&file);
                }
                Err(e)
            }
            other => other,
        }
    }

    /// Appends the simulation's current step (every process calls): complete in the file at
    /// once with `commit`, else at the next commit (`[output] flush` seconds apart).
    pub fn append(&mut self, sim: &Simulation, commit: bool) -> Result<()> {
        let t = Instant::now();
        let data = field_blocks(sim, &self.fields);
        let refs: Vec<&[f64]> = data.iter().map(|d| d.as_slice()).collect();
        if !sim.tools.is_empty() {
            self.writer.append_tools(sim.time(), sim.step(), &sim.tool_states())?;
        }
        let checked = sim.inspect();
        self.writer.append_checks(
            sim.step(),
            checked.inverted,
            &checked.inside,
            checked.across,
            sim.tool_energy().map(|e| [e.work, e.stored, e.dissipated]),
        )?;
        self.folds.note(sim.time(), checked);
        let committed = self
            .writer
            .append(sim.time(), sim.step(), &refs, &sim.probes(), commit)?;
        self.appended_step = sim.step();
        if committed {
            self.complete_step = sim.step();
        }
        self.appends.push(t.elapsed().as_secs_f64());
        Ok(())
    }

    /// Makes every appended step complete in the file (every process calls).
    pub fn commit(&mut self) -> Result<()> {
        let t = Instant::now();
        self.writer.commit()?;
        self.complete_step = self.appended_step;
        if let Some(last) = self.appends.last_mut() {
            *last += t.elapsed().as_secs_f64();
        }
        Ok(())
    }

    /// The warnings of the first written step with inverted cells or nodes inside a tool, and
    /// of the first with nodes across a support, once each (every process calls:
    /// `guard::fold::Record::warnings`).
    pub fn fold_warnings(&mut self, sim: &Simulation) -> Vec<String> {
        self.folds.warnings(sim)
    }

    /// Whether steps were appended that are not complete in the file yet (the same on every
    /// process: commits are collective).
    pub fn pending(&self) -> bool {
        self.appended_step != self.complete_step
    }

    /// The simulation step of the last complete output step.
    pub fn complete_step(&self) -> u64 {
        self.complete_step
    }

    /// Seconds spent appending.
    pub fn seconds(&self) -> f64 {
        // + 0.0: none is 0, not the empty sum's -0
        self.appends.iter().sum::<f64>() + 0.0
    }

    /// Median seconds of one append over the first and over the last 100 appends.
    pub fn append_medians(&self) -> (f64, f64) {
        let k = self.appends.len().min(100);
        (
            median(&self.appends[..k]),
            median(&self.appends[self.appends.len() - k..]),
        )
    }

    pub fn path(&self) -> &Path {
        self.writer.path()
    }

    /// Output steps written (complete in the file after the next commit).
    pub fn steps_written(&self) -> usize {
        self.writer.steps_written()
    }

    /// Output steps complete in the file.
    pub fn steps_complete(&self) -> usize {
        self.writer.steps_complete()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::distribute::comm::Comm;
    use crate::testing::threads;

    #[test]
    fn a_missing_output_directory_is_named() {
        assert!(check_output_dir(Path::new("out.h5")).is_ok());
        assert!(check_output_dir(&std::env::temp_dir().join("x.h5")).is_ok());
        let e = check_output_dir(Path::new("/no/such/dir/out.h5"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/no/such/dir/out.h5") && e.contains("fix:"), "{e}");
    }

    #[test]
    fn fields_are_collected_into_blocks_of_the_global_order() {
        use crate::distribute::halo::BlockScatter;
        // 7 nodes over 3 processes, owned in a scrambled order; process r's block is
        // rows r*7/3 .. (r+1)*7/3 of the global order
        let owned: [&[u64]; 3] = [&[6, 0, 3], &[1, 5], &[4, 2]];
        let blocks = threads(3, |comm| {
            let gids = owned[comm.rank()];
            let b = BlockScatter::new(gids, 7, comm);
            let values: Vec<f64> = gids.iter().flat_map(|&g| [g as f64, -(g as f64)]).collect();
            let block = b.collect(&values, 2, comm);
            // and back to the owned order
            assert_eq!(b.distribute(&block, 2, comm), values);
            (b.start, b.len, block)
        });
        assert_eq!(
            blocks,
            [
                (0, 2, vec![0.0, -0.0, 1.0, -1.0]),
                (2, 2, vec![2.0, -2.0, 3.0, -3.0]),
                (4, 3, vec![4.0, -4.0, 5.0, -5.0, 6.0, -6.0]),
            ]
        );
    }
}
