//! `[mesh]`: the mesh file, its length unit (or scale) and the strictness of the reader.

use super::{Reading, Scenario};
use anyhow::{anyhow, Result};
use eprop_mesh::Mesh;
use serde::de::Error;
use serde::{Deserialize, Deserializer, Serialize};

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct MeshSec {
    /// Relative to the scenario file.
    pub file: String,
    /// The length unit of the mesh file's coordinates: they are converted to metres on
    /// reading (docs/model.md).
    #[serde(default)]
    pub unit: Option<Unit>,
    /// Every coordinate is multiplied by this on reading: the factor from the file's unit to
    /// metres in the continuum reading (for units `unit` does not name), to the scenario's
    /// length unit in the paper reading. Not with `unit`.
    #[serde(default, deserialize_with = "scale")]
    pub scale: Option<f64>,
    /// Refuse inverted cells instead of reorienting them (as `eprop info --strict`).
    #[serde(default)]
    pub strict: bool,
}

/// A length unit of a mesh file.
#[derive(Deserialize, Serialize, Debug, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Unit {
    M,
    Cm,
    Mm,
    Um,
}

impl Unit {
    /// As the scenario spells it.
    pub fn name(self) -> &'static str {
        match self {
            Unit::M => "m",
            Unit::Cm => "cm",
            Unit::Mm => "mm",
            Unit::Um => "um",
        }
    }

    /// Metres per unit.
    pub fn metres(self) -> f64 {
        match self {
            Unit::M => 1.0,
            Unit::Cm => 1e-2,
            Unit::Mm => 1e-3,
            Unit::Um => 1e-6,
        }
    }
}

impl MeshSec {
    /// The factor every coordinate is multiplied by on reading: the unit's metres, the scale,
    /// or 1 in the paper reading without either. In the continuum reading a mesh without a
    /// unit is an error that names the fix; unit and scale together are one.
    pub fn factor(&self, reading: Reading) -> Result<f64, String> {
        match (self.unit, self.scale, reading) {
            (Some(_), Some(_), _) => Err(
                "[mesh] unit and scale both given; fix: keep `unit` (m, cm, mm or um), or `scale` alone for another unit (the factor to metres)"
                    .into(),
            ),
            (Some(u), None, _) => Ok(u.metres()),
            (None, Some(s), _) => Ok(s),
            (None, None, Reading::Paper) => Ok(1.0),
            (None, None, Reading::Continuum) => Err(
                "[mesh] unit is missing: the continuum reading (the default [model] reading) needs the length unit of the mesh file's coordinates; fix: add `unit = \"mm\"` (or \"m\", \"cm\", \"um\") to [mesh], or `scale = F` (F metres per file unit), or `reading = \"paper\"` in [model] for the paper's unit-free per-node reading"
                    .into(),
            ),
        }
    }
}

fn scale<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    let s = f64::deserialize(d)?;
    if s > 0.0 && s.is_finite() {
        Ok(Some(s))
    } else {
        Err(D::Error::custom(format!(
            "{} must be a positive number; fix: the factor from the mesh's length unit to the scenario's (1000 turns metres into mm)",
            crate::diagnostics::short(s)
        )))
    }
}

/// A VTKHDF mesh (`eprop convert MESH FILE.vtkhdf`) read whole by one process: points, node
/// ids, volume cells and their tags (its format keeps no facets or group names).
pub fn read_vtkhdf(path: &std::path::Path, opts: &eprop_io::ReadOptions) -> Result<Mesh> {
    let slab = eprop_series::vtkhdf::read_slab(path, None)?;
    let mut mesh = mesh_of_slab(path, slab);
    eprop_io::validate(&mut mesh, opts)?;
    Ok(mesh)
}

/// The mesh of a slab that holds a whole VTKHDF mesh (global node indices are local ones).
pub fn mesh_of_slab(path: &std::path::Path, slab: eprop_series::vtkhdf::MeshSlab) -> Mesh {
    let mut mesh = Mesh::new(path.display().to_string());
    mesh.conn.reserve(slab.conn.len());
    for c in 0..slab.n_cells() {
        mesh.push_cell(slab.kinds[c], slab.cell(c), slab.cell_tags[c]);
    }
    mesh.points = slab.points;
    mesh.node_ids = slab.node_ids;
    mesh
}

/// The scaled mesh's bounding-box diagonal must lie in this range.
pub(crate) const EXTENT: (f64, f64) = (1e-60, 1e60);

/// The factor that scales the scenario's mesh file to the reading's length unit.
pub fn factor(sc: &Scenario) -> Result<f64> {
    sc.file
        .mesh
        .factor(sc.file.model.reading)
        .map_err(|e| anyhow!("{}: {e}", sc.path.display()))
}

/// Reads the mesh the scenario names and scales it (refused if its extent is out of `EXTENT`).
pub fn read(sc: &Scenario) -> Result<Mesh> {
    let ms = &sc.file.mesh;
    let factor = factor(sc)?;
    let opts = eprop_io::ReadOptions { strict: ms.strict };
    let path = sc.mesh_path();
    let mesh = match super::local::slab_mesh(sc) {
        true => read_vtkhdf(&path, &opts),
        false => eprop_io::read_mesh_with(&path, &opts),
    };
    let mut mesh = mesh.map_err(|e| anyhow!("{e}\n  (mesh named by {} [mesh] file)", sc.path.display()))?;
    if factor != 1.0 {
        for p in mesh.points.iter_mut() {
            for x in p.iter_mut() {
                *x *= factor;
            }
        }
    }
    // volumes go as the extent cubed, contact stresses as its inverse square: outside this
    // range they overflow or underflow (a load of zero, an operator of inf)
    let (lo, hi) = mesh.bounds();
    let extent = super::distance(hi, lo);
    if !mesh.points.is_empty() && !(EXTENT.0..=EXTENT.1).contains(&extent) {
        let key = if factor != 1.0 {
            match ms.unit {
                Some(u) => format!("[mesh] unit = \"{}\" makes the mesh span", u.name()),
                None => format!("[mesh] scale = {factor:e} makes the mesh span"),
            }
        } else {
            "the mesh spans".to_string()
        };
        return Err(anyhow!(
            "{}: {key} {extent:.4e} units (its bounding-box diagonal), outside {:e} to {:e}, where volumes and contact stresses overflow or underflow; fix: a [mesh] unit that names the unit of the file's coordinates (\"m\", \"cm\", \"mm\", \"um\"), or a [mesh] scale that makes it a few units to a few thousand across (1000 turns metres into mm, 0.001 mm into metres)",
            sc.path.display(),
            EXTENT.0,
            EXTENT.1
        ));
    }
    Ok(mesh)
}
