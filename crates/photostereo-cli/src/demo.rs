//! `photostereo demo`: the six built-in scenes under the paper's four-light rig, every method,
//! a table of mean angular errors shaped like the paper's Table 1, and outputs plus one figure
//! per scene on disk.

use crate::common::{print_json, OutputOpts};
use anyhow::{bail, Context, Result};
use clap::Args;
use photostereo::export::{write_json, OutputFolder};
use photostereo::figure::{heat_map, normals_picture, text_width, Canvas};
use photostereo::imageio::Image;
use photostereo::metrics::{evaluate, ErrorStats};
use photostereo::pipeline::{reconstruct, write_reconstruction, Method, RunOptions};
use photostereo::progress::Silent;
use photostereo::report::Report;
use photostereo::scene::{synthesize, write_capture, Brdf, Rig, SceneKind, SynthSpec};
use std::path::PathBuf;
use std::time::Instant;

/// Marker file that identifies a folder written by `demo` (so re-running replaces it).
const MARKER: &str = ".photostereo-demo";
/// The demo's fixed noise seed.
const DEMO_SEED: u64 = 2007;
/// The demo's noise σ, fraction of full scale.
const DEMO_NOISE: f64 = 0.005;
/// Upper end of the error maps' colour scale, degrees.
const ERROR_SCALE_DEG: f32 = 30.0;

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(short, long, default_value = "photostereo-demo")]
    pub output: PathBuf,
    /// Scene size in pixels.
    #[arg(long, default_value_t = 128)]
    pub size: usize,
    /// Light rigs, each giving one table: the paper's `square4`, `ring8`, `dome-N`, `ring-N`.
    #[arg(long = "rig", default_values_t = ["square4".to_string(), "ring8".to_string(), "dome-20".to_string()])]
    pub rigs: Vec<String>,
    #[command(flatten)]
    pub out: OutputOpts,
}

struct Row {
    rig: String,
    scene: &'static str,
    method: &'static str,
    stats: ErrorStats,
}

pub fn main(a: DemoArgs) -> Result<()> {
    if a.size < 16 || a.size > 4096 {
        bail!("--size {}: expected 16..=4096 pixels", a.size);
    }
    let rigs: Vec<Rig> = a
        .rigs
        .iter()
        .map(|r| Rig::parse(r))
        .collect::<photostereo::Result<_>>()?;
    let ours = a.output.join(MARKER).exists();
    let folder = OutputFolder::create(&a.output, a.out.force || ours)?;
    std::fs::write(folder.file(MARKER), "written by photostereo demo\n")?;
    let start = Instant::now();
    let mut rows: Vec<Row> = Vec::new();
    let mut scene_stats = Vec::new();
    for rig in &rigs {
        run_rig(rig, folder.path(), a.size, &mut rows, &mut scene_stats)?;
    }
    let elapsed = start.elapsed().as_secs_f64();
    let target = folder.commit()?;
    if a.out.json {
        let v: Vec<_> = rows
            .iter()
            .map(|r| serde_json::json!({"scene": r.scene, "rig": r.rig, "method": r.method, "error": r.stats}))
            .collect();
        let s: Vec<_> = scene_stats
            .iter()
            .map(|(rig, name, st)| serde_json::json!({"scene": name, "rig": rig, "stats": st}))
            .collect();
        print_json(&serde_json::json!({
            "output": target.display().to_string(),
            "results": v,
            "scenes": s,
            "seconds": elapsed,
        }));
    } else if a.out.text() {
        for rig in &rigs {
            let name = rig.name();
            let n_lights = rig.lights().map(|l| l.len()).unwrap_or(0);
            println!(
                "Mean angular error (degrees), as the paper's Table 1: six scenes {}×{} under {} ({} lights), Blinn–Phong, noise σ {}%",
                a.size,
                a.size,
                name,
                n_lights,
                DEMO_NOISE * 100.0
            );
            let stats: Vec<_> = scene_stats.iter().filter(|(r, _, _)| *r == name).collect();
            print!("{:<14}", "method");
            for (_, scene, _) in &stats {
                print!(" {:>9}", scene);
            }
            println!(" {:>9}", "mean");
            for &method in Method::ALL {
                print!("{:<14}", method.name());
                let errs: Vec<f64> = rows
                    .iter()
                    .filter(|r| r.method == method.name() && r.rig == name)
                    .map(|r| r.stats.mean_deg)
                    .collect();
                for e in &errs {
                    print!(" {:>9.2}", e);
                }
                println!(
                    " {:>9.2}",
                    errs.iter().sum::<f64>() / errs.len().max(1) as f64
                );
            }
            for (label, pick) in [("shadowed %", 0usize), ("cast %", 1), ("highlight %", 2)] {
                print!("{:<14}", label);
                for (_, _, st) in &stats {
                    let v = match pick {
                        0 => st.shadow_fraction,
                        1 => st.cast_shadow_fraction,
                        _ => st.highlight_fraction,
                    };
                    print!(" {:>9.1}", 100.0 * v);
                }
                println!();
            }
            println!();
        }
        println!("wrote {} in {:.2} s", target.display(), elapsed);
    }
    Ok(())
}

/// Creates `dir` and its missing parents below `root`, which must exist: unlike
/// `create_dir_all`, a staging folder removed on an interrupt is never created again.
fn make_dirs(root: &std::path::Path, dir: &std::path::Path) -> Result<()> {
    let rel = dir.strip_prefix(root).unwrap_or(dir);
    let mut path = root.to_path_buf();
    for part in rel.components() {
        path.push(part);
        if !path.is_dir() {
            std::fs::create_dir(&path).with_context(|| path.display().to_string())?;
        }
    }
    Ok(())
}

/// Renders the six scenes under one rig, runs every method, writes captures, outputs and one
/// figure per scene under `root`.
fn run_rig(
    rig: &Rig,
    root: &std::path::Path,
    size: usize,
    rows: &mut Vec<Row>,
    scene_stats: &mut Vec<(String, &'static str, photostereo::scene::CaptureStats)>,
) -> Result<()> {
    for &kind in SceneKind::ALL {
        let mut spec = SynthSpec::new(kind, rig.clone());
        spec.size = size;
        spec.render.brdf = Brdf::BlinnPhong;
        spec.render.noise_sigma = DEMO_NOISE;
        spec.render.seed = DEMO_SEED;
        let rendered = synthesize(&spec)?;
        let scene_dir = root.join(rig.name()).join(kind.name());
        let capture_dir = scene_dir.join("capture");
        make_dirs(root, &capture_dir)?;
        write_capture(&capture_dir, &rendered, Some(&spec))?;
        let capture = rendered.capture()?;
        let truth = &rendered.truth;
        let (w, h) = (truth.width, truth.height);
        let mut figure_rows: Vec<(String, Vec<Canvas>)> = Vec::new();
        let mut inputs: Vec<Canvas> = rendered.images.iter().map(rgb_picture).collect();
        inputs.push(normals_picture(&truth.normals, w, h));
        figure_rows.push(("inputs / truth".into(), inputs));
        for &method in Method::ALL {
            let mut report = Report::new(method.name());
            let options = RunOptions {
                method,
                error_map: true,
                error_map_max_deg: ERROR_SCALE_DEG,
                ..RunOptions::default()
            };
            let mut rec = reconstruct(
                &capture,
                &options,
                Some(&truth.normals),
                &Silent,
                &mut report,
            )?;
            let (map, stats) = evaluate(&rec.normals, &truth.normals, Some(&truth.mask))?;
            rec.error_map = Some(map.clone());
            rec.report.error = Some(stats.clone());
            let dir = scene_dir.join(method.name());
            make_dirs(root, &dir)?;
            write_reconstruction(&rec, &dir, &options)?;
            write_json(&dir.join("report.json"), &rec.report)?;
            figure_rows.push((
                format!("{}  mae {:.2}", method.name(), stats.mean_deg),
                vec![
                    normals_picture(&rec.normals, w, h),
                    heat_map(&map, w, h, ERROR_SCALE_DEG, "°"),
                ],
            ));
            rows.push(Row {
                rig: rig.name(),
                scene: kind.name(),
                method: method.name(),
                stats,
            });
        }
        figure(&format!("{} {}", rig.name(), kind.name()), &figure_rows)
            .save(&root.join(format!("{}-{}.png", rig.name(), kind.name())))?;
        scene_stats.push((rig.name(), kind.name(), rendered.stats.clone()));
    }
    Ok(())
}

/// An RGB image (values in [0, 1]) as an 8-bit picture.
fn rgb_picture(img: &Image) -> Canvas {
    let mut c = Canvas::new(img.width, img.height, [0, 0, 0]);
    for row in 0..img.height {
        for col in 0..img.width {
            let px = if img.channels >= 3 {
                [
                    img.at(row, col, 0),
                    img.at(row, col, 1),
                    img.at(row, col, 2),
                ]
            } else {
                [img.at(row, col, 0); 3]
            };
            c.put(
                col,
                row,
                px.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8),
            );
        }
    }
    c
}

/// A figure: a title, then one labelled row of panels per entry, 4-pixel gaps.
fn figure(title: &str, rows: &[(String, Vec<Canvas>)]) -> Canvas {
    const GAP: usize = 4;
    const LABEL: usize = 12;
    let row_w = |panels: &[Canvas]| panels.iter().map(|p| p.width + GAP).sum::<usize>();
    let width = rows
        .iter()
        .map(|(label, p)| row_w(p).max(text_width(label, 1) + GAP))
        .max()
        .unwrap_or(1)
        .max(text_width(title, 2) + GAP)
        + GAP;
    let height = 2 * 7
        + 2 * GAP
        + rows
            .iter()
            .map(|(_, p)| LABEL + p.iter().map(|c| c.height).max().unwrap_or(0) + GAP)
            .sum::<usize>();
    let mut c = Canvas::new(width, height, [255, 255, 255]);
    c.text(GAP, GAP, title, 2, [0, 0, 0]);
    let mut y = 2 * 7 + 2 * GAP;
    for (label, panels) in rows {
        c.text(GAP, y + 2, label, 1, [0, 0, 0]);
        y += LABEL;
        let mut x = GAP;
        for p in panels {
            c.blit(p, x, y);
            x += p.width + GAP;
        }
        y += panels.iter().map(|p| p.height).max().unwrap_or(0) + GAP;
    }
    c
}
