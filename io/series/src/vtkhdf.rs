//! Time-series output in the VTKHDF 2.x temporal UnstructuredGrid layout.
//!
//! `/VTKHDF` holds the static mesh once (one partition) and the point data of every output
//! step appended along the first axis; `/VTKHDF/Steps` maps step k to the rows
//! `k*N .. (k+1)*N` of each point-data array (the mesh offsets stay 0). `/eprop` holds what VTK
//! does not model: the scenario text, the program version, control volumes, input node ids,
//! per-load probes and the count of complete steps. Every dataset that grows per step is
//! chunked and extendible, so appending step k costs the same for every k.

use crate::outcome::Team;
use anyhow::{anyhow, Result};
use eprop_io::mesh::Mesh;
use eprop_io::vtk::vtk_order;
use hdf5::dataset::{AllocTime, FillTime};
use hdf5::types::{FixedAscii, VarLenUnicode};
use hdf5::{Dataset, Extent, File};
use ndarray::{s, ArrayView3};
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// Sizes of the whole mesh (every process knows them; only one holds the mesh itself).
#[derive(Clone, Copy, Debug)]
pub struct Layout {
    pub nodes: usize,
    pub cells: usize,
    pub conn: usize,
}

impl Layout {
    pub fn of(mesh: &Mesh) -> Layout {
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
}

/// One tool's row of an output step (`/eprop/tools`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ToolRow {
    pub position: [f64; 3],
    pub force: [f64; 3],
    pub contact_nodes: u64,
    pub contact_area: f64,
    pub indentation: f64,
    pub displacement: [f64; 3],
}

/// The growing datasets of `/eprop/tools`: per output step, and per step and tool.
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
    /// Every dataset, each growing by one row per output step.
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
    values: Dataset,
    probe_time: Dataset,
    probe_step: Dataset,
    probe_force: Dataset,
    probe_disp: Dataset,
    n_loads: usize,
    /// Output steps whose rows are written.
    n_steps: usize,
    /// Output steps counted complete in the file (`steps_complete`, `NSteps`): the rest are
    /// written but not yet flushed and counted.
    counted: usize,
    /// Seconds between commits (flush, count, flush); 0 commits every step.
    commit_every: f64,
    last_commit: std::time::Instant,
    /// The writing processes; every call's outcome is agreed through it.
    team: Team,
    tools: Option<ToolSets>,
    /// `/VTKHDF/Steps/CellDataOffsets/tag`: the cell tags are static (offset 0 at every
    /// step); absent in series written before they were stored.
    cell_offsets: Option<Dataset>,
}

/// `what` as a message maker for `Team::settle`.
fn at(what: impl std::fmt::Display) -> impl FnOnce() -> String {
    move || what.to_string()
}

fn growing(group: &hdf5::Group, name: &str, tail: &[usize], chunk_rows: usize) -> hdf5::Result<Dataset> {
    let mut ext = vec![Extent::resizable(0)];
    let mut chunk = vec![chunk_rows.max(1)];
    for &t in tail {
        // an empty dimension (no loads: (steps, 0, 3)) has a chunk of 1, which HDF5 allows only
        // on a dimension that may grow
        ext.push(if t == 0 { Extent::resizable(0) } else { Extent::fixed(t) });
        chunk.push(t.max(1));
    }
    let b = group.new_dataset::<f64>().chunk(chunk).shape(ext);
    // allocated early in every file, so that a serial file can be continued under MPI-IO
    let b = b.alloc_time(Some(AllocTime::Early)).fill_time(FillTime::Never);
    b.create(name)
}

fn growing_i64(group: &hdf5::Group, name: &str) -> hdf5::Result<Dataset> {
    let b = group.new_dataset::<i64>().chunk(1024).shape(Extent::resizable(0));
    // allocated early in every file, so that a serial file can be continued under MPI-IO
    let b = b.alloc_time(Some(AllocTime::Early)).fill_time(FillTime::Never);
    b.create(name)
}

/// A growing point array: float64 or float32, optionally deflated.
fn point_array(
    group: &hdf5::Group,
    name: &str,
    tail: &[usize],
    chunk_rows: usize,
    spec: &SeriesSpec,
) -> hdf5::Result<Dataset> {
    let mut ext = vec![Extent::resizable(0)];
    let mut chunk = vec![chunk_rows.max(1)];
    for &t in tail {
        ext.push(Extent::fixed(t));
        chunk.push(t);
    }
    let b = if spec.float32 {
        group.new_dataset::<f32>()
    } else {
        group.new_dataset::<f64>()
    };
    let b = b.chunk(chunk).shape(ext);
    // allocated early in every file, so that a serial file can be continued under MPI-IO
    let b = b.alloc_time(Some(AllocTime::Early)).fill_time(FillTime::Never);
    let b = if spec.compression > 0 {
        b.deflate(spec.compression)
    } else {
        b
    };
    b.create(name)
}

/// A fixed-size dataset created by every process and filled by the one holding `data`.
fn fixed<T: hdf5::H5Type>(
    team: &Team,
    group: &hdf5::Group,
    name: &str,
    shape: &[usize],
    data: Option<&[T]>,
) -> Result<()> {
    let what = at(format!("creating the output ({name})"));
    let ds = team.settle(what, group.new_dataset::<T>().shape(shape).create(name))?;
    let written = match data {
        Some(d) if !d.is_empty() => ndarray::ArrayViewD::from_shape(shape, d)
            .map_err(hdf5::Error::from)
            .and_then(|v| ds.write(v)),
        _ => Ok(()),
    };
    team.settle(at(format!("writing the output ({name})")), written)
}

/// A scalar attribute created and written by every process (the same value).
fn scalar_attr<T: hdf5::H5Type>(team: &Team, loc: &hdf5::Location, name: &str, v: &T) -> Result<()> {
    team.settle(
        at(format!("creating the output (attribute {name})")),
        loc.new_attr::<T>().create(name).and_then(|a| a.write_scalar(v)),
    )
}

/// Writes rows `row0..row0 + rows` (`ncomp` values each) of a dataset, collectively under MPI
/// (every process calls, some with no rows).
fn write_rows(ds: &Dataset, row0: usize, rows: usize, ncomp: usize, data: &[f64], parallel: bool) -> hdf5::Result<()> {
    use hdf5_sys::h5d::H5Dwrite;
    use hdf5_sys::h5p::{H5Pclose, H5Pcreate, H5P_CLS_DATASET_XFER};
    use hdf5_sys::h5s::{H5S_seloper_t, H5Sclose, H5Screate_simple, H5Sselect_hyperslab, H5Sselect_none};
    use hdf5_sys::h5t::{H5T_NATIVE_DOUBLE, H5T_NATIVE_FLOAT};
    if data.len() != rows * ncomp {
        return Err(format!("internal: {} values for {rows} rows of {ncomp}", data.len()).into());
    }
    // A float32 file array gets float32 values: parallel HDF5 writes no filtered (deflated)
    // chunks through a type conversion, so the conversion is done here, the same on every path.
    let narrow: Option<Vec<f32>> = (ds.dtype()?.size() == 4).then(|| data.iter().map(|&x| x as f32).collect());
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
        let st = match &narrow {
            Some(v) => H5Dwrite(ds.id(), *H5T_NATIVE_FLOAT, ms, fs, dxpl, v.as_ptr().cast()),
            None => H5Dwrite(ds.id(), *H5T_NATIVE_DOUBLE, ms, fs, dxpl, data.as_ptr().cast()),
        };
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

/// Keeps the first failure of a batch of calls that every process makes in full.
fn keep(first: &mut hdf5::Result<()>, r: hdf5::Result<()>) {
    if first.is_ok() {
        *first = r;
    }
}

/// Resizes a growing dataset to `rows` rows (its other dimensions unchanged).
fn resize(ds: &Dataset, rows: usize) -> hdf5::Result<()> {
    let mut shape = ds.shape();
    shape[0] = rows;
    ds.resize(shape)
}

/// The state stored at the last complete step of a series (this process's block).
pub struct Resume {
    pub step: u64,
    pub time: f64,
    pub u: Vec<f64>,
    pub v: Vec<f64>,
    pub phi: Vec<f64>,
}

/// The file access of every process: MPI-IO under MPI, else without HDF5's file lock so
/// that readers (h5py, ParaView) may open the file while the run goes on.
fn access(comm: Option<&mpi::topology::SimpleCommunicator>) -> hdf5::FileBuilder {
    let mut b = File::with_options();
    match comm {
        Some(c) => {
            use mpi::raw::AsRaw;
            let raw = c.as_raw();
            b.with_fapl(|p| p.mpio(raw, None));
        }
        None => {
            b.with_fapl(|p| p.file_locking(false));
        }
    }
    b
}

/// The static mesh of a new series under `/VTKHDF` (every process calls; rank 0, which holds
/// `mesh`, gives the values): the counts, the connectivity in VTK's node order, the offsets,
/// the cell types and the points.
fn write_mesh(t: &Team, top: &hdf5::Group, layout: Layout, mesh: Option<&Mesh>) -> Result<()> {
    let root = mesh.is_some();
    let n = layout.nodes;
    let (mut conn, mut offs, mut types, mut pts) = (vec![], vec![], vec![], vec![]);
    if let Some(mesh) = mesh {
        conn.reserve(mesh.conn.len());
        offs.push(0i64);
        for c in 0..mesh.n_cells() {
            conn.extend(vtk_order(mesh.kinds[c], mesh.cell(c)).iter().map(|&x| x as i64));
            offs.push(conn.len() as i64);
            types.push(mesh.kinds[c].vtk_type());
        }
        pts = mesh.points.iter().flatten().copied().collect::<Vec<f64>>();
    }
    let on_root = |v: &[i64]| Some(v.to_vec()).filter(|_| root);
    let counts = [n as i64, layout.cells as i64, layout.conn as i64];
    fixed(t, top, "NumberOfPoints", &[1], on_root(&counts[0..1]).as_deref())?;
    fixed(t, top, "NumberOfCells", &[1], on_root(&counts[1..2]).as_deref())?;
    fixed(
        t,
        top,
        "NumberOfConnectivityIds",
        &[1],
        on_root(&counts[2..3]).as_deref(),
    )?;
    fixed(t, top, "Connectivity", &[layout.conn], Some(&conn[..]).filter(|_| root))?;
    fixed(t, top, "Offsets", &[layout.cells + 1], Some(&offs[..]).filter(|_| root))?;
    fixed(t, top, "Types", &[layout.cells], Some(&types[..]).filter(|_| root))?;
    fixed(t, top, "Points", &[n, 3], Some(&pts[..]).filter(|_| root))?;
    Ok(())
}

/// `/eprop` of a new series (every process calls; rank 0 holds `mesh`): the version, the
/// count of complete steps, the identity and extra attributes, the scenario text, the control
/// volumes, node ids and cell tags, and the growing probe datasets, returned as time, step,
/// force, displacement.
fn create_eprop(
    t: &Team,
    file: &File,
    layout: Layout,
    mesh: Option<&Mesh>,
    spec: &SeriesSpec,
    parallel: bool,
) -> Result<[Dataset; 4]> {
    let root = mesh.is_some();
    let n = layout.nodes;
    let mk = |what: &str| at(format!("creating the output ({what})"));
    let ep = t.settle(mk("/eprop"), file.create_group("eprop"))?;
    let vs = VarLenUnicode::from_str(spec.version).unwrap();
    scalar_attr(t, &ep, "version", &vs)?;
    scalar_attr(t, &ep, "steps_complete", &0i64)?;
    for (name, v) in &spec.attrs {
        scalar_attr(t, &ep, name, v)?;
    }
    for (name, v) in &spec.ids {
        scalar_attr(t, &ep, name, v)?;
    }
    scalar_attr(t, &ep, "float32", &(spec.float32 as u8))?;
    let text = spec.scenario.as_bytes();
    fixed(t, &ep, "scenario", &[text.len()], Some(text).filter(|_| root))?;
    let cv = t.settle(
        mk("control_volumes"),
        ep.new_dataset::<f64>().shape([n]).create("control_volumes"),
    )?;
    t.settle(
        at("writing the output (control_volumes)"),
        write_rows(&cv, spec.block_start, spec.block_len, 1, spec.control_volumes, parallel),
    )?;
    let ids: Option<Vec<i64>> = mesh.map(|m| m.node_ids.iter().map(|&x| x as i64).collect());
    fixed(t, &ep, "node_ids", &[n], ids.as_deref())?;
    fixed(t, &ep, "cell_tags", &[layout.cells], mesh.map(|m| &m.cell_tags[..]))?;
    let pr = t.settle(mk("probes"), ep.create_group("probes"))?;
    let ln: Vec<i64> = spec.load_nodes.iter().map(|&x| x as i64).collect();
    fixed(t, &pr, "node", &[ln.len()], Some(&ln[..]).filter(|_| root))?;
    let nl = spec.n_loads;
    let probe_time = t.settle(mk("probes/time"), growing(&pr, "time", &[], 1024))?;
    let probe_step = t.settle(mk("probes/step"), growing_i64(&pr, "step"))?;
    let probe_force = t.settle(mk("probes/force"), growing(&pr, "force", &[nl, 3], 256))?;
    let probe_disp = t.settle(mk("probes/displacement"), growing(&pr, "displacement", &[nl, 3], 256))?;
    Ok([probe_time, probe_step, probe_force, probe_disp])
}

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

impl SeriesWriter {
    /// Creates (truncates) the file and writes the static mesh. `mesh` is given on exactly one
    /// process (rank 0), `comm` under MPI (then every process of it must call). A failure is a
    /// `WriteFailed` on every process (the file is closed on every process when it returns).
    pub fn create(
        path: &Path,
        layout: Layout,
        mesh: Option<&Mesh>,
        spec: &SeriesSpec,
        comm: Option<&mpi::topology::SimpleCommunicator>,
    ) -> Result<Self> {
        let parallel = comm.is_some();
        let root = mesh.is_some();
        let team = Team::new(path, comm);
        let file = team.settle_open(at(CREATING), access(comm).create(path))?;
        team.hold(&file);
        let t = &team;
        let n = layout.nodes;
        let top = t.settle(at("creating the output (/VTKHDF)"), file.create_group("VTKHDF"))?;
        t.settle(
            at("creating the output (Version)"),
            top.new_attr::<i64>()
                .shape([2])
                .create("Version")
                .and_then(|a| a.write(&[2i64, 1])),
        )?;
        let ty = FixedAscii::<16>::from_ascii(b"UnstructuredGrid").unwrap();
        scalar_attr(t, &top, "Type", &ty)?;

        write_mesh(t, &top, layout, mesh)?;

        let mk = |what: &str| at(format!("creating the output ({what})"));
        let pd = t.settle(mk("PointData"), top.create_group("PointData"))?;
        let steps = t.settle(mk("Steps"), top.create_group("Steps"))?;
        scalar_attr(t, &steps, "NSteps", &0i64)?;
        let pdo = t.settle(mk("PointDataOffsets"), steps.create_group("PointDataOffsets"))?;
        let cdo = t.settle(mk("CellDataOffsets"), steps.create_group("CellDataOffsets"))?;
        t.settle(mk("FieldDataOffsets"), steps.create_group("FieldDataOffsets"))?;
        // the mesh's cell tags (physical groups: the tissues) as cell data, so that a viewer
        // colours by them; written once, every step points at the same rows
        let cd = t.settle(mk("CellData"), top.create_group("CellData"))?;
        let tags: Option<Vec<i64>> = mesh.map(|m| m.cell_tags.iter().map(|&x| x as i64).collect());
        fixed(t, &cd, "tag", &[layout.cells], tags.as_deref())?;
        let cell_offsets = Some(t.settle(mk("CellDataOffsets/tag"), growing_i64(&cdo, "tag"))?);
        let values = t.settle(mk("Values"), growing(&steps, "Values", &[], 1024))?;
        let mut step_sets = Vec::new();
        for name in STEP_SETS {
            step_sets.push(t.settle(mk(name), growing_i64(&steps, name))?);
        }
        let mut fields = Vec::new();
        for &(name, ncomp) in &spec.fields {
            let rows = n.clamp(1, (1 << 20) / (8 * ncomp));
            let tail: &[usize] = if ncomp == 1 { &[] } else { &[ncomp] };
            let data = t.settle(mk(name), point_array(&pd, name, tail, rows, spec))?;
            let offsets = t.settle(mk(name), growing_i64(&pdo, name))?;
            fields.push(Field {
                name: name.to_string(),
                ncomp,
                data,
                offsets,
            });
        }

        let [probe_time, probe_step, probe_force, probe_disp] = create_eprop(t, &file, layout, mesh, spec, parallel)?;
        let nl = spec.n_loads;
        t.settle(at("writing the output (flush)"), file.flush())?;
        Ok(SeriesWriter {
            path: path.to_path_buf(),
            file,
            n_points: n,
            block: (spec.block_start, spec.block_len),
            root,
            parallel,
            fields,
            steps,
            step_sets,
            values,
            probe_time,
            probe_step,
            probe_force,
            probe_disp,
            n_loads: nl,
            n_steps: 0,
            counted: 0,
            commit_every: 0.0,
            last_commit: std::time::Instant::now(),
            team,
            tools: None,
            cell_offsets,
        })
    }

    /// Adds `/eprop/tools` for `n` tools to a new series, before its first step (every process
    /// calls): `time`, `step` (output steps), `position`, `force`, `displacement` (output
    /// steps, tools, 3), `contact_nodes`, `contact_area`, `indentation` (output steps, tools).
    pub fn add_tools(&mut self, n: usize) -> Result<()> {
        if self.n_steps > 0 || n == 0 {
            return Err(anyhow!("internal: tools are added to a new series, and at least one"));
        }
        let t = &self.team;
        let mk = |what: &str| at(format!("creating the output ({what})"));
        let ep = t.settle(mk("/eprop"), self.file.group("eprop"))?;
        let g = t.settle(mk("/eprop/tools"), ep.create_group("tools"))?;
        let vector = |name: &str| t.settle(mk(name), growing(&g, name, &[n, 3], 256));
        let scalar = |name: &str| t.settle(mk(name), growing(&g, name, &[n], 256));
        let b = g
            .new_dataset::<i64>()
            .chunk([256, n])
            .shape([Extent::resizable(0), Extent::fixed(n)]);
        let b = b.alloc_time(Some(AllocTime::Early)).fill_time(FillTime::Never);
        let contact_nodes = t.settle(mk("contact_nodes"), b.create("contact_nodes"))?;
        let sets = ToolSets {
            n,
            time: t.settle(mk("tools/time"), growing(&g, "time", &[], 1024))?,
            step: t.settle(mk("tools/step"), growing_i64(&g, "step"))?,
            vectors: [vector("position")?, vector("force")?, vector("displacement")?],
            scalars: [scalar("contact_area")?, scalar("indentation")?],
            contact_nodes,
        };
        t.settle(at("writing the output (flush)"), self.file.flush())?;
        self.tools = Some(sets);
        Ok(())
    }

    /// Writes the tools' rows of the next output step (every process calls; rank 0's rows are
    /// written): call before `append`, which completes the step. A failure is a `WriteFailed`
    /// on every process.
    pub fn append_tools(&mut self, time: f64, step: u64, rows: &[ToolRow]) -> Result<()> {
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
        // every table to k + 1 rows (made in full by every process, agreed once)
        let mut resized = Ok(());
        for d in tt.datasets() {
            keep(&mut resized, resize(d, k + 1));
        }
        self.team.settle(what, resized)?;
        let rows_of_root = || -> hdf5::Result<()> {
            tt.time.write_slice(&[time], s![k..k + 1])?;
            tt.step.write_slice(&[step as i64], s![k..k + 1])?;
            let pick = |f: fn(&ToolRow) -> [f64; 3]| rows.iter().flat_map(f).collect::<Vec<f64>>();
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

    /// Seconds between commits: steps appended in between are written but counted (and
    /// flushed) only at the next commit. 0 (the default) commits every step.
    pub fn commit_every(&mut self, seconds: f64) {
        self.commit_every = seconds.max(0.0);
    }

    /// Appends one output step (every process calls): `data[f]` holds field f for this
    /// process's block of nodes (node-major, components interleaved); `probes[l]` = (applied
    /// force, contact displacement) of load l (used on rank 0). The step is then committed
    /// when `commit` is true, when it is the first, or when the commit interval has passed
    /// (rank 0's clock decides for every process); returns whether it was. A failure at any
    /// point leaves the file at its last commit; a failure is a `WriteFailed` on every process.
    pub fn append(
        &mut self,
        time: f64,
        step: u64,
        data: &[&[f64]],
        probes: &[([f64; 3], [f64; 3])],
        commit: bool,
    ) -> Result<bool> {
        let k = self.n_steps;
        let n = self.n_points;
        let (b0, bl) = self.block;
        let root = self.root;
        let t = &self.team;
        let what = || format!("writing output step {k} (step {step})");
        // every growing dataset to k + 1 steps: calls on distinct datasets, each made by every
        // process whatever the others' outcome, agreed once
        let mut resized = Ok(());
        for f in &self.fields {
            keep(&mut resized, resize(&f.data, (k + 1) * n));
            keep(&mut resized, resize(&f.offsets, k + 1));
        }
        for ds in self.step_sets.iter().chain(&self.cell_offsets).chain([
            &self.values,
            &self.probe_time,
            &self.probe_step,
            &self.probe_force,
            &self.probe_disp,
        ]) {
            keep(&mut resized, resize(ds, k + 1));
        }
        t.settle(what, resized)?;
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
            self.values.write_slice(&[time], s![k..k + 1])?;
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

    /// Makes every appended step complete in the file (every process calls; nothing to do
    /// when none is pending): the rows and tables are flushed before `steps_complete` and
    /// `NSteps` count them (a second flush), so a failure at any point leaves the file at its
    /// previous commit. Under MPI-IO each flush is a sync of the file on every process.
    pub fn commit(&mut self) -> Result<()> {
        if self.counted == self.n_steps {
            return Ok(());
        }
        let (k, t) = (self.n_steps, &self.team);
        let what = || format!("completing output steps {} to {}", self.counted, k - 1);
        t.settle(what, self.file.flush().and_then(|_| self.sync()))?;
        let ns = k as i64;
        let mut counted = self.steps.attr("NSteps").and_then(|a| a.write_scalar(&ns));
        keep(
            &mut counted,
            self.file
                .group("eprop")
                .and_then(|g| g.attr("steps_complete"))
                .and_then(|a| a.write_scalar(&ns)),
        );
        t.settle(what, counted)?;
        t.settle(what, self.file.flush().and_then(|_| self.sync()))?;
        self.counted = k;
        self.last_commit = std::time::Instant::now();
        Ok(())
    }

    /// Opens a series written by `create` with the same `spec` to continue it after its last
    /// complete step (rows of an incomplete step are dropped). Every process calls under MPI.
    /// Refuses a file whose identity attributes (`spec.ids`) or layout differ.
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
        let read = |what: &str| at(format!("reading the file to restart ({what})"));
        // what a file may lack (then it is refused alike on every process)
        let ep = t
            .settle_opt(read("/eprop"), file.group("eprop"))?
            .ok_or_else(|| bad("no /eprop group (not an eprop series)".into()))?;
        check_identity(t, &ep, spec, path)?;
        let n: i64 = t.settle(
            read("NumberOfPoints"),
            file.dataset("VTKHDF/NumberOfPoints").and_then(|d| d.read_raw::<i64>()),
        )?[0];
        if n as usize != layout.nodes {
            return Err(bad(format!("the file has {n} nodes, the mesh {}", layout.nodes)));
        }
        let k: i64 = t.settle(
            read("steps_complete"),
            ep.attr("steps_complete").and_then(|a| a.read_scalar()),
        )?;
        if k < 1 {
            return Err(bad("the file holds no complete step".into()));
        }
        let k = k as usize;
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
        let nd = layout.nodes;
        // a count past the rows the file holds: changed by hand or damaged (the same answer
        // on every process: the shapes are the file's)
        for f in &fields {
            let rows = f.data.shape().first().copied().unwrap_or(0);
            if rows < k * nd {
                return Err(anyhow!(
                    "{}: cannot restart: /eprop steps_complete = {k} but `{}` holds {} complete steps: the file was changed or damaged; fix: restore the file, or start a new run (--overwrite)",
                    path.display(),
                    f.name,
                    rows / nd.max(1)
                ));
            }
        }
        // the state at the last complete step
        let (b0, bl) = (spec.block_start, spec.block_len);
        let mut state = Vec::new();
        for name in ["displacement", "velocity", "potential"] {
            let f = fields
                .iter()
                .find(|f| f.name == name)
                .ok_or_else(|| bad(format!("the run did not write `{name}`, which a restart needs")))?;
            let rows = (k - 1) * nd + b0;
            let v = t.settle(read(name), f.data.read_slice_2d::<f64, _>(s![rows..rows + bl, ..]))?;
            state.push(v.iter().copied().collect::<Vec<f64>>());
        }
        let values = t.settle(read("Values"), steps.dataset("Values"))?;
        let time = t.settle(read("Values"), values.read_slice_1d::<f64, _>(s![k - 1..k]))?[0];
        let pr = t.settle(read("probes"), ep.group("probes"))?;
        let probe_step = t.settle(read("probes/step"), pr.dataset("step"))?;
        let step = t.settle(read("probes/step"), probe_step.read_slice_1d::<i64, _>(s![k - 1..k]))?[0];
        let mut step_sets = Vec::new();
        for name in STEP_SETS {
            step_sets.push(t.settle(read(name), steps.dataset(name))?);
        }
        let probe_time = t.settle(read("probes/time"), pr.dataset("time"))?;
        let probe_force = t.settle(read("probes/force"), pr.dataset("force"))?;
        let probe_disp = t.settle(read("probes/displacement"), pr.dataset("displacement"))?;
        // the file's own count: a series written before (steps, 0, 3) keeps its one row of zeros
        let n_loads = probe_force.shape().get(1).copied().unwrap_or(0);
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
        let w = SeriesWriter {
            path: path.to_path_buf(),
            n_points: nd,
            block: (b0, bl),
            root,
            parallel,
            fields,
            step_sets,
            values,
            probe_time,
            probe_step,
            probe_force,
            probe_disp,
            n_loads,
            n_steps: k,
            counted: k,
            commit_every: 0.0,
            last_commit: std::time::Instant::now(),
            steps,
            file,
            team,
            tools,
            cell_offsets,
        };
        // drop the rows of a step that was being written when the run ended
        w.truncate()?;
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

    /// Drops the last complete step (every process calls): the file then holds one step less.
    pub fn forget_last(&mut self) -> Result<()> {
        let k = self.n_steps.saturating_sub(1);
        let ns = k as i64;
        let t = &self.team;
        let what = || format!("dropping output step {k}");
        // the count first: a reader never sees a step whose rows are gone
        t.settle(what, self.steps.attr("NSteps").and_then(|a| a.write_scalar(&ns)))?;
        t.settle(
            what,
            self.file
                .group("eprop")
                .and_then(|g| g.attr("steps_complete"))
                .and_then(|a| a.write_scalar(&ns)),
        )?;
        t.settle(what, self.file.flush())?;
        self.n_steps = k;
        self.counted = k;
        self.truncate()
    }

    /// Cuts every growing dataset to the complete steps.
    fn truncate(&self) -> Result<()> {
        let (k, n, t) = (self.n_steps, self.n_points, &self.team);
        let what = || "dropping the rows of an incomplete step".to_string();
        for f in &self.fields {
            t.settle(what, resize(&f.data, k * n))?;
            t.settle(what, resize(&f.offsets, k))?;
        }
        for ds in self.step_sets.iter().chain(&self.cell_offsets).chain([
            &self.values,
            &self.probe_time,
            &self.probe_step,
            &self.probe_force,
            &self.probe_disp,
        ]) {
            t.settle(what, resize(ds, k))?;
        }
        if let Some(tt) = &self.tools {
            for d in tt.datasets() {
                t.settle(what, resize(d, k))?;
            }
        }
        t.settle(what, self.file.flush())
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

/// What a failure to create (open) the file is called; a failure after it left a file behind.
pub const CREATING: &str = "creating the output file";

/// The per-step tables of `/VTKHDF/Steps` besides `Values`.
const STEP_SETS: [&str; 5] = [
    "PartOffsets",
    "NumberOfParts",
    "PointOffsets",
    "CellOffsets",
    "ConnectivityIdOffsets",
];

/// What a file is, for the refusal to replace it: not HDF5, HDF5 but not an eprop series, or
/// a series with its count of complete steps and the program that wrote it.
#[derive(Clone, Debug, PartialEq)]
pub enum Kind {
    NotHdf5,
    OtherHdf5,
    Series { steps: i64, version: String },
}

/// Looks at an existing file (read only, without HDF5's file lock).
pub fn kind_of(path: &Path) -> Result<Kind> {
    use std::io::Read;
    let mut head = [0u8; 8];
    let mut f = std::fs::File::open(path).map_err(|e| anyhow!("{}: cannot open: {e}", path.display()))?;
    let signature = *b"\x89HDF\r\n\x1a\n";
    // the signature is at 0 or, after a user block, at 512, 1024, 2048, ...
    let len = f.metadata().map(|m| m.len()).unwrap_or(0);
    let mut found = false;
    let mut at = 0u64;
    while at + 8 <= len {
        use std::io::Seek;
        if f.seek(std::io::SeekFrom::Start(at)).is_ok() && f.read_exact(&mut head).is_ok() && head == signature {
            found = true;
            break;
        }
        at = if at == 0 { 512 } else { at * 2 };
    }
    if !found {
        return Ok(Kind::NotHdf5);
    }
    let Ok(h) = File::with_options().with_fapl(|p| p.file_locking(false)).open(path) else {
        return Ok(Kind::OtherHdf5);
    };
    let Ok(ep) = h.group("eprop") else {
        return Ok(Kind::OtherHdf5);
    };
    let version: Option<VarLenUnicode> = ep.attr("version").and_then(|a| a.read_scalar()).ok();
    let steps: Option<i64> = ep.attr("steps_complete").and_then(|a| a.read_scalar()).ok();
    match (version, steps) {
        (Some(v), Some(steps)) if v.as_str().starts_with("eprop") && h.group("VTKHDF").is_ok() => Ok(Kind::Series {
            steps,
            version: v.as_str().to_string(),
        }),
        _ => Ok(Kind::OtherHdf5),
    }
}

/// Reads point array `name` of output step `k` (node-major, components interleaved).
pub fn read_step(path: &Path, name: &str, k: usize) -> Result<Vec<f64>> {
    let f = File::open(path).map_err(|e| anyhow!("{}: cannot open: {e}", path.display()))?;
    let n = f.dataset("VTKHDF/NumberOfPoints")?.read_raw::<i64>()?[0] as usize;
    let ds = f
        .dataset(&format!("VTKHDF/PointData/{name}"))
        .map_err(|e| anyhow!("{}: no field {name}: {e}", path.display()))?;
    let shape = ds.shape();
    if shape[0] < (k + 1) * n {
        return Err(anyhow!(
            "{}: step {k} is not in the file ({} steps)",
            path.display(),
            shape[0] / n.max(1)
        ));
    }
    if shape.len() == 1 {
        Ok(ds.read_slice_1d::<f64, _>(s![k * n..(k + 1) * n])?.to_vec())
    } else {
        Ok(ds
            .read_slice_2d::<f64, _>(s![k * n..(k + 1) * n, ..])?
            .iter()
            .copied()
            .collect())
    }
}

fn h5<T>(r: hdf5::Result<T>, path: &Path, what: &str) -> Result<T> {
    r.map_err(|e| anyhow!("{}: {what}: {e}", path.display()))
}

/// Writes a sparse matrix in CSR form (global rows in input node order) with scalar
/// attributes, for comparisons with other solvers: datasets `row_ptr`, `col`, `val`.
pub fn write_csr(path: &Path, row_ptr: &[i64], col: &[i64], val: &[f64], attrs: &[(&str, f64)]) -> Result<()> {
    let f =
        File::create(path).map_err(|e| anyhow!("{}: cannot create: {e}; fix: check the directory", path.display()))?;
    for (name, v) in [("row_ptr", row_ptr), ("col", col)] {
        h5(f.new_dataset_builder().with_data(v).create(name), path, name)?;
    }
    h5(f.new_dataset_builder().with_data(val).create("val"), path, "val")?;
    for (name, v) in attrs {
        h5(
            f.new_attr::<f64>().create(*name).and_then(|a| a.write_scalar(v)),
            path,
            name,
        )?;
    }
    Ok(())
}

/// Adds the float64 dataset `name` to the existing HDF5 file `path` (next to `write_csr`'s).
pub fn add_dataset(path: &Path, name: &str, data: &[f64]) -> Result<()> {
    let f = File::open_rw(path).map_err(|e| anyhow!("{}: cannot open: {e}; fix: check the file", path.display()))?;
    h5(f.new_dataset_builder().with_data(data).create(name), path, name)?;
    Ok(())
}

/// The rest mesh a series was written for (points, cells and their tags as the file holds
/// them), and its complete steps (`/eprop` `steps_complete`).
pub fn read_mesh(path: &Path) -> Result<(Mesh, usize)> {
    let f = File::open(path).map_err(|e| anyhow!("{}: cannot open: {e}", path.display()))?;
    let read_i = |name: &str| -> Result<Vec<i64>> {
        h5(f.dataset(&format!("VTKHDF/{name}")), path, name)
            .and_then(|d| h5(d.read_raw::<i64>(), path, name))
            .map_err(|e| anyhow!("{e}; fix: give a series written by eprop run"))
    };
    let points = h5(f.dataset("VTKHDF/Points"), path, "Points")?;
    let points: Vec<f64> = h5(points.read_raw::<f64>(), path, "Points")?;
    let conn = read_i("Connectivity")?;
    let starts = read_i("Offsets")?;
    let types: Vec<i64> = h5(f.dataset("VTKHDF/Types"), path, "Types")
        .and_then(|d| h5(d.read_raw::<u8>(), path, "Types"))?
        .into_iter()
        .map(i64::from)
        .collect();
    let steps = f
        .group("eprop")
        .and_then(|g| g.attr("steps_complete"))
        .and_then(|a| a.read_scalar::<i64>())
        .map_err(|e| {
            anyhow!(
                "{}: not an eprop series (no /eprop steps_complete: {e})",
                path.display()
            )
        })?;
    let d = eprop_io::vtk::VtkData {
        points,
        conn,
        starts,
        types,
        cell_arrays: vec![],
        point_arrays: vec![],
    };
    let mesh = eprop_io::vtk::build(&path.display().to_string(), d)?;
    Ok((mesh, steps.max(0) as usize))
}
