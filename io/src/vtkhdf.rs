//! Time-series output in the VTKHDF 2.x temporal UnstructuredGrid layout.
//!
//! `/VTKHDF` holds the static mesh once (one partition) and the point data of every output
//! step appended along the first axis; `/VTKHDF/Steps` maps step k to the rows
//! `k*N .. (k+1)*N` of each point-data array (the mesh offsets stay 0). `/eprop` holds what VTK
//! does not model: the scenario text, the program version, control volumes, input node ids,
//! per-load probes and the count of complete steps. Every dataset that grows per step is
//! chunked and extendible, so appending step k costs the same for every k.

use crate::mesh::Mesh;
use crate::vtk::vtk_order;
use anyhow::{anyhow, Context, Result};
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
    n_steps: usize,
    tools: Option<ToolSets>,
}

fn h5<T>(r: hdf5::Result<T>, path: &Path, what: &str) -> Result<T> {
    r.map_err(|e| anyhow!("{}: {what}: {e}", path.display()))
}

fn growing(group: &hdf5::Group, name: &str, tail: &[usize], chunk_rows: usize, path: &Path) -> Result<Dataset> {
    let mut ext = vec![Extent::resizable(0)];
    let mut chunk = vec![chunk_rows.max(1)];
    for &t in tail {
        ext.push(Extent::fixed(t));
        chunk.push(t);
    }
    let b = group.new_dataset::<f64>().chunk(chunk).shape(ext);
    // allocated early in every file, so that a serial file can be continued under MPI-IO
    let b = b.alloc_time(Some(AllocTime::Early)).fill_time(FillTime::Never);
    h5(b.create(name), path, &format!("create {name}"))
}

fn growing_i64(group: &hdf5::Group, name: &str, path: &Path) -> Result<Dataset> {
    let b = group.new_dataset::<i64>().chunk(1024).shape(Extent::resizable(0));
    // allocated early in every file, so that a serial file can be continued under MPI-IO
    let b = b.alloc_time(Some(AllocTime::Early)).fill_time(FillTime::Never);
    h5(b.create(name), path, &format!("create {name}"))
}

/// A growing point array: float64 or float32, optionally deflated.
fn point_array(
    group: &hdf5::Group,
    name: &str,
    tail: &[usize],
    chunk_rows: usize,
    spec: &SeriesSpec,
    path: &Path,
) -> Result<Dataset> {
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
    h5(b.create(name), path, &format!("create {name}"))
}

/// A fixed-size dataset created by every process and filled by the one holding `data`.
fn fixed<T: hdf5::H5Type>(
    group: &hdf5::Group,
    name: &str,
    shape: &[usize],
    data: Option<&[T]>,
    path: &Path,
) -> Result<()> {
    let ds = h5(group.new_dataset::<T>().shape(shape).create(name), path, name)?;
    if let Some(d) = data {
        if !d.is_empty() {
            let v = ndarray::ArrayViewD::from_shape(shape, d).map_err(|e| anyhow!("{name}: {e}"))?;
            h5(ds.write(v), path, name)?;
        }
    }
    Ok(())
}

/// Writes rows `row0..row0 + rows` (`ncomp` values each) of a dataset, collectively under MPI
/// (every process calls, some with no rows).
fn write_rows(ds: &Dataset, row0: usize, rows: usize, ncomp: usize, data: &[f64], parallel: bool) -> Result<()> {
    use hdf5_sys::h5d::H5Dwrite;
    use hdf5_sys::h5p::{H5Pclose, H5Pcreate, H5P_CLS_DATASET_XFER};
    use hdf5_sys::h5s::{H5S_seloper_t, H5Sclose, H5Screate_simple, H5Sselect_hyperslab, H5Sselect_none};
    use hdf5_sys::h5t::H5T_NATIVE_DOUBLE;
    if data.len() != rows * ncomp {
        return Err(anyhow!("internal: {} values for {rows} rows of {ncomp}", data.len()));
    }
    let nd = ds.ndim();
    let start = [row0 as u64, 0];
    let count = [rows as u64, ncomp as u64];
    let mdims = [(rows * ncomp).max(1) as u64];
    // SAFETY: plain HDF5 C calls on ids owned here or by `ds`; buffers outlive the calls.
    let status = unsafe {
        let fs = hdf5_sys::h5d::H5Dget_space(ds.id());
        let ms = H5Screate_simple(1, mdims.as_ptr(), std::ptr::null());
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
        let st = H5Dwrite(ds.id(), *H5T_NATIVE_DOUBLE, ms, fs, dxpl, data.as_ptr().cast());
        H5Pclose(dxpl);
        H5Sclose(ms);
        H5Sclose(fs);
        st
    };
    if status < 0 {
        return Err(anyhow!("writing rows {row0}..{} of {} failed", row0 + rows, ds.name()));
    }
    Ok(())
}

/// The state stored at the last complete step of a series (this process's block).
pub struct Resume {
    pub step: u64,
    pub time: f64,
    pub u: Vec<f64>,
    pub v: Vec<f64>,
    pub phi: Vec<f64>,
}

impl SeriesWriter {
    /// Creates (truncates) the file and writes the static mesh. `mesh` is given on exactly one
    /// process (rank 0), `comm` under MPI (then every process of it must call).
    pub fn create(
        path: &Path,
        layout: Layout,
        mesh: Option<&Mesh>,
        spec: &SeriesSpec,
        comm: Option<&mpi::topology::SimpleCommunicator>,
    ) -> Result<Self> {
        let parallel = comm.is_some();
        let root = mesh.is_some();
        let file = match comm {
            Some(c) => {
                use mpi::raw::AsRaw;
                let raw = c.as_raw();
                File::with_options().with_fapl(|p| p.mpio(raw, None)).create(path)
            }
            // no lock: readers (h5py, ParaView) may open the file while the run goes on
            None => File::with_options().with_fapl(|p| p.file_locking(false)).create(path),
        }
        .map_err(|e| {
            anyhow!(
                "{}: cannot create the output file: {e}; fix: check that the directory exists and is writable",
                path.display()
            )
        })?;
        let n = layout.nodes;
        let top = h5(file.create_group("VTKHDF"), path, "create /VTKHDF")?;
        h5(
            top.new_attr::<i64>()
                .shape([2])
                .create("Version")
                .and_then(|a| a.write(&[2i64, 1])),
            path,
            "Version",
        )?;
        let ty = FixedAscii::<16>::from_ascii(b"UnstructuredGrid").unwrap();
        h5(
            top.new_attr::<FixedAscii<16>>()
                .create("Type")
                .and_then(|a| a.write_scalar(&ty)),
            path,
            "Type",
        )?;

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
        fixed(&top, "NumberOfPoints", &[1], on_root(&counts[0..1]).as_deref(), path)?;
        fixed(&top, "NumberOfCells", &[1], on_root(&counts[1..2]).as_deref(), path)?;
        fixed(
            &top,
            "NumberOfConnectivityIds",
            &[1],
            on_root(&counts[2..3]).as_deref(),
            path,
        )?;
        fixed(
            &top,
            "Connectivity",
            &[layout.conn],
            Some(&conn[..]).filter(|_| root),
            path,
        )?;
        fixed(
            &top,
            "Offsets",
            &[layout.cells + 1],
            Some(&offs[..]).filter(|_| root),
            path,
        )?;
        fixed(&top, "Types", &[layout.cells], Some(&types[..]).filter(|_| root), path)?;
        fixed(&top, "Points", &[n, 3], Some(&pts[..]).filter(|_| root), path)?;
        drop((conn, offs, types, pts));

        let pd = h5(top.create_group("PointData"), path, "PointData")?;
        let steps = h5(top.create_group("Steps"), path, "Steps")?;
        h5(
            steps
                .new_attr::<i64>()
                .create("NSteps")
                .and_then(|a| a.write_scalar(&0i64)),
            path,
            "NSteps",
        )?;
        let pdo = h5(steps.create_group("PointDataOffsets"), path, "PointDataOffsets")?;
        h5(steps.create_group("CellDataOffsets"), path, "CellDataOffsets")?;
        h5(steps.create_group("FieldDataOffsets"), path, "FieldDataOffsets")?;
        let values = growing(&steps, "Values", &[], 1024, path)?;
        let mut step_sets = Vec::new();
        for name in [
            "PartOffsets",
            "NumberOfParts",
            "PointOffsets",
            "CellOffsets",
            "ConnectivityIdOffsets",
        ] {
            step_sets.push(growing_i64(&steps, name, path)?);
        }
        let mut fields = Vec::new();
        for &(name, ncomp) in &spec.fields {
            let rows = n.clamp(1, (1 << 20) / (8 * ncomp));
            let tail: &[usize] = if ncomp == 1 { &[] } else { &[ncomp] };
            let data = point_array(&pd, name, tail, rows, spec, path)?;
            let offsets = growing_i64(&pdo, name, path)?;
            fields.push(Field {
                name: name.to_string(),
                ncomp,
                data,
                offsets,
            });
        }

        let ep = h5(file.create_group("eprop"), path, "create /eprop")?;
        let vs = VarLenUnicode::from_str(spec.version).unwrap();
        h5(
            ep.new_attr::<VarLenUnicode>()
                .create("version")
                .and_then(|a| a.write_scalar(&vs)),
            path,
            "version",
        )?;
        h5(
            ep.new_attr::<i64>()
                .create("steps_complete")
                .and_then(|a| a.write_scalar(&0i64)),
            path,
            "steps_complete",
        )?;
        for (name, v) in &spec.attrs {
            h5(
                ep.new_attr::<f64>().create(*name).and_then(|a| a.write_scalar(v)),
                path,
                name,
            )?;
        }
        for (name, v) in &spec.ids {
            h5(
                ep.new_attr::<u64>().create(*name).and_then(|a| a.write_scalar(v)),
                path,
                name,
            )?;
        }
        h5(
            ep.new_attr::<u8>()
                .create("float32")
                .and_then(|a| a.write_scalar(&(spec.float32 as u8))),
            path,
            "float32",
        )?;
        let text = spec.scenario.as_bytes();
        fixed(&ep, "scenario", &[text.len()], Some(text).filter(|_| root), path)?;
        let cv = h5(
            ep.new_dataset::<f64>().shape([n]).create("control_volumes"),
            path,
            "control_volumes",
        )?;
        write_rows(&cv, spec.block_start, spec.block_len, 1, spec.control_volumes, parallel)
            .with_context(|| format!("{}: control_volumes", path.display()))?;
        let ids: Option<Vec<i64>> = mesh.map(|m| m.node_ids.iter().map(|&x| x as i64).collect());
        fixed(&ep, "node_ids", &[n], ids.as_deref(), path)?;
        fixed(&ep, "cell_tags", &[layout.cells], mesh.map(|m| &m.cell_tags[..]), path)?;
        let pr = h5(ep.create_group("probes"), path, "probes")?;
        let ln: Vec<i64> = spec.load_nodes.iter().map(|&x| x as i64).collect();
        fixed(&pr, "node", &[ln.len()], Some(&ln[..]).filter(|_| root), path)?;
        let nl = spec.n_loads.max(1);
        let probe_time = growing(&pr, "time", &[], 1024, path)?;
        let probe_step = growing_i64(&pr, "step", path)?;
        let probe_force = growing(&pr, "force", &[nl, 3], 256, path)?;
        let probe_disp = growing(&pr, "displacement", &[nl, 3], 256, path)?;
        h5(file.flush(), path, "flush")?;
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
            tools: None,
        })
    }

    /// Adds `/eprop/tools` for `n` tools to a new series, before its first step (every process
    /// calls): `time`, `step` (output steps), `position`, `force`, `displacement` (output
    /// steps, tools, 3), `contact_nodes`, `contact_area`, `indentation` (output steps, tools).
    pub fn add_tools(&mut self, n: usize) -> Result<()> {
        let p = &self.path;
        if self.n_steps > 0 || n == 0 {
            return Err(anyhow!("internal: tools are added to a new series, and at least one"));
        }
        let ep = h5(self.file.group("eprop"), p, "/eprop")?;
        let g = h5(ep.create_group("tools"), p, "create /eprop/tools")?;
        let vector = |name: &str| growing(&g, name, &[n, 3], 256, p);
        let scalar = |name: &str| growing(&g, name, &[n], 256, p);
        let b = g
            .new_dataset::<i64>()
            .chunk([256, n])
            .shape([Extent::resizable(0), Extent::fixed(n)]);
        let b = b.alloc_time(Some(AllocTime::Early)).fill_time(FillTime::Never);
        let contact_nodes = h5(b.create("contact_nodes"), p, "create contact_nodes")?;
        self.tools = Some(ToolSets {
            n,
            time: growing(&g, "time", &[], 1024, p)?,
            step: growing_i64(&g, "step", p)?,
            vectors: [vector("position")?, vector("force")?, vector("displacement")?],
            scalars: [scalar("contact_area")?, scalar("indentation")?],
            contact_nodes,
        });
        h5(self.file.flush(), p, "flush")
    }

    /// Writes the tools' rows of the next output step (every process calls; rank 0's rows are
    /// written): call before `append`, which completes the step.
    pub fn append_tools(&mut self, time: f64, step: u64, rows: &[ToolRow]) -> Result<()> {
        let (k, p, root) = (self.n_steps, &self.path, self.root);
        let t = self
            .tools
            .as_ref()
            .ok_or_else(|| anyhow!("internal: the series has no tools"))?;
        if rows.len() != t.n {
            return Err(anyhow!("internal: {} tool rows for {} tools", rows.len(), t.n));
        }
        let n = t.n;
        h5(t.time.resize([k + 1]), p, "tools/time")?;
        h5(t.step.resize([k + 1]), p, "tools/step")?;
        for d in &t.vectors {
            h5(d.resize([k + 1, n, 3]), p, "tools")?;
        }
        for d in t.scalars.iter().chain([&t.contact_nodes]) {
            h5(d.resize([k + 1, n]), p, "tools")?;
        }
        if root {
            h5(t.time.write_slice(&[time], s![k..k + 1]), p, "tools/time")?;
            h5(t.step.write_slice(&[step as i64], s![k..k + 1]), p, "tools/step")?;
            let pick = |f: fn(&ToolRow) -> [f64; 3]| rows.iter().flat_map(f).collect::<Vec<f64>>();
            let vectors = [pick(|r| r.position), pick(|r| r.force), pick(|r| r.displacement)];
            for (d, v) in t.vectors.iter().zip(&vectors) {
                let view = ArrayView3::from_shape((1, n, 3), v).unwrap();
                h5(d.write_slice(view, s![k..k + 1, .., ..]), p, "tools")?;
            }
            let area: Vec<f64> = rows.iter().map(|r| r.contact_area).collect();
            let depth: Vec<f64> = rows.iter().map(|r| r.indentation).collect();
            for (d, v) in t.scalars.iter().zip([area, depth]) {
                let view = ndarray::ArrayView2::from_shape((1, n), &v).unwrap();
                h5(d.write_slice(view, s![k..k + 1, ..]), p, "tools")?;
            }
            let count: Vec<i64> = rows.iter().map(|r| r.contact_nodes as i64).collect();
            let view = ndarray::ArrayView2::from_shape((1, n), &count).unwrap();
            h5(t.contact_nodes.write_slice(view, s![k..k + 1, ..]), p, "tools")?;
        }
        Ok(())
    }

    /// Appends one output step (every process calls): `data[f]` holds field f for this
    /// process's block of nodes (node-major, components interleaved); `probes[l]` = (applied
    /// force, contact displacement) of load l (used on rank 0).
    pub fn append(&mut self, time: f64, step: u64, data: &[&[f64]], probes: &[([f64; 3], [f64; 3])]) -> Result<()> {
        let k = self.n_steps;
        let n = self.n_points;
        let (b0, bl) = self.block;
        let p = &self.path;
        let root = self.root;
        for (f, d) in self.fields.iter().zip(data) {
            if f.ncomp == 1 {
                h5(f.data.resize([(k + 1) * n]), p, &f.name)?;
            } else {
                h5(f.data.resize([(k + 1) * n, f.ncomp]), p, &f.name)?;
            }
            write_rows(&f.data, k * n + b0, bl, f.ncomp, d, self.parallel)
                .with_context(|| format!("{}: {}", p.display(), f.name))?;
            h5(f.offsets.resize([k + 1]), p, &f.name)?;
            if root {
                h5(f.offsets.write_slice(&[(k * n) as i64], s![k..k + 1]), p, &f.name)?;
            }
        }
        for (i, ds) in self.step_sets.iter().enumerate() {
            let v = if i == 1 { 1i64 } else { 0 };
            h5(ds.resize([k + 1]), p, "Steps")?;
            if root {
                h5(ds.write_slice(&[v], s![k..k + 1]), p, "Steps")?;
            }
        }
        h5(self.values.resize([k + 1]), p, "Values")?;
        let nl = self.n_loads;
        let mut fr = vec![0.0; nl * 3];
        let mut ds = vec![0.0; nl * 3];
        for (l, (f, u)) in probes.iter().enumerate().take(nl) {
            fr[3 * l..3 * l + 3].copy_from_slice(f);
            ds[3 * l..3 * l + 3].copy_from_slice(u);
        }
        h5(self.probe_time.resize([k + 1]), p, "probes")?;
        h5(self.probe_step.resize([k + 1]), p, "probes")?;
        for dset in [&self.probe_force, &self.probe_disp] {
            h5(dset.resize([k + 1, nl, 3]), p, "probes")?;
        }
        if root {
            h5(self.values.write_slice(&[time], s![k..k + 1]), p, "Values")?;
            h5(self.probe_time.write_slice(&[time], s![k..k + 1]), p, "probes")?;
            h5(self.probe_step.write_slice(&[step as i64], s![k..k + 1]), p, "probes")?;
            for (dset, v) in [(&self.probe_force, &fr), (&self.probe_disp, &ds)] {
                let view = ArrayView3::from_shape((1, nl, 3), v).unwrap();
                h5(dset.write_slice(view, s![k..k + 1, .., ..]), p, "probes")?;
            }
        }
        self.n_steps = k + 1;
        let ns = self.n_steps as i64;
        h5(self.steps.attr("NSteps").and_then(|a| a.write_scalar(&ns)), p, "NSteps")?;
        h5(
            self.file
                .group("eprop")
                .and_then(|g| g.attr("steps_complete"))
                .and_then(|a| a.write_scalar(&ns)),
            p,
            "steps_complete",
        )?;
        h5(self.file.flush(), p, "flush").context("writing an output step")?;
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
        let file = match comm {
            Some(c) => {
                use mpi::raw::AsRaw;
                let raw = c.as_raw();
                File::with_options().with_fapl(|p| p.mpio(raw, None)).open_rw(path)
            }
            None => File::with_options().with_fapl(|p| p.file_locking(false)).open_rw(path),
        }
        .map_err(|e| {
            anyhow!(
                "{}: cannot open the file to restart: {e}; fix: give the output file of the interrupted run",
                path.display()
            )
        })?;
        let bad = |what: String| {
            anyhow!(
                "{}: cannot restart: {what}; fix: restart with the scenario and mesh that wrote the file, or start a new run",
                path.display()
            )
        };
        let ep = file
            .group("eprop")
            .map_err(|_| bad("no /eprop group (not an eprop series)".into()))?;
        for (name, v) in &spec.ids {
            let got: u64 = ep
                .attr(name)
                .and_then(|a| a.read_scalar())
                .map_err(|_| bad(format!("no {name} attribute")))?;
            if got != *v {
                return Err(bad(format!(
                    "it was written for a different {}",
                    name.trim_end_matches("_hash")
                )));
            }
        }
        let f32_file: u8 = ep.attr("float32").and_then(|a| a.read_scalar()).unwrap_or(0);
        if f32_file != 0 || spec.float32 {
            return Err(bad(
                "float32 output cannot restart exactly (precision = \"float64\" is)".into(),
            ));
        }
        let n: i64 = h5(
            file.dataset("VTKHDF/NumberOfPoints").and_then(|d| d.read_raw::<i64>()),
            path,
            "NumberOfPoints",
        )?[0];
        if n as usize != layout.nodes {
            return Err(bad(format!("the file has {n} nodes, the mesh {}", layout.nodes)));
        }
        let k: i64 = h5(
            ep.attr("steps_complete").and_then(|a| a.read_scalar()),
            path,
            "steps_complete",
        )?;
        if k < 1 {
            return Err(bad("the file holds no complete step".into()));
        }
        let k = k as usize;
        let top = h5(file.group("VTKHDF"), path, "VTKHDF")?;
        let pd = h5(top.group("PointData"), path, "PointData")?;
        let steps = h5(top.group("Steps"), path, "Steps")?;
        let pdo = h5(steps.group("PointDataOffsets"), path, "PointDataOffsets")?;
        let mut fields = Vec::new();
        for &(name, ncomp) in &spec.fields {
            let data = pd.dataset(name).map_err(|_| bad(format!("no field {name}")))?;
            let offsets = h5(pdo.dataset(name), path, name)?;
            fields.push(Field {
                name: name.to_string(),
                ncomp,
                data,
                offsets,
            });
        }
        let nd = layout.nodes;
        // the state at the last complete step
        let (b0, bl) = (spec.block_start, spec.block_len);
        let mut state = Vec::new();
        for name in ["displacement", "velocity", "potential"] {
            let f = fields
                .iter()
                .find(|f| f.name == name)
                .ok_or_else(|| bad(format!("the run did not write `{name}`, which a restart needs")))?;
            let rows = (k - 1) * nd + b0;
            let v = h5(f.data.read_slice_2d::<f64, _>(s![rows..rows + bl, ..]), path, name)?;
            state.push(v.iter().copied().collect::<Vec<f64>>());
        }
        let values = h5(steps.dataset("Values"), path, "Values")?;
        let time = h5(values.read_slice_1d::<f64, _>(s![k - 1..k]), path, "Values")?[0];
        let pr = h5(ep.group("probes"), path, "probes")?;
        let probe_step = h5(pr.dataset("step"), path, "probes/step")?;
        let step = h5(probe_step.read_slice_1d::<i64, _>(s![k - 1..k]), path, "probes/step")?[0];
        let step_sets = [
            "PartOffsets",
            "NumberOfParts",
            "PointOffsets",
            "CellOffsets",
            "ConnectivityIdOffsets",
        ]
        .iter()
        .map(|nm| h5(steps.dataset(nm), path, nm))
        .collect::<Result<Vec<_>>>()?;
        let w = SeriesWriter {
            path: path.to_path_buf(),
            n_points: nd,
            block: (b0, bl),
            root,
            parallel,
            fields,
            step_sets,
            values,
            probe_time: h5(pr.dataset("time"), path, "probes/time")?,
            probe_step,
            probe_force: h5(pr.dataset("force"), path, "probes/force")?,
            probe_disp: h5(pr.dataset("displacement"), path, "probes/displacement")?,
            n_loads: spec.n_loads.max(1),
            n_steps: k,
            steps,
            file,
            tools: None,
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

    /// Cuts every growing dataset to the complete steps.
    fn truncate(&self) -> Result<()> {
        let (k, n, p) = (self.n_steps, self.n_points, &self.path);
        for f in &self.fields {
            if f.ncomp == 1 {
                h5(f.data.resize([k * n]), p, &f.name)?;
            } else {
                h5(f.data.resize([k * n, f.ncomp]), p, &f.name)?;
            }
            h5(f.offsets.resize([k]), p, &f.name)?;
        }
        for ds in self
            .step_sets
            .iter()
            .chain([&self.values, &self.probe_time, &self.probe_step])
        {
            h5(ds.resize([k]), p, "Steps")?;
        }
        for ds in [&self.probe_force, &self.probe_disp] {
            h5(ds.resize([k, self.n_loads, 3]), p, "probes")?;
        }
        h5(self.file.flush(), p, "flush")
    }

    pub fn steps_written(&self) -> usize {
        self.n_steps
    }
    pub fn path(&self) -> &Path {
        &self.path
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
