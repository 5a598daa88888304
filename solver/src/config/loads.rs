//! `[[load]]`: contact nodes, force or normal pressure, the ramp in time or a force table.

use super::select::{Entry, Keys, Selector};
use super::values::{Finite, Point, Ramp};
use super::{Reading, Scenario};
use crate::config::tables::{read_table, History};
use anyhow::Result;
use eprop_mesh::Mesh;
use serde::de::MapAccess;
use serde::{Deserialize, Serialize};
use toml::Spanned;

/// The columns of a force table.
pub const FORCE_COLUMNS: [&str; 4] = ["t", "fx", "fy", "fz"];

/// The keys of a `[[load]]` besides its selector: how it pushes.
#[derive(Clone, Debug, Default)]
pub struct Push {
    pub force: Option<[f64; 3]>,
    pub normal: Option<f64>,
    pub ramp: Option<Vec<[f64; 2]>>,
    /// A CSV force history `t, fx, fy, fz` (relative to the scenario file).
    pub table: Option<Spanned<String>>,
    /// Driven by the client of `eprop serve`.
    pub live: bool,
}

impl Keys for Push {
    const TABLE: &'static str = "load";
    const CHOOSES: &'static str = "a load's contact nodes";
    const SELECTORS: &'static [&'static str] = &["node", "nearest", "patch"];
    const OWN: &'static [&'static str] = &["force", "normal", "ramp", "table", "live"];
    fn read<'de, A: MapAccess<'de>>(&mut self, key: &str, map: &mut A) -> Result<(), A::Error> {
        match key {
            "force" => self.force = Some(map.next_value::<Point>()?.0),
            "normal" => self.normal = Some(map.next_value::<Finite>()?.0),
            "table" => self.table = Some(map.next_value()?),
            "live" => self.live = map.next_value()?,
            _ => self.ramp = Some(map.next_value::<Ramp>()?.0),
        }
        Ok(())
    }
    fn finish(&self) -> Result<(), String> {
        let given = [self.force.is_some(), self.normal.is_some(), self.table.is_some()];
        if given.iter().filter(|&&b| b).count() != 1 {
            return Err(
                "give exactly one of `force = [fx, fy, fz]`, `normal = magnitude` or `table = \"forces.csv\"` (columns t, fx, fy, fz)"
                    .into(),
            );
        }
        if self.table.is_some() && self.ramp.is_some() {
            return Err("a force table gives the force itself, a ramp scales a constant one; fix: drop `ramp` and write the scaling into the table".into());
        }
        Ok(())
    }
}

/// A resolved load.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Load {
    /// Contact nodes (global indices) and their weights (summing to 1).
    pub nodes: Vec<u32>,
    /// Their ids in the mesh file, for messages.
    pub node_ids: Vec<u64>,
    pub weights: Vec<f64>,
    /// Force at ramp scale 1.
    pub force: [f64; 3],
    /// |sum of the contact nodes' boundary dual areas|, filled in by the solver (a continuum
    /// patch: the sum of its shares, the patch area).
    pub area: f64,
    pub ramp: Option<Vec<[f64; 2]>>,
    /// Normal load magnitude (force direction is set from the boundary normal).
    pub normal: Option<f64>,
    /// Contact patches: the source enters through the patch surface as a flux of depth
    /// `depth` (the patch radius): Q_i = q |A_i| depth / V_i, so the energy put in does not
    /// depend on the mesh. None: the paper's nodal source Q_c = q.
    pub depth: Option<f64>,
    /// The force in time from a table (or, in `eprop serve`, from the client's samples).
    pub history: Option<History>,
    /// The continuum reading's patch (docs/model.md section 4): each contact node's share a_i
    /// of the patch area (`select::patch_shares`), and the patch's outward area vector; empty
    /// and zero otherwise.
    pub shares: Vec<f64>,
    pub area_vector: [f64; 3],
    /// Driven by the client of `eprop serve` (in `eprop run`, the load is as written).
    pub live: bool,
}

impl Load {
    /// The force at time t: the table's, or the force (set from the normal for `normal`
    /// loads) times the ramp's scale.
    pub fn force_at(&self, t: f64) -> [f64; 3] {
        match &self.history {
            Some(h) => h.at(t),
            None => eprop_io::geom::scale(self.force, self.scale(t)),
        }
    }

    /// Ramp scale at time t (piecewise linear, constant beyond the ends).
    pub fn scale(&self, t: f64) -> f64 {
        let Some(r) = &self.ramp else { return 1.0 };
        if t <= r[0][0] {
            return r[0][1];
        }
        for w in r.windows(2) {
            if t <= w[1][0] {
                let a = (t - w[0][0]) / (w[1][0] - w[0][0]);
                return w[0][1] + a * (w[1][1] - w[0][1]);
            }
        }
        r[r.len() - 1][1]
    }
}

/// For a message about where a load lands: when `[mesh] scale` or `unit` rescales the mesh,
/// what it spans then (the scenario's lengths are in the scaled unit: `nearest = [1, 0, 2]` on
/// a mesh scaled by 1e59 lands at its fixed end); empty otherwise.
fn scaled_hint(sc: &Scenario, mesh: &Mesh) -> String {
    if super::unit_note(sc).is_empty() {
        return String::new();
    }
    let (lo, hi) = mesh.bounds();
    format!(
        " (the mesh spans {}{})",
        crate::diagnostics::span(lo, hi),
        super::unit_note(sc)
    )
}

/// Every load's contact nodes and weights on the mesh; none may be fixed.
///
/// In the continuum reading a patch's nodes are those its disc reaches on the boundary faces,
/// weighted by their shares of its area (`select::patch_shares`).
pub fn resolve(sc: &Scenario, loads: &[Entry<Push>], mesh: &Mesh, fixed: &[bool]) -> Result<Vec<Load>> {
    let continuum = sc.file.model.reading == Reading::Continuum;
    let mut out = Vec::with_capacity(loads.len());
    for l in loads {
        let sel = l.selector.get_ref();
        let mut patch = (Vec::new(), [0.0; 3]);
        let (nodes, weights) = match sel {
            Selector::Patch(ball) if continuum => {
                let (nodes, shares, vector) = super::select::patch_shares(mesh, ball)
                    .map_err(|e| sc.error_at(l.selector.span(), Push::TABLE, sel.key(), e))?;
                let total: f64 = shares.iter().sum();
                let weights = shares.iter().map(|a| a / total).collect();
                patch = (shares, vector);
                (nodes, weights)
            }
            _ => sel
                .contacts(mesh)
                .map_err(|e| sc.error_at(l.selector.span(), Push::TABLE, sel.key(), e))?,
        };
        if let Some(&bad) = nodes.iter().find(|&&n| fixed[n as usize]) {
            return Err(sc.error_at(
                l.selector.span(),
                Push::TABLE,
                sel.key(),
                format!(
                    "the load's node {} is in the fixed set; fix: load free nodes or shrink the [[fixed]] set{}",
                    mesh.node_ids[bad as usize],
                    scaled_hint(sc, mesh)
                ),
            ));
        }
        let p = &l.with;
        let history = match &p.table {
            Some(file) => {
                let base = sc.path.parent().unwrap_or(std::path::Path::new("."));
                let role = format!("force table of [[load]] {}", out.len() + 1);
                let h = read_table(&base.join(file.get_ref()), &role, FORCE_COLUMNS)
                    .map_err(|e| sc.error_at(file.span(), Push::TABLE, "table", format!("{e:#}")))?;
                Some(h)
            }
            None => None,
        };
        let area = if continuum { patch.0.iter().sum() } else { 0.0 };
        out.push(Load {
            shares: patch.0,
            area_vector: patch.1,
            history,
            live: p.live,
            depth: match sel {
                Selector::Patch(b) => Some(b.radius),
                _ => None,
            },
            node_ids: nodes.iter().map(|&n| mesh.node_ids[n as usize]).collect(),
            nodes,
            weights,
            force: p.force.unwrap_or([0.0; 3]),
            area,
            ramp: p.ramp.clone(),
            normal: p.normal,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ramp_is_piecewise_linear_and_constant_beyond_its_ends() {
        let mut l = Load {
            nodes: vec![0],
            node_ids: vec![1],
            weights: vec![1.0],
            force: [1.0, 0.0, 0.0],
            area: 0.0,
            ramp: None,
            normal: None,
            depth: None,
            history: None,
            live: false,
            shares: vec![],
            area_vector: [0.0; 3],
        };
        assert_eq!(l.scale(5.0), 1.0);
        l.ramp = Some(vec![[1.0, 0.0], [2.0, 1.0], [4.0, 0.5]]);
        for (t, s) in [(0.0, 0.0), (1.0, 0.0), (1.5, 0.5), (2.0, 1.0), (3.0, 0.75), (9.0, 0.5)] {
            assert_eq!(l.scale(t), s, "t = {t}");
        }
    }

    #[test]
    fn a_load_pushes_one_way() {
        let push = |keys: &str| -> Result<Push, String> {
            #[derive(serde::Deserialize)]
            struct F {
                load: Vec<Entry<Push>>,
            }
            toml::from_str::<F>(&format!("[[load]]\nnode = 1\n{keys}"))
                .map(|mut f| f.load.remove(0).with)
                .map_err(|e| e.message().to_string())
        };
        assert_eq!(push("force = [1, 0, 0]").unwrap().force, Some([1.0, 0.0, 0.0]));
        assert_eq!(push("normal = -0.5").unwrap().normal, Some(-0.5));
        for bad in ["", "force = [1, 0, 0]\nnormal = 1.0", "table = \"f.csv\"\nnormal = 1.0"] {
            assert!(push(bad).unwrap_err().contains("exactly one of `force"), "{bad}");
        }
        let p = push("table = \"f.csv\"\nlive = true").unwrap();
        assert_eq!(p.table.map(|t| t.into_inner()), Some("f.csv".to_string()));
        assert!(p.live);
        assert!(push("table = \"f.csv\"\nramp = [[0, 0], [1, 1]]")
            .unwrap_err()
            .contains("drop `ramp`"));
        assert!(push("force = [1, 0, 0]\nlive = 1").is_err());
        assert!(push("normal = nan").unwrap_err().contains("finite"));
        assert!(push("normal = 1.0\nramp = [[1.0, 0.0], [0.5, 1.0]]")
            .unwrap_err()
            .contains("increasing"));
        assert!(push("force = [1, 0, 0]\nbox = [[0, 0, 0], [1, 1, 1]]")
            .unwrap_err()
            .contains("`box` does not select a load's contact nodes"));
    }
}
