//! Linear algebra of the propagation's solvers, a layer below the integrators as PETSc's Mat,
//! PC and KSP are below its TS: sparse matrices (`csr`), the operator as the solvers sweep it
//! (`Sweep`), preconditioners (`Precond`: `jacobi`, `multigrid`, `amg`), conjugate
//! gradients with exact dot products (`cg`) and the real-time mode's direct solver (`direct`:
//! a sparse Cholesky factor, CHOLMOD's). It knows nothing of the scenario or the
//! integrators: the discretization stores its operator in a `csr::Csr`, the propagation
//! (`propagate::Propagation`) is the `Sweep` the solvers run on, and the implicit integrator
//! says what a failed solve means for the scenario.

/// Whether the library was built with hypre, the `amg` preconditioner (`build.rs`).
pub const HAS_AMG: bool = cfg!(eprop_hypre);

#[cfg(eprop_hypre)]
pub mod amg;
pub mod cg;
pub mod csr;
pub mod direct;
pub mod jacobi;
pub mod multigrid;

use crate::distribute::field::NodeField;
use crate::distribute::halo::Halo;
use csr::AnyCsr;
use eprop_partition::Layout;

/// A value per node: the three components of the potential.
pub type V3 = [f64; 3];

/// The operator L, (L x)_i = sum_j c_ij (x_j - x_i), on the owned rows of one process, as the
/// solvers use it: every sweep refreshes the halo of its input (overlapped with the interior
/// rows) and hands each owned row's (L x)_i to a pointwise update, so that a solver's vector
/// operations ride on the operator's pass. `propagate::Propagation` is the one in use.
pub trait Sweep {
    /// An operator on L's pattern with other weights (a preconditioner's own), swept by
    /// `update_with` with L's kernel.
    type Twin: Send + Sync;

    /// Owned rows (interior, then border), then halo nodes.
    fn layout(&self) -> Layout;

    /// The halo exchange between the processes (its communicator carries a preconditioner's
    /// own collectives).
    fn halo(&self) -> &Halo;

    /// The coefficients c_ij on the pairs of the owned rows (columns: the local numbering); None
    /// for an operator that has none (the paper scheme).
    fn coefficients(&self) -> Option<&AnyCsr>;

    /// The operator of L's pattern with the weight `w[p]` on stored pair p, in f32.
    fn twin(&self, w: Vec<f32>) -> Self::Twin;

    /// Owned rows held at their value (Dirichlet rows of L, emptied): a solver keeps its
    /// search directions zero there.
    fn frozen(&self) -> &[u32] {
        &[]
    }

    /// The screening sink s_i of the owned rows (L's diagonal beyond -sum_j c_ij), None
    /// without one.
    fn sink(&self) -> Option<&[f64]> {
        None
    }

    /// y_i <- f(acc, i, x_i, (L x)_i, y_i) on the owned rows, the halo of x refreshed first;
    /// each block of rows folds from `A::default()` and `combine` merges blocks in no fixed
    /// order (so the fold must not depend on it, as exact integer sums do).
    fn fold_to<A, F, C>(&mut self, x: &mut NodeField<V3>, y: &mut [V3], f: F, combine: C) -> A
    where
        A: Default + Send,
        F: Fn(&mut A, usize, V3, V3, &mut V3) + Sync,
        C: Fn(A, A) -> A + Sync;

    /// y_i <- f(i, x_i, (L x)_i, y_i) on the owned rows, the halo of x refreshed first.
    fn update_to<F>(&mut self, x: &mut NodeField<V3>, y: &mut [V3], f: F)
    where
        F: Fn(usize, V3, V3, &mut V3) + Sync,
    {
        self.fold_to(x, y, |_: &mut (), i, xi, l, yi| f(i, xi, l, yi), |_, _| ());
    }

    /// `update_to` with the twin `op` in place of L.
    fn update_with<F>(&mut self, op: &Self::Twin, x: &mut NodeField<V3>, y: &mut [V3], f: F)
    where
        F: Fn(usize, V3, V3, &mut V3) + Sync;

    /// Overwrites the halo entries of `x` with their owners' values.
    fn refresh(&self, x: &mut NodeField<V3>) {
        self.halo().exchange(x.flat_mut(), 3);
    }
}

/// A preconditioner M ~ A^-1 of the solves on the owned rows of `S`'s operator.
pub trait Precond<S: Sweep>: Send {
    /// z = M r on the owned rows (three components). Every process calls it at the same
    /// point (a preconditioner may sweep the operator, exchanging its halo).
    fn apply(&mut self, s: &mut S, r: &[V3], z: &mut [V3]);
    /// The inverse diagonal when M is diagonal (the solver fuses it into its vector update).
    fn inverse_diagonal(&self) -> Option<&[f64]> {
        None
    }
    /// The cost of one application in forward Euler substeps (the integrators' unit of work)
    /// beyond the conjugate-gradient iteration's own (a diagonal one is fused into it: 0).
    fn cost(&self) -> f64 {
        0.0
    }
    /// Frees the work buffers while the preconditioner of another sub-step length runs (the
    /// next `apply` allocates them again).
    fn release(&mut self) {}
    /// The preconditioner of the same operator with another theta tau, made from this one
    /// more cheaply than anew (None: build it anew).
    fn derive(&self, _theta_tau: f64) -> Option<anyhow::Result<Box<dyn Precond<S>>>> {
        None
    }
}
