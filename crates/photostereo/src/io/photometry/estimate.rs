//! What the readings themselves say about their photometry.
//!
//! **Response.** A Lambertian surface lit by every light reads `x_k = s_k · ρ n · l_k`: across
//! the lights, a pixel's linear readings lie in the 3-D subspace the light vectors span. Read
//! through the wrong response they do not (a power of a sum is no sum of powers). A candidate
//! response is scored by how well a rank-3 model `x_rk ≈ g_k l_k · b_r` fits the readings it
//! makes linear, its subspace the one the given light directions `l_k` span: the gains `g_k`
//! (each light's brightness as the readings see it) and `b` (one per pixel and channel) are
//! fitted by alternating weighted least squares, each residual weighted by the
//! noise of its encoded value (the quantisation step) carried through the candidate's slope:
//! the residuals are measured where the noise is, in the file's own units, so the candidates'
//! scores are comparable χ² values. (Measured relative to the linear values instead, a
//! response that flattens every reading towards one value would fit best.) The subspace is
//! anchored on the lights rather than fitted freely: with lights around the viewing direction
//! any smooth function of `n · l` is nearly affine in the light's direction, so a freely fitted
//! rank-3 model absorbs a compressive response as a constant and cannot tell it from linear. The score is the median over pixels of the reduced χ² (a few
//! highlights do not move it). Candidates: powers 1 to 3 in steps of 0.02 and sRGB. The
//! estimate's spread is that of the best power over eight disjoint sets of pixels; sRGB is
//! chosen when it fits better than every power, linear when 1 lies within the 99% interval of
//! the best power.
//!
//! Only pixels lit by every light ([`lit_rows`]) enter: a shadowed reading is no projection of
//! the normal.
//!
//! The test cannot tell a response from a material whose brightness falls off with `n · l`
//! other than linearly: `(n · l)^p` through a linear camera reads like a Lambertian surface
//! through a power `p`. On real objects the estimate is therefore biased towards the
//! material's falloff (a 2.2 power on DiLiGenT's cat is estimated at 1.8); on matte ones it
//! holds within ±0.1.
//!
//! **Offset.** Light left on in the room, or a black level not removed, adds to every image
//! the same amount per pixel: readings `x_k = s_k (ρ n · l_k + a)`, a fourth dimension the
//! Lambertian model lacks. [`offset_check`] fits it at each pixel and reports the median
//! offset relative to the pixel's mean reading, with its spread over disjoint pixel sets. The
//! closer the lights lie to a cone around one axis, the more an offset looks like a tilt of
//! the normal towards that axis, and the more any misfit of the model feigns one: an offset is
//! reported when it exceeds the model's relative error κ divided by how far its pattern lies
//! from the lights' span.

use super::Response;
use rayon::prelude::*;
use serde::Serialize;

/// Encoded (not yet linear) readings of some pixels of a capture.
#[derive(Clone, Debug)]
pub struct Samples {
    /// `[row][image]`: one row per pixel and channel.
    pub encoded: Vec<f32>,
    /// The ambient frame's encoded value per row, when there is one.
    pub ambient: Option<Vec<f32>>,
    pub images: usize,
    /// Bits per sample of the encoded values (8, 16; 32 for float data).
    pub bit_depth: u8,
}

impl Samples {
    fn rows(&self) -> usize {
        self.encoded.len() / self.images.max(1)
    }
}

/// The response the capture shows, with its uncertainty (report.json
/// `photometry.response_estimate`).
#[derive(Clone, Debug, Serialize)]
pub struct ResponseEstimate {
    /// The response chosen: `linear`, `srgb` or `gamma:G`.
    pub chosen: String,
    /// The best power law's exponent.
    pub gamma: f64,
    /// Its standard error (from disjoint pixel sets).
    pub gamma_std: f64,
    /// Median reduced χ² of the rank-3 fit under the best power, sRGB, and linear.
    pub score_gamma: f64,
    pub score_srgb: f64,
    pub score_linear: f64,
    /// Pixel-channel rows lit by every light that were used.
    pub rows: usize,
    #[serde(skip)]
    pub response: Response,
}

/// The relative model error the detector's noise model uses by default (κ).
const KAPPA: f64 = 0.01;
/// Disjoint pixel sets for the estimates' spread.
const GROUPS: usize = 8;
/// Student's t quantile 0.995 with 7 degrees of freedom (the spread of [`GROUPS`] estimates):
/// the exponent is taken as 1 (linear) when it lies within this many standard errors of it,
/// a two-sided 99% interval.
const T7_995: f64 = 3.499;

/// The candidates' exponents: 1 to 3 in steps of 0.02. Files are encoded to spend their levels
/// on the dark end (exponents above 1); none below 1 is searched, because a surface darker than
/// Lambertian at grazing light reads like one (DiLiGenT's bear and cat, linear, score best
/// at 0.6 and 0.8).
fn gamma_grid() -> Vec<f64> {
    (0..=100).map(|i| 1.0 + 0.02 * i as f64).collect()
}

/// The rows (pixel-channel) lit by every light: every encoded reading at least a quarter of
/// the row's brightest and five quantisation levels above black (0.5% of full scale for float
/// data), none above 99% of full scale. Under any response that brightens the dark end no
/// more than a 2.2 power does, a quarter of the brightest encoded reading is more than 4% of
/// its light: a shadow, which reads only noise or ambient light, falls below it.
pub fn lit_rows(s: &Samples) -> Vec<usize> {
    let level: f64 = match s.bit_depth {
        8 => 1.0 / 255.0,
        16 => 1.0 / 65535.0,
        _ => 0.001,
    };
    let lo = (5.0 * level).max(0.005) as f32;
    (0..s.rows())
        .filter(|&r| {
            let row = &s.encoded[r * s.images..(r + 1) * s.images];
            let max = row.iter().cloned().fold(0.0f32, f32::max);
            row.iter().all(|&e| e >= lo.max(0.25 * max) && e <= 0.99)
        })
        .collect()
}

/// Estimates the capture's response from `s`: `lights` are the given light vectors (intensity
/// included), `scale[k]` what image k's linear readings are multiplied by (1 / its exposure
/// factor), `ambient_scale` the same for the ambient frame. `None` with fewer than five images
/// or fewer than 30 rows lit by every light (too little to tell).
pub fn estimate_response(
    s: &Samples,
    lights: &[[f64; 3]],
    scale: &[f64],
    ambient_scale: f64,
) -> Option<ResponseEstimate> {
    let rows = lit_rows(s);
    if s.images < 5 || rows.len() < 30 {
        return None;
    }
    let grid = gamma_grid();
    let mut candidates: Vec<Response> = grid.iter().map(|&g| Response::Gamma(g)).collect();
    candidates.push(Response::Srgb);
    let fit = Fit {
        s,
        rows: &rows,
        lights,
        scale,
        ambient_scale,
    };
    // Per candidate, each row's reduced χ².
    let chi: Vec<Vec<f64>> = candidates.par_iter().map(|&r| fit.row_chi2(r)).collect();
    let score = |c: &[f64], group: Option<usize>| -> f64 {
        let mut v: Vec<f64> = c
            .iter()
            .enumerate()
            .filter(|(i, _)| group.is_none_or(|g| i % GROUPS == g))
            .map(|(_, x)| *x)
            .collect();
        median(&mut v)
    };
    let best = |group: Option<usize>| -> usize {
        (0..grid.len())
            .min_by(|&a, &b| score(&chi[a], group).total_cmp(&score(&chi[b], group)))
            .unwrap_or(0)
    };
    let b = best(None);
    let group_best: Vec<f64> = (0..GROUPS).map(|g| grid[best(Some(g))]).collect();
    let mean = group_best.iter().sum::<f64>() / GROUPS as f64;
    let var = group_best.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / (GROUPS - 1) as f64;
    // The grid's own resolution bounds how small the error can be.
    let gamma_std = (var / GROUPS as f64).sqrt().max(0.02 / 12f64.sqrt());
    let gamma = grid[b];
    let score_gamma = score(&chi[b], None);
    let score_srgb = score(&chi[grid.len()], None);
    let linear = grid
        .iter()
        .position(|g| (g - 1.0).abs() < 1e-9)
        .unwrap_or(0);
    let score_linear = score(&chi[linear], None);
    let response = if score_srgb < score_gamma {
        Response::Srgb
    } else if (gamma - 1.0).abs() <= T7_995 * gamma_std {
        Response::Linear
    } else {
        Response::Gamma(gamma)
    };
    Some(ResponseEstimate {
        chosen: response.name(),
        gamma,
        gamma_std,
        score_gamma,
        score_srgb,
        score_linear,
        rows: rows.len(),
        response,
    })
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    *v.select_nth_unstable_by(m, f64::total_cmp).1
}

/// The rank-3 fit of a candidate response.
struct Fit<'a> {
    s: &'a Samples,
    rows: &'a [usize],
    lights: &'a [[f64; 3]],
    scale: &'a [f64],
    ambient_scale: f64,
}

impl Fit<'_> {
    /// Linear readings and their weights (1 / variance) of every used row under `r`.
    fn linear(&self, r: Response) -> (Vec<f64>, Vec<f64>) {
        let n = self.s.images;
        let q = match self.s.bit_depth {
            8 => 1.0 / 255.0,
            16 => 1.0 / 65535.0,
            _ => 1e-4,
        } / 12f64.sqrt();
        let mut x = Vec::with_capacity(self.rows.len() * n);
        let mut w = Vec::with_capacity(self.rows.len() * n);
        for &row in self.rows {
            let (a, va) = match &self.s.ambient {
                Some(amb) => {
                    let e = amb[row] as f64;
                    (
                        r.linear(e) * self.ambient_scale,
                        (r.slope(e) * self.ambient_scale * q).powi(2),
                    )
                }
                None => (0.0, 0.0),
            };
            for k in 0..n {
                let e = self.s.encoded[row * n + k] as f64;
                let v = r.linear(e) * self.scale[k] - a;
                let var = (r.slope(e) * self.scale[k] * q).powi(2) + va;
                x.push(v);
                w.push(1.0 / var.max(1e-30));
            }
        }
        (x, w)
    }

    /// Each used row's reduced χ² under the rank-3 model fitted to the readings `r` makes.
    fn row_chi2(&self, r: Response) -> Vec<f64> {
        let n = self.s.images;
        let (x, w) = self.linear(r);
        let mut u: Vec<[f64; 3]> = self.lights.to_vec();
        let mut b = vec![[0.0; 3]; self.rows.len()];
        for _ in 0..3 {
            for (i, bi) in b.iter_mut().enumerate() {
                let xs = &x[i * n..(i + 1) * n];
                let ws = &w[i * n..(i + 1) * n];
                *bi = solve_weighted(u.iter().zip(xs).zip(ws).map(|((u, x), w)| (*u, *x, *w)));
            }
            // Each light's gain (its brightness and exposure, as the readings see them); its
            // direction stays the given one.
            for (k, uk) in u.iter_mut().enumerate() {
                let (mut num, mut den) = (0.0, 0.0);
                for (i, bi) in b.iter().enumerate() {
                    let p = dot(self.lights[k], *bi);
                    num += w[i * n + k] * x[i * n + k] * p;
                    den += w[i * n + k] * p * p;
                }
                let g = if den > 0.0 { num / den } else { 1.0 };
                *uk = self.lights[k].map(|v| v * g);
            }
        }
        b.iter()
            .enumerate()
            .map(|(i, bi)| {
                let chi: f64 = (0..n)
                    .map(|k| {
                        let d = x[i * n + k] - dot(u[k], *bi);
                        d * d * w[i * n + k]
                    })
                    .sum();
                chi / (n - 3) as f64
            })
            .collect()
    }
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The 3-vector `v` minimising Σ w (y − a · v)² over `(a, y, w)`; zero when singular.
fn solve_weighted(terms: impl Iterator<Item = ([f64; 3], f64, f64)>) -> [f64; 3] {
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut rhs = nalgebra::Vector3::<f64>::zeros();
    for (a, y, w) in terms {
        let a = nalgebra::Vector3::from(a);
        m += w * a * a.transpose();
        rhs += w * y * a;
    }
    m.cholesky()
        .map(|c| {
            let v = c.solve(&rhs);
            [v[0], v[1], v[2]]
        })
        .unwrap_or([0.0; 3])
}

/// A constant per-pixel offset across lights, measured on linear readings (report.json
/// `photometry.offset_check`).
#[derive(Clone, Debug, Serialize)]
pub struct OffsetCheck {
    /// Median over pixels of the fitted offset relative to the pixel's mean reading.
    pub relative_offset: f64,
    /// Its standard error (from disjoint pixel sets).
    pub std_error: f64,
    /// Pixel-channel rows lit by every light that were used.
    pub rows: usize,
    /// How far an offset's pattern across the lights lies from the lights' span: the sine of
    /// the angle between them (0: an offset reads as a change of normal, 1: fully distinct).
    pub separation: f64,
    /// Whether the offset is positive (light added: a negative one is what surfaces darker
    /// than Lambertian at grazing light show, as DiLiGenT's objects do), significant (beyond
    /// three standard errors) and larger than what the model's relative error κ can feign
    /// through the lights' geometry, κ / separation.
    pub detected: bool,
}

/// Fits `x_k = l_k · b + a · c_k` at each row of linear readings `x` (`[row][light]`, lit by
/// every light), where `c_k` is what light k's readings were multiplied by (a constant offset
/// in the files is `a · c_k` in the readings), and reports the median of `a` over the row's
/// mean reading. `None` with fewer than five lights or 30 rows.
pub fn offset_check(x: &[f64], lights: &[[f64; 3]], c: &[f64]) -> Option<OffsetCheck> {
    let n = lights.len();
    let rows = x.len() / n.max(1);
    if n < 5 || rows < 30 {
        return None;
    }
    let design: Vec<nalgebra::Vector4<f64>> = lights
        .iter()
        .zip(c)
        .map(|(l, c)| nalgebra::Vector4::new(l[0], l[1], l[2], *c))
        .collect();
    let mut ata = nalgebra::Matrix4::<f64>::zeros();
    for d in &design {
        ata += d * d.transpose();
    }
    let inv = ata.try_inverse()?;
    // The part of the offset pattern c outside the lights' span.
    let mut ltl = nalgebra::Matrix3::<f64>::zeros();
    let mut ltc = nalgebra::Vector3::<f64>::zeros();
    for (l, ck) in lights.iter().zip(c) {
        let l = nalgebra::Vector3::from(*l);
        ltl += l * l.transpose();
        ltc += *ck * l;
    }
    let coef = ltl.try_inverse()? * ltc;
    let (mut outside, mut total) = (0.0, 0.0);
    for (l, ck) in lights.iter().zip(c) {
        let r = ck - (l[0] * coef[0] + l[1] * coef[1] + l[2] * coef[2]);
        outside += r * r;
        total += ck * ck;
    }
    let separation = (outside / total.max(1e-300)).sqrt();
    let rel: Vec<f64> = (0..rows)
        .map(|r| {
            let xs = &x[r * n..(r + 1) * n];
            let mut atb = nalgebra::Vector4::<f64>::zeros();
            for (d, v) in design.iter().zip(xs) {
                atb += d * *v;
            }
            let mean = xs.iter().sum::<f64>() / n as f64;
            let mean_c = c.iter().sum::<f64>() / n as f64;
            (inv * atb)[3] * mean_c / mean.max(1e-12)
        })
        .collect();
    let mut all = rel.clone();
    let m = median(&mut all);
    let groups: Vec<f64> = (0..GROUPS)
        .map(|g| {
            let mut v: Vec<f64> = rel.iter().skip(g).step_by(GROUPS).copied().collect();
            median(&mut v)
        })
        .collect();
    let gm = groups.iter().sum::<f64>() / GROUPS as f64;
    let var = groups.iter().map(|v| (v - gm).powi(2)).sum::<f64>() / (GROUPS - 1) as f64;
    let se = (var / GROUPS as f64).sqrt();
    Some(OffsetCheck {
        relative_offset: m,
        std_error: se,
        rows,
        separation,
        detected: m > 3.0 * se && m * separation > KAPPA,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Pcg32;

    /// Lights on a grid in front of the camera, as a dome or DiLiGenT's rig.
    fn lights() -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        for i in -2..=2 {
            for j in -2..=2 {
                let (x, y) = (0.25 * i as f64, 0.25 * j as f64);
                let z = 1.0f64;
                let n = (x * x + y * y + z * z).sqrt();
                v.push([x / n, y / n, z / n]);
            }
        }
        v
    }

    /// Lambertian readings of random normals within 30° of the view (lit by every light),
    /// offset by `ambient`, encoded by `r` into `bits`-bit levels.
    fn samples(r: Response, bits: u8, ambient: f64, seed: u64) -> Samples {
        let l = lights();
        let mut rng = Pcg32::new(seed, 0);
        let levels = ((1u32 << bits) - 1) as f64;
        let mut encoded = Vec::new();
        for _ in 0..2000 {
            let (a, t) = (rng.next_f64() * 0.5, rng.next_f64() * std::f64::consts::TAU);
            let n = [a.sin() * t.cos(), a.sin() * t.sin(), a.cos()];
            let rho = 0.3 + 0.6 * rng.next_f64();
            for lk in &l {
                let x = (rho * dot(n, *lk) + ambient).min(1.0);
                encoded.push(((r.encode(x) * levels).round() / levels) as f32);
            }
        }
        Samples {
            encoded,
            ambient: None,
            images: l.len(),
            bit_depth: bits,
        }
    }

    #[test]
    fn the_response_is_recovered_on_analytic_scenes() {
        let l = lights();
        let ones = vec![1.0; l.len()];
        for (truth, seed) in [
            (Response::Gamma(2.2), 1),
            (Response::Gamma(1.8), 2),
            (Response::Gamma(2.6), 3),
        ] {
            let e = estimate_response(&samples(truth, 8, 0.0, seed), &l, &ones, 1.0).unwrap();
            let Response::Gamma(g) = e.response else {
                panic!("{truth:?}: {e:?}")
            };
            let Response::Gamma(t) = truth else {
                unreachable!()
            };
            assert!((g - t).abs() <= 0.1, "{truth:?}: {e:?}");
        }
        let e = estimate_response(&samples(Response::Srgb, 8, 0.0, 4), &l, &ones, 1.0).unwrap();
        assert_eq!(e.response, Response::Srgb, "{e:?}");
        for bits in [8, 16] {
            let e = estimate_response(&samples(Response::Linear, bits, 0.0, 5), &l, &ones, 1.0)
                .unwrap();
            assert_eq!(e.response, Response::Linear, "{bits}-bit: {e:?}");
        }
    }

    #[test]
    fn an_offset_is_found_where_there_is_one() {
        let l = lights();
        let ones = vec![1.0; l.len()];
        for (ambient, expect) in [(0.0, false), (0.15, true)] {
            let s = samples(Response::Linear, 16, ambient, 7);
            let x: Vec<f64> = s.encoded.iter().map(|&v| v as f64).collect();
            let c = offset_check(&x, &l, &ones).unwrap();
            assert_eq!(c.detected, expect, "ambient {ambient}: {c:?}");
        }
    }
}
