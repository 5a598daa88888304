//! The in-memory mesh every reader produces and every consumer reads.
//!
//! Nodes keep the order of the input file (output datasets use the same order).
//! Volume cells and lower-dimensional elements (surface, line, point) are kept apart:
//! only volume cells take part in the geometry; the others carry tags for boundary sets.

use std::collections::BTreeMap;

/// A first-order volume cell type. Local node order is the one shared by Gmsh and VTK.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum CellKind {
    Tet,
    Hex,
    Wedge,
    Pyramid,
}

const TET_EDGES: [[usize; 2]; 6] = [[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]];
const TET_FACES: [&[usize]; 4] = [&[0, 2, 1], &[0, 1, 3], &[1, 2, 3], &[0, 3, 2]];
const HEX_EDGES: [[usize; 2]; 12] = [
    [0, 1],
    [1, 2],
    [2, 3],
    [0, 3],
    [4, 5],
    [5, 6],
    [6, 7],
    [4, 7],
    [0, 4],
    [1, 5],
    [2, 6],
    [3, 7],
];
const HEX_FACES: [&[usize]; 6] = [
    &[0, 3, 2, 1],
    &[4, 5, 6, 7],
    &[0, 1, 5, 4],
    &[1, 2, 6, 5],
    &[2, 3, 7, 6],
    &[3, 0, 4, 7],
];
const WEDGE_EDGES: [[usize; 2]; 9] = [[0, 1], [1, 2], [0, 2], [3, 4], [4, 5], [3, 5], [0, 3], [1, 4], [2, 5]];
const WEDGE_FACES: [&[usize]; 5] = [&[0, 2, 1], &[3, 4, 5], &[0, 1, 4, 3], &[1, 2, 5, 4], &[2, 0, 3, 5]];
const PYR_EDGES: [[usize; 2]; 8] = [[0, 1], [1, 2], [2, 3], [0, 3], [0, 4], [1, 4], [2, 4], [3, 4]];
const PYR_FACES: [&[usize]; 5] = [&[0, 3, 2, 1], &[0, 1, 4], &[1, 2, 4], &[2, 3, 4], &[3, 0, 4]];

impl CellKind {
    pub fn n_nodes(self) -> usize {
        match self {
            CellKind::Tet => 4,
            CellKind::Hex => 8,
            CellKind::Wedge => 6,
            CellKind::Pyramid => 5,
        }
    }
    /// Local edges (pairs of local node indices).
    pub fn edges(self) -> &'static [[usize; 2]] {
        match self {
            CellKind::Tet => &TET_EDGES,
            CellKind::Hex => &HEX_EDGES,
            CellKind::Wedge => &WEDGE_EDGES,
            CellKind::Pyramid => &PYR_EDGES,
        }
    }
    /// Local faces, each wound so that its normal points out of a positively oriented cell.
    pub fn faces(self) -> &'static [&'static [usize]] {
        match self {
            CellKind::Tet => &TET_FACES,
            CellKind::Hex => &HEX_FACES,
            CellKind::Wedge => &WEDGE_FACES,
            CellKind::Pyramid => &PYR_FACES,
        }
    }
    pub fn vtk_type(self) -> u8 {
        match self {
            CellKind::Tet => 10,
            CellKind::Hex => 12,
            CellKind::Wedge => 13,
            CellKind::Pyramid => 14,
        }
    }
    pub fn gmsh_type(self) -> u32 {
        match self {
            CellKind::Tet => 4,
            CellKind::Hex => 5,
            CellKind::Wedge => 6,
            CellKind::Pyramid => 7,
        }
    }
    pub fn from_gmsh(t: u32) -> Option<CellKind> {
        match t {
            4 => Some(CellKind::Tet),
            5 => Some(CellKind::Hex),
            6 => Some(CellKind::Wedge),
            7 => Some(CellKind::Pyramid),
            _ => None,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            CellKind::Tet => "tetrahedron",
            CellKind::Hex => "hexahedron",
            CellKind::Wedge => "prism",
            CellKind::Pyramid => "pyramid",
        }
    }
    /// A permutation of the local nodes that reverses the orientation.
    pub fn flip(self) -> &'static [usize] {
        match self {
            CellKind::Tet => &[0, 2, 1, 3],
            CellKind::Hex => &[0, 3, 2, 1, 4, 7, 6, 5],
            CellKind::Wedge => &[0, 2, 1, 3, 5, 4],
            CellKind::Pyramid => &[0, 3, 2, 1, 4],
        }
    }
}

/// An unstructured volume mesh with tags.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Where it came from (file name, or a generator description); used in messages.
    pub source: String,
    pub points: Vec<[f64; 3]>,
    /// Node ids as the file numbered them (1-based in Gmsh, sparse allowed).
    pub node_ids: Vec<u64>,
    pub kinds: Vec<CellKind>,
    /// `offsets[c]..offsets[c+1]` indexes `conn` for cell `c`.
    pub offsets: Vec<usize>,
    pub conn: Vec<u32>,
    /// Physical tag of each volume cell (0 when the file gave none).
    pub cell_tags: Vec<i32>,
    /// Element ids as the file numbered the volume cells (empty: cell index + 1).
    pub cell_ids: Vec<u64>,
    /// Lower-dimensional elements (triangles, quads, lines, points) kept for their tags.
    pub facets: Facets,
    /// Physical group names: (dimension, tag) -> name.
    pub group_names: BTreeMap<(u8, i32), String>,
    /// Things the reader repaired or noticed, for `eprop info` and the run log.
    pub warnings: Vec<String>,
}

/// Lower-dimensional elements with their physical tags.
#[derive(Clone, Debug, Default)]
pub struct Facets {
    pub dim: Vec<u8>,
    pub tags: Vec<i32>,
    pub offsets: Vec<usize>,
    pub conn: Vec<u32>,
}

impl Facets {
    pub fn new() -> Self {
        Facets {
            offsets: vec![0],
            ..Default::default()
        }
    }
    pub fn len(&self) -> usize {
        self.tags.len()
    }
    pub fn is_empty(&self) -> bool {
        self.tags.is_empty()
    }
    pub fn push(&mut self, dim: u8, tag: i32, nodes: &[u32]) {
        self.dim.push(dim);
        self.tags.push(tag);
        self.conn.extend_from_slice(nodes);
        self.offsets.push(self.conn.len());
    }
    pub fn nodes(&self, f: usize) -> &[u32] {
        &self.conn[self.offsets[f]..self.offsets[f + 1]]
    }
}

impl Mesh {
    pub fn new(source: impl Into<String>) -> Self {
        Mesh {
            source: source.into(),
            offsets: vec![0],
            facets: Facets::new(),
            ..Default::default()
        }
    }
    pub fn n_nodes(&self) -> usize {
        self.points.len()
    }
    pub fn n_cells(&self) -> usize {
        self.kinds.len()
    }
    /// The file's id of volume cell `c`, for messages.
    pub fn cell_id(&self, c: usize) -> u64 {
        self.cell_ids.get(c).copied().unwrap_or(c as u64 + 1)
    }
    /// The file's id of node `n`, for messages.
    pub fn node_id(&self, n: usize) -> u64 {
        self.node_ids.get(n).copied().unwrap_or(n as u64 + 1)
    }
    #[inline]
    pub fn cell(&self, c: usize) -> &[u32] {
        &self.conn[self.offsets[c]..self.offsets[c + 1]]
    }
    pub fn push_cell(&mut self, kind: CellKind, nodes: &[u32], tag: i32) {
        debug_assert_eq!(nodes.len(), kind.n_nodes());
        self.kinds.push(kind);
        self.conn.extend_from_slice(nodes);
        self.offsets.push(self.conn.len());
        self.cell_tags.push(tag);
    }
    /// Counts of each cell kind, for summaries.
    pub fn kind_counts(&self) -> BTreeMap<CellKind, usize> {
        let mut m = BTreeMap::new();
        for k in &self.kinds {
            *m.entry(*k).or_insert(0) += 1;
        }
        m
    }
    /// The tag of a physical group given by name (any dimension).
    pub fn group_tag(&self, name: &str) -> Option<(u8, i32)> {
        self.group_names
            .iter()
            .find(|(_, n)| n.as_str() == name)
            .map(|(k, _)| *k)
    }
    /// Axis-aligned bounding box.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &self.points {
            for d in 0..3 {
                lo[d] = lo[d].min(p[d]);
                hi[d] = hi[d].max(p[d]);
            }
        }
        (lo, hi)
    }
}

/// Boundary faces of the volume cells: faces that belong to exactly one cell, wound outward.
/// Returned as (cell index, local face index) in cell order.
pub fn boundary_faces(mesh: &Mesh) -> Vec<(u32, u8)> {
    let mut out = Vec::new();
    let _ = for_each_face(mesh, |_, cells| {
        if let [one] = cells {
            out.push(*one);
        }
        Ok::<(), ()>(())
    });
    out.sort_unstable();
    out
}

/// Calls `f(key, cells)` for every distinct face of the mesh: its sorted node ids (`face_key`)
/// and the (cell, local face) pairs that have it, in cell order. Faces are grouped by their
/// smallest node (4 bytes per face, not a table of every face's key). Stops at the first error.
pub fn for_each_face<E>(mesh: &Mesh, mut f: impl FnMut(&[u32; 4], &[(u32, u8)]) -> Result<(), E>) -> Result<(), E> {
    let faces_of = |c: usize| mesh.kinds[c].faces();
    let (ptr, items) = group_by_node(mesh.n_nodes(), mesh.n_cells(), 8, |c, f| {
        let face = faces_of(c).get(f)?;
        Some(face_key(mesh.cell(c), face)[0])
    });
    let mut keys: Vec<([u32; 4], u32, u8)> = Vec::new();
    let mut run: Vec<(u32, u8)> = Vec::new();
    for n in 0..mesh.n_nodes() {
        keys.clear();
        keys.extend(items[ptr[n] as usize..ptr[n + 1] as usize].iter().map(|&it| {
            let (c, lf) = ((it >> 3) as usize, (it & 7) as usize);
            (face_key(mesh.cell(c), faces_of(c)[lf]), c as u32, lf as u8)
        }));
        keys.sort_unstable();
        for group in keys.chunk_by(|a, b| a.0 == b.0) {
            run.clear();
            run.extend(group.iter().map(|k| (k.1, k.2)));
            f(&group[0].0, &run)?;
        }
    }
    Ok(())
}

/// Items `(cell, slot)` for `slot < per_cell`, grouped by the node `key` gives them (`None`:
/// no such item), as CSR: `ptr` per node, items encoded `cell * per_cell + slot` (`per_cell`
/// is 1 or 8). Two passes, so the memory is 4 bytes per item.
pub fn group_by_node(
    np: usize,
    n_cells: usize,
    per_cell: usize,
    key: impl Fn(usize, usize) -> Option<u32>,
) -> (Vec<u32>, Vec<u32>) {
    assert!(
        (n_cells as u64) * (per_cell as u64) < u32::MAX as u64,
        "more than 2^32 cell items: {n_cells} cells"
    );
    let key = &key;
    let keys = |c: usize| (0..per_cell).filter_map(move |f| key(c, f).map(|n| (f, n)));
    let mut ptr = vec![0u32; np + 1];
    for c in 0..n_cells {
        for (_, n) in keys(c) {
            ptr[n as usize + 1] += 1;
        }
    }
    for n in 0..np {
        ptr[n + 1] += ptr[n];
    }
    let mut at: Vec<u32> = ptr[..np].to_vec();
    let mut items = vec![0u32; ptr[np] as usize];
    for c in 0..n_cells {
        for (f, n) in keys(c) {
            items[at[n as usize] as usize] = (c * per_cell + f) as u32;
            at[n as usize] += 1;
        }
    }
    (ptr, items)
}

/// Sorted node ids of a face, padded with u32::MAX.
#[inline]
pub fn face_key(nodes: &[u32], face: &[usize]) -> [u32; 4] {
    let mut k = [u32::MAX; 4];
    for (i, &l) in face.iter().enumerate() {
        k[i] = nodes[l];
    }
    // a sorting network of four (five compare-exchanges, no branches to mispredict)
    let mut cx = |a: usize, b: usize| {
        let (x, y) = (k[a], k[b]);
        k[a] = x.min(y);
        k[b] = x.max(y);
    };
    cx(0, 1);
    cx(2, 3);
    cx(0, 2);
    cx(1, 3);
    cx(1, 2);
    k
}

/// Connected components of the cells (nodes sharing a cell): a component id per node, and
/// the number of components (cell-less nodes get their own ids).
pub fn components(mesh: &Mesh) -> (Vec<u32>, usize) {
    let n = mesh.n_nodes();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn root(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    for c in 0..mesh.n_cells() {
        let cell = mesh.cell(c);
        let r0 = root(&mut parent, cell[0]);
        for &v in &cell[1..] {
            let r = root(&mut parent, v);
            if r != r0 {
                parent[r as usize] = r0;
            }
        }
    }
    let mut id = vec![u32::MAX; n];
    let mut comp = vec![0u32; n];
    let mut count = 0usize;
    for i in 0..n {
        let r = root(&mut parent, i as u32) as usize;
        if id[r] == u32::MAX {
            id[r] = count as u32;
            count += 1;
        }
        comp[i] = id[r];
    }
    (comp, count)
}
