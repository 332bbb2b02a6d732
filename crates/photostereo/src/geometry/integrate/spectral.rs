//! `dct` and `fft`: direct solvers on the full rectangle.
//!
//! Outside the mask the gradients are taken as 0 (a flat apron); the depth is reported inside
//! the mask only, with its mean removed. Unreliable pixels (weight below `fill_below`) get
//! interpolated gradients first; weights above it are not used (these solvers are unweighted).

use super::{
    fill_unreliable, to_depth, Depth, IntegrationProblem, IntegrationStats, Integrator,
    DEFAULT_FILL_BELOW,
};
use crate::base::error::{Error, Result};
use crate::base::progress::Progress;
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
    p.par_iter_mut()
        .zip(q.par_iter_mut())
        .zip(problem.mask.par_iter())
        .for_each(|((p, q), &m)| {
            if !m {
                *p = 0.0;
                *q = 0.0;
            }
        });
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

/// The unit-weight normal equations of the trapezoid edge targets on the full `w × h`
/// rectangle, `(L + λ) f = b`, solved exactly by the DCT (Neumann boundary): `g(i)` gives the
/// gradients `(p, q)` of pixel `i` (0 outside the mask: the flat apron), `prior` adds `λ · z_i`
/// to `b` inside `mask`. Without a prior (λ = 0) the solution has zero mean over `mask`. With
/// `residual`, also returns the true relative residual `‖b − (L + λ) f‖ / ‖b‖` (f64).
///
/// Two transposes: DCT-II along rows, transpose, DCT-II along columns, the division by the
/// eigenvalues, DCT-III along columns (still transposed), transpose back, DCT-III along rows.
pub(super) fn dct_solve<G: Fn(usize) -> (f64, f64) + Sync>(
    w: usize,
    h: usize,
    g: G,
    mask: &[bool],
    prior: Option<super::Prior>,
    residual: bool,
) -> (Vec<f64>, f64) {
    let lambda = prior.map_or(0.0, |pr| pr.lambda as f64);
    // Row r of b (see `Dct`): −div of the edge targets, plus the prior's pull; `rows` is a
    // scratch of 4 · w values (p of row r, q of rows r − 1, r, r + 1; 0 beyond the grid).
    let rhs_row = |r: usize, rows: &mut [f64], out: &mut [f64]| {
        let (pr, rest) = rows.split_at_mut(w);
        let (qu, rest) = rest.split_at_mut(w);
        let (qm, qd) = rest.split_at_mut(w);
        let lo = r * w;
        for c in 0..w {
            let (p, q) = g(lo + c);
            pr[c] = p;
            qm[c] = q;
            qu[c] = if r > 0 { g(lo + c - w).1 } else { 0.0 };
            qd[c] = if r + 1 < h { g(lo + c + w).1 } else { 0.0 };
        }
        for c in 0..w {
            let mut s = 0f64;
            if c + 1 < w {
                s -= 0.5 * (pr[c] + pr[c + 1]);
            }
            if c > 0 {
                s += 0.5 * (pr[c] + pr[c - 1]);
            }
            if r + 1 < h {
                s -= 0.5 * (qm[c] + qd[c]);
            }
            if r > 0 {
                s += 0.5 * (qm[c] + qu[c]);
            }
            out[c] = s;
        }
        if let Some(pr) = prior {
            for c in 0..w {
                if mask[lo + c] {
                    out[c] += lambda * pr.depth[lo + c] as f64;
                }
            }
        }
    };
    let mut planner = DctPlanner::<f64>::new();
    let (dw, dh) = (planner.plan_dct2(w), planner.plan_dct2(h));
    let (sw, sh) = (dw.get_scratch_len(), dh.get_scratch_len());
    // b row by row, each row transformed while it is in cache; ‖b‖² on the way.
    let mut f: Vec<f64> = super::multigrid::par_zeros(w * h);
    let b_sq: f64 = f
        .par_chunks_mut(w)
        .enumerate()
        .map_init(
            || (vec![0f64; sw], vec![0f64; 4 * w]),
            |(scratch, rows), (r, row)| {
                rhs_row(r, rows, row);
                let sq = row.iter().map(|v| v * v).sum::<f64>();
                dw.process_dct2_with_scratch(row, scratch);
                sq
            },
        )
        .collect::<Vec<f64>>()
        .into_iter()
        .sum();
    let mut t: Vec<f64> = super::multigrid::par_zeros(w * h);
    transpose(&f, w, h, &mut t);
    // Column k of the transposed array holds row frequency l at t[k * h + l].
    let eh: Vec<f64> = (0..h)
        .map(|k| 2.0 - 2.0 * (std::f64::consts::PI * k as f64 / h as f64).cos())
        .collect();
    let scale = 4.0 / (w as f64 * h as f64);
    t.par_chunks_mut(h).enumerate().for_each_init(
        || vec![0f64; sh],
        |scratch, (k, col)| {
            dh.process_dct2_with_scratch(col, scratch);
            let ew = 2.0 - 2.0 * (std::f64::consts::PI * k as f64 / w as f64).cos();
            for (v, &e) in col.iter_mut().zip(&eh) {
                let e = ew + e + lambda;
                *v = if e > 0.0 { *v * scale / e } else { 0.0 };
            }
            dh.process_dct3_with_scratch(col, scratch);
        },
    );
    transpose(&t, h, w, &mut f);
    drop(t);
    let (sum, count) = f
        .par_chunks_mut(w)
        .zip(mask.par_chunks(w))
        .map_init(
            || vec![0f64; sw],
            |scratch, (row, m)| {
                dw.process_dct3_with_scratch(row, scratch);
                row.iter()
                    .zip(m)
                    .filter(|(_, &m)| m)
                    .fold((0f64, 0usize), |(s, n), (v, _)| (s + v, n + 1))
            },
        )
        .collect::<Vec<_>>()
        .into_iter()
        .fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    if lambda == 0.0 && count > 0 {
        let mean = sum / count as f64;
        f.par_iter_mut().for_each(|v| *v -= mean);
    }
    if !residual || b_sq == 0.0 {
        return (f, 0.0);
    }
    let res_sq: f64 = (0..h)
        .into_par_iter()
        .map_init(
            || (vec![0f64; 4 * w], vec![0f64; w]),
            |(rows, b), r| {
                rhs_row(r, rows, b);
                let mut sq = 0f64;
                for (c, &bc) in b.iter().enumerate() {
                    let i = r * w + c;
                    let mut a = lambda * f[i];
                    if c + 1 < w {
                        a += f[i] - f[i + 1];
                    }
                    if c > 0 {
                        a += f[i] - f[i - 1];
                    }
                    if r + 1 < h {
                        a += f[i] - f[i + w];
                    }
                    if r > 0 {
                        a += f[i] - f[i - w];
                    }
                    let d = bc - a;
                    sq += d * d;
                }
                sq
            },
        )
        .collect::<Vec<f64>>()
        .into_iter()
        .sum();
    (f, (res_sq / b_sq).sqrt())
}

impl Integrator for Dct {
    fn name(&self) -> &'static str {
        "dct"
    }

    fn integrate(&self, problem: &IntegrationProblem, progress: &dyn Progress) -> Result<Depth> {
        problem.validate()?;
        let (w, h) = (problem.width, problem.height);
        progress.begin("integrate", 1);
        let (p, q, filled) = fill_unreliable(problem, self.fill_below);
        let mask = problem.mask;
        let g = |i: usize| {
            if mask[i] {
                (p[i] as f64, q[i] as f64)
            } else {
                (0.0, 0.0)
            }
        };
        let (f, _) = dct_solve(w, h, g, mask, problem.prior, false);
        drop((p, q));
        progress.advance(1);
        progress.end();
        let stats = IntegrationStats {
            method: "dct".into(),
            components: super::Components::of(w, h, problem.mask).count,
            filled_pixels: filled,
            notes: notes_for(problem, "dct"),
            ..Default::default()
        };
        Ok(to_depth(w, h, &f, problem.mask, stats))
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
