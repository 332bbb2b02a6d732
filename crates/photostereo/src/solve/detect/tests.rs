use super::chi2::least_squares_rss;
use super::kappa::measure_kappa;
use super::noise::{measure_dark_floor, measure_image_noise};
use super::*;
use crate::base::progress::Silent;
use crate::fixtures::{lambert_sphere, ring};
use crate::model::lights::Lights;

fn square4() -> Vec<[f64; 3]> {
    let s = 35f64.to_radians();
    [45.0f64, 135.0, 225.0, 315.0]
        .iter()
        .map(|t| {
            let t = t.to_radians();
            [s.sin() * t.cos(), s.sin() * t.sin(), s.cos()]
        })
        .collect()
}

#[test]
fn paper_rig_null_vector() {
    let lights = Lights::new(&square4()).unwrap();
    let a = null_space(&lights);
    assert_eq!(a.shape(), (4, 1));
    let sign = if a[(0, 0)] < 0.0 { 1.0 } else { -1.0 };
    for (k, want) in [-0.5, 0.5, -0.5, 0.5].iter().enumerate() {
        assert!((sign * a[(k, 0)] - want).abs() < 1e-12, "{:?}", a);
    }
}

#[test]
fn residual_norm_equals_least_squares_rss() {
    let dirs = ring(9, 40.0);
    let lights = Lights::new(&dirs).unwrap();
    let a = null_space(&lights);
    let intens: Vec<f64> = (0..9).map(|k| 0.3 + 0.07 * ((k * 7) % 5) as f64).collect();
    let r = a.transpose() * nalgebra::DVector::from_vec(intens.clone());
    let (_, rss, count) = {
        let cap = lambert_sphere(16, 6.0, &dirs).0;
        let test = ChiSquareTest::new(&cap, &DetectionParams::default()).unwrap();
        least_squares_rss(&test, &intens, &[true; 9], &test.gram_inv)
    };
    assert_eq!(count, 9);
    assert!(
        (r.norm_squared() - rss).abs() < 1e-12,
        "{} vs {rss}",
        r.norm_squared()
    );
}

/// Corrupts one light at every other pixel and detects. Also returns, per pixel, whether every
/// light's clean intensity is at least 20% of the pixel's mean: with four lights a zeroed light
/// and a highlight are indistinguishable by intensities at pixels where a light is nearly
/// grazing, so the attribution check is made away from the terminator.
fn corrupted(
    dirs: &[[f64; 3]],
    light: usize,
    delta: Option<f32>,
) -> (Capture, Detection, Vec<bool>) {
    let (mut capture, _) = lambert_sphere(48, 20.0, dirs);
    let n = capture.n_lights();
    let c = capture.channels;
    let clear: Vec<bool> = (0..capture.n_pixels())
        .map(|p| {
            let s = capture.pixel_samples(p);
            let grey: Vec<f32> = s.chunks(c).map(|v| v.iter().sum::<f32>()).collect();
            let mean = grey.iter().sum::<f32>() / n as f32;
            grey.iter().all(|&g| g >= 0.2 * mean)
        })
        .collect();
    // Corrupt one light at every other pixel: zero it (shadow) or brighten it above every other
    // light by `delta` (a highlight is the brightest reading; with four lights that is what
    // tells it from the opposite light, which the linear test implicates equally).
    for p in (0..capture.n_pixels()).step_by(2) {
        let top = capture.pixel_samples(p).iter().cloned().fold(0.0, f32::max);
        for ch in 0..c {
            let v = &mut capture.samples[(p * n + light) * c + ch];
            *v = match delta {
                None => 0.0,
                Some(d) => top + d,
            };
        }
    }
    let params = DetectionParams {
        sigma: Some(0.002),
        relative_noise: Some(0.0),
        ..Default::default()
    };
    let det = detect(&capture, &params, &Silent).unwrap();
    (capture, det, clear)
}

#[test]
fn one_zeroed_or_brightened_light_is_attributed() {
    for dirs in [square4(), ring(8, 35.0)] {
        let n = dirs.len();
        for light in 0..n {
            for (delta, kind) in [(None, status::SHADOW), (Some(0.3), status::HIGHLIGHT)] {
                let (capture, det, clear) = corrupted(&dirs, light, delta);
                let mut right = 0;
                let mut total = 0;
                for p in (0..capture.n_pixels()).step_by(2).filter(|&p| clear[p]) {
                    total += 1;
                    let st = &det.light_status[p * n..(p + 1) * n];
                    if det.unreliable[p]
                        && st[light] == kind
                        && st.iter().filter(|&&s| s != status::USED).count() == 1
                    {
                        right += 1;
                    }
                }
                assert!(
                    total > 300 && right == total,
                    "N={n} light {light} {kind}: {right}/{total}"
                );
                // Clean pixels stay clean (no noise here, so none is flagged).
                let false_alarms = (1..capture.n_pixels())
                    .step_by(2)
                    .filter(|&p| det.unreliable[p])
                    .count();
                assert_eq!(false_alarms, 0);
            }
        }
    }
}

#[test]
fn noise_level_is_estimated_from_a_noisy_capture() {
    // Gaussian noise of known σ on a Lambertian sphere; 8×8-pixel patches in a checkerboard
    // third of the frame get a highlight from one light each (spatially coherent, as real
    // highlights are).
    let dirs = ring(8, 35.0);
    let (mut capture, _) = lambert_sphere(64, 28.0, &dirs);
    let n = capture.n_lights();
    let sigma = 0.005;
    let mut rng = crate::base::rng::Pcg32::new(3, 0);
    for v in capture.samples.iter_mut() {
        *v += (sigma * rng.next_normal()) as f32;
    }
    let patch = |p: usize| {
        let (r, c) = capture.pixel_position(p);
        ((r / 8 + c / 8) % 3 == 0).then_some((r / 8 * 8 + c / 8) % n)
    };
    let corrupted: Vec<Option<usize>> = (0..capture.n_pixels()).map(patch).collect();
    for (p, k) in corrupted.iter().enumerate() {
        if let Some(k) = k {
            for ch in 0..3 {
                capture.samples[(p * n + k) * 3 + ch] += 0.3;
            }
        }
    }
    let det = detect(&capture, &DetectionParams::default(), &Silent).unwrap();
    let grey_sigma = sigma / 3f64.sqrt();
    assert!(det.noise.estimated);
    let est = det.noise.sigma0;
    assert!(
        est > 0.8 * grey_sigma && est < 1.25 * grey_sigma,
        "estimated {est}, true {grey_sigma}"
    );
    // False alarms near the 5% of the test on clean pixels, detection near 100% on corrupted ones.
    let clean: Vec<usize> = (0..capture.n_pixels())
        .filter(|&p| corrupted[p].is_none())
        .collect();
    let fa = clean.iter().filter(|&&p| det.unreliable[p]).count() as f64 / clean.len() as f64;
    assert!(fa < 0.10, "false alarms {fa}");
    let bad: Vec<usize> = (0..capture.n_pixels())
        .filter(|&p| corrupted[p].is_some())
        .collect();
    let hit = bad.iter().filter(|&&p| det.unreliable[p]).count() as f64 / bad.len() as f64;
    assert!(bad.len() > 500 && hit > 0.99, "hits {hit}");
}

#[test]
fn capture_statistics_are_measured_once_and_not_shared_with_derived_captures() {
    // Lights 0–4 with noise σ, lights 5–7 with 3σ: the image noise is a median over the lights,
    // so the capture of lights 5–7 alone has about three times the capture's.
    let dirs = ring(8, 35.0);
    let (mut capture, _) = lambert_sphere(64, 28.0, &dirs);
    let (n, c) = (capture.n_lights(), capture.channels);
    let sigma = 0.004;
    let mut rng = crate::base::rng::Pcg32::new(5, 0);
    // Light intensities off by up to ±3% (a model error κ measures: it differs from light to
    // light), then the noise.
    for (i, v) in capture.samples.iter_mut().enumerate() {
        let k = (i / c) % n;
        let gain = 1.0 + 0.03 * (((k * 7) % 5) as f64 - 2.0) / 2.0;
        let s = if k < 5 { sigma } else { 3.0 * sigma };
        *v = (*v as f64 * gain + s * rng.next_normal()) as f32;
    }
    let whole = image_noise(&capture).unwrap();
    // The remembered figures are the measured ones, for every key of κ.
    assert_eq!(Some(whole), measure_image_noise(&capture));
    assert_eq!(dark_floor(&capture), measure_dark_floor(&capture));
    let floor = dark_floor(&capture);
    let params = DetectionParams::default();
    for shadow_sigmas in [params.shadow_sigmas, 1.0] {
        let p = DetectionParams {
            shadow_sigmas,
            ..params.clone()
        };
        let kappa = estimate_kappa(&capture, whole, floor, &p);
        assert_eq!(
            kappa,
            measure_kappa(&capture, whole, floor, shadow_sigmas, &[])
        );
        assert_eq!(kappa, estimate_kappa(&capture, whole, floor, &p));
        // Other light factors are another key.
        let factors = [1.0, 1.0, 1.0, 1.0, 1.0, 3.0, 3.0, 3.0];
        let weighted = estimate_kappa_weighted(&capture, whole, floor, &p, &factors);
        let measured = measure_kappa(&capture, whole, floor, shadow_sigmas, &factors);
        assert_eq!(weighted, measured);
        assert!(kappa.unwrap() > 0.005, "{kappa:?}");
        assert_ne!(weighted, kappa);
    }
    // A derived capture measures its own.
    let noisy = capture.select_lights(&[5, 6, 7]).unwrap();
    let derived = image_noise(&noisy).unwrap();
    assert_eq!(Some(derived), measure_image_noise(&noisy));
    assert!(derived > 2.0 * whole, "lights 5–7: {derived}, all: {whole}");
    // So does a clone whose samples then change.
    let mut scaled = capture.clone();
    for v in scaled.samples.iter_mut() {
        *v *= 2.0;
    }
    let twice = image_noise(&scaled).unwrap();
    assert!((twice / whole - 2.0).abs() < 1e-6, "{twice} vs 2 × {whole}");
    // And a capture told to forget after an in-place change.
    let mut changed = capture.clone();
    assert_eq!(image_noise(&changed), Some(whole));
    for v in changed.samples.iter_mut() {
        *v *= 0.5;
    }
    changed.forget_statistics();
    let half = image_noise(&changed).unwrap();
    assert!((half / whole - 0.5).abs() < 1e-6, "{half} vs {whole} / 2");
}

/// A light whose readings carry six times the others' relative error gets a noise factor well
/// above 1; the others stay at 1.
#[test]
fn light_noise_factors_find_the_inconsistent_light() {
    let dirs = ring(8, 40.0);
    let (mut capture, _) = lambert_sphere(64, 28.0, &dirs);
    let (n, c) = (capture.n_lights(), capture.channels);
    let mut rng = crate::base::rng::Pcg32::new(7, 1);
    for p in 0..capture.n_pixels() {
        for k in 0..n {
            let share = if k == 3 { 0.06 } else { 0.01 };
            let f = 1.0 + share * rng.next_normal();
            for ch in 0..c {
                capture.samples[(p * n + k) * c + ch] *= f as f32;
            }
        }
    }
    let params = DetectionParams::default();
    let noise = NoiseModel {
        sigma0: 1e-4,
        kappa: 0.01,
        estimated: false,
        kappa_estimated: false,
        floor: 0.0,
        light_factor: Vec::new(),
    };
    let f = light_noise_factors(&capture, &noise, &params);
    assert_eq!(f.len(), n);
    // Light 3's readings err by 6% of themselves where the model allows 1% of the pixel's
    // level: its factor is several times 1 (not the full 6: a reading is mostly below the
    // level and the fit absorbs part of its error); the others are as the model says.
    assert!(f[3] > 2.0 && f[3] < 9.0, "{f:?}");
    for (k, &x) in f.iter().enumerate().filter(|&(k, _)| k != 3) {
        assert_eq!(x, 1.0, "light {k}: {f:?}");
    }
    // The weighted test flags fewer pixels than the unweighted one: the extra error of light 3
    // is expected under its own factor.
    let weighted = NoiseModel {
        light_factor: f,
        ..noise.clone()
    };
    let plain = detect_with_noise(&capture, &params, noise, &Silent).unwrap();
    let det = detect_with_noise(&capture, &params, weighted, &Silent).unwrap();
    assert!(
        det.unreliable_share() < 0.5 * plain.unreliable_share(),
        "{} vs {}",
        det.unreliable_share(),
        plain.unreliable_share()
    );
}

/// With four lights the standardised residuals of a pixel are equal in size: no light can be
/// told apart and every factor is 1.
#[test]
fn light_noise_factors_are_one_with_four_lights() {
    let (capture, _) = lambert_sphere(48, 20.0, &square4());
    let noise = NoiseModel {
        sigma0: 1e-3,
        kappa: 0.01,
        estimated: false,
        kappa_estimated: false,
        floor: 0.0,
        light_factor: Vec::new(),
    };
    assert!(light_noise_factors(&capture, &noise, &DetectionParams::default()).is_empty());
}

/// The interior pixels (whole 3×3 neighbourhood in the mask) and their sample, against a
/// brute-force list over an irregular mask that touches the frame's border.
#[test]
fn interior_neighbourhoods_are_every_stride_th_of_the_brute_force_list() {
    let (mut capture, _) = lambert_sphere(40, 17.0, &ring(6, 30.0));
    let (w, h) = (capture.width, capture.height);
    // Holes and a border strip: pixels whose neighbourhoods leave the mask.
    for i in 0..w * h {
        let (r, c) = (i / w, i % w);
        if (r * 7 + c * 3) % 23 == 0 || r == 0 {
            capture.mask[i] = true;
        }
        if (r * 5 + c * 11) % 31 == 0 {
            capture.mask[i] = false;
        }
    }
    capture.pixels = (0..w * h)
        .filter(|&i| capture.mask[i])
        .map(|i| i as u32)
        .collect();
    let index = |i: usize| capture.pixels.iter().position(|&q| q as usize == i);
    let mut brute: Vec<[u32; 9]> = Vec::new();
    for &i in &capture.pixels {
        let (r, c) = (i as usize / w, i as usize % w);
        if r == 0 || c == 0 || r + 1 == h || c + 1 == w {
            continue;
        }
        let nb: Vec<Option<usize>> = (0..9)
            .map(|j| index((r + j / 3 - 1) * w + c + j % 3 - 1))
            .collect();
        if nb.iter().all(|q| q.is_some()) {
            brute.push(std::array::from_fn(|j| nb[j].unwrap() as u32));
        }
    }
    assert!(brute.len() > 300, "{}", brute.len());
    for at_most in [4096, 100, 7] {
        let (sampled, total) = interior_neighbourhoods(&capture, at_most);
        assert_eq!(total, brute.len());
        let stride = brute.len().div_ceil(at_most);
        let expected: Vec<[u32; 9]> = brute.iter().step_by(stride).copied().collect();
        assert_eq!(sampled, expected, "at most {at_most}");
        assert!(sampled.len() <= at_most);
    }
}
