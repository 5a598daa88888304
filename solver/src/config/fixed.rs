//! `[[fixed]]`: the Dirichlet set (the union of every set).

use super::select::{Entry, Keys, Selector};
use super::Scenario;
use anyhow::{bail, Result};
use eprop_io::geom::{cross, dot, norm, scale, sub};
use eprop_mesh::Mesh;
use serde::de::MapAccess;
use serde::{Deserialize, Serialize};

/// A fixed support's plane (docs/model.md section 6): the organ lies on the side opposite
/// `normal`; a node whose deformed position lies more than `tol` along `normal` from `point`
/// has gone through the support.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Plane {
    pub point: [f64; 3],
    /// Unit, from the organ into the support.
    pub normal: [f64; 3],
    /// 1e-9 of the mesh's diagonal (the half-space selector's own tolerance).
    pub tol: f64,
}

impl Plane {
    /// How far y lies across the plane (positive: through the support).
    pub fn across(&self, y: [f64; 3]) -> f64 {
        dot(sub(y, self.point), self.normal)
    }
}

/// A `[[fixed]]` table: a selector and nothing else.
#[derive(Clone, Debug, Default)]
pub struct FixedSet;

impl Keys for FixedSet {
    const TABLE: &'static str = "fixed";
    const CHOOSES: &'static str = "a fixed set";
    const SELECTORS: &'static [&'static str] = &["box", "sphere", "halfspace", "nodes", "tag", "group"];
    const OWN: &'static [&'static str] = &[];
    fn read<'de, A: MapAccess<'de>>(&mut self, _: &str, _: &mut A) -> Result<(), A::Error> {
        Ok(())
    }
}

/// The fixed flag of every node, and the supports' planes (`support_plane`). Every piece of
/// the mesh needs a fixed node of its own, otherwise its energy never leaves.
pub fn resolve(sc: &Scenario, sets: &[Entry<FixedSet>], mesh: &Mesh) -> Result<(Vec<bool>, Vec<Plane>)> {
    if sets.is_empty() {
        bail!(
            "{}: no [[fixed]] set; fix: fix part of the organ (for example `[[fixed]] group = \"bottom\"`), \
             otherwise energy never leaves the body and the run has no steady state",
            sc.path.display()
        );
    }
    let n = mesh.n_nodes();
    let mut fixed = vec![false; n];
    let mut planes = Vec::new();
    for e in sets {
        let none = "selects no node; fix: check it against the mesh (eprop info MESH)";
        let set = sc.select(&e.selector, FixedSet::TABLE, mesh, none)?;
        if set.iter().all(|&b| b) {
            let (lo, hi) = mesh.bounds();
            return Err(sc.error_at(
                e.selector.span(),
                FixedSet::TABLE,
                e.selector.get_ref().key(),
                format!(
                    "selects every node of the mesh, so nothing can move (the mesh spans {}{}); fix: select the part that is held, in the mesh's coordinates as read",
                    crate::diagnostics::span(lo, hi),
                    super::unit_note(sc)
                ),
            ));
        }
        for i in 0..n {
            fixed[i] |= set[i];
        }
        planes.extend(support_plane(e.selector.get_ref(), &set, mesh));
    }
    every_piece_held(sc, mesh, &fixed)?;
    Ok((fixed, planes))
}

/// The plane of a fixed set that supports the organ from one side, or None: a half-space's
/// boundary (the organ's free nodes lie outside it); any other set whose nodes lie in one
/// plane (within 1e-9 of the mesh's diagonal) with the whole mesh on one side of it (a fixed
/// face: `group = "bottom"`, a flat box).
pub(crate) fn support_plane(selector: &Selector, set: &[bool], mesh: &Mesh) -> Option<Plane> {
    let (lo, hi) = mesh.bounds();
    let tol = 1e-9 * norm(sub(hi, lo));
    if let Some(p) = half_space_plane(selector, tol) {
        return Some(p);
    }
    let pts: Vec<[f64; 3]> = (0..set.len()).filter(|&i| set[i]).map(|i| mesh.points[i]).collect();
    let a = *pts.first()?;
    let far = |from: &dyn Fn([f64; 3]) -> f64| {
        pts.iter()
            .copied()
            .max_by(|p, q| from(*p).total_cmp(&from(*q)))
            .unwrap_or(a)
    };
    plane_of_set(a, tol, &far, &|t| pts.iter().any(|&p| t(p)), &|t| {
        mesh.points.iter().any(|&p| t(p))
    })
}

/// A half-space selector's boundary plane (unit normal), None for another selector.
pub(crate) fn half_space_plane(selector: &Selector, tol: f64) -> Option<Plane> {
    let Selector::HalfSpace(h) = selector else {
        return None;
    };
    let n = norm(h.normal);
    Some(Plane {
        point: h.point,
        normal: scale(h.normal, 1.0 / n),
        tol,
    })
}

/// The plane of a set whose first point is `a`, if its points lie in one plane (within
/// `tol`) with the mesh on one side: through `a`, the point `far` from it and the point
/// farthest from that line. `far(from)` is the set's point of largest `from` (ties: the
/// highest index), `set_any(t)` and `mesh_any(t)` whether `t` holds at a point of the set and
/// of the mesh (whole, or by reductions over the processes: `config::local`).
pub(crate) fn plane_of_set(
    a: [f64; 3],
    tol: f64,
    far: &dyn Fn(&dyn Fn([f64; 3]) -> f64) -> [f64; 3],
    set_any: &dyn Fn(&dyn Fn([f64; 3]) -> bool) -> bool,
    mesh_any: &dyn Fn(&dyn Fn([f64; 3]) -> bool) -> bool,
) -> Option<Plane> {
    let b = far(&|p| norm(sub(p, a)));
    let ab = sub(b, a);
    let c = far(&|p| norm(cross(ab, sub(p, a))));
    let nn = cross(ab, sub(c, a));
    let m = norm(nn);
    if !(m > 0.0) || !m.is_finite() {
        return None;
    }
    let normal = scale(nn, 1.0 / m);
    if set_any(&|p| dot(sub(p, a), normal).abs() > tol) {
        return None;
    }
    let side = |p: [f64; 3]| dot(sub(p, a), normal);
    let normal = if !mesh_any(&|p| side(p) > tol) {
        normal
    } else if !mesh_any(&|p| side(p) < -tol) {
        scale(normal, -1.0)
    } else {
        return None;
    };
    Some(Plane { point: a, normal, tol })
}

fn every_piece_held(sc: &Scenario, mesh: &Mesh, fixed: &[bool]) -> Result<()> {
    let n = mesh.n_nodes();
    let (comp, ncomp) = eprop_io::mesh::components(mesh);
    if ncomp <= 1 {
        return Ok(());
    }
    let mut has_cells = vec![false; ncomp];
    let mut held = vec![false; ncomp];
    let mut size = vec![0usize; ncomp];
    for c in 0..mesh.n_cells() {
        has_cells[comp[mesh.cell(c)[0] as usize] as usize] = true;
    }
    for i in 0..n {
        size[comp[i] as usize] += 1;
        held[comp[i] as usize] |= fixed[i];
    }
    if let Some(q) = (0..ncomp).find(|&q| has_cells[q] && !held[q]) {
        let any = (0..n).find(|&i| comp[i] as usize == q).unwrap_or(0);
        bail!(
            "{}: the mesh has {} separate pieces and the one with node {} ({} nodes) holds no fixed node; \
             fix: add a [[fixed]] set on that piece (every piece needs its own)",
            sc.path.display(),
            has_cells.iter().filter(|&&b| b).count(),
            mesh.node_ids[any],
            size[q]
        );
    }
    Ok(())
}
