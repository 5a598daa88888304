//! A mesh alone in VTKHDF (`eprop convert any.msh mesh.vtkhdf`): the `/VTKHDF`
//! UnstructuredGrid of a series without its steps or `/eprop`, with the cell tags as cell data
//! (`CellData/tag`) and the input node ids as point data (`PointData/node_ids`). It is the
//! mesh format that the processes of a job read in slabs (`read_slab`): each its contiguous
//! share of the cells and of the points, none the whole mesh.
//!
//! What it keeps: points, volume cells (in VTK's node order, as a series holds them), their
//! tags and the node ids. Boundary facets and physical group names are not kept.

use super::access;
use anyhow::{anyhow, bail, Result};
use eprop_io::mesh::{CellKind, Mesh};
use eprop_io::vtk::{volume_cell, vtk_order};
use hdf5::types::FixedAscii;
use hdf5::File;
use ndarray::s;
use std::path::Path;

fn h5<T>(r: hdf5::Result<T>, path: &Path, what: &str) -> Result<T> {
    r.map_err(|e| anyhow!("{}: {what}: {e}", path.display()))
}

/// Writes `mesh` as a VTKHDF UnstructuredGrid (one process; the file created or truncated).
pub fn write_mesh_file(mesh: &Mesh, path: &Path) -> Result<()> {
    let f = h5(File::create(path), path, "cannot create")?;
    let top = h5(f.create_group("VTKHDF"), path, "creating /VTKHDF")?;
    h5(
        top.new_attr::<i64>()
            .shape([2])
            .create("Version")
            .and_then(|a| a.write(&[2i64, 1])),
        path,
        "writing Version",
    )?;
    let ty = FixedAscii::<16>::from_ascii(b"UnstructuredGrid").map_err(|e| anyhow!("internal: {e}"))?;
    h5(
        top.new_attr::<FixedAscii<16>>()
            .create("Type")
            .and_then(|a| a.write_scalar(&ty)),
        path,
        "writing Type",
    )?;
    let mut conn: Vec<i64> = Vec::with_capacity(mesh.conn.len());
    let mut offs: Vec<i64> = Vec::with_capacity(mesh.n_cells() + 1);
    offs.push(0);
    for c in 0..mesh.n_cells() {
        conn.extend(vtk_order(mesh.kinds[c], mesh.cell(c)).iter().map(|&x| x as i64));
        offs.push(conn.len() as i64);
    }
    let types: Vec<u8> = mesh.kinds.iter().map(|k| k.vtk_type()).collect();
    let n = mesh.n_nodes();
    for (name, v) in [
        ("NumberOfPoints", n as i64),
        ("NumberOfCells", mesh.n_cells() as i64),
        ("NumberOfConnectivityIds", conn.len() as i64),
    ] {
        h5(top.new_dataset_builder().with_data(&[v]).create(name), path, name)?;
    }
    h5(
        top.new_dataset_builder().with_data(&conn).create("Connectivity"),
        path,
        "Connectivity",
    )?;
    drop(conn);
    h5(
        top.new_dataset_builder().with_data(&offs).create("Offsets"),
        path,
        "Offsets",
    )?;
    h5(
        top.new_dataset_builder().with_data(&types).create("Types"),
        path,
        "Types",
    )?;
    let pts = ndarray::Array2::from_shape_vec((n, 3), mesh.points.iter().flatten().copied().collect())
        .map_err(|e| anyhow!("internal: {e}"))?;
    h5(
        top.new_dataset_builder().with_data(&pts).create("Points"),
        path,
        "Points",
    )?;
    let cd = h5(top.create_group("CellData"), path, "creating CellData")?;
    let tags: Vec<i64> = mesh.cell_tags.iter().map(|&t| t as i64).collect();
    h5(
        cd.new_dataset_builder().with_data(&tags).create("tag"),
        path,
        "CellData/tag",
    )?;
    let pd = h5(top.create_group("PointData"), path, "creating PointData")?;
    let ids: Vec<i64> = mesh.node_ids.iter().map(|&i| i as i64).collect();
    h5(
        pd.new_dataset_builder().with_data(&ids).create("node_ids"),
        path,
        "PointData/node_ids",
    )?;
    Ok(())
}

/// One process's slab of a VTKHDF mesh: the cells `cell_start..cell_start + n_cells()` and
/// the points `node_start..node_start + points.len()` of the whole mesh, whose sizes are
/// `nodes` and `cells`. The connectivity names global node indices, in eprop's node order.
#[derive(Clone, Debug, Default)]
pub struct MeshSlab {
    pub nodes: usize,
    pub cells: usize,
    pub node_start: usize,
    pub points: Vec<[f64; 3]>,
    pub node_ids: Vec<u64>,
    pub cell_start: usize,
    /// The first of the slab's connectivity ids in the whole mesh's connectivity.
    pub conn_start: usize,
    pub kinds: Vec<CellKind>,
    /// `offsets[c]..offsets[c + 1]` indexes `conn` for local cell c (from 0).
    pub offsets: Vec<usize>,
    pub conn: Vec<u32>,
    pub cell_tags: Vec<i32>,
}

impl MeshSlab {
    pub fn n_cells(&self) -> usize {
        self.kinds.len()
    }

    /// Global node indices of local cell `c`.
    pub fn cell(&self, c: usize) -> &[u32] {
        &self.conn[self.offsets[c]..self.offsets[c + 1]]
    }
}

/// The first of `n` things that process `r` of `size` holds (`block(n, size, size) == n`):
/// contiguous blocks of nearly equal length, as `Slab::of` cuts a graph.
pub fn block(n: usize, size: usize, r: usize) -> usize {
    (r as u128 * n as u128 / size as u128) as usize
}

/// The connectivity ids `read_slab` reads at a time (8 MiB as int64).
const CONNECTIVITY_CHUNK: i64 = 1 << 20;

/// Reads process `rank`'s slab (of `size`) of the VTKHDF mesh at `path`: under MPI (`comm`)
/// the file is opened by every process of `comm` together (MPI-IO), each reading its own
/// rows; without, the whole mesh is one slab. A file that is not such a mesh, or whose arrays
/// disagree with its counts, is refused by name (on the process that finds it: the caller
/// agrees the outcome).
pub fn read_slab(path: &Path, comm: Option<&mpi::topology::SimpleCommunicator>) -> Result<MeshSlab> {
    read_slab_in(path, comm, CONNECTIVITY_CHUNK)
}

/// `read_slab` reading the connectivity `chunk` ids at a time (at least one cell).
fn read_slab_in(path: &Path, comm: Option<&mpi::topology::SimpleCommunicator>, chunk: i64) -> Result<MeshSlab> {
    use mpi::topology::Communicator;
    let (rank, size) = comm.map_or((0, 1), |c| (c.rank() as usize, c.size() as usize));
    let f = h5(access(comm).open(path), path, "cannot open")?;
    let top = f.group("VTKHDF").map_err(|_| {
        anyhow!(
            "{}: not a VTKHDF mesh (no /VTKHDF group); fix: write one with eprop convert MESH FILE.vtkhdf",
            path.display()
        )
    })?;
    let one = |name: &str| -> Result<usize> {
        let v: Vec<i64> = h5(top.dataset(name).and_then(|d| d.read_raw::<i64>()), path, name)?;
        match v.as_slice() {
            [x] if *x >= 0 => Ok(*x as usize),
            _ => bail!("{}: /VTKHDF/{name} must hold one count, not {v:?}", path.display()),
        }
    };
    let (nodes, cells, nconn) = (
        one("NumberOfPoints")?,
        one("NumberOfCells")?,
        one("NumberOfConnectivityIds")?,
    );
    let ds = |name: &str| h5(top.dataset(name), path, name);
    let check = |name: &str, want: &[usize]| -> Result<hdf5::Dataset> {
        let d = ds(name)?;
        if d.shape() != want {
            bail!(
                "{}: /VTKHDF/{name} holds {:?} values, but the counts say {want:?}",
                path.display(),
                d.shape()
            );
        }
        Ok(d)
    };
    let (c0, c1) = (block(cells, size, rank), block(cells, size, rank + 1));
    let (p0, p1) = (block(nodes, size, rank), block(nodes, size, rank + 1));
    let starts: Vec<i64> = h5(
        check("Offsets", &[cells + 1])?.read_slice_1d::<i64, _>(s![c0..=c1]),
        path,
        "Offsets",
    )?
    .to_vec();
    let (k0, k1) = (starts[0], starts[starts.len() - 1]);
    if k0 < 0 || k1 < k0 || k1 as usize > nconn || starts.windows(2).any(|w| w[1] < w[0]) {
        bail!(
            "{}: /VTKHDF/Offsets of cells {c0}..{c1} are not increasing within the {nconn} connectivity ids",
            path.display()
        );
    }
    let read_1d = |d: &hdf5::Dataset, a: usize, b: usize, name: &str| -> Result<Vec<i64>> {
        if a == b {
            return Ok(vec![]);
        }
        Ok(h5(d.read_slice_1d::<i64, _>(s![a..b]), path, name)?.to_vec())
    };
    let connectivity = check("Connectivity", &[nconn])?;
    let types: Vec<u8> = match c0 == c1 {
        true => vec![],
        false => h5(
            check("Types", &[cells])?.read_slice_1d::<u8, _>(s![c0..c1]),
            path,
            "Types",
        )?
        .to_vec(),
    };
    let tags = match top.link_exists("CellData") && top.link_exists("CellData/tag") {
        true => read_1d(&check("CellData/tag", &[cells])?, c0, c1, "CellData/tag")?,
        false => vec![0; c1 - c0],
    };
    let mut slab = MeshSlab {
        nodes,
        cells,
        node_start: p0,
        cell_start: c0,
        conn_start: k0 as usize,
        offsets: Vec::with_capacity(c1 - c0 + 1),
        conn: Vec::with_capacity((k1 - k0) as usize),
        kinds: Vec::with_capacity(c1 - c0),
        cell_tags: Vec::with_capacity(c1 - c0),
        ..Default::default()
    };
    slab.offsets.push(0);
    // the connectivity is read in chunks of whole cells, each narrowed to u32 as it comes
    // (not the slab's whole connectivity as int64 at once)
    let (mut raw, mut from, mut to) = (Vec::new(), k0, k0);
    for c in 0..c1 - c0 {
        if starts[c + 1] > to {
            let end = (c + 1..=c1 - c0)
                .take_while(|&e| starts[e] - starts[c] <= chunk)
                .last()
                .unwrap_or(c + 1)
                .max(c + 1);
            (from, to) = (starts[c], starts[end]);
            raw = read_1d(&connectivity, from as usize, to as usize, "Connectivity")?;
        }
        let (s, e) = ((starts[c] - from) as usize, (starts[c + 1] - from) as usize);
        let vtk = &raw[s..e];
        let Some((kind, perm)) = volume_cell(types[c] as i64) else {
            bail!(
                "{}: cell {} is of VTK type {}, not a volume cell eprop reads (tetrahedron, hexahedron, wedge, pyramid)",
                path.display(),
                c0 + c,
                types[c]
            );
        };
        if vtk.len() != perm.len() {
            bail!(
                "{}: cell {} ({}) has {} nodes, expected {}",
                path.display(),
                c0 + c,
                kind.name(),
                vtk.len(),
                perm.len()
            );
        }
        for &p in perm {
            let g = vtk[p];
            if g < 0 || g as u64 >= nodes as u64 {
                bail!("{}: cell {} names node {g} of {nodes}", path.display(), c0 + c);
            }
            slab.conn.push(g as u32);
        }
        slab.offsets.push(slab.conn.len());
        slab.kinds.push(kind);
        let tag = tags[c];
        slab.cell_tags.push(
            i32::try_from(tag)
                .map_err(|_| anyhow!("{}: cell {} has tag {tag}, outside 32 bits", path.display(), c0 + c))?,
        );
    }
    drop(raw);
    if p0 < p1 {
        let pts = h5(
            check("Points", &[nodes, 3])?.read_slice_2d::<f64, _>(s![p0..p1, ..]),
            path,
            "Points",
        )?;
        slab.points = pts.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect();
        slab.node_ids = match top.link_exists("PointData") && top.link_exists("PointData/node_ids") {
            true => read_1d(&check("PointData/node_ids", &[nodes])?, p0, p1, "PointData/node_ids")?
                .into_iter()
                .map(|i| i as u64)
                .collect(),
            false => (p0 as u64..p1 as u64).collect(),
        };
    }
    Ok(slab)
}

#[cfg(test)]
mod tests {
    use super::*;
    use eprop_io::generate::{box_mesh, BoxCells};

    #[test]
    fn a_mesh_written_reads_back_in_slabs() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.vtkhdf");
        let mut m = box_mesh([1.0, 2.0, 3.0], [3, 2, 2], BoxCells::Wedge).unwrap();
        for (c, t) in m.cell_tags.iter_mut().enumerate() {
            *t = (c % 3) as i32 + 7;
        }
        m.node_ids.iter_mut().for_each(|i| *i = *i * 3 + 5);
        write_mesh_file(&m, &path).unwrap();
        let whole = read_slab(&path, None).unwrap();
        // the connectivity read a few ids at a time: the same slab
        for chunk in [1, 5, 13] {
            let by = read_slab_in(&path, None, chunk).unwrap();
            assert_eq!(
                (&by.conn, &by.offsets, &by.kinds),
                (&whole.conn, &whole.offsets, &whole.kinds)
            );
        }
        assert_eq!((whole.nodes, whole.cells), (m.n_nodes(), m.n_cells()));
        assert_eq!((&whole.points, &whole.node_ids), (&m.points, &m.node_ids));
        assert_eq!(
            (&whole.kinds, &whole.offsets, &whole.conn),
            (&m.kinds, &m.offsets, &m.conn)
        );
        assert_eq!(whole.cell_tags, m.cell_tags);
        // the blocks cover everything once, in order
        for size in 1..5 {
            assert_eq!(block(m.n_cells(), size, size), m.n_cells());
            let cuts: Vec<usize> = (0..=size).map(|r| block(m.n_nodes(), size, r)).collect();
            assert!(cuts.windows(2).all(|w| w[0] <= w[1]));
        }
    }

    #[test]
    fn another_hdf5_file_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.h5");
        File::create(&path).unwrap();
        let e = read_slab(&path, None).err().unwrap().to_string();
        assert!(e.contains("not a VTKHDF mesh"), "{e}");
    }
}
