//! The tissues of a mesh (docs/model.md sections 1, 4): per tissue the constitutive tensor R
//! (symmetric positive definite), mass, damping, pull-back, coupling and the 1-D tissue law
//! that turns a contact stress into an energy density; a table of distinct tissues and an
//! index per node (`Materials`).

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

pub type Tensor = Matrix3<f64>;

/// Checks that R is symmetric (to 1e-12 relative) and positive definite.
pub(crate) fn check_spd(r: &Tensor) -> Result<(), String> {
    if r.iter().any(|x| !x.is_finite()) {
        return Err("it has a non-finite entry".into());
    }
    let scale = r.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if (r - r.transpose()).iter().any(|x| x.abs() > 1e-12 * scale) {
        return Err("it is not symmetric".into());
    }
    if r.cholesky().is_none() {
        return Err("it is not positive definite (every conductivity must be > 0)".into());
    }
    Ok(())
}

/// The tissue law: sigma = (E/beta)(exp(beta eps) - 1), linear when beta = 0.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TissueLaw {
    pub young: f64,
    pub beta: f64,
}

impl TissueLaw {
    /// Strain-energy density q(sigma) = integral of sigma d eps.
    pub fn energy_density(&self, sigma: f64) -> f64 {
        let (e, b) = (self.young, self.beta);
        if b == 0.0 {
            sigma * sigma / (2.0 * e)
        } else {
            // q = (E / beta^2) (x - ln(1 + x)), x = beta sigma / E; the difference cancels for
            // small x, where its series x^2/2 - x^3/3 + ... is used instead
            let x = b * sigma / e;
            let d = if x.abs() < 0.1 {
                let (mut term, mut sum) = (-x, 0.0);
                for k in 2..=24 {
                    term *= -x;
                    sum += term / k as f64;
                }
                sum
            } else {
                x - x.ln_1p()
            };
            e / (b * b) * d
        }
    }
    /// Stress sigma(eps), the inverse of `strain`: E eps, or (E/beta)(exp(beta eps) - 1).
    pub fn stress(&self, strain: f64) -> f64 {
        let (e, b) = (self.young, self.beta);
        if b == 0.0 {
            e * strain
        } else {
            e / b * (b * strain).exp_m1()
        }
    }
    /// Strain eps(sigma).
    pub fn strain(&self, sigma: f64) -> f64 {
        if self.beta == 0.0 {
            sigma / self.young
        } else {
            (self.beta * sigma / self.young).ln_1p() / self.beta
        }
    }
}

/// One tissue: a distinct combination of the parameters `[material]`, `[model]`, `[tissue]`
/// and the `[[material.region]]`s give a node (docs/model.md section 1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Tissue {
    /// Conductivity tensor R.
    pub r: Tensor,
    pub mass: f64,
    pub damping: f64,
    /// The pull-back k (k_e in the paper reading).
    pub stiffness: f64,
    /// The coupling kappa.
    pub coupling: f64,
    /// Young's modulus and stiffening of the tissue law.
    pub law: TissueLaw,
    /// Poisson's ratio nu, 0 <= nu < 0.5 (`[tissue] poisson`; the propagation does not read
    /// it).
    pub poisson: f64,
}

impl Tissue {
    /// Bitwise equality (a tissue's parameters are copied, never computed, so equal tissues
    /// are equal bit for bit).
    fn same(&self, o: &Tissue) -> bool {
        let bits = |t: &Tissue| {
            let mut v: Vec<u64> = t.r.iter().map(|x| x.to_bits()).collect();
            v.extend(
                [
                    t.mass,
                    t.damping,
                    t.stiffness,
                    t.coupling,
                    t.law.young,
                    t.law.beta,
                    t.poisson,
                ]
                .map(f64::to_bits),
            );
            v
        };
        bits(self) == bits(o)
    }
}

/// The tissues of a mesh: a small table of distinct tissues and each node's index into it
/// (two bytes per node instead of a tensor and five numbers).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Materials {
    pub tissues: Vec<Tissue>,
    pub of_node: Vec<u16>,
    /// The reference Young's modulus E0 of the propagation's weights (docs/model.md section
    /// 3): the scenario's `[tissue] young`, the same on every process.
    pub young0: f64,
}

/// More distinct tissues than a node's index can name.
pub(crate) const MAX_TISSUES: usize = u16::MAX as usize + 1;

impl Materials {
    /// Every one of `n` nodes of one tissue.
    pub fn uniform(n: usize, t: Tissue) -> Materials {
        Materials {
            tissues: vec![t],
            of_node: vec![0; n],
            young0: t.law.young,
        }
    }

    /// `base` on every node with node i's conductivity `r[i]` (a tissue per distinct tensor).
    pub fn with_conductivities(r: &[Tensor], base: Tissue) -> Materials {
        let mut m = Materials {
            tissues: Vec::new(),
            of_node: Vec::with_capacity(r.len()),
            young0: base.law.young,
        };
        for t in r {
            let k = m
                .index_of(Tissue { r: *t, ..base })
                .expect("fewer distinct tensors than MAX_TISSUES");
            m.of_node.push(k);
        }
        m
    }

    /// Node i's tissue.
    #[inline]
    pub fn at(&self, i: usize) -> &Tissue {
        &self.tissues[self.of_node[i] as usize]
    }

    /// Node i's conductivity tensor.
    #[inline]
    pub fn r(&self, i: usize) -> &Tensor {
        &self.at(i).r
    }

    pub fn n_nodes(&self) -> usize {
        self.of_node.len()
    }

    /// The index of `t` in the table, added when new; None when the table is full.
    pub fn index_of(&mut self, t: Tissue) -> Option<u16> {
        if let Some(k) = self.tissues.iter().position(|x| x.same(&t)) {
            return Some(k as u16);
        }
        if self.tissues.len() >= MAX_TISSUES {
            return None;
        }
        self.tissues.push(t);
        Some((self.tissues.len() - 1) as u16)
    }

    /// The nodes `ids` (indices into this table's nodes), in that order, with only the
    /// tissues they use (in the order of first use, so the table does not depend on which
    /// nodes a process holds beyond them).
    pub fn pick(&self, ids: &[u32]) -> Materials {
        let mut map = vec![u32::MAX; self.tissues.len()];
        let mut out = Materials {
            tissues: Vec::new(),
            of_node: Vec::with_capacity(ids.len()),
            young0: self.young0,
        };
        for &g in ids {
            let k = self.of_node[g as usize] as usize;
            if map[k] == u32::MAX {
                map[k] = out.tissues.len() as u32;
                out.tissues.push(self.tissues[k]);
            }
            out.of_node.push(map[k] as u16);
        }
        out
    }

    /// Whether every node has the same Young's modulus (then it weighs nothing in the
    /// propagation: docs/model.md section 3).
    pub fn uniform_young(&self) -> bool {
        self.tissues
            .windows(2)
            .all(|w| w[0].law.young.to_bits() == w[1].law.young.to_bits())
    }

    /// Whether some tissue's Young's modulus differs from the reference E0 (then the
    /// propagation weighs each cell and control volume by E / E0: docs/model.md section 3;
    /// otherwise every weight is exactly 1 and none is applied).
    pub fn weighs_young(&self) -> bool {
        self.tissues
            .iter()
            .any(|t| t.law.young.to_bits() != self.young0.to_bits())
    }

    /// Node i's ratio E_i / E0 (exactly 1 where its tissue has the reference young).
    #[inline]
    pub fn young_ratio(&self, i: usize) -> f64 {
        self.at(i).law.young / self.young0
    }
}
