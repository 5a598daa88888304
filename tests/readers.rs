//! Readers checked against independent writers: every shared organ mesh reads and passes the
//! geometry identities; VTU written here by hand in each binary encoding (inline base64, zlib
//! blocks, appended raw and base64) reads back the same mesh and its `tissue` tags; TetGen files
//! with either numbering and with markers; meshes `tetgen` made. The malformed-file catalogue
//! and the round trips through eprop's own writers are in `formats.rs`.

mod common;

use base64::Engine;
use eprop_io::generate::{box_mesh, cylinder_mesh, BoxCells};
use eprop_mesh::Mesh;
use std::io::Write;
use std::path::Path;

fn same(a: &Mesh, b: &Mesh) {
    assert_eq!(a.points, b.points);
    assert_eq!(a.conn, b.conn);
    assert_eq!(a.kinds, b.kinds);
    assert_eq!(a.cell_tags, b.cell_tags);
    assert_eq!(a.node_ids, b.node_ids);
}

#[test]
fn every_shared_tetrahedral_mesh_reads_with_closed_control_volumes() {
    for name in [
        "sofa_liver.msh",
        "sofa_liver2.msh",
        "caribou_deformed_liver_volume_tetrahedrons.vtu",
        "mor_liverFine.vtu",
        "mmc_head_atlas.vtu",
    ] {
        let Some(p) = common::shared_mesh(name) else { continue };
        let m = eprop_io::read_mesh(&p).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        let info = eprop::simulate::mesh_info(&m);
        let rel = ((info.control_volume_sum - info.volume) / info.volume).abs();
        assert!(rel < 1e-12, "{name}: sum V_i off by {rel:e}");
        assert!(
            info.max_closure_error < 1e-12,
            "{name}: closure {:e}",
            info.max_closure_error
        );
    }
}

#[test]
fn vtu_round_trips_every_cell_kind() {
    let d = tempfile::tempdir().unwrap();
    for (k, m) in [
        box_mesh([1.0, 2.0, 1.5], [3, 2, 2], BoxCells::Tet).unwrap(),
        box_mesh([1.0, 2.0, 1.5], [3, 2, 2], BoxCells::Hex).unwrap(),
        box_mesh([1.0, 2.0, 1.5], [3, 2, 2], BoxCells::Wedge).unwrap(),
        cylinder_mesh(1.0, 4.0, 3, 11).unwrap(),
    ]
    .into_iter()
    .enumerate()
    {
        let p = d.path().join(format!("m{k}.vtu"));
        eprop_io::write_mesh(&m, &p).unwrap();
        let back = eprop_io::read_mesh(&p).unwrap();
        same(&m, &back);
        // and through Gmsh 4.1
        let g = d.path().join(format!("m{k}.msh"));
        eprop_io::write_mesh(&back, &g).unwrap();
        same(&m, &eprop_io::read_mesh(&g).unwrap());
    }
}

/// A VTU of `m` with its arrays in one of VTK's binary encodings.
fn vtu_binary(m: &Mesh, mode: &str) -> Vec<u8> {
    let pts: Vec<u8> = m.points.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
    let conn: Vec<u8> = m.conn.iter().flat_map(|&x| (x as i64).to_le_bytes()).collect();
    let mut offs = vec![];
    let mut at = 0i64;
    for c in 0..m.n_cells() {
        at += m.cell(c).len() as i64;
        offs.extend_from_slice(&at.to_le_bytes());
    }
    let types: Vec<u8> = m.kinds.iter().map(|k| k.vtk_type()).collect();
    let tags: Vec<u8> = m.cell_tags.iter().flat_map(|t| t.to_le_bytes()).collect();
    let arrays = [
        ("Float64", "Points", 3, pts),
        ("Int64", "connectivity", 1, conn),
        ("Int64", "offsets", 1, offs),
        ("UInt8", "types", 1, types),
        ("Int32", "tissue", 1, tags),
    ];
    let b64 = |b: &[u8]| base64::engine::general_purpose::STANDARD.encode(b);
    let zlib = mode.contains("zlib");
    let enc = |raw: &[u8]| -> (Vec<u8>, Vec<u8>) {
        // (header, data) with UInt32 header
        if zlib {
            let mut e = flate2::write::ZlibEncoder::new(vec![], flate2::Compression::default());
            e.write_all(raw).unwrap();
            let z = e.finish().unwrap();
            let mut h = vec![];
            for v in [1u32, raw.len() as u32, raw.len() as u32, z.len() as u32] {
                h.extend_from_slice(&v.to_le_bytes());
            }
            (h, z)
        } else {
            ((raw.len() as u32).to_le_bytes().to_vec(), raw.to_vec())
        }
    };
    let comp = if zlib {
        " compressor=\"vtkZLibDataCompressor\""
    } else {
        ""
    };
    let mut head = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt32\"{comp}>\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">\n",
        m.n_nodes(),
        m.n_cells()
    );
    let mut appended: Vec<u8> = vec![];
    for (i, (ty, name, nc, raw)) in arrays.iter().enumerate() {
        let open = match i {
            0 => "<Points>\n",
            1 => "<Cells>\n",
            4 => "<CellData>\n",
            _ => "",
        };
        head.push_str(open);
        let (h, data) = enc(raw);
        if mode.starts_with("appended") {
            let off = appended.len();
            if mode.contains("base64") {
                if zlib {
                    appended.extend_from_slice(b64(&h).as_bytes());
                    appended.extend_from_slice(b64(&data).as_bytes());
                } else {
                    appended.extend_from_slice(b64(&[h, data].concat()).as_bytes());
                }
            } else {
                appended.extend_from_slice(&h);
                appended.extend_from_slice(&data);
            }
            head.push_str(&format!(
                "<DataArray type=\"{ty}\" Name=\"{name}\" NumberOfComponents=\"{nc}\" format=\"appended\" offset=\"{off}\"/>\n"
            ));
        } else {
            let text = if zlib {
                b64(&h) + &b64(&data)
            } else {
                b64(&[h, data].concat())
            };
            head.push_str(&format!(
                "<DataArray type=\"{ty}\" Name=\"{name}\" NumberOfComponents=\"{nc}\" format=\"binary\">\n{text}\n</DataArray>\n"
            ));
        }
        let close = match i {
            0 => "</Points>\n",
            3 => "</Cells>\n",
            4 => "</CellData>\n",
            _ => "",
        };
        head.push_str(close);
    }
    head.push_str("</Piece>\n</UnstructuredGrid>\n");
    let mut out = head.into_bytes();
    if mode.starts_with("appended") {
        let enc = if mode.contains("base64") { "base64" } else { "raw" };
        out.extend_from_slice(format!("<AppendedData encoding=\"{enc}\">\n_").as_bytes());
        out.extend_from_slice(&appended);
        out.extend_from_slice(b"\n</AppendedData>\n");
    }
    out.extend_from_slice(b"</VTKFile>\n");
    out
}

#[test]
fn vtu_reads_every_binary_encoding() {
    let mut m = cylinder_mesh(1.0, 4.0, 3, 5).unwrap();
    for (c, t) in m.cell_tags.iter_mut().enumerate() {
        *t = (c % 3) as i32 + 1;
    }
    for mode in [
        "binary",
        "binary-zlib",
        "appended-raw",
        "appended-raw-zlib",
        "appended-base64",
        "appended-base64-zlib",
    ] {
        let b = vtu_binary(&m, mode);
        let back = eprop_io::vtu::parse(mode, &b).unwrap_or_else(|e| panic!("{mode}: {e:#}"));
        assert_eq!(back.points, m.points, "{mode}");
        assert_eq!(back.conn, m.conn, "{mode}");
        assert_eq!(back.cell_tags, m.cell_tags, "{mode}: the `tissue` array is the tag");
    }
}

#[test]
fn tetgen_files_read_with_markers_and_both_numberings() {
    let d = tempfile::tempdir().unwrap();
    let m = box_mesh([1.0, 1.0, 1.0], [2, 2, 2], BoxCells::Tet).unwrap();
    for base in [0i64, 1] {
        let mut node = format!("# a box\n{} 3 0 0\n", m.n_nodes());
        for (i, p) in m.points.iter().enumerate() {
            node += &format!("{} {:?} {:?} {:?}\n", i as i64 + base, p[0], p[1], p[2]);
        }
        let mut ele = format!("{} 4 1\n", m.n_cells());
        for c in 0..m.n_cells() {
            let v: Vec<String> = m.cell(c).iter().map(|&x| (x as i64 + base).to_string()).collect();
            ele += &format!("{} {} {}\n", c as i64 + base, v.join(" "), 1 + c % 2);
        }
        let stem = d.path().join(format!("b{base}.1"));
        std::fs::write(stem.with_extension("node"), &node).unwrap();
        std::fs::write(stem.with_extension("ele"), &ele).unwrap();
        std::fs::write(
            stem.with_extension("face"),
            format!("1 1\n{base} {} {} {} 7\n", base, base + 1, base + 2),
        )
        .unwrap();
        let back = eprop_io::read_mesh(&stem.with_extension("ele")).unwrap();
        assert_eq!(back.points, m.points);
        assert_eq!(back.conn, m.conn);
        assert_eq!(back.cell_tags[..2], [1, 2]);
        assert_eq!(back.facets.tags, [7]);
        // the .node file names the same mesh
        assert_eq!(eprop_io::read_mesh(&stem.with_extension("node")).unwrap().conn, m.conn);
        // damaged: a missing node, a truncated element list
        std::fs::write(stem.with_extension("ele"), ele.replacen(" 1 ", " 999 ", 1)).unwrap();
        let e = format!("{:#}", eprop_io::read_mesh(&stem.with_extension("ele")).unwrap_err());
        assert!(e.contains("does not define") && e.contains("fix:"), "{e}");
        let cut: String = ele.lines().take(5).collect::<Vec<_>>().join("\n");
        std::fs::write(stem.with_extension("ele"), cut).unwrap();
        let e = format!("{:#}", eprop_io::read_mesh(&stem.with_extension("ele")).unwrap_err());
        assert!(e.contains("truncated") && e.contains(".ele"), "{e}");
    }
}

#[test]
fn tetgen_made_organ_meshes_read() {
    let surf = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/meshes/surface/hubmap_VH_M_prostate_peripheral_zone_L.off");
    if !surf.exists() {
        common::skip(&format!("{} not found (the shared surfaces)", surf.display()));
        return;
    }
    if !common::tool("tetgen") {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let off = d.path().join("p.off");
    std::fs::copy(&surf, &off).unwrap();
    let st = std::process::Command::new("tetgen")
        .args(["-pq1.5", "-Q"])
        .arg(&off)
        .output()
        .unwrap();
    assert!(st.status.success());
    let m = eprop_io::read_mesh(&d.path().join("p.1.ele")).unwrap();
    let info = eprop::simulate::mesh_info(&m);
    assert!(((info.control_volume_sum - info.volume) / info.volume).abs() < 1e-12);
    assert!(info.max_closure_error < 1e-10);
    assert!(!m.facets.is_empty(), "the .face file gives the boundary");
}
