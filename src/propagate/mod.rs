//! The propagation state of one process: the operator L of the vector Poisson equation, the
//! halo exchange it needs, the potential phi and work vectors. It offers the sweeps the
//! integrators are built from (`integrate`): an explicit Euler substep and an operator
//! application, each refreshing the halo of its input while the interior rows are computed.

pub mod integrate;
pub mod wavefront;

use crate::discretize::operator::{Operator, V3};
use crate::distribute::field::NodeField;
use crate::distribute::halo::{Exchange, Halo};
use crate::propagate::wavefront::{drive, DeepFront, Wavefront};
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
    /// The fused sweep's schedule and its level buffers, made on first use.
    wave: Option<Wavefront>,
    levels: Vec<NodeField<[f64; 4]>>,
    /// Level buffers of the fused sweep with four values per node (one 256-bit load per
    /// neighbour), else three (for comparisons: `examples/kernel_ab.rs`).
    pub pad: bool,
    /// Over a deep halo, sweep the owned and halo rows in one wavefront in the plan's locality
    /// order (`DeepFront`, `EPROP_DEEPFRONT=1`) rather than the interior wavefront then the
    /// rest of each level (the default: the exchange hides behind the interior rows).
    pub deep_front: bool,
    /// Halo layers a fused sweep may use (1: a one-layer halo, exchanged once per level; d >= 2:
    /// the operator has the rows of halo layers 1..d-1 and a sweep of up to d substeps
    /// exchanges d layers once, `deep_sweep`).
    deep: usize,
    /// `layer_end[k]`: one past the last local index of halo layer k + 1.
    layer_end: Vec<usize>,
    /// The visiting order of the deep sweep's rows (`Plan::order`; empty: local order).
    order: Vec<u32>,
    /// The deep sweep's schedule, made on first use.
    front: Option<DeepFront>,
    /// Sources of the halo rows the deep sweep computes (copies of their owners' sources, in
    /// the owners' order), set with `set_halo_sources`.
    halo_q: Vec<(u32, V3)>,
}

/// The depths (substeps per sweep) the tuner tries (under a deep halo, those up to its depth).
pub const DEPTHS: [usize; 5] = [1, 2, 3, 4, 8];
/// Sweeps of each depth the tuner times before it chooses.
const TUNE_ROUNDS: usize = 3;

/// `EPROP_FUSE=d`: d substeps per sweep (1: no fusion), also under MPI; unset or `auto`: chosen
/// by timing on one process, none on several.
fn fuse_setting() -> Option<usize> {
    std::env::var("EPROP_FUSE")
        .ok()
        .and_then(|v| v.parse().ok())
        .map(|d: usize| d.clamp(1, 16))
}

/// Chooses the fusion depth on this process by timing sweeps of each depth in turn (the
/// fastest depth depends on the mesh, the caches and the load of the machine: 8 on a 300k-node
/// box, 4 on a 1M box and on a 749k-node kidney). The choice changes the speed only:
/// every depth gives the same bits; processes agree on it (`choice`), though differing depths
/// would still pair their messages (one exchange per substep whatever the grouping).
#[derive(Clone, Debug)]
struct Tuner {
    /// The depths tried, in turn.
    depths: Vec<usize>,
    /// Seconds per substep of the timed sweeps, per depth in `depths`.
    times: Vec<Vec<f64>>,
    round: usize,
}

impl Tuner {
    /// Tries the depths of `DEPTHS` up to `max`.
    fn new(max: usize) -> Tuner {
        let depths: Vec<usize> = DEPTHS.iter().copied().filter(|&d| d <= max).collect();
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
    /// The depth with the smallest median time (the largest over the processes, so that all
    /// choose the same: a process fusing while its neighbour does not waits for the neighbour's
    /// whole sweep), once every depth had its rounds. Every process reaches the end of the
    /// rounds at the same call (the same substep counts everywhere), where `halo` reduces.
    fn choice(&self, halo: &Halo) -> Option<usize> {
        if self.round < TUNE_ROUNDS * self.depths.len() {
            return None;
        }
        let mut medians: Vec<f64> = self
            .times
            .iter()
            .map(|v| {
                let mut v = v.clone();
                v.sort_by(f64::total_cmp);
                v.get(v.len() / 2).copied().unwrap_or(f64::INFINITY)
            })
            .collect();
        halo.max_all(&mut medians);
        let best = (0..self.depths.len()).min_by(|&a, &b| medians[a].total_cmp(&medians[b]));
        Some(best.map_or(1, |k| self.depths[k]))
    }
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
        // A deep halo serves sweeps of up to its depth, as far as the operator has the rows of
        // its layers (the paper scheme never has them).
        let pattern = halo.pattern();
        let layer_end: Vec<usize> = pattern.layer_end.iter().map(|&e| e as usize).collect();
        let rows = op.n_rows();
        let deep = (1..=pattern.depth())
            .take_while(|&d| d == 1 || (matches!(op, Operator::Compact(_)) && layer_end[d - 2] <= rows))
            .last()
            .unwrap_or(1);
        // One collective (every process builds its propagation at the same point): whether
        // there are several processes, the largest `EPROP_FUSE` and the smallest deep halo, and
        // whether some process cannot fuse (several threads).
        let setting = fuse_setting();
        let can = rayon::current_num_threads() == 1;
        let mut agreed = [
            if pattern.neighbours.is_empty() { 0.0 } else { 1.0 },
            setting.unwrap_or(0) as f64,
            -(deep as f64),
            if can { 0.0 } else { 1.0 },
        ];
        halo.max_all(&mut agreed);
        let several = agreed[0] > 0.0;
        let deep = if agreed[3] > 0.0 { 1 } else { (-agreed[2]) as usize };
        // Without a setting, one process tunes its depth, and so do several over a deep halo
        // (one exchange per sweep; the tuner's choice is the same on every process). Over a
        // one-layer halo several processes do not fuse: a fused sweep makes one halo exchange
        // per level with little work left to hide it, and on a loaded machine each of them
        // waits for a descheduled neighbour (2 processes, 300k and 1M boxes: 1.2x faster to
        // 3.5x slower than one substep per sweep, run to run). Over a deep halo every process
        // sweeps the same depth (the exchanges pair sweep by sweep): the largest setting, at
        // most the halo's depth.
        let (fuse, tuner) = match setting {
            Some(_) if deep >= 2 => ((agreed[1] as usize).clamp(1, deep), None),
            Some(d) => (d, None),
            None if several && deep < 2 => (1, None),
            None => {
                let max = if several { deep } else { usize::MAX };
                (DEPTHS[DEPTHS.len() - 1].min(max), Some(Tuner::new(max)))
            }
        };
        tracing::debug!(
            "propagation: {} halo layers for fused sweeps, {} substeps per sweep{}",
            deep,
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
            pad: true,
            deep_front: std::env::var("EPROP_DEEPFRONT").is_ok_and(|v| v == "1"),
            deep,
            layer_end,
            halo_q: vec![],
            order: vec![],
            front: None,
        }
    }

    /// The order in which a fused sweep over a deep halo visits its rows (`Plan::order`).
    pub fn set_sweep_order(&mut self, order: Vec<u32>) {
        self.order = order;
        self.front = None;
    }

    /// Halo layers a fused sweep uses (1: one exchange per level).
    pub fn halo_depth(&self) -> usize {
        self.deep
    }

    /// The sources of the halo rows of a deep halo (local index of a node in halo layers
    /// 1..depth-1, Q), the same as their owners give `substeps`, in the same order; used by
    /// deep sweeps, for the `substeps` calls until they are set again.
    pub fn set_halo_sources(&mut self, q: Vec<(u32, V3)>) {
        self.halo_q = q;
    }

    /// Substeps per fused sweep from now on (1: every substep on its own; over a deep halo at
    /// most its depth); no tuning. Over a deep halo every process must set the same depth.
    pub fn set_fuse(&mut self, depth: usize) {
        self.fuse = if self.deep >= 2 {
            depth.clamp(1, self.deep)
        } else {
            depth.max(1)
        };
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
                if let Some(best) = t.choice(&self.halo) {
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
        if self.deep >= d && !self.deep_front {
            if !self.pad {
                self.fused_p::<3, true>(h, q, d)
            } else {
                self.fused_p::<4, true>(h, q, d)
            }
        } else if self.deep >= d {
            if !self.pad {
                self.deep_sweep::<3>(h, q, d)
            } else {
                self.deep_sweep::<4>(h, q, d)
            }
        } else if !self.pad {
            self.fused_p::<3, false>(h, q, d)
        } else {
            self.fused_p::<4, false>(h, q, d)
        }
    }

    /// A fused sweep of `d` substeps over a deep halo (`DeepFront`): one exchange of d layers
    /// of phi, then one wavefront over the owned rows and the halo rows still valid at each
    /// level (level l: halo layers 1..d-l), the halo rows with their owners' sources.
    fn deep_sweep<const P: usize>(&mut self, h: f64, q: &Sources, d: usize) {
        if self.front.as_ref().is_none_or(|f| f.depth != d) {
            let Operator::Compact(c) = &self.op else {
                unreachable!("fused sweeps run the compact scheme")
            };
            let f = DeepFront::new(c, self.layout, &self.layer_end, &self.order, d);
            tracing::debug!(
                "deep front: {} levels, {} runs, {} segments per level, owned {}, rows {}",
                d,
                f.runs.len(),
                f.levels[0].len(),
                self.layout.n_owned,
                self.layer_end.get(d.saturating_sub(2)).copied().unwrap_or(0)
            );
            self.front = Some(f);
        }
        while self.levels.len() + 1 < d {
            self.levels.push(NodeField::filled(self.layout, [0.0; 4]));
        }
        let mut qs = q.to_vec();
        qs.extend_from_slice(&self.halo_q);
        qs.sort_by_key(|s| s.0); // stable: a node's sources keep their order
        let Propagation {
            op,
            halo,
            phi,
            next,
            front,
            levels,
            ..
        } = self;
        let (Operator::Compact(c), Some(f)) = (&*op, front.as_ref()) else {
            unreachable!("fused sweeps run the compact scheme")
        };
        let ex = Some(halo.start_layers(phi.flat(), 3, 3, d));
        let mut st = (phi, next, levels, ex);
        drive(
            &f.levels[..d],
            &mut st,
            |(phi, next, levels, ex), l, s| {
                if s.halo {
                    if let Some(e) = ex.take() {
                        e.finish(phi.flat_mut());
                    }
                }
                let mut rows = 0;
                for r in &f.runs[s.runs.start as usize..s.runs.end as usize] {
                    level_rows::<P>(c, h, &qs, phi, next, levels, l, d, r.start as usize..r.end as usize);
                    rows += r.len();
                }
                rows
            },
            |(_, _, _, ex)| {
                if let Some(e) = ex.as_mut() {
                    e.progress();
                }
            },
        );
        let (phi, next, _, mut ex) = st;
        if let Some(e) = ex.take() {
            e.finish(phi.flat_mut());
        }
        std::mem::swap(phi, next);
    }

    fn fused_p<const P: usize, const DEEP: bool>(&mut self, h: f64, q: &Sources, d: usize) {
        self.wavefront();
        while self.levels.len() + 1 < d {
            self.levels.push(NodeField::filled(self.layout, [0.0; 4]));
        }
        let mut qs = q.to_vec();
        if DEEP {
            // the halo rows' sources too (indices beyond the owned ones)
            qs.extend_from_slice(&self.halo_q);
        }
        let Propagation {
            op,
            halo,
            phi,
            next,
            wave,
            levels,
            layout,
            layer_end,
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
                   r: Range<usize>| level_rows::<P>(c, h, &qs, phi, next, levels, l, d, r);
        // the wavefront over the interior, phi's halo in flight
        let ex = Some(halo.start_layers(phi.flat(), 3, 3, if DEEP { d } else { 1 }));
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
        if DEEP {
            // the rest of each level in level order: the interior rows outside the wavefront,
            // the border rows and halo layers 1..d-l (each level's halo rows read the level
            // before on one layer more, all computed here from phi's d layers)
            if let Some(e) = ex.take() {
                e.finish(phi.flat_mut());
            }
            for l in 1..=d {
                for r in &w.rest[l - 1] {
                    run(phi, next, levels, l, r.clone());
                }
                run(phi, next, levels, l, border.clone());
                if l < d {
                    run(phi, next, levels, l, layout.n_owned..layer_end[d - l - 1]);
                }
            }
            std::mem::swap(phi, next);
            return;
        }
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
                // three values per node whatever the padding: the messages of a process that
                // pads pair with those of one that does not (or does not fuse)
                ex = Some(halo.start_part(&levels[l - 1].flat()[..P * layout.n_local], P, 3));
            }
        }
        std::mem::swap(phi, next);
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

/// Level l of a fused sweep of d levels on the rows r, then the sources of those rows: level l
/// reads level l - 1 (level 0: phi) and writes `levels[l - 1]` (`P` values per node), the last
/// level writes `next`.
#[allow(clippy::too_many_arguments)]
#[inline]
fn level_rows<const P: usize>(
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
    let so = if l == d { 3 } else { P };
    let y: &mut [f64] = match (l, l == d) {
        (1, false) => {
            c.step_strided::<3, P>(
                phi.flat(),
                &mut levels[0].flat_mut()[P * r.start..P * r.end],
                h,
                r.start,
            );
            levels[0].flat_mut()
        }
        (_, false) => {
            let (a, b) = levels.split_at_mut(l - 1);
            c.step_strided::<P, P>(
                a[l - 2].flat(),
                &mut b[0].flat_mut()[P * r.start..P * r.end],
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
                c.step_strided::<P, 3>(levels[l - 2].flat(), y, h, r.start);
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
        let setup = crate::cli::bench::box_setup(cells, "compact").unwrap();
        let sim = crate::simulate::Simulation::new(setup).unwrap();
        let h = sim.step_plan().h;
        let Operator::Compact(c) = &sim.prop.op else {
            unreachable!()
        };
        let id: Vec<u32> = (0..c.row_ptr.len() as u32 - 1).collect();
        (c.permuted(&id), h)
    }

    fn run(c: &Compact, layout: Layout, fuse: usize, count: usize, h: f64) -> Vec<V3> {
        let n = layout.n_owned;
        let id: Vec<u32> = (0..n as u32).collect();
        let mut p = Propagation::new(Operator::Compact(c.permuted(&id)), Halo::serial(), layout);
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
        let n = c.row_ptr.len() - 1;
        // RCM order too: the fronts stay close there
        let mesh = eprop_io::generate::box_mesh([1.0; 3], [7; 3], eprop_io::generate::BoxCells::Tet).unwrap();
        let (xadj, adj) = eprop_partition::node_graph(mesh.n_nodes(), &mesh.offsets, &mesh.conn);
        let key = eprop_partition::rcm_keys(&xadj, &adj);
        let new_of: Vec<u32> = key.iter().map(|&k| k as u32).collect();
        let rcm = c.permuted(&new_of);
        let mut portable = c.permuted(&(0..n as u32).collect::<Vec<_>>());
        portable.kernel = Kernel {
            vector: false,
            prefetch: 0,
        };
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

#[cfg(test)]
mod deep_tests {
    use super::*;
    use crate::config::Setup;
    use crate::discretize::geometry::{compact_coefficients, Dual, Incidence};
    use crate::discretize::operator::Compact;
    use eprop_partition::Plan;

    /// The compact operator of the rows `0..plan.rows()` of a process's part, built as the
    /// simulation builds it (rows of halo layers 1..depth-1 included).
    fn operator_of(whole: &Setup, plan: &Plan, f32: bool) -> Compact {
        let s = whole.restrict(plan);
        let rows = plan.rows();
        let gid: Vec<u64> = plan.numbering.global.iter().map(|&g| g as u64).collect();
        let inc = Incidence::new(&s.mesh);
        let dual = Dual::build(&s.mesh, &inc, rows, Some(&gid));
        let active: Vec<bool> = (0..gid.len())
            .map(|i| !s.fixed[i] && (i >= rows || dual.vol[i] > 0.0))
            .collect();
        let a = compact_coefficients(&s.mesh, &inc, &dual, &s.r);
        let c = Compact::from_pairs(&dual.row_ptr[..=rows], dual.col.clone(), a, &dual.vol, &active);
        if f32 {
            c.into_f32()
        } else {
            c
        }
    }

    fn start(g: u32) -> V3 {
        let x = g as f64;
        [(x * 0.37).sin(), (x * 0.11).cos(), 1.0 / (1.0 + x)]
    }

    /// Sources on global nodes (two on one node, in order).
    const SOURCES: [(u32, V3); 5] = [
        (40, [1.0, 0.5, 0.0]),
        (200, [0.0, 2.0, 1.0]),
        (40, [1e-3, 0.0, 3.0]),
        (170, [0.5; 3]),
        (301, [1.0, -1.0, 0.25]),
    ];

    /// One process of a split, its halo values written by hand from the run of the whole mesh
    /// before every sweep (the exchange a deep sweep makes once): the owned values after each
    /// sweep of d substeps are bitwise those of the whole mesh's single substeps, for halos of
    /// 2, 3 and 8 layers, sweeps of 2 to 8 substeps, float64 and float32 coefficients, both
    /// deep sweeps (the interior wavefront then the rest; `DeepFront`).
    #[test]
    fn deep_sweeps_are_bitwise_the_whole_meshs_substeps() {
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        one.install(deep_bitwise);
    }

    fn deep_bitwise() {
        let whole = crate::cli::bench::box_setup(7, "compact").unwrap();
        let m = &whole.mesh;
        let n = m.n_nodes();
        let (xadj, adj) = eprop_partition::node_graph(n, &m.offsets, &m.conn);
        let key = eprop_partition::rcm_keys(&xadj, &adj);
        let h = 2e-3;
        for f32 in [false, true] {
            // the whole mesh, one substep at a time: the state after every substep, by global id
            let serial = Plan::new(n, &m.offsets, &m.conn, &vec![0; n], 0, Some(&key));
            let mut all = Propagation::new(
                Operator::Compact(operator_of(&whole, &serial, f32)),
                Halo::serial(),
                serial.numbering.layout(),
            );
            all.set_fuse(1);
            let g_all = &serial.numbering.global;
            for (x, &g) in all.phi.iter_mut().zip(g_all) {
                *x = start(g);
            }
            let local_of = |plan: &Plan, g: u32| plan.numbering.global.iter().position(|&x| x == g);
            let q_all: Vec<(u32, V3)> = SOURCES
                .iter()
                .map(|&(g, q)| (local_of(&serial, g).unwrap() as u32, q))
                .collect();
            let mut states = vec![];
            for _ in 0..=16 {
                let mut by_gid = vec![[0.0; 3]; n];
                for (x, &g) in all.phi.iter().zip(g_all) {
                    by_gid[g as usize] = *x;
                }
                states.push(by_gid);
                all.substep(h, &q_all);
            }
            for parts in [2, 3] {
                let part = eprop_partition::partition(&xadj, &adj, parts, eprop_partition::Method::Metis).unwrap();
                for (depth, sweeps) in [(2, &[2][..]), (3, &[2, 3]), (8, &[2, 3, 8])] {
                    for rank in 0..parts {
                        let plan = Plan::with_depth(n, &m.offsets, &m.conn, &part, rank, Some(&key), depth);
                        assert!(plan.rows() > plan.numbering.n_owned, "halo rows to compute");
                        let nb = &plan.numbering;
                        let (q, hq): (Vec<(u32, V3)>, Vec<(u32, V3)>) = SOURCES
                            .iter()
                            .filter_map(|&(g, q)| local_of(&plan, g).map(|l| (l as u32, q)))
                            .filter(|&(l, _)| (l as usize) < plan.rows())
                            .partition(|&(l, _)| (l as usize) < nb.n_owned);
                        for (&d, front) in sweeps.iter().flat_map(|d| [(d, false), (d, true)]) {
                            let mut p = Propagation::new(
                                Operator::Compact(operator_of(&whole, &plan, f32)),
                                Halo::without_comm(plan.pattern.clone()),
                                nb.layout(),
                            );
                            assert_eq!(p.halo_depth(), depth);
                            p.set_fuse(d);
                            assert!(p.fuses());
                            p.set_halo_sources(hq.clone());
                            p.deep_front = front;
                            if rank == 1 {
                                p.set_sweep_order(plan.order.clone()); // else the local order
                            }
                            for (x, &g) in p.phi.iter_mut().zip(&nb.global) {
                                *x = start(g);
                            }
                            for sweep in 1..=2 {
                                p.substeps(h, &q, d);
                                let want = &states[sweep * d];
                                for (l, x) in p.phi.owned().iter().enumerate() {
                                    let g = nb.global[l] as usize;
                                    assert!(
                                        x.iter().zip(&want[g]).all(|(a, b)| a.to_bits() == b.to_bits()),
                                        "f32 {f32}, {parts} parts, rank {rank}, {depth} layers, front {front}, sweep {sweep} of {d}: node {g}"
                                    );
                                }
                                // the exchange, by hand
                                for l in nb.n_owned..nb.n_local() {
                                    p.phi[l] = want[nb.global[l] as usize];
                                }
                            }
                            assert_ne!(states[2 * d], states[0], "the values move");
                        }
                    }
                }
            }
        }
    }
}
