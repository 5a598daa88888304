//! VTK legacy `.vtk` UNSTRUCTURED_GRID reader: the 4.2 layout (`CELLS n size` with counts)
//! and the 5.1 layout (`OFFSETS` / `CONNECTIVITY` arrays), ASCII and BINARY (big-endian).
//! Also holds the cell-type mapping shared with the `.vtu` reader.

use crate::mesh::{CellKind, Mesh};
use crate::scan::{cap, decode, parse_text, pick_tags, reserve, short, Scan, Ty, Vals};
use anyhow::{anyhow, bail, Result};

/// What a VTK cell type becomes.
enum VtkCell {
    /// A volume cell; `perm[k]` is the VTK local node that becomes local node `k`.
    Volume(CellKind, &'static [usize]),
    Facet(u8, usize),
    Skip,
    Unsupported(&'static str),
}

fn vtk_cell(t: i64) -> VtkCell {
    match t {
        10 => VtkCell::Volume(CellKind::Tet, &[0, 1, 2, 3]),
        12 => VtkCell::Volume(CellKind::Hex, &[0, 1, 2, 3, 4, 5, 6, 7]),
        11 => VtkCell::Volume(CellKind::Hex, &[0, 1, 3, 2, 4, 5, 7, 6]),
        // VTK winds the first triangle of a wedge the other way round from Gmsh
        13 => VtkCell::Volume(CellKind::Wedge, &[0, 2, 1, 3, 5, 4]),
        14 => VtkCell::Volume(CellKind::Pyramid, &[0, 1, 2, 3, 4]),
        5 => VtkCell::Facet(2, 3),
        9 => VtkCell::Facet(2, 4),
        3 => VtkCell::Facet(1, 2),
        24 => VtkCell::Unsupported("quadratic tetrahedron (VTK type 24)"),
        25 => VtkCell::Unsupported("quadratic hexahedron (VTK type 25)"),
        26 => VtkCell::Unsupported("quadratic wedge (VTK type 26)"),
        27 => VtkCell::Unsupported("quadratic pyramid (VTK type 27)"),
        29 => VtkCell::Unsupported("triquadratic hexahedron (VTK type 29)"),
        32 => VtkCell::Unsupported("biquadratic-quadratic wedge (VTK type 32)"),
        33 => VtkCell::Unsupported("biquadratic-quadratic hexahedron (VTK type 33)"),
        42 => VtkCell::Unsupported("polyhedron (VTK type 42)"),
        71..=74 | 79..=81 => VtkCell::Unsupported("Lagrange/Bezier higher-order volume cell"),
        15 | 16 => VtkCell::Unsupported("pentagonal/hexagonal prism"),
        _ => VtkCell::Skip,
    }
}

/// The volume cell of VTK type `t` and the permutation from VTK's node order to eprop's
/// (`nodes[i] = vtk_nodes[perm[i]]`); None for a facet, a skipped or an unsupported type.
pub fn volume_cell(t: i64) -> Option<(CellKind, &'static [usize])> {
    match vtk_cell(t) {
        VtkCell::Volume(kind, perm) => Some((kind, perm)),
        _ => None,
    }
}

/// Inverse of the VTK permutation: local node order to write for a cell kind.
pub fn vtk_order(kind: CellKind, nodes: &[u32]) -> Vec<u32> {
    match kind {
        CellKind::Wedge if nodes.len() == 6 => vec![nodes[0], nodes[2], nodes[1], nodes[3], nodes[5], nodes[4]],
        _ => nodes.to_vec(),
    }
}

/// The VTK type of a facet of dimension `dim` with `n` nodes (triangle, quad, line), if any.
pub fn facet_vtk_type(dim: u8, n: usize) -> Option<u8> {
    match (dim, n) {
        (2, 3) => Some(5),
        (2, 4) => Some(9),
        (1, 2) => Some(3),
        _ => None,
    }
}

/// Data common to the legacy and XML readers, before it becomes a `Mesh`.
pub struct VtkData {
    pub points: Vec<f64>,
    pub conn: Vec<i64>,
    /// `starts[c]..starts[c+1]` indexes `conn` (length cells + 1).
    pub starts: Vec<i64>,
    pub types: Vec<i64>,
    pub cell_arrays: Vec<(String, Vals)>,
    pub point_arrays: Vec<(String, Vals)>,
}

/// Builds a mesh from VTK arrays, checking every index against the arrays' lengths.
pub fn build(name: &str, d: VtkData) -> Result<Mesh> {
    if !d.points.len().is_multiple_of(3) {
        bail!(
            "{name}: the points array holds {} values, not a multiple of 3; fix: export the points with 3 components",
            d.points.len()
        );
    }
    let np = d.points.len() / 3;
    let nc = d.types.len();
    if d.starts.len() != nc + 1 {
        bail!(
            "{name}: {} cell types but {} cell offsets; fix: the cell arrays disagree, export the mesh again",
            nc,
            d.starts.len().saturating_sub(1)
        );
    }
    let mut mesh = Mesh::new(name);
    mesh.points = d.points.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
    mesh.node_ids = (0..np as u64).collect();
    if let Some((_, v)) = d.point_arrays.iter().find(|(n, _)| n == "node_ids") {
        if let Some(ids) = v.to_i64() {
            let mut seen = std::collections::HashSet::new();
            if ids.len() == np && ids.iter().all(|&i| i >= 0 && seen.insert(i)) {
                mesh.node_ids = ids.iter().map(|&i| i as u64).collect();
            }
        }
    }
    let tags = pick_tags(&d.cell_arrays, nc, &mut mesh.warnings);
    let mut skipped = 0usize;
    let mut buf: Vec<u32> = Vec::with_capacity(8);
    for c in 0..nc {
        let (s, e) = (d.starts[c], d.starts[c + 1]);
        if s < 0 || e < s || e as u64 > d.conn.len() as u64 {
            bail!(
                "{name}: cell {c}: offsets {s}..{e} are outside the connectivity array ({} entries); fix: the cell arrays are inconsistent, export the mesh again",
                d.conn.len()
            );
        }
        let nodes = &d.conn[s as usize..e as usize];
        buf.clear();
        for &n in nodes {
            if n < 0 || n as u64 >= np as u64 {
                bail!("{name}: cell {c} names node {n}, but the file has {np} points (0..{}); fix: repair the connectivity", np.saturating_sub(1));
            }
            buf.push(n as u32);
        }
        let tag = tags.as_ref().map(|t| t[c]).unwrap_or(0);
        let t = d.types[c];
        match vtk_cell(t) {
            VtkCell::Volume(kind, perm) => {
                if buf.len() != perm.len() {
                    bail!("{name}: cell {c} ({}) has {} nodes, expected {}; fix: repair the cell", kind.name(), buf.len(), perm.len());
                }
                let nodes: Vec<u32> = perm.iter().map(|&p| buf[p]).collect();
                mesh.push_cell(kind, &nodes, tag);
                mesh.cell_ids.push(c as u64);
            }
            VtkCell::Facet(dim, nn) => {
                if buf.len() != nn {
                    bail!("{name}: cell {c} (VTK type {t}) has {} nodes, expected {nn}; fix: repair the cell", buf.len());
                }
                mesh.facets.push(dim, tag, &buf);
            }
            VtkCell::Skip => skipped += 1,
            VtkCell::Unsupported(what) => bail!(
                "{name}: cell {c} is a {what}, which eprop does not read; fix: re-mesh with first-order tetrahedra, hexahedra, prisms or pyramids"
            ),
        }
    }
    if skipped > 0 {
        mesh.warnings.push(format!(
            "{skipped} cell(s) of other types (vertices, polygons, ...) skipped"
        ));
    }
    Ok(mesh)
}

/// Reads values after a keyword line: binary (big-endian, right after the line) or text.
fn values(sc: &mut Scan, binary: bool, n: usize, ty: Ty, what: &str) -> Result<Vals> {
    values_from(sc, binary, true, n, ty, what)
}

/// As `values`; `line_pending` says the keyword line's newline is still ahead of the cursor.
fn values_from(sc: &mut Scan, binary: bool, line_pending: bool, n: usize, ty: Ty, what: &str) -> Result<Vals> {
    if binary {
        if line_pending {
            sc.rest_of_line();
        }
        let nb = n
            .checked_mul(ty.size())
            .ok_or_else(|| sc.err(format!("{what}: count {n} is too large; fix: repair the count")))?;
        let bytes = sc.raw(nb, what)?;
        Ok(decode(bytes, ty, true))
    } else {
        parse_text(sc, n, ty, what)
    }
}

fn ty_of(sc: &mut Scan, what: &str) -> Result<Ty> {
    let w = sc.word(what)?;
    Ty::from_legacy(w).ok_or_else(|| {
        sc.err(format!(
            "unknown data type `{}` for {what}; fix: use int, long, vtktypeint64, float or double",
            short(w)
        ))
    })
}

fn ints(v: Vals, sc: &Scan, what: &str) -> Result<Vec<i64>> {
    v.to_i64()
        .ok_or_else(|| sc.err(format!("{what} holds non-integer values; fix: write them as integers")))
}

/// What the sections of a legacy file hold, gathered keyword by keyword.
#[derive(Default)]
struct Parts {
    points: Option<Vec<f64>>,
    conn: Option<Vec<i64>>,
    starts: Option<Vec<i64>>,
    types: Option<Vec<i64>>,
    cell_arrays: Vec<(String, Vals)>,
    point_arrays: Vec<(String, Vals)>,
    /// The data section the arrays that follow belong to: 'C' cell data, 'P' point data, and
    /// its count.
    attr: Option<(char, usize)>,
}

impl Parts {
    /// Keeps a one-component array of the current data section.
    fn push(&mut self, which: char, name: String, v: Vals) {
        if which == 'C' {
            self.cell_arrays.push((name, v));
        } else {
            self.point_arrays.push((name, v));
        }
    }
}

/// A legacy file after its header: the cursor, ASCII or BINARY, and the major version.
struct Legacy<'a> {
    sc: Scan<'a>,
    binary: bool,
    major: u32,
}

/// Parses a legacy VTK file.
pub fn parse(name: &str, bytes: &[u8]) -> Result<Mesh> {
    let mut rd = header(name, bytes)?;
    let mut p = Parts::default();
    while let Some(t) = rd.sc.token() {
        let kpos = rd.sc.pos;
        let key = String::from_utf8_lossy(t).to_ascii_uppercase();
        match key.as_str() {
            "POINTS" => p.points = Some(rd.points()?),
            "CELLS" => {
                let (starts, conn) = rd.cells(kpos)?;
                p.starts = Some(starts);
                p.conn = Some(conn);
            }
            "CELL_TYPES" => p.types = Some(rd.cell_types()?),
            "CELL_DATA" => p.attr = Some(('C', rd.sc.count("the cell data count")?)),
            "POINT_DATA" => p.attr = Some(('P', rd.sc.count("the point data count")?)),
            "SCALARS" | "VECTORS" | "NORMALS" | "TENSORS" | "TEXTURE_COORDINATES" | "COLOR_SCALARS" | "FIELD" => {
                rd.data_arrays(&key, kpos, &mut p)?
            }
            "LOOKUP_TABLE" => rd.lookup_table()?,
            "METADATA" => rd.metadata(),
            _ => {
                return Err(rd.sc.err_at(
                    kpos,
                    format!(
                        "unexpected `{}`; fix: the file is malformed or a count is wrong",
                        short(&key)
                    ),
                ));
            }
        }
    }
    let points = p
        .points
        .ok_or_else(|| anyhow!("{name}: no POINTS section; fix: the file holds no mesh"))?;
    let (Some(conn), Some(starts)) = (p.conn, p.starts) else {
        bail!("{name}: no CELLS section; fix: the file holds no cells");
    };
    let types = p
        .types
        .ok_or_else(|| anyhow!("{name}: no CELL_TYPES section; fix: the file is incomplete, export it again"))?;
    build(
        name,
        VtkData {
            points,
            conn,
            starts,
            types,
            cell_arrays: p.cell_arrays,
            point_arrays: p.point_arrays,
        },
    )
}

/// The first four lines: version, title, ASCII or BINARY, `DATASET UNSTRUCTURED_GRID`.
fn header<'a>(name: &'a str, bytes: &'a [u8]) -> Result<Legacy<'a>> {
    let mut sc = Scan::new(name, bytes);
    let l1 = String::from_utf8_lossy(sc.rest_of_line()).trim().to_string();
    let Some(ver) = l1
        .strip_prefix("# vtk DataFile Version")
        .or_else(|| l1.strip_prefix("# vtk DataFile version"))
    else {
        return Err(sc.err_at(
            0,
            format!(
                "`{}` is not a VTK legacy header (`# vtk DataFile Version x.y`); fix: check the file type",
                short(&l1)
            ),
        ));
    };
    let major: u32 = ver.trim().split('.').next().and_then(|s| s.parse().ok()).unwrap_or(0);
    sc.rest_of_line(); // title
    let fmt = sc.word("ASCII or BINARY")?.to_ascii_uppercase();
    let binary = match fmt.as_str() {
        "ASCII" => false,
        "BINARY" => true,
        _ => {
            return Err(sc.err(format!(
                "expected ASCII or BINARY on line 3, found `{}`; fix: repair the header",
                short(&fmt)
            )))
        }
    };
    let kw = sc.word("DATASET")?;
    if !kw.eq_ignore_ascii_case("DATASET") {
        return Err(sc.err(format!(
            "expected DATASET, found `{}`; fix: repair the header",
            short(kw)
        )));
    }
    let ds = sc.word("the dataset type")?.to_ascii_uppercase();
    if ds != "UNSTRUCTURED_GRID" {
        return Err(sc.err(format!(
            "dataset `{}` is not a volume mesh (UNSTRUCTURED_GRID is read); fix: tetrahedralize the surface first (e.g. tetgen -pq) and save an unstructured grid",
            short(&ds)
        )));
    }
    Ok(Legacy { sc, binary, major })
}

impl Legacy<'_> {
    fn values(&mut self, n: usize, ty: Ty, what: &str) -> Result<Vals> {
        values(&mut self.sc, self.binary, n, ty, what)
    }

    /// `POINTS n type` and 3n values.
    fn points(&mut self) -> Result<Vec<f64>> {
        let sc = &mut self.sc;
        let n = sc.count("the point count")?;
        let ty = ty_of(sc, "POINTS")?;
        let n3 = n
            .checked_mul(3)
            .ok_or_else(|| sc.err("point count too large; fix: repair the count"))?;
        Ok(self.values(n3, ty, "the points")?.to_f64())
    }

    /// `CELLS a b` in either layout: (starts, connectivity).
    fn cells(&mut self, kpos: usize) -> Result<(Vec<i64>, Vec<i64>)> {
        let a = self.sc.count("the cell count")?;
        let b = self.sc.count("the cell list size")?;
        let p = self.sc.pos;
        let next = self.sc.token().map(|t| t.to_ascii_uppercase());
        self.sc.pos = p;
        if next.as_deref() == Some(b"OFFSETS") || self.major >= 5 {
            self.cells_v51(a, b)
        } else {
            self.cells_v42(a, b, kpos)
        }
    }

    /// The 5.1 layout: `OFFSETS type` and a values, `CONNECTIVITY type` and b values.
    fn cells_v51(&mut self, a: usize, b: usize) -> Result<(Vec<i64>, Vec<i64>)> {
        let major = self.major;
        let k = self.sc.word("OFFSETS")?;
        if !k.eq_ignore_ascii_case("OFFSETS") {
            return Err(self.sc.err(format!(
                "expected OFFSETS after CELLS in a version {major} file, found `{}`; fix: repair the file",
                short(k)
            )));
        }
        let ty = ty_of(&mut self.sc, "OFFSETS")?;
        let off = ints(self.values(a, ty, "the cell offsets")?, &self.sc, "OFFSETS")?;
        let k = self.sc.word("CONNECTIVITY")?;
        if !k.eq_ignore_ascii_case("CONNECTIVITY") {
            return Err(self.sc.err(format!(
                "expected CONNECTIVITY, found `{}`; fix: repair the file",
                short(k)
            )));
        }
        let ty = ty_of(&mut self.sc, "CONNECTIVITY")?;
        let c = ints(self.values(b, ty, "the connectivity")?, &self.sc, "CONNECTIVITY")?;
        if off.first().copied().unwrap_or(0) != 0 {
            return Err(self.sc.err("the first cell offset is not 0; fix: repair OFFSETS"));
        }
        Ok((if off.is_empty() { vec![0] } else { off }, c))
    }

    /// The 4.2 layout: b integers, each cell as `count ids...`.
    fn cells_v42(&mut self, a: usize, b: usize, kpos: usize) -> Result<(Vec<i64>, Vec<i64>)> {
        let list = ints(self.values(b, Ty::I32, "the cell list")?, &self.sc, "CELLS")?;
        let sc = &self.sc;
        let (mut st, mut cn) = (Vec::new(), Vec::new());
        reserve(&mut st, cap(a, list.len(), 1) + 1, sc.name)?;
        reserve(&mut cn, list.len(), sc.name)?;
        let mut i = 0usize;
        st.push(0i64);
        for c in 0..a {
            let Some(&k) = list.get(i) else {
                return Err(sc.err_at(kpos, format!("CELLS announces {a} cells in {b} integers, but the list ends at cell {c}; fix: the counts disagree, export the mesh again")));
            };
            if k < 0 || (k as u64) > (list.len() - i - 1) as u64 {
                return Err(sc.err_at(kpos, format!("cell {c} announces {k} nodes, more than the list holds; fix: the counts disagree, export the mesh again")));
            }
            cn.extend_from_slice(&list[i + 1..i + 1 + k as usize]);
            i += 1 + k as usize;
            st.push(cn.len() as i64);
        }
        if i != list.len() {
            return Err(sc.err_at(kpos, format!("CELLS announces {a} cells in {b} integers, but the cells use {i}; fix: the counts disagree, export the mesh again")));
        }
        Ok((st, cn))
    }

    /// `CELL_TYPES n` and n integers.
    fn cell_types(&mut self) -> Result<Vec<i64>> {
        let n = self.sc.count("the cell type count")?;
        ints(self.values(n, Ty::I32, "the cell types")?, &self.sc, "CELL_TYPES")
    }

    /// The arrays of one attribute keyword of the current data section; one-component arrays
    /// are kept (cell tag candidates, `node_ids`).
    fn data_arrays(&mut self, key: &str, kpos: usize, p: &mut Parts) -> Result<()> {
        let binary = self.binary;
        let Some((which, n)) = p.attr else {
            return Err(self.sc.err_at(
                kpos,
                format!("{key} before CELL_DATA or POINT_DATA; fix: repair the file"),
            ));
        };
        let sc = &mut self.sc;
        let aname = sc.word("the array name")?.to_string();
        let mut arrays: Vec<(String, usize, Ty)> = Vec::new();
        match key {
            "SCALARS" => {
                let Some(a) = self.scalars(aname, which, n, p)? else {
                    return Ok(());
                };
                arrays.push(a);
            }
            "VECTORS" | "NORMALS" => arrays.push((aname, 3, ty_of(sc, key)?)),
            "TENSORS" => arrays.push((aname, 9, ty_of(sc, key)?)),
            "TEXTURE_COORDINATES" => {
                let d = sc.count("the dimension")?;
                arrays.push((aname, d, ty_of(sc, key)?));
            }
            "COLOR_SCALARS" => {
                let d = sc.count("the component count")?;
                arrays.push((aname, d, if binary { Ty::U8 } else { Ty::F32 }));
            }
            _ => return self.field(which, n, p),
        }
        for (an, ncomp, ty) in arrays {
            let len = ncomp
                .checked_mul(n)
                .ok_or_else(|| self.sc.err("data array too large; fix: repair the counts"))?;
            let v = self.values(len, ty, "a data array")?;
            if ncomp == 1 {
                p.push(which, an, v);
            }
        }
        Ok(())
    }

    /// `SCALARS name type [ncomp]`: without a `LOOKUP_TABLE` line its values follow at once
    /// (read here, None returned); with one, the array is returned for the caller to read.
    fn scalars(&mut self, aname: String, which: char, n: usize, p: &mut Parts) -> Result<Option<(String, usize, Ty)>> {
        let sc = &mut self.sc;
        let ty = ty_of(sc, "SCALARS")?;
        // optional component count on the same line
        let rest = String::from_utf8_lossy(sc.rest_of_line()).to_string();
        let ncomp: usize = rest.split_whitespace().next().and_then(|s| s.parse().ok()).unwrap_or(1);
        let pos = sc.pos;
        if sc.token().map(|t| t.eq_ignore_ascii_case(b"LOOKUP_TABLE")) == Some(true) {
            sc.word("the lookup table name")?;
            return Ok(Some((aname, ncomp.max(1), ty)));
        }
        sc.pos = pos;
        let len = ncomp
            .max(1)
            .checked_mul(n)
            .ok_or_else(|| sc.err("data array too large; fix: repair the counts"))?;
        let v = values_from(sc, self.binary, false, len, ty, "a data array")?;
        if ncomp <= 1 {
            p.push(which, aname, v);
        }
        Ok(None)
    }

    /// `FIELD name k`, then k arrays `name ncomp ntuples type` with their values.
    fn field(&mut self, which: char, n: usize, p: &mut Parts) -> Result<()> {
        let k = self.sc.count("the field array count")?;
        for _ in 0..k {
            let sc = &mut self.sc;
            let an = sc.word("a field array name")?.to_string();
            let nc = sc.count("the component count")?;
            let nt = sc.count("the tuple count")?;
            let ty = ty_of(sc, "a field array")?;
            let len = nc
                .checked_mul(nt)
                .ok_or_else(|| sc.err("field array too large; fix: repair the counts"))?;
            let v = self.values(len, ty, "a field array")?;
            if nc == 1 && nt == n {
                p.push(which, an, v);
            }
        }
        Ok(())
    }

    /// `LOOKUP_TABLE name n` and its n RGBA entries (skipped).
    fn lookup_table(&mut self) -> Result<()> {
        let binary = self.binary;
        self.sc.word("the lookup table name")?;
        let n = self.sc.count("the lookup table size")?;
        let len = n
            .checked_mul(4)
            .ok_or_else(|| self.sc.err("lookup table too large; fix: repair the count"))?;
        self.values(len, if binary { Ty::U8 } else { Ty::F32 }, "a lookup table")?;
        Ok(())
    }

    /// `METADATA` and its lines up to a blank one (skipped).
    fn metadata(&mut self) {
        let sc = &mut self.sc;
        sc.rest_of_line();
        while sc.remaining() > 0 {
            let l = sc.rest_of_line();
            if l.iter().all(|c| c.is_ascii_whitespace()) {
                break;
            }
        }
    }
}
