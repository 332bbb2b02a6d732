//! Calibration on the public `psmImages` data: lights from the `chrome` mirror sphere, scored by
//! least squares on the matte `gray` sphere, whose true normals follow from its outline.

use photostereo::calibrate::{calibrate, fit_mask_circle, CalibrationOptions, SphereFiles};
use photostereo::estimate::{Estimator, LeastSquares};
use photostereo::metrics::angular_error_deg;
use photostereo::progress::Silent;
use photostereo::{Capture, Lights};
use std::path::PathBuf;

fn psm(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/psmImages")).join(name)
}

/// Mean angular error (degrees) of least squares on `gray` with `lights`, over the mask pixels
/// within 90% of the fitted radius, against the sphere normals of the fitted circle.
fn gray_error(lights: &Lights) -> f64 {
    let files = SphereFiles::resolve(&[psm("gray.txt")]).unwrap();
    let loaded = files.load(&Silent).unwrap();
    let mask = loaded.mask.clone().unwrap();
    let (w, h) = (loaded.images[0].width, loaded.images[0].height);
    let fit = fit_mask_circle(&mask, w, h, "gray mask").unwrap();
    let c = fit.circle;
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
        let e = angular_error_deg(est.normals[p], [g[0] as f32, g[1] as f32, g[2] as f32]);
        sum += e;
        n += 1;
    }
    assert!(n > 1000, "{n} pixels");
    sum / n as f64
}

fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    d.clamp(-1.0, 1.0).acos().to_degrees()
}

#[test]
fn chrome_lights_do_as_well_as_the_reference_on_gray() {
    let files = SphereFiles::resolve(&[psm("chrome.txt")]).unwrap();
    let loaded = files.load(&Silent).unwrap();
    let cal = calibrate(
        &loaded.images,
        loaded.mask.as_deref(),
        None,
        &CalibrationOptions::default(),
    )
    .unwrap();
    let ours = cal.to_lights().unwrap();
    let reference = Lights::read_directions(&psm("lights.reference.txt")).unwrap();
    println!("sphere {:?}", cal.sphere);
    let mut diffs = Vec::new();
    for (k, (a, b)) in ours.directions.iter().zip(&reference.directions).enumerate() {
        let d = angle_deg(*a, *b);
        diffs.push(d);
        let hl = cal.lights[k].highlight.unwrap();
        println!("light {k}: ours {:?} ref {:?} diff {d:.2} hl ({:.2},{:.2}) px {} sat {} conf {:.2}", a, b, hl.x, hl.y, hl.pixels, hl.saturated, cal.lights[k].confidence);
    }
    println!("mean diff {:.3}", diffs.iter().sum::<f64>() / diffs.len() as f64);
    for w in &cal.warnings { println!("warning {:?}", w); }
    let e_ours = gray_error(&ours);
    let e_ref = gray_error(&reference);
    println!("gray error: ours {e_ours:.3} reference {e_ref:.3}");
    assert!(e_ours <= e_ref + 0.05, "ours {e_ours:.3}° vs reference {e_ref:.3}°");
}
