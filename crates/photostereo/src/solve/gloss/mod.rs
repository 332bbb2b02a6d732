//! Highlights modelled rather than dropped, for distant lights: the recursive method's
//! reflectance model (`--reflectance`).
//!
//! The recursion leaves a highlight's readings out of a pixel's estimate. Where a pixel keeps
//! enough lights that is harmless; on glossy objects many pixels lose several lights, and the
//! readings left are fewer and lie further from the normal's best-conditioned directions. The
//! readings of a lobe hold information about the normal too — a lobe peaks where n meets the
//! light's half vector h_k = (l_k + v)/‖l_k + v‖, v = (0, 0, 1) toward the orthographic camera —
//! so at such pixels the normal is fitted jointly with a specular term, with the model the
//! near-light fit uses ([`crate::solve::near_lobe`]) and unit light brightness:
//!
//! I_k = ρ max(n · l_k, 0) + s · exp(−m (1 − n · h_k)),   ρ ≥ 0, s ≥ 0,
//!
//! over every light the recursion did not put in shadow and the camera did not clip (shadows
//! and clipped readings stay excluded, [`Capture::clip_levels`]; the recursion's statuses are
//! not changed). The readings are weighted by their noise, σ_k² =
//! c_k² (σ₀² + κ² I_k²) ([`NoiseModel`]), so that squared residuals are χ² values. The lobe
//! sharpness m is a property of the material: the capture's m is chosen among
//! [`LOBE_EXPONENTS`] by the least total χ² over a sample of pixels; a pixel takes its own m
//! where that lowers its χ² by more than the χ² quantile of one degree of freedom (one more
//! parameter). exp(−m (1 − cos α)) ≈ exp(−α² / (2/m)) is a Beckmann-like lobe of roughness
//! σ = √(2/m): the roughness map gives that σ (radians of the half-vector angle), the strength
//! map s (the lobe's peak, in the units of the intensity-normalised readings, like the albedo).
//!
//! A pixel is fitted where the recursion attributed a highlight to one of its lights and at
//! least [`MIN_LIGHTS`] lights are out of shadow, from the recursion's normal (a
//! Levenberg–Marquardt descent, `descend`). Whether the lobe is evidence of a highlight is
//! decided by tests, all at the detector's confidence:
//!
//! - *significant*: the Lambertian fit over the lit readings (USED and HIGHLIGHT) fails its χ²
//!   test (χ² above the quantile of N − 3 degrees of freedom for the measured noise), and the
//!   lobe's lowering of that χ² passes the F-test of nested fits, F = (Δχ²/Δp) / (χ²_lobe /
//!   (N − p)) against the F(Δp, N − p) quantile (p = 4 unknowns, 5 with the pixel's own m;
//!   Δp = p − 3). The ratio does not depend on the noise level, so that a noise model that is
//!   off by a factor does not make every lobe significant;
//! - *physical*: the fit's normal faces the camera and every lit light (a surface reflects
//!   neither diffusely nor specularly a light behind it);
//! - *specular*: the lobe about the half vectors fits better than the same lobe about the light
//!   directions (shading that falls faster than n · l — a non-linear camera response, sheen —
//!   fits that one as well or better);
//! - *determined*: the fit's normal has a standard error (its covariance scaled by χ²_lobe /
//!   (N − p)) at most the Lambertian normal's (scaled by χ²_L / (N − 3)); a lobe that trades
//!   off against the diffuse term leaves the normal loose.
//!
//! [`Reflectance::Auto`] decides per capture first, over the pixels sampled for m: the capture
//! has lobes when more of them are significant than the binomial quantile of the F-test's
//! false-alarm rate (what Lambertian readings would give), and more of those are specular and
//! determined than the binomial quantile of a coin toss; then each pixel that passes all four
//! tests takes the fit's normal. [`Reflectance::Lobe`] takes every physical fit with a lobe
//! (s > 0). Elsewhere the recursion's choice of lights stands. The fit's own χ² test (χ² at
//! most the quantile of N − p degrees of freedom) is reported, not used: on real captures the
//! lobe, like the Lambertian model over the lights the recursion keeps, rarely explains the
//! readings to the noise level, while its normal is the better one.
//!
//! Light ring and four-light rigs leave fewer than [`MIN_LIGHTS`] lights: the per-pixel fits
//! (`lobe`, `auto`) have nothing to fit there; `material` fits them with one strength per
//! material ([`material`]), from four lights up. Cost: a few Gauss–Newton passes over the pixel's lights per fitted pixel; memory two
//! f32 maps per mask pixel.

pub mod material;

use crate::base::error::Result;
use crate::model::capture::{clipped, Capture};
use crate::solve::detect::NoiseModel;
use crate::solve::lambert::{
    channel_mean, status, write_normal_albedo_with, Estimate, Statuses, CHUNK,
};
use crate::solve::near_lobe::{basis, diffuse_residual, fit_at, quantiles, PixelData};
use nalgebra::{Matrix4, Vector4};
use rayon::prelude::*;
use serde::Serialize;
use std::str::FromStr;

/// Lights out of shadow a pixel needs for its lobe fit: the four unknowns (n, ρ, s) and two
/// degrees of freedom for the residual to be compared with the Lambertian fit's.
pub const MIN_LIGHTS: usize = crate::solve::near_lobe::MIN_LIGHTS;

/// The exponential lobe the materials' shapes start from under fewer than [`MIN_LIGHTS`]
/// lights, where no pixel can measure the capture's sharpness (roughness √(2/50) = 0.2, a
/// broad start the non-negative shape fit narrows).
pub const SHARED_START_EXPONENT: f64 = 50.0;
/// The lobe sharpnesses m tried: the near-light fit's ([`crate::solve::near_lobe::LOBE_EXPONENTS`],
/// half height 13.3° to 3.4° from the peak), two broader ones (half height 19.6° and 16.1°,
/// roughness 0.41 and 0.33) and two sharper ones (2.9° and 2.4°, roughness 0.06 and 0.05):
/// with many lights all around, the broad lobes of rough plastics and the sharp ones of
/// polished metal both show in the readings.
pub const LOBE_EXPONENTS: &[f64] = &[
    12.0, 18.0, 25.0, 35.0, 50.0, 70.0, 100.0, 140.0, 200.0, 280.0, 400.0, 560.0, 800.0,
];
/// Pixels sampled to choose the capture's lobe sharpness (evenly spaced over the candidates).
const SAMPLE_PIXELS: usize = 400;

/// The reflectance model of the recursive method's final estimate with distant lights.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Reflectance {
    /// Lambert only: the highlight lights are dropped (the paper).
    #[serde(rename = "lambert")]
    Lambert,
    /// Lambert plus a specular lobe wherever the fit finds one (s > 0).
    #[serde(rename = "lobe")]
    Lobe,
    /// The lobe where the χ² evidence says it is significant, Lambert elsewhere.
    #[serde(rename = "auto")]
    Auto,
    /// One lobe shape (and diffuse falloff) shared by the pixels of a material, where the
    /// material's pooled evidence (BIC) says it has a lobe; Lambert elsewhere
    /// ([`crate::solve::gloss::material`]).
    #[serde(rename = "material")]
    Material,
}

impl Reflectance {
    /// Every choice, default first.
    pub const ALL: &'static [Reflectance] = &[
        Reflectance::Lambert,
        Reflectance::Auto,
        Reflectance::Lobe,
        Reflectance::Material,
    ];

    /// The name accepted by `--reflectance` (and the Python keyword `reflectance`).
    pub fn name(self) -> &'static str {
        match self {
            Reflectance::Lambert => "lambert",
            Reflectance::Lobe => "lobe",
            Reflectance::Auto => "auto",
            Reflectance::Material => "material",
        }
    }
}

impl FromStr for Reflectance {
    type Err = crate::Error;
    fn from_str(s: &str) -> Result<Self> {
        crate::base::error::parse_name(s, Reflectance::ALL, Reflectance::name, "reflectance")
    }
}

/// What [`model_highlights`] did, for `report.json`.
#[derive(Clone, Debug, Serialize)]
pub struct GlossSummary {
    /// The model asked for.
    pub reflectance: Reflectance,
    /// What was used: "lobe" where any pixel took the lobe fit's normal, else "lambert".
    pub chosen: &'static str,
    /// The capture's lobe sharpness m; `None` when no pixel was fitted.
    pub exponent: Option<f64>,
    /// Its roughness √(2/m).
    pub roughness: Option<f64>,
    /// The capture's evidence: candidate pixels sampled (a highlight attributed,
    /// [`MIN_LIGHTS`] lights out of shadow) ...
    pub sample_pixels: usize,
    /// ... of them, those whose lobe is significant ...
    pub sample_significant: usize,
    /// ... and the most that Lambertian readings would give at the detector's confidence
    /// (binomial quantile at the test's false-alarm rate) ...
    pub sample_null_bound: usize,
    /// ... of the significant, those whose lobe about the half vectors fits better than the
    /// same lobe about the light directions, with a normal determined at least as well as the
    /// Lambertian one ...
    pub sample_specular: usize,
    /// ... and the most that a coin toss would give (binomial quantile, p = ½). `auto` models
    /// the capture's lobes only when both counts exceed their bounds.
    pub sample_specular_bound: usize,
    /// Pixels fitted: a highlight attributed and [`MIN_LIGHTS`] lights out of shadow.
    pub fitted_pixels: usize,
    /// Of those, the pixels whose Lambertian fit over the lit readings fails its χ² test.
    pub lambert_rejected_pixels: usize,
    /// Of those, the pixels where the lobe is significant.
    pub significant_pixels: usize,
    /// Of those, the pixels whose lobe fit passes the χ² test.
    pub passing_pixels: usize,
    /// Pixels whose normal now comes from the lobe fit.
    pub refined_pixels: usize,
    /// Their share of the mask.
    pub refined_share: f64,
    /// Refined pixels with a sharpness of their own.
    pub own_exponent_pixels: usize,
    /// Readings of the mask the camera clipped at full scale ([`Capture::clip_levels`]), left
    /// out of the fits like shadows (a clipped reading only bounds its light's value from
    /// below; fitted as a value it pulls the normal off the highlight).
    pub clipped_readings: u64,
    /// With [`Reflectance::Material`]: the materials found and what each chose.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub materials: Vec<crate::solve::gloss::material::MaterialSummary>,
}

impl GlossSummary {
    /// The summary of `reflectance` before any pixel is fitted: Lambert chosen, every count 0.
    pub fn nothing_fitted(reflectance: Reflectance) -> GlossSummary {
        GlossSummary {
            reflectance,
            chosen: "lambert",
            exponent: None,
            roughness: None,
            sample_pixels: 0,
            sample_significant: 0,
            sample_null_bound: 0,
            sample_specular: 0,
            sample_specular_bound: 0,
            fitted_pixels: 0,
            lambert_rejected_pixels: 0,
            significant_pixels: 0,
            passing_pixels: 0,
            refined_pixels: 0,
            refined_share: 0.0,
            own_exponent_pixels: 0,
            clipped_readings: 0,
            materials: Vec::new(),
        }
    }
}

/// Per mask pixel: the fitted lobe's peak s and roughness √(2/m); NaN where not fitted, and
/// strength 0 (roughness NaN) where fitted without a significant lobe.
#[derive(Clone, Debug, Default)]
pub struct GlossMaps {
    pub strength: Vec<f32>,
    pub roughness: Vec<f32>,
}

/// Per-thread buffers of one pixel (no allocation per pixel).
pub(crate) struct Scratch {
    pub(crate) v: Vec<[f64; 3]>,
    pub(crate) b: Vec<f64>,
    pub(crate) g: Vec<f64>,
    pub(crate) used: Vec<bool>,
    /// The lights of the Lambertian estimate (USED), for the albedo.
    pub(crate) diffuse: Vec<bool>,
}

/// What every pixel's fit reads: the unit light directions, their half vectors, the noise.
pub(crate) struct Lights<'a> {
    pub(crate) dirs: &'a [[f64; 3]],
    pub(crate) half: Vec<[f64; 3]>,
    /// Per light and channel, the reading at and above which the camera clipped it
    /// ([`Capture::clip_levels`]): a clipped reading only bounds the light's true value from
    /// below, and the fits leave it out like a shadow.
    pub(crate) clip: Vec<[f32; 3]>,
    noise: &'a NoiseModel,
    /// χ² quantiles at the detector's confidence, by degrees of freedom.
    pub(crate) q: Vec<f64>,
    /// F quantiles at the detector's confidence: `f[j][d]` for j + 1 extra parameters and d
    /// degrees of freedom of the lobe fit's residual.
    f: [Vec<f64>; 2],
}

/// One pixel's fit.
#[derive(Clone, Copy)]
struct PixelFit {
    normal: [f64; 3],
    rho: f64,
    strength: f64,
    exponent: f64,
    own_exponent: bool,
    /// The fit has a lobe (s > 0) and its normal faces the camera and the lit lights.
    lobe: bool,
    /// The Lambertian fit's χ² over the lit readings exceeds its quantile.
    lambert_rejected: bool,
    /// The lobe's lowering of that χ² passes the F-test.
    significant: bool,
    /// The lobe about the half vectors fits better than the same lobe about the lights, and
    /// the fit's normal is determined at least as well as the Lambertian one.
    specular: bool,
    passes: bool,
}

impl Scratch {
    pub(crate) fn new(n: usize) -> Self {
        Scratch {
            v: vec![[0.0; 3]; n],
            b: vec![0.0; n],
            g: vec![0.0; n],
            used: vec![false; n],
            diffuse: vec![false; n],
        }
    }

    /// Loads a pixel's noise-weighted readings and the lights out of shadow and not clipped;
    /// returns their count, or 0 when the pixel has no highlight attributed (not fitted)
    /// unless `any`.
    pub(crate) fn load(
        &mut self,
        lights: &Lights,
        samples: &[f32],
        channels: usize,
        st: &[u8],
        any: bool,
    ) -> usize {
        if !any && !st.contains(&status::HIGHLIGHT) {
            return 0;
        }
        channel_mean(samples, channels, &mut self.g);
        let mut count = 0;
        for (k, &code) in st.iter().enumerate() {
            let kept = !clipped(samples, channels, k, &lights.clip);
            self.used[k] = (code == status::USED || code == status::HIGHLIGHT) && kept;
            self.diffuse[k] = code == status::USED && kept;
            count += self.used[k] as usize;
            let f = lights.noise.light_factor.get(k).copied().unwrap_or(1.0);
            let w = 1.0 / (f * lights.noise.variance(self.g[k].max(0.0)).sqrt());
            let l = lights.dirs[k];
            self.v[k] = [l[0] * w, l[1] * w, l[2] * w];
            self.b[k] = w;
            self.g[k] *= w;
        }
        count
    }

    pub(crate) fn data<'a>(&'a self, lights: &'a Lights) -> PixelData<'a> {
        PixelData {
            v: &self.v,
            h: &lights.half,
            b: &self.b,
            g: &self.g,
            used: &self.used,
        }
    }
}

impl Lights<'_> {
    /// The fit of one loaded pixel from the normal `start` at the capture's sharpness `m`.
    fn fit(&self, d: &PixelData, count: usize, start: [f64; 3], m: f64) -> PixelFit {
        let q1 = self.q[1];
        let (mut e, mut normal) = descend(d, start, m);
        let mut exponent = m;
        // A sharpness of the pixel's own where it pays for its parameter.
        let at_normal = LOBE_EXPONENTS
            .iter()
            .map(|&x| (fit_at(d, normal, x).0, x))
            .fold((f64::INFINITY, m), |a, b| if b.0 < a.0 { b } else { a });
        if at_normal.1 != m {
            let (eo, no) = descend(d, normal, at_normal.1);
            if eo + q1 < e {
                (e, normal, exponent) = (eo, no, at_normal.1);
            }
        }
        let own_exponent = exponent != m;
        let (_, rho, strength) = fit_at(d, normal, exponent);
        let lambert = diffuse_residual(d);
        // Unknowns: the normal's two angles, ρ and s, and the pixel's own m where it has one;
        // the Lambertian fit has three (the scaled normal).
        let params = 4 + own_exponent as usize;
        let dof = count.saturating_sub(params);
        // A surface reflects only the lights in front of it, diffusely or specularly: the fit's
        // normal must face the camera and every light the recursion found lit.
        let physical =
            normal[2] > 0.0 && (0..d.v.len()).all(|k| !d.used[k] || dot(d.v[k], normal) > 0.0);
        let lobe = strength > 0.0 && physical;
        // The same lobe about the light direction instead of the half vector: shading that
        // falls off faster than n · l (a non-linear camera response, sheen) fits it as well or
        // better, a highlight does not.
        let about_light = PixelData { h: self.dirs, ..*d };
        let specular = lobe && e < descend(&about_light, start, exponent).0;
        // The better-determined normal: the lobe fit's where its standard error (the
        // covariance of the fit, scaled by its residual per degree of freedom) is at most the
        // Lambertian fit's; a lobe that trades off against the diffuse term leaves the normal
        // loose.
        let determined = dof > 0
            && count > 3
            && lobe_normal_variance(d, normal, exponent, rho, strength) * e / dof as f64
                <= lambert_normal_variance(d) * lambert / (count - 3) as f64;
        PixelFit {
            normal,
            rho,
            strength,
            exponent,
            own_exponent,
            lobe,
            lambert_rejected: lambert > self.q[count.saturating_sub(3)],
            significant: lobe && lambert > self.q[count.saturating_sub(3)] && dof > 0 && {
                let extra = params - 3;
                let f = ((lambert - e) / extra as f64) / (e / dof as f64).max(1e-300);
                f > self.f[extra - 1][dof]
            },
            passes: dof > 0 && e <= self.q[dof],
            specular: specular && determined,
        }
    }
}

/// Refits the pixels of `est` (per mask pixel; `light_status` the recursion's statuses, `n`
/// per pixel) that carry a highlight with the lobe model, and takes the fitted normal (and the
/// albedo of the Lambertian lights at it) where `reflectance` says (see the module
/// documentation). Returns the summary and the maps; nothing is fitted with
/// [`Reflectance::Lambert`].
pub fn model_highlights(
    capture: &Capture,
    light_status: &(impl Statuses + ?Sized),
    est: &mut Estimate,
    noise: &NoiseModel,
    confidence: f64,
    reflectance: Reflectance,
) -> Result<(GlossSummary, GlossMaps)> {
    let (n, c, np) = (capture.n_lights(), capture.channels, capture.n_pixels());
    let dirs = &capture.lights.directions;
    let half = dirs
        .iter()
        .map(|l| unit([l[0], l[1], l[2] + 1.0]))
        .collect();
    let lights = Lights {
        dirs,
        half,
        clip: capture.clip_levels(),
        noise,
        q: quantiles(confidence, n),
        f: [1, 2].map(|extra| f_quantiles(confidence, extra, n)),
    };
    let mut summary = GlossSummary::nothing_fitted(reflectance);
    let mut maps = GlossMaps {
        strength: vec![f32::NAN; np],
        roughness: vec![f32::NAN; np],
    };
    let few = n < MIN_LIGHTS;
    let material = reflectance == Reflectance::Material;
    if reflectance == Reflectance::Lambert || (few && !material) || n < material::MIN_SHARED_LIGHTS
    {
        return Ok((summary, maps));
    }
    let clipped = clipped_readings(capture, &lights.clip)?;
    summary.clipped_readings = clipped;
    if few {
        // No pixel has the lights for its own lobe, nor the capture for its sharpness: the
        // materials' shapes and strengths from the start lobe.
        let mut material =
            material::model_materials(capture, light_status, est, &lights, SHARED_START_EXPONENT)?;
        material.summary.reflectance = reflectance;
        material.summary.clipped_readings = clipped;
        return Ok((material.summary, material.maps));
    }
    let Some(evidence) = capture_sharpness(capture, light_status, est, &lights)? else {
        return Ok((summary, maps));
    };
    let m = evidence.exponent;
    if reflectance == Reflectance::Material {
        let mut material =
            crate::solve::gloss::material::model_materials(capture, light_status, est, &lights, m)?;
        material.summary.reflectance = reflectance;
        material.summary.clipped_readings = clipped;
        return Ok((material.summary, material.maps));
    }
    summary.exponent = Some(m);
    summary.roughness = Some((2.0 / m).sqrt());
    summary.sample_pixels = evidence.sampled;
    summary.sample_significant = evidence.significant;
    summary.sample_null_bound = binomial_quantile(evidence.sampled, 1.0 - confidence, confidence);
    summary.sample_specular = evidence.specular;
    summary.sample_specular_bound = binomial_quantile(evidence.significant, 0.5, confidence);
    if reflectance == Reflectance::Auto
        && (evidence.significant <= summary.sample_null_bound
            || evidence.specular <= summary.sample_specular_bound)
    {
        return Ok((summary, maps));
    }
    // (fitted, significant, passing, refined, own exponent, Lambert rejected)
    let counts = refit_pixels(
        capture,
        light_status,
        est,
        &mut maps,
        |scratch, samples, st, _, start, counts: &mut [usize; 6]| {
            let count = scratch.load(&lights, samples, c, st, false);
            if count < MIN_LIGHTS {
                return None;
            }
            let fit = lights.fit(&scratch.data(&lights), count, start, m);
            counts[0] += 1;
            counts[1] += fit.significant as usize;
            counts[2] += fit.passes as usize;
            counts[5] += fit.lambert_rejected as usize;
            let take = match reflectance {
                Reflectance::Auto => fit.significant && fit.specular,
                _ => fit.lobe,
            };
            if !take {
                return Some(None);
            }
            counts[3] += 1;
            counts[4] += fit.own_exponent as usize;
            Some(Some(Taken {
                normal: fit.normal,
                rho: fit.rho,
                strength: fit.strength,
                roughness: (2.0 / fit.exponent).sqrt(),
            }))
        },
    )?;
    let [fitted, significant, passing, refined, own, rejected] = counts;
    summary.fitted_pixels = fitted;
    summary.lambert_rejected_pixels = rejected;
    summary.significant_pixels = significant;
    summary.passing_pixels = passing;
    summary.refined_pixels = refined;
    summary.refined_share = refined as f64 / np.max(1) as f64;
    summary.own_exponent_pixels = own;
    if refined > 0 {
        summary.chosen = "lobe";
    }
    Ok((summary, maps))
}

/// The mask's readings with a channel at or above its light's clip level `clip`.
fn clipped_readings(capture: &Capture, clip: &[[f32; 3]]) -> Result<u64> {
    let (n, c) = (capture.n_lights(), capture.channels);
    let mut total = 0u64;
    let np = capture.n_pixels();
    capture.for_each_tile(|start, view| {
        total += (0..view.n_pixels().min(np - start))
            .into_par_iter()
            .map(|p| {
                let s = view.pixel_samples(p);
                (0..n).filter(|&k| clipped(s, c, k, clip)).count() as u64
            })
            .sum::<u64>();
        Ok(())
    })?;
    Ok(total)
}

/// A refitted pixel's result that replaces the recursion's estimate.
pub(crate) struct Taken {
    pub(crate) normal: [f64; 3],
    /// The diffuse albedo of the fit (grey), the scale of the Lambertian lights' albedo.
    pub(crate) rho: f64,
    pub(crate) strength: f64,
    pub(crate) roughness: f64,
}

/// Refits every mask pixel of `est` with a normal, tile by tile and in parallel: `refit`
/// (scratch, the pixel's samples, its statuses, the mask pixel, the start normal, the
/// counts) returns `None` to leave the pixel as it is (not fitted), `Some(None)` for a fit
/// that keeps the recursion's estimate (strength 0 in the maps), `Some(Some(taken))` for one
/// whose normal replaces it, with the albedo of the recursion's Lambertian lights (USED) at
/// that normal and the fit's strength and roughness in the maps. Returns the counts summed.
pub(crate) fn refit_pixels<const K: usize>(
    capture: &Capture,
    light_status: &(impl Statuses + ?Sized),
    est: &mut Estimate,
    maps: &mut GlossMaps,
    refit: impl Fn(&mut Scratch, &[f32], &[u8], usize, [f64; 3], &mut [usize; K]) -> Option<Option<Taken>>
        + Sync,
) -> Result<[usize; K]> {
    let (n, c) = (capture.n_lights(), capture.channels);
    let dirs = &capture.lights.directions;
    let mut counts = [0usize; K];
    capture.for_each_tile(|off, tile| {
        let tn = tile.n_pixels();
        let sums: Vec<[usize; K]> = est.normals[off..off + tn]
            .par_chunks_mut(CHUNK)
            .zip(est.albedo[off * c..(off + tn) * c].par_chunks_mut(CHUNK * c))
            .zip(maps.strength[off..off + tn].par_chunks_mut(CHUNK))
            .zip(maps.roughness[off..off + tn].par_chunks_mut(CHUNK))
            .enumerate()
            .map_init(
                || (Scratch::new(n), vec![0u8; n]),
                |(scratch, st), (chunk, (((normals, albedo), strength), roughness))| {
                    let mut counts = [0usize; K];
                    for (dp, normal) in normals.iter_mut().enumerate() {
                        let lp = chunk * CHUNK + dp;
                        let Some(start) = start_of(*normal) else {
                            continue;
                        };
                        let samples = tile.pixel_samples(lp);
                        light_status.row_into(off + lp, st);
                        let Some(fit) = refit(scratch, samples, st, off + lp, start, &mut counts)
                        else {
                            continue;
                        };
                        let Some(t) = fit else {
                            strength[dp] = 0.0;
                            continue;
                        };
                        strength[dp] = t.strength as f32;
                        roughness[dp] = t.roughness as f32;
                        let b = nalgebra::Vector3::from(t.normal) * t.rho.max(1e-12);
                        write_normal_albedo_with(
                            dirs,
                            c,
                            samples,
                            &b,
                            Some(&scratch.diffuse),
                            normal,
                            &mut albedo[dp * c..(dp + 1) * c],
                        );
                    }
                    counts
                },
            )
            .collect();
        for s in sums {
            for (a, b) in counts.iter_mut().zip(s) {
                *a += b;
            }
        }
        Ok(())
    })?;
    Ok(counts)
}

/// The capture's lobe sharpness and the evidence for its lobes (see [`capture_sharpness`]).
struct Evidence {
    exponent: f64,
    sampled: usize,
    significant: usize,
    /// Of the significant, those whose lobe about the half vectors beats the lobe about the
    /// lights.
    specular: usize,
}

/// The capture's lobe sharpness: over at most [`SAMPLE_PIXELS`] candidate pixels (a highlight
/// attributed, [`MIN_LIGHTS`] lights out of shadow), the exponent of [`LOBE_EXPONENTS`] whose
/// fits from the pixels' current normals have the least total χ²; and how many of those pixels
/// have a significant lobe at it. `None` without candidates.
fn capture_sharpness(
    capture: &Capture,
    light_status: &(impl Statuses + ?Sized),
    est: &Estimate,
    lights: &Lights,
) -> Result<Option<Evidence>> {
    let n = capture.n_lights();
    let mut st = vec![0u8; n];
    let candidates: Vec<usize> = (0..capture.n_pixels())
        .filter(|&p| {
            light_status.row_into(p, &mut st);
            st.contains(&status::HIGHLIGHT)
                && st
                    .iter()
                    .filter(|&&s| s == status::USED || s == status::HIGHLIGHT)
                    .count()
                    >= MIN_LIGHTS
                && start_of(est.normals[p]).is_some()
        })
        .collect();
    if candidates.is_empty() {
        return Ok(None);
    }
    let ids: Vec<usize> = candidates
        .iter()
        .step_by(candidates.len().div_ceil(SAMPLE_PIXELS).max(1))
        .copied()
        .collect();
    let mut totals = vec![0f64; LOBE_EXPONENTS.len()];
    let mut scratch = Scratch::new(n);
    capture.for_ids_by_tile(&ids, |sub, view| {
        for &p in sub {
            light_status.row_into(p, &mut st);
            scratch.load(lights, view.pixel_samples(p), capture.channels, &st, false);
            let d = scratch.data(lights);
            let start = start_of(est.normals[p]).expect("a candidate has a normal");
            let row: Vec<f64> = LOBE_EXPONENTS
                .par_iter()
                .map(|&m| descend(&d, start, m).0)
                .collect();
            for (t, e) in totals.iter_mut().zip(row) {
                *t += e;
            }
        }
        Ok(())
    })?;
    let best = (0..totals.len())
        .min_by(|&a, &b| totals[a].total_cmp(&totals[b]))
        .expect("exponents");
    let exponent = LOBE_EXPONENTS[best];
    let (mut significant, mut specular) = (0, 0);
    capture.for_ids_by_tile(&ids, |sub, view| {
        for &p in sub {
            light_status.row_into(p, &mut st);
            let count = scratch.load(lights, view.pixel_samples(p), capture.channels, &st, false);
            let start = start_of(est.normals[p]).expect("a candidate has a normal");
            let fit = lights.fit(&scratch.data(lights), count, start, exponent);
            significant += fit.significant as usize;
            specular += (fit.significant && fit.specular) as usize;
        }
        Ok(())
    })?;
    Ok(Some(Evidence {
        exponent,
        sampled: ids.len(),
        significant,
        specular,
    }))
}

/// The upper `confidence` quantile of the binomial distribution of `trials` tries with
/// success probability `p`: the least k with P(X ≤ k) ≥ confidence (pmf summed in logs).
fn binomial_quantile(trials: usize, p: f64, confidence: f64) -> usize {
    use crate::base::stats::ln_gamma;
    let nf = trials as f64;
    let mut cdf = 0.0;
    for k in 0..=trials {
        let kf = k as f64;
        let ln_pmf = ln_gamma(nf + 1.0) - ln_gamma(kf + 1.0) - ln_gamma(nf - kf + 1.0)
            + kf * p.ln()
            + (nf - kf) * (1.0 - p).ln();
        cdf += ln_pmf.exp();
        if cdf >= confidence {
            return k;
        }
    }
    trials
}

/// F quantiles at `confidence` with `extra` numerator degrees of freedom, for 0..=n denominator
/// degrees of freedom (infinite for none: no test).
fn f_quantiles(confidence: f64, extra: usize, n: usize) -> Vec<f64> {
    (0..=n)
        .map(|d| {
            if d == 0 {
                f64::INFINITY
            } else {
                crate::base::stats::f_quantile(confidence, extra, d)
            }
        })
        .collect()
}

/// Iterations of [`descend`] at most.
pub(crate) const MAX_STEPS: usize = 30;
/// [`descend`] stops when the normal moves by less than this, radians (0.003°).
pub(crate) const SMALLEST_STEP: f64 = 5e-5;

/// The Levenberg–Marquardt descent of [`descend`] and of the per-material fit
/// ([`crate::solve::gloss::material`]): from `from`, steps in the normal's two tangent angles and (ρ, s)
/// solved from the normal equations (JᵀJ, Jᵀr) that `normal_equations(n, (t1, t2), ρ, s)` sums
/// over the readings, each step's normal scored by `fit(n)` → (χ², ρ, s) with ρ and s solved
/// exactly, so that χ² never rises. Returns (χ², normal).
pub(crate) fn descend_by(
    from: [f64; 3],
    fit: impl Fn([f64; 3]) -> (f64, f64, f64),
    normal_equations: impl Fn([f64; 3], ([f64; 3], [f64; 3]), f64, f64) -> (Matrix4<f64>, Vector4<f64>),
) -> (f64, [f64; 3]) {
    let mut n = from;
    let (mut e, mut rho, mut s) = fit(n);
    let mut lambda = 1e-3;
    for _ in 0..MAX_STEPS {
        let (t1, t2) = basis(n);
        let (jtj, jtr) = normal_equations(n, (t1, t2), rho, s);
        let mut moved = false;
        while lambda < 1e8 {
            let mut damped = jtj;
            for i in 0..4 {
                damped[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
            }
            let Some(step) = damped.lu().solve(&jtr) else {
                lambda *= 10.0;
                continue;
            };
            let turn = (step[0] * step[0] + step[1] * step[1]).sqrt();
            let c = unit([
                n[0] + step[0] * t1[0] + step[1] * t2[0],
                n[1] + step[0] * t1[1] + step[1] * t2[1],
                n[2] + step[0] * t1[2] + step[1] * t2[2],
            ]);
            let (ec, rc, sc) = fit(c);
            if ec < e {
                (e, n, rho, s) = (ec, c, rc, sc);
                lambda = (lambda * 0.1).max(1e-7);
                moved = turn > SMALLEST_STEP;
                break;
            }
            if turn < SMALLEST_STEP {
                break;
            }
            lambda *= 10.0;
        }
        if !moved {
            break;
        }
    }
    (e, n)
}

/// The least χ² normal for sharpness `m` near `from` (returns (χ², normal)): Levenberg–Marquardt
/// steps in the normal's two tangent angles and (ρ, s), each step's normal then scored with ρ
/// and s solved exactly ([`fit_at`], non-negative), so that χ² never rises. The model is smooth
/// in n except where n · l_k changes sign, and the start (the recursion's normal) lies within a
/// few degrees of the fit: a descent finds the minimum in a fraction of the evaluations of the
/// near-light fit's pattern search, which has to search from far starts.
pub(crate) fn descend(d: &PixelData, from: [f64; 3], m: f64) -> (f64, [f64; 3]) {
    descend_by(
        from,
        |n| fit_at(d, n, m),
        |n, (t1, t2), rho, s| {
            let (mut jtj, mut jtr) = (Matrix4::<f64>::zeros(), Vector4::<f64>::zeros());
            for k in (0..d.v.len()).filter(|&k| d.used[k]) {
                let vn = dot(d.v[k], n);
                let lobe = d.b[k] * (-m * (1.0 - dot(d.h[k], n))).exp();
                let (a, lit) = if vn > 0.0 { (vn, 1.0) } else { (0.0, 0.0) };
                let r = d.g[k] - rho * a - s * lobe;
                let j = Vector4::new(
                    rho * lit * dot(d.v[k], t1) + s * lobe * m * dot(d.h[k], t1),
                    rho * lit * dot(d.v[k], t2) + s * lobe * m * dot(d.h[k], t2),
                    a,
                    lobe,
                );
                jtj += j * j.transpose();
                jtr += j * r;
            }
            (jtj, jtr)
        },
    )
}

/// The variance (rad², per unit residual variance) of the lobe fit's normal at `n`: the sum of
/// the tangent-angle entries of (JᵀJ)⁻¹ over (angles, ρ, s). Infinite where JᵀJ is singular.
fn lobe_normal_variance(d: &PixelData, n: [f64; 3], m: f64, rho: f64, s: f64) -> f64 {
    let (t1, t2) = basis(n);
    let mut jtj = Matrix4::<f64>::zeros();
    for k in (0..d.v.len()).filter(|&k| d.used[k]) {
        let vn = dot(d.v[k], n);
        let lobe = d.b[k] * (-m * (1.0 - dot(d.h[k], n))).exp();
        let (a, lit) = if vn > 0.0 { (vn, 1.0) } else { (0.0, 0.0) };
        let j = Vector4::new(
            rho * lit * dot(d.v[k], t1) + s * lobe * m * dot(d.h[k], t1),
            rho * lit * dot(d.v[k], t2) + s * lobe * m * dot(d.h[k], t2),
            a,
            lobe,
        );
        jtj += j * j.transpose();
    }
    jtj.try_inverse()
        .map_or(f64::INFINITY, |c| (c[(0, 0)] + c[(1, 1)]).max(0.0))
}

/// The variance (rad², per unit residual variance) of the Lambertian fit's normal: with
/// b = (VᵀV)⁻¹Vᵀg over the lit lights, the part of (VᵀV)⁻¹ across b, over |b|².
fn lambert_normal_variance(d: &PixelData) -> f64 {
    use nalgebra::{Matrix3, Vector3};
    let mut vtv = Matrix3::<f64>::zeros();
    let mut vtg = Vector3::<f64>::zeros();
    for k in (0..d.v.len()).filter(|&k| d.used[k]) {
        let v = Vector3::from(d.v[k]);
        vtv += v * v.transpose();
        vtg += v * d.g[k];
    }
    let Some(c) = vtv.try_inverse() else {
        return f64::INFINITY;
    };
    let b = c * vtg;
    let r2 = b.norm_squared();
    if r2 <= 0.0 {
        return f64::INFINITY;
    }
    let u = b / r2.sqrt();
    ((c.trace() - (u.transpose() * c * u)[(0, 0)]) / r2).max(0.0)
}

pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `x` as an f64 unit vector, or `None` for the zero vector (no normal).
pub(crate) fn start_of(x: [f32; 3]) -> Option<[f64; 3]> {
    (x != [0.0; 3]).then(|| unit([x[0] as f64, x[1] as f64, x[2] as f64]))
}

pub(crate) fn unit(a: [f64; 3]) -> [f64; 3] {
    let r = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    if r > 0.0 {
        [a[0] / r, a[1] / r, a[2] / r]
    } else {
        [0.0, 0.0, 1.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binomial_quantiles_match_exact_sums() {
        // Exact cumulative sums of C(n, k) p^k (1 − p)^(n − k), computed independently.
        assert_eq!(binomial_quantile(400, 0.01, 0.99), 9);
        assert_eq!(binomial_quantile(10, 0.5, 0.5), 5);
        assert_eq!(binomial_quantile(50, 0.05, 0.95), 5);
        assert_eq!(binomial_quantile(0, 0.01, 0.99), 0);
    }
}
