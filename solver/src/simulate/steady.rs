//! `[time] equilibrium = tol` (docs/model.md section 6): a run stops once its state satisfies
//! the steady equations to tol, not when max |v| alone is small. Judged after a step whose
//! max |v| is below tol (the cheap test first): the potential's residual L phi + Q relative to
//! max(|Q|, |L phi|), and the mechanics' f - k_e u + kappa |phi|^(p-1) phi relative to the
//! largest of its three terms, both over the active nodes no tool holds (a held node's
//! potential and place are the contact's); max
//! norms over every process (exact maxima, so the same stop on any number of processes).

use super::{load_sources, Flux, Simulation};
use crate::config::{Reading, Stop};
use crate::linalg::V3;
use eprop_io::geom::{add, norm, scale};

/// The relative residuals of the steady equations: the potential's and the mechanics'.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Residuals {
    pub potential: f64,
    pub mechanics: f64,
}

impl Residuals {
    /// Both at most `tol`.
    pub fn within(&self, tol: f64) -> bool {
        self.potential <= tol && self.mechanics <= tol
    }
}

/// r / s, 0 when both are 0 (nothing to balance), infinite when only s is.
fn relative(r: f64, s: f64) -> f64 {
    if s > 0.0 {
        r / s
    } else if r > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }
}

impl Simulation {
    /// The relative residuals of the steady equations in the current state, with the loads and
    /// tools at the current time (every process calls: one operator application and one
    /// reduction; nothing of the run changes).
    pub fn residuals(&mut self) -> Residuals {
        let n = self.numbering.n_owned;
        let applied = self.applied(self.time);
        let flux = Flux::of(&self.setup, &self.dual.vol);
        let mut q = load_sources(&self.loads, &self.load_local, &applied, flux);
        if !self.tools.is_empty() {
            let nodes = super::nodes_of(&self.surface, &self.active, &self.setup, &self.dual);
            let conductivity = (self.setup.model.reading == Reading::Continuum).then_some(&self.setup.materials);
            for t in &self.tools {
                // a copy: the sources record the tool's path
                t.clone()
                    .sources(self.time, &nodes, &self.setup.law, conductivity, &mut q);
            }
        }
        let mut source = vec![[0.0; 3]; n];
        for &(i, qi) in &q {
            source[i as usize] = add(source[i as usize], qi);
        }
        let mut force = vec![[0.0; 3]; n];
        for (mine, a) in self.load_local.iter().zip(&applied) {
            for &(i, _, fw, _) in mine {
                force[i as usize] = add(force[i as usize], scale(a.force, fw));
            }
        }
        let mut x = self.prop.phi.clone();
        let mut lphi = vec![[0.0; 3]; self.prop.phi.len()];
        self.prop.apply_to(&mut x, &mut lphi);
        // the nodes a tool holds: their equation is the contact's
        let held = |i: usize| {
            let xi = add(self.setup.mesh.points[i], self.u[i]);
            self.tools
                .iter()
                .any(|t| super::kinematic::touches(&t.tool.shape, t.state.position, xi))
        };
        let (mat, p) = (&self.setup.materials, self.setup.model.exponent);
        let mut m = [0.0f64; 4];
        for i in (0..n).filter(|&i| self.active[i]) {
            // a held node's potential is the contact's (a Dirichlet value), its mechanics too
            if !self.tools.is_empty() && held(i) {
                continue;
            }
            let (l, s) = (lphi[i], source[i]);
            m[0] = m[0].max(norm(add(l, s)));
            m[1] = m[1].max(norm(l).max(norm(s)));
            let t = mat.at(i);
            let ph = self.prop.phi[i];
            let mag = norm(ph);
            let push = if p == 1.0 {
                t.coupling
            } else if mag > 0.0 {
                t.coupling * mag.powf(p - 1.0)
            } else {
                0.0
            };
            let (f, ku, pp) = (force[i], scale(self.u[i], t.stiffness), scale(ph, push));
            let r: V3 = [f[0] - ku[0] + pp[0], f[1] - ku[1] + pp[1], f[2] - ku[2] + pp[2]];
            m[2] = m[2].max(norm(r));
            m[3] = m[3].max(norm(f).max(norm(ku)).max(norm(pp)));
        }
        let m = self.comm.max_each(&m);
        Residuals {
            potential: relative(m[0], m[1]),
            mechanics: relative(m[2], m[3]),
        }
    }

    /// After a step of a run to equilibrium: the residuals when max |v| passed (None
    /// otherwise, and in other runs); every process calls (max |v| is agreed).
    pub(super) fn judge_steady(&mut self) {
        self.steady = match self.setup.time.stop {
            Stop::Equilibrium { tol, .. } if self.max_speed < tol => {
                let r = self.residuals();
                // an integrator whose fixed point is the steady state only to its solves'
                // tolerance solves tighter from here (the same verdict on every process)
                if r.potential > tol {
                    self.stepper.tighten(0.1 * tol / r.potential);
                }
                Some(r)
            }
            _ => None,
        };
    }

    /// The residuals of the last step of a run to equilibrium, when its max |v| was below the
    /// tolerance (`residuals`).
    pub fn steady_residuals(&self) -> Option<Residuals> {
        self.steady
    }
}
