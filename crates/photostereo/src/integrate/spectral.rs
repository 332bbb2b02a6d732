//! `dct` and `fft`: direct solvers on the full rectangle.
//!
//! Outside the mask the gradients are taken as 0 (a flat apron); the depth is reported inside
//! the mask only, with its mean removed. Unreliable pixels (weight below `fill_below`) get
//! interpolated gradients first; weights above it are not used (these solvers are unweighted).

use super::{
    fill_unreliable, to_depth, Depth, IntegrationProblem, IntegrationStats, Integrator,
    DEFAULT_FILL_BELOW,
};
use crate::error::{Error, Result};
use crate::progress::Progress;
use rayon::prelude::*;
use rustdct::rustfft::num_complex::Complex;
use rustdct::rustfft::FftPlanner;
use rustdct::DctPlanner;

/// Full-rectangle least squares with Neumann boundaries by the discrete cosine transform
/// (Simchony, Chellappa & Shao): the same discrete equations as `poisson` on a full rectangle,
/// solved exactly in O(n log n).
#[derive(Clone, Debug)]
pub struct Dct {
    pub fill_below: f32,
}

impl Default for Dct {
    fn default() -> Self {
        Dct {
            fill_below: DEFAULT_FILL_BELOW,
        }
    }
}

/// Frankot–Chellappa: the surface whose spectral derivatives best fit (p, q) in the Fourier
/// basis, computed on the rectangle mirrored to 2H × 2W (p odd and q even across vertical
/// borders, the reverse across horizontal ones) so that the periodic basis sees no jump in f.
#[derive(Clone, Debug)]
pub struct Fft {
    pub fill_below: f32,
}

impl Default for Fft {
    fn default() -> Self {
        Fft {
            fill_below: DEFAULT_FILL_BELOW,
        }
    }
}

fn masked_gradients(problem: &IntegrationProblem, fill_below: f32) -> (Vec<f32>, Vec<f32>, usize) {
    let (p, q, filled) = fill_unreliable(problem, fill_below);
    let (mut p, mut q) = (p.into_owned(), q.into_owned());
    for i in 0..p.len() {
        if !problem.mask[i] {
            p[i] = 0.0;
            q[i] = 0.0;
        }
    }
    (p, q, filled)
}

fn mean_over_mask(f: &mut [f64], mask: &[bool]) {
    let (s, n) = f
        .iter()
        .zip(mask)
        .filter(|(_, &m)| m)
        .fold((0f64, 0usize), |(s, n), (v, _)| (s + v, n + 1));
    let mean = if n > 0 { s / n as f64 } else { 0.0 };
    f.iter_mut().for_each(|v| *v -= mean);
}

fn notes_for(problem: &IntegrationProblem, name: &str) -> Vec<String> {
    let mut notes = Vec::new();
    if problem.mask.iter().any(|&m| !m) {
        notes.push(format!(
            "{name} solves on the full rectangle with zero gradients outside the mask; depth near the mask border is biased (use poisson for masked inputs)"
        ));
    }
    if problem.weights.is_some() {
        notes.push(format!(
            "{name} is unweighted: only pixels below the fill threshold were treated (interpolated)"
        ));
    }
    notes
}

/// In-place 2-D transform of a row-major `h × w` array: `f` along rows, then along columns.
fn transform_2d(
    data: &mut [f64],
    w: usize,
    h: usize,
    row_op: &(dyn Fn(&mut [f64], &mut [f64]) + Sync),
    col_op: &(dyn Fn(&mut [f64], &mut [f64]) + Sync),
    row_scratch: usize,
    col_scratch: usize,
) {
    data.par_chunks_mut(w)
        .for_each_init(|| vec![0f64; row_scratch], |s, row| row_op(row, s));
    let mut t = vec![0f64; w * h];
    transpose(data, w, h, &mut t);
    t.par_chunks_mut(h)
        .for_each_init(|| vec![0f64; col_scratch], |s, col| col_op(col, s));
    transpose(&t, h, w, data);
}

/// `dst[c * h + r] = src[r * w + c]` for a row-major `h × w` `src`, in cache-sized blocks of
/// columns (a plain column-by-column copy strides through memory a row at a time).
fn transpose(src: &[f64], w: usize, h: usize, dst: &mut [f64]) {
    const BLOCK: usize = 32;
    if w == 0 || h == 0 {
        return;
    }
    dst.par_chunks_mut(BLOCK * h)
        .enumerate()
        .for_each(|(block, out)| {
            let c0 = block * BLOCK;
            let cols = out.len() / h;
            for r0 in (0..h).step_by(BLOCK) {
                let r1 = (r0 + BLOCK).min(h);
                for c in 0..cols {
                    let column = &mut out[c * h..(c + 1) * h];
                    for r in r0..r1 {
                        column[r] = src[r * w + c0 + c];
                    }
                }
            }
        });
}

impl Integrator for Dct {
    fn name(&self) -> &'static str {
        "dct"
    }

    fn integrate(&self, problem: &IntegrationProblem, progress: &dyn Progress) -> Result<Depth> {
        problem.validate()?;
        let (w, h) = (problem.width, problem.height);
        progress.begin("integrate", 1);
        let (p, q, filled) = masked_gradients(problem, self.fill_below);
        let lambda = problem.prior.map_or(0.0, |pr| pr.lambda as f64);
        // Right-hand side of the unit-weight normal equations on the full rectangle.
        let mut b = vec![0f64; w * h];
        b.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
            for (c, v) in row.iter_mut().enumerate() {
                let i = r * w + c;
                let mut s = 0f64;
                if c + 1 < w {
                    s -= 0.5 * (p[i] as f64 + p[i + 1] as f64);
                }
                if c > 0 {
                    s += 0.5 * (p[i] as f64 + p[i - 1] as f64);
                }
                if r + 1 < h {
                    s -= 0.5 * (q[i] as f64 + q[i + w] as f64);
                }
                if r > 0 {
                    s += 0.5 * (q[i] as f64 + q[i - w] as f64);
                }
                if let Some(pr) = problem.prior {
                    if problem.mask[i] {
                        s += lambda * pr.depth[i] as f64;
                    }
                }
                *v = s;
            }
        });
        drop(p);
        drop(q);
        let mut planner = DctPlanner::<f64>::new();
        let (dw, dh) = (planner.plan_dct2(w), planner.plan_dct2(h));
        let (sw, sh) = (dw.get_scratch_len(), dh.get_scratch_len());
        transform_2d(
            &mut b,
            w,
            h,
            &|x, s| dw.process_dct2_with_scratch(x, s),
            &|x, s| dh.process_dct2_with_scratch(x, s),
            sw,
            sh,
        );
        let ew: Vec<f64> = (0..w)
            .map(|k| 2.0 - 2.0 * (std::f64::consts::PI * k as f64 / w as f64).cos())
            .collect();
        let eh: Vec<f64> = (0..h)
            .map(|k| 2.0 - 2.0 * (std::f64::consts::PI * k as f64 / h as f64).cos())
            .collect();
        let scale = 4.0 / (w as f64 * h as f64);
        b.par_chunks_mut(w).enumerate().for_each(|(l, row)| {
            for (k, v) in row.iter_mut().enumerate() {
                let e = ew[k] + eh[l] + lambda;
                *v = if e > 0.0 { *v * scale / e } else { 0.0 };
            }
        });
        transform_2d(
            &mut b,
            w,
            h,
            &|x, s| dw.process_dct3_with_scratch(x, s),
            &|x, s| dh.process_dct3_with_scratch(x, s),
            sw,
            sh,
        );
        if lambda == 0.0 {
            mean_over_mask(&mut b, problem.mask);
        }
        progress.advance(1);
        progress.end();
        let stats = IntegrationStats {
            method: "dct".into(),
            components: super::Components::of(w, h, problem.mask).count,
            filled_pixels: filled,
            notes: notes_for(problem, "dct"),
            ..Default::default()
        };
        Ok(to_depth(w, h, &b, problem.mask, stats))
    }
}

impl Integrator for Fft {
    fn name(&self) -> &'static str {
        "fft"
    }

    fn integrate(&self, problem: &IntegrationProblem, progress: &dyn Progress) -> Result<Depth> {
        problem.validate()?;
        if problem.prior.is_some() {
            return Err(Error::invalid(
                "integration method fft takes no depth prior: use poisson or dct",
            ));
        }
        let (w, h) = (problem.width, problem.height);
        progress.begin("integrate", 1);
        let (p, q, filled) = masked_gradients(problem, self.fill_below);
        let (w2, h2) = (2 * w, 2 * h);
        let kw = w + 1; // non-negative row frequencies of a real FFT of length 2w
        let mut real_planner = realfft::RealFftPlanner::<f64>::new();
        let r2c = real_planner.plan_fft_forward(w2);
        let c2r = real_planner.plan_fft_inverse(w2);
        let mut planner = FftPlanner::<f64>::new();
        let col_fwd = planner.plan_fft_forward(h2);
        let col_inv = planner.plan_fft_inverse(h2);
        // Spectrum of the mirrored field, stored transposed: `spec[k * h2 + l]`.
        let spectrum = |g: &[f32], odd_in_col: bool| -> Vec<Complex<f64>> {
            let mut rows = vec![Complex::new(0f64, 0f64); h2 * kw];
            rows.par_chunks_mut(kw).enumerate().for_each_init(
                || (r2c.make_input_vec(), r2c.make_scratch_vec()),
                |(input, scratch), (l, out)| {
                    // Mirror rows: row l of the extended field is row l (l < h) or 2h−1−l.
                    let (r, row_sign) = if l < h {
                        (l, 1.0)
                    } else {
                        (2 * h - 1 - l, if odd_in_col { 1.0 } else { -1.0 })
                    };
                    for c in 0..w {
                        let v = g[r * w + c] as f64 * row_sign;
                        input[c] = v;
                        input[w2 - 1 - c] = if odd_in_col { -v } else { v };
                    }
                    // Errors only arise from wrong buffer lengths, which the plan guarantees.
                    let _ = r2c.process_with_scratch(input, out, scratch);
                },
            );
            let mut t = vec![Complex::new(0f64, 0f64); kw * h2];
            t.par_chunks_mut(h2).enumerate().for_each_init(
                || vec![Complex::new(0f64, 0f64); col_fwd.get_inplace_scratch_len()],
                |scratch, (k, col)| {
                    for (l, v) in col.iter_mut().enumerate() {
                        *v = rows[l * kw + k];
                    }
                    col_fwd.process_with_scratch(col, scratch);
                },
            );
            t
        };
        // p = ∂f/∂col is odd across vertical borders and even across horizontal ones; q the reverse.
        let sp = spectrum(&p, true);
        drop(p);
        let mut sq = spectrum(&q, false);
        drop(q);
        let two_pi = 2.0 * std::f64::consts::PI;
        sq.par_chunks_mut(h2).enumerate().for_each(|(k, col)| {
            let wx = two_pi * k as f64 / w2 as f64;
            for (l, v) in col.iter_mut().enumerate() {
                let ls = if l <= h {
                    l as f64
                } else {
                    l as f64 - h2 as f64
                };
                let wy = two_pi * ls / h2 as f64;
                let d = wx * wx + wy * wy;
                if d == 0.0 || k == w || l == h {
                    *v = Complex::new(0.0, 0.0);
                    continue;
                }
                let num = sp[k * h2 + l] * wx + *v * wy;
                // F = −i (ωx P + ωy Q) / (ωx² + ωy²)
                *v = Complex::new(num.im, -num.re) / d;
            }
        });
        drop(sp);
        sq.par_chunks_mut(h2).for_each_init(
            || vec![Complex::new(0f64, 0f64); col_inv.get_inplace_scratch_len()],
            |scratch, col| col_inv.process_with_scratch(col, scratch),
        );
        let scale = 1.0 / (w2 as f64 * h2 as f64);
        let mut f = vec![0f64; w * h];
        f.par_chunks_mut(w).enumerate().for_each_init(
            || {
                (
                    c2r.make_input_vec(),
                    c2r.make_output_vec(),
                    c2r.make_scratch_vec(),
                )
            },
            |(input, output, scratch), (r, row)| {
                for (k, v) in input.iter_mut().enumerate() {
                    *v = sq[k * h2 + r];
                }
                input[0].im = 0.0;
                input[kw - 1].im = 0.0;
                let _ = c2r.process_with_scratch(input, output, scratch);
                for (c, v) in row.iter_mut().enumerate() {
                    *v = output[c] * scale;
                }
            },
        );
        mean_over_mask(&mut f, problem.mask);
        progress.advance(1);
        progress.end();
        let stats = IntegrationStats {
            method: "fft".into(),
            components: super::Components::of(w, h, problem.mask).count,
            filled_pixels: filled,
            notes: notes_for(problem, "fft"),
            ..Default::default()
        };
        Ok(to_depth(w, h, &f, problem.mask, stats))
    }
}

#[cfg(test)]
mod tests {
    use super::transpose;

    /// The blocked transpose equals the element-by-element definition on sizes that are not
    /// multiples of the block, and transposing twice gives the input back.
    #[test]
    fn blocked_transpose_matches_the_definition() {
        for (w, h) in [(1, 1), (37, 70), (64, 33), (100, 1), (1, 45)] {
            let src: Vec<f64> = (0..w * h).map(|i| i as f64 * 0.5 - 7.0).collect();
            let mut t = vec![f64::NAN; w * h];
            transpose(&src, w, h, &mut t);
            for r in 0..h {
                for c in 0..w {
                    assert_eq!(t[c * h + r], src[r * w + c], "{w}×{h} at ({r}, {c})");
                }
            }
            let mut back = vec![f64::NAN; w * h];
            transpose(&t, h, w, &mut back);
            assert_eq!(back, src);
        }
    }
}
