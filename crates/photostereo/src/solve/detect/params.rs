//! The detector's parameters ([`DetectionParams`]) and where the noise floor comes from
//! ([`NoiseEstimate`]).

use crate::base::error::{Error, Result};
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
    /// brightness. Default `None`: measured on the capture itself ([`estimate_kappa`](super::estimate_kappa): the
    /// light-to-light part of the misfit — the differences of the residuals of neighbouring
    /// lights after a trimmed fit, so that smooth departures from Lambert such as a broad
    /// specular lobe, which the test is there to find, do not count — with the lights' noise
    /// factors weighting the fit when `light_noise` is on; 0–1% on the demo's renders,
    /// 0.5–1.1% on DiLiGenT, 2.7–4.2% on psmImages), or [`DEFAULT_RELATIVE_NOISE`](super::DEFAULT_RELATIVE_NOISE) (1%, the
    /// model error a calibrated rig leaves: intensities known to about 1%, directions to about
    /// half a degree) where it cannot be measured (fewer than [`MIN_KAPPA_LIGHTS`](super::MIN_KAPPA_LIGHTS) lights, near
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
    /// level), `floor` the capture's dark floor ([`NoiseModel::floor`](super::NoiseModel::floor)). Only such readings are
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
    /// Measure a noise factor per light ([`light_noise_factors`](super::light_noise_factors), distant lights): a light whose
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
