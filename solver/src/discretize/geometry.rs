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
use eprop_io::mesh::{CellKind, Mesh};
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
        // a row's distinct neighbours, and per node the (call, row) that last took it
        static SCRATCH: std::cell::RefCell<(Vec<u32>, Vec<u64>)> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
    }
    static CALLS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed) << 32;
    let n_nodes = mesh.n_nodes();
    // the distinct neighbours of row i (a mark per node, so only they are sorted: a row
    // meets each neighbour about four times), sorted, in a reused buffer
    let with_row = |i: usize, f: &mut dyn FnMut(&[u32])| {
        SCRATCH.with(|sc| {
            let (v, mark) = &mut *sc.borrow_mut();
            if mark.len() < n_nodes {
                mark.resize(n_nodes, u64::MAX);
            }
            let me = call | i as u64;
            // the cells' nodes first (one cell's loads do not wait for another's), then the
            // distinct ones but i
            v.clear();
            for &c in inc.of(i) {
                v.extend_from_slice(mesh.cell(c as usize));
            }
            mark[i] = me;
            v.retain(|&j| std::mem::replace(&mut mark[j as usize], me) != me);
            v.sort_unstable_by_key(|&j| key(j));
            f(v)
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

/// Sorts keys `c << 32 | k` that were pushed in increasing k: a least-significant-digit radix
/// sort over the bits of c, 11 at a time (stable, so k stays increasing within a c: the order
/// of sorting the keys whole), two passes for two million cells instead of a comparison sort.
fn sort_by_cell(at: &mut Vec<u64>) {
    const DIGIT: u32 = 11;
    let max = at.iter().map(|&k| k >> 32).max().unwrap_or(0);
    let mut tmp = vec![0u64; at.len()];
    let mut shift = 32;
    while shift < 64 - max.leading_zeros() + 32 {
        let digit = |k: u64| ((k >> shift) & ((1 << DIGIT) - 1)) as usize;
        let mut at_digit = [0u32; (1 << DIGIT) + 1];
        for &k in at.iter() {
            at_digit[digit(k) + 1] += 1;
        }
        for d in 0..1 << DIGIT {
            at_digit[d + 1] += at_digit[d];
        }
        for &k in at.iter() {
            let d = digit(k);
            tmp[at_digit[d] as usize] = k;
            at_digit[d] += 1;
        }
        std::mem::swap(at, &mut tmp);
        shift += DIGIT;
    }
}

/// Per-cell pieces of the cells of a block of rows, each computed once for the block (the rows
/// of a block are near each other in the visit order, so few cells are computed in two
/// blocks), and for every incident cell of every row the slot of its piece: a row finds its
/// cells' pieces by position, without a search. The rows must be asked for in the block's
/// order (`row`), as `par_rows_with` visits them.
pub struct BlockCells<T> {
    /// The pieces, in increasing cell order (a `Vec` of them, or a flat layout).
    pub items: T,
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
    pub fn new(inc: &Incidence, rows: &[u32], keep: impl Fn(u32) -> bool, pieces: impl FnOnce(&[u32]) -> T) -> Self {
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
        sort_by_cell(&mut at);
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

/// A second CSR array that a `par_rows_with` pass fills beside its own, row by row.
struct RowsOut<'a, T> {
    at: Shared<T>,
    row_ptr: &'a [usize],
    _data: std::marker::PhantomData<&'a mut [T]>,
}

impl<'a, T: Send> RowsOut<'a, T> {
    fn new(data: &'a mut [T], row_ptr: &'a [usize]) -> Self {
        assert!(row_ptr.windows(2).all(|w| w[0] <= w[1]) && row_ptr[row_ptr.len() - 1] <= data.len());
        RowsOut {
            at: Shared(data.as_mut_ptr()),
            row_ptr,
            _data: std::marker::PhantomData,
        }
    }

    /// Row i's values.
    ///
    /// # Safety
    /// No other reference to row i may be alive: each row asked for by the one iteration of
    /// `par_rows_with` that builds that row.
    #[allow(clippy::mut_from_ref)]
    unsafe fn row(&self, i: usize) -> &mut [T] {
        // SAFETY: the row lies inside `data` (checked in `new`); exclusive by the caller's
        // promise
        unsafe {
            std::slice::from_raw_parts_mut(
                self.at.get().add(self.row_ptr[i]),
                self.row_ptr[i + 1] - self.row_ptr[i],
            )
        }
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

/// The dual pieces of a block's cells, flat (`Dual::build`): their kinds and nodes
/// (`Gathered`, without the points once the pieces are computed), S^cell of each local edge
/// (`eptr[k]..eptr[k + 1]` for the k-th cell) and the volume piece of each local node
/// (indexed as the nodes).
struct DualPieces {
    g: Gathered,
    eptr: Vec<u32>,
    s: Vec<[f64; 3]>,
    vol: Vec<f64>,
    /// With a `CellTensor`: each tetrahedron's compact coefficients (`CellTensor::tet`; zero
    /// for the other kinds, whose rows take theirs from the mesh).
    a: Vec<[f64; 6]>,
}

impl DualPieces {
    /// Without `faces`, the volume pieces alone (`s` empty).
    fn new(mesh: &Mesh, cells: &[u32], faces: bool, tensor: Option<&CellTensor>) -> Self {
        let mut g = Gathered::new(mesh, cells);
        let mut eptr = Vec::with_capacity(cells.len() + 1);
        eptr.push(0);
        let mut s = Vec::with_capacity(if faces { 6 * cells.len() } else { 0 });
        let mut vol = Vec::with_capacity(g.nodes.len());
        let mut a = Vec::with_capacity(if tensor.is_some() { cells.len() } else { 0 });
        for k in 0..cells.len() {
            let (kind, nodes, x) = g.cell(k);
            let n = nodes.len();
            if let Some(t) = tensor {
                a.push(if kind == CellKind::Tet {
                    t.tet(nodes, x)
                } else {
                    [0.0; 6]
                });
            }
            if !faces && kind == CellKind::Tet {
                // `cell_dual`'s volume pieces of a tetrahedron, without its faces
                vol.extend_from_slice(&[cell_volume(kind, &LOCAL[..n], x) / 4.0; 4]);
            } else {
                let cd = cell_dual(kind, &LOCAL[..n], x);
                if faces {
                    s.extend_from_slice(&cd.s[..kind.edges().len()]);
                }
                vol.extend_from_slice(&cd.vol[..n]);
            }
            eptr.push(s.len() as u32);
        }
        g.x = Vec::new();
        DualPieces { g, eptr, s, vol, a }
    }
}

/// A row's faces through its node, to tell the boundary ones (on one cell only) apart: every
/// cell with a face through node i is one of i's cells, so the row alone decides, as
/// `boundary_faces` on the whole mesh would. A face is named by the positions among the row's
/// columns of its other nodes.
#[derive(Default)]
struct RowFaces {
    /// Triangles (i, a, b), a < b: bit b % 64 of word a * words + b / 64 is set once the
    /// triangle is seen (`seen`) and once it is seen again (`twice`); words = 0 on a row of
    /// more than `DENSE` columns, whose triangles go to `listed` (the bitsets grow as the
    /// square of the columns).
    seen: Vec<u64>,
    twice: Vec<u64>,
    words: usize,
    /// Triangles seen exactly once so far.
    single: usize,
    /// Quadrilaterals (and the triangles of a row of many columns, third position u32::MAX):
    /// their other nodes' positions, sorted.
    listed: Vec<[u32; 3]>,
}

impl RowFaces {
    /// The most columns of a row whose triangles are told apart in the bitsets.
    const DENSE: usize = 1024;

    fn reset(&mut self, n_cols: usize) {
        self.words = if n_cols <= Self::DENSE { n_cols.div_ceil(64) } else { 0 };
        for v in [&mut self.seen, &mut self.twice] {
            v.clear();
            v.resize(n_cols * self.words, 0);
        }
        self.single = 0;
        self.listed.clear();
    }

    /// The face's other nodes' positions (`pos`: of each local node of the cell), sorted, and
    /// their count; None when the face does not pass through `li`.
    fn key(face: &[usize], li: usize, pos: &[u32; MAX_NODES]) -> Option<([u32; 3], usize)> {
        if !face.contains(&li) {
            return None;
        }
        let mut k = [u32::MAX; 3];
        let mut n = 0;
        for &l in face {
            if l != li {
                k[n] = pos[l];
                n += 1;
            }
        }
        k[..n].sort_unstable();
        Some((k, n))
    }

    fn tri(&self, k: &[u32; 3]) -> (usize, u64) {
        (k[0] as usize * self.words + k[1] as usize / 64, 1 << (k[1] % 64))
    }

    fn add(&mut self, (k, n): ([u32; 3], usize)) {
        if n == 2 && self.words > 0 {
            let (w, bit) = self.tri(&k);
            if self.seen[w] & bit == 0 {
                self.seen[w] |= bit;
                self.single += 1;
            } else if self.twice[w] & bit == 0 {
                self.twice[w] |= bit;
                self.single -= 1;
            }
        } else {
            self.listed.push(k);
        }
    }

    /// Whether any face is on the boundary (sorts `listed`: call once all faces are in).
    fn any(&mut self) -> bool {
        self.listed.sort_unstable();
        self.single > 0 || self.listed.chunk_by(|a, b| a == b).any(|g| g.len() == 1)
    }

    fn is_boundary(&self, (k, n): ([u32; 3], usize)) -> bool {
        if n == 2 && self.words > 0 {
            let (w, bit) = self.tri(&k);
            self.seen[w] & bit != 0 && self.twice[w] & bit == 0
        } else {
            let at = self.listed.partition_point(|q| *q < k);
            self.listed[at..].iter().take_while(|q| **q == k).count() == 1
        }
    }
}

thread_local! {
    /// Per node, its position among the columns of the row this thread builds
    /// (`with_columns`); stale entries of other rows stay.
    static AT: std::cell::RefCell<Vec<u32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The positions of a row's columns: a table per node, so that finding a neighbour's entry is
/// one load, not a search of the row (the search was half of a row's time on a tetgen mesh).
#[derive(Clone, Copy)]
pub(crate) struct Columns<'a> {
    at: &'a [u32],
    cols: &'a [u32],
}

impl Columns<'_> {
    /// The position of node `j` among the row's columns (it must be one of them).
    #[inline]
    pub fn of(&self, j: u32) -> usize {
        let p = self.at[j as usize] as usize;
        assert!(self.cols.get(p) == Some(&j), "node {j} is not a column of the row");
        p
    }

    /// The positions of a cell's local nodes (u32::MAX for the row's own, `li`).
    fn of_cell(&self, nodes: &[u32], li: usize) -> [u32; MAX_NODES] {
        let mut pos = [u32::MAX; MAX_NODES];
        for (l, &n) in nodes.iter().enumerate() {
            if l != li {
                pos[l] = self.of(n) as u32;
            }
        }
        pos
    }
}

/// Runs `f` with the positions of the row's columns `cols` (nodes below `n_nodes`).
pub(crate) fn with_columns<R>(n_nodes: usize, cols: &[u32], f: impl FnOnce(Columns<'_>) -> R) -> R {
    AT.with(|at| {
        let mut at = at.borrow_mut();
        if at.len() < n_nodes {
            at.resize(n_nodes, u32::MAX);
        }
        for (p, &j) in cols.iter().enumerate() {
            at[j as usize] = p as u32;
        }
        f(Columns { at: &at, cols })
    })
}

impl Dual {
    /// Median-dual geometry of rows `0..n_rows`. Every cell incident to a row must be present.
    pub fn build(mesh: &Mesh, inc: &Incidence, n_rows: usize, gid: Option<&[u64]>) -> Dual {
        Dual::build_inner(mesh, inc, n_rows, gid, true, None).0
    }

    /// What a compact-scheme operator needs, in one pass over blocks of rows: the dual without
    /// its faces S_ij and their closure scale (`s` and `dual_area` empty, as after
    /// `release_pairs`; the compact operator never reads them) and the compact coefficients
    /// (`compact_coefficients`). The same bits as `build` and `compact_coefficients`.
    pub fn build_compact(
        mesh: &Mesh,
        inc: &Incidence,
        n_rows: usize,
        gid: Option<&[u64]>,
        r: &Materials,
    ) -> (Dual, Vec<f64>) {
        Dual::build_inner(mesh, inc, n_rows, gid, false, Some(r))
    }

    /// The dual, its faces where `faces` asks for them, and with materials `r` the compact
    /// coefficients (else an empty vector).
    fn build_inner(
        mesh: &Mesh,
        inc: &Incidence,
        n_rows: usize,
        gid: Option<&[u64]>,
        faces: bool,
        r: Option<&Materials>,
    ) -> (Dual, Vec<f64>) {
        let t = std::time::Instant::now();
        let (row_ptr, col) = pair_graph(mesh, inc, n_rows, gid);
        let t_pairs = t.elapsed().as_secs_f64();
        let pts = &mesh.points;
        let mut s = vec![[0.0; 3]; if faces { col.len() } else { 0 }];
        // without the faces (the coefficients), every row's slice of `s` (`coef`) is empty
        let empty = vec![0; n_rows + 1];
        let s_ptr = if faces { &row_ptr[..=n_rows] } else { &empty };
        let tensor = r.map(CellTensor::new);
        let mut coef = vec![0.0; if r.is_some() { col.len() } else { 0 }];
        let coef_rows = RowsOut::new(&mut coef, if r.is_some() { &row_ptr[..=n_rows] } else { &empty });
        // the dual of each cell of a block of rows, computed once for the block (the rows of a
        // block are near each other in the visit order, so few cells are computed in two
        // blocks); the cells' nodes and kinds beside their pieces: a row then reads nothing of
        // the mesh's cell arrays
        let cell_duals = |rows: &[u32]| {
            (
                BlockCells::new(
                    inc,
                    rows,
                    |_| true,
                    |cells| DualPieces::new(mesh, cells, faces, tensor.as_ref()),
                ),
                std::cell::RefCell::new(RowFaces::default()),
            )
        };
        let order = visit_order(mesh, n_rows);
        let rows: Vec<(f64, [f64; 3], f64)> =
            par_rows_with(&mut s, s_ptr, Some(&order), cell_duals, |(ctx, row_faces), i, s| {
                let cols = &col[row_ptr[i]..row_ptr[i + 1]];
                with_columns(mesh.n_nodes(), cols, |at| {
                    let row_faces = &mut *row_faces.borrow_mut();
                    row_faces.reset(cols.len());
                    let p = &ctx.items;
                    let cell = |slot: u32| {
                        let k = slot as usize;
                        let (kind, nodes) = (p.g.kinds[k], &p.g.nodes[p.g.ptr[k] as usize..p.g.ptr[k + 1] as usize]);
                        let li = nodes.iter().position(|&x| x as usize == i).unwrap();
                        (k, kind, nodes, li, at.of_cell(nodes, li))
                    };
                    let mut v = 0.0;
                    let slots = ctx.row(i);
                    // SAFETY: this iteration is row i's only one
                    let w = unsafe { coef_rows.row(i) };
                    for (&c, &slot) in inc.of(i).iter().zip(slots) {
                        let (k, kind, _, li, pos) = cell(slot);
                        v += p.vol[p.g.ptr[k] as usize + li];
                        match &tensor {
                            Some(_) if kind == CellKind::Tet => add_tet_row(&p.a[k], li, &pos, w),
                            Some(tensor) => tensor.add_other_row(mesh, c as usize, i, at, w),
                            None => {}
                        }
                        let cs = &p.s[p.eptr[k] as usize..];
                        if faces {
                            for (e, edge) in kind.edges().iter().enumerate() {
                                let (other, sign) = if edge[0] == li {
                                    (edge[1], 1.0)
                                } else if edge[1] == li {
                                    (edge[0], -1.0)
                                } else {
                                    continue;
                                };
                                let q = pos[other] as usize;
                                s[q] = add(s[q], scale(cs[e], sign));
                            }
                        }
                        for face in kind.faces() {
                            if let Some(key) = RowFaces::key(face, li, &pos) {
                                row_faces.add(key);
                            }
                        }
                    }
                    // the boundary faces' areas, in the order of the cells and their faces
                    let mut a = [0.0; 3];
                    if row_faces.any() {
                        for &slot in slots {
                            let (_, kind, nodes, li, pos) = cell(slot);
                            for face in kind.faces() {
                                let Some(key) = RowFaces::key(face, li, &pos) else {
                                    continue;
                                };
                                if !row_faces.is_boundary(key) {
                                    continue;
                                }
                                let nf = face.len();
                                let k = face.iter().position(|&l| l == li).unwrap();
                                let next = nodes[face[(k + 1) % nf]] as usize;
                                let prev = nodes[face[(k + nf - 1) % nf]] as usize;
                                let (fnodes, n) = face_nodes(face, nodes);
                                let fcn = centroid(&fnodes[..n], pts);
                                let xi = pts[i];
                                let quad = [xi, scale(add(xi, pts[next]), 0.5), fcn, scale(add(xi, pts[prev]), 0.5)];
                                a = add(a, loop_area(&quad));
                            }
                        }
                    }
                    let da: f64 = s.iter().map(|x| dot(*x, *x).sqrt()).sum();
                    (v, a, da)
                })
            });
        let vol = rows.iter().map(|r| r.0).collect();
        let area = rows.iter().map(|r| r.1).collect();
        let dual_area = if faces {
            rows.iter().map(|r| r.2).collect()
        } else {
            Vec::new()
        };
        tracing::debug!(
            "dual geometry{} of {n_rows} rows in {:.2} s: pair graph {t_pairs:.2} s, {}volumes and boundary faces{} {:.2} s",
            if r.is_some() { " and compact coefficients" } else { "" },
            t.elapsed().as_secs_f64(),
            if faces { "dual faces, " } else { "" },
            if r.is_some() { ", coefficients" } else { "" },
            t.elapsed().as_secs_f64() - t_pairs
        );
        let dual = Dual {
            n_rows,
            row_ptr,
            col,
            s,
            vol,
            area,
            dual_area,
        };
        (dual, coef)
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
        with_columns(mesh.n_nodes(), cols, |at| {
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
                    let p = at.of(nodes[other]);
                    s[p] = add(s[p], scale(cd.s[e], sign));
                }
            }
        })
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

/// A cell's tensor for the compact coefficients: the mean of its nodes', weighed by its young
/// where tissues weigh (`cell_young`; no weight at all unless `Materials::weighs_young`).
struct CellTensor<'a> {
    r: &'a Materials,
    weighs: bool,
}

impl<'a> CellTensor<'a> {
    fn new(r: &'a Materials) -> Self {
        CellTensor {
            r,
            weighs: r.weighs_young(),
        }
    }

    fn of(&self, nodes: &[u32]) -> Matrix3<f64> {
        let mut rc = Matrix3::zeros();
        for &n in nodes {
            rc += self.r.r(n as usize);
        }
        rc /= nodes.len() as f64;
        if self.weighs {
            rc *= cell_young(nodes, self.r);
        }
        rc
    }

    /// A tetrahedron's coefficient a_ab of each pair of its nodes (`TET_PAIRS`), from its
    /// nodes and their points `x`: a_ab = -V grad N_a . R grad N_b, for (a, b) in increasing
    /// local order so that a_ab == a_ba bitwise.
    fn tet(&self, nodes: &[u32], x: &[[f64; 3]]) -> [f64; 6] {
        let (gr, v) = tet_gradients(&LOCAL[..4], x);
        let rc = self.of(nodes);
        let mut a = [0.0; 6];
        for (k, &(lo, hi)) in TET_PAIRS.iter().enumerate() {
            let rg = rc * Vector3::from(gr[hi]);
            a[k] = -v * (gr[lo][0] * rg[0] + gr[lo][1] * rg[1] + gr[lo][2] * rg[2]);
        }
        a
    }

    /// Adds to row i's coefficients `w` those of the mesh's cell `c`, not a tetrahedron: the
    /// exact flux of R grad u (its Green-Gauss gradient) through i's dual faces in the cell.
    fn add_other_row(&self, mesh: &Mesh, c: usize, i: usize, at: Columns<'_>, w: &mut [f64]) {
        let pts = &mesh.points;
        let kind = mesh.kinds[c];
        let nodes = mesh.cell(c);
        let li = nodes.iter().position(|&x| x as usize == i).unwrap();
        let rc = self.of(nodes);
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
            w[at.of(nodes[lk])] += val;
        }
    }
}

/// Adds to the coefficients `w` of the row of a tetrahedron's local node `li` the
/// tetrahedron's (`CellTensor::tet`); `pos`: the positions of its local nodes among the row's
/// columns (`Columns::of_cell`).
fn add_tet_row(a: &[f64; 6], li: usize, pos: &[u32; MAX_NODES], w: &mut [f64]) {
    for lk in (0..4).filter(|&lk| lk != li) {
        w[pos[lk] as usize] += a[TET_PAIR_OF[li.min(lk)][li.max(lk)]];
    }
}

/// Compact-scheme coefficients a_ij of rows `0..n_rows` on the pair graph of `dual`:
/// sum_j a_ij (u_j - u_i) is the exact flux of (E/E0) R grad u (cell gradients) into the
/// control volume of i. `r` gives the tensor and young of every local node; a cell uses the
/// mean of its nodes' tensors and `cell_young` (no weight at all unless
/// `Materials::weighs_young`).
pub fn compact_coefficients(mesh: &Mesh, inc: &Incidence, dual: &Dual, r: &Materials) -> Vec<f64> {
    let t = std::time::Instant::now();
    let mut out = vec![0.0; dual.row_ptr[dual.n_rows]];
    let order = visit_order(mesh, dual.n_rows);
    let tensor = CellTensor::new(r);
    // the coefficients of each tetrahedron of a block of rows, computed once for the block
    // (as the dual's cell pieces in `Dual::build`)
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
                        (tensor.tet(nodes, x), [nodes[0], nodes[1], nodes[2], nodes[3]])
                    })
                    .collect::<Vec<_>>()
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
            with_columns(mesh.n_nodes(), cols, |at| {
                let slots = ctx.row(i);
                for (&c, &slot) in inc.of(i).iter().zip(slots) {
                    if slot != u32::MAX {
                        // a tetrahedron: its nodes and coefficients are the block's
                        let (a, nodes) = &ctx.items[slot as usize];
                        let li = nodes.iter().position(|&x| x as usize == i).unwrap();
                        add_tet_row(a, li, &at.of_cell(nodes, li), w);
                    } else {
                        tensor.add_other_row(mesh, c as usize, i, at, w);
                    }
                }
            })
        },
    );
    tracing::debug!(
        "compact coefficients of {} rows in {:.2} s",
        dual.n_rows,
        t.elapsed().as_secs_f64()
    );
    out
}
