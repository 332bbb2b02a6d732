//! Camera RAW: DNG files written here from the specifications (tests/dng, an encoder
//! independent of the `rawler` decoder under test) read back as their linear sensor values
//! (black level subtracted, white at 1, no white balance, half size), reconstruct like the
//! 16-bit render they were made from, and bad ones are errors.

#[path = "dng/mod.rs"]
mod dng;

use photostereo::base::progress::Silent;
use photostereo::base::rng::Pcg32;
use photostereo::io::imageio::{decode_image, read_image};
use photostereo::io::layouts::{CaptureFiles, LoadOptions};
use photostereo::io::photometry::meta::read_meta;
use photostereo::io::photometry::Response;
use photostereo::method::engine::{reconstruct, Method, Params};
use photostereo::scene::{Rig, SceneKind, SynthSpec};

const PATTERNS: [(&str, [u8; 4]); 4] = [
    ("RGGB", [0, 1, 1, 2]),
    ("GRBG", [1, 0, 2, 1]),
    ("BGGR", [2, 1, 1, 0]),
    ("GBRG", [1, 2, 0, 1]),
];

#[test]
fn dng_mosaics_read_as_their_linear_values() {
    let mut rng = Pcg32::new(7, 1);
    let (w, h) = (9, 7);
    let black = [500, 512, 524, 536];
    let white = 16000;
    for (name, cfa) in PATTERNS {
        let rgb: Vec<f32> = (0..w * h * 3).map(|_| rng.next_f64() as f32).collect();
        let d = dng::mosaic(w, h, &rgb, cfa, black, white);
        let bytes = d.bytes();
        let img = decode_image(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!((img.width, img.height, img.channels), (w, h, 3), "{name}");
        // Each value from the samples themselves: (sample − its site's black) / (white − black),
        // the two greens averaged; the white balance the file states (AsShotNeutral) unused.
        let mw = 2 * w;
        for y in 0..h {
            for x in 0..w {
                let mut want = [0.0f64; 3];
                for (site, c) in cfa.iter().enumerate() {
                    let (sx, sy) = (2 * x + site % 2, 2 * y + site / 2);
                    let b = black[site] as f64;
                    let v = (d.samples[sy * mw + sx] as f64 - b) / (white as f64 - b);
                    want[*c as usize] += if *c == 1 { 0.5 * v } else { v };
                }
                for c in 0..3 {
                    let got = img.data[(y * w + x) * 3 + c] as f64;
                    assert!(
                        (got - want[c]).abs() < 1e-6,
                        "{name} ({x},{y},{c}): {got} vs {}",
                        want[c]
                    );
                    // Within one sensor step of the values the mosaic was made from.
                    let step = 1.0 / (white as f64 - black[0] as f64);
                    assert!(
                        (got - rgb[(y * w + x) * 3 + c] as f64).abs() <= step,
                        "{name}"
                    );
                }
            }
        }
        let meta = read_meta(&bytes).unwrap();
        assert_eq!(meta.declared.as_ref().unwrap().0, Response::Linear);
        assert!(meta.decoder.contains("raw dng") && meta.decoder.contains("white balance none"));
    }
}

#[test]
fn bad_dngs_are_errors() {
    let rgb = vec![0.5f32; 8 * 6 * 3];
    let good = dng::mosaic(8, 6, &rgb, [0, 1, 1, 2], [0; 4], 4095).bytes();
    // Truncated inside the strip.
    let cut = &good[..good.len() - 40];
    assert!(decode_image(cut).is_err());
    // A four-colour mosaic (red, green, green, cyan).
    let mut four = dng::mosaic(8, 6, &rgb, [0, 1, 1, 2], [0; 4], 4095);
    four.cfa = [0, 1, 1, 3];
    let cmy = four.bytes();
    let e = decode_image(&cmy).unwrap_err();
    assert!(e.contains("mosaic") || e.contains("unsupported"), "{e}");
    // A forged size: 2^20 × 6 samples in a file of a few hundred bytes.
    let mut big = dng::mosaic(8, 6, &rgb, [0, 1, 1, 2], [0; 4], 4095);
    big.width = 1 << 20;
    let bytes = big.bytes();
    let e = decode_image(&bytes).unwrap_err();
    assert!(e.contains("declares"), "{e}");
    // A Fujifilm RAF container is refused with advice.
    let e = decode_image(b"FUJIFILMCCD-RAW 0201FF383501").unwrap_err();
    assert!(e.contains("convert it to DNG"), "{e}");
}

/// A rendered Lambertian capture written as 14-bit DNG mosaics (each pixel a 2×2 block, black
/// 512) reconstructs like the 16-bit PNG render, and report.json says how it was read.
#[test]
fn a_dng_capture_reconstructs_like_its_16bit_render() {
    let root = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Sphere, Rig::Dome(24));
    spec.size = 64;
    spec.render.brdf = photostereo::scene::Brdf::Lambert;
    spec.render.noise_sigma = 0.002;
    let (rendered, png_dir) =
        photostereo::io::synth::synth_to_folder(&spec, &root.path().join("png"), false).unwrap();
    let png = CaptureFiles::diligent(&png_dir).unwrap();
    let dng_dir = root.path().join("dng");
    std::fs::create_dir_all(&dng_dir).unwrap();
    for f in ["light_directions.txt", "light_intensities.txt", "mask.png"] {
        if png_dir.join(f).exists() {
            std::fs::copy(png_dir.join(f), dng_dir.join(f)).unwrap();
        }
    }
    for (k, p) in png.images.iter().enumerate() {
        let img = read_image(p).unwrap();
        let d = dng::mosaic(
            img.width,
            img.height,
            &img.data,
            [0, 1, 1, 2],
            [512; 4],
            16383,
        );
        std::fs::write(dng_dir.join(format!("{:03}.dng", k + 1)), d.bytes()).unwrap();
    }
    let raw = CaptureFiles::diligent(&dng_dir).unwrap();
    assert_eq!(raw.images.len(), png.images.len());
    let params = Params {
        method: Method::L2,
        integrate: false,
        ..Params::default()
    };
    let error = |files: &CaptureFiles| {
        let (capture, report) = files
            .load_measured(&Silent, &LoadOptions::default())
            .unwrap();
        let mut rec = reconstruct(&capture, &params, &Silent).unwrap();
        (
            rec.evaluate(&rendered.truth.normals).unwrap().mean_deg,
            report,
        )
    };
    let (e_png, _) = error(&png);
    let (e_raw, report) = error(&raw);
    // 14 bits against 16: the quantisation is far under the render's noise.
    assert!((e_raw - e_png).abs() < 0.05, "dng {e_raw}° vs png {e_png}°");
    let first = &report.images[0];
    assert_eq!(first.response, "linear");
    assert!(
        first.decoder.contains("white balance none"),
        "{}",
        first.decoder
    );
    assert_eq!(first.response_source, "camera RAW (sensor readings)");
}
