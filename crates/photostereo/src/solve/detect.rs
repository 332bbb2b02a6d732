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

use crate::base::error::{Error, Result};
use crate::base::progress::Progress;
use crate::base::stats::{chi2_quantile, normal_upper_quantile};
use crate::model::capture::Capture;
use crate::solve::lambert::{channel_mean, status, CHUNK};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

/// Parameters of the detector. Every default comes from a principle stated on its field.
#[derive(Clone, Debug, Serialize)]
pub struct DetectionParams {
    /// Image noise σ per channel, in units of the normalised intensities (full scale = 1).
    /// `None`: estimate the noise model from the capture. The test works on channel means, so
    /// σ is divided by √C (independent channels).
    pub sigma: Option<f64>,
    /// Relative noise κ (share of the pixel's intensity level): the model error of the capture
    /// that the test must accept (light calibration, sensor response), which grows with
    /// brightness. Default `None`: measured on the capture itself ([`estimate_kappa`]: the
    /// light-to-light part of the misfit — the differences of the residuals of neighbouring
    /// lights after a trimmed fit, so that smooth departures from Lambert such as a broad
    /// specular lobe, which the test is there to find, do not count — with the lights' noise
    /// factors weighting the fit when `light_noise` is on; 0–1% on the demo's renders,
    /// 0.5–1.1% on DiLiGenT, 2.7–4.2% on psmImages), or [`DEFAULT_RELATIVE_NOISE`] (1%, the
    /// model error a calibrated rig leaves: intensities known to about 1%, directions to about
    /// half a degree) where it cannot be measured (fewer than [`MIN_KAPPA_LIGHTS`] lights, near
    /// lights).
    /// `Some(κ)` fixes it. The engine reports the measured value either way.
    pub relative_noise: Option<f64>,
    /// Confidence of the χ² test (default 0.95, the paper's 2σ for four lights).
    pub confidence: f64,
    /// Attribution keeps at least this share of the lights (and never fewer than three).
    /// Default 0.25: on a convex surface about half the lights of a dense dome can be in attached
    /// shadow at grazing normals; a floor well below that keeps the fit determined.
    pub min_kept_share: f64,
    /// Family-wise error rate for removing, in one step, several lights that read at the shadow
    /// level while the fit predicts clearly more (Bonferroni over the lights, two-sided).
    /// Default 0.05.
    pub batch_alpha: f64,
    /// A reading is at the shadow level when it is below
    /// `floor + shadow_sigmas · σ_p + shadow_ratio · Ī_p` (default 3σ and 10% of the pixel's mean
    /// level), `floor` the capture's dark floor ([`NoiseModel::floor`]). Only such readings are
    /// labelled shadows; a removed reading above it is a highlight if brighter than predicted and
    /// "rejected" (darker than the model allows, yet lit) otherwise.
    pub shadow_sigmas: f64,
    /// See `shadow_sigmas`.
    pub shadow_ratio: f64,
    /// Attribute the failures to lights (default true). Without it only the test runs (the
    /// residual and unreliable maps), in O(N) per pixel.
    pub attribute: bool,
    /// How σ₀ is estimated when `sigma` is not given (default: from the images).
    pub noise_estimate: NoiseEstimate,
    /// Rounds of noise re-estimation from the pixels' retained lights, for
    /// [`NoiseEstimate::Residuals`] (default 1, at most [`MAX_NOISE_REFINEMENTS`]).
    pub noise_refinements: usize,
    /// Measure a noise factor per light ([`light_noise_factors`], distant lights): a light whose
    /// readings disagree with the others' fit more than the typical light's gets its own larger
    /// κ_k (default true). The test is then weighted least squares with those factors.
    pub light_noise: bool,
}

impl Default for DetectionParams {
    fn default() -> Self {
        DetectionParams {
            sigma: None,
            relative_noise: None,
            confidence: 0.95,
            min_kept_share: 0.25,
            batch_alpha: 0.05,
            shadow_sigmas: 3.0,
            shadow_ratio: 0.1,
            attribute: true,
            noise_estimate: NoiseEstimate::Images,
            noise_refinements: 1,
            light_noise: true,
        }
    }
}

/// Where the noise floor σ₀ comes from when it is not given.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum NoiseEstimate {
    /// The sensor noise of the images themselves: in each image, the robust spread (1.4826 ×
    /// median absolute value) of a 3×3 second-difference filter whose response to a smooth
    /// surface is nearly zero (Immerkær's operator, 6σ for white noise), over object pixels whose
    /// 3×3 neighbourhood lies in the mask; the median over the images. κ is then the relative
    /// model error (`relative_noise`).
    Images,
    /// From the least-squares residuals: a low quantile (25%) of the all-light residuals in eight
    /// brightness bins fits σ₀ and κ, refined from the residuals of the lights each pixel kept.
    /// Model error then counts as noise, which makes the test lenient on real captures.
    Residuals,
}

/// The most rounds of noise re-estimation: each is a pass over the capture, and the estimate
/// settles within a few.
pub const MAX_NOISE_REFINEMENTS: usize = 20;

impl NoiseEstimate {
    /// Every choice, default first.
    pub const ALL: &'static [NoiseEstimate] = &[NoiseEstimate::Images, NoiseEstimate::Residuals];

    /// The name the front ends accept (`noise_estimate`).
    pub fn name(self) -> &'static str {
        match self {
            NoiseEstimate::Images => "images",
            NoiseEstimate::Residuals => "residuals",
        }
    }
}

impl std::str::FromStr for NoiseEstimate {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        crate::base::error::parse_name(s, NoiseEstimate::ALL, NoiseEstimate::name, "noise_estimate")
    }
}

impl DetectionParams {
    /// Checks the parameters' domains; errors name the parameter (the library's spelling,
    /// [`Error::Parameter`]).
    pub fn validate(&self) -> Result<()> {
        if self.noise_refinements > MAX_NOISE_REFINEMENTS {
            return Err(Error::parameter(
                "noise_refinements",
                format!(
                    "{}: expected an integer in [0, {MAX_NOISE_REFINEMENTS}]",
                    self.noise_refinements
                ),
            ));
        }
        if let Some(s) = self.sigma {
            if !(s.is_finite() && s > 0.0) {
                return Err(Error::parameter(
                    "sigma",
                    format!("{s}: expected a finite positive noise level"),
                ));
            }
        }
        if let Some(k) = self.relative_noise {
            if !(k.is_finite() && k >= 0.0) {
                return Err(Error::parameter(
                    "relative_noise",
                    format!("{k}: expected a finite value ≥ 0"),
                ));
            }
        }
        if !(self.confidence > 0.5 && self.confidence < 1.0) {
            return Err(Error::parameter(
                "confidence",
                format!("{}: expected a value in (0.5, 1)", self.confidence),
            ));
        }
        if !(0.0..=1.0).contains(&self.min_kept_share) {
            return Err(Error::parameter(
                "min_kept_share",
                format!("{}: expected a value in [0, 1]", self.min_kept_share),
            ));
        }
        if !(self.batch_alpha > 0.0 && self.batch_alpha < 1.0) {
            return Err(Error::parameter(
                "batch_alpha",
                format!("{}: expected a value in (0, 1)", self.batch_alpha),
            ));
        }
        for (name, v) in [
            ("shadow_sigmas", self.shadow_sigmas),
            ("shadow_ratio", self.shadow_ratio),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::parameter(
                    name,
                    format!("{v}: expected a finite value ≥ 0"),
                ));
            }
        }
        Ok(())
    }
}

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

/// Per-capture constants of the test (per pixel with near lights: see [`Test::set_directions`]).
#[derive(Clone)]
struct Test {
    directions: Vec<Vector3<f64>>,
    /// Structure-of-arrays copies for vectorised loops: components and the products that
    /// give the leverage lᵀ G⁻¹ l from the six distinct entries of the symmetric G⁻¹.
    lx: Vec<f64>,
    ly: Vec<f64>,
    lz: Vec<f64>,
    quad: [Vec<f64>; 6],
    gram: Matrix3<f64>,
    gram_inv: Matrix3<f64>,
    /// thresholds[d] = χ²_d quantile at the confidence (d = 1..N−3).
    thresholds: Vec<f64>,
    /// z² of the batch-removal test.
    batch_z2: f64,
    min_kept: usize,
    /// Per light 1 / c_k ([`NoiseModel::light_factor`]; empty: all 1). The test then works on
    /// the readings and light vectors divided by c_k — weighted least squares with weights
    /// 1 / c_k², whose statistic is χ² under the per-light noise — and `directions` (with the
    /// copies and the normal matrix) hold the divided vectors.
    inv_factor: Vec<f64>,
}

impl Test {
    fn new(capture: &Capture, params: &DetectionParams) -> Result<Self> {
        let n = capture.n_lights();
        if n < 4 {
            return Err(Error::invalid(format!(
                "detection needs at least four lights (the test has N − 3 degrees of freedom); the capture has {n}"
            )));
        }
        let directions: Vec<Vector3<f64>> = capture
            .lights
            .directions
            .iter()
            .map(|d| Vector3::from(*d))
            .collect();
        let gram = capture.lights.gram();
        let gram_inv = gram
            .try_inverse()
            .ok_or_else(|| Error::invalid("singular light matrix"))?;
        let mut thresholds = vec![f64::INFINITY; n - 2];
        for (d, t) in thresholds.iter_mut().enumerate().skip(1) {
            *t = chi2_quantile(params.confidence, d);
        }
        let z = normal_upper_quantile(params.batch_alpha / (2.0 * n as f64));
        let min_kept = ((params.min_kept_share * n as f64).ceil() as usize).max(3);
        let lx: Vec<f64> = directions.iter().map(|l| l.x).collect();
        let ly: Vec<f64> = directions.iter().map(|l| l.y).collect();
        let lz: Vec<f64> = directions.iter().map(|l| l.z).collect();
        let quad = [
            directions.iter().map(|l| l.x * l.x).collect(),
            directions.iter().map(|l| l.y * l.y).collect(),
            directions.iter().map(|l| l.z * l.z).collect(),
            directions.iter().map(|l| 2.0 * l.x * l.y).collect(),
            directions.iter().map(|l| 2.0 * l.x * l.z).collect(),
            directions.iter().map(|l| 2.0 * l.y * l.z).collect(),
        ];
        Ok(Test {
            directions,
            lx,
            ly,
            lz,
            quad,
            gram,
            gram_inv,
            thresholds,
            batch_z2: z * z,
            min_kept,
            inv_factor: Vec::new(),
        })
    }

    /// The test of a capture under a noise model: [`Test::new`] with the light vectors divided
    /// by the model's per-light factors (when it has them).
    fn with_noise(capture: &Capture, params: &DetectionParams, noise: &NoiseModel) -> Result<Self> {
        let mut test = Test::new(capture, params)?;
        let n = test.directions.len();
        if noise.light_factor.len() == n && noise.light_factor.iter().any(|&c| c != 1.0) {
            test.inv_factor = noise.light_factor.iter().map(|&c| 1.0 / c).collect();
            let dirs: Vec<[f64; 3]> = capture.lights.directions.clone();
            if !test.set_directions(&dirs) {
                return Err(Error::invalid("singular light matrix"));
            }
        }
        Ok(test)
    }

    /// 1 / c_k of light k.
    #[inline]
    fn inv_factor(&self, k: usize) -> f64 {
        self.inv_factor.get(k).copied().unwrap_or(1.0)
    }
}

impl Test {
    /// Replaces the light vectors (a pixel's own near-light vectors, ALGORITHMS.md §9): the
    /// structure-of-arrays copies and the normal matrix follow. Returns false when the vectors
    /// do not determine a normal (singular normal matrix).
    fn set_directions(&mut self, dirs: &[[f64; 3]]) -> bool {
        let mut gram = Matrix3::zeros();
        for (k, d) in dirs.iter().enumerate() {
            let l = Vector3::from(*d) * self.inv_factor(k);
            self.directions[k] = l;
            self.lx[k] = l.x;
            self.ly[k] = l.y;
            self.lz[k] = l.z;
            self.quad[0][k] = l.x * l.x;
            self.quad[1][k] = l.y * l.y;
            self.quad[2][k] = l.z * l.z;
            self.quad[3][k] = 2.0 * l.x * l.y;
            self.quad[4][k] = 2.0 * l.x * l.z;
            self.quad[5][k] = 2.0 * l.y * l.z;
            gram += l * l.transpose();
        }
        self.gram = gram;
        match gram.try_inverse() {
            Some(inv) => {
                self.gram_inv = inv;
                true
            }
            None => false,
        }
    }
}

/// Per-pixel test constants with near lights: a copy of the test and the light model's access.
struct NearTest<'a> {
    test: Test,
    lights: crate::model::lightmodel::PixelLights<'a>,
}

impl<'a> NearTest<'a> {
    fn of(capture: &'a Capture, test: &Test) -> Option<Self> {
        capture.lights.near.as_deref().map(|m| NearTest {
            test: test.clone(),
            lights: crate::model::lightmodel::PixelLights::new(
                &capture.lights.directions,
                Some(m),
                capture.width,
            ),
        })
    }

    /// The test at full-frame pixel `pixel`; None where its vectors are singular.
    fn at(&mut self, pixel: usize) -> Option<&Test> {
        let dirs = self.lights.at(pixel);
        self.test.set_directions(dirs).then_some(&self.test)
    }
}

/// Per-thread scratch space: no allocation per pixel.
struct Scratch {
    grey: Vec<f64>,
    /// The readings divided by their lights' noise factors (the test's weighted readings;
    /// `grey` itself where the factors are all 1).
    sgrey: Vec<f64>,
    /// 1.0 for kept lights, 0.0 for removed ones (branch-free loops).
    weight: Vec<f64>,
    resid: Vec<f64>,
    score: Vec<f64>,
    /// Lights removed together in one step of the attribution.
    candidates: Vec<usize>,
    /// The last score pass's largest score (light, score) and the runner-up score.
    best: (usize, f64, f64),
}

impl Scratch {
    fn new(n: usize) -> Self {
        Scratch {
            grey: vec![0.0; n],
            sgrey: vec![0.0; n],
            weight: vec![1.0; n],
            resid: vec![0.0; n],
            score: vec![0.0; n],
            candidates: Vec::with_capacity(n),
            best: (usize::MAX, -1.0, -1.0),
        }
    }
}

/// Least squares over the kept lights: (m, RSS, kept count, G⁻¹), or None if singular.
#[inline]
fn fit(
    test: &Test,
    grey: &[f64],
    kept: &[bool],
    gram_inv: &Matrix3<f64>,
) -> (Vector3<f64>, f64, usize) {
    let mut b = Vector3::zeros();
    let mut count = 0;
    for ((l, &i), &k) in test.directions.iter().zip(grey).zip(kept) {
        if k {
            b += l * i;
            count += 1;
        }
    }
    let m = gram_inv * b;
    let mut rss = 0.0;
    for ((l, &i), &k) in test.directions.iter().zip(grey).zip(kept) {
        if k {
            let e = i - l.dot(&m);
            rss += e * e;
        }
    }
    (m, rss, count)
}

/// One pass over the lights: residuals eₖ = Iₖ − lₖ·m, deleted-residual scores
/// wₖ eₖ² / (1 − hₖ) with hₖ = lₖᵀ G⁻¹ lₖ, and the residual sum of squares over kept lights.
///
/// On x86-64 processors with AVX2 the same code runs compiled for 4-wide vectors. Rust never
/// fuses a multiply and an add on its own, so every operation rounds as in the baseline build
/// and the results are bit-identical on every processor.
#[inline]
fn score_pass(test: &Test, s: &mut Scratch, m: &Vector3<f64>, gi: &Matrix3<f64>) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor supports AVX2 (checked just above).
        return unsafe { score_pass_avx2(test, s, m, gi) };
    }
    score_pass_portable(test, s, m, gi)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn score_pass_avx2(test: &Test, s: &mut Scratch, m: &Vector3<f64>, gi: &Matrix3<f64>) -> f64 {
    score_pass_portable(test, s, m, gi)
}

#[inline(always)]
fn score_pass_portable(test: &Test, s: &mut Scratch, m: &Vector3<f64>, gi: &Matrix3<f64>) -> f64 {
    let (g00, g11, g22, g01, g02, g12) = (
        gi[(0, 0)],
        gi[(1, 1)],
        gi[(2, 2)],
        gi[(0, 1)],
        gi[(0, 2)],
        gi[(1, 2)],
    );
    let n = s.grey.len();
    // Slices of one length (no bounds checks): the per-light loop vectorises; the residual sum
    // of squares follows in a loop of its own, in the same order (identical rounding).
    let (lx, ly, lz) = (&test.lx[..n], &test.ly[..n], &test.lz[..n]);
    let [qxx, qyy, qzz, qxy, qxz, qyz] = &test.quad;
    let (qxx, qyy, qzz) = (&qxx[..n], &qyy[..n], &qzz[..n]);
    let (qxy, qxz, qyz) = (&qxy[..n], &qxz[..n], &qyz[..n]);
    let (grey, weight) = (&s.sgrey[..n], &s.weight[..n]);
    let (resid, score) = (&mut s.resid[..n], &mut s.score[..n]);
    for k in 0..n {
        let e = grey[k] - (lx[k] * m.x + ly[k] * m.y + lz[k] * m.z);
        let h =
            g00 * qxx[k] + g11 * qyy[k] + g22 * qzz[k] + g01 * qxy[k] + g02 * qxz[k] + g12 * qyz[k];
        resid[k] = e;
        score[k] = weight[k] * e * e / (1.0 - h).max(1e-9);
    }
    // The sum, and the largest score with the runner-up (for the next removal).
    let mut rss = 0.0;
    let (mut best, mut best_score, mut second) = (usize::MAX, -1.0, -1.0);
    for (k, ((&w, &e), &sc)) in weight
        .iter()
        .zip(resid.iter())
        .zip(score.iter())
        .enumerate()
    {
        rss += w * e * e;
        if sc > best_score {
            second = best_score;
            best_score = sc;
            best = k;
        } else if sc > second {
            second = sc;
        }
    }
    s.best = (best, best_score, second);
    rss
}

/// Attribution at one pixel. Fills `status_out` (N) and returns (s with all lights, RSS and
/// kept count at the end).
fn attribute(
    test: &Test,
    params: &DetectionParams,
    noise: &NoiseModel,
    scratch: &mut Scratch,
    status_out: &mut [u8],
) -> (f64, f64, usize) {
    scratch.weight.fill(1.0);
    status_out.fill(status::USED);
    attribute_from(test, params, noise, scratch, status_out)
}

/// Attribution starting from the kept set in `scratch.weight` (1 = kept), with the statuses of
/// already-removed lights in `status_out`.
fn attribute_from(
    test: &Test,
    params: &DetectionParams,
    noise: &NoiseModel,
    scratch: &mut Scratch,
    status_out: &mut [u8],
) -> (f64, f64, usize) {
    let n = test.directions.len();
    let level = scratch.grey.iter().sum::<f64>() / n as f64;
    let var = noise.variance(level);
    let sigma = var.sqrt();
    if test.inv_factor.is_empty() {
        scratch.sgrey.copy_from_slice(&scratch.grey);
    } else {
        for ((sg, &g), &f) in scratch
            .sgrey
            .iter_mut()
            .zip(&scratch.grey)
            .zip(&test.inv_factor)
        {
            *sg = g * f;
        }
    }
    let mut count = scratch.weight.iter().filter(|&&w| w > 0.0).count();
    let (mut gram, mut gram_inv) = (test.gram, test.gram_inv);
    if count < n {
        gram = Matrix3::zeros();
        for k in (0..n).filter(|&k| scratch.weight[k] > 0.0) {
            let l = test.directions[k];
            gram += l * l.transpose();
        }
        match gram.try_inverse() {
            Some(inv) if count >= 3 => gram_inv = inv,
            _ => return (f64::NAN, 0.0, count),
        }
    }
    let mut b = Vector3::zeros();
    for k in 0..n {
        b += test.directions[k] * (scratch.sgrey[k] * scratch.weight[k]);
    }
    let mut m = gram_inv * b;
    if !params.attribute {
        // The test alone: the residual sum of squares, O(N).
        let mut rss = 0.0;
        for k in 0..n {
            let e = scratch.sgrey[k] - (test.lx[k] * m.x + test.ly[k] * m.y + test.lz[k] * m.z);
            rss += scratch.weight[k] * e * e;
        }
        return (rss / var, rss, count);
    }
    let mut rss = score_pass(test, scratch, &m, &gram_inv);
    let s_all = rss / var;
    let _ = sigma;
    let shadow_level = noise.shadow_level(params, level);
    while params.attribute
        && count > 3
        && count > test.min_kept
        && rss / var > test.thresholds[count - 3]
    {
        // The largest deleted residual, and whether it is tied (always so with four lights).
        // The largest score and the runner-up, from the last score pass. Removed lights score
        // zero (weight 0), so they never lead a positive maximum nor reach a tie with it; a
        // zero maximum stops the loop below either way.
        let (mut best, best_score, second) = scratch.best;
        // Prefer keeping lights: a removal must lower the residual by more than the test's
        // per-light threshold (the χ² quantile of one degree of freedom); otherwise the
        // remaining misfit is spread over the lights — model error, not one light's fault.
        if best == usize::MAX
            || scratch.weight[best] == 0.0
            || best_score / var <= test.thresholds[1]
        {
            break;
        }
        let tie = best_score * (1.0 - 1e-6);
        let tied = second >= tie;
        if tied {
            // Decide by intensities: the darkest too-dark candidate if it reads at the shadow
            // level, else the brightest too-bright candidate.
            let candidates =
                || (0..n).filter(|&k| scratch.weight[k] > 0.0 && scratch.score[k] >= tie);
            let dark = candidates()
                .filter(|&k| scratch.resid[k] < 0.0)
                .min_by(|&a, &b| scratch.grey[a].total_cmp(&scratch.grey[b]));
            let bright = candidates()
                .filter(|&k| scratch.resid[k] > 0.0)
                .max_by(|&a, &b| scratch.grey[a].total_cmp(&scratch.grey[b]));
            best = match (dark, bright) {
                (Some(d), _) if scratch.grey[d] <= shadow_level => d,
                (_, Some(b)) => b,
                (Some(d), None) => d,
                (None, None) => best,
            };
        }
        // Remove the chosen light and, in the same step, every light that reads at the shadow
        // level while the fit predicts clearly more (Bonferroni outlier): a reading near zero
        // is a shadow however much other faulty lights have pulled the fit, whereas judging
        // brighter readings against that fit would swamp.
        let mut remove =
            |k: usize, s: &mut Scratch, gram: &mut Matrix3<f64>, b: &mut Vector3<f64>| {
                s.weight[k] = 0.0;
                let l = test.directions[k];
                *gram -= l * l.transpose();
                *b -= l * s.sgrey[k];
                // A shadow reads at the shadow level (also where the fit predicts a negative
                // value: an attached shadow); a brighter-than-predicted reading is a highlight;
                // a darker one above the shadow level is lit but off the model: rejected.
                status_out[k] = if s.grey[k] <= shadow_level {
                    status::SHADOW
                } else if s.resid[k] > 0.0 {
                    status::HIGHLIGHT
                } else {
                    status::REJECTED
                };
            };
        remove(best, scratch, &mut gram, &mut b);
        count -= 1;
        if !tied {
            let floor = test.min_kept.max(3);
            // The candidates in light order (removing one changes no other's test), taken
            // while more than `floor` lights remain.
            let mut candidates = std::mem::take(&mut scratch.candidates);
            candidates.clear();
            let (weight, resid) = (&scratch.weight[..n], &scratch.resid[..n]);
            let (grey, score) = (&scratch.grey[..n], &scratch.score[..n]);
            for k in 0..n {
                if resid[k] < 0.0
                    && grey[k] <= shadow_level
                    && weight[k] > 0.0
                    && score[k] / var > test.batch_z2
                {
                    candidates.push(k);
                }
            }
            for &k in &candidates {
                if count <= floor {
                    break;
                }
                remove(k, scratch, &mut gram, &mut b);
                count -= 1;
            }
            scratch.candidates = candidates;
        }
        match gram.try_inverse() {
            Some(inv) => gram_inv = inv,
            None => break,
        }
        m = gram_inv * b;
        rss = score_pass(test, scratch, &m, &gram_inv);
    }
    (s_all, rss, count)
}

/// Runs the test and the attribution over every mask pixel with a fixed noise model.
fn sweep(
    capture: &Capture,
    test: &Test,
    params: &DetectionParams,
    noise: &NoiseModel,
    progress: &dyn Progress,
) -> Sweep {
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
            || (Scratch::new(n), NearTest::of(capture, test)),
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
                        attribute(test, params, noise, scratch, &mut st[dp * n..(dp + 1) * n]);
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
    Sweep {
        residual,
        light_status,
        invisible,
        settled,
    }
}

/// What [`sweep`] finds per mask pixel.
struct Sweep {
    residual: Vec<f32>,
    light_status: Vec<u8>,
    invisible: Vec<bool>,
    settled: Vec<bool>,
}

/// Faults confined to a set S of lights are invisible to the linear test when they can be
/// absorbed by another normal, which needs |S| ≥ N − 2 (the fault vector must lie in the light
/// matrix's column space while vanishing on the other lights). Such pixels are recognisable when
/// the faults are shadows: at least N − 2 readings at the shadow level. They are flagged
/// unreliable: a pixel lit by at most two lights does not determine a normal anyway.
fn dark_beyond_the_test(params: &DetectionParams, noise: &NoiseModel, grey: &[f64]) -> bool {
    let n = grey.len();
    let level = grey.iter().sum::<f64>() / n as f64;
    let shadow_level = noise.shadow_level(params, level);
    grey.iter().filter(|&&g| g <= shadow_level).count() + 2 >= n
}

/// Fits σ² = σ₀² + κ² · level² to per-bin variance estimates (level, variance), with σ₀², κ² ≥ 0.
fn fit_noise(bins: &[(f64, f64)]) -> (f64, f64) {
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
fn measure_dark_floor(capture: &Capture) -> f64 {
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
/// light vectors carry the error of its unknown depth: measured there, κ took the recursive
/// error on the near ring's 128² sphere from 0.52° to 19.9°) or with fewer than 100 pixels
/// counted; the noise model then keeps [`DEFAULT_RELATIVE_NOISE`]. Measured this way κ is
/// 0.5–1.1% on DiLiGenT (whose lobes the robust scale of all residuals took for model error:
/// 1.3–4.0%), 2.7–4.2% on psmImages, at most 1% on the demo's renders of five lights or more.
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
    let mut key = vec![
        KAPPA_KEY,
        sigma0.to_bits(),
        floor.to_bits(),
        params.shadow_sigmas.to_bits(),
    ];
    key.extend(factors.iter().map(|f| f.to_bits()));
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

/// The first word of the memo keys of κ and of the light factors.
const KAPPA_KEY: u64 = 1;
const LIGHT_FACTORS_KEY: u64 = 2;

/// Lights needed to measure κ: with four, a pixel's residual has one degree of freedom and a
/// fault on one light looks the same as model error spread over all of them (the four
/// standardised residuals are equal in size), so no reading can be trimmed.
pub const MIN_KAPPA_LIGHTS: usize = 5;

/// Refits of the robust fit behind [`estimate_kappa`] at most, after the first.
pub const KAPPA_TRIM_ROUNDS: usize = 10;

/// The χ²₁ median: the median of d²/Var(d) for a normal d.
const CHI2_1_MEDIAN: f64 = 0.454_936_423_119_572_7;

/// [`estimate_kappa_weighted`], measured (`shadow_sigmas`: [`DetectionParams::shadow_sigmas`]).
fn measure_kappa(
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

/// Triplets of lights that determine a normal well (the determinant of their unit vectors at
/// least 0.05), with the inverse of the 3 × 3 matrix of their (possibly weighted) vectors: all
/// of them up to [`MAX_TRIPLETS`], else that many drawn by a fixed sequence (the same on every
/// run).
fn light_triplets(dirs: &[Vector3<f64>]) -> Vec<([usize; 3], Matrix3<f64>)> {
    let n = dirs.len();
    let total = n * n.saturating_sub(1) * n.saturating_sub(2) / 6;
    let mut out = Vec::new();
    let consider = |t: [usize; 3]| -> Option<([usize; 3], Matrix3<f64>)> {
        let m = Matrix3::from_rows(&[
            dirs[t[0]].transpose(),
            dirs[t[1]].transpose(),
            dirs[t[2]].transpose(),
        ]);
        let unit = Matrix3::from_rows(&[
            dirs[t[0]].normalize().transpose(),
            dirs[t[1]].normalize().transpose(),
            dirs[t[2]].normalize().transpose(),
        ]);
        if unit.determinant().abs() < 0.05 {
            return None;
        }
        m.try_inverse().map(|inv| (t, inv))
    };
    if total <= MAX_TRIPLETS {
        for a in 0..n {
            for b in a + 1..n {
                for c in b + 1..n {
                    out.extend(consider([a, b, c]));
                }
            }
        }
    } else {
        // A 64-bit linear congruential sequence (Knuth's MMIX constants).
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 33) as usize) % n
        };
        let mut tries = 0;
        while out.len() < MAX_TRIPLETS && tries < 20 * MAX_TRIPLETS {
            tries += 1;
            let (a, b, c) = (next(), next(), next());
            if a != b && b != c && a != c {
                out.extend(consider([a, b, c]));
            }
        }
    }
    out
}

/// Light triplets tried by `high_breakdown_fit` at most: with a third of a pixel's readings
/// faulty a triplet is clean with probability ≥ 0.25 (twelve lights), so that forty miss a clean
/// one with probability below 10⁻⁵.
const MAX_TRIPLETS: usize = 40;

/// Lights (evenly spaced in the capture's order) over which `high_breakdown_fit` ranks the
/// triplets by their median squared residual, at most; the fit that follows uses every light.
const RANK_LIGHTS: usize = 24;

/// The fit behind [`estimate_kappa`], robust to a large share of faulty readings (Rousseeuw &
/// Leroy's reweighted least median of squares, iterated): the least median of squares over the
/// light triplets whose three readings are all lit (`lit`; the median over at most
/// [`RANK_LIGHTS`] of the lit readings) — a fit that the majority of the readings agree with,
/// even when a third of them are off by a moderate amount, which trimming a least-squares fit
/// cannot undo — with its scale s₀ = 1.4826 (1 + 5/(n − 3)) √median (n the lit readings); the
/// readings within 3 s₀ are fitted by least squares, and then, while the set changes (at most
/// [`KAPPA_TRIM_ROUNDS`] times), the lit readings within 3 σ̂ of the last fit (σ̂² = the set's
/// residual sum of squares over its count − 3; readings may come back) are fitted again.
/// `keep` (any content on entry) is left holding that set. Returns the fit m = ρn and the
/// inverse normal matrix of the set; None with fewer than four readings in it or no usable
/// triplet.
fn high_breakdown_fit(
    dirs: &[Vector3<f64>],
    triplets: &[([usize; 3], Matrix3<f64>)],
    grey: &[f64],
    keep: &mut [bool],
    lit: &[bool],
    scratch: &mut Vec<f64>,
) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let n = dirs.len();
    let mut best: Option<(f64, Vector3<f64>)> = None;
    for (t, inv) in triplets {
        if !(lit[t[0]] && lit[t[1]] && lit[t[2]]) {
            continue;
        }
        let m = inv * Vector3::new(grey[t[0]], grey[t[1]], grey[t[2]]);
        scratch.clear();
        scratch.extend(
            (0..n)
                .step_by(n.div_ceil(RANK_LIGHTS))
                .filter(|&k| lit[k])
                .map(|k| (grey[k] - dirs[k].dot(&m)).powi(2)),
        );
        if scratch.is_empty() {
            continue;
        }
        let med = crate::solve::metrics::median(scratch);
        if best.is_none_or(|(b, _)| med < b) {
            best = Some((med, m));
        }
    }
    let (median_square, mut fit) = best?;
    let count = lit.iter().filter(|&&l| l).count() as f64;
    let mut scale = 1.4826 * (1.0 + 5.0 / (count - 3.0).max(1.0)) * median_square.sqrt();
    let mut gram_inv = Matrix3::zeros();
    for round in 0..=KAPPA_TRIM_ROUNDS {
        let mut changed = false;
        for k in 0..n {
            let inside = lit[k] && (grey[k] - dirs[k].dot(&fit)).abs() <= 3.0 * scale;
            changed |= inside != keep[k];
            keep[k] = inside;
        }
        if round > 0 && !changed {
            break;
        }
        let kept = keep.iter().filter(|&&k| k).count();
        if kept < 4 {
            return None;
        }
        (fit, gram_inv) = least_squares(dirs, grey, keep)?;
        let rss: f64 = (0..n)
            .filter(|&k| keep[k])
            .map(|k| (grey[k] - dirs[k].dot(&fit)).powi(2))
            .sum();
        scale = (rss / (kept as f64 - 3.0)).sqrt();
    }
    Some((fit, gram_inv))
}

/// The least-squares fit m = ρn of the readings flagged in `keep` and the inverse of their normal
/// matrix; None where those lights do not determine a normal.
fn least_squares(
    dirs: &[Vector3<f64>],
    grey: &[f64],
    keep: &[bool],
) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let mut gram = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for k in (0..dirs.len()).filter(|&k| keep[k]) {
        gram += dirs[k] * dirs[k].transpose();
        b += dirs[k] * grey[k];
    }
    let gram_inv = gram.try_inverse()?;
    Some((gram_inv * b, gram_inv))
}

/// For each light, the index of the light nearest to it in direction (the largest cosine
/// between the unit vectors; the later index on ties). Near lights: their nominal directions.
fn nearest_lights(directions: &[[f64; 3]]) -> Vec<usize> {
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

/// The capture's light vectors (distant lights).
pub(crate) fn distant_directions(capture: &Capture) -> Vec<Vector3<f64>> {
    capture
        .lights
        .directions
        .iter()
        .map(|d| Vector3::from(*d))
        .collect()
}

/// The robust all-light fit of one pixel behind [`estimate_kappa`] and [`light_noise_factors`]:
/// the readings flagged in `keep` (those above the shadow level) are fitted by least squares,
/// the readings beyond 3 robust scales dropped, and the fit repeated once. Fills `u` with
/// (light, standardised residual) for every light — eₖ / √(1 − hₖ) for the kept readings, the
/// prediction error eₖ / √(1 + hₖ) for the others — and `keep` with the readings kept, and
/// returns the robust scale of the kept ones (1.4826 × their median absolute standardised
/// residual) with the final fit m = ρ n and the inverse normal matrix G⁻¹ of its readings
/// (also the lights' refinement's pixel fit, [`crate::solve::refine::refine_lights`]). `None` when
/// fewer than four readings are kept, the pixel is black or the kept lights do not determine a
/// normal.
pub(crate) fn robust_fit_with(
    dirs: &[Vector3<f64>],
    grey: &[f64],
    keep: &mut [bool],
    u: &mut Vec<(usize, f64)>,
    scratch: &mut Vec<f64>,
) -> Option<(f64, Vector3<f64>, Matrix3<f64>)> {
    let n = dirs.len();
    let level = grey.iter().sum::<f64>() / n as f64;
    let mut scale = f64::NAN;
    let (mut fit, mut fit_inv) = (Vector3::zeros(), Matrix3::zeros());
    for round in 0..2 {
        let count = keep.iter().filter(|&&k| k).count();
        if count < 4 || level <= 0.0 {
            return None;
        }
        let (m, gi) = least_squares(dirs, grey, keep)?;
        (fit, fit_inv) = (m, gi);
        u.clear();
        for k in 0..n {
            let h = dirs[k].dot(&(gi * dirs[k]));
            let e = grey[k] - dirs[k].dot(&m);
            // Kept readings: standardised residual; others: prediction error.
            let z = if keep[k] {
                e / (1.0 - h).max(1e-9).sqrt()
            } else {
                e / (1.0 + h).sqrt()
            };
            u.push((k, z));
        }
        scratch.clear();
        scratch.extend(u.iter().filter(|(k, _)| keep[*k]).map(|(_, z)| z.abs()));
        scale = 1.4826 * crate::solve::metrics::median(scratch);
        if round == 0 {
            for &(k, z) in u.iter() {
                if keep[k] && z.abs() > 3.0 * scale {
                    keep[k] = false;
                }
            }
        }
    }
    Some((scale, fit, fit_inv))
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
fn measure_image_noise(capture: &Capture) -> Option<f64> {
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
    let test = Test::new(capture, params)?;
    let n = capture.n_lights();
    let mut samples: Vec<(f64, f64, usize)> = (0..capture.n_pixels())
        .into_par_iter()
        .map_init(
            || (vec![0f64; n], vec![true; n]),
            |(grey, all), p| {
                channel_mean(capture.pixel_samples(p), c, grey);
                let level = grey.iter().sum::<f64>() / n as f64;
                let (_, rss, _) = fit(&test, grey, all, &test.gram_inv);
                (level, rss, n - 3)
            },
        )
        .collect();
    let (s0, k) = fit_noise(&binned_variance(&mut samples, 0.25, 8));
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
                    let scratch = Scratch::new(n);
                    (scratch, vec![0u8; n])
                },
                |(scratch, st), p| {
                    channel_mean(capture.pixel_samples(p), c, &mut scratch.grey);
                    let level = scratch.grey.iter().sum::<f64>() / n as f64;
                    let (_, rss, kept) = attribute(&test, params, &noise, scratch, st);
                    (level, rss, kept)
                },
            )
            .filter(|f| f.2 > 3)
            .map(|(l, rss, k)| (l, rss, k - 3))
            .collect();
        if samples.len() < 100 {
            break;
        }
        let (s0, k) = fit_noise(&binned_variance(&mut samples, 0.5, 8));
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
    let test = Test::with_noise(capture, params, &noise)?;
    let n = capture.n_lights();
    let Sweep {
        residual,
        light_status,
        invisible,
        settled,
    } = sweep(capture, &test, params, &noise, progress);
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

/// Re-runs the attribution at single pixels from a given starting set of lights: the recursive
/// method's step after the geometric shadows of the reconstructed surface have been removed.
pub struct Attributor<'a> {
    test: Test,
    params: &'a DetectionParams,
    noise: NoiseModel,
    capture: &'a Capture,
}

impl<'a> Attributor<'a> {
    /// For a capture, with the detector's parameters and noise model.
    pub fn new(
        capture: &'a Capture,
        params: &'a DetectionParams,
        noise: NoiseModel,
    ) -> Result<Self> {
        Ok(Attributor {
            test: Test::with_noise(capture, params, &noise)?,
            params,
            noise,
            capture,
        })
    }

    /// [`Attributor::new`] under the light vectors `vectors` (direction times relative
    /// intensity, camera frame, one per light) instead of the capture's: the attribution of the
    /// readings while the lights are refined ([`crate::solve::refine::refine_lights`]). Distant
    /// lights.
    pub fn with_vectors(
        capture: &'a Capture,
        params: &'a DetectionParams,
        noise: NoiseModel,
        vectors: &[[f64; 3]],
    ) -> Result<Self> {
        let mut attributor = Attributor::new(capture, params, noise)?;
        if vectors.len() != attributor.test.directions.len()
            || !attributor.test.set_directions(vectors)
        {
            return Err(Error::invalid(
                "light vectors: one per light, determining a normal, expected",
            ));
        }
        Ok(attributor)
    }

    /// Per-thread scratch space for [`Attributor::run`].
    pub fn scratch(&self) -> AttributionScratch<'a> {
        AttributionScratch(
            Scratch::new(self.test.directions.len()),
            NearTest::of(self.capture, &self.test),
        )
    }

    /// The test at full-frame pixel `pixel`: the capture's own with distant lights, the pixel's
    /// with near lights (None where its vectors are singular).
    fn test_at<'s>(&'s self, near: &'s mut Option<NearTest<'a>>, pixel: usize) -> Option<&'s Test> {
        match near.as_mut() {
            None => Some(&self.test),
            Some(t) => t.at(pixel),
        }
    }

    /// [`Attributor::test_at`], or where the pixel's near-light vectors are singular the answer
    /// of [`Attributor::run_at`] and [`Attributor::settle_at`] there: a NaN statistic and the
    /// count of USED lights in `status` (nothing changed).
    fn test_or_count<'s>(
        &'s self,
        near: &'s mut Option<NearTest<'a>>,
        pixel: usize,
        status: &[u8],
    ) -> std::result::Result<&'s Test, (f64, usize)> {
        self.test_at(near, pixel).ok_or_else(|| {
            let count = status.iter().filter(|&&x| x == status::USED).count();
            (f64::NAN, count)
        })
    }

    /// [`Attributor::run`] at full-frame pixel `pixel`: with near lights, with that pixel's
    /// light vectors at the current surface (NaN statistic, nothing changed, where they are
    /// singular); with distant lights exactly `run`.
    pub fn run_at(
        &self,
        pixel: usize,
        grey: &[f64],
        status: &mut [u8],
        scratch: &mut AttributionScratch<'a>,
    ) -> (f64, usize) {
        let AttributionScratch(s, near) = scratch;
        let test = match self.test_or_count(near, pixel, status) {
            Ok(test) => test,
            Err(singular) => return singular,
        };
        self.run_with(test, grey, status, s)
    }

    /// Attribution at a pixel with grey intensities `grey` (one per light), starting from the
    /// lights whose `status` is USED (others keep their status). Updates `status` and returns
    /// (χ² statistic of the final set, or NaN if fewer than three lights remain; kept count).
    pub fn run(
        &self,
        grey: &[f64],
        status: &mut [u8],
        scratch: &mut AttributionScratch,
    ) -> (f64, usize) {
        self.run_with(&self.test, grey, status, &mut scratch.0)
    }

    fn run_with(
        &self,
        test: &Test,
        grey: &[f64],
        status: &mut [u8],
        s: &mut Scratch,
    ) -> (f64, usize) {
        s.grey.copy_from_slice(grey);
        for (w, &st) in s.weight.iter_mut().zip(status.iter()) {
            *w = if st == status::USED { 1.0 } else { 0.0 };
        }
        let (_, rss, count) = attribute_from(test, self.params, &self.noise, s, status);
        let n = grey.len();
        let level = grey.iter().sum::<f64>() / n as f64;
        let stat = if count > 3 {
            rss / self.noise.variance(level)
        } else {
            f64::NAN
        };
        (stat, count)
    }

    /// After the usable set of a pixel was changed from outside the attribution (the spatial
    /// consensus of [`crate::solve::consensus`]): the fit over the USED lights at full-frame pixel
    /// `pixel`, the labels of the removed lights by the attribution's rule (SHADOW at the shadow
    /// level, HIGHLIGHT brighter than the fit predicts, REJECTED darker), and the χ² statistic
    /// (NaN below four lights) with the kept count.
    pub fn settle_at(
        &self,
        pixel: usize,
        grey: &[f64],
        status: &mut [u8],
        scratch: &mut AttributionScratch<'a>,
    ) -> (f64, usize) {
        let AttributionScratch(s, near) = scratch;
        let test = match self.test_or_count(near, pixel, status) {
            Ok(test) => test,
            Err(singular) => return singular,
        };
        let n = grey.len();
        let level = grey.iter().sum::<f64>() / n as f64;
        let (mut gram, mut b, mut count) = (Matrix3::zeros(), Vector3::zeros(), 0);
        for (k, (w, &st)) in s.weight.iter_mut().zip(status.iter()).enumerate() {
            *w = f64::from(u8::from(st == status::USED));
            if st == status::USED {
                let l = test.directions[k];
                gram += l * l.transpose();
                b += l * (grey[k] * test.inv_factor(k));
                count += 1;
            }
        }
        let Some(gram_inv) = gram.try_inverse().filter(|_| count >= 3) else {
            return (f64::NAN, count);
        };
        let m = gram_inv * b;
        let mut rss = 0.0;
        for (k, ((&g, l), &w)) in grey.iter().zip(&test.directions).zip(&s.weight).enumerate() {
            let e = g * test.inv_factor(k) - l.dot(&m);
            rss += w * e * e;
        }
        let shadow_level = self.noise.shadow_level(self.params, level);
        for k in (0..n).filter(|&k| s.weight[k] == 0.0) {
            status[k] = if grey[k] <= shadow_level {
                status::SHADOW
            } else if grey[k] * test.inv_factor(k) > test.directions[k].dot(&m) {
                status::HIGHLIGHT
            } else {
                status::REJECTED
            };
        }
        let stat = if count > 3 {
            rss / self.noise.variance(level)
        } else {
            f64::NAN
        };
        (stat, count)
    }

    /// The χ² threshold for `count` kept lights (infinite below four).
    pub fn threshold(&self, count: usize) -> f64 {
        if count > 3 {
            self.test.thresholds[count - 3]
        } else {
            f64::INFINITY
        }
    }
}

/// Scratch space of an [`Attributor`] (with near lights, the per-pixel test too).
pub struct AttributionScratch<'a>(Scratch, Option<NearTest<'a>>);

/// An orthonormal basis A (N × (N−3)) of the null space of Lᵀ: the eigenvectors of L Lᵀ with
/// eigenvalue zero (for four lights, the paper's vector a). The detector never needs it (it uses
/// the equal least-squares residual); it is exposed for analysis and tests.
pub fn null_space(lights: &crate::model::lights::Lights) -> nalgebra::DMatrix<f64> {
    let n = lights.len();
    let l = nalgebra::DMatrix::from_fn(n, 3, |r, c| lights.directions[r][c]);
    let eig = nalgebra::SymmetricEigen::new(&l * l.transpose());
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let k = n.saturating_sub(3);
    nalgebra::DMatrix::from_fn(n, k, |r, c| eig.eigenvectors[(r, order[c])])
}

#[cfg(test)]
#[path = "detect/tests.rs"]
mod tests;
