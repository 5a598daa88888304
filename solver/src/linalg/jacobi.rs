//! The Jacobi preconditioner of A = V - theta tau W (W = V L, c_ij the coefficients of L):
//! z_i = r_i / A_ii, fused by the solver into its vector update.

use super::csr::AnyCsr;
use super::{Precond, Sweep, V3};
use rayon::prelude::*;

/// Jacobi: z_i = r_i / A_ii.
pub struct Jacobi {
    inv: Vec<f64>,
}

impl Jacobi {
    /// The inverse diagonal of A = V - theta_tau W on the owned rows (`vol`: the volumes of the
    /// rows that move, 0 elsewhere; 0 where A_ii is not positive).
    pub fn new(c: Option<&AnyCsr>, sink: Option<&[f64]>, vol: &[f64], theta_tau: f64) -> Jacobi {
        let d = diagonal(c, sink, vol, theta_tau);
        Jacobi {
            inv: d.iter().map(|&d| if d > 0.0 { 1.0 / d } else { 0.0 }).collect(),
        }
    }
}

impl<S: Sweep> Precond<S> for Jacobi {
    fn apply(&mut self, _: &mut S, r: &[V3], z: &mut [V3]) {
        z.par_iter_mut()
            .zip(r.par_iter())
            .zip(self.inv.par_iter())
            .for_each(|((z, r), d)| {
                *z = [r[0] * d, r[1] * d, r[2] * d];
            });
    }
    fn inverse_diagonal(&self) -> Option<&[f64]> {
        Some(&self.inv)
    }
}

/// The diagonal of A = V - theta tau W on the owned rows: V_i (1 + theta tau (sum_j c_ij + s_i))
/// with s_i the screening sink (zero on rows that do not move, and everywhere without
/// coefficients).
pub fn diagonal(c: Option<&AnyCsr>, sink: Option<&[f64]>, vol: &[f64], theta_tau: f64) -> Vec<f64> {
    let Some(c) = c else {
        return vec![0.0; vol.len()];
    };
    (0..vol.len())
        .into_par_iter()
        .map(|i| {
            if vol[i] > 0.0 {
                let mut sum: f64 = c.row(i).map(|p| c.value(p)).sum();
                if let Some(s) = sink {
                    sum += s[i];
                }
                vol[i] * (1.0 + theta_tau * sum)
            } else {
                0.0
            }
        })
        .collect()
}
