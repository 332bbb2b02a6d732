//! Highlights modelled rather than dropped, for near-light captures.
//!
//! With LEDs close around the lens (a ring rig) the glossy lobe covers every LED at once on
//! surfaces that face the camera: no light is free of highlight there, so no choice of lights
//! can recover the normal. What does separate them is the shape of the readings: the diffuse
//! part follows n · l_k, the specular part a lobe about each light's half vector
//! h_k = (l_k + u)/‖l_k + u‖ (u toward the camera). Each pixel is fitted with
//!
//! I_k = b_k · (ρ n · l_k + s · exp(−m (1 − n · h_k))),   ρ ≥ 0, s ≥ 0,
//!
//! in the units of the intensity-normalised channel means (b_k the light's relative brightness
//! at the pixel, [`crate::model::lightmodel::NearLights`]). exp(−m (1 − cos θ)) ≈ exp(−m θ²/2) is the
//! Gaussian lobe that Blinn–Phong (cos^m), Ward and Torrance–Sparrow lobes all approach near
//! their peak. The sharpness m is a property of the material, shared by the capture: it is
//! chosen among [`LOBE_EXPONENTS`] by the least total squared residual over a sample of
//! pixels. Per pixel, with m fixed, ρ and s follow linearly from n, and n is found by a grid
//! over the normals within [`CONE_DEG`] of u ([`GRID_STEP_DEG`] apart) and a pattern search
//! from the best node and the method's own normal (the residual has several minima: a local
//! search alone lands in the wrong one at most highlight pixels).
//!
//! A pixel takes the fitted normal when the lobe lowers its squared residual, over the same
//! lights, below that of the best purely diffuse fit by more than the χ² quantile of one
//! degree of freedom at the detector's confidence times the pixel's variance: a Lambertian
//! pixel keeps the method's estimate. Lights in the method's shadow maps stay out of the fit.
//!
//! Pixels with fewer than [`MIN_LIGHTS`] lights out of shadow — every pixel of a four-light
//! rig — cannot fit a lobe of their own, and those left with three usable lights (one light in
//! shadow) or two have no spare reading for the χ² test to see a highlight with. There the
//! capture's lobe — one m and one strength s, fitted where four lights or more are lit and the
//! method has judged the readings ([`fit_capture_lobe`]) — is taken out of the readings before
//! the exact solve ([`correct_without_spare`]).
//!
//! Frames and units as in [`crate::model::lightmodel`].

use crate::model::capture::Capture;
use crate::model::lightmodel::{NearLights, PixelLights};
use crate::solve::detect::NoiseModel;
use crate::solve::lambert::{channel_mean, status, Estimate, CHUNK};
use rayon::prelude::*;
use serde::Serialize;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The lobe sharpnesses m tried (about 25 to 400: lobes that fall to half height 13.3° to
/// 3.4° from their peak).
pub const LOBE_EXPONENTS: &[f64] = &[25.0, 35.0, 50.0, 70.0, 100.0, 140.0, 200.0, 280.0, 400.0];
/// Spacing of the grid of trial normals, degrees.
pub const GRID_STEP_DEG: f64 = 4.0;
/// Spacing of the trial normals within [`FINE_CONE_DEG`] of the direction toward the camera,
/// degrees: a sharp lobe's residual changes too fast for [`GRID_STEP_DEG`] there (a node 3°
/// from the true normal can score worse than a wrong normal 35° away).
pub const FINE_STEP_DEG: f64 = 1.5;
/// The cone of the fine grid, degrees: a lobe about the half vectors of lights near the lens
/// reaches normals up to about this far from the camera's direction.
pub const FINE_CONE_DEG: f64 = 20.0;
/// Trial normals lie within this angle of the direction toward the camera, degrees.
pub const CONE_DEG: f64 = 60.0;
/// The broad lobe whose grid minimum seeds the search of a sharper one (half height 13.3°
/// from the peak).
const BROAD_LOBE: f64 = 25.0;
/// Lights a pixel needs in the fit: the four unknowns (n, ρ, s) and two degrees of freedom
/// left for the residual to compare with the diffuse fit's.
pub const MIN_LIGHTS: usize = 6;
/// Pixels sampled to choose m (evenly spaced over the mask).
const SAMPLE_PIXELS: usize = 400;
/// The pattern search stops at this step, radians (0.05°).
const FINEST_STEP: f64 = 0.05 * std::f64::consts::PI / 180.0;

/// What [`refine`] did, for `report.json`.
#[derive(Clone, Debug, Serialize)]
pub struct LobeSummary {
    /// The lobe sharpness m chosen for the capture; `None` when no pixel has
    /// [`MIN_LIGHTS`] lights out of shadow (then nothing is refitted).
    pub exponent: Option<f64>,
    /// Mask pixels whose normal now comes from the lobe fit.
    pub refined_pixels: usize,
    /// Their share of the mask.
    pub refined_share: f64,
    /// Mask pixels fitted: those with [`MIN_LIGHTS`] lights out of shadow whose purely diffuse
    /// fit fails the χ² test (the others show no highlight and are not fitted).
    pub fitted_pixels: usize,
    /// Of those, the pixels whose nearby starts gave no acceptable fit, so that the whole grid
    /// of trial normals was searched in this round (at most once per pixel and
    /// reconstruction: a later round starts from that search's basin).
    pub grid_pixels: usize,
}

/// One pixel's data: scaled light vectors v_k = b_k l_k, unit half vectors, grey readings and
/// the lights in the fit.
pub(crate) struct PixelData<'a> {
    pub v: &'a [[f64; 3]],
    pub h: &'a [[f64; 3]],
    pub b: &'a [f64],
    pub g: &'a [f64],
    pub used: &'a [bool],
}

/// The fit at normal `n` with sharpness `m`: (squared residual, ρ, s).
#[inline]
pub(crate) fn fit_at(d: &PixelData, n: [f64; 3], m: f64) -> (f64, f64, f64) {
    let mut sums = PairSums::default();
    for k in 0..d.v.len() {
        if d.used[k] {
            let a = dot(d.v[k], n).max(0.0);
            let b = d.b[k] * (-m * (1.0 - dot(d.h[k], n))).exp();
            sums.add(a, b, d.g[k]);
        }
    }
    sums.solve()
}

/// The sums of products of a two-term model's columns a_k (diffuse), b_k (lobe) and the
/// readings g_k, from which the non-negative (ρ, s) of g ≈ ρ a + s b follow.
#[derive(Clone, Copy, Default)]
pub(crate) struct PairSums {
    aa: f64,
    ab: f64,
    bb: f64,
    ag: f64,
    bg: f64,
    gg: f64,
}

impl PairSums {
    /// Adds one reading `g` with the columns' values `a` and `b`.
    #[inline]
    pub(crate) fn add(&mut self, a: f64, b: f64, g: f64) {
        self.aa += a * a;
        self.ab += a * b;
        self.bb += b * b;
        self.ag += a * g;
        self.bg += b * g;
        self.gg += g * g;
    }

    /// Non-negative least squares in the two unknowns: the interior solution where both are
    /// non-negative, else the better edge (ρ alone, s alone, or neither). Returns
    /// (squared residual, ρ, s).
    pub(crate) fn solve(&self) -> (f64, f64, f64) {
        let PairSums {
            aa,
            ab,
            bb,
            ag,
            bg,
            gg,
        } = *self;
        let mut best = (gg, 0.0, 0.0);
        if aa > 0.0 {
            let r = (ag / aa).max(0.0);
            best = (gg - r * ag, r, 0.0);
        }
        if bb > 0.0 {
            let s = (bg / bb).max(0.0);
            if gg - s * bg < best.0 {
                best = (gg - s * bg, 0.0, s);
            }
        }
        let det = aa * bb - ab * ab;
        if det > 1e-12 * (aa * bb).max(1e-300) {
            let r = (ag * bb - bg * ab) / det;
            let s = (bg * aa - ag * ab) / det;
            if r >= 0.0 && s >= 0.0 {
                let e = gg - r * ag - s * bg;
                if e < best.0 {
                    best = (e, r, s);
                }
            }
        }
        (best.0.max(0.0), best.1, best.2)
    }
}

/// Grid offsets (tan x, tan y) of the trial normals about u.
fn grid() -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    let mut add = |step: f64, inner: f64, outer: f64| {
        let r = (outer / step).floor() as i32;
        for i in -r..=r {
            for j in -r..=r {
                let (x, y) = (i as f64 * step, j as f64 * step);
                let a2 = x * x + y * y;
                if a2 <= outer * outer && a2 > inner * inner {
                    out.push((x.to_radians().tan(), y.to_radians().tan()));
                }
            }
        }
    };
    // Finely where the highlights are (normals near the camera's direction), coarsely beyond.
    add(FINE_STEP_DEG, -1.0, FINE_CONE_DEG);
    add(GRID_STEP_DEG, FINE_CONE_DEG, CONE_DEG);
    out
}

/// The best normal for sharpness `m`: the grid about `u`, then a pattern search from the best
/// node and from each of `starts`. Returns (squared residual, normal, ρ, s).
fn fit_pixel(
    d: &PixelData,
    u: [f64; 3],
    starts: &[[f64; 3]],
    m: f64,
    nodes: &[(f64, f64)],
    refine: bool,
) -> (f64, [f64; 3], f64, f64) {
    let (t1, t2) = basis(u);
    // The best node with the lobe itself and with a broad one: a sharp lobe's residual varies
    // too fast for the grid's spacing near the true normal, a broad lobe's leads to its basin.
    let broad = m.min(BROAD_LOBE);
    let mut best = (f64::INFINITY, u);
    let mut best_broad = (f64::INFINITY, u);
    for &(x, y) in nodes {
        let n = unit(add3(u, add3(scale(t1, x), scale(t2, y))));
        let e = fit_at(d, n, m).0;
        if e < best.0 {
            best = (e, n);
        }
        if refine && broad < m {
            let e = fit_at(d, n, broad).0;
            if e < best_broad.0 {
                best_broad = (e, n);
            }
        }
    }
    if !refine {
        let (e, r, s) = fit_at(d, best.1, m);
        return (e, best.1, r, s);
    }
    let mut result = search(d, best.1, m);
    let from_broad = (broad < m).then(|| search(d, search(d, best_broad.1, broad).1, m));
    for other in from_broad
        .into_iter()
        .chain(starts.iter().map(|&s| search(d, s, m)))
    {
        if other.0 < result.0 {
            result = other;
        }
    }
    let (e, r, s) = fit_at(d, result.1, m);
    (e, result.1, r, s)
}

/// Pattern search on the sphere of normals: eight directions, the step halved when none
/// improves, from 2° (half the grid spacing) down to [`FINEST_STEP`].
pub(crate) fn search(d: &PixelData, from: [f64; 3], m: f64) -> (f64, [f64; 3]) {
    let mut n = from;
    let mut e = fit_at(d, n, m).0;
    let mut step = (GRID_STEP_DEG / 2.0).to_radians();
    while step > FINEST_STEP {
        let (t1, t2) = basis(n);
        let mut improved = false;
        for dir in 0..8 {
            let a = dir as f64 * std::f64::consts::FRAC_PI_4;
            let c = unit(add3(
                n,
                add3(scale(t1, a.cos() * step), scale(t2, a.sin() * step)),
            ));
            let ec = fit_at(d, c, m).0;
            if ec < e {
                e = ec;
                n = c;
                improved = true;
            }
        }
        if !improved {
            step *= 0.5;
        }
    }
    (e, n)
}

/// Squared residual of the best purely diffuse fit (unconstrained least squares, 3 unknowns)
/// over the used lights; infinite when they do not span three dimensions.
pub(crate) fn diffuse_residual(d: &PixelData) -> f64 {
    let used = (0..d.v.len()).filter(|&k| d.used[k]);
    match crate::solve::lambert::solve_with(d.v, Some(d.used), d.g) {
        Some(x) => used
            .map(|k| {
                let r = d.g[k] - (d.v[k][0] * x[0] + d.v[k][1] * x[1] + d.v[k][2] * x[2]);
                r * r
            })
            .sum(),
        None => f64::INFINITY,
    }
}

/// Per-thread buffers of one pixel (no allocation per pixel).
struct Scratch<'a> {
    lights: PixelLights<'a>,
    v: Vec<[f64; 3]>,
    h: Vec<[f64; 3]>,
    b: Vec<f64>,
    g: Vec<f64>,
    used: Vec<bool>,
}

impl<'a> Scratch<'a> {
    fn new(capture: &'a Capture, near: &'a NearLights) -> Self {
        let n = capture.n_lights();
        Scratch {
            lights: PixelLights::new(&capture.lights.directions, Some(near), capture.width),
            v: vec![[0.0; 3]; n],
            h: vec![[0.0; 3]; n],
            b: vec![0.0; n],
            g: vec![0.0; n],
            used: vec![false; n],
        }
    }

    /// Loads full-frame pixel `pixel` with grey readings from `samples` and the lights not in
    /// shadow by `statuses`; returns u, the unit vector toward the camera.
    #[allow(clippy::too_many_arguments)]
    fn load(
        &mut self,
        near: &NearLights,
        depth: &[f32],
        width: usize,
        pixel: usize,
        samples: &[f32],
        channels: usize,
        statuses: Option<&[u8]>,
    ) -> [f64; 3] {
        channel_mean(samples, channels, &mut self.g);
        self.v.copy_from_slice(self.lights.at(pixel));
        let z = depth
            .get(pixel)
            .map_or(near.mean_distance, |&z| z as f64)
            .max(1e-6);
        let x = near.point(pixel % width, pixel / width, z);
        let u = unit([-x[0], -x[1], -x[2]]);
        for k in 0..self.v.len() {
            let b = norm(self.v[k]);
            self.b[k] = b;
            let l = if b > 0.0 {
                scale(self.v[k], 1.0 / b)
            } else {
                [0.0, 0.0, 1.0]
            };
            self.h[k] = unit(add3(l, u));
            self.used[k] = statuses.is_none_or(|s| s[k] != status::SHADOW);
        }
        u
    }

    fn data(&self) -> PixelData<'_> {
        PixelData {
            v: &self.v,
            h: &self.h,
            b: &self.b,
            g: &self.g,
            used: &self.used,
        }
    }
}

/// What the lobe fits of one reconstruction carry from one round of the near-light alternation
/// to the next: the capture's sharpness m (a property of the material, chosen once) and each
/// pixel's fitted normal (the start of its next fit: the light vectors move only a little
/// between rounds).
#[derive(Clone, Debug, Default)]
pub struct LobeMemory {
    /// The sharpness chosen in the first round that had pixels to fit.
    exponent: Option<f64>,
    /// Per mask pixel, the last fitted normal; (0, 0, 0) where none.
    normals: Vec<[f32; 3]>,
    /// Per mask pixel, whether that fit came out of (or was checked against) the whole grid:
    /// its basin was then chosen among all, and the next round's search starts in it.
    searched: Vec<bool>,
}

/// Distinct starts of the pattern search: two closer than this (radians, 0.1°) are one.
const SEED_SEPARATION: f64 = 0.1 * std::f64::consts::PI / 180.0;

/// The best of the pattern searches from `seeds` (the first `count`) at sharpness `m`; a seed
/// within [`SEED_SEPARATION`] of an earlier one is skipped. `(∞, u)` without seeds.
fn search_seeds(d: &PixelData, seeds: &[[f64; 3]], m: f64, u: [f64; 3]) -> (f64, [f64; 3]) {
    let mut best = (f64::INFINITY, u);
    let cos_sep = SEED_SEPARATION.cos();
    for (i, &seed) in seeds.iter().enumerate() {
        if seeds[..i].iter().any(|&o| dot(o, seed) > cos_sep) {
            continue;
        }
        let r = search(d, seed, m);
        if r.0 < best.0 {
            best = r;
        }
    }
    best
}

/// `x` as an f64 unit vector, or `None` for the zero vector (no normal).
#[inline]
fn seed_of(x: [f32; 3]) -> Option<[f64; 3]> {
    (x != [0.0; 3]).then(|| unit([x[0] as f64, x[1] as f64, x[2] as f64]))
}

/// χ² quantiles at `confidence` for 0..=n degrees of freedom (0 for none).
pub(crate) fn quantiles(confidence: f64, n: usize) -> Vec<f64> {
    (0..=n)
        .map(|k| {
            if k == 0 {
                0.0
            } else {
                crate::base::stats::chi2_quantile(confidence, k)
            }
        })
        .collect()
}

/// Refits the pixels of `est` (per mask pixel, statuses in `est.light_status`, the near model's
/// current surface) with the lobe model and keeps the fit where the lobe is significant (see
/// the module documentation). Statuses: lights in the fit become USED, or HIGHLIGHT where the
/// fitted lobe adds more than three σ_p to their reading. Returns the summary and the
/// per-mask-pixel flags of the refined pixels.
///
/// The cost is kept to the pixels that need it: a pixel whose purely diffuse fit passes the χ²
/// test (N_used − 3 degrees of freedom at `confidence`) shows no highlight and keeps the
/// method's estimate unfitted; the others are searched first from the normals nearest at hand
/// (the pixel's fit of the last round in `memory`, the fits of its left and upper neighbours,
/// the method's own normal), and only when none of those searches reaches a residual the χ²
/// test accepts (N_used − 4 degrees of freedom) is the whole grid of trial normals searched —
/// once per pixel and reconstruction: the light vectors move little between rounds, so a later
/// round searches from the basin the grid chose. The sharpness m is chosen once, in the first
/// round, and kept in `memory`.
pub fn refine(
    capture: &Capture,
    near: &NearLights,
    est: &mut Estimate,
    noise: &NoiseModel,
    confidence: f64,
    memory: &mut LobeMemory,
) -> crate::base::error::Result<(LobeSummary, Vec<bool>)> {
    let n = capture.n_lights();
    let c = capture.channels;
    let np = capture.n_pixels();
    let depth = near.surface();
    let nodes = grid();
    // Whole-fit acceptance (index: used lights − 4) and the diffuse fit's test (used − 3).
    let q = quantiles(confidence, n);
    if memory.normals.len() != np {
        memory.normals = vec![[0.0; 3]; np];
        memory.searched = vec![false; np];
    }
    let inputs = LobeInputs {
        capture,
        near,
        depth: &depth,
        nodes: &nodes,
        q: &q,
        noise,
    };
    // 1. The capture's lobe sharpness, once.
    if memory.exponent.is_none() {
        match inputs.lobe_sharpness(est)? {
            Some(m) => memory.exponent = Some(m),
            None => {
                memory.normals.fill([0.0; 3]);
                return Ok((
                    LobeSummary {
                        exponent: None,
                        refined_pixels: 0,
                        refined_share: 0.0,
                        fitted_pixels: 0,
                        grid_pixels: 0,
                    },
                    vec![false; np],
                ));
            }
        }
    }
    let m = memory.exponent.expect("chosen above");
    // 2. Every pixel with that sharpness.
    let pass = LobePass {
        inputs,
        m,
        fitted: AtomicUsize::new(0),
        searched_grid: AtomicUsize::new(0),
    };
    let mut refined = vec![false; np];
    let mut new_status = est
        .light_status
        .clone()
        .unwrap_or_else(|| vec![status::USED; np * n]);
    capture.for_each_tile(|off, tile| {
        let tn = tile.n_pixels();
        est.normals[off..off + tn]
            .par_chunks_mut(CHUNK)
            .zip(est.albedo[off * c..(off + tn) * c].par_chunks_mut(CHUNK * c))
            .zip(new_status[off * n..(off + tn) * n].par_chunks_mut(CHUNK * n))
            .zip(refined[off..off + tn].par_chunks_mut(CHUNK))
            .zip(memory.normals[off..off + tn].par_chunks_mut(CHUNK))
            .zip(memory.searched[off..off + tn].par_chunks_mut(CHUNK))
            .map(
                |(((((normals, albedo), status), refined), fits), searched)| LobeChunk {
                    normals,
                    albedo,
                    status,
                    refined,
                    fits,
                    searched,
                },
            )
            .enumerate()
            .for_each_init(
                || (Scratch::new(capture, near), vec![0f64; c]),
                |(s, num), (chunk, mut pixels)| {
                    let first = off + chunk * CHUNK;
                    for dp in 0..pixels.normals.len() {
                        let samples = tile.pixel_samples(chunk * CHUNK + dp);
                        pass.refine_pixel(s, num, samples, &mut pixels, first, dp);
                    }
                },
            );
        Ok(())
    })?;
    est.light_status = Some(new_status);
    let count = refined.iter().filter(|&&r| r).count();
    Ok((
        LobeSummary {
            exponent: Some(m),
            refined_pixels: count,
            refined_share: count as f64 / np.max(1) as f64,
            fitted_pixels: pass.fitted.into_inner(),
            grid_pixels: pass.searched_grid.into_inner(),
        },
        refined,
    ))
}

/// What [`refine`] reads.
struct LobeInputs<'a> {
    capture: &'a Capture,
    near: &'a NearLights,
    /// The light model's current surface, full frame.
    depth: &'a [f32],
    /// The grid of trial normals ([`grid`]).
    nodes: &'a [(f64, f64)],
    /// The χ² quantiles of [`quantiles`].
    q: &'a [f64],
    noise: &'a NoiseModel,
}

/// The refinement of every pixel with the lobe's sharpness `m` (step 2 of [`refine`]), and its
/// counts.
struct LobePass<'a> {
    inputs: LobeInputs<'a>,
    m: f64,
    /// Pixels whose diffuse fit failed its test (fitted with the lobe).
    fitted: AtomicUsize,
    /// Pixels searched on the whole grid.
    searched_grid: AtomicUsize,
}

/// One chunk of mask pixels in the refinement, as named slices.
struct LobeChunk<'e> {
    normals: &'e mut [[f32; 3]],
    albedo: &'e mut [f32],
    status: &'e mut [u8],
    refined: &'e mut [bool],
    /// Per pixel, the fitted normal: the last round's on entry, this round's after.
    fits: &'e mut [[f32; 3]],
    /// Per pixel, whether it was searched on the whole grid.
    searched: &'e mut [bool],
}

impl LobeInputs<'_> {
    /// The capture's lobe sharpness: the least total residual over evenly spaced pixels whose
    /// diffuse fit fails its test. Per pixel the broadest lobe is searched on the whole grid and
    /// each sharper one from the last one's normal (and the method's). `None` when no sampled
    /// pixel fails its diffuse test.
    fn lobe_sharpness(&self, est: &Estimate) -> crate::base::error::Result<Option<f64>> {
        let capture = self.capture;
        let (n, c, np) = (capture.n_lights(), capture.channels, capture.n_pixels());
        let (q, noise, near) = (self.q, self.noise, self.near);
        let statuses = est.light_status.as_deref();
        let stride = (np / SAMPLE_PIXELS).max(1);
        let sample: Vec<usize> = (0..np).step_by(stride).collect();
        let view = if capture.is_tiled() {
            std::borrow::Cow::Owned(capture.sampled(&sample)?)
        } else {
            std::borrow::Cow::Borrowed(capture)
        };
        let normals = &est.normals;
        let totals: Vec<f64> = sample
            .par_chunks(16)
            .map_init(
                || Scratch::new(capture, near),
                |s, ps| {
                    let mut t = vec![0f64; LOBE_EXPONENTS.len() + 1];
                    for &p in ps {
                        let pixel = capture.pixels[p] as usize;
                        let u = s.load(
                            near,
                            self.depth,
                            capture.width,
                            pixel,
                            view.pixel_samples(p),
                            c,
                            statuses.map(|st| &st[p * n..(p + 1) * n]),
                        );
                        let used = s.used.iter().filter(|&&x| x).count();
                        if used < MIN_LIGHTS {
                            continue;
                        }
                        let d = s.data();
                        let var = noise.variance(d.g.iter().sum::<f64>() / n.max(1) as f64);
                        if diffuse_residual(&d) <= q[used - 3] * var {
                            continue;
                        }
                        t[LOBE_EXPONENTS.len()] += 1.0;
                        let own = seed_of(normals[p]);
                        let starts = own.as_slice();
                        let (e, mut prev, _, _) =
                            fit_pixel(&d, u, starts, LOBE_EXPONENTS[0], self.nodes, true);
                        t[0] += e / var;
                        for (j, &m) in LOBE_EXPONENTS.iter().enumerate().skip(1) {
                            let seeds = [prev, own.unwrap_or(prev)];
                            let (e, nf) = search_seeds(&d, &seeds, m, u);
                            t[j] += e / var;
                            prev = nf;
                        }
                    }
                    t
                },
            )
            .reduce(
                || vec![0f64; LOBE_EXPONENTS.len() + 1],
                |a, b| a.iter().zip(&b).map(|(x, y)| x + y).collect(),
            );
        if totals[LOBE_EXPONENTS.len()] == 0.0 {
            return Ok(None);
        }
        let (best_j, _) = totals[..LOBE_EXPONENTS.len()].iter().enumerate().fold(
            (0, f64::INFINITY),
            |acc, (j, &t)| {
                if t < acc.1 {
                    (j, t)
                } else {
                    acc
                }
            },
        );
        Ok(Some(LOBE_EXPONENTS[best_j]))
    }
}

impl LobePass<'_> {
    /// The lobe fit of the chunk's pixel `dp` (mask pixel `first + dp`, its samples `samples`):
    /// none where its purely diffuse fit passes the χ² test; else searched from the normals at
    /// hand (the last round's fit, the left and upper neighbours' fits of this round, the
    /// method's normal) and on the whole grid when none of those reaches a residual the test
    /// accepts (once per pixel and reconstruction). Where the lobe lowers the residual beyond the
    /// test's quantile the pixel takes the fit's normal, the albedo per channel with the normal
    /// and the lobe fixed (the lobe is the same in every channel of the normalised images), and
    /// its readings the lobe dominates are labelled highlights.
    fn refine_pixel(
        &self,
        s: &mut Scratch,
        num: &mut [f64],
        samples: &[f32],
        chunk: &mut LobeChunk,
        first: usize,
        dp: usize,
    ) {
        let (inputs, m) = (&self.inputs, self.m);
        let (capture, q) = (inputs.capture, inputs.q);
        let (n, c, width) = (capture.n_lights(), capture.channels, capture.width);
        let p = first + dp;
        let pixel = capture.pixels[p] as usize;
        let stp = &mut chunk.status[dp * n..(dp + 1) * n];
        let u = s.load(
            inputs.near,
            inputs.depth,
            width,
            pixel,
            samples,
            c,
            Some(stp),
        );
        let used = s.used.iter().filter(|&&x| x).count();
        let fits = &mut *chunk.fits;
        let last = std::mem::replace(&mut fits[dp], [0.0; 3]);
        let was_searched = std::mem::replace(&mut chunk.searched[dp], false);
        if used < MIN_LIGHTS {
            return;
        }
        let d = s.data();
        let level = d.g.iter().sum::<f64>() / d.g.len().max(1) as f64;
        let var = inputs.noise.variance(level);
        let diffuse = diffuse_residual(&d);
        if diffuse <= q[used - 3] * var {
            return;
        }
        self.fitted.fetch_add(1, Ordering::Relaxed);
        // Starts at hand: the last round's fit, the left and upper neighbours' fits of this
        // round (in this chunk), the method's normal.
        let mut seeds = [[0f64; 3]; 4];
        let mut count = 0;
        let left = (dp > 0 && capture.pixels[p - 1] as usize + 1 == pixel).then(|| fits[dp - 1]);
        let up = (pixel >= width)
            .then(|| {
                capture.pixels[first..p]
                    .binary_search(&((pixel - width) as u32))
                    .ok()
                    .map(|i| fits[i])
            })
            .flatten();
        for x in [Some(last), left, up, Some(chunk.normals[dp])]
            .into_iter()
            .flatten()
        {
            if let Some(v) = seed_of(x) {
                seeds[count] = v;
                count += 1;
            }
        }
        let (e, mut nf) = search_seeds(&d, &seeds[..count], m, u);
        if e > q[used - 4] * var && !(was_searched && last != [0.0; 3]) {
            self.searched_grid.fetch_add(1, Ordering::Relaxed);
            chunk.searched[dp] = true;
            let (eg, ng, _, _) = fit_pixel(&d, u, &[], m, inputs.nodes, true);
            if eg < e {
                nf = ng;
            }
        }
        let (e, rho, spec) = fit_at(&d, nf, m);
        fits[dp] = [nf[0] as f32, nf[1] as f32, nf[2] as f32];
        chunk.searched[dp] |= was_searched;
        if !(rho > 0.0 && diffuse - e > q[1] * var) {
            return;
        }
        chunk.refined[dp] = true;
        chunk.normals[dp] = fits[dp];
        let sd = 3.0 * var.sqrt();
        num.fill(0.0);
        let mut den = 0f64;
        for k in 0..n {
            if !d.used[k] {
                continue;
            }
            let a = dot(d.v[k], nf).max(0.0);
            let lobe = spec * d.b[k] * (-m * (1.0 - dot(d.h[k], nf))).exp();
            for (ch, x) in num.iter_mut().enumerate() {
                *x += a * (samples[k * c + ch] as f64 - lobe);
            }
            den += a * a;
            stp[k] = if lobe > sd {
                status::HIGHLIGHT
            } else {
                status::USED
            };
        }
        albedo_from_sums(num, den, &mut chunk.albedo[dp * c..(dp + 1) * c]);
    }
}

/// The capture's highlight lobe, I_k = b_k (ρ n · l_k + s exp(−m (1 − n · h_k))) with one
/// sharpness m and one strength s for the whole capture, fitted where the readings are
/// trusted: at the pixels whose usable lights passed the χ² test with four lit lights or
/// more, each lit light's excess over the diffuse prediction from the pixel's normal and
/// albedo (large for the lights the method dropped as highlights, about zero for the others).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct CaptureLobe {
    /// The sharpness m, one of [`LOBE_EXPONENTS`].
    pub exponent: f64,
    /// The strength s, in the units of the intensity-normalised readings.
    pub strength: f64,
    /// The (pixel, light) readings the fit used.
    pub readings: usize,
}

/// Fits the [`CaptureLobe`] from `est` (per mask pixel; statuses in `est.light_status`) at the
/// mask pixels flagged in `reliable`; `None` when no highlight was dropped at such a pixel (no
/// lobe to fit).
pub fn fit_capture_lobe(
    capture: &Capture,
    near: &NearLights,
    est: &Estimate,
    reliable: &[bool],
) -> crate::base::error::Result<Option<CaptureLobe>> {
    let n = capture.n_lights();
    let c = capture.channels;
    let depth = near.surface();
    let Some(statuses) = est.light_status.as_deref() else {
        return Ok(None);
    };
    let e_len = LOBE_EXPONENTS.len();
    // Per exponent: Σ e g, Σ g²; then Σ e², readings, dropped highlights.
    let mut sums = vec![0f64; 2 * e_len + 3];
    capture.for_each_tile(|off, tile| {
        let tn = tile.n_pixels();
        let part: Vec<f64> = (0..tn.div_ceil(CHUNK))
            .into_par_iter()
            .map_init(
                || Scratch::new(capture, near),
                |s, chunk| {
                    let mut t = vec![0f64; 2 * e_len + 3];
                    for lp in chunk * CHUNK..((chunk + 1) * CHUNK).min(tn) {
                        let p = off + lp;
                        let st = &statuses[p * n..(p + 1) * n];
                        let lit = st
                            .iter()
                            .filter(|&&x| x == status::USED || x == status::HIGHLIGHT)
                            .count();
                        let used = st.iter().filter(|&&x| x == status::USED).count();
                        let nrm = est.normals[p];
                        // Passed the test with four lights or more, or one light dropped as a
                        // highlight from four or more.
                        if !(used >= 3 && lit >= 4 && (reliable[p] || lit == used + 1))
                            || nrm == [0.0; 3]
                        {
                            continue;
                        }
                        let pixel = capture.pixels[p] as usize;
                        s.load(
                            near,
                            &depth,
                            capture.width,
                            pixel,
                            tile.pixel_samples(lp),
                            c,
                            Some(st),
                        );
                        let nv = unit([nrm[0] as f64, nrm[1] as f64, nrm[2] as f64]);
                        let rho = est.albedo[p * c..(p + 1) * c]
                            .iter()
                            .map(|&a| a as f64)
                            .sum::<f64>()
                            / c as f64;
                        for (k, &sk) in st.iter().enumerate() {
                            if !(sk == status::USED || sk == status::HIGHLIGHT) {
                                continue;
                            }
                            let e = s.g[k] - rho * dot(s.v[k], nv).max(0.0);
                            let x = 1.0 - dot(s.h[k], nv);
                            for (j, &m) in LOBE_EXPONENTS.iter().enumerate() {
                                let g = s.b[k] * (-m * x).exp();
                                t[2 * j] += e * g;
                                t[2 * j + 1] += g * g;
                            }
                            t[2 * e_len] += e * e;
                            t[2 * e_len + 1] += 1.0;
                            if st[k] == status::HIGHLIGHT {
                                t[2 * e_len + 2] += 1.0;
                            }
                        }
                    }
                    t
                },
            )
            // In chunk order: the sums do not depend on the threads' timing.
            .collect::<Vec<_>>()
            .into_iter()
            .fold(vec![0f64; 2 * e_len + 3], |a, b| {
                a.iter().zip(&b).map(|(x, y)| x + y).collect()
            });
        for (a, b) in sums.iter_mut().zip(&part) {
            *a += b;
        }
        Ok(())
    })?;
    if sums[2 * e_len + 2] == 0.0 {
        return Ok(None);
    }
    // Per m the least-squares s ≥ 0, and the m of the least residual.
    let mut best: Option<(f64, f64, f64)> = None;
    for (j, &m) in LOBE_EXPONENTS.iter().enumerate() {
        let (eg, gg) = (sums[2 * j], sums[2 * j + 1]);
        if gg <= 0.0 {
            continue;
        }
        let strength = (eg / gg).max(0.0);
        let cost = sums[2 * e_len] - 2.0 * strength * eg + strength * strength * gg;
        if best.is_none_or(|b| cost < b.0) {
            best = Some((cost, m, strength));
        }
    }
    Ok(best.and_then(|(_, m, strength)| {
        (strength > 0.0).then_some(CaptureLobe {
            exponent: m,
            strength,
            readings: sums[2 * e_len + 1] as usize,
        })
    }))
}

/// Damped fixed-point iterations of [`correct_exact`]: at most this many.
const EXACT_ITERATIONS: usize = 50;

/// Pixels with exactly three usable lights have no redundancy: the χ² test cannot see a
/// highlight among them, and a highlighted light bends the normal toward itself. There the
/// capture's lobe ([`fit_capture_lobe`]) is taken out of the readings before the three-light
/// solve: n ← normalise(n + solve(I − b s exp(−m (1 − n · h)))), from the method's normal until
/// it moves less than 0.01°. Pixels whose lights the lobe does not reach keep their normal.
/// Pixels flagged in `fitted` (per mask pixel: refitted by [`refine`], whose statuses then
/// mark the lights its own lobe reaches) are left alone. Returns the number of pixels whose
/// normal moved by more than 0.1°.
pub fn correct_exact(
    capture: &Capture,
    near: &NearLights,
    est: &mut Estimate,
    lobe: &CaptureLobe,
    fitted: &[bool],
) -> crate::base::error::Result<usize> {
    let n = capture.n_lights();
    let c = capture.channels;
    let depth = near.surface();
    let Some(statuses) = est.light_status.clone() else {
        return Ok(0);
    };
    let (m, strength) = (lobe.exponent, lobe.strength);
    let moved = AtomicUsize::new(0);
    capture.for_each_tile(|off, tile| {
        let tn = tile.n_pixels();
        est.normals[off..off + tn]
            .par_chunks_mut(CHUNK)
            .zip(est.albedo[off * c..(off + tn) * c].par_chunks_mut(CHUNK * c))
            .enumerate()
            .for_each_init(
                || (Scratch::new(capture, near), vec![0f64; n], vec![0f64; c]),
                |(s, corrected, num), (chunk, (nrm, alb))| {
                    for dp in 0..nrm.len() {
                        let lp = chunk * CHUNK + dp;
                        let p = off + lp;
                        let st = &statuses[p * n..(p + 1) * n];
                        if st.iter().filter(|&&x| x == status::USED).count() != 3
                            || nrm[dp] == [0.0; 3]
                            || fitted[p]
                        {
                            continue;
                        }
                        let pixel = capture.pixels[p] as usize;
                        let samples = tile.pixel_samples(lp);
                        s.load(near, &depth, capture.width, pixel, samples, c, Some(st));
                        for (u, &sk) in s.used.iter_mut().zip(st) {
                            *u = sk == status::USED;
                        }
                        let start = unit([nrm[dp][0] as f64, nrm[dp][1] as f64, nrm[dp][2] as f64]);
                        let mut nv = start;
                        for _ in 0..EXACT_ITERATIONS {
                            for (k, x) in corrected.iter_mut().enumerate() {
                                *x = s.g[k]
                                    - strength * s.b[k] * (-m * (1.0 - dot(s.h[k], nv))).exp();
                            }
                            let Some(x) =
                                crate::solve::lambert::solve_with(&s.v, Some(&s.used), corrected)
                            else {
                                break;
                            };
                            if step_settles(&mut nv, unit([x[0], x[1], x[2]])) {
                                break;
                            }
                        }
                        if !turned_away(nv, start) {
                            continue;
                        }
                        moved.fetch_add(1, Ordering::Relaxed);
                        nrm[dp] = [nv[0] as f32, nv[1] as f32, nv[2] as f32];
                        num.fill(0.0);
                        let mut den = 0f64;
                        for k in (0..n).filter(|&k| s.used[k]) {
                            let a = dot(s.v[k], nv).max(0.0);
                            let l = strength * s.b[k] * (-m * (1.0 - dot(s.h[k], nv))).exp();
                            for (ch, x) in num.iter_mut().enumerate() {
                                *x += a * (samples[k * c + ch] as f64 - l);
                            }
                            den += a * a;
                        }
                        albedo_from_sums(num, den, &mut alb[dp * c..(dp + 1) * c]);
                    }
                },
            );
        Ok(())
    })?;
    Ok(moved.into_inner())
}

/// The unit normals n with n · l₁ = a and n · l₂ = b (unit l₁, l₂): the root closer to `hint`;
/// with no real root (readings too bright or too dark for any normal) the nearest point of the
/// plane of l₁ and l₂'s solutions. `None` when l₁ ∥ l₂.
fn two_source(l1: [f64; 3], l2: [f64; 3], a: f64, b: f64, hint: [f64; 3]) -> Option<[f64; 3]> {
    let cos = dot(l1, l2);
    let det = 1.0 - cos * cos;
    if det < 1e-6 {
        return None;
    }
    let alpha = (a - b * cos) / det;
    let beta = (b - a * cos) / det;
    let in_plane = add3(scale(l1, alpha), scale(l2, beta));
    let cr = cross(l1, l2);
    let gamma = ((1.0 - dot(in_plane, in_plane)) / dot(cr, cr))
        .max(0.0)
        .sqrt();
    let p = add3(in_plane, scale(cr, gamma));
    let q = add3(in_plane, scale(cr, -gamma));
    let best = if dot(p, hint) >= dot(q, hint) { p } else { q };
    (norm(best) > 1e-9).then(|| unit(best))
}

/// Pixels left with two usable lights (completed by the method from two lights and the
/// neighbours' albedo ρ̂, the median grey albedo of the nearest pixels that passed the χ² test
/// in `reliable`, however far they are): the same correction as [`correct_exact`] with two-source photometric stereo
/// of known albedo, n ← normalise(n + two_source((I − b s exp(−m (1 − n · h))) / (ρ̂ b))), the
/// root nearer the current normal; pixels flagged in `fitted` are left alone. Returns the
/// number of pixels whose normal moved by more than 0.1°.
pub fn correct_two(
    capture: &Capture,
    near: &NearLights,
    est: &mut Estimate,
    lobe: &CaptureLobe,
    reliable: &[bool],
    fitted: &[bool],
    hints: &[[f32; 3]],
) -> crate::base::error::Result<usize> {
    let n = capture.n_lights();
    let c = capture.channels;
    let (w, h) = (capture.width, capture.height);
    let depth = near.surface();
    let Some(statuses) = est.light_status.clone() else {
        return Ok(0);
    };
    let used_count = |p: usize| {
        statuses[p * n..(p + 1) * n]
            .iter()
            .filter(|&&x| x == status::USED)
            .count()
    };
    let todo: Vec<usize> = (0..capture.n_pixels())
        .filter(|&p| used_count(p) == 2 && est.normals[p] != [0.0; 3] && !fitted[p])
        .collect();
    if todo.is_empty() {
        return Ok(0);
    }
    // Grey albedo of the pixels that passed the test with three lights or more, full frame.
    let mut albedo_map = vec![f32::NAN; w * h];
    for (p, &i) in capture.pixels.iter().enumerate() {
        if reliable[p] && used_count(p) >= 3 && est.normals[p] != [0.0; 3] {
            albedo_map[i as usize] = est.albedo[p * c..(p + 1) * c].iter().sum::<f32>() / c as f32;
        }
    }
    let view = if capture.is_tiled() {
        std::borrow::Cow::Owned(capture.sampled(&todo)?)
    } else {
        std::borrow::Cow::Borrowed(capture)
    };
    let (m, strength) = (lobe.exponent, lobe.strength);
    let mut s = Scratch::new(capture, near);
    let mut window = Vec::new();
    let mut moved = 0;
    for (j, &p) in todo.iter().enumerate() {
        let pixel = capture.pixels[p] as usize;
        let (row, col) = (pixel / w, pixel % w);
        // Growing windows, as far as the nearest judged pixels are (a cast shadow is wider
        // in pixels the finer the image).
        let rho = crate::solve::metrics::median_in_growing_window(
            &albedo_map,
            w,
            h,
            (row, col),
            w.max(h),
            &mut window,
        );
        if !rho.is_finite() {
            continue;
        }
        let samples = view.pixel_samples(if capture.is_tiled() { j } else { p });
        let st = &statuses[p * n..(p + 1) * n];
        s.load(near, &depth, w, pixel, samples, c, Some(st));
        let lights: Vec<usize> = (0..n).filter(|&k| st[k] == status::USED).collect();
        let (k1, k2) = (lights[0], lights[1]);
        let dir = |k: usize| scale(s.v[k], 1.0 / s.b[k].max(1e-300));
        let nrm = est.normals[p];
        let start = unit([nrm[0] as f64, nrm[1] as f64, nrm[2] as f64]);
        // The root is chosen by the surface's normal first, then by the iterate.
        let hint = hints[pixel];
        let mut nv = if hint == [0.0; 3] || hint.iter().any(|x| !x.is_finite()) {
            start
        } else {
            unit([hint[0] as f64, hint[1] as f64, hint[2] as f64])
        };
        for _ in 0..EXACT_ITERATIONS {
            let read = |k: usize, nv: [f64; 3]| {
                (s.g[k] - strength * s.b[k] * (-m * (1.0 - dot(s.h[k], nv))).exp()) / (rho * s.b[k])
            };
            let Some(x) = two_source(dir(k1), dir(k2), read(k1, nv), read(k2, nv), nv) else {
                break;
            };
            if step_settles(&mut nv, x) {
                break;
            }
        }
        if !turned_away(nv, start) {
            continue;
        }
        moved += 1;
        est.normals[p] = [nv[0] as f32, nv[1] as f32, nv[2] as f32];
        for ch in 0..c {
            let (mut num, mut den) = (0f64, 0f64);
            for &k in &lights {
                let a = dot(s.v[k], nv).max(0.0);
                let l = strength * s.b[k] * (-m * (1.0 - dot(s.h[k], nv))).exp();
                num += a * (samples[k * c + ch] as f64 - l);
                den += a * a;
            }
            est.albedo[p * c + ch] = if den > 0.0 {
                (num / den).max(0.0) as f32
            } else {
                0.0
            };
        }
    }
    Ok(moved)
}

/// What [`correct_without_spare`] did, for `report.json`.
#[derive(Clone, Debug, Serialize)]
pub struct SpareSummary {
    /// The capture's lobe.
    pub lobe: CaptureLobe,
    /// Pixels with three usable lights whose normal moved ([`correct_exact`]).
    pub corrected_pixels: usize,
    /// Pixels with two usable lights whose normal moved ([`correct_two`]).
    pub corrected_two_light_pixels: usize,
}

/// The near model's answer to pixels without a spare light (the four-light rig's pixels in one
/// light's shadow): [`fit_capture_lobe`] from the pixels `reliable` flags, then
/// [`correct_exact`], then [`correct_two`] with the roots chosen by the normals of
/// `surface(est)` (full frame: the surface of the corrected normals, whose three-light pixels
/// no longer lean toward their highlights), leaving the pixels `fitted` by [`refine`] alone.
/// `None` when no highlight was dropped at a trusted pixel (then nothing changes).
pub fn correct_without_spare(
    capture: &Capture,
    near: &NearLights,
    est: &mut Estimate,
    reliable: &[bool],
    fitted: &[bool],
    surface: impl FnOnce(&Estimate) -> crate::base::error::Result<Vec<[f32; 3]>>,
) -> crate::base::error::Result<Option<SpareSummary>> {
    let Some(lobe) = fit_capture_lobe(capture, near, est, reliable)? else {
        return Ok(None);
    };
    let corrected_pixels = correct_exact(capture, near, est, &lobe, fitted)?;
    let hints = surface(est)?;
    let corrected_two_light_pixels =
        correct_two(capture, near, est, &lobe, reliable, fitted, &hints)?;
    Ok(Some(SpareSummary {
        lobe,
        corrected_pixels,
        corrected_two_light_pixels,
    }))
}

/// Two unit vectors orthogonal to unit `n` and to each other.
#[inline]
pub(crate) fn basis(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let a = if n[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let t1 = unit(cross(n, a));
    (t1, cross(n, t1))
}

#[inline]
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

#[inline]
fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

#[inline]
fn add3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[inline]
fn unit(a: [f64; 3]) -> [f64; 3] {
    let l = norm(a);
    if l > 0.0 {
        scale(a, 1.0 / l)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// One damped step of the corrected-normal iteration: `nv` moves to the unit mean of itself and
/// `target` (unit); true when it moved by less than 0.01° (settled).
fn step_settles(nv: &mut [f64; 3], target: [f64; 3]) -> bool {
    let next = unit(add3(*nv, target));
    let step = dot(next, *nv);
    *nv = next;
    step > (0.01f64).to_radians().cos()
}

/// Whether a corrected normal `nv` faces the camera and turned more than 0.1° from `start`
/// (worth writing back).
fn turned_away(nv: [f64; 3], start: [f64; 3]) -> bool {
    nv[2] > 0.0 && dot(nv, start) <= (0.1f64).to_radians().cos()
}

/// Per-channel albedo from the normal equations of a fixed normal: `num[ch] / den` (the
/// readings' projections on the shading over its square), clamped at zero; zero when `den` is 0.
fn albedo_from_sums(num: &[f64], den: f64, out: &mut [f32]) {
    for (o, &x) in out.iter_mut().zip(num) {
        *o = if den > 0.0 {
            (x / den).max(0.0) as f32
        } else {
            0.0
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One pixel under a ring of 12 distant lights 14° off the axis, with a Gaussian lobe about
    /// each half vector: the lobe fit recovers the normal (the diffuse fit does not).
    #[test]
    fn the_lobe_fit_recovers_a_normal_whose_every_light_is_highlighted() {
        let u = [0.0, 0.0, 1.0];
        let slant = 14f64.to_radians();
        let v: Vec<[f64; 3]> = (0..12)
            .map(|k| {
                let t = (30.0 * k as f64 + 15.0).to_radians();
                [slant.sin() * t.cos(), slant.sin() * t.sin(), slant.cos()]
            })
            .collect();
        let h: Vec<[f64; 3]> = v.iter().map(|l| unit(add3(*l, u))).collect();
        let b = vec![1.0; 12];
        let used = vec![true; 12];
        let nodes = grid();
        for (tilt, azimuth) in [(3.0f64, 40.0f64), (5.0, 200.0), (7.0, 300.0)] {
            let (t, a) = (tilt.to_radians(), azimuth.to_radians());
            let n = [t.sin() * a.cos(), t.sin() * a.sin(), t.cos()];
            let (rho, spec, m) = (0.5, 0.6, 100.0);
            let g: Vec<f64> = (0..12)
                .map(|k| rho * dot(v[k], n) + spec * (-m * (1.0 - dot(h[k], n))).exp())
                .collect();
            // Every light carries a lobe of at least 5% of its diffuse reading.
            let least = (0..12)
                .map(|k| (g[k] - rho * dot(v[k], n)) / (rho * dot(v[k], n)))
                .fold(f64::INFINITY, f64::min);
            assert!(least > 0.05, "tilt {tilt}°: least lobe share {least}");
            let d = PixelData {
                v: &v,
                h: &h,
                b: &b,
                g: &g,
                used: &used,
            };
            let (e, found, r, s) = fit_pixel(&d, u, &[], m, &nodes, true);
            let err = dot(found, n).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(err < 0.5, "tilt {tilt}°: {err}° off, residual {e}");
            assert!((r - rho).abs() < 0.05 && (s - spec).abs() < 0.05, "{r} {s}");
            let x = crate::solve::lambert::solve_with(&v, None, &g).unwrap();
            let diffuse = unit([x[0], x[1], x[2]]);
            let err_diffuse = dot(diffuse, n).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(
                err_diffuse > 5.0,
                "the diffuse fit errs by only {err_diffuse}°"
            );
            assert!(diffuse_residual(&d) > 10.0 * e.max(1e-12));
        }
    }

    /// The fast path of [`refine`] (χ² pre-gate, searches from nearby starts, the grid at most
    /// once) against the brute force (the whole grid and its searches at every pixel): on a
    /// near-ring sphere with Blinn–Phong highlights, the refined pixels' fits reach the brute
    /// force's residual, and most pixels need no grid.
    #[test]
    fn the_fast_fit_reaches_the_brute_force_residual() {
        use crate::scene::near::{synthesize_near, NearRig, NearSpec};
        let r = synthesize_near(&NearSpec {
            size: 40,
            ..NearSpec::new(crate::scene::SceneKind::Sphere, NearRig::Ring)
        })
        .unwrap();
        let capture = r.capture().unwrap();
        let near = capture.lights.near.clone().unwrap();
        let params = crate::solve::detect::DetectionParams::default();
        let detection =
            crate::solve::tiled::detect_tiles(&capture, &params, &crate::base::progress::Silent)
                .unwrap();
        let mut est =
            crate::solve::lambert::solve_subsets(&capture, None, &crate::base::progress::Silent);
        let mut memory = LobeMemory::default();
        let (summary, refined) = refine(
            &capture,
            &near,
            &mut est,
            &detection.noise,
            params.confidence,
            &mut memory,
        )
        .unwrap();
        let m = summary.exponent.unwrap();
        assert!(summary.refined_pixels > 100, "{summary:?}");
        assert!(
            summary.grid_pixels * 4 < summary.fitted_pixels,
            "most fits should start nearby: {summary:?}"
        );
        let nodes = grid();
        let depth = near.surface();
        let statuses = est.light_status.clone().unwrap();
        let n = capture.n_lights();
        let mut s = Scratch::new(&capture, &near);
        let (mut worse, mut total) = (0, 0);
        for p in (0..capture.n_pixels()).filter(|&p| refined[p]) {
            let pixel = capture.pixels[p] as usize;
            let u = s.load(
                &near,
                &depth,
                capture.width,
                pixel,
                capture.pixel_samples(p),
                capture.channels,
                Some(&statuses[p * n..(p + 1) * n]),
            );
            let d = s.data();
            let fast = est.normals[p];
            let fast = [fast[0] as f64, fast[1] as f64, fast[2] as f64];
            let e_fast = fit_at(&d, fast, m).0;
            let (e_brute, ..) = fit_pixel(&d, u, &[], m, &nodes, true);
            total += 1;
            if e_fast > 1.05 * e_brute + 1e-12 {
                worse += 1;
            }
        }
        assert!(
            worse * 50 <= total,
            "{worse} of {total} refined pixels above the brute-force residual"
        );
    }
}
