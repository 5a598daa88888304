//! A direct solver of A = V - c W (the implicit integrator's matrix, `cg::Shifted`) for the
//! real-time mode (docs/realtime.md): A is factorised once at setup by CHOLMOD's sparse
//! Cholesky (SuiteSparse, through the thin C layer `cholmod.c`; found at build time, see
//! `build.rs`), and each solve is a pair of triangular solves for the three components.
//!
//! The factored matrix is A on the rows that move (`vol` > 0) with no row held. The rows a
//! kinematic tool holds (`Sweep::frozen`: Dirichlet rows, x_h = b_h / V_h) change from step to
//! step; the factor does not. The held set H enters through its capacitance (Schur
//! complement) form: with E the columns of the identity on H, Z = A^-1 E (one column per held
//! node, solved when the node joins and kept while it stays or returns soon) and
//! S = E^T Z = (A^-1)_HH (small, dense, factorised by Cholesky when H changes),
//!   y = A^-1 b,  S mu = g - E^T y,  x = y + Z mu,
//! x solves the free rows' equations with x = g on H. The rows that do not move (`vol` = 0)
//! keep their value: their coupling goes to the right-hand side.
//!
//! Several processes: every process gathers the whole matrix at setup and factorises it
//! (redundantly; the solver is for meshes of real-time size, `MAX_NODES`), and every solve
//! gathers the right-hand side and the held rows, solves the whole system and keeps its own
//! rows. The gathered system is numbered by global node id and each row's pairs are summed in
//! the order of their global ids, so every process computes the same bits on any number of
//! processes.

use super::{Sweep, V3};
use crate::distribute::comm::Comm;
use crate::distribute::field::NodeField;
use anyhow::{anyhow, bail, Result};
use fnv::FnvHashMap;
use nalgebra::DMatrix;

/// Whether the library was built with CHOLMOD (`build.rs`).
pub const HAS_DIRECT: bool = cfg!(eprop_cholmod);

/// The most nodes (over every process) the real-time mode factorises; above it it keeps
/// the fixed multigrid iterations. The factors of tetgen organ meshes measured 30-100 entries
/// per node at 1.5k-7k nodes (the fill grows with the mesh), and a step reads the factor four
/// times (two stages, two triangular solves each), about 1 ms per 1e5 entries on one core
/// (BENCHMARKS.md): near this limit a step takes tens of milliseconds, still below the fixed
/// iterations on meshes measured so far, and the factor's memory is on every process.
pub const MAX_NODES: usize = 60_000;
/// The most factor entries (8 bytes each, and a 4-byte row index, on every process) the
/// real-time mode accepts: about 720 MB. CHOLMOD's analysis counts them before the factor's
/// memory is taken.
pub const MAX_FACTOR_ENTRIES: f64 = 6e7;

#[cfg(eprop_cholmod)]
mod ffi {
    use std::os::raw::{c_double, c_int, c_void};
    extern "C" {
        pub fn eprop_cholmod_factor(
            n: c_int,
            colp: *const c_int,
            rowi: *const c_int,
            val: *const c_double,
            supernodal: c_int,
            max_lnz: c_double,
            lnz: *mut c_double,
            status: *mut c_int,
        ) -> *mut c_void;
        pub fn eprop_cholmod_solve(h: *mut c_void, k: c_int, b: *mut c_double) -> c_int;
        pub fn eprop_cholmod_free(h: *mut c_void);
    }
}

/// A sparse Cholesky factor of a symmetric positive definite matrix (CHOLMOD's).
pub struct Factor {
    #[cfg(eprop_cholmod)]
    h: *mut std::os::raw::c_void,
    n: usize,
    /// The entries of the factor.
    pub entries: f64,
}

// SAFETY: the factor is owned by this value alone, and CHOLMOD's calls on it are made through
// `&mut self` (one at a time).
unsafe impl Send for Factor {}

impl Factor {
    /// Factorises the n x n matrix whose upper triangle is given in compressed columns
    /// (`colp`, rows `rowi` ascending in each column, values `val`), unless the analysis
    /// finds that the factor would have more than `max_entries` entries.
    pub fn new(n: usize, colp: &[i32], rowi: &[i32], val: &[f64], max_entries: f64) -> Result<Factor> {
        assert_eq!(colp.len(), n + 1);
        assert_eq!(rowi.len(), colp[n] as usize);
        assert_eq!(val.len(), rowi.len());
        #[cfg(eprop_cholmod)]
        {
            let n_c = i32::try_from(n).map_err(|_| anyhow!("{n} rows are too many for a factor"))?;
            let (mut lnz, mut status) = (0.0f64, 0i32);
            // SAFETY: the arrays have the lengths CHOLMOD reads (checked above); it copies them
            let h = unsafe {
                ffi::eprop_cholmod_factor(
                    n_c,
                    colp.as_ptr(),
                    rowi.as_ptr(),
                    val.as_ptr(),
                    0,
                    max_entries,
                    &mut lnz,
                    &mut status,
                )
            };
            if h.is_null() {
                bail!(match status {
                    1 => "the matrix is not positive definite".to_string(),
                    3 =>
                        format!("its factor would have {lnz:.3e} entries, above the direct solver's {max_entries:.0e}"),
                    _ => "CHOLMOD could not factorise it (out of memory?)".to_string(),
                });
            }
            Ok(Factor { h, n, entries: lnz })
        }
        #[cfg(not(eprop_cholmod))]
        {
            let _ = (rowi, val, max_entries);
            bail!("this eprop was built without CHOLMOD (Debian: libsuitesparse-dev; it is found at build time) for {n} rows")
        }
    }

    /// Rows of the matrix.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Solves A X = B for `k` right-hand sides: `b` (n x k, one column after the other) is
    /// overwritten by X.
    pub fn solve(&mut self, b: &mut [f64], k: usize) {
        assert_eq!(b.len(), self.n * k);
        if k == 0 {
            return;
        }
        #[cfg(eprop_cholmod)]
        {
            // SAFETY: `b` holds n k values; the factor is alive
            let r = unsafe { ffi::eprop_cholmod_solve(self.h, k as i32, b.as_mut_ptr()) };
            assert_eq!(r, 0, "CHOLMOD's solve failed (out of memory)");
        }
    }
}

impl Drop for Factor {
    fn drop(&mut self) {
        #[cfg(eprop_cholmod)]
        // SAFETY: the handle came from eprop_cholmod_factor and is freed once
        unsafe {
            ffi::eprop_cholmod_free(self.h)
        }
    }
}

/// Not an unknown (a row that does not move).
const NONE: u32 = u32::MAX;
/// Values per owned row in a solve's gather: b (3), x (3), held (1).
const PER_ROW: usize = 7;
/// Rows per block of the held rows' correction y += Z mu (three components of 8 bytes and a
/// column's block: 32 KiB, within a core's L1 cache).
const Z_BLOCK: usize = 1024;

/// The held set's correction: the held unknowns (ascending), and the Cholesky factor of
/// S = (A^-1)_HH.
struct Held {
    rows: Vec<u32>,
    s: Option<nalgebra::linalg::Cholesky<f64, nalgebra::Dyn>>,
}

/// A = V - c W solved directly on the whole (gathered) system (see the module's text).
pub struct Direct {
    /// global slot (rank of the global id) of each gathered owned row, in rank order
    slot: Vec<u32>,
    /// unknown of each slot (NONE: a row that does not move)
    unknown: Vec<u32>,
    /// V and the slot of each unknown
    vol: Vec<f64>,
    slot_of: Vec<u32>,
    /// c V_a c_aj of unknown a's pairs with rows j that do not move, as (a, slot j, weight),
    /// in the order of a, then of j's global id
    fixed: Vec<(u32, u32, f64)>,
    factor: Factor,
    /// entries of A (both triangles)
    entries: usize,
    held: Held,
    /// A^-1 e_h of the held unknowns (and of some that were)
    columns: FnvHashMap<u32, Vec<f64>>,
    // work: the gathered values (slot order), the right-hand sides (unknowns, three columns)
    x_all: Vec<V3>,
    b_all: Vec<V3>,
    held_all: Vec<bool>,
    rhs: Vec<f64>,
    send: Vec<f64>,
}

impl Direct {
    /// Gathers A = V - c W on every process and factorises it: `vol` the volumes of the owned
    /// rows that move (0 elsewhere), `gid` the global ids of the local nodes (owned, then
    /// halo). Fails (the caller keeps its iterations) where the operator has no coefficients,
    /// rows are held already, the mesh has more than `MAX_NODES` nodes, A is not symmetric
    /// or not positive definite, or its factor would exceed `MAX_FACTOR_ENTRIES`.
    pub fn new<S: Sweep>(s: &S, vol: &[f64], c: f64, gid: &[u64], comm: &dyn Comm) -> Result<Direct> {
        let Some(coef) = s.coefficients() else {
            bail!("the operator has no coefficients")
        };
        if comm.max(f64::from(u8::from(!s.frozen().is_empty()))) > 0.0 {
            bail!("rows are held at setup");
        }
        let n_owned = vol.len();
        let nodes = comm.sum_i128(n_owned as i128) as usize;
        if nodes > MAX_NODES {
            bail!("{nodes} nodes, above the direct solver's {MAX_NODES}");
        }
        let sink = s.sink();
        // each owned row: gid, V, s, pairs, then (gid_j, c_ij) sorted by gid_j
        let mut send = Vec::new();
        let mut pairs: Vec<(u64, f64)> = Vec::new();
        for i in 0..n_owned {
            pairs.clear();
            pairs.extend(coef.row(i).map(|p| (gid[coef.col()[p] as usize], coef.value(p))));
            pairs.sort_by_key(|&(g, _)| g);
            send.extend([gid[i] as f64, vol[i], sink.map_or(0.0, |s| s[i]), pairs.len() as f64]);
            for &(g, v) in &pairs {
                send.extend([g as f64, v]);
            }
        }
        let (all, _) = comm.all_gather_var(&send);
        // the rows in gathered order
        struct Row {
            gid: u64,
            vol: f64,
            sink: f64,
            at: usize,
            len: usize,
        }
        let mut rows = Vec::with_capacity(nodes);
        let mut k = 0;
        while k < all.len() {
            let len = all[k + 3] as usize;
            rows.push(Row {
                gid: all[k] as u64,
                vol: all[k + 1],
                sink: all[k + 2],
                at: k + 4,
                len,
            });
            k += 4 + 2 * len;
        }
        let mut order: Vec<u32> = (0..rows.len() as u32).collect();
        order.sort_by_key(|&r| rows[r as usize].gid);
        let mut slot = vec![0u32; rows.len()];
        let mut slot_of_gid: FnvHashMap<u64, u32> = FnvHashMap::default();
        for (sl, &r) in order.iter().enumerate() {
            slot[r as usize] = sl as u32;
            slot_of_gid.insert(rows[r as usize].gid, sl as u32);
        }
        let mut unknown = vec![NONE; rows.len()];
        let (mut uvol, mut slot_of) = (Vec::new(), Vec::new());
        for (sl, &r) in order.iter().enumerate() {
            if rows[r as usize].vol > 0.0 {
                unknown[sl] = uvol.len() as u32;
                uvol.push(rows[r as usize].vol);
                slot_of.push(sl as u32);
            }
        }
        let nu = uvol.len();
        // the upper triangle by columns: (column b, row a, value) for a < b, then the diagonal
        let mut upper: Vec<(u32, u32, f64)> = Vec::new();
        let mut fixed = Vec::new();
        let mut lower: FnvHashMap<(u32, u32), f64> = FnvHashMap::default();
        let (mut asym, mut big) = (0.0f64, 0.0f64);
        for &r in &order {
            let row = &rows[r as usize];
            let Some(&sl) = slot_of_gid.get(&row.gid) else {
                unreachable!()
            };
            let a = unknown[sl as usize];
            if a == NONE {
                continue;
            }
            let mut sum = 0.0;
            for q in 0..row.len {
                let (g, cv) = (all[row.at + 2 * q] as u64, all[row.at + 2 * q + 1]);
                sum += cv;
                let Some(&sj) = slot_of_gid.get(&g) else {
                    bail!("node {} has a neighbour {g} no process owns", row.gid)
                };
                let b = unknown[sj as usize];
                let v = -c * row.vol * cv;
                big = big.max(v.abs());
                if b == NONE {
                    fixed.push((a, sj, c * row.vol * cv));
                } else if b > a {
                    upper.push((b, a, v));
                    lower.insert((a, b), v);
                } else if b < a {
                    match lower.remove(&(b, a)) {
                        Some(w) => asym = asym.max((w - v).abs()),
                        None => asym = asym.max(v.abs()),
                    }
                }
            }
            upper.push((a, a, row.vol * (1.0 + c * (sum + row.sink))));
        }
        for (_, w) in lower {
            asym = asym.max(w.abs());
        }
        if asym > 1e-10 * big {
            bail!("the matrix is not symmetric (|A_ij - A_ji| up to {asym:.1e} of {big:.1e})");
        }
        upper.sort_by_key(|&(b, a, _)| (b, a));
        let mut colp = vec![0i32; nu + 1];
        for &(b, _, _) in &upper {
            colp[b as usize + 1] += 1;
        }
        for j in 0..nu {
            colp[j + 1] += colp[j];
        }
        let rowi: Vec<i32> = upper.iter().map(|&(_, a, _)| a as i32).collect();
        let val: Vec<f64> = upper.iter().map(|&(_, _, v)| v).collect();
        let factor = Factor::new(nu, &colp, &rowi, &val, MAX_FACTOR_ENTRIES)?;
        tracing::debug!(
            "direct solver: {nu} unknowns of {nodes} nodes, {} entries in the upper triangle, {:.3e} in the factor; symmetric to {asym:.1e} of {big:.1e}",
            rowi.len(),
            factor.entries
        );
        Ok(Direct {
            slot,
            unknown,
            vol: uvol,
            slot_of,
            fixed,
            factor,
            entries: 2 * rowi.len() - nu,
            held: Held {
                rows: Vec::new(),
                s: None,
            },
            columns: FnvHashMap::default(),
            x_all: vec![[0.0; 3]; nodes],
            b_all: vec![[0.0; 3]; nodes],
            held_all: vec![false; nodes],
            rhs: vec![0.0; 3 * nu],
            send: Vec::with_capacity(PER_ROW * n_owned),
        })
    }

    /// The unknowns (rows that move, over every process).
    pub fn unknowns(&self) -> usize {
        self.vol.len()
    }

    /// The entries of the factor.
    pub fn factor_entries(&self) -> f64 {
        self.factor.entries
    }

    /// The entries of A (both triangles).
    pub fn matrix_entries(&self) -> usize {
        self.entries
    }

    /// The held unknowns now.
    pub fn held(&self) -> usize {
        self.held.rows.len()
    }

    /// Solves A x = b on the owned rows that move, the held rows (`s.frozen()`) at b / V and
    /// the rows that do not move at x's value (x's owned rows are read as the values there).
    /// Every process calls it at the same point.
    pub fn solve<S: Sweep>(&mut self, s: &S, x: &mut NodeField<V3>, b: &[V3], comm: &dyn Comm) -> Result<()> {
        let n_owned = b.len();
        self.send.clear();
        let frozen = s.frozen();
        let mut held = vec![false; n_owned];
        for &i in frozen {
            held[i as usize] = true;
        }
        for i in 0..n_owned {
            let (bi, xi) = (b[i], x[i]);
            self.send
                .extend([bi[0], bi[1], bi[2], xi[0], xi[1], xi[2], f64::from(u8::from(held[i]))]);
        }
        let (all, counts) = comm.all_gather_var(&self.send);
        if all.len() != PER_ROW * self.slot.len() {
            bail!(
                "the direct solver's gather has {} values for {} rows ({counts:?})",
                all.len(),
                self.slot.len()
            );
        }
        for (r, &sl) in self.slot.iter().enumerate() {
            let v = &all[PER_ROW * r..PER_ROW * (r + 1)];
            let sl = sl as usize;
            self.b_all[sl] = [v[0], v[1], v[2]];
            self.x_all[sl] = [v[3], v[4], v[5]];
            self.held_all[sl] = v[6] != 0.0;
        }
        // right-hand sides of the unknowns, the rows that do not move carried over
        let nu = self.vol.len();
        let mut rows = Vec::new();
        for (sl, &a) in self.unknown.iter().enumerate() {
            if a == NONE {
                continue;
            }
            for d in 0..3 {
                self.rhs[d * nu + a as usize] = self.b_all[sl][d];
            }
            if self.held_all[sl] {
                rows.push(a);
            }
        }
        for &(a, sj, w) in &self.fixed {
            let xj = self.x_all[sj as usize];
            for d in 0..3 {
                self.rhs[d * nu + a as usize] += w * xj[d];
            }
        }
        self.set_held(rows)?;
        self.factor.solve(&mut self.rhs, 3);
        // the held rows: S mu = g - y_H, x = y + Z mu, x_H = g
        if let Some(sf) = &self.held.s {
            let m = self.held.rows.len();
            let g: Vec<V3> = self
                .held
                .rows
                .iter()
                .map(|&a| {
                    let sl = self.slot_of[a as usize] as usize;
                    let v = self.vol[a as usize];
                    [0, 1, 2].map(|d| self.b_all[sl][d] / v)
                })
                .collect();
            let mut r = DMatrix::<f64>::zeros(m, 3);
            for (p, &a) in self.held.rows.iter().enumerate() {
                for d in 0..3 {
                    r[(p, d)] = g[p][d] - self.rhs[d * nu + a as usize];
                }
            }
            let mu = sf.solve(&r);
            // y += Z mu by blocks of rows: each block of the three components stays in the
            // cache while the held columns pass over it, so each column is read once (not
            // once per component); every entry adds the columns in the held rows' order, as
            // a column at a time would, so the bits do not change
            let z: Vec<&[f64]> = self.held.rows.iter().map(|a| &self.columns[a][..]).collect();
            let (y0, rest) = self.rhs.split_at_mut(nu);
            let (y1, y2) = rest.split_at_mut(nu);
            for lo in (0..nu).step_by(Z_BLOCK) {
                let hi = (lo + Z_BLOCK).min(nu);
                let (b0, b1, b2) = (&mut y0[lo..hi], &mut y1[lo..hi], &mut y2[lo..hi]);
                for (p, zp) in z.iter().enumerate() {
                    let zp = &zp[lo..hi];
                    for (y, d) in [(&mut *b0, 0), (&mut *b1, 1), (&mut *b2, 2)] {
                        let md = mu[(p, d)];
                        for (yi, zi) in y.iter_mut().zip(zp) {
                            *yi += md * zi;
                        }
                    }
                }
            }
            for (p, &a) in self.held.rows.iter().enumerate() {
                for d in 0..3 {
                    self.rhs[d * nu + a as usize] = g[p][d];
                }
            }
        }
        // this process's rows (the first gathered rows of rank r follow those of ranks < r)
        let start: usize = counts[..comm.rank()].iter().sum::<usize>() / PER_ROW;
        for i in 0..n_owned {
            let a = self.unknown[self.slot[start + i] as usize];
            if a != NONE {
                x[i] = [0, 1, 2].map(|d| self.rhs[d * nu + a as usize]);
            }
        }
        Ok(())
    }

    /// Makes `rows` (held unknowns, ascending) the held set: the columns A^-1 e_h of the rows
    /// that join (one solve for all of them) and the Cholesky factor of S = (A^-1)_HH.
    fn set_held(&mut self, rows: Vec<u32>) -> Result<()> {
        if rows == self.held.rows {
            return Ok(());
        }
        let nu = self.vol.len();
        let new: Vec<u32> = rows.iter().copied().filter(|a| !self.columns.contains_key(a)).collect();
        if !new.is_empty() {
            let mut z = vec![0.0; nu * new.len()];
            for (k, &a) in new.iter().enumerate() {
                z[k * nu + a as usize] = 1.0;
            }
            self.factor.solve(&mut z, new.len());
            for (k, &a) in new.iter().enumerate() {
                self.columns.insert(a, z[k * nu..(k + 1) * nu].to_vec());
            }
        }
        // keep the columns of rows that left while few are kept (a tool that slides back)
        if self.columns.len() > 2 * rows.len() + 64 {
            self.columns.retain(|a, _| rows.binary_search(a).is_ok());
        }
        let m = rows.len();
        self.held.s = if m == 0 {
            None
        } else {
            let s = DMatrix::<f64>::from_fn(m, m, |p, q| {
                let (zp, zq) = (&self.columns[&rows[p]], &self.columns[&rows[q]]);
                0.5 * (zq[rows[p] as usize] + zp[rows[q] as usize])
            });
            Some(
                nalgebra::linalg::Cholesky::new(s)
                    .ok_or_else(|| anyhow!("the held rows' capacitance matrix is not positive definite"))?,
            )
        };
        self.held.rows = rows;
        Ok(())
    }
}
