//! Built-in scenes with exact ground truth: height fields in pixel units (z toward the camera),
//! their analytic normals, and Lambertian renderings with attached and cast shadows.
//!
//! Cast shadows here come from a fine ray march against the height field, independent of any
//! horizon sweep an estimator may use, so that errors cannot cancel.

use crate::capture::Capture;
use crate::error::Result;
use crate::imageio::Image;
use crate::lights::Lights;
use rayon::prelude::*;

/// A height field with its exact normals and albedo.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub width: usize,
    pub height: usize,
    /// Height toward the camera per pixel, pixel units, row-major.
    pub depth: Vec<f32>,
    /// Unit normals, camera frame, row-major.
    pub normals: Vec<[f32; 3]>,
    /// Albedo per pixel (RGB).
    pub albedo: Vec<[f32; 3]>,
    /// Object pixels (only they cast shadows and are evaluated).
    pub mask: Vec<bool>,
}

/// A sphere of radius 0.3·size resting on a plane: the demo's first scene.
pub fn sphere_on_plane(size: usize) -> Scene {
    let r = 0.3 * size as f64;
    let c = (size as f64 - 1.0) / 2.0;
    let mut depth = vec![0f32; size * size];
    let mut normals = vec![[0f32, 0.0, 1.0]; size * size];
    for row in 0..size {
        for col in 0..size {
            let x = col as f64 - c;
            let y = c - row as f64;
            let rr = x * x + y * y;
            if rr < r * r {
                let z = (r * r - rr).sqrt();
                depth[row * size + col] = z as f32;
                normals[row * size + col] = [(x / r) as f32, (y / r) as f32, (z / r) as f32];
            }
        }
    }
    Scene {
        name: "sphere-on-plane".into(),
        width: size,
        height: size,
        depth,
        normals,
        albedo: vec![[0.75, 0.65, 0.55]; size * size],
        mask: vec![true; size * size],
    }
}

/// Bilinear height at fractional (row, col); `None` outside the frame or the mask.
fn height_at(scene: &Scene, row: f64, col: f64) -> Option<f64> {
    if row < 0.0 || col < 0.0 || row > (scene.height - 1) as f64 || col > (scene.width - 1) as f64 {
        return None;
    }
    let r0 = row.floor() as usize;
    let c0 = col.floor() as usize;
    let r1 = (r0 + 1).min(scene.height - 1);
    let c1 = (c0 + 1).min(scene.width - 1);
    let fr = row - r0 as f64;
    let fc = col - c0 as f64;
    let idx = |r: usize, c: usize| r * scene.width + c;
    if !(scene.mask[idx(r0, c0)]
        && scene.mask[idx(r0, c1)]
        && scene.mask[idx(r1, c0)]
        && scene.mask[idx(r1, c1)])
    {
        return None;
    }
    let h = |r: usize, c: usize| scene.depth[idx(r, c)] as f64;
    Some(
        h(r0, c0) * (1.0 - fr) * (1.0 - fc)
            + h(r0, c1) * (1.0 - fr) * fc
            + h(r1, c0) * fr * (1.0 - fc)
            + h(r1, c1) * fr * fc,
    )
}

/// Cast-shadow flags for one light by ray marching from every pixel toward the light in steps
/// of `step` pixels; a pixel is shadowed when the height field rises above the ray.
pub fn ray_march_shadows(scene: &Scene, light: [f64; 3], step: f64) -> Vec<bool> {
    let horiz = (light[0] * light[0] + light[1] * light[1]).sqrt();
    let mut out = vec![false; scene.width * scene.height];
    if horiz < 1e-9 {
        return out;
    }
    // Per unit of horizontal travel: columns grow with x, rows shrink with y.
    let (dc, dr, dz) = (light[0] / horiz, -light[1] / horiz, light[2] / horiz);
    let max_h = scene
        .depth
        .iter()
        .cloned()
        .fold(f32::NEG_INFINITY, f32::max) as f64;
    out.par_chunks_mut(scene.width)
        .enumerate()
        .for_each(|(row, out_row)| {
            for (col, o) in out_row.iter_mut().enumerate() {
                if !scene.mask[row * scene.width + col] {
                    continue;
                }
                let h0 = scene.depth[row * scene.width + col] as f64;
                let mut t = step;
                loop {
                    let z = h0 + 1e-4 + dz * t;
                    if z > max_h {
                        break;
                    }
                    match height_at(scene, row as f64 + dr * t, col as f64 + dc * t) {
                        Some(h) if h > z => {
                            *o = true;
                            break;
                        }
                        Some(_) => {}
                        None if row as f64 + dr * t < 0.0
                            || col as f64 + dc * t < 0.0
                            || row as f64 + dr * t > (scene.height - 1) as f64
                            || col as f64 + dc * t > (scene.width - 1) as f64 =>
                        {
                            break
                        }
                        None => {}
                    }
                    t += step;
                }
            }
        });
    out
}

/// Lambertian images of the scene under `lights` (RGB, float), with attached shadows (n·l ≤ 0)
/// and cast shadows (ray march). Returns the images and the per-light shadow flags.
pub fn render_lambert(scene: &Scene, lights: &Lights) -> (Vec<Image>, Vec<Vec<bool>>) {
    lights
        .directions
        .par_iter()
        .zip(&lights.intensities)
        .map(|(l, e)| {
            let cast = ray_march_shadows(scene, *l, 0.25);
            let mut data = vec![0f32; scene.width * scene.height * 3];
            let mut shadow = vec![false; scene.width * scene.height];
            for i in 0..scene.width * scene.height {
                let n = scene.normals[i];
                let s = l[0] * n[0] as f64 + l[1] * n[1] as f64 + l[2] * n[2] as f64;
                shadow[i] = s <= 0.0 || cast[i];
                if !shadow[i] {
                    for c in 0..3 {
                        data[i * 3 + c] = (scene.albedo[i][c] as f64 * s * e[c]) as f32;
                    }
                }
            }
            (
                Image {
                    width: scene.width,
                    height: scene.height,
                    channels: 3,
                    bit_depth: 32,
                    data,
                },
                shadow,
            )
        })
        .unzip()
}

/// Renders the scene and builds the capture (mask = the scene's mask).
pub fn lambert_capture(scene: &Scene, lights: &Lights) -> Result<(Capture, Vec<Vec<bool>>)> {
    let (images, shadows) = render_lambert(scene, lights);
    let capture = Capture::from_images(&images, lights.clone(), Some(scene.mask.clone()))?;
    Ok((capture, shadows))
}

/// `n` lights evenly spread in tilt at slant `slant_deg` (tilt 0 = +x, counter-clockwise).
pub fn ring_lights(n: usize, slant_deg: f64) -> Lights {
    let s = slant_deg.to_radians();
    let dirs: Vec<[f64; 3]> = (0..n)
        .map(|k| {
            let t = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
            [s.sin() * t.cos(), s.sin() * t.sin(), s.cos()]
        })
        .collect();
    Lights::new(&dirs).expect("ring directions are unit vectors")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_casts_shadow_of_length_h_tan_slant() {
        // A wall of height 10 px: columns < 20 at height 10, the rest at 0. A light from -x at
        // slant 45° casts a shadow of length 10 px on the ground to the right of the wall.
        let (w, h) = (64, 8);
        let mut depth = vec![0f32; w * h];
        for r in 0..h {
            for c in 0..20 {
                depth[r * w + c] = 10.0;
            }
        }
        let scene = Scene {
            name: "step".into(),
            width: w,
            height: h,
            depth,
            normals: vec![[0.0, 0.0, 1.0]; w * h],
            albedo: vec![[1.0; 3]; w * h],
            mask: vec![true; w * h],
        };
        let s = 45f64.to_radians();
        let shadow = ray_march_shadows(&scene, [-s.sin(), 0.0, s.cos()], 0.05);
        let len = (20..w).take_while(|&c| shadow[4 * w + c]).count() as f64;
        assert!((len - 10.0).abs() <= 1.0, "shadow length {len}");
    }
}
