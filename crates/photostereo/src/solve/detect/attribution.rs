//! Attributing a failed χ² test to the lights at fault (ALGORITHMS.md §2): remove, while the
//! test fails, the light whose removal lowers the residual most (the deleted residual), decide
//! ties by intensities, and label each removed reading a shadow, a highlight or a rejected
//! reading. [`Attributor`] re-runs it at single pixels for the recursive method (paper Fig. 2,
//! step 5).

use super::chi2::{ChiSquareTest, NearLightTest};
use super::kernels::score_lights;
use super::noise::NoiseModel;
use super::params::DetectionParams;
use crate::base::error::{Error, Result};
use crate::model::capture::Capture;
use crate::solve::lambert::status;
use nalgebra::{Matrix3, Vector3};

/// Per-thread scratch space: no allocation per pixel.
pub(super) struct AttributionBuffers {
    pub(super) grey: Vec<f64>,
    /// The readings divided by their lights' noise factors (the test's weighted readings;
    /// `grey` itself where the factors are all 1).
    pub(super) sgrey: Vec<f64>,
    /// 1.0 for kept lights, 0.0 for removed ones (branch-free loops).
    pub(super) weight: Vec<f64>,
    pub(super) resid: Vec<f64>,
    pub(super) score: Vec<f64>,
    /// Lights removed together in one step of the attribution.
    pub(super) candidates: Vec<usize>,
    /// The last score pass's largest score (light, score) and the runner-up score.
    pub(super) best: (usize, f64, f64),
}

impl AttributionBuffers {
    pub(super) fn new(n: usize) -> Self {
        AttributionBuffers {
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

/// Attribution at one pixel. Fills `status_out` (N) and returns (s with all lights, RSS and
/// kept count at the end).
pub(super) fn attribute_all(
    test: &ChiSquareTest,
    params: &DetectionParams,
    noise: &NoiseModel,
    scratch: &mut AttributionBuffers,
    status_out: &mut [u8],
) -> (f64, f64, usize) {
    scratch.weight.fill(1.0);
    status_out.fill(status::USED);
    attribute_kept(test, params, noise, scratch, status_out)
}

/// Attribution starting from the kept set in `scratch.weight` (1 = kept), with the statuses of
/// already-removed lights in `status_out`: the weighted least-squares fit of the kept lights,
/// then, while the χ² test fails (ALGORITHMS.md §2), the removal of the light with the largest
/// deleted residual (ties decided by intensities, [`tied_choice`]) together with the readings
/// at the shadow level that the fit clearly over-predicts ([`Removal::dark_outliers`]).
pub(super) fn attribute_kept(
    test: &ChiSquareTest,
    params: &DetectionParams,
    noise: &NoiseModel,
    scratch: &mut AttributionBuffers,
    status_out: &mut [u8],
) -> (f64, f64, usize) {
    let n = test.directions.len();
    let level = scratch.grey.iter().sum::<f64>() / n as f64;
    let var = noise.variance(level);
    weigh_readings(test, scratch);
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
        let rss = kept_rss(test, scratch, &m);
        return (rss / var, rss, count);
    }
    let mut rss = score_lights(test, scratch, &m, &gram_inv);
    let s_all = rss / var;
    let removal = Removal {
        test,
        shadow_level: noise.shadow_level(params, level),
    };
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
            best = tied_choice(scratch, tie, removal.shadow_level, best);
        }
        removal.remove(best, scratch, &mut gram, &mut b, status_out);
        count -= 1;
        if !tied {
            count = removal.dark_outliers(scratch, &mut gram, &mut b, status_out, count, var);
        }
        match gram.try_inverse() {
            Some(inv) => gram_inv = inv,
            None => break,
        }
        m = gram_inv * b;
        rss = score_lights(test, scratch, &m, &gram_inv);
    }
    (s_all, rss, count)
}

/// The readings the test fits, `scratch.sgrey`: the grey readings divided by their lights'
/// noise factors (weighted least squares), or the readings themselves when every factor is 1.
fn weigh_readings(test: &ChiSquareTest, scratch: &mut AttributionBuffers) {
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
}

/// The residual sum of squares of the fit `m` over the kept lights (the test without the
/// attribution).
fn kept_rss(test: &ChiSquareTest, scratch: &AttributionBuffers, m: &Vector3<f64>) -> f64 {
    let mut rss = 0.0;
    for k in 0..test.directions.len() {
        let e = scratch.sgrey[k] - (test.lx[k] * m.x + test.ly[k] * m.y + test.lz[k] * m.z);
        rss += scratch.weight[k] * e * e;
    }
    rss
}

/// The light removed when the largest deleted residuals tie (always so with four lights, where
/// the projector onto the residual space is a aᵀ): among the kept lights scoring at least `tie`,
/// the darkest too-dark candidate if it reads at the shadow level, else the brightest too-bright
/// candidate (`best` when there is neither).
fn tied_choice(scratch: &AttributionBuffers, tie: f64, shadow_level: f64, best: usize) -> usize {
    let n = scratch.grey.len();
    let candidates = || (0..n).filter(|&k| scratch.weight[k] > 0.0 && scratch.score[k] >= tie);
    let dark = candidates()
        .filter(|&k| scratch.resid[k] < 0.0)
        .min_by(|&a, &b| scratch.grey[a].total_cmp(&scratch.grey[b]));
    let bright = candidates()
        .filter(|&k| scratch.resid[k] > 0.0)
        .max_by(|&a, &b| scratch.grey[a].total_cmp(&scratch.grey[b]));
    match (dark, bright) {
        (Some(d), _) if scratch.grey[d] <= shadow_level => d,
        (_, Some(b)) => b,
        (Some(d), None) => d,
        (None, None) => best,
    }
}

/// Taking lights out of a pixel's fit: the normal equations lose the light's term and its
/// reading gets its label.
struct Removal<'t> {
    test: &'t ChiSquareTest,
    /// The pixel's shadow level ([`NoiseModel::shadow_level`]).
    shadow_level: f64,
}

impl Removal<'_> {
    /// Removes light `k` from the kept set and from the normal equations (`gram`, `b`). A
    /// shadow reads at the shadow level (also where the fit predicts a negative value: an
    /// attached shadow); a brighter-than-predicted reading is a highlight; a darker one above
    /// the shadow level is lit but off the model: rejected.
    fn remove(
        &self,
        k: usize,
        s: &mut AttributionBuffers,
        gram: &mut Matrix3<f64>,
        b: &mut Vector3<f64>,
        status_out: &mut [u8],
    ) {
        s.weight[k] = 0.0;
        let l = self.test.directions[k];
        *gram -= l * l.transpose();
        *b -= l * s.sgrey[k];
        status_out[k] = if s.grey[k] <= self.shadow_level {
            status::SHADOW
        } else if s.resid[k] > 0.0 {
            status::HIGHLIGHT
        } else {
            status::REJECTED
        };
    }

    /// In the same step as an untied removal, every light that reads at the shadow level while
    /// the fit predicts clearly more (a Bonferroni outlier, `batch_z2`): a reading near zero is
    /// a shadow however much other faulty lights have pulled the fit, whereas judging brighter
    /// readings against that fit would swamp. The candidates go in light order (removing one
    /// changes no other's test) while more than the floor of kept lights remain; returns the
    /// kept count.
    fn dark_outliers(
        &self,
        scratch: &mut AttributionBuffers,
        gram: &mut Matrix3<f64>,
        b: &mut Vector3<f64>,
        status_out: &mut [u8],
        mut count: usize,
        var: f64,
    ) -> usize {
        let test = self.test;
        let n = test.directions.len();
        let floor = test.min_kept.max(3);
        let mut candidates = std::mem::take(&mut scratch.candidates);
        candidates.clear();
        let (weight, resid) = (&scratch.weight[..n], &scratch.resid[..n]);
        let (grey, score) = (&scratch.grey[..n], &scratch.score[..n]);
        for k in 0..n {
            if resid[k] < 0.0
                && grey[k] <= self.shadow_level
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
            self.remove(k, scratch, gram, b, status_out);
            count -= 1;
        }
        scratch.candidates = candidates;
        count
    }
}

/// Re-runs the attribution at single pixels from a given starting set of lights: the recursive
/// method's step after the geometric shadows of the reconstructed surface have been removed.
pub struct Attributor<'a> {
    test: ChiSquareTest,
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
            test: ChiSquareTest::with_noise(capture, params, &noise)?,
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
            AttributionBuffers::new(self.test.directions.len()),
            NearLightTest::of(self.capture, &self.test),
        )
    }

    /// The test at full-frame pixel `pixel`: the capture's own with distant lights, the pixel's
    /// with near lights (None where its vectors are singular).
    fn test_at<'s>(
        &'s self,
        near: &'s mut Option<NearLightTest<'a>>,
        pixel: usize,
    ) -> Option<&'s ChiSquareTest> {
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
        near: &'s mut Option<NearLightTest<'a>>,
        pixel: usize,
        status: &[u8],
    ) -> std::result::Result<&'s ChiSquareTest, (f64, usize)> {
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
        test: &ChiSquareTest,
        grey: &[f64],
        status: &mut [u8],
        s: &mut AttributionBuffers,
    ) -> (f64, usize) {
        s.grey.copy_from_slice(grey);
        for (w, &st) in s.weight.iter_mut().zip(status.iter()) {
            *w = if st == status::USED { 1.0 } else { 0.0 };
        }
        let (_, rss, count) = attribute_kept(test, self.params, &self.noise, s, status);
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

/// AttributionBuffers space of an [`Attributor`] (with near lights, the per-pixel test too).
pub struct AttributionScratch<'a>(AttributionBuffers, Option<NearLightTest<'a>>);
