//! Time-series output in the VTKHDF 2.x temporal UnstructuredGrid layout.
//!
//! `/VTKHDF` holds the static mesh once (one partition) and the point data of every output
//! step appended along the first axis; `/VTKHDF/Steps` maps step k to the rows
//! `k*N .. (k+1)*N` of each point-data array (the mesh offsets stay 0). `/eprop` holds what VTK
//! does not model: the scenario text, the program version, control volumes, input node ids,
//! per-load probes and the count of complete steps. Every dataset that grows per step is
//! chunked and extendible, so appending step k costs the same for every k.

use crate::mesh::{CellKind, Mesh};
use anyhow::{anyhow, Context, Result};
use hdf5::types::{FixedAscii, VarLenUnicode};
use hdf5::{Dataset, Extent, File};
use ndarray::{s, ArrayView1, ArrayView2, ArrayView3};
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// What a series holds besides the mesh.
pub struct SeriesSpec<'a> {
    /// Point arrays written every output step: (name, components).
    pub fields: Vec<(&'a str, usize)>,
    /// Number of loads (probes per step).
    pub n_loads: usize,
    /// Contact node of each load (input order index), stored once.
    pub load_nodes: Vec<u64>,
    /// The scenario text, stored verbatim.
    pub scenario: &'a str,
    /// Program name and version.
    pub version: &'a str,
    /// Control volume V_i of each node.
    pub control_volumes: &'a [f64],
    /// Extra scalar attributes on `/eprop` (name, value).
    pub attrs: Vec<(&'a str, f64)>,
}

struct Field {
    name: String,
    ncomp: usize,
    data: Dataset,
    offsets: Dataset,
}

/// Appends output steps to one VTKHDF file.
pub struct SeriesWriter {
    path: PathBuf,
    file: File,
    n_points: usize,
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
    h5(
        group.new_dataset::<f64>().chunk(chunk).shape(ext).create(name),
        path,
        &format!("create {name}"),
    )
}

fn growing_i64(group: &hdf5::Group, name: &str, path: &Path) -> Result<Dataset> {
    h5(
        group
            .new_dataset::<i64>()
            .chunk(1024)
            .shape(Extent::resizable(0))
            .create(name),
        path,
        &format!("create {name}"),
    )
}

/// VTK connectivity order of a cell (VTK wedges wind their first triangle the other way).
pub fn vtk_order(kind: CellKind, nodes: &[u32]) -> Vec<u32> {
    match kind {
        CellKind::Wedge => vec![nodes[0], nodes[2], nodes[1], nodes[3], nodes[5], nodes[4]],
        _ => nodes.to_vec(),
    }
}

impl SeriesWriter {
    /// Creates (truncates) the file and writes the static mesh.
    pub fn create(path: &Path, mesh: &Mesh, spec: &SeriesSpec) -> Result<Self> {
        let file = File::create(path).map_err(|e| {
            anyhow!(
                "{}: cannot create the output file: {e}; fix: check that the directory exists and is writable",
                path.display()
            )
        })?;
        let n = mesh.n_nodes();
        let root = h5(file.create_group("VTKHDF"), path, "create /VTKHDF")?;
        h5(
            root.new_attr::<i64>()
                .shape([2])
                .create("Version")
                .and_then(|a| a.write(&[2i64, 1])),
            path,
            "Version",
        )?;
        let ty = FixedAscii::<16>::from_ascii(b"UnstructuredGrid").unwrap();
        h5(
            root.new_attr::<FixedAscii<16>>()
                .create("Type")
                .and_then(|a| a.write_scalar(&ty)),
            path,
            "Type",
        )?;

        let mut conn: Vec<i64> = Vec::with_capacity(mesh.conn.len());
        let mut offs: Vec<i64> = Vec::with_capacity(mesh.n_cells() + 1);
        let mut types: Vec<u8> = Vec::with_capacity(mesh.n_cells());
        offs.push(0);
        for c in 0..mesh.n_cells() {
            conn.extend(vtk_order(mesh.kinds[c], mesh.cell(c)).iter().map(|&x| x as i64));
            offs.push(conn.len() as i64);
            types.push(mesh.kinds[c].vtk_type());
        }
        let pts: Vec<f64> = mesh.points.iter().flatten().copied().collect();
        let w1 = |name: &str, v: &[i64]| {
            h5(
                root.new_dataset_builder().with_data(v).create(name).map(|_| ()),
                path,
                name,
            )
        };
        w1("NumberOfPoints", &[n as i64])?;
        w1("NumberOfCells", &[mesh.n_cells() as i64])?;
        w1("NumberOfConnectivityIds", &[conn.len() as i64])?;
        w1("Connectivity", &conn)?;
        w1("Offsets", &offs)?;
        h5(
            root.new_dataset_builder().with_data(&types).create("Types"),
            path,
            "Types",
        )?;
        let pv = ArrayView2::from_shape((n, 3), &pts).unwrap();
        h5(
            root.new_dataset_builder().with_data(pv).create("Points"),
            path,
            "Points",
        )?;

        let pd = h5(root.create_group("PointData"), path, "PointData")?;
        let steps = h5(root.create_group("Steps"), path, "Steps")?;
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
            let data = if ncomp == 1 {
                growing(&pd, name, &[], rows, path)?
            } else {
                growing(&pd, name, &[ncomp], rows, path)?
            };
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
        let sc = VarLenUnicode::from_str(spec.scenario).unwrap();
        h5(
            ep.new_dataset::<VarLenUnicode>()
                .create("scenario")
                .and_then(|d| d.write_scalar(&sc)),
            path,
            "scenario",
        )?;
        h5(
            ep.new_dataset_builder()
                .with_data(spec.control_volumes)
                .create("control_volumes"),
            path,
            "control_volumes",
        )?;
        let ids: Vec<i64> = mesh.node_ids.iter().map(|&x| x as i64).collect();
        h5(
            ep.new_dataset_builder().with_data(&ids).create("node_ids"),
            path,
            "node_ids",
        )?;
        h5(
            ep.new_dataset_builder().with_data(&mesh.cell_tags).create("cell_tags"),
            path,
            "cell_tags",
        )?;
        let pr = h5(ep.create_group("probes"), path, "probes")?;
        let ln: Vec<i64> = spec.load_nodes.iter().map(|&x| x as i64).collect();
        h5(
            pr.new_dataset_builder().with_data(&ln).create("node"),
            path,
            "probes/node",
        )?;
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
        })
    }

    /// Appends one output step: `data[f]` holds field f for every node (node-major, components
    /// interleaved); `probes[l]` = (applied force, contact displacement) of load l.
    pub fn append(&mut self, time: f64, step: u64, data: &[&[f64]], probes: &[([f64; 3], [f64; 3])]) -> Result<()> {
        let k = self.n_steps;
        let n = self.n_points;
        let p = &self.path;
        for (f, d) in self.fields.iter().zip(data) {
            if d.len() != n * f.ncomp {
                return Err(anyhow!(
                    "field {} has {} values, expected {}",
                    f.name,
                    d.len(),
                    n * f.ncomp
                ));
            }
            if f.ncomp == 1 {
                h5(f.data.resize([(k + 1) * n]), p, &f.name)?;
                h5(
                    f.data.write_slice(ArrayView1::from(*d), s![k * n..(k + 1) * n]),
                    p,
                    &f.name,
                )?;
            } else {
                h5(f.data.resize([(k + 1) * n, f.ncomp]), p, &f.name)?;
                let v = ArrayView2::from_shape((n, f.ncomp), d).unwrap();
                h5(f.data.write_slice(v, s![k * n..(k + 1) * n, ..]), p, &f.name)?;
            }
            h5(f.offsets.resize([k + 1]), p, &f.name)?;
            h5(f.offsets.write_slice(&[(k * n) as i64], s![k..k + 1]), p, &f.name)?;
        }
        for (i, ds) in self.step_sets.iter().enumerate() {
            let v = if i == 1 { 1i64 } else { 0 };
            h5(ds.resize([k + 1]), p, "Steps")?;
            h5(ds.write_slice(&[v], s![k..k + 1]), p, "Steps")?;
        }
        h5(self.values.resize([k + 1]), p, "Values")?;
        h5(self.values.write_slice(&[time], s![k..k + 1]), p, "Values")?;
        let nl = self.n_loads;
        let mut fr = vec![0.0; nl * 3];
        let mut ds = vec![0.0; nl * 3];
        for (l, (f, u)) in probes.iter().enumerate().take(nl) {
            fr[3 * l..3 * l + 3].copy_from_slice(f);
            ds[3 * l..3 * l + 3].copy_from_slice(u);
        }
        h5(self.probe_time.resize([k + 1]), p, "probes")?;
        h5(self.probe_time.write_slice(&[time], s![k..k + 1]), p, "probes")?;
        h5(self.probe_step.resize([k + 1]), p, "probes")?;
        h5(self.probe_step.write_slice(&[step as i64], s![k..k + 1]), p, "probes")?;
        for (dset, v) in [(&self.probe_force, &fr), (&self.probe_disp, &ds)] {
            h5(dset.resize([k + 1, nl, 3]), p, "probes")?;
            let view = ArrayView3::from_shape((1, nl, 3), v).unwrap();
            h5(dset.write_slice(view, s![k..k + 1, .., ..]), p, "probes")?;
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
