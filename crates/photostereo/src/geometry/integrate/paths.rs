//! `paths`: the paper's path integration (eqs. 11–12), averaged over many paths.
//!
//! From a seed pixel, the "column first" order sums `∂f/∂row` along the seed's column and then
//! `∂f/∂col` along every row from that column (eq. 12); the "row first" order is the transpose.
//! Pixels such an L-shaped path cannot reach inside the mask (non-convex shapes) are reached by
//! further alternating sweeps along rows and columns from the pixels already reached. Each
//! integral is made mean-zero per component, and the integrals from `seeds` seeds per component
//! (spread along the component's scan order) and both orders are averaged.

use super::{
    edge_targets, fill_unreliable, to_depth, Components, Depth, IntegrationProblem,
    IntegrationStats, Integrator, DEFAULT_FILL_BELOW,
};
use crate::base::error::{Error, Result};
use crate::base::progress::Progress;

/// Averaged path integration.
#[derive(Clone, Debug)]
pub struct Paths {
    /// Seeds per connected component (each used with both scan orders).
    pub seeds: usize,
    pub fill_below: f32,
}

impl Default for Paths {
    fn default() -> Self {
        Paths {
            seeds: 4,
            fill_below: DEFAULT_FILL_BELOW,
        }
    }
}

/// One path integral from the given seeds (one per component), column first or row first.
#[allow(clippy::too_many_arguments)]
fn integrate_once(
    w: usize,
    h: usize,
    mask: &[bool],
    dh: &[f32],
    dv: &[f32],
    seeds: &[usize],
    column_first: bool,
    f: &mut [f64],
    reached: &mut [bool],
) {
    reached.fill(false);
    f.fill(0.0);
    // Propagation along one row (horizontal) or one column (vertical) from reached pixels.
    let sweep_row = |r: usize, f: &mut [f64], reached: &mut [bool]| -> bool {
        let mut changed = false;
        let base = r * w;
        for c in 1..w {
            let i = base + c;
            if mask[i] && !reached[i] && reached[i - 1] && mask[i - 1] {
                f[i] = f[i - 1] + dh[i - 1] as f64;
                reached[i] = true;
                changed = true;
            }
        }
        for c in (0..w.saturating_sub(1)).rev() {
            let i = base + c;
            if mask[i] && !reached[i] && reached[i + 1] {
                f[i] = f[i + 1] - dh[i] as f64;
                reached[i] = true;
                changed = true;
            }
        }
        changed
    };
    let sweep_col = |c: usize, f: &mut [f64], reached: &mut [bool]| -> bool {
        let mut changed = false;
        for r in 1..h {
            let i = r * w + c;
            if mask[i] && !reached[i] && reached[i - w] {
                f[i] = f[i - w] + dv[i - w] as f64;
                reached[i] = true;
                changed = true;
            }
        }
        for r in (0..h.saturating_sub(1)).rev() {
            let i = r * w + c;
            if mask[i] && !reached[i] && reached[i + w] {
                f[i] = f[i + w] - dv[i] as f64;
                reached[i] = true;
                changed = true;
            }
        }
        changed
    };
    for &s in seeds {
        reached[s] = true;
        f[s] = 0.0;
    }
    // The first leg of the L: the seeds' own column (or row).
    for &s in seeds {
        if column_first {
            sweep_col(s % w, f, reached);
        } else {
            sweep_row(s / w, f, reached);
        }
    }
    // Second leg, then alternate until every pixel of the components is reached.
    loop {
        let mut changed = false;
        if column_first {
            for r in 0..h {
                changed |= sweep_row(r, f, reached);
            }
            for c in 0..w {
                changed |= sweep_col(c, f, reached);
            }
        } else {
            for c in 0..w {
                changed |= sweep_col(c, f, reached);
            }
            for r in 0..h {
                changed |= sweep_row(r, f, reached);
            }
        }
        if !changed {
            break;
        }
    }
}

impl Integrator for Paths {
    fn name(&self) -> &'static str {
        "paths"
    }

    fn integrate(&self, problem: &IntegrationProblem, progress: &dyn Progress) -> Result<Depth> {
        problem.validate()?;
        if problem.prior.is_some() {
            return Err(Error::invalid(
                "integration method paths takes no depth prior: use poisson or dct",
            ));
        }
        if self.seeds == 0 {
            return Err(Error::invalid("paths: seeds must be at least 1"));
        }
        let (w, h) = (problem.width, problem.height);
        let (p, q, filled) = fill_unreliable(problem, self.fill_below);
        let (dh, dv) = edge_targets(w, h, &p, &q, problem.mask);
        drop(p);
        drop(q);
        let components = Components::of(w, h, problem.mask);
        // Pixels of each component in scan order, to spread the seeds along it.
        let mut members: Vec<Vec<usize>> = vec![Vec::new(); components.count];
        for i in 0..w * h {
            if let Some(l) = components.label(i) {
                members[l].push(i);
            }
        }
        let n = w * h;
        let mut sum = vec![0f64; n];
        let mut f = vec![0f64; n];
        let mut reached = vec![false; n];
        let total = self.seeds * 2;
        progress.begin("integrate", total as u64);
        for k in 0..self.seeds {
            let seeds: Vec<usize> = members
                .iter()
                .map(|m| m[((2 * k + 1) * m.len()) / (2 * self.seeds)])
                .collect();
            for column_first in [true, false] {
                integrate_once(
                    w,
                    h,
                    problem.mask,
                    &dh,
                    &dv,
                    &seeds,
                    column_first,
                    &mut f,
                    &mut reached,
                );
                components.remove_means(&mut f);
                sum.iter_mut().zip(&f).for_each(|(s, v)| *s += v);
                progress.advance(1);
            }
        }
        progress.end();
        sum.iter_mut().for_each(|s| *s /= total as f64);
        let stats = IntegrationStats {
            method: "paths".into(),
            iterations: total,
            components: components.count,
            filled_pixels: filled,
            ..Default::default()
        };
        Ok(to_depth(w, h, &sum, problem.mask, stats))
    }
}
