//! `photostereo eval`: score a normal map against ground truth.

use crate::common::print_json;
use anyhow::{bail, Result};
use clap::Args;
use photostereo::figure::write_error_map;
use photostereo::groundtruth::read_normal_map;
use photostereo::imageio::read_mask;
use photostereo::metrics::evaluate;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Predicted normals (.npy, .mat, normal-map PNG/TIFF/EXR).
    pub pred: PathBuf,
    /// Ground-truth normals (same formats).
    pub gt: PathBuf,
    /// Evaluate only where this mask is non-zero (and the ground truth is non-zero).
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Print a JSON object on stdout.
    #[arg(long)]
    pub json: bool,
    /// Write a colour-mapped angular-error PNG with a scale bar to this file.
    #[arg(long)]
    pub error_map: Option<PathBuf>,
    /// Upper end of the error map's scale, degrees.
    #[arg(long, default_value_t = 45.0)]
    pub error_map_max: f32,
    /// Replace an existing error-map file.
    #[arg(long)]
    pub force: bool,
}

pub fn main(a: EvalArgs) -> Result<()> {
    if let Some(p) = &a.error_map {
        if p.exists() && !a.force {
            bail!(
                "{}: already exists (pass --force to replace it)",
                p.display()
            );
        }
    }
    let pred = read_normal_map(&a.pred)?;
    let truth = read_normal_map(&a.gt)?;
    if (pred.width, pred.height) != (truth.width, truth.height) {
        bail!(
            "{}: ground truth is {}×{} but {} is {}×{}",
            a.gt.display(),
            truth.width,
            truth.height,
            a.pred.display(),
            pred.width,
            pred.height
        );
    }
    let mask = match &a.mask {
        Some(p) => {
            let (h, w, m) = read_mask(p)?;
            if (w, h) != (pred.width, pred.height) {
                bail!(
                    "{}: mask is {}×{} but the normal maps are {}×{}",
                    p.display(),
                    w,
                    h,
                    pred.width,
                    pred.height
                );
            }
            Some(m)
        }
        None => None,
    };
    let (map, s) = evaluate(&pred.normals, &truth.normals, mask.as_deref())?;
    if let Some(p) = &a.error_map {
        let tmp = p.with_extension("png.tmp");
        write_error_map(&tmp, &map, pred.width, pred.height, a.error_map_max)?;
        std::fs::rename(&tmp, p)?;
    }
    if a.json {
        print_json(&serde_json::to_value(&s)?);
    } else {
        println!("pixels      {}", s.pixels);
        println!("mean        {:.3}°", s.mean_deg);
        println!("median      {:.3}°", s.median_deg);
        println!("under 5°    {:.2}%", 100.0 * s.under_5deg);
        println!("under 10°   {:.2}%", 100.0 * s.under_10deg);
        println!("under 20°   {:.2}%", 100.0 * s.under_20deg);
        println!(
            "eq. 14 mean {:.3}° (the paper's figure; not comparable)",
            s.mean_eq14_deg
        );
        if s.missing > 0 {
            println!(
                "missing     {} (zero predictions, counted as 90°)",
                s.missing
            );
        }
    }
    Ok(())
}
