//! `photostereo compare`: every method on one capture — the paper's Table 1 row (with ground
//! truth), its Table 2 row (mean intensity of the highlights each method found),
//! `compare.json` and one figure in the manner of its Figs. 7–12.

use crate::common::{print_json, OutputOpts};
use crate::params::ParamArgs;
use anyhow::{bail, Result};
use clap::Args;
use photostereo::app::compare::{compare, CompareOptions, FIGURE};
use photostereo::app::pipeline::LightSubset;
use photostereo::method::engine::Method;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct CompareArgs {
    #[command(flatten)]
    pub capture: crate::common::CaptureInput,
    #[command(flatten)]
    pub photometry: crate::photometry::PhotometryArgs,
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
    /// The algorithm's parameters, one flag each (docs/parameters.md).
    #[command(flatten)]
    pub params: ParamArgs<crate::params::Compare>,
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
    let params = a.params.params()?;
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
    let mut files = a.capture.files()?;
    a.photometry.apply(&mut files)?;
    let options = CompareOptions {
        params,
        methods,
        ground_truth: a.gt.clone(),
        light_subset: a.light_subset.clone(),
        figure_light: a.light.map(|k| k - 1),
        save_runs: a.save_runs,
        panel_size: a.panel_size,
    };
    let name = capture_name(&a.capture.input);
    let progress = a.out.progress();
    let c = compare(&files, &options, &a.output, a.out.force, &name, &progress)?;
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
