//! Rank 0 reads the scenario and the mesh, partitions the node graph and sends every process
//! its part: the plan (owned, halo, neighbours), the local cells and nodes, the per-node
//! material arrays and the scenario text. Messages are a plain little-endian byte encoding.

use crate::material::{Tensor, TissueLaw};
use crate::scenario::{Load, Scenario, Scheme, Setup, Stop};
use anyhow::{anyhow, Result};
use eprop_io::{CellKind, Mesh};
use eprop_partition::{HaloPattern, LocalNumbering, Neighbour, Plan};
use std::path::PathBuf;

/// Sizes of the whole mesh that every process needs to lay out the output file.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GlobalSizes {
    pub nodes: usize,
    pub cells: usize,
    pub conn: usize,
    /// A hash of the points, cells and node ids (restart checks it).
    pub mesh_hash: u64,
}

impl GlobalSizes {
    pub fn of(mesh: &Mesh) -> GlobalSizes {
        let mut h = Fnv::default();
        mesh.points.iter().flatten().for_each(|x| h.u64(x.to_bits()));
        mesh.conn.iter().for_each(|&c| h.u64(c as u64));
        mesh.kinds.iter().for_each(|&k| h.u64(kind_code(k) as u64));
        mesh.node_ids.iter().for_each(|&i| h.u64(i));
        GlobalSizes {
            nodes: mesh.n_nodes(),
            cells: mesh.n_cells(),
            conn: mesh.conn.len(),
            mesh_hash: h.0,
        }
    }
}

/// FNV-1a, 64 bit: a stable hash for identity checks (not for security).
pub struct Fnv(pub u64);

impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    pub fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= x as u64;
            self.0 = self.0.wrapping_mul(0x100_0000_01b3);
        }
    }
    pub fn u64(&mut self, x: u64) {
        self.bytes(&x.to_le_bytes());
    }
}

/// What one process receives.
pub struct Part {
    pub setup: Setup,
    pub plan: Plan,
    pub sizes: GlobalSizes,
}

#[derive(Default)]
pub struct Writer(pub Vec<u8>);

impl Writer {
    fn u64(&mut self, x: u64) {
        self.0.extend_from_slice(&x.to_le_bytes());
    }
    fn f64(&mut self, x: f64) {
        self.0.extend_from_slice(&x.to_le_bytes());
    }
    fn opt_f64(&mut self, x: Option<f64>) {
        self.u64(x.is_some() as u64);
        self.f64(x.unwrap_or(0.0));
    }
    fn str(&mut self, s: &str) {
        self.u64(s.len() as u64);
        self.0.extend_from_slice(s.as_bytes());
    }
    fn u32s(&mut self, v: &[u32]) {
        self.u64(v.len() as u64);
        for &x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn u64s(&mut self, v: &[u64]) {
        self.u64(v.len() as u64);
        v.iter().for_each(|&x| self.u64(x));
    }
    fn f64s(&mut self, v: &[f64]) {
        self.u64(v.len() as u64);
        v.iter().for_each(|&x| self.f64(x));
    }
}

pub struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    pub fn new(b: &'a [u8]) -> Self {
        Reader { b, at: 0 }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.b.len())
            .ok_or_else(|| anyhow!("internal: a partition message is truncated"))?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn usize(&mut self) -> Result<usize> {
        Ok(self.u64()? as usize)
    }
    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn opt_f64(&mut self) -> Result<Option<f64>> {
        let some = self.u64()? != 0;
        let x = self.f64()?;
        Ok(some.then_some(x))
    }
    fn str(&mut self) -> Result<String> {
        let n = self.usize()?;
        Ok(String::from_utf8_lossy(self.take(n)?).into_owned())
    }
    fn u32s(&mut self) -> Result<Vec<u32>> {
        let n = self.usize()?;
        let b = self.take(n.checked_mul(4).ok_or_else(|| anyhow!("internal: bad message"))?)?;
        Ok(b.chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
    fn u64s(&mut self) -> Result<Vec<u64>> {
        let n = self.usize()?;
        let b = self.take(n.checked_mul(8).ok_or_else(|| anyhow!("internal: bad message"))?)?;
        Ok(b.chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
    fn f64s(&mut self) -> Result<Vec<f64>> {
        Ok(self.u64s()?.into_iter().map(f64::from_bits).collect())
    }
}

fn kind_code(k: CellKind) -> u32 {
    match k {
        CellKind::Tet => 0,
        CellKind::Hex => 1,
        CellKind::Wedge => 2,
        CellKind::Pyramid => 3,
    }
}

fn kind_of(c: u32) -> Result<CellKind> {
    Ok(match c {
        0 => CellKind::Tet,
        1 => CellKind::Hex,
        2 => CellKind::Wedge,
        3 => CellKind::Pyramid,
        _ => return Err(anyhow!("internal: unknown cell kind {c} in a partition message")),
    })
}

/// Encodes a process's part (`setup` already restricted to `plan`).
pub fn encode(setup: &Setup, plan: &Plan, sizes: GlobalSizes) -> Vec<u8> {
    let mut w = Writer::default();
    w.u64(sizes.nodes as u64);
    w.u64(sizes.cells as u64);
    w.u64(sizes.conn as u64);
    w.u64(sizes.mesh_hash);
    // plan
    w.u64(plan.rank as u64);
    w.u32s(&plan.numbering.global);
    w.u64(plan.numbering.n_interior as u64);
    w.u64(plan.numbering.n_owned as u64);
    w.u32s(&plan.cells);
    w.u64(plan.pattern.neighbours.len() as u64);
    for nb in &plan.pattern.neighbours {
        w.u64(nb.rank as u64);
        w.u32s(&nb.send);
        w.u32s(&nb.recv);
    }
    // scenario
    w.str(&setup.scenario.path.to_string_lossy());
    w.str(&setup.scenario.text);
    // local mesh
    let m = &setup.mesh;
    w.str(&m.source);
    w.f64s(m.points.as_flattened());
    w.u64s(&m.node_ids);
    w.u32s(&m.kinds.iter().map(|&k| kind_code(k)).collect::<Vec<_>>());
    w.u32s(&m.conn);
    w.u32s(&m.cell_tags.iter().map(|&t| t as u32).collect::<Vec<_>>());
    w.u64(m.warnings.len() as u64);
    m.warnings.iter().for_each(|s| w.str(s));
    // per-node arrays
    let r: Vec<f64> = setup
        .r
        .iter()
        .flat_map(|t| t.iter().copied().collect::<Vec<_>>())
        .collect();
    w.f64s(&r);
    w.f64s(&setup.mass);
    w.f64s(&setup.damping);
    w.u32s(&setup.fixed.iter().map(|&b| b as u32).collect::<Vec<_>>());
    // loads
    w.u64(setup.loads.len() as u64);
    for l in &setup.loads {
        w.u32s(&l.nodes);
        w.u64s(&l.node_ids);
        w.f64s(&l.weights);
        w.f64s(&l.force);
        w.f64(l.area);
        w.u64(l.ramp.is_some() as u64);
        w.f64s(l.ramp.as_deref().unwrap_or(&[]).as_flattened());
        w.opt_f64(l.normal);
        w.opt_f64(l.depth);
    }
    // settings
    match setup.scheme {
        Scheme::Compact => w.u64(0),
        Scheme::Paper { correction } => w.u64(1 + correction as u64),
    }
    w.f64(setup.stiffness);
    w.f64(setup.coupling);
    w.f64(setup.exponent);
    w.f64(setup.law.young);
    w.f64(setup.law.beta);
    match setup.stop {
        Stop::Steps(n) => {
            w.u64(0);
            w.u64(n);
            w.f64(0.0);
        }
        Stop::End(t) => {
            w.u64(1);
            w.u64(0);
            w.f64(t);
        }
        Stop::Equilibrium { tol, max_steps } => {
            w.u64(2);
            w.u64(max_steps);
            w.f64(tol);
        }
    }
    w.opt_f64(setup.dt);
    w.opt_f64(setup.h);
    w.str(&setup.output.to_string_lossy());
    w.u64(setup.every);
    let it = &setup.integrator;
    w.u64(it.kind as u64);
    w.f64(it.tolerance);
    w.u64(it.max_iterations as u64);
    w.u64(it.max_stages as u64);
    w.u64(it.preconditioner as u64);
    w.0
}

/// Decodes what `encode` wrote.
pub fn decode(bytes: &[u8]) -> Result<Part> {
    let mut r = Reader::new(bytes);
    let sizes = GlobalSizes {
        nodes: r.usize()?,
        cells: r.usize()?,
        conn: r.usize()?,
        mesh_hash: r.u64()?,
    };
    let rank = r.usize()?;
    let global = r.u32s()?;
    let n_interior = r.usize()?;
    let n_owned = r.usize()?;
    let cells = r.u32s()?;
    let nn = r.usize()?;
    let mut neighbours = Vec::new();
    for _ in 0..nn {
        neighbours.push(Neighbour {
            rank: r.usize()?,
            send: r.u32s()?,
            recv: r.u32s()?,
        });
    }
    let plan = Plan {
        rank,
        numbering: LocalNumbering {
            global,
            n_interior,
            n_owned,
        },
        pattern: HaloPattern { neighbours },
        cells,
    };
    let path = PathBuf::from(r.str()?);
    let text = r.str()?;
    let scenario = Scenario::parse(&path, text)?;
    let mut mesh = Mesh::new(r.str()?);
    mesh.points = r.f64s()?.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    mesh.node_ids = r.u64s()?;
    let kinds = r.u32s()?;
    let conn = r.u32s()?;
    let tags = r.u32s()?;
    let mut at = 0;
    for (k, &t) in kinds.iter().zip(&tags) {
        let kind = kind_of(*k)?;
        let nodes = conn
            .get(at..at + kind.n_nodes())
            .ok_or_else(|| anyhow!("internal: cells do not match their connectivity"))?;
        mesh.push_cell(kind, nodes, t as i32);
        at += kind.n_nodes();
    }
    for _ in 0..r.usize()? {
        mesh.warnings.push(r.str()?);
    }
    let rt: Vec<Tensor> = r.f64s()?.chunks_exact(9).map(Tensor::from_column_slice).collect();
    let mass = r.f64s()?;
    let damping = r.f64s()?;
    let fixed: Vec<bool> = r.u32s()?.iter().map(|&b| b != 0).collect();
    let mut loads = Vec::new();
    for _ in 0..r.usize()? {
        let nodes = r.u32s()?;
        let node_ids = r.u64s()?;
        let weights = r.f64s()?;
        let f = r.f64s()?;
        let area = r.f64()?;
        let has_ramp = r.u64()? != 0;
        let ramp: Vec<[f64; 2]> = r.f64s()?.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let normal = r.opt_f64()?;
        let depth = r.opt_f64()?;
        loads.push(Load {
            depth,
            nodes,
            node_ids,
            weights,
            force: [f[0], f[1], f[2]],
            area,
            ramp: has_ramp.then_some(ramp),
            normal,
        });
    }
    let scheme = match r.u64()? {
        0 => Scheme::Compact,
        c => Scheme::Paper { correction: c == 2 },
    };
    let (stiffness, coupling, exponent) = (r.f64()?, r.f64()?, r.f64()?);
    let law = TissueLaw {
        young: r.f64()?,
        beta: r.f64()?,
    };
    let (kind, n, t) = (r.u64()?, r.u64()?, r.f64()?);
    let stop = match kind {
        0 => Stop::Steps(n),
        1 => Stop::End(t),
        _ => Stop::Equilibrium { tol: t, max_steps: n },
    };
    let dt = r.opt_f64()?;
    let h = r.opt_f64()?;
    let output = PathBuf::from(r.str()?);
    let every = r.u64()?;
    let integrator = {
        use crate::integrate::{Kind, Preconditioner, Settings, KINDS, PRECONDITIONERS};
        let kind = r.usize()?;
        let (tolerance, max_iterations, max_stages, pre) = (r.f64()?, r.usize()?, r.usize()?, r.usize()?);
        Settings {
            kind: KINDS
                .iter()
                .map(|k| k.1)
                .find(|&k| k as usize == kind)
                .unwrap_or(Kind::Auto),
            tolerance,
            max_iterations,
            max_stages,
            preconditioner: PRECONDITIONERS
                .iter()
                .map(|k| k.1)
                .find(|&k| k as usize == pre)
                .unwrap_or(Preconditioner::Jacobi),
        }
    };
    Ok(Part {
        setup: Setup {
            scenario,
            mesh,
            r: rt,
            mass,
            damping,
            fixed,
            loads,
            scheme,
            stiffness,
            coupling,
            exponent,
            law,
            stop,
            dt,
            h,
            output,
            every,
            integrator,
        },
        plan,
        sizes,
    })
}

/// Peak resident memory of this process so far, in bytes (Linux; 0 elsewhere).
/// Logs (at -vv) the resident and peak memory of this process after a setup phase.
pub fn log_memory(phase: &str) {
    if tracing::enabled!(tracing::Level::DEBUG) {
        let now = status_kb("VmRSS:") * 1024;
        tracing::debug!(
            "memory after {phase}: {:.1} MiB resident, peak {:.1} MiB",
            now as f64 / 1048576.0,
            peak_rss() as f64 / 1048576.0
        );
    }
}

fn status_kb(key: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(key))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse::<u64>().ok())
        })
        .unwrap_or(0)
}

pub fn peak_rss() -> u64 {
    status_kb("VmHWM:") * 1024
}
