//! The recursive method's surface prior and the lights' refinement from the readings (issue
//! 19), against ground truth: rendered scenes with known normals and known lights.

use photostereo::base::progress::Silent;
use photostereo::io::layouts::{CaptureFiles, LoadOptions};
use photostereo::io::synth::synth_to_folder;
use photostereo::method::engine::{reconstruct, Method, Params};
use photostereo::model::memory::{Force, Layout};
use photostereo::scene::{synthesize, Brdf, Rendered, Rig, SceneKind, SynthSpec};
use photostereo::solve::metrics::evaluate;
use photostereo::solve::refine::{refine_capture_lights, refine_lights, RefineParams};

fn render(kind: SceneKind, rig: Rig, brdf: Brdf, noise: f64, seed: u64) -> Rendered {
    let mut spec = SynthSpec::new(kind, rig);
    spec.size = 96;
    spec.render.brdf = brdf;
    spec.render.noise_sigma = noise;
    spec.render.seed = seed;
    synthesize(&spec).unwrap()
}

/// The recursive method's mean error against the truth and the κ its test used, with the
/// default parameters changed by `tweak`.
fn recursive_run(
    r: &Rendered,
    capture: &photostereo::Capture,
    tweak: impl FnOnce(&mut Params),
) -> (f64, f64) {
    let mut params = Params {
        method: Method::Recursive,
        integrate: false,
        ..Params::default()
    };
    tweak(&mut params);
    let rec = reconstruct(capture, &params, &Silent).unwrap();
    let kappa = rec.report.extra["detection"]["noise"]["kappa"]
        .as_f64()
        .unwrap();
    let error = evaluate(&rec.normals, &r.truth.normals, Some(&r.truth.mask))
        .unwrap()
        .1
        .mean_deg;
    (error, kappa)
}

fn recursive_error(r: &Rendered, capture: &photostereo::Capture, prior_deg: f64) -> f64 {
    recursive_run(r, capture, |p| p.recursive.surface_prior_deg = prior_deg).0
}

/// On noisy captures (3% of full scale, twelve lights, highlights and shadows) the surface
/// prior brings the recursive method's normals closer to the truth than its least squares
/// over the usable lights alone: by at least 10% on every scene (measured 11–29%).
#[test]
fn the_surface_prior_lowers_the_error_on_noisy_captures() {
    for (i, kind) in [SceneKind::Sphere, SceneKind::Bumps, SceneKind::Terrain]
        .into_iter()
        .enumerate()
    {
        let r = render(kind, Rig::Ring(12), Brdf::BlinnPhong, 0.03, i as u64 + 1);
        let capture = r.capture().unwrap();
        let alone = recursive_error(&r, &capture, 0.0);
        let with = recursive_error(&r, &capture, 1.0);
        eprintln!("{kind}: {with:.3}° with the prior, {alone:.3}° without");
        assert!(
            with < 0.9 * alone,
            "{kind}: {with:.3}° with the prior, {alone:.3}° without"
        );
    }
}

/// Where the readings determine the normals well (twenty lights, 0.5% noise), the prior moves
/// them by little and does not make them worse: within 0.02° of the error without it, and the
/// report says how far the normals moved on average (below 0.1°).
#[test]
fn the_surface_prior_leaves_well_determined_normals() {
    let r = render(SceneKind::Blocks, Rig::Dome(20), Brdf::BlinnPhong, 0.005, 3);
    let capture = r.capture().unwrap();
    let alone = recursive_error(&r, &capture, 0.0);
    let with = recursive_error(&r, &capture, 1.0);
    assert!(with <= alone + 0.02, "{with:.3}° with, {alone:.3}° without");
    let params = Params {
        integrate: false,
        ..Params::default()
    };
    let rec = reconstruct(&capture, &params, &Silent).unwrap();
    let prior = &rec.report.extra["recursive"]["surface_prior"];
    assert_eq!(prior["prior_deg"].as_f64(), Some(1.0));
    assert!(prior["pixels"].as_u64().unwrap() > 1000, "{prior}");
    let shift = prior["mean_shift_deg"].as_f64().unwrap();
    assert!(shift > 0.0 && shift < 0.2, "{prior}");
}

/// Lights given with errors of 1.5–3° in direction and ±4% in intensity are recovered from the
/// readings of a Lambertian scene with shadows (twelve lights, 0.5% noise), up to the linear
/// map the readings cannot fix (kept on the given lights): every refined vector within 0.3°
/// and 1% of the truth under that map (measured 0.024° and 0.021%), and the pixels' misfit
/// at least halves (1.8% → 0.9%).
#[test]
fn refinement_recovers_miscalibrated_lights() {
    let r = render(SceneKind::Bumps, Rig::Ring(12), Brdf::Lambert, 0.005, 7);
    let mut capture = r.capture().unwrap();
    let truth = capture.lights.directions.clone();
    // Perturb each direction by a rotation about an axis orthogonal to it, by 1.5–3°, in
    // alternating senses; scale each light's samples by a gain the given lights do not know.
    let n = truth.len();
    let mut given = truth.clone();
    for (k, d) in given.iter_mut().enumerate() {
        let angle =
            (1.5 + 1.5 * (k % 3) as f64 / 2.0).to_radians() * if k % 2 == 0 { 1.0 } else { -1.0 };
        let axis = normalise(cross(*d, [0.3, -0.7, 0.2]));
        *d = rotate(*d, axis, angle);
    }
    let gains: Vec<f64> = (0..n)
        .map(|k| 1.0 + 0.04 * ((k * 7 % 5) as f64 - 2.0) / 2.0)
        .collect();
    let c = capture.channels;
    for pixel in capture.samples.chunks_exact_mut(n * c) {
        for (k, light) in pixel.chunks_exact_mut(c).enumerate() {
            for v in light {
                *v *= gains[k] as f32;
            }
        }
    }
    capture.lights.directions = given.clone();
    capture.forget_statistics();
    let refined = refine_lights(&capture, &RefineParams::default())
        .unwrap()
        .expect("twelve distant lights calibrate");
    let before: f64 = given
        .iter()
        .zip(&truth)
        .map(|(a, b)| angle_deg(*a, *b))
        .sum::<f64>()
        / n as f64;
    assert!(before > 1.5, "{before}");
    // The readings fix the lights up to a linear map, and the refinement keeps the given
    // lights' frame: the best it can return is the true light vectors (gain times direction)
    // under the linear map that takes them closest to the given ones.
    let true_vectors: Vec<[f64; 3]> = (0..n).map(|k| scale(truth[k], gains[k])).collect();
    let frame = best_linear_map(&true_vectors, &given);
    let (mut worst_angle, mut worst_gain) = (0f64, 0f64);
    for k in 0..n {
        let best = apply(&frame, true_vectors[k]);
        let error = angle_deg(refined.directions[k], best);
        worst_angle = worst_angle.max(error);
        worst_gain = worst_gain.max((refined.gains[k] / norm(best) - 1.0).abs());
        assert!(
            error < 0.3,
            "light {k}: {error:.3}° from the best (given {:.3}°)",
            angle_deg(given[k], best)
        );
        let relative = refined.gains[k] / norm(best);
        assert!(
            (relative - 1.0).abs() < 0.01,
            "light {k}: gain {} for {}",
            refined.gains[k],
            norm(best)
        );
    }
    eprintln!(
        "refined within {worst_angle:.3}° and {:.3}% of the best; misfit {:.4} -> {:.4}",
        100.0 * worst_gain,
        refined.misfit_before,
        refined.misfit_after
    );
    assert!(
        refined.misfit_after < 0.5 * refined.misfit_before,
        "{refined:?}"
    );
    capture.apply_light_refinement(refined).unwrap();
    assert!(capture.notes.last().unwrap().contains("lights refined"));
    // Once only.
    assert!(!refine_capture_lights(&mut capture, &RefineParams::default()).unwrap());
}

/// Exact lights stay close to where they are on shiny scenes (twenty lights, 20% of the
/// readings highlights): the detector's attribution keeps the highlights out of the lights'
/// fits, so that no light moves by more than 2° (measured up to 1.5°; a refinement over
/// every lit reading moved them by up to 7.6° toward the highlights) and the recursive method's
/// error with the refined lights stays within 0.05° of its error with the exact ones.
#[test]
fn refinement_leaves_exact_lights_on_shiny_scenes() {
    for (i, kind) in [SceneKind::Sphere, SceneKind::Cavities]
        .into_iter()
        .enumerate()
    {
        let r = render(kind, Rig::Dome(20), Brdf::BlinnPhong, 0.005, 11 + i as u64);
        let mut capture = r.capture().unwrap();
        let exact = recursive_error(&r, &capture, 1.0);
        let refined = refine_lights(&capture, &RefineParams::default())
            .unwrap()
            .expect("twenty distant lights calibrate");
        let worst = refined.angle_deg.iter().cloned().fold(0.0, f64::max);
        eprintln!("{kind}: lights moved up to {worst:.2}°");
        assert!(worst < 2.0, "{kind}: a light moved {worst:.2}°");
        for g in &refined.gains {
            assert!((g - 1.0).abs() < 0.03, "{kind}: gain {g}");
        }
        capture.apply_light_refinement(refined).unwrap();
        let after = recursive_error(&r, &capture, 1.0);
        eprintln!("{kind}: recursive {after:.3}° with the refined lights, {exact:.3}° exact");
        assert!(
            after <= exact + 0.05,
            "{kind}: {after:.3}° refined, {exact:.3}° exact"
        );
    }
}

/// Fewer than six lights, or near lights, are not calibrated on.
#[test]
fn refinement_needs_six_distant_lights() {
    let r = render(SceneKind::Sphere, Rig::Square4, Brdf::Lambert, 0.005, 1);
    let capture = r.capture().unwrap();
    assert!(refine_lights(&capture, &RefineParams::default())
        .unwrap()
        .is_none());
}

/// A capture in tiles (a spill file) refines its lights exactly as the capture held whole, and
/// gives the same samples and the same recursive results afterwards.
#[test]
fn refinement_in_tiles_is_the_refinement_held_whole() {
    let out = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Blocks, Rig::Ring(8));
    spec.size = 64;
    let (_, folder) = synth_to_folder(&spec, &out.path().join("blocks"), false).unwrap();
    let files = CaptureFiles::diligent(&folder).unwrap();
    let mut whole = files.load(&Silent).unwrap();
    let options = LoadOptions {
        budget: Some(64 << 30),
        spill_dir: Some(out.path().to_path_buf()),
        force: Force {
            layout: Some(Layout::Spill),
            tile_pixels: Some(300),
            park: None,
        },
        ..Default::default()
    };
    let mut tiled = files.load_with(&Silent, &options).unwrap();
    assert!(tiled.is_tiled());
    assert!(refine_capture_lights(&mut whole, &RefineParams::default()).unwrap());
    assert!(refine_capture_lights(&mut tiled, &RefineParams::default()).unwrap());
    assert_eq!(whole.light_refinement, tiled.light_refinement);
    assert_eq!(whole.lights.directions, tiled.lights.directions);
    let stride = whole.n_lights() * whole.channels;
    tiled
        .for_each_tile(|off, tile| {
            let n = tile.n_pixels();
            assert!(tile.samples == whole.samples[off * stride..(off + n) * stride]);
            Ok(())
        })
        .unwrap();
    let params = Params::default();
    let a = reconstruct(&whole, &params, &Silent).unwrap();
    let b = reconstruct(&tiled, &params, &Silent).unwrap();
    assert_eq!(a.normals, b.normals);
    assert_eq!(a.albedo, b.albedo);
    assert_eq!(
        a.report.input.light_refinement,
        b.report.input.light_refinement
    );
}

fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let na = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    let nb = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
    (dot / (na * nb)).clamp(-1.0, 1.0).acos().to_degrees()
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalise(a: [f64; 3]) -> [f64; 3] {
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    [a[0] / n, a[1] / n, a[2] / n]
}

/// Rodrigues' rotation of `v` about the unit `axis` by `angle` radians.
fn rotate(v: [f64; 3], axis: [f64; 3], angle: f64) -> [f64; 3] {
    let (s, c) = angle.sin_cos();
    let k = axis;
    let kxv = cross(k, v);
    let kdv = k[0] * v[0] + k[1] * v[1] + k[2] * v[2];
    [
        v[0] * c + kxv[0] * s + k[0] * kdv * (1.0 - c),
        v[1] * c + kxv[1] * s + k[1] * kdv * (1.0 - c),
        v[2] * c + kxv[2] * s + k[2] * kdv * (1.0 - c),
    ]
}

fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

/// The 3 × 3 map M minimising Σ ‖M a_k − b_k‖².
fn best_linear_map(a: &[[f64; 3]], b: &[[f64; 3]]) -> nalgebra::Matrix3<f64> {
    use nalgebra::{Matrix3, Vector3};
    let (mut aa, mut ba) = (Matrix3::zeros(), Matrix3::zeros());
    for (x, y) in a.iter().zip(b) {
        let (x, y) = (Vector3::from(*x), Vector3::from(*y));
        aa += x * x.transpose();
        ba += y * x.transpose();
    }
    ba * aa.try_inverse().unwrap()
}

fn apply(m: &nalgebra::Matrix3<f64>, v: [f64; 3]) -> [f64; 3] {
    let r = m * nalgebra::Vector3::from(v);
    [r.x, r.y, r.z]
}

/// The recursive method's error and the κ its test used, with κ measured (`None`, the
/// default) or fixed.
fn recursive_error_with_kappa(
    r: &Rendered,
    capture: &photostereo::Capture,
    kappa: Option<f64>,
) -> (f64, f64) {
    recursive_run(r, capture, |p| p.detection.relative_noise = kappa)
}

/// κ measured as the light-to-light misfit follows a rig's calibration error: with
/// every light direction given 1.5° off (twenty lights, Lambertian and glossy scenes, 0.5%
/// noise) it measures 1–5% (a 1.5° error changes a reading by up to 2.6% of its level), and
/// the test that accepts that much misfit keeps the lights a fixed 1% would drop: the
/// recursive error falls against κ = 1% on every scene (by at least 3%; measured 0.78–0.95 of
/// it) and by at least 12% on average (measured 16%).
#[test]
fn measured_kappa_follows_the_lights_calibration_error() {
    let mut ratios = Vec::new();
    for (i, (kind, brdf)) in [
        (SceneKind::Sphere, Brdf::Lambert),
        (SceneKind::Bumps, Brdf::Lambert),
        (SceneKind::Sphere, Brdf::BlinnPhong),
        (SceneKind::Terrain, Brdf::BlinnPhong),
    ]
    .into_iter()
    .enumerate()
    {
        let r = render(kind, Rig::Dome(20), brdf, 0.005, 11 + i as u64);
        let mut capture = r.capture().unwrap();
        // Each light 1.5° off about its own axis (independent errors, as a calibration leaves).
        for (k, d) in capture.lights.directions.iter_mut().enumerate() {
            let t = k as f64;
            let other = [(2.4 * t).sin(), (3.7 * t).cos(), (1.3 * t + 0.5).sin()];
            let axis = normalise(cross(*d, other));
            *d = rotate(*d, axis, 1.5f64.to_radians());
        }
        capture.forget_statistics();
        let (fixed, _) = recursive_error_with_kappa(&r, &capture, Some(0.01));
        let (measured, kappa) = recursive_error_with_kappa(&r, &capture, None);
        eprintln!(
            "{kind} {}: κ measured {:.2}%: {measured:.3}°, κ = 1%: {fixed:.3}°",
            brdf.name(),
            100.0 * kappa
        );
        assert!((0.01..0.05).contains(&kappa), "{kind}: κ {kappa}");
        assert!(
            measured < 0.97 * fixed,
            "{kind}: {measured:.3}° with κ measured, {fixed:.3}° at 1%"
        );
        ratios.push(measured / fixed);
    }
    let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
    assert!(mean < 0.88, "mean ratio {mean:.3}: {ratios:?}");
}

/// Smooth departures from Lambert are what the test must find, not model error it must accept:
/// under fifty lights, the broad lobes of a Torrance–Sparrow surface (with sensor noise only)
/// measure κ below 0.5% — the all-residual scale would count them — and the recursive error
/// is no worse than at κ = 1% (measured 0.03–0.08° better).
#[test]
fn measured_kappa_leaves_smooth_lobes_to_the_test() {
    for (i, kind) in [SceneKind::Sphere, SceneKind::Bumps, SceneKind::Face]
        .into_iter()
        .enumerate()
    {
        let r = render(
            kind,
            Rig::Dome(50),
            Brdf::TorranceSparrow,
            0.005,
            21 + i as u64,
        );
        let capture = r.capture().unwrap();
        let (fixed, _) = recursive_error_with_kappa(&r, &capture, Some(0.01));
        let (measured, kappa) = recursive_error_with_kappa(&r, &capture, None);
        eprintln!(
            "{kind}: κ measured {:.2}%: {measured:.3}°, κ = 1%: {fixed:.3}°",
            100.0 * kappa
        );
        assert!(kappa < 0.005, "{kind}: κ {kappa}");
        assert!(
            measured <= fixed + 0.01,
            "{kind}: {measured:.3}° with κ measured, {fixed:.3}° at 1%"
        );
    }
}
