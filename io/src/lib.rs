//! eprop-io: meshes in (readers, generators), time series out (VTKHDF).

pub mod generate;
pub mod geom;
pub mod gmsh;
pub mod mesh;
pub mod tetgen;
pub mod vtkhdf;
pub mod vtu;

pub use mesh::{CellKind, Mesh};

use anyhow::{bail, Result};
use std::path::Path;

/// Reads a mesh file, choosing the reader by extension.
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    if !path.exists() {
        bail!("{}: no such mesh file; fix: check the path (relative paths in a scenario are relative to the scenario file)", path.display());
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "msh" => gmsh::read(path),
        "vtu" => vtu::read(path),
        "ele" | "node" => tetgen::read(path),
        _ => bail!(
            "{}: unknown mesh format `.{ext}`; fix: eprop reads Gmsh .msh (versions 1, 2.2, 4.1 ASCII), VTK .vtu and TetGen .node/.ele",
            path.display()
        ),
    }
}

/// Writes a mesh, choosing the writer by extension.
pub fn write_mesh(mesh: &Mesh, path: &Path) -> Result<()> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "msh" => gmsh::write(mesh, path),
        "vtu" => vtu::write(mesh, path),
        _ => bail!(
            "{}: eprop writes Gmsh 4.1 (.msh) and VTK XML (.vtu); fix: name the output FILE.msh or FILE.vtu",
            path.display()
        ),
    }
}
