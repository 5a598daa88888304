//! The time loop: energy source, propagation substeps, restoring mechanics (MODEL.md 3-6).

use crate::geometry::{compact_coefficients, Dual, Incidence};
use crate::operator::{Compact, Operator, Paper, V3};
use crate::scenario::{Load, Scheme, Setup, Stop};
use anyhow::{anyhow, bail, Result};
use eprop_io::geom::{dot, norm, scale};
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

/// The propagation state and operator of one process.
pub struct Propagation {
    pub op: Operator,
    pub phi: Vec<V3>,
    next: Vec<V3>,
    grad: Vec<[f64; 9]>,
}

impl Propagation {
    pub fn new(op: Operator, n_local: usize) -> Self {
        let ng = if op.needs_gradients() { n_local } else { 0 };
        Propagation {
            op,
            phi: vec![[0.0; 3]; n_local],
            next: vec![[0.0; 3]; n_local],
            grad: vec![[0.0; 9]; ng],
        }
    }

    /// One forward Euler substep of size h with nodal sources `q` (node, Q).
    pub fn substep(&mut self, h: f64, q: &[(u32, V3)]) {
        let n = self.op.n_rows();
        if self.op.needs_gradients() {
            self.op.gradients(&self.phi, &mut self.grad);
        }
        self.op
            .step_rows(&self.phi, &self.grad, &mut self.next, h, 0..n);
        for &(i, qi) in q {
            let y = &mut self.next[i as usize];
            y[0] += h * qi[0];
            y[1] += h * qi[1];
            y[2] += h * qi[2];
        }
        std::mem::swap(&mut self.phi, &mut self.next);
    }

    /// y = L x (for tests and spectral estimates).
    pub fn apply(&mut self, x: &[V3], y: &mut [V3]) {
        if self.op.needs_gradients() {
            self.op.gradients(x, &mut self.grad);
        }
        self.op.apply(x, &self.grad, y);
    }

    /// Largest stable substep h of forward Euler for this operator.
    ///
    /// `compact`: the spectrum of L is real and non-positive (L = V^-1 W, W symmetric negative
    /// semi-definite), so h < 2 / rho with rho bounded by Gershgorin. `paper`: L is not
    /// symmetric and its spectrum may be complex, so the bound comes from the amplification
    /// operator itself: a start value from power iteration on L, then h is reduced until
    /// repeated substeps of I + hL no longer grow a random vector.
    pub fn stable_h(&mut self, active: &[bool]) -> f64 {
        match &self.op {
            Operator::Compact(c) => {
                let g = c.gershgorin();
                if g > 0.0 {
                    2.0 / g
                } else {
                    f64::INFINITY
                }
            }
            Operator::Paper(_) => self.paper_stable_h(active),
        }
    }

    fn paper_stable_h(&mut self, active: &[bool]) -> f64 {
        let n = self.op.n_rows();
        let start: Vec<V3> = (0..n)
            .map(|i| {
                if active[i] {
                    [
                        hash_unit(3 * i as u64),
                        hash_unit(3 * i as u64 + 1),
                        hash_unit(3 * i as u64 + 2),
                    ]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        let nrm = |x: &[V3]| x.iter().map(|v| dot(*v, *v)).sum::<f64>().sqrt();
        // power iteration on L: growth rate of |L^k x|
        let mut x = start.clone();
        let mut y = vec![[0.0; 3]; n];
        let mut logs = Vec::new();
        for _ in 0..60 {
            self.apply(&x, &mut y);
            let ny = nrm(&y);
            let nx = nrm(&x);
            if ny == 0.0 || nx == 0.0 {
                return f64::INFINITY;
            }
            logs.push((ny / nx).ln());
            let s = 1.0 / ny;
            for (xi, yi) in x.iter_mut().zip(&y) {
                *xi = scale(*yi, s);
            }
        }
        let tail = &logs[logs.len() - 20..];
        let rho = (tail.iter().sum::<f64>() / tail.len() as f64).exp();
        let mut h = 2.0 / (1.05 * rho);
        // check the amplification I + hL on a random vector; shrink until it does not grow
        for _ in 0..12 {
            let mut x = start.clone();
            let mut growth = Vec::new();
            for _ in 0..120 {
                self.apply(&x, &mut y);
                let nx = nrm(&x);
                for (xi, yi) in x.iter_mut().zip(&y) {
                    xi[0] += h * yi[0];
                    xi[1] += h * yi[1];
                    xi[2] += h * yi[2];
                }
                let nn = nrm(&x);
                growth.push(nn / nx);
                let s = 1.0 / nn.max(1e-300);
                x.iter_mut().for_each(|v| *v = scale(*v, s));
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

/// A load as applied at one instant.
#[derive(Clone, Copy, Debug)]
pub struct Applied {
    pub force: V3,
    /// energy density q(sigma)
    pub q: f64,
    pub sigma: f64,
}

/// One serial simulation.
pub struct Simulation {
    pub setup: Setup,
    pub dual: Dual,
    pub prop: Propagation,
    /// nodes that move: not fixed and with a control volume
    pub active: Vec<bool>,
    pub u: Vec<V3>,
    pub v: Vec<V3>,
    pub force: Vec<V3>,
    pub loads: Vec<Load>,
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

impl Simulation {
    pub fn new(setup: Setup) -> Result<Simulation> {
        let mesh = &setup.mesh;
        let n = mesh.n_nodes();
        let inc = Incidence::new(mesh);
        let dual = Dual::build(mesh, &inc, n, None);
        let inactive_nodes = dual.vol.iter().filter(|&&v| v <= 0.0).count();
        let active: Vec<bool> = (0..n)
            .map(|i| !setup.fixed[i] && dual.vol[i] > 0.0)
            .collect();
        let op = match setup.scheme {
            Scheme::Compact => {
                let a = compact_coefficients(mesh, &inc, &dual, &setup.r);
                Operator::Compact(Compact::new(&dual, &a, &active))
            }
            Scheme::Paper { correction } => Operator::Paper(Paper::new(
                &dual,
                &mesh.points,
                &setup.r,
                &active,
                correction,
            )),
        };
        let mut prop = Propagation::new(op, n);
        let h_bound = prop.stable_h(&active);
        let sc = &setup.scenario;

        // mechanics step
        let dt_bound = (0..n)
            .filter(|&i| active[i])
            .map(|i| dt_bound_node(setup.mass[i], setup.damping[i], setup.stiffness))
            .fold(f64::INFINITY, f64::min);
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

        // loads: contact area, normal direction
        let mut loads = setup.loads.clone();
        for (k, l) in loads.iter_mut().enumerate() {
            let mut a = [0.0; 3];
            for (&i, &w) in l.nodes.iter().zip(&l.weights) {
                let ai = dual.area[i as usize];
                a = [a[0] + w * ai[0], a[1] + w * ai[1], a[2] + w * ai[2]];
            }
            let an = norm(a);
            if !(an > 0.0) {
                bail!(
                    "{}: load {} on node {}: the node is inside the volume (no boundary area), so no contact stress is defined; fix: load a surface node (`nearest` picks one)",
                    sc.path.display(),
                    k + 1,
                    mesh.node_ids[l.nodes[0] as usize]
                );
            }
            l.area = an;
            if let Some(mag) = l.normal {
                l.force = scale(a, -mag / an);
            }
        }
        Ok(Simulation {
            u: vec![[0.0; 3]; n],
            v: vec![[0.0; 3]; n],
            force: vec![[0.0; 3]; n],
            dual,
            prop,
            active,
            loads,
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
        for (l, a) in self.loads.iter().zip(&applied) {
            let fn_ = norm(a.force);
            for (&i, &w) in l.nodes.iter().zip(&l.weights) {
                self.force[i as usize] = scale(a.force, w);
                if fn_ > 0.0 {
                    q.push((i, scale(a.force, w * a.q / fn_)));
                }
            }
        }
        q
    }

    /// One mechanics step: sources at t_n, propagation substeps, then u and v.
    pub fn advance(&mut self) {
        let q = self.sources(self.time);
        for _ in 0..self.substeps {
            self.prop.substep(self.h, &q);
        }
        let (dt, k, kappa, p) = (
            self.dt,
            self.setup.stiffness,
            self.setup.coupling,
            self.setup.exponent,
        );
        let phi = &self.prop.phi;
        let (mass, damp, force, active) = (
            &self.setup.mass,
            &self.setup.damping,
            &self.force,
            &self.active,
        );
        self.max_speed = self
            .u
            .par_iter_mut()
            .zip(self.v.par_iter_mut())
            .enumerate()
            .map(|(i, (u, v))| {
                if !active[i] {
                    return 0.0;
                }
                let ph = phi[i];
                let mag = norm(ph);
                let push = if mag > 0.0 {
                    kappa * if p == 1.0 { 1.0 } else { mag.powf(p - 1.0) }
                } else {
                    0.0
                };
                let (inv_m, g, f) = (1.0 / mass[i], damp[i], force[i]);
                for d in 0..3 {
                    let a = (f[d] - k * u[d] + push * ph[d] - g * v[d]) * inv_m;
                    v[d] += dt * a;
                    u[d] += dt * v[d];
                }
                norm(*v)
            })
            .reduce(|| 0.0, f64::max);
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

    /// Probes per load: (applied force, displacement of the contact node).
    pub fn probes(&self) -> Vec<(V3, V3)> {
        let applied = self.applied(self.time);
        self.loads
            .iter()
            .zip(&applied)
            .map(|(l, a)| {
                let mut d = [0.0; 3];
                for (&i, &w) in l.nodes.iter().zip(&l.weights) {
                    let ui = self.u[i as usize];
                    d = [d[0] + w * ui[0], d[1] + w * ui[1], d[2] + w * ui[2]];
                }
                (a.force, d)
            })
            .collect()
    }

    /// Sum of V_i |phi_i| over the body.
    pub fn total_energy(&self) -> f64 {
        self.prop
            .phi
            .iter()
            .zip(&self.dual.vol)
            .map(|(p, v)| v * norm(*p))
            .sum()
    }

    /// Largest |u| and its node.
    pub fn max_displacement(&self) -> (f64, usize) {
        self.u
            .iter()
            .enumerate()
            .map(|(i, u)| (norm(*u), i))
            .fold((0.0, 0), |a, b| if b.0 > a.0 { b } else { a })
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
        return Err(anyhow!("{}: the output directory does not exist; fix: create it or choose another [output] file / --output", path.display()));
    }
    Ok(())
}
