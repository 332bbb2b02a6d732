//! `photostereo eval`: score a normal map against ground truth.

use crate::common::print_json;
use anyhow::{bail, Result};
use clap::Args;
use photostereo::io::export::{OutputFile, OutputKind};
use photostereo::io::figure::write_error_map;
use photostereo::io::groundtruth::read_normal_map;
use photostereo::io::imageio::read_mask;
use photostereo::solve::metrics::evaluate;
use std::path::{Path, PathBuf};

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
    /// Replace an existing error-map file (only one photostereo wrote, never an input).
    #[arg(long)]
    pub force: bool,
}

pub fn main(a: EvalArgs) -> Result<()> {
    if !(a.error_map_max > 0.0 && a.error_map_max <= 180.0) {
        bail!(
            "--error-map-max {}: expected an angle in (0, 180] degrees",
            a.error_map_max
        );
    }
    for p in [&a.pred, &a.gt].into_iter().chain(a.mask.as_ref()) {
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
    let inputs: Vec<&Path> = [a.pred.as_path(), a.gt.as_path()]
        .into_iter()
        .chain(a.mask.as_deref())
        .collect();
    // Refuse a bad --error-map before any work; the file is written under a temporary name
    // and renamed into place at the end.
    let out = match &a.error_map {
        Some(p) => Some(OutputFile::create(
            p,
            a.force,
            OutputKind::ErrorMap,
            &inputs,
        )?),
        None => None,
    };
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
    if let (Some(out), Some(p)) = (out, &a.error_map) {
        write_error_map(out.path(), &map, pred.width, pred.height, a.error_map_max)
            .map_err(|e| anyhow::anyhow!("{}: writing the error map failed: {}", p.display(), e))?;
        out.commit()?;
    }
    let mut notes = Vec::new();
    for (path, m) in [(&a.pred, &pred), (&a.gt, &truth)] {
        if m.non_finite > 0 {
            notes.push(format!(
                "{}: {} vector(s) with NaN or infinite components, read as missing",
                path.display(),
                m.non_finite
            ));
        }
    }
    if a.json {
        let mut v = serde_json::to_value(&s)?;
        v["pred_non_finite"] = pred.non_finite.into();
        v["gt_non_finite"] = truth.non_finite.into();
        v["notes"] = notes.clone().into();
        print_json(&v);
    } else {
        for n in &notes {
            eprintln!("note: {n}");
        }
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
                "missing     {} (no prediction: zero, NaN or infinite vectors; counted as 90°)",
                s.missing
            );
        }
    }
    Ok(())
}
