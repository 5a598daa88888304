//! A run under mpirun from a VTKHDF mesh starts from slabs (each process reads its share, the
//! graph is split by PT-Scotch or METIS, every process resolves the scenario on its own part):
//! its series must be bitwise the series of the same mesh in .msh, on 1, 2 and 3 processes.
//! What this start does not resolve yet is refused by name.

mod common;

use common::{counted_bits, mpirun, open_pair, serial, steps_complete};
use std::path::Path;

/// Every dataset of two series the same bits (`common::assert_same`) but the scenario's text,
/// which names another mesh file.
fn assert_same(a: &Path, b: &Path) {
    let (fa, fb, names) = open_pair(a, b);
    let k = steps_complete(a);
    assert_eq!(k, steps_complete(b));
    let n = fa.dataset("VTKHDF/NumberOfPoints").unwrap().read_raw::<i64>().unwrap()[0] as usize;
    let mut compared = 0;
    for name in names.iter().filter(|n| *n != "/eprop/scenario") {
        let (x, y) = (
            counted_bits(&fa, name, k as usize, n),
            counted_bits(&fb, name, k as usize, n),
        );
        assert!(x == y, "{name} differs between {} and {}", a.display(), b.display());
        compared += 1;
    }
    assert!(compared >= 20, "{names:?}");
    // the mesh's hash (a restart checks it) is the whole mesh's, from the slabs too
    let hash = |f: &hdf5::File| {
        f.group("eprop")
            .unwrap()
            .attr("mesh_hash")
            .unwrap()
            .read_scalar::<u64>()
            .unwrap()
    };
    assert_eq!(hash(&fa), hash(&fb));
}

/// The box mesh as .msh and converted to .vtkhdf in `dir`.
fn meshes(dir: &Path) -> (String, String) {
    let msh = dir.join("box.msh");
    let mesh = eprop_io::generate::box_mesh([1.0; 3], [8, 7, 6], eprop_io::generate::BoxCells::Tet).unwrap();
    eprop_io::write_mesh(&mesh, &msh).unwrap();
    let vtkhdf = dir.join("box.vtkhdf");
    let out = serial(&["convert", msh.to_str().unwrap(), vtkhdf.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    (msh.display().to_string(), vtkhdf.display().to_string())
}

/// Runs `body` (the scenario without its [mesh]) from the .msh on one process and from the
/// .vtkhdf on 1, 2 and 3: every series the same bits.
fn same_from_both(tag: &str, body: &str) {
    let d = tempfile::Builder::new().prefix(tag).tempdir().unwrap();
    let (msh, vtkhdf) = meshes(d.path());
    let scenario = |name: &str, mesh: &str| {
        let sc = d.path().join(name);
        std::fs::write(&sc, format!("[mesh]\nfile = \"{mesh}\"\n{body}")).unwrap();
        sc.display().to_string()
    };
    let (a, b) = (scenario("msh.toml", &msh), scenario("vtkhdf.toml", &vtkhdf));
    let reference = d.path().join("msh.h5");
    let out = serial(&["run", &a, "-q", "-o", reference.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for n in 1..=3 {
        let f = d.path().join(format!("vtkhdf{n}.h5"));
        let out = match n {
            1 => serial(&["run", &b, "-q", "-o", f.to_str().unwrap()], 1),
            _ => mpirun(n, &["run", &b, "-q", "-o", f.to_str().unwrap()]),
        };
        assert!(
            out.status.success(),
            "{n} processes: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("on {n} process")));
        assert_same(&reference, &f);
    }
}

#[test]
fn loads_and_supports_from_slabs_are_the_bits_of_the_msh() {
    same_from_both(
        "slab-loads",
        "[material]\nmass = 1.0\ndamping = 2.0\nconductivity = 0.05\n\
         [[fixed]]\nhalfspace = { point = [0, 0, 0.01], normal = [0, 0, -1] }\n\
         [[fixed]]\nbox = [[0.99, -1, -1], [2, 2, 2]]\n\
         [[load]]\nnearest = [0.5, 0.5, 1.0]\nnormal = 0.05\nramp = [[0, 0], [1, 1]]\n\
         [[load]]\npatch = { center = [0.5, 0.0, 0.5], radius = 0.3 }\nforce = [0, 0.02, 0.01]\n\
         [[load]]\nnode = 77\nforce = [0.01, 0, 0]\n\
         [model]\nreading = \"paper\"\n[time]\nsteps = 6\n[output]\nevery = 2\n",
    );
}

#[test]
fn a_tool_from_slabs_is_the_bits_of_the_msh() {
    same_from_both(
        "slab-tool",
        "[[fixed]]\nhalfspace = { point = [0, 0, 0.01], normal = [0, 0, -1] }\n\
         [[tool]]\nshape = \"sphere\"\nradius = 0.3\nstart = [0.5, 0.5, 1.31]\nvelocity = [0, 0, -0.02]\n\
         [model]\nreading = \"paper\"\n[time]\nsteps = 5\n",
    );
}

#[test]
fn what_slabs_do_not_resolve_yet_is_refused_by_key() {
    let d = tempfile::tempdir().unwrap();
    let (_, vtkhdf) = meshes(d.path());
    for (body, key, alone) in [
        ("[[fixed]]\ntag = 1\n", "[fixed] tag", false),
        (
            "[[fixed]]\nhalfspace = { point = [0, 0, 0.01], normal = [0, 0, -1] }\n[[material.region]]\nbox = [[0, 0, 0], [1, 1, 0.5]]\nmass = 2.0\n",
            "[material.region] box",
            true,
        ),
    ] {
        let sc = d.path().join("s.toml");
        std::fs::write(
            &sc,
            format!("[mesh]\nfile = \"{vtkhdf}\"\n{body}[model]\nreading = \"paper\"\n[time]\nsteps = 1\n"),
        )
        .unwrap();
        let out = mpirun(2, &["run", sc.to_str().unwrap(), "-q", "-o", d.path().join("o.h5").to_str().unwrap()]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success());
        assert!(err.contains(key) && err.contains(".vtkhdf mesh") && err.contains("fix:"), "{err}");
        // printed once
        assert_eq!(err.matches(key).count(), 1, "{err}");
        if !alone {
            continue;
        }
        // one process reads the whole .vtkhdf and resolves it
        let out = serial(&["run", sc.to_str().unwrap(), "-q", "-o", d.path().join("o1.h5").to_str().unwrap()], 1);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
}

/// Two separate boxes, one of them without a fixed node: the slabs' refusal is the whole
/// mesh's, word for word.
#[test]
fn an_unheld_piece_is_refused_as_on_the_whole_mesh() {
    let d = tempfile::tempdir().unwrap();
    let gen = |x: f64| {
        let mut m = eprop_io::generate::box_mesh([1.0; 3], [3, 3, 3], eprop_io::generate::BoxCells::Tet).unwrap();
        m.points.iter_mut().for_each(|p| p[0] += x);
        m
    };
    let (mut a, b) = (gen(0.0), gen(2.0));
    let base = a.n_nodes() as u32;
    for c in 0..b.n_cells() {
        let nodes: Vec<u32> = b.cell(c).iter().map(|&v| v + base).collect();
        a.push_cell(b.kinds[c], &nodes, b.cell_tags[c]);
    }
    a.points.extend(&b.points);
    a.node_ids = (1..=a.points.len() as u64).collect();
    a.facets = eprop_mesh::mesh::Facets::new();
    let msh = d.path().join("two.msh");
    eprop_io::write_mesh(&a, &msh).unwrap();
    let vtkhdf = d.path().join("two.vtkhdf");
    let out = serial(&["convert", msh.to_str().unwrap(), vtkhdf.to_str().unwrap()], 1);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let mut errors = vec![];
    for (mesh, n) in [(&msh, 1), (&vtkhdf, 2), (&vtkhdf, 3)] {
        let sc = d.path().join("s.toml");
        std::fs::write(
            &sc,
            format!(
                "[mesh]\nfile = \"{}\"\n[[fixed]]\nbox = [[-1, -1, -1], [1.5, 2, 0.01]]\n[model]\nreading = \"paper\"\n[time]\nsteps = 1\n",
                mesh.display()
            ),
        )
        .unwrap();
        let o = d.path().join("o.h5");
        let out = match n {
            1 => serial(&["run", sc.to_str().unwrap(), "-q", "-o", o.to_str().unwrap()], 1),
            _ => mpirun(n, &["run", sc.to_str().unwrap(), "-q", "-o", o.to_str().unwrap()]),
        };
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(err.contains("separate pieces"), "{err}");
        errors.push(err.lines().next().unwrap_or_default().to_string());
    }
    assert_eq!(errors[1], errors[0]);
    assert_eq!(errors[2], errors[0]);
}

/// Writes `m` as `NAME.msh` and `NAME.vtkhdf` in `dir` (the .vtkhdf written as it is: the
/// converter would refuse a defective mesh).
fn both(dir: &Path, name: &str, m: &eprop_mesh::Mesh) -> (String, String) {
    let msh = dir.join(format!("{name}.msh"));
    eprop_io::write_mesh(m, &msh).unwrap();
    let vtkhdf = dir.join(format!("{name}.vtkhdf"));
    eprop_series::vtkhdf::write_mesh_file(m, &vtkhdf).unwrap();
    (msh.display().to_string(), vtkhdf.display().to_string())
}

/// A box of tetrahedra without boundary elements (cell ids are cell indices + 1 in both files).
fn plain_box(n: [usize; 3]) -> eprop_mesh::Mesh {
    let mut m = eprop_io::generate::box_mesh([1.0; 3], n, eprop_io::generate::BoxCells::Tet).unwrap();
    m.facets = eprop_mesh::mesh::Facets::new();
    m.node_ids = (1..=m.n_nodes() as u64).map(|i| 3 * i + 7).collect();
    m
}

/// Runs the scenario `body` on `mesh` (on `n` processes, one without mpirun) with --json.
fn run_on(dir: &Path, mesh: &str, body: &str, n: usize) -> std::process::Output {
    let sc = dir.join(format!("s{n}.toml"));
    std::fs::write(&sc, format!("[mesh]\nfile = \"{mesh}\"\n{body}")).unwrap();
    let o = dir.join(format!("o{n}.h5"));
    let args = [
        "run",
        sc.to_str().unwrap(),
        "--json",
        "-o",
        o.to_str().unwrap(),
        "--overwrite",
    ];
    match n {
        1 => serial(&args, 1),
        _ => mpirun(n, &args),
    }
}

/// Defects of the mesh that the whole mesh's check refuses (non-finite coordinates, repeated
/// nodes, duplicate, inverted and non-manifold cells) are refused from the slabs with the same
/// message (the .msh read strictly, as the slabs are: an inverted cell is refused), naming the
/// same cell or node: the first of the whole mesh.
#[test]
fn mesh_defects_from_slabs_are_refused_as_on_the_whole_mesh() {
    let d = tempfile::tempdir().unwrap();
    let base = plain_box([4, 4, 4]);
    let mut cases: Vec<(&str, eprop_mesh::Mesh, &str)> = vec![];
    // two inverted cells, one in each half: the first is named
    let mut m = base.clone();
    for c in [200, 90] {
        let s = m.offsets[c];
        m.conn.swap(s, s + 1);
    }
    cases.push(("inverted", m, "is inverted"));
    // two duplicated cells: the pair of the lowest node is named
    let mut m = base.clone();
    for c in [300, 41] {
        let nodes = m.cell(c).to_vec();
        m.push_cell(m.kinds[c], &nodes, m.cell_tags[c]);
    }
    cases.push(("duplicate", m, "are duplicates"));
    // two nodes with a non-finite coordinate: the first is named
    let mut m = base.clone();
    m.points[90][1] = f64::NAN;
    m.points[40][2] = f64::INFINITY;
    cases.push(("nonfinite", m, "non-finite coordinate"));
    // a cell with a repeated node
    let mut m = base.clone();
    let s = m.offsets[150];
    m.conn[s + 2] = m.conn[s];
    cases.push(("repeated", m, "repeats a node"));
    // a third cell on an inner face: cell c with its fourth node moved a little
    let mut m = base.clone();
    let mut inner = vec![];
    eprop_mesh::mesh::for_each_face(&m, |_, cells| {
        if cells.len() == 2 {
            inner.push(cells[0]);
        }
        Ok::<(), ()>(())
    })
    .unwrap();
    inner.sort_unstable();
    let (c, f) = inner[inner.len() / 2];
    let c = c as usize;
    let face = m.kinds[c].faces()[f as usize];
    let apex = (0..4).find(|k| !face.contains(k)).unwrap();
    let cell = m.cell(c).to_vec();
    let (p, q) = (m.points[cell[apex] as usize], m.points[cell[face[0]] as usize]);
    m.points.push([0, 1, 2].map(|k| 0.8 * p[k] + 0.2 * q[k]));
    m.node_ids.push(1_000_001);
    let mut nodes = cell.clone();
    nodes[apex] = (m.points.len() - 1) as u32;
    m.push_cell(m.kinds[c], &nodes, 1);
    cases.push(("nonmanifold", m, "non-manifold"));
    for (name, m, what) in &cases {
        let (msh, vtkhdf) = both(d.path(), name, m);
        let text = |mesh: &str| {
            format!(
                "[mesh]\nfile = \"{mesh}\"\nstrict = true\n[[fixed]]\nhalfspace = {{ point = [0, 0, 0.01], normal = [0, 0, -1] }}\n[model]\nreading = \"paper\"\n[time]\nsteps = 1\n"
            )
        };
        let mut errors = vec![];
        // the .msh reader refuses a non-finite coordinate itself (with its line): the reference
        // is then the .vtkhdf read whole by one process
        let first = match *name {
            "nonfinite" => &vtkhdf,
            _ => &msh,
        };
        for (mesh, n) in [(first, 1), (&vtkhdf, 2), (&vtkhdf, 3)] {
            let sc = d.path().join(format!("{name}{n}.toml"));
            std::fs::write(&sc, text(mesh)).unwrap();
            let o = d.path().join("o.h5");
            let args = ["run", sc.to_str().unwrap(), "-q", "-o", o.to_str().unwrap()];
            let out = match n {
                1 => serial(&args, 1),
                _ => mpirun(n, &args),
            };
            assert!(!out.status.success(), "{name} on {n}");
            let err = String::from_utf8_lossy(&out.stderr).replace(".vtkhdf", ".msh");
            assert!(err.contains(what), "{name} on {n}: {err}");
            // printed once
            assert_eq!(err.matches(what).count(), 1, "{err}");
            // the message, without mpirun's note of the exit status
            let err: Vec<&str> = err.lines().take_while(|l| !l.starts_with("-----")).collect();
            errors.push(err.join("\n").replace(&format!("{name}{n}.toml"), "s.toml"));
        }
        assert_eq!(errors[1], errors[0], "{name}");
        assert_eq!(errors[2], errors[0], "{name}");
    }
}

/// The summary of a run from the slabs is the whole mesh's: the node of max |u| (its input id
/// and position), the cell count, the reader's warning about disconnected components and the
/// warning about a `nearest` point far from its node.
#[test]
fn the_summary_from_slabs_is_the_whole_meshs() {
    let d = tempfile::tempdir().unwrap();
    let gen = |x: f64| {
        let mut m = plain_box([3, 4, 3]);
        m.points.iter_mut().for_each(|p| p[0] += x);
        m
    };
    let (mut m, b) = (gen(0.0), gen(2.0));
    let base = m.n_nodes() as u32;
    for c in 0..b.n_cells() {
        let nodes: Vec<u32> = b.cell(c).iter().map(|&v| v + base).collect();
        m.push_cell(b.kinds[c], &nodes, b.cell_tags[c]);
    }
    m.points.extend(&b.points);
    m.node_ids.extend(b.node_ids.iter().map(|i| i + 100_000));
    let (msh, vtkhdf) = both(d.path(), "two", &m);
    let body = "[[fixed]]\nhalfspace = { point = [0, 0, 0.01], normal = [0, 0, -1] }\n\
                [[load]]\nnearest = [2.5, 0.5, 1.3]\nnormal = 0.05\nramp = [[0, 0], [1, 1]]\n\
                [[load]]\npatch = { center = [0.5, 0.5, 1.0], radius = 0.3 }\nforce = [0, 0.02, 0.01]\n\
                [model]\nreading = \"paper\"\n[time]\nsteps = 4\n";
    let summary = |mesh: &str, n: usize| {
        let out = run_on(d.path(), mesh, body, n);
        assert!(out.status.success(), "{n}: {}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let keep = [
            "nodes",
            "cells",
            "max_displacement",
            "max_displacement_node",
            "max_displacement_at",
            "warnings",
            "loads",
        ];
        keep.map(|k| (k, v[k].clone()))
    };
    let whole = summary(&msh, 1);
    let warnings = whole[5].1.to_string();
    assert!(
        warnings.contains("2 disconnected components") && warnings.contains("nearest"),
        "{warnings}"
    );
    assert!(whole[3].1.as_u64().unwrap() > 100_000, "{whole:?}");
    for n in [2, 3] {
        assert_eq!(summary(&vtkhdf, n), whole, "{n} processes");
    }
}
