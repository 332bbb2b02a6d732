//! Test fixtures shared by the unit tests of several modules: analytic Lambertian scenes.

use crate::model::capture::Capture;
use crate::model::image::Image;
use crate::model::lights::Lights;

/// A Lambertian sphere of radius `r` px centred in a `size`² frame, RGB albedo (0.8, 0.6, 0.4),
/// rendered without shadows: the mask keeps only pixels lit by every light.
pub(crate) fn lambert_sphere(size: usize, r: f64, dirs: &[[f64; 3]]) -> (Capture, Vec<[f64; 3]>) {
    let lights = Lights::new(dirs).unwrap();
    let c = (size as f64 - 1.0) / 2.0;
    let mut mask = vec![false; size * size];
    let mut truth = vec![[0.0; 3]; size * size];
    for row in 0..size {
        for col in 0..size {
            let x = (col as f64 - c) / r;
            let y = (c - row as f64) / r;
            let rr = x * x + y * y;
            if rr < 0.9 {
                let n = [x, y, (1.0 - rr).sqrt()];
                if lights
                    .directions
                    .iter()
                    .all(|l| l[0] * n[0] + l[1] * n[1] + l[2] * n[2] > 0.0)
                {
                    mask[row * size + col] = true;
                    truth[row * size + col] = n;
                }
            }
        }
    }
    let albedo = [0.8, 0.6, 0.4];
    let images: Vec<Image> = lights
        .directions
        .iter()
        .map(|l| {
            let mut data = vec![0f32; size * size * 3];
            for i in 0..size * size {
                let n = truth[i];
                let s = (l[0] * n[0] + l[1] * n[1] + l[2] * n[2]).max(0.0);
                for ch in 0..3 {
                    data[i * 3 + ch] = (albedo[ch] * s) as f32;
                }
            }
            Image {
                width: size,
                height: size,
                channels: 3,
                bit_depth: 32,
                data,
            }
        })
        .collect();
    let capture = Capture::from_images(&images, lights, Some(mask)).unwrap();
    let truth_masked = capture.pixels.iter().map(|&i| truth[i as usize]).collect();
    (capture, truth_masked)
}

pub(crate) fn ring(n: usize, slant_deg: f64) -> Vec<[f64; 3]> {
    let s = slant_deg.to_radians();
    (0..n)
        .map(|k| {
            let t = 2.0 * std::f64::consts::PI * k as f64 / n as f64 + 0.3;
            [s.sin() * t.cos(), s.sin() * t.sin(), s.cos()]
        })
        .collect()
}
