//! `photostereo demo`: built-in scenes, every method, a table of errors, figures on disk.

use crate::common::{print_json, OutputOpts};
use anyhow::{bail, Context, Result};
use clap::Args;
use photostereo::export::{write_json, OutputFolder};
use photostereo::figure::{grey_picture, heat_map, normals_picture, Canvas};
use photostereo::metrics::evaluate;
use photostereo::pipeline::{reconstruct, write_reconstruction, Method, RunOptions};
use photostereo::progress::Silent;
use photostereo::report::Report;
use photostereo::scene::{lambert_capture, ring_lights, sphere_on_plane};
use std::path::PathBuf;
use std::time::Instant;

/// Marker file that identifies a folder written by `demo` (so re-running replaces it).
const MARKER: &str = ".photostereo-demo";

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(short, long, default_value = "photostereo-demo")]
    pub output: PathBuf,
    /// Scene size in pixels.
    #[arg(long, default_value_t = 256)]
    pub size: usize,
    #[command(flatten)]
    pub out: OutputOpts,
}

pub fn main(a: DemoArgs) -> Result<()> {
    if a.size < 16 || a.size > 4096 {
        bail!("--size {}: expected 16..=4096 pixels", a.size);
    }
    let ours = a.output.join(MARKER).exists();
    let folder = OutputFolder::create(&a.output, a.out.force || ours)?;
    std::fs::write(folder.file(MARKER), "written by photostereo demo\n")?;
    let start = Instant::now();
    let scene = sphere_on_plane(a.size);
    let lights = ring_lights(8, 40.0);
    let (capture, _shadows) = lambert_capture(&scene, &lights)?;
    let mut rows = Vec::new();
    let mut panels = vec![
        grey_picture(&mean_image(&capture), scene.width, scene.height),
        normals_picture(&scene.normals, scene.width, scene.height),
    ];
    for &method in Method::ALL {
        let mut report = Report::new(method.name());
        let options = RunOptions {
            method,
            error_map: true,
            ..RunOptions::default()
        };
        let mut rec = reconstruct(
            &capture,
            &options,
            Some(&scene.normals),
            &Silent,
            &mut report,
        )?;
        let (map, stats) = evaluate(&rec.normals, &scene.normals, Some(&scene.mask))?;
        rec.error_map = Some(map.clone());
        rec.report.error = Some(stats.clone());
        let dir = folder.path().join(&scene.name).join(method.name());
        std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
        let options = RunOptions {
            method,
            error_map: true,
            ..RunOptions::default()
        };
        write_reconstruction(&rec, &dir, &options)?;
        write_json(&dir.join("report.json"), &rec.report)?;
        panels.push(normals_picture(&rec.normals, scene.width, scene.height));
        panels.push(heat_map(&map, scene.width, scene.height, 30.0, "°"));
        rows.push((scene.name.clone(), method.name(), stats));
    }
    montage(&panels).save(&folder.path().join(format!("{}.png", scene.name)))?;
    let elapsed = start.elapsed().as_secs_f64();
    let target = folder.commit()?;
    if a.out.json {
        let v: Vec<_> = rows
            .iter()
            .map(|(s, m, e)| serde_json::json!({"scene": s, "method": m, "error": e}))
            .collect();
        print_json(
            &serde_json::json!({"output": target.display().to_string(), "results": v, "seconds": elapsed}),
        );
    } else if a.out.text() {
        println!("Lambertian sphere on a plane, {}×{}, 8 lights at slant 40° (mean angular error, degrees)", a.size, a.size);
        println!("{:<18} {:>8} {:>8}", "scene", "method", "MAE");
        for (s, m, e) in &rows {
            println!("{:<18} {:>8} {:>8.2}", s, m, e.mean_deg);
        }
        println!("wrote {} in {:.2} s", target.display(), elapsed);
    }
    Ok(())
}

/// Mean over lights and channels of a capture's images, for display (scaled to its maximum).
fn mean_image(capture: &photostereo::Capture) -> Vec<f32> {
    let n = capture.n_lights() * capture.channels;
    let per: Vec<f32> = (0..capture.n_pixels())
        .map(|p| capture.pixel_samples(p).iter().sum::<f32>() / n as f32)
        .collect();
    let max = per.iter().cloned().fold(1e-6, f32::max);
    let scaled: Vec<f32> = per.iter().map(|v| v / max).collect();
    capture.scatter(&scaled, 1, 0.0)
}

/// Places pictures side by side with a 4-pixel gap.
fn montage(panels: &[Canvas]) -> Canvas {
    let w: usize = panels.iter().map(|p| p.width + 4).sum();
    let h = panels.iter().map(|p| p.height).max().unwrap_or(1);
    let mut c = Canvas::new(w, h, [255, 255, 255]);
    let mut x = 0;
    for p in panels {
        c.blit(p, x, 0);
        x += p.width + 4;
    }
    c
}
