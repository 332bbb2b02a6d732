//! Captures as cameras write them, from linear ones with ground truth: each image encoded
//! through a response (sRGB, a bare power law), with a room's ambient light added (and its
//! frame written as `ambient.*`), at an exposure that changes from image to image (recorded in
//! EXIF), as 8-bit PNG, 16-bit PNG or JPEG. `photostereo synth --response … --ambient …
//! --exposure-jitter … --format jpeg` and the tests' re-encodings of real captures use it.

use crate::base::error::{Error, Result};
use crate::base::rng::Pcg32;
use crate::io::imageio::{read_image, write_png16, write_png8};
use crate::io::layouts::CaptureFiles;
use crate::io::photometry::{Exposure, Response};
use crate::model::image::Image;
use std::path::{Path, PathBuf};

/// The file format a camera writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraFormat {
    Png8,
    Png16,
    /// Baseline JPEG at this quality (1 to 100), with EXIF declaring the response (sRGB, or
    /// Adobe RGB's power law; [`jpeg_colour_space`]).
    Jpeg(u8),
}

/// How to write a capture as a camera would.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraSpec {
    pub response: Response,
    /// The ambient light added to every image: its brightest (99th percentile) reading as a
    /// share of full scale; 0 = none. It lights the scene evenly from every light's side at
    /// once (the mean of the images), so it shades like a lamp over the camera.
    pub ambient: f64,
    /// Exposures spread log-uniformly from ×1/jitter to ×jitter about the nominal exposure
    /// (EXIF records each); the pixel data are the source's scaled by exposure/jitter, so the
    /// longest exposure is the source's own and none clips; 1 = all the same.
    pub exposure_jitter: f64,
    pub format: CameraFormat,
    pub seed: u64,
}

/// The nominal exposure a re-encoded image records: 1/60 s, ISO 100, f/8, its time scaled.
const BASE_TIME_S: f64 = 1.0 / 60.0;

/// Encodes the images of `src` into `dst` as `spec` says (named like the source, with the
/// format's extension), writes the ambient frame as `ambient.*` when `spec.ambient > 0`, and
/// `filenames.txt` listing the new names. Returns the images written and their exposures
/// relative to the nominal exposure. The ambient frame is taken at the longest exposure
/// (×jitter).
pub fn reencode_capture(
    src: &CaptureFiles,
    dst: &Path,
    spec: &CameraSpec,
) -> Result<(Vec<PathBuf>, Vec<f64>)> {
    check_spec(spec)?;
    let mut rng = Pcg32::new(spec.seed, 7);
    let n = src.images.len();
    let exposures: Vec<f64> = (0..n)
        .map(|_| {
            if spec.exposure_jitter > 1.0 {
                let t = rng.next_f64();
                spec.exposure_jitter.powf(2.0 * t - 1.0)
            } else {
                1.0
            }
        })
        .collect();
    let ambient = if spec.ambient > 0.0 {
        Some(ambient_light(src, spec.ambient)?)
    } else {
        None
    };
    let ext = match spec.format {
        CameraFormat::Jpeg(_) => "jpg",
        _ => "png",
    };
    let mut written = Vec::with_capacity(n);
    for (k, path) in src.images.iter().enumerate() {
        let img = read_image(path)?;
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("image")
            .to_string();
        let out = dst.join(format!("{stem}.{ext}"));
        write_camera_image(&out, &img, ambient.as_ref(), exposures[k], spec)?;
        if path.parent() == Some(dst) && *path != out {
            std::fs::remove_file(path).map_err(|e| Error::io(path, e))?;
        }
        written.push(out);
    }
    if let Some(a) = &ambient {
        let zero = Image {
            data: vec![0.0; a.data.len()],
            ..a.clone()
        };
        write_camera_image(
            &dst.join(format!("ambient.{ext}")),
            &zero,
            Some(a),
            spec.exposure_jitter,
            spec,
        )?;
    }
    let names: Vec<String> = written
        .iter()
        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    let list = dst.join("filenames.txt");
    std::fs::write(&list, names.join("\n") + "\n").map_err(|e| Error::io(&list, e))?;
    Ok((written, exposures))
}

fn check_spec(spec: &CameraSpec) -> Result<()> {
    if !(0.0..0.5).contains(&spec.ambient) {
        return Err(Error::invalid(format!(
            "ambient level {}: expected a share of full scale from 0 to 0.5",
            spec.ambient
        )));
    }
    if !(1.0..=16.0).contains(&spec.exposure_jitter) {
        return Err(Error::invalid(format!(
            "exposure jitter {}: expected a factor from 1 (none) to 16",
            spec.exposure_jitter
        )));
    }
    if let CameraFormat::Jpeg(q) = spec.format {
        if !(1..=100).contains(&q) {
            return Err(Error::invalid(format!(
                "JPEG quality {q}: expected 1 to 100"
            )));
        }
        if jpeg_colour_space(spec.response).is_none() {
            return Err(Error::invalid(format!(
                "response {} in a JPEG: a JPEG declares sRGB or Adobe RGB (gamma:{ADOBE_RGB_GAMMA}) \
                 and is read so; write {} images as PNG",
                spec.response.name(),
                spec.response.name()
            )));
        }
    }
    Ok(())
}

/// Adobe RGB (1998)'s transfer exponent, 563/256: what a reader takes an uncalibrated EXIF
/// colour space to mean.
const ADOBE_RGB_GAMMA: f64 = 563.0 / 256.0;

/// The EXIF colour space (tag 0xA001) that declares `response` in a JPEG: 1 (sRGB) for sRGB,
/// 0xFFFF (uncalibrated, read as Adobe RGB) for Adobe RGB's power law; None for a response a
/// JPEG cannot declare (linear, other powers), since readers take an undeclared JPEG as sRGB.
pub fn jpeg_colour_space(response: Response) -> Option<u16> {
    match response {
        Response::Srgb => Some(1),
        Response::Gamma(g) if (g - ADOBE_RGB_GAMMA).abs() < 1e-9 => Some(0xFFFF),
        _ => None,
    }
}

/// The ambient light: the mean of the images, scaled so that its 99th percentile over the
/// frame is `level`.
fn ambient_light(src: &CaptureFiles, level: f64) -> Result<Image> {
    let mut sum: Option<Image> = None;
    for path in &src.images {
        let img = read_image(path)?;
        match &mut sum {
            None => sum = Some(img),
            Some(s) => s.data.iter_mut().zip(&img.data).for_each(|(a, b)| *a += b),
        }
    }
    let mut a = sum.ok_or_else(|| Error::invalid("no images to re-encode"))?;
    let mut values = a.data.clone();
    let (_, p99, _) = values.select_nth_unstable_by((a.data.len() - 1) * 99 / 100, f32::total_cmp);
    let p99 = p99.max(1e-12);
    drop(values);
    let s = (level / p99 as f64) as f32;
    a.data.iter_mut().for_each(|v| *v *= s);
    Ok(a)
}

/// Writes one image as the camera would: `(linear + ambient) × exposure / jitter`, clipped to
/// full scale, encoded through the response and quantised by the format; a JPEG's EXIF records
/// the nominal exposure times `exposure`.
fn write_camera_image(
    out: &Path,
    linear: &Image,
    ambient: Option<&Image>,
    exposure: f64,
    spec: &CameraSpec,
) -> Result<()> {
    // The encoded value of sample i in [0, 1], quantised straight into the format's type.
    let encoded = |i: usize| -> f64 {
        let a = ambient.map_or(0.0, |a| a.data[i] as f64);
        let y = ((linear.data[i] as f64 + a) * exposure / spec.exposure_jitter).clamp(0.0, 1.0);
        spec.response.encode(y)
    };
    let to_u8 = || -> Vec<u8> {
        (0..linear.data.len())
            .map(|i| (encoded(i) * 255.0).round() as u8)
            .collect()
    };
    let (w, h, c) = (linear.width, linear.height, linear.channels);
    match spec.format {
        CameraFormat::Png16 => {
            let v: Vec<u16> = (0..linear.data.len())
                .map(|i| (encoded(i) * 65535.0).round() as u16)
                .collect();
            write_png16(out, w, h, c, &v)
        }
        CameraFormat::Png8 => write_png8(out, w, h, c, &to_u8()),
        CameraFormat::Jpeg(q) => {
            let exposure = Exposure {
                time_s: Some(BASE_TIME_S * exposure),
                iso: Some(100.0),
                f_number: Some(8.0),
            };
            // check_spec refused the responses a JPEG cannot declare.
            let colour_space = jpeg_colour_space(spec.response).unwrap_or(1);
            let exif = exif_block_declaring(&exposure, 1, colour_space);
            write_jpeg(out, w, h, c, &to_u8(), q, exif)
        }
    }
}

/// Writes a baseline JPEG (grey or RGB) with an EXIF block.
pub fn write_jpeg(
    out: &Path,
    width: usize,
    height: usize,
    channels: usize,
    data: &[u8],
    quality: u8,
    exif: Vec<u8>,
) -> Result<()> {
    use image::ImageEncoder;
    let color = match channels {
        1 => image::ExtendedColorType::L8,
        3 => image::ExtendedColorType::Rgb8,
        _ => {
            return Err(Error::invalid(format!(
                "cannot write a JPEG with {channels} channels"
            )))
        }
    };
    let mut bytes = Vec::new();
    let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, quality);
    if !exif.is_empty() {
        enc.set_exif_metadata(exif)
            .map_err(|e| Error::file(out, format!("JPEG encoding failed: {e}")))?;
    }
    enc.write_image(data, width as u32, height as u32, color)
        .map_err(|e| Error::file(out, format!("JPEG encoding failed: {e}")))?;
    std::fs::write(out, bytes).map_err(|e| Error::io(out, e))
}

/// A little-endian EXIF block (a TIFF structure: IFD0 with the orientation and a pointer to
/// the Exif IFD holding ExposureTime, FNumber, PhotographicSensitivity and ColorSpace sRGB),
/// as EXIF 2.32 lays it out.
pub fn exif_block(e: &Exposure) -> Vec<u8> {
    exif_block_oriented(e, 1)
}

/// [`exif_block`] with an orientation tag (1 to 8).
pub fn exif_block_oriented(e: &Exposure, orientation: u16) -> Vec<u8> {
    exif_block_declaring(e, orientation, 1)
}

/// [`exif_block_oriented`] declaring the EXIF colour space `colour_space` (1 sRGB, 0xFFFF
/// uncalibrated: [`jpeg_colour_space`]).
pub fn exif_block_declaring(e: &Exposure, orientation: u16, colour_space: u16) -> Vec<u8> {
    // Layout: header (8), IFD0 at 8 with 2 entries (2 + 24 + 4 = 30 bytes, to 38), the Exif
    // IFD at 38 with 4 entries (2 + 48 + 4 = 54 bytes, to 92), then two rationals.
    let rational = |v: f64| -> (u32, u32) {
        let d = 1_000_000u32;
        ((v * d as f64).round() as u32, d)
    };
    let (t, f) = (
        rational(e.time_s.unwrap_or(BASE_TIME_S)),
        rational(e.f_number.unwrap_or(8.0)),
    );
    let mut b: Vec<u8> = b"II*\0".to_vec();
    b.extend_from_slice(&8u32.to_le_bytes());
    let entry = |b: &mut Vec<u8>, tag: u16, kind: u16, count: u32, value: u32| {
        b.extend_from_slice(&tag.to_le_bytes());
        b.extend_from_slice(&kind.to_le_bytes());
        b.extend_from_slice(&count.to_le_bytes());
        b.extend_from_slice(&value.to_le_bytes());
    };
    const SHORT: u16 = 3;
    const LONG: u16 = 4;
    const RATIONAL: u16 = 5;
    b.extend_from_slice(&2u16.to_le_bytes());
    entry(&mut b, 0x0112, SHORT, 1, orientation as u32);
    entry(&mut b, 0x8769, LONG, 1, 38);
    b.extend_from_slice(&0u32.to_le_bytes());
    b.extend_from_slice(&4u16.to_le_bytes());
    entry(&mut b, 0x829A, RATIONAL, 1, 92);
    entry(&mut b, 0x829D, RATIONAL, 1, 100);
    entry(
        &mut b,
        0x8827,
        SHORT,
        1,
        e.iso.unwrap_or(100.0).round() as u32,
    );
    entry(&mut b, 0xA001, SHORT, 1, colour_space as u32);
    b.extend_from_slice(&0u32.to_le_bytes());
    for (num, den) in [t, f] {
        b.extend_from_slice(&num.to_le_bytes());
        b.extend_from_slice(&den.to_le_bytes());
    }
    b
}
