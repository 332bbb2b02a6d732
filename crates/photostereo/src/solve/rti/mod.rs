//! Reflectance transformation imaging (RTI): per-pixel least-squares fits of a light-dependent
//! reflectance function, the representation heritage viewers (RTIViewer, OpenLIME) relight.
//!
//! A basis of T functions b_j(l) of the unit light direction l = (l_x, l_y, l_z) (camera frame:
//! x right, y up, z toward the camera) models the reading of pixel p under light k as
//! I_pk ≈ Σ_j c_pj · b_j(l_k). The coefficients are the least-squares solution of the normal
//! equations (AᵀA) c = Aᵀ y with A_kj = b_j(l_k). With distant lights A is the same for every
//! pixel, so G = AᵀA is factored once and the projector P = G⁻¹Aᵀ (T × N) is applied to each
//! pixel's readings; a pixel with excluded readings (a per-pixel light mask, e.g. the recursive
//! method's shadows and highlights) gets its own normal equations over the lights it keeps.
//!
//! Bases:
//! - PTM (Malzbender, Gelb & Wolters 2001, "Polynomial texture maps"; HP Labs "PTM file
//!   format" v1.2): with the light projected on the image plane, (l_u, l_v) = (l_x, l_y),
//!   L = a0 l_u² + a1 l_v² + a2 l_u l_v + a3 l_u + a4 l_v + a5. The LRGB variant fits the
//!   luminance Y = mean of the channels and keeps a per-pixel chroma (the ratio of each
//!   channel to Y, summed over the lights); the RGB variant fits each channel.
//! - HSH, hemispherical harmonics (Gautron, Křivánek, Pattanaik & Bouatouch 2004, "A novel
//!   hemispherical basis for accurate and efficient rendering"), in the order and
//!   normalisation RTIViewer's `.rti` files use, with θ the light's angle from the view axis
//!   (cos θ = l_z) and φ = atan2(l_y, l_x), s = √(cos θ − cos² θ):
//!   - H0 = 1/√(2π)
//!   - H1 = √(6/π) cos φ · s
//!   - H2 = √(3/(2π)) (2 cos θ − 1)
//!   - H3 = √(6/π) sin φ · s
//!   - H4 = √(30/π) cos 2φ (cos² θ − cos θ)
//!   - H5 = √(30/π) cos φ (2 cos θ − 1) s
//!   - H6 = √(5/(2π)) (6 cos² θ − 6 cos θ + 1)
//!   - H7 = √(30/π) sin φ (2 cos θ − 1) s
//!   - H8 = √(30/π) sin 2φ (cos² θ − cos θ)
//!
//!   Order 2 is H0…H3 (4 terms), order 3 H0…H8 (9 terms), per channel.
//! - RBF: relight's radial-basis model, the readings' principal components rendered by
//!   normalised Gaussian weights over render positions, where they are resampled by PTM's ridge
//!   quadratic plus Gaussians of its residuals ([`smoother`]), P = 9 coefficients a pixel
//!   ([`rbf`]). It is not a fixed basis of l: its fit and leave-one-out error are [`rbf::fit`]'s.
//!
//! Leave-one-out (LOO) error: for a linear least-squares fit with hat matrix H = A G⁻¹ Aᵀ, the
//! residual of reading k when the fit leaves k out is e_k / (1 − h_kk), e_k the residual of the
//! full fit (the PRESS identity; e.g. Hastie, Tibshirani & Friedman, "The Elements of
//! Statistical Learning", eq. 7.52 for linear smoothers). It is exact, so no refit per light is
//! needed; [`RtiFit`]'s figures use it for every basis. For PTM LRGB the chroma left out of
//! light k is recomputed without k as well, so its LOO prediction is exact too.
//!
//! Ridge (Tikhonov regularisation): the linear bases are fitted by c = (AᵀA + λ D)⁻¹ Aᵀ y, D a
//! diagonal roughness penalty over the light hemisphere ([`Basis::roughness`]: the Dirichlet
//! energy ∫|∇f|² of the fitted function, zero for the constant term). The fit is still a
//! fixed linear smoother, H = A (AᵀA + λ D)⁻¹ Aᵀ, so the PRESS identity above holds exactly
//! for it. One λ per capture and basis is chosen from the data ([`Penalty::Auto`]): the value
//! of a log grid, λ = 0 included, whose exact leave-one-out error over a regular sample of
//! mask pixels is least (cross-validation, e.g. Hastie, Tibshirani & Friedman §7.10). λ = 0 is
//! the unregularised least-squares fit; the coefficients are those of the same basis whatever λ.
//! HSH may instead be pulled toward PTM's ridge fit of the same readings over the rig's cap of
//! the hemisphere ([`Prior::Ptm`], [`design`]); its candidates join those toward zero, and its
//! leave-one-out error is exact as well.
//!
//! Units: readings are the capture's intensity-normalised samples times a display gain
//! ([`display_gain`]), so that 1.0 is the top of the 8-bit range of the files (RTIViewer shows
//! HSH values × 255 and PTM values as they are, with the PTM coefficients stored × 255).
//! Memory: the coefficients, f32, `4 · (C·T + 3)` bytes per mask pixel (C channels fitted), and
//! the capture's samples `4 · N · C` bytes per mask pixel (or its tiles).

pub mod design;
pub mod rbf;
pub mod smoother;

use crate::base::error::{Error, Result};
use crate::model::capture::{clipped, Capture};
pub use design::Prior;
use design::{Design, Operators, PTM_TERMS};
use rayon::prelude::*;
use std::str::FromStr;

/// The most terms a linear basis has (HSH order 3); rbf's planes are [`rbf::PLANES`].
pub const MAX_TERMS: usize = 9;

/// A reflectance basis of the RTI fits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Basis {
    /// PTM of the luminance with a per-pixel RGB chroma (`PTM_FORMAT_LRGB`).
    PtmLrgb,
    /// PTM of each channel (`PTM_FORMAT_RGB`).
    PtmRgb,
    /// Hemispherical harmonics of order 2: 4 terms per channel.
    Hsh2,
    /// Hemispherical harmonics of order 3: 9 terms per channel.
    Hsh3,
    /// relight's RBF: 9 principal-component coefficients per pixel, interpolated over the
    /// lights ([`rbf`]).
    Rbf,
}

impl Basis {
    /// Every basis, in the order tables list them.
    pub const ALL: [Basis; 5] = [
        Basis::PtmLrgb,
        Basis::PtmRgb,
        Basis::Hsh2,
        Basis::Hsh3,
        Basis::Rbf,
    ];

    /// The bases that are fixed functions of the light ([`Basis::eval`]), fitted by least
    /// squares per pixel.
    pub const LINEAR: [Basis; 4] = [Basis::PtmLrgb, Basis::PtmRgb, Basis::Hsh2, Basis::Hsh3];

    /// The name `--basis` accepts.
    pub fn name(self) -> &'static str {
        match self {
            Basis::PtmLrgb => "ptm",
            Basis::PtmRgb => "ptm-rgb",
            Basis::Hsh2 => "hsh2",
            Basis::Hsh3 => "hsh3",
            Basis::Rbf => "rbf",
        }
    }

    /// Number of basis functions T.
    pub fn terms(self) -> usize {
        match self {
            Basis::PtmLrgb | Basis::PtmRgb => 6,
            Basis::Hsh2 => 4,
            Basis::Hsh3 => 9,
            Basis::Rbf => rbf::PLANES,
        }
    }

    /// Whether the fit is of the luminance with a per-pixel chroma (PTM LRGB).
    pub fn luminance(self) -> bool {
        self == Basis::PtmLrgb
    }

    /// Whether the basis is a fixed function of the light ([`Basis::LINEAR`]).
    pub fn linear(self) -> bool {
        self != Basis::Rbf
    }

    /// The basis functions at the unit light direction `l` (module documentation), into
    /// `out[..terms]`. A light below the horizon (l_z < 0) is evaluated at the horizon. RBF,
    /// whose functions are the fit's own ([`rbf::RbfModel::light_basis`]), writes zeros.
    pub fn eval(self, l: [f64; 3], out: &mut [f64]) {
        use std::f64::consts::PI;
        match self {
            Basis::PtmLrgb | Basis::PtmRgb => {
                let (u, v) = (l[0], l[1]);
                out[..6].copy_from_slice(&[u * u, v * v, u * v, u, v, 1.0]);
            }
            Basis::Hsh2 | Basis::Hsh3 => {
                let ct = l[2].clamp(0.0, 1.0);
                let phi = l[1].atan2(l[0]);
                let s = (ct - ct * ct).max(0.0).sqrt();
                out[0] = 1.0 / (2.0 * PI).sqrt();
                out[1] = (6.0 / PI).sqrt() * phi.cos() * s;
                out[2] = (3.0 / (2.0 * PI)).sqrt() * (2.0 * ct - 1.0);
                out[3] = (6.0 / PI).sqrt() * phi.sin() * s;
                if self == Basis::Hsh3 {
                    let k = (30.0 / PI).sqrt();
                    out[4] = k * (2.0 * phi).cos() * (ct * ct - ct);
                    out[5] = k * phi.cos() * (2.0 * ct - 1.0) * s;
                    out[6] = (5.0 / (2.0 * PI)).sqrt() * (6.0 * ct * ct - 6.0 * ct + 1.0);
                    out[7] = k * phi.sin() * (2.0 * ct - 1.0) * s;
                    out[8] = k * (2.0 * phi).sin() * (ct * ct - ct);
                }
            }
            Basis::Rbf => out.iter_mut().take(rbf::PLANES).for_each(|o| *o = 0.0),
        }
    }

    /// The diagonal of the roughness penalty D of the ridge fit (module documentation), per
    /// term into `out[..terms]`: the Dirichlet energy ∫|∇f|² of f = Σ_j c_j b_j is Σ_j D_j c_j²
    /// (for HSH up to a common factor, which λ absorbs).
    /// - HSH: the harmonics are √2 × the spherical harmonics of the hemisphere stretched to the
    ///   sphere (cos θ' = 2 cos θ − 1), each an eigenfunction of the Laplacian with eigenvalue
    ///   l(l + 1), orthogonal: ∫|∇f|² dω' = 2 Σ_j l_j(l_j + 1) c_j². D = 0 (H0), 2 (H1…H3,
    ///   l = 1), 6 (H4…H8, l = 2).
    /// - PTM: over the unit disk of the projected light (l_u, l_v), where ∫1 = π and
    ///   ∫l_u² = ∫l_v² = π/4, ∫|∇L|² = π (a0² + a1² + a2²/2 + a3² + a4²) exactly (the cross
    ///   terms integrate to zero): D = π (1, 1, 1/2, 1, 1, 0).
    /// - RBF, not a fixed basis, is not regularised: zeros.
    pub fn roughness(self, out: &mut [f64]) {
        use std::f64::consts::PI;
        match self {
            Basis::PtmLrgb | Basis::PtmRgb => {
                out[..6].copy_from_slice(&[PI, PI, PI / 2.0, PI, PI, 0.0]);
            }
            Basis::Hsh2 | Basis::Hsh3 => {
                const DEGREE: [f64; MAX_TERMS] = [0.0, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0, 2.0];
                for (o, l) in out.iter_mut().zip(DEGREE).take(self.terms()) {
                    *o = l * (l + 1.0);
                }
            }
            Basis::Rbf => out.iter_mut().take(rbf::PLANES).for_each(|o| *o = 0.0),
        }
    }
}

/// How the ridge weight λ of a linear fit is set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Penalty {
    /// Chosen from the data: the value of [`RIDGE_GRID`] (× the number of lights, λ = 0
    /// included) with the least leave-one-out error over a regular sample of up to
    /// [`RIDGE_SAMPLE`] mask pixels ([`choose_ridge`]).
    Auto,
    /// This λ toward zero (0: unregularised least squares).
    Fixed(f64),
    /// HSH only: this λ toward PTM's ridge fit with weight `ptm_lambda` ([`Prior::Ptm`]).
    TowardPtm {
        /// λ of eq. (1) of [`design`].
        lambda: f64,
        /// PTM's ridge weight λ_p.
        ptm_lambda: f64,
    },
}

/// The candidate ridge weights per light, λ / N: 0 and half decades from 10⁻⁶ to 10². AᵀA
/// grows with the number of lights N, so λ / N weighs the roughness against the mean squared
/// residual per light whatever the rig.
pub const RIDGE_GRID: [f64; 18] = [
    0.0, 1e-6, 3.16e-6, 1e-5, 3.16e-5, 1e-4, 3.16e-4, 1e-3, 3.16e-3, 1e-2, 3.16e-2, 0.1, 0.316,
    1.0, 3.16, 10.0, 31.6, 100.0,
];

/// The most mask pixels, evenly spaced, whose leave-one-out error chooses λ.
pub const RIDGE_SAMPLE: usize = 4096;

/// The ridge weight of a fit and how it was chosen.
#[derive(Clone, Debug, PartialEq)]
pub struct Ridge {
    /// λ of (AᵀA + λ D) c = Aᵀ y toward zero, or of eq. (1) of [`design`] toward PTM (0:
    /// unregularised).
    pub lambda: f64,
    /// What the ridge pulls toward.
    pub prior: Prior,
    /// Each candidate λ toward zero and the mean over the lights of its leave-one-out RMSE
    /// (8-bit units) over the sample; empty when λ was given.
    pub candidates: Vec<(f64, f64)>,
    /// HSH: each candidate λ > 0 toward PTM (its λ_p PTM's own choice on the sample) and its
    /// error likewise; empty for PTM and when λ was given.
    pub toward_ptm: Vec<(f64, f64)>,
    /// Mask pixels of the sample (0 when λ was given).
    pub sample_pixels: usize,
}

impl FromStr for Basis {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Basis::ALL
            .into_iter()
            .find(|b| b.name() == s)
            .ok_or_else(|| {
                Error::parameter(
                    "basis",
                    format!("'{s}': expected one of ptm, ptm-rgb, hsh2, hsh3, rbf"),
                )
            })
    }
}

/// Per-light sums of a relighting error over the mask pixels and channels, in display units
/// (1.0 = 255 in 8 bits).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RelightErrors {
    /// Σ (prediction − reading)² per light.
    pub sse: Vec<f64>,
    /// Σ reading² per light (for the relative error).
    pub sum_sq: Vec<f64>,
    /// Readings compared per light.
    pub count: Vec<u64>,
}

impl RelightErrors {
    /// Zero sums for `n` lights.
    pub fn new(n: usize) -> Self {
        RelightErrors {
            sse: vec![0.0; n],
            sum_sq: vec![0.0; n],
            count: vec![0; n],
        }
    }

    fn add(&mut self, k: usize, predicted: f64, reading: f64) {
        let d = predicted - reading;
        self.sse[k] += d * d;
        self.sum_sq[k] += reading * reading;
        self.count[k] += 1;
    }

    fn merge(mut self, o: RelightErrors) -> RelightErrors {
        for k in 0..self.sse.len() {
            self.sse[k] += o.sse[k];
            self.sum_sq[k] += o.sum_sq[k];
            self.count[k] += o.count[k];
        }
        self
    }

    /// RMSE of light k in 8-bit units (255 × display units); NaN without readings.
    pub fn rmse_8bit(&self, k: usize) -> f64 {
        255.0 * (self.sse[k] / self.count[k] as f64).sqrt()
    }

    /// RMSE of light k relative to the RMS of its readings.
    pub fn relative(&self, k: usize) -> f64 {
        (self.sse[k] / self.sum_sq[k]).sqrt()
    }

    /// Mean over the lights (with readings) of the per-light 8-bit RMSE.
    pub fn mean_rmse_8bit(&self) -> f64 {
        mean(
            (0..self.sse.len())
                .filter(|&k| self.count[k] > 0)
                .map(|k| self.rmse_8bit(k)),
        )
    }

    /// Mean over the lights (with readings) of the per-light relative RMSE.
    pub fn mean_relative(&self) -> f64 {
        mean(
            (0..self.sse.len())
                .filter(|&k| self.count[k] > 0 && self.sum_sq[k] > 0.0)
                .map(|k| self.relative(k)),
        )
    }
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        s / n as f64
    }
}

/// A capture's RTI fit: coefficients per mask pixel and the leave-one-out figures.
#[derive(Clone, Debug)]
pub struct RtiFit {
    /// The basis.
    pub basis: Basis,
    /// Frame columns.
    pub width: usize,
    /// Frame rows.
    pub height: usize,
    /// Channels of the capture (1 or 3).
    pub channels: usize,
    /// Row-major frame index of each mask pixel (the capture's `pixels`).
    pub pixels: Vec<u32>,
    /// Channels fitted: 1 for PTM LRGB (the luminance), else the capture's channels.
    pub fitted_channels: usize,
    /// Coefficients, `[pixel][fitted channel][term]`, display units.
    pub coefficients: Vec<f32>,
    /// PTM LRGB: the chroma `[pixel][3]` (channel / luminance, 1 for grey); empty otherwise.
    pub chroma: Vec<f32>,
    /// The factor applied to the intensity-normalised samples ([`display_gain`]).
    pub gain: f64,
    /// Leave-one-out errors per light over the readings each fit used.
    pub loo: RelightErrors,
    /// Readings the light mask excluded from the fits.
    pub excluded_readings: u64,
    /// Pixels whose kept lights were too few for a leave-one-out fit (fewer than T + 2) and
    /// that were fitted with every light instead.
    pub fell_back_to_all_lights: u64,
    /// RBF: the model the coefficients weight; `None` for the other bases.
    pub rbf: Option<rbf::RbfModel>,
    /// The linear bases: the fit's ridge weight and its choice; `None` for RBF.
    pub ridge: Option<Ridge>,
    /// RBF: the kernel width's choice (the width itself is `rbf`'s σ); `None` otherwise.
    pub kernel: Option<rbf::KernelChoice>,
    /// Per term, the least and greatest coefficient over the mask pixels and fitted channels
    /// (measured as the fit made them, so also known when the coefficients went to a
    /// [`CoefficientSink`]).
    pub ranges: Vec<(f32, f32)>,
}

impl RtiFit {
    /// The fitted model of mask pixel `p` under the unit light `l`, per channel of the capture
    /// (display units), into `out[..channels]`.
    pub fn predict(&self, p: usize, l: [f64; 3], out: &mut [f64]) {
        let t = self.basis.terms();
        if let Some(model) = &self.rbf {
            let c = self.channels;
            let mut b = vec![0.0; (t + 1) * c];
            model.light_basis(l, &mut b);
            let coef = &self.coefficients[p * t..(p + 1) * t];
            for (ch, o) in out.iter_mut().take(c).enumerate() {
                *o = b[ch]
                    + (0..t)
                        .map(|j| f64::from(coef[j]) * b[(j + 1) * c + ch])
                        .sum::<f64>();
            }
            return;
        }
        let mut b = [0.0; MAX_TERMS];
        self.basis.eval(l, &mut b);
        let fc = self.fitted_channels;
        let c = &self.coefficients[p * fc * t..(p + 1) * fc * t];
        let dot = |ch: usize| (0..t).map(|j| c[ch * t + j] as f64 * b[j]).sum::<f64>();
        if self.basis.luminance() {
            let y = dot(0);
            for (ch, o) in out.iter_mut().take(self.channels).enumerate() {
                *o = y * self.chroma[p * 3 + ch.min(2)] as f64;
            }
        } else {
            for (ch, o) in out.iter_mut().take(self.channels).enumerate() {
                *o = dot(ch);
            }
        }
    }

    /// Per term, the least and greatest coefficient over the mask pixels and fitted channels.
    pub fn coefficient_ranges(&self) -> Vec<(f32, f32)> {
        self.ranges.clone()
    }

    /// Bytes the fit holds per mask pixel (coefficients and chroma).
    pub fn bytes_per_pixel(basis: Basis, channels: usize) -> u64 {
        let fc = if basis.luminance() || basis == Basis::Rbf {
            1
        } else {
            channels
        };
        4 * (fc * basis.terms() + 3) as u64
    }
}

/// The factor that maps the capture's intensity-normalised readings to display units: 1 / the
/// 99.5th percentile of the readings of up to 4096 evenly spaced mask pixels (all lights and
/// channels), so that all but the brightest highlights fit the 8-bit range; 1 when that is 0.
pub fn display_gain(capture: &Capture) -> Result<f64> {
    let np = capture.n_pixels();
    if np == 0 {
        return Ok(1.0);
    }
    let ids = sample_ids(np, 4096);
    let view = sample_view(capture, &ids)?;
    let mut v: Vec<f32> = ids
        .iter()
        .flat_map(|&p| view.pixel_samples(p).iter().copied())
        .filter(|x| x.is_finite())
        .collect();
    if v.is_empty() {
        return Ok(1.0);
    }
    let i = ((v.len() - 1) as f64 * 0.995).round() as usize;
    let (_, q, _) = v.select_nth_unstable_by(i, f32::total_cmp);
    Ok(if *q > 0.0 { 1.0 / f64::from(*q) } else { 1.0 })
}

/// Up to `most` evenly spaced mask pixels of `np` (every ⌈np / most⌉-th).
pub(crate) fn sample_ids(np: usize, most: usize) -> Vec<usize> {
    (0..np).step_by(np.div_ceil(most).max(1)).collect()
}

/// A view of `capture` that answers for the mask pixels `ids`: the capture itself when held
/// whole (no copy), else the samples of those pixels read from its tiles.
pub(crate) fn sample_view<'a>(
    capture: &'a Capture,
    ids: &[usize],
) -> Result<std::borrow::Cow<'a, Capture>> {
    Ok(if capture.is_tiled() {
        std::borrow::Cow::Owned(capture.sampled(ids)?)
    } else {
        std::borrow::Cow::Borrowed(capture)
    })
}

/// Scratch of one worker: the readings of one pixel per fitted channel, the pixel's excluded
/// lights, its own operators when it excludes lights, and PTM's coefficients per fitted
/// channel when the fit pulls toward PTM.
struct Scratch {
    y: Vec<f64>,
    /// The pixel's excluded lights.
    flags: Vec<bool>,
    own: Operators,
    ptm: Vec<f64>,
    errors: RelightErrors,
}

/// Which readings a fit leaves out, per mask pixel (the capture's mask-pixel order) and light:
/// flags held whole (`[pixel][light]`, for tests and callers of their own) or read in place from
/// what already holds them (the `rti` command reads the recursive method's statuses, no copy).
pub trait ReadingMask: Sync {
    /// Readings covered: mask pixels × lights.
    fn readings(&self) -> usize;
    /// Whether the reading of light `k` of `n` at mask pixel `p` is left out.
    fn excluded(&self, p: usize, k: usize, n: usize) -> bool;
}

impl ReadingMask for Vec<bool> {
    fn readings(&self) -> usize {
        self.len()
    }
    fn excluded(&self, p: usize, k: usize, n: usize) -> bool {
        self[p * n + k]
    }
}

/// Where a fit puts its coefficients as it makes them, a block of consecutive mask pixels at a
/// time in ascending order: so that a capture's fit need not be held whole (the `rti` command
/// writes them to `coefficients.npy` as they come).
pub trait CoefficientSink {
    /// The mask pixels `start..start + n`: `coefficients` `[pixel][fitted channel][term]`
    /// (display units) and for PTM LRGB `chroma` `[pixel][3]` (empty for the other bases).
    fn put(&mut self, start: usize, coefficients: &[f32], chroma: &[f32]) -> Result<()>;
}

/// A sink that keeps every coefficient ([`fit`]).
#[derive(Default)]
struct Collect {
    coefficients: Vec<f32>,
    chroma: Vec<f32>,
}

impl CoefficientSink for Collect {
    fn put(&mut self, _start: usize, coefficients: &[f32], chroma: &[f32]) -> Result<()> {
        self.coefficients.extend_from_slice(coefficients);
        self.chroma.extend_from_slice(chroma);
        Ok(())
    }
}

/// Mask pixels fitted per block: the coefficients held at a time by [`fit_into`], whatever
/// the capture's layout (at most 4 · (3 · 9 + 3) · 65 536 bytes, 7.9 MB).
pub const BLOCK_PIXELS: usize = 65_536;

/// Widens `ranges` (per term) to hold `values` (`[..][term]`).
pub(crate) fn widen_ranges(ranges: &mut [(f32, f32)], values: &[f32]) {
    let t = ranges.len();
    for (i, &c) in values.iter().enumerate() {
        let e = &mut ranges[i % t];
        e.0 = e.0.min(c);
        e.1 = e.1.max(c);
    }
}

/// Fits `basis` to every mask pixel of `capture` and measures its leave-one-out error, the
/// coefficients held whole in the result ([`fit_into`] with a sink that keeps them).
/// The ridge weight is chosen from the data ([`Penalty::Auto`]).
pub fn fit(capture: &Capture, basis: Basis, exclude: Option<&dyn ReadingMask>) -> Result<RtiFit> {
    fit_penalised(capture, basis, exclude, Penalty::Auto)
}

/// [`fit`] with the ridge weight set by `penalty`.
pub fn fit_penalised(
    capture: &Capture,
    basis: Basis,
    exclude: Option<&dyn ReadingMask>,
    penalty: Penalty,
) -> Result<RtiFit> {
    let mut kept = Collect::default();
    let mut f = fit_penalised_into(capture, basis, exclude, penalty, &mut kept)?;
    f.coefficients = kept.coefficients;
    f.chroma = kept.chroma;
    Ok(f)
}

/// Fits `basis` to every mask pixel of `capture`, block by block ([`BLOCK_PIXELS`]) into
/// `sink`, and measures its leave-one-out error; the result holds no coefficients (its
/// `coefficients` and `chroma` are empty, its `ranges` measured). `exclude`, when given, flags
/// per mask pixel and light the readings to leave out of the pixel's fit and error; the
/// readings the camera clipped ([`Capture::clip_levels`]) are then left out as well. The ridge
/// weight is chosen from the data ([`Penalty::Auto`]).
pub fn fit_into(
    capture: &Capture,
    basis: Basis,
    exclude: Option<&dyn ReadingMask>,
    sink: &mut dyn CoefficientSink,
) -> Result<RtiFit> {
    fit_penalised_into(capture, basis, exclude, Penalty::Auto, sink)
}

/// [`fit_into`] with the ridge weight of the linear bases set by `penalty` (RBF has none).
pub fn fit_penalised_into(
    capture: &Capture,
    basis: Basis,
    exclude: Option<&dyn ReadingMask>,
    penalty: Penalty,
    sink: &mut dyn CoefficientSink,
) -> Result<RtiFit> {
    if basis == Basis::Rbf {
        if exclude.is_some() {
            return Err(Error::parameter(
                "exclude_unreliable",
                "rbf projects every pixel's readings under all the lights on one set of \
                 principal components; it has no per-pixel light mask (use ptm or hsh)",
            ));
        }
        check_distant(capture)?;
        return rbf::fit_into(capture, rbf::Width::Auto, rbf::Smoothing::Auto, sink);
    }
    let (np, n, c, t) = (
        capture.n_pixels(),
        capture.n_lights(),
        capture.channels,
        basis.terms(),
    );
    check_distant(capture)?;
    if let Some(e) = exclude {
        if e.readings() != np * n {
            return Err(Error::invalid(format!(
                "light mask of {} flags for {np} pixels × {n} lights",
                e.readings()
            )));
        }
    }
    let gain = display_gain(capture)?;
    let ridge = match penalty {
        Penalty::Auto => choose_ridge(capture, basis, exclude, gain)?,
        Penalty::Fixed(lambda) => given_ridge(lambda, Prior::Zero)?,
        Penalty::TowardPtm { lambda, ptm_lambda } => {
            given_ridge(ptm_lambda, Prior::Zero)?;
            given_ridge(lambda, Prior::Ptm { ptm_lambda })?
        }
    };
    let design = Design::new(capture, basis, ridge.lambda, ridge.prior)?;
    let clip = capture.clip_levels();
    let fc = if basis.luminance() { 1 } else { c };
    let per_pixel = fc * t;
    let mut loo = RelightErrors::new(n);
    let (mut excluded, mut fell_back) = (0u64, 0u64);
    let mut ranges = vec![(f32::INFINITY, f32::NEG_INFINITY); t];
    let (mut coefficients, mut chroma) = (Vec::new(), Vec::new());
    capture.for_each_tile(|start, view| {
        let count = view.n_pixels().min(np - start);
        for first in (0..count).step_by(BLOCK_PIXELS) {
            let len = BLOCK_PIXELS.min(count - first);
            coefficients.clear();
            coefficients.resize(len * per_pixel, 0f32);
            chroma.clear();
            chroma.resize(if basis.luminance() { len * 3 } else { 0 }, 1f32);
            let job = TileJob {
                view,
                start,
                first,
                ids: None,
                basis,
                design: &design,
                gain,
                exclude,
                clip: &clip,
            };
            let (errors, ex, fb) = job.run(&mut coefficients, &mut chroma);
            loo = std::mem::take(&mut loo).merge(errors);
            excluded += ex;
            fell_back += fb;
            widen_ranges(&mut ranges, &coefficients);
            sink.put(start + first, &coefficients, &chroma)?;
        }
        Ok(())
    })?;
    Ok(RtiFit {
        basis,
        width: capture.width,
        height: capture.height,
        channels: c,
        pixels: capture.pixels.clone(),
        fitted_channels: fc,
        coefficients: Vec::new(),
        chroma: Vec::new(),
        gain,
        loo,
        excluded_readings: excluded,
        fell_back_to_all_lights: fell_back,
        rbf: None,
        ridge: Some(ridge),
        kernel: None,
        ranges,
    })
}

/// A ridge given by the caller: `lambda` toward `prior`, refused unless a finite weight ≥ 0.
fn given_ridge(lambda: f64, prior: Prior) -> Result<Ridge> {
    if !(lambda.is_finite() && lambda >= 0.0) {
        return Err(Error::parameter(
            "ridge",
            format!("{lambda}: expected a finite weight ≥ 0"),
        ));
    }
    Ok(Ridge {
        lambda,
        prior,
        candidates: Vec::new(),
        toward_ptm: Vec::new(),
        sample_pixels: 0,
    })
}

/// The ridge of [`Penalty::Auto`] for `basis` on `capture` (readings × `gain`, `exclude` as
/// [`fit_into`] takes it): of the candidates [`RIDGE_GRID`] × N toward zero and, for HSH,
/// those > 0 toward PTM (PTM's λ_p chosen first the same way, where the lights determine
/// PTM), the one whose exact
/// leave-one-out error (the mean over the lights of the RMSE, as [`RtiFit::loo`] reports it)
/// over up to [`RIDGE_SAMPLE`] evenly spaced mask pixels is least; on a tie the first, so
/// toward zero before toward PTM and λ = 0 unless a ridge predicts the left-out readings
/// better. By construction the sample's error at the choice is at most its error
/// unregularised.
pub fn choose_ridge(
    capture: &Capture,
    basis: Basis,
    exclude: Option<&dyn ReadingMask>,
    gain: f64,
) -> Result<Ridge> {
    let ids = sample_ids(capture.n_pixels(), RIDGE_SAMPLE);
    let view = sample_view(capture, &ids)?;
    let sample = Sample {
        capture,
        view: &view,
        ids: &ids,
        exclude,
        clip: capture.clip_levels(),
        gain,
    };
    let candidates = sample.errors(basis, &RIDGE_GRID, Prior::Zero)?;
    let mut ridge = Ridge {
        lambda: 0.0,
        prior: Prior::Zero,
        candidates,
        toward_ptm: Vec::new(),
        sample_pixels: ids.len(),
    };
    // A rig whose lights determine HSH but not PTM (HSH2 under five lights) has no PTM to pull
    // toward: the ridge stays toward zero.
    let ptm = matches!(basis, Basis::Hsh2 | Basis::Hsh3)
        .then(|| sample.errors(Basis::PtmRgb, &RIDGE_GRID, Prior::Zero).ok())
        .flatten();
    if let Some(ptm) = ptm {
        let ptm_lambda = least(&ptm).0;
        ridge.toward_ptm = sample.errors(basis, &RIDGE_GRID[1..], Prior::Ptm { ptm_lambda })?;
        let (best, toward) = (least(&ridge.candidates), least(&ridge.toward_ptm));
        if toward.1 < best.1 {
            ridge.lambda = toward.0;
            ridge.prior = Prior::Ptm { ptm_lambda };
            return Ok(ridge);
        }
    }
    ridge.lambda = least(&ridge.candidates).0;
    Ok(ridge)
}

/// The (λ, error) with the least error, the first on a tie.
fn least(candidates: &[(f64, f64)]) -> (f64, f64) {
    candidates
        .iter()
        .copied()
        .fold(candidates[0], |b, c| if c.1 < b.1 { c } else { b })
}

/// The sample of mask pixels [`choose_ridge`] scores candidates on.
struct Sample<'a> {
    capture: &'a Capture,
    view: &'a Capture,
    ids: &'a [usize],
    exclude: Option<&'a dyn ReadingMask>,
    clip: Vec<[f32; 3]>,
    gain: f64,
}

impl Sample<'_> {
    /// Each λ / N of `per_light` (× N) toward `prior` and the sample's leave-one-out error.
    fn errors(&self, basis: Basis, per_light: &[f64], prior: Prior) -> Result<Vec<(f64, f64)>> {
        let (n, t) = (self.capture.n_lights(), basis.terms());
        let fc = if basis.luminance() {
            1
        } else {
            self.capture.channels
        };
        let len = self.ids.len();
        let mut coefficients = vec![0f32; len * fc * t];
        let mut chroma = vec![1f32; if basis.luminance() { len * 3 } else { 0 }];
        let mut out = Vec::with_capacity(per_light.len());
        for &w in per_light {
            let lambda = w * n as f64;
            let design = Design::new(self.capture, basis, lambda, prior)?;
            let job = TileJob {
                view: self.view,
                start: 0,
                first: 0,
                ids: Some(self.ids),
                basis,
                design: &design,
                gain: self.gain,
                exclude: self.exclude,
                clip: &self.clip,
            };
            let (errors, _, _) = job.run(&mut coefficients, &mut chroma);
            out.push((lambda, errors.mean_rmse_8bit()));
        }
        Ok(out)
    }
}

/// Refuses a capture with near lights.
fn check_distant(capture: &Capture) -> Result<()> {
    if capture.lights.near.is_some() {
        return Err(Error::invalid(
            "RTI bases model a reflectance under distant lights; this capture has near lights \
             (light_positions.txt), whose direction changes across the object",
        ));
    }
    Ok(())
}

/// One pixel's readings, fitted coefficients, operators and kept lights.
struct PixelData<'a> {
    samples: &'a [f32],
    coeffs: &'a [f32],
    /// The operators of the fit (the design's, or the pixel's own over its kept lights).
    ops: &'a Operators,
    /// Toward PTM: PTM's coefficients per fitted channel (`[channel][term]`).
    ptm: &'a [f64],
    /// Readings per fitted channel, display units (`[channel][light]`).
    y: &'a [f64],
    kept: &'a dyn Fn(usize) -> bool,
}

/// The fits of one block of a tile's pixels.
struct TileJob<'a> {
    view: &'a Capture,
    /// The tile's first mask pixel.
    start: usize,
    /// The block's first pixel within the tile.
    first: usize,
    /// When given, the pixels fitted (indices of `view`, which answers for them): pixel i of
    /// the block is `ids[first + i]` ([`choose_ridge`]'s sample).
    ids: Option<&'a [usize]>,
    basis: Basis,
    design: &'a Design,
    gain: f64,
    exclude: Option<&'a dyn ReadingMask>,
    /// With `exclude`: per light and channel the clip level ([`Capture::clip_levels`]); a
    /// reading at or above it is left out as well.
    clip: &'a [[f32; 3]],
}

/// Pixels per rayon task (the scratch is allocated per task, not per pixel).
const CHUNK: usize = 256;

impl TileJob<'_> {
    /// Fits the block's pixels into `out` (and `chroma` for LRGB); returns the LOO sums, the
    /// readings excluded and the pixels that fell back to every light.
    fn run(&self, out: &mut [f32], chroma: &mut [f32]) -> (RelightErrors, u64, u64) {
        let (n, t) = (self.view.n_lights(), self.design.t);
        let fc = if self.basis.luminance() {
            1
        } else {
            self.view.channels
        };
        let per_pixel = fc * t;
        let chroma_stride = if self.basis.luminance() { 3 } else { 0 };
        let mut chroma_chunks: Vec<&mut [f32]> = if chroma_stride > 0 {
            chroma.chunks_mut(CHUNK * 3).collect()
        } else {
            Vec::new()
        };
        chroma_chunks.resize_with(out.len().div_ceil(CHUNK * per_pixel), Default::default);
        out.par_chunks_mut(CHUNK * per_pixel)
            .zip(chroma_chunks.into_par_iter())
            .enumerate()
            .fold(
                || {
                    let toward_ptm = self.design.all.ptm.is_some();
                    let s = Scratch {
                        y: vec![0.0; n * fc],
                        flags: vec![false; n],
                        own: Operators::new(t, n, toward_ptm),
                        ptm: vec![0.0; if toward_ptm { fc * PTM_TERMS } else { 0 }],
                        errors: RelightErrors::new(n),
                    };
                    (s, 0u64, 0u64)
                },
                |(mut s, mut ex, mut fb), (i, (coeffs, chroma))| {
                    for (j, cp) in coeffs.chunks_mut(per_pixel).enumerate() {
                        let local = self.first + i * CHUNK + j;
                        let ch = if chroma.is_empty() {
                            None
                        } else {
                            Some(&mut chroma[j * 3..j * 3 + 3])
                        };
                        let (e, f) = self.pixel(local, cp, ch, &mut s);
                        ex += e;
                        fb += u64::from(f);
                    }
                    (s, ex, fb)
                },
            )
            .map(|(s, ex, fb)| (s.errors, ex, fb))
            .reduce(
                || (RelightErrors::new(n), 0, 0),
                |a, b| (a.0.merge(b.0), a.1 + b.1, a.2 + b.2),
            )
    }

    /// Fits one pixel (tile-local index `local`); returns the readings it excluded and whether
    /// it fell back to every light.
    fn pixel(
        &self,
        local: usize,
        coeffs: &mut [f32],
        chroma: Option<&mut [f32]>,
        s: &mut Scratch,
    ) -> (u64, bool) {
        let (n, t, c) = (self.view.n_lights(), self.design.t, self.view.channels);
        let local = self.ids.map_or(local, |ids| ids[local]);
        let samples = self.view.pixel_samples(local);
        let fc = if chroma.is_some() { 1 } else { c };
        for k in 0..n {
            let r = &samples[k * c..(k + 1) * c];
            if chroma.is_some() {
                s.y[k] = r.iter().map(|&x| f64::from(x)).sum::<f64>() / c as f64 * self.gain;
            } else {
                for (ch, &v) in r.iter().enumerate() {
                    s.y[ch * n + k] = f64::from(v) * self.gain;
                }
            }
        }
        let global = self.start + local;
        let mut held = std::mem::take(&mut s.flags);
        if let Some(e) = self.exclude {
            for (k, f) in held.iter_mut().enumerate() {
                *f = e.excluded(global, k, n) || clipped(samples, c, k, self.clip);
            }
        }
        let flags = self.exclude.map(|_| held.as_slice());
        let excluded = flags.map_or(0, |f| f.iter().filter(|&&x| x).count());
        let mut fell_back = false;
        let own = excluded > 0 && {
            let keep = |k: usize| !held[k];
            if n - excluded < t + 2 || !self.design.operators_into(keep, &mut s.own) {
                fell_back = true;
                false
            } else {
                true
            }
        };
        let ops = if own { &s.own } else { &self.design.all };
        let kept = |k: usize| !own || !flags.is_some_and(|f| f[k]);
        // Coefficients c = P y (+ V c_p toward PTM, c_p = P_p y; eq. 2 of [`design`]) per
        // fitted channel, over the kept lights.
        let apply = |p: &[f64], y: &[f64], j: usize| -> f64 {
            (0..n)
                .filter(|&k| kept(k))
                .map(|k| p[j * n + k] * y[k])
                .sum()
        };
        for ch in 0..fc {
            let y = &s.y[ch * n..(ch + 1) * n];
            let cp = &mut s.ptm[..];
            if let Some(po) = &ops.ptm {
                for i in 0..PTM_TERMS {
                    cp[ch * PTM_TERMS + i] = apply(&po.projector, y, i);
                }
            }
            for j in 0..t {
                let pulled = ops.ptm.as_ref().map_or(0.0, |po| {
                    (0..PTM_TERMS)
                        .map(|i| po.pull[j * PTM_TERMS + i] * cp[ch * PTM_TERMS + i])
                        .sum()
                });
                coeffs[ch * t + j] = (apply(&ops.projector, y, j) + pulled) as f32;
            }
        }
        let data = PixelData {
            samples,
            coeffs,
            ops,
            ptm: &s.ptm,
            y: &s.y,
            kept: &kept,
        };
        self.loo_errors(&data, chroma, &mut s.errors);
        s.flags = held;
        (excluded as u64 * u64::from(own), fell_back)
    }

    /// Adds the pixel's leave-one-out errors (closed form e_k / (1 − h_kk)) over its kept
    /// lights to `errors`, and for LRGB writes the chroma.
    fn loo_errors(&self, d: &PixelData, chroma: Option<&mut [f32]>, errors: &mut RelightErrors) {
        let (n, t, c) = (self.view.n_lights(), self.design.t, self.view.channels);
        let (samples, coeffs, kept) = (d.samples, d.coeffs, d.kept);
        let leverage = &d.ops.leverage;
        let a = &self.design.a;
        let fitted = |ch: usize, k: usize| -> f64 {
            (0..t)
                .map(|j| f64::from(coeffs[ch * t + j]) * a[k * t + j])
                .sum()
        };
        let reading = |k: usize, ch: usize| f64::from(samples[k * c + ch]) * self.gain;
        if let Some(chroma) = chroma {
            // Chroma: Σ_k I_kc / Σ_k Y_k over the kept lights (1 for a dark pixel).
            let (mut sc, mut sy) = ([0.0f64; 3], 0.0);
            for k in (0..n).filter(|&k| kept(k)) {
                sy += d.y[k];
                for (ch, v) in sc.iter_mut().enumerate().take(c) {
                    *v += reading(k, ch);
                }
            }
            let ratio = |num: f64, den: f64| if den > 1e-12 { num / den } else { 1.0 };
            for ch in 0..3 {
                chroma[ch] = ratio(sc[ch.min(c - 1)], sy) as f32;
            }
            for k in (0..n).filter(|&k| kept(k)) {
                let e = d.y[k] - fitted(0, k);
                let y_loo = d.y[k] - e / (1.0 - leverage[k]);
                for (ch, &total) in sc.iter().enumerate().take(c) {
                    let chroma_loo = ratio(total - reading(k, ch), sy - d.y[k]);
                    errors.add(k, chroma_loo * y_loo, reading(k, ch));
                }
            }
        } else {
            // Toward PTM, the shift of PTM's fit without light k (eq. 3 of [`design`]).
            let ptm = d.ops.ptm.as_ref().zip(self.design.ptm_at_lights());
            let shift = |ch: usize, k: usize, y: f64| -> f64 {
                ptm.map_or(0.0, |(po, ap)| {
                    let cp = &d.ptm[ch * PTM_TERMS..(ch + 1) * PTM_TERMS];
                    let row = &ap[k * PTM_TERMS..(k + 1) * PTM_TERMS];
                    let ep = y - (0..PTM_TERMS).map(|i| cp[i] * row[i]).sum::<f64>();
                    po.carry[k] * ep / (1.0 - po.leverage[k])
                })
            };
            for ch in 0..c {
                for k in (0..n).filter(|&k| kept(k)) {
                    let y = d.y[ch * n + k];
                    let e = y - fitted(ch, k) + shift(ch, k, y);
                    errors.add(k, y - e / (1.0 - leverage[k]), y);
                }
            }
        }
    }
}

/// The relighting error of a Lambertian model, I_kc = ρ_c · max(0, n · l_k), with full-frame
/// normals (H·W) and albedo (H·W·C, the capture's intensity-normalised units) against the
/// capture's readings, in display units (`gain` as [`RtiFit::gain`]), over the readings
/// `exclude` (as [`fit`] takes it) does not flag. The model's own fit, not left out: a
/// reference for the RTI bases' leave-one-out figures.
pub fn lambert_errors(
    capture: &Capture,
    normals: &[[f32; 3]],
    albedo: &[f32],
    gain: f64,
    exclude: Option<&dyn ReadingMask>,
) -> Result<RelightErrors> {
    let (n, c) = (capture.n_lights(), capture.channels);
    let dirs = &capture.lights.directions;
    let clip = capture.clip_levels();
    let mut total = RelightErrors::new(n);
    capture.for_each_tile(|start, view| {
        let e = (0..view.n_pixels())
            .into_par_iter()
            .fold(
                || RelightErrors::new(n),
                |mut acc, p| {
                    let i = capture.pixels[start + p] as usize;
                    let nn = normals[i];
                    let s = view.pixel_samples(p);
                    for (k, l) in dirs.iter().enumerate() {
                        if exclude.is_some_and(|e| e.excluded(start + p, k, n))
                            || (exclude.is_some() && clipped(s, c, k, &clip))
                        {
                            continue;
                        }
                        let shade = (f64::from(nn[0]) * l[0]
                            + f64::from(nn[1]) * l[1]
                            + f64::from(nn[2]) * l[2])
                            .max(0.0);
                        for ch in 0..c {
                            let pred = f64::from(albedo[i * c + ch]) * shade * gain;
                            acc.add(k, pred, f64::from(s[k * c + ch]) * gain);
                        }
                    }
                    acc
                },
            )
            .reduce(|| RelightErrors::new(n), RelightErrors::merge);
        total = std::mem::take(&mut total).merge(e);
        Ok(())
    })?;
    Ok(total)
}
