//! Kinematic tools on organ meshes the project did not make (../shared/meshes, SOURCES.md):
//! a tetgen mesh of a prostate zone with slivers pressed by a sphere and by a punch keeps
//! every node out of the tool and on the organ's side of its fixed support at every output
//! step; on the head atlas a skull 1000 times stiffer in young than the rest of the head moves
//! less under the same tool than in the homogeneous head. Under EPROP_REQUIRE_ALL a missing
//! mesh or tetgen is a failure (`common::skip`).
//!
//! The prostate zone runs under the default integrator (auto: implicit, about a second a press).
//! Under euler it is impractical: a sliver on its surface (node 205 in `eprop info`, quality
//! 0.005) sets the explicit substep 93,000 times below the median node's, 6.4e6 substeps per
//! step at dt = 0.04.

mod common;

use eprop::simulate::Simulation;
use eprop_io::geom::norm;
use eprop_io::Mesh;
use std::path::Path;
use std::process::Command;

/// The prostate's left peripheral zone (HuBMAP, metres) tetrahedralized by tetgen without a
/// quality bound (`-pQ`): a coarse mesh with slivers. None (a skip) without the data or tetgen.
fn prostate(dir: &Path) -> Option<Mesh> {
    let src = common::shared_dir("surface")?.join("hubmap_VH_M_prostate_peripheral_zone_L.off");
    if !src.exists() {
        common::skip(&format!("{} not found", src.display()));
        return None;
    }
    if !common::tool("tetgen") {
        return None;
    }
    let off = dir.join("zone.off");
    std::fs::copy(&src, &off).unwrap();
    let st = Command::new("tetgen").arg("-pQ").arg(&off).status().unwrap();
    assert!(st.success(), "tetgen failed");
    Some(eprop_io::read_mesh(&dir.join("zone.1.ele")).unwrap())
}

/// Tetrahedra whose volume is below 1 % of that of the regular one on their longest edge.
fn slivers(m: &Mesh) -> usize {
    (0..m.n_cells())
        .filter(|&c| {
            let p: Vec<[f64; 3]> = m.cell(c).iter().map(|&k| m.points[k as usize]).collect();
            let d = |a: usize, b: usize| norm(eprop_io::geom::sub(p[a], p[b]));
            let l = [d(0, 1), d(0, 2), d(0, 3), d(1, 2), d(1, 3), d(2, 3)]
                .into_iter()
                .fold(0.0, f64::max);
            let v = eprop_io::geom::det3(
                eprop_io::geom::sub(p[1], p[0]),
                eprop_io::geom::sub(p[2], p[0]),
                eprop_io::geom::sub(p[3], p[0]),
            )
            .abs()
                / 6.0;
            v < 0.01 * l.powi(3) / (6.0 * 2f64.sqrt())
        })
        .count()
}

#[test]
fn a_tetgen_organ_with_slivers_pressed_by_a_sphere_and_a_punch_keeps_its_nodes_out_of_the_tool_and_the_support() {
    let d = tempfile::tempdir().unwrap();
    let Some(mesh) = prostate(d.path()) else {
        return;
    };
    let (lo, hi) = mesh.bounds();
    let thin = slivers(&mesh);
    println!(
        "prostate zone: {} nodes, {} tetrahedra, {thin} slivers; box {:?} - {:?} m",
        mesh.n_nodes(),
        mesh.n_cells(),
        lo,
        hi
    );
    assert!(thin > 0, "no sliver in a mesh made without a quality bound");
    // the topmost node, pressed down; the organ held at the end of its longest side
    let top = (0..mesh.n_nodes())
        .max_by(|&a, &b| mesh.points[a][2].total_cmp(&mesh.points[b][2]))
        .unwrap();
    let t = mesh.points[top];
    let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    let axis = (0..3).max_by(|&a, &b| ext[a].total_cmp(&ext[b])).unwrap();
    let far_low = t[axis] - lo[axis] > hi[axis] - t[axis];
    let (cut, sign) = match far_low {
        true => (lo[axis] + 0.2 * ext[axis], -1.0),
        false => (hi[axis] - 0.2 * ext[axis], 1.0),
    };
    let mut point = [0.0; 3];
    let mut normal = [0.0; 3];
    point[axis] = cut;
    normal[axis] = sign;
    let depth = 0.25 * ext[2];
    let r = 0.2 * ext[2];
    for (name, tool, lift) in [
        ("sphere", format!("shape = \"sphere\"\nradius = {r}"), r),
        (
            "punch",
            format!("shape = \"punch\"\nradius = {r}\nnormal = [0, 0, -1]"),
            0.0,
        ),
    ] {
        std::fs::write(
            d.path().join("path.csv"),
            format!(
                "t,x,y,z\n0,{x},{y},{z0}\n0.16,{x},{y},{z1}\n0.24,{x},{y},{z1}\n0.4,{x},{y},{z0}\n",
                x = t[0],
                y = t[1],
                z0 = t[2] + lift,
                z1 = t[2] + lift - depth
            ),
        )
        .unwrap();
        let text = format!(
            "[[fixed]]\nhalfspace = {{ point = {point:?}, normal = {normal:?} }}\n[[tool]]\n{tool}\ntable = \"path.csv\"\n[material]\nconductivity = 1e-4\n[time]\ndt = 0.04\nend = 0.4\n[model]\nreading = \"continuum\"\n"
        );
        let setup = common::setup_with(mesh.clone(), &text, d.path(), &["mesh.unit=\"m\"".to_string()]);
        assert_eq!(setup.supports.len(), 1);
        let mut sim = Simulation::new(setup).expect("simulation builds");
        let (mut inside, mut across, mut contact, mut inverted) = (0, 0, 0, 0);
        while !sim.done() {
            sim.advance().unwrap();
            let i = sim.inspect();
            inside = inside.max(i.inside[0]);
            across = across.max(i.across);
            inverted = inverted.max(i.inverted);
            contact = contact.max(sim.tool_states()[0].contact_nodes);
        }
        println!(
            "{name} r = {r:.4e} m pressed {depth:.4e} m: at most {contact} contact nodes, {inside} inside, {across} across the support, {inverted} inverted cells"
        );
        assert!(contact > 0, "{name}: the tool never touched");
        assert_eq!((inside, across), (0, 0), "{name}");
    }
}

#[test]
fn on_the_head_atlas_a_skull_stiffer_in_young_moves_less_under_a_tool() {
    let Some(path) = common::shared_mesh("mmc_head_atlas.vtu") else {
        return;
    };
    // the atlas is in mm: in metres
    let mut mesh = eprop_io::read_mesh(&path).unwrap();
    for p in &mut mesh.points {
        *p = p.map(|x| x * 1e-3);
    }
    let (lo, hi) = mesh.bounds();
    let n = mesh.n_nodes();
    let skull_tag = 3;
    let mut on_skull = vec![false; n];
    for c in 0..mesh.n_cells() {
        if mesh.cell_tags[c] == skull_tag {
            for &k in mesh.cell(c) {
                on_skull[k as usize] = true;
            }
        }
    }
    let top = (0..n)
        .max_by(|&a, &b| mesh.points[a][2].total_cmp(&mesh.points[b][2]))
        .unwrap();
    let t = mesh.points[top];
    let dist = |i: usize| norm(eprop_io::geom::sub(mesh.points[i], t));
    let under: Vec<usize> = (0..n).filter(|&i| on_skull[i] && dist(i) < 0.025).collect();
    assert!(under.len() > 10, "{} skull nodes within 25 mm of the top", under.len());
    let d = tempfile::tempdir().unwrap();
    // a 10 mm sphere pressed 4 mm into the top of the head over 0.2 s, held; in real time (one
    // TR-BDF2 step per dt, about 10 s a run): under error control the contact steps take
    // sub-steps down to dt / 2^18, about 3 minutes a run
    std::fs::write(
        d.path().join("path.csv"),
        format!(
            "t,x,y,z\n0,{x},{y},{z0}\n0.2,{x},{y},{z1}\n",
            x = t[0],
            y = t[1],
            z0 = t[2] + 0.010,
            z1 = t[2] + 0.006
        ),
    )
    .unwrap();
    let base = format!(
        "[[fixed]]\nbox = [[-1e9, -1e9, -1e9], [1e9, 1e9, {}]]\n[[tool]]\nshape = \"sphere\"\nradius = 0.01\ntable = \"path.csv\"\n[time]\ndt = 0.03\nend = 0.6\nrealtime = true\n[model]\nreading = \"continuum\"\n",
        lo[2] + 0.1 * (hi[2] - lo[2])
    );
    let mut moved = Vec::new();
    for extra in ["", "[[material.region]]\ntag = 3\nyoung = 4e6\n"] {
        let setup = common::setup_with(
            mesh.clone(),
            &format!("{extra}{base}"),
            d.path(),
            &["mesh.unit=\"m\"".to_string()],
        );
        let mut sim = Simulation::new(setup).expect("simulation builds");
        while !sim.done() {
            sim.advance().unwrap();
        }
        let contact = sim.tool_states()[0].contact_nodes;
        assert!(contact > 0);
        let u = sim.u();
        // one process: local index = mesh index through the output order
        let x = sim.in_output_order(&u[..sim.n_owned()]);
        let mean = under
            .iter()
            .map(|&i| norm([x[3 * i], x[3 * i + 1], x[3 * i + 2]]))
            .sum::<f64>()
            / under.len() as f64;
        moved.push(mean);
        println!("head atlas{}: {contact} contact nodes; mean |u| of the {} skull nodes within 25 mm of the tool {mean:.4e} m", if extra.is_empty() { "" } else { ", skull 1000x stiffer" }, under.len());
    }
    assert!(moved[1] < 0.5 * moved[0], "{moved:?}");
}
