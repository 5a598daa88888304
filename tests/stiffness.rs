//! Stiffness per tissue in the propagation (docs/model.md section 3): each cell's conductance
//! weighed by its Young's modulus E_c / E0 and each control volume's capacity by E_i / E0, so
//! that the steady potential solves div(E R grad phi) = 0 while the transient keeps its speed.

mod common;

use eprop::discretize::geometry::{compact_coefficients, Dual, Incidence};
use eprop::discretize::operator::Operator;
use eprop::propagate::integrate::stability::hash_unit;
use eprop::simulate::Simulation;
use eprop_io::generate::{box_mesh, BoxCells};
use eprop_mesh::Mesh;

const PAPER_SCHEME: &str = "[model]\nscheme = \"paper\"\nintegrator = \"euler\"\n";
const COMPACT: &str = "[model]\nintegrator = \"euler\"\n";

/// A region of young `young` (the paper reading's [tissue] young is 100) on the half x >= at.
fn stiff_half(at: f64, young: f64) -> String {
    format!(
        "[[material.region]]\nhalfspace = {{ point = [{at}, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }}\nyoung = {young}\n"
    )
}

fn build(mesh: Mesh, model: &str, extra: &str) -> Simulation {
    common::sim(
        mesh,
        &format!("{model}[material]\nconductivity = 1.0\n{extra}[[fixed]]\ngroup = \"xmin\"\n[time]\nsteps = 1\n"),
    )
}

/// The steady potential's x component (explicit Euler substeps to a standstill) of a bar fixed at
/// x = 0 into which a flux of density 1 enters through the face x = 1 (node i of that face
/// gets Q_i = |A_i| / C_i, so that C_i Q_i = |A_i|): in each tissue phi_x = x / (E/E0) on the far
/// side of the interface, continuous flux (E/E0) d phi / dx = 1.
fn bar_steady(model: &str, extra: &str) -> (Vec<[f64; 3]>, Vec<f64>) {
    let mesh = box_mesh([1.0, 0.2, 0.2], [20, 2, 2], BoxCells::Tet).unwrap();
    let s = build(mesh, model, extra);
    let n = s.n_owned();
    let points: Vec<[f64; 3]> = (0..n).map(|i| s.setup().mesh.points[i]).collect();
    let cap = s.capacities().to_vec();
    let q: Vec<(u32, [f64; 3])> = (0..n)
        .filter(|&i| (points[i][0] - 1.0).abs() < 1e-12)
        .map(|i| {
            let a = s.dual().area[i];
            (i as u32, [a[0].abs() / cap[i], 0.0, 0.0])
        })
        .collect();
    let h = s.step_plan().h;
    let mut prop = s.into_propagation();
    let mut steps = 0;
    loop {
        let before = prop.phi.clone();
        for _ in 0..500 {
            prop.substep(h, &q);
        }
        steps += 500;
        let change = prop
            .phi
            .iter()
            .zip(&before)
            .map(|(a, b)| (a[0] - b[0]).abs())
            .fold(0.0, f64::max);
        if change < 1e-14 * common::max_abs(&prop.phi) || steps > 2_000_000 {
            break;
        }
    }
    let phi: Vec<f64> = prop.phi.owned().iter().map(|p| p[0]).collect();
    (points, phi)
}

/// The mean slope d phi / dx between the node planes x = a and x = b.
fn slope(points: &[[f64; 3]], phi: &[f64], a: f64, b: f64) -> f64 {
    let mean = |x: f64| {
        let v: Vec<f64> = (0..phi.len())
            .filter(|&i| (points[i][0] - x).abs() < 1e-9)
            .map(|i| phi[i])
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    (mean(b) - mean(a)) / (b - a)
}

#[test]
fn a_stiff_half_carries_the_same_flux_with_a_gradient_smaller_by_its_young() {
    // homogeneous: the slope 1 everywhere (compact: exact on this linear field; the paper
    // scheme's nodal gradients at the loaded face give 0.9973), then a half ten times stiffer:
    // the layer of cells with nodes in both tissues is not uniform across the bar (a
    // tetrahedron there has one to three stiff nodes), which bends the potential near it
    // (compact 2.3e-4; the paper scheme, whose nodal gradients mix both sides, 1.3e-3)
    for (model, exact, tol) in [(COMPACT, 1e-12, 1e-3), (PAPER_SCHEME, 5e-3, 1e-2)] {
        let (points, phi) = bar_steady(model, "");
        let all = slope(&points, &phi, 0.1, 0.9);
        assert!((all - 1.0).abs() < exact, "{model}: homogeneous slope {all}");
        let (points, phi) = bar_steady(model, &stiff_half(0.5, 1000.0));
        let (soft, stiff) = (slope(&points, &phi, 0.1, 0.4), slope(&points, &phi, 0.6, 0.9));
        println!("{model}: slopes {soft} (soft) and {stiff} (stiff), {all} homogeneous");
        // the same flux density in both halves: (E/E0) d phi / dx the same with E/E0 = 1 and 10
        assert!(
            (soft / all - 1.0).abs() < tol && (10.0 * stiff / all - 1.0).abs() < tol,
            "{model}: slopes {soft} (soft) and {stiff} (stiff), {all} homogeneous: E1 g1 = {soft}, E2 g2 = {}",
            10.0 * stiff
        );
    }
}

/// The coefficients of the operator of `sim` (compact: c_ij; paper: the flux arrays and the
/// inverse capacities), as bits.
fn operator_bits(s: &Simulation) -> Vec<u64> {
    match &s.prop().op {
        Operator::Compact(c) => {
            let a = c.coefficients();
            let mut v: Vec<u64> = a.ptr().iter().map(|&x| x as u64).collect();
            v.extend(a.col().iter().map(|&x| x as u64));
            v.extend((0..a.col().len()).map(|p| c.c(p).to_bits()));
            v
        }
        Operator::Paper(p) => {
            let mut v: Vec<u64> = p.col.iter().map(|&x| x as u64).collect();
            for arr in [&p.s, &p.ris, &p.rjs, &p.e] {
                v.extend(arr.iter().flatten().map(|x| x.to_bits()));
            }
            v.extend(p.c.iter().chain(&p.inv_vol).chain(&p.inv_cap).map(|x| x.to_bits()));
            v
        }
    }
}

#[test]
fn a_uniform_young_leaves_the_operator_bit_for_bit() {
    let mesh = || box_mesh([1.0, 0.6, 0.4], [6, 4, 3], BoxCells::Tet).unwrap();
    for model in [COMPACT, PAPER_SCHEME] {
        let plain = build(mesh(), model, "");
        let want = operator_bits(&plain);
        assert_eq!(plain.capacities(), plain.volumes());
        // a region with the scenario's young, and one that gives every node another young
        for extra in [stiff_half(0.5, 100.0), stiff_half(-1.0, 5000.0)] {
            let s = build(mesh(), model, &extra);
            assert!(operator_bits(&s) == want, "{model}{extra}: the operator changed");
            assert_eq!(s.capacities(), s.volumes(), "{model}{extra}");
            assert_eq!(s.step_plan().h_bound.to_bits(), plain.step_plan().h_bound.to_bits());
        }
    }
}

/// A region 1000 times stiffer than the rest keeps the explicit substep: the capacities weigh
/// as the conductances do, so the operator's rows stay mediants of the unweighted cells'. The
/// compact bound (Gershgorin) is the homogeneous one; the paper scheme's bound (power iteration,
/// then a growth check that shrinks it by 0.8 at a time) can come out lower, but the operator
/// itself stays stable at 0.95 of the homogeneous bound: forward Euler at that substep from a
/// random start does not grow.
#[test]
fn a_stiffer_region_keeps_the_substep() {
    let mesh = || box_mesh([1.0, 0.6, 0.4], [10, 6, 4], BoxCells::Tet).unwrap();
    for model in [COMPACT, PAPER_SCHEME] {
        let plain = build(mesh(), model, "").step_plan().h_bound;
        for at in [0.5, 0.55] {
            let s = build(mesh(), model, &stiff_half(at, 1e5));
            let bound = s.step_plan().h_bound;
            let active = s.active().to_vec();
            let mut prop = s.into_propagation();
            for (k, p) in prop.phi.owned_mut().iter_mut().enumerate() {
                if active[k] {
                    *p = [
                        hash_unit(3 * k as u64),
                        hash_unit(3 * k as u64 + 1),
                        hash_unit(3 * k as u64 + 2),
                    ];
                }
            }
            let start = common::max_abs(&prop.phi);
            let mut sizes = Vec::new();
            for _ in 0..4 {
                prop.substeps(0.95 * plain, &[], 2500);
                sizes.push(common::max_abs(&prop.phi));
            }
            println!(
                "{}: stiff region from x = {at}: bound {bound:e} against {plain:e} homogeneous; max |phi| {start:.3} then {sizes:.3?} every 2500 substeps at 0.95 of the homogeneous bound",
                model.lines().nth(1).unwrap()
            );
            assert!(
                sizes.windows(2).all(|w| w[1] <= w[0]) && sizes[0] < start,
                "{model}: grows at 0.95 of the homogeneous bound: {sizes:?}"
            );
            let want = if model == COMPACT { 0.999 } else { 0.4 };
            assert!(
                bound > want * plain && bound < 1.001 * plain,
                "{model}: a 1000x stiffer region moved the bound from {plain:e} to {bound:e}"
            );
        }
    }
}

/// CG with Jacobi on the SPD system sum_j a_ij (x_i - x_j) = b_i of the free nodes.
fn solve(a: &[f64], ptr: &[usize], col: &[u32], free: &[bool], b: &[f64]) -> Vec<f64> {
    let n = b.len();
    let diag: Vec<f64> = (0..n)
        .map(|i| {
            if free[i] {
                (ptr[i]..ptr[i + 1]).map(|p| a[p]).sum()
            } else {
                1.0
            }
        })
        .collect();
    let apply = |x: &[f64], y: &mut [f64]| {
        for i in 0..n {
            y[i] = if free[i] {
                (ptr[i]..ptr[i + 1])
                    .map(|p| a[p] * (x[i] - if free[col[p] as usize] { x[col[p] as usize] } else { 0.0 }))
                    .sum()
            } else {
                0.0
            };
        }
    };
    let dot = |u: &[f64], v: &[f64]| u.iter().zip(v).map(|(x, y)| x * y).sum::<f64>();
    let mut x = vec![0.0; n];
    let mut r: Vec<f64> = (0..n).map(|i| if free[i] { b[i] } else { 0.0 }).collect();
    let mut z: Vec<f64> = (0..n).map(|i| r[i] / diag[i]).collect();
    let mut p = z.clone();
    let mut ap = vec![0.0; n];
    let mut rz = dot(&r, &z);
    let b2 = dot(&r, &r);
    for _ in 0..20_000 {
        apply(&p, &mut ap);
        let alpha = rz / dot(&p, &ap);
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
        }
        if dot(&r, &r) < 1e-20 * b2 {
            break;
        }
        for i in 0..n {
            z[i] = r[i] / diag[i];
        }
        let rz2 = dot(&r, &z);
        for i in 0..n {
            p[i] = z[i] + rz2 / rz * p[i];
        }
        rz = rz2;
    }
    x
}

/// The head atlas (scalp 1, skull 3, ...; ../shared/meshes/SOURCES.md) with its base fixed and
/// a flux load through the scalp at the top of the head: the skull under the load reaches a
/// lower steady potential (u = kappa phi / k moves it less) when it is 1000 times stiffer than
/// the rest of the head than when the head is homogeneous.
#[test]
fn a_stiff_skull_moves_less_under_a_load_on_the_scalp() {
    let Some(path) = common::shared_mesh("mmc_head_atlas.vtu") else {
        return;
    };
    let mesh = eprop_io::read_mesh(&path).unwrap();
    let (lo, hi) = mesh.bounds();
    let n = mesh.n_nodes();
    let base = format!(
        "[[fixed]]\nbox = [[-1e9, -1e9, -1e9], [1e9, 1e9, {}]]\n[time]\nsteps = 1\n",
        lo[2] + 0.1 * (hi[2] - lo[2])
    );
    let skull_tag = 3;
    let on_skull: Vec<bool> = {
        let mut v = vec![false; n];
        for c in 0..mesh.n_cells() {
            if mesh.cell_tags[c] == skull_tag {
                for &k in mesh.cell(c) {
                    v[k as usize] = true;
                }
            }
        }
        v
    };
    let inc = Incidence::new(&mesh);
    let dual = Dual::build(&mesh, &inc, n, None);
    // the contact: the boundary nodes within 10 mm of the topmost node
    let top = (0..n)
        .max_by(|&a, &b| mesh.points[a][2].total_cmp(&mesh.points[b][2]))
        .unwrap();
    let dist = |i: usize| {
        let (p, t) = (mesh.points[i], mesh.points[top]);
        ((p[0] - t[0]).powi(2) + (p[1] - t[1]).powi(2) + (p[2] - t[2]).powi(2)).sqrt()
    };
    let area = |i: usize| dual.area[i].iter().map(|x| x * x).sum::<f64>().sqrt();
    let b: Vec<f64> = (0..n)
        .map(|i| if dist(i) < 10.0 && area(i) > 0.0 { area(i) } else { 0.0 })
        .collect();
    let under: Vec<usize> = (0..n).filter(|&i| on_skull[i] && dist(i) < 25.0).collect();
    assert!(under.len() > 10, "{} skull nodes within 25 mm of the top", under.len());
    let mut means = Vec::new();
    for extra in ["", "[[material.region]]\ntag = 3\nyoung = 1e5\n"] {
        let setup = common::setup(mesh.clone(), &format!("{extra}{base}"), &std::env::temp_dir());
        let a = compact_coefficients(&mesh, &inc, &dual, &setup.materials);
        let free: Vec<bool> = (0..n).map(|i| !setup.fixed[i] && dual.vol[i] > 0.0).collect();
        let phi = solve(&a, &dual.row_ptr, &dual.col, &free, &b);
        means.push(under.iter().map(|&i| phi[i]).sum::<f64>() / under.len() as f64);
    }
    println!(
        "head atlas: mean steady potential of the {} skull nodes within 25 mm of the load: {:e} homogeneous, {:e} with a 1000x stiffer skull ({:.3}x)",
        under.len(),
        means[0],
        means[1],
        means[1] / means[0]
    );
    assert!(means[1] < 0.5 * means[0], "{means:?}");
}

/// A load's energy source in the continuum reading takes q(sigma) from the contact nodes' own
/// tissue law: a load on a region of young 8 kPa injects what it injects on a head of that
/// young throughout, not what the scenario's [tissue] young (4 kPa) would give.
#[test]
fn a_load_takes_the_energy_density_of_the_tissue_it_presses() {
    let sources = |extra: &str| {
        let mesh = box_mesh([0.1, 0.1, 0.1], [4, 4, 4], BoxCells::Tet).unwrap();
        let toml = format!(
            "unit = \"m\"\n[model]\nreading = \"continuum\"\nintegrator = \"euler\"\n{extra}[[fixed]]\ngroup = \"zmin\"\n[[load]]\npatch = {{ center = [0.05, 0.05, 0.1], radius = 0.02 }}\nnormal = 0.5\n[time]\nsteps = 1\n"
        );
        let mut s = common::sim(mesh, &toml);
        let mut q = s.sources(0.0);
        q.sort_by_key(|x| x.0);
        q
    };
    let region = sources("[[material.region]]\nbox = [[-1, -1, 0.07], [1, 1, 1]]\nyoung = 8000\n");
    let stiff = sources("[tissue]\nyoung = 8000\n");
    let soft = sources("");
    assert!(!region.is_empty());
    assert_eq!(region, stiff);
    // linear law: q = sigma^2 / (2 E), half as much at twice the young
    for (a, b) in region.iter().zip(&soft) {
        assert!((a.1[2] / b.1[2] - 0.5).abs() < 1e-12, "{a:?} against {b:?}");
    }
}

/// rkl2 and implicit weigh their symmetric forms by the capacities: with a half 100 times
/// stiffer they follow euler (phi and u to 1e-3 of their size over ten steps, the integrators'
/// accuracy; measured 3.9e-5 and 3.4e-5).
#[test]
fn every_integrator_follows_euler_with_a_stiff_region() {
    let mesh = box_mesh([1.0, 0.5, 0.5], [8, 4, 4], BoxCells::Tet).unwrap();
    let base = format!(
        "[material]\nconductivity = 0.3\n{}[[fixed]]\ngroup = \"xmin\"\n[[load]]\npatch = {{ center = [1.0, 0.25, 0.25], radius = 0.2 }}\nnormal = 1.0\n[time]\nsteps = 10\n",
        stiff_half(0.5, 1e4)
    );
    let run = |kind: &str| {
        let mut s = common::sim(mesh.clone(), &format!("[model]\nintegrator = \"{kind}\"\n{base}"));
        assert_eq!(s.step_plan().integrator.name(), kind);
        for _ in 0..10 {
            s.advance().unwrap();
        }
        (s.phi().owned().to_vec(), s.u().owned().to_vec())
    };
    let rel = |a: &[[f64; 3]], b: &[[f64; 3]]| {
        let d: f64 = a
            .iter()
            .zip(b)
            .flat_map(|(x, y)| (0..3).map(move |k| (x[k] - y[k]).powi(2)))
            .sum();
        let n: f64 = b.iter().flatten().map(|x| x * x).sum();
        (d / n).sqrt()
    };
    let (pe, ue) = run("euler");
    for kind in ["rkl2", "implicit"] {
        let (p, u) = run(kind);
        let (dp, du) = (rel(&p, &pe), rel(&u, &ue));
        println!("{kind}: phi {dp:.2e}, u {du:.2e} from euler's");
        assert!(dp < 1e-3 && du < 1e-3, "{kind}: phi {dp:e}, u {du:e} from euler's");
    }
}
