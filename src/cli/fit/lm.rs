//! A bounded Levenberg-Marquardt on residual vectors that each cost a full simulation.

/// Why the search stopped.
#[derive(Clone, Debug, PartialEq)]
pub enum Stop {
    /// An accepted step reduced the sum of squares by less than the tolerance (relative).
    Reduction,
    /// The step changed every parameter by less than the tolerance.
    Step,
    /// The residual is zero.
    Exact,
    /// The evaluation budget is spent.
    Evaluations,
    /// No step reduced the sum of squares, however short.
    NoDecrease,
    /// Every parameter is at a bound that the gradient pushes against.
    Bounds,
}

impl Stop {
    pub fn text(&self) -> &'static str {
        match self {
            Stop::Reduction => "the sum of squares decreased by less than the tolerance",
            Stop::Step => "the step changed every parameter by less than the tolerance",
            Stop::Exact => "the residual is zero",
            Stop::Evaluations => "the evaluation budget (--max-evaluations) is spent",
            Stop::NoDecrease => "no step reduced the sum of squares",
            Stop::Bounds => "every parameter is held at a bound",
        }
    }
}

/// The problem in the fitting coordinates z (each within [lo, hi]).
pub struct Problem<'a> {
    pub lo: Vec<f64>,
    pub hi: Vec<f64>,
    /// The residuals at z, or why there are none (a rejected point).
    pub residuals: &'a mut dyn FnMut(&[f64], &str) -> anyhow::Result<Result<Vec<f64>, String>>,
    /// Maximum evaluations of the search (the start counts).
    pub max_evaluations: usize,
    /// Relative reduction of the sum of squares, and step in z relative to |z| (>= 1) ...
    pub tolerance: f64,
}

/// The search's end point.
pub struct Solution {
    pub z: Vec<f64>,
    pub r: Vec<f64>,
    /// dr/dz at `z` (rows: residuals), or None when it was never computed there.
    pub jacobian: Option<Vec<Vec<f64>>>,
    pub evaluations: usize,
    pub iterations: usize,
    pub stop: Stop,
}

fn ss(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Forward-difference step of coordinate j: 1e-6 of its range, pointing into the bounds.
fn fd_step(lo: f64, hi: f64, z: f64) -> f64 {
    let h = 1e-6 * (hi - lo);
    if z + h <= hi {
        h
    } else {
        -h
    }
}

/// Solves A x = b (n small) by Gaussian elimination with partial pivoting; None when A is
/// singular.
pub fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(scale > 0.0) || !scale.is_finite() {
        return None;
    }
    for c in 0..n {
        let p = (c..n).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if !(a[p][c].abs() > 1e-14 * scale) {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        for r in c + 1..n {
            let f = a[r][c] / a[c][c];
            for k in c..n {
                a[r][k] -= f * a[c][k];
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = vec![0.0; n];
    for c in (0..n).rev() {
        let s: f64 = (c + 1..n).map(|k| a[c][k] * x[k]).sum();
        x[c] = (b[c] - s) / a[c][c];
    }
    Some(x)
}

/// The inverse of a small symmetric positive definite matrix (None when singular).
pub fn inverse(a: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let n = a.len();
    let mut cols = vec![];
    for j in 0..n {
        let mut e = vec![0.0; n];
        e[j] = 1.0;
        cols.push(solve(a.to_vec(), e)?);
    }
    Some((0..n).map(|i| (0..n).map(|j| cols[j][i]).collect()).collect())
}

/// The Jacobian dr/dz at z (r0 = r(z)) by forward differences, one evaluation per column
/// (the other side of z when the first is rejected).
pub fn jacobian(
    p: &mut Problem,
    z: &[f64],
    r0: &[f64],
    names: &[String],
    evals: &mut usize,
) -> anyhow::Result<Vec<Vec<f64>>> {
    let (m, n) = (r0.len(), z.len());
    let mut jac = vec![vec![0.0; n]; m];
    for j in 0..n {
        let mut h = fd_step(p.lo[j], p.hi[j], z[j]);
        let mut tried = 0;
        let rj = loop {
            let mut zz = z.to_vec();
            zz[j] += h;
            *evals += 1;
            match (p.residuals)(&zz, &format!("derivative {}", names[j]))? {
                Ok(r) => break r,
                Err(why) if tried == 0 && z[j] - h >= p.lo[j] && z[j] - h <= p.hi[j] => {
                    tracing::info!("derivative {}: {why}; the other side", names[j]);
                    h = -h;
                    tried += 1;
                }
                Err(why) => anyhow::bail!(
                    "the derivative by {} could not be computed: {why}; fix: narrow its bounds away from where the simulation fails",
                    names[j]
                ),
            }
        };
        for i in 0..m {
            jac[i][j] = (rj[i] - r0[i]) / h;
        }
    }
    Ok(jac)
}

/// Minimises |r(z)|^2 from z0 within [lo, hi]: Levenberg-Marquardt with Marquardt's
/// scaling diag(J^T J), steps projected onto the bounds, and the coordinates at a bound
/// held there while the gradient pushes out of it.
pub fn minimize(p: &mut Problem, z0: Vec<f64>, names: &[String]) -> anyhow::Result<Solution> {
    let n = z0.len();
    let mut evals = 1;
    let mut r = match (p.residuals)(&z0, "start")? {
        Ok(r) => r,
        Err(why) => anyhow::bail!(
            "at the starting values {why}; fix: a scenario whose run covers the curve (a later [time] end, a deeper tool path) and stays finite, or other starting values"
        ),
    };
    let mut z = z0;
    let mut cost = ss(&r);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let done = |z: Vec<f64>, r, jacobian, evaluations, iterations, stop| Solution {
        z,
        r,
        jacobian,
        evaluations,
        iterations,
        stop,
    };
    loop {
        if cost == 0.0 {
            return Ok(done(z, r, None, evals, iterations, Stop::Exact));
        }
        if evals + n + 1 > p.max_evaluations {
            return Ok(done(z, r, None, evals, iterations, Stop::Evaluations));
        }
        iterations += 1;
        let jac = jacobian(p, &z, &r, names, &mut evals)?;
        let m = r.len();
        let mut a = vec![vec![0.0; n]; n];
        let mut g = vec![0.0; n];
        for i in 0..m {
            for j in 0..n {
                g[j] += jac[i][j] * r[i];
                for k in 0..n {
                    a[j][k] += jac[i][j] * jac[i][k];
                }
            }
        }
        // held: at a bound with the descent direction -g pointing out of it
        let free: Vec<usize> = (0..n)
            .filter(|&j| !((z[j] <= p.lo[j] && g[j] > 0.0) || (z[j] >= p.hi[j] && g[j] < 0.0)))
            .collect();
        if free.is_empty() {
            return Ok(done(z, r, Some(jac), evals, iterations, Stop::Bounds));
        }
        let dmax = free.iter().map(|&j| a[j][j]).fold(0.0f64, f64::max);
        loop {
            if evals >= p.max_evaluations {
                return Ok(done(z, r, Some(jac), evals, iterations, Stop::Evaluations));
            }
            if lambda > 1e16 {
                return Ok(done(z, r, Some(jac), evals, iterations, Stop::NoDecrease));
            }
            let sub: Vec<Vec<f64>> = free
                .iter()
                .map(|&j| {
                    free.iter()
                        .map(|&k| {
                            a[j][k]
                                + if j == k {
                                    lambda * a[j][j].max(1e-12 * dmax)
                                } else {
                                    0.0
                                }
                        })
                        .collect()
                })
                .collect();
            let rhs: Vec<f64> = free.iter().map(|&j| -g[j]).collect();
            let Some(d) = solve(sub, rhs) else {
                lambda *= 10.0;
                continue;
            };
            let mut zt = z.clone();
            for (&j, dj) in free.iter().zip(&d) {
                zt[j] = (z[j] + dj).clamp(p.lo[j], p.hi[j]);
            }
            let small = (0..n).all(|j| (zt[j] - z[j]).abs() <= p.tolerance * z[j].abs().max(1.0));
            if zt == z {
                return Ok(done(z, r, Some(jac), evals, iterations, Stop::Step));
            }
            evals += 1;
            let trial = (p.residuals)(&zt, &format!("step (lambda {lambda:.0e})"))?;
            match trial {
                Ok(rt) if ss(&rt) < cost => {
                    let ct = ss(&rt);
                    let reduction = (cost - ct) / cost;
                    z = zt;
                    r = rt;
                    cost = ct;
                    lambda = (lambda / 10.0).max(1e-12);
                    if cost == 0.0 {
                        return Ok(done(z, r, None, evals, iterations, Stop::Exact));
                    }
                    if reduction <= p.tolerance {
                        return Ok(done(z, r, None, evals, iterations, Stop::Reduction));
                    }
                    if small {
                        return Ok(done(z, r, None, evals, iterations, Stop::Step));
                    }
                    break;
                }
                _ => {
                    if small {
                        return Ok(done(z, r, Some(jac), evals, iterations, Stop::Step));
                    }
                    lambda *= 10.0;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lm_recovers_an_exponential_within_bounds() {
        // y = a exp(-b t) from (a, b) = (2, 0.5), fitted in (ln a, ln b)
        let t: Vec<f64> = (0..20).map(|k| k as f64 * 0.25).collect();
        let y: Vec<f64> = t.iter().map(|t| 2.0 * (-0.5 * t).exp()).collect();
        let mut f = |z: &[f64], _: &str| -> anyhow::Result<Result<Vec<f64>, String>> {
            let (a, b) = (z[0].exp(), z[1].exp());
            Ok(Ok(t.iter().zip(&y).map(|(t, y)| a * (-b * t).exp() - y).collect()))
        };
        let mut p = Problem {
            lo: vec![0.1f64.ln(), 0.01f64.ln()],
            hi: vec![10f64.ln(), 5f64.ln()],
            residuals: &mut f,
            max_evaluations: 200,
            tolerance: 1e-10,
        };
        let s = minimize(&mut p, vec![0.5f64.ln(), 2f64.ln()], &["a".into(), "b".into()]).unwrap();
        assert!((s.z[0].exp() - 2.0).abs() < 1e-6, "{:?}", s.z);
        assert!((s.z[1].exp() - 0.5).abs() < 1e-6, "{:?}", s.z);
        // a bound below the truth: held at the bound
        let mut p2 = Problem {
            lo: vec![0.1f64.ln(), 0.01f64.ln()],
            hi: vec![1.5f64.ln(), 5f64.ln()],
            residuals: &mut f,
            max_evaluations: 200,
            tolerance: 1e-10,
        };
        let s = minimize(&mut p2, vec![0.5f64.ln(), 2f64.ln()], &["a".into(), "b".into()]).unwrap();
        assert!((s.z[0].exp() - 1.5).abs() < 1e-12, "{:?}", s.z);
    }
}
