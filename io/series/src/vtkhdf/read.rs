//! Readers of a series: its header checked against the extents of its datasets before
//! anything is allocated from it (`SeriesFile`), its steps and rest mesh, what a file is
//! (`kind_of`), and the operator files of `export-operator`.

use super::COUNT;
use anyhow::{anyhow, Result};
use eprop_io::mesh::Mesh;
use hdf5::types::VarLenUnicode;
use hdf5::File;
use ndarray::s;
use std::path::{Path, PathBuf};

/// A series opened for reading. Its counts (`steps_complete`, `NumberOfPoints`, cells and
/// connectivity) were checked against the extents of the datasets they describe, so a damaged
/// or edited header is refused by name before anything is read or allocated from it.
pub struct SeriesFile {
    path: PathBuf,
    file: File,
    /// Points of the mesh (`NumberOfPoints`, the rows of `Points`).
    pub nodes: usize,
    /// Complete output steps (the counter): every point array and the probes hold them.
    pub steps: usize,
}

/// The refusal of a damaged series: what is wrong, and the fix.
fn damaged(path: &Path, what: String) -> anyhow::Error {
    anyhow!(
        "{}: a damaged series: {what}; fix: restore the file from a copy, or write it again (eprop run ... --overwrite)",
        path.display()
    )
}

/// The one value of a count dataset (`/VTKHDF/NumberOfPoints`, ...), which must hold one.
fn one(f: &File, path: &Path, name: &str) -> Result<i64> {
    let v = f
        .dataset(name)
        .and_then(|d| d.read_raw::<i64>())
        .map_err(|e| damaged(path, format!("no readable {name} ({e})")))?;
    match v.as_slice() {
        [x] => Ok(*x),
        _ => Err(damaged(path, format!("{name} holds {} values, not one", v.len()))),
    }
}

/// The count of complete steps of an open file: the counter `/eprop/steps_complete`, or in a
/// series written before it was a dataset, the attribute of that name (None: neither).
pub(super) fn count_of(f: &File) -> Option<i64> {
    let ep = f.group("eprop").ok()?;
    if ep.link_exists(COUNT) {
        return ep
            .dataset(COUNT)
            .and_then(|d| d.read_raw::<i64>())
            .ok()?
            .first()
            .copied();
    }
    ep.attr(COUNT).and_then(|a| a.read_scalar()).ok()
}

impl SeriesFile {
    /// Opens a series (read only) and checks its header.
    pub fn open(path: &Path) -> Result<SeriesFile> {
        let file = File::open(path).map_err(|e| anyhow!("{}: cannot open: {e}", path.display()))?;
        if file.group("VTKHDF").is_err() || file.group("eprop").is_err() {
            return Err(anyhow!(
                "{}: not an eprop series (no /VTKHDF or /eprop group); fix: give a series written by eprop run",
                path.display()
            ));
        }
        let k = count_of(&file).ok_or_else(|| {
            anyhow!(
                "{}: not an eprop series (no /eprop steps_complete); fix: give a series written by eprop run",
                path.display()
            )
        })?;
        let n = one(&file, path, "VTKHDF/NumberOfPoints")?;
        let cells = one(&file, path, "VTKHDF/NumberOfCells")?;
        let conn = one(&file, path, "VTKHDF/NumberOfConnectivityIds")?;
        let shape = |name: &str| -> Result<Vec<usize>> {
            file.dataset(name)
                .map(|d| d.shape())
                .map_err(|e| damaged(path, format!("no readable {name} ({e})")))
        };
        let points = shape("VTKHDF/Points")?;
        if n < 1 || points != [n as usize, 3] {
            return Err(damaged(
                path,
                format!("/VTKHDF/NumberOfPoints is {n} but /VTKHDF/Points holds {points:?} values"),
            ));
        }
        if cells < 1 || conn < 1 {
            return Err(damaged(
                path,
                format!("/VTKHDF/NumberOfCells is {cells} and NumberOfConnectivityIds {conn}"),
            ));
        }
        for (name, want, what) in [
            ("VTKHDF/Types", cells, "NumberOfCells"),
            ("VTKHDF/Offsets", cells.saturating_add(1), "NumberOfCells + 1"),
            ("VTKHDF/Connectivity", conn, "NumberOfConnectivityIds"),
        ] {
            let got = shape(name)?;
            if got != [want as usize] {
                return Err(damaged(
                    path,
                    format!("/{name} holds {got:?} entries, but {what} is {want}"),
                ));
            }
        }
        let n = n as usize;
        // the count against the rows that hold it: every point array, the probes' steps and times
        let pd = file
            .group("VTKHDF/PointData")
            .map_err(|e| damaged(path, format!("no /VTKHDF/PointData ({e})")))?;
        let mut held: Vec<(String, usize)> = Vec::new();
        for name in pd.member_names().unwrap_or_default() {
            let rows = shape(&format!("VTKHDF/PointData/{name}"))?
                .first()
                .copied()
                .unwrap_or(0);
            held.push((format!("/VTKHDF/PointData/{name}"), rows / n));
        }
        for name in ["eprop/probes/time", "eprop/probes/step"] {
            held.push((format!("/{name}"), shape(name)?.first().copied().unwrap_or(0)));
        }
        for (name, steps) in &held {
            if k < 0 || k as u64 > *steps as u64 {
                return Err(damaged(
                    path,
                    format!("/eprop steps_complete is {k} but {name} holds {steps} steps (of {n} points)"),
                ));
            }
        }
        Ok(SeriesFile {
            path: path.to_path_buf(),
            file,
            nodes: n,
            steps: k as usize,
        })
    }

    /// Point array `name` of output step `k` (node-major, components interleaved).
    pub fn read_step(&self, name: &str, k: usize) -> Result<Vec<f64>> {
        let path = &self.path;
        if k >= self.steps {
            return Err(anyhow!(
                "{}: step {k} is not in the file ({} complete steps)",
                path.display(),
                self.steps
            ));
        }
        let ds = self
            .file
            .dataset(&format!("VTKHDF/PointData/{name}"))
            .map_err(|e| anyhow!("{}: no field {name}: {e}", path.display()))?;
        let n = self.nodes;
        let read = match ds.shape().len() {
            1 => ds.read_slice_1d::<f64, _>(s![k * n..(k + 1) * n]).map(|v| v.to_vec()),
            _ => ds
                .read_slice_2d::<f64, _>(s![k * n..(k + 1) * n, ..])
                .map(|v| v.iter().copied().collect()),
        };
        read.map_err(|e| anyhow!("{}: reading {name} of step {k}: {e}", path.display()))
    }

    /// The rest mesh the series was written for (points, cells and their tags as it holds them).
    pub fn mesh(&self) -> Result<Mesh> {
        let (f, path) = (&self.file, &self.path);
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
        let d = eprop_io::vtk::VtkData {
            points,
            conn,
            starts,
            types,
            cell_arrays: vec![],
            point_arrays: vec![],
        };
        eprop_io::vtk::build(&path.display().to_string(), d)
    }
}

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
    match (version, count_of(&h)) {
        (Some(v), Some(steps)) if v.as_str().starts_with("eprop") && h.group("VTKHDF").is_ok() => Ok(Kind::Series {
            steps,
            version: v.as_str().to_string(),
        }),
        _ => Ok(Kind::OtherHdf5),
    }
}

/// Reads point array `name` of output step `k` (node-major, components interleaved) of the
/// series at `path` (its header checked: `SeriesFile`).
pub fn read_step(path: &Path, name: &str, k: usize) -> Result<Vec<f64>> {
    SeriesFile::open(path)?.read_step(name, k)
}

/// The scenario text a series was written with (`/eprop/scenario`: the file's text with its
/// `--set` overrides; empty when the series holds none).
pub fn read_scenario(path: &Path) -> Result<String> {
    let f = SeriesFile::open(path)?;
    let bytes = match f.file.dataset("eprop/scenario") {
        Ok(d) => h5(d.read_raw::<u8>(), path, "reading /eprop/scenario")?,
        Err(_) => Vec::new(),
    };
    Ok(String::from_utf8_lossy(&bytes).into_owned())
}

/// The rest mesh a series was written for, and its complete steps (its header checked:
/// `SeriesFile`).
pub fn read_mesh(path: &Path) -> Result<(Mesh, usize)> {
    let f = SeriesFile::open(path)?;
    Ok((f.mesh()?, f.steps))
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
