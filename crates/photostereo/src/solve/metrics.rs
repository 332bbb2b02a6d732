//! Error figures against ground truth (CONVENTIONS.md, "Error metric"): angular error in degrees
//! between normalised vectors, over the mask pixels where the ground truth is non-zero.

use crate::base::error::{Error, Result};
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
/// `pred` is `height * width` normals; `mask` optionally restricts the pixels; `truth` is
/// either `height * width` normals or, with a mask, one normal per mask pixel in row-major
/// order (what [`truth_at_pixels`] gathers: a twelfth of a frame's bytes per mask pixel).
pub fn evaluate(
    pred: &[[f32; 3]],
    truth: &[[f32; 3]],
    mask: Option<&[bool]>,
) -> Result<(Vec<f32>, ErrorStats)> {
    if let Some(m) = mask {
        if m.len() != pred.len() {
            return Err(Error::invalid(format!(
                "mask has {} pixels but the normal maps have {}",
                m.len(),
                pred.len()
            )));
        }
    }
    let per_mask_pixel = match mask {
        _ if truth.len() == pred.len() => false,
        Some(m) if truth.len() == m.iter().filter(|&&x| x).count() => true,
        _ => {
            return Err(Error::invalid(format!(
                "prediction has {} pixels but the ground truth has {}{}",
                pred.len(),
                truth.len(),
                if mask.is_some() {
                    " (expected the frame's pixels or one normal per mask pixel)"
                } else {
                    ""
                }
            )))
        }
    };
    let mut map = vec![f32::NAN; pred.len()];
    let mut errs = Vec::new();
    let mut eq14 = 0.0;
    let mut missing = 0;
    // The mask index of the next mask pixel (truth per mask pixel).
    let mut next = 0;
    for i in 0..pred.len() {
        if mask.is_some_and(|m| !m[i]) {
            continue;
        }
        let t = if per_mask_pixel {
            next += 1;
            truth[next - 1]
        } else {
            truth[i]
        };
        if t == [0.0; 3] || t.iter().any(|v| !v.is_finite()) {
            continue;
        }
        let e = if pred[i] == [0.0; 3] || pred[i].iter().any(|v| !v.is_finite()) {
            missing += 1;
            90.0
        } else {
            angular_error_deg(pred[i], t)
        };
        eq14 += eq14_error_deg(pred[i], t);
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

/// Ground-truth normals at the mask pixels `pixels` (row-major flat indices, ascending) of a
/// `width` × `height` frame: `truth` itself when it already holds one normal per mask pixel,
/// gathered from it when it is a full frame. Errors name the sizes expected.
pub fn truth_at_pixels<'a>(
    truth: &'a [[f32; 3]],
    width: usize,
    height: usize,
    pixels: &[u32],
) -> Result<std::borrow::Cow<'a, [[f32; 3]]>> {
    use std::borrow::Cow;
    if truth.len() == pixels.len() {
        Ok(Cow::Borrowed(truth))
    } else if truth.len() == width * height {
        Ok(Cow::Owned(
            pixels.iter().map(|&i| truth[i as usize]).collect(),
        ))
    } else {
        Err(Error::invalid(format!(
            "ground truth has {} normals: expected {width}×{height} = {} (the frame) or {} (one \
             per mask pixel)",
            truth.len(),
            width * height,
            pixels.len()
        )))
    }
}

/// Something that yields a sequence of values to a visitor, as often as it is called.
pub type ValueSource<'a> = dyn Fn(&mut dyn FnMut(f32)) + 'a;

/// The value of rank `⌊q·n⌋` (0-based, at most `n − 1`) among the `n` values that `values`
/// yields, in `f32::total_cmp`'s order — what sorting them and indexing would give — without
/// holding them: `values` is called twice (a histogram of the upper 16 bits of each value's
/// order key, then of the lower 16 bits within the bin of the rank). `None` when it yields none.
pub fn select_by_total_order(values: &ValueSource, q: f64) -> Option<f32> {
    // Unsigned keys in total_cmp's order: negatives flipped below, positives above.
    let key = |x: f32| {
        let b = x.to_bits();
        if b >> 31 == 1 {
            !b
        } else {
            b | 0x8000_0000
        }
    };
    let mut upper = vec![0u64; 1 << 16];
    let mut n = 0u64;
    values(&mut |x| {
        upper[(key(x) >> 16) as usize] += 1;
        n += 1;
    });
    if n == 0 {
        return None;
    }
    let mut rank = ((n as f64 * q) as u64).min(n - 1);
    let mut bin = 0;
    for (b, &c) in upper.iter().enumerate() {
        if rank < c {
            bin = b as u32;
            break;
        }
        rank -= c;
    }
    let mut lower = vec![0u64; 1 << 16];
    values(&mut |x| {
        let k = key(x);
        if k >> 16 == bin {
            lower[(k & 0xffff) as usize] += 1;
        }
    });
    for (j, &c) in lower.iter().enumerate() {
        if rank < c {
            let k = (bin << 16) | j as u32;
            return Some(f32::from_bits(if k >> 31 == 1 {
                k & 0x7fff_ffff
            } else {
                !k
            }));
        }
        rank -= c;
    }
    None
}

/// The median of the finite positive values of a `width × height` map (row-major) in the
/// smallest square window around (`row`, `col`) that holds at least five of them: radii 2, 4,
/// 8, … while below `widest`. NaN when none does. `scratch` holds the window's values.
pub fn median_in_growing_window(
    map: &[f32],
    width: usize,
    height: usize,
    (row, col): (usize, usize),
    widest: usize,
    scratch: &mut Vec<f64>,
) -> f64 {
    let radii = std::iter::successors(Some(2usize), |&r| (r < widest).then_some(2 * r));
    for radius in radii {
        scratch.clear();
        for r in row.saturating_sub(radius)..(row + radius + 1).min(height) {
            for c in col.saturating_sub(radius)..(col + radius + 1).min(width) {
                let a = map[r * width + c];
                if a.is_finite() && a > 0.0 {
                    scratch.push(a as f64);
                }
            }
        }
        if scratch.len() >= 5 {
            return median(scratch);
        }
    }
    f64::NAN
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

/// `mask` (`width * height`, row-major) eroded by a square of radius `r`: a pixel stays when
/// every pixel within `r` rows and columns is inside the mask (and inside the frame).
pub fn erode(mask: &[bool], width: usize, height: usize, r: usize) -> Vec<bool> {
    let mut out = vec![false; mask.len()];
    for row in r..height.saturating_sub(r) {
        for col in r..width.saturating_sub(r) {
            out[row * width + col] = (row - r..=row + r).all(|rr| {
                mask[rr * width + col - r..=rr * width + col + r]
                    .iter()
                    .all(|&m| m)
            });
        }
    }
    out
}

/// Roughness of a normal map: the mean angle (degrees) between each normal and the normalised
/// average of the normals in its 5×5 window, over the pixels of `mask` eroded by 3 px (so that
/// the outline does not count) whose normal is defined. A smooth surface scores near zero;
/// speckle (isolated pixels with a different normal) raises it.
pub fn roughness_deg(normals: &[[f32; 3]], mask: &[bool], width: usize, height: usize) -> f64 {
    let inner = erode(mask, width, height, 3);
    let (mut sum, mut count) = (0.0, 0usize);
    for row in 2..height.saturating_sub(2) {
        for col in 2..width.saturating_sub(2) {
            let i = row * width + col;
            if !inner[i] || normals[i] == [0.0; 3] {
                continue;
            }
            let mut avg = [0f64; 3];
            for rr in row - 2..=row + 2 {
                for cc in col - 2..=col + 2 {
                    let j = rr * width + cc;
                    if mask[j] {
                        for (a, v) in avg.iter_mut().zip(normals[j]) {
                            *a += v as f64;
                        }
                    }
                }
            }
            let a = [avg[0] as f32, avg[1] as f32, avg[2] as f32];
            sum += angular_error_deg(normals[i], a);
            count += 1;
        }
    }
    sum / count.max(1) as f64
}

/// The sphere whose outline best fits the mask's (least-squares circle through the mask's
/// boundary pixels): (centre column, centre row, radius), pixel units.
pub fn circle_from_mask(mask: &[bool], width: usize, height: usize) -> Option<(f64, f64, f64)> {
    // Kåsa fit: x² + y² = 2a x + 2b y + c, linear in (a, b, c).
    let mut ata = nalgebra::Matrix3::<f64>::zeros();
    let mut atb = nalgebra::Vector3::<f64>::zeros();
    let inside = |r: isize, c: isize| {
        r >= 0
            && c >= 0
            && (r as usize) < height
            && (c as usize) < width
            && mask[r as usize * width + c as usize]
    };
    for row in 0..height as isize {
        for col in 0..width as isize {
            if !inside(row, col) {
                continue;
            }
            let edge = !inside(row - 1, col)
                || !inside(row + 1, col)
                || !inside(row, col - 1)
                || !inside(row, col + 1);
            if edge {
                let (x, y) = (col as f64, row as f64);
                let v = nalgebra::Vector3::new(2.0 * x, 2.0 * y, 1.0);
                ata += v * v.transpose();
                atb += v * (x * x + y * y);
            }
        }
    }
    let s = ata.try_inverse()? * atb;
    let r2 = s.z + s.x * s.x + s.y * s.y;
    // The boundary pixels lie half a pixel inside the true outline.
    (r2 > 0.0).then(|| (s.x, s.y, r2.sqrt() + 0.5))
}

/// Angular errors (degrees) of `normals` against the sphere (centre column `cx`, row `cy`,
/// radius `radius`) over the pixels within `inner · radius` of the centre with a defined normal.
pub fn sphere_errors(
    normals: &[[f32; 3]],
    width: usize,
    (cx, cy, radius): (f64, f64, f64),
    inner: f64,
) -> Vec<f64> {
    let mut out = Vec::new();
    for (i, n) in normals.iter().enumerate() {
        let (x, y) = ((i % width) as f64 - cx, (i / width) as f64 - cy);
        let (u, v) = (x / radius, -y / radius);
        if (u * u + v * v).sqrt() > inner || *n == [0.0; 3] {
            continue;
        }
        let g = [
            u as f32,
            v as f32,
            (1.0 - u * u - v * v).max(0.0).sqrt() as f32,
        ];
        out.push(angular_error_deg(*n, g));
    }
    out
}

/// The q-quantile (nearest rank) of a non-empty slice (reorders it).
pub fn quantile(v: &mut [f64], q: f64) -> f64 {
    let k = ((v.len() as f64 * q) as usize).min(v.len() - 1);
    *v.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Scoring against the truth at the mask pixels gives the full-frame truth's map and
    /// figures exactly; a truth of another length is refused naming both sizes.
    #[test]
    fn truth_per_mask_pixel_scores_as_the_full_frame() {
        let (w, h) = (7, 5);
        let unit = |a: f32, b: f32| [a.sin() * b.cos(), a.sin() * b.sin(), a.cos()];
        let pred: Vec<[f32; 3]> = (0..w * h)
            .map(|i| unit(0.3 + 0.01 * i as f32, i as f32))
            .collect();
        let mut truth: Vec<[f32; 3]> = (0..w * h)
            .map(|i| unit(0.31 + 0.012 * i as f32, 0.9 * i as f32))
            .collect();
        truth[3] = [0.0; 3]; // unknown ground truth: not scored
        let mask: Vec<bool> = (0..w * h).map(|i| i % 3 != 1).collect();
        let pixels: Vec<u32> = (0..w * h).filter(|&i| mask[i]).map(|i| i as u32).collect();
        let at_mask = truth_at_pixels(&truth, w, h, &pixels).unwrap();
        assert_eq!(at_mask.len(), pixels.len());
        for (p, &i) in pixels.iter().enumerate() {
            assert_eq!(at_mask[p], truth[i as usize]);
        }
        // Already per mask pixel: borrowed as it is.
        assert!(matches!(
            truth_at_pixels(&at_mask, w, h, &pixels).unwrap(),
            std::borrow::Cow::Borrowed(_)
        ));
        let (map_full, stats_full) = evaluate(&pred, &truth, Some(&mask)).unwrap();
        let (map_mask, stats_mask) = evaluate(&pred, &at_mask, Some(&mask)).unwrap();
        assert_eq!(stats_full, stats_mask);
        assert_eq!(stats_full.pixels, pixels.len() - 1);
        for (a, b) in map_full.iter().zip(&map_mask) {
            assert!(a.to_bits() == b.to_bits(), "{a} {b}");
        }
        let e = truth_at_pixels(&truth[..10], w, h, &pixels)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("35") && e.contains(&pixels.len().to_string()),
            "{e}"
        );
        assert!(evaluate(&pred, &truth[..10], Some(&mask)).is_err());
    }

    #[test]
    fn selection_by_total_order_equals_sorting() {
        // Negatives, both zeros, duplicates, subnormals and a wide range of magnitudes.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for n in [1usize, 2, 7, 1000, 20_000] {
            let mut v: Vec<f32> = (0..n)
                .map(|i| match next() % 7 {
                    0 => -0.0,
                    1 => 0.0,
                    2 => f32::from_bits(1 + (next() % 1000) as u32),
                    3 => (i % 5) as f32,
                    _ => {
                        let m = (next() % 2_000_000) as f32 / 1000.0 - 1000.0;
                        m * 10f32.powi((next() % 9) as i32 - 4)
                    }
                })
                .collect();
            let yielded = v.clone();
            let values = |visit: &mut dyn FnMut(f32)| yielded.iter().copied().for_each(&mut *visit);
            v.sort_by(|a, b| a.total_cmp(b));
            for q in [0.0, 0.1, 0.5, 0.995, 1.0] {
                let k = ((n as f64 * q) as usize).min(n - 1);
                let got = select_by_total_order(&values, q).unwrap();
                assert_eq!(got.to_bits(), v[k].to_bits(), "n {n}, q {q}");
            }
        }
        assert_eq!(select_by_total_order(&|_| {}, 0.5), None);
    }

    #[test]
    fn growing_window_medians_match_a_direct_search() {
        // 40×30 map: NaN and non-positive values here and there, a valid island far away.
        let (w, h) = (40usize, 30usize);
        let map: Vec<f32> = (0..w * h)
            .map(|i| {
                let (r, c) = (i / w, i % w);
                if r < 12 && c < 15 {
                    f32::NAN
                } else if (r + c) % 5 == 0 {
                    -1.0
                } else {
                    (1 + (r * 7 + c * 3) % 11) as f32
                }
            })
            .collect();
        let direct = |row: usize, col: usize, widest: usize| -> f64 {
            let mut radius = 2;
            loop {
                let mut v: Vec<f64> = Vec::new();
                for r in row.saturating_sub(radius)..(row + radius + 1).min(h) {
                    for c in col.saturating_sub(radius)..(col + radius + 1).min(w) {
                        let a = map[r * w + c];
                        if a.is_finite() && a > 0.0 {
                            v.push(a as f64);
                        }
                    }
                }
                if v.len() >= 5 {
                    v.sort_by(f64::total_cmp);
                    let m = v.len() / 2;
                    return if v.len() % 2 == 1 {
                        v[m]
                    } else {
                        (v[m - 1] + v[m]) / 2.0
                    };
                }
                if radius >= widest {
                    return f64::NAN;
                }
                radius *= 2;
            }
        };
        let mut scratch = Vec::new();
        for (row, col, widest) in [(0, 0, 32), (0, 0, 4), (5, 5, 8), (20, 30, 32), (29, 39, 2)] {
            let got = median_in_growing_window(&map, w, h, (row, col), widest, &mut scratch);
            let want = direct(row, col, widest);
            assert!(
                got == want || (got.is_nan() && want.is_nan()),
                "{row},{col}: {got} vs {want}"
            );
        }
        // Deep inside the NaN block with a small reach: nothing found.
        assert!(median_in_growing_window(&map, w, h, (0, 0), 4, &mut scratch).is_nan());
    }

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
