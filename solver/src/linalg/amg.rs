//! Algebraic multigrid preconditioner of the implicit solves: one BoomerAMG V-cycle of hypre
//! (Debian's libhypre 2.26, through the hand-written declarations below) per component and
//! conjugate-gradient iteration, on the matrix A = V - theta tau W of the free nodes.
//!
//! The V-cycle (HMIS coarsening, aggressive on the first level, extended+i interpolation,
//! l1 Gauss-Seidel smoothing forward down and backward up) is a fixed symmetric positive-definite operator, so the conjugate gradients
//! stay valid; it is not the same on every number of processes (coarsening and smoothing
//! follow the partition), so results agree across process counts to the solver tolerance,
//! not bitwise. Jacobi is the deterministic default.

use super::{Precond, Sweep, V3};
use crate::distribute::comm::{Comm, RawComm};
use anyhow::{bail, Result};
use std::ffi::c_void;
use std::os::raw::{c_double, c_int};

type HypreInt = c_int; // HYPRE_Int and HYPRE_BigInt: int in Debian's build (no BIGINT)
type Handle = *mut c_void;
const HYPRE_PARCSR: HypreInt = 5555;

#[link(name = "HYPRE")]
extern "C" {
    fn HYPRE_Init() -> HypreInt;
    fn HYPRE_IJMatrixCreate(
        comm: RawComm,
        ilower: HypreInt,
        iupper: HypreInt,
        jlower: HypreInt,
        jupper: HypreInt,
        m: *mut Handle,
    ) -> HypreInt;
    fn HYPRE_IJMatrixSetObjectType(m: Handle, t: HypreInt) -> HypreInt;
    fn HYPRE_IJMatrixSetRowSizes(m: Handle, sizes: *const HypreInt) -> HypreInt;
    fn HYPRE_IJMatrixInitialize(m: Handle) -> HypreInt;
    fn HYPRE_IJMatrixSetValues(
        m: Handle,
        nrows: HypreInt,
        ncols: *const HypreInt,
        rows: *const HypreInt,
        cols: *const HypreInt,
        values: *const c_double,
    ) -> HypreInt;
    fn HYPRE_IJMatrixAssemble(m: Handle) -> HypreInt;
    fn HYPRE_IJMatrixGetObject(m: Handle, obj: *mut Handle) -> HypreInt;
    fn HYPRE_IJMatrixDestroy(m: Handle) -> HypreInt;
    fn HYPRE_IJVectorCreate(comm: RawComm, jlower: HypreInt, jupper: HypreInt, v: *mut Handle) -> HypreInt;
    fn HYPRE_IJVectorSetObjectType(v: Handle, t: HypreInt) -> HypreInt;
    fn HYPRE_IJVectorInitialize(v: Handle) -> HypreInt;
    fn HYPRE_IJVectorSetValues(v: Handle, n: HypreInt, idx: *const HypreInt, values: *const c_double) -> HypreInt;
    fn HYPRE_IJVectorGetValues(v: Handle, n: HypreInt, idx: *const HypreInt, values: *mut c_double) -> HypreInt;
    fn HYPRE_IJVectorAssemble(v: Handle) -> HypreInt;
    fn HYPRE_IJVectorGetObject(v: Handle, obj: *mut Handle) -> HypreInt;
    fn HYPRE_IJVectorDestroy(v: Handle) -> HypreInt;
    fn HYPRE_BoomerAMGCreate(s: *mut Handle) -> HypreInt;
    fn HYPRE_BoomerAMGDestroy(s: Handle) -> HypreInt;
    fn HYPRE_BoomerAMGSetup(s: Handle, a: Handle, b: Handle, x: Handle) -> HypreInt;
    fn HYPRE_BoomerAMGSolve(s: Handle, a: Handle, b: Handle, x: Handle) -> HypreInt;
    fn HYPRE_BoomerAMGSetMaxIter(s: Handle, n: HypreInt) -> HypreInt;
    fn HYPRE_BoomerAMGSetTol(s: Handle, tol: c_double) -> HypreInt;
    fn HYPRE_BoomerAMGSetPrintLevel(s: Handle, level: HypreInt) -> HypreInt;
    fn HYPRE_BoomerAMGSetCoarsenType(s: Handle, t: HypreInt) -> HypreInt;
    fn HYPRE_BoomerAMGSetInterpType(s: Handle, t: HypreInt) -> HypreInt;
    fn HYPRE_BoomerAMGSetPMaxElmts(s: Handle, n: HypreInt) -> HypreInt;
    fn HYPRE_BoomerAMGSetStrongThreshold(s: Handle, t: c_double) -> HypreInt;
    fn HYPRE_BoomerAMGSetAggNumLevels(s: Handle, n: HypreInt) -> HypreInt;
}

#[link(name = "gomp")]
extern "C" {
    // libgomp, which hypre links: its threads follow rayon's count
    fn omp_set_num_threads(n: c_int);
}

fn check(code: HypreInt, what: &str) -> Result<()> {
    if code != 0 {
        bail!("hypre: {what} failed (error code {code}); fix: use [integrator] preconditioner = \"jacobi\"");
    }
    Ok(())
}

/// Starts hypre, once. MPI must be running: under mpirun it is; a run on one process has the
/// launcher start it (`launch::start_alone`), and its `Comm` then gives MPI_COMM_SELF.
fn start_hypre() {
    static STARTED: std::sync::Once = std::sync::Once::new();
    STARTED.call_once(|| {
        // SAFETY: MPI is initialised (the caller has a communicator); called once
        unsafe {
            HYPRE_Init();
            if std::env::var_os("OMP_NUM_THREADS").is_none() {
                omp_set_num_threads(rayon::current_num_threads() as c_int);
            }
        }
    });
}

/// BoomerAMG on A = V - theta tau W of this process's free nodes.
pub struct Amg {
    matrix: Handle,
    parcsr: Handle,
    b: Handle,
    x: Handle,
    b_par: Handle,
    x_par: Handle,
    solver: Handle,
    /// owned local index of each of this process's rows, and the rows' global indices
    rows: Vec<u32>,
    index: Vec<HypreInt>,
    buf: Vec<f64>,
}

// SAFETY: the handles are used by the one thread that owns the stepper
unsafe impl Send for Amg {}

impl Amg {
    /// Builds A on this process's free owned rows (`vol` > 0) and sets BoomerAMG up on it.
    pub fn new<S: Sweep>(prop: &S, vol: &[f64], theta_tau: f64, comm: &dyn Comm) -> Result<Amg> {
        let Some(raw) = comm.raw() else {
            bail!("the amg preconditioner (hypre) needs MPI, which this process has not started; fix: run under mpirun, or start MPI first (`eprop run` does, as eprop::distribute::launch::start_alone)");
        };
        start_hypre();
        let Some(c) = prop.coefficients() else {
            bail!("the amg preconditioner needs the compact scheme; fix: use preconditioner = \"jacobi\"");
        };
        let n = vol.len();
        let rows: Vec<u32> = (0..n as u32).filter(|&i| vol[i as usize] > 0.0).collect();
        // contiguous global numbering of the free rows, rank by rank
        let counts = comm.all_gather(&[rows.len() as f64]);
        let first: f64 = counts[..comm.rank()].iter().sum();
        let total: f64 = counts.iter().sum();
        if total >= i32::MAX as f64 {
            bail!("the amg preconditioner handles fewer than 2^31 free nodes; fix: use preconditioner = \"jacobi\"");
        }
        let first = first as HypreInt;
        let layout = prop.layout();
        // global index of every local node (-1: not free), halo entries from their owners
        let mut g = crate::distribute::field::NodeField::filled(layout, [-1.0, 0.0, 0.0]);
        for (k, &i) in rows.iter().enumerate() {
            g[i as usize][0] = (first + k as HypreInt) as f64;
        }
        prop.refresh(&mut g);
        let (lo, hi) = (first, first + rows.len() as HypreInt - 1);
        let mut amg = Amg {
            matrix: std::ptr::null_mut(),
            parcsr: std::ptr::null_mut(),
            b: std::ptr::null_mut(),
            x: std::ptr::null_mut(),
            b_par: std::ptr::null_mut(),
            x_par: std::ptr::null_mut(),
            solver: std::ptr::null_mut(),
            index: (lo..=hi).collect(),
            buf: vec![0.0; rows.len()],
            rows,
        };
        // SAFETY: hypre's documented call sequence; every array outlives the call that reads it
        unsafe {
            check(
                HYPRE_IJMatrixCreate(raw, lo, hi, lo, hi, &mut amg.matrix),
                "IJMatrixCreate",
            )?;
            check(
                HYPRE_IJMatrixSetObjectType(amg.matrix, HYPRE_PARCSR),
                "IJMatrixSetObjectType",
            )?;
            let sizes: Vec<HypreInt> = amg
                .rows
                .iter()
                .map(|&i| (c.ptr()[i as usize + 1] - c.ptr()[i as usize] + 1) as HypreInt)
                .collect();
            check(
                HYPRE_IJMatrixSetRowSizes(amg.matrix, sizes.as_ptr()),
                "IJMatrixSetRowSizes",
            )?;
            check(HYPRE_IJMatrixInitialize(amg.matrix), "IJMatrixInitialize")?;
            let (mut cols, mut vals) = (Vec::new(), Vec::new());
            for (k, &i) in amg.rows.iter().enumerate() {
                let i = i as usize;
                cols.clear();
                vals.clear();
                let v = vol[i];
                let mut diag = v;
                for p in c.row(i) {
                    let cij = c.value(p);
                    diag += theta_tau * v * cij;
                    let gj = g[c.col()[p] as usize][0];
                    if gj >= 0.0 {
                        cols.push(gj as HypreInt);
                        vals.push(-theta_tau * v * cij);
                    }
                }
                cols.push(lo + k as HypreInt);
                vals.push(diag);
                let nc = cols.len() as HypreInt;
                let row = lo + k as HypreInt;
                check(
                    HYPRE_IJMatrixSetValues(amg.matrix, 1, &nc, &row, cols.as_ptr(), vals.as_ptr()),
                    "IJMatrixSetValues",
                )?;
            }
            check(HYPRE_IJMatrixAssemble(amg.matrix), "IJMatrixAssemble")?;
            check(
                HYPRE_IJMatrixGetObject(amg.matrix, &mut amg.parcsr),
                "IJMatrixGetObject",
            )?;
            for (v, par) in [(&mut amg.b, &mut amg.b_par), (&mut amg.x, &mut amg.x_par)] {
                check(HYPRE_IJVectorCreate(raw, lo, hi, v), "IJVectorCreate")?;
                check(HYPRE_IJVectorSetObjectType(*v, HYPRE_PARCSR), "IJVectorSetObjectType")?;
                check(HYPRE_IJVectorInitialize(*v), "IJVectorInitialize")?;
                check(HYPRE_IJVectorAssemble(*v), "IJVectorAssemble")?;
                check(HYPRE_IJVectorGetObject(*v, par), "IJVectorGetObject")?;
            }
            check(HYPRE_BoomerAMGCreate(&mut amg.solver), "BoomerAMGCreate")?;
            let s = amg.solver;
            HYPRE_BoomerAMGSetPrintLevel(s, 0);
            HYPRE_BoomerAMGSetCoarsenType(s, 10); // HMIS
            HYPRE_BoomerAMGSetInterpType(s, 6); // extended+i
            HYPRE_BoomerAMGSetPMaxElmts(s, 4);
            HYPRE_BoomerAMGSetStrongThreshold(s, 0.5); // 3-D
                                                       // aggressive coarsening on the first level: measured 15% less time per step on a
                                                       // 271k-node liver than without, for 20% more iterations
            HYPRE_BoomerAMGSetAggNumLevels(s, 1);
            // smoothing: hypre's default, l1 Gauss-Seidel forward going down and backward
            // going up, so the cycle is symmetric
            HYPRE_BoomerAMGSetMaxIter(s, 1); // one V-cycle per application
            HYPRE_BoomerAMGSetTol(s, 0.0);
            check(
                HYPRE_BoomerAMGSetup(s, amg.parcsr, amg.b_par, amg.x_par),
                "BoomerAMGSetup",
            )?;
        }
        Ok(amg)
    }
}

impl<S: Sweep> Precond<S> for Amg {
    fn apply(&mut self, _: &mut S, r: &[V3], z: &mut [V3]) {
        let m = self.rows.len() as HypreInt;
        for d in 0..3 {
            for (k, &i) in self.rows.iter().enumerate() {
                self.buf[k] = r[i as usize][d];
            }
            // SAFETY: the vectors were assembled in `new` over exactly these indices
            unsafe {
                HYPRE_IJVectorInitialize(self.b);
                HYPRE_IJVectorSetValues(self.b, m, self.index.as_ptr(), self.buf.as_ptr());
                HYPRE_IJVectorAssemble(self.b);
                self.buf.iter_mut().for_each(|v| *v = 0.0);
                HYPRE_IJVectorInitialize(self.x);
                HYPRE_IJVectorSetValues(self.x, m, self.index.as_ptr(), self.buf.as_ptr());
                HYPRE_IJVectorAssemble(self.x);
                HYPRE_BoomerAMGSolve(self.solver, self.parcsr, self.b_par, self.x_par);
                HYPRE_IJVectorGetValues(self.x, m, self.index.as_ptr(), self.buf.as_mut_ptr());
            }
            for z in z.iter_mut() {
                z[d] = 0.0;
            }
            for (k, &i) in self.rows.iter().enumerate() {
                z[i as usize][d] = self.buf[k];
            }
        }
    }
}

impl Drop for Amg {
    fn drop(&mut self) {
        // SAFETY: each handle was created in `new` (null ones are skipped)
        unsafe {
            if !self.solver.is_null() {
                HYPRE_BoomerAMGDestroy(self.solver);
            }
            for v in [self.b, self.x] {
                if !v.is_null() {
                    HYPRE_IJVectorDestroy(v);
                }
            }
            if !self.matrix.is_null() {
                HYPRE_IJMatrixDestroy(self.matrix);
            }
        }
    }
}
