//! Near-light scenes: a built-in surface placed about D = 300 mm in front of a
//! pinhole camera with a ~19° field of view, lit by LEDs a few hundred millimetres away — an
//! LED ring around the lens, a four-light square at 35° slant, a 24-light dome — rendered with
//! the near image model of CONVENTIONS.md (inverse-square fall-off, cos^μ anisotropy), a
//! Blinn–Phong lobe toward the real viewer, cast shadows of point lights, textured albedo and
//! 16-bit quantisation; ground truth normals and depth Z in mm. Written in the near-light layout.
//!
//! Geometry (camera frame, mm, camera centre at the origin): the object is the height field
//! z(x, y) = −D + R · g(x/R, y/R) of a built-in surface g ([`SceneKind::surface`]), R = D/6 its
//! half width, so its normals are (−g_u, −g_v, 1)/‖·‖ exactly. The camera sees the square
//! [−R, R]² at depth D across the image: f_x = f_y = (N/2) · D/R, principal point at the
//! image centre.

use super::reflectance::{BLINN_PHONG_EXPONENT, BLINN_PHONG_KS};
use super::render::{gather_lights, GroundTruth, LightResult, Rendered};
use super::surfaces::{MaskShape, SceneKind};
use super::Brdf;
use crate::base::error::{Error, Result};
use crate::base::rng::{splitmix64, Pcg32};
use crate::model::capture::Capture;
use crate::model::image::Image;
use crate::model::lightmodel::{dot, norm, sub, Camera, NearLights};
use crate::model::lights::Lights;
use rayon::prelude::*;
use std::sync::Arc;

/// The near-light rigs of `synth --rig`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NearRig {
    /// 12 LEDs on a ring of radius D/4 around the lens (in the camera plane z = 0), μ = 1.
    Ring,
    /// Four LEDs at 35° slant seen from the object's centre, in the camera plane, μ = 0.5.
    Square,
    /// 24 isotropic LEDs on a hemisphere of radius D about the object's centre: rings of 8 at
    /// slants 20°, 40° and 60°.
    Dome,
}

impl NearRig {
    /// Every near rig.
    pub const ALL: &'static [NearRig] = &[NearRig::Ring, NearRig::Square, NearRig::Dome];

    /// The name `synth --rig` takes.
    pub fn name(self) -> &'static str {
        match self {
            NearRig::Ring => "near-ring",
            NearRig::Square => "near-square",
            NearRig::Dome => "near-dome",
        }
    }

    /// Parses a name of [`NearRig::name`]; `None` for any other.
    pub fn parse(s: &str) -> Option<NearRig> {
        NearRig::ALL.iter().copied().find(|r| r.name() == s)
    }

    /// LED positions (mm) and anisotropy μ for an object at distance `d`; axes aim at (0,0,−d).
    pub fn layout(self, d: f64) -> (Vec<[f64; 3]>, Vec<f64>) {
        let centre = [0.0, 0.0, -d];
        let on_sphere = |slant: f64, tilt: f64, radius: f64| {
            let (s, t) = (slant.to_radians(), tilt.to_radians());
            [
                centre[0] + radius * s.sin() * t.cos(),
                centre[1] + radius * s.sin() * t.sin(),
                centre[2] + radius * s.cos(),
            ]
        };
        match self {
            NearRig::Ring => {
                let r = d / 4.0;
                let p = (0..12)
                    .map(|k| {
                        let t = (k as f64 * 30.0 + 15.0).to_radians();
                        [r * t.cos(), r * t.sin(), 0.0]
                    })
                    .collect();
                (p, vec![1.0; 12])
            }
            NearRig::Square => {
                let r = d * 35f64.to_radians().tan();
                let p = [45.0f64, 135.0, 225.0, 315.0]
                    .iter()
                    .map(|t| {
                        let t = t.to_radians();
                        [r * t.cos(), r * t.sin(), 0.0]
                    })
                    .collect();
                (p, vec![0.5; 4])
            }
            NearRig::Dome => {
                let mut p = Vec::new();
                for (i, slant) in [20.0, 40.0, 60.0].iter().enumerate() {
                    for j in 0..8 {
                        p.push(on_sphere(*slant, j as f64 * 45.0 + i as f64 * 15.0, d));
                    }
                }
                (p, vec![0.0; 24])
            }
        }
    }
}

/// Everything a near-light scene takes.
#[derive(Clone, Debug, PartialEq)]
pub struct NearSpec {
    pub scene: SceneKind,
    pub rig: NearRig,
    /// Image width and height, pixels.
    pub size: usize,
    /// The object's distance D, mm (default 300).
    pub distance: f64,
    pub mask: Option<MaskShape>,
    pub textured_albedo: bool,
    /// `Lambert` or `BlinnPhong` (the lobe toward the real viewer −X/‖X‖).
    pub brdf: Brdf,
    /// Gaussian read noise σ, fraction of full scale.
    pub noise_sigma: f64,
    pub seed: u64,
}

impl NearSpec {
    /// The defaults of `synth` with a near rig: 256², D = 300 mm, textured, Blinn–Phong,
    /// σ = 0.5%, seed 1.
    pub fn new(scene: SceneKind, rig: NearRig) -> Self {
        NearSpec {
            scene,
            rig,
            size: 256,
            distance: 300.0,
            mask: None,
            textured_albedo: true,
            brdf: Brdf::BlinnPhong,
            noise_sigma: 0.005,
            seed: 1,
        }
    }
}

/// A rendered near-light scene: the images and ground truth (depth = Z in mm) as
/// [`Rendered`], whose lights carry the near model, and the rig as the layout files state it.
#[derive(Clone, Debug)]
pub struct NearRendered {
    pub rendered: Rendered,
    pub camera: Camera,
    pub positions: Vec<[f64; 3]>,
    pub axes: Vec<[f64; 3]>,
    pub anisotropy: Vec<f64>,
    /// Radiance along each LED's axis at 1 mm, RGB.
    pub radiance: Vec<[f64; 3]>,
    /// The object's mean distance: mean Z over the mask, mm.
    pub distance: f64,
}

impl NearRendered {
    /// The capture in the near model (a fresh copy of the model: its own current surface).
    pub fn capture(&self) -> Result<Capture> {
        let mut lights = self.rendered.lights.clone();
        if let Some(m) = &lights.near {
            lights.near = Some(Arc::new(m.permuted(&(0..m.len()).collect::<Vec<_>>())));
        }
        Capture::from_images(
            &self.images(),
            lights,
            Some(self.rendered.truth.mask.clone()),
        )
    }

    /// The same capture under the distant approximation: directions toward each LED and its
    /// brightness at the object's centre, the same at every pixel.
    pub fn distant_capture(&self) -> Result<Capture> {
        let mut lights = self.rendered.lights.clone();
        lights.near = None;
        Capture::from_images(
            &self.images(),
            lights,
            Some(self.rendered.truth.mask.clone()),
        )
    }

    fn images(&self) -> Vec<Image> {
        self.rendered.images.clone()
    }
}

/// Renders a near-light scene: the object's visible point under every pixel, each LED's
/// image of it (inverse-square fall-off, cos^μ anisotropy, attached and cast shadows, the
/// Blinn–Phong lobe, noise and 16-bit quantisation) and the ground truth.
pub fn synthesize_near(spec: &NearSpec) -> Result<NearRendered> {
    check_spec(spec)?;
    let (size, d) = (spec.size, spec.distance);
    let object = NearObject {
        kind: spec.scene,
        d,
        r_obj: d / 6.0,
        pixel: 2.0 / size as f64, // one pixel in normalised units
    };
    let f = (size as f64 / 2.0) * d / object.r_obj;
    let c = (size as f64 - 1.0) / 2.0;
    let camera = Camera::new(f, f, c, c)?;
    let grid = HeightGrid::new(&object);
    let hits = visible_points(spec, &camera, &object, &grid);
    let mask: Vec<bool> = hits
        .iter()
        .map(|h| h.as_ref().is_some_and(|h| h.inside))
        .collect();
    if !mask.iter().any(|&m| m) {
        return Err(Error::invalid("near-light scene: the mask is empty"));
    }
    // The object's mean distance (what mean_distance.txt states): the mean Z over the mask.
    let (z_sum, z_count) = hits
        .iter()
        .zip(&mask)
        .filter(|(_, &m)| m)
        .fold((0.0, 0usize), |(s, c), (h, _)| {
            (s + h.as_ref().map_or(0.0, |h| -h.x[2]), c + 1)
        });
    let mean_z = z_sum / z_count as f64;
    let (positions, anisotropy) = spec.rig.layout(d);
    let n_lights = positions.len();
    // Every LED aims at the centre of the rig, (0, 0, −D).
    let axes: Vec<[f64; 3]> = positions
        .iter()
        .map(|p| {
            let v = sub([0.0, 0.0, -d], *p);
            let l = norm(v);
            [v[0] / l, v[1] / l, v[2] / l]
        })
        .collect();
    let model = NearLights::new(
        camera,
        positions.clone(),
        Some(axes),
        Some(anisotropy.clone()),
        mean_z,
    )?;
    // Radiance: 0.8 of full scale at the centre for a white surface facing the light, with a
    // per-light spread of ±10% and a slight tint.
    let radiance: Vec<[f64; 3]> = (0..n_lights)
        .map(|k| {
            let base = 0.8 / model.centre_brightness()[k] * (1.0 + 0.1 * (1.7 * k as f64).sin());
            [base * 1.02, base, base * 0.97]
        })
        .collect();
    let render = LedRender {
        spec,
        model: &model,
        hits: &hits,
        grid: &grid,
        radiance: &radiance,
        anisotropy: &anisotropy,
        positions: &positions,
        threshold: 0.02f64.max(3.0 * spec.noise_sigma),
        seed: splitmix64(spec.seed),
    };
    let per_light: Vec<LightResult> = (0..n_lights)
        .into_par_iter()
        .map(|k| render.light(k))
        .collect();
    let mask_pixels = mask.iter().filter(|&&m| m).count() as f64;
    let mut truth = ground_truth(&hits, mask, size, n_lights);
    let (images, stats) = gather_lights(per_light, size, size, mask_pixels, &mut truth);
    // The capture's lights: the distant approximation at the centre plus the near model; the
    // images are divided by E_k times the brightness at the centre.
    let centre = model.centre_brightness().to_vec();
    let lights = Lights::new(&model.centre_directions())?.with_intensities(
        radiance
            .iter()
            .zip(&centre)
            .map(|(e, b)| [e[0] * b, e[1] * b, e[2] * b])
            .collect(),
    )?;
    let axes = model.axes.clone();
    let lights = Lights {
        near: Some(Arc::new(model)),
        ..lights
    };
    Ok(NearRendered {
        rendered: Rendered {
            scene: spec.scene.name().to_string(),
            rig: spec.rig.name().to_string(),
            images,
            lights,
            truth,
            stats,
        },
        camera,
        positions,
        axes,
        anisotropy,
        radiance,
        distance: mean_z,
    })
}

/// The domains of a near-light scene's size, distance, reflectance and noise.
fn check_spec(spec: &NearSpec) -> Result<()> {
    if !(16..=8192).contains(&spec.size) {
        return Err(Error::invalid(format!(
            "scene size {}: expected 16..=8192 pixels for a near-light scene",
            spec.size
        )));
    }
    if !(spec.distance.is_finite() && spec.distance > 0.0) {
        return Err(Error::parameter(
            "distance",
            format!("{}: expected a positive distance in mm", spec.distance),
        ));
    }
    if !matches!(spec.brdf, Brdf::Lambert | Brdf::BlinnPhong) {
        return Err(Error::invalid(format!(
            "near-light scenes render lambert or blinn-phong, not {}",
            spec.brdf.name()
        )));
    }
    if !(spec.noise_sigma.is_finite() && spec.noise_sigma >= 0.0) {
        return Err(Error::invalid(format!(
            "noise σ {}: expected a finite value ≥ 0",
            spec.noise_sigma
        )));
    }
    Ok(())
}

/// The object of a near-light scene: the height field z(x, y) = −D + R · g(x/R, y/R) of the
/// built-in surface g (module documentation).
struct NearObject {
    kind: SceneKind,
    /// D, mm.
    d: f64,
    /// R = D/6, the object's half width, mm.
    r_obj: f64,
    /// One pixel in normalised units (the surfaces' smoothing scale).
    pixel: f64,
}

impl NearObject {
    /// Height (mm, z) and gradient of the object at world (x, y).
    fn height(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let [g, gu, gv] = self
            .kind
            .surface(x / self.r_obj, y / self.r_obj, self.pixel);
        (-self.d + self.r_obj * g, gu, gv)
    }
}

/// A grid of the object's heights for the ray and shadow marches: half a pixel's footprint
/// apart, over 1.6 R on each side of the axis.
struct HeightGrid {
    step: f64,
    extent: f64,
    /// Nodes per side.
    gn: usize,
    values: Vec<f64>,
    /// The highest and lowest heights.
    top: f64,
    bottom: f64,
}

impl HeightGrid {
    fn new(object: &NearObject) -> Self {
        let step = object.r_obj * object.pixel / 2.0;
        let extent = 1.6 * object.r_obj;
        let gn = (2.0 * extent / step).ceil() as usize + 1;
        let values: Vec<f64> = (0..gn * gn)
            .into_par_iter()
            .map(|i| {
                object
                    .height(
                        -extent + (i % gn) as f64 * step,
                        -extent + (i / gn) as f64 * step,
                    )
                    .0
            })
            .collect();
        let top = values.iter().cloned().fold(f64::MIN, f64::max);
        let bottom = values.iter().cloned().fold(f64::MAX, f64::min);
        HeightGrid {
            step,
            extent,
            gn,
            values,
            top,
            bottom,
        }
    }

    /// The height at world (x, y), bilinear between the nodes; `None` off the grid.
    fn at(&self, x: f64, y: f64) -> Option<f64> {
        let gn = self.gn;
        let gx = (x + self.extent) / self.step;
        let gy = (y + self.extent) / self.step;
        if gx < 0.0 || gy < 0.0 || gx >= (gn - 1) as f64 || gy >= (gn - 1) as f64 {
            return None;
        }
        let (ix, iy) = (gx as usize, gy as usize);
        let (fx, fy) = (gx - ix as f64, gy - iy as f64);
        let at = |a: usize, b: usize| self.values[b * gn + a];
        Some(
            (1.0 - fy) * ((1.0 - fx) * at(ix, iy) + fx * at(ix + 1, iy))
                + fy * ((1.0 - fx) * at(ix, iy + 1) + fx * at(ix + 1, iy + 1)),
        )
    }
}

/// The object's visible point under a pixel: position (mm), unit normal, whether it is inside
/// the scene's mask shape, and its albedo.
struct Hit {
    x: [f64; 3],
    n: [f64; 3],
    inside: bool,
    albedo: [f64; 3],
}

/// The visible point of every pixel: march along the ray from in front of the object's top to
/// its bottom, bisect the first crossing.
fn visible_points(
    spec: &NearSpec,
    camera: &Camera,
    object: &NearObject,
    grid: &HeightGrid,
) -> Vec<Option<Hit>> {
    let size = spec.size;
    let mask_shape = spec.mask.unwrap_or(spec.scene.default_mask());
    (0..size * size)
        .into_par_iter()
        .map(|i| {
            let r = camera.ray((i % size) as f64, (i / size) as f64);
            let phi = |t: f64| {
                let (x, y) = (t * r[0], t * r[1]);
                -t - object.height(x, y).0
            };
            let dt = grid.step;
            let mut t0 = -grid.top - dt;
            let end = -grid.bottom + dt;
            let mut t1 = t0;
            let mut found = false;
            while t1 < end {
                t1 = t0 + dt;
                if phi(t1) <= 0.0 {
                    found = true;
                    break;
                }
                t0 = t1;
            }
            if !found {
                return None;
            }
            for _ in 0..50 {
                let m = 0.5 * (t0 + t1);
                // Adjacent floats: every further halving gives t0 or t1 again.
                if m == t0 || m == t1 {
                    break;
                }
                if phi(m) <= 0.0 {
                    t1 = m;
                } else {
                    t0 = m;
                }
            }
            let t = 0.5 * (t0 + t1);
            let x = [t * r[0], t * r[1], -t];
            let (_, gu, gv) = object.height(x[0], x[1]);
            let len = (gu * gu + gv * gv + 1.0).sqrt();
            let (u, v) = (x[0] / object.r_obj, x[1] / object.r_obj);
            Some(Hit {
                x,
                n: [-gu / len, -gv / len, 1.0 / len],
                inside: mask_shape.contains(u, v),
                albedo: spec.scene.albedo(u, v, spec.textured_albedo),
            })
        })
        .collect()
}

/// The ground truth of the visible points inside `mask`: normals, depth Z (mm) and albedo; the
/// per-light maps are filled by [`gather_lights`].
fn ground_truth(
    hits: &[Option<Hit>],
    mask: Vec<bool>,
    size: usize,
    n_lights: usize,
) -> GroundTruth {
    GroundTruth {
        width: size,
        height: size,
        normals: hits
            .iter()
            .zip(&mask)
            .map(|(h, &m)| match h {
                Some(h) if m => [h.n[0] as f32, h.n[1] as f32, h.n[2] as f32],
                _ => [0.0; 3],
            })
            .collect(),
        depth: hits
            .iter()
            .zip(&mask)
            .map(|(h, &m)| match h {
                Some(h) if m => -h.x[2] as f32,
                _ => f32::NAN,
            })
            .collect(),
        albedo: hits
            .iter()
            .zip(&mask)
            .map(|(h, &m)| match h {
                Some(h) if m => [h.albedo[0] as f32, h.albedo[1] as f32, h.albedo[2] as f32],
                _ => [0.0; 3],
            })
            .collect(),
        mask,
        shadow: Vec::with_capacity(n_lights),
        cast_shadow: Vec::with_capacity(n_lights),
        highlight: Vec::with_capacity(n_lights),
    }
}

/// What each LED's image is rendered from.
struct LedRender<'a> {
    spec: &'a NearSpec,
    model: &'a NearLights,
    hits: &'a [Option<Hit>],
    grid: &'a HeightGrid,
    /// Radiance along each LED's axis at 1 mm, RGB.
    radiance: &'a [[f64; 3]],
    anisotropy: &'a [f64],
    positions: &'a [[f64; 3]],
    /// A lit reading whose lobe exceeds it is a highlight of the ground truth.
    threshold: f64,
    seed: u64,
}

impl LedRender<'_> {
    /// LED `k`'s image (noise from its own stream, 16-bit quantisation, clipped pixels counted)
    /// and its ground-truth shadow, cast-shadow and highlight maps.
    fn light(&self, k: usize) -> LightResult {
        let size = self.spec.size;
        let mut rng = Pcg32::new(self.seed, k as u64 + 1);
        let mut out = LightResult {
            image: vec![0.0; size * size * 3],
            shadow: vec![false; size * size],
            cast: vec![false; size * size],
            highlight: vec![false; size * size],
            clipped: 0,
        };
        for (i, hit) in self.hits.iter().enumerate() {
            let mut value = [0.0f64; 3];
            if let Some(h) = hit {
                self.shade(k, h, i, &mut value, &mut out);
            }
            let mut clipped = false;
            for (ch, v) in value.iter().enumerate() {
                let noisy = v + self.spec.noise_sigma * rng.next_normal();
                if noisy >= 1.0 {
                    clipped = true;
                }
                out.image[i * 3 + ch] =
                    ((noisy.clamp(0.0, 1.0) * 65535.0).round() / 65535.0) as f32;
            }
            if clipped && hit.as_ref().is_some_and(|h| h.inside) {
                out.clipped += 1;
            }
        }
        out
    }

    /// The noiseless radiance of LED `k` at the visible point `h` of pixel `i` into `value`,
    /// and the pixel's ground-truth flags into `out` when it is inside the mask.
    fn shade(&self, k: usize, h: &Hit, i: usize, value: &mut [f64; 3], out: &mut LightResult) {
        let radiance = self.radiance;
        let (l, _) = self.model.light_at_point(k, h.x);
        let dist = norm(sub(self.positions[k], h.x));
        let raw = {
            let a = self.model.axes[k];
            let cos = (-dot(a, l)).max(0.0);
            let mu = self.anisotropy[k];
            (if mu == 0.0 { 1.0 } else { cos.powf(mu) }) / (dist * dist)
        };
        let ndl = dot(h.n, l);
        let attached = ndl <= 0.0;
        let cast = !attached && self.blocked(h, l, dist);
        let mut spec_v = 0.0;
        if !attached && !cast {
            if self.spec.brdf == Brdf::BlinnPhong {
                spec_v = blinn_phong_lobe(h, l);
            }
            for (ch, v) in value.iter_mut().enumerate() {
                *v = radiance[k][ch] * raw * (h.albedo[ch] * ndl + spec_v);
            }
        }
        if h.inside {
            out.shadow[i] = attached || cast;
            out.cast[i] = cast;
            out.highlight[i] = !(attached || cast)
                && radiance[k].iter().sum::<f64>() / 3.0 * raw * spec_v > self.threshold;
        }
    }

    /// Whether the object blocks the segment from the point `h` toward the LED in direction
    /// `l`, `dist` away (a cast shadow): marched in grid steps until it rises above the
    /// object's top or leaves the grid.
    fn blocked(&self, h: &Hit, l: [f64; 3], dist: f64) -> bool {
        let (grid, step) = (self.grid, self.grid.step);
        let mut t = 2.0 * step;
        while t < dist {
            let p = [h.x[0] + t * l[0], h.x[1] + t * l[1], h.x[2] + t * l[2]];
            if p[2] > grid.top {
                break;
            }
            match grid.at(p[0], p[1]) {
                Some(z) if p[2] < z - 0.05 * step => return true,
                Some(_) => {}
                None => break,
            }
            t += step;
        }
        false
    }
}

/// The Blinn–Phong lobe toward the real viewer −X/‖X‖ at the point `h` lit from direction `l`:
/// k_s (n · h)^e with the half vector h of `l` and the view direction; 0 where the surface faces
/// away from the viewer.
fn blinn_phong_lobe(h: &Hit, l: [f64; 3]) -> f64 {
    let v = {
        let len = norm(h.x);
        [-h.x[0] / len, -h.x[1] / len, -h.x[2] / len]
    };
    let hv = [l[0] + v[0], l[1] + v[1], l[2] + v[2]];
    let hl = norm(hv);
    if hl > 1e-12 && dot(h.n, v) > 0.0 {
        let ndh = (dot(h.n, hv) / hl).max(0.0);
        BLINN_PHONG_KS * ndh.powf(BLINN_PHONG_EXPONENT)
    } else {
        0.0
    }
}

/// The oracle of the acceptance test: least squares on the truly lit lights of every pixel
/// (those not in the ground truth's attached or cast shadow) with the true per-pixel light
/// vectors (at the true depth). Returns its mean angular error in degrees over the mask.
pub fn oracle_error(near: &NearRendered) -> Result<f64> {
    let capture = near.capture()?;
    let model = capture
        .lights
        .near
        .as_deref()
        .ok_or_else(|| Error::invalid("the oracle needs a near-light capture"))?;
    let truth = &near.rendered.truth;
    model.set_surface(&truth.depth);
    let n = capture.n_lights();
    let mut usable = vec![false; capture.n_pixels() * n];
    for (p, &i) in capture.pixels.iter().enumerate() {
        for k in 0..n {
            usable[p * n + k] = !truth.shadow[k][i as usize];
        }
    }
    let est = crate::solve::lambert::solve_subsets(
        &capture,
        Some(&usable),
        &crate::base::progress::Silent,
    );
    let normals = capture.scatter(&est.normals, 1, [0.0; 3]);
    let (_, stats) = crate::solve::metrics::evaluate(&normals, &truth.normals, Some(&truth.mask))?;
    Ok(stats.mean_deg)
}
