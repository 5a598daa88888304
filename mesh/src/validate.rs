//! One validation pass applied to every mesh read, whatever its format.
//!
//! Errors (each names the file, the node or cell, and a fix): non-finite coordinates, node
//! indices out of range, no volume cells, zero-volume cells, duplicate cells, faces shared by
//! more than two cells. Repairs (each leaves a warning): inverted cells are reoriented (an
//! error when `strict`), nodes that no cell uses are dropped (the kept nodes keep their input
//! ids). Several disconnected components are reported as a warning.

use crate::mesh::{group_by_node, Mesh};
use anyhow::{bail, Result};

/// Options of `validate`.
#[derive(Clone, Copy, Debug, Default)]
pub struct ReadOptions {
    /// Refuse inverted cells instead of reorienting them.
    pub strict: bool,
}

/// Checks and repairs a mesh in place.
pub fn validate(mesh: &mut Mesh, opts: &ReadOptions) -> Result<()> {
    let src = mesh.source.clone();
    if mesh.node_ids.len() != mesh.n_nodes() {
        mesh.node_ids = (1..=mesh.n_nodes() as u64).collect();
    }
    check_coordinates(mesh, &src)?;
    check_arrays(mesh, &src)?;
    check_repeated_nodes(mesh, &src)?;
    check_duplicate_cells(mesh, &src)?;
    orient_cells(mesh, &src, opts)?;
    check_manifold(mesh, &src)?;
    drop_unused_nodes(mesh);
    warn_components(mesh);
    Ok(())
}

/// Every coordinate is finite.
fn check_coordinates(mesh: &Mesh, src: &str) -> Result<()> {
    for (n, p) in mesh.points.iter().enumerate() {
        if p.iter().any(|x| !x.is_finite()) {
            bail!(
                "{src}: node {} has a non-finite coordinate ({}, {}, {}); fix: repair or remove the node",
                mesh.node_id(n),
                p[0],
                p[1],
                p[2]
            );
        }
    }
    Ok(())
}

/// There are volume cells; the cell and facet arrays agree with each other, every node index is
/// in range, and the cell count fits eprop's indices.
fn check_arrays(mesh: &Mesh, src: &str) -> Result<()> {
    let np = mesh.n_nodes();
    if mesh.n_cells() == 0 {
        bail!("{src}: no volume cells (tetrahedra, hexahedra, prisms or pyramids); fix: mesh the volume (e.g. gmsh -3 or tetgen), not only its surface");
    }
    if mesh.offsets.len() != mesh.n_cells() + 1 || mesh.cell_tags.len() != mesh.n_cells() {
        bail!("{src}: inconsistent cell arrays; fix: this is a reader bug, report it with the file");
    }
    for c in 0..mesh.n_cells() {
        let (s, e) = (mesh.offsets[c], mesh.offsets[c + 1]);
        if e < s || e > mesh.conn.len() || e - s != mesh.kinds[c].n_nodes() {
            bail!(
                "{src}: cell {} has a wrong node count; fix: repair the cell",
                mesh.cell_id(c)
            );
        }
        if let Some(&bad) = mesh.conn[s..e].iter().find(|&&n| n as usize >= np) {
            bail!(
                "{src}: cell {} names node index {bad}, but the mesh has {np} nodes; fix: repair the cell",
                mesh.cell_id(c)
            );
        }
    }
    for f in 0..mesh.facets.len() {
        let ok = mesh
            .facets
            .offsets
            .get(f + 1)
            .is_some_and(|&e| e <= mesh.facets.conn.len() && mesh.facets.offsets[f] <= e);
        if !ok || mesh.facets.nodes(f).iter().any(|&n| n as usize >= np) {
            bail!(
                "{src}: boundary element {} names a node out of range; fix: repair the element",
                f + 1
            );
        }
    }
    if mesh.n_cells() >= 1 << 29 {
        bail!(
            "{src}: {} cells is more than eprop handles (2^29); fix: split the mesh",
            mesh.n_cells()
        );
    }
    Ok(())
}

/// No node appears twice in one cell.
fn check_repeated_nodes(mesh: &Mesh, src: &str) -> Result<()> {
    for c in 0..mesh.n_cells() {
        let k = sorted_key(mesh.cell(c));
        if k.windows(2).any(|w| w[0] == w[1] && w[0] != u32::MAX) {
            let ids: Vec<u64> = mesh.cell(c).iter().map(|&n| mesh.node_id(n as usize)).collect();
            bail!(
                "{src}: cell {} ({}) repeats a node (nodes {ids:?}) and has zero volume; fix: remove the degenerate cell or re-mesh",
                mesh.cell_id(c),
                mesh.kinds[c].name()
            );
        }
    }
    Ok(())
}

/// No two cells have the same node set: cells grouped by their smallest node, compared within
/// each group (no table of every cell's key).
fn check_duplicate_cells(mesh: &Mesh, src: &str) -> Result<()> {
    let np = mesh.n_nodes();
    let (ptr, cells) = group_by_node(np, mesh.n_cells(), 1, |c, _| mesh.cell(c).iter().min().copied());
    let mut keys: Vec<([u32; 8], u32)> = Vec::new();
    for n in 0..np {
        let g = &cells[ptr[n] as usize..ptr[n + 1] as usize];
        if g.len() < 2 {
            continue;
        }
        keys.clear();
        keys.extend(g.iter().map(|&c| (sorted_key(mesh.cell(c as usize)), c)));
        keys.sort_unstable();
        if let Some(w) = keys.windows(2).find(|w| w[0].0 == w[1].0) {
            bail!(
                "{src}: cells {} and {} are duplicates (same nodes); fix: remove one of them",
                mesh.cell_id(w[0].1 as usize),
                mesh.cell_id(w[1].1 as usize)
            );
        }
    }
    Ok(())
}

/// Zero-volume cells are errors; inverted cells are reoriented with a warning (errors when
/// `strict`).
fn orient_cells(mesh: &mut Mesh, src: &str, opts: &ReadOptions) -> Result<()> {
    let mut flipped = 0usize;
    let mut first = 0u64;
    for c in 0..mesh.n_cells() {
        let kind = mesh.kinds[c];
        let r = mesh.offsets[c]..mesh.offsets[c + 1];
        let nodes: Vec<u32> = mesh.conn[r.clone()].to_vec();
        let v = crate::geom::cell_volume(kind, &nodes, &mesh.points);
        let scale = crate::geom::cell_size(kind, &nodes, &mesh.points);
        let cube = scale.powi(3);
        if !(v.is_finite() && cube.is_finite()) || (scale > 0.0 && !(cube > 0.0)) {
            // a volume of 1e450 or 1e-450 is no number an f64 holds: not a zero volume
            let ids: Vec<u64> = nodes.iter().map(|&n| mesh.node_id(n as usize)).collect();
            let way = if cube.is_finite() {
                "underflows to zero"
            } else {
                "overflows"
            };
            bail!(
                "{src}: cell {} ({}) has edges up to {scale:e} long, so its volume {way} in double precision (nodes {ids:?}); fix: write the coordinates in a length unit that makes the mesh between about 1e-60 and 1e60 across (metres instead of micrometres, say)",
                mesh.cell_id(c),
                kind.name()
            );
        }
        if !(v.abs() > 1e-14 * cube) {
            let ids: Vec<u64> = nodes.iter().map(|&n| mesh.node_id(n as usize)).collect();
            bail!(
                "{src}: cell {} ({}) has zero volume (nodes {ids:?}); fix: remove the degenerate cell or re-mesh",
                mesh.cell_id(c),
                kind.name()
            );
        }
        if v < 0.0 {
            if opts.strict {
                bail!(
                    "{src}: cell {} ({}) is inverted (negative volume); fix: reorder its nodes, or read without --strict to reorient it",
                    mesh.cell_id(c),
                    kind.name()
                );
            }
            for (k, &p) in kind.flip().iter().enumerate() {
                mesh.conn[r.start + k] = nodes[p];
            }
            if flipped == 0 {
                first = mesh.cell_id(c);
            }
            flipped += 1;
        }
    }
    if flipped > 0 {
        mesh.warnings
            .push(format!("{flipped} inverted cell(s) reoriented (first: cell {first})"));
    }
    Ok(())
}

/// No face is shared by more than two cells.
fn check_manifold(mesh: &Mesh, src: &str) -> Result<()> {
    crate::mesh::for_each_face(mesh, |key, cells| {
        if cells.len() > 2 {
            let ids: Vec<u64> = key
                .iter()
                .filter(|&&n| n != u32::MAX)
                .map(|&n| mesh.node_id(n as usize))
                .collect();
            let cells: Vec<u64> = cells.iter().map(|f| mesh.cell_id(f.0 as usize)).collect();
            bail!(
                "{src}: the face with nodes {ids:?} is shared by {} cells ({cells:?}); a face may bound at most two cells (non-manifold); fix: remove the overlapping cells or re-mesh",
                cells.len()
            );
        }
        Ok(())
    })
}

/// Drops the nodes no cell uses, with a warning; the others keep their input ids, and boundary
/// elements on dropped nodes go too.
fn drop_unused_nodes(mesh: &mut Mesh) {
    let np = mesh.n_nodes();
    let mut used = vec![false; np];
    for &n in &mesh.conn {
        used[n as usize] = true;
    }
    let unused = used.iter().filter(|&&u| !u).count();
    if unused == 0 {
        return;
    }
    let mut map = vec![u32::MAX; np];
    let mut k = 0u32;
    for n in 0..np {
        if used[n] {
            map[n] = k;
            k += 1;
        }
    }
    let first = (0..np).find(|&n| !used[n]).map(|n| mesh.node_id(n)).unwrap_or(0);
    mesh.points = (0..np).filter(|&n| used[n]).map(|n| mesh.points[n]).collect();
    mesh.node_ids = (0..np).filter(|&n| used[n]).map(|n| mesh.node_ids[n]).collect();
    for n in &mut mesh.conn {
        *n = map[*n as usize];
    }
    let old = std::mem::replace(&mut mesh.facets, crate::mesh::Facets::new());
    let mut lost = 0usize;
    for f in 0..old.len() {
        let nodes: Vec<u32> = old.nodes(f).iter().map(|&n| map[n as usize]).collect();
        if nodes.contains(&u32::MAX) {
            lost += 1;
        } else {
            mesh.facets.push(old.dim[f], old.tags[f], &nodes);
        }
    }
    let extra = if lost > 0 {
        format!("; {lost} boundary element(s) on them dropped too")
    } else {
        String::new()
    };
    mesh.warnings.push(format!(
        "{unused} node(s) used by no cell dropped (first: node {first}); the others keep their ids{extra}"
    ));
}

/// Several connected components (over shared nodes; every node is in a cell by now) are a
/// warning: each needs its own fixed set.
fn warn_components(mesh: &mut Mesh) {
    let (_, comps) = crate::mesh::components(mesh);
    if comps > 1 {
        mesh.warnings.push(format!(
            "the mesh has {comps} disconnected components; each needs its own fixed set (a free component drifts)"
        ));
    }
}

/// The nodes of a cell, sorted, padded with `u32::MAX` (cells have at most 8 nodes).
fn sorted_key(nodes: &[u32]) -> [u32; 8] {
    let mut k = [u32::MAX; 8];
    for (d, &n) in k.iter_mut().zip(nodes) {
        *d = n;
    }
    k.sort_unstable();
    k
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::CellKind;

    fn two_tets() -> Mesh {
        let mut m = Mesh::new("t");
        m.points = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [9.0; 3],
        ];
        m.node_ids = vec![10, 20, 30, 40, 50, 60];
        m.push_cell(CellKind::Tet, &[0, 1, 2, 3], 1);
        m.push_cell(CellKind::Tet, &[0, 1, 2, 4], 1); // inverted
        m
    }

    #[test]
    fn repairs_keep_input_ids() {
        let mut m = two_tets();
        validate(&mut m, &ReadOptions::default()).unwrap();
        assert_eq!(m.node_ids, vec![10, 20, 30, 40, 50]);
        assert_eq!(m.cell(1), &[0, 2, 1, 4]);
        assert_eq!(m.warnings.len(), 2, "{:?}", m.warnings);
        let e = validate(&mut two_tets(), &ReadOptions { strict: true })
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("cell 2") && e.contains("inverted") && e.contains("fix:"),
            "{e}"
        );
    }

    #[test]
    fn defects_name_nodes_and_cells() {
        let mut m = two_tets();
        m.points[3][1] = f64::NAN;
        let e = validate(&mut m, &ReadOptions::default()).unwrap_err().to_string();
        assert!(e.contains("node 40") && e.contains("non-finite"), "{e}");
        let mut m = two_tets();
        m.push_cell(CellKind::Tet, &[3, 2, 1, 0], 1);
        let e = validate(&mut m, &ReadOptions::default()).unwrap_err().to_string();
        assert!(e.contains("cells 1 and 3 are duplicates"), "{e}");
        // coordinates whose volume overflows or underflows (it said "zero volume")
        for (f, way) in [(1e150, "overflows"), (1e-150, "underflows to zero")] {
            let mut m = two_tets();
            m.points.iter_mut().flatten().for_each(|x| *x *= f);
            let e = validate(&mut m, &ReadOptions::default()).unwrap_err().to_string();
            assert!(
                e.contains(&format!("its volume {way}")) && !e.contains("zero volume") && e.contains("fix:"),
                "{e}"
            );
        }
        let mut m = two_tets();
        m.conn[7] = 99;
        let e = validate(&mut m, &ReadOptions::default()).unwrap_err().to_string();
        assert!(e.contains("cell 2 names node index 99"), "{e}");
    }
}
