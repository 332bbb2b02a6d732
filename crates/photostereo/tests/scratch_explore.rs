use photostereo::calibrate::*;
use photostereo::estimate::{Estimator, LeastSquares};
use photostereo::metrics::angular_error_deg;
use photostereo::progress::Silent;
use photostereo::{Capture, Lights};
use std::path::PathBuf;
fn psm(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/psmImages")).join(name)
}
fn gray_error(lights: &Lights, intens: Option<Vec<[f64;3]>>) -> f64 {
    let files = SphereFiles::resolve(&[psm("gray.txt")]).unwrap();
    let loaded = files.load(&Silent).unwrap();
    let mask = loaded.mask.clone().unwrap();
    let (w, h) = (loaded.images[0].width, loaded.images[0].height);
    let c = fit_mask_circle(&mask, w, h, "gray").unwrap().circle;
    let mut lights = lights.clone();
    if let Some(i) = intens { lights = lights.with_intensities(i).unwrap(); }
    let capture = Capture::from_images(&loaded.images, lights, Some(mask)).unwrap();
    let est = LeastSquares.estimate(&capture, &Silent).unwrap();
    let (mut sum, mut n) = (0.0, 0usize);
    for p in 0..capture.n_pixels() {
        let (row, col) = capture.pixel_position(p);
        let (dx, dy) = (col as f64 - c.cx, row as f64 - c.cy);
        if (dx * dx + dy * dy).sqrt() > 0.9 * c.r { continue; }
        let g = c.normal_at(col as f64, row as f64).unwrap();
        sum += angular_error_deg(est.normals[p], [g[0] as f32, g[1] as f32, g[2] as f32]);
        n += 1;
    }
    sum / n as f64
}
#[test]
fn explore() {
    let files = SphereFiles::resolve(&[psm("chrome.txt")]).unwrap();
    let loaded = files.load(&Silent).unwrap();
    let cal = calibrate(&loaded.images, loaded.mask.as_deref(), None, &CalibrationOptions::default()).unwrap();
    let c = cal.sphere.circle;
    let gfiles = SphereFiles::resolve(&[psm("gray.txt")]).unwrap().load(&Silent).unwrap();
    let gc = fit_mask_circle(gfiles.mask.as_ref().unwrap(), 512, 340, "g").unwrap();
    println!("gray circle {:?}", gc);
    let hl: Vec<[f64;2]> = cal.lights.iter().map(|l| { let h = l.highlight.unwrap(); [h.x, h.y] }).collect();
    for s in [0.9, 0.95, 1.0, 1.05, 1.1, 1.15] {
        let alt = Circle { r: c.r * s, ..c };
        let dirs: Vec<[f64;3]> = hl.iter().map(|p| reflect_view(alt.normal_at(p[0], p[1]).unwrap())).collect();
        let l = Lights::new(&dirs).unwrap();
        println!("radius x{s}: gray error {:.3}", gray_error(&l, None));
    }
    let alt = Circle{cx:256.07, cy:149.96, r:132.63};
    let dirs: Vec<[f64;3]> = hl.iter().map(|p| reflect_view(alt.normal_at(p[0], p[1]).unwrap())).collect();
    println!("ref-fitted circle: gray error {:.3}", gray_error(&Lights::new(&dirs).unwrap(), None));
    let ours = cal.to_lights().unwrap();
    let reference = Lights::read_directions(&psm("lights.reference.txt")).unwrap();
    let io = matte_intensities(&gfiles.images, &gc.circle, &ours.directions).unwrap();
    let ir = matte_intensities(&gfiles.images, &gc.circle, &reference.directions).unwrap();
    println!("intensities ours {:?}", io.iter().map(|v| (v[0]*1000.0).round()/1000.0).collect::<Vec<_>>());
    println!("with matte intensities: ours {:.3} ref {:.3}", gray_error(&ours, Some(io)), gray_error(&reference, Some(ir)));
}
