//! The time loop: energy source, propagation substeps, restoring mechanics (MODEL.md 3-6).

use crate::comm::{exact_sum, Comm, Serial};
use crate::geometry::{compact_coefficients, Dual, Incidence};
use crate::operator::{Compact, Operator, Paper, V3};
use crate::scenario::{Load, Scheme, Setup, Stop};
use anyhow::{anyhow, bail, Result};
use eprop_io::geom::{dot, norm, scale};
use eprop_io::Mesh;
use eprop_partition::Plan;
use rayon::prelude::*;

/// Safety factor applied to every stability bound for the automatic choices.
pub const SAFETY: f64 = 0.9;

/// Largest stable mechanics step of one node (semi-implicit Euler), infinite when undamped
/// and unsprung.
pub fn dt_bound_node(m: f64, g: f64, k: f64) -> f64 {
    if k > 0.0 {
        (-g + (g * g + 4.0 * m * k).sqrt()) / k
    } else if g > 0.0 {
        2.0 * m / g
    } else {
        f64::INFINITY
    }
}

/// A deterministic pseudo-random number in [-1, 1) from an integer (SplitMix64).
pub fn hash_unit(mut x: u64) -> f64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// The interior rows `0..n` in pieces of at least 16k rows, at most 16 of them: between two
/// pieces MPI gets a chance to move the halo messages (see `Comm::exchange_overlapped`).
fn pieces(n: usize) -> impl Iterator<Item = std::ops::Range<usize>> {
    let size = n.div_ceil(16).max(16 * 1024);
    (0..n.div_ceil(size)).map(move |k| k * size..((k + 1) * size).min(n))
}

/// The propagation state and operator of one process. Rows `0..n_interior` read owned
/// values only; rows `n_interior..n_rows` also read halo values.
pub struct Propagation {
    pub op: Operator,
    pub phi: Vec<V3>,
    next: Vec<V3>,
    grad: Vec<[f64; 9]>,
    n_interior: usize,
}

impl Propagation {
    pub fn new(op: Operator, n_local: usize, n_interior: usize) -> Self {
        let ng = if op.needs_gradients() { n_local } else { 0 };
        Propagation {
            n_interior: n_interior.min(op.n_rows()),
            op,
            phi: vec![[0.0; 3]; n_local],
            next: vec![[0.0; 3]; n_local],
            grad: vec![[0.0; 9]; ng],
        }
    }

    /// One forward Euler substep of size h with nodal sources `q` (owned node, Q). The halo of
    /// phi is refreshed first, while the interior rows are computed; the border rows follow.
    pub fn substep(&mut self, h: f64, q: &[(u32, V3)], comm: &dyn Comm) {
        let (n, ni) = (self.op.n_rows(), self.n_interior);
        let Propagation {
            op, phi, next, grad, ..
        } = self;
        if op.needs_gradients() {
            comm.exchange_overlapped(phi.as_flattened_mut(), 3, &mut |x, progress| {
                for r in pieces(ni) {
                    op.gradients(as_v3(x), grad, r);
                    progress();
                }
            });
            op.gradients(phi, grad, ni..n);
            let phi: &[V3] = phi;
            comm.exchange_overlapped(grad.as_flattened_mut(), 9, &mut |g, progress| {
                for r in pieces(ni) {
                    op.step_rows(phi, g.as_chunks::<9>().0, next, h, r);
                    progress();
                }
            });
            op.step_rows(phi, grad, next, h, ni..n);
        } else {
            comm.exchange_overlapped(phi.as_flattened_mut(), 3, &mut |x, progress| {
                for r in pieces(ni) {
                    op.step_rows(as_v3(x), &[], next, h, r);
                    progress();
                }
            });
            op.step_rows(phi, &[], next, h, ni..n);
        }
        for &(i, qi) in q {
            let y = &mut next[i as usize];
            y[0] += h * qi[0];
            y[1] += h * qi[1];
            y[2] += h * qi[2];
        }
        std::mem::swap(phi, next);
    }

    /// One substep on a single process (tests).
    pub fn substep_serial(&mut self, h: f64, q: &[(u32, V3)]) {
        self.substep(h, q, &Serial)
    }

    /// y = L x on the owned rows; x must have a current halo.
    pub fn apply_with(&mut self, x: &[V3], y: &mut [V3], comm: &dyn Comm) {
        if self.op.needs_gradients() {
            let n = self.op.n_rows();
            self.op.gradients(x, &mut self.grad, 0..n);
            comm.exchange(self.grad.as_flattened_mut(), 9);
        }
        self.op.apply(x, &self.grad, y);
    }

    /// y = L x on one process (tests).
    pub fn apply(&mut self, x: &[V3], y: &mut [V3]) {
        self.apply_with(x, y, &Serial)
    }

    /// Largest stable substep h of forward Euler for this operator.
    ///
    /// `compact`: the spectrum of L is real and non-positive (L = V^-1 W, W symmetric negative
    /// semi-definite), so h < 2 / rho with rho bounded by Gershgorin. `paper`: L is not
    /// symmetric and its spectrum may be complex, so the bound comes from the amplification
    /// operator itself: a start value from power iteration on L, then h is reduced until
    /// repeated substeps of I + hL no longer grow a random vector. Start vectors hash the
    /// global node id and norms are exact sums: the same h on any number of processes.
    /// `active` and `gid` cover the local nodes (owned, then halo).
    pub fn stable_h(&mut self, active: &[bool], gid: &[u64], comm: &dyn Comm) -> f64 {
        match &self.op {
            Operator::Compact(c) => {
                let g = comm.max(c.gershgorin());
                if g > 0.0 {
                    2.0 / g
                } else {
                    f64::INFINITY
                }
            }
            Operator::Paper(_) => self.paper_stable_h(active, gid, comm),
        }
    }

    fn paper_stable_h(&mut self, active: &[bool], gid: &[u64], comm: &dyn Comm) -> f64 {
        let n = self.op.n_rows();
        let nl = self.phi.len();
        let start: Vec<V3> = (0..nl)
            .map(|i| {
                let g = gid[i];
                if active[i] {
                    [hash_unit(3 * g), hash_unit(3 * g + 1), hash_unit(3 * g + 2)]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        let nrm = |x: &[V3]| exact_sum(comm, x[..n].iter().map(|v| dot(*v, *v))).sqrt();
        // power iteration on L: growth rate of |L^k x|
        let mut x = start.clone();
        let mut y = vec![[0.0; 3]; nl];
        let mut logs = Vec::new();
        for _ in 0..60 {
            self.apply_with(&x, &mut y, comm);
            let ny = nrm(&y);
            let nx = nrm(&x);
            if ny == 0.0 || nx == 0.0 {
                return f64::INFINITY;
            }
            logs.push((ny / nx).ln());
            let s = 1.0 / ny;
            for (xi, yi) in x.iter_mut().zip(&y).take(n) {
                *xi = scale(*yi, s);
            }
            comm.exchange(x.as_flattened_mut(), 3);
        }
        let tail = &logs[logs.len() - 20..];
        let rho = (tail.iter().sum::<f64>() / tail.len() as f64).exp();
        let mut h = 2.0 / (1.05 * rho);
        // check the amplification I + hL on a random vector; shrink until it does not grow
        for _ in 0..12 {
            let mut x = start.clone();
            let mut growth = Vec::new();
            for _ in 0..120 {
                self.apply_with(&x, &mut y, comm);
                let nx = nrm(&x);
                for (xi, yi) in x.iter_mut().zip(&y).take(n) {
                    xi[0] += h * yi[0];
                    xi[1] += h * yi[1];
                    xi[2] += h * yi[2];
                }
                let nn = nrm(&x);
                growth.push(nn / nx);
                let s = 1.0 / nn.max(1e-300);
                x.iter_mut().take(n).for_each(|v| *v = scale(*v, s));
                comm.exchange(x.as_flattened_mut(), 3);
            }
            let late = &growth[growth.len() - 40..];
            let g = (late.iter().map(|v| v.ln()).sum::<f64>() / late.len() as f64).exp();
            if g <= 1.0 + 1e-9 {
                return h;
            }
            h *= 0.8;
        }
        h
    }
}

/// 3-vectors seen in a flat slice.
fn as_v3(x: &[f64]) -> &[V3] {
    x.as_chunks::<3>().0
}

/// A load as applied at one instant.
#[derive(Clone, Copy, Debug)]
pub struct Applied {
    pub force: V3,
    /// energy density q(sigma)
    pub q: f64,
    pub sigma: f64,
}

/// Moves owned values into contiguous blocks of the global node order for output: process r
/// holds rows `start..start + len`, with `start = r N / P`. Built once; each use is one
/// all-to-all, so no process ever holds a global array.
pub struct Blocks {
    pub start: usize,
    pub len: usize,
    send_order: Vec<u32>,
    counts: Vec<usize>,
    recv_counts: Vec<usize>,
    place: Vec<u32>,
}

impl Blocks {
    pub fn new(gid_owned: &[u64], n_global: usize, comm: &dyn Comm) -> Blocks {
        let p = comm.size();
        let first = |r: usize| (r * n_global) / p;
        let owner = |g: u64| {
            // the last r with first(r) <= g
            let mut r = ((g as usize + 1) * p).div_ceil(n_global.max(1)).min(p) - 1;
            while first(r) > g as usize {
                r -= 1;
            }
            while r + 1 < p && first(r + 1) <= g as usize {
                r += 1;
            }
            r
        };
        let mut items: Vec<(usize, u64, u32)> = gid_owned
            .iter()
            .enumerate()
            .map(|(l, &g)| (owner(g), g, l as u32))
            .collect();
        items.sort_unstable();
        let mut counts = vec![0usize; p];
        for it in &items {
            counts[it.0] += 1;
        }
        let gids: Vec<f64> = items.iter().map(|it| it.1 as f64).collect();
        let me = comm.rank();
        let start = first(me);
        let got = comm.all_to_all(&gids, &counts);
        let cf: Vec<f64> = counts.iter().map(|&c| c as f64).collect();
        let recv_counts = comm.all_to_all(&cf, &vec![1; p]).iter().map(|&c| c as usize).collect();
        Blocks {
            recv_counts,
            start,
            len: first(me + 1) - start,
            send_order: items.iter().map(|it| it.2).collect(),
            counts,
            place: got.iter().map(|&g| (g as usize - start) as u32).collect(),
        }
    }

    /// This process's block of a per-node array (`stride` values per node) from the owned values.
    pub fn collect(&self, owned: &[f64], stride: usize, comm: &dyn Comm) -> Vec<f64> {
        let mut send = Vec::with_capacity(self.send_order.len() * stride);
        for &l in &self.send_order {
            send.extend_from_slice(&owned[l as usize * stride..(l as usize + 1) * stride]);
        }
        let counts: Vec<usize> = self.counts.iter().map(|c| c * stride).collect();
        let got = comm.all_to_all(&send, &counts);
        let mut out = vec![0.0; self.len * stride];
        for (k, &at) in self.place.iter().enumerate() {
            out[at as usize * stride..(at as usize + 1) * stride].copy_from_slice(&got[k * stride..(k + 1) * stride]);
        }
        out
    }

    /// The inverse of `collect`: the owned values (local order) from this process's block.
    pub fn distribute(&self, block: &[f64], stride: usize, comm: &dyn Comm) -> Vec<f64> {
        let mut send = Vec::with_capacity(self.place.len() * stride);
        for &at in &self.place {
            send.extend_from_slice(&block[at as usize * stride..(at as usize + 1) * stride]);
        }
        let counts: Vec<usize> = self.recv_counts.iter().map(|c| c * stride).collect();
        let got = comm.all_to_all(&send, &counts);
        let mut out = vec![0.0; self.send_order.len() * stride];
        for (k, &l) in self.send_order.iter().enumerate() {
            out[l as usize * stride..(l as usize + 1) * stride].copy_from_slice(&got[k * stride..(k + 1) * stride]);
        }
        out
    }
}

/// A Morton (Z-order) index of every node inside the mesh's bounding box: sorting by it
/// keeps nodes that are close in space close in memory.
pub fn morton_keys(mesh: &Mesh) -> Vec<u64> {
    let (lo, hi) = mesh.bounds();
    let spread = |mut x: u64| {
        x &= 0x1f_ffff;
        x = (x | x << 32) & 0x1f00000000ffff;
        x = (x | x << 16) & 0x1f0000ff0000ff;
        x = (x | x << 8) & 0x100f00f00f00f00f;
        x = (x | x << 4) & 0x10c30c30c30c30c3;
        (x | x << 2) & 0x1249249249249249
    };
    mesh.points
        .iter()
        .map(|p| {
            let mut k = 0u64;
            for d in 0..3 {
                let w = hi[d] - lo[d];
                let t = if w > 0.0 {
                    ((p[d] - lo[d]) / w).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                k |= spread((t * 2097151.0) as u64) << d;
            }
            k
        })
        .collect()
}

/// One simulation on this process's part of the mesh (all of it on one process).
/// Local numbering: owned nodes first, then halo nodes; per-node arrays cover both, and only
/// owned entries are computed here (halo entries are copies from their owners).
pub struct Simulation {
    /// This process's view of the scenario: its local mesh and per-node arrays in local
    /// numbering (loads keep global node indices).
    pub setup: Setup,
    pub comm: Box<dyn Comm>,
    /// The whole mesh, on the process that writes the static part of the output (rank 0).
    pub global: Option<Mesh>,
    pub n_global: usize,
    /// Global node index of each local node.
    pub gid: Vec<u64>,
    pub n_owned: usize,
    pub n_interior: usize,
    /// Output blocks of the global node order.
    pub blocks: Blocks,
    pub dual: Dual,
    pub prop: Propagation,
    /// nodes that move: not fixed and with a control volume
    pub active: Vec<bool>,
    pub u: Vec<V3>,
    pub v: Vec<V3>,
    pub force: Vec<V3>,
    pub loads: Vec<Load>,
    /// owned contact nodes of each load (local index, probe weight, force weight, source weight)
    pub load_local: Vec<Vec<(u32, f64, f64, f64)>>,
    /// control volumes of this process's output block
    pub vol_block: Vec<f64>,
    /// nodes of the whole mesh that belong to no cell; fixed nodes of the whole mesh
    pub fixed_nodes: usize,
    pub h: f64,
    pub h_bound: f64,
    pub dt: f64,
    pub dt_bound: f64,
    pub substeps: usize,
    pub step: u64,
    pub time: f64,
    pub max_speed: f64,
    pub inactive_nodes: usize,
}

/// The cells of a plan, renumbered locally.
pub fn local_mesh(global: &Mesh, plan: &Plan) -> Mesh {
    let mut map = std::collections::HashMap::with_capacity(plan.global.len());
    for (l, &g) in plan.global.iter().enumerate() {
        map.insert(g, l as u32);
    }
    let mut m = Mesh::new(global.source.clone());
    m.points = plan.global.iter().map(|&g| global.points[g as usize]).collect();
    m.node_ids = plan.global.iter().map(|&g| global.node_ids[g as usize]).collect();
    let mut buf = Vec::with_capacity(8);
    for &c in &plan.cells {
        buf.clear();
        buf.extend(global.cell(c as usize).iter().map(|g| map[g]));
        m.push_cell(global.kinds[c as usize], &buf, global.cell_tags[c as usize]);
    }
    m
}

impl Simulation {
    /// A simulation on one process (nodes reordered for locality; output in input order).
    pub fn new(setup: Setup) -> Result<Simulation> {
        let m = &setup.mesh;
        let part = vec![0u32; m.n_nodes()];
        let plan = Plan::new(m.n_nodes(), &m.offsets, &m.conn, &part, 0, Some(&morton_keys(m)));
        let local = setup.restrict(&plan);
        let Setup { mesh, .. } = setup; // the global per-node arrays go before the build
        Self::new_with(local, Box::new(Serial), plan, Some(mesh))
    }

    /// A simulation of this process's part: `setup` is its local view (`Setup::restrict`),
    /// `global` the whole mesh on the process that writes the static output.
    pub fn new_with(setup: Setup, comm: Box<dyn Comm>, plan: Plan, global: Option<Mesh>) -> Result<Simulation> {
        let mesh = &setup.mesh;
        let nl = mesh.n_nodes();
        let gid: Vec<u64> = plan.global.iter().map(|&g| g as u64).collect();
        let (n_owned, n_interior) = (plan.n_owned, plan.n_interior);
        let n_global = comm.sum_i128(n_owned as i128) as usize;
        let inc = Incidence::new(mesh);
        crate::distribute::log_memory("the local mesh and plan");
        let mut dual = Dual::build(mesh, &inc, n_owned, Some(gid.as_slice()));
        crate::distribute::log_memory("the dual geometry");
        let inactive_nodes = comm.sum_i128(dual.vol.iter().filter(|&&v| v <= 0.0).count() as i128) as usize;
        // activity of halo nodes comes from their owners; only fixedness matters there
        let active: Vec<bool> = (0..nl)
            .map(|i| !setup.fixed[i] && (i >= n_owned || dual.vol[i] > 0.0))
            .collect();
        let fixed_nodes = comm.sum_i128(setup.fixed[..n_owned].iter().filter(|&&b| b).count() as i128) as usize;
        let r = &setup.r;
        let op = match setup.scheme {
            Scheme::Compact => {
                dual.release_pairs(); // S_ij are not needed by compact: free them first
                let a = compact_coefficients(mesh, &inc, &dual, r);
                crate::distribute::log_memory("the coefficients");
                let col = std::mem::take(&mut dual.col);
                let c = Compact::from_pairs(&dual.row_ptr[..=n_owned], col, a, &dual.vol, &active);
                if setup.scenario.file.model.operator_precision == "float32" {
                    Operator::Compact(c.into_f32())
                } else {
                    Operator::Compact(c)
                }
            }
            Scheme::Paper { correction } => Operator::Paper(Paper::new(&dual, &mesh.points, r, &active, correction)),
        };
        drop(inc);
        dual.release_pairs();
        dual.col = Vec::new();
        dual.row_ptr = Vec::new();
        crate::distribute::log_memory("the operator");
        let mut prop = Propagation::new(op, nl, n_interior);
        tracing::info!(
            "geometry and operator built ({} rows); searching the stable substep",
            n_owned
        );
        let h_bound = prop.stable_h(&active, &gid, comm.as_ref());
        let sc = &setup.scenario;

        // mechanics step
        let dt_bound = comm.min(
            (0..n_owned)
                .filter(|&i| active[i])
                .map(|i| dt_bound_node(setup.mass[i], setup.damping[i], setup.stiffness))
                .fold(f64::INFINITY, f64::min),
        );
        let dt = match setup.dt {
            Some(dt) if dt > dt_bound => bail!(
                "{}: [time] dt = {dt} is above the mechanics stability bound {dt_bound:.6e}; fix: use dt <= {:.6e} or leave dt out (automatic)",
                sc.path.display(),
                SAFETY * dt_bound
            ),
            Some(dt) => dt,
            None if dt_bound.is_finite() => SAFETY * dt_bound,
            None => bail!(
                "{}: with stiffness = 0 and damping = 0 no step size is stable by itself; fix: set [time] dt",
                sc.path.display()
            ),
        };
        let h_max = match setup.h {
            Some(h) if h > h_bound => bail!(
                "{}: [time] h = {h} is above the stability bound {h_bound:.6e} of the {} scheme on this mesh; fix: use h <= {:.6e} or leave h out (automatic)",
                sc.path.display(),
                scheme_name(setup.scheme),
                SAFETY * h_bound
            ),
            Some(h) => h,
            None => SAFETY * h_bound,
        };
        let substeps = if h_max.is_finite() {
            (dt / h_max).ceil().max(1.0) as usize
        } else {
            1
        };
        let h = dt / substeps as f64;

        // loads: contact area (summed over the owners of the contact nodes), normal direction
        let mut local_of = std::collections::HashMap::new();
        for i in 0..n_owned {
            local_of.insert(gid[i] as u32, i as u32);
        }
        let mut loads = setup.loads.clone();
        let mut load_local = Vec::new();
        for (k, l) in loads.iter_mut().enumerate() {
            let mine: Vec<(u32, f64)> = l
                .nodes
                .iter()
                .zip(&l.weights)
                .filter_map(|(gn, &w)| local_of.get(gn).map(|&li| (li, w)))
                .collect();
            let mut a = [0.0; 3];
            for d in 0..3 {
                a[d] = exact_sum(comm.as_ref(), mine.iter().map(|&(li, _)| dual.area[li as usize][d]));
            }
            let an = norm(a);
            if !(an > 0.0) {
                bail!(
                    "{}: load {} on node {}: the node is inside the volume (no boundary area), so no contact stress is defined; fix: load a surface node (`nearest` picks one)",
                    sc.path.display(),
                    k + 1,
                    l.node_ids[0]
                );
            }
            l.area = an;
            if let Some(mag) = l.normal {
                l.force = scale(a, -mag / an);
            }
            let mine = mine
                .iter()
                .map(|&(li, w)| match l.depth {
                    // a patch: every contact node is pressed by F (the mechanics are nodal) and
                    // the source enters through the patch surface as a flux
                    Some(depth) => (li, w, 1.0, norm(dual.area[li as usize]) * depth / dual.vol[li as usize]),
                    None => (li, w, w, w),
                })
                .collect();
            load_local.push(mine);
        }
        let blocks = Blocks::new(&gid[..n_owned], n_global, comm.as_ref());
        let vol_block = blocks.collect(&dual.vol, 1, comm.as_ref());
        Ok(Simulation {
            u: vec![[0.0; 3]; nl],
            v: vec![[0.0; 3]; nl],
            force: vec![[0.0; 3]; nl],
            dual,
            prop,
            active,
            loads,
            load_local,
            vol_block,
            fixed_nodes,
            blocks,
            n_global,
            n_interior,
            h,
            h_bound,
            dt,
            dt_bound,
            substeps,
            step: 0,
            time: 0.0,
            max_speed: 0.0,
            inactive_nodes,
            setup,
            comm,
            global,
            gid,
            n_owned,
        })
    }

    /// The loads at time t.
    pub fn applied(&self, t: f64) -> Vec<Applied> {
        self.loads
            .iter()
            .map(|l| {
                let f = scale(l.force, l.scale(t));
                let sigma = norm(f) / l.area;
                Applied {
                    force: f,
                    q: self.setup.law.energy_density(sigma),
                    sigma,
                }
            })
            .collect()
    }

    /// Nodal sources Q and forces f for the loads at time t.
    fn sources(&mut self, t: f64) -> Vec<(u32, V3)> {
        let applied = self.applied(t);
        let mut q = Vec::new();
        for (mine, a) in self.load_local.iter().zip(&applied) {
            let fn_ = norm(a.force);
            for &(i, _, fw, sw) in mine {
                self.force[i as usize] = scale(a.force, fw);
                if fn_ > 0.0 {
                    q.push((i, scale(a.force, sw * a.q / fn_)));
                }
            }
        }
        q
    }

    /// One mechanics step: sources at t_n, propagation substeps, then u and v.
    pub fn advance(&mut self) {
        let q = self.sources(self.time);
        for _ in 0..self.substeps {
            self.prop.substep(self.h, &q, self.comm.as_ref());
        }
        let (dt, k, kappa, p) = (self.dt, self.setup.stiffness, self.setup.coupling, self.setup.exponent);
        let phi = &self.prop.phi;
        let (mass, damp, force, active) = (&self.setup.mass, &self.setup.damping, &self.force, &self.active);
        let n = self.n_owned;
        const CH: usize = 4096;
        let local_max2 = self.u[..n]
            .par_chunks_mut(CH)
            .zip(self.v[..n].par_chunks_mut(CH))
            .enumerate()
            .map(|(b, (us, vs))| {
                let mut m2 = 0.0f64;
                for (o, (u, v)) in us.iter_mut().zip(vs.iter_mut()).enumerate() {
                    let i = b * CH + o;
                    if !active[i] {
                        continue;
                    }
                    let ph = phi[i];
                    // kappa |phi|^(p-1) phi; for p = 1 simply kappa phi
                    let push = if p == 1.0 {
                        kappa
                    } else {
                        let mag = norm(ph);
                        if mag > 0.0 {
                            kappa * mag.powf(p - 1.0)
                        } else {
                            0.0
                        }
                    };
                    let (inv_m, g, f) = (1.0 / mass[i], damp[i], force[i]);
                    for d in 0..3 {
                        let a = (f[d] - k * u[d] + push * ph[d] - g * v[d]) * inv_m;
                        v[d] += dt * a;
                        u[d] += dt * v[d];
                    }
                    m2 = m2.max(dot(*v, *v));
                }
                m2
            })
            .reduce(|| 0.0, f64::max);
        let local_max = local_max2.sqrt();
        self.max_speed = self.comm.max(local_max);
        self.step += 1;
        self.time = self.step as f64 * self.dt;
    }

    /// Number of steps the stop condition allows (equilibrium: its cap).
    pub fn max_steps(&self) -> u64 {
        match self.setup.stop {
            Stop::Steps(n) => n,
            Stop::End(t) => (t / self.dt - 1e-9).ceil().max(0.0) as u64,
            Stop::Equilibrium { max_steps, .. } => max_steps,
        }
    }

    /// True when the run should stop after the current step.
    pub fn done(&self) -> bool {
        if self.step >= self.max_steps() {
            return true;
        }
        match self.setup.stop {
            Stop::Equilibrium { tol, .. } => self.step > 0 && self.max_speed < tol,
            _ => false,
        }
    }

    /// Per load: (applied force, weighted displacement of its contact nodes), the same on
    /// every process (exact sums).
    pub fn probes(&self) -> Vec<(V3, V3)> {
        let applied = self.applied(self.time);
        self.load_local
            .iter()
            .zip(&applied)
            .map(|(mine, a)| {
                let mut d = [0.0; 3];
                for c in 0..3 {
                    d[c] = exact_sum(
                        self.comm.as_ref(),
                        mine.iter().map(|&(i, w, _, _)| w * self.u[i as usize][c]),
                    );
                }
                (a.force, d)
            })
            .collect()
    }

    /// Sum of V_i |phi_i| over the mesh (exact sum).
    pub fn total_energy(&self) -> f64 {
        let n = self.n_owned;
        exact_sum(
            self.comm.as_ref(),
            self.dual.vol[..n]
                .iter()
                .zip(&self.prop.phi[..n])
                .map(|(v, p)| v * norm(*p)),
        )
    }

    /// Largest |u| and the global index of its node (ties: the lowest index).
    pub fn max_displacement(&self) -> (f64, u64) {
        let n = self.n_owned;
        let (mut best, mut at) = (-1.0, u64::MAX);
        for i in 0..n {
            let m = norm(self.u[i]);
            if m > best || (m == best && self.gid[i] < at) {
                (best, at) = (m, self.gid[i]);
            }
        }
        let all = self.comm.all_gather(&[best, at as f64]);
        let (mut best, mut at) = (-1.0, u64::MAX);
        for c in all.chunks(2) {
            let (m, g) = (c[0], c[1] as u64);
            if m > best || (m == best && g < at) {
                (best, at) = (m, g);
            }
        }
        (best.max(0.0), at)
    }

    /// Continues from a stored state: this process's blocks of u, v and phi at `step`.
    pub fn restore(&mut self, step: u64, u: &[f64], v: &[f64], phi: &[f64]) {
        let c = self.comm.as_ref();
        let n = self.n_owned;
        for (dst, src) in [(&mut self.u, u), (&mut self.v, v), (&mut self.prop.phi, phi)] {
            let owned = self.blocks.distribute(src, 3, c);
            for i in 0..n {
                dst[i] = [owned[3 * i], owned[3 * i + 1], owned[3 * i + 2]];
            }
        }
        self.step = step;
        self.time = step as f64 * self.dt;
        let local = (0..n)
            .filter(|&i| self.active[i])
            .map(|i| norm(self.v[i]))
            .fold(0.0, f64::max);
        self.max_speed = c.max(local);
    }

    /// Local index of a global node owned here.
    pub fn local(&self, global: u32) -> Option<usize> {
        self.gid[..self.n_owned].iter().position(|&g| g == global as u64)
    }

    /// This process's output block of a per-node array (global node order), flattened.
    pub fn in_output_order(&self, x: &[V3]) -> Vec<f64> {
        self.blocks
            .collect(x[..self.n_owned].as_flattened(), 3, self.comm.as_ref())
    }

    /// The local mesh this process computes on.
    pub fn mesh(&self) -> &Mesh {
        &self.setup.mesh
    }
}

pub fn scheme_name(s: Scheme) -> &'static str {
    match s {
        Scheme::Compact => "compact",
        Scheme::Paper { correction: true } => "paper (corrected)",
        Scheme::Paper { correction: false } => "paper (uncorrected)",
    }
}

/// Flattens 3-vectors for output.
pub fn flat(v: &[V3]) -> Vec<f64> {
    v.iter().flatten().copied().collect()
}

/// Checks that a path's directory exists before a long run starts.
pub fn check_output_dir(path: &std::path::Path) -> Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    if !dir.is_dir() {
        return Err(anyhow!(
            "{}: the output directory does not exist; fix: create it or choose another [output] file / --output",
            path.display()
        ));
    }
    Ok(())
}
