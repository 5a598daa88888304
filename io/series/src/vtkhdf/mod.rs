//! Time-series output in the VTKHDF 2.x temporal UnstructuredGrid layout.
//!
//! `/VTKHDF` holds the static mesh once (one partition) and the point data of every output
//! step along the first axis; `/VTKHDF/Steps` maps step k to the rows `k*N .. (k+1)*N` of each
//! point-data array (the mesh offsets stay 0). `/eprop` holds what VTK does not model: the
//! scenario text, the program version, control volumes, input node ids, per-load probes, the
//! tools' rows, the checks of each step's state (inverted cells, nodes inside tools) and the
//! count of complete steps.
//!
//! The layout keeps every complete step readable whatever write a crash interrupts:
//! - **Room made at creation.** Every per-step dataset is chunked, allocated early and sized
//!   for the run's output steps (its *room*) when the file is created, so a step's rows go to
//!   space whose place in the file, chunk index and dataspace never change: HDF5's metadata of
//!   those datasets is final from the start.
//! - **The counter.** The count of complete steps is `/eprop/steps_complete`, an 8-byte
//!   contiguous dataset allocated at creation. A commit writes it last and alone: one pwrite at
//!   a fixed address, after the rows and everything else were flushed and synced.
//! - **Mirrors.** What VTK reads besides the rows (`NSteps`, and `Steps/Values`, whose extent
//!   must equal `NSteps` or vtkHDFReader overruns a buffer) and the `steps_complete` attribute of
//!   `/eprop` (for readers of older series) follow the count. A commit writes them before the
//!   counter, after the rows, so they may count one step more than the counter after a crash,
//!   never a step whose rows were not written; a restart sets them from the counter.
//! - **No cached raw data.** The chunk cache and the sieve buffer are off, so every write of
//!   rows is a pwrite when it is made: between commits the file changes only in rows of steps
//!   not yet counted, and HDF5's metadata cache holds nothing dirty that it could write at a
//!   time of its choosing.
//!
//! Growing the room (a run longer than its room: an equilibrium run past its first estimate, a
//! restart that extends a run, a series written before this layout) changes metadata: it is
//! done between commits, flushed and synced before the next step's rows; a crash inside it is
//! the one case this layout does not cover.

mod append;
mod checks;
mod create;
mod mesh;
mod read;
mod restart;

pub use create::{StaticMesh, CREATING};
pub use mesh::{block, read_slab, write_mesh_file, MeshSlab};
pub use read::{add_dataset, kind_of, read_mesh, read_scenario, read_step, write_csr, Kind, SeriesFile};

use crate::outcome::Team;
use hdf5::dataset::{AllocTime, FillTime};
use hdf5::{Dataset, Extent, File};
use std::path::{Path, PathBuf};

/// Sizes of the whole mesh (every process knows them; only one holds the mesh itself).
#[derive(Clone, Copy, Debug)]
pub struct Layout {
    pub nodes: usize,
    pub cells: usize,
    pub conn: usize,
}

impl Layout {
    pub fn of(mesh: &eprop_io::mesh::Mesh) -> Layout {
        Layout {
            nodes: mesh.n_nodes(),
            cells: mesh.n_cells(),
            conn: mesh.conn.len(),
        }
    }
}

/// Prefix of the identity attribute that holds the hash of a table the scenario names
/// (`table_hash:forces.csv`): a restart refuses a file whose table changed.
pub const TABLE_HASH: &str = "table_hash:";

/// An attribute of `/eprop` (1) on a series whose inputs a client sent (`eprop serve`): its
/// samples are in no file, so a restart refuses it.
pub const LIVE_SESSION: &str = "live_session";

/// What a series holds besides the mesh.
pub struct SeriesSpec<'a> {
    /// Point arrays written every output step: (name, components).
    pub fields: Vec<(&'a str, usize)>,
    /// Number of loads (probes per step).
    pub n_loads: usize,
    /// Contact node of each load (input order index), stored once.
    pub load_nodes: Vec<u64>,
    /// The scenario text, stored verbatim (UTF-8 bytes).
    pub scenario: &'a str,
    /// Program name and version.
    pub version: &'a str,
    /// This process's rows of the output: `block_start..block_start + block_len`.
    pub block_start: usize,
    pub block_len: usize,
    /// Control volume V_i of each node of this process's block.
    pub control_volumes: &'a [f64],
    /// Extra scalar attributes on `/eprop` (name, value).
    pub attrs: Vec<(&'a str, f64)>,
    /// Identity attributes on `/eprop` (name, value), checked by `reopen`.
    pub ids: Vec<(&'a str, u64)>,
    /// Store the point arrays as float32 (computed values are float64).
    pub float32: bool,
    /// gzip level of the point arrays (0: off).
    pub compression: u8,
    /// Output steps the run writes, the first included: the room made at creation (at most
    /// `MAX_ROOM`; more grow it).
    pub output_steps: usize,
}

/// The most output steps a series makes room for at once: the chunk index of the room is
/// written when it is made (a few MiB for a mesh of one chunk per field and step; 0.09 s for
/// 20,001 steps of the cylinder), and the unwritten room takes no disk space where the file
/// system keeps sparse files.
pub const MAX_ROOM: usize = 1 << 16;

/// What a tool did at the end of a mechanics step (the same on every process): the one record
/// of a tool's reading, which the simulation fills (`eprop::simulate::contact`), the series
/// writes as the tool's row of an output step (`/eprop/tools`) and the run's summary reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ToolState {
    /// The tool position (sphere centre, punch face centre) at the step's time.
    pub position: [f64; 3],
    /// The force the tool exerts on the organ (the kinematic law: the model's reaction at the
    /// nodes it holds; the elastic foundation: F = -sum_i p_i A_i over the pressed surface
    /// nodes, docs/tools.md; the organ pushes back on the tool with its opposite).
    pub force: [f64; 3],
    /// Surface nodes in contact (the elastic foundation: a contact pressure p_i > 0).
    pub contact_nodes: u64,
    /// sum of |A_i| over those nodes: the contact area.
    pub contact_area: f64,
    /// How deep the tool is below the undeformed surface along its path: the largest distance
    /// it must move back along its direction of motion until it overlaps no rest surface node
    /// (negative: the gap it must still travel; -inf when its path meets no surface node).
    pub indentation: f64,
    /// The contact nodes' displacement, mean weighted by |A_i| (zero without contact).
    pub displacement: [f64; 3],
}

/// The per-step datasets of `/eprop/tools`: per output step, and per step and tool.
struct ToolSets {
    n: usize,
    time: Dataset,
    step: Dataset,
    /// (steps, tools, 3): position, force, displacement
    vectors: [Dataset; 3],
    /// (steps, tools): contact_area, indentation
    scalars: [Dataset; 2],
    /// (steps, tools)
    contact_nodes: Dataset,
}

impl ToolSets {
    /// Every dataset, each with one row per output step.
    fn datasets(&self) -> impl Iterator<Item = &Dataset> {
        [&self.time, &self.step]
            .into_iter()
            .chain(&self.vectors)
            .chain(&self.scalars)
            .chain([&self.contact_nodes])
    }
}

struct Field {
    name: String,
    ncomp: usize,
    data: Dataset,
    offsets: Dataset,
}

/// Appends output steps to one VTKHDF file. Under MPI every process opens the file (MPI-IO),
/// makes the same metadata calls, and writes its own block of rows of every point array in
/// one collective transfer; the static mesh and the small per-step tables come from rank 0.
pub struct SeriesWriter {
    path: PathBuf,
    file: File,
    n_points: usize,
    block: (usize, usize),
    root: bool,
    parallel: bool,
    fields: Vec<Field>,
    steps: hdf5::Group,
    step_sets: Vec<Dataset>,
    /// `/VTKHDF/Steps/Values`: a mirror of the count (its extent is `NSteps`).
    values: Dataset,
    probe_time: Dataset,
    probe_step: Dataset,
    probe_force: Dataset,
    probe_disp: Dataset,
    /// `/eprop/steps_complete`: the count of complete steps.
    count: Dataset,
    n_loads: usize,
    /// Output steps whose rows are written.
    n_steps: usize,
    /// Output steps counted complete in the file (`steps_complete`): the rest are written but
    /// not yet synced and counted.
    counted: usize,
    /// Output steps the per-step datasets have room for.
    room: usize,
    /// Times of the steps written since the last commit (`Values` gets them at the commit).
    pending: Vec<f64>,
    /// Seconds between commits; 0 commits every step.
    commit_every: f64,
    last_commit: std::time::Instant,
    /// The writing processes; every call's outcome is agreed through it.
    team: Team,
    tools: Option<ToolSets>,
    /// `/eprop/checks` (`checks.rs`); absent in series written before it was stored.
    checks: Option<checks::CheckSets>,
    /// `/VTKHDF/Steps/CellDataOffsets/tag`: the cell tags are static (offset 0 at every
    /// step); absent in series written before they were stored.
    cell_offsets: Option<Dataset>,
}

/// The state stored at the last complete step of a series (this process's block).
pub struct Resume {
    pub step: u64,
    pub time: f64,
    pub u: Vec<f64>,
    pub v: Vec<f64>,
    pub phi: Vec<f64>,
}

/// The per-step tables of `/VTKHDF/Steps` besides `Values`.
const STEP_SETS: [&str; 5] = [
    "PartOffsets",
    "NumberOfParts",
    "PointOffsets",
    "CellOffsets",
    "ConnectivityIdOffsets",
];

/// The name of the counter under `/eprop` (a dataset; also an attribute there, its mirror).
const COUNT: &str = "steps_complete";

/// `what` as a message maker for `Team::settle`.
fn at(what: impl std::fmt::Display) -> impl FnOnce() -> String {
    move || what.to_string()
}

/// A per-step table of `room` rows (room for its steps; `tail`: the other dimensions),
/// chunked along the first axis and allocated early: its chunks and their index are written
/// when it is made (or grown), never by a step.
fn table<T: hdf5::H5Type>(
    group: &hdf5::Group,
    name: &str,
    room: usize,
    tail: &[usize],
    chunk_rows: usize,
) -> hdf5::Result<Dataset> {
    let mut ext = vec![Extent::resizable(room)];
    let mut chunk = vec![chunk_rows.max(1)];
    for &t in tail {
        // an empty dimension (no loads: (steps, 0, 3)) has a chunk of 1, which HDF5 allows only
        // on a dimension that may grow
        ext.push(if t == 0 { Extent::resizable(0) } else { Extent::fixed(t) });
        chunk.push(t.max(1));
    }
    group
        .new_dataset::<T>()
        .chunk(chunk)
        .shape(ext)
        .alloc_time(Some(AllocTime::Early))
        .fill_time(FillTime::Never)
        .create(name)
}

/// `/VTKHDF/Steps/Values` with `steps` entries, in one chunk of `room` entries: its extent
/// follows the count (VTK reads exactly `NSteps` of it) and never leaves the chunk, so a commit
/// allocates nothing.
fn values_set(steps: &hdf5::Group, room: usize, n: usize) -> hdf5::Result<Dataset> {
    steps
        .new_dataset::<f64>()
        .chunk([room.max(1)])
        .shape([Extent::resizable(n)])
        .alloc_time(Some(AllocTime::Early))
        .fill_time(FillTime::Never)
        .create("Values")
}

/// The file access of every process: MPI-IO under MPI, else without HDF5's file lock so
/// that readers (h5py, ParaView) may open the file while the run goes on. No raw data is
/// cached (chunk cache and sieve buffer off): each write reaches the file when it is made.
fn access(comm: Option<&mpi::topology::SimpleCommunicator>) -> hdf5::FileBuilder {
    let mut b = File::with_options();
    match comm {
        Some(c) => {
            use mpi::raw::AsRaw;
            let raw = c.as_raw();
            b.with_fapl(|p| p.mpio(raw, None).chunk_cache(0, 0, 1.0).sieve_buf_size(0));
        }
        None => {
            b.with_fapl(|p| p.file_locking(false).chunk_cache(0, 0, 1.0).sieve_buf_size(0));
        }
    }
    b
}

/// Keeps the first failure of a batch of calls that every process makes in full.
fn keep(first: &mut hdf5::Result<()>, r: hdf5::Result<()>) {
    if first.is_ok() {
        *first = r;
    }
}

/// Resizes a dataset to `rows` rows (its other dimensions unchanged).
fn resize(ds: &Dataset, rows: usize) -> hdf5::Result<()> {
    let mut shape = ds.shape();
    shape[0] = rows;
    ds.resize(shape)
}

/// The rows of a dataset (its first dimension).
fn rows_of(ds: &Dataset) -> usize {
    ds.shape().first().copied().unwrap_or(0)
}

/// Writes rows `row0..row0 + rows` (`ncomp` values each) of a dataset, collectively under MPI
/// (every process calls, some with no rows).
fn write_rows(ds: &Dataset, row0: usize, rows: usize, ncomp: usize, data: &[f64], parallel: bool) -> hdf5::Result<()> {
    if data.len() != rows * ncomp {
        return Err(format!("internal: {} values for {rows} rows of {ncomp}", data.len()).into());
    }
    // A float32 file array gets float32 values: parallel HDF5 writes no filtered (deflated)
    // chunks through a type conversion, so the conversion is done here, the same on every path.
    match ds.dtype()?.size() == 4 {
        true => {
            let narrow: Vec<f32> = data.iter().map(|&x| x as f32).collect();
            write_rows_of(ds, row0, rows, ncomp, &narrow, parallel)
        }
        false => write_rows_of(ds, row0, rows, ncomp, data, parallel),
    }
}

/// Writes `rows` rows of `ncomp` values of `T` at row `row0` of `ds` (a collective write
/// under MPI-IO when `parallel`: every process calls, with its own rows, possibly none).
pub(super) fn write_rows_of<T: hdf5::H5Type>(
    ds: &Dataset,
    row0: usize,
    rows: usize,
    ncomp: usize,
    data: &[T],
    parallel: bool,
) -> hdf5::Result<()> {
    use hdf5_sys::h5d::H5Dwrite;
    use hdf5_sys::h5p::{H5Pclose, H5Pcreate, H5P_CLS_DATASET_XFER};
    use hdf5_sys::h5s::{H5S_seloper_t, H5Sclose, H5Screate_simple, H5Sselect_hyperslab, H5Sselect_none};
    if data.len() != rows * ncomp {
        return Err(format!("internal: {} values for {rows} rows of {ncomp}", data.len()).into());
    }
    let mem_type = hdf5::Datatype::from_type::<T>()?;
    let nd = ds.ndim();
    let start = [row0 as u64, 0];
    let count = [rows as u64, ncomp as u64];
    // the memory space has the shape of the file selection: with a flat memory space HDF5 maps
    // every element to its chunk one at a time (most of an output step's time)
    let mdims = [rows.max(1) as u64, ncomp as u64];
    // SAFETY: plain HDF5 C calls on ids owned here or by `ds`; buffers outlive the calls.
    let status = unsafe {
        let fs = hdf5_sys::h5d::H5Dget_space(ds.id());
        let ms = H5Screate_simple(nd as i32, mdims[..nd].as_ptr(), std::ptr::null());
        if rows == 0 {
            H5Sselect_none(fs);
            H5Sselect_none(ms);
        } else {
            H5Sselect_hyperslab(
                fs,
                H5S_seloper_t::H5S_SELECT_SET,
                start.as_ptr(),
                std::ptr::null(),
                count[..nd].as_ptr(),
                std::ptr::null(),
            );
        }
        let dxpl = H5Pcreate(*H5P_CLS_DATASET_XFER);
        if parallel {
            hdf5_sys::h5p::H5Pset_dxpl_mpio(dxpl, hdf5_sys::h5p::H5FD_mpio_xfer_t::H5FD_MPIO_COLLECTIVE);
        }
        let st = H5Dwrite(ds.id(), mem_type.id(), ms, fs, dxpl, data.as_ptr().cast());
        // the error stack of the write, before the closes below add to it
        let err = (st < 0).then(|| hdf5::Error::query().unwrap_or_else(|e| e));
        H5Pclose(dxpl);
        H5Sclose(ms);
        H5Sclose(fs);
        err
    };
    match status {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

impl SeriesWriter {
    /// Every per-step dataset (room for `room` steps) with its rows per step; `Values`, whose
    /// extent is the count, is not one of them.
    fn per_step_sets(&self) -> impl Iterator<Item = (&Dataset, usize)> {
        let n = self.n_points;
        let fields = self.fields.iter().flat_map(move |f| [(&f.data, n), (&f.offsets, 1)]);
        let tables = self
            .step_sets
            .iter()
            .chain(&self.cell_offsets)
            .chain([&self.probe_time, &self.probe_step, &self.probe_force, &self.probe_disp])
            .chain(self.tools.iter().flat_map(|t| t.datasets()))
            .chain(self.checks.iter().flat_map(|c| c.datasets()))
            .map(|d| (d, 1));
        fields.chain(tables)
    }

    /// Writes the file's data to the disk: under MPI-IO HDF5's flush did (a file sync on every
    /// process); one process syncs it here, so that a commit means the same on any count.
    fn sync(&self) -> hdf5::Result<()> {
        if self.parallel {
            return Ok(());
        }
        std::fs::File::open(&self.path)
            .and_then(|f| f.sync_data())
            .map_err(|e| hdf5::Error::from(format!("syncing the file to the disk: {e}")))
    }

    /// Flushes HDF5's buffers and syncs the file (every process calls; agreed).
    fn flush_sync(&self, what: impl FnOnce() -> String) -> anyhow::Result<()> {
        self.team.settle(what, self.file.flush().and_then(|_| self.sync()))
    }

    /// Output steps appended (complete in the file after the next commit).
    pub fn steps_written(&self) -> usize {
        self.n_steps
    }
    /// Output steps complete in the file (counted by its last commit).
    pub fn steps_complete(&self) -> usize {
        self.counted
    }
    pub fn path(&self) -> &Path {
        &self.path
    }
    /// True when every writing process says `ok` (a reduction; every process calls).
    pub fn all(&self, ok: bool) -> bool {
        self.team.all(ok)
    }
}
