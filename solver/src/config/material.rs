//! `[material]` and its `[[material.region]]`s: per-node conductivity tensor, mass and damping.

use super::model::Model;
use super::select::{Entry, Keys};
use super::values::{opt_non_negative, opt_positive, Finite, NonNegative, Poisson, Positive};
use super::Scenario;
use crate::config::tissue::{check_spd, Materials, Tensor, Tissue, TissueLaw, MAX_TISSUES};
use anyhow::Result;
use eprop_mesh::Mesh;
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

/// The keys of a `[[material.region]]` besides its selector: what it changes (a key left out
/// keeps what the node had: the sections' values, or an earlier region's).
#[derive(Clone, Debug, Default)]
pub struct Region {
    pub conductivity: Option<Conductivity>,
    pub mass: Option<f64>,
    pub damping: Option<f64>,
    /// `[tissue] young` and `beta` of the region's tissue law.
    pub young: Option<f64>,
    pub beta: Option<f64>,
    /// `[tissue] poisson` in the region.
    pub poisson: Option<f64>,
    /// `[model] stiffness` (the pull-back) and `coupling` in the region.
    pub stiffness: Option<f64>,
    pub coupling: Option<f64>,
}

impl Keys for Region {
    const TABLE: &'static str = "material.region";
    const CHOOSES: &'static str = "a material region";
    const SELECTORS: &'static [&'static str] = &["box", "sphere", "halfspace", "tag", "group"];
    const OWN: &'static [&'static str] = &[
        "conductivity",
        "mass",
        "damping",
        "young",
        "beta",
        "poisson",
        "stiffness",
        "coupling",
    ];
    fn read<'de, A: MapAccess<'de>>(&mut self, key: &str, map: &mut A) -> Result<(), A::Error> {
        match key {
            "conductivity" => self.conductivity = Some(map.next_value()?),
            "mass" => self.mass = Some(map.next_value::<Positive>()?.0),
            "damping" => self.damping = Some(map.next_value::<NonNegative>()?.0),
            "young" => self.young = Some(map.next_value::<Positive>()?.0),
            "beta" => self.beta = Some(map.next_value::<NonNegative>()?.0),
            "poisson" => self.poisson = Some(map.next_value::<Poisson>()?.0),
            "stiffness" => self.stiffness = Some(map.next_value::<NonNegative>()?.0),
            _ => self.coupling = Some(map.next_value::<Finite>()?.0),
        }
        Ok(())
    }
}

impl Region {
    /// `t` with this region's keys applied.
    fn apply(&self, mut t: Tissue) -> Tissue {
        if let Some(c) = self.conductivity {
            t.r = c.0;
        }
        t.mass = self.mass.unwrap_or(t.mass);
        t.damping = self.damping.unwrap_or(t.damping);
        t.law.young = self.young.unwrap_or(t.law.young);
        t.law.beta = self.beta.unwrap_or(t.law.beta);
        t.poisson = self.poisson.unwrap_or(t.poisson);
        t.stiffness = self.stiffness.unwrap_or(t.stiffness);
        t.coupling = self.coupling.unwrap_or(t.coupling);
        t
    }
}

/// The tissue of every node: the sections' values (`[material]`, `[model]` stiffness and
/// coupling, `[tissue]`; the reading's defaults where a key is not written), then each
/// region's keys on its nodes, in order (a later region wins where they overlap).
pub fn resolve(
    sc: &Scenario,
    m: &MaterialSec,
    model: &Model,
    law: TissueLaw,
    poisson: f64,
    mesh: &Mesh,
) -> Result<Materials> {
    let n = mesh.n_nodes();
    let d = model.reading.defaults();
    let base = Tissue {
        r: m.conductivity.map_or(Tensor::identity() * d.conductivity, |c| c.0),
        mass: m.mass.unwrap_or(d.mass),
        damping: m.damping.unwrap_or(d.damping),
        stiffness: model.stiffness(),
        coupling: model.coupling(),
        law,
        poisson,
    };
    let mut mat = Materials::uniform(n, base);
    for (k, reg) in m.region.iter().enumerate() {
        let none = "the region holds no node; fix: check its bounds against the mesh (eprop info MESH)";
        let set = sc.select(&reg.selector, Region::TABLE, mesh, none)?;
        // the tissue each tissue of the table becomes in this region, made once
        let mut becomes: Vec<Option<u16>> = vec![None; mat.tissues.len()];
        for i in (0..n).filter(|&i| set[i]) {
            let old = mat.of_node[i] as usize;
            let new = match becomes[old] {
                Some(t) => t,
                None => {
                    let t = mat.index_of(reg.with.apply(mat.tissues[old])).ok_or_else(|| {
                        anyhow::anyhow!(
                            "{}: [[material.region]] {}: the regions make more than {MAX_TISSUES} distinct tissues; fix: use fewer regions, or regions that share their values",
                            sc.path.display(),
                            k + 1
                        )
                    })?;
                    becomes.resize(mat.tissues.len(), None);
                    becomes[old] = Some(t);
                    t
                }
            };
            mat.of_node[i] = new;
        }
    }
    // one young on every node (a region may give them all another): the reference, so that no
    // weight is applied (docs/model.md section 3)
    if let Some(k) = mat.of_node.first() {
        let young = mat.tissues[*k as usize].law.young;
        if mat
            .of_node
            .iter()
            .all(|&t| mat.tissues[t as usize].law.young.to_bits() == young.to_bits())
        {
            mat.young0 = young;
        }
    }
    Ok(mat)
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
