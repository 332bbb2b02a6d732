//! Shadows of near point lights (ALGORITHMS.md §9): attached where the surface faces away
//! from an LED, cast where the segment from the surface point toward the LED passes behind the
//! surface as the camera sees it.

use super::{ShadowMaps, ShadowParams, Window};
use crate::base::error::{Error, Result};
use crate::model::lightmodel::{norm, sub, NearLights};
use rayon::prelude::*;

/// Shadow maps of near point lights from a depth map Z (mm along the optical axis, full frame,
/// NaN outside the mask) and shading normals (full frame): attached where n · l_k(p) ≤
/// `attached_tolerance`, cast where the segment from X(p) toward the LED passes behind the
/// surface as the camera sees it (a ray march in steps of about one pixel; the surface hides
/// the point when it is nearer the camera by more than `cast_tolerance_px` pixels of depth).
/// Only mask pixels cast shadows. The result has the layout of [`ShadowMaps`].
///
/// Only the bounding box of the pixels with a depth is visited, and a march stops where its
/// image point leaves that box (widened by the pixel the bilinear look-up reaches): the image
/// of the segment is a segment walked in one direction, so it never comes back, and outside
/// the box no depth can hide the light. The flags are those of the whole frame's march, bit
/// for bit (`near_window_tests`). A step skips the look-up where the least depth of the
/// 8 × 8 pixel cell it falls in cannot hide the light.
pub fn near_shadow_maps(
    near: &NearLights,
    depth: &[f32],
    normals: &[[f32; 3]],
    mask: &[bool],
    width: usize,
    height: usize,
    params: &ShadowParams,
) -> Result<ShadowMaps> {
    let hw = width * height;
    if depth.len() != hw || normals.len() != hw || mask.len() != hw {
        return Err(Error::invalid(format!(
            "near shadows: depth {}, normals {} and mask {} values for a {width}×{height} image",
            depth.len(),
            normals.len(),
            mask.len()
        )));
    }
    let ok = |i: usize| mask[i] && depth[i].is_finite() && depth[i] > 0.0;
    let window = Window::of(width, height, ok);
    Ok(near_shadow_maps_in(
        near, depth, normals, mask, width, height, params, window, true,
    ))
}

/// [`near_shadow_maps`] over `window` (`None`: no pixel with a depth), which must hold every
/// pixel with a depth; checked inputs. `cell_skip`: a step skips the look-up where no depth it
/// could read is near enough to hide the light (the flags do not change).
#[allow(clippy::too_many_arguments)]
fn near_shadow_maps_in(
    near: &NearLights,
    depth: &[f32],
    normals: &[[f32; 3]],
    mask: &[bool],
    width: usize,
    height: usize,
    params: &ShadowParams,
    window: Option<Window>,
    cell_skip: bool,
) -> ShadowMaps {
    let hw = width * height;
    let n = near.len();
    let Some(window) = window else {
        return ShadowMaps::empty(width, height, n);
    };
    let ok = |i: usize| mask[i] && depth[i].is_finite() && depth[i] > 0.0;
    // Beyond these image positions the look-up below finds no depth (its 2×2 block and its
    // nearest pixel lie outside the window).
    let (c_lo, c_hi) = (window.col0 as f64 - 1.0, window.col1 as f64);
    let (r_lo, r_hi) = (window.row0 as f64 - 1.0, window.row1 as f64);
    let z_min = (0..hw)
        .filter(|&i| ok(i))
        .map(|i| depth[i] as f64)
        .fold(f64::INFINITY, f64::min);
    let cam = &near.camera;
    let f = cam.fx.min(cam.fy);
    // Per cell of CELL × CELL pixels, the least depth the look-up below can read from an image
    // position in the cell (its pixels and the next row and column: the 2×2 block and the
    // nearest pixel of a position lie there); ∞ where none has a depth.
    const CELL: usize = 8;
    let (cells_w, cells_h) = (width.div_ceil(CELL), height.div_ceil(CELL));
    let cell_min: Vec<f64> = (0..cells_w * cells_h)
        .map(|j| {
            let (cr, cc) = (j / cells_w * CELL, j % cells_w * CELL);
            let mut m = f64::INFINITY;
            for r in cr..(cr + CELL + 1).min(height) {
                for c in cc..(cc + CELL + 1).min(width) {
                    if ok(r * width + c) {
                        m = m.min(depth[r * width + c] as f64);
                    }
                }
            }
            m
        })
        .collect();
    // The surface's depth at image position (col, row): bilinear over mask pixels, nearest
    // where the 2×2 block leaves the mask; None outside it.
    let surface_at = |c: f64, r: f64| -> Option<f64> {
        if c < 0.0 || r < 0.0 || c > (width - 1) as f64 || r > (height - 1) as f64 {
            return None;
        }
        let (c0, r0) = (c.floor() as usize, r.floor() as usize);
        let (c1, r1) = ((c0 + 1).min(width - 1), (r0 + 1).min(height - 1));
        let (fc, fr) = (c - c0 as f64, r - r0 as f64);
        let ids = [
            r0 * width + c0,
            r0 * width + c1,
            r1 * width + c0,
            r1 * width + c1,
        ];
        if ids.iter().all(|&i| ok(i)) {
            let d = |i: usize| depth[ids[i]] as f64;
            Some(
                (1.0 - fr) * ((1.0 - fc) * d(0) + fc * d(1)) + fr * ((1.0 - fc) * d(2) + fc * d(3)),
            )
        } else {
            let i =
                (r.round() as usize).min(height - 1) * width + (c.round() as usize).min(width - 1);
            ok(i).then(|| depth[i] as f64)
        }
    };
    // Light k's flags at mask pixel i with a depth: attached by its normal, cast by a march
    // toward the LED.
    let flags_at = |k: usize, i: usize| -> u8 {
        let s = near.positions[k];
        let mut o = 0u8;
        let z = depth[i] as f64;
        let x = near.point(i % width, i / width, z);
        let d = sub(s, x);
        let dist = norm(d);
        let l = [d[0] / dist, d[1] / dist, d[2] / dist];
        let nrm = normals[i];
        let ndl = l[0] * nrm[0] as f64 + l[1] * nrm[1] as f64 + l[2] * nrm[2] as f64;
        if nrm != [0.0; 3] && ndl <= params.attached_tolerance {
            o |= ShadowMaps::ATTACHED;
        }
        // March: one pixel's footprint at this depth per step.
        let step = z / f;
        let tol = params.cast_tolerance_px * step;
        let mut t = 1.5 * step;
        while t < dist {
            let p = [x[0] + t * l[0], x[1] + t * l[1], x[2] + t * l[2]];
            let pz = -p[2];
            if pz < z_min - tol {
                break;
            }
            let Some((c, r)) = cam.project(p) else { break };
            if c < c_lo || c > c_hi || r < r_lo || r > r_hi {
                break;
            }
            // No depth the look-up can read here is nearer than the ray by the tolerance
            // (with a margin far above the rounding of its bilinear mean): nothing to read.
            if cell_skip && c >= 0.0 && r >= 0.0 {
                let (cc, cr) = (c as usize / CELL, r as usize / CELL);
                if cc < cells_w
                    && cr < cells_h
                    && cell_min[cr * cells_w + cc] > pz - tol + 1e-9 * pz
                {
                    t += pz / f;
                    continue;
                }
            }
            match surface_at(c, r) {
                Some(zs) if zs < pz - tol => {
                    o |= ShadowMaps::CAST;
                    break;
                }
                _ => {}
            }
            t += pz / f;
        }
        o
    };
    // Light by light, rows in parallel within each light.
    ShadowMaps::build(width, height, n, |k, out| {
        out[window.row0 * width..window.row1 * width]
            .par_chunks_mut(width)
            .enumerate()
            .for_each(|(r, out_row)| {
                let first = (window.row0 + r) * width;
                for (col, o) in out_row
                    .iter_mut()
                    .enumerate()
                    .take(window.col1)
                    .skip(window.col0)
                {
                    if ok(first + col) {
                        *o = flags_at(k, first + col);
                    }
                }
            });
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::lightmodel::Camera;

    /// The march over the bounding box of the pixels with a depth, stopping where it leaves the
    /// box and skipping the look-ups of cells too far from the camera, gives bit for bit the flags of the march over the whole frame that stops only at
    /// the image's edge and reads the depth at every step: on blocks standing on a masked, tilted ground with a hole, off the
    /// image's centre, walls along the box's edges, for LEDs on every side of the lens, near it and wide of it, level with
    /// the camera and toward the object.
    #[test]
    fn the_bounding_box_march_equals_the_whole_frame_march() {
        let (w, h) = (61, 47);
        let cam = Camera::new(120.0, 118.0, 29.3, 24.1).unwrap();
        let d = 300.0;
        let mut depth = vec![f32::NAN; w * h];
        let mut mask = vec![false; w * h];
        for r in 9..40 {
            for c in 14..55 {
                let hole = (r - 30) * (r - 30) + (c - 22) * (c - 22) < 10;
                if hole {
                    continue;
                }
                // Ground tilted along both axes, two blocks (one tall, one low).
                let mut z = d + 0.4 * (c as f64 - 30.0) - 0.25 * (r as f64 - 24.0);
                if (15..24).contains(&r) && (30..38).contains(&c) {
                    z -= 45.0;
                }
                if (28..35).contains(&r) && (40..52).contains(&c) {
                    z -= 12.0;
                }
                // Walls on the box's edges: rays that graze them from just outside the box
                // find them by the nearest-pixel look-up.
                if c < 16 && r > 20 || c > 52 && r < 30 || r < 11 && c > 24 || r > 37 && c < 40 {
                    z -= 30.0;
                }
                depth[r * w + c] = z as f32;
                mask[r * w + c] = true;
            }
        }
        // One mask pixel without a depth: masked but never marched.
        depth[20 * w + 50] = f32::NAN;
        let normals = vec![[0.0f32, 0.0, 1.0]; w * h];
        let mut positions = Vec::new();
        for t in 0..16 {
            let phi = t as f64 * std::f64::consts::PI / 8.0 + 0.05;
            let radius = [40.0, 120.0, 260.0, 600.0][t % 4];
            let z = [0.0, -60.0, -150.0, -5.0][(t / 4) % 4];
            positions.push([radius * phi.cos(), radius * phi.sin(), z]);
        }
        let near = NearLights::new(cam, positions, None, None, d).unwrap();
        let params = ShadowParams::default();
        let bbox = near_shadow_maps(&near, &depth, &normals, &mask, w, h, &params).unwrap();
        let whole = Window {
            row0: 0,
            row1: h,
            col0: 0,
            col1: w,
        };
        let reference = near_shadow_maps_in(
            &near,
            &depth,
            &normals,
            &mask,
            w,
            h,
            &params,
            Some(whole),
            false,
        );
        let cast = |m: &ShadowMaps| m.count(ShadowMaps::CAST);
        for k in 0..near.len() {
            let (a, b) = (bbox.flags_of(k), reference.flags_of(k));
            let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
            assert_eq!(differ, 0, "light {k}: {differ} flags differ");
        }
        assert!(
            cast(&reference) > 500,
            "the blocks cast shadows: {}",
            cast(&reference)
        );
        // No pixel with a depth: nothing to march, every flag zero.
        let none = near_shadow_maps(
            &near,
            &vec![f32::NAN; w * h],
            &normals,
            &mask,
            w,
            h,
            &params,
        )
        .unwrap();
        assert_eq!(none.count(ShadowMaps::ATTACHED | ShadowMaps::CAST), 0);
    }
}
