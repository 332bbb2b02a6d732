//! `photostereo run`: reconstruct a capture.

use crate::common::{print_json, OutputOpts};
use anyhow::{bail, Result};
use clap::Args;
use photostereo::app::pipeline::{run, LightSubset, RunOptions, DEFAULT_ERROR_MAP_MAX_DEG};
use photostereo::geometry::integrate::{IntegrationParams, IntegratorKind};
use photostereo::io::layouts::CaptureFiles;
use photostereo::method::engine::{Method, Params};
use photostereo::method::recursive::{Fallback, RecursiveParams};
use photostereo::solve::detect::DetectionParams;
use std::path::{Path, PathBuf};

/// The library's defaults, the one source of the flags' defaults.
fn defaults() -> Params {
    Params::default()
}

#[derive(Args, Debug)]
pub struct RunArgs {
    /// A DiLiGenT-layout folder, a list file (with --lights), or image files (with --lights).
    #[arg(required = true)]
    pub input: Vec<PathBuf>,
    /// Light directions (N rows `x y z`, optionally preceded by a count line).
    #[arg(long)]
    pub lights: Option<PathBuf>,
    /// Per-light intensities (N rows `R G B` or one value each).
    #[arg(long)]
    pub intensities: Option<PathBuf>,
    /// Mask image (non-zero = object); overrides the layout's own mask.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// A folder with light_positions.txt (near lights) or K.txt (a camera with distant lights):
    /// the object's mean distance from the camera along the optical axis, mm; replaces
    /// mean_distance.txt.
    #[arg(long)]
    pub distance: Option<f64>,
    #[command(flatten)]
    pub photometry: crate::photometry::PhotometryArgs,
    /// Estimation method: recursive, l2, coleman-jain, barsky-petrou.
    #[arg(long, default_value = defaults().method.name(), value_parser = parse_method)]
    pub method: Method,
    /// Ground-truth normals (.npy, DiLiGenT .mat, or 16-bit normal-map PNG) to score against.
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Also write error_map.png (angular error, colour-mapped, with a scale bar); needs --gt.
    #[arg(long)]
    pub error_map: bool,
    /// Upper end of the error map's scale, degrees.
    #[arg(long, default_value_t = DEFAULT_ERROR_MAP_MAX_DEG)]
    pub error_map_max: f32,
    /// Image noise σ per channel (full scale = 1) for the non-Lambertian test; estimated when absent.
    #[arg(long)]
    pub sigma: Option<f64>,
    /// Relative model error κ: the noise at a pixel is √(σ² + (κ · its mean intensity)²); a
    /// share such as 0.01, or `measured`: the light-to-light part of the capture's misfit
    /// (report.json: detection.noise.kappa, and detection.kappa_measured in every run; 0.01
    /// where it cannot be measured: fewer than five lights, or near lights).
    #[arg(long, default_value = "measured", value_parser = parse_relative_noise)]
    pub relative_noise: RelativeNoise,
    /// Confidence of the χ² test for non-Lambertian pixels.
    #[arg(long, default_value_t = defaults().detection.confidence)]
    pub confidence: f64,
    /// Use only some lights: `square` (the four closest to the paper's rig: slant 35°, tilts 90°
    /// apart), `square:SLANT`, or 1-based indices such as `1,5,9,13`.
    #[arg(long, value_parser = parse_subset)]
    pub light_subset: Option<LightSubset>,
    /// Skip the non-Lambertian detector and its maps (residual.npy, unreliable*.png, light_status.npy).
    #[arg(long)]
    pub no_detect: bool,
    /// Recursive method: iteration limit.
    #[arg(long, default_value_t = defaults().recursive.max_iterations)]
    pub max_iterations: usize,
    /// Recursive method: stop when the usable-light sets change at fewer than this share of pixels.
    #[arg(long, default_value_t = defaults().recursive.change_tolerance)]
    pub change_tolerance: f64,
    /// Recursive method: angular standard deviation (degrees) of the integrated surface's
    /// normal as a prior on each pixel's normal in the final estimate (it steadies pixels
    /// with few usable lights and is released where the readings disagree with it); 0 = the
    /// usable lights' least squares alone.
    #[arg(long, default_value_t = defaults().recursive.surface_prior_deg, allow_negative_numbers = true)]
    pub surface_prior: f64,
    /// Refine the light directions and intensities from the readings before estimating (six
    /// or more distant lights): each light's vector by least squares over the pixels' fits,
    /// with the readings the detector keeps, its frame kept on the given lights; every method
    /// then uses the refined lights, and report.json's input.light_refinement says how far
    /// each moved.
    #[arg(long)]
    pub refine_lights: bool,
    /// Recursive method: radius of the spatial consensus of the usable lights (a pixel takes
    /// the majority of its (2r+1)² neighbourhood's removals where its readings pass the test
    /// with them); 0 = the paper's per-pixel decisions.
    #[arg(long, default_value_t = defaults().recursive.consensus_radius)]
    pub consensus_radius: usize,
    /// Integration weight of unreliable pixels relative to reliable ones (0 = fill them from
    /// their neighbours), for the recursive method's surfaces and the exported depth.
    #[arg(long, default_value_t = defaults().integration.unreliable_weight)]
    pub unreliable_weight: f32,
    /// Recursive method: completion of pixels with fewer than three usable lights: `neighbours`
    /// (their albedo with the two usable lights, else the integrated surface's normal) or
    /// `brightest` (the paper's choice: add the brightest remaining lights).
    #[arg(long, default_value = defaults().recursive.fallback.name(), value_parser = parse_fallback)]
    pub fallback: Fallback,
    /// Skip integrating the normals (no depth.*, mesh.*, curl.npy).
    #[arg(long)]
    pub no_depth: bool,
    /// Integration method for depth: bilateral (keeps depth jumps, any mask; writes
    /// discontinuities.npy/.png), poisson (any mask), dct, fft (full rectangle), paths.
    #[arg(long, default_value = defaults().integration.method.name(), value_parser = parse_integrator)]
    pub integrator: IntegratorKind,
    /// Cap on the depth gradient |∂z/∂x|, |∂z/∂y| (pixel units per pixel) when integrating.
    #[arg(long, default_value_t = defaults().integration.max_slope)]
    pub max_slope: f32,
    /// Memory budget (e.g. `4G`, `500M`; powers of 1024): captures whose samples do not fit
    /// as 32-bit floats are held in tiles at the images' precision, in memory or in a
    /// temporary spill file in the output's staging folder, with the same results. Default:
    /// half of the memory available. Too small for the capture's full-frame stages: refused
    /// with the smallest budget that works.
    #[arg(long, value_parser = crate::common::parse_memory_limit)]
    pub memory_limit: Option<u64>,
    /// Write mesh.obj at any size (by default it is skipped, with a note, above 10 million
    /// vertices; mesh.ply is always written).
    #[arg(long)]
    pub obj: bool,
    /// Also write the browser viewer (index.html and view/) into the output folder.
    #[arg(long)]
    pub view: bool,
    /// Output folder.
    #[arg(short, long, default_value = "photostereo-out")]
    pub output: PathBuf,
    #[command(flatten)]
    pub out: OutputOpts,
}

fn parse_subset(s: &str) -> Result<LightSubset, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
}

fn parse_integrator(s: &str) -> Result<IntegratorKind, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
}

fn parse_fallback(s: &str) -> Result<Fallback, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
}

fn parse_method(s: &str) -> Result<Method, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
}

/// The engine's parameters from the flags.
pub fn params(a: &RunArgs) -> Params {
    let d = defaults();
    Params {
        method: a.method,
        detection: DetectionParams {
            sigma: a.sigma,
            relative_noise: a.relative_noise.0,
            confidence: a.confidence,
            ..d.detection
        },
        recursive: RecursiveParams {
            max_iterations: a.max_iterations,
            change_tolerance: a.change_tolerance,
            surface_prior_deg: a.surface_prior,
            consensus_radius: a.consensus_radius,
            fallback: a.fallback,
            ..d.recursive
        },
        integration: IntegrationParams {
            method: a.integrator,
            max_slope: a.max_slope,
            unreliable_weight: a.unreliable_weight,
        },
        detect: !a.no_detect,
        integrate: !a.no_depth,
        memory_limit: a.memory_limit,
        refine_lights: a.refine_lights,
    }
}

/// Checks the options the library does not see (it checks its own parameters, and
/// [`crate::common::flag_error`] names them by their flags).
fn check_options(a: &RunArgs) -> Result<()> {
    if !(a.error_map_max > 0.0 && a.error_map_max <= 180.0) {
        bail!(
            "--error-map-max {}: expected an angle in (0, 180] degrees",
            a.error_map_max
        );
    }
    Ok(())
}

pub fn main(a: RunArgs) -> Result<()> {
    check_options(&a)?;
    crate::common::check_input_paths(
        &a.input,
        a.lights.as_deref(),
        a.intensities.as_deref(),
        a.mask.as_deref(),
    )?;
    let mut files = match (a.distance, a.input.as_slice()) {
        (Some(d), [dir]) if dir.is_dir() && photostereo::io::layouts::near::is_near_layout(dir) => {
            let mut f = photostereo::io::layouts::near::near_capture_files(dir, Some(d))?;
            if let Some(m) = &a.mask {
                f.mask = Some(m.clone());
            }
            f
        }
        (Some(d), [dir]) if dir.is_dir() => {
            // Distant lights with a camera (K.txt): --distance replaces mean_distance.txt.
            let mut f = CaptureFiles::diligent_with_lights(dir, a.lights.as_deref())?;
            if let Some(p) = &a.intensities {
                f = f.with_intensities_file(p)?;
            }
            if let Some(m) = &a.mask {
                f.mask = Some(m.clone());
            }
            photostereo::io::layouts::near::attach_camera(f, dir, Some(d))?
        }
        (Some(_), _) => anyhow::bail!(
            "--distance applies to one capture folder holding light_positions.txt or K.txt"
        ),
        (None, _) => CaptureFiles::from_inputs(
            &a.input,
            a.lights.as_deref(),
            a.intensities.as_deref(),
            a.mask.as_deref(),
        )?,
    };
    a.photometry.apply(&mut files)?;
    // --force never replaces an input or a folder holding one.
    let mut inputs: Vec<&Path> = a.input.iter().map(PathBuf::as_path).collect();
    inputs.extend(files.images.iter().map(PathBuf::as_path));
    inputs.extend(files.mask.as_deref());
    inputs.extend(files.photometry.ambient.as_deref());
    inputs.extend(a.lights.as_deref());
    inputs.extend(a.intensities.as_deref());
    inputs.extend(a.gt.as_deref());
    photostereo::io::export::check_output(
        &a.output,
        a.out.force,
        photostereo::io::export::OutputKind::Run,
        &inputs,
    )?;
    let options = RunOptions {
        params: params(&a),
        ground_truth: a.gt.clone(),
        error_map: a.error_map,
        error_map_max_deg: Some(a.error_map_max),
        light_subset: a.light_subset.clone(),
        obj_any_size: a.obj,
        // The command line owns its process: within a budget, freed maps go back at once.
        return_freed_memory_when_tiled: true,
    };
    let progress = a.out.progress();
    let rec = run(&files, &options, &a.output, a.out.force, &progress)
        .map_err(crate::common::flag_error)?;
    let r = &rec.report;
    if a.out.json {
        // The JSON on stdout holds every note; a recursion that did not settle and a missing
        // mask are also said on stderr.
        for n in r.notes.iter().filter(|n| {
            n.starts_with("recursive: not converged")
                || n.starts_with("no mask:")
                || n.starts_with("photometry:")
                || n.starts_with("response:")
        }) {
            eprintln!("note: {n}");
        }
        let mut v = serde_json::to_value(r)?;
        v["output"] = serde_json::Value::from(a.output.display().to_string());
        print_json(&v);
    } else if !a.out.quiet {
        for n in &r.notes {
            eprintln!("note: {n}");
        }
        println!(
            "{}: {} lights, {}×{}, {} mask pixels, method {}",
            a.input[0].display(),
            r.input.lights,
            r.input.width,
            r.input.height,
            r.input.mask_pixels,
            r.method
        );
        if let Some(e) = &r.error {
            println!(
                "angular error: mean {:.2}°, median {:.2}°, <5° {:.1}%, <10° {:.1}%, <20° {:.1}% ({} pixels)",
                e.mean_deg,
                e.median_deg,
                100.0 * e.under_5deg,
                100.0 * e.under_10deg,
                100.0 * e.under_20deg,
                e.pixels
            );
        }
        if let Some(s) = &rec.surface {
            println!(
                "depth: {} ({} iterations), mean |curl| {:.4}, {} bad normals masked out",
                s.depth.stats.method,
                s.depth.stats.iterations,
                s.mean_abs_curl,
                s.rejected_invalid + s.rejected_backfacing
            );
        }
        let total = r
            .timings_s
            .get("total")
            .and_then(|v| v.as_f64())
            .unwrap_or(0.0);
        println!("wrote {} in {:.2} s", a.output.display(), total);
    }
    if a.view {
        crate::view::after_run(&a.output, &files, a.gt.as_deref(), r, a.out.text())?;
    }
    Ok(())
}

/// `--relative-noise`: a share, or `measured` (None).
#[derive(Clone, Copy, Debug)]
pub struct RelativeNoise(pub Option<f64>);

pub fn parse_relative_noise(s: &str) -> std::result::Result<RelativeNoise, String> {
    if s == "measured" {
        return Ok(RelativeNoise(None));
    }
    s.parse::<f64>()
        .map(|v| RelativeNoise(Some(v)))
        .map_err(|_| format!("{s}: expected a share such as 0.01, or `measured`"))
}
