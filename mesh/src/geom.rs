//! Small geometric helpers shared by the readers, the generator and the solver.

use crate::mesh::CellKind;

#[inline]
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
pub fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
pub fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline]
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline]
pub fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}
#[inline]
pub fn det3(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    dot(a, cross(b, c))
}

/// Mean of a set of points.
pub fn centroid(nodes: &[u32], pts: &[[f64; 3]]) -> [f64; 3] {
    let mut c = [0.0; 3];
    for &n in nodes {
        c = add(c, pts[n as usize]);
    }
    scale(c, 1.0 / nodes.len() as f64)
}

/// Vector area of a closed polygon loop (exact for any non-planar loop).
pub fn loop_area(p: &[[f64; 3]]) -> [f64; 3] {
    let n = p.len();
    let mut a = [0.0; 3];
    for k in 0..n {
        a = add(a, cross(sub(p[k], p[0]), sub(p[(k + 1) % n], p[0])));
    }
    scale(a, 0.5)
}

/// Signed volume of a cell; faces are triangulated as fans from their centroids.
/// Positive for a positively oriented cell.
pub fn cell_volume(kind: CellKind, nodes: &[u32], pts: &[[f64; 3]]) -> f64 {
    let o = pts[nodes[0] as usize];
    if kind == CellKind::Tet {
        let p = |k: usize| sub(pts[nodes[k] as usize], o);
        return det3(p(1), p(2), p(3)) / 6.0;
    }
    let mut v = 0.0;
    for face in kind.faces() {
        let fnodes: Vec<u32> = face.iter().map(|&l| nodes[l]).collect();
        if fnodes.len() == 3 {
            let p = |k: usize| sub(pts[fnodes[k] as usize], o);
            v += det3(p(0), p(1), p(2));
        } else {
            let fc = sub(centroid(&fnodes, pts), o);
            for k in 0..fnodes.len() {
                let a = sub(pts[fnodes[k] as usize], o);
                let b = sub(pts[fnodes[(k + 1) % fnodes.len()] as usize], o);
                v += det3(fc, a, b);
            }
        }
    }
    v / 6.0
}

/// Longest edge of a cell.
pub fn cell_size(kind: CellKind, nodes: &[u32], pts: &[[f64; 3]]) -> f64 {
    kind.edges()
        .iter()
        .map(|e| norm(sub(pts[nodes[e[0]] as usize], pts[nodes[e[1]] as usize])))
        .fold(0.0, f64::max)
}

/// Shape quality in (0, 1]: 1 for a regular tetrahedron or a cube, 0 when flat.
/// Mean-ratio style: 6*sqrt(2)*V / l_rms^3 for tets, V / l_rms^3 normalised for others.
pub fn cell_quality(kind: CellKind, nodes: &[u32], pts: &[[f64; 3]]) -> f64 {
    let v = cell_volume(kind, nodes, pts);
    let edges = kind.edges();
    let l2: f64 = edges
        .iter()
        .map(|e| {
            let d = sub(pts[nodes[e[0]] as usize], pts[nodes[e[1]] as usize]);
            dot(d, d)
        })
        .sum::<f64>()
        / edges.len() as f64;
    let l3 = l2.powf(1.5);
    let ideal = match kind {
        CellKind::Tet => 1.0 / (6.0 * 2f64.sqrt()),
        CellKind::Hex => 1.0,
        CellKind::Wedge => 3f64.sqrt() / 4.0,
        CellKind::Pyramid => 2f64.sqrt() / 6.0,
    };
    v / (ideal * l3)
}
