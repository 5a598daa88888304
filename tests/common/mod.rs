#![allow(dead_code)]
//! Helpers shared by the integration tests.

use eprop::scenario::{Scenario, Setup};
use eprop::solver::Simulation;
use eprop_io::Mesh;
use std::path::{Path, PathBuf};

/// `../shared/meshes/tet/NAME`, or None (with a message) when the shared data is absent.
pub fn shared_mesh(name: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/meshes/tet")
        .join(name);
    if p.exists() {
        Some(p)
    } else {
        eprintln!(
            "skipped: {} not found (the shared organ meshes are not beside this checkout)",
            p.display()
        );
        None
    }
}

/// A scenario from text, resolved against a mesh already in memory.
pub fn setup(mesh: Mesh, toml: &str, dir: &Path) -> Setup {
    let path = dir.join("test.toml");
    let full = format!("[mesh]\nfile = \"unused.msh\"\n{toml}");
    let sc = Scenario::parse(&path, full).expect("scenario parses");
    Setup::with_mesh(sc, mesh).expect("scenario resolves")
}

pub fn sim(mesh: Mesh, toml: &str) -> Simulation {
    let dir = std::env::temp_dir();
    Simulation::new(setup(mesh, toml, &dir)).expect("simulation builds")
}

pub fn max_abs(v: &[[f64; 3]]) -> f64 {
    v.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()))
}
