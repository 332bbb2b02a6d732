//! The run driver: load a capture, estimate normals and albedo, evaluate against ground truth,
//! and write the output folder. Algorithms stay free of I/O; this module is where files are
//! read and written, and where stages are timed for `report.json`.

use crate::capture::{Capture, CaptureFiles};
use crate::error::{Error, Result};
use crate::estimate::{Estimate, Estimator, LeastSquares};
use crate::export::{write_albedo, write_json, write_normals, OutputFolder};
use crate::figure::write_error_map;
use crate::groundtruth::{read_normal_map, NormalMap};
use crate::integrate::{surface_from_normals, IntegratorKind, Surface, DEFAULT_MAX_SLOPE};
use crate::metrics::{evaluate, ErrorStats};
use crate::progress::Progress;
use crate::report::{InputSummary, Report};
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Instant;

/// The estimation methods `run` offers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Least squares over all lights (Woodham).
    L2,
}

impl Method {
    /// Every method, in the order tables list them.
    pub const ALL: &'static [Method] = &[Method::L2];

    /// The name accepted by `--method`.
    pub fn name(self) -> &'static str {
        match self {
            Method::L2 => "l2",
        }
    }

    /// The estimator implementing the method.
    pub fn estimator(self) -> Box<dyn Estimator> {
        match self {
            Method::L2 => Box::new(LeastSquares),
        }
    }
}

impl FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Method::ALL
            .iter()
            .copied()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
                Error::invalid(format!(
                    "unknown method '{s}': expected one of {}",
                    names.join(", ")
                ))
            })
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
    /// Integrate the normals into depth and meshes with this method (`None`: skip).
    pub integration: Option<IntegratorKind>,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            method: Method::L2,
            ground_truth: None,
            error_map: false,
            error_map_max_deg: 45.0,
            integration: Some(IntegratorKind::default()),
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
    /// Depth, curl and integration figures, when integration ran.
    pub surface: Option<Surface>,
    pub report: Report,
}

/// Estimates normals and albedo of a loaded capture; fills the report's input and timings.
pub fn reconstruct(
    capture: &Capture,
    method: Method,
    progress: &dyn Progress,
    report: &mut Report,
) -> Result<Reconstruction> {
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
    let est: Estimate = method.estimator().estimate(capture, progress)?;
    report.time("estimate", t);
    Ok(Reconstruction {
        width: capture.width,
        height: capture.height,
        channels: capture.channels,
        normals: capture.scatter(&est.normals, 1, [0.0; 3]),
        albedo: capture.scatter(&est.albedo, capture.channels, 0.0),
        mask: capture.mask.clone(),
        error_map: None,
        surface: None,
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
    let capture = files.load(progress)?;
    report.time("load", t);
    let mut rec = reconstruct(&capture, options.method, progress, &mut report)?;
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
            None,
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
