//! `photostereo run`: reconstruct a capture.

use crate::common::{print_json, OutputOpts};
use anyhow::{bail, Result};
use clap::Args;
use photostereo::capture::CaptureFiles;
use photostereo::integrate::IntegratorKind;
use photostereo::pipeline::{run, LightSubset, Method, RunOptions};
use std::path::{Path, PathBuf};

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
    /// Estimation method: recursive, l2, coleman-jain, barsky-petrou.
    #[arg(long, default_value = "recursive", value_parser = parse_method)]
    pub method: Method,
    /// Ground-truth normals (.npy, DiLiGenT .mat, or 16-bit normal-map PNG) to score against.
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Also write error_map.png (angular error, colour-mapped, with a scale bar); needs --gt.
    #[arg(long)]
    pub error_map: bool,
    /// Upper end of the error map's scale, degrees.
    #[arg(long, default_value_t = 45.0)]
    pub error_map_max: f32,
    /// Image noise σ per channel (full scale = 1) for the non-Lambertian test; estimated when absent.
    #[arg(long)]
    pub sigma: Option<f64>,
    /// Relative model error κ: the noise at a pixel is √(σ² + (κ · its mean intensity)²).
    #[arg(long, default_value_t = photostereo::detect::DEFAULT_RELATIVE_NOISE)]
    pub relative_noise: f64,
    /// Confidence of the χ² test for non-Lambertian pixels.
    #[arg(long, default_value_t = 0.95)]
    pub confidence: f64,
    /// Use only some lights: `square` (the four closest to the paper's rig: slant 35°, tilts 90°
    /// apart), `square:SLANT`, or 1-based indices such as `1,5,9,13`.
    #[arg(long, value_parser = parse_subset)]
    pub light_subset: Option<LightSubset>,
    /// Skip the non-Lambertian detector and its maps (residual.npy, unreliable*.png, light_status.npy).
    #[arg(long)]
    pub no_detect: bool,
    /// Recursive method: iteration limit.
    #[arg(long, default_value_t = 5)]
    pub max_iterations: usize,
    /// Recursive method: stop when the usable-light sets change at fewer than this share of pixels.
    #[arg(long, default_value_t = 0.002)]
    pub change_tolerance: f64,
    /// Recursive method: integration weight of unreliable pixels (0 = fill them from neighbours).
    #[arg(long, default_value_t = 0.1)]
    pub unreliable_weight: f32,
    /// Recursive method: completion of pixels with fewer than three usable lights: `neighbours`
    /// (their albedo with the two usable lights, else the integrated surface's normal) or
    /// `brightest` (the paper's choice: add the brightest remaining lights).
    #[arg(long, default_value = "neighbours", value_parser = parse_fallback)]
    pub fallback: photostereo::recursive::Fallback,
    /// Skip integrating the normals (no depth.*, mesh.*, curl.npy).
    #[arg(long)]
    pub no_depth: bool,
    /// Integration method for depth: poisson (any mask), dct, fft (full rectangle), paths.
    #[arg(long, default_value = "poisson", value_parser = parse_integrator)]
    pub integrator: IntegratorKind,
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

fn parse_fallback(s: &str) -> Result<photostereo::recursive::Fallback, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
}

fn parse_method(s: &str) -> Result<Method, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
}

/// Resolves the input arguments into capture files.
pub fn capture_files(
    input: &[PathBuf],
    lights: Option<&Path>,
    intensities: Option<&Path>,
    mask: Option<&Path>,
) -> Result<CaptureFiles> {
    let mut files = if input.len() == 1 && input[0].is_dir() {
        let mut f = CaptureFiles::diligent_with_lights(&input[0], lights)?;
        if let Some(p) = intensities {
            f.lights = f.lights.read_intensities(p)?;
        }
        f
    } else if input.len() == 1
        && input[0]
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("txt"))
    {
        let Some(l) = lights else {
            bail!(
                "{}: a list file needs --lights FILE with the light directions",
                input[0].display()
            );
        };
        let mut f = CaptureFiles::list_file(&input[0], l)?;
        if let Some(p) = intensities {
            f.lights = f.lights.read_intensities(p)?;
        }
        f
    } else {
        let Some(l) = lights else {
            bail!("image files given explicitly need --lights FILE with one direction per image");
        };
        for p in input {
            if !p.is_file() {
                bail!("{}: no such image file", p.display());
            }
        }
        CaptureFiles::explicit(input.to_vec(), l, intensities, None)?
    };
    if let Some(m) = mask {
        files.mask = Some(m.to_path_buf());
    }
    Ok(files)
}

pub fn main(a: RunArgs) -> Result<()> {
    let files = capture_files(
        &a.input,
        a.lights.as_deref(),
        a.intensities.as_deref(),
        a.mask.as_deref(),
    )?;
    let options = RunOptions {
        method: a.method,
        ground_truth: a.gt.clone(),
        error_map: a.error_map,
        error_map_max_deg: a.error_map_max,
        detect: !a.no_detect,
        detection: photostereo::detect::DetectionParams {
            sigma: a.sigma,
            relative_noise: Some(a.relative_noise),
            confidence: a.confidence,
            ..Default::default()
        },
        light_subset: a.light_subset.clone(),
        integration: (!a.no_depth).then_some(a.integrator),
        recursive: photostereo::recursive::RecursiveParams {
            max_iterations: a.max_iterations,
            change_tolerance: a.change_tolerance,
            unreliable_weight: a.unreliable_weight,
            fallback: a.fallback,
            ..Default::default()
        },
    };
    let progress = a.out.progress();
    let rec = run(&files, &options, &a.output, a.out.force, &progress)?;
    let r = &rec.report;
    if a.out.json {
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
