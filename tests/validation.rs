//! The validation harness of docs/validation.md, without DOLFINx: the committed finite-element
//! reference (scenarios/validation/reference, made by scripts/fe_reference.py) is well formed
//! and physically plausible (force grows with depth, near Hertz at the shallowest depth, the
//! fixed bottom does not move, the top under the sphere follows it), and the validation
//! scenarios run and are compared with it by scripts/validate_compare.py.

mod common;

use std::path::{Path, PathBuf};

fn reference() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/validation/reference")
}

/// The header and the rows of a CSV file (no quoting in these files).
fn csv(name: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let p = reference().join(name);
    let text = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let header = lines.next().unwrap().split(',').map(str::to_string).collect::<Vec<_>>();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect::<Vec<_>>())
        .collect::<Vec<_>>();
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), header.len(), "{name}: row {} has {} fields", i + 1, r.len());
    }
    (header, rows)
}

fn num(s: &str) -> f64 {
    let v: f64 = s.parse().unwrap_or_else(|_| panic!("{s:?} is not a number"));
    assert!(v.is_finite(), "{s} is not finite");
    v
}

/// (indentation, force, contact radius) of a force curve.
fn curve(name: &str) -> Vec<[f64; 3]> {
    let (h, rows) = csv(name);
    assert_eq!(h, ["indentation_m", "force_N", "contact_radius_m"], "{name}");
    assert!(rows.len() >= 2, "{name}: {} rows", rows.len());
    rows.iter().map(|r| [num(&r[0]), num(&r[1]), num(&r[2])]).collect()
}

fn strictly_increasing(name: &str, c: &[[f64; 3]]) {
    for w in c.windows(2) {
        assert!(w[1][0] > w[0][0], "{name}: indentation {} after {}", w[1][0], w[0][0]);
        assert!(
            w[1][1] > w[0][1],
            "{name}: force {} at {} after {} at {}",
            w[1][1],
            w[1][0],
            w[0][1],
            w[0][0]
        );
    }
    for p in c {
        assert!(p[0] > 0.0 && p[0] <= 0.02, "{name}: indentation {} m", p[0]);
        assert!(p[1] > 0.0, "{name}: force {} N at {} m", p[1], p[0]);
        assert!(
            p[2] > 0.0 && p[2] < 0.02,
            "{name}: contact radius {} m at {} m",
            p[2],
            p[0]
        );
    }
}

#[test]
fn reference_force_curves_are_well_formed_and_monotone() {
    let fit = curve("force_centre.csv");
    let deep = curve("force_centre_deep.csv");
    let off = curve("force_offcentre.csv");
    strictly_increasing("force_centre.csv", &fit);
    strictly_increasing("force_centre_deep.csv", &deep);
    strictly_increasing("force_offcentre.csv", &off);
    // the deep press continues the fitted one, deeper than the fit reaches
    let (last, first) = (fit.last().unwrap(), deep[0]);
    assert!(first[0] > last[0] && first[1] > last[1], "{last:?} then {first:?}");
    assert!(
        fit.iter().any(|p| (p[0] - 4e-3).abs() < 1e-12),
        "the fit part reaches 4 mm"
    );
    assert!(
        deep.iter().any(|p| p[0] >= 5e-3),
        "the held-out press goes to 5 mm or deeper"
    );
    // Hertz at 0.5 mm (a half-space, small strain): F = 4/3 E/(1 - nu^2) sqrt(R) d^1.5; the
    // finite block and the large strain make the FE a little stiffer, never far off
    let p = fit
        .iter()
        .find(|p| (p[0] - 5e-4).abs() < 1e-12)
        .expect("a row at 0.5 mm");
    let hertz = 4.0 / 3.0 * 5e3 / (1.0 - 0.45f64 * 0.45) * 0.005f64.sqrt() * 5e-4f64.powf(1.5);
    let ratio = p[1] / hertz;
    assert!((0.9..1.25).contains(&ratio), "F(0.5 mm) / Hertz = {ratio}");
    // the off-centre press is near the centred one (8 mm off, 12 mm from the side)
    for q in &off {
        if let Some(c) = fit.iter().find(|c| (c[0] - q[0]).abs() < 1e-12) {
            assert!(
                (q[1] / c[1] - 1.0).abs() < 0.2,
                "off-centre {q:?} against centred {c:?}"
            );
        }
    }
}

#[test]
fn reference_lines_are_well_formed() {
    for (name, depths) in [
        ("lines_centre.csv", vec![0.5e-3, 1e-3, 2e-3, 3e-3, 4e-3, 5e-3, 6e-3]),
        ("lines_offcentre.csv", vec![1e-3, 2e-3, 3e-3, 4e-3]),
    ] {
        let (h, rows) = csv(name);
        assert_eq!(h, ["depth_m", "line", "x", "y", "z", "ux", "uy", "uz"], "{name}");
        let mut top_prev = 0.0;
        for d in depths {
            let at = |line: &str| {
                rows.iter()
                    .filter(|r| (num(&r[0]) - d).abs() < 1e-12 && r[1] == line)
                    .map(|r| r[2..].iter().map(|v| num(v)).collect::<Vec<_>>())
                    .collect::<Vec<_>>()
            };
            for line in ["surface", "middepth"] {
                let v = at(line);
                assert!(v.len() >= 21, "{name}: {line} at {d}: {} points", v.len());
            }
            let v = at("vertical");
            assert!(v.len() >= 11, "{name}: vertical at {d}: {} points", v.len());
            let (bottom, top) = (&v[0], v.last().unwrap());
            assert!(
                bottom[2] == 0.0 && top[2] == 0.02,
                "{name}: the vertical line runs z = 0 to 0.02"
            );
            assert!(
                bottom[3..].iter().all(|u| u.abs() < 1e-12),
                "{name}: the fixed bottom moves: {bottom:?}"
            );
            // the top under the sphere follows it: at most its depth (plus the penalty's
            // penetration), more than 80 % of it; deeper presses push it further
            let uz = top[5];
            assert!(
                uz < 0.0 && -uz <= d + 2e-5 && -uz > 0.8 * d,
                "{name}: uz {uz} at depth {d}"
            );
            assert!(uz < top_prev, "{name}: uz {uz} at {d} not below {top_prev}");
            top_prev = uz;
        }
    }
}

/// The validation scenarios pass `eprop check` without a warning and run (on a coarse block) and
/// scripts/validate_compare.py compares them with the reference: a row per reference depth.
#[test]
fn validation_scenarios_run_and_compare() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let py = root.join(".venv/bin/python");
    assert!(py.exists(), "{} is missing; fix: run scripts/setup.sh", py.display());
    let d = tempfile::tempdir().unwrap();
    let mesh = d.path().join("block.msh");
    let mesh_s = mesh.to_str().unwrap();
    let out = common::serial(
        &[
            "mesh",
            "box",
            "--size",
            "0.04,0.04,0.02",
            "--cells",
            "10,10,5",
            "--kind",
            "tet",
            "-o",
            mesh_s,
        ],
        1,
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for (case, rows) in [("centre", 12), ("offcentre", 8)] {
        let sc = d.path().join(format!("{case}.toml"));
        std::fs::copy(root.join(format!("scenarios/validation/{case}.toml")), &sc).unwrap();
        let s = sc.to_str().unwrap();
        let toml = std::fs::read_to_string(&sc).unwrap();
        assert!(
            toml.contains("reading = \"continuum\"") && toml.contains("unit = \"m\""),
            "{case}: the validation scenarios are in the continuum reading, in metres"
        );
        let out = common::serial(&["check", s], 1);
        assert!(out.status.success(), "{case}: {}", String::from_utf8_lossy(&out.stderr));
        // the continuum reading in SI: no warning about units, scales or the contact strain
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(!text.contains("warning"), "{case}: {text}");
        let h5 = d.path().join(format!("{case}.h5"));
        let out = common::serial(&["run", s, "-q", "-o", h5.to_str().unwrap()], 1);
        assert!(out.status.success(), "{case}: {}", String::from_utf8_lossy(&out.stderr));
        let cmp = d.path().join(case);
        let out = std::process::Command::new(&py)
            .arg(root.join("scripts/validate_compare.py"))
            .args([h5.to_str().unwrap(), "--reference", reference().to_str().unwrap()])
            .args(["--case", case, "--length", "1", "-o", cmp.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(out.status.success(), "{case}: {}", String::from_utf8_lossy(&out.stderr));
        let force = std::fs::read_to_string(cmp.join("force.csv")).unwrap();
        let lines: Vec<&str> = force.lines().collect();
        assert_eq!(lines[0], "indentation_m,force_fe_N,force_eprop_N,ratio,set");
        assert_eq!(lines.len() - 1, rows, "{case}: {force}");
        for l in &lines[1..] {
            let f: Vec<&str> = l.split(',').collect();
            // the press reaches every reference depth: eprop's force is a number at each
            assert!(f[2].parse::<f64>().unwrap().is_finite(), "{case}: {l}");
            // only the centred press to 4 mm is for fitting; the rest is predicted
            let depth: f64 = f[0].parse().unwrap();
            let fit = case == "centre" && depth <= 4e-3 + 1e-12;
            assert_eq!(f[4], if fit { "fit" } else { "predict" }, "{case}: {l}");
        }
        let summary = std::fs::read_to_string(cmp.join("summary.csv")).unwrap();
        assert!(summary.lines().count() > 3, "{case}: {summary}");
    }
}
