//! The paper's synthetic evaluation on the built-in scenes with exact ground truth: detection
//! precision and recall, the baselines' ordering, and the recursive method's advantage
//!. Every figure is measured against the renderer's ground truth.

use photostereo::base::progress::Silent;
use photostereo::method::engine::{reconstruct, reconstruct_with_truth, Method, Params};
use photostereo::scene::{synthesize, Brdf, Rendered, Rig, SceneKind, SynthSpec};
use photostereo::solve::detect::{detect, DetectionParams};
use photostereo::solve::metrics::evaluate;

const NOISE: f64 = 0.005;

fn spec(kind: SceneKind, rig: &str, noise: f64) -> SynthSpec {
    let mut spec = SynthSpec::new(kind, Rig::parse(rig).unwrap());
    spec.size = 128;
    spec.render.brdf = Brdf::BlinnPhong;
    spec.render.noise_sigma = noise;
    spec.render.seed = 1;
    spec
}

/// Mean angular error of every method (in `Method::ALL` order) and the IoU of the recursive
/// method's final shadow maps with the ground truth (over lights and mask pixels).
fn errors(rendered: &Rendered) -> (Vec<f64>, f64) {
    let capture = rendered.capture().unwrap();
    let truth = &rendered.truth;
    let mut out = Vec::new();
    let mut iou = f64::NAN;
    for &method in Method::ALL {
        let params = Params {
            method,
            ..Params::default()
        };
        let rec = reconstruct_with_truth(&capture, &params, Some(&truth.normals), &Silent).unwrap();
        let (_, s) = evaluate(&rec.normals, &truth.normals, Some(&truth.mask)).unwrap();
        out.push(s.mean_deg);
        if let Some(r) = &rec.recursive {
            let (mut inter, mut union) = (0usize, 0usize);
            for k in 0..capture.n_lights() {
                let est = r.shadows.union(k);
                for i in (0..est.len()).filter(|&i| truth.mask[i]) {
                    inter += usize::from(est[i] && truth.shadow[k][i]);
                    union += usize::from(est[i] || truth.shadow[k][i]);
                }
            }
            iou = inter as f64 / union.max(1) as f64;
        }
    }
    (out, iou)
}

fn index(m: Method) -> usize {
    Method::ALL.iter().position(|&x| x == m).unwrap()
}

#[test]
fn square4_table_one_ordering() {
    let (l2, cj, bp, rec) = (
        index(Method::L2),
        index(Method::ColemanJain),
        index(Method::BarskyPetrou),
        index(Method::Recursive),
    );
    let mut mean = vec![0.0; Method::ALL.len()];
    let mut iou_mean = 0.0;
    for &kind in SceneKind::ALL {
        let rendered = synthesize(&spec(kind, "square4", NOISE)).unwrap();
        assert!(
            rendered.stats.cast_shadow_fraction > 0.0 && rendered.stats.highlight_fraction > 0.0
        );
        let (e, iou) = errors(&rendered);
        let name = kind.name();
        // Both baselines beat least squares; Barsky & Petrou beats Coleman & Jain (cast shadows).
        assert!(e[cj] < e[l2] && e[bp] < e[l2], "{name}: {e:?}");
        assert!(e[bp] < e[cj], "{name}: {e:?}");
        // The recursive method is the best of the four.
        for (i, v) in e.iter().enumerate() {
            if i != rec {
                assert!(e[rec] < *v, "{name}: {e:?}");
            }
        }
        for (m, v) in mean.iter_mut().zip(&e) {
            *m += v / SceneKind::ALL.len() as f64;
        }
        iou_mean += iou / SceneKind::ALL.len() as f64;
    }
    println!("square4 means {mean:.2?} shadow IoU {iou_mean:.3}");
    assert!(mean[rec] <= 0.6 * mean[l2], "means {mean:?}");
    assert!(iou_mean >= 0.85, "shadow IoU {iou_mean}");
}

#[test]
fn denser_rigs_halve_the_error() {
    let (l2, rec) = (index(Method::L2), index(Method::Recursive));
    for rig in ["ring8", "dome-20"] {
        let mut mean = vec![0.0; Method::ALL.len()];
        let mut iou_mean = 0.0;
        for &kind in SceneKind::ALL {
            let (e, iou) = errors(&synthesize(&spec(kind, rig, NOISE)).unwrap());
            for (m, v) in mean.iter_mut().zip(&e) {
                *m += v / SceneKind::ALL.len() as f64;
            }
            iou_mean += iou / SceneKind::ALL.len() as f64;
        }
        println!("{rig} means {mean:.2?} shadow IoU {iou_mean:.3}");
        assert!(mean[rec] <= 0.5 * mean[l2], "{rig}: {mean:?}");
        assert!(iou_mean >= 0.85, "{rig}: shadow IoU {iou_mean}");
    }
}

/// Per pixel: the largest deviation (grey, normalised units) of a light's noise-free reading
/// from the Lambertian value ρ (n · l) of the ground truth, and the part of the deviation vector
/// the linear test can see at all, ‖Aᵀ δ‖ (deviations along the light matrix's columns are
/// indistinguishable from another Lambertian normal).
fn lambertian_deviation(clean: &Rendered) -> Vec<(f64, f64)> {
    let t = &clean.truth;
    let capture = clean.capture().unwrap();
    let n = capture.n_lights();
    let c = capture.channels;
    let a = photostereo::solve::detect::null_space(&capture.lights);
    (0..capture.n_pixels())
        .map(|p| {
            let i = capture.pixels[p] as usize;
            let s = capture.pixel_samples(p);
            let delta: Vec<f64> = (0..n)
                .map(|k| {
                    let l = capture.lights.directions[k];
                    let nl = l[0] * t.normals[i][0] as f64
                        + l[1] * t.normals[i][1] as f64
                        + l[2] * t.normals[i][2] as f64;
                    (0..c)
                        .map(|ch| s[k * c + ch] as f64 - t.albedo[i][ch] as f64 * nl)
                        .sum::<f64>()
                        / c as f64
                })
                .collect();
            let visible = (a.transpose() * nalgebra::DVector::from_vec(delta.clone())).norm();
            (delta.iter().fold(0.0f64, |m, d| m.max(d.abs())), visible)
        })
        .collect()
}

/// Precision and recall of the unreliable map against the pixels deviating by more than 3σ,
/// and recall on those deviating by more than 5σ; printed as the README's table. Twice: with κ
/// measured on the capture (the default) and with κ fixed at 1%. The renders have no model
/// error, so the measured κ is near 0 and the test is the calibrated 95% test: its false alarms
/// on noise-only pixels (deviation below 1σ) stay near 5% (asserted ≤ 7.5%), and the flagged
/// pixels between 1σ and 3σ (real, small deviations) lower the precision against the 3σ truth
/// (0.86 on ring8's sphere). κ = 1% is a conservative test: fewer flags, precision ≥ 0.95.
#[test]
fn detection_precision_and_recall() {
    println!("rig      scene      kappa     precision  recall(>3σ)  recall(>5σ)  recall(visible >5σ)  false alarms(<1σ)");
    for rig in ["square4", "ring8"] {
        for &kind in SceneKind::ALL {
            let noisy = synthesize(&spec(kind, rig, NOISE)).unwrap();
            let clean = synthesize(&spec(kind, rig, 0.0)).unwrap();
            let dev = lambertian_deviation(&clean);
            for relative_noise in [None, Some(0.01)] {
                let params = DetectionParams {
                    relative_noise,
                    ..DetectionParams::default()
                };
                let det = detect(&noisy.capture().unwrap(), &params, &Silent).unwrap();
                let count =
                    |f: &dyn Fn(usize) -> bool| (0..dev.len()).filter(|&p| f(p)).count() as f64;
                let flagged = count(&|p| det.unreliable[p]);
                let tp3 = count(&|p| det.unreliable[p] && dev[p].0 > 3.0 * NOISE);
                let precision = tp3 / flagged.max(1.0);
                let recall3 = tp3 / count(&|p| dev[p].0 > 3.0 * NOISE).max(1.0);
                let recall5 = count(&|p| det.unreliable[p] && dev[p].0 > 5.0 * NOISE)
                    / count(&|p| dev[p].0 > 5.0 * NOISE).max(1.0);
                let visible5 = count(&|p| det.unreliable[p] && dev[p].1 > 5.0 * NOISE)
                    / count(&|p| dev[p].1 > 5.0 * NOISE).max(1.0);
                let quiet = count(&|p| dev[p].0 < NOISE);
                let false_alarms =
                    count(&|p| det.unreliable[p] && dev[p].0 < NOISE) / quiet.max(1.0);
                let kappa = det.noise.kappa;
                println!(
                    "{rig:<8} {:<10} {kappa:>6.4} {precision:>9.3} {recall3:>12.3} {recall5:>12.3} {visible5:>12.3} {false_alarms:>12.3}",
                    kind.name()
                );
                let name = format!("{rig} {} κ {kappa:.4}", kind.name());
                if !det.noise.kappa_estimated {
                    // Given, or not measurable (four lights: κ stays 1%).
                    assert!(relative_noise.is_some() || rig == "square4", "{name}");
                    assert!(precision >= 0.95, "{name}: precision {precision}");
                } else {
                    assert!(
                        kappa < 0.01,
                        "{name}: κ measured on a render without model error"
                    );
                    assert!(
                        quiet < 500.0 || false_alarms <= 0.075,
                        "{name}: {false_alarms} of {quiet} noise-only pixels flagged"
                    );
                }
                assert!(
                    visible5 >= 0.95,
                    "{name}: recall of visible deviations {visible5}"
                );
                assert!(recall5 >= 0.9, "{name}: recall above 5σ {recall5}");
            }
        }
    }
}

/// The paper's method works with as few as three lights: no linear test is possible, but the
/// shadows of the reconstructed surface still prune the lights.
#[test]
fn three_lights_recursive_beats_least_squares() {
    let (l2, rec) = (index(Method::L2), index(Method::Recursive));
    let mut mean = [0.0, 0.0];
    for &kind in SceneKind::ALL {
        let mut s = spec(kind, "ring-3", NOISE);
        s.size = 96;
        let rendered = synthesize(&s).unwrap();
        let capture = rendered.capture().unwrap();
        let truth = &rendered.truth;
        let mut e = vec![0.0; Method::ALL.len()];
        for m in [Method::L2, Method::Recursive] {
            let params = Params {
                method: m,
                ..Params::default()
            };
            let rec = reconstruct(&capture, &params, &Silent).unwrap();
            e[index(m)] = evaluate(&rec.normals, &truth.normals, Some(&truth.mask))
                .unwrap()
                .1
                .mean_deg;
        }
        println!(
            "ring-3 {}: l2 {:.2} recursive {:.2}",
            kind.name(),
            e[l2],
            e[rec]
        );
        mean[0] += e[l2] / SceneKind::ALL.len() as f64;
        mean[1] += e[rec] / SceneKind::ALL.len() as f64;
    }
    println!("ring-3 mean: l2 {:.2} recursive {:.2}", mean[0], mean[1]);
    assert!(mean[1] < 0.8 * mean[0], "{mean:?}");
}
