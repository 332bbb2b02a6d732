//! The model error κ of a capture — the part of the misfit that changes independently from one
//! light to the next, which the χ² test must accept — and the per-light noise factors c_k
//! (κ_k = c_k κ), both measured on the capture with robust fits ([`super::regression`]) and
//! remembered in the capture's statistics memo.

use super::noise::NoiseModel;
use super::params::DetectionParams;
use super::regression::{distant_directions, high_breakdown_fit, light_triplets, robust_fit_with};
use crate::model::capture::Capture;
use crate::solve::lambert::channel_mean;
use nalgebra::Vector3;
use rayon::prelude::*;

/// κ measured on the capture: the part of the model error that changes independently from one
/// light to the next (each light's calibration error, the sensor's response), which the χ² test
/// must accept, and not the smooth departures from Lambert (a broad specular lobe, interreflection,
/// soft shadow edges) that it is there to find. For a regular sample of at most 8192 mask pixels,
/// the readings above the absolute shadow level (`floor + 3σ₀`) are fitted robustly
/// (`high_breakdown_fit`: least median of squares over light triplets, then least squares
/// over the readings within 3 robust scales, repeated until that set settles), so that neither
/// a sharp highlight nor a third of the readings dimmed by a partial occluder bias it. Then, for
/// each kept light k whose nearest light j (in direction) is also kept, the difference of their
/// residuals d = eₖ − eⱼ, whose variance under noise alone is σ²(2 − hₖₖ − hⱼⱼ + 2hₖⱼ) (H the fit's
/// hat matrix): a smooth departure is nearly the same at neighbouring lights and cancels, an
/// independent one does not. The pixel's variance v_p is the median of d² over its pairs divided
/// by that factor and by the χ²₁ median (0.4549), and κ_p² = (v_p − σ₀²) / Ī_p². κ is the square
/// root of the median of κ_p² over the pixels (negative medians give 0). Pixels with fewer than
/// four readings kept or fewer than three pairs do not count. None (not measurable) with fewer
/// than [`MIN_KAPPA_LIGHTS`] lights, with near lights (before the surface is known a pixel's
/// light vectors carry the error of its unknown depth, which κ would take for model error) or
/// with fewer than 100 pixels counted; the noise model then keeps
/// [`DEFAULT_RELATIVE_NOISE`](super::DEFAULT_RELATIVE_NOISE). Typical values: κ is 0.5–1.1% on
/// DiLiGenT, 2.7–4.2% on psmImages, at most 1% on renders of five lights or more.
pub fn estimate_kappa(
    capture: &Capture,
    sigma0: f64,
    floor: f64,
    params: &DetectionParams,
) -> Option<f64> {
    estimate_kappa_weighted(capture, sigma0, floor, params, &[])
}

/// [`estimate_kappa`] under per-light noise factors c_k ([`NoiseModel::light_factor`]; empty:
/// all 1): the fit is weighted least squares (readings and light vectors divided by c_k), so
/// that κ is the model error of a light of factor 1 — a few inconsistent images then do not
/// inflate it. Measured once per capture and arguments (the capture's statistics memo).
pub fn estimate_kappa_weighted(
    capture: &Capture,
    sigma0: f64,
    floor: f64,
    params: &DetectionParams,
    factors: &[f64],
) -> Option<f64> {
    let key = kappa_key(sigma0, floor, params, factors);
    capture
        .statistics()
        .remember(key, || {
            measure_kappa(capture, sigma0, floor, params.shadow_sigmas, factors)
                .into_iter()
                .collect()
        })
        .first()
        .copied()
}

/// [`estimate_kappa_weighted`] when the capture's memo already holds it (`Some` of the
/// estimate), else `None`: nothing is measured, so it also answers for a capture held in tiles.
pub fn remembered_kappa(
    capture: &Capture,
    sigma0: f64,
    floor: f64,
    params: &DetectionParams,
    factors: &[f64],
) -> Option<Option<f64>> {
    let key = kappa_key(sigma0, floor, params, factors);
    let values = capture.statistics().recall(&key)?;
    Some(values.first().copied())
}

/// The memo key of κ for these arguments.
fn kappa_key(sigma0: f64, floor: f64, params: &DetectionParams, factors: &[f64]) -> Vec<u64> {
    let mut key = vec![
        KAPPA_KEY,
        sigma0.to_bits(),
        floor.to_bits(),
        params.shadow_sigmas.to_bits(),
    ];
    key.extend(factors.iter().map(|f| f.to_bits()));
    key
}

/// The first word of the memo keys of κ and of the light factors.
const KAPPA_KEY: u64 = 1;
const LIGHT_FACTORS_KEY: u64 = 2;

/// Lights needed to measure κ: with four, a pixel's residual has one degree of freedom and a
/// fault on one light looks the same as model error spread over all of them (the four
/// standardised residuals are equal in size), so no reading can be trimmed.
pub const MIN_KAPPA_LIGHTS: usize = 5;

/// The χ²₁ median: the median of d²/Var(d) for a normal d.
const CHI2_1_MEDIAN: f64 = 0.454_936_423_119_572_7;

/// [`estimate_kappa_weighted`], measured (`shadow_sigmas`: [`DetectionParams::shadow_sigmas`]).
pub(super) fn measure_kappa(
    capture: &Capture,
    sigma0: f64,
    floor: f64,
    shadow_sigmas: f64,
    factors: &[f64],
) -> Option<f64> {
    let n = capture.n_lights();
    let np = capture.n_pixels();
    if n < MIN_KAPPA_LIGHTS || np == 0 || capture.lights.near.is_some() {
        return None;
    }
    let c = capture.channels;
    let weighted = factors.len() == n;
    let neighbour = nearest_lights(&capture.lights.directions);
    let mut dirs = distant_directions(capture);
    if weighted {
        for (d, &f) in dirs.iter_mut().zip(factors) {
            *d /= f;
        }
    }
    let stride = np.div_ceil(8192).max(1);
    let dark = floor + shadow_sigmas * sigma0;
    let triplets = light_triplets(&dirs);
    let mut k2: Vec<f64> = (0..np)
        .into_par_iter()
        .step_by(stride)
        .map_init(
            || {
                (
                    vec![0f64; n],
                    vec![false; n],
                    vec![false; n],
                    Vec::with_capacity(n),
                )
            },
            |(grey, keep, lit, scratch), p| {
                channel_mean(capture.pixel_samples(p), c, grey);
                let level = grey.iter().sum::<f64>() / n as f64;
                for (l, g) in lit.iter_mut().zip(grey.iter()) {
                    *l = *g > dark;
                }
                if weighted {
                    for (g, &f) in grey.iter_mut().zip(factors) {
                        *g /= f;
                    }
                }
                let (fit, gram_inv) =
                    high_breakdown_fit(&dirs, &triplets, grey, keep, lit, scratch)?;
                scratch.clear();
                for (k, &j) in neighbour.iter().enumerate() {
                    if !(keep[k] && keep[j]) {
                        continue;
                    }
                    let d = (grey[k] - dirs[k].dot(&fit)) - (grey[j] - dirs[j].dot(&fit));
                    let (gk, gj) = (gram_inv * dirs[k], gram_inv * dirs[j]);
                    let factor = 2.0 - dirs[k].dot(&gk) - dirs[j].dot(&gj) + 2.0 * dirs[k].dot(&gj);
                    scratch.push(d * d / factor.max(1e-9));
                }
                if scratch.len() < 3 {
                    return None;
                }
                let variance = crate::solve::metrics::median(scratch) / CHI2_1_MEDIAN;
                Some((variance - sigma0 * sigma0) / (level * level))
            },
        )
        .flatten()
        .collect();
    if k2.len() < 100 {
        return None;
    }
    Some(crate::solve::metrics::median(&mut k2).max(0.0).sqrt())
}

/// For each light, the index of the light nearest to it in direction (the largest cosine
/// between the unit vectors; the later index on ties). Near lights: their nominal directions.
pub(super) fn nearest_lights(directions: &[[f64; 3]]) -> Vec<usize> {
    let unit: Vec<Vector3<f64>> = directions
        .iter()
        .map(|d| {
            Vector3::from(*d)
                .try_normalize(0.0)
                .unwrap_or_else(Vector3::zeros)
        })
        .collect();
    (0..unit.len())
        .map(|k| {
            (0..unit.len())
                .filter(|&j| j != k)
                .max_by(|&a, &b| unit[k].dot(&unit[a]).total_cmp(&unit[k].dot(&unit[b])))
                .unwrap_or(k)
        })
        .collect()
}

/// Per-light noise factors c_k ≥ 1 of a capture under the noise model `noise`
/// ([`NoiseModel::light_factor`]), measured like [`estimate_kappa`]: over a regular sample of
/// at most 8192 mask pixels, the robust all-light fit of each pixel; for every reading above the
/// absolute shadow level (`floor + shadow_sigmas · σ₀`) its standardised residual in units of
/// the model's σ_p, zₖₚ. Light k's scale sₖ is the lower quartile of |zₖₚ| over the pixels
/// divided by that of a standard normal, 0.3186 (the quartile ignores a light's highlights
/// while they cover less than three quarters of its pixels). With s̃ the larger of 1 and the
/// median of the sₖ over the lights, and ŝ = 1.4826 × the median absolute deviation of the sₖ
/// from s̃, c_k = sₖ / s̃ for the lights beyond the fence s̃ + 3ŝ and 1 for the others: a light
/// is as good as the typical light (or the model) unless its readings are measured to disagree
/// clearly more. With four lights the
/// standardised residuals of a pixel are equal in size and no light can be singled out.
/// Empty (every factor 1) with near lights (the vectors follow the surface), fewer than five
/// lights, or fewer than 100 readings for a light.
pub fn light_noise_factors(
    capture: &Capture,
    noise: &NoiseModel,
    params: &DetectionParams,
) -> Vec<f64> {
    let key = vec![
        LIGHT_FACTORS_KEY,
        noise.sigma0.to_bits(),
        noise.kappa.to_bits(),
        noise.floor.to_bits(),
        params.shadow_sigmas.to_bits(),
    ];
    capture
        .statistics()
        .remember(key, || measure_light_noise_factors(capture, noise, params))
}

/// [`light_noise_factors`], measured.
fn measure_light_noise_factors(
    capture: &Capture,
    noise: &NoiseModel,
    params: &DetectionParams,
) -> Vec<f64> {
    let n = capture.n_lights();
    let np = capture.n_pixels();
    if n < 5 || np == 0 || capture.lights.near.is_some() {
        return Vec::new();
    }
    let c = capture.channels;
    let dirs = distant_directions(capture);
    let stride = np.div_ceil(8192).max(1);
    let dark = noise.floor + params.shadow_sigmas * noise.sigma0;
    // Per light, the |z| of its readings; collected per thread and concatenated.
    let per_light: Vec<Vec<f64>> = (0..np)
        .into_par_iter()
        .step_by(stride)
        .fold(
            || {
                let buffers = (vec![0f64; n], vec![false; n], Vec::with_capacity(n));
                (vec![Vec::new(); n], buffers, Vec::with_capacity(n))
            },
            |(mut acc, (mut grey, mut keep, mut u), mut scratch), p| {
                channel_mean(capture.pixel_samples(p), c, &mut grey);
                let level = grey.iter().sum::<f64>() / n as f64;
                for (k, g) in keep.iter_mut().zip(grey.iter()) {
                    *k = *g > dark;
                }
                if robust_fit_with(&dirs, &grey, &mut keep, &mut u, &mut scratch).is_some() {
                    let sigma = noise.variance(level).sqrt();
                    for &(k, z) in u.iter() {
                        if grey[k] > dark {
                            acc[k].push(z.abs() / sigma);
                        }
                    }
                }
                (acc, (grey, keep, u), scratch)
            },
        )
        .map(|(acc, ..)| acc)
        .reduce(
            || vec![Vec::new(); n],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    x.extend(y);
                }
                a
            },
        );
    if per_light.iter().any(|v| v.len() < 100) {
        return Vec::new();
    }
    // The lower quartile of |z| of a standard normal.
    const Q25_ABS_NORMAL: f64 = 0.318_639_363_964_375;
    let scales: Vec<f64> = per_light
        .into_iter()
        .map(|mut v| crate::solve::metrics::quantile(&mut v, 0.25) / Q25_ABS_NORMAL)
        .collect();
    // The reference: the typical light, or the noise model itself where the typical light fits
    // better than the model says (a factor below 1 is never given).
    let typical = crate::solve::metrics::median(&mut scales.clone()).max(1.0);
    if !typical.is_finite() {
        return Vec::new();
    }
    // A light is an outlier among the lights when its scale lies beyond 3 robust spreads
    // (1.4826 × the median absolute deviation of the scales) above the reference.
    let mut dev: Vec<f64> = scales.iter().map(|&s| (s - typical).abs()).collect();
    let fence = typical + 3.0 * 1.4826 * crate::solve::metrics::median(&mut dev);
    scales
        .iter()
        .map(|&s| if s > fence { s / typical } else { 1.0 })
        .collect()
}
