//! Mesh formats: every shared test mesh reads, round trips through every format, meshes made
//! by tetgen and gmsh (when installed) read alike, a catalogue of malformed files gives clear
//! errors without panics, and every fuzzing regression input is handled.

mod common;

use eprop_io::generate::{box_mesh, cylinder_mesh, BoxCells};
use eprop_io::testwrite;
use eprop_io::vtu::{to_bytes, Encoding, VtuOptions};
use eprop_io::{read_mesh, read_mesh_with, Mesh, ReadOptions};
use std::path::{Path, PathBuf};
use std::process::Command;

fn eprop(args: &[&str]) -> (bool, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_eprop")).args(args).output().unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

fn shared(sub: &str) -> Option<PathBuf> {
    common::shared_dir(sub)
}

#[test]
fn every_shared_tet_mesh_reads_and_validates() {
    let Some(dir) = shared("tet") else { return };
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap().flatten() {
        let p = e.path();
        let m = read_mesh(&p).unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
        assert!(m.n_cells() > 0 && m.n_nodes() > 0, "{}", p.display());
        let (ok, out, err) = eprop(&["info", p.to_str().unwrap(), "--json"]);
        assert!(ok, "{}: {err}", p.display());
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert_eq!(v["cells"].as_u64().unwrap() as usize, m.n_cells());
        assert!(v["warnings"].is_array());
        // the cell tags (an atlas's tissues) with their cells, which add up to the mesh's
        let tags = v["cell_tags"].as_array().unwrap();
        let cells: u64 = tags.iter().map(|t| t[1].as_u64().unwrap()).sum();
        assert_eq!(cells as usize, m.n_cells(), "{}", p.display());
        if p.to_string_lossy().contains("head_atlas") {
            assert!(tags.len() >= 4, "an atlas has its tissues: {tags:?}");
            let (_, text, _) = eprop(&["info", p.to_str().unwrap()]);
            assert!(text.contains("  cell tag         3: "), "{text}");
        }
        n += 1;
    }
    assert!(n >= 5, "expected the five shared tet meshes, found {n}");
}

fn meshes() -> Vec<(&'static str, Mesh)> {
    vec![
        ("tet", box_mesh([1.0, 2.0, 0.5], [3, 2, 2], BoxCells::Tet).unwrap()),
        ("hex", box_mesh([1.0, 2.0, 0.5], [3, 2, 2], BoxCells::Hex).unwrap()),
        ("wedge", box_mesh([1.0, 2.0, 0.5], [3, 2, 2], BoxCells::Wedge).unwrap()),
        (
            "pyramid",
            box_mesh([1.0, 2.0, 0.5], [3, 2, 2], BoxCells::PyramidTet).unwrap(),
        ),
        ("cyl", cylinder_mesh(1.0, 2.0, 2, 3).unwrap()),
    ]
}

/// Points, cells, tags and facets equal; node ids equal unless the format numbers 1..n itself.
fn same(a: &Mesh, b: &Mesh, what: &str, with_facets: bool, ids: bool) {
    assert_eq!(a.points, b.points, "{what}: points");
    if a.kinds == b.kinds || !(what.ends_with(".mesh") || what.ends_with("msh")) {
        assert_eq!(a.kinds, b.kinds, "{what}: kinds");
        assert_eq!(a.offsets, b.offsets, "{what}: offsets");
        assert_eq!(a.conn, b.conn, "{what}: connectivity");
        assert_eq!(a.cell_tags, b.cell_tags, "{what}: tags");
    } else {
        // Medit, and Gmsh 4.1 (one entity block per kind), group cells by kind: each kind's
        // cells in the order written
        let by_kind = |m: &Mesh| {
            let mut v: Vec<(String, Vec<u32>, i32)> = (0..m.n_cells())
                .map(|c| (format!("{:?}", m.kinds[c]), m.cell(c).to_vec(), m.cell_tags[c]))
                .collect();
            v.sort_by(|x, y| x.0.cmp(&y.0));
            v
        };
        assert_eq!(by_kind(a), by_kind(b), "{what}: cells of each kind");
    }
    if ids {
        assert_eq!(a.node_ids, b.node_ids, "{what}: node ids");
    }
    if with_facets {
        // Medit groups facets by type: compare them as sets
        let set = |m: &Mesh| {
            let mut v: Vec<(i32, Vec<u32>)> = (0..m.facets.len())
                .map(|f| (m.facets.tags[f], m.facets.nodes(f).to_vec()))
                .collect();
            v.sort();
            v
        };
        assert_eq!(set(a), set(b), "{what}: facets");
    }
}

#[test]
fn round_trips_through_every_format() {
    let d = tempfile::tempdir().unwrap();
    for (name, m) in meshes() {
        let tet = m.kinds.iter().all(|&k| k == eprop_io::CellKind::Tet);
        let mut files: Vec<(String, Vec<u8>)> = vec![
            (
                format!("{name}-42a.vtk"),
                testwrite::vtk_legacy(&m, testwrite::Legacy::V42, false),
            ),
            (
                format!("{name}-42b.vtk"),
                testwrite::vtk_legacy(&m, testwrite::Legacy::V42, true),
            ),
            (
                format!("{name}-51a.vtk"),
                testwrite::vtk_legacy(&m, testwrite::Legacy::V51, false),
            ),
            (
                format!("{name}-51b.vtk"),
                testwrite::vtk_legacy(&m, testwrite::Legacy::V51, true),
            ),
            (format!("{name}-22le.msh"), testwrite::gmsh22_binary(&m, false)),
            (format!("{name}-22be.msh"), testwrite::gmsh22_binary(&m, true)),
            (format!("{name}-41le.msh"), testwrite::gmsh41_binary(&m, false)),
            (format!("{name}-41be.msh"), testwrite::gmsh41_binary(&m, true)),
            (format!("{name}.mesh"), testwrite::medit(&m).into_bytes()),
        ];
        for (enc, en) in [
            (Encoding::Ascii, "ascii"),
            (Encoding::Base64, "b64"),
            (Encoding::AppendedRaw, "raw"),
            (Encoding::AppendedBase64, "ab64"),
        ] {
            for zlib in [false, true] {
                for (h64, be) in [(false, false), (true, false), (false, true)] {
                    let o = VtuOptions {
                        encoding: enc,
                        zlib,
                        header64: h64,
                        big_endian: be,
                    };
                    files.push((format!("{name}-{en}-{zlib}-{h64}-{be}.vtu"), to_bytes(&m, &o)));
                }
            }
        }
        for (f, bytes) in &files {
            let p = d.path().join(f);
            std::fs::write(&p, bytes).unwrap();
            let r = read_mesh_with(&p, &ReadOptions { strict: true }).unwrap_or_else(|e| panic!("{f}: {e:#}"));
            same(&m, &r, f, true, !f.ends_with(".mesh"));
        }
        if tet {
            let (node, ele, face) = testwrite::tetgen(&m);
            let base = d.path().join(format!("{name}.1"));
            std::fs::write(base.with_extension("1.node"), node).unwrap();
            std::fs::write(base.with_extension("1.ele"), ele).unwrap();
            std::fs::write(base.with_extension("1.face"), face).unwrap();
            for ext in ["ele", "node"] {
                let r = read_mesh(&base.with_extension(format!("1.{ext}"))).unwrap();
                same(&m, &r, "tetgen", false, true);
                let tris = (0..m.facets.len()).filter(|&f| m.facets.nodes(f).len() == 3).count();
                assert_eq!(r.facets.len(), tris);
            }
        }
        // the writers eprop ships
        for ext in ["msh", "vtu"] {
            let p = d.path().join(format!("{name}-out.{ext}"));
            eprop_io::write_mesh(&m, &p).unwrap();
            let r = read_mesh(&p).unwrap();
            same(&m, &r, ext, ext == "vtu", true);
        }
    }
}

#[test]
fn convert_cli_round_trips() {
    let d = tempfile::tempdir().unwrap();
    let m = box_mesh([1.0, 1.0, 1.0], [2, 2, 2], BoxCells::Wedge).unwrap();
    let a = d.path().join("a.vtk");
    std::fs::write(&a, testwrite::vtk_legacy(&m, testwrite::Legacy::V51, true)).unwrap();
    let b = d.path().join("b.vtu");
    let c = d.path().join("c.msh");
    let (ok, _, err) = eprop(&["convert", a.to_str().unwrap(), b.to_str().unwrap(), "--strict"]);
    assert!(ok, "{err}");
    let (ok, _, err) = eprop(&["convert", b.to_str().unwrap(), c.to_str().unwrap()]);
    assert!(ok, "{err}");
    let r = read_mesh(&c).unwrap();
    same(&m, &r, "convert", false, true);
}

fn tool(name: &str) -> bool {
    common::tool(name)
}

#[test]
fn tetgen_output_reads() {
    let Some(dir) = shared("surface") else { return };
    if !tool("tetgen") {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let off = d.path().join("liver.off");
    std::fs::copy(dir.join("sofa_liver_main_closed.off"), &off).unwrap();
    let st = Command::new("tetgen")
        .args(["-pq1.4kQ", "-a50"])
        .arg(&off)
        .status()
        .unwrap();
    assert!(st.success());
    let m = read_mesh(&d.path().join("liver.1.ele")).unwrap();
    assert!(m.n_cells() > 0);
    assert!(!m.facets.is_empty(), "liver.1.face gives boundary facets");
    assert!(m.warnings.iter().all(|w| !w.contains("inverted")), "{:?}", m.warnings);
    let v = read_mesh(&d.path().join("liver.1.vtk")).unwrap();
    assert_eq!((v.n_nodes(), v.n_cells()), (m.n_nodes(), m.n_cells()));
    assert_eq!(v.kinds, m.kinds);
}

/// A .geo that turns the closed liver surface into one tetrahedral volume.
const GEO: &str = "Merge \"liver.stl\";\nSurface Loop(1) = {1};\nVolume(1) = {1};\nPhysical Surface(2) = {1};\nPhysical Volume(1) = {1};\n";

#[test]
fn gmsh_output_reads_alike() {
    let Some(dir) = shared("surface") else { return };
    if !tool("gmsh") {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    std::fs::copy(dir.join("sofa_liver_main_closed.stl"), d.path().join("liver.stl")).unwrap();
    std::fs::write(d.path().join("liver.geo"), GEO).unwrap();
    // one volume mesh, then written in every format gmsh has that eprop reads
    let st = Command::new("gmsh")
        .current_dir(d.path())
        .args(["-3", "liver.geo", "-format", "msh41", "-o", "ref.msh", "-v", "1"])
        .status()
        .unwrap();
    assert!(st.success());
    let reference = read_mesh(&d.path().join("ref.msh")).unwrap();
    assert!(reference.n_cells() > 0 && !reference.facets.is_empty());
    let outputs: [(&str, &[&str]); 7] = [
        ("a22.msh", &["-format", "msh22"]),
        ("b22.msh", &["-format", "msh22", "-bin"]),
        ("a41.msh", &["-format", "msh41"]),
        ("b41.msh", &["-format", "msh41", "-bin"]),
        ("a.vtk", &["-format", "vtk"]),
        ("b.vtk", &["-format", "vtk", "-bin"]),
        ("a.mesh", &["-format", "mesh"]),
    ];
    for (out, args) in outputs {
        let st = Command::new("gmsh")
            .current_dir(d.path())
            .args(["ref.msh", "-0", "-o", out, "-v", "1"])
            .args(args)
            .status()
            .unwrap();
        assert!(st.success(), "{out}");
        let m = read_mesh(&d.path().join(out)).unwrap_or_else(|e| panic!("{out}: {e:#}"));
        assert_eq!(
            (m.n_nodes(), m.n_cells()),
            (reference.n_nodes(), reference.n_cells()),
            "{out}"
        );
        assert!(
            m.warnings.iter().all(|w| !w.contains("inverted")),
            "{out}: {:?}",
            m.warnings
        );
        let (ok, _, err) = eprop(&["info", d.path().join(out).to_str().unwrap()]);
        assert!(ok, "{out}: {err}");
    }
}

const GMSH: &str = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n6\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0 0 -1\n6 0.2 0.2 0.5\n$EndNodes\n$Elements\n3\n1 4 2 7 1 1 2 3 4\n2 4 2 7 1 1 3 2 5\n3 2 2 3 3 1 2 4\n$EndElements\n";
const VTK: &str = "# vtk DataFile Version 4.2\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 5 double\n0 0 0 1 0 0 0 1 0 0 0 1 0 0 -1\nCELLS 2 10\n4 0 1 2 3\n4 0 2 1 4\nCELL_TYPES 2\n10 10\n";
const VTK51: &str = "# vtk DataFile Version 5.1\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 5 double\n0 0 0 1 0 0 0 1 0 0 0 1 0 0 -1\nCELLS 3 8\nOFFSETS vtktypeint64\n0 4 8\nCONNECTIVITY vtktypeint64\n0 1 2 3 0 2 1 4\nCELL_TYPES 2\n10 10\n";
const NODE: &str = "# liver\n6 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0 0 -1\n6 0.2 0.2 0.5\n";
const ELE: &str = "2 4 1\n1 1 2 3 4 7\n2 1 3 2 5 7\n";
const MEDIT: &str = "MeshVersionFormatted 2\nDimension 3\nVertices\n6\n0 0 0 0\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 -1 0\n0.2 0.2 0.5 0\nTetrahedra\n2\n1 2 3 4 7\n1 3 2 5 7\nEnd\n";

/// (file name, contents, key phrase of the error, strict)
fn catalogue() -> Vec<(String, Vec<u8>, &'static str, bool)> {
    let mut v: Vec<(String, Vec<u8>, &'static str, bool)> = Vec::new();
    let mut t = |name: &str, text: String, key: &'static str, strict: bool| {
        v.push((name.to_string(), text.into_bytes(), key, strict))
    };
    let el = "$EndElements";
    t(
        "gmsh_truncated.msh",
        GMSH[..GMSH.find("3 2 2 3").unwrap()].to_string(),
        "file ends",
        false,
    );
    t(
        "gmsh_cut_line.msh",
        GMSH[..GMSH.find(el).unwrap() - 12].to_string(),
        "line is cut",
        false,
    );
    t(
        "gmsh_node_count.msh",
        GMSH.replace("$Nodes\n6", "$Nodes\n7"),
        "node count disagrees",
        false,
    );
    t(
        "gmsh_element_count.msh",
        GMSH.replace("$Elements\n3", "$Elements\n4"),
        "disagrees",
        false,
    );
    t(
        "gmsh_nan.msh",
        GMSH.replace("4 0 0 1\n", "4 0 nan 1\n"),
        "non-finite",
        false,
    );
    t(
        "gmsh_out_of_range.msh",
        GMSH.replace("1 1 2 3 4\n", "1 1 2 3 9\n"),
        "node 9",
        false,
    );
    t(
        "gmsh_duplicate.msh",
        GMSH.replace("1 1 3 2 5\n", "1 2 1 3 4\n"),
        "duplicates",
        false,
    );
    t(
        "gmsh_zero_volume.msh",
        GMSH.replace("5 0 0 -1\n", "5 0.3 0.3 0\n"),
        "zero volume",
        false,
    );
    t(
        "gmsh_inverted_strict.msh",
        GMSH.replace("1 1 3 2 5\n", "1 1 2 3 5\n"),
        "inverted",
        true,
    );
    t(
        "gmsh_nonmanifold.msh",
        GMSH.replace("$Elements\n3", "$Elements\n4")
            .replace("3 2 2 3 3 1 2 4\n", "3 2 2 3 3 1 2 4\n4 4 2 7 1 1 2 3 6\n"),
        "non-manifold",
        false,
    );
    t(
        "gmsh_quadratic.msh",
        GMSH.replace("1 4 2 7 1 1 2 3 4\n", "1 11 2 7 1 1 2 3 4 1 2 3 4 5 6\n"),
        "higher-order",
        false,
    );
    t(
        "gmsh_bad_version.msh",
        GMSH.replace("2.2 0 8", "9.9 0 8"),
        "not supported",
        false,
    );
    t(
        "gmsh_no_volume.msh",
        GMSH.replace("$Elements\n3", "$Elements\n1")
            .replace("1 4 2 7 1 1 2 3 4\n2 4 2 7 1 1 3 2 5\n", ""),
        "no volume cells",
        false,
    );
    t(
        "gmsh_no_elements.msh",
        GMSH[..GMSH.find("$Elements").unwrap()].to_string(),
        "without an $Elements section",
        false,
    );
    t(
        "gmsh1_no_elements.msh",
        "$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n".into(),
        "truncated",
        false,
    );
    t(
        "vtk_truncated.vtk",
        VTK[..VTK.find("4 0 2 1").unwrap()].to_string(),
        "file ends",
        false,
    );
    t(
        "vtk_wrong_cells_count.vtk",
        VTK.replace("CELLS 2 10", "CELLS 3 10"),
        "counts disagree",
        false,
    );
    t(
        "vtk_nan.vtk",
        VTK.replace("0 0 1 0 0 -1", "0 0 nan 0 0 -1"),
        "non-finite",
        false,
    );
    t(
        "vtk_out_of_range.vtk",
        VTK.replace("4 0 2 1 4", "4 0 2 1 7"),
        "names node 7",
        false,
    );
    t(
        "vtk_quadratic.vtk",
        VTK.replace("10 10", "24 10"),
        "quadratic tetrahedron",
        false,
    );
    t(
        "vtk_polydata.vtk",
        VTK.replace("UNSTRUCTURED_GRID", "POLYDATA"),
        "not a volume mesh",
        false,
    );
    t(
        "vtk_bad_type.vtk",
        VTK.replace("POINTS 5 double", "POINTS 5 quad"),
        "unknown data type",
        false,
    );
    t(
        "vtk51_bad_offsets.vtk",
        VTK51.replace("0 4 8", "0 4 12"),
        "outside the connectivity",
        false,
    );
    t(
        "vtk_inverted_strict.vtk",
        VTK.replace("4 0 2 1 4", "4 0 1 2 4"),
        "inverted",
        true,
    );
    t(
        "vtk_missing_types.vtk",
        VTK[..VTK.find("CELL_TYPES").unwrap()].to_string(),
        "no CELL_TYPES",
        false,
    );
    t(
        "tetgen_out_of_range.ele",
        ELE.replace("2 1 3 2 5", "2 1 3 2 9"),
        "does not define",
        false,
    );
    t(
        "tetgen_quadratic.ele",
        "1 10 0\n1 1 2 3 4 1 2 3 4 5 6\n".into(),
        "first-order",
        false,
    );
    t(
        "tetgen_truncated.ele",
        ELE.replace("2 4 1", "3 4 1"),
        "file ends",
        false,
    );
    t(
        "tetgen_nonmanifold.ele",
        "3 4 1\n1 1 2 3 4 7\n2 1 3 2 5 7\n3 1 2 3 6 7\n".into(),
        "non-manifold",
        false,
    );
    t(
        "tetgen_extra_lines.ele",
        ELE.replace("2 4 1", "1 4 1"),
        "more lines",
        false,
    );
    t(
        "medit_out_of_range.mesh",
        MEDIT.replace("1 3 2 5 7", "1 3 2 9 7"),
        "names vertex 9",
        false,
    );
    t(
        "medit_truncated.mesh",
        MEDIT[..MEDIT.find("1 3 2 5").unwrap()].to_string(),
        "file ends",
        false,
    );
    t(
        "medit_zero_volume.mesh",
        MEDIT.replace("0 0 -1 0\n", "0.3 0.3 0 0\n"),
        "zero volume",
        false,
    );
    t(
        "medit_duplicate.mesh",
        MEDIT.replace("1 3 2 5 7", "4 3 2 1 7"),
        "duplicates",
        false,
    );
    t(
        "medit_p2.mesh",
        MEDIT.replace("Tetrahedra\n", "TetrahedraP2\n"),
        "higher-order",
        false,
    );
    t(
        "medit_inverted_strict.mesh",
        MEDIT.replace("1 3 2 5 7", "1 2 3 5 7"),
        "inverted",
        true,
    );
    t(
        "medit_2d.mesh",
        MEDIT.replace("Dimension 3", "Dimension 2"),
        "3D",
        false,
    );
    t(
        "medit_repeated_node.mesh",
        MEDIT.replace("1 3 2 5 7", "1 3 3 5 7"),
        "repeats a node",
        false,
    );
    // binary and XML variants made from generated meshes
    let m = box_mesh([1.0, 1.0, 1.0], [1, 1, 1], BoxCells::Tet).unwrap();
    let b41 = testwrite::gmsh41_binary(&m, false);
    v.push((
        "gmsh41_bin_truncated.msh".into(),
        b41[..b41.len() * 2 / 3].to_vec(),
        "truncated",
        false,
    ));
    let cut = b41.windows(9).position(|w| w == b"$Elements").unwrap();
    v.push((
        "gmsh41_bin_no_elements.msh".into(),
        b41[..cut].to_vec(),
        "without an $Elements section",
        false,
    ));
    let mut bad = testwrite::gmsh22_binary(&m, false);
    bad[20] = 2;
    v.push(("gmsh22_bin_bad_marker.msh".into(), bad, "endianness", false));
    let b41s = String::from_utf8_lossy(&b41[..30]).to_string();
    assert!(b41s.contains("4.1 1 8"));
    let mut ds = b41.clone();
    ds[18] = b'6';
    v.push(("gmsh41_bin_data_size.msh".into(), ds, "data-size", false));
    let vb = testwrite::vtk_legacy(&m, testwrite::Legacy::V42, true);
    v.push((
        "vtk_binary_truncated.vtk".into(),
        vb[..vb.len() / 2].to_vec(),
        "file ends",
        false,
    ));
    let b64 = String::from_utf8(to_bytes(&m, &VtuOptions::default())).unwrap();
    let p = b64.find("format=\"binary\">\n").unwrap() + 30;
    v.push((
        "vtu_bad_base64.vtu".into(),
        format!("{}!{}", &b64[..p], &b64[p + 1..]).into_bytes(),
        "not a base64 character",
        false,
    ));
    let z = to_bytes(
        &m,
        &VtuOptions {
            encoding: Encoding::AppendedRaw,
            zlib: true,
            header64: false,
            big_endian: false,
        },
    );
    let a = z.windows(2).position(|w| w == b"\n_").unwrap() + 2 + 4 * 4 + 4;
    let mut zb = z.clone();
    for k in a..a + 8 {
        zb[k] ^= 0x55;
    }
    v.push(("vtu_bad_zlib.vtu".into(), zb, "zlib", false));
    let raw = to_bytes(
        &m,
        &VtuOptions {
            encoding: Encoding::AppendedRaw,
            zlib: false,
            header64: true,
            big_endian: false,
        },
    );
    v.push((
        "vtu_truncated.vtu".into(),
        raw[..raw.len() - 200].to_vec(),
        "ends",
        false,
    ));
    let nc = format!("NumberOfCells=\"{}\"", m.n_cells() + m.facets.len());
    v.push((
        "vtu_wrong_count.vtu".into(),
        b64.replace(&nc, "NumberOfCells=\"3\"").into_bytes(),
        "counts disagree",
        false,
    ));
    v.push((
        "vtu_bad_header_type.vtu".into(),
        b64.replace("UInt64\"", "UInt16\"").into_bytes(),
        "header_type",
        false,
    ));
    v.push((
        "vtu_lz4.vtu".into(),
        b64.replace("LittleEndian\"", "LittleEndian\" compressor=\"vtkLZ4DataCompressor\"")
            .into_bytes(),
        "not supported",
        false,
    ));
    v.push((
        "vtu_not_xml.vtu".into(),
        b"hello, world\n".to_vec(),
        "no <VTKFile>",
        false,
    ));
    v.push((
        "vtu_unclosed.vtu".into(),
        b64.as_bytes()[..b64.find("<Cells>").unwrap() + 3].to_vec(),
        "not closed",
        false,
    ));
    v
}

#[test]
fn malformed_files_give_clear_errors() {
    let d = tempfile::tempdir().unwrap();
    let cat = catalogue();
    assert!(cat.len() >= 30);
    let mut bad = Vec::new();
    for (name, bytes, key, strict) in &cat {
        let p = d.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        if name.starts_with("tetgen") {
            std::fs::write(p.with_extension("node"), NODE).unwrap();
        }
        let stem = name.split('.').next().unwrap();
        let e = match read_mesh_with(&p, &ReadOptions { strict: *strict }) {
            Ok(_) => {
                bad.push(format!("{name}: read without error"));
                continue;
            }
            Err(e) => format!("{e:#}"),
        };
        if !(e.contains(stem) && e.contains("fix:") && e.contains(key)) {
            bad.push(format!("{name}: expected the file name, `fix:` and `{key}` in: {e}"));
            continue;
        }
        if *strict {
            assert!(read_mesh(&p).is_ok(), "{name}: reads without --strict");
        }
        let mut args = vec!["info", p.to_str().unwrap()];
        if *strict {
            args.push("--strict");
        }
        let (ok, _, err) = eprop(&args);
        assert!(!ok, "{name}: eprop info succeeded");
        assert!(!err.contains("panicked"), "{name}: {err}");
        assert!(err.contains("fix:"), "{name}: {err}");
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

#[test]
fn repairs_are_reported() {
    let d = tempfile::tempdir().unwrap();
    // inverted cell reoriented, unused node dropped, two components
    let text = GMSH
        .replace("1 1 3 2 5\n", "1 1 2 3 5\n")
        .replace("$Nodes\n6", "$Nodes\n11")
        .replace(
            "6 0.2 0.2 0.5\n",
            "6 0.2 0.2 0.5\n7 5 5 5\n8 6 5 5\n9 5 6 5\n10 5 5 6\n11 9 9 9\n",
        )
        .replace("$Elements\n3", "$Elements\n4")
        .replace("3 2 2 3 3 1 2 4\n", "3 2 2 3 3 1 2 4\n4 4 2 7 1 7 8 9 10\n");
    let p = d.path().join("repairs.msh");
    std::fs::write(&p, text).unwrap();
    let m = read_mesh(&p).unwrap();
    let w = m.warnings.join("\n");
    assert!(w.contains("1 inverted cell(s) reoriented"), "{w}");
    assert!(w.contains("dropped"), "{w}");
    assert!(w.contains("2 disconnected components"), "{w}");
    assert!(!m.node_ids.contains(&6) && !m.node_ids.contains(&11) && m.node_ids.contains(&10));
    let (ok, out, err) = eprop(&["info", p.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(v["warnings"].to_string().contains("reoriented"));
    let (ok, _, err) = eprop(&["info", p.to_str().unwrap(), "--strict"]);
    assert!(!ok && err.contains("inverted"), "{err}");
}

/// The reader a fuzzing input is for, by the prefix of its file name.
fn fuzz_format(name: &str) -> Option<eprop_io::Format> {
    Some(match name.split('-').next().unwrap_or("") {
        "gmsh" => eprop_io::Format::Gmsh,
        "vtk" => eprop_io::Format::VtkLegacy,
        "vtu" => eprop_io::Format::Vtu,
        "tetgen" => eprop_io::Format::TetGen,
        "medit" => eprop_io::Format::Medit,
        _ => return None,
    })
}

/// The fuzzing inputs of a folder of tests/data: (name, format, bytes), by name.
fn fuzz_inputs(sub: &str) -> Vec<(String, eprop_io::Format, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(sub);
    let mut v: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().to_string();
            let f = fuzz_format(&name)?;
            Some((name, f, std::fs::read(e.path()).unwrap()))
        })
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

#[test]
fn fuzz_regressions_do_not_panic() {
    // the seeds the fuzzer starts from (every reader, every encoding) and what it found
    let seeds = fuzz_inputs("fuzz-seeds");
    let found = fuzz_inputs("fuzz-regressions");
    for r in ["gmsh", "vtk", "vtu", "tetgen", "medit"] {
        assert!(
            seeds.iter().any(|s| s.0.starts_with(&format!("{r}-"))),
            "no {r} seeds in tests/data/fuzz-seeds"
        );
    }
    let mut n = 0;
    for (name, format, bytes) in seeds.iter().chain(&found) {
        let t = std::time::Instant::now();
        let r = std::panic::catch_unwind(|| {
            eprop_io::parse_mesh(*format, name, bytes)
                .and_then(|mut m| eprop_io::validate(&mut m, &ReadOptions::default()))
        });
        assert!(r.is_ok(), "{name} panics");
        // a hang detector, generous for a loaded machine (each input takes milliseconds)
        assert!(t.elapsed().as_secs_f64() < 60.0, "{name} hangs");
        n += 1;
    }
    assert!(n >= seeds.len() && !seeds.is_empty(), "no fuzzing inputs found");
    println!(
        "{n} fuzzing inputs replayed ({} seeds, {} regressions)",
        seeds.len(),
        found.len()
    );
}

#[test]
fn fuzz_seeds_are_the_fuzzers_and_read() {
    // the committed seeds are what the fuzzer starts from, and each is a valid mesh
    let seeds = fuzz_inputs("fuzz-seeds");
    let mut want = Vec::new();
    for (r, f) in [
        ("gmsh", eprop_io::Format::Gmsh),
        ("vtk", eprop_io::Format::VtkLegacy),
        ("vtu", eprop_io::Format::Vtu),
        ("tetgen", eprop_io::Format::TetGen),
        ("medit", eprop_io::Format::Medit),
    ] {
        want.extend(testwrite::seeds(f).into_iter().map(|(n, b)| (format!("{r}-{n}"), b)));
    }
    want.sort();
    let have: Vec<(String, Vec<u8>)> = seeds.iter().map(|s| (s.0.clone(), s.2.clone())).collect();
    assert!(
        have == want,
        "tests/data/fuzz-seeds differs from testwrite::seeds; fix: cargo run --release -p eprop-io --example fuzz -- --write-seeds tests/data/fuzz-seeds"
    );
    for (name, format, bytes) in &seeds {
        let mut m = eprop_io::parse_mesh(*format, name, bytes).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        eprop_io::validate(&mut m, &ReadOptions { strict: true }).unwrap_or_else(|e| panic!("{name}: {e:#}"));
    }
}

#[test]
fn gmsh_hexahedra_read_alike_in_msh_mesh_and_vtk() {
    if !tool("gmsh") {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let geo = "Point(1)={0,0,0}; Point(2)={1,0,0}; Point(3)={1,1,0}; Point(4)={0,1,0};\n\
Line(1)={1,2}; Line(2)={2,3}; Line(3)={3,4}; Line(4)={4,1};\n\
Curve Loop(1)={1,2,3,4}; Plane Surface(1)={1};\n\
Transfinite Curve{1,2,3,4}=3; Transfinite Surface{1}; Recombine Surface{1};\n\
Extrude{0,0,1}{Surface{1}; Layers{2}; Recombine;}\nPhysical Volume(5) = {1};\n";
    std::fs::write(d.path().join("hex.geo"), geo).unwrap();
    let mut meshes = Vec::new();
    for (fmt, out) in [("msh41", "hex.msh"), ("mesh", "hex.mesh"), ("vtk", "hex.vtk")] {
        let st = Command::new("gmsh")
            .current_dir(d.path())
            .args(["-3", "hex.geo", "-format", fmt, "-o", out, "-v", "1"])
            .status()
            .unwrap();
        assert!(st.success());
        let m = read_mesh(&d.path().join(out)).unwrap();
        assert!(
            m.warnings.iter().all(|w| !w.contains("inverted")),
            "{out}: {:?}",
            m.warnings
        );
        assert_eq!(m.kind_counts().get(&eprop_io::CellKind::Hex), Some(&8), "{out}");
        meshes.push(m);
    }
    // Medit and VTK keep Gmsh's local hexahedron order
    assert_eq!(meshes[0].conn, meshes[1].conn);
    assert_eq!(meshes[0].conn, meshes[2].conn);
}

/// Reads a mesh on another thread and returns its error: a reader that blocks (on a FIFO)
/// fails the test instead of hanging it.
fn read_error_within(p: &Path, secs: u64) -> String {
    let (tx, rx) = std::sync::mpsc::channel();
    let q = p.to_path_buf();
    std::thread::spawn(move || {
        let _ = tx.send(read_mesh(&q).map(|_| ()).map_err(|e| format!("{e:#}")));
    });
    match rx.recv_timeout(std::time::Duration::from_secs(secs)) {
        Ok(r) => r.expect_err("read without error"),
        Err(_) => panic!("reading {} did not return within {secs} s", p.display()),
    }
}

#[cfg(unix)]
#[test]
fn only_regular_files_are_read() {
    use std::os::unix::fs::symlink;
    let d = tempfile::tempdir().unwrap();
    let good = d.path().join("good.msh");
    std::fs::write(&good, GMSH).unwrap();
    // a FIFO would block the reader forever
    let fifo = d.path().join("pipe.msh");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let e = read_error_within(&fifo, 10);
    assert!(
        e.contains("pipe.msh") && e.contains("FIFO") && e.contains("not a regular file") && e.contains("fix:"),
        "{e}"
    );
    // /dev/zero never ends
    let zero = d.path().join("zero.msh");
    symlink("/dev/zero", &zero).unwrap();
    let e = read_error_within(&zero, 10);
    assert!(
        e.contains("zero.msh") && e.contains("character device") && e.contains("fix:"),
        "{e}"
    );
    // a link loop is not a missing file
    let (a, b) = (d.path().join("a.vtu"), d.path().join("b.vtu"));
    symlink(&b, &a).unwrap();
    symlink(&a, &b).unwrap();
    let e = read_error_within(&a, 10);
    assert!(
        e.contains("a.vtu") && e.contains("symbolic link loop") && e.contains("fix:"),
        "{e}"
    );
    assert!(!e.contains("no such"), "{e}");
    // a directory
    let dir = d.path().join("dir.vtk");
    std::fs::create_dir(&dir).unwrap();
    let e = read_error_within(&dir, 10);
    assert!(e.contains("is a directory") && e.contains("fix:"), "{e}");
    // a TetGen part that is a FIFO
    std::fs::write(d.path().join("t.ele"), ELE).unwrap();
    assert!(Command::new("mkfifo")
        .arg(d.path().join("t.node"))
        .status()
        .unwrap()
        .success());
    let e = read_error_within(&d.path().join("t.ele"), 10);
    assert!(e.contains("t.node") && e.contains("FIFO") && e.contains("fix:"), "{e}");
    // a link to a mesh is read
    let link = d.path().join("link.msh");
    symlink(&good, &link).unwrap();
    assert_eq!(read_mesh(&link).unwrap().n_cells(), 2);
    // and the program says it too
    for p in [&fifo, &zero, &a] {
        let (ok, _, err) = eprop(&["info", p.to_str().unwrap()]);
        assert!(!ok && err.contains("fix:") && !err.contains("panicked"), "{err}");
    }
}

/// A `.vtu` of one tetrahedron whose `which` array (0 points, 1 connectivity, another value
/// none) is a zlib bomb: `blocks` blocks that each inflate to `mib` MiB of zeros (1/1000 of that
/// compressed), of which `present` are in the file. `np` is its NumberOfPoints.
fn zlib_bomb(which: usize, np: u64, mib: u64, blocks: u64, present: u64) -> Vec<u8> {
    use std::io::Write as _;
    let z = |data: &[u8]| {
        let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        e.write_all(data).unwrap();
        e.finish().unwrap()
    };
    let one = |data: &[u8]| {
        let c = z(data);
        let mut a: Vec<u8> = [1u64, data.len() as u64, data.len() as u64, c.len() as u64]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        a.extend(c);
        a
    };
    let bs = mib << 20;
    let blk = z(&vec![0u8; bs as usize]);
    let mut bomb: Vec<u8> = [blocks, bs, 0].iter().flat_map(|x| x.to_le_bytes()).collect();
    for _ in 0..blocks {
        bomb.extend((blk.len() as u64).to_le_bytes());
    }
    for _ in 0..present {
        bomb.extend(&blk);
    }
    let pts: Vec<u8> = [0.0f64, 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1.]
        .iter()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    let conn: Vec<u8> = [0i64, 1, 2, 3].iter().flat_map(|x| x.to_le_bytes()).collect();
    let mut arrays = vec![one(&pts), one(&conn), one(&4i64.to_le_bytes()), one(&[10u8])];
    if let Some(a) = arrays.get_mut(which) {
        *a = bomb;
    }
    let mut offsets = Vec::new();
    let mut app: Vec<u8> = Vec::new();
    for a in &arrays {
        offsets.push(app.len());
        app.extend(a);
    }
    let mut f = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\" compressor=\"vtkZLibDataCompressor\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"{}\" NumberOfCells=\"1\">\n<Points>\n<DataArray type=\"Float64\" Name=\"Points\" NumberOfComponents=\"3\" format=\"appended\" offset=\"{}\"/>\n</Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"appended\" offset=\"{}\"/>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"appended\" offset=\"{}\"/>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"appended\" offset=\"{}\"/>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n<AppendedData encoding=\"raw\">\n_",
        np, offsets[0], offsets[1], offsets[2], offsets[3]
    )
    .into_bytes();
    f.extend(app);
    f.extend(b"\n</AppendedData>\n</VTKFile>\n");
    f
}

/// The peak resident memory of this process so far (Linux), in KiB.
fn peak_rss_kib() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let l = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    l.split_whitespace().nth(1)?.parse().ok()
}

#[test]
fn zlib_bombs_are_refused_before_inflating() {
    let d = tempfile::tempdir().unwrap();
    // the sanity of the generator: with its real arrays the file reads
    let p = d.path().join("one.vtu");
    std::fs::write(&p, zlib_bomb(9, 4, 0, 0, 0)).unwrap();
    assert_eq!(read_mesh(&p).unwrap().n_cells(), 1);
    // 160 blocks of 16 MiB (2.7 GB) from 2.6 MB, where 12 coordinates or 4 indices are needed;
    // and the 5 GB of coordinates 100 * 2^21 points need, from 100 blocks of which 1 is there
    for (which, np, mib, blocks, present, key) in [
        (0, 4, 16, 160, 160, "but its 12 values take 96"),
        (1, 4, 16, 160, 160, "more than the 4 values the cell offsets use"),
        (0, 100 << 21, 48, 100, 1, "ends while reading"),
    ] {
        let p = d.path().join(format!("bomb{which}-{present}.vtu"));
        std::fs::write(&p, zlib_bomb(which, np, mib, blocks, present)).unwrap();
        let before = peak_rss_kib();
        let t = std::time::Instant::now();
        let e = format!("{:#}", read_mesh(&p).unwrap_err());
        let took = t.elapsed().as_secs_f64();
        assert!(
            e.contains(&format!("bomb{which}-{present}.vtu")) && e.contains(key) && e.contains("fix:"),
            "{e}"
        );
        // a hang detector (inflating the bomb would take minutes); generous for a loaded machine
        assert!(took < 60.0, "{e}: {took:.1} s");
        if let (Some(a), Some(b)) = (before, peak_rss_kib()) {
            assert!(b < a + (256 << 10), "{e}: peak memory grew from {a} to {b} KiB");
        }
    }
}

/// `eprop mesh box -o FILE.vtkhdf` writes the mesh a job reads in slabs: the same points,
/// cells, tags and node ids as the box written as .msh (whose faces it leaves out, and says so).
#[test]
fn a_generated_box_writes_vtkhdf_directly() {
    let d = tempfile::tempdir().unwrap();
    let (msh, vtkhdf) = (d.path().join("b.msh"), d.path().join("b.vtkhdf"));
    let box_to = |out: &Path| {
        eprop(&[
            "mesh",
            "box",
            "--size",
            "1,2,0.5",
            "--cells",
            "3,4,2",
            "-o",
            out.to_str().unwrap(),
        ])
    };
    let (ok, _, err) = box_to(&msh);
    assert!(ok, "{err}");
    let (ok, out, err) = box_to(&vtkhdf);
    assert!(ok, "{err}");
    assert!(out.contains("60 nodes, 144 cells"), "{out}");
    assert!(err.contains("boundary facets and group names are left out"), "{err}");
    let a = read_mesh(&msh).unwrap();
    let b = eprop::config::mesh::read_vtkhdf(&vtkhdf, &ReadOptions::default()).unwrap();
    same(&a, &b, "vtkhdf", false, true);
}
