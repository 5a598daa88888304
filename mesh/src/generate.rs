//! Structured mesh generators: a box (tetrahedra, hexahedra or prisms) and a cylinder
//! (tetrahedra). Both tag their boundary faces, so scenarios can fix or load them by name.

use crate::geom::{cell_volume, centroid};
use crate::mesh::{boundary_faces, CellKind, Mesh};
use anyhow::{bail, Result};

/// Which cells a box is filled with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BoxCells {
    Tet,
    Hex,
    Wedge,
    /// Each hexahedron split into six pyramids around a centre node; a pyramid whose base is on
    /// the box boundary is split further into two tetrahedra (a pyramid + tetrahedron mesh).
    PyramidTet,
}

/// Pushes a cell, reordering it to positive orientation.
fn push_oriented(mesh: &mut Mesh, kind: CellKind, nodes: &[u32], tag: i32) {
    if cell_volume(kind, nodes, &mesh.points) < 0.0 {
        let flipped: Vec<u32> = kind.flip().iter().map(|&p| nodes[p]).collect();
        mesh.push_cell(kind, &flipped, tag);
    } else {
        mesh.push_cell(kind, nodes, tag);
    }
}

/// Generated lengths must lie in this range: outside it cell volumes overflow or underflow
/// and the reader refuses the mesh as degenerate.
pub const LENGTHS: (f64, f64) = (1e-60, 1e60);

fn in_range(what: &str, keys: &str, lengths: &[f64]) -> Result<()> {
    let lo = lengths.iter().fold(f64::INFINITY, |m, &x| m.min(x));
    let hi = lengths.iter().fold(0.0f64, |m, &x| m.max(x));
    if lo < LENGTHS.0 || hi > LENGTHS.1 {
        bail!(
            "{what}: {keys} must lie between {:e} and {:e} (given {lo:e} to {hi:e}): beyond that the cells' volumes overflow or underflow and the mesh reader refuses the file; fix: give the sizes in a unit that makes them a few units to a few thousand (`[mesh] scale` converts on reading)",
            LENGTHS.0,
            LENGTHS.1
        );
    }
    Ok(())
}

/// A box `[0,lx]x[0,ly]x[0,lz]` with `n` cells along each axis. Hexahedra are split into six
/// tetrahedra around their main diagonal (a conforming Kuhn split) or into two prisms.
/// Boundary triangles/quads are tagged 1..6 = xmin, xmax, ymin, ymax, zmin, zmax.
pub fn box_mesh(size: [f64; 3], n: [usize; 3], cells: BoxCells) -> Result<Mesh> {
    if n.contains(&0) || size.iter().any(|&s| !(s > 0.0 && s.is_finite())) {
        bail!("box: every size must be positive and every cell count at least 1");
    }
    in_range("box", "every size", &size)?;
    let lattice = (n[0] + 1) * (n[1] + 1) * (n[2] + 1);
    let np = lattice
        + if cells == BoxCells::PyramidTet {
            n[0] * n[1] * n[2]
        } else {
            0
        };
    if np > u32::MAX as usize / 2 {
        bail!("box: {np} nodes is more than eprop indexes (2^31)");
    }
    let mut mesh = Mesh::new(format!("box {}x{}x{} cells of {:?}", n[0], n[1], n[2], cells));
    mesh.points.reserve(np);
    for k in 0..=n[2] {
        for j in 0..=n[1] {
            for i in 0..=n[0] {
                mesh.points.push([
                    size[0] * i as f64 / n[0] as f64,
                    size[1] * j as f64 / n[1] as f64,
                    size[2] * k as f64 / n[2] as f64,
                ]);
            }
        }
    }
    let id = |i: usize, j: usize, k: usize| (i + (n[0] + 1) * (j + (n[1] + 1) * k)) as u32;
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                let v = |a: usize, b: usize, c: usize| id(i + a, j + b, k + c);
                match cells {
                    BoxCells::Hex => {
                        let h = [
                            v(0, 0, 0),
                            v(1, 0, 0),
                            v(1, 1, 0),
                            v(0, 1, 0),
                            v(0, 0, 1),
                            v(1, 0, 1),
                            v(1, 1, 1),
                            v(0, 1, 1),
                        ];
                        push_oriented(&mut mesh, CellKind::Hex, &h, 1);
                    }
                    BoxCells::Wedge => {
                        let w1 = [v(0, 0, 0), v(1, 0, 0), v(1, 1, 0), v(0, 0, 1), v(1, 0, 1), v(1, 1, 1)];
                        let w2 = [v(0, 0, 0), v(1, 1, 0), v(0, 1, 0), v(0, 0, 1), v(1, 1, 1), v(0, 1, 1)];
                        push_oriented(&mut mesh, CellKind::Wedge, &w1, 1);
                        push_oriented(&mut mesh, CellKind::Wedge, &w2, 1);
                    }
                    BoxCells::PyramidTet => {
                        let c = mesh.points.len() as u32;
                        let (a, b) = (mesh.points[v(0, 0, 0) as usize], mesh.points[v(1, 1, 1) as usize]);
                        mesh.points
                            .push([(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0, (a[2] + b[2]) / 2.0]);
                        let (lo, hi) = ([i == 0, j == 0, k == 0], [i + 1 == n[0], j + 1 == n[1], k + 1 == n[2]]);
                        // the two faces normal to each axis, as quads in cyclic order
                        for axis in 0..3 {
                            for side in 0..2 {
                                let corner = |s: usize, t: usize| {
                                    let mut o = [0usize; 3];
                                    o[axis] = side;
                                    o[(axis + 1) % 3] = s;
                                    o[(axis + 2) % 3] = t;
                                    v(o[0], o[1], o[2])
                                };
                                let q = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
                                if [lo, hi][side][axis] {
                                    push_oriented(&mut mesh, CellKind::Tet, &[q[0], q[1], q[2], c], 1);
                                    push_oriented(&mut mesh, CellKind::Tet, &[q[0], q[2], q[3], c], 1);
                                } else {
                                    push_oriented(&mut mesh, CellKind::Pyramid, &[q[0], q[1], q[2], q[3], c], 1);
                                }
                            }
                        }
                    }
                    BoxCells::Tet => {
                        const PERMS: [[usize; 3]; 6] =
                            [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
                        for p in PERMS {
                            let mut c = [0usize; 3];
                            let mut t = [v(0, 0, 0); 4];
                            for (s, &axis) in p.iter().enumerate() {
                                c[axis] = 1;
                                t[s + 1] = v(c[0], c[1], c[2]);
                            }
                            push_oriented(&mut mesh, CellKind::Tet, &t, 1);
                        }
                    }
                }
            }
        }
    }
    mesh.node_ids = (1..=mesh.points.len() as u64).collect();
    mesh.group_names.insert((3, 1), "tissue".into());
    for (t, name) in ["xmin", "xmax", "ymin", "ymax", "zmin", "zmax"].iter().enumerate() {
        mesh.group_names.insert((2, t as i32 + 1), name.to_string());
    }
    tag_boundary(&mut mesh, |c| {
        for d in 0..3 {
            if c[d].abs() < 1e-9 * size[d] {
                return 2 * d as i32 + 1;
            }
            if (c[d] - size[d]).abs() < 1e-9 * size[d] {
                return 2 * d as i32 + 2;
            }
        }
        0
    });
    Ok(mesh)
}

/// A cylinder of radius `radius` along z from 0 to `length`: `rings` concentric rings of 6k
/// nodes around the axis, `layers` cell layers along it, prisms split into three tetrahedra
/// each (conforming). Boundary triangles are tagged 1 = bottom (z = 0), 2 = top, 3 = side.
/// `rings = 3, layers = 11` gives the paper-sized cylinder (444 nodes, 1782 tetrahedra).
pub fn cylinder_mesh(radius: f64, length: f64, rings: usize, layers: usize) -> Result<Mesh> {
    if rings == 0 || layers == 0 || !(radius > 0.0 && radius.is_finite()) || !(length > 0.0 && length.is_finite()) {
        bail!("cylinder: radius and length must be positive, rings and layers at least 1");
    }
    in_range("cylinder", "the radius and the length", &[radius, length])?;
    let per_layer = 1 + 3 * rings * (rings + 1);
    let np = per_layer * (layers + 1);
    if np > u32::MAX as usize / 2 {
        bail!("cylinder: {np} nodes is more than eprop indexes (2^31)");
    }
    let mut mesh = Mesh::new(format!("cylinder r={radius} l={length} rings={rings} layers={layers}"));
    // cross-section: node 0 at the centre, then ring k (1-based) holds 6k nodes
    let mut ring_start = vec![1usize; rings + 1];
    let mut xy = vec![[0.0f64; 2]];
    for k in 1..=rings {
        ring_start[k] = xy.len();
        let m = 6 * k;
        let r = radius * k as f64 / rings as f64;
        for j in 0..m {
            let a = 2.0 * std::f64::consts::PI * j as f64 / m as f64;
            xy.push([r * a.cos(), r * a.sin()]);
        }
    }
    // triangles of the cross-section
    let mut tris: Vec<[usize; 3]> = Vec::new();
    for j in 0..6 {
        tris.push([0, ring_start[1] + j, ring_start[1] + (j + 1) % 6]);
    }
    for k in 2..=rings {
        let (n0, n1) = (6 * (k - 1), 6 * k);
        let inner = |i: usize| ring_start[k - 1] + i % n0;
        let outer = |i: usize| ring_start[k] + i % n1;
        let (mut i0, mut i1) = (0usize, 0usize);
        while i0 < n0 || i1 < n1 {
            let a0 = (i0 + 1) as f64 / n0 as f64;
            let a1 = (i1 + 1) as f64 / n1 as f64;
            if i1 < n1 && (i0 == n0 || a1 <= a0) {
                tris.push([inner(i0), outer(i1), outer(i1 + 1)]);
                i1 += 1;
            } else {
                tris.push([inner(i0), outer(i1), inner(i0 + 1)]);
                i0 += 1;
            }
        }
    }
    for l in 0..=layers {
        let z = length * l as f64 / layers as f64;
        for p in &xy {
            mesh.points.push([p[0], p[1], z]);
        }
    }
    mesh.node_ids = (1..=np as u64).collect();
    for l in 0..layers {
        for t in &tris {
            let b = l * per_layer;
            let prism = [
                t[0] + b,
                t[1] + b,
                t[2] + b,
                t[0] + b + per_layer,
                t[1] + b + per_layer,
                t[2] + b + per_layer,
            ];
            for tet in split_prism(prism) {
                let nodes = tet.map(|x| x as u32);
                push_oriented(&mut mesh, CellKind::Tet, &nodes, 1);
            }
        }
    }
    mesh.group_names.insert((3, 1), "tissue".into());
    mesh.group_names.insert((2, 1), "bottom".into());
    mesh.group_names.insert((2, 2), "top".into());
    mesh.group_names.insert((2, 3), "side".into());
    tag_boundary(&mut mesh, |c| {
        if c[2].abs() < 1e-9 * length {
            1
        } else if (c[2] - length).abs() < 1e-9 * length {
            2
        } else {
            3
        }
    });
    Ok(mesh)
}

/// Splits a prism (bottom a b c, top d e f above them) into three tetrahedra so that every
/// quadrilateral face is cut along the diagonal through its smallest node index: neighbouring
/// prisms then agree on their shared faces.
fn split_prism(p: [usize; 6]) -> [[usize; 4]; 3] {
    let m = (0..6).min_by_key(|&k| p[k]).unwrap();
    // bring the smallest node to position 0 by reflecting (top <-> bottom) and rotating
    let mut q = if m >= 3 {
        [p[3], p[4], p[5], p[0], p[1], p[2]]
    } else {
        p
    };
    let r = m % 3;
    q = [
        q[r],
        q[(r + 1) % 3],
        q[(r + 2) % 3],
        q[3 + r],
        q[3 + (r + 1) % 3],
        q[3 + (r + 2) % 3],
    ];
    let [a, b, c, d, e, f] = q;
    if b.min(f) < c.min(e) {
        [[a, b, c, f], [a, b, f, e], [a, e, f, d]]
    } else {
        [[a, b, c, e], [a, e, c, f], [a, e, f, d]]
    }
}

/// Adds the boundary faces of the volume cells as tagged facets; `classify` maps a face
/// centroid to a tag (0 = untagged, not stored).
pub fn tag_boundary(mesh: &mut Mesh, classify: impl Fn([f64; 3]) -> i32) {
    for (c, f) in boundary_faces(mesh) {
        let cell = mesh.cell(c as usize);
        let face: Vec<u32> = mesh.kinds[c as usize].faces()[f as usize]
            .iter()
            .map(|&l| cell[l])
            .collect();
        let tag = classify(centroid(&face, &mesh.points));
        if tag != 0 {
            mesh.facets.push(2, tag, &face);
        }
    }
}
