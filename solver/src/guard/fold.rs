//! When the mesh folds: the record of each output step's inverted cells and nodes inside tools
//! (`simulate::inspect`), and the one warning of the first step with inverted cells, which
//! names where they are and the cause that applies (a tool's depth, a load, the model itself).

use crate::diagnostics::{fixed, short};
use crate::simulate::inspect::Inspection;
use crate::simulate::Simulation;
use eprop_io::geom::norm;

/// What the output steps of a run (since its start or restart) said of their state.
#[derive(Clone, Debug, Default)]
pub struct Record {
    /// The last output step's inspection.
    pub last: Inspection,
    /// The most inverted cells of an output step, and that step's time.
    pub most: u64,
    pub most_time: f64,
    /// The largest count of nodes inside each tool at an output step.
    pub most_inside: Vec<u64>,
    /// The most nodes across a support's plane at an output step.
    pub most_across: u64,
    /// Inverted cells appeared and were not yet warned of.
    pending: bool,
    warned: bool,
    /// Nodes across a support appeared and were not yet warned of.
    across_pending: bool,
    across_warned: bool,
}

impl Record {
    /// Notes the inspection of the output step at `time`.
    pub fn note(&mut self, time: f64, i: Inspection) {
        if i.inverted > self.most {
            (self.most, self.most_time) = (i.inverted, time);
        }
        self.most_inside.resize(i.inside.len(), 0);
        for (m, &k) in self.most_inside.iter_mut().zip(&i.inside) {
            *m = (*m).max(k);
        }
        if i.inverted > 0 && !self.warned {
            self.pending = true;
        }
        self.most_across = self.most_across.max(i.across);
        if i.across > 0 && !self.across_warned {
            self.across_pending = true;
        }
        self.last = i;
    }

    /// The warnings of the first output step with inverted cells and of the first with nodes
    /// across a support, once each (every process calls: the cause takes reductions; the same
    /// verdict everywhere).
    pub fn warnings(&mut self, sim: &Simulation) -> Vec<String> {
        let mut out = Vec::new();
        if self.pending {
            (self.pending, self.warned) = (false, true);
            out.push(describe(sim, &self.last));
        }
        if self.across_pending {
            (self.across_pending, self.across_warned) = (false, true);
            out.push(format!(
                "{} node(s) lie across a fixed support's plane at step {} (t = {:.6e}), up to {:.4e} beyond it: the support is rigid, so this is where a node's update outran it; fix: a smaller dt, or a shallower tool path or smaller load near the support",
                self.last.across,
                sim.step(),
                sim.time(),
                self.last.farthest
            ));
        }
        out
    }
}

fn point(p: [f64; 3]) -> String {
    format!("({}, {}, {})", fixed(p[0], 4), fixed(p[1], 4), fixed(p[2], 4))
}

/// The first inverted cells: how many, where, and why (every process calls).
pub fn describe(sim: &Simulation, i: &Inspection) -> String {
    let within = match i.bounds {
        Some((lo, hi)) => format!(", within {} - {}", point(lo), point(hi)),
        None => String::new(),
    };
    format!(
        "{} cell(s) inverted at step {} (t = {:.6e}): the deformed mesh folds around {} (rest positions{within}); {}",
        i.inverted,
        sim.step(),
        sim.time(),
        point(i.centroid),
        cause(sim, i)
    )
}

/// The cause that applies: a tool that presses (its depth against its radius and the mesh near
/// it; its path is prescribed, so no force is to blame), else a load that pushes, else the
/// model itself.
fn cause(sim: &Simulation, i: &Inspection) -> String {
    let pressing: Vec<usize> = sim
        .tools
        .iter()
        .enumerate()
        .filter(|(k, t)| {
            t.state.indentation > 0.0 || t.state.contact_nodes > 0 || i.inside.get(*k).is_some_and(|&n| n > 0)
        })
        .map(|(k, _)| k)
        .collect();
    if !pressing.is_empty() {
        let mut parts = Vec::new();
        for k in pressing {
            let t = &sim.tools[k];
            let (r, d) = (t.tool.shape.radius(), t.state.indentation.max(0.0));
            // every process calls (a reduction)
            let spacing = sim.surface_spacing_near(&[t.state.position], r + d);
            let mesh = match spacing {
                Some(h) => format!(", {:.2} times the surface spacing {:.4e} near it", d / h, h),
                None => String::new(),
            };
            let inside = match i.inside.get(k) {
                Some(&n) if n > 0 => format!("; {n} node(s) lie inside it, up to {:.4e} deep", i.deepest[k]),
                _ => String::new(),
            };
            parts.push(format!(
                "tool {} ({} r = {}) is pressed {:.4e} into the organ, {:.2} of its radius{mesh}{inside}",
                k + 1,
                t.tool.shape.name(),
                short(r),
                d,
                d / r,
            ));
        }
        return format!(
            "cause: the tools' prescribed paths: {}; fix: a shallower path (an indentation of a few cells near the tool at most), a mesh finer near the tool, or a larger tool",
            parts.join("; ")
        );
    }
    let applied = sim.applied(sim.time());
    let pushing: Vec<String> = sim
        .loads
        .iter()
        .zip(&applied)
        .enumerate()
        .filter(|(_, (_, a))| norm(a.force) > 0.0)
        .map(|(k, (l, a))| {
            format!(
                "load {} pushes with |F| = {:.4e} on {} node(s) (area {:.4e}, contact stress {:.4e}, energy density {:.4e})",
                k + 1,
                norm(a.force),
                l.nodes.len(),
                l.area,
                a.sigma,
                a.q
            )
        })
        .collect();
    if !pushing.is_empty() {
        return format!(
            "cause: the loads: {}; fix: a smaller force, a larger contact patch, or a stiffer tissue",
            pushing.join("; ")
        );
    }
    "cause: no tool presses and no load pushes now: the model's own deformation (its potential and pull-back are not finite-strain elasticity and do not keep cells from inverting, docs/model.md section 8); fix: check [model] coupling and the stiffness of the reading, or end the run before this step".into()
}
