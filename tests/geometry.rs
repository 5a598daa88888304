//! Median-dual geometry: identities that must hold on any valid mesh.

mod common;

use eprop::discretize::geometry::{cell_dual, tet_gradients, Dual, Incidence};
use eprop_io::generate::{box_mesh, cylinder_mesh, BoxCells};
use eprop_io::geom::cell_volume;
use eprop_mesh::Mesh;

fn check_identities(mesh: &Mesh) {
    let inc = Incidence::new(mesh);
    let dual = Dual::build(mesh, &inc, mesh.n_nodes(), None);
    let volume: f64 = (0..mesh.n_cells())
        .map(|c| cell_volume(mesh.kinds[c], mesh.cell(c), &mesh.points))
        .sum();
    let sum_v: f64 = dual.vol.iter().sum();
    let rel = ((sum_v - volume) / volume).abs();
    assert!(
        rel < 1e-12,
        "{}: sum V_i = {sum_v}, volume = {volume}, rel {rel:e}",
        mesh.source
    );
    assert!(
        dual.vol.iter().all(|&v| v > 0.0),
        "{}: a control volume is not positive",
        mesh.source
    );
    let closure = dual.max_closure_error();
    assert!(closure < 1e-12, "{}: closure error {closure:e}", mesh.source);
    // antisymmetry S_ji = -S_ij, bitwise
    for i in 0..mesh.n_nodes() {
        for p in dual.row_ptr[i]..dual.row_ptr[i + 1] {
            let j = dual.col[p] as usize;
            let q = (dual.row_ptr[j]..dual.row_ptr[j + 1])
                .find(|&q| dual.col[q] as usize == i)
                .unwrap();
            let (a, b) = (dual.s[p], dual.s[q]);
            assert_eq!(a, [-b[0], -b[1], -b[2]], "{}: S_ij != -S_ji at ({i},{j})", mesh.source);
        }
    }
    // the boundary dual areas add up to a closed surface
    let total: [f64; 3] = dual
        .area
        .iter()
        .fold([0.0; 3], |t, a| [t[0] + a[0], t[1] + a[1], t[2] + a[2]]);
    let scale: f64 = dual
        .area
        .iter()
        .map(|a| (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt())
        .sum();
    assert!(
        total.iter().all(|x| x.abs() < 1e-12 * scale),
        "{}: sum A_i = {total:?}",
        mesh.source
    );
}

#[test]
fn identities_on_generated_tetrahedral_meshes() {
    check_identities(&box_mesh([1.0, 2.0, 0.5], [4, 5, 3], BoxCells::Tet).unwrap());
    check_identities(&cylinder_mesh(1.0, 4.0, 3, 11).unwrap());
    check_identities(&cylinder_mesh(0.3, 1.0, 5, 7).unwrap());
}

#[test]
fn identities_on_hexahedra_prisms_and_pyramids() {
    check_identities(&box_mesh([1.0, 1.0, 1.0], [3, 4, 2], BoxCells::Hex).unwrap());
    check_identities(&box_mesh([1.0, 0.5, 2.0], [3, 2, 4], BoxCells::Wedge).unwrap());
    let pt = box_mesh([1.0, 0.8, 1.2], [3, 2, 2], BoxCells::PyramidTet).unwrap();
    let kinds: std::collections::BTreeSet<_> = pt.kinds.iter().collect();
    assert_eq!(kinds.len(), 2, "a pyramid + tetrahedron mesh: {kinds:?}");
    check_identities(&pt);
    // distorted (non-affine) meshes: dual volumes are exact, not 1/8 (1/5, 1/6) fractions
    for cells in [BoxCells::Hex, BoxCells::Wedge, BoxCells::PyramidTet] {
        let mut m = box_mesh([1.0, 1.0, 1.0], [3, 3, 3], cells).unwrap();
        for p in m.points.iter_mut() {
            let (x, y, z) = (p[0], p[1], p[2]);
            p[0] += 0.07 * (3.0 * y).sin() * z;
            p[1] += 0.05 * (2.0 * z).cos() * x;
            p[2] += 0.06 * (x * y);
        }
        check_identities(&m);
    }
}

#[test]
fn identities_on_real_organ_meshes() {
    for name in ["sofa_liver.msh", "sofa_liver2.msh"] {
        let Some(p) = common::shared_mesh(name) else {
            continue;
        };
        let mesh = eprop_io::read_mesh(&p).unwrap();
        check_identities(&mesh);
    }
}

#[test]
fn tetrahedron_dual_faces_are_shape_function_differences() {
    // S_ij^T = (V_T / 4) (grad N_j - grad N_i), on irregular tetrahedra
    let pts = vec![
        [0.1, -0.2, 0.05],
        [1.3, 0.1, -0.1],
        [0.2, 0.9, 0.3],
        [0.4, 0.35, 1.7],
        [2.0, 1.0, 1.0],
    ];
    for nodes in [[0u32, 1, 2, 3], [1, 2, 3, 4], [0, 1, 2, 4]] {
        let mut nodes = nodes;
        if cell_volume(eprop_io::CellKind::Tet, &nodes, &pts) < 0.0 {
            nodes.swap(1, 2);
        }
        let cd = cell_dual(eprop_io::CellKind::Tet, &nodes, &pts);
        let (g, v) = tet_gradients(&nodes, &pts);
        for (e, edge) in eprop_io::CellKind::Tet.edges().iter().enumerate() {
            let (i, j) = (edge[0], edge[1]);
            for d in 0..3 {
                let want = v / 4.0 * (g[j][d] - g[i][d]);
                assert!(
                    (cd.s[e][d] - want).abs() < 1e-14 * (1.0 + want.abs()),
                    "edge {i}-{j}: {:?} vs {want}",
                    cd.s[e]
                );
            }
        }
        let sum: f64 = cd.vol.iter().sum();
        assert!((sum - v).abs() < 1e-15 * v.abs().max(1.0));
    }
}

#[test]
fn cylinder_generator_is_paper_sized() {
    let m = cylinder_mesh(1.0, 4.0, 3, 11).unwrap();
    assert_eq!(m.n_nodes(), 444);
    assert_eq!(m.n_cells(), 1782);
    assert!(m.group_tag("bottom").is_some() && m.group_tag("side").is_some());
}

/// The dual geometry and the compact coefficients built on one thread and on two are the same
/// bits (the build gathers each row's pieces in a fixed cell order, whatever the threads).
#[test]
fn the_geometry_and_operator_are_the_same_bits_on_one_and_two_threads() {
    use eprop::config::tissue::{Materials, Tensor};
    use eprop::discretize::geometry::compact_coefficients;
    let bits3 = |v: &[[f64; 3]]| v.iter().flat_map(|x| x.map(f64::to_bits)).collect::<Vec<u64>>();
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
    let meshes = [
        box_mesh([1.0, 2.0, 0.5], [22, 20, 10], BoxCells::Tet).unwrap(),
        box_mesh([1.0, 1.0, 1.0], [6, 5, 4], BoxCells::PyramidTet).unwrap(),
        box_mesh([1.0, 1.0, 1.0], [6, 5, 4], BoxCells::Hex).unwrap(),
    ];
    for mut mesh in meshes {
        // irregular points and tensors, so that the sums' order shows
        for (k, p) in mesh.points.iter_mut().enumerate() {
            let w = 0.01 * (((k * 2654435761) % 1000) as f64 / 1000.0 - 0.5);
            *p = [p[0] + w, p[1] - 0.5 * w, p[2] + 0.25 * w];
        }
        let n = mesh.n_nodes();
        let r: Vec<Tensor> = (0..n)
            .map(|k| {
                Tensor::new(
                    0.3,
                    0.05,
                    -0.02,
                    0.05,
                    0.2 + 1e-3 * (k % 7) as f64,
                    0.04,
                    -0.02,
                    0.04,
                    0.1,
                )
            })
            .collect();
        let mat = Materials::with_conductivities(&r, eprop::config::PAPER_TISSUE);
        let build = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let inc = Incidence::new(&mesh);
                let dual = Dual::build(&mesh, &inc, n, None);
                let a = compact_coefficients(&mesh, &inc, &dual, &mat);
                (
                    dual.row_ptr.clone(),
                    dual.col.clone(),
                    bits3(&dual.s),
                    bits(&dual.vol),
                    bits3(&dual.area),
                    bits(&dual.dual_area),
                    bits(&a),
                )
            })
        };
        let (one, two) = (build(1), build(2));
        assert!(one == two, "{}: the build differs on two threads", mesh.source);
    }
}

/// The boundary areas A_i as the whole mesh's boundary faces give them (`boundary_faces`):
/// each face's quarter-loop added to its nodes in the order of the cells and their faces.
fn areas_from_boundary_faces(mesh: &Mesh) -> Vec<[f64; 3]> {
    use eprop_io::geom::{add, centroid, loop_area, scale};
    let pts = &mesh.points;
    let mut by_cell: Vec<Vec<u8>> = vec![Vec::new(); mesh.n_cells()];
    for (c, f) in eprop_io::mesh::boundary_faces(mesh) {
        by_cell[c as usize].push(f);
    }
    let mut area = vec![[0.0; 3]; mesh.n_nodes()];
    let inc = Incidence::new(mesh);
    for (i, a) in area.iter_mut().enumerate() {
        for &c in inc.of(i) {
            let (kind, nodes) = (mesh.kinds[c as usize], mesh.cell(c as usize));
            let li = nodes.iter().position(|&x| x as usize == i).unwrap();
            for &f in &by_cell[c as usize] {
                let face = kind.faces()[f as usize];
                let Some(k) = face.iter().position(|&l| l == li) else {
                    continue;
                };
                let nf = face.len();
                let (next, prev) = (
                    nodes[face[(k + 1) % nf]] as usize,
                    nodes[face[(k + nf - 1) % nf]] as usize,
                );
                let fnodes: Vec<u32> = face.iter().map(|&l| nodes[l]).collect();
                let xi = pts[i];
                let quad = [
                    xi,
                    scale(add(xi, pts[next]), 0.5),
                    centroid(&fnodes, pts),
                    scale(add(xi, pts[prev]), 0.5),
                ];
                *a = add(*a, loop_area(&quad));
            }
        }
    }
    area
}

#[test]
fn a_rows_own_boundary_faces_are_the_whole_meshs() {
    // generated boxes of every kind, and a fan: an apex over a 40 x 40 grid of triangles, so
    // that the apex's row has 1,600 columns (its triangles are told apart by a sorted list, not
    // the bitsets of a row of few columns)
    let mut meshes: Vec<Mesh> = [BoxCells::Tet, BoxCells::Hex, BoxCells::Wedge, BoxCells::PyramidTet]
        .into_iter()
        .map(|k| box_mesh([1.0, 0.8, 0.6], [5, 4, 3], k).unwrap())
        .collect();
    let mut fan = Mesh::new("fan");
    let n = 40;
    for y in 0..n {
        for x in 0..n {
            fan.points.push([x as f64, y as f64, 0.0]);
        }
    }
    fan.points.push([n as f64 / 2.0, n as f64 / 2.0, 5.0]);
    let apex = (n * n) as u32;
    let at = |x: usize, y: usize| (y * n + x) as u32;
    for y in 0..n - 1 {
        for x in 0..n - 1 {
            fan.push_cell(
                eprop_mesh::CellKind::Tet,
                &[at(x, y), at(x + 1, y), at(x, y + 1), apex],
                0,
            );
            fan.push_cell(
                eprop_mesh::CellKind::Tet,
                &[at(x + 1, y), at(x + 1, y + 1), at(x, y + 1), apex],
                0,
            );
        }
    }
    meshes.push(fan);
    for mesh in &meshes {
        let inc = Incidence::new(mesh);
        let dual = Dual::build(mesh, &inc, mesh.n_nodes(), None);
        let want = areas_from_boundary_faces(mesh);
        for (i, (a, b)) in dual.area.iter().zip(&want).enumerate() {
            assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "{}: A_{i}", mesh.source);
        }
    }
}
