//! A large grey capture in the DiLiGenT layout, for measuring `photostereo rti` and `run --rti`
//! against their memory plan: an analytic height field (bumps on a dome inside an elliptical
//! mask), a textured albedo, Lambertian diffuse plus a Blinn-Phong lobe, under N lights on
//! rings of a dome, written as 8-bit grey PNGs one light at a time (what is held: one image).
//!
//! cargo run --release --example rti_large -- [WIDTH HEIGHT LIGHTS [FOLDER]]
//! (default 8000 6000 48 ./rti-large), then `photostereo rti FOLDER -o OUT`.

use photostereo::io::imageio::write_png8;
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

/// Unit light directions (x right, y up, z toward the camera) on rings of 12 lights at
/// elevations from 20° to 75°, as many rings as `n` needs.
fn dome(n: usize) -> Vec<[f64; 3]> {
    let rings = n.div_ceil(12).max(1);
    (0..n)
        .map(|k| {
            let ring = k / 12;
            let e = (20.0 + 55.0 * ring as f64 / (rings - 1).max(1) as f64).to_radians();
            let a = (k % 12) as f64 * std::f64::consts::TAU / 12.0 + ring as f64 * 0.26;
            [a.cos() * e.cos(), a.sin() * e.cos(), e.sin()]
        })
        .collect()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let w: usize = args.first().map_or(Ok(8000), |s| s.parse())?;
    let h: usize = args.get(1).map_or(Ok(6000), |s| s.parse())?;
    let n: usize = args.get(2).map_or(Ok(48), |s| s.parse())?;
    let dir = PathBuf::from(args.get(3).map_or("rti-large", |s| s.as_str()));
    std::fs::create_dir_all(&dir)?;
    let t = Instant::now();
    let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
    let (ax, ay) = (w as f64 * 0.48, h as f64 * 0.48);
    let scale = w.min(h) as f64;
    let k = std::f64::consts::TAU * 12.0 / scale;
    // Normal (x right, y up) and albedo at a pixel of the mask; None outside.
    let surface = |c: f64, r: f64| -> Option<([f64; 3], f64)> {
        let (u, v) = ((c - cx) / ax, (r - cy) / ay);
        if u * u + v * v >= 1.0 {
            return None;
        }
        let dfc = -0.3 * scale * u / ax + 0.004 * scale * k * (k * c).cos() * (k * r * 1.3).cos();
        let dfr =
            -0.3 * scale * v / ay - 0.004 * scale * k * 1.3 * (k * c).sin() * (k * r * 1.3).sin();
        let (nx, ny) = (-dfc, dfr);
        let l = (nx * nx + ny * ny + 1.0).sqrt();
        let albedo = 0.55 + 0.25 * (c / scale * 9.0).sin() * (r / scale * 7.0).cos();
        Some(([nx / l, ny / l, 1.0 / l], albedo))
    };
    let lights = dome(n);
    let mut image = vec![0u8; w * h];
    let mut names = Vec::new();
    for (i, d) in lights.iter().enumerate() {
        let half = [d[0], d[1], d[2] + 1.0];
        let hl = (half[0] * half[0] + half[1] * half[1] + half[2] * half[2]).sqrt();
        image.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
            for (c, o) in row.iter_mut().enumerate() {
                *o = match surface(c as f64, r as f64) {
                    None => 0,
                    Some((nv, albedo)) => {
                        let ndl = nv[0] * d[0] + nv[1] * d[1] + nv[2] * d[2];
                        let ndh = (nv[0] * half[0] + nv[1] * half[1] + nv[2] * half[2]) / hl;
                        let v = if ndl <= 0.0 {
                            0.0
                        } else {
                            0.8 * albedo * ndl + 0.3 * ndh.max(0.0).powi(40)
                        };
                        (255.0 * v).round().clamp(0.0, 255.0) as u8
                    }
                };
            }
        });
        let name = format!("{:03}.png", i + 1);
        write_png8(&dir.join(&name), w, h, 1, &image)?;
        names.push(name);
        eprintln!("{}/{n} ({:.0} s)", i + 1, t.elapsed().as_secs_f64());
    }
    image.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
        for (c, o) in row.iter_mut().enumerate() {
            *o = if surface(c as f64, r as f64).is_some() {
                255
            } else {
                0
            };
        }
    });
    write_png8(&dir.join("mask.png"), w, h, 1, &image)?;
    std::fs::write(dir.join("filenames.txt"), names.join("\n") + "\n")?;
    let text = |f: &dyn Fn(&[f64; 3]) -> String| -> String {
        lights.iter().map(|d| f(d) + "\n").collect()
    };
    // DiLiGenT's frame: x right, y up, z toward the camera.
    std::fs::write(
        dir.join("light_directions.txt"),
        text(&|d| format!("{:.6} {:.6} {:.6}", d[0], d[1], d[2])),
    )?;
    std::fs::write(
        dir.join("light_intensities.txt"),
        text(&|_| "1 1 1".to_string()),
    )?;
    println!(
        "wrote {} ({w}×{h}, {n} lights) in {:.0} s",
        dir.display(),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
