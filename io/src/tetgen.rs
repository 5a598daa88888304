//! TetGen `.node` / `.ele` (+ optional `.face`) reader.
//!
//! The region attribute (first attribute) of each tetrahedron becomes its cell tag; boundary
//! markers of `.face` become facet tags. Numbering may start at 0 or 1; `#` starts a comment.

use crate::mesh::{CellKind, Mesh};
use crate::scan::{cap, reserve, Scan};
use anyhow::{bail, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The marker line that separates the parts of a bundle (`parse_bundle`).
pub const BUNDLE_SEP: &str = "%% tetgen-part";

fn id_of(sc: &mut Scan, what: &str) -> Result<u64> {
    let w = sc.word(what)?;
    w.parse::<u64>().map_err(|_| {
        sc.err(format!(
            "`{}` is not a valid index for {what}; fix: repair the line",
            crate::scan::short(w)
        ))
    })
}

/// The local index of each node id: `Dense(Some(first))` while the ids run first, first + 1,
/// ... in file order (index = id - first), a table otherwise.
enum Index {
    Dense(Option<u64>),
    Table(HashMap<u64, u32>),
}

impl Index {
    /// Records node `id` at index `ids.len()` (`ids`: the ids before it); false when it is
    /// there already. `cap`: the expected number of nodes (the table's reservation).
    fn insert(&mut self, id: u64, ids: &[u64], cap: usize) -> Result<bool, String> {
        let at = ids.len() as u32;
        match self {
            Index::Dense(first) => {
                let f = *first.get_or_insert(id);
                if f.checked_add(ids.len() as u64) == Some(id) {
                    return Ok(true);
                }
                // out of the run: a table of the ids so far (distinct, being consecutive)
                let mut t: HashMap<u64, u32> = HashMap::new();
                t.try_reserve(cap.max(ids.len() + 1)).map_err(|_| {
                    format!("not enough memory for {cap} nodes; fix: free memory or use a machine with more")
                })?;
                t.extend(ids.iter().enumerate().map(|(k, &i)| (i, k as u32)));
                *self = Index::Table(t);
                self.insert(id, ids, cap)
            }
            Index::Table(t) => Ok(t.insert(id, at).is_none()),
        }
    }

    /// The index of node `id` among `n` nodes.
    #[inline]
    fn get(&self, id: u64, n: usize) -> Option<u32> {
        match self {
            Index::Dense(None) => None,
            Index::Dense(Some(f)) => id.checked_sub(*f).filter(|&k| k < n as u64).map(|k| k as u32),
            Index::Table(t) => t.get(&id).copied(),
        }
    }
}

/// Parses the three files (the `.face` part is optional).
pub fn parse(name: &str, node: &[u8], ele: &[u8], face: Option<&[u8]>) -> Result<Mesh> {
    let node_name = format!("{name}.node");
    let mut sc = Scan::new(&node_name, node);
    sc.comment = Some(b'#');
    let n = sc.count("the node count")?;
    let dim = sc.count("the dimension")?;
    if dim != 3 {
        return Err(sc.err(format!("dimension {dim}; eprop reads 3D meshes; fix: mesh in 3D")));
    }
    let nattr = sc.count("the attribute count")?;
    let nmark = sc.count("the boundary marker flag")?;
    if nmark > 1 || nattr > 1 << 16 {
        return Err(sc.err("the header is not `<#points> 3 <#attributes> <0|1>`; fix: repair the first line"));
    }
    let mut mesh = Mesh::new(name);
    let c = cap(n, sc.remaining(), 8);
    reserve(&mut mesh.points, c, sc.name)?;
    reserve(&mut mesh.node_ids, c, sc.name)?;
    // node ids as the file numbers them: consecutive from the first (tetgen's own numbering)
    // need no table; the first id out of that run builds one
    let mut index = Index::Dense(None);
    for _ in 0..n {
        let id = id_of(&mut sc, "a node index")?;
        let mut p = [0.0; 3];
        for v in &mut p {
            *v = sc.num("a coordinate")?;
        }
        for _ in 0..nattr + nmark {
            sc.num::<f64>("a node attribute or marker")?;
        }
        if !index.insert(id, &mesh.node_ids, c).map_err(|e| sc.err(e))? {
            return Err(sc.err(format!("node {id} is defined twice; fix: renumber the nodes")));
        }
        mesh.points.push(p);
        mesh.node_ids.push(id);
    }
    let n_nodes = mesh.node_ids.len();
    if !sc.at_end() {
        return Err(sc.err(format!(
            "more lines than the {n} nodes announced; fix: the node count is wrong"
        )));
    }
    let ele_name = format!("{name}.ele");
    let mut sc = Scan::new(&ele_name, ele);
    sc.comment = Some(b'#');
    let ne = sc.count("the tetrahedron count")?;
    let npt = sc.count("the nodes per tetrahedron")?;
    if npt != 4 {
        return Err(sc.err(format!(
            "{npt} nodes per tetrahedron; eprop reads first-order (4-node) tetrahedra; fix: re-mesh with first-order elements (tetgen without -o2)"
        )));
    }
    let nreg = sc.count("the region attribute count")?;
    if nreg > 1 << 16 {
        return Err(sc.err("too many attributes; fix: repair the first line"));
    }
    let c = cap(ne, sc.remaining(), 10);
    reserve(&mut mesh.conn, c * 4, sc.name)?;
    let mut nodes = [0u32; 4];
    for _ in 0..ne {
        let eid = id_of(&mut sc, "a tetrahedron index")?;
        for k in &mut nodes {
            let nid = id_of(&mut sc, "a node index")?;
            *k = index.get(nid, n_nodes).ok_or_else(|| {
                sc.err(format!("tetrahedron {eid} names node {nid}, which the .node file does not define; fix: repair the element or use the matching .node file"))
            })?;
        }
        let mut tag = 0i32;
        for a in 0..nreg {
            let v: f64 = sc.num("a region attribute")?;
            if a == 0 {
                if v.fract() != 0.0 || !(i32::MIN as f64..=i32::MAX as f64).contains(&v) {
                    return Err(sc.err(format!("region attribute {v} of tetrahedron {eid} is not an integer; fix: use integer region attributes")));
                }
                tag = v as i32;
            }
        }
        mesh.push_cell(CellKind::Tet, &nodes, tag);
        mesh.cell_ids.push(eid);
    }
    if !sc.at_end() {
        return Err(sc.err(format!(
            "more lines than the {ne} tetrahedra announced; fix: the count is wrong"
        )));
    }
    if let Some(face) = face {
        let face_name = format!("{name}.face");
        let mut sc = Scan::new(&face_name, face);
        sc.comment = Some(b'#');
        let nf = sc.count("the face count")?;
        let nm = sc.count("the boundary marker flag")?;
        if nm > 1 {
            return Err(sc.err("the header is not `<#faces> <0|1>`; fix: repair the first line"));
        }
        let mut tri = [0u32; 3];
        for _ in 0..nf {
            let fid = id_of(&mut sc, "a face index")?;
            for k in &mut tri {
                let nid = id_of(&mut sc, "a node index")?;
                *k = index.get(nid, n_nodes).ok_or_else(|| {
                    sc.err(format!("face {fid} names node {nid}, which the .node file does not define; fix: use the matching .face file"))
                })?;
            }
            let tag = if nm == 1 {
                sc.num::<i32>("a boundary marker")?
            } else {
                0
            };
            // tetgen -nn adds the two adjacent tetrahedra: skip what is left on the line
            let rest = sc.rest_of_line();
            if rest.iter().any(|c| !c.is_ascii_whitespace()) && !rest.trim_ascii().starts_with(b"#") {
                let ok = rest
                    .split(|c| c.is_ascii_whitespace())
                    .filter(|t| !t.is_empty())
                    .all(|t| {
                        std::str::from_utf8(t)
                            .ok()
                            .and_then(|s| s.parse::<i64>().ok())
                            .is_some()
                    });
                if !ok {
                    return Err(sc.err(format!(
                        "face {fid}: unexpected values after the marker; fix: repair the line"
                    )));
                }
            }
            mesh.facets.push(2, tag, &tri);
        }
        if !sc.at_end() {
            return Err(sc.err(format!(
                "more lines than the {nf} faces announced; fix: the count is wrong"
            )));
        }
    }
    Ok(mesh)
}

/// Parses `node`, `ele` and optional `face` parts joined by `BUNDLE_SEP` lines (for fuzzing).
pub fn parse_bundle(name: &str, bytes: &[u8]) -> Result<Mesh> {
    let sep = BUNDLE_SEP.as_bytes();
    let mut parts: Vec<&[u8]> = Vec::new();
    let mut s = 0;
    let mut i = 0;
    while i + sep.len() <= bytes.len() {
        if &bytes[i..i + sep.len()] == sep {
            parts.push(&bytes[s..i]);
            i += sep.len();
            s = i;
        } else {
            i += 1;
        }
    }
    parts.push(&bytes[s..]);
    match parts.as_slice() {
        [n, e] => parse(name, n, e, None),
        [n, e, f] => parse(name, n, e, Some(f)),
        _ => bail!("{name}: a TetGen bundle needs node and ele parts; fix: join them with `{BUNDLE_SEP}`"),
    }
}

/// Reads `x.node` + `x.ele` (+ `x.face` when present), given any of them.
pub fn read(path: &Path) -> Result<Mesh> {
    let base: PathBuf = path.with_extension("");
    // `x.1.ele` -> `x.1.node`: append, since with_extension would replace the `.1`
    let sib = |ext: &str| PathBuf::from(format!("{}.{ext}", base.display()));
    let node = crate::read_input_file(&sib("node"), "TetGen .node")?;
    let ele = crate::read_input_file(&sib("ele"), "TetGen .ele")?;
    // the .face file is optional; one that is there must be readable
    let face = match std::fs::symlink_metadata(sib("face")) {
        Ok(_) => Some(crate::read_input_file(&sib("face"), "TetGen .face")?),
        Err(_) => None,
    };
    parse(&base.display().to_string(), &node, &ele, face.as_deref())
}

#[cfg(test)]
mod tests {
    #[test]
    fn zero_based_numbering_and_region_attribute() {
        let node = "4 3 0 1\n0 0 0 0 1\n1 1 0 0 1\n2 0 1 0 1\n3 0 0 1 1\n";
        let ele = "# tets\n1 4 1\n0 0 1 2 3 -2.0\n";
        let face = "1 1\n0 0 1 2 7\n";
        let m = super::parse("x", node.as_bytes(), ele.as_bytes(), Some(face.as_bytes())).unwrap();
        assert_eq!(m.node_ids, vec![0, 1, 2, 3]);
        assert_eq!((m.cell_tags[0], m.facets.tags[0]), (-2, 7));
    }

    #[test]
    fn ids_out_of_a_run_are_looked_up_and_duplicates_refused() {
        // consecutive from 1, then a gap: the ids after it are found through the table
        let node = "5 3 0 0\n1 0 0 0\n2 1 0 0\n7 0 1 0\n3 0 0 1\n9 1 1 1\n";
        let ele = "2 4 0\n1 1 2 7 3\n2 2 7 3 9\n";
        let m = super::parse("x", node.as_bytes(), ele.as_bytes(), None).unwrap();
        assert_eq!(m.conn, vec![0, 1, 2, 3, 1, 2, 3, 4]);
        // an id outside the run, and one past the last node of a consecutive run
        let e = super::parse("x", node.as_bytes(), "1 4 0\n1 1 2 8 3\n".as_bytes(), None).unwrap_err();
        assert!(e.to_string().contains("names node 8"), "{e}");
        let dense = "2 3 0 0\n0 0 0 0\n1 1 0 0\n";
        let e = super::parse("x", dense.as_bytes(), "1 4 0\n1 0 1 2 0\n".as_bytes(), None).unwrap_err();
        assert!(e.to_string().contains("names node 2"), "{e}");
        // a duplicate inside the run (the table starts there) and after it
        for node in [
            "3 3 0 0\n1 0 0 0\n2 1 0 0\n1 0 1 0\n",
            "4 3 0 0\n1 0 0 0\n5 1 0 0\n6 0 1 0\n5 0 0 1\n",
        ] {
            let e = super::parse("x", node.as_bytes(), "0 4 0\n".as_bytes(), None).unwrap_err();
            assert!(e.to_string().contains("is defined twice"), "{e}");
        }
    }
}
