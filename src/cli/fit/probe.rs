//! One evaluation: a simulation built and stepped with the parameters applied, each curve's
//! quantity sampled per step (`Probe`) and interpolated at the curve's x.

use super::curve::{Curve, XKind, YKind};
use super::params::Param;
use super::{broadcast, FitOptions, Outcome};
use crate::cli::run::start_mpi_if_needed;
use anyhow::{bail, Result};
use eprop::config::{Scenario, Setup};
use eprop::diagnostics::short;
use eprop::distribute::comm::Comm;
use eprop::distribute::launch::{Agreed, EXIT_STOPPED};
use eprop::linalg::V3;
use eprop::simulate::distributed::build_mpi;
use eprop::simulate::{Simulation, StopToken};
use std::path::Path;

/// What is measured of one curve in a simulation. With `evaluate` (which steps the simulation)
/// the only code here that reads a simulation: its public methods, and the fields `global` (the
/// node ids), `comm`, `u`, `time`, `step` and `stop_signal`.
pub(super) struct Probe {
    x: XKind,
    y: YKind,
    tool: usize,
    load: usize,
    /// The measured node's local index where this process owns it (None elsewhere); None for
    /// a load's probe.
    node: Option<Option<usize>>,
    /// A profile: its nodes' rest coordinates along the axis (increasing) and local indices
    /// where this process has them.
    line: Vec<(f64, Option<usize>)>,
    /// The sampled polyline (time or indentation), or a profile's values at the deepest step.
    xs: Vec<f64>,
    ys: Vec<f64>,
    /// A profile: the deepest indentation of its tool so far.
    deepest: f64,
}

impl Probe {
    fn new(sim: &Simulation, scenario: &Path, c: &Curve) -> Result<Probe> {
        let path = scenario.display();
        let s = &c.spec;
        let file = s.file.display();
        let tools = sim.tool_states().len();
        let loads = sim.probes().len();
        let needs_tool = c.x_kind == XKind::Indentation || c.y_kind == YKind::Force;
        if needs_tool && !(1..=tools).contains(&s.tool) {
            bail!(
                "{path}: the curve {file}'s {} is a tool's, and the scenario has {tools} [[tool]] table(s) (tool {}); fix: a scenario with a [[tool]], or --tool 1..={tools} (or --data {file}:tool=K)",
                if c.y_kind == YKind::Force { "force" } else { "indentation" },
                s.tool
            );
        }
        let mut node = None;
        let mut line = vec![];
        if let Some(a) = c.x_kind.axis() {
            if tools > 0 && !(1..=tools).contains(&s.tool) {
                bail!("{path}: the profile {file} is taken at the deepest step of tool {}, and the scenario has {tools} [[tool]] table(s); fix: --data {file}:tool=1..={tools}", s.tool);
            }
            let others: Vec<usize> = (0..3).filter(|&b| b != a).collect();
            if others.iter().any(|&b| s.line[b].is_none()) || s.line[a].is_some() {
                bail!(
                    "{path}: the profile {file} runs along {}: name its line by the two other rest coordinates, in the x column's unit; fix: --data {file}:{}=VALUE,{}=VALUE",
                    c.x_kind.name(),
                    ["x", "y", "z"][others[0]],
                    ["x", "y", "z"][others[1]]
                );
            }
            // rank 0 has the whole mesh: the nodes on the line, broadcast
            let mut on: Vec<f64> = vec![];
            if let Some(m) = sim.global_mesh() {
                let (lo, hi) = m.bounds();
                let tol = s
                    .tol
                    .map_or(1e-6 * eprop::config::distance(hi, lo), |t| t * c.factor[0]);
                let mut hits: Vec<(f64, usize)> = m
                    .points
                    .iter()
                    .enumerate()
                    .filter(|(_, p)| {
                        others
                            .iter()
                            .all(|&b| (p[b] - s.line[b].unwrap_or(0.0) * c.factor[0]).abs() <= tol)
                    })
                    .map(|(g, p)| (p[a], g))
                    .collect();
                hits.sort_by(|p, q| p.0.total_cmp(&q.0));
                hits.dedup_by(|p, q| p.0 == q.0);
                on = hits.iter().flat_map(|&(x, g)| [x, g as f64]).collect();
            }
            broadcast(Some(sim.comm()), &mut on);
            if on.len() < 4 {
                bail!(
                    "{path}: the profile {file}: {} node(s) of the mesh lie on its line ({}); fix: the rest coordinates of a line of nodes (in the x column's unit), or a wider tol=",
                    on.len() / 2,
                    others.iter().map(|&b| format!("{} = {}", ["x", "y", "z"][b], short(s.line[b].unwrap_or(0.0)))).collect::<Vec<_>>().join(", ")
                );
            }
            line = on.chunks(2).map(|p| (p[0], sim.local(p[1] as u32))).collect();
        } else if c.y_kind != YKind::Force {
            match s.node {
                Some(id) => {
                    // rank 0 has the whole mesh and its node ids
                    let g = match sim.global_mesh() {
                        Some(m) => m.node_ids.iter().position(|&x| x == id).map_or(-1.0, |g| g as f64),
                        None => -1.0,
                    };
                    let g = sim.comm().max(g);
                    if g < 0.0 {
                        bail!("{path}: --node {id}: the mesh has no node with that id; fix: a node id of the mesh file (as [[load]] node = ID takes it) for the curve {file}");
                    }
                    node = Some(sim.local(g as u32));
                }
                None if !(1..=loads).contains(&s.load) => bail!(
                    "{path}: the curve {file}'s displacement is a load's probe, and the scenario has {loads} [[load]] table(s) (load {}); fix: a scenario with a [[load]], --load 1..={loads}, or --node ID (or --data {file}:node=ID) for a node's displacement",
                    s.load
                ),
                None => {}
            }
        }
        Ok(Probe {
            x: c.x_kind,
            y: c.y_kind,
            tool: s.tool.saturating_sub(1),
            load: s.load.saturating_sub(1),
            node,
            line,
            xs: vec![],
            ys: vec![],
            deepest: f64::NEG_INFINITY,
        })
    }

    /// The measured quantity of a displacement `d`.
    fn of(&self, d: V3) -> f64 {
        match self.y.component() {
            Some(k) => d[k],
            None => eprop_io::geom::norm(d),
        }
    }

    /// Samples the simulation now (after each step); false when what it sampled is not finite.
    /// The same on every process.
    fn sample(&mut self, sim: &Simulation) -> bool {
        let tool = || sim.tool_states()[self.tool];
        if self.x.axis().is_some() {
            // a profile: at the deepest step of the tool (the last step without a tool)
            let deeper = match sim.tool_states().get(self.tool) {
                Some(t) => t.indentation > self.deepest,
                None => sim.done(),
            };
            if deeper {
                self.deepest = sim.tool_states().get(self.tool).map_or(0.0, |t| t.indentation);
                let u = sim.u();
                let local: Vec<f64> = self
                    .line
                    .iter()
                    .map(|(_, l)| l.map_or(f64::NEG_INFINITY, |i| self.of(u[i])))
                    .collect();
                self.xs = self.line.iter().map(|p| p.0).collect();
                self.ys = sim.comm().max_each(&local);
            }
            return self.ys.iter().all(|v| v.is_finite());
        }
        let x = match self.x {
            XKind::Indentation => tool().indentation,
            _ => sim.time(),
        };
        let y = match (self.y, self.node) {
            (YKind::Force, _) => eprop_io::geom::norm(tool().force),
            (_, None) => self.of(sim.probes()[self.load].1),
            (_, Some(local)) => {
                let none = if self.y.component().is_some() {
                    f64::NEG_INFINITY
                } else {
                    0.0
                };
                sim.comm().max(local.map_or(none, |i| self.of(sim.u()[i])))
            }
        };
        // indentation: the loading branch, the steps where the tool passes its deepest so far
        if self.x == XKind::Time || self.xs.last().is_none_or(|&l| x > l) {
            self.xs.push(x);
            self.ys.push(y);
        }
        x.is_finite() && y.is_finite()
    }

    /// The measured y at the curve's x, or why there is none.
    fn at(&self, c: &Curve) -> std::result::Result<Vec<f64>, String> {
        c.x.iter()
            .map(|&x| interpolate(&self.xs, &self.ys, x))
            .collect::<Option<Vec<f64>>>()
            .ok_or_else(|| {
                let what = match c.x_kind {
                    XKind::Time => "time",
                    XKind::Indentation => "indentation (loading branch)",
                    _ => "profile's nodes along its line",
                };
                format!(
                    "the curve's x {} .. {} is beyond the simulated {what} {:.6e} .. {:.6e} ({})",
                    short(c.x[0]),
                    short(c.x[c.x.len() - 1]),
                    self.xs.first().copied().unwrap_or(f64::NAN),
                    self.xs.last().copied().unwrap_or(f64::NAN),
                    c.spec.file.display()
                )
            })
    }
}

/// One full simulation with the parameter values `p` applied; the measured y at every curve's
/// x (the curves one after the other), or why there is none (a state that is no longer finite,
/// x beyond the simulated range). A request on `stop` (a signal) ends it after the step in
/// progress.
pub(super) fn evaluate(
    world: Option<&dyn Comm>,
    stop: &StopToken,
    scenario: &Path,
    opts: &FitOptions,
    params: &[Param],
    p: &[f64],
    curves: &[Curve],
) -> Result<Outcome> {
    let mut p = p.to_vec();
    broadcast(world, &mut p); // rank 0 decides
    let mut sets = opts.sets.clone();
    sets.extend(params.iter().zip(&p).map(|(q, v)| format!("{}={v:?}", q.key)));
    let make = || Setup::new(Scenario::load_with(scenario, &sets)?);
    let mut sim = match world {
        None => {
            let setup = make()?;
            start_mpi_if_needed(&setup)?;
            Simulation::new(setup)?
        }
        Some(w) => build_mpi(w, make)?.sim,
    };
    sim.set_stop(stop.clone());
    let mut probes = curves
        .iter()
        .map(|c| Probe::new(&sim, scenario, c))
        .collect::<Result<Vec<_>>>()?;
    // every probe samples (a profile's is collective), whatever the others found
    let mut sample_all = |sim: &Simulation| {
        let mut ok = true;
        for p in probes.iter_mut() {
            ok &= p.sample(sim);
        }
        ok
    };
    let mut finite = sample_all(&sim);
    while finite && !sim.done() {
        sim.advance()?;
        if sim.stop_signal() != 0 {
            return Err(Agreed::error(
                EXIT_STOPPED,
                format!(
                    "stopped by {} during an evaluation (step {} of {}); nothing was written",
                    crate::guard::signals::name(sim.stop_signal()),
                    sim.step(),
                    sim.max_steps()
                ),
            ));
        }
        finite = sample_all(&sim);
    }
    let mut out = match finite {
        false => Err(format!(
            "the state is no longer finite at step {} (t = {:.6e})",
            sim.step(),
            sim.time()
        )),
        true => probes
            .iter()
            .zip(curves)
            .map(|(p, c)| p.at(c))
            .collect::<std::result::Result<Vec<Vec<f64>>, String>>()
            .map(|v| v.concat()),
    };
    // the curve is rank 0's (it is the same on every process: the simulation is rank independent)
    if world.is_some() {
        let failed = sim.comm().max(f64::from(u8::from(out.is_err())));
        match out.as_mut() {
            Ok(_) if failed > 0.0 => out = Err("another process had no curve".into()),
            Ok(v) => sim.comm().broadcast(0, v),
            Err(_) => {}
        }
    }
    Ok(out)
}

/// y at x on the polyline (xs increasing); None outside [xs_0, xs_last].
pub(super) fn interpolate(xs: &[f64], ys: &[f64], x: f64) -> Option<f64> {
    let (first, last) = (*xs.first()?, *xs.last()?);
    if !(x >= first && x <= last) {
        return None;
    }
    let k = xs.partition_point(|&v| v <= x);
    if k == xs.len() {
        return Some(ys[xs.len() - 1]);
    }
    let (x0, x1, y0, y1) = (xs[k - 1], xs[k], ys[k - 1], ys[k]);
    Some(y0 + (y1 - y0) * (x - x0) / (x1 - x0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_is_linear_and_bounded() {
        let (xs, ys) = ([0.0, 1.0, 3.0], [0.0, 2.0, 6.0]);
        assert_eq!(interpolate(&xs, &ys, 0.5), Some(1.0));
        assert_eq!(interpolate(&xs, &ys, 2.0), Some(4.0));
        assert_eq!(interpolate(&xs, &ys, 3.0), Some(6.0));
        assert_eq!(interpolate(&xs, &ys, 0.0), Some(0.0));
        assert_eq!(interpolate(&xs, &ys, 3.0001), None);
        assert_eq!(interpolate(&xs, &ys, -1e-12), None);
    }
}
