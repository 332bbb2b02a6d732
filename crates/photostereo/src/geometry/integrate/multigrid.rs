//! A weighted 5-point graph Laplacian on a (masked) pixel grid, plus a non-negative diagonal,
//! solved by conjugate gradients preconditioned with a multigrid V-cycle.
//!
//! Operator: `(A x)_i = e_i x_i + Σ_j w_ij (x_i − x_j)` over the 4-neighbours `j` of `i`, with
//! `e_i ≥ 0` a prior's weight or a Dirichlet anchor (often 0 everywhere). It is applied in this
//! difference form, so that `A·1 = 0` exactly when `e = 0` whatever the rounding of the f32
//! weights: such a problem is singular with one constant per connected component, and [`pcg`]
//! solves it as such (see its `null_space`). Inactive cells (outside the mask) have no edges and
//! `1/d_i = 0` (`d_i = Σ_j w_ij + e_i`); they are never touched.
//!
//! Multigrid: 2×2 aggregation (piecewise-constant prolongation `P`, restriction `Pᵀ`), coarse
//! operators by Galerkin `PᵀAP` with the Laplacian part scaled by ½ — which is what
//! rediscretising the Laplacian on the coarse grid gives for a constant weight (plain Galerkin
//! with piecewise-constant `P` is twice too stiff on smooth modes and loses grid independence).
//! Smoothing: red–black Gauss–Seidel, red then black before the coarse correction (from zero) and
//! black then red after it, so that the V-cycle is a symmetric positive definite preconditioner.
//! The coarsest grid (at most 8×8) is solved exactly by a dense Cholesky factorisation, with one
//! diagonal entry doubled in each component that nothing anchors.
//!
//! Storage (bounded memory): the finest level stores nothing — its edge weights, extra
//! diagonal and `1/d` are computed row by row from the caller's mask and per-pixel weights
//! ([`Level::problem`], [`Level::fill`]) into a few scratch rows per thread. The coarse levels
//! (a third of the fine cells together) store their weights in f32. Every vector is f32 (the
//! CG iterate, residual and direction, the V-cycle's work); sums, dot products and each cell's
//! `A x` are taken in f64.

use super::{Components, LabelSlice};
use crate::base::cholesky::{self, SmallPivot};
use crate::base::progress::Progress;
use rayon::prelude::*;

/// Rows handled by one rayon task (keeps task overhead negligible on small grids).
const ROWS_PER_TASK: usize = 16;
/// Largest side of the coarsest grid.
const COARSEST_SIDE: usize = 8;
/// A computed finest level of at most this many cells is stored once (16 bytes a cell, 8 MiB
/// at most, inside the memory plan's fixed allowance): on small grids recomputing its rows in
/// every sweep costs more than reading them.
const STORE_FINE_UP_TO: usize = 1 << 19;

/// How a level's operator is held.
#[derive(Clone, Debug)]
enum Kind<'a> {
    /// Stored weights (the coarse levels, small test grids).
    Stored {
        /// Weight of the edge from cell `i` to `i + 1` (0 in the last column or when absent).
        east: Vec<f32>,
        /// Weight of the edge from cell `i` to `i + w` (0 in the last row or when absent).
        south: Vec<f32>,
        /// The extra diagonal `e_i ≥ 0`; 0 outside. Empty when it is 0 everywhere.
        extra: Vec<f32>,
        /// `1 / d_i`; 0 marks an inactive cell.
        inv_diag: Vec<f32>,
    },
    /// The normal equations of an integration problem, computed from its inputs: the cells of
    /// `mask`; the edge between two masked 4-neighbours weighs `max(min(w_a, w_b), min_edge)`
    /// (`w = 1` without `weights`); the extra diagonal is `lambda` on the mask.
    Problem {
        mask: &'a [bool],
        weights: Option<&'a [f32]>,
        min_edge: f32,
        lambda: f32,
    },
    /// The harmonic fill of unreliable gradients: the cells are the holes (mask pixels whose
    /// weight is below `below`), unit edges between holes, and the extra diagonal of a hole is
    /// the number of its reliable mask neighbours (Dirichlet data), plus 1 at each of `pins`
    /// (one cell of each hole component without reliable neighbours; sorted).
    Fill {
        mask: &'a [bool],
        weights: &'a [f32],
        below: f32,
        pins: Vec<usize>,
    },
    /// An operator whose owner computes its rows (see [`RowOperator`]); stores nothing.
    Computed { op: &'a dyn RowOperator },
}

/// The rows of one computed row of a level, for a [`RowOperator`] to fill: the east edges of
/// the row (the last one is set to 0 after), its south edges, the south edges of the row above
/// (zeros on the first row), the extra diagonal, which cells are active, and scratch `work` the
/// operator may size as it needs (kept between rows of one thread).
pub(crate) struct RowParts<'s> {
    pub e: &'s mut [f32],
    pub s: &'s mut [f32],
    pub su: &'s mut [f32],
    pub ex: &'s mut [f32],
    pub active: &'s mut [bool],
    pub work: &'s mut Vec<f32>,
}

/// A finest-level operator computed row by row by the integrator that owns its inputs (the
/// bilateral systems, whose edge weights come from its reweighting), so that neither its
/// edge weights nor `1 / d` are stored; `1 / d` is computed from the row as for the other
/// computed levels ([`inverse_diagonal`]).
pub(crate) trait RowOperator: Sync + std::fmt::Debug {
    /// Writes row `r` of the operator into `out`.
    fn row(&self, r: usize, out: RowParts<'_>);
}

/// One grid level of the operator.
#[derive(Clone, Debug)]
pub(crate) struct Level<'a> {
    pub w: usize,
    pub h: usize,
    kind: Kind<'a>,
}

/// One row of a level's operator: east and south weights, the south weights of the row above
/// (zeros on the first row), the extra diagonal and `1 / d` (0 on inactive cells).
pub(crate) struct Rows<'s> {
    pub e: &'s [f32],
    pub s: &'s [f32],
    pub su: &'s [f32],
    pub ex: &'s [f32],
    pub inv: &'s [f32],
}

/// Scratch rows (one per thread) into which computed levels write their rows.
pub(crate) struct Scratch {
    e: Vec<f32>,
    s: Vec<f32>,
    su: Vec<f32>,
    ex: Vec<f32>,
    inv: Vec<f32>,
    zeros: Vec<f32>,
    active: Vec<bool>,
    /// Scratch of a [`RowOperator`] (empty until it sizes it).
    work: Vec<f32>,
    /// The row whose operator the computed rows hold (`usize::MAX`: none), so that a row
    /// computed for one colour of a sweep is reused by the other.
    row: usize,
}

impl Scratch {
    pub fn new(w: usize) -> Scratch {
        Scratch {
            e: vec![0.0; w],
            s: vec![0.0; w],
            su: vec![0.0; w],
            ex: vec![0.0; w],
            inv: vec![0.0; w],
            zeros: vec![0.0; w],
            active: vec![false; w],
            work: Vec::new(),
            row: usize::MAX,
        }
    }
}

/// A raw pointer that may cross threads; used by red–black sweeps, where the cells written in a
/// half-sweep (one colour) are never read by the same half-sweep.
#[derive(Clone, Copy)]
struct SharedMut(*mut f32);
unsafe impl Send for SharedMut {}
unsafe impl Sync for SharedMut {}

impl SharedMut {
    /// The pointer (a method, so that closures capture the whole `Send` wrapper).
    fn get(self) -> *mut f32 {
        self.0
    }
}

/// `1 / d` of the cells of one row (`d = e + s + ex + e_left + s_up`, summed in that order);
/// 0 where the cell is not `active` or `d = 0`. Vectorisable.
#[inline]
fn inverse_diagonal(
    e: &[f32],
    s: &[f32],
    su: &[f32],
    ex: &[f32],
    active: &[bool],
    inv: &mut [f32],
) {
    let w = inv.len();
    for (((d, &ev), &sv), &xv) in inv.iter_mut().zip(e).zip(s).zip(ex) {
        *d = ev + sv + xv;
    }
    for (d, &el) in inv[1..].iter_mut().zip(&e[..w - 1]) {
        *d += el;
    }
    for ((d, &sv), &a) in inv.iter_mut().zip(su).zip(active) {
        let v = *d + sv;
        *d = if a && v > 0.0 { 1.0 / v } else { 0.0 };
    }
}

/// One row of a [`Kind::Problem`] level's mask (`m`, from flat index `lo`) with the rows below
/// and above it (none beyond the grid).
struct MaskRows<'a> {
    lo: usize,
    m: &'a [bool],
    below: Option<&'a [bool]>,
    above: Option<&'a [bool]>,
}

/// The edge weights being computed for one row: east, south, and south of the row above.
struct EdgeRows<'s> {
    e: &'s mut [f32],
    s: &'s mut [f32],
    su: &'s mut [f32],
}

impl MaskRows<'_> {
    /// Edges without weights: `max(1, min_edge)` between masked 4-neighbours, 0 elsewhere (the
    /// last east edge is set by the caller).
    #[inline]
    fn unit_edges(&self, min_edge: f32, out: &mut EdgeRows) {
        let (m, w) = (self.m, self.m.len());
        let one = 1f32.max(min_edge);
        let on = |a: bool, b: bool| if a & b { one } else { 0.0 };
        for ((v, &a), &b) in out.e[..w - 1].iter_mut().zip(&m[..w - 1]).zip(&m[1..]) {
            *v = on(a, b);
        }
        match self.below {
            Some(md) => {
                for ((v, &a), &b) in out.s.iter_mut().zip(m).zip(md) {
                    *v = on(a, b);
                }
            }
            None => out.s.fill(0.0),
        }
        match self.above {
            Some(mu) => {
                for ((v, &a), &b) in out.su.iter_mut().zip(mu).zip(m) {
                    *v = on(a, b);
                }
            }
            None => out.su.fill(0.0),
        }
    }

    /// Edges with the weights `ws` (full frame): `max(min(w_a, w_b), min_edge)` between masked
    /// 4-neighbours, 0 elsewhere (the last east edge is set by the caller).
    #[inline]
    fn weighted_edges(&self, ws: &[f32], min_edge: f32, out: &mut EdgeRows) {
        let (m, w, lo) = (self.m, self.m.len(), self.lo);
        let wr = &ws[lo..lo + w];
        let edge = |a: bool, b: bool, wa: f32, wb: f32| {
            if a & b {
                wa.min(wb).max(min_edge)
            } else {
                0.0
            }
        };
        for ((v, (&a, &b)), (&wa, &wb)) in out.e[..w - 1]
            .iter_mut()
            .zip(m[..w - 1].iter().zip(&m[1..]))
            .zip(wr[..w - 1].iter().zip(&wr[1..]))
        {
            *v = edge(a, b, wa, wb);
        }
        match self.below {
            Some(md) => {
                let wd = &ws[lo + w..lo + 2 * w];
                for ((v, (&a, &b)), (&wa, &wb)) in out
                    .s
                    .iter_mut()
                    .zip(m.iter().zip(md))
                    .zip(wr.iter().zip(wd))
                {
                    *v = edge(a, b, wa, wb);
                }
            }
            None => out.s.fill(0.0),
        }
        match self.above {
            Some(mu) => {
                let wu = &ws[lo - w..lo];
                for ((v, (&a, &b)), (&wa, &wb)) in out
                    .su
                    .iter_mut()
                    .zip(mu.iter().zip(m))
                    .zip(wu.iter().zip(wr))
                {
                    *v = edge(a, b, wa, wb);
                }
            }
            None => out.su.fill(0.0),
        }
    }
}

impl<'a> Level<'a> {
    /// Builds a stored level from edge weights and the extra diagonal `extra(i)` (active cells:
    /// `active`).
    pub fn from_parts(
        w: usize,
        h: usize,
        east: Vec<f32>,
        south: Vec<f32>,
        extra: impl Fn(usize) -> f32 + Sync,
        active: &[bool],
    ) -> Level<'static> {
        // The extra diagonal is stored only where it is not 0 everywhere (often it is).
        let any_extra = (0..w * h)
            .into_par_iter()
            .any(|i| active[i] && extra(i) != 0.0);
        let mut extra_diag: Vec<f32> = if any_extra {
            par_zeros(w * h)
        } else {
            Vec::new()
        };
        let mut inv_diag: Vec<f32> = par_zeros(w * h);
        inv_diag
            .par_chunks_mut(w)
            .enumerate()
            .for_each(|(r, inv_row)| {
                for (c, inv) in inv_row.iter_mut().enumerate() {
                    let i = r * w + c;
                    if !active[i] {
                        continue;
                    }
                    let x = extra(i);
                    let mut s = east[i] + south[i] + x;
                    if c > 0 {
                        s += east[i - 1];
                    }
                    if r > 0 {
                        s += south[i - w];
                    }
                    *inv = if s > 0.0 { 1.0 / s } else { 0.0 };
                }
            });
        if any_extra {
            extra_diag
                .par_chunks_mut(w)
                .enumerate()
                .for_each(|(r, row)| {
                    for (c, x) in row.iter_mut().enumerate() {
                        let i = r * w + c;
                        if active[i] {
                            *x = extra(i);
                        }
                    }
                });
        }
        Level {
            w,
            h,
            kind: Kind::Stored {
                east,
                south,
                extra: extra_diag,
                inv_diag,
            },
        }
    }

    /// The normal equations of a masked weighted problem (see [`Kind::Problem`]); stores nothing.
    pub fn problem(
        w: usize,
        h: usize,
        mask: &'a [bool],
        weights: Option<&'a [f32]>,
        min_edge: f32,
        lambda: f32,
    ) -> Level<'a> {
        Level {
            w,
            h,
            kind: Kind::Problem {
                mask,
                weights,
                min_edge,
                lambda,
            },
        }
    }

    /// The fill of the holes `mask ∧ weight < below` (see [`Kind::Fill`]); stores the pins only.
    pub fn fill(
        w: usize,
        h: usize,
        mask: &'a [bool],
        weights: &'a [f32],
        below: f32,
        mut pins: Vec<usize>,
    ) -> Level<'a> {
        pins.sort_unstable();
        Level {
            w,
            h,
            kind: Kind::Fill {
                mask,
                weights,
                below,
                pins,
            },
        }
    }

    pub fn n(&self) -> usize {
        self.w * self.h
    }

    /// The same operator with its rows stored (bit for bit what [`Level::rows`] computes).
    pub fn stored(&self) -> Level<'static> {
        let (w, h) = (self.w, self.h);
        let n = w * h;
        let (mut east, mut south) = (par_zeros::<f32>(n), par_zeros::<f32>(n));
        let (mut extra, mut inv_diag) = (par_zeros::<f32>(n), par_zeros::<f32>(n));
        east.par_chunks_mut(w)
            .zip(south.par_chunks_mut(w))
            .zip(extra.par_chunks_mut(w).zip(inv_diag.par_chunks_mut(w)))
            .enumerate()
            .for_each_init(
                || Scratch::new(w),
                |sc, (r, ((e, s), (ex, inv)))| {
                    let rows = self.rows(r, sc);
                    e.copy_from_slice(rows.e);
                    s.copy_from_slice(rows.s);
                    ex.copy_from_slice(rows.ex);
                    inv.copy_from_slice(rows.inv);
                },
            );
        if extra.par_iter().all(|&x| x == 0.0) {
            extra = Vec::new();
        }
        Level {
            w,
            h,
            kind: Kind::Stored {
                east,
                south,
                extra,
                inv_diag,
            },
        }
    }

    /// The operator's rows at row `r` (slices of the storage, or computed into `sc`).
    #[inline]
    pub fn rows<'s>(&'s self, r: usize, sc: &'s mut Scratch) -> Rows<'s> {
        let w = self.w;
        let lo = r * w;
        if sc.row == r && !matches!(self.kind, Kind::Stored { .. }) {
            return Rows {
                e: &sc.e[..w],
                s: &sc.s[..w],
                su: &sc.su[..w],
                ex: &sc.ex[..w],
                inv: &sc.inv[..w],
            };
        }
        if !matches!(self.kind, Kind::Stored { .. }) {
            sc.row = r;
        }
        match &self.kind {
            Kind::Stored {
                east,
                south,
                extra,
                inv_diag,
            } => {
                let sc: &'s Scratch = sc;
                Rows {
                    e: &east[lo..lo + w],
                    s: &south[lo..lo + w],
                    su: if r > 0 {
                        &south[lo - w..lo]
                    } else {
                        &sc.zeros[..w]
                    },
                    ex: if extra.is_empty() {
                        &sc.zeros[..w]
                    } else {
                        &extra[lo..lo + w]
                    },
                    inv: &inv_diag[lo..lo + w],
                }
            }
            Kind::Problem {
                mask,
                weights,
                min_edge,
                lambda,
            } => self.problem_rows(r, mask, *weights, *min_edge, *lambda, sc),
            Kind::Fill {
                mask,
                weights,
                below,
                pins,
            } => self.fill_rows(r, mask, weights, *below, pins, sc),
            Kind::Computed { op } => self.computed_rows(r, *op, sc),
        }
    }

    /// An operator computed row by row by `op` (see [`Kind::Computed`]).
    pub fn computed(w: usize, h: usize, op: &'a dyn RowOperator) -> Level<'a> {
        Level {
            w,
            h,
            kind: Kind::Computed { op },
        }
    }

    /// The rows of a [`Kind::Computed`] level at row `r`, computed into `sc` by `op`, and `1 / d`.
    #[inline]
    fn computed_rows<'s>(&self, r: usize, op: &dyn RowOperator, sc: &'s mut Scratch) -> Rows<'s> {
        let w = self.w;
        let (e, s, su, ex, inv) = (
            &mut sc.e[..w],
            &mut sc.s[..w],
            &mut sc.su[..w],
            &mut sc.ex[..w],
            &mut sc.inv[..w],
        );
        let active = &mut sc.active[..w];
        let work = &mut sc.work;
        op.row(
            r,
            RowParts {
                e: &mut *e,
                s: &mut *s,
                su: &mut *su,
                ex: &mut *ex,
                active: &mut *active,
                work,
            },
        );
        e[w - 1] = 0.0;
        inverse_diagonal(e, s, su, ex, active, inv);
        Rows { e, s, su, ex, inv }
    }

    /// The rows of a [`Kind::Problem`] level at row `r`, computed into `sc`: the edges of row
    /// `r` (east), to row `r + 1` (south) and from row `r − 1` (su), in vectorisable passes
    /// over the row, the extra diagonal `lambda` on the mask, and `1 / d`.
    #[inline]
    fn problem_rows<'s>(
        &self,
        r: usize,
        mask: &[bool],
        weights: Option<&[f32]>,
        min_edge: f32,
        lambda: f32,
        sc: &'s mut Scratch,
    ) -> Rows<'s> {
        let (w, h) = (self.w, self.h);
        let lo = r * w;
        let rows = MaskRows {
            lo,
            m: &mask[lo..lo + w],
            below: (r + 1 < h).then(|| &mask[lo + w..lo + 2 * w]),
            above: (r > 0).then(|| &mask[lo - w..lo]),
        };
        let (e, s, su, ex, inv) = (
            &mut sc.e[..w],
            &mut sc.s[..w],
            &mut sc.su[..w],
            &mut sc.ex[..w],
            &mut sc.inv[..w],
        );
        let mut edges = EdgeRows { e, s, su };
        match weights {
            None => rows.unit_edges(min_edge, &mut edges),
            Some(ws) => rows.weighted_edges(ws, min_edge, &mut edges),
        }
        let EdgeRows { e, s, su } = edges;
        e[w - 1] = 0.0;
        for (v, &mv) in ex.iter_mut().zip(rows.m) {
            *v = if mv { lambda } else { 0.0 };
        }
        inverse_diagonal(e, s, su, ex, rows.m, inv);
        Rows { e, s, su, ex, inv }
    }

    /// The rows of a [`Kind::Fill`] level at row `r`, computed into `sc`: unit edges between
    /// holes, the extra diagonal of a hole its count of reliable neighbours (plus 1 at the
    /// `pins`), and `1 / d` on the holes.
    #[inline]
    fn fill_rows<'s>(
        &self,
        r: usize,
        mask: &[bool],
        weights: &[f32],
        below: f32,
        pins: &[usize],
        sc: &'s mut Scratch,
    ) -> Rows<'s> {
        let (w, h) = (self.w, self.h);
        let lo = r * w;
        let hole = |i: usize| mask[i] && weights[i] < below;
        let reliable = |i: usize| mask[i] && weights[i] >= below;
        let (e, s, su, ex, inv) = (
            &mut sc.e[..w],
            &mut sc.s[..w],
            &mut sc.su[..w],
            &mut sc.ex[..w],
            &mut sc.inv[..w],
        );
        let flag = |b: bool| if b { 1f32 } else { 0.0 };
        for c in 0..w {
            let i = lo + c;
            if !hole(i) {
                e[c] = 0.0;
                s[c] = 0.0;
                su[c] = 0.0;
                ex[c] = 0.0;
                continue;
            }
            e[c] = flag(c + 1 < w && hole(i + 1));
            s[c] = flag(r + 1 < h && hole(i + w));
            su[c] = flag(r > 0 && hole(i - w));
            // Reliable neighbours, counted in the order left, right, up, down.
            let mut x = 0f32;
            for (ok, j) in [
                (c > 0, i.wrapping_sub(1)),
                (c + 1 < w, i + 1),
                (r > 0, i.wrapping_sub(w)),
                (r + 1 < h, i + w),
            ] {
                if ok && reliable(j) {
                    x += 1.0;
                }
            }
            ex[c] = x;
        }
        let from = pins.partition_point(|&i| i < lo);
        for &i in pins[from..].iter().take_while(|&&i| i < lo + w) {
            ex[i - lo] = 1.0;
        }
        let active = &mut sc.active[..w];
        for (c, a) in active.iter_mut().enumerate() {
            *a = hole(lo + c);
        }
        inverse_diagonal(e, s, su, ex, active, inv);
        Rows { e, s, su, ex, inv }
    }

    /// Rows `r − 1`, `r + 1` of `x` (zeros beyond the grid).
    #[inline]
    fn x_rows<'x, T>(&self, x: &'x [T], r: usize, zeros: &'x [T]) -> (&'x [T], &'x [T]) {
        let w = self.w;
        let up = if r > 0 {
            &x[(r - 1) * w..r * w]
        } else {
            &zeros[..w]
        };
        let down = if r + 1 < self.h {
            &x[(r + 1) * w..(r + 2) * w]
        } else {
            &zeros[..w]
        };
        (up, down)
    }

    /// Row `r` of `A x` in the difference form `e_c x_c + Σ_j w_cj (x_c − x_j)`, which is
    /// exactly 0 on a constant `x` whatever the rounding of the weights (so a problem without
    /// prior stays exactly singular, with constants as its null space). Arithmetic in `T`.
    #[inline]
    fn operator_row<X, T>(&self, op: &Rows, x: &[X], r: usize, zeros_x: &[X], out: &mut [T])
    where
        X: Copy + Into<T>,
        T: Copy
            + From<f32>
            + std::ops::Add<Output = T>
            + std::ops::Sub<Output = T>
            + std::ops::Mul<Output = T>,
    {
        let w = self.w;
        let (e, s, su, ex) = (op.e, op.s, op.su, op.ex);
        let (up, down) = self.x_rows(x, r, zeros_x);
        let mid = &x[r * w..(r + 1) * w];
        let out = &mut out[..w];
        let f = T::from;
        for (((o, (&exv, &m)), (&sv, &dn)), (&suv, &u)) in out
            .iter_mut()
            .zip(ex.iter().zip(mid))
            .zip(s.iter().zip(down))
            .zip(su.iter().zip(up))
        {
            let m: T = m.into();
            *o = f(exv) * m + f(sv) * (m - dn.into()) + f(suv) * (m - u.into());
        }
        if w > 1 {
            for ((o, &ev), (&m, &right)) in out[..w - 1]
                .iter_mut()
                .zip(&e[..w - 1])
                .zip(mid[..w - 1].iter().zip(&mid[1..]))
            {
                *o = *o + f(ev) * (m.into() - right.into());
            }
            for ((o, &ev), (&m, &left)) in out[1..]
                .iter_mut()
                .zip(&e[..w - 1])
                .zip(mid[1..].iter().zip(&mid[..w - 1]))
            {
                *o = *o + f(ev) * (m.into() - left.into());
            }
        }
    }

    /// `out = A x` (f32 input and output, f64 arithmetic per cell: A x of a smooth x cancels
    /// heavily, and CG needs it accurately).
    /// Returns `xᵀ A x` and `Σ_i (A x)_i` (of the stored f32 values).
    pub fn apply32(&self, x: &[f32], out: &mut [f32]) -> (f64, f64) {
        let w = self.w;
        let zeros = vec![0f32; w];
        out.par_chunks_mut(w)
            .enumerate()
            .map_init(
                || (Scratch::new(w), vec![0f64; w]),
                |(sc, acc), (r, o)| {
                    let op = self.rows(r, sc);
                    self.operator_row::<f32, f64>(&op, x, r, &zeros, acc);
                    let mut sum = 0f64;
                    for (ov, &a) in o.iter_mut().zip(acc.iter()) {
                        *ov = a as f32;
                        sum += *ov as f64;
                    }
                    (dot_f32_f64(&x[r * w..(r + 1) * w], &acc[..w]), sum)
                },
            )
            .collect::<Vec<_>>()
            .into_iter()
            .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1))
    }

    /// `out = b − A x` on the active cells (0 on the others), f32 storage and f64 arithmetic,
    /// with row `r` of `b` given by `rhs(r, operator rows, out_row)` in f64 and `x = 0` when
    /// `x` is `None`. Returns `‖b‖²` (over every cell).
    pub fn residual_from(
        &self,
        rhs: impl Fn(usize, &Rows, &mut [f64]) + Sync,
        x: Option<&[f32]>,
        out: &mut [f32],
    ) -> f64 {
        let w = self.w;
        let zeros = vec![0f32; w];
        out.par_chunks_mut(w)
            .enumerate()
            .map_init(
                || (Scratch::new(w), vec![0f64; w], vec![0f64; w]),
                |(sc, b, ax), (r, o)| {
                    let op = self.rows(r, sc);
                    rhs(r, &op, b);
                    let bb: f64 = b.iter().map(|v| v * v).sum();
                    match x {
                        Some(x) => self.operator_row::<f32, f64>(&op, x, r, &zeros, ax),
                        None => ax.fill(0.0),
                    }
                    for (((ov, &bv), &av), &inv) in o.iter_mut().zip(&*b).zip(&*ax).zip(op.inv) {
                        *ov = if inv > 0.0 { (bv - av) as f32 } else { 0.0 };
                    }
                    bb
                },
            )
            .sum()
    }

    /// `r = b − A x` with f64 `x` and `b` (0 on inactive cells).
    #[cfg(test)]
    pub fn residual64(&self, b: &[f64], x: &[f64], res: &mut [f64]) {
        let w = self.w;
        let zeros64 = vec![0f64; w];
        let mut sc = Scratch::new(w);
        for (r, o) in res.chunks_mut(w).enumerate() {
            let op = self.rows(r, &mut sc);
            self.operator_row::<f64, f64>(&op, x, r, &zeros64, o);
            let lo = r * w;
            for ((ov, &bv), &inv) in o.iter_mut().zip(&b[lo..lo + w]).zip(op.inv) {
                *ov = if inv > 0.0 { bv - *ov } else { 0.0 };
            }
        }
    }

    /// `out[c] = Σ_j w_cj x_j` over the 4-neighbours of the cells of row `r` (f32), in one
    /// vectorisable pass.
    #[inline]
    fn neighbour_sum(&self, op: &Rows, x: &[f32], r: usize, zeros: &[f32], out: &mut [f32]) {
        let w = self.w;
        let (e, s, su) = (op.e, op.s, op.su);
        let (up, down) = self.x_rows(x, r, zeros);
        let mid = &x[r * w..(r + 1) * w];
        let out = &mut out[..w];
        let vertical = |c: usize| s[c] * down[c] + su[c] * up[c];
        if w == 1 {
            out[0] = vertical(0);
            return;
        }
        out[0] = vertical(0) + e[0] * mid[1];
        out[w - 1] = vertical(w - 1) + e[w - 2] * mid[w - 2];
        let n = w - 2;
        let o = &mut out[1..w - 1];
        let (sc, dn, suc, u) = (&s[1..w - 1], &down[1..w - 1], &su[1..w - 1], &up[1..w - 1]);
        let (ec, el, ml, mr) = (&e[1..w - 1], &e[..n], &mid[..n], &mid[2..]);
        for k in 0..n {
            o[k] = sc[k] * dn[k] + suc[k] * u[k] + ec[k] * mr[k] + el[k] * ml[k];
        }
    }

    /// `coarse = Pᵀ (b − A x)`: the residual summed over 2×2 blocks, without storing it.
    fn restrict_residual(&self, b: &[f32], x: &[f32], zeros: &[f32], coarse: &mut [f32]) {
        let (w, h) = (self.w, self.h);
        let cw = w.div_ceil(2);
        coarse.par_chunks_mut(cw).enumerate().for_each_init(
            || (Scratch::new(w), vec![0f32; w]),
            |(sc, tmp), (cr, row)| {
                row.fill(0.0);
                for r in (2 * cr)..(2 * cr + 2).min(h) {
                    let op = self.rows(r, sc);
                    self.operator_row::<f32, f32>(&op, x, r, zeros, tmp);
                    for (ov, &bv) in tmp[..w].iter_mut().zip(&b[r * w..(r + 1) * w]) {
                        *ov = bv - *ov;
                    }
                    for (o, pair) in row.iter_mut().zip(tmp[..w].chunks(2)) {
                        *o += pair.iter().sum::<f32>();
                    }
                }
            },
        );
    }

    /// Gauss–Seidel update of the cells of row `r` with `(r + c) % 2 == colour`, in place in
    /// `x` (`tmp`: a scratch row). The new values are computed for the whole row in one
    /// vectorisable pass (cells of one colour depend only on cells of the other), then stored
    /// into the colour's cells: with `exclusive` (no other thread reads the row meanwhile) by a
    /// vectorisable select over the whole row, which rewrites the other colour's cells with their
    /// own values; otherwise cell by cell. With `from_zero`, `x` is taken as 0: the colour's cells
    /// get `b / d` and the other cells 0, whatever `x` held.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn gs_row(
        &self,
        b: &[f32],
        x: &mut [f32],
        r: usize,
        colour: usize,
        from_zero: bool,
        exclusive: bool,
        zeros: &[f32],
        sc: &mut Scratch,
        tmp: &mut [f32],
    ) {
        let w = self.w;
        let lo = r * w;
        let brow = &b[lo..lo + w];
        let op = self.rows(r, sc);
        let inv = op.inv;
        let first = (r + colour) % 2;
        if from_zero {
            let mid = &mut x[lo..lo + w];
            for (c, ((m, &bv), &iv)) in mid.iter_mut().zip(brow).zip(inv).enumerate() {
                *m = if c % 2 == first { bv * iv } else { 0.0 };
            }
            return;
        }
        let tmp = &mut tmp[..w];
        self.neighbour_sum(&op, x, r, zeros, tmp);
        for ((t, &bv), &iv) in tmp.iter_mut().zip(brow).zip(inv) {
            *t = (*t + bv) * iv;
        }
        let mid = &mut x[lo..lo + w];
        if exclusive {
            for (c, (m, &t)) in mid.iter_mut().zip(tmp.iter()).enumerate() {
                *m = if c % 2 == first { t } else { *m };
            }
        } else {
            for c in (first..w).step_by(2) {
                mid[c] = tmp[c];
            }
        }
    }

    /// One Gauss–Seidel sweep: every cell of colour `first` (`(r + c) % 2 == first`), then every
    /// cell of the other colour; with `from_zero` the sweep starts from `x = 0` (whatever `x`
    /// holds on entry). The two half-sweeps are pipelined row by row — row `r`'s second colour is
    /// updated right after row `r + 1`'s first — so the operator is read once per sweep; the
    /// result is exactly that of the two half-sweeps in turn. Rows are split into blocks over
    /// threads; the second colour of a block's rows that touch another block is updated in a
    /// second parallel pass, once every first-colour cell is final.
    fn sweep(&self, b: &[f32], x: &mut [f32], first: usize, from_zero: bool, zeros: &[f32]) {
        let (w, h) = (self.w, self.h);
        assert_eq!(x.len(), w * h);
        assert_eq!(b.len(), w * h);
        let second = 1 - first;
        let blocks = h.div_ceil(ROWS_PER_TASK);
        let bounds = move |t: usize| (t * ROWS_PER_TASK, ((t + 1) * ROWS_PER_TASK).min(h));
        // Rows whose second colour waits for the second pass: a block's first row (unless it is
        // the grid's first) and its last row (unless it is the grid's last).
        let deferred =
            move |r: usize, r0: usize, r1: usize| (r == r0 && r0 > 0) || (r + 1 == r1 && r1 < h);
        let ptr = SharedMut(x.as_mut_ptr());
        // SAFETY (both passes): `ptr` covers `w * h` initialised f32 (asserted above) and
        // outlives this call. Pass 1: a block writes only its own rows; it reads another block's
        // cells only when updating its first colour next to a block boundary, and those are
        // second-colour cells of the neighbouring block's deferred boundary row, which pass 1
        // never writes. (From zero, the first-colour update reads nothing.) Pass 2 writes only
        // second-colour cells of deferred rows (distinct rows per block) and reads only
        // first-colour cells, which pass 2 never writes.
        // Two scratches, one per row parity: row r − 1's operator, computed for its first
        // colour, is still there for its second.
        (0..blocks).into_par_iter().for_each_init(
            || ([Scratch::new(w), Scratch::new(w)], vec![0f32; w]),
            |(sc, tmp), t| {
                let (r0, r1) = bounds(t);
                let xs = unsafe { std::slice::from_raw_parts_mut(ptr.get(), w * h) };
                for r in r0..r1 {
                    // A block's first and last rows are read by the neighbouring blocks.
                    let shared = (r == r0 && r0 > 0) || (r + 1 == r1 && r1 < h);
                    let s = &mut sc[r % 2];
                    self.gs_row(b, xs, r, first, from_zero, !shared, zeros, s, tmp);
                    if r > r0 && !deferred(r - 1, r0, r1) {
                        let s = &mut sc[(r - 1) % 2];
                        self.gs_row(b, xs, r - 1, second, false, true, zeros, s, tmp);
                    }
                }
                if !deferred(r1 - 1, r0, r1) {
                    let s = &mut sc[(r1 - 1) % 2];
                    self.gs_row(b, xs, r1 - 1, second, false, true, zeros, s, tmp);
                }
            },
        );
        if blocks > 1 {
            (0..blocks).into_par_iter().for_each_init(
                || (Scratch::new(w), vec![0f32; w]),
                |(sc, tmp), t| {
                    let (r0, r1) = bounds(t);
                    let xs = unsafe { std::slice::from_raw_parts_mut(ptr.get(), w * h) };
                    if deferred(r0, r0, r1) {
                        self.gs_row(b, xs, r0, second, false, false, zeros, sc, tmp);
                    }
                    if r1 - 1 != r0 && deferred(r1 - 1, r0, r1) {
                        self.gs_row(b, xs, r1 - 1, second, false, false, zeros, sc, tmp);
                    }
                },
            );
        }
    }

    /// The next coarser level by 2×2 aggregation (see the module notes); always stored.
    fn coarsen(&self) -> Level<'static> {
        let (w, h) = (self.w, self.h);
        let (cw, ch) = (w.div_ceil(2), h.div_ceil(2));
        let mut east: Vec<f32> = par_zeros(cw * ch);
        let mut south: Vec<f32> = par_zeros(cw * ch);
        let mut extra: Vec<f32> = par_zeros(cw * ch);
        let mut active = vec![false; cw * ch];
        east.par_chunks_mut(cw)
            .zip(south.par_chunks_mut(cw))
            .zip(extra.par_chunks_mut(cw))
            .zip(active.par_chunks_mut(cw))
            .enumerate()
            .for_each_init(
                || Scratch::new(w),
                |sc, (cr, (((e_row, s_row), x_row), a_row))| {
                    for dr in 0..2 {
                        let r = 2 * cr + dr;
                        if r >= h {
                            continue;
                        }
                        let op = self.rows(r, sc);
                        for cc in 0..cw {
                            for dc in 0..2 {
                                let c = 2 * cc + dc;
                                if c >= w || op.inv[c] <= 0.0 {
                                    continue;
                                }
                                a_row[cc] = true;
                                x_row[cc] += op.ex[c];
                                if dc == 1 {
                                    e_row[cc] += op.e[c];
                                }
                                if dr == 1 {
                                    s_row[cc] += op.s[c];
                                }
                            }
                        }
                    }
                    for v in e_row.iter_mut().chain(s_row.iter_mut()) {
                        *v *= 0.5;
                    }
                },
            );
        Level::from_parts(cw, ch, east, south, |i| extra[i], &active)
    }

    /// `fine += P coarse` on active cells.
    fn prolong_add(&self, coarse: &[f32], fine: &mut [f32]) {
        let w = self.w;
        let cw = w.div_ceil(2);
        fine.par_chunks_mut(w).enumerate().for_each_init(
            || Scratch::new(w),
            |sc, (r, row)| {
                let crow = &coarse[(r / 2) * cw..(r / 2 + 1) * cw];
                let active = self.rows(r, sc).inv;
                for c in 0..w {
                    if active[c] > 0.0 {
                        row[c] += crow[c / 2];
                    }
                }
            },
        );
    }
}

/// Dense Cholesky factor of the coarsest level's active cells.
#[derive(Clone, Debug)]
struct CoarseSolver {
    cells: Vec<usize>,
    /// Lower-triangular factor, row-major `m × m`.
    factor: Vec<f64>,
}

impl CoarseSolver {
    fn new(level: &Level) -> CoarseSolver {
        let (w, h) = (level.w, level.h);
        let mut sc = Scratch::new(w);
        let cells: Vec<usize> = (0..h)
            .flat_map(|r| {
                let inv = level.rows(r, &mut sc).inv.to_vec();
                (0..w)
                    .filter(move |&c| inv[c] > 0.0)
                    .map(move |c| r * w + c)
            })
            .collect();
        let m = cells.len();
        let mut pos = vec![usize::MAX; level.n()];
        for (k, &i) in cells.iter().enumerate() {
            pos[i] = k;
        }
        let mut a = vec![0f64; m * m];
        for (k, &i) in cells.iter().enumerate() {
            let (r, c) = (i / w, i % w);
            let op = level.rows(r, &mut sc);
            let mut edges = op.e[c] + op.s[c];
            if c > 0 {
                edges += op.e[c - 1];
            }
            if r > 0 {
                edges += op.su[c];
            }
            a[k * m + k] = op.ex[c] as f64 + edges as f64;
            if c + 1 < w && pos[i + 1] != usize::MAX {
                let j = pos[i + 1];
                a[k * m + j] -= op.e[c] as f64;
                a[j * m + k] -= op.e[c] as f64;
            }
            if r + 1 < h && pos[i + w] != usize::MAX {
                let j = pos[i + w];
                a[k * m + j] -= op.s[c] as f64;
                a[j * m + k] -= op.s[c] as f64;
            }
        }
        // A component of the coarsest graph whose rows sum to ~0 (no prior, pin or Dirichlet
        // anchor reaches it) is singular; its first cell gets an extra diagonal equal to its
        // own, which keeps the V-cycle symmetric positive definite (the fine operator may stay
        // semidefinite: CG then converges on a consistent right-hand side).
        let mut component = vec![usize::MAX; m];
        for start in 0..m {
            if component[start] != usize::MAX {
                continue;
            }
            let mut stack = vec![start];
            component[start] = start;
            let (mut row_sum, mut diag_sum) = (0f64, 0f64);
            while let Some(k) = stack.pop() {
                diag_sum += a[k * m + k];
                row_sum += (0..m).map(|j| a[k * m + j]).sum::<f64>();
                for j in 0..m {
                    if j != k && a[k * m + j] != 0.0 && component[j] == usize::MAX {
                        component[j] = start;
                        stack.push(j);
                    }
                }
            }
            if row_sum <= 1e-6 * diag_sum {
                a[start * m + start] *= 2.0;
            }
        }
        // A non-positive pivot cannot happen once every component is anchored, but f32
        // round-off on huge grids could bring one near zero: it is raised to a tiny positive one.
        cholesky::factor(&mut a, m, SmallPivot::Raise);
        CoarseSolver { cells, factor: a }
    }

    fn solve(&self, b: &[f32], x: &mut [f32]) {
        let m = self.cells.len();
        let l = &self.factor;
        let mut y: Vec<f64> = self.cells.iter().map(|&i| b[i] as f64).collect();
        cholesky::solve(l, m, &mut y);
        x.fill(0.0);
        for (k, &i) in self.cells.iter().enumerate() {
            x[i] = y[k] as f32;
        }
    }
}

/// Work vectors of one level (empty on the finest level, whose right-hand side and iterate
/// are the caller's).
#[derive(Clone, Debug, Default)]
struct Work {
    b: Vec<f32>,
    x: Vec<f32>,
}

/// The multigrid hierarchy: the levels, the coarsest solver and the work vectors.
#[derive(Clone, Debug)]
pub(crate) struct Hierarchy<'a> {
    levels: Vec<Level<'a>>,
    coarse: CoarseSolver,
    work: Vec<Work>,
    /// A row of zeros as long as the widest level.
    zeros: Vec<f32>,
    /// Gauss–Seidel sweeps (red + black) before and after the coarse correction.
    pub sweeps: usize,
    /// [`pcg`] also stops once a step moves no cell by more than the f32 resolution of the
    /// iterate (`f32::EPSILON · max |x|`): the stored surface can no longer change.
    pub stop_at_precision: bool,
}

impl<'a> Hierarchy<'a> {
    /// Builds all levels from the finest one.
    pub fn new(fine: Level<'a>) -> Hierarchy<'a> {
        let fine = if fine.n() <= STORE_FINE_UP_TO && !matches!(fine.kind, Kind::Stored { .. }) {
            fine.stored()
        } else {
            fine
        };
        let mut levels = vec![fine];
        loop {
            let last = &levels[levels.len() - 1];
            if last.w <= COARSEST_SIDE && last.h <= COARSEST_SIDE {
                break;
            }
            let next = last.coarsen();
            levels.push(next);
        }
        let coarse = CoarseSolver::new(&levels[levels.len() - 1]);
        let work = levels
            .iter()
            .enumerate()
            .map(|(l, level)| {
                let n = if l == 0 { 0 } else { level.n() };
                Work {
                    b: par_zeros(n),
                    x: par_zeros(n),
                }
            })
            .collect();
        let zeros = vec![0f32; levels[0].w];
        Hierarchy {
            levels,
            coarse,
            work,
            zeros,
            sweeps: 1,
            stop_at_precision: false,
        }
    }

    /// The finest level.
    pub fn fine(&self) -> &Level<'a> {
        &self.levels[0]
    }

    /// Number of levels.
    pub fn depth(&self) -> usize {
        self.levels.len()
    }

    /// `x ≈ A⁻¹ b` by one V-cycle from `x = 0`.
    pub fn vcycle(&mut self, b: &[f32], x: &mut [f32]) {
        self.cycle_at(0, b, x);
    }

    fn cycle_at(&mut self, l: usize, b: &[f32], x: &mut [f32]) {
        if l + 1 == self.levels.len() {
            self.coarse.solve(b, x);
            return;
        }
        let level = &self.levels[l];
        for k in 0..self.sweeps {
            level.sweep(b, x, 0, k == 0, &self.zeros);
        }
        let mut next = std::mem::take(&mut self.work[l + 1]);
        level.restrict_residual(b, x, &self.zeros, &mut next.b);
        self.cycle_at(l + 1, &next.b, &mut next.x);
        let level = &self.levels[l];
        level.prolong_add(&next.x, x);
        self.work[l + 1] = next;
        for _ in 0..self.sweeps {
            level.sweep(b, x, 1, false, &self.zeros);
        }
    }
}

/// Result of [`pcg`].
#[derive(Clone, Debug)]
pub(crate) struct Solve {
    pub iterations: usize,
    /// ‖b − A x‖ / ‖b‖ at the end (the recurrence's residual; 0 when `b = 0`).
    pub relative_residual: f64,
    /// Stopped because the last step was below the iterate's f32 resolution (see
    /// [`Hierarchy::stop_at_precision`]), not at the tolerance.
    pub at_precision: bool,
}

/// Independent accumulators of the f64 sums below (they let the sums vectorise).
const LANES: usize = 8;

/// `Σ a_k b_k` in f64 over f32 `a` and f64 `b` (one thread).
fn dot_f32_f64(a: &[f32], b: &[f64]) -> f64 {
    let (ca, cb) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(&u, &v)| u as f64 * v)
        .sum();
    let mut acc = [0f64; LANES];
    for (x, y) in ca.zip(cb) {
        for k in 0..LANES {
            acc[k] += x[k] as f64 * y[k];
        }
    }
    acc.iter().sum::<f64>() + tail
}

/// `(Σ a_k b_k, Σ a_k, Σ b_k)` in f64 over f32 `a` and `b` (one thread).
fn dot_and_sums(a: &[f32], b: &[f32]) -> (f64, f64, f64) {
    let (ca, cb) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (mut dot, mut sa, mut sb) = (0f64, 0f64, 0f64);
    for (&u, &v) in ca.remainder().iter().zip(cb.remainder()) {
        dot += u as f64 * v as f64;
        sa += u as f64;
        sb += v as f64;
    }
    let mut acc = [[0f64; LANES]; 3];
    for (x, y) in ca.zip(cb) {
        for k in 0..LANES {
            acc[0][k] += x[k] as f64 * y[k] as f64;
            acc[1][k] += x[k] as f64;
            acc[2][k] += y[k] as f64;
        }
    }
    let total = |l: &[f64; LANES]| l.iter().sum::<f64>();
    (
        dot + total(&acc[0]),
        sa + total(&acc[1]),
        sb + total(&acc[2]),
    )
}

/// Elements per rayon task in the vector operations below.
const CHUNK: usize = 1 << 14;

/// `Σ a_k²` in f64 over threads.
pub(crate) fn norm2(a: &[f32]) -> f64 {
    a.par_chunks(CHUNK)
        .map(|x| dot_and_sums(x, x).0)
        .collect::<Vec<f64>>()
        .into_iter()
        .sum()
}

/// A vector of `n` zeros written by all threads (the first touch of fresh pages is a parallel
/// write, not a read of the shared zero page followed by copy-on-write faults).
pub(crate) fn par_zeros<T: Default + Copy + Send + Sync>(n: usize) -> Vec<T> {
    (0..n).into_par_iter().map(|_| T::default()).collect()
}

/// What [`cg_update`] adds back to `A p` at each cell.
enum Shift<'s> {
    /// The same value everywhere.
    Const(f64),
    /// One value per component (labels: `MAX` outside the mask, where the shift is 0).
    Small(&'s [u8], &'s [f64]),
    Large(&'s [u32], &'s [f64]),
}

/// One chunk of [`cg_update`], with the shift of the chunk's `k`-th cell from `shift(k)`.
#[inline(always)]
fn cg_update_chunk<const TRACK: bool>(
    xs: &mut [f32],
    rs: &mut [f32],
    aps: &[f32],
    ps: &[f32],
    alpha: f64,
    shift: impl Fn(usize) -> f64,
) -> Update {
    let mut acc = [0f64; LANES];
    let (mut p_max, mut x_max) = ([0f32; LANES], [0f32; LANES]);
    for (j, (((xc, rc), ac), pc)) in xs
        .chunks_mut(LANES)
        .zip(rs.chunks_mut(LANES))
        .zip(aps.chunks(LANES))
        .zip(ps.chunks(LANES))
        .enumerate()
    {
        for k in 0..xc.len() {
            xc[k] = (xc[k] as f64 + alpha * pc[k] as f64) as f32;
            if TRACK {
                p_max[k] = p_max[k].max(pc[k].abs());
                x_max[k] = x_max[k].max(xc[k].abs());
            }
            let rv = (rc[k] as f64 - alpha * (ac[k] as f64 - shift(j * LANES + k))) as f32;
            rc[k] = rv;
            acc[k] += rv as f64 * rv as f64;
        }
    }
    let most = |m: [f32; LANES]| m.iter().fold(0f32, |a, &v| a.max(v));
    Update {
        rr: acc.iter().sum::<f64>(),
        p_max: most(p_max),
        x_max: most(x_max),
    }
}

/// What [`cg_update`] measured: `‖r‖²` (of the stored values), `max |p|` and `max |x|` (new).
#[derive(Clone, Copy, Default)]
struct Update {
    rr: f64,
    p_max: f32,
    x_max: f32,
}

impl Update {
    fn join(self, o: Update) -> Update {
        Update {
            rr: self.rr + o.rr,
            p_max: self.p_max.max(o.p_max),
            x_max: self.x_max.max(o.x_max),
        }
    }
}

/// One CG update in a single pass: `x += α p`, `r −= α (A p − shift)` (f32 storage, f64
/// arithmetic). Returns `‖r‖²` (of the stored values), and with `track` `max |p|` and
/// `max |x|` (else 0).
fn cg_update(
    track: bool,
    x: &mut [f32],
    r: &mut [f32],
    ap: &[f32],
    p: &[f32],
    alpha: f64,
    shift: Shift,
) -> Update {
    x.par_chunks_mut(CHUNK)
        .zip(r.par_chunks_mut(CHUNK))
        .zip(ap.par_chunks(CHUNK))
        .zip(p.par_chunks(CHUNK))
        .enumerate()
        .map(|(t, (((xs, rs), aps), ps))| {
            let lo = t * CHUNK;
            let hi = lo + xs.len();
            // One monomorphised loop per (shift, track): no branch on either inside it.
            macro_rules! chunk {
                ($shift:expr) => {
                    if track {
                        cg_update_chunk::<true>(xs, rs, aps, ps, alpha, $shift)
                    } else {
                        cg_update_chunk::<false>(xs, rs, aps, ps, alpha, $shift)
                    }
                };
            }
            match shift {
                Shift::Const(v) => chunk!(|_| v),
                Shift::Small(labels, values) => {
                    let l = &labels[lo..hi];
                    chunk!(|k| {
                        if l[k] == u8::MAX {
                            0.0
                        } else {
                            values[l[k] as usize]
                        }
                    })
                }
                Shift::Large(labels, values) => {
                    let l = &labels[lo..hi];
                    chunk!(|k| {
                        if l[k] == u32::MAX {
                            0.0
                        } else {
                            values[l[k] as usize]
                        }
                    })
                }
            }
        })
        .collect::<Vec<Update>>()
        .into_iter()
        .fold(Update::default(), Update::join)
}

/// Conjugate gradients on the finest level's operator, preconditioned by one V-cycle, in place:
/// `x` holds the starting point (f32; inactive cells are never changed) and receives the
/// solution; `r` holds the starting residual `b − A x` (0 on inactive cells, see
/// [`Level::residual_from`]) and is used up; `b_norm` is `‖b‖`. Stops at
/// `‖r‖ ≤ tolerance · ‖b‖` or after `max_iterations`, or with the hierarchy's
/// `stop_at_precision` once `max |α p| ≤ f32::EPSILON · max |x|` (a step below the resolution
/// of the stored iterate: with the V-cycle's contraction the error left is smaller still);
/// `progress` gets one unit per iteration.
/// Besides `x` and `r` it holds two f32 vectors (the direction, and one shared by the
/// preconditioned residual and `A p`, whose uses never overlap).
///
/// `null_space`: when the operator is singular with one constant per component (no prior and no
/// anchor) and `b` sums to zero over each component, the components. Each `A p` then has its
/// per-component mean removed before it updates the residual, so that f32 round-off cannot
/// make the residual inconsistent (CG would stall and then diverge at tight tolerances); the
/// solution is defined up to those constants.
#[allow(clippy::too_many_arguments)]
pub(crate) fn pcg(
    hierarchy: &mut Hierarchy,
    r: &mut [f32],
    b_norm: f64,
    x: &mut [f32],
    null_space: Option<&Components>,
    tolerance: f64,
    max_iterations: usize,
    progress: &dyn Progress,
) -> Solve {
    let n = hierarchy.fine().n();
    assert_eq!(r.len(), n);
    assert_eq!(x.len(), n);
    if b_norm == 0.0 {
        return Solve {
            iterations: 0,
            relative_residual: 0.0,
            at_precision: false,
        };
    }
    let mut rel = norm2(r).sqrt() / b_norm;
    if rel <= tolerance {
        return Solve {
            iterations: 0,
            relative_residual: rel,
            at_precision: false,
        };
    }
    // `zap` holds the preconditioned residual z, then A p (the two uses never overlap).
    let mut zap: Vec<f32> = par_zeros(n);
    // `(rᵀ ẑ, m)` where ẑ = z − m·1 is z with its null-space part removed: on a labelled mask
    // the per-component means are subtracted from z here (m = 0); on the whole grid m is z's
    // mean, subtracted on the fly by the callers.
    // Also returns `Σ r` and, on a labelled mask, r's mean over each component (taken in the
    // pass that takes z's).
    let dot_rz = |r: &[f32], z: &mut [f32]| -> (f64, f64, f64, Vec<f64>) {
        let r_means = match null_space.filter(|c| !c.is_whole_grid()) {
            Some(c) => c.remove_means_and_measure(z, Some(r)),
            None => Vec::new(),
        };
        let (rz, z_sum, r_sum) = z
            .par_chunks(CHUNK)
            .zip(r.par_chunks(CHUNK))
            .map(|(a, b)| dot_and_sums(a, b))
            .collect::<Vec<_>>()
            .into_iter()
            .fold((0.0, 0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
        match null_space {
            Some(c) if c.is_whole_grid() => {
                let m = z_sum / n as f64;
                (rz - m * r_sum, m, r_sum, r_means)
            }
            _ => (rz, 0.0, r_sum, r_means),
        }
    };
    hierarchy.vcycle(r, &mut zap);
    let (mut rz, z_mean, mut r_sum, mut r_means) = dot_rz(r, &mut zap);
    let mut p: Vec<f32> = zap
        .par_iter()
        .map(|&v| (v as f64 - z_mean) as f32)
        .collect();
    let mut iterations = 0;
    let mut at_precision = false;
    let track = hierarchy.stop_at_precision;
    while iterations < max_iterations {
        iterations += 1;
        let (pap, ap_sum) = hierarchy.fine().apply32(&p, &mut zap);
        if pap.is_nan() || pap <= 0.0 {
            break;
        }
        let alpha = rz / pap;
        // x += α p and r −= α A p, both less their null-space parts, in one pass: the f32
        // rounding of the stored r leaves a small null-space part in it at each step, which CG
        // cannot reduce; it is removed at the next step (so it never accumulates).
        let update = match null_space {
            None => cg_update(track, x, r, &zap, &p, alpha, Shift::Const(0.0)),
            Some(c) if c.is_whole_grid() => {
                let shift = ap_sum / n as f64 - r_sum / n as f64 / alpha;
                cg_update(track, x, r, &zap, &p, alpha, Shift::Const(shift))
            }
            Some(c) => {
                let ap_means = c.means(&zap);
                let shift: Vec<f64> = ap_means
                    .iter()
                    .zip(&r_means)
                    .map(|(a, m)| a - m / alpha)
                    .collect();
                let by = match c.labels() {
                    LabelSlice::Small(l) => Shift::Small(l, &shift),
                    LabelSlice::Large(l) => Shift::Large(l, &shift),
                    LabelSlice::Whole => unreachable!("a labelled mask"),
                };
                cg_update(track, x, r, &zap, &p, alpha, by)
            }
        };
        progress.advance(1);
        rel = update.rr.sqrt() / b_norm;
        if rel <= tolerance {
            break;
        }
        let step = alpha.abs() * update.p_max as f64;
        if hierarchy.stop_at_precision && step <= f32::EPSILON as f64 * update.x_max as f64 {
            at_precision = true;
            break;
        }
        hierarchy.vcycle(r, &mut zap);
        let (rz_new, z_mean, new_r_sum, new_r_means) = dot_rz(r, &mut zap);
        (r_sum, r_means) = (new_r_sum, new_r_means);
        let beta = rz_new / rz;
        rz = rz_new;
        let z_mean = z_mean as f32;
        p.par_chunks_mut(CHUNK)
            .zip(zap.par_chunks(CHUNK))
            .for_each(|(ps, zs)| {
                for (pv, &zv) in ps.iter_mut().zip(zs) {
                    *pv = (zv - z_mean) + (beta as f32) * *pv;
                }
            });
    }
    Solve {
        iterations,
        relative_residual: rel,
        at_precision,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::progress::Silent;

    /// A masked grid with unit weights and one pinned cell (the first of the mask).
    fn laplacian(w: usize, h: usize, mask: &[bool]) -> Level<'static> {
        unit_laplacian(w, h, mask, true, |_| 1.0)
    }

    /// Unit (times `scale(i)`) weights between masked neighbours, optionally one pin.
    fn unit_laplacian(
        w: usize,
        h: usize,
        mask: &[bool],
        pin: bool,
        scale: impl Fn(usize) -> f32,
    ) -> Level<'static> {
        let mut east = vec![0f32; w * h];
        let mut south = vec![0f32; w * h];
        for r in 0..h {
            for c in 0..w {
                let i = r * w + c;
                if c + 1 < w && mask[i] && mask[i + 1] {
                    east[i] = scale(2 * i);
                }
                if r + 1 < h && mask[i] && mask[i + w] {
                    south[i] = scale(2 * i + 1);
                }
            }
        }
        let mut extra = vec![0f32; w * h];
        if pin {
            let first = mask.iter().position(|&m| m).unwrap();
            extra[first] = 1.0;
        }
        Level::from_parts(w, h, east, south, |i| extra[i], mask)
    }

    /// `A x` in f64 (as the negated residual of `b = 0`).
    fn product(level: &Level, x: &[f64]) -> Vec<f64> {
        let mut b = vec![0f64; x.len()];
        level.residual64(&vec![0f64; x.len()], x, &mut b);
        b.iter_mut().for_each(|v| *v = -*v);
        b
    }

    /// Solves `A x = b` from zero by [`pcg`]; returns x in f64 and the solve.
    fn solve(
        hier: &mut Hierarchy,
        b: &[f64],
        null_space: Option<&Components>,
        tolerance: f64,
    ) -> (Vec<f64>, Solve) {
        let mut r: Vec<f32> = b.iter().map(|&v| v as f32).collect();
        let b_norm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        let mut x = vec![0f32; b.len()];
        let s = pcg(
            hier, &mut r, b_norm, &mut x, null_space, tolerance, 100, &Silent,
        );
        (x.iter().map(|&v| v as f64).collect(), s)
    }

    /// A pseudo-random value in [0, 1) from an index.
    fn hash01(i: usize, salt: u64) -> f32 {
        let mut v = (i as u64 ^ salt).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        v ^= v >> 29;
        v = v.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        v ^= v >> 32;
        (v % 1_000_003) as f32 / 1_000_003.0
    }

    /// One Gauss–Seidel half-sweep over the cells of `colour`, cell by cell (the reference),
    /// from the stored weights.
    #[allow(clippy::too_many_arguments)]
    fn plain_half_sweep(
        w: usize,
        h: usize,
        east: &[f32],
        south: &[f32],
        extra: &[f32],
        active: &[bool],
        b: &[f32],
        x: &mut [f32],
        colour: usize,
    ) {
        for r in 0..h {
            for c in 0..w {
                let i = r * w + c;
                if (r + c) % 2 != colour || !active[i] {
                    continue;
                }
                let mut d = extra[i] as f64 + east[i] as f64 + south[i] as f64;
                let mut s = b[i] as f64;
                if c + 1 < w {
                    s += east[i] as f64 * x[i + 1] as f64;
                }
                if c > 0 {
                    s += east[i - 1] as f64 * x[i - 1] as f64;
                    d += east[i - 1] as f64;
                }
                if r + 1 < h {
                    s += south[i] as f64 * x[i + w] as f64;
                }
                if r > 0 {
                    s += south[i - w] as f64 * x[i - w] as f64;
                    d += south[i - w] as f64;
                }
                x[i] = (s / d) as f32;
            }
        }
    }

    #[test]
    fn pipelined_sweep_equals_two_plain_half_sweeps() {
        // Several row blocks (odd sizes, blocks of ROWS_PER_TASK rows), a single block, a column.
        for (w, h) in [(37, 101), (40, 5 * ROWS_PER_TASK + 1), (9, 7), (1, 45)] {
            let mask: Vec<bool> = (0..w * h).map(|i| hash01(i, 1) > 0.1).collect();
            let weight = |i: usize, salt: u64| 0.1 + hash01(i, salt);
            let mut east = vec![0f32; w * h];
            let mut south = vec![0f32; w * h];
            for r in 0..h {
                for c in 0..w {
                    let i = r * w + c;
                    if c + 1 < w && mask[i] && mask[i + 1] {
                        east[i] = weight(i, 2);
                    }
                    if r + 1 < h && mask[i] && mask[i + w] {
                        south[i] = weight(i, 3);
                    }
                }
            }
            let extra: Vec<f32> = (0..w * h)
                .map(|i| if mask[i] { 0.01 * hash01(i, 4) } else { 0.0 })
                .collect();
            let level = Level::from_parts(w, h, east.clone(), south.clone(), |i| extra[i], &mask);
            let b: Vec<f32> = (0..w * h)
                .map(|i| if mask[i] { hash01(i, 5) - 0.5 } else { 0.0 })
                .collect();
            let x0: Vec<f32> = (0..w * h)
                .map(|i| if mask[i] { hash01(i, 6) } else { 0.0 })
                .collect();
            let zeros = vec![0f32; w];
            for first in [0, 1] {
                for from_zero in [false, true] {
                    let mut expected = if from_zero {
                        vec![0f32; w * h]
                    } else {
                        x0.clone()
                    };
                    for colour in [first, 1 - first] {
                        plain_half_sweep(
                            w,
                            h,
                            &east,
                            &south,
                            &extra,
                            &mask,
                            &b,
                            &mut expected,
                            colour,
                        );
                    }
                    // From zero the sweep may not read x: start from garbage.
                    let mut got = if from_zero {
                        vec![7.0; w * h]
                    } else {
                        x0.clone()
                    };
                    level.sweep(&b, &mut got, first, from_zero, &zeros);
                    for i in 0..w * h {
                        let want = if mask[i] || !from_zero {
                            expected[i]
                        } else {
                            0.0
                        };
                        assert!(
                            (got[i] - want).abs() <= 1e-5 * (1.0 + want.abs()),
                            "{w}×{h}, first {first}, from zero {from_zero}, cell {i}: {} vs {want}",
                            got[i],
                        );
                    }
                }
            }
        }
    }

    /// The rows of `level` and of `reference` (stored) are bit-identical.
    fn assert_same_rows(level: &Level, reference: &Level, what: &str) {
        let (mut a, mut b) = (Scratch::new(level.w), Scratch::new(level.w));
        for r in 0..level.h {
            let (x, y) = (level.rows(r, &mut a), reference.rows(r, &mut b));
            for (name, u, v) in [
                ("east", x.e, y.e),
                ("south", x.s, y.s),
                ("south above", x.su, y.su),
                ("extra", x.ex, y.ex),
                ("1/d", x.inv, y.inv),
            ] {
                for c in 0..level.w {
                    assert_eq!(
                        u[c].to_bits(),
                        v[c].to_bits(),
                        "{what}: {name} at row {r}, column {c}: {} vs {}",
                        u[c],
                        v[c]
                    );
                }
            }
        }
    }

    #[test]
    fn computed_levels_equal_their_stored_form() {
        let (w, h) = (23, 17);
        let mask: Vec<bool> = (0..w * h).map(|i| hash01(i, 21) > 0.15).collect();
        // Weights in 0..1, some below the fill threshold 0.2 and below the edge floor 0.05.
        let weights: Vec<f32> = (0..w * h).map(|i| hash01(i, 22)).collect();
        for (ws, min_edge, lambda) in [
            (None, 1e-3, 0.0),
            (Some(&weights[..]), 0.05, 0.0),
            (Some(&weights[..]), 1e-3, 0.25),
        ] {
            let wt = |i: usize| ws.map_or(1.0, |v: &[f32]| v[i]);
            let edge = |a: usize, b: usize| wt(a).min(wt(b)).max(min_edge);
            let (mut east, mut south) = (vec![0f32; w * h], vec![0f32; w * h]);
            for r in 0..h {
                for c in 0..w {
                    let i = r * w + c;
                    if mask[i] && c + 1 < w && mask[i + 1] {
                        east[i] = edge(i, i + 1);
                    }
                    if mask[i] && r + 1 < h && mask[i + w] {
                        south[i] = edge(i, i + w);
                    }
                }
            }
            let stored = Level::from_parts(w, h, east, south, |_| lambda, &mask);
            let level = Level::problem(w, h, &mask, ws, min_edge, lambda);
            assert_same_rows(&level, &stored, &format!("problem λ {lambda}"));
            assert_same_rows(
                &level.stored(),
                &stored,
                &format!("problem λ {lambda}, stored"),
            );
        }
        // The fill's graph: holes are mask pixels with weight < 0.2; two pins.
        let below = 0.2;
        let hole: Vec<bool> = (0..w * h).map(|i| mask[i] && weights[i] < below).collect();
        let pins: Vec<usize> = hole
            .iter()
            .enumerate()
            .filter(|(_, &b)| b)
            .map(|(i, _)| i)
            .step_by(7)
            .take(2)
            .collect();
        let (mut east, mut south, mut extra) =
            (vec![0f32; w * h], vec![0f32; w * h], vec![0f32; w * h]);
        for r in 0..h {
            for c in 0..w {
                let i = r * w + c;
                if !hole[i] {
                    continue;
                }
                let nbrs = [
                    (c > 0).then(|| i - 1),
                    (c + 1 < w).then(|| i + 1),
                    (r > 0).then(|| i - w),
                    (r + 1 < h).then(|| i + w),
                ];
                for j in nbrs.into_iter().flatten() {
                    if mask[j] && !hole[j] {
                        extra[i] += 1.0;
                    }
                }
                if c + 1 < w && hole[i + 1] {
                    east[i] = 1.0;
                }
                if r + 1 < h && hole[i + w] {
                    south[i] = 1.0;
                }
            }
        }
        for &i in &pins {
            extra[i] = 1.0;
        }
        let stored = Level::from_parts(w, h, east, south, |i| extra[i], &hole);
        let level = Level::fill(
            w,
            h,
            &mask,
            &weights,
            below,
            pins.into_iter().rev().collect(),
        );
        assert_same_rows(&level, &stored, "fill");
        assert_same_rows(&level.stored(), &stored, "fill, stored");
    }

    #[test]
    fn pcg_solves_a_singular_system_up_to_a_constant_per_component() {
        // Two components, no pin and no prior: A is singular (one constant per component) and
        // b = A·truth is consistent. Tolerance 1e-10 is far below f32 precision of the V-cycle:
        // without the null-space projection CG stalls there and then diverges.
        let (w, h) = (64, 48);
        let mask: Vec<bool> = (0..w * h)
            .map(|i| {
                let (r, c) = ((i / w) as f64, (i % w) as f64);
                (r - 20.0).hypot(c - 20.0) < 16.0 || (r - 30.0).hypot(c - 50.0) < 10.0
            })
            .collect();
        // Weights that f32 cannot sum exactly: the operator must stay exactly singular anyway.
        let level = unit_laplacian(w, h, &mask, false, |k| {
            0.2 + hash01(k / 2, 11 + k as u64 % 2)
        });
        let truth: Vec<f64> = (0..w * h)
            .map(|i| {
                let (r, c) = ((i / w) as f64, (i % w) as f64);
                if mask[i] {
                    (0.1 * r).sin() * 5.0 + 0.02 * c * c + if c > 38.0 { 100.0 } else { 0.0 }
                } else {
                    0.0
                }
            })
            .collect();
        let b = product(&level, &truth);
        let mut hier = Hierarchy::new(level);
        let components = Components::of(w, h, &mask);
        let (x, s) = solve(&mut hier, &b, Some(&components), 1e-10);
        assert!(s.relative_residual <= 1e-10, "{}", s.relative_residual);
        assert!(s.iterations < 25, "{} iterations", s.iterations);
        // Compare after removing each component's mean (the components split at column 38).
        let side = |i: usize| (i % w) > 38;
        for part in [false, true] {
            let cells: Vec<usize> = (0..w * h).filter(|&i| mask[i] && side(i) == part).collect();
            let mean = |v: &[f64]| cells.iter().map(|&i| v[i]).sum::<f64>() / cells.len() as f64;
            let (mx, mt) = (mean(&x), mean(&truth));
            for &i in &cells {
                assert!((x[i] - mx - (truth[i] - mt)).abs() < 1e-4, "cell {i}");
            }
        }
    }

    #[test]
    fn pcg_matches_a_dense_solve_on_an_irregular_grid() {
        let (w, h) = (37, 29);
        let mask: Vec<bool> = (0..w * h)
            .map(|i| {
                let (r, c) = ((i / w) as f64, (i % w) as f64);
                ((r - 14.0).powi(2) + (c - 18.0).powi(2)).sqrt() < 13.5
                    && !(r > 12.0 && c > 20.0 && c < 23.0)
            })
            .collect();
        let level = laplacian(w, h, &mask);
        // A reference by many Gauss–Seidel sweeps in f64 against a known solution.
        let truth: Vec<f64> = (0..w * h)
            .map(|i| {
                if mask[i] {
                    ((i * 7919) % 101) as f64 / 10.0
                } else {
                    0.0
                }
            })
            .collect();
        let b = product(&level, &truth);
        let mut hier = Hierarchy::new(level);
        let (x, s) = solve(&mut hier, &b, None, 1e-10);
        assert!(s.relative_residual <= 1e-10, "{}", s.relative_residual);
        // The true residual of the f32 solution, recomputed in f64: at the level of the f32
        // rounding of x (|x| ≤ 10, half an ulp 5e-7 per cell), far below the start's 1.
        let mut r = vec![0f64; w * h];
        hier.fine().residual64(&b, &x, &mut r);
        let rn = r.iter().map(|v| v * v).sum::<f64>().sqrt();
        let bn = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(rn / bn < 1e-6, "true relative residual {}", rn / bn);
        for (i, (x, t)) in x.iter().zip(&truth).enumerate() {
            assert!((x - t).abs() < 1e-4, "{i}: {x} vs {t}");
        }
        assert!(s.iterations < 30, "{} iterations", s.iterations);
    }
}
