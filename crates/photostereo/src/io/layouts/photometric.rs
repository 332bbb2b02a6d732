//! Deciding how a capture's images are made linear ([`crate::io::photometry`]): each image's
//! response, exposure factor and the ambient frame, from the files' metadata, the capture's
//! [`Photometry`] choices and, where they leave it open, the readings themselves.

use super::CaptureFiles;
use crate::base::error::{Error, Result};
use crate::io::imageio::decode_image;
use crate::io::photometry::estimate::{
    estimate_response, offset_check, LightInfo, OffsetCheck, ResponseEstimate, Samples,
};
use crate::io::photometry::meta::{read_meta, ImageMeta};
use crate::io::photometry::{
    ImageRecord, Linearisation, PhotometryReport, Response, ResponseChoice,
};
use crate::model::capture::{light_scale, Capture};
use crate::model::image::Image;
use rayon::prelude::*;
use std::path::Path;

/// Most pixels read for a response estimate.
const ESTIMATE_PIXELS: usize = 4000;

/// The photometric plan of a capture: the steps, what report.json says of them, and notes.
pub(crate) struct Plan {
    pub linearisation: Linearisation,
    pub report: PhotometryReport,
    pub notes: Vec<String>,
}

/// The metadata of an image file. PNG and JPEG keep theirs before the pixels: only the
/// file's first 4 MiB are read; a TIFF's directories may lie anywhere, so it is read whole.
fn meta_of(path: &Path) -> Result<ImageMeta> {
    use std::io::Read;
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut head = Vec::new();
    file.take(4 << 20)
        .read_to_end(&mut head)
        .map_err(|e| Error::io(path, e))?;
    let bytes = match crate::io::imageio::sniff(&head) {
        Some(crate::io::imageio::Format::Tiff | crate::io::imageio::Format::Raw) => {
            crate::io::limits::read_file(path)?
        }
        _ => head,
    };
    read_meta(&bytes).map_err(|m| Error::file(path, m))
}

impl CaptureFiles {
    /// Decides how each image is made linear. `mask` (the images' frame) picks the pixels a
    /// response estimate reads; `channels` is the images' channel count.
    pub(crate) fn photometric_plan(&self, mask: &[bool], channels: usize) -> Result<Plan> {
        let p = &self.photometry;
        let metas: Vec<ImageMeta> = self
            .images
            .par_iter()
            .map(|f| meta_of(f))
            .collect::<Result<_>>()?;
        let mut notes = Vec::new();
        self.check_orientation(&metas, &mut notes)?;
        let ambient_meta = p.ambient.as_deref().map(meta_of).transpose()?;
        let (factors, ambient_factor) =
            self.exposure_factors(&metas, ambient_meta.as_ref(), &mut notes);
        // Each image's response and where it comes from, before any estimate.
        let mut responses: Vec<(Response, String)> = match p.response {
            Some(ResponseChoice::Fixed(r)) => vec![(r, "--response".into()); metas.len()],
            _ => metas.iter().map(ImageMeta::default_response).collect(),
        };
        let unknown_8bit = metas
            .iter()
            .all(|m| m.declared.is_none() && m.bit_depth == 8);
        let mut estimate = None;
        let mut ambient = None;
        if let Some(path) = &p.ambient {
            ambient = Some(read_image_checked(path, self, channels)?);
        }
        if p.response == Some(ResponseChoice::Auto) || (p.response.is_none() && unknown_8bit) {
            let samples = self.encoded_samples(mask, channels, ambient.as_ref())?;
            let lights = LightInfo {
                directions: self.lights.directions.clone(),
                intensities: self.lights.intensities.clone(),
                scale: factors.iter().map(|f| 1.0 / f).collect(),
                ambient_scale: 1.0 / ambient_factor,
            };
            estimate = estimate_response(&samples, &lights);
            match (&estimate, p.response) {
                (Some(e), Some(ResponseChoice::Auto)) => {
                    responses = vec![
                        (
                            e.response,
                            "estimated from the capture (--response auto)".into()
                        );
                        metas.len()
                    ];
                    notes.push(estimate_note(e, true));
                }
                (Some(e), _) => {
                    if e.response != Response::Linear {
                        notes.push(estimate_note(e, false));
                    }
                }
                (None, Some(ResponseChoice::Auto)) => {
                    return Err(Error::invalid(format!(
                        "--response auto: the response cannot be estimated from this capture ({} \
                         images, {} pixel(s) lit by every light; it needs five images and 30 \
                         such pixels): give it (--response srgb, gamma:G or linear)",
                        metas.len(),
                        lit_pixels(&samples, &lights)
                    )))
                }
                (None, _) => {}
            }
        }
        // A calibration frame goes through the images' response (the first image's when
        // each keeps its own, unless the frame declares its own).
        let frame_response = |meta: Option<&ImageMeta>| match p.response {
            Some(ResponseChoice::Fixed(r)) => r,
            Some(ResponseChoice::Auto) => responses[0].0,
            None => meta.map_or(responses[0].0, |m| m.default_response().0),
        };
        let linear_frame = |path: &Path| -> Result<Image> {
            let mut img = read_image_checked(path, self, channels)?;
            frame_response(Some(&meta_of(path)?)).linearise(&mut img);
            img.bit_depth = 32;
            Ok(img)
        };
        let mut steps = Linearisation {
            dark: p.dark.as_deref().map(linear_frame).transpose()?,
            ..Linearisation::default()
        };
        if let Some(path) = p.flat.as_deref() {
            let mut flat = linear_frame(path)?;
            steps.dark_and_flat(&mut flat);
            steps.flat_gain = Some(flat_gain(&flat, mask, path)?);
        }
        if let Some(img) = &mut ambient {
            // The ambient frame: linear, less the dark, through the flat, then its exposure.
            frame_response(ambient_meta.as_ref()).linearise(img);
            steps.dark_and_flat(img);
            let s = (1.0 / ambient_factor) as f32;
            img.data.iter_mut().for_each(|v| *v *= s);
            img.bit_depth = 32;
        }
        let records = self
            .images
            .iter()
            .zip(&metas)
            .zip(&responses)
            .zip(&factors)
            .map(|(((f, m), (r, src)), fac)| ImageRecord {
                file: f.display().to_string(),
                decoder: m.decoder.clone(),
                response: r.name(),
                response_source: src.clone(),
                exposure: m.exposure,
                exposure_factor: *fac,
                ambient_removed: ambient.is_some(),
            })
            .collect();
        Ok(Plan {
            linearisation: Linearisation {
                responses: responses.iter().map(|r| r.0).collect(),
                exposure_factors: factors,
                ambient,
                ..steps
            },
            report: PhotometryReport {
                images: records,
                ambient_file: p.ambient.as_ref().map(|a| a.display().to_string()),
                dark_file: p.dark.as_ref().map(|a| a.display().to_string()),
                flat_file: p.flat.as_ref().map(|a| a.display().to_string()),
                response_estimate: estimate,
                offset_check: None,
            },
            notes,
        })
    }

    /// Refuses images whose EXIF orientations differ (a tripod's frames share the sensor's
    /// grid: turning some of them would misalign the stack); notes a common turn.
    fn check_orientation(&self, metas: &[ImageMeta], notes: &mut Vec<String>) -> Result<()> {
        let o = metas[0].orientation;
        if let Some(k) = metas.iter().position(|m| m.orientation != o) {
            return Err(Error::file(
                &self.images[k],
                format!(
                    "EXIF orientation {} but {} has {}: the images of a capture must share \
                     their orientation (the camera's tilt sensor changed its mind between \
                     frames; set the same orientation tag on every image, e.g. with exiftool \
                     -Orientation=1 -n)",
                    metas[k].orientation,
                    self.images[0].display(),
                    o
                ),
            ));
        }
        if o != 1 {
            notes.push(format!(
                "the images carry EXIF orientation {o}: they are turned upright as a viewer \
                 shows them, and a mask must be drawn on the upright images"
            ));
        }
        Ok(())
    }

    /// Each image's exposure relative to the capture's median (all 1 when the exposures are
    /// equal, not all recorded, or ignored), and the ambient frame's.
    fn exposure_factors(
        &self,
        metas: &[ImageMeta],
        ambient: Option<&ImageMeta>,
        notes: &mut Vec<String>,
    ) -> (Vec<f64>, f64) {
        let ones = (vec![1.0; metas.len()], 1.0);
        let rel: Vec<Option<f64>> = metas.iter().map(|m| m.exposure.relative()).collect();
        let known = rel.iter().filter(|r| r.is_some()).count();
        if known == 0 {
            return ones;
        }
        let values: Vec<f64> = rel.iter().flatten().copied().collect();
        let (lo, hi) = values
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
        if hi <= lo * (1.0 + 1e-6) && known == metas.len() {
            return ones;
        }
        if self.photometry.ignore_exposure {
            notes.push(format!(
                "the images' exposures differ ({:.3}× from the shortest to the longest) but \
                 --ignore-exposure leaves them as they are",
                hi / lo
            ));
            return ones;
        }
        if known < metas.len() {
            let k = rel.iter().position(Option::is_none).unwrap_or(0);
            notes.push(format!(
                "exposures not corrected: {} of {} images record their exposure ({} has none)",
                known,
                metas.len(),
                self.images[k].display()
            ));
            return ones;
        }
        let mut sorted = values.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        let ambient_factor = ambient
            .and_then(|m| m.exposure.relative())
            .map_or(1.0, |a| a / median);
        notes.push(format!(
            "the images' exposures differ ({:.3}× from the shortest to the longest, EXIF time × \
             ISO / f-number²): each image's readings are divided by its exposure relative to \
             the median (report.json photometry.images; --ignore-exposure leaves them)",
            hi / lo
        ));
        (values.iter().map(|v| v / median).collect(), ambient_factor)
    }

    /// The encoded readings of up to [`ESTIMATE_PIXELS`] mask pixels, spread evenly over the
    /// mask, of every image (decoded in parallel) and of the ambient frame.
    fn encoded_samples(
        &self,
        mask: &[bool],
        channels: usize,
        ambient: Option<&Image>,
    ) -> Result<Samples> {
        let ids: Vec<usize> = mask
            .iter()
            .enumerate()
            .filter(|(_, &m)| m)
            .map(|(i, _)| i)
            .collect();
        let step = ids.len().div_ceil(ESTIMATE_PIXELS).max(1);
        let ids: Vec<usize> = ids.into_iter().step_by(step).collect();
        let n = self.images.len();
        let planes: Vec<(Vec<f32>, u8)> = self
            .images
            .par_iter()
            .map(|path| {
                let img = read_image_checked(path, self, channels)?;
                let mut v = Vec::with_capacity(ids.len() * channels);
                for &i in &ids {
                    v.extend_from_slice(&img.data[i * channels..(i + 1) * channels]);
                }
                Ok((v, img.bit_depth))
            })
            .collect::<Result<_>>()?;
        let rows = ids.len() * channels;
        let mut encoded = vec![0f32; rows * n];
        for (k, (plane, _)) in planes.iter().enumerate() {
            for (r, v) in plane.iter().enumerate() {
                encoded[r * n + k] = *v;
            }
        }
        let ambient = ambient.map(|a| {
            let mut v = Vec::with_capacity(rows);
            for &i in &ids {
                v.extend_from_slice(&a.data[i * channels..(i + 1) * channels]);
            }
            v
        });
        Ok(Samples {
            encoded,
            ambient,
            images: n,
            channels,
            bit_depth: planes.iter().map(|p| p.1).max().unwrap_or(8),
        })
    }
}

/// The per-sample reciprocal of a flat field (linear, less the dark frame) normalised to its
/// mean inside the mask, per channel. A flat that reads under 5% of its mean at a mask pixel
/// does not light the object: refused, naming the pixel.
fn flat_gain(flat: &Image, mask: &[bool], path: &Path) -> Result<Vec<f32>> {
    let c = flat.channels;
    let inside = |i: usize| mask.get(i).copied().unwrap_or(true);
    let mut means = vec![0.0f64; c];
    let mut count = 0usize;
    let pixels = flat.data.chunks_exact(c).enumerate();
    for (_, px) in pixels.filter(|(i, _)| inside(*i)) {
        means.iter_mut().zip(px).for_each(|(m, v)| *m += *v as f64);
        count += 1;
    }
    if count == 0 || means.iter().any(|m| *m <= 0.0) {
        return Err(Error::file(
            path,
            "the flat field is dark inside the mask (expected a frame of a uniform white target)",
        ));
    }
    means.iter_mut().for_each(|m| *m /= count as f64);
    let mut gain = Vec::with_capacity(flat.data.len());
    for (i, px) in flat.data.chunks_exact(c).enumerate() {
        for (v, m) in px.iter().zip(&means) {
            let rel = *v as f64 / m;
            if rel < 0.05 && inside(i) {
                return Err(Error::file(
                    path,
                    format!(
                        "the flat field reads {:.1}% of its mean at pixel (x {}, y {}) inside \
                         the mask: a flat must light the whole object (expected a frame of a \
                         uniform white target under the capture's optics)",
                        100.0 * rel,
                        i % flat.width,
                        i / flat.width
                    ),
                ));
            }
            gain.push(if rel > 0.05 { (1.0 / rel) as f32 } else { 1.0 });
        }
    }
    Ok(gain)
}

/// Reads an image (encoded values) and checks its size and channels against the capture's
/// first image.
fn read_image_checked(path: &Path, files: &CaptureFiles, channels: usize) -> Result<Image> {
    let bytes = crate::io::limits::read_file(path)?;
    let img = decode_image(&bytes).map_err(|m| Error::file(path, m))?;
    let first = crate::io::imageio::probe(&files.images[0])?;
    if (img.width, img.height) != (first.width, first.height) || img.channels != channels {
        return Err(Error::file(
            path,
            format!(
                "image is {}×{} with {} channel(s) but {} is {}×{} with {}: a capture's images \
                 (and its ambient frame) must share size and channels",
                img.width,
                img.height,
                img.channels,
                files.images[0].display(),
                first.width,
                first.height,
                channels
            ),
        ));
    }
    Ok(img)
}

fn lit_pixels(s: &Samples, lights: &LightInfo) -> usize {
    use crate::io::photometry::estimate::{lit_rows, pilot_response};
    lit_rows(s, lights, pilot_response(s)).len()
}

/// The note of a response estimate: used (`--response auto`) or only reported.
fn estimate_note(e: &ResponseEstimate, used: bool) -> String {
    let basis = if e.basis == "brightness" {
        "from how each light's brightness shows in the readings against its given intensity \
         and exposure"
            .to_string()
    } else {
        format!(
            "from the shading alone, which a surface darker than matte at grazing light biases \
             low{}",
            match e.intensities_disagree {
                Some([g, sd]) => format!(
                    "; the given light intensities disagree with the images (each light's \
                     brightness shows as its intensity to the power {g:.2} ± {sd:.2}), so they \
                     could not be used"
                ),
                None => String::new(),
            }
        )
    };
    let left_out = e
        .left_out_note()
        .map_or(String::new(), |n| format!("; {n}"));
    let what = format!(
        "the readings fit the Lambertian model best under the response {} (best power law \
         {:.2} ± {:.2}, {basis}; {} pixel-channels lit by every light{left_out})",
        e.chosen, e.gamma, e.gamma_std, e.rows
    );
    if used {
        format!("response: {what}")
    } else {
        format!(
            "response: 8-bit images without colour metadata are read as linear, but {what}: \
             if a camera or an editor wrote them, give their response (--response srgb for \
             most; --response {} is this estimate, which rests on the given intensities or on \
             a matte surface)",
            e.chosen
        )
    }
}

/// The constant-offset check ([`crate::io::photometry::estimate::offset_check`]) on up to
/// [`ESTIMATE_PIXELS`] mask pixels of a loaded (linear) capture with distant lights: the
/// pixel-channels whose least-squares normal sees every light at least 5° above its horizon
/// (attached shadows and the limb are no Lambertian projection) and with no reading below half
/// its Lambertian prediction (a cast shadow; an offset only raises the dark readings).
pub(crate) fn offset_of(capture: &Capture) -> Result<Option<OffsetCheck>> {
    if capture.lights.near.is_some() || capture.n_pixels() == 0 {
        return Ok(None);
    }
    let n = capture.n_lights();
    let c = capture.channels;
    let step = capture.n_pixels().div_ceil(ESTIMATE_PIXELS).max(1);
    let ids: Vec<usize> = (0..capture.n_pixels()).step_by(step).collect();
    let view = capture.sampled(&ids)?;
    let dirs = &capture.lights.directions;
    let scales: Vec<[f32; 3]> = capture
        .lights
        .intensities
        .iter()
        .map(|i| light_scale(i, c))
        .collect();
    let min_cos = 5f64.to_radians().sin();
    let mut rows: Vec<Vec<f64>> = vec![Vec::new(); c];
    for &p in &ids {
        let s = view.pixel_samples(p);
        for (ch, out) in rows.iter_mut().enumerate() {
            let x: Vec<f64> = (0..n).map(|k| s[k * c + ch] as f64).collect();
            let b = solve_normal(dirs, &x);
            let norm = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
            let lit = |(l, v): (&[f64; 3], &f64)| {
                let p = l[0] * b[0] + l[1] * b[1] + l[2] * b[2];
                p >= min_cos * norm && *v >= 0.5 * p
            };
            if norm > 0.0 && dirs.iter().zip(&x).all(lit) {
                out.extend_from_slice(&x);
            }
        }
    }
    // Channels side by side would mix their light scales: the channel with most rows.
    let (ch, x) = rows
        .iter()
        .enumerate()
        .max_by_key(|(_, r)| r.len())
        .map(|(ch, r)| (ch, r.clone()))
        .unwrap_or((0, Vec::new()));
    let per_light: Vec<f64> = scales.iter().map(|s| s[ch] as f64).collect();
    Ok(offset_check(&x, dirs, &per_light))
}

/// The least-squares `b` of `x_k ≈ l_k · b`.
fn solve_normal(dirs: &[[f64; 3]], x: &[f64]) -> [f64; 3] {
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut r = nalgebra::Vector3::<f64>::zeros();
    for (l, v) in dirs.iter().zip(x) {
        let l = nalgebra::Vector3::from(*l);
        m += l * l.transpose();
        r += *v * l;
    }
    m.try_inverse()
        .map(|i| {
            let b = i * r;
            [b[0], b[1], b[2]]
        })
        .unwrap_or([0.0; 3])
}

/// The note of a detected offset: its likely causes and what removes it.
pub(crate) fn offset_note(c: &OffsetCheck) -> String {
    format!(
        "photometry: the readings share a constant offset across lights of {:+.1}% (± {:.1}%) of \
         their mean, which the Lambertian model lacks: light left on in the room, or a black \
         level not subtracted — photograph the scene with every controlled light off and give \
         it as --ambient FILE (or ambient.png in the capture folder); if the images are not \
         linear, --response auto",
        100.0 * c.relative_offset,
        100.0 * c.std_error,
    )
}
