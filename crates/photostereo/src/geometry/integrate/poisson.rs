//! `poisson`: masked weighted least squares, solved by multigrid-preconditioned CG.

use super::multigrid::{par_zeros, pcg, Hierarchy, Level, Rows};
use super::{
    fill_unreliable, into_depth, to_depth, Components, Depth, IntegrationProblem, IntegrationStats,
    Integrator, Paths, DEFAULT_FILL_BELOW, DEFAULT_MIN_EDGE_WEIGHT, DEFAULT_TOLERANCE,
};
use crate::base::error::Result;
use crate::base::progress::Progress;
use rayon::prelude::*;

/// Where the CG iteration starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum InitialGuess {
    /// f = 0.
    #[default]
    Zero,
    /// The averaged path integral ([`Paths`]), as the paper seeds its global solve.
    Paths,
}

/// Masked least-squares integration (see the module notes of [`crate::geometry::integrate`]).
#[derive(Clone, Debug)]
pub struct Poisson {
    /// Stop when ‖b − A f‖ ≤ tolerance · ‖b‖.
    pub tolerance: f64,
    pub max_iterations: usize,
    /// Pixels with a weight below this get interpolated gradients.
    pub fill_below: f32,
    /// Lower bound of every edge weight.
    pub min_edge_weight: f32,
    /// Red–black Gauss–Seidel sweeps before and after each coarse correction.
    pub smoothing_sweeps: usize,
    pub initial_guess: InitialGuess,
    /// Solve exactly by the DCT when the problem allows it: the mask covers the whole
    /// rectangle, every weight is 1 (or none is given) and any prior is uniform — then the
    /// equations are those of [`Dct`](super::Dct), and a direct O(n log n) solve beats the
    /// iterations. Default true; false forces multigrid-preconditioned CG.
    pub direct_on_rectangle: bool,
}

impl Default for Poisson {
    fn default() -> Self {
        Poisson {
            tolerance: DEFAULT_TOLERANCE,
            max_iterations: 200,
            fill_below: DEFAULT_FILL_BELOW,
            min_edge_weight: DEFAULT_MIN_EDGE_WEIGHT,
            smoothing_sweeps: 1,
            initial_guess: InitialGuess::Zero,
            direct_on_rectangle: true,
        }
    }
}

/// Row `r` of `b` in `A f = b` for `Σ w_e (f_b − f_a − d_e)² + λ Σ (f_i − z_i)²`, from the
/// (filled) gradients and the operator's rows (`op.e`, `op.s`, `op.su`: the edge weights of the
/// row, to the row below and from the row above). Without a prior `A` is singular, one
/// constant per component: `b` sums to zero over each component, CG converges on it, and the
/// caller removes the component means afterwards.
fn rhs_row(
    problem: &IntegrationProblem,
    p: &[f32],
    q: &[f32],
    r: usize,
    op: &Rows,
    out: &mut [f64],
) {
    let (w, h) = (problem.width, problem.height);
    let mask = problem.mask;
    let prior = problem.prior.filter(|pr| pr.lambda > 0.0);
    for (c, b) in out.iter_mut().enumerate() {
        let i = r * w + c;
        if !mask[i] {
            *b = 0.0;
            continue;
        }
        let mut s = 0f64;
        if c + 1 < w && op.e[c] > 0.0 {
            s -= op.e[c] as f64 * 0.5 * (p[i] as f64 + p[i + 1] as f64);
        }
        if c > 0 && op.e[c - 1] > 0.0 {
            s += op.e[c - 1] as f64 * 0.5 * (p[i] as f64 + p[i - 1] as f64);
        }
        if r + 1 < h && op.s[c] > 0.0 {
            s -= op.s[c] as f64 * 0.5 * (q[i] as f64 + q[i + w] as f64);
        }
        if r > 0 && op.su[c] > 0.0 {
            s += op.su[c] as f64 * 0.5 * (q[i] as f64 + q[i - w] as f64);
        }
        if let Some(prior) = prior {
            s += prior.lambda as f64 * prior.depth[i] as f64;
        }
        *b = s;
    }
}

impl Integrator for Poisson {
    fn name(&self) -> &'static str {
        "poisson"
    }

    fn integrate(&self, problem: &IntegrationProblem, progress: &dyn Progress) -> Result<Depth> {
        self.solve(problem, None, progress)
    }
}

impl Poisson {
    /// [`Integrator::integrate`] without a copy of the starting point: `start` (`height *
    /// width`, e.g. the last [`Depth::values`], NaN outside the mask) is taken over, warm-starts
    /// the solve as `problem.initial` would (values outside the mask and non-finite ones are
    /// ignored; `problem.initial` is then not read) and becomes the returned depth's values, so
    /// that the caller holds one depth map rather than two. The result is the same as
    /// `integrate` with `initial: Some(&start)`. The direct solve of a full rectangle ignores
    /// the start (and frees it first).
    pub fn integrate_in_place(
        &self,
        problem: &IntegrationProblem,
        start: Vec<f32>,
        progress: &dyn Progress,
    ) -> Result<Depth> {
        if start.len() != problem.width * problem.height {
            return Err(crate::base::error::Error::invalid(format!(
                "integration: the starting depth has {} values, expected {}×{} = {}",
                start.len(),
                problem.width,
                problem.height,
                problem.width * problem.height
            )));
        }
        self.solve(problem, Some(start), progress)
    }

    fn solve(
        &self,
        problem: &IntegrationProblem,
        start: Option<Vec<f32>>,
        progress: &dyn Progress,
    ) -> Result<Depth> {
        problem.validate()?;
        let (w, h) = (problem.width, problem.height);
        if self.direct_on_rectangle
            && self.min_edge_weight <= 1.0
            && self.fill_below <= 1.0
            && problem.mask.par_iter().all(|&m| m)
            && problem
                .weights
                .is_none_or(|ws| ws.par_iter().all(|&v| v == 1.0))
        {
            drop(start);
            return Ok(self.direct(problem, progress));
        }
        let (p, q, filled) = fill_unreliable(problem, self.fill_below);
        let has_prior = problem.prior.is_some_and(|pr| pr.lambda > 0.0);
        let lambda = if has_prior {
            problem.prior.map_or(0.0, |pr| pr.lambda)
        } else {
            0.0
        };
        let components = Components::of(w, h, problem.mask);
        // The iterate lives in the returned depth map (f32): the starting point, then the
        // solution, then NaN outside the mask.
        let warm = start.is_some() || problem.initial.is_some();
        let mut x: Vec<f32> = match self.initial_guess {
            InitialGuess::Zero if start.is_some() => {
                let mut x = start.unwrap_or_default();
                x.par_iter_mut()
                    .zip(problem.mask.par_iter())
                    .for_each(|(v, &m)| {
                        if !(m && v.is_finite()) {
                            *v = 0.0;
                        }
                    });
                x
            }
            InitialGuess::Zero => match problem.initial {
                Some(start) => start
                    .par_iter()
                    .zip(problem.mask.par_iter())
                    .map(|(&v, &m)| if m && v.is_finite() { v } else { 0.0 })
                    .collect(),
                None => par_zeros(w * h),
            },
            InitialGuess::Paths => {
                let filled_problem = IntegrationProblem {
                    p: &p,
                    q: &q,
                    weights: None,
                    prior: None,
                    ..*problem
                };
                let mut d =
                    Paths::default().integrate(&filled_problem, &crate::base::progress::Silent)?;
                d.values.par_iter_mut().for_each(|v| {
                    if !v.is_finite() {
                        *v = 0.0;
                    }
                });
                d.values
            }
        };
        let start = (self.initial_guess == InitialGuess::Paths || warm).then_some(&x[..]);
        // The normal equations' operator, computed row by row from the mask and weights.
        let level = Level::problem(
            w,
            h,
            problem.mask,
            problem.weights,
            self.min_edge_weight,
            lambda,
        );
        let mut r: Vec<f32> = par_zeros(w * h);
        let b_norm = level
            .residual_from(
                |row, op, b| rhs_row(problem, &p, &q, row, op, b),
                start,
                &mut r,
            )
            .sqrt();
        drop(p);
        drop(q);
        let mut hier = Hierarchy::new(level);
        hier.sweeps = self.smoothing_sweeps.max(1);
        progress.begin("integrate", self.max_iterations as u64);
        let solve = pcg(
            &mut hier,
            &mut r,
            b_norm,
            &mut x,
            (!has_prior).then_some(&components),
            self.tolerance,
            self.max_iterations,
            progress,
        );
        progress.end();
        drop(r);
        if !has_prior {
            components.remove_means(&mut x);
        }
        let mut notes = Vec::new();
        if solve.relative_residual > self.tolerance {
            notes.push(format!(
                "poisson stopped after {} iterations at relative residual {:.2e} (tolerance {:.1e})",
                solve.iterations, solve.relative_residual, self.tolerance
            ));
        }
        let stats = IntegrationStats {
            method: "poisson".into(),
            iterations: solve.iterations,
            relative_residual: solve.relative_residual,
            components: components.count,
            filled_pixels: filled,
            levels: hier.depth(),
            direct: false,
            reweightings: 0,
            notes,
        };
        Ok(into_depth(w, h, x, problem.mask, stats))
    }
}

impl Poisson {
    /// The whole-rectangle, unit-weight case: every edge weight is 1 (`max(1, min_edge_weight)`
    /// with `min_edge_weight ≤ 1`), so `A` is the unit graph Laplacian (plus λ) that the DCT
    /// diagonalises; the solution is exact up to round-off.
    fn direct(&self, problem: &IntegrationProblem, progress: &dyn Progress) -> Depth {
        let (w, h) = (problem.width, problem.height);
        progress.begin("integrate", 1);
        let (p, q) = (problem.p, problem.q);
        let g = |i: usize| (p[i] as f64, q[i] as f64);
        let (f, relative_residual) =
            super::spectral::dct_solve(w, h, g, problem.mask, problem.prior, true);
        progress.advance(1);
        progress.end();
        let mut notes = Vec::new();
        if relative_residual > self.tolerance {
            notes.push(format!(
                "poisson's direct solve ended at relative residual {relative_residual:.2e} (tolerance {:.1e})",
                self.tolerance
            ));
        }
        let stats = IntegrationStats {
            method: "poisson".into(),
            iterations: 0,
            relative_residual,
            components: 1,
            filled_pixels: 0,
            levels: 0,
            direct: true,
            reweightings: 0,
            notes,
        };
        to_depth(w, h, &f, problem.mask, stats)
    }
}
