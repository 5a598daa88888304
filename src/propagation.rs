//! The propagation state of one process: the operator L of the vector Poisson equation, the
//! halo exchange it needs, the potential phi and work vectors. It offers the sweeps the
//! integrators are built from (`integrate`): an explicit Euler substep and an operator
//! application, each refreshing the halo of its input while the interior rows are computed.

use crate::field::NodeField;
use crate::operator::{Operator, V3};
use crate::scatter::{Exchange, Halo};
use eprop_partition::Layout;
use std::ops::Range;

/// Nodal sources Q: (local index of an owned node, Q).
pub type Sources = [(u32, V3)];

/// The interior rows `0..n` in pieces of at least 16k rows, at most 16 of them: between two
/// pieces MPI gets a chance to move the halo messages (`Exchange::progress`).
pub fn pieces(n: usize) -> impl Iterator<Item = Range<usize>> {
    let size = n.div_ceil(16).max(16 * 1024);
    (0..n.div_ceil(size)).map(move |k| k * size..((k + 1) * size).min(n))
}

/// The operator, its halo exchange and the potential of one process. Rows `interior()` read
/// owned values only; rows `border()` also read halo values.
pub struct Propagation {
    pub op: Operator,
    pub halo: Halo,
    pub phi: NodeField<V3>,
    next: NodeField<V3>,
    /// Nodal gradients of the `paper` scheme (empty for `compact`).
    grad: NodeField<[f64; 9]>,
    layout: Layout,
}

impl Propagation {
    pub fn new(op: Operator, halo: Halo, layout: Layout) -> Self {
        let mut layout = layout;
        layout.n_interior = layout.n_interior.min(op.n_rows());
        let gl = if op.needs_gradients() {
            layout
        } else {
            Layout::default()
        };
        Propagation {
            op,
            halo,
            phi: NodeField::filled(layout, [0.0; 3]),
            next: NodeField::filled(layout, [0.0; 3]),
            grad: NodeField::filled(gl, [0.0; 9]),
            layout,
        }
    }

    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// A zero field over this process's nodes.
    pub fn zeros(&self) -> NodeField<V3> {
        NodeField::filled(self.layout, [0.0; 3])
    }

    /// One forward Euler substep of size h with nodal sources `q`:
    /// phi <- phi + h (L phi + Q) on the owned rows (Dirichlet and inactive rows do not move).
    pub fn substep(&mut self, h: f64, q: &Sources) {
        let Propagation {
            op,
            halo,
            phi,
            next,
            grad,
            layout,
        } = self;
        sweep(op, halo, grad, phi, *layout, |op, x, g, rows| {
            op.step_rows(x, g, next, h, rows)
        });
        for &(i, qi) in q {
            let y = &mut next[i as usize];
            y[0] += h * qi[0];
            y[1] += h * qi[1];
            y[2] += h * qi[2];
        }
        std::mem::swap(phi, next);
    }

    /// One substep on a single process (tests; the halo is empty there).
    pub fn substep_serial(&mut self, h: f64, q: &Sources) {
        self.substep(h, q)
    }

    /// y = L x on the owned rows, refreshing the halo of x first (overlapped with the interior
    /// rows). Entries of y beyond the owned rows are left alone.
    pub fn apply_to(&mut self, x: &mut NodeField<V3>, y: &mut [V3]) {
        let Propagation {
            op, halo, grad, layout, ..
        } = self;
        sweep(op, halo, grad, x, *layout, |op, x, g, rows| {
            op.apply_rows(x, g, y, rows)
        });
    }

    /// y_i <- f(i, x_i, (L x)_i, y_i) on the owned rows, refreshing the halo of x first (overlapped
    /// with the interior rows): one operator application fused with the pointwise part of a
    /// stage or a solver iteration. Entries of y beyond the owned rows are left alone.
    pub fn update_to<F>(&mut self, x: &mut NodeField<V3>, y: &mut [V3], f: F)
    where
        F: Fn(usize, V3, V3, &mut V3) + Sync,
    {
        self.fold_to(x, y, |_: &mut (), i, xi, l, yi| f(i, xi, l, yi), |_, _| ());
    }

    /// `update_to` that also folds a value over the owned rows (`Operator::fold_rows`): each
    /// block of rows starts from `A::default()`, `combine` merges blocks in no fixed order.
    pub fn fold_to<A, F, C>(&mut self, x: &mut NodeField<V3>, y: &mut [V3], f: F, combine: C) -> A
    where
        A: Default + Send,
        F: Fn(&mut A, usize, V3, V3, &mut V3) + Sync,
        C: Fn(A, A) -> A + Sync,
    {
        let Propagation {
            op, halo, grad, layout, ..
        } = self;
        let mut total = Some(A::default());
        sweep(op, halo, grad, x, *layout, |op, x, g, rows| {
            let part = op.fold_rows(x, g, y, rows, &f, &combine);
            total = Some(combine(total.take().unwrap_or_default(), part));
        });
        total.unwrap_or_default()
    }

    /// y = L x on the owned rows of one process, x taken as it is (tests).
    pub fn apply(&mut self, x: &[V3], y: &mut [V3]) {
        let mut xf = NodeField::from_vec(self.layout, x.to_vec());
        self.apply_to(&mut xf, y);
    }

    /// Overwrites the halo entries of `x` with their owners' values.
    pub fn refresh(&self, x: &mut NodeField<V3>) {
        self.halo.exchange(x.flat_mut(), 3);
    }
}

/// Runs `rows` (a sweep over operator rows that reads `x`, and the gradients for `paper`) on
/// every owned row, refreshing the halo of `x` meanwhile: the interior rows run while the
/// messages are in flight, in pieces with MPI progress between them, then the border rows.
/// `paper` needs the gradients of x first, and their halo: two exchanges.
fn sweep(
    op: &Operator,
    halo: &Halo,
    grad: &mut NodeField<[f64; 9]>,
    x: &mut NodeField<V3>,
    layout: Layout,
    mut rows: impl FnMut(&Operator, &[V3], &[[f64; 9]], Range<usize>),
) {
    let (interior, border) = (layout.interior(), layout.border());
    if op.needs_gradients() {
        let mut ex = halo.start(x.flat(), 3);
        for r in pieces(interior.end) {
            op.gradients(x, grad, r);
            ex.progress();
        }
        ex.finish(x.flat_mut());
        op.gradients(x, grad, border.clone());
        let mut ex: Exchange = halo.start(grad.flat(), 9);
        for r in pieces(interior.end) {
            rows(op, x, grad, r);
            ex.progress();
        }
        ex.finish(grad.flat_mut());
        rows(op, x, grad, border);
    } else {
        let mut ex = halo.start(x.flat(), 3);
        for r in pieces(interior.end) {
            rows(op, x, &[], r);
            ex.progress();
        }
        ex.finish(x.flat_mut());
        rows(op, x, &[], border);
    }
}
