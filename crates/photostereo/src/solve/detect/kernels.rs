//! The attribution's inner loop over the lights — residuals, leverages and deleted-residual
//! scores — compiled for AVX2 where the processor has it, next to the scalar reference it is
//! built from (the same source, hence the same rounding).

use super::attribution::AttributionBuffers;
use super::chi2::ChiSquareTest;
use nalgebra::{Matrix3, Vector3};

/// One pass over the lights: residuals eₖ = Iₖ − lₖ·m, deleted-residual scores
/// wₖ eₖ² / (1 − hₖ) with hₖ = lₖᵀ G⁻¹ lₖ, and the residual sum of squares over kept lights.
///
/// On x86-64 processors with AVX2 the same code runs compiled for 4-wide vectors. Rust never
/// fuses a multiply and an add on its own, so every operation rounds as in the baseline build
/// and the results are bit-identical on every processor.
#[inline]
pub(super) fn score_lights(
    test: &ChiSquareTest,
    s: &mut AttributionBuffers,
    m: &Vector3<f64>,
    gi: &Matrix3<f64>,
) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor supports AVX2 (checked just above).
        return unsafe { score_lights_avx2(test, s, m, gi) };
    }
    score_lights_scalar(test, s, m, gi)
}

/// [`score_lights_scalar`] compiled for AVX2 (4-wide vectors). Call only where the processor
/// has AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn score_lights_avx2(
    test: &ChiSquareTest,
    s: &mut AttributionBuffers,
    m: &Vector3<f64>,
    gi: &Matrix3<f64>,
) -> f64 {
    score_lights_scalar(test, s, m, gi)
}

/// The scalar reference of [`score_lights`], inlined into each build: the per-light loop over
/// structure-of-arrays slices of one length, then the residual sum of squares and the two
/// largest scores in a loop of their own.
#[inline(always)]
fn score_lights_scalar(
    test: &ChiSquareTest,
    s: &mut AttributionBuffers,
    m: &Vector3<f64>,
    gi: &Matrix3<f64>,
) -> f64 {
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
