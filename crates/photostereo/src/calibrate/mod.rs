//! Light calibration from a mirror sphere (and optionally relative intensities from a matte
//! sphere).
//!
//! For each image: the sphere's outline gives its centre (cx, cy) and radius r in pixels; the
//! specular highlight at image point (x, y) sees the sphere normal
//! n = ((x − cx)/r, (cy − y)/r, √(1 − …)) in the camera frame (x right, y up, z toward the camera,
//! orthographic view); the light direction is the viewing direction v = (0, 0, 1) mirrored about
//! n: l = 2 (n·v) n − v.
//!
//! The library returns problems with individual images as [`CalibrationWarning`] values; it never
//! prints. A capture in which no light's highlight is confident (confidence below
//! [`CalibrationOptions::min_confidence`] in every image: a matte sphere, noise, no highlights)
//! is refused with an error that says why.

pub mod circle;
pub mod highlight;

pub use circle::{detect_sphere, fit_circle, fit_mask_circle, Circle, CircleFit};
pub use highlight::{find_highlight, Highlight, HighlightOptions, HighlightSearch};

use crate::base::error::{Error, Result};
use crate::model::image::Image;
use crate::model::lights::Lights;
use rayon::prelude::*;

/// Decoded images of a sphere capture with its optional mask.
#[derive(Clone, Debug)]
pub struct SphereImages {
    /// The images in light order.
    pub images: Vec<Image>,
    /// `height * width` flags, true on the sphere, when a mask was given.
    pub mask: Option<Vec<bool>>,
    /// The mask's file name, for messages.
    pub mask_name: Option<String>,
}

/// How the sphere's outline was obtained.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SphereSource {
    /// Fitted to a given mask.
    Mask,
    /// Detected from the images.
    Detected,
}

/// What is wrong with one image's highlight (or with the sphere, for `image: None`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum WarningKind {
    /// No highlight was found: the image has no light direction.
    Missing,
    /// Two separated bright blobs of similar strength.
    Doubled,
    /// The saturated area is larger than expected of a small light.
    Clipped,
    /// The highlight is close to the sphere's rim, where the direction is least precise.
    NearRim,
    /// The sphere touches the image border.
    SphereCut,
    /// The automatically detected outline is irregular (a side never lit, clutter).
    RoughOutline,
    /// The mask's circle is not where the images show the sphere (a mask of another capture,
    /// or shifted): every light's direction is then off.
    MaskOffSphere,
    /// The brightest blob covers more of the sphere than a mirror's highlight can
    /// ([`HighlightOptions::max_disc_share`]): a matte sphere's shading, or a grossly
    /// overexposed highlight. Its confidence is 0.
    NotMirror,
    /// The highlight does not stand [`HighlightOptions::min_significance`] noise σ above the
    /// sphere's median: noise, not a highlight. Its confidence is 0.
    Faint,
    /// The light's confidence is below [`CalibrationOptions::min_confidence`] (for a reason
    /// not already warned of as `missing`, `not_mirror` or `faint`).
    LowConfidence,
}

/// A problem found during calibration.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CalibrationWarning {
    /// 0-based image index, or `None` for the sphere as a whole.
    pub image: Option<usize>,
    /// What kind of problem.
    pub kind: WarningKind,
    /// A sentence for the user.
    pub message: String,
}

/// Parameters of a calibration.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct CalibrationOptions {
    /// The highlight search.
    pub highlight: HighlightOptions,
    /// Highlights farther than this share of the radius from the centre are "near the rim".
    pub near_rim: f64,
    /// A light is confident when its [`LightEstimate::confidence`] reaches this value (0.25 by
    /// default); each light below it is warned of, and a capture without any confident light
    /// is refused. The confidence is the product of five quality factors (and the 0-or-1
    /// mirror test); 0.25 is all five at 3/4 (0.75⁵ ≈ 0.24), or one of them at a quarter: a
    /// highlight at 97% of the radius (n_z 0.25, where a pixel of error turns the direction
    /// four times as much as at the centre), or a second blob with three quarters of the
    /// first's weight. Mirror spheres measure 0.60–0.71 (`psmImages/chrome`) and 0.38–0.80
    /// (the rendered spheres with bloom, saturation, dust, noise, a faint highlight; 0.69–0.77
    /// by default); a matte sphere and noise fail the mirror tests (0).
    pub min_confidence: f64,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        CalibrationOptions {
            highlight: HighlightOptions::default(),
            near_rim: 0.95,
            min_confidence: 0.25,
        }
    }
}

/// The factors of a light's confidence, each in [0, 1]; the confidence is their product.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ConfidenceParts {
    /// (peak − background) / peak.
    pub contrast: f64,
    /// √(blob area over the disc about its centroid that holds it): 1 for a round blob,
    /// about 0.7 for a 2:1 ellipse, lower for streaks.
    pub compactness: f64,
    /// 1 − ¼ · (saturated share of the blob): a flat saturated core locates less precisely.
    pub saturation: f64,
    /// n_z at the highlight: 1 at the sphere's centre, 0 at the rim, where a pixel of error in
    /// the highlight turns the direction most (dθ = 2 dρ / n_z).
    pub rim: f64,
    /// 1 − (mass of the second blob / mass of the first).
    pub uniqueness: f64,
    /// 1 when the blob passes the mirror tests (it covers at most
    /// [`HighlightOptions::max_disc_share`] of the disc and stands at least
    /// [`HighlightOptions::min_significance`] noise σ above the median), else 0.
    pub mirror: f64,
}

/// One image's calibrated light.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LightEstimate {
    /// The highlight, when found.
    pub highlight: Option<Highlight>,
    /// Sphere normal at the highlight (camera frame), when found.
    pub normal: Option<[f64; 3]>,
    /// Unit light direction (camera frame, toward the light), when found.
    pub direction: Option<[f64; 3]>,
    /// Confidence in [0, 1] (0 when missing, or when the blob fails the mirror tests): the
    /// product of [`ConfidenceParts`]. A relative figure for comparing the lights of one
    /// capture (1 = a round, unsaturated, unique highlight at the sphere's centre), not a
    /// probability; below [`CalibrationOptions::min_confidence`] the light is warned of.
    pub confidence: f64,
    /// The factors of the confidence, when found.
    pub confidence_parts: Option<ConfidenceParts>,
}

/// The result of a mirror-sphere calibration.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Calibration {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// The sphere's fitted outline.
    pub sphere: CircleFit,
    /// Where the outline came from.
    pub sphere_source: SphereSource,
    /// One entry per image, in order.
    pub lights: Vec<LightEstimate>,
    /// Problems found, in image order.
    pub warnings: Vec<CalibrationWarning>,
}

/// The light direction (camera frame) that a mirror sphere reflects toward the camera from the
/// point with unit normal `n`: l = 2 (n·v) n − v, v = (0, 0, 1).
pub fn reflect_view(n: [f64; 3]) -> [f64; 3] {
    let d = n[2];
    let l = [2.0 * d * n[0], 2.0 * d * n[1], 2.0 * d * n[2] - 1.0];
    let norm = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
    [l[0] / norm, l[1] / norm, l[2] / norm]
}

/// Calibrates light directions from images of a mirror sphere. The sphere's outline is fitted
/// to `mask` when given, else detected from the images. Errors concern the sphere as a whole
/// (no images, mismatched sizes, no usable outline, `min_confidence` outside [0, 1]) or the
/// capture as a whole: when no image has a highlight with confidence at least
/// [`CalibrationOptions::min_confidence`] (a matte sphere, noise, no highlights), the error
/// says why. Problems with single images are warnings, among them every light below that
/// confidence.
pub fn calibrate(
    images: &[Image],
    mask: Option<&[bool]>,
    mask_name: Option<&str>,
    options: &CalibrationOptions,
) -> Result<Calibration> {
    let (w, h) = check_images(images, options)?;
    let (sphere, source) = match mask {
        Some(m) => (
            fit_mask_circle(m, w, h, mask_name.unwrap_or("the sphere mask"))?,
            SphereSource::Mask,
        ),
        None => (detect_sphere(images)?.1, SphereSource::Detected),
    };
    let mut warnings = sphere_warnings(&sphere, source);
    if source == SphereSource::Mask {
        warnings.extend(mask_off_sphere(images, &sphere));
    }
    let circle = sphere.circle;
    let searches: Vec<HighlightSearch> = images
        .par_iter()
        .map(|img| find_highlight(img, &circle, &options.highlight))
        .collect();
    let mut lights = Vec::with_capacity(images.len());
    for (k, search) in searches.into_iter().enumerate() {
        let light = match search {
            HighlightSearch::Missing(reason) => {
                warnings.push(CalibrationWarning {
                    image: Some(k),
                    kind: WarningKind::Missing,
                    message: reason,
                });
                LightEstimate {
                    highlight: None,
                    normal: None,
                    direction: None,
                    confidence: 0.0,
                    confidence_parts: None,
                }
            }
            HighlightSearch::Found(hl) => light_from(k, hl, &circle, options, &mut warnings),
        };
        lights.push(light);
    }
    if !lights
        .iter()
        .any(|l| l.direction.is_some() && l.confidence >= options.min_confidence)
    {
        return Err(Error::invalid(refusal(&lights, &warnings, options)));
    }
    Ok(Calibration {
        width: w,
        height: h,
        sphere,
        sphere_source: source,
        lights,
        warnings,
    })
}

/// The images' common size; errors when there is none or `min_confidence` is outside [0, 1].
fn check_images(images: &[Image], options: &CalibrationOptions) -> Result<(usize, usize)> {
    let first = images
        .first()
        .ok_or_else(|| Error::invalid("no sphere image given"))?;
    if !(0.0..=1.0).contains(&options.min_confidence) {
        return Err(Error::parameter(
            "min_confidence",
            format!("{}: expected a value in [0, 1]", options.min_confidence),
        ));
    }
    let (w, h) = (first.width, first.height);
    for (k, img) in images.iter().enumerate() {
        if (img.width, img.height) != (w, h) {
            return Err(Error::invalid(format!(
                "sphere image {} is {}×{}, expected {}×{} like the first",
                k + 1,
                img.width,
                img.height,
                w,
                h
            )));
        }
    }
    Ok((w, h))
}

/// Warnings about the sphere as a whole: cut by the image border, or a detected outline
/// rough for its circle.
fn sphere_warnings(sphere: &CircleFit, source: SphereSource) -> Vec<CalibrationWarning> {
    let mut warnings = Vec::new();
    if sphere.touches_frame {
        warnings.push(CalibrationWarning {
            image: None,
            kind: WarningKind::SphereCut,
            message: format!(
                "the sphere touches the image border: its circle was fitted to {:.0}% of its outline",
                100.0 * sphere.coverage
            ),
        });
    }
    if source == SphereSource::Detected
        && sphere.rms_residual_px > (0.01 * sphere.circle.r).max(1.0)
    {
        warnings.push(CalibrationWarning {
            image: None,
            kind: WarningKind::RoughOutline,
            message: format!(
                "the detected outline is {:.2} px RMS from its circle (a side never lit, or \
                 clutter): pass a mask for an accurate centre and radius",
                sphere.rms_residual_px
            ),
        });
    }
    warnings
}

/// The warning when a given mask's circle is not the sphere the images show: the sphere is
/// detected in the images as without a mask ([`detect_sphere`]); when that succeeds with a
/// clean outline and its circle is displaced from the mask's by more than
/// [`MASK_DISPLACEMENT_SHARE`] of the radius (at least 2 px: the detection's own precision on
/// 8-bit images is a fraction of that), the mask is said to be off. A detection that fails
/// or is rough says nothing (a dark room around a mirror sphere gives no outline).
fn mask_off_sphere(images: &[Image], mask_fit: &CircleFit) -> Option<CalibrationWarning> {
    let (_, seen) = detect_sphere(images).ok()?;
    let (m, d) = (mask_fit.circle, seen.circle);
    if seen.rms_residual_px > (0.01 * d.r).max(1.0) {
        return None;
    }
    let displacement = (m.cx - d.cx).hypot(m.cy - d.cy) + (m.r - d.r).abs();
    if displacement <= (MASK_DISPLACEMENT_SHARE * d.r).max(2.0) {
        return None;
    }
    Some(CalibrationWarning {
        image: None,
        kind: WarningKind::MaskOffSphere,
        message: format!(
            "the mask's circle (centre ({:.1}, {:.1}), radius {:.1} px) is {displacement:.1} px \
             from the sphere seen in the images (centre ({:.1}, {:.1}), radius {:.1} px): every \
             light may be off by up to {:.0}°; check that the mask belongs to these images, or \
             leave it out to use the detected sphere",
            m.cx,
            m.cy,
            m.r,
            d.cx,
            d.cy,
            d.r,
            (2.0 * displacement / d.r).to_degrees()
        ),
    })
}

/// The share of the sphere's radius by which a mask's circle may differ from the sphere the
/// images show before [`WarningKind::MaskOffSphere`] is warned of: a centre δ off turns a
/// normal by up to δ / r and its mirror direction by twice that, so 2% is about 2.3° at most.
pub const MASK_DISPLACEMENT_SHARE: f64 = 0.02;

/// Image `k`'s light from its highlight `hl` on the sphere `circle`: the sphere's normal there
/// (a centroid just outside the disc, a rim highlight, is pulled onto the rim), the mirror
/// direction ([`reflect_view`]) and the confidence; the image's problems go to `warnings`.
fn light_from(
    k: usize,
    hl: Highlight,
    circle: &Circle,
    options: &CalibrationOptions,
    warnings: &mut Vec<CalibrationWarning>,
) -> LightEstimate {
    let (mut nx, mut ny) = ((hl.x - circle.cx) / circle.r, (circle.cy - hl.y) / circle.r);
    let rho = (nx * nx + ny * ny).sqrt();
    if rho > 1.0 {
        nx /= rho;
        ny /= rho;
    }
    let nz = (1.0 - nx * nx - ny * ny).max(0.0).sqrt();
    let normal = [nx, ny, nz];
    let direction = reflect_view(normal);
    let disc_area = std::f64::consts::PI * circle.r * circle.r;
    let mut warn = |kind: WarningKind, message: String| {
        warnings.push(CalibrationWarning {
            image: Some(k),
            kind,
            message,
        })
    };
    let (broad, faint) = highlight_warnings(&hl, rho, disc_area, options, &mut warn);
    let parts = ConfidenceParts {
        contrast: (((hl.peak - hl.background) / hl.peak.max(1e-6)) as f64).clamp(0.0, 1.0),
        compactness: hl.compactness.clamp(0.0, 1.0).sqrt(),
        saturation: 1.0 - 0.25 * hl.saturated as f64 / hl.pixels.max(1) as f64,
        rim: nz,
        uniqueness: (1.0 - hl.second_blob_share).clamp(0.0, 1.0),
        mirror: if broad || faint { 0.0 } else { 1.0 },
    };
    let confidence = parts.contrast
        * parts.compactness
        * parts.saturation
        * parts.rim
        * parts.uniqueness
        * parts.mirror;
    if confidence < options.min_confidence && !broad && !faint {
        warn(
            WarningKind::LowConfidence,
            low_confidence(confidence, &parts, options),
        );
    }
    LightEstimate {
        highlight: Some(hl),
        normal: Some(normal),
        direction: Some(direction),
        confidence,
        confidence_parts: Some(parts),
    }
}

/// The problems of one image's highlight, in order: doubled, clipped, near the rim (`rho` its
/// distance from the centre in radii), too broad for a mirror, too faint for the noise; each
/// given to `warn`. Returns (broad, faint): either sets the confidence to 0.
fn highlight_warnings(
    hl: &Highlight,
    rho: f64,
    disc_area: f64,
    options: &CalibrationOptions,
    warn: &mut impl FnMut(WarningKind, String),
) -> (bool, bool) {
    let limits = &options.highlight;
    if hl.second_blob_share >= limits.doubled_mass_share {
        let s = hl.second_blob.unwrap_or([f64::NAN; 2]);
        warn(
            WarningKind::Doubled,
            format!(
                "two highlights: a second bright blob at ({:.1}, {:.1}) carries {:.0}% of the \
                 first's weight (at ({:.1}, {:.1})); the first was used",
                s[0],
                s[1],
                100.0 * hl.second_blob_share,
                hl.x,
                hl.y
            ),
        );
    }
    if hl.saturated as f64 > limits.max_saturated_share * disc_area {
        warn(
            WarningKind::Clipped,
            format!(
                "clipped highlight: {} saturated pixels ({:.2}% of the sphere, at most {:.2}% \
                 expected); lower the exposure",
                hl.saturated,
                100.0 * hl.saturated as f64 / disc_area,
                100.0 * limits.max_saturated_share
            ),
        );
    }
    if rho > options.near_rim {
        warn(
            WarningKind::NearRim,
            format!(
                "the highlight is at {:.0}% of the radius from the centre: the direction is imprecise",
                100.0 * rho.min(1.0)
            ),
        );
    }
    let broad = hl.disc_share > limits.max_disc_share;
    if broad {
        warn(
            WarningKind::NotMirror,
            format!(
                "not a mirror sphere's highlight: the brightest region covers {:.1}% of the \
                 sphere's disc, a mirror's highlight of a small light at most {:.0}% (a matte \
                 sphere's shading, or a grossly overexposed highlight?); confidence 0",
                100.0 * hl.disc_share,
                100.0 * limits.max_disc_share
            ),
        );
    }
    let faint = hl.significance.is_nan() || hl.significance < limits.min_significance;
    if faint {
        warn(
            WarningKind::Faint,
            format!(
                "no highlight stands out of the noise: the brightest spot is {:.1}σ above the \
                 sphere's median (σ = {:.4}), at least {:.0}σ expected; confidence 0",
                hl.significance, hl.noise, limits.min_significance
            ),
        );
    }
    (broad, faint)
}

/// The warning of a light below the confidence threshold, naming its weak factors.
fn low_confidence(
    confidence: f64,
    parts: &ConfidenceParts,
    options: &CalibrationOptions,
) -> String {
    let factors = [
        ("contrast", parts.contrast),
        ("compactness", parts.compactness),
        ("saturation", parts.saturation),
        ("rim", parts.rim),
        ("uniqueness", parts.uniqueness),
    ];
    let weak: Vec<String> = factors
        .iter()
        .filter(|(_, v)| *v < 0.75)
        .map(|(n, v)| format!("{n} {v:.2}"))
        .collect();
    format!(
        "low confidence {confidence:.2} (below {:.2}){}: check this light's direction",
        options.min_confidence,
        if weak.is_empty() {
            String::new()
        } else {
            format!("; weak factors: {}", weak.join(", "))
        }
    )
}

/// Why no light of a capture is confident: the image counts and figures of each kind of
/// failure, for the error that refuses the capture.
fn refusal(
    lights: &[LightEstimate],
    warnings: &[CalibrationWarning],
    options: &CalibrationOptions,
) -> String {
    let n = lights.len();
    let of_kind = |kind: WarningKind| -> Vec<usize> {
        warnings
            .iter()
            .filter(|w| w.kind == kind)
            .filter_map(|w| w.image)
            .collect()
    };
    let range = |v: Vec<f64>, digits: usize| -> String {
        let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        if format!("{lo:.digits$}") == format!("{hi:.digits$}") {
            format!("{lo:.digits$}")
        } else {
            format!("{lo:.digits$}–{hi:.digits$}")
        }
    };
    let highlights = |images: &[usize]| -> Vec<Highlight> {
        images.iter().filter_map(|&k| lights[k].highlight).collect()
    };
    let mut why = Vec::new();
    let broad = of_kind(WarningKind::NotMirror);
    if !broad.is_empty() {
        why.push(format!(
            "in {} of {n} images the brightest region covers {}% of the \
             sphere's disc, where a mirror sphere's highlight of a small light covers at most {:.0}% (a matte sphere?)",
            broad.len(),
            range(
                highlights(&broad)
                    .iter()
                    .map(|h| 100.0 * h.disc_share)
                    .collect(),
                1
            ),
            100.0 * options.highlight.max_disc_share
        ));
    }
    let faint = of_kind(WarningKind::Faint);
    if !faint.is_empty() {
        why.push(format!(
            "in {} of {n} images the brightest spot stands only {}σ above the sphere's median, at \
             least {:.0}σ expected (noise?)",
            faint.len(),
            range(
                highlights(&faint).iter().map(|h| h.significance).collect(),
                1
            ),
            options.highlight.min_significance
        ));
    }
    let missing = of_kind(WarningKind::Missing);
    if let Some(first) = warnings.iter().find(|w| w.kind == WarningKind::Missing) {
        why.push(format!(
            "in {} of {n} images no highlight was found (image {}: {})",
            missing.len(),
            first.image.map_or(0, |k| k + 1),
            first.message
        ));
    }
    let low = of_kind(WarningKind::LowConfidence);
    if !low.is_empty() {
        why.push(format!(
            "in {} of {n} images the confidence is only {}",
            low.len(),
            range(low.iter().map(|&k| lights[k].confidence).collect(), 2)
        ));
    }
    format!(
        "no confident highlight: no sphere image has a highlight with confidence at least {:.2}, \
         so these are not the highlights of a mirror sphere under small lights; {}",
        options.min_confidence,
        why.join("; ")
    )
}

impl Calibration {
    /// The calibrated directions as [`Lights`] (unit intensities). An error names the images
    /// without a highlight.
    pub fn to_lights(&self) -> Result<Lights> {
        let missing: Vec<String> = self
            .lights
            .iter()
            .enumerate()
            .filter(|(_, l)| l.direction.is_none())
            .map(|(k, _)| (k + 1).to_string())
            .collect();
        if !missing.is_empty() {
            return Err(Error::invalid(format!(
                "no highlight found in sphere image(s) {} (1-based): their light directions are unknown",
                missing.join(", ")
            )));
        }
        let dirs: Vec<[f64; 3]> = self.lights.iter().filter_map(|l| l.direction).collect();
        Lights::new(&dirs)
    }

    /// Mean confidence over the images.
    pub fn mean_confidence(&self) -> f64 {
        self.lights.iter().map(|l| l.confidence).sum::<f64>() / self.lights.len().max(1) as f64
    }
}

/// Relative light intensities from a matte (Lambertian) sphere or grey ball seen in `images`
/// under the calibrated `directions`, its outline `circle`. For each image k and channel c the
/// brightness I = a_kc · (n·l_k) is fitted by least squares over the sphere's pixels within 95%
/// of its radius that are lit (n·l_k ≥ 0.2) and not saturated; each channel's a_kc are then
/// divided by their mean over the images (the sphere's own albedo cancels). Grey images give
/// equal R, G, B values.
pub fn matte_intensities(
    images: &[Image],
    circle: &Circle,
    directions: &[[f64; 3]],
) -> Result<Vec<[f64; 3]>> {
    if images.len() != directions.len() {
        return Err(Error::invalid(format!(
            "{} matte images for {} calibrated lights: expected one per light",
            images.len(),
            directions.len()
        )));
    }
    let first = images
        .first()
        .ok_or_else(|| Error::invalid("no matte image given"))?;
    let (w, h, c) = (first.width, first.height, first.channels);
    let r_in = 0.95 * circle.r;
    let mut pixels: Vec<(usize, [f64; 3])> = Vec::new();
    for row in 0..h {
        for col in 0..w {
            let (dx, dy) = (col as f64 - circle.cx, row as f64 - circle.cy);
            if dx * dx + dy * dy <= r_in * r_in {
                if let Some(n) = circle.normal_at(col as f64, row as f64) {
                    pixels.push((row * w + col, n));
                }
            }
        }
    }
    let gains: Vec<Result<[f64; 3]>> = images
        .par_iter()
        .zip(directions.par_iter())
        .enumerate()
        .map(|(k, (img, l))| {
            if (img.width, img.height, img.channels) != (w, h, c) {
                return Err(Error::invalid(format!(
                    "matte image {} is {}×{}×{}, expected {}×{}×{}",
                    k + 1,
                    img.width,
                    img.height,
                    img.channels,
                    w,
                    h,
                    c
                )));
            }
            let sat = highlight::saturation_level(img.bit_depth);
            let (mut num, mut den, mut used) = ([0f64; 3], 0f64, 0usize);
            for &(i, n) in &pixels {
                let s = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
                if s < 0.2 {
                    continue;
                }
                let px = &img.data[i * c..(i + 1) * c];
                if px.iter().any(|&v| v >= sat) {
                    continue;
                }
                for ch in 0..c {
                    num[ch] += s * px[ch] as f64;
                }
                den += s * s;
                used += 1;
            }
            if used < 20 || den <= 0.0 {
                return Err(Error::invalid(format!(
                    "matte image {}: only {used} lit, unsaturated sphere pixels; cannot fit its intensity",
                    k + 1
                )));
            }
            let mut g = [0f64; 3];
            for ch in 0..3 {
                g[ch] = num[ch.min(c - 1)] / den;
            }
            if g.iter().any(|v| v.is_nan() || *v <= 0.0) {
                return Err(Error::invalid(format!(
                    "matte image {}: the fitted intensity is not positive (is the sphere lit?)",
                    k + 1
                )));
            }
            Ok(g)
        })
        .collect();
    let gains: Vec<[f64; 3]> = gains.into_iter().collect::<Result<_>>()?;
    let n = gains.len() as f64;
    let mut mean = [0f64; 3];
    for g in &gains {
        for ch in 0..3 {
            mean[ch] += g[ch] / n;
        }
    }
    Ok(gains
        .iter()
        .map(|g| [g[0] / mean[0], g[1] / mean[1], g[2] / mean[2]])
        .collect())
}

/// The sphere's circle for a matte capture: fitted to its mask when given, else detected.
pub fn sphere_circle(images: &SphereImages) -> Result<(CircleFit, SphereSource)> {
    let first = images
        .images
        .first()
        .ok_or_else(|| Error::invalid("no image given"))?;
    match &images.mask {
        Some(m) => Ok((
            fit_mask_circle(
                m,
                first.width,
                first.height,
                images.mask_name.as_deref().unwrap_or("the mask"),
            )?,
            SphereSource::Mask,
        )),
        None => Ok((detect_sphere(&images.images)?.1, SphereSource::Detected)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reflection_of_the_view_about_the_half_vector_is_the_light() {
        let l = [0.3f64, -0.5, 0.81];
        let nl = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        let l = [l[0] / nl, l[1] / nl, l[2] / nl];
        let hv = [l[0], l[1], l[2] + 1.0];
        let nh = (hv[0] * hv[0] + hv[1] * hv[1] + hv[2] * hv[2]).sqrt();
        let got = reflect_view([hv[0] / nh, hv[1] / nh, hv[2] / nh]);
        for i in 0..3 {
            assert!((got[i] - l[i]).abs() < 1e-12);
        }
    }
}
