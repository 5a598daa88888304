//! Median-dual geometry on the rest mesh (docs/model.md section 2) and the cell operators
//! built on it.
//!
//! Everything is assembled row by row: row i visits its incident cells in increasing cell
//! order and adds that cell's contribution to its own entries only. A cell's numbers are
//! computed from its local node order alone, so S_ji = -S_ij and the tetrahedral compact
//! coefficients a_ij = a_ji hold bitwise, and a row's value never depends on which other rows
//! are built beside it (the property that makes partitioned runs bitwise identical).

use crate::config::tissue::Materials;
use eprop_io::geom::{add, cell_volume, centroid, det3, dot, loop_area, scale, sub};
use eprop_io::mesh::{boundary_faces, CellKind, Mesh};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Node-to-cell incidence in CSR form (cells in increasing order).
pub struct Incidence {
    pub ptr: Vec<usize>,
    pub cells: Vec<u32>,
}

impl Incidence {
    pub fn new(mesh: &Mesh) -> Self {
        let (ptr, cells) = eprop_partition::incidence(mesh.n_nodes(), &mesh.offsets, &mesh.conn);
        Incidence { ptr, cells }
    }
    pub fn of(&self, i: usize) -> &[u32] {
        &self.cells[self.ptr[i]..self.ptr[i + 1]]
    }
}

/// The median-dual geometry of rows `0..n_rows` of a (local) mesh.
pub struct Dual {
    pub n_rows: usize,
    /// Pairs (i, j) that share a cell, j != i, each row sorted by the global node id of j.
    pub row_ptr: Vec<usize>,
    pub col: Vec<u32>,
    /// Dual-face area vector S_ij per pair (zero for pairs that share a cell but no edge).
    pub s: Vec<[f64; 3]>,
    /// Control volume V_i.
    pub vol: Vec<f64>,
    /// Outward boundary dual area A_i.
    pub area: Vec<[f64; 3]>,
    /// Total dual-face area |S| around each node (the scale of closure errors).
    pub dual_area: Vec<f64>,
}

/// For an edge (a, b) of a cell kind: the two faces that contain it.
fn edge_faces(kind: CellKind, a: usize, b: usize) -> [usize; 2] {
    let mut out = [usize::MAX; 2];
    let mut k = 0;
    for (f, face) in kind.faces().iter().enumerate() {
        if face.contains(&a) && face.contains(&b) && k < 2 {
            out[k] = f;
            k += 1;
        }
    }
    out
}

/// The most edges, nodes and faces of a cell kind (a hexahedron's).
const MAX_EDGES: usize = 12;
const MAX_NODES: usize = 8;
const MAX_FACES: usize = 6;

/// Per-cell median-dual pieces, in the cell's local numbering (fixed arrays: no allocation
/// per cell; entries past the kind's edges and nodes are zero).
#[derive(Clone, Copy)]
pub struct CellDual {
    /// S^cell of each local edge (kind.edges() order), oriented from edge[0] to edge[1].
    pub s: [[f64; 3]; MAX_EDGES],
    /// Dual volume piece of each local node.
    pub vol: [f64; MAX_NODES],
    /// Cell volume.
    pub volume: f64,
}

/// The node ids of a face of a cell, on the stack.
fn face_nodes(face: &[usize], nodes: &[u32]) -> ([u32; 4], usize) {
    let mut f = [0u32; 4];
    for (k, &l) in face.iter().enumerate() {
        f[k] = nodes[l];
    }
    (f, face.len())
}

pub fn cell_dual(kind: CellKind, nodes: &[u32], pts: &[[f64; 3]]) -> CellDual {
    let x = |l: usize| pts[nodes[l] as usize];
    let c = centroid(nodes, pts);
    let mut fc = [[0.0; 3]; MAX_FACES];
    for (k, f) in kind.faces().iter().enumerate() {
        let (fnodes, n) = face_nodes(f, nodes);
        fc[k] = centroid(&fnodes[..n], pts);
    }
    let mut vol = [0.0; MAX_NODES];
    let mut s = [[0.0; 3]; MAX_EDGES];
    for (k, e) in kind.edges().iter().enumerate() {
        let (a, b) = (e[0], e[1]);
        let m = scale(add(x(a), x(b)), 0.5);
        let [f1, f2] = edge_faces(kind, a, b);
        let (mut fa, mut fb) = (fc[f1], fc[f2]);
        let mut sv = loop_area(&[m, fa, c, fb]);
        if dot(sv, sub(x(b), x(a))) < 0.0 {
            std::mem::swap(&mut fa, &mut fb);
            sv = loop_area(&[m, fa, c, fb]);
        }
        if kind != CellKind::Tet {
            for (node, sign) in [(a, 1.0), (b, -1.0)] {
                let o = x(node);
                let (mo, fao, co, fbo) = (sub(m, o), sub(fa, o), sub(c, o), sub(fb, o));
                vol[node] += sign * (det3(mo, fao, co) + det3(mo, co, fbo)) / 6.0;
            }
        }
        s[k] = sv;
    }
    let volume = cell_volume(kind, nodes, pts);
    if kind == CellKind::Tet {
        vol[..4].iter_mut().for_each(|v| *v = volume / 4.0);
    }
    CellDual { s, vol, volume }
}

/// Gradients of the linear shape functions of a tetrahedron, and its volume.
pub fn tet_gradients(nodes: &[u32], pts: &[[f64; 3]]) -> ([[f64; 3]; 4], f64) {
    let x0 = pts[nodes[0] as usize];
    let col = |k: usize| {
        let d = sub(pts[nodes[k] as usize], x0);
        Vector3::new(d[0], d[1], d[2])
    };
    let j = Matrix3::from_columns(&[col(1), col(2), col(3)]);
    let inv = j.try_inverse().unwrap_or_else(Matrix3::zeros);
    let mut g = [[0.0; 3]; 4];
    for k in 0..3 {
        g[k + 1] = [inv[(k, 0)], inv[(k, 1)], inv[(k, 2)]];
    }
    g[0] = [
        -(g[1][0] + g[2][0] + g[3][0]),
        -(g[1][1] + g[2][1] + g[3][1]),
        -(g[1][2] + g[2][2] + g[3][2]),
    ];
    (g, j.determinant() / 6.0)
}

/// Exact Green-Gauss gradient weights of a cell: grad u = sum_k u_k G_k for linear u.
/// Faces are fans of triangles from their centroids, as in `cell_volume`.
pub(crate) fn green_gauss(kind: CellKind, nodes: &[u32], pts: &[[f64; 3]], volume: f64) -> Vec<[f64; 3]> {
    let nn = kind.n_nodes();
    let mut g = vec![[0.0; 3]; nn];
    for face in kind.faces() {
        let fnodes: Vec<u32> = face.iter().map(|&l| nodes[l]).collect();
        let k = face.len();
        if k == 3 {
            let a = loop_area(&[
                pts[fnodes[0] as usize],
                pts[fnodes[1] as usize],
                pts[fnodes[2] as usize],
            ]);
            for &l in face.iter() {
                g[l] = add(g[l], scale(a, 1.0 / 3.0));
            }
        } else {
            let fc = centroid(&fnodes, pts);
            for t in 0..k {
                let (la, lb) = (face[t], face[(t + 1) % k]);
                let a = loop_area(&[fc, pts[nodes[la] as usize], pts[nodes[lb] as usize]]);
                let third = scale(a, 1.0 / 3.0);
                g[la] = add(g[la], third);
                g[lb] = add(g[lb], third);
                for &l in face.iter() {
                    g[l] = add(g[l], scale(third, 1.0 / k as f64));
                }
            }
        }
    }
    g.iter().map(|v| scale(*v, 1.0 / volume)).collect()
}

/// Builds the sorted neighbour lists of rows `0..n_rows`: every node that shares a cell.
/// `gid` orders neighbours (global ids); None means local index order.
pub(crate) fn pair_graph(mesh: &Mesh, inc: &Incidence, n_rows: usize, gid: Option<&[u64]>) -> (Vec<usize>, Vec<u32>) {
    let key = |j: u32| gid.map_or(j as u64, |g| g[j as usize]);
    thread_local! {
        static SCRATCH: std::cell::RefCell<Vec<u32>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    // the sorted, distinct neighbours of row i in a reused buffer
    let with_row = |i: usize, f: &mut dyn FnMut(&[u32])| {
        SCRATCH.with(|v| {
            let mut v = v.borrow_mut();
            v.clear();
            for &c in inc.of(i) {
                v.extend(mesh.cell(c as usize).iter().filter(|&&j| j as usize != i));
            }
            v.sort_unstable_by_key(|&j| key(j));
            v.dedup();
            f(&v)
        })
    };
    // one pass over blocks of rows, each block's rows in one buffer, joined in row order (no
    // per-row allocation; the buffers together are the size of `col`)
    const BLOCK: usize = 4096;
    let blocks: Vec<(Vec<u32>, Vec<u32>)> = (0..n_rows.div_ceil(BLOCK))
        .into_par_iter()
        .map(|b| {
            let rows = b * BLOCK..((b + 1) * BLOCK).min(n_rows);
            let (mut counts, mut cols) = (Vec::with_capacity(rows.len()), Vec::new());
            for i in rows {
                with_row(i, &mut |v| {
                    counts.push(v.len() as u32);
                    cols.extend_from_slice(v);
                });
            }
            (counts, cols)
        })
        .collect();
    let mut ptr = Vec::with_capacity(n_rows + 1);
    ptr.push(0);
    for (counts, _) in &blocks {
        for &c in counts {
            ptr.push(ptr[ptr.len() - 1] + c as usize);
        }
    }
    let mut col = Vec::with_capacity(ptr[n_rows]);
    for (_, cols) in blocks {
        col.extend_from_slice(&cols);
    }
    (ptr, col)
}

/// Per-cell bitmask of boundary faces.
pub(crate) fn boundary_mask(mesh: &Mesh) -> Vec<u8> {
    let mut mask = vec![0u8; mesh.n_cells()];
    for (c, f) in boundary_faces(mesh) {
        mask[c as usize] |= 1 << f;
    }
    mask
}

/// Runs `f(row, values of the row)` over the rows of a CSR array in parallel, filling `data`
/// in place (no per-row allocation, so the peak memory is the array itself).
pub(crate) fn par_rows<T: Send, R: Send>(
    data: &mut [T],
    row_ptr: &[usize],
    f: impl Fn(usize, &mut [T]) -> R + Sync + Send,
) -> Vec<R> {
    par_rows_with(data, row_ptr, None, |_| (), |_, i, row| f(i, row))
}

/// The rows `0..n` of a local mesh in Morton order of their points: the order in which the
/// setup visits rows, so that the rows of a block and their cells are near each other whatever
/// the numbering (the band order of the numbering puts consecutive rows on a thin level).
pub(crate) fn visit_order(mesh: &Mesh, n: usize) -> Vec<u32> {
    let keys = eprop_partition::morton_keys(&mesh.points[..n]);
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_unstable_by_key(|&i| (keys[i as usize], i));
    order
}

/// Local node numbers 0..8: `cell_dual(kind, &LOCAL[..n], x)` computes on a cell's own copy
/// `x` of its points (the same arithmetic as on the mesh's points).
const LOCAL: [u32; MAX_NODES] = [0, 1, 2, 3, 4, 5, 6, 7];

/// The kinds, nodes and points of a list of cells, copied side by side in two passes: one
/// cell's loads do not wait for another's, so the processor overlaps their cache misses (a
/// tetgen file numbers its cells and nodes in no spatial order, and a cell read at a time,
/// offsets then nodes then points, waited for each miss in turn).
pub(crate) struct Gathered {
    pub kinds: Vec<CellKind>,
    /// `ptr[k]..ptr[k + 1]` indexes `nodes` and `x` for the k-th cell.
    pub ptr: Vec<u32>,
    pub nodes: Vec<u32>,
    pub x: Vec<[f64; 3]>,
}

impl Gathered {
    pub fn new(mesh: &Mesh, cells: &[u32]) -> Self {
        let mut kinds = Vec::with_capacity(cells.len());
        let mut ptr = Vec::with_capacity(cells.len() + 1);
        let mut nodes = Vec::with_capacity(4 * cells.len());
        ptr.push(0);
        for &c in cells {
            kinds.push(mesh.kinds[c as usize]);
            nodes.extend_from_slice(mesh.cell(c as usize));
            ptr.push(nodes.len() as u32);
        }
        let pts = &mesh.points;
        let x = nodes.iter().map(|&n| pts[n as usize]).collect();
        Gathered { kinds, ptr, nodes, x }
    }

    /// The k-th cell's kind, nodes and points.
    pub fn cell(&self, k: usize) -> (CellKind, &[u32], &[[f64; 3]]) {
        let r = self.ptr[k] as usize..self.ptr[k + 1] as usize;
        (self.kinds[k], &self.nodes[r.clone()], &self.x[r])
    }
}

/// Per-cell pieces of the cells of a block of rows, each computed once for the block (the rows
/// of a block are near each other in the visit order, so few cells are computed in two
/// blocks), and for every incident cell of every row the slot of its piece: a row finds its
/// cells' pieces by position, without a search. The rows must be asked for in the block's
/// order (`row`), as `par_rows_with` visits them.
pub struct BlockCells<T> {
    /// The pieces, in increasing cell order.
    pub items: Vec<T>,
    /// Per incidence of the block's rows, in row order then the row's cell order: the slot in
    /// `items` (u32::MAX for a cell `keep` leaves out).
    slot: Vec<u32>,
    /// The block's rows and where each row's incidences start in `slot`.
    rows: Vec<u32>,
    start: Vec<usize>,
    /// The next row `row` expects.
    next: std::cell::Cell<usize>,
}

impl<T> BlockCells<T> {
    /// The pieces of the cells of `rows` that `keep` keeps: `pieces(cells)` gives them for the
    /// block's kept cells, in increasing order (one call per block, so that it can gather the
    /// cells' nodes and points side by side before it computes: `Gathered`).
    pub fn new(
        inc: &Incidence,
        rows: &[u32],
        keep: impl Fn(u32) -> bool,
        pieces: impl FnOnce(&[u32]) -> Vec<T>,
    ) -> Self {
        let mut start = Vec::with_capacity(rows.len() + 1);
        let mut at: Vec<u64> = Vec::new();
        for &i in rows {
            start.push(at.len());
            for &c in inc.of(i as usize) {
                at.push((c as u64) << 32 | at.len() as u64);
            }
        }
        start.push(at.len());
        let mut slot = vec![u32::MAX; at.len()];
        at.sort_unstable();
        let mut cells = Vec::new();
        let (mut last, mut kept) = (u64::MAX, false);
        for &key in &at {
            let c = key >> 32;
            if c != last {
                last = c;
                kept = keep(c as u32);
                if kept {
                    cells.push(c as u32);
                }
            }
            if kept {
                slot[(key & 0xffff_ffff) as usize] = (cells.len() - 1) as u32;
            }
        }
        let items = pieces(&cells);
        assert_eq!(items.len(), cells.len(), "one piece per kept cell");
        BlockCells {
            items,
            slot,
            rows: rows.to_vec(),
            start,
            next: std::cell::Cell::new(0),
        }
    }

    /// The slots of row `i`'s cells (in `inc.of(i)`'s order); `i` must be the block's next row.
    pub fn row(&self, i: usize) -> &[u32] {
        let r = self.next.get();
        assert_eq!(self.rows[r] as usize, i, "rows asked for out of the block's order");
        self.next.set(r + 1);
        &self.slot[self.start[r]..self.start[r + 1]]
    }
}

/// A pointer that threads may share, each writing its own disjoint entries.
struct Shared<T>(*mut T);
unsafe impl<T: Send> Send for Shared<T> {}
unsafe impl<T: Send> Sync for Shared<T> {}
impl<T> Shared<T> {
    fn get(&self) -> *mut T {
        self.0
    }
}

/// `par_rows` with a context built once per block of rows (`init(rows of the block)`), shared
/// by the rows of that block, the rows taken in blocks of `order` (a permutation of the rows;
/// None: increasing). Results come back in row order; a row's work does not depend on the order.
pub(crate) fn par_rows_with<T: Send, R: Send, C>(
    data: &mut [T],
    row_ptr: &[usize],
    order: Option<&[u32]>,
    init: impl Fn(&[u32]) -> C + Sync + Send,
    f: impl Fn(&C, usize, &mut [T]) -> R + Sync + Send,
) -> Vec<R> {
    const BLOCK: usize = 1024;
    let n = row_ptr.len() - 1;
    assert!(data.len() >= row_ptr[n]);
    let ident: Vec<u32>;
    let order = match order {
        Some(o) => {
            let mut seen = vec![false; n];
            for &i in o {
                assert!(
                    !std::mem::replace(&mut seen[i as usize], true),
                    "row {i} twice in the order"
                );
            }
            assert_eq!(o.len(), n, "the order must name every row once");
            o
        }
        None => {
            ident = (0..n as u32).collect();
            &ident
        }
    };
    let mut out: Vec<R> = Vec::with_capacity(n);
    let (rows_at, out_at) = (Shared(data.as_mut_ptr()), Shared(out.as_mut_ptr()));
    order.par_chunks(BLOCK).for_each(|rows| {
        let ctx = init(rows);
        for &i in rows {
            let i = i as usize;
            // SAFETY: `order` is a permutation of the rows (checked), so each row's slice of
            // `data` and each slot of `out` is touched by exactly one iteration; the slices lie
            // inside `data` (row_ptr is non-decreasing up to row_ptr[n] <= data.len()) and the
            // slots inside `out`'s capacity.
            unsafe {
                let row = std::slice::from_raw_parts_mut(rows_at.get().add(row_ptr[i]), row_ptr[i + 1] - row_ptr[i]);
                out_at.get().add(i).write(f(&ctx, i, row));
            }
        }
    });
    // SAFETY: every slot 0..n was written above (a panic there propagates before this line)
    unsafe { out.set_len(n) };
    out
}

impl Dual {
    /// Median-dual geometry of rows `0..n_rows`. Every cell incident to a row must be present.
    pub fn build(mesh: &Mesh, inc: &Incidence, n_rows: usize, gid: Option<&[u64]>) -> Dual {
        let t = std::time::Instant::now();
        let (row_ptr, col) = pair_graph(mesh, inc, n_rows, gid);
        let t_pairs = t.elapsed().as_secs_f64();
        let mask = boundary_mask(mesh);
        let t_mask = t.elapsed().as_secs_f64() - t_pairs;
        let pts = &mesh.points;
        let mut s = vec![[0.0; 3]; col.len()];
        // the dual of each cell of a block of rows, computed once for the block (the rows of a
        // block are near each other in the visit order, so few cells are computed in two blocks)
        let cell_duals = |rows: &[u32]| {
            BlockCells::new(
                inc,
                rows,
                |_| true,
                |cells| {
                    // the cell's nodes, kind and boundary faces beside its dual piece: a row
                    // then reads nothing of the mesh's cell arrays
                    let g = Gathered::new(mesh, cells);
                    let mut out = Vec::with_capacity(cells.len());
                    for (k, &c) in cells.iter().enumerate() {
                        let (kind, nodes, x) = g.cell(k);
                        let mut at = [0u32; MAX_NODES];
                        at[..nodes.len()].copy_from_slice(nodes);
                        out.push((cell_dual(kind, &LOCAL[..nodes.len()], x), at, kind, mask[c as usize]));
                    }
                    out
                },
            )
        };
        let order = visit_order(mesh, n_rows);
        let rows: Vec<(f64, [f64; 3], f64)> =
            par_rows_with(&mut s, &row_ptr[..=n_rows], Some(&order), cell_duals, |ctx, i, s| {
                let cols = &col[row_ptr[i]..row_ptr[i + 1]];
                let mut v = 0.0;
                let mut a = [0.0; 3];
                let slots = ctx.row(i);
                for &slot in slots {
                    let (cd, nodes, kind, mask) = &ctx.items[slot as usize];
                    let (kind, mask) = (*kind, *mask);
                    let nodes = &nodes[..kind.n_nodes()];
                    let li = nodes.iter().position(|&x| x as usize == i).unwrap();
                    v += cd.vol[li];
                    for (e, edge) in kind.edges().iter().enumerate() {
                        let (other, sign) = if edge[0] == li {
                            (edge[1], 1.0)
                        } else if edge[1] == li {
                            (edge[0], -1.0)
                        } else {
                            continue;
                        };
                        let p = cols.iter().position(|&x| x == nodes[other]).unwrap();
                        s[p] = add(s[p], scale(cd.s[e], sign));
                    }
                    if mask != 0 {
                        for (f, face) in kind.faces().iter().enumerate() {
                            if mask & (1 << f) == 0 {
                                continue;
                            }
                            if let Some(k) = face.iter().position(|&l| l == li) {
                                let nf = face.len();
                                let next = nodes[face[(k + 1) % nf]] as usize;
                                let prev = nodes[face[(k + nf - 1) % nf]] as usize;
                                let fnodes: Vec<u32> = face.iter().map(|&l| nodes[l]).collect();
                                let fcn = centroid(&fnodes, pts);
                                let xi = pts[i];
                                let quad = [xi, scale(add(xi, pts[next]), 0.5), fcn, scale(add(xi, pts[prev]), 0.5)];
                                a = add(a, loop_area(&quad));
                            }
                        }
                    }
                }
                let da: f64 = s.iter().map(|x| dot(*x, *x).sqrt()).sum();
                (v, a, da)
            });
        let vol = rows.iter().map(|r| r.0).collect();
        let area = rows.iter().map(|r| r.1).collect();
        let dual_area = rows.iter().map(|r| r.2).collect();
        tracing::debug!(
            "dual geometry of {n_rows} rows in {:.2} s: pair graph {t_pairs:.2} s, boundary faces {t_mask:.2} s, dual faces and volumes {:.2} s",
            t.elapsed().as_secs_f64(),
            t.elapsed().as_secs_f64() - t_pairs - t_mask
        );
        Dual {
            n_rows,
            row_ptr,
            col,
            s,
            vol,
            area,
            dual_area,
        }
    }

    /// Frees the dual-face vectors S_ij (and the closure scale) once the operator is built;
    /// the control volumes and boundary areas stay.
    pub fn release_pairs(&mut self) {
        self.s = Vec::new();
        self.dual_area = Vec::new();
    }

    /// Largest |sum_j S_ij + A_i| / (dual area of i) over the rows.
    pub fn max_closure_error(&self) -> f64 {
        (0..self.n_rows)
            .map(|i| {
                let mut t = self.area[i];
                for p in self.row_ptr[i]..self.row_ptr[i + 1] {
                    t = add(t, self.s[p]);
                }
                let scale = self.dual_area[i] + dot(self.area[i], self.area[i]).sqrt();
                if scale > 0.0 {
                    dot(t, t).sqrt() / scale
                } else {
                    0.0
                }
            })
            .fold(0.0, f64::max)
    }
}

/// A cell's Young's modulus over the reference, E_c / E0 (docs/model.md section 3): its
/// nodes' ratio when they all have the same (bit for bit, so exactly 1 in a tissue of the
/// reference young), otherwise the harmonic mean of its nodes' ratios (a cell is as stiff as
/// the stiff tissue only when every node of it belongs to that tissue).
pub(crate) fn cell_young(nodes: &[u32], mat: &Materials) -> f64 {
    let first = mat.young_ratio(nodes[0] as usize);
    if nodes
        .iter()
        .all(|&n| mat.young_ratio(n as usize).to_bits() == first.to_bits())
    {
        return first;
    }
    nodes.len() as f64 / nodes.iter().map(|&n| 1.0 / mat.young_ratio(n as usize)).sum::<f64>()
}

/// The capacity of every row's control volume, C_i = sum over the node's cells of
/// (E_c / E0) V_i^cell (docs/model.md section 3): V_i itself when every cell of the node has
/// the same ratio 1 (bit for bit); None when no tissue weighs (`Materials::weighs_young`:
/// the capacities are `dual.vol`, not copied).
pub fn capacities(mesh: &Mesh, inc: &Incidence, dual: &Dual, mat: &Materials) -> Option<Vec<f64>> {
    if !mat.weighs_young() {
        return None;
    }
    let pts = &mesh.points;
    (0..dual.n_rows)
        .into_par_iter()
        .map(|i| {
            let cells = inc.of(i);
            let w: Vec<f64> = cells.iter().map(|&c| cell_young(mesh.cell(c as usize), mat)).collect();
            if let Some(&w0) = w.first() {
                if w.iter().all(|x| x.to_bits() == w0.to_bits()) {
                    return dual.vol[i] * w0;
                }
            }
            let mut v = 0.0;
            for (&c, wc) in cells.iter().zip(&w) {
                let c = c as usize;
                let nodes = mesh.cell(c);
                let li = nodes.iter().position(|&x| x as usize == i).unwrap();
                let piece = if mesh.kinds[c] == CellKind::Tet {
                    cell_volume(CellKind::Tet, nodes, pts) / 4.0
                } else {
                    cell_dual(mesh.kinds[c], nodes, pts).vol[li]
                };
                v += wc * piece;
            }
            v
        })
        .collect::<Vec<f64>>()
        .into()
}

/// The dual faces weighted by their cells' Young's modulus, sum over cells of
/// (E_c / E0) S_ij^cell, on the pair graph of `dual` (the paper scheme's fluxes when
/// `Materials::weighs_young`; docs/model.md section 3).
pub(crate) fn young_faces(mesh: &Mesh, inc: &Incidence, dual: &Dual, mat: &Materials) -> Vec<[f64; 3]> {
    let pts = &mesh.points;
    let mut out = vec![[0.0; 3]; dual.row_ptr[dual.n_rows]];
    par_rows(&mut out, &dual.row_ptr[..=dual.n_rows], |i, s| {
        let cols = &dual.col[dual.row_ptr[i]..dual.row_ptr[i + 1]];
        for &c in inc.of(i) {
            let c = c as usize;
            let (kind, nodes) = (mesh.kinds[c], mesh.cell(c));
            let li = nodes.iter().position(|&x| x as usize == i).unwrap();
            let cd = cell_dual(kind, nodes, pts);
            let w = cell_young(nodes, mat);
            for (e, edge) in kind.edges().iter().enumerate() {
                let (other, sign) = if edge[0] == li {
                    (edge[1], w)
                } else if edge[1] == li {
                    (edge[0], -w)
                } else {
                    continue;
                };
                let p = cols.iter().position(|&x| x == nodes[other]).unwrap();
                s[p] = add(s[p], scale(cd.s[e], sign));
            }
        }
    });
    out
}

/// The pairs (lo, hi), lo < hi, of a tetrahedron's local nodes, and the index of each in it.
const TET_PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
const TET_PAIR_OF: [[usize; 4]; 4] = [
    [usize::MAX, 0, 1, 2],
    [0, usize::MAX, 3, 4],
    [1, 3, usize::MAX, 5],
    [2, 4, 5, usize::MAX],
];

/// Compact-scheme coefficients a_ij of rows `0..n_rows` on the pair graph of `dual`:
/// sum_j a_ij (u_j - u_i) is the exact flux of (E/E0) R grad u (cell gradients) into the
/// control volume of i. `r` gives the tensor and young of every local node; a cell uses the
/// mean of its nodes' tensors and `cell_young` (no weight at all unless
/// `Materials::weighs_young`).
pub fn compact_coefficients(mesh: &Mesh, inc: &Incidence, dual: &Dual, r: &Materials) -> Vec<f64> {
    let t = std::time::Instant::now();
    let pts = &mesh.points;
    let mut out = vec![0.0; dual.row_ptr[dual.n_rows]];
    let order = visit_order(mesh, dual.n_rows);
    let weighs = r.weighs_young();
    // a cell's tensor: the mean of its nodes', weighed by its young where tissues weigh
    let tensor = |nodes: &[u32]| {
        let mut rc = Matrix3::zeros();
        for &n in nodes {
            rc += r.r(n as usize);
        }
        rc /= nodes.len() as f64;
        if weighs {
            rc *= cell_young(nodes, r);
        }
        rc
    };
    // the coefficient a_ab of each pair of nodes of each tetrahedron of a block of rows,
    // computed once for the block (as the dual's cell pieces in `Dual::build`):
    // a_ab = -V grad N_a . R grad N_b, for (a, b) in increasing local order so that
    // a_ab == a_ba bitwise
    let tets = |rows: &[u32]| {
        BlockCells::new(
            inc,
            rows,
            |c| mesh.kinds[c as usize] == CellKind::Tet,
            |cells| {
                let g = Gathered::new(mesh, cells);
                (0..cells.len())
                    .map(|k| {
                        let (_, nodes, x) = g.cell(k);
                        let (gr, v) = tet_gradients(&LOCAL[..4], x);
                        let rc = tensor(nodes);
                        let mut a = [0.0; 6];
                        for (k, &(lo, hi)) in TET_PAIRS.iter().enumerate() {
                            let rg = rc * Vector3::from(gr[hi]);
                            a[k] = -v * (gr[lo][0] * rg[0] + gr[lo][1] * rg[1] + gr[lo][2] * rg[2]);
                        }
                        (a, [nodes[0], nodes[1], nodes[2], nodes[3]])
                    })
                    .collect()
            },
        )
    };
    par_rows_with(
        &mut out,
        &dual.row_ptr[..=dual.n_rows],
        Some(&order),
        tets,
        |ctx, i, w| {
            let cols = &dual.col[dual.row_ptr[i]..dual.row_ptr[i + 1]];
            let slots = ctx.row(i);
            for (&c, &slot) in inc.of(i).iter().zip(slots) {
                if slot != u32::MAX {
                    // a tetrahedron: its nodes and coefficients are the block's
                    let (a, nodes) = &ctx.items[slot as usize];
                    let li = nodes.iter().position(|&x| x as usize == i).unwrap();
                    for lk in 0..4 {
                        if lk == li {
                            continue;
                        }
                        let val = a[TET_PAIR_OF[li.min(lk)][li.max(lk)]];
                        let p = cols.iter().position(|&x| x == nodes[lk]).unwrap();
                        w[p] += val;
                    }
                } else {
                    let c = c as usize;
                    let kind = mesh.kinds[c];
                    let nodes = mesh.cell(c);
                    let li = nodes.iter().position(|&x| x as usize == i).unwrap();
                    let rc = tensor(nodes);
                    let cd = cell_dual(kind, nodes, pts);
                    let gg = green_gauss(kind, nodes, pts, cd.volume);
                    // total outward dual-face vector of node li in this cell
                    let mut sum_s = [0.0; 3];
                    for (e, edge) in kind.edges().iter().enumerate() {
                        if edge[0] == li {
                            sum_s = add(sum_s, cd.s[e]);
                        } else if edge[1] == li {
                            sum_s = sub(sum_s, cd.s[e]);
                        }
                    }
                    let rs = rc * Vector3::from(sum_s);
                    for (lk, gk) in gg.iter().enumerate() {
                        if lk == li {
                            continue;
                        }
                        let val = rs[0] * gk[0] + rs[1] * gk[1] + rs[2] * gk[2];
                        let p = cols.iter().position(|&x| x == nodes[lk]).unwrap();
                        w[p] += val;
                    }
                }
            }
        },
    );
    tracing::debug!(
        "compact coefficients of {} rows in {:.2} s",
        dual.n_rows,
        t.elapsed().as_secs_f64()
    );
    out
}
