//! The discrete operator L of the vector Poisson equation and its explicit Euler step
//! (docs/model.md section 3), in the two schemes.
//!
//! Layout: CSR (`linalg::csr`) over the rows a process updates (owned nodes), neighbour index
//! (u32, local numbering, halo nodes after owned ones) and per-pair coefficients; the
//! potential is an array of 3-vectors so one gather fetches all three components. A row is a fixed-order sum
//! over its neighbours (sorted by global id): no atomics, the same bits on any partition and
//! any thread count. Rows of Dirichlet or inactive nodes are empty and never change.

use crate::config::tissue::Materials;
use crate::discretize::geometry::Dual;
use crate::linalg::csr::{AnyCsr, Csr, Scalar};
use eprop_io::geom::{dot, sub};
use nalgebra::Vector3;
use rayon::prelude::*;

use crate::linalg::V3;

/// Rows per rayon task: large enough to amortise scheduling, small enough to balance.
const CHUNK: usize = 2048;

/// `compact` scheme: (L u)_i = sum_j c_ij (u_j - u_i) - s_i u_i, c_ij = a_ij / V_i, s_i the
/// screening sink (zero without `[model] screening`).
#[derive(Clone)]
pub struct Compact {
    /// c_ij on the stored pairs, in float64 or float32 (`into_f32`); its `n_cols`, one more
    /// than the largest neighbour index, is the least length of the potential.
    coef: AnyCsr,
    /// The screening sink s_i = D_i / l^2 of each row (`with_sink`; None: no sink, and not a
    /// bit of the step changes).
    sink: Option<Vec<f64>>,
    /// Which kernel the step runs (`Kernel::default()`: the fastest this CPU has; `kernel`,
    /// `set_kernel`).
    pub(crate) kernel: Kernel,
}

/// The kernel of the `compact` step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Kernel {
    /// 256-bit vectors with fused multiply-add (x86-64 with AVX2 and FMA only; `[performance]
    /// simd = false` turns it off).
    pub vector: bool,
}

impl Default for Kernel {
    fn default() -> Self {
        Kernel {
            vector: simd_available(),
        }
    }
}

impl Compact {
    /// Like `new`, taking the pair columns and a_ij over and compacting them in place (no
    /// second copy of the largest arrays at the peak of the setup).
    pub fn from_pairs(row_ptr: &[usize], mut col: Vec<u32>, mut a: Vec<f64>, vol: &[f64], update: &[bool]) -> Compact {
        let n_rows = row_ptr.len() - 1;
        assert!(
            col.len() < u32::MAX as usize,
            "more than 2^32 stored pairs in one process"
        );
        let mut ptr = Vec::with_capacity(n_rows + 1);
        ptr.push(0u32);
        let mut w = 0;
        for i in 0..n_rows {
            if update[i] {
                let inv = 1.0 / vol[i];
                for p in row_ptr[i]..row_ptr[i + 1] {
                    col[w] = col[p];
                    a[w] = a[p] * inv;
                    w += 1;
                }
            }
            ptr.push(w as u32);
        }
        col.truncate(w);
        a.truncate(w);
        col.shrink_to_fit();
        a.shrink_to_fit();
        let n_cols = col.iter().map(|&j| j as usize + 1).max().unwrap_or(0).max(n_rows);
        Compact::from_csr(AnyCsr::F64(Csr {
            n_cols,
            ptr,
            col,
            val: a,
        }))
    }

    /// The operator of the coefficients `coef` (the potential must be at least `n_cols` long),
    /// with the default kernel.
    pub fn from_csr(coef: AnyCsr) -> Compact {
        Compact {
            coef,
            sink: None,
            kernel: Kernel::default(),
        }
    }

    /// The same operator with the screening sink s_i on row i (`sink` has one value per row;
    /// rows that do not move must have 0).
    pub fn with_sink(mut self, sink: Vec<f64>) -> Compact {
        assert_eq!(sink.len(), self.coef.n_rows(), "one sink per row");
        self.sink = Some(sink);
        self
    }

    /// The screening sink of each row (None: none).
    pub fn sink(&self) -> Option<&[f64]> {
        self.sink.as_deref()
    }

    /// The coefficients c_ij.
    pub fn coefficients(&self) -> &AnyCsr {
        &self.coef
    }

    /// The row pointers: row i's pairs are `row_ptr()[i]..row_ptr()[i + 1]`.
    pub fn row_ptr(&self) -> &[u32] {
        self.coef.ptr()
    }

    /// The neighbour (local index) of each stored pair.
    pub fn col(&self) -> &[u32] {
        self.coef.col()
    }

    /// One more than the largest neighbour index: the potential must be at least this long.
    pub fn n_cols(&self) -> usize {
        self.coef.n_cols()
    }

    /// Whether the coefficients are stored in float32.
    pub fn is_f32(&self) -> bool {
        self.coef.is_f32()
    }

    /// The same pattern with the coefficient `c[p]` on pair p in float32, and this kernel (a
    /// preconditioner's own operator, without the screening sink: the preconditioner's
    /// hierarchy is built from the coefficients alone).
    pub fn with_f32(&self, c: Vec<f32>) -> Compact {
        Compact {
            coef: AnyCsr::F32(self.coef.with_values(c)),
            sink: None,
            kernel: self.kernel,
        }
    }

    /// `a` holds a_ij on the pair graph of `dual`; rows with `update[i] == false` are emptied.
    pub fn new(dual: &Dual, a: &[f64], update: &[bool]) -> Compact {
        let pairs = dual.row_ptr[dual.n_rows];
        let rows = &dual.row_ptr[..=dual.n_rows];
        Self::from_pairs(rows, dual.col[..pairs].to_vec(), a[..pairs].to_vec(), &dual.vol, update)
    }

    /// The kernel the step runs.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// Runs the step with `kernel` (the vector kernel only where this CPU has it, whatever
    /// `kernel` says).
    pub fn set_kernel(&mut self, kernel: Kernel) {
        self.kernel = kernel;
    }

    /// Stores the coefficients in float32 (a third fewer bytes per substep; the rounded
    /// coefficients define the operator, so results stay deterministic).
    pub fn into_f32(self) -> Compact {
        Compact {
            coef: self.coef.into_f32(),
            sink: self.sink,
            kernel: self.kernel,
        }
    }

    /// (L x)_i, the sink included.
    #[inline(always)]
    fn row(&self, i: usize, x: &[V3]) -> V3 {
        let l = self.row_s::<3>(i, x.as_flattened());
        match &self.sink {
            None => l,
            Some(s) => screened(l, s[i], x[i]),
        }
    }

    /// (L x)_i with x given flat, `S` values per node (the first three are the potential).
    #[inline(always)]
    fn row_s<const S: usize>(&self, i: usize, x: &[f64]) -> V3 {
        match &self.coef {
            AnyCsr::F64(a) => Self::row_with::<_, S>(a, i, x),
            AnyCsr::F32(a) => Self::row_with::<_, S>(a, i, x),
        }
    }

    /// The coefficient of stored pair p.
    pub fn c(&self, p: usize) -> f64 {
        self.coef.value(p)
    }

    /// Empties `rows` (their potential then stays as it is: Dirichlet rows), appending their
    /// coefficients to `saved` for `thaw`.
    pub fn freeze(&mut self, rows: &[u32], saved: &mut Vec<f64>) {
        for &i in rows {
            for p in self.coef.row(i as usize) {
                saved.push(self.coef.value(p));
                self.coef.set_value(p, 0.0);
            }
            if let Some(s) = &mut self.sink {
                saved.push(s[i as usize]);
                s[i as usize] = 0.0;
            }
        }
    }

    /// Gives `rows`, frozen by `freeze` with `saved`, their coefficients back.
    pub fn thaw(&mut self, rows: &[u32], saved: &[f64]) {
        let mut k = 0;
        for &i in rows {
            for p in self.coef.row(i as usize) {
                self.coef.set_value(p, saved[k]);
                k += 1;
            }
            if let Some(s) = &mut self.sink {
                s[i as usize] = saved[k];
                k += 1;
            }
        }
    }

    /// (L x)_i. Pairs are taken two at a time into two partial sums (a fixed order, so
    /// the same bits on any partition): one chain of dependent additions per sum would
    /// otherwise bound the speed by the add latency instead of the memory bandwidth.
    #[inline(always)]
    fn row_with<C: Scalar, const S: usize>(a: &Csr<C>, i: usize, x: &[f64]) -> V3 {
        let (s, e) = (a.ptr[i] as usize, a.ptr[i + 1] as usize);
        let at = |j: usize| [x[S * j], x[S * j + 1], x[S * j + 2]];
        let xi = at(i);
        let cols = &a.col[s..e];
        let coef = &a.val[s..e];
        let mut a = [0.0; 3];
        let mut b = [0.0; 3];
        let pairs = cols.len() / 2;
        for k in 0..pairs {
            let (j0, j1) = (cols[2 * k] as usize, cols[2 * k + 1] as usize);
            let (c0, c1): (f64, f64) = (coef[2 * k].into(), coef[2 * k + 1].into());
            let (x0, x1) = (at(j0), at(j1));
            for d in 0..3 {
                a[d] += c0 * (x0[d] - xi[d]);
                b[d] += c1 * (x1[d] - xi[d]);
            }
        }
        if cols.len() % 2 == 1 {
            let j = cols[cols.len() - 1] as usize;
            let c: f64 = coef[cols.len() - 1].into();
            let xj = at(j);
            for d in 0..3 {
                a[d] += c * (xj[d] - xi[d]);
            }
        }
        [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
    }

    /// y_i = x_i + h (L x)_i for the rows `start..start + y.len() / SO` with the vector kernel,
    /// when it is chosen and this CPU has it; false (nothing done) otherwise.
    #[inline]
    fn vector_step<const SI: usize, const SO: usize>(&self, x: &[f64], y: &mut [f64], h: f64, start: usize) -> bool {
        #[cfg(target_arch = "x86_64")]
        if self.kernel.vector && simd_available() {
            // SAFETY: the CPU has AVX2 and FMA (`simd_available`), every column index is below
            // `n_cols` and `x` holds at least that many nodes (checked by the caller).
            unsafe {
                match &self.coef {
                    AnyCsr::F64(a) => avx::step_rows::<_, SI, SO>(&a.ptr, &a.col, &a.val, x, y, h, start),
                    AnyCsr::F32(a) => avx::step_rows::<_, SI, SO>(&a.ptr, &a.col, &a.val, x, y, h, start),
                }
            }
            return true;
        }
        let _ = (x, y, h, start);
        false
    }

    /// y_i = x_i + h (L x)_i for the rows `start..start + y.len()` on this thread: the vector
    /// kernel when chosen, the portable one otherwise. A row's bits do not depend on which
    /// rows are taken together.
    pub fn step_range(&self, x: &[V3], y: &mut [V3], h: f64, start: usize) {
        self.step_strided::<3, 3>(x.as_flattened(), y.as_flattened_mut(), h, start)
    }

    /// `step_range` on flat arrays of `SI` (input) and `SO` (output) values per node, 3 or 4:
    /// the first three are the potential; a fourth input value is never used in a sum (padding
    /// that lets a node's potential be one 256-bit load); the fourth output value is the
    /// fourth input value plus h times a sum of zeros. The potential's bits do not depend on
    /// the strides.
    pub fn step_strided<const SI: usize, const SO: usize>(&self, x: &[f64], y: &mut [f64], h: f64, start: usize) {
        const { assert!((SI == 3 || SI == 4) && (SO == 3 || SO == 4)) };
        assert!(
            x.len() >= SI * self.n_cols(),
            "potential shorter than the operator's columns"
        );
        assert!(
            y.len().is_multiple_of(SO) && self.row_ptr().len() > start + y.len() / SO,
            "rows out of range"
        );
        if !self.vector_step::<SI, SO>(x, y, h, start) {
            for (k, yi) in y.chunks_exact_mut(SO).enumerate() {
                let i = start + k;
                let l = self.row_s::<SI>(i, x);
                for d in 0..3 {
                    yi[d] = x[SI * i + d] + h * l[d];
                }
                if SO == 4 {
                    yi[3] = if SI == 4 { x[SI * i + 3] } else { 0.0 };
                }
            }
        }
        // the sink after either kernel's step: y_i <- (x_i + h sum_j c_ij (x_j - x_i)) - h s_i x_i
        if let Some(s) = &self.sink {
            for (k, yi) in y.chunks_exact_mut(SO).enumerate() {
                let i = start + k;
                let hs = h * s[i];
                for d in 0..3 {
                    yi[d] -= hs * x[SI * i + d];
                }
            }
        }
    }

    /// The same operator with its rows and columns renumbered: old index i becomes `new_of[i]`
    /// (a permutation of `0..n_cols`); each row keeps the order of its pairs, so its bits.
    pub fn permuted(&self, new_of: &[u32]) -> Compact {
        let coef = match &self.coef {
            AnyCsr::F64(a) => AnyCsr::F64(permuted(a, new_of)),
            AnyCsr::F32(a) => AnyCsr::F32(permuted(a, new_of)),
        };
        let sink = self.sink.as_ref().map(|s| {
            let mut t = vec![0.0; s.len()];
            for (i, &v) in s.iter().enumerate() {
                t[new_of[i] as usize] = v;
            }
            t
        });
        Compact {
            coef,
            sink,
            kernel: self.kernel,
        }
    }

    /// y_i <- f(acc, i, x_i, (L x)_i, y_i) for the rows `start..start + y.len()` with the vector
    /// kernel (the same row sums as the Euler step's), when it is chosen and this CPU has it;
    /// false (nothing done) otherwise.
    #[inline]
    fn vector_update<A, F>(&self, x: &[V3], y: &mut [V3], start: usize, acc: &mut A, f: &F) -> bool
    where
        F: Fn(&mut A, usize, V3, V3, &mut V3),
    {
        #[cfg(target_arch = "x86_64")]
        if self.kernel.vector && simd_available() {
            let Some(s) = &self.sink else {
                // SAFETY: as in `vector_step`
                unsafe {
                    match &self.coef {
                        AnyCsr::F64(a) => avx_u::update_rows(&a.ptr, &a.col, &a.val, x, y, start, acc, f),
                        AnyCsr::F32(a) => avx_u::update_rows(&a.ptr, &a.col, &a.val, x, y, start, acc, f),
                    }
                }
                return true;
            };
            let g = |acc: &mut A, i: usize, xi: V3, l: V3, yi: &mut V3| f(acc, i, xi, screened(l, s[i], xi), yi);
            // SAFETY: as in `vector_step`
            unsafe {
                match &self.coef {
                    AnyCsr::F64(a) => avx_u::update_rows(&a.ptr, &a.col, &a.val, x, y, start, acc, &g),
                    AnyCsr::F32(a) => avx_u::update_rows(&a.ptr, &a.col, &a.val, x, y, start, acc, &g),
                }
            }
            return true;
        }
        let _ = (x, y, start, acc, f);
        false
    }

    /// Gershgorin bound of the spectral radius of L.
    pub fn gershgorin(&self) -> f64 {
        self.row_bounds().into_iter().fold(0.0, f64::max)
    }

    /// The Gershgorin bound of every row, |sum_j c_ij + s_i| + sum_j |c_ij| (0 for empty rows).
    pub fn row_bounds(&self) -> Vec<f64> {
        (0..self.coef.n_rows())
            .map(|i| {
                let r = self.coef.row(i);
                let sum: f64 = r.clone().map(|p| self.c(p)).sum();
                let abs: f64 = r.map(|p| self.c(p).abs()).sum();
                match &self.sink {
                    None => sum.abs() + abs,
                    Some(s) => (sum + s[i]).abs() + abs,
                }
            })
            .collect()
    }
}

/// l - s x: a row sum with the screening sink s of its node, whose potential is x.
#[inline(always)]
fn screened(l: V3, s: f64, x: V3) -> V3 {
    [l[0] - s * x[0], l[1] - s * x[1], l[2] - s * x[2]]
}

/// `a` with its rows and columns renumbered (`Compact::permuted`).
fn permuted<C: Scalar>(a: &Csr<C>, new_of: &[u32]) -> Csr<C> {
    let n = a.n_rows();
    assert_eq!(new_of.len(), n, "one new index per row");
    let mut old_of = vec![0u32; n];
    for (i, &r) in new_of.iter().enumerate() {
        old_of[r as usize] = i as u32;
    }
    let mut ptr = Vec::with_capacity(n + 1);
    ptr.push(0u32);
    let (mut col, mut val) = (vec![], vec![]);
    for &i in &old_of {
        let r = a.row(i as usize);
        col.extend(a.col[r.clone()].iter().map(|&j| new_of[j as usize]));
        val.extend_from_slice(&a.val[r]);
        ptr.push(col.len() as u32);
    }
    Csr {
        n_cols: a.n_cols,
        ptr,
        col,
        val,
    }
}

/// Whether the vector kernel of the `compact` step runs on this CPU (x86-64 with AVX2 and
/// FMA). `[performance] simd = false` (or `eprop bench --simd off`) runs the portable kernel
/// instead (different rounding, no FMA).
pub fn simd_available() -> bool {
    static ON: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *ON.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        {
            is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            false
        }
    })
}

/// The `compact` step with 256-bit vectors: the three components of a neighbour's potential
/// in one register (a masked load, so nothing past the array is touched), one fused
/// multiply-add per pair, four partial sums per row taken in a fixed order (pair k goes to
/// sum k mod 4), so the bits do not depend on the partition or the thread count.
#[cfg(target_arch = "x86_64")]
mod avx {
    use std::arch::x86_64::*;

    #[inline(always)]
    unsafe fn load3(p: *const f64) -> __m256d {
        _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(p)), _mm_load_sd(p.add(2)), 1)
    }

    /// A node's potential: three values (a masked load) or the first of four (one load).
    #[inline(always)]
    unsafe fn load<const S: usize>(p: *const f64) -> __m256d {
        if S == 4 {
            _mm256_loadu_pd(p)
        } else {
            load3(p)
        }
    }

    /// Rows `start..start + y.len() / SO`; x holds `SI` values per node, y `SO` per row.
    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    pub unsafe fn step_rows<C: Copy + Into<f64>, const SI: usize, const SO: usize>(
        row_ptr: &[u32],
        col: &[u32],
        coef: &[C],
        x: &[f64],
        y: &mut [f64],
        h: f64,
        start: usize,
    ) {
        let xp = x.as_ptr();
        let hv = _mm256_set1_pd(h);
        let n = y.len() / SO;
        let rows = &row_ptr[start..start + n + 1];
        for k in 0..n {
            let i = start + k;
            let (s, e) = (rows[k] as usize, rows[k + 1] as usize);
            let (cols, cs) = (&col[s..e], &coef[s..e]);
            let xi = load::<SI>(xp.add(SI * i));
            let mut acc = [_mm256_setzero_pd(); 4];
            let quads = cols.len() / 4;
            for q in 0..quads {
                for (l, a) in acc.iter_mut().enumerate() {
                    let j = *cols.get_unchecked(4 * q + l) as usize;
                    debug_assert!(SI * j + 3 <= x.len());
                    let c = _mm256_set1_pd((*cs.get_unchecked(4 * q + l)).into());
                    let d = _mm256_sub_pd(load::<SI>(xp.add(SI * j)), xi);
                    *a = _mm256_fmadd_pd(c, d, *a);
                }
            }
            for l in 0..cols.len() - 4 * quads {
                let j = *cols.get_unchecked(4 * quads + l) as usize;
                debug_assert!(SI * j + 3 <= x.len());
                let c = _mm256_set1_pd((*cs.get_unchecked(4 * quads + l)).into());
                let d = _mm256_sub_pd(load::<SI>(xp.add(SI * j)), xi);
                acc[l] = _mm256_fmadd_pd(c, d, acc[l]);
            }
            let sum = _mm256_add_pd(_mm256_add_pd(acc[0], acc[1]), _mm256_add_pd(acc[2], acc[3]));
            let r = _mm256_fmadd_pd(hv, sum, xi);
            let out = y.as_mut_ptr().add(SO * k);
            if SO == 4 {
                _mm256_storeu_pd(out, r);
            } else {
                _mm_storeu_pd(out, _mm256_castpd256_pd128(r));
                _mm_store_sd(out.add(2), _mm256_extractf128_pd(r, 1));
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx_update {
    use super::V3;
    use std::arch::x86_64::*;

    #[inline(always)]
    unsafe fn load3(p: *const f64) -> __m256d {
        _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(p)), _mm_load_sd(p.add(2)), 1)
    }

    /// Rows handed to `f` per block: their sums are computed by the vector kernel first, then
    /// `f` runs outside it, where the compiler can inline it (a closure does not inline into
    /// a function with target features of its own).
    const BLOCK: usize = 64;

    /// `avx::step_rows`'s row sums, handed to `f` with the row's index, x_i and y_i.
    ///
    /// # Safety
    /// AVX2 and FMA are available, and every column index is below `x.len()`.
    #[inline]
    pub unsafe fn update_rows<C: Copy + Into<f64>, A, F>(
        row_ptr: &[u32],
        col: &[u32],
        coef: &[C],
        x: &[V3],
        y: &mut [V3],
        start: usize,
        acc: &mut A,
        f: &F,
    ) where
        F: Fn(&mut A, usize, V3, V3, &mut V3),
    {
        let mut sums = [[0.0f64; 3]; BLOCK];
        for (b, ys) in y.chunks_mut(BLOCK).enumerate() {
            let first = start + b * BLOCK;
            let sums = &mut sums[..ys.len()];
            row_sums(row_ptr, col, coef, x, first, sums);
            for (k, (yi, l)) in ys.iter_mut().zip(sums.iter()).enumerate() {
                let i = first + k;
                f(acc, i, *x.get_unchecked(i), *l, yi);
            }
        }
    }

    /// (L x)_i for the rows start..start + out.len().
    #[target_feature(enable = "avx2,fma")]
    unsafe fn row_sums<C: Copy + Into<f64>>(
        row_ptr: &[u32],
        col: &[u32],
        coef: &[C],
        x: &[V3],
        start: usize,
        out: &mut [V3],
    ) {
        let xp = x.as_ptr() as *const f64;
        let rows = &row_ptr[start..start + out.len() + 1];
        for (k, o) in out.iter_mut().enumerate() {
            let i = start + k;
            let (s, e) = (rows[k] as usize, rows[k + 1] as usize);
            let (cols, cs) = (&col[s..e], &coef[s..e]);
            let xi = load3(xp.add(3 * i));
            let mut acc4 = [_mm256_setzero_pd(); 4];
            let quads = cols.len() / 4;
            for q in 0..quads {
                for (l, a) in acc4.iter_mut().enumerate() {
                    let j = *cols.get_unchecked(4 * q + l) as usize;
                    debug_assert!(j < x.len());
                    let c = _mm256_set1_pd((*cs.get_unchecked(4 * q + l)).into());
                    let d = _mm256_sub_pd(load3(xp.add(3 * j)), xi);
                    *a = _mm256_fmadd_pd(c, d, *a);
                }
            }
            for l in 0..cols.len() - 4 * quads {
                let j = *cols.get_unchecked(4 * quads + l) as usize;
                debug_assert!(j < x.len());
                let c = _mm256_set1_pd((*cs.get_unchecked(4 * quads + l)).into());
                let d = _mm256_sub_pd(load3(xp.add(3 * j)), xi);
                acc4[l] = _mm256_fmadd_pd(c, d, acc4[l]);
            }
            let sum = _mm256_add_pd(_mm256_add_pd(acc4[0], acc4[1]), _mm256_add_pd(acc4[2], acc4[3]));
            let mut l = [0.0f64; 4];
            _mm256_storeu_pd(l.as_mut_ptr(), sum);
            *o = [l[0], l[1], l[2]];
        }
    }
}

#[cfg(target_arch = "x86_64")]
use avx_update as avx_u;

/// `paper` scheme: nodal Green-Gauss gradients, averaged flux, optional edge correction.
#[derive(Clone)]
pub struct Paper {
    pub row_ptr: Vec<u32>,
    pub col: Vec<u32>,
    /// S_ij
    pub s: Vec<V3>,
    /// R_i S_ij and R_j S_ij (the young-weighted face in place of S_ij where tissues weigh)
    pub ris: Vec<V3>,
    pub rjs: Vec<V3>,
    /// e = X_j - X_i
    pub e: Vec<V3>,
    /// (R_bar e) . S_ij / |e|^2 (zero when the correction is off)
    pub c: Vec<f64>,
    /// 1 / V_i (the gradients)
    pub inv_vol: Vec<f64>,
    /// 1 / C_i, the capacity the fluxes fill (`geometry::capacities`; 1 / V_i when no tissue
    /// weighs)
    pub inv_cap: Vec<f64>,
    pub update: Vec<bool>,
    /// The screening sink s_i of each row (None: none; `Compact::with_sink`).
    pub sink: Option<Vec<f64>>,
}

impl Paper {
    /// `faces`: the dual faces weighted by young the fluxes pass (`geometry::young_faces`;
    /// None: S_ij, no weight), `capacity` the control volumes they fill
    /// (`geometry::capacities`).
    pub fn new(
        dual: &Dual,
        points: &[V3],
        mat: &Materials,
        update: &[bool],
        correction: bool,
        faces: Option<&[V3]>,
        capacity: &[f64],
    ) -> Paper {
        let n = dual.n_rows;
        let mut row_ptr = Vec::with_capacity(n + 1);
        let (mut col, mut s, mut ris, mut rjs, mut e, mut c) = (vec![], vec![], vec![], vec![], vec![], vec![]);
        row_ptr.push(0u32);
        for i in 0..n {
            for p in dual.row_ptr[i]..dual.row_ptr[i + 1] {
                let sij = dual.s[p];
                if sij == [0.0; 3] {
                    continue; // shares a cell but no edge: no dual face
                }
                let j = dual.col[p] as usize;
                // the flux passes the weighted face, the gradient the geometric one
                let sw = faces.map_or(sij, |f| f[p]);
                let sv = Vector3::from(sw);
                let (r_i, r_j) = (mat.r(i), mat.r(j));
                let ri = r_i * sv;
                let rj = r_j * sv;
                let ev = sub(points[j], points[i]);
                let rbar = (r_i + r_j) * 0.5;
                let re = rbar * Vector3::from(ev);
                col.push(j as u32);
                s.push(sij);
                ris.push([ri[0], ri[1], ri[2]]);
                rjs.push([rj[0], rj[1], rj[2]]);
                e.push(ev);
                c.push(if correction {
                    dot([re[0], re[1], re[2]], sw) / dot(ev, ev)
                } else {
                    0.0
                });
            }
            row_ptr.push(col.len() as u32);
        }
        let inverse = |x: &[f64]| x.iter().map(|&v| if v > 0.0 { 1.0 / v } else { 0.0 }).collect();
        let (inv_vol, inv_cap) = (inverse(&dual.vol), inverse(capacity));
        Paper {
            row_ptr,
            col,
            s,
            ris,
            rjs,
            e,
            c,
            inv_vol,
            inv_cap,
            update: update.to_vec(),
            sink: None,
        }
    }

    /// Nodal gradients of the three components, g[i][3*c + d] = d u_c / d x_d, for the rows
    /// `start..start + g.len()`.
    pub fn gradients(&self, x: &[V3], g: &mut [[f64; 9]], start: usize) {
        g.par_chunks_mut(CHUNK).enumerate().for_each(|(b, chunk)| {
            for (k, gi) in chunk.iter_mut().enumerate() {
                let i = start + b * CHUNK + k;
                let (s0, e0) = (self.row_ptr[i] as usize, self.row_ptr[i + 1] as usize);
                let xi = x[i];
                let mut acc = [0.0; 9];
                for p in s0..e0 {
                    let xj = x[self.col[p] as usize];
                    let sv = self.s[p];
                    for c in 0..3 {
                        let d = 0.5 * (xj[c] - xi[c]);
                        acc[3 * c] += d * sv[0];
                        acc[3 * c + 1] += d * sv[1];
                        acc[3 * c + 2] += d * sv[2];
                    }
                }
                let iv = self.inv_vol[i];
                for a in acc.iter_mut() {
                    *a *= iv;
                }
                *gi = acc;
            }
        });
    }

    #[inline(always)]
    fn row(&self, i: usize, x: &[V3], g: &[[f64; 9]]) -> V3 {
        if !self.update[i] {
            return [0.0; 3];
        }
        let (s0, e0) = (self.row_ptr[i] as usize, self.row_ptr[i + 1] as usize);
        let xi = x[i];
        let gi = &g[i];
        let mut acc = [0.0; 3];
        for p in s0..e0 {
            let j = self.col[p] as usize;
            let (xj, gj) = (x[j], &g[j]);
            let (ri, rj, e, cc) = (self.ris[p], self.rjs[p], self.e[p], self.c[p]);
            for c in 0..3 {
                let gic = [gi[3 * c], gi[3 * c + 1], gi[3 * c + 2]];
                let gjc = [gj[3 * c], gj[3 * c + 1], gj[3 * c + 2]];
                let mut f = 0.5 * (dot(gic, ri) + dot(gjc, rj));
                if cc != 0.0 {
                    let gbar_e = 0.5 * (dot(gic, e) + dot(gjc, e));
                    f -= cc * (gbar_e - (xj[c] - xi[c]));
                }
                acc[c] += f;
            }
        }
        let iv = self.inv_cap[i];
        let l = [acc[0] * iv, acc[1] * iv, acc[2] * iv];
        match &self.sink {
            None => l,
            Some(s) => screened(l, s[i], xi),
        }
    }
}

/// Either scheme.
#[derive(Clone)]
pub enum Operator {
    Compact(Compact),
    Paper(Paper),
}

impl Operator {
    pub fn n_rows(&self) -> usize {
        match self {
            Operator::Compact(c) => c.row_ptr().len() - 1,
            Operator::Paper(p) => p.row_ptr.len() - 1,
        }
    }
    /// Bytes one substep must stream at least on this process: every operator array once, the
    /// potential read once and written once (gradients: written once, read once).
    pub fn stream_bytes(&self) -> usize {
        self.stream_bytes_rows(self.n_rows())
    }
    /// `stream_bytes` of rows `0..n`.
    pub fn stream_bytes_rows(&self, n: usize) -> usize {
        match self {
            Operator::Compact(c) => {
                let pairs = c.row_ptr()[n] as usize;
                let cb = if c.is_f32() { 4 } else { 8 };
                (n + 1) * 4 + pairs * (4 + cb) + n * 48
            }
            Operator::Paper(p) => {
                let pairs = p.row_ptr[n] as usize;
                // gradient pass: row_ptr, col, s, inv_vol; update pass: all arrays
                ((n + 1) * 4 + pairs * (4 + 24) + n * 8)
                    + ((n + 1) * 4 + pairs * (4 + 4 * 24 + 8) + n * 9)
                    + n * (24 + 72) // gradient pass: phi in, gradients out
                    + n * (24 + 72 + 24) // update pass: phi and gradients in, next out
            }
        }
    }
    pub fn needs_gradients(&self) -> bool {
        matches!(self, Operator::Paper(_))
    }
    /// Gradient pass (paper scheme only) over the rows in `range`.
    pub fn gradients(&self, x: &[V3], g: &mut [[f64; 9]], range: std::ops::Range<usize>) {
        if let Operator::Paper(p) = self {
            let start = range.start;
            p.gradients(x, &mut g[range], start);
        }
    }
    /// y_i = (L x)_i for rows `0..n_rows` (`g` holds gradients of x for the paper scheme).
    pub fn apply(&self, x: &[V3], g: &[[f64; 9]], y: &mut [V3]) {
        self.apply_rows(x, g, y, 0..self.n_rows());
    }
    /// y_i = (L x)_i for the rows in `range`.
    pub fn apply_rows(&self, x: &[V3], g: &[[f64; 9]], y: &mut [V3], range: std::ops::Range<usize>) {
        let start = range.start;
        y[range].par_chunks_mut(CHUNK).enumerate().for_each(|(b, chunk)| {
            for (k, yi) in chunk.iter_mut().enumerate() {
                let i = start + b * CHUNK + k;
                *yi = match self {
                    Operator::Compact(c) => c.row(i, x),
                    Operator::Paper(p) => p.row(i, x, g),
                };
            }
        });
    }
    /// y_i <- f(i, x_i, (L x)_i, y_i) for the rows in `range`: an operator application fused
    /// with a pointwise update (`f` may read y_i's old value, so a stage can overwrite a buffer
    /// in place). The row sums are those of the Euler step's kernel: the same bits on any
    /// partition.
    pub fn update_rows<F>(&self, x: &[V3], g: &[[f64; 9]], y: &mut [V3], range: std::ops::Range<usize>, f: &F)
    where
        F: Fn(usize, V3, V3, &mut V3) + Sync,
    {
        self.fold_rows(x, g, y, range, &|_: &mut (), i, xi, l, yi| f(i, xi, l, yi), &|_, _| ());
    }

    /// `update_rows` that also folds a value over the rows: every block of rows starts from
    /// `A::default()`, `f` updates it row by row and `combine` merges the blocks (in an order
    /// that depends on the threads: the fold must not depend on it, as exact integer sums do).
    pub fn fold_rows<A, F, C>(
        &self,
        x: &[V3],
        g: &[[f64; 9]],
        y: &mut [V3],
        range: std::ops::Range<usize>,
        f: &F,
        combine: &C,
    ) -> A
    where
        A: Default + Send,
        F: Fn(&mut A, usize, V3, V3, &mut V3) + Sync,
        C: Fn(A, A) -> A + Sync,
    {
        let start = range.start;
        if let Operator::Compact(c) = self {
            assert!(x.len() >= c.n_cols(), "potential shorter than the operator's columns");
        }
        y[range]
            .par_chunks_mut(CHUNK)
            .enumerate()
            .map(|(b, chunk)| {
                let mut acc = A::default();
                let first = start + b * CHUNK;
                if let Operator::Compact(c) = self {
                    if c.vector_update(x, chunk, first, &mut acc, f) {
                        return acc;
                    }
                }
                for (k, yi) in chunk.iter_mut().enumerate() {
                    let i = first + k;
                    let l = match self {
                        Operator::Compact(c) => c.row(i, x),
                        Operator::Paper(p) => p.row(i, x, g),
                    };
                    f(&mut acc, i, x[i], l, yi);
                }
                acc
            })
            .reduce(A::default, combine)
    }

    /// One forward Euler substep without source: y_i = x_i + h (L x)_i, for rows in `range`.
    pub fn step_rows(&self, x: &[V3], g: &[[f64; 9]], y: &mut [V3], h: f64, range: std::ops::Range<usize>) {
        let start = range.start;
        if let Operator::Compact(c) = self {
            // the vector kernel reads x without bounds checks: every index is below n_cols
            assert!(x.len() >= c.n_cols(), "potential shorter than the operator's columns");
        }
        y[range]
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(b, chunk)| match self {
                Operator::Compact(c) => c.step_range(x, chunk, h, start + b * CHUNK),
                Operator::Paper(p) => {
                    for (k, yi) in chunk.iter_mut().enumerate() {
                        let i = start + b * CHUNK + k;
                        let l = p.row(i, x, g);
                        let xi = x[i];
                        *yi = [xi[0] + h * l[0], xi[1] + h * l[1], xi[2] + h * l[2]];
                    }
                }
            });
    }
}
