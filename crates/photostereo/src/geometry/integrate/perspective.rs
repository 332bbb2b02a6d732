//! Perspective integration (ALGORITHMS.md §9): normals seen through a pinhole camera to the
//! depth Z along the optical axis, in millimetres.
//!
//! With X(p) = Z(p) · r(p), r = ((u − c_x)/f_x, −(v − c_y)/f_y, −1) (CONVENTIONS.md), the
//! tangency conditions n · ∂X/∂u = n · ∂X/∂v = 0 give, for z̃ = ln Z,
//!
//! ∂z̃/∂col = −n_x / (f_x · (n · r)),  ∂z̃/∂row = +n_y / (f_y · (n · r)),
//!
//! linear in z̃ (n · r < 0 on a visible surface). The same masked solver as the orthographic
//! case integrates z̃ (any mask, weights, multigrid); Z = exp(z̃ + c) with c set so that the
//! mean of Z over the integrated pixels is the given mean distance D. Slopes are capped as in
//! the orthographic case: |n_x / (n · r)| and |n_y / (n · r)| (height per pixel over depth per
//! pixel) at `max_slope`.

use super::{curl_map, Gradients, IntegrationProblem, Integrator, Surface};
use crate::base::error::{Error, Result};
use crate::base::progress::Progress;
use crate::model::lightmodel::Camera;
use rayon::prelude::*;

/// The scale `f̄ = √(f_x f_y)` (pixels) by which the log-depth gradients are multiplied: the
/// integrated `f̄ · ln Z` changes by one where the depth changes by `Z / f̄`, the size of a
/// pixel at that depth, so its gradients, curl and jumps read in pixels as in the orthographic
/// case (and the same discontinuity threshold serves both).
pub fn log_depth_scale(camera: &Camera) -> f64 {
    (camera.fx * camera.fy).sqrt()
}

/// Gradients of `f̄ · ln Z` ([`log_depth_scale`]) per pixel from a normal map seen through
/// `camera`, over `mask` (default: [`super::default_mask`]). A normal is usable when it faces
/// the camera along its own ray (`n · r < 0`), whatever the sign of its `n_z`; the others are
/// dropped and counted as back-facing. The height-like slopes `n_x / (n · r)` and
/// `n_y / (n · r)` are capped at `max_slope`.
pub fn log_depth_gradients(
    width: usize,
    height: usize,
    normals: &[[f32; 3]],
    mask: Option<&[bool]>,
    camera: &Camera,
    max_slope: f32,
) -> Result<Gradients> {
    let scale = log_depth_scale(camera);
    let to_log = [scale / camera.fx, scale / camera.fy];
    super::gradients_with(
        width,
        height,
        normals,
        mask,
        max_slope,
        to_log,
        |i, [nx, ny, nz]| {
            let r = camera.ray((i % width) as f64, (i / width) as f64);
            let nr = nx * r[0] + ny * r[1] + nz * r[2];
            // f_x ∂z̃/∂col = −n_x / (n · r), f_y ∂z̃/∂row = n_y / (n · r) (the module notes).
            (nr < -1e-9).then(|| (-nx / nr, ny / nr))
        },
    )
}

/// Integrates a normal map seen through `camera` into Z (mm along the optical axis, NaN outside
/// the integrated pixels), the mean of Z over them equal to `mean_distance`. The integrator
/// sees the gradients of `f̄ · ln Z` ([`log_depth_gradients`]), and the curl map is theirs: in
/// pixels, like the orthographic one.
#[allow(clippy::too_many_arguments)]
pub fn perspective_surface(
    width: usize,
    height: usize,
    normals: &[[f32; 3]],
    mask: Option<&[bool]>,
    weights: Option<&[f32]>,
    camera: &Camera,
    mean_distance: f64,
    integrator: &dyn Integrator,
    max_slope: f32,
    progress: &dyn Progress,
) -> Result<Surface> {
    if !(mean_distance.is_finite() && mean_distance > 0.0) {
        return Err(Error::parameter(
            "distance",
            format!(
                "{mean_distance}: expected the object's mean distance in mm, finite and positive"
            ),
        ));
    }
    let g = log_depth_gradients(width, height, normals, mask, camera, max_slope)?;
    let problem = IntegrationProblem {
        weights,
        ..IntegrationProblem::new(width, height, &g.p, &g.q, &g.mask)
    };
    let mut depth = integrator.integrate(&problem, progress)?;
    // The curl map is made after the solve: not held beside the integrator's work arrays.
    let (curl, mean_abs_curl) = curl_map(width, height, &g.p, &g.q, &g.mask);
    // Back from f̄ · ln Z to ln Z.
    let inv_scale = 1.0 / log_depth_scale(camera);
    depth.values.par_iter_mut().for_each(|v| {
        *v = (*v as f64 * inv_scale) as f32;
    });
    let (sum, count) = depth
        .values
        .iter()
        .filter(|v| v.is_finite())
        .fold((0f64, 0usize), |(s, c), &v| (s + (v as f64).exp(), c + 1));
    if count == 0 {
        return Err(Error::invalid(
            "perspective integration: no pixel to integrate",
        ));
    }
    let shift = mean_distance.ln() - (sum / count as f64).ln();
    depth.values.par_iter_mut().for_each(|v| {
        if v.is_finite() {
            *v = ((*v as f64) + shift).exp() as f32;
        }
    });
    depth
        .stats
        .notes
        .push(format!("perspective: Z in mm, mean {mean_distance} mm"));
    Ok(Surface {
        depth,
        curl,
        mean_abs_curl,
        rejected_invalid: g.rejected_invalid,
        rejected_backfacing: g.rejected_backfacing,
        not_unit: g.not_unit,
        capped: g.capped,
        max_slope,
    })
}

/// Normals of a depth map Z (mm along the optical axis) seen through `camera`: the cross
/// product of the central differences of X = Z · r along the rows and columns (one-sided at the
/// mask's border). Zero outside the mask or where Z is not finite.
pub fn normals_from_z(
    width: usize,
    height: usize,
    z: &[f32],
    mask: &[bool],
    camera: &Camera,
) -> Vec<[f32; 3]> {
    let ok = |i: usize| mask[i] && z[i].is_finite() && z[i] > 0.0;
    let point = |i: usize| {
        let r = camera.ray((i % width) as f64, (i / width) as f64);
        let d = z[i] as f64;
        [d * r[0], d * r[1], d * r[2]]
    };
    let mut out = vec![[0f32; 3]; width * height];
    out.par_chunks_mut(width)
        .enumerate()
        .for_each(|(row, line)| {
            for (col, o) in line.iter_mut().enumerate() {
                let i = row * width + col;
                if !ok(i) {
                    continue;
                }
                let diff = |a: usize, b: usize| {
                    let (pa, pb) = (point(a), point(b));
                    [pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]]
                };
                // ∂X/∂col and −∂X/∂row (toward the image's top, +y); the scale of each is
                // irrelevant, the normal is normalised below.
                let [along_cols, along_rows] = super::difference_pairs(i, width, height, ok);
                let du = along_cols.map_or([1.0, 0.0, 0.0], |(a, b, _)| diff(a, b));
                let dv = along_rows.map_or([0.0, 1.0, 0.0], |(a, b, _)| diff(b, a));
                let n = [
                    du[1] * dv[2] - du[2] * dv[1],
                    du[2] * dv[0] - du[0] * dv[2],
                    du[0] * dv[1] - du[1] * dv[0],
                ];
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                if len > 0.0 && len.is_finite() {
                    *o = [
                        (n[0] / len) as f32,
                        (n[1] / len) as f32,
                        (n[2] / len) as f32,
                    ];
                }
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::progress::Silent;
    use crate::geometry::integrate::{Integrator, Poisson, DEFAULT_MAX_SLOPE};

    /// A sphere cap of radius 40 mm centred 330 mm away on the axis, seen by a 20° camera:
    /// Z(ray) solved exactly; its normals are (X − C)/R.
    fn sphere(size: usize) -> (Camera, Vec<[f32; 3]>, Vec<f32>, Vec<bool>) {
        sphere_seen(size, 3.0, [4.0, -3.0, -330.0], 40.0, 0.35)
    }

    /// A sphere of `radius` mm centred at `centre` seen by a camera of focal length
    /// `focal · size` pixels, where its normals are within acos(`min_cos`) of the rays.
    fn sphere_seen(
        size: usize,
        focal: f64,
        centre: [f64; 3],
        radius: f64,
        min_cos: f64,
    ) -> (Camera, Vec<[f32; 3]>, Vec<f32>, Vec<bool>) {
        let f = size as f64 * focal;
        let c = (size as f64 - 1.0) / 2.0;
        let cam = Camera::new(f, f * 1.01, c + 3.0, c - 2.0).unwrap();
        let mut normals = vec![[0f32; 3]; size * size];
        let mut z = vec![f32::NAN; size * size];
        let mut mask = vec![false; size * size];
        for i in 0..size * size {
            let r = cam.ray((i % size) as f64, (i / size) as f64);
            // |t r − C|² = R²: t² r·r − 2t r·C + C·C − R² = 0, nearer root.
            let a = r[0] * r[0] + r[1] * r[1] + 1.0;
            let b = -2.0 * (r[0] * centre[0] + r[1] * centre[1] + r[2] * centre[2]);
            let cc = centre.iter().map(|v| v * v).sum::<f64>() - radius * radius;
            let disc = b * b - 4.0 * a * cc;
            if disc <= 0.0 {
                continue;
            }
            let t = (-b - disc.sqrt()) / (2.0 * a);
            let x = [t * r[0], t * r[1], t * r[2]];
            let n = [
                (x[0] - centre[0]) / radius,
                (x[1] - centre[1]) / radius,
                (x[2] - centre[2]) / radius,
            ];
            let cos = -(n[0] * r[0] + n[1] * r[1] + n[2] * r[2]) / a.sqrt();
            if cos < min_cos {
                continue;
            }
            normals[i] = [n[0] as f32, n[1] as f32, n[2] as f32];
            z[i] = t as f32;
            mask[i] = true;
        }
        (cam, normals, z, mask)
    }

    #[test]
    fn true_normals_of_a_sphere_give_its_depth_within_half_a_percent_of_the_range() {
        let size = 96;
        let (cam, normals, z, mask) = sphere(size);
        let truth: Vec<f64> = z
            .iter()
            .filter(|v| v.is_finite())
            .map(|&v| v as f64)
            .collect();
        let mean = truth.iter().sum::<f64>() / truth.len() as f64;
        let range = truth.iter().cloned().fold(f64::MIN, f64::max)
            - truth.iter().cloned().fold(f64::MAX, f64::min);
        let s = perspective_surface(
            size,
            size,
            &normals,
            Some(&mask),
            None,
            &cam,
            mean,
            &Poisson::default(),
            DEFAULT_MAX_SLOPE,
            &Silent,
        )
        .unwrap();
        let mut worst = 0f64;
        for i in 0..size * size {
            if mask[i] {
                worst = worst.max((s.depth.values[i] as f64 - z[i] as f64).abs());
            } else {
                assert!(s.depth.values[i].is_nan());
            }
        }
        assert!(
            worst < 0.005 * range,
            "worst {worst} mm of a {range} mm range"
        );
        // Orthographic integration of the same normals misses (the check can fail).
        let back = normals_from_z(size, size, &s.depth.values, &mask, &cam);
        let mut err = 0f64;
        let mut count = 0;
        for i in 0..size * size {
            if mask[i] {
                let d = back[i][0] * normals[i][0]
                    + back[i][1] * normals[i][1]
                    + back[i][2] * normals[i][2];
                err += (d.clamp(-1.0, 1.0) as f64).acos().to_degrees();
                count += 1;
            }
        }
        assert!(
            err / (count as f64) < 1.0,
            "re-derived normals {}°",
            err / count as f64
        );
    }

    #[test]
    fn normals_facing_the_camera_along_their_ray_are_integrated_whatever_their_n_z() {
        // A wide-angle camera (90°) and a sphere off to the side: on its limb toward the axis
        // the normals point away from the optical axis's direction (n_z < 0) yet face their
        // own rays.
        let size = 96;
        let (cam, normals, z, mask) = sphere_seen(size, 0.5, [90.0, 0.0, -100.0], 30.0, 0.08);
        let behind = (0..size * size)
            .filter(|&i| mask[i] && normals[i][2] <= 0.0)
            .count();
        assert!(behind > 10, "{behind} pixels with n_z ≤ 0");
        let mean = {
            let t: Vec<f64> = z
                .iter()
                .filter(|v| v.is_finite())
                .map(|&v| v as f64)
                .collect();
            t.iter().sum::<f64>() / t.len() as f64
        };
        let s = perspective_surface(
            size,
            size,
            &normals,
            Some(&mask),
            None,
            &cam,
            mean,
            &Poisson::default(),
            1000.0,
            &Silent,
        )
        .unwrap();
        assert_eq!(s.rejected_backfacing, 0);
        for (i, &inside) in mask.iter().enumerate() {
            assert_eq!(s.depth.values[i].is_finite(), inside, "pixel {i}");
        }
    }

    #[test]
    fn bilateral_keeps_a_jump_seen_through_the_camera() {
        // A half cylinder (radius 12.5 pixels at the plane's distance) rising out of a plane
        // 300 mm away, its sides level with the plane on row 10 and 0.5 pixel higher on every
        // row below: Z = 300 − (height in pixels) · 300 / f. Normals from X = Z · ray.
        let size = 80;
        let cam = Camera::new(400.0, 404.0, 42.0, 37.0).unwrap();
        let mm = 300.0 / 400.0;
        let radius = 12.5f64;
        let edge = (radius * radius - 144.0f64).sqrt();
        let height = |c: f64, r: f64| {
            let d = c - 40.0;
            let above = 0.5 * (r - 10.0) - edge + (radius * radius - d * d).max(0.0).sqrt();
            if d.abs() < radius {
                above.max(0.0)
            } else {
                0.0
            }
        };
        let point = |c: f64, r: f64| {
            let ray = cam.ray(c, r);
            let z = 300.0 - mm * height(c, r);
            [z * ray[0], z * ray[1], z * ray[2]]
        };
        let n = size * size;
        let mut normals = vec![[0f32; 3]; n];
        let mut truth = vec![0f64; n];
        let e = 1e-5;
        for i in 0..n {
            let (c, r) = ((i % size) as f64, (i / size) as f64);
            let (a, b) = (point(c + e, r), point(c - e, r));
            let du = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
            let (a, b) = (point(c, r - e), point(c, r + e));
            let dv = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
            let m = [
                du[1] * dv[2] - du[2] * dv[1],
                du[2] * dv[0] - du[0] * dv[2],
                du[0] * dv[1] - du[1] * dv[0],
            ];
            let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
            normals[i] = m.map(|v| (v / len) as f32);
            truth[i] = 300.0 - mm * height(c, r);
        }
        let mean = truth.iter().sum::<f64>() / n as f64;
        let range = mm * (0.5 * (size as f64 - 11.0) + radius);
        // The contour pixels (either side of each side) may be claimed by either side.
        let judged = |i: usize| ![27, 28, 52, 53].contains(&(i % size));
        let mut errors = Vec::new();
        for integrator in [
            &Poisson::default() as &dyn Integrator,
            &super::super::Bilateral::default(),
        ] {
            let s = perspective_surface(
                size, size, &normals, None, None, &cam, mean, integrator, 1000.0, &Silent,
            )
            .unwrap();
            // Align the levels (the mean distance includes the contour pixels).
            let ids: Vec<usize> = (0..n).filter(|&i| judged(i)).collect();
            let shift = ids
                .iter()
                .map(|&i| truth[i] - s.depth.values[i] as f64)
                .sum::<f64>()
                / ids.len() as f64;
            let rmse = (ids
                .iter()
                .map(|&i| (s.depth.values[i] as f64 + shift - truth[i]).powi(2))
                .sum::<f64>()
                / ids.len() as f64)
                .sqrt();
            errors.push(rmse / range);
        }
        assert!(
            errors[1] <= 0.005,
            "bilateral: {:.3}% of the range",
            100.0 * errors[1]
        );
        assert!(
            errors[0] >= 10.0 * errors[1],
            "poisson: {:.3}% of the range should be far worse",
            100.0 * errors[0]
        );
    }
}
