//! Gmsh `.msh` reader (formats 1, 2.2 and 4.1, ASCII) and writer (4.1 ASCII).
//!
//! Physical tags become cell tags and facet tags; `$PhysicalNames` become group names.

use crate::mesh::{CellKind, Mesh};
use crate::scan::{cap, reserve, short, Scan};
use anyhow::{anyhow, bail, Result};
use std::collections::{BTreeMap, HashMap};
use std::fmt::Write as _;
use std::path::Path;

/// The text reader's view of a file: its non-blank lines, trimmed, each with the byte position
/// of its start (messages turn it into a line number).
struct Lines<'a> {
    sc: Scan<'a>,
    text: &'a str,
}

impl<'a> Lines<'a> {
    fn new(name: &'a str, text: &'a str) -> Self {
        Lines {
            sc: Scan::new(name, text.as_bytes()),
            text,
        }
    }
    fn name(&self) -> &'a str {
        self.sc.name
    }
    /// The next non-blank line and its position, or None at the end of the file.
    fn next_line(&mut self) -> Option<(usize, &'a str)> {
        let (p, l) = self.sc.next_line()?;
        // the line is cut at ASCII bytes of valid UTF-8 text, so it is text itself
        Some((p, self.text.get(p..p + l.len()).unwrap_or_default()))
    }
    /// The next non-blank line and its position; the end of the file is an error naming `what`.
    fn next(&mut self, what: &str) -> Result<(usize, &'a str)> {
        self.next_line().ok_or_else(|| {
            let b = self.sc.b;
            let lines = b.iter().filter(|&&c| c == b'\n').count() + usize::from(!b.is_empty() && !b.ends_with(b"\n"));
            anyhow!(
                "{}:{lines}: file ends while reading {what}; fix: the file is truncated, export it again",
                self.name()
            )
        })
    }
    fn err(&self, pos: usize, msg: impl std::fmt::Display) -> anyhow::Error {
        self.sc.err_at(pos, msg)
    }
    /// Parses every whitespace-separated token of the next line.
    fn numbers<T: std::str::FromStr>(&mut self, what: &str) -> Result<(usize, Vec<T>)> {
        let (at, l) = self.next(what)?;
        let mut v = Vec::new();
        for tok in l.split_whitespace() {
            v.push(tok.parse::<T>().map_err(|_| {
                if tok.starts_with('$') {
                    self.err(
                        at,
                        format!("found `{}` while reading {what}; fix: the count in the section header disagrees with its lines, repair it", short(tok)),
                    )
                } else {
                    self.err(at, format!("cannot read `{}` as a number in {what}; fix: repair the line", short(tok)))
                }
            })?);
        }
        Ok((at, v))
    }
    fn expect(&mut self, tag: &str) -> Result<()> {
        let (at, l) = self.next(tag)?;
        if l != tag {
            return Err(self.err(
                at,
                format!(
                    "expected `{tag}`, found `{}`; fix: the section is malformed or truncated",
                    short(l)
                ),
            ));
        }
        Ok(())
    }
    /// Skips to the end marker of a section we do not use.
    fn skip_section(&mut self, name: &str) -> Result<()> {
        let end = format!("$End{}", &name[1..]);
        loop {
            let (_, l) = self.next(&end)?;
            if l == end {
                return Ok(());
            }
        }
    }
}

/// Raw elements before node ids are resolved, in flat arrays (no allocation per element).
#[derive(Default)]
struct RawElems {
    /// Where each element starts in the file (a byte position), for messages.
    pos: Vec<usize>,
    id: Vec<u64>,
    gtype: Vec<u32>,
    tag: Vec<i32>,
    offsets: Vec<usize>,
    nodes: Vec<u64>,
}

impl RawElems {
    fn push(&mut self, pos: usize, id: u64, gtype: u32, tag: i32, nodes: &[u64]) {
        if self.offsets.is_empty() {
            self.offsets.push(0);
        }
        self.pos.push(pos);
        self.id.push(id);
        self.gtype.push(gtype);
        self.tag.push(tag);
        self.nodes.extend_from_slice(nodes);
        self.offsets.push(self.nodes.len());
    }
    /// Room for `n` more elements of up to four nodes (callers bound `n` by the data left).
    fn reserve(&mut self, n: usize, name: &str) -> Result<()> {
        reserve(&mut self.pos, n, name)?;
        reserve(&mut self.id, n, name)?;
        reserve(&mut self.gtype, n, name)?;
        reserve(&mut self.tag, n, name)?;
        reserve(&mut self.offsets, n + 1, name)?;
        reserve(&mut self.nodes, 4 * n, name)
    }
    fn len(&self) -> usize {
        self.id.len()
    }
    fn nodes(&self, e: usize) -> &[u64] {
        &self.nodes[self.offsets[e]..self.offsets[e + 1]]
    }
}

fn nodes_per_type(t: u32) -> Option<(usize, u8)> {
    // (node count, dimension) for the first-order types we keep
    match t {
        15 => Some((1, 0)),
        1 => Some((2, 1)),
        2 => Some((3, 2)),
        3 => Some((4, 2)),
        4 => Some((4, 3)),
        5 => Some((8, 3)),
        6 => Some((6, 3)),
        7 => Some((5, 3)),
        _ => None,
    }
}

fn type_problem(t: u32) -> String {
    match t {
        8 | 9 | 10 | 11 | 12 | 13 | 14 | 16 | 17 | 18 | 19 | 20..=31 => format!(
            "element type {t} is a higher-order element; fix: mesh with order 1 (gmsh -order 1) or convert to linear cells"
        ),
        _ => format!("element type {t} is not supported (tetrahedra, hexahedra, prisms, pyramids and their faces are); fix: re-export the mesh with those cells"),
    }
}

/// Reads a Gmsh file of any supported version, ASCII or binary.
pub fn read(path: &Path) -> Result<Mesh> {
    let bytes = crate::read_input_file(path, "mesh")?;
    parse_bytes(&path.display().to_string(), &bytes)
}

/// Parses the bytes of a Gmsh file: binary files by the binary reader, text by `parse`.
pub fn parse_bytes(name: &str, bytes: &[u8]) -> Result<Mesh> {
    let mut sc = Scan::new(name, bytes);
    let first = sc.rest_of_line().trim_ascii();
    if first == b"$MeshFormat" {
        let fmt = String::from_utf8_lossy(sc.rest_of_line()).to_string();
        let f: Vec<&str> = fmt.split_whitespace().collect();
        if f.get(1) == Some(&"1") {
            return parse_binary(name, bytes);
        }
    }
    match std::str::from_utf8(bytes) {
        Ok(t) => parse(name, t),
        Err(e) => {
            let line = bytes[..e.valid_up_to()].iter().filter(|&&b| b == b'\n').count() + 1;
            bail!("{name}:{line}: binary data in a file whose $MeshFormat says ASCII; fix: the file is corrupt, export it again")
        }
    }
}

/// Parses the text of a Gmsh file.
pub fn parse(name: &str, text: &str) -> Result<Mesh> {
    let mut rd = Lines::new(name, text);
    let (at, first) = rd.next("the first section")?;
    match first {
        "$NOD" => parse_v1(rd),
        "$MeshFormat" => {
            let (at2, fmt) = rd
                .numbers::<f64>("$MeshFormat")
                .map_err(|e| e.context("reading $MeshFormat"))?;
            if fmt.len() < 3 {
                return Err(rd.err(
                    at2,
                    "$MeshFormat needs `version file-type data-size`; fix: repair the header",
                ));
            }
            if fmt[1] != 0.0 {
                return Err(rd.err(
                    at2,
                    "binary .msh given as text; fix: read it with gmsh::parse_bytes (read_mesh does)",
                ));
            }
            rd.expect("$EndMeshFormat")?;
            let v = fmt[0];
            if (2.0..3.0).contains(&v) {
                parse_v2(rd)
            } else if (4.1..4.2).contains(&v) {
                parse_v41(rd)
            } else {
                Err(rd.err(at2, format!("Gmsh format {v} is not supported (1, 2.2 and 4.1 are); fix: save with gmsh -format msh41 or msh22")))
            }
        }
        _ => Err(rd.err(
            at,
            format!(
                "`{}` is not the start of a Gmsh file ($MeshFormat or $NOD); fix: check the file type",
                short(first)
            ),
        )),
    }
}

fn parse_v1(mut rd: Lines) -> Result<Mesh> {
    let mut ids = Vec::new();
    let mut pts = Vec::new();
    let (at, n) = rd.numbers::<usize>("the node count")?;
    if n.len() != 1 {
        return Err(rd.err(at, "expected the node count alone on the line after $NOD"));
    }
    read_nodes_lines(&mut rd, n[0], &mut ids, &mut pts)?;
    rd.expect("$ENDNOD")?;
    let mut elems = RawElems::default();
    let mut saw_elements = false;
    while let Some((at, l)) = rd.next_line() {
        if l == "$ELM" {
            saw_elements = true;
            let (at2, n) = rd.numbers::<usize>("the element count")?;
            if n.len() != 1 {
                return Err(rd.err(at2, "expected the element count alone on the line after $ELM"));
            }
            for _ in 0..n[0] {
                let (at3, v) = rd.numbers::<i64>("an element")?;
                if v.len() < 5 || v[4] < 0 || (v.len() - 5) as u64 != v[4] as u64 {
                    return Err(rd.err(at3, format!("element line has {} numbers; expected `id type phys elem n` and n node ids; fix: the count disagrees with the $ELM header or the line is cut", v.len())));
                }
                let nodes: Vec<u64> = v[5..].iter().map(|&x| x as u64).collect();
                elems.push(at3, v[0] as u64, v[1] as u32, v[2] as i32, &nodes);
            }
            rd.expect("$ENDELM")?;
        } else {
            return Err(rd.err(at, format!("unexpected `{}` between sections", short(l))));
        }
    }
    if !saw_elements {
        return Err(no_elements(rd.name(), "$ELM"));
    }
    build(ids, pts, elems, BTreeMap::new(), &rd)
}

fn read_nodes_lines(rd: &mut Lines, n: usize, ids: &mut Vec<u64>, pts: &mut Vec<[f64; 3]>) -> Result<()> {
    let c = cap(n, rd.sc.remaining(), 8);
    reserve(ids, c, rd.name())?;
    reserve(pts, c, rd.name())?;
    for _ in 0..n {
        let (at, l) = rd.next("a node")?;
        let t: Vec<&str> = l.split_whitespace().collect();
        if t.len() < 4 || t[0].starts_with('$') {
            return Err(rd.err(
                at,
                format!(
                    "expected `id x y z`, found `{}`; fix: the node count disagrees with the node lines",
                    short(l)
                ),
            ));
        }
        let id: u64 = t[0]
            .parse()
            .map_err(|_| rd.err(at, format!("node id `{}` is not a positive integer", t[0])))?;
        let mut p = [0.0f64; 3];
        for d in 0..3 {
            p[d] = t[1 + d]
                .parse()
                .map_err(|_| rd.err(at, format!("coordinate `{}` is not a number", t[1 + d])))?;
            if !p[d].is_finite() {
                return Err(rd.err(
                    at,
                    format!(
                        "node {id} has a non-finite coordinate `{}`; fix: repair the node",
                        t[1 + d]
                    ),
                ));
            }
        }
        ids.push(id);
        pts.push(p);
    }
    Ok(())
}

fn read_physical_names(rd: &mut Lines) -> Result<BTreeMap<(u8, i32), String>> {
    let (at, n) = rd.numbers::<usize>("the physical name count")?;
    if n.len() != 1 {
        return Err(rd.err(at, "expected the number of physical names"));
    }
    let mut m = BTreeMap::new();
    for _ in 0..n[0] {
        let (at, l) = rd.next("a physical name")?;
        let mut it = l.splitn(3, char::is_whitespace);
        let dim: u8 = it
            .next()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| rd.err(at, "expected `dim tag \"name\"`"))?;
        let tag: i32 = it
            .next()
            .and_then(|s| s.trim().parse().ok())
            .ok_or_else(|| rd.err(at, "expected `dim tag \"name\"`"))?;
        let name = it.next().unwrap_or("").trim().trim_matches('"').to_string();
        m.insert((dim, tag), name);
    }
    rd.expect("$EndPhysicalNames")?;
    Ok(m)
}

fn parse_v2(mut rd: Lines) -> Result<Mesh> {
    let mut ids = Vec::new();
    let mut pts = Vec::new();
    let mut elems = RawElems::default();
    let mut names = BTreeMap::new();
    let mut saw_nodes = false;
    let mut saw_elements = false;
    while let Some((at, l)) = rd.next_line() {
        match l {
            "$PhysicalNames" => names = read_physical_names(&mut rd)?,
            "$Nodes" => {
                let (at2, n) = rd.numbers::<usize>("the node count")?;
                if n.len() != 1 {
                    return Err(rd.err(at2, "expected the node count alone on the line after $Nodes"));
                }
                read_nodes_lines(&mut rd, n[0], &mut ids, &mut pts)?;
                rd.expect("$EndNodes")?;
                saw_nodes = true;
            }
            "$Elements" => {
                saw_elements = true;
                let (at2, n) = rd.numbers::<usize>("the element count")?;
                if n.len() != 1 {
                    return Err(rd.err(at2, "expected the element count alone on the line after $Elements"));
                }
                elems.reserve(cap(n[0], rd.sc.remaining(), 8), rd.name())?;
                for _ in 0..n[0] {
                    let (at3, v) = rd.numbers::<i64>("an element")?;
                    if v.len() < 3 || v[2] < 0 || ((v.len() - 3) as u64) < v[2] as u64 {
                        return Err(rd.err(at3, "element line too short; expected `id type ntags tags... nodes...`; fix: the count disagrees with $Elements or the line is cut"));
                    }
                    let ntags = v[2] as usize;
                    let gtype = v[1] as u32;
                    let tag = if ntags > 0 { v[3] as i32 } else { 0 };
                    let nodes: Vec<u64> = v[3 + ntags..].iter().map(|&x| x as u64).collect();
                    if let Some((nn, _)) = nodes_per_type(gtype) {
                        if nodes.len() != nn {
                            return Err(rd.err(
                                at3,
                                format!(
                                    "element {} of type {gtype} has {} node ids, expected {nn}",
                                    v[0],
                                    nodes.len()
                                ),
                            ));
                        }
                    }
                    elems.push(at3, v[0] as u64, gtype, tag, &nodes);
                }
                rd.expect("$EndElements")?;
            }
            s if s.starts_with('$') => rd.skip_section(s)?,
            _ => return Err(rd.err(at, format!("unexpected `{}` between sections", short(l)))),
        }
    }
    if !saw_nodes {
        bail!(
            "{}: no $Nodes section; fix: the file holds no mesh (run gmsh -3 first)",
            rd.name()
        );
    }
    if !saw_elements {
        return Err(no_elements(rd.name(), "$Elements"));
    }
    build(ids, pts, elems, names, &rd)
}

fn parse_v41(mut rd: Lines) -> Result<Mesh> {
    let mut m = Parts::default();
    while let Some((at, l)) = rd.next_line() {
        match l {
            "$PhysicalNames" => m.names = read_physical_names(&mut rd)?,
            "$Entities" => rd.entities_v41(&mut m.entity_phys)?,
            "$Nodes" => rd.nodes_v41(&mut m)?,
            "$Elements" => {
                m.saw_elements = true;
                rd.elements_v41(&mut m)?
            }
            s if s.starts_with('$') => rd.skip_section(s)?,
            _ => return Err(rd.err(at, format!("unexpected `{}` between sections", short(l)))),
        }
    }
    if !m.saw_nodes {
        bail!(
            "{}: no $Nodes section; fix: the file holds no mesh (run gmsh -3 first)",
            rd.name()
        );
    }
    if !m.saw_elements {
        return Err(no_elements(rd.name(), "$Elements"));
    }
    build(m.ids, m.pts, m.elems, m.names, &rd)
}

/// The sections of a 4.1 text file.
impl Lines<'_> {
    /// `$Entities`: the first physical tag of every entity.
    fn entities_v41(&mut self, entity_phys: &mut HashMap<(u8, i32), i32>) -> Result<()> {
        let (at2, c) = self.numbers::<usize>("entity counts")?;
        if c.len() != 4 {
            return Err(self.err(at2, "expected `numPoints numCurves numSurfaces numVolumes`"));
        }
        for dim in 0..4u8 {
            for _ in 0..c[dim as usize] {
                let (at3, v) = self.numbers::<f64>("an entity")?;
                let np_at = if dim == 0 { 4 } else { 7 };
                if v.len() <= np_at {
                    return Err(self.err(at3, "entity line too short"));
                }
                let nphys = v[np_at] as usize;
                if v.len().saturating_sub(np_at + 1) < nphys {
                    return Err(self.err(at3, "entity line has fewer physical tags than it announces"));
                }
                if nphys > 0 {
                    entity_phys.insert((dim, v[0] as i32), v[np_at + 1] as i32);
                }
            }
        }
        self.expect("$EndEntities")
    }

    /// `$Nodes`: entity blocks, each with its node tags, then its coordinates.
    fn nodes_v41(&mut self, m: &mut Parts) -> Result<()> {
        let (at2, h) = self.numbers::<usize>("the $Nodes header")?;
        if h.len() != 4 {
            return Err(self.err(at2, "expected `numEntityBlocks numNodes minNodeTag maxNodeTag`"));
        }
        reserve(&mut m.ids, cap(h[1], self.sc.remaining(), 8), self.name())?;
        reserve(&mut m.pts, cap(h[1], self.sc.remaining(), 8), self.name())?;
        for _ in 0..h[0] {
            let (at3, b) = self.numbers::<i64>("a node block header")?;
            if b.len() != 4 || b[3] < 0 {
                return Err(self.err(at3, "expected `entityDim entityTag parametric numNodesInBlock`"));
            }
            let parametric = b[2] != 0;
            let n = b[3] as usize;
            let start = m.ids.len();
            for _ in 0..n {
                let (at4, t) = self.numbers::<u64>("a node tag")?;
                if t.len() != 1 {
                    return Err(self.err(
                        at4,
                        "expected one node tag per line; fix: the block count disagrees with its lines",
                    ));
                }
                m.ids.push(t[0]);
            }
            for k in 0..n {
                let (at4, c) = self.numbers::<f64>("node coordinates")?;
                if c.len() < 3 || (!parametric && c.len() != 3) {
                    return Err(self.err(at4, "expected `x y z`; fix: the block count disagrees with its lines"));
                }
                if c[..3].iter().any(|x| !x.is_finite()) {
                    return Err(self.err(
                        at4,
                        format!(
                            "node {} has a non-finite coordinate; fix: repair the node",
                            m.ids[start + k]
                        ),
                    ));
                }
                m.pts.push([c[0], c[1], c[2]]);
            }
        }
        if m.ids.len() != h[1] {
            return Err(self.err(
                at2,
                format!(
                    "$Nodes announces {} nodes but its blocks hold {}; fix: repair the header",
                    h[1],
                    m.ids.len()
                ),
            ));
        }
        self.expect("$EndNodes")?;
        m.saw_nodes = true;
        Ok(())
    }

    /// `$Elements`: entity blocks of one element type each; the entity's first physical tag
    /// becomes the elements' tag.
    fn elements_v41(&mut self, m: &mut Parts) -> Result<()> {
        let (at2, h) = self.numbers::<usize>("the $Elements header")?;
        if h.len() != 4 {
            return Err(self.err(
                at2,
                "expected `numEntityBlocks numElements minElementTag maxElementTag`",
            ));
        }
        m.elems.reserve(cap(h[1], self.sc.remaining(), 8), self.name())?;
        let mut count = 0usize;
        for _ in 0..h[0] {
            let (at3, b) = self.numbers::<i64>("an element block header")?;
            if b.len() != 4 || b[3] < 0 {
                return Err(self.err(at3, "expected `entityDim entityTag elementType numElementsInBlock`"));
            }
            let tag = m.entity_phys.get(&(b[0] as u8, b[1] as i32)).copied().unwrap_or(0);
            let gtype = b[2] as u32;
            for _ in 0..b[3] {
                let (at4, v) = self.numbers::<u64>("an element")?;
                if v.is_empty() {
                    return Err(self.err(at4, "empty element line"));
                }
                if let Some((nn, _)) = nodes_per_type(gtype) {
                    if v.len() != nn + 1 {
                        return Err(self.err(at4, format!("element {} of type {gtype} has {} node ids, expected {nn}; fix: the block count disagrees with its lines", v[0], v.len() - 1)));
                    }
                }
                m.elems.push(at4, v[0], gtype, tag, &v[1..]);
                count += 1;
            }
        }
        if count != h[1] {
            return Err(self.err(
                at2,
                format!(
                    "$Elements announces {} elements but its blocks hold {count}; fix: repair the header",
                    h[1]
                ),
            ));
        }
        self.expect("$EndElements")
    }
}

/// A file whose nodes are not followed by an elements section: cut short, or a point cloud.
fn no_elements(name: &str, section: &str) -> anyhow::Error {
    anyhow!(
        "{name}: the file ends without an {section} section (nodes but no elements); fix: the file is truncated, export it again (if it holds only nodes, mesh the volume first: gmsh -3)"
    )
}

fn build(
    ids: Vec<u64>,
    pts: Vec<[f64; 3]>,
    elems: RawElems,
    names: BTreeMap<(u8, i32), String>,
    rd: &Lines,
) -> Result<Mesh> {
    let sc = &rd.sc;
    build_at(rd.name().to_string(), ids, pts, elems, names, &|pos| {
        format!("{}:{}", sc.name, sc.line_of(pos))
    })
}

/// Resolves node ids of the raw elements; `loc` turns a raw element's position into
/// `file:line` (text) or `file: byte N` (binary) for messages.
fn build_at(
    source: String,
    ids: Vec<u64>,
    pts: Vec<[f64; 3]>,
    elems: RawElems,
    names: BTreeMap<(u8, i32), String>,
    loc: &dyn Fn(usize) -> String,
) -> Result<Mesh> {
    let mut index: HashMap<u64, u32> = HashMap::with_capacity(ids.len());
    for (k, &id) in ids.iter().enumerate() {
        if index.insert(id, k as u32).is_some() {
            bail!("{source}: node id {id} appears twice; fix: renumber the nodes");
        }
    }
    let mut mesh = Mesh::new(source.clone());
    mesh.points = pts;
    mesh.node_ids = ids;
    mesh.group_names = names;
    let mut buf = Vec::with_capacity(8);
    for e in 0..elems.len() {
        let (pos, id, gtype, tag, nodes) = (elems.pos[e], elems.id[e], elems.gtype[e], elems.tag[e], elems.nodes(e));
        let Some((nn, dim)) = nodes_per_type(gtype) else {
            return Err(anyhow!("{}: element {}: {}", loc(pos), id, type_problem(gtype)));
        };
        if nodes.len() != nn {
            return Err(anyhow!(
                "{}: element {} has {} node ids, expected {nn}; fix: repair the element",
                loc(pos),
                id,
                nodes.len()
            ));
        }
        buf.clear();
        for &n in nodes {
            let Some(&k) = index.get(&n) else {
                return Err(anyhow!("{}: element {} names node {n}, which the file does not define; fix: repair the element or add the node", loc(pos), id));
            };
            buf.push(k);
        }
        if let (3, Some(kind)) = (dim, CellKind::from_gmsh(gtype)) {
            mesh.push_cell(kind, &buf, tag);
            mesh.cell_ids.push(id);
        } else {
            mesh.facets.push(dim, tag, &buf);
        }
    }
    drop(elems);
    if mesh.n_cells() == 0 {
        bail!("{source}: no volume cells (tetrahedra, hexahedra, prisms or pyramids); fix: mesh the volume (gmsh -3), not only its surface");
    }
    Ok(mesh)
}

/// Writes a mesh as Gmsh 4.1 ASCII, with one entity per (dimension, physical tag).
pub fn write(mesh: &Mesh, path: &Path) -> Result<()> {
    let mut s = String::with_capacity(64 * mesh.n_nodes() + 48 * mesh.conn.len());
    s.push_str("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n");
    if !mesh.group_names.is_empty() {
        let _ = writeln!(s, "$PhysicalNames\n{}", mesh.group_names.len());
        for ((d, t), n) in &mesh.group_names {
            let _ = writeln!(s, "{d} {t} \"{n}\"");
        }
        s.push_str("$EndPhysicalNames\n");
    }
    // entities: one per (dim, tag) used; entity tag = index + 1 within its dimension
    let mut ents: BTreeMap<(u8, i32), i32> = BTreeMap::new();
    for &t in &mesh.cell_tags {
        ents.entry((3, t)).or_insert(0);
    }
    for f in 0..mesh.facets.len() {
        ents.entry((mesh.facets.dim[f], mesh.facets.tags[f])).or_insert(0);
    }
    let mut counts = [0usize; 4];
    for ((d, _), e) in ents.iter_mut() {
        counts[*d as usize] += 1;
        *e = counts[*d as usize] as i32;
    }
    let (lo, hi) = mesh.bounds();
    let _ = writeln!(s, "$Entities\n{} {} {} {}", counts[0], counts[1], counts[2], counts[3]);
    for ((d, t), e) in &ents {
        let phys = if *t != 0 { format!("1 {t}") } else { "0".to_string() };
        if *d == 0 {
            let _ = writeln!(s, "{e} {} {} {} {phys}", lo[0], lo[1], lo[2]);
        } else {
            let _ = writeln!(
                s,
                "{e} {} {} {} {} {} {} {phys} 0",
                lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
            );
        }
    }
    s.push_str("$EndEntities\n");
    // nodes: all in the first volume entity
    let n = mesh.n_nodes();
    let vol_ent = ents.iter().find(|((d, _), _)| *d == 3).map(|(_, e)| *e).unwrap_or(1);
    // Gmsh node tags start at 1: shift 0-based numberings (VTK, TetGen) by one
    let ids: Vec<u64> = if mesh.node_ids.len() == n {
        let shift = mesh.node_ids.contains(&0) as u64;
        mesh.node_ids.iter().map(|&i| i + shift).collect()
    } else {
        (1..=n as u64).collect()
    };
    let (minid, maxid) = (
        ids.iter().min().copied().unwrap_or(0),
        ids.iter().max().copied().unwrap_or(0),
    );
    let _ = writeln!(s, "$Nodes\n1 {n} {minid} {maxid}\n3 {vol_ent} 0 {n}");
    for id in &ids {
        let _ = writeln!(s, "{id}");
    }
    for p in &mesh.points {
        let _ = writeln!(s, "{:e} {:e} {:e}", p[0], p[1], p[2]);
    }
    s.push_str("$EndNodes\n");
    // elements: blocks per (dim, tag, type)
    let mut blocks: BTreeMap<(u8, i32, u32), Vec<usize>> = BTreeMap::new();
    for c in 0..mesh.n_cells() {
        blocks
            .entry((3, mesh.cell_tags[c], mesh.kinds[c].gmsh_type()))
            .or_default()
            .push(c);
    }
    for f in 0..mesh.facets.len() {
        let t = match (mesh.facets.dim[f], mesh.facets.nodes(f).len()) {
            (0, _) => 15,
            (1, _) => 1,
            (2, 3) => 2,
            (2, 4) => 3,
            _ => continue,
        };
        blocks
            .entry((mesh.facets.dim[f], mesh.facets.tags[f], t))
            .or_default()
            .push(usize::MAX - f);
    }
    let total: usize = blocks.values().map(|v| v.len()).sum();
    let _ = writeln!(s, "$Elements\n{} {total} 1 {total}", blocks.len());
    let mut eid = 1usize;
    for ((d, t, ty), list) in &blocks {
        let _ = writeln!(s, "{d} {} {ty} {}", ents[&(*d, *t)], list.len());
        for &k in list {
            let nodes = if *d == 3 {
                mesh.cell(k)
            } else {
                mesh.facets.nodes(usize::MAX - k)
            };
            let _ = write!(s, "{eid}");
            for &nn in nodes {
                let _ = write!(s, " {}", ids[nn as usize]);
            }
            s.push('\n');
            eid += 1;
        }
    }
    s.push_str("$EndElements\n");
    std::fs::write(path, s).map_err(|e| anyhow!("{}: cannot write: {e}", path.display()))
}

/// Binary `.msh` data: little- or big-endian numbers, `size_t` of 4 or 8 bytes.
struct Bin<'a> {
    sc: Scan<'a>,
    big: bool,
    dsize: usize,
}

impl<'a> Bin<'a> {
    fn i32(&mut self, what: &str) -> Result<i32> {
        let b = self.sc.raw(4, what)?;
        let a = [b[0], b[1], b[2], b[3]];
        Ok(if self.big {
            i32::from_be_bytes(a)
        } else {
            i32::from_le_bytes(a)
        })
    }
    fn size(&mut self, what: &str) -> Result<u64> {
        if self.dsize == 4 {
            return Ok(self.i32(what)? as u32 as u64);
        }
        let a = self.bytes8(what)?;
        Ok(if self.big {
            u64::from_be_bytes(a)
        } else {
            u64::from_le_bytes(a)
        })
    }
    fn bytes8(&mut self, what: &str) -> Result<[u8; 8]> {
        let mut a = [0u8; 8];
        a.copy_from_slice(self.sc.raw(8, what)?);
        Ok(a)
    }
    fn count(&mut self, what: &str) -> Result<usize> {
        let p = self.sc.pos;
        let v = self.size(what)?;
        usize::try_from(v).map_err(|_| {
            self.sc
                .err_byte(p, format!("{what} {v} is too large; fix: the file is corrupt"))
        })
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        let a = self.bytes8(what)?;
        Ok(if self.big {
            f64::from_be_bytes(a)
        } else {
            f64::from_le_bytes(a)
        })
    }
    /// A text line (section markers, ASCII counts).
    fn line(&mut self) -> Option<String> {
        self.sc
            .next_line()
            .map(|(_, l)| String::from_utf8_lossy(l).into_owned())
    }
    fn expect(&mut self, tag: &str) -> Result<()> {
        let p = self.sc.pos;
        match self.line() {
            Some(l) if l == tag => Ok(()),
            Some(l) => Err(self.sc.err_byte(
                p,
                format!(
                    "expected `{tag}`, found `{}`; fix: a count disagrees with the data or the file is truncated",
                    short(&l)
                ),
            )),
            None => Err(self.sc.truncated(tag)),
        }
    }
    fn text_count(&mut self, what: &str) -> Result<usize> {
        let p = self.sc.pos;
        let l = self.line().ok_or_else(|| self.sc.truncated(what))?;
        l.parse().map_err(|_| {
            self.sc.err_at(
                p,
                format!("expected {what}, found `{}`; fix: repair the line", short(&l)),
            )
        })
    }
}

/// What the sections of a 4.1 or binary file hold, gathered section by section.
#[derive(Default)]
struct Parts {
    ids: Vec<u64>,
    pts: Vec<[f64; 3]>,
    elems: RawElems,
    names: BTreeMap<(u8, i32), String>,
    /// (dim, entity tag) -> first physical tag (4.1)
    entity_phys: HashMap<(u8, i32), i32>,
    saw_nodes: bool,
    saw_elements: bool,
}

fn parse_binary(name: &str, bytes: &[u8]) -> Result<Mesh> {
    let (mut b, v2) = binary_header(name, bytes)?;
    let mut m = Parts::default();
    while let Some(l) = b.line() {
        let sec_pos = b.sc.pos;
        match l.as_str() {
            "$PhysicalNames" => m.names = b.physical_names()?,
            "$Entities" if !v2 => b.entities(&mut m.entity_phys)?,
            "$Nodes" if v2 => b.nodes_v2(&mut m)?,
            "$Nodes" => b.nodes_v41(&mut m, sec_pos)?,
            "$Elements" if v2 => {
                m.saw_elements = true;
                b.elements_v2(&mut m.elems)?
            }
            "$Elements" => {
                m.saw_elements = true;
                b.elements_v41(&mut m, sec_pos)?
            }
            s if s.starts_with('$') && s.len() > 1 => b.skip_section(s, sec_pos)?,
            _ => {
                return Err(b.sc.err_byte(
                    sec_pos,
                    format!(
                        "unexpected `{}` between sections; fix: a count disagrees with the data",
                        short(&l)
                    ),
                ))
            }
        }
    }
    if !m.saw_nodes {
        bail!("{name}: no $Nodes section; fix: the file holds no mesh (run gmsh -3 first)");
    }
    if !m.saw_elements {
        return Err(no_elements(name, "$Elements"));
    }
    let nm = name.to_string();
    build_at(name.to_string(), m.ids, m.pts, m.elems, m.names, &|p| {
        format!("{nm}: byte {p}")
    })
}

/// Reads `$MeshFormat` of a binary file up to `$EndMeshFormat`: the version (2.2 or 4.1: true
/// for 2.2), the data size and the byte order (from the integer 1 written after the line).
fn binary_header<'a>(name: &'a str, bytes: &'a [u8]) -> Result<(Bin<'a>, bool)> {
    let mut sc = Scan::new(name, bytes);
    sc.rest_of_line();
    let fmt_pos = sc.pos;
    let fmt = String::from_utf8_lossy(sc.rest_of_line()).to_string();
    let f: Vec<&str> = fmt.split_whitespace().collect();
    let version: f64 = f.first().and_then(|v| v.parse().ok()).unwrap_or(0.0);
    let dsize: usize = f.get(2).and_then(|v| v.parse().ok()).unwrap_or(0);
    if dsize != 4 && dsize != 8 {
        return Err(sc.err_at(
            fmt_pos,
            format!(
                "data-size {} is not 4 or 8; fix: repair the $MeshFormat line",
                f.get(2).unwrap_or(&"")
            ),
        ));
    }
    let v2 = (2.0..3.0).contains(&version);
    if !v2 && !(4.1..4.2).contains(&version) {
        return Err(sc.err_at(fmt_pos, format!("binary Gmsh format {version} is not supported (2.2 and 4.1 are); fix: save with gmsh -format msh41 or msh22")));
    }
    let one = sc.raw(4, "the endianness marker")?;
    let big = match one {
        [1, 0, 0, 0] => false,
        [0, 0, 0, 1] => true,
        _ => {
            return Err(sc.err_byte(
                sc.pos - 4,
                "the endianness marker is not the integer 1; fix: the file is corrupt, export it again",
            ))
        }
    };
    let mut b = Bin { sc, big, dsize };
    b.expect("$EndMeshFormat")?;
    Ok((b, v2))
}

impl Bin<'_> {
    /// `$PhysicalNames` (text lines in a binary file) up to its end marker.
    fn physical_names(&mut self) -> Result<BTreeMap<(u8, i32), String>> {
        let mut names = BTreeMap::new();
        let n = self.text_count("the physical name count")?;
        for _ in 0..n {
            let p = self.sc.pos;
            let l = self.line().ok_or_else(|| self.sc.truncated("a physical name"))?;
            let mut it = l.splitn(3, char::is_whitespace);
            let dim = it.next().and_then(|s| s.parse::<u8>().ok());
            let tag = it.next().and_then(|s| s.trim().parse::<i32>().ok());
            let (Some(dim), Some(tag)) = (dim, tag) else {
                return Err(self.sc.err_at(p, "expected `dim tag \"name\"`; fix: repair the line"));
            };
            names.insert((dim, tag), it.next().unwrap_or("").trim().trim_matches('"').to_string());
        }
        self.expect("$EndPhysicalNames")?;
        Ok(names)
    }

    /// `$Entities` (4.1): the first physical tag of every entity.
    fn entities(&mut self, entity_phys: &mut HashMap<(u8, i32), i32>) -> Result<()> {
        let mut c = [0usize; 4];
        for x in &mut c {
            *x = self.count("an entity count")?;
        }
        for dim in 0..4u8 {
            for _ in 0..c[dim as usize] {
                let tag = self.i32("an entity tag")?;
                for _ in 0..if dim == 0 { 3 } else { 6 } {
                    self.f64("an entity bound")?;
                }
                let np = self.count("a physical tag count")?;
                for k in 0..np {
                    let ph = self.i32("a physical tag")?;
                    if k == 0 {
                        entity_phys.insert((dim, tag), ph);
                    }
                }
                if dim > 0 {
                    let nb = self.count("a bounding entity count")?;
                    for _ in 0..nb {
                        self.i32("a bounding entity")?;
                    }
                }
            }
        }
        self.expect("$EndEntities")
    }

    /// `$Nodes` of a 2.2 file: a text count, then `id x y z` records.
    fn nodes_v2(&mut self, m: &mut Parts) -> Result<()> {
        let n = self.text_count("the node count")?;
        let c = cap(n, self.sc.remaining(), 28);
        reserve(&mut m.ids, c, self.sc.name)?;
        reserve(&mut m.pts, c, self.sc.name)?;
        for _ in 0..n {
            let id = self.i32("a node id")?;
            let mut p = [0.0; 3];
            for x in &mut p {
                *x = self.f64("a coordinate")?;
            }
            m.ids.push(id as u32 as u64);
            m.pts.push(p);
        }
        self.expect("$EndNodes")?;
        m.saw_nodes = true;
        Ok(())
    }

    /// The header of a 4.1 `$Nodes` or `$Elements` section: block count, item count, minimum
    /// and maximum tag (unused); `item` is "node" or "element".
    fn blocks_header(&mut self, item: &str) -> Result<(usize, usize)> {
        let nblocks = self.count(&format!("the {item} block count"))?;
        let n = self.count(&format!("the {item} count"))?;
        self.count(&format!("the minimum {item} tag"))?;
        self.count(&format!("the maximum {item} tag"))?;
        Ok((nblocks, n))
    }

    /// `$Nodes` of a 4.1 file: entity blocks, each with its node tags, then its coordinates.
    fn nodes_v41(&mut self, m: &mut Parts, sec_pos: usize) -> Result<()> {
        let dsize = self.dsize;
        let (nblocks, n) = self.blocks_header("node")?;
        let c = cap(n, self.sc.remaining(), 32);
        reserve(&mut m.ids, c, self.sc.name)?;
        reserve(&mut m.pts, c, self.sc.name)?;
        for _ in 0..nblocks {
            let edim = self.i32("an entity dimension")?;
            self.i32("an entity tag")?;
            let param = self.i32("the parametric flag")?;
            let nn = self.count("the block node count")?;
            if nn > self.sc.remaining() / (dsize + 24) {
                return Err(self.sc.err_byte(self.sc.pos, format!("a node block announces {nn} nodes, more than the file holds; fix: the file is truncated or corrupt")));
            }
            for _ in 0..nn {
                m.ids.push(self.size("a node tag")?);
            }
            let extra = if param != 0 { edim.clamp(0, 3) as usize } else { 0 };
            for _ in 0..nn {
                let mut p = [0.0; 3];
                for x in &mut p {
                    *x = self.f64("a coordinate")?;
                }
                for _ in 0..extra {
                    self.f64("a parametric coordinate")?;
                }
                m.pts.push(p);
            }
        }
        if m.ids.len() != n {
            return Err(self.sc.err_byte(
                sec_pos,
                format!(
                    "$Nodes announces {n} nodes but its blocks hold {}; fix: repair the header",
                    m.ids.len()
                ),
            ));
        }
        self.expect("$EndNodes")?;
        m.saw_nodes = true;
        Ok(())
    }

    /// `$Elements` of a 2.2 file: a text count, then blocks of `type count ntags` headers
    /// followed by `id tags... nodes...` records.
    fn elements_v2(&mut self, elems: &mut RawElems) -> Result<()> {
        let n = self.text_count("the element count")?;
        elems.reserve(cap(n, self.sc.remaining(), 20), self.sc.name)?;
        let mut done = 0usize;
        while done < n {
            let hp = self.sc.pos;
            let gtype = self.i32("an element type")? as u32;
            let follow = self.i32("the element count of a block")?.max(0) as usize;
            let ntags = self.i32("the tag count")?.max(0) as usize;
            let Some((nn, _)) = nodes_per_type(gtype) else {
                return Err(self.sc.err_byte(hp, type_problem(gtype)));
            };
            if follow == 0 || follow > n - done {
                return Err(self.sc.err_byte(hp, format!("an element block announces {follow} elements, but {} remain of the {n} announced; fix: the counts disagree, export again", n - done)));
            }
            if ntags > 1 << 16 {
                return Err(self
                    .sc
                    .err_byte(hp, format!("{ntags} tags per element; fix: the file is corrupt")));
            }
            for _ in 0..follow {
                let p = self.sc.pos;
                let id = self.i32("an element id")? as u32 as u64;
                let mut tag = 0;
                for k in 0..ntags {
                    let t = self.i32("an element tag")?;
                    if k == 0 {
                        tag = t;
                    }
                }
                let mut nodes = Vec::with_capacity(nn);
                for _ in 0..nn {
                    nodes.push(self.i32("an element node")? as u32 as u64);
                }
                elems.push(p, id, gtype, tag, &nodes);
            }
            done += follow;
        }
        self.expect("$EndElements")
    }

    /// `$Elements` of a 4.1 file: entity blocks of one element type each; the entity's first
    /// physical tag becomes the elements' tag.
    fn elements_v41(&mut self, m: &mut Parts, sec_pos: usize) -> Result<()> {
        let dsize = self.dsize;
        let (nblocks, n) = self.blocks_header("element")?;
        m.elems.reserve(cap(n, self.sc.remaining(), 2 * dsize), self.sc.name)?;
        for _ in 0..nblocks {
            let hp = self.sc.pos;
            let edim = self.i32("an entity dimension")?;
            let etag = self.i32("an entity tag")?;
            let gtype = self.i32("an element type")? as u32;
            let ne = self.count("the block element count")?;
            let Some((nn, _)) = nodes_per_type(gtype) else {
                return Err(self.sc.err_byte(hp, type_problem(gtype)));
            };
            if ne > self.sc.remaining() / ((nn + 1) * dsize) {
                return Err(self.sc.err_byte(hp, format!("an element block announces {ne} elements, more than the file holds; fix: the file is truncated or corrupt")));
            }
            let tag = u8::try_from(edim)
                .ok()
                .and_then(|d| m.entity_phys.get(&(d, etag)).copied())
                .unwrap_or(0);
            for _ in 0..ne {
                let p = self.sc.pos;
                let id = self.size("an element tag")?;
                let mut nodes = Vec::with_capacity(nn);
                for _ in 0..nn {
                    nodes.push(self.size("an element node")?);
                }
                m.elems.push(p, id, gtype, tag, &nodes);
            }
        }
        if m.elems.len() != n {
            return Err(self.sc.err_byte(
                sec_pos,
                format!(
                    "$Elements announces {n} elements but its blocks hold {}; fix: repair the header",
                    m.elems.len()
                ),
            ));
        }
        self.expect("$EndElements")
    }

    /// A section eprop does not use: moves past its end marker.
    fn skip_section(&mut self, s: &str, sec_pos: usize) -> Result<()> {
        let end = format!("\n$End{}", &s[1..]);
        let from = self.sc.pos.saturating_sub(1);
        let hay = &self.sc.b[from..];
        match hay.windows(end.len()).position(|w| w == end.as_bytes()) {
            Some(k) => {
                self.sc.pos = from + k + 1;
                self.line();
                Ok(())
            }
            None => Err(self.sc.err_byte(
                sec_pos,
                format!("section {} has no end marker; fix: the file is truncated", short(s)),
            )),
        }
    }
}
