//! `[mesh]`: the mesh file, its length scale and the strictness of the reader.

use super::values::one;
use super::Scenario;
use anyhow::{anyhow, Result};
use eprop_io::Mesh;
use serde::de::Error;
use serde::{Deserialize, Deserializer};

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct MeshSec {
    /// Relative to the scenario file.
    pub file: String,
    /// Every coordinate is multiplied by this on reading (1000 reads a mesh in metres as mm).
    #[serde(default = "one", deserialize_with = "scale")]
    pub scale: f64,
    /// Refuse inverted cells instead of reorienting them (as `eprop info --strict`).
    #[serde(default)]
    pub strict: bool,
}

fn scale<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    let s = f64::deserialize(d)?;
    if s > 0.0 && s.is_finite() {
        Ok(s)
    } else {
        Err(D::Error::custom(format!(
            "{s} must be a positive number; fix: the factor from the mesh's length unit to the scenario's (1000 turns metres into mm)"
        )))
    }
}

/// The scaled mesh's bounding-box diagonal must lie in this range.
pub const EXTENT: (f64, f64) = (1e-60, 1e60);

/// Reads the mesh the scenario names and scales it (refused if its extent is out of `EXTENT`).
pub fn read(sc: &Scenario) -> Result<Mesh> {
    let ms = &sc.file.mesh;
    let opts = eprop_io::ReadOptions { strict: ms.strict };
    let mut mesh = eprop_io::read_mesh_with(&sc.mesh_path(), &opts)
        .map_err(|e| anyhow!("{e}\n  (mesh named by {} [mesh] file)", sc.path.display()))?;
    if ms.scale != 1.0 {
        for p in mesh.points.iter_mut() {
            for x in p.iter_mut() {
                *x *= ms.scale;
            }
        }
    }
    // volumes go as the extent cubed, contact stresses as its inverse square: outside this
    // range they overflow or underflow (a load of zero, an operator of inf)
    let (lo, hi) = mesh.bounds();
    let extent = super::distance(hi, lo);
    if !mesh.points.is_empty() && !(EXTENT.0..=EXTENT.1).contains(&extent) {
        let key = if ms.scale != 1.0 {
            format!("[mesh] scale = {:e} makes the mesh span", ms.scale)
        } else {
            "the mesh spans".to_string()
        };
        return Err(anyhow!(
            "{}: {key} {extent:.4e} units (its bounding-box diagonal), outside {:e} to {:e}, where volumes and contact stresses overflow or underflow; fix: a [mesh] scale that makes it a few units to a few thousand across (1000 turns metres into mm, 0.001 mm into metres)",
            sc.path.display(),
            EXTENT.0,
            EXTENT.1
        ));
    }
    Ok(mesh)
}
