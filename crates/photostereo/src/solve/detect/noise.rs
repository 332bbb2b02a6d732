//! The noise model of the grey readings, σ_p² = σ₀² + (κ · Ī_p)² with a per-light factor
//! (ALGORITHMS.md §2), and its parts measured on the capture: the sensor noise σ₀ of the
//! images ([`image_noise`]) or of the least-squares residuals, and the dark floor a shadowed
//! reading reads ([`dark_floor`]). κ itself is measured in [`super::kappa`].

use super::attribution::{attribute_all, AttributionBuffers};
use super::chi2::{least_squares_rss, ChiSquareTest};
use super::kappa::{estimate_kappa, estimate_kappa_weighted, light_noise_factors};
use super::params::{DetectionParams, NoiseEstimate};
use crate::base::error::Result;
use crate::base::progress::Progress;
use crate::base::stats::chi2_quantile;
use crate::model::capture::Capture;
use crate::solve::lambert::channel_mean;
use rayon::prelude::*;
use serde::Serialize;

/// Noise of the grey (channel-mean) intensities: σ_p² = σ₀² + (κ · level)², times the light's
/// factor squared for light k's reading (`light_factor`, 1 for every light unless measured).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct NoiseModel {
    /// Floor σ₀.
    pub sigma0: f64,
    /// Share κ of the intensity level.
    pub kappa: f64,
    /// Whether σ₀ was estimated (true) or given.
    pub estimated: bool,
    /// Whether κ was measured on the capture (true) or given.
    pub kappa_estimated: bool,
    /// The capture's dark floor: what a shadowed reading reads (ambient light, sensor offset),
    /// in the units of the intensity-normalised channel means ([`dark_floor`]).
    pub floor: f64,
    /// Per light k, the factor c_k ≥ 1 of its noise: light k's reading has the standard
    /// deviation c_k · σ_p, i.e. its model error is κ_k = c_k · κ (with σ₀ scaled alike). Measured
    /// on the capture by [`light_noise_factors`] (an image that disagrees with the others, e.g.
    /// a light whose calibration is off, gets its own larger κ instead of inflating every
    /// light's); empty means 1 for every light (given, or near lights).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub light_factor: Vec<f64>,
}

impl NoiseModel {
    /// The shadow level at a pixel of mean intensity `level` (see
    /// [`DetectionParams::shadow_sigmas`]).
    #[inline]
    pub fn shadow_level(&self, params: &DetectionParams, level: f64) -> f64 {
        self.floor
            + params.shadow_sigmas * self.variance(level).sqrt()
            + params.shadow_ratio * level
    }

    /// κ_k = c_k · κ per light (the factors of [`NoiseModel::light_factor`]); empty when every
    /// light has the capture's κ.
    pub fn light_kappa(&self) -> Vec<f64> {
        self.light_factor.iter().map(|c| c * self.kappa).collect()
    }

    /// σ_p² at a pixel of mean intensity `level`.
    #[inline]
    pub fn variance(&self, level: f64) -> f64 {
        (self.sigma0 * self.sigma0 + self.kappa * self.kappa * level * level).max(1e-20)
    }
}

/// Fits σ² = σ₀² + κ² · level² to per-bin variance estimates (level, variance), with σ₀², κ² ≥ 0.
fn fit_sigma0_kappa(bins: &[(f64, f64)]) -> (f64, f64) {
    let n = bins.len() as f64;
    if bins.is_empty() {
        return (1e-3, 0.0);
    }
    let (sx, sy, sxx, sxy) = bins.iter().fold((0.0, 0.0, 0.0, 0.0), |a, &(l, v)| {
        let x = l * l;
        (a.0 + x, a.1 + v, a.2 + x * x, a.3 + x * v)
    });
    let det = n * sxx - sx * sx;
    let (mut a, mut b) = if det.abs() > 1e-30 {
        ((sy * sxx - sx * sxy) / det, (n * sxy - sx * sy) / det)
    } else {
        (sy / n, 0.0)
    };
    if b < 0.0 {
        b = 0.0;
        a = sy / n;
    }
    if a < 0.0 {
        a = 0.0;
        b = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    }
    (a.max(1e-16).sqrt(), b.max(0.0).sqrt())
}

/// Per-level-bin variance estimates from (level, statistic, dof) triples: in each of `n_bins`
/// equal-count bins of level, the q-quantile of RSS / χ²_d(q) (a low quantile is robust to the
/// non-Lambertian pixels, which only inflate the residual).
fn binned_variance(samples: &mut [(f64, f64, usize)], q: f64, n_bins: usize) -> Vec<(f64, f64)> {
    samples.sort_by(|a, b| a.0.total_cmp(&b.0));
    let per = samples.len().div_ceil(n_bins).max(1);
    let mut out = Vec::new();
    let mut quant_cache = std::collections::HashMap::new();
    for bin in samples.chunks_mut(per) {
        if bin.len() < 20 {
            continue;
        }
        let level = bin.iter().map(|s| s.0).sum::<f64>() / bin.len() as f64;
        let mut norm: Vec<f64> = bin
            .iter()
            .map(|&(_, rss, d)| {
                let qd = *quant_cache.entry(d).or_insert_with(|| chi2_quantile(q, d));
                rss / qd
            })
            .collect();
        let k = ((norm.len() as f64 * q) as usize).min(norm.len() - 1);
        let (_, v, _) = norm.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
        out.push((level, *v));
    }
    out
}

/// The noise model of a capture: σ₀ given (`sigma`, per channel, divided by √C for the channel
/// means) or estimated ([`NoiseEstimate`]), and κ = `relative_noise`.
pub fn noise_model(
    capture: &Capture,
    params: &DetectionParams,
    _progress: &dyn Progress,
) -> Result<NoiseModel> {
    params.validate()?;
    let c = capture.channels;
    let sigma0 = match params.sigma {
        Some(s) => Some(s / (c as f64).sqrt()),
        None if params.noise_estimate == NoiseEstimate::Images => {
            image_noise(capture).map(|s0| s0.max(1e-6))
        }
        None => None,
    };
    let Some(sigma0) = sigma0 else {
        let mut noise = residual_noise_model(capture, params)?;
        noise.floor = dark_floor(capture).min(params.shadow_sigmas * noise.sigma0);
        if let Some(k) = params.relative_noise {
            noise.kappa = k;
            noise.kappa_estimated = false;
        }
        if params.light_noise {
            noise.light_factor = light_noise_factors(capture, &noise, params);
        }
        return Ok(noise);
    };
    // The quantile measures lit readings when no image leaves part of the object in shadow:
    // the floor never exceeds what the sensor noise alone puts on a black reading.
    let floor = dark_floor(capture).min(params.shadow_sigmas * sigma0);
    let (kappa, kappa_estimated) = match params.relative_noise {
        Some(k) => (k, false),
        // Too few lights or pixels to measure it: the calibrated rig's default.
        None => match estimate_kappa(capture, sigma0, floor, params) {
            Some(k) => (k, true),
            None => (DEFAULT_RELATIVE_NOISE, false),
        },
    };
    let mut noise = NoiseModel {
        sigma0,
        kappa,
        estimated: params.sigma.is_none(),
        kappa_estimated,
        floor,
        light_factor: Vec::new(),
    };
    if params.light_noise {
        noise.light_factor = light_noise_factors(capture, &noise, params);
        if kappa_estimated && !noise.light_factor.is_empty() {
            // κ of the lights of factor 1, the inconsistent lights weighted down.
            if let Some(k) =
                estimate_kappa_weighted(capture, sigma0, floor, params, &noise.light_factor)
            {
                noise.kappa = k;
            }
        }
    }
    Ok(noise)
}

/// κ where it cannot be measured (see [`DetectionParams::relative_noise`]).
pub const DEFAULT_RELATIVE_NOISE: f64 = 0.01;

/// The dark floor of a capture: in each image, the 1% quantile of the channel-mean readings over
/// (a regular sample of at most 4096) mask pixels — the level of its shadowed pixels — and the
/// smallest of these over the images (an image whose light leaves no part of the object in
/// shadow has a higher quantile; the smallest is the conservative choice: fewer readings count
/// as shadow). Never negative. The noise model caps it at `shadow_sigmas · σ₀`: on a capture
/// where no image leaves any part of the object in shadow the quantile is a lit reading.
pub fn dark_floor(capture: &Capture) -> f64 {
    *capture
        .statistics()
        .dark_floor
        .get_or_init(|| measure_dark_floor(capture))
}

/// [`dark_floor`], measured.
pub(super) fn measure_dark_floor(capture: &Capture) -> f64 {
    let np = capture.n_pixels();
    if np == 0 {
        return 0.0;
    }
    let n = capture.n_lights();
    let c = capture.channels;
    let stride = np.div_ceil(4096).max(1);
    (0..n)
        .into_par_iter()
        .map(|k| {
            let mut v: Vec<f64> = (0..np)
                .step_by(stride)
                .map(|p| {
                    let s = &capture.pixel_samples(p)[k * c..(k + 1) * c];
                    s.iter().map(|&x| x as f64).sum::<f64>() / c as f64
                })
                .collect();
            crate::solve::metrics::quantile(&mut v, 0.01)
        })
        .reduce(|| f64::INFINITY, f64::min)
        .max(0.0)
}

/// The mask pixels whose whole 3×3 neighbourhood lies in the mask ("interior"): how many there
/// are, and every `total.div_ceil(at_most)`-th of them (at most `at_most`), each as the nine
/// mask-pixel indices of its neighbourhood (row by row), in the order of [`Capture::pixels`].
/// Found from the mask and a binary search in the ascending [`Capture::pixels`]: no
/// frame-sized index and no list of every interior pixel.
pub(crate) fn interior_neighbourhoods(capture: &Capture, at_most: usize) -> (Vec<[u32; 9]>, usize) {
    let (w, h) = (capture.width, capture.height);
    let interior = |i: u32| {
        let (r, col) = (i as usize / w, i as usize % w);
        r > 0
            && col > 0
            && r + 1 < h
            && col + 1 < w
            && (0..9).all(|j| capture.mask[(r + j / 3 - 1) * w + col + j % 3 - 1])
    };
    let total = capture.pixels.iter().filter(|&&i| interior(i)).count();
    let stride = total.div_ceil(at_most.max(1)).max(1);
    let sampled = capture
        .pixels
        .iter()
        .copied()
        .filter(|&i| interior(i))
        .step_by(stride)
        .map(|i| {
            let (r, col) = (i as usize / w, i as usize % w);
            std::array::from_fn(|j| {
                let f = ((r + j / 3 - 1) * w + col + j % 3 - 1) as u32;
                capture.pixels.binary_search(&f).unwrap_or(0) as u32
            })
        })
        .collect();
    (sampled, total)
}

/// Sensor noise of the channel-mean images (see [`NoiseEstimate::Images`]); `None` when fewer
/// than 100 object pixels have their whole 3×3 neighbourhood in the mask.
pub fn image_noise(capture: &Capture) -> Option<f64> {
    *capture
        .statistics()
        .image_noise
        .get_or_init(|| measure_image_noise(capture))
}

/// [`image_noise`], measured: for each sampled interior pixel the 3×3 Laplacian-like kernel of
/// every light at once (each neighbour's samples read once, in memory order), then the robust
/// scale of each light's values and the median over the lights.
pub(super) fn measure_image_noise(capture: &Capture) -> Option<f64> {
    let (sampled, interior) = interior_neighbourhoods(capture, 4096);
    if interior < 100 {
        return None;
    }
    let n = capture.n_lights();
    let c = capture.channels;
    const KERNEL: [f64; 9] = [1.0, -2.0, 1.0, -2.0, 4.0, -2.0, 1.0, -2.0, 1.0];
    // Pixel-major: values[i * n + k] is |kernel| of light k at sampled pixel i.
    let mut values = vec![0f64; sampled.len() * n];
    values
        .par_chunks_mut(n)
        .zip(sampled.par_iter())
        .for_each(|(out, nb)| {
            out.fill(0.0);
            for (q, m) in nb.iter().zip(KERNEL) {
                let samples = capture.pixel_samples(*q as usize);
                for (acc, s) in out.iter_mut().zip(samples.chunks_exact(c)) {
                    *acc += m * s.iter().map(|&v| v as f64).sum::<f64>() / c as f64;
                }
            }
            for v in out.iter_mut() {
                *v = v.abs();
            }
        });
    let m = sampled.len();
    let mut per_light: Vec<f64> = (0..n)
        .into_par_iter()
        .map_init(
            || Vec::with_capacity(m),
            |column, k| {
                column.clear();
                column.extend((0..m).map(|i| values[i * n + k]));
                1.4826 * crate::solve::metrics::median(column) / 6.0
            },
        )
        .collect();
    Some(crate::solve::metrics::median(&mut per_light))
}

/// [`NoiseEstimate::Residuals`].
fn residual_noise_model(capture: &Capture, params: &DetectionParams) -> Result<NoiseModel> {
    let c = capture.channels;
    let test = ChiSquareTest::new(capture, params)?;
    let n = capture.n_lights();
    let mut samples: Vec<(f64, f64, usize)> = (0..capture.n_pixels())
        .into_par_iter()
        .map_init(
            || (vec![0f64; n], vec![true; n]),
            |(grey, all), p| {
                channel_mean(capture.pixel_samples(p), c, grey);
                let level = grey.iter().sum::<f64>() / n as f64;
                let (_, rss, _) = least_squares_rss(&test, grey, all, &test.gram_inv);
                (level, rss, n - 3)
            },
        )
        .collect();
    let (s0, k) = fit_sigma0_kappa(&binned_variance(&mut samples, 0.25, 8));
    let mut noise = NoiseModel {
        sigma0: s0,
        kappa: k,
        estimated: true,
        kappa_estimated: true,
        floor: 0.0,
        light_factor: Vec::new(),
    };
    // Refinements look at a regular sample of at most REFINE_SAMPLES pixels: the estimate needs
    // a few thousand residuals, not all of them.
    const REFINE_SAMPLES: usize = 8192;
    let stride = capture.n_pixels().div_ceil(REFINE_SAMPLES).max(1);
    for _ in 0..params.noise_refinements {
        let mut samples: Vec<(f64, f64, usize)> = (0..capture.n_pixels())
            .into_par_iter()
            .step_by(stride)
            .map_init(
                || {
                    let scratch = AttributionBuffers::new(n);
                    (scratch, vec![0u8; n])
                },
                |(scratch, st), p| {
                    channel_mean(capture.pixel_samples(p), c, &mut scratch.grey);
                    let level = scratch.grey.iter().sum::<f64>() / n as f64;
                    let (_, rss, kept) = attribute_all(&test, params, &noise, scratch, st);
                    (level, rss, kept)
                },
            )
            .filter(|f| f.2 > 3)
            .map(|(l, rss, k)| (l, rss, k - 3))
            .collect();
        if samples.len() < 100 {
            break;
        }
        let (s0, k) = fit_sigma0_kappa(&binned_variance(&mut samples, 0.5, 8));
        noise = NoiseModel {
            sigma0: s0,
            kappa: k,
            estimated: true,
            kappa_estimated: true,
            floor: noise.floor,
            light_factor: Vec::new(),
        };
    }
    Ok(noise)
}
