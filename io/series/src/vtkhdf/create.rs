//! A new series: the static mesh, `/eprop`, and every per-step dataset with room for the run's
//! output steps.

use super::mesh::MeshSlab;
use super::{
    access, at, table, values_set, Field, Layout, SeriesSpec, SeriesWriter, ToolSets, COUNT, MAX_ROOM, STEP_SETS,
};
use crate::outcome::Team;
use anyhow::{anyhow, Result};
use eprop_io::mesh::Mesh;
use eprop_io::vtk::vtk_order;
use hdf5::dataset::{AllocTime, FillTime};
use hdf5::types::{FixedAscii, VarLenUnicode};
use hdf5::{Dataset, Extent, File};
use std::path::Path;
use std::str::FromStr;

/// What a failure to create (open) the file is called; a failure after it left a file behind.
pub const CREATING: &str = "creating the output file";

/// A point array with room for `room` steps of `n` rows: float64 or float32, optionally
/// deflated. A chunk holds one step's rows (at most 1 MiB of them).
fn point_array(
    group: &hdf5::Group,
    name: &str,
    ncomp: usize,
    n: usize,
    room: usize,
    spec: &SeriesSpec,
) -> hdf5::Result<Dataset> {
    let chunk_rows = n.clamp(1, (1 << 20) / (8 * ncomp));
    let (ext, chunk): (Vec<Extent>, Vec<usize>) = match ncomp {
        1 => (vec![Extent::resizable(room * n)], vec![chunk_rows]),
        c => (vec![Extent::resizable(room * n), Extent::fixed(c)], vec![chunk_rows, c]),
    };
    let b = if spec.float32 {
        group.new_dataset::<f32>()
    } else {
        group.new_dataset::<f64>()
    };
    let b = b.chunk(chunk).shape(ext);
    // allocated early: the chunk index is final when the file is made (and a serial file can be
    // continued under MPI-IO)
    let b = b.alloc_time(Some(AllocTime::Early)).fill_time(FillTime::Never);
    let b = if spec.compression > 0 {
        b.deflate(spec.compression)
    } else {
        b
    };
    b.create(name)
}

/// A fixed-size dataset created by every process and filled by the one holding `data`.
pub(super) fn fixed<T: hdf5::H5Type>(
    team: &Team,
    group: &hdf5::Group,
    name: &str,
    shape: &[usize],
    data: Option<&[T]>,
) -> Result<Dataset> {
    let what = at(format!("creating the output ({name})"));
    let ds = team.settle(what, group.new_dataset::<T>().shape(shape).create(name))?;
    let written = match data {
        Some(d) if !d.is_empty() => ndarray::ArrayViewD::from_shape(shape, d)
            .map_err(hdf5::Error::from)
            .and_then(|v| ds.write(v)),
        _ => Ok(()),
    };
    team.settle(at(format!("writing the output ({name})")), written)?;
    Ok(ds)
}

/// `/eprop/steps_complete`, the count of complete steps: one int64 in contiguous storage
/// allocated now, so that a commit's count is one write at a fixed address (every process
/// calls; rank 0 writes `k`).
pub(super) fn make_count(team: &Team, ep: &hdf5::Group, k: usize, root: bool) -> Result<Dataset> {
    let b = ep.new_dataset::<i64>().shape([1]).alloc_time(Some(AllocTime::Early));
    let ds = team.settle(at("creating the output (/eprop/steps_complete)"), b.create(COUNT))?;
    let written = match root {
        true => ds.write(&[k as i64]),
        false => Ok(()),
    };
    team.settle(at("writing the output (/eprop/steps_complete)"), written)?;
    Ok(ds)
}

/// A scalar attribute created and written by every process (the same value).
fn scalar_attr<T: hdf5::H5Type>(team: &Team, loc: &hdf5::Location, name: &str, v: &T) -> Result<()> {
    team.settle(
        at(format!("creating the output (attribute {name})")),
        loc.new_attr::<T>().create(name).and_then(|a| a.write_scalar(v)),
    )
}

/// Where the static mesh of a new series comes from.
#[derive(Clone, Copy)]
pub enum StaticMesh<'a> {
    /// The whole mesh, on the one process that writes it (rank 0); None on the others.
    Whole(Option<&'a Mesh>),
    /// Every process's slab of the mesh (`read_slab`, its points as the run reads them): each
    /// process writes its own rows, and the file is the one the whole mesh makes.
    Slabs(&'a MeshSlab),
}

/// A fixed-size dataset created by every process, each writing its `rows` rows (of `ncomp`
/// values) at `row0` together (one process: all of them).
#[allow(clippy::too_many_arguments)]
fn fixed_rows<T: hdf5::H5Type>(
    team: &Team,
    group: &hdf5::Group,
    name: &str,
    shape: &[usize],
    row0: usize,
    data: &[T],
    ncomp: usize,
    parallel: bool,
) -> Result<Dataset> {
    let what = at(format!("creating the output ({name})"));
    let ds = team.settle(what, group.new_dataset::<T>().shape(shape).create(name))?;
    let written = super::write_rows_of(&ds, row0, data.len() / ncomp, ncomp, data, parallel);
    team.settle(at(format!("writing the output ({name})")), written)?;
    Ok(ds)
}

/// The connectivity (VTK's node order), offsets and types of the static mesh from a slab's
/// cells, at their global rows, every process its own (`last`: the process that writes the
/// final offset).
fn write_slab_cells(
    t: &Team,
    top: &hdf5::Group,
    layout: Layout,
    s: &MeshSlab,
    last: bool,
    parallel: bool,
) -> Result<()> {
    let mut conn: Vec<i64> = Vec::with_capacity(s.conn.len());
    let mut offs: Vec<i64> = Vec::with_capacity(s.n_cells() + 1);
    for c in 0..s.n_cells() {
        offs.push((s.conn_start + conn.len()) as i64);
        conn.extend(vtk_order(s.kinds[c], s.cell(c)).iter().map(|&x| x as i64));
    }
    if last {
        offs.push((s.conn_start + conn.len()) as i64);
    }
    fixed_rows(t, top, "Connectivity", &[layout.conn], s.conn_start, &conn, 1, parallel)?;
    drop(conn);
    fixed_rows(t, top, "Offsets", &[layout.cells + 1], s.cell_start, &offs, 1, parallel)?;
    drop(offs);
    let types: Vec<u8> = s.kinds.iter().map(|k| k.vtk_type()).collect();
    fixed_rows(t, top, "Types", &[layout.cells], s.cell_start, &types, 1, parallel)?;
    Ok(())
}

/// The static mesh of a new series under `/VTKHDF` (every process calls; rank 0, which holds
/// the whole mesh, gives the values, or every process its slab's): the counts, the
/// connectivity in VTK's node order, the offsets, the cell types and the points.
fn write_mesh(
    t: &Team,
    top: &hdf5::Group,
    layout: Layout,
    src: StaticMesh,
    root: bool,
    last: bool,
    parallel: bool,
) -> Result<()> {
    let n = layout.nodes;
    let mesh = match src {
        StaticMesh::Whole(m) => m,
        StaticMesh::Slabs(_) => None,
    };
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
    if let StaticMesh::Slabs(s) = src {
        write_slab_cells(t, top, layout, s, last, parallel)?;
        let pts: Vec<f64> = s.points.iter().flatten().copied().collect();
        fixed_rows(t, top, "Points", &[n, 3], s.node_start, &pts, 3, parallel)?;
        return Ok(());
    }
    fixed(t, top, "Connectivity", &[layout.conn], Some(&conn[..]).filter(|_| root))?;
    fixed(t, top, "Offsets", &[layout.cells + 1], Some(&offs[..]).filter(|_| root))?;
    fixed(t, top, "Types", &[layout.cells], Some(&types[..]).filter(|_| root))?;
    fixed(t, top, "Points", &[n, 3], Some(&pts[..]).filter(|_| root))?;
    Ok(())
}

/// `/eprop` of a new series (every process calls; rank 0 holds `mesh`): the version, the
/// count of complete steps (the dataset and its mirror attribute), the identity and extra
/// attributes, the scenario text, the control volumes, node ids and cell tags, and the probe
/// tables, returned as time, step, force, displacement, and the count.
#[allow(clippy::too_many_arguments)]
fn create_eprop(
    t: &Team,
    file: &File,
    layout: Layout,
    src: StaticMesh,
    root: bool,
    spec: &SeriesSpec,
    room: usize,
    parallel: bool,
) -> Result<[Dataset; 5]> {
    let n = layout.nodes;
    let mk = |what: &str| at(format!("creating the output ({what})"));
    let ep = t.settle(mk("/eprop"), file.create_group("eprop"))?;
    let vs = VarLenUnicode::from_str(spec.version).unwrap();
    scalar_attr(t, &ep, "version", &vs)?;
    scalar_attr(t, &ep, COUNT, &0i64)?;
    for (name, v) in &spec.attrs {
        scalar_attr(t, &ep, name, v)?;
    }
    for (name, v) in &spec.ids {
        scalar_attr(t, &ep, name, v)?;
    }
    scalar_attr(t, &ep, "float32", &(spec.float32 as u8))?;
    let count = make_count(t, &ep, 0, root)?;
    let text = spec.scenario.as_bytes();
    fixed(t, &ep, "scenario", &[text.len()], Some(text).filter(|_| root))?;
    let cv = t.settle(
        mk("control_volumes"),
        ep.new_dataset::<f64>().shape([n]).create("control_volumes"),
    )?;
    t.settle(
        at("writing the output (control_volumes)"),
        super::write_rows(&cv, spec.block_start, spec.block_len, 1, spec.control_volumes, parallel),
    )?;
    match src {
        StaticMesh::Whole(mesh) => {
            let ids: Option<Vec<i64>> = mesh.map(|m| m.node_ids.iter().map(|&x| x as i64).collect());
            fixed(t, &ep, "node_ids", &[n], ids.as_deref())?;
            fixed(t, &ep, "cell_tags", &[layout.cells], mesh.map(|m| &m.cell_tags[..]))?;
        }
        StaticMesh::Slabs(s) => {
            let ids: Vec<i64> = s.node_ids.iter().map(|&x| x as i64).collect();
            fixed_rows(t, &ep, "node_ids", &[n], s.node_start, &ids, 1, parallel)?;
            fixed_rows(
                t,
                &ep,
                "cell_tags",
                &[layout.cells],
                s.cell_start,
                &s.cell_tags,
                1,
                parallel,
            )?;
        }
    }
    let pr = t.settle(mk("probes"), ep.create_group("probes"))?;
    let ln: Vec<i64> = spec.load_nodes.iter().map(|&x| x as i64).collect();
    fixed(t, &pr, "node", &[ln.len()], Some(&ln[..]).filter(|_| root))?;
    let nl = spec.n_loads;
    let (c1, c3) = (room.clamp(1, 1024), room.clamp(1, 256));
    let probe_time = t.settle(mk("probes/time"), table::<f64>(&pr, "time", room, &[], c1))?;
    let probe_step = t.settle(mk("probes/step"), table::<i64>(&pr, "step", room, &[], c1))?;
    let probe_force = t.settle(mk("probes/force"), table::<f64>(&pr, "force", room, &[nl, 3], c3))?;
    let probe_disp = t.settle(
        mk("probes/displacement"),
        table::<f64>(&pr, "displacement", room, &[nl, 3], c3),
    )?;
    Ok([probe_time, probe_step, probe_force, probe_disp, count])
}

impl SeriesWriter {
    /// Creates (truncates) the file and writes the static mesh, with room for
    /// `spec.output_steps` output steps (at most `MAX_ROOM`). `mesh` is given on exactly one
    /// process (rank 0), `comm` under MPI (then every process of it must call). A failure is a
    /// `WriteFailed` on every process (the file is closed on every process when it returns).
    pub fn create(
        path: &Path,
        layout: Layout,
        mesh: Option<&Mesh>,
        spec: &SeriesSpec,
        comm: Option<&mpi::topology::SimpleCommunicator>,
    ) -> Result<Self> {
        Self::create_from(path, layout, StaticMesh::Whole(mesh), spec, comm)
    }

    /// `create` with the static mesh from `src`: the whole mesh on rank 0, or every
    /// process's slab (then every process writes its rows of the mesh, and rank 0 is the
    /// root of the rest).
    pub fn create_from(
        path: &Path,
        layout: Layout,
        src: StaticMesh,
        spec: &SeriesSpec,
        comm: Option<&mpi::topology::SimpleCommunicator>,
    ) -> Result<Self> {
        use mpi::topology::Communicator;
        let parallel = comm.is_some();
        let (rank, size) = comm.map_or((0, 1), |c| (c.rank(), c.size()));
        let root = match src {
            StaticMesh::Whole(mesh) => mesh.is_some(),
            StaticMesh::Slabs(_) => rank == 0,
        };
        let last = rank + 1 == size;
        let team = Team::new(path, comm);
        let file = team.settle_open(at(CREATING), access(comm).create(path))?;
        team.hold(&file);
        let t = &team;
        let n = layout.nodes;
        let room = spec.output_steps.clamp(1, MAX_ROOM);
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

        write_mesh(t, &top, layout, src, root, last, parallel)?;

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
        match src {
            StaticMesh::Whole(mesh) => {
                let tags: Option<Vec<i64>> = mesh.map(|m| m.cell_tags.iter().map(|&x| x as i64).collect());
                fixed(t, &cd, "tag", &[layout.cells], tags.as_deref())?;
            }
            StaticMesh::Slabs(s) => {
                let tags: Vec<i64> = s.cell_tags.iter().map(|&x| x as i64).collect();
                fixed_rows(t, &cd, "tag", &[layout.cells], s.cell_start, &tags, 1, parallel)?;
            }
        }
        let c1 = room.clamp(1, 1024);
        let cell_offsets = Some(t.settle(mk("CellDataOffsets/tag"), table::<i64>(&cdo, "tag", room, &[], c1))?);
        let values = t.settle(mk("Values"), values_set(&steps, room, 0))?;
        let mut step_sets = Vec::new();
        for name in STEP_SETS {
            step_sets.push(t.settle(mk(name), table::<i64>(&steps, name, room, &[], c1))?);
        }
        let mut fields = Vec::new();
        for &(name, ncomp) in &spec.fields {
            let data = t.settle(mk(name), point_array(&pd, name, ncomp, n, room, spec))?;
            let offsets = t.settle(mk(name), table::<i64>(&pdo, name, room, &[], c1))?;
            fields.push(Field {
                name: name.to_string(),
                ncomp,
                data,
                offsets,
            });
        }

        let [probe_time, probe_step, probe_force, probe_disp, count] =
            create_eprop(t, &file, layout, src, root, spec, room, parallel)?;
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
            count,
            n_loads: spec.n_loads,
            n_steps: 0,
            counted: 0,
            room,
            pending: Vec::new(),
            commit_every: 0.0,
            last_commit: std::time::Instant::now(),
            team,
            tools: None,
            checks: None,
            cell_offsets,
        })
    }

    /// Adds `/eprop/tools` for `n` tools to a new series, before its first step (every process
    /// calls): `time`, `step` (output steps), `position`, `force`, `displacement` (output
    /// steps, tools, 3), `contact_nodes`, `contact_area`, `indentation` (output steps, tools),
    /// each with the series' room.
    pub fn add_tools(&mut self, n: usize) -> Result<()> {
        if self.n_steps > 0 || n == 0 {
            return Err(anyhow!("internal: tools are added to a new series, and at least one"));
        }
        let t = &self.team;
        let room = self.room;
        let (c1, c3) = (room.clamp(1, 1024), room.clamp(1, 256));
        let mk = |what: &str| at(format!("creating the output ({what})"));
        let ep = t.settle(mk("/eprop"), self.file.group("eprop"))?;
        let g = t.settle(mk("/eprop/tools"), ep.create_group("tools"))?;
        let vector = |name: &str| t.settle(mk(name), table::<f64>(&g, name, room, &[n, 3], c3));
        let scalar = |name: &str| t.settle(mk(name), table::<f64>(&g, name, room, &[n], c3));
        let sets = ToolSets {
            n,
            time: t.settle(mk("tools/time"), table::<f64>(&g, "time", room, &[], c1))?,
            step: t.settle(mk("tools/step"), table::<i64>(&g, "step", room, &[], c1))?,
            vectors: [vector("position")?, vector("force")?, vector("displacement")?],
            scalars: [scalar("contact_area")?, scalar("indentation")?],
            contact_nodes: t.settle(mk("contact_nodes"), table::<i64>(&g, "contact_nodes", room, &[n], c3))?,
        };
        t.settle(at("writing the output (flush)"), self.file.flush())?;
        self.tools = Some(sets);
        Ok(())
    }
}
