//! The two propagation schemes: exactness, symmetry, conservation of constants, stability,
//! and the steady state against a direct solve.

mod common;

use common::{max_abs, sim};
use eprop::config::tissue::{Materials, Tensor};
use eprop::config::PAPER_TISSUE;
use eprop::discretize::geometry::{compact_coefficients, Dual, Incidence};
use eprop::discretize::operator::Operator;
use eprop::propagate::integrate::stability::hash_unit;
use eprop_io::generate::{box_mesh, cylinder_mesh, BoxCells};
use eprop_mesh::Mesh;
use nalgebra::Vector3;

fn tensors() -> Vec<Tensor> {
    vec![
        Tensor::identity() * 0.05,
        Tensor::from_diagonal(&Vector3::new(0.08, 0.05, 0.05)),
        Tensor::new(0.3, 0.05, -0.02, 0.05, 0.2, 0.04, -0.02, 0.04, 0.1),
    ]
}

/// sum_j a_ij (u_j - u_i) must equal the exact boundary flux -(R g).A_i for linear u = g.x.
fn check_compact_linear_exactness(mesh: &Mesh) {
    let n = mesh.n_nodes();
    let inc = Incidence::new(mesh);
    let dual = Dual::build(mesh, &inc, n, None);
    for r in tensors() {
        let a = compact_coefficients(
            mesh,
            &inc,
            &dual,
            &Materials::with_conductivities(&vec![r; n], PAPER_TISSUE),
        );
        for g in [[1.0, 0.0, 0.0], [0.3, -1.2, 0.7]] {
            let u: Vec<f64> = mesh
                .points
                .iter()
                .map(|p| 0.4 + g[0] * p[0] + g[1] * p[1] + g[2] * p[2])
                .collect();
            let rg = r * Vector3::from(g);
            let mut worst = 0.0f64;
            for i in 0..n {
                let mut flux = 0.0;
                let mut scale = 0.0;
                for p in dual.row_ptr[i]..dual.row_ptr[i + 1] {
                    flux += a[p] * (u[dual.col[p] as usize] - u[i]);
                    scale += (a[p] * (u[dual.col[p] as usize] - u[i])).abs();
                }
                let ai = dual.area[i];
                let exact = -(rg[0] * ai[0] + rg[1] * ai[1] + rg[2] * ai[2]);
                worst = worst.max((flux - exact).abs() / (scale + exact.abs() + 1e-300));
            }
            assert!(
                worst < 1e-12,
                "{}: compact not exact on a linear field (rel {worst:e})",
                mesh.source
            );
        }
    }
}

#[test]
fn compact_is_exact_on_linear_fields() {
    check_compact_linear_exactness(&cylinder_mesh(1.0, 4.0, 3, 11).unwrap());
    check_compact_linear_exactness(&box_mesh([1.0, 0.7, 1.3], [4, 3, 5], BoxCells::Tet).unwrap());
    check_compact_linear_exactness(&box_mesh([1.0, 0.7, 1.3], [3, 3, 2], BoxCells::Hex).unwrap());
    check_compact_linear_exactness(&box_mesh([1.0, 0.7, 1.3], [3, 2, 2], BoxCells::Wedge).unwrap());
    check_compact_linear_exactness(&box_mesh([1.0, 0.7, 1.3], [3, 2, 2], BoxCells::PyramidTet).unwrap());
    if let Some(p) = common::shared_mesh("sofa_liver2.msh") {
        check_compact_linear_exactness(&eprop_io::read_mesh(&p).unwrap());
    }
}

#[test]
fn compact_is_symmetric_on_tetrahedra() {
    let mesh = cylinder_mesh(1.0, 4.0, 3, 11).unwrap();
    let n = mesh.n_nodes();
    let inc = Incidence::new(&mesh);
    let dual = Dual::build(&mesh, &inc, n, None);
    // heterogeneous: per-node tensors differ, the cell mean keeps the operator symmetric
    let r: Vec<Tensor> = (0..n).map(|i| tensors()[i % 3]).collect();
    let a = compact_coefficients(&mesh, &inc, &dual, &Materials::with_conductivities(&r, PAPER_TISSUE));
    for i in 0..n {
        for p in dual.row_ptr[i]..dual.row_ptr[i + 1] {
            let j = dual.col[p] as usize;
            let q = (dual.row_ptr[j]..dual.row_ptr[j + 1])
                .find(|&q| dual.col[q] as usize == i)
                .unwrap();
            assert_eq!(a[p], a[q], "a_ij != a_ji at ({i},{j})");
        }
    }
}

const PAPER: &str = "[model]\nreading = \"paper\"\nscheme = \"paper\"\n";
const PAPER_RAW: &str = "[model]\nreading = \"paper\"\nscheme = \"paper\"\npaper_correction = false\n";
const BASE: &str =
    "[[fixed]]\ngroup = \"bottom\"\n[[load]]\nnearest = [1.0, 0.0, 2.0]\nnormal = 1.0\n[time]\nsteps = 5\n";

#[test]
fn paper_scheme_annihilates_constants() {
    const BOX: &str =
        "[[fixed]]\ngroup = \"zmin\"\n[[load]]\nnearest = [0.5, 0.5, 1.0]\nnormal = 1.0\n[time]\nsteps = 5\n";
    let meshes = || {
        [
            (cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), BASE),
            (box_mesh([1.0, 1.0, 1.0], [3, 3, 2], BoxCells::Hex).unwrap(), BOX),
            (box_mesh([1.0, 1.0, 1.0], [3, 3, 2], BoxCells::Wedge).unwrap(), BOX),
            (box_mesh([1.0, 1.0, 1.0], [3, 3, 2], BoxCells::PyramidTet).unwrap(), BOX),
        ]
    };
    for model in [PAPER, PAPER_RAW] {
        for (mesh, base) in meshes() {
            let what = mesh.source.clone();
            let mut prop = sim(mesh.clone(), &format!("{model}{base}")).into_propagation();
            let n = prop.phi.len();
            let c = vec![[1.5, -2.0, 0.25]; n];
            let mut y = vec![[9.0; 3]; n];
            prop.apply(&c, &mut y);
            let m = max_abs(&y);
            assert!(m < 1e-12, "{what}: paper scheme: L(constant) = {m:e}");
            // and it runs: the load deforms the mesh, nothing blows up
            let mut s = sim(mesh, &format!("{model}{base}"));
            for _ in 0..5 {
                s.advance().unwrap();
            }
            let u = max_abs(s.u());
            assert!(u > 0.0 && u.is_finite(), "{what}: max |u| = {u}");
        }
    }
}

/// Drives the potential with the scenario's load, then switches the source off: max |phi|
/// must never grow again, at every substep.
fn check_no_growth(model: &str) {
    let mut s = sim(cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), &format!("{model}{BASE}"));
    for _ in 0..10 {
        s.advance().unwrap();
    }
    let h = s.step_plan().h;
    let mut prop = s.into_propagation();
    let mut prev = max_abs(&prop.phi);
    assert!(prev > 0.0);
    for k in 0..3000 {
        prop.substep(h, &[]);
        let m = max_abs(&prop.phi);
        assert!(
            m <= prev * (1.0 + 1e-12),
            "{model}: max |phi| grew at substep {k}: {prev:e} -> {m:e}"
        );
        prev = m;
    }
}

#[test]
fn no_scheme_grows_the_potential_without_source() {
    check_no_growth("");
    check_no_growth(PAPER);
    check_no_growth(PAPER_RAW);
}

#[test]
fn compact_keeps_a_maximum_principle_on_random_data() {
    // Kuhn-split boxes give non-negative couplings: max |phi| cannot grow from any start
    let mesh = box_mesh([1.0, 1.0, 1.0], [5, 5, 5], BoxCells::Tet).unwrap();
    let s = sim(mesh, "[[fixed]]\ngroup = \"xmin\"\n[time]\nsteps = 1\n");
    let (n, h, active) = (s.u().len(), s.step_plan().h, s.active().to_vec());
    let mut prop = s.into_propagation();
    for i in 0..n {
        if active[i] {
            prop.phi[i] = [
                hash_unit(i as u64),
                hash_unit(7 * i as u64 + 1),
                hash_unit(13 * i as u64 + 2),
            ];
        }
    }
    let mut prev = max_abs(&prop.phi);
    for _ in 0..500 {
        prop.substep(h, &[]);
        let m = max_abs(&prop.phi);
        assert!(m <= prev * (1.0 + 1e-14));
        prev = m;
    }
    assert!(prev < 0.5, "the potential did not decay ({prev})");
}

#[test]
fn substep_above_the_bound_is_refused() {
    let base = sim(cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), BASE);
    let dir = std::env::temp_dir();
    for (model, bound) in [
        ("", base.step_plan().h_bound),
        (
            PAPER,
            sim(cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), &format!("{PAPER}{BASE}"))
                .step_plan()
                .h_bound,
        ),
    ] {
        let toml = format!("{model}{BASE}h = {}\n", 1.5 * bound);
        let setup = common::setup(cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), &toml, &dir);
        let err = eprop::simulate::Simulation::new(setup)
            .err()
            .expect("h above the bound must be refused")
            .to_string();
        assert!(err.contains("above the stability bound"), "{err}");
        // and a value below the bound is taken
        let ok = format!("{model}{BASE}h = {}\n", 0.5 * bound);
        let s = eprop::simulate::Simulation::new(common::setup(cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), &ok, &dir))
            .unwrap();
        assert!(s.step_plan().h <= 0.5 * bound);
    }
}

/// Conjugate gradients on K x = b, K the SPD stiffness of the compact operator on free nodes.
fn cg(apply: impl Fn(&[f64], &mut [f64]), b: &[f64]) -> Vec<f64> {
    let n = b.len();
    let mut x = vec![0.0; n];
    let mut r = b.to_vec();
    let mut p = r.clone();
    let mut ap = vec![0.0; n];
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let mut rr = dot(&r, &r);
    let b2 = rr;
    for _ in 0..10 * n {
        apply(&p, &mut ap);
        let alpha = rr / dot(&p, &ap);
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
        }
        let rr2 = dot(&r, &r);
        if rr2 < 1e-30 * b2 {
            break;
        }
        for i in 0..n {
            p[i] = r[i] + rr2 / rr * p[i];
        }
        rr = rr2;
    }
    x
}

#[test]
fn steady_state_matches_a_direct_solve() {
    let mesh = box_mesh([1.0, 0.5, 0.5], [8, 4, 4], BoxCells::Tet).unwrap();
    let toml = "[material]\nconductivity = [1.0, 0.6, 0.8]\n[[fixed]]\ngroup = \"xmin\"\n[[load]]\nnearest = [1.0, 0.25, 0.25]\nforce = [1.0, 0.5, -0.3]\n[time]\nsteps = 1\n";
    let s = sim(mesh, toml);
    let n = s.u().len();
    let c = s.local(s.loads()[0].nodes[0]).unwrap();
    let (h, vol, active) = (s.step_plan().h, s.volumes().to_vec(), s.active().to_vec());
    let mut prop = s.into_propagation();
    let qv = [0.7, -0.2, 0.4];
    let q = vec![(c as u32, qv)];
    // explicit Euler to steady state
    let mut steps = 0;
    loop {
        let before = prop.phi.clone();
        for _ in 0..200 {
            prop.substep(h, &q);
        }
        steps += 200;
        let change = prop
            .phi
            .iter()
            .zip(&before)
            .map(|(a, b)| (a[0] - b[0]).abs().max((a[1] - b[1]).abs()).max((a[2] - b[2]).abs()))
            .fold(0.0, f64::max);
        if change < 1e-15 * max_abs(&prop.phi) || steps > 400_000 {
            break;
        }
    }
    // direct: sum_j a_ij (phi_j - phi_i) = -V_i Q_i on free nodes, phi = 0 on the fixed face
    let Operator::Compact(op) = &prop.op else { panic!() };
    let free: Vec<usize> = (0..n).filter(|&i| active[i]).collect();
    let mut pos = vec![usize::MAX; n];
    for (k, &i) in free.iter().enumerate() {
        pos[i] = k;
    }
    let apply = |x: &[f64], y: &mut [f64]| {
        for (k, &i) in free.iter().enumerate() {
            let mut acc = 0.0;
            for p in op.coefficients().row(i) {
                let j = op.col()[p] as usize;
                let xj = if pos[j] == usize::MAX { 0.0 } else { x[pos[j]] };
                acc += op.c(p) * vol[i] * (xj - x[k]);
            }
            y[k] = -acc;
        }
    };
    for d in 0..3 {
        let b: Vec<f64> = free
            .iter()
            .map(|&i| if i == c { vol[i] * qv[d] } else { 0.0 })
            .collect();
        let x = cg(apply, &b);
        let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (k, &i) in free.iter().enumerate() {
            let diff = (prop.phi[i][d] - x[k]).abs();
            assert!(
                diff < 1e-8 * scale,
                "component {d}, node {i}: explicit {} vs direct {} after {steps} substeps",
                prop.phi[i][d],
                x[k]
            );
        }
    }
}

/// The vector kernel (AVX2 + FMA) and the portable one each compute the step of a reference
/// sum written here from the CSR arrays, up to rounding, on every row, including the last
/// node (read through the masked path); and they are two kernels: their bits differ on some
/// row (FMA and four partial sums against two). Without AVX2+FMA there is no vector kernel to
/// test: a skip (a failure under EPROP_REQUIRE_ALL=1).
#[test]
fn vector_and_portable_kernels_agree() {
    use eprop::discretize::operator::{Kernel, Operator};
    if !eprop::discretize::operator::simd_available() {
        common::skip("no AVX2+FMA on this CPU: there is no vector kernel to compare with the portable one");
        return;
    }
    let s = sim(cylinder_mesh(1.0, 4.0, 3, 11).unwrap(), BASE);
    let h = s.step_plan().h;
    let mut prop = s.into_propagation();
    let n = prop.phi.len();
    let x: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            let t = i as f64;
            [(0.37 * t).sin(), (0.11 * t).cos() + 2.0, 1e-3 * t]
        })
        .collect();
    let rows = prop.op.n_rows();
    assert!(rows > 100, "rows to compare");
    // the reference: x_i + h sum_j c_ij (x_j - x_i), pair by pair in row order
    let want: Vec<[f64; 3]> = {
        let Operator::Compact(c) = &prop.op else {
            panic!("the base scenario runs the compact scheme")
        };
        (0..rows)
            .map(|i| {
                let mut l = [0.0; 3];
                for p in c.coefficients().row(i) {
                    let j = c.col()[p] as usize;
                    for d in 0..3 {
                        l[d] += c.c(p) * (x[j][d] - x[i][d]);
                    }
                }
                [x[i][0] + h * l[0], x[i][1] + h * l[1], x[i][2] + h * l[2]]
            })
            .collect()
    };
    let mut out = vec![];
    for vector in [false, true] {
        if let Operator::Compact(c) = &mut prop.op {
            c.set_kernel(Kernel { vector });
        }
        let mut y = vec![[0.0; 3]; n];
        prop.op.step_rows(&x, &[], &mut y, h, 0..rows);
        for i in 0..rows {
            for d in 0..3 {
                let (a, b) = (want[i][d], y[i][d]);
                assert!(
                    (a - b).abs() <= 1e-13 * (1.0 + a.abs()),
                    "vector {vector}, row {i}: reference {a} vs {b}"
                );
            }
        }
        out.push(y);
    }
    let differ = (0..rows).filter(|&i| out[0][i] != out[1][i]).count();
    assert!(
        differ > 0,
        "the vector kernel gave the portable kernel's bits on every row: did it run?"
    );
}
