//! Materials: per-node constitutive tensor R (symmetric positive definite), mass and damping,
//! and the 1-D tissue law that turns a contact stress into an energy density (docs/model.md
//! sections 1, 4).

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

pub type Tensor = Matrix3<f64>;

/// Checks that R is symmetric (to 1e-12 relative) and positive definite.
pub fn check_spd(r: &Tensor) -> Result<(), String> {
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
