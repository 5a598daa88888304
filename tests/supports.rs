//! Nothing through a support (docs/model.md section 6): a fixed face or half-space is a rigid
//! plane; no node's deformed position lies across it at any step, counted in the series
//! (`/eprop/checks/across`) and the summary, even under a tool pressed most of the way through
//! a thin block.

mod common;

use eprop::simulate::Simulation;
use eprop_io::generate::{box_mesh, BoxCells};
use std::path::Path;

/// A 40 x 40 x 8 mm block in metres on a fixed floor (`fixed`), a sticky punch of radius 5 mm
/// pressed `depth` into its top centre over 0.3 s and held 0.1 s: the most nodes across the
/// floor and inside the punch at a step, and the supports' planes.
fn punch(dir: &Path, fixed: &str, depth: f64) -> (u64, u64, usize) {
    std::fs::write(
        dir.join("path.csv"),
        format!("t,x,y,z\n0,0.02,0.02,0.008\n0.3,0.02,0.02,{}\n", 0.008 - depth),
    )
    .unwrap();
    let mesh = box_mesh([0.04, 0.04, 0.008], [12, 12, 4], BoxCells::Tet).unwrap();
    let text = format!(
        "[[fixed]]\n{fixed}\n[[tool]]\nshape = \"punch\"\nradius = 0.005\nnormal = [0, 0, -1]\ntable = \"path.csv\"\n[time]\ndt = 0.01\nend = 0.4\n[model]\nreading = \"continuum\"\n"
    );
    let setup = common::setup_with(mesh, &text, dir, &["mesh.unit=\"m\"".to_string()]);
    let planes = setup.supports.len();
    let mut sim = Simulation::new(setup).expect("simulation builds");
    let (mut across, mut inside) = (0, 0);
    while !sim.done() {
        sim.advance().unwrap();
        let i = sim.inspect();
        across = across.max(i.across);
        inside = inside.max(i.inside[0]);
    }
    (across, inside, planes)
}

#[test]
fn a_deep_punch_into_a_thin_block_leaves_every_node_above_its_fixed_floor_and_out_of_the_punch() {
    let d = tempfile::tempdir().unwrap();
    for fixed in [
        "group = \"zmin\"",
        "halfspace = { point = [0.0, 0.0, 0.0], normal = [0.0, 0.0, -1.0] }",
    ] {
        for depth in [0.004, 0.006] {
            let (across, inside, planes) = punch(d.path(), fixed, depth);
            assert_eq!(planes, 1, "{fixed}");
            println!("{fixed}: punch {depth} m into 8 mm: at most {across} node(s) across the floor, {inside} inside the punch");
            assert_eq!((across, inside), (0, 0), "{fixed}, {depth}");
        }
    }
}

#[test]
fn a_fixed_face_or_half_space_is_a_support_plane_and_a_curved_set_is_none() {
    let d = tempfile::tempdir().unwrap();
    let mesh = || box_mesh([0.04, 0.04, 0.008], [4, 4, 2], BoxCells::Tet).unwrap();
    let planes = |fixed: &str| {
        let text = format!("[[fixed]]\n{fixed}\n[time]\nsteps = 1\n[model]\nreading = \"continuum\"\n");
        common::setup_with(mesh(), &text, d.path(), &["mesh.unit=\"m\"".to_string()]).supports
    };
    let floor = planes("group = \"zmin\"");
    assert_eq!(floor.len(), 1);
    assert_eq!(floor[0].normal, [0.0, 0.0, -1.0], "{floor:?}");
    let side = planes("box = [[0.039, -1.0, -1.0], [1.0, 1.0, 1.0]]");
    assert_eq!(side.len(), 1);
    assert!((side[0].normal[0] - 1.0).abs() < 1e-15, "{side:?}");
    // the nodes of an edge (a line) and a fixed set through the middle of the organ are no
    // support plane; a half-space is, whatever its normal's length
    assert!(planes("box = [[0.039, -1.0, -1.0], [1.0, 1.0, 0.0]]").is_empty());
    assert!(planes("box = [[0.019, -1.0, -1.0], [0.021, 1.0, 1.0]]").is_empty());
    let h = planes("halfspace = { point = [0.0, 0.0, 0.002], normal = [0.0, 0.0, -2.0] }");
    assert_eq!(h[0].normal, [0.0, 0.0, -1.0], "{h:?}");
}
