//! What an output step's state says of itself (docs/model.md section 6): the cells the
//! deformation has inverted, and the nodes that lie inside a tool. Counted exactly, the same on
//! any number of processes: a cell is counted by the process that owns its node of smallest
//! global index, the counts are integer sums.

use super::{contact, Simulation};
use crate::distribute::comm::reproducible_sums;
use crate::linalg::V3;
use eprop_io::geom::{add, det3, sub};
use eprop_io::mesh::CellKind;

/// A node counts as inside a tool when it lies deeper than this fraction of the tool's radius:
/// the band the kinematic contact leaves a node it puts on the surface in (`ON_SURFACE`).
pub(crate) const INSIDE_TOLERANCE: f64 = super::kinematic::ON_SURFACE;

/// The inverted cells and the nodes inside tools at one step, over every process.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Inspection {
    /// Cells whose deformed corner Jacobians are not all of their rest sign.
    pub inverted: u64,
    /// The mean of the inverted cells' rest centroids, and the box of their rest nodes.
    pub centroid: V3,
    pub bounds: Option<(V3, V3)>,
    /// Per tool: the active nodes deeper inside it than `INSIDE_TOLERANCE` of its radius, and
    /// the deepest one's depth (0 when none).
    pub inside: Vec<u64>,
    pub deepest: Vec<f64>,
    /// The active free nodes whose deformed position lies across a fixed support's plane
    /// (farther than its tolerance), and the farthest one's distance (0 when none).
    pub across: u64,
    pub farthest: f64,
}

/// The corners of a cell as tetrahedra: (corner, three of its neighbours along the cell's
/// edges), one for a tetrahedron (all four give its signed volume), one per corner of a
/// hexahedron or prism, and for a pyramid one per base corner and four at the apex (each three
/// of its four base neighbours).
fn corners(kind: CellKind) -> Vec<[usize; 4]> {
    if kind == CellKind::Tet {
        return vec![[0, 1, 2, 3]];
    }
    let mut out = Vec::new();
    for c in 0..kind.n_nodes() {
        let nb: Vec<usize> = kind
            .edges()
            .iter()
            .filter_map(|e| match (e[0] == c, e[1] == c) {
                (true, _) => Some(e[1]),
                (_, true) => Some(e[0]),
                _ => None,
            })
            .collect();
        if nb.len() == 3 {
            out.push([c, nb[0], nb[1], nb[2]]);
            continue;
        }
        // the apex of a pyramid: each three of its four neighbours
        for skip in 0..nb.len() {
            let t: Vec<usize> = (0..nb.len()).filter(|&k| k != skip).map(|k| nb[k]).collect();
            out.push([c, t[0], t[1], t[2]]);
        }
    }
    out
}

/// True when the deformed cell (rest points `pts` moved by `u`, indexed by `nodes`) is
/// inverted: one of its corner Jacobians (`corners`) is zero or of the other sign than at rest
/// (a corner flat at rest is not judged).
pub fn cell_inverted(kind: CellKind, nodes: &[u32], pts: &[V3], u: &[V3]) -> bool {
    inverted_at(&corners(kind), nodes, pts, u)
}

/// `cell_inverted` with the cell kind's `corners`.
fn inverted_at(corners: &[[usize; 4]], nodes: &[u32], pts: &[V3], u: &[V3]) -> bool {
    let x = |k: usize| add(pts[nodes[k] as usize], u[nodes[k] as usize]);
    let p = |k: usize| pts[nodes[k] as usize];
    corners.iter().any(|&[c, a, b, d]| {
        let rest = det3(sub(p(a), p(c)), sub(p(b), p(c)), sub(p(d), p(c)));
        if rest == 0.0 {
            return false;
        }
        let now = det3(sub(x(a), x(c)), sub(x(b), x(c)), sub(x(d), x(c)));
        !(now * rest.signum() > 0.0)
    })
}

impl Simulation {
    /// The inverted cells and the nodes inside each tool in the current state (every process
    /// calls: one halo exchange of u and a few reductions).
    pub fn inspect(&self) -> Inspection {
        let c = self.comm.as_ref();
        let n = self.numbering.n_owned;
        let mesh = &self.setup.mesh;
        let pts = &mesh.points;
        // the halo's displacements: the cells at the border read them
        let mut u = self.u.clone();
        self.prop.refresh(&mut u);
        let kinds = [CellKind::Tet, CellKind::Hex, CellKind::Wedge, CellKind::Pyramid];
        let table = kinds.map(corners);
        let mut bad = Vec::new();
        for cell in 0..mesh.n_cells() {
            let nodes = mesh.cell(cell);
            let first = nodes
                .iter()
                .min_by_key(|&&k| self.gid[k as usize])
                .copied()
                .unwrap_or(0);
            let at = kinds.iter().position(|&k| k == mesh.kinds[cell]).unwrap_or(0);
            if (first as usize) < n && inverted_at(&table[at], nodes, pts, &u) {
                bad.push(cell);
            }
        }
        let inverted = c.sum_i128(bad.len() as i128) as u64;
        let (mut centroid, mut bounds) = ([0.0; 3], None);
        if inverted > 0 {
            let sums = reproducible_sums(c, bad.iter().map(|&k| eprop_io::geom::centroid(mesh.cell(k), pts)));
            centroid = sums.map(|s| s / inverted as f64);
            let mut local = [f64::NEG_INFINITY; 6];
            for &k in &bad {
                for &i in mesh.cell(k) {
                    for d in 0..3 {
                        local[d] = local[d].max(-pts[i as usize][d]);
                        local[3 + d] = local[3 + d].max(pts[i as usize][d]);
                    }
                }
            }
            let m = c.max_each(&local);
            bounds = Some(([-m[0], -m[1], -m[2]], [m[3], m[4], m[5]]));
        }
        let (mut inside, mut deepest) = (Vec::new(), Vec::new());
        for t in &self.tools {
            let (shape, at) = (t.tool.shape, t.state.position);
            let tol = INSIDE_TOLERANCE * shape.radius();
            let (mut count, mut most) = (0i128, 0.0f64);
            for i in (0..n).filter(|&i| self.active[i]) {
                let d = contact::depth(&shape, at, add(pts[i], self.u[i]));
                if d > tol {
                    count += 1;
                    most = most.max(d);
                }
            }
            inside.push(c.sum_i128(count) as u64);
            deepest.push(c.max(most));
        }
        let (mut across, mut farthest) = (0i128, 0.0f64);
        for i in (0..n).filter(|&i| self.active[i] && !self.setup.fixed[i]) {
            let y = add(pts[i], self.u[i]);
            let beyond = self
                .setup
                .supports
                .iter()
                .map(|p| p.across(y) - p.tol)
                .fold(f64::NEG_INFINITY, f64::max);
            if beyond > 0.0 {
                across += 1;
                farthest = farthest.max(beyond);
            }
        }
        Inspection {
            inverted,
            centroid,
            bounds,
            inside,
            deepest,
            across: c.sum_i128(across) as u64,
            farthest: c.max(farthest),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TET: [V3; 4] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

    fn cube() -> Vec<V3> {
        let mut p = Vec::new();
        for z in [0.0, 1.0] {
            for (x, y) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
                p.push([x, y, z]);
            }
        }
        p
    }

    #[test]
    fn a_tetrahedron_is_inverted_when_its_volume_is_not_positive() {
        let nodes = [0, 1, 2, 3];
        let rest = [[0.0; 3]; 4];
        assert!(!cell_inverted(CellKind::Tet, &nodes, &TET, &rest));
        // the apex moved to the base plane (flat) and through it
        for (dz, want) in [(-0.5, false), (-1.0, true), (-1.5, true)] {
            let mut u = rest;
            u[3] = [0.2, 0.1, dz];
            assert_eq!(cell_inverted(CellKind::Tet, &nodes, &TET, &u), want, "dz = {dz}");
        }
        // a rigid rotation inverts nothing
        let u: Vec<V3> = TET.iter().map(|p| [-p[1] - p[0], p[0] - p[1], 0.0]).collect();
        assert!(!cell_inverted(CellKind::Tet, &nodes, &TET, &u));
    }

    #[test]
    fn a_hexahedron_is_inverted_when_a_corner_folds() {
        let pts = cube();
        let nodes: Vec<u32> = (0..8).collect();
        let zero = vec![[0.0; 3]; 8];
        assert!(!cell_inverted(CellKind::Hex, &nodes, &pts, &zero));
        // the top pressed half-way down: not inverted; a top corner pushed below the bottom
        let mut u = zero.clone();
        for k in 4..8 {
            u[k] = [0.0, 0.0, -0.5];
        }
        assert!(!cell_inverted(CellKind::Hex, &nodes, &pts, &u));
        u[6] = [0.0, 0.0, -1.2];
        assert!(cell_inverted(CellKind::Hex, &nodes, &pts, &u));
        // a corner moved across its neighbours' plane inside the cell (a folded corner whose
        // volume stays positive)
        let mut u = zero.clone();
        u[0] = [0.9, 0.9, 0.9];
        assert!(cell_inverted(CellKind::Hex, &nodes, &pts, &u));
        // the mirrored node order (negative at rest) judges the same deformation the same
        let flipped: Vec<u32> = vec![4, 5, 6, 7, 0, 1, 2, 3];
        assert!(!cell_inverted(CellKind::Hex, &flipped, &pts, &zero));
        assert!(cell_inverted(CellKind::Hex, &flipped, &pts, &u));
    }

    #[test]
    fn prisms_and_pyramids_have_their_corners() {
        assert_eq!(corners(CellKind::Tet).len(), 1);
        assert_eq!(corners(CellKind::Hex).len(), 8);
        assert_eq!(corners(CellKind::Wedge).len(), 6);
        assert_eq!(corners(CellKind::Pyramid).len(), 4 + 4);
        let pyr = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.5, 0.5, 1.0],
        ];
        let nodes = [0, 1, 2, 3, 4];
        let mut u = vec![[0.0; 3]; 5];
        assert!(!cell_inverted(CellKind::Pyramid, &nodes, &pyr, &u));
        u[4] = [0.0, 0.0, -1.1]; // the apex through the base
        assert!(cell_inverted(CellKind::Pyramid, &nodes, &pyr, &u));
        let wedge = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 1.0],
            [0.0, 1.0, 1.0],
        ];
        let nodes = [0, 1, 2, 3, 4, 5];
        let mut u = vec![[0.0; 3]; 6];
        assert!(!cell_inverted(CellKind::Wedge, &nodes, &wedge, &u));
        u[3] = [0.0, 0.0, -1.01];
        assert!(cell_inverted(CellKind::Wedge, &nodes, &wedge, &u));
    }
}
