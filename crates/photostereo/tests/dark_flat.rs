//! Dark frames and flat fields (issue 33): a rendered capture given a sensor offset (a dark
//! frame) and vignetting (a flat field), `reading = V(x) · light + D(x)`, comes back with
//! `dark` and `flat` to the original's normals and, up to one factor, its albedo; each frame
//! left out costs what physics says it should (the offset bends the normals, the vignetting
//! stays in the albedo). The frames are found as `dark.*`/`flat.*` in a capture folder too.

use photostereo::base::progress::Silent;
use photostereo::io::imageio::{read_image, write_png16};
use photostereo::io::layouts::{CaptureFiles, LoadOptions};
use photostereo::io::photometry::{Frames, Photometry};
use photostereo::method::engine::{reconstruct, Method, Params};
use photostereo::scene::{Rig, SceneKind, SynthSpec};
use std::path::Path;

const SIZE: usize = 64;

/// Vignetting: 1 at the centre, 0.55 at the corners (a cos⁴-like fall-off).
fn vignette(x: usize, y: usize) -> f32 {
    let c = (SIZE as f32 - 1.0) / 2.0;
    let r2 = ((x as f32 - c).powi(2) + (y as f32 - c).powi(2)) / (2.0 * c * c);
    1.0 - 0.45 * r2
}

/// The sensor's offset: 2-4% of full scale, patterned.
fn dark(x: usize, y: usize, c: usize) -> f32 {
    0.02 + 0.01 * ((x + 2 * y + c) % 3) as f32
}

fn write(path: &Path, f: impl Fn(usize, usize, usize) -> f32) {
    let data: Vec<u16> = (0..SIZE * SIZE * 3)
        .map(|i| {
            let (p, c) = (i / 3, i % 3);
            (f(p % SIZE, p / SIZE, c).clamp(0.0, 1.0) * 65535.0).round() as u16
        })
        .collect();
    write_png16(path, SIZE, SIZE, 3, &data).unwrap();
}

struct Measured {
    error_deg: f64,
    /// The spread (coefficient of variation) over the mask of the albedo's ratio to the
    /// original capture's: 0 when equal up to one factor.
    albedo_spread: f64,
}

fn measure(
    files: &CaptureFiles,
    truth: &[[f32; 3]],
    reference: Option<&[f32]>,
) -> (Measured, Vec<f32>) {
    let (capture, _) = files
        .load_measured(&Silent, &LoadOptions::default())
        .unwrap();
    let params = Params {
        method: Method::L2,
        integrate: false,
        ..Params::default()
    };
    let mut rec = reconstruct(&capture, &params, &Silent).unwrap();
    let error_deg = rec.evaluate(truth).unwrap().mean_deg;
    let albedo_spread = reference.map_or(0.0, |r| {
        let ratios: Vec<f64> = (0..SIZE * SIZE)
            .filter(|&i| rec.mask[i] && r[3 * i + 1] > 0.05)
            .map(|i| rec.albedo[3 * i + 1] as f64 / r[3 * i + 1] as f64)
            .collect();
        let n = ratios.len() as f64;
        let mean = ratios.iter().sum::<f64>() / n;
        let var = ratios.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        var.sqrt() / mean
    });
    (
        Measured {
            error_deg,
            albedo_spread,
        },
        rec.albedo.clone(),
    )
}

#[test]
fn dark_and_flat_undo_an_offset_and_vignetting() {
    let root = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Sphere, Rig::Dome(24));
    spec.size = SIZE;
    spec.render.brdf = photostereo::scene::Brdf::Lambert;
    spec.render.noise_sigma = 0.002;
    let (rendered, orig_dir) =
        photostereo::io::synth::synth_to_folder(&spec, &root.path().join("orig"), false).unwrap();
    let truth = &rendered.truth.normals;
    let orig = CaptureFiles::diligent(&orig_dir).unwrap();
    let (base, albedo) = measure(&orig, truth, None);

    let cam = root.path().join("cam");
    std::fs::create_dir_all(&cam).unwrap();
    for f in ["light_directions.txt", "light_intensities.txt", "mask.png"] {
        if orig_dir.join(f).exists() {
            std::fs::copy(orig_dir.join(f), cam.join(f)).unwrap();
        }
    }
    for p in &orig.images {
        let img = read_image(p).unwrap();
        write(&cam.join(p.file_name().unwrap()), |x, y, c| {
            vignette(x, y) * img.data[(y * SIZE + x) * 3 + c] + dark(x, y, c)
        });
    }
    let (dark_file, flat_file) = (root.path().join("d.png"), root.path().join("f.png"));
    write(&dark_file, dark);
    write(&flat_file, |x, y, c| 0.8 * vignette(x, y) + dark(x, y, c));

    let with = |d: bool, f: bool| {
        let mut files = CaptureFiles::diligent(&cam).unwrap();
        let frames = Frames {
            ambient: None,
            dark: d.then_some(dark_file.as_path()),
            flat: f.then_some(flat_file.as_path()),
        };
        files.photometry = Photometry::from_options(None, frames, false).unwrap();
        measure(&files, truth, Some(&albedo)).0
    };
    let both = with(true, true);
    let dark_only = with(true, false);
    let neither = with(false, false);
    let flat_only = with(false, true);
    eprintln!(
        "original {:.3}°; dark+flat {:.3}° spread {:.4}; dark {:.3}° spread {:.4}; flat {:.3}° \
         spread {:.4}; neither {:.3}° spread {:.4}",
        base.error_deg,
        both.error_deg,
        both.albedo_spread,
        dark_only.error_deg,
        dark_only.albedo_spread,
        flat_only.error_deg,
        flat_only.albedo_spread,
        neither.error_deg,
        neither.albedo_spread
    );
    // Both frames: the original's normals, and its albedo up to one factor (16-bit rounding
    // and the render's noise aside).
    assert!((both.error_deg - base.error_deg).abs() < 0.1);
    assert!(both.albedo_spread < 0.01);
    // The dark frame alone fixes the normals (a per-pixel gain scales a pixel's readings
    // alike), not the albedo: it keeps the vignetting's spread (0.45 × r² over the sphere).
    assert!((dark_only.error_deg - base.error_deg).abs() < 0.1);
    assert!(dark_only.albedo_spread > 0.05);
    // Without the dark frame the offset (2-4% of full scale) bends the normals.
    assert!(neither.error_deg > base.error_deg + 0.3);
    assert!(flat_only.error_deg > base.error_deg + 0.3);

    // The same frames as dark.png and flat.png in the folder are found by themselves, and
    // are not read as photographs.
    std::fs::copy(&dark_file, cam.join("dark.png")).unwrap();
    std::fs::copy(&flat_file, cam.join("flat.png")).unwrap();
    let files = CaptureFiles::diligent(&cam).unwrap();
    assert_eq!(files.images.len(), orig.images.len());
    let (capture, report) = files
        .load_measured(&Silent, &LoadOptions::default())
        .unwrap();
    assert!(report.dark_file.as_deref().unwrap().ends_with("dark.png"));
    assert!(report.flat_file.as_deref().unwrap().ends_with("flat.png"));
    drop(capture);
    let (found, _) = measure(&files, truth, Some(&albedo));
    assert!((found.error_deg - both.error_deg).abs() < 1e-9);
}

#[test]
fn bad_dark_and_flat_frames_are_errors() {
    let root = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Sphere, Rig::Dome(8));
    spec.size = 32;
    let (_, dir) =
        photostereo::io::synth::synth_to_folder(&spec, &root.path().join("c"), false).unwrap();
    let missing = root.path().join("nowhere.png");
    let e = Photometry::from_options(
        None,
        Frames {
            dark: Some(&missing),
            ..Frames::default()
        },
        false,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("dark=") && e.contains("no such image file"),
        "{e}"
    );
    // A flat of another size names the file.
    let small = root.path().join("small.png");
    write_png16(&small, 8, 8, 3, &vec![30000; 8 * 8 * 3]).unwrap();
    let mut files = CaptureFiles::diligent(&dir).unwrap();
    files.photometry.flat = Some(small.clone());
    let e = files.load(&Silent).unwrap_err().to_string();
    assert!(e.contains("small.png") && e.contains("8×8"), "{e}");
    // A flat that is black where the object is.
    let black = root.path().join("black.png");
    write_png16(&black, 32, 32, 3, &vec![0; 32 * 32 * 3]).unwrap();
    files.photometry.flat = Some(black);
    let e = files.load(&Silent).unwrap_err().to_string();
    assert!(e.contains("black.png") && e.contains("flat field"), "{e}");
}
