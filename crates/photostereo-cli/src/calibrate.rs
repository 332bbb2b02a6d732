//! `photostereo calibrate`: light directions from a mirror sphere (and relative intensities
//! from a matte sphere), written in the DiLiGenT layout.

use crate::common::{print_json, OutputOpts};
use anyhow::{Context, Result};
use clap::Args;
use photostereo::base::progress::Progress;
use photostereo::calibrate::{
    calibrate, matte_intensities, sphere_circle, Calibration, CalibrationOptions, HighlightOptions,
};
use photostereo::io::calibration_figure::calibration_figure;
use photostereo::io::export::{write_json, OutputFolder, OutputKind};
use photostereo::io::layouts::sphere::SphereFiles;
use photostereo::model::lights::Lights;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct CalibrateArgs {
    /// The mirror-sphere capture: a list file (image count, image paths, mask path), a folder of
    /// images (natural name order; a file named *mask* is the mask), or image paths.
    #[arg(required = true, value_name = "SPHERE_CAPTURE")]
    pub input: Vec<PathBuf>,
    /// The sphere's mask (non-zero = sphere); overrides the capture's own. Without any mask the
    /// sphere is detected from the brightest values of the images.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// A matte sphere (or grey ball) under the same lights, for relative light intensities: a
    /// list file, a folder, or image paths (`--matte a.png b.png …`, after SPHERE_CAPTURE).
    #[arg(long, value_name = "CAPTURE", num_args = 1..)]
    pub matte: Vec<PathBuf>,
    /// The matte sphere's mask; overrides the matte capture's own.
    #[arg(long)]
    pub matte_mask: Option<PathBuf>,
    /// Least brightness of a highlight above the sphere's median, in image units (0..1).
    #[arg(long, default_value_t = 0.1)]
    pub min_contrast: f32,
    /// Bright blobs with fewer pixels are ignored as dust or hot pixels.
    #[arg(long, default_value_t = 3)]
    pub min_blob_pixels: usize,
    /// Least confidence (0..1) of a light's highlight: each light below it is warned of, and a
    /// capture with no light reaching it (a matte sphere, noise) is refused. 0 accepts all.
    #[arg(long, default_value_t = 0.25)]
    pub min_confidence: f64,
    /// Output folder (light_directions.txt, light_intensities.txt with --matte,
    /// calibration.json, calibration.png).
    #[arg(short, long, default_value = "photostereo-calibration")]
    pub output: PathBuf,
    #[command(flatten)]
    pub out: OutputOpts,
}

pub fn main(a: CalibrateArgs) -> Result<()> {
    check_args(&a)?;
    let mut files = SphereFiles::resolve(&a.input)?;
    if let Some(m) = &a.mask {
        files.mask = Some(m.clone());
    }
    // --force never replaces an input or a folder holding one.
    let inputs: Vec<&std::path::Path> = a
        .input
        .iter()
        .chain(&files.images)
        .chain(&files.mask)
        .chain(&a.matte)
        .chain(&a.matte_mask)
        .map(PathBuf::as_path)
        .collect();
    let folder =
        OutputFolder::create_for(&a.output, a.out.force, OutputKind::Calibration, &inputs)?;
    let progress = a.out.progress();
    let loaded = files.load(&progress)?;
    let options = CalibrationOptions {
        highlight: HighlightOptions {
            min_contrast: a.min_contrast,
            min_blob_pixels: a.min_blob_pixels,
            ..HighlightOptions::default()
        },
        min_confidence: a.min_confidence,
        ..CalibrationOptions::default()
    };
    let cal = calibrate(
        &loaded.images,
        loaded.mask.as_deref(),
        loaded.mask_name.as_deref(),
        &options,
    )?;
    if !a.out.quiet {
        print_warnings(&files, &cal);
    }
    let lights = cal.to_lights()?;
    let rank_note = lights.check_rank().err().map(|e| e.to_string());
    if let (Some(n), false) = (&rank_note, a.out.quiet) {
        eprintln!("warning: {n}");
    }
    let (lights, matte_info) = if a.matte.is_empty() {
        (lights, None)
    } else {
        let (lights, info) = matte_intensities_of(&a, lights, &progress)?;
        (lights, Some(info))
    };
    photostereo::io::light_files::write_directions(&lights, &folder.file("light_directions.txt"))?;
    if matte_info.is_some() {
        photostereo::io::light_files::write_intensities(
            &lights,
            &folder.file("light_intensities.txt"),
        )?;
    }
    calibration_figure(&loaded.images, &cal).save(&folder.file("calibration.png"))?;
    let per_light: Vec<serde_json::Value> = cal
        .lights
        .iter()
        .enumerate()
        .map(|(k, l)| {
            serde_json::json!({
                "image": k + 1,
                "file": files.images[k].display().to_string(),
                "highlight": l.highlight,
                "normal": l.normal,
                "direction": l.direction,
                "intensity": matte_info.as_ref().map(|_| lights.intensities[k]),
                "confidence": l.confidence,
                "confidence_parts": l.confidence_parts,
            })
        })
        .collect();
    let summary = serde_json::json!({
        "sphere": cal.sphere,
        "sphere_source": cal.sphere_source,
        "image_size": [cal.width, cal.height],
        "mean_confidence": cal.mean_confidence(),
        "lights": per_light,
        "warnings": cal.warnings,
        "rank_warning": rank_note,
        "matte": matte_info,
        "options": options,
        "notes": files.notes,
    });
    write_json(&folder.file("calibration.json"), &summary)?;
    let target = folder.commit()?;
    if a.out.json {
        let mut v = summary;
        v["output"] = serde_json::Value::from(target.display().to_string());
        print_json(&v);
    } else if a.out.text() {
        print_table(&cal, &lights, matte_info.is_some(), &target);
    }
    Ok(())
}

/// The option values' domains, checked before any file is read.
fn check_args(a: &CalibrateArgs) -> Result<()> {
    if !(a.min_contrast > 0.0 && a.min_contrast < 1.0) {
        anyhow::bail!(
            "--min-contrast {}: expected a value in (0, 1)",
            a.min_contrast
        );
    }
    if !(0.0..=1.0).contains(&a.min_confidence) {
        anyhow::bail!(
            "--min-confidence {}: expected a value in [0, 1]",
            a.min_confidence
        );
    }
    if a.min_blob_pixels == 0 {
        anyhow::bail!("--min-blob-pixels 0: expected at least 1");
    }
    Ok(())
}

/// The layout's notes and the calibration's warnings on stderr, each image by number and file.
fn print_warnings(files: &SphereFiles, cal: &Calibration) {
    for n in &files.notes {
        eprintln!("note: {n}");
    }
    for w in &cal.warnings {
        match w.image {
            Some(k) => eprintln!(
                "warning: image {} ({}): {}",
                k + 1,
                files.images[k].display(),
                w.message
            ),
            None => eprintln!("warning: {}", w.message),
        }
    }
}

/// `--matte`: the lights with the relative intensities a matte sphere under them shows, and the
/// matte capture's entry of calibration.json (its images and fitted sphere).
fn matte_intensities_of(
    a: &CalibrateArgs,
    lights: Lights,
    progress: &dyn Progress,
) -> Result<(Lights, serde_json::Value)> {
    let mut mfiles = SphereFiles::resolve(&a.matte).context("--matte")?;
    if let Some(m) = &a.matte_mask {
        mfiles.mask = Some(m.clone());
    }
    let mloaded = mfiles.load(progress).context("--matte")?;
    let (fit, source) = sphere_circle(&mloaded).context("--matte")?;
    let intensities =
        matte_intensities(&mloaded.images, &fit.circle, &lights.directions).context("--matte")?;
    let lights = lights.with_intensities(intensities)?;
    let info = serde_json::json!({
        "images": mfiles.images.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "sphere": fit,
        "sphere_source": source,
    });
    Ok((lights, info))
}

/// The text summary: the sphere, one line per light found, and what was written where.
fn print_table(cal: &Calibration, lights: &Lights, matte: bool, target: &std::path::Path) {
    let c = cal.sphere.circle;
    println!(
        "sphere ({:?}): centre ({:.2}, {:.2}) px, radius {:.2} px, outline RMS {:.2} px",
        cal.sphere_source, c.cx, c.cy, c.r, cal.sphere.rms_residual_px
    );
    println!(
        "{:>3} {:>17} {:>28} {:>6}{}",
        "#",
        "highlight (x, y)",
        "direction (x, y, z)",
        "conf",
        if matte { "  intensity" } else { "" }
    );
    for (k, l) in cal.lights.iter().enumerate() {
        let (Some(h), Some(d)) = (l.highlight, l.direction) else {
            continue;
        };
        let intensity = if matte {
            format!("  {:.3}", lights.intensities[k].iter().sum::<f64>() / 3.0)
        } else {
            String::new()
        };
        println!(
            "{:>3} ({:>7.2}, {:>7.2}) ({:>8.5}, {:>8.5}, {:>8.5}) {:>6.2}{}",
            k + 1,
            h.x,
            h.y,
            d[0],
            d[1],
            d[2],
            l.confidence,
            intensity
        );
    }
    println!(
        "wrote {} (light_directions.txt{}, calibration.json, calibration.png)",
        target.display(),
        if matte { ", light_intensities.txt" } else { "" }
    );
}
