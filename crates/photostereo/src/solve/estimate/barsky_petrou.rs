//! Barsky & Petrou's four-source method (ALGORITHMS.md §3), generalised to N lights: the eq. 5
//! test flags a pixel; the light at fault is dropped — the darkest if it reads near the shadow
//! level (shadow), else the brightest too-bright candidate (highlight) — and the normal is solved
//! from the others. With more than four lights the drop is iterated while the test fails (see
//! [`crate::solve::detect`]); with four, one light at most is dropped, as published.

use super::{solve_subsets, Estimate, Estimator};
use crate::base::error::Result;
use crate::base::progress::Progress;
use crate::model::capture::Capture;
use crate::solve::detect::{detect, Detection, DetectionParams};

/// Barsky & Petrou with the detector's parameters.
#[derive(Clone, Debug, Default)]
pub struct BarskyPetrou {
    pub params: DetectionParams,
}

impl BarskyPetrou {
    /// The estimate from a detection already run with attribution (its per-light statuses say
    /// which lights each pixel keeps): least squares over the kept lights, weighted by the
    /// lights' noise factors where the noise model has them (distant lights; the fit the test
    /// made).
    pub fn from_detection(
        capture: &Capture,
        detection: &Detection,
        progress: &dyn Progress,
    ) -> Estimate {
        let mut est = solve_subsets(capture, Some(&detection.usable()), progress);
        let factors = &detection.noise.light_factor;
        if !factors.is_empty() && capture.lights.near.is_none() && !capture.is_tiled() {
            let ids: Vec<usize> = (0..capture.n_pixels()).collect();
            let status = &detection.light_status;
            crate::solve::lambert::resolve_subsets_at(capture, status, &ids, &mut est, factors);
        }
        est.light_status = Some(detection.light_status.clone());
        est
    }
}

impl Estimator for BarskyPetrou {
    fn name(&self) -> &'static str {
        "barsky-petrou"
    }

    fn estimate(&self, capture: &Capture, progress: &dyn Progress) -> Result<Estimate> {
        let detection = detect(capture, &self.params, progress)?;
        Ok(Self::from_detection(capture, &detection, progress))
    }
}
