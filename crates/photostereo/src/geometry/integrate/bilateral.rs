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

use super::multigrid::{par_zeros, pcg, Hierarchy, Level};
use super::{
    fill_unreliable, into_depth, Components, Depth, IntegrationProblem, IntegrationStats,
    Integrator, DEFAULT_FILL_BELOW, DEFAULT_TOLERANCE,
};
use crate::base::error::Result;
use crate::base::progress::Progress;
use rayon::prelude::*;

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
    /// Relative residual of the last solve (the converged weights' system).
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

/// The per-pixel inputs of (B1)–(B3) shared by both versions.
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
        let t = self.weights.map_or(1.0, |ws| ws[i].max(1e-3));
        t * self.nz2(i) // (B1)
    }

    /// The forward neighbour of `i` along the columns (`axis` 0) or rows (1) inside the mask.
    #[inline]
    fn next(&self, i: usize, axis: usize) -> Option<usize> {
        let (r, c) = (i / self.w, i % self.w);
        let j = match axis {
            0 if c + 1 < self.w => i + 1,
            1 if r + 1 < self.h => i + self.w,
            _ => return None,
        };
        self.mask[j].then_some(j)
    }

    /// The backward neighbour of `i` along `axis` inside the mask.
    #[inline]
    fn prev(&self, i: usize, axis: usize) -> Option<usize> {
        let (r, c) = (i / self.w, i % self.w);
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
        let d = |a: usize, b: usize| (f[b].into() - f[a].into()) as f32;
        let forward = self.next(i, axis).map_or(0.0, |j| d(i, j));
        let backward = self.prev(i, axis).map_or(0.0, |j| d(j, i));
        forward_weight(k, self.nz2(i), backward, forward)
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
        let (oi, oj) = (self.omega(i), self.omega(j));
        let a = oi * plus_i; // ω_i w⁺_i
        let b = oj * (1.0 - plus_j); // ω_j w⁻_j
        let (gi, gj) = (self.gradient(i, axis), self.gradient(j, axis));
        let weight = a + b; // (B4)
        let least = floor * 0.5 * (oi + oj);
        if weight >= least {
            (weight, a * gi + b * gj) // (B4)
        } else {
            // Below the floor: the missing weight goes to the trapezoid target.
            (least, a * gi + b * gj + (least - weight) * 0.5 * (gi + gj))
        }
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
        let mean = 0.5 * (self.omega(i) + self.omega(j));
        let target = 0.5 * (self.gradient(i, axis) + self.gradient(j, axis));
        let cut = plus_i + (1.0 - plus_j) < 0.5; // (B5): w⁺_i + w⁻_j < ½
        let weight = if cut { floor * mean } else { mean };
        (weight, weight * target)
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
                    if let Some(j) = self.next(i, axis) {
                        d = d.max(cut(i, j));
                    }
                    if let Some(j) = self.prev(i, axis) {
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
                    let depth = self.solve(&cut.problem(), progress)?;
                    Ok(crop.embed(depth))
                }
                None => self.solve(problem, progress),
            },
        )
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
    fn solve(&self, problem: &IntegrationProblem, progress: &dyn Progress) -> Result<Depth> {
        let (w, h) = (problem.width, problem.height);
        let (p, q, filled) = fill_unreliable(problem, self.fill_below);
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
        let mut state = State::new(problem, &components);
        let mut energy = f64::INFINITY;
        let mut reweightings = 0;
        progress.begin("integrate", self.max_iterations as u64 + 1);
        while reweightings < self.max_iterations {
            self.solve_reweighted(&px, problem, &mut state, false);
            progress.advance(1);
            reweightings += 1;
            // (B3) from the new surface, and the energy (B2) under the new weights.
            self.update_weights(&px, &state.x, &mut state.plus);
            let new_energy = px.energy(&state.x, [&state.plus[0], &state.plus[1]]);
            let change = (energy - new_energy).abs() / new_energy.max(f64::MIN_POSITIVE);
            energy = new_energy;
            if change < self.tolerance {
                break;
            }
        }
        let (relative_residual, levels) = self.solve_reweighted(&px, problem, &mut state, true);
        progress.advance(1);
        progress.end();
        let State { mut x, plus, .. } = state;
        if problem.prior.is_none_or(|pr| pr.lambda == 0.0) {
            components.remove_means(&mut x);
        }
        let discontinuities = px.discontinuities([&plus[0], &plus[1]]);
        let mut notes = Vec::new();
        if relative_residual > self.final_tolerance {
            notes.push(format!(
                "bilateral's last solve stopped at relative residual {relative_residual:.2e} (tolerance {:.1e})",
                self.final_tolerance
            ));
        }
        let stats = IntegrationStats {
            method: "bilateral".into(),
            iterations: state.cg_iterations,
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
    /// `final_tolerance`. Returns the relative residual `‖b − A f‖ / ‖b‖` and the multigrid
    /// levels.
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
        self.edges(
            px,
            plus,
            tight && self.debias,
            [&mut st.east, &mut st.south],
            [&mut st.pull_east, &mut st.pull_south],
        );
        let level = Level::from_parts(
            w,
            h,
            std::mem::take(&mut st.east),
            std::mem::take(&mut st.south),
            |i| if problem.mask[i] { lambda } else { 0.0 },
            problem.mask,
        );
        let pull = [&st.pull_east[..], &st.pull_south[..]];
        let b_norm = level
            .residual_from(
                |row, _, b| rhs_row(px, pull, prior, row, b),
                Some(&st.x),
                &mut st.r,
            )
            .sqrt();
        let mut hier = Hierarchy::new(level);
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
        (st.east, st.south) = hier.into_fine().into_edges();
        (
            solve.relative_residual * scale / b_norm.max(f64::MIN_POSITIVE),
            levels,
        )
    }
}

/// The arrays of a bilateral solve.
struct State<'c> {
    /// The surface (f32, as the multigrid solver keeps it).
    x: Vec<f32>,
    /// The forward weights (B3) along the columns and the rows; ½ at first (`poisson`'s system).
    plus: [Vec<f32>; 2],
    /// `W_e` of the east and south edges (lent to the solver's finest level while it solves).
    east: Vec<f32>,
    south: Vec<f32>,
    /// `W_e d_e` of the east and south edges.
    pull_east: Vec<f32>,
    pull_south: Vec<f32>,
    /// The residual.
    r: Vec<f32>,
    /// The constants of each component, when no prior fixes them.
    null_space: Option<&'c Components>,
    cg_iterations: usize,
}

impl<'c> State<'c> {
    fn new(problem: &IntegrationProblem, components: &'c Components) -> State<'c> {
        let n = problem.width * problem.height;
        let x = match problem.initial {
            Some(start) => start
                .par_iter()
                .zip(problem.mask.par_iter())
                .map(|(&v, &m)| if m && v.is_finite() { v } else { 0.0 })
                .collect(),
            None => par_zeros(n),
        };
        let has_prior = problem.prior.is_some_and(|pr| pr.lambda > 0.0);
        State {
            x,
            plus: [vec![0.5; n], vec![0.5; n]],
            east: par_zeros(n),
            south: par_zeros(n),
            pull_east: par_zeros(n),
            pull_south: par_zeros(n),
            r: par_zeros(n),
            null_space: (!has_prior).then_some(components),
            cg_iterations: 0,
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

    /// `W_e` and `W_e d_e` of (B4), or of (B5) when `debiased`, for every east and south edge
    /// (0 where the edge leaves the mask): `weight[0]`, `pull[0]` east, `weight[1]`, `pull[1]`
    /// south.
    fn edges(
        &self,
        px: &Pixels,
        plus: [&[f32]; 2],
        debiased: bool,
        weight: [&mut [f32]; 2],
        pull: [&mut [f32]; 2],
    ) {
        let w = px.w;
        let [we, ws] = weight;
        let [pe, ps] = pull;
        we.par_chunks_mut(w)
            .zip(ws.par_chunks_mut(w))
            .zip(pe.par_chunks_mut(w).zip(ps.par_chunks_mut(w)))
            .enumerate()
            .for_each(|(r, ((we, ws), (pe, ps)))| {
                for c in 0..w {
                    let i = r * w + c;
                    for (axis, wo, po) in [(0, &mut we[c], &mut pe[c]), (1, &mut ws[c], &mut ps[c])]
                    {
                        (*wo, *po) = match px.mask[i].then(|| px.next(i, axis)).flatten() {
                            Some(j) => {
                                let pl = plus[axis];
                                let floor = self.min_edge_weight;
                                // (B5) in the last system, (B4) before it.
                                if debiased {
                                    px.debiased_edge(i, j, axis, pl[i], pl[j], floor)
                                } else {
                                    px.edge(i, j, axis, pl[i], pl[j], floor)
                                }
                            }
                            None => (0.0, 0.0),
                        };
                    }
                }
            });
    }

    /// Replaces the forward weights by (B3) of the surface `x`.
    fn update_weights(&self, px: &Pixels, x: &[f32], plus: &mut [Vec<f32>; 2]) {
        let w = px.w;
        let [pu, pv] = plus;
        pu.par_chunks_mut(w)
            .zip(pv.par_chunks_mut(w))
            .enumerate()
            .for_each(|(r, (u_row, v_row))| {
                for c in 0..w {
                    let i = r * w + c;
                    if px.mask[i] {
                        u_row[c] = px.weight_from(self.k, x, i, 0);
                        v_row[c] = px.weight_from(self.k, x, i, 1);
                    }
                }
            });
    }
}

/// Row `r` of `b` in the normal equations of (B4) (+ the prior): `Σ ± W_e d_e` over the
/// cell's edges (`pull`: `W_e d_e` of the east and south edges, 0 where there is none).
fn rhs_row(px: &Pixels, pull: [&[f32]; 2], prior: Option<super::Prior>, r: usize, out: &mut [f64]) {
    let w = px.w;
    let [east, south] = pull;
    for (c, b) in out.iter_mut().enumerate() {
        let i = r * w + c;
        *b = 0.0;
        if !px.mask[i] {
            continue;
        }
        let mut s = -(east[i] as f64) - south[i] as f64;
        if c > 0 {
            s += east[i - 1] as f64;
        }
        if r > 0 {
            s += south[i - w] as f64;
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
    let mut f = vec![0f64; n];
    let mut plus = [vec![0.5f32; n], vec![0.5f32; n]];
    let mut energy = f64::INFINITY;
    let mut reweightings = 0;
    loop {
        // The last pass solves (B5) under the converged weights.
        let last = reweightings >= params.max_iterations;
        // The normal equations of (B4): A f = b, A = Σ_e W_e (1_j − 1_i)(1_j − 1_i)ᵀ + λ I.
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
            for (axis, pl) in plus.iter().enumerate() {
                if let Some(j) = px.next(i, axis) {
                    let floor = params.min_edge_weight;
                    let (we, wd) = if last && params.debias {
                        px.debiased_edge(i, j, axis, pl[i], pl[j], floor) // (B5)
                    } else {
                        px.edge(i, j, axis, pl[i], pl[j], floor)
                    };
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
        jacobi_cg(&apply, &diag, &b, &mut f, px.mask);
        if reweightings >= params.max_iterations {
            break;
        }
        reweightings += 1;
        for (axis, pl) in plus.iter_mut().enumerate() {
            for (i, wp) in pl.iter_mut().enumerate() {
                if px.mask[i] {
                    *wp = px.weight_from(params.k, &f, i, axis); // (B3)
                }
            }
        }
        let new_energy = px.energy(&f, [&plus[0], &plus[1]]); // (B2)
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
