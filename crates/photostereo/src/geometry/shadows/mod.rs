//! Attached and cast shadows of a reconstructed height field under distant lights
//! (ALGORITHMS.md §6).
//!
//! Inputs share one layout: a height field `depth` (pixel units, z toward the camera,
//! `height * width` values row-major), an object `mask` of the same size, and light directions
//! as vectors from the surface toward the light in the camera frame (x = +col, y = −row,
//! z toward the camera; they are normalised here). A pixel is *valid* when it is inside the mask
//! and its height is finite; invalid pixels are never marked and cast no shadow (their height is
//! unknown).
//!
//! - Attached shadow: n·l ≤ τ ([`ShadowParams::attached_tolerance`]).
//! - Cast shadow: the height field rises above the ray x + t·l for some t > 0.
//!   [`cast_shadows`] finds it with a horizon sweep in O(H·W) per light;
//!   [`cast_shadows_ray_march`] is the plain per-pixel reference it is tested against.
//!
//! **Holes.** A ray that crosses an invalid pixel stops there: the horizon is not carried
//! through holes or past the image border (it resets to −∞). Both the sweep and the ray march
//! follow this rule, so an occluder on the far side of a hole in the mask casts nothing across it.

pub mod near;

use crate::base::error::{Error, Result};
use rayon::prelude::*;

/// Thresholds of the shadow tests.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ShadowParams {
    /// A pixel is in attached shadow when n·l ≤ this cosine (dimensionless). Default 0.02,
    /// i.e. the light within about 1.1° of the tangent plane or behind it.
    pub attached_tolerance: f64,
    /// A pixel is in cast shadow when its height is below the horizon toward the light by more
    /// than this, in pixel units of height. Default 0.05 px: it halves the sweep's false shadows
    /// on smooth lit slopes (interpolation error near grazing light) while keeping about 97% of
    /// the exact cast shadow on surfaces facing the light (measurements in `docs/shadows.md`); it
    /// shortens a shadow by about `tolerance · tan(slant)` pixels.
    pub cast_tolerance_px: f64,
}

impl Default for ShadowParams {
    fn default() -> Self {
        ShadowParams {
            attached_tolerance: 0.02,
            cast_tolerance_px: 0.05,
        }
    }
}

impl ShadowParams {
    /// Checks the domains; errors name the parameter (`attached_tolerance`,
    /// `cast_tolerance`).
    pub fn check(&self) -> Result<()> {
        if !self.attached_tolerance.is_finite() || self.attached_tolerance.abs() >= 1.0 {
            return Err(Error::parameter(
                "attached_tolerance",
                format!("{}: expected a cosine in (-1, 1)", self.attached_tolerance),
            ));
        }
        if !self.cast_tolerance_px.is_finite() || self.cast_tolerance_px < 0.0 {
            return Err(Error::parameter(
                "cast_tolerance",
                format!(
                    "{}: expected a finite height ≥ 0 in pixels",
                    self.cast_tolerance_px
                ),
            ));
        }
        Ok(())
    }

    /// Whether both tolerances are the defaults.
    pub fn is_default(&self) -> bool {
        *self == ShadowParams::default()
    }
}

/// Per-light shadow flags of a height field: for each light and pixel a combination of
/// [`ShadowMaps::ATTACHED`] and [`ShadowMaps::CAST`], 0 outside the mask. Held as two bit
/// planes per light (2 bits per pixel and light: 6 bytes per pixel under 24 lights), so that a
/// large capture's maps stay a small part of its memory.
#[derive(Clone, Debug, PartialEq)]
pub struct ShadowMaps {
    pub width: usize,
    pub height: usize,
    pub lights: usize,
    /// 64-bit words per light plane: `(width * height).div_ceil(64)`.
    words: usize,
    /// Bit `i % 64` of word `k * words + i / 64`: pixel `i` (row-major) in light `k`'s
    /// attached shadow.
    attached: Vec<u64>,
    /// The same for the cast shadow.
    cast: Vec<u64>,
}

impl ShadowMaps {
    /// Bit set when n·l ≤ τ.
    pub const ATTACHED: u8 = 1;
    /// Bit set when the height field hides the light.
    pub const CAST: u8 = 2;

    /// The attached and cast bit planes, given up (to park them in a file while a full-frame
    /// stage needs the memory).
    pub fn into_planes(self) -> [Vec<u64>; 2] {
        [self.attached, self.cast]
    }

    /// Maps from their bit planes ([`ShadowMaps::into_planes`]).
    pub fn from_planes(width: usize, height: usize, lights: usize, planes: [Vec<u64>; 2]) -> Self {
        let words = (width * height).div_ceil(64);
        let [attached, cast] = planes;
        assert!(attached.len() == words * lights && cast.len() == words * lights);
        ShadowMaps {
            width,
            height,
            lights,
            words,
            attached,
            cast,
        }
    }

    /// Maps without any shadow.
    pub fn empty(width: usize, height: usize, lights: usize) -> ShadowMaps {
        let words = (width * height).div_ceil(64);
        ShadowMaps {
            width,
            height,
            lights,
            words,
            attached: vec![0; words * lights],
            cast: vec![0; words * lights],
        }
    }

    /// Maps made light by light, one light at a time: `flags_of_light(k, out)` writes light
    /// `k`'s flags into `out` (`width * height` bytes, zero on entry), in parallel within the
    /// light; the result keeps the bits. One byte map and one light's working arrays are held
    /// whatever the thread count, so the memory plan's per-pixel bytes hold on any machine.
    pub fn build(
        width: usize,
        height: usize,
        lights: usize,
        flags_of_light: impl Fn(usize, &mut [u8]) + Sync,
    ) -> ShadowMaps {
        let mut maps = ShadowMaps::empty(width, height, lights);
        let (hw, words) = (width * height, maps.words);
        if hw == 0 {
            return maps;
        }
        let mut out = vec![0u8; hw];
        for (k, (att, cast)) in maps
            .attached
            .chunks_mut(words)
            .zip(maps.cast.chunks_mut(words))
            .enumerate()
        {
            out.par_chunks_mut(1 << 16).for_each(|c| c.fill(0));
            flags_of_light(k, &mut out);
            // 64 flags to a word, 1024 words to a task.
            const WORDS: usize = 1 << 10;
            att.par_chunks_mut(WORDS)
                .zip(cast.par_chunks_mut(WORDS))
                .zip(out.par_chunks(64 * WORDS))
                .for_each(|((att, cast), flags)| {
                    for ((a, c), chunk) in att.iter_mut().zip(cast.iter_mut()).zip(flags.chunks(64))
                    {
                        (*a, *c) = (0, 0);
                        for (b, &f) in chunk.iter().enumerate() {
                            *a |= ((f & Self::ATTACHED != 0) as u64) << b;
                            *c |= ((f & Self::CAST != 0) as u64) << b;
                        }
                    }
                });
        }
        maps
    }

    /// The flags of pixel `pixel` (flat row-major index) under light `k`.
    #[inline]
    pub fn flag(&self, k: usize, pixel: usize) -> u8 {
        let (w, b) = (k * self.words + pixel / 64, pixel % 64);
        ((self.attached[w] >> b & 1) as u8 * Self::ATTACHED)
            | ((self.cast[w] >> b & 1) as u8 * Self::CAST)
    }

    /// The flags of light `k` (`height * width`, row-major).
    pub fn flags_of(&self, k: usize) -> Vec<u8> {
        (0..self.width * self.height)
            .map(|i| self.flag(k, i))
            .collect()
    }

    /// Attached-shadow map of light `k`.
    pub fn attached(&self, k: usize) -> Vec<bool> {
        self.map(k, Self::ATTACHED)
    }

    /// Cast-shadow map of light `k`.
    pub fn cast(&self, k: usize) -> Vec<bool> {
        self.map(k, Self::CAST)
    }

    /// Union of the attached and cast shadows of light `k`.
    pub fn union(&self, k: usize) -> Vec<bool> {
        self.map(k, Self::ATTACHED | Self::CAST)
    }

    /// True when pixel `pixel` (flat row-major index) is in either shadow of light `k`.
    #[inline]
    pub fn is_shadowed(&self, k: usize, pixel: usize) -> bool {
        self.flag(k, pixel) != 0
    }

    /// How many (pixel, light) pairs carry any of the flags in `bits`.
    pub fn count(&self, bits: u8) -> usize {
        let planes = |v: &[u64]| v.iter().map(|w| w.count_ones() as usize).sum::<usize>();
        match bits & (Self::ATTACHED | Self::CAST) {
            0 => 0,
            Self::ATTACHED => planes(&self.attached),
            Self::CAST => planes(&self.cast),
            _ => self
                .attached
                .iter()
                .zip(&self.cast)
                .map(|(a, c)| (a | c).count_ones() as usize)
                .sum(),
        }
    }

    /// Per pixel of `pixels` (flat row-major indices), its shadows as bits: bit `k % 8` of
    /// byte `k / 8` of the pixel's `n_lights.div_ceil(8)` bytes is set when light `k`
    /// shadows it. Read light by light over runs of pixels, so the maps are walked in order.
    pub fn pixel_bits(&self, pixels: &[u32]) -> Vec<u8> {
        let bytes = self.lights.div_ceil(8);
        let mut bits = vec![0u8; pixels.len() * bytes];
        bits.par_chunks_mut(1024 * bytes)
            .zip(pixels.par_chunks(1024))
            .for_each(|(out, run)| {
                for k in 0..self.lights {
                    let plane = k * self.words;
                    let (byte, bit) = (k / 8, 1u8 << (k % 8));
                    for (j, &i) in run.iter().enumerate() {
                        let (w, b) = (plane + i as usize / 64, i % 64);
                        if (self.attached[w] | self.cast[w]) >> b & 1 != 0 {
                            out[j * bytes + byte] |= bit;
                        }
                    }
                }
            });
        bits
    }

    fn map(&self, k: usize, bits: u8) -> Vec<bool> {
        (0..self.width * self.height)
            .map(|i| self.flag(k, i) & bits != 0)
            .collect()
    }
}

/// Shadow maps of every light: attached shadows from `normals` (unit, camera frame) and cast
/// shadows from `depth` by the horizon sweep, computed in parallel over the lights.
///
/// Errors when a buffer's length is not `width * height`, a light is not a finite non-zero
/// vector, or a parameter is out of its domain.
pub fn shadow_maps(
    depth: &[f32],
    normals: &[[f32; 3]],
    mask: &[bool],
    width: usize,
    height: usize,
    lights: &[[f64; 3]],
    params: &ShadowParams,
) -> Result<ShadowMaps> {
    check_inputs(depth, mask, width, height)?;
    params.check()?;
    if normals.len() != width * height {
        return Err(Error::invalid(format!(
            "shadow maps: {} normals for a {width}×{height} height field (expected {})",
            normals.len(),
            width * height
        )));
    }
    let units = lights
        .iter()
        .enumerate()
        .map(|(k, l)| unit_light(*l).map_err(|m| Error::invalid(format!("light {}: {m}", k + 1))))
        .collect::<Result<Vec<_>>>()?;
    let n = width * height;
    if n == 0 {
        return Ok(ShadowMaps::empty(width, height, lights.len()));
    }
    let heights = valid_heights(depth, mask);
    // Flags are zero outside the mask: only the bounding box of the valid pixels is visited
    // (mask pixels with a non-finite height take their attached flag there too).
    let window = Window::of(width, height, |i| {
        heights[i] != f32::NEG_INFINITY || mask[i]
    });
    let Some(window) = window else {
        return Ok(ShadowMaps::empty(width, height, lights.len()));
    };
    // One light at a time: the sweep's buffers are reused from light to light.
    let scratch = std::sync::Mutex::new(SweepScratch::default());
    Ok(ShadowMaps::build(width, height, lights.len(), |k, out| {
        let l = units[k];
        let field = Field {
            heights: &heights,
            width,
            height,
            window,
        };
        let mut scratch = scratch
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        sweep(&field, l, params.cast_tolerance_px, &mut scratch, out);
        let tau = params.attached_tolerance;
        out[window.row0 * width..window.row1 * width]
            .par_chunks_mut(width)
            .enumerate()
            .for_each(|(r, out_row)| {
                let row = window.row0 + r;
                let span = row * width + window.col0..row * width + window.col1;
                for ((o, nrm), &inside) in out_row[window.col0..window.col1]
                    .iter_mut()
                    .zip(&normals[span.clone()])
                    .zip(&mask[span])
                {
                    // `sweep` wrote 0/1; keep CAST in its bit and add ATTACHED.
                    let mut f = if *o != 0 { ShadowMaps::CAST } else { 0 };
                    let s = l[0] * nrm[0] as f64 + l[1] * nrm[1] as f64 + l[2] * nrm[2] as f64;
                    if inside && s <= tau {
                        f |= ShadowMaps::ATTACHED;
                    }
                    *o = f;
                }
            });
    }))
}

/// Cast-shadow map of one light by a horizon sweep (see the module notes for holes).
///
/// The image is walked from the light's side along the dominant horizontal direction of the
/// light (columns when |l_x| ≥ |l_y|, rows otherwise; the 8 octants differ only in the walk's
/// direction), one column (row) per step. Sweep lines parallel to the light start one pixel
/// apart; along each, the point u one step toward the light is interpolated linearly between
/// the two pixels of the previous column (row) that bracket the ray, and the horizon is
/// H(x) = max(h(u), H(u)) − k·step, k = l_z / ‖(l_x, l_y)‖ the fall of the ray per pixel of
/// horizontal travel and step the horizontal length of one step. A pixel takes the horizon
/// interpolated between the two sweep lines that bracket it and is shadowed when
/// h(x) < H(x) − `cast_tolerance_px`. O(H·W) work, O(1) per pixel; the sweep lines are
/// independent and run in parallel. A light at the zenith casts no shadow.
pub fn cast_shadows(
    depth: &[f32],
    mask: &[bool],
    width: usize,
    height: usize,
    light: [f64; 3],
    params: &ShadowParams,
) -> Result<Vec<bool>> {
    check_inputs(depth, mask, width, height)?;
    params.check()?;
    let l = unit_light(light).map_err(|m| Error::invalid(format!("light {light:?}: {m}")))?;
    let mut out = vec![0u8; width * height];
    let heights = valid_heights(depth, mask);
    if let Some(window) = Window::of(width, height, |i| heights[i] != f32::NEG_INFINITY) {
        let field = Field {
            heights: &heights,
            width,
            height,
            window,
        };
        sweep(
            &field,
            l,
            params.cast_tolerance_px,
            &mut SweepScratch::default(),
            &mut out,
        );
    }
    Ok(out.into_iter().map(|f| f != 0).collect())
}

/// Reference cast-shadow map of one light: from every valid pixel, march toward the light in
/// steps of `step` pixels of horizontal travel, sampling the height bilinearly, and mark the
/// pixel when a sample rises above the ray by more than `tolerance_px` (+ 1e-4 px against
/// rounding; pass [`ShadowParams::cast_tolerance_px`] to compare with the sweep). The march stops when the ray
/// climbs above the highest valid height, leaves the image, or reaches a sample whose bilinear
/// support touches an invalid pixel (holes do not carry the horizon). Parallel over rows.
pub fn cast_shadows_ray_march(
    depth: &[f32],
    mask: &[bool],
    width: usize,
    height: usize,
    light: [f64; 3],
    step: f64,
    tolerance_px: f64,
) -> Result<Vec<bool>> {
    check_inputs(depth, mask, width, height)?;
    if !(step.is_finite() && step > 0.0) {
        return Err(Error::invalid(format!(
            "ray march step = {step}: expected a positive number of pixels"
        )));
    }
    if !(tolerance_px.is_finite() && tolerance_px >= 0.0) {
        return Err(Error::invalid(format!(
            "ray march tolerance = {tolerance_px}: expected a finite height >= 0 in pixels"
        )));
    }
    let threshold = tolerance_px + 1e-4;
    let l = unit_light(light).map_err(|m| Error::invalid(format!("light {light:?}: {m}")))?;
    let mut out = vec![false; width * height];
    let horiz = l[0].hypot(l[1]);
    if horiz < ZENITH_EPS || out.is_empty() {
        return Ok(out);
    }
    // Per unit of horizontal travel: columns grow with x, rows shrink with y.
    let (dc, dr, dz) = (l[0] / horiz, -l[1] / horiz, l[2] / horiz);
    let valid = |i: usize| mask[i] && depth[i].is_finite();
    let max_h = (0..width * height)
        .filter(|&i| valid(i))
        .map(|i| depth[i] as f64)
        .fold(f64::NEG_INFINITY, f64::max);
    let (last_r, last_c) = ((height - 1) as f64, (width - 1) as f64);
    let sample = |r: f64, c: f64| -> Option<f64> {
        let r0 = r.floor() as usize;
        let c0 = c.floor() as usize;
        let fr = r - r0 as f64;
        let fc = c - c0 as f64;
        let mut acc = 0.0;
        for (rr, wr) in [(r0, 1.0 - fr), (r0 + 1, fr)] {
            for (cc, wc) in [(c0, 1.0 - fc), (c0 + 1, fc)] {
                let w = wr * wc;
                if w > 1e-9 {
                    let i = rr * width + cc;
                    if rr >= height || cc >= width || !valid(i) {
                        return None;
                    }
                    acc += w * depth[i] as f64;
                }
            }
        }
        Some(acc)
    };
    out.par_chunks_mut(width)
        .enumerate()
        .for_each(|(row, out_row)| {
            for (col, o) in out_row.iter_mut().enumerate() {
                let i = row * width + col;
                if !valid(i) {
                    continue;
                }
                let h0 = depth[i] as f64;
                let mut t = step;
                loop {
                    let z = h0 + dz * t;
                    if z > max_h {
                        break;
                    }
                    let (r, c) = (row as f64 + dr * t, col as f64 + dc * t);
                    if r < 0.0 || c < 0.0 || r > last_r || c > last_c {
                        break;
                    }
                    match sample(r, c) {
                        Some(h) if h - z > threshold => {
                            *o = true;
                            break;
                        }
                        Some(_) => {}
                        None => break,
                    }
                    t += step;
                }
            }
        });
    Ok(out)
}

/// Below this horizontal component the light counts as at the zenith: no cast shadow.
const ZENITH_EPS: f64 = 1e-9;

fn check_inputs(depth: &[f32], mask: &[bool], width: usize, height: usize) -> Result<()> {
    let n = width
        .checked_mul(height)
        .ok_or_else(|| Error::invalid(format!("height field {width}×{height} is too large")))?;
    if depth.len() != n || mask.len() != n {
        return Err(Error::invalid(format!(
            "shadows: height field of {} values and mask of {} for a {width}×{height} image \
             (expected {n} each)",
            depth.len(),
            mask.len()
        )));
    }
    Ok(())
}

fn unit_light(l: [f64; 3]) -> std::result::Result<[f64; 3], String> {
    let norm = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
    if !norm.is_finite() || norm < 1e-12 {
        return Err("expected a finite, non-zero direction toward the light".into());
    }
    Ok(l.map(|v| v / norm))
}

/// How a light's sweep walks the image: step i (0 at the light's side) along the primary axis,
/// lateral index j across it; pixel (i, j) is at `base + i·di + j·dj`.
struct Walk {
    n_steps: usize,
    base: isize,
    di: isize,
    dj: isize,
    /// True when the primary axis is the column axis.
    along_cols: bool,
    /// Lateral offset (pixels) of the point one step toward the light.
    shift: f64,
    /// Fall of the ray over one step away from the light (pixel units of height):
    /// k · step, k = l_z / ‖(l_x, l_y)‖, step = horizontal length of one step.
    drop: f32,
}

impl Walk {
    /// `None` for a light at the zenith or an empty image.
    fn new(width: usize, height: usize, l: [f64; 3]) -> Option<Walk> {
        let horiz = l[0].hypot(l[1]);
        if horiz < ZENITH_EPS || width == 0 || height == 0 {
            return None;
        }
        // Image steps toward the light per unit of horizontal travel.
        let (dc, dr) = (l[0] / horiz, -l[1] / horiz);
        let w = width as isize;
        let (along_cols, toward_plus, primary, lateral) = if dc.abs() >= dr.abs() {
            (true, dc > 0.0, dc, dr)
        } else {
            (false, dr > 0.0, dr, dc)
        };
        let (n_steps, stride_primary, stride_lateral) = if along_cols {
            (width, 1, w)
        } else {
            (height, w, 1)
        };
        let step = 1.0 / primary.abs();
        Some(Walk {
            n_steps,
            base: if toward_plus {
                (n_steps as isize - 1) * stride_primary
            } else {
                0
            },
            di: if toward_plus {
                -stride_primary
            } else {
                stride_primary
            },
            dj: stride_lateral,
            along_cols,
            shift: lateral * step,
            drop: (l[2] / horiz * step) as f32,
        })
    }

    #[inline]
    fn index(&self, i: usize, j: isize) -> usize {
        (self.base + i as isize * self.di + j * self.dj) as usize
    }
}

/// Heights of valid pixels, −∞ elsewhere (outside the mask or not finite).
fn valid_heights(depth: &[f32], mask: &[bool]) -> Vec<f32> {
    depth
        .par_iter()
        .zip(mask.par_iter())
        .map(|(&h, &inside)| {
            if inside && h.is_finite() {
                h
            } else {
                f32::NEG_INFINITY
            }
        })
        .collect()
}

/// Buffers of one light's sweep, reused from light to light.
#[derive(Default)]
struct SweepScratch {
    /// Horizon of every sweep line at every step.
    horizons: Vec<f32>,
    /// Per step i: integer part and fraction of −shift·i.
    offsets: Vec<isize>,
    fractions: Vec<f32>,
}

/// Side of the square tiles in which pass 2 of the sweep visits pixels (cache locality).
const TILE: usize = 64;

/// Writes 1 into `out` where light `l` (unit) is hidden by the height field `heights` (−∞ at
/// invalid pixels), 0 elsewhere.
///
/// Lines q = 0, 1, … run parallel to the light at lateral position p = q_min + q − shift·i
/// (step i); along each, the height at the ray's crossing of the step is interpolated between the
/// two pixels that bracket it, and the horizon recursion H(i) = max(h(i−1), H(i−1)) − drop runs
/// exactly (the lines are independent: parallel over lines). A pixel's horizon is then
/// interpolated between the two lines that bracket it. An invalid sample (hole, border) resets a
/// line's horizon to −∞.
fn sweep(field: &Field, l: [f64; 3], tolerance: f64, scratch: &mut SweepScratch, out: &mut [u8]) {
    let Field {
        heights,
        width,
        height,
        window,
    } = *field;
    out.fill(0);
    let Some(walk) = Walk::new(width, height, l) else {
        return;
    };
    let tolerance = tolerance as f32;
    let (n_steps, shift) = (walk.n_steps, walk.shift);
    // The window's steps and laterals in the whole frame's walk. Outside the window every pixel
    // is invalid, so a line enters it with its horizon reset to −∞ exactly as in a sweep of the
    // whole frame; with the lines and the per-step tables kept at their whole-frame positions
    // (global step i, lateral j), the result is bit-identical and the work is the window's.
    let (along_lo, along_hi, lat_lo, lat_hi) = if walk.along_cols {
        (window.col0, window.col1, window.row0, window.row1)
    } else {
        (window.row0, window.row1, window.col0, window.col1)
    };
    let (i_lo, i_hi) = if walk.di < 0 {
        (n_steps - along_hi, n_steps - along_lo)
    } else {
        (along_lo, along_hi)
    };
    let w_steps = i_hi - i_lo;
    let shift_lo = (shift * i_lo as f64).min(shift * (i_hi - 1) as f64);
    let shift_hi = (shift * i_lo as f64).max(shift * (i_hi - 1) as f64);
    let q_min = (lat_lo as f64 + shift_lo).floor() as isize - 2;
    let q_max = (lat_hi as f64 + shift_hi).ceil() as isize + 2;
    let n_lines = (q_max - q_min + 1) as usize;
    // Line q sits at lateral q − shift·i at step i: the integer part and the fraction of
    // −shift·i are the same for every line, so they are tabulated once per step.
    scratch.offsets.clear();
    scratch.fractions.clear();
    for i in i_lo..i_hi {
        let p = -shift * i as f64;
        let p0 = p.floor();
        let mut f = (p - p0) as f32;
        let mut p0 = p0 as isize;
        if f > 1.0 - 1e-6 {
            (p0, f) = (p0 + 1, 0.0);
        } else if f < 1e-6 {
            f = 0.0;
        }
        scratch.offsets.push(p0);
        scratch.fractions.push(f);
    }
    scratch.horizons.clear();
    scratch
        .horizons
        .resize(n_lines * w_steps, f32::NEG_INFINITY);
    let (offsets, fractions) = (&scratch.offsets, &scratch.fractions);
    let (lat_lo, lat_hi) = (lat_lo as isize, lat_hi as isize);
    // Pass 1: the horizon of every line at every step of the window,
    // `horizons[line * w_steps + (i − i_lo)]`.
    scratch
        .horizons
        .par_chunks_mut(w_steps)
        .enumerate()
        .for_each(|(line, line_horizons)| {
            let q = q_min + line as isize;
            let at = |i: usize, j: isize| -> f32 {
                if j < lat_lo || j >= lat_hi {
                    f32::NEG_INFINITY
                } else {
                    heights[walk.index(i, j)]
                }
            };
            let mut highest = f32::NEG_INFINITY; // M = max(h, H) at the previous step
            for (s, horizon) in line_horizons.iter_mut().enumerate() {
                *horizon = highest - walk.drop;
                let p0 = q + offsets[s];
                let f = fractions[s];
                // −∞ on a side with weight (hole or border) stays −∞: the horizon resets.
                let h = if f == 0.0 {
                    at(i_lo + s, p0)
                } else {
                    (1.0 - f) * at(i_lo + s, p0) + f * at(i_lo + s, p0 + 1)
                };
                highest = if h == f32::NEG_INFINITY {
                    h
                } else {
                    h.max(*horizon)
                };
            }
        });
    // Pass 2: each valid pixel of the window against the horizon interpolated between its two
    // lines, in bands of TILE rows and tiles of TILE columns so that the lines read stay in
    // cache.
    let horizons = &scratch.horizons;
    out[window.row0 * width..window.row1 * width]
        .par_chunks_mut(width * TILE)
        .enumerate()
        .for_each(|(band, out_band)| {
            let row0 = window.row0 + band * TILE;
            let rows = out_band.len() / width;
            for col0 in (window.col0..window.col1).step_by(TILE) {
                for r in 0..rows {
                    let row = row0 + r;
                    for col in col0..(col0 + TILE).min(window.col1) {
                        let x = row * width + col;
                        let h = heights[x];
                        if h == f32::NEG_INFINITY {
                            continue;
                        }
                        let (along, j) = if walk.along_cols {
                            (col, row)
                        } else {
                            (row, col)
                        };
                        let i = if walk.di < 0 {
                            n_steps - 1 - along
                        } else {
                            along
                        } - i_lo;
                        // The pixel lies at lateral j = q − shift·i, i.e. on line
                        // q = j − offsets[i] − fractions[i]: between lines q0 − 1 and q0.
                        let q0 = (j as isize - offsets[i] - q_min) as usize;
                        let f = fractions[i];
                        let a = q0 * w_steps + i;
                        let horizon = if f == 0.0 {
                            horizons[a]
                        } else {
                            f * horizons[a - w_steps] + (1.0 - f) * horizons[a]
                        };
                        if h < horizon - tolerance {
                            out_band[r * width + col] = 1;
                        }
                    }
                }
            }
        });
}

/// A height field for [`sweep`]: `heights` (−∞ at invalid pixels), its size, and a window
/// holding every valid pixel.
#[derive(Clone, Copy)]
struct Field<'a> {
    heights: &'a [f32],
    width: usize,
    height: usize,
    window: Window,
}

/// A bounding box: rows `row0..row1`, columns `col0..col1`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Window {
    pub(crate) row0: usize,
    pub(crate) row1: usize,
    pub(crate) col0: usize,
    pub(crate) col1: usize,
}

impl Window {
    /// The bounding box of the pixels (flat row-major indices) where `inside` holds.
    pub(crate) fn of(
        width: usize,
        height: usize,
        inside: impl Fn(usize) -> bool,
    ) -> Option<Window> {
        let (mut row0, mut row1, mut col0, mut col1) = (height, 0, width, 0);
        for r in 0..height {
            let first = (0..width).find(|&c| inside(r * width + c));
            if let Some(c) = first {
                let last = (c..width)
                    .rev()
                    .find(|&c| inside(r * width + c))
                    .unwrap_or(c);
                row0 = row0.min(r);
                row1 = r + 1;
                col0 = col0.min(c);
                col1 = col1.max(last + 1);
            }
        }
        (row0 < row1).then_some(Window {
            row0,
            row1,
            col0,
            col1,
        })
    }
}

#[cfg(test)]
mod window_tests {
    use super::*;

    /// The sweep over the valid pixels' bounding box gives bit for bit the flags of the sweep
    /// over the whole frame (the lines and per-step tables stay at their whole-frame positions),
    /// for lights in every octant and at the axes, on a masked field with a hole.
    #[test]
    fn the_bounding_box_sweep_equals_the_whole_frame_sweep() {
        let (w, h) = (53, 41);
        let mut heights = vec![f32::NEG_INFINITY; w * h];
        for r in 7..33 {
            for c in 11..47 {
                let (x, y) = (c as f32 * 0.37, r as f32 * 0.29);
                let hole = (r - 20) * (r - 20) + (c - 30) * (c - 30) < 9;
                if !hole {
                    heights[r * w + c] = 6.0 * x.sin() * y.cos() + 0.2 * c as f32;
                }
            }
        }
        let bbox = Window::of(w, h, |i| heights[i] != f32::NEG_INFINITY).unwrap();
        assert_eq!(
            (bbox.row0, bbox.row1, bbox.col0, bbox.col1),
            (7, 33, 11, 47)
        );
        let whole = Window {
            row0: 0,
            row1: h,
            col0: 0,
            col1: w,
        };
        let mut scratch = SweepScratch::default();
        let (mut a, mut b) = (vec![0u8; w * h], vec![0u8; w * h]);
        let mut shadowed = 0;
        for t in 0..48 {
            let phi = t as f64 * std::f64::consts::PI / 24.0 + 0.013 * (t % 3) as f64;
            let slant = 0.35 + 0.02 * t as f64;
            let l = unit_light([
                slant.sin() * phi.cos(),
                slant.sin() * phi.sin(),
                slant.cos(),
            ])
            .unwrap();
            let field = |window| Field {
                heights: &heights,
                width: w,
                height: h,
                window,
            };
            sweep(&field(bbox), l, 0.05, &mut scratch, &mut a);
            sweep(&field(whole), l, 0.05, &mut scratch, &mut b);
            assert_eq!(a, b, "light {t}: {l:?}");
            shadowed += a.iter().filter(|&&f| f != 0).count();
        }
        assert!(shadowed > 1000, "the field casts shadows: {shadowed}");
    }
}
