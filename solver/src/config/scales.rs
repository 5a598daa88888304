//! The magnitudes a run derives from the scenario's parameters, estimated when the scenario is
//! read: each load's contact stress sigma = |F| / A, its energy density q(sigma) (the
//! potential's scale), the coupling's push kappa q^p and, in the continuum reading, its flux
//! source (D / l) q a / V. A product that overflows or underflows double precision is refused
//! before any step (by `eprop check` too), naming the keys, their values and the fix: young =
//! 1e-300 or coupling = 1e300 would otherwise run into inf at the first step, young = 1e300
//! would propagate nothing. The estimates are taken as logarithms (no estimate overflows) with
//! the mesh's typical node spacing for a node's contact area; they lie within a few orders of
//! magnitude of the run's values, far inside the margins `HUGE` and `TINY`. The run-time watch
//! of `guard::plausible` stays: it sees what no estimate can (a live load's samples, say: live
//! loads are not estimated here, so `run` and `serve` stop alike on the same samples).

use super::{Load, Reading, Setup};
use crate::diagnostics::{power_of_ten, short};
use anyhow::{anyhow, Result};

/// A derived magnitude above this is refused: the fields a run writes hold sums of its squares
/// (|phi|, |u|, the energies), which pass f64's 1.8e308 beyond 1.3e154; the margin covers the
/// estimates' factors.
pub(crate) const HUGE: f64 = 1e200;
/// An energy density or a source below this (from positive factors) is refused: it underflows
/// in the run's products, and the load does nothing.
pub(crate) const TINY: f64 = 1e-200;

/// The largest force component of a load over the run (its table's rows, or its force or
/// normal times the ramp's peak scale).
fn peak_force(l: &Load) -> f64 {
    let largest = |f: &[f64]| f.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    match &l.history {
        Some(h) => h.rows().iter().fold(0.0f64, |m, r| m.max(largest(&r[1..]))),
        None => {
            let f = l.normal.map_or_else(|| largest(&l.force), f64::abs);
            let ramp = l
                .ramp
                .as_ref()
                .map_or(1.0, |r| r.iter().fold(0.0f64, |m, p| m.max(p[1].abs())));
            f * ramp
        }
    }
}

/// log10 of the mesh's typical node spacing: the cube root of its bounding box's volume per
/// node (a flat side counts as a millionth of the diagonal).
fn lg_spacing((lo, hi): ([f64; 3], [f64; 3]), n_nodes: usize) -> f64 {
    let diag = super::distance(hi, lo);
    let lg_vol: f64 = (0..3).map(|d| (hi[d] - lo[d]).max(diag * 1e-6).log10()).sum();
    (lg_vol - (n_nodes.max(1) as f64).log10()) / 3.0
}

/// Refuses a scenario whose derived magnitudes overflow or underflow (module docs).
pub fn check(setup: &Setup) -> Result<()> {
    check_with(setup, setup.mesh.bounds(), setup.mesh.n_nodes())
}

/// `check` of a setup on a process's share of a mesh whose whole has these bounds and nodes.
pub fn check_with(setup: &Setup, bounds: ([f64; 3], [f64; 3]), n_nodes: usize) -> Result<()> {
    if n_nodes == 0 {
        return Ok(());
    }
    let path = setup.scenario.path.display();
    let file = &setup.scenario.file;
    let continuum = file.model.reading == Reading::Continuum;
    let (young, beta) = (setup.law.young, setup.law.beta);
    let (kappa, p) = (setup.model.coupling(), setup.model.exponent);
    let lg_ell = lg_spacing(bounds, n_nodes);
    let refuse = |what: String, fix: &str| Err(anyhow!("{path}: {what}; fix: {fix}"));
    let (huge, tiny) = (HUGE.log10(), TINY.log10());
    for (k, l) in setup.loads.iter().enumerate() {
        let f = peak_force(l);
        // a live load's force comes from the client of `eprop serve` (and `run` reads its
        // table as that client would send it): the run-time watch sees it, as in a session
        if l.live || !(f > 0.0) {
            continue;
        }
        let n = k + 1;
        let (lg_a, area) = if l.area > 0.0 {
            (l.area.log10(), format!("{:.3e}", l.area))
        } else {
            let lg = (l.nodes.len().max(1) as f64).log10() + 2.0 * lg_ell;
            (lg, format!("about {}", power_of_ten(lg)))
        };
        let lg_sigma = f.log10() - lg_a;
        let sigma = format!(
            "load {n}'s force {} over its contact area ({area}) is a contact stress sigma of about {}",
            crate::diagnostics::fixed(f, 4),
            power_of_ten(lg_sigma)
        );
        if lg_sigma > huge {
            return refuse(
                format!("{sigma}, above {HUGE:e}: the potential, the displacements and the energies written would overflow to inf"),
                "check the force (in N in the continuum reading) and the mesh's units ([mesh] unit or scale)",
            );
        }
        // q = sigma^2 / (2 young); with beta > 0 and beta sigma / young > 1, about sigma / beta
        let lg_x = if beta > 0.0 {
            beta.log10() + lg_sigma - young.log10()
        } else {
            f64::NEG_INFINITY
        };
        let (lg_q, law) = if lg_x > 0.0 {
            (
                lg_sigma - beta.log10(),
                format!("[tissue] young = {}, beta = {}", short(young), short(beta)),
            )
        } else {
            (
                2.0 * lg_sigma - (2.0 * young).log10(),
                format!("[tissue] young = {}", short(young)),
            )
        };
        let q = format!(
            "{sigma}; with {law} its energy density q(sigma) is about {}",
            power_of_ten(lg_q)
        );
        let fix_law = &format!(
            "[tissue] young in Pa in the continuum reading (soft tissue: kPa, 4 kPa is 4000; the paper reading's default is 100){}, or check the force and the mesh's units",
            if beta > 0.0 { " and a stiffening beta of order 1 to 10" } else { "" }
        );
        if lg_q > huge {
            return refuse(
                format!("{q}, above {HUGE:e}: the potential (of that scale), the displacements and the energies written would overflow to inf"),
                fix_law,
            );
        }
        if lg_q < tiny {
            return refuse(
                format!("{q}, below {TINY:e}: the load's energy source underflows to nothing and its potential never moves the tissue"),
                fix_law,
            );
        }
        if kappa > 0.0 {
            let lg_push = kappa.log10() + p * lg_q;
            let push = format!(
                "{q}; [model] coupling = {}{} times the potential to the power p gives a push of about {}",
                short(kappa),
                if p == 1.0 {
                    String::new()
                } else {
                    format!(" with exponent p = {}", short(p))
                },
                power_of_ten(lg_push)
            );
            let default = file.model.reading.defaults().coupling;
            let fix = format!("a coupling near the reading's default ({}) and an exponent near 1, or coupling = 0 to switch the push off", short(default));
            if lg_push > huge {
                return refuse(
                    format!("{push}, above {HUGE:e}: the displacements and the energies written would overflow to inf"),
                    &fix,
                );
            }
            if lg_push < tiny {
                return refuse(
                    format!(
                        "{push}, below {TINY:e}: it underflows to nothing, so the potential never moves the tissue"
                    ),
                    &fix,
                );
            }
        }
        if continuum {
            // the flux source (D / l) q a / V, with l, a / V and its inverse of the node spacing
            let d = setup
                .materials
                .tissues
                .iter()
                .map(|t| t.r.trace() / 3.0)
                .fold(f64::INFINITY, f64::min);
            let lg_source = d.log10() + lg_q - 2.0 * lg_ell;
            if d > 0.0 && lg_source < tiny {
                return refuse(
                    format!(
                        "{q}; with [material] conductivity {} m^2/s its flux source (D / l) q a / V is about {}, below {TINY:e}: it underflows to nothing and the load does nothing",
                        short(d),
                        power_of_ten(lg_source)
                    ),
                    "[material] conductivity in m^2/s (the continuum default is 0.1), or leave it out",
                );
            }
        }
    }
    Ok(())
}
