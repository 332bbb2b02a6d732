//! The run driver: load a capture, estimate normals and albedo, evaluate against ground truth,
//! and write the output folder. Algorithms stay free of I/O; this module is where files are
//! read and written, and where stages are timed for `report.json`.

use crate::capture::{Capture, CaptureFiles};
use crate::detect::{detect, Detection, DetectionParams};
use crate::error::{Error, Result};
use crate::estimate::{status, BarskyPetrou, ColemanJain, Estimate, Estimator, LeastSquares};
use crate::export::{
    write_albedo, write_json, write_normals, write_npy_f32, write_npy_u8, OutputFolder,
};
use crate::figure::write_error_map;
use crate::groundtruth::{read_normal_map, NormalMap};
use crate::imageio::write_png8;
use crate::integrate::{surface_from_normals, IntegratorKind, Surface, DEFAULT_MAX_SLOPE};
use crate::metrics::{evaluate, ErrorStats};
use crate::progress::Progress;
use crate::recursive::{Recursive, RecursiveParams};
use crate::report::{InputSummary, Report};
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Arc;
use std::time::Instant;

/// The estimation methods `run` offers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Least squares over all lights (Woodham).
    L2,
    /// Coleman & Jain: highlights by albedo disagreement between light subsets.
    ColemanJain,
    /// Barsky & Petrou: the eq. 5 test and one faulty light dropped (iterated for N > 4).
    BarskyPetrou,
    /// Recursive photometric stereo (Argyriou & Petrou): shadows from the reconstructed surface,
    /// highlights from what the shadows do not explain, repeated.
    Recursive,
}

impl Method {
    /// Every method, in the order tables list them.
    pub const ALL: &'static [Method] = &[
        Method::L2,
        Method::ColemanJain,
        Method::BarskyPetrou,
        Method::Recursive,
    ];

    /// The name accepted by `--method`.
    pub fn name(self) -> &'static str {
        match self {
            Method::L2 => "l2",
            Method::ColemanJain => "coleman-jain",
            Method::BarskyPetrou => "barsky-petrou",
            Method::Recursive => "recursive",
        }
    }

    /// The estimator implementing the method, with the detector's parameters where it uses them.
    /// `truth` (full-frame normals) only feeds the recursive method's per-iteration figures.
    pub fn estimator(self, options: &RunOptions, truth: Option<&[[f32; 3]]>) -> Box<dyn Estimator> {
        let detection = &options.detection;
        match self {
            Method::Recursive => Box::new(Recursive {
                params: RecursiveParams {
                    detection: detection.clone(),
                    ..options.recursive.clone()
                },
                truth: truth.map(|t| Arc::new(t.to_vec())),
            }),
            Method::L2 => Box::new(LeastSquares),
            Method::ColemanJain => Box::new(ColemanJain {
                params: detection.clone(),
                ..ColemanJain::default()
            }),
            Method::BarskyPetrou => Box::new(BarskyPetrou {
                params: detection.clone(),
            }),
        }
    }
}

impl FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        crate::error::parse_name(s, Method::ALL, Method::name, "method")
    }
}

/// A subset of a capture's lights to use instead of all of them.
#[derive(Clone, Debug, PartialEq)]
pub enum LightSubset {
    /// These lights (0-based indices), in this order.
    Indices(Vec<usize>),
    /// The four lights closest to a square rig at this slant (degrees), tilts 90° apart.
    Square { slant_deg: f64 },
}

impl FromStr for LightSubset {
    type Err = Error;
    /// `square` (slant 35°, the paper's rig), `square:SLANT`, or 1-based indices `1,5,9,13`.
    fn from_str(s: &str) -> Result<Self> {
        if s == "square" {
            return Ok(LightSubset::Square { slant_deg: 35.0 });
        }
        if let Some(v) = s.strip_prefix("square:") {
            let slant: f64 = v.parse().map_err(|_| {
                Error::invalid(format!("light subset '{s}': slant '{v}' is not a number"))
            })?;
            if !(0.0..90.0).contains(&slant) {
                return Err(Error::invalid(format!(
                    "light subset '{s}': slant must be in [0, 90) degrees"
                )));
            }
            return Ok(LightSubset::Square { slant_deg: slant });
        }
        let idx: std::result::Result<Vec<usize>, _> =
            s.split(',').map(|t| t.trim().parse::<usize>()).collect();
        match idx {
            Ok(v) if !v.is_empty() && v.iter().all(|&i| i >= 1) => Ok(LightSubset::Indices(v.into_iter().map(|i| i - 1).collect())),
            _ => Err(Error::invalid(format!(
                "light subset '{s}': expected 'square', 'square:SLANT' or 1-based indices like 1,5,9,13"
            ))),
        }
    }
}

impl LightSubset {
    /// The 0-based indices this subset picks from `lights`.
    pub fn resolve(&self, lights: &crate::lights::Lights) -> Result<Vec<usize>> {
        match self {
            LightSubset::Indices(v) => Ok(v.clone()),
            LightSubset::Square { slant_deg } => {
                crate::lights::closest_square_rig(lights, *slant_deg)
                    .map(|a| a.to_vec())
                    .ok_or_else(|| {
                        Error::invalid("no four distinct lights form a square rig in this capture")
                    })
            }
        }
    }
}

/// What a run does besides estimating.
#[derive(Clone, Debug)]
pub struct RunOptions {
    pub method: Method,
    /// Ground-truth normal map to evaluate against.
    pub ground_truth: Option<PathBuf>,
    /// Write `error_map.png` (needs ground truth).
    pub error_map: bool,
    /// Upper end of the error map's colour scale, degrees.
    pub error_map_max_deg: f32,
    /// Run the non-Lambertian detector and write its maps (needs four lights or more).
    pub detect: bool,
    /// The detector's parameters (also used by the methods built on it).
    pub detection: DetectionParams,
    /// Use only these lights.
    pub light_subset: Option<LightSubset>,
    /// Integrate the normals into depth and meshes with this method (`None`: skip).
    pub integration: Option<IntegratorKind>,
    /// Parameters of the recursive method (its detector's come from `detection`).
    pub recursive: RecursiveParams,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            method: Method::L2,
            ground_truth: None,
            error_map: false,
            error_map_max_deg: 45.0,
            detect: true,
            detection: DetectionParams::default(),
            light_subset: None,
            integration: Some(IntegratorKind::default()),
            recursive: RecursiveParams::default(),
        }
    }
}

/// The result of a run, in memory.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    /// Unit normals, `height * width`, row-major, zero outside the mask.
    pub normals: Vec<[f32; 3]>,
    /// Albedo, `height * width * channels`, zero outside the mask.
    pub albedo: Vec<f32>,
    /// The mask used.
    pub mask: Vec<bool>,
    /// Per-pixel angular errors in degrees (NaN where not evaluated), with ground truth.
    pub error_map: Option<Vec<f32>>,
    /// Detector maps, full frame: ‖r‖/σ (0 outside), unreliable flags, per-light status
    /// (`n_lights * height * width`, 255 outside).
    pub detection: Option<DetectionMaps>,
    /// Depth, curl and integration figures, when integration ran.
    pub surface: Option<Surface>,
    /// Per-pixel integration weights (full frame): low where the estimate is unreliable.
    pub integration_weights: Option<Vec<f32>>,
    /// The recursive method's shadow, highlight and fewer-than-three maps.
    pub recursive: Option<Box<crate::recursive::RecursiveDiagnostics>>,
    pub report: Report,
}

/// The detector's maps scattered to the full frame.
#[derive(Clone, Debug)]
pub struct DetectionMaps {
    pub residual: Vec<f32>,
    pub unreliable: Vec<bool>,
    pub light_status: Vec<u8>,
    pub n_lights: usize,
}

impl DetectionMaps {
    fn new(capture: &Capture, light_status: &[u8], detection: Option<&Detection>) -> Self {
        let n = capture.n_lights();
        let hw = capture.width * capture.height;
        let mut status_full = vec![status::OUTSIDE; n * hw];
        for (p, &i) in capture.pixels.iter().enumerate() {
            for k in 0..n {
                status_full[k * hw + i as usize] = light_status[p * n + k];
            }
        }
        let (residual, unreliable) = match detection {
            Some(d) => (
                capture.scatter(&d.residual, 1, 0.0),
                capture.scatter(&d.unreliable, 1, false),
            ),
            None => (vec![0.0; hw], vec![false; hw]),
        };
        DetectionMaps {
            residual,
            unreliable,
            light_status: status_full,
            n_lights: n,
        }
    }
}

/// Estimates normals and albedo of a loaded capture (and the detector's maps when asked);
/// fills the report's input, parameters and timings.
pub fn reconstruct(
    capture: &Capture,
    options: &RunOptions,
    truth: Option<&[[f32; 3]]>,
    progress: &dyn Progress,
    report: &mut Report,
) -> Result<Reconstruction> {
    let method = options.method;
    report.method = method.name().into();
    report.input = InputSummary {
        width: capture.width,
        height: capture.height,
        channels: capture.channels,
        bit_depth: capture.bit_depth,
        lights: capture.n_lights(),
        mask_pixels: capture.n_pixels(),
        lights_renormalised: capture.lights.renormalised,
        light_condition_number: capture.lights.condition_number(),
    };
    report.notes.extend(capture.notes.iter().cloned());
    let t = Instant::now();
    if method == Method::Recursive {
        report.param(
            "recursive",
            serde_json::to_value(&options.recursive).unwrap_or_default(),
        );
    }
    let mut est: Estimate = method
        .estimator(options, truth)
        .estimate(capture, progress)?;
    report.time("estimate", t);
    let can_detect = capture.n_lights() >= 4;
    if options.detect && can_detect && est.detection.is_none() {
        let t = Instant::now();
        // The maps of the test only: the method used every light, which is what its
        // light_status says.
        let maps_only = DetectionParams {
            attribute: false,
            ..options.detection.clone()
        };
        est.detection = Some(detect(capture, &maps_only, progress)?);
        report.time("detect", t);
    }
    if options.detect && !can_detect {
        report
            .notes
            .push("detection skipped: it needs at least four lights".into());
    }
    if let Some(d) = &est.detection {
        report.extra.insert(
            "detection".into(),
            serde_json::json!({
                "noise": d.noise,
                "threshold_chi2": d.threshold,
                "confidence": d.params.confidence,
                "unreliable_share": d.unreliable_share(),
            }),
        );
    }
    // Integration weights: unreliable estimates count for little (ALGORITHMS.md §4).
    let low = options.recursive.unreliable_weight;
    let integration_weights = match (&est.recursive, &est.detection) {
        (Some(r), _) => Some(
            r.reliable
                .iter()
                .map(|&ok| if ok { 1.0 } else { low })
                .collect(),
        ),
        (None, Some(d)) if method != Method::BarskyPetrou => Some(
            capture.scatter(
                &d.unreliable
                    .iter()
                    .map(|&u| if u { low } else { 1.0 })
                    .collect::<Vec<f32>>(),
                1,
                0.0,
            ),
        ),
        _ => None,
    };
    if let Some(r) = &est.recursive {
        let few = r.fewer_than_three.iter().filter(|&&f| f).count();
        report.extra.insert(
            "recursive".into(),
            serde_json::json!({
                "iterations": r.iterations,
                "fewer_than_three_pixels": few,
                "fallback": r.fallback,
            }),
        );
        report
            .extra
            .insert("fewer_than_three_pixels".into(), few.into());
    }
    let detection = match (&est.light_status, &est.detection) {
        (Some(st), d) => Some(DetectionMaps::new(capture, st, d.as_ref())),
        (None, Some(d)) => Some(DetectionMaps::new(capture, &d.light_status, Some(d))),
        (None, None) => None,
    };
    Ok(Reconstruction {
        width: capture.width,
        height: capture.height,
        channels: capture.channels,
        normals: capture.scatter(&est.normals, 1, [0.0; 3]),
        albedo: capture.scatter(&est.albedo, capture.channels, 0.0),
        mask: capture.mask.clone(),
        error_map: None,
        detection,
        surface: None,
        integration_weights,
        recursive: est.recursive.take(),
        report: report.clone(),
    })
}

/// Evaluates a reconstruction against a ground-truth normal map of the same size.
pub fn evaluate_against(
    rec: &mut Reconstruction,
    truth: &NormalMap,
    truth_path: &Path,
) -> Result<ErrorStats> {
    if (truth.width, truth.height) != (rec.width, rec.height) {
        return Err(Error::file(
            truth_path,
            format!(
                "ground truth is {}×{} but the capture is {}×{}",
                truth.width, truth.height, rec.width, rec.height
            ),
        ));
    }
    let (map, stats) = evaluate(&rec.normals, &truth.normals, Some(&rec.mask))?;
    rec.error_map = Some(map);
    rec.report.error = Some(stats.clone());
    Ok(stats)
}

/// Writes a reconstruction's files into a (staging) folder.
pub fn write_reconstruction(rec: &Reconstruction, dir: &Path, options: &RunOptions) -> Result<()> {
    write_normals(dir, rec.width, rec.height, &rec.normals)?;
    write_albedo(
        dir,
        rec.width,
        rec.height,
        rec.channels,
        &rec.albedo,
        &rec.mask,
    )?;
    if let Some(d) = &rec.detection {
        let (w, h) = (rec.width, rec.height);
        write_npy_f32(&dir.join("residual.npy"), &[h, w], &d.residual)?;
        write_npy_u8(
            &dir.join("light_status.npy"),
            &[d.n_lights, h, w],
            &d.light_status,
        )?;
        // Fig. 6a: the statistic as grey (square root of ‖r‖/σ over its maximum); Fig. 6b: binary.
        let top = d
            .residual
            .iter()
            .zip(&rec.mask)
            .filter(|(_, &m)| m)
            .map(|(r, _)| *r)
            .fold(1e-6f32, f32::max);
        let grey: Vec<u8> = d
            .residual
            .iter()
            .map(|r| ((r / top).sqrt().clamp(0.0, 1.0) * 255.0) as u8)
            .collect();
        write_png8(&dir.join("unreliable.png"), w, h, 1, &grey)?;
        let binary: Vec<u8> = d
            .unreliable
            .iter()
            .map(|&u| if u { 255 } else { 0 })
            .collect();
        write_png8(&dir.join("unreliable_mask.png"), w, h, 1, &binary)?;
    }
    if let Some(r) = &rec.recursive {
        let (w, h) = (rec.width, rec.height);
        let maps: Vec<Vec<bool>> = (0..r.shadows.lights).map(|k| r.shadows.union(k)).collect();
        crate::shadows::shadow_montage(&maps, w, h).save(&dir.join("shadows.png"))?;
        let bytes = |m: &[bool]| {
            m.iter()
                .map(|&b| if b { 255u8 } else { 0 })
                .collect::<Vec<u8>>()
        };
        write_png8(&dir.join("highlight.png"), w, h, 1, &bytes(&r.highlight))?;
        write_png8(
            &dir.join("fewer_than_three.png"),
            w,
            h,
            1,
            &bytes(&r.fewer_than_three),
        )?;
    }
    if let Some(surface) = &rec.surface {
        crate::surface::write_surface(dir, surface, &rec.normals, true)?;
    }
    if options.error_map {
        if let Some(map) = &rec.error_map {
            write_error_map(
                &dir.join("error_map.png"),
                map,
                rec.width,
                rec.height,
                options.error_map_max_deg,
            )?;
        }
    }
    Ok(())
}

/// The whole `run`: load, estimate, evaluate, write `output` atomically.
pub fn run(
    files: &CaptureFiles,
    options: &RunOptions,
    output: &Path,
    force: bool,
    progress: &dyn Progress,
) -> Result<Reconstruction> {
    if options.error_map && options.ground_truth.is_none() {
        return Err(Error::invalid("--error-map needs ground truth (--gt FILE)"));
    }
    // Refuse an existing output before any work.
    let folder = OutputFolder::create(output, force)?;
    let mut report = Report::new(options.method.name());
    report.param("method", options.method.name());
    let start = Instant::now();
    // Read the ground truth first: a bad file fails fast, before decoding the capture.
    let truth = match &options.ground_truth {
        Some(p) => Some(read_normal_map(p)?),
        None => None,
    };
    let t = Instant::now();
    let mut capture = files.load(progress)?;
    if let Some(subset) = &options.light_subset {
        let keep = subset.resolve(&capture.lights)?;
        capture = capture.select_lights(&keep)?;
        report.param(
            "light_subset",
            keep.iter().map(|k| k + 1).collect::<Vec<_>>(),
        );
    }
    report.time("load", t);
    report.param("detect", options.detect);
    report.param(
        "detection",
        serde_json::to_value(&options.detection).unwrap_or_default(),
    );
    let truth_normals = match &truth {
        Some(t) if (t.width, t.height) == (capture.width, capture.height) => {
            Some(t.normals.as_slice())
        }
        _ => None,
    };
    let mut rec = reconstruct(&capture, options, truth_normals, progress, &mut report)?;
    rec.report
        .notes
        .extend(crate::plausibility::unestimated_note(
            &rec.normals,
            &rec.mask,
        ));
    drop(capture);
    if let (Some(truth), Some(path)) = (&truth, &options.ground_truth) {
        let t = Instant::now();
        evaluate_against(&mut rec, truth, path)?;
        rec.report.param("ground_truth", path.display().to_string());
        rec.report.time("evaluate", t);
    }
    if let Some(kind) = options.integration {
        let t = Instant::now();
        let surface = surface_from_normals(
            rec.width,
            rec.height,
            &rec.normals,
            Some(&rec.mask),
            rec.integration_weights.as_deref(),
            kind.integrator().as_ref(),
            DEFAULT_MAX_SLOPE,
            progress,
        )?;
        rec.report.param("integration", kind.name());
        rec.report
            .extra
            .insert("integration".into(), surface.summary());
        rec.surface = Some(surface);
        rec.report.time("integrate", t);
    }
    let t = Instant::now();
    write_reconstruction(&rec, folder.path(), options)?;
    rec.report.time("write", t);
    rec.report.time("total", start);
    write_json(&folder.file("report.json"), &rec.report)?;
    folder.commit()?;
    Ok(rec)
}
