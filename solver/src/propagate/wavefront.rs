//! Temporal blocking of forward Euler substeps (`compact` scheme): `depth` substeps in one
//! sweep over the rows. Substep l of a block (level l) follows level l - 1 through the rows in
//! segments of consecutive rows; a segment runs once every value it reads at level l - 1 is
//! there. With a band-limited node order (`eprop_partition::rcm_keys`) the fronts of the levels
//! stay a band of rows apart, so what level l reads (the operator rows and the potential that
//! level l - 1 read or wrote moments before) is still in cache: the operator streams from memory
//! about once per block instead of once per substep.
//!
//! Every row runs the same kernel on the same values as in `Propagation::substep`, and sources
//! are added to a row right after it is computed, as there: the result is bitwise that of
//! `depth` plain substeps.
//!
//! Under MPI the wavefront covers the interior rows whose inputs at every earlier level are
//! themselves in the wavefront (rows at least `l - 1` neighbours away from the border at level
//! l); the rest of each level follows in level order, each level's halo exchanged once, the
//! exchange of level l - 1 overlapped with the interior rows of level l left out of the wavefront.

use crate::discretize::operator::Compact;
use eprop_partition::Layout;
use std::ops::Range;

/// Rows per segment: small enough that level l follows level l - 1 closely, large enough that
/// the hardware prefetchers follow the operator's streams between switches of level (64 rows
/// measured up to 2x slower than 256 on an organ mesh; 1,024 no better).
const SEG: usize = 256;

/// Consecutive rows of one level and the largest index they read at the level before.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Segment {
    pub start: u32,
    pub end: u32,
    pub need: u32,
}

/// Runs the segments of the levels `levels[0..d]` in wavefront order: one segment of level 1,
/// then every other level as far as the level before allows, and again, until no level can go
/// on. `run(st, l, segment)` runs a segment of level l and returns the rows it counts towards
/// `poke(st)`, called after every 16k rows (the MPI progress of an exchange in flight).
pub fn drive<T>(
    levels: &[Vec<Segment>],
    st: &mut T,
    mut run: impl FnMut(&mut T, usize, &Segment) -> usize,
    mut poke: impl FnMut(&mut T),
) {
    let d = levels.len();
    let mut at = vec![0usize; d + 1];
    let mut done = vec![0u32; d + 1];
    done[0] = u32::MAX;
    let mut rows_since = 0;
    loop {
        let mut busy = false;
        for l in 1..=d {
            let segs = &levels[l - 1];
            while let Some(s) = segs.get(at[l]) {
                if s.need >= done[l - 1] {
                    break;
                }
                rows_since += run(st, l, s);
                done[l] = s.end;
                at[l] += 1;
                busy = true;
                if l == 1 {
                    break; // one segment of level 1, then the others catch up
                }
            }
            if at[l] == segs.len() {
                done[l] = u32::MAX;
            }
        }
        if rows_since >= 16 * 1024 {
            poke(st);
            rows_since = 0;
        }
        if !busy {
            break;
        }
    }
}

/// The schedule of a block of up to `depth` fused substeps on one process.
#[derive(Clone, Debug)]
pub struct Wavefront {
    pub depth: usize,
    /// `deep[l - 1]`: the wavefront segments of level l, in row order.
    pub deep: Vec<Vec<Segment>>,
    /// `rest[l - 1]`: the interior rows of level l outside the wavefront.
    pub rest: Vec<Vec<Range<usize>>>,
    pub layout: Layout,
}

impl Wavefront {
    /// The schedule of `depth` levels for the rows of `c` on `layout`: level 1's wavefront is
    /// every interior row; level l's, the rows of level l - 1's whose every neighbour is in it.
    pub fn new(c: &Compact, layout: Layout, depth: usize) -> Wavefront {
        let ni = layout.n_interior;
        let (ptr, col) = (c.row_ptr(), c.col());
        let cols = |i: usize| &col[ptr[i] as usize..ptr[i + 1] as usize];
        let need: Vec<u32> = (0..ni)
            .map(|i| cols(i).iter().copied().max().unwrap_or(0).max(i as u32))
            .collect();
        let mut inside = vec![true; ni];
        let (mut deep, mut rest) = (vec![], vec![]);
        for l in 1..=depth.max(1) {
            if l > 1 {
                let prev = inside.clone();
                for (i, d) in inside.iter_mut().enumerate() {
                    *d = *d && cols(i).iter().all(|&j| (j as usize) < ni && prev[j as usize]);
                }
            }
            let (mut segs, mut out) = (vec![], vec![]);
            let mut i = 0;
            while i < ni {
                let run = i + inside[i..].iter().take_while(|&&d| d == inside[i]).count();
                if inside[i] {
                    for s in (i..run).step_by(SEG) {
                        let e = (s + SEG).min(run);
                        segs.push(Segment {
                            start: s as u32,
                            end: e as u32,
                            need: need[s..e].iter().copied().max().unwrap_or(0),
                        });
                    }
                } else {
                    out.push(i..run);
                }
                i = run;
            }
            deep.push(segs);
            rest.push(out);
        }
        Wavefront {
            depth: depth.max(1),
            deep,
            rest,
            layout,
        }
    }

    /// Rows of level l (1-based) that the wavefront leaves to the catch-up.
    pub fn rest_rows(&self, l: usize) -> usize {
        self.rest[l - 1].iter().map(|r| r.len()).sum::<usize>() + self.layout.border().len()
    }

    /// The largest distance in rows between a row and the values it reads, over the wavefront
    /// rows of level 2 (0 without one): how far level 2 trails level 1.
    pub fn lag(&self) -> usize {
        self.deep
            .get(1)
            .map(|s| {
                s.iter()
                    .map(|s| s.need.saturating_sub(s.start) as usize)
                    .max()
                    .unwrap_or(0)
            })
            .unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A path 0 - 1 - ... - 9: interior 0..8, border 8..10, halo 10.
    fn path() -> (Compact, Layout) {
        let n = 10usize;
        let mut row_ptr = vec![0u32];
        let mut col = vec![];
        for i in 0..n {
            if i > 0 {
                col.push(i as u32 - 1);
            }
            col.push(i as u32 + 1);
            row_ptr.push(col.len() as u32);
        }
        let val = vec![1.0; col.len()];
        let c = Compact::from_csr(crate::linalg::csr::AnyCsr::F64(crate::linalg::csr::Csr {
            n_cols: n + 1,
            ptr: row_ptr,
            col,
            val,
        }));
        let layout = Layout {
            n_interior: 8,
            n_owned: 10,
            n_local: 11,
        };
        (c, layout)
    }

    #[test]
    fn levels_shrink_away_from_the_border() {
        let (c, layout) = path();
        let w = Wavefront::new(&c, layout, 3);
        let rows = |l: usize| -> Vec<usize> {
            w.deep[l - 1]
                .iter()
                .flat_map(|s| s.start as usize..s.end as usize)
                .collect()
        };
        assert_eq!(rows(1), (0..8).collect::<Vec<_>>());
        assert_eq!(rows(2), (0..7).collect::<Vec<_>>()); // row 7 reads border row 8
        assert_eq!(rows(3), (0..6).collect::<Vec<_>>());
        assert_eq!(w.rest[2], vec![6..8]);
        assert_eq!(w.rest_rows(3), 4);
        assert_eq!(w.deep[1][0].need, 7);
        assert_eq!(w.lag(), 7);
    }
}
