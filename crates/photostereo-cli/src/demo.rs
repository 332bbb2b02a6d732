//! `photostereo demo`: the six built-in scenes under the paper's four-light rig, every method,
//! a table of mean angular errors shaped like the paper's Table 1, and outputs plus one figure
//! per scene on disk.

use crate::common::{print_json, OutputOpts};
use anyhow::{bail, Context, Result};
use clap::Args;
use photostereo::app::pipeline::{write_reconstruction, RunOptions};
use photostereo::base::progress::Silent;
use photostereo::io::export::{write_json, OutputFolder, OutputKind};
use photostereo::io::figure::{heat_map, normals_picture, text_width, Canvas};
use photostereo::io::maps::{nice_ceil, tick_label};
use photostereo::io::synth::write_capture;
use photostereo::method::engine::{reconstruct_with_truth, Method, Params};
use photostereo::model::image::Image;
use photostereo::scene::{spec_scene, synthesize_scene, Brdf, Rig, Scene, SceneKind, SynthSpec};
use photostereo::solve::metrics::{evaluate, ErrorStats};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

/// The demo's fixed noise seed.
const DEMO_SEED: u64 = 2007;
/// The demo's noise σ, fraction of full scale.
const DEMO_NOISE: f64 = 0.005;
/// The error maps' colour scale fits each scene's results (the largest 95th percentile of the
/// methods' errors, rounded up); it never exceeds three times this, degrees.
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
        .map(|r| photostereo::io::light_files::parse_rig(r))
        .collect::<photostereo::Result<_>>()?;
    // The demo replaces its own folder without being asked.
    let ours = photostereo::io::export::marker_kind(&a.output) == Some(OutputKind::Demo);
    let folder = OutputFolder::create(&a.output, a.out.force || ours, OutputKind::Demo)?;
    let start = Instant::now();
    // Every (rig, scene) pair is independent (fixed seeds): all of them, and the near-light
    // line, run side by side; the results are gathered in the tables' order.
    for rig in &rigs {
        make_dirs(folder.path(), &folder.path().join(rig.name()))?;
    }
    let jobs: Vec<(&Rig, SceneKind)> = rigs
        .iter()
        .flat_map(|rig| SceneKind::ALL.iter().map(move |&kind| (rig, kind)))
        .collect();
    let root = folder.path();
    let (scenes, near) = rayon::join(
        || {
            // Each scene's surface is built once and rendered under every rig.
            let built = match rigs.first() {
                Some(rig) => SceneKind::ALL
                    .par_iter()
                    .map(|&kind| spec_scene(&demo_spec(kind, rig, a.size)))
                    .collect::<photostereo::Result<Vec<Scene>>>()?,
                None => Vec::new(),
            };
            jobs.par_iter()
                .map(|&(rig, kind)| {
                    let k = SceneKind::ALL.iter().position(|&x| x == kind).unwrap_or(0);
                    run_scene(rig, kind, &built[k], root, a.size)
                })
                .collect::<Result<Vec<_>>>()
        },
        || near_line(a.size),
    );
    let (scenes, near) = (scenes?, near?);
    let mut rows: Vec<Row> = Vec::new();
    let mut scene_stats = Vec::new();
    for (scene_rows, stats) in scenes {
        rows.extend(scene_rows);
        scene_stats.push(stats);
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
            "near_lights": {
                "scene": "face", "rig": "near-square",
                "l2_distant_deg": near.0, "l2_near_deg": near.1, "recursive_near_deg": near.2,
            },
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
        println!(
            "Near lights (face {}×{} at {:.0} mm under near-square, perspective camera): l2 with the distant approximation {:.2}°, l2 near {:.2}°, recursive near {:.2}°",
            a.size, a.size, near.3, near.0, near.1, near.2
        );
        println!("wrote {} in {:.2} s", target.display(), elapsed);
    }
    Ok(())
}

/// One near-light scene (face under the four-LED square at 300 mm): the mean angular error of
/// `l2` with the distant approximation, of `l2` and of `recursive` in the near model, and the
/// object's distance.
fn near_line(size: usize) -> Result<(f64, f64, f64, f64)> {
    use photostereo::scene::near::{synthesize_near, NearRig, NearSpec};
    let r = synthesize_near(&NearSpec {
        size,
        seed: DEMO_SEED,
        noise_sigma: DEMO_NOISE,
        ..NearSpec::new(SceneKind::Face, NearRig::Square)
    })?;
    let truth = &r.rendered.truth.normals;
    let err = |capture: &photostereo::Capture, method: Method| -> Result<f64> {
        let params = Params {
            method,
            ..Params::default()
        };
        let mut rec = reconstruct_with_truth(capture, &params, None, &Silent)?;
        Ok(rec.evaluate(truth)?.mean_deg)
    };
    Ok((
        err(&r.distant_capture()?, Method::L2)?,
        err(&r.capture()?, Method::L2)?,
        err(&r.capture()?, Method::Recursive)?,
        r.distance,
    ))
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

/// What one scene gives the tables: a row per method, and the capture's statistics.
type SceneResult = (
    Vec<Row>,
    (String, &'static str, photostereo::scene::CaptureStats),
);

/// The demo's rendering of scene `kind` under `rig` at `size` pixels.
fn demo_spec(kind: SceneKind, rig: &Rig, size: usize) -> SynthSpec {
    let mut spec = SynthSpec::new(kind, rig.clone());
    spec.size = size;
    spec.render.brdf = Brdf::BlinnPhong;
    spec.render.noise_sigma = DEMO_NOISE;
    spec.render.seed = DEMO_SEED;
    spec
}

/// Renders one scene (`scene`, built from `demo_spec(kind, …)`) under one rig, runs every
/// method, writes the capture, the outputs and the scene's figure under `root` (the rig's
/// folder must exist).
fn run_scene(
    rig: &Rig,
    kind: SceneKind,
    scene: &Scene,
    root: &std::path::Path,
    size: usize,
) -> Result<SceneResult> {
    let mut rows = Vec::new();
    {
        let spec = demo_spec(kind, rig, size);
        let rendered = synthesize_scene(&spec, scene)?;
        let scene_dir = root.join(rig.name()).join(kind.name());
        let capture_dir = scene_dir.join("capture");
        make_dirs(root, &capture_dir)?;
        write_capture(&capture_dir, &rendered, Some(&spec))?;
        let mut capture = rendered.capture()?;
        // Prepared as a run prepares a capture from files (default parameters: the lights as
        // given).
        photostereo::method::engine::prepare(&mut capture, &Params::default())?;
        let truth = &rendered.truth;
        let (w, h) = (truth.width, truth.height);
        let mut figure_rows: Vec<(String, Vec<Canvas>)> = Vec::new();
        let inputs: Vec<Canvas> = rendered.images.iter().map(rgb_picture).collect();
        let mut results = Vec::new();
        for &method in Method::ALL {
            let params = Params {
                method,
                ..Params::default()
            };
            let mut rec = reconstruct_with_truth(&capture, &params, Some(&truth.normals), &Silent)?;
            let (map, stats) = evaluate(&rec.normals, &truth.normals, Some(&truth.mask))?;
            rec.error_map = Some(map);
            rec.report.error = Some(stats.clone());
            results.push((method, rec, stats));
        }
        // One error scale per scene that fits its results: the largest 95th percentile of the
        // methods' errors, rounded up to a round number (errors above it clip to yellow).
        let p95: Vec<f32> = results
            .iter()
            .map(|(_, rec, _)| percentile95(rec.error_map.as_deref().unwrap_or(&[])))
            .collect();
        let scale =
            nice_ceil(p95.iter().copied().fold(1.0f32, f32::max)).min(ERROR_SCALE_DEG * 3.0);
        // A second, finer scale fitted to the best method, when the first would flatten it.
        let fine = nice_ceil(p95.iter().copied().fold(f32::INFINITY, f32::min).max(0.1));
        let fine = (fine * 3.0 <= scale).then_some(fine);
        let method_rows: Vec<(String, Vec<Canvas>)> = results
            .iter()
            .map(|(method, rec, stats)| {
                (format!("{}  mae {:.2}°", method.name(), stats.mean_deg), {
                    let errors = rec.error_map.as_deref().unwrap_or(&[]);
                    let mut panels = vec![
                        normals_picture(&rec.normals, w, h),
                        heat_map(errors, w, h, scale, "°"),
                    ];
                    if let Some(f) = fine {
                        panels.push(heat_map(errors, w, h, f, "°"));
                    }
                    panels
                })
            })
            .collect();
        let row_width = method_rows
            .iter()
            .map(|(_, p)| p.iter().map(|c| c.width + 4).sum::<usize>())
            .max()
            .unwrap_or(w);
        figure_rows.push((
            format!("truth / {} inputs", inputs.len()),
            vec![
                normals_picture(&truth.normals, w, h),
                thumbnails(&inputs, w, h, row_width.saturating_sub(w + 8)),
            ],
        ));
        figure_rows.extend(method_rows);
        for (method, rec, stats) in results {
            let options = RunOptions {
                params: Params {
                    method,
                    ..Params::default()
                },
                error_map: true,
                error_map_max_deg: Some(scale),
                ..RunOptions::default()
            };
            let dir = scene_dir.join(method.name());
            make_dirs(root, &dir)?;
            write_reconstruction(&rec, &dir, &options)?;
            write_json(&dir.join("report.json"), &rec.report)?;
            rows.push(Row {
                rig: rig.name(),
                scene: kind.name(),
                method: method.name(),
                stats,
            });
        }
        let title = match fine {
            Some(f) => format!(
                "{} {}: error 0-{}° and 0-{}°",
                rig.name(),
                kind.name(),
                tick_label(scale),
                tick_label(f)
            ),
            None => format!(
                "{} {}: error 0-{}°",
                rig.name(),
                kind.name(),
                tick_label(scale)
            ),
        };
        figure(&title, &figure_rows).save(&root.join(format!(
            "{}-{}.png",
            rig.name(),
            kind.name()
        )))?;
        Ok((rows, (rig.name(), kind.name(), rendered.stats.clone())))
    }
}

/// The 95th percentile of the finite values (0 when none).
fn percentile95(values: &[f32]) -> f32 {
    let mut v: Vec<f32> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    let k = ((v.len() - 1) as f64 * 0.95).round() as usize;
    *v.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
}

/// The inputs as numbered thumbnails in a grid at most `max_width` wide: each reduced by the
/// smallest integer factor (up to 4) that keeps the grid within 1.25 times a panel's height,
/// so the method rows below keep their full size whatever the number of lights.
fn thumbnails(inputs: &[Canvas], w: usize, h: usize, max_width: usize) -> Canvas {
    const GAP: usize = 3;
    const LABEL: usize = 9;
    let n = inputs.len().max(1);
    let layout = |f: usize| {
        let (tw, th) = (w.div_ceil(f), h.div_ceil(f));
        let cols = (max_width / (tw + GAP)).clamp(1, n);
        let rows = n.div_ceil(cols);
        (tw, th, cols, rows)
    };
    let factor = (1..=4)
        .find(|&f| {
            let (_, th, _, rows) = layout(f);
            rows * (th + LABEL + GAP) <= h * 5 / 4
        })
        .unwrap_or(4);
    let (tw, th, cols, rows) = layout(factor);
    let mut c = Canvas::new(cols * (tw + GAP), rows * (th + LABEL + GAP), [255; 3]);
    for (k, img) in inputs.iter().enumerate() {
        let (x0, y0) = ((k % cols) * (tw + GAP), (k / cols) * (th + LABEL + GAP));
        c.text(x0, y0, &(k + 1).to_string(), 1, [90, 90, 90]);
        for y in 0..th {
            for x in 0..tw {
                let (mut sum, mut cnt) = ([0u32; 3], 0u32);
                for yy in y * factor..((y + 1) * factor).min(img.height) {
                    for xx in x * factor..((x + 1) * factor).min(img.width) {
                        let i = (yy * img.width + xx) * 3;
                        for (acc, &v) in sum.iter_mut().zip(&img.data[i..i + 3]) {
                            *acc += v as u32;
                        }
                        cnt += 1;
                    }
                }
                c.put(x0 + x, y0 + LABEL + y, sum.map(|v| (v / cnt.max(1)) as u8));
            }
        }
    }
    c
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
                px.map(|v| photostereo::io::figure::round_u8(v.clamp(0.0, 1.0) * 255.0)),
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
