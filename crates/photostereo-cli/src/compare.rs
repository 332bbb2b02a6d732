//! `photostereo compare`: every method on one capture — the paper's Table 1 row (with ground
//! truth), its Table 2 row (mean intensity of the highlights each method found),
//! `compare.json` and one figure in the manner of its Figs. 7–12.

use crate::common::{print_json, OutputOpts};
use anyhow::{bail, Result};
use clap::Args;
use photostereo::app::compare::{compare, CompareOptions, FIGURE};
use photostereo::app::pipeline::LightSubset;
use photostereo::geometry::integrate::{IntegrationParams, IntegratorKind};
use photostereo::io::layouts::CaptureFiles;
use photostereo::method::engine::{Method, Params};
use photostereo::method::recursive::{Fallback, RecursiveParams};
use photostereo::solve::detect::DetectionParams;
use std::path::{Path, PathBuf};

fn defaults() -> Params {
    Params::default()
}

#[derive(Args, Debug)]
pub struct CompareArgs {
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
    /// Ground-truth normals (.npy, DiLiGenT .mat, or 16-bit normal-map PNG): adds the Table 1
    /// row (mean angular error) and error maps.
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// The methods to compare, comma-separated, in table order.
    #[arg(long, value_delimiter = ',', default_value = "l2,coleman-jain,barsky-petrou,recursive", value_parser = parse_method)]
    pub methods: Vec<Method>,
    /// The light (1-based) whose shadow maps the figure shows; default: the light farthest
    /// from the viewing direction.
    #[arg(long)]
    pub light: Option<usize>,
    /// Use only some lights: `square`, `square:SLANT`, or 1-based indices such as `1,5,9,13`.
    #[arg(long, value_parser = parse_subset)]
    pub light_subset: Option<LightSubset>,
    /// Also write each method's output folder, as `run` writes it, into `OUTPUT/<method>/`.
    #[arg(long)]
    pub save_runs: bool,
    /// Longest side of a panel of the figure, pixels (32 to 2048).
    #[arg(long, default_value_t = 360)]
    pub panel_size: usize,
    /// Image noise σ per channel (full scale = 1) for the non-Lambertian test; estimated when absent.
    #[arg(long)]
    pub sigma: Option<f64>,
    /// Relative model error κ: the noise at a pixel is √(σ² + (κ · its mean intensity)²); a
    /// share such as 0.01, or `measured` (as `run`).
    #[arg(long, default_value = "measured", value_parser = crate::run::parse_relative_noise)]
    pub relative_noise: crate::run::RelativeNoise,
    /// Confidence of the χ² test for non-Lambertian pixels.
    #[arg(long, default_value_t = defaults().detection.confidence)]
    pub confidence: f64,
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
    /// Integration weight of unreliable pixels relative to reliable ones.
    #[arg(long, default_value_t = defaults().integration.unreliable_weight)]
    pub unreliable_weight: f32,
    /// Recursive method: completion of pixels with fewer than three usable lights
    /// (`neighbours` or `brightest`).
    #[arg(long, default_value = defaults().recursive.fallback.name(), value_parser = parse_fallback)]
    pub fallback: Fallback,
    /// Integration method for depth: poisson, dct, fft, paths.
    #[arg(long, default_value = defaults().integration.method.name(), value_parser = parse_integrator)]
    pub integrator: IntegratorKind,
    /// Cap on the depth gradient (pixel units per pixel) when integrating.
    #[arg(long, default_value_t = defaults().integration.max_slope)]
    pub max_slope: f32,
    /// Output folder.
    #[arg(short, long, default_value = "photostereo-compare")]
    pub output: PathBuf,
    #[command(flatten)]
    pub out: OutputOpts,
}

fn parse_method(s: &str) -> Result<Method, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
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

/// The engine's parameters from the flags, as `run` builds them.
fn params(a: &CompareArgs) -> Params {
    let d = defaults();
    Params {
        method: d.method,
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
            fallback: a.fallback,
            ..d.recursive
        },
        integration: IntegrationParams {
            method: a.integrator,
            max_slope: a.max_slope,
            unreliable_weight: a.unreliable_weight,
        },
        detect: true,
        integrate: true,
        memory_limit: None,
        refine_lights: a.refine_lights,
    }
}

/// A short name for titles: the folder or list file's stem, else the first image's folder.
fn capture_name(input: &[PathBuf]) -> String {
    let p: &Path = if input.len() == 1 {
        &input[0]
    } else {
        input[0].parent().unwrap_or(&input[0])
    };
    let p = p.canonicalize().unwrap_or_else(|_| p.to_path_buf());
    p.file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "capture".into())
}

pub fn main(a: CompareArgs) -> Result<()> {
    if a.light == Some(0) {
        bail!("--light 0: lights are numbered from 1");
    }
    if !(32..=2048).contains(&a.panel_size) {
        bail!("--panel-size {}: expected 32 to 2048 pixels", a.panel_size);
    }
    let mut methods = Vec::new();
    for m in &a.methods {
        if !methods.contains(m) {
            methods.push(*m);
        }
    }
    crate::common::check_input_paths(
        &a.input,
        a.lights.as_deref(),
        a.intensities.as_deref(),
        a.mask.as_deref(),
    )?;
    let files = CaptureFiles::from_inputs(
        &a.input,
        a.lights.as_deref(),
        a.intensities.as_deref(),
        a.mask.as_deref(),
    )?;
    let options = CompareOptions {
        params: params(&a),
        methods,
        ground_truth: a.gt.clone(),
        light_subset: a.light_subset.clone(),
        figure_light: a.light.map(|k| k - 1),
        save_runs: a.save_runs,
        panel_size: a.panel_size,
    };
    let name = capture_name(&a.input);
    let progress = a.out.progress();
    let c = compare(&files, &options, &a.output, a.out.force, &name, &progress)
        .map_err(crate::common::flag_error)?;
    if a.out.json {
        let mut v = c.json.clone();
        v["output"] = serde_json::Value::from(a.output.display().to_string());
        print_json(&v);
        return Ok(());
    }
    if a.out.quiet {
        return Ok(());
    }
    let i = &c.input;
    println!(
        "{name}: {} lights, {}×{}, {}-bit, {} object pixels",
        i.lights, i.width, i.height, i.bit_depth, i.mask_pixels
    );
    let cell = |v: Option<f64>, digits: usize| match v {
        Some(x) => format!("{x:>17.digits$}"),
        None => format!("{:>17}", "—"),
    };
    print!("{:<40}", "");
    for r in &c.results {
        print!("{:>17}", r.method.name());
    }
    println!();
    if a.gt.is_some() {
        print!("{:<40}", "Table 1: mean angular error (deg)");
        for (_, v) in c.table1() {
            print!("{}", cell(v, 2));
        }
        println!();
    }
    print!("{:<40}", "Table 2: mean highlight intensity (0-255)");
    for (_, v) in c.table2() {
        print!("{}", cell(v, 1));
    }
    println!();
    print!("{:<40}", "  highlight pairs (% of object pairs)");
    for r in &c.results {
        let h = &r.indicators.highlights;
        print!(
            "{:>17}",
            format!("{} ({:.1}%)", h.pairs, 100.0 * h.share_of_pairs)
        );
    }
    println!();
    print!("{:<40}", "  mean shadow intensity (0-255)");
    for r in &c.results {
        print!(
            "{}",
            cell(
                r.indicators
                    .shadows
                    .mean_intensity_255
                    .as_ref()
                    .map(|m| m.grey),
                1
            )
        );
    }
    println!();
    print!("{:<40}", "  shadow pairs (% of object pairs)");
    for r in &c.results {
        let s = &r.indicators.shadows;
        print!(
            "{:>17}",
            format!("{} ({:.1}%)", s.pairs, 100.0 * s.share_of_pairs)
        );
    }
    println!();
    if let Some(m) = c
        .results
        .first()
        .and_then(|r| r.indicators.all_pairs.mean_intensity_255.as_ref())
    {
        println!(
            "mean intensity of all object pairs: {:.1}/255 (raw image values, grey)",
            m.grey
        );
    }
    println!(
        "wrote {} ({FIGURE}: shadows of light {})",
        a.output.join("compare.json").display(),
        c.figure_light + 1
    );
    Ok(())
}
