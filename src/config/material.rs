//! `[material]` and its `[[material.region]]`s: per-node conductivity tensor, mass and damping.

use super::select::{Entry, Keys};
use super::values::{opt_non_negative, opt_positive, NonNegative, Positive};
use super::Reading;
use super::Scenario;
use crate::discretize::material::{check_spd, Tensor};
use anyhow::Result;
use eprop_io::Mesh;
use serde::de::MapAccess;
use serde::Deserialize;

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct MaterialSec {
    /// None: the reading's default (`[model] reading`), as for damping and conductivity.
    #[serde(default, deserialize_with = "opt_positive")]
    pub mass: Option<f64>,
    #[serde(default, deserialize_with = "opt_non_negative")]
    pub damping: Option<f64>,
    #[serde(default)]
    pub conductivity: Option<Conductivity>,
    /// Heterogeneous parts, applied in order (a later region wins where they overlap).
    #[serde(default)]
    pub region: Vec<Entry<Region>>,
}

/// A conductivity tensor R, checked symmetric positive definite. The scenario writes a
/// scalar, three diagonal values, a full symmetric 3x3 table, or diagonal values along the
/// axes of an orthonormal frame (`{ diagonal = [...], axes = [[...], [...], [...]] }`).
#[derive(Deserialize, Debug, Clone, Copy, PartialEq)]
#[serde(try_from = "toml::Value")]
pub struct Conductivity(pub Tensor);

const SHAPES: &str = "a conductivity is a number (`0.05`), three diagonal values (`[rx, ry, rz]`), \
a symmetric 3x3 table (`[[rxx, rxy, rxz], [ryx, ryy, ryz], [rzx, rzy, rzz]]`) or values along \
orthonormal axes (`{ diagonal = [r1, r2, r3], axes = [[...], [...], [...]] }`)";

impl TryFrom<toml::Value> for Conductivity {
    type Error = String;
    fn try_from(v: toml::Value) -> Result<Self, String> {
        let t = tensor(&v).ok_or_else(|| format!("{} is not a conductivity; fix: {SHAPES}", describe(&v)))??;
        check_spd(&t)?;
        Ok(Conductivity(t))
    }
}

/// What a TOML value is, for messages.
fn describe(v: &toml::Value) -> String {
    match v {
        toml::Value::Array(a) => format!("an array of {} value(s)", a.len()),
        toml::Value::Table(t) => format!(
            "a table with keys {}",
            super::select::either(&t.keys().map(|k| k.as_str()).collect::<Vec<_>>(), "`")
        ),
        other => format!("a {}", other.type_str()),
    }
}

fn number(v: &toml::Value) -> Option<f64> {
    match v {
        toml::Value::Float(x) => Some(*x),
        toml::Value::Integer(i) => Some(*i as f64),
        _ => None,
    }
}

fn three(v: &toml::Value) -> Option<[f64; 3]> {
    match v.as_array()?.as_slice() {
        [a, b, c] => Some([number(a)?, number(b)?, number(c)?]),
        _ => None,
    }
}

fn table3(v: &toml::Value) -> Option<[[f64; 3]; 3]> {
    match v.as_array()?.as_slice() {
        [a, b, c] => Some([three(a)?, three(b)?, three(c)?]),
        _ => None,
    }
}

/// The tensor a value describes: None when it has none of the shapes, an error when it is a
/// frame whose axes are not orthonormal.
fn tensor(v: &toml::Value) -> Option<Result<Tensor, String>> {
    if let Some(r) = number(v) {
        return Some(Ok(Tensor::identity() * r));
    }
    if let Some(d) = three(v) {
        return Some(Ok(Tensor::from_diagonal(&nalgebra::Vector3::from(d))));
    }
    if let Some(m) = table3(v) {
        return Some(Ok(Tensor::from_fn(|i, j| m[i][j])));
    }
    let t = v.as_table().filter(|t| t.len() == 2)?;
    let (diagonal, axes) = (three(t.get("diagonal")?)?, table3(t.get("axes")?)?);
    Some(frame(diagonal, axes))
}

/// R = sum_k d_k a_k a_k^T over orthonormal axes a_k (to 1e-6).
fn frame(diagonal: [f64; 3], axes: [[f64; 3]; 3]) -> Result<Tensor, String> {
    for i in 0..3 {
        for j in 0..3 {
            let d: f64 = (0..3).map(|c| axes[i][c] * axes[j][c]).sum();
            let want = if i == j { 1.0 } else { 0.0 };
            if !((d - want).abs() <= 1e-6) {
                return Err(format!(
                    "the axes are not orthonormal (axis {} . axis {} = {d:.6}); fix: give three unit vectors at right angles",
                    i + 1,
                    j + 1
                ));
            }
        }
    }
    let mut t = Tensor::zeros();
    for k in 0..3 {
        let a = nalgebra::Vector3::from(axes[k]);
        t += a * a.transpose() * diagonal[k];
    }
    Ok(t)
}

/// The keys of a `[[material.region]]` besides its selector: what it changes.
#[derive(Clone, Debug, Default)]
pub struct Region {
    pub conductivity: Option<Conductivity>,
    pub mass: Option<f64>,
    pub damping: Option<f64>,
}

impl Keys for Region {
    const TABLE: &'static str = "material.region";
    const CHOOSES: &'static str = "a material region";
    const SELECTORS: &'static [&'static str] = &["box", "sphere", "halfspace", "tag", "group"];
    const OWN: &'static [&'static str] = &["conductivity", "mass", "damping"];
    fn read<'de, A: MapAccess<'de>>(&mut self, key: &str, map: &mut A) -> Result<(), A::Error> {
        match key {
            "conductivity" => self.conductivity = Some(map.next_value()?),
            "mass" => self.mass = Some(map.next_value::<Positive>()?.0),
            _ => self.damping = Some(map.next_value::<NonNegative>()?.0),
        }
        Ok(())
    }
}

/// Per-node material arrays (the mesh's numbering).
#[derive(Debug, Clone, PartialEq)]
pub struct Materials {
    pub r: Vec<Tensor>,
    pub mass: Vec<f64>,
    pub damping: Vec<f64>,
}

/// The `[material]` values on every node (the reading's defaults where a key is not
/// written), then each region's on its nodes, in order.
pub fn resolve(sc: &Scenario, m: &MaterialSec, reading: Reading, mesh: &Mesh) -> Result<Materials> {
    let n = mesh.n_nodes();
    let d = reading.defaults();
    let conductivity = m.conductivity.map_or(Tensor::identity() * d.conductivity, |c| c.0);
    let mut r = vec![conductivity; n];
    let mut mass = vec![m.mass.unwrap_or(d.mass); n];
    let mut damping = vec![m.damping.unwrap_or(d.damping); n];
    for reg in &m.region {
        let none = "the region holds no node; fix: check its bounds against the mesh (eprop info MESH)";
        let set = sc.select(&reg.selector, Region::TABLE, mesh, none)?;
        let w = &reg.with;
        for i in (0..n).filter(|&i| set[i]) {
            if let Some(c) = w.conductivity {
                r[i] = c.0;
            }
            if let Some(ms) = w.mass {
                mass[i] = ms;
            }
            if let Some(d) = w.damping {
                damping[i] = d;
            }
        }
    }
    Ok(Materials { r, mass, damping })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn conductivity(v: &str) -> Result<Tensor, String> {
        #[derive(Deserialize)]
        struct W {
            c: Conductivity,
        }
        toml::from_str::<W>(&format!("c = {v}"))
            .map(|w| w.c.0)
            .map_err(|e| e.message().to_string())
    }

    #[test]
    fn every_shape_of_conductivity_gives_its_tensor() {
        assert_eq!(conductivity("0.05").unwrap(), Tensor::identity() * 0.05);
        assert_eq!(conductivity("2").unwrap(), Tensor::identity() * 2.0);
        assert_eq!(
            conductivity("[0.08, 0.05, 1]").unwrap(),
            Tensor::from_diagonal(&nalgebra::Vector3::new(0.08, 0.05, 1.0))
        );
        let full = conductivity("[[0.06, 0.01, 0.0], [0.01, 0.05, 0.0], [0.0, 0.0, 0.05]]").unwrap();
        assert_eq!((full[(0, 1)], full[(1, 0)], full[(1, 1)]), (0.01, 0.01, 0.05));
        // along axes rotated 90 degrees about z: diagonal (1, 2, 3) becomes (2, 1, 3)
        let f = conductivity("{ diagonal = [1, 2, 3], axes = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]] }").unwrap();
        assert_eq!(f, Tensor::from_diagonal(&nalgebra::Vector3::new(2.0, 1.0, 3.0)));
    }

    #[test]
    fn a_bad_conductivity_says_what_is_accepted() {
        for (v, want) in [
            ("\"high\"", "a string is not a conductivity"),
            ("[0.1, 0.1]", "an array of 2 value(s)"),
            ("[[0.1, 0.0, 0.0], [0.0, 0.1]]", "an array of 2 value(s)"),
            ("{ diagonal = [1, 1, 1] }", "a table with keys `diagonal`"),
        ] {
            let e = conductivity(v).unwrap_err();
            assert!(
                e.contains(want) && e.contains("fix: a conductivity is a number"),
                "{v}: {e}"
            );
            assert!(e.contains("orthonormal axes"), "{e}");
        }
        assert!(conductivity("[0.1, -0.1, 0.1]")
            .unwrap_err()
            .contains("positive definite"));
        assert!(conductivity("[[1, 2, 0], [0, 1, 0], [0, 0, 1]]")
            .unwrap_err()
            .contains("not symmetric"));
        let e = conductivity("{ diagonal = [1, 1, 1], axes = [[1, 0, 0], [1, 0, 0], [0, 0, 1]] }").unwrap_err();
        assert!(e.contains("not orthonormal (axis 1 . axis 2 = 1.000000)"), "{e}");
    }
}
