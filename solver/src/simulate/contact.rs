//! Tools at run time (docs/tools.md has the equations): an elastic-foundation (Winkler)
//! contact. The pressure on a surface node is the tissue law's stress at the strain of the
//! tool's overlap with the node's REST position, p_i = sigma(delta_i / h); the tool's force is
//! F = -sum_i p_i A_i over the surface nodes (A_i the outward boundary dual area vector), summed
//! exactly so every process agrees, and each pressed node gets an energy source along its
//! inward normal (`contact_source`). The force is a continuous function of the tool's position
//! and does not depend on the displacement, so every integrator and process count gives the
//! same bits. Nodes whose deformed position enters the tool are still moved onto its surface,
//! so nothing penetrates; that projection does not feed the force or the source.
//!
//! Per node everything depends only on the node's own rest geometry (and, for the projection,
//! its own state) and the tool's position, so the contact set, the pressures and their sums
//! are the same on any number of processes.

use crate::config::tissue::TissueLaw;
use crate::config::{ContactLaw, Shape, Tool, Trajectory};
use crate::distribute::comm::{reproducible_sums, Comm};
use crate::linalg::V3;
use eprop_io::geom::{dot, norm, scale, sub};
use eprop_series::vtkhdf::ToolState;

/// Below this contact strain (delta / h) the pressure rises quadratically, so that a node's
/// pressure, and the force, are continuously differentiable in the tool position when the node
/// is first touched (`contact_strain`).
pub const SMOOTH_STRAIN: f64 = 0.01;

/// How far a point is inside a tool at `c`: > 0 inside (its depth), <= 0 outside; -inf beside
/// a punch's face.
pub fn depth(shape: &Shape, c: V3, x: V3) -> f64 {
    match *shape {
        Shape::Sphere { radius } => radius - norm(sub(x, c)),
        Shape::Punch { radius, normal } => {
            let d = sub(x, c);
            let s = dot(d, normal);
            if norm(sub(d, scale(normal, s))) <= radius {
                -s
            } else {
                f64::NEG_INFINITY
            }
        }
    }
}

/// The overlap of the tool at `c` with a rest point x, along the tool's direction of motion
/// `dir` (unit): how far the tool must move back along `dir` until x is no longer inside it
/// (> 0: x is inside or behind it; < 0: the distance the tool must still travel to reach x;
/// -inf: its path misses x). For a sphere, the largest s with |x - (c - s dir)| = R; without
/// a direction (a tool that has not moved yet), its radial depth R - |x - c|. For a punch, the
/// face's offset past x along its normal (`depth`), whatever the path.
pub fn overlap(shape: &Shape, c: V3, dir: Option<V3>, x: V3) -> f64 {
    match (*shape, dir) {
        (Shape::Sphere { radius }, Some(d)) => {
            let w = sub(x, c);
            let b = dot(w, d);
            let perp = norm(sub(w, scale(d, b)));
            if perp > radius {
                f64::NEG_INFINITY
            } else {
                // (radius - perp)(radius + perp): no cancellation near the rim
                ((radius - perp) * (radius + perp)).sqrt() - b
            }
        }
        _ => depth(shape, c, x),
    }
}

/// The point of the tool's surface a point inside it is pushed to (along the surface
/// normal): the nearest point of the sphere, the point of the punch's face in front of it.
pub fn project(shape: &Shape, c: V3, x: V3) -> V3 {
    match *shape {
        Shape::Sphere { radius } => {
            let d = sub(x, c);
            let r = norm(d);
            [
                c[0] + d[0] * (radius / r),
                c[1] + d[1] * (radius / r),
                c[2] + d[2] * (radius / r),
            ]
        }
        Shape::Punch { normal, .. } => {
            let s = dot(sub(x, c), normal);
            [x[0] - s * normal[0], x[1] - s * normal[1], x[2] - s * normal[2]]
        }
    }
}

/// The contact strain of an overlap strain e = delta / h, regularised below SMOOTH_STRAIN = e0:
/// e^2 / (2 e0) for 0 < e < e0, e - e0/2 above (value and slope continuous), 0 for e <= 0.
pub fn contact_strain(e: f64) -> f64 {
    const E0: f64 = SMOOTH_STRAIN;
    if !(e > 0.0) {
        0.0
    } else if e < E0 {
        e * e / (2.0 * E0)
    } else {
        e - 0.5 * E0
    }
}

/// The elastic foundation: the contact pressure of a rest overlap delta on a foundation of
/// depth h, the tissue law's stress at the regularised strain (0 without overlap).
pub fn pressure(law: &TissueLaw, delta: f64, h: f64) -> f64 {
    law.stress(contact_strain(delta / h))
}

/// The magnitude of a pressed node's energy source, |Q_i|, from the energy density q = q(p_i)
/// of its pressure, its boundary dual area |A_i|, its control volume V_i and the tool's length
/// scale (its radius): in the paper's per-node reading q |A_i| length / V_i, as a patch load of
/// that radius puts it in; in the continuum reading (`d_cond`: the node's conductivity along
/// the pressing direction) the flux of a patch load, (D / length) q |A_i| / V_i
/// (`super::flux_source`).
pub fn contact_source(q: f64, area: f64, vol: f64, length: f64, d_cond: Option<f64>) -> f64 {
    match d_cond {
        Some(d) => super::flux_source(d, length, q, area, vol),
        None => q * area * length / vol,
    }
}

/// A unit vector along v, None for a zero vector (scaled by its largest component first, so
/// a vector of 1e300 is a direction, not inf).
fn unit(v: V3) -> Option<V3> {
    let m = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if !(m > 0.0 && m.is_finite()) {
        return None;
    }
    let d = scale(v, 1.0 / m);
    Some(scale(d, 1.0 / norm(d)))
}

/// One tool of a running simulation.
#[derive(Clone)]
pub struct ToolRun {
    pub tool: Tool,
    /// The state at the end of the last step.
    pub state: ToolState,
    /// Where the tool was when the run started (`at_rest`), and the position farthest from it
    /// it has been at, at a step's time: they give a path's direction of motion.
    origin: V3,
    reach: V3,
    reach_distance: f64,
}

/// The per-node geometry the tools need (this process's local arrays).
pub struct Nodes<'a> {
    /// Owned surface nodes that move (local indices): the candidates for contact.
    pub surface: &'a [u32],
    /// Which nodes move (owned first): every one is kept out of the tools.
    pub active: &'a [bool],
    pub points: &'a [V3],
    /// Outward boundary dual area vectors A_i.
    pub area: &'a [V3],
    pub vol: &'a [f64],
}

impl ToolRun {
    pub fn new(tool: Tool) -> ToolRun {
        ToolRun {
            tool,
            state: ToolState::default(),
            origin: [0.0; 3],
            reach: [0.0; 3],
            reach_distance: 0.0,
        }
    }

    /// Whether the tool follows the kinematic law (`super::kinematic`).
    pub fn kinematic(&self) -> bool {
        self.tool.law == ContactLaw::Kinematic
    }

    /// The indentation of the tool at `c` on this process's surface nodes (`ToolState`).
    fn indentation(&self, c: V3, n: &Nodes) -> f64 {
        let dir = self.direction();
        n.surface
            .iter()
            .map(|&i| overlap(&self.tool.shape, c, dir, n.points[i as usize]))
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// Restarts the record of the path at the tool's position `c`.
    fn start_at(&mut self, c: V3) {
        (self.origin, self.reach, self.reach_distance) = (c, c, 0.0);
    }

    /// Records the tool at position `c` (a step's time).
    fn observe(&mut self, c: V3) {
        let d = norm(sub(c, self.origin));
        if d > self.reach_distance {
            (self.reach, self.reach_distance) = (c, d);
        }
    }

    /// The tool's direction of motion: a straight path's velocity; for a path table or a live
    /// tool, from where it was at the start of the run to the farthest point from there it has
    /// reached at a step's time (so a press, a hold and a withdrawal along one line keep the
    /// pressing direction); None while it has not moved.
    pub fn direction(&self) -> Option<V3> {
        if let Trajectory::Linear { velocity, .. } = self.tool.path {
            if let Some(d) = unit(velocity) {
                return Some(d);
            }
        }
        if self.reach_distance > 0.0 {
            unit(sub(self.reach, self.origin))
        } else {
            None
        }
    }

    /// The pressures p_i > 0 of this process's surface nodes with the tool at `c`, and the
    /// largest overlap of a surface node (this process's part of the indentation).
    fn pressures(&self, c: V3, n: &Nodes, law: &TissueLaw) -> (Vec<(u32, f64)>, f64) {
        let (shape, h) = (self.tool.shape, self.tool.foundation);
        let dir = self.direction();
        let mut most = f64::NEG_INFINITY;
        let mut pressed = Vec::new();
        for &i in n.surface {
            let d = overlap(&shape, c, dir, n.points[i as usize]);
            most = most.max(d);
            let p = pressure(law, d, h);
            if p > 0.0 {
                pressed.push((i, p));
            }
        }
        (pressed, most)
    }

    /// Adds the tool's energy source at time t (the start of the step) to `q`: each pressed
    /// node gets contact_source(q(p_i), |A_i|, V_i, R) along its inward normal -A_i / |A_i|.
    /// `conductivity`: the nodes' tensors in the continuum reading (None: the paper's).
    pub fn sources(
        &mut self,
        t: f64,
        n: &Nodes,
        law: &TissueLaw,
        conductivity: Option<&crate::config::tissue::Materials>,
        q: &mut Vec<(u32, V3)>,
    ) {
        let c = self.tool.path.at(t);
        self.observe(c);
        if self.kinematic() {
            return; // its source depends on the state (`Simulation::advance`)
        }
        let rho = self.tool.shape.radius();
        for (i, p) in self.pressures(c, n, law).0 {
            let ar = n.area[i as usize];
            let a = norm(ar);
            let d_cond = conductivity.map(|r| {
                let d = nalgebra::Vector3::new(ar[0] / a, ar[1] / a, ar[2] / a);
                (d.transpose() * r.r(i as usize) * d)[(0, 0)]
            });
            let m = contact_source(law.energy_density(p), a, n.vol[i as usize], rho, d_cond);
            q.push((i, scale(ar, -m / a)));
        }
    }

    /// The tool's state at `c` over every process (exact sums; every process calls), its
    /// indentation this process's part (reduce with max).
    fn measure(&self, c: V3, n: &Nodes, law: &TissueLaw, u: &[V3], comm: &dyn Comm) -> ToolState {
        if self.kinematic() {
            // the force and the contact come from the state (`kinematic::measure`)
            return ToolState {
                position: c,
                indentation: self.indentation(c, n),
                ..ToolState::default()
            };
        }
        let (pressed, most) = self.pressures(c, n, law);
        let s = reproducible_sums(
            comm,
            pressed.iter().map(|&(i, p)| {
                let (ar, ui) = (n.area[i as usize], u[i as usize]);
                let a = norm(ar);
                [
                    -p * ar[0],
                    -p * ar[1],
                    -p * ar[2],
                    a,
                    1.0,
                    a * ui[0],
                    a * ui[1],
                    a * ui[2],
                ]
            }),
        );
        let area = s[3];
        ToolState {
            position: c,
            force: [s[0], s[1], s[2]],
            contact_nodes: s[4] as u64,
            contact_area: area,
            indentation: most,
            displacement: if area > 0.0 {
                [s[5] / area, s[6] / area, s[7] / area]
            } else {
                [0.0; 3]
            },
        }
    }
}

/// The owned surface nodes that can touch a tool: active (not fixed, in a cell) with a
/// boundary dual area.
pub fn surface_nodes(n_owned: usize, active: &[bool], area: &[V3]) -> Vec<u32> {
    (0..n_owned)
        .filter(|&i| active[i] && norm(area[i]) > 0.0)
        .map(|i| i as u32)
        .collect()
}

/// The tools at time t (the end of the mechanics step of size dt): after the free update
/// (u*, v*) of every node, each owned active node (surface or interior) whose deformed
/// position is inside a tool is moved onto its surface, u = P(X + u*) - X,
/// v = v* + (u - u*) / dt; then each tool's state at t (`measure`: a foundation's pressures on
/// the rest surface, summed exactly; a kinematic tool's contact is measured by the caller).
/// Returns the largest |v|^2 of the surface nodes (after the tools) and each tool's local
/// largest overlap with the rest surface (reduce with max).
#[allow(clippy::too_many_arguments)]
pub fn constrain(
    tools: &mut [ToolRun],
    t: f64,
    dt: f64,
    n: &Nodes,
    law: &TissueLaw,
    u: &mut [V3],
    v: &mut [V3],
    comm: &dyn Comm,
) -> (f64, Vec<f64>) {
    let mut overlaps = Vec::with_capacity(tools.len());
    for run in tools.iter_mut() {
        let shape = run.tool.shape;
        let c = run.tool.path.at(t);
        run.observe(c);
        for i in 0..u.len() {
            if !n.active[i] {
                continue;
            }
            let x0 = n.points[i];
            let ui = u[i];
            let x = [x0[0] + ui[0], x0[1] + ui[1], x0[2] + ui[2]];
            if !(depth(&shape, c, x) > 0.0) {
                continue;
            }
            let unew = sub(project(&shape, c, x), x0);
            if !unew.iter().all(|z| z.is_finite()) {
                continue; // a sphere's own centre: no direction to push along
            }
            let du = sub(unew, ui);
            u[i] = unew;
            let vi = v[i];
            v[i] = [vi[0] + du[0] / dt, vi[1] + du[1] / dt, vi[2] + du[2] / dt];
        }
        run.state = run.measure(c, n, law, u, comm);
        overlaps.push(run.state.indentation);
    }
    let m2 = (0..v.len())
        .filter(|&i| n.active[i])
        .map(|i| dot(v[i], v[i]))
        .fold(0.0, f64::max);
    (m2, overlaps)
}

/// The tools' state at time t before any step: the record of each path starts there, and the
/// state is measured with the displacement u (every process calls: reductions).
pub fn at_rest(tools: &mut [ToolRun], t: f64, n: &Nodes, law: &TissueLaw, u: &[V3], comm: &dyn Comm) {
    for run in tools.iter_mut() {
        let c = run.tool.path.at(t);
        run.start_at(c);
        run.state = run.measure(c, n, law, u, comm);
    }
    let local: Vec<f64> = tools.iter().map(|r| r.state.indentation).collect();
    for (run, d) in tools.iter_mut().zip(comm.max_each(&local)) {
        run.state.indentation = d;
    }
}

/// The tools' sources (this process's surface nodes, in the order a run appends them) at the
/// step times k dt, k = 0, 1, ..., as a run makes them (each path's record from its start),
/// until `stop(k, sources)` says so or `steps` steps; `tools` are left alone. None where a
/// tool is live (its path is not known in advance).
#[allow(clippy::too_many_arguments)]
pub fn planned_sources(
    tools: &[ToolRun],
    dt: f64,
    steps: u64,
    n: &Nodes,
    law: &TissueLaw,
    conductivity: Option<&crate::config::tissue::Materials>,
    mut stop: impl FnMut(u64, &[(u32, V3)]) -> bool,
) -> Option<Vec<Vec<(u32, V3)>>> {
    if tools.iter().any(|t| t.tool.live || t.kinematic()) {
        return None;
    }
    let mut runs: Vec<ToolRun> = tools.to_vec();
    for r in &mut runs {
        r.start_at(r.tool.path.at(0.0));
    }
    let mut out = Vec::new();
    for k in 0..steps {
        let mut q = Vec::new();
        for r in &mut runs {
            r.sources(k as f64 * dt, n, law, conductivity, &mut q);
        }
        let done = stop(k, &q);
        out.push(q);
        if done {
            break;
        }
    }
    Some(out)
}

/// The tools of a run continued at `step` (a restart): each path's record is what the run
/// made of it (its start at t = 0, then every step's time j dt up to `step`), and the state is
/// measured there with the restored displacement u (every process calls: reductions). The
/// contact pressures and sources depend only on the path and the rest surface, the held nodes
/// only on u, so the continued run is the uninterrupted one bit for bit.
pub fn resume(tools: &mut [ToolRun], step: u64, dt: f64, n: &Nodes, law: &TissueLaw, u: &[V3], comm: &dyn Comm) {
    for run in tools.iter_mut() {
        run.start_at(run.tool.path.at(0.0));
        for j in 0..=step {
            run.observe(run.tool.path.at(j as f64 * dt));
        }
        let c = run.tool.path.at(step as f64 * dt);
        run.state = run.measure(c, n, law, u, comm);
    }
    let local: Vec<f64> = tools.iter().map(|r| r.state.indentation).collect();
    for (run, d) in tools.iter_mut().zip(comm.max_each(&local)) {
        run.state.indentation = d;
    }
}

/// A tool's state at each of the increasing `times` as a run that starts at times[0] and
/// steps through them would measure it (the path's direction recorded along them), with
/// the displacement u; the run's own record is untouched. Every process calls.
pub fn survey(run: &ToolRun, times: &[f64], n: &Nodes, law: &TissueLaw, u: &[V3], comm: &dyn Comm) -> Vec<ToolState> {
    let mut r = run.clone();
    let mut out = Vec::with_capacity(times.len());
    for (k, &t) in times.iter().enumerate() {
        let c = r.tool.path.at(t);
        if k == 0 {
            r.start_at(c);
        }
        r.observe(c);
        out.push(r.measure(c, n, law, u, comm));
    }
    let local: Vec<f64> = out.iter().map(|s| s.indentation).collect();
    for (s, d) in out.iter_mut().zip(comm.max_each(&local)) {
        s.indentation = d;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_and_projection_of_each_shape() {
        let s = Shape::Sphere { radius: 2.0 };
        let c = [1.0, 0.0, 0.0];
        assert_eq!(depth(&s, c, [1.0, 0.0, 1.5]), 0.5);
        assert_eq!(depth(&s, c, [1.0, 0.0, 3.0]), -1.0);
        assert_eq!(project(&s, c, [1.0, 0.0, 1.5]), [1.0, 0.0, 2.0]);
        let p = project(&s, c, [2.0, 1.0, 0.0]);
        assert!((norm(sub(p, c)) - 2.0).abs() < 1e-15 && (p[0] - p[1] - 1.0).abs() < 1e-15);
        // a punch pressing down (-z) with its face at z = 1
        let s = Shape::Punch {
            radius: 0.5,
            normal: [0.0, 0.0, -1.0],
        };
        let c = [0.0, 0.0, 1.0];
        assert_eq!(depth(&s, c, [0.3, 0.0, 1.25]), 0.25);
        assert_eq!(depth(&s, c, [0.3, 0.0, 0.5]), -0.5);
        assert_eq!(depth(&s, c, [0.6, 0.0, 1.25]), f64::NEG_INFINITY);
        assert_eq!(project(&s, c, [0.3, 0.2, 1.25]), [0.3, 0.2, 1.0]);
    }

    #[test]
    fn the_overlap_is_along_the_path_and_passes_the_radius() {
        // a sphere of radius 1 moving down (-z) onto the plane z = 0, centre at height 1 - D
        let s = Shape::Sphere { radius: 1.0 };
        let d = Some([0.0, 0.0, -1.0]);
        for depth in [-0.5, 0.0, 0.3, 1.0, 1.7, 2.5] {
            let c = [0.0, 0.0, 1.0 - depth];
            // the node under the centre: the depth itself, past the radius and the diameter
            assert!((overlap(&s, c, d, [0.0; 3]) - depth).abs() < 1e-15, "{depth}");
            // a node at r = 0.6: sqrt(1 - 0.36) - (1 - D)
            let o = overlap(&s, c, d, [0.6, 0.0, 0.0]);
            assert!((o - (0.8 - 1.0 + depth)).abs() < 1e-15, "{depth}: {o}");
            // beside the path: never touched
            assert_eq!(overlap(&s, c, d, [1.2, 0.0, 0.0]), f64::NEG_INFINITY);
        }
        // without a direction: the radial depth
        assert!((overlap(&s, [0.0, 0.0, 0.5], None, [0.6, 0.0, 0.0]) - (1.0 - 0.61f64.sqrt())).abs() < 1e-15);
        // a punch: the face's offset along its normal, whatever the direction given
        let p = Shape::Punch {
            radius: 0.5,
            normal: [0.0, 0.0, -1.0],
        };
        assert_eq!(
            overlap(&p, [0.0, 0.0, -0.25], Some([1.0, 0.0, 0.0]), [0.3, 0.0, 0.0]),
            0.25
        );
    }

    #[test]
    fn the_law_is_zero_without_overlap_and_smooth_at_first_touch() {
        let law = TissueLaw { young: 10.0, beta: 2.0 };
        let e0 = SMOOTH_STRAIN;
        assert_eq!(contact_strain(0.0), 0.0);
        assert_eq!(contact_strain(-1.0), 0.0);
        assert_eq!(contact_strain(f64::NEG_INFINITY), 0.0);
        assert!((contact_strain(e0) - e0 / 2.0).abs() < 1e-18);
        assert!((contact_strain(0.3) - (0.3 - e0 / 2.0)).abs() < 1e-16);
        // the exponential law's stress at the strain of the overlap
        let p = pressure(&law, 0.6, 2.0);
        assert!(
            (p - 10.0 / 2.0 * ((2.0 * (0.3 - e0 / 2.0)).exp() - 1.0)).abs() < 1e-13,
            "{p}"
        );
        // stress and strain are inverse
        for sigma in [1e-6, 0.5, 3.0, 40.0] {
            assert!((law.stress(law.strain(sigma)) - sigma).abs() < 1e-12 * sigma.max(1.0));
        }
    }

    #[test]
    fn a_path_keeps_its_pressing_direction_through_hold_and_withdrawal() {
        use crate::config::tables::History;
        let mut h = History::empty();
        for row in [
            [0.0, 0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0, 0.5],
            [2.0, 0.0, 0.0, 0.5],
            [3.0, 0.0, 0.0, 0.9],
        ] {
            h.push(row).unwrap();
        }
        let mut run = ToolRun::new(Tool {
            shape: Shape::Sphere { radius: 0.2 },
            path: Trajectory::Table(h),
            live: false,
            law: ContactLaw::Foundation,
            grip: crate::config::Grip::Slide,
            foundation: 0.2,
        });
        run.start_at(run.tool.path.at(0.0));
        assert_eq!(run.direction(), None, "not moved yet");
        for k in 1..=30 {
            let t = 0.1 * k as f64;
            run.observe(run.tool.path.at(t));
            assert_eq!(run.direction(), Some([0.0, 0.0, -1.0]), "t = {t}");
        }
        // a straight path: its velocity's direction from the start, even before it moves
        let run = ToolRun::new(Tool {
            shape: Shape::Sphere { radius: 0.2 },
            path: Trajectory::Linear {
                start: [0.0; 3],
                velocity: [0.0, 3e300, 4e300],
            },
            live: false,
            law: ContactLaw::Foundation,
            grip: crate::config::Grip::Slide,
            foundation: 0.2,
        });
        let d = run.direction().unwrap();
        assert!((d[1] - 0.6).abs() < 1e-15 && (d[2] - 0.8).abs() < 1e-15, "{d:?}");
    }
}
