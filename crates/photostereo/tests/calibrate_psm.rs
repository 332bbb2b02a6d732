//! Calibration on the public `psmImages` data: lights from the `chrome` mirror sphere, scored by
//! least squares on the matte `gray` sphere, whose true normals follow from its outline; and the
//! experiment that explains the difference to `lights.reference.txt`.

use nalgebra::{DMatrix, DVector};
use photostereo::base::progress::Silent;
use photostereo::calibrate::{
    calibrate, fit_mask_circle, reflect_view, Calibration, CalibrationOptions, Circle,
};
use photostereo::io::layouts::sphere::SphereFiles;
use photostereo::solve::estimate::{Estimator, LeastSquares};
use photostereo::solve::metrics::angular_error_deg;
use photostereo::{Capture, Lights};
use std::path::PathBuf;

fn psm(name: &str) -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/psmImages"
    ))
    .join(name)
}

/// Mean angular error (degrees) of least squares on `gray` with `lights`, over the mask pixels
/// within 90% of the fitted radius, against the normals of the sphere fitted to its mask.
fn gray_error(lights: &Lights) -> f64 {
    let loaded = SphereFiles::resolve(&[psm("gray.txt")])
        .unwrap()
        .load(&Silent)
        .unwrap();
    let mask = loaded.mask.clone().unwrap();
    let (w, h) = (loaded.images[0].width, loaded.images[0].height);
    let c = fit_mask_circle(&mask, w, h, "gray mask").unwrap().circle;
    let capture = Capture::from_images(&loaded.images, lights.clone(), Some(mask)).unwrap();
    let est = LeastSquares.estimate(&capture, &Silent).unwrap();
    let (mut sum, mut n) = (0.0, 0usize);
    for p in 0..capture.n_pixels() {
        let (row, col) = capture.pixel_position(p);
        let (dx, dy) = (col as f64 - c.cx, row as f64 - c.cy);
        if (dx * dx + dy * dy).sqrt() > 0.9 * c.r {
            continue;
        }
        let g = c.normal_at(col as f64, row as f64).unwrap();
        sum += angular_error_deg(est.normals[p], [g[0] as f32, g[1] as f32, g[2] as f32]);
        n += 1;
    }
    assert!(n > 20_000, "{n} pixels");
    sum / n as f64
}

fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    d.clamp(-1.0, 1.0).acos().to_degrees()
}

fn chrome() -> Calibration {
    let loaded = SphereFiles::resolve(&[psm("chrome.txt")])
        .unwrap()
        .load(&Silent)
        .unwrap();
    calibrate(
        &loaded.images,
        loaded.mask.as_deref(),
        Some("chrome.mask.png"),
        &CalibrationOptions::default(),
    )
    .unwrap()
}

fn reference() -> Lights {
    photostereo::io::light_files::read_directions(&psm("lights.reference.txt")).unwrap()
}

#[test]
fn chrome_lights_do_as_well_as_the_reference_on_gray() {
    let cal = chrome();
    assert!(cal.warnings.is_empty(), "{:?}", cal.warnings);
    let ours = cal.to_lights().unwrap();
    let e_ours = gray_error(&ours);
    let e_ref = gray_error(&reference());
    println!("gray, least squares, inner 90%: ours {e_ours:.3}°, reference {e_ref:.3}°");
    // "No worse" within 0.05°, far below the uncertainty of the gray sphere's own outline fit
    // (docs/calibration.md: 4.652° vs 4.649°).
    assert!(
        e_ours <= e_ref + 0.05,
        "ours {e_ours:.3}° vs reference {e_ref:.3}°"
    );
    // Both are plausible figures for a matte sphere under 12 calibrated lights.
    assert!(e_ref > 3.0 && e_ref < 6.0, "reference {e_ref:.3}°");
}

#[test]
fn difference_to_the_reference_is_a_larger_sphere_outline() {
    let cal = chrome();
    let c = cal.sphere.circle;
    // The mask's circle.
    assert!(
        (c.cx - 253.23).abs() < 0.05 && (c.cy - 147.74).abs() < 0.05 && (c.r - 120.11).abs() < 0.05
    );
    let ours = cal.to_lights().unwrap();
    let reference = reference();
    let diffs: Vec<f64> = ours
        .directions
        .iter()
        .zip(&reference.directions)
        .map(|(a, b)| angle_deg(*a, *b))
        .collect();
    let mean = diffs.iter().sum::<f64>() / 12.0;
    println!("per-light difference to the reference (°): {diffs:.2?}; mean {mean:.3}");
    assert!((2.5..3.5).contains(&mean), "{mean}");
    // Which circle would turn our highlight positions into the reference directions? Solve
    // x_k = cx + r·n_x,k and y_k = cy − r·n_y,k by least squares, n_k = normalise(l_k + v) the
    // reference's sphere normals.
    let hl: Vec<[f64; 2]> = cal
        .lights
        .iter()
        .map(|l| {
            let h = l.highlight.unwrap();
            [h.x, h.y]
        })
        .collect();
    let mut a = DMatrix::zeros(24, 3);
    let mut b = DVector::zeros(24);
    for (k, l) in reference.directions.iter().enumerate() {
        let hv = [l[0], l[1], l[2] + 1.0];
        let nh = (hv[0] * hv[0] + hv[1] * hv[1] + hv[2] * hv[2]).sqrt();
        let n = [hv[0] / nh, hv[1] / nh];
        a[(2 * k, 0)] = 1.0;
        a[(2 * k, 2)] = n[0];
        b[2 * k] = hl[k][0];
        a[(2 * k + 1, 1)] = 1.0;
        a[(2 * k + 1, 2)] = -n[1];
        b[2 * k + 1] = hl[k][1];
    }
    let s = a.clone().svd(true, true).solve(&b, 1e-12).unwrap();
    let rms = ((&a * &s - &b).norm_squared() / 24.0).sqrt();
    let implied = Circle {
        cx: s[0],
        cy: s[1],
        r: s[2],
    };
    println!("circle implied by the reference: {implied:?}, RMS {rms:.2} px");
    // A 10% larger radius and a centre 2–3 px lower right…
    assert!((1.08..1.13).contains(&(implied.r / c.r)), "{implied:?}");
    assert!((implied.cx - c.cx - 2.8).abs() < 1.0 && (implied.cy - c.cy - 2.2).abs() < 1.0);
    // …explains most of the difference: with it our highlights give directions within 1.3° on
    // average of the reference (the rest is per-image highlight localisation).
    let redone: Vec<f64> = hl
        .iter()
        .zip(&reference.directions)
        .map(|(p, l)| angle_deg(reflect_view(implied.normal_at(p[0], p[1]).unwrap()), *l))
        .collect();
    let mean_redone = redone.iter().sum::<f64>() / 12.0;
    println!("with the implied circle: {redone:.2?}; mean {mean_redone:.3}");
    assert!(mean_redone < 1.35, "{mean_redone}");
    // Perspective does not explain it: a pinhole model with any focal length from 300 px to
    // orthographic leaves the mean difference at 2.9° or more (checked while writing this test;
    // see docs/calibration.md).
}

/// The mirror tests on real spheres: every `chrome` highlight is a small blob far out of the
/// noise (confident), every `gray` "highlight" is the broad lobe of a matte sphere, which is
/// refused; the figures are those of docs/calibration.md.
#[test]
fn chrome_passes_the_mirror_tests_and_gray_is_refused() {
    let cal = chrome();
    for l in &cal.lights {
        let h = l.highlight.unwrap();
        assert!(h.disc_share < 0.01 && h.significance > 100.0, "{h:?}");
        assert!((0.59..0.72).contains(&l.confidence), "{}", l.confidence);
    }
    let loaded = SphereFiles::resolve(&[psm("gray.txt")])
        .unwrap()
        .load(&Silent)
        .unwrap();
    let run = |options: &CalibrationOptions| {
        calibrate(
            &loaded.images,
            loaded.mask.as_deref(),
            Some("gray.mask.png"),
            options,
        )
    };
    let e = run(&CalibrationOptions::default()).unwrap_err().to_string();
    assert!(
        e.contains("no confident highlight") && e.contains("(a matte sphere?)"),
        "{e}"
    );
    let accepted = run(&CalibrationOptions {
        min_confidence: 0.0,
        ..CalibrationOptions::default()
    })
    .unwrap();
    let shares: Vec<f64> = accepted
        .lights
        .iter()
        .map(|l| l.highlight.unwrap().disc_share)
        .collect();
    println!("gray: blob shares of the disc {shares:.3?}");
    assert!(
        shares.iter().all(|&s| (0.25..0.45).contains(&s)),
        "{shares:?}"
    );
    assert!(accepted.lights.iter().all(|l| l.confidence == 0.0));
}
