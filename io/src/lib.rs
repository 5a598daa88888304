//! eprop-io: meshes in (readers) and out (writers); no HDF5, no MPI (the output series is
//! `eprop-series`, in `io/series`).
//!
//! Readers: Gmsh `.msh` (1, 2.2, 4.1; ASCII and binary), VTK legacy `.vtk`, VTK XML `.vtu`,
//! TetGen `.node`/`.ele`/`.face`, Medit `.mesh`. Each has a `parse` function on bytes; every
//! mesh read through `read_mesh` goes through one validation pass (`validate`).
//!
//! The mesh itself, its geometry, the validation pass and the generators live in `eprop-mesh`
//! (no HDF5, no MPI) and are re-exported here under the same paths (`eprop_io::mesh`,
//! `eprop_io::geom`, `eprop_io::generate`, `eprop_io::validate`, `eprop_io::Mesh`, ...).

pub mod gmsh;
pub mod input;
pub mod medit;
pub mod scan;
#[cfg(feature = "test-writers")]
pub mod testwrite;
pub mod tetgen;
pub mod vtk;
pub mod vtu;

pub use eprop_mesh::{generate, geom, mesh, validate, CellKind, Mesh, ReadOptions};
pub use input::{read_input_file, read_input_text};

use anyhow::{bail, Result};
use std::path::Path;

/// The mesh formats eprop reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Gmsh,
    VtkLegacy,
    Vtu,
    TetGen,
    Medit,
}

impl Format {
    /// The format of a file name, by extension.
    pub fn of(path: &Path) -> Option<Format> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        Some(match ext.as_str() {
            "msh" => Format::Gmsh,
            "vtk" => Format::VtkLegacy,
            "vtu" => Format::Vtu,
            "node" | "ele" | "face" => Format::TetGen,
            "mesh" => Format::Medit,
            _ => return None,
        })
    }
}

/// Parses a mesh held in memory (no validation). TetGen bytes are a bundle
/// (see `tetgen::parse_bundle`).
pub fn parse_mesh(format: Format, name: &str, bytes: &[u8]) -> Result<Mesh> {
    match format {
        Format::Gmsh => gmsh::parse_bytes(name, bytes),
        Format::VtkLegacy => vtk::parse(name, bytes),
        Format::Vtu => vtu::parse(name, bytes),
        Format::TetGen => tetgen::parse_bundle(name, bytes),
        Format::Medit => medit::parse(name, bytes),
    }
}

/// Reads a mesh file, choosing the reader by extension, and validates it (not strict).
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    read_mesh_with(path, &ReadOptions::default())
}

/// Reads a mesh file, choosing the reader by extension, and validates it.
pub fn read_mesh_with(path: &Path, opts: &ReadOptions) -> Result<Mesh> {
    let Some(format) = Format::of(path) else {
        bail!(
            "{}: unknown mesh format; fix: eprop reads Gmsh .msh, VTK .vtk and .vtu, TetGen .node/.ele, Medit .mesh",
            path.display()
        );
    };
    if format == Format::TetGen {
        let base = path.with_extension("").display().to_string();
        // a link or special file in its place is not missing: reading it says what it is
        let missing = |ext: &str| std::fs::symlink_metadata(format!("{base}.{ext}")).is_err();
        if missing("ele") || missing("node") {
            bail!(
                "{}: no such mesh file (TetGen needs x.node and x.ele side by side); fix: check the path",
                path.display()
            );
        }
    }
    let mut mesh = match format {
        Format::TetGen => tetgen::read(path)?,
        _ => {
            let bytes = read_input_file(path, "mesh")?;
            parse_mesh(format, &path.display().to_string(), &bytes)?
        }
    };
    validate(&mut mesh, opts)?;
    Ok(mesh)
}

/// Every file `read_mesh` reads for `path`: the file itself, or a TetGen mesh's `.node`,
/// `.ele` and `.face` (so that writers can refuse to replace any of them).
pub fn mesh_files(path: &Path) -> Vec<std::path::PathBuf> {
    if Format::of(path) != Some(Format::TetGen) {
        return vec![path.to_path_buf()];
    }
    let base = path.with_extension("").display().to_string();
    ["node", "ele", "face"]
        .iter()
        .map(|ext| std::path::PathBuf::from(format!("{base}.{ext}")))
        .collect()
}

/// Writes a mesh, choosing the writer by extension: Gmsh 4.1 `.msh` or `.vtu`.
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
