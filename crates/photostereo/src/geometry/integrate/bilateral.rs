//! `bilateral`: discontinuity-preserving integration by bilaterally weighted least squares
//! (Cao, Santo, Shi, Okura and Matsushita, "Bilateral Normal Integration", ECCV 2022).
//!
//! The surface is assumed one-sided differentiable: at every pixel at least one of the two
//! one-sided differences along each axis follows the normal, and the other may jump. With
//! `p_i`, `q_i` the pixel's gradients, `Δ⁺_i`, `Δ⁻_i` its forward and backward differences
//! of f along the columns (`Δ⁺_i = f_{i+1} − f_i`, `Δ⁻_i = f_i − f_{i−1}`) and likewise along
//! the rows, and `w⁺_i + w⁻_i = 1` the weights of the two sides (docs/integration.md):
//!
//! - (B1) `ω_i = t_i / (1 + p_i² + q_i²)`: each pixel's equations are those of the normal,
//!   `n_z Δ + n_x = 0`, whose weight `n_z² = 1 / (1 + p² + q²)` fades near grazing normals
//!   (where the gradient is least certain), times the caller's trust `t_i` (1 by default);
//! - (B2) `E(f) = Σ_i ω_i [w⁺_i (Δ⁺_i − p_i)² + w⁻_i (Δ⁻_i − p_i)²] + (rows alike, with q)`
//!   `+ λ Σ_i (f_i − prior_i)²`, over the differences that exist inside the mask;
//! - (B3) `w⁺_i = σ_k(n_z,i² ((Δ⁻_i)² − (Δ⁺_i)²))`, `w⁻_i = 1 − w⁺_i`, `σ_k(x) = 1 / (1 + e^{−k x})`:
//!   the side whose (normal-scaled) difference is the larger is the likelier jump and loses
//!   its weight (a missing difference at the mask's border counts as 0);
//! - (B4) per edge `e = (i, j)`, `j` after `i`, (B2) is `W_e (f_j − f_i − d_e)² + const` with
//!   `W_e = ω_i w⁺_i + ω_j w⁻_j` and `d_e = (ω_i w⁺_i p_i + ω_j w⁻_j p_j) / W_e`: a weighted
//!   graph Laplacian like `poisson`'s (with `w⁺ = w⁻ = ½` and `ω = 1` it is `poisson`'s
//!   trapezoid energy), solved by the same multigrid-preconditioned CG;
//! - iteratively reweighted least squares: solve (B4) with the weights fixed, update them by
//!   (B3) from the new f, and stop when (B2) changes by less than `tolerance` of itself;
//! - (B5) the last system: the weights found serve as a jump detector, not as the surface's
//!   discretisation. An edge is cut where the shares its two sides give it add up to less
//!   than half those of a smooth edge (`w⁺_i + w⁻_j < ½` against `½ + ½`, i.e.
//!   `w⁺_j − w⁺_i > ½`: the edge is more a jump than not); every other edge gets the
//!   symmetric weight `ω̄_e = (ω_i + ω_j) / 2` and the trapezoid target `(p_i + p_j) / 2`, as in
//!   `poisson`. Why: on a smooth but steep, curved surface the argument of (B3) is
//!   `n_z² ((Δ⁻)² − (Δ⁺)²) ≈ −2 n_z² f′ f″`, far from 0, so the converged weights make (B4)
//!   a one-sided, first-order difference there, and its error (`f″ / 2` per pixel) adds up
//!   along the few steep paths that join the parts a jump separates (a bear's head and body).
//!   The trapezoid target is second-order (error `f‴ / 12`); cut edges keep the floor weight.
//!
//! [`bilateral_reference`] is the plain version of the same equations (f64, Jacobi-
//! preconditioned CG on an explicitly summed operator, every inner solve converged), kept to
//! read and to test [`Bilateral`] against. [`Bilateral`] solves each reweighted system only
//! roughly (the weights move anyway), starting from the last surface, and the last system
//! (B5) tightly. With `debias` false the last system is (B4) under the converged weights (the
//! published method).
//!
//! Jumps are found in the units of the depth differences: heights in pixels (orthographic), or
//! `f̄ · ln Z` from [`super::perspective`] (the relative depth change times the focal length in
//! pixels, which is a height in pixels at the object's distance). `k = 2` is the published
//! setting; a larger k breaks the surface more readily.

use super::multigrid::{par_zeros, pcg, Hierarchy, Level, RowOperator, RowParts};
use super::spectral::dct_solve;
use super::{
    fill_unreliable, fill_unreliable_in_place, into_depth, Components, Depth, IntegrationProblem,
    IntegrationStats, Integrator, DEFAULT_FILL_BELOW, DEFAULT_TOLERANCE,
};
use crate::base::error::Result;
use crate::base::progress::Progress;
use rayon::prelude::*;
use std::borrow::Cow;

/// Default sharpness `k` of the sigmoid (B3): the setting published with the method (Cao et al.,
/// ECCV 2022), whose argument is in the same units here (squared height differences in pixels
/// times `n_z²`, orthographic and perspective alike).
pub const DEFAULT_SHARPNESS: f32 = 2.0;
/// Default relative change of the energy (B2) at which the reweighting stops.
pub const DEFAULT_ENERGY_TOLERANCE: f64 = 1e-3;
/// Default cap on reweighting iterations.
pub const DEFAULT_REWEIGHTINGS: usize = 100;

/// Discontinuity-preserving integration (see the module notes).
#[derive(Clone, Debug)]
pub struct Bilateral {
    /// Sharpness `k` of the sigmoid (B3); > 0.
    pub k: f32,
    /// Most reweighting iterations (solves of (B4)).
    pub max_iterations: usize,
    /// Stop when the energy (B2) changes by less than this share between iterations.
    pub tolerance: f64,
    /// Each reweighted solve reduces its starting residual by this factor.
    pub inner_reduction: f64,
    /// Most CG iterations of each reweighted solve.
    pub inner_iterations: usize,
    /// Relative residual of the last solve (the converged weights' system); at the default or
    /// above it also stops once a CG step moves no pixel by more than the f32 resolution of the
    /// surface (on a smooth whole frame the DCT start is already that close); a tolerance below
    /// the default is solved to.
    pub final_tolerance: f64,
    /// Pixels with a weight below this get interpolated gradients (as in `poisson`).
    pub fill_below: f32,
    /// Lower bound of an edge weight `W_e`, relative to the mean `ω` of its two pixels: a jump
    /// is cut to this weight, never to 0, so that every connected component of the mask stays
    /// one system.
    pub min_edge_weight: f32,
    /// Weight each pixel by `n_z²` (B1); false weighs every pixel by its trust alone.
    pub slope_weighting: bool,
    /// Solve the last system as (B5): trapezoid targets on the edges the weights keep, the
    /// others cut. False solves (B4) under the converged weights instead.
    pub debias: bool,
    /// On a mask that covers the whole grid, start the reweighting from the unit-weight surface
    /// the DCT solves directly (`poisson`'s) and its weights (B3), in place of a first solve
    /// under ½ weights; the energy (B2) under those weights against that under ½ weights is the
    /// first change, so that a smooth surface (where they barely differ) goes straight to the
    /// last system. False starts from ½ weights everywhere (the published method).
    pub poisson_start: bool,
}

impl Default for Bilateral {
    fn default() -> Self {
        Bilateral {
            k: DEFAULT_SHARPNESS,
            max_iterations: DEFAULT_REWEIGHTINGS,
            tolerance: DEFAULT_ENERGY_TOLERANCE,
            inner_reduction: 0.1,
            inner_iterations: 5,
            final_tolerance: DEFAULT_TOLERANCE,
            fill_below: DEFAULT_FILL_BELOW,
            min_edge_weight: 1e-5,
            slope_weighting: true,
            debias: true,
            poisson_start: true,
        }
    }
}

/// The logistic function `σ_k(x) = 1 / (1 + e^{−k x})` of (B3).
#[inline]
fn sigmoid(k: f32, x: f32) -> f32 {
    1.0 / (1.0 + (-k * x).exp())
}

/// `n_z² = 1 / (1 + p² + q²)`, the normal weighting of (B1).
#[inline]
fn slope_weight(p: f32, q: f32) -> f32 {
    1.0 / (1.0 + p * p + q * q)
}

/// The forward weight `w⁺` of (B3) from the backward and forward differences (0 where
/// missing) and the pixel's `n_z²`.
#[inline]
fn forward_weight(k: f32, nz2: f32, backward: f32, forward: f32) -> f32 {
    sigmoid(k, nz2 * (backward * backward - forward * forward)) // (B3)
}

/// `(W_e, W_e d_e)` of (B4) for an edge whose pixels have `ω` `oi`, `oj`, forward weights
/// `plus_i`, `plus_j` and gradients `gi`, `gj` along it; `W_e` is at least `floor` times the
/// mean `ω`.
#[inline]
fn edge_of(oi: f32, oj: f32, plus_i: f32, plus_j: f32, gi: f32, gj: f32, floor: f32) -> (f32, f32) {
    let a = oi * plus_i; // ω_i w⁺_i
    let b = oj * (1.0 - plus_j); // ω_j w⁻_j
    let weight = a + b; // (B4)
    let least = floor * 0.5 * (oi + oj);
    if weight >= least {
        (weight, a * gi + b * gj) // (B4)
    } else {
        // Below the floor: the missing weight goes to the trapezoid target.
        (least, a * gi + b * gj + (least - weight) * 0.5 * (gi + gj))
    }
}

/// `(W_e, W_e d_e)` of (B5) for the edge of [`edge_of`]: the symmetric weight and the
/// trapezoid target, or `floor` times them where the edge is cut.
#[inline]
fn debiased_edge_of(
    oi: f32,
    oj: f32,
    plus_i: f32,
    plus_j: f32,
    gi: f32,
    gj: f32,
    floor: f32,
) -> (f32, f32) {
    let mean = 0.5 * (oi + oj);
    let target = 0.5 * (gi + gj);
    let cut = plus_i + (1.0 - plus_j) < 0.5; // (B5): w⁺_i + w⁻_j < ½
    let weight = if cut { floor * mean } else { mean };
    (weight, weight * target)
}

/// The per-pixel inputs of (B1)–(B3) shared by both versions.
#[derive(Debug)]
struct Pixels<'a> {
    w: usize,
    h: usize,
    mask: &'a [bool],
    p: &'a [f32],
    q: &'a [f32],
    weights: Option<&'a [f32]>,
    slope_weighting: bool,
}

impl Pixels<'_> {
    /// `n_z²` (1 without slope weighting).
    #[inline]
    fn nz2(&self, i: usize) -> f32 {
        if self.slope_weighting {
            slope_weight(self.p[i], self.q[i])
        } else {
            1.0
        }
    }

    /// `ω_i` of (B1); trust below 1e-3 counts as 1e-3 (a filled pixel keeps the graph whole).
    #[inline]
    fn omega(&self, i: usize) -> f32 {
        self.omega_with(i, self.nz2(i))
    }

    /// [`Pixels::omega`] from the pixel's `n_z²` (`nz2`, as [`Pixels::nz2`] gives it).
    #[inline]
    fn omega_with(&self, i: usize, nz2: f32) -> f32 {
        let t = self.weights.map_or(1.0, |ws| ws[i].max(1e-3));
        t * nz2 // (B1)
    }

    /// The forward neighbour of `i` along the columns (`axis` 0) or rows (1) inside the mask.
    #[inline]
    fn next(&self, i: usize, axis: usize) -> Option<usize> {
        self.next_at(i, i / self.w, i % self.w, axis)
    }

    /// The backward neighbour of `i` along `axis` inside the mask.
    #[inline]
    fn prev(&self, i: usize, axis: usize) -> Option<usize> {
        self.prev_at(i, i / self.w, i % self.w, axis)
    }

    /// [`Pixels::next`] of pixel `i` at row `r`, column `c` (no division in the row passes).
    #[inline]
    fn next_at(&self, i: usize, r: usize, c: usize, axis: usize) -> Option<usize> {
        let j = match axis {
            0 if c + 1 < self.w => i + 1,
            1 if r + 1 < self.h => i + self.w,
            _ => return None,
        };
        self.mask[j].then_some(j)
    }

    /// [`Pixels::prev`] of pixel `i` at row `r`, column `c`.
    #[inline]
    fn prev_at(&self, i: usize, r: usize, c: usize, axis: usize) -> Option<usize> {
        let j = match axis {
            0 if c > 0 => i - 1,
            1 if r > 0 => i - self.w,
            _ => return None,
        };
        self.mask[j].then_some(j)
    }

    /// The gradient of pixel `i` along `axis`.
    #[inline]
    fn gradient(&self, i: usize, axis: usize) -> f32 {
        if axis == 0 {
            self.p[i]
        } else {
            self.q[i]
        }
    }

    /// The forward weight (B3) of pixel `i` along `axis` from the depth `f`.
    #[inline]
    fn weight_from<T: Copy + Into<f64>>(&self, k: f32, f: &[T], i: usize, axis: usize) -> f32 {
        self.weight_at(k, f, i, i / self.w, i % self.w, axis)
    }

    /// [`Pixels::weight_from`] of pixel `i` at row `r`, column `c`.
    #[inline]
    fn weight_at<T: Copy + Into<f64>>(
        &self,
        k: f32,
        f: &[T],
        i: usize,
        r: usize,
        c: usize,
        axis: usize,
    ) -> f32 {
        let d = |a: usize, b: usize| (f[b].into() - f[a].into()) as f32;
        let forward = self.next_at(i, r, c, axis).map_or(0.0, |j| d(i, j));
        let backward = self.prev_at(i, r, c, axis).map_or(0.0, |j| d(j, i));
        forward_weight(k, self.nz2(i), backward, forward)
    }

    /// `ω` (B1) of the pixels of row `r` into `out`.
    #[inline]
    fn omega_row(&self, r: usize, out: &mut [f32]) {
        let lo = r * self.w;
        for (c, o) in out.iter_mut().enumerate() {
            *o = self.omega(lo + c);
        }
    }

    /// The edges of row `r` by (B4), or (B5) when `debiased`, from the `ω` of its pixels (`om`)
    /// and of the next row's (`om_below`, unread on the last row): `(W_e, W_e d_e)` of the east
    /// edges into `east`, of the south edges into `south`; 0 where an edge leaves the mask. The
    /// values of [`Pixels::edge`] and [`Pixels::debiased_edge`], each `ω` computed once.
    #[allow(clippy::too_many_arguments)]
    fn row_edges(
        &self,
        plus: [&[f32]; 2],
        debiased: bool,
        floor: f32,
        r: usize,
        om: &[f32],
        om_below: &[f32],
        east: [&mut [f32]; 2],
        south: [&mut [f32]; 2],
    ) {
        // One loop per system, free of branches on `debiased` (they vectorise).
        if debiased {
            let edge = |oi, oj, pi, pj, gi, gj| debiased_edge_of(oi, oj, pi, pj, gi, gj, floor);
            self.row_edges_by(edge, plus, r, om, om_below, east, south); // (B5)
        } else {
            let edge = |oi, oj, pi, pj, gi, gj| edge_of(oi, oj, pi, pj, gi, gj, floor);
            self.row_edges_by(edge, plus, r, om, om_below, east, south); // (B4)
        }
    }

    /// [`Pixels::row_edges`] with the edge rule `edge(ω_i, ω_j, w⁺_i, w⁺_j, g_i, g_j)`; every
    /// edge of the row is computed, and those that leave the mask are set to 0.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn row_edges_by(
        &self,
        edge: impl Fn(f32, f32, f32, f32, f32, f32) -> (f32, f32),
        plus: [&[f32]; 2],
        r: usize,
        om: &[f32],
        om_below: &[f32],
        east: [&mut [f32]; 2],
        south: [&mut [f32]; 2],
    ) {
        let (w, lo) = (self.w, r * self.w);
        let m = &self.mask[lo..lo + w];
        let inside = |a: bool, b: bool, e: (f32, f32)| if a & b { e } else { (0.0, 0.0) };
        let [ew, ep] = east;
        let (pl, g) = (&plus[0][lo..lo + w], &self.p[lo..lo + w]);
        for c in 0..w - 1 {
            let e = edge(om[c], om[c + 1], pl[c], pl[c + 1], g[c], g[c + 1]);
            (ew[c], ep[c]) = inside(m[c], m[c + 1], e);
        }
        (ew[w - 1], ep[w - 1]) = (0.0, 0.0);
        let [sw, sp] = south;
        if r + 1 == self.h {
            sw.fill(0.0);
            sp.fill(0.0);
            return;
        }
        let (next, md) = (lo + w, &self.mask[lo + w..lo + 2 * w]);
        let (pl, pd) = (&plus[1][lo..lo + w], &plus[1][next..next + w]);
        let (g, gd) = (&self.q[lo..lo + w], &self.q[next..next + w]);
        for c in 0..w {
            let e = edge(om[c], om_below[c], pl[c], pd[c], g[c], gd[c]);
            (sw[c], sp[c]) = inside(m[c], md[c], e);
        }
    }

    /// `(W_e, W_e d_e)` of (B4) for the edge from `i` to `j` along `axis`, `plus_i` the forward
    /// weight of `i` and `plus_j` that of `j`; `W_e` is at least `floor` times the mean `ω`.
    #[inline]
    fn edge(
        &self,
        i: usize,
        j: usize,
        axis: usize,
        plus_i: f32,
        plus_j: f32,
        floor: f32,
    ) -> (f32, f32) {
        let (gi, gj) = (self.gradient(i, axis), self.gradient(j, axis));
        edge_of(self.omega(i), self.omega(j), plus_i, plus_j, gi, gj, floor)
    }

    /// `(W_e, W_e d_e)` of (B5) for the edge from `i` to `j` along `axis`: the symmetric
    /// weight and the trapezoid target, or `floor` times them where the edge is cut.
    #[inline]
    fn debiased_edge(
        &self,
        i: usize,
        j: usize,
        axis: usize,
        plus_i: f32,
        plus_j: f32,
        floor: f32,
    ) -> (f32, f32) {
        let (gi, gj) = (self.gradient(i, axis), self.gradient(j, axis));
        debiased_edge_of(self.omega(i), self.omega(j), plus_i, plus_j, gi, gj, floor)
    }

    /// The energy (B2) of `f` under the forward weights `plus` (`[columns, rows]`).
    fn energy<T: Copy + Into<f64> + Sync>(&self, f: &[T], plus: [&[f32]; 2]) -> f64 {
        (0..self.h)
            .into_par_iter()
            .map(|r| {
                let mut e = 0f64;
                for i in r * self.w..(r + 1) * self.w {
                    if !self.mask[i] {
                        continue;
                    }
                    let om = self.omega(i) as f64;
                    for (axis, pl) in plus.iter().enumerate() {
                        let g = self.gradient(i, axis) as f64;
                        let wp = pl[i] as f64;
                        if let Some(j) = self.next(i, axis) {
                            let d = f[j].into() - f[i].into() - g;
                            e += om * wp * d * d; // (B2)
                        }
                        if let Some(j) = self.prev(i, axis) {
                            let d = f[i].into() - f[j].into() - g;
                            e += om * (1.0 - wp) * d * d; // (B2)
                        }
                    }
                }
                e
            })
            .sum()
    }

    /// The discontinuity of each pixel: over its edges, the largest `w⁺_j − w⁺_i` (the share of
    /// the edge that neither side claims, 0..1), NaN outside the mask.
    fn discontinuities(&self, plus: [&[f32]; 2]) -> Vec<f32> {
        let mut out = vec![0f32; self.w * self.h];
        out.par_chunks_mut(self.w).enumerate().for_each(|(r, row)| {
            for (c, o) in row.iter_mut().enumerate() {
                let i = r * self.w + c;
                if !self.mask[i] {
                    *o = f32::NAN;
                    continue;
                }
                let mut d = 0f32;
                for (axis, pl) in plus.iter().enumerate() {
                    let cut = |a: usize, b: usize| (pl[b] - pl[a]).clamp(0.0, 1.0);
                    if let Some(j) = self.next_at(i, r, c, axis) {
                        d = d.max(cut(i, j));
                    }
                    if let Some(j) = self.prev_at(i, r, c, axis) {
                        d = d.max(cut(j, i));
                    }
                }
                *o = d;
            }
        });
        out
    }
}

/// A depth map with the discontinuity map that came with it.
fn finish(
    w: usize,
    h: usize,
    x: Vec<f32>,
    mask: &[bool],
    discontinuities: Vec<f32>,
    stats: IntegrationStats,
) -> Depth {
    let mut d = into_depth(w, h, x, mask, stats);
    d.discontinuities = Some(discontinuities);
    d
}

impl Integrator for Bilateral {
    fn name(&self) -> &'static str {
        "bilateral"
    }

    fn integrate(&self, problem: &IntegrationProblem, progress: &dyn Progress) -> Result<Depth> {
        problem.validate()?;
        self.check()?;
        // Every pass runs over the whole grid: solve on the mask's bounding box when it is
        // clearly smaller (an object in the middle of its photograph).
        // The many short parallel passes run from a pool thread: called from outside the pool
        // each would hand its work over to the pool and wait for it to be picked up.
        rayon::scope(
            |_| match Crop::of(problem.width, problem.height, problem.mask) {
                Some(crop) => {
                    let cut = crop.cut(problem);
                    let depth = self.solve(&cut.problem(), Given::default(), progress)?;
                    Ok(crop.embed(depth))
                }
                None => self.solve(problem, Given::default(), progress),
            },
        )
    }
}

/// What a solve is given beyond its problem, to work in: the starting surface (in place of the
/// problem's `initial`, which is then not read) and the number of pixels already filled in the
/// problem's gradients (they are then not filled again).
#[derive(Default)]
struct Given {
    start: Option<Vec<f32>>,
    filled: Option<usize>,
}

impl Bilateral {
    /// The intermediate surfaces' integrator of the recursive method: the reweighting from ½
    /// weights, without the debiased last solve.
    pub fn intermediate() -> Self {
        Bilateral {
            debias: false,
            poisson_start: false,
            ..Bilateral::default()
        }
    }

    /// [`Integrator::integrate`] of the gradients `p`, `q` (`height * width`) over `mask` with
    /// `weights`, from the surface `start` (as the problem's `initial`), in the arrays given: the
    /// unreliable pixels' gradients are filled in `p` and `q` and the surface is solved in
    /// `start`'s buffer, so that no second copy of either is held (on a mask whose bounding box
    /// is clearly smaller than the frame the solve works on cut copies, as `integrate` does).
    /// The depth is the same as `integrate`'s with `initial: Some(&start)`.
    #[allow(clippy::too_many_arguments)]
    pub fn integrate_owned(
        &self,
        width: usize,
        height: usize,
        mut p: Vec<f32>,
        mut q: Vec<f32>,
        mask: &[bool],
        weights: Option<&[f32]>,
        start: Vec<f32>,
        progress: &dyn Progress,
    ) -> Result<Depth> {
        if start.len() != width * height {
            return Err(crate::base::error::Error::invalid(format!(
                "integration: the starting depth has {} values, expected {width}×{height} = {}",
                start.len(),
                width * height
            )));
        }
        let problem = IntegrationProblem {
            weights,
            initial: Some(&start),
            ..IntegrationProblem::new(width, height, &p, &q, mask)
        };
        problem.validate()?;
        self.check()?;
        if let Some(crop) = Crop::of(width, height, mask) {
            return rayon::scope(|_| {
                let cut = crop.cut(&problem);
                let depth = self.solve(&cut.problem(), Given::default(), progress)?;
                Ok(crop.embed(depth))
            });
        }
        let filled = weights.map_or(0, |ws| {
            fill_unreliable_in_place(width, height, mask, ws, self.fill_below, &mut p, &mut q)
        });
        let problem = IntegrationProblem {
            weights,
            ..IntegrationProblem::new(width, height, &p, &q, mask)
        };
        let given = Given {
            start: Some(start),
            filled: Some(filled),
        };
        rayon::scope(|_| self.solve(&problem, given, progress))
    }
}

/// The bounding box of a mask, when it covers at most 3/4 of the grid.
struct Crop {
    width: usize,
    height: usize,
    r0: usize,
    c0: usize,
    w: usize,
    h: usize,
}

/// A problem's arrays cut to a [`Crop`].
struct CutProblem {
    w: usize,
    h: usize,
    p: Vec<f32>,
    q: Vec<f32>,
    mask: Vec<bool>,
    weights: Option<Vec<f32>>,
    prior: Option<(Vec<f32>, f32)>,
    initial: Option<Vec<f32>>,
}

impl CutProblem {
    fn problem(&self) -> IntegrationProblem<'_> {
        IntegrationProblem {
            weights: self.weights.as_deref(),
            prior: self.prior.as_ref().map(|(depth, lambda)| super::Prior {
                depth,
                lambda: *lambda,
            }),
            initial: self.initial.as_deref(),
            ..IntegrationProblem::new(self.w, self.h, &self.p, &self.q, &self.mask)
        }
    }
}

impl Crop {
    fn of(width: usize, height: usize, mask: &[bool]) -> Option<Crop> {
        let rows: Vec<Option<(usize, usize)>> = mask
            .par_chunks(width)
            .map(|row| {
                let first = row.iter().position(|&m| m)?;
                let last = row.iter().rposition(|&m| m)?;
                Some((first, last))
            })
            .collect();
        let r0 = rows.iter().position(Option::is_some)?;
        let r1 = rows.iter().rposition(Option::is_some)?;
        let (c0, c1) = rows
            .iter()
            .flatten()
            .fold((usize::MAX, 0), |(a, b), &(f, l)| (a.min(f), b.max(l)));
        let (w, h) = (c1 - c0 + 1, r1 - r0 + 1);
        (4 * w * h <= 3 * width * height).then_some(Crop {
            width,
            height,
            r0,
            c0,
            w,
            h,
        })
    }

    fn cut_slice<T: Copy + Send + Sync>(&self, full: &[T]) -> Vec<T> {
        (0..self.h)
            .into_par_iter()
            .flat_map_iter(|r| {
                let lo = (self.r0 + r) * self.width + self.c0;
                full[lo..lo + self.w].iter().copied()
            })
            .collect()
    }

    fn cut(&self, problem: &IntegrationProblem) -> CutProblem {
        CutProblem {
            w: self.w,
            h: self.h,
            p: self.cut_slice(problem.p),
            q: self.cut_slice(problem.q),
            mask: self.cut_slice(problem.mask),
            weights: problem.weights.map(|v| self.cut_slice(v)),
            prior: problem
                .prior
                .map(|pr| (self.cut_slice(pr.depth), pr.lambda)),
            initial: problem.initial.map(|v| self.cut_slice(v)),
        }
    }

    /// A full-frame copy of `cropped` (`w * h`), NaN outside the box.
    fn embed_slice(&self, cropped: &[f32]) -> Vec<f32> {
        let mut out = vec![f32::NAN; self.width * self.height];
        out.par_chunks_mut(self.width)
            .enumerate()
            .skip(self.r0)
            .take(self.h)
            .for_each(|(r, row)| {
                let lo = (r - self.r0) * self.w;
                row[self.c0..self.c0 + self.w].copy_from_slice(&cropped[lo..lo + self.w]);
            });
        out
    }

    fn embed(&self, depth: Depth) -> Depth {
        Depth {
            width: self.width,
            height: self.height,
            values: self.embed_slice(&depth.values),
            discontinuities: depth.discontinuities.map(|d| self.embed_slice(&d)),
            stats: depth.stats,
        }
    }
}

impl Bilateral {
    /// [`Integrator::integrate`] on a validated problem: solve (B4), reweight by (B3), until
    /// the energy (B2) settles; then the converged weights' system, tightly.
    ///
    /// With `poisson_start`, on a mask that covers the whole grid, the iteration starts from the
    /// unit-weight solution that the DCT gives directly (`poisson`'s surface, the first
    /// reweighted system's solution up to its `ω`): its weights (B3) replace the first solve,
    /// and the energy (B2) of that surface under them against under ½ weights is the first
    /// change. On a smooth surface the two barely differ (both sides' residuals are about
    /// `±f″/2`, so the weights hardly matter), and the last system follows at once.
    fn solve(
        &self,
        problem: &IntegrationProblem,
        given: Given,
        progress: &dyn Progress,
    ) -> Result<Depth> {
        let (w, h) = (problem.width, problem.height);
        let (p, q, filled) = match given.filled {
            Some(filled) => (Cow::Borrowed(problem.p), Cow::Borrowed(problem.q), filled),
            None => fill_unreliable(problem, self.fill_below),
        };
        let px = Pixels {
            w,
            h,
            mask: problem.mask,
            p: &p,
            q: &q,
            weights: problem.weights,
            slope_weighting: self.slope_weighting,
        };
        let components = Components::of(w, h, problem.mask);
        let from_dct = self.poisson_start
            && problem.initial.is_none()
            && given.start.is_none()
            && components.is_whole_grid()
            && self.max_iterations > 0;
        let start = from_dct.then(|| {
            let g = |i: usize| (p[i] as f64, q[i] as f64);
            let (f, _) = dct_solve(w, h, g, problem.mask, problem.prior, false);
            f.par_iter().map(|&v| v as f32).collect::<Vec<f32>>()
        });
        // A given start is read as `initial` is: 0 outside the mask and where not finite.
        let start = start.or(given.start.map(|mut x| {
            x.par_iter_mut()
                .zip(problem.mask.par_iter())
                .for_each(|(v, &m)| {
                    if !(m && v.is_finite()) {
                        *v = 0.0;
                    }
                });
            x
        }));
        let mut state = State::new(problem, &components, start);
        let mut energy = f64::INFINITY;
        let mut reweightings = 0;
        progress.begin("integrate", self.max_iterations as u64 + 1);
        let mut settled = false;
        if from_dct {
            // The DCT's surface stands for the first solve (under ½ weights): the energy (B2)
            // under its weights (B3) against that under ½ weights is the first change.
            let half;
            (energy, half) = self.reweight(&px, &state.x, &mut state.plus); // (B3), (B2)
            let change = (energy - half).abs() / energy.max(f64::MIN_POSITIVE);
            settled = change < self.tolerance;
        }
        while !settled && reweightings < self.max_iterations {
            self.solve_reweighted(&px, problem, &mut state, false);
            progress.advance(1);
            reweightings += 1;
            // (B3) from the new surface, and the energy (B2) under the new weights.
            let (new_energy, _) = self.reweight(&px, &state.x, &mut state.plus);
            let change = (energy - new_energy).abs() / new_energy.max(f64::MIN_POSITIVE);
            energy = new_energy;
            if change < self.tolerance {
                break;
            }
        }
        let (relative_residual, levels) = self.solve_reweighted(&px, problem, &mut state, true);
        progress.advance(1);
        progress.end();
        let (cg_iterations, at_precision) = (state.cg_iterations, state.at_precision);
        let State { mut x, plus, r, .. } = state;
        drop(r);
        if problem.prior.is_none_or(|pr| pr.lambda == 0.0) {
            components.remove_means(&mut x);
        }
        let discontinuities = px.discontinuities([&plus[0], &plus[1]]);
        drop(plus);
        let mut notes = Vec::new();
        if relative_residual > self.final_tolerance && !at_precision {
            notes.push(format!(
                "bilateral's last solve stopped at relative residual {relative_residual:.2e} (tolerance {:.1e})",
                self.final_tolerance
            ));
        }
        let stats = IntegrationStats {
            method: "bilateral".into(),
            iterations: cg_iterations,
            relative_residual,
            components: components.count,
            filled_pixels: filled,
            levels,
            direct: false,
            reweightings,
            notes,
        };
        Ok(finish(w, h, x, problem.mask, discontinuities, stats))
    }

    /// Solves (B4) under the current weights from the current surface: roughly (the starting
    /// residual reduced by `inner_reduction`, at least one CG iteration), or with `tight` to
    /// `final_tolerance` (as (B5) when `debias`). Returns the relative residual
    /// `‖b − A f‖ / ‖b‖` and the multigrid levels.
    fn solve_reweighted(
        &self,
        px: &Pixels,
        problem: &IntegrationProblem,
        st: &mut State,
        tight: bool,
    ) -> (f64, usize) {
        let (w, h) = (px.w, px.h);
        let prior = problem.prior.filter(|pr| pr.lambda > 0.0);
        let lambda = prior.map_or(0.0, |pr| pr.lambda);
        let plus = [&st.plus[0][..], &st.plus[1][..]];
        let debiased = tight && self.debias;
        let floor = self.min_edge_weight;
        let system = System {
            px,
            plus,
            debiased,
            floor,
            lambda,
        };
        let level = Level::computed(w, h, &system);
        // The right-hand side's `W_e d_e` are recomputed row by row rather than stored.
        let b_norm = level
            .residual_from(
                |row, _, b| rhs_row(px, plus, debiased, floor, prior, row, b),
                Some(&st.x),
                &mut st.r,
            )
            .sqrt();
        let mut hier = Hierarchy::new(level);
        // The last solve also stops when CG can no longer change the stored (f32) surface,
        // unless a tolerance below the default asks for the residual itself.
        hier.stop_at_precision = tight && self.final_tolerance >= DEFAULT_TOLERANCE;
        let levels = hier.depth();
        let (scale, tolerance, most) = if tight {
            (b_norm, self.final_tolerance, 200)
        } else {
            let r0 = super::multigrid::norm2(&st.r).sqrt();
            (r0, self.inner_reduction, self.inner_iterations)
        };
        let solve = pcg(
            &mut hier,
            &mut st.r,
            scale,
            &mut st.x,
            st.null_space,
            tolerance,
            most,
            &crate::base::progress::Silent,
        );
        st.cg_iterations += solve.iterations;
        st.at_precision = solve.at_precision;
        (
            solve.relative_residual * scale / b_norm.max(f64::MIN_POSITIVE),
            levels,
        )
    }
}

/// The normal equations of (B4), or (B5) when `debiased`, plus the prior's `lambda` on the
/// mask, as the solver's finest level: each row's edge weights `W_e` computed from the forward
/// weights `plus` when the solver asks for it (the values [`Pixels::row_edges`] gives), so that
/// no edge weight is stored.
#[derive(Debug)]
struct System<'p, 'a> {
    px: &'p Pixels<'a>,
    plus: [&'p [f32]; 2],
    debiased: bool,
    floor: f32,
    lambda: f32,
}

impl RowOperator for System<'_, '_> {
    fn row(&self, r: usize, out: RowParts<'_>) {
        let (px, w) = (self.px, self.px.w);
        let (plus, debiased, floor) = (self.plus, self.debiased, self.floor);
        out.work.resize(7 * w, 0.0);
        let mut rows = out.work.chunks_mut(w);
        let mut row = || rows.next().expect("seven rows");
        let (om_up, om, om_below) = (row(), row(), row());
        let (east_pull, south_pull, up_east, up_pull) = (row(), row(), row(), row());
        px.omega_row(r, om);
        if r + 1 < px.h {
            px.omega_row(r + 1, om_below);
        }
        let (east, south) = ([out.e, east_pull], [out.s, south_pull]);
        px.row_edges(plus, debiased, floor, r, om, om_below, east, south);
        if r > 0 {
            px.omega_row(r - 1, om_up);
            let (east, south) = ([up_east, up_pull], [&mut *out.su, &mut *south_pull]);
            px.row_edges(plus, debiased, floor, r - 1, om_up, om, east, south);
        } else {
            out.su.fill(0.0);
        }
        let m = &px.mask[r * w..(r + 1) * w];
        for ((x, a), &mv) in out.ex.iter_mut().zip(out.active.iter_mut()).zip(m) {
            *x = if mv { self.lambda } else { 0.0 };
            *a = mv;
        }
    }
}

/// The arrays of a bilateral solve.
struct State<'c> {
    /// The surface (f32, as the multigrid solver keeps it).
    x: Vec<f32>,
    /// The forward weights (B3) along the columns and the rows; ½ at first (`poisson`'s system).
    plus: [Vec<f32>; 2],
    /// The residual.
    r: Vec<f32>,
    /// The constants of each component, when no prior fixes them.
    null_space: Option<&'c Components>,
    cg_iterations: usize,
    /// The last solve stopped at the f32 resolution of the surface, not at its tolerance.
    at_precision: bool,
}

impl<'c> State<'c> {
    /// The arrays, the surface from `start` (else from the problem's initial depth, else 0).
    fn new(
        problem: &IntegrationProblem,
        components: &'c Components,
        start: Option<Vec<f32>>,
    ) -> State<'c> {
        let n = problem.width * problem.height;
        let x = match (start, problem.initial) {
            (Some(x), _) => x,
            (None, Some(start)) => start
                .par_iter()
                .zip(problem.mask.par_iter())
                .map(|(&v, &m)| if m && v.is_finite() { v } else { 0.0 })
                .collect(),
            (None, None) => par_zeros(n),
        };
        let has_prior = problem.prior.is_some_and(|pr| pr.lambda > 0.0);
        State {
            x,
            plus: [vec![0.5; n], vec![0.5; n]],
            r: par_zeros(n),
            null_space: (!has_prior).then_some(components),
            cg_iterations: 0,
            at_precision: false,
        }
    }
}

impl Bilateral {
    /// Checks the parameters; errors name them.
    fn check(&self) -> Result<()> {
        use crate::base::error::Error;
        if !(self.k > 0.0 && self.k.is_finite()) {
            return Err(Error::parameter(
                "sharpness",
                format!("{}: expected a positive number", self.k),
            ));
        }
        if !(self.min_edge_weight > 0.0 && self.min_edge_weight <= 1.0) {
            return Err(Error::parameter(
                "min_edge_weight",
                format!("{}: expected a value in (0, 1]", self.min_edge_weight),
            ));
        }
        Ok(())
    }

    /// Replaces the forward weights by (B3) of the surface `x` and returns the energy (B2) of
    /// `x` under the new weights and under the weights it replaced, in one pass.
    fn reweight(&self, px: &Pixels, x: &[f32], plus: &mut [Vec<f32>; 2]) -> (f64, f64) {
        let w = px.w;
        let [pu, pv] = plus;
        pu.par_chunks_mut(w)
            .zip(pv.par_chunks_mut(w))
            .enumerate()
            .map_init(
                || vec![0f32; 6 * w],
                |scratch, (r, (u_row, v_row))| self.reweight_row(px, x, r, [u_row, v_row], scratch),
            )
            .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1))
    }

    /// Row `r` of [`Bilateral::reweight`]: the forward weights of its pixels along the columns
    /// into `rows[0]`, along the rows into `rows[1]` (pixels outside the mask keep theirs);
    /// returns the row's share of the energy under the new and the old weights. `scratch`
    /// holds six rows. The differences are those of the f32 surface (as the solver keeps it),
    /// 0 where they leave the mask, with a presence factor (1 or 0) that drops their terms
    /// from (B2): every pass is free of branches.
    fn reweight_row(
        &self,
        px: &Pixels,
        x: &[f32],
        r: usize,
        rows: [&mut [f32]; 2],
        scratch: &mut [f32],
    ) -> (f64, f64) {
        let (w, lo) = (px.w, r * px.w);
        let (m, xr) = (&px.mask[lo..lo + w], &x[lo..lo + w]);
        let mut parts = scratch.chunks_mut(w);
        let mut part = || parts.next().expect("six rows");
        let (nz2, om, ahead, behind, ahead_in, behind_in) =
            (part(), part(), part(), part(), part(), part());
        let (p, q) = (&px.p[lo..lo + w], &px.q[lo..lo + w]);
        for c in 0..w {
            nz2[c] = if px.slope_weighting {
                slope_weight(p[c], q[c])
            } else {
                1.0
            };
        }
        match px.weights {
            Some(ws) => {
                for ((o, &s), &t) in om.iter_mut().zip(&*nz2).zip(&ws[lo..lo + w]) {
                    *o = t.max(1e-3) * s; // (B1)
                }
            }
            None => om.copy_from_slice(nz2),
        }
        // Along the columns: the east difference of each pixel, and its west one.
        ahead_in[w - 1] = 0.0;
        ahead[w - 1] = 0.0;
        for c in 0..w - 1 {
            let both = m[c] & m[c + 1];
            ahead_in[c] = if both { 1.0 } else { 0.0 };
            ahead[c] = if both { xr[c + 1] - xr[c] } else { 0.0 };
        }
        behind[0] = 0.0;
        behind_in[0] = 0.0;
        behind[1..].copy_from_slice(&ahead[..w - 1]);
        behind_in[1..].copy_from_slice(&ahead_in[..w - 1]);
        let [u_row, v_row] = rows;
        let (mut new, mut old) =
            self.reweight_pass(m, nz2, om, p, [ahead, behind], [ahead_in, behind_in], u_row);
        // Along the rows: the south difference, and the north one.
        let vertical = |out: &mut [f32], inside: &mut [f32], other: Option<usize>, down: bool| {
            let Some(o) = other else {
                out.fill(0.0);
                inside.fill(0.0);
                return;
            };
            let (xo, mo) = (&x[o..o + w], &px.mask[o..o + w]);
            for c in 0..w {
                let both = m[c] & mo[c];
                inside[c] = if both { 1.0 } else { 0.0 };
                let d = if down { xo[c] - xr[c] } else { xr[c] - xo[c] };
                out[c] = if both { d } else { 0.0 };
            }
        };
        vertical(ahead, ahead_in, (r + 1 < px.h).then_some(lo + w), true);
        vertical(behind, behind_in, (r > 0).then(|| lo - w), false);
        let (a, b) =
            self.reweight_pass(m, nz2, om, q, [ahead, behind], [ahead_in, behind_in], v_row);
        new += a;
        old += b;
        (new, old)
    }

    /// One axis of [`Bilateral::reweight_row`]: from the forward and backward differences
    /// `diff` (0 where missing, `inside` 1 where present), the forward weights (B3) into `out`
    /// (on the mask `m`), and the energy (B2) of the row along the axis under the new weights
    /// and under those `out` held.
    #[allow(clippy::too_many_arguments)]
    fn reweight_pass(
        &self,
        m: &[bool],
        nz2: &[f32],
        om: &[f32],
        g: &[f32],
        diff: [&[f32]; 2],
        inside: [&[f32]; 2],
        out: &mut [f32],
    ) -> (f64, f64) {
        let [ahead, behind] = diff;
        let [ahead_in, behind_in] = inside;
        let (mut new, mut old) = (0f64, 0f64);
        for c in 0..out.len() {
            let (f, b) = (ahead[c], behind[c]);
            let wp = forward_weight(self.k, nz2[c], b, f); // (B3)
            let (df, db) = (f - g[c], b - g[c]);
            let (ef, eb) = (ahead_in[c] * df * df, behind_in[c] * db * db);
            let was = out[c];
            let inside = if m[c] { 1.0 } else { 0.0 };
            new += (inside * om[c] * (wp * ef + (1.0 - wp) * eb)) as f64; // (B2)
            old += (inside * om[c] * (was * ef + (1.0 - was) * eb)) as f64;
            out[c] = if m[c] { wp } else { was };
        }
        (new, old)
    }
}

/// Row `r` of `b` in the normal equations of (B4), or (B5) when `debiased` (+ the prior):
/// `Σ ± W_e d_e` over the cell's edges.
fn rhs_row(
    px: &Pixels,
    plus: [&[f32]; 2],
    debiased: bool,
    floor: f32,
    prior: Option<super::Prior>,
    r: usize,
    out: &mut [f64],
) {
    let (w, h) = (px.w, px.h);
    // ω of rows r − 1, r, r + 1; the edges of row r and the south edges of row r − 1.
    let mut scratch = vec![0f32; 11 * w];
    let mut rows = scratch.chunks_mut(w);
    let mut row = || rows.next().expect("eleven rows");
    let (om_up, om, om_below) = (row(), row(), row());
    let (east, east_pull, south, south_pull) = (row(), row(), row(), row());
    let (up_east, up_east_pull, up, up_pull) = (row(), row(), row(), row());
    px.omega_row(r, om);
    if r + 1 < h {
        px.omega_row(r + 1, om_below);
    }
    px.row_edges(
        plus,
        debiased,
        floor,
        r,
        om,
        om_below,
        [east, east_pull],
        [south, south_pull],
    );
    if r > 0 {
        px.omega_row(r - 1, om_up);
        let up_row = [up_east, up_east_pull];
        px.row_edges(
            plus,
            debiased,
            floor,
            r - 1,
            om_up,
            om,
            up_row,
            [up, up_pull],
        );
    }
    let lo = r * w;
    for (c, b) in out.iter_mut().enumerate() {
        let i = lo + c;
        *b = 0.0;
        if !px.mask[i] {
            continue;
        }
        let mut s = -(east_pull[c] as f64) - south_pull[c] as f64;
        if c > 0 {
            s += east_pull[c - 1] as f64;
        }
        if r > 0 {
            s += up_pull[c] as f64;
        }
        if let Some(prior) = prior {
            s += prior.lambda as f64 * prior.depth[i] as f64;
        }
        *b = s;
    }
}

/// The reference version of [`Bilateral`] (same parameters and result, within the solvers'
/// tolerances): the equations as written, in f64, each reweighted system (B4) solved to a
/// relative residual of 1e-10 by Jacobi-preconditioned CG. Slow (O(n^1.5) per solve); for
/// reading and testing.
pub fn bilateral_reference(params: &Bilateral, problem: &IntegrationProblem) -> Result<Depth> {
    problem.validate()?;
    params.check()?;
    let (w, h) = (problem.width, problem.height);
    let n = w * h;
    let (p, q, filled) = fill_unreliable(problem, params.fill_below);
    let px = Pixels {
        w,
        h,
        mask: problem.mask,
        p: &p,
        q: &q,
        weights: problem.weights,
        slope_weighting: params.slope_weighting,
    };
    let lambda = problem.prior.map_or(0.0, |pr| pr.lambda as f64);
    // The normal equations of `Σ_e W_e (f_j − f_i − d_e)² + λ Σ_i (f_i − prior_i)²` with
    // `(W_e, W_e d_e) = edge(i, j, axis)`: A f = b, A = Σ_e W_e (1_j − 1_i)(1_j − 1_i)ᵀ + λ I,
    // solved from `f`.
    let solve = |edge: &dyn Fn(usize, usize, usize) -> (f32, f32), f: &mut [f64]| {
        let mut diag = vec![0f64; n];
        let mut edges = Vec::new(); // (i, j, W_e)
        let mut b = vec![0f64; n];
        for i in 0..n {
            if !px.mask[i] {
                continue;
            }
            diag[i] += lambda;
            if let Some(prior) = problem.prior {
                b[i] += lambda * prior.depth[i] as f64;
            }
            for axis in 0..2 {
                if let Some(j) = px.next(i, axis) {
                    let (we, wd) = edge(i, j, axis);
                    let (we, wd) = (we as f64, wd as f64);
                    edges.push((i, j, we));
                    diag[i] += we;
                    diag[j] += we;
                    b[i] -= wd;
                    b[j] += wd;
                }
            }
        }
        let apply = |x: &[f64], out: &mut [f64]| {
            for (o, (&d, &v)) in out.iter_mut().zip(diag.iter().zip(x)) {
                *o = d * v;
            }
            for &(i, j, we) in &edges {
                out[i] -= we * x[j];
                out[j] -= we * x[i];
            }
        };
        jacobi_cg(&apply, &diag, &b, f, px.mask);
    };
    // The weights (B3) of `f`, and the energy (B2) of `f` under them.
    let reweight = |f: &[f64], plus: &mut [Vec<f32>; 2]| {
        for (axis, pl) in plus.iter_mut().enumerate() {
            for (i, wp) in pl.iter_mut().enumerate() {
                if px.mask[i] {
                    *wp = px.weight_from(params.k, f, i, axis); // (B3)
                }
            }
        }
        px.energy(f, [&plus[0], &plus[1]]) // (B2)
    };
    let mut f = vec![0f64; n];
    let mut plus = [vec![0.5f32; n], vec![0.5f32; n]];
    let mut energy = f64::INFINITY;
    let floor = params.min_edge_weight;
    let mut settled = false;
    if params.poisson_start && params.max_iterations > 0 && px.mask.iter().all(|&m| m) {
        // On a whole grid the iteration starts from the unit-weight trapezoid system's
        // solution (`poisson`'s) and its weights.
        let g = |i: usize, axis: usize| px.gradient(i, axis);
        solve(&|i, j, axis| (1.0, 0.5 * (g(i, axis) + g(j, axis))), &mut f);
        let half = px.energy(&f, [&plus[0], &plus[1]]); // (B2) under ½ weights
        energy = reweight(&f, &mut plus);
        settled = (energy - half).abs() / energy.max(f64::MIN_POSITIVE) < params.tolerance;
    }
    let mut reweightings = if settled { params.max_iterations } else { 0 };
    loop {
        // The last pass solves (B5) under the converged weights.
        let last = reweightings >= params.max_iterations;
        let pl = &plus;
        solve(
            &|i, j, axis| {
                let (a, b) = (pl[axis][i], pl[axis][j]);
                if last && params.debias {
                    px.debiased_edge(i, j, axis, a, b, floor) // (B5)
                } else {
                    px.edge(i, j, axis, a, b, floor) // (B4)
                }
            },
            &mut f,
        );
        if last {
            break;
        }
        reweightings += 1;
        let new_energy = reweight(&f, &mut plus);
        let change = (energy - new_energy).abs() / new_energy.max(f64::MIN_POSITIVE);
        energy = new_energy;
        if change < params.tolerance {
            reweightings = params.max_iterations;
        }
    }
    let components = Components::of(w, h, problem.mask);
    if lambda == 0.0 {
        components.remove_means(&mut f);
    }
    let discontinuities = px.discontinuities([&plus[0], &plus[1]]);
    let values: Vec<f32> = f.iter().map(|&v| v as f32).collect();
    let stats = IntegrationStats {
        method: "bilateral".into(),
        components: components.count,
        filled_pixels: filled,
        ..IntegrationStats::default()
    };
    Ok(finish(w, h, values, problem.mask, discontinuities, stats))
}

/// Jacobi-preconditioned CG on `A x = b` (A symmetric positive semi-definite; without a prior
/// singular, and `b` then sums to zero over each component, so the system is consistent and
/// CG stays in A's range), from `x`, to ‖b − A x‖ ≤ 1e-10 ‖b‖.
fn jacobi_cg(
    apply: &dyn Fn(&[f64], &mut [f64]),
    diag: &[f64],
    b: &[f64],
    x: &mut [f64],
    mask: &[bool],
) {
    let n = b.len();
    let inv: Vec<f64> = diag
        .iter()
        .zip(mask)
        .map(|(&d, &m)| if m && d > 0.0 { 1.0 / d } else { 0.0 })
        .collect();
    let dot = |a: &[f64], c: &[f64]| a.iter().zip(c).map(|(u, v)| u * v).sum::<f64>();
    let b_norm = dot(b, b).sqrt();
    if b_norm == 0.0 {
        x.iter_mut().for_each(|v| *v = 0.0);
        return;
    }
    let mut ax = vec![0f64; n];
    apply(x, &mut ax);
    let mut r: Vec<f64> = (0..n)
        .map(|i| if inv[i] > 0.0 { b[i] - ax[i] } else { 0.0 })
        .collect();
    let mut z: Vec<f64> = (0..n).map(|i| inv[i] * r[i]).collect();
    let mut d = z.clone();
    let mut rz = dot(&r, &z);
    for _ in 0..100 * n.max(10) {
        if dot(&r, &r).sqrt() <= 1e-10 * b_norm {
            break;
        }
        apply(&d, &mut ax);
        let dad = dot(&d, &ax);
        if dad <= 0.0 {
            break;
        }
        let alpha = rz / dad;
        for i in 0..n {
            x[i] += alpha * d[i];
            r[i] -= alpha * ax[i];
            z[i] = inv[i] * r[i];
        }
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            d[i] = z[i] + beta * d[i];
        }
    }
}
