//! `photostereo rti`: fit a relightable image (PTM or hemispherical harmonics) to a capture and
//! write the file RTIViewer and OpenLIME read, with the fit's leave-one-out error.

use crate::common::{print_json, OutputOpts};
use anyhow::Result;
use clap::Args;
use photostereo::app::rti::{image_name, rti, RtiOptions};
use photostereo::solve::rti::Basis;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct RtiArgs {
    #[command(flatten)]
    pub capture: crate::common::CaptureInput,
    #[command(flatten)]
    pub photometry: crate::photometry::PhotometryArgs,
    /// The basis: ptm (PTM_FORMAT_LRGB: luminance polynomial and RGB chroma), ptm-rgb
    /// (PTM_FORMAT_RGB), hsh2 or hsh3 (hemispherical harmonics, 4 or 9 terms per channel,
    /// written as .rti), rbf (relight's radial basis: 18 principal-component coefficients per
    /// pixel, as many numbers as ptm-rgb, the components resampled by PTM's ridge quadratic plus Gaussians of its residuals
    /// at a grid of render positions; its model in basis.npy).
    #[arg(long, default_value = "hsh3", value_parser = parse_basis)]
    pub basis: Basis,
    /// Run the recursive method first and leave out of each pixel's fit the readings it found
    /// to be shadows or highlights, and those the camera clipped at full scale.
    #[arg(long)]
    pub exclude_unreliable: bool,
    /// The ridge weight per light, λ / N, of the ptm and hsh fits, (AᵀA + λ D) c = Aᵀ y with D
    /// the basis's roughness over the light hemisphere: auto (the weight with the least
    /// leave-one-out error on a sample of pixels, 0 included; for hsh also weights toward PTM's
    /// fit of the same readings instead of toward zero) or a number ≥ 0 toward zero (0: plain
    /// least squares). Not with rbf.
    #[arg(long, default_value = "auto", value_parser = parse_ridge)]
    pub ridge: RidgeArg,
    /// Also write relight's plane images as IIIF Image API 3.0 level-0 static tiles
    /// (relight/plane_G/info.json and the tiles), to be served at this base URI (e.g.
    /// https://example.org/iiif/object): each plane's service id is BASE/relight/plane_G.
    #[arg(long, value_name = "BASE_URI")]
    pub iiif: Option<String>,
    /// Memory budget (e.g. `4G`, `500M`; powers of 1024), as `run`'s: the fit writes its
    /// coefficients to coefficients.npy as it makes them, and what it holds beside the run's
    /// stages is part of the plan (report.json `memory`).
    #[arg(long, value_parser = crate::common::parse_memory_limit)]
    pub memory_limit: Option<u64>,
    /// Output folder: image.ptm, image.rti or basis.npy, coefficients.npy (chroma.npy for ptm),
    /// report.json.
    #[arg(short, long, default_value = "photostereo-rti")]
    pub output: PathBuf,
    #[command(flatten)]
    pub out: OutputOpts,
}

pub fn parse_basis(s: &str) -> Result<Basis, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
}

/// `--ridge`: `auto` (`None`) or a weight per light.
#[derive(Clone, Copy, Debug)]
pub struct RidgeArg(pub Option<f64>);

fn parse_ridge(s: &str) -> Result<RidgeArg, String> {
    if s == "auto" {
        return Ok(RidgeArg(None));
    }
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(RidgeArg(Some(v))),
        _ => Err(format!("'{s}': expected auto or a weight per light ≥ 0")),
    }
}

pub fn main(a: RtiArgs) -> Result<()> {
    let mut files = a.capture.files()?;
    a.photometry.apply(&mut files)?;
    // --force never replaces an input or a folder holding one.
    let mut inputs: Vec<&Path> = a.capture.given().collect();
    inputs.extend(files.images.iter().map(PathBuf::as_path));
    inputs.extend(files.mask.as_deref());
    inputs.extend(files.photometry.frames());
    photostereo::io::export::check_output(
        &a.output,
        a.out.force,
        photostereo::io::export::OutputKind::Rti,
        &inputs,
    )?;
    let options = RtiOptions {
        basis: a.basis,
        exclude_unreliable: a.exclude_unreliable,
        ridge: a.ridge.0,
        memory_limit: a.memory_limit,
        iiif: a.iiif.clone(),
    };
    let progress = a.out.progress();
    let mut report = rti(&files, &options, &a.output, a.out.force, &progress)?;
    if a.out.json {
        report["output"] = serde_json::Value::from(a.output.display().to_string());
        print_json(&report);
    } else if !a.out.quiet {
        let loo = &report["leave_one_out"];
        let lam = &report["lambertian_reference"]["errors"];
        println!(
            "{}: {} lights, {} mask pixels, basis {}",
            a.capture.input[0].display(),
            report["input"]["lights"],
            report["input"]["mask_pixels"],
            a.basis.name()
        );
        println!(
            "leave-one-out RMSE: {:.2} (8-bit), {:.2}% relative; Lambertian reference {:.2} (8-bit), {:.2}%",
            loo["mean_rmse_8bit"].as_f64().unwrap_or(f64::NAN),
            100.0 * loo["mean_relative"].as_f64().unwrap_or(f64::NAN),
            lam["mean_rmse_8bit"].as_f64().unwrap_or(f64::NAN),
            100.0 * lam["mean_relative"].as_f64().unwrap_or(f64::NAN),
        );
        println!("wrote {}", a.output.join(image_name(a.basis)).display());
    }
    Ok(())
}
