//! `photostereo integrate`: a normal map in, depth and meshes out.

use crate::common::{print_json, OutputOpts};
use anyhow::{bail, Context, Result};
use clap::Args;
use photostereo::geometry::integrate::{
    surface_from_normals, Bilateral, IntegratorKind, Poisson, Surface, DEFAULT_MAX_SLOPE,
    DEFAULT_TOLERANCE,
};
use photostereo::io::export::{write_json, OutputFolder, OutputKind};
use photostereo::io::groundtruth::{read_normal_map, NormalMap};
use photostereo::io::imageio::read_mask;
use photostereo::method::report::Report;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Args, Debug)]
pub struct IntegrateArgs {
    /// Normal map: .npy (H, W, 3), DiLiGenT .mat, 16-bit normal-map PNG, or float EXR/TIFF.
    pub normals: PathBuf,
    /// Mask image (non-zero = object). Default: the pixels with a non-zero normal, less a
    /// uniform background that is not of unit length (e.g. white, decoded (1, 1, 1)).
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Integration method: bilateral (keeps depth jumps, any mask; writes
    /// discontinuities.npy/.png), poisson (any mask), dct, fft (full rectangle), paths.
    #[arg(long, visible_alias = "integrator", default_value = IntegratorKind::default().name(), value_parser = parse_kind)]
    pub method: IntegratorKind,
    /// Cap on |∂f/∂col| and |∂f/∂row| (pixels per pixel) for near-grazing normals.
    #[arg(long, default_value_t = DEFAULT_MAX_SLOPE)]
    pub max_slope: f32,
    /// Relative residual at which poisson (bilateral: its last solve) stops.
    #[arg(long, default_value_t = DEFAULT_TOLERANCE)]
    pub tolerance: f64,
    /// Perspective integration (log-depth) through this pinhole camera (K.txt: fx 0 cx / 0 fy
    /// cy / 0 0 1): depth.npy then holds Z in mm along the optical axis; needs --distance.
    #[arg(long, requires = "distance")]
    pub camera: Option<PathBuf>,
    /// With --camera: the object's mean distance along the optical axis, mm (mean of Z).
    #[arg(long, requires = "camera")]
    pub distance: Option<f64>,
    /// Skip mesh.ply and mesh.obj (large for big maps).
    #[arg(long)]
    pub no_mesh: bool,
    /// Output folder.
    #[arg(short, long, default_value = "photostereo-depth")]
    pub output: PathBuf,
    #[command(flatten)]
    pub out: OutputOpts,
}

fn parse_kind(s: &str) -> Result<IntegratorKind, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
}

pub fn main(a: IntegrateArgs) -> Result<()> {
    check_args(&a)?;
    let inputs: Vec<&Path> = std::iter::once(a.normals.as_path())
        .chain(a.mask.as_deref())
        .chain(a.camera.as_deref())
        .collect();
    let folder =
        OutputFolder::create_for(&a.output, a.out.force, OutputKind::Integration, &inputs)?;
    let start = Instant::now();
    let mut report = Report::new(a.method.name());
    let t = Instant::now();
    let (map, mask) = read_inputs(&a)?;
    report.time("load", t);
    describe_inputs(&a, &map, &mut report);
    let t = Instant::now();
    let surface = integrate(&a, &map, mask.as_deref(), &mut report)?;
    report.time("integrate", t);
    let invalid = check_and_note(&a, &map, mask.is_none(), &surface, &mut report)?;
    let mut summary = surface.summary();
    summary["rejected_invalid_normals"] = invalid.into();
    summary["non_finite_normals"] = map.non_finite.into();
    report.extra.insert("integration".into(), summary);
    let t = Instant::now();
    let camera = match &a.camera {
        Some(k) => Some(photostereo::io::layouts::near::read_camera(k)?),
        None => None,
    };
    photostereo::io::surface::write_surface_camera(
        folder.path(),
        &surface,
        &map.normals,
        !a.no_mesh,
        camera.as_ref(),
    )
    .with_context(|| format!("writing {}", a.output.display()))?;
    report.time("write", t);
    report.time("total", start);
    write_json(&folder.file("report.json"), &report)?;
    folder.commit()?;
    print_summary(&a, &map, &surface, &report, invalid)
}

/// The options' ranges and the input files' existence.
fn check_args(a: &IntegrateArgs) -> Result<()> {
    if !(a.tolerance > 0.0 && a.tolerance < 1.0) {
        bail!("--tolerance {}: expected a number in (0, 1)", a.tolerance);
    }
    if !(a.max_slope > 0.0 && a.max_slope.is_finite()) {
        bail!(
            "--max-slope {}: expected a positive finite number (pixels per pixel)",
            a.max_slope
        );
    }
    for p in std::iter::once(&a.normals).chain(a.mask.as_ref()) {
        if !p.is_file() {
            bail!(
                "{}: {}",
                p.display(),
                if p.exists() {
                    "not a file"
                } else {
                    "no such file"
                }
            );
        }
    }
    Ok(())
}

/// The normal map and the mask (checked against the map's size).
fn read_inputs(a: &IntegrateArgs) -> Result<(NormalMap, Option<Vec<bool>>)> {
    let map = read_normal_map(&a.normals)?;
    let mask = match &a.mask {
        Some(path) => {
            let (h, w, m) = read_mask(path)?;
            if (w, h) != (map.width, map.height) {
                bail!(
                    "{}: mask is {w}×{h} but the normal map {} is {}×{}",
                    path.display(),
                    a.normals.display(),
                    map.width,
                    map.height
                );
            }
            Some(m)
        }
        None => None,
    };
    Ok((map, mask))
}

/// The inputs and parameters as `report.json` records them.
fn describe_inputs(a: &IntegrateArgs, map: &NormalMap, report: &mut Report) {
    report.param("normals", a.normals.display().to_string());
    if let Some(m) = &a.mask {
        report.param("mask", m.display().to_string());
    }
    report.param("integration", a.method.name());
    report.param("max_slope", a.max_slope);
    report.input.width = map.width;
    report.input.height = map.height;
    report.input.files = vec![a.normals.display().to_string()];
    report.input.mask_file = a.mask.as_ref().map(|m| m.display().to_string());
}

/// The surface by the chosen integrator, orthographic or through the camera.
fn integrate(
    a: &IntegrateArgs,
    map: &NormalMap,
    mask: Option<&[bool]>,
    report: &mut Report,
) -> Result<Surface> {
    let integrator: Box<dyn photostereo::geometry::integrate::Integrator> = match a.method {
        IntegratorKind::Poisson => {
            report.param("tolerance", a.tolerance);
            Box::new(Poisson {
                tolerance: a.tolerance,
                ..Poisson::default()
            })
        }
        IntegratorKind::Bilateral => {
            report.param("tolerance", a.tolerance);
            Box::new(Bilateral {
                final_tolerance: a.tolerance,
                ..Bilateral::default()
            })
        }
        other => other.integrator(),
    };
    let progress = a.out.progress();
    let surface = match (&a.camera, a.distance) {
        (Some(k), Some(d)) => {
            let camera = photostereo::io::layouts::near::read_camera(k)?;
            if !(d.is_finite() && d > 0.0) {
                bail!("--distance {d}: expected the object's mean distance in mm, positive");
            }
            report.param("camera", k.display().to_string());
            report.param("distance_mm", d);
            photostereo::geometry::integrate::perspective::perspective_surface(
                map.width,
                map.height,
                &map.normals,
                mask,
                None,
                &camera,
                d,
                integrator.as_ref(),
                a.max_slope,
                &progress,
            )?
        }
        _ => surface_from_normals(
            map.width,
            map.height,
            &map.normals,
            mask,
            None,
            integrator.as_ref(),
            a.max_slope,
            &progress,
        )?,
    };
    Ok(surface)
}

/// The pixels integrated (refused when none), and the notes on what was left out or capped;
/// returns the count of invalid normals.
fn check_and_note(
    a: &IntegrateArgs,
    map: &NormalMap,
    default_mask: bool,
    surface: &Surface,
    report: &mut Report,
) -> Result<usize> {
    report.input.mask_pixels = {
        use rayon::prelude::*;
        surface
            .depth
            .values
            .par_iter()
            .filter(|v| v.is_finite())
            .count()
    };
    // NaN/infinite vectors of the file were read as "no data": count them as invalid (with a
    // mask they already are, as zero vectors inside it).
    let invalid = surface.rejected_invalid + if default_mask { map.non_finite } else { 0 };
    if report.input.mask_pixels == 0 {
        bail!(
            "{}: no pixel with a valid normal to integrate ({} invalid — zero, NaN or infinite — and {} facing away from the camera{})",
            a.normals.display(),
            invalid,
            surface.rejected_backfacing,
            if a.mask.is_some() { ", inside the mask" } else { "" }
        );
    }
    if map.non_finite > 0 {
        report.notes.push(format!(
            "{} normal(s) with NaN or infinite components were dropped",
            map.non_finite
        ));
    }
    if surface.rejected_backfacing > 0 {
        report.notes.push(format!(
            "{} normal(s) facing away from the camera ({}) were dropped",
            surface.rejected_backfacing,
            if a.camera.is_some() {
                "n · ray ≥ 0 along their own ray"
            } else {
                "n_z ≤ 0"
            }
        ));
    }
    if surface.not_unit > 0 {
        report.notes.push(format!(
            "{} pixel(s) whose vector is not of unit length (a background colour such as white, decoded (1, 1, 1)) were left out of the default mask; pass --mask to choose the object's pixels",
            surface.not_unit
        ));
    }
    if surface.capped > 0 {
        report.notes.push(format!(
            "{} pixel(s) steeper than --max-slope {} (normals within {:.1}° of grazing) had their slopes capped: depth changes there are underestimated; a larger --max-slope keeps them",
            surface.capped,
            a.max_slope,
            (1.0 / a.max_slope as f64).atan().to_degrees()
        ));
    }
    Ok(invalid)
}

/// The summary on stdout (JSON with `--json`), the notes on stderr.
fn print_summary(
    a: &IntegrateArgs,
    map: &NormalMap,
    surface: &Surface,
    report: &Report,
    invalid: usize,
) -> Result<()> {
    let s = &surface.depth.stats;
    if a.out.json {
        let mut v = serde_json::to_value(report)?;
        v["output"] = serde_json::Value::from(a.output.display().to_string());
        print_json(&v);
    } else if !a.out.quiet {
        for n in s.notes.iter().chain(&report.notes) {
            eprintln!("note: {n}");
        }
        println!(
            "{}: {}×{}, {} pixels integrated ({} components), method {}, {} iterations",
            a.normals.display(),
            map.width,
            map.height,
            report.input.mask_pixels,
            s.components,
            s.method,
            s.iterations
        );
        println!(
            "mean |curl| {:.4} {}; masked out: {} invalid (zero, NaN or infinite), {} facing away{}; {} slopes capped at {}",
            surface.mean_abs_curl,
            if a.camera.is_some() {
                "(of f·ln Z, in pixels)"
            } else {
                "(pixels)"
            },
            invalid,
            surface.rejected_backfacing,
            if surface.not_unit > 0 {
                format!(", {} not of unit length", surface.not_unit)
            } else {
                String::new()
            },
            surface.capped,
            a.max_slope
        );
        if surface.depth.discontinuities.is_some() {
            println!(
                "{} pixels on a depth jump (discontinuities.png), {} reweightings",
                surface.discontinuity_pixels(),
                s.reweightings
            );
        }
        println!("wrote {}", a.output.display());
    }
    Ok(())
}
