//! Writers for formats eprop reads but does not write (VTK legacy, TetGen, Medit, binary
//! Gmsh), used by the round-trip tests and to make fuzzing seeds. Not meant for production
//! output: `write_mesh` writes `.msh` and `.vtu`. Built only with the `test-writers` feature,
//! which the tests and examples of eprop and eprop-io turn on.

use crate::mesh::Mesh;
use crate::vtk::vtk_order;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// VTK legacy layouts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Legacy {
    V42,
    V51,
}

/// All cells (volume then facets) as (VTK type, VTK-ordered nodes, tag).
fn vtk_cells(m: &Mesh) -> Vec<(u8, Vec<u32>, i32)> {
    let mut v = Vec::new();
    for c in 0..m.n_cells() {
        v.push((m.kinds[c].vtk_type(), vtk_order(m.kinds[c], m.cell(c)), m.cell_tags[c]));
    }
    for f in 0..m.facets.len() {
        let n = m.facets.nodes(f);
        let Some(t) = crate::vtk::facet_vtk_type(m.facets.dim[f], n.len()) else {
            continue;
        };
        v.push((t, n.to_vec(), m.facets.tags[f]));
    }
    v
}

/// VTK legacy unstructured grid, ASCII or BINARY (big-endian), with `tag` cell scalars and
/// `node_ids` point scalars.
pub fn vtk_legacy(m: &Mesh, layout: Legacy, binary: bool) -> Vec<u8> {
    let cells = vtk_cells(m);
    let mut o: Vec<u8> = Vec::new();
    let ver = if layout == Legacy::V42 { "4.2" } else { "5.1" };
    let _ = write!(
        Str(&mut o),
        "# vtk DataFile Version {ver}\neprop test\n{}\nDATASET UNSTRUCTURED_GRID\nPOINTS {} double\n",
        if binary { "BINARY" } else { "ASCII" },
        m.n_nodes()
    );
    let nums = |o: &mut Vec<u8>, vals: &[f64], be: &dyn Fn(f64) -> Vec<u8>, txt: &dyn Fn(f64) -> String| {
        if binary {
            for &v in vals {
                o.extend(be(v));
            }
            o.push(b'\n');
        } else {
            for ch in vals.chunks(9) {
                let s: Vec<String> = ch.iter().map(|&v| txt(v)).collect();
                o.extend(s.join(" ").bytes());
                o.push(b'\n');
            }
        }
    };
    let f64be = |v: f64| v.to_be_bytes().to_vec();
    let i32be = |v: f64| (v as i32).to_be_bytes().to_vec();
    let i64be = |v: f64| (v as i64).to_be_bytes().to_vec();
    let ftxt = |v: f64| format!("{v:?}");
    let itxt = |v: f64| format!("{}", v as i64);
    let pts: Vec<f64> = m.points.iter().flatten().copied().collect();
    nums(&mut o, &pts, &f64be, &ftxt);
    match layout {
        Legacy::V42 => {
            let mut list = Vec::new();
            for (_, n, _) in &cells {
                list.push(n.len() as f64);
                list.extend(n.iter().map(|&x| x as f64));
            }
            o.extend(format!("CELLS {} {}\n", cells.len(), list.len()).bytes());
            nums(&mut o, &list, &i32be, &itxt);
        }
        Legacy::V51 => {
            let mut off = vec![0.0];
            let mut conn = Vec::new();
            for (_, n, _) in &cells {
                conn.extend(n.iter().map(|&x| x as f64));
                off.push(conn.len() as f64);
            }
            o.extend(format!("CELLS {} {}\nOFFSETS vtktypeint64\n", off.len(), conn.len()).bytes());
            nums(&mut o, &off, &i64be, &itxt);
            o.extend(b"CONNECTIVITY vtktypeint64\n");
            nums(&mut o, &conn, &i64be, &itxt);
        }
    }
    o.extend(format!("CELL_TYPES {}\n", cells.len()).bytes());
    let types: Vec<f64> = cells.iter().map(|c| c.0 as f64).collect();
    nums(&mut o, &types, &i32be, &itxt);
    o.extend(format!("CELL_DATA {}\nSCALARS tag int 1\nLOOKUP_TABLE default\n", cells.len()).bytes());
    let tags: Vec<f64> = cells.iter().map(|c| c.2 as f64).collect();
    nums(&mut o, &tags, &i32be, &itxt);
    o.extend(
        format!(
            "POINT_DATA {}\nSCALARS node_ids vtktypeint64\nLOOKUP_TABLE default\n",
            m.n_nodes()
        )
        .bytes(),
    );
    let ids: Vec<f64> = m.node_ids.iter().map(|&i| i as f64).collect();
    nums(&mut o, &ids, &i64be, &itxt);
    o
}

struct Str<'a>(&'a mut Vec<u8>);
impl std::fmt::Write for Str<'_> {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        self.0.extend_from_slice(s.as_bytes());
        Ok(())
    }
}

/// TetGen `.node`, `.ele`, `.face` texts (tetrahedra and triangles only).
pub fn tetgen(m: &Mesh) -> (String, String, String) {
    let mut node = format!("# eprop test\n{} 3 0 0\n", m.n_nodes());
    for (k, p) in m.points.iter().enumerate() {
        let _ = writeln!(node, "{} {:?} {:?} {:?}", m.node_ids[k], p[0], p[1], p[2]);
    }
    let mut ele = format!("{} 4 1\n", m.n_cells());
    for c in 0..m.n_cells() {
        let _ = write!(ele, "{}", c + 1);
        for &n in m.cell(c) {
            let _ = write!(ele, " {}", m.node_ids[n as usize]);
        }
        let _ = writeln!(ele, " {}", m.cell_tags[c]);
    }
    let tris: Vec<usize> = (0..m.facets.len()).filter(|&f| m.facets.nodes(f).len() == 3).collect();
    let mut face = format!("{} 1\n", tris.len());
    for (k, &f) in tris.iter().enumerate() {
        let _ = write!(face, "{}", k + 1);
        for &n in m.facets.nodes(f) {
            let _ = write!(face, " {}", m.node_ids[n as usize]);
        }
        let _ = writeln!(face, " {}  # boundary", m.facets.tags[f]);
    }
    (node, ele, face)
}

/// The three TetGen parts joined for `tetgen::parse_bundle`.
pub fn tetgen_bundle(m: &Mesh) -> Vec<u8> {
    let (n, e, f) = tetgen(m);
    let sep = crate::tetgen::BUNDLE_SEP;
    format!("{n}{sep}\n{e}{sep}\n{f}").into_bytes()
}

/// Medit `.mesh` text.
pub fn medit(m: &Mesh) -> String {
    let mut s = format!("MeshVersionFormatted 2\n\nDimension 3\n\nVertices\n{}\n", m.n_nodes());
    for p in &m.points {
        let _ = writeln!(s, "{:?} {:?} {:?} 0", p[0], p[1], p[2]);
    }
    for (kw, kind) in [
        ("Tetrahedra", crate::CellKind::Tet),
        ("Hexahedra", crate::CellKind::Hex),
        ("Prisms", crate::CellKind::Wedge),
        ("Pyramids", crate::CellKind::Pyramid),
    ] {
        let cs: Vec<usize> = (0..m.n_cells()).filter(|&c| m.kinds[c] == kind).collect();
        if cs.is_empty() {
            continue;
        }
        let _ = writeln!(s, "\n{kw}\n{}", cs.len());
        for c in cs {
            for &n in m.cell(c) {
                let _ = write!(s, "{} ", n + 1);
            }
            let _ = writeln!(s, "{}", m.cell_tags[c]);
        }
    }
    for (kw, dim, nn) in [("Triangles", 2, 3), ("Quadrilaterals", 2, 4), ("Edges", 1, 2)] {
        let fs: Vec<usize> = (0..m.facets.len())
            .filter(|&f| m.facets.dim[f] == dim && m.facets.nodes(f).len() == nn)
            .collect();
        if fs.is_empty() {
            continue;
        }
        let _ = writeln!(s, "\n{kw}\n{}", fs.len());
        for f in fs {
            for &n in m.facets.nodes(f) {
                let _ = write!(s, "{} ", n + 1);
            }
            let _ = writeln!(s, "{}", m.facets.tags[f]);
        }
    }
    s.push_str("\nEnd\n");
    s
}

fn gmsh_type(dim: u8, nn: usize) -> Option<u32> {
    match (dim, nn) {
        (2, 3) => Some(2),
        (2, 4) => Some(3),
        (1, 2) => Some(1),
        (0, 1) => Some(15),
        _ => None,
    }
}

/// All elements as (dim, gmsh type, tag, nodes).
fn gmsh_elems(m: &Mesh) -> Vec<(u8, u32, i32, Vec<u32>)> {
    let mut v: Vec<(u8, u32, i32, Vec<u32>)> = (0..m.n_cells())
        .map(|c| (3, m.kinds[c].gmsh_type(), m.cell_tags[c], m.cell(c).to_vec()))
        .collect();
    for f in 0..m.facets.len() {
        let n = m.facets.nodes(f);
        if let Some(t) = gmsh_type(m.facets.dim[f], n.len()) {
            v.push((m.facets.dim[f], t, m.facets.tags[f], n.to_vec()));
        }
    }
    v
}

fn names_section(m: &Mesh) -> String {
    if m.group_names.is_empty() {
        return String::new();
    }
    let mut s = format!("$PhysicalNames\n{}\n", m.group_names.len());
    for ((d, t), n) in &m.group_names {
        let _ = writeln!(s, "{d} {t} \"{n}\"");
    }
    s.push_str("$EndPhysicalNames\n");
    s
}

/// Binary Gmsh 2.2 (little- or big-endian).
pub fn gmsh22_binary(m: &Mesh, big: bool) -> Vec<u8> {
    let i = |x: i32| if big { x.to_be_bytes() } else { x.to_le_bytes() };
    let d = |x: f64| if big { x.to_be_bytes() } else { x.to_le_bytes() };
    let mut o: Vec<u8> = b"$MeshFormat\n2.2 1 8\n".to_vec();
    o.extend(i(1));
    o.extend(b"\n$EndMeshFormat\n");
    o.extend(names_section(m).bytes());
    o.extend(format!("$Nodes\n{}\n", m.n_nodes()).bytes());
    for (k, p) in m.points.iter().enumerate() {
        o.extend(i(m.node_ids[k] as i32));
        for &x in p {
            o.extend(d(x));
        }
    }
    let els = gmsh_elems(m);
    o.extend(format!("\n$EndNodes\n$Elements\n{}\n", els.len()).bytes());
    // consecutive elements of one type share a block header
    let mut k = 0;
    while k < els.len() {
        let mut j = k + 1;
        while j < els.len() && els[j].1 == els[k].1 {
            j += 1;
        }
        o.extend(i(els[k].1 as i32));
        o.extend(i((j - k) as i32));
        o.extend(i(2));
        for (e, el) in els.iter().enumerate().take(j).skip(k) {
            o.extend(i(e as i32 + 1));
            o.extend(i(el.2));
            o.extend(i(el.2));
            for &n in &el.3 {
                o.extend(i(m.node_ids[n as usize] as i32));
            }
        }
        k = j;
    }
    o.extend(b"\n$EndElements\n");
    o
}

/// Binary Gmsh 4.1 (little- or big-endian, 8-byte size_t).
pub fn gmsh41_binary(m: &Mesh, big: bool) -> Vec<u8> {
    let i = |x: i32| if big { x.to_be_bytes() } else { x.to_le_bytes() };
    let z = |x: u64| if big { x.to_be_bytes() } else { x.to_le_bytes() };
    let d = |x: f64| if big { x.to_be_bytes() } else { x.to_le_bytes() };
    let els = gmsh_elems(m);
    let mut ents: BTreeMap<(u8, i32), i32> = BTreeMap::new();
    for e in &els {
        ents.entry((e.0, e.2)).or_insert(0);
    }
    let mut counts = [0u64; 4];
    for ((dim, _), e) in ents.iter_mut() {
        counts[*dim as usize] += 1;
        *e = counts[*dim as usize] as i32;
    }
    let mut o: Vec<u8> = b"$MeshFormat\n4.1 1 8\n".to_vec();
    o.extend(i(1));
    o.extend(b"\n$EndMeshFormat\n");
    o.extend(names_section(m).bytes());
    o.extend(b"$Entities\n");
    for c in counts {
        o.extend(z(c));
    }
    for ((dim, tag), e) in &ents {
        o.extend(i(*e));
        for _ in 0..if *dim == 0 { 3 } else { 6 } {
            o.extend(d(0.0));
        }
        o.extend(z(1));
        o.extend(i(*tag));
        if *dim > 0 {
            o.extend(z(0));
        }
    }
    o.extend(b"\n$EndEntities\n$Nodes\n");
    let n = m.n_nodes() as u64;
    let vol = ents.iter().find(|((dd, _), _)| *dd == 3).map(|(_, e)| *e).unwrap_or(1);
    for x in [1, n, 1, n] {
        o.extend(z(x));
    }
    o.extend(i(3));
    o.extend(i(vol));
    o.extend(i(0));
    o.extend(z(n));
    for &id in &m.node_ids {
        o.extend(z(id));
    }
    for p in &m.points {
        for &x in p {
            o.extend(d(x));
        }
    }
    o.extend(b"\n$EndNodes\n$Elements\n");
    // runs of elements with the same (dim, tag, type) become blocks, keeping element order
    let mut blocks: Vec<((u8, i32, u32), Vec<usize>)> = Vec::new();
    for (k, e) in els.iter().enumerate() {
        match blocks.last_mut() {
            Some((key, list)) if *key == (e.0, e.2, e.1) => list.push(k),
            _ => blocks.push(((e.0, e.2, e.1), vec![k])),
        }
    }
    for x in [blocks.len() as u64, els.len() as u64, 1, els.len() as u64] {
        o.extend(z(x));
    }
    let mut eid = 1u64;
    for ((dim, tag, ty), list) in &blocks {
        o.extend(i(*dim as i32));
        o.extend(i(ents[&(*dim, *tag)]));
        o.extend(i(*ty as i32));
        o.extend(z(list.len() as u64));
        for &k in list {
            o.extend(z(eid));
            eid += 1;
            for &nn in &els[k].3 {
                o.extend(z(m.node_ids[nn as usize]));
            }
        }
    }
    o.extend(b"\n$EndElements\n");
    o
}

/// Small meshes (tetrahedra, hexahedra, prisms, a cylinder) written in every encoding of a
/// format: the seeds of the fuzzer and the inputs of round-trip tests.
pub fn seeds(format: crate::Format) -> Vec<(String, Vec<u8>)> {
    use crate::generate::{box_mesh, cylinder_mesh, BoxCells};
    use crate::vtu::{to_bytes, Encoding, VtuOptions};
    use crate::Format;
    let mut meshes: Vec<(&str, Mesh)> = Vec::new();
    for (n, k) in [
        ("tet", BoxCells::Tet),
        ("hex", BoxCells::Hex),
        ("wedge", BoxCells::Wedge),
    ] {
        if let Ok(m) = box_mesh([1.0, 2.0, 0.5], [2, 1, 1], k) {
            meshes.push((n, m));
        }
    }
    if let Ok(m) = cylinder_mesh(1.0, 1.0, 1, 1) {
        meshes.push(("cyl", m));
    }
    let mut out = Vec::new();
    for (n, m) in &meshes {
        match format {
            Format::Gmsh => {
                out.push((format!("{n}-22le.msh"), gmsh22_binary(m, false)));
                out.push((format!("{n}-22be.msh"), gmsh22_binary(m, true)));
                out.push((format!("{n}-41le.msh"), gmsh41_binary(m, false)));
                out.push((format!("{n}-41be.msh"), gmsh41_binary(m, true)));
                let p = std::env::temp_dir().join(format!("eprop-seed-{}-{n}.msh", std::process::id()));
                if crate::gmsh::write(m, &p).is_ok() {
                    if let Ok(b) = std::fs::read(&p) {
                        out.push((format!("{n}-41.msh"), b));
                    }
                }
                let _ = std::fs::remove_file(&p);
            }
            Format::VtkLegacy => {
                out.push((format!("{n}-42a.vtk"), vtk_legacy(m, Legacy::V42, false)));
                out.push((format!("{n}-42b.vtk"), vtk_legacy(m, Legacy::V42, true)));
                out.push((format!("{n}-51a.vtk"), vtk_legacy(m, Legacy::V51, false)));
                out.push((format!("{n}-51b.vtk"), vtk_legacy(m, Legacy::V51, true)));
            }
            Format::Vtu => {
                for (e, en) in [
                    (Encoding::Ascii, "ascii"),
                    (Encoding::Base64, "b64"),
                    (Encoding::AppendedRaw, "raw"),
                    (Encoding::AppendedBase64, "ab64"),
                ] {
                    for zlib in [false, true] {
                        if e == Encoding::Ascii && zlib {
                            continue;
                        }
                        for (h64, be) in [(false, false), (true, true)] {
                            let o = VtuOptions {
                                encoding: e,
                                zlib,
                                header64: h64,
                                big_endian: be,
                            };
                            let z = if zlib { "-zlib" } else { "" };
                            let h = if h64 { "-h64" } else { "-h32" };
                            let b = if be { "-be" } else { "-le" };
                            out.push((format!("{n}-{en}{z}{h}{b}.vtu"), to_bytes(m, &o)));
                        }
                    }
                }
            }
            Format::TetGen => {
                if m.kinds.iter().all(|&k| k == crate::CellKind::Tet) {
                    out.push((format!("{n}.tetgen"), tetgen_bundle(m)));
                }
            }
            Format::Medit => out.push((format!("{n}.mesh"), medit(m).into_bytes())),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Format;

    #[test]
    fn every_seed_parses_and_validates() {
        for f in [
            Format::Gmsh,
            Format::VtkLegacy,
            Format::Vtu,
            Format::TetGen,
            Format::Medit,
        ] {
            for (name, bytes) in seeds(f) {
                let mut m = crate::parse_mesh(f, &name, &bytes).unwrap_or_else(|e| panic!("{name}: {e:#}"));
                crate::validate(&mut m, &crate::ReadOptions { strict: true })
                    .unwrap_or_else(|e| panic!("{name}: {e:#}"));
                assert!(m.n_cells() > 0, "{name}");
            }
        }
    }
}
