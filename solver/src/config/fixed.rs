//! `[[fixed]]`: the Dirichlet set (the union of every set).

use super::select::{Entry, Keys};
use super::Scenario;
use anyhow::{bail, Result};
use eprop_mesh::Mesh;
use serde::de::MapAccess;

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

/// The fixed flag of every node. Every piece of the mesh needs a fixed node of its own,
/// otherwise its energy never leaves.
pub fn resolve(sc: &Scenario, sets: &[Entry<FixedSet>], mesh: &Mesh) -> Result<Vec<bool>> {
    if sets.is_empty() {
        bail!(
            "{}: no [[fixed]] set; fix: fix part of the organ (for example `[[fixed]] group = \"bottom\"`), \
             otherwise energy never leaves the body and the run has no steady state",
            sc.path.display()
        );
    }
    let n = mesh.n_nodes();
    let mut fixed = vec![false; n];
    for e in sets {
        let none = "selects no node; fix: check it against the mesh (eprop info MESH)";
        let set = sc.select(&e.selector, FixedSet::TABLE, mesh, none)?;
        for i in 0..n {
            fixed[i] |= set[i];
        }
    }
    every_piece_held(sc, mesh, &fixed)?;
    Ok(fixed)
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
