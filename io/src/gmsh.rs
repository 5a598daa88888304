//! Gmsh `.msh` reader (formats 1, 2.2 and 4.1, ASCII) and writer (4.1 ASCII).
//!
//! Physical tags become cell tags and facet tags; `$PhysicalNames` become group names.

use crate::mesh::{CellKind, Mesh};
use anyhow::{anyhow, bail, Result};
use std::collections::{BTreeMap, HashMap};
use std::fmt::Write as _;
use std::path::Path;

/// Line-oriented token reader that knows where it is, for messages.
struct Lines<'a> {
    path: String,
    lines: Vec<&'a str>,
    pos: usize,
}

impl<'a> Lines<'a> {
    fn new(path: &str, text: &'a str) -> Self {
        Lines {
            path: path.to_string(),
            lines: text.lines().collect(),
            pos: 0,
        }
    }
    /// The next non-blank line, with its 1-based number.
    fn next(&mut self, what: &str) -> Result<(usize, &'a str)> {
        while self.pos < self.lines.len() {
            let l = self.lines[self.pos].trim();
            self.pos += 1;
            if !l.is_empty() {
                return Ok((self.pos, l));
            }
        }
        Err(anyhow!(
            "{}:{}: file ends while reading {}; fix: the file is truncated, export it again",
            self.path,
            self.lines.len(),
            what
        ))
    }
    fn err(&self, line: usize, msg: impl std::fmt::Display) -> anyhow::Error {
        anyhow!("{}:{}: {}", self.path, line, msg)
    }
    /// Parses every whitespace-separated token of the next line.
    fn numbers<T: std::str::FromStr>(&mut self, what: &str) -> Result<(usize, Vec<T>)> {
        let (ln, l) = self.next(what)?;
        let mut v = Vec::new();
        for tok in l.split_whitespace() {
            v.push(tok.parse::<T>().map_err(|_| {
                self.err(
                    ln,
                    format!("cannot read `{tok}` as a number in {what}; fix: repair the line"),
                )
            })?);
        }
        Ok((ln, v))
    }
    fn expect(&mut self, tag: &str) -> Result<()> {
        let (ln, l) = self.next(tag)?;
        if l != tag {
            return Err(self.err(
                ln,
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

fn short(s: &str) -> String {
    if s.len() > 40 {
        format!("{}...", &s[..s.char_indices().nth(40).map(|c| c.0).unwrap_or(s.len())])
    } else {
        s.to_string()
    }
}

/// A raw element before node ids are resolved.
struct RawElem {
    line: usize,
    id: u64,
    gtype: u32,
    tag: i32,
    nodes: Vec<u64>,
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

/// Reads a Gmsh file of any supported version.
pub fn read(path: &Path) -> Result<Mesh> {
    let bytes = std::fs::read(path).map_err(|e| anyhow!("{}: cannot read: {e}", path.display()))?;
    let name = path.display().to_string();
    let text = match std::str::from_utf8(&bytes) {
        Ok(t) => t,
        Err(e) => {
            // binary sections are not text
            let upto = &bytes[..e.valid_up_to()];
            let line = upto.iter().filter(|&&b| b == b'\n').count() + 1;
            bail!("{name}:{line}: binary data in the file; fix: binary .msh is not read yet, save as ASCII (gmsh -bin 0 or File > Export > ASCII)")
        }
    };
    parse(&name, text)
}

/// Parses the text of a Gmsh file.
pub fn parse(name: &str, text: &str) -> Result<Mesh> {
    let mut rd = Lines::new(name, text);
    let (ln, first) = rd.next("the first section")?;
    match first {
        "$NOD" => parse_v1(rd),
        "$MeshFormat" => {
            let (ln2, fmt) = rd
                .numbers::<f64>("$MeshFormat")
                .map_err(|e| e.context("reading $MeshFormat"))?;
            if fmt.len() < 3 {
                return Err(rd.err(
                    ln2,
                    "$MeshFormat needs `version file-type data-size`; fix: repair the header",
                ));
            }
            if fmt[1] != 0.0 {
                return Err(rd.err(ln2, "binary .msh is not read yet; fix: save as ASCII (gmsh -bin 0)"));
            }
            rd.expect("$EndMeshFormat")?;
            let v = fmt[0];
            if (2.0..3.0).contains(&v) {
                parse_v2(rd)
            } else if (4.1..4.2).contains(&v) {
                parse_v41(rd)
            } else {
                Err(rd.err(ln2, format!("Gmsh format {v} is not supported (1, 2.2 and 4.1 are); fix: save with gmsh -format msh41 or msh22")))
            }
        }
        _ => Err(rd.err(
            ln,
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
    let (ln, n) = rd.numbers::<usize>("the node count")?;
    if n.len() != 1 {
        return Err(rd.err(ln, "expected the node count alone on the line after $NOD"));
    }
    read_nodes_lines(&mut rd, n[0], &mut ids, &mut pts)?;
    rd.expect("$ENDNOD")?;
    let mut elems = Vec::new();
    loop {
        let (ln, l) = match rd.next("$ELM") {
            Ok(x) => x,
            Err(_) => break,
        };
        if l == "$ELM" {
            let (ln2, n) = rd.numbers::<usize>("the element count")?;
            if n.len() != 1 {
                return Err(rd.err(ln2, "expected the element count alone on the line after $ELM"));
            }
            for _ in 0..n[0] {
                let (ln3, v) = rd.numbers::<i64>("an element")?;
                if v.len() < 5 || v[4] < 0 || v.len() != 5 + v[4] as usize {
                    return Err(rd.err(ln3, format!("element line has {} numbers; expected `id type phys elem n` and n node ids; fix: the count disagrees with the $ELM header or the line is cut", v.len())));
                }
                elems.push(RawElem {
                    line: ln3,
                    id: v[0] as u64,
                    gtype: v[1] as u32,
                    tag: v[2] as i32,
                    nodes: v[5..].iter().map(|&x| x as u64).collect(),
                });
            }
            rd.expect("$ENDELM")?;
        } else {
            return Err(rd.err(ln, format!("unexpected `{}` between sections", short(l))));
        }
    }
    build(rd.path.clone(), ids, pts, elems, BTreeMap::new(), &rd)
}

fn read_nodes_lines(rd: &mut Lines, n: usize, ids: &mut Vec<u64>, pts: &mut Vec<[f64; 3]>) -> Result<()> {
    ids.reserve(n);
    pts.reserve(n);
    for _ in 0..n {
        let (ln, l) = rd.next("a node")?;
        let t: Vec<&str> = l.split_whitespace().collect();
        if t.len() < 4 || t[0].starts_with('$') {
            return Err(rd.err(
                ln,
                format!(
                    "expected `id x y z`, found `{}`; fix: the node count disagrees with the node lines",
                    short(l)
                ),
            ));
        }
        let id: u64 = t[0]
            .parse()
            .map_err(|_| rd.err(ln, format!("node id `{}` is not a positive integer", t[0])))?;
        let mut p = [0.0f64; 3];
        for d in 0..3 {
            p[d] = t[1 + d]
                .parse()
                .map_err(|_| rd.err(ln, format!("coordinate `{}` is not a number", t[1 + d])))?;
            if !p[d].is_finite() {
                return Err(rd.err(
                    ln,
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
    let (ln, n) = rd.numbers::<usize>("the physical name count")?;
    if n.len() != 1 {
        return Err(rd.err(ln, "expected the number of physical names"));
    }
    let mut m = BTreeMap::new();
    for _ in 0..n[0] {
        let (ln, l) = rd.next("a physical name")?;
        let mut it = l.splitn(3, char::is_whitespace);
        let dim: u8 = it
            .next()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| rd.err(ln, "expected `dim tag \"name\"`"))?;
        let tag: i32 = it
            .next()
            .and_then(|s| s.trim().parse().ok())
            .ok_or_else(|| rd.err(ln, "expected `dim tag \"name\"`"))?;
        let name = it.next().unwrap_or("").trim().trim_matches('"').to_string();
        m.insert((dim, tag), name);
    }
    rd.expect("$EndPhysicalNames")?;
    Ok(m)
}

fn parse_v2(mut rd: Lines) -> Result<Mesh> {
    let mut ids = Vec::new();
    let mut pts = Vec::new();
    let mut elems = Vec::new();
    let mut names = BTreeMap::new();
    let mut saw_nodes = false;
    loop {
        let (ln, l) = match rd.next("a section") {
            Ok(x) => x,
            Err(_) => break,
        };
        match l {
            "$PhysicalNames" => names = read_physical_names(&mut rd)?,
            "$Nodes" => {
                let (ln2, n) = rd.numbers::<usize>("the node count")?;
                if n.len() != 1 {
                    return Err(rd.err(ln2, "expected the node count alone on the line after $Nodes"));
                }
                read_nodes_lines(&mut rd, n[0], &mut ids, &mut pts)?;
                rd.expect("$EndNodes")?;
                saw_nodes = true;
            }
            "$Elements" => {
                let (ln2, n) = rd.numbers::<usize>("the element count")?;
                if n.len() != 1 {
                    return Err(rd.err(ln2, "expected the element count alone on the line after $Elements"));
                }
                elems.reserve(n[0]);
                for _ in 0..n[0] {
                    let (ln3, v) = rd.numbers::<i64>("an element")?;
                    if v.len() < 3 || v[2] < 0 || v.len() < 3 + v[2] as usize {
                        return Err(rd.err(ln3, "element line too short; expected `id type ntags tags... nodes...`; fix: the count disagrees with $Elements or the line is cut"));
                    }
                    let ntags = v[2] as usize;
                    let gtype = v[1] as u32;
                    let tag = if ntags > 0 { v[3] as i32 } else { 0 };
                    let nodes: Vec<u64> = v[3 + ntags..].iter().map(|&x| x as u64).collect();
                    if let Some((nn, _)) = nodes_per_type(gtype) {
                        if nodes.len() != nn {
                            return Err(rd.err(
                                ln3,
                                format!(
                                    "element {} of type {gtype} has {} node ids, expected {nn}",
                                    v[0],
                                    nodes.len()
                                ),
                            ));
                        }
                    }
                    elems.push(RawElem {
                        line: ln3,
                        id: v[0] as u64,
                        gtype,
                        tag,
                        nodes,
                    });
                }
                rd.expect("$EndElements")?;
            }
            s if s.starts_with('$') => rd.skip_section(s)?,
            _ => return Err(rd.err(ln, format!("unexpected `{}` between sections", short(l)))),
        }
    }
    if !saw_nodes {
        bail!(
            "{}: no $Nodes section; fix: the file holds no mesh (run gmsh -3 first)",
            rd.path
        );
    }
    build(rd.path.clone(), ids, pts, elems, names, &rd)
}

fn parse_v41(mut rd: Lines) -> Result<Mesh> {
    let mut ids = Vec::new();
    let mut pts = Vec::new();
    let mut elems = Vec::new();
    let mut names = BTreeMap::new();
    // (dim, entity tag) -> first physical tag
    let mut entity_phys: HashMap<(u8, i32), i32> = HashMap::new();
    let mut saw_nodes = false;
    loop {
        let (ln, l) = match rd.next("a section") {
            Ok(x) => x,
            Err(_) => break,
        };
        match l {
            "$PhysicalNames" => names = read_physical_names(&mut rd)?,
            "$Entities" => {
                let (ln2, c) = rd.numbers::<usize>("entity counts")?;
                if c.len() != 4 {
                    return Err(rd.err(ln2, "expected `numPoints numCurves numSurfaces numVolumes`"));
                }
                for dim in 0..4u8 {
                    for _ in 0..c[dim as usize] {
                        let (ln3, v) = rd.numbers::<f64>("an entity")?;
                        let np_at = if dim == 0 { 4 } else { 7 };
                        if v.len() <= np_at {
                            return Err(rd.err(ln3, "entity line too short"));
                        }
                        let nphys = v[np_at] as usize;
                        if v.len() < np_at + 1 + nphys {
                            return Err(rd.err(ln3, "entity line has fewer physical tags than it announces"));
                        }
                        if nphys > 0 {
                            entity_phys.insert((dim, v[0] as i32), v[np_at + 1] as i32);
                        }
                    }
                }
                rd.expect("$EndEntities")?;
            }
            "$Nodes" => {
                let (ln2, h) = rd.numbers::<usize>("the $Nodes header")?;
                if h.len() != 4 {
                    return Err(rd.err(ln2, "expected `numEntityBlocks numNodes minNodeTag maxNodeTag`"));
                }
                ids.reserve(h[1]);
                pts.reserve(h[1]);
                for _ in 0..h[0] {
                    let (ln3, b) = rd.numbers::<i64>("a node block header")?;
                    if b.len() != 4 || b[3] < 0 {
                        return Err(rd.err(ln3, "expected `entityDim entityTag parametric numNodesInBlock`"));
                    }
                    let parametric = b[2] != 0;
                    let n = b[3] as usize;
                    let start = ids.len();
                    for _ in 0..n {
                        let (ln4, t) = rd.numbers::<u64>("a node tag")?;
                        if t.len() != 1 {
                            return Err(rd.err(
                                ln4,
                                "expected one node tag per line; fix: the block count disagrees with its lines",
                            ));
                        }
                        ids.push(t[0]);
                    }
                    for k in 0..n {
                        let (ln4, c) = rd.numbers::<f64>("node coordinates")?;
                        if c.len() < 3 || (!parametric && c.len() != 3) {
                            return Err(rd.err(ln4, "expected `x y z`; fix: the block count disagrees with its lines"));
                        }
                        if c[..3].iter().any(|x| !x.is_finite()) {
                            return Err(rd.err(
                                ln4,
                                format!(
                                    "node {} has a non-finite coordinate; fix: repair the node",
                                    ids[start + k]
                                ),
                            ));
                        }
                        pts.push([c[0], c[1], c[2]]);
                    }
                }
                if ids.len() != h[1] {
                    return Err(rd.err(
                        ln2,
                        format!(
                            "$Nodes announces {} nodes but its blocks hold {}; fix: repair the header",
                            h[1],
                            ids.len()
                        ),
                    ));
                }
                rd.expect("$EndNodes")?;
                saw_nodes = true;
            }
            "$Elements" => {
                let (ln2, h) = rd.numbers::<usize>("the $Elements header")?;
                if h.len() != 4 {
                    return Err(rd.err(
                        ln2,
                        "expected `numEntityBlocks numElements minElementTag maxElementTag`",
                    ));
                }
                elems.reserve(h[1]);
                let mut count = 0usize;
                for _ in 0..h[0] {
                    let (ln3, b) = rd.numbers::<i64>("an element block header")?;
                    if b.len() != 4 || b[3] < 0 {
                        return Err(rd.err(ln3, "expected `entityDim entityTag elementType numElementsInBlock`"));
                    }
                    let tag = entity_phys.get(&(b[0] as u8, b[1] as i32)).copied().unwrap_or(0);
                    let gtype = b[2] as u32;
                    for _ in 0..b[3] {
                        let (ln4, v) = rd.numbers::<u64>("an element")?;
                        if v.is_empty() {
                            return Err(rd.err(ln4, "empty element line"));
                        }
                        if let Some((nn, _)) = nodes_per_type(gtype) {
                            if v.len() != nn + 1 {
                                return Err(rd.err(ln4, format!("element {} of type {gtype} has {} node ids, expected {nn}; fix: the block count disagrees with its lines", v[0], v.len() - 1)));
                            }
                        }
                        elems.push(RawElem {
                            line: ln4,
                            id: v[0],
                            gtype,
                            tag,
                            nodes: v[1..].to_vec(),
                        });
                        count += 1;
                    }
                }
                if count != h[1] {
                    return Err(rd.err(
                        ln2,
                        format!(
                            "$Elements announces {} elements but its blocks hold {count}; fix: repair the header",
                            h[1]
                        ),
                    ));
                }
                rd.expect("$EndElements")?;
            }
            s if s.starts_with('$') => rd.skip_section(s)?,
            _ => return Err(rd.err(ln, format!("unexpected `{}` between sections", short(l)))),
        }
    }
    if !saw_nodes {
        bail!(
            "{}: no $Nodes section; fix: the file holds no mesh (run gmsh -3 first)",
            rd.path
        );
    }
    build(rd.path.clone(), ids, pts, elems, names, &rd)
}

fn build(
    source: String,
    ids: Vec<u64>,
    pts: Vec<[f64; 3]>,
    elems: Vec<RawElem>,
    names: BTreeMap<(u8, i32), String>,
    rd: &Lines,
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
    for e in &elems {
        let Some((nn, dim)) = nodes_per_type(e.gtype) else {
            return Err(rd.err(e.line, format!("element {}: {}", e.id, type_problem(e.gtype))));
        };
        if e.nodes.len() != nn {
            return Err(rd.err(
                e.line,
                format!("element {} has {} node ids, expected {nn}", e.id, e.nodes.len()),
            ));
        }
        buf.clear();
        for &n in &e.nodes {
            let Some(&k) = index.get(&n) else {
                return Err(rd.err(e.line, format!("element {} names node {n}, which the file does not define; fix: repair the element or add the node", e.id)));
            };
            buf.push(k);
        }
        if dim == 3 {
            mesh.push_cell(CellKind::from_gmsh(e.gtype).unwrap(), &buf, e.tag);
        } else {
            mesh.facets.push(dim, e.tag, &buf);
        }
    }
    if mesh.n_cells() == 0 {
        bail!("{source}: no volume cells (tetrahedra, hexahedra, prisms or pyramids); fix: mesh the volume (gmsh -3), not only its surface");
    }
    mesh.orient_cells()?;
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
    let ids: Vec<u64> = if mesh.node_ids.len() == n {
        mesh.node_ids.clone()
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
