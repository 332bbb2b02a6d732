//! The light model behind one door (ARCHITECTURE.md): "the light vector and brightness of light
//! k at pixel p given the current surface", for distant lights (one direction per light, the
//! same at every pixel) and for near point lights seen through a pinhole camera
//! (CONVENTIONS.md, "Near lights and perspective cameras"; ALGORITHMS.md §9).
//!
//! Frames and units: the camera frame of CONVENTIONS.md (x right, y up, z toward the camera)
//! with the **camera centre at the origin**, millimetres. Pixel (row v, col u) sees the ray
//! r(p) = ((u − c_x)/f_x, −(v − c_y)/f_y, −1); the surface point is X(p) = Z(p) · r(p) with Z
//! the depth along the optical axis (mm, positive).
//!
//! Near image model: I_k(p) = ρ(p) · E_k · cos^μ_k(θ_k) · max(0, n · l_k) / ‖s_k − X‖², with
//! l_k = (s_k − X)/‖s_k − X‖ and θ_k the angle between the LED's axis and X − s_k. The capture
//! divides each image by the brightness its light gives the object's centre C = (0, 0, −D)
//! (E_k cos^μ_k / ‖s_k − C‖², so that the readings are near ρ n · l), and the kernel solves each
//! pixel with the *scaled* light vectors v_k(p) = b_k(p) l_k(p), b_k(p) the brightness at X(p)
//! relative to the one at C. The distant approximation of a near rig — directions and
//! brightness at C — is the same capture with the near model removed
//! ([`NearLights::centre_directions`]).

use crate::base::error::{Error, Result};
use std::sync::{Arc, RwLock};

/// A pinhole camera: intrinsics in pixels (`K = [fx 0 cx; 0 fy cy; 0 0 1]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Focal length along the columns, pixels.
    pub fx: f64,
    /// Focal length along the rows, pixels.
    pub fy: f64,
    /// Principal point, column (pixels, 0 = centre of the first column).
    pub cx: f64,
    /// Principal point, row (pixels).
    pub cy: f64,
}

impl Camera {
    /// Checks that K is invertible and sensible (positive finite focal lengths, finite centre).
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Result<Camera> {
        if !(fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0) {
            return Err(Error::invalid(format!(
                "camera focal lengths fx = {fx}, fy = {fy}: expected positive finite values (K must be invertible)"
            )));
        }
        if !(cx.is_finite() && cy.is_finite()) {
            return Err(Error::invalid(format!(
                "camera principal point ({cx}, {cy}): expected finite values"
            )));
        }
        Ok(Camera { fx, fy, cx, cy })
    }

    /// Checks that the principal point lies in a `width × height` image (pixel centres at whole
    /// coordinates, so the image spans −0.5 to `width` − 0.5): intrinsics of the full sensor
    /// given with images that were cropped or binned put it elsewhere, and every ray is then
    /// wrong. The message says how to correct K.
    pub fn check_frame(&self, width: usize, height: usize) -> std::result::Result<(), String> {
        let (w, h) = (width as f64, height as f64);
        if (-0.5..=w - 0.5).contains(&self.cx) && (-0.5..=h - 0.5).contains(&self.cy) {
            return Ok(());
        }
        Err(format!(
            "principal point (cx, cy) = ({}, {}): it lies outside the {width}×{height} images, so \
             K belongs to another image size. For a crop, subtract the crop's offset from \
             cx and cy; for images binned by b, divide fx, fy, cx + 0.5 and cy + 0.5 by b (then \
             subtract 0.5)",
            self.cx, self.cy
        ))
    }

    /// The ray of pixel (col, row): ((u − cx)/fx, −(v − cy)/fy, −1), camera frame; X = Z · ray.
    #[inline]
    pub fn ray(&self, col: f64, row: f64) -> [f64; 3] {
        [(col - self.cx) / self.fx, -(row - self.cy) / self.fy, -1.0]
    }

    /// The pixel (col, row) where point `x` (camera frame, z < 0) projects, or None behind.
    #[inline]
    pub fn project(&self, x: [f64; 3]) -> Option<(f64, f64)> {
        if x[2] >= -1e-9 {
            return None;
        }
        let z = -x[2];
        Some((self.cx + self.fx * x[0] / z, self.cy - self.fy * x[1] / z))
    }
}

/// Near point lights (LEDs) seen through a pinhole camera, with the current surface.
///
/// The current surface (depth Z per pixel, mm, full frame) starts as the plane Z = D and is
/// replaced by the reconstruction's alternation ([`NearLights::set_surface`]); it is shared by
/// every clone of the capture that holds this model, so two near-light reconstructions of one
/// capture must not run at the same time.
#[derive(Debug)]
pub struct NearLights {
    /// The camera.
    pub camera: Camera,
    /// LED positions, mm, camera frame.
    pub positions: Vec<[f64; 3]>,
    /// Unit axes, from each LED toward the scene.
    pub axes: Vec<[f64; 3]>,
    /// Anisotropy μ ≥ 0 per LED (radiance ∝ cos^μ off the axis).
    pub anisotropy: Vec<f64>,
    /// The object's mean distance D along the optical axis, mm.
    pub mean_distance: f64,
    /// Relative brightness cos^μ/r² of each LED at the object's centre (0, 0, −D).
    centre_brightness: Vec<f64>,
    surface: RwLock<Arc<Vec<f32>>>,
}

impl PartialEq for NearLights {
    fn eq(&self, other: &Self) -> bool {
        self.camera == other.camera
            && self.positions == other.positions
            && self.axes == other.axes
            && self.anisotropy == other.anisotropy
            && self.mean_distance == other.mean_distance
    }
}

impl NearLights {
    /// A near rig. `axes`: `None` aims every LED at (0, 0, −D); `anisotropy`: `None` = isotropic.
    /// Errors name the light (1-based) and what is wrong: a light behind the object (z ≤ −D, at
    /// or beyond its mean depth) or behind the camera (z > 0), a non-positive or non-finite
    /// distance, an axis that is zero or points away from the object, μ < 0.
    pub fn new(
        camera: Camera,
        positions: Vec<[f64; 3]>,
        axes: Option<Vec<[f64; 3]>>,
        anisotropy: Option<Vec<f64>>,
        mean_distance: f64,
    ) -> Result<NearLights> {
        if !(mean_distance.is_finite() && mean_distance > 0.0) {
            return Err(Error::parameter(
                "distance",
                format!("{mean_distance}: expected the object's mean distance in mm, finite and positive"),
            ));
        }
        let n = positions.len();
        let centre = [0.0, 0.0, -mean_distance];
        for (k, s) in positions.iter().enumerate() {
            if s.iter().any(|v| !v.is_finite()) {
                return Err(Error::invalid(format!(
                    "light {} position {s:?}: expected finite millimetres",
                    k + 1
                )));
            }
            if s[2] <= -mean_distance {
                return Err(Error::invalid(format!(
                    "light {} at z = {} mm is behind the object (its mean depth is z = {} mm): near lights must be in front of it",
                    k + 1,
                    s[2],
                    -mean_distance
                )));
            }
            if s[2] > 1e-6 * mean_distance {
                return Err(Error::invalid(format!(
                    "light {} at z = {} mm is behind the camera (camera at z = 0, looking down −z): check the sign of z",
                    k + 1,
                    s[2]
                )));
            }
        }
        let axes = match axes {
            Some(a) => {
                if a.len() != n {
                    return Err(Error::invalid(format!(
                        "{} light axes for {n} light positions",
                        a.len()
                    )));
                }
                let mut out = Vec::with_capacity(n);
                for (k, (v, s)) in a.iter().zip(&positions).enumerate() {
                    let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                    if !(norm.is_finite() && norm > 1e-12) {
                        return Err(Error::invalid(format!(
                            "light {} axis {v:?}: expected a non-zero finite vector",
                            k + 1
                        )));
                    }
                    let u = [v[0] / norm, v[1] / norm, v[2] / norm];
                    let to_centre = sub(centre, *s);
                    if dot(u, to_centre) <= 0.0 {
                        return Err(Error::invalid(format!(
                            "light {} axis {v:?} points away from the object (from the LED toward the scene is expected)",
                            k + 1
                        )));
                    }
                    out.push(u);
                }
                out
            }
            None => positions
                .iter()
                .map(|s| {
                    let d = sub(centre, *s);
                    let r = norm(d);
                    [d[0] / r, d[1] / r, d[2] / r]
                })
                .collect(),
        };
        let anisotropy = match anisotropy {
            Some(m) => {
                if m.len() != n {
                    return Err(Error::invalid(format!(
                        "{} anisotropy values for {n} light positions",
                        m.len()
                    )));
                }
                for (k, &mu) in m.iter().enumerate() {
                    if !(mu.is_finite() && mu >= 0.0) {
                        return Err(Error::invalid(format!(
                            "light {} anisotropy μ = {mu}: expected a finite value ≥ 0",
                            k + 1
                        )));
                    }
                }
                m
            }
            None => vec![0.0; n],
        };
        // Seen from the object's centre the LEDs must spread over more than the model's own
        // precision: at a distance so large that they all arrive from one direction (1 mrad,
        // below any rig's calibration error) no normal is determined.
        let toward = |s: &[f64; 3]| {
            let d = sub(*s, centre);
            let l = norm(d);
            [d[0] / l, d[1] / l, d[2] / l]
        };
        let spread = positions
            .iter()
            .flat_map(|a| positions.iter().map(move |b| (a, b)))
            .map(|(a, b)| dot(toward(a), toward(b)).clamp(-1.0, 1.0).acos())
            .fold(0.0f64, f64::max);
        if n >= 2 && spread < 1e-3 {
            return Err(Error::parameter(
                "distance",
                format!(
                    "{mean_distance:e}: at that distance (mm) the {n} LEDs are seen within {:.4}° of one \
                     another, a single direction that determines no normal; expected the object's \
                     mean distance in millimetres",
                    spread.to_degrees()
                ),
            ));
        }
        let mut model = NearLights {
            camera,
            positions,
            axes,
            anisotropy,
            mean_distance,
            centre_brightness: Vec::new(),
            surface: RwLock::new(Arc::new(Vec::new())),
        };
        model.centre_brightness = (0..n)
            .map(|k| model.raw_light(k, centre).1)
            .collect::<Vec<f64>>();
        for (k, &b) in model.centre_brightness.iter().enumerate() {
            if !(b.is_finite() && b > 0.0) {
                return Err(Error::invalid(format!(
                    "light {} gives the object's centre no light (it lies at or beyond 90° off the LED's axis)",
                    k + 1
                )));
            }
        }
        Ok(model)
    }

    /// A near rig restored from the fields of another ([`crate::io::capture_state`]): `axes`
    /// and `anisotropy` taken as they are, after the checks of [`NearLights::new`] (the axes
    /// are unit vectors already; normalising them again could change their last bits).
    pub fn restore(
        camera: Camera,
        positions: Vec<[f64; 3]>,
        axes: Vec<[f64; 3]>,
        anisotropy: Vec<f64>,
        mean_distance: f64,
    ) -> Result<NearLights> {
        let mut model = NearLights::new(
            camera,
            positions,
            Some(axes.clone()),
            Some(anisotropy),
            mean_distance,
        )?;
        model.axes = axes;
        let centre = [0.0, 0.0, -mean_distance];
        model.centre_brightness = (0..model.len())
            .map(|k| model.raw_light(k, centre).1)
            .collect();
        Ok(model)
    }

    /// Number of lights.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True without lights.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Unit direction and relative brightness cos^μ/r² (per unit E) of light k at point x (mm).
    #[inline]
    fn raw_light(&self, k: usize, x: [f64; 3]) -> ([f64; 3], f64) {
        let d = sub(self.positions[k], x);
        let r2 = dot(d, d).max(1e-12);
        let r = r2.sqrt();
        let l = [d[0] / r, d[1] / r, d[2] / r];
        // Angle off the axis: between the axis and X − s = −l.
        let cos = (-dot(self.axes[k], l)).max(0.0);
        let mu = self.anisotropy[k];
        let lobe = if mu == 0.0 { 1.0 } else { cos.powf(mu) };
        (l, lobe / r2)
    }

    /// The brightness each light gives the object's centre (0, 0, −D) relative to its
    /// on-axis radiance E at 1 mm: cos^μ(θ)/r² (1/mm²). A capture's images are divided by
    /// E_k times this value.
    pub fn centre_brightness(&self) -> &[f64] {
        &self.centre_brightness
    }

    /// The directions toward each light from the object's centre: the distant approximation.
    pub fn centre_directions(&self) -> Vec<[f64; 3]> {
        let c = [0.0, 0.0, -self.mean_distance];
        (0..self.len()).map(|k| self.raw_light(k, c).0).collect()
    }

    /// The surface point X = Z · ray of pixel (col, row) at depth `z` (mm).
    #[inline]
    pub fn point(&self, col: usize, row: usize, z: f64) -> [f64; 3] {
        let r = self.camera.ray(col as f64, row as f64);
        [z * r[0], z * r[1], z * r[2]]
    }

    /// Light k at point `x`: its unit direction and its brightness relative to the object's
    /// centre (1 at (0, 0, −D)).
    #[inline]
    pub fn light_at_point(&self, k: usize, x: [f64; 3]) -> ([f64; 3], f64) {
        let (l, b) = self.raw_light(k, x);
        (l, b / self.centre_brightness[k])
    }

    /// The scaled light vectors v_k = b_k l_k of every light at pixel (col, row) with depth `z`
    /// (mm), into `out` (length N).
    #[inline]
    pub fn vectors(&self, col: usize, row: usize, z: f64, out: &mut [[f64; 3]]) {
        let x = self.point(col, row, z);
        for (k, o) in out.iter_mut().enumerate() {
            let (l, b) = self.light_at_point(k, x);
            *o = [b * l[0], b * l[1], b * l[2]];
        }
    }

    /// The current surface: depth Z per pixel (full frame, mm); empty for the plane Z = D.
    pub fn surface(&self) -> Arc<Vec<f32>> {
        self.surface
            .read()
            .map(|g| g.clone())
            .unwrap_or_else(|e| e.into_inner().clone())
    }

    /// Replaces the current surface (full frame of the capture, mm). Non-finite or
    /// non-positive values (no depth there) fall back to the mean distance.
    pub fn set_surface(&self, depth: &[f32]) {
        let d = self.mean_distance as f32;
        let v: Vec<f32> = depth
            .iter()
            .map(|&z| if z.is_finite() && z > 0.0 { z } else { d })
            .collect();
        match self.surface.write() {
            Ok(mut g) => *g = Arc::new(v),
            Err(e) => *e.into_inner() = Arc::new(v),
        }
    }

    /// Resets the current surface to the plane Z = D.
    pub fn reset_surface(&self) {
        self.set_surface(&[]);
    }

    /// The same rig with the lights reordered by `order` (a fresh plane surface).
    pub fn permuted(&self, order: &[usize]) -> NearLights {
        let mut m = NearLights {
            camera: self.camera,
            positions: order.iter().map(|&k| self.positions[k]).collect(),
            axes: order.iter().map(|&k| self.axes[k]).collect(),
            anisotropy: order.iter().map(|&k| self.anisotropy[k]).collect(),
            mean_distance: self.mean_distance,
            centre_brightness: order.iter().map(|&k| self.centre_brightness[k]).collect(),
            surface: RwLock::new(Arc::new(Vec::new())),
        };
        m.surface = RwLock::new(self.surface());
        m
    }
}

/// Per-thread access to the light vectors of one pixel after another: the distant directions
/// (no copy) or the near model's scaled vectors at the current surface. No allocation per pixel.
pub struct PixelLights<'a> {
    directions: &'a [[f64; 3]],
    near: Option<(&'a NearLights, Arc<Vec<f32>>)>,
    width: usize,
    buf: Vec<[f64; 3]>,
}

impl<'a> PixelLights<'a> {
    /// For lights `directions` (distant) and the near model when there is one, on images
    /// `width` pixels wide.
    pub fn new(directions: &'a [[f64; 3]], near: Option<&'a NearLights>, width: usize) -> Self {
        PixelLights {
            directions,
            near: near.map(|m| (m, m.surface())),
            width,
            buf: vec![[0.0; 3]; directions.len()],
        }
    }

    /// Whether the vectors vary per pixel.
    #[inline]
    pub fn is_near(&self) -> bool {
        self.near.is_some()
    }

    /// The light vectors at full-frame pixel `pixel`.
    #[inline]
    pub fn at(&mut self, pixel: usize) -> &[[f64; 3]] {
        match &self.near {
            None => self.directions,
            Some((m, z)) => {
                let depth = z.get(pixel).map_or(m.mean_distance, |&v| v as f64);
                m.vectors(pixel % self.width, pixel / self.width, depth, &mut self.buf);
                &self.buf
            }
        }
    }
}

/// Rounds of the near-light alternation (estimate → integrate → update X) at most; 3–5 settle
/// rigs at a few hundred millimetres (ALGORITHMS.md §9).
pub const MAX_ROUNDS: usize = 5;
/// The alternation stops when the mean |ΔZ| of a round falls below this share of the mean
/// distance (0.1%: 0.3 mm at 300 mm, a tenth of a degree of light direction).
pub const DEPTH_TOLERANCE: f64 = 1e-3;

#[inline]
pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub(crate) fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> NearLights {
        let cam = Camera::new(768.0, 768.0, 127.5, 127.5).unwrap();
        NearLights::new(
            cam,
            vec![[100.0, 0.0, 0.0], [0.0, 100.0, -50.0], [-80.0, -60.0, 0.0]],
            None,
            Some(vec![0.0, 1.0, 2.0]),
            300.0,
        )
        .unwrap()
    }

    #[test]
    fn brightness_is_one_at_the_centre_and_follows_the_inverse_square() {
        let m = rig();
        let c = [0.0, 0.0, -300.0];
        for k in 0..3 {
            let (l, b) = m.light_at_point(k, c);
            assert!((b - 1.0).abs() < 1e-12);
            let d = sub(m.positions[k], c);
            let r = norm(d);
            for i in 0..3 {
                assert!((l[i] - d[i] / r).abs() < 1e-12);
            }
        }
        // Isotropic light 0: moving the point to twice... a point on the axis further away.
        let s = m.positions[0];
        let a = m.axes[0];
        let r0 = norm(sub(s, c));
        let far = [
            s[0] + 2.0 * r0 * a[0],
            s[1] + 2.0 * r0 * a[1],
            s[2] + 2.0 * r0 * a[2],
        ];
        let (_, b) = m.light_at_point(0, far);
        assert!((b - 0.25).abs() < 1e-9, "{b}");
    }

    #[test]
    fn anisotropy_falls_as_cos_mu_off_the_axis() {
        let m = rig();
        let k = 2; // μ = 2
        let s = m.positions[k];
        let a = m.axes[k];
        // A point at distance r0 on a direction 30° off the axis.
        let r0 = norm(sub(s, [0.0, 0.0, -300.0]));
        let perp = {
            let t = [a[1], -a[0], 0.0];
            let n = norm(t);
            [t[0] / n, t[1] / n, 0.0]
        };
        let (c30, s30) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let dir = [
            c30 * a[0] + s30 * perp[0],
            c30 * a[1] + s30 * perp[1],
            c30 * a[2] + s30 * perp[2],
        ];
        let x = [s[0] + r0 * dir[0], s[1] + r0 * dir[1], s[2] + r0 * dir[2]];
        let (_, b) = m.light_at_point(k, x);
        assert!((b - c30 * c30).abs() < 1e-9, "{b}");
    }

    #[test]
    fn rays_project_back_to_their_pixels() {
        let m = rig();
        for &(col, row) in &[(0.0, 0.0), (200.0, 31.0), (127.5, 127.5)] {
            let r = m.camera.ray(col, row);
            let x = [r[0] * 290.0, r[1] * 290.0, r[2] * 290.0];
            let (c, rr) = m.camera.project(x).unwrap();
            assert!((c - col).abs() < 1e-9 && (rr - row).abs() < 1e-9);
        }
    }

    #[test]
    fn inconsistent_rigs_are_refused_with_the_light_named() {
        let cam = Camera::new(768.0, 768.0, 127.5, 127.5).unwrap();
        let e = NearLights::new(cam, vec![[0.0, 0.0, -400.0]; 3], None, None, 300.0)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("light 1") && e.contains("behind the object"),
            "{e}"
        );
        let e = NearLights::new(cam, vec![[0.0, 0.0, 0.0]; 3], None, None, -1.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("distance"), "{e}");
        let e = NearLights::new(
            cam,
            vec![[0.0, 10.0, 0.0]; 3],
            Some(vec![[0.0, 0.0, 1.0]; 3]),
            None,
            300.0,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("points away"), "{e}");
        assert!(Camera::new(0.0, 1.0, 0.0, 0.0).is_err());
    }
}
