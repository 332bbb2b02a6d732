//! Robust regression of one pixel's readings on its light vectors: plain least squares, the
//! high-breakdown fit behind κ (least median of squares over light triplets, then trimmed least
//! squares) and the two-round trimmed fit behind the light factors and the lights' refinement.

use crate::model::capture::Capture;
use nalgebra::{Matrix3, Vector3};

/// Refits of the robust fit behind [`estimate_kappa`](super::estimate_kappa) at most, after the first.
pub(super) const KAPPA_TRIM_ROUNDS: usize = 10;

/// Triplets of lights that determine a normal well (the determinant of their unit vectors at
/// least 0.05), with the inverse of the 3 × 3 matrix of their (possibly weighted) vectors: all
/// of them up to [`MAX_TRIPLETS`], else that many drawn by a fixed sequence (the same on every
/// run).
pub(super) fn light_triplets(dirs: &[Vector3<f64>]) -> Vec<([usize; 3], Matrix3<f64>)> {
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

/// The fit behind [`estimate_kappa`](super::estimate_kappa), robust to a large share of faulty readings (Rousseeuw &
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
pub(super) fn high_breakdown_fit(
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
pub(super) fn least_squares(
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

/// The capture's light vectors (distant lights).
pub(crate) fn distant_directions(capture: &Capture) -> Vec<Vector3<f64>> {
    capture
        .lights
        .directions
        .iter()
        .map(|d| Vector3::from(*d))
        .collect()
}

/// The robust all-light fit of one pixel behind [`estimate_kappa`](super::estimate_kappa) and [`light_noise_factors`](super::light_noise_factors):
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
