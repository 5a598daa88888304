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

/// Reads the mesh the scenario names and scales it.
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
    Ok(mesh)
}
