//! A weighted 5-point graph Laplacian on a (masked) pixel grid, plus a non-negative diagonal,
//! solved by conjugate gradients preconditioned with a multigrid V-cycle.
//!
//! Operator: `(A x)_i = d_i x_i − Σ_j w_ij x_j` over the 4-neighbours `j` of `i`, with
//! `d_i = Σ_j w_ij + e_i` (`e_i ≥ 0`: a prior, a Dirichlet anchor or a pin). Inactive cells
//! (outside the mask) have `d_i = 0` and are never touched.
//!
//! Multigrid: 2×2 aggregation (piecewise-constant prolongation `P`, restriction `Pᵀ`), coarse
//! operators by Galerkin `PᵀAP` with the Laplacian part scaled by ½ — which is what
//! rediscretising the Laplacian on the coarse grid gives for a constant weight (plain Galerkin
//! with piecewise-constant `P` is twice too stiff on smooth modes and loses grid independence).
//! Smoothing: red–black Gauss–Seidel, red then black before the coarse correction and black then
//! red after it, so that the V-cycle is a symmetric positive definite preconditioner. The coarsest
//! grid (at most 8×8) is solved exactly by a dense Cholesky factorisation.
//!
//! Storage: f32 for the operator and the V-cycle, f64 for the CG iterate and residual.

use crate::progress::Progress;
use rayon::prelude::*;

/// Rows handled by one rayon task (keeps task overhead negligible on small grids).
const ROWS_PER_TASK: usize = 16;
/// Largest side of the coarsest grid.
const COARSEST_SIDE: usize = 8;

/// One grid level of the operator.
#[derive(Clone, Debug)]
pub(crate) struct Level {
    pub w: usize,
    pub h: usize,
    /// Weight of the edge from cell `i` to `i + 1` (0 in the last column or when absent).
    pub east: Vec<f32>,
    /// Weight of the edge from cell `i` to `i + w` (0 in the last row or when absent).
    pub south: Vec<f32>,
    /// Diagonal `d_i`; 0 marks an inactive cell.
    pub diag: Vec<f32>,
    /// `1 / d_i` (0 for inactive cells).
    pub inv_diag: Vec<f32>,
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

impl Level {
    /// Builds a level from edge weights and the extra diagonal `extra` (active cells: `active`).
    pub fn from_parts(
        w: usize,
        h: usize,
        east: Vec<f32>,
        south: Vec<f32>,
        extra: &[f32],
        active: &[bool],
    ) -> Level {
        let mut diag = vec![0f32; w * h];
        diag.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
            for (c, d) in row.iter_mut().enumerate() {
                let i = r * w + c;
                if !active[i] {
                    continue;
                }
                let mut s = east[i] + south[i] + extra[i];
                if c > 0 {
                    s += east[i - 1];
                }
                if r > 0 {
                    s += south[i - w];
                }
                *d = s;
            }
        });
        let inv_diag = diag
            .par_iter()
            .map(|&d| if d > 0.0 { 1.0 / d } else { 0.0 })
            .collect();
        Level {
            w,
            h,
            east,
            south,
            diag,
            inv_diag,
        }
    }

    fn n(&self) -> usize {
        self.w * self.h
    }

    /// Sum of the weights of cell `i`'s edges.
    #[inline]
    fn edge_sum(&self, i: usize, r: usize, c: usize) -> f32 {
        let mut s = self.east[i] + self.south[i];
        if c > 0 {
            s += self.east[i - 1];
        }
        if r > 0 {
            s += self.south[i - self.w];
        }
        s
    }

    /// The operator's rows at row `r`: east and south weights, the south weights of the row
    /// above (zeros on the first row) and the diagonal.
    #[inline]
    fn op_rows<'a>(
        &'a self,
        r: usize,
        zeros: &'a [f32],
    ) -> (&'a [f32], &'a [f32], &'a [f32], &'a [f32]) {
        let w = self.w;
        let lo = r * w;
        let s_up = if r > 0 {
            &self.south[lo - w..lo]
        } else {
            &zeros[..w]
        };
        (
            &self.east[lo..lo + w],
            &self.south[lo..lo + w],
            s_up,
            &self.diag[lo..lo + w],
        )
    }

    /// Rows `r − 1`, `r + 1` of `x` (zeros beyond the grid).
    #[inline]
    fn x_rows<'a, T>(&self, x: &'a [T], r: usize, zeros: &'a [T]) -> (&'a [T], &'a [T]) {
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

    /// `out = A x` (f32 input and output, f64 arithmetic per cell: A x of a smooth x cancels
    /// heavily, and CG needs it accurately).
    /// Returns `xᵀ A x`.
    pub fn apply32(&self, x: &[f32], out: &mut [f32]) -> f64 {
        let w = self.w;
        let zeros = vec![0f32; w];
        out.par_chunks_mut(w)
            .enumerate()
            .map(|(r, o)| {
                let (e, s, su, d) = self.op_rows(r, &zeros);
                let (up, down) = self.x_rows(x, r, &zeros);
                let mid = &x[r * w..(r + 1) * w];
                let f = |v: f32| v as f64;
                let vert =
                    |c: usize| f(d[c]) * f(mid[c]) - f(s[c]) * f(down[c]) - f(su[c]) * f(up[c]);
                if w == 1 {
                    o[0] = vert(0) as f32;
                    return f(mid[0]) * f(o[0]);
                }
                o[0] = (vert(0) - f(e[0]) * f(mid[1])) as f32;
                for c in 1..w - 1 {
                    o[c] = (vert(c) - f(e[c]) * f(mid[c + 1]) - f(e[c - 1]) * f(mid[c - 1])) as f32;
                }
                o[w - 1] = (vert(w - 1) - f(e[w - 2]) * f(mid[w - 2])) as f32;
                mid.iter()
                    .zip(o.iter())
                    .map(|(&a, &b)| f(a) * f(b))
                    .sum::<f64>()
            })
            .sum()
    }

    /// `r = b − A x` with f64 `x` and `b` (the CG's true residual).
    pub fn residual64(&self, b: &[f64], x: &[f64], res: &mut [f64]) {
        let w = self.w;
        let zeros = vec![0f32; w];
        let zeros64 = vec![0f64; w];
        res.par_chunks_mut(w).enumerate().for_each(|(r, o)| {
            let (e, s, su, d) = self.op_rows(r, &zeros);
            let (up, down) = self.x_rows(x, r, &zeros64);
            let mid = &x[r * w..(r + 1) * w];
            let brow = &b[r * w..(r + 1) * w];
            for c in 0..w {
                let mut v = d[c] as f64 * mid[c] - s[c] as f64 * down[c] - su[c] as f64 * up[c];
                if c + 1 < w {
                    v -= e[c] as f64 * mid[c + 1];
                }
                if c > 0 {
                    v -= e[c - 1] as f64 * mid[c - 1];
                }
                o[c] = if d[c] > 0.0 { brow[c] - v } else { 0.0 };
            }
        });
    }

    /// Row `r` of `b − A x` in f32 into `o`.
    #[inline]
    fn residual_row(&self, b: &[f32], x: &[f32], r: usize, zeros: &[f32], o: &mut [f32]) {
        let w = self.w;
        let (e, s, su, d) = self.op_rows(r, zeros);
        let (up, down) = self.x_rows(x, r, zeros);
        let mid = &x[r * w..(r + 1) * w];
        let brow = &b[r * w..(r + 1) * w];
        let o = &mut o[..w];
        let vert = |c: usize| brow[c] - d[c] * mid[c] + s[c] * down[c] + su[c] * up[c];
        if w == 1 {
            o[0] = vert(0);
            return;
        }
        o[0] = vert(0) + e[0] * mid[1];
        for c in 1..w - 1 {
            o[c] = vert(c) + e[c] * mid[c + 1] + e[c - 1] * mid[c - 1];
        }
        o[w - 1] = vert(w - 1) + e[w - 2] * mid[w - 2];
    }

    /// `coarse = Pᵀ (b − A x)`: the residual summed over 2×2 blocks, without storing it.
    fn restrict_residual(&self, b: &[f32], x: &[f32], zeros: &[f32], coarse: &mut [f32]) {
        let (w, h) = (self.w, self.h);
        let cw = w.div_ceil(2);
        coarse.par_chunks_mut(cw).enumerate().for_each_init(
            || vec![0f32; w],
            |tmp, (cr, row)| {
                row.fill(0.0);
                for r in (2 * cr)..(2 * cr + 2).min(h) {
                    self.residual_row(b, x, r, zeros, tmp);
                    for (cc, o) in row.iter_mut().enumerate() {
                        let c = 2 * cc;
                        *o += tmp[c] + if c + 1 < w { tmp[c + 1] } else { 0.0 };
                    }
                }
            },
        );
    }

    /// One Gauss–Seidel half-sweep over the cells with `(r + c) % 2 == colour`. Each row's new
    /// values are computed for every cell in a vectorisable pass (the cells of the colour being
    /// updated depend only on cells of the other colour), then copied to the colour's cells.
    fn half_sweep(&self, b: &[f32], x: &mut [f32], colour: usize, zeros: &[f32]) {
        let (w, h) = (self.w, self.h);
        assert_eq!(x.len(), w * h);
        let ptr = SharedMut(x.as_mut_ptr());
        (0..h.div_ceil(ROWS_PER_TASK))
            .into_par_iter()
            .for_each_init(
                || vec![0f32; w],
                |tmp, t| {
                    let r0 = t * ROWS_PER_TASK;
                    let r1 = (r0 + ROWS_PER_TASK).min(h);
                    // SAFETY: `ptr` covers `w * h` initialised f32 (asserted above) and outlives this
                    // call. A half-sweep writes only cells of one colour and reads only cells of the
                    // other colour (their 4-neighbours); different tasks write disjoint rows. So no
                    // cell is written by one thread while another reads or writes it.
                    let xs = unsafe { std::slice::from_raw_parts_mut(ptr.get(), w * h) };
                    for r in r0..r1 {
                        let lo = r * w;
                        let (e, s, su) = {
                            let (e, s, su, _) = self.op_rows(r, zeros);
                            (e, s, su)
                        };
                        let inv = &self.inv_diag[lo..lo + w];
                        let (before, rest) = xs.split_at_mut(lo);
                        let (mid, after) = rest.split_at_mut(w);
                        let up = if r > 0 {
                            &before[(r - 1) * w..]
                        } else {
                            &zeros[..w]
                        };
                        let down = if r + 1 < h { &after[..w] } else { &zeros[..w] };
                        let brow = &b[lo..lo + w];
                        let tmp = &mut tmp[..w];
                        let vert = |c: usize| brow[c] + s[c] * down[c] + su[c] * up[c];
                        if w == 1 {
                            tmp[0] = vert(0) * inv[0];
                        } else {
                            tmp[0] = (vert(0) + e[0] * mid[1]) * inv[0];
                            for c in 1..w - 1 {
                                tmp[c] =
                                    (vert(c) + e[c] * mid[c + 1] + e[c - 1] * mid[c - 1]) * inv[c];
                            }
                            tmp[w - 1] = (vert(w - 1) + e[w - 2] * mid[w - 2]) * inv[w - 1];
                        }
                        let mut c = (r + colour) % 2;
                        while c < w {
                            mid[c] = tmp[c];
                            c += 2;
                        }
                    }
                },
            );
    }

    /// The next coarser level by 2×2 aggregation (see the module notes).
    fn coarsen(&self) -> Level {
        let (w, h) = (self.w, self.h);
        let (cw, ch) = (w.div_ceil(2), h.div_ceil(2));
        let mut east = vec![0f32; cw * ch];
        let mut south = vec![0f32; cw * ch];
        let mut extra = vec![0f32; cw * ch];
        let mut active = vec![false; cw * ch];
        east.par_chunks_mut(cw)
            .zip(south.par_chunks_mut(cw))
            .zip(extra.par_chunks_mut(cw))
            .zip(active.par_chunks_mut(cw))
            .enumerate()
            .for_each(|(cr, (((e_row, s_row), x_row), a_row))| {
                for cc in 0..cw {
                    let mut e = 0f32;
                    let mut s = 0f32;
                    let mut x = 0f32;
                    let mut a = false;
                    for dr in 0..2 {
                        let r = 2 * cr + dr;
                        if r >= h {
                            continue;
                        }
                        for dc in 0..2 {
                            let c = 2 * cc + dc;
                            if c >= w {
                                continue;
                            }
                            let i = r * w + c;
                            if self.diag[i] <= 0.0 {
                                continue;
                            }
                            a = true;
                            x += (self.diag[i] - self.edge_sum(i, r, c)).max(0.0);
                            if dc == 1 {
                                e += self.east[i];
                            }
                            if dr == 1 {
                                s += self.south[i];
                            }
                        }
                    }
                    e_row[cc] = 0.5 * e;
                    s_row[cc] = 0.5 * s;
                    x_row[cc] = x;
                    a_row[cc] = a;
                }
            });
        Level::from_parts(cw, ch, east, south, &extra, &active)
    }

    /// `fine += P coarse` on active cells.
    fn prolong_add(&self, coarse: &[f32], fine: &mut [f32]) {
        let w = self.w;
        let cw = w.div_ceil(2);
        fine.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
            let crow = &coarse[(r / 2) * cw..(r / 2 + 1) * cw];
            let drow = &self.diag[r * w..(r + 1) * w];
            for c in 0..w {
                if drow[c] > 0.0 {
                    row[c] += crow[c / 2];
                }
            }
        });
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
        let cells: Vec<usize> = (0..level.n()).filter(|&i| level.diag[i] > 0.0).collect();
        let m = cells.len();
        let mut pos = vec![usize::MAX; level.n()];
        for (k, &i) in cells.iter().enumerate() {
            pos[i] = k;
        }
        let mut a = vec![0f64; m * m];
        for (k, &i) in cells.iter().enumerate() {
            a[k * m + k] = level.diag[i] as f64;
            let (r, c) = (i / level.w, i % level.w);
            if c + 1 < level.w && pos[i + 1] != usize::MAX {
                let j = pos[i + 1];
                a[k * m + j] -= level.east[i] as f64;
                a[j * m + k] -= level.east[i] as f64;
            }
            if r + 1 < level.h && pos[i + level.w] != usize::MAX {
                let j = pos[i + level.w];
                a[k * m + j] -= level.south[i] as f64;
                a[j * m + k] -= level.south[i] as f64;
            }
        }
        // In-place Cholesky; a non-positive pivot (cannot happen for a pinned system, but f32
        // round-off on huge grids could bring one near zero) is replaced by a tiny positive one.
        let scale = (0..m).map(|k| a[k * m + k]).fold(0f64, f64::max).max(1e-30);
        for j in 0..m {
            let mut d = a[j * m + j];
            for k in 0..j {
                d -= a[j * m + k] * a[j * m + k];
            }
            let d = if d > 1e-12 * scale {
                d.sqrt()
            } else {
                (1e-12 * scale).sqrt()
            };
            a[j * m + j] = d;
            for i in j + 1..m {
                let mut s = a[i * m + j];
                for k in 0..j {
                    s -= a[i * m + k] * a[j * m + k];
                }
                a[i * m + j] = s / d;
            }
        }
        CoarseSolver { cells, factor: a }
    }

    fn solve(&self, b: &[f32], x: &mut [f32]) {
        let m = self.cells.len();
        let l = &self.factor;
        let mut y: Vec<f64> = self.cells.iter().map(|&i| b[i] as f64).collect();
        for i in 0..m {
            let mut s = y[i];
            for k in 0..i {
                s -= l[i * m + k] * y[k];
            }
            y[i] = s / l[i * m + i];
        }
        for i in (0..m).rev() {
            let mut s = y[i];
            for k in i + 1..m {
                s -= l[k * m + i] * y[k];
            }
            y[i] = s / l[i * m + i];
        }
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
pub(crate) struct Hierarchy {
    levels: Vec<Level>,
    coarse: CoarseSolver,
    work: Vec<Work>,
    /// A row of zeros as long as the widest level.
    zeros: Vec<f32>,
    /// Gauss–Seidel sweeps (red + black) before and after the coarse correction.
    pub sweeps: usize,
}

impl Hierarchy {
    /// Builds all levels from the finest one.
    pub fn new(fine: Level) -> Hierarchy {
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
                    b: vec![0.0; n],
                    x: vec![0.0; n],
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
        }
    }

    /// The finest level.
    pub fn fine(&self) -> &Level {
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
        x.fill(0.0);
        let level = &self.levels[l];
        for _ in 0..self.sweeps {
            level.half_sweep(b, x, 0, &self.zeros);
            level.half_sweep(b, x, 1, &self.zeros);
        }
        let mut next = std::mem::take(&mut self.work[l + 1]);
        level.restrict_residual(b, x, &self.zeros, &mut next.b);
        self.cycle_at(l + 1, &next.b, &mut next.x);
        let level = &self.levels[l];
        level.prolong_add(&next.x, x);
        self.work[l + 1] = next;
        for _ in 0..self.sweeps {
            level.half_sweep(b, x, 1, &self.zeros);
            level.half_sweep(b, x, 0, &self.zeros);
        }
    }
}

/// Result of [`pcg`].
#[derive(Clone, Debug)]
pub(crate) struct Solve {
    pub x: Vec<f64>,
    pub iterations: usize,
    /// ‖b − A x‖ / ‖b‖ at the end (the recurrence's residual; 0 when `b = 0`).
    pub relative_residual: f64,
}

fn dot64(a: &[f64], b: &[f64]) -> f64 {
    a.par_chunks(1 << 14)
        .zip(b.par_chunks(1 << 14))
        .map(|(x, y)| x.iter().zip(y).map(|(u, v)| u * v).sum::<f64>())
        .sum()
}

/// Conjugate gradients on the finest level's operator, preconditioned by one V-cycle, from
/// `x0` (or zero) to `‖r‖ ≤ tolerance · ‖b‖` or `max_iterations`. `progress` gets one unit per
/// iteration.
pub(crate) fn pcg(
    hierarchy: &mut Hierarchy,
    b: Vec<f64>,
    x0: Option<Vec<f64>>,
    tolerance: f64,
    max_iterations: usize,
    progress: &dyn Progress,
) -> Solve {
    let n = hierarchy.fine().n();
    let b_norm = dot64(&b, &b).sqrt();
    let mut r = b;
    let mut x = match x0 {
        Some(x0) => {
            let mut res = vec![0f64; n];
            hierarchy.fine().residual64(&r, &x0, &mut res);
            r = res;
            x0
        }
        None => vec![0f64; n],
    };
    if b_norm == 0.0 {
        return Solve {
            x: vec![0.0; n],
            iterations: 0,
            relative_residual: 0.0,
        };
    }
    let mut rel = dot64(&r, &r).sqrt() / b_norm;
    if rel <= tolerance {
        return Solve {
            x,
            iterations: 0,
            relative_residual: rel,
        };
    }
    // `r32` holds r in f32 for the V-cycle, then A p (the two uses never overlap).
    let mut r32: Vec<f32> = r.par_iter().map(|&v| v as f32).collect();
    let mut z = vec![0f32; n];
    hierarchy.vcycle(&r32, &mut z);
    let mut p = z.clone();
    let mut rz: f64 = r
        .par_chunks(1 << 14)
        .zip(z.par_chunks(1 << 14))
        .map(|(a, b)| a.iter().zip(b).map(|(u, &v)| u * v as f64).sum::<f64>())
        .sum();
    let mut iterations = 0;
    while iterations < max_iterations {
        iterations += 1;
        let ap = &mut r32;
        let pap = hierarchy.fine().apply32(&p, ap);
        if pap.is_nan() || pap <= 0.0 {
            break;
        }
        let alpha = rz / pap;
        // x += α p, r −= α A p, and r32 = r for the next V-cycle, in one pass.
        let rr: f64 = x
            .par_chunks_mut(1 << 14)
            .zip(r.par_chunks_mut(1 << 14))
            .zip(ap.par_chunks_mut(1 << 14))
            .zip(p.par_chunks(1 << 14))
            .map(|(((xs, rs), aps), ps)| {
                let mut s = 0f64;
                for k in 0..xs.len() {
                    xs[k] += alpha * ps[k] as f64;
                    let rv = rs[k] - alpha * aps[k] as f64;
                    rs[k] = rv;
                    aps[k] = rv as f32;
                    s += rv * rv;
                }
                s
            })
            .sum();
        progress.advance(1);
        rel = rr.sqrt() / b_norm;
        if rel <= tolerance {
            break;
        }
        hierarchy.vcycle(&r32, &mut z);
        let rz_new: f64 = r
            .par_chunks(1 << 14)
            .zip(z.par_chunks(1 << 14))
            .map(|(a, b)| a.iter().zip(b).map(|(u, &v)| u * v as f64).sum::<f64>())
            .sum();
        let beta = rz_new / rz;
        rz = rz_new;
        p.par_chunks_mut(1 << 14)
            .zip(z.par_chunks(1 << 14))
            .for_each(|(ps, zs)| {
                for (pv, &zv) in ps.iter_mut().zip(zs) {
                    *pv = zv + (beta as f32) * *pv;
                }
            });
    }
    Solve {
        x,
        iterations,
        relative_residual: rel,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progress::Silent;

    /// A masked grid with unit weights and one pinned cell per component.
    fn laplacian(w: usize, h: usize, mask: &[bool]) -> Level {
        let mut east = vec![0f32; w * h];
        let mut south = vec![0f32; w * h];
        for r in 0..h {
            for c in 0..w {
                let i = r * w + c;
                if c + 1 < w && mask[i] && mask[i + 1] {
                    east[i] = 1.0;
                }
                if r + 1 < h && mask[i] && mask[i + w] {
                    south[i] = 1.0;
                }
            }
        }
        let mut extra = vec![0f32; w * h];
        let first = mask.iter().position(|&m| m).unwrap();
        extra[first] = 1.0;
        Level::from_parts(w, h, east, south, &extra, mask)
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
        let mut b = vec![0f64; w * h];
        let zero = vec![0f64; w * h];
        level.residual64(&zero, &truth, &mut b);
        b.iter_mut().for_each(|v| *v = -*v);
        let mut hier = Hierarchy::new(level);
        let b_copy = b.clone();
        let s = pcg(&mut hier, b, None, 1e-10, 100, &Silent);
        assert!(s.relative_residual <= 1e-10, "{}", s.relative_residual);
        // The true residual, recomputed, agrees with the recurrence's.
        let mut r = vec![0f64; w * h];
        hier.fine().residual64(&b_copy, &s.x, &mut r);
        let rn = r.iter().map(|v| v * v).sum::<f64>().sqrt();
        let bn = b_copy.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(rn / bn < 1e-6, "true relative residual {}", rn / bn);
        for (i, (x, t)) in s.x.iter().zip(&truth).enumerate() {
            assert!((x - t).abs() < 1e-4, "{i}: {x} vs {t}");
        }
        assert!(s.iterations < 30, "{} iterations", s.iterations);
    }
}
