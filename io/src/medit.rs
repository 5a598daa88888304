//! Medit `.mesh` (ASCII) reader.
//!
//! Keywords `Vertices`, `Tetrahedra`, `Hexahedra`, `Prisms`, `Pyramids` (volume cells),
//! `Triangles`, `Quadrilaterals`, `Edges` (facets); the reference of each entity is its tag.
//! Medit numbers vertices from 1. Its local orders of tetrahedra and hexahedra (bottom face, then
//! the top face above it) are Gmsh's (checked against gmsh's own `.mesh` output in
//! tests/formats.rs); prisms are taken the same way (bottom triangle, then the top one above it;
//! gmsh writes no prisms to `.mesh`, so that order is not cross-checked), and the validation pass
//! reorients any cell that comes inverted.

use crate::mesh::{CellKind, Mesh};
use crate::scan::{cap, reserve, short, Scan};
use anyhow::{bail, Result};

/// Parses the bytes of a `.mesh` file.
pub fn parse(name: &str, bytes: &[u8]) -> Result<Mesh> {
    if bytes.starts_with(&[1, 0, 0, 0]) || bytes.starts_with(&[0, 0, 0, 1]) {
        bail!("{name}: binary Medit (.meshb) data; fix: save as ASCII .mesh");
    }
    let mut sc = Scan::new(name, bytes);
    sc.comment = Some(b'#');
    let mut mesh = Mesh::new(name);
    let mut saw_vertices = false;
    let mut pending: Vec<(CellKind, Vec<u64>, i32, usize, u64)> = Vec::new();
    let mut facets: Vec<(u8, Vec<u64>, i32, usize, u64)> = Vec::new();
    let mut cell_no = 0u64;
    while let Some(t) = sc.token() {
        let kpos = sc.pos;
        let key = String::from_utf8_lossy(t).to_string();
        match key.as_str() {
            "MeshVersionFormatted" => {
                let v: u32 = sc.num("the format version")?;
                if v == 0 || v > 4 {
                    return Err(sc.err(format!("MeshVersionFormatted {v} is unknown; fix: use 1, 2 or 3")));
                }
            }
            "Dimension" => {
                let d: u32 = sc.num("the dimension")?;
                if d != 3 {
                    return Err(sc.err(format!("Dimension {d}; eprop reads 3D meshes; fix: mesh in 3D")));
                }
            }
            "Vertices" => {
                let n = sc.count("the vertex count")?;
                let c = cap(n, sc.remaining(), 8);
                reserve(&mut mesh.points, c, name)?;
                for _ in 0..n {
                    let mut p = [0.0; 3];
                    for v in &mut p {
                        *v = sc.num("a vertex coordinate")?;
                    }
                    sc.num::<i64>("a vertex reference")?;
                    mesh.points.push(p);
                }
                mesh.node_ids = (1..=mesh.points.len() as u64).collect();
                saw_vertices = true;
            }
            "Tetrahedra" | "Hexahedra" | "Prisms" | "Pyramids" | "Triangles" | "Quadrilaterals" | "Edges" => {
                let n = sc.count("the element count")?;
                let (vol, nn, dim) = match key.as_str() {
                    "Tetrahedra" => (Some(CellKind::Tet), 4, 3),
                    "Hexahedra" => (Some(CellKind::Hex), 8, 3),
                    "Prisms" => (Some(CellKind::Wedge), 6, 3),
                    "Pyramids" => (Some(CellKind::Pyramid), 5, 3),
                    "Triangles" => (None, 3, 2),
                    "Quadrilaterals" => (None, 4, 2),
                    _ => (None, 2, 1),
                };
                let c = cap(n, sc.remaining(), 2 * nn + 2);
                if vol.is_some() {
                    reserve(&mut pending, c, name)?;
                } else {
                    reserve(&mut facets, c, name)?;
                }
                for k in 0..n {
                    let pos = sc.pos;
                    let mut v = Vec::with_capacity(nn);
                    for _ in 0..nn {
                        v.push(sc.num::<u64>("a vertex index")?);
                    }
                    let r: i64 = sc.num("an element reference")?;
                    let r = i32::try_from(r).map_err(|_| {
                        sc.err(format!(
                            "reference {r} out of range; fix: use references that fit 32 bits"
                        ))
                    })?;
                    match vol {
                        Some(kind) => {
                            cell_no += 1;
                            pending.push((kind, v, r, pos, cell_no));
                        }
                        None => facets.push((dim, v, r, pos, k as u64 + 1)),
                    }
                }
            }
            "TetrahedraP2" | "HexahedraQ2" | "TrianglesP2" | "QuadrilateralsQ2" | "EdgesP2" | "PrismsP2" => {
                return Err(sc.err_at(kpos, format!("{key} are higher-order elements, which eprop does not read; fix: re-mesh with first-order elements")));
            }
            "End" => break,
            _ if key.starts_with(|c: char| c.is_ascii_alphabetic()) => {
                // a section eprop does not use (Corners, Ridges, Normals, ...): skip its numbers
                while let Some(t) = sc.peek() {
                    if t.first().is_some_and(|c| c.is_ascii_alphabetic()) {
                        break;
                    }
                    sc.token();
                }
            }
            _ => {
                return Err(sc.err_at(
                    kpos,
                    format!(
                        "unexpected `{}`; fix: a count disagrees with its entries or the file is malformed",
                        short(&key)
                    ),
                ))
            }
        }
    }
    if !saw_vertices {
        bail!("{name}: no Vertices section; fix: the file holds no mesh");
    }
    let np = mesh.points.len() as u64;
    let check = |v: &[u64], pos: usize, what: String, sc: &Scan| -> Result<Vec<u32>> {
        v.iter()
            .map(|&i| {
                if i == 0 || i > np {
                    Err(sc.err_at(
                        pos,
                        format!("{what} names vertex {i}, but vertices are numbered 1..{np}; fix: repair the element"),
                    ))
                } else {
                    Ok((i - 1) as u32)
                }
            })
            .collect()
    };
    for (kind, v, r, pos, no) in pending {
        let nodes = check(&v, pos, format!("{} {no}", kind.name()), &sc)?;
        mesh.push_cell(kind, &nodes, r);
        mesh.cell_ids.push(no);
    }
    for (dim, v, r, pos, no) in facets {
        let nodes = check(&v, pos, format!("element {no}"), &sc)?;
        mesh.facets.push(dim, r, &nodes);
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    #[test]
    fn skips_unused_sections_and_comments() {
        let t = "MeshVersionFormatted 2 # v\nDimension\n3\nVertices\n4\n0 0 0 1\n1 0 0 1\n0 1 0 1\n0 0 1 1\nCorners\n1\n1\nNormals\n1\n0 0 1\nTetrahedra\n1\n1 2 3 4 5\nTriangles\n1\n1 2 3 9\nEnd\n";
        let m = super::parse("m.mesh", t.as_bytes()).unwrap();
        assert_eq!(
            (m.n_nodes(), m.n_cells(), m.cell_tags[0], m.facets.tags[0]),
            (4, 1, 5, 9)
        );
    }
}
