//! Ground-truth scenes: height fields in pixel units (z toward the camera) with analytic
//! normals, rendered under distant lights with Lambertian, Blinn–Phong or Torrance–Sparrow
//! reflectance, attached and cast shadows, sensor noise, clipping at white and 16-bit
//! quantisation; with per-light ground-truth shadow and highlight masks.
//!
//! - [`surfaces`]: the built-in surfaces ([`SceneKind`]) and masks ([`MaskShape`]).
//! - [`rigs`]: light rigs ([`Rig`]: `square4`, `ring8`, `dome-N`, light files).
//! - [`reflectance`]: the reflectance models ([`Brdf`]).
//! - [`shadows`]: cast shadows by a fine ray march against the height field, independent of any
//!   horizon sweep an estimator may use, so that errors cannot cancel.
//! - [`render`](mod@render): rendering to images and ground truth in memory ([`synthesize`], [`render()`]), or
//!   one light at a time ([`render::LightByLight`]); [`crate::io::synth`] writes them as folders.
//!
//! Frame (CONVENTIONS.md): x right, y up (opposite to the row index), z toward the camera; a
//! height field f has ∂f/∂col = −n_x/n_z and ∂f/∂row = +n_y/n_z. Light directions point from
//! the surface toward the light.

pub mod near;
pub mod reflectance;
pub mod render;
pub mod rigs;
pub mod shadows;
pub mod surfaces;

pub use reflectance::Brdf;
pub use render::{
    render, spec_scene, synthesize, synthesize_scene, CaptureStats, GroundTruth, LightIntensities,
    RenderOptions, Rendered, SynthSpec,
};
pub use rigs::Rig;
pub use shadows::{cast_shadows, ray_march_shadows};
pub use surfaces::{MaskShape, SceneKind};

use crate::base::error::{Error, Result};
use crate::model::capture::Capture;
use crate::model::image::Image;
use crate::model::lights::Lights;
use rayon::prelude::*;

/// One sampled pixel: height, unit normal, albedo, inside the mask.
type Sample = (f32, [f32; 3], [f32; 3], bool);

/// A height field with its exact normals and albedo.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub width: usize,
    pub height: usize,
    /// Height toward the camera per pixel, pixel units, row-major (defined on the whole frame).
    pub depth: Vec<f32>,
    /// Unit normals, camera frame, row-major.
    pub normals: Vec<[f32; 3]>,
    /// Albedo per pixel (RGB).
    pub albedo: Vec<[f32; 3]>,
    /// Object pixels (only they cast shadows and are evaluated).
    pub mask: Vec<bool>,
}

impl Scene {
    /// Samples a height field at the pixel centres. `surface(col, row)` returns the height in
    /// pixel units and its exact derivatives `[h, ∂h/∂col, ∂h/∂row]`; the normal is
    /// (−∂h/∂col, +∂h/∂row, 1) normalised. `albedo(col, row)` gives RGB, `inside(col, row)` the
    /// mask. Rows are computed in parallel.
    pub fn from_height_fn(
        name: &str,
        width: usize,
        height: usize,
        surface: impl Fn(f64, f64) -> [f64; 3] + Sync,
        albedo: impl Fn(f64, f64) -> [f64; 3] + Sync,
        inside: impl Fn(f64, f64) -> bool + Sync,
    ) -> Result<Scene> {
        if width == 0 || height == 0 {
            return Err(Error::invalid(format!(
                "scene size {width}×{height}: expected at least one pixel"
            )));
        }
        let n = width * height;
        let mut scene = Scene {
            name: name.to_string(),
            width,
            height,
            depth: vec![0.0; n],
            normals: vec![[0.0; 3]; n],
            albedo: vec![[0.0; 3]; n],
            mask: vec![false; n],
        };
        // Filled in place, row by row in parallel: no second copy of the frame.
        scene
            .depth
            .par_chunks_mut(width)
            .zip(scene.normals.par_chunks_mut(width))
            .zip(scene.albedo.par_chunks_mut(width))
            .zip(scene.mask.par_chunks_mut(width))
            .enumerate()
            .for_each(|(row, (((d, nr), al), m))| {
                for col in 0..width {
                    let (c, r) = (col as f64, row as f64);
                    let [h, h_col, h_row] = surface(c, r);
                    let v = [-h_col, h_row, 1.0];
                    let norm = (v[0] * v[0] + v[1] * v[1] + 1.0).sqrt();
                    let a = albedo(c, r);
                    let sample: Sample = (
                        h as f32,
                        [
                            (v[0] / norm) as f32,
                            (v[1] / norm) as f32,
                            (1.0 / norm) as f32,
                        ],
                        [a[0] as f32, a[1] as f32, a[2] as f32],
                        inside(c, r),
                    );
                    d[col] = sample.0;
                    nr[col] = sample.1;
                    al[col] = sample.2;
                    m[col] = sample.3;
                }
            });
        if !scene.mask.iter().any(|&m| m) {
            return Err(Error::invalid(format!("scene '{name}': the mask is empty")));
        }
        Ok(scene)
    }

    /// A built-in scene of `width`×`height` pixels: the square scene of side min(W, H) at the
    /// centre of the frame (pixel units scaled alike), the surface's surroundings beyond it.
    /// `builtin_wh(k, s, s, …)` is `builtin(k, s, …)`.
    pub fn builtin_wh(
        kind: SceneKind,
        width: usize,
        height: usize,
        mask: Option<MaskShape>,
        textured: bool,
    ) -> Result<Scene> {
        let side = crate::model::image::MAX_IMAGE_SIDE as usize;
        if !(8..=side).contains(&width)
            || !(8..=side).contains(&height)
            || (width * height) as u64 > crate::model::image::MAX_IMAGE_PIXELS
        {
            return Err(Error::invalid(format!(
                "scene size {width}×{height}: expected 8 to {side} pixels a side and at most {} pixels",
                crate::model::image::MAX_IMAGE_PIXELS
            )));
        }
        let mask = mask.unwrap_or(kind.default_mask());
        let s = width.min(height) as f64 / 2.0;
        let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
        let uv = move |col: f64, row: f64| ((col - cx) / s, (cy - row) / s);
        Scene::from_height_fn(
            kind.name(),
            width,
            height,
            |col, row| {
                let (u, v) = uv(col, row);
                let [g, gu, gv] = kind.surface(u, v, 1.0 / s);
                [s * g, gu, -gv]
            },
            |col, row| {
                let (u, v) = uv(col, row);
                kind.albedo(u, v, textured)
            },
            |col, row| {
                let (u, v) = uv(col, row);
                mask.contains(u, v)
            },
        )
    }

    /// A built-in scene of `size`×`size` pixels with its default mask unless `mask` is given;
    /// `textured` modulates the albedo with a smooth colour texture.
    pub fn builtin(
        kind: SceneKind,
        size: usize,
        mask: Option<MaskShape>,
        textured: bool,
    ) -> Result<Scene> {
        if !(8..=8192).contains(&size) {
            return Err(Error::invalid(format!(
                "scene size {size}: expected 8..=8192 pixels"
            )));
        }
        let mask = mask.unwrap_or(kind.default_mask());
        let frame = Frame::new(size);
        Scene::from_height_fn(
            kind.name(),
            size,
            size,
            |col, row| frame.height_and_gradient(kind, col, row),
            |col, row| {
                let (u, v) = frame.uv(col, row);
                kind.albedo(u, v, textured)
            },
            |col, row| {
                let (u, v) = frame.uv(col, row);
                mask.contains(u, v)
            },
        )
    }
}

/// The mapping between pixel coordinates and the normalised coordinates of [`surfaces`].
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// Image centre, (N − 1)/2.
    pub centre: f64,
    /// Half size S = N/2: pixels per normalised unit.
    pub scale: f64,
}

impl Frame {
    /// The frame of an N×N image.
    pub fn new(size: usize) -> Self {
        Frame {
            centre: (size as f64 - 1.0) / 2.0,
            scale: size as f64 / 2.0,
        }
    }

    /// Normalised (u right, v up) coordinates of pixel (col, row).
    pub fn uv(&self, col: f64, row: f64) -> (f64, f64) {
        (
            (col - self.centre) / self.scale,
            (self.centre - row) / self.scale,
        )
    }

    /// `[h, ∂h/∂col, ∂h/∂row]` of a built-in surface at pixel (col, row), pixel units.
    pub fn height_and_gradient(&self, kind: SceneKind, col: f64, row: f64) -> [f64; 3] {
        let (u, v) = self.uv(col, row);
        let [g, gu, gv] = kind.surface(u, v, 1.0 / self.scale);
        [self.scale * g, gu, -gv]
    }
}

/// A sphere of radius 0.3·size resting on a plane (full mask, constant albedo).
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

/// Noise-free Lambertian images of the scene under `lights` (RGB, float, not clipped), with
/// attached shadows (n·l ≤ 0) and cast shadows (ray march). Returns the images and the per-light
/// shadow flags. For the full model (specular lobes, noise, quantisation) use [`render()`].
pub fn render_lambert(scene: &Scene, lights: &Lights) -> (Vec<Image>, Vec<Vec<bool>>) {
    lights
        .directions
        .par_iter()
        .zip(&lights.intensities)
        .map(|(l, e)| {
            let cast = cast_shadows(scene, *l);
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

/// Renders the scene (noise-free Lambert) and builds the capture (mask = the scene's mask).
pub fn lambert_capture(scene: &Scene, lights: &Lights) -> Result<(Capture, Vec<Vec<bool>>)> {
    let (images, shadows) = render_lambert(scene, lights);
    let capture = Capture::from_images(&images, lights.clone(), Some(scene.mask.clone()))?;
    Ok((capture, shadows))
}

/// `n` lights evenly spread in tilt at slant `slant_deg` (tilt 0 = +x, counter-clockwise).
pub fn ring_lights(n: usize, slant_deg: f64) -> Lights {
    let tilts: Vec<f64> = (0..n).map(|k| 360.0 * k as f64 / n as f64).collect();
    rigs::slant_tilt_lights(slant_deg, &tilts)
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
