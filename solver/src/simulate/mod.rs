//! One simulation on one process's part of the mesh: loads, propagation, mechanics
//! (docs/model.md sections 3-6). `Simulation::advance` is one mechanics step: the loads at t_n
//! give the sources Q and the forces f; the stepper advances the potential over dt; the nodes
//! move.

mod access;
pub mod contact;
pub mod distributed;
pub mod inspect;
pub mod kinematic;
mod live;
mod mesh_info;
pub mod realtime;
pub mod steady;
mod stop;
#[cfg(test)]
mod tests;

use crate::config::tissue::Materials;
use crate::config::{Fuse, Load, Precision, Reading, Scheme, Setup, Stop};
use crate::diagnostics::short;
use crate::discretize::geometry::{capacities, compact_coefficients, young_faces, Dual, Incidence};
use crate::discretize::operator::{Compact, Operator, Paper};
use crate::distribute::comm::{reproducible_sum, Comm, Serial};
use crate::distribute::field::NodeField;
use crate::distribute::halo::{BlockScatter, Halo};
use crate::linalg::V3;
use crate::propagate::integrate::{stability, StepPlan, StepStats, Stepper};
use crate::propagate::Propagation;
use anyhow::{bail, Result};
use contact::ToolRun;
use eprop_io::geom::{dot, norm, scale};
use eprop_mesh::Mesh;
use eprop_partition::{LocalNumbering, Plan};
use eprop_series::vtkhdf::ToolState;
use rayon::prelude::*;

use crate::propagate::integrate::euler::SAFETY;
pub use access::WholeMesh;
pub use mesh_info::{mesh_info, MeshInfo};
pub use stop::StopToken;

/// Largest stable mechanics step of one node (semi-implicit Euler), infinite when undamped
/// and unsprung.
fn dt_bound_node(m: f64, g: f64, k: f64) -> f64 {
    if k > 0.0 {
        let direct = (-g + (g * g + 4.0 * m * k).sqrt()) / k;
        if direct.is_finite() && direct > 0.0 && 4.0 * m * k > 1e-8 * g * g {
            return direct;
        }
        // the same bound where the direct form overflows (m k huge) or cancels (m k tiny
        // against g^2): 2 sqrt(m/k) / (sqrt(1 + a^2) + a), a = g / (2 sqrt(m k))
        let a = g / (2.0 * m.sqrt() * k.sqrt());
        2.0 * (m.sqrt() / k.sqrt()) / (a.hypot(1.0) + a)
    } else if g > 0.0 {
        2.0 * m / g
    } else {
        f64::INFINITY
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

/// One simulation on this process's part of the mesh (all of it on one process).
/// Local numbering (`LocalNumbering`): owned nodes first, then halo nodes; per-node fields
/// cover both, and only owned entries are computed here (halo entries are copies from their
/// owners).
pub struct Simulation {
    /// This process's view of the scenario: its local mesh and per-node arrays in local
    /// numbering (loads keep global node indices).
    setup: Setup,
    comm: Box<dyn Comm>,
    /// The whole mesh, on the process that writes the static part of the output (rank 0).
    global: Option<Mesh>,
    /// This process's slab of the mesh on a start from the slabs: every process writes its
    /// rows of the static output.
    rows: Option<eprop_series::vtkhdf::MeshSlab>,
    n_global: usize,
    numbering: LocalNumbering,
    /// Global node index of each local node.
    gid: Vec<u64>,
    /// Output blocks of the global node order.
    blocks: BlockScatter,
    dual: Dual,
    pub(crate) prop: Propagation,
    /// The integrator of the propagation.
    stepper: Box<dyn Stepper>,
    /// nodes that move: not fixed and with a control volume
    active: Vec<bool>,
    u: NodeField<V3>,
    v: NodeField<V3>,
    force: NodeField<V3>,
    pub(crate) loads: Vec<Load>,
    /// owned contact nodes of each load (local index, probe weight, force weight, source weight)
    load_local: Vec<Vec<(u32, f64, f64, f64)>>,
    /// control volumes of this process's output block
    vol_block: Vec<f64>,
    /// The capacities C_i of the operator's rows where tissues weigh (`geometry::capacities`;
    /// None: the control volumes), the weights of the integrators' symmetric forms.
    capacity: Option<Vec<f64>>,
    /// fixed nodes of the whole mesh
    fixed_nodes: usize,
    dt: f64,
    dt_bound: f64,
    step: u64,
    time: f64,
    max_speed: f64,
    /// nodes of the whole mesh that belong to no cell
    inactive_nodes: usize,
    /// Operator applications of every step this process advanced.
    applications: Vec<u32>,
    /// Read once per step: a stop requested from outside (a signal handler, an embedding
    /// program; `set_stop`).
    stop: StopToken,
    /// The largest stop code any process's token held before the last step (0: none), agreed
    /// by every process in the step's reduction.
    stop_signal: i32,
    /// The scenario's tools (docs/tools.md).
    pub(crate) tools: Vec<ToolRun>,
    /// What kinematic tools keep between steps (None without one).
    kin: Option<kinematic::State>,
    /// Owned surface nodes that move (the tools' contact candidates; empty without tools)
    /// and a flag per owned node for them.
    surface: Vec<u32>,
    on_surface: Vec<bool>,
    /// A run to equilibrium: the steady equations' residuals after the last step, judged when
    /// its max |v| was below the tolerance (`steady.rs`).
    steady: Option<steady::Residuals>,
}

/// The operator of the scenario's scheme on this process's rows (`compact` frees the dual
/// faces before its coefficients are computed, unless `coefficients` brings them
/// (`Dual::build_compact`), and takes the pair columns over), and the
/// capacities C_i of its rows (`geometry::capacities`: the control volumes weighted by young,
/// which the integrators' symmetric forms weigh by; None, the control volumes, when no tissue
/// weighs).
fn build_operator(
    setup: &Setup,
    inc: &Incidence,
    dual: &mut Dual,
    coefficients: Option<Vec<f64>>,
    active: &[bool],
    n_rows: usize,
) -> (Operator, Option<Vec<f64>>) {
    let (mesh, r) = (&setup.mesh, &setup.materials);
    let capacity = capacities(mesh, inc, dual, r);
    let sink = setup.model.screening.map(|l| screening_sink(r, active, n_rows, l));
    let op = match setup.model.scheme() {
        Scheme::Compact => {
            dual.release_pairs(); // S_ij are not needed by compact: free them first
            let a = coefficients.unwrap_or_else(|| compact_coefficients(mesh, inc, dual, r));
            crate::diagnostics::log_memory("the coefficients");
            let col = std::mem::take(&mut dual.col);
            let cap = capacity.as_deref().unwrap_or(&dual.vol);
            let mut c = Compact::from_pairs(&dual.row_ptr[..=n_rows], col, a, cap, active);
            if let Some(s) = sink {
                c = c.with_sink(s);
            }
            if setup.model.operator_precision == Precision::Float32 {
                Operator::Compact(c.into_f32())
            } else {
                Operator::Compact(c)
            }
        }
        Scheme::Paper { correction } => {
            let faces = r.weighs_young().then(|| young_faces(mesh, inc, dual, r));
            let mut p = Paper::new(
                dual,
                &mesh.points,
                r,
                active,
                correction,
                faces.as_deref(),
                capacity.as_deref().unwrap_or(&dual.vol),
            );
            p.sink = sink;
            Operator::Paper(p)
        }
    };
    (op, capacity)
}

/// The screening sink of each row, s_i = D_i / l^2 (D_i the mean of node i's conductivity's
/// diagonal, l the screening length; docs/model.md section 3), zero on rows that do not move.
pub(crate) fn screening_sink(mat: &Materials, active: &[bool], n_rows: usize, l: f64) -> Vec<f64> {
    (0..n_rows)
        .map(|i| {
            if active[i] {
                mean_conductivity(mat, i) / (l * l)
            } else {
                0.0
            }
        })
        .collect()
}

/// D_i: the mean of the diagonal of node i's conductivity tensor.
pub(crate) fn mean_conductivity(mat: &Materials, i: usize) -> f64 {
    let r = &mat.at(i).r;
    (r[(0, 0)] + r[(1, 1)] + r[(2, 2)]) / 3.0
}

/// The mechanics step: the scenario's dt, or 0.9 of the stability bound over all nodes.
fn mechanics_dt(setup: &Setup, active: &[bool], n_owned: usize, comm: &dyn Comm) -> Result<(f64, f64)> {
    let dt_bound = comm.min(
        (0..n_owned)
            .filter(|&i| active[i])
            .map(|i| {
                let t = setup.materials.at(i);
                dt_bound_node(t.mass, t.damping, t.stiffness)
            })
            .fold(f64::INFINITY, f64::min),
    );
    let path = setup.scenario.path.display();
    let free = comm.sum_i128((0..n_owned).filter(|&i| active[i]).count() as i128);
    if free == 0 {
        // every node fixed (or in no cell): there is nothing to step, whatever dt
        bail!(
            "{path}: every node of the mesh is fixed by the [[fixed]] sets, so nothing can move{}; fix: select only the part that is held",
            crate::config::unit_note(&setup.scenario)
        )
    }
    let dt = match setup.time.dt {
        Some(dt) if dt > dt_bound => bail!(
            "{path}: [time] dt = {} is above the mechanics stability bound {dt_bound:.6e}; fix: use dt <= {:.6e} or leave dt out (automatic)",
            short(dt),
            SAFETY * dt_bound
        ),
        Some(dt) => dt,
        None if dt_bound.is_finite() => SAFETY * dt_bound,
        None => {
            // infinite: every node has k = 0 and g = 0, or its bound overflows (2 m / g with
            // m = 1e300 and g = 1e-300)
            let (k, mat) = (setup.model.stiffness(), &setup.scenario.file.material);
            let d = setup.model.reading.defaults();
            let (m, g) = (mat.mass.unwrap_or(d.mass), mat.damping.unwrap_or(d.damping));
            let damped = g > 0.0 || mat.region.iter().any(|r| r.with.damping.is_some_and(|g| g > 0.0));
            if k == 0.0 && !damped {
                bail!("{path}: with stiffness = 0 and damping = 0 no step size is stable by itself; fix: set [time] dt")
            }
            bail!(
                "{path}: the mechanics stability bound of [material] mass = {}, damping = {} and [model] stiffness = {} overflows (2 mass / damping, or 2 sqrt(mass / stiffness), is beyond 1.8e308), so no step size follows from them; fix: check their units (docs/model.md), or set [time] dt",
                short(m),
                short(g),
                short(k)
            )
        }
    };
    Ok((dt, dt_bound))
}

/// The stepper of the scenario for the mechanics step dt, on an operator whose forward Euler
/// stability bound is `h_bound` (`integrate::choose`).
/// The integrators' default accuracy with a kinematic tool (`build_stepper`).
pub(crate) const KINEMATIC_ACCURACY: f64 = 2.5e-4;

fn build_stepper(
    setup: &Setup,
    prop: &mut Propagation,
    vol: &[f64],
    active: &[bool],
    gid: &[u64],
    h_bound: f64,
    dt: f64,
    trial: Option<crate::propagate::integrate::choose::TrialRun>,
    comm: &dyn Comm,
) -> Result<Box<dyn Stepper>> {
    let path = setup.scenario.path.display().to_string();
    // a kinematic tool sets its held potential anew at every step: a jump the integrators'
    // error control meets at each step, so their default accuracy is tightened to keep them
    // within 1e-3 of euler (tests/accuracy.rs)
    let mut settings = setup.integrator.clone();
    {
        use crate::config::integrator::{DEFAULT_ACCURACY, DEFAULT_TOLERANCE};
        let kinematic = setup
            .tools
            .iter()
            .any(|t| t.law == crate::config::ContactLaw::Kinematic);
        if kinematic && settings.accuracy == DEFAULT_ACCURACY && settings.tolerance == DEFAULT_TOLERANCE {
            settings.accuracy = KINEMATIC_ACCURACY;
            settings.tolerance = DEFAULT_TOLERANCE * KINEMATIC_ACCURACY / DEFAULT_ACCURACY;
        }
    }
    // without trials (`eprop check` unless --measure) auto weighs the models alone
    let trial = trial.filter(|_| settings.trials);
    // the real-time mode: one implicit step per dt, no error control, a multigrid unless the
    // scenario names a preconditioner (`choose::realtime`)
    let realtime = setup.time.realtime();
    if realtime {
        use crate::config::integrator::{Kind, Preconditioner, DEFAULT_TOLERANCE, UNCONTROLLED_TOLERANCE};
        settings.kind = Kind::Implicit;
        settings.accuracy = f64::INFINITY;
        // a tolerance the scenario left at its default is the real-time mode's
        let t = setup.integrator.tolerance;
        if t == DEFAULT_TOLERANCE || t == UNCONTROLLED_TOLERANCE {
            settings.tolerance = crate::propagate::integrate::choose::REALTIME_TOLERANCE;
        }
        if settings.preconditioner == Preconditioner::Auto {
            settings.preconditioner = Preconditioner::Multigrid;
        }
    }
    crate::propagate::integrate::choose::build(&mut crate::propagate::integrate::choose::Context {
        settings: &settings,
        scheme: scheme_name(setup.model.scheme()),
        compact: setup.model.scheme() == Scheme::Compact,
        h_bound,
        dt,
        user_h: setup.time.h,
        path: &path,
        prop,
        vol,
        active,
        gid,
        trial,
        realtime: realtime.then_some(setup.time.realtime_solver),
        comm,
    })
}

/// The source density of a flux through a contact area (docs/model.md section 4): a contact
/// node with share `area` of the contact area and control volume `vol` takes the energy density
/// `q` in at the rate of a flux D q / l through its share, Q = (D / l) q a / V, with D the
/// conductivity along the force (`d_cond`) and l the contact's length (`length`: a patch's
/// radius). The steady potential then does not depend on D, and the total flux sum V_i Q_i
/// = (D / l) q A not on the mesh.
pub(crate) fn flux_source(d_cond: f64, length: f64, q: f64, area: f64, vol: f64) -> f64 {
    d_cond / length * q * area / vol
}

/// What the continuum reading's sources need besides the loads: this process's conductivity
/// tensors and control volumes (local numbering).
#[derive(Clone, Copy)]
struct Flux<'a> {
    r: &'a crate::config::tissue::Materials,
    vol: &'a [f64],
}

impl<'a> Flux<'a> {
    /// Some in the continuum reading.
    fn of(setup: &'a Setup, vol: &'a [f64]) -> Option<Flux<'a>> {
        (setup.model.reading == Reading::Continuum).then_some(Flux {
            r: &setup.materials,
            vol,
        })
    }
}

/// Per load: its contact area and force direction (summed over the owners of its contact
/// nodes) and the owned contact nodes with their probe, force and source weights. In the
/// continuum reading the force weight is 0 (loads push only through their source) and the
/// source weight is the node's share a_i of the contact area; a load without a patch gets the
/// length l = sqrt(A_c / pi) of its node's boundary dual area A_c (docs/model.md section 8: a
/// singular source).
#[allow(clippy::type_complexity)]
fn resolve_loads(
    setup: &Setup,
    dual: &Dual,
    numbering: &LocalNumbering,
    comm: &dyn Comm,
) -> Result<(Vec<Load>, Vec<Vec<(u32, f64, f64, f64)>>)> {
    let mut local_of = std::collections::HashMap::new();
    for i in 0..numbering.n_owned {
        local_of.insert(numbering.global[i], i as u32);
    }
    let continuum = setup.model.reading == Reading::Continuum;
    let mut loads = setup.loads.clone();
    let mut load_local = Vec::new();
    for (k, l) in loads.iter_mut().enumerate() {
        if continuum && !l.shares.is_empty() {
            // a patch: its area and direction from its shares (the same on every process)
            let an = norm(l.area_vector);
            if let Some(mag) = l.normal {
                l.force = scale(l.area_vector, -mag / an);
            }
            let mine = l
                .nodes
                .iter()
                .zip(&l.weights)
                .zip(&l.shares)
                .filter_map(|((gn, &w), &a)| local_of.get(gn).map(|&li| (li, w, 0.0, a)))
                .collect();
            load_local.push(mine);
            continue;
        }
        let mine: Vec<(u32, f64)> = l
            .nodes
            .iter()
            .zip(&l.weights)
            .filter_map(|(gn, &w)| local_of.get(gn).map(|&li| (li, w)))
            .collect();
        let mut a = [0.0; 3];
        for d in 0..3 {
            a[d] = reproducible_sum(comm, mine.iter().map(|&(li, _)| dual.area[li as usize][d]));
        }
        let an = norm(a);
        if !(an > 0.0) {
            bail!(
                "{}: load {} on node {}: the node is inside the volume (no boundary area), so no contact stress is defined; fix: load a surface node (`nearest` picks one)",
                setup.scenario.path.display(),
                k + 1,
                l.node_ids[0]
            );
        }
        l.area = an;
        if let Some(mag) = l.normal {
            l.force = scale(a, -mag / an);
        }
        if continuum {
            // one node (or a few): the flux enters through their boundary dual areas over
            // the length of a disc of the same area
            l.depth = Some((an / std::f64::consts::PI).sqrt());
            let mine = mine
                .iter()
                .map(|&(li, w)| (li, w, 0.0, norm(dual.area[li as usize])))
                .collect();
            load_local.push(mine);
            continue;
        }
        // a patch: every contact node is pressed by F (the mechanics are nodal) and the source
        // enters through the patch surface as a flux
        let source = |li: u32, w: f64| match l.depth {
            Some(depth) => norm(dual.area[li as usize]) * depth / dual.vol[li as usize],
            None => w,
        };
        let mine = mine
            .iter()
            .map(|&(li, w)| (li, w, if l.depth.is_some() { 1.0 } else { w }, source(li, w)))
            .collect();
        load_local.push(mine);
    }
    Ok((loads, load_local))
}

/// The sources of loads as applied, on the owned contact nodes: the paper's q times the
/// source weight along F/|F|, or in the continuum reading the flux of `flux_source` with q
/// from each contact node's own tissue law.
fn load_sources(
    loads: &[Load],
    load_local: &[Vec<(u32, f64, f64, f64)>],
    applied: &[Applied],
    flux: Option<Flux>,
) -> Vec<(u32, V3)> {
    let mut q = Vec::new();
    for ((mine, a), l) in load_local.iter().zip(applied).zip(loads) {
        let fn_ = norm(a.force);
        if !(fn_ > 0.0) {
            continue;
        }
        match (flux, l.depth) {
            (Some(fx), Some(length)) => {
                let d = scale(a.force, 1.0 / fn_);
                q.extend(mine.iter().map(|&(i, _, _, area)| {
                    let r = fx.r.r(i as usize);
                    let rd = r * nalgebra::Vector3::from(d);
                    let d_cond = d[0] * rd[0] + d[1] * rd[1] + d[2] * rd[2];
                    // the energy density of the contact node's own tissue law (the same bits
                    // as a.q where it is the scenario's)
                    let q = fx.r.at(i as usize).law.energy_density(a.sigma);
                    let s = flux_source(d_cond, length, q, area, fx.vol[i as usize]);
                    (i, scale(d, s))
                }));
            }
            _ => q.extend(mine.iter().map(|&(i, _, _, sw)| (i, scale(a.force, sw * a.q / fn_)))),
        }
    }
    q
}

/// The loads at time t: each one's force, contact stress sigma = |F| / A and energy density
/// q(sigma).
fn applied_at(loads: &[Load], law: &crate::config::tissue::TissueLaw, t: f64) -> Vec<Applied> {
    loads
        .iter()
        .map(|l| {
            let f = l.force_at(t);
            let sigma = norm(f) / l.area;
            Applied {
                force: f,
                q: law.energy_density(sigma),
                sigma,
            }
        })
        .collect()
}

/// The sources of the first step whose loads push or whose tools press (within the first
/// TRIAL_SEARCH steps) and of the two steps after it, as the run will make them (a tool's
/// contact source depends only on its path and the rest surface), for the automatic choice's
/// trial steps, with the run's steps from that first one (None for a run to equilibrium, whose
/// length is not known); None when nothing pushes by then, or a tool is live (its path is not
/// known in advance). The same step on every process (a reduction where tools press).
#[allow(clippy::too_many_arguments)]
fn trial_sources(
    setup: &Setup,
    loads: &[Load],
    load_local: &[Vec<(u32, f64, f64, f64)>],
    tools: &[ToolRun],
    nodes: &contact::Nodes,
    vol: &[f64],
    dt: f64,
    comm: &dyn Comm,
) -> Option<crate::propagate::integrate::choose::TrialRun> {
    const TRIAL_SEARCH: u64 = 1000;
    let applied = |k: u64| applied_at(loads, &setup.law, k as f64 * dt);
    let pushes = (0..TRIAL_SEARCH).find(|&k| applied(k).iter().any(|a| norm(a.force) > 0.0 && a.q != 0.0));
    let mut planned = Vec::new();
    let mut first = pushes;
    if !tools.is_empty() {
        // every process plans to its own first pressed step (or the search's end) and two more
        let conductivity = (setup.model.reading == Reading::Continuum).then_some(&setup.materials);
        let limit = pushes.map_or(TRIAL_SEARCH, |k| k + 1);
        let mut mine = None;
        planned = contact::planned_sources(tools, dt, limit + 2, nodes, &setup.law, conductivity, |k, q| {
            if mine.is_none() && q.iter().any(|(_, x)| x.iter().any(|&v| v != 0.0)) {
                mine = Some(k);
            }
            mine.is_some_and(|m| k >= m + 2)
        })?;
        let pressed = comm.min(mine.map_or(f64::INFINITY, |k| k as f64));
        if pressed.is_finite() {
            first = Some(first.map_or(pressed as u64, |k| k.min(pressed as u64)));
        }
    }
    let first = first?;
    let flux = Flux::of(setup, vol);
    let steps = match setup.time.stop {
        Stop::Steps(n) => Some(n),
        Stop::End(t) => Some(crate::config::steps_to(t, dt) as u64),
        Stop::Equilibrium { .. } => None,
    };
    let steps = steps.map(|n| n.saturating_sub(first));
    // no more trial steps than the run takes from the first push (a trial never outlasts
    // the run: a one-step run measures one step, which it then replays)
    let count = steps.map_or(3, |n| n.clamp(1, 3));
    Some(crate::propagate::integrate::choose::TrialRun {
        sources: (first..first + count)
            .map(|k| {
                let mut q = load_sources(loads, load_local, &applied(k), flux);
                if let Some(t) = planned.get(k as usize) {
                    q.extend_from_slice(t);
                }
                q
            })
            .collect(),
        first,
        steps,
    })
}

/// Semi-implicit Euler on the owned active nodes (docs/model.md section 5):
/// v += dt/m (f - k_e u + kappa |phi|^(p-1) phi - g v); u += dt v. Returns the largest |v|^2
/// of the nodes not flagged in `speed_elsewhere` (empty: of every node).
fn mechanics_step(
    setup: &Setup,
    dt: f64,
    phi: &[V3],
    force: &[V3],
    active: &[bool],
    speed_elsewhere: &[bool],
    u: &mut [V3],
    v: &mut [V3],
) -> f64 {
    let (mat, p) = (&setup.materials, setup.model.exponent);
    const CH: usize = 4096;
    u.par_chunks_mut(CH)
        .zip(v.par_chunks_mut(CH))
        .enumerate()
        .map(|(b, (us, vs))| {
            let mut m2 = 0.0f64;
            for (o, (u, v)) in us.iter_mut().zip(vs.iter_mut()).enumerate() {
                let i = b * CH + o;
                if !active[i] {
                    continue;
                }
                let ph = phi[i];
                let t = mat.at(i);
                let (k, kappa) = (t.stiffness, t.coupling);
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
                let (inv_m, g, f) = (1.0 / t.mass, t.damping, force[i]);
                for d in 0..3 {
                    let a = (f[d] - k * u[d] + push * ph[d] - g * v[d]) * inv_m;
                    v[d] += dt * a;
                    u[d] += dt * v[d];
                }
                if speed_elsewhere.is_empty() || !speed_elsewhere[i] {
                    m2 = m2.max(dot(*v, *v));
                }
            }
            m2
        })
        .reduce(|| 0.0, f64::max)
}

/// The geometry the tools need: the owned surface nodes and this process's rest positions,
/// boundary dual areas and control volumes.
fn nodes_of<'a>(surface: &'a [u32], active: &'a [bool], setup: &'a Setup, dual: &'a Dual) -> contact::Nodes<'a> {
    contact::Nodes {
        surface,
        active,
        points: &setup.mesh.points,
        area: &dual.area,
        vol: &dual.vol,
    }
}

/// The order of a process's nodes (`Plan::new`): reverse Cuthill-McKee on the node graph, so
/// that a row's neighbours lie within a narrow band of rows (the fused substeps of
/// `Propagation::substeps` need it; the single substep gathers better too).
pub(crate) fn locality_keys(m: &Mesh) -> Vec<u64> {
    let (xadj, adj) = eprop_partition::node_graph(m.n_nodes(), &m.offsets, &m.conn);
    eprop_partition::rcm_keys(&xadj, &adj)
}

impl Simulation {
    /// The stiffness of the compact operator on one process (`eprop check`); None for the
    /// paper scheme or a distributed simulation.
    pub fn stiffness(&self) -> Option<crate::discretize::quality::Stiffness> {
        let Operator::Compact(op) = &self.prop.op else {
            return None;
        };
        if self.comm.size() > 1 {
            return None;
        }
        // one process: the local cells are the mesh's cells in their order
        let ids = self.global.as_ref();
        Some(crate::discretize::quality::analyse(
            self.mesh(),
            op,
            self.capacities(),
            &self.setup.materials,
            &|c| ids.map(|m| m.cell_id(c)).unwrap_or(c as u64 + 1),
        ))
    }

    /// A simulation on one process (nodes reordered for locality, `locality_keys`; output in
    /// input order).
    pub fn new(setup: Setup) -> Result<Simulation> {
        let m = &setup.mesh;
        let part = vec![0u32; m.n_nodes()];
        let keys = locality_keys(m);
        let plan = Plan::new(m.n_nodes(), &m.offsets, &m.conn, &part, 0, Some(&keys));
        let local = setup.restrict(&plan);
        let Setup { mesh, .. } = setup; // the global per-node arrays go before the build
        Self::new_with(local, Box::new(Serial), Halo::serial(), plan, Some(mesh))
    }

    /// A simulation of this process's part: `setup` is its local view (`Setup::restrict`),
    /// `halo` its exchange along the plan's pattern, `global` the whole mesh on the process
    /// that writes the static output.
    pub fn new_with(
        setup: Setup,
        comm: Box<dyn Comm>,
        halo: Halo,
        plan: Plan,
        global: Option<Mesh>,
    ) -> Result<Simulation> {
        let c = comm.as_ref();
        let numbering = plan.numbering;
        let layout = numbering.layout();
        let n_owned = numbering.n_owned;
        let n_rows = n_owned; // operator rows: the owned nodes
        let gid: Vec<u64> = numbering.global.iter().map(|&g| g as u64).collect();
        let n_global = c.sum_i128(n_owned as i128) as usize;
        let inc = Incidence::new(&setup.mesh);
        crate::diagnostics::log_memory("the local mesh and plan");
        // the compact scheme's dual (no faces) and coefficients in one pass
        let (mut dual, coefficients) = if setup.model.scheme() == Scheme::Compact {
            let (d, a) = Dual::build_compact(&setup.mesh, &inc, n_rows, Some(gid.as_slice()), &setup.materials);
            (d, Some(a))
        } else {
            (Dual::build(&setup.mesh, &inc, n_rows, Some(gid.as_slice())), None)
        };
        crate::diagnostics::log_memory("the dual geometry");
        let inactive_nodes = c.sum_i128(dual.vol[..n_owned].iter().filter(|&&v| v <= 0.0).count() as i128) as usize;
        // halo nodes have no row here; only their fixedness matters
        let active: Vec<bool> = (0..layout.n_local)
            .map(|i| !setup.fixed[i] && (i >= n_rows || dual.vol[i] > 0.0))
            .collect();
        let fixed_nodes = c.sum_i128(setup.fixed[..n_owned].iter().filter(|&&b| b).count() as i128) as usize;
        let (mut op, capacity) = build_operator(&setup, &inc, &mut dual, coefficients, &active, n_rows);
        if let Operator::Compact(c) = &mut op {
            c.kernel.vector &= setup.performance.simd;
        }
        drop(inc);
        dual.release_pairs();
        dual.col = Vec::new();
        dual.row_ptr = Vec::new();
        crate::diagnostics::log_memory("the operator");
        // several processes do not fuse unless told: see `Propagation::new`
        let fuse = match setup.performance.fuse {
            Fuse::Auto if c.size() > 1 => Fuse::Fixed(1),
            f => f,
        };
        let mut prop = Propagation::new(op, halo, layout, fuse);
        tracing::info!(
            "geometry and operator built ({} rows); searching the stable substep",
            n_owned
        );
        let (dt, dt_bound) = mechanics_dt(&setup, &active, n_owned, c)?;
        let h_bound = stability::euler_bound(&mut prop, &active, &gid, c);
        let (loads, load_local) = resolve_loads(&setup, &dual, &numbering, c)?;
        let mut tools: Vec<ToolRun> = setup.tools.iter().cloned().map(ToolRun::new).collect();
        let (mut surface, mut on_surface) = (Vec::new(), Vec::new());
        if !tools.is_empty() {
            surface = contact::surface_nodes(n_owned, &active, &dual.area);
            on_surface = vec![false; n_owned];
            for &i in &surface {
                on_surface[i as usize] = true;
            }
            let nodes = nodes_of(&surface, &active, &setup, &dual);
            let rest = vec![[0.0; 3]; n_owned];
            contact::at_rest(&mut tools, 0.0, &nodes, &setup.law, &rest, c);
        }
        let kin = if tools.iter().any(|t| t.kinematic()) {
            let Some(mu) = kinematic::relaxation_rates(&prop.op, n_owned) else {
                bail!(
                    "{}: a tool's kinematic contact needs the compact scheme; fix: remove [model] scheme = \"paper\", or give the tools law = \"foundation\"",
                    setup.scenario.path.display()
                );
            };
            Some(kinematic::State {
                mu,
                lphi: vec![[0.0; 3]; n_owned],
                scratch: prop.zeros(),
                held: Vec::new(),
                lplus: vec![[0.0; 3]; n_owned],
                energy: kinematic::Energy::default(),
                after_move: None,
            })
        } else {
            None
        };
        let trial = trial_sources(
            &setup,
            &loads,
            &load_local,
            &tools,
            &nodes_of(&surface, &active, &setup, &dual),
            &dual.vol,
            dt,
            c,
        );
        let cap = capacity.as_deref().unwrap_or(&dual.vol);
        let stepper = build_stepper(&setup, &mut prop, cap, &active, &gid, h_bound, dt, trial, c)?;
        let blocks = BlockScatter::new(&gid[..n_owned], n_global, c);
        let vol_block = blocks.collect(&dual.vol, 1, c);
        Ok(Simulation {
            tools,
            kin,
            surface,
            on_surface,
            capacity,
            u: NodeField::filled(layout, [0.0; 3]),
            v: NodeField::filled(layout, [0.0; 3]),
            force: NodeField::filled(layout, [0.0; 3]),
            dual,
            prop,
            stepper,
            active,
            loads,
            load_local,
            vol_block,
            fixed_nodes,
            blocks,
            n_global,
            dt,
            dt_bound,
            step: 0,
            time: 0.0,
            max_speed: 0.0,
            inactive_nodes,
            applications: Vec::new(),
            steady: None,
            stop: StopToken::new(),
            stop_signal: 0,
            setup,
            comm,
            global,
            rows: None,
            gid,
            numbering,
        })
    }

    /// Owned nodes of this process.
    pub fn n_owned(&self) -> usize {
        self.numbering.n_owned
    }

    /// What the stepper chose: integrator, substep or stage size, count per step.
    pub fn step_plan(&self) -> &StepPlan {
        self.stepper.plan()
    }

    /// Replaces the mechanics step (and re-plans the propagation for it).
    pub fn set_dt(&mut self, dt: f64) -> Result<()> {
        let trial = trial_sources(
            &self.setup,
            &self.loads,
            &self.load_local,
            &self.tools,
            &self.tool_nodes(),
            &self.dual.vol,
            dt,
            self.comm.as_ref(),
        );
        self.stepper = build_stepper(
            &self.setup,
            &mut self.prop,
            self.capacity.as_deref().unwrap_or(&self.dual.vol),
            &self.active,
            &self.gid,
            self.stepper.plan().h_bound,
            dt,
            trial,
            self.comm.as_ref(),
        )?;
        self.dt = dt;
        Ok(())
    }

    /// The token this simulation reads once per step: a request on it (or on any clone) stops
    /// the run after the step in progress (`stop_signal`). A new simulation's token is never
    /// requested.
    pub fn set_stop(&mut self, token: StopToken) {
        self.stop = token;
    }

    /// The loads at time t.
    pub fn applied(&self, t: f64) -> Vec<Applied> {
        applied_at(&self.loads, &self.setup.law, t)
    }

    /// Nodal sources Q on the owned nodes and forces f for the loads at time t.
    pub fn sources(&mut self, t: f64) -> Vec<(u32, V3)> {
        let applied = self.applied(t);
        for (mine, a) in self.load_local.iter().zip(&applied) {
            for &(i, _, fw, _) in mine {
                self.force[i as usize] = scale(a.force, fw);
            }
        }
        let flux = Flux::of(&self.setup, &self.dual.vol);
        load_sources(&self.loads, &self.load_local, &applied, flux)
    }

    /// The geometry the tools need.
    fn tool_nodes(&self) -> contact::Nodes<'_> {
        nodes_of(&self.surface, &self.active, &self.setup, &self.dual)
    }

    /// One mechanics step: the loads and the tools at t_n give the sources and forces; the
    /// stepper advances the potential over dt; the owned nodes move, the tools at t_{n+1} keep
    /// them out of their solids and measure their contact; max |v| is reduced over every
    /// process.
    pub fn advance(&mut self) -> Result<StepStats> {
        let mut q = self.sources(self.time);
        if !self.tools.is_empty() {
            let nodes = nodes_of(&self.surface, &self.active, &self.setup, &self.dual);
            for t in &mut self.tools {
                let conductivity = (self.setup.model.reading == Reading::Continuum).then_some(&self.setup.materials);
                t.sources(self.time, &nodes, &self.setup.law, conductivity, &mut q);
            }
        }
        let n = self.numbering.n_owned;
        self.hold_potential(&mut q);
        let stats = self.stepper.advance(&mut self.prop, &q, self.comm.as_ref())?;
        let m2 = mechanics_step(
            &self.setup,
            self.dt,
            &self.prop.phi,
            &self.force,
            &self.active,
            &self.on_surface,
            &mut self.u[..n],
            &mut self.v[..n],
        );
        self.put_held();
        if !self.tools.is_empty() {
            self.keep_off_supports();
        }
        // a stop request rides on the step's reduction, so every process stops after this step
        let signal = self.stop.requested() as f64;
        if self.tools.is_empty() {
            let all = self.comm.max_each(&[m2.sqrt(), signal]);
            self.max_speed = all[0];
            self.stop_signal = all[1] as i32;
        } else {
            let t_next = (self.step + 1) as f64 * self.dt;
            let nodes = nodes_of(&self.surface, &self.active, &self.setup, &self.dual);
            let c = self.comm.as_ref();
            let (m2s, overlaps) = contact::constrain(
                &mut self.tools,
                t_next,
                self.dt,
                &nodes,
                &self.setup.law,
                &mut self.u[..n],
                &mut self.v[..n],
                c,
            );
            self.measure_kinematic(t_next);
            let c = self.comm.as_ref();
            let mut local = vec![m2.max(m2s).sqrt(), signal];
            local.extend(overlaps);
            let all = c.max_each(&local);
            self.max_speed = all[0];
            self.stop_signal = all[1] as i32;
            for (t, d) in self.tools.iter_mut().zip(&all[2..]) {
                t.state.indentation = *d;
            }
        }
        self.applications.push(stats.applications.min(u32::MAX as usize) as u32);
        self.step += 1;
        self.time = self.step as f64 * self.dt;
        self.judge_steady();
        Ok(stats)
    }

    /// The kinematic tools' holds over the step from t_n to t_{n+1}: which nodes they hold
    /// and where (`kinematic::held_nodes`); each held node's potential is set to the value
    /// that holds it there and kept there over the step (its row is frozen, and sources on
    /// it are dropped from `q`).
    fn hold_potential(&mut self, q: &mut Vec<(u32, V3)>) {
        let Some(k) = &mut self.kin else { return };
        let n = self.numbering.n_owned;
        let t_next = (self.step + 1) as f64 * self.dt;
        let now: Vec<V3> = self.tools.iter().map(|t| t.tool.path.at(self.time)).collect();
        let next: Vec<V3> = self.tools.iter().map(|t| t.tool.path.at(t_next)).collect();
        let (mat, p) = (&self.setup.materials, self.setup.model.exponent);
        let (phi, lphi, mu, u) = (&self.prop.phi, &k.lphi, &k.mu, &self.u);
        // the reaction of node i held where it is, along n
        let pulls = |i: usize, nn: V3| {
            let t = mat.at(i);
            let held = kinematic::held_potential(u[i], t.stiffness, t.coupling, p);
            let r: V3 = [0, 1, 2].map(|d| -(lphi[i][d] + mu[i] * (phi[i][d] - held[d])));
            dot(r, nn) < 0.0
        };
        k.held = kinematic::held_nodes(
            &self.tools,
            &now,
            &next,
            &self.setup.mesh.points[..n],
            &self.u[..n],
            (&self.v[..n], self.dt),
            &self.active[..n],
            pulls,
        );
        let mut rows = Vec::with_capacity(k.held.len());
        let mut before = Vec::with_capacity(k.held.len());
        let mut is_held = vec![false; n];
        let mut moved = false;
        for h in &k.held {
            let i = h.node as usize;
            let t = mat.at(i);
            before.push((h.node, self.prop.phi[i]));
            // the tool moves the node (or catches it away from where it is)
            moved |= h.target != h.before;
            self.prop.phi[i] = kinematic::held_potential(h.target, t.stiffness, t.coupling, p);
            rows.push(h.node);
            is_held[i] = true;
        }
        self.prop.set_held_moved(moved);
        // the energy of the move: L phi right after it, on the whole operator
        self.prop.thaw();
        k.scratch[..n].copy_from_slice(&self.prop.phi[..n]);
        self.prop.apply_to(&mut k.scratch, &mut k.lplus);
        let cap = self.capacity.as_deref().unwrap_or(&self.dual.vol);
        let c = self.comm.as_ref();
        let work = kinematic::step_work(mat, cap, &before, &self.prop.phi, &k.lphi, &k.lplus, c);
        let after = kinematic::stored_energy(mat, &self.active, cap, &self.prop.phi, &k.lplus, c);
        k.energy.work += work;
        // what the integration over the step takes out of S is counted at its end
        k.after_move = Some(after);
        self.prop.freeze(&rows);
        q.retain(|(i, _)| !is_held[*i as usize]);
    }

    /// Puts every owned active node whose position after the free update lies across a fixed
    /// support's plane back on the plane (docs/model.md section 6), with the velocity of that
    /// move: the support is rigid. Nothing moves where no node crossed. Runs with tools only
    /// (a run with loads alone keeps its results; its crossings are counted and warned of).
    fn keep_off_supports(&mut self) {
        let n = self.numbering.n_owned;
        let (pts, planes) = (&self.setup.mesh.points, &self.setup.supports);
        for i in 0..n {
            if !self.active[i] {
                continue;
            }
            for p in planes {
                let y = eprop_io::geom::add(pts[i], self.u[i]);
                let d = p.across(y);
                if d > p.tol {
                    for k in 0..3 {
                        self.u[i][k] -= d * p.normal[k];
                        self.v[i][k] -= d * p.normal[k] / self.dt;
                    }
                }
            }
        }
    }

    /// Puts the nodes the tools held over the step at their targets (after the free
    /// update), with the velocity of that move.
    fn put_held(&mut self) {
        let Some(k) = &self.kin else { return };
        for h in &k.held {
            let i = h.node as usize;
            self.u[i] = h.target;
            self.v[i] = [0, 1, 2].map(|d| (h.target[d] - h.before[d]) / self.dt);
        }
    }

    /// L phi at the current state, and each kinematic tool's contact and force there
    /// (`kinematic::measure`; its indentation is kept). Every process calls.
    fn measure_kinematic(&mut self, t: f64) {
        let Some(k) = &mut self.kin else { return };
        let n = self.numbering.n_owned;
        self.prop.thaw();
        k.scratch[..n].copy_from_slice(&self.prop.phi[..n]);
        self.prop.apply_to(&mut k.scratch, &mut k.lphi);
        let cap = self.capacity.as_deref().unwrap_or(&self.dual.vol);
        let stored = kinematic::stored_energy(
            &self.setup.materials,
            &self.active,
            cap,
            &self.prop.phi,
            &k.lphi,
            self.comm.as_ref(),
        );
        if let Some(after) = k.after_move.take() {
            k.energy.dissipated += after - stored;
        }
        k.energy.stored = stored;
        let nodes = nodes_of(&self.surface, &self.active, &self.setup, &self.dual);
        for run in self.tools.iter_mut().filter(|r| r.kinematic()) {
            let c = run.tool.path.at(t);
            let indentation = run.state.indentation;
            run.state = kinematic::measure(
                run,
                c,
                &nodes,
                &self.setup.materials,
                cap,
                &self.u[..n],
                &k.lphi,
                self.comm.as_ref(),
            );
            run.state.indentation = indentation;
        }
    }

    /// Number of steps the stop condition allows (equilibrium: its cap).
    pub fn max_steps(&self) -> u64 {
        match self.setup.time.stop {
            Stop::Steps(n) => n,
            Stop::End(t) => crate::config::steps_to(t, self.dt) as u64,
            Stop::Equilibrium { max_steps, .. } => max_steps,
        }
    }

    /// True when the run should stop after the current step: its count, its end, or at
    /// equilibrium max |v| and the steady equations' residuals within the tolerance.
    pub fn done(&self) -> bool {
        if self.step >= self.max_steps() {
            return true;
        }
        match self.setup.time.stop {
            Stop::Equilibrium { tol, .. } => {
                self.step > 0 && self.max_speed < tol && self.steady.is_some_and(|r| r.within(tol))
            }
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
                    d[c] = reproducible_sum(
                        self.comm.as_ref(),
                        mine.iter().map(|&(i, w, _, _)| w * self.u[i as usize][c]),
                    );
                }
                (a.force, d)
            })
            .collect()
    }

    /// Seconds per substep of the step plan's h without sources, the mean of `count` run
    /// outside any step (`eprop check`'s estimate of a run's time). The potential changes; a
    /// simulation timed so is for looking at, not for stepping on.
    pub fn time_substeps(&mut self, count: usize) -> f64 {
        let h = self.step_plan().h;
        let t = std::time::Instant::now();
        for _ in 0..count {
            self.prop.substep(h, &[]);
        }
        t.elapsed().as_secs_f64() / count.max(1) as f64
    }

    /// The kinematic tools' energy account at the end of the last step (docs/tools.md,
    /// "Energy"); None without a kinematic tool.
    pub fn tool_energy(&self) -> Option<kinematic::Energy> {
        self.kin.as_ref().map(|k| k.energy)
    }

    /// Continues the energy account of a restored run with the work and dissipation the
    /// series holds at the restart step (the stored energy is the restored state's).
    pub fn resume_energy(&mut self, work: f64, dissipated: f64) {
        if let Some(k) = &mut self.kin {
            k.energy.work = work;
            k.energy.dissipated = dissipated;
        }
    }

    /// Each tool's state at the end of the last step (at rest before the first).
    pub fn tool_states(&self) -> Vec<ToolState> {
        self.tools.iter().map(|t| t.state).collect()
    }

    /// Recomputes the tools' state before the first step at the current time (after their
    /// paths changed, as `serve` does for live tools); every process calls.
    pub fn tools_at_rest(&mut self) {
        let nodes = nodes_of(&self.surface, &self.active, &self.setup, &self.dual);
        let n = self.numbering.n_owned;
        contact::at_rest(
            &mut self.tools,
            self.time,
            &nodes,
            &self.setup.law,
            &self.u[..n],
            self.comm.as_ref(),
        );
        self.measure_kinematic(self.time);
    }

    /// The largest spacing of the surface nodes within `reach` of any of `points` (rest
    /// positions), estimated from their boundary dual areas (a node of a regular triangulation
    /// of spacing h has a dual area of about 0.87 h^2), over every process; None when there are
    /// none (every process calls: a reduction).
    pub fn surface_spacing_near(&self, points: &[V3], reach: f64) -> Option<f64> {
        let pts = &self.setup.mesh.points;
        let largest = self
            .surface
            .iter()
            .map(|&i| i as usize)
            .filter(|&i| points.iter().any(|p| norm(eprop_io::geom::sub(pts[i], *p)) <= reach))
            .map(|i| norm(self.dual.area[i]))
            .fold(-1.0f64, f64::max);
        let largest = self.comm.max(largest);
        (largest >= 0.0).then(|| (largest / 0.87).sqrt())
    }

    /// How deep the rest-frame point `p` lies inside the organ: its distance to the nearest
    /// surface node that moves, when p is on the inner side of that node's boundary dual area
    /// (A_i . (p - X_i) < 0); None outside or without such nodes (every process calls: two
    /// reductions).
    pub fn depth_inside(&self, p: V3) -> Option<f64> {
        let pts = &self.setup.mesh.points;
        let (mut best, mut inside) = (f64::INFINITY, false);
        for &i in &self.surface {
            let w = eprop_io::geom::sub(p, pts[i as usize]);
            let d = norm(w);
            if d < best {
                (best, inside) = (d, dot(w, self.dual.area[i as usize]) < 0.0);
            }
        }
        let d = self.comm.min(best);
        let flag = self.comm.max(f64::from(u8::from(inside && best == d)));
        (d.is_finite() && flag > 0.0).then_some(d)
    }

    /// Tool k's state at each of the increasing `times` (from the run's start) as a run
    /// stepping through them would measure it, with the current displacement; nothing of the
    /// run changes (`contact::survey`; every process calls).
    pub fn tool_survey(&self, k: usize, times: &[f64]) -> Vec<ToolState> {
        let n = self.numbering.n_owned;
        contact::survey(
            &self.tools[k],
            times,
            &self.tool_nodes(),
            &self.setup.law,
            &self.u[..n],
            self.comm.as_ref(),
        )
    }

    /// Sum of V_i |phi_i| over the mesh (exact sum).
    pub fn total_energy(&self) -> f64 {
        let n = self.numbering.n_owned;
        reproducible_sum(
            self.comm.as_ref(),
            self.dual.vol[..n]
                .iter()
                .zip(&self.prop.phi[..n])
                .map(|(v, p)| v * norm(*p)),
        )
    }

    /// Largest |u| and the global index of its node (ties: the lowest index).
    pub fn max_displacement(&self) -> (f64, u64) {
        let n = self.numbering.n_owned;
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
        let n = self.numbering.n_owned;
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
        if !self.tools.is_empty() {
            let nodes = nodes_of(&self.surface, &self.active, &self.setup, &self.dual);
            contact::resume(&mut self.tools, step, self.dt, &nodes, &self.setup.law, &self.u[..n], c);
            self.measure_kinematic(self.time);
        }
    }

    /// Local index of a global node owned here.
    pub fn local(&self, global: u32) -> Option<usize> {
        self.gid[..self.numbering.n_owned]
            .iter()
            .position(|&g| g == global as u64)
    }

    /// This process's output block of a per-node array (global node order), flattened.
    pub fn in_output_order(&self, x: &[V3]) -> Vec<f64> {
        self.blocks
            .collect(x[..self.numbering.n_owned].as_flattened(), 3, self.comm.as_ref())
    }

    /// The local mesh this process computes on.
    pub fn mesh(&self) -> &Mesh {
        &self.setup.mesh
    }
}

/// The scenario key's word for a scheme (`[model] scheme`).
pub fn scheme_name(s: Scheme) -> &'static str {
    match s {
        Scheme::Compact => "compact",
        Scheme::Paper { correction: true } => "paper (corrected)",
        Scheme::Paper { correction: false } => "paper (uncorrected)",
    }
}
