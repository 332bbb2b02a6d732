//! Detecting non-Lambertian pixels through the linear dependence of the light directions
//! (paper eqs. 4–6, generalised to N lights; ALGORITHMS.md §2), and attributing each failure to
//! the lights at fault.
//!
//! For N > 3 lights the intensities of a Lambertian pixel lit by every light lie in the column
//! space of the N×3 light matrix L. The residual r = Aᵀ I, with A an orthonormal basis of the
//! null space of Lᵀ, is zero up to noise; its squared norm equals the residual sum of squares of
//! the least-squares fit, which is how it is computed here (O(N) per pixel, A never formed).
//! With noise σ_p, s = ‖r‖² / σ_p² follows χ² with N − 3 degrees of freedom; the pixel is
//! unreliable when s exceeds the χ² quantile at the chosen confidence (95%: for four lights
//! |r| > 1.96 σ, the paper's "T = 2σ").
//!
//! Noise model: σ_p² = σ₀² + (κ · Ī_p)², a floor plus a share of the pixel's own intensity level
//! Ī_p (the mean of its intensities), because on real captures the "noise" is mostly model error
//! that grows with brightness. σ₀ and κ are given or estimated robustly (see [`NoiseModel`]).
//!
//! Attribution: while the test fails and more than `min_kept` lights remain, remove the light
//! whose removal lowers the residual sum of squares most (e_k² / P_kk, the deleted residual, with
//! P = A Aᵀ the projector onto the residual space); its sign says darker (shadow) or brighter
//! (highlight) than the others predict. When the scores tie — always the case with four lights,
//! where P = a aᵀ — the intensities decide: the darkest too-dark candidate is a shadow if it is
//! near the shadow level, otherwise the brightest too-bright candidate is a highlight.
//! Intensities are the channel means of the intensity-normalised images.
//!
//! The module's files, one concept each: `params` (the detector's parameters), `chi2` (the
//! χ² test's per-capture constants and the statistic), `attribution` (removing the lights at
//! fault, and the [`Attributor`] the recursive method re-runs), `kernels` (the per-light score
//! pass, its AVX2 build next to the scalar reference), `noise` (the noise model σ₀, floor and
//! its estimates), `kappa` (the model error κ of the capture and of each light) and
//! `regression` (the robust fits behind κ and the light factors).

mod attribution;
mod chi2;
mod kappa;
mod kernels;
mod noise;
mod params;
mod regression;

pub use attribution::{AttributionScratch, Attributor};
pub use chi2::null_space;
pub use kappa::{
    estimate_kappa, estimate_kappa_weighted, light_noise_factors, remembered_kappa,
    MIN_KAPPA_LIGHTS,
};
pub(crate) use noise::interior_neighbourhoods;
pub use noise::{dark_floor, image_noise, noise_model, NoiseModel, DEFAULT_RELATIVE_NOISE};
pub use params::{DetectionParams, NoiseEstimate, MAX_NOISE_REFINEMENTS};
pub(crate) use regression::{distant_directions, robust_fit_with};

use crate::base::error::Result;
use crate::base::progress::Progress;
use crate::model::capture::Capture;
use crate::solve::lambert::{channel_mean, status, CHUNK};
use attribution::{attribute_all, AttributionBuffers};
use chi2::{dark_beyond_the_test, ChiSquareTest, NearLightTest};
use rayon::prelude::*;

/// The detector's results, per mask pixel (see [`Capture::pixels`]). A pixel is unreliable when
/// the χ² test fails, or when at least N − 2 of its readings are at the shadow level (faults the
/// linear test cannot see; see `dark_beyond_the_test`).
#[derive(Clone, Debug)]
pub struct Detection {
    /// ‖r‖ / σ_p with all lights: the grey map of the paper's Fig. 6a.
    pub residual: Vec<f32>,
    /// The χ² test failed with all lights: the binary map of Fig. 6b.
    pub unreliable: Vec<bool>,
    /// Per pixel and light (`n_pixels * n_lights`): USED, SHADOW or HIGHLIGHT.
    pub light_status: Vec<u8>,
    /// Per pixel: the lights the attribution kept (USED in `light_status`) pass the χ² test —
    /// more than three of them and the statistic of their fit under its threshold (the test's
    /// verdict with all lights where no light was removed).
    pub settled: Vec<bool>,
    /// The noise model used.
    pub noise: NoiseModel,
    /// The χ² threshold with all lights.
    pub threshold: f64,
    /// The parameters used.
    pub params: DetectionParams,
}

impl Detection {
    /// The maps of a capture the test cannot examine (three lights): nothing flagged, every
    /// light used; the noise model is the given or image-estimated one.
    pub fn untested(capture: &Capture, params: &DetectionParams) -> Self {
        let c = capture.channels as f64;
        let sigma0 = params
            .sigma
            .map(|s| s / c.sqrt())
            .or_else(|| image_noise(capture))
            .unwrap_or(0.0);
        let np = capture.n_pixels();
        Detection {
            residual: vec![0.0; np],
            unreliable: vec![false; np],
            light_status: vec![status::USED; np * capture.n_lights()],
            settled: vec![false; np],
            noise: NoiseModel {
                sigma0,
                kappa: params.relative_noise.unwrap_or(0.0),
                estimated: params.sigma.is_none(),
                kappa_estimated: false,
                floor: dark_floor(capture).min(params.shadow_sigmas * sigma0),
                light_factor: Vec::new(),
            },
            threshold: f64::INFINITY,
            params: params.clone(),
        }
    }

    /// Share of mask pixels flagged unreliable.
    pub fn unreliable_share(&self) -> f64 {
        self.unreliable.iter().filter(|&&u| u).count() as f64 / self.unreliable.len().max(1) as f64
    }

    /// Usable-light flags (`n_pixels * n_lights`, true = USED).
    pub fn usable(&self) -> Vec<bool> {
        crate::solve::lambert::usable(&self.light_status)
    }
}

/// Runs the test and the attribution over every mask pixel with a fixed noise model.
fn test_every_pixel(
    capture: &Capture,
    test: &ChiSquareTest,
    params: &DetectionParams,
    noise: &NoiseModel,
    progress: &dyn Progress,
) -> PixelFindings {
    let n = capture.n_lights();
    let c = capture.channels;
    let np = capture.n_pixels();
    let mut residual = vec![0f32; np];
    let mut light_status = vec![status::USED; np * n];
    let mut invisible = vec![false; np];
    let mut settled = vec![false; np];
    progress.begin("detecting", np as u64);
    residual
        .par_chunks_mut(CHUNK)
        .zip(light_status.par_chunks_mut(CHUNK * n))
        .zip(invisible.par_chunks_mut(CHUNK))
        .zip(settled.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each_init(
            || (AttributionBuffers::new(n), NearLightTest::of(capture, test)),
            |(scratch, near), (chunk, (((res, st), inv), set))| {
                let p0 = chunk * CHUNK;
                for dp in 0..res.len() {
                    channel_mean(capture.pixel_samples(p0 + dp), c, &mut scratch.grey);
                    inv[dp] = dark_beyond_the_test(params, noise, &scratch.grey);
                    let test = match near.as_mut() {
                        None => test,
                        Some(t) => match t.at(capture.pixels[p0 + dp] as usize) {
                            Some(t) => t,
                            None => {
                                res[dp] = 0.0;
                                continue;
                            }
                        },
                    };
                    let (s_all, rss, count) =
                        attribute_all(test, params, noise, scratch, &mut st[dp * n..(dp + 1) * n]);
                    res[dp] = s_all.sqrt() as f32;
                    // The same statistic as [`Attributor::run`]'s of the final set.
                    let level = scratch.grey.iter().sum::<f64>() / n as f64;
                    set[dp] =
                        count > 3 && rss / noise.variance(level) <= test.thresholds[count - 3];
                }
                progress.advance(res.len() as u64);
            },
        );
    progress.end();
    PixelFindings {
        residual,
        light_status,
        invisible,
        settled,
    }
}

/// What [`test_every_pixel`] finds per mask pixel.
struct PixelFindings {
    residual: Vec<f32>,
    light_status: Vec<u8>,
    invisible: Vec<bool>,
    settled: Vec<bool>,
}

/// Detects the non-Lambertian pixels of a capture and attributes them to lights, with the noise
/// model from [`noise_model`].
pub fn detect(
    capture: &Capture,
    params: &DetectionParams,
    progress: &dyn Progress,
) -> Result<Detection> {
    let noise = noise_model(capture, params, progress)?;
    detect_with_noise(capture, params, noise, progress)
}

/// Detection with a known noise model.
pub fn detect_with_noise(
    capture: &Capture,
    params: &DetectionParams,
    noise: NoiseModel,
    progress: &dyn Progress,
) -> Result<Detection> {
    params.validate()?;
    let test = ChiSquareTest::with_noise(capture, params, &noise)?;
    let n = capture.n_lights();
    let PixelFindings {
        residual,
        light_status,
        invisible,
        settled,
    } = test_every_pixel(capture, &test, params, &noise, progress);
    let threshold = test.thresholds[n - 3];
    let unreliable = residual
        .iter()
        .zip(&invisible)
        .map(|(&r, &dark)| (r as f64) * (r as f64) > threshold || dark)
        .collect();
    Ok(Detection {
        residual,
        unreliable,
        light_status,
        settled,
        noise,
        threshold,
        params: params.clone(),
    })
}

#[cfg(test)]
mod tests;
