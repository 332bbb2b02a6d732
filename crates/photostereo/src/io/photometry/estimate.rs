//! What the readings themselves say about their photometry.
//!
//! **Response.** A Lambertian surface lit by every light reads `x_k = m_k ρ n · l_k`, where
//! `m_k` is what is known of light k's brightness (its given intensity times its image's
//! exposure): across the lights, a pixel's linear readings lie in the 3-D subspace the light
//! vectors span. Read through the wrong response they do not (a power of a sum is no sum of
//! powers). Two things tell a candidate response (powers 1 to 3 in steps of 0.02, and sRGB)
//! from the right one.
//!
//! *The lights' known brightness* (the basis `"brightness"`). A power law is blind to every
//! factor: read through `linear = encoded^γ'` a file encoded with `γ` gives
//! `(m_k ρ n · l_k)^(γ'/γ)`, so each light's gain `G_k` (its brightness as the rank-3 model
//! `x_rk ≈ G_k l_k · b_r` fitted to the readings sees it) is `m_k^(γ'/γ)` times what the
//! surface's shape and material make of the light's direction. Regressing `ln(G_k / m_k)` on
//! `ln m_k`, with one constant per channel and a term linear in `l_k` for the direction's
//! share, gives the slope `β = γ'/γ − 1`: zero under the right response whatever the
//! material, with a standard error from the regression's residuals. The exponent is the
//! candidate's `γ' / (1 + β)` where `|β|` is smallest. This needs brightness that varies in a
//! way the directions do not explain — calibrated intensities such as DiLiGenT's (×6 from the
//! dimmest light to the brightest), or exposures that change — and is used when its standard
//! error is at most [`BRIGHTNESS_MAX_STD`] and it is no exponent below 1 (which no file has:
//! the given intensities then disagree with the images, and the note says so). The fits are
//! robust: each row's `b_r` is fitted with every reading relative to its light's gain (so that
//! the gains scale with the lights), each gain is the median ratio of readings to model over
//! the rows, and the regression is fitted by least trimmed squares over images and then by
//! least squares on the images consistent with it (a per-image 99% test): a minority of images
//! whose given intensity or exposure is wrong is found, left out and named.
//!
//! *The shading* (the basis `"shading"`, when the brightness does not decide). A candidate is
//! scored by how well the same rank-3 model fits the readings it makes linear, the gains
//! fitted by least squares, each residual weighted by the noise of its encoded value (the
//! quantisation step) carried through the candidate's slope: the residuals are measured where
//! the noise is, in the file's own units, so the candidates' scores are comparable χ² values.
//! (Measured relative to the linear values instead, a response that flattens every reading
//! towards one value would fit best.) The subspace is anchored on the lights rather than
//! fitted freely: with lights around the viewing direction any smooth function of `n · l` is
//! nearly affine in the light's direction, so a freely fitted rank-3 model absorbs a
//! compressive response as a constant and cannot tell it from linear. The score is the median
//! over rows of the reduced χ² (highlights do not move it); the spread is that of the best
//! power over eight disjoint sets of pixels. The shading cannot tell a power-law response from
//! a material whose brightness falls off as `(n · l)^p` (a Lambertian surface through a power
//! `p` reads the same): on real objects this estimate carries the material's falloff (surfaces
//! darker than matte at grazing light lower it), which no spread over pixels shows.
//!
//! Either way sRGB is chosen when it fits the shading at least as well as the power nearest the
//! exponent (and, with the brightness basis, its own slope `β` is within the 99% interval of
//! zero or [`SYSTEMATIC`]), linear when 1 lies within the 99% interval of the exponent or
//! [`SYSTEMATIC`] of it. Only pixels lit by every light ([`lit_rows`]) enter: a shadowed
//! reading is no projection of the normal, a saturated one no measurement; the shading is
//! scored on the well-lit ones among them.
//!
//! **Offset.** Light left on in the room, or a black level not removed, adds to every image
//! the same amount per pixel: readings `x_k = s_k (ρ n · l_k + a)`, a fourth dimension the
//! Lambertian model lacks. [`offset_check`] fits it at each pixel and reports the median
//! offset relative to the pixel's mean reading, with its spread over disjoint pixel sets. The
//! closer the lights lie to a cone around one axis, the more an offset looks like a tilt of
//! the normal towards that axis, and the more any misfit of the model feigns one: an offset is
//! reported when it exceeds the model's relative error κ divided by how far its pattern lies
//! from the lights' span.

use super::Response;
use rayon::prelude::*;
use serde::Serialize;

/// Encoded (not yet linear) readings of some pixels of a capture.
#[derive(Clone, Debug)]
pub struct Samples {
    /// `[row][image]`: one row per pixel and channel (pixel-major, channels interleaved).
    pub encoded: Vec<f32>,
    /// The ambient frame's encoded value per row, when there is one.
    pub ambient: Option<Vec<f32>>,
    pub images: usize,
    /// Channels per pixel: row `r` is channel `r % channels`.
    pub channels: usize,
    /// Bits per sample of the encoded values (8, 16; 32 for float data).
    pub bit_depth: u8,
}

impl Samples {
    fn rows(&self) -> usize {
        self.encoded.len() / self.images.max(1)
    }
}

/// The lights as the estimate sees them.
#[derive(Clone, Debug)]
pub struct LightInfo {
    /// Unit directions.
    pub directions: Vec<[f64; 3]>,
    /// Each light's red, green and blue intensity (grey images use their mean).
    pub intensities: Vec<[f64; 3]>,
    /// What each image's linear readings are multiplied by (1 / its exposure factor).
    pub scale: Vec<f64>,
    /// The same for the ambient frame.
    pub ambient_scale: f64,
}

/// The response the capture shows, with its uncertainty (report.json
/// `photometry.response_estimate`).
#[derive(Clone, Debug, Serialize)]
pub struct ResponseEstimate {
    /// The response chosen: `linear`, `srgb` or `gamma:G`.
    pub chosen: String,
    /// What the estimate rests on: `brightness` (the lights' known brightness, blind to the
    /// material) or `shading` (the rank-3 fit alone, which a material's falloff biases).
    pub basis: String,
    /// The power-law exponent the basis gives.
    pub gamma: f64,
    /// Its standard error.
    pub gamma_std: f64,
    /// The brightness test's slope β under sRGB and its standard error (absent without a
    /// lever).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub srgb_slope: Option<[f64; 2]>,
    /// When the brightness test gives an exponent significantly below 1 (no file's): that
    /// exponent and its standard error. The given intensities then disagree with the images
    /// (each light's brightness as the readings show it goes as its intensity to this power)
    /// and the estimate rests on the shading.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub intensities_disagree: Option<[f64; 2]>,
    /// The images (numbered from 0 in the capture's order) whose brightness in the readings
    /// disagrees with their given intensity and exposure under the exponent the others share,
    /// left out of the brightness test. When they are not a minority, `intensities_disagree`
    /// is set.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub images_left_out: Vec<usize>,
    /// The best power by the shading alone, with its standard error over pixel sets.
    pub gamma_shading: f64,
    pub gamma_shading_std: f64,
    /// Median reduced χ² of the rank-3 fit under the power `gamma` (nearest candidate),
    /// sRGB, and linear.
    pub score_gamma: f64,
    pub score_srgb: f64,
    pub score_linear: f64,
    /// Pixel-channel rows lit by every light that were used.
    pub rows: usize,
    #[serde(skip)]
    pub response: Response,
}

impl ResponseEstimate {
    /// The images the brightness test left out, for a note: how many, and which (numbered
    /// from 1, runs as `a–b`); `None` when none was.
    pub fn left_out_note(&self) -> Option<String> {
        let v = &self.images_left_out;
        if v.is_empty() {
            return None;
        }
        let mut runs: Vec<String> = Vec::new();
        let mut i = 0;
        while i < v.len() {
            let mut j = i;
            while j + 1 < v.len() && v[j + 1] == v[j] + 1 {
                j += 1;
            }
            runs.push(if j > i {
                format!("{}–{}", v[i] + 1, v[j] + 1)
            } else {
                format!("{}", v[i] + 1)
            });
            i = j + 1;
        }
        Some(format!(
            "{} image(s) ({}, numbered from 1) show a brightness that disagrees with their given \
             intensity and exposure under the exponent the others share, and were left out of \
             the brightness test",
            v.len(),
            runs.join(", ")
        ))
    }
}

/// The relative model error the detector's noise model uses by default (κ).
const KAPPA: f64 = 0.01;
/// Disjoint pixel sets for the estimates' spread.
const GROUPS: usize = 8;
/// Student's t quantile 0.995 with 7 degrees of freedom (the spread of [`GROUPS`] estimates):
/// the exponent is taken as 1 (linear) when it lies within this many standard errors of it,
/// a two-sided 99% interval.
const T7_995: f64 = 3.499;
/// The largest standard error of the brightness basis's exponent for it to decide: half the
/// ±0.1 that separates the power laws files are written with (1.8, 2.2, 2.4).
pub const BRIGHTNESS_MAX_STD: f64 = 0.05;

/// The systematic error allowed the brightness test, in its slope β and in the exponent near
/// 1: what the lights' calibration and a material's departure from Lambert's law leave. It
/// lies far below the gaps between the responses files are written with (1; 1.8; 2.2 and sRGB;
/// 2.4), so linear is chosen for an exponent within it of 1 and sRGB for a slope within it of
/// 0.
pub const SYSTEMATIC: f64 = 0.025;

/// The candidates' exponents: 1 to 3 in steps of 0.02. Files are encoded to spend their levels
/// on the dark end (exponents above 1); the shading searches none below 1, because a surface
/// darker than Lambertian at grazing light reads like one.
fn gamma_grid() -> Vec<f64> {
    (0..=100).map(|i| 1.0 + 0.02 * i as f64).collect()
}

/// The least elevation of every light above a used pixel's horizon (by its pilot normal).
pub const MIN_ELEVATION_DEG: f64 = 15.0;

/// The rows (pixel-channel) lit by every light and read within range: every encoded reading
/// five quantisation levels above black (0.5% of full scale for float data) and none above 99%
/// of full scale; the row's normal, fitted by least squares to the readings made linear by
/// the `pilot` response (each divided by its light's known brightness), sees every light at
/// least [`MIN_ELEVATION_DEG`] above its horizon (attached shadows and grazing light out); no
/// reading below half of that fit's prediction (a cast shadow). The choice rests on the fitted
/// normal, not on how one reading compares with another, so that it does not favour pixels
/// where a dim light happens to read high (which would bias the lights' gains).
pub fn lit_rows(s: &Samples, lights: &LightInfo, pilot: Response) -> Vec<usize> {
    let level: f64 = match s.bit_depth {
        8 => 1.0 / 255.0,
        16 => 1.0 / 65535.0,
        _ => 0.001,
    };
    let lo = (5.0 * level).max(0.005) as f32;
    let c = s.channels.max(1);
    let min_cos = MIN_ELEVATION_DEG.to_radians().sin();
    // 1 / m per light and channel (m: intensity × exposure); unknown brightness counts as 1.
    let inv: Vec<f64> = (0..s.images * c)
        .map(|i| {
            let (k, ch) = (i / c, i % c);
            brightness(lights, k, ch, c).map_or(1.0, |m| 1.0 / m)
        })
        .collect();
    let dirs = &lights.directions;
    (0..s.rows())
        .filter(|&r| {
            let row = &s.encoded[r * s.images..(r + 1) * s.images];
            let ch = r % c;
            if dirs.len() != s.images || !row.iter().all(|&e| e >= lo && e <= 0.99) {
                return false;
            }
            let x: Vec<f64> = row
                .iter()
                .enumerate()
                .map(|(k, &e)| pilot.linear(e as f64) * inv[k * c + ch])
                .collect();
            let b = solve_weighted(dirs.iter().zip(&x).map(|(d, v)| (*d, *v, 1.0)));
            let norm = dot(b, b).sqrt();
            norm > 0.0
                && dirs.iter().zip(&x).all(|(d, v)| {
                    let p = dot(*d, b);
                    p >= min_cos * norm && *v >= 0.5 * p
                })
        })
        .collect()
}

/// Light `k`'s known brightness in channel `ch` of `c` (its intensity × exposure, relative);
/// `None` when it is not a positive finite number. Unknown intensities count as 1.
fn brightness(lights: &LightInfo, k: usize, ch: usize, c: usize) -> Option<f64> {
    let m = lights
        .intensities
        .get(k)
        .map_or(1.0, |int| channel_intensity(int, ch, c))
        / lights.scale.get(k).copied().unwrap_or(1.0);
    (m > 0.0 && m.is_finite()).then_some(m)
}

/// Of `rows`, those the shading is scored on: the encoded readings, each divided by its
/// light's known brightness to the power 1/2.2 (the common encoding's), the smallest at least a
/// quarter of the largest. Through a 2.2 power that keeps each light at least 4.7% of the
/// best-lit one's `n · l`; read linearly, 25%: the grazing light where a material departs most
/// from Lambert's law, and which the shading cannot tell from a response, stays out. (The
/// brightness test keeps every row: its choice would depend on the readings compared.)
fn well_lit(s: &Samples, lights: &LightInfo, rows: &[usize]) -> Vec<usize> {
    let c = s.channels.max(1);
    let weight = |k: usize, ch: usize| -> f32 {
        brightness(lights, k, ch, c).map_or(1.0, |m| m.powf(-1.0 / 2.2) as f32)
    };
    rows.iter()
        .copied()
        .filter(|&r| {
            let row = &s.encoded[r * s.images..(r + 1) * s.images];
            let (mut min, mut max) = (f32::MAX, 0.0f32);
            for (k, &e) in row.iter().enumerate() {
                let v = e * weight(k, r % c);
                min = min.min(v);
                max = max.max(v);
            }
            min >= 0.25 * max
        })
        .collect()
}

/// The response rows are first chosen under: a 2.2 power for 8-bit data, linear for deeper.
pub fn pilot_response(s: &Samples) -> Response {
    if s.bit_depth <= 8 {
        Response::Gamma(2.2)
    } else {
        Response::Linear
    }
}

/// Estimates the capture's response from `s` and its `lights`. `None` with fewer than five
/// images or fewer than 30 rows lit by every light (too little to tell).
pub fn estimate_response(s: &Samples, lights: &LightInfo) -> Option<ResponseEstimate> {
    // Rows chosen under a pilot response, then again under the first estimate's.
    let pilot = pilot_response(s);
    let other = if pilot == Response::Linear {
        Response::Gamma(2.2)
    } else {
        Response::Linear
    };
    let first = estimate_on(s, lights, &lit_rows(s, lights, pilot))
        .or_else(|| estimate_on(s, lights, &lit_rows(s, lights, other)));
    let rows = lit_rows(s, lights, first.as_ref()?.response);
    estimate_on(s, lights, &rows).or(first)
}

/// [`estimate_response`] on the given rows.
fn estimate_on(s: &Samples, lights: &LightInfo, rows: &[usize]) -> Option<ResponseEstimate> {
    if s.images < 5 || rows.len() < 30 || lights.directions.len() != s.images {
        return None;
    }
    let grid = gamma_grid();
    let mut candidates: Vec<Response> = grid.iter().map(|&g| Response::Gamma(g)).collect();
    candidates.push(Response::Srgb);
    let fit = Fit { s, rows, lights };
    let shading_rows = well_lit(s, lights, rows);
    let shading = Fit {
        s,
        rows: if shading_rows.len() >= 30 {
            &shading_rows
        } else {
            rows
        },
        lights,
    };
    // Per candidate: each row's reduced χ² (shading) and the brightness slope β ± se.
    let per: Vec<(Vec<f64>, Option<Slope>)> = candidates
        .par_iter()
        .map(|&r| {
            (
                shading.row_chi2(r),
                brightness_slope(&fit.gains(r), s, lights),
            )
        })
        .collect();
    let srgb = grid.len();
    let score = |i: usize, group: Option<usize>| -> f64 {
        let mut v: Vec<f64> = per[i]
            .0
            .iter()
            .enumerate()
            .filter(|(j, _)| group.is_none_or(|g| j % GROUPS == g))
            .map(|(_, x)| *x)
            .collect();
        median(&mut v)
    };
    let best = |group: Option<usize>| -> usize {
        (0..grid.len())
            .min_by(|&a, &b| score(a, group).total_cmp(&score(b, group)))
            .unwrap_or(0)
    };
    let shading_best = best(None);
    let group_best: Vec<f64> = (0..GROUPS).map(|g| grid[best(Some(g))]).collect();
    let mean = group_best.iter().sum::<f64>() / GROUPS as f64;
    let var = group_best.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / (GROUPS - 1) as f64;
    // The grid's own resolution bounds how small the error can be.
    let shading_std = (var / GROUPS as f64).sqrt().max(0.02 / 12f64.sqrt());
    let brightness = brightness_exponent(&grid, &per);
    // An exponent significantly below 1 is no file's, and images that do not share one
    // exponent no capture's: the given intensities disagree with the images, and the
    // brightness cannot be the basis.
    let disagree = brightness
        .as_ref()
        .filter(|b| !b.slope.majority() || b.gamma < 1.0 - (b.t * b.sd).max(SYSTEMATIC));
    let (basis, gamma, gamma_std, t) = match &brightness {
        Some(b) if b.sd <= BRIGHTNESS_MAX_STD && disagree.is_none() => {
            ("brightness", b.gamma, b.sd, b.t)
        }
        _ => ("shading", grid[shading_best], shading_std, T7_995),
    };
    // The candidate nearest the exponent, for its shading score.
    let near = grid
        .iter()
        .enumerate()
        .min_by(|a, b| (a.1 - gamma).abs().total_cmp(&(b.1 - gamma).abs()))
        .map_or(0, |(i, _)| i);
    let score_gamma = score(near, None);
    let score_srgb = score(srgb, None);
    let srgb_slope = per[srgb].1.as_ref().map(|b| [b.beta, b.se]);
    let srgb_consistent = match (basis, &per[srgb].1) {
        ("brightness", Some(b)) => b.beta.abs() <= (t_995(b.dof) * b.se).max(SYSTEMATIC),
        ("brightness", None) => false,
        _ => true,
    };
    let response = if srgb_consistent && score_srgb <= score_gamma {
        Response::Srgb
    } else if (gamma - 1.0).abs() <= (t * gamma_std).max(SYSTEMATIC) {
        Response::Linear
    } else {
        Response::Gamma((gamma * 100.0).round() / 100.0)
    };
    Some(ResponseEstimate {
        chosen: response.name(),
        basis: basis.into(),
        gamma,
        gamma_std,
        srgb_slope,
        intensities_disagree: disagree.map(|d| [d.gamma, d.sd]),
        images_left_out: brightness.map_or(Vec::new(), |b| b.slope.left_out),
        gamma_shading: grid[shading_best],
        gamma_shading_std: shading_std,
        score_gamma,
        score_srgb,
        score_linear: score(0, None),
        rows: rows.len(),
        response,
    })
}

/// What the lights' brightness gives: the exponent, its standard error, the 99% t quantile of
/// its regression, and that regression.
struct Brightness {
    gamma: f64,
    sd: f64,
    t: f64,
    slope: Slope,
}

/// The exponent the lights' brightness gives: `γ' / (1 + β)` at the power candidate whose
/// slope `|β|` is smallest. `None` without a lever (the brightness constant, or explained by
/// the directions).
fn brightness_exponent(grid: &[f64], per: &[(Vec<f64>, Option<Slope>)]) -> Option<Brightness> {
    let (i, slope) = grid
        .iter()
        .enumerate()
        .filter_map(|(i, _)| per[i].1.as_ref().map(|s| (i, s)))
        .min_by(|a, b| a.1.beta.abs().total_cmp(&b.1.beta.abs()))?;
    let b = slope.beta;
    if 1.0 + b <= 0.0 || !slope.se.is_finite() {
        return None;
    }
    Some(Brightness {
        gamma: grid[i] / (1.0 + b),
        sd: grid[i] * slope.se / (1.0 + b).powi(2),
        t: t_995(slope.dof),
        slope: slope.clone(),
    })
}

/// Student's t quantile 0.995 with `dof` degrees of freedom (Cornish–Fisher expansion about
/// the normal quantile; within 1% from 5 degrees of freedom up).
fn t_995(dof: f64) -> f64 {
    let z: f64 = 2.575_829;
    let d = dof.max(1.0);
    z + (z.powi(3) + z) / (4.0 * d)
        + (5.0 * z.powi(5) + 16.0 * z.powi(3) + 3.0 * z) / (96.0 * d * d)
        + (3.0 * z.powi(7) + 19.0 * z.powi(5) + 17.0 * z.powi(3) - 15.0 * z) / (384.0 * d * d * d)
}

/// The brightness test at one candidate response ([`brightness_slope`]).
#[derive(Clone, Debug)]
struct Slope {
    /// The slope β, its standard error and the fit's degrees of freedom.
    beta: f64,
    se: f64,
    dof: f64,
    /// Images (0-based, in the capture's order) whose brightness the consistency test found
    /// inconsistent with the others' common exponent, left out of the fit.
    left_out: Vec<usize>,
    /// Images in the regression.
    images: usize,
}

impl Slope {
    /// Whether the images consistent with the common exponent are a majority (the most a
    /// high-breakdown fit can rest on); otherwise the slope is that of every image.
    fn majority(&self) -> bool {
        2 * self.left_out.len() < self.images
    }
}

/// The brightness regression's points: one per light and channel, grouped by image.
struct Regression {
    /// `[point][parameter]`: a constant per channel, the light's direction, `ln` of its known
    /// brightness (the last parameter, whose coefficient is β).
    design: Vec<f64>,
    /// `ln(G_kc / I_kc)`.
    y: Vec<f64>,
    /// Per image in the regression: its index and its points' range.
    groups: Vec<(usize, std::ops::Range<usize>)>,
    p: usize,
}

impl Regression {
    fn new(gains: &[f64], s: &Samples, lights: &LightInfo) -> Self {
        let c = s.channels.max(1);
        let p = c + 4;
        let (mut design, mut y, mut groups) = (Vec::new(), Vec::new(), Vec::new());
        for (k, (d, i)) in lights
            .directions
            .iter()
            .zip(&lights.intensities)
            .enumerate()
        {
            let start = y.len();
            for ch in 0..c {
                let (g, int) = (gains[k * c + ch], channel_intensity(i, ch, c));
                if !(g > 0.0 && int > 0.0 && lights.scale[k] > 0.0) {
                    continue;
                }
                let mut row = vec![0.0; p];
                row[ch] = 1.0;
                row[c..c + 3].copy_from_slice(d);
                row[c + 3] = (int / lights.scale[k]).ln();
                design.extend_from_slice(&row);
                y.push((g / int).ln());
            }
            if y.len() > start {
                groups.push((k, start..y.len()));
            }
        }
        Regression {
            design,
            y,
            groups,
            p,
        }
    }

    fn row(&self, i: usize) -> &[f64] {
        &self.design[i * self.p..(i + 1) * self.p]
    }

    /// Least squares on the points of the groups `subset`: the coefficients and the inverse
    /// of the normal matrix; `None` when the subset does not determine them.
    fn fit(&self, subset: &[usize]) -> Option<(Vec<f64>, nalgebra::DMatrix<f64>)> {
        let p = self.p;
        let mut ata = nalgebra::DMatrix::<f64>::zeros(p, p);
        let mut atb = nalgebra::DVector::<f64>::zeros(p);
        for &g in subset {
            for i in self.groups[g].1.clone() {
                let a = self.row(i);
                for u in 0..p {
                    atb[u] += a[u] * self.y[i];
                    for v in 0..p {
                        ata[(u, v)] += a[u] * a[v];
                    }
                }
            }
        }
        let inv = ata.try_inverse()?;
        let coef = &inv * atb;
        coef.iter()
            .all(|v| v.is_finite())
            .then(|| (coef.iter().copied().collect(), inv))
    }

    /// Each group's mean residual under `coef`.
    fn group_residuals(&self, coef: &[f64]) -> Vec<f64> {
        self.groups
            .iter()
            .map(|(_, range)| {
                let sum: f64 = range
                    .clone()
                    .map(|i| {
                        let a = self.row(i);
                        self.y[i] - a.iter().zip(coef).map(|(a, c)| a * c).sum::<f64>()
                    })
                    .sum();
                sum / range.len() as f64
            })
            .collect()
    }

    /// One concentration step: the `h` groups whose mean residual under `coef` is smallest,
    /// and the sum of their squares (the trimmed objective).
    fn concentrate(&self, coef: &[f64], h: usize) -> (f64, Vec<usize>) {
        let r = self.group_residuals(coef);
        let mut order: Vec<usize> = (0..r.len()).collect();
        order.sort_by(|&a, &b| r[a].abs().total_cmp(&r[b].abs()));
        order.truncate(h);
        (order.iter().map(|&g| r[g] * r[g]).sum(), order)
    }

    /// Least trimmed squares over images (Rousseeuw and Van Driessen's FAST-LTS): the fit of
    /// the `h` images (about half) whose mean residuals have the smallest sum of squares,
    /// searched from [`LTS_STARTS`] random elemental sets of [`ELEMENTAL`] images, each
    /// improved by two concentration steps, the best [`LTS_KEEP`] then to convergence. Its
    /// breakdown point is about one half: images whose given brightness is wrong, up to
    /// nearly half of them, cannot move it.
    fn lts(&self, h: usize) -> Option<Vec<f64>> {
        let n = self.groups.len();
        let mut rng = crate::base::rng::Pcg32::new(0x1175, 0);
        let mut pool: Vec<(f64, Vec<usize>)> = Vec::with_capacity(LTS_STARTS);
        let mut order: Vec<usize> = (0..n).collect();
        for _ in 0..LTS_STARTS {
            // A random elemental set, enlarged until it determines the fit.
            for i in 0..n {
                let j = i + (rng.next_u32() as usize) % (n - i);
                order.swap(i, j);
            }
            let Some((mut coef, _)) = (ELEMENTAL..=n).find_map(|m| self.fit(&order[..m])) else {
                continue;
            };
            let mut best = self.concentrate(&coef, h);
            for _ in 0..2 {
                let Some((c, _)) = self.fit(&best.1) else {
                    break;
                };
                coef = c;
                best = self.concentrate(&coef, h);
            }
            pool.push(best);
        }
        pool.sort_by(|a, b| a.0.total_cmp(&b.0));
        pool.truncate(LTS_KEEP);
        let mut best: Option<(f64, Vec<f64>)> = None;
        for (mut obj, mut subset) in pool {
            let mut coef = self.fit(&subset)?.0;
            for _ in 0..50 {
                let (o, s) = self.concentrate(&coef, h);
                if o >= obj * (1.0 - 1e-12) && s == subset {
                    break;
                }
                (obj, subset) = (o, s);
                coef = self.fit(&subset)?.0;
            }
            if best.as_ref().is_none_or(|b| obj < b.0) {
                best = Some((obj, coef));
            }
        }
        best.map(|b| b.1)
    }
}

/// Random elemental sets of the least-trimmed-squares search, the ones kept to convergence,
/// and the images in an elemental set: with grey (or grey-ratioed) lights an image adds one
/// equation to the four of the direction's share and the slope, and one for the constant. At
/// half the images wrong, 128 sets of five miss a clean one with probability (1 − 2⁻⁵)¹²⁸ ≈
/// 2%; at a quarter wrong, 10⁻¹⁰.
const LTS_STARTS: usize = 128;
const LTS_KEEP: usize = 8;
const ELEMENTAL: usize = 5;

/// The brightness test on a candidate's gains (`[k * C + c]`): the slope β of
/// `ln(G_kc / I_kc)` on `ln(I_kc / scale_k)` (the light's known brightness in channel c, its
/// exposure included), with a constant per channel and `l_k` as further regressors, with its
/// standard error and degrees of freedom, and the images left out.
///
/// The fit must survive images whose given intensity or exposure is wrong, and these are
/// wrong in all their channels at once: a least-trimmed-squares fit over images
/// ([`Regression::lts`]) finds the common exponent of the consistent half; each image's mean
/// residual under it is then studentised by the residuals' robust spread (1.4826 × their
/// median absolute value) and the images beyond the two-sided 99% normal quantile are left
/// out; β is the least-squares slope of the others, its standard error from their residuals.
/// When those left out are not a minority, the images do not share one exponent: β is then
/// that of every image, and [`Slope::majority`] says so. `None` with fewer than three degrees
/// of freedom, or when the known brightness varies by less than 1% beyond what the other
/// regressors explain (no lever).
fn brightness_slope(gains: &[f64], s: &Samples, lights: &LightInfo) -> Option<Slope> {
    let reg = Regression::new(gains, s, lights);
    let (n, p) = (reg.groups.len(), reg.p);
    if (reg.y.len() as f64) < p as f64 + 3.0 || n < ELEMENTAL + 2 {
        return None;
    }
    let all: Vec<usize> = (0..n).collect();
    let h = (n + ELEMENTAL).div_ceil(2);
    let coef = reg.lts(h).or_else(|| reg.fit(&all).map(|f| f.0))?;
    let r = reg.group_residuals(&coef);
    let mut abs: Vec<f64> = r.iter().map(|v| v.abs()).collect();
    let scale = 1.4826 * median(&mut abs) * (n as f64 / (n - ELEMENTAL) as f64).sqrt();
    let z = crate::base::stats::normal_upper_quantile(0.005);
    let (kept, out): (Vec<usize>, Vec<usize>) =
        (0..n).partition(|&g| r[g].abs() <= z * scale.max(1e-12));
    let left_out: Vec<usize> = out.iter().map(|&g| reg.groups[g].0).collect();
    let used = if 2 * out.len() < n { &kept } else { &all };
    let (coef, inv) = reg.fit(used)?;
    let points: usize = used.iter().map(|&g| reg.groups[g].1.len()).sum();
    let sxx = 1.0 / inv[(p - 1, p - 1)];
    // The known brightness's spread beyond the other regressors, per point: at least 1%.
    if !(sxx.is_finite() && sxx > 1e-4 * points as f64) {
        return None;
    }
    let rss: f64 = used
        .iter()
        .flat_map(|&g| reg.groups[g].1.clone())
        .map(|i| {
            let fit: f64 = reg.row(i).iter().zip(&coef).map(|(a, c)| a * c).sum();
            (reg.y[i] - fit).powi(2)
        })
        .sum();
    let dof = points as f64 - p as f64;
    if dof < 3.0 {
        return None;
    }
    Some(Slope {
        beta: coef[p - 1],
        se: (rss / dof / sxx).sqrt(),
        dof,
        left_out,
        images: n,
    })
}

/// A light's intensity in channel `ch` of images with `channels` channels (grey images: the
/// mean of red, green and blue).
fn channel_intensity(i: &[f64; 3], ch: usize, channels: usize) -> f64 {
    if channels == 3 {
        i[ch]
    } else {
        (i[0] + i[1] + i[2]) / 3.0
    }
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    *v.select_nth_unstable_by(m, f64::total_cmp).1
}

/// The rank-3 fits of a candidate response.
struct Fit<'a> {
    s: &'a Samples,
    rows: &'a [usize],
    lights: &'a LightInfo,
}

impl Fit<'_> {
    /// Linear readings (exposure corrected, ambient removed) and their weights (1 / variance)
    /// of every used row under `r`.
    fn linear(&self, r: Response) -> (Vec<f64>, Vec<f64>) {
        let n = self.s.images;
        let q = match self.s.bit_depth {
            8 => 1.0 / 255.0,
            16 => 1.0 / 65535.0,
            _ => 1e-4,
        } / 12f64.sqrt();
        let scale = &self.lights.scale;
        let ambient_scale = self.lights.ambient_scale;
        let mut x = Vec::with_capacity(self.rows.len() * n);
        let mut w = Vec::with_capacity(self.rows.len() * n);
        for &row in self.rows {
            let (a, va) = match &self.s.ambient {
                Some(amb) => {
                    let e = amb[row] as f64;
                    (
                        r.linear(e) * ambient_scale,
                        (r.slope(e) * ambient_scale * q).powi(2),
                    )
                }
                None => (0.0, 0.0),
            };
            for (&e, &sc) in self.s.encoded[row * n..(row + 1) * n].iter().zip(scale) {
                let e = e as f64;
                let v = r.linear(e) * sc - a;
                let var = (r.slope(e) * sc * q).powi(2) + va;
                x.push(v);
                w.push(1.0 / var.max(1e-30));
            }
        }
        (x, w)
    }

    /// The light vectors with each light's mean intensity.
    fn light_vectors(&self) -> Vec<[f64; 3]> {
        self.lights
            .directions
            .iter()
            .zip(&self.lights.intensities)
            .map(|(d, i)| d.map(|v| v * (i[0] + i[1] + i[2]) / 3.0))
            .collect()
    }

    /// Each used row's reduced χ² under the rank-3 model fitted to the readings `r` makes.
    fn row_chi2(&self, r: Response) -> Vec<f64> {
        let n = self.s.images;
        let (x, w) = self.linear(r);
        let lights = self.light_vectors();
        let mut u = lights.clone();
        let mut b = vec![[0.0; 3]; self.rows.len()];
        for _ in 0..3 {
            for (i, bi) in b.iter_mut().enumerate() {
                let xs = &x[i * n..(i + 1) * n];
                let ws = &w[i * n..(i + 1) * n];
                *bi = solve_weighted(u.iter().zip(xs).zip(ws).map(|((u, x), w)| (*u, *x, *w)));
            }
            // Each light's gain (its brightness and exposure, as the readings see them); its
            // direction stays the given one.
            for (k, uk) in u.iter_mut().enumerate() {
                let (mut num, mut den) = (0.0, 0.0);
                for (i, bi) in b.iter().enumerate() {
                    let p = dot(lights[k], *bi);
                    num += w[i * n + k] * x[i * n + k] * p;
                    den += w[i * n + k] * p * p;
                }
                let g = if den > 0.0 { num / den } else { 1.0 };
                *uk = lights[k].map(|v| v * g);
            }
        }
        b.iter()
            .enumerate()
            .map(|(i, bi)| {
                let chi: f64 = (0..n)
                    .map(|k| {
                        let d = x[i * n + k] - dot(u[k], *bi);
                        d * d * w[i * n + k]
                    })
                    .sum();
                chi / (n - 3) as f64
            })
            .collect()
    }

    /// Each light's gain per channel (`[k * C + c]`) under `r`: the model `x_rk ≈ G_kc l_k ·
    /// b_r` fitted with each reading relative to its gain (each row's `b_r` then scales with
    /// the gains, whatever they are), each gain the median over the channel's rows of reading
    /// over model.
    fn gains(&self, r: Response) -> Vec<f64> {
        let n = self.s.images;
        let c = self.s.channels.max(1);
        let (x, _) = self.linear(r);
        let dirs = &self.lights.directions;
        let mut g: Vec<f64> = (0..n * c)
            .map(|i| channel_intensity(&self.lights.intensities[i / c], i % c, c))
            .collect();
        let mut b = vec![[0.0; 3]; self.rows.len()];
        let mut ratios: Vec<Vec<f64>> = vec![Vec::with_capacity(self.rows.len() / c + 1); n * c];
        for _ in 0..3 {
            for (i, bi) in b.iter_mut().enumerate() {
                let ch = self.rows[i] % c;
                let xs = &x[i * n..(i + 1) * n];
                *bi = solve_weighted(
                    dirs.iter()
                        .zip(xs)
                        .enumerate()
                        .map(|(k, (d, v))| (*d, v / g[k * c + ch], 1.0)),
                );
            }
            ratios.iter_mut().for_each(Vec::clear);
            for (i, bi) in b.iter().enumerate() {
                let ch = self.rows[i] % c;
                for (k, d) in dirs.iter().enumerate() {
                    let p = dot(*d, *bi);
                    if p > 0.0 {
                        ratios[k * c + ch].push(x[i * n + k] / p);
                    }
                }
            }
            for (gk, rs) in g.iter_mut().zip(ratios.iter_mut()) {
                if !rs.is_empty() {
                    *gk = median(rs);
                }
            }
        }
        g
    }
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The 3-vector `v` minimising Σ w (y − a · v)² over `(a, y, w)`; zero when singular.
fn solve_weighted(terms: impl Iterator<Item = ([f64; 3], f64, f64)>) -> [f64; 3] {
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut rhs = nalgebra::Vector3::<f64>::zeros();
    for (a, y, w) in terms {
        let a = nalgebra::Vector3::from(a);
        m += w * a * a.transpose();
        rhs += w * y * a;
    }
    m.cholesky()
        .map(|c| {
            let v = c.solve(&rhs);
            [v[0], v[1], v[2]]
        })
        .unwrap_or([0.0; 3])
}

/// A constant per-pixel offset across lights, measured on linear readings (report.json
/// `photometry.offset_check`).
#[derive(Clone, Debug, Serialize)]
pub struct OffsetCheck {
    /// Median over pixels of the fitted offset relative to the pixel's mean reading.
    pub relative_offset: f64,
    /// Its standard error (from disjoint pixel sets).
    pub std_error: f64,
    /// Pixel-channel rows lit by every light that were used.
    pub rows: usize,
    /// How far an offset's pattern across the lights lies from the lights' span: the sine of
    /// the angle between them (0: an offset reads as a change of normal, 1: fully distinct).
    pub separation: f64,
    /// Whether the offset is positive (light added: a negative one is what surfaces darker
    /// than Lambertian at grazing light show, as DiLiGenT's objects do), significant (beyond
    /// three standard errors) and larger than what the model's relative error κ can feign
    /// through the lights' geometry, κ / separation.
    pub detected: bool,
}

/// Fits `x_k = l_k · b + a · c_k` at each row of linear readings `x` (`[row][light]`, lit by
/// every light), where `c_k` is what light k's readings were multiplied by (a constant offset
/// in the files is `a · c_k` in the readings), and reports the median of `a` over the row's
/// mean reading. `None` with fewer than five lights or 30 rows.
pub fn offset_check(x: &[f64], lights: &[[f64; 3]], c: &[f64]) -> Option<OffsetCheck> {
    let n = lights.len();
    let rows = x.len() / n.max(1);
    if n < 5 || rows < 30 {
        return None;
    }
    let design: Vec<nalgebra::Vector4<f64>> = lights
        .iter()
        .zip(c)
        .map(|(l, c)| nalgebra::Vector4::new(l[0], l[1], l[2], *c))
        .collect();
    let mut ata = nalgebra::Matrix4::<f64>::zeros();
    for d in &design {
        ata += d * d.transpose();
    }
    let inv = ata.try_inverse()?;
    // The part of the offset pattern c outside the lights' span.
    let mut ltl = nalgebra::Matrix3::<f64>::zeros();
    let mut ltc = nalgebra::Vector3::<f64>::zeros();
    for (l, ck) in lights.iter().zip(c) {
        let l = nalgebra::Vector3::from(*l);
        ltl += l * l.transpose();
        ltc += *ck * l;
    }
    let coef = ltl.try_inverse()? * ltc;
    let (mut outside, mut total) = (0.0, 0.0);
    for (l, ck) in lights.iter().zip(c) {
        let r = ck - (l[0] * coef[0] + l[1] * coef[1] + l[2] * coef[2]);
        outside += r * r;
        total += ck * ck;
    }
    let separation = (outside / total.max(1e-300)).sqrt();
    let rel: Vec<f64> = (0..rows)
        .map(|r| {
            let xs = &x[r * n..(r + 1) * n];
            let mut atb = nalgebra::Vector4::<f64>::zeros();
            for (d, v) in design.iter().zip(xs) {
                atb += d * *v;
            }
            let mean = xs.iter().sum::<f64>() / n as f64;
            let mean_c = c.iter().sum::<f64>() / n as f64;
            (inv * atb)[3] * mean_c / mean.max(1e-12)
        })
        .collect();
    let mut all = rel.clone();
    let m = median(&mut all);
    let groups: Vec<f64> = (0..GROUPS)
        .map(|g| {
            let mut v: Vec<f64> = rel.iter().skip(g).step_by(GROUPS).copied().collect();
            median(&mut v)
        })
        .collect();
    let gm = groups.iter().sum::<f64>() / GROUPS as f64;
    let var = groups.iter().map(|v| (v - gm).powi(2)).sum::<f64>() / (GROUPS - 1) as f64;
    let se = (var / GROUPS as f64).sqrt();
    Some(OffsetCheck {
        relative_offset: m,
        std_error: se,
        rows,
        separation,
        detected: m > 3.0 * se && m * separation > KAPPA,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Pcg32;

    /// Lights on a grid in front of the camera, as a dome or DiLiGenT's rig.
    fn lights() -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        for i in -2..=2 {
            for j in -2..=2 {
                let (x, y) = (0.25 * i as f64, 0.25 * j as f64);
                let z = 1.0f64;
                let n = (x * x + y * y + z * z).sqrt();
                v.push([x / n, y / n, z / n]);
            }
        }
        v
    }

    /// Readings `(ρ I_k (n · l_k)^p + ambient)` of random normals within 30° of the view (lit by
    /// every light; `p = 1` is Lambertian, `p > 1` a surface darker than matte at grazing
    /// light), encoded by `r` into `bits`-bit levels.
    fn readings(
        r: Response,
        bits: u8,
        ambient: f64,
        seed: u64,
        intensities: &[f64],
        p: f64,
    ) -> Samples {
        let l = lights();
        let mut rng = Pcg32::new(seed, 0);
        let levels = ((1u32 << bits) - 1) as f64;
        let top = intensities.iter().cloned().fold(0.0, f64::max);
        let mut encoded = Vec::new();
        for _ in 0..2000 {
            let (a, t) = (rng.next_f64() * 0.5, rng.next_f64() * std::f64::consts::TAU);
            let n = [a.sin() * t.cos(), a.sin() * t.sin(), a.cos()];
            let rho = 0.3 + 0.6 * rng.next_f64();
            for (lk, ik) in l.iter().zip(intensities) {
                let x = (rho * ik / top * dot(n, *lk).powf(p) + ambient).min(1.0);
                encoded.push(((r.encode(x) * levels).round() / levels) as f32);
            }
        }
        Samples {
            encoded,
            ambient: None,
            images: l.len(),
            channels: 1,
            bit_depth: bits,
        }
    }

    fn samples(r: Response, bits: u8, ambient: f64, seed: u64) -> Samples {
        readings(r, bits, ambient, seed, &vec![1.0; lights().len()], 1.0)
    }

    fn info(intensities: &[f64]) -> LightInfo {
        LightInfo {
            directions: lights(),
            intensities: intensities.iter().map(|&i| [i; 3]).collect(),
            scale: vec![1.0; intensities.len()],
            ambient_scale: 1.0,
        }
    }

    #[test]
    fn the_response_is_recovered_on_analytic_scenes() {
        let ones = vec![1.0; lights().len()];
        let l = info(&ones);
        for (truth, seed) in [
            (Response::Gamma(2.2), 1),
            (Response::Gamma(1.8), 2),
            (Response::Gamma(2.6), 3),
        ] {
            let e = estimate_response(&samples(truth, 8, 0.0, seed), &l).unwrap();
            let Response::Gamma(g) = e.response else {
                panic!("{truth:?}: {e:?}")
            };
            let Response::Gamma(t) = truth else {
                unreachable!()
            };
            assert!((g - t).abs() <= 0.1, "{truth:?}: {e:?}");
            // Equal lights give the brightness test no lever.
            assert_eq!(e.basis, "shading");
        }
        let e = estimate_response(&samples(Response::Srgb, 8, 0.0, 4), &l).unwrap();
        assert_eq!(e.response, Response::Srgb, "{e:?}");
        for bits in [8, 16] {
            let e = estimate_response(&samples(Response::Linear, bits, 0.0, 5), &l).unwrap();
            assert_eq!(e.response, Response::Linear, "{bits}-bit: {e:?}");
        }
    }

    /// Lights whose brightness varies ×4 in an order unrelated to their directions.
    fn uneven() -> Vec<f64> {
        let mut rng = Pcg32::new(99, 1);
        (0..lights().len())
            .map(|_| 4f64.powf(rng.next_f64()))
            .collect()
    }

    /// A surface darker than matte at grazing light (`(n · l)^1.5`) through a power law reads
    /// like a Lambertian one through a power 1.5 times smaller: the shading is fooled, the
    /// lights' uneven brightness is not.
    #[test]
    fn the_lights_brightness_tells_the_response_from_the_material() {
        let int = uneven();
        let l = info(&int);
        for (truth, seed) in [
            (Response::Gamma(2.2), 11),
            (Response::Gamma(1.8), 12),
            (Response::Gamma(2.4), 13),
        ] {
            let Response::Gamma(t) = truth else {
                unreachable!()
            };
            let e = estimate_response(&readings(truth, 8, 0.0, seed, &int, 1.5), &l).unwrap();
            assert_eq!(e.basis, "brightness", "{e:?}");
            assert!((e.gamma - t).abs() <= 0.1, "{truth:?}: {e:?}");
            assert!(
                (e.gamma - t).abs() <= 3.0 * e.gamma_std + 0.02,
                "{truth:?}: {e:?}"
            );
            assert!(e.gamma_shading < t - 0.3, "{truth:?}: {e:?}");
        }
        let e = estimate_response(&readings(Response::Srgb, 8, 0.0, 14, &int, 1.5), &l).unwrap();
        assert_eq!(e.response, Response::Srgb, "{e:?}");
        let e = estimate_response(&readings(Response::Linear, 16, 0.0, 15, &int, 1.5), &l).unwrap();
        assert_eq!(e.response, Response::Linear, "{e:?}");
        // Exposures that change are a lever too: equal lights, images exposed ×0.5 to ×2.
        let mut rng = Pcg32::new(5, 5);
        let exposure: Vec<f64> = (0..lights().len())
            .map(|_| 4f64.powf(rng.next_f64() - 0.5))
            .collect();
        let ones = vec![1.0; exposure.len()];
        let s = readings(Response::Gamma(2.2), 8, 0.0, 16, &exposure, 1.5);
        let mut l = info(&ones);
        l.scale = exposure.iter().map(|f| 1.0 / f).collect();
        let e = estimate_response(&s, &l).unwrap();
        assert_eq!(e.basis, "brightness", "{e:?}");
        assert!((e.gamma - 2.2).abs() <= 0.1, "{e:?}");
    }

    /// A fifth of the lights stated ×1.6 or ×0.625 off their true brightness (as a lamp whose
    /// calibration was mislabelled): the brightness test leaves exactly those images out (or at
    /// most two more) and the others give the true exponent.
    #[test]
    fn images_whose_stated_intensity_is_wrong_are_left_out() {
        let truth = uneven();
        let wrong: Vec<usize> = (0..truth.len()).step_by(5).collect();
        let stated: Vec<f64> = truth
            .iter()
            .enumerate()
            .map(|(k, &i)| match wrong.iter().position(|&w| w == k) {
                Some(j) if j % 2 == 0 => i * 1.6,
                Some(_) => i * 0.625,
                None => i,
            })
            .collect();
        let s = readings(Response::Gamma(2.2), 8, 0.0, 21, &truth, 1.5);
        let e = estimate_response(&s, &info(&stated)).unwrap();
        assert_eq!(e.basis, "brightness", "{e:?}");
        assert!((e.gamma - 2.2).abs() <= 0.1, "{e:?}");
        assert!(e.intensities_disagree.is_none(), "{e:?}");
        for w in &wrong {
            assert!(e.images_left_out.contains(w), "image {w}: {e:?}");
        }
        assert!(e.images_left_out.len() <= wrong.len() + 2, "{e:?}");
    }

    #[test]
    fn an_offset_is_found_where_there_is_one() {
        let l = lights();
        let ones = vec![1.0; l.len()];
        for (ambient, expect) in [(0.0, false), (0.15, true)] {
            let s = samples(Response::Linear, 16, ambient, 7);
            let x: Vec<f64> = s.encoded.iter().map(|&v| v as f64).collect();
            let c = offset_check(&x, &l, &ones).unwrap();
            assert_eq!(c.detected, expect, "ambient {ambient}: {c:?}");
        }
    }
}
