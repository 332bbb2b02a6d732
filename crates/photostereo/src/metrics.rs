//! Error figures against ground truth (CONVENTIONS.md, "Error metric"): angular error in degrees
//! between normalised vectors, over the mask pixels where the ground truth is non-zero.

use crate::error::{Error, Result};
use serde::Serialize;

/// Angular error in degrees between two vectors, both normalised first; NaN if either is zero.
#[inline]
pub fn angular_error_deg(a: [f32; 3], b: [f32; 3]) -> f64 {
    let a = [a[0] as f64, a[1] as f64, a[2] as f64];
    let b = [b[0] as f64, b[1] as f64, b[2] as f64];
    let na = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    let nb = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
    if na == 0.0 || nb == 0.0 {
        return f64::NAN;
    }
    let d = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (na * nb);
    d.clamp(-1.0, 1.0).acos().to_degrees()
}

/// The paper's eq. 14: the angle between (n, 1) and (g, 1), vectors not normalised first. Kept
/// only as an extra column: it shrinks errors (10° reads as about 7°).
#[inline]
pub fn eq14_error_deg(a: [f32; 3], b: [f32; 3]) -> f64 {
    let a = [a[0] as f64, a[1] as f64, a[2] as f64, 1.0];
    let b = [b[0] as f64, b[1] as f64, b[2] as f64, 1.0];
    let dot: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
    let na: f64 = a.iter().map(|x| x * x).sum::<f64>().sqrt();
    let nb: f64 = b.iter().map(|x| x * x).sum::<f64>().sqrt();
    (dot / (na * nb)).clamp(-1.0, 1.0).acos().to_degrees()
}

/// Summary of the angular errors of a normal map.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ErrorStats {
    /// Mean angular error (MAE), degrees.
    pub mean_deg: f64,
    /// Median angular error, degrees.
    pub median_deg: f64,
    /// Share of pixels under 5°, 10° and 20° (0..1).
    pub under_5deg: f64,
    pub under_10deg: f64,
    pub under_20deg: f64,
    /// Mean of the paper's eq. 14 figure (not the headline; see CONVENTIONS.md).
    pub mean_eq14_deg: f64,
    /// Pixels evaluated.
    pub pixels: usize,
    /// Pixels of the evaluated set without a prediction: zero, NaN or infinite (counted as 90°).
    pub missing: usize,
}

/// Per-pixel angular errors (degrees, row-major; NaN where not evaluated) and their summary.
/// `pred` and `truth` are `height * width` normals; `mask` optionally restricts the pixels.
pub fn evaluate(
    pred: &[[f32; 3]],
    truth: &[[f32; 3]],
    mask: Option<&[bool]>,
) -> Result<(Vec<f32>, ErrorStats)> {
    if pred.len() != truth.len() {
        return Err(Error::invalid(format!(
            "prediction has {} pixels but the ground truth has {}",
            pred.len(),
            truth.len()
        )));
    }
    if let Some(m) = mask {
        if m.len() != pred.len() {
            return Err(Error::invalid(format!(
                "mask has {} pixels but the normal maps have {}",
                m.len(),
                pred.len()
            )));
        }
    }
    let mut map = vec![f32::NAN; pred.len()];
    let mut errs = Vec::new();
    let mut eq14 = 0.0;
    let mut missing = 0;
    for i in 0..pred.len() {
        if mask.is_some_and(|m| !m[i])
            || truth[i] == [0.0; 3]
            || truth[i].iter().any(|v| !v.is_finite())
        {
            continue;
        }
        let e = if pred[i] == [0.0; 3] || pred[i].iter().any(|v| !v.is_finite()) {
            missing += 1;
            90.0
        } else {
            angular_error_deg(pred[i], truth[i])
        };
        eq14 += eq14_error_deg(pred[i], truth[i]);
        map[i] = e as f32;
        errs.push(e);
    }
    if errs.is_empty() {
        return Err(Error::invalid(
            "no pixel to evaluate: the mask and the ground truth do not overlap",
        ));
    }
    let n = errs.len() as f64;
    let mean = errs.iter().sum::<f64>() / n;
    let share = |t: f64| errs.iter().filter(|&&e| e < t).count() as f64 / n;
    let (under_5deg, under_10deg, under_20deg) = (share(5.0), share(10.0), share(20.0));
    let stats = ErrorStats {
        mean_deg: mean,
        median_deg: median(&mut errs),
        under_5deg,
        under_10deg,
        under_20deg,
        mean_eq14_deg: eq14 / n,
        pixels: errs.len(),
        missing,
    };
    Ok((map, stats))
}

/// Median of a non-empty slice (reorders it).
pub fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    let mid = n / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    let hi = *m;
    if n % 2 == 1 {
        hi
    } else {
        let lo = v[..mid].iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        (lo + hi) / 2.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_angles() {
        assert!((angular_error_deg([1.0, 0.0, 0.0], [0.0, 0.0, 2.0]) - 90.0).abs() < 1e-9);
        let t = 10f32.to_radians();
        assert!((angular_error_deg([0.0, 0.0, 1.0], [t.sin(), 0.0, t.cos()]) - 10.0).abs() < 1e-4);
        // eq. 14 shrinks a 10° error to about 7°.
        let e = eq14_error_deg([0.0, 0.0, 1.0], [t.sin(), 0.0, t.cos()]);
        assert!(e > 6.0 && e < 8.0, "{e}");
    }

    #[test]
    fn stats_over_mask_and_nonzero_truth() {
        let t = 10f32.to_radians();
        let pred = vec![[0.0, 0.0, 1.0]; 4];
        let truth = vec![
            [t.sin(), 0.0, t.cos()],
            [0.0, 0.0, 1.0],
            [0.0; 3],
            [1.0, 0.0, 0.0],
        ];
        let mask = vec![true, true, true, false];
        let (map, s) = evaluate(&pred, &truth, Some(&mask)).unwrap();
        assert_eq!(s.pixels, 2);
        assert!((s.mean_deg - 5.0).abs() < 1e-4);
        assert!((s.median_deg - 5.0).abs() < 1e-4);
        assert_eq!(s.under_5deg, 0.5);
        assert_eq!(s.under_20deg, 1.0);
        assert!(map[2].is_nan() && map[3].is_nan());
    }

    #[test]
    fn median_even_and_odd() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
    }
}
