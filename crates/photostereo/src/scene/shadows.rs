//! Cast shadows by ray marching against a scene's height field (bilinear heights, pixel
//! units). This is deliberately a different method from the horizon sweep an estimator may use,
//! so that errors in one cannot cancel errors in the other.
//!
//! A pixel is in the cast shadow of a light when the height field of the object (mask pixels
//! only: the background casts nothing) rises above the ray from the pixel's surface point toward
//! the light, sampled every `step` pixels of horizontal travel.

use super::Scene;
use rayon::prelude::*;

/// Horizontal step of the renderer's ray march, pixels.
pub const RENDER_STEP_PX: f64 = 0.25;

/// Rays start this far (pixels) above the surface, so that a surface does not shadow itself
/// through rounding.
const RAY_OFFSET: f64 = 1e-4;

/// Sides (as powers of two: 16 and 4 pixels) of the coarse and fine tiles whose maximum heights
/// let [`cast_shadows`] skip empty space.
const COARSE_SHIFT: u32 = 4;
const FINE_SHIFT: u32 = 2;
/// The bilinear cells themselves (side 1): a sample is skipped when the ray is above its
/// cell's four corners by more than [`CELL_MARGIN`] (relative), so that the rounding of the
/// bilinear mean can never matter.
const CELL_SHIFT: u32 = 0;
const CELL_MARGIN: f64 = 1e-9;

/// Bilinear height at fractional (row, col); `None` outside the frame or when a corner of the
/// cell is outside the mask.
fn height_at(scene: &Scene, row: f64, col: f64) -> Option<f64> {
    if row < 0.0 || col < 0.0 || row > (scene.height - 1) as f64 || col > (scene.width - 1) as f64 {
        return None;
    }
    // Non-negative here, so truncation is the floor (and avoids a libm call).
    let r0 = row as usize;
    let c0 = col as usize;
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

/// The ray's direction per unit of horizontal travel: (d row, d col, d z), or `None` for a light
/// on the viewing axis (no cast shadows) or at or below the horizon.
fn ray_steps(light: [f64; 3]) -> Option<(f64, f64, f64)> {
    let horiz = (light[0] * light[0] + light[1] * light[1]).sqrt();
    if horiz < 1e-9 || light[2] <= 0.0 {
        return None;
    }
    // Columns grow with x, rows shrink with y.
    Some((-light[1] / horiz, light[0] / horiz, light[2] / horiz))
}

fn max_mask_height(scene: &Scene) -> f64 {
    scene
        .depth
        .iter()
        .zip(&scene.mask)
        .filter(|(_, &m)| m)
        .map(|(&h, _)| h as f64)
        .fold(f64::NEG_INFINITY, f64::max)
}

fn outside_frame(scene: &Scene, row: f64, col: f64) -> bool {
    row < 0.0 || col < 0.0 || row > (scene.height - 1) as f64 || col > (scene.width - 1) as f64
}

/// Cast-shadow flags (row-major) for one light by a plain ray march: from every mask pixel,
/// samples at t = step, 2·step, … pixels of horizontal travel until the ray is above the highest
/// point of the object or leaves the frame. The reference for [`cast_shadows`]. Lights at or
/// below the horizon give no cast shadow (they are attached shadows everywhere).
pub fn ray_march_shadows(scene: &Scene, light: [f64; 3], step: f64) -> Vec<bool> {
    let mut out = vec![false; scene.width * scene.height];
    let Some((dr, dc, dz)) = ray_steps(light) else {
        return out;
    };
    let max_h = max_mask_height(scene);
    out.par_chunks_mut(scene.width)
        .enumerate()
        .for_each(|(row, out_row)| {
            for (col, o) in out_row.iter_mut().enumerate() {
                if !scene.mask[row * scene.width + col] {
                    continue;
                }
                let h0 = scene.depth[row * scene.width + col] as f64;
                let mut k = 1u64;
                loop {
                    let t = k as f64 * step;
                    let z = h0 + RAY_OFFSET + dz * t;
                    if z > max_h {
                        break;
                    }
                    let (r, c) = (row as f64 + dr * t, col as f64 + dc * t);
                    if outside_frame(scene, r, c) {
                        break;
                    }
                    if matches!(height_at(scene, r, c), Some(h) if h > z) {
                        *o = true;
                        break;
                    }
                    k += 1;
                }
            }
        });
    out
}

/// Cast-shadow flags for one light, identical to `ray_march_shadows(scene, light, 0.25)` but
/// faster: samples inside a tile whose highest point (cell corners included) is below the ray
/// are skipped, which cannot change the result because the ray only rises.
pub fn cast_shadows(scene: &Scene, light: [f64; 3]) -> Vec<bool> {
    cast_shadows_where(scene, light, None)
}

/// [`cast_shadows`] restricted to the pixels where `wanted` is true (all mask pixels when
/// `None`); the others are reported unshadowed.
pub(crate) fn cast_shadows_where(
    scene: &Scene,
    light: [f64; 3],
    wanted: Option<&[bool]>,
) -> Vec<bool> {
    cast_shadows_in(scene, &ShadowField::new(scene), light, wanted)
}

/// What the ray march of a scene needs for any light, built once per scene and shared by its
/// lights: the heights of mask pixels (NaN elsewhere, so one look-up tells a cell's corners
/// and whether they are all in the mask), the highest mask point, and the tiles' maxima.
pub(crate) struct ShadowField {
    /// Height of each mask pixel, pixel units; NaN outside the mask.
    masked: Vec<f32>,
    max_h: f64,
    coarse: TileMax,
    fine: TileMax,
    /// Per cell: the highest of its four corners plus the margin; −∞ where a corner is
    /// outside the mask (no sample there can hit).
    cell: Vec<f64>,
    /// Per coarse tile and direction quadrant ([`quadrant`]): the highest point of the tiles a
    /// ray in that quadrant can still reach from the tile (itself and those at or beyond it
    /// on both axes), plus the margin. A ray above it never meets the surface again.
    ahead: [Vec<f64>; 4],
}

/// The quadrant of a ray's direction: rows growing (`dr` ≥ 0) and columns growing (`dc` ≥ 0)
/// as bits 0 and 1.
#[inline]
fn quadrant(dr: f64, dc: f64) -> usize {
    (dr >= 0.0) as usize | ((dc >= 0.0) as usize) << 1
}

/// [`ShadowField::ahead`] for one quadrant `q`.
fn ahead_of(coarse: &TileMax, rows: usize, q: usize) -> Vec<f64> {
    let cols = coarse.cols;
    let mut out = coarse.max.clone();
    let (down, right) = (q & 1 == 1, q & 2 == 2);
    let order = |n: usize, forward: bool| -> Vec<usize> {
        // Tiles farther along the direction first.
        if forward {
            (0..n).rev().collect()
        } else {
            (0..n).collect()
        }
    };
    for &tr in &order(rows, down) {
        for &tc in &order(cols, right) {
            let mut m = out[tr * cols + tc];
            let next_r = if down { tr + 1 } else { tr.wrapping_sub(1) };
            let next_c = if right { tc + 1 } else { tc.wrapping_sub(1) };
            if next_r < rows {
                m = m.max(out[next_r * cols + tc]);
            }
            if next_c < cols {
                m = m.max(out[tr * cols + next_c]);
            }
            out[tr * cols + tc] = m;
        }
    }
    for m in &mut out {
        *m += CELL_MARGIN * (1.0 + m.abs());
    }
    out
}

impl ShadowField {
    pub(crate) fn new(scene: &Scene) -> Self {
        let coarse = TileMax::new(scene, COARSE_SHIFT);
        let rows = scene.height.div_ceil(1 << COARSE_SHIFT);
        let ahead = [0, 1, 2, 3].map(|q| ahead_of(&coarse, rows, q));
        ShadowField {
            masked: scene
                .depth
                .iter()
                .zip(&scene.mask)
                .map(|(&d, &m)| if m { d } else { f32::NAN })
                .collect(),
            max_h: max_mask_height(scene),
            coarse,
            fine: TileMax::new(scene, FINE_SHIFT),
            cell: cell_bounds(scene),
            ahead,
        }
    }
}

/// [`cast_shadows_where`] with the scene's [`ShadowField`] given.
pub(crate) fn cast_shadows_in(
    scene: &Scene,
    field: &ShadowField,
    light: [f64; 3],
    wanted: Option<&[bool]>,
) -> Vec<bool> {
    let step = RENDER_STEP_PX;
    let (w, hgt) = (scene.width, scene.height);
    let mut out = vec![false; w * hgt];
    let Some((dr, dc, dz)) = ray_steps(light) else {
        return out;
    };
    let max_h = field.max_h;
    let (coarse, fine, cell) = (&field.coarse, &field.fine, field.cell.as_slice());
    // Travel per unit of row and column (∞ along an axis the ray does not move on).
    let inv = |d: f64| {
        if d.abs() > 1e-12 {
            1.0 / d
        } else {
            f64::INFINITY
        }
    };
    let (inv_dr, inv_dc) = (inv(dr), inv(dc));
    let ahead = field.ahead[quadrant(dr, dc)].as_slice();
    let masked = field.masked.as_slice();
    let (last_row, last_col) = ((hgt - 1) as f64, (w - 1) as f64);
    // Bilinear height at (r, c) inside the frame, as `height_at` computes it: `None` when a
    // corner of the cell is outside the mask (NaN there).
    // (r0, c0) = (⌊r⌋, ⌊c⌋), the cell.
    let height_in = |r: f64, c: f64, r0: usize, c0: usize| -> Option<f64> {
        let r1 = (r0 + 1).min(hgt - 1);
        let c1 = (c0 + 1).min(w - 1);
        let (a, b) = (masked[r0 * w + c0], masked[r0 * w + c1]);
        let (cc, d) = (masked[r1 * w + c0], masked[r1 * w + c1]);
        if a.is_nan() || b.is_nan() || cc.is_nan() || d.is_nan() {
            return None;
        }
        let fr = r - r0 as f64;
        let fc = c - c0 as f64;
        Some(
            a as f64 * (1.0 - fr) * (1.0 - fc)
                + b as f64 * (1.0 - fr) * fc
                + cc as f64 * fr * (1.0 - fc)
                + d as f64 * fr * fc,
        )
    };
    out.par_chunks_mut(w)
        .enumerate()
        .for_each(|(row, out_row)| {
            for (col, o) in out_row.iter_mut().enumerate() {
                let i = row * w + col;
                if !scene.mask[i] || wanted.is_some_and(|m| !m[i]) {
                    continue;
                }
                let h0 = scene.depth[i] as f64;
                // Signed integers throughout: their conversions to and from f64 are single
                // instructions (the values are far from the ranges where they differ).
                let mut k = 1i64;
                loop {
                    let t = k as f64 * step;
                    let z = h0 + RAY_OFFSET + dz * t;
                    if z > max_h {
                        break;
                    }
                    let (r, c) = (row as f64 + dr * t, col as f64 + dc * t);
                    if r < 0.0 || c < 0.0 || r > last_row || c > last_col {
                        break;
                    }
                    // Non-negative here: truncation is the floor.
                    let (ri, ci) = (r as i64 as usize, c as i64 as usize);
                    // Above everything the ray can still reach: lit (the ray only rises).
                    if z > ahead[(ri >> COARSE_SHIFT) * coarse.cols + (ci >> COARSE_SHIFT)] {
                        break;
                    }
                    let skip_shift = if z > coarse.max_at(ri, ci) {
                        Some(COARSE_SHIFT)
                    } else if z > fine.max_at(ri, ci) {
                        Some(FINE_SHIFT)
                    } else if z > cell[ri * w + ci] {
                        Some(CELL_SHIFT)
                    } else {
                        None
                    };
                    if let Some(shift) = skip_shift {
                        // Horizontal travel to the tile's far side along the ray; the samples
                        // before it are inside the tile, below the ray.
                        let exit = exit_along(r, inv_dr, ri >> shift, shift).min(exit_along(
                            c,
                            inv_dc,
                            ci >> shift,
                            shift,
                        ));
                        // Jump to the first sample at or past the exit (less a margin far above
                        // rounding): every sample skipped lies strictly inside the tile.
                        let x = ((exit - 1e-7) / step).max(0.0);
                        let whole = x as i64; // truncation = floor here, without a libm call
                        let jump = if (whole as f64) < x { whole + 1 } else { whole };
                        k += jump.max(1);
                        continue;
                    }
                    if matches!(height_in(r, c, ri, ci), Some(h) if h > z) {
                        *o = true;
                        break;
                    }
                    k += 1;
                }
            }
        });
    out
}

/// Travel (pixels along the ray's horizontal direction) from coordinate `x` until it leaves
/// tile number `index` (of side 2^`shift`) on its axis, given the travel per unit of that axis
/// `inv_d` (the reciprocal of the ray's step on it; ∞ when the ray does not move on it).
#[inline]
fn exit_along(x: f64, inv_d: f64, index: usize, shift: u32) -> f64 {
    let lo = (index << shift) as f64;
    let hi = lo + (1usize << shift) as f64;
    if inv_d.is_infinite() {
        f64::INFINITY
    } else if inv_d > 0.0 {
        (hi - x) * inv_d
    } else {
        (lo - x) * inv_d
    }
}

/// Per bilinear cell (top-left pixel (r, c), corners up to the next row and column, clamped
/// at the frame's edge): the highest corner raised by [`CELL_MARGIN`], or −∞ when a corner is
/// outside the mask.
fn cell_bounds(scene: &Scene) -> Vec<f64> {
    let (w, h) = (scene.width, scene.height);
    let mut out = vec![f64::NEG_INFINITY; w * h];
    for r in 0..h {
        let r1 = (r + 1).min(h - 1);
        for c in 0..w {
            let c1 = (c + 1).min(w - 1);
            let ids = [r * w + c, r * w + c1, r1 * w + c, r1 * w + c1];
            if ids.iter().all(|&i| scene.mask[i]) {
                let m = ids
                    .iter()
                    .map(|&i| scene.depth[i] as f64)
                    .fold(f64::NEG_INFINITY, f64::max);
                out[r * w + c] = m + CELL_MARGIN * (1.0 + m.abs());
            }
        }
    }
    out
}

/// Maximum height of mask pixels per tile, over the tile's pixels and the next row and column
/// (the corners a bilinear sample inside the tile may use); −∞ for tiles without mask pixels.
struct TileMax {
    shift: u32,
    cols: usize,
    max: Vec<f64>,
}

impl TileMax {
    fn new(scene: &Scene, shift: u32) -> Self {
        let tile = 1usize << shift;
        let rows = scene.height.div_ceil(tile);
        let cols = scene.width.div_ceil(tile);
        let mut max = vec![f64::NEG_INFINITY; rows * cols];
        for tr in 0..rows {
            for tc in 0..cols {
                let mut m = f64::NEG_INFINITY;
                for r in tr * tile..((tr + 1) * tile + 1).min(scene.height) {
                    for c in tc * tile..((tc + 1) * tile + 1).min(scene.width) {
                        let i = r * scene.width + c;
                        if scene.mask[i] {
                            m = m.max(scene.depth[i] as f64);
                        }
                    }
                }
                max[tr * cols + tc] = m;
            }
        }
        TileMax { shift, cols, max }
    }

    /// The bound for a bilinear sample whose cell's top-left pixel is (row, col).
    #[inline]
    fn max_at(&self, row: usize, col: usize) -> f64 {
        self.max[(row >> self.shift) * self.cols + (col >> self.shift)]
    }
}
