//! The propagation state of one process: the operator L of the vector Poisson equation, the
//! halo exchange it needs, the potential phi and work vectors. It offers the sweeps the
//! integrators are built from (`integrate`): an explicit Euler substep and an operator
//! application, each refreshing the halo of its input while the interior rows are computed.

pub mod integrate;
pub mod wavefront;

use crate::config::Fuse;
use crate::discretize::operator::Operator;
use crate::distribute::field::NodeField;
use crate::distribute::halo::{Exchange, Halo};
use crate::linalg::csr::AnyCsr;
use crate::linalg::Sweep;
use crate::linalg::V3;
use crate::propagate::wavefront::{drive, Wavefront};
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
    /// Substeps per fused sweep (`substeps`; 1: none).
    fuse: usize,
    /// Chooses `fuse` by timing the first sweeps, unless a depth was set.
    tuner: Option<Tuner>,
    /// The fused sweep's schedule and its level buffers (four values per node: one 256-bit
    /// load per neighbour), made on first use.
    wave: Option<Wavefront>,
    levels: Vec<NodeField<[f64; 4]>>,
    /// Owned rows held at their potential (`freeze`), and their coefficients.
    frozen: Vec<u32>,
    saved: Vec<f64>,
    /// Whether the potential of a row held over this step was changed at its start
    /// (`set_held_moved`).
    held_moved: bool,
}

/// The depths (substeps per sweep) the tuner tries.
pub(crate) const DEPTHS: [usize; 5] = [1, 2, 3, 4, 8];
/// Sweeps of each depth the tuner times before it chooses.
const TUNE_ROUNDS: usize = 3;

/// Chooses the fusion depth on this process by timing sweeps of each depth in turn (the
/// fastest depth depends on the mesh, the caches and the load of the machine: 8 on a 300k-node
/// box, 4 on a 1M box and on a 749k-node kidney). The choice changes the speed only:
/// every depth gives the same bits. It runs on one process only (`Fuse::Auto` on several is one
/// substep per sweep), so the choice needs no agreement.
#[derive(Clone, Debug)]
struct Tuner {
    /// The depths tried, in turn.
    depths: Vec<usize>,
    /// Seconds per substep of the timed sweeps, per depth in `depths`.
    times: Vec<Vec<f64>>,
    round: usize,
}

impl Tuner {
    /// Tries the depths of `DEPTHS`.
    fn new() -> Tuner {
        let depths = DEPTHS.to_vec();
        Tuner {
            times: vec![vec![]; depths.len()],
            depths,
            round: 0,
        }
    }
    fn next(&self) -> usize {
        self.depths[self.round % self.depths.len()]
    }
    fn record(&mut self, depth: usize, seconds_per_substep: f64) {
        if let Some(k) = self.depths.iter().position(|&d| d == depth) {
            self.times[k].push(seconds_per_substep);
        }
        self.round += 1;
    }
    /// The depth with the smallest median time, once every depth had its rounds.
    fn choice(&self) -> Option<usize> {
        if self.round < TUNE_ROUNDS * self.depths.len() {
            return None;
        }
        let medians: Vec<f64> = self
            .times
            .iter()
            .map(|v| {
                let mut v = v.clone();
                v.sort_by(f64::total_cmp);
                v.get(v.len() / 2).copied().unwrap_or(f64::INFINITY)
            })
            .collect();
        let best = (0..self.depths.len()).min_by(|&a, &b| medians[a].total_cmp(&medians[b]));
        Some(best.map_or(1, |k| self.depths[k]))
    }
}

impl Propagation {
    /// The propagation of one process with `fuse` substeps per fused sweep (`Fuse::Auto`:
    /// chosen by timing the first sweeps; the caller decides what several processes run, see
    /// `Simulation::new_with`). Fusing or not, every process makes one halo exchange per
    /// substep, so processes that group their substeps differently still pair their messages.
    pub fn new(op: Operator, halo: Halo, layout: Layout, fuse: Fuse) -> Self {
        let mut layout = layout;
        layout.n_interior = layout.n_interior.min(op.n_rows());
        let gl = if op.needs_gradients() {
            layout
        } else {
            Layout::default()
        };
        let (fuse, tuner) = match fuse {
            Fuse::Fixed(d) => (d.max(1), None),
            Fuse::Auto => (DEPTHS[DEPTHS.len() - 1], Some(Tuner::new())),
        };
        tracing::debug!(
            "propagation: {} substeps per sweep{}",
            fuse,
            if tuner.is_some() { " (tuning)" } else { "" }
        );
        Propagation {
            op,
            halo,
            phi: NodeField::filled(layout, [0.0; 3]),
            next: NodeField::filled(layout, [0.0; 3]),
            grad: NodeField::filled(gl, [0.0; 9]),
            layout,
            fuse,
            tuner,
            wave: None,
            levels: vec![],
            frozen: Vec::new(),
            held_moved: false,
            saved: Vec::new(),
        }
    }

    /// Substeps per fused sweep from now on (1: every substep on its own); no tuning.
    pub fn set_fuse(&mut self, depth: usize) {
        self.fuse = depth.max(1);
        self.tuner = None;
    }

    /// Substeps per fused sweep (while tuning: the largest depth tried).
    pub fn fuse(&self) -> usize {
        self.fuse
    }

    /// Whether the depth is settled (set, or chosen by timing).
    pub fn tuned(&self) -> bool {
        self.tuner.is_none()
    }

    /// Whether `substeps` fuses: `compact` scheme, one thread (the wavefront is sequential).
    pub fn fuses(&self) -> bool {
        self.fuse >= 2 && matches!(self.op, Operator::Compact(_)) && rayon::current_num_threads() == 1
    }

    /// `count` forward Euler substeps of size h with sources `q`: bitwise the same as `count`
    /// calls of `substep`, in fused sweeps of `fuse()` substeps where `fuses()` (while the
    /// tuner runs: of each depth in turn, timed).
    pub fn substeps(&mut self, h: f64, q: &Sources, count: usize) {
        let mut left = count;
        while left > 0 && self.fuses() {
            let d = match &self.tuner {
                Some(t) => t.next().min(left),
                None => self.fuse.min(left),
            };
            let t0 = std::time::Instant::now();
            if d >= 2 {
                self.fused(h, q, d);
            } else {
                self.substep(h, q);
            }
            left -= d;
            if let Some(t) = &mut self.tuner {
                t.record(d, t0.elapsed().as_secs_f64() / d as f64);
                if let Some(best) = t.choice() {
                    tracing::debug!("fused sweeps: {best} substeps per sweep (timed {:?})", t.times);
                    self.tuner = None;
                    self.fuse = best;
                    // keep only what the chosen depth needs
                    self.levels.truncate(best.saturating_sub(1));
                    self.wave = None;
                }
            }
        }
        for _ in 0..left {
            self.substep(h, q);
        }
    }

    /// The wavefront schedule of the fused sweep (made on first use).
    pub fn wavefront(&mut self) -> Option<&Wavefront> {
        let Operator::Compact(c) = &self.op else {
            return None;
        };
        if self.wave.as_ref().is_none_or(|w| w.depth < self.fuse) {
            tracing::debug!("wavefront: {} levels", self.fuse);
            self.wave = Some(Wavefront::new(c, self.layout, self.fuse));
        }
        self.wave.as_ref()
    }

    /// `d` substeps in one sweep (`wavefront.rs`): level l reads level l - 1 (level 0: phi)
    /// and writes `levels[l - 1]`, the last level writes `next`, which becomes phi. The levels
    /// in between hold four values per node (one 256-bit load per neighbour).
    fn fused(&mut self, h: f64, q: &Sources, d: usize) {
        self.wavefront();
        while self.levels.len() + 1 < d {
            self.levels.push(NodeField::filled(self.layout, [0.0; 4]));
        }
        let mut qs = q.to_vec();
        let Propagation {
            op,
            halo,
            phi,
            next,
            wave,
            levels,
            layout,
            ..
        } = self;
        let (Operator::Compact(c), Some(w)) = (&*op, wave.as_ref()) else {
            unreachable!("fused sweeps run the compact scheme")
        };
        qs.sort_by_key(|s| s.0); // stable: a node's sources keep their order
                                 // level l on rows r, then the sources of those rows
        let run = |phi: &NodeField<V3>,
                   next: &mut NodeField<V3>,
                   levels: &mut [NodeField<[f64; 4]>],
                   l: usize,
                   r: Range<usize>| level_rows(c, h, &qs, phi, next, levels, l, d, r);
        // the wavefront over the interior, phi's halo in flight
        let ex = Some(halo.start(phi.flat(), 3));
        let mut st = (&mut *phi, &mut *next, &mut levels[..], ex);
        drive(
            &w.deep[..d],
            &mut st,
            |(phi, next, levels, _), l, s| {
                run(phi, next, levels, l, s.start as usize..s.end as usize);
                // the progress pokes count level 1's rows
                if l == 1 {
                    (s.end - s.start) as usize
                } else {
                    0
                }
            },
            |(_, _, _, ex)| {
                if let Some(e) = ex.as_mut() {
                    e.progress();
                }
            },
        );
        let mut ex = st.3;
        let border = layout.border();
        // the rest of each level in level order, one halo exchange per level (that of level
        // l - 1 in flight while the interior rows of level l outside the wavefront run)
        for l in 1..=d {
            for r in &w.rest[l - 1] {
                run(phi, next, levels, l, r.clone());
            }
            if let Some(e) = ex.take() {
                if l == 1 {
                    e.finish(phi.flat_mut());
                } else {
                    e.finish(levels[l - 2].flat_mut());
                }
            }
            run(phi, next, levels, l, border.clone());
            if l < d {
                // three values of the four per node: the messages pair with those of a process
                // that does not fuse
                ex = Some(halo.start_part(&levels[l - 1].flat()[..4 * layout.n_local], 4, 3));
            }
        }
        std::mem::swap(phi, next);
    }

    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// Holds the potential of the owned `rows` where it is (a Dirichlet condition: their rows
    /// of the operator are emptied), and lets go of the rows held before. Every integrator
    /// then keeps them fixed; sources on them must be left out. The compact scheme only
    /// (the paper scheme's rows are unchanged).
    pub fn freeze(&mut self, rows: &[u32]) {
        self.thaw();
        if let Operator::Compact(c) = &mut self.op {
            c.freeze(rows, &mut self.saved);
            self.frozen = rows.to_vec();
        }
    }

    /// Lets go of the rows `freeze` held.
    pub fn thaw(&mut self) {
        if let Operator::Compact(c) = &mut self.op {
            c.thaw(&self.frozen, &self.saved);
        }
        self.frozen.clear();
        self.saved.clear();
    }

    /// The rows `freeze` holds (sorted as given).
    pub fn frozen(&self) -> &[u32] {
        &self.frozen
    }

    /// Says whether the caller moved the potential of a row it holds over the coming step at
    /// the step's start (a tool that moves what it holds, or catches a node away from where it
    /// is): a jump of the data, whose layer the implicit integrator's error control carries to
    /// the step's end (`integrate::implicit::carry_level`). On this process only.
    pub fn set_held_moved(&mut self, moved: bool) {
        self.held_moved = moved;
    }

    /// Whether a held row's potential was changed at this step's start (`set_held_moved`).
    pub fn held_moved(&self) -> bool {
        self.held_moved
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
            ..
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

    /// `update_to` with another operator on the same rows and halo (a preconditioner's own
    /// copy of the operator, in other precision or weights): `op` has this one's pattern.
    pub fn update_with<F>(&mut self, op: &Operator, x: &mut NodeField<V3>, y: &mut [V3], f: F)
    where
        F: Fn(usize, V3, V3, &mut V3) + Sync,
    {
        let Propagation { halo, grad, layout, .. } = self;
        let f = |_: &mut (), i, xi, l, yi: &mut V3| f(i, xi, l, yi);
        sweep(op, halo, grad, x, *layout, |op, x, g, rows| {
            op.fold_rows(x, g, y, rows, &f, &|_, _| ());
        });
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

/// The propagation as the linear solvers see it (`linalg::Sweep`): its sweeps, and the
/// compact operator's coefficients and pattern.
impl Sweep for Propagation {
    type Twin = Operator;

    fn frozen(&self) -> &[u32] {
        &self.frozen
    }

    fn layout(&self) -> Layout {
        self.layout
    }

    fn halo(&self) -> &Halo {
        &self.halo
    }

    fn coefficients(&self) -> Option<&AnyCsr> {
        match &self.op {
            Operator::Compact(c) => Some(c.coefficients()),
            Operator::Paper(_) => None,
        }
    }

    fn sink(&self) -> Option<&[f64]> {
        match &self.op {
            Operator::Compact(c) => c.sink(),
            Operator::Paper(_) => None,
        }
    }

    fn twin(&self, w: Vec<f32>) -> Operator {
        let Operator::Compact(c) = &self.op else {
            panic!("an operator of the compact scheme's pattern needs the compact scheme")
        };
        Operator::Compact(c.with_f32(w))
    }

    fn fold_to<A, F, C>(&mut self, x: &mut NodeField<V3>, y: &mut [V3], f: F, combine: C) -> A
    where
        A: Default + Send,
        F: Fn(&mut A, usize, V3, V3, &mut V3) + Sync,
        C: Fn(A, A) -> A + Sync,
    {
        Propagation::fold_to(self, x, y, f, combine)
    }

    fn update_with<F>(&mut self, op: &Operator, x: &mut NodeField<V3>, y: &mut [V3], f: F)
    where
        F: Fn(usize, V3, V3, &mut V3) + Sync,
    {
        Propagation::update_with(self, op, x, y, f)
    }

    fn refresh(&self, x: &mut NodeField<V3>) {
        Propagation::refresh(self, x)
    }
}

/// Level l of a fused sweep of d levels on the rows r, then the sources of those rows: level l
/// reads level l - 1 (level 0: phi) and writes `levels[l - 1]` (four values per node), the
/// last level writes `next`.
#[allow(clippy::too_many_arguments)]
#[inline]
fn level_rows(
    c: &crate::discretize::operator::Compact,
    h: f64,
    qs: &[(u32, V3)],
    phi: &NodeField<V3>,
    next: &mut NodeField<V3>,
    levels: &mut [NodeField<[f64; 4]>],
    l: usize,
    d: usize,
    r: Range<usize>,
) {
    let so = if l == d { 3 } else { 4 };
    let y: &mut [f64] = match (l, l == d) {
        (1, false) => {
            c.step_strided::<3, 4>(
                phi.flat(),
                &mut levels[0].flat_mut()[4 * r.start..4 * r.end],
                h,
                r.start,
            );
            levels[0].flat_mut()
        }
        (_, false) => {
            let (a, b) = levels.split_at_mut(l - 1);
            c.step_strided::<4, 4>(
                a[l - 2].flat(),
                &mut b[0].flat_mut()[4 * r.start..4 * r.end],
                h,
                r.start,
            );
            b[0].flat_mut()
        }
        (_, true) => {
            let y = &mut next.flat_mut()[3 * r.start..3 * r.end];
            if l == 1 {
                c.step_strided::<3, 3>(phi.flat(), y, h, r.start);
            } else {
                c.step_strided::<4, 3>(levels[l - 2].flat(), y, h, r.start);
            }
            next.flat_mut()
        }
    };
    if qs.is_empty() {
        return;
    }
    let first = qs.partition_point(|s| (s.0 as usize) < r.start);
    for &(i, qi) in qs[first..].iter().take_while(|s| (s.0 as usize) < r.end) {
        let y = &mut y[so * i as usize..so * i as usize + 3];
        y[0] += h * qi[0];
        y[1] += h * qi[1];
        y[2] += h * qi[2];
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discretize::operator::{Compact, Kernel};

    /// The compact operator of a small bench box (Morton order) and one in RCM order.
    fn box_operator(cells: usize) -> (Compact, f64) {
        let setup = crate::config::Setup::bench_box(cells, "compact").unwrap();
        let sim = crate::simulate::Simulation::new(setup).unwrap();
        let h = sim.step_plan().h;
        let Operator::Compact(c) = &sim.prop.op else {
            unreachable!()
        };
        let id: Vec<u32> = (0..c.row_ptr().len() as u32 - 1).collect();
        (c.permuted(&id), h)
    }

    fn run(c: &Compact, layout: Layout, fuse: usize, count: usize, h: f64) -> Vec<V3> {
        let n = layout.n_owned;
        let id: Vec<u32> = (0..n as u32).collect();
        let mut p = Propagation::new(Operator::Compact(c.permuted(&id)), Halo::serial(), layout, Fuse::Auto);
        p.set_fuse(fuse);
        assert_eq!(p.fuses(), fuse > 1, "the fused sweep runs on one thread");
        for (i, x) in p.phi.iter_mut().enumerate() {
            *x = [(i as f64 * 0.37).sin(), (i as f64 * 0.11).cos(), 1.0 / (1.0 + i as f64)];
        }
        // sources: repeated nodes keep their order, one on the last row
        let q = vec![
            (7u32, [1.0, 0.5, 0.0]),
            (3, [0.0, 2.0, 1.0]),
            (7, [1e-3, 0.0, 3.0]),
            (n as u32 - 1, [1.0; 3]),
        ];
        p.substeps(h, &q, count);
        p.phi.owned().to_vec()
    }

    fn bits(x: &[V3]) -> Vec<u64> {
        x.iter().flatten().map(|v| v.to_bits()).collect()
    }

    #[test]
    fn fused_substeps_are_bitwise_plain_substeps() {
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        one.install(fused_bitwise);
    }

    fn fused_bitwise() {
        let (c, h) = box_operator(7);
        let n = c.row_ptr().len() - 1;
        // RCM order too: the fronts stay close there
        let mesh = eprop_io::generate::box_mesh([1.0; 3], [7; 3], eprop_io::generate::BoxCells::Tet).unwrap();
        let (xadj, adj) = eprop_partition::node_graph(mesh.n_nodes(), &mesh.offsets, &mesh.conn);
        let key = eprop_partition::rcm_keys(&xadj, &adj);
        let new_of: Vec<u32> = key.iter().map(|&k| k as u32).collect();
        let rcm = c.permuted(&new_of);
        let mut portable = c.permuted(&(0..n as u32).collect::<Vec<_>>());
        portable.kernel = Kernel { vector: false };
        let single = c.permuted(&(0..n as u32).collect::<Vec<_>>()).into_f32();
        // every row interior (one process), and a border of the last 40 % (the catch-up path)
        let layouts = [
            Layout::serial(n),
            Layout {
                n_interior: n * 3 / 5,
                n_owned: n,
                n_local: n,
            },
        ];
        for op in [&c, &rcm, &portable, &single] {
            for layout in layouts {
                for count in [2, 5, 11] {
                    let plain = bits(&run(op, layout, 1, count, h));
                    for fuse in [2, 3, 4, 8] {
                        let f = bits(&run(op, layout, fuse, count, h));
                        assert!(
                            f == plain,
                            "fuse {fuse}, {count} substeps, layout {layout:?}: bits differ"
                        );
                    }
                }
            }
        }
        // the fused sweep changes phi (the test compares something that moves)
        let before = run(&c, layouts[0], 1, 0, h);
        assert_ne!(bits(&before), bits(&run(&c, layouts[0], 4, 4, h)));
    }
}
