//! TetGen `.node` / `.ele` (+ optional `.face`) reader (own code).
//!
//! Given `x.ele` or `x.node`, reads both (and `x.face` when present: boundary markers become
//! facet tags). Numbering may start at 0 or 1 (taken from the first node). The first element
//! attribute, when there is one (a region from `tetgen -A`), becomes the cell tag. Comments start
//! with `#`.

use crate::mesh::{CellKind, Mesh};
use anyhow::{anyhow, bail, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Non-empty, comment-free lines with their 1-based line numbers.
fn lines(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.split('#').next().unwrap_or("");
        let w: Vec<&str> = l.split_whitespace().collect();
        (!w.is_empty()).then_some((i + 1, w))
    })
}

fn num<T: std::str::FromStr>(file: &str, line: usize, w: &str, what: &str) -> Result<T> {
    w.parse()
        .map_err(|_| anyhow!("{file}:{line}: `{w}` is not a valid {what}; fix: repair the line"))
}

fn sibling(path: &Path, ext: &str) -> PathBuf {
    path.with_extension(ext)
}

pub fn read(path: &Path) -> Result<Mesh> {
    let node = sibling(path, "node");
    let ele = sibling(path, "ele");
    let face = sibling(path, "face");
    let rd = |p: &Path| {
        std::fs::read_to_string(p).map_err(|e| {
            anyhow!(
                "{}: cannot read: {e}; fix: TetGen meshes need both FILE.node and FILE.ele side by side",
                p.display()
            )
        })
    };
    let nt = rd(&node)?;
    let et = rd(&ele)?;
    let ft = if face.exists() { Some(rd(&face)?) } else { None };
    parse(
        &node.display().to_string(),
        &nt,
        &ele.display().to_string(),
        &et,
        ft.as_deref().map(|t| (face.display().to_string(), t)),
    )
}

/// Parses the texts of `.node`, `.ele` and optionally `.face`.
pub fn parse(nname: &str, ntext: &str, ename: &str, etext: &str, face: Option<(String, &str)>) -> Result<Mesh> {
    let mut it = lines(ntext);
    let (hl, h) = it
        .next()
        .ok_or_else(|| anyhow!("{nname}: empty file; fix: give a TetGen .node file"))?;
    let n: usize = num(nname, hl, h[0], "node count")?;
    let dim: usize = match h.get(1) {
        Some(w) => num(nname, hl, w, "dimension")?,
        None => 3,
    };
    if dim != 3 {
        bail!("{nname}:{hl}: dimension {dim}; fix: eprop needs 3-D nodes");
    }
    if n > ntext.len() {
        bail!("{nname}:{hl}: {n} nodes announced, more than the file can hold; fix: repair the header");
    }
    let mut mesh = Mesh::new(ename);
    let mut index: HashMap<i64, u32> = HashMap::with_capacity(n);
    for (ln, w) in it.by_ref().take(n) {
        if w.len() < 4 {
            bail!("{nname}:{ln}: a node line needs an id and three coordinates; fix: repair the line");
        }
        let id: i64 = num(nname, ln, w[0], "node id")?;
        let mut p = [0.0f64; 3];
        for d in 0..3 {
            p[d] = num(nname, ln, w[1 + d], "coordinate")?;
            if !p[d].is_finite() {
                bail!("{nname}:{ln}: node {id} has a NaN or infinite coordinate; fix: repair the node");
            }
        }
        if index.insert(id, mesh.points.len() as u32).is_some() {
            bail!("{nname}:{ln}: node id {id} appears twice; fix: renumber the nodes");
        }
        mesh.points.push(p);
        mesh.node_ids.push(id.max(0) as u64);
    }
    if mesh.points.len() != n {
        bail!(
            "{nname}: {n} nodes announced but {} found; fix: the file is truncated or its header is wrong",
            mesh.points.len()
        );
    }
    let mut it = lines(etext);
    let (hl, h) = it
        .next()
        .ok_or_else(|| anyhow!("{ename}: empty file; fix: give a TetGen .ele file"))?;
    let ne: usize = num(ename, hl, h[0], "element count")?;
    let per: usize = match h.get(1) {
        Some(w) => num(ename, hl, w, "nodes per element")?,
        None => 4,
    };
    let nattr: usize = match h.get(2) {
        Some(w) => num(ename, hl, w, "attribute count")?,
        None => 0,
    };
    if per != 4 {
        bail!("{ename}:{hl}: {per} nodes per element; fix: eprop reads linear tetrahedra (run tetgen without -o2)");
    }
    if ne > etext.len() {
        bail!("{ename}:{hl}: {ne} elements announced, more than the file can hold; fix: repair the header");
    }
    let mut count = 0;
    for (ln, w) in it.by_ref().take(ne) {
        if w.len() < 5 {
            bail!("{ename}:{ln}: an element line needs an id and four nodes; fix: repair the line");
        }
        let mut v = [0u32; 4];
        for k in 0..4 {
            let id: i64 = num(ename, ln, w[1 + k], "node index")?;
            v[k] = *index.get(&id).ok_or_else(|| {
                anyhow!(
                    "{ename}:{ln}: element {} names node {id}, which {nname} does not define; fix: repair the element",
                    w[0]
                )
            })?;
        }
        let tag = if nattr > 0 {
            let a: f64 = num(ename, ln, w.get(5).copied().unwrap_or("0"), "attribute")?;
            a as i32
        } else {
            0
        };
        mesh.push_cell(CellKind::Tet, &v, tag);
        count += 1;
    }
    if count != ne {
        bail!("{ename}: {ne} elements announced but {count} found; fix: the file is truncated or its header is wrong");
    }
    if let Some((fname, ftext)) = face {
        let mut it = lines(ftext);
        if let Some((hl, h)) = it.next() {
            let nf: usize = num(&fname, hl, h[0], "face count")?;
            let marked = h.get(1).is_some_and(|m| *m == "1");
            for (ln, w) in it.take(nf) {
                if w.len() < 4 {
                    bail!("{fname}:{ln}: a face line needs an id and three nodes; fix: repair the line");
                }
                let mut v = [0u32; 3];
                for k in 0..3 {
                    let id: i64 = num(&fname, ln, w[1 + k], "node index")?;
                    v[k] = *index.get(&id).ok_or_else(|| {
                        anyhow!("{fname}:{ln}: face names node {id}, which is not defined; fix: repair the face")
                    })?;
                }
                let tag = if marked {
                    num(&fname, ln, w.get(4).copied().unwrap_or("0"), "boundary marker")?
                } else {
                    0
                };
                mesh.facets.push(2, tag, &v);
            }
        }
    }
    if mesh.n_cells() == 0 {
        bail!("{ename}: no tetrahedra; fix: mesh the volume (tetgen -p SURFACE)");
    }
    mesh.orient_cells()?;
    Ok(mesh)
}
