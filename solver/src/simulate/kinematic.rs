//! The kinematic contact law (docs/tools.md): a tool is a condition on where the tissue is,
//! and the model finds the energy it takes.
//!
//! At the start of a step (state u^n, phi^n; the tool moves from c_n to c_{n+1}) every active
//! node the tool touches gets a target position on the tool's surface (`hold`): a node inside
//! the tool at c_{n+1} is pushed onto its surface (a punch along its normal, a moving sphere
//! along its move, `push_out`); a node on its surface follows it (a sticky tool carries it
//! along, a sliding one pushes it out where it moves into it and takes it to the nearest
//! surface point where it moves away). A node on the surface stays held only while its reaction pushes on the tool: a
//! tool does not pull (`held_nodes`).
//!
//! The potential of a held node is set to the value that holds the node there at
//! equilibrium, phi*_c = g_c / lambda_c (lambda = kappa / k, so u = lambda phi; p != 1:
//! |phi| = (|g| / lambda)^(1/p)), and kept there over the step: its row of the operator is
//! emptied for the step (`Propagation::freeze`), so every integrator holds it (the implicit
//! one's conjugate gradients keep their search directions zero there), and sources on it are
//! dropped. That is the paper's Dirichlet condition on the potential at the contact, with the
//! energy the tool puts in as the unknown. After the mechanics the held nodes are at their
//! targets, and any other node the tool would contain is pushed out of it
//! (`super::contact::constrain`, every node, surface and interior).
//!
//! The force on the organ is the model's reaction at the end of the step, from the Dirichlet
//! energy the potential stores: f_c = M lambda_c / D_c (-C_c) (L phi)_c, the outflow of energy
//! at each node on or in the tool, M = E / (2 (1 - nu^2)) (the harmonic model's modulus that
//! gives Boussinesq's surface displacement on a half-space), D_c the node's mean
//! conductivity, C_c its capacity (its control volume, weighed by young where tissues differ,
//! with E the reference young then); for a sliding tool only the nodes that push on it (a
//! punch: the part along its normal; a sphere, which carries them along its move: their
//! whole reaction, by virtual work). Every factor
//! but E is fixed by the displacement, so a prescribed tool path moves the tissue the same
//! whatever young, and the force scales with young.
//!
//! The reaction is the derivative of the stored energy S = 1/2 sum_i Gamma_i phi_i .
//! (-C_i (L phi)_i), Gamma = M lambda^2 / D, with respect to a held node's displacement
//! lambda phi (C L is the symmetric conductance matrix): the tools' work over a step, the mean
//! reaction before and after their move times the move (`step_work`), is S's change over the
//! move, and the integration over the step with the held nodes still takes S down by what the
//! propagation dissipates (`Energy`).

use super::contact::{depth, project, ToolRun};
use crate::config::tissue::Materials;
use crate::config::{Grip, Shape};
use crate::discretize::operator::Operator;
use crate::linalg::V3;
use eprop_io::geom::{dot, norm, scale, sub};
use eprop_series::vtkhdf::ToolState;

/// A node counts as touching a tool when it is less than this fraction of the tool's radius
/// outside it (round-off of a node put on the surface).
pub(crate) const ON_SURFACE: f64 = 1e-9;

/// Whether a point y touches the tool at `c`: inside it, or outside by less than ON_SURFACE
/// of its radius.
pub fn touches(shape: &Shape, c: V3, y: V3) -> bool {
    depth(shape, c, y) >= -ON_SURFACE * shape.radius()
}

/// A node held over one step.
#[derive(Clone, Copy, Debug)]
pub struct Held {
    pub node: u32,
    /// The displacement the tool gives it at the step's end.
    pub target: V3,
    /// Its displacement at the step's start.
    pub before: V3,
}

/// a + b
fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// The direction the tool at `c` pushes the tissue at a point y on or near its surface: a
/// punch's normal; a sphere's outward radius (None at its centre).
pub(crate) fn push_normal(shape: &Shape, c: V3, y: V3) -> Option<V3> {
    match *shape {
        Shape::Punch { normal, .. } => Some(normal),
        Shape::Sphere { .. } => {
            let d = sub(y, c);
            let r = norm(d);
            (r > 0.0 && r.is_finite()).then(|| scale(d, 1.0 / r))
        }
    }
}

/// A moving sphere moves the tissue along its move where its surface faces the move within
/// 60 degrees (the cosine of that angle; `along_move`).
pub const ALONG_MOVE: f64 = 0.5;

/// Where a sphere moving from `c_now` to `c_next` (unit move m) takes a point y along its
/// move, or None where it does not: with w = y - c_next and w_perp its part across m, the
/// line y + s m meets the sphere at s = -w.m -+ h, h = sqrt(R^2 - |w_perp|^2). A point inside
/// it (`inside`) in front of its centre (w.m >= 0) is pushed forward to where the line
/// leaves it, s = h - w.m; a point it moves away from follows it to where the line enters it,
/// s = -h - w.m >= 0; either only where the sphere's surface there faces the move within 60
/// degrees (h >= ALONG_MOVE R): beside the move (a sphere dragged across the surface), the
/// nearest point instead (the caller's `project`), so a frictionless sphere does not plough.
/// Along the move rather than to the nearest point: a node the sphere presses stays under the
/// point of the sphere that met it instead of sliding out along its surface step after step
/// (the harmonic model has no stiffness against that sliding; the elastic reference's surface
/// hardly slides, docs/validation.md), and a withdrawal takes the nodes back the way they came.
pub fn along_move(shape: &Shape, c_now: V3, c_next: V3, y: V3, inside: bool) -> Option<V3> {
    let Shape::Sphere { radius } = *shape else {
        return None;
    };
    let mv = sub(c_next, c_now);
    let len = norm(mv);
    if !(len > 0.0 && len.is_finite()) {
        return None;
    }
    let m = scale(mv, 1.0 / len);
    let w = sub(y, c_next);
    let b = dot(w, m);
    let perp = norm(sub(w, scale(m, b)));
    if !(perp < radius) {
        return None;
    }
    let h = ((radius - perp) * (radius + perp)).sqrt();
    if h < ALONG_MOVE * radius {
        return None;
    }
    let s = if inside {
        (b >= 0.0).then(|| (h - b).max(0.0))?
    } else {
        Some(-h - b).filter(|&s| s >= 0.0)?
    };
    Some(add(y, scale(m, s)))
}

/// Where the tool moving from `c_now` to `c_next` pushes a point y inside it at `c_next`: a
/// moving sphere along its move where it faces it (`along_move`), else onto the nearest point
/// of its surface; a punch onto its face along its normal (`project`).
pub fn push_out(shape: &Shape, c_now: V3, c_next: V3, y: V3) -> V3 {
    along_move(shape, c_now, c_next, y, true).unwrap_or_else(|| project(shape, c_next, y))
}

/// Where the tool moving from `c_now` to `c_next` puts the point y (a node's position at the
/// step's start), or None when it does not touch it. A point inside the tool at c_next is
/// pushed onto its surface (`push_out`); a point on the surface at c_now follows it: a
/// sticky tool carries it along (with the tool's whole move), a sliding one pushes it out
/// where it moves into it and, where it moves away from it, takes it along its move
/// (`along_move`) or else to the nearest point of its surface at c_next. Whether a touching point stays held is the
/// reaction's to say (`held_nodes`): a tool does not pull.
pub fn hold(run: &ToolRun, c_now: V3, c_next: V3, y: V3) -> Option<V3> {
    let shape = run.tool.shape;
    let tol = ON_SURFACE * shape.radius();
    let on_now = touches(&shape, c_now, y);
    let mut y = y;
    if run.tool.grip == Grip::Stick && on_now {
        y = add(y, sub(c_next, c_now));
    }
    let d = depth(&shape, c_next, y);
    let p = if d > 0.0 {
        push_out(&shape, c_now, c_next, y)
    } else if on_now && d.is_finite() && d < -tol {
        along_move(&shape, c_now, c_next, y, false).unwrap_or_else(|| project(&shape, c_next, y))
    } else if d >= -tol {
        y
    } else {
        return None;
    };
    p.iter().all(|x| x.is_finite()).then_some(p)
}

/// The potential that holds a node at displacement g at equilibrium: kappa |phi|^(p-1) phi
/// = k g, i.e. phi = g / lambda for p = 1.
pub(crate) fn held_potential(g: V3, stiffness: f64, coupling: f64, p: f64) -> V3 {
    if p == 1.0 {
        let s = stiffness / coupling;
        return [g[0] * s, g[1] * s, g[2] * s];
    }
    let m = norm(g);
    if !(m > 0.0) {
        return [0.0; 3];
    }
    let mag = (stiffness * m / coupling).powf(1.0 / p);
    scale(g, mag / m)
}

/// Each owned row's relaxation rate mu_i = sum_j c_ij + s_i (the compact operator, s_i its
/// screening sink), or None for the paper scheme.
pub(crate) fn relaxation_rates(op: &Operator, n_rows: usize) -> Option<Vec<f64>> {
    let Operator::Compact(c) = op else {
        return None;
    };
    let ptr = c.row_ptr();
    Some(
        (0..n_rows)
            .map(|i| {
                let mu: f64 = (ptr[i] as usize..ptr[i + 1] as usize).map(|p| c.c(p)).sum();
                match c.sink() {
                    None => mu,
                    Some(s) => mu + s[i],
                }
            })
            .collect(),
    )
}

/// The force factor of node i, M lambda_i / D_i with M = E / (2 (1 - nu_i^2)) and D_i the
/// mean of its conductivity's diagonal; E is the node's tissue's young, or the reference E0
/// where the propagation weighs young (its capacity C_i then carries each cell's E_c / E0:
/// the force M0 lambda / D (-C_i (L phi)_i) is the derivative of the stored energy, module
/// docs).
pub(crate) fn force_factor(mat: &Materials, i: usize) -> f64 {
    let t = mat.at(i);
    let e = if mat.weighs_young() { mat.young0 } else { t.law.young };
    let m = e / (2.0 * (1.0 - t.poisson * t.poisson));
    m * (t.coupling / t.stiffness) / super::mean_conductivity(mat, i)
}

/// The nodes the kinematic tools hold over the step from t (tools at `now`) to t + dt (at
/// `next`), among the owned `active` nodes at rest positions `x` displaced by `u` and moving
/// at `v`; a node is held by the first tool that holds it.
/// A node the tool does not touch at t is judged where its own motion takes it over the step,
/// y + v dt: a node is caught when the tool's move and its own would overlap, and is put on
/// the tool from there. So a node just outside the catch moves freely by about v dt and a node
/// just inside it is put on the surface near y + v dt: the catch is continuous in the node's
/// gap (judged from y alone, a node running ahead of the tool would stop dead when caught,
/// a jump of v dt between a node caught and one just missed).
/// `pulls(i, n)`: whether node i, held where it is, would pull the tool along n (a tensile
/// reaction): such a node on the surface is let go; one inside the tool is always pushed out.
#[allow(clippy::too_many_arguments)]
pub(crate) fn held_nodes(
    tools: &[ToolRun],
    now: &[V3],
    next: &[V3],
    x: &[V3],
    u: &[V3],
    (v, dt): (&[V3], f64),
    active: &[bool],
    pulls: impl Fn(usize, V3) -> bool,
) -> Vec<Held> {
    let mut out = Vec::new();
    let mut taken = vec![false; u.len()];
    for (k, run) in tools.iter().enumerate() {
        if !run.kinematic() {
            continue;
        }
        let reach = run.tool.shape.radius() + norm(sub(next[k], now[k])) + ON_SURFACE * run.tool.shape.radius();
        for i in 0..u.len() {
            if !active[i] || taken[i] {
                continue;
            }
            let mut y = add(x[i], u[i]);
            let drift = scale(v[i], dt);
            // a cheap test first: points farther than the radius and the moves from both
            // positions cannot be held
            let r = 2.0 * reach + norm(drift);
            if norm(sub(y, next[k])) > r && norm(sub(y, now[k])) > r {
                continue;
            }
            if !touches(&run.tool.shape, now[k], y) {
                y = add(y, drift);
            }
            if let Some(p) = hold(run, now[k], next[k], y) {
                let shape = &run.tool.shape;
                if depth(shape, next[k], p) <= 0.0 && depth(shape, next[k], y) <= ON_SURFACE * shape.radius() {
                    // on the surface, not pushed: it stays only while it pushes back
                    if push_normal(shape, next[k], y).is_some_and(|nn| pulls(i, nn)) {
                        continue;
                    }
                }
                taken[i] = true;
                out.push(Held {
                    node: i as u32,
                    target: sub(p, x[i]),
                    before: u[i],
                });
            }
        }
    }
    out
}

/// What the kinematic tools keep between steps on one process.
pub struct State {
    /// Each owned row's relaxation rate mu_i.
    pub mu: Vec<f64>,
    /// L phi on the owned rows at the current state.
    pub lphi: Vec<V3>,
    /// A copy of phi whose halo the operator refreshes.
    pub scratch: crate::distribute::field::NodeField<V3>,
    /// The nodes held over the last step.
    pub held: Vec<Held>,
    /// L phi on the owned rows just after the held potential was set (the energy's jump).
    pub lplus: Vec<V3>,
    /// The tools' energy account so far.
    pub energy: Energy,
    /// S right after the last step's move, until the step's end counts its dissipation.
    pub after_move: Option<f64>,
}

/// The kinematic tools' energy account (docs/tools.md, "Energy"), cumulative from the start of
/// the run, in joules (the reading's energy unit), the same on every process.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Energy {
    /// The work the tools did on the organ: sum over the steps and held nodes of the mean of
    /// the reaction before and after the step's move times the move.
    pub work: f64,
    /// The energy the potential stores now, S = 1/2 sum_i Gamma_i phi_i . (-C_i (L phi)_i).
    pub stored: f64,
    /// What the propagation's relaxation took out while the held nodes stood still: the
    /// decrease of S over each step's integration.
    pub dissipated: f64,
}

/// Gamma_i = M lambda_i^2 / D_i: the stored energy's factor of node i (`force_factor` times
/// lambda_i), so that the reaction f_i = Gamma_i / lambda_i (-C_i (L phi)_i) is the
/// derivative of S with respect to the node's displacement lambda_i phi_i.
pub(crate) fn energy_factor(mat: &Materials, i: usize) -> f64 {
    let t = mat.at(i);
    force_factor(mat, i) * (t.coupling / t.stiffness)
}

/// The stored energy S = 1/2 sum_i Gamma_i phi_i . (-C_i (L phi)_i) over the owned `active`
/// rows, with `cap` the capacities C_i and `lphi` = L phi (every process calls: an exact sum).
pub(crate) fn stored_energy(
    mat: &Materials,
    active: &[bool],
    cap: &[f64],
    phi: &[V3],
    lphi: &[V3],
    comm: &dyn crate::distribute::comm::Comm,
) -> f64 {
    let n = lphi.len();
    let term = |i: usize| -> [f64; 1] {
        if !active[i] {
            return [0.0];
        }
        [-0.5 * energy_factor(mat, i) * cap[i] * dot(phi[i], lphi[i])]
    };
    crate::distribute::comm::reproducible_sums(comm, (0..n).map(term))[0]
}

/// The tools' work over one step's move of the held potential from `before` to the value now
/// in `phi` at each held node: sum_c Gamma_c (phi_c - before_c) . (-C_c (L phi^n + L phi^+)_c / 2),
/// the mean of the reaction before (`lphi`) and after (`lplus`) the move times the move
/// (exactly the change of S over the move, S being quadratic). Every process calls.
#[allow(clippy::too_many_arguments)]
pub(crate) fn step_work(
    mat: &Materials,
    cap: &[f64],
    held: &[(u32, V3)],
    phi: &[V3],
    lphi: &[V3],
    lplus: &[V3],
    comm: &dyn crate::distribute::comm::Comm,
) -> f64 {
    let term = |&(c, before): &(u32, V3)| -> [f64; 1] {
        let i = c as usize;
        let moved = sub(phi[i], before);
        let mean = scale(add(lphi[i], lplus[i]), 0.5);
        [-energy_factor(mat, i) * cap[i] * dot(moved, mean)]
    };
    crate::distribute::comm::reproducible_sums(comm, held.iter().map(term))[0]
}

/// What a kinematic tool at `c` does at the end of a step, from the state (u and lphi =
/// L phi on the owned rows): the nodes on or in it (surface and interior), their reaction
/// force f_c = M lambda_c / D_c (-C_c) (L phi)_c (module docs), the contact area and the
/// mean displacement of its surface nodes (weighted by |A_i|); the indentation is left at
/// -inf for the caller. Every process calls (exact sums).
#[allow(clippy::too_many_arguments)]
pub fn measure(
    run: &ToolRun,
    c: V3,
    n: &super::contact::Nodes,
    mat: &Materials,
    cap: &[f64],
    u: &[V3],
    lphi: &[V3],
    comm: &dyn crate::distribute::comm::Comm,
) -> ToolState {
    let shape = run.tool.shape;
    let mut rows = Vec::new();
    for i in 0..u.len() {
        if !n.active[i] {
            continue;
        }
        let y = add(n.points[i], u[i]);
        if !touches(&shape, c, y) {
            continue;
        }
        let s = -force_factor(mat, i) * cap[i];
        let f0 = scale(lphi[i], s);
        let mut f = f0;
        if run.tool.grip == Grip::Slide {
            if let Some(nn) = push_normal(&shape, c, y) {
                let pushes = dot(f, nn);
                f = match shape {
                    // a sphere carries the nodes it pushes along its move (`push_out`): by
                    // virtual work its force is their whole reaction, while they push
                    Shape::Sphere { .. } if pushes > 0.0 => f0,
                    _ => scale(nn, pushes.max(0.0)),
                };
            }
        }
        let a = norm(n.area[i]);
        rows.push([f[0], f[1], f[2], a, 1.0, a * u[i][0], a * u[i][1], a * u[i][2]]);
    }
    let s = crate::distribute::comm::reproducible_sums(comm, rows.iter().copied());
    let area = s[3];
    ToolState {
        position: c,
        force: [s[0], s[1], s[2]],
        contact_nodes: s[4] as u64,
        contact_area: area,
        indentation: f64::NEG_INFINITY,
        displacement: if area > 0.0 {
            [s[5] / area, s[6] / area, s[7] / area]
        } else {
            [0.0; 3]
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{ContactLaw, Tool, Trajectory};

    fn run(shape: Shape, grip: Grip) -> ToolRun {
        ToolRun::new(Tool {
            shape,
            path: Trajectory::Linear {
                start: [0.0; 3],
                velocity: [0.0; 3],
            },
            live: false,
            law: ContactLaw::Kinematic,
            grip,
            foundation: 1.0,
        })
    }

    #[test]
    fn a_sliding_sphere_pushes_out_and_lets_go_when_it_leaves() {
        let r = run(Shape::Sphere { radius: 1.0 }, Grip::Slide);
        // a point 0.25 inside the sphere at its new position: onto the surface
        let p = hold(&r, [0.0, 0.0, 2.0], [0.0, 0.0, 1.5], [0.0, 0.0, 0.75]).unwrap();
        assert_eq!(p, [0.0, 0.0, 0.5]);
        // on the surface of the still tool: stays
        assert_eq!(hold(&r, [0.0; 3], [0.0; 3], [0.0, 0.0, -1.0]), Some([0.0, 0.0, -1.0]));
        // the tool moves away: the point follows its surface (the reaction decides whether
        // it stays held)
        let p = hold(&r, [0.0; 3], [0.0, 0.0, 0.1], [0.0, 0.0, -1.0]).unwrap();
        assert!((p[2] + 0.9).abs() < 1e-15, "{p:?}");
        // a point off the surface is not touched
        assert_eq!(hold(&r, [0.0; 3], [0.0, 0.0, 0.1], [0.0, 0.0, -1.01]), None);
    }

    #[test]
    fn a_moving_sphere_pushes_along_its_move_and_carries_what_it_presses() {
        let r = run(Shape::Sphere { radius: 1.0 }, Grip::Slide);
        // off the axis, in front of the centre: down along the move (x kept), not radially
        let p = hold(&r, [0.0, 0.0, 1.0], [0.0, 0.0, 0.5], [0.6, 0.0, 0.0]).unwrap();
        assert_eq!(p[0], 0.6);
        assert!((p[2] - (0.5 - 0.8)).abs() < 1e-15, "{p:?}");
        // a point on the sphere in front of its centre moves with it, as a sticky one would
        let p = hold(&r, [0.0; 3], [0.0, 0.0, -0.1], [0.6, 0.0, -0.8]).unwrap();
        assert!((p[0] - 0.6).abs() < 1e-15 && (p[2] + 0.9).abs() < 1e-15, "{p:?}");
        // withdrawn, it takes the point back along its move (x kept)
        let p = hold(&r, [0.0; 3], [0.0, 0.0, 0.1], [0.6, 0.0, -0.8]).unwrap();
        assert!((p[0] - 0.6).abs() < 1e-15 && (p[2] + 0.7).abs() < 1e-15, "{p:?}");
        // dragged sideways, a point under it goes to the nearest point, not ahead of it
        let y = [0.1, 0.0, -0.99];
        let c = [0.1, 0.0, 0.0];
        assert_eq!(push_out(&r.tool.shape, [0.0; 3], c, y), project(&r.tool.shape, c, y));
        // behind the centre, or the sphere still: the nearest point
        let y = [0.9, 0.0, 0.2];
        assert_eq!(
            push_out(&r.tool.shape, [0.0, 0.0, 0.1], [0.0; 3], y),
            project(&r.tool.shape, [0.0; 3], y)
        );
        let y = [0.5, 0.0, -0.5];
        assert_eq!(
            push_out(&r.tool.shape, [0.0; 3], [0.0; 3], y),
            project(&r.tool.shape, [0.0; 3], y)
        );
    }

    #[test]
    fn a_sticky_punch_carries_its_face_and_leaves_it_when_withdrawn() {
        let n = [0.0, 0.0, -1.0];
        let r = run(Shape::Punch { radius: 1.0, normal: n }, Grip::Stick);
        // on the face, the punch presses 0.1 and moves 0.2 sideways: the point follows
        let p = hold(&r, [0.0; 3], [0.2, 0.0, -0.1], [0.5, 0.0, 0.0]).unwrap();
        assert!((p[0] - 0.7).abs() < 1e-15 && (p[2] + 0.1).abs() < 1e-15, "{p:?}");
        // a sliding punch does not carry the point sideways
        let s = run(Shape::Punch { radius: 1.0, normal: n }, Grip::Slide);
        assert_eq!(
            hold(&s, [0.0; 3], [0.2, 0.0, -0.1], [0.5, 0.0, 0.0]),
            Some([0.5, 0.0, -0.1])
        );
        // beside the face: never
        assert_eq!(hold(&s, [0.0; 3], [0.0, 0.0, -0.1], [1.5, 0.0, 0.0]), None);
        // a withdrawal lets go of every point whose reaction pulls, keeps the others
        let x = [[0.5, 0.0, 0.0], [-0.5, 0.0, 0.0], [0.0, 0.5, 0.0]];
        let u = [[0.0; 3]; 3];
        let held = held_nodes(
            &[r],
            &[[0.0; 3]],
            &[[0.0, 0.0, 0.1]],
            &x,
            &u,
            (&u, 1.0),
            &[true; 3],
            |i, nn| {
                assert_eq!(nn, n);
                i == 1
            },
        );
        let ids: Vec<u32> = held.iter().map(|h| h.node).collect();
        assert_eq!(ids, [0, 2]);
        assert!((held[0].target[2] - 0.1).abs() < 1e-15);
    }

    #[test]
    fn the_held_potential_gives_the_target_at_equilibrium() {
        for p in [1.0, 0.5, 2.0] {
            let (k, kappa) = (4e5, 15.0);
            let g = [1e-3, -2e-3, 3e-4];
            let phi = held_potential(g, k, kappa, p);
            let m = norm(phi);
            let u = scale(phi, kappa * m.powf(p - 1.0) / k);
            for d in 0..3 {
                assert!((u[d] - g[d]).abs() < 1e-15, "p = {p}: {u:?}");
            }
        }
    }
}
