//! A large output folder for the viewer, without running the engine: an analytic height field
//! (bumps on a dome inside an elliptical mask) with its normals, a textured albedo, depth, a
//! residual map and the statuses of 8 lights, written in the layout of `photostereo run`, then
//! the viewer written with `write_view`. Used to measure how the page copes with 8000 × 6000.
//!
//! cargo run --release --example viewer_large -- [WIDTH HEIGHT [FOLDER]]
//! (default 8000 6000 ./viewer-large), then open FOLDER/index.html.

use photostereo::io::export::{write_npy_f32, write_npy_u8};
use photostereo::io::viewer::{write_view, ViewOptions};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

/// Normal, albedo, depth, residual and the statuses of the 8 lights at one pixel.
type Pixel = ([f32; 3], [f32; 3], f32, f32, [u8; 8]);

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let w: usize = args.first().map_or(Ok(8000), |s| s.parse())?;
    let h: usize = args.get(1).map_or(Ok(6000), |s| s.parse())?;
    let dir = PathBuf::from(args.get(2).map_or("viewer-large", |s| s.as_str()));
    std::fs::create_dir_all(&dir)?;
    let t = Instant::now();
    let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
    let (ax, ay) = (w as f64 * 0.48, h as f64 * 0.48);
    let scale = w.min(h) as f64;
    // Height in pixels and its gradient (d/dcol, d/drow).
    let height = |c: f64, r: f64| -> Option<(f64, f64, f64)> {
        let (u, v) = ((c - cx) / ax, (r - cy) / ay);
        let q = u * u + v * v;
        if q >= 1.0 {
            return None;
        }
        let k = std::f64::consts::TAU * 12.0 / scale;
        let dome = 0.15 * scale * (1.0 - q);
        let bump = 0.004 * scale * ((k * c).sin() * (k * r * 1.3).cos());
        let f = dome + bump;
        let dfc =
            -0.15 * scale * 2.0 * u / ax + 0.004 * scale * k * (k * c).cos() * (k * r * 1.3).cos();
        let dfr = -0.15 * scale * 2.0 * v / ay
            - 0.004 * scale * k * 1.3 * (k * c).sin() * (k * r * 1.3).sin();
        Some((f, dfc, dfr))
    };
    let lights: Vec<[f64; 3]> = (0..8)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 8.0;
            let s = 45f64.to_radians();
            [a.cos() * s.sin(), a.sin() * s.sin(), s.cos()]
        })
        .collect();
    let px: Vec<Pixel> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (r, c) = ((i / w) as f64, (i % w) as f64);
            match height(c, r) {
                None => ([0.0; 3], [0.0; 3], f32::NAN, 0.0, [255; 8]),
                Some((f, dfc, dfr)) => {
                    // n ∝ (−∂f/∂x, −∂f/∂y, 1) with x = col, y = −row.
                    let (nx, ny) = (-dfc, dfr);
                    let l = (nx * nx + ny * ny + 1.0).sqrt();
                    let n = [nx / l, ny / l, 1.0 / l];
                    let t = (c / scale * 9.0).sin() * (r / scale * 7.0).cos();
                    let albedo = [0.55 + 0.25 * t, 0.45 + 0.1 * t, 0.35 - 0.15 * t];
                    let mut st = [0u8; 8];
                    for (k, d) in lights.iter().enumerate() {
                        let ndl = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
                        st[k] = if ndl < 0.05 {
                            1
                        } else if ndl > 0.995 {
                            2
                        } else {
                            0
                        };
                    }
                    let res = ((c * 0.013).sin() * (r * 0.011).cos()).abs() * 20.0;
                    (
                        n.map(|v| v as f32),
                        albedo.map(|v| v as f32),
                        f as f32,
                        res as f32,
                        st,
                    )
                }
            }
        })
        .collect();
    let normals: Vec<f32> = px.iter().flat_map(|p| p.0).collect();
    write_npy_f32(&dir.join("normals.npy"), &[h, w, 3], &normals)?;
    drop(normals);
    let albedo: Vec<f32> = px.iter().flat_map(|p| p.1).collect();
    write_npy_f32(&dir.join("albedo.npy"), &[h, w, 3], &albedo)?;
    drop(albedo);
    let depth: Vec<f32> = px.iter().map(|p| p.2).collect();
    write_npy_f32(&dir.join("depth.npy"), &[h, w], &depth)?;
    let residual: Vec<f32> = px.iter().map(|p| p.3).collect();
    write_npy_f32(&dir.join("residual.npy"), &[h, w], &residual)?;
    let status: Vec<u8> = (0..8)
        .flat_map(|k| px.iter().map(move |p| p.4[k]))
        .collect();
    write_npy_u8(&dir.join("light_status.npy"), &[8, h, w], &status)?;
    drop(px);
    println!(
        "wrote the maps of {w}×{h} in {:.1} s",
        t.elapsed().as_secs_f64()
    );
    let options = ViewOptions {
        lights: Some(lights),
        ..Default::default()
    };
    let s = write_view(&dir, &options)?;
    println!(
        "viewer: {} levels, {} files, {:.0} MB, {:.1} s",
        s.levels,
        s.files,
        s.bytes as f64 / 1e6,
        s.seconds
    );
    Ok(())
}
