//! The checks `eprop_mesh::validate` makes of a whole mesh, made of a VTKHDF mesh read in
//! slabs (`slabs::start`) with no process holding the whole mesh: the same refusals and
//! warnings, with the same messages (the same node and cell named: the first in the whole
//! mesh's order).
//!
//! - coordinates: each process its slab of points (`coordinates`);
//! - cells: each cell by the process that owns its lowest global node, which holds every
//!   cell touching that node (`redistribute`'s one layer of halo cells): repeated nodes,
//!   duplicate cells (grouped by their lowest node), volumes and orientation, faces shared by
//!   more than two cells (grouped by the face's lowest node) (`cells`);
//! - components: labels (the lowest global node of each component) propagated over the local
//!   meshes and the halo exchange until no process changes one (`config::local::piece_labels`,
//!   counted by `components`).
//!
//! A check fails where the first offender (lowest global index) is: that process's message
//! is the error (`first`), every other process's is `ReportedElsewhere`.

use super::comm::Comm;
use super::parts::ReportedElsewhere;
use super::slabs::Local;
use anyhow::{anyhow, Result};
use eprop_mesh::mesh::face_key;
use eprop_mesh::CellKind;
use eprop_series::vtkhdf::MeshSlab;

/// A check's first offender on this process: its global index (the order of the whole
/// mesh's check) and the message the whole mesh's check gives for it.
type Found = Option<(u64, String)>;

/// The first failure of a sequence of checks over every process (every process calls with
/// the same number of checks): the first check that fails anywhere, at its lowest index. The
/// process that found it returns its message, the others `ReportedElsewhere`.
pub fn first(comm: &dyn Comm, checks: Vec<Found>) -> Result<()> {
    // the max of the negated indices: the min (indices are below 2^53: nodes and cells)
    let mine: Vec<f64> = checks
        .iter()
        .map(|f| f.as_ref().map_or(f64::NEG_INFINITY, |(k, _)| -(*k as f64)))
        .collect();
    let all = comm.max_each(&mine);
    let Some(k) = all.iter().position(|x| x.is_finite()) else {
        return Ok(());
    };
    match &checks[k] {
        Some((at, msg)) if -(*at as f64) == all[k] => Err(anyhow!("{msg}")),
        _ => Err(ReportedElsewhere.into()),
    }
}

/// Every coordinate of the slab's points is finite (the whole mesh's first check).
pub fn coordinates(slab: &MeshSlab, src: &str) -> Found {
    let (n, p) = slab
        .points
        .iter()
        .enumerate()
        .find(|(_, p)| p.iter().any(|x| !x.is_finite()))?;
    Some((
        (slab.node_start + n) as u64,
        format!(
            "{src}: node {} has a non-finite coordinate ({}, {}, {}); fix: repair or remove the node",
            slab.node_ids[n], p[0], p[1], p[2]
        ),
    ))
}

/// The whole mesh has volume cells and no more than eprop handles (every process knows the
/// count).
pub fn count(cells: usize, src: &str) -> Result<()> {
    if cells == 0 {
        anyhow::bail!("{src}: no volume cells (tetrahedra, hexahedra, prisms or pyramids); fix: mesh the volume (e.g. gmsh -3 or tetgen), not only its surface");
    }
    if cells >= 1 << 29 {
        anyhow::bail!("{src}: {cells} cells is more than eprop handles (2^29); fix: split the mesh");
    }
    Ok(())
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

/// The checks of the cells of a process's share (before any scaling, as the whole mesh is
/// checked as read), in the whole mesh's order: repeated nodes, duplicate cells, volumes and
/// orientation (an inverted cell refused, as `strict` does), non-manifold faces. Each cell is
/// checked by the owner of its lowest node, each face by the owner of its lowest node; cells
/// and faces are grouped by that node as the whole mesh's check groups them (4 bytes an item).
pub fn cells(local: &Local, src: &str) -> Vec<Found> {
    let n_owned = local.n_owned;
    let owned = &local.global[..n_owned];
    let halo = &local.global[n_owned..];
    let at = |g: u32| -> u32 {
        match owned.binary_search(&g) {
            Ok(k) => k as u32,
            Err(_) => (n_owned + halo.binary_search(&g).expect("a node of a local cell")) as u32,
        }
    };
    let cells = &local.cells;
    // the cells' nodes in local indices (owned nodes come first, in increasing global order)
    let lconn: Vec<u32> = cells.conn.iter().map(|&g| at(g)).collect();
    let lcell = |c: usize| &lconn[cells.offsets[c]..cells.offsets[c + 1]];
    let n_local = local.global.len();
    let id = |c: usize| cells.ids[c] + 1;
    let ids_of = |nodes: &[u32]| -> Vec<u64> { nodes.iter().map(|&l| local.node_ids[l as usize]).collect() };
    // the local index of a cell's lowest node (global order), if this process owns it
    let lowest = |c: usize| -> Option<u32> {
        let (k, _) = cells.cell(c).iter().enumerate().min_by_key(|&(_, &g)| g)?;
        let l = lcell(c)[k];
        ((l as usize) < n_owned).then_some(l)
    };
    // repeated nodes: the first cell (local cells come in increasing global order)
    let repeated = (0..cells.len())
        .filter(|&c| lowest(c).is_some())
        .find(|&c| sorted_key(cells.cell(c)).windows(2).any(|w| w[0] == w[1] && w[0] != u32::MAX))
        .map(|c| {
            let ids = ids_of(lcell(c));
            (
                cells.ids[c],
                format!(
                    "{src}: cell {} ({}) repeats a node (nodes {ids:?}) and has zero volume; fix: remove the degenerate cell or re-mesh",
                    id(c),
                    cells.kinds[c].name()
                ),
            )
        });
    // duplicates: the cells grouped by their lowest node, the first pair of the lowest group
    let duplicate = {
        let (ptr, items) = eprop_mesh::mesh::group_by_node(n_local, cells.len(), 1, |c, _| lowest(c));
        let mut keys: Vec<([u32; 8], u64, u32)> = Vec::new();
        (0..n_owned).find_map(|n| {
            let g = &items[ptr[n] as usize..ptr[n + 1] as usize];
            if g.len() < 2 {
                return None;
            }
            keys.clear();
            keys.extend(
                g.iter()
                    .map(|&c| (sorted_key(cells.cell(c as usize)), cells.ids[c as usize], c)),
            );
            keys.sort_unstable();
            let w = keys.windows(2).find(|w| w[0].0 == w[1].0)?;
            Some((
                u64::from(owned[n]),
                format!(
                    "{src}: cells {} and {} are duplicates (same nodes); fix: remove one of them",
                    id(w[0].2 as usize),
                    id(w[1].2 as usize)
                ),
            ))
        })
    };
    let volume = (0..cells.len())
        .filter(|&c| lowest(c).is_some())
        .find_map(|c| volume(local, lcell(c), c, src).map(|m| (cells.ids[c], m)));
    // non-manifold faces: the faces grouped by their lowest node, the first face of more than two cells
    let manifold = {
        let face_at = |c: usize, f: usize| -> Option<u32> {
            let face = cells.kinds[c].faces().get(f)?;
            let low = face_key(cells.cell(c), face)[0];
            let k = cells.cell(c).iter().position(|&g| g == low)?;
            let l = lcell(c)[k];
            ((l as usize) < n_owned).then_some(l)
        };
        let (ptr, items) = eprop_mesh::mesh::group_by_node(n_local, cells.len(), 8, face_at);
        let mut keys: Vec<([u32; 4], u64, u32)> = Vec::new();
        (0..n_owned).find_map(|n| {
            keys.clear();
            keys.extend(items[ptr[n] as usize..ptr[n + 1] as usize].iter().map(|&it| {
                let (c, f) = ((it >> 3) as usize, (it & 7) as usize);
                (face_key(cells.cell(c), cells.kinds[c].faces()[f]), cells.ids[c], c as u32)
            }));
            keys.sort_unstable();
            let g = keys.chunk_by(|a, b| a.0 == b.0).find(|g| g.len() > 2)?;
            let key = g[0].0;
            let ids: Vec<u64> = key
                .iter()
                .filter(|&&n| n != u32::MAX)
                .map(|&n| local.node_ids[at(n) as usize])
                .collect();
            let on: Vec<u64> = g.iter().map(|f| id(f.2 as usize)).collect();
            Some((
                u64::from(key[0]),
                format!(
                    "{src}: the face with nodes {ids:?} is shared by {} cells ({on:?}); a face may bound at most two cells (non-manifold); fix: remove the overlapping cells or re-mesh",
                    on.len()
                ),
            ))
        })
    };
    vec![repeated, duplicate, volume, manifold]
}

/// The whole mesh's verdict on one cell's volume (read strictly): a volume out of double
/// precision's range, zero, or negative (inverted) is refused.
fn volume(local: &Local, nodes: &[u32], c: usize, src: &str) -> Option<String> {
    let cells = &local.cells;
    let kind: CellKind = cells.kinds[c];
    let v = eprop_mesh::geom::cell_volume(kind, nodes, &local.points);
    let scale = eprop_mesh::geom::cell_size(kind, nodes, &local.points);
    let cube = scale.powi(3);
    let id = cells.ids[c] + 1;
    let ids = || -> Vec<u64> { nodes.iter().map(|&n| local.node_ids[n as usize]).collect() };
    if !(v.is_finite() && cube.is_finite()) || (scale > 0.0 && !(cube > 0.0)) {
        let way = if cube.is_finite() {
            "underflows to zero"
        } else {
            "overflows"
        };
        return Some(format!(
            "{src}: cell {id} ({}) has edges up to {scale:e} long, so its volume {way} in double precision (nodes {:?}); fix: write the coordinates in a length unit that makes the mesh between about 1e-60 and 1e60 across (metres instead of micrometres, say)",
            kind.name(),
            ids()
        ));
    }
    if !(v.abs() > 1e-14 * cube) {
        return Some(format!(
            "{src}: cell {id} ({}) has zero volume (nodes {:?}); fix: remove the degenerate cell or re-mesh",
            kind.name(),
            ids()
        ));
    }
    if v < 0.0 {
        return Some(format!(
            "{src}: cell {id} ({}) is inverted (negative volume); fix: reorder its nodes, or read without --strict to reorient it",
            kind.name()
        ));
    }
    None
}

/// How many pieces (connected components) the whole mesh has: the pieces named by one of
/// their own owned nodes (`config::local::piece_labels`), summed over the processes.
pub fn components(pieces: &[f64], gid: &[u32], n_owned: usize, comm: &dyn Comm) -> usize {
    let own = (0..n_owned).filter(|&i| pieces[i] == f64::from(gid[i])).count();
    comm.sum_i128(own as i128) as usize
}

/// The whole mesh's warning about several components.
pub fn components_warning(comps: usize) -> Option<String> {
    (comps > 1).then(|| {
        format!("the mesh has {comps} disconnected components; each needs its own fixed set (a free component drifts)")
    })
}
