//! Mesh formats: every shared test mesh reads, round trips through every format, meshes made
//! by tetgen and gmsh (when installed) read alike, a catalogue of malformed files gives clear
//! errors without panics, and every fuzzing regression input is handled.

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
    let d = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes").join(sub);
    if d.is_dir() {
        Some(d)
    } else {
        println!("skipped: {} is absent", d.display());
        None
    }
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
        n += 1;
    }
    assert!(n >= 5, "expected the five shared tet meshes, found {n}");
}

fn meshes() -> Vec<(&'static str, Mesh)> {
    vec![
        ("tet", box_mesh([1.0, 2.0, 0.5], [3, 2, 2], BoxCells::Tet).unwrap()),
        ("hex", box_mesh([1.0, 2.0, 0.5], [3, 2, 2], BoxCells::Hex).unwrap()),
        ("wedge", box_mesh([1.0, 2.0, 0.5], [3, 2, 2], BoxCells::Wedge).unwrap()),
        ("cyl", cylinder_mesh(1.0, 2.0, 2, 3).unwrap()),
    ]
}

/// Points, cells, tags and facets equal; node ids equal unless the format numbers 1..n itself.
fn same(a: &Mesh, b: &Mesh, what: &str, with_facets: bool, ids: bool) {
    assert_eq!(a.points, b.points, "{what}: points");
    assert_eq!(a.kinds, b.kinds, "{what}: kinds");
    assert_eq!(a.offsets, b.offsets, "{what}: offsets");
    assert_eq!(a.conn, b.conn, "{what}: connectivity");
    assert_eq!(a.cell_tags, b.cell_tags, "{what}: tags");
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
    let ok = Command::new(name).arg("-h").output().is_ok();
    if !ok {
        println!("skipped: `{name}` is not installed (scripts/setup.sh installs it)");
    }
    ok
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
