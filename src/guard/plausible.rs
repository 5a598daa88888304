//! Warnings about results that are computed correctly but mean little: a source far outside
//! the tissue law's range (often a units mistake; for loads and tools), a contact area too
//! small for its mesh, a tool that never reaches the organ, a
//! `nearest` point far from the node it picks, and displacements past small-deformation
//! validity. None of them changes a number. And the checks that stop a run whose state is no
//! longer finite, or whose tool leaves the range where its contact is computed.

use eprop::config::{Reading, CONTINUUM};
use eprop::diagnostics::{fixed, short};
use eprop::simulate::{Simulation, WholeMesh};
use eprop_io::geom::{norm, sub};

/// max |u| above this fraction of the mesh's bounding-box diagonal is warned about once (the
/// model is a small-deformation one).
pub const U_FRACTION: f64 = 0.1;
/// A `nearest` node farther than this fraction of the diagonal from its point is warned about.
pub const NEAREST_FRACTION: f64 = 0.05;
/// A contact area below this fraction of the squared diagonal is warned about.
pub const AREA_FRACTION: f64 = 1e-6;
/// The tissue law is meant for contact stresses sigma up to this multiple of `young`.
pub const STRESS_RATIO: f64 = 1.0;

fn diagonal(mesh: &WholeMesh) -> f64 {
    let (lo, hi) = mesh.bounds;
    norm(sub(hi, lo))
}

/// The largest ramp scale of a load (1 without a ramp).
fn peak_scale(ramp: &Option<Vec<[f64; 2]>>) -> f64 {
    ramp.as_ref()
        .map(|r| r.iter().fold(0.0f64, |m, p| m.max(p[1].abs())))
        .unwrap_or(1.0)
}

/// The hint added to a load's or tool's warning when a small mesh may be in metres: the paper
/// reading takes coordinates as they are (the continuum reading knows its unit, and
/// `scale_warnings` judges its size).
fn metres_hint(sim: &Simulation, diag: f64) -> String {
    let ms = &sim.setup().scenario.file.mesh;
    let paper = sim.setup().model.reading == Reading::Paper;
    if paper && diag < 2.0 && ms.scale.is_none() && ms.unit.is_none() {
        format!("; the mesh spans {diag:.3} units: if it is in metres, `[mesh] scale = 1000` reads it in millimetres")
    } else {
        String::new()
    }
}

/// The nodes of the whole mesh `load_warnings` looks at (`Simulation::whole_mesh`): the
/// first node of each load (global indices).
pub fn load_nodes(sim: &Simulation) -> Vec<usize> {
    sim.loads()
        .iter()
        .filter_map(|l| l.nodes.first().map(|&n| n as usize))
        .collect()
}

/// Warnings about the loads of a simulation on its whole mesh (rank 0's view of it, with the
/// nodes of `load_nodes`).
pub fn load_warnings(sim: &Simulation, mesh: &WholeMesh) -> Vec<String> {
    let mut out = Vec::new();
    let diag = diagonal(mesh);
    let young = sim.setup().law.young;
    let metres = metres_hint(sim, diag);
    let entries = &sim.setup().scenario.file.load;
    for (k, l) in sim.loads().iter().enumerate() {
        let f = norm(l.force) * peak_scale(&l.ramp);
        let sigma = f / l.area;
        if sigma / young > STRESS_RATIO {
            out.push(format!(
                "load {}: its contact stress sigma = |F| / A = {f:.4e} / {:.4e} = {sigma:.4e} is {:.3e} times [tissue] young = {}, far outside the tissue law's range (sigma/young up to {STRESS_RATIO}): the source and the displacements will be far too large; fix: check the force, young and the units{metres}",
                k + 1,
                l.area,
                sigma / young,
                short(young)
            ));
        }
        if l.area < AREA_FRACTION * diag * diag {
            out.push(format!(
                "load {}: its contact area {:.4e} is below {AREA_FRACTION:e} of the squared extent of the mesh ({:.4e}): the stress on it is concentrated on a speck; fix: a `patch = {{ center, radius }}` spreads the load{metres}",
                k + 1,
                l.area,
                diag * diag
            ));
        }
        if let Some(eprop::config::Selector::Nearest(p)) = entries.get(k).map(|e| e.selector.get_ref()) {
            let node = l.nodes[0] as usize;
            let x = mesh.node(node).1;
            let d = eprop::config::distance(x, p.0);
            if d > NEAREST_FRACTION * diag {
                out.push(format!(
                    "load {}: `nearest = [{}, {}, {}]` picks node {} at ({}, {}, {}), {d:.4e} away from the point ({:.1} % of the mesh's diagonal {diag:.4e}); fix: give a point on the surface of the mesh",
                    k + 1,
                    short(p.0[0]),
                    short(p.0[1]),
                    short(p.0[2]),
                    l.node_ids[0],
                    fixed(x[0], 4),
                    fixed(x[1], 4),
                    fixed(x[2], 4),
                    100.0 * d / diag
                ));
            }
        }
    }
    out.extend(scale_warnings(sim, mesh));
    out
}

/// The continuum reading's length, time and stress scales are warned about when they lie
/// more than this factor from the defaults' (a liver-like organ, docs/model.md).
pub const SCALE_FACTOR: f64 = 1e3;
/// The organ sizes (bounding-box diagonal, m) the continuum defaults are meant for, within
/// the warning's range is ten times wider on either side.
pub const ORGAN_DIAGONAL: (f64, f64) = (0.02, 0.5);

/// The slowest decay time of m u'' + g u' + k u = 0 (infinite when k = 0 or g = 0).
pub fn relaxation_time(m: f64, g: f64, k: f64) -> f64 {
    if !(k > 0.0) || !(g > 0.0) {
        return f64::INFINITY;
    }
    let disc = g * g - 4.0 * m * k;
    let rate = if disc <= 0.0 {
        g / (2.0 * m)
    } else {
        // the slow root, in the form that does not cancel: 2k / (g + sqrt(disc))
        2.0 * k / (g + disc.sqrt())
    };
    1.0 / rate
}

/// Warnings of the continuum reading about scales far from its defaults' (docs/model.md,
/// "Defaults"): the mesh's extent (a unit mistake: a mesh in mm read as metres spans 180 m),
/// the mechanics' relaxation time, the time the energy takes to cross the mesh, and the
/// stiffness of the tissue law. None in the paper reading (no units).
pub fn scale_warnings(sim: &Simulation, mesh: &WholeMesh) -> Vec<String> {
    let mut out = Vec::new();
    let st = sim.setup();
    if st.model.reading != Reading::Continuum {
        return out;
    }
    let d = CONTINUUM;
    let far = |x: f64, reference: f64| !(x / reference <= SCALE_FACTOR && reference / x <= SCALE_FACTOR);
    let diag = diagonal(mesh);
    let ms = &st.scenario.file.mesh;
    let read_as = match (ms.unit, ms.scale) {
        (Some(u), _) => format!("[mesh] unit = \"{}\"", u.name()),
        (None, Some(s)) => format!("[mesh] scale = {}", short(s)),
        _ => "[mesh]".into(),
    };
    if !(ORGAN_DIAGONAL.0 / 10.0..=ORGAN_DIAGONAL.1 * 10.0).contains(&diag) {
        out.push(format!(
            "the mesh spans {diag:.4e} m (its bounding-box diagonal, read with {read_as}), far from the organs of 2 to 50 cm the continuum defaults are made for; fix: check [mesh] unit (the unit of the file's coordinates: \"mm\" when a 20 cm organ's coordinates run to 200)"
        ));
    }
    let mat = &st.scenario.file.material;
    let (m, g, k) = (
        mat.mass.unwrap_or(d.mass),
        mat.damping.unwrap_or(d.damping),
        st.model.stiffness(),
    );
    let tau = relaxation_time(m, g, k);
    let tau0 = relaxation_time(d.mass, d.damping, d.stiffness);
    if tau.is_finite() && far(tau, tau0) {
        out.push(format!(
            "the mechanics relax in {tau:.4e} s (density {}, damping {}, stiffness {}), far from the {tau0:.3} s of the liver-like defaults (kg/m^3, kg/(m^3 s), N/m^4); fix: check the units of [material] mass and damping and [model] stiffness (docs/model.md), or leave them out",
            short(m),
            short(g),
            short(k)
        ));
    }
    if let Some(t) = st.materials.tissues.first() {
        let cond = t.r.trace() / 3.0;
        let (t, t0) = (diag * diag / cond, diag * diag / d.conductivity);
        if far(t, t0) {
            out.push(format!(
                "the energy crosses the mesh in {t:.4e} s (diagonal^2 / conductivity = {:.4e}^2 / {}), {:.1e} times the {t0:.4e} s of the default conductivity {} m^2/s; fix: check the units of [material] conductivity (m^2/s), or leave it out",
                diag,
                short(cond),
                t / t0,
                short(d.conductivity)
            ));
        }
    }
    if far(st.law.young, d.young) {
        out.push(format!(
            "[tissue] young = {} Pa is far from soft tissue's kPa (the default {} Pa); fix: young in Pa (4 kPa is 4000), or leave it out",
            short(st.law.young),
            short(d.young)
        ));
    }
    out
}

/// At most this many instants of a tool's path are looked at by `tool_warnings`.
const TOOL_SAMPLES: usize = 1000;

/// How deep a sphere tool's centre at `at` lies inside the organ when that is deeper than its
/// radius (None for other shapes, outside, or shallower; every process calls): the case where
/// the surface behind it counts as pressed by up to that depth once it moves.
pub(crate) fn sphere_deep_inside(sim: &Simulation, tool: &eprop::config::Tool, at: [f64; 3]) -> Option<f64> {
    let eprop::config::Shape::Sphere { radius } = tool.shape else {
        return None;
    };
    sim.depth_inside(at).filter(|&d| d > radius)
}

/// Warnings about the tools of a simulation, as for loads (`load_warnings`): a contact
/// pressure past the tissue law's range at the deepest point of the path, a tool too small for
/// the mesh, a tool that never reaches the organ; each with the hint about a mesh in metres.
/// Live tools (moved by a client) are not looked at. Every process calls (reductions).
pub fn tool_warnings(sim: &Simulation) -> Vec<String> {
    let mut out = Vec::new();
    if sim.tools().is_empty() {
        return out;
    }
    let (lo, hi) = sim.mesh().bounds();
    let m = sim.comm().max_each(&[hi[0], hi[1], hi[2], -lo[0], -lo[1], -lo[2]]);
    let diag = norm([m[0] + m[3], m[1] + m[4], m[2] + m[5]]);
    let young = sim.setup().law.young;
    let metres = metres_hint(sim, diag);
    let end = sim.max_steps() as f64 * sim.dt();
    for (k, run) in sim.tools().iter().enumerate() {
        let tool = &run.tool;
        let radius = tool.shape.radius();
        if std::f64::consts::PI * radius * radius < AREA_FRACTION * diag * diag {
            out.push(format!(
                "tool {}: its radius {} gives it an area below {AREA_FRACTION:e} of the squared extent of the mesh ({:.4e}): it presses a speck, between nodes; fix: check the radius and the units{metres}",
                k + 1,
                short(radius),
                diag * diag
            ));
        }
        if tool.live {
            continue;
        }
        // a sphere whose centre starts inside the organ, deeper than its radius: it touches
        // no surface node, yet the overlaps are measured along its direction of motion, so the
        // surface behind it counts as pressed from the first step
        if let Some(depth) = sphere_deep_inside(sim, tool, tool.path.at(0.0)) {
            out.push(format!(
                "tool {}: its centre starts inside the organ, {depth:.4e} from the nearest surface node, deeper than its radius {}: the contact measures each surface node's overlap against the rest surface along the tool's direction of motion, so once it moves the surface behind it counts as pressed by up to that depth, a large foundation force and source from step 0 (at rest it touches nothing and does nothing); fix: start it outside the organ, at the surface it should press (`start`, or the first row of its path table){metres}",
                k + 1,
                short(radius)
            ));
            continue;
        }
        let mut times = vec![0.0];
        if let eprop::config::Trajectory::Table(h) = &tool.path {
            let rows: Vec<f64> = h.rows().iter().map(|r| r[0]).filter(|&t| t > 0.0 && t < end).collect();
            let stride = rows.len().div_ceil(TOOL_SAMPLES).max(1);
            times.extend(rows.iter().step_by(stride));
        }
        if end > 0.0 {
            times.push(end);
        }
        let states = sim.tool_survey(k, &times);
        let (deepest, at) = states
            .iter()
            .zip(&times)
            .map(|(s, &t)| (s.indentation, t))
            .fold((f64::NEG_INFINITY, 0.0), |a, b| if b.0 > a.0 { b } else { a });
        if !(deepest > 0.0) {
            let gap = if deepest.is_finite() {
                format!("it stays {:.4e} away from it", -deepest)
            } else {
                "its path misses it".into()
            };
            out.push(format!(
                "tool {}: it never reaches the organ's surface by t = {end:.4e} ({gap}); fix: check its start, velocity or path table and the units{metres}",
                k + 1,
            ));
            continue;
        }
        // the contact is found at surface nodes: a tool narrower than their spacing can pass
        // between them (into the organ, to press its far side from inside)
        const PLACES: usize = 64;
        let places: Vec<_> = (0..=PLACES)
            .map(|j| tool.path.at(at * j as f64 / PLACES as f64))
            .collect();
        if let Some(spacing) = sim.surface_spacing_near(&places, 2.0 * radius) {
            if radius < spacing {
                out.push(format!(
                    "tool {}: its radius {} is below the spacing of the surface nodes along its path (up to {spacing:.3e}, from their boundary dual areas): the contact is found at nodes, so the tool can pass between them into the organ and press its far side from inside; fix: a surface mesh finer than the radius there (tetgen -a, gmsh's mesh size) or a larger radius{metres}",
                    k + 1,
                    short(radius),
                ));
            }
        }
        // the foundation law's pressure (a kinematic tool's contact has none to check: it
        // puts the tissue where it is and the force follows)
        let h = tool.foundation;
        let p = eprop::simulate::contact::pressure(&sim.setup().law, deepest, h);
        if tool.law == eprop::config::ContactLaw::Foundation && p / young > STRESS_RATIO {
            out.push(format!(
                "tool {}: at t = {at:.4e} it is {deepest:.4e} deep in the rest surface, a contact strain of {:.3e} on its foundation {}: the contact pressure {p:.4e} is {:.3e} times [tissue] young = {}, far outside the tissue law's range (up to {STRESS_RATIO}): the source and the displacements will be far too large; fix: check the path, `foundation`, young and the units{metres}",
                k + 1,
                deepest / h,
                short(h),
                p / young,
                short(young)
            ));
        }
    }
    out
}

/// Refuses a tool whose straight path (`start` + t `velocity`) leaves `config::tools::REACH`
/// before the run's last step (tables are bounded row by row when they are read, and a live
/// tool's samples as they arrive). The same verdict on every process.
pub fn tool_reach(sim: &Simulation) -> Result<(), String> {
    use eprop::config::{REACH, REACH_WHY};
    let end = sim.max_steps() as f64 * sim.dt();
    for (k, run) in sim.tools().iter().enumerate() {
        if let eprop::config::Trajectory::Linear { .. } = run.tool.path {
            let far = run.tool.path.at(end);
            if far.iter().any(|x| !(x.abs() <= REACH)) {
                return Err(format!(
                    "{}: tool {}'s path `start` + t `velocity` is at ({}, {}, {}) by the last step's time t = {}, beyond +-{}, {REACH_WHY}; fix: a smaller velocity, fewer steps, or a path table that holds the tool still",
                    sim.setup().scenario.path.display(),
                    k + 1,
                    short(far[0]),
                    short(far[1]),
                    short(far[2]),
                    short(end),
                    short(REACH)
                ));
            }
        }
    }
    Ok(())
}

/// The likely cause of a state that is no longer finite, for the message that stops the run.
pub fn nonfinite_cause(sim: &Simulation) -> String {
    for (k, s) in sim.tool_states().iter().enumerate() {
        if !(norm(s.position).is_finite() && norm(s.force).is_finite()) {
            return format!(
                "tool {}'s position ({}, {}, {}) or force ({}, {}, {}) is not finite; fix: check its path",
                k + 1,
                short(s.position[0]),
                short(s.position[1]),
                short(s.position[2]),
                short(s.force[0]),
                short(s.force[1]),
                short(s.force[2])
            );
        }
    }
    for (k, (l, a)) in sim.loads().iter().zip(sim.applied(sim.time())).enumerate() {
        let peak = sim
            .setup()
            .law
            .energy_density(norm(l.force) * peak_scale(&l.ramp) / l.area);
        if !a.q.is_finite() || !peak.is_finite() || a.sigma / sim.setup().law.young > STRESS_RATIO {
            return format!(
                "load {}'s contact stress sigma = {:.4e} gives the energy density q = {:.4e} (sigma/young = {:.3e}): the source is far outside the tissue law's range; fix: check the force, [tissue] young and the mesh's units ([mesh] scale)",
                k + 1,
                a.sigma,
                a.q,
                a.sigma / sim.setup().law.young
            );
        }
    }
    // the coupling's push kappa q^p past the range whose squares (the norms written) are finite
    let model = &sim.setup().model;
    let (kappa, p) = (model.coupling(), model.exponent);
    for (k, a) in sim.applied(sim.time()).iter().enumerate() {
        let push = kappa * a.q.powf(p);
        if !(push < 1e150) {
            return format!(
                "[model] coupling = {}{} times load {}'s energy density q = {:.4e} pushes with {:.4e}: the displacements' squares overflow; fix: a coupling near the reading's default ({})",
                short(kappa),
                if p == 1.0 { String::new() } else { format!(" (exponent {})", short(p)) },
                k + 1,
                a.q,
                push,
                short(model.reading.defaults().coupling)
            );
        }
    }
    "the potential or the motion grew without bound; fix: check the warnings of `eprop check`, and lower [model] coupling or exponent, or [time] dt".into()
}

/// What the watch saw at an output step.
pub enum Look {
    /// Every value finite; a warning the first time max |u| passes its limit.
    Finite(Option<String>),
    /// Some process holds a NaN or an infinity in u, v, phi, |phi|, a probe or a tool's
    /// position or force.
    NonFinite,
}

/// Watches the state of a run at its output steps, on every process alike (one reduction).
pub struct Watch {
    diag: f64,
    warned: bool,
}

impl Watch {
    /// Every process calls (the bounding box is reduced).
    pub fn new(sim: &Simulation) -> Watch {
        let (lo, hi) = sim.mesh().bounds();
        let m = sim.comm().max_each(&[hi[0], hi[1], hi[2], -lo[0], -lo[1], -lo[2]]);
        let diag = norm([m[0] + m[3], m[1] + m[4], m[2] + m[5]]);
        Watch { diag, warned: false }
    }

    /// Looks at u, v, phi and |phi| of the owned nodes, the probes and the tools (every
    /// process calls).
    pub fn look(&mut self, sim: &Simulation) -> Look {
        let n = sim.n_owned();
        // every written field: u, v, phi, the energy |phi|, and the probes' displacements; a
        // finite norm implies finite components, and the norm of a component near f64::MAX
        // overflows (the energy written would be inf)
        let finite = |x: &[[f64; 3]]| x.iter().all(|p| norm(*p).is_finite());
        let probes = sim
            .probes()
            .iter()
            .all(|(f, d)| norm(*f).is_finite() && norm(*d).is_finite());
        let tools = sim
            .tool_states()
            .iter()
            .all(|s| norm(s.position).is_finite() && norm(s.force).is_finite());
        let bad = !(finite(&sim.u()[..n]) && finite(&sim.v()[..n]) && finite(&sim.phi()[..n]) && probes && tools);
        let umax = sim.u()[..n].iter().map(|p| norm(*p)).fold(0.0f64, f64::max);
        let all = sim.comm().max_each(&[f64::from(u8::from(bad)), umax]);
        if all[0] > 0.0 {
            return Look::NonFinite;
        }
        let umax = all[1];
        if self.warned || !(umax > U_FRACTION * self.diag) {
            return Look::Finite(None);
        }
        self.warned = true;
        // the cause that applies: a prescribed tool path (its depth), else the loads
        let pressing: Vec<String> = sim
            .tools()
            .iter()
            .enumerate()
            .filter(|(_, t)| t.state.indentation > 0.0)
            .map(|(k, t)| format!("tool {} is {:.4e} deep", k + 1, t.state.indentation))
            .collect();
        let fix = if pressing.is_empty() {
            "fix: a smaller force, or check [tissue] young and the units".to_string()
        } else {
            format!(
                "cause: the tools' prescribed paths ({}); fix: a shallower path, or check the path's units",
                pressing.join(", ")
            )
        };
        Look::Finite(Some(format!(
            "max |u| = {umax:.4e} at step {} (t = {:.6e}) passed {} % of the mesh's diagonal {:.4e}: the small-deformation model is no longer valid there; {fix}",
            sim.step(),
            sim.time(),
            100.0 * U_FRACTION,
            self.diag
        )))
    }
}
