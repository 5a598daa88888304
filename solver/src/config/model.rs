//! `[model]` (the discretisation and the coupling constants) and `[tissue]` (the tissue law).
//! Both are checked completely while parsing, so the parsed sections are the resolved ones.
//!
//! A new choice goes here and nowhere else in the scenario: a `#[derive(Deserialize,
//! Serialize)]` enum with `#[serde(rename_all = "lowercase")]` (a wrong spelling then fails
//! the parse at its line, naming the accepted ones) as a field of `Model` with a
//! `#[serde(default)]`, and its options as further fields (checked by their types, see
//! `values`). `Setup::model` carries it to every process and to the simulation.

use super::values::{
    non_negative, one, opt_finite, opt_non_negative, opt_positive, poisson, poisson_default, positive, yes, Precision,
};
use crate::config::integrator::{self, Kind, Preconditioner, Settings};
use crate::config::tissue::TissueLaw;
use serde::{de::Error, Deserialize, Deserializer, Serialize};

/// The scheme of the propagation operator, as the scenario spells it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SchemeName {
    #[default]
    Compact,
    Paper,
}

/// How the model's parameters and loads are read (docs/model.md): `paper` is the per-node
/// reading of the paper (mass, damping and pull-back per node, loads as nodal forces, no
/// units); `continuum` reads them as densities and fluxes in SI units, so results converge as
/// the mesh is refined and do not depend on the mesh file's length unit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Reading {
    Paper,
    #[default]
    Continuum,
}

/// The defaults of one reading (docs/model.md, "Defaults"). `paper`: the paper's unit-free
/// values; `continuum`: a liver-like soft tissue in SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Defaults {
    /// paper: mass per node; continuum: density rho, kg/m^3
    pub mass: f64,
    /// paper: per node; continuum: kg/(m^3 s)
    pub damping: f64,
    /// paper: length^2/time; continuum: m^2/s
    pub conductivity: f64,
    /// paper: k_e per node; continuum: N/m^4 (a pull-back force per volume and displacement)
    pub stiffness: f64,
    /// paper: kappa; continuum: 1/m (u = coupling phi / stiffness at equilibrium, in m)
    pub coupling: f64,
    /// paper: unit-free; continuum: Pa
    pub young: f64,
}

/// Liver-like soft tissue (docs/model.md, "Defaults"): density 1060 kg/m^3, Young's modulus
/// 4 kPa, conductivity 0.1 m^2/s (the energy crosses a 0.1 m organ in L^2/D = 0.1 s, the time a
/// shear wave takes), stiffness E/L^2 = 4e5 N/m^4 with L = 0.1 m, critical damping
/// 2 sqrt(k rho), and a coupling that gives Boussinesq's displacement under a 5 mm disc at 10 %
/// strain.
pub const CONTINUUM: Defaults = Defaults {
    mass: 1060.0,
    damping: 4.118e4,
    conductivity: 0.1,
    stiffness: 4.0e5,
    coupling: 15.0,
    young: 4000.0,
};

/// The paper's reading: the paper defaults of docs/model.md section 0.
pub const PAPER: Defaults = Defaults {
    mass: 1.0,
    damping: 2.0,
    conductivity: 0.05,
    stiffness: 1.0,
    coupling: 1.0,
    young: 100.0,
};

impl Reading {
    pub fn defaults(self) -> Defaults {
        match self {
            Reading::Paper => PAPER,
            Reading::Continuum => CONTINUUM,
        }
    }
}

/// The propagation operator's scheme, with its option.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scheme {
    Compact,
    Paper { correction: bool },
}

/// `[model]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Model {
    /// The reading of the parameters and loads.
    #[serde(default)]
    pub reading: Reading,
    #[serde(default)]
    pub scheme: SchemeName,
    /// The paper scheme's correction term (docs/model.md section 3: the paper's eq. 11).
    #[serde(default = "yes")]
    pub paper_correction: bool,
    /// Storage of the compact operator's coefficients.
    #[serde(default)]
    pub operator_precision: Precision,
    /// k_e (None: the reading's default, `Model::stiffness`)
    #[serde(default, deserialize_with = "opt_non_negative")]
    pub stiffness: Option<f64>,
    /// kappa (None: the reading's default, `Model::coupling`)
    #[serde(default, deserialize_with = "opt_finite")]
    pub coupling: Option<f64>,
    /// p
    #[serde(default = "one", deserialize_with = "positive")]
    pub exponent: f64,
    /// The integrator of the propagation (docs/integrators.md).
    #[serde(default)]
    pub integrator: Kind,
    /// The screening length l (docs/model.md section 3): a sink -(D/l^2) phi in the
    /// propagation (None: no sink, the paper's equation).
    #[serde(default, deserialize_with = "screening")]
    pub screening: Option<f64>,
}

/// `[model] screening`: a positive, finite length (an Option on the wire, a present key in
/// TOML).
fn screening<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    let l = Option::<f64>::deserialize(d)?;
    match l {
        Some(x) if !(x > 0.0 && x.is_finite()) => Err(D::Error::custom(format!(
            "{} is not a screening length; fix: a positive length (continuum: in m, such as 0.01), or leave it out for none",
            crate::diagnostics::short(x)
        ))),
        _ => Ok(l),
    }
}

/// `[integrator]`: the settings of `rkl2` and `implicit`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IntegratorSec {
    /// rkl2 and implicit: the relative error each mechanics step may add to the potential
    /// (`inf`: no error control)
    #[serde(default = "default_accuracy", deserialize_with = "accuracy")]
    pub accuracy: f64,
    /// implicit: relative residual of every solve (by default tied to the accuracy)
    #[serde(default, deserialize_with = "tolerance")]
    pub tolerance: Option<f64>,
    /// implicit: conjugate-gradient iterations per solve before it is an error
    #[serde(default = "default_max_iterations", deserialize_with = "max_iterations")]
    pub max_iterations: u64,
    /// rkl2: stages per mechanics step before it is an error
    #[serde(default = "default_max_stages", deserialize_with = "max_stages")]
    pub max_stages: u64,
    /// implicit: "auto" (the default: jacobi, or multigrid where a trial solve shows it
    /// cheaper), "jacobi", "multigrid" (smoothed aggregation) or "amg" (hypre BoomerAMG)
    #[serde(default)]
    pub preconditioner: Preconditioner,
}

fn default_accuracy() -> f64 {
    integrator::DEFAULT_ACCURACY
}

fn accuracy<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    let a = f64::deserialize(d)?;
    if a > 0.0 && (a < 1.0 || a == f64::INFINITY) {
        Ok(a)
    } else {
        Err(D::Error::custom(format!(
            "{} is not a relative error per step; fix: a number between 0 and 1, such as {:e} (the default), or inf for no error control",
            crate::diagnostics::short(a),
            integrator::DEFAULT_ACCURACY
        )))
    }
}
fn default_max_iterations() -> u64 {
    integrator::DEFAULT_MAX_ITERATIONS as u64
}
fn default_max_stages() -> u64 {
    integrator::DEFAULT_MAX_STAGES as u64
}

fn tolerance<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    let t = f64::deserialize(d)?;
    if t > 0.0 && t < 1.0 {
        Ok(Some(t))
    } else {
        Err(D::Error::custom(format!(
            "{} is not a relative residual; fix: a number between 0 and 1, such as 1e-8 (by default 1e-2 of [integrator] accuracy)",
            crate::diagnostics::short(t)
        )))
    }
}

fn max_iterations<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
    let m = u64::deserialize(d)?;
    if m >= 1 {
        Ok(m.min(u32::MAX as u64))
    } else {
        Err(D::Error::custom(format!(
            "must be at least 1; fix: leave it out (default {})",
            integrator::DEFAULT_MAX_ITERATIONS
        )))
    }
}

fn max_stages<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
    let m = u64::deserialize(d)?;
    if m >= 2 {
        Ok(m.min(u32::MAX as u64))
    } else {
        Err(D::Error::custom(format!(
            "rkl2 needs at least 2 stages; fix: leave it out (default {})",
            integrator::DEFAULT_MAX_STAGES
        )))
    }
}

impl IntegratorSec {
    /// The integrator `kind` with these settings.
    pub fn settings(&self, kind: Kind) -> Settings {
        Settings {
            kind,
            accuracy: self.accuracy,
            tolerance: self.tolerance.unwrap_or(if self.accuracy.is_finite() {
                (integrator::CG_SHARE * self.accuracy).max(1e-14)
            } else {
                integrator::UNCONTROLLED_TOLERANCE
            }),
            max_iterations: self.max_iterations as usize,
            max_stages: self.max_stages as usize,
            preconditioner: self.preconditioner,
            trials: true,
        }
    }
}

impl Model {
    /// k_e: as written, or the reading's default.
    pub fn stiffness(&self) -> f64 {
        self.stiffness.unwrap_or(self.reading.defaults().stiffness)
    }

    /// kappa: as written, or the reading's default.
    pub fn coupling(&self) -> f64 {
        self.coupling.unwrap_or(self.reading.defaults().coupling)
    }

    pub fn scheme(&self) -> Scheme {
        match self.scheme {
            SchemeName::Compact => Scheme::Compact,
            SchemeName::Paper => Scheme::Paper {
                correction: self.paper_correction,
            },
        }
    }
}

/// `[tissue]`: the tissue law that turns a contact stress into an energy density.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TissueSec {
    /// None: the reading's default (`TissueSec::law`).
    #[serde(default, deserialize_with = "opt_positive")]
    pub young: Option<f64>,
    /// 0: linear; > 0: exponential stiffening.
    #[serde(default, deserialize_with = "non_negative")]
    pub beta: f64,
    /// Poisson's ratio nu (0 <= nu < 0.5): not used by the propagation; a tool's contact
    /// modulus E / (2 (1 - nu^2)) reads it.
    #[serde(default = "poisson_default", deserialize_with = "poisson")]
    pub poisson: f64,
}

impl TissueSec {
    /// The law, with the reading's default where young is not written.
    pub fn law(&self, reading: Reading) -> TissueLaw {
        TissueLaw {
            young: self.young.unwrap_or(reading.defaults().young),
            beta: self.beta,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::values::defaults;
    use super::*;

    fn model(text: &str) -> Result<Model, String> {
        toml::from_str(text).map_err(|e| e.message().to_string())
    }

    #[test]
    fn defaults_and_spellings() {
        let m: Model = defaults();
        assert_eq!(m.scheme(), Scheme::Compact);
        assert_eq!(m.operator_precision, Precision::Float64);
        assert_eq!(m.reading, Reading::Continuum);
        assert_eq!((m.stiffness(), m.coupling(), m.exponent), (4.0e5, 15.0, 1.0));
        let p = model("reading = \"paper\"").unwrap();
        assert_eq!((p.stiffness(), p.coupling()), (1.0, 1.0));
        assert_eq!(model("stiffness = 2.0").unwrap().stiffness(), 2.0);
        let p = model("scheme = \"paper\"\npaper_correction = false\noperator_precision = \"float32\"").unwrap();
        assert_eq!(p.scheme(), Scheme::Paper { correction: false });
        assert_eq!(p.operator_precision, Precision::Float32);
        assert_eq!(
            model("scheme = \"paper\"").unwrap().scheme(),
            Scheme::Paper { correction: true }
        );
        let t: TissueSec = defaults();
        assert_eq!((t.law(Reading::Paper).young, t.beta), (100.0, 0.0));
        assert_eq!(t.law(Reading::Continuum).young, 4000.0);
        assert_eq!(t.poisson, 0.45);
        let tissue = |text: &str| toml::from_str::<TissueSec>(text).map_err(|e| e.message().to_string());
        assert_eq!(tissue("poisson = 0.3").unwrap().poisson, 0.3);
        assert_eq!(tissue("poisson = 0").unwrap().poisson, 0.0);
        for bad in ["poisson = 0.5", "poisson = -0.1"] {
            let e = tissue(bad).unwrap_err();
            assert!(e.contains("0 <= poisson < 0.5"), "{bad}: {e}");
        }
    }

    #[test]
    fn each_key_is_checked_while_parsing() {
        let e = model("scheme = \"magic\"").unwrap_err();
        assert!(e.contains("`magic`") && e.contains("`compact` or `paper`"), "{e}");
        assert!(model("stiffness = -1.0").unwrap_err().contains("zero or positive"));
        assert!(model("coupling = nan").unwrap_err().contains("finite"));
        assert!(model("exponent = 0.0").unwrap_err().contains("positive"));
        assert_eq!(model("screening = 0.01").unwrap().screening, Some(0.01));
        assert_eq!(model("").unwrap().screening, None);
        for bad in ["screening = 0.0", "screening = -1e-3", "screening = inf"] {
            assert!(model(bad).unwrap_err().contains("screening length"), "{bad}");
        }
        assert!(model("integrater = \"euler\"")
            .unwrap_err()
            .contains("unknown field `integrater`"));
        let t = toml::from_str::<TissueSec>("young = 0.0").unwrap_err();
        assert!(t.message().contains("positive"));
        assert!(toml::from_str::<TissueSec>("beta = -1").is_err());
    }
}
