//! Tools at run time (docs/tools.md has the equations): each mechanics step the owned surface
//! nodes a tool reaches are held on its surface, the reaction that holds them is summed over
//! the contact set (exactly, so every process agrees), and that force feeds the energy
//! source of the next step through the contact area, as a patch load of the tool's radius.
//!
//! Per node everything depends only on the node's own state and the tool's position, so the
//! contact set, the reactions and their sums are the same on any number of processes.

use crate::config::{Shape, Tool};
use crate::discretize::material::TissueLaw;
use crate::discretize::operator::V3;
use crate::distribute::comm::{exact_sums, Comm};
use eprop_io::geom::{dot, norm, scale, sub};

/// What a tool did at the end of a mechanics step (the same on every process).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ToolState {
    /// The tool position (sphere centre, punch face centre) at the step's time.
    pub position: V3,
    /// The sum of the reactions over the contact set: the force the tool exerts on the organ
    /// (the organ pushes back on the tool with its opposite).
    pub force: V3,
    pub contact_nodes: u64,
    /// |sum of the contact nodes' boundary dual area vectors| (the projected contact area).
    pub contact_area: f64,
    /// How deep the tool is in the undeformed organ: the largest overlap of the tool with the
    /// rest position of a surface node (negative: the smallest gap).
    pub indentation: f64,
    /// The contact nodes' displacement, mean weighted by |A_i| (zero without contact).
    pub displacement: V3,
}

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

/// One tool of a running simulation.
pub struct ToolRun {
    pub tool: Tool,
    /// The state at the end of the last step.
    pub state: ToolState,
    /// Owned contact nodes of the last step with their source weights |A_i| rho / V_i.
    contact: Vec<(u32, f64)>,
}

/// The per-node geometry and material the tools need (this process's local arrays).
pub struct Nodes<'a> {
    /// Owned surface nodes that move (local indices): the candidates for contact.
    pub surface: &'a [u32],
    pub points: &'a [V3],
    pub area: &'a [V3],
    pub vol: &'a [f64],
    pub mass: &'a [f64],
}

impl ToolRun {
    pub fn new(tool: Tool) -> ToolRun {
        ToolRun {
            tool,
            state: ToolState::default(),
            contact: Vec::new(),
        }
    }

    /// Adds the tool's energy source for the next step to `q`: the last step's force F over
    /// its contact set C, sigma = |F| / |sum_C A_i|, Q_i = q(sigma) F/|F| |A_i| rho / V_i with rho
    /// the tool radius (a patch load of force F and radius rho on C).
    pub fn sources(&self, law: &TissueLaw, q: &mut Vec<(u32, V3)>) {
        let f = self.state.force;
        let fnorm = norm(f);
        if !(fnorm > 0.0 && self.state.contact_area > 0.0) {
            return;
        }
        let qd = law.energy_density(fnorm / self.state.contact_area);
        for &(i, w) in &self.contact {
            q.push((i, scale(f, w * qd / fnorm)));
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
/// (u*, v*) of every node, each owned surface node inside a tool is moved onto its surface,
/// u = P(X + u*) - X, v = v* + (u - u*) / dt, and its reaction R_i = m_i (u - u*) / dt^2 is added
/// to the tool's force; then each tool's sums are reduced exactly over every process.
/// Returns the largest |v|^2 of the surface nodes (after the tools) and each tool's local
/// largest overlap with the rest surface (reduce with max).
pub fn constrain(
    tools: &mut [ToolRun],
    t: f64,
    dt: f64,
    n: &Nodes,
    u: &mut [V3],
    v: &mut [V3],
    comm: &dyn Comm,
) -> (f64, Vec<f64>) {
    let mut overlaps = Vec::with_capacity(tools.len());
    for run in tools.iter_mut() {
        let shape = run.tool.shape;
        let c = run.tool.path.at(t);
        let rho = shape.radius();
        run.contact.clear();
        let mut overlap = f64::NEG_INFINITY;
        // (i, R_i, |A_i|)
        let mut held: Vec<(u32, V3, f64)> = Vec::new();
        for &i in n.surface {
            let i = i as usize;
            let x0 = n.points[i];
            overlap = overlap.max(depth(&shape, c, x0));
            let ui = u[i];
            let x = [x0[0] + ui[0], x0[1] + ui[1], x0[2] + ui[2]];
            if !(depth(&shape, c, x) > 0.0) {
                continue;
            }
            let p = project(&shape, c, x);
            let unew = sub(p, x0);
            if !unew.iter().all(|z| z.is_finite()) {
                continue; // a sphere's own centre: no direction to push along
            }
            let du = sub(unew, ui);
            let m = n.mass[i];
            let r = [m * du[0] / (dt * dt), m * du[1] / (dt * dt), m * du[2] / (dt * dt)];
            u[i] = unew;
            let vi = v[i];
            v[i] = [vi[0] + du[0] / dt, vi[1] + du[1] / dt, vi[2] + du[2] / dt];
            let a = norm(n.area[i]);
            run.contact.push((i as u32, a * rho / n.vol[i]));
            held.push((i as u32, r, a));
        }
        let s = exact_sums(
            comm,
            held.iter().map(|&(i, r, a)| {
                let (ar, ui) = (n.area[i as usize], u[i as usize]);
                [
                    r[0],
                    r[1],
                    r[2],
                    ar[0],
                    ar[1],
                    ar[2],
                    1.0,
                    a * ui[0],
                    a * ui[1],
                    a * ui[2],
                    a,
                ]
            }),
        );
        let weight = s[10];
        run.state = ToolState {
            position: c,
            force: [s[0], s[1], s[2]],
            contact_nodes: s[6] as u64,
            contact_area: norm([s[3], s[4], s[5]]),
            indentation: overlap,
            displacement: if weight > 0.0 {
                [s[7] / weight, s[8] / weight, s[9] / weight]
            } else {
                [0.0; 3]
            },
        };
        overlaps.push(overlap);
    }
    let m2 = n
        .surface
        .iter()
        .map(|&i| dot(v[i as usize], v[i as usize]))
        .fold(0.0, f64::max);
    (m2, overlaps)
}

/// The tools' state at time t before any step (no contact yet): position and indentation
/// (a reduction: every process calls).
pub fn at_rest(tools: &mut [ToolRun], t: f64, n: &Nodes, comm: &dyn Comm) {
    let local: Vec<f64> = tools
        .iter()
        .map(|run| {
            let c = run.tool.path.at(t);
            n.surface
                .iter()
                .map(|&i| depth(&run.tool.shape, c, n.points[i as usize]))
                .fold(f64::NEG_INFINITY, f64::max)
        })
        .collect();
    let all = comm.max_each(&local);
    for (run, d) in tools.iter_mut().zip(all) {
        run.contact.clear();
        run.state = ToolState {
            position: run.tool.path.at(t),
            indentation: d,
            ..ToolState::default()
        };
    }
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
}
