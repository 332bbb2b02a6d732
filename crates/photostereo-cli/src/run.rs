//! `photostereo run`: reconstruct a capture.

use crate::common::{print_json, OutputOpts};
use crate::params::ParamArgs;
use anyhow::{bail, Result};
use clap::Args;
use photostereo::app::pipeline::{run, LightSubset, RunOptions, DEFAULT_ERROR_MAP_MAX_DEG};
use photostereo::io::layouts::CaptureFiles;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct RunArgs {
    #[command(flatten)]
    pub capture: crate::common::CaptureInput,
    /// A folder with light_positions.txt (near lights) or K.txt (a camera with distant lights):
    /// the object's mean distance from the camera along the optical axis, mm; replaces
    /// mean_distance.txt. For a relight .dome capture: the distance from the camera to the
    /// dome's origin (the imaged plane).
    #[arg(long)]
    pub distance: Option<f64>,
    /// The camera's intrinsics (K.txt: fx 0 cx / 0 fy cy / 0 0 1, pixels) in place of the
    /// capture folder's K.txt; with it a relight .dome's LED positions are near lights.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    #[command(flatten)]
    pub photometry: crate::photometry::PhotometryArgs,
    /// Ground-truth normals (.npy, DiLiGenT .mat, or 16-bit normal-map PNG) to score against.
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Also write error_map.png (angular error, colour-mapped, with a scale bar); needs --gt.
    #[arg(long)]
    pub error_map: bool,
    /// Upper end of the error map's scale, degrees.
    #[arg(long, default_value_t = DEFAULT_ERROR_MAP_MAX_DEG)]
    pub error_map_max: f32,
    /// Use only some lights: `square` (the four closest to the paper's rig: slant 35°, tilts 90°
    /// apart), `square:SLANT`, or 1-based indices such as `1,5,9,13`.
    #[arg(long, value_parser = parse_subset)]
    pub light_subset: Option<LightSubset>,
    /// The algorithm's parameters, one flag each (docs/parameters.md).
    #[command(flatten)]
    pub params: ParamArgs<crate::params::Run>,
    /// Write mesh.obj at any size (by default it is skipped, with a note, above 10 million
    /// vertices; mesh.ply is always written).
    #[arg(long)]
    pub obj: bool,
    /// Also write the browser viewer (index.html and view/) into the output folder.
    #[arg(long)]
    pub view: bool,
    /// Also fit a relightable image to the readings, as `rti --basis` does (ptm, ptm-rgb, hsh2,
    /// hsh3, rbf), and write its files beside the normals (image.ptm or image.rti or basis.npy,
    /// coefficients.npy, rti.json, relight/), its leave-one-out error in report.json's `rti`;
    /// the viewer shows it as its RTI layer.
    #[arg(long, value_parser = crate::rti::parse_basis)]
    pub rti: Option<photostereo::solve::rti::Basis>,
    /// Output folder.
    #[arg(short, long, default_value = "photostereo-out")]
    pub output: PathBuf,
    #[command(flatten)]
    pub out: OutputOpts,
}

fn parse_subset(s: &str) -> Result<LightSubset, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
}

/// Checks the options the library does not see (it checks its own parameters, and its errors
/// name them by their flags, [`crate::params::spell`]).
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
    let params = a.params.params()?;
    check_options(&a)?;
    a.capture.check()?;
    let camera = match &a.camera {
        Some(k) => Some(photostereo::io::layouts::near::read_camera(k)?),
        None => None,
    };
    let mut files = CaptureFiles::from_inputs_with(
        &a.capture.input,
        a.capture.lights.as_deref(),
        a.capture.intensities.as_deref(),
        a.capture.mask.as_deref(),
        a.distance,
        camera,
    )?;
    a.photometry.apply(&mut files)?;
    // --force never replaces an input or a folder holding one.
    let mut inputs: Vec<&Path> = a.capture.given().collect();
    inputs.extend(files.images.iter().map(PathBuf::as_path));
    inputs.extend(files.mask.as_deref());
    inputs.extend(files.photometry.frames());
    inputs.extend(a.gt.as_deref());
    inputs.extend(a.camera.as_deref());
    photostereo::io::export::check_output(
        &a.output,
        a.out.force,
        photostereo::io::export::OutputKind::Run,
        &inputs,
    )?;
    let options = RunOptions {
        params,
        ground_truth: a.gt.clone(),
        error_map: a.error_map,
        error_map_max_deg: Some(a.error_map_max),
        light_subset: a.light_subset.clone(),
        obj_any_size: a.obj,
        // The command line owns its process: within a budget, freed maps go back at once.
        return_freed_memory_when_tiled: true,
        rti: a.rti,
    };
    let progress = a.out.progress();
    let rec = run(&files, &options, &a.output, a.out.force, &progress)?;
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
            if n.starts_with("mesh.obj skipped") {
                eprintln!("note: --obj writes mesh.obj at any size");
            }
        }
        println!(
            "{}: {} lights, {}×{}, {} mask pixels, method {}",
            a.capture.input[0].display(),
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
        if let Some(rti) = r.extra.get("rti") {
            println!(
                "rti {}: leave-one-out RMSE {:.2} (8-bit); Lambertian reference {:.2}",
                rti["basis"].as_str().unwrap_or("?"),
                rti["leave_one_out"]["mean_rmse_8bit"]
                    .as_f64()
                    .unwrap_or(f64::NAN),
                rti["lambertian_reference"]["errors"]["mean_rmse_8bit"]
                    .as_f64()
                    .unwrap_or(f64::NAN),
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
