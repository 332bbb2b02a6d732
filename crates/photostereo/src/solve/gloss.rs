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
//! over every light the recursion did not put in shadow (shadows stay excluded; the
//! recursion's statuses are not changed). The readings are weighted by their noise, σ_k² =
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
//! Levenberg–Marquardt descent, `descend`). The lobe is significant where it lowers the χ² of
//! the best Lambertian fit over the same lights by more than the χ²₁ quantile at the detector's
//! confidence (one more parameter, s). With [`Reflectance::Auto`] a significant fit's normal
//! replaces the recursion's; with [`Reflectance::Lobe`] every fit with a lobe (s > 0) does;
//! elsewhere the recursion's choice of lights stands. The fit's own χ² test (χ² at most the
//! quantile of N_fit − 4 degrees of freedom, N_fit − 5 with its own m) is reported, not used:
//! on real captures the lobe, like the Lambertian model over the lights the recursion keeps,
//! rarely explains the readings to the noise level, while its normal is the better one.
//!
//! Light ring and four-light rigs leave fewer than [`MIN_LIGHTS`] lights: nothing is fitted
//! there. Cost: a few Gauss–Newton passes over the pixel's lights per fitted pixel; memory two
//! f32 maps per mask pixel.

use crate::base::error::Result;
use crate::model::capture::Capture;
use crate::solve::detect::NoiseModel;
use crate::solve::lambert::{
    channel_mean, status, write_normal_albedo_with, Estimate, Statuses, CHUNK,
};
use crate::solve::near_lobe::{basis, diffuse_residual, fit_at, quantiles, PixelData};
use rayon::prelude::*;
use serde::Serialize;
use std::str::FromStr;

/// Lights out of shadow a pixel needs for its lobe fit: the four unknowns (n, ρ, s) and two
/// degrees of freedom for the residual to be compared with the Lambertian fit's.
pub const MIN_LIGHTS: usize = crate::solve::near_lobe::MIN_LIGHTS;
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
}

impl Reflectance {
    /// Every choice, default first.
    pub const ALL: &'static [Reflectance] =
        &[Reflectance::Lambert, Reflectance::Auto, Reflectance::Lobe];

    /// The name accepted by `--reflectance` (and the Python keyword `reflectance`).
    pub fn name(self) -> &'static str {
        match self {
            Reflectance::Lambert => "lambert",
            Reflectance::Lobe => "lobe",
            Reflectance::Auto => "auto",
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
    /// Pixels fitted: a highlight attributed and [`MIN_LIGHTS`] lights out of shadow.
    pub fitted_pixels: usize,
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
}

/// Per mask pixel: the fitted lobe's peak s and roughness √(2/m); NaN where not fitted, and
/// strength 0 (roughness NaN) where fitted without a significant lobe.
#[derive(Clone, Debug, Default)]
pub struct GlossMaps {
    pub strength: Vec<f32>,
    pub roughness: Vec<f32>,
}

/// Per-thread buffers of one pixel (no allocation per pixel).
struct Scratch {
    v: Vec<[f64; 3]>,
    b: Vec<f64>,
    g: Vec<f64>,
    used: Vec<bool>,
    /// The lights of the Lambertian estimate (USED), for the albedo.
    diffuse: Vec<bool>,
}

/// What every pixel's fit reads: the unit light directions, their half vectors, the noise.
struct Lights<'a> {
    dirs: &'a [[f64; 3]],
    half: Vec<[f64; 3]>,
    noise: &'a NoiseModel,
    /// χ² quantiles at the detector's confidence, by degrees of freedom.
    q: Vec<f64>,
}

/// One pixel's fit.
#[derive(Clone, Copy)]
struct PixelFit {
    normal: [f64; 3],
    rho: f64,
    strength: f64,
    exponent: f64,
    own_exponent: bool,
    /// The fit has a lobe (s > 0).
    lobe: bool,
    significant: bool,
    passes: bool,
}

impl Scratch {
    fn new(n: usize) -> Self {
        Scratch {
            v: vec![[0.0; 3]; n],
            b: vec![0.0; n],
            g: vec![0.0; n],
            used: vec![false; n],
            diffuse: vec![false; n],
        }
    }

    /// Loads a pixel's noise-weighted readings and the lights out of shadow; returns their
    /// count, or 0 when the pixel has no highlight attributed (not fitted).
    fn load(&mut self, lights: &Lights, samples: &[f32], channels: usize, st: &[u8]) -> usize {
        if !st.contains(&status::HIGHLIGHT) {
            return 0;
        }
        channel_mean(samples, channels, &mut self.g);
        let mut count = 0;
        for (k, &code) in st.iter().enumerate() {
            self.used[k] = code == status::USED || code == status::HIGHLIGHT;
            self.diffuse[k] = code == status::USED;
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

    fn data<'a>(&'a self, lights: &'a Lights) -> PixelData<'a> {
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
        let dof = count.saturating_sub(4 + own_exponent as usize);

        PixelFit {
            normal,
            rho,
            strength,
            exponent,
            own_exponent,
            lobe: strength > 0.0,
            significant: strength > 0.0 && lambert - e > q1,
            passes: dof > 0 && e <= self.q[dof],
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
        noise,
        q: quantiles(confidence, n),
    };
    let mut summary = GlossSummary {
        reflectance,
        chosen: "lambert",
        exponent: None,
        roughness: None,
        fitted_pixels: 0,
        significant_pixels: 0,
        passing_pixels: 0,
        refined_pixels: 0,
        refined_share: 0.0,
        own_exponent_pixels: 0,
    };
    let mut maps = GlossMaps {
        strength: vec![f32::NAN; np],
        roughness: vec![f32::NAN; np],
    };
    if reflectance == Reflectance::Lambert || n < MIN_LIGHTS {
        return Ok((summary, maps));
    }
    let Some(m) = capture_sharpness(capture, light_status, est, &lights)? else {
        return Ok((summary, maps));
    };
    summary.exponent = Some(m);
    summary.roughness = Some((2.0 / m).sqrt());
    // (fitted, significant, passing, refined, own exponent)
    let mut counts = [0usize; 5];
    capture.for_each_tile(|off, tile| {
        let tn = tile.n_pixels();
        let sums: Vec<[usize; 5]> = est.normals[off..off + tn]
            .par_chunks_mut(CHUNK)
            .zip(est.albedo[off * c..(off + tn) * c].par_chunks_mut(CHUNK * c))
            .zip(maps.strength[off..off + tn].par_chunks_mut(CHUNK))
            .zip(maps.roughness[off..off + tn].par_chunks_mut(CHUNK))
            .enumerate()
            .map_init(
                || (Scratch::new(n), vec![0u8; n]),
                |(scratch, st), (chunk, (((normals, albedo), strength), roughness))| {
                    let mut counts = [0usize; 5];
                    for (dp, normal) in normals.iter_mut().enumerate() {
                        let lp = chunk * CHUNK + dp;
                        let p = off + lp;
                        let samples = tile.pixel_samples(lp);
                        light_status.row_into(p, st);
                        let count = scratch.load(&lights, samples, c, st);
                        let Some(start) = start_of(*normal) else {
                            continue;
                        };
                        if count < MIN_LIGHTS {
                            continue;
                        }
                        let fit = lights.fit(&scratch.data(&lights), count, start, m);
                        counts[0] += 1;
                        counts[1] += fit.significant as usize;
                        counts[2] += fit.passes as usize;
                        let take = match reflectance {
                            Reflectance::Auto => fit.significant,
                            _ => fit.lobe,
                        };
                        if !take {
                            strength[dp] = 0.0;
                            continue;
                        }
                        strength[dp] = fit.strength as f32;
                        roughness[dp] = (2.0 / fit.exponent).sqrt() as f32;
                        counts[3] += 1;
                        counts[4] += fit.own_exponent as usize;
                        let b = nalgebra::Vector3::from(fit.normal) * fit.rho.max(1e-12);
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
    let [fitted, significant, passing, refined, own] = counts;
    summary.fitted_pixels = fitted;
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

/// The capture's lobe sharpness: over at most [`SAMPLE_PIXELS`] candidate pixels (a highlight
/// attributed, [`MIN_LIGHTS`] lights out of shadow), the exponent of [`LOBE_EXPONENTS`] whose
/// fits from the pixels' current normals have the least total χ². `None` without candidates.
fn capture_sharpness(
    capture: &Capture,
    light_status: &(impl Statuses + ?Sized),
    est: &Estimate,
    lights: &Lights,
) -> Result<Option<f64>> {
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
            scratch.load(lights, view.pixel_samples(p), capture.channels, &st);
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
    Ok(Some(LOBE_EXPONENTS[best]))
}

/// Iterations of [`descend`] at most.
const MAX_STEPS: usize = 30;
/// [`descend`] stops when the normal moves by less than this, radians (0.003°).
const SMALLEST_STEP: f64 = 5e-5;

/// The least χ² normal for sharpness `m` near `from` (returns (χ², normal)): Levenberg–Marquardt
/// steps in the normal's two tangent angles and (ρ, s), each step's normal then scored with ρ
/// and s solved exactly ([`fit_at`], non-negative), so that χ² never rises. The model is smooth
/// in n except where n · l_k changes sign, and the start (the recursion's normal) lies within a
/// few degrees of the fit: a descent finds the minimum in a fraction of the evaluations of the
/// near-light fit's pattern search, which has to search from far starts.
fn descend(d: &PixelData, from: [f64; 3], m: f64) -> (f64, [f64; 3]) {
    use nalgebra::{Matrix4, Vector4};
    let mut n = from;
    let (mut e, mut rho, mut s) = fit_at(d, n, m);
    let mut lambda = 1e-3;
    for _ in 0..MAX_STEPS {
        let (t1, t2) = basis(n);
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
            let (ec, rc, sc) = fit_at(d, c, m);
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

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `x` as an f64 unit vector, or `None` for the zero vector (no normal).
fn start_of(x: [f32; 3]) -> Option<[f64; 3]> {
    (x != [0.0; 3]).then(|| unit([x[0] as f64, x[1] as f64, x[2] as f64]))
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let r = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    if r > 0.0 {
        [a[0] / r, a[1] / r, a[2] / r]
    } else {
        [0.0, 0.0, 1.0]
    }
}
