//! The mesh-quality report of the compact operator: which part of a mesh sets forward
//! Euler's substep. Per-node Gershgorin bounds of the operator, their median, the nodes far
//! above it, and for the stiffest nodes the cell that contributes most to their row (on real
//! organ meshes: slivers, flat tetrahedra with a dihedral angle near 180 degrees, whose
//! coefficients a_ij are large against the control volume). `eprop info` and `eprop check`
//! print it so that a user knows which cells to repair.

use crate::config::tissue::{Materials, Tensor};
use crate::discretize::geometry::tet_gradients;
use crate::discretize::operator::Compact;
use eprop_io::geom::cell_quality;
use eprop_mesh::{CellKind, Mesh};
use nalgebra::Vector3;
use serde::Serialize;

/// How many of the stiffest nodes a report names.
pub(crate) const NAMED: usize = 5;
/// A node is "far above" the median when its bound is this many times the median's.
pub(crate) const FAR: f64 = 10.0;

/// A cell, as the mesh file names it.
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct StiffCell {
    /// The cell's id in the mesh file.
    pub id: u64,
    pub kind: String,
    /// Shape quality (1 = regular, 0 = flat).
    pub quality: f64,
    pub volume: f64,
    /// Share of the node's Gershgorin bound that comes from this cell (tetrahedra).
    pub share: f64,
}

/// One of the nodes with the largest bounds.
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct StiffNode {
    /// The node's id in the mesh file.
    pub id: u64,
    pub position: [f64; 3],
    /// The largest stable Euler substep of its row alone, 2 / (Gershgorin bound).
    pub h: f64,
    /// Its bound over the median node's.
    pub ratio: f64,
    /// The incident cell that contributes most to its row.
    pub cell: Option<StiffCell>,
}

/// Per-node stiffness of an operator.
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct Stiffness {
    /// Nodes with a row (that move).
    pub nodes: usize,
    /// The Euler substep the median node alone would allow, and the stiffest node's (which
    /// sets the substep of the whole mesh).
    pub median_h: f64,
    pub worst_h: f64,
    /// Nodes whose bound is more than FAR times the median's.
    pub far_above: usize,
    /// The NAMED stiffest nodes, stiffest first.
    pub stiffest: Vec<StiffNode>,
}

/// The median of the positive values (0 when there is none).
pub(crate) fn median_positive(g: &[f64]) -> f64 {
    let mut v: Vec<f64> = g.iter().copied().filter(|&x| x > 0.0).collect();
    if v.is_empty() {
        return 0.0;
    }
    let k = v.len() / 2;
    *v.select_nth_unstable_by(k, f64::total_cmp).1
}

/// Stiffness of `op` on `mesh` (the operator's rows are the mesh's first nodes, in its
/// numbering); `vol` the capacities of its rows (`geometry::capacities`: the control volumes
/// when no tissue weighs) and `r` the conductivity and young of every node; `cell_id`
/// the file's id of a cell.
pub(crate) fn analyse(
    mesh: &Mesh,
    op: &Compact,
    vol: &[f64],
    r: &Materials,
    cell_id: &dyn Fn(usize) -> u64,
) -> Stiffness {
    let g = op.row_bounds();
    let med = median_positive(&g);
    let nodes = g.iter().filter(|&&x| x > 0.0).count();
    let far_above = g.iter().filter(|&&x| x > FAR * med).count();
    let mut order: Vec<usize> = (0..g.len()).filter(|&i| g[i] > 0.0).collect();
    // stiffest first, ties by index
    let stiffer = |a: &usize, b: &usize| g[*b].total_cmp(&g[*a]).then(a.cmp(b));
    let k = NAMED.min(order.len());
    if k > 0 && k < order.len() {
        order.select_nth_unstable_by(k - 1, stiffer);
    }
    order.truncate(k);
    order.sort_by(stiffer);
    // the incident cell of each named node that weighs most in its row
    let mut best: Vec<Option<(f64, usize)>> = vec![None; k];
    for c in 0..mesh.n_cells() {
        let cell = mesh.cell(c);
        for (slot, &i) in order.iter().enumerate() {
            let Some(li) = cell.iter().position(|&v| v as usize == i) else {
                continue;
            };
            let w = cell_weight(mesh, c, li, r);
            if best[slot].is_none_or(|(bw, bc)| w > bw || (w == bw && c < bc)) {
                best[slot] = Some((w, c));
            }
        }
    }
    let h = |x: f64| if x > 0.0 { 2.0 / x } else { f64::INFINITY };
    let stiffest = order
        .iter()
        .zip(&best)
        .map(|(&i, b)| {
            StiffNode {
                id: mesh.node_id(i),
                position: mesh.points[i],
                h: h(g[i]),
                ratio: if med > 0.0 { g[i] / med } else { 0.0 },
                cell: b.map(|(w, c)| {
                    let kind = mesh.kinds[c];
                    let nodes = mesh.cell(c);
                    StiffCell {
                        id: cell_id(c),
                        kind: kind.name().to_string(),
                        quality: cell_quality(kind, nodes, &mesh.points),
                        volume: eprop_io::geom::cell_volume(kind, nodes, &mesh.points),
                        // the cell's |a_ik| / V_i count twice in the row's bound (diagonal
                        // and off-diagonal), exactly when every coefficient is positive
                        share: if kind == CellKind::Tet {
                            (2.0 * w / (vol[i] * g[i])).min(1.0)
                        } else {
                            f64::NAN
                        },
                    }
                }),
            }
        })
        .collect();
    Stiffness {
        nodes,
        median_h: h(med),
        worst_h: h(g.iter().copied().fold(0.0, f64::max)),
        far_above,
        stiffest,
    }
}

/// A cell's weight in row `i` (its local node `li`): sum over its other nodes k of
/// |a_ik^cell| = |V grad N_i . R grad N_k| for tetrahedra; for other kinds, 1 - quality (the
/// flattest incident cell).
fn cell_weight(mesh: &Mesh, c: usize, li: usize, r: &Materials) -> f64 {
    let kind = mesh.kinds[c];
    let nodes = mesh.cell(c);
    if kind != CellKind::Tet {
        return 1.0 - cell_quality(kind, nodes, &mesh.points);
    }
    let (gr, v) = tet_gradients(nodes, &mesh.points);
    let mut rc = Tensor::zeros();
    for &n in nodes {
        rc += r.r(n as usize);
    }
    rc /= 4.0;
    if r.weighs_young() {
        rc *= crate::discretize::geometry::cell_young(nodes, r);
    }
    let gi = rc * Vector3::from(gr[li]);
    (0..4)
        .filter(|&k| k != li)
        .map(|k| (v * (gr[k][0] * gi[0] + gr[k][1] * gi[1] + gr[k][2] * gi[2])).abs())
        .sum()
}

impl Stiffness {
    /// Whether some cells are worth repairing: a node's bound more than FAR times the median's.
    pub fn needs_repair(&self) -> bool {
        self.far_above > 0 || self.stiffest.first().is_some_and(|n| n.ratio > FAR)
    }

    /// What to do about the stiffest cells, in parentheses.
    fn advice(&self) -> &'static str {
        match self.needs_repair() {
            true => "(repair the cells named below to raise the substep: remesh with a quality bound, `tetgen -q`, or improve them with gmsh's optimiser, `gmsh -3 -optimize` or `-optimize_netgen`; or let [model] integrator = \"implicit\" absorb them)",
            false => "(no cell needs repair: the substep is set by the mesh size)",
        }
    }

    /// The report as lines under a key column of `width` characters (after two spaces).
    pub fn describe(&self, width: usize) -> String {
        let mut out = String::new();
        let key = |k: &str| format!("  {k:<width$}");
        let Some(top) = self.stiffest.first() else {
            return format!("{}no node moves", key("stiffness"));
        };
        out += &format!(
            "{}the Euler substep {:.3e} is set by node {}, {:.0}x the median node's bound (substep {:.3e}); {} of {} nodes lie more than {FAR}x above the median {}",
            key("stiffness"),
            top.h,
            top.id,
            top.ratio,
            self.median_h,
            self.far_above,
            self.nodes,
            self.advice()
        );
        // positions to about six significant digits of the largest coordinate named
        let big = self
            .stiffest
            .iter()
            .flat_map(|n| n.position)
            .fold(0.0f64, |m, x| m.max(x.abs()));
        let dec = if big > 0.0 {
            (6 - big.log10().ceil() as i32).clamp(0, 15) as usize
        } else {
            4
        };
        for (k, n) in self.stiffest.iter().enumerate() {
            let p = n.position;
            let cell = match &n.cell {
                Some(c) if c.share.is_finite() => format!(
                    "cell {} ({}, quality {:.4}, volume {:.3e}, {:.0}% of the node's bound)",
                    c.id,
                    c.kind,
                    c.quality,
                    c.volume,
                    100.0 * c.share
                ),
                Some(c) => format!(
                    "cell {} ({}, quality {:.4}, volume {:.3e})",
                    c.id, c.kind, c.quality, c.volume
                ),
                None => "no cell".into(),
            };
            out += &format!(
                "\n{}node {} at ({:.dec$}, {:.dec$}, {:.dec$}): substep {:.3e} ({:.0}x the median), {cell}",
                key(if k == 0 { "stiffest" } else { "" }),
                n.id,
                p[0],
                p[1],
                p[2],
                n.h,
                n.ratio
            );
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discretize::geometry::{compact_coefficients, Dual, Incidence};

    #[test]
    fn a_flattened_tetrahedron_is_named_as_the_stiffest() {
        // a regular box of tetrahedra with one node pushed almost onto its neighbour's face
        let mut mesh = eprop_io::generate::box_mesh([1.0; 3], [4, 4, 4], eprop_io::generate::BoxCells::Tet).unwrap();
        let n = mesh.n_nodes();
        let centre = (0..n)
            .min_by(|&a, &b| {
                let d = |i: usize| mesh.points[i].iter().map(|x| (x - 0.5) * (x - 0.5)).sum::<f64>();
                d(a).total_cmp(&d(b))
            })
            .unwrap();
        // the operator of the mesh and its report (cell ids from `first_id`), and the operator
        let report = |mesh: &Mesh, first_id: u64| {
            let inc = Incidence::new(mesh);
            let dual = Dual::build(mesh, &inc, n, None);
            let r = Materials::uniform(
                n,
                crate::config::tissue::Tissue {
                    r: Tensor::identity(),
                    ..crate::config::PAPER_TISSUE
                },
            );
            let a = compact_coefficients(mesh, &inc, &dual, &r);
            let op = Compact::new(&dual, &a, &vec![true; n]);
            (analyse(mesh, &op, &dual.vol, &r, &|c| c as u64 + first_id), op)
        };
        let (before, _) = report(&mesh, 1);
        assert!(before.stiffest[0].ratio < 3.0, "{before:?}");
        mesh.points[centre][0] += 0.24; // almost onto a neighbour: flat cells around it
        mesh.points[centre][1] += 0.24;
        mesh.points[centre][2] += 0.24;
        let (s, op) = report(&mesh, 100);
        let worst = &s.stiffest[0];
        let cell = worst.cell.as_ref().unwrap();
        // the stiffest node is the moved one or a node of one of its cells, and the named
        // cell holds the moved node and is flatter than any cell of the regular box
        let named = (0..mesh.n_cells()).find(|&c| c as u64 + 100 == cell.id).unwrap();
        assert!(mesh.cell(named).contains(&(centre as u32)), "{s:?}");
        assert!(cell.quality < 0.5 && cell.share > 0.0 && cell.share <= 1.0, "{cell:?}");
        assert!(worst.ratio > 3.0 && s.worst_h < before.worst_h, "{s:?}");
        assert_eq!(s.worst_h, worst.h);
        assert!(s.far_above < n);
        // the advice to repair (and how) only when a node lies more than FAR above the median
        assert!(!before.needs_repair() && before.describe(12).contains("no cell needs repair"));
        assert!(!before.describe(12).contains("repair the cells"));
        assert_eq!(s.needs_repair(), worst.ratio > FAR || s.far_above > 0);
        assert_eq!(s.needs_repair(), s.describe(12).contains("repair the cells named below to raise the substep: remesh with a quality bound, `tetgen -q`, or improve them with gmsh's optimiser, `gmsh -3 -optimize` or `-optimize_netgen`"), "{}", s.describe(12));
        let med = crate::propagate::integrate::stability::median_bound(&op, n, &crate::distribute::comm::Serial);
        assert!(
            (med - 2.0 / s.median_h).abs() <= 1e-12 * med,
            "{med} {}",
            2.0 / s.median_h
        );
        let text = s.describe(10);
        assert!(
            text.contains(&format!("cell {}", cell.id)) && text.contains("stiffest"),
            "{text}"
        );
    }
}
