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

/// Gradients of ln Z (per pixel) from a normal map seen through `camera`, over `mask` (default:
/// non-zero normals). Normals facing away from their ray (n · r ≥ 0) are dropped and counted
/// as back-facing.
pub fn log_depth_gradients(
    width: usize,
    height: usize,
    normals: &[[f32; 3]],
    mask: Option<&[bool]>,
    camera: &Camera,
    max_slope: f32,
) -> Result<Gradients> {
    // Reuse the orthographic checks (lengths, invalid normals), then replace the gradients.
    let mut g = super::gradients_from_normals(width, height, normals, mask, f32::MAX)?;
    if !(max_slope > 0.0 && max_slope.is_finite()) {
        return Err(Error::invalid(format!(
            "max_slope {max_slope}: expected a positive finite number"
        )));
    }
    let cap = max_slope as f64;
    let mut capped = 0;
    let mut backfacing = 0;
    for (i, n) in normals.iter().enumerate() {
        if !g.mask[i] {
            continue;
        }
        let (nx, ny, nz) = (n[0] as f64, n[1] as f64, n[2] as f64);
        let r = camera.ray((i % width) as f64, (i / width) as f64);
        let nr = nx * r[0] + ny * r[1] + nz * r[2];
        if nr >= -1e-9 {
            g.mask[i] = false;
            g.p[i] = 0.0;
            g.q[i] = 0.0;
            backfacing += 1;
            continue;
        }
        let a = -nx / nr;
        let b = ny / nr;
        if a.abs() > cap || b.abs() > cap {
            capped += 1;
        }
        g.p[i] = (a.clamp(-cap, cap) / camera.fx) as f32;
        g.q[i] = (b.clamp(-cap, cap) / camera.fy) as f32;
    }
    g.capped = capped;
    g.rejected_backfacing += backfacing;
    Ok(g)
}

/// Integrates a normal map seen through `camera` into Z (mm along the optical axis, NaN outside
/// the integrated pixels), the mean of Z over them equal to `mean_distance`. The curl map is
/// that of the log-depth gradients (per pixel, dimensionless).
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
    let (curl, mean_abs_curl) = curl_map(width, height, &g.p, &g.q, &g.mask);
    let problem = IntegrationProblem {
        weights,
        ..IntegrationProblem::new(width, height, &g.p, &g.q, &g.mask)
    };
    let mut depth = integrator.integrate(&problem, progress)?;
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
    use crate::geometry::integrate::{Poisson, DEFAULT_MAX_SLOPE};

    /// A sphere cap of radius 40 mm centred 330 mm away on the axis, seen by a 20° camera:
    /// Z(ray) solved exactly; its normals are (X − C)/R.
    fn sphere(size: usize) -> (Camera, Vec<[f32; 3]>, Vec<f32>, Vec<bool>) {
        let f = size as f64 * 3.0;
        let c = (size as f64 - 1.0) / 2.0;
        let cam = Camera::new(f, f * 1.01, c + 3.0, c - 2.0).unwrap();
        let centre = [4.0, -3.0, -330.0];
        let radius = 40.0;
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
            // Keep the part whose normals are within 70° of the ray (well-conditioned).
            let cos = -(n[0] * r[0] + n[1] * r[1] + n[2] * r[2]) / a.sqrt();
            if cos < 0.35 {
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
}
