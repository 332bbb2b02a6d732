//! Photographs as cameras write them: JPEG decoding against an independent decoder, damaged
//! files, EXIF orientation and exposure, and captures re-encoded as cameras write them (sRGB
//! JPEG, a bare power law in 8-bit PNG, ambient light with its frame, exposures that change)
//! reconstructed as well as their linear originals.
//!
//! `tests/data/jpeg/` holds a 40 × 30 pattern encoded by libjpeg-turbo 2.1.5 (`cjpeg -quality
//! 90`, with `-progressive` and `-grayscale`) and its decodings by the same library (`djpeg`,
//! `*.djpeg.pnm`): an encoder and a decoder independent of the ones under test.
//!
//! The re-encodings of the DiLiGenT objects read `../shared/data/diligent` (never copied into
//! the repository) and are `#[ignore]`d (minutes):
//! `cargo test --release -p photostereo --test camera_captures -- --ignored --nocapture`.

use photostereo::base::progress::Silent;
use photostereo::io::camera::{
    exif_block_oriented, reencode_capture, write_jpeg, CameraFormat, CameraSpec,
};
use photostereo::io::imageio::read_image;
use photostereo::io::layouts::CaptureFiles;
use photostereo::io::photometry::{Exposure, Photometry, Response, ResponseChoice};
use photostereo::method::engine::{reconstruct, Method, Params};
use photostereo::scene::{Rig, SceneKind, SynthSpec};
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/jpeg")).join(name)
}

/// A binary PNM (P5 grey, P6 RGB, maxval 255): width, height, channels, samples.
fn read_pnm(path: &Path) -> (usize, usize, usize, Vec<u8>) {
    let bytes = std::fs::read(path).unwrap();
    let mut fields = Vec::new();
    let mut at = 0;
    while fields.len() < 4 {
        while bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        let start = at;
        while !bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        fields.push(String::from_utf8_lossy(&bytes[start..at]).into_owned());
    }
    let channels = if fields[0] == "P6" { 3 } else { 1 };
    let (w, h) = (fields[1].parse().unwrap(), fields[2].parse().unwrap());
    (w, h, channels, bytes[at + 1..].to_vec())
}

#[test]
fn jpegs_decode_as_libjpeg_decodes_them() {
    for name in ["baseline", "progressive", "grey"] {
        let img = read_image(&fixture(&format!("{name}.jpg"))).unwrap();
        let (w, h, c, reference) = read_pnm(&fixture(&format!("{name}.djpeg.pnm")));
        assert_eq!(
            (img.width, img.height, img.channels, img.bit_depth),
            (w, h, c, 8)
        );
        let diffs: Vec<f64> = img
            .data
            .iter()
            .zip(&reference)
            .map(|(a, b)| ((*a as f64 * 255.0).round() - *b as f64).abs())
            .collect();
        let max = diffs.iter().cloned().fold(0.0, f64::max);
        let mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
        // Decoders may round the inverse DCT and the chroma upsampling differently: a few
        // levels at most, well under one on average.
        assert!(max <= 4.0 && mean < 0.5, "{name}: max {max}, mean {mean}");
    }
    // The progressive and baseline files code the same picture at the same quality.
    let a = read_image(&fixture("baseline.jpg")).unwrap();
    let b = read_image(&fixture("progressive.jpg")).unwrap();
    let gap = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| ((x - y) * 255.0).round().abs())
        .fold(0.0f32, f32::max);
    assert!(gap <= 4.0, "{gap}");
}

#[test]
fn damaged_jpegs_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["baseline", "progressive", "grey"] {
        let bytes = std::fs::read(fixture(&format!("{name}.jpg"))).unwrap();
        let p = dir.path().join(format!("cut-{name}.jpg"));
        // Every truncation short of the last two bytes (the end-of-image marker) is refused.
        for len in 0..bytes.len() - 2 {
            std::fs::write(&p, &bytes[..len]).unwrap();
            let r = std::panic::catch_unwind(|| read_image(&p));
            let r = r.unwrap_or_else(|_| panic!("{name}: truncated at {len} panicked"));
            let e = r
                .err()
                .unwrap_or_else(|| panic!("{name} truncated at {len} was read"))
                .to_string();
            assert!(e.contains(&format!("cut-{name}.jpg")), "{e}");
        }
        // Flipped bytes: read or refused, never a panic.
        for at in (0..bytes.len()).step_by(3) {
            let mut b = bytes.clone();
            b[at] ^= 0x5A;
            std::fs::write(&p, &b).unwrap();
            let r = std::panic::catch_unwind(|| read_image(&p));
            assert!(r.is_ok(), "{name}: byte {at} flipped panicked");
        }
    }
    // A header declaring 65000 × 65000 in a small file is refused before decoding.
    let mut bytes = std::fs::read(fixture("baseline.jpg")).unwrap();
    let sof = bytes.windows(2).position(|w| w == [0xFF, 0xC0]).unwrap();
    bytes[sof + 5..sof + 9].copy_from_slice(&[0xFD, 0xE8, 0xFD, 0xE8]);
    let p = dir.path().join("huge.jpg");
    std::fs::write(&p, &bytes).unwrap();
    let e = read_image(&p).unwrap_err().to_string();
    assert!(e.contains("huge.jpg") && e.contains("65000"), "{e}");
}

/// A 6 × 4 RGB image whose pixel (x, y) reads x · 40 in red and y · 60 in green.
fn ramp() -> Vec<u8> {
    let mut v = Vec::new();
    for y in 0..4u8 {
        for x in 0..6u8 {
            v.extend_from_slice(&[x * 40, y * 60, 128]);
        }
    }
    v
}

#[test]
fn exif_orientation_and_exposure_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("turned.jpg");
    let exposure = Exposure {
        time_s: Some(1.0 / 125.0),
        iso: Some(400.0),
        f_number: Some(5.6),
    };
    write_jpeg(&p, 6, 4, 3, &ramp(), 100, exif_block_oriented(&exposure, 6)).unwrap();
    // Orientation 6: the stored 0th row is the visual right side, the 0th column the top.
    let img = read_image(&p).unwrap();
    assert_eq!((img.width, img.height), (4, 6));
    let at = |x: usize, y: usize, c: usize| (img.data[(y * 4 + x) * 3 + c] * 255.0).round();
    // Visual (3, 0), the top-right corner, is stored (0, 0): red 0, green 0.
    assert!(at(3, 0, 0) <= 3.0 && at(3, 0, 1) <= 3.0);
    // Visual (0, 5), bottom-left, is stored (5, 3): red 200, green 180.
    assert!((at(0, 5, 0) - 200.0).abs() <= 4.0 && (at(0, 5, 1) - 180.0).abs() <= 4.0);
    let bytes = std::fs::read(&p).unwrap();
    let meta = photostereo::io::photometry::meta::read_meta(&bytes).unwrap();
    assert_eq!(meta.orientation, 6);
    assert_eq!(meta.exposure, exposure);
    assert_eq!(meta.declared.unwrap().0, Response::Srgb);
    assert!(meta.decoder.starts_with("jpeg baseline"));
}

/// A small Lambertian capture rendered under a dome, written linear into `dir`.
fn synth_linear(scene: SceneKind, dir: &Path) -> (CaptureFiles, Vec<[f32; 3]>) {
    let mut spec = SynthSpec::new(scene, Rig::Dome(24));
    spec.size = 96;
    spec.render.brdf = photostereo::scene::Brdf::Lambert;
    spec.render.noise_sigma = 0.002;
    let (rendered, target) = photostereo::io::synth::synth_to_folder(&spec, dir, false).unwrap();
    (
        CaptureFiles::diligent(&target).unwrap(),
        rendered.truth.normals,
    )
}

fn l2_error(files: &CaptureFiles, truth: &[[f32; 3]]) -> (f64, Vec<String>) {
    let capture = files.load(&Silent).unwrap();
    let params = Params {
        method: Method::L2,
        integrate: false,
        ..Params::default()
    };
    let mut rec = reconstruct(&capture, &params, &Silent).unwrap();
    let e = rec.evaluate(truth).unwrap();
    (e.mean_deg, capture.notes.clone())
}

fn camera(files: &CaptureFiles, dir: &Path, spec: CameraSpec) -> CaptureFiles {
    std::fs::create_dir_all(dir).unwrap();
    for f in ["light_directions.txt", "light_intensities.txt", "mask.png"] {
        let src = files.images[0].parent().unwrap().join(f);
        if src.exists() {
            std::fs::copy(&src, dir.join(f)).unwrap();
        }
    }
    reencode_capture(files, dir, &spec).unwrap();
    CaptureFiles::diligent(dir).unwrap()
}

/// A JPEG says what its values mean (EXIF colour space 1: sRGB; 0xFFFF, uncalibrated: Adobe
/// RGB's 563/256 power) and is decoded through it, reconstructing within 0.8° of the linear
/// original as the camera captures below do. A response a JPEG cannot declare (linear, another
/// power) is refused: under the sRGB a reader assumes, such values would be raised to about
/// 2.2 and lose the Lambertian model.
#[test]
fn a_jpeg_declares_its_response_or_is_refused() {
    let root = tempfile::tempdir().unwrap();
    let (linear, truth) = synth_linear(SceneKind::Sphere, &root.path().join("lin"));
    let (base, _) = l2_error(&linear, &truth);
    let spec = |response| CameraSpec {
        response,
        ambient: 0.0,
        exposure_jitter: 1.0,
        format: CameraFormat::Jpeg(90),
        seed: 5,
    };
    for (name, response) in [
        ("srgb", Response::Srgb),
        ("adobe", Response::Gamma(563.0 / 256.0)),
    ] {
        let jpeg = camera(&linear, &root.path().join(name), spec(response));
        let bytes = std::fs::read(&jpeg.images[0]).unwrap();
        let meta = photostereo::io::photometry::meta::read_meta(&bytes).unwrap();
        assert_eq!(meta.declared.unwrap().0, response, "{name}");
        let (e, _) = l2_error(&jpeg, &truth);
        assert!(e < base + 0.8, "{name}: {e:.2}° vs linear {base:.2}°");
    }
    for response in [Response::Linear, Response::Gamma(2.2)] {
        let dir = root.path().join("refused");
        std::fs::create_dir_all(&dir).unwrap();
        let e = reencode_capture(&linear, &dir, &spec(response))
            .unwrap_err()
            .to_string();
        assert!(e.contains("JPEG") && e.contains(&response.name()), "{e}");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
    }
}

/// On three rendered scenes: an sRGB JPEG with EXIF exposures over ×0.5–×2 of the nominal one
/// (the pixel data scaled likewise, from half the linear original) and ambient light with
/// its frame reconstructs within 0.8° of the linear original with no option; a bare 2.2 power
/// law in 8-bit PNG is flagged (read as linear), and `auto` recovers its exponent within 0.1,
/// sRGB, and linear on the linear capture.
#[test]
fn rendered_camera_captures_reconstruct_like_linear_ones() {
    let root = tempfile::tempdir().unwrap();
    for (i, scene) in [SceneKind::Sphere, SceneKind::Bumps, SceneKind::Terrain]
        .into_iter()
        .enumerate()
    {
        let (linear, truth) = synth_linear(scene, &root.path().join(format!("lin{i}")));
        let (base, _) = l2_error(&linear, &truth);
        let jpeg = camera(
            &linear,
            &root.path().join(format!("jpeg{i}")),
            CameraSpec {
                response: Response::Srgb,
                ambient: 0.08,
                exposure_jitter: 2.0,
                format: CameraFormat::Jpeg(90),
                seed: 3,
            },
        );
        assert!(jpeg.photometry.ambient.is_some());
        // The recorded exposures, relative to the nominal 1/60 s, span ×0.5–×2.
        let rel: Vec<f64> = jpeg
            .images
            .iter()
            .map(|p| {
                let meta = photostereo::io::photometry::meta::read_meta(&std::fs::read(p).unwrap());
                meta.unwrap().exposure.time_s.unwrap() * 60.0
            })
            .collect();
        let (lo, hi) = rel
            .iter()
            .fold((f64::MAX, 0.0f64), |(a, b), &t| (a.min(t), b.max(t)));
        assert!(
            lo >= 0.499 && hi <= 2.001 && lo < 0.7 && hi > 1.4,
            "{rel:?}"
        );
        let (e, notes) = l2_error(&jpeg, &truth);
        assert!(
            e < base + 0.8,
            "{scene:?}: jpeg {e:.2}° vs {base:.2}° linear; {notes:?}"
        );
        let gamma = camera(
            &linear,
            &root.path().join(format!("gamma{i}")),
            CameraSpec {
                response: Response::Gamma(2.2),
                ambient: 0.0,
                exposure_jitter: 1.0,
                format: CameraFormat::Png8,
                seed: 3,
            },
        );
        let (_, notes) = l2_error(&gamma, &truth);
        assert!(
            notes.iter().any(|n| n.contains("--response")),
            "{scene:?}: {notes:?}"
        );
        let mut auto = gamma.clone();
        auto.photometry.response = Some(ResponseChoice::Auto);
        let (e, notes) = l2_error(&auto, &truth);
        let g = gamma_of(&notes);
        assert!((g - 2.2).abs() <= 0.1, "{scene:?}: {notes:?}");
        assert!(
            e < base + 0.8,
            "{scene:?}: gamma auto {e:.2}° vs {base:.2}°"
        );
        let mut lin_auto = linear.clone();
        lin_auto.photometry.response = Some(ResponseChoice::Auto);
        let (_, notes) = l2_error(&lin_auto, &truth);
        assert!(
            notes.iter().any(|n| n.contains("response linear")),
            "{scene:?}: {notes:?}"
        );
        let mut srgb = camera(
            &linear,
            &root.path().join(format!("srgb{i}")),
            CameraSpec {
                response: Response::Srgb,
                ambient: 0.0,
                exposure_jitter: 1.0,
                format: CameraFormat::Png8,
                seed: 3,
            },
        );
        srgb.photometry.response = Some(ResponseChoice::Auto);
        let (_, notes) = l2_error(&srgb, &truth);
        assert!(
            notes.iter().any(|n| n.contains("response srgb")),
            "{scene:?}: {notes:?}"
        );
    }
}

/// The best power law a response note states.
fn gamma_of(notes: &[String]) -> f64 {
    let n = notes
        .iter()
        .find(|n| n.contains("best power law"))
        .unwrap_or_else(|| panic!("{notes:?}"));
    let after = n.split("best power law ").nth(1).unwrap();
    after.split_whitespace().next().unwrap().parse().unwrap()
}

/// A sphere written as sRGB JPEGs (EXIF exposures jittered by `exposure_jitter`) into
/// `root/jpeg`, with image `k` written again carrying the EXIF block `exif` instead; returns
/// the capture and that image's path.
fn jpegs_with_one_rewritten(
    root: &Path,
    exposure_jitter: f64,
    k: usize,
    exif: Vec<u8>,
) -> (CaptureFiles, PathBuf) {
    let (linear, _) = synth_linear(SceneKind::Sphere, &root.join("lin"));
    let jpeg = camera(
        &linear,
        &root.join("jpeg"),
        CameraSpec {
            response: Response::Srgb,
            ambient: 0.0,
            exposure_jitter,
            format: CameraFormat::Jpeg(90),
            seed: 1,
        },
    );
    let path = jpeg.images[k].clone();
    let img = read_image(&path).unwrap();
    let bytes: Vec<u8> = img.data.iter().map(|v| (v * 255.0).round() as u8).collect();
    write_jpeg(&path, img.width, img.height, 3, &bytes, 90, exif).unwrap();
    (jpeg, path)
}

#[test]
fn a_capture_whose_orientations_differ_is_refused() {
    let root = tempfile::tempdir().unwrap();
    let exif = exif_block_oriented(&Exposure::default(), 3);
    let (jpeg, turned) = jpegs_with_one_rewritten(root.path(), 1.0, 3, exif);
    let e = jpeg.load(&Silent).unwrap_err().to_string();
    assert!(
        e.contains(&turned.display().to_string()) && e.contains("orientation"),
        "{e}"
    );
}

/// Exposures recorded in some files only cannot be corrected: the capture loads with every
/// image's factor 1 and a note naming a file without one.
#[test]
fn exposures_recorded_in_some_files_only_are_left_and_named() {
    let root = tempfile::tempdir().unwrap();
    let (jpeg, bare) = jpegs_with_one_rewritten(root.path(), 2.0, 5, Vec::new());
    let (capture, report) = jpeg.load_measured(&Silent, &Default::default()).unwrap();
    let name = bare.display().to_string();
    assert!(
        capture
            .notes
            .iter()
            .any(|n| n.contains("exposures not corrected") && n.contains(&name)),
        "{:?}",
        capture.notes
    );
    assert_eq!(report.images.len(), jpeg.images.len());
    assert!(report.images.iter().all(|r| r.exposure_factor == 1.0));
}

#[test]
fn photometry_options_have_a_json_form() {
    let p = Photometry {
        response: Some(ResponseChoice::Fixed(Response::Gamma(2.2))),
        ambient: Some(PathBuf::from("dark.jpg")),
        ignore_exposure: true,
        ..Photometry::default()
    };
    let json = serde_json::to_string(&p).unwrap();
    assert_eq!(
        json,
        r#"{"response":"gamma:2.2","ambient":"dark.jpg","ignore_exposure":true}"#
    );
    assert_eq!(serde_json::from_str::<Photometry>(&json).unwrap(), p);
}

// ---- DiLiGenT objects re-encoded as cameras write them ----

fn diligent(name: &str) -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/diligent"
    ))
    .join(format!("{name}PNG"))
}

/// The ways a camera writes a capture that the issue's acceptance names.
fn kinds() -> Vec<(&'static str, CameraSpec, Option<ResponseChoice>)> {
    let spec = |response, ambient, exposure_jitter, format| CameraSpec {
        response,
        ambient,
        exposure_jitter,
        format,
        seed: 11,
    };
    vec![
        (
            "srgb-jpeg",
            spec(Response::Srgb, 0.0, 1.0, CameraFormat::Jpeg(90)),
            None,
        ),
        (
            "gamma2.2-png8",
            spec(Response::Gamma(2.2), 0.0, 1.0, CameraFormat::Png8),
            Some(ResponseChoice::Auto),
        ),
        (
            "gamma2.2-png8-given",
            spec(Response::Gamma(2.2), 0.0, 1.0, CameraFormat::Png8),
            Some(ResponseChoice::Fixed(Response::Gamma(2.2))),
        ),
        (
            "linear16+ambient",
            spec(Response::Linear, 0.075, 1.0, CameraFormat::Png16),
            None,
        ),
        (
            "srgb-jpeg-exposure",
            spec(Response::Srgb, 0.0, 2.0, CameraFormat::Jpeg(90)),
            None,
        ),
    ]
}

/// Mean angular errors of `l2` and `recursive` on a capture, and its notes.
fn diligent_errors(files: &CaptureFiles, truth: &[[f32; 3]]) -> ([f64; 2], Vec<String>) {
    let capture = files.load(&Silent).unwrap();
    let mut out = [0.0; 2];
    for (i, method) in [Method::L2, Method::Recursive].into_iter().enumerate() {
        let params = Params {
            method,
            integrate: false,
            ..Params::default()
        };
        let mut rec = reconstruct(&capture, &params, &Silent).unwrap();
        out[i] = rec.evaluate(truth).unwrap().mean_deg;
    }
    (out, capture.notes.clone())
}

#[test]
#[ignore = "minutes: reads and re-encodes the DiLiGenT objects in ../shared/data"]
fn diligent_objects_as_cameras_write_them() {
    let only: Option<String> = std::env::var("PHOTOSTEREO_OBJECTS").ok();
    let root = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    for name in ["ball", "bear", "cat"] {
        if only
            .as_deref()
            .is_some_and(|o| !o.split(',').any(|x| x == name))
        {
            continue;
        }
        let src = diligent(name);
        let original = CaptureFiles::diligent(&src).unwrap();
        let truth = photostereo::io::groundtruth::read_normal_map(&src.join("Normal_gt.mat"))
            .unwrap()
            .normals;
        let (base, _) = diligent_errors(&original, &truth);
        println!(
            "{name} original: l2 {:.2}° recursive {:.2}°",
            base[0], base[1]
        );
        // PHOTOSTEREO_KINDS=a,b measures only those kinds.
        let wanted = std::env::var("PHOTOSTEREO_KINDS").ok();
        for (kind, spec, response) in kinds() {
            if wanted
                .as_deref()
                .is_some_and(|w| !w.split(',').any(|x| x == kind))
            {
                continue;
            }
            let mut files = camera(&original, &root.path().join(format!("{name}-{kind}")), spec);
            files.photometry.response = response;
            let (e, notes) = diligent_errors(&files, &truth);
            let estimate: Vec<&String> = notes
                .iter()
                .filter(|n| n.starts_with("response") || n.starts_with("photometry"))
                .collect();
            println!(
                "{name} {kind}: l2 {:.2}° ({:+.2}) recursive {:.2}° ({:+.2}); {estimate:?}",
                e[0],
                e[0] - base[0],
                e[1],
                e[1] - base[1]
            );
            let tolerance = if kind.contains("jpeg") { 0.8 } else { 0.5 };
            // `auto` on a bare power law is reported, not held to the tolerance: the estimate
            // is biased by the material (see `photometry::estimate`).
            if !kind.ends_with("png8") && (e[0] > base[0] + tolerance || e[1] > base[1] + tolerance)
            {
                failures.push(format!("{name} {kind}: {e:?} vs {base:?}"));
            }
            // Wipe each re-encoding once measured: three objects × five kinds would hold
            // gigabytes.
            let _ = std::fs::remove_dir_all(root.path().join(format!("{name}-{kind}")));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Tiled loading makes the images linear as loading whole does: the same samples.
#[test]
fn tiled_and_whole_loads_make_the_same_linear_samples() {
    use photostereo::io::layouts::LoadOptions;
    use photostereo::model::memory::{Force, Layout};
    let root = tempfile::tempdir().unwrap();
    let (linear, _) = synth_linear(SceneKind::Sphere, &root.path().join("lin"));
    let jpeg = camera(
        &linear,
        &root.path().join("jpeg"),
        CameraSpec {
            response: Response::Srgb,
            ambient: 0.05,
            exposure_jitter: 2.0,
            format: CameraFormat::Jpeg(90),
            seed: 2,
        },
    );
    let whole = jpeg.load(&Silent).unwrap();
    let options = LoadOptions {
        budget: Some(64 << 30),
        spill_dir: Some(root.path().to_path_buf()),
        force: Force {
            layout: Some(Layout::Tiles),
            tile_pixels: Some(500),
            park: None,
        },
        ..Default::default()
    };
    let tiled = jpeg.load_with(&Silent, &options).unwrap();
    assert!(tiled.is_tiled() && !whole.is_tiled());
    let ids: Vec<usize> = (0..whole.n_pixels()).step_by(37).collect();
    let view = tiled.sampled(&ids).unwrap();
    for &p in &ids {
        assert_eq!(view.pixel_samples(p), whole.pixel_samples(p), "pixel {p}");
    }
}

/// True normals, one per pixel.
type Normals = Vec<[f32; 3]>;

/// The encodings the response estimate is measured on.
fn encodings() -> Vec<(&'static str, Option<Response>)> {
    vec![
        ("as-is", None),
        ("gamma1.8", Some(Response::Gamma(1.8))),
        ("gamma2.2", Some(Response::Gamma(2.2))),
        ("gamma2.4", Some(Response::Gamma(2.4))),
        ("srgb", Some(Response::Srgb)),
    ]
}

/// `--response auto` on the DiLiGenT objects and psmImages, as they are and re-encoded into
/// 8-bit PNG through power laws and sRGB: the estimate, its basis and uncertainty, and `l2`'s
/// mean error against the original's (DiLiGenT, which has ground truth). psmImages are 8-bit
/// files of unknown response; their re-encodings treat the stored values as linear.
#[test]
#[ignore = "minutes: reads and re-encodes ../shared/data"]
fn response_estimates_on_real_captures() {
    use photostereo::io::layouts::LoadOptions;
    let only: Option<String> = std::env::var("PHOTOSTEREO_OBJECTS").ok();
    let data = diligent("ball")
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .to_path_buf();
    let root = tempfile::tempdir().unwrap();
    let mut captures: Vec<(String, CaptureFiles, Option<Normals>)> = Vec::new();
    for name in ["ball", "bear", "cat"] {
        let src = diligent(name);
        let truth = photostereo::io::groundtruth::read_normal_map(&src.join("Normal_gt.mat"))
            .unwrap()
            .normals;
        captures.push((
            name.into(),
            CaptureFiles::diligent(&src).unwrap(),
            Some(truth),
        ));
    }
    for name in ["cat", "gray", "buddha", "owl", "horse", "rock"] {
        let psm = data.join("psmImages");
        let files = CaptureFiles::list_file(
            &psm.join(format!("{name}.txt")),
            &psm.join("lights.reference.txt"),
        )
        .unwrap();
        captures.push((format!("psm-{name}"), files, None));
    }
    let mut failures = Vec::new();
    for (name, original, truth) in &captures {
        if only
            .as_deref()
            .is_some_and(|o| !o.split(',').any(|x| x == name))
        {
            continue;
        }
        // PHOTOSTEREO_SKIP=name:N leaves out an object's first N images (and lights).
        let skip: usize = std::env::var("PHOTOSTEREO_SKIP")
            .ok()
            .and_then(|v| {
                let (o, n) = v.split_once(':')?;
                (o == name).then(|| n.parse().ok())?
            })
            .unwrap_or(0);
        let mut original = original.clone();
        if skip > 0 {
            original.images.drain(..skip);
            original.lights.directions.drain(..skip);
            original.lights.intensities.drain(..skip);
        }
        let original = &original;
        let base = truth.as_ref().map(|t| l2_error(original, t).0);
        for (kind, response) in encodings() {
            let dir = root.path().join(format!("{name}-{kind}"));
            let mut files = match response {
                None => original.clone(),
                Some(r) => {
                    std::fs::create_dir_all(&dir).unwrap();
                    let spec = CameraSpec {
                        response: r,
                        ambient: 0.0,
                        exposure_jitter: 1.0,
                        format: CameraFormat::Png8,
                        seed: 11,
                    };
                    let (images, _) = reencode_capture(original, &dir, &spec).unwrap();
                    let mut f = original.clone();
                    f.images = images;
                    f
                }
            };
            files.photometry.response = Some(ResponseChoice::Auto);
            let loaded = files.load_measured(&Silent, &LoadOptions::default());
            let Some(e) = loaded
                .as_ref()
                .ok()
                .and_then(|l| l.1.response_estimate.clone())
            else {
                println!("{name} {kind}: no estimate ({:?})", loaded.err());
                failures.push(format!("{name} {kind}: no estimate"));
                continue;
            };
            let err = truth.as_ref().map(|t| l2_error(&files, t).0);
            println!(
                "{name} {kind}: chose {} ({} {:.3} ± {:.3}; shading {:.2} ± {:.2}; sRGB slope \
                 {:?}; {} rows; images left out {:?}); l2 {}",
                e.chosen,
                e.basis,
                e.gamma,
                e.gamma_std,
                e.gamma_shading,
                e.gamma_shading_std,
                e.srgb_slope,
                e.rows,
                e.images_left_out,
                match (err, base) {
                    (Some(a), Some(b)) => format!("{a:.2}° ({:+.2} vs the original)", a - b),
                    _ => "-".into(),
                }
            );
            if truth.is_some() {
                let ok = match response {
                    None => e.response == Response::Linear,
                    Some(Response::Gamma(g)) => match e.response {
                        Response::Gamma(h) => (h - g).abs() <= 0.1,
                        _ => false,
                    },
                    Some(r) => e.response == r,
                };
                if !ok {
                    failures.push(format!("{name} {kind}: {}", e.chosen));
                }
            }
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
