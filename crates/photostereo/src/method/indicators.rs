//! The paper's indicator for real captures without ground truth (Argyriou & Petrou, Table 2):
//! the mean image intensity over the pixel–light pairs a method classified as highlights — the
//! higher, the more of the bright specular readings it found — and the same over the pairs it
//! classified as shadows (the lower, the darker the readings it dropped).
//!
//! **Which intensity.** The capture stores each sample divided by its light's intensity
//! ([`Capture::samples`]). The paper averages the *raw* image intensity, so this module
//! multiplies each sample back by its light's intensity (per channel for RGB images; by the
//! mean of the light's three values for grey images, as the loader divides): the value is the
//! one in the image file, full scale = 1 (an 8-bit 255 or a 16-bit 65535 reads 1). The mean of
//! the intensity-normalised samples is reported beside it (`mean_normalised_intensity`); the
//! two agree when every light has intensity 1.
//!
//! Per channel c: mean_c = Σ_(p,k) ∈ class I_kc(p) / pairs; grey = the mean of the channel
//! means (the channel mean the estimators fit). `mean_intensity_255` is the same on the paper's
//! 0–255 scale (× 255, whatever the bit depth). No pair in the class: the means are `null`.
//!
//! Every mask pixel–light pair counts once per channel; statuses come from the method's full
//! frame `light_status` (N, H, W) of [`crate::solve::lambert::status`] values.

use crate::method::report::Report;
use crate::method::statusmap::StatusMap;
use crate::model::capture::Capture;
use crate::solve::lambert::status;
use serde::Serialize;

/// Means per channel and their mean (grey).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ChannelMeans {
    /// The mean of the channel means.
    pub grey: f64,
    /// One mean per image channel (1 or 3).
    pub channels: Vec<f64>,
}

impl ChannelMeans {
    fn scaled(&self, f: f64) -> ChannelMeans {
        ChannelMeans {
            grey: self.grey * f,
            channels: self.channels.iter().map(|v| v * f).collect(),
        }
    }
}

/// The pairs of one class (highlights, shadows, or all pairs inside the mask) and their mean
/// intensities.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ClassIntensity {
    /// Pixel–light pairs in the class.
    pub pairs: u64,
    /// Share of all pixel–light pairs inside the mask.
    pub share_of_pairs: f64,
    /// Mask pixels with at least one pair in the class.
    pub pixels: u64,
    /// Mean raw image intensity (sample × light intensity), full scale = 1; `null` without pairs.
    pub mean_intensity: Option<ChannelMeans>,
    /// `mean_intensity` × 255: the paper's Table 2 scale.
    pub mean_intensity_255: Option<ChannelMeans>,
    /// Mean intensity-normalised sample (sample as the estimators see it, divided by the light's
    /// intensity).
    pub mean_normalised_intensity: Option<ChannelMeans>,
}

/// The indicator of one method's statuses on one capture.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StatusIntensities {
    /// Pairs classified [`status::HIGHLIGHT`].
    pub highlights: ClassIntensity,
    /// Pairs classified [`status::SHADOW`].
    pub shadows: ClassIntensity,
    /// Every pair inside the mask: the baseline the two classes are read against.
    pub all_pairs: ClassIntensity,
}

/// The multiplier that turns light `k`'s stored samples back into raw image values, per
/// channel: the light's intensity (grey images: the mean of its three values).
pub fn raw_scale(capture: &Capture, k: usize) -> [f64; 3] {
    let i = capture.lights.intensities[k];
    if capture.channels == 1 {
        [(i[0] + i[1] + i[2]) / 3.0; 3]
    } else {
        i
    }
}

#[derive(Clone)]
struct Sums {
    pairs: u64,
    pixels: u64,
    raw: [f64; 3],
    normalised: [f64; 3],
}

impl Sums {
    fn new() -> Self {
        Sums {
            pairs: 0,
            pixels: 0,
            raw: [0.0; 3],
            normalised: [0.0; 3],
        }
    }

    fn finish(&self, channels: usize, total_pairs: u64) -> ClassIntensity {
        let means = |s: &[f64; 3]| {
            (self.pairs > 0).then(|| {
                let ch: Vec<f64> = s[..channels]
                    .iter()
                    .map(|v| v / self.pairs as f64)
                    .collect();
                ChannelMeans {
                    grey: ch.iter().sum::<f64>() / channels as f64,
                    channels: ch,
                }
            })
        };
        let raw = means(&self.raw);
        ClassIntensity {
            pairs: self.pairs,
            share_of_pairs: if total_pairs > 0 {
                self.pairs as f64 / total_pairs as f64
            } else {
                0.0
            },
            pixels: self.pixels,
            mean_intensity_255: raw.as_ref().map(|m| m.scaled(255.0)),
            mean_intensity: raw,
            mean_normalised_intensity: means(&self.normalised),
        }
    }
}

/// Measures the indicator from a capture and a method's full-frame statuses (N, H, W).
///
/// # Panics
/// When `light_status` is not N·H·W long.
pub fn status_intensities(capture: &Capture, light_status: &StatusMap) -> StatusIntensities {
    let n = capture.n_lights();
    let c = capture.channels;
    assert_eq!(
        light_status.lights, n,
        "light_status must have the capture's lights"
    );
    let scales: Vec<[f64; 3]> = (0..n).map(|k| raw_scale(capture, k)).collect();
    let (mut hl, mut sh, mut all) = (Sums::new(), Sums::new(), Sums::new());
    let _ = capture.for_each_tile(|off, tile| {
        for p in 0..tile.n_pixels() {
            let samples = tile.pixel_samples(p);
            let (mut any_h, mut any_s) = (false, false);
            for k in 0..n {
                let st = light_status.code(off + p, k);
                let class = match st {
                    status::HIGHLIGHT => {
                        any_h = true;
                        Some(&mut hl)
                    }
                    status::SHADOW => {
                        any_s = true;
                        Some(&mut sh)
                    }
                    _ => None,
                };
                let px = &samples[k * c..(k + 1) * c];
                for target in [Some(&mut all), class].into_iter().flatten() {
                    target.pairs += 1;
                    for (ch, &v) in px.iter().enumerate() {
                        target.normalised[ch] += v as f64;
                        target.raw[ch] += v as f64 * scales[k][ch];
                    }
                }
            }
            all.pixels += 1;
            hl.pixels += any_h as u64;
            sh.pixels += any_s as u64;
        }
        Ok(())
    });
    let total = all.pairs;
    StatusIntensities {
        highlights: hl.finish(c, total),
        shadows: sh.finish(c, total),
        all_pairs: all.finish(c, total),
    }
}

/// Measures the indicator and records it in `report` as `highlights`, `shadows` and
/// `all_pairs`; `decided` = whether the statuses are the method's own decisions (false for a
/// method that classifies no light: its classes are then empty by construction).
pub fn record(
    capture: &Capture,
    light_status: &StatusMap,
    decided: bool,
    report: &mut Report,
) -> StatusIntensities {
    let s = status_intensities(capture, light_status);
    let with_flag = |c: &ClassIntensity| {
        let mut v = serde_json::to_value(c).unwrap_or_default();
        v["classified_by_method"] = decided.into();
        v
    };
    report
        .extra
        .insert("highlights".into(), with_flag(&s.highlights));
    report.extra.insert("shadows".into(), with_flag(&s.shadows));
    report.extra.insert(
        "all_pairs".into(),
        serde_json::to_value(&s.all_pairs).unwrap_or_default(),
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::lights::Lights;
    use ndarray::Array4;

    fn capture(channels: usize, intensities: Vec<[f64; 3]>) -> Capture {
        let dirs = [
            [0.0, 0.0, 1.0],
            [0.5, 0.0, 0.866],
            [0.0, 0.5, 0.866],
            [-0.5, 0.0, 0.866],
        ];
        let lights = Lights::new(&dirs)
            .unwrap()
            .with_intensities(intensities)
            .unwrap();
        let (h, w) = (2, 3);
        let stack = Array4::from_shape_fn((4, h, w, channels), |(k, r, col, ch)| {
            0.1 * (k + 1) as f32 + 0.01 * (r * w + col) as f32 + 0.001 * ch as f32
        });
        let mut mask = ndarray::Array2::from_elem((h, w), true);
        mask[[1, 2]] = false;
        Capture::from_stack(
            crate::model::capture::Stack::F32(stack.view()),
            lights,
            Some(mask.view()),
        )
        .unwrap()
    }

    fn frame_statuses(cap: &Capture, full: &[u8]) -> StatusMap {
        StatusMap::from_frame(
            cap.width,
            cap.height,
            cap.n_lights(),
            cap.pixels.clone(),
            full,
        )
    }

    #[test]
    fn means_are_raw_values_over_the_classified_pairs() {
        let intens = vec![[2.0, 1.0, 0.5], [1.0; 3], [1.0; 3], [4.0, 4.0, 4.0]];
        let cap = capture(3, intens);
        let hw = 6;
        let mut st = vec![status::USED; 4 * hw];
        st[5] = status::OUTSIDE;
        st[hw + 5] = status::OUTSIDE;
        st[2 * hw + 5] = status::OUTSIDE;
        st[3 * hw + 5] = status::OUTSIDE;
        // Highlights: light 1 (index 0) at pixel 0 and light 4 at pixel 4; shadow: light 2 at 1.
        st[0] = status::HIGHLIGHT;
        st[3 * hw + 4] = status::HIGHLIGHT;
        st[hw + 1] = status::SHADOW;
        let s = status_intensities(&cap, &frame_statuses(&cap, &st));
        assert_eq!(s.highlights.pairs, 2);
        assert_eq!(s.highlights.pixels, 2);
        assert_eq!(s.shadows.pairs, 1);
        assert_eq!(s.all_pairs.pairs, 20);
        // Raw values are the stack's: light 1 pixel 0 = 0.1 + 0.001 ch, light 4 pixel 4 =
        // 0.4 + 0.04 + 0.001 ch.
        let m = s.highlights.mean_intensity.as_ref().unwrap();
        for ch in 0..3 {
            let want = (0.1 + 0.44 + 2.0 * 0.001 * ch as f64) / 2.0;
            assert!(
                (m.channels[ch] - want).abs() < 1e-6,
                "{ch}: {}",
                m.channels[ch]
            );
        }
        assert!((m.grey - m.channels.iter().sum::<f64>() / 3.0).abs() < 1e-12);
        let m255 = s.highlights.mean_intensity_255.as_ref().unwrap();
        assert!((m255.grey - 255.0 * m.grey).abs() < 1e-9);
        // Normalised: divided by the light's intensity per channel.
        let nm = s.highlights.mean_normalised_intensity.as_ref().unwrap();
        let want_r = (0.1 / 2.0 + 0.44 / 4.0) / 2.0;
        assert!((nm.channels[0] - want_r).abs() < 1e-6);
        assert!(s.shadows.mean_intensity.is_some());
        assert!((s.highlights.share_of_pairs - 0.1).abs() < 1e-12);
    }

    #[test]
    fn grey_images_use_the_mean_light_intensity_and_empty_classes_are_null() {
        let cap = capture(1, vec![[1.0, 2.0, 3.0], [1.0; 3], [1.0; 3], [1.0; 3]]);
        let hw = 6;
        let mut st = vec![status::USED; 4 * hw];
        for k in 0..4 {
            st[k * hw + 5] = status::OUTSIDE;
        }
        st[2] = status::HIGHLIGHT;
        let s = status_intensities(&cap, &frame_statuses(&cap, &st));
        let m = s.highlights.mean_intensity.unwrap();
        assert!((m.grey - 0.12).abs() < 1e-6, "{}", m.grey);
        assert_eq!(m.channels.len(), 1);
        assert_eq!(s.shadows.pairs, 0);
        assert!(s.shadows.mean_intensity.is_none());
        let v = serde_json::to_value(&s.shadows).unwrap();
        assert!(v["mean_intensity"].is_null());
    }
}
