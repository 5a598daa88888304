//! Compressed sparse rows: one type for every sparse matrix of the solvers, generic over the
//! stored scalar (f64 or f32): the propagation operator's coefficients
//! (`discretize::operator::Compact`, in either precision: `AnyCsr`), the multigrid
//! hierarchy's matrices (f64) and its transfers between levels (f32, summed in f64). Row
//! pointers and columns are u32: a process's operator and the multigrid's global levels hold
//! fewer than 2^32 entries. Products, transposes and the three-column kernels of the cycle:
//! every row is summed in the order of its stored entries, so a row's bits do not depend on
//! the thread count.

use super::V3;
use rayon::prelude::*;
use std::ops::Range;

/// Rows per parallel task of the kernels; smaller matrices run on one thread.
const CHUNK: usize = 1024;
const SERIAL_BELOW: usize = 8192;

/// A stored value: f64, or f32 (a third fewer bytes per entry; summed in f64).
pub trait Scalar: Copy + Default + PartialOrd + Into<f64> + Send + Sync + std::fmt::Debug + 'static {
    /// The value nearest `v` in this type.
    fn from_f64(v: f64) -> Self;
}

impl Scalar for f64 {
    #[inline(always)]
    fn from_f64(v: f64) -> f64 {
        v
    }
}

impl Scalar for f32 {
    #[inline(always)]
    fn from_f64(v: f64) -> f32 {
        v as f32
    }
}

/// A sparse matrix by rows: row i's entries are `ptr[i]..ptr[i + 1]` of `col` and `val`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Csr<T> {
    pub n_cols: usize,
    pub ptr: Vec<u32>,
    pub col: Vec<u32>,
    pub val: Vec<T>,
}

/// A row pointer: an entry count that must fit in u32.
#[inline]
fn offset(n: usize) -> u32 {
    u32::try_from(n).expect("a sparse matrix with 2^32 entries or more")
}

impl<T: Scalar> Csr<T> {
    pub fn n_rows(&self) -> usize {
        self.ptr.len().saturating_sub(1)
    }

    pub fn nnz(&self) -> usize {
        self.col.len()
    }

    /// The positions of row i's entries in `col` and `val`.
    #[inline(always)]
    pub fn row(&self, i: usize) -> Range<usize> {
        self.ptr[i] as usize..self.ptr[i + 1] as usize
    }

    /// The entry (i, j), 0 when not stored (columns ascending in the row).
    pub fn get(&self, i: usize, j: usize) -> T {
        let r = self.row(i);
        match self.col[r.clone()].binary_search(&(j as u32)) {
            Ok(k) => self.val[r.start + k],
            Err(_) => T::default(),
        }
    }

    /// The diagonal (0 where not stored).
    pub fn diagonal(&self) -> Vec<T> {
        (0..self.n_rows()).map(|i| self.get(i, i)).collect()
    }

    /// The identity of n rows.
    pub fn identity(n: usize) -> Csr<T> {
        Csr {
            n_cols: n,
            ptr: (0..=offset(n)).collect(),
            col: (0..offset(n)).collect(),
            val: vec![T::from_f64(1.0); n],
        }
    }

    /// The same matrix with its values in another type (f64 to f32 rounds to nearest).
    pub fn to<U: Scalar>(&self) -> Csr<U> {
        Csr {
            n_cols: self.n_cols,
            ptr: self.ptr.clone(),
            col: self.col.clone(),
            val: self.val.iter().map(|&v| U::from_f64(v.into())).collect(),
        }
    }

    /// The transpose, its rows' columns ascending (a counting sort: deterministic).
    pub fn transpose(&self) -> Csr<T> {
        let n = self.n_rows();
        let mut count = vec![0usize; self.n_cols + 1];
        for &j in &self.col {
            count[j as usize + 1] += 1;
        }
        for j in 0..self.n_cols {
            count[j + 1] += count[j];
        }
        let ptr = count.iter().map(|&c| offset(c)).collect();
        let mut next = count;
        let mut col = vec![0u32; self.nnz()];
        let mut val = vec![T::default(); self.nnz()];
        for i in 0..n {
            for p in self.row(i) {
                let j = self.col[p] as usize;
                col[next[j]] = i as u32;
                val[next[j]] = self.val[p];
                next[j] += 1;
            }
        }
        Csr {
            n_cols: n,
            ptr,
            col,
            val,
        }
    }

    /// y = A x (three columns).
    pub fn spmv(&self, x: &[V3], y: &mut [V3]) {
        spmv(&self.ptr, &self.col, &self.val, x, y)
    }

    /// y += A x (three columns).
    pub fn spmv_add(&self, x: &[V3], y: &mut [V3]) {
        spmv_add(&self.ptr, &self.col, &self.val, x, y)
    }
}

impl Csr<f64> {
    /// self * b (Gustavson): each entry of a row accumulates its terms in the order of the
    /// row's entries then b's, so the product is the same bits on any thread count.
    pub fn matmul(&self, b: &Csr<f64>) -> Csr<f64> {
        assert_eq!(self.n_cols, b.n_rows(), "matmul: inner dimensions");
        let n = self.n_rows();
        let blocks: Vec<(Vec<usize>, Vec<u32>, Vec<f64>)> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|blk| {
                let rows = blk * CHUNK..((blk + 1) * CHUNK).min(n);
                let mut acc = vec![0.0f64; b.n_cols];
                let mut seen = vec![false; b.n_cols];
                let mut touched: Vec<u32> = vec![];
                let (mut lens, mut col, mut val) = (vec![], vec![], vec![]);
                for i in rows {
                    touched.clear();
                    for p in self.row(i) {
                        let (k, a) = (self.col[p] as usize, self.val[p]);
                        for q in b.row(k) {
                            let j = b.col[q] as usize;
                            if !seen[j] {
                                seen[j] = true;
                                touched.push(j as u32);
                                acc[j] = a * b.val[q];
                            } else {
                                acc[j] += a * b.val[q];
                            }
                        }
                    }
                    touched.sort_unstable();
                    lens.push(touched.len());
                    for &j in &touched {
                        col.push(j);
                        val.push(acc[j as usize]);
                        seen[j as usize] = false;
                    }
                }
                (lens, col, val)
            })
            .collect();
        let mut ptr = Vec::with_capacity(n + 1);
        ptr.push(0u32);
        let (mut col, mut val) = (vec![], vec![]);
        let mut at = 0usize;
        for (lens, c, v) in blocks {
            for l in lens {
                at += l;
                ptr.push(offset(at));
            }
            col.extend_from_slice(&c);
            val.extend_from_slice(&v);
        }
        Csr {
            n_cols: b.n_cols,
            ptr,
            col,
            val,
        }
    }
}

/// A matrix whose values are stored in f64 or in f32, as chosen at run time (the propagation
/// operator's coefficients: `[model] operator_precision`).
#[derive(Clone, Debug, PartialEq)]
pub enum AnyCsr {
    F64(Csr<f64>),
    F32(Csr<f32>),
}

impl AnyCsr {
    pub fn ptr(&self) -> &[u32] {
        match self {
            AnyCsr::F64(a) => &a.ptr,
            AnyCsr::F32(a) => &a.ptr,
        }
    }

    pub fn col(&self) -> &[u32] {
        match self {
            AnyCsr::F64(a) => &a.col,
            AnyCsr::F32(a) => &a.col,
        }
    }

    pub fn n_cols(&self) -> usize {
        match self {
            AnyCsr::F64(a) => a.n_cols,
            AnyCsr::F32(a) => a.n_cols,
        }
    }

    pub fn n_rows(&self) -> usize {
        self.ptr().len().saturating_sub(1)
    }

    /// The positions of row i's entries.
    #[inline(always)]
    pub fn row(&self, i: usize) -> Range<usize> {
        let ptr = self.ptr();
        ptr[i] as usize..ptr[i + 1] as usize
    }

    /// The value of stored entry p.
    #[inline(always)]
    pub fn value(&self, p: usize) -> f64 {
        match self {
            AnyCsr::F64(a) => a.val[p],
            AnyCsr::F32(a) => a.val[p] as f64,
        }
    }

    /// Sets stored entry p to v (rounded to f32 where the values are f32; a value read back
    /// with `value` is restored exactly).
    #[inline]
    pub fn set_value(&mut self, p: usize, v: f64) {
        match self {
            AnyCsr::F64(a) => a.val[p] = v,
            AnyCsr::F32(a) => a.val[p] = v as f32,
        }
    }

    /// Whether the values are stored in f32.
    pub fn is_f32(&self) -> bool {
        matches!(self, AnyCsr::F32(_))
    }

    /// The same matrix with its values in f32.
    pub fn into_f32(self) -> AnyCsr {
        match self {
            AnyCsr::F64(a) => AnyCsr::F32(a.to()),
            f32 => f32,
        }
    }

    /// This pattern with the values `val` (one per stored entry).
    pub fn with_values<U: Scalar>(&self, val: Vec<U>) -> Csr<U> {
        assert_eq!(val.len(), self.col().len(), "one value per stored entry");
        Csr {
            n_cols: self.n_cols(),
            ptr: self.ptr().to_vec(),
            col: self.col().to_vec(),
            val,
        }
    }
}

/// Runs `f(first_row, rows_of_y)` over y in chunks, in parallel when y is large.
#[inline]
fn rows_of<T: Send, F: Fn(usize, &mut [T]) + Sync + Send>(y: &mut [T], f: F) {
    if y.len() < SERIAL_BELOW {
        f(0, y);
    } else {
        y.par_chunks_mut(CHUNK).enumerate().for_each(|(k, c)| f(k * CHUNK, c));
    }
}

/// (A x)_i for the three columns, in the order of the row's entries (values stored in f64 or
/// f32, summed in f64).
#[inline(always)]
fn row3<V: Copy + Into<f64>>(ptr: &[u32], col: &[u32], val: &[V], i: usize, x: &[V3]) -> V3 {
    let mut s = [0.0; 3];
    for p in ptr[i] as usize..ptr[i + 1] as usize {
        let (a, xj): (f64, V3) = (val[p].into(), x[col[p] as usize]);
        s[0] += a * xj[0];
        s[1] += a * xj[1];
        s[2] += a * xj[2];
    }
    s
}

/// y = A x (three columns).
pub(crate) fn spmv<V: Copy + Into<f64> + Sync>(ptr: &[u32], col: &[u32], val: &[V], x: &[V3], y: &mut [V3]) {
    rows_of(y, |s, y| {
        for (k, yi) in y.iter_mut().enumerate() {
            *yi = row3(ptr, col, val, s + k, x);
        }
    });
}

/// y += A x (three columns).
pub(crate) fn spmv_add<V: Copy + Into<f64> + Sync>(ptr: &[u32], col: &[u32], val: &[V], x: &[V3], y: &mut [V3]) {
    rows_of(y, |s, y| {
        for (k, yi) in y.iter_mut().enumerate() {
            let t = row3(ptr, col, val, s + k, x);
            for d in 0..3 {
                yi[d] += t[d];
            }
        }
    });
}

/// r = b - A x (three columns).
pub fn residual<V: Copy + Into<f64> + Sync>(ptr: &[u32], col: &[u32], val: &[V], x: &[V3], b: &[V3], r: &mut [V3]) {
    rows_of(r, |s, r| {
        for (k, ri) in r.iter_mut().enumerate() {
            let t = row3(ptr, col, val, s + k, x);
            let bi = b[s + k];
            *ri = [bi[0] - t[0], bi[1] - t[1], bi[2] - t[2]];
        }
    });
}

/// d = alpha d + beta D^-1 (b - A x) (three columns): one Chebyshev update in one pass.
#[allow(clippy::too_many_arguments)]
pub(crate) fn cheb_update<V: Copy + Into<f64> + Sync>(
    ptr: &[u32],
    col: &[u32],
    val: &[V],
    dinv: &[f64],
    x: &[V3],
    b: &[V3],
    d: &mut [V3],
    alpha: f64,
    beta: f64,
) {
    rows_of(d, |s, d| {
        for (k, di) in d.iter_mut().enumerate() {
            let i = s + k;
            let t = row3(ptr, col, val, i, x);
            let (bi, w) = (b[i], beta * dinv[i]);
            for c in 0..3 {
                di[c] = alpha * di[c] + w * (bi[c] - t[c]);
            }
        }
    });
}

/// `cheb_update` on the rows `rows` only (the rows of this process), then x += d on them; the
/// same row sums (`row3`) as the full kernel, so the same bits row for row.
#[allow(clippy::too_many_arguments)]
pub(crate) fn cheb_step_rows<V: Copy + Into<f64>>(
    rows: &[u32],
    ptr: &[u32],
    col: &[u32],
    val: &[V],
    dinv: &[f64],
    x: &mut [V3],
    b: &[V3],
    d: &mut [V3],
    alpha: f64,
    beta: f64,
) {
    for &i in rows {
        let i = i as usize;
        let t = row3(ptr, col, val, i, x);
        let (bi, w) = (b[i], beta * dinv[i]);
        for c in 0..3 {
            d[i][c] = alpha * d[i][c] + w * (bi[c] - t[c]);
        }
    }
    for &i in rows {
        let i = i as usize;
        for c in 0..3 {
            x[i][c] += d[i][c];
        }
    }
}

/// `residual` on the rows `rows` only.
pub(crate) fn residual_rows<V: Copy + Into<f64>>(
    rows: &[u32],
    ptr: &[u32],
    col: &[u32],
    val: &[V],
    x: &[V3],
    b: &[V3],
    r: &mut [V3],
) {
    for &i in rows {
        let i = i as usize;
        let t = row3(ptr, col, val, i, x);
        r[i] = [b[i][0] - t[0], b[i][1] - t[1], b[i][2] - t[2]];
    }
}

/// x += d.
pub fn add(x: &mut [V3], d: &[V3]) {
    rows_of(x, |s, x| {
        for (k, xi) in x.iter_mut().enumerate() {
            let di = d[s + k];
            for c in 0..3 {
                xi[c] += di[c];
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dense(a: &Csr<f64>) -> Vec<Vec<f64>> {
        let mut m = vec![vec![0.0; a.n_cols]; a.n_rows()];
        for i in 0..a.n_rows() {
            for p in a.row(i) {
                m[i][a.col[p] as usize] += a.val[p];
            }
        }
        m
    }

    fn sample(n: usize, m: usize, seed: u64) -> Csr<f64> {
        let mut s = seed;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 33) as f64 / (1u64 << 31) as f64
        };
        let mut ptr = vec![0];
        let (mut col, mut val) = (vec![], vec![]);
        for _ in 0..n {
            for j in 0..m {
                if next() < 0.3 {
                    col.push(j as u32);
                    val.push(next() - 0.5);
                }
            }
            ptr.push(col.len() as u32);
        }
        Csr {
            n_cols: m,
            ptr,
            col,
            val,
        }
    }

    #[test]
    fn products_and_transposes_match_dense_ones() {
        let (a, b) = (sample(7, 5, 1), sample(5, 9, 2));
        let (da, db) = (dense(&a), dense(&b));
        let c = dense(&a.matmul(&b));
        for i in 0..7 {
            for j in 0..9 {
                let want: f64 = (0..5).map(|k| da[i][k] * db[k][j]).sum();
                assert!((c[i][j] - want).abs() < 1e-14);
            }
        }
        let t = dense(&a.transpose());
        for i in 0..7 {
            for j in 0..5 {
                assert_eq!(t[j][i], da[i][j]);
            }
        }
        assert_eq!(a.transpose().transpose(), a);
    }

    #[test]
    fn a_precision_chosen_at_run_time_reads_as_its_values() {
        let a = sample(6, 4, 3);
        let f32s = AnyCsr::F64(a.clone()).into_f32();
        assert!(f32s.is_f32() && f32s.n_rows() == 6 && f32s.n_cols() == 4);
        for i in 0..6 {
            assert_eq!(f32s.row(i), a.row(i));
            for p in a.row(i) {
                assert_eq!(f32s.value(p), a.val[p] as f32 as f64);
                assert_eq!(f32s.col()[p], a.col[p]);
            }
        }
        // the same pattern with other values; the identity leaves three columns alone
        let w = f32s.with_values(vec![2.0f64; a.nnz()]);
        assert_eq!((w.ptr.clone(), w.col.clone()), (a.ptr.clone(), a.col.clone()));
        let x: Vec<V3> = (0..5).map(|i| [i as f64, -(i as f64), 0.5]).collect();
        let mut y = vec![[7.0; 3]; 5];
        Csr::<f32>::identity(5).spmv(&x, &mut y);
        assert_eq!(y, x);
    }
}
