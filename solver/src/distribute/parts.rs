//! Each process's part of a run. Rank 0 reads the scenario and the mesh, resolves the
//! scenario on the whole mesh, splits the node graph (METIS on rank 0, or with
//! `[performance] partitioner = "ptscotch"` PT-Scotch on every process, each given a slab of
//! the graph, `ptscotch`) and, one process at a time,
//! builds that process's plan, restricts the setup to it (`Setup::restrict`) and sends it;
//! every other process receives its own. A part travels as postcard's compact binary form
//! of its serde derive (`Part`; the mesh and paths through `config::wire`). A one-process run is one
//! part of the same kind, made in place.

use crate::config::Setup;
use crate::diagnostics::log_memory;
use crate::distribute::comm::{Comm, Handle, Mpi};
use crate::distribute::halo::Halo;
use crate::distribute::ptscotch::{self, Slab};
use anyhow::{anyhow, bail, Result};
use eprop_mesh::Mesh;
use eprop_partition::Plan;
use serde::{Deserialize, Serialize};

/// Sizes of the whole mesh that every process needs to lay out the output file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GlobalSizes {
    pub nodes: usize,
    pub cells: usize,
    pub conn: usize,
    /// A hash of the points, cells and node ids (restart checks it).
    pub mesh_hash: u64,
}

impl GlobalSizes {
    pub fn of(mesh: &Mesh) -> GlobalSizes {
        let mut h = StableHash::default();
        mesh.points.iter().flatten().for_each(|x| h.u64(x.to_bits()));
        mesh.conn.iter().for_each(|&c| h.u64(c as u64));
        mesh.kinds
            .iter()
            .for_each(|&k| h.u64(crate::config::wire::kind_code(k) as u64));
        mesh.node_ids.iter().for_each(|&i| h.u64(i));
        GlobalSizes {
            nodes: mesh.n_nodes(),
            cells: mesh.n_cells(),
            conn: mesh.conn.len(),
            mesh_hash: h.finish(),
        }
    }
}

/// FNV-1a, 64 bit (the `fnv` crate): a stable hash for identity checks (not for security).
#[derive(Default)]
pub struct StableHash(fnv::FnvHasher);

impl StableHash {
    pub fn bytes(&mut self, b: &[u8]) {
        std::hash::Hasher::write(&mut self.0, b);
    }
    /// A hash that continues from `state` (what `finish` gave).
    pub fn resume(state: u64) -> StableHash {
        StableHash(fnv::FnvHasher::with_key(state))
    }
    pub fn u64(&mut self, x: u64) {
        self.bytes(&x.to_le_bytes());
    }
    pub fn finish(&self) -> u64 {
        std::hash::Hasher::finish(&self.0)
    }
}

/// What one process receives: its view of the scenario, its plan and the whole mesh's sizes.
#[derive(Serialize, Deserialize)]
pub struct Part {
    pub setup: Setup,
    pub plan: Plan,
    pub sizes: GlobalSizes,
    /// The process's slab of the mesh, kept for the static output of a start from the slabs
    /// (`slabs::start`: every process writes its rows); never sent.
    #[serde(skip)]
    pub rows: Option<eprop_series::vtkhdf::MeshSlab>,
}

/// The cells of a plan, renumbered locally (owned nodes, then halo nodes).
fn local_mesh(global: &Mesh, plan: &Plan) -> Mesh {
    let ids = &plan.numbering.global;
    let mut map = std::collections::HashMap::with_capacity(ids.len());
    for (l, &g) in ids.iter().enumerate() {
        map.insert(g, l as u32);
    }
    let mut m = Mesh::new(global.source.clone());
    m.points = ids.iter().map(|&g| global.points[g as usize]).collect();
    m.node_ids = ids.iter().map(|&g| global.node_ids[g as usize]).collect();
    let mut buf = Vec::with_capacity(8);
    for &c in &plan.cells {
        buf.clear();
        buf.extend(global.cell(c as usize).iter().map(|g| map[g]));
        m.push_cell(global.kinds[c as usize], &buf, global.cell_tags[c as usize]);
    }
    m
}

impl Setup {
    /// The view of one process: the plan's cells and nodes renumbered locally (owned, then
    /// halo) with their per-node arrays. Loads keep their global node indices.
    pub fn restrict(&self, plan: &Plan) -> Setup {
        fn pick<T: Clone>(v: &[T], plan: &Plan) -> Vec<T> {
            plan.numbering.global.iter().map(|&g| v[g as usize].clone()).collect()
        }
        Setup {
            scenario: self.scenario.clone(),
            mesh: local_mesh(&self.mesh, plan),
            materials: self.materials.pick(&plan.numbering.global),
            fixed: pick(&self.fixed, plan),
            supports: self.supports.clone(),
            loads: self.loads.clone(),
            tools: self.tools.clone(),
            model: self.model.clone(),
            integrator: self.integrator.clone(),
            law: self.law,
            time: self.time,
            output: self.output.clone(),
            performance: self.performance,
        }
    }
}

/// What rank 0 sends every other process: its part, or the error that stopped rank 0; before
/// them, with PT-Scotch, the process's slab of the node graph to split.
#[derive(Serialize, Deserialize)]
enum Message<P, S = Box<Setup>> {
    Failed(String),
    Part(P),
    Slab(Slab),
    /// The setup of a run that starts from a VTKHDF mesh in slabs (`Setup::deferred`).
    Deferred(S),
}

/// A message of rank 0 that is not an error.
enum Incoming {
    Part(Box<Part>),
    Slab(Slab),
    Deferred(Box<Setup>),
}

/// A part's message.
fn encode(part: &Part) -> Result<Vec<u8>> {
    postcard::to_allocvec(&Message::<_, ()>::Part(part)).map_err(|e| anyhow!("internal: a part cannot be encoded: {e}"))
}

/// The part or slab in a message (`encode`); `ReportedElsewhere` when rank 0 sent its error
/// instead.
fn decode_any(bytes: &[u8]) -> Result<Incoming> {
    match postcard::from_bytes::<Message<Part>>(bytes) {
        Ok(Message::Part(p)) => Ok(Incoming::Part(Box::new(p))),
        Ok(Message::Slab(s)) => Ok(Incoming::Slab(s)),
        Ok(Message::Deferred(s)) => Ok(Incoming::Deferred(s)),
        Ok(Message::Failed(_)) => Err(ReportedElsewhere.into()),
        Err(e) => Err(anyhow!("internal: a part message is malformed: {e}")),
    }
}

/// The part in a message (`encode`).
#[cfg(test)]
fn decode(bytes: &[u8]) -> Result<Part> {
    match decode_any(bytes)? {
        Incoming::Part(p) => Ok(*p),
        _ => Err(anyhow!("internal: a part message is malformed: not a part")),
    }
}

fn failure(e: &anyhow::Error) -> Vec<u8> {
    postcard::to_allocvec(&Message::<()>::Failed(format!("{e:#}"))).unwrap_or_default()
}

/// An error already reported by another process (rank 0); this process exits quietly.
#[derive(Debug)]
pub struct ReportedElsewhere;

impl std::fmt::Display for ReportedElsewhere {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "the run failed on rank 0 (see its message)")
    }
}

impl std::error::Error for ReportedElsewhere {}

/// An error found by rank 0 before the parts were sent, and sent to every process instead.
#[derive(Debug)]
pub struct Collective(pub String);

impl std::fmt::Display for Collective {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Collective {}

/// Rank 0's split of the whole mesh: the part of every node (METIS, or PT-Scotch with every
/// process of `world` when the scenario asks for it) and the locality keys.
fn split(setup: &Setup, world: &Handle) -> Result<(Vec<u32>, Vec<u64>)> {
    use crate::config::Partitioner;
    use mpi::topology::Communicator;
    let size = world.communicator().size() as usize;
    let mesh = &setup.mesh;
    log_memory("reading the scenario and mesh");
    let (xadj, adj) = eprop_partition::node_graph(mesh.n_nodes(), &mesh.offsets, &mesh.conn);
    let weights = eprop_partition::degree_weights(&xadj);
    let by_scotch = match setup.performance.partitioner {
        Partitioner::Ptscotch if size > 1 && !ptscotch::AVAILABLE => {
            tracing::warn!("this build has no PT-Scotch (see build.rs): the nodes are split by METIS");
            None
        }
        Partitioner::Ptscotch if size > 1 && size <= mesh.n_nodes() => {
            tracing::info!("splitting {} nodes into {size} parts (PT-Scotch)", mesh.n_nodes());
            match split_together(world, &xadj, &adj, &weights) {
                Ok(part) => Some(part),
                Err(e) => {
                    tracing::warn!("{}: {e}: the nodes are split by METIS", mesh.source);
                    None
                }
            }
        }
        _ => None,
    };
    let part = match by_scotch {
        Some(part) => part,
        None => {
            tracing::info!("splitting {} nodes into {size} parts (METIS)", mesh.n_nodes());
            eprop_partition::partition_weighted(&xadj, &adj, size, eprop_partition::Method::Metis, Some(&weights))
                .map_err(|e| anyhow!("{}: {e}", mesh.source))?
        }
    };
    Ok((part, eprop_partition::rcm_keys(&xadj, &adj)))
}

/// Rank 0's side of the PT-Scotch split: every other process gets its slab of the graph
/// (`Message::Slab`), all split together (`split_slab`), and rank 0 gathers the parts; a part
/// left empty or a failure on any process is an error (the caller falls back to METIS).
fn split_together(world: &Handle, xadj: &[usize], adj: &[u32], weights: &[u32]) -> Result<Vec<u32>, String> {
    use mpi::point_to_point::{Destination, Source};
    use mpi::topology::Communicator;
    let comm = world.communicator();
    let size = comm.size() as usize;
    for r in 1..size {
        let slab = Slab::of(xadj, adj, weights, size, r);
        let msg = postcard::to_allocvec(&Message::<()>::Slab(slab))
            .map_err(|e| format!("internal: a slab cannot be encoded: {e}"))?;
        comm.process_at_rank(r as i32).send(&msg[..]);
    }
    let slab = Slab::of(xadj, adj, weights, size, 0);
    let mine = split_slab(world, &slab, size);
    let vtxdist = slab.vtxdist;
    let mut part = Vec::with_capacity(xadj.len() - 1);
    let mut failed = mine.as_ref().err().cloned();
    part.extend(mine.unwrap_or_default());
    for r in 1..size {
        let (got, _) = comm.process_at_rank(r as i32).receive_vec::<u32>();
        let rows = (vtxdist[r + 1] - vtxdist[r]) as usize;
        if got.len() != rows && failed.is_none() {
            failed = Some(format!("PT-Scotch failed on process {r}"));
        }
        part.extend(got);
    }
    if let Some(e) = failed {
        return Err(e);
    }
    eprop_partition::check_parts(&part, size).map_err(|e| format!("PT-Scotch: {e}"))?;
    Ok(part)
}

/// Every process's side of the PT-Scotch split: its slab split together with the others on
/// a communicator of their own (PT-Scotch's messages never meet the parts').
fn split_slab(world: &Handle, slab: &Slab, size: usize) -> Result<Vec<u32>, String> {
    let own = world.duplicate();
    let t = std::time::Instant::now();
    let part = ptscotch::part_kway(slab, size, own.raw());
    tracing::debug!(
        "PT-Scotch split {} rows in {:.3} s",
        slab.n_rows(),
        t.elapsed().as_secs_f64()
    );
    part
}

/// Rank 0 makes the whole-mesh setup (`make_setup`, called nowhere else), splits it and
/// sends every process its part, one at a time; every process returns its own part, rank 0
/// also the whole mesh. An error of rank 0 before the sends reaches every process: rank 0
/// returns it as `Collective`, the others `ReportedElsewhere`; an error once sending has
/// begun is rank 0's alone (the job's policy aborts it, see `launch`).
fn scatter(handle: &Handle, make_setup: impl FnOnce() -> Result<Setup>) -> Result<(Part, Option<Mesh>)> {
    use mpi::point_to_point::{Destination, Source};
    use mpi::topology::Communicator;
    let world = handle.communicator();
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    if rank != 0 {
        loop {
            let (msg, _) = world.process_at_rank(0).receive_vec::<u8>();
            match decode_any(&msg)? {
                Incoming::Part(p) => return Ok((*p, None)),
                Incoming::Deferred(s) => return super::slabs::start(handle, *s),
                Incoming::Slab(slab) => {
                    // an empty answer says this process failed
                    let part = split_slab(handle, &slab, size).unwrap_or_default();
                    world.process_at_rank(0).send(&part[..]);
                }
            }
        }
    }
    let made = make_setup();
    if let Some(s) = made.as_ref().ok().filter(|s| s.is_deferred() && size > 1) {
        // a VTKHDF mesh: every process reads its slab and builds its own part
        let msg = postcard::to_allocvec(&Message::<(), &Setup>::Deferred(s))
            .map_err(|e| anyhow!("internal: a setup cannot be encoded: {e}"))?;
        for r in 1..size {
            world.process_at_rank(r as i32).send(&msg[..]);
        }
        return super::slabs::start(handle, made.expect("checked"));
    }
    let (setup, (part, keys)) = match made.and_then(|s| split(&s, handle).map(|p| (s, p))) {
        Ok(x) => x,
        Err(e) => {
            let msg = failure(&e);
            for r in 1..size {
                world.process_at_rank(r as i32).send(&msg[..]);
            }
            return Err(Collective(format!("{e:#}")).into());
        }
    };
    let mesh = &setup.mesh;
    let sizes = GlobalSizes::of(mesh);
    let plan_of = |r| Plan::new(mesh.n_nodes(), &mesh.offsets, &mesh.conn, &part, r, Some(&keys));
    for r in 1..size {
        let plan = plan_of(r);
        let (owned, halo, neighbours) = (plan.numbering.n_owned, plan.n_halo(), plan.pattern.neighbours.len());
        let msg = encode(&Part {
            setup: setup.restrict(&plan),
            plan,
            sizes,
            rows: None,
        })?;
        tracing::debug!(
            "part {r}: {owned} owned, {halo} halo, {neighbours} neighbours; {} bytes",
            msg.len()
        );
        world.process_at_rank(r as i32).send(&msg[..]);
    }
    let plan = plan_of(0);
    let mine = Part {
        setup: setup.restrict(&plan),
        plan,
        sizes,
        rows: None,
    };
    Ok((mine, Some(setup.mesh)))
}

/// This process's share of a distributed run: its part, the whole mesh on rank 0, and two
/// communicators of the processes of `world` of its own: one for its simulation's collectives,
/// one in the halo exchange along its part's pattern.
pub struct Share {
    pub part: Part,
    pub global: Option<Mesh>,
    pub comm: Box<dyn Comm>,
    pub halo: Halo,
}

/// Every process of `world` calls: rank 0 makes the whole-mesh setup and sends every process
/// its part (`scatter`, with its error policy); each gets its share.
pub fn share(world: &dyn Comm, make_setup: impl FnOnce() -> Result<Setup>) -> Result<Share> {
    let Some(world) = world.handle() else {
        bail!("internal: a distributed build needs the processes of an MPI job");
    };
    let comm = Box::new(Mpi::new(world.duplicate()));
    let halo_comm = world.duplicate();
    let (part, global) = scatter(world, make_setup)?;
    let halo = Halo::new(part.plan.pattern.clone(), halo_comm);
    Ok(Share {
        part,
        global,
        comm,
        halo,
    })
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Scenario;
    use eprop_io::generate::{box_mesh, BoxCells};

    fn setup() -> Setup {
        let text = "[mesh]\nfile = \"m.msh\"\n[material]\nconductivity = [0.08, 0.05, 0.05]\n\
                    [[material.region]]\nhalfspace = { point = [0.5, 0, 0], normal = [1, 0, 0] }\nmass = 3.0\n\
                    [model]\nscheme = \"paper\"\n[[fixed]]\ngroup = \"xmin\"\n[[load]]\npatch = { center = [1, 0.5, 0.5], radius = 0.3 }\n\
                    normal = 1.0\nramp = [[0, 0], [1, 1]]\n\
                    [[tool]]\nshape = \"punch\"\nradius = 0.2\nnormal = [0, 0, -1]\nstart = [0.5, 0.5, 1.1]\nvelocity = [0, 0, -0.1]\n[time]\nequilibrium = 1e-4\ndt = 0.01\n[output]\nfields = [\"energy\"]\n";
        let sc = Scenario::parse(std::path::Path::new("dir/s.toml"), text.into()).unwrap();
        let mut mesh = box_mesh([1.0; 3], [3; 3], BoxCells::Wedge).unwrap();
        mesh.warnings.push("a warning".into());
        Setup::with_mesh(sc, mesh).unwrap()
    }

    /// A split into two parts by x < 0.5.
    fn plan(s: &Setup, rank: usize) -> Plan {
        let m = &s.mesh;
        let part: Vec<u32> = m.points.iter().map(|p| (p[0] >= 0.5) as u32).collect();
        Plan::new(m.n_nodes(), &m.offsets, &m.conn, &part, rank, None)
    }

    #[test]
    fn a_part_arrives_as_it_was_sent() {
        let whole = setup();
        let plan = plan(&whole, 1);
        let part = Part {
            setup: whole.restrict(&plan),
            sizes: GlobalSizes::of(&whole.mesh),
            plan,
            rows: None,
        };
        let got = decode(&encode(&part).unwrap()).unwrap();
        assert_eq!(got.plan, part.plan);
        assert_eq!(got.sizes, part.sizes);
        let (a, b) = (&part.setup, &got.setup);
        assert_eq!(
            (&a.scenario.path, &a.scenario.text),
            (&b.scenario.path, &b.scenario.text)
        );
        assert_eq!(b.scenario.file.output.fields, a.scenario.file.output.fields);
        let (x, y) = (&a.mesh, &b.mesh);
        assert_eq!((&x.source, &x.points, &x.node_ids), (&y.source, &y.points, &y.node_ids));
        assert_eq!(
            (&x.kinds, &x.offsets, &x.conn, &x.cell_tags),
            (&y.kinds, &y.offsets, &y.conn, &y.cell_tags)
        );
        assert_eq!(x.warnings, y.warnings);
        assert_eq!((&a.materials, &a.fixed), (&b.materials, &b.fixed));
        assert_eq!((&a.loads, &a.model, &a.law), (&b.loads, &b.model, &b.law));
        assert_eq!(a.tools, b.tools);
        assert_eq!((&a.time, &a.output), (&b.time, &b.output));
        // the values are the interesting ones, not defaults
        assert!(
            a.materials.tissues.iter().any(|t| t.mass == 3.0) && a.fixed.contains(&false) && a.loads[0].ramp.is_some()
        );
        assert_eq!(a.tools.len(), 1);
    }

    #[test]
    fn a_non_utf8_path_arrives_unchanged() {
        use std::os::unix::ffi::OsStrExt;
        let mut s = setup();
        s.output.file = std::ffi::OsStr::from_bytes(b"out/\xff.h5").into();
        let plan = plan(&s, 0);
        let part = Part {
            setup: s.restrict(&plan),
            plan,
            sizes: GlobalSizes::default(),
            rows: None,
        };
        assert_eq!(
            decode(&encode(&part).unwrap()).unwrap().setup.output.file,
            s.output.file
        );
    }

    #[test]
    fn a_failure_or_a_broken_message_is_an_error() {
        let e = decode(&failure(&anyhow!("bad scenario"))).err().unwrap();
        assert!(e.is::<ReportedElsewhere>());
        let whole = setup();
        let plan = plan(&whole, 0);
        let msg = encode(&Part {
            setup: whole.restrict(&plan),
            plan,
            sizes: GlobalSizes::default(),
            rows: None,
        })
        .unwrap();
        for cut in [1, msg.len() / 2, msg.len() - 1] {
            let e = decode(&msg[..cut]).err().unwrap().to_string();
            assert!(e.contains("malformed"), "{e}");
        }
    }

    #[test]
    fn restricting_keeps_each_local_node_with_its_values() {
        let whole = setup();
        for rank in 0..2 {
            let plan = plan(&whole, rank);
            let s = whole.restrict(&plan);
            let ids = &plan.numbering.global;
            assert_eq!(s.mesh.n_nodes(), ids.len());
            assert_eq!(s.mesh.n_cells(), plan.cells.len());
            for (l, &g) in ids.iter().enumerate() {
                let g = g as usize;
                assert_eq!(s.mesh.points[l], whole.mesh.points[g]);
                assert_eq!(s.mesh.node_ids[l], whole.mesh.node_ids[g]);
                assert_eq!((s.materials.at(l), s.fixed[l]), (whole.materials.at(g), whole.fixed[g]));
            }
            // every local cell is its global cell, renumbered
            for (lc, &gc) in plan.cells.iter().enumerate() {
                let local: Vec<u32> = s.mesh.cell(lc).iter().map(|&l| ids[l as usize]).collect();
                assert_eq!(local, whole.mesh.cell(gc as usize));
                assert_eq!(s.mesh.cell_tags[lc], whole.mesh.cell_tags[gc as usize]);
            }
            assert_eq!(s.loads, whole.loads);
        }
    }

    #[test]
    fn the_mesh_hash_sees_every_change() {
        let m = box_mesh([1.0; 3], [2; 3], BoxCells::Tet).unwrap();
        let h = GlobalSizes::of(&m);
        assert_eq!((h.nodes, h.cells, h.conn), (27, 48, 192));
        let mut moved = m.clone();
        moved.points[3][1] += 1e-12;
        let mut renamed = m.clone();
        renamed.node_ids[0] = 1000;
        assert_ne!(GlobalSizes::of(&moved).mesh_hash, h.mesh_hash);
        assert_ne!(GlobalSizes::of(&renamed).mesh_hash, h.mesh_hash);
        assert_eq!(GlobalSizes::of(&m.clone()).mesh_hash, h.mesh_hash);
    }
}
